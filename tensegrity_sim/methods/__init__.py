"""Stepping methods, picked by name from :data:`METHODS`; ``"auto"`` is :func:`choose_method`."""
from __future__ import annotations


import numpy as np

from ..checks import describe
from ..system import System
from .base import MethodStep, State, StepError, StepMethod
from .elastic.method import ElasticMethod
from .inextensible.method import InextensibleMethod
from .massive.method import MassiveMethod
from .qp.solvers import SOLVERS

__all__ = ["METHODS", "SOLVERS", "BACKENDS", "choose_method", "make_method", "check_backend", "State", "MethodStep",
           "StepMethod", "StepError"]

METHODS: dict[str, type[StepMethod]] = {
    ElasticMethod.name: ElasticMethod,
    InextensibleMethod.name: InextensibleMethod,
    MassiveMethod.name: MassiveMethod,
}


# Where the elastic method's step runs: the numba kernels (with their numpy reference) or JAX (methods/jax/, the
# optional ``jax`` extra: imported only when asked for)
BACKENDS = ("numba", "jax")


def check_backend(backend, method: str, dtype) -> None:
    """A ``backend`` (and ``dtype``, the JAX backend's precision) that can step ``method``, or a ValueError."""
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {list(BACKENDS)}, got {describe(backend)}")
    if backend == "jax" and method != "elastic":
        raise ValueError(f"backend 'jax' steps the elastic method only; method {method!r} runs on backend 'numba'")
    if dtype is not None and backend != "jax":
        raise ValueError(f"dtype={describe(dtype)} is an option of backend 'jax' (its precision); backend "
                         f"{backend!r} runs in float64")


# The auto rule's two thresholds (docs/methods.md, "auto"):
RESOLVED = 0.5      # omega * dt at or below which the step resolves a vibration (>= 12.6 steps per period)
SEPARATION = 10.0   # a cable vibration this many times faster than the scene's other time scales is instantaneous
# a snap restitution m*/(m* + m_c) within this of 0 or 1 is taken as its limit (plastic: inextensible; elastic:
# the massless cables of methods 1 and 2)
RESTITUTION_TOL = 0.02


def scene_frequency(system: System) -> tuple[float, str]:
    """The fastest time scale of the scene apart from the cables' axial vibration, as an angular
    frequency (rad/s), and what sets it: the elastic struts' axial vibration, a pendulum swing of the
    shortest cable under gravity, or the initial motion (relative speed / length of a member)."""
    scene, x = system.scene, system.scene.positions
    g = float(np.linalg.norm(scene.gravity))
    candidates = [(system.max_frequency(x, include_cables=False), "the elastic struts' axial vibration")]
    if g > 0 and system.n_cables:
        candidates.append((float(np.sqrt(g / np.min(scene.cable_rest_lengths))), "a pendulum swing under gravity"))
    if system.n_members:
        _, length, _ = system.geometry(x)
        v = scene.velocities
        rel = np.linalg.norm(v[system.ends[:, 1]] - v[system.ends[:, 0]], axis=1)
        candidates.append((float(np.max(rel / length)), "the initial motion"))
    return max(candidates, key=lambda c: c[0])


def restitutions(system: System) -> np.ndarray:
    """Each cable's snap restitution ``m*/(m* + m_c)`` (n_cables,) at the scene's configuration, with ``m* =
    1/(b_c^T M^-1 b_c)`` the structure's effective mass along the cable (physics §4b): 1 for a massless cable,
    0 for one whose ends are both fixed (or whose plate is infinitely heavier)."""
    _, _, n = system.geometry(system.scene.positions, system.cable_ends)
    k = np.arange(system.n_cables)
    b = np.zeros((system.n_nodes, 3, system.n_cables))   # each cable's b_c, batch last
    b[system.cable_ends[:, 0], :, k] -= n
    b[system.cable_ends[:, 1], :, k] += n
    inv = np.einsum("njk,njk->k", b, system.mass.solve(b))   # b^T M^-1 b
    plates = system.scene.cable_masses
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(plates > 0, 1.0 / (1.0 + plates * inv), 1.0)


