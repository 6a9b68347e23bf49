"""NTRT's YAML structures (the NASA Tensegrity Robotics Toolkit's ``yamlbuilder``), read into a scene.

The format: ``nodes`` (name: [x, y, z]), ``pair_groups`` (space-separated tags: a list of node pairs),
``builders`` (a tag: ``class`` and ``parameters``), ``substructures`` (child names, ``a/b/c`` for several:
``path`` of another structure file, ``rotation`` {axis, angle in degrees, reference}, ``scale``, ``offset``
(times the child's index among ``a/b/c``), ``translation``) and ``bond_groups`` (``child1/child2/node_node``
with tags: pairs between two children's nodes). A pair is built by the builder whose tag it carries (the
defaults: ``rod`` a tgRodInfo, ``string`` a tgBasicActuatorInfo, with NTRT's default parameters).

Mapping (:func:`import_ntrt`):

* **Units.** NTRT's world is y-up and its models are usually in decimetres (its apps run them with gravity
  98.1 length units/s²; SUPERball's rods are 16.84 long). ``length_scale`` (m per file unit) defaults to
  0.1 for that reason; pass 1.0 for a model written in metres. Positions are rotated y-up to z-up
  (``(x, y, z) -> (x, -z, y)``) and scaled. Stiffness and damping (force per length, per speed: kg/s², kg/s)
  are the same in any length unit; a pretension (kg·unit/s²) is scaled to N, a density (kg/unit³) gives the
  rod's mass in kg from the file's own lengths.
* **tgRodInfo** -> a rigid strut: mass ``density·π·radius²·length`` spread uniformly, its radius scaled
  (a cylinder's own thickness inertia ``m r²/4`` about axes normal to it is dropped: a slender rod), the
  end nodes massless. ``friction`` becomes the ground's (the largest of the rods'); ``roll_friction`` and
  ``restitution`` are Bullet's and are noted, not mapped.
* **tgBasicActuatorInfo**, **tgKinematicActuatorInfo** and their contact-cable relatives -> an elastic
  cable: stiffness, damping (acting while taut), rest length ``length - pretension/stiffness`` (NTRT's
  tgBasicActuator starts at that rest length). Every NTRT string is motor-driven: command its rest length.
  The motor's own parameters (``max_tension``, ``target_velocity``, motor inertia, ...) are noted, not
  mapped; a string's anchor is its node (NTRT may move it to the rod's surface: ``moveCablePoint*ToEdge``).
* A string node that is no rod's end but lies on a rod is attached to that rod's nearer end node, with a
  warning naming it, its place along the rod and the distance dropped (a scene's cables end at nodes).
* A ground ``z = 0`` under the lowest rod end (its centre minus the rod's radius), gravity 9.81 m/s² down.

Refused (``SceneError`` naming the file and the element): a malformed file, an unknown key, builder class
or parameter (as NTRT refuses them), a node on no rod, an unknown node, ``node_edge`` bonds and boxes
(tgBoxInfo), a rest length <= 0, a substructure that includes itself.
"""
from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np

from ..checks import describe, read_yaml, real
from ..scene import Scene, SceneError
from ._common import Imported, MappingWarning, scene_name

__all__ = ["import_ntrt", "load_ntrt", "DEFAULT_LENGTH_SCALE"]

DEFAULT_LENGTH_SCALE = 0.1   # m per file unit: NTRT's models are usually in decimetres
_ROOT_KEYS = ("nodes", "pair_groups", "builders", "substructures", "bond_groups")
_CHILD_KEYS = ("path", "rotation", "translation", "scale", "offset")
_ROD = {"radius": 0.5, "density": 1.0, "friction": 1.0, "roll_friction": 0.0, "restitution": 0.2}
_BASIC = {"stiffness": 1000.0, "damping": 10.0, "pretension": 0.0, "history": 0.0, "max_tension": 1000.0,
          "target_velocity": 100.0, "min_actual_length": 0.1, "min_rest_length": 0.1, "rotation": 0.0,
          "moveCablePointAToEdge": True, "moveCablePointBToEdge": True}
