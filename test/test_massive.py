"""The full model (physics.md §4b, ``method="massive"``): cables with stiffness and mass, a snap a plastic impact
on the cable's plate. Closed forms of the 1-D snap (a body m at speed v on an anchored cable k, m_c), the limits
m_c -> 0 (the elastic method) and k -> inf (restitution m*/(m* + m_c)), momentum through snaps and releases, and
energy falling by exactly the plates' losses."""
import math

import numpy as np
import pytest

import tensegrity_sim as ts
from tensegrity_sim.methods import choose_method, restitutions
from tensegrity_sim.methods.massive.method import plate_impact
from tensegrity_sim.system import System

L, GAP, V, M = 1.0, 0.05, 1.0, 1.0
OMEGA = 10.0   # rad/s: the taut oscillation of body and plate, sqrt(k / (m + m_c))


def bungee(plate: float, *, k: float | None = None, tangential: float = 0.0) -> ts.Scene:
    """A body of mass ``M`` at ``GAP`` short of an anchored cable's rest length ``L``, moving out along it at
    ``V`` (and across it at ``tangential``); the cable's mass ``plate``, stiffness ``k`` (default: the taut
    phase's angular frequency ``OMEGA``)."""
    k = OMEGA ** 2 * (M + plate) if k is None else k
    return ts.Scene.from_dict({
        "name": "bungee", "nodes": [{"name": "a", "position": [0, 0, 0], "fixed": True},
                                    {"name": "b", "position": [L - GAP, 0, 0], "mass": M,
                                     "velocity": [V, tangential, 0]}],
        "cables": [{"name": "c", "nodes": ["a", "b"], "stiffness": k, "rest_length": L, "mass": plate}]})


def closed_form(plate: float, t: float) -> float:
    """The body's position at time ``t`` (after the release): snap at GAP/V, taut for pi/omega, back out at
    the rebound speed m v/(m + m_c)."""
    after = M * V / (M + plate)
    release = GAP / V + math.pi / OMEGA
    return L - after * (t - release)


# ------------------------------------------------------------------ the scene field
def test_cable_mass_round_trips_and_is_checked():
    scene = bungee(0.25)
    assert scene.cables[0].mass == 0.25
    assert ts.Scene.from_dict(scene.to_dict()) == scene
    raw = scene.to_dict()
    raw["cables"][0]["mass"] = -1.0
    with pytest.raises(ts.SceneError, match=r"cables\[0\] 'c': mass must be >= 0, got -1.0"):
        ts.Scene.from_dict(raw)
    raw["cables"][0]["mass"] = float("nan")
    with pytest.raises(ts.SceneError, match=r"cables\[0\] 'c': mass"):
        ts.Scene.from_dict(raw)
    assert "mass" not in ts.load_scene("prism3").to_dict()["cables"][0]   # a massless cable is written as before


# ------------------------------------------------------------------ the snap's impact
def test_plate_impact_one_cable_and_a_moving_plate():
    # one cable: de+ = m* de-/(m* + m_c), p = m_c de+
    m_star, plate, rate = 2.0, 0.5, 3.0
    p = plate_impact(np.array([[1 / m_star + 1 / plate]]), np.array([rate]), np.array([True]))
    assert p[0] == pytest.approx(plate * m_star * rate / (m_star + plate), rel=1e-14)
    # a cable pulling away (rate <= 0) leaves its plate at rest
    assert plate_impact(np.array([[1.0]]), np.array([-1.0]), np.array([True]))[0] == 0.0
    # two cables on one body (m*: the same mass m), one already moving with its plate: the moving plate (m2)
    # joins the body, so the snapping one sees the mass m + m2
    m, m1, m2, rate = 1.0, 0.3, 0.7, 2.0
    g = np.array([[1 / m + 1 / m1, 1 / m], [1 / m, 1 / m + 1 / m2]])
    p = plate_impact(g, np.array([rate, rate]), np.array([True, False]))
    after = (m + m2) * rate / (m + m2 + m1)
    assert p[0] == pytest.approx(m1 * after, rel=1e-13)
    assert p[1] == pytest.approx(m2 * (after - rate), rel=1e-13)


