"""A model fitted to a log (``tensegrity-sim fit``, ``tensegrity_sim.fit``): the log's ``node_poses`` and its
commands turned into :class:`~tensegrity_sim.methods.jax.fit.Observed`, fitted by multiple shooting
(``methods/jax/fit.py``), written out as a scene, a table and figures.

**The commands a run received.** Every ``cable_rest_lengths`` message (a ``JointState``: cable names and rest
lengths) and ``external_wrench`` message (a node's force) is logged at the simulation time it took effect: the
step that starts there, and every later one, runs with it. With the node's ``max_rest_length_rate`` > 0 a rest
length is a motor's target, which the rest length in effect follows at that speed (``reel_speed``, a parameter
that can be fitted). A pose is the state at its log time (the end of the step before).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import yaml

from ..scene import Scene, load_scene
from . import messages as M
from .interface import TOPICS
from .log_reader import LogError, LogReader
from .replay import _decode, _run_info

__all__ = ["read_observed", "fit_log"]


def read_observed(path: str | Path, scene: Scene | None = None):
    """(the log's embedded scene, :class:`Observed`) of the log at ``path``; the commands are laid over
    ``scene``'s rest lengths (default: the embedded scene's), which must have the log's nodes and cables."""
    from ..methods.jax.fit import Observed

    path = Path(path)
    with LogReader(path) as reader:
        info = _run_info(reader, path)
        logged = Scene.from_dict(yaml.safe_load(info["scene_yaml"]), source=f"{path} (embedded scene)")
        dt = float(info["dt"])
        reel = float(json.loads(info["node_settings"]).get("max_rest_length_rate", 0.0))
        topics = json.loads(info["topics"])
        keys = {topics[k]: k for k in ("node_poses", "cable_rest_lengths", "external_wrench") if k in topics}
        poses, steps, inputs = [], [], []
        for message in reader.messages():
            key = keys.get(message.topic)
            if key is None:
                continue
            step = round(message.log_time * 1e-9 / dt)
            msg = _decode(path, message, TOPICS[key].typename)
            if key == "node_poses":
                steps.append(step)
                poses.append([(p.position.x, p.position.y, p.position.z) for p in msg.poses])
            else:
                inputs.append((step, key, msg))
    if not poses:
        raise LogError(f"{path}: no node_poses in the log: fit needs the nodes' positions")
    scene = logged if scene is None else scene
    if scene.node_names != logged.node_names or scene.cable_names != logged.cable_names or \
            [c.nodes for c in scene.cables] != [c.nodes for c in logged.cables]:
        raise ValueError(f"{scene.source}: its nodes and cables are not the log's ({len(logged.nodes)} nodes "
                         f"{', '.join(logged.node_names)}; cables {', '.join(logged.cable_names)})")
    bad = [k for k, p in enumerate(poses) if len(p) != len(scene.nodes)]
    if bad:
        raise LogError(f"{path}: node_poses at t = {steps[bad[0]] * dt:.6f} s has {len(poses[bad[0]])} poses, "
                       f"the scene {len(scene.nodes)} nodes")
    positions = np.array(poses, dtype=float)
    finite = np.all(np.isfinite(positions), axis=(1, 2))
    if not finite.all():
        k = int(np.flatnonzero(~finite)[0])
        raise ValueError(f"{path}: node_poses at t = {steps[k] * dt:.6f} s holds a non-finite position (NaN or "
                         f"inf): remove or repair that pose")
    order = np.argsort(steps, kind="stable")
    steps, positions = np.asarray(steps, dtype=np.int64)[order], positions[order]
    keep = np.concatenate([[True], np.diff(steps) > 0])   # a pose logged twice at one step: the first
    rest, forces = _commands(path, scene, inputs, int(steps[-1]), dt)
    return logged, Observed(dt, steps[keep], positions[keep], rest, forces, reel)


def _commands(path: Path, scene: Scene, inputs: list, n_steps: int, dt: float):
    """The rest lengths (targets) (S, nc) m and forces (S, N, 3) N in effect at every step from the input
    messages (step, key, message)."""
    cables = {n: i for i, n in enumerate(scene.cable_names)}
    nodes = {n: i for i, n in enumerate(scene.node_names)}
    rest = np.repeat(scene.cable_rest_lengths[None], n_steps, axis=0)
    forces = np.zeros((n_steps, len(scene.nodes), 3))
    for step, key, msg in sorted(inputs, key=lambda item: item[0]):
        if step >= n_steps:
            continue
        if key == "cable_rest_lengths":
            for name, value in zip(msg.name, np.asarray(msg.position, dtype=float)):
                if name not in cables:
                    raise LogError(f"{path}: cable_rest_lengths at t = {step * dt:.6f} s names cable {name!r}, "
                                   f"which the scene does not have")
                rest[step:, cables[name]] = value
        else:
            node = msg.header.frame_id
            if node not in nodes:
                raise LogError(f"{path}: external_wrench at t = {step * dt:.6f} s names node {node!r}, which the "
                               f"scene does not have")
            f = msg.wrench.force
            forces[step:, nodes[node]] = (f.x, f.y, f.z)
    return rest, forces


def fit_log(log: str | Path, params: str, *, scene: str | Path | Scene | None = None, window: int | None = None,
            loss: str = "linear", loss_scale: float = 3e-3, prior: float = 0.0, chord: bool = False,
            out: str | Path | None = None, plot: str | Path | None = None):
    """Fit ``params`` (``methods/jax/fit.py``'s ``parse_parameters``) to the log at ``log``, starting from
    ``scene`` (a scene or its file: the nominal model; default the log's own); writes the fitted scene to ``out``
    and the before/after figures into the directory ``plot`` when given. Returns the ``FitResult``."""
    from ..methods.jax.fit import fit_observed, parse_parameters

    nominal = scene if isinstance(scene, Scene) or scene is None else load_scene(scene)
    logged, observed = read_observed(log, nominal)
    nominal = logged if nominal is None else nominal
    unknowns = parse_parameters(params, nominal, reel_speed=observed.reel_speed)
    result = fit_observed(nominal, observed, unknowns, window=window, loss=loss, loss_scale=loss_scale,
                          prior=prior, chord=chord)
    if out is not None:
        Path(out).write_text(result.scene.to_yaml())
    if plot is not None:
        from ..viz.fit_plots import plot_fit

        plot_fit(result, Path(plot))
    return result


def table(result) -> list[str]:
    """The per-parameter table and the fit's summary lines."""
    from ..methods.jax.fit import KINDS

    out = [f"{'parameter':<16} {'start':>14} {'fitted':>14} {'sigma':>11}  unit"]
    for u, a, b, s in zip(result.unknowns, result.start, result.fitted, result.sigma):
        out.append(f"{u.name:<16} {a:>14.8g} {b:>14.8g} {s:>11.3g}  {KINDS[u.kind] or '-'}"
                   + (" (total)" if u.kind == "mass" else ""))
    out += [f"residual (rms)   {result.rms_start:.6g} m -> {result.rms_fitted:.6g} m "
            f"({result.evaluations} runs; {result.message})",
            f"pose noise       {result.noise:.3g} m (estimated from the residual)",
            f"windows          {result.windows} of {result.window} x {result.every} steps "
            f"({result.switches} slack/taut switches seen in the poses; {result.jacobians} Jacobians of the "
            f"start states)"]
    return out
