"""Ground contacts as events (contract §5): a node begins touching the ground when its gap
(``methods/contact/friction.py``: height above the ground minus its radius) drops to ``TOUCH_TOL`` and ends when
it rises above it. Events and active contacts name the pair ``(node name, "ground")``: the node is what
touches (its largest member's capsule end), and two ends of one strut are two contacts.
"""
from __future__ import annotations

import numpy as np

from ._ground_event_kernels import changed_steps, ground_changes
from .detection import ActiveContact
from .friction import TOUCH_TOL
from ...results import ContactEvent
from ...system import System

__all__ = ["GroundDetector", "GROUND", "walk_copies"]

GROUND = "ground"
_DOWN = np.array([0.0, 0.0, -1.0])
_PLANE = np.array([1.0, 1.0, 0.0])   # an impulse's friction part: its x and y


class GroundDetector:
    """Begin/end events of the nodes' ground contacts, and the contacts going on (with the impulses of
    the last step). A begin's time is where the node's free path from the step's start (its velocity
    and gravity) reaches the ground, as the methods locate an impact; an end's is interpolated linearly
    between the step's two gaps."""

    def __init__(self, system: System):
        self.names = system.scene.node_names
        self.height = system.scene.ground.height
        self.radii = system.scene.node_radii
        self.free = system.free
        self.gravity = float(system.scene.gravity[2])
        self.reset(system.scene.positions)

    def gaps(self, x: np.ndarray) -> np.ndarray:
        return x[:, 2] - self.radii - self.height

    def reset(self, positions: np.ndarray) -> None:
        """No contact known at ``positions``: nodes touching there begin at the next step's start."""
        self._inside = np.zeros(len(self.names), dtype=bool)
        self._since = np.full(len(self.names), np.nan)
        self.impulses = np.zeros((len(self.names), 3))

    def _event(self, kind: str, p: int, position: np.ndarray, time: float, gap: float,
               impulse: np.ndarray) -> ContactEvent:
        """Node ``p``'s event at its ``position`` (3,) m, with the ground's ``impulse`` (3,) N*s on it."""
        point = position.copy()
        ground = point.copy()
        ground[2] = self.height
        point[2] -= self.radii[p]
        return ContactEvent(kind, (self.names[p], GROUND), time, point, ground, _DOWN.copy(), gap,
                            float(impulse[2]), impulse * _PLANE)

    def step(self, x0: np.ndarray, x1: np.ndarray, v0: np.ndarray, t0: float, dt: float,
             impulses: np.ndarray | None) -> tuple[ContactEvent, ...]:
        """The events (time order) of a step from ``x0`` to ``x1`` (N, 3) m starting at ``t0`` s with
        velocities ``v0`` (N, 3) m/s; ``impulses`` (N, 3) N*s: the ground's impulses of the step (or None)."""
        self.impulses = np.zeros_like(self.impulses) if impulses is None else impulses
        g0, g1 = self.gaps(x0), self.gaps(x1)
        now = ((g1 <= TOUCH_TOL) | (self.impulses[:, 2] > 0)) & self.free
        changed = np.flatnonzero(now != self._inside)
        if not changed.size:
            return ()
        frac = _fractions(g0[changed], g1[changed], v0[changed, 2], now[changed], self.gravity, dt)
        events = []
        for p, f in sorted(zip(changed, frac), key=lambda pf: (pf[1], pf[0])):
            events.append(self._crossing(int(p), bool(now[p]), f, x0[p], x1[p], g0[p], g1[p], t0, dt))
        self._inside = now
        return tuple(events)

    def _crossing(self, p: int, begins: bool, f, x0, x1, g0, g1, t0: float, dt: float) -> ContactEvent:
        """Node ``p``'s event at fraction ``f`` of the step from ``t0`` (its positions ``x0``, ``x1`` (3,) and
        gaps ``g0``, ``g1`` at the step's ends), with the step's impulses (``impulses``)."""
        time = float(t0 + f * dt)
        xp = (1.0 - f) * x0 + f * x1   # the point: on the straight path (the gap is ~0 at a landing)
        if begins:
            self._since[p] = time
        return self._event("begin" if begins else "end", p, xp, time, float((1.0 - f) * g0 + f * g1),
                           self.impulses[p])

    def walk(self, x0: np.ndarray, v0: np.ndarray, positions: np.ndarray, velocities: np.ndarray,
             impulses: np.ndarray, t0: float, dt: float) -> list[ContactEvent]:
        """The events of consecutive steps from ``x0``, ``v0`` (N, 3) to ``positions``, ``velocities``
        (K, N, 3) in turn, with the ground's ``impulses`` (K, N, 3) N*s of each, the first starting at
        ``t0`` s: :meth:`step` called for the steps where a node's contact begins or ends only (the others
        would return no event and change nothing but the last impulses), found for all steps at once."""
        found = walk_copies([self], x0[..., None], v0[..., None], positions[..., None], velocities[..., None],
                            impulses[..., None], t0, dt)
        return [e for k in sorted(found) for e in found[k][0]]

    def changes(self, positions: np.ndarray, impulses: np.ndarray) -> np.ndarray:
        """(K,) bool: the consecutive steps to ``positions`` (K, N, 3) with ``impulses`` (K, N, 3) at which
        :meth:`step` would find an event; at the others it only keeps the impulses (``impulses = ...``)."""
        changed = np.empty(len(positions), dtype=bool)
        changed_steps(positions, impulses, self._inside, self.radii, self.height, self.free, TOUCH_TOL, changed)
        return changed

    def active(self, positions: np.ndarray) -> tuple[ActiveContact, ...]:
        """Every node touching the ground now, with its gap and the last step's impulses."""
        out = []
        for p in np.flatnonzero(self._inside):
            e = self._event("begin", int(p), positions[p], float(self._since[p]), float(self.gaps(positions)[p]),
                            self.impulses[p])
            out.append(ActiveContact(e.members, e.time, e.point_a, e.point_b, e.normal, e.distance,
                                     e.normal_impulse, e.tangential_impulse))
        return tuple(out)


