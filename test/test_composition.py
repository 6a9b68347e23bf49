"""The elastic method's accuracy options (methods/elastic/composition.py): located slack/taut switches and the
fourth-order composition, against closed forms, conservation laws, DOP853 and MuJoCo."""
import numpy as np
import pytest

import tensegrity_sim as ts
from bench.analytic import bungee_dict, bungee_exact, deadband_dict, deadband_exact
from bench.cases import icosahedron_thrown
from bench.reference import ElasticReference
from tensegrity_sim.methods.elastic.composition import STABILITY, WEIGHTS

DURATION = 2.0   # s: the bungee falls, snaps taut, swings, releases and falls again; the dead band's mass
#                  crosses the gap four times


def _final_error(case: str, dt: float, **options) -> tuple[float, float]:
    """(position error m, impulse error N*s) at ``DURATION`` against the closed form."""
    if case == "bungee":
        sim = ts.Simulator(ts.Scene.from_dict(bungee_dict()), method="elastic", dt=dt, **options)
        traj = sim.run(duration=DURATION)
        z, vz = bungee_exact(DURATION)
        # momentum balance of the mass: its cable's impulse is m (vz(T) - vz(0)) + m g T
        return abs(sim.positions[1, 2] - z), abs(traj.impulses.sum() - (vz + 9.81 * DURATION))
    sim = ts.Simulator(ts.Scene.from_dict(deadband_dict()), method="elastic", dt=dt, **options)
    traj = sim.run(duration=DURATION)
    x, impulses = deadband_exact(DURATION)
    return abs(sim.positions[1, 0] - x), float(np.max(np.abs(traj.impulses.sum(axis=0) - impulses)))


def _composed_map(weights, omega_h):
    """The composed Verlet map of ``x'' = -x`` over one step of ``omega_h``, as a 2x2 matrix."""
    m = np.eye(2)
    for w in weights:
        h = w * omega_h
        m = np.array([[1 - h * h / 2, h], [-h * (1 - h * h / 4), 1 - h * h / 2]]) @ m
    return m


@pytest.mark.parametrize("order", sorted(STABILITY))
def test_stability_limits(order):
    """The refused step sizes are exactly the unstable ones: |trace| < 2 just below the documented limit
    and >= 2 just above it (Verlet: 2; Suzuki's composition: 2.7219)."""
    limit = STABILITY[order]
    below = np.linspace(1e-3, limit - 1e-6, 2000)
    assert all(abs(np.trace(_composed_map(WEIGHTS[order], wh))) < 2.0 for wh in below)
    assert abs(np.trace(_composed_map(WEIGHTS[order], limit + 0.01))) >= 2.0


def test_composition_is_consistent_and_symmetric():
    """The weights sum to one and read the same backwards (so the scheme is time-reversible), and the
    partial sums stay in [0, 1] (no stage looks beyond a located switch)."""
    w = np.array(WEIGHTS[4])
    assert w.sum() == pytest.approx(1.0, abs=1e-15)
    np.testing.assert_array_equal(w, w[::-1])
    assert np.all((np.cumsum(w) >= 0) & (np.cumsum(w) <= 1 + 1e-15))
    # the third-order condition of a symmetric composition: sum w^3 = 0
    assert np.sum(w ** 3) == pytest.approx(0.0, abs=1e-15)


@pytest.mark.parametrize("case", ["bungee", "deadband"])
def test_located_switches_divide_the_error_by_four_per_halving(case):
    """Every halving of dt from 4 ms to 0.25 ms divides the final position error by 3.3 to 4.8 (measured:
    bungee 3.73 4.10 3.97 4.05, dead band 4.00 4.00 3.99 4.00; unlocated, the bungee's ratios were
    1.48 44.2 0.38 4.21), and the cables' impulses converge too."""
    dts = [4e-3, 2e-3, 1e-3, 5e-4, 2.5e-4]
    errors = np.array([_final_error(case, dt, locate_switches=True) for dt in dts])
    ratios = errors[:-1, 0] / errors[1:, 0]
    assert np.all((ratios > 3.3) & (ratios < 4.8)), ratios
    assert errors[-1, 1] < errors[0, 1] / 100, errors[:, 1]


@pytest.mark.parametrize("case, dts", [("bungee", [4e-3, 2e-3, 1e-3, 5e-4]),
                                       ("deadband", [8e-3, 4e-3, 2e-3, 1e-3])])
def test_order_four_holds_through_switches(case, dts):
    """Suzuki's composition with located switches: observed order >= 3.8 over the range, every halving's
    ratio >= 12 (measured: bungee 14.6 16.4 17.3, errors 7.0e-10 m at 4 ms to 1.7e-13 m at 0.5 ms).
    Without locating, the switches cost it its order (bungee ratios 3.5 11.3 1.0 measured)."""
    errors = np.array([_final_error(case, dt, order=4)[0] for dt in dts])
    ratios = errors[:-1] / errors[1:]
    assert np.all(ratios >= 12.0), ratios
    assert np.polyfit(np.log(dts), np.log(errors), 1)[0] >= 3.8


