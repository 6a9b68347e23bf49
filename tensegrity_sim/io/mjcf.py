"""MuJoCo's MJCF, both ways: :func:`scene_to_mjcf` writes a scene as a model, :func:`import_mjcf` reads one.

**Export** (:func:`scene_to_mjcf`; also ``Scene.to_mjcf()``). One MJCF body per rigid strut or per free
point mass, nothing else:

* A **rigid strut** is a body with a free joint, its origin at the strut's centre of mass, carrying the
  strut's mass, payloads and its end nodes' own masses with their exact centre of mass and inertia normal to
  the axis (the consistent mass of physics.md §4c has the same three moments), a site named after each end
  node, and a massless capsule of the strut's radius (a sphere of a node's radius at an end cap). A
  slender rod has no inertia about its axis; MuJoCo needs some, so
  ``axial_inertia`` (relative to the transverse inertia) is added: no cable acts off the axis, so it only
  enters through round-off.
* Any other free node is a body with three slide joints (a point mass), a fixed node a site on the world.
* An **elastic strut** is a spatial tendon with ``springlength = L`` (two-sided); an **elastic cable** one
  with ``springlength = "0 L"``: MuJoCo's dead band, no force for lengths in ``[0, L]`` and ``k (l - L)``
  beyond, i.e. ``k max(0, l - L)``: the rest length is the band's upper bound. Cable damping becomes
  tendon damping, which MuJoCo applies also while the cable is slack.
* An **inextensible cable** is a limited tendon, ``range = "0 L_max"``, ``L_max`` the rest length plus the
  stretch the cable has at load time (as the inextensible method takes it, physics.md §3), with
  ``solreflimit = "2*dt zeta"`` (the stiffest MuJoCo allows).
* A ``ground`` is a plane with its friction; struts' capsules, end caps and point masses touch it (not
  each other), elliptic friction cones, ``impratio``. Without a ground contacts are off, unless
  ``strut_contacts``: then the struts' capsules collide with each other (frictionless).

Names: bodies after their strut (or point node), sites after their node, tendons after their member;
every sensor reads a cable (its length, or its limit force). Gravity from the scene; no actuators (drive a
cable in MuJoCo through ``model.tendon_lengthspring``).

**Import** (:func:`import_mjcf`): MuJoCo's own parser reads the file (defaults, includes, ``fromto``
resolved), then the compiled model is mapped; the mapping rules are :func:`import_mjcf`'s docstring.
"""
from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np

from ..scene import Scene, SceneError, Strut
from ._common import Imported, MappingWarning, scene_name

__all__ = ["scene_to_mjcf", "import_mjcf", "load_mjcf", "INTEGRATORS"]

INTEGRATORS = ("Euler", "implicitfast", "RK4")


def _fmt(values) -> str:
    return " ".join(repr(float(v)) for v in np.ravel(values))


def _unique(name: str, taken: set[str]) -> str:
    while name in taken:
        name += "_"
    taken.add(name)
    return name


def rod_moments(strut: Strut, mass_a: float, mass_b: float) -> np.ndarray:
    """The three mass moments ``(∫dm, ∫s dm, ∫s² dm)`` (kg) of ``strut`` along ``s`` in [0, 1] from its first
    node (its :attr:`~tensegrity_sim.scene.Strut.mass_block`), with its end nodes' own masses ``mass_a``,
    ``mass_b``: they fix its mass, centre of mass (``∫s dm / ∫dm``) and inertia normal to the axis about it
    (``L² (∫s² dm - (∫s dm)²/∫dm)``)."""
    a, b, c = strut.mass_block
    return np.array([a + 2.0 * b + c + mass_a + mass_b, b + c + mass_b, c + mass_b])


