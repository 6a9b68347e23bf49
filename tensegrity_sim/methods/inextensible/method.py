"""Method 1 of physics.md §3: inextensible cables (stiffness -> infinity), Moreau's midpoint time-stepping
with one QP over the cables that can be taut, elastic or rigid struts.

One step of ``h`` from ``(x_i, v_i)`` is one sub-step, or a few when cables snap inside it, each of
Moreau's midpoint form::

    x_m = x_i + tau/2 v_i;   v0 = v_i + tau M^-1 F(x_m);   v_f = QP(v0; rows at x_m);   x_f = x_m + tau/2 v_f

``F`` holds gravity, the external forces and the elastic struts' forces at the midpoint (explicit, so
``h < 2 / omega_struts`` is required and checked at start-up). The QP (``methods/qp/solvers.py``) is
``min 1/2 (v - v0)^T M (v - v0)`` with one row ``b_i(x_m)^T v`` per member that can be taut in the
sub-step: ``<= r_i`` for a cable, ``= r_i`` for a rigid strut. Its multipliers are the cable impulses.

**Rows.** A cable is a row when it could reach its length limit by the sub-step's end,
``l_m + tau/2 |u0| >= L (1 - LIMIT_TOL)`` (``u0``: its ends' relative free velocity), a documented
superset of the seed's ``e(x_m) >= 0`` that also stops a cable about to overshoot. With no such cable
and no rigid strut, no QP is solved.

**Targets: the drift stabiliser.** The velocity-level scheme alone (targets 0) lengthens a swinging
cable by ``h^2 v^2 / 2L`` per step. A cable's target is instead the rate that lands it exactly on its
limit at ``x_f``::

    r = (2 / tau) (sqrt(L^2 - (tau/2)^2 |u_perp|^2) - l_m)

where ``u_perp`` is its ends' relative velocity across it at the sub-step's end (the part its own
impulse does not change; other members' impulses do, so it is iterated to convergence, one extra solve
while things move). The targets only change impulses along the members at ``x_m``, so linear and
angular momentum stay exact. Two caps keep the stabiliser from creating energy:

* the impulses' work over a sub-step is ``-1/2 sum y_i (r_i + b_i.v_i)``, so a cable's target is never
  below the reversal ``-b_i.v_i`` of its rate at the midpoint (its ``y_i >= 0``), and a rigid strut's
  target is that reversal (its ``y_i`` has either sign). Then no impulse does positive work, and
  ``v_f = -v_i`` meets every row, so the QP is never infeasible. Where a cap binds the member lands
  ``(tau/2)^2 |u_f^2 - u_i^2| / 2L`` off its limit, a bounded error that is not carried forward;
* a commanded shortening is a reel-in at ``change / h``; the cable may pull faster by twice that rate
  (the motor's work). It lands half a step's reel behind its moving limit (``h |reel| / 2``, O(h),
  gone when the motor stops), so its ends move at the motor's speed: landing on the limit would make
  the second half-step cover the whole reel, and a motor starting from rest would launch them at twice
  its speed (4x the kinetic energy; a hanging mass reeled at 1 m/s left at 2 m/s and flew 20 cm above
  the motor's stop). An impulsive start then gains half the motor's work ``y |reel|``, the rest being
  lost as in a perfectly inelastic impact, as in the exact solution (``test_motor_commands.py``).

**Motor speed.** A rest length is changed by a motor, at a finite speed: the rest lengths in effect
(``applied_rest_lengths``) follow the commanded ones at most at ``reel_speed`` (default
``REEL_SPEED`` = 1 m/s; ``math.inf`` for none), so a command faster than that, a jump above all, is
spread over the steps the motor needs. Why: an inextensible cable reeled in within one step of ``h``
gives its ends a speed ``2 change / h``, so the kinetic energy of a jump grows as ``1 / h^2`` and does
not converge; prism3 with every cable 5 % shorter in one 1 ms step took 3.6e3 J of motor work (the
impulses' work against the reel rate, exactly) and the elastic struts, struck at ``omega h = 0.28``,
then oscillated 2 % of that around the balance. Spread at 1 m/s the same command takes 82 J, and the
balance holds to 7.9e-4 (2.0e-4 at 0.5 ms: O(h^2), from the explicit elastic struts), measured by
``bench/hard_cases.py``; without elastic struts it holds to round-off (``test_inextensible.py``).

**Motor force.** A motor pulls at most ``reel_force`` (default ``REEL_FORCE`` = 2 kN; ``math.inf``: none).
Where following its reel would take a larger impulse over a sub-step (or a structure not locked at load cannot
follow at all), the motor pulls at that force, a known impulse along its cable at the midpoint, and its brake
holds the cable where the motor stood (its row at that length, no reel): it reels in only what the cable gives
(``stalls`` counts those motor steps). The energy gained is then below ``reel_force`` times the cable reeled in:
unlimited motors drove ``icosahedron_ground`` (rigid struts), which locks a few mm into ``examples/roll.yaml``,
on with up to 3e4 N*s a step and launched it 3.6 m up (issue 47). The step kernels leave such a step to the
Python path.

**Snaps.** Steering a cable back while its ends still separate would push them apart again (a
rebound: effective restitution up to 0.96 for Baumgarte with gamma = 1, see the tests). A snap is an
event instead, located inside the step and resolved where it happens:

1. *Locate it.* For each slack cable whose ends' free path (constant free acceleration) crosses its
   limit during the sub-step, the crossing time is found by Newton's method; the sub-step is cut at the
   earliest crossing (at most ``MAX_EVENTS`` per step, ``MAX_CONTACT_EVENTS`` with contacts, snaps and landings
   alike; later ones are stopped at their limit by their rows and resolved at the next step's start).
2. *Impact.* At that configuration, if a cable at its limit that was not already holding (active at
   its limit in the previous sub-step) separates, Moreau's impact law: ``v+ = argmin |v+ - v|_M`` with
   ``b^T v+ <= 0`` for every cable at its limit and ``b^T v+ = 0`` for the rigid struts. Perfectly
   inelastic, no push; simultaneous snaps are resolved together; the admissible set is a cone, so the
   kinetic energy cannot grow.
3. The rest of the step is another sub-step, in which the snapped cable is taut.

**Ground** (a scene with a ``ground``; ``methods/contact/friction.py``): the backend is wrapped so that every
QP above also carries the ground's contact rows (normal rows with the same landing targets and caps as
the cables', Coulomb friction by a mode fixed point); a node reaching the ground is an event located
like a snap, and the impact at its start is one inelastic impact with the snapping cables. A member
contact response (``contact: response: true``) adds the member pairs' rows the same way
(``methods/contact/member.py``).

**Prestress.** A scene written for elastic cables has them longer than their rest lengths by
``tension / k``. The method takes each cable's length limit as its rest length plus that stretch at load
time (``length_offsets``), keeps the offset when rest lengths are commanded, warns
(:class:`LengthOffsetWarning`) and reports the offsets in ``describe()``. No cable strain is stored:
``strain_energy`` counts the elastic struts only. When the taut cables and rigid struts carry a
self-stress (the icosahedron with rigid struts) the structure is locked: the QP's multipliers are not
unique (any multiple of the self-stress can be added; the backend returns one, growing like 1/dt), and a
cable cannot be reeled in, which is reported as a :class:`~.qp.QPError` naming it. The impulses
published for such a step are chosen by :mod:`.self_stress` (the prestress ``reference_tensions``
projected onto the step's self-stress plus the minimum-norm dynamic part), in :meth:`_publish` only;
the QP's own multipliers still decide which cables hold. A cable is slack when it is short of its limit
and carried no impulse over the step.
"""
from __future__ import annotations

import warnings

import numpy as np

from ...system import System
from . import _kernels as kernels
from ..elastic._kernels import keep
from .._numpy_blas import numpy_blas
from ..base import MethodStep, State, StepMethod
from ..contact import friction
from ..contact.friction import ContactSet
from ..qp.solvers import (_FEASIBILITY_TOL, _VELOCITY_FLOOR, BlockMassSolver, DaqpSolver, QPError, Rows, choose_solver,
                          make_solver)
from ..rigid import RigidStruts
from .self_stress import TAUT_TOL, SelfStress, reference_tensions

__all__ = ["InextensibleMethod", "LengthOffsetWarning", "LIMIT_TOL", "MAX_CONTACT_EVENTS", "MAX_EVENTS", "REEL_FORCE",
           "REEL_SPEED"]

REEL_SPEED = 1.0     # m/s: the motors' default top speed (cable-driven tensegrity robots reel slower)
REEL_FORCE = 2e3     # N: the motors' default largest pull (their stall force; module docstring, *Motor force*)

