"""Fitting scene parameters to observed node positions by multiple shooting (``tensegrity-sim fit``, which reads
the positions and the commands from a log: ``tensegrity_sim.ros.fit_log``).

**The unknowns** (``parse_parameters``, comma-separated):

    stiffness, damping            one factor on every cable's stiffness (N/m) / one damping for every cable
    stiffness:CABLE, damping:CABLE that cable's alone; stiffness:each, damping:each one unknown per cable
    mass                          one factor on every mass of the scene (nodes and struts), kg
    mass:NODE, mass:STRUT         a node's own mass / a strut's mass (half on each end)
    friction, restitution         the ground's Coulomb coefficient and Newton's restitution
    reel_speed                    the motors' top speed (the node's max_rest_length_rate), m/s

**Multiple shooting.** The observed steps are put on a grid (the greatest common divisor of their spacing) and
cut into windows of ``window`` grid intervals. Each window is restarted from its own initial positions and
velocities, which are unknowns of the least squares too (started from the observed positions and their central
finite differences), so that an error in the parameters cannot build up over more than one window and the
landscape stays close to quadratic: the fit does not depend on a start within a factor of 2 of the truth. The
residual holds, in metres: every observation minus the simulated position at its step (each observation once:
the first by the first window's initial positions, every other by the window that ends at or runs through it),
and, weighted by ``continuity``, each window's end state minus the next window's start (velocities times the
grid interval). All windows run as one batch of the JAX step (the batch axis is the window: on a GPU they run
together), with the commands in effect at every step of each (rest lengths, forces; a rate-limited motor
follows its targets at ``reel_speed``, differentiable in it).

**The Jacobian** is exact (forward mode) and sparse: a window's residuals depend on the parameters and its own
start state only (a continuity row also on the next window's start, linearly). One ``jax.jvp`` per parameter and
per start-state coordinate, seeded in every window at once, gives every window's block together (6 N + P tangents
whatever the number of windows); the jvps are vmapped over their seeds, so the run itself is computed once for all
of them, and the seeds are split among JAX's devices (``shard_map``; on a CPU one device per core where the
process called :func:`spread_over_cores` before JAX ran, as the ``fit`` verb does). Every run here is
differentiated in forward mode only, so a ground's sweeps stop at ``ground.TOLERANCE`` (``ground.py``:
warm-started, each end on the problem with its strut's length row eliminated; half the CPU of the fixed 60 sweeps
a Jacobian of the rolling icosahedron).

**Two stages.** First the parameters alone, every window held at its start from the poses
(``scipy.optimize.least_squares``, trust region reflective, P tangents a Jacobian): cheap, and close to the
optimum where the poses' start states are (noise-free, the 10 s roll's stiffness 2e-5, its damping 1.2 % off).
Each window starts from the poses' central differences or, where its run follows its poses closer, from their
local quadratics (``SMOOTHING``; :meth:`_Problem.choose_starts`, before the first stage and after it: noisy logs).
Then everything, by Levenberg-Marquardt with the sparse normal equations solved exactly
(``_levenberg_marquardt``): Gauss-Newton's steps near the optimum (least_squares' sparse solver takes lsmr's
inexact step in a two-dimensional subspace, and with it and the chord the 10 s roll stopped 3 % off). The start
states' tangents (6 N of the 6 N + P runs, the Jacobian's cost) are computed fresh after the first stage and, with
``chord``, reused between steps while a step does at least ``REFRESH`` of what its linear model predicted; the
parameters' are computed every time. It stops once the parameters' steps are below ``SIGMA_STEP`` of their
standard deviations (``_levenberg_marquardt``). ``loss``: ``soft_l1``, ``huber``, ``cauchy``, ``arctan`` (scipy's, with
``loss_scale`` in m; the normal equations weighted by the loss's derivative).

**Bounds and prior.** Bounds are physical (stiffness, mass and reel speed > 0, damping and friction >= 0,
restitution in [0, 1]); an unknown with a positive scene value is fitted as a factor on it, one that is 0 in the
scene as its value. ``prior`` > 0
adds one row per factor, ``loss_scale (factor - 1) / prior``: a Gaussian prior of relative standard deviation
``prior`` about the scene's value, weighed against poses of noise ``loss_scale``.

**Uncertainty and noise.** The pose noise is estimated from the observation residual at the optimum (its root
mean square with the degrees of freedom taken off); each parameter's standard deviation is that noise times
the square root of the parameter's diagonal entry of ``(J^T J)^-1``, the window states eliminated by their Schur
complement (a sparse factorisation).

**Windows by default** (``choose_window``): the observed cable lengths against the rest lengths give the
slack/taut switches; a window holds about ``SWITCHES_PER_WINDOW`` of them (a switch moves where a parameter
changes, and the discrete run's derivative jumps there: ``elastic.py``), between ``MIN_WINDOW`` and
``MAX_WINDOW`` grid intervals.
"""
from __future__ import annotations

import os
import time
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp
from jax import lax, shard_map
from jax.sharding import Mesh
from jax.sharding import PartitionSpec as Spec
from scipy.optimize import least_squares
from scipy.sparse.linalg import splu

from ...scene import Scene
from ...system import System
from ..rigid import RigidStruts
from .elastic import Carry, model_arrays, start_carry, verlet_step
from .ground import TOLERANCE

__all__ = ["KINDS", "LOSSES", "FitResult", "Observed", "Unknown", "choose_window", "fit_observed",
           "parse_parameters", "spread_over_cores"]

KINDS = {"stiffness": "N/m", "damping": "N*s/m", "mass": "kg", "friction": "", "restitution": "",
         "reel_speed": "m/s"}
