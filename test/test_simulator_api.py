"""The Python API of contract §2: shapes, partial updates by name, refusals that change nothing."""
import math
import warnings

import numpy as np
import pytest

import tensegrity_sim as ts
from conftest import deadband_dict


@pytest.fixture
def sim():
    s = ts.Simulator(ts.Scene.from_dict(deadband_dict()), method="elastic", dt=1e-3)
    s.run(steps=10)
    return s


def snapshot(sim):
    return (sim.time, sim.positions, sim.velocities, sim.rest_lengths, sim.external_forces)


def assert_unchanged(before, sim):
    after = snapshot(sim)
    assert before[0] == after[0]
    for a, b in zip(before[1:], after[1:]):
        np.testing.assert_array_equal(a, b)


BAD_REST = [
    ({"nope": 1.0}, "rest_lengths: unknown name 'nope' (known: cl, cr)"),
    ({"cl": -1.0}, "rest_lengths['cl']: must be > 0, got -1.0"),
    ({"cl": 0.0}, "rest_lengths['cl']: must be > 0, got 0.0"),
    ({"cl": math.nan}, "rest_lengths['cl'] must be finite, got nan"),
    ({"cl": [1.0, 2.0]}, "rest_lengths['cl'] must be a number, got shape (2,)"),
    ({"cl": "long"}, "rest_lengths['cl'] must be numbers, got 'long'"),
    ([1.0, 2.0, 3.0], "rest_lengths must be an array of shape (2,), got shape (3,)"),
    ([1.0, math.inf], "rest_lengths must be finite, got [1.0, inf]"),
    ({"cl": 10 ** 400}, "rest_lengths['cl'] must be numbers, got an integer of 401 digits"),
    ({"cl": 1j}, "rest_lengths['cl'] must be numbers, got 1j"),
    ({("cl",): 1.0}, "rest_lengths: unknown name ('cl',) (known: cl, cr)"),
    # a float64 array of the right shape (a controller's each step) is checked on a path of its own
    (np.array([1.0, np.nan]), "rest_lengths must be finite, got array([ 1., nan])"),
    (np.array([np.inf, 1.0]), "rest_lengths must be finite, got array([inf, 1.])"),
    (np.array([1.0, -np.inf]), "rest_lengths must be finite, got array([ 1., -inf])"),
    (np.array([1.0, -1.0]), "rest_lengths['cr']: must be > 0, got -1.0"),
    (np.array([0.0, 1.0]), "rest_lengths['cl']: must be > 0, got 0.0"),
    (np.array([[1.0, 1.0]]), "rest_lengths must be an array of shape (2,), got shape (1, 2)"),
]


@pytest.mark.parametrize("values, message", BAD_REST, ids=[m for _, m in BAD_REST])
def test_bad_rest_lengths_refused_state_unchanged(sim, values, message):
    before = snapshot(sim)
    with pytest.raises(ValueError) as err:
        sim.set_rest_lengths(values)
    assert str(err.value) == message
    assert_unchanged(before, sim)


def test_rest_lengths_array_taken_as_a_copy_and_the_same_lengths_change_nothing(sim):
    """The array path: new lengths are copied (the caller's array is theirs to write), the lengths in effect
    keep the steps computed ahead, and lengths whose sum overflows are still accepted (each is finite)."""
    new = np.array([1.0, 0.9])
    sim.set_rest_lengths(new)
    new[0] = 5.0
    np.testing.assert_array_equal(sim.rest_lengths, [1.0, 0.9])
    sim.step()
    ahead = sim.steps_ahead
    assert ahead > 0
    sim.set_rest_lengths(np.array([1.0, 0.9]))
    assert sim.steps_ahead == ahead
    sim.set_rest_lengths(np.array([1e308, 1e308]))
    np.testing.assert_array_equal(sim.rest_lengths, [1e308, 1e308])
    assert sim.steps_ahead == 0


BAD_FORCES = [
    ({"ghost": [0, 0, 1]}, "external_forces: unknown name 'ghost' (known: left, mass, right)"),
    ({"mass": [0, 1]}, "external_forces['mass'] must be an array of shape (3,), got shape (2,)"),
    ({"mass": [0, math.nan, 1]}, "external_forces['mass'] must be finite, got [0, nan, 1]"),
    (np.zeros((2, 3)), "external_forces must be an array of shape (3, 3), got shape (2, 3)"),
    ({"mass": [0, [1], 2]}, "external_forces['mass'] must be numbers, got [0, [1], 2]"),
    (np.array(["a"] * 3), "external_forces must be numbers, got array(['a', 'a', 'a'], dtype='<U1')"),
]


