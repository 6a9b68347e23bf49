"""The JAX backend's throughput on the device JAX finds (issue 29), beside the numba batch and, where
``mujoco.mjx`` imports, MJX on the same scene; float64 and float32 with float32's error.

    python3 bench/bench_jax.py                    # this machine's defaults (CPU: 256 and 1,024 copies)
    python3 bench/bench_jax.py --gpu              # a GPU's run: 1,024 ... 524,288 copies (the issue's targets)
    python3 bench/bench_jax.py --copies 4096,65536 --steps 200 --repeats 3

Writes ``bench/results/jax.csv`` (``jax_<platform>.csv`` with ``--gpu``) and prints a table; every row names
the device (``jax.devices()[0]``), the load (``os.getloadavg``) and the JAX version.

Cases (dt = 1 ms, ``--steps`` steps per timed call, kept: the last step only):

* ``free``: the thrown icosahedron (``bench/cases.icosahedron_thrown``: rigid struts, 613 N/m cables, no
  gravity, cables going slack and snapping taut), one copy per seed-perturbed velocity field;
* ``ground``: ``icosahedron_ground`` (mu 0.8) rolling under ``examples/roll.yaml`` (rest-length ramps evaluated
  inside the run; the per-strut Coulomb blocks of ``methods/jax/ground.py``), the copies' velocities at rest;
  "finite" says whether every copy's state stayed finite;
* ``gradient``: ``jax.value_and_grad`` of the sum of squared node coordinates after the run with respect to
  every copy's rest lengths (forward and backward; float64), the free case.

Contenders taking turns in one process, each timed after a warm-up (compile), best of ``--repeats``:
the JAX run (``methods/jax/elastic.elastic_steps``, the state kept on the device); the numba batch
(``methods/elastic/_kernels.elastic_steps_copies``, one thread, free case; ``BatchSimulator``'s compiled ground
loop on every core, ground case; up to ``--numba-max`` copies: its rate per copy does not change beyond);
MJX (``mujoco.mjx`` in its own float32, ``bench/mujoco_peer.py``'s model: spring tendons with the dead band,
contacts off for ``free``; capsules on a plane for ``ground``), in a last pass of its own against the JAX runs, up
to ``--mjx-max`` / ``--mjx-ground-max`` copies. The CSV is rewritten after each row (``--out``): a run cut short
keeps what it measured.
scene-steps/s = copies x steps / wall time. float32's error: the largest node position difference (m) from
float64 after the timed run's steps, from the same start.

Targets (issue 29) on a GPU: free >= 50 M scene-steps/s in float64 and >= 10x MJX; ground >= 10 M and finite;
gradient >= 10 M forward and backward (up to ``--grad-max`` copies). On a CPU: within 1.5x of the numba batch.
"""
from __future__ import annotations

import argparse
import importlib.util
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import tensegrity_sim as ts  # noqa: E402
from bench.cases import icosahedron_thrown  # noqa: E402
from bench.tables import write_csv  # noqa: E402
from tensegrity_sim.methods.elastic import _kernels as kernels  # noqa: E402
from tensegrity_sim.methods.rigid import RigidStruts  # noqa: E402
from tensegrity_sim.system import System  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
GPU_COPIES = (1024, 4096, 16384, 65536, 131072, 262144, 524288)
CPU_COPIES = (256, 1024)
DT = 1e-3


ROLL = Path(__file__).resolve().parents[1] / "examples" / "roll.yaml"


def _states(scene: ts.Scene, copies: int):
    """Per-copy initial positions and velocities (N, 3, copies), the batch last: the scene's, velocities scaled
    per copy by a factor in [0.5, 1.5] (rigid-consistent: a scaled consistent field is consistent)."""
    scale = np.linspace(0.5, 1.5, copies)
    x = np.ascontiguousarray(np.broadcast_to(scene.positions[..., None], scene.positions.shape + (copies,)))
    return x, np.ascontiguousarray(scene.velocities[..., None] * scale)