LIMIT_TOL = 1e-9     # relative: a cable within LIMIT_TOL * L of its limit is at it (taut, not slack)
# Snap events located inside one step; each costs an impact and a sub-step. Later snaps in the same
# step are still stopped exactly at their limit and resolved at the next step's start. On rattling
# built-ins (0.1 s against dt = 1e-4) locating up to 8 changed nothing beyond the trajectories'
# chaotic spread and cost up to 1.5x (tower10); the closed-form cases need one.
MAX_EVENTS = 2
# ... and with contacts (a ground, a member response): a snap or landing past the limit is stopped by its row inside
# a midpoint sub-step, where the contacts' friction, its law met at the sub-step's end, works on the mean of its
# velocities and can create energy (issue 47, bench_throws.py --seed 0, the throws the energy check called unsound:
# 12958, the superball pivoting on a node sliding at 2 m/s, whose third sub-step turned the slip to -0.98 m/s under
# a 6.2 N*s normal impulse and made 1.94 J; 10448 and 9087, a node stopped by sticking friction while a cable
# snapped inside the last sub-step, 3.9e-3 and 0.018 J; 11130, three_bar landing a node at 1.5 m/s in its last
# sub-step, bounced by the landing target, 0.027 J). Up to 8 located, the first three make none; 64 since the superball
# spinning at 8 rad/s onto the ground at mu = 2 (throw 22315) took 44 events in one step, a chatter of snaps 1e-9 s apart:
# stopped at 8, its last sub-step stuck a node sliding at 3.2 m/s and made 50 J (at 16, 8.7 J); 22365 takes 101, sound
# from 32 on. Events are the Python path's, only in the steps that have them
MAX_CONTACT_EVENTS = 64
_MIN_EVENT = 1e-6    # an event closer than this fraction of dt to the sub-step's start is not split off
_NEWTON_ITER = 4     # Newton iterations for a snap time (the start point is exact for a straight path)
_LANDING_TOL = 1e-11  # relative: a binding row must end within this of its member's limit ...
_LANDING_ITER = 4     # ... after at most this many solves per sub-step


# the step kernels' ground and friction memory where the scene has no ground (``InextensibleMethod._ground_table``)
_NO_GROUND = (False, np.zeros(0, dtype=np.int64), np.zeros(0), 0.0, 0.0, 0.0, np.zeros(0, dtype=np.int64), 0.0, 0.0,
              0, 0, 0.0)
_NO_MEMORY = (np.zeros(0, dtype=bool), np.zeros(0), np.zeros((0, 2)))
# the kernels' Schur coordinates of the rods' mass blocks where the scene has none (``InextensibleMethod._qp_call``)
_NO_BLOCKS = (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0))


def _same(a, b) -> bool:
    """Whether two step-kernel arguments (arrays, numbers, nested tuples) are equal, arrays in dtype, shape and
    values (``InextensibleMethod.same_tables``)."""
    if isinstance(a, tuple):
        return isinstance(b, tuple) and len(a) == len(b) and all(_same(p, q) for p, q in zip(a, b))
    if isinstance(a, np.ndarray):
        return isinstance(b, np.ndarray) and a.dtype == b.dtype and np.array_equal(a, b)
    return type(a) is type(b) and a == b


def _motor_limit(value, name: str, unit: str) -> float:
    """A motor's limit ``value`` as a float > 0 (``math.inf``: none), else a ValueError naming ``name``."""
    try:
        limit = float(value)
    except (TypeError, ValueError):
        limit = float("nan")
    if not limit > 0:
        raise ValueError(f"{name} must be a number of {unit} > 0 (math.inf: no limit), got {value!r}")
    return limit


class LengthOffsetWarning(UserWarning):
    """The inextensible method lengthened cable limits by their prestress stretch at load time."""