LOSSES = {   # rho(z) and rho'(z) of z = (r / loss_scale)^2, as scipy.optimize.least_squares' losses
    "linear": (lambda z: z, np.ones_like),
    "soft_l1": (lambda z: 2.0 * (np.sqrt(1.0 + z) - 1.0), lambda z: 1.0 / np.sqrt(1.0 + z)),
    "huber": (lambda z: np.where(z <= 1.0, z, 2.0 * np.sqrt(z) - 1.0),
              lambda z: np.where(z <= 1.0, 1.0, 1.0 / np.sqrt(np.maximum(z, 1.0)))),
    "cauchy": (np.log1p, lambda z: 1.0 / (1.0 + z)),
    "arctan": (np.arctan, lambda z: 1.0 / (1.0 + z * z)),
}
SWITCHES_PER_WINDOW = 4.0
MIN_WINDOW, MAX_WINDOW = 5, 40   # grid intervals
CONTINUITY = 10.0                # weight of the continuity rows against the observations'
PRIOR = 0.0                      # the prior's relative standard deviation about the scene's values (0: none)
REFRESH = 0.5                   # the chord's tangents are refreshed after a step doing less than this of its model
PARAMETER_TOLERANCE = 1e-5       # a parameter's (a factor's) step that ends the fit
FAILED = 8                      # failed steps in a row on fresh tangents that end the fit
HELD_TOLERANCE = 1e-6           # the first stage's (the parameters alone, the windows' starts held from the poses)
SMOOTHING = (4, 8)               # grid points each side of the smoothed start states' local quadratics
SIGMA_STEP = 0.1                 # a parameter step below this many of its standard deviations ends the fit,
SETTLED = 1e-2                   # in a step that decreased the cost by less than this of itself (else it is no noise)


def spread_over_cores() -> bool:
    """Give JAX's CPU one device per core this process may use (``jax_num_cpu_devices``), so that a fit's
    tangents run on every core (:meth:`_Problem._jit`). For a fit's own process (the ``fit`` verb, a bench),
    before JAX has run anything: after that its devices are fixed, and this changes nothing (returns False)."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    try:
        jax.config.update("jax_num_cpu_devices", cores)
    except RuntimeError:   # JAX has run: its backends are initialised
        return False
    return True


@dataclass(frozen=True)
class Unknown:
    """One fitted number: ``kind`` (a key of ``KINDS``), its name as given; the cables it sets (stiffness,
    damping) and, for a mass, its share of every node's lumped mass (N,) kg in the scene."""

    name: str
    kind: str
    cables: tuple[int, ...] = ()
    masses: tuple[float, ...] = ()


@dataclass(frozen=True)
class Observed:
    """What a run shows: ``positions`` (K, N, 3) m after ``steps`` (K,) steps of ``dt`` s (strictly increasing,
    >= 0); the commands in effect at every step ``k < steps[-1]`` (the one from ``k dt`` to ``(k + 1) dt``):
    ``rest`` (S, nc) m (a motor's target where ``reel_speed`` > 0) and ``forces`` (S, N, 3) N; ``reel_speed``
    m/s, the fastest a rest length follows its target (0: at once)."""

    dt: float
    steps: np.ndarray
    positions: np.ndarray
    rest: np.ndarray
    forces: np.ndarray
    reel_speed: float = 0.0


def parse_parameters(spec: str, scene: Scene, *, reel_speed: float = 0.0) -> list[Unknown]:
    """The unknowns of ``--params`` (module docstring), checked against ``scene`` (and ``reel_speed``, the run's
    motor speed: 0, no limit, has nothing to fit)."""
    cables = {n: i for i, n in enumerate(scene.cable_names)}
    nodes = {n: i for i, n in enumerate(scene.node_names)}
    struts = {s.name: s for s in scene.struts}
    known = "stiffness, damping, mass, friction, restitution, reel_speed, stiffness:CABLE|each, " \
            "damping:CABLE|each, mass:NODE|STRUT"
    out = []
    for item in [s.strip() for s in spec.split(",") if s.strip()]:
        kind, _, name = item.partition(":")
        if kind not in KINDS or (name and kind not in ("stiffness", "damping", "mass")):
            raise ValueError(f"--params: unknown parameter {item!r} (known: {known})")
        if kind in ("friction", "restitution") and scene.ground is None:
            raise ValueError(f"--params: {item!r}: the scene has no ground")
        if kind == "reel_speed" and not reel_speed > 0:
            raise ValueError("--params: 'reel_speed': the run's motors had no speed limit (the node's "
                             "max_rest_length_rate was 0): nothing to fit")
        if kind == "mass":
            out.append(Unknown(item, kind, masses=tuple(_mass_share(scene, name, nodes, struts))))
        elif name == "each":
            out += [Unknown(f"{kind}:{c}", kind, (i,)) for c, i in cables.items()]
        elif name and name not in cables:
            raise ValueError(f"--params: {item!r}: no cable {name!r} in the scene (cables: {', '.join(cables)})")
        else:
            out.append(Unknown(item, kind, (cables[name],) if name else tuple(range(len(scene.cables)))))
    if not out:
        raise ValueError(f"--params: name at least one parameter ({known})")
    names = [u.name for u in out]
    if len(set(names)) != len(names):
        raise ValueError(f"--params: a parameter is named twice: {spec!r}")
    return out


def _mass_share(scene: Scene, name: str, nodes: dict, struts: dict) -> np.ndarray:
    """(N,) kg: what the mass ``name`` (none: every mass) adds to each node's lumped mass."""
    if name and name not in nodes and name not in struts:
        raise ValueError(f"--params: 'mass:{name}': no node or strut {name!r} in the scene")
    share = _scaled(scene, name, 2.0).masses - scene.masses
    if not np.any(share > 0):
        raise ValueError(f"--params: 'mass:{name}': it has no mass in the scene (nothing to scale)")
    return share


def _scaled(scene: Scene, name: str, factor: float) -> Scene:
    """``scene`` with the mass of node or strut ``name`` (a strut's payloads too; none: every mass) times
    ``factor``."""
    d = scene.to_dict()
    for key in ("nodes", "struts"):
        for item in d.get(key) or []:
            if name and item["name"] != name:
                continue
            if "mass" in item:
                item["mass"] = float(item["mass"]) * factor
            for payload in item.get("payloads") or []:
                payload["mass"] = float(payload["mass"]) * factor
    return Scene.from_dict(d, source=scene.source)


