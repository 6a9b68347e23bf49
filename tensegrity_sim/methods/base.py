"""The stepping contract every method implements.

Rules for whoever writes a new method (compare ``scipy.integrate.OdeSolver``):

1. Subclass :class:`StepMethod`, set ``name``, and register the class in ``methods.METHODS``.
2. ``__init__(system, dt, **options)`` checks once everything the method needs of the scene and of
   ``dt`` (a missing cable stiffness, a step beyond a stability limit) and raises ``ValueError`` naming
   what is wrong. Nothing is checked inside the step loop.
3. ``_step_impl(state)`` advances one step of ``dt`` from ``state`` and returns a :class:`MethodStep`.
   It must not modify ``state``: the simulator commits the result, so a failure leaves it untouched.
   No Python loops over members.
4. A method may cache quantities derived from the state between steps (forces at the step's end become
   the next step's start). The simulator calls ``invalidate()`` whenever it changes the state from
   outside (new rest lengths, new external forces, a reset); the method must then recompute.
5. ``strain_energy(positions, rest_lengths)`` is the elastic energy the method's model stores (J);
   ``plate_energy(positions, velocities, rest_lengths)`` the kinetic energy its model keeps apart from the
   nodes' (the full model's moving cable plates; 0 by default), counted in ``Simulator.energy()["kinetic"]``;
   ``losses`` the energy (J) its model removed at events since ``prepare`` (the plates' at snaps and releases;
   ``Simulator.energy_lost``).
6. ``impulses`` are each cable's impulse over the step (N*s), snaps included, in cable order.
7. ``prepare(state)`` makes an initial state consistent with the method's constraints (e.g. removes
   the part of the initial velocities that would stretch a rigid strut); it may modify ``state``.
8. ``slack(positions, rest_lengths)`` says which cables are slack in the method's model (by default:
   shorter than their rest length).
9. Options (e.g. ``solver``) are keyword-only arguments of ``__init__``, listed in ``options``.
10. A method with a compiled multi-step loop says so in ``has_loop()`` and implements ``advance()``
    (``Simulator.run`` then runs in it, inputs held); its results must equal those of ``step()``.
    ``carry()``/``restore(carry)`` save and put back what the loop carries from one step to the next
    (``Simulator.step`` runs steps ahead in the loop and rewinds to a saved carry when it must). With a
    member contact response, ``advanced_pairs`` holds the steps of the last ``advance()`` that had member
    contact impulses, ``{step (from 0): MethodStep.pair_impulses}``, for the contact events. A
    carry that ``invalidate()`` does not rebuild from the state (``carry_outlives_inputs``: a motor's
    position, a warm start) makes the simulator rewind the steps ahead before an input changes or the
    method is asked about the present (``slack``, ``applied_rest_lengths``).
11. ``applied_rest_lengths(state)`` are the rest lengths the cables follow now, if a method lags the
    commanded ones (a motor's finite speed).
12. Masses: apply ``M`` and ``M^-1`` only through ``system.mass`` (``tensegrity_sim.mass``) or its kernel form
    (``methods/_mass_kernels.py``), rigid struts' 2x2 blocks included: every method applies them.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..system import System

__all__ = ["State", "MethodStep", "StepMethod", "StepError"]


class StepError(RuntimeError):
    """A step that cannot be taken (a QP without a solution, a result that is not finite); the simulator
    is as it was before the step, and the message says why."""


@dataclass
class State:
    """What changes during a run. Shapes: positions, velocities, external_forces (N, 3);
    rest_lengths (n_cables,). Units: m, m/s, N, s."""

    positions: np.ndarray
    velocities: np.ndarray
    rest_lengths: np.ndarray
    external_forces: np.ndarray
    step_count: int = 0

    def copy(self) -> "State":
        return State(self.positions.copy(), self.velocities.copy(), self.rest_lengths.copy(),
                     self.external_forces.copy(), self.step_count)


@dataclass(frozen=True)
class MethodStep:
    """One step's outcome: positions, velocities (N, 3) at the step's end; impulses (n_cables,) N*s;
    slack (n_cables,) bool at the step's end if the method has it at hand (else the simulator asks
    ``slack()``); contact_impulses (N, 3) N*s, the ground's impulse on each node over the step (None
    without a ground); pair_impulses: {(member i, member j): (normal N*s, friction (3,) N*s)} the member
    contacts' impulses on member j over the step (None without a member contact response)."""

    positions: np.ndarray
    velocities: np.ndarray
    impulses: np.ndarray
    slack: np.ndarray | None = None
    contact_impulses: np.ndarray | None = None
    pair_impulses: dict | None = None


