"""Ground contact with Coulomb friction (issue 11), both methods: closed forms and conservation laws."""
import warnings

import numpy as np
import pytest

import tensegrity_sim as ts
from tensegrity_sim.methods.contact.friction import FrictionalSolver

METHODS = ["inextensible", "elastic", "elastic-reference"]
G, MU = 9.81, 0.5


def simulator(scene, method, dt=1e-3):
    """A Simulator of ``scene`` with ``method``; "elastic" steps the ground in the compiled loop
    (``elastic/_ground_kernels.py``), "elastic-reference" in its numpy reference (friction.py's QP fixed point)."""
    sim = ts.Simulator(scene, method=method.removesuffix("-reference"), dt=dt)
    if method == "elastic-reference":
        sim._method.compiled = False
    elif method == "elastic":
        assert sim._method.has_ground_loop() == (scene.ground is not None)
    return sim


def strut(v0=0.0, theta=0.0, mu=MU, height=0.0):
    """A rigid 1 m strut (radius 1 cm, 1 kg per end) lying on the ground along x, moving at ``v0`` along x,
    under gravity tilted by ``theta`` towards +x (a slope of angle theta)."""
    return ts.Scene.from_dict({
        "gravity": [G * np.sin(theta), 0.0, -G * np.cos(theta)],
        "ground": {"height": height, "friction": mu},
        "nodes": [{"name": "a", "position": [0, 0, height + 0.01], "mass": 1.0, "velocity": [v0, 0, 0]},
                  {"name": "b", "position": [1, 0, height + 0.01], "mass": 1.0, "velocity": [v0, 0, 0]}],
        "struts": [{"name": "s", "nodes": ["a", "b"], "stiffness": "rigid", "radius": 0.01}]})


# ---------------------------------------------------------------------------------------------- scene keys
@pytest.mark.parametrize("edit, message", [
    ({"ground": {"friction": -0.1}}, "ground: friction must be >= 0, got -0.1"),
    ({"ground": {"restitution": 1.5}}, "ground: restitution must be in [0, 1], got 1.5"),
    ({"ground": {"height": float("nan")}}, "ground: height must be finite, got nan"),
    ({"ground": {"mu": 0.3}}, "ground: unknown key 'mu' (allowed: friction, height, restitution)"),
    ({"ground": [0.0]}, "ground: must be a mapping, got list"),
    ({"contact": {"friction": -1}}, "contact: friction must be >= 0, got -1.0"),
    ({"contact": {"restitution": -0.5}}, "contact: restitution must be in [0, 1], got -0.5"),
    ({"contact": {"response": "yes"}}, "contact: response must be true or false, got 'yes'"),
    ({"contact": {"response": True, "kinds": []}}, "contact: response: true needs member kinds to check "
                                                   "(kinds is empty)"),
])
def test_scene_keys_refused_with_exact_message(edit, message):
    raw = strut().to_dict()
    raw.update(edit)
    with pytest.raises(ts.SceneError) as err:
        ts.Scene.from_dict(raw, source="s.yaml")
    assert str(err.value) == f"s.yaml: {message}"


def test_scene_keys_round_trip():
    raw = strut().to_dict()
    raw["ground"] = {"height": -0.5, "friction": 0.8, "restitution": 0.25}
    raw["contact"] = {"kinds": ["strut_strut"], "response": False, "friction": 0.3, "restitution": 0.1}
    scene = ts.Scene.from_dict(raw)
    assert scene.ground == ts.scene.Ground(-0.5, 0.8, 0.25)
    assert scene.contact_response == ts.scene.ContactResponse(False, 0.3, 0.1)
    assert ts.Scene.from_dict(scene.to_dict()) == scene
    assert "ground" not in ts.load_scene("prism3").to_dict()


# ---------------------------------------------------------------------------------------------- friction
@pytest.mark.parametrize("method", METHODS)
def test_sliding_strut_stops_at_the_closed_form(method):
    v0 = 2.0
    sim = simulator(strut(v0), method)
    tr = sim.run(duration=0.6)
    t_stop, d_stop = v0 / (MU * G), v0 ** 2 / (2 * MU * G)
    stopped = np.flatnonzero(tr.velocities[:, 0, 0] == 0.0)
    assert stopped.size and abs(tr.time[stopped[0]] - t_stop) <= 0.01 * t_stop
    assert np.abs(tr.velocities[stopped[0]:]).max() <= 1e-15   # at rest from then on, to round-off
    assert abs(tr.positions[-1, 0, 0] - d_stop) <= 0.01 * d_stop
    assert np.abs(tr.positions[:, :, 2] - 0.01).max() <= 1e-4
    # the reported friction is mu times the normal impulse while sliding, the normal impulse the weight
    sliding = tr.velocities[:, 0, 0] > 1e-12
    imp = tr.contact_impulses[sliding]
    np.testing.assert_allclose(imp[:, :, 2], G * 1e-3, rtol=1e-12)
    np.testing.assert_allclose(imp[1:, :, 0], -MU * G * 1e-3, rtol=1e-9)


