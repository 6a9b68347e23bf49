"""Sweeps: every Parquet row equals a single Simulator run with its parameters, embedded and on a real
local Ray cluster; the spec's errors name the key; the table reads without this package."""
import os
import shutil
import socket
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import yaml

import tensegrity_sim as ts
from tensegrity_sim.cli import main
from tensegrity_sim.sweep import SweepError, load_spec, run_sweep

SPEC = {
    "scene": "icosahedron",
    "method": "elastic",
    "dt": 0.001,
    "duration": 0.15,
    "vary": {
        "gravity": [[0, 0, 0], [0, 0, -9.81]],
        "rest_lengths.c0": [0.85, 0.95],
        "velocity.n0": [[0, 0, 0], [12.0, -9.0, 6.0]],
        "method": ["elastic", "inextensible"],
    },
}


def _write(tmp_path: Path, spec: dict) -> Path:
    path = tmp_path / "spec.yaml"
    path.write_text(yaml.safe_dump(spec, sort_keys=False))
    return path


def _single(params: dict, spec: dict) -> dict:
    """What one Simulator run gives for ``params``, the scene written by hand (not by the sweep's code)."""
    d = ts.load_scene(spec["scene"]).to_dict()
    method, dt = spec["method"], spec["dt"]
    for key, value in params.items():
        if key == "gravity":
            d["gravity"] = list(value)
        elif key == "rest_lengths.c0":
            next(c for c in d["cables"] if c["name"] == "c0")["rest_length"] = value
        elif key == "stiffness.c1":
            next(c for c in d["cables"] if c["name"] == "c1")["stiffness"] = value
        elif key == "velocity.n0":
            next(n for n in d["nodes"] if n["name"] == "n0")["velocity"] = list(value)
        elif key == "method":
            method = value
        elif key == "dt":
            dt = value
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sim = ts.Simulator(ts.Scene.from_dict(d), method=method, dt=dt,
                           contacts=[] if spec.get("contacts") == "none" else None)
    e0 = sim.energy()["total"]
    peak, snaps, contacts = 0.0, 0, 0
    was = sim.slack()
    for _ in range(int(round(spec["duration"] / dt))):
        r = sim.step()
        peak = max(peak, float(r.tensions.max()))
        snaps += int(np.count_nonzero(was & ~r.slack))
        was = r.slack
        contacts += sum(e.kind == "begin" for e in r.contacts)
    return {"max_tension": peak, "final_positions": sim.positions.ravel(), "energy_drift": sim.energy()["total"] - e0,
            "snaps": snaps, "contacts": contacts}


def _check_rows(table, spec: dict) -> None:
    rows = table.to_pylist()
    assert [r["run"] for r in rows] == list(range(len(rows)))
    keys = list(spec.get("vary", {})) + list(spec.get("ranges", {}))
    for r in rows:
        params = {k: r[k] for k in keys}
        want = _single(params, spec)
        assert r["failed"] is None
        assert r["max_tension"] == pytest.approx(want["max_tension"], rel=1e-10, abs=1e-8)
        np.testing.assert_allclose(r["final_positions"], want["final_positions"], rtol=0, atol=1e-10)
        assert r["energy_drift"] == pytest.approx(want["energy_drift"], rel=1e-8, abs=1e-8)
        assert (r["snaps"], r["contacts"]) == (want["snaps"], want["contacts"])
        assert r["steps"] == int(round(spec["duration"] / spec["dt"]))


def test_embedded_sweep_rows_equal_single_runs(tmp_path, capsys):
    out = tmp_path / "results.parquet"
    assert main(["sweep", str(_write(tmp_path, SPEC)), "--out", str(out), "--quiet"]) == 0
    text = capsys.readouterr().out
    assert "runs             16 in 4 groups (this process)" in text
    table = pq.read_table(out)
    assert table.num_rows == 16
    assert table.column_names == ["run", "gravity", "rest_lengths.c0", "velocity.n0", "method", "max_tension",
                                  "final_positions", "energy_drift", "snaps", "contacts", "steps", "failed"]
    # the grid in order: the last key varies fastest
    rows = table.to_pylist()
    assert [r["method"] for r in rows[:4]] == ["elastic", "inextensible"] * 2
    assert rows[8]["gravity"] == [0, 0, -9.81] and rows[7]["gravity"] == [0, 0, 0]
    _check_rows(table, SPEC)
    assert sum(r["snaps"] for r in rows) > 0
    assert table.schema.metadata[b"tensegrity_sim.nodes"].startswith(b'["n0", "n1"')


