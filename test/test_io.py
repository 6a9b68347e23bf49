"""Robots in and out: MJCF both ways (tensegrity_sim.io.mjcf, MuJoCo's own parser) and NTRT YAML in.

Closed forms (a rod body's mass, centre of mass and inertia; an NTRT rod's mass and a string's rest length;
a substructure's rotation), round trips (``load_mjcf(scene.to_mjcf())``), cross-checks against MuJoCo running
the same robot, the fixtures settling on the ground, and every refusal's message pinned.
"""
import math
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

import tensegrity_sim as ts
from tensegrity_sim.io import MappingWarning, import_mjcf, import_ntrt
from tensegrity_sim.io.mjcf import rod_moments

FIXTURES = Path(__file__).resolve().parent / "fixtures"
THREE_BAR = FIXTURES / "mjcf" / "three_bar.xml"
SUPERBALL = FIXTURES / "ntrt" / "superball.yaml"
PRISM = FIXTURES / "ntrt" / "prism3.yaml"


def _moments(scene: ts.Scene) -> dict:
    """Each strut's mass moments (kg) with its end nodes' own masses."""
    own = {n.name: n.mass for n in scene.nodes}
    return {s.name: rod_moments(s, own[s.nodes[0]], own[s.nodes[1]]) for s in scene.struts}


def _body(moments: np.ndarray, length: float) -> tuple[float, float, float]:
    """Mass (kg), centre of mass (fraction along the rod) and inertia normal to the rod about it (kg m²)."""
    m0, m1, m2 = moments
    return m0, m1 / m0, length ** 2 * (m2 - m1 * m1 / m0)


# ------------------------------------------------------------------------------------------- closed forms
def test_a_rod_body_keeps_its_mass_centre_and_inertia():
    """A cylinder rod (0.4 kg, radius 1 cm, 0.8 m), two end-cap spheres (50 g, 2 cm) and a motor (0.3 kg
    cylinder, radius 2.5 cm, 6 cm long) at 30 % of the rod: the strut, its node masses and payload reproduce
    the body's mass, centre of mass and inertia normal to the axis in closed form."""
    pytest.importorskip("mujoco")
    xml = """<mujoco><worldbody><body name="rod" pos="0.1 0.2 0.3" euler="0.3 0.2 0.1"><freejoint/>
      <geom name="tube" type="cylinder" fromto="0 0 0 0.8 0 0" size="0.01" mass="0.4"/>
      <geom name="cap_a" type="sphere" size="0.02" mass="0.05"/>
      <geom name="cap_b" type="sphere" pos="0.8 0 0" size="0.02" mass="0.05"/>
      <geom name="motor" type="cylinder" fromto="0.21 0 0 0.27 0 0" size="0.025" mass="0.3"/>
      </body></worldbody></mujoco>"""
    imported = import_mjcf(xml)
    (strut,) = imported.scene.struts
    # closed form, along the rod from cap_a: parts (mass, centre, own inertia normal to the axis)
    parts = [(0.4, 0.4, 0.4 * (3 * 0.01 ** 2 + 0.8 ** 2) / 12), (0.05, 0.0, 0.4 * 0.05 * 0.02 ** 2),
             (0.05, 0.8, 0.4 * 0.05 * 0.02 ** 2), (0.3, 0.24, 0.3 * (3 * 0.025 ** 2 + 0.06 ** 2) / 12)]
    mass = sum(m for m, _, _ in parts)
    centre = sum(m * s for m, s, _ in parts) / mass
    inertia = sum(i + m * (s - centre) ** 2 for m, s, i in parts)
    got = _body(_moments(imported.scene)[strut.name], strut.rest_length)
    assert strut.rest_length == pytest.approx(0.8, rel=1e-12)
    np.testing.assert_allclose(got, (mass, centre / 0.8, inertia), rtol=1e-10)
    # each geom's share is named
    assert "body 'rod': geom 'motor' (cylinder, 0.3 kg) -> a payload at 0.3" in imported.notes
    assert "body 'rod': geom 'tube' (cylinder, 0.4 kg) -> the strut's uniform mass" in imported.notes
    assert "body 'rod': geom 'cap_b' (sphere, 0.05 kg) -> node 'rod_b'" in imported.notes
    assert [n.radius for n in imported.scene.nodes] == [0.02, 0.02]