def _rest(scene: ts.Scene, copies: int) -> np.ndarray:
    """(n_cables, copies) m: the scene's rest lengths in every copy."""
    return np.ascontiguousarray(np.broadcast_to(scene.cable_rest_lengths[:, None], (len(scene.cables), copies)))


def _best(contenders: dict, repeats: int) -> dict:
    """Best wall time (s) of each callable, in turns, after one untimed call each (compile, allocate)."""
    for run in contenders.values():
        run()
    best = {name: float("inf") for name in contenders}
    for _ in range(repeats):
        for name, run in contenders.items():
            start = time.perf_counter()
            run()
            best[name] = min(best[name], time.perf_counter() - start)
    return best


def _inputs(scene, copies, dtype, x):
    """Held inputs, or examples/roll.yaml's schedule on a scene with a ground; and whether scheduled."""
    from tensegrity_sim.commands import load_commands
    from tensegrity_sim.methods.jax import elastic as jel

    if scene.ground is None:
        return jel.held_inputs(_rest(scene, copies), np.zeros_like(x), dtype), False
    return jel.schedule_inputs(load_commands(ROLL, scene), _rest(scene, copies), np.zeros_like(x), dtype), True


def _run(scene, copies, steps, dtype):
    """A callable running ``steps`` steps of ``copies`` copies in ``dtype`` on the device; returns positions."""
    import jax
    import jax.numpy as jnp

    from tensegrity_sim.methods.jax import elastic as jel

    system = System(scene)
    model = jel.model_arrays(system, RigidStruts(system), dtype)
    x, v = _states(scene, copies)
    inputs, scheduled = _inputs(scene, copies, dtype, x)
    carry = jel.start_carry(model, jnp.asarray(x, dtype), jnp.asarray(v, dtype), inputs.rest, inputs.ext)

    def run():
        out = jel.elastic_steps(model, carry, inputs, DT, steps, steps, scheduled=scheduled)
        return jax.block_until_ready(out[0].x)

    return run


def _gradient_case(scene, copies, steps):
    import jax
    import jax.numpy as jnp

    from tensegrity_sim.methods.jax import elastic as jel

    system = System(scene)
    model = jel.model_arrays(system, RigidStruts(system))
    x, v = (jnp.asarray(a) for a in _states(scene, copies))
    inputs = jel.held_inputs(_rest(scene, copies), np.zeros(x.shape))

    @jax.jit
    def loss_and_grad(rest):
        return jax.value_and_grad(lambda r: jnp.sum(jel.rollout(model, x, v, inputs._replace(rest=r), DT, steps,
                                                               steps).x[-1] ** 2))(rest)

    return lambda: jax.block_until_ready(loss_and_grad(inputs.rest))


def _numba_case(scene, copies, steps):
    system = System(scene)
    model = kernels.model_arrays(system, RigidStruts(system))
    x0, v0 = _states(scene, copies)
    rest = _rest(scene, copies)
    ext = np.zeros_like(x0)
    nc, n = system.n_cables, system.n_nodes
    outs = (np.empty((1, n, 3, copies)), np.empty((1, n, 3, copies)), np.empty((1, nc, copies)),
            np.empty((1, nc, copies), dtype=bool))

    def run():
        x, v = x0.copy(), v0.copy()
        carry = (np.empty_like(x), np.empty((nc, copies)), np.empty((len(model.rigid_members), 3, copies)))
        kernels.elastic_forces(x, v, rest, ext, *model[:10], *carry)
        kernels.elastic_steps_copies(x, v, rest, ext, DT, steps, steps, *model, *carry, *outs)

    return run


def _numba_ground_case(scene, copies, steps):
    """The numba batch on the ground: ``BatchSimulator`` (the compiled ground loop, copies on every core) under
    the same schedule, evaluated inside that loop (``run(commands=...)``), no member detection (the JAX backend
    has none); built in the timed call (a run cannot be undone), a few ms of the call."""
    from tensegrity_sim.commands import load_commands

    schedule = load_commands(ROLL, scene)

    def run():
        ts.BatchSimulator(scene, copies, method="elastic", dt=DT, contacts=[]).run(steps=steps, every=steps,
                                                                                   commands=schedule)

    return run