def scene_to_mjcf(scene: Scene, *, cable_model: str | None = None, dt: float = 1e-3, integrator: str = "RK4",
                  axial_inertia: float = 1e-6, limit_dampratio: float = 1.0, impratio: float = 100.0,
                  strut_contacts: bool = False, visual: bool = True) -> str:
    """The scene as an MJCF model (a string for ``mujoco.MjModel.from_xml_string``), as the module says.

    ``cable_model``: "elastic" (spring tendons) or "inextensible" (limited tendons); default elastic when
    every cable has a stiffness. ``dt``: MuJoCo's step, s; ``integrator``: one of :data:`INTEGRATORS`;
    ``axial_inertia``: a rigid strut's inertia about its axis relative to its transverse inertia;
    ``limit_dampratio``: damping ratio of inextensible cables' soft limits; ``impratio``: MuJoCo's
    frictional-to-normal impedance ratio on the ground; ``strut_contacts``: struts' capsules collide with
    each other (no ground); ``visual``: massless, non-colliding capsules show the struts where nothing else
    does (the benchmarks leave them out). Refused (``ValueError``): a rigid strut with a fixed end, a node
    carrying two rigid struts.
    """
    d = scene.to_dict()
    if cable_model is None:
        cable_model = "elastic" if all(c.stiffness is not None for c in scene.cables) else "inextensible"
    if cable_model not in ("elastic", "inextensible"):
        raise ValueError(f"cable_model must be 'elastic' or 'inextensible', got {cable_model!r}")
    if integrator not in INTEGRATORS:
        raise ValueError(f"integrator must be one of {INTEGRATORS}, got {integrator!r}")
    where = scene.source or scene.name
    nodes = {n["name"]: n for n in d["nodes"]}
    x = {n: np.asarray(v["position"], float) for n, v in nodes.items()}
    own = {n.name: n.mass for n in scene.nodes}
    # a node without a rigid strut is a point mass: its own mass and its elastic struts' shares (row sums)
    point_mass = dict(zip(scene.node_names, (float(m) for m in scene.masses)))
    rigid_of: dict[str, dict] = {}
    for s in d["struts"]:
        if s["stiffness"] == "rigid":
            for n in s["nodes"]:
                if nodes[n].get("fixed", False):
                    raise ValueError(f"{where}: rigid strut {s['name']!r} has a fixed end {n!r} (not modelled in MJCF)")
                if n in rigid_of:
                    raise ValueError(f"{where}: node {n!r} carries two rigid struts (not modelled in MJCF)")
                rigid_of[n] = s
    ground = d.get("ground")
    # what touches the ground: contype 1 against the plane's conaffinity 1, never each other (MuJoCo combines
    # two geoms' friction by the larger: the moving geoms carry the ground's too)
    touch = (f' contype="1" conaffinity="0" condim="3" friction="{ground["friction"]!r} 0 0"'
             if ground is not None else "")
    capsule = touch
    if strut_contacts:   # bit 2: the struts' capsules also collide with each other, frictionless without a ground
        friction = ground["friction"] if ground is not None else 0.0
        capsule = (f' contype="{3 if ground is not None else 2}" conaffinity="2" '
                   f'condim="{3 if ground is not None else 1}" friction="{friction!r} 0 0"')
    if not capsule and visual:
        capsule = ' contype="0" conaffinity="0"'
    radius = dict(zip(scene.node_names, (float(r) for r in scene.node_radii)))   # where a node touches the ground
    world, bodies = [], []
    if ground is not None:
        world.append(f'<geom name="ground" type="plane" size="0 0 1" pos="0 0 {ground["height"]!r}" contype="0" '
                     f'conaffinity="1" friction="{ground["friction"]!r} 0 0" condim="3"/>')
    for n, v in nodes.items():
        if v.get("fixed", False):
            world.append(f'<site name="{n}" pos="{_fmt(x[n])}"/>')
    for n, v in nodes.items():
        if v.get("fixed", False) or n in rigid_of:
            continue
        bodies.append(
            f'<body name="{n}" pos="{_fmt(x[n])}">'
            + "".join(f'<joint type="slide" axis="{ax}"/>' for ax in ("1 0 0", "0 1 0", "0 0 1"))
            # no rotational freedom: this inertia never enters the dynamics, MuJoCo only needs it > 0
            + f'<inertial pos="0 0 0" mass="{point_mass[n]!r}" diaginertia="1e-9 1e-9 1e-9"/>'
            + (f'<geom type="sphere" size="{max(radius[n], 1e-6)!r}" mass="0"{touch}/>' if touch else "")
            + f'<site name="{n}"/></body>')
    for strut, s in zip(scene.struts, d["struts"]):
        if not strut.rigid:
            continue
        a, b = s["nodes"]
        moments = rod_moments(strut, own[a], own[b])
        length = float(np.linalg.norm(x[b] - x[a]))
        axis = (x[b] - x[a]) / length
        com = x[a] + (moments[1] / moments[0]) * (x[b] - x[a])
        transverse = length ** 2 * (moments[2] - moments[1] ** 2 / moments[0])
        inertia = transverse * (np.eye(3) - np.outer(axis, axis)) + axial_inertia * transverse * np.outer(axis, axis)
        full = [inertia[0, 0], inertia[1, 1], inertia[2, 2], inertia[0, 1], inertia[0, 2], inertia[1, 2]]
        geoms = ""
        if capsule:
            geoms += (f'<geom type="capsule" fromto="{_fmt(np.concatenate([x[a] - com, x[b] - com]))}" '
                      f'size="{max(float(s.get("radius", 0.0)), 1e-6)!r}" mass="0"{capsule}/>')
            # an end cap of the node's own (a smaller one is hidden in the capsule, which touches first)
            geoms += "".join(f'<geom type="sphere" pos="{_fmt(x[n] - com)}" size="{radius[n]!r}" mass="0"{capsule}/>'
                             for n in (a, b) if nodes[n].get("radius") is not None and radius[n] > 0)
        bodies.append(
            f'<body name="{s["name"]}" pos="{_fmt(com)}"><freejoint/>'
            f'<inertial pos="0 0 0" mass="{float(moments[0])!r}" fullinertia="{_fmt(full)}"/>'
            f'<site name="{a}" pos="{_fmt(x[a] - com)}"/><site name="{b}" pos="{_fmt(x[b] - com)}"/>'
            + geoms + "</body>")
    tendons, sensors = [], []
    for s in d["struts"]:
        if s["stiffness"] == "rigid" or all(nodes[n].get("fixed", False) for n in s["nodes"]):
            continue
        tendons.append(f'<spatial name="{s["name"]}" stiffness="{float(s["stiffness"])!r}" '
                       f'springlength="{float(s["rest_length"])!r}"{_width(s["radius"])}><site site="{s["nodes"][0]}"/>'
                       f'<site site="{s["nodes"][1]}"/></spatial>')
    for cable, (a, b) in zip(scene.cables, (c.nodes for c in scene.cables)):
        if cable_model == "elastic":
            if cable.stiffness is None:
                raise ValueError(f"{where}: cable {cable.name!r} has no stiffness (an elastic model needs one)")
            law = f'stiffness="{cable.stiffness!r}" springlength="0 {cable.rest_length!r}"'
            if cable.damping > 0:
                law += f' damping="{cable.damping!r}"'
        else:
            limit = max(cable.rest_length, float(np.linalg.norm(x[b] - x[a])))
            law = f'limited="true" range="0 {limit!r}" solreflimit="{2 * dt!r} {float(limit_dampratio)!r}"'
        tendons.append(f'<spatial name="{cable.name}" {law}{_width(cable.radius)}><site site="{a}"/>'
                       f'<site site="{b}"/></spatial>')
        kind = "tendonpos" if cable_model == "elastic" else "tendonlimitfrc"
        sensors.append(f'<{kind} tendon="{cable.name}"/>')
    option = f'<option timestep="{dt!r}" integrator="{integrator}" gravity="{_fmt(scene.gravity)}"'
    if ground is not None:
        option += f' cone="elliptic" impratio="{impratio!r}"></option>'
    else:
        option += '></option>' if strut_contacts else '><flag contact="disable"/></option>'
    return (f'<mujoco model="{scene.name}"><compiler angle="radian"/>{option}'
            f'<worldbody>{"".join(world)}{"".join(bodies)}</worldbody>'
            f'<tendon>{"".join(tendons)}</tendon><sensor>{"".join(sensors)}</sensor></mujoco>')


