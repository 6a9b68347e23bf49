"""BatchSimulator: every copy equals a single Simulator run from the same state with the same inputs;
the compiled batch equals the numpy batch; a failed QP stops its copy only; bad input changes nothing."""
import warnings

import numpy as np
import pytest

import tensegrity_sim as ts
from bench.cases import icosahedron_thrown, tower_kicked
from tensegrity_sim.batch import BatchSimulator
from tensegrity_sim.commands import parse_commands
from tensegrity_sim.methods.elastic.batch import ElasticBatch
from tensegrity_sim.system import System

TOL = 1e-10


def _quiet(factory):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")   # the inextensible method's prestress warning
        return factory()


def _scenes(kind: str):
    if kind == "icosahedron":
        return [icosahedron_thrown(scale=2.0, seed=s) for s in range(3)]
    return [tower_kicked(speed) for speed in (1.0, 2.0, 3.0)]


def _commands(k: int, rest0: np.ndarray, n_nodes: int):
    """Per copy: rest lengths (B, n_cables) at step k (a ramp on c1 and c2, different per copy) and
    forces (B, N, 3) from step 40 on (different per copy)."""
    b = rest0.shape[0]
    rest = rest0.copy()
    scale = 1.0 - 1e-4 * min(k, 30) * np.arange(1, b + 1)
    rest[:, 1] *= scale
    rest[:, 2] *= scale[::-1]
    forces = np.zeros((b, n_nodes, 3))
    if k >= 40:
        forces[:, 1] = np.outer(np.arange(1, b + 1), [3.0, -2.0, 1.0])
    return rest, forces


@pytest.mark.parametrize("kind", ["icosahedron", "tower"])
@pytest.mark.parametrize("method", ["elastic", "inextensible"])
def test_every_copy_equals_a_single_simulator(method, kind):
    scenes = _scenes(kind)
    dt = 1e-3 if kind == "icosahedron" else 2e-4
    batch = _quiet(lambda: BatchSimulator.from_scenes(scenes, method=method, dt=dt))
    singles = [_quiet(lambda s=s: ts.Simulator(s, method=method, dt=dt)) for s in scenes]
    assert batch.method == method and batch.batch == 3
    rest0 = batch.rest_lengths
    np.testing.assert_array_equal(rest0, [s.rest_lengths for s in singles])
    n = len(scenes[0].nodes)
    for k in range(80):
        if k <= 30 or k == 40:   # commands while ramping, then a force step
            rest, forces = _commands(k, rest0, n)
            batch.set_rest_lengths(rest)
            batch.set_external_forces(forces)
            for s, r, f in zip(singles, rest, forces):
                s.set_rest_lengths(r)
                s.set_external_forces(f)
        got = batch.step()
        assert got.time == pytest.approx((k + 1) * dt, rel=1e-15)
        for b, s in enumerate(singles):
            want = s.step()
            np.testing.assert_allclose(got.positions[b], want.positions, rtol=0, atol=TOL)
            np.testing.assert_allclose(got.velocities[b], want.velocities, rtol=0, atol=TOL * 100)
            np.testing.assert_allclose(got.impulses[b], want.impulses, rtol=0, atol=TOL)
            np.testing.assert_array_equal(got.slack[b], want.slack)
            assert [(e.kind, e.members) for e in got.contacts[b]] == [(e.kind, e.members) for e in want.contacts]
    # run() with every=k: the same kept steps, impulse sums and tensions as Simulator.run
    traj = batch.run(steps=45, every=10)
    assert traj.positions.shape == (3, 5, n, 3) and traj.impulses.shape == (3, 5, len(scenes[0].cables))
    for b, s in enumerate(singles):
        want = s.run(steps=45, every=10)
        np.testing.assert_allclose(traj.time, want.time, rtol=1e-15)
        np.testing.assert_allclose(traj.positions[b], want.positions, rtol=0, atol=TOL)
        np.testing.assert_allclose(traj.velocities[b], want.velocities, rtol=0, atol=TOL * 100)
        np.testing.assert_allclose(traj.impulses[b], want.impulses, rtol=0, atol=TOL)
        np.testing.assert_allclose(traj.tensions[b], want.tensions, rtol=0, atol=TOL / dt)
        np.testing.assert_array_equal(traj.slack[b], want.slack)
        assert len(traj.contacts[b]) == len(want.contacts)
        energy = s.energy()
        for key in ("kinetic", "strain", "gravity", "total"):
            assert batch.energy()[key][b] == pytest.approx(energy[key], rel=1e-10, abs=1e-9)
    assert batch.failures == {}


