"""The JAX backend of the elastic method (methods/jax/) against the numba batch, to 1e-12 in float64: free,
damped, elastic and rigid struts, commands (rest-length ramps and force steps, per copy) and ``every``;
``Simulator(backend="jax")`` against the numba ``Simulator``; float32's error; a missing JAX refused with a
message naming the extra; bad input refused.

Skipped only where JAX is not installed (CI's ROS leg); ``TENSEGRITY_SIM_REQUIRE_JAX=1`` (CI's no-ROS leg)
makes a missing JAX an error. Small scenes and few steps: each new run length compiles (seconds)."""
import os
import subprocess
import sys

import numpy as np
import pytest

import tensegrity_sim as ts
from bench.cases import icosahedron_thrown, tower_kicked
from tensegrity_sim.batch import BatchSimulator
from tensegrity_sim.commands import parse_commands

if os.environ.get("TENSEGRITY_SIM_REQUIRE_JAX") == "1":
    import jax  # noqa: F401  (an ImportError here fails the leg that must run these tests)
else:
    pytest.importorskip("jax")

TOL = 1e-12   # relative to each quantity's largest magnitude


def _close(actual, expected, what):
    actual, expected = np.asarray(actual, dtype=float), np.asarray(expected, dtype=float)
    scale = max(1.0, float(np.max(np.abs(expected))))
    err = float(np.max(np.abs(actual - expected)))
    assert err <= TOL * scale, f"{what}: max difference {err:.3g} (scale {scale:.3g})"


def _same_run(a, b):
    for f in ("positions", "velocities", "impulses", "tensions", "peak_tensions"):
        _close(getattr(b, f), getattr(a, f), f)
    np.testing.assert_array_equal(b.slack, a.slack)
    np.testing.assert_array_equal(b.snaps, a.snaps)
    np.testing.assert_array_equal(b.time, a.time)


def _damped(scene: ts.Scene, damping: float) -> ts.Scene:
    d = scene.to_dict()
    for c in d["cables"]:
        c["damping"] = damping
    return ts.Scene.from_dict(d)


def _scenes(kind):
    if kind == "icosahedron":   # rigid struts, no gravity, cables going slack and snapping taut
        return [icosahedron_thrown(scale=2.0, seed=s) for s in range(3)], 1e-3
    if kind == "damped":
        return [_damped(icosahedron_thrown(scale=2.0, seed=s), 3.0) for s in range(3)], 1e-3
    return [tower_kicked(speed) for speed in (1.0, 2.0, 3.0)], 2e-4   # elastic struts, gravity, a fixed base


@pytest.mark.parametrize("kind", ["icosahedron", "damped", "tower"])
def test_free_runs_equal_the_numba_batch(kind):
    scenes, dt = _scenes(kind)
    numba = BatchSimulator.from_scenes(scenes, method="elastic", dt=dt)
    jax_ = BatchSimulator.from_scenes(scenes, method="elastic", dt=dt, backend="jax")
    assert jax_.method == "elastic" and jax_.backend == "jax"
    a, b = numba.run(steps=300, every=7), jax_.run(steps=300, every=7)
    assert a.snaps.sum() > 0   # the regime this backend must get right: slack/taut switches
    _same_run(a, b)
    # the run goes on from the carried forces, and a held force (an input change between runs) is taken
    for sim in (numba, jax_):
        sim.set_external_forces({scenes[0].node_names[1]: [3.0, -2.0, 1.0]})
    _same_run(numba.run(steps=300, every=7), jax_.run(steps=300, every=7))
    _close(jax_.positions, numba.positions, "final positions")