def _width(radius: float) -> str:
    """A tendon's width: its member's radius (MuJoCo's default where the member has none)."""
    return f' width="{float(radius)!r}"' if radius > 0 else ""


# ------------------------------------------------------------------------------------------------ import
def _mujoco():
    try:
        import mujoco
    except ImportError:
        raise SceneError("reading MJCF needs MuJoCo's parser: pip install \"tensegrity_sim[io]\"") from None
    return mujoco


def load_mjcf(source) -> Scene:
    """The scene of an MJCF model: :func:`import_mjcf`'s, without its notes (its warnings are still issued)."""
    return import_mjcf(source).scene


# geom types MuJoCo numbers (mjtGeom)
_PLANE, _HFIELD, _SPHERE, _CAPSULE, _ELLIPSOID, _CYLINDER, _BOX, _MESH = 0, 1, 2, 3, 4, 5, 6, 7
_GEOM_KIND = {_PLANE: "plane", _HFIELD: "height field", _SPHERE: "sphere", _CAPSULE: "capsule",
              _ELLIPSOID: "ellipsoid", _CYLINDER: "cylinder", _BOX: "box", _MESH: "mesh"}
_JOINT_KIND = {0: "free", 1: "ball", 2: "slide", 3: "hinge"}
_VOLUME_KINDS = (_SPHERE, _CAPSULE, _ELLIPSOID, _CYLINDER, _BOX)
_TOL = 1e-3     # relative to a rod's length: a point this close to its axis or an end is on it (files round)


def _volume(kind: int, size: np.ndarray) -> float:
    """A primitive geom's volume (m³) from MuJoCo's sizes, as MuJoCo computes a geom's mass from its density."""
    r = size[0]
    return {_SPHERE: 4.0 / 3.0 * math.pi * r ** 3,
            _CAPSULE: math.pi * r * r * 2.0 * size[1] + 4.0 / 3.0 * math.pi * r ** 3,
            _CYLINDER: math.pi * r * r * 2.0 * size[1],
            _ELLIPSOID: 4.0 / 3.0 * math.pi * size[0] * size[1] * size[2],
            _BOX: 8.0 * size[0] * size[1] * size[2]}[kind]


def _fits(moments: np.ndarray, scale: float) -> bool:
    """Whether ``(M0, M1, M2)`` are the mass moments of non-negative masses between the ends (to round-off
    of ``scale`` kg): a mass, a centre in [0, 1], a variance between 0 and that of all the mass at the ends."""
    m0, m1, m2 = moments
    eps = 1e-12 * scale
    return m0 >= -eps and -eps <= m1 <= m0 + eps and m1 * m1 <= m0 * m2 + eps * scale and m2 <= m1 + eps


def _split_moments(moments: np.ndarray) -> tuple[float, float, float, float]:
    """Non-negative masses ``(node a, node b, strut uniform, payload at the centre of mass)`` (kg) with the
    three mass moments ``(M0, M1, M2)`` (kg; see :func:`rod_moments`): end nodes and a uniform strut when they
    can (a unique 3x3 solve), else a payload at the centre of mass with the uniform strut and one end, else
    with both ends (always possible while the moments are those of masses between the ends)."""
    m0, m1, m2 = moments
    if m0 <= 0.0:   # nothing left beside the payloads
        return 0.0, 0.0, 0.0, 0.0
    c = m1 / m0
    columns = {"a": (1.0, 0.0, 0.0), "b": (1.0, 1.0, 1.0), "s": (1.0, 0.5, 1.0 / 3.0), "p": (1.0, c, c * c)}
    for keys in ("abs", "bsp", "asp"):
        matrix = np.array([columns[k] for k in keys]).T
        if abs(np.linalg.det(matrix)) < 1e-9:
            continue
        solution = np.linalg.solve(matrix, moments)
        if solution.min() >= -1e-12 * m0:
            out = dict(zip(keys, np.maximum(solution, 0.0)))
            return out.get("a", 0.0), out.get("b", 0.0), out.get("s", 0.0), out.get("p", 0.0)
    # both ends (variance c (1 - c) about c) and a payload at c (none), in the proportion of the variance
    share = (m2 / m0 - c * c) / (c * (1.0 - c))
    return share * m0 * (1.0 - c), share * m0 * c, 0.0, (1.0 - share) * m0


