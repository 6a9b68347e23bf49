"""Scenes: the immutable description of a tensegrity structure, its YAML schema and its validation.

A :class:`Scene` holds what does not change during a run (topology, masses, stiffnesses, radii, the
initial state and the initial rest lengths). Everything is checked once, here, when the scene is built;
a bad entry raises :class:`SceneError` naming the source, the entry and the field::

    prism3.yaml: cables[3] 'c3': stiffness must be > 0, got -5.0

Units are SI: metres, kilograms, newtons, seconds.
"""
from __future__ import annotations

import math
import re
import warnings
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import yaml

from .checks import describe, read_yaml, real

__all__ = [
    "SceneError",
    "ClassKWarning",
    "LumpedMassWarning",
    "Node",
    "Strut",
    "Cable",
    "Attachment",
    "Ground",
    "ContactResponse",
    "Scene",
    "load_scene",
    "builtin_scenes",
    "CONTACT_KINDS",
    "DEFAULT_CONTACT_KINDS",
    "contact_kinds",
]

_NAME_RE = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
RIGID = "rigid"


class SceneError(ValueError):
    """A scene that cannot be loaded; the message names the source, the entry and the field."""


class ClassKWarning(UserWarning):
    """A node carries more than one strut: a class-k structure, not a tensegrity in the strict sense."""


class LumpedMassWarning(UserWarning):
    """A rigid strut's distributed mass is lumped at its ends (row sums) because its consistent mass block cannot
    stand alone: one of its ends is also another rigid strut's (class-k), or the method takes no blocks (the
    inextensible method; the JAX backend with a ground). The elastic method takes them everywhere else."""


@dataclass(frozen=True)
class Node:
    name: str
    position: tuple[float, float, float]  # m
    mass: float  # kg (own lumped mass, without strut masses); 0.0 allowed only for a fixed node
    velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)  # m/s
    fixed: bool = False
    radius: float | None = None  # m: an end cap of its own (ground contact); None: its members' largest radius


@dataclass(frozen=True)
class Strut:
    name: str
    nodes: tuple[str, str]
    stiffness: float  # N/m axial (EA/L); math.inf for a rigid strut
    rest_length: float  # m
    mass: float = 0.0  # kg, spread along the strut as ``mass_distribution`` says
    radius: float = 0.0  # m
    mass_distribution: str = "uniform"  # "uniform" along the strut, or "ends" (half at each end node)
    payloads: tuple[tuple[float, float], ...] = ()  # point masses (at, kg), ``at`` in [0, 1] from the first node

    @property
    def rigid(self) -> bool:
        return math.isinf(self.stiffness)

    @property
    def mass_block(self) -> tuple[float, float, float]:
        """The strut's consistent mass matrix in its two end nodes' coordinates, ``[[A, B], [B, C]] (x) I3``
        (physics.md section 4c), as ``(A, B, C)`` kg: ``A = int (1-s)^2 dm``, ``B = int s(1-s) dm``,
        ``C = int s^2 dm`` over the strut's mass (``s`` from 0 at the first node to 1 at the second): a uniform
        rod gives ``m/6 [[2, 1], [1, 2]]``, its ends only ``m/2 [[1, 0], [0, 1]]``, a payload ``m_p`` at ``s = a``
        adds ``m_p [[(1-a)^2, a(1-a)], [a(1-a), a^2]]``. Its row sums are the mass each end carries."""
        if self.mass_distribution == "uniform":
            a, b, c = self.mass / 3.0, self.mass / 6.0, self.mass / 3.0
        else:
            a, b, c = 0.5 * self.mass, 0.0, 0.5 * self.mass
        for at, m in self.payloads:
            a += m * (1.0 - at) ** 2
            b += m * at * (1.0 - at)
            c += m * at * at
        return a, b, c


@dataclass(frozen=True)
class Attachment:
    """A cable end on a strut (physics.md section 4c): the point ``(1 - at) x_a + at x_b`` of strut ``strut``
    (``x_a`` its first node, ``x_b`` its second), ``at`` in [0, 1]; the cable's force there is shared
    ``(1 - at, at)`` between the strut's ends."""

    strut: str
    at: float


