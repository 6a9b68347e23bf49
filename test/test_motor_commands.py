"""Rest-length commands with inextensible cables: the motor's finite speed (``reel_speed``) and the
energy balance against the motor's work."""
import math
import warnings

import numpy as np
import pytest

import tensegrity_sim as ts
from bench.analytic import bungee_dict


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
    """Without a speed limit a jump is a reel-in within one step at ``w = change / dt``: an impulsive
    start of the motor. As in the exact solution the mass leaves at ``w`` and gains half the motor's
    work ``y w`` (the other half is lost as in a perfectly inelastic impact), to round-off; that energy
    grows as 1/dt^2, which is why the default spreads a jump."""
    kinetic = []
    for dt in (1e-3, 5e-4):
        sim = ts.Simulator(ts.Scene.from_dict(bungee_dict(drop=1.0)), method="inextensible", dt=dt,
                           reel_speed=math.inf)
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
    with pytest.raises(ValueError, match=r"reel_speed=2.0 is an option of the inextensible method; method 'elastic'"):
        ts.Simulator(ts.Scene.from_dict(bungee_dict()), method="elastic", reel_speed=2.0)
