"""Fitting scene parameters to observed node positions by least squares with the JAX run's exact Jacobian
(``tensegrity-sim fit``, which reads the positions from a log's ``node_poses``).

The unknowns (``--params``, comma-separated):

    stiffness        every cable's stiffness times one factor (N/m)
    damping          one damping for every cable (N*s/m)
    mass             every mass of the scene (nodes and struts) times one factor (kg)
    stiffness:NAME   cable NAME's stiffness alone; damping:NAME likewise

The residual is the run's positions at the observed steps minus the observed ones (m), from the scene's initial
state with its inputs held; ``scipy.optimize.least_squares`` (Levenberg-Marquardt) minimises its sum of squares,
with the Jacobian from ``jax.jacfwd`` (forward mode: a few unknowns, many residuals). Each unknown is scaled by
its start value (a damping that starts at zero by 1 N*s/m), so the problem is well conditioned whatever the units.
The derivative is that of the discrete run (``elastic.py``'s docstring): through slack/taut switches the
residual is only piecewise smooth, and a start that moves a switch across a step may need a closer guess.
"""
from __future__ import annotations

from dataclasses import dataclass
from math import gcd

import jax
import jax.numpy as jnp
import numpy as np
from scipy.optimize import least_squares

from ...scene import Scene
from ...system import System
from ..rigid import RigidStruts
from .elastic import held_inputs, model_arrays, rollout

__all__ = ["FitResult", "fit_positions", "parse_parameters"]

KINDS = {"stiffness": "N/m", "damping": "N*s/m", "mass": "kg"}


@dataclass(frozen=True)
class Unknown:
    """One fitted number: ``kind`` (stiffness, damping, mass), the cables it sets (indices; all for mass) and its
    name as given."""

    name: str
    kind: str
    cables: tuple[int, ...]


def parse_parameters(spec: str, scene: Scene) -> list[Unknown]:
    """The unknowns of ``--params`` (module docstring), checked against ``scene``."""
    index = {n: i for i, n in enumerate(scene.cable_names)}
    out = []
    for item in [s.strip() for s in spec.split(",") if s.strip()]:
        kind, _, name = item.partition(":")
        if kind not in KINDS or (name and kind == "mass"):
            raise ValueError(f"--params: unknown parameter {item!r} (known: stiffness, damping, mass, "
                             f"stiffness:CABLE, damping:CABLE)")
        if name and name not in index:
            raise ValueError(f"--params: {item!r}: no cable {name!r} in the scene (cables: {', '.join(index)})")
        cables = (index[name],) if name else tuple(range(len(scene.cables)))
        out.append(Unknown(item, kind, cables))
    if not out:
        raise ValueError("--params: name at least one parameter (stiffness, damping, mass)")
    names = [u.name for u in out]
    if len(set(names)) != len(names):
        raise ValueError(f"--params: a parameter is named twice: {spec!r}")
    return out


@dataclass(frozen=True)
class FitResult:
    """start and fitted: each unknown's value (its unit in ``KINDS``; a stiffness or mass group: the mean over it);
    rms_start, rms_fitted: the residual's root mean square, m; scene: the scene with the fitted values;
    evaluations: runs of the model; message: the solver's."""

    unknowns: list[Unknown]
    start: np.ndarray
    fitted: np.ndarray
    rms_start: float
    rms_fitted: float
    scene: Scene
    evaluations: int
    message: str


def _base_values(scene: Scene, u: Unknown) -> np.ndarray:
    if u.kind == "mass":
        return scene.masses
    return np.array([getattr(scene.cables[i], u.kind) for i in u.cables], dtype=float)