class _Reader:
    """One MJCF model being mapped: the compiled model at ``qpos0``, the notes, the refusals."""

    def __init__(self, source):
        mujoco = self.mj = _mujoco()
        text = source if isinstance(source, str) and source.lstrip().startswith("<") else None
        self.label = "<MJCF string>" if text is not None else str(source)
        if text is None and not Path(source).is_file():
            raise SceneError(f"{self.label}: no such file")
        try:
            self.spec = mujoco.MjSpec.from_string(text) if text is not None else mujoco.MjSpec.from_file(str(source))
            self.model = self.spec.compile()
        except Exception as exc:   # MuJoCo's parser and compiler raise ValueError (or its own errors)
            raise SceneError(f"{self.label}: MuJoCo cannot read it: {' '.join(str(exc).split())}") from None
        self.data = mujoco.MjData(self.model)
        mujoco.mj_forward(self.model, self.data)
        self.notes: list[str] = []
        self.taken: set[str] = set()    # the scene's names (nodes and members share one namespace)
        # each geom's own mass (kg), as MuJoCo's compiler takes it: its mass, else density x volume
        # (0 for a mesh or height field: those never reach the mass split, see _rod)
        self.geom_mass = np.array([
            g.mass if math.isfinite(g.mass) else
            g.density * _volume(int(self.model.geom_type[i]), self.model.geom_size[i])
            if int(self.model.geom_type[i]) in _VOLUME_KINDS else 0.0
            for i, g in enumerate(self.spec.geoms)])

    def error(self, msg: str) -> SceneError:
        return SceneError(f"{self.label}: {msg}")

    def warn(self, msg: str) -> None:
        warnings.warn(f"{self.label}: {msg}", MappingWarning, stacklevel=4)

    def name(self, kind, index: int, fallback: str) -> str:
        raw = self.mj.mj_id2name(self.model, kind, index)
        return raw if raw else fallback