@dataclass(frozen=True)
class Cable:
    name: str
    nodes: tuple[str | Attachment, str | Attachment]  # a node's name, or a point on a strut
    stiffness: float | None  # N/m; None when the scene only serves the inextensible method
    rest_length: float  # m
    damping: float = 0.0  # N*s/m, acts only while taut
    radius: float = 0.0  # m
    mass: float = 0.0  # kg, the plate of the full model (physics §4b); 0: massless (methods 1 and 2)


@dataclass(frozen=True)
class Ground:
    """The plane ``z = height`` (m) that nothing passes below; ``friction``: Coulomb coefficient (static
    = kinetic) >= 0; ``restitution``: Newton's coefficient in [0, 1] (0: perfectly plastic)."""

    height: float = 0.0
    friction: float = 0.0
    restitution: float = 0.0


@dataclass(frozen=True)
class ContactResponse:
    """What member contacts do: ``response`` false (default) detects them only; true keeps members from
    interpenetrating, with Coulomb ``friction`` >= 0 and ``restitution`` in [0, 1]."""

    response: bool = False
    friction: float = 0.0
    restitution: float = 0.0


class _Context:
    """Builds error messages: ``source: entry 'name': field message``."""

    def __init__(self, source: str):
        self.source = source

    def error(self, where: str, msg: str) -> SceneError:
        prefix = f"{self.source}: " if self.source else ""
        return SceneError(f"{prefix}{where}: {msg}" if where else f"{prefix}{msg}")


def _entry_label(kind: str, index: int, raw: Any) -> str:
    name = raw.get("name") if isinstance(raw, Mapping) else None
    return f"{kind}[{index}] {describe(name)}" if isinstance(name, str) else f"{kind}[{index}]"


def _check_keys(ctx: _Context, where: str, raw: Any, allowed: set[str], required: set[str]) -> None:
    if not isinstance(raw, Mapping):
        raise ctx.error(where, f"must be a mapping, got {type(raw).__name__}")
    unknown = [key for key in raw if key not in allowed]  # keys of a dict may be of any type: no sorting
    if unknown:
        raise ctx.error(where, f"unknown key {describe(unknown[0])} (allowed: {', '.join(sorted(allowed))})")
    missing = sorted(required - set(raw))
    if missing:
        raise ctx.error(where, f"missing required key {missing[0]!r}")


def _number(ctx: _Context, where: str, fld: str, value: Any) -> float:
    try:
        return real(value, fld)
    except ValueError as exc:
        raise ctx.error(where, str(exc)) from None


def _positive(ctx: _Context, where: str, fld: str, value: Any) -> float:
    value = _number(ctx, where, fld, value)
    if value <= 0.0:
        raise ctx.error(where, f"{fld} must be > 0, got {value!r}")
    return value


def _non_negative(ctx: _Context, where: str, fld: str, value: Any) -> float:
    value = _number(ctx, where, fld, value)
    if value < 0.0:
        raise ctx.error(where, f"{fld} must be >= 0, got {value!r}")
    return value


def _fraction(ctx: _Context, where: str, fld: str, value: Any) -> float:
    value = _number(ctx, where, fld, value)
    if not 0.0 <= value <= 1.0:
        raise ctx.error(where, f"{fld} must be in [0, 1], got {value!r}")
    return value


def _vector3(ctx: _Context, where: str, fld: str, value: Any) -> tuple[float, float, float]:
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise ctx.error(where, f"{fld} must be a list of 3 numbers, got {describe(value)}")
    return tuple(_number(ctx, where, fld, v) for v in value)  # type: ignore[return-value]