def test_ntrt_rods_and_strings_in_closed_form():
    """SUPERball's layout: each rod's mass is density x pi r² x length in the file's units (0.7 x pi x 0.3² x
    16.8 kg), each string's rest length its length less pretension (800 x 0.1 N) over stiffness (600 N/m)."""
    scene = ts.load_ntrt(SUPERBALL)
    assert (len(scene.nodes), len(scene.struts), len(scene.cables)) == (12, 6, 24)
    for strut in scene.struts:
        assert strut.rigid and strut.mass == pytest.approx(0.7 * math.pi * 0.3 ** 2 * 16.8, rel=1e-12)
        assert strut.rest_length == pytest.approx(1.68, rel=1e-12) and strut.radius == pytest.approx(0.03)
    x = dict(zip(scene.node_names, scene.positions))
    for cable in scene.cables:
        length = np.linalg.norm(x[cable.nodes[1]] - x[cable.nodes[0]])
        assert cable.rest_length == pytest.approx(length - 80.0 / 600.0, rel=1e-12)
        assert (cable.stiffness, cable.damping) == (600.0, 50.0)
    # y up in NTRT is z up here; the ground under the lowest rod end
    assert x["ya_pos"] == pytest.approx([0.42, 0.0, 0.9 + 0.84])
    assert scene.ground.height == pytest.approx(0.06 - 0.03) and scene.ground.friction == 0.9
    # metres per unit given: everything scales, stiffness does not
    metres = ts.load_ntrt(SUPERBALL, length_scale=1.0)
    assert metres.struts[0].rest_length == pytest.approx(16.8) and metres.cables[0].stiffness == 600.0


def test_ntrt_string_node_along_a_rod_goes_to_its_nearer_end(tmp_path):
    path = tmp_path / "m.yaml"
    path.write_text("nodes: {a: [0, 0, 0], b: [10, 0, 0], m: [7, 0, 0], c: [0, 5, 0], d: [10, 5, 0]}\n"
                    "pair_groups: {rod: [[a, b], [c, d]], string: [[m, c], [b, d]]}\n")
    with pytest.warns(MappingWarning) as record:
        scene = ts.load_ntrt(path)
    assert [str(w.message) for w in record] == [
        f"{path}: pair_groups: 'string': node 'm' lies at 0.7 along rod (a, b): attached to its end node 'b', 0.3 m "
        f"away"]
    assert [c.nodes for c in scene.cables] == [("b", "c"), ("b", "d")]


def test_ntrt_substructures_are_turned_about_their_reference():
    """prism3.yaml: three copies of rod.yaml, two turned about NTRT's y axis (here z) through the origin by
    -120 and -240 degrees; strings bonded between the copies' nodes."""
    scene = ts.load_ntrt(PRISM)
    x = dict(zip(scene.node_names, scene.positions))
    for k in range(3):
        turn = math.radians(-120 * k)   # about NTRT's y: about z once y-up is turned to z-up
        assert x[f"r{k}_bottom"] == pytest.approx([0.4 * math.cos(turn), 0.4 * math.sin(turn), 0.0], abs=1e-12)
    assert [c.nodes for c in scene.cables[:3]] == [("r0_bottom", "r1_bottom"), ("r0_top", "r1_top"),
                                                   ("r0_top", "r1_bottom")]