@pytest.mark.parametrize("method", METHODS)
def test_no_creep_below_the_friction_angle(method):
    sim = simulator(strut(theta=np.arctan(0.9 * MU)), method)
    tr = sim.run(duration=1.0)
    assert np.abs(tr.positions - tr.positions[0]).max() < 1e-6


@pytest.mark.parametrize("method", METHODS)
def test_sliding_down_a_slope_accelerates_at_the_closed_form(method):
    theta = np.arctan(1.2 * MU)
    sim = simulator(strut(theta=theta), method)
    tr = sim.run(duration=0.5)
    accel = (tr.velocities[-1, 0, 0] - tr.velocities[99, 0, 0]) / (tr.time[-1] - tr.time[99])
    expected = G * (np.sin(theta) - MU * np.cos(theta))
    assert abs(accel - expected) <= 0.01 * expected
    assert np.abs(tr.positions[:, :, 2] - 0.01).max() <= 1e-4


@pytest.mark.parametrize("method", METHODS)
def test_momentum_balance_with_the_reported_impulses(method):
    """M (v_f - v_i) = dt * weight + the ground's impulses, every step (the struts' impulses are internal)."""
    sim = simulator(strut(2.0, theta=0.3), method)
    v = sim.velocities
    for _ in range(50):
        r = sim.step()
        change = (r.velocities - v).sum(axis=0)           # unit masses
        weight = 2.0 * 1e-3 * np.array([G * np.sin(0.3), 0.0, -G * np.cos(0.3)])
        np.testing.assert_allclose(change, weight + r.contact_impulses.sum(axis=0), atol=1e-13)
        v = r.velocities


# ---------------------------------------------------------------------------------------------- impacts
@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("e", [0.0, 0.5, 0.8])
def test_point_mass_bounces_to_e_squared_h(method, e):
    scene = ts.Scene.from_dict({"gravity": [0, 0, -G], "ground": {"friction": 0.5, "restitution": e},
                                "nodes": [{"name": "p", "position": [0, 0, 1.0], "mass": 1.0}]})
    sim = simulator(scene, method)
    tr = sim.run(duration=1.0)
    z = tr.positions[:, 0, 2]
    impact = np.sqrt(2.0 / G)
    after = tr.time > impact + 2e-3
    assert z.min() >= -1e-12
    assert abs(z[after].max() - e * e) <= 1e-3
    begins = [c for c in tr.contacts if c.kind == "begin"]
    assert begins[0].members == ("p", "ground") and abs(begins[0].time - impact) <= 1e-3
    if e > 0:
        assert [c.kind for c in tr.contacts[:2]] == ["begin", "end"]
        assert abs(begins[0].normal_impulse - (1 + e) * G * impact) <= 0.01 * (1 + e) * G * impact


@pytest.mark.parametrize("method", METHODS)
def test_a_fixed_node_beside_the_ground_leaves_a_bounce_unchanged(method):
    """A fixed node (a support, here above the ground with a slack cable to the ball) never touches the
    ground: the ball bounces exactly as it does alone (the gaps are the free nodes' only)."""
    ball = {"name": "p", "position": [0, 0, 1.0], "mass": 1.0}
    alone = {"gravity": [0, 0, -G], "ground": {"friction": 0.5, "restitution": 0.5}, "nodes": [ball]}
    tied = dict(alone, nodes=[ball, {"name": "post", "position": [0.0, 0.0, 0.5], "fixed": True}],
                cables=[{"name": "c", "nodes": ["post", "p"], "stiffness": 100.0, "rest_length": 2.0}])
    runs = [simulator(ts.Scene.from_dict(d), method).run(duration=1.0) for d in (alone, tied)]
    assert np.array_equal(runs[0].positions[:, 0], runs[1].positions[:, 0])
    assert abs(runs[1].positions[:, 0, 2][runs[1].time > np.sqrt(2.0 / G) + 2e-3].max() - 0.25) <= 1e-3


def dropped(lift=0.3, damping=0.0, spin=1.0):
    """icosahedron_ground lifted by ``lift`` m, spinning at ``spin`` rad/s about z."""
    raw = ts.load_scene("icosahedron_ground").to_dict()
    raw["nodes"] = [dict(n, position=[n["position"][0], n["position"][1], n["position"][2] + lift],
                         velocity=[-spin * n["position"][1], spin * n["position"][0], 0.0]) for n in raw["nodes"]]
    raw["cables"] = [dict(c, damping=damping) for c in raw["cables"]]
    return ts.Scene.from_dict(raw)


@pytest.mark.parametrize("method, damping, duration, wobble", [("inextensible", 0.0, 1.0, 1e-12),
                                                               ("elastic", 300.0, 2.0, 1e-5),
                                                               ("elastic-reference", 300.0, 2.0, 1e-5)])
