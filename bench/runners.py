"""Simulator configurations run through the same sweep: tensegrity_sim's methods and MuJoCo's integrators.

A runner makes a :class:`Session` for a case and a step; a session can ``advance`` (the timed part:
stepping only, nothing measured) and ``measure`` (the same run again with the bookkeeping: final state,
each cable's impulse, energy deviation). Adding a method, a QP backend or a contact setting to the
benchmarks is adding a runner to :func:`tensegrity_runners`.
"""
from __future__ import annotations

import importlib.util
from dataclasses import dataclass, field

import numpy as np

import tensegrity_sim as ts
from tensegrity_sim.scene import CONTACT_KINDS

from .cases import Case
from .reference import Final

__all__ = ["Measured", "TensegrityRunner", "MujocoRunner", "tensegrity_runners", "default_runners",
           "scale_runners", "mujoco_runners", "mujoco_available"]

WARMUP_STEPS = 300


@dataclass(frozen=True)
class Measured:
    """What one measured run gives: the final state (positions, velocities, impulses over the run) and
    the largest deviation of the total energy from its initial value over the samples, J (NaN for a
    model that does not conserve energy)."""

    final: Final
    energy_error: float


@dataclass(frozen=True)
class TensegrityRunner:
    """tensegrity_sim with ``method`` and extra ``Simulator`` keyword ``options`` (a QP backend, contact
    detection...); ``variant`` names the configuration in tables and plots."""

    method: str
    variant: str
    options: dict = field(default_factory=dict)
    simulator: str = "tensegrity_sim"

    @property
    def model(self) -> str:
        return self.method

    @property
    def label(self) -> str:
        return f"{self.simulator} {self.variant}"

    def simulator_for(self, scene: ts.Scene, dt: float) -> ts.Simulator:
        return ts.Simulator(scene, method=self.method, dt=dt, **self.options)

    def session(self, case: Case, dt: float) -> "TensegritySession":
        return TensegritySession(self.simulator_for(case.scene, dt), int(round(case.duration / dt)),
                                 energy=self.model == "elastic")


class TensegritySession:
    def __init__(self, sim: ts.Simulator, steps: int, energy: bool):
        self.sim, self.steps, self._energy = sim, steps, energy

    def warmup(self) -> None:
        for _ in range(min(self.steps, WARMUP_STEPS)):
            self.sim.step()

    def reset(self) -> None:
        self.sim.reset()

    def advance(self) -> None:
        """The run as a user makes it, keeping the last step only, as MuJoCo's C loop does (its
        compiled loop where the method has one)."""
        self.sim.run(steps=self.steps, every=max(self.steps, 1))

    @property
    def unstable(self) -> bool:
        return not np.all(np.isfinite(self.sim.positions))

    def measure(self, samples: int = 100) -> Measured:
        sim = self.sim
        sim.reset()
        e0 = sim.energy()["total"]
        every = max(1, self.steps // samples)
        impulses = np.zeros(len(sim.scene.cables))
        de = 0.0
        for start in range(0, self.steps, every):   # run(): the compiled loop where the method has one
            n = min(every, self.steps - start)
            impulses += sim.run(steps=n, every=n).impulses[0]
            if self._energy and n == every:
                de = max(de, abs(sim.energy()["total"] - e0))
        de = max(de, abs(sim.energy()["total"] - e0)) if self._energy else float("nan")
        return Measured(Final(sim.positions, sim.velocities, impulses), de)


@dataclass(frozen=True)
class MujocoRunner:
    """MuJoCo with ``integrator`` on the same structure (see :mod:`bench.mujoco_peer`);
    ``limit_dampratio`` for the inextensible cables' soft limits."""

    integrator: str
    model: str = "elastic"
    limit_dampratio: float = 1.0
    simulator: str = "MuJoCo"

    @property
    def variant(self) -> str:
        if self.model == "elastic":
            return self.integrator
        return f"{self.integrator} limit zeta={self.limit_dampratio:g}"

    @property
    def label(self) -> str:
        return f"{self.simulator} {self.variant}"

    def session(self, case: Case, dt: float) -> "MujocoSession":
        from .mujoco_peer import MujocoPeer
        peer = MujocoPeer(case.scene, model=self.model, dt=dt, integrator=self.integrator,
                          limit_dampratio=self.limit_dampratio)
        return MujocoSession(peer, int(round(case.duration / dt)), energy=self.model == "elastic")


class MujocoSession:
    def __init__(self, peer, steps: int, energy: bool):
        self.peer, self.steps, self._energy = peer, steps, energy

    def warmup(self) -> None:
        self.peer.advance(min(self.steps, WARMUP_STEPS))

    def reset(self) -> None:
        self.peer.reset()

    def advance(self) -> None:
        self.peer.advance(self.steps)

    @property
    def unstable(self) -> bool:
        return self.peer.unstable or not np.all(np.isfinite(self.peer.positions()))

    def measure(self, samples: int = 100) -> Measured:
        final, de = self.peer.run_measured(self.steps, samples)
        return Measured(final, de if self._energy else float("nan"))


def mujoco_available() -> bool:
    return importlib.util.find_spec("mujoco") is not None


NO_CONTACTS = {"contacts": ()}
ALL_CONTACTS = {"contacts": CONTACT_KINDS}


def tensegrity_runners() -> list[TensegrityRunner]:
    """The tensegrity_sim configurations of the work-precision sweep: every method, the elastic one as
    plain Verlet (the default, compiled), with located switches and at order 4, the inextensible one with
    every QP backend, the massive one with its snaps located (the default) and not, all without contact
    detection (MuJoCo's contacts are off too)."""
    runners = [TensegrityRunner("elastic", "elastic", NO_CONTACTS),
               TensegrityRunner("elastic", "elastic located", {**NO_CONTACTS, "locate_switches": True}),
               TensegrityRunner("elastic", "elastic order 4", {**NO_CONTACTS, "order": 4})]
    runners += [TensegrityRunner("inextensible", f"inextensible {name}", {**NO_CONTACTS, "solver": name})
                for name in ts.SOLVERS]
    runners += [TensegrityRunner("massive", "massive", NO_CONTACTS),
                TensegrityRunner("massive", "massive not located", {**NO_CONTACTS, "locate_switches": False})]
    return runners


def default_runners(contacts: bool = False) -> list[TensegrityRunner]:
    """Each method with its default settings (the inextensible one with its default QP backend),
    contact detection off, or on for every member kind with ``contacts``."""
    if contacts:
        return [TensegrityRunner(method, f"{method} +contacts", ALL_CONTACTS) for method in ("elastic", "inextensible")]
    return [TensegrityRunner(method, method, NO_CONTACTS) for method in ("elastic", "inextensible")]


def scale_runners() -> list[TensegrityRunner]:
    """The configurations of the scale and real-time studies: each method with its defaults, with
    contact detection off and on."""
    return default_runners() + default_runners(contacts=True)


def mujoco_runners() -> list[MujocoRunner]:
    """MuJoCo's Euler, implicitfast and RK4 with spring cables, and Euler and RK4 with limit cables at
    damping ratios 1 (MuJoCo's default) and 30 (nearly inelastic snaps); empty without ``mujoco``."""
    if not mujoco_available():
        return []
    from .mujoco_peer import INTEGRATORS
    # limit cables without implicitfast: with nothing velocity-dependent it is Euler, to the bit (as the
    # elastic sweeps show)
    return ([MujocoRunner(integrator) for integrator in INTEGRATORS]
            + [MujocoRunner(integrator, "inextensible", zeta) for zeta in (1.0, 30.0) for integrator in ("Euler", "RK4")])