def import_mjcf(source) -> Imported:
    """A scene from an MJCF model (a path, or the XML itself as a string starting with ``<``), read by
    MuJoCo's own parser (the ``io`` extra), at its initial configuration ``qpos0``, at rest.

    Mapping, element by element:

    * A body on the world body with a free joint whose geoms lie along one axis is a **rigid strut** named
      after it. The axis is that of its capsule and cylinder geoms (all collinear), else the line through
      its two farthest geoms and sites. Its two end nodes sit at the extremes of its geoms (segment ends,
      centres) and sites projected onto the axis; a node takes the name of a site exactly there, else
      ``BODY_a``/``BODY_b``; node a is the end of the first site on an end, else of the first capsule's or
      cylinder's ``fromto`` start. Each geom's share of the mass is named in the notes: a capsule or cylinder from
      end to end goes to the strut's uniform mass, a sphere centred at an end to that node, any other geom
      to a payload at its centre's projection. MuJoCo's compiled body (mass, centre of mass, inertia) is
      then matched exactly: the payloads are kept and the rest of the three mass moments
      ``(∫dm, ∫s dm, ∫s² dm)`` is solved for the end nodes' masses and the strut's uniform mass (a 3x3
      linear system), or where that needs a negative mass, for a payload at the centre of mass with the strut
      and one end, or with both ends. The inertia kept is the mean of the two about axes normal to the rod
      (a slender rod does not spin about its own axis: the axial inertia is dropped, and a warning says when
      the two normal ones differ). A centre of mass off the axis is projected onto it, with a warning. The
      largest radius of the capsules and cylinders from end to end (else of any) is the strut's radius (a
      node touches the ground at its largest member radius, which so covers a capsule's rounded end); a
      sphere centred at an end is an end cap: its radius is the node's.
    * A body with exactly three orthogonal slide joints is a point-mass node (what :func:`scene_to_mjcf`
      writes for a node without a rigid strut); a body with no joint is part of the world (its sites are
      fixed nodes, its geoms the world's).
    * A spatial tendon through two sites is a **cable** between nodes: a site at a rod's end is that node (its
      radial offset from the axis is noted); a site along the rod is attached to the nearer end node, with a
      warning naming the site, its place along the rod and the distance dropped (a scene's cables end at
      nodes).
      Its ``stiffness``, ``damping`` and ``springlength`` become the cable's stiffness, damping and rest
      length: MuJoCo's dead band ``[lower, upper]`` pulls beyond ``upper``, which is the rest length (a
      push below ``lower`` is dropped, with a warning). A two-sided spring (one ``springlength``) between
      two nodes without a rigid strut is an elastic strut. A limited tendon with no stiffness is an
      inextensible cable of rest length its range's upper bound. The tendon's width is the member's radius.
    * An actuator on a tendon: :attr:`Imported.actuators` says which cable it drives.
    * A plane on the world facing +z is the ground, with its sliding friction (MuJoCo takes the larger of
      two touching geoms' frictions; the ground keeps the plane's). Gravity from ``<option>``.

    Refused (``SceneError`` naming the file and the element): hinge, slide (other than the point-mass
    triple) and ball joints, nested bodies, geoms off a rod's axis when they are capsules or cylinders,
    meshes and height fields that carry mass or collide, tendons through more or fewer than two sites,
    wrapping or fixed tendons, equality constraints, a tilted or second plane. Dropped with a
    :class:`~tensegrity_sim.io.MappingWarning`: actuators on joints, other world geoms, keyframes, and what
    the notes above say.
    """
    r = _Reader(source)
    model, mj = r.model, r.mj
    if model.neq:
        raise r.error(f"equality {r.name(mj.mjtObj.mjOBJ_EQUALITY, 0, '#0')!r}: equality constraints are not "
                      f"mapped (a scene has none)")
    nodes: list[dict] = []
    struts: list[dict] = []
    node_of_site: dict[int, str] = {}    # sites that are nodes
    rod_of_body: dict[int, dict] = {}    # body -> its strut and axis
    world_bodies = {0}
    for b in range(1, model.nbody):
        bname = r.name(mj.mjtObj.mjOBJ_BODY, b, f"body{b}")
        if model.body_parentid[b] != 0:
            parent = r.name(mj.mjtObj.mjOBJ_BODY, int(model.body_parentid[b]), "world")
            raise r.error(f"body {bname!r}: nested in body {parent!r} (only the world's children map to rods "
                          f"and point masses)")
        joints = range(model.body_jntadr[b], model.body_jntadr[b] + model.body_jntnum[b])
        kinds = [int(model.jnt_type[j]) for j in joints]
        if not kinds:
            world_bodies.add(b)
        elif kinds == [0]:
            rod_of_body[b] = _rod(r, b, bname, nodes, struts)
        elif kinds == [2, 2, 2] and abs(np.linalg.det(model.jnt_axis[list(joints)])) > 1 - 1e-9:
            _point(r, b, bname, nodes, node_of_site)
        else:
            j = next((j for j in joints if model.jnt_type[j] != 0), joints[0])
            raise r.error(f"joint {r.name(mj.mjtObj.mjOBJ_JOINT, j, f'#{j}')!r} of body {bname!r}: "
                          f"{_JOINT_KIND[int(model.jnt_type[j])]} joints{' beside others' if kinds[0] == 0 else ''} "
                          f"are not mapped (only a free joint, a rod, or three slide joints, a point mass)")
    cables, cable_of = _tendons(r, nodes, struts, node_of_site, rod_of_body, world_bodies)
    ground = _world(r, world_bodies)
    actuators = {}
    for a in range(model.nu):
        aname = r.name(mj.mjtObj.mjOBJ_ACTUATOR, a, f"actuator{a}")
        target = int(model.actuator_trnid[a, 0])
        if model.actuator_trntype[a] == mj.mjtTrn.mjTRN_TENDON and target in cable_of:
            actuators[aname] = cable_of[target]
        else:
            r.warn(f"actuator {aname!r}: drives no cable (only actuators on a cable's tendon map): dropped")
    if model.nkey:
        r.warn(f"{model.nkey} keyframe(s) dropped: the scene starts at qpos0, at rest")
    r.notes.append(f"MuJoCo's timestep {model.opt.timestep!r} s and integrator are not part of a scene")
    mapping = {"name": r.spec.modelname or "mjcf", "gravity": [float(g) for g in model.opt.gravity],
               "nodes": nodes, "struts": struts, "cables": cables}
    if ground is not None:
        mapping["ground"] = ground
    return Imported(Scene.from_dict(mapping, source=r.label), actuators, tuple(r.notes))


