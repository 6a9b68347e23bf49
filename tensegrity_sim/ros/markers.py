"""The node's ``~/markers`` (visualization_msgs/MarkerArray, ``msg_docs/markers.md``): what a display
draws of the structure, as message objects or CDR bytes.

:class:`Markers` keeps what the drawing remembers between two marker arrays (the largest tension and
ground force seen, which scale the colours and force lines, and the namespaces on screen) and one
:class:`~.cdr.CdrTemplate` per marker shape. The node logic (:mod:`.node_logic`) decides when to draw.
"""
from __future__ import annotations

import numpy as np

from ..results import StepResult
from . import messages as M
from .cdr import CdrTemplate

__all__ = ["Markers", "MARKERS_TYPE"]

MARKERS_TYPE = "visualization_msgs/msg/MarkerArray"
_LINE_LIST, _CUBE_LIST, _SPHERE_LIST = 5, 6, 7
_ADD, _DELETE = 0, 2
_SHAPES_KEPT = 64  # MarkerArray templates kept of each kind (shapes: markers and point counts; markers alone)
_NO_POINTS = np.zeros((0, 3))

# (namespace, points (k, 3) m or None to delete it, per-point colours (k, 4) RGBA or None)
Content = list[tuple[str, np.ndarray | None, np.ndarray | None]]


class _MarkerStyle:
    """What never changes in a marker of one namespace: its fields but the header, action and points,
    built once (building message objects is most of what publishing costs)."""

    def __init__(self, ns: str, marker_id: int, kind: int, scale: float, color: tuple):
        self.spec = {"ns": ns, "id": marker_id, "type": kind, "pose": {"orientation": {"w": 1.0}},
                     "scale": dict.fromkeys("xyz", scale), "color": dict(zip("rgba", color))}
        empty_header = M.header(0, "")
        self.fields = dict(
            ns=ns, id=marker_id, type=kind,
            pose=M.new("geometry_msgs/msg/Pose", position=M.point(0.0, 0.0, 0.0),
                       orientation=M.new("geometry_msgs/msg/Quaternion", x=0.0, y=0.0, z=0.0, w=1.0)),
            scale=M.vector3(scale, scale, scale), color=M.color(*color),
            lifetime=M.new("builtin_interfaces/msg/Duration", sec=0, nanosec=0), frame_locked=False,
            texture_resource="",
            texture=M.new("sensor_msgs/msg/CompressedImage", header=empty_header, format="", data=M.uint8s()),
            uv_coordinates=[], text="", mesh_resource="",
            mesh_file=M.new("visualization_msgs/msg/MeshFile", filename="", data=M.uint8s()),
            mesh_use_embedded_materials=False)

    def marker(self, header, points: np.ndarray | None, colors: np.ndarray | None = None):
        """ADD with ``points`` (k, 3) m (and per-point ``colors`` (k, 4) RGBA), or DELETE when ``points``
        is None."""
        return M.new("visualization_msgs/msg/Marker", header=header, action=_DELETE if points is None else _ADD,
                     points=[] if points is None else [M.point(*p) for p in points.tolist()],
                     colors=[] if colors is None else [M.color(*c) for c in colors.tolist()], **self.fields)

    def prototype(self, frame_id: str, points: int | None, colored: bool) -> dict:
        """The fields of :meth:`marker` for :func:`~.cdr.prototype`: ``points`` points (None: DELETE), as
        many colours if ``colored``; the stamp, points and colours are left to slots."""
        return {**self.spec, "header": {"frame_id": frame_id}, "action": _DELETE if points is None else _ADD,
                "points": [{}] * (points or 0), "colors": [{}] * (points or 0) if colored else []}


def _keep(kept: dict, key, template: CdrTemplate) -> None:
    """(Re)insert ``template`` last in ``kept`` (the most recently used), forgetting the oldest beyond
    :data:`_SHAPES_KEPT`."""
    kept.pop(key, None)
    kept[key] = template
    if len(kept) > _SHAPES_KEPT:
        kept.pop(next(iter(kept)))


def _ground_grid(scene, size: float) -> np.ndarray:
    """A square grid of lines (LINE_LIST points (k, 3) m) on the ground plane under the scene's start,
    four scene sizes wide, lines half a size apart; none without a ground."""
    if scene.ground is None:
        return np.zeros((0, 3))
    cx, cy = scene.positions[:, :2].mean(axis=0)
    ticks = np.arange(-4, 5) * 0.5 * size
    lo, hi = ticks[0], ticks[-1]
    lines = [[(cx + t, cy + lo), (cx + t, cy + hi)] for t in ticks] + [[(cx + lo, cy + t), (cx + hi, cy + t)]
                                                                       for t in ticks]
    xy = np.array(lines, dtype=float).reshape(-1, 2)
    return np.column_stack([xy, np.full(len(xy), scene.ground.height)])