@pytest.mark.parametrize("values, message", BAD_FORCES, ids=[m for _, m in BAD_FORCES])
def test_bad_forces_refused_state_unchanged(sim, values, message):
    before = snapshot(sim)
    with pytest.raises(ValueError) as err:
        sim.set_external_forces(values)
    assert str(err.value) == message
    assert_unchanged(before, sim)


def test_partial_updates_by_name(sim):
    sim.set_rest_lengths({"cr": 0.5})
    np.testing.assert_array_equal(sim.rest_lengths, [1.1, 0.5])
    sim.set_external_forces({"mass": [1.0, 2.0, 3.0]})
    sim.set_external_forces({"left": [0.0, 0.0, 1.0]})
    np.testing.assert_array_equal(sim.external_forces, [[0, 0, 1], [1, 2, 3], [0, 0, 0]])


def test_shortened_cable_pulls_immediately(sim):
    """A rest-length command takes effect at the next step (the cached forces are dropped)."""
    sim.set_rest_lengths({"cr": 0.5})  # the mass is near the centre: cr is now stretched by ~0.5 m
    v_before = sim.velocities[1, 0]
    r = sim.step()
    assert r.tensions[1] > 0.9 * 50.0 * 0.45 and not r.slack[1]
    assert r.velocities[1, 0] - v_before > 0.9 * 1e-3 * 50.0 * 0.45 / 2.0


def test_step_and_run_shapes(sim):
    r = sim.step()
    assert r.positions.shape == (3, 3) and r.impulses.shape == (2,) and r.slack.dtype == bool
    assert r.contacts == ()
    np.testing.assert_allclose(r.tensions, r.impulses / 1e-3, rtol=1e-15)
    assert r.time == pytest.approx(11e-3, abs=1e-15)
    traj = sim.run(duration=0.05)
    assert traj.time.shape == (50,) and traj.positions.shape == (50, 3, 3) and traj.slack.shape == (50, 2)
    assert traj.time[-1] == pytest.approx(61e-3, abs=1e-15) and traj.contacts == []
    # results are copies: changing them does not touch the simulator
    r.positions[:] = 99.0
    assert not np.any(sim.positions == 99.0)


def test_reset_returns_to_the_scene():
    scene = ts.Scene.from_dict(deadband_dict())
    sim = ts.Simulator(scene, method="elastic", dt=1e-3)
    first = sim.run(steps=20)
    sim.set_rest_lengths({"cl": 0.3})
    sim.reset()
    again = sim.run(steps=20)
    np.testing.assert_array_equal(first.positions, again.positions)


@pytest.mark.parametrize("kwargs, message", [
    ({"method": "verlet"}, "method must be one of ['elastic', "),
    ({"dt": 0.0}, "dt must be a number of seconds >= 1e-09 (stamps are integer nanoseconds), got 0.0"),
    ({"dt": 5e-324}, "dt must be a number of seconds >= 1e-09 (stamps are integer nanoseconds), got 5e-324"),
    ({"dt": math.nan}, "dt must be finite, got nan"),
    ({"dt": "fast"}, "dt must be a number, got 'fast'"),
    ({"dt": 10 ** 400}, "dt is too large for a float: an integer of 401 digits"),
    ({"method": ["auto"]}, "method must be one of ['elastic', 'inextensible', 'massive', 'auto'], got ['auto']"),
    ({"solver": {}}, "solver must be one of ['daqp', 'nnls', 'osqp', 'sparse'], got {}"),
])
def test_bad_constructor_arguments(kwargs, message):
    with pytest.raises(ValueError) as err:
        ts.Simulator(ts.Scene.from_dict(deadband_dict()), **kwargs)
    assert str(err.value).startswith(message)


def test_run_arguments(sim):
    with pytest.raises(ValueError, match="exactly one of duration"):
        sim.run()
    with pytest.raises(ValueError, match="steps must be a whole number >= 0, got -1"):
        sim.run(steps=-1)