# ------------------------------------------------------------------------------------------- round trips
def _same(a: ts.Scene, b: ts.Scene) -> None:
    """Same robot: nodes (by name), members, rest lengths, stiffness, masses as mass moments, ground."""
    xa, xb = dict(zip(a.node_names, a.positions)), dict(zip(b.node_names, b.positions))
    assert set(xa) == set(xb)
    for name in xa:
        np.testing.assert_allclose(xb[name], xa[name], atol=1e-12)
    assert [(s.name, s.nodes, s.rigid) for s in a.struts] == [(s.name, s.nodes, s.rigid) for s in b.struts]
    assert [(c.name, c.nodes, c.stiffness) for c in a.cables] == [(c.name, c.nodes, c.stiffness) for c in b.cables]
    np.testing.assert_allclose(b.cable_rest_lengths, a.cable_rest_lengths, rtol=1e-14)
    np.testing.assert_allclose([s.rest_length for s in b.struts], [s.rest_length for s in a.struts], rtol=1e-12)
    ma, mb = _moments(a), _moments(b)
    for name, strut in zip(a.strut_names, a.struts):
        if strut.rigid:
            np.testing.assert_allclose(mb[name], ma[name], rtol=1e-12, atol=1e-15)
    free = {n.name: m for n, m in zip(b.nodes, b.masses) if not n.fixed}
    assert free == pytest.approx({n.name: m for n, m in zip(a.nodes, a.masses) if not n.fixed}, rel=1e-12)
    assert a.gravity == b.gravity and a.ground == b.ground


@pytest.mark.parametrize("name", ["icosahedron_ground", "prism3", "tower"])
def test_builtins_round_trip_through_mjcf(name):
    """Rigid struts on the ground, elastic struts between point masses, fixed nodes: load_mjcf(to_mjcf())."""
    pytest.importorskip("mujoco")
    scene = ts.load_scene(name)
    _same(scene, ts.load_mjcf(scene.to_mjcf()))


def test_imported_robot_round_trips():
    """An imported robot's scene exported and imported again is the same scene (payloads kept as its mass
    moments, attachment points, end caps)."""
    pytest.importorskip("mujoco")
    with pytest.warns(MappingWarning):
        imported = import_mjcf(THREE_BAR)
    assert imported.actuators == {f"motor_{c}": c for c in ("bottom0", "bottom1", "bottom2", "top0", "top1", "top2")}
    d = imported.scene.to_dict()
    for c in d["cables"]:
        c["damping"] = 0.0
    scene = ts.Scene.from_dict(d)
    _same(scene, ts.load_mjcf(scene.to_mjcf()))


# ------------------------------------------------------------------------------------------- against MuJoCo
def _final(scene: ts.Scene, duration: float, dt: float) -> np.ndarray:
    """Node positions (N, 3) m after ``duration`` s of the elastic method at order 4 (its switches located)."""
    sim = ts.Simulator(scene, method="elastic", dt=dt, order=4)
    sim.run(duration=duration)
    return sim.positions


def test_a_scene_and_its_mjcf_follow_the_same_trajectory():
    """The three-bar fixture thrown in the air (no contacts, elastic cables, gravity, 180 slack/taut switches in
    1 s): this simulator (rigid struts in node coordinates, the consistent mass, order 4 at 0.5 ms) and MuJoCo
    running ``scene.to_mjcf()`` (free bodies, RK4 at 0.05 ms, switches not located) agree after 1 s to 4.0e-7 m
    (measured; 9.6e-7 m with MuJoCo at 0.1 ms: MuJoCo's own error)."""
    pytest.importorskip("mujoco")
    from bench.cases import rigid_consistent
    from bench.mujoco_peer import MujocoPeer
    with pytest.warns(MappingWarning):
        d = ts.load_mjcf(THREE_BAR).to_dict()
    del d["ground"]
    rng = np.random.default_rng(1)
    for n in d["nodes"]:
        n["velocity"] = [float(v) for v in rng.normal(scale=1.0, size=3)]
    for c in d["cables"]:
        c["damping"] = 0.0
    scene = rigid_consistent(d)
    peer = MujocoPeer(scene, dt=5e-5, integrator="RK4")
    peer.advance(20_000)
    assert np.max(np.linalg.norm(_final(scene, 1.0, 5e-4) - peer.positions(), axis=1)) < 1e-6