# ------------------------------------------------------------------ 1-D closed forms
@pytest.mark.parametrize("ratio", [1e-3, 0.1, 1.0, 10.0])
def test_one_dimensional_snap_closed_forms(ratio):
    """Speed after the snap, largest stretch, time taut, rebound speed, kinetic energy kept and the loss, for
    m_c/m from 1e-3 to 10; the position after the release converges at order 2 (located snap and release)."""
    plate = ratio * M
    duration = GAP / V + math.pi / OMEGA + 0.05
    errors = []
    for dt in (2e-3, 1e-3):
        sim = ts.Simulator(bungee(plate), method="massive", dt=dt)
        # the snap falls on a step's end here: the speed just after it is the impact's to round-off
        snap = sim.run(steps=round(GAP / V / dt))
        assert snap.velocities[-1, 1, 0] == pytest.approx(M * V / (M + plate), rel=1e-9)
        assert snap.impulses[-1, 0] == pytest.approx(plate * M * V / (M + plate), rel=1e-6)
        traj = sim.run(steps=round((duration - GAP / V) / dt))
        stretch = traj.positions[:, 1, 0].max() - L
        assert stretch == pytest.approx(M * V / math.sqrt(OMEGA ** 2 * (M + plate) * (M + plate)), rel=5e-3)
        x, v = traj.positions[-1, 1, 0], traj.velocities[-1, 1, 0]
        rebound = M * V / (M + plate)
        assert -v == pytest.approx(rebound, rel=1e-6)
        # time taut: from the snap to where the body's line after the release crosses the rest length
        release = sim.time + (x - L) / rebound
        assert release - GAP / V == pytest.approx(math.pi / OMEGA, rel=0.1 * (OMEGA * dt) ** 2)   # Verlet: O(dt^2)
        kept = sim.energy()["kinetic"] / (0.5 * M * V * V)
        assert kept == pytest.approx((M / (M + plate)) ** 2, rel=1e-6)
        assert sim.energy_lost == pytest.approx(0.5 * M * V * V * (1 - (M / (M + plate)) ** 2), rel=1e-6)
        errors.append(abs(x - closed_form(plate, sim.time)))
    assert errors[0] / errors[1] > 3.0   # order 2 or better


def test_taut_time_and_stretch_do_not_depend_on_where_the_snap_falls():
    """The snap located inside a step (not on its end): the rebound's closed form to O(dt^2)."""
    plate = 0.5
    errors = []
    for dt in (1.3e-3, 0.65e-3):
        sim = ts.Simulator(bungee(plate), method="massive", dt=dt)
        sim.run(duration=0.45)
        errors.append(abs(sim.positions[1, 0] - closed_form(plate, sim.time)))
    assert errors[1] < 1e-6 and errors[0] / errors[1] > 3.0


# ------------------------------------------------------------------ the limits
def _free_scene(name: str, plate: float, *, gravity=False) -> ts.Scene:
    """``name`` (struts made elastic, 1e5 N/m) thrown free: a spin and a stretch of every node from the centre,
    so that cables slacken and snap; every cable carries ``plate`` kg."""
    raw = ts.load_scene(name).to_dict()
    rng = np.random.default_rng(7)
    x = np.array([n["position"] for n in raw["nodes"]])
    centre = x.mean(axis=0)
    v = np.cross([0.3, -0.5, 2.0], x - centre) + 1.5 * rng.normal(size=x.shape)
    v -= v.mean(axis=0)
    for node, vi in zip(raw["nodes"], v):
        node["velocity"] = [float(a) for a in vi]
    for s in raw["struts"]:
        s["stiffness"] = 1e5
        s["rest_length"] = float(np.linalg.norm(np.subtract(*[x[[n["name"] for n in raw["nodes"]].index(e)]
                                                                for e in s["nodes"]])))
    for c in raw["cables"]:
        c["mass"] = plate
    if gravity:
        raw["gravity"] = [0.0, 0.0, -9.81]
    return ts.Scene.from_dict(raw)