@dataclass(frozen=True)
class FitResult:
    """start, fitted, sigma: each unknown's value and standard deviation (its unit in ``KINDS``; a group of
    cables: the mean over it; a mass: its total); rms_start, rms_fitted: the observation residual's root mean
    square, m; noise: the pose noise estimated from it, m; scene: the scene with the fitted values; window: grid
    intervals per window, windows, every: steps of ``dt`` s per grid interval; grid_steps (G,), observed
    (G, N, 3) (NaN where no pose), before, after (G, N, 3): the windows' simulated positions at the start and at
    the optimum; evaluations: runs of the model; message: the solver's; reel_speed: the fitted one (m/s, 0: none);
    switches: the slack/taut switches seen in the poses; jacobians: the start states' Jacobians computed (the
    rest of the runs reused one)."""

    unknowns: list[Unknown]
    start: np.ndarray
    fitted: np.ndarray
    sigma: np.ndarray
    rms_start: float
    rms_fitted: float
    noise: float
    scene: Scene
    window: int
    windows: int
    every: int
    dt: float
    grid_steps: np.ndarray
    observed: np.ndarray
    before: np.ndarray
    after: np.ndarray
    evaluations: int
    message: str
    reel_speed: float = 0.0
    switches: int = field(default=0)
    jacobians: int = field(default=0)


def observed_slack(scene: Scene, obs: Observed) -> tuple[np.ndarray, int]:
    """Which cables are seen taut at some pose ((nc,) bool), and the slack/taut switches between consecutive
    poses (against the rest lengths in effect, or targeted, at each)."""
    system = System(scene)
    ends = system.ends[system.n_struts:]
    d = obs.positions[:, ends[:, 1]] - obs.positions[:, ends[:, 0]]
    length = np.sqrt(np.einsum("kcj,kcj->kc", d, d))
    rest = obs.rest[np.minimum(obs.steps, len(obs.rest) - 1)] if len(obs.rest) else scene.cable_rest_lengths[None]
    taut = length >= rest
    return taut.any(axis=0), int(np.count_nonzero(taut[1:] != taut[:-1]))