def test_dropped_icosahedron_lands_without_sinking_or_gaining_energy(method, damping, duration, wobble):
    """Landing spinning on a face: impacts, cable snaps (inextensible), friction modes; the ground's
    plastic impact and friction and the cables' snaps and damping only remove energy. ``wobble``
    (relative) is what a step may add: round-off for the inextensible method; for the elastic one
    velocity Verlet's energy error, which oscillates at O(h^2) instead of decreasing monotonically."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ts.LengthOffsetWarning)
        sim = simulator(dropped(damping=damping), method)
    energy = [sim.energy()["total"]]
    lowest = np.inf
    for _ in range(int(round(duration / 1e-3))):
        r = sim.step()
        energy.append(sim.energy()["total"])
        lowest = min(lowest, float((r.positions[:, 2] - 0.025).min()))
    assert lowest >= -1e-3
    assert np.diff(energy).max() <= wobble * energy[0]
    assert sim.energy()["kinetic"] < 1e-3 * (energy[0] - energy[-1])


# ---------------------------------------------------------------------------------------------- robot at rest
@pytest.mark.parametrize("method", METHODS)
def test_icosahedron_ground_starts_in_static_equilibrium(method):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ts.LengthOffsetWarning)
        sim = simulator(ts.load_scene("icosahedron_ground"), method)
    x0 = sim.positions
    tr = sim.run(duration=0.3)
    assert np.abs(tr.positions - x0).max() < 1e-12
    weight = float(sim.system.masses.sum()) * G
    np.testing.assert_allclose(tr.contact_impulses[:, :, 2].sum(axis=1), weight * 1e-3, rtol=1e-9)
    active = sim.active_contacts()
    assert sorted(c.members for c in active) == [("n0", "ground"), ("n4", "ground"), ("n8", "ground")]
    assert sum(c.normal_impulse for c in active) == pytest.approx(weight * 1e-3, rel=1e-9)
    assert all(np.hypot(*c.tangential_impulse[:2]) <= 0.8 * c.normal_impulse for c in active)


def test_icosahedron_resting_for_9_s_stays_in_the_step_kernel_as_its_reference_steps():
    """Issue 47: the inextensible icosahedron at rest on the ground, from 8.7 s on, met every other step a mode QP
    whose sticking rows and drift-correcting targets (1.3e-12 m/s, DAQP's primal_tol) DAQP called infeasible;
    NNLS, the backend's fallback, answered it by the Python path (3.4 ms a step, 100x the kernel's). The targets
    now yield to the velocity level for that QP in the kernel and in its reference alike: no step of 9 s leaves
    the step kernel, the robot stays put, and the reference (friction modes and QPs in numpy) steps on from
    the kernel's state to the same numbers without any fallback backend."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ts.LengthOffsetWarning)
        sims = [simulator(ts.load_scene("icosahedron_ground"), "inextensible") for _ in range(2)]
    x0 = sims[0].positions
    for sim in sims:
        sim.run(steps=100)
    method = sims[0]._method
    python_steps = []
    step_impl = method._step_impl
    method._step_impl = lambda state: python_steps.append(state.step_count) or step_impl(state)
    tr = sims[0].run(steps=9000, every=100)
    assert python_steps == []
    assert np.abs(tr.positions - x0).max() < 1e-12
    sims[1].run(steps=9000, every=9000)
    np.testing.assert_array_equal(sims[1].positions, sims[0].positions)
    sims[1]._method.compiled = False
    for _ in range(4):   # the degenerate QP every other step
        compiled, reference = (sim.run(steps=1) for sim in sims)
        for field in ("positions", "velocities", "impulses", "contact_impulses"):
            a, b = getattr(compiled, field), getattr(reference, field)
            assert np.abs(a - b).max() <= 1e-12 * max(np.abs(b).max(), 1e-300), field
    assert sims[1]._method.solver.inner.fallbacks == {}


def test_friction_fixed_point_reports_iterations():
    """Plain sliding needs the mode iteration's 2 QPs per solve (the normal impulse, then agreement)."""
    sim = ts.Simulator(strut(2.0), method="inextensible", dt=1e-3)
    sim.run(steps=5)
    solver = sim._method.solver
    assert isinstance(solver, FrictionalSolver) and solver.iterations <= 2