def _fractions(g0: np.ndarray, g1: np.ndarray, vz: np.ndarray, begins: np.ndarray, gravity: float,
               dt: float) -> np.ndarray:
    """Where in a step (fraction 0..1) each contact that begins or ends crosses ``TOUCH_TOL``: for gaps
    ``g0``, ``g1`` (k,) m at the step's ends, the crossing on the straight path between them (0 if
    already there); for a landing (``begins`` (k,) bool, from above), the small root of
    ``g0 + vz t + a t^2 / 2 = TOUCH_TOL`` on the free path (``vz`` (k,) m/s at the start, ``a`` the
    scene's gravity along z)."""
    frac = np.clip(np.divide(g0 - TOUCH_TOL, g0 - g1, out=np.zeros(g0.size), where=g0 != g1), 0.0, 1.0)
    g = g0 - TOUCH_TOL
    disc = np.sqrt(np.maximum(vz * vz - 2.0 * gravity * g, 0.0))
    path = np.divide(2.0 * g, (-vz + disc) * dt, out=np.full(g0.size, np.nan), where=(-vz + disc) > 0)
    landing = begins & (g > 0) & np.isfinite(path)
    frac[landing] = np.clip(path[landing], 0.0, 1.0)
    return frac


def walk_copies(detectors: list[GroundDetector], x0: np.ndarray, v0: np.ndarray, positions: np.ndarray,
                velocities: np.ndarray, impulses: np.ndarray, t0: float, dt: float) -> dict[int, list[tuple]]:
    """:meth:`GroundDetector.step` of B copies (one detector each) over K consecutive steps at once: ``x0``,
    ``v0`` (N, 3, B), ``positions``, ``velocities``, ``impulses`` (K, N, 3, B). Returns the events of the
    steps that have any, by step (from 0): a list of B tuples, each copy's. The contacts that begin or end are
    found in one compiled pass (:func:`ground_changes`), their crossings computed (:func:`_fractions`) for
    every step and copy together; each event is then made in the order and arithmetic of
    :meth:`GroundDetector.step`."""
    found: dict[int, list[tuple]] = {}
    if not len(positions):
        return found
    first = detectors[0]
    inside = np.stack([d._inside for d in detectors], axis=-1)                                     # (N, B)
    last = np.empty_like(inside)
    steps, nodes, copies, begins = ground_changes(positions, impulses, inside, first.radii, first.height,
                                                  first.free, TOUCH_TOL, last)
    if len(steps):
        start = steps > 0
        before = np.maximum(steps - 1, 0)
        g0 = np.where(start, positions[before, nodes, 2, copies], x0[nodes, 2, copies]) - first.radii[nodes] \
            - first.height
        vz = np.where(start, velocities[before, nodes, 2, copies], v0[nodes, 2, copies])
        g1 = positions[steps, nodes, 2, copies] - first.radii[nodes] - first.height
        frac = _fractions(g0, g1, vz, begins, first.gravity, dt)
        for e in np.lexsort((nodes, frac, copies, steps)):   # by step and copy, then as GroundDetector.step
            i, p, b = int(steps[e]), int(nodes[e]), int(copies[e])
            d = detectors[b]
            d.impulses = impulses[i, ..., b]
            start_x = positions[i - 1, p, :, b] if i else x0[p, :, b]
            event = d._crossing(p, bool(begins[e]), frac[e], start_x, positions[i, p, :, b], g0[e], g1[e],
                                t0 + i * dt, dt)
            row = found.setdefault(i, [()] * len(detectors))
            row[b] = row[b] + (event,)
    for b, d in enumerate(detectors):
        d._inside = last[:, b].copy()
        d.impulses = impulses[-1, ..., b].copy()
    return found