_KINEMATIC = {**_BASIC, "radius": 1.0, "motor_friction": 0.0, "motor_inertia": 1.0, "back_drivable": 0.0}
# NTRT's builder classes and their parameters with NTRT's defaults (yamlbuilder/TensegrityModel.h)
_CLASSES = {"tgRodInfo": _ROD, "tgBasicActuatorInfo": _BASIC, "tgBasicContactCableInfo": _BASIC,
            "tgKinematicActuatorInfo": _KINEMATIC, "tgKinematicContactCableInfo": _KINEMATIC}
_CABLE_MAPPED = ("stiffness", "damping", "pretension")


def load_ntrt(path, length_scale: float | None = None) -> Scene:
    """The scene of an NTRT YAML structure: :func:`import_ntrt`'s, without its notes."""
    return import_ntrt(path, length_scale).scene


class _Structure:
    """One structure file's nodes (global ids by name) and its children, in NTRT's order."""

    def __init__(self, name: str):
        self.name = name
        self.nodes: dict[str, int] = {}
        self.children: list[_Structure] = []

    def subtree(self) -> list[int]:
        """Every node id of this structure and its children's."""
        return list(self.nodes.values()) + [i for c in self.children for i in c.subtree()]

    def find(self, ref: str) -> int | None:
        """A node by NTRT's path: ``child.node`` (dotted), else the first by name, breadth first."""
        if "." in ref:
            child, rest = ref.split(".", 1)
            found = next((c for c in self.children if c.name == child), None)
            return None if found is None else found.find(rest)
        queue = [self]
        while queue:
            s = queue.pop(0)
            if ref in s.nodes:
                return s.nodes[ref]
            queue += s.children
        return None


