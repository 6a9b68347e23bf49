"""Parameter sweeps: many runs of one scene with some numbers changed, one Parquet row per run.

The spec (YAML; ``tensegrity-sim sweep SPEC.yaml --out RESULTS.parquet``)::

    scene: icosahedron          # a built-in scene or a YAML file (a relative path is from the spec's folder)
    method: elastic             # elastic | inextensible | massive | auto (default auto, decided per run)
    dt: 0.001                   # s (default 0.001)
    duration: 2.0               # s, required
    solver: daqp                # optional: the inextensible method's QP backend
    contacts: none              # optional: member kinds checked for contact, as run --contacts (default:
                                # the scene's); detection runs copy by copy, so "none" is much faster
    batch: 1024                 # optional: at most this many runs stepped together (default 1024)
    vary:                       # a full grid over these keys (every combination)
      gravity: [[0, 0, 0], [0, 0, -9.81]]
      rest_lengths.c0: [0.9, 0.95, 1.0, 1.05]
    samples: 100                # optional: random designs, each grid point with this many draws ...
    ranges:                     # ... uniform between the two bounds of each key (vectors: per component)
      velocity.n0: [[-1, -1, -1], [1, 1, 1]]
    seed: 0                     # of the draws (default 0)

**Keys** name a number of the scene by its path in the scene's YAML: ``gravity`` (a top-level number or
vector), ``<section>.<key>`` for a top-level mapping (e.g. ``ground.friction``), and ``<field>.<name>``
for a field of the node, strut or cable called ``name``: ``rest_lengths.<cable>`` (or ``rest_length``),
``stiffness.<member>``, ``mass.<node or strut>``, ``velocity.<node>``, ``position.<node>``,
``damping.<cable>``, ``radius.<member>``. Besides the scene: ``dt`` and ``method``. Every run's scene
is rebuilt from the YAML mapping and validated like a scene file, so a bad value names its run and key.

**Result rows** (Parquet, pyarrow; plain columns that pandas or polars read without this package):
``run`` (0, 1, ... in grid order); one column per key of ``vary`` and ``ranges``, named as there
(numbers; vectors as lists; ``method`` as text); ``max_tension`` N, the largest cable tension of any step
(``impulses / dt``); ``final_positions`` the positions after the last step (node order, N x 3 flattened,
m); ``energy_drift`` J, total energy at the end minus at the start (``Simulator.energy``); ``snaps``, how
often any cable went from slack to taut (between consecutive step ends); ``contacts``, the contacts
that began; ``steps`` completed; ``failed``, the reason a run stopped early, else null (its other
columns then describe the run up to its last good step). The table's metadata holds the spec and the
node names (``tensegrity_sim.spec``, ``tensegrity_sim.nodes``, JSON).

**Execution.** Runs whose scenes differ only in their initial state (positions, velocities, rest
lengths) and share method and dt are stepped together by a :class:`~tensegrity_sim.batch.BatchSimulator`
(a group, at most ``batch`` runs). Groups run in this process (``workers=1``), in local processes, or
as Ray tasks on a cluster (``address``); every row equals a single ``Simulator`` run with its parameters.
"""
from __future__ import annotations

import itertools
import json
import math
import os
import sys
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np
import yaml

from .batch import BatchSimulator, structure_of
from .methods import BACKENDS, METHODS, choose_method
from .scene import Scene, SceneError, builtin_scenes, contact_kinds, load_scene
from .system import System

__all__ = ["SweepError", "SweepSpec", "SweepSummary", "load_spec", "run_sweep", "run_group", "RAY_HINT"]

RAY_HINT = 'the sweep extra is not installed: pip install -e ".[sweep]" (Ray and pyarrow)'
DEFAULT_BATCH = 1024
_SPEC_KEYS = {"scene", "method", "dt", "duration", "solver", "contacts", "batch", "vary", "samples", "ranges",
              "seed"}
_PLURALS = {"rest_lengths": "rest_length", "masses": "mass", "velocities": "velocity", "positions": "position"}
_ENTRY_FIELDS = {"position", "velocity", "mass", "stiffness", "rest_length", "damping", "radius"}


class SweepError(ValueError):
    """A sweep spec that cannot be run; the message names the file and the key."""


# --------------------------------------------------------------------------- keys
@dataclass(frozen=True)
class _Key:
    """A sweep key resolved against the scene mapping: ``path`` into it (None for dt and method)."""

    name: str
    path: tuple | None


