"""Rest-length commands with inextensible cables: the motor's finite speed (``reel_speed``) and the
energy balance against the motor's work."""
import math
import warnings
from pathlib import Path

import numpy as np
import pytest

import tensegrity_sim as ts
from bench.analytic import bungee_dict
from tensegrity_sim.commands import load_commands

ROOT = Path(__file__).resolve().parents[1]


def _hanging(**options) -> ts.Simulator:
    """A 1 kg mass hanging at rest on a 1 m inextensible cable under gravity (no elastic member)."""
    return ts.Simulator(ts.Scene.from_dict(bungee_dict(drop=1.0)), method="inextensible", dt=1e-3, **options)


def test_a_jump_is_followed_at_the_motor_speed():
    """5 cm shorter at once, default 1 m/s: the rest length in effect moves 1 mm a step and lands exactly on
    the command after 50 steps; the commanded value is reported throughout. The exact motion: the motor's
    impulsive start gives the mass 1 m/s (impulse m w), the cable then carries its weight (m g dt a step),
    and when the motor stops the mass flies on (before the fix it left at 2 m/s)."""
    sim = _hanging()
    assert sim.method_settings["reel_speed"] == 1.0
    sim.set_rest_lengths({"c": 0.95})
    applied = []
    traj = sim.run(steps=60, callback=lambda k, r: applied.append(sim.applied_rest_lengths[0]))
    assert sim.rest_lengths[0] == 0.95
    np.testing.assert_allclose(applied[:49], 1.0 - 1e-3 * np.arange(1, 50), rtol=0, atol=1e-14)
    assert applied[49:] == [0.95] * 11
    np.testing.assert_allclose(traj.velocities[:50, 1, 2], 1.0, rtol=1e-12)
    assert traj.impulses[0, 0] == pytest.approx(1.0 + 9.81e-3, rel=1e-12)
    np.testing.assert_allclose(traj.impulses[1:50, 0], 9.81e-3, rtol=1e-10)
    # it lags the moving limit by half a step's reel, 0.5 mm, while the motor runs
    np.testing.assert_allclose(-traj.positions[:49, 1, 2], np.array(applied[:49]) + 5e-4, rtol=0, atol=1e-12)
    assert traj.slack[55:, 0].all() and np.all(traj.impulses[51:, 0] == 0.0)


def test_one_step_reel_balances_the_motors_work_to_round_off():
    """Without a speed limit (nor a force limit) a jump is a reel-in within one step at ``w = change / dt``: an
    impulsive start of the motor. As in the exact solution the mass leaves at ``w`` and gains half the motor's
    work ``y w`` (the other half is lost as in a perfectly inelastic impact), to round-off; that energy
    grows as 1/dt^2, which is why the default spreads a jump."""
    kinetic = []
    for dt in (1e-3, 5e-4):
        sim = ts.Simulator(ts.Scene.from_dict(bungee_dict(drop=1.0)), method="inextensible", dt=dt,
                           reel_speed=math.inf, reel_force=math.inf)
        before = sim.energy()["total"]
        sim.set_rest_lengths({"c": 0.99})
        r = sim.step()
        work = float(r.impulses[0]) * 0.01 / dt
        assert sim.energy()["total"] - before == pytest.approx(0.5 * work, rel=1e-12)
        assert sim.velocities[1, 2] == pytest.approx(0.01 / dt, rel=1e-12)
        kinetic.append(sim.energy()["kinetic"])
    assert kinetic[1] / kinetic[0] == pytest.approx(4.0, rel=1e-6)


