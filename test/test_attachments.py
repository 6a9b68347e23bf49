"""Cables attached along a rod (issue 46, physics.md section 4c): a cable end ``{strut: s, at: w}`` lies at
``(1 - w) x_a + w x_b`` of the strut's nodes, moves with the same weights and shares its force by them.

Checked against: the closed form of a pinned horizontal uniform rod held level by a vertical cable at ``at``
(it carries ``m g / (2 at)``: ``m g`` at the middle, ``m g / 2`` at the tip; lumping the cable at a node
would not), the conservation of linear and angular momentum (a force at a point of the rod shared by the
weights has that point's torque), naming a strut's end either way (the same numbers, bit for bit), and the
fast paths (compiled step, compiled loop, batch, ground loop, JAX) against the numpy reference.
"""

import numpy as np
import pytest

import tensegrity_sim as ts
from tensegrity_sim.methods.base import State
from tensegrity_sim.methods.contact.detection import ContactDetector
from tensegrity_sim.methods.elastic import _kernels as kernels
from tensegrity_sim.scene import CONTACT_KINDS, Attachment, SceneError
from tensegrity_sim.system import System
from test_rods import HAVE_JAX, simulate


L, M, G = 1.2, 2.0, 9.81   # m, kg, m/s^2


def attached_icosahedron(ground=False):
    """The built-in icosahedron (thrown, spinning), eight of its cables moved from a strut's end node to a
    point along that strut (four by both ends), damped."""
    d = ts.load_scene("icosahedron_ground" if ground else "icosahedron").to_dict()
    rng = np.random.default_rng(3)
    on = {}
    for s in d["struts"]:
        on[s["nodes"][0]], on[s["nodes"][1]] = (s["name"], 0.0), (s["name"], 1.0)
        s["mass"] = 1.0
    for node in d["nodes"]:
        node["velocity"] = list(rng.normal(0.0, 0.3 if ground else 1.0, 3))
    for i, c in enumerate(d["cables"][:8]):
        for j in ([1] if i % 2 else [0, 1]):
            strut, end = on[c["nodes"][j]]
            c["nodes"][j] = {"strut": strut, "at": abs(end - 0.12 - 0.02 * i)}
        c["damping"] = 5.0
        del c["rest_length"]   # its length between its new end points ...
    length = np.linalg.norm(System(ts.Scene.from_dict(d)).cable_vectors(ts.Scene.from_dict(d).positions), axis=1)
    for c, cable_length in zip(d["cables"][:8], length):
        c["rest_length"] = 0.95 * cable_length   # ... less 5 %: taut as the icosahedron's other cables
    return ts.Scene.from_dict(d)


# ------------------------------------------------------------------ the scene format
def test_a_cable_end_on_a_strut_reads_writes_and_places_itself():
    scene = attached_icosahedron()
    assert scene.cables[0].nodes == (Attachment("s0", 0.12), Attachment("s2", 0.12))
    assert scene.cables[1].nodes == ("n0", Attachment("s2", 0.86))
    assert ts.Scene.from_dict(scene.to_dict()) == scene
    assert ts.Scene.from_dict(ts.Scene.from_dict(scene.to_dict()).to_dict()).to_dict() == scene.to_dict()
    system = System(scene)
    np.testing.assert_array_equal(system.attached, np.arange(8))
    x = scene.positions
    points = system.cable_points(x)
    index = {n: i for i, n in enumerate(scene.node_names)}
    struts = {s.name: s for s in scene.struts}
    for c, cable in enumerate(scene.cables):
        for j, end in enumerate(cable.nodes):
            if isinstance(end, str):
                expected = x[index[end]]
            else:
                a, b = (x[index[n]] for n in struts[end.strut].nodes)
                expected = (1 - end.at) * a + end.at * b
            np.testing.assert_allclose(points[c, j], expected, rtol=0, atol=1e-15)
    # a cable's rest length defaults to its length between its real end points
    d = scene.to_dict()
    del d["cables"][0]["rest_length"]
    fresh = ts.Scene.from_dict(d)
    assert fresh.cables[0].rest_length == pytest.approx(np.linalg.norm(points[0, 1] - points[0, 0]), rel=1e-15)
    assert fresh.cables[0].rest_length < 0.9 * scene.cables[9].rest_length   # not the nodes' distance


