"""Rods with their true inertia (issue 46, physics.md section 4c): a rigid strut's mass spread along it is its
consistent 2x2 mass block in its end nodes' coordinates.

Closed forms, each of which fails when the rod's mass is lumped half at each end: a uniform rod spinning end over
end has ``I = m L^2 / 12`` (lumped: ``m L^2 / 4``), a payload puts the centre of mass and the inertia where the
integrals say, a rod pinned at one end swings with the physical pendulum's period ``2 pi sqrt(2 L / 3 g)``
(lumped: ``2 pi sqrt(L / g)``), a rod standing on frictionless ground falls with its centre on a vertical line and
turns as ``m L^2 / 12`` says. Every path that applies the blocks (the elastic method's numpy reference, its
compiled step and loop, the batch and the JAX backend; the inextensible method's reference, compiled path, run and
batch) is held to them and to each other. The inextensible method's own: the spinning rod's momentum and energy,
and a payload rod's tether snapping taut, which takes ``m_eff U^2 / 2`` (``m_eff`` from the integrals).
"""
import math
import os
import warnings

import numpy as np
import pytest

import tensegrity_sim as ts
from tensegrity_sim.batch import BatchSimulator
from tensegrity_sim.mass import MassOperator
from tensegrity_sim.scene import LumpedMassWarning
from tensegrity_sim.system import System

HAVE_JAX = os.environ.get("TENSEGRITY_SIM_REQUIRE_JAX") == "1"
if not HAVE_JAX:
    try:
        import jax  # noqa: F401
        HAVE_JAX = True
    except ImportError:
        pass
PATHS = ["reference", "compiled", "run", "batch"] + (["jax"] if HAVE_JAX else [])

L, M = 1.2, 2.0   # m, kg


def rod(*, distribution="uniform", payloads=(), fixed_first=False, gravity=(0.0, 0.0, 0.0), velocities=None,
        ground=None, angle=0.0):
    """One rigid rod of length L along x (tilted down by ``angle`` about y) from node a at the origin."""
    b = [L * math.cos(angle), 0.0, -L * math.sin(angle)]
    nodes = [{"name": "a", "position": [0.0, 0.0, 0.0]}, {"name": "b", "position": b}]
    if fixed_first:
        nodes[0]["fixed"] = True
    if velocities is not None:
        for node, vel in zip(nodes, velocities):
            node["velocity"] = list(vel)
    d = {"name": "rod", "gravity": list(gravity), "nodes": nodes,
         "struts": [{"name": "s", "nodes": ["a", "b"], "stiffness": "rigid", "mass": M,
                     "mass_distribution": distribution, "payloads": [{"at": at, "mass": m} for at, m in payloads]}]}
    if ground is not None:
        d["ground"] = ground
    return ts.Scene.from_dict(d)


def simulate(scene, path, steps, dt, method="elastic"):
    """Positions (K, N, 3) and velocities after each step, and the final momentum/energy, along ``path``."""
    if path == "batch":
        batch = BatchSimulator(scene, 2, method=method, dt=dt)
        traj = batch.run(steps=steps)
        return traj.positions[0], traj.velocities[0], None
    if path == "massive":
        method = "massive"   # the massive method's numpy reference (its blocks)
    sim = ts.Simulator(scene, method=method, dt=dt, backend="jax" if path == "jax" else "numba")
    if path == "reference":
        sim._method.compiled = False
    if path in ("run", "jax"):
        traj = sim.run(steps=steps)
        return traj.positions, traj.velocities, sim
    rows = [sim.step() for _ in range(steps)]
    return np.array([r.positions for r in rows]), np.array([r.velocities for r in rows]), sim


def rod_angular_momentum(x, v, payloads, distribution, about):
    """The rod's angular momentum about ``about`` (3,), integrated along it: the uniform part by 2-point Gauss
    quadrature (exact for the quadratic integrand), ``ends`` as two point masses, each payload as a point."""
    points = []
    if distribution == "uniform":
        for s in (0.5 - 0.5 / math.sqrt(3.0), 0.5 + 0.5 / math.sqrt(3.0)):
            points.append((s, 0.5 * M))
    else:
        points += [(0.0, 0.5 * M), (1.0, 0.5 * M)]
    points += list(payloads)
    total = np.zeros(3)
    for s, m in points:
        r = (1 - s) * x[0] + s * x[1] - about
        u = (1 - s) * v[0] + s * v[1]
        total += m * np.cross(r, u)
    return total