@pytest.mark.parametrize("method", ["elastic", "inextensible"])
def test_run_peaks_and_snaps_over_every_step(method):
    """peak_tensions and snaps count every step, kept or not: checked against a step-by-step single run."""
    scenes = _scenes("icosahedron")
    batch = _quiet(lambda: BatchSimulator.from_scenes(scenes, method=method, dt=1e-3))
    traj = batch.run(steps=300, every=300)
    for b, scene in enumerate(scenes):
        sim = _quiet(lambda: ts.Simulator(scene, method=method, dt=1e-3))
        was = sim.slack()
        peak, snaps = np.zeros(len(scene.cables)), np.zeros(len(scene.cables), dtype=int)
        for _ in range(300):
            r = sim.step()
            peak = np.maximum(peak, r.tensions)
            snaps += was & ~r.slack
            was = r.slack
        np.testing.assert_allclose(traj.peak_tensions[b], peak, rtol=1e-10, atol=1e-8)
        np.testing.assert_array_equal(traj.snaps[b], snaps)
        np.testing.assert_allclose(traj.positions[b, -1], sim.positions, rtol=0, atol=TOL)
    if method == "elastic":   # the thrown elastic icosahedron's cables go slack and snap; the inextensible
        assert traj.snaps.sum() > 0   # one is locked, its cables carry the prestress and stay taut (issue 20)


def test_inextensible_slack_of_the_copies_at_once_is_each_copys_slack():
    """BatchSimulator.slack of inextensible copies (InextensibleMethod.slack_copies, all copies at once) is each
    copy's own Simulator.slack, flag for flag, with some cables slack (lengthened rest lengths, different per copy,
    reached at the motors' speed) and some taut, before and after steps."""
    scenes = _scenes("icosahedron")
    batch = _quiet(lambda: BatchSimulator.from_scenes(scenes, method="inextensible", dt=1e-3))
    singles = [_quiet(lambda: ts.Simulator(scene, method="inextensible", dt=1e-3)) for scene in scenes]
    rest = np.stack([scene.cable_rest_lengths for scene in scenes])
    rest[:, ::2] *= 1.0 + 0.05 * np.arange(1, len(scenes) + 1)[:, None]
    batch.set_rest_lengths(rest)
    for sim, r in zip(singles, rest):
        sim.set_rest_lengths(r)
    seen = []
    for _ in range(4):
        want = np.stack([sim.slack() for sim in singles])
        np.testing.assert_array_equal(batch.slack(), want)
        seen.append(want)
        batch.run(steps=40)
        for sim in singles:
            sim.run(steps=40)
    assert np.any(seen) and not np.all(seen)


@pytest.mark.parametrize("batch_size", [3, 8])
def test_compiled_batch_equals_the_numpy_reference(batch_size):
    """Same arithmetic, so agreement to 1e-12; damped cables and a padding copy (B = 8) included."""
    d = icosahedron_thrown(scale=4.0).to_dict()
    for c in d["cables"]:
        c["damping"] = 3.0
    scene = ts.Scene.from_dict(d)
    system = System(scene)
    rng = np.random.default_rng(1)
    x = np.repeat(scene.positions[:, :, None], batch_size, axis=2)
    v = scene.velocities[:, :, None] * rng.uniform(0.5, 1.5, batch_size)
    rest = scene.cable_rest_lengths[:, None] * rng.uniform(1.0, 1.1, (len(scene.cables), batch_size))
    f_ext = rng.normal(size=x.shape)
    compiled, reference = ElasticBatch(system, 1e-3), ElasticBatch(system, 1e-3, compiled=False)
    v = compiled.prepare(x, v)
    got = compiled.advance(x, v, rest, f_ext, 150)
    got2 = compiled.advance(got[0][-1], got[1][-1], rest, f_ext, 50)   # the carried end forces
    want = reference.advance(x, v, rest, f_ext, 150)
    want2 = reference.advance(want[0][-1], want[1][-1], rest, f_ext, 50)
    for g, w in zip(got + got2, want + want2):
        assert g.shape == w.shape
        if g.dtype == bool:
            np.testing.assert_array_equal(g, w)
        else:
            np.testing.assert_allclose(g, w, rtol=0, atol=1e-12 * max(1.0, np.abs(w).max()))
    assert np.any(got[3]) and not np.all(got[3])   # some cables slack, some taut: the kink is exercised


def test_a_failed_qp_stops_its_copy_only():
    """The locked icosahedron (rigid struts, inextensible cables) cannot reel in a cable: copy 1 is
    commanded to, fails with the reason and keeps its last state; copies 0 and 2 go on as single runs."""
    scene = ts.load_scene("icosahedron")
    batch = _quiet(lambda: BatchSimulator(scene, 3, method="inextensible", dt=1e-3))
    singles = [_quiet(lambda: ts.Simulator(scene, method="inextensible", dt=1e-3)) for _ in range(3)]
    batch.run(steps=5)
    for s in singles:
        s.run(steps=5)
    rest = batch.rest_lengths
    rest[1, 0] -= 1e-4
    batch.set_rest_lengths(rest)
    for s, r in zip(singles, rest):
        s.set_rest_lengths(r)
    before = batch.positions
    r = batch.step()
    assert list(batch.failures) == [1]
    assert "c0 cannot be followed" in batch.failures[1] and batch.failures[1].startswith("step 6 ")
    np.testing.assert_array_equal(r.failed, [False, True, False])
    assert np.isnan(r.positions[1]).all() and np.isnan(r.impulses[1]).all()
    np.testing.assert_array_equal(batch.positions[1], before[1])
    with pytest.raises(ts.QPError):
        singles[1].step()
    traj = batch.run(steps=10)
    assert np.isnan(traj.positions[1]).all() and traj.failures == {1: batch.failures[1]}
    for b in (0, 2):
        singles[b].step()
        want = singles[b].run(steps=10)
        np.testing.assert_allclose(traj.positions[b], want.positions, rtol=0, atol=TOL)
    assert batch.time == pytest.approx(16e-3)