def _one_rod(ends, **cable):
    return {"name": "r", "nodes": [{"name": "a", "position": [0, 0, 0], "fixed": True},
                                   {"name": "b", "position": [L, 0, 0], "mass": 0.1},
                                   {"name": "h", "position": [0.5, 0, 1], "fixed": True}],
            "struts": [{"name": "s", "nodes": ["a", "b"], "stiffness": "rigid", "mass": M}],
            "cables": [{"name": "c", "nodes": ends, "stiffness": 1e4, **cable}]}


@pytest.mark.parametrize("ends, message", [
    (["h", {"strut": "t", "at": 0.5}], "cables[0] 'c' nodes[1]: strut: unknown strut 't'"),
    (["h", {"strut": "a", "at": 0.5}], "cables[0] 'c' nodes[1]: strut: unknown strut 'a'"),
    (["h", {"strut": "s", "at": 1.5}], "cables[0] 'c' nodes[1]: at must be in [0, 1], got 1.5"),
    (["h", {"strut": "s", "at": -0.1}], "cables[0] 'c' nodes[1]: at must be in [0, 1], got -0.1"),
    (["h", {"strut": "s", "at": "half"}], "cables[0] 'c' nodes[1]: at must be a number, got 'half'"),
    (["h", {"strut": "s"}], "cables[0] 'c' nodes[1]: missing required key 'at'"),
    ([{"strut": "s", "at": 0.5, "side": 1}, "h"], "cables[0] 'c' nodes[0]: unknown key 'side' (allowed: at, strut)"),
    (["h", 3], "cables[0] 'c': nodes: an end is a node name or {strut, at}, got 3"),
    (["h"], "cables[0] 'c': nodes must be a list of two ends (a node name or {strut, at}), got ['h']"),
    (["b", {"strut": "s", "at": 0.5}], "cables[0] 'c': nodes: a cable cannot join strut 's' to itself"),
    ([{"strut": "s", "at": 0.2}, {"strut": "s", "at": 0.7}], "a cable cannot join strut 's' to itself"),
    (["a", {"strut": "s", "at": 0.0}], "a cable cannot join strut 's' to itself (both ends on it)"),
    (["h", "h"], "cables[0] 'c': nodes: a member cannot join node 'h' to itself"),
])
def test_a_bad_cable_end_is_refused_in_one_line_naming_the_entry_and_field(ends, message):
    with pytest.raises(SceneError) as err:
        ts.Scene.from_dict(_one_rod(ends), source="rod.yaml")
    text = str(err.value)
    assert text.startswith("rod.yaml: cables[0] 'c'") and message in text and "\n" not in text


def test_a_cable_end_at_a_point_where_the_other_end_is_has_zero_length():
    d = _one_rod(["h", {"strut": "s", "at": 0.5}])
    d["nodes"][2]["position"] = [0.5 * L, 0, 0]
    with pytest.raises(SceneError, match=r"^r\.yaml: cables\[0\] 'c': nodes: zero-length member \('h' and 's' at "
                                         r"0\.5 coincide\)$"):
        ts.Scene.from_dict(d, source="r.yaml")