def test_an_imported_robot_follows_mujoco_running_the_original_file():
    """The three-bar fixture as written (capsules with hemispherical ends, end-cap spheres, a motor cylinder:
    MuJoCo's own inertia) without damping and contacts, under gravity, 1 s: node positions against the file's
    sites agree to 1.2e-6 m (measured, whatever either step: the fixture's four-decimal motor lies 5e-5 m off
    the rod's axis, which the import projects onto it)."""
    mujoco = pytest.importorskip("mujoco")
    xml = THREE_BAR.read_text().replace('damping="8"', 'damping="0"').replace(
        '<option timestep="0.001"', '<option timestep="0.00005" integrator="RK4"><flag contact="disable"/></option'
        '><option')
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", MappingWarning)   # contacts off: the floor is dropped
        scene = ts.load_mjcf(xml)
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    mujoco.mj_step(model, data, nstep=20_000)
    original = data.site_xpos[[model.site(n).id for n in scene.node_names]]
    assert np.max(np.linalg.norm(_final(scene, 1.0, 5e-4) - original, axis=1)) < 3e-6


# ------------------------------------------------------------------------------------------- on the ground
def _fixture(path):
    """The fixture at ``path`` imported (MJCF or NTRT), its mapping warnings silenced."""
    if path.suffix == ".xml":
        pytest.importorskip("mujoco")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", MappingWarning)
        return ts.load_mjcf(path) if path.suffix == ".xml" else ts.load_ntrt(path)


@pytest.mark.parametrize("path", [SUPERBALL, PRISM, THREE_BAR], ids=lambda p: p.name)
def test_imported_robots_settle_on_the_ground(path):
    """Each fixture, dropped into gravity as written (prestressed, not form-found), stands on the ground: after
    3 s its nodes swing less than 1 cm about where they sit and that place no longer moves (the prisms' soft
    mechanism mode, which cable dampers barely touch, still swings by millimetres; SUPERball stops), every
    cable taut, nothing below the ground, and no energy made."""
    scene = _fixture(path)
    sim = ts.Simulator(scene, method="elastic", dt=1e-3)
    start = sim.energy()["total"]
    sim.run(duration=2.0)
    before, last = sim.run(duration=1.0), sim.run(duration=1.0)
    sway = np.linalg.norm(last.positions - last.positions.mean(axis=0), axis=2).max()
    drift = np.linalg.norm(last.positions.mean(axis=0) - before.positions.mean(axis=0), axis=1).max()
    assert sway < 0.01 and drift < 0.002, (sway, drift)
    assert not last.slack.any()
    assert last.positions[:, :, 2].min() > scene.ground.height
    assert sim.energy()["total"] < start


@pytest.mark.parametrize("path, distance, heading", [(SUPERBALL, 0.45, (0.0, 1.0)), (PRISM, 0.5, (0.656, 0.754)),
                                                     (THREE_BAR, 0.28, (0.618, -0.786))], ids=lambda p: str(p)[-14:])