def test_samples_draw_from_ranges_and_stiffness_splits_groups(tmp_path):
    spec = {"scene": "icosahedron", "method": "elastic", "dt": 0.001, "duration": 0.1, "contacts": "none",
            "vary": {"stiffness.c1": [500.0, 700.0]}, "samples": 3, "seed": 4,
            "ranges": {"velocity.n0": [[-2, -2, -2], [2, 2, 2]], "rest_lengths.c0": [0.8, 0.9]}}
    out = tmp_path / "r.parquet"
    summary = run_sweep(load_spec(_write(tmp_path, spec)), out)
    assert (summary.runs, summary.groups) == (6, 2)   # a stiffness is structure: one group per value
    table = pq.read_table(out)
    rows = table.to_pylist()
    assert [r["stiffness.c1"] for r in rows] == [500.0] * 3 + [700.0] * 3
    draws = np.array([r["velocity.n0"] for r in rows])
    assert np.all(np.abs(draws) <= 2) and len({tuple(d) for d in draws[:3]}) == 3
    np.testing.assert_array_equal(draws[:3], draws[3:])   # each grid point gets the same draws
    assert all(0.8 <= r["rest_lengths.c0"] <= 0.9 for r in rows)
    _check_rows(table, spec)


def test_a_group_that_cannot_start_fails_its_runs_only(tmp_path):
    spec = {"scene": "icosahedron", "method": "elastic", "duration": 0.01, "vary": {"dt": [0.001, 0.2]}}
    out = tmp_path / "r.parquet"
    summary = run_sweep(load_spec(_write(tmp_path, spec)), out)
    rows = pq.read_table(out).to_pylist()
    assert summary.failed == 1
    assert rows[0]["failed"] is None and rows[0]["steps"] == 10
    assert "beyond the stability limit" in rows[1]["failed"] and rows[1]["steps"] == 0


@pytest.mark.parametrize("spec, message", [
    ({"scene": "icosahedron"}, r"missing required key 'duration'"),
    ({"scene": "icosahedron", "duration": 1, "vary": {"rest_lengths.c99": [1.0]}},
     r"vary: 'rest_lengths.c99': the scene has no node, strut or cable named 'c99'"),
    ({"scene": "icosahedron", "duration": 1, "vary": {"stiffness.c0": [-1.0]}},
     r"run with stiffness.c0=-1.0: .*cables\[0\] 'c0': stiffness must be > 0, got -1.0"),
    ({"scene": "icosahedron", "duration": 1, "vary": {"wind": [1.0]}}, r"unknown key 'wind'"),
    ({"scene": "icosahedron", "duration": 1, "samples": 3}, r"samples and ranges go together"),
    ({"scene": "icosahedron", "duration": 1, "vary": {"method": ["rk4"]}}, r"method must be one of"),
    ({"scene": "icosahedron", "duration": 1, "vary": {"gravity": []}}, r"'gravity' must be a non-empty list"),
    ({"scene": "icosahedron", "duration": 1, "vray": {}}, r"unknown key 'vray' \(allowed: batch, contacts, dt, duration"),
])
def test_spec_errors_name_the_key(tmp_path, capsys, spec, message):
    path = _write(tmp_path, spec)
    with pytest.raises(SweepError, match=message):
        load_spec(path)
    out = tmp_path / "r.parquet"
    assert main(["sweep", str(path), "--out", str(out)]) == 2
    assert "tensegrity-sim sweep: error:" in capsys.readouterr().err
    assert not out.exists()