def test_a_frictional_problem_answered_only_near_the_tolerance_is_answered_and_counted(monkeypatch):
    """Where no Newton start meets the Coulomb law to its tolerance (here made 1e-18 relative, below the
    round-off of the resting icosahedron's statically indeterminate contacts, with the modes and the further
    starts skipped), the best answer is taken if it meets the law to ACCEPT_TOL of the momentum in play,
    and counted: the robot stays at rest, its weight on the ground; with ACCEPT_TOL = 1e-18 the same step is
    a FrictionError naming the contacts that miss the law (which of the three miss it at 1e-18 is round-off:
    all three with one machine's BLAS, n0 and n8 with an AMD EPYC's)."""
    from tensegrity_sim.methods.contact import friction

    for name, value in (("MAX_MODE_ITER", 0), ("_NSGS_SWEEPS", ()), ("_RESTARTS", 0), ("_DRIFT_ROUNDS", 0),
                        ("FIXED_POINT_TOL", 1e-18)):
        monkeypatch.setattr(friction, name, value)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ts.LengthOffsetWarning)
        sim = simulator(ts.load_scene("icosahedron_ground"), "inextensible")
    x0 = sim.positions
    tr = sim.run(steps=20)
    assert sim._method.solver.relaxed >= 20
    assert np.abs(tr.positions - x0).max() < 1e-12
    weight = float(sim.system.masses.sum()) * G
    np.testing.assert_allclose(tr.contact_impulses[:, :, 2].sum(axis=1), weight * 1e-3, rtol=1e-9)
    monkeypatch.setattr(friction, "ACCEPT_TOL", 1e-18)
    with pytest.raises(friction.FrictionError, match=r"\(no solution\): contacts 'n[048]' on the ground(, 'n[048]' on "
                                                     r"the ground)* miss the Coulomb law"):
        sim.step()


def test_drop_and_slide_against_mujoco_and_the_closed_form():
    """A strut dropped 4 cm while moving at 2 m/s: the landing's plastic impact takes mu times its normal
    impulse off the sliding speed (Coulomb's law for impulses), then friction stops it, at
    ``x = v0 t_fall + (v0 - mu v_impact)^2 / (2 mu g)``. Both methods land on that to 1e-5 relative;
    MuJoCo (elliptic cones, impratio 100, its soft contact) lands within 1e-3 m of it (measured 7.6e-4 m,
    after sinking 2.8 mm into the ground at the impact, where we sink none)."""
    mujoco = pytest.importorskip("mujoco")
    v0, gap = 2.0, 0.04
    scene = strut(v0, height=0.0)
    raw = scene.to_dict()
    for node in raw["nodes"]:
        node["position"][2] += gap
    scene = ts.Scene.from_dict(raw)
    closed = v0 * np.sqrt(2 * gap / G) + (v0 - MU * np.sqrt(2 * G * gap)) ** 2 / (2 * MU * G)
    for method in METHODS:
        tr = simulator(scene, method).run(duration=0.7)
        assert tr.positions[-1, 0, 0] == pytest.approx(closed, rel=1e-5)
        assert tr.positions[:, :, 2].min() >= 0.01 - 1e-12
    model = mujoco.MjModel.from_xml_string(f"""<mujoco>
      <option timestep="0.001" cone="elliptic" impratio="100" gravity="0 0 {-G}"/>
      <worldbody><geom type="plane" size="5 5 0.1" friction="{MU} 0 0"/>
        <body pos="0 0 {0.01 + gap}"><freejoint/>
          <geom type="capsule" fromto="0 0 0 1 0 0" size="0.01" mass="2" friction="{MU} 0 0"/></body>
      </worldbody></mujoco>""")
    data = mujoco.MjData(model)
    data.qvel[0] = v0
    mujoco.mj_step(model, data, nstep=700)
    assert abs(data.qpos[0] - closed) < 1e-3


def test_landing_and_snap_in_the_same_step_create_no_energy():
    """Node a lands while the slack cable to node b (moving away at the same speed) snaps taut at that
    very instant (t = 10.5 ms, inside a step). One inelastic impact with the ground row and the cable
    row: the least kinetic energy that keeps a off the ground and the cable from stretching is both
    nodes at rest, reached by the cable's impulse of 1 N*s alone (closed form: the projection of
    (-1, +1) m/s with equal masses onto {v_a >= 0, v_b <= v_a} is (0, 0))."""
    scene = ts.Scene.from_dict({"ground": {"friction": 0.5},
                                "nodes": [{"name": "a", "position": [0, 0, 0.0105], "mass": 1.0, "velocity": [0, 0, -1.0]},
                                          {"name": "b", "position": [0, 0, 0.5105], "mass": 1.0, "velocity": [0, 0, 1.0]}],
                                "cables": [{"name": "c", "nodes": ["a", "b"], "rest_length": 0.521}]})
    sim = ts.Simulator(scene, method="inextensible", dt=1e-3)
    energy = [sim.energy()["total"]]
    results = []
    for _ in range(30):
        results.append(sim.step())
        energy.append(sim.energy()["total"])
    assert np.diff(energy).max() <= 0.0 and energy[-1] <= 1e-24
    landing = results[10]
    assert [(c.kind, c.members) for c in landing.contacts] == [("begin", ("a", "ground"))]
    assert landing.contacts[0].time == pytest.approx(0.0105, abs=2e-9)   # TOUCH_TOL / 1 m/s
    assert landing.impulses[0] == pytest.approx(1.0, rel=1e-12)
    assert np.abs(landing.velocities).max() <= 1e-12
    assert min(r.positions[0, 2] for r in results) >= -1e-12