def _name(ctx: _Context, where: str, value: Any, seen: set[str]) -> str:
    if not isinstance(value, str) or not _NAME_RE.fullmatch(value):  # match() would let a final newline in
        raise ctx.error(where, f"name must match [A-Za-z_][A-Za-z0-9_]*, got {describe(value)}")
    if value in seen:
        raise ctx.error(where, f"duplicate name {value!r}")
    seen.add(value)
    return value


def _bool(ctx: _Context, where: str, fld: str, value: Any) -> bool:
    if not isinstance(value, bool):
        raise ctx.error(where, f"{fld} must be true or false, got {describe(value)}")
    return value


# Member pairs that contact detection can check (physics.md section 5); a scene picks some with its
# optional ``contact: {kinds: [...]}`` key. Struts against struts by default: thin cables rarely matter.
CONTACT_KINDS = ("strut_strut", "strut_cable", "cable_cable")
DEFAULT_CONTACT_KINDS = ("strut_strut",)


def contact_kinds(value: Any, fld: str) -> tuple[str, ...]:
    """The member kinds of a list such as ``["strut_cable", "strut_strut"]``, in the order of
    :data:`CONTACT_KINDS`; an empty list checks nothing. Raises ``ValueError`` whose message starts
    with ``fld``."""
    allowed = ", ".join(CONTACT_KINDS)
    if not isinstance(value, (list, tuple)):
        raise ValueError(f"{fld} must be a list of member kinds ({allowed}), got {describe(value)}")
    for i, kind in enumerate(value):
        if not isinstance(kind, str) or kind not in CONTACT_KINDS:
            raise ValueError(f"{fld}: unknown member kind {describe(kind)} (allowed: {allowed})")
        if kind in value[:i]:
            raise ValueError(f"{fld}: duplicate member kind {kind!r}")
    return tuple(k for k in CONTACT_KINDS if k in value)


_TOP_KEYS = {"name", "gravity", "nodes", "struts", "cables", "contact", "ground"}
_CONTACT_KEYS = {"kinds", "response", "friction", "restitution"}
_GROUND_KEYS = {"height", "friction", "restitution"}
_NODE_KEYS = {"name", "position", "mass", "velocity", "fixed", "radius"}
_STRUT_KEYS = {"name", "nodes", "stiffness", "rest_length", "mass", "radius", "mass_distribution", "payloads"}
_PAYLOAD_KEYS = {"at", "mass"}
MASS_DISTRIBUTIONS = ("uniform", "ends")
_CABLE_KEYS = {"name", "nodes", "stiffness", "rest_length", "damping", "radius", "mass"}
_ATTACHMENT_KEYS = {"strut", "at"}