class InextensibleMethod(StepMethod):
    """``compiled``: the motors' limits, the sub-steps' rows and targets, the QP's rows and answer check
    and the self-stress rule's basis in numba kernels (True) or in the numpy reference (False); the QP
    backend is the same.

    Compiled, with dense DAQP and no contact rows, a step runs in one kernel call
    (``_inextensible_kernels.step``: the motors, the impact test, the free motion, the snap search, the
    rows, DAQP's C function and its answer check, the landing, the self-stress rule with its fit) when it
    has no event (no snap located inside it, no impact at its start) and no elastic struts; a sub-step
    of any other step in one call too (``midpoint``), but for the rule's fit. Anything those kernels do
    not cover (an event, a refused QP answer, an SVD of the rule, a pulling cable in its fit) takes the
    Python path with the same kernels, to the same bits (``test_compiled.py``); ``one_kernel = False``
    takes it always. On a ground (no member contact response) the step kernel also arms the ground's
    contacts and solves them by the compiled friction modes (``_friction_kernels.contact_solve``: modes that
    cycle once more at the velocity level, a node an answer carried into the ground armed and the sub-step
    solved again, as the Python path does); a step with a landing inside it, or whose modes the kernel leaves
    to the reference, is Python's. An impact at a step's start (a snap, a node landing) is the kernel's too
    (``_inextensible_kernels.impact``, the touching nodes' rows by the compiled modes) where the rule's fit is
    one-dimensional; a command schedule runs inside the loop
    (:meth:`runs_commands`), and a batch's copies step in it together on every core (:meth:`advance_copies`).
    Rigid rods' mass blocks (physics.md section 4c) are the kernels' too in free flight (DAQP in
    ``BlockMassSolver``'s coordinates, ``_inextensible_kernels._solve_blocks``, to the reference's bits); on a ground
    the friction modes' kernels take a diagonal mass, so a scene with blocks steps by the Python path."""

    name = "inextensible"
    options = ("solver", "reel_speed", "reel_force")
    carry_outlives_inputs = True

    def __init__(self, system: System, dt: float, *, solver: str | None = None, reel_speed: float = REEL_SPEED,
                 reel_force: float = REEL_FORCE, compiled: bool = True):
        super().__init__(system, dt)
        if len(system.attached):
            raise ValueError(f"method 'inextensible' does not take a cable attached along a strut (cable "
                             f"{system.scene.cable_names[system.attached[0]]!r}: its constraint rows join two nodes); "
                             f"give the cables a stiffness and use method 'elastic'")
        self.reel_speed = _motor_limit(reel_speed, "reel_speed", "m/s")
        self.reel_force = _motor_limit(reel_force, "reel_force", "N")
        self.stalls = 0   # motor steps at the force limit (pulling at reel_force, behind the command)
        self._pulled = np.zeros(system.n_cables, dtype=bool)   # the step's motors at their force limit
        scene = system.scene
        self.omega_struts = system.max_frequency(scene.positions, include_cables=False)
        if self.omega_struts * self.dt >= 2.0:
            raise ValueError(
                f"dt={self.dt!r} s is beyond the stability limit of the elastic struts, which the inextensible "
                f"method treats explicitly: dt must be < 2/omega_struts = {2.0 / self.omega_struts:.6g} s "
                f"(omega_struts = {self.omega_struts:.6g} rad/s); use a smaller dt or rigid struts")
        _, length0, _ = system.geometry(scene.positions, system.cable_ends)
        self.length_offsets = np.maximum(length0 - scene.cable_rest_lengths, 0.0)
        if np.any(self.length_offsets > 0):
            worst = int(np.argmax(self.length_offsets))
            warnings.warn(
                f"inextensible cables: {int(np.count_nonzero(self.length_offsets))} cables start longer than "
                f"their rest length (prestress); their length limits are rest length + that stretch (largest "
                f"{self.length_offsets[worst]:.6g} m, {scene.cable_names[worst]!r}), kept when rest lengths "
                f"are commanded", LengthOffsetWarning, stacklevel=4)
        free = system.free
        self._free = free
        self._free_nodes = np.flatnonzero(free)
        index = np.full(system.n_nodes, -1)
        index[free] = np.arange(int(free.sum()))
        self._inv_mass = system.inv_mass[:, None]
        self._kernel_mass = system.mass.kernel_array   # the step kernels' M^-1 (N, 2), made once
        # the backend: named, or chosen by size (dense DAQP for small structures, sparse for large ones); with rigid
        # rods' mass blocks that backend in BlockMassSolver's coordinates, where M is diagonal
        self.solver_choice = f"{solver}: requested" if solver else choose_solver(int(free.sum()))[1]
        self.solver = make_solver(solver, system.masses[free], system.mass)
        # a ground or a member contact response adds its contact rows to every QP (methods/contact/friction.py),
        # through the same interface
        self.ground = (None if scene.ground is None and not scene.contact_response.response
                       else ContactSet(system, self.solver))
        if self.ground is not None:
            self.solver = self.ground.solver
        self.max_events = MAX_EVENTS if self.ground is None else MAX_CONTACT_EVENTS   # events located per step
        # The member table of the QP rows: the rigid struts that move (equalities), then every cable.
        self.rigid = RigidStruts(system)
        self._n_eq = self.rigid.count
        self._ends = np.vstack([self.rigid.ends, system.cable_ends])
        self._row_nodes = index[self._ends]
        self._rigid_lengths = np.sqrt(self.rigid.length_sq)
        self._cables_move = free[system.cable_ends].any(axis=1)
        elastic = ~system.rigid
        self._elastic_ends = system.strut_ends[elastic]
        self._elastic_k = system.stiffness[: system.n_struts][elastic]
        self._elastic_rest = system.strut_rest[elastic]
        self._elastic_incidence = system.incidence_matrix(self._elastic_ends)
        self._holding = np.zeros(system.n_cables, dtype=bool)
        self._hint = self._holding   # the QP's warm start of the first sub-step (see invalidate)
        self._carried = np.zeros(system.n_cables, dtype=bool)   # motors at their force in the last step (_motor_modes)
        # the last step's friction modes cycled on its Python path (FrictionalSolver.cycled): the next step skips the
        # step kernel, whose modes would cycle the same way before leaving it to that path (_step_impl)
        self._cycling = False
        # the cables that held in the last sub-step of the last step cut at snaps: the warm start of such a
        # step's last sub-step, where the backend asks for it (QPSolver.last_hint)
        self._last_hint = self._holding
        self._end_geometry = None   # (positions, cable vectors, lengths) last computed (a step's end)
        self._applied = scene.cable_rest_lengths   # the rest lengths in effect (the motors' positions), m
        # what the impulses of a locked structure are published as (issue 20, methods/inextensible/self_stress.py)
        moving = np.concatenate([np.arange(self._n_eq), self._n_eq + np.flatnonzero(self._cables_move)])
        _, _, n_load = system.geometry(scene.positions, self._ends[moving])
        self.reference_tensions = reference_tensions(system.stiffness[system.n_struts:], self.length_offsets)
        self.self_stress = SelfStress(int(free.sum()), self.reference_tensions,
                                      Rows(self._row_nodes[moving], n_load, np.zeros(len(moving)), self._n_eq),
                                      np.flatnonzero(self._cables_move), system.masses[free])
        # a structure that can lock counts a cable this close to its limit as at it (self_stress.TAUT_TOL)
        self._taut_tol = TAUT_TOL if self.self_stress.possible else LIMIT_TOL
        self.compiled = compiled   # the solver's rows and check and the self-stress rule follow (the property)
        # a compiled sub-step in one kernel call where it applies (_one_kernel); False: through the solver's
        # and the self-stress rule's Python API, with the same kernels and bits (test_compiled.py)
        self.one_kernel = True
        self._blas = numpy_blas()   # numpy's ddot/dgemv: the step kernel's fit to numpy's bits (else no step kernel)

    @property
    def compiled(self) -> bool:
        return self.solver.compiled

    @compiled.setter
    def compiled(self, value: bool) -> None:
        self.solver.compiled = self.self_stress.compiled = bool(value)

    # ------------------------------------------------------------------ contract
    def invalidate(self) -> None:
        """A command or a reset: no cable is known to hold (each one at its limit is checked for a snap),
        but across a command the QP keeps its warm start (``_hint``, the cables that held before): a guess
        it verifies, which spares a large structure's first step after a command a cold start (a reset
        drops it: :meth:`prepare`)."""
        self._holding = np.zeros(self.system.n_cables, dtype=bool)
        self._end_geometry = None

    def prepare(self, state: State) -> None:
        """Initial velocities that would stretch a rigid strut lose that component (momentum unchanged).
        Initial velocities that stretch a taut cable are an impact at t = 0, resolved by the first step.
        A reset forgets what the steps before it left (the QP's warm start, the rule's kept spaces and
        starts), so that a reset simulator steps as a fresh one does, to the bit: a sparse backend's
        guess from an old hint once took another path to the same QP answer (1.3e-12 N apart on a
        moving 15-stage tower)."""
        if self.rigid.count:
            state.velocities = state.velocities + self.rigid.project_velocities(state.positions, state.velocities)
        self._applied = state.rest_lengths.copy()
        self._holding = self._hint = self._last_hint = np.zeros(self.system.n_cables, dtype=bool)
        self._carried = np.zeros(self.system.n_cables, dtype=bool)
        self._cycling = False
        self.self_stress.forget()

    def applied_rest_lengths(self, state: State) -> np.ndarray:
        """The rest lengths in effect (n_cables,) m: the commanded ones, reached at ``reel_speed``."""
        return self._applied.copy()

    def limits(self, rest_lengths: np.ndarray) -> np.ndarray:
        """Cable length limits (n_cables,) m: rest lengths plus the prestress offsets."""
        return rest_lengths + self.length_offsets

    def slack(self, positions: np.ndarray, rest_lengths: np.ndarray) -> np.ndarray:
        """(n_cables,) bool: shorter than the length limit by more than ``LIMIT_TOL`` (relative), or
        ``TAUT_TOL`` in a structure that can lock (a step's flags also need the cable to carry no impulse).
        The limit is that of the rest lengths in effect (``rest_lengths`` is the command, which they may
        still follow)."""
        _, length = self._cable_geometry(positions)
        return length < self.limits(self._applied) * (1.0 - self._taut_tol)

    @staticmethod
    def slack_copies(methods: list, positions: np.ndarray) -> np.ndarray:
        """:meth:`slack` of B copies of one structure at once, the same arithmetic element by element (the
        lengths by the same ``einsum`` over each cable's row): ``methods`` (B,), ``positions`` (B, N, 3) m;
        (B, n_cables) bool. A batch's run asks it at its start: 256 calls of :meth:`slack` took 6 ms of
        Python, a tenth of a 20-step chunk of 256 thrown icosahedra (issue 47)."""
        ends = methods[0].system.cable_ends
        d = positions[:, ends[:, 1]] - positions[:, ends[:, 0]]
        rows = d.reshape(-1, 3)
        length = np.sqrt(np.einsum("ij,ij->i", rows, rows)).reshape(d.shape[:2])
        # (limits as limits() adds them, the copies stacked first)
        limits = np.stack([m._applied for m in methods]) + np.stack([m.length_offsets for m in methods])
        return length < limits * (1.0 - np.array([m._taut_tol for m in methods]))[:, None]

    def strain_energy(self, positions: np.ndarray, rest_lengths: np.ndarray) -> float:
        """Elastic struts only: an inextensible cable stores no strain energy (J)."""
        if not len(self._elastic_ends):
            return 0.0
        _, length, _ = self.system.geometry(positions, self._elastic_ends)
        e = length - self._elastic_rest
        return float(0.5 * np.sum(self._elastic_k * e * e))

    def describe(self) -> dict:
        offsets = self.length_offsets
        return {"method": self.name, "dt": self.dt, **self.solver.describe(), "solver_choice": self.solver_choice,
                "limit_tol": LIMIT_TOL, "reel_speed": self.reel_speed, "reel_force": self.reel_force,
                "max_events": self.max_events, "omega_struts": self.omega_struts,
                "length_offsets": {name: float(o) for name, o in zip(self.system.scene.cable_names, offsets)
                                   if o > 0}}

    # ------------------------------------------------------------------ step
    def _cable_geometry(self, x):
        """Cable vectors (n_cables, 3) and lengths (n_cables,) at ``x``, reusing the last ones computed
        (the step's end, where the self-stress rule needs them, is the step's result, which the simulator
        commits as that very array and the next step starts from: identity means the same positions)."""
        cached = self._end_geometry
        if cached is not None and cached[0] is x:
            return cached[1], cached[2]
        d, length, _ = self.system.geometry(x, self.system.cable_ends)
        self._end_geometry = (x, d, length)
        return d, length

    def _step_impl(self, state: State) -> MethodStep:
        """One step: in the step kernel (:meth:`_step_kernel`) where it can take it, else on the Python path
        (:meth:`_step_python`). A step after one whose friction modes cycled (answered by the Newton method,
        which only the Python path has) goes to the Python path at once, its friction solves starting from the
        Newton method's last answer (``FrictionalSolver.resume``): the kernel's modes would most likely cycle
        again (the same QPs) and leave the step to that path. Measured (issue 47, the inextensible roll of
        ``examples/roll.yaml``): 74 steps cycled, 55 of them right after one that did, each paying a failed
        kernel try of ~1 ms (two in ``run()``) and ~90 mode QPs before Newton."""
        self.self_stress.begin_step()
        if self._kernel_steps() and not self._cycling:
            done = self._step_kernel(state)
            if done is not None:
                return done
        cycled = 0
        if self.ground is not None:
            cycled, self.solver.resume = self.solver.cycled, self._cycling
        try:
            return self._step_python(state)
        finally:
            self._cycling = self.ground is not None and self.solver.cycled > cycled

    def _step_python(self, state: State) -> MethodStep:
        """:meth:`_step_impl` on the Python path: the events inside the step located and taken, each sub-step's
        QP by the backend (on a ground its friction solver)."""
        x, v = state.positions, state.velocities
        if self.compiled:
            applied, reel, limits, floor, taut, reeling = kernels.motor_limits(
                state.rest_lengths, self._applied, self.reel_speed * self.dt, self.dt, self.length_offsets,
                LIMIT_TOL, self._taut_tol)
        else:
            applied, reel, limits, floor, taut, reeling = self._motor_limits_reference(state.rest_lengths)
        f_ext = self.system.gravity_force + state.external_forces
        impulses = np.zeros(self.system.n_cables)
        self._pulled = np.zeros(self.system.n_cables, dtype=bool)
        if self.ground is not None:
            self.ground.begin_step()
        holding = self._holding
        hint = self._hint
        remaining = self.dt
        landed = None   # the nodes whose impact the last cut was placed at (ContactSet.landed)
        snapped = None  # ... and the cables (_snapped)
        for event in range(self.max_events + 1):
            d, length = self._cable_geometry(x)
            at_limit = (length >= floor) & self._cables_move
            if snapped is not None:
                at_limit |= snapped
            maybe = at_limit & ~holding
            landing = self.ground is not None and self.ground.arm_impact(x, v, self.dt, landed)
            if (maybe.any() or landing) and v.any():
                v, y = self._impact(x, v, d, length, limits, at_limit, maybe, holding, landing)
                if y is not None:
                    impulses += y
            tau = remaining
            x_m, v0 = self._free_motion(x, v, tau, f_ext)
            cut = False
            whole = None   # the sub-step taken whole though a snap was located inside it
            if event < self.max_events:
                slack = ~at_limit & self._cables_move
                snap = theta = 1.0 if at_limit.all() else self._first_snap(d, limits, v, v0, tau, slack)
                if self.ground is not None:
                    theta = min(theta, self.ground.first_impact(x, v, v0, tau))
                cut = _MIN_EVENT * self.dt < theta * tau < tau - _MIN_EVENT * self.dt
                if cut and self.ground is None and self.self_stress.possible:
                    last = event > 0 and self.solver.last_hint
                    whole = self._whole(x_m, v, v0, tau, d, length, limits, floor, taut, reel, reeling, slack,
                                        self._last_hint if last else hint)
                    cut = whole is None
                if cut:
                    snapped = self._snapped(d, limits, v, v0, tau, slack) if snap == theta else None
                    tau = theta * tau
                    x_m, v0 = self._free_motion(x, v, tau, f_ext)
            last = event > 0 and not cut and self.solver.last_hint
            if whole is None:
                x, v, y, published = self._midpoint(x_m, v, v0, tau, limits, floor, taut, reel, reeling,
                                                    self._last_hint if last else hint)
            else:
                x, v, y, published = whole
            impulses += published
            holding = hint = (y > 0) & at_limit
            if not cut:
                if last:
                    self._last_hint = y > 0
                break
            if self.ground is not None:
                landed = self.ground.landed(theta)
            remaining -= tau
        end_length = self._cable_geometry(x)[1]   # cached if the self-stress rule computed it
        pulled = self._pulled
        if pulled.any():
            # a motor at its force limit reeled in only what its cable gave: it stands where the cable ends, half
            # a step's reel ahead as a running motor does (within what it could reel: no farther than commanded,
            # never back out)
            ahead = end_length[pulled] - self.length_offsets[pulled] + (0.5 * self.dt) * reel[pulled]
            applied[pulled] = np.maximum(applied[pulled], np.minimum(self._applied[pulled], ahead))
            self.stalls += int(np.count_nonzero(pulled))
        self._holding = self._hint = holding
        self._applied = applied
        self._carried = pulled
        contact = pairs = None
        if self.ground is not None:
            contact, pairs = self.ground.take_impulses(), self.ground.take_pair_impulses()
        # slack: short of its limit and no impulse over the step (a locked cable carrying prestress is taut)
        slack = (end_length < taut) & ~(impulses > 0)
        return MethodStep(x, v, impulses, slack, contact, pairs)

    def _step_kernel(self, state: State) -> MethodStep | None:
        """:meth:`_step_impl` of a step without events (one sub-step, no impact at its start) in one kernel
        call (``_inextensible_kernels.step``; the self-stress rule's numpy fit after it when the kernel
        could not fit); None when the step needs the Python path (an event, or a QP answer it must
        handle)."""
        rule = self.self_stress
        (ok, x, v, holding, applied, taut, fitted, impulses, slack, node, cables, y, d, length, binding, members,
         a_t, basis, contact, modes, stalls, pulled) = kernels.step(state.positions, state.velocities,
                                                            *self._step_inputs(state),
                                                    self._applied, *self._motors(), self._holding, self._hint,
                                                    *self._step_constants(), self._memory(), self._carried)
        if not ok:
            return None
        self._carried = pulled
        for kept, new in zip(self._memory(), modes):
            kept[:] = new
        self.stalls += stalls
        self._end_geometry = (x, d, length)
        if fitted:
            rule.residual = max(rule.residual, node)
        else:
            published = np.zeros(len(cables))
            published[cables] = rule.locked_impulses(binding, members, a_t, basis, y, self.dt, self._n_eq)[self._n_eq:]
            impulses = np.zeros(len(cables))
            impulses += published
            # slack: short of its limit and no impulse over the step (a locked cable carrying prestress is taut)
            slack = (length < taut) & ~(impulses > 0)
        self._holding = self._hint = holding
        self._applied = applied
        if self.ground is None:
            return MethodStep(x, v, impulses, slack, None, None)
        return MethodStep(x, v, impulses, slack, contact, {})

    def _step_inputs(self, state: State) -> tuple:
        """The step kernels' arguments that the inputs set: the force (N, 3) N and the commanded rest
        lengths (n_cables,) m."""
        return self.system.gravity_force + state.external_forces, state.rest_lengths

    def _motors(self) -> tuple:
        """The step kernels' arguments after the rest lengths in effect: the motors' reach over a step (m),
        dt, the length offsets and the tolerances."""
        return self.reel_speed * self.dt, self.dt, self.length_offsets, LIMIT_TOL, self._taut_tol

    def _step_constants(self) -> tuple:
        """The step kernel's arguments after the cables that hold: the system's tables, DAQP's C call,
        the tolerances, the self-stress rule's load-time space and numpy's BLAS."""
        rule = self.self_stress
        backend = self.solver if self.ground is None else self.solver.inner   # DAQP (a ground's: under its friction)
        return (self._kernel_mass, self._ends, self._n_eq, self._rigid_lengths, self._cables_move,
                self._row_nodes, self._free_nodes, self.system.cable_ends, _MIN_EVENT, _NEWTON_ITER,
                *self._qp_call(backend),
                _FEASIBILITY_TOL, _VELOCITY_FLOOR, _LANDING_TOL, _LANDING_ITER, self.reel_force, rule.possible,
                *rule.load_space, *self._blas, rule.reference, self._ground_table())

    def _ground_table(self) -> tuple:
        """What the step kernels take of the ground (``_inextensible_kernels.midpoint``'s ``ground``): its
        nodes, radii, height and friction, ``ContactSet``'s tolerance and free-node index, the friction
        modes' settings as ``friction.py`` has them now and the restitution; ``_NO_GROUND`` without one (or with
        a member contact response, which is Python's)."""
        ground = self.ground
        if ground is None or ground.members is not None:
            return _NO_GROUND
        return (True, ground._grounded, np.asarray(ground.radii, dtype=float), float(ground.height), float(ground.mu),
                friction.TOUCH_TOL, ground._free_index, friction.FIXED_POINT_TOL, friction._SLIP_FLOOR,
                friction.MAX_MODE_ITER, friction._ANDERSON_DEPTH, float(ground.restitution))

    def _memory(self) -> tuple:
        """Each node's friction mode, ``y_n`` and slip direction as the friction solver keeps them (the step
        kernels read and update them), or empty arrays without a ground."""
        if self.ground is None:
            return _NO_MEMORY
        solver = self.solver
        return solver._stick, solver._normal, solver._slip

    # ------------------------------------------------------------------ the compiled loop
    def has_loop(self) -> bool:
        """A compiled loop where every step can run in the step kernel (:meth:`_kernel_steps`); a step the
        kernel leaves to Python is taken there, in the loop."""
        return self._kernel_steps()

    def _kernel_steps(self) -> bool:
        """Whether a step without events runs in the step kernel: dense DAQP, no member contact rows (a
        ground's are the kernel's, with the friction solver's compiled modes not replaced on the instance),
        no elastic struts (:meth:`_compiled_dense`)."""
        if len(self._elastic_ends) or self._blas is None:
            return False
        if self.ground is None:
            return self._one_kernel()
        solver = self.solver
        # the ground's compiled friction modes take a diagonal mass: with the rods' blocks, the Python path
        return (self.ground.members is None and not self.system.mass.consistent and self._compiled_dense(solver.inner)
                and not {"solve", "_modes_compiled", "_modes"} & vars(solver).keys())

    def has_ground_loop(self) -> bool:
        return self.ground is not None and self.has_loop()

    def runs_commands(self) -> bool:
        """:meth:`advance` takes each step's inputs (a command schedule evaluated ahead) where it has a loop."""
        return self.has_loop()

    def carry(self):
        """What a step leaves to the next (a motor's position, the cables that hold, the warm start, the
        rule's largest dropped impulse, on a ground each node's friction mode and the friction solver's last
        Newton answer, a start of its next, and the motors that pulled at their force): a command or a reset does
        not recompute it from the state, so the simulator rewinds the steps computed ahead before either
        (``carry_outlives_inputs``). The motors' positions, the cables that hold and the warm starts are arrays
        each step replaces and none changes in place: the carry holds them as they are (a batch takes 256 carries
        a run); the friction memory and the pulling motors, which the loops update in place, are copied."""
        answer = None if self.ground is None else self.solver.answer   # (immutable: replaced, never changed)
        return (self._applied, self._holding, self._hint, self._last_hint, self.self_stress.residual,
                tuple(a.copy() for a in self._memory()), answer, self._carried.copy(), self._cycling)

    def restore(self, carry) -> None:
        applied, holding, hint, last, self.self_stress.residual, memory, answer, carried, self._cycling = carry
        self._carried = carried.copy()
        self._applied, self._holding, self._hint = applied.copy(), holding.copy(), hint.copy()
        self._last_hint = last.copy()
        for kept, saved in zip(self._memory(), memory):
            kept[:] = saved
        if self.ground is not None:
            self.solver.answer = answer
        self._end_geometry = None

    def advance(self, state: State, steps: int, every: int, positions: np.ndarray, velocities: np.ndarray,
                impulses: np.ndarray, slack: np.ndarray, contact: np.ndarray | None = None, inputs=None
                ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`StepMethod.advance` in ``_inextensible_kernels.steps``, with each step the kernel leaves
        to Python taken by :meth:`step`'s own path (the same bits as stepping one at a time). A step that
        fails (:class:`QPError`, an answer that is not finite) ends the loop: it and what would follow are
        NaN, which the simulator takes for a step it must retake alone (and raise at). On a ground,
        ``contact`` (K, N, 3) N*s gets its impulses, summed like the cables' (None: not kept). ``inputs``
        (:meth:`runs_commands`): each step's rest lengths (steps, nc) and external forces (steps, N, 3),
        ``state``'s being those in effect before them (not changed), each step the very arithmetic of setting
        its inputs (a change is an :meth:`invalidate`) and stepping it."""
        x, v = state.positions, state.velocities
        rest_now, ext_now = state.rest_lengths, state.external_forces
        n, nc = x.shape[0], self.system.n_cables
        if inputs is None:
            rest_seq, ext_seq = np.empty((0, nc)), np.empty((0, n, 3))
        else:
            rest_seq, ext_seq = (np.ascontiguousarray(a, dtype=float) for a in inputs)
        motors, constants = self._motors(), self._step_constants()
        out = positions[..., None], velocities[..., None], impulses[..., None], slack[..., None]
        total = np.zeros(nc)
        if contact is None:
            contact = np.empty((0 if self.ground is None else len(positions), n, 3))
        on_ground = np.zeros((n, 3))   # the ground's impulses since the last kept step
        gravity = self.system.gravity_force
        rule, i = self.self_stress, 0
        stall_count = np.zeros(1, dtype=np.int64)   # the kernel's motor steps at their force
        while True:
            if not self._cycling:
                i, x, v, self._applied, self._holding, self._hint, rule.residual = kernels.steps(
                    i, steps, every, x, v, self._applied, self._holding, self._hint, rule.residual, total, *out,
                    gravity + ext_now, rest_now, *motors, *constants, self._memory(), on_ground, contact, rest_seq,
                    ext_seq, gravity, ext_now, stall_count, self._carried)
                self.stalls += int(stall_count[0])
                stall_count[0] = 0
                if i == steps:
                    break
            elif len(rest_seq) and not (np.array_equal(rest_seq[i], rest_now) and np.array_equal(ext_seq[i], ext_now)):
                self.invalidate()   # the step's new inputs, as the kernel takes them (_step_impl's kernel skipped)
            if len(rest_seq):   # the step's inputs (the kernel invalidated the method if they changed)
                rest_now, ext_now = rest_seq[i], ext_seq[i]
            try:
                r = self._step_impl(State(x, v, rest_now, ext_now, state.step_count + i))
            except QPError:
                r = None
            if r is None or not np.isfinite(r.positions).all():
                positions[i // every:] = velocities[i // every:] = impulses[i // every:] = np.nan
                break
            x, v = r.positions, r.velocities
            total += r.impulses
            if r.contact_impulses is not None:
                on_ground += r.contact_impulses
            i += 1
            if i % every == 0 or i == steps:
                if len(contact):
                    contact[(i - 1) // every] = on_ground
                    on_ground[:] = 0.0
                keep(x.reshape(-1, 3, 1), v.reshape(-1, 3, 1), 0, total, r.slack, (i - 1) // every, 0, *out)
            if i == steps:
                break
        self._end_geometry = None
        return x.copy(), v.copy()

    def same_tables(self, other: "InextensibleMethod") -> bool:
        """Whether ``other`` (a method of another copy of the structure) steps with this one's tables and
        constants (:meth:`_step_constants`, :meth:`_motors` but the length offsets, which
        :meth:`advance_copies` takes per copy): copies built from scenes whose prestress differs do not."""
        mine, theirs = self._step_constants() + self._motors(), other._step_constants() + other._motors()
        mine, theirs = mine[:-3] + mine[-2:], theirs[:-3] + theirs[-2:]   # without the offsets
        return _same(mine, theirs)

    @staticmethod
    def advance_copies(methods: list, states: list, steps: int, positions: np.ndarray, velocities: np.ndarray,
                       impulses: np.ndarray, slack: np.ndarray, contact: np.ndarray | None = None
                       ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`advance` of B copies of one structure, every step kept: ``methods`` (B,) each
        :meth:`has_loop` and :meth:`same_tables` as the first, from ``states`` (B,); the outputs
        ``positions``, ``velocities`` (B, steps, N, 3), ``impulses``, ``slack`` (B, steps, n_cables),
        ``contact`` (B, steps, N, 3) on a ground. The copies' compiled steps run on every core
        (``_inextensible_kernels.copies_steps``), each copy's steps from the first one its kernel leaves to
        Python by that copy's own :meth:`advance`: each copy's numbers are those of its :meth:`advance`
        alone (a failed step and what follows NaN). Returns the positions and velocities (B, N, 3) after
        them."""
        first = methods[0]
        x = np.stack([s.positions for s in states])
        v = np.stack([s.velocities for s in states])
        applied = np.stack([m._applied for m in methods])
        holding = np.stack([m._holding for m in methods])
        hint = np.stack([m._hint for m in methods])
        carried = np.stack([m._carried for m in methods])
        residual = np.array([m.self_stress.residual for m in methods], dtype=float)
        f_ext = np.stack([m._step_inputs(s)[0] for m, s in zip(methods, states)])
        commanded = np.stack([s.rest_lengths for s in states])
        offsets = np.stack([m.length_offsets for m in methods])
        grounded = first.ground is not None
        # each copy's friction memory; without a ground empty arrays, the same for every copy
        memory = ([np.stack(kept) for kept in zip(*(m._memory() for m in methods))] if grounded else
                  [np.empty((len(methods), *kept.shape), dtype=kept.dtype) for kept in _NO_MEMORY])
        n = x.shape[1]
        on_ground = np.zeros((len(methods), n, 3))
        out_contact = np.empty((len(methods), 0, n, 3)) if contact is None else contact
        done = np.empty(len(methods), dtype=np.int64)
        stalls = np.zeros(len(methods), dtype=np.int64)   # each copy's motor steps at their force
        most, dt, _, limit_tol, taut_tol = first._motors()
        kernels.copies_steps(steps, x, v, applied, holding, hint, residual, np.zeros(applied.shape),
                             positions[..., None], velocities[..., None], impulses[..., None], slack[..., None], f_ext,
                             commanded, most, dt, offsets, limit_tol, taut_tol, *first._step_constants(), *memory,
                             on_ground, out_contact, done, stalls, carried,
                             np.array([m._cycling for m in methods], dtype=bool))
        for b, method in enumerate(methods):
            # each copy's carry a row of the copies' arrays, its own (replaced, never changed in place, by its steps)
            method._applied, method._holding, method._hint = applied[b], holding[b], hint[b]
            method._carried = carried[b]
            method.self_stress.residual = float(residual[b])
            method.stalls += int(stalls[b])
            if grounded:
                for kept, new in zip(method._memory(), memory):
                    kept[:] = new[b]
            method._end_geometry = None
            i = int(done[b])
            if i < steps:   # the rest of the copy's steps by its own advance (the Python path's steps in it)
                state = states[b]
                x[b], v[b] = method.advance(
                    State(x[b].copy(), v[b].copy(), state.rest_lengths, state.external_forces, state.step_count + i),
                    steps - i, 1, positions[b, i:], velocities[b, i:], impulses[b, i:], slack[b, i:],
                    None if contact is None else contact[b, i:])
        return x, v

    def _motor_limits_reference(self, commanded):
        """The numpy reference of ``_inextensible_kernels.motor_limits`` for the ``commanded`` rest
        lengths (n_cables,) m."""
        # the motors move the rest lengths in effect towards the commanded ones, at most reel_speed * dt
        # (landing exactly on the command); a shortening is a reel-in at that rate (m/s, <= 0)
        change = commanded - self._applied
        most = self.reel_speed * self.dt
        applied = np.where(np.abs(change) <= most, commanded, self._applied + np.copysign(most, change))
        reel = np.minimum(applied - self._applied, 0.0) / self.dt
        limits = self.limits(applied)
        return (applied, reel, limits, limits * (1.0 - LIMIT_TOL), limits * (1.0 - self._taut_tol),
                bool(reel.any()))

    def _free_motion(self, x, v, tau, f_ext):
        """Midpoint ``x_m`` (N, 3) and free velocity ``v0 = v + tau M^-1 F(x_m)`` (N, 3)."""
        x_m = x + (0.5 * tau) * v
        force = f_ext
        if len(self._elastic_ends):
            _, length, n = self.system.geometry(x_m, self._elastic_ends)
            tension = self._elastic_k * (length - self._elastic_rest)
            force = force + self._elastic_incidence @ (tension[:, None] * n)
        if self.system.mass.consistent:   # the rods' blocks: M^-1 couples each rod's two ends
            return x_m, v + tau * self.system.mass.solve(force)
        return x_m, v + tau * self._inv_mass * force   # the step kernel's arithmetic, to the bit

    def _solve_mass(self, impulse: np.ndarray) -> np.ndarray:
        """``M^-1`` of ``impulse`` (N, 3): the rods' blocks through ``system.mass``, else the lumped arithmetic of the
        kernels (``_inextensible_kernels._solve_mass`` and ``inv_mass[:, :1] * push``), to the bit."""
        if self.system.mass.consistent:
            return self.system.mass.solve(impulse)
        return self._inv_mass * impulse

    def _first_snap(self, d, limits, v, v0, tau, slack) -> float:
        """Fraction of the sub-step (0, 1] at which the first ``slack`` cable reaches its limit on the
        free path ``d(t) = d + t tau u + (t tau)^2 a / 2`` of its ends (1.0 if none does); compiled in
        ``_inextensible_kernels.first_snap``, of which this is the numpy reference."""
        if self.compiled:
            return kernels.first_snap(d, limits, v, v0, tau, self.system.cable_ends, slack, _NEWTON_ITER)
        return float(self._snap_times(d, limits, v, v0, tau, slack)[1].min(initial=1.0))

    def _whole(self, x_m, v, v0, tau, d, length, limits, floor, taut, reel, reeling, slack, hint):
        """The sub-step from ``x_m`` of a structure that can lock, without a ground, taken whole (:meth:`_midpoint`'s
        result) though a snap was located inside it, where the snap does not happen on the constrained path: every
        ``slack`` cable whose free path crosses its limit in it (:meth:`_snap_times`' cables; ``d``, ``length`` their
        vectors and lengths at the start) reaches it by its path's curvature alone (its rate at the start would not close its gap in the sub-step) and ends
        it short of its limit (below ``floor``), with no impulse and no motor pulling it; else None, nothing
        changed (the sub-step is cut at the snap, with no QP taken for the try where a cable closes at its
        rate). Why: a slack cable of a locked structure (a prestressed icosahedron with rigid struts: its limits
        consistent to ~1e-7 of a length, so one cable hovers that short of its limit while the others hold it)
        crosses its limit on its ends' free path in every step of a tumble, the free path being straight lines,
        while the rows of the cables that hold keep it short: each step was cut there for an impact that did
        nothing (steps 6-43 of the thrown icosahedron, every copy of a batch on the Python path, 50-100x
        slower)."""
        crossing = self._snap_times(d, limits, v, v0, tau, slack)[0]
        ends, length = self.system.cable_ends[crossing], length[crossing]
        # a cable whose rate at the start closes its gap within the sub-step snaps: only one reaching its limit by
        # its free path's curvature alone (the straight lines of a turning body) may not
        closing = tau * np.einsum("ij,ij->i", d[crossing], v[ends[:, 1]] - v[ends[:, 0]])
        if np.any(closing >= (limits[crossing] - length) * length):
            return None
        pulled, residual = self._pulled.copy(), self.self_stress.residual
        out = self._midpoint(x_m, v, v0, tau, limits, floor, taut, reel, reeling, hint)
        length = self._cable_geometry(out[0])[1]
        if not (np.all(out[2][crossing] == 0.0) and not self._pulled[crossing].any()
                and np.all(length[crossing] < floor[crossing])):
            self._pulled, self.self_stress.residual = pulled, residual
            return None
        return out

    def _snapped(self, d, limits, v, v0, tau, slack) -> np.ndarray:
        """The cables (n_cables,) bool whose snap :meth:`_first_snap` located first: a sub-step cut there ends with
        them at their limits to the accuracy of their free path, and they take the impact at the cut (as the nodes
        landing there, ``ContactSet.landed``). Measured (issue 47, ``bench_throws.py`` throw 9087: three_bar, a
        cable snapping 6.1 us into a step): the cut left it 1e-9 m short of its limit, below ``LIMIT_TOL``'s reach,
        and its snap 1.4e-10 s into the next sub-step, too near to split off: its row stopped it inside the
        sub-step, 2.5 N*s, while a node stuck on the ground, whose friction working on the sub-step's mean
        velocity made 0.020 J."""
        cables, t = self._snap_times(d, limits, v, v0, tau, slack)
        out = np.zeros(len(limits), dtype=bool)
        out[cables[t == t.min(initial=np.inf)]] = True
        return out

    def _snap_times(self, d, limits, v, v0, tau, slack):
        """The ``slack`` cables that reach their limits within the sub-step on their free path (indices) and the
        fraction (0, 1] at which each does (:meth:`_first_snap`'s reference)."""
        cables = np.flatnonzero(slack)
        ends = self.system.cable_ends[slack]
        d, lim = d[slack], limits[slack]
        u = v[ends[:, 1]] - v[ends[:, 0]]
        u_mean = 0.5 * (u + v0[ends[:, 1]] - v0[ends[:, 0]])
        d_end = d + tau * u_mean
        cross = np.einsum("ij,ij->i", d_end, d_end) > lim * lim
        cables, d, u, u_mean, lim = cables[cross], d[cross], u[cross], u_mean[cross], lim[cross]
        acc = 2.0 * (u_mean - u) / tau
        # start: the crossing of the straight path d + t tau u_mean (exact at t = 1), small root form
        b = np.einsum("ij,ij->i", d, u_mean) * tau
        a = np.einsum("ij,ij->i", u_mean, u_mean) * tau * tau
        c = np.einsum("ij,ij->i", d, d) - lim * lim
        t = np.clip(-c / (b + np.sqrt(np.maximum(b * b - a * c, 0.0))), 0.0, 1.0)
        for _ in range(_NEWTON_ITER):
            p = d + (t * tau)[:, None] * u + (0.5 * (t * tau) ** 2)[:, None] * acc
            dp = tau * u + (t * tau * tau)[:, None] * acc
            g = np.einsum("ij,ij->i", p, p) - lim * lim
            slope = 2.0 * np.einsum("ij,ij->i", p, dp)
            t = np.clip(t - g / np.where(slope > 0, slope, np.inf), 0.0, 1.0)
        return cables, t

    def _midpoint(self, x_m, v, v0, tau, limits, floor, taut, reel, reeling, holding):
        """Moreau's midpoint sub-step from ``x_m`` with free velocity ``v0``: returns ``x_f``, ``v_f``
        (N, 3), the QP's cable impulses (n_cables,) N*s (they decide which cables hold) and the published
        ones (:meth:`_publish`). A motor that would pull its cable harder than ``reel_force`` pulls at that
        force instead (*Motor force* in the module docstring): the sub-step is solved again with it."""
        n_eq = self._n_eq
        # a cable being reeled in lands half a sub-step's reel behind its moving limit: landing on it would
        # make the second half-step cover the whole reel, launching its ends at twice the motor's speed
        landing = limits - (0.5 * tau) * reel if reeling else limits
        all_limits = np.concatenate([self._rigid_lengths, landing])
        if self._one_kernel():
            done = self._midpoint_kernel(x_m, v, v0, tau, limits, all_limits, floor, taut, reel, holding)
            if done is not None:
                return done
        x_f, v_f, y, rows, cables, pull = self._motor_modes(x_m, v, v0, tau, limits, all_limits, floor, reel, holding)
        impulses = np.zeros(len(limits))
        impulses[cables] = y[n_eq:]
        self._pulled |= pull > 0
        if self.ground is not None:
            self.solver.commit()
        if rows is None:
            return x_f, v_f, impulses, impulses
        y = y.copy()
        y[n_eq:] += pull[cables]
        impulses += pull
        return x_f, v_f, impulses, self._publish(rows, np.flatnonzero(cables), y, tau, x_f, taut)

    def _motor_modes(self, x_m, v, v0, tau, limits, all_limits, floor, reel, holding):
        """The sub-step's QP with each reeling motor following its reel (its cable's row lands behind the
        moving limit) or, where that would take more than ``reel_force`` (or where a structure not locked at
        load cannot follow at all: its QP has no answer), pulling at that force: a known impulse along the cable at the
        midpoint, the cable held where the motor stood at the step's start (its brake). Motors only go from
        following to pulling within a sub-step, so this ends. Returns ``x_f``, ``v_f`` (N, 3), the
        multipliers (k,) N*s, the rows (or None), the cable rows (nc,) bool and the motors' impulses at their
        force (nc,) N*s.

        The motors that pulled at their force in the last step (``_carried``) and still reel start pulling: a
        stalled motor stays stalled, and its step is one solve. Where one's cable ends the sub-step shorter than
        its landing (a following motor would have held it there: it is not stalled), the sub-step is solved again
        from every motor following, as without the carry. Measured (issue 47, ``bench/roll_cost.py``: the locked
        icosahedron's reel of ``examples/roll.yaml``): the hold's steps took 21 friction QPs each, solved with the
        motors following, then pulling, then for the landing; carried, 1.1, and the step kernel's steps 0.10 ms
        where they took 0.67."""
        n_eq = self._n_eq
        most = self.reel_force * tau   # N*s: the most a motor pulls over the sub-step
        reeling = reel < 0
        pulling = reeling & self._carried
        carried = pulling.any()
        while True:
            ends = self.system.cable_ends[pulling]
            d = x_m[ends[:, 1]] - x_m[ends[:, 0]]
            impulse = (most / np.sqrt(np.einsum("ij,ij->i", d, d)))[:, None] * d
            push = np.zeros_like(v0)
            np.add.at(push, ends[:, 0], impulse)
            np.add.at(push, ends[:, 1], -impulse)
            held = all_limits.copy()
            # (the motor stands half a step's reel ahead of its cable, as a running one does: _step_impl)
            held[n_eq:][pulling] = limits[pulling] - (self.dt + 0.5 * tau) * reel[pulling]
            try:
                v_f, y, rows, cables = self._solve_sub_step(x_m, v, v0 + self._solve_mass(push), tau, held, floor,
                                                            np.where(pulling, 0.0, reel), holding)
            except QPError:
                # a structure locked at load cannot reel at all (a clear error, docs/errors.md); one that locks on
                # the way (a reel that takes it to where its members carry a self-stress) stalls its motors there
                if not np.isfinite(most) or self.self_stress.possible or (pulling == reeling).all():
                    raise
                pulling = reeling.copy()   # the structure cannot follow the reel: the motors pull at their force
                continue
            impulses = np.zeros(len(reel))
            impulses[cables] = y[n_eq:]
            over = reeling & ~pulling & (impulses > most)
            if carried:
                length = self.system.geometry(x_m + (0.5 * tau) * v_f, self.system.cable_ends)[1]
                if (pulling & (length < all_limits[n_eq:])).any():   # pulled in past its landing: not stalled
                    carried = False
                    pulling = np.zeros(len(reel), dtype=bool)
                    if self.ground is not None:
                        self.solver.last = None
                    continue
            if not over.any():
                return x_m + (0.5 * tau) * v_f, v_f, y, rows, cables, np.where(pulling, most, 0.0)
            pulling |= over
            if self.ground is not None:
                self.solver.last = None   # this answer is not kept: its contact impulses are not the step's

    def _solve_sub_step(self, x_m, v, v0, tau, all_limits, floor, reel, holding):
        """The QP of a midpoint sub-step (its rows, the landing, the ground's contacts armed, not committed):
        ``v_f`` (N, 3), the multipliers (k,) N*s, the rows (None: nothing can be taut, no cable row) and the
        cable rows (n_cables,) bool."""
        n_eq = self._n_eq
        if self.compiled:
            cables, sel, m_n, m_length, m_limits, floor_rate, targets, warm = kernels.select_rows(
                x_m, v, v0, tau, self._ends, n_eq, all_limits, floor, self._cables_move, reel, holding)
        else:
            cables, sel, m_n, m_length, m_limits, floor_rate, targets, warm = self._rows_reference(
                x_m, v, v0, tau, all_limits, floor, reel, holding)
        touching = self.ground is not None and self.ground.arm_step(x_m, v, v0, tau, 0.5 * tau)
        if len(sel) == 0:   # nothing can be taut: free motion, no QP (unless on the ground)
            v_f = v0
            if touching:
                v_f = v0.copy()
                v_f[self._free] = self.solver.solve(v0[self._free], Rows(np.zeros((0, 2), int), np.zeros((0, 3)),
                                                                         np.zeros(0), 0))[0]
            return v_f, np.zeros(n_eq), None, cables
        rows = Rows(self._row_nodes[sel], m_n, targets, n_eq)
        v_f, y = self._land(v, v0, rows, warm, self._ends[sel], m_length, m_limits, tau, floor_rate, reel)
        if self.ground is not None and self.ground.missed(x_m, v_f, 0.5 * tau):
            # a cable's impulse carried a node that its free motion kept clear of the ground into it:
            # the sub-step again with that node armed too (judged on this answer)
            self.ground.arm_step(x_m, v, v0, tau, 0.5 * tau, v_f)
            v_f, y = self._land(v, v0, rows, warm, self._ends[sel], m_length, m_limits, tau, floor_rate, reel)
        return v_f, y, rows, cables

    def _one_kernel(self) -> bool:
        """Whether a sub-step runs in ``_inextensible_kernels.midpoint``: compiled, dense DAQP, no contact
        rows (a ground or a member contact response), the self-stress rule compiled too and dense (its
        sparse path, for large structures, is Python's), and neither the solver's ``solve`` nor the rule's
        ``impulses`` replaced on the instance (a benchmark's clock, a test's recorder: they see every
        call, through the API)."""
        return self.ground is None and self._compiled_dense(self.solver)

    def _compiled_dense(self, solver) -> bool:
        """Whether the kernels can stand for the QP backend ``solver`` and the self-stress rule: the method
        and the rule compiled, the rule dense, ``solver`` dense DAQP (or DAQP in ``BlockMassSolver``'s coordinates,
        the rods' mass blocks: ``_inextensible_kernels._solve_blocks``), and neither replaced on the instance."""
        rule = self.self_stress
        daqp = solver.inner if type(solver) is BlockMassSolver else solver
        return (self.one_kernel and self.compiled and rule.compiled and not rule.sparse and type(daqp) is DaqpSolver
                and not {"solve", "_solve", "_check"} & (vars(solver).keys() | vars(daqp).keys())
                and "impulses" not in vars(rule))

    @staticmethod
    def _qp_call(solver) -> tuple:
        """What the kernels take of the QP backend ``solver`` (:meth:`_compiled_dense`): DAQP's ``c_call`` and the
        Schur coordinates of the rods' blocks (``BlockMassSolver``: pivots, their partners and ``beta``; empty
        without blocks)."""
        if type(solver) is BlockMassSolver:
            return (*solver.inner.c_call, (solver._pivot.astype(np.int64), solver._other.astype(np.int64),
                                           solver._beta))
        return (*solver.c_call, _NO_BLOCKS)

    def _midpoint_kernel(self, x_m, v, v0, tau, limits, all_limits, floor, taut, reel, holding):
        """:meth:`_midpoint` in one kernel call (plus the self-stress rule's numpy fit); None when a QP
        answer needs the Python path (a failed or refused solve: it raises or solves again)."""
        locked = self.self_stress.possible
        (ok, x_f, v_f, y, cables, nodes, directions, d, length, binding, members, a_t, basis, _,
         pulled) = kernels.midpoint(
            x_m, v, v0, tau, self._ends, self._n_eq, all_limits, floor, self._cables_move, reel, holding,
            self._row_nodes, self._free_nodes, self.system.cable_ends, taut, *self._qp_call(self.solver),
            _FEASIBILITY_TOL, _VELOCITY_FLOOR, _LANDING_TOL, _LANDING_ITER, self.reel_force, limits, self.dt,
            self._kernel_mass, locked, *self.self_stress.load_space, _NO_GROUND, _NO_MEMORY, self._carried)
        if not ok:
            return None
        self._pulled |= pulled
        self._end_geometry = (x_f, d, length)
        impulses = np.zeros(len(cables))
        n_eq = self._n_eq
        if len(y) == 0:
            return x_f, v_f, impulses, impulses
        impulses[cables] = y[n_eq:]
        if not locked:
            return x_f, v_f, impulses, impulses.copy()
        published = np.zeros(len(cables))
        published[cables] = self.self_stress.locked_impulses(binding, members, a_t, basis, y, tau, n_eq)[n_eq:]
        return x_f, v_f, impulses, published

    def _rows_reference(self, x_m, v, v0, tau, all_limits, floor, reel, holding):
        """The numpy reference of ``_inextensible_kernels.select_rows`` (same arguments and results)."""
        n_eq = self._n_eq
        _, length, n = self.system.geometry(x_m, self._ends)
        ends = self.system.cable_ends
        u0 = v0[ends[:, 1]] - v0[ends[:, 0]]
        reach = length[n_eq:] + (0.5 * tau) * np.sqrt(np.einsum("ij,ij->i", u0, u0))
        cables = (reach >= floor) & self._cables_move
        sel = np.concatenate([np.arange(n_eq), n_eq + np.flatnonzero(cables)])
        m_ends, m_length, m_n, m_limits = self._ends[sel], length[sel], n[sel], all_limits[sel]
        # The impulses' work over the sub-step is -1/2 sum y (r + b.v_i): no row may ask for less than
        # the reversal -b.v_i of its midpoint rate (module docstring), except by a reel-in's rate.
        u = v[m_ends[:, 1]] - v[m_ends[:, 0]]
        un = np.einsum("ij,ij->i", u, m_n)
        floor_rate = -un
        if reel.any():
            floor_rate[n_eq:] += 2.0 * reel[cables]
        targets = self._targets(u, un, m_length, m_limits, tau, floor_rate, n_eq)
        warm = np.concatenate([np.ones(n_eq, dtype=bool), holding[cables]])
        return cables, sel, m_n, m_length, m_limits, floor_rate, targets, warm

    def _land(self, v, v0, rows, warm, ends, length, limits, tau, floor_rate, reel):
        """Solve the sub-step's QP so that every binding row lands on its target.

        The cable targets need the relative velocity across each cable at the sub-step's end, which the
        other members' impulses change: start from the velocity at the start (exact at rest) and
        iterate on the solution (usually one more solve while things move). The landing error is below
        (tau^2 / 8 L) |u_f^2 - u^2|, so it is only checked when the velocities changed enough for that
        bound to exceed the tolerance. Returns ``v_f`` (N, 3) and the multipliers (k,)."""
        n_eq = rows.n_eq
        v_f = np.zeros_like(v0)
        shortest = float(limits.min())
        for _ in range(_LANDING_ITER):
            try:
                v_free, y = self.solver.solve(v0[self._free], rows, warm)
            except QPError as exc:
                if not (reel < 0).any():
                    raise
                # only a reel-in can make the rows infeasible (without one, v_f = -v_i meets them all)
                names = ", ".join(np.asarray(self.system.scene.cable_names)[reel < 0])
                raise QPError(exc.solver, exc.status, f"{exc.detail}; the commanded shortening of {names} cannot "
                              f"be followed: the taut cables and rigid struts lock the structure (they carry a "
                              f"self-stress), so no cable can shorten unless another member gives") from exc
            v_f[self._free] = v_free
            if self.compiled:
                done, targets, warm = kernels.landed(v_f, v, v_free, y, ends, rows.nodes, rows.directions, length,
                                                     limits, tau, floor_rate, n_eq, shortest, _LANDING_TOL)
                if done:
                    break
            else:
                change = float(np.abs(v_f - v).max())
                if 0.5 * tau * tau * change * (change + 2.0 * float(np.abs(v).max())) <= _LANDING_TOL * shortest ** 2:
                    break
                u = v_f[ends[:, 1]] - v_f[ends[:, 0]]
                targets = self._targets(u, np.einsum("ij,ij->i", u, rows.directions), length, limits, tau,
                                        floor_rate, n_eq)
                miss = rows.rates(v_free) - targets
                warm = y > 0
                warm[:n_eq] = True
                if not (np.where(warm, np.abs(miss), miss) > _LANDING_TOL * (2.0 / tau) * limits).any():
                    break
            rows.targets = targets
            v = v_f.copy()
        return v_f, y

    @staticmethod
    def _targets(u, un, length, limits, tau, floor_rate, n_eq):
        """Row targets (k,) m/s. A cable's is the rate that puts it exactly at its limit at the sub-step's
        end given the relative velocity ``u`` (k, 3) of its ends across it (the part its own impulse
        does not change; ``un`` is the part along it), but never below ``floor_rate``; a rigid strut's
        (the first ``n_eq`` rows) is ``floor_rate``."""
        across2 = np.einsum("ij,ij->i", u[n_eq:], u[n_eq:]) - un[n_eq:] ** 2
        half = 0.5 * tau
        lim = limits[n_eq:]
        land = (np.sqrt(np.maximum(lim * lim - half * half * across2, 0.0)) - length[n_eq:]) / half
        targets = floor_rate.copy()
        np.maximum(land, floor_rate[n_eq:], out=targets[n_eq:])
        return targets

    def _impact(self, x, v, d, length, limits, at_limit, maybe, holding, landing=False):
        """Moreau's impact law at ``x`` when a cable at its limit that was not holding (``maybe``)
        separates: ``v+ = argmin |v+ - v|_M`` with ``b^T v+ <= 0`` for every cable at its limit and
        ``b^T v+ = 0`` for the rigid struts. The admissible set is a cone, so the projection never
        increases the kinetic energy. With ``landing``, nodes hitting the ground (armed in ``self.ground``)
        are part of the same impact. Returns ``v+`` (N, 3) and the published cable impulses (n_cables,)
        N*s (:meth:`_publish`), or ``v`` and None when nothing snaps or lands."""
        ends = self.system.cable_ends
        n = d / length[:, None]
        rate = self.system.member_rates(v, n, ends)
        # separating faster than would stretch it beyond the tolerance within a step: a snap
        snapping = maybe & (rate * self.dt > LIMIT_TOL * limits)
        if not (snapping.any() or landing):
            return v, None
        cables = np.flatnonzero(at_limit)
        n_eq = self._n_eq
        directions = n[cables]
        if n_eq:
            directions = np.vstack([self.system.geometry(x, self.rigid.ends)[2], directions])
        sel = np.concatenate([np.arange(n_eq), n_eq + cables])
        rows = Rows(self._row_nodes[sel], directions, np.zeros(len(sel)), n_eq)
        warm = np.concatenate([np.ones(n_eq, dtype=bool), snapping[cables] | holding[cables]])
        v_free, y = self.solver.solve(v[self._free], rows, warm)
        if landing:
            self.solver.commit()
            self.ground.solver.disarm()
        v_plus = np.zeros_like(v)
        v_plus[self._free] = v_free
        return v_plus, self._publish(rows, cables, y, 0.0)

    def _publish(self, rows, cables, y, tau, x_end=None, taut=None):
        """The cable impulses (n_cables,) N*s published for a QP answer (``rows``, the cables ``cables``
        (k - n_eq,) int of its inequality rows, multipliers ``y`` (k,)) over ``tau`` s: the QP's own
        unless the rows carry a self-stress, then the rule of :mod:`.self_stress` (the one place where it
        is applied). The cables at their limit are those reaching ``taut`` (n_cables,) m at ``x_end``
        (N, 3), or all of them (an impact, ``tau = 0``, acts on cables at their limit)."""
        if self.self_stress.possible:
            if x_end is None:
                at_limit = np.ones(len(cables), dtype=bool)
            else:
                at_limit = self._cable_geometry(x_end)[1][cables] >= taut[cables]
            y = self.self_stress.impulses(rows, cables, at_limit, y, tau)
        impulses = np.zeros(self.system.n_cables)
        impulses[cables] = y[rows.n_eq:]
        return impulses