def test_energy_parts_closed_form():
    """One stretched cable, mass at rest: strain = k e^2 / 2; gravity = -m g.x; kinetic = m v^2 / 2."""
    d = deadband_dict(k=50.0, m=2.0, v0=0.0)
    d["nodes"][1]["position"] = [0.4, 0.0, 0.3]
    d["nodes"][1]["velocity"] = [0.0, 3.0, 0.0]
    d["gravity"] = [0.0, 0.0, -9.81]
    sim = ts.Simulator(ts.Scene.from_dict(d), method="elastic", dt=1e-3)
    e = sim.energy()
    stretch = math.hypot(1.4, 0.3) - 1.1
    assert e["strain"] == pytest.approx(0.5 * 50.0 * stretch ** 2, rel=1e-14)
    assert e["kinetic"] == pytest.approx(9.0, rel=1e-15)
    assert e["gravity"] == pytest.approx(2.0 * 9.81 * 0.3, rel=1e-15)
    assert e["total"] == pytest.approx(e["strain"] + 9.0 + 2.0 * 9.81 * 0.3, rel=1e-15)
    p, ang = sim.momentum()
    np.testing.assert_allclose(p, [0.0, 6.0, 0.0])
    np.testing.assert_allclose(ang, np.cross([0.4, 0.0, 0.3], [0.0, 6.0, 0.0]))


@pytest.mark.parametrize("method", sorted(ts.METHODS))
def test_external_force_impulse_balance(method):
    """Contract §2: with external forces, sum m (v_f - v_i) = dt sum f over any number of steps, here
    through cables going slack and snapping taut again under the pushes."""
    scene = ts.load_scene("prism3")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ts.LengthOffsetWarning)
        sim = ts.Simulator(scene, method=method, dt=1e-3)
    f = np.zeros((len(scene.nodes), 3))
    f[0] = [300.0, -100.0, 200.0]
    f[4] = [50.0, 50.0, 50.0]
    sim.set_external_forces(f)
    p0, _ = sim.momentum()
    traj = sim.run(steps=300)
    p1, _ = sim.momentum()
    np.testing.assert_allclose(p1 - p0, 300 * 1e-3 * f.sum(axis=0), rtol=1e-11)
    assert traj.slack.any()


def test_non_finite_step_is_refused_and_changes_nothing(sim):
    """Issue 13: a finite but absurd force used to turn the positions into NaN silently. Now the step
    raises NonFiniteError naming the node and the input, the state is as before, and once the force is
    taken back the run goes on exactly as a twin's that never had it."""
    twin = ts.Simulator(sim.scene, method=sim.method, dt=sim.dt)
    twin.run(steps=sim.step_count + 5)
    sim.run(steps=5)
    sim.set_external_forces({"mass": [1e300, 0.0, 0.0]})
    before = snapshot(sim)
    with np.errstate(over="ignore", invalid="ignore"), pytest.raises(ts.NonFiniteError) as err:
        sim.step()   # numpy warns of the overflow, the compiled kernel does not: neither is the point
    assert str(err.value) == (
        "the step from t = 0.015000 s gave non-finite values at node 'mass' (and 2 more) and cable 'cl' (and 1 "
        "more) (inputs: largest external force 1e+300 N at node 'mass'; largest speed 0.5 m/s at node 'mass'; "
        "largest coordinate 1 m at node 'left'; longest rest length 1.1 m of cable 'cl'; dt 0.001 s); the state "
        "is as before the step")
    assert isinstance(err.value, ts.StepError)
    assert_unchanged(before, sim)
    sim.set_external_forces({"mass": [0.0, 0.0, 0.0]})
    a, b = sim.run(steps=20), twin.run(steps=20)
    np.testing.assert_array_equal(a.positions, b.positions)
    np.testing.assert_array_equal(a.impulses, b.impulses)


def test_non_finite_step_in_a_compiled_run_fails_like_step(sim):
    """run() without a callback steps in the compiled loop, which has no per-step guard: it must still stop
    at the failing step with NonFiniteError and the state before that step (here the first)."""
    assert sim._method.has_loop()
    sim.set_external_forces({"mass": [1e300, 0.0, 0.0]})
    before = snapshot(sim)
    with np.errstate(over="ignore", invalid="ignore"), pytest.raises(ts.NonFiniteError, match="node 'mass'"):
        sim.run(steps=50)
    assert_unchanged(before, sim)