def _rod(r: _Reader, b: int, bname: str, nodes: list, struts: list) -> dict:
    """Map free body ``b`` to a rigid strut and its two end nodes (appended to ``struts``, ``nodes``);
    returns its axis: ``{"strut", "a", "b", "start", "axis", "length"}`` (start: node a's position, m)."""
    model, data, mj = r.model, r.data, r.mj
    geoms = []
    for g in range(model.body_geomadr[b], model.body_geomadr[b] + model.body_geomnum[b]):
        kind, gname = int(model.geom_type[g]), r.name(mj.mjtObj.mjOBJ_GEOM, g, f"#{g}")
        if kind not in _VOLUME_KINDS:
            what = _GEOM_KIND.get(kind, f"type-{kind}")
            if r.geom_mass[g] > 0 or model.geom_contype[g] or model.geom_conaffinity[g]:
                raise r.error(f"body {bname!r}: geom {gname!r} is a {what} that carries mass or collides: not mapped "
                              f"(a rod is made of capsules, cylinders, spheres, boxes and ellipsoids)")
            r.warn(f"body {bname!r}: visual {what} geom {gname!r} dropped")
            continue
        geoms.append((g, kind, gname))
    sites = [s for s in range(model.nsite) if model.site_bodyid[s] == b]
    segments = [(g, data.geom_xpos[g], data.geom_xmat[g].reshape(3, 3)[:, 2] * model.geom_size[g, 1])
                for g, kind, _ in geoms if kind in (_CAPSULE, _CYLINDER)]
    if segments:   # MuJoCo turns a fromto geom's z axis from its second point to its first: a runs from first
        start, axis = segments[0][1], -segments[0][2] / np.linalg.norm(segments[0][2])
    else:
        points = [data.geom_xpos[g] for g, _, _ in geoms] + [data.site_xpos[s] for s in sites]
        far = max(((p, q) for p in points for q in points), key=lambda pq: np.linalg.norm(pq[1] - pq[0]),
                  default=None)
        if far is None or np.linalg.norm(far[1] - far[0]) == 0.0:
            raise r.error(f"body {bname!r}: no rod axis (no capsule or cylinder geom, and fewer than two distinct "
                          f"geoms and sites)")
        start, axis = far[0], (far[1] - far[0]) / np.linalg.norm(far[1] - far[0])

    def along(p):   # (distance along the axis from start, distance from the axis), m
        t = float((p - start) @ axis)
        return t, float(np.linalg.norm(p - start - t * axis))

    ts = [along(p)[0] for g, centre, half in segments for p in (centre - half, centre + half)]
    ts += [along(data.geom_xpos[g])[0] for g, kind, _ in geoms if kind not in (_CAPSULE, _CYLINDER)]
    ts += [along(data.site_xpos[s])[0] for s in sites]
    low, high = min(ts), max(ts)
    length = high - low
    first = next((t for t in ts[len(ts) - len(sites):] if min(abs(t - low), abs(t - high)) <= _TOL * length), low)
    if abs(first - high) < abs(first - low):   # the first site at an end is node a's (round trips keep the order)
        axis, low, high, ts = -axis, -high, -low, [-t for t in ts]
    if length <= 0.0:
        raise r.error(f"body {bname!r}: its geoms and sites span no length along the axis (not a rod)")
    tol = _TOL * length
    for g, centre, half in segments[1:]:
        if max(along(centre - half)[1], along(centre + half)[1]) > tol:   # both its ends on the axis
            first = segments[0][0]
            raise r.error(f"body {bname!r}: geom {r.name(mj.mjtObj.mjOBJ_GEOM, g, f'#{g}')!r} does not lie along "
                          f"the axis of geom {r.name(mj.mjtObj.mjOBJ_GEOM, first, f'#{first}')!r} (not a rod)")
    pa, pb = start + low * axis, start + high * axis
    strut = scene_name(bname, r.taken)
    end_names = []
    for end, p in (("a", pa), ("b", pb)):
        exact = [s for s in sites if np.linalg.norm(data.site_xpos[s] - p) <= tol]
        end_names.append(scene_name(r.name(mj.mjtObj.mjOBJ_SITE, exact[0], "") if exact else f"{bname}_{end}",
                                    r.taken))
    # each geom's share: the strut (end to end), an end node (a sphere centred there) or a payload
    explicit = r.spec.bodies[b].explicitinertial and \
        r.spec.compiler.inertiafromgeom != mj.mjtInertiaFromGeom.mjINERTIAFROMGEOM_TRUE
    caps = [0.0, 0.0]
    radii = {True: 0.0, False: 0.0}   # of the capsules and cylinders from end to end, and of the others
    payloads = []
    for g, kind, gname in geoms:
        mass, size = float(r.geom_mass[g]), model.geom_size[g]
        t, off = along(data.geom_xpos[g])
        s = (t - low) / length
        if kind in (_CAPSULE, _CYLINDER):
            half = float(size[1])
            spans = abs(t - half - low) <= tol and abs(t + half - high) <= tol
            radii[spans] = max(radii[spans], float(size[0]))
            share = "the strut's uniform mass" if spans else f"a payload at {s:.6g}"
        elif kind == _SPHERE and off <= tol and min(s, 1.0 - s) <= _TOL:
            j = int(s > 0.5)
            caps[j] = max(caps[j], float(size[0]))
            share = f"node {end_names[j]!r}"
        else:
            share = f"a payload at {s:.6g}"
            spans = False
        if off > tol:
            r.warn(f"body {bname!r}: geom {gname!r} lies {off:.3g} m off the rod's axis: taken onto it")
        if explicit:
            r.notes.append(f"body {bname!r}: geom {gname!r} ({_GEOM_KIND[kind]}) carries no mass (the body's "
                           f"<inertial> gives it)")
            continue
        r.notes.append(f"body {bname!r}: geom {gname!r} ({_GEOM_KIND[kind]}, {mass:.6g} kg) -> {share}")
        if share.startswith("a payload") and mass > 0:
            payloads.append((s, mass))
    # MuJoCo's compiled body, matched exactly: mass, centre of mass along the axis, inertia normal to it
    total = float(model.body_mass[b])
    if total <= 0.0:
        raise r.error(f"body {bname!r}: no mass (a rod needs some)")
    rot = data.ximat[b].reshape(3, 3)
    inertia = rot @ np.diag(model.body_inertia[b]) @ rot.T
    c, off = along(data.xipos[b])
    c = (c - low) / length
    if off > tol:
        r.warn(f"body {bname!r}: its centre of mass lies {off:.3g} m off the rod's axis: taken onto it")
    normal = np.linalg.eigvalsh((np.eye(3) - np.outer(axis, axis)) @ inertia @ (np.eye(3) - np.outer(axis, axis)))[1:]
    transverse = float(normal.mean())
    if normal[1] - normal[0] > _TOL * normal[1]:
        r.warn(f"body {bname!r}: inertia {normal[0]:.6g} and {normal[1]:.6g} kg m^2 about the two axes normal to "
               f"the rod: their mean is kept")
    r.notes.append(f"body {bname!r}: inertia {float(axis @ inertia @ axis):.3g} kg m^2 about the rod's own axis "
                   f"dropped (a slender rod does not spin about it)")
    moments = total * np.array([1.0, c, c * c]) + np.array([0.0, 0.0, transverse / length ** 2])
    if moments[2] > moments[1] * (1.0 + 1e-12):   # more inertia than all the mass at the two ends gives
        r.warn(f"body {bname!r}: inertia {transverse:.6g} kg m^2 normal to the rod exceeds what masses between "
               f"its ends can carry ({length ** 2 * (moments[1] - moments[1] ** 2 / total):.6g}): the excess is "
               f"dropped")
        moments[2] = moments[1]
    rest = moments - sum(m * np.array([1.0, s, s * s]) for s, m in payloads)
    if payloads and not _fits(rest, total):
        r.warn(f"body {bname!r}: its payload geoms do not fit the body's compiled mass and inertia: they are "
               f"folded into the match")
        payloads, rest = [], moments
    ma, mb, ms, mp = _split_moments(rest)
    if mp > 0:
        payloads.append((float(rest[1] / rest[0]), mp))
    for name, p, m, cap in zip(end_names, (pa, pb), (ma, mb), caps):
        nodes.append({"name": name, "position": [float(v) for v in p], "mass": float(m), **_radius(cap)})
    struts.append({"name": strut, "nodes": end_names, "stiffness": "rigid", "mass": float(ms),
                   "radius": radii[True] or radii[False],
                   **({"payloads": [{"at": float(s), "mass": float(m)} for s, m in payloads]} if payloads else {})})
    r.notes.append(f"body {bname!r} -> strut {strut!r} ({length:.6g} m): {total:.6g} kg as node masses "
                   f"{ma:.6g}, {mb:.6g} kg, uniform {ms:.6g} kg, payloads "
                   f"{', '.join(f'{m:.6g} kg at {s:.6g}' for s, m in payloads) or 'none'} (mass, centre of mass "
                   f"and inertia normal to the axis matched)")
    return {"strut": strut, "a": end_names[0], "b": end_names[1], "start": pa, "axis": axis, "length": length}