def test_slack_robot_landing_snaps_its_cables_on_the_ground_without_creating_energy():
    """icosahedron_ground with every cable 2 % longer than its length (all slack), dropped spinning: it
    lands on three nodes at once and its cables then snap taut one after another while it stands on
    them (the frictional contacts and the snaps in the same impacts); kinetic + gravity energy never
    grows beyond 1e-10 of itself and nothing sinks. Not round-off: a node that an impact lifts at 5e-7 m/s
    comes back within the step and sticks, and its friction impulse works on the mean of its start and end
    velocities (Moreau's midpoint), returning f . v_t / 2 (measured 4.5e-9 J at step 103, 2.7e-11 of the
    energy, since a node landing at a cut takes the impact law there, issue 47; the throws' bound,
    ``throw_cases.problems``, is 1e-7 of their scale)."""
    raw = dropped(lift=0.05, spin=0.5).to_dict()
    x = {n["name"]: np.array(n["position"]) for n in raw["nodes"]}
    for c in raw["cables"]:
        c["rest_length"] = 1.02 * float(np.linalg.norm(x[c["nodes"][0]] - x[c["nodes"][1]]))
    sim = ts.Simulator(ts.Scene.from_dict(raw), method="inextensible", dt=1e-3)
    energy, slack, snaps_on_ground, lowest = [sim.energy()["total"]], sim.slack(), 0, np.inf
    for _ in range(200):
        r = sim.step()
        energy.append(sim.energy()["total"])
        snaps_on_ground += bool((slack & ~r.slack).any() and (r.contact_impulses[:, 2] > 0).any())
        slack = r.slack
        lowest = min(lowest, float((r.positions[:, 2] - 0.025).min()))
    assert snaps_on_ground >= 3
    assert np.diff(energy).max() <= 1e-10 * energy[0]
    assert lowest >= -1e-9


# ---------------------------------------------------------------------------------------------- ROS outputs
def test_ground_events_and_impulses_survive_the_contacts_encoding():
    from tensegrity_sim.ros import messages as M
    from tensegrity_sim.ros.node_logic import decode_contacts, encode_contacts
    sim = ts.Simulator(strut(2.0), method="inextensible", dt=1e-3)
    events = list(sim.step().contacts)
    assert [e.members for e in events] == [("a", "ground"), ("b", "ground")]
    assert events[0].normal_impulse == pytest.approx(G * 1e-3, rel=1e-12)
    assert events[0].tangential_impulse[0] == pytest.approx(-MU * G * 1e-3, rel=1e-9)
    typename = "diagnostic_msgs/msg/DiagnosticArray"
    back = decode_contacts(M.deserialize(M.serialize(encode_contacts(events, M.header(1, "world")), typename),
                                         typename))
    for e, x in zip(back, events):
        assert (e.kind, e.members, e.time, e.distance, e.normal_impulse) == (
            x.kind, x.members, x.time, x.distance, x.normal_impulse)
        assert e.tangential_impulse.tobytes() == x.tangential_impulse.tobytes()


def test_markers_draw_the_ground_and_its_forces():
    from ros_helpers import make_logic
    logic, sent, _ = make_logic(strut(2.0), method="inextensible", publish_rate=1000.0)
    r = logic.step()
    logic.publish()
    markers = {m.ns: m for m in [msg for key, msg in sent if key == "markers"][-1].markers}
    assert {"ground", "contact_forces"} <= set(markers)
    grid = np.array([[p.x, p.y, p.z] for p in markers["ground"].points])
    assert len(grid) == 36 and np.all(grid[:, 2] == 0.0)
    lines = np.array([[p.x, p.y, p.z] for p in markers["contact_forces"].points]).reshape(-1, 2, 3)
    force = r.contact_impulses / 1e-3
    direction = (lines[:, 1] - lines[:, 0]) / np.linalg.norm(lines[:, 1] - lines[:, 0], axis=1)[:, None]
    np.testing.assert_allclose(direction, force / np.linalg.norm(force, axis=1)[:, None], atol=1e-12)
    np.testing.assert_array_equal(lines[:, 0, :2], r.positions[:, :2])


def test_a_reset_forgets_the_largest_ground_force_of_the_markers():
    """After a reset the ground forces are drawn against the forces of the new run alone, as a fresh
    node draws them (a replay of the new log starts from a fresh node): 30 N pressing the strut down
    before the reset must not shorten the lines after it."""
    from ros_helpers import make_logic

    def force_lines(sent):
        markers = {m.ns: m for m in [msg for key, msg in sent if key == "markers"][-1].markers}
        return np.array([[p.x, p.y, p.z] for p in markers["contact_forces"].points])

    fresh, fresh_sent, _ = make_logic(strut(), method="inextensible", publish_rate=1000.0)
    fresh.step()
    fresh.publish()
    logic, sent, _ = make_logic(strut(), method="inextensible", publish_rate=1000.0)
    logic.sim.set_external_forces({"a": [0.0, 0.0, -30.0]})
    logic.step()
    logic.publish()
    pressed = force_lines(sent)
    logic.reset()
    logic.step()
    logic.publish()
    after = force_lines(sent)
    np.testing.assert_array_equal(after, force_lines(fresh_sent))
    # the pressed node's line was the longest before the reset (the free node's ~G / (G + 30) of it),
    # and after it the free node's line is as long: drawn against the new run's largest force alone
    longest = np.linalg.norm(pressed[1] - pressed[0])
    assert np.linalg.norm(pressed[3] - pressed[2]) < 0.5 * longest
    assert np.linalg.norm(after[1] - after[0]) == pytest.approx(longest, rel=1e-12)