@pytest.mark.parametrize("method", ["elastic", "inextensible"])
def test_a_non_finite_copy_stops_alone_as_simulator_would(method):
    """An absurd force on copy 1 (Simulator raises a StepError: NonFiniteError, or for the inextensible
    method the QP's failure): that copy fails with the same message and keeps the state before the step;
    the others go on as single runs."""
    scenes = _scenes("icosahedron")
    batch = _quiet(lambda: BatchSimulator.from_scenes(scenes, method=method, dt=1e-3))
    singles = [_quiet(lambda s=s: ts.Simulator(s, method=method, dt=1e-3)) for s in scenes]
    batch.run(steps=7)
    for s in singles:
        s.run(steps=7)
    forces = np.zeros((3, len(scenes[0].nodes), 3))
    forces[1, 4] = [1e300, 0.0, 0.0]
    batch.set_external_forces(forces)
    for s, f in zip(singles, forces):
        s.set_external_forces(f)
    before = singles[1].positions
    with np.errstate(over="ignore", invalid="ignore"):
        traj = batch.run(steps=10)
        with pytest.raises(ts.NonFiniteError if method == "elastic" else ts.StepError) as err:
            singles[1].step()
    assert batch.failures == {1: f"step 8 (t = 0.008 s): {err.value}"}
    np.testing.assert_array_equal(batch.positions[1], before)
    np.testing.assert_array_equal(batch.step_counts, [17, 7, 17])
    assert np.isnan(traj.positions[1]).all() and not np.isnan(traj.positions[[0, 2]]).any()
    for b in (0, 2):
        want = singles[b].run(steps=10)
        np.testing.assert_allclose(traj.positions[b], want.positions, rtol=0, atol=TOL)


def test_initial_states_per_copy():
    """positions/velocities per copy: a rotated, moving icosahedron equals a single run of the scene
    written with that state."""
    scene = icosahedron_thrown(scale=1.0)
    c, s = np.cos(0.3), np.sin(0.3)
    rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    x = np.stack([scene.positions, scene.positions @ rot.T])
    v = np.stack([scene.velocities, scene.velocities @ rot.T])
    batch = BatchSimulator(scene, 2, method="elastic", positions=x, velocities=v)
    d = scene.to_dict()
    for node, p, u in zip(d["nodes"], x[1], v[1]):
        node["position"], node["velocity"] = list(p), list(u)
    single = ts.Simulator(ts.Scene.from_dict(d), method="elastic")
    traj = batch.run(steps=200, every=50)
    want = single.run(steps=200, every=50)
    np.testing.assert_allclose(traj.positions[1], want.positions, rtol=0, atol=TOL)
    # rotating the state rotates the motion (the scene has no gravity)
    np.testing.assert_allclose(traj.positions[1], traj.positions[0] @ rot.T, rtol=0, atol=1e-9)


def test_bad_input_is_refused_and_changes_nothing():
    scene = ts.load_scene("icosahedron")
    with pytest.raises(ValueError, match=r"batch must be a whole number >= 1, got 0"):
        BatchSimulator(scene, 0)
    with pytest.raises(ValueError, match=r"positions: expected shape \(2, 12, 3\) \(per copy\) or \(12, 3\) "
                                         r"\(every copy\), got \(3, 12, 3\)"):
        BatchSimulator(scene, 2, positions=np.zeros((3, 12, 3)))
    stretched = np.array([scene.positions, scene.positions * 1.01])
    with pytest.raises(ValueError, match=r"positions\[1\]: rigid strut 's0' has length"):
        BatchSimulator(scene, 2, method="elastic", positions=stretched)
    with pytest.raises(ValueError, match=r"scenes\[1\] \('prism3'\) differs from scenes\[0\]"):
        BatchSimulator.from_scenes([scene, ts.load_scene("prism3")])
    with pytest.raises(ValueError, match=r"method must be one of"):
        BatchSimulator(scene, 2, method="euler")
    batch = BatchSimulator(scene, 2, method="elastic")
    rest, forces = batch.rest_lengths, batch.external_forces
    for bad, match in [
        ({"c99": 1.0}, r"rest_lengths: unknown name 'c99'"),
        ({"c0": [1.0, 1.0, 1.0]}, r"rest_lengths\['c0'\]: expected shape \(\) \(every copy\) or \(2,\) \(per copy\)"),
        (np.ones(5), r"rest_lengths: expected shape \(2, 24\) \(per copy\) or \(24,\) \(every copy\), got \(5,\)"),
        ({"c3": [1.0, -1.0]}, r"rest_lengths\[1\]\['c3'\]: must be > 0, got -1.0"),
        ({"c3": [1.0, np.nan]}, r"rest_lengths\['c3'\] must be finite, got \[1.0, nan\]"),
        ("long", r"rest_lengths must be numbers, got 'long'"),
    ]:
        with pytest.raises(ValueError, match=match):
            batch.set_rest_lengths(bad)
    with pytest.raises(ValueError, match=r"external_forces\['n1'\]: expected shape \(3,\) \(every copy\)"):
        batch.set_external_forces({"n1": [1.0, 2.0]})
    np.testing.assert_array_equal(batch.rest_lengths, rest)
    np.testing.assert_array_equal(batch.external_forces, forces)
    with pytest.raises(ValueError, match=r"every must be a whole number >= 1, got 0"):
        batch.run(steps=3, every=0)
    assert batch.step_count == 0