def _radius(radius: float) -> dict:
    """A node's ``radius`` key: only for an end cap (a scene's default is 0)."""
    return {"radius": radius} if radius > 0 else {}


def _point(r: _Reader, b: int, bname: str, nodes: list, node_of_site: dict) -> None:
    """Map body ``b`` (three slide joints) to a point-mass node named after it."""
    model, data = r.model, r.data
    name = scene_name(bname, r.taken)
    radius = max((float(model.geom_size[g, 0]) for g in range(model.body_geomadr[b],
                  model.body_geomadr[b] + model.body_geomnum[b]) if model.geom_type[g] == _SPHERE), default=0.0)
    nodes.append({"name": name, "position": [float(v) for v in data.xipos[b]], "mass": float(model.body_mass[b]),
                  **_radius(radius)})
    for s in range(model.nsite):
        if model.site_bodyid[s] == b:
            node_of_site[s] = name
            off = float(np.linalg.norm(data.site_xpos[s] - data.xipos[b]))
            if off > 0.0:
                r.notes.append(f"site {r.name(r.mj.mjtObj.mjOBJ_SITE, s, f'#{s}')!r} lies {off:.3g} m from point "
                               f"mass {bname!r}: attached at the point")


def _world(r: _Reader, world_bodies: set) -> dict | None:
    """The ground from the world's plane (None without one); other world geoms are dropped, with a warning."""
    model, data, mj = r.model, r.data, r.mj
    planes, dropped = [], []
    for g in range(model.ngeom):
        if model.geom_bodyid[g] not in world_bodies:
            continue
        gname = r.name(mj.mjtObj.mjOBJ_GEOM, g, f"#{g}")
        if model.geom_type[g] == _PLANE:
            planes.append((g, gname))
        else:
            dropped.append(gname)
    if dropped:
        r.warn(f"world geoms {', '.join(repr(n) for n in dropped)} dropped (a scene's world is its ground)")
    if len(planes) > 1:
        raise r.error(f"planes {planes[0][1]!r} and {planes[1][1]!r}: a scene has one ground")
    if not planes:
        return None
    g, gname = planes[0]
    normal = data.geom_xmat[g].reshape(3, 3)[:, 2]
    if abs(normal[2] - 1.0) > 1e-9:
        raise r.error(f"plane {gname!r}: its normal {normal.tolist()} is not +z (the ground is horizontal)")
    if model.opt.disableflags & int(mj.mjtDisableBit.mjDSBL_CONTACT):
        r.warn(f"plane {gname!r} dropped: the model disables contacts")
        return None
    r.notes.append(f"plane {gname!r} -> the ground at z = {float(data.geom_xpos[g, 2]):.6g} m, friction "
                   f"{float(model.geom_friction[g, 0]):.6g}")
    return {"height": float(data.geom_xpos[g, 2]), "friction": float(model.geom_friction[g, 0])}