# ------------------------------------------------------------------------- command schedules in the loop
def _roll_schedule(scene, force: bool):
    """examples/roll.yaml's ramps (reel in, hold, let out), and with ``force`` a push on n3 stepped on
    mid-ramp and off again: rest lengths and forces both changing inside one run."""
    from pathlib import Path

    import yaml

    from tensegrity_sim.commands import parse_commands

    points = yaml.safe_load((Path(__file__).resolve().parents[1] / "examples" / "roll.yaml").read_text())
    if force:
        points += [{"time": 0.15, "forces": {"n3": [8.0, -3.0, 2.0]}}, {"time": 0.45, "forces": {"n3": [0, 0, 0]}}]
        points.sort(key=lambda p: p["time"])
        merged = []   # one point per time, as the format requires
        for p in points:
            if merged and merged[-1]["time"] == p["time"]:
                merged[-1].update({k: v for k, v in p.items() if k != "time"})
            else:
                merged.append(dict(p))
        points = merged
    return parse_commands(points, scene)


def _commanded_by_hand(scene, schedule, steps, every=1, dt=1e-3, method="elastic"):
    """A Simulator stepped one step at a time, each input set before the step where it changed (what
    ``tensegrity-sim run --commands`` did before schedules ran inside the loop)."""
    sim = simulator(scene, method, dt)
    return sim, sim.run(steps=steps, every=every, commands=schedule, callback=lambda k, r: None)


@pytest.mark.parametrize("method", ["elastic", "inextensible"])
@pytest.mark.parametrize("force", [False, True])
def test_a_schedule_inside_the_compiled_ground_loop_equals_commanding_each_step(force, method):
    """Simulator.run(commands=...) on the ground evaluates the schedule inside the compiled loop
    (``_ground_kernels``: each step's inputs, the start forces recomputed where they change; the inextensible
    ``_kernels.steps``: a step whose inputs changed starts with no cable known to hold, as after a command);
    against the same schedule set step by step: the same arithmetic, so the same numbers to round-off (the
    contact solver's warm starts differ: a step-by-step Simulator's come from steps it computed ahead). The
    inextensible robot, its motors stalling at the lock (about 2 ms of CPU a step), runs the first 450 steps, in
    which it has moved 0.33 m."""
    scene = ts.load_scene("icosahedron_ground")
    schedule = _roll_schedule(scene, force)
    steps = 1500 if method == "elastic" else 450
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")   # the inextensible method's prestress warning
        inside = simulator(scene, method)
        by_hand, ref = _commanded_by_hand(scene, schedule, steps, 7, method=method)
    assert inside._method.runs_commands()
    traj = inside.run(steps=steps, every=7, commands=schedule)
    assert np.abs(traj.positions[-1] - scene.positions).max() > 0.3   # it rolled
    np.testing.assert_allclose(traj.positions, ref.positions, rtol=0, atol=1e-12)
    np.testing.assert_allclose(traj.velocities, ref.velocities, rtol=0, atol=1e-11)
    np.testing.assert_allclose(traj.impulses, ref.impulses, rtol=0, atol=1e-12)
    # ground impulses: the block Newton's tolerance (1e-10 relative) apart, from the different warm starts
    np.testing.assert_allclose(traj.contact_impulses, ref.contact_impulses, rtol=0, atol=1e-9)
    assert [(e.kind, e.members) for e in traj.contacts] == [(e.kind, e.members) for e in ref.contacts]
    # the inputs in effect after the run: the schedule's at the last step's start
    np.testing.assert_array_equal(inside.rest_lengths, by_hand.rest_lengths)
    np.testing.assert_array_equal(inside.external_forces, by_hand.external_forces)
    # and the run goes on from there as the hand-commanded one does
    more = steps // 7
    np.testing.assert_allclose(inside.run(steps=more, commands=schedule).positions,
                               by_hand.run(steps=more, commands=schedule, callback=lambda k, r: None).positions,
                               rtol=0, atol=1e-12)