def choose_method(system: System, dt: float) -> tuple[str, str]:
    """The method ``"auto"`` resolves to for this scene and step, and the reason, in one sentence.

    A scene whose cables carry mass (physics §4b) gets the massive method where some cable's snap restitution
    ``m*/(m* + m_c)`` (:func:`restitutions`) lies more than ``RESTITUTION_TOL`` from 0 and from 1, and the
    method takes the scene (rigid struts and contacts, but no cable attached along a strut yet); otherwise the
    rules below pick the cheaper limit (restitution near 1: massless cables; near 0: plastic snaps, which the
    inextensible method makes). With ``omega_c`` the highest axial frequency of the cables (all taut, struts
    ignored) and ``omega_s`` the scene's fastest other time scale (:func:`scene_frequency`):

    1. a cable without a stiffness can only be inextensible; a cable attached along a strut only elastic
       (the inextensible method's rows join two nodes);
    2. if the elastic method would be unstable (``omega_max dt >= 2``), inextensible;
    3. if the step resolves the cables' vibration (``omega_c dt <= RESOLVED``), elastic: it represents
       the scene exactly and needs no QP;
    4. otherwise the cables' vibration is under-resolved: if it is at least ``SEPARATION`` times faster
       than everything else, the cables act as inextensible on every time scale of interest, so
       inextensible; if not, their elasticity is part of the dynamics, so elastic.
    """
    if not system.n_cables:
        return "elastic", "elastic: the scene has no cables"
    massive = _massive_choice(system)
    if massive is not None:
        return "massive", massive
    missing = [c.name for c in system.scene.cables if c.stiffness is None]
    if missing:
        return "inextensible", f"inextensible: cables without a stiffness ({', '.join(missing)})"
    if len(system.attached):
        names = ", ".join(system.scene.cable_names[c] for c in system.attached)
        return "elastic", f"elastic: cables attached along a strut ({names}) are the elastic method's only"
    x = system.scene.positions
    omega_max = system.max_frequency(x, include_cables=True)
    if omega_max * dt >= 2.0:
        return "inextensible", (f"inextensible: the elastic method would be unstable "
                                f"(omega_max*dt = {omega_max * dt:.3g} >= 2)")
    omega_c = system.max_frequency(x, include_cables=True, include_struts=False)
    if omega_c * dt <= RESOLVED:
        return "elastic", (f"elastic: dt resolves the cables' axial vibration "
                           f"(omega_cable*dt = {omega_c * dt:.3g} <= {RESOLVED:g})")
    omega_s, what = scene_frequency(system)
    if omega_c >= SEPARATION * omega_s:
        return "inextensible", (f"inextensible: the cables' axial vibration is under-resolved "
                                f"(omega_cable*dt = {omega_c * dt:.3g} > {RESOLVED:g}) and "
                                f"{omega_c / omega_s if omega_s else float('inf'):.3g} times faster than "
                                f"{what} ({omega_s:.3g} rad/s)")
    return "elastic", (f"elastic: the cables' axial vibration ({omega_c:.3g} rad/s) is only "
                       f"{omega_c / omega_s:.3g} times faster than {what}: their elasticity matters")


def _massive_choice(system: System) -> str | None:
    """The reason to pick the massive method for a scene with cable masses, or None."""
    scene = system.scene
    if not np.any(scene.cable_masses > 0) or any(c.stiffness is None for c in scene.cables):
        return None
    if len(system.attached):
        return None
    e = restitutions(system)
    between = (e > RESTITUTION_TOL) & (e < 1.0 - RESTITUTION_TOL)
    if not between.any():
        return None
    i = int(np.argmax(np.minimum(e, 1.0 - e) * between))
    return (f"massive: the cables carry mass and a snap's restitution m*/(m*+m_c) is away from 0 and 1 "
            f"({scene.cables[i].name}: {e[i]:.3g}; limits within {RESTITUTION_TOL:g} of them are left to "
            f"methods 1 and 2)")


# what has each option, for the error when a named method lacks it
_OPTION_OF = {"solver": "a method with a QP", "order": "the elastic and massive methods",
              "locate_switches": "the elastic and massive methods",
              "reel_speed": "the inextensible method", "reel_force": "the inextensible method"}


def make_method(system: System, method: str, dt: float, *, backend: str = "numba", dtype: str | None = None,
                **options) -> tuple[StepMethod, str]:
    """Instantiate ``method`` (a name of :data:`METHODS` or ``"auto"``); returns it and the reason.

    ``options`` are the methods' keyword options (``solver`` of a method that solves QPs, ``order`` and
    ``locate_switches`` of the elastic and massive methods, ``reel_speed`` and ``reel_force`` of the inextensible one); None means the
    method's default. An option the chosen method does not have is an error when the method was named,
    and ignored when ``"auto"`` chose it. ``backend="jax"`` steps the elastic method in JAX
    (:class:`~tensegrity_sim.methods.jax.engine.ElasticMethodJax`, in ``dtype`` "float64" or "float32")."""
    solver = options.get("solver")
    if solver is not None and (not isinstance(solver, str) or solver not in SOLVERS):
        raise ValueError(f"solver must be one of {sorted(SOLVERS)}, got {describe(solver)}")
    if not isinstance(method, str):
        raise ValueError(f"method must be one of {sorted(METHODS) + ['auto']}, got {describe(method)}")
    if method == "auto":
        method, reason = choose_method(system, dt)
    elif method in METHODS:
        reason = f"{method}: requested"
    else:
        raise ValueError(f"method must be one of {sorted(METHODS) + ['auto']}, got {describe(method)}")
    check_backend(backend, method, dtype)
    cls = METHODS[method]
    if backend == "jax":
        from .jax.engine import ElasticMethodJax   # imports JAX: only here

        cls = ElasticMethodJax
    given = {name: value for name, value in options.items() if value is not None}
    if backend == "jax" and given:
        name = next(iter(given))
        raise ValueError(f"{name}={describe(given[name])}: backend 'jax' steps plain velocity Verlet (order 2, "
                         f"switches not located) and has no options")
    for name in given:
        if name not in cls.options and reason.endswith("requested"):
            raise ValueError(f"{name}={describe(given[name])} is an option of {_OPTION_OF[name]}; "
                             f"method {method!r} has none")
    extra = {} if backend == "numba" else {"dtype": dtype or "float64"}
    return cls(system, dt, **{name: value for name, value in given.items() if name in cls.options}, **extra), reason
