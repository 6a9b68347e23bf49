"""The massive method (physics.md §4b) with rigid struts: SHAKE/RATTLE under the plate-augmented mass ``M + sum m_c
b_c b_c^T`` (``M`` with the rods' consistent blocks, physics.md §4c), the struts keeping their length rates through
a snap (rows without a plate in the impact). The free rod's closed form is in test_rods.py (path "massive")."""
import numpy as np
import pytest

import tensegrity_sim as ts


def thrown_rods(plate: float, rod_mass: float = 3.0) -> ts.Scene:
    """The built-in icosahedron (rigid struts) with ``rod_mass`` kg spread along each strut (its block), thrown
    spinning with random node velocities, every cable carrying ``plate`` kg."""
    raw = ts.load_scene("icosahedron").to_dict()
    x = np.array([n["position"] for n in raw["nodes"]])
    v = np.cross([0.3, -0.5, 2.0], x - x.mean(axis=0)) + 1.5 * np.random.default_rng(7).normal(size=x.shape)
    v -= v.mean(axis=0)
    for node, vi in zip(raw["nodes"], v):
        node["velocity"] = [float(a) for a in vi]
    for strut in raw["struts"]:
        strut["mass"] = rod_mass
    for cable in raw["cables"]:
        cable["mass"] = plate
    return ts.Scene.from_dict(raw)


def test_rods_with_plates_keep_momentum_lengths_and_energy_less_the_plates_losses():
    """Thrown with plates on every cable and the rods' blocks: cables snap and release; momentum holds to round-off,
    every strut its length, and the energy with the plates' losses added stays to Verlet's O(dt^2) (halving dt
    quarters the residual)."""
    scene = thrown_rods(0.05)
    scale = float(np.sum(scene.masses[:, None] * np.abs(scene.velocities)))
    residuals = []
    for dt in (1e-3, 5e-4):
        sim = ts.Simulator(scene, method="massive", dt=dt)
        assert sim.system.mass.consistent and not sim._method.compiled
        p0, l0 = sim.momentum()
        e0 = sim.energy()["total"]
        traj = sim.run(duration=0.2)
        p1, l1 = sim.momentum()
        assert np.abs(p1 - p0).max() < 1e-13 * scale and np.abs(l1 - l0).max() < 1e-13 * scale
        _, length, _ = sim.system.geometry(sim.positions)
        assert np.abs(length[:6] - sim.system.strut_rest).max() < 1e-12
        assert np.abs(np.diff(traj.slack.astype(int), axis=0)).sum() >= 2 and sim.energy_lost > 1e-3
        residuals.append(abs(sim.energy()["total"] + sim.energy_lost - e0) / e0)
    assert residuals[1] < 1e-4 and residuals[0] / residuals[1] > 3.0, residuals


def test_a_snap_keeps_the_rods_length_rates():
    """The impact on the plates has the rigid struts' rows beside the cables' (no plate: ``1/m = 0``): after a step
    whose snap is resolved at its end, after RATTLE's closing projection (switches not located), every strut's
    length rate is still zero."""
    sim = ts.Simulator(thrown_rods(0.5), method="massive", dt=1e-3, locate_switches=False)
    method = sim._method
    worst, snaps = 0.0, 0
    slack = sim.slack()
    for _ in range(200):
        r = sim.step()
        if (slack & ~r.slack & (method.plates > 0)).any():   # a snap in this step
            snaps += 1
            _, _, n = sim.system.geometry(r.positions)
            rates = sim.system.member_rates(r.velocities, n[:6], sim.system.strut_ends)
            worst = max(worst, float(np.abs(rates).max()))
        slack = r.slack
    assert snaps > 0 and worst < 1e-12, (snaps, worst)


def test_massless_limit_with_rods_is_the_elastic_method():
    """m_c -> 0 with rigid rods and their blocks: the elastic method's RATTLE (its numpy reference), the difference
    proportional to m_c."""
    steps = 150
    elastic = ts.Simulator(thrown_rods(0.0), method="elastic", dt=1e-3)
    elastic._method.compiled = False
    reference = elastic.run(steps=steps).positions[-1]
    zero = ts.Simulator(thrown_rods(0.0), method="massive", dt=1e-3, locate_switches=False)
    assert np.abs(zero.run(steps=steps).positions[-1] - reference).max() < 1e-12
    plates = np.array([1e-4, 1e-5, 1e-6])
    errors = [np.abs(ts.Simulator(thrown_rods(p), method="massive", dt=1e-3, locate_switches=False)
                     .run(steps=steps).positions[-1] - reference).max() for p in plates]
    slope = np.polyfit(np.log(plates), np.log(errors), 1)[0]
    assert 0.9 < slope < 1.1, (errors, slope)


def test_rigid_icosahedron_with_cable_masses_rests_on_the_ground():
    """The built-in ``icosahedron_ground`` (rigid struts) with cable plates, on the ground for 0.3 s: no node moves
    1e-6 m (the contacts' problems take the rods' rows and the plates' mass together); ``auto`` picks the method."""
    raw = ts.load_scene("icosahedron_ground").to_dict()
    for cable in raw["cables"]:
        cable["mass"] = 0.05
    sim = ts.Simulator(ts.Scene.from_dict(raw), method="auto", dt=1e-3)
    assert sim.method == "massive"
    x0 = sim.positions.copy()
    traj = sim.run(duration=0.3)
    assert np.abs(traj.positions - x0).max() < 1e-6
    _, length, _ = sim.system.geometry(sim.positions)
    assert np.abs(length[:6] - sim.system.strut_rest).max() < 1e-12


@pytest.mark.parametrize("plate", [0.05])
def test_the_plates_mass_enters_the_rods_projections(plate):
    """RATTLE's velocity change under the plate-augmented mass: the projected velocities are the augmented-mass
    projection (``M_eff dv = S^T mu`` with the rods' rates zeroed), checked with dense numpy matrices."""
    sim = ts.Simulator(thrown_rods(plate), method="massive", dt=1e-3)
    method, system = sim._method, sim.system
    x = sim.positions
    v = np.random.default_rng(3).normal(size=x.shape)
    forces = method.accelerations(x, v, sim._state)
    method._hold(forces)
    n = forces.directions
    dv = method.rigid.project_velocities(x, v, n[:6])
    nn = system.n_nodes
    heavy = np.zeros((3 * nn, 3 * nn))
    for a, c in [(i, i) for i in range(nn)]:
        heavy[3 * a:3 * a + 3, 3 * c:3 * c + 3] = np.eye(3) * system.mass.diagonal[a]
    for a, c in system.mass.blocks:
        heavy[3 * a:3 * a + 3, 3 * c:3 * c + 3] = heavy[3 * c:3 * c + 3, 3 * a:3 * a + 3] = \
            np.eye(3) * system.mass.cross[a]
    for cable in np.flatnonzero(forces.held):
        b = np.zeros(3 * nn)
        a, c = system.cable_ends[cable]
        b[3 * a:3 * a + 3], b[3 * c:3 * c + 3] = -n[6 + cable], n[6 + cable]
        heavy += plate * np.outer(b, b)
    s = np.zeros((6, 3 * nn))
    for i, (a, c) in enumerate(system.strut_ends):
        s[i, 3 * a:3 * a + 3], s[i, 3 * c:3 * c + 3] = -n[i], n[i]
    inv = np.linalg.inv(heavy)
    mu = np.linalg.solve(s @ inv @ s.T, -s @ v.ravel())
    assert np.abs(dv.ravel() - inv @ s.T @ mu).max() < 1e-12