class _Reader:
    def __init__(self, length_scale: float):
        self.scale = length_scale
        self.positions: list[np.ndarray] = []      # file units, NTRT's axes
        self.node_names: list[str] = []
        self.pairs: list[tuple[str, int, int, str]] = []   # (tags, node, node, where)
        self.builders = {"rod": ("tgRodInfo", dict(_ROD)), "string": ("tgBasicActuatorInfo", dict(_BASIC))}
        self.notes: list[str] = []
        self.stack: list[tuple[Path, str]] = []   # the files being read: (resolved, as named)

    def structure(self, path: Path, name: str, prefix: str) -> _Structure:
        label = str(path)
        if path.resolve() in [resolved for resolved, _ in self.stack]:
            raise SceneError(f"{label}: includes itself (through {' -> '.join(name for _, name in self.stack)})")
        root = read_yaml(label, SceneError)
        if root is None:
            root = {}
        if not isinstance(root, dict):
            raise SceneError(f"{label}: must be a mapping of {', '.join(_ROOT_KEYS)}, got {describe(root)}")
        _only(label, "", root, _ROOT_KEYS)
        self.stack.append((path.resolve(), label))
        s = _Structure(name)
        self._children(label, path, s, prefix, _mapping(label, "substructures", root.get("substructures")))
        self._builders(label, _mapping(label, "builders", root.get("builders")))
        for node, xyz in _mapping(label, "nodes", root.get("nodes")).items():
            if not isinstance(xyz, list) or len(xyz) != 3:
                raise SceneError(f"{label}: nodes: {node!r} must be a list of 3 numbers, got {describe(xyz)}")
            s.nodes[str(node)] = len(self.positions)
            self.positions.append(np.array([_real(label, f"nodes: {node!r}", v) for v in xyz]))
            self.node_names.append(prefix + str(node))
        for tags, pairs in _mapping(label, "pair_groups", root.get("pair_groups")).items():
            self._pairs(label, f"pair_groups: {tags!r}", str(tags), pairs, s, s)
        self._bonds(label, s, _mapping(label, "bond_groups", root.get("bond_groups")))
        self.stack.pop()
        return s

    def _children(self, label: str, path: Path, s: _Structure, prefix: str, children: dict) -> None:
        placed = []
        for key, attrs in children.items():
            where = f"substructures: {key!r}"
            attrs = _mapping(label, where, attrs)
            _only(label, where, attrs, _CHILD_KEYS)
            if "path" not in attrs:
                raise SceneError(f"{label}: {where}: missing required key 'path'")
            child_path = path.parent / str(attrs["path"])
            if not child_path.is_file():
                raise SceneError(f"{label}: {where}: path {str(attrs['path'])!r}: no such file ({child_path})")
            for index, name in enumerate(str(key).split("/")):
                child = self.structure(child_path, name, f"{prefix}{name}_")
                s.children.append(child)
                placed.append((child, index, attrs, where))
        # NTRT's order: every child's rotation first, then each child's scale, offset and translation
        for child, _, attrs, where in placed:
            if "rotation" in attrs:
                self._rotate(label, where, child, _mapping(label, f"{where}: rotation", attrs["rotation"]))
        for child, index, attrs, where in placed:
            ids = child.subtree()
            x = np.array([self.positions[i] for i in ids]).reshape(-1, 3)
            if "scale" in attrs:
                centre = x.mean(axis=0)
                x = centre + _real(label, f"{where}: scale", attrs["scale"]) * (x - centre)
            if "offset" in attrs:
                x = x + index * _vector(label, f"{where}: offset", attrs["offset"])
            if "translation" in attrs:
                x = x + _vector(label, f"{where}: translation", attrs["translation"])
            for i, p in zip(ids, x):
                self.positions[i] = p

    def _rotate(self, label: str, where: str, child: _Structure, rotation: dict) -> None:
        _only(label, f"{where}: rotation", rotation, ("axis", "angle", "reference"))
        if "axis" not in rotation or "angle" not in rotation:   # NTRT ignores a rotation without both
            return
        axis = _vector(label, f"{where}: rotation: axis", rotation["axis"])
        if not np.any(axis):
            raise SceneError(f"{label}: {where}: rotation: axis must not be zero")
        axis = axis / np.linalg.norm(axis)
        angle = math.radians(_real(label, f"{where}: rotation: angle", rotation["angle"]))
        ids = child.subtree()
        x = np.array([self.positions[i] for i in ids]).reshape(-1, 3)
        centre = (_vector(label, f"{where}: rotation: reference", rotation["reference"])
                  if "reference" in rotation else x.mean(axis=0))
        cross = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
        turn = np.eye(3) + math.sin(angle) * cross + (1 - math.cos(angle)) * cross @ cross   # Rodrigues
        for i, p in zip(ids, centre + (x - centre) @ turn.T):
            self.positions[i] = p

    def _builders(self, label: str, builders: dict) -> None:
        for tag, spec in builders.items():
            where = f"builders: {tag!r}"
            spec = _mapping(label, where, spec)
            _only(label, where, spec, ("class", "parameters"))
            cls = spec.get("class")
            if cls == "tgBoxInfo":
                raise SceneError(f"{label}: {where}: class tgBoxInfo: boxes are not mapped (a scene has rods)")
            if cls not in _CLASSES:
                raise SceneError(f"{label}: {where}: class {describe(cls)} is not an NTRT builder class "
                                 f"({', '.join(_CLASSES)})")
            params = dict(_CLASSES[cls])
            for key, value in _mapping(label, f"{where}: parameters", spec.get("parameters")).items():
                if key not in params:
                    raise SceneError(f"{label}: {where}: unknown {cls} parameter {describe(key)} "
                                     f"(allowed: {', '.join(params)})")
                params[key] = value if isinstance(params[key], bool) else _real(label, f"{where}: {key}", value)
            self.builders[str(tag)] = (cls, params)

    def _pairs(self, label: str, where: str, tags: str, pairs, first: _Structure, second: _Structure) -> None:
        if not isinstance(pairs, list):
            raise SceneError(f"{label}: {where}: must be a list of node pairs, got {describe(pairs)}")
        for pair in pairs:
            if not isinstance(pair, list) or len(pair) != 2:
                raise SceneError(f"{label}: {where}: a pair must be a list of two node names, got {describe(pair)}")
            ends = []
            for ref, s in zip(pair, (first, second)):
                node = s.find(str(ref))
                if node is None:
                    raise SceneError(f"{label}: {where}: unknown node {describe(ref)}")
                ends.append(node)
            if ends[0] == ends[1]:
                raise SceneError(f"{label}: {where}: pair joins node {str(pair[0])!r} to itself")
            self.pairs.append((tags, ends[0], ends[1], f"{label}: {where}"))

    def _bonds(self, label: str, s: _Structure, groups: dict) -> None:
        for first, content in groups.items():
            for second, pairs in _mapping(label, f"bond_groups: {first!r}", content).items():
                bond, tags = (str(first), str(second)) if "/" in str(first) else (str(second), str(first))
                where = f"bond_groups: {first!r}: {second!r}"
                kind, names = bond.rsplit("/", 1)[1], bond.rsplit("/", 1)[0].split("/")
                if kind != "node_node":
                    raise SceneError(f"{label}: {where}: {kind} bonds are not mapped (only node_node)")
                children = [next((c for c in s.children if c.name == n), None) for n in names]
                if len(names) < 2 or None in children:
                    raise SceneError(f"{label}: {where}: a bond names two or more of this structure's children")
                for a, b in zip(children, children[1:]):
                    self._pairs(label, where, f"{tags} {a.name} {b.name} {a.name}/{b.name}", pairs, a, b)