def _thrown_on_ground(batch_size, seed=28):
    """icosahedron_ground lifted 20 cm and tilted, each copy thrown with its own velocity (the same for every
    node, so that no rigid strut's length rate needs projecting: the copies start exactly as single runs
    do), cables damped: landings on one end, bounces, sliding and sticking, lift-offs."""
    raw = ts.load_scene("icosahedron_ground").to_dict()
    raw["cables"] = [dict(c, damping=5.0) for c in raw["cables"]]
    scene = ts.Scene.from_dict(raw)
    rng = np.random.default_rng(seed)
    tilt = 0.3
    turn = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(tilt), -np.sin(tilt)], [0.0, np.sin(tilt), np.cos(tilt)]])
    x = np.repeat((scene.positions @ turn.T)[None], batch_size, axis=0) + [0.0, 0.0, 0.3]
    v = np.repeat(rng.normal(scale=1.0, size=(batch_size, 1, 3)), len(scene.nodes), axis=1)
    return scene, x, v


@pytest.mark.parametrize("method", ["elastic", "inextensible"])
def test_a_scene_with_a_ground_steps_in_the_compiled_batch_as_single_runs_do(method):
    """The batched elastic engine steps the ground (``_elastic_ground_kernels.ground_steps``, the copies
    spread over the cores), the inextensible copies their compiled steps likewise
    (``InextensibleMethod.advance_copies``, each landing's step by its copy's Python path): every copy
    equals a Simulator run from its state to 1e-12 (the same arithmetic), with the same ground contact
    events, through a rest-length command mid-run."""
    scene, x, v = _thrown_on_ground(6)
    batch = _quiet(lambda: BatchSimulator(scene, 6, method=method, dt=1e-3, positions=x, velocities=v,
                                          contacts=()))
    if method == "elastic":
        assert isinstance(batch._engine, ElasticBatch) and batch._copies is None
    else:
        assert batch._compiled_copies() == list(range(6))
    first = batch.run(steps=250, every=10)
    batch.set_rest_lengths({"c4": 0.6})
    second = batch.run(steps=250, every=10)
    events = 0
    for b in range(6):
        sim = _quiet(lambda: ts.Simulator(batch._with_state(scene, x[b], v[b], b), method=method, dt=1e-3,
                                          contacts=()))
        want = [sim.run(steps=250, every=10)]
        sim.set_rest_lengths({"c4": 0.6})
        want.append(sim.run(steps=250, every=10))
        for got, w in zip((first, second), want):
            np.testing.assert_allclose(got.positions[b], w.positions, rtol=0, atol=1e-12)
            np.testing.assert_allclose(got.velocities[b], w.velocities, rtol=0, atol=1e-12)
            # a kept step's impulses summed over its steps in another order: round-off of the locked
            # structure's large impulses
            np.testing.assert_allclose(got.impulses[b], w.impulses, rtol=1e-14, atol=1e-12)
            assert [(c.kind, c.members) for c in got.contacts[b]] == [(c.kind, c.members) for c in w.contacts]
            np.testing.assert_allclose([c.time for c in got.contacts[b]], [c.time for c in w.contacts], rtol=0,
                                       atol=1e-12)
            events += len(w.contacts)
    assert events > 6 * 3   # landings and lift-offs, not only three nodes touching down


def test_a_ground_batch_in_many_chunks_is_its_copies_stepped_alone():
    """The ground kernel steps a core's copies in chunks of ``CHUNK`` side by side, and a chunk of one copy in a
    compilation of its own (W = 1 a constant): 67 thrown copies go in chunks of 32, 32 and 3 on one thread and
    of 32 and 1, 32 and 2 on two (the same numbers), and every copy's positions and velocities are those of a
    Simulator stepping it alone, bit for bit, through a rest-length command mid-run."""
    import numba
    from tensegrity_sim.methods.elastic._ground_kernels import CHUNK

    copies = 2 * CHUNK + 3
    scene, x, v = _thrown_on_ground(copies, seed=11)
    runs = {}
    threads = numba.get_num_threads()
    for n in sorted({1, min(2, numba.config.NUMBA_NUM_THREADS)}):
        numba.set_num_threads(n)
        try:
            batch = BatchSimulator(scene, copies, method="elastic", dt=1e-3, positions=x, velocities=v, contacts=())
            first = batch.run(steps=150, every=50)
            batch.set_rest_lengths({"c4": 0.6})
            runs[n] = (first, batch.run(steps=150, every=50))
        finally:
            numba.set_num_threads(threads)
    one = runs[1]
    for got in runs.values():
        for a, b in zip(got, one):
            for field in ("positions", "velocities", "impulses"):
                np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    for b in range(copies):
        sim = ts.Simulator(BatchSimulator._with_state(scene, x[b], v[b], b), method="elastic", dt=1e-3,
                           contacts=())
        want = [sim.run(steps=150, every=50)]
        sim.set_rest_lengths({"c4": 0.6})
        want.append(sim.run(steps=150, every=50))
        for got, w in zip(one, want):
            for field in ("positions", "velocities"):
                np.testing.assert_array_equal(getattr(got, field)[b], getattr(w, field), err_msg=f"copy {b}")
            # (a kept step's impulses are summed in another order by the Simulator's run: round-off)
            np.testing.assert_allclose(got.impulses[b], w.impulses, rtol=1e-14, atol=1e-18, err_msg=f"copy {b}")
    assert np.ptp(one[1].positions[:, -1, :, 2].min(axis=1)) > 1e-3   # the copies went their own ways