class Markers:
    """The marker arrays of one node: ``sim`` (its scene and ``dt``), ``frame_id`` of the points.

    Marker sizes are the members' radii where the scene gives them, else a fraction of its size.
    """

    def __init__(self, sim, frame_id: str):
        scene = sim.scene
        self._sim = sim
        self._frame_id = frame_id
        x0 = scene.positions
        size = float(np.linalg.norm(x0.max(axis=0) - x0.min(axis=0))) or 1.0
        strut_r = max((s.radius for s in scene.struts), default=0.0)
        cable_r = max((c.radius for c in scene.cables), default=0.0)
        strut_width = 2 * strut_r if strut_r > 0 else 0.01 * size
        cable_width = 2 * cable_r if cable_r > 0 else 0.004 * size
        self._styles = {
            "struts": _MarkerStyle("struts", 0, _LINE_LIST, strut_width, (0.25, 0.4, 0.8, 1.0)),
            "cables": _MarkerStyle("cables", 1, _LINE_LIST, cable_width, (1.0, 1.0, 1.0, 1.0)),
            "slack_cables": _MarkerStyle("slack_cables", 2, _LINE_LIST, 0.5 * cable_width, (0.6, 0.6, 0.6, 0.5)),
            "supports": _MarkerStyle("supports", 3, _CUBE_LIST, 3.0 * strut_width, (0.5, 0.5, 0.5, 1.0)),
            "contacts": _MarkerStyle("contacts", 4, _SPHERE_LIST, 3.0 * strut_width, (1.0, 0.0, 0.0, 1.0)),
            "ground": _MarkerStyle("ground", 5, _LINE_LIST, 0.5 * cable_width, (0.45, 0.35, 0.25, 1.0)),
            "contact_forces": _MarkerStyle("contact_forces", 6, _LINE_LIST, strut_width, (1.0, 0.55, 0.0, 1.0)),
        }
        system = sim.system
        # node indices of the points of each line list, flattened once (x.take(...) is one gather)
        self._strut_points = system.strut_ends.reshape(-1)
        self._cable_ends = system.cable_ends
        # a cable attached along a strut is drawn from where it is attached (System.cable_points), the others
        # by a gather of their nodes
        self._cable_points = system.cable_points if len(system.attached) else None
        self._supports = np.flatnonzero(~system.free)
        self._ground_grid = _ground_grid(scene, size)
        self._scene_size = size
        self._templates: dict[tuple, CdrTemplate] = {}  # marker shape -> template, oldest use first
        self._bases: dict[tuple, CdrTemplate] = {}      # markers -> their template with a point each, the same
        self.clear()

    def clear(self) -> None:
        """Forget the largest tension and ground force seen and what is on screen (a reset)."""
        self._tension_scale = 0.0                    # the largest tension seen: red in the markers
        self._force_scale = 0.0   # the largest ground force seen (N): drawn 0.3 scene sizes long
        self._shown: set[str] = set()                # marker namespaces on screen

    def prepare(self, r: StepResult) -> None:
        """Build now the template of the marker array after ``r`` (with no contacts), remembering nothing
        else of it, and the markers' templates that a run meets first: with contacts (and, with a ground,
        their forces), and with slack cables shown, then deleted. A node does so for its initial state, so
        that no publication pays them (1.3-2.3 ms each of rosbags serialisation and layout walk, measured in
        a rolling run: over two ticks' worth)."""
        remembered = self._tension_scale, set(self._shown), self._force_scale
        initial = self.content(r, ())
        self.cdr(0, initial)
        self._tension_scale, self._shown, self._force_scale = remembered
        touching = {"contacts"} | ({"contact_forces"} if self._sim.scene.ground is not None else set())
        shown = {ns for ns, _, _ in initial} | touching
        for slack in ((), (("slack_cables", False),), (("slack_cables", True),)):
            kinds = tuple((ns, dict(slack).get(ns, False), ns == "cables") for ns in self._styles
                          if ns in shown or ns in dict(slack))
            if kinds not in self._bases:
                _keep(self._bases, kinds, self._base(kinds))

    def content(self, r: StepResult, active_contacts) -> Content:
        """The markers of one MarkerArray after step ``r``: struts (thick blue lines); taut cables (lines
        coloured blue -> red by tension, red = the largest tension seen so far); slack cables (thin grey
        lines); supports (grey cubes at fixed nodes); ``active_contacts`` (the ContactEvents that began and
        have not ended: red spheres at both closest points); the ground (a brown grid) and its forces on the
        nodes (orange lines). A namespace with nothing to show is deleted once, then left out."""
        x = r.positions
        slack = r.slack
        self._tension_scale = max(self._tension_scale, float(r.tensions.max(initial=0.0)))
        ends = None if self._cable_points is None else self._cable_points(x)   # (n_cables, 2, 3) m
        if slack.any():
            taut = ~slack
            tensions = r.tensions[taut]
            if ends is None:
                cables = x.take(self._cable_ends[taut].reshape(-1), axis=0)
                slack_cables = x.take(self._cable_ends[slack].reshape(-1), axis=0)
            else:
                cables, slack_cables = ends[taut].reshape(-1, 3), ends[slack].reshape(-1, 3)
        else:  # the usual case: every cable taut, no mask to apply
            tensions = r.tensions
            cables = x.take(self._cable_ends.reshape(-1), axis=0) if ends is None else ends.reshape(-1, 3)
            slack_cables = _NO_POINTS
        level = np.repeat(tensions / self._tension_scale if self._tension_scale > 0 else tensions, 2)
        colors = np.empty((len(level), 4))
        colors[:, 0] = level
        colors[:, 1] = 0.2
        colors[:, 2] = 1.0 - level
        colors[:, 3] = 1.0
        contacts = [p for e in active_contacts for p in (e.point_a, e.point_b)]
        content = {
            "struts": (x.take(self._strut_points, axis=0), None),
            "cables": (cables, colors),
            "slack_cables": (slack_cables, None),
            "supports": (x.take(self._supports, axis=0), None),
            "contacts": (np.array(contacts, dtype=float).reshape(-1, 3) if contacts else _NO_POINTS, None),
            "ground": (self._ground_grid, None),
            "contact_forces": self._contact_forces(r),
        }
        markers = []
        for ns, (points, colors) in content.items():
            if len(points):
                markers.append((ns, points, colors))
                self._shown.add(ns)
            elif ns in self._shown:
                markers.append((ns, None, None))
                self._shown.discard(ns)
        return markers

    def _contact_forces(self, r: StepResult):
        """Lines from each node's ground contact point along the ground's mean force over the step
        (impulse / dt), the largest force seen drawn 0.3 scene sizes long: (points (2k, 3), None)."""
        ground = self._sim.scene.ground
        if r.contact_impulses is None or ground is None:
            return _NO_POINTS, None
        force = r.contact_impulses / self._sim.dt
        magnitude = np.linalg.norm(force, axis=1)
        on = magnitude > 0
        self._force_scale = max(self._force_scale, float(magnitude.max(initial=0.0)))
        start = r.positions[on].copy()
        start[:, 2] = ground.height
        end = start + force[on] * (0.3 * self._scene_size / max(self._force_scale, 1e-300))
        return np.stack([start, end], axis=1).reshape(-1, 3), None

    def message(self, header, markers: Content):
        """The MarkerArray object of :meth:`content`'s ``markers``."""
        return M.new(MARKERS_TYPE, markers=[self._styles[ns].marker(header, points, colors)
                                            for ns, points, colors in markers])

    def cdr(self, time_ns: int, markers: Content) -> bytes:
        """The CDR bytes of :meth:`message` stamped ``time_ns``. Which markers there are and how
        many points each has (its shape) changes with the slack cables and the contacts, so there is one
        template per shape (:data:`_SHAPES_KEPT` of them, the oldest forgotten first), resized from the one of
        its markers with a point each (:meth:`~.cdr.CdrTemplate.resized`: ~0.1 ms), which is made when those
        markers are first seen (a few rosbags serialisations and a walk of ~400 fields: ~3 ms)."""
        shape = tuple((ns, None if points is None else len(points)) for ns, points, _ in markers)
        template = self._templates.get(shape)
        if template is None:
            kinds = tuple((ns, points is None, colors is not None) for ns, points, colors in markers)
            base = self._bases.get(kinds) or self._base(kinds)
            _keep(self._bases, kinds, base)
            template = base.resized({f"markers[{i}].{field}": len(points) for i, (_, points, colors) in
                                     enumerate(markers) if points is not None
                                     for field in (("points", "colors") if colors is not None else ("points",))})
        _keep(self._templates, shape, template)
        values = []
        sec, nanosec = divmod(time_ns, 1_000_000_000)
        for _, points, colors in markers:
            values += [sec, nanosec] + [a for a in (points, colors) if a is not None]
        return template.encode(*values)

    def _base(self, kinds: tuple[tuple[str, bool, bool], ...]) -> CdrTemplate:
        """The template of the markers ``kinds`` (namespace, deleted, coloured), one point each."""
        fields, slots = [], []
        for i, (ns, deleted, colored) in enumerate(kinds):
            fields.append(self._styles[ns].prototype(self._frame_id, None if deleted else 1, colored))
            slots += [f"markers[{i}].header.stamp.sec", f"markers[{i}].header.stamp.nanosec"]
            if not deleted:
                slots.append(f"markers[{i}].points[]")
            if colored:
                slots.append(f"markers[{i}].colors[]")
        return CdrTemplate(MARKERS_TYPE, {"markers": fields}, slots)