class StepMethod:
    """Base class of the stepping methods (see the module docstring for the rules)."""

    name: str = ""
    carry_outlives_inputs = False   # rule 10: True: rewind the steps ahead before an input changes
    advanced_pairs: dict = {}       # rule 10: the member contacts' impulses of the last advance(), by step
    options: tuple[str, ...] = ()
    losses: float = 0.0             # rule 5: J removed at events since prepare()

    def __init__(self, system: System, dt: float):
        self.system = system
        self.dt = float(dt)

    def invalidate(self) -> None:
        """The state was changed from outside: drop anything cached from the previous step."""

    def prepare(self, state: State) -> None:
        """Make ``state`` consistent with the method's constraints (called on reset)."""

    def _step_impl(self, state: State) -> MethodStep:
        raise NotImplementedError

    def step(self, state: State) -> MethodStep:
        return self._step_impl(state)

    def retrace(self, state: State) -> MethodStep | None:
        """After a step from ``state`` failed (its result was not finite): take it again in the plain
        numpy reference and return that, if the method has a compiled implementation (else None), so that
        numpy's floating-point warnings and the failure report are the reference's. The simulator then
        calls ``invalidate()``."""
        return None

    def has_loop(self) -> bool:
        """Whether :meth:`advance` runs many steps in compiled code."""
        return False

    def has_ground_loop(self) -> bool:
        """Whether :meth:`advance` also steps the scene's ground (then it takes ``contact``, (K, N, 3) N*s,
        for the ground's impulses); without it a scene with a ground is stepped one :meth:`step` at a time."""
        return False

    def runs_commands(self) -> bool:
        """Whether :meth:`advance` takes ``inputs``: each step's rest lengths (steps, nc) and external forces
        (steps, N, 3), a command schedule evaluated ahead (``Simulator.run(commands=...)``), each step the very
        arithmetic of setting its inputs and stepping it alone."""
        return False

    def loop_detects(self) -> bool:
        """Whether :meth:`advance` runs member-contact detection in its loop: with ``detection`` set to a
        ``contact.CompiledDetector`` it moves that detector's state on and leaves the events in ``found``."""
        return False

    def advance(self, state: State, steps: int, every: int, positions: np.ndarray, velocities: np.ndarray,
                impulses: np.ndarray, slack: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``steps`` steps from ``state`` (not modified), keeping steps ``every``, ``2 every``, ... and
        the last into ``positions``, ``velocities`` (K, N, 3), ``impulses`` (K, n_cables; summed over
        the steps since the previous kept one) and ``slack`` (K, n_cables), ``K = ceil(steps / every)``.
        Returns the final positions and velocities (N, 3)."""
        raise NotImplementedError

    def carry(self):
        """A copy of what :meth:`advance` carries from one step to the next (None: nothing yet; the
        loop then starts from the state)."""
        raise NotImplementedError

    def restore(self, carry) -> None:
        """Put back a :meth:`carry`: the next :meth:`advance` goes on from it."""
        raise NotImplementedError

    def applied_rest_lengths(self, state: State) -> np.ndarray:
        """The rest lengths in effect (n_cables,) m: the commanded ones, unless the method follows a
        command at a finite motor speed (the inextensible method's ``reel_speed``)."""
        return state.rest_lengths.copy()

    def slack(self, positions: np.ndarray, rest_lengths: np.ndarray) -> np.ndarray:
        """(n_cables,) bool: the cables that are slack at ``positions`` (m) for ``rest_lengths`` (m)."""
        d = self.system.cable_vectors(positions)
        return np.sqrt(np.einsum("ij,ij->i", d, d)) < rest_lengths

    def plate_energy(self, positions: np.ndarray, velocities: np.ndarray, rest_lengths: np.ndarray) -> float:
        """Kinetic energy (J) the model keeps beyond the nodes' (rule 5): none unless the cables carry mass."""
        return 0.0

    def describe(self) -> dict:
        """Settings of the method worth logging (solver, tolerances...)."""
        return {"method": self.name, "dt": self.dt}