def _schedules(scene: ts.Scene, b: int):
    """Per copy: a ramp of two cables (different per copy), a hold, a force step on and off."""
    c, n = scene.cable_names, scene.node_names
    out = []
    for k in range(b):
        r1, r2 = scene.cables[1].rest_length, scene.cables[2].rest_length
        points = [{"time": 0.0, "rest_lengths": {c[1]: r1, c[2]: r2}},
                  {"time": 0.03, "rest_lengths": {c[1]: r1 * (1 - 0.02 * (k + 1))}},
                  {"time": 0.05, "rest_lengths": {c[2]: r2 * (1 - 0.01 * (k + 1))},
                   "forces": {n[1]: [3.0 * k, -2.0, 1.0]}},
                  {"time": 0.12, "forces": {n[1]: [0.0, 0.0, 0.0]}}]
        out.append(parse_commands(points, scene))
    return out


@pytest.mark.parametrize("kind", ["damped", "tower"])
def test_commands_inside_the_run_equal_the_numba_batch(kind):
    scenes, dt = _scenes(kind)
    schedules = _schedules(scenes[0], 3)
    numba = BatchSimulator.from_scenes(scenes, method="elastic", dt=dt)
    jax_ = BatchSimulator.from_scenes(scenes, method="elastic", dt=dt, backend="jax")
    steps = int(round(0.16 / dt))
    a = numba.run(steps=steps, every=5, commands=schedules)
    b = jax_.run(steps=steps, every=5, commands=schedules)
    _same_run(a, b)
    _close(jax_.rest_lengths, numba.rest_lengths, "rest lengths in effect")
    _close(jax_.external_forces, numba.external_forces, "forces in effect")
    assert not np.array_equal(numba.rest_lengths, BatchSimulator.from_scenes(scenes, dt=dt).rest_lengths)


def test_numba_commands_equal_single_simulators_stepped_by_hand():
    """The numba batch's ``run(commands=...)`` (the JAX backend's reference) against a Simulator per copy with
    each input set before each step where it changed, as ``tensegrity-sim run --commands`` does."""
    scenes, dt = _scenes("damped")
    schedules = _schedules(scenes[0], 3)
    traj = BatchSimulator.from_scenes(scenes, method="elastic", dt=dt).run(steps=140, commands=schedules)
    for b, (scene, schedule) in enumerate(zip(scenes, schedules)):
        sim = ts.Simulator(scene, method="elastic", dt=dt)
        base = sim.rest_lengths
        for k in range(140):
            rest = schedule.rest_lengths_at(sim.time, base)
            if not np.array_equal(rest, sim.rest_lengths):
                sim.set_rest_lengths(rest)
            forces = schedule.forces_at(sim.time)
            if forces is not None and not np.array_equal(forces, sim.external_forces):
                sim.set_external_forces(forces)
            r = sim.step()
            np.testing.assert_allclose(traj.positions[b, k], r.positions, rtol=0, atol=1e-10)


def test_simulator_backend_jax_equals_numba():
    scene = _damped(icosahedron_thrown(scale=2.0, seed=4), 2.0)
    numba = ts.Simulator(scene, method="elastic", dt=1e-3)
    jax_ = ts.Simulator(scene, method="elastic", dt=1e-3, backend="jax")
    assert jax_.method_settings["backend"] == "jax" and jax_.method_settings["dtype"] == "float64"
    for _ in range(5):   # step by step (the steps-ahead loop), then a run
        a, b = numba.step(), jax_.step()
        _close(b.positions, a.positions, "step positions")
        _close(b.impulses, a.impulses, "step impulses")
    numba.set_rest_lengths({scene.cable_names[0]: 0.9 * scene.cables[0].rest_length})
    jax_.set_rest_lengths({scene.cable_names[0]: 0.9 * scene.cables[0].rest_length})
    a, b = numba.run(steps=64, every=8), jax_.run(steps=64, every=8)
    for f in ("positions", "velocities", "impulses"):
        _close(getattr(b, f), getattr(a, f), f)
    np.testing.assert_array_equal(b.slack, a.slack)