def choose_window(obs: Observed, switches: int, every: int) -> int:
    """Grid intervals per window: about ``SWITCHES_PER_WINDOW`` switches in each (module docstring)."""
    intervals = max(1, (int(obs.steps[-1]) - int(obs.steps[0])) // every)
    if switches == 0:
        return int(min(MAX_WINDOW, intervals))
    return int(np.clip(round(SWITCHES_PER_WINDOW * intervals / switches), MIN_WINDOW, MAX_WINDOW))


class _Problem:
    """The windows, their data and the residual and Jacobian of the least squares (module docstring)."""

    def __init__(self, scene: Scene, obs: Observed, unknowns: list[Unknown], window: int, continuity: float,
                 prior: float = PRIOR, prior_scale: float = 1e-3):
        self.scene, self.obs, self.unknowns = scene, obs, unknowns
        system = System(scene)
        rigid = RigidStruts(system)
        self.model = model_arrays(system, rigid)
        if self.model.ground is not None:   # forward mode only: the ground's sweeps may stop at a tolerance
            self.model = self.model._replace(ground=self.model.ground._replace(tolerance=TOLERANCE))
        self.ns = system.n_struts
        self.free = np.flatnonzero(system.free)
        steps = np.asarray(obs.steps, dtype=np.int64)
        self.every = every = int(np.gcd.reduce(np.diff(steps))) if len(steps) > 1 else 1
        self.first = int(steps[0])
        g = (int(steps[-1]) - self.first) // every + 1
        self.window = L = int(min(window, g - 1))
        self.windows = W = -(-(g - 1) // L)
        n, nf = len(scene.nodes), len(self.free)
        grid = np.full((W * L + 1, n, 3), np.nan)
        grid[(steps - self.first) // every] = obs.positions
        self.grid_steps = self.first + every * np.arange(g)
        self.observed = grid[:g]
        self.mask = ~np.isnan(grid[:, 0, 0])
        filled = _fill(grid)
        # targets in window order: obs (L, nf, 3, W) of grid w L + 1 .. w L + L, and the window starts
        idx = np.arange(W)[None, :] * L + np.arange(1, L + 1)[:, None]          # (L, W)
        self.target = np.transpose(filled[idx][:, :, self.free], (0, 2, 3, 1))   # (L, nf, 3, W)
        self.obs_mask = self.mask[idx].astype(float)                            # (L, W)
        self.start_grid = np.arange(W) * L
        tau = every * obs.dt
        x0 = filled[self.start_grid]                                            # (W, N, 3)
        before, after = _fill_at(filled, self.start_grid - 1), _fill_at(filled, self.start_grid + 1)
        span = np.where((self.start_grid > 0) & (self.start_grid + 1 < len(filled)), 2.0, 1.0)
        v0 = (after - before) / (span[:, None, None] * tau)
        self.fixed_x = np.moveaxis(filled[self.start_grid], 0, -1)               # (N, 3, W)
        self.state0 = np.concatenate([x0[:, self.free].reshape(W, -1), v0[:, self.free].reshape(W, -1)], axis=1)
        # the smoothed candidates of the start states: a local quadratic through the poses within k of each start
        self.smoothed = [np.concatenate([a[:, self.free].reshape(W, -1) for a in
                                         _local_quadratic(grid[:g], self.start_grid, k, tau)], axis=1)
                         for k in SMOOTHING]
        self.nf, self.tau, self.cw = nf, tau, continuity
        # the steps of every window: (L, every) step indices into the per-step commands (held past the last)
        step_idx = (self.first + np.arange(W)[None, None, :] * L * every
                    + np.arange(L)[:, None, None] * every + np.arange(every)[None, :, None])   # (L, every, W)
        self.step_idx = np.minimum(step_idx, max(len(obs.rest) - 1, 0))
        self.forces = np.moveaxis(obs.forces[self.step_idx], 2, -1) if len(obs.forces) else \
            np.zeros((L, every, n, 3, W))                                        # (L, every, N, 3, W)
        self.rest_fixed = np.moveaxis(obs.rest[self.step_idx], 2, -1) if len(obs.rest) else \
            np.broadcast_to(scene.cable_rest_lengths[None, None, :, None], (L, every, len(scene.cables), W))
        self.reel = obs.reel_speed
        # the commands, handed to the compiled runs as arguments (as constants XLA would fold them, slowly)
        self.data = (jnp.asarray(self.rest_fixed), jnp.asarray(self.forces), jnp.asarray(obs.rest))
        # the unknowns: factors on their start values (an unknown starting at 0: its value)
        # a mass unknown's share of the model's lumped masses and mass blocks (both linear in the masses)
        self.mass_shares = {}
        for u in unknowns:
            if u.kind == "mass":
                doubled = System(_scaled(scene, u.name.partition(":")[2], 2.0))
                other = model_arrays(doubled, RigidStruts(doubled))
                self.mass_shares[u.name] = (other.masses - self.model.masses,
                                            other.mass_block - self.model.mass_block)
        self.base = [self._base_value(u) for u in unknowns]
        self.factor = [bool(b > 0) for b in self.base]
        self.p0 = np.array([1.0 if f else 0.0 for f in self.factor])
        self.n_params = len(unknowns)
        # the prior rows: prior_scale (m) times each factor's distance from 1 in prior standard deviations
        self.prior_rows = np.flatnonzero(self.factor) if prior > 0 else np.zeros(0, int)
        self.prior_weight = prior_scale / prior if prior > 0 else 0.0
        self._chord, self._gram, self.param_columns, self.state_jacobians = None, None, None, 0
        self._jit()

    # ----------------------------------------------------------------- parameters
    def _base_value(self, u: Unknown) -> float:
        sc, m = self.scene, self.model
        if u.kind == "stiffness":
            return float(np.mean(np.asarray(m.stiffness)[self.ns + np.array(u.cables)]))
        if u.kind == "damping":
            values = np.asarray(m.damping)[np.array(u.cables)]
            return float(np.mean(values)) if np.all(values > 0) else 0.0
        if u.kind == "mass":
            return float(np.sum(u.masses))
        if u.kind == "reel_speed":
            return self.obs.reel_speed
        return float(getattr(sc.ground, u.kind))

    def values(self, p) -> np.ndarray:
        """Each unknown's value (a group of cables: the mean; a mass: its total) at ``p``."""
        return np.array([b * v if f else v for b, f, v in zip(self.base, self.factor, np.asarray(p))])

    def model_of(self, p):
        m, ns = self.model, self.ns
        masses = m.masses
        for u, f, value in zip(self.unknowns, self.factor, p):
            if u.kind == "stiffness":
                idx = ns + np.array(u.cables)
                m = m._replace(stiffness=m.stiffness.at[idx].set(self.model.stiffness[idx] * value))
            elif u.kind == "damping":
                idx = np.array(u.cables)
                m = m._replace(damping=m.damping.at[idx].set(self.model.damping[idx] * value if f else value))
            elif u.kind == "mass":
                lumped, block = self.mass_shares[u.name]
                masses = masses + (value - 1.0) * lumped
                m = m._replace(mass_block=m.mass_block + (value - 1.0) * block)
            elif u.kind in ("friction", "restitution"):
                base = getattr(self.model.ground, u.kind)
                m = m._replace(ground=m.ground._replace(**{u.kind: base * value if f else value}))
        return m._replace(masses=masses)

    def rest_of(self, p, data):
        """The rest lengths in effect at every step of every window (L, every, nc, W)."""
        rest_fixed, _, targets = data
        if not self.reel > 0:
            return rest_fixed
        speed = self.reel
        for u, value in zip(self.unknowns, p):
            if u.kind == "reel_speed":
                speed = self.reel * value
        reach = speed * self.obs.dt

        def move(applied, target):   # the node's rate limiter (node_logic.step), landing on the target
            diff = target - applied
            applied = jnp.where(jnp.abs(diff) <= reach, target, applied + jnp.sign(diff) * reach)
            return applied, applied

        _, applied = lax.scan(move, jnp.asarray(self.scene.cable_rest_lengths), targets)
        return jnp.moveaxis(applied[self.step_idx], 2, -1)

    # ----------------------------------------------------------------- the run of the windows
    def _states(self, state):
        """Start positions and velocities (N, 3, W) of the windows from their unknown states (W, 6 nf)."""
        nf = self.nf
        xf = state[:, :3 * nf].reshape(-1, nf, 3)
        vf = state[:, 3 * nf:].reshape(-1, nf, 3)
        x = jnp.asarray(self.fixed_x).at[self.free].set(jnp.moveaxis(xf, 0, -1))
        v = jnp.zeros_like(x).at[self.free].set(jnp.moveaxis(vf, 0, -1))
        return x, v

    def run(self, p, state, data):
        """The windows from start states ``state`` (W, 6 nf), with ``data`` (the commands, :attr:`data`):
        positions at each observation (L, N, 3, W), end positions and velocities (N, 3, W)."""
        model = self.model_of(p)
        rest, forces = self.rest_of(p, data), data[1]
        x0, v0 = self._states(state)
        h = jnp.asarray(self.obs.dt)
        carry = start_carry(model, x0, v0, rest[0, 0], forces[0, 0])

        def step(loop, inputs):
            carry, r_prev, f_prev = loop
            r, f = inputs
            changed = jnp.any(r != r_prev, axis=0) | jnp.any(f != f_prev, axis=(0, 1))   # (W,)

            def restart():   # a new input: the start forces with it, in the windows where it changed
                fresh = start_carry(model, carry.x, carry.v, r, f, carry.contact)
                return Carry(*(jnp.where(changed, a, b) for a, b in zip(fresh, carry)))

            carry = lax.cond(jnp.any(changed), restart, lambda: carry)
            carry = verlet_step(model, carry, r, f, h)[0]
            return (carry, r, f), None

        def interval(loop, inputs):
            loop, _ = lax.scan(step, loop, inputs)
            return loop, loop[0].x

        (carry, _, _), xs = lax.scan(interval, (carry, rest[0, 0], forces[0, 0]), (rest, forces))
        return xs, carry.x, carry.v

    def _jit(self):
        free = self.free

        def pieces(p, state, data):
            xs, xe, ve = self.run(p, state, data)
            return xs[:, free], xe[free], ve[free]

        self.pieces = jax.jit(pieces)
        self.simulated = jax.jit(lambda p, state, data: self.run(p, state, data)[0])
        # the tangents: one jvp per seed, vmapped over the seeds (the run itself computed once, not once per
        # seed), the seeds split among the devices (shard_map; on a CPU, as many devices as jax_num_cpu_devices:
        # spread_over_cores), each running every window
        mesh = Mesh(np.array(jax.devices()), ("seeds",))
        self.devices = mesh.size

        def spread(tangent):
            batched = lambda p, state, data, seeds: jax.vmap(lambda e: tangent(p, state, data, e))(seeds)  # noqa
            return jax.jit(shard_map(batched, mesh=mesh, in_specs=(Spec(), Spec(), Spec(), Spec("seeds")),
                                     out_specs=Spec("seeds")))

        # a parameter's tangent: every window at once; a start-state coordinate's: seeded in every window at once
        self.param_tangents = spread(lambda p, state, data, dp: jax.jvp(lambda q: pieces(q, state, data), (p,),
                                                                        (dp,))[1])
        self.state_tangents = spread(lambda p, state, data, e: jax.jvp(
            lambda st: pieces(p, st, data), (state,), (jnp.broadcast_to(e, state.shape),))[1])

    def _seeded(self, compiled, p, state, n: int) -> list[np.ndarray]:
        """``compiled`` (:meth:`_jit`'s ``spread``) along the n unit seeds (zero seeds pad them to a multiple of
        the devices): (n, L, nf, 3, W), (n, nf, 3, W) twice."""
        seeds = np.zeros((-(-n // self.devices) * self.devices, n))
        seeds[np.arange(n), np.arange(n)] = 1.0
        return [np.asarray(a)[:n] for a in compiled(jnp.asarray(p), jnp.asarray(state), self.data,
                                                    jnp.asarray(seeds))]

    def parameter_tangents(self, p, state):
        """Every parameter's tangent: (P, L, nf, 3, W), (P, nf, 3, W) twice."""
        return self._seeded(self.param_tangents, p, state, len(p))

    # ----------------------------------------------------------------- least squares
    def split(self, z):
        return z[:self.n_params], z[self.n_params:].reshape(self.windows, -1)

    def residual(self, z) -> np.ndarray:
        p, state = self.split(z)
        xs, xe, ve = (np.asarray(a) for a in self.pieces(jnp.asarray(p), jnp.asarray(state), self.data))
        return self._assemble(xs, xe, ve, p, state)

    def _assemble(self, xs, xe, ve, p, state) -> np.ndarray:
        nf, w = self.nf, self.windows
        obs = (xs - self.target) * self.obs_mask[:, None, None, :]                 # (L, nf, 3, W)
        first = state[0, :3 * nf] - self.target_start()
        x_next = np.moveaxis(state[1:, :3 * nf].reshape(w - 1, nf, 3), 0, -1)
        v_next = np.moveaxis(state[1:, 3 * nf:].reshape(w - 1, nf, 3), 0, -1)
        cx = self.cw * (xe[..., :-1] - x_next)
        cv = self.cw * self.tau * (ve[..., :-1] - v_next)
        p = np.asarray(p)
        return np.concatenate([np.moveaxis(obs, -1, 0).ravel(), first,
                               np.moveaxis(np.stack([cx, cv]), -1, 0).ravel(),
                               self.prior_weight * (p[self.prior_rows] - 1.0)])

    def choose_starts(self, p) -> np.ndarray:
        """Each window's start state (W, 6 nf) for the parameters ``p``: of the poses' central differences and
        their local quadratics (``SMOOTHING``), the one whose run follows the window's poses best."""
        candidates = [self.state0] + self.smoothed
        misses = []
        for state in candidates:
            xs = np.asarray(self.pieces(jnp.asarray(p), jnp.asarray(state), self.data)[0])
            misses.append(np.sum(((xs - self.target) * self.obs_mask[:, None, None, :]) ** 2, axis=(0, 1, 2)))
        best = np.argmin(misses, axis=0)
        return np.stack([candidates[b][w] for w, b in enumerate(best)])

    def target_start(self) -> np.ndarray:
        return _fill(self.observed)[0][self.free].ravel()

    def n_observed(self) -> int:
        return int(self.obs_mask.sum()) * 3 * self.nf + 3 * self.nf

    def jacobian(self, z, states: bool = True) -> sp.csr_matrix:
        """The sparse Jacobian at ``z``: the parameters' columns (:meth:`parameter_jacobian`), then the start
        states' (:meth:`state_columns`); ``states`` False: those last computed reused (the chord: module
        docstring)."""
        p, state = self.split(z)
        if states or self._chord is None:
            self._chord, self._gram = self.state_columns(p, state), None
            self.state_jacobians += 1
        self.param_columns = self.parameter_jacobian(p, state)
        return sp.hstack([sp.csr_matrix(self.param_columns), self._chord], format="csr")

    def normal(self, w: np.ndarray) -> sp.csc_matrix:
        """``J^T diag(w) J`` of the Jacobian last computed (:meth:`jacobian`); the start states' block is kept
        while their columns and the weights ``w`` stay the same (chord steps: only the parameters' columns
        change)."""
        if self._gram is None or not np.array_equal(self._gram[0], w):
            self._gram = w.copy(), (self._chord.T @ sp.diags(w) @ self._chord).tocsc()
        weighted = w[:, None] * self.param_columns
        cross = np.asarray(self._chord.T @ weighted)                                 # (W 6 nf, P)
        return sp.bmat([[self.param_columns.T @ weighted, cross.T], [cross, self._gram[1]]], format="csc")

    def state_columns(self, p, state) -> sp.csr_matrix:
        """The Jacobian's start-state columns (the rows of :meth:`residual`, W 6 nf columns), sparse: a window's
        observation and continuity rows in its own start state's columns, a continuity row's weight (negative)
        in the next window's, the first window's start positions' identity."""
        nf, W, L = self.nf, self.windows, self.window
        s = 6 * nf
        dxs, dxe, dve = self._seeded(self.state_tangents, p, state, s)
        per, k = L * nf * 3, np.arange(s)
        # observation rows of window w: (s, L, nf, 3, W) -> (W, per, s)
        block = (dxs * self.obs_mask[None, :, None, None, :]).reshape(s, per, W).transpose(2, 1, 0)
        r = np.arange(W)[:, None, None] * per + np.arange(per)[None, :, None]
        c = np.arange(W)[:, None, None] * s + k[None, None, :]
        base = W * per   # then the first window's start positions
        rows = [np.broadcast_to(r, block.shape).ravel(), base + np.arange(3 * nf)]
        cols = [np.broadcast_to(c, block.shape).ravel(), np.arange(3 * nf)]
        vals = [block.ravel(), np.ones(3 * nf)]
        base += 3 * nf
        if W > 1:   # continuity rows of windows w, w + 1: (W - 1, 2, nf, 3) each
            end = np.stack([self.cw * dxe, self.cw * self.tau * dve], axis=1)[..., :-1]   # (s, 2, nf, 3, W-1)
            block = end.reshape(s, s, W - 1).transpose(2, 1, 0)                          # (W-1, s, s)
            r = base + np.arange(W - 1)[:, None, None] * s + np.arange(s)[None, :, None]
            c = np.arange(W - 1)[:, None, None] * s + k[None, None, :]
            weight = np.concatenate([np.full(3 * nf, self.cw), np.full(3 * nf, self.cw * self.tau)])
            following = np.arange(W - 1)[:, None] * s + k[None, :]
            rows += [np.broadcast_to(r, block.shape).ravel(), (base + following).ravel()]
            cols += [np.broadcast_to(c, block.shape).ravel(), (s + following).ravel()]
            vals += [block.ravel(), -np.broadcast_to(weight, following.shape).ravel()]
        n_rows = base + (W - 1) * s + len(self.prior_rows)
        return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                             shape=(n_rows, W * s))

    def parameter_jacobian(self, p, state) -> np.ndarray:
        """The residual's Jacobian in the parameters alone, the start states ``state`` (W, 6 nf) held: (rows, P),
        dense, the rows of :meth:`residual`."""
        dxs, dxe, dve = self.parameter_tangents(p, state)
        n = self.n_params
        obs = dxs * self.obs_mask[None, :, None, None, :]                                    # (P, L, nf, 3, W)
        ends = np.stack([self.cw * dxe, self.cw * self.tau * dve], axis=1)[..., :-1]         # (P, 2, nf, 3, W-1)
        prior = np.zeros((len(self.prior_rows), n))
        prior[np.arange(len(self.prior_rows)), self.prior_rows] = self.prior_weight
        return np.concatenate([np.moveaxis(obs, -1, 1).reshape(n, -1).T, np.zeros((3 * self.nf, n)),
                               np.moveaxis(ends, -1, 1).reshape(n, -1).T, prior])

    def bounds(self):
        """Physical: stiffness, mass and reel speed > 0, damping and friction >= 0, restitution in [0, 1]."""
        lower = {"stiffness": 1e-9, "mass": 1e-9, "reel_speed": 1e-9}
        lo = np.array([lower.get(u.kind, 0.0) for u in self.unknowns])
        hi = np.array([1.0 / b if u.kind == "restitution" and f else (1.0 if u.kind == "restitution" else np.inf)
                       for u, b, f in zip(self.unknowns, self.base, self.factor)])
        n = self.windows * 6 * self.nf
        return np.concatenate([lo, np.full(n, -np.inf)]), np.concatenate([hi, np.full(n, np.inf)])

    def positions(self, z) -> np.ndarray:
        """The windows' simulated positions on the grid (G, N, 3): each window's start, then its steps."""
        p, state = self.split(z)
        xs = np.asarray(self.simulated(jnp.asarray(p), jnp.asarray(state), self.data))   # (L, N, 3, W)
        x0, _ = self._states(jnp.asarray(state))
        out = np.concatenate([np.moveaxis(np.asarray(x0)[..., :1], -1, 0),
                              np.moveaxis(xs, -1, 0).reshape(-1, *xs.shape[1:3])])
        return out[:len(self.observed)]


def _fill(grid: np.ndarray) -> np.ndarray:
    """``grid`` (G, ...) with each missing (NaN) row taken from the nearest observed one."""
    have = np.flatnonzero(~np.isnan(grid[:, 0, 0]))
    nearest = have[np.clip(np.searchsorted(have, np.arange(len(grid))), 0, len(have) - 1)]
    return grid[nearest]


def _local_quadratic(grid: np.ndarray, starts: np.ndarray, k: int, tau: float) -> tuple[np.ndarray, np.ndarray]:
    """Positions and velocities (len(starts), N, 3) at the grid points ``starts``: the least-squares quadratic in
    time through the observed rows of ``grid`` (G, N, 3; NaN: none) within ``k`` points of each (fewer than three:
    the nearest observed row, at rest)."""
    x, v = np.zeros((len(starts), *grid.shape[1:])), np.zeros((len(starts), *grid.shape[1:]))
    seen = ~np.isnan(grid[:, 0, 0])
    for i, c in enumerate(starts):
        near = np.flatnonzero(seen[max(0, c - k):c + k + 1]) + max(0, c - k)
        if len(near) < 3:
            x[i] = _fill_at(_fill(grid), np.array([c]))[0]
            continue
        t = (near - c) * tau
        coef = np.linalg.lstsq(np.stack([np.ones_like(t), t, t * t], axis=1), grid[near].reshape(len(near), -1),
                               rcond=None)[0]
        x[i], v[i] = coef[0].reshape(grid.shape[1:]), coef[1].reshape(grid.shape[1:])
    return x, v


def _fill_at(filled: np.ndarray, idx: np.ndarray) -> np.ndarray:
    return filled[np.clip(idx, 0, len(filled) - 1)]


def _parameter_sigma(normal, n_params: int, noise: float) -> np.ndarray:
    """Each parameter's standard deviation: the noise times the square root of its diagonal entry of the inverse
    of the normal matrix ``normal`` (``J^T J``, sparse), the window states eliminated by their Schur complement."""
    normal = sp.csc_matrix(normal)
    aa = normal[:n_params, :n_params].toarray()
    bt = normal[n_params:, :n_params].toarray()
    d = normal[n_params:, n_params:].tocsc()
    try:
        lu = splu(d + sp.identity(d.shape[0], format="csc") * 1e-14 * max(d.diagonal().max(), 1.0))
        schur = aa - bt.T @ lu.solve(bt)
        cov = np.linalg.pinv(schur)
    except (RuntimeError, np.linalg.LinAlgError):
        return np.full(n_params, np.nan)
    return noise * np.sqrt(np.maximum(np.diag(cov), 0.0))


def _levenberg_marquardt(problem: _Problem, z: np.ndarray, lo: np.ndarray, hi: np.ndarray, *, loss: str,
                         loss_scale: float, tolerance: float, max_evaluations: int, chord: bool, dof: int,
                         verbose: int):
    """Minimise ``0.5 loss_scale^2 sum(rho((r / loss_scale)^2))`` (``LOSSES``) over ``z`` within the bounds by
    Levenberg-Marquardt: each step solves the sparse normal equations exactly (``J^T W J`` with ``rho'`` as the
    weights ``W``; Marquardt's scaling by its diagonal, floored at 1 % of its median, so that a coordinate the
    poses do not see, such as the first window's start velocity of a node resting on the ground, is damped too),
    Gauss-Newton's step near the optimum. With ``chord`` the start states' tangents are reused while the steps
    do what the linear model predicts (a ratio of the actual to the predicted decrease of at least ``REFRESH``),
    and refreshed after a poorer step or a second failed one. It stops once a step that did at least ``REFRESH``
    of what its model predicted and decreased the cost by less than ``SETTLED`` of itself (the residual is the
    noise, no misfit) moved every parameter by less than ``SIGMA_STEP`` of its standard deviation (the noise from
    the cost over ``dof`` degrees of freedom, and the normal equations the step came from: what is left is below
    what the poses can tell), or, on fresh tangents, once the cost decreases by less than
    ``tolerance`` of itself or every parameter moves by less than ``PARAMETER_TOLERANCE`` (lambda < 1), or after
    ``FAILED`` failed steps in a row (the cost's floor: its round-off and the ground's sweep tolerance). Returns
    ``z``, the runs of the model, the message and the Jacobian at ``z`` (or one step before it; after the
    standard-deviation rule with ``chord``, the start states' columns from their last refresh)."""
    cpu = time.process_time()
    rho, weight = LOSSES[loss]
    cost = lambda r: 0.5 * loss_scale ** 2 * float(np.sum(rho((r / loss_scale) ** 2)))   # noqa: E731
    n = problem.n_params
    r = problem.residual(z)
    f, evaluations = cost(r), 1
    jac, fresh, normal = problem.jacobian(z), True, None
    lam, nu, failed, message, small = 1e-3, 2.0, 0, "the evaluation limit reached", False
    while evaluations < max_evaluations:
        if normal is None:   # J^T W J and the gradient, after a new Jacobian or residual
            w = weight((r / loss_scale) ** 2)
            a = problem.normal(w)
            normal = a, jac.T @ (w * r), np.maximum(a.diagonal(), 1e-2 * np.median(a.diagonal()))
        a, g, d = normal
        try:
            step = -splu((a + lam * sp.diags(d)).tocsc()).solve(g)
        except RuntimeError:   # singular: more damping
            lam, nu = lam * nu, nu * 2.0
            continue
        new = np.clip(z + step, lo, hi)
        step = new - z
        predicted = -(g @ step + 0.5 * step @ (a @ step))
        r_new = problem.residual(new)
        f_new, evaluations = cost(r_new), evaluations + 1
        ratio = (f - f_new) / predicted if predicted > 0 else -1.0
        # the parameters' steps in standard deviations (the noise from the cost), after a step the model predicted
        sigma = _parameter_sigma(a, n, np.sqrt(2.0 * f / dof)) if ratio >= REFRESH else np.full(n, np.nan)
        if verbose:
            print(f"fit: run {evaluations:3d}  cpu {time.process_time() - cpu:6.1f} s  state Jacobians "
                  f"{problem.state_jacobians:2d}  cost {f:.6e} -> {f_new:.6e}  ratio {ratio:+.3f}  lambda {lam:.1e}"
                  f"  step {np.linalg.norm(step):.2e}  parameters {new[:n]}  steps / sigma {np.abs(step[:n]) / sigma}"
                  f"{'' if fresh else '  (chord)'}", flush=True)
        if ratio > 1e-4:
            if f - f_new < SETTLED * f and np.all(np.abs(step[:n]) < SIGMA_STEP * sigma):
                z, small = new, True
                message = f"converged: every parameter's step below {SIGMA_STEP} of its standard deviation"
                break
            converged = f - f_new <= tolerance * f or (lam < 1.0 and np.all(
                np.abs(step[:n]) <= PARAMETER_TOLERANCE * (PARAMETER_TOLERANCE + np.abs(new[:n]))))
            z, r, f, failed, normal = new, r_new, f_new, 0, None
            if converged and fresh:   # the Jacobian one step below the tolerances away serves for sigma
                message = "converged: the cost's decrease or the parameters' step below the tolerance"
                break
            lam, nu = lam * max(1.0 / 3.0, 1.0 - (2.0 * ratio - 1.0) ** 3), 2.0
            refresh = not chord or ratio < REFRESH or converged
            jac, fresh = problem.jacobian(z, states=refresh), refresh
            continue
        failed += 1
        if not fresh and failed >= 2:   # a stale model: refresh it before damping more
            jac, fresh, normal, failed = problem.jacobian(z), True, None, 0
        elif fresh and failed >= FAILED:
            message = f"{FAILED} failed steps in a row: the cost's floor"
            break
        else:
            lam, nu = lam * nu, nu * 2.0
    if not fresh and not small:   # after the standard-deviation rule, sigma from the Jacobian at hand
        jac = problem.jacobian(z)
    return z, evaluations, message, jac


def fit_observed(scene: Scene, obs: Observed, unknowns: list[Unknown], *, window: int | None = None,
                 loss: str = "linear", loss_scale: float = 3e-3, continuity: float = CONTINUITY,
                 prior: float = PRIOR, chord: bool = False, tolerance: float = 1e-6, max_evaluations: int = 100,
                 verbose: int = 0) -> FitResult:
    """Fit ``unknowns`` of ``scene`` (their start values) to ``obs`` by multiple shooting (module docstring);
    ``window``: grid intervals per window (None: :func:`choose_window`); ``prior``: the prior's relative standard
    deviation about the scene's values (0: none); ``chord``: reuse the start states' Jacobian (module
    docstring); ``tolerance``: the relative decrease of the cost that ends the fit; ``verbose``: every step's
    progress printed (2: least_squares' of the first stage too)."""
    if not prior >= 0:
        raise ValueError(f"prior must be >= 0 (a relative standard deviation; 0: none), got {prior}")
    if loss not in LOSSES:
        raise ValueError(f"loss must be one of {', '.join(LOSSES)}, got {loss!r}")
    steps = np.asarray(obs.steps, dtype=np.int64)
    if steps.ndim != 1 or len(steps) < 3 or np.any(steps < 0) or np.any(np.diff(steps) <= 0):
        raise ValueError("the observed steps must be at least 3, >= 0 and strictly increasing")
    if obs.positions.shape != (len(steps), len(scene.nodes), 3):
        raise ValueError(f"positions: expected shape {(len(steps), len(scene.nodes), 3)}, got "
                         f"{obs.positions.shape}")
    if not np.all(np.isfinite(obs.positions)):
        k = int(np.flatnonzero(~np.all(np.isfinite(obs.positions), axis=(1, 2)))[0])
        raise ValueError(f"pose {k} (step {int(steps[k])}) is not finite (NaN or inf)")
    taut, switches = observed_slack(scene, obs)
    for u in unknowns:
        if u.kind in ("stiffness", "damping") and not np.any(taut[list(u.cables)]):
            names = ", ".join(scene.cable_names[i] for i in u.cables)
            what = "cable" if len(u.cables) == 1 else "cables"
            raise ValueError(f"--params: {u.name!r}: the log cannot see it: {what} {names} slack at every pose")
    every = int(np.gcd.reduce(np.diff(steps)))
    if window is None:
        window = choose_window(obs, switches, every)
    if window < 1:
        raise ValueError(f"window must be at least 1 grid interval, got {window}")
    problem = _Problem(scene, obs, unknowns, window, continuity, prior, loss_scale)
    lo, hi = problem.bounds()
    p0 = np.clip(problem.p0, lo[:problem.n_params], hi[:problem.n_params])
    starts = problem.choose_starts(p0)
    z0 = np.concatenate([p0, starts.ravel()])
    r0 = problem.residual(z0)
    n_obs = problem.n_observed()
    rms = lambda r: float(np.sqrt(np.sum(r[:n_obs] ** 2) / n_obs))   # noqa: E731
    # first the parameters alone, the windows held at their starts from the poses: a few cheap runs that bring
    # them close, so that the start states' tangents (6 nf per window) are computed near the optimum
    n = problem.n_params
    held = starts.ravel()
    first = least_squares(lambda p: problem.residual(np.concatenate([p, held])), z0[:n],
                          jac=lambda p: problem.parameter_jacobian(p, starts), bounds=(lo[:n], hi[:n]),
                          method="trf", x_scale="jac", loss=loss, f_scale=loss_scale, xtol=HELD_TOLERANCE,
                          ftol=HELD_TOLERANCE, gtol=HELD_TOLERANCE, max_nfev=max_evaluations, verbose=verbose)
    choices = 1 + len(problem.smoothed)   # the runs of each choice of the start states
    # the continuity rows act as constraints: each takes one unknown off (the prior rows do not)
    dof = max(1, len(r0) - len(z0) - len(problem.prior_rows))
    z, evaluations, message, jac = _levenberg_marquardt(
        problem, np.concatenate([first.x, problem.choose_starts(first.x).ravel()]), lo, hi, loss=loss,
        loss_scale=loss_scale, tolerance=tolerance, chord=chord, dof=dof, verbose=verbose,
        max_evaluations=max(1, max_evaluations - first.nfev - 2 * choices))
    evaluations += first.nfev + 2 * choices
    r = problem.residual(z)
    noise = float(np.sqrt(np.sum(r[:n_obs] ** 2) / dof))
    scale = np.array([b if f else 1.0 for b, f in zip(problem.base, problem.factor)])
    sigma = _parameter_sigma(jac.T @ jac, problem.n_params, noise) * scale
    p = z[:n]
    fitted = problem.values(p)
    reel = problem.reel
    for u, value in zip(unknowns, fitted):
        if u.kind == "reel_speed":
            reel = float(value)
    return FitResult(unknowns, problem.values(problem.p0), fitted, sigma, rms(r0), rms(r), noise,
                     _fitted_scene(scene, unknowns, problem, p), problem.window, problem.windows, problem.every,
                     obs.dt,
                     problem.grid_steps, problem.observed, problem.positions(z0), problem.positions(z),
                     evaluations, message, reel, switches, problem.state_jacobians)


def _fitted_scene(scene: Scene, unknowns: list[Unknown], problem: _Problem, p) -> Scene:
    """``scene`` with the fitted values."""
    d = scene.to_dict()
    m = problem.model_of(jnp.asarray(p))
    ns = problem.ns
    masses = []   # (name, factor) of the fitted masses, applied last
    for u, value in zip(unknowns, p):
        if u.kind == "stiffness":
            for i in u.cables:
                d["cables"][i]["stiffness"] = float(m.stiffness[ns + i])
        elif u.kind == "damping":
            for i in u.cables:
                d["cables"][i]["damping"] = float(m.damping[i])
        elif u.kind == "mass":
            masses.append((u.name.partition(":")[2], float(value)))
        elif u.kind in ("friction", "restitution"):
            d["ground"][u.kind] = float(getattr(m.ground, u.kind))
    fitted = Scene.from_dict(d, source=f"{scene.source} (fitted)")
    for name, factor in masses:
        fitted = _scaled(fitted, name, factor)
    return fitted
