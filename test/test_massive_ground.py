"""The massive method (physics.md §4b) with contacts, the ground's and the members': their velocity problems
under the plate-augmented mass ``M + sum m_c b_c b_c^T`` (``PlateMassSolver``), answered by the project's
frictional solver (friction.py), which checks every answer against the Coulomb law. An icosahedron with cable
masses resting on the ground stays; a thrown one lands with the momentum balance of its ground impulses exact; as
``m_c -> 0`` it tends to the elastic method on the ground, the difference proportional to ``m_c``; a member contact
response likewise."""
import numpy as np
import pytest

import tensegrity_sim as ts
from bench.massive import resting, thrown
from tensegrity_sim.methods.contact.friction import TOUCH_TOL
from tensegrity_sim.methods.massive.method import PlateMassSolver
from tensegrity_sim.methods.qp.solvers import Rows
from tensegrity_sim.system import System


def test_plate_mass_solver_is_the_augmented_mass_qp():
    """``inverse`` is ``(M + B^T diag(m_c) B)^-1`` (dense, against numpy) and a solve's answer is that matrix's
    QP: ``M_eff (v - v0) = -A^T y`` with the rows met."""
    system = System(resting(0.05))
    solver = PlateMassSolver(system, system.scene.cable_masses)
    _, _, n = system.geometry(system.scene.positions)
    cables = np.array([0, 3, 7, 11])
    units = n[system.n_struts + cables]
    solver.hold(cables, units)
    b = np.zeros((len(cables), system.n_nodes, 3))
    b[np.arange(4), system.cable_ends[cables, 0]] -= units
    b[np.arange(4), system.cable_ends[cables, 1]] += units
    b = b.reshape(4, -1)
    heavy = np.diag(np.repeat(system.masses, 3)) + b.T @ np.diag(system.scene.cable_masses[cables]) @ b
    p = np.random.default_rng(0).normal(size=(3 * system.n_nodes, 5))
    assert np.abs(solver.inverse(p) - np.linalg.solve(heavy, p)).max() < 1e-14
    v0 = np.random.default_rng(1).normal(size=(system.n_nodes, 3))
    down = np.array([[0.0, 0.0, -1.0]] * 2)
    rows = Rows(np.array([[-1, 0], [-1, 4]]), down, np.array([-1.0, -2.0]), 0)   # v_z >= 1, 2 m/s
    v, y = solver.solve(v0, rows)
    assert np.abs(heavy @ (v - v0).ravel() + rows.dense(system.n_nodes).T @ y).max() < 1e-12
    assert rows.rates(v) == pytest.approx([-1.0, -2.0], abs=1e-12) and (y > 0).all()


def test_resting_icosahedron_with_cable_masses_stays():
    """At rest on three nodes (mu = 0.8): over 1 s the centre stays within 1e-7 m and no node moves 1e-7 m or
    sinks (the contact impulse holds the weight exactly; the plates take no part at rest)."""
    sim = ts.Simulator(resting(0.05), method="massive", dt=1e-3)
    x0 = sim.positions.copy()
    traj = sim.run(duration=1.0)
    drift = np.abs(traj.positions - x0).max(axis=(1, 2))
    assert drift.max() < 1e-7, drift.max()
    assert np.abs(traj.positions.mean(axis=1) - x0.mean(axis=0)).max() < 1e-7
    assert drift[-100:].max() < 1e-7 and traj.positions[..., 2].min() > 0.025 - TOUCH_TOL   # no creep, no sinking
    weight = float(np.sum(sim.system.masses)) * 9.81
    assert traj.contact_impulses[-1, :, 2].sum() == pytest.approx(weight * sim.dt, rel=1e-6)


def test_thrown_icosahedron_lands_with_its_momentum_balance():
    """Thrown onto the ground (mu = 0.8, plastic) spinning: it lands and stays above the ground; each step's
    friction is inside the disc of its normal impulse, and the nodes' momentum changes by exactly the ground's
    impulses and the weight (the plates' inertia is equal and opposite on each cable's ends)."""
    scene = thrown(0.05)
    sim = ts.Simulator(scene, method="massive", dt=1e-3)
    p0 = sim.momentum()[0]
    traj = sim.run(duration=0.25)
    ground = traj.contact_impulses
    assert (ground[..., 2] > 0).any(axis=1).sum() > 50          # it landed and stays on the ground
    assert traj.positions[..., 2].min() > 0.025 - 1e-6           # the nodes' radius: not through the ground
    friction = np.linalg.norm(ground[..., :2], axis=-1)
    assert (ground[..., 2] >= 0).all() and (friction <= 0.8 * ground[..., 2] + 1e-12).all()
    weight = sim.system.masses.sum() * 9.81 * sim.time
    change = sim.momentum()[0] - p0
    balance = ground.sum(axis=(0, 1)) - np.array([0.0, 0.0, weight])
    assert np.abs(change - balance).max() < 1e-10 * np.abs(scene.masses[:, None] * scene.velocities).sum()
    assert sim.energy_lost > 0.0   # cables slackened and snapped on the landing: the plates lost energy