@pytest.mark.filterwarnings("ignore::tensegrity_sim.LengthOffsetWarning")   # the icosahedron is prestressed
@pytest.mark.parametrize("method", ["elastic", "inextensible"])
@pytest.mark.parametrize("how", ["step", "run"])
def test_absurd_speed_refused_at_the_first_step(method, how):
    """Issue 28: nodes starting at 1e100 m/s ran the elastic method for over 20 s of steps whose structure
    was lost in round-off. The first step (or run) refuses them with a StepError naming the fastest node
    and its speed, and nothing changes; a speed just under the limit (SPEED_LIMIT_LENGTHS shortest
    members per step) is stepped."""
    from tensegrity_sim.simulator import SPEED_LIMIT_LENGTHS
    d = ts.load_scene("icosahedron").to_dict()
    for node in d["nodes"]:
        node["velocity"] = [0.0, -1e100, 0.0]   # a translation: the same for the rigid struts' projection
    sim = ts.Simulator(ts.Scene.from_dict(d), method=method, dt=1e-3)
    with pytest.raises(ts.SpeedError) as err:
        sim.step() if how == "step" else sim.run(steps=1000)
    assert isinstance(err.value, ts.StepError)
    assert str(err.value).startswith("the step from t = 0.000000 s is refused: node 'n0' moves at 1e+100 m/s: "
                                     "in one step of 0.001 s it would move 1e+97 m")
    assert sim.step_count == 0 and np.array_equal(sim.velocities, ts.Scene.from_dict(d).velocities)
    shortest = float(sim.system.geometry(sim.scene.positions)[1].min())
    for node in d["nodes"]:
        node["velocity"] = [0.99 * SPEED_LIMIT_LENGTHS * shortest / 1e-3, 0.0, 0.0]   # a uniform translation
    fast = ts.Simulator(ts.Scene.from_dict(d), method=method, dt=1e-3)
    fast.step()
    assert fast.step_count == 1


def test_absurd_speed_fails_its_copy_only_at_the_first_step():
    """The batch's elastic engine refuses a copy starting at 1e100 m/s at step 1, as Simulator does; the
    other copies run as a Simulator would."""
    scene = ts.load_scene("icosahedron")
    v = np.zeros((3, len(scene.nodes), 3))
    v[1] = [0.0, 1e100, 0.0]
    batch = ts.BatchSimulator(scene, 3, method="elastic", velocities=v, contacts=())
    out = batch.run(steps=5)
    assert list(batch.failures) == [1] and batch.failures[1].startswith("step 1 (t = 0.001 s): node 'n0' moves at "
                                                                        "1e+100 m/s")
    assert np.isnan(out.positions[1]).all()
    single = ts.Simulator(scene, method="elastic", dt=1e-3, contacts=()).run(steps=5)
    np.testing.assert_allclose(out.positions[0], single.positions, rtol=0, atol=1e-12)


BAD_RUNS = [
    ({"steps": 10 ** 400}, "run: the trajectory of an integer of 401 digits steps would need over 1e300 bytes, "
                           "more than this machine's memory"),
    ({"steps": math.inf}, "steps must be a whole number >= 0, got inf"),
    ({"steps": "3"}, "steps must be a whole number >= 0, got '3'"),
    ({"steps": 2.5}, "steps must be a whole number >= 0, got 2.5"),
    ({"duration": 1e300}, "run: the trajectory of"),
    ({"duration": [1.0]}, "duration must be a number, got [1.0]"),
    ({"duration": 9e307, "dt_": 1e-9}, "duration / dt = 9e+307 / 1e-09 s is beyond the float range"),
    ({"steps": 2, "callback": "print"}, "callback must be callable, got 'print'"),
]


@pytest.mark.parametrize("kwargs, message", BAD_RUNS, ids=[m for _, m in BAD_RUNS])
def test_bad_run_arguments_refused_before_any_step(sim, kwargs, message):
    kwargs = dict(kwargs)
    if "dt_" in kwargs:
        sim = ts.Simulator(sim.scene, method=sim.method, dt=kwargs.pop("dt_"))
    before = snapshot(sim)
    with pytest.raises(ValueError) as err:
        sim.run(**kwargs)
    assert str(err.value).startswith(message)
    assert_unchanged(before, sim)