def test_float32_error_is_that_of_single_precision():
    """float32 on request: the same run within a few hundred float32 round-offs of float64 (the numbers a
    benchmark reports), and float64 unchanged by a float32 run beside it."""
    scenes, dt = _scenes("icosahedron")
    f64 = BatchSimulator.from_scenes(scenes, method="elastic", dt=dt, backend="jax").run(steps=300, every=7)
    f32 = BatchSimulator.from_scenes(scenes, method="elastic", dt=dt, backend="jax", dtype="float32")
    assert f32.method_settings["method"] == "elastic"
    err = np.max(np.abs(f32.run(steps=300, every=7).positions - f64.positions))
    eps32 = np.finfo(np.float32).eps
    assert 10 * np.finfo(float).eps < err < 300 * eps32 * np.max(np.abs(f64.positions)), err


def test_bad_backend_arguments_are_refused():
    scene = ts.load_scene("icosahedron")
    with pytest.raises(ValueError, match=r"backend must be one of \['numba', 'jax'\], got 'cuda'"):
        ts.Simulator(scene, method="elastic", backend="cuda")
    with pytest.raises(ValueError, match="dtype='float32' is an option of backend 'jax'"):
        BatchSimulator(scene, 2, method="elastic", dtype="float32")
    with pytest.raises(ValueError, match="dtype must be one of"):
        BatchSimulator(scene, 2, method="elastic", backend="jax", dtype="float16")
    with pytest.raises(ValueError, match="backend 'jax' steps the elastic method only"):
        ts.Simulator(scene, method="inextensible", backend="jax")
    with pytest.raises(ValueError, match="order=4: backend 'jax' steps plain velocity Verlet"):
        ts.Simulator(scene, method="elastic", backend="jax", order=4)
    sim = BatchSimulator(scene, 2, method="elastic", backend="jax")
    with pytest.raises(ValueError, match="commands must be a CommandSchedule"):
        sim.run(steps=2, commands=["not a schedule"] * 2)
    assert sim.step_count == 0


def _python(code: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.getcwd()}
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)


def test_core_imports_no_jax_and_a_missing_jax_names_the_extra():
    core = _python("import sys, tensegrity_sim, tensegrity_sim.batch, tensegrity_sim.cli, tensegrity_sim.sweep; "
                   "print('jax' in sys.modules)")
    assert core.returncode == 0 and core.stdout.strip() == "False", core.stderr
    missing = _python("import sys; sys.modules['jax'] = None\n"
                      "import tensegrity_sim as ts\n"
                      "ts.Simulator(ts.load_scene('icosahedron'), method='elastic', backend='jax')")
    assert missing.returncode != 0
    assert 'needs JAX, which is not installed: pip install "tensegrity_sim[jax]"' in missing.stderr


def test_sweep_backend_jax_gives_the_numba_table(tmp_path):
    import pyarrow.parquet as pq
    import yaml

    from tensegrity_sim.cli import main

    spec = {"scene": "icosahedron", "method": "elastic", "dt": 0.001, "duration": 0.1, "contacts": "none",
            "vary": {"gravity": [[0, 0, 0], [0, 0, -9.81]], "velocity.n0": [[0, 0, 0], [12.0, -9.0, 6.0]]}}
    path = tmp_path / "spec.yaml"
    path.write_text(yaml.safe_dump(spec))
    tables = {}
    for backend in ("numba", "jax"):
        out = tmp_path / f"{backend}.parquet"
        assert main(["sweep", str(path), "--out", str(out), "--quiet", "--backend", backend]) == 0
        tables[backend] = pq.read_table(out).to_pylist()
    assert sum(r["snaps"] for r in tables["numba"]) > 0
    for a, b in zip(tables["numba"], tables["jax"]):
        _close(b["final_positions"], a["final_positions"], "final positions")
        _close(b["max_tension"] * 1e-3, a["max_tension"] * 1e-3, "peak impulse")
        assert (b["snaps"], b["steps"], b["failed"]) == (a["snaps"], a["steps"], None)