def test_a_command_every_step_steps_alone_as_a_look_ahead_of_one_step():
    """A controller that sets new rest lengths before every step gets each step from the method's ``step``
    (``Simulator._step_once``: no bookkeeping of steps ahead for one step) and its ground events from the
    detector's one-step ``changes``; the very numbers and events of looking one step ahead first (the path the
    step took before), bit for bit, through the roll's ramps, holds and landings."""
    scene = ts.load_scene("icosahedron_ground")
    schedule = _roll_schedule(scene, True)
    # (without strut-strut detection: a detector walks the steps computed ahead, and they are computed so)
    alone, ahead = (ts.Simulator(scene, method="elastic", dt=1e-3, contacts=()) for _ in range(2))
    base = scene.cable_rest_lengths
    steps = []
    for k in range(700):
        rest = schedule.rest_lengths_at(k * 1e-3, base)
        forces = schedule.forces_at(k * 1e-3)
        for sim in (alone, ahead):
            sim.set_rest_lengths(rest)
            if forces is not None:
                sim.set_external_forces(forces)
        assert k == 0 or ahead.look_ahead()   # (none before the first step, which checks the speeds)
        steps.append((alone.step(), ahead.step()))
        if k < 300:   # the ramp: a new length every step, so the step alone, nothing computed ahead
            assert alone._ahead is None
    assert sum(len(a.contacts) for a, _ in steps) > 0   # contacts began and ended
    for a, b in steps:
        for f in ("positions", "velocities", "impulses", "tensions", "slack", "contact_impulses"):
            np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
        assert len(a.contacts) == len(b.contacts)
        for x, y in zip(a.contacts, b.contacts):
            assert (x.kind, x.members, x.time, x.normal_impulse) == (y.kind, y.members, y.time, y.normal_impulse)
            np.testing.assert_array_equal(x.point_a, y.point_a)


def test_a_schedule_inside_the_compiled_ground_loop_against_the_numpy_reference():
    """The same run against the numpy reference (friction.py's QP fixed point per step, the schedule set
    step by step): two solvers of the contact problem, each to its tolerance."""
    scene = ts.load_scene("icosahedron_ground")
    schedule = _roll_schedule(scene, True)
    traj = simulator(scene, "elastic").run(steps=600, commands=schedule)
    ref = simulator(scene, "elastic-reference").run(steps=600, commands=schedule)
    np.testing.assert_allclose(traj.positions, ref.positions, rtol=0, atol=1e-8)
    np.testing.assert_allclose(traj.impulses, ref.impulses, rtol=0, atol=1e-8)


def test_a_batch_with_a_ground_runs_schedules_inside_its_compiled_loop():
    """BatchSimulator (numba, a ground): one schedule for every copy and one per copy, evaluated inside
    the compiled batch loop, against a Simulator per copy commanded step by step."""
    scene = ts.load_scene("icosahedron_ground")
    shared = _roll_schedule(scene, True)
    own = [shared, _roll_schedule(scene, False), shared]
    for commands in (shared, own):
        batch = ts.BatchSimulator(scene, 3, method="elastic", contacts=[])
        assert batch._engine.runs_commands()
        traj = batch.run(steps=900, every=3, commands=commands)
        for b in range(3):
            schedule = commands[b] if isinstance(commands, list) else commands
            sim = ts.Simulator(scene, method="elastic", contacts=[])
            ref = sim.run(steps=900, every=3, commands=schedule, callback=lambda k, r: None)
            np.testing.assert_allclose(traj.positions[b], ref.positions, rtol=0, atol=1e-12)
            np.testing.assert_allclose(traj.impulses[b], ref.impulses, rtol=0, atol=1e-12)
            np.testing.assert_array_equal(batch.rest_lengths[b], sim.rest_lengths)
            np.testing.assert_array_equal(batch.external_forces[b], sim.external_forces)