def test_imported_robots_roll_under_a_schedule(path, distance, heading):
    """Each fixture, settled 2 s on the ground (its rods with their consistent mass), rolls over an edge of the
    triangle it stands on when two of that triangle's cables (the first two in the file) are reeled to 60 % over
    0.4 s, held 0.8 s and let out over 0.4 s: after 3 s its centre of mass has moved ``distance`` m or more
    within 18 degrees of ``heading`` (measured: SUPERball 0.51 m along +y, the 3-prism 0.59 m, the MJCF 3-bar
    0.31 m), on the ground, no cable slack at the end, every contact problem answered with the rods' blocks."""
    from tensegrity_sim.commands import parse_commands

    scene = _fixture(path)
    sim = ts.Simulator(scene, method="elastic", dt=1e-3)
    assert sim.system.mass.consistent
    sim.run(duration=2.0)
    base = set(np.argsort(sim.positions[:, 2])[:3].tolist())
    names = scene.node_names
    cables = [c.name for c in scene.cables if {names.index(n) for n in c.nodes} <= base][:2]
    rest = dict(zip(scene.cable_names, sim.rest_lengths))
    points = [{"time": t, "rest_lengths": {c: float(f * rest[c]) for c in cables}}
              for t, f in ((2.0, 1.0), (2.4, 0.6), (3.2, 0.6), (3.6, 1.0))]
    mass = scene.masses[:, None]
    start = (mass * sim.positions).sum(axis=0) / mass.sum()
    traj = sim.run(duration=3.0, commands=parse_commands(points, scene, "roll"))
    moved = ((mass * sim.positions).sum(axis=0) / mass.sum() - start)[:2]
    assert len(cables) == 2 and np.linalg.norm(moved) > distance, (cables, moved)
    assert moved @ np.asarray(heading) > np.cos(np.radians(18.0)) * np.linalg.norm(moved)
    assert traj.positions[:, :, 2].min() > scene.ground.height
    assert not traj.slack[-1].any()


# ------------------------------------------------------------------------------------------- refusals
_BODY = '<body name="r"><freejoint/><geom type="capsule" fromto="0 0 0 1 0 0" size="0.01"/>' \
        '<site name="a" pos="0 0 0"/><site name="b" pos="1 0 0"/><site name="m" pos="0.5 0 0"/>{}</body>'


def _xml(body: str = "", extra: str = "", world: str = "") -> str:
    return f'<mujoco><worldbody>{world}{_BODY.format(body)}<body name="q" pos="0 1 0"><freejoint/>' \
           f'<geom type="capsule" fromto="0 0 0 1 0 0" size="0.01"/><site name="c" pos="0 0 0"/></body>' \
           f'</worldbody>{extra}</mujoco>'


@pytest.mark.parametrize("xml, message", [
    ("<mujoco><worldbody>", "<MJCF string>: MuJoCo cannot read it: XML parse error 14: "
                            "Error=XML_ERROR_MISMATCHED_ELEMENT ErrorID=14 (0xe) Line number=1: XMLElement "
                            "name=worldbody"),
    (_xml('<body name="arm"><joint name="elbow" type="hinge"/><geom size="0.1"/></body>'),
     "<MJCF string>: body 'arm': nested in body 'r' (only the world's children map to rods and point masses)"),
    ('<mujoco><worldbody><body name="arm"><joint name="elbow" type="hinge"/><geom size="0.1"/></body>'
     '</worldbody></mujoco>',
     "<MJCF string>: joint 'elbow' of body 'arm': hinge joints are not mapped (only a free joint, a rod, or "
     "three slide joints, a point mass)"),
    (_xml(extra='<tendon><spatial name="t" stiffness="1"><site site="a"/><site site="c"/><site site="b"/>'
                '</spatial></tendon>'),
     "<MJCF string>: tendon 't': runs through 3 sites or pulleys: only a tendon through two sites maps to a "
     "cable"),
    (_xml(world='<geom name="drum" type="cylinder" pos="0.5 0 0.2" size="0.05 0.05"/>',
          extra='<tendon><spatial name="t" stiffness="1"><site site="a"/><geom geom="drum"/><site site="c"/>'
          '</spatial></tendon>'),
     "<MJCF string>: tendon 't': wraps around geom 'drum': wrapping tendons are not mapped"),
    (_xml('<geom name="hull" type="mesh" mesh="tetra" mass="0.1"/>',
          '<asset><mesh name="tetra" vertex="0 0 0 0.1 0 0 0 0.1 0 0 0 0.1"/></asset>'),
     "<MJCF string>: body 'r': geom 'hull' is a mesh that carries mass or collides: not mapped (a rod is made "
     "of capsules, cylinders, spheres, boxes and ellipsoids)"),
    (_xml(extra='<equality><connect name="pin" body1="r" body2="q" anchor="0 0 0"/></equality>'),
     "<MJCF string>: equality 'pin': equality constraints are not mapped (a scene has none)"),
    (_xml(extra='<tendon><spatial name="t"><site site="a"/><site site="c"/></spatial></tendon>'),
     "<MJCF string>: tendon 't': neither a stiffness nor a length limit (nothing makes it a cable)"),
    (_xml(world='<geom name="slope" type="plane" size="1 1 1" euler="10 0 0"/>'),
     "<MJCF string>: plane 'slope': its normal [0.0, -0.17364817766693033, 0.9848077530122081] is not +z "
     "(the ground is horizontal)"),
    (_xml('<geom name="plate" type="box" pos="0.5 0 0" size="0.1 0.1 0.01" mass="0.1"/>'
          '<geom name="peg" type="capsule" fromto="0 0.1 0 1 0.1 0" size="0.01"/>'),
     "<MJCF string>: body 'r': geom 'peg' does not lie along the axis of geom '#0' (not a rod)"),
])
def test_mjcf_refusals_name_the_element(xml, message):
    pytest.importorskip("mujoco")
    with pytest.raises(ts.SceneError) as error:
        ts.load_mjcf(xml)
    assert str(error.value) == message