def fit_positions(scene: Scene, dt: float, steps: np.ndarray, positions: np.ndarray, unknowns: list[Unknown], *,
                  tolerance: float = 1e-14) -> FitResult:
    """Fit ``unknowns`` of ``scene`` (start values and initial state) so that its elastic run with steps of ``dt``
    (s), inputs held, passes through ``positions`` (K, N, 3) m after ``steps`` (K,) steps (increasing, > 0)."""
    steps = np.asarray(steps, dtype=np.int64)
    if steps.ndim != 1 or not len(steps) or np.any(steps <= 0) or np.any(np.diff(steps) <= 0):
        raise ValueError("the observed steps must increase strictly from 1 on")
    if positions.shape != (len(steps), len(scene.nodes), 3):
        raise ValueError(f"positions: expected shape {(len(steps), len(scene.nodes), 3)}, got {positions.shape}")
    system = System(scene)
    rigid = RigidStruts(system)
    model = model_arrays(system, rigid)
    x0, v0 = scene.positions, scene.velocities
    if rigid.count:   # as Simulator's reset: no initial velocity stretches a rigid strut
        v0 = v0 + rigid.project_velocities(x0, v0)
    every = int(np.gcd.reduce(steps))
    kept = steps // every - 1
    inputs = held_inputs(scene.cable_rest_lengths[:, None], np.zeros((len(scene.nodes), 3, 1)))
    ns = system.n_struts
    bases = [_base_values(scene, u) for u in unknowns]
    # each unknown is a factor on its start values, or (a damping starting at 0) a value in N*s/m
    factor = [u.kind == "mass" or bool(np.all(b > 0)) for u, b in zip(unknowns, bases)]
    scales = [b if f else np.ones_like(b) for b, f in zip(bases, factor)]
    start = np.array([1.0 if f else float(np.mean(b)) for b, f in zip(bases, factor)])
    observed = jnp.asarray(positions)

    def model_of(p):
        m = model
        for u, scale, value in zip(unknowns, scales, p):
            if u.kind == "stiffness":
                m = m._replace(stiffness=m.stiffness.at[ns + np.array(u.cables)].set(scale * value))
            elif u.kind == "damping":
                m = m._replace(damping=m.damping.at[np.array(u.cables)].set(scale * value))
            else:
                m = m._replace(masses=jnp.asarray(scale) * value)
        return m

    @jax.jit
    def residual(p):
        out = rollout(model_of(p), jnp.asarray(x0[..., None]), jnp.asarray(v0[..., None]), inputs, dt,
                      int(steps[-1]), every)
        return (out.x[kept, ..., 0] - observed).ravel()

    jacobian = jax.jit(jax.jacfwd(residual))
    r0 = np.asarray(residual(jnp.asarray(start)))
    sol = least_squares(lambda p: np.asarray(residual(jnp.asarray(p))), start,
                        jac=lambda p: np.asarray(jacobian(jnp.asarray(p))), method="lm",
                        xtol=tolerance, ftol=tolerance, gtol=tolerance)
    fitted_model = model_of(sol.x)
    values = lambda m: np.array([float(np.mean(_values(m, u, ns))) for u in unknowns])   # noqa: E731
    return FitResult(unknowns, values(model), values(fitted_model), float(np.sqrt(np.mean(r0 ** 2))),
                     float(np.sqrt(np.mean(sol.fun ** 2))), _fitted_scene(scene, unknowns, fitted_model, ns),
                     int(sol.nfev), sol.message)


def _values(m, u: Unknown, ns: int) -> np.ndarray:
    if u.kind == "stiffness":
        return np.asarray(m.stiffness)[ns + np.array(u.cables)]
    if u.kind == "damping":
        return np.asarray(m.damping)[np.array(u.cables)]
    return np.asarray(m.masses)


def _fitted_scene(scene: Scene, unknowns: list[Unknown], m, ns: int) -> Scene:
    """``scene`` with the fitted values (every mass scaled by the fitted factor: node and strut masses)."""
    d = scene.to_dict()
    for u in unknowns:
        if u.kind == "mass":
            factor = float(np.asarray(m.masses)[scene.masses > 0][0] / scene.masses[scene.masses > 0][0])
            for item in d["nodes"] + d["struts"]:
                if "mass" in item:
                    item["mass"] = float(item["mass"]) * factor
            continue
        for i, value in zip(u.cables, _values(m, u, ns)):
            d["cables"][i][u.kind] = float(value)
    return Scene.from_dict(d, source=f"{scene.source} (fitted)")