@pytest.mark.parametrize("path", PATHS + ["massive"])
def test_a_free_uniform_rod_spins_end_over_end_with_a_twelfth_of_m_l_squared(path):
    omega, drift = 3.0, np.array([0.2, -0.1, 0.3])   # rad/s about z, m/s of the centre
    half = 0.5 * L * omega
    scene = rod(velocities=[drift - [0.0, half, 0.0], drift + [0.0, half, 0.0]])
    x, v, sim = simulate(scene, path, 400, 1e-3)
    centre = 0.5 * (x[:, 0] + x[:, 1])
    np.testing.assert_allclose(centre[-1], 0.5 * np.array([L, 0, 0]) + 0.4 * drift, rtol=0, atol=1e-12)
    for k in (0, 199, 399):
        spin = rod_angular_momentum(x[k], v[k], (), "uniform", centre[k])
        np.testing.assert_allclose(spin, [0.0, 0.0, M * L * L / 12.0 * omega], rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(np.linalg.norm(x[k, 1] - x[k, 0]), L, rtol=1e-14)
    # the rod turns at omega: the angle after 0.4 s, to RATTLE's second order ((omega dt)^2 relative)
    d = x[-1, 1] - x[-1, 0]
    assert abs(math.atan2(d[1], d[0]) - 0.4 * omega) <= (omega * 1e-3) ** 2 * 0.4 * omega
    if sim is not None:
        linear, angular = sim.momentum()
        np.testing.assert_allclose(linear, M * drift, rtol=1e-12)
        expected = M * np.cross(centre[-1], drift) + [0.0, 0.0, M * L * L / 12.0 * omega]
        np.testing.assert_allclose(angular, expected, rtol=1e-12, atol=1e-14)
        kinetic = 0.5 * M * drift @ drift + 0.5 * M * L * L / 12.0 * omega ** 2
        assert math.isclose(sim.energy()["kinetic"], kinetic, rel_tol=1e-12)


@pytest.mark.parametrize("distribution", ["uniform", "ends"])
def test_a_payload_puts_the_centre_of_mass_and_the_inertia_where_the_integrals_say(distribution):
    payloads = ((0.8, 1.5), (0.25, 0.4))
    scene = rod(distribution=distribution, payloads=payloads)
    op = System(scene).mass
    shares = [(0.5, M)] if distribution == "uniform" else [(0.0, 0.5 * M), (1.0, 0.5 * M)]
    total = M + sum(m for _, m in payloads)
    first = sum(s * m for s, m in shares + list(payloads))
    second = sum(s * s * m for s, m in list(payloads) + ([] if distribution == "uniform" else [(1.0, 0.5 * M)]))
    second += M / 3.0 if distribution == "uniform" else 0.0
    centre = first / total                       # along the rod, from node a
    inertia = (second - total * centre ** 2) * L * L   # about the centre, normal to the rod
    np.testing.assert_allclose(op.lumped.sum(), total, rtol=1e-15)
    np.testing.assert_allclose(op.lumped[1] / total, centre, rtol=1e-14)   # the lever rule: the weight's shares
    # a rotation about the centre at omega: linear momentum 0, angular I omega, energy I omega^2 / 2
    omega = 2.0
    v = np.array([[0.0, -centre * L * omega, 0.0], [0.0, (1 - centre) * L * omega, 0.0]])
    x = np.array([[0.0, 0.0, 0.0], [L, 0.0, 0.0]])
    linear, angular = op.momentum(x - [centre * L, 0.0, 0.0], v)
    np.testing.assert_allclose(linear, 0.0, atol=1e-14)
    np.testing.assert_allclose(angular, [0.0, 0.0, inertia * omega], rtol=1e-13)
    assert math.isclose(op.kinetic_energy(v), 0.5 * inertia * omega ** 2, rel_tol=1e-13)
    np.testing.assert_allclose(angular, rod_angular_momentum(x - [centre * L, 0, 0], v, payloads, distribution,
                                                             np.zeros(3)), rtol=1e-13)
    # M^-1 undoes M
    f = np.array([[0.3, -1.0, 2.0], [1.5, 0.2, -0.7]])
    np.testing.assert_allclose(op.apply(op.solve(f)), f, rtol=1e-14, atol=1e-15)


def test_the_ends_distribution_keeps_the_old_lumped_meaning():
    lumped = rod(distribution="ends")
    op = System(lumped).mass
    assert not op.consistent
    np.testing.assert_array_equal(op.inv_diagonal, [1.0 / (0.5 * M), 1.0 / (0.5 * M)])


@pytest.mark.parametrize("method, path", [("elastic", p) for p in PATHS]
                         + [("inextensible", p) for p in ["reference", "compiled", "run", "batch"]])
def test_a_rod_pinned_at_one_end_swings_with_the_physical_pendulums_period(method, path):
    g, theta0, dt = 9.81, 0.02, 2e-4
    scene = rod(fixed_first=True, gravity=(0.0, 0.0, -g), angle=math.pi / 2 - theta0)   # hanging, 0.02 rad out
    period = 2 * math.pi * math.sqrt(2 * L / (3 * g)) * (1 + theta0 ** 2 / 16)   # small-angle series
    steps = int(2.2 * period / dt)
    x, _, _ = simulate(scene, path, steps, dt, method)
    sway = x[:, 1, 0]
    up = np.flatnonzero((sway[:-1] > 0) & (sway[1:] <= 0))   # downward zero crossings, interpolated
    times = (up + sway[up] / (sway[up] - sway[up + 1]) + 1) * dt
    measured = times[1] - times[0]
    assert abs(measured - period) / period < 2e-5, (measured, period)   # lumped: 2 pi sqrt(L/g), 22 % longer


INEXTENSIBLE_PATHS = ["reference", "compiled", "run", "batch"]


@pytest.mark.parametrize("path", INEXTENSIBLE_PATHS)
def test_the_inextensible_method_spins_a_free_uniform_rod_with_a_twelfth_of_m_l_squared(path):
    """The rigid rod as an equality row of the inextensible method's QPs, its mass the block: it keeps its length,
    its linear and angular momentum ``m L^2 / 12 omega`` and its energy to round-off over 400 steps. Lumped at its
    ends the same motion carries ``m L^2 / 4 omega``, 3x (asserted on the reference's run)."""
    omega, drift = 3.0, np.array([0.2, -0.1, 0.3])   # rad/s about z, m/s of the centre
    half = 0.5 * L * omega
    velocities = [drift - [0.0, half, 0.0], drift + [0.0, half, 0.0]]
    scene = rod(velocities=velocities)
    x, v, _ = simulate(scene, path, 400, 1e-3, "inextensible")
    op = System(scene).mass
    centre = 0.5 * (x[:, 0] + x[:, 1])
    np.testing.assert_allclose(centre[-1], 0.5 * np.array([L, 0, 0]) + 0.4 * drift, rtol=0, atol=1e-12)
    spin = M * L * L / 12.0 * omega
    kinetic = 0.5 * M * drift @ drift + 0.5 * spin * omega
    for k in (0, 199, 399):
        np.testing.assert_allclose(rod_angular_momentum(x[k], v[k], (), "uniform", centre[k]), [0.0, 0.0, spin],
                                   rtol=1e-12, atol=1e-14)
        linear, angular = op.momentum(x[k] - centre[k], v[k])
        np.testing.assert_allclose(linear, M * drift, rtol=1e-12)
        np.testing.assert_allclose(angular, [0.0, 0.0, spin], rtol=1e-12, atol=1e-14)
        assert math.isclose(op.kinetic_energy(v[k]), kinetic, rel_tol=1e-12)
        np.testing.assert_allclose(np.linalg.norm(x[k, 1] - x[k, 0]), L, rtol=1e-14)
    if path == "reference":   # lumped: the same velocities, three times the spin's momentum and energy
        lumped = ts.Simulator(rod(distribution="ends", velocities=velocities), method="inextensible", dt=1e-3)
        lumped.step()
        linear, angular = lumped.momentum()
        angular = angular - np.cross(0.5 * (lumped.positions[0] + lumped.positions[1]), linear)
        np.testing.assert_allclose(angular, [0.0, 0.0, 3.0 * spin], rtol=1e-12, atol=1e-14)


TETHER, GAP, U = 0.5, 0.0105, 1.0   # m of the tether to node b, m of slack, m/s of the rod's drift across it
PAYLOADS = ((0.8, 1.5), (0.25, 0.4))


def tethered_rod(distribution="uniform"):
    """The rod with :data:`PAYLOADS` drifting at U across its axis away from a fixed anchor, tied to its end b by
    an inextensible cable GAP slack: it snaps taut after GAP / U = 10.5 ms."""
    d = rod(distribution=distribution, payloads=PAYLOADS, velocities=[[0.0, U, 0.0]] * 2).to_dict()
    d["nodes"].append({"name": "o", "position": [L, -TETHER, 0.0], "fixed": True})
    d["cables"] = [{"name": "t", "nodes": ["o", "b"], "rest_length": TETHER + GAP}]
    return ts.Scene.from_dict(d)


def effective_mass(distribution):
    """The rod's mass at its end b for a push across it, ``1 / (1/m + r_b^2 / I_c)``, from the integrals (its
    mass, centre ``c`` from node a and inertia ``I_c`` about it normal to the axis; ``r_b = (1 - c) L``)."""
    shares = [(0.5, M)] if distribution == "uniform" else [(0.0, 0.5 * M), (1.0, 0.5 * M)]
    total = M + sum(m for _, m in PAYLOADS)
    centre = sum(s * m for s, m in shares + list(PAYLOADS)) / total
    second = sum(s * s * m for s, m in list(PAYLOADS) + ([] if distribution == "uniform" else [(1.0, 0.5 * M)]))
    second += M / 3.0 if distribution == "uniform" else 0.0
    inertia = (second - total * centre ** 2) * L * L
    return 1.0 / (1.0 / total + ((1.0 - centre) * L) ** 2 / inertia)


@pytest.mark.parametrize("path", INEXTENSIBLE_PATHS)
def test_a_payload_rod_snapping_its_tether_taut_loses_its_effective_mass_times_u_squared_over_two(path):
    """Moreau's plastic impact at end b: the snap stops b's velocity along the cable, which takes ``m_eff U^2 / 2``
    of energy with ``m_eff`` the rod's effective mass there (its mass, centre and inertia with the payloads, from
    the integrals): to 1e-12. The energy then holds, the cable taut (no work), and the angular momentum about the
    anchor (the cable's pull passes through it) is kept throughout, to round-off. Lumped at its ends the rod's
    ``m_eff`` is 58 % larger (1.91 kg against 1.21), and so is the loss (the test below)."""
    scene = tethered_rod()
    x, v, _ = simulate(scene, path, 60, 1e-3, "inextensible")
    op = System(scene).mass
    energy = np.array([op.kinetic_energy(v[k]) for k in range(len(v))])
    start = op.kinetic_energy(scene.velocities)
    anchor = scene.positions[2]
    np.testing.assert_allclose(energy[:10], start, rtol=1e-15)   # the snap at 10.5 ms, inside step 11
    assert energy[10] < 0.9 * start
    np.testing.assert_allclose(start - energy[10:], 0.5 * effective_mass("uniform") * U ** 2, rtol=1e-12)
    h0 = op.momentum(scene.positions - anchor, scene.velocities)[1]
    for k in range(len(x)):
        np.testing.assert_allclose(op.momentum(x[k] - anchor, v[k])[1], h0, rtol=0, atol=1e-14)
    # taut at its limit, to the landing's bounded error (the method's module docstring; measured 5.6e-10 m)
    assert abs(np.linalg.norm(x[-1, 1] - anchor) - (TETHER + GAP)) <= 2e-9
    assert effective_mass("ends") > 1.5 * effective_mass("uniform")


def test_the_payload_rod_lumped_at_its_ends_loses_what_the_wrong_effective_mass_says():
    scene = tethered_rod("ends")
    x, v, _ = simulate(scene, "reference", 20, 1e-3, "inextensible")
    op = System(scene).mass
    lost = op.kinetic_energy(scene.velocities) - op.kinetic_energy(v[-1])
    assert math.isclose(lost, 0.5 * effective_mass("ends") * U ** 2, rel_tol=1e-12)
    assert lost > 1.5 * 0.5 * effective_mass("uniform") * U ** 2


def blocked_icosahedron():
    """The built-in icosahedron thrown and spun, its struts' mass spread along them and end caps on the nodes."""
    d = ts.load_scene("icosahedron").to_dict()
    rng = np.random.default_rng(7)
    for node in d["nodes"]:
        node["mass"] = 0.25
        node["velocity"] = list(rng.normal(0.0, 1.5, 3))
    for i, s in enumerate(d["struts"]):
        s["mass"] = 3.0
        s["payloads"] = [{"at": 0.3 + 0.1 * i, "mass": 0.5}]
    return ts.Scene.from_dict(d)


@pytest.mark.parametrize("method, path", [("elastic", p) for p in ["compiled", "run", "batch"] + (["jax"] if HAVE_JAX
                                                                                                else [])]
                         + [("inextensible", p) for p in ["compiled", "run", "batch"]])
def test_the_fast_paths_apply_the_blocks_as_the_numpy_reference_does(method, path):
    """The elastic method's compiled step, loop, batch and JAX backend, and the inextensible method's step kernel,
    compiled loop and batch loop (DAQP's C call in ``BlockMassSolver``'s coordinates, where the reference calls
    DAQP's wrapper), follow their numpy references to round-off (measured: the same bits for the inextensible
    method) through 300 steps of the thrown icosahedron with its rods' blocks (the inextensible method's locked:
    its published impulses by the self-stress rule), and keep its momentum."""
    scene = blocked_icosahedron()
    assert System(scene).mass.consistent
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")   # the inextensible method's prestress offsets (LengthOffsetWarning)
        x_ref, v_ref, ref = simulate(scene, "reference", 300, 1e-3, method)
        x, v, sim = simulate(scene, path, 300, 1e-3, method)
    assert ref._method.system.mass.consistent
    if method == "inextensible" and path != "batch":   # the blocks in the kernels, not a fallback to Python
        assert sim._method.has_loop()
    scale = max(1.0, float(np.max(np.abs(v_ref))))
    assert np.max(np.abs(x - x_ref)) <= 1e-12 * max(1.0, float(np.max(np.abs(x_ref))))
    assert np.max(np.abs(v - v_ref)) <= 1e-12 * scale
    # momentum through 300 steps of snapping cables, to round-off
    start = System(scene).mass.momentum(scene.positions, scene.velocities)
    end = ref.momentum()
    np.testing.assert_allclose(end[0], start[0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(end[1], start[1], rtol=0, atol=1e-12)


def test_every_method_and_backend_takes_the_blocks_without_a_warning():
    scene = rod(ground={"friction": 0.5}, gravity=(0.0, 0.0, -9.81), angle=0.0)
    with warnings.catch_warnings():   # the elastic method takes the blocks with a ground ...
        warnings.simplefilter("error")
        assert ts.Simulator(scene, method="elastic", dt=1e-3).system.mass.consistent
        ts.Simulator(rod(distribution="ends", ground={"friction": 0.5}), method="elastic", dt=1e-3)
        for ground in (None, {"friction": 0.5}):   # ... and so does the inextensible method, in flight and on it
            assert ts.Simulator(rod(ground=ground), method="inextensible", dt=1e-3).system.mass.consistent
        if HAVE_JAX:   # ... and the JAX backend, its ground too
            assert ts.Simulator(scene, method="elastic", dt=1e-3, backend="jax").system.mass.consistent
            assert BatchSimulator(scene, 2, method="elastic", dt=1e-3, backend="jax").system.mass.consistent


TILT = 0.3   # rad from the vertical


def standing_rod(distribution="uniform"):
    """The rod standing on frictionless ground on node a, TILT from the vertical, at rest."""
    return rod(distribution=distribution, gravity=(0.0, 0.0, -G_FALL), ground={"friction": 0.0, "restitution": 0.0},
               angle=-(math.pi / 2 - TILT))


G_FALL = 9.81


def falling_rate(theta, inertia):
    """The standing rod's angular speed (rad/s) at ``theta`` from the vertical, from rest at TILT: energy, with
    its centre falling on a vertical line (no horizontal force), ``m g L/2 (cos TILT - cos theta) = m (L/2)^2
    sin^2 theta w^2 / 2 + inertia w^2 / 2``."""
    drop = M * G_FALL * 0.5 * L * (math.cos(TILT) - np.cos(theta))
    return np.sqrt(2.0 * drop / (M * (0.5 * L) ** 2 * np.sin(theta) ** 2 + inertia))


def fall(scene, path, steps=300, dt=1e-3, method="elastic"):
    """The rod's centre (K, 3), its angle from the vertical (K,) and angular speed (K,: the angle's central
    differences, second order as the positions are; the velocities after a contact's closing kick are first
    order), and node a's heights."""
    x, _, _ = simulate(scene, path, steps, dt, method)
    d = x[:, 1] - x[:, 0]
    theta = np.arctan2(d[:, 0], d[:, 2])
    return 0.5 * (x[:, 0] + x[:, 1]), theta, np.gradient(theta, dt), x[:, 0, 2]


@pytest.mark.parametrize("method, path", [("elastic", p) for p in ["reference", "compiled", "run", "batch"]
                                          + (["jax"] if HAVE_JAX else [])]
                         + [("inextensible", p) for p in ["reference", "compiled", "run", "batch"]])
def test_a_rod_standing_on_frictionless_ground_falls_with_its_centre_on_a_vertical_line(path, method):
    """Its foot slides, its centre falls straight down (no horizontal force), and it turns as energy says with
    ``I = m L^2 / 12``: to 1e-5 relative through 300 steps (to 0.8 rad from the vertical; measured 3.1e-6 for the
    inextensible method, whose ground row holds the foot at 0 to 1e-17 m). Lumped at its ends (``I = m L^2 / 4``)
    it turns slower: 24 % at 0.7 rad (the test below)."""
    centre, theta, rate, foot = fall(standing_rod(), path, method=method)
    np.testing.assert_allclose(centre[:, :2], np.broadcast_to(centre[0, :2], centre[:, :2].shape), rtol=0, atol=1e-12)
    assert theta[-1] > 0.75 and np.all(np.diff(centre[:, 2]) < 0)
    assert np.all(np.abs(foot) <= 5e-6)   # on the ground (the drift's contact lands it at the step's end)
    later = (theta > 0.5) & (np.arange(len(theta)) < len(theta) - 1)
    np.testing.assert_allclose(rate[later], falling_rate(theta[later], M * L * L / 12.0), rtol=1e-5)


@pytest.mark.parametrize("method", ["elastic", "inextensible"])
def test_the_standing_rod_lumped_at_its_ends_falls_as_the_wrong_inertia_says(method):
    """The same fall with the rod's mass at its ends (what the ground paths did before issue 46): the centre still
    falls straight, but the turning follows ``I = m L^2 / 4`` and misses ``m L^2 / 12`` by over 20 %."""
    centre, theta, rate, _ = fall(standing_rod("ends"), "compiled", steps=400, method=method)
    np.testing.assert_allclose(centre[:, :2], np.broadcast_to(centre[0, :2], centre[:, :2].shape), rtol=0, atol=1e-12)
    later = (theta > 0.5) & (np.arange(len(theta)) < len(theta) - 1)
    np.testing.assert_allclose(rate[later], falling_rate(theta[later], M * L * L / 4.0), rtol=1e-5)
    assert np.all(rate[later] < 0.8 * falling_rate(theta[later], M * L * L / 12.0))


def blocked_icosahedron_on_the_ground():
    """:func:`blocked_icosahedron` dropped 5 cm onto ground with friction 0.6, its rods' blocks taken there."""
    d = blocked_icosahedron().to_dict()
    low = min(node["position"][2] for node in d["nodes"])
    for node in d["nodes"]:
        node["position"][2] += 0.05 - low
    d["gravity"] = [0.0, 0.0, -9.81]
    d["ground"] = {"friction": 0.6, "restitution": 0.0}
    return ts.Scene.from_dict(d)


@pytest.mark.parametrize("path", ["compiled", "run", "batch"] + (["jax"] if HAVE_JAX else []))
def test_the_fast_ground_paths_apply_the_blocks_as_the_numpy_reference_does(path):
    """Thrown, spun and landing on rough ground: the compiled step, loop and batch follow the reference (its QPs
    in ``BlockMassSolver``'s coordinates) through 300 steps to the reference's own tolerance (its QP fixed point
    answers to FIXED_POINT_TOL = 1e-10 of the impulse scale, the blocks' Newton to 1e-13; the blocks' numpy twin is
    held to 1e-12 in test_friction_blocks.py). Measured: 1.6e-12 m and 2.4e-11 of the speed scale."""
    scene = blocked_icosahedron_on_the_ground()
    x_ref, v_ref, _ = simulate(scene, "reference", 300, 1e-3)
    x, v, sim = simulate(scene, path, 300, 1e-3)
    assert path == "batch" or sim._method.system.mass.consistent
    scale = max(1.0, float(np.max(np.abs(v_ref))))
    assert np.max(np.abs(x - x_ref)) <= 1e-11 * max(1.0, float(np.max(np.abs(x_ref))))
    assert np.max(np.abs(v - v_ref)) <= 1e-10 * scale


def test_a_class_k_joint_lumps_the_struts_that_share_it():
    d = {"name": "vee", "nodes": [{"name": "a", "position": [0, 0, 0]}, {"name": "b", "position": [1, 0, 0]},
                                  {"name": "c", "position": [0, 1, 0]}],
         "struts": [{"name": "s0", "nodes": ["a", "b"], "stiffness": "rigid", "mass": 1.0},
                    {"name": "s1", "nodes": ["a", "c"], "stiffness": "rigid", "mass": 1.0}]}
    with pytest.warns(UserWarning) as caught:
        scene = ts.Scene.from_dict(d)
        op = MassOperator(scene, np.ones(3, dtype=bool))
    assert any(issubclass(w.category, LumpedMassWarning) and "['s0', 's1']" in str(w.message) for w in caught)
    assert not op.consistent
    np.testing.assert_array_equal(op.lumped, [1.0, 0.5, 0.5])


@pytest.mark.parametrize("method", ["elastic", "inextensible"])
def test_an_end_cap_radius_sets_where_a_node_touches_the_ground(method):
    d = rod(ground={"friction": 0.3}, gravity=(0.0, 0.0, -9.81), distribution="ends").to_dict()
    d["struts"][0]["radius"] = 0.01
    d["nodes"][0]["radius"] = 0.05    # an end cap at a, none at b: b rests on the strut's own radius
    d["nodes"][0]["position"] = [0.0, 0.0, 0.06]
    d["nodes"][1]["position"][2] = 0.03
    del d["struts"][0]["rest_length"]
    scene = ts.Scene.from_dict(d)
    np.testing.assert_array_equal(scene.node_radii, [0.05, 0.01])
    assert ts.Scene.from_dict(scene.to_dict()) == scene
    sim = ts.Simulator(scene, method=method, dt=1e-3)
    sim.run(duration=1.0)
    np.testing.assert_allclose(sim.positions[:, 2], [0.05, 0.01], rtol=0, atol=1e-6)


def test_the_block_mass_qp_meets_the_full_hessians_optimality_conditions():
    """``BlockMassSolver`` (the reference's QPs with the rods' blocks, solved in Schur coordinates by DAQP) on
    random member rows: its answer checked against the dense ``M`` independently, ``M (v - v0) = -A^T y``, the
    rows met, ``y >= 0`` on the inequalities and complementary; and it is not the lumped answer."""
    from tensegrity_sim.methods.qp.solvers import BlockMassSolver, Rows, make_solver

    scene = blocked_icosahedron()
    op = System(scene).mass
    solver = make_solver(None, scene.masses, op)
    assert isinstance(solver, BlockMassSolver)
    dense = np.kron(np.diag(op.diagonal), np.eye(3))
    for a, c in op.blocks:
        dense[3 * a: 3 * a + 3, 3 * c: 3 * c + 3] = dense[3 * c: 3 * c + 3, 3 * a: 3 * a + 3] = op.cross[a] * np.eye(3)
    rng = np.random.default_rng(3)
    ends = System(scene).ends
    for _ in range(20):
        members = rng.choice(len(ends), 12, replace=False)
        directions = rng.normal(size=(12, 3))
        directions /= np.linalg.norm(directions, axis=1)[:, None]
        rows = Rows(ends[members], directions, 0.2 * rng.normal(size=12), 3)
        v0 = rng.normal(size=(len(scene.nodes), 3))
        v, y = solver.solve(v0, rows)
        a = rows.dense(len(scene.nodes))
        np.testing.assert_allclose(dense @ (v - v0).ravel(), -a.T @ y, rtol=0, atol=1e-9)
        res = a @ v.ravel() - rows.targets
        assert np.abs(res[:3]).max() <= 1e-10 and res[3:].max() <= 1e-10
        assert y[3:].min() >= -1e-10 and np.abs(y[3:] * res[3:]).max() <= 1e-9
        lumped = make_solver(None, scene.masses).solve(v0, rows)[0]
        assert np.abs(lumped - v).max() > 1e-3


def test_three_bar_reeling_three_cables_runs_with_its_blocks_throughout():
    """``three_bar`` reeling c0, c1 and c5 to 40 % at once (rods landing and sliding at 1.6 m/s): at one step no
    mode fixed point or Newton start answers the contact problem with the rods' blocks (it was answered with the rods
    lumped, counted in ``lumped_solves``); the last resort (NSGS with steps along the null space) answers it with
    the blocks, the run goes on, nothing sunk. The step's problem itself: the test below."""
    from tensegrity_sim.commands import parse_commands

    scene = ts.load_scene("three_bar")
    rest = dict(zip(scene.cable_names, scene.cable_rest_lengths))
    cables = ("c0", "c1", "c5")
    points = [{"time": t, "rest_lengths": {c: float(f * rest[c]) for c in cables}}
              for t, f in ((0.0, 1.0), (0.4, 0.4), (1.2, 0.4), (1.6, 1.0))]
    sim = ts.Simulator(scene, method="elastic", dt=1e-3)
    traj = sim.run(duration=1.5, commands=parse_commands(points, scene, "reel"))
    assert sim.system.mass.consistent and len(traj.time) == 1500
    assert (traj.positions[:, :, 2] - scene.node_radii).min() > -1e-4


# the drift's contact problem of that run at t = 1.039 s: rod s0 lies on both ends (n0, n3), s1 and s2 touch with n4
# and n5; positions (m) and velocities after the first half-kick (m/s), the armed nodes, their targets (m/s)
REEL_STEP = {
    "x": [[1.3596367740659571e-01, 8.5692494575496783e-02, 2.9999992651662248e-02],
          [1.1811579645241514e-02, -3.6914272349638670e-04, 4.6003441101366851e-02],
          [-1.2588953362549501e-01, -1.3753448236383189e-01, 3.8345283378604614e-02],
          [-4.0502286645420593e-01, 3.4517938517097735e-01, 3.0336103695783923e-02],
          [-5.5500001701357027e-01, 1.9576553033013785e-01, 3.0009569799127320e-02],
          [-2.7760989144057563e-01, 4.4290611694777315e-01, 3.0000003560134103e-02]],
    "v": [[-1.6520654414672460e+00, 7.7312043369537542e-01, 1.8646879620789997e-03],
          [-1.4794394316167361e+00, 1.0005187524508456e+00, -1.3053196590786198e+00],
          [-6.3066806656496499e-02, 2.4223038085567143e+00, 8.0265636805510887e-01],
          [1.6675476646165350e+00, -6.6548507503088783e-01, -1.3980676836767938e+00],
          [1.5765752160116440e+00, -9.8204795519955079e-01, 6.2813696794854615e-02],
          [7.2752940835303548e-01, -1.1700473610917714e+00, -3.6037361930640048e-02]],
    "nodes": [0, 3, 4, 5], "touching": [True, False, False, False],
    "targets": [0.0, -3.3610369578392429e-01, -9.5707991273208115e-03, -3.5601341041857637e-06]}


def test_the_contact_problem_that_was_answered_lumped_is_answered_with_the_blocks():
    """:data:`REEL_STEP`'s problem through the reference's ``ContactSet.velocity_step``, checked independently of
    the solver: ``M (v' - v)`` with the rods' blocks is the ground's impulses plus equal-and-opposite impulses along
    each rod (with ``m`` per end in place of the blocks it is not: the rods' angular momentum); each rod keeps its
    length; each armed node meets ``v_z >= w`` with ``y_n (v_z - w) = 0``; and its friction meets Coulomb's law in
    its projection form
    ``f = proj_disc(mu y_n)(f - m v_t)`` to twice FIXED_POINT_TOL of the impulse scale (the solver's own
    tolerance), with no step to the physical tolerance (``relaxed`` stays 0)."""
    from tensegrity_sim.methods.contact.friction import FIXED_POINT_TOL

    sim = ts.Simulator(ts.load_scene("three_bar"), method="elastic", dt=1e-3)
    method, mass = sim._method, sim.system.mass
    ground = method.ground
    x, v = np.array(REEL_STEP["x"]), np.array(REEL_STEP["v"])
    nodes, targets = np.array(REEL_STEP["nodes"]), np.array(REEL_STEP["targets"])
    ground.solver.arm(nodes, targets, np.array(REEL_STEP["touching"]))
    out = ground.velocity_step(x, v, method.rigid)
    impulses = ground.take_impulses()
    assert ground.solver.relaxed == 0
    internal = mass.apply(out - v) - impulses
    scale = float(np.max(mass.lumped[:, None] * np.abs(v)))   # the momentum in play, N*s
    for a, c in method.rigid.ends:
        n = (x[c] - x[a]) / np.linalg.norm(x[c] - x[a])
        np.testing.assert_allclose(internal[a] + internal[c], 0.0, rtol=0, atol=1e-12 * scale)
        np.testing.assert_allclose(np.cross(internal[c], n), 0.0, rtol=0, atol=1e-12 * scale)
        assert abs(n @ (out[c] - out[a])) <= 1e-12 * np.abs(v).max()
    # read with the rods lumped, the same answer's strut impulses are not along the rods (its sums are: row sums)
    lumped = mass.lumped[:, None] * (out - v) - impulses
    a, c = method.rigid.ends[0]
    assert np.linalg.norm(np.cross(lumped[c], x[c] - x[a])) > 1e-3 * scale
    unarmed = np.setdiff1d(np.arange(6), nodes)
    assert np.all(impulses[unarmed] == 0.0)
    y, f, vz, vt = impulses[nodes, 2], impulses[nodes, :2], out[nodes, 2], out[nodes, :2]
    tol = 2.0 * FIXED_POINT_TOL * max(scale, float(np.abs(impulses).max()))
    assert np.all(y >= 0.0) and np.all(vz >= targets - 1e-12)
    assert np.all(y * (vz - targets) <= tol * np.abs(v).max())
    trial = f - (1.0 / mass.inv_diagonal[nodes])[:, None] * vt
    size = np.linalg.norm(trial, axis=1)
    radius = sim.scene.ground.friction * y
    projected = trial * np.minimum(1.0, radius / np.maximum(size, 1e-300))[:, None]
    assert np.linalg.norm(f - projected, axis=1).max() <= tol
    # the rod lying on both ends carries friction on both, one of them at its disc's edge (the null space's end)
    assert np.isclose(np.linalg.norm(f[0]), radius[0], rtol=1e-9) and y[1] > 0.0


# throw 24 of ``bench_throws.py --rods`` (seed 0): an icosahedron on end caps, its rods carrying 80 % of the mass
ROD_THROW = {"robot": "icosahedron_ground", "method": "elastic", "mu": 1.2861441637022353, "e": 0.0,
             "height": 0.32808233037668905, "velocity": [-1.670594922576476, 1.1823404740293975, -2.4887508284104767],
             "spin": [-5.774339644355363, 1.1828683291925552, 2.016443048794176], "command_step": 280,
             "command_cables": [8, 9, 20, 23], "command_factor": 1.0409363400244003, "steps": 212,
             "rods": [0.5855543456473643, 0.8722948482241771, 0.10709055111542465, 0.6125225345354264,
                      0.4050191246348116, 0.6749511610858301]}


def test_a_thrown_rod_end_is_armed_where_its_strut_carries_it_into_the_ground():
    """The drift's contacts with the rods' blocks (``ElasticMethod.verlet``): at step 182 of :data:`ROD_THROW` an end
    clear of the ground on its free velocity was carried 0.13 mm into it by zeroing its strut's length rate (the
    strut's axial rate under the block: 0.42 m/s), and at step 211 a rod landing on one end turned its other, unarmed
    end 0.39 mm into it (sunk until the run's end). Armed on the rate-free velocity too, and solved again with a
    node the answer carries into the ground: no node sinks past ``TOUCH_TOL`` (1 nm; 1 um asserted, the bench's
    bound is 0.1 mm), in the compiled loop and the numpy reference alike, which agree."""
    import throw_cases as T
    ends = {}
    for path in ("compiled", "reference"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            sim = ts.Simulator(T.throw_scene(ROD_THROW), method="elastic", dt=1e-3)
        assert sim._method.system.mass.consistent
        sim._method.compiled = path == "compiled"
        radii, sink = sim.scene.node_radii, 0.0
        for _ in range(ROD_THROW["steps"]):
            sim.step()
            sink = max(sink, float(-(sim.positions[:, 2] - radii).min()))
        assert sink <= 1e-6, (path, sink)
        ends[path] = sim.positions.copy()
    assert np.max(np.abs(ends["compiled"] - ends["reference"])) <= 1e-9
