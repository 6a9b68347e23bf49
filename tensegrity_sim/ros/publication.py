"""The CDR bytes of the four outputs of every publication of the node: ``/clock``, ``~/node_poses``,
``~/cable_states`` and ``~/cable_impulses`` (``msg_docs/``), written in one compiled pass.

:class:`PublicationTemplates` holds one :class:`~.cdr.CdrTemplate` per output (the bytes rosbags
serialises for the node's frame id, cable names and sizes, with slots for the stamp and the arrays) and
fills them in turn (numpy assignments into views): the plain reference. :class:`PublicationCdr` lays
the four templates' bytes side by side in one buffer, placed so that every
float64 of them is 8-byte aligned, and writes the stamp, the positions, the cable lengths and rates,
tensions and impulse sums with one call of :func:`._publication_kernels.write_publication`; tests require
the very bytes of the reference.

Why (``bench/bench_log.py``, icosahedron, one process): the four template encodes and the member
kinematics took ~8.5 us a publication on a loaded machine (four calls, eleven numpy assignments, each
a few hundred ns of dispatch), the compiled pass ~2.2 us, its four ``bytes`` copies included. The rest of
a publication's cost is mcap's writer (~5-8 us a message; see :mod:`.log`).
"""
from __future__ import annotations

import numpy as np

from .._system_kernels import member_kinematics
from ._publication_kernels import LAYOUT, write_publication
from .cdr import CdrTemplate
from .interface import TOPICS

__all__ = ["PUBLISHED", "PublicationTemplates", "PublicationCdr"]

# the outputs of every publication (keys of TOPICS), in the order they go out
PUBLISHED = ("clock", "node_poses", "cable_states", "cable_impulses")
_STAMP = ("header.stamp.sec", "header.stamp.nanosec")


class PublicationTemplates:
    """The plain reference: one :class:`~.cdr.CdrTemplate` per output of :data:`PUBLISHED`, filled in
    turn. ``frame_id`` of the poses and cable states, ``n_nodes``, ``cable_names`` (n_cables,), and where the
    cables' ends lie: ``cable_nodes`` (n_cables, 2, 2) node indices and ``cable_weights`` (n_cables, 2)
    (``System.cable_nodes``, ``cable_weights``: a cable attached along a strut is measured there).

    What never changes in the templates is fixed here (the frame id, which is not a runtime parameter, the
    cable names, the number of nodes and cables, the identity orientation of the poses); the slots take
    the stamp and the arrays: clock (sec, nanosec); node_poses (sec, nanosec, positions (N, 3) m);
    cable_states (sec, nanosec, lengths m, rates m/s, tensions N, each (n_cables,)); cable_impulses (sec,
    nanosec, impulse sums (n_cables,) N*s). They encode the messages the node logic builds as objects,
    byte for byte (the tests check it).
    """

    def __init__(self, frame_id: str, n_nodes: int, cable_names, cable_nodes: np.ndarray, cable_weights: np.ndarray):
        header = {"frame_id": frame_id}
        zeros = np.zeros(len(cable_names))
        self.cable_nodes = np.ascontiguousarray(cable_nodes, dtype=np.int64).reshape(-1, 2, 2)
        self.cable_weights = np.ascontiguousarray(cable_weights, dtype=float).reshape(-1, 2)
        self.templates = {
            "clock": CdrTemplate(TOPICS["clock"].typename, {}, ("clock.sec", "clock.nanosec")),
            "node_poses": CdrTemplate(TOPICS["node_poses"].typename, {
                "header": header, "poses": [{"orientation": {"w": 1.0}}] * n_nodes}, (*_STAMP, "poses[].position")),
            "cable_states": CdrTemplate(TOPICS["cable_states"].typename, {
                "header": header, "name": list(cable_names), "position": zeros, "velocity": zeros, "effort": zeros},
                (*_STAMP, "position", "velocity", "effort")),
            "cable_impulses": CdrTemplate(TOPICS["cable_impulses"].typename, {
                "header": header, "name": list(cable_names), "effort": zeros}, (*_STAMP, "effort")),
        }

    def encode(self, ns: int, positions: np.ndarray, velocities: np.ndarray, tensions: np.ndarray,
               impulses: np.ndarray) -> list[bytes]:
        """The CDR bytes of :data:`PUBLISHED` stamped ``ns``: positions and velocities (N, 3) m, m/s (the
        cable lengths and rates from them, :func:`~tensegrity_sim._system_kernels.member_kinematics`),
        tensions and impulse sums (n_cables,) N, N*s."""
        sec, nanosec = divmod(ns, 1_000_000_000)
        length, rate = np.empty(len(self.cable_nodes)), np.empty(len(self.cable_nodes))
        member_kinematics(positions, velocities, self.cable_nodes, self.cable_weights, length, rate)
        t = self.templates
        return [t["clock"].encode(sec, nanosec),
                t["node_poses"].encode(sec, nanosec, positions),
                t["cable_states"].encode(sec, nanosec, length, rate, tensions),
                t["cable_impulses"].encode(sec, nanosec, impulses)]