def _tendons(r: _Reader, nodes: list, struts: list, node_of_site: dict, rod_of_body: dict,
             world_bodies: set) -> tuple[list, dict]:
    """The cables (and elastic struts, appended to ``struts``) of the model's tendons; returns the cables and
    tendon id -> cable name."""
    model, data, mj = r.model, r.data, r.mj
    cables, cable_of = [], {}
    damped = []
    rigid_nodes = {rod[k] for rod in rod_of_body.values() for k in ("a", "b")}
    for t in range(model.ntendon):
        tname = r.name(mj.mjtObj.mjOBJ_TENDON, t, f"tendon{t}")
        adr, num = int(model.tendon_adr[t]), int(model.tendon_num[t])
        types = [int(model.wrap_type[w]) for w in range(adr, adr + num)]
        site, joint = int(mj.mjtWrap.mjWRAP_SITE), int(mj.mjtWrap.mjWRAP_JOINT)
        if joint in types:
            raise r.error(f"tendon {tname!r}: a fixed (joint) tendon is not mapped (a cable joins two sites)")
        wraps = [w for w, k in zip(range(adr, adr + num), types) if k in (int(mj.mjtWrap.mjWRAP_SPHERE),
                                                                         int(mj.mjtWrap.mjWRAP_CYLINDER))]
        if wraps:
            gname = r.name(mj.mjtObj.mjOBJ_GEOM, int(model.wrap_objid[wraps[0]]), "?")
            raise r.error(f"tendon {tname!r}: wraps around geom {gname!r}: wrapping tendons are not mapped")
        if types != [site, site]:
            raise r.error(f"tendon {tname!r}: runs through {num} sites or pulleys: only a tendon through two sites "
                          f"maps to a cable")
        ends = [_end(r, int(model.wrap_objid[w]), tname, nodes, node_of_site, rod_of_body, world_bodies)
                for w in range(adr, adr + 2)]
        if ends[0] == ends[1]:
            raise r.error(f"tendon {tname!r}: both its sites map to node {ends[0]!r}")
        k, (low, high) = float(model.tendon_stiffness[t]), (float(v) for v in model.tendon_lengthspring[t])
        limited, top = bool(model.tendon_limited[t]), float(model.tendon_range[t, 1])
        name = scene_name(tname, r.taken)
        member = {"name": name, "nodes": ends, "radius": float(model.tendon_width[t])}
        if k > 0 and low == high and all(isinstance(e, str) and e not in rigid_nodes for e in ends):
            struts.append({**member, "stiffness": k, "rest_length": high})
            r.notes.append(f"tendon {tname!r} -> elastic strut {name!r}: two-sided spring, rest length {high:.6g} m")
            continue
        if k > 0:
            member.update(stiffness=k, rest_length=high)
            if low > 0.0:
                r.warn(f"tendon {tname!r}: MuJoCo also pushes while it is shorter than {low:.6g} m (springlength's "
                       f"lower bound); the cable goes slack instead")
            if limited:
                r.warn(f"tendon {tname!r}: its length limit {top:.6g} m is dropped (the cable is elastic)")
            law = f"stiffness {k:.6g} N/m, rest length {high:.6g} m (springlength's upper bound)"
        elif limited:
            member.update(rest_length=top)
            law = f"inextensible, rest length {top:.6g} m (its range's upper bound)"
        else:
            raise r.error(f"tendon {tname!r}: neither a stiffness nor a length limit (nothing makes it a cable)")
        if model.tendon_damping[t] > 0:
            member["damping"] = float(model.tendon_damping[t])
            damped.append(tname)
        cable_of[t] = name
        cables.append(member)
        r.notes.append(f"tendon {tname!r} -> cable {name!r}: {law}")
    if damped:
        r.warn(f"tendons {', '.join(repr(n) for n in damped)}: damping acts here only while a cable is taut "
               f"(in MuJoCo also while slack)")
    return cables, cable_of


def _end(r: _Reader, site: int, tname: str, nodes: list, node_of_site: dict, rod_of_body: dict,
         world_bodies: set):
    """A cable end from a tendon's site: a node name (a site along a rod: its nearer end's)."""
    model, data, mj = r.model, r.data, r.mj
    sname = r.name(mj.mjtObj.mjOBJ_SITE, site, f"#{site}")
    body = int(model.site_bodyid[site])
    if site in node_of_site:
        return node_of_site[site]
    if body in world_bodies:   # a fixed node
        name = node_of_site[site] = scene_name(sname, r.taken)
        nodes.append({"name": name, "position": [float(v) for v in data.site_xpos[site]], "fixed": True})
        return name
    rod = rod_of_body[body]
    p = data.site_xpos[site] - rod["start"]
    t = float(p @ rod["axis"])
    off = float(np.linalg.norm(p - t * rod["axis"]))
    at = min(max(t / rod["length"], 0.0), 1.0)
    if off > _TOL * rod["length"]:
        r.notes.append(f"site {sname!r} (tendon {tname!r}) lies {off:.3g} m off rod {rod['strut']!r}'s axis: "
                       f"attached on the axis")
    end = "a" if at <= 0.5 else "b"
    if _TOL < at < 1.0 - _TOL:   # a scene's cable ends at nodes: the nearer end takes it
        node = rod["start"] + (end == "b") * rod["length"] * rod["axis"]
        dropped = float(np.linalg.norm(data.site_xpos[site] - node))
        r.warn(f"site {sname!r} (tendon {tname!r}) lies at {at:.4g} along rod {rod['strut']!r}: attached to its end "
               f"node {rod[end]!r}, {dropped:.3g} m away")
    return rod[end]