@dataclass(frozen=True)
class Scene:
    """An immutable tensegrity scene.

    Node order is index order everywhere (arrays, messages, logs); members keep file order.
    Build one with :meth:`from_dict` or :func:`load_scene`; both validate everything.
    """

    name: str
    gravity: tuple[float, float, float]
    nodes: tuple[Node, ...]
    struts: tuple[Strut, ...]
    cables: tuple[Cable, ...]
    contact_kinds: tuple[str, ...] = DEFAULT_CONTACT_KINDS  # member pairs contact detection checks
    ground: Ground | None = None                            # None: no ground
    contact_response: ContactResponse = ContactResponse()   # what member contacts do
    source: str = field(default="", compare=False)

    # ----------------------------------------------------------------- names
    @property
    def node_names(self) -> tuple[str, ...]:
        return tuple(n.name for n in self.nodes)

    @property
    def strut_names(self) -> tuple[str, ...]:
        return tuple(s.name for s in self.struts)

    @property
    def cable_names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.cables)

    # ----------------------------------------------------------------- arrays
    @property
    def positions(self) -> np.ndarray:
        """Initial node positions, (N, 3) m."""
        return np.array([n.position for n in self.nodes], dtype=float).reshape(-1, 3)

    @property
    def velocities(self) -> np.ndarray:
        """Initial node velocities, (N, 3) m/s."""
        return np.array([n.velocity for n in self.nodes], dtype=float).reshape(-1, 3)

    @property
    def fixed(self) -> np.ndarray:
        """(N,) bool: supports."""
        return np.array([n.fixed for n in self.nodes], dtype=bool)

    @property
    def masses(self) -> np.ndarray:
        """Lumped node masses, (N,) kg: each node's own mass plus its share of every strut touching it (the
        row sums of the strut's :attr:`Strut.mass_block`: half of a uniform strut's mass, a payload's by the
        lever rule). They carry the weight, the linear momentum and the total mass exactly; the rotational
        inertia of a rigid strut is its block's (``System.mass``)."""
        index = {n.name: i for i, n in enumerate(self.nodes)}
        m = np.array([n.mass for n in self.nodes], dtype=float)
        with np.errstate(over="ignore"):  # a sum beyond the float range is refused by from_dict
            for s in self.struts:
                a, b, c = s.mass_block
                m[index[s.nodes[0]]] += a + b
                m[index[s.nodes[1]]] += b + c
        return m

    @property
    def cable_rest_lengths(self) -> np.ndarray:
        """Initial cable rest lengths, (n_cables,) m."""
        return np.array([c.rest_length for c in self.cables], dtype=float)

    @property
    def cable_masses(self) -> np.ndarray:
        """Cable (plate) masses, (n_cables,) kg (physics §4b; 0: massless)."""
        return np.array([c.mass for c in self.cables], dtype=float)

    @property
    def node_radii(self) -> np.ndarray:
        """(N,) m: a node's own ``radius`` (an end cap) where it gives one, else the largest radius of its
        members (0 for a bare node). A node touches the ground at its position minus this radius."""
        index = {n.name: i for i, n in enumerate(self.nodes)}
        r = np.zeros(len(self.nodes))
        for m in self.struts + self.cables:
            for end in m.nodes:
                if isinstance(end, str):   # a cable attached along a strut gives that strut's nodes no radius
                    r[index[end]] = max(r[index[end]], m.radius)
        own = [(i, n.radius) for i, n in enumerate(self.nodes) if n.radius is not None]
        for i, radius in own:
            r[i] = radius
        return r

    def member_index(self, members: tuple[Strut, ...] | tuple[Cable, ...]) -> np.ndarray:
        """(n, 2) int node indices of the members' ends (a, b): struts, or cables whose ends are all nodes
        (:meth:`cable_points` places every cable end)."""
        index = {n.name: i for i, n in enumerate(self.nodes)}
        return np.array([[index[m.nodes[0]], index[m.nodes[1]]] for m in members], dtype=np.intp).reshape(-1, 2)

    def cable_points(self) -> tuple[np.ndarray, np.ndarray]:
        """Where each cable end lies: nodes (n_cables, 2, 2) int and weights (n_cables, 2), end ``j`` of
        cable ``c`` at ``(1 - w) x[nodes[c, j, 0]] + w x[nodes[c, j, 1]]`` with ``w = weights[c, j]``. A node
        end is ``(node, node)`` with ``w = 0``; an end ``{strut, at}`` is the strut's ``(a, b)`` with
        ``w = at``, except at ``at = 0`` or ``1``, which is the node itself (``w = 0``), so that a scene that
        names a strut's end either way steps the same numbers."""
        index = {n.name: i for i, n in enumerate(self.nodes)}
        struts = {s.name: s for s in self.struts}
        nodes = np.zeros((len(self.cables), 2, 2), dtype=np.intp)
        weights = np.zeros((len(self.cables), 2))
        for c, cable in enumerate(self.cables):
            for j, end in enumerate(cable.nodes):
                if isinstance(end, str):
                    nodes[c, j] = index[end]
                    continue
                a, b = (index[name] for name in struts[end.strut].nodes)
                if end.at == 0.0 or end.at == 1.0:
                    nodes[c, j] = a if end.at == 0.0 else b
                else:
                    nodes[c, j] = a, b
                    weights[c, j] = end.at
        return nodes, weights

    # ----------------------------------------------------------------- (de)serialisation
    @classmethod
    def from_dict(cls, mapping: Mapping[str, Any], *, source: str = "") -> "Scene":
        """Validate a mapping in the YAML schema of the contract and build the scene.

        ``source`` names the origin (a file name) in error messages.
        """
        ctx = _Context(source)
        _check_keys(ctx, "", mapping, _TOP_KEYS, {"nodes"})
        name = mapping.get("name", "scene")
        if not isinstance(name, str):
            raise ctx.error("name", f"must be a string, got {describe(name)}")
        gravity = _vector3(ctx, "scene", "gravity", mapping.get("gravity", [0.0, 0.0, 0.0]))

        nodes = cls._parse_nodes(ctx, mapping.get("nodes"))
        node_names = {n.name: n for n in nodes}
        member_names: set[str] = set(node_names)
        struts = cls._parse_members(ctx, "struts", mapping.get("struts", []), nodes, member_names)
        cables = cls._parse_members(ctx, "cables", mapping.get("cables", []), nodes, member_names, struts)

        kinds, response = cls._parse_contact(ctx, mapping.get("contact", {}))
        ground = cls._parse_ground(ctx, mapping["ground"]) if "ground" in mapping else None

        scene = cls(name=name, gravity=gravity, nodes=tuple(nodes), struts=tuple(struts),
                    cables=tuple(cables), contact_kinds=kinds, ground=ground, contact_response=response,
                    source=source)
        scene._check_masses(ctx)
        scene._warn_class_k()
        return scene

    @staticmethod
    def _parse_contact(ctx: _Context, raw: Any) -> tuple[tuple[str, ...], ContactResponse]:
        _check_keys(ctx, "contact", raw, _CONTACT_KEYS, set())
        try:
            kinds = contact_kinds(raw.get("kinds", list(DEFAULT_CONTACT_KINDS)), "kinds")
        except ValueError as exc:
            raise ctx.error("contact", str(exc)) from None
        response = _bool(ctx, "contact", "response", raw.get("response", False))
        friction = _non_negative(ctx, "contact", "friction", raw.get("friction", 0.0))
        restitution = _fraction(ctx, "contact", "restitution", raw.get("restitution", 0.0))
        if response and not kinds:
            raise ctx.error("contact", "response: true needs member kinds to check (kinds is empty)")
        return kinds, ContactResponse(response, friction, restitution)

    @staticmethod
    def _parse_ground(ctx: _Context, raw: Any) -> Ground:
        _check_keys(ctx, "ground", raw, _GROUND_KEYS, set())
        return Ground(_number(ctx, "ground", "height", raw.get("height", 0.0)),
                      _non_negative(ctx, "ground", "friction", raw.get("friction", 0.0)),
                      _fraction(ctx, "ground", "restitution", raw.get("restitution", 0.0)))

    @staticmethod
    def _parse_nodes(ctx: _Context, raw_nodes: Any) -> list[Node]:
        if not isinstance(raw_nodes, list) or not raw_nodes:
            raise ctx.error("nodes", "must be a non-empty list")
        seen: set[str] = set()
        nodes = []
        for i, raw in enumerate(raw_nodes):
            where = _entry_label("nodes", i, raw)
            _check_keys(ctx, where, raw, _NODE_KEYS, {"name", "position"})
            name = _name(ctx, where, raw["name"], seen)
            fixed = _bool(ctx, where, "fixed", raw.get("fixed", False))
            position = _vector3(ctx, where, "position", raw["position"])
            velocity = _vector3(ctx, where, "velocity", raw.get("velocity", [0.0, 0.0, 0.0]))
            if "mass" in raw:
                mass = _non_negative(ctx, where, "mass", raw["mass"])
            else:
                mass = 0.0
            if fixed and any(velocity):
                raise ctx.error(where, f"velocity of a fixed node must be zero, got {list(velocity)!r}")
            radius = _non_negative(ctx, where, "radius", raw["radius"]) if "radius" in raw else None
            nodes.append(Node(name, position, mass, velocity, fixed, radius))
        return nodes

    @staticmethod
    def _parse_members(ctx: _Context, kind: str, raw_members: Any, nodes: list[Node],
                       seen: set[str], struts: list[Strut] = ()) -> list:
        if raw_members is None:
            raw_members = []
        if not isinstance(raw_members, list):
            raise ctx.error(kind, f"must be a list, got {type(raw_members).__name__}")
        by_name = {n.name: n for n in nodes}
        struts = {s.name: s for s in struts}
        keys = _STRUT_KEYS if kind == "struts" else _CABLE_KEYS
        required = {"name", "nodes", "stiffness"} if kind == "struts" else {"name", "nodes"}
        out = []
        for i, raw in enumerate(raw_members):
            where = _entry_label(kind, i, raw)
            _check_keys(ctx, where, raw, keys, required)
            name = _name(ctx, where, raw["name"], seen)
            ends = raw["nodes"]
            if kind == "cables":
                ends = Scene._parse_cable_ends(ctx, where, ends, by_name, struts)
                points = [Scene._end_position(e, by_name, struts) for e in ends]
                labels = [describe(e) if isinstance(e, str) else f"{e.strut!r} at {e.at!r}" for e in ends]
            else:
                if not isinstance(ends, (list, tuple)) or len(ends) != 2 or not all(isinstance(e, str) for e in ends):
                    raise ctx.error(where, f"nodes must be a list of two node names, got {describe(ends)}")
                for e in ends:
                    if e not in by_name:
                        raise ctx.error(where, f"nodes: unknown node {describe(e)}")
                if ends[0] == ends[1]:
                    raise ctx.error(where, f"nodes: a member cannot join node {ends[0]!r} to itself")
                points = [np.array(by_name[e].position) for e in ends]
                labels = [repr(e) for e in ends]
            pa, pb = points
            with np.errstate(over="ignore"):  # an overflowing distance is refused below
                length = float(np.linalg.norm(pb - pa))
            if length == 0.0:
                raise ctx.error(where, f"nodes: zero-length member ({labels[0]} and {labels[1]} coincide)")
            if not math.isfinite(length):  # the ends' coordinates are finite, their distance overflows
                raise ctx.error(where, f"nodes: the distance from {labels[0]} to {labels[1]} overflows the float "
                                       f"range (ends at {pa.tolist()} and {pb.tolist()} m)")
            stiffness_raw = raw.get("stiffness")
            if kind == "struts" and isinstance(stiffness_raw, str) and stiffness_raw == RIGID:
                stiffness: float | None = math.inf
            elif kind == "cables" and stiffness_raw is None:
                stiffness = None
            else:
                stiffness = _positive(ctx, where, "stiffness", stiffness_raw)
            rest = _positive(ctx, where, "rest_length", raw["rest_length"]) if "rest_length" in raw else length
            radius = _non_negative(ctx, where, "radius", raw.get("radius", 0.0))
            if kind == "struts":
                mass = _non_negative(ctx, where, "mass", raw.get("mass", 0.0))
                distribution = raw.get("mass_distribution", "uniform")
                if distribution not in MASS_DISTRIBUTIONS:
                    raise ctx.error(where, f"mass_distribution must be one of {', '.join(MASS_DISTRIBUTIONS)}, "
                                           f"got {describe(distribution)}")
                payloads = Scene._parse_payloads(ctx, where, raw.get("payloads", []))
                if stiffness == math.inf:
                    if "rest_length" in raw and abs(rest - length) > 1e-9 * length:
                        raise ctx.error(where, f"rest_length of a rigid strut must equal its length {length!r}, "
                                               f"got {rest!r}")
                    rest = length
                out.append(Strut(name, (ends[0], ends[1]), stiffness, rest, mass, radius, distribution, payloads))
            else:
                damping = _non_negative(ctx, where, "damping", raw.get("damping", 0.0))
                mass = _non_negative(ctx, where, "mass", raw.get("mass", 0.0))
                out.append(Cable(name, tuple(ends), stiffness, rest, damping, radius, mass))
        return out

    @staticmethod
    def _parse_cable_ends(ctx: _Context, where: str, raw: Any, by_name: Mapping[str, Node],
                          struts: Mapping[str, Strut]) -> tuple:
        """A cable's two ends: node names or :class:`Attachment` points ``{strut: NAME, at: 0..1}``."""
        if not isinstance(raw, (list, tuple)) or len(raw) != 2:
            raise ctx.error(where, f"nodes must be a list of two ends (a node name or {{strut, at}}), "
                                   f"got {describe(raw)}")
        ends = []
        for j, e in enumerate(raw):
            if isinstance(e, str):
                if e not in by_name:
                    raise ctx.error(where, f"nodes: unknown node {describe(e)}")
                ends.append(e)
                continue
            label = f"{where} nodes[{j}]"
            if not isinstance(e, Mapping):
                raise ctx.error(where, f"nodes: an end is a node name or {{strut, at}}, got {describe(e)}")
            _check_keys(ctx, label, e, _ATTACHMENT_KEYS, _ATTACHMENT_KEYS)
            if not isinstance(e["strut"], str) or e["strut"] not in struts:
                raise ctx.error(label, f"strut: unknown strut {describe(e['strut'])}")
            ends.append(Attachment(e["strut"], _fraction(ctx, label, "at", e["at"])))
        for j, e in enumerate(ends):
            other = ends[1 - j]
            if isinstance(e, Attachment) and (other in struts[e.strut].nodes
                                              or isinstance(other, Attachment) and other.strut == e.strut):
                raise ctx.error(where, f"nodes: a cable cannot join strut {e.strut!r} to itself (both ends on it)")
        if ends[0] == ends[1]:
            raise ctx.error(where, f"nodes: a member cannot join node {ends[0]!r} to itself")
        return tuple(ends)

    @staticmethod
    def _end_position(end: str | Attachment, by_name: Mapping[str, Node], struts: Mapping[str, Strut]) -> np.ndarray:
        """Where a cable end is in the scene's initial positions, (3,) m."""
        if isinstance(end, str):
            return np.array(by_name[end].position)
        a, b = (np.array(by_name[n].position) for n in struts[end.strut].nodes)
        return (1.0 - end.at) * a + end.at * b

    @staticmethod
    def _parse_payloads(ctx: _Context, where: str, raw: Any) -> tuple[tuple[float, float], ...]:
        if not isinstance(raw, list):
            raise ctx.error(where, f"payloads must be a list of {{at, mass}} mappings, got {describe(raw)}")
        out = []
        for j, item in enumerate(raw):
            label = f"{where} payloads[{j}]"
            _check_keys(ctx, label, item, _PAYLOAD_KEYS, _PAYLOAD_KEYS)
            out.append((_fraction(ctx, label, "at", item["at"]), _non_negative(ctx, label, "mass", item["mass"])))
        return tuple(out)

    def _check_masses(self, ctx: _Context) -> None:
        masses = self.masses
        for i, n in enumerate(self.nodes):
            if not n.fixed and masses[i] <= 0.0:
                raise ctx.error(_entry_label("nodes", i, {"name": n.name}),
                                f"mass must be > 0 for a free node, got {float(masses[i])!r}")
            if not math.isfinite(masses[i]):
                raise ctx.error(_entry_label("nodes", i, {"name": n.name}),
                                "its mass plus its share of its struts' masses overflows the float range")

    def _warn_class_k(self) -> None:
        counts: dict[str, int] = {}
        for s in self.struts:
            for end in s.nodes:
                counts[end] = counts.get(end, 0) + 1
        crowded = sorted(n for n, c in counts.items() if c > 1)
        if crowded:
            where = f"{self.source}: " if self.source else ""
            warnings.warn(f"{where}nodes {crowded} carry more than one strut: a class-k structure",
                          ClassKWarning, stacklevel=4)

    def to_dict(self) -> dict[str, Any]:
        """The scene as a mapping in the YAML schema; ``Scene.from_dict(s.to_dict()) == s``."""
        def node(n: Node) -> dict[str, Any]:
            d: dict[str, Any] = {"name": n.name, "position": list(n.position)}
            if not n.fixed or n.mass > 0:
                d["mass"] = n.mass
            d["velocity"] = list(n.velocity)
            d["fixed"] = n.fixed
            if n.radius is not None:
                d["radius"] = n.radius
            return d

        def strut(s: Strut) -> dict[str, Any]:
            d: dict[str, Any] = {"name": s.name, "nodes": list(s.nodes), "stiffness": RIGID if s.rigid else s.stiffness,
                                 "rest_length": s.rest_length, "mass": s.mass, "radius": s.radius,
                                 "mass_distribution": s.mass_distribution}
            if s.payloads:
                d["payloads"] = [{"at": at, "mass": m} for at, m in s.payloads]
            return d

        out = {
            "name": self.name,
            "gravity": list(self.gravity),
            "nodes": [node(n) for n in self.nodes],
            "struts": [strut(s) for s in self.struts],
            "cables": [{"name": c.name, "nodes": [e if isinstance(e, str) else {"strut": e.strut, "at": e.at}
                                                  for e in c.nodes],
                        **({"stiffness": c.stiffness} if c.stiffness is not None else {}),
                        "rest_length": c.rest_length, "damping": c.damping, "radius": c.radius,
                        **({"mass": c.mass} if c.mass > 0 else {})}   # massless: written as before
                       for c in self.cables],
        }
        contact: dict[str, Any] = {}
        if self.contact_kinds != DEFAULT_CONTACT_KINDS:  # scenes that keep the default stay as they were
            contact["kinds"] = list(self.contact_kinds)
        if self.contact_response != ContactResponse():
            contact.update(response=self.contact_response.response, friction=self.contact_response.friction,
                           restitution=self.contact_response.restitution)
        if contact:
            out["contact"] = contact
        if self.ground is not None:
            out["ground"] = {"height": self.ground.height, "friction": self.ground.friction,
                             "restitution": self.ground.restitution}
        return out

    def to_yaml(self) -> str:
        return yaml.safe_dump(self.to_dict(), sort_keys=False)

    def to_mjcf(self, **options) -> str:
        """The scene as a MuJoCo model (MJCF text), so that one robot runs in both engines:
        :func:`tensegrity_sim.io.mjcf.scene_to_mjcf` (its keyword options and mapping); the mapping back
        is :func:`tensegrity_sim.load_mjcf`. Needs no MuJoCo to write."""
        from .io.mjcf import scene_to_mjcf   # io sits around the core: imported only here
        return scene_to_mjcf(self, **options)


# --------------------------------------------------------------------------- loading
_SCENE_PACKAGE = "tensegrity_sim.scenes"


def builtin_scenes() -> tuple[str, ...]:
    """Names of the scenes shipped with the package (YAML files in ``tensegrity_sim/scenes``)."""
    return tuple(sorted(p.name[:-5] for p in resources.files(_SCENE_PACKAGE).iterdir()
                        if p.name.endswith(".yaml")))


def load_scene(name_or_path: str | Path) -> Scene:
    """Load a built-in scene by name (see :func:`builtin_scenes`) or a YAML file by path."""
    text: str | None
    source: str
    if not isinstance(name_or_path, (str, Path)):
        raise SceneError(f"a scene is a built-in name or a path, got {describe(name_or_path)}")
    name = str(name_or_path)
    if name in builtin_scenes():
        source = f"{name}.yaml"
        text = resources.files(_SCENE_PACKAGE).joinpath(source).read_text()
    else:
        path = Path(name_or_path)
        if not path.is_file():
            raise SceneError(f"{name}: no such scene file, and not a built-in scene "
                             f"(built-ins: {', '.join(builtin_scenes())})")
        source = str(path)
        text = None
    return Scene.from_dict(read_yaml(source, SceneError, text), source=source)