class PublicationCdr:
    """:meth:`PublicationTemplates.encode` of ``reference`` in one compiled pass (module docstring).

    ValueError (never expected) if a slot of the templates is not where the compiled pass writes it: an
    unaligned float64, a stamp whose nanosec does not follow its sec, positions not 3 float64s in a row.
    """

    def __init__(self, reference: PublicationTemplates):
        templates = reference.templates
        self._nodes, self._weights = reference.cable_nodes, reference.cable_weights
        pieces = [templates[key].encode(*[0] * len(templates[key].slots)) for key in PUBLISHED]
        # message k starts at 4 mod 8, so its body (after the 4-byte encapsulation header), to which CDR
        # aligns, starts at 0 mod 8 in the buffer, and so does every float64 of it
        starts, end = [], 0
        for data in pieces:
            end += (4 - end) % 8
            starts.append(end)
            end += len(data)
        buffer = np.zeros(end + (-end) % 8, dtype=np.uint8)
        for start, data in zip(starts, pieces):
            buffer[start:start + len(data)] = np.frombuffer(data, dtype=np.uint8)
        self._spans = [(start, start + len(data)) for start, data in zip(starts, pieces)]
        self._f64, self._u32 = buffer.view(np.float64), buffer.view(np.uint32)
        self._bytes = memoryview(buffer)
        start = dict(zip(PUBLISHED, starts))

        def index(key: str, slot: str, dtype: str, shape: tuple) -> int:
            """The slot's first number as an index into the buffer's view of ``dtype`` (0 for a slot
            with no numbers: no cables), after checking that the slot is ``shape``d, aligned and its
            rows contiguous, as the compiled pass writes it."""
            place = templates[key].place(slot)
            if place is None:
                return 0
            offset, slot_shape, strides, slot_dtype = place
            at, size = start[key] + offset, slot_dtype.itemsize
            if (slot_dtype != np.dtype(dtype) or slot_shape != shape or at % size or any(s % size for s in strides)
                    or (shape and strides[-1] != size)):
                raise ValueError(f"{key}: slot {slot!r} is not where the compiled pass writes it")
            return at // size

        n_nodes, n_cables = templates["node_poses"].place("poses[].position")[1][0], len(self._nodes)
        layout = {"n_nodes": n_nodes}
        for key in PUBLISHED:
            sec, nanosec = ("clock.sec", "clock.nanosec") if key == "clock" else _STAMP
            layout[f"stamp_{key}"] = index(key, sec, "<i4", ())
            if index(key, nanosec, "<u4", ()) != layout[f"stamp_{key}"] + 1:
                raise ValueError(f"{key}: nanosec does not follow sec")
        layout["positions"] = index("node_poses", "poses[].position", "<f8", (n_nodes, 3))
        layout["pose_stride"] = templates["node_poses"].place("poses[].position")[2][0] // 8
        for name, key, slot in (("lengths", "cable_states", "position"), ("rates", "cable_states", "velocity"),
                                ("tensions", "cable_states", "effort"), ("impulses", "cable_impulses", "effort")):
            layout[name] = index(key, slot, "<f8", (n_cables,))
        self._layout = np.array([layout[name] for name in LAYOUT], dtype=np.int64)

    def encode(self, ns: int, positions: np.ndarray, velocities: np.ndarray, tensions: np.ndarray,
               impulses: np.ndarray) -> list[bytes]:
        """:meth:`PublicationTemplates.encode`, for stamps of 0 <= ``ns`` < 2**31 s (an int32's seconds)."""
        sec, nanosec = divmod(ns, 1_000_000_000)
        if not 0 <= sec < 2**31:
            raise ValueError(f"stamp {ns} ns: the seconds do not fit a builtin_interfaces/Time (int32)")
        write_publication(self._f64, self._u32, self._layout, positions, velocities, self._nodes, self._weights,
                          tensions, impulses, sec, nanosec)
        data = self._bytes
        return [bytes(data[a:b]) for a, b in self._spans]