@pytest.mark.parametrize("apart", ["rest_lengths", "forces"])
def test_a_batch_schedule_over_copies_whose_rest_lengths_or_forces_differ(apart):
    """One schedule (no forces) over two copies that differ only in their held rest lengths, or only in their held
    forces: the compiled loop takes the inputs that every copy shares as one column and the others copy by copy
    (an environment's copies: each reels its own cables, none has a force); each copy as a Simulator commanded
    step by step."""
    scene = ts.load_scene("icosahedron_ground")
    schedule = _roll_schedule(scene, False)
    rest = np.tile(scene.cable_rest_lengths, (2, 1))
    forces = np.zeros((2, len(scene.nodes), 3))
    if apart == "rest_lengths":
        rest[1, 0] *= 0.9     # c0: a cable the schedule does not name, so it stays apart
    else:
        forces[1, 3] = [6.0, -2.0, 1.0]
    batch = ts.BatchSimulator(scene, 2, method="elastic", contacts=[])
    batch.set_rest_lengths(rest)
    batch.set_external_forces(forces)
    traj = batch.run(steps=400, every=5, commands=schedule)
    for b in range(2):
        sim = ts.Simulator(scene, method="elastic", contacts=[])
        sim.set_rest_lengths(rest[b])
        sim.set_external_forces(forces[b])
        ref = sim.run(steps=400, every=5, commands=schedule, callback=lambda k, r: None)
        np.testing.assert_allclose(traj.positions[b], ref.positions, rtol=0, atol=1e-12)
        np.testing.assert_allclose(traj.impulses[b], ref.impulses, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(batch.external_forces[b], sim.external_forces)
    assert np.abs(traj.positions[0, -1] - traj.positions[1, -1]).max() > 1e-3   # the copies went apart


def test_the_batch_ground_loops_parallel_kernel_is_its_own_and_equals_the_serial_one(monkeypatch):
    """The batch's ground loop with ``parallel=True`` has a name of its own (numba names cache files after the
    function: before the loops had names of their own, the parallel one was only ever the serial one's cached
    code, and did not compile; on CI's cold cache it compiles here), and with per-copy schedules each copy is bit
    for bit the serial loop's numbers."""
    from tensegrity_sim.methods.elastic import _ground_kernels as gk

    assert gk.ground_steps.targetoptions.get("parallel") and not gk.ground_steps_serial.targetoptions.get("parallel")
    assert gk.ground_steps.py_func.__name__ != gk.ground_steps_serial.py_func.__name__
    scene = ts.load_scene("icosahedron_ground")
    own = [_roll_schedule(scene, True), _roll_schedule(scene, False)]
    runs = {}
    for name, kernel in (("serial", gk.ground_steps_serial), ("parallel", gk.ground_steps)):
        monkeypatch.setattr(gk, "ground_steps", kernel)
        runs[name] = ts.BatchSimulator(scene, 2, method="elastic", contacts=[]).run(steps=400, every=7, commands=own)
    for field in ("positions", "velocities", "impulses", "slack"):
        np.testing.assert_array_equal(getattr(runs["parallel"], field), getattr(runs["serial"], field))
    assert np.ptp(runs["serial"].positions[:, -1, :, 0], axis=0).max() > 0.01   # the two copies' schedules differ


def test_run_refuses_a_schedule_for_another_scene():
    scene = ts.load_scene("icosahedron_ground")
    other = _roll_schedule(scene, False)
    sim = simulator(ts.load_scene("prism3"), "elastic")
    with pytest.raises(ValueError, match="commands: a schedule for 12 nodes, the scene has 6"):
        sim.run(steps=2, commands=other)
    with pytest.raises(ValueError, match="commands must be a CommandSchedule"):
        sim.run(steps=2, commands="roll.yaml")
    assert sim.step_count == 0


def test_the_ground_detectors_changes_are_its_steps_events():
    """GroundDetector.changes (compiled) flags exactly the steps at which its step() (numpy) finds an event: a
    contact beginning or ending (gap within TOUCH_TOL or pushed by the ground, free nodes only), over random
    chunks with nodes on the tolerance's edge, pushed or not, fixed or free."""
    from tensegrity_sim.methods.contact.friction import TOUCH_TOL

    sim = ts.Simulator(ts.load_scene("icosahedron_ground"), method="elastic", dt=1e-3)
    detector = sim._ground
    rng = np.random.default_rng(5)
    n = len(detector.radii)
    flagged = 0
    for trial in range(200):
        k = int(rng.integers(1, 9))
        x = np.zeros((k, n, 3))
        edge = detector.radii + detector.height + TOUCH_TOL   # a node's height at the tolerance's edge
        x[..., 2] = edge + rng.choice([-1e-3, 0.0, 1e-3], size=(k, n))
        impulses = np.zeros((k, n, 3))
        impulses[..., 2] = rng.choice([0.0, 0.0, 1e-9], size=(k, n))
        detector.free = rng.random(n) > 0.1
        detector._inside = rng.random(n) > 0.5
        changed = detector.changes(x, impulses)
        inside = detector._inside.copy()
        for j in range(k):   # the reference: step() one step at a time, its events
            events = detector.step(x[j - 1] if j else x[j], x[j], np.zeros((n, 3)), 0.0, 1e-3, impulses[j])
            assert changed[j] == bool(events), (trial, j)
        flagged += changed.sum()
        detector._inside = inside
    assert 100 < flagged < 1000   # both kinds of steps were seen


def test_the_physical_tolerance_is_a_millionth_of_the_weight_times_the_step_at_rest():
    """A structure at rest has, over one step, the free velocity g dt on every node: the momentum in play is
    its weight times the step, and an answer may miss the Coulomb law by ACCEPT_TOL of that (issue 47), not
    by round-off of one contact's sliver of the load (the 1.8e-15 N*s that stopped a prism dropped 5 cm)."""
    from tensegrity_sim.methods import contact

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ts.LengthOffsetWarning)
        sim = simulator(ts.load_scene("icosahedron_ground"), "inextensible")
    solver = sim._method.solver
    free = sim.system.masses > 0
    v0 = np.tile([0.0, 0.0, -G * 1e-3], (int(free.sum()), 1))
    weight_step = float(sim.system.masses.sum()) * G * 1e-3
    tol = solver._physical_tol(v0, np.zeros(3))
    assert tol == pytest.approx(0.5 * contact.friction.ACCEPT_TOL * weight_step, rel=1e-12)
    assert solver._physical_tol(v0, np.array([10.0 * weight_step])) == pytest.approx(10.0 * tol, rel=1e-12)
