"""The elastic-cable method against closed forms and conservation laws."""
import math

import numpy as np
import pytest

import tensegrity_sim as ts
from bench.analytic import bungee_constants, bungee_exact
from conftest import bungee_dict, class_k_dict, deadband_dict, random_velocities


def test_bungee_lowest_point_period_and_energy():
    dt = 1e-4
    sim = ts.Simulator(ts.Scene.from_dict(bungee_dict()), method="elastic", dt=dt)
    e0 = sim.energy()["total"]
    period, lowest = bungee_constants()
    traj = sim.run(duration=1.5 * period)
    z = traj.positions[:, 1, 2]
    vz = traj.velocities[:, 1, 2]
    assert z.min() == pytest.approx(lowest, abs=2e-6)
    # the top of the first bounce: vz changes sign from + to -, interpolated
    k = np.flatnonzero((vz[:-1] > 0) & (vz[1:] <= 0))[0]
    t_top = traj.time[k] + dt * vz[k] / (vz[k] - vz[k + 1])
    assert t_top == pytest.approx(period, abs=2e-6)
    assert abs(sim.energy()["total"] - e0) < 1e-5 * abs(e0)


def test_bungee_converges_second_order():
    """The kink at the slack/taut switch does not cost Verlet its order (see methods/elastic/method.py).

    Error: the largest height error over a whole bounce (free fall, snap, taut swing, release),
    sampled every 20 ms over two bounces. Each halving's ratio scatters (the snap falls at a different
    fraction of the step, and the kink's O(h^2) error is proportional to theta (1 - theta)), so the order
    is the least-squares slope over a 32-fold range of steps: measured 1.94."""
    samples = np.arange(0.02, 2.0, 0.02)
    exact = np.array([bungee_exact(t)[0] for t in samples])
    errors = []
    dts = [4e-3, 2e-3, 1e-3, 5e-4, 2.5e-4, 1.25e-4]
    for dt in dts:
        sim = ts.Simulator(ts.Scene.from_dict(bungee_dict()), method="elastic", dt=dt)
        traj = sim.run(duration=2.0)
        idx = np.rint(samples / dt).astype(int) - 1
        errors.append(np.max(np.abs(traj.positions[idx, 1, 2] - exact)))
    order = np.polyfit(np.log(dts), np.log(errors), 1)[0]
    assert 1.85 < order < 2.15, order


def test_deadband_period():
    m, k, slack, v0 = 2.0, 50.0, 0.1, 0.5
    dt = 1e-4
    sim = ts.Simulator(ts.Scene.from_dict(deadband_dict(k=k, m=m, slack=slack, v0=v0)), method="elastic", dt=dt)
    expected = 2 * math.pi * math.sqrt(m / k) + 4 * slack / v0
    traj = sim.run(duration=3.2 * expected)
    x = traj.positions[:, 1, 0]
    up = np.flatnonzero((x[:-1] < 0) & (x[1:] >= 0))
    crossings = traj.time[up] - dt * x[up + 1] / (x[up + 1] - x[up])
    assert crossings[1] - crossings[0] == pytest.approx(expected, abs=1e-6)
    assert crossings[2] - crossings[1] == pytest.approx(expected, abs=1e-6)
    # never more than one cable taut: the dead band is wider than nothing
    assert not np.any(~traj.slack[:, 0] & ~traj.slack[:, 1])


def test_damped_cable_never_pushes():
    """A heavily damped cable that is being released must not push (tension >= 0 always)."""
    d = bungee_dict(k=100.0, damping=50.0, drop=1.2)  # starts stretched: the mass recoils upward fast
    d["gravity"] = [0.0, 0.0, 0.0]
    d["nodes"][1]["velocity"] = [0.0, 0.0, 3.0]
    sim = ts.Simulator(ts.Scene.from_dict(d), method="elastic", dt=1e-4)
    traj = sim.run(duration=0.2)
    assert traj.tensions.min() >= 0.0
    # once slack, the mass coasts: its speed is constant (no pull, no push)
    slack = traj.slack[:, 0]
    first = np.argmax(slack)
    assert slack[first:].all() and first > 0
    assert np.ptp(traj.velocities[first + 1:, 1, 2]) == 0.0


@pytest.mark.parametrize("scene_name", ["prism3", "icosahedron"])
def test_free_structure_conserves_momentum_and_bounds_energy(scene_name):
    scene = random_velocities(ts.load_scene(scene_name), seed=1, scale=0.5)
    sim = ts.Simulator(scene, method="elastic", dt=1e-3)
    m = sim.system.masses[:, None]
    p0, l0 = sim.momentum()
    p_scale = np.sum(m * np.abs(sim.velocities))
    l_scale = np.sum(m * np.linalg.norm(sim.positions, axis=1)[:, None] * np.abs(sim.velocities))
    e0 = sim.energy()["total"]
    energies = []
    for _ in range(10):
        sim.run(steps=1000)
        energies.append(sim.energy()["total"])
    p1, l1 = sim.momentum()
    assert np.max(np.abs(p1 - p0)) < 1e-9 * p_scale
    assert np.max(np.abs(l1 - l0)) < 1e-9 * l_scale
    # bounded: no drift between the first and the last thousand steps beyond the O(h^2) oscillation
    assert np.max(np.abs(np.array(energies) - e0)) < 1e-3 * abs(e0) + 1e-3


def test_rigid_struts_hold_their_length():
    scene = random_velocities(ts.load_scene("icosahedron"), seed=3, scale=2.0)
    sim = ts.Simulator(scene, method="elastic", dt=1e-3)
    sim.run(steps=3000)
    ends = sim.system.strut_ends
    lengths = np.linalg.norm(sim.positions[ends[:, 1]] - sim.positions[ends[:, 0]], axis=1)
    np.testing.assert_allclose(lengths, sim.system.strut_rest, rtol=1e-13)


def test_class_k_rigid_struts_coupled_newton():
    """Two rigid struts sharing a node (class-k): the coupled SHAKE solve keeps both lengths."""
    with pytest.warns(ts.ClassKWarning):
        scene = ts.Scene.from_dict(class_k_dict())
    sim = ts.Simulator(scene, method="elastic", dt=1e-3)
    p0, l0 = sim.momentum()
    e0 = sim.energy()["total"]
    sim.run(steps=5000)
    x = sim.positions
    assert np.linalg.norm(x[1] - x[0]) == pytest.approx(1.0, rel=1e-13)
    assert np.linalg.norm(x[2] - x[1]) == pytest.approx(1.0, rel=1e-13)
    p1, l1 = sim.momentum()
    np.testing.assert_allclose(p1, p0, atol=1e-12)
    np.testing.assert_allclose(l1, l0, atol=1e-12)
    assert abs(sim.energy()["total"] - e0) < 1e-3 * e0


def test_too_large_step_is_refused_with_the_limit():
    d = bungee_dict(k=1.0e6)
    with pytest.raises(ValueError, match=r"dt must be < 2/omega_max = 0\.002 s"):
        ts.Simulator(ts.Scene.from_dict(d), method="elastic", dt=2.5e-3)


def test_elastic_needs_cable_stiffness():
    d = bungee_dict()
    del d["cables"][0]["stiffness"]
    with pytest.raises(ValueError, match=r"needs a stiffness for every cable; missing for \['c'\]"):
        ts.Simulator(ts.Scene.from_dict(d), method="elastic")