def test_massless_limit_is_the_elastic_method_with_error_proportional_to_the_mass():
    """m_c -> 0: the trajectory tends to the elastic method's (located switches, the same arithmetic at
    m_c = 0), the difference proportional to m_c (log-log slope 1)."""
    steps = 300
    reference = ts.Simulator(_free_scene("prism3", 0.0), method="elastic", dt=5e-4, locate_switches=True)
    x_ref = reference.run(steps=steps).positions[-1]
    zero = ts.Simulator(_free_scene("prism3", 0.0), method="massive", dt=5e-4).run(steps=steps).positions[-1]
    assert np.abs(zero - x_ref).max() < 1e-10
    plates = np.array([1e-4, 1e-5, 1e-6])
    errors = []
    for plate in plates:
        sim = ts.Simulator(_free_scene("prism3", plate), method="massive", dt=5e-4)
        errors.append(np.abs(sim.run(steps=steps).positions[-1] - x_ref).max())
    slope = np.polyfit(np.log(plates), np.log(errors), 1)[0]
    assert 0.9 < slope < 1.1, (errors, slope)


def test_stiff_limit_restitution_is_the_mass_ratio():
    """k -> inf at fixed m_c: an oblique snap (the cable turns while taut) tends to the instantaneous one, the
    radial speed kept m/(m + m_c), the tangential one untouched; the error falls as the taut time does."""
    plate, across = 0.5, 0.8
    # where the free flight meets the rest length: (L - GAP + V t)^2 + (across t)^2 = L^2
    a, b, c = V * V + across * across, 2 * (L - GAP) * V, (L - GAP) ** 2 - L * L
    t = (-b + math.sqrt(b * b - 4 * a * c)) / (2 * a)
    out = np.array([L - GAP + V * t, across * t, 0.0]) / L
    v0 = np.array([V, across, 0.0])
    radial = v0 @ out
    # the instantaneous snap: the radial rate reversed and scaled by the restitution, the rest untouched
    want = v0 - (1 + M / (M + plate)) * radial * out
    misses = []
    for k in (1e3, 1e5):
        dt = 0.05 / math.sqrt(k / M)
        sim = ts.Simulator(bungee(plate, k=k, tangential=across), method="massive", dt=dt)
        sim.run(duration=t + 4 * math.pi * math.sqrt((M + plate) / k))
        assert sim.slack()[0]
        misses.append(np.abs(sim.velocities[1] - want).max())
    assert misses[1] < 0.02 * V and misses[1] < misses[0] / 5, misses


def test_heavy_plates_make_the_snap_plastic():
    """m_c >> m*: the rebound speed m v/(m + m_c) tends to method 1's zero."""
    sim = ts.Simulator(bungee(1e4), method="massive", dt=1e-4)
    sim.run(duration=GAP / V + math.pi / OMEGA + 0.01)
    assert abs(sim.velocities[1, 0]) == pytest.approx(M * V / (M + 1e4), rel=1e-6)
    assert abs(sim.velocities[1, 0]) < 1e-3 * V


# ------------------------------------------------------------------ invariants
@pytest.mark.parametrize("name", ["prism3", "icosahedron"])
def test_momentum_exact_and_energy_falls_by_the_plates_losses(name):
    """Thrown free with massive cables: momentum to round-off through every snap and release; the energy
    falls, and what it loses is the plates' losses up to Verlet's O(dt^2) error (halving dt quarters it)."""
    scene = _free_scene(name, 0.05)
    scale = float(np.sum(scene.masses[:, None] * np.abs(scene.velocities)))
    residuals = []
    for dt in (2.5e-4, 1.25e-4):
        sim = ts.Simulator(scene, method="massive", dt=dt)
        p0, l0 = sim.momentum()
        e0 = sim.energy()["total"]
        traj = sim.run(duration=0.1)
        p1, l1 = sim.momentum()
        assert np.abs(p1 - p0).max() < 1e-13 * scale
        assert np.abs(l1 - l0).max() < 2e-13 * scale
        switches = np.abs(np.diff(traj.slack.astype(int), axis=0)).sum()
        assert switches >= 2 and sim.energy_lost > 5e-4 * e0   # snaps and releases happened, and lost energy
        assert sim.energy()["total"] < e0 - 0.5 * sim.energy_lost
        residuals.append(abs(sim.energy()["total"] + sim.energy_lost - e0) / e0)
    assert residuals[1] < 5e-4 and residuals[0] / residuals[1] > 3.0, residuals


def test_energy_kept_between_events_counts_the_moving_plates():
    """While a massive cable is taut, the plate's kinetic energy is part of the kinetic energy."""
    sim = ts.Simulator(bungee(1.0), method="massive", dt=1e-3)
    sim.run(steps=round(GAP / V / 1e-3) + 20)
    e = sim.energy()
    rate = sim.velocities[1, 0]
    assert e["kinetic"] == pytest.approx(0.5 * (M + 1.0) * rate ** 2, rel=1e-12)
    assert e["total"] + sim.energy_lost == pytest.approx(0.5 * M * V * V, rel=1e-6)