def test_fast_command_on_prism3_keeps_the_energy_balance():
    """The hard-case row (bench/hard_cases.py): every cable of prism3 5 % shorter in one step. With the
    default motor speed the energy stays within 1e-3 of the balance net of the motor's work (7.8e-4 over
    10 s measured; a one-step reel gave 2.0e-2)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ts.LengthOffsetWarning)
        sim = ts.Simulator(ts.load_scene("prism3"), method="inextensible", dt=1e-3)
    e0 = sim.energy()["total"]
    sim.set_rest_lengths(sim.rest_lengths * 0.95)
    work, growth = 0.0, -math.inf
    for _ in range(300):
        old = sim.applied_rest_lengths
        r = sim.step()
        work += float(r.impulses @ (old - sim.applied_rest_lengths)) / sim.dt
        growth = max(growth, sim.energy()["total"] - e0 - work)
    assert 50.0 < work < 100.0   # 82 J measured; the one-step reel took 3.6e3 J
    assert growth < 1e-3 * (e0 + work)


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), "fast"])
def test_reel_speed_is_checked(bad):
    with pytest.raises(ValueError, match=r"reel_speed must be a number of m/s > 0 \(math.inf: no limit\), got"):
        _hanging(reel_speed=bad)
    with pytest.raises(ValueError, match=r"reel_force must be a number of N > 0 \(math.inf: no limit\), got"):
        _hanging(reel_force=bad)
    with pytest.raises(ValueError, match=r"reel_speed=2.0 is an option of the inextensible method; method 'elastic'"):
        ts.Simulator(ts.Scene.from_dict(bungee_dict()), method="elastic", reel_speed=2.0)


def test_a_motor_at_its_force_limit_pulls_at_that_force():
    """``reel_force`` 20 N on the hanging 1 kg mass, reeled in 5 cm: the motor cannot give the impulsive start
    (1 N*s in a step), so it pulls at 20 N and the mass rises at the constant ``F/m - g`` until it reaches the
    motor's 1 m/s; meanwhile the cable carries ``F dt`` a step, the motor stands where the cable ends (behind
    its free reel) and the stalled steps are counted."""
    force, dt = 20.0, 1e-3
    sim = _hanging(reel_force=force)
    assert sim.method_settings["reel_force"] == force
    sim.set_rest_lengths({"c": 0.95})
    traj = sim.run(steps=90)
    k = np.arange(1, 91)
    np.testing.assert_allclose(traj.velocities[:, 1, 2], k * dt * (force - 9.81), rtol=1e-12)
    np.testing.assert_allclose(traj.impulses[:, 0], force * dt, rtol=1e-12)
    assert sim.motor_stalls == 90
    # the motor reeled in what the mass rose, (F/m - g) t^2 / 2 = 41 mm of the 50 commanded
    _, length, _ = sim.system.geometry(sim.positions, sim.system.cable_ends)
    assert sim.applied_rest_lengths[0] == pytest.approx(length[0] - 0.5e-3, abs=1e-12)   # half a step's reel ahead
    assert length[0] == pytest.approx(1.0 - 0.5 * (force - 9.81) * 0.09 ** 2, rel=1e-12)


def test_a_rolling_command_the_locked_icosahedron_cannot_follow_stalls_its_motors():
    """Regression (issue 47): ``examples/roll.yaml`` on the inextensible ``icosahedron_ground`` (rigid struts)
    launched it 3.6 m up in 2 s: a few mm of reel bring the structure to a configuration where it locks, and
    motors of unlimited force drove it on with impulses of up to 3e4 N*s a step (12 kJ of kinetic energy at
    step 9). With motors of finite force (default 2 kN) they stall there: over the reel-in (0.3 s) the energy
    gained stays below the motors' work bound ``reel_force`` times the cable they reeled in, the centre rises
    less than 5 cm, the compiled loop matches the numpy reference to 1e-12 and the stalls are reported."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ts.LengthOffsetWarning)
        scene = ts.load_scene("icosahedron_ground")
    schedule = load_commands(ROOT / "examples" / "roll.yaml", scene)
    mass = scene.masses / scene.masses.sum()
    runs = []
    for compiled in (True, False):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ts.LengthOffsetWarning)
            sim = ts.Simulator(scene, method="inextensible", dt=1e-3)
        sim._method.compiled = compiled
        e0, rest0 = sim.energy()["total"], sim.applied_rest_lengths
        traj = sim.run(steps=300, commands=schedule)
        reeled = float(np.sum(rest0 - sim.applied_rest_lengths))
        assert 0.0 < reeled < 0.03   # 3 x 0.3 m commanded
        assert sim.energy()["total"] - e0 <= 2e3 * reeled
        rise = np.einsum("n,knj->kj", mass, traj.positions)[:, 2] - mass @ scene.positions[:, 2]
        assert rise.max() < 0.05
        assert sim.motor_stalls > 0
        runs.append(traj.positions)
    np.testing.assert_allclose(runs[0], runs[1], rtol=0, atol=1e-12)


def test_a_stalled_motor_starts_its_next_step_pulling():
    """A motor that pulled at its force starts the next step pulling (``InextensibleMethod._motor_modes``): in
    the hold of ``examples/roll.yaml`` on the locked ``icosahedron_ground`` (its three motors stalled at 2 kN,
    the robot rocking on its edges) each step solves its sub-step once or, for the landing, twice, where solving
    it with the motors following first took three solves; the stalled cables stay where they locked, to the
    tolerance of a locked structure's cable at its limit (the structure gives no more), and the step kernel
    takes the same steps to the bit."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ts.LengthOffsetWarning)
        scene = ts.load_scene("icosahedron_ground")
        sims = [ts.Simulator(scene, method="inextensible", dt=1e-3, contacts=()) for _ in range(2)]
    schedule = load_commands(ROOT / "examples" / "roll.yaml", scene)
    for sim in sims:
        sim.run(steps=400, commands=schedule)
    api, kernel = sims
    api._method.one_kernel = False   # each solve through the friction solver's API, counted
    solves = []
    solve = api._method.solver.solve

    def counted(*args):
        solves[-1] += 1
        return solve(*args)
    api._method.solver.solve = counted
    cables = [scene.cable_names.index(name) for name in ("c4", "c5", "c6")]
    ends = api.system.cable_ends[cables]
    locked = np.linalg.norm(np.diff(api.positions[ends], axis=1)[:, 0], axis=1)
    stalls = api.motor_stalls
    for _ in range(50):
        solves.append(0)
        a, b = api.step(), kernel.step()
        assert np.array_equal(a.positions, b.positions) and np.array_equal(a.impulses, b.impulses)
    assert api.motor_stalls - stalls == 150   # the three motors at their force in every step
    assert max(solves) <= 2 and sum(solves) < 75
    from tensegrity_sim.methods.inextensible.self_stress import TAUT_TOL   # (a locked structure's cable at its limit)
    np.testing.assert_allclose(np.linalg.norm(np.diff(api.positions[ends], axis=1)[:, 0], axis=1), locked,
                               rtol=TAUT_TOL, atol=0)