def test_a_copy_whose_step_the_reference_cannot_take_on_the_ground_stops_alone(monkeypatch):
    """Regression: a copy whose ground step the compiled loop leaves to the reference (``UNSOLVED``) and the
    reference cannot take either (a ``StepError``) stopped every copy: the exception left ``ElasticBatch``'s
    run (Roll-v0's refused copy, stepped on from its absurd state, met it). Now that copy fails alone, with the
    reference's message, keeping its state before the step, and the others go on as a batch without it."""
    from tensegrity_sim.methods.elastic import _ground_kernels as ground_kernels
    from tensegrity_sim.methods.elastic.method import ElasticMethod

    scene, x, v = _thrown_on_ground(3, seed=2)
    healthy, batch = (BatchSimulator(scene, 3, method="elastic", dt=1e-3, positions=x, velocities=v, contacts=())
                      for _ in range(2))
    want = healthy.run(steps=20)
    batch.run(steps=10)
    before = batch.positions
    compiled = ground_kernels.ground_steps

    def copy_1_unsolved(x, v, *arguments):   # the kernel leaves copy 1's first step to the reference
        x1, v1 = x[..., 1].copy(), v[..., 1].copy()
        compiled(x, v, *arguments)
        x[..., 1], v[..., 1] = x1, v1
        failed, reason = arguments[-6], arguments[-5]   # (then the summary: peak, snaps, was_slack; then blocks)
        failed[1], reason[1] = 0, ground_kernels.UNSOLVED

    failure = ts.QPError("daqp", "non-finite", "the solution contains NaN or inf")

    def refused(*arguments, **keywords):
        raise failure

    monkeypatch.setattr(ground_kernels, "ground_steps", copy_1_unsolved)
    monkeypatch.setattr(ElasticMethod, "advance", refused)           # the retake's
    monkeypatch.setattr(ElasticMethod, "_step_reference", refused)   # the guard's report
    traj = batch.run(steps=10)
    assert batch.failures == {1: f"step 11 (t = 0.011 s): {failure}"}
    np.testing.assert_array_equal(batch.positions[1], before[1])
    assert np.isnan(traj.positions[1]).all()
    for b in (0, 2):
        np.testing.assert_array_equal(traj.positions[b], want.positions[b][10:])


@pytest.mark.parametrize("unsolved", [False, True])
def test_a_run_keeping_no_step_sums_its_steps_up_in_the_kernel(monkeypatch, unsolved):
    """A run on the ground that keeps no step (``fields=()``, no ground events: an environment's control period)
    has the kernel keep only the last step and count the peaks and snaps itself
    (``ElasticBatch.advance_summary``): the same state, peak tensions and snaps, bit for bit, as the run keeping
    every step's positions, through cables let out to slack and reeled in taut again (snaps). A copy whose step
    the kernel leaves to the reference (``unsolved``: copy 1's first step of each run, forced) makes the summary
    give up, changing nothing, and the run take every step as the full one does: the same numbers still."""
    from tensegrity_sim.methods.elastic import _ground_kernels as ground_kernels

    scene, x, v = _thrown_on_ground(4, seed=3)
    if unsolved:
        compiled = ground_kernels.ground_steps

        def copy_1_unsolved(x, v, *arguments):
            x1, v1 = x[..., 1].copy(), v[..., 1].copy()
            compiled(x, v, *arguments)
            x[..., 1], v[..., 1] = x1, v1
            failed, reason = arguments[-6], arguments[-5]
            failed[1], reason[1] = 0, ground_kernels.UNSOLVED

        monkeypatch.setattr(ground_kernels, "ground_steps", copy_1_unsolved)
    summarised = []
    summary = ElasticBatch.advance_summary

    def counted(self, *arguments):
        out = summary(self, *arguments)
        summarised.append(out is not None)
        return out

    monkeypatch.setattr(ElasticBatch, "advance_summary", counted)
    lean, full = (BatchSimulator(scene, 4, method="elastic", dt=1e-3, positions=x, velocities=v, contacts=())
                  for _ in range(2))
    # landing; every cable let out past slack by 0.15 s; reeled in taut by 0.25 s (the schedule run inside the kernel)
    schedule = parse_commands([{"time": t, "rest_lengths": dict(zip(scene.cable_names, (f * scene.cable_rest_lengths
                                                                                         ).tolist()))}
                               for t, f in ((0.05, 1.0), (0.15, 1.4), (0.25, 0.8))], scene)
    snaps = 0
    for _ in range(3):
        got = lean.run(steps=120, every=120, commands=schedule, fields=(), ground_events=False)
        want = full.run(steps=120, every=120, commands=schedule, fields=("positions",), ground_events=False)
        np.testing.assert_array_equal(lean.positions, full.positions)
        np.testing.assert_array_equal(lean.velocities, full.velocities)
        np.testing.assert_array_equal(lean.rest_lengths, full.rest_lengths)
        np.testing.assert_array_equal(got.peak_tensions, want.peak_tensions)
        np.testing.assert_array_equal(got.snaps, want.snaps)
        assert got.positions is None and lean.step_count == full.step_count
        # the slack cables at the end: the summary's own (kept for slack() and the next run's snaps) where it ran,
        # equal to those measured at the state
        assert (lean._known_slack is not None) == (not unsolved)
        np.testing.assert_array_equal(lean.slack(), full.slack())
        snaps += want.snaps.sum()
    assert snaps > 4 * 10 and want.peak_tensions.min() > 0
    assert summarised == [not unsolved] * 3
    # new rest lengths are another array: slack() measures again
    rest = lean.rest_lengths * 2.0
    lean.set_rest_lengths(rest)
    full.set_rest_lengths(rest)
    np.testing.assert_array_equal(lean.slack(), full.slack())
    assert lean.slack().all()