@pytest.mark.parametrize("at", [0.0, 1.0])
def test_an_end_at_a_struts_end_steps_the_numbers_of_naming_its_node(at):
    """``{strut: s, at: 0}`` is the strut's first node and ``at: 1`` its second, to the bit."""
    plain = attached_icosahedron().to_dict()
    plain["cables"] = [c for c in plain["cables"]
                       if all(isinstance(e, str) for e in c["nodes"])]   # the icosahedron's plain cables
    named = ts.Scene.from_dict(plain)
    moved = ts.Scene.from_dict(plain)
    d = moved.to_dict()
    strut = next(s for s in d["struts"] if d["cables"][0]["nodes"][1] in s["nodes"])
    if strut["nodes"][round(at)] != d["cables"][0]["nodes"][1]:
        strut["nodes"].reverse()
        named = ts.Scene.from_dict({**plain, "struts": d["struts"]})
    d["cables"][0]["nodes"][1] = {"strut": strut["name"], "at": at}
    moved = ts.Scene.from_dict(d)
    assert isinstance(moved.cables[0].nodes[1], Attachment) and not len(System(moved).attached)
    for path in ("reference", "run"):
        x0, v0, _ = simulate(named, path, 60, 1e-3)
        x1, v1, _ = simulate(moved, path, 60, 1e-3)
        np.testing.assert_array_equal(x1, x0)
        np.testing.assert_array_equal(v1, v0)


# ------------------------------------------------------------------ physics
def test_the_force_at_a_point_of_the_rod_has_that_points_force_and_torque():
    """The assembled node forces of a cable attached along a strut: the tension at each real end point, summed
    over the nodes it is shared between (force) and their moments (torque about any point) are the point's."""
    scene = attached_icosahedron()
    sim = ts.Simulator(scene, method="elastic", dt=1e-3)
    sim._method.compiled = False
    system = sim.system
    x = scene.positions + np.random.default_rng(0).normal(0.0, 0.01, scene.positions.shape)
    t, _, n = sim._method.tensions(x, np.zeros_like(x), 0.8 * scene.cable_rest_lengths)   # all taut
    points = system.cable_points(x)
    for c in system.attached:
        only = np.zeros_like(t)
        only[system.n_struts + c] = t[system.n_struts + c]
        f = system.assemble(only[:, None] * n)
        pull = only[system.n_struts + c] * n[system.n_struts + c]    # on end a, toward b
        assert only[system.n_struts + c] > 0
        np.testing.assert_allclose(f.sum(axis=0), np.zeros(3), atol=1e-12)
        origin = np.array([0.3, -2.0, 1.0])
        torque = np.cross(x - origin, f).sum(axis=0)
        np.testing.assert_allclose(torque, np.cross(points[c, 0] - origin, pull)
                                   + np.cross(points[c, 1] - origin, -pull), atol=1e-12)
        a0, a1 = system.cable_nodes[c, 0]
        w = system.cable_weights[c, 0]
        if a0 != a1:   # end a shared (1 - w, w) between the strut's nodes
            np.testing.assert_allclose(f[a1], w * pull, atol=1e-12)


@pytest.mark.parametrize("at", [0.25, 0.5, 1.0])
def test_a_cable_holds_a_pinned_uniform_rod_level_with_m_g_over_2_at(at):
    """Physics section 4c: a uniform rod pinned at one end, held level by a vertical cable at ``at``: the moments
    about the pin give ``T at L = m g L / 2``, ``T = m g / (2 at)`` (m g at the middle, m g / 2 at the tip). Run
    to rest from a slack start with a damped cable (compiled loop), then the equilibrium checked directly (zero
    acceleration) on the reference and the kernel."""
    k, c = 1e6, 2e3
    d = _one_rod(["h", {"strut": "s", "at": at}], damping=c)
    d["nodes"][1]["mass"] = 0.0
    d["nodes"][2]["position"] = [at * L, 0.0, 1.0]
    d["gravity"] = [0.0, 0.0, -G]
    d["cables"][0]["stiffness"] = k
    d["cables"][0]["rest_length"] = 1.0
    scene = ts.Scene.from_dict(d)
    sim = ts.Simulator(scene, method="elastic", dt=2e-5)
    sim.run(steps=30_000, every=30_000)
    tension = M * G / (2 * at)
    r = sim.step()
    assert r.tensions[0] == pytest.approx(tension, rel=1e-7)
    assert abs(r.positions[1, 2]) < 2 * tension / k / at   # level to the cable's stretch
    # at the exactly level pose with the cable stretched by T/k, nothing accelerates (the pin end is fixed)
    x = scene.positions.copy()
    rest = np.array([1.0 - tension / k])
    state = State(x, np.zeros_like(x), rest, np.zeros_like(x))
    acc = sim._method.accelerations(x, np.zeros_like(x), state).acc
    np.testing.assert_allclose(acc[1], 0.0, atol=1e-9)
    model = kernels.model_arrays(sim.system, sim._method.rigid)
    out = (np.empty((3, 3, 1)), np.empty((1, 1)), np.empty((1, 3, 1)))
    kernels.elastic_forces(x[..., None], np.zeros((3, 3, 1)), rest[:, None], np.zeros((3, 3, 1)), *model[:10], *out)
    np.testing.assert_allclose(out[0][1, :, 0], 0.0, atol=1e-9)
    if at < 1.0:   # the same tension at the strut's end node would not hold it: half the rod's weight is m g / 2
        assert abs(tension - M * G / 2) > 0.1 * M * G