# ------------------------------------------------------------------ auto and refusals
def test_auto_chooses_among_three_and_says_why():
    sys = System(bungee(0.5))
    assert restitutions(sys)[0] == pytest.approx(M / (M + 0.5))
    method, reason = choose_method(sys, 1e-3)
    assert method == "massive" and "c: 0.667" in reason
    method, reason = choose_method(System(bungee(1e-4)), 1e-3)   # restitution ~1: massless cables' methods
    assert method in ("elastic", "inextensible") and "massive" not in reason
    assert choose_method(System(bungee(0.0)), 1e-3)[0] == "elastic"
    sim = ts.Simulator(bungee(0.5), method="auto", dt=1e-3)
    assert sim.method == "massive" and sim.method_settings["locate_switches"] is True


def test_refuses_what_it_cannot_step_yet():
    with pytest.raises(ValueError, match="located switches are not available with contacts"):
        ts.Simulator(ts.Scene.from_dict({**bungee(0.5).to_dict(), "contact": {"response": True}}), method="massive",
                     locate_switches=True)
    with pytest.raises(ValueError, match="reel_speed=2.0 is an option of the inextensible method; method 'massive'"):
        ts.Simulator(bungee(0.5), method="massive", reel_speed=2.0)


# ------------------------------------------------------------------ the compiled kernel against the reference
def _damped(scene: ts.Scene) -> ts.Scene:
    raw = scene.to_dict()
    for c in raw["cables"]:
        c["damping"] = 5.0
    return ts.Scene.from_dict(raw)


@pytest.mark.parametrize("case, options", [
    ("prism3", {}), ("icosahedron", {}), ("icosahedron", {"order": 4}), ("prism3", {"locate_switches": False}),
    ("prism3 damped", {}), ("drop", {})])
def test_kernel_matches_the_numpy_reference(case, options):
    """Snaps (one at a time, and three together in the drop), releases, moving plates, damping, order 4: the
    numba step is the reference's arithmetic to 1e-12."""
    if case == "drop":   # prism3 on its fixed bottom triangle, cables 3 cm slack, under gravity: three snap at once
        raw = ts.load_scene("prism3").to_dict()
        for n in raw["nodes"][:3]:
            n["fixed"] = True
        for c in raw["cables"]:
            c["rest_length"] += 0.03
            c["mass"] = 0.2
        raw["gravity"] = [0.0, 0.0, -9.81]
        scene, dt, steps = ts.Scene.from_dict(raw), 1e-4, 700
    else:
        scene, dt, steps = _free_scene(case.split()[0], 0.05), 2.5e-4, 300
        if case.endswith("damped"):
            scene = _damped(scene)
    runs = []
    for compiled in (True, False):
        sim = ts.Simulator(scene, method="massive", dt=dt, **options)
        sim._method.compiled = compiled
        runs.append((sim.run(steps=steps), sim.energy_lost))
    (a, lost_a), (b, lost_b) = runs
    assert np.abs(np.diff(b.slack.astype(int), axis=0)).sum() >= 1 and lost_b > 0
    assert np.abs(a.positions - b.positions).max() < 1e-12
    assert np.abs(a.velocities - b.velocities).max() < 1e-12 * np.abs(b.velocities).max()
    assert np.abs(a.impulses - b.impulses).max() < 1e-12
    assert lost_a == pytest.approx(lost_b, rel=1e-12, abs=1e-14)