def test_massless_limit_on_the_ground_is_the_elastic_method():
    """m_c -> 0: the thrown icosahedron's landing tends to the elastic method's on the ground (its numpy
    reference, the same contact arithmetic at m_c = 0), the difference proportional to m_c."""
    steps = 200   # it lands at 0.12 s
    elastic = ts.Simulator(thrown(0.0), method="elastic", dt=1e-3)
    elastic._method.compiled = False
    reference = elastic.run(steps=steps).positions[-1]
    zero = ts.Simulator(thrown(0.0), method="massive", dt=1e-3).run(steps=steps).positions[-1]
    assert np.abs(zero - reference).max() < 1e-12
    plates = np.array([1e-4, 1e-5, 1e-6])
    errors = [np.abs(ts.Simulator(thrown(p), method="massive", dt=1e-3).run(steps=steps).positions[-1]
                     - reference).max() for p in plates]
    slope = np.polyfit(np.log(plates), np.log(errors), 1)[0]
    assert 0.85 < slope < 1.15, (errors, slope)


def test_ground_options_and_auto():
    """With a ground the massive method steps plain Verlet (its events at the step's end) and refuses the options
    it cannot take there; ``auto`` picks it for a scene on the ground whose cables' restitution is between."""
    scene = resting(0.5)
    with pytest.raises(ValueError, match="located switches are not available with contacts"):
        ts.Simulator(scene, method="massive", locate_switches=True)
    with pytest.raises(ValueError, match="order 4"):
        ts.Simulator(scene, method="massive", order=4)
    sim = ts.Simulator(scene, method="auto", dt=1e-3)
    assert sim.method == "massive" and sim.method_settings["locate_switches"] is False


def crossing_with_a_plate(plate: float) -> ts.Scene:
    """test_member_contact's crossing struts (B falls at 1 m/s onto A, across it at A's point 0.25 m, a member
    contact response) with a taut cable of ``plate`` kg from A's end a1 to B's end b1."""
    from test_member_contact import crossing
    raw = crossing(0.25).to_dict()
    raw["cables"] = [{"name": "c", "nodes": ["a1", "b1"], "stiffness": 100.0, "rest_length": 0.5, "mass": plate}]
    return ts.Scene.from_dict(raw)


def test_member_contact_with_a_plate_keeps_momentum_and_tends_to_the_elastic_method():
    """A member contact response under the plate-augmented mass: strut B strikes strut A (plastic) while a massive
    cable pulls between them; momentum holds to round-off, the struts do not pass through each other (TOUCH_TOL),
    the pair's impulse is reported, and as m_c -> 0 the motion tends to the elastic method's (its reference, the
    same arithmetic at m_c = 0), the difference proportional to m_c."""
    from test_member_contact import gap
    elastic = ts.Simulator(crossing_with_a_plate(0.0), method="elastic", dt=1e-3)
    elastic._method.compiled = False
    reference = elastic.run(steps=80).positions[-1]
    errors = []
    for plate in (0.0, 1e-3, 1e-4, 1e-5):
        sim = ts.Simulator(crossing_with_a_plate(plate), method="massive", dt=1e-3)
        linear, angular = sim.momentum()
        normals = []
        for _ in range(80):
            sim.step()
            normals += [normal for normal, _ in (sim._method._pairs or {}).values()]   # the method's step record
        assert max(normals) > 0.1 and min(normals) >= 0.0   # the blow, then B resting on A
        assert np.abs(sim.momentum()[0] - linear).max() < 1e-14 and np.abs(sim.momentum()[1] - angular).max() < 1e-14
        assert gap(sim.positions) > -3e-9 and not sim.slack()[0]
        errors.append(np.abs(sim.positions - reference).max())
    assert errors[0] < 1e-14
    slope = np.polyfit(np.log([1e-3, 1e-4, 1e-5]), np.log(errors[1:]), 1)[0]
    assert 0.95 < slope < 1.05, (errors, slope)