def _mjx_case(scene, copies, steps):
    """MJX on bench/mujoco_peer.py's model (float32, its matrix products at full float32 precision: in a GPU's
    default TF32 its state was not finite after 200 steps on an H200), or None where mujoco.mjx does not import."""
    if importlib.util.find_spec("mujoco") is None or importlib.util.find_spec("mujoco.mjx") is None:
        return None
    import jax
    import jax.numpy as jnp
    from mujoco import mjx

    from bench.mujoco_peer import MujocoPeer

    peer = MujocoPeer(scene, model="elastic", dt=DT, integrator="Euler")
    with jax.enable_x64(False):   # MJX's own precision: float32 throughout (this process runs JAX in float64)
        m = mjx.put_model(peer.model)
        d0 = mjx.put_data(peer.model, peer.data)
        scale = jnp.linspace(0.5, 1.5, copies, dtype=jnp.float32)
        batch = jax.vmap(lambda s: d0.replace(qvel=d0.qvel * s))(scale)

    @jax.jit
    def run_steps(d):
        return jax.lax.scan(lambda d, _: (jax.vmap(mjx.step, in_axes=(None, 0))(m, d), None), d, None,
                            length=steps)[0]

    def run():
        with jax.enable_x64(False), jax.default_matmul_precision("highest"):
            return jax.block_until_ready(run_steps(batch).qpos)

    return run


def _device_name() -> str:
    import jax

    device = jax.devices()[0]
    kind = getattr(device, "device_kind", str(device))
    if device.platform == "cpu":   # JAX calls every CPU "cpu": name the processor and its cores
        model = [line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                 if line.startswith("model name")] if Path("/proc/cpuinfo").exists() else []
        kind = f"{model[0] if model else 'cpu'}, {os.cpu_count()} cores"
    return f"{device.platform}: {kind}"


def _report(rows, where, case, copies, steps, best, ratios, error32, finite) -> None:
    """Append and print a row per contender of ``best`` (name: s); ``ratios`` names the baselines."""
    import jax

    load = os.getloadavg()[0]
    for name, t in best.items():
        rate = copies * steps / t
        row = {"device": where, "jax": jax.__version__, "case": case, "copies": copies, "steps": steps,
               "contender": name, "scene_steps_per_s": round(rate), "ratio_to_numba": "", "ratio_to_mjx": "",
               "float32_error_m": error32 if name == "jax float32" else "",
               "finite": finite if name.startswith("jax float") else "", "load_1min": round(load, 2)}
        text = ""
        for column, baseline in ratios.items():
            if baseline in best:
                row[column] = round(best[baseline] / t, 3)
                text += f"  x{best[baseline] / t:.2f} {baseline.split()[0]}"
        rows.append(row)
        print(f"{case:6} {copies:>8,} {name:22} {rate:>14,.0f} scene-steps/s{text}"
              + (f"  float32 error {error32:.2e} m" if name == "jax float32" and error32 != "" else "")
              + f"  ({where}, load {load:.1f})", flush=True)