def test_the_batch_ground_kernel_equals_its_reference():
    """ElasticBatch with a ground, compiled against its reference (an ElasticMethod numpy reference per
    copy: friction.py's QP fixed point): the same states to that reference's tolerance."""
    scene, x, v = _thrown_on_ground(3, seed=5)
    system = System(scene)
    compiled, reference = ElasticBatch(system, 1e-3), ElasticBatch(system, 1e-3, compiled=False)
    x, v = np.moveaxis(x, 0, -1).copy(), np.moveaxis(v, 0, -1).copy()
    v = compiled.prepare(x, v)
    rest = np.repeat(scene.cable_rest_lengths[:, None], 3, axis=1)
    f_ext = np.zeros_like(x)
    got = compiled.advance(x, v, rest, f_ext, 200)
    want = reference.advance(x, v, rest, f_ext, 200)
    np.testing.assert_allclose(got[0], want[0], rtol=0, atol=1e-8)
    np.testing.assert_allclose(got[1], want[1], rtol=0, atol=1e-6)
    assert np.abs(reference.contact).max() > 0
    np.testing.assert_allclose(compiled.contact[:, :, 2], reference.contact[:, :, 2], rtol=0, atol=1e-7)


@pytest.mark.parametrize("records", [None, 1])
def test_a_scene_with_member_contact_response_equals_single_runs(monkeypatch, records):
    """A scene with ``contact: response: true`` steps in the compiled batch (the touching pairs' coupled blocks
    in the kernel, as in a Simulator's loop): B lands on A on the ground, rocks on it and slides once its
    cable is reeled in, each copy thrown a little differently. Every copy equals its Simulator run to round-off:
    positions, velocities, impulses, slack cables, and the member and ground contact events with their times
    and impulses; and without a ground (struts that would pass through each other stop on each other). With
    room for one step's pair impulses a call (``records`` 1), a copy stops where it runs out of room and goes
    on from its carry (``ElasticMethod.advance``), to the same numbers."""
    from test_member_contact import across, crossing

    from tensegrity_sim.methods.elastic import batch as elastic_batch

    if records is not None:
        monkeypatch.setattr(elastic_batch, "_PAIR_RECORDS", records)

    def same_events(got, want):
        assert [(e.kind, e.members) for e in got] == [(e.kind, e.members) for e in want]
        for field in ("time", "normal_impulse", "tangential_impulse"):
            np.testing.assert_allclose([getattr(e, field) for e in got], [getattr(e, field) for e in want], rtol=0,
                                       atol=TOL, err_msg=field)

    scene = across(0.2, 1.0)
    v = np.repeat(scene.velocities[None], 3, axis=0)
    v[:, 3] += [[0.0, 0.0, 0.0], [0.1, -0.05, 0.0], [-0.1, 0.0, -0.1]]
    batch = BatchSimulator(scene, 3, method="elastic", dt=1e-3, velocities=v)
    assert isinstance(batch._engine, ElasticBatch) and batch._copies is None
    runs = [batch.run(steps=450, every=7)]
    batch.set_rest_lengths([0.4])
    runs.append(batch.run(steps=450, every=7))
    impacts = 0
    for b in range(3):
        sim = ts.Simulator(batch._with_state(scene, scene.positions, v[b], b), method="elastic", dt=1e-3)
        want = [sim.run(steps=450, every=7)]
        sim.set_rest_lengths([0.4])
        want.append(sim.run(steps=450, every=7))
        assert sim._method.member_steps == sim._method.fallbacks == 0   # the kernel took every step
        for got, w in zip(runs, want):
            for field in ("positions", "velocities", "impulses"):
                np.testing.assert_allclose(getattr(got, field)[b], getattr(w, field), rtol=0, atol=TOL,
                                           err_msg=f"copy {b}: {field}")
            assert np.array_equal(got.slack[b], w.slack)
            same_events(got.contacts[b], w.contacts)
            impacts += any(e.members == ("A", "B") and e.kind == "begin" and e.normal_impulse > 0
                           for e in w.contacts)
    assert impacts >= 3
    scene = crossing(0.25)
    batch = BatchSimulator(scene, 2, method="elastic", dt=1e-3)
    single = ts.Simulator(scene, method="elastic", dt=1e-3)
    traj, want = batch.run(steps=60, every=30), single.run(steps=60, every=30)
    for b in range(2):
        np.testing.assert_allclose(traj.positions[b], want.positions, rtol=0, atol=TOL)
        same_events(traj.contacts[b], want.contacts)
    assert want.positions[-1, 2, 2] > 0.0   # B's ends stayed above A