def _resolve(name: str, scene: Mapping[str, Any], where: str) -> _Key:
    if name in ("dt", "method"):
        return _Key(name, None)
    parts = name.split(".")
    first = _PLURALS.get(parts[0], parts[0])
    if len(parts) == 2 and first in _ENTRY_FIELDS:
        for section in ("nodes", "struts", "cables"):
            for i, entry in enumerate(scene.get(section) or []):
                if entry["name"] == parts[1]:
                    return _Key(name, (section, i, first))
        raise SweepError(f"{where}: {name!r}: the scene has no node, strut or cable named {parts[1]!r}")
    if first in _ENTRY_FIELDS or parts[0] in ("nodes", "struts", "cables", "name"):
        raise SweepError(f"{where}: {name!r}: write {first}.<name> (one node, strut or cable by name)")
    if any(not p for p in parts):
        raise SweepError(f"{where}: {name!r} is not a key (see tensegrity_sim.sweep for the forms)")
    return _Key(name, tuple(parts))


def _with(mapping: Any, path: tuple, value: Any) -> Any:
    """A copy of ``mapping`` with ``value`` at ``path``, copying only what lies on the path."""
    head, rest = path[0], path[1:]
    if isinstance(mapping, list):
        out = list(mapping)
        out[head] = _with(out[head], rest, value) if rest else value
        return out
    out = dict(mapping or {})
    out[head] = _with(out.get(head), rest, value) if rest else value
    return out