def measure(copies_list, steps: int, repeats: int, numba_max: int, grad_max: int, mjx_max: dict,
            save=lambda rows: None, only_mjx: bool = False) -> list[dict]:
    """The rows of the table; ``save(rows)`` after each case and copy count (a run cut short keeps what it
    measured). MJX is measured last, in a pass of its own against the JAX runs (its compilation is the slowest, and
    an MJX that stalls then costs nothing else)."""
    import jax.numpy as jnp

    where = _device_name()
    rows: list[dict] = []
    scenes = {"free": icosahedron_thrown(), "ground": ts.load_scene("icosahedron_ground")}
    dtypes = (("float64", jnp.float64), ("float32", jnp.float32))
    for case, scene in scenes.items():
        for copies in ([] if only_mjx else copies_list):
            contenders = {f"jax {name}": _run(scene, copies, steps, dtype) for name, dtype in dtypes}
            if case == "free" and copies <= grad_max:
                contenders["jax gradient float64"] = _gradient_case(scene, copies, steps)
            if copies <= numba_max:
                contenders["numba batch float64"] = (_numba_case if case == "free" else _numba_ground_case)(
                    scene, copies, steps)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                best = _best(contenders, repeats)
            # each JAX run starts from the same state: its output is that of the timed calls
            x64, x32 = (np.asarray(contenders[f"jax {name}"](), dtype=float) for name, _ in dtypes)
            _report(rows, where, case, copies, steps, best, {"ratio_to_numba": "numba batch float64"},
                    float(np.max(np.abs(x32 - x64))), bool(np.all(np.isfinite(x64)) and np.all(np.isfinite(x32))))
            save(rows)
    for case, scene in scenes.items():
        for copies in (c for c in copies_list if c <= mjx_max[case]):
            try:
                mjx_run = _mjx_case(scene, copies, steps)
                if mjx_run is None:
                    break
                mjx_run()   # compiles: an MJX that fails on the model fails here
            except Exception as exc:   # an MJX that does not take the model: say why, keep the rest
                print(f"MJX skipped ({case}, {copies}): {type(exc).__name__}: {exc}", file=sys.stderr)
                continue
            contenders = {f"jax {name}": _run(scene, copies, steps, dtype) for name, dtype in dtypes}
            contenders["mjx float32"] = mjx_run
            best = _best(contenders, repeats)
            measured = False
            for row in rows:   # the JAX rows of the first pass get this pass's in-turn ratio
                if (row["case"], row["copies"]) == (case, copies) and row["contender"] in best:
                    measured = True
                    row["ratio_to_mjx"] = round(best["mjx float32"] / best[row["contender"]], 3)
                    print(f"{case:6} {copies:>8,} {row['contender']:22} x{row['ratio_to_mjx']:.2f} MJX (in turns)")
            _report(rows, where, case, copies, steps, best if not measured else {"mjx float32": best["mjx float32"]},
                    {"ratio_to_mjx": "mjx float32"}, "", "")
            rows[-1]["finite"] = bool(np.all(np.isfinite(np.asarray(mjx_run()))))
            save(rows)
    return rows


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--gpu", action="store_true", help="the GPU run: 1,024 ... 524,288 copies")
    parser.add_argument("--copies", help="comma-separated copy counts (overrides the defaults)")
    parser.add_argument("--steps", type=int, default=200, help="steps per timed call (default 200)")
    parser.add_argument("--repeats", type=int, default=3, help="timed turns per contender (default 3)")
    parser.add_argument("--numba-max", type=int, default=4096,
                        help="the numba batch runs up to this many copies (default 4096)")
    parser.add_argument("--grad-max", type=int, default=65536,
                        help="the gradient runs up to this many copies (default 65536: the backward pass keeps every "
                             "step's carry, ~2 kB a copy-step in float64)")
    parser.add_argument("--mjx-max", type=int, default=65536,
                        help="MJX runs the free case up to this many copies (default 65536)")
    parser.add_argument("--mjx-ground-max", type=int, default=4096,
                        help="MJX runs the ground case up to this many copies (default 4096: its contacts step "
                             "~100x slower)")
    parser.add_argument("--only-mjx", action="store_true", help="the MJX pass alone (with the JAX runs it is timed "
                        "against)")
    parser.add_argument("--out", type=Path, default=RESULTS, help="folder of the CSV (default bench/results)")
    args = parser.parse_args(argv)
    import jax

    import tensegrity_sim.methods.jax  # noqa: F401  (turns on float64)

    copies = ([int(c) for c in args.copies.split(",")] if args.copies else
              list(GPU_COPIES if args.gpu else CPU_COPIES))
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / (f"jax_{jax.devices()[0].platform}.csv" if args.gpu else "jax.csv")
    measure(copies, args.steps, args.repeats, args.numba_max, args.grad_max,
            {"free": args.mjx_max, "ground": args.mjx_ground_max}, lambda rows: write_csv(path, rows), args.only_mjx)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