def test_mjcf_drops_with_a_warning():
    """A push below the dead band's lower bound, a site along a rod (a cable ends at a node), world geoms:
    dropped, each said."""
    pytest.importorskip("mujoco")
    xml = _xml(world='<geom name="rock" type="sphere" pos="3 3 3" size="0.1"/>',
               extra='<tendon><spatial name="t" stiffness="100" springlength="0.2 0.5"><site site="b"/>'
                     '<site site="c"/></spatial><spatial name="u" stiffness="100" springlength="0 1"><site site="m"/>'
                     '<site site="c"/></spatial></tendon><actuator><motor name="drive" tendon="t"/></actuator>')
    with pytest.warns(MappingWarning) as record:
        imported = import_mjcf(xml)
    said = [str(w.message) for w in record]
    assert "<MJCF string>: world geoms 'rock' dropped (a scene's world is its ground)" in said
    assert ("<MJCF string>: tendon 't': MuJoCo also pushes while it is shorter than 0.2 m (springlength's lower "
            "bound); the cable goes slack instead") in said
    assert ("<MJCF string>: site 'm' (tendon 'u') lies at 0.5 along rod 'r': attached to its end node 'a', 0.5 m "
            "away") in said
    cable, other = imported.scene.cables
    assert cable.rest_length == 0.5 and imported.actuators == {"drive": "t"}
    assert cable.nodes == ("b", "c") and other.nodes == ("a", "c")