PATHS = ["compiled", "run", "batch"] + (["jax"] if HAVE_JAX else [])


@pytest.mark.parametrize("path", PATHS)
def test_the_fast_paths_step_cables_along_rods_as_the_numpy_reference_does(path):
    scene = attached_icosahedron()
    x_ref, v_ref, ref = simulate(scene, "reference", 200, 1e-3)
    x, v, _ = simulate(scene, path, 200, 1e-3)
    assert np.max(np.abs(x - x_ref)) <= 1e-12 * max(1.0, float(np.max(np.abs(x_ref))))
    assert np.max(np.abs(v - v_ref)) <= 1e-12 * max(1.0, float(np.max(np.abs(v_ref))))
    # momentum through 200 steps of cables pulling at points along the rods (with their mass blocks), to round-off
    start = ts.Simulator(scene, method="elastic", dt=1e-3).momentum()
    end = ref.momentum()
    np.testing.assert_allclose(end[0], start[0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(end[1], start[1], rtol=0, atol=1e-12)


def test_the_composed_fourth_order_step_takes_cables_along_rods():
    """Order 4 without located switches composes the same primitive (``_composition_kernels``): against its
    numpy reference."""
    scene = attached_icosahedron()
    out = []
    for compiled in (False, True):
        sim = ts.Simulator(scene, method="elastic", dt=1e-3, order=4, locate_switches=False)
        sim._method.compiled = compiled
        out.append(np.array([sim.step().positions for _ in range(100)]))
    np.testing.assert_allclose(out[1], out[0], rtol=0, atol=1e-12)


def test_the_ground_loop_takes_cables_along_rods():
    """The elastic method's compiled ground loop calls the same force kernel: against the reference's ground step."""
    scene = attached_icosahedron(ground=True)
    x_ref, v_ref, _ = simulate(scene, "reference", 300, 1e-3)
    x, v, _ = simulate(scene, "run", 300, 1e-3)
    assert np.max(np.abs(x[-1] - x[0])) > 1e-3
    np.testing.assert_allclose(x, x_ref, rtol=0, atol=1e-9)
    np.testing.assert_allclose(v, v_ref, rtol=0, atol=1e-7)


# ------------------------------------------------------------------ what does not take them
def test_paths_that_join_two_nodes_refuse_a_cable_along_a_strut_clearly():
    scene = attached_icosahedron()
    with pytest.raises(ValueError, match=r"^method 'inextensible' does not take a cable attached along a strut "
                                         r"\(cable 'c0': its constraint rows join two nodes\); give the cables a "
                                         r"stiffness and use method 'elastic'$"):
        ts.Simulator(scene, method="inextensible", dt=1e-3)
    prism = ts.load_scene("prism3").to_dict()   # elastic struts: what the massive method takes
    prism["cables"][0]["nodes"] = [{"strut": prism["struts"][0]["name"], "at": 0.5}, prism["cables"][0]["nodes"][1]]
    del prism["cables"][0]["rest_length"]
    for cable in prism["cables"]:
        cable["mass"] = 0.05
    with pytest.raises(ValueError, match=r"^method 'massive' does not take a cable attached along a strut yet "
                                         r"\(cable 'c0'\); use method 'elastic'$"):
        ts.Simulator(ts.Scene.from_dict(prism), method="massive", dt=1e-4)
    assert ts.Simulator(ts.Scene.from_dict(prism), method="auto", dt=1e-4).method != "massive"
    with pytest.raises(ValueError, match=r"locates slack/taut switches only for cables between two nodes; cable "
                                         r"'c0' is attached along a strut: use locate_switches=False$"):
        ts.Simulator(scene, method="elastic", dt=1e-3, locate_switches=True)
    sim = ts.Simulator(scene, method="auto", dt=1e-3)
    assert sim.method_reason.startswith("elastic: cables attached along a strut (c0, c1, ")
    # member-contact detection checks node-to-node segments: the attached cables are left out of it
    system = System(scene)
    detector = ContactDetector(system, CONTACT_KINDS)
    cables = detector.members[detector.members >= system.n_struts] - system.n_struts
    np.testing.assert_array_equal(cables, np.arange(8, system.n_cables))


# ------------------------------------------------------------------ what shows them
def test_the_node_the_log_and_the_page_show_a_cable_where_it_is_attached(tmp_path):
    """The markers draw each cable from its real end points, the published (and logged) cable states measure it
    there, and the 3-D page's frames draw the logged run the same way."""
    from ros_helpers import make_logic
    from tensegrity_sim.cli import simulate as run_logged
    from tensegrity_sim.ros.offline import logged_run
    from tensegrity_sim.ros.record import read_log
    from tensegrity_sim.viz.page import build_figure, frame_indices

    scene = attached_icosahedron()
    system = System(scene)
    logic, sent, _ = make_logic(scene, publish_rate=1000.0)
    for _ in range(3):
        r = logic.step()
    logic.publish()
    messages = {key: msg for key, msg in sent}
    ends = system.cable_points(r.positions)
    assert not r.slack.any()
    drawn = np.array([[p.x, p.y, p.z] for p in next(m for m in messages["markers"].markers if m.ns == "cables").points])
    np.testing.assert_array_equal(drawn, ends.reshape(-1, 3))
    states = messages["cable_states"]
    length = np.linalg.norm(ends[:, 1] - ends[:, 0], axis=1)
    velocity_ends = system.cable_points(r.velocities)
    rate = np.einsum("ij,ij->i", velocity_ends[:, 1] - velocity_ends[:, 0], (ends[:, 1] - ends[:, 0]) / length[:, None])
    np.testing.assert_allclose(states.position, length, rtol=1e-14)
    np.testing.assert_allclose(states.velocity, rate, rtol=0, atol=1e-13)
    assert np.all(length[:8] < 0.95 * length[8:].min())   # the attached cables are shorter than their nodes' span

    path = tmp_path / "attached.mcap"
    sim = ts.Simulator(scene, method="elastic", dt=1e-3)
    with logged_run(sim, str(path)) as driver:
        run_logged(sim, 50, None, driver=driver)
    record = read_log(path)
    for k in range(len(record.times)):
        ends = system.cable_points(record.positions[k])
        np.testing.assert_allclose(record.lengths[k], np.linalg.norm(ends[:, 1] - ends[:, 0], axis=1), rtol=1e-14)
    picked = frame_indices(record, max_frames=5)
    fig = build_figure(record, picked)
    for frame, k in zip(fig.frames, picked):
        taut = frame.data[1]
        pts = np.column_stack([taut.x, taut.y, taut.z]).reshape(-1, 3, 3)[:, :2]
        expected = system.cable_points(record.positions[k])[~record.slack[k]]
        np.testing.assert_array_equal(pts, expected.astype(np.float32))