def test_blocks_of_copies_on_threads_give_the_numbers_of_one_block(monkeypatch):
    """The free elastic batch's member-contact detection runs blocks of copies side by side on threads
    (``methods/_copy_blocks.py``: each block the very operations of the whole batch on its copies): three
    blocks give the positions, impulses, slack cables and contact events of one block, bit for bit."""
    import numba

    from tensegrity_sim.methods import _copy_blocks

    scenes = [icosahedron_thrown(scale=4.0, seed=s) for s in range(12)]   # struts that meet: contact events
    runs = {}
    for threads in (1, 3):
        monkeypatch.setattr(_copy_blocks, "MIN_BLOCK", 4)
        monkeypatch.setattr(numba, "get_num_threads", lambda t=threads: t)
        assert len(_copy_blocks.copy_blocks(12)) == threads
        runs[threads] = BatchSimulator.from_scenes(scenes, method="elastic").run(steps=400, every=9)
    one, three = runs[1], runs[3]
    for field in ("positions", "velocities", "impulses", "slack", "peak_tensions", "snaps"):
        np.testing.assert_array_equal(getattr(three, field), getattr(one, field))
    events = [[(e.kind, e.members, e.time) for e in c] for c in one.contacts]
    assert len({b // 4 for b, c in enumerate(events) if c}) >= 2   # events in more than one block
    assert [[(e.kind, e.members, e.time) for e in c] for c in three.contacts] == events


def test_inextensible_copies_walk_their_member_contacts_as_single_runs_do():
    """Rigid strut B thrown through rigid strut A on the ground (a slack inextensible cable between them,
    strut-strut detection without a response): each copy, its own throw, steps in the compiled copies' run
    and its detector walks those steps after it, giving the member and ground events and states of a single
    run from the same state, to the bit."""
    r = 0.01
    scene = ts.Scene.from_dict({
        "gravity": [0, 0, -9.81], "ground": {"height": 0.0, "friction": 0.5, "restitution": 0.0},
        "contact": {"kinds": ["strut_strut"]},
        "nodes": [{"name": "a0", "position": [-0.5, 0, r], "mass": 1.0},
                  {"name": "a1", "position": [0.5, 0, r], "mass": 1.0},
                  {"name": "b0", "position": [0.2, -0.5, 0.3], "mass": 1.0},
                  {"name": "b1", "position": [0.2, 0.5, 0.3], "mass": 1.0}],
        "struts": [{"name": "A", "nodes": ["a0", "a1"], "stiffness": "rigid", "radius": r},
                   {"name": "B", "nodes": ["b0", "b1"], "stiffness": "rigid", "radius": r}],
        "cables": [{"name": "c", "nodes": ["a1", "b1"], "rest_length": 1.2, "radius": 0.0}]})
    x = np.repeat(scene.positions[None], 3, axis=0)
    v = np.zeros((3, 4, 3))
    v[:, 2:] = [[0.3, 0.0, -1.5]]
    v[:, 2:, 0] += np.arange(3)[:, None] * 0.2   # each copy crosses A at its own place and time
    batch = BatchSimulator(scene, 3, method="inextensible", dt=1e-3, positions=x, velocities=v)
    assert batch._compiled_copies() == [0, 1, 2]
    got = batch.run(steps=300, every=7)
    for b in range(3):
        sim = ts.Simulator(batch._with_state(scene, x[b], v[b], b), method="inextensible", dt=1e-3)
        want = sim.run(steps=300, every=7)
        np.testing.assert_array_equal(got.positions[b], want.positions)
        np.testing.assert_array_equal(got.impulses[b], want.impulses)
        kinds = [(e.kind, e.members, e.time) for e in want.contacts]
        assert [(e.kind, e.members, e.time) for e in got.contacts[b]] == kinds
        assert {e.members for e in want.contacts} >= {("A", "B"), ("b0", "ground")}   # members and ground


@pytest.mark.parametrize("ground", [False, True])
def test_a_lighter_trajectory_holds_the_full_ones_numbers(monkeypatch, ground):
    """run(dtype="float32", fields=...) keeps exactly the float64 run's numbers rounded to float32, None for the
    fields left out, the same peaks and snaps; chunks that split a kept step (a small chunk) sum its impulses
    to round-off of one chunk's; every step kept equals those steps' every-1 numbers."""
    import tensegrity_sim.batch as batch_module

    if ground:
        scene = ts.load_scene("icosahedron_ground")
        scenes = [ts.Scene.from_dict({**scene.to_dict(), "nodes": [
            {**node, "velocity": [0.3 * s, -0.2, 0.1 * s]} for node in scene.to_dict()["nodes"]]}) for s in (1, 2)]
    else:
        scenes = _scenes("icosahedron")
    runs = {}
    for name, kwargs in {"full": {}, "float32": {"dtype": "float32", "fields": ["impulses", "positions"]},
                         "every1": {"every": 1}, "none": {"fields": ()}}.items():
        sim = BatchSimulator.from_scenes(scenes, method="elastic", contacts=())
        runs[name] = sim.run(steps=23, **{"every": 5, **kwargs})
    full, light = runs["full"], runs["float32"]
    assert light.velocities is None and light.slack is None and light.positions.dtype == np.float32
    for field in ("positions", "impulses", "tensions"):
        np.testing.assert_array_equal(getattr(light, field), getattr(full, field).astype(np.float32))
    for run in (light, runs["none"]):
        np.testing.assert_array_equal(run.peak_tensions, full.peak_tensions)
        np.testing.assert_array_equal(run.snaps, full.snaps)
    every1 = runs["every1"]
    np.testing.assert_array_equal(full.positions, every1.positions[:, [4, 9, 14, 19, 22]])
    np.testing.assert_array_equal(full.slack, every1.slack[:, [4, 9, 14, 19, 22]])
    want = np.add.reduceat(every1.impulses, [0, 5, 10, 15, 20], axis=1)
    np.testing.assert_allclose(full.impulses, want, rtol=1e-14, atol=1e-18)
    np.testing.assert_allclose(full.tensions, want / (np.array([5, 5, 5, 5, 3])[:, None] * 1e-3), rtol=1e-14)
    # chunks of 3 steps: kept steps of 5 cross chunk ends
    monkeypatch.setattr(batch_module, "_CHUNK_NUMBERS", 3 * len(scenes) * len(scenes[0].nodes) * 3)
    chunked = BatchSimulator.from_scenes(scenes, method="elastic", contacts=()).run(steps=23, every=5)
    np.testing.assert_array_equal(chunked.positions, full.positions)
    np.testing.assert_allclose(chunked.impulses, full.impulses, rtol=1e-14, atol=1e-18)
    with pytest.raises(ValueError, match="dtype must be 'float64' or 'float32'"):
        BatchSimulator.from_scenes(scenes, method="elastic").run(steps=2, dtype="int8")
    with pytest.raises(ValueError, match="fields: unknown field 'forces'"):
        BatchSimulator.from_scenes(scenes, method="elastic").run(steps=2, fields=["forces"])


def test_a_run_without_ground_events_steps_the_same():
    """ground_events=False finds no events and changes no number; a later run finds them again, those touching at
    its start beginning there (a fresh detector's rule)."""
    scene = ts.load_scene("icosahedron_ground")
    with_events, without = (BatchSimulator(scene, 2, method="elastic", contacts=()) for _ in range(2))
    full, bare = with_events.run(steps=150, every=50), without.run(steps=150, every=50, ground_events=False)
    assert sum(map(len, full.contacts)) > 0 and bare.contacts == [[], []]
    for field in ("positions", "velocities", "impulses", "slack"):
        np.testing.assert_array_equal(getattr(bare, field), getattr(full, field))
    again = without.run(steps=1)
    touching = {e.members for e in again.contacts[0] if e.kind == "begin"}
    fresh = BatchSimulator(scene, 2, method="elastic", contacts=(), positions=with_events.positions,
                           velocities=with_events.velocities)
    assert touching and touching == {e.members for e in fresh.run(steps=1).contacts[0] if e.kind == "begin"}


def test_inextensible_copies_rocking_on_the_ground_step_as_single_runs_do():
    """Two copies of the inextensible roll of ``examples/roll.yaml`` into its let-out, where the icosahedron rocks
    on its edges and the friction modes of many steps cycle: a copy whose last step cycled skips the copies'
    kernel (``_inextensible_kernels.copies_steps``' ``cycling``) and takes its step as a single run does, from
    the Newton method's last answer, so each copy equals a Simulator under the same schedule, bit for bit."""
    from pathlib import Path

    from tensegrity_sim.commands import load_commands

    scene = ts.load_scene("icosahedron_ground")
    schedule = load_commands(Path(__file__).resolve().parents[1] / "examples" / "roll.yaml", scene)
    batch = _quiet(lambda: BatchSimulator(scene, 2, method="inextensible", dt=1e-3, contacts=()))
    sim = _quiet(lambda: ts.Simulator(scene, method="inextensible", dt=1e-3, contacts=()))
    got = batch.run(steps=1450, every=50, commands=schedule)
    want = sim.run(steps=1450, every=50, commands=schedule)
    for b in range(2):
        np.testing.assert_array_equal(got.positions[b], want.positions)
        np.testing.assert_array_equal(got.velocities[b], want.velocities)
    assert sim._method.solver.resumed >= 10
    assert all(c._method.solver.resumed == sim._method.solver.resumed for c in batch._copies)