@pytest.mark.parametrize("files, message", [
    ({"m.yaml": "nodes: {a: [0, 0, 0]}\nrods: {}\n"},
     "m.yaml: unknown key 'rods' (allowed: nodes, pair_groups, builders, substructures, bond_groups)"),
    ({"m.yaml": "builders: {rod: {class: tgSphereInfo}}\n"},
     "m.yaml: builders: 'rod': class 'tgSphereInfo' is not an NTRT builder class (tgRodInfo, tgBasicActuatorInfo, "
     "tgBasicContactCableInfo, tgKinematicActuatorInfo, tgKinematicContactCableInfo)"),
    ({"m.yaml": "builders: {rod: {class: tgRodInfo, parameters: {mass: 3}}}\n"},
     "m.yaml: builders: 'rod': unknown tgRodInfo parameter 'mass' (allowed: radius, density, friction, "
     "roll_friction, restitution)"),
    ({"m.yaml": "builders: {box: {class: tgBoxInfo}}\n"},
     "m.yaml: builders: 'box': class tgBoxInfo: boxes are not mapped (a scene has rods)"),
    ({"m.yaml": "nodes: {a: [0, 0, 0], b: [1, 0, 0]}\npair_groups: {rod: [[a, c]]}\n"},
     "m.yaml: pair_groups: 'rod': unknown node 'c'"),
    ({"m.yaml": "nodes: {a: [0, 0, 0], b: [10, 0, 0], c: [0, 5, 0]}\n"
                "pair_groups: {rod: [[a, b]], string: [[b, c]]}\n"},
     "m.yaml: pair_groups: 'string': node 'c' lies on no rod (NTRT anchors a string on a rigid body)"),
    ({"m.yaml": "nodes: {a: [0, 0, 0], b: [10, 0, 0], c: [0, 5, 0], d: [10, 5, 0]}\n"
                "pair_groups: {rod: [[a, b], [c, d]], string: [[a, c]]}\n"
                "builders: {string: {class: tgBasicActuatorInfo, parameters: {stiffness: 10, pretension: 500}}}\n"},
     "m.yaml: pair_groups: 'string': string 'string0': pretension 500 leaves a rest length -4.5 m <= 0 (length "
     "0.5 m, stiffness 10)"),
    ({"m.yaml": "substructures: {a: {path: m.yaml}}\n"}, "m.yaml: includes itself (through m.yaml)"),
    ({"m.yaml": "substructures: {a/b: {path: c.yaml}}\nbond_groups: {string: {a/b/node_edge: [[x, y]]}}\n",
      "c.yaml": "nodes: {x: [0, 0, 0]}\n"},
     "m.yaml: bond_groups: 'string': 'a/b/node_edge': node_edge bonds are not mapped (only node_node)"),
    ({"m.yaml": "nodes: [1, 2]\n"}, "m.yaml: nodes: must be a mapping, got [1, 2]"),
    ({"m.yaml": "nodes: {a: [0, 0]}\n"}, "m.yaml: nodes: 'a' must be a list of 3 numbers, got [0, 0]"),
])
def test_ntrt_refusals_name_the_element(tmp_path, monkeypatch, files, message):
    monkeypatch.chdir(tmp_path)
    for name, text in files.items():
        Path(name).write_text(text)
    with pytest.raises(ts.SceneError) as error:
        ts.load_ntrt("m.yaml")
    assert str(error.value) == message


# ------------------------------------------------------------------------------------------- the verb
def test_import_verb_writes_the_scene_or_nothing(tmp_path, capsys):
    from tensegrity_sim.cli import main
    out = tmp_path / "robot.yaml"
    assert main(["import", str(PRISM), "--out", str(out)]) == 0
    assert ts.load_scene(out) == ts.load_ntrt(PRISM)
    assert out.read_text().startswith(f"# Imported from {PRISM} by tensegrity-sim import.\n")
    bad = tmp_path / "bad.yaml"
    bad.write_text("nodes: {a: [0, 0]}\n")
    assert main(["import", str(bad), "--out", str(tmp_path / "none.yaml")]) == 2
    assert capsys.readouterr().err == f"tensegrity-sim import: error: {bad}: nodes: 'a' must be a list of 3 " \
                                      f"numbers, got [0, 0]\n"
    assert main(["import", str(THREE_BAR), "--out", str(out), "--length-scale", "2"]) == 2
    assert capsys.readouterr().err == f"tensegrity-sim import: error: --length-scale: applies to an NTRT YAML " \
                                      f"file, not to {THREE_BAR} (MJCF is in metres)\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.yaml", "robot.yaml"]


def test_importing_the_package_reads_no_file_format():
    """``import tensegrity_sim`` imports neither tensegrity_sim.io nor MuJoCo; ts.load_mjcf imports io only."""
    code = ("import sys, tensegrity_sim as ts; a = {'mujoco', 'tensegrity_sim.io'} & set(sys.modules); "
            "ts.load_mjcf; b = 'mujoco' in sys.modules; print(sorted(a), b)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=Path(__file__).resolve().parents[1])
    assert out.stdout.strip() == "[] False"