def _only(label: str, where: str, mapping: dict, allowed) -> None:
    unknown = [k for k in mapping if k not in allowed]
    if unknown:
        raise SceneError(f"{label}: {where + ': ' if where else ''}unknown key {describe(unknown[0])} "
                         f"(allowed: {', '.join(allowed)})")


def _mapping(label: str, where: str, value) -> dict:
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise SceneError(f"{label}: {where}: must be a mapping, got {describe(value)}")
    return value


def _real(label: str, where: str, value) -> float:
    try:
        return real(value, where)
    except ValueError as exc:
        raise SceneError(f"{label}: {exc}") from None


def _vector(label: str, where: str, value) -> np.ndarray:
    if not isinstance(value, list) or len(value) != 3:
        raise SceneError(f"{label}: {where} must be a list of 3 numbers, got {describe(value)}")
    return np.array([_real(label, where, v) for v in value])


def import_ntrt(path, length_scale: float | None = None) -> Imported:
    """A scene from an NTRT YAML structure file (and the files its substructures name), as the module
    says; ``length_scale``: metres per file unit (default :data:`DEFAULT_LENGTH_SCALE`, NTRT's decimetres)."""
    if not isinstance(path, (str, Path)):
        raise SceneError(f"an NTRT structure is a path, got {describe(path)}")
    path = Path(path)
    label = str(path)
    if length_scale is None:
        length_scale = DEFAULT_LENGTH_SCALE
        scale_note = f"length scale {length_scale} m per unit (NTRT's decimetres; --length-scale to change)"
    else:
        length_scale = _real(label, "length_scale", length_scale)
        if length_scale <= 0:
            raise SceneError(f"{label}: length_scale must be > 0, got {length_scale!r}")
        scale_note = f"length scale {length_scale} m per unit (given)"
    if not path.is_file():
        raise SceneError(f"{label}: no such file")
    r = _Reader(length_scale)
    r.structure(path, path.stem, "")
    r.notes.append(scale_note)
    up = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])   # NTRT's y-up to z-up
    x = np.array(r.positions).reshape(-1, 3) @ up.T * length_scale
    taken: set[str] = set()
    rods, strings, friction = [], [], []
    for tags, a, b, where in r.pairs:
        matches = [t for t in tags.split() if t in r.builders]
        if not matches:
            warnings.warn(f"{where}: pair ({r.node_names[a]}, {r.node_names[b]}) with tags {tags!r} matches no "
                          f"builder: dropped (as NTRT builds nothing for it)", MappingWarning, stacklevel=2)
            continue
        cls, params = r.builders[matches[-1]]
        (rods if cls == "tgRodInfo" else strings).append((matches[-1], a, b, cls, params, where))
    node_name = {}
    nodes, struts, cables = [], [], []

    def node(i: int) -> str:
        if i not in node_name:
            node_name[i] = scene_name(r.node_names[i], taken)
            nodes.append({"name": node_name[i], "position": [float(v) for v in x[i]], "mass": 0.0})
        return node_name[i]

    for tag, a, b, cls, p, where in rods:
        length_file = float(np.linalg.norm(r.positions[b] - r.positions[a]))
        mass = p["density"] * math.pi * p["radius"] ** 2 * length_file
        name = scene_name(f"{tag}{len(struts)}", taken)
        struts.append({"name": name, "nodes": [node(a), node(b)], "stiffness": "rigid", "mass": mass,
                       "radius": p["radius"] * length_scale})
        friction.append(p["friction"])
        r.notes.append(f"{where}: rod {name!r} ({r.node_names[a]}, {r.node_names[b]}): {mass:.6g} kg uniform "
                       f"(density {p['density']:g} x pi x {p['radius']:g}^2 x {length_file:.6g}), radius "
                       f"{p['radius'] * length_scale:.6g} m; roll_friction {p['roll_friction']:g} and restitution "
                       f"{p['restitution']:g} not mapped")
    rod_ends = {i for s in rods for i in s[1:3]}
    for tag, a, b, cls, p, where in strings:
        ends = [node(i) if i in rod_ends else _along(i, x, rods, node, r.node_names, where) for i in (a, b)]
        length = float(np.linalg.norm(x[b] - x[a]))
        rest = length - p["pretension"] * length_scale / p["stiffness"]
        name = scene_name(f"{tag}{len(cables)}", taken)
        if rest <= 0:
            raise SceneError(f"{where}: string {name!r}: pretension {p['pretension']:g} leaves a rest length "
                             f"{rest:.6g} m <= 0 (length {length:.6g} m, stiffness {p['stiffness']:g})")
        cables.append({"name": name, "nodes": ends, "stiffness": p["stiffness"], "damping": p["damping"],
                       "rest_length": rest})
        r.notes.append(f"{where}: {cls} {name!r}: stiffness {p['stiffness']:g} N/m, damping {p['damping']:g} "
                       f"N s/m, rest length {rest:.6g} m (length {length:.6g} m less pretension "
                       f"{p['pretension'] * length_scale:.6g} N / stiffness); motor parameters not mapped")
    if not struts:
        raise SceneError(f"{label}: no rods (pairs built by a tgRodInfo builder): nothing to carry the strings")
    radius = {node_name[i]: max(s[4]["radius"] * length_scale for s in rods if i in s[1:3]) for i in rod_ends}
    floor = min(n["position"][2] - radius[n["name"]] for n in nodes if n["name"] in radius)
    r.notes.append(f"ground at z = {floor:.6g} m (under the lowest rod end), friction {max(friction):g}; "
                   f"gravity 9.81 m/s^2 along -z (NTRT's -y)")
    mapping = {"name": path.stem, "gravity": [0.0, 0.0, -9.81], "nodes": nodes, "struts": struts,
               "cables": cables, "ground": {"height": floor, "friction": max(friction)}}
    return Imported(Scene.from_dict(mapping, source=label), {}, tuple(r.notes))


def _along(i: int, x: np.ndarray, rods: list, node, names: list, where: str) -> str:
    """A string's node that is no rod's end: the nearer end node of the rod it lies on (m positions), warned."""
    for _, a, b, _, _, _ in rods:
        d = x[b] - x[a]
        at = float((x[i] - x[a]) @ d / (d @ d))
        if 0.0 <= at <= 1.0 and np.linalg.norm(x[a] + at * d - x[i]) <= 1e-9 * math.sqrt(d @ d):
            end = a if at <= 0.5 else b
            warnings.warn(f"{where}: node {names[i]!r} lies at {at:.4g} along rod ({names[a]}, {names[b]}): attached "
                          f"to its end node {names[end]!r}, {np.linalg.norm(x[i] - x[end]):.3g} m away",
                          MappingWarning, stacklevel=3)
            return node(end)
    raise SceneError(f"{where}: node {names[i]!r} lies on no rod (NTRT anchors a string on a rigid body)")