def _plain(value: Any) -> Any:
    """A YAML/JSON-like value with numpy numbers turned into Python ones."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


# --------------------------------------------------------------------------- spec
@dataclass
class SweepSpec:
    """A parsed spec: the base scene mapping, defaults, and the parameters of every run in order."""

    scene: Scene
    source: str
    method: str
    dt: float
    duration: float
    solver: str | None
    contacts: tuple[str, ...] | None
    batch: int
    columns: tuple[str, ...]
    runs: list[dict[str, Any]]
    text: str = ""
    _keys: dict[str, _Key] = field(default_factory=dict)
    _mapping: dict[str, Any] = field(default_factory=dict)

    def run_setup(self, params: Mapping[str, Any]) -> tuple[Scene, str, float]:
        """The scene, method and dt of a run with ``params`` (validated; a bad value names the key)."""
        mapping = self._mapping
        method, dt = self.method, self.dt
        for name, value in params.items():
            key = self._keys[name]
            if key.name == "method":
                method = value
            elif key.name == "dt":
                dt = value
            else:
                mapping = _with(mapping, key.path, _plain(value))
        where = ", ".join(f"{k}={_plain(v)!r}" for k, v in params.items())
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")   # the base scene's warnings were given at load time
                scene = Scene.from_dict(mapping, source=self.source)
        except SceneError as exc:
            raise SweepError(f"run with {where}: {exc}") from None
        if method not in METHODS and method != "auto":
            raise SweepError(f"run with {where}: method must be one of {sorted(METHODS) + ['auto']}, got {method!r}")
        if isinstance(dt, bool) or not isinstance(dt, (int, float)) or not math.isfinite(dt) or dt <= 0:
            raise SweepError(f"run with {where}: dt must be a positive number of seconds, got {dt!r}")
        return scene, method, float(dt)


def _number(where: str, name: str, value: Any, *, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
            or (positive and value <= 0):
        raise SweepError(f"{where}: {name} must be a {'positive ' if positive else ''}finite number, got {value!r}")
    return float(value)


def parse_spec(raw: Any, source: str = "<spec>", base_dir: Path | None = None, text: str = "") -> SweepSpec:
    """Validate a spec mapping (the YAML content) and expand its runs."""
    if not isinstance(raw, Mapping):
        raise SweepError(f"{source}: must be a mapping with scene, duration and vary/samples")
    unknown = sorted(set(raw) - _SPEC_KEYS)
    if unknown:
        raise SweepError(f"{source}: unknown key {unknown[0]!r} (allowed: {', '.join(sorted(_SPEC_KEYS))})")
    for required in ("scene", "duration"):
        if required not in raw:
            raise SweepError(f"{source}: missing required key {required!r}")
    scene_ref = str(raw["scene"])
    if scene_ref not in builtin_scenes() and base_dir is not None and not Path(scene_ref).is_absolute():
        scene_ref = str(base_dir / scene_ref)
    try:
        scene = load_scene(scene_ref)
    except SceneError as exc:
        raise SweepError(f"{source}: scene: {exc}") from None
    method = raw.get("method", "auto")
    dt = _number(source, "dt", raw.get("dt", 1e-3), positive=True)
    duration = _number(source, "duration", raw["duration"], positive=True)
    solver = raw.get("solver")
    contacts = raw.get("contacts")
    if contacts is not None:
        try:
            contacts = contact_kinds([] if contacts == "none" else contacts, "contacts")
        except ValueError as exc:
            raise SweepError(f"{source}: {exc}") from None
    batch = raw.get("batch", DEFAULT_BATCH)
    if isinstance(batch, bool) or not isinstance(batch, int) or batch < 1:
        raise SweepError(f"{source}: batch must be a whole number >= 1, got {batch!r}")
    vary = raw.get("vary") or {}
    ranges = raw.get("ranges") or {}
    if not isinstance(vary, Mapping) or not isinstance(ranges, Mapping):
        raise SweepError(f"{source}: vary and ranges must be mappings of key: values")
    samples = raw.get("samples")
    if (samples is None) != (not ranges):
        raise SweepError(f"{source}: samples and ranges go together (samples: N draws from ranges: key: [lo, hi])")
    if samples is not None and (isinstance(samples, bool) or not isinstance(samples, int) or samples < 1):
        raise SweepError(f"{source}: samples must be a whole number >= 1, got {samples!r}")
    both = sorted(set(vary) & set(ranges))
    if both:
        raise SweepError(f"{source}: {both[0]!r} is in both vary and ranges")
    mapping = scene.to_dict()
    keys = {name: _resolve(str(name), mapping, f"{source}: vary" if name in vary else f"{source}: ranges")
            for name in [*vary, *ranges]}
    grid_values = []
    for name, values in vary.items():
        if not isinstance(values, list) or not values:
            raise SweepError(f"{source}: vary: {name!r} must be a non-empty list of values")
        grid_values.append(values)
    draws: dict[str, np.ndarray] = {}
    seed = raw.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise SweepError(f"{source}: seed must be a whole number >= 0, got {seed!r}")
    if samples:
        rng = np.random.default_rng(seed)
        for name, bounds in ranges.items():
            if keys[name].path is None and name == "method":
                raise SweepError(f"{source}: ranges: 'method' cannot be drawn; put it in vary")
            try:
                lo, hi = (np.asarray(b, dtype=float) for b in bounds)
            except (TypeError, ValueError):
                raise SweepError(f"{source}: ranges: {name!r} must be [low, high] (numbers or vectors)") from None
            if lo.shape != hi.shape or not (np.all(np.isfinite(lo)) and np.all(hi >= lo)):
                raise SweepError(f"{source}: ranges: {name!r} needs finite bounds of one shape with low <= high")
            draws[name] = rng.uniform(lo, hi, size=(samples, *lo.shape))
    runs = []
    for combo in itertools.product(*grid_values):
        base = dict(zip(vary, combo))
        for s in range(samples or 1):
            runs.append({**base, **{name: draws[name][s] for name in ranges}})
    spec = SweepSpec(scene, scene.source, method, dt, duration, solver, contacts, batch, tuple(keys), runs, text,
                     keys, mapping)
    spec.run_setup(runs[0])   # the first run's scene: a key the scene schema refuses fails here, not later
    return spec


def load_spec(path: str | Path) -> SweepSpec:
    """Read and validate a spec file (relative scene paths are from the spec's folder)."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise SweepError(f"{path}: cannot read: {exc.strerror}") from None
    try:
        raw = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise SweepError(f"{path}: not valid YAML: {exc}") from None
    return parse_spec(raw, str(path), path.parent, text)


# --------------------------------------------------------------------------- groups
@dataclass
class Group:
    """Runs stepped together: their indices, scenes (one structure), method, dt, duration, solver, contact
    kinds (None: the scene's) and the backend of an elastic group ("numba" or "jax")."""

    runs: list[int]
    scenes: list[Scene]
    method: str
    dt: float
    duration: float
    solver: str | None
    contacts: tuple[str, ...] | None
    backend: str = "numba"


def make_groups(spec: SweepSpec, parts: int = 1, backend: str = "numba") -> list[Group]:
    """The runs grouped by structure, method and dt, split to at most ``spec.batch`` runs and into at
    least ``parts`` pieces where there are enough runs (so every worker gets some); the elastic groups on
    ``backend`` (the others on numba: the JAX backend has the elastic method only)."""
    by_key: dict[tuple, list[tuple[int, Scene]]] = {}
    for i, params in enumerate(spec.runs):
        scene, method, dt = spec.run_setup(params)
        if method == "auto":   # decided per run, as a single Simulator would
            method = choose_method(System(scene), dt)[0]
        by_key.setdefault((structure_of(scene), method, dt), []).append((i, scene))
    size = max(1, min(spec.batch, math.ceil(len(spec.runs) / max(1, parts))))
    groups = []
    for (_, method, dt), members in by_key.items():
        for k in range(0, len(members), size):
            chunk = members[k:k + size]
            groups.append(Group([i for i, _ in chunk], [s for _, s in chunk], method, dt, spec.duration, spec.solver,
                                spec.contacts, backend if method == "elastic" else "numba"))
    return groups


def run_group(group: Group) -> tuple[list[dict[str, Any]], list[str]]:
    """Run one group; returns its result rows (the result columns and ``run``) and the distinct
    warnings it raised. A group that cannot start (a dt beyond the stability limit) fails every run."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            sim = BatchSimulator.from_scenes(group.scenes, method=group.method, dt=group.dt, solver=group.solver,
                                             contacts=group.contacts, backend=group.backend)
        except ValueError as exc:
            rows = [_row(i, np.full(3 * len(s.nodes), np.nan), 0.0, math.nan, 0, 0, 0, str(exc))
                    for i, s in zip(group.runs, group.scenes)]
            return rows, []
        steps = int(round(group.duration / sim.dt))
        start = sim.energy()["total"]
        traj = sim.run(steps=steps, every=max(steps, 1))
        drift = sim.energy()["total"] - start
        final = sim.positions.reshape(sim.batch, -1)
        done = sim.step_counts
        rows = [_row(i, final[b], float(traj.peak_tensions[b].max(initial=0.0)), float(drift[b]),
                     int(traj.snaps[b].sum()), sum(e.kind == "begin" for e in traj.contacts[b]), int(done[b]),
                     traj.failures.get(b))
                for b, i in enumerate(group.runs)]
    return rows, sorted({f"{w.category.__name__}: {w.message}" for w in caught})


def _row(run, final, max_tension, drift, snaps, contacts, steps, failed) -> dict[str, Any]:
    return {"run": run, "max_tension": max_tension, "final_positions": final.tolist(), "energy_drift": drift,
            "snaps": snaps, "contacts": contacts, "steps": steps, "failed": failed}


# --------------------------------------------------------------------------- running
@dataclass
class SweepSummary:
    """What ``sweep`` prints at the end."""

    runs: int
    groups: int
    where: str
    wall_time: float
    scene_steps: int
    failed: int
    max_tension: float
    snaps: int
    out: str
    warnings: list[str] = field(default_factory=list)

    def lines(self) -> list[str]:
        rate = self.scene_steps / self.wall_time if self.wall_time > 0 else float("inf")
        return [
            f"runs             {self.runs} in {self.groups} groups ({self.where})",
            f"wall time        {self.wall_time:.3f} s ({self.runs / self.wall_time:,.1f} runs/s, "
            f"{rate:,.0f} scene-steps/s)",
            f"failed           {self.failed}",
            f"max tension      {self.max_tension:.6g} N (largest of all runs)",
            f"snaps            {self.snaps} (all runs)",
            f"results          {self.out}",
            *[f"warning          {w}" for w in self.warnings],
        ]


def _embedded(groups: list[Group], workers: int, done: Callable) -> None:
    if workers == 1:
        for g in groups:
            done(g, run_group(g))
        return
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    # spawn: a fresh interpreter per worker (forking a process with BLAS and numba threads is unsafe)
    with ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn")) as pool:
        futures = {pool.submit(run_group, g): g for g in groups}
        for f in as_completed(futures):
            done(futures[f], f.result())


def _on_ray(groups: list[Group], done: Callable) -> None:
    """The groups as Ray tasks on the cluster this process is connected to."""
    import ray

    task = ray.remote(run_group)
    pending = {task.remote(g): g for g in groups}
    while pending:
        ready, _ = ray.wait(list(pending), num_returns=1)
        for ref in ready:
            done(pending.pop(ref), ray.get(ref))


def _connect(address: str) -> int:
    """Connect this process to the Ray cluster at ``address``; returns its CPU count."""
    try:
        import ray
    except ImportError:
        raise SweepError(f"--address needs Ray: {RAY_HINT}") from None
    try:
        ray.init(address=address, logging_level="ERROR", log_to_driver=False)
    except (ConnectionError, RuntimeError, ValueError) as exc:
        raise SweepError(f"--address {address}: cannot connect to a Ray cluster there: {exc}") from None
    return max(1, int(ray.cluster_resources().get("CPU", 1)))


def results_table(spec: SweepSpec, rows: list[dict[str, Any]]):
    """The pyarrow table of ``rows`` (in run order) with the varied keys' columns and the metadata."""
    import pyarrow as pa

    rows = sorted(rows, key=lambda r: r["run"])
    columns: dict[str, Any] = {"run": pa.array([r["run"] for r in rows], pa.int64())}
    for name in spec.columns:
        values = [_plain(spec.runs[r["run"]][name]) for r in rows]
        if name == "method":
            columns[name] = pa.array(values, pa.string())
        elif isinstance(values[0], list):
            columns[name] = pa.array(values, pa.list_(pa.float64()))
        else:
            columns[name] = pa.array(values, pa.float64())
    columns["max_tension"] = pa.array([r["max_tension"] for r in rows], pa.float64())
    columns["final_positions"] = pa.array([r["final_positions"] for r in rows], pa.list_(pa.float64()))
    for name in ("energy_drift",):
        columns[name] = pa.array([r[name] for r in rows], pa.float64())
    for name in ("snaps", "contacts", "steps"):
        columns[name] = pa.array([r[name] for r in rows], pa.int64())
    columns["failed"] = pa.array([r["failed"] for r in rows], pa.string())
    meta = {"tensegrity_sim.spec": spec.text or json.dumps({"runs": len(spec.runs)}),
            "tensegrity_sim.nodes": json.dumps(list(spec.scene.node_names))}
    return pa.table(columns).replace_schema_metadata(meta)


def run_sweep(spec: SweepSpec, out: str | Path, *, address: str | None = None, workers: int = 1,
              progress: bool = False, backend: str = "numba") -> SweepSummary:
    """Run every run of ``spec`` and write the Parquet table ``out``; returns the summary.

    ``address``: a Ray cluster (``HOST:PORT``) to run the groups on as tasks; else this process
    (``workers`` = 1) or ``workers`` local processes. ``backend``: where the elastic groups step, "numba" or
    "jax" (``BatchSimulator``'s; the jax extra)."""
    try:
        import pyarrow.parquet as pq
    except ImportError:
        raise SweepError(f"writing Parquet needs pyarrow: {RAY_HINT}") from None
    from tqdm import tqdm

    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise SweepError(f"workers must be a whole number >= 1, got {workers!r}")
    if backend not in BACKENDS:
        raise SweepError(f"backend must be one of {list(BACKENDS)}, got {backend!r}")
    out = Path(out)
    if not out.parent.is_dir():
        raise SweepError(f"--out {out}: no such folder {str(out.parent)!r}")
    start = time.perf_counter()
    parts = workers if address is None else _connect(address)
    rows: list[dict[str, Any]] = []
    seen_warnings: set[str] = set()
    scene_steps = 0

    def done(group: Group, result) -> None:
        nonlocal scene_steps
        group_rows, group_warnings = result
        rows.extend(group_rows)
        seen_warnings.update(group_warnings)
        scene_steps += sum(r["steps"] for r in group_rows)
        bar.update(len(group_rows))

    bar = tqdm(total=len(spec.runs), unit="run", disable=not progress, mininterval=0.5)
    groups: list[Group] = []
    try:
        groups = make_groups(spec, parts, backend)
        if address is None:
            _embedded(groups, workers, done)
        else:
            _on_ray(groups, done)
    except BaseException:
        # interrupted or a worker died: the runs finished so far are kept beside the final name
        if rows:
            kept = out.with_name(out.name + ".incomplete.parquet")
            pq.write_table(results_table(spec, rows), kept)
            print(f"tensegrity-sim sweep: {len(rows)} of {len(spec.runs)} runs kept in {kept}", file=sys.stderr)
        raise
    finally:
        bar.close()
        if address is not None:
            import ray

            ray.shutdown()
    partial = out.with_name(out.name + ".partial")   # never a half-written file under the final name
    pq.write_table(results_table(spec, rows), partial)
    os.replace(partial, out)
    wall = time.perf_counter() - start
    where = (f"Ray cluster at {address}" if address else
             "this process" if workers == 1 else f"{workers} local processes")
    return SweepSummary(len(spec.runs), len(groups), where, wall, scene_steps,
                        sum(r["failed"] is not None for r in rows),
                        max((r["max_tension"] for r in rows), default=0.0), sum(r["snaps"] for r in rows),
                        str(out), _first_of_each_kind(seen_warnings))


def _first_of_each_kind(messages: set[str]) -> list[str]:
    """One warning per category (their texts differ only in numbers from run to run), with a count."""
    kinds: dict[str, list[str]] = {}
    for m in sorted(messages):
        kinds.setdefault(m.split(":")[0], []).append(m)
    return [f"{ms[0]} (and {len(ms) - 1} similar)" if len(ms) > 1 else ms[0] for ms in kinds.values()]