@pytest.mark.parametrize("order", [2, 4])
def test_located_steps_keep_momentum_lengths_and_bounded_energy(order):
    """The tumbling icosahedron with rigid struts (cables go slack and snap taut all the time): the split
    and composed steps apply only equal-and-opposite member forces, so momentum holds to round-off and
    the rigid struts keep their lengths; the energy error stays bounded, at O(h^order)."""
    scene = icosahedron_thrown()
    sim = ts.Simulator(scene, method="elastic", dt=1e-3, order=order, locate_switches=True)
    m = sim.system.masses[:, None]
    p0, l0 = sim.momentum()
    p_scale = np.sum(m * np.abs(sim.velocities))
    l_scale = np.sum(m * np.linalg.norm(sim.positions, axis=1)[:, None] * np.abs(sim.velocities))
    e0 = sim.energy()["total"]
    traj = sim.run(duration=1.0)
    assert traj.slack.any() and (~traj.slack).any()
    p1, l1 = sim.momentum()
    assert np.max(np.abs(p1 - p0)) < 1e-12 * p_scale
    assert np.max(np.abs(l1 - l0)) < 1e-12 * l_scale
    ends = sim.system.strut_ends
    lengths = np.linalg.norm(sim.positions[ends[:, 1]] - sim.positions[ends[:, 0]], axis=1)
    np.testing.assert_allclose(lengths, sim.system.strut_rest, rtol=1e-13)
    assert abs(sim.energy()["total"] - e0) < (1e-4 if order == 2 else 1e-8) * e0


def test_order_four_on_the_rigid_strut_icosahedron_against_dop853_and_mujoco_rk4():
    """Rigid struts (RATTLE in every stage) and 13 switches in 0.3 s: the error against DOP853 restarted
    at every switch falls >= 12-fold per halving (measured 15.3 16.0 15.6; 3.2e-11 m at 0.5 ms), and MuJoCo's
    RK4 at a 40x smaller step (2.5e-5 s) agrees with the 1 ms run to its own accuracy (RK4 does not
    locate the switches: 7.7e-10 m from DOP853, measured)."""
    scene = icosahedron_thrown()
    ref = ElasticReference(scene).solve(0.3)
    finals = []
    for dt in (4e-3, 2e-3, 1e-3, 5e-4):
        sim = ts.Simulator(scene, method="elastic", dt=dt, order=4)
        sim.run(duration=0.3)
        finals.append(sim.positions)
    errors = np.array([np.max(np.linalg.norm(x - ref.positions, axis=1)) for x in finals])
    assert np.all(errors[:-1] / errors[1:] >= 12.0), errors
    assert errors[-1] < 1e-10
    pytest.importorskip("mujoco")
    from bench.mujoco_peer import MujocoPeer
    peer = MujocoPeer(scene, dt=2.5e-5, integrator="RK4")
    peer.advance(12_000)
    gaps = [np.max(np.linalg.norm(x - peer.positions(), axis=1)) for x in finals]
    assert gaps[0] / gaps[1] >= 12.0
    assert gaps[2] < 2e-9


def test_options_are_checked_and_reported():
    scene = ts.Scene.from_dict(bungee_dict())
    with pytest.raises(ValueError, match=r"order must be one of \[2, 4\], got 3"):
        ts.Simulator(scene, method="elastic", order=3)
    with pytest.raises(ValueError, match=r"locate_switches must be True, False or None \(automatic\), got 'yes'"):
        ts.Simulator(scene, method="elastic", locate_switches="yes")
    with pytest.raises(ValueError,
                       match=r"order=4 is an option of the elastic and massive methods; method 'inextensible' has none"):
        ts.Simulator(scene, method="inextensible", order=4)
    sim = ts.Simulator(scene, method="elastic", dt=1e-3, order=4, locate_switches=False)
    assert sim.method_settings == {"method": "elastic", "dt": 1e-3, "order": 4, "locate_switches": False}
    # by default only order 4 locates; every option runs compiled (methods/elastic/_composition_kernels.py)
    plain = ts.Simulator(scene, method="elastic", dt=1e-3)
    assert not plain.method_settings["locate_switches"] and plain._method.compiled
    located = ts.Simulator(scene, method="elastic", dt=1e-3, locate_switches=True)
    assert located.method_settings["locate_switches"] and located._method.compiled
    assert ts.Simulator(scene, method="elastic", dt=1e-3, order=4).method_settings["locate_switches"]
    # the composition's wider stability interval is used: 2 < omega dt < 2.72 runs at order 4 only
    stiff = ts.Scene.from_dict(bungee_dict(k=1.0e6))
    with pytest.raises(ValueError, match=r"dt must be < 2/omega_max = 0\.002 s"):
        ts.Simulator(stiff, method="elastic", dt=2.5e-3)
    ts.Simulator(stiff, method="elastic", dt=2.5e-3, order=4)
    with pytest.raises(ValueError, match=r"dt must be < 2\.72/omega_max = 0\.00272 s"):
        ts.Simulator(stiff, method="elastic", dt=2.8e-3, order=4)