def test_parquet_reads_without_the_package(tmp_path):
    """A fresh interpreter with only pyarrow on its path (no tensegrity_sim importable) reads the table."""
    spec = {"scene": "prism3", "method": "elastic", "duration": 0.01, "vary": {"gravity": [[0, 0, -9.81]]}}
    out = tmp_path / "r.parquet"
    run_sweep(load_spec(_write(tmp_path, spec)), out)
    import pyarrow

    site = str(Path(pyarrow.__file__).parent.parent)
    # -I -S: no current folder, no site processing, so not the project's editable install either
    code = (f"import sys; sys.path.append({site!r}); import importlib.util; "
            "assert importlib.util.find_spec('tensegrity_sim') is None; "
            "import pyarrow.parquet as pq; t = pq.read_table(sys.argv[1]); "
            "print(t.num_rows, len(t.column('final_positions')[0]))")
    result = subprocess.run([sys.executable, "-I", "-S", "-c", code, str(out)], capture_output=True, text=True,
                            timeout=60, cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    n_nodes = len(ts.load_scene("prism3").nodes)
    assert result.stdout.split() == ["1", str(3 * n_nodes)]


def _free_ports(n: int) -> list[int]:
    """``n`` distinct ports free now (held open together while they are picked)."""
    sockets = [socket.socket() for _ in range(n)]
    try:
        for s in sockets:
            s.bind(("127.0.0.1", 0))
        return [s.getsockname()[1] for s in sockets]
    finally:
        for s in sockets:
            s.close()


@pytest.fixture
def ray_cluster(tmp_path_factory):
    """A real local Ray cluster (``ray start --head`` on a free port), stopped after the test."""
    ray = shutil.which("ray", path=os.path.dirname(sys.executable))
    assert ray, "the ray command is missing: pip install -e '.[test]' installs it"
    # every port Ray would otherwise take at a fixed default is a free one, so the test cannot collide
    port, agent, agent_grpc, env_agent, metrics = _free_ports(5)
    temp = Path("/tmp") / f"ray_ts_{os.getpid()}"   # short: Ray's socket paths must stay under 108 bytes
    env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0"}
    start = [ray, "start", "--head", f"--port={port}", "--num-cpus=2", "--include-dashboard=false",
             "--disable-usage-stats", f"--temp-dir={temp}",
             f"--dashboard-agent-listen-port={agent}", f"--dashboard-agent-grpc-port={agent_grpc}",
             f"--runtime-env-agent-port={env_agent}", f"--metrics-export-port={metrics}"]
    try:
        started = subprocess.run(start, capture_output=True, text=True, timeout=180, env=env)
        assert started.returncode == 0, f"ray start failed: {started.stderr[-3000:]}"
        yield f"127.0.0.1:{port}"
    finally:
        subprocess.run([ray, "stop", "--force"], capture_output=True, timeout=120, env=env)
        shutil.rmtree(temp, ignore_errors=True)


def test_ray_sweep_rows_equal_single_runs(tmp_path, ray_cluster):
    spec = {**SPEC, "vary": {k: v for k, v in SPEC["vary"].items() if k != "gravity"}}
    out = tmp_path / "ray.parquet"
    summary = run_sweep(load_spec(_write(tmp_path, spec)), out, address=ray_cluster)
    assert summary.where == f"Ray cluster at {ray_cluster}"
    assert summary.groups >= 2    # cut for the cluster's two CPUs
    table = pq.read_table(out)
    assert table.num_rows == 8
    _check_rows(table, spec)


def test_local_workers_give_the_same_table(tmp_path):
    spec = {"scene": "prism3", "method": "elastic", "duration": 0.05, "batch": 2,
            "vary": {"velocity.n1": [[0, 0, 0], [0.5, 0, 0], [0, 0.5, 0]], "gravity": [[0, 0, -9.81]]}}
    sweep = load_spec(_write(tmp_path, spec))
    one, two = run_sweep(sweep, tmp_path / "one.parquet"), run_sweep(sweep, tmp_path / "two.parquet", workers=2)
    assert (one.where, two.where) == ("this process", "2 local processes")
    assert two.groups == 2    # three runs cut for two workers
    assert pq.read_table(tmp_path / "one.parquet").equals(pq.read_table(tmp_path / "two.parquet"))


def test_an_interrupted_sweep_keeps_the_finished_runs(tmp_path, monkeypatch):
    from tensegrity_sim import sweep as sweep_module

    spec = {"scene": "prism3", "method": "elastic", "duration": 0.01, "batch": 1,
            "vary": {"velocity.n1": [[0, 0, 0], [0.5, 0, 0], [0, 0.5, 0]]}}
    real, calls = sweep_module.run_group, []

    def interrupted_at_the_third(group):
        calls.append(group)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return real(group)

    monkeypatch.setattr(sweep_module, "run_group", interrupted_at_the_third)
    out = tmp_path / "r.parquet"
    with pytest.raises(KeyboardInterrupt):
        run_sweep(load_spec(_write(tmp_path, spec)), out)
    assert not out.exists()
    kept = pq.read_table(tmp_path / "r.parquet.incomplete.parquet").to_pylist()
    assert [r["run"] for r in kept] == [0, 1] and kept[1]["velocity.n1"] == [0.5, 0, 0]


def test_without_ray_the_cli_says_how_to_get_it(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)   # import ray raises ImportError
    path = _write(tmp_path, {"scene": "prism3", "duration": 0.01})
    assert main(["sweep", str(path), "--out", str(tmp_path / "r.parquet"), "--address", "127.0.0.1:1"]) == 2
    assert 'pip install -e ".[sweep]"' in capsys.readouterr().err
