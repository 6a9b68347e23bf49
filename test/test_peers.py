"""Cross-checks against independent implementations of the same elastic-cable model: MuJoCo (rigid
struts as free bodies, cables as dead-band tendon springs) and scipy's DOP853 restarted at every
slack/taut switch (bench/reference.py)."""
import numpy as np
import pytest

import tensegrity_sim as ts
from bench.cases import icosahedron_thrown, tower_kicked
from bench.reference import ElasticReference


def _final_positions(scene, dt, duration, **options):
    sim = ts.Simulator(scene, method="elastic", dt=dt, **options)
    sim.run(duration=duration)
    return sim.positions


def _mujoco(scene, dt, duration, integrator):
    from bench.mujoco_peer import MujocoPeer
    peer = MujocoPeer(scene, dt=dt, integrator=integrator)
    peer.advance(int(round(duration / dt)))
    assert not peer.unstable
    return peer.positions()


def _distance(a, b):
    return float(np.max(np.linalg.norm(a - b, axis=1)))


@pytest.mark.parametrize("make_scene", [icosahedron_thrown, tower_kicked])
def test_mujoco_and_tensegrity_sim_converge_to_the_same_trajectory(make_scene):
    """Rigid struts (icosahedron, tumbling, 33 switches/s) and elastic struts under gravity on a fixed base
    (tower, ~600 switches/s): the two simulators' final positions after 0.5 s approach each other as the
    step shrinks (measured: 3.0e-5 -> 1.9e-6 m and 1.5e-3 -> 5.0e-5 m from 1 ms to 0.25 ms)."""
    pytest.importorskip("mujoco")
    scene = make_scene()
    gaps = [_distance(_final_positions(scene, dt, 0.5), _mujoco(scene, dt, 0.5, "RK4")) for dt in (1e-3, 2.5e-4)]
    assert gaps[1] < 1e-4
    assert gaps[0] / gaps[1] > 10.0       # second order in the step: 16 expected


@pytest.mark.parametrize("make_scene", [icosahedron_thrown, tower_kicked])
def test_mujoco_model_starts_with_the_same_energy(make_scene):
    """Masses, rest lengths, dead bands, strut springs and gravity carried over: MuJoCo's own energy
    of the initial state equals the simulator's."""
    pytest.importorskip("mujoco")
    from bench.mujoco_peer import MujocoPeer
    scene = make_scene()
    assert MujocoPeer(scene).energy() == pytest.approx(ts.Simulator(scene).energy()["total"], rel=1e-12)


def test_mujoco_euler_reproduces_verlet_positions_to_round_off():
    """Point masses only (the tower): MuJoCo's semi-implicit Euler and velocity Verlet obey the same
    two-step recurrence ``x+ - 2x + x- = h^2 a(x)``; they differ only in the first step, by
    ``h^2 a(x0) / 2``, which is zero here (the structure starts in equilibrium). So two independent
    codes must produce the same positions, step after step, through hundreds of slack/taut switches
    (Verlet's plain step: MuJoCo does not locate switches)."""
    pytest.importorskip("mujoco")
    scene = tower_kicked()
    verlet = _final_positions(scene, 1e-3, 0.5, locate_switches=False)
    assert _distance(verlet, _mujoco(scene, 1e-3, 0.5, "Euler")) < 1e-12


def test_mujoco_strut_axial_inertia_has_no_effect():
    """The tiny axial inertia MuJoCo needs for a rigid strut made of two point masses changes nothing:
    no tendon acts off the axis, so the axial spin stays zero (measured: 5e-15 m over 1e-3..1e-9)."""
    pytest.importorskip("mujoco")
    from bench.mujoco_peer import axial_inertia_effect
    effect = axial_inertia_effect(icosahedron_thrown(), duration=0.5, dt=1e-3)
    assert max(effect.values()) < 1e-12


def test_elastic_method_converges_at_second_order_to_the_dop853_reference():
    """The tumbling icosahedron (rigid struts by RATTLE in the simulator, by acceleration-level
    multipliers in the reference): measured errors after 0.3 s 2.0e-5, 4.9e-6, 1.2e-6 m."""
    scene = icosahedron_thrown()
    ref = ElasticReference(scene).solve(0.3)
    errors = [_distance(_final_positions(scene, dt, 0.3), ref.positions) for dt in (1e-3, 5e-4, 2.5e-4)]
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all((orders > 1.85) & (orders < 2.2)), orders
    assert errors[-1] < 2e-6


def test_reference_finds_switches_between_its_steps():
    """A cable that goes taut and slack again between two DOP853 steps is found from its length
    extremum: with ten times longer steps allowed the reference finds the same 33 switches and the
    same final state (before this check, long steps silently missed two of them: 7e-7 m)."""
    ref = ElasticReference(icosahedron_thrown())
    fine = ref.solve(1.0)
    omega = ref.system.max_frequency(ref.scene.positions, include_cables=True)
    coarse = ref.solve(1.0, max_step=1.0 / omega)
    assert fine.switches == coarse.switches == 33
    assert _distance(fine.positions, coarse.positions) < 1e-10


@pytest.mark.parametrize("name", ["deadband", "snap_pair"])
def test_closed_forms_of_the_benchmark_cases(name):
    """The benchmarks' exact solutions (bench/analytic.py) against the simulator at a small step: final
    positions and each cable's impulse summed over the run (the snap pair's is 2 mu v_rel = 3 N*s)."""
    from bench.cases import work_precision_cases
    case = next(c for c in work_precision_cases() if c.name == name)
    exact = case.exact("elastic")
    sim = ts.Simulator(case.scene, method="elastic", dt=1e-4)
    traj = sim.run(duration=case.duration)
    assert _distance(sim.positions, exact.positions) < 1e-6
    np.testing.assert_allclose(traj.impulses.sum(axis=0), exact.impulses, atol=1e-5)