def test_kernel_solves_the_plates_system_as_a_dense_solve():
    """The kernel's G (built node by node over shared nodes) and its envelope factor in the cables' RCM order,
    with some plates at rest (their rows identity rows in the scene's fixed envelope), against the reference's
    dense G and numpy's solve; the resting plates' unknowns come out exactly 0."""
    from tensegrity_sim.methods.massive import _kernels as kernels
    sim = ts.Simulator(_free_scene("icosahedron", 0.05), method="massive", dt=2.5e-4)
    method = sim._method
    model, dirs = method._model, method._start[4]
    rows, plated, envelope, pairs, signs = model[9:14]
    nc, n_struts = len(plated), sim.system.n_struts
    assert sorted(plated) == list(range(nc)) and (rows[plated] == np.arange(nc)).all()
    held = np.arange(nc) % 5 != 2                       # four in five of the rows
    mask = np.zeros(nc, dtype=bool)
    mask[plated[held]] = True
    g, rdiag = np.zeros((nc, nc)), np.empty(nc)
    assert kernels._delassus(mask, dirs, n_struts, model[0], model[5], model[8], plated, envelope, pairs, signs,
                             g) == held.sum()
    dense = method._delassus(plated[held], dirs[n_struts + plated[held]])
    lower = np.tril(g)
    assert np.array_equal(lower[np.ix_(held, held)] != 0, np.tril(dense) != 0)   # the envelope holds every coupling
    assert np.abs(lower[np.ix_(held, held)] - np.tril(dense)).max() < 1e-14 * np.abs(dense).max()
    assert np.array_equal(lower[~held], np.eye(nc)[~held]) and not lower[:, ~held][held].any()
    assert 0 < envelope.max() and (envelope <= np.arange(nc)).all()
    assert all(envelope[r] <= p < r for r, p, _ in pairs)
    rhs = np.where(held, np.random.default_rng(3).normal(size=nc), 0.0)
    y = rhs.copy()
    kernels._factor(g, envelope, rdiag, y)   # the factor and the forward substitution, then the backward
    kernels._back(g, envelope, rdiag, y)
    assert np.abs(y[held] - np.linalg.solve(dense, rhs[held])).max() < 1e-13 * np.abs(y).max()
    assert not y[~held].any()


def test_run_loop_equals_single_steps_and_losses_follow_the_present():
    """run() in the kernel's loop, and step() (steps computed ahead in it, rewound when an input changes): the
    same numbers, and energy_lost is the present's, not that of the steps computed ahead."""
    scene = _free_scene("prism3", 0.05)
    loop = ts.Simulator(scene, method="massive", dt=2.5e-4)
    traj = loop.run(steps=200)
    single = ts.Simulator(scene, method="massive", dt=2.5e-4)
    lost = []
    for k in range(200):
        r = single.step()
        assert np.array_equal(r.positions, traj.positions[k]) and np.array_equal(r.impulses, traj.impulses[k])
        lost.append(single.energy_lost)
    assert single.energy_lost == loop.energy_lost > 0
    assert lost == sorted(lost) and lost[0] < lost[-1]   # read step by step, the losses grow as they happen
    single.set_rest_lengths(single.rest_lengths * 0.99)   # an input: the steps ahead dropped, the losses kept
    assert single.energy_lost == loop.energy_lost


def test_batch_copies_step_the_massive_method():
    """BatchSimulator: one simulator per copy; each copy's rebound is its own closed form m v/(m + m_c)."""
    speeds = np.array([1.0, 0.5])
    v = np.zeros((2, 2, 3))
    v[:, 1, 0] = speeds
    batch = ts.BatchSimulator(bungee(0.5), 2, method="massive", dt=1e-3, velocities=v)
    traj = batch.run(steps=600)
    assert batch.method_reason == "massive: requested"
    assert traj.velocities[:, -1, 1, 0] == pytest.approx(-M * speeds / (M + 0.5), rel=1e-6)


def test_work_precision_case_is_its_closed_form_at_order_two():
    """bench's plate_snap case (the work-precision study's for this method): its closed form (position,
    velocity, the cable's impulse: the body's momentum change) is what the method converges to at order 2."""
    from bench.cases import work_precision_cases
    case = next(c for c in work_precision_cases() if c.name == "plate_snap")
    want = case.exact("massive")
    errors = []
    for dt in (2e-3, 1e-3):
        sim = ts.Simulator(case.scene, method="massive", dt=dt)
        traj = sim.run(steps=round(case.duration / dt), every=round(case.duration / dt))
        assert sim.time == pytest.approx(case.duration, rel=1e-12)
        assert traj.impulses[0] == pytest.approx(want.impulses, rel=1e-9)
        assert sim.velocities[1] == pytest.approx(want.velocities[1], abs=1e-8)
        errors.append(np.abs(sim.positions - want.positions).max())
    assert errors[1] < 1e-6 and 3.5 < errors[0] / errors[1] < 4.5, errors
