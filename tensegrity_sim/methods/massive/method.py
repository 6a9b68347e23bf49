"""The full model of physics.md §4b (seed eq. 9): elastic cables that carry a mass ``m_c`` (the seed's plate).

Each cable's plate rides on its elastic part. While the cable is slack the plate rests at the natural length
and the cable exerts nothing; when it snaps taut the structure hits the plate in a perfectly inelastic
impact; while taut the plate moves with the elongation, so its kinetic energy ``1/2 m_c de^2`` adds
``m_c b_c b_c^T`` to the mass matrix and the cable pulls with ``k_c e_c`` (plus damping); when the cable comes
back to its natural length the plate stops there (its kinetic energy is lost) and the nodes go on untouched.
With every ``m_c = 0`` this is the elastic method's model; with ``k -> inf`` a snap keeps the restitution
``m*/(m* + m_c)`` (``m* = 1/(b^T M^-1 b)``) that methods 1 and 2 set to 0 and 1.

**Between events** the equation of motion is the Lagrangian one with the plates' kinetic energy: with ``B``
the rows ``b_c^T`` of the taut cables that carry a plate and ``y_c = m_c d2e_c/dt2`` their plates' inertial
forces, ``M a = f - B^T y`` and ``d2e_c/dt2 = b_c^T a + q_c`` (``q_c = (|dv_c|^2 - de_c^2) / l_c``, the
centripetal part of the elongation's acceleration), i.e. ::

    (B M^-1 B^T + diag(1/m_c)) y = B M^-1 f + q,     a = M^-1 (f - B^T y)

a small dense solve over the taut massive cables (Woodbury's form of ``(M + B^T diag(m_c) B)^-1``). The
term acts along each cable, equal and opposite on its ends: momentum is exact. It is stepped by the elastic
method's velocity Verlet (``verlet``). While plates move, the forces depend on the velocity (the plates' ``q``,
damping): they are evaluated once, at the end velocity that the start's acceleration predicts, ``a(x1, v_half +
h/2 a0)`` (``O(h^2)`` from the kick's own, so second order: one solve with ``G`` a step, where correcting the
closing kick took two), and the rates the events read are those at the kick's velocity. Otherwise (damping
without moving plates; rigid struts; contacts) the closing kick is corrected once, as the elastic method's:
``v1 = v_half + h/2 a(x, v_half)``, then ``a(x, v1)``. With nothing velocity-dependent both are the elastic
method's arithmetic. (On the thrown icosahedron the two schemes' energy errors agree to 1% at 1 to 0.125 ms, and
their trajectories differ by ``O(h^2)``, 1/200 of either's error.)

**Events** (a cable's switch state: taut, or within ``BAND`` of its natural length and lengthening) are
located inside the step by the elastic method's located-switch stepper (``methods/elastic/composition.py``:
the earliest switch's time by Newton on the step itself) and resolved at that instant (:meth:`_events`):

* a snap of cables ``S`` (plates at rest) while the cables ``A`` are taut with their plates moving: the
  seed's impulse complementarity (eq. 5) with the plate masses, ``G = B M^-1 B^T + diag(1/m_c)`` over
  ``A + S``: ``G_A p = 0`` (a moving plate stays on its cable) and ``0 <= p_S ⟂ G_S p - de_S >= 0`` (a plate
  leaves with the cable's new rate or stays at rest), solved by eliminating ``A`` and a non-negative least
  squares on the Cholesky factor of the Schur complement (:func:`plate_impact`). In one cable:
  ``de+ = m* de-/(m* + m_c)``, ``p = m_c de+``, the plate's momentum: the cable's snap impulse.
* a release: the plate stops, ``1/2 m_c de^2`` is lost, the nodes are not touched.

Every loss is added to ``losses`` (J), so ``energy()["total"] + losses`` is conserved to the integrator's
error; ``energy()["kinetic"]`` includes the moving plates' (:meth:`plate_energy`).

Two implementations of the same arithmetic: the numba kernel ``massive/_kernels.py`` (one step per call; used
unless ``compiled`` is False) and the numpy code below, the plain reference it must match to 1e-12 in tests.
The structure's inverse mass is applied in one place in each, :meth:`MassiveMethod.inverse_mass` and
``_kernels.inverse_mass`` (lumped, diagonal, now; the kernel builds the plates' ``G`` node by node and factors it
once a step, see its docstring). Not available yet (refused at construction with a message): a cable attached
along a strut.

**Rigid struts** (RATTLE, as the elastic method's, with the rods' consistent mass blocks of ``tensegrity_sim.mass``
in ``M``): SHAKE and RATTLE push along the struts through the plate-augmented mass ``(M + sum m_c b_c b_c^T)^-1``
of the cables taut then (:class:`_PlateRigidStruts`: a plate moves with its cable under a strut's push too), and
the closing kick's velocity-dependent forces are corrected at RATTLE's projected velocities (corrected at the
unprojected ones, the energy error measured first order: 4.3e-5, 2.4e-5, 1.2e-5 at 1, 0.5, 0.25 ms; now 1.8e-5,
4.6e-6, 1.2e-6). At a snap the struts' rows join the plates' impact as rows with no plate (``1/m = 0``: their
length rates do not change). Stepped by the numpy reference (the kernel takes no rigid struts).

**A ground and a member contact response** (``methods/contact/friction.py``, ``member.py``): the elastic method's
contact impulses at each half-kick
(``ContactSet.drift_step``: lands every node that would pass the ground exactly on it; ``settle_step``: no node
on it moves into it or slides against friction), exact Coulomb friction, with the velocity problems posed under
the mass matrix of the moment, ``M + sum m_c b_c b_c^T`` over the taut cables whose plates move with them
(:class:`PlateMassSolver`: each plate a node of mass ``m_c`` on an equality row, so that the project's backends
and the frictional solver's mode fixed point, semismooth Newton method and Coulomb checks answer it unchanged).
A scene with contacts is stepped by plain Verlet (order 2), its snaps and releases resolved at the end of the step
they happen in (first order there, as the elastic method's unlocated switches), and by the numpy reference: the
compiled kernel takes no ground yet (``describe()["contacts"]`` says so). The contacts' losses are not in
``losses`` (only the plates'): on the ground ``energy()["total"] + losses`` only falls.

``run()`` steps in the kernel's loop (``massive_steps``, base.py's rule 10); its carry is the start workspace
(positions, velocities and the forces there) and the losses so far, so the simulator rewinds the steps it
computed ahead before an input changes or ``energy_lost`` is read (``carry_outlives_inputs``).
"""
from __future__ import annotations

from types import SimpleNamespace
from typing import NamedTuple

import numpy as np
import scipy.linalg as scipy_linalg
import scipy.sparse as scipy_sparse
from scipy.sparse.csgraph import reverse_cuthill_mckee
from scipy.optimize import nnls

from ...system import System
from ..base import MethodStep, State, StepMethod
from ..contact import _detection_kernels as detection_kernels
from ..contact.friction import ContactSet
from ..qp.solvers import BlockMassSolver, MassWrapper, Rows, make_solver
from ..elastic import _kernels as elastic_kernels
from ..elastic.composition import MIN_SPLIT, STABILITY, WEIGHTS, Stepper, check_stable
from ..elastic.method import ElasticMethod
from ..rigid import _NEWTON_MAX_ITER, _NEWTON_TOL, RigidStruts
from . import _kernels as kernels

__all__ = ["MassiveMethod", "PlateMassSolver", "plate_impact", "BAND"]

# relative to the rest length: a cable this close to its natural length has the switch state of its rate's sign
# (taut when lengthening), so that a located snap (|e| <= LOCATE_TOL L = 1e-13 L) counts as taut and a located
# release as slack on both sides of the step that ends there
BAND = 1e-10


class _Forces(NamedTuple):
    """The step's record at one configuration (the fields the located stepper reads): accelerations (N, 3)
    m/s^2, each cable's force on the structure ``k e + c de + m_c d2e`` (n_cables,) N, member unit vectors
    (m, 3), ``slack`` (n_cables,) bool: not in the switch state taut, elongations (n_cables,) m, elongation
    rates (n_cables,) m/s, ``held`` (n_cables,) bool: the cables taut in ``acc`` (damped, their plates moving with
    them)."""

    acc: np.ndarray
    cable_tensions: np.ndarray
    directions: np.ndarray
    slack: np.ndarray
    elongations: np.ndarray
    rates: np.ndarray
    held: np.ndarray


def plate_impact(g: np.ndarray, rates: np.ndarray, snapping: np.ndarray) -> np.ndarray:
    """The impulses ``p`` (k,) N*s of a plastic impact on the plates: ``g`` (k, k) is ``B M^-1 B^T +
    diag(1/m_c)`` over the cables involved, ``rates`` (k,) their elongation rates before it (m/s), ``snapping``
    (k,) bool the cables whose plates are at rest (the others move with their cables). ``G_A p = 0`` on the
    moving ones and ``0 <= p_S ⟂ G_S p - rates_S >= 0`` on the snapping ones."""
    a, s = np.flatnonzero(~snapping), np.flatnonzero(snapping)
    # eliminate the moving plates' rows: p_A = -G_AA^-1 G_AS p_S; the Schur complement is positive definite
    if len(a):
        coupling = np.linalg.solve(g[np.ix_(a, a)], g[np.ix_(a, s)])
        schur = g[np.ix_(s, s)] - g[np.ix_(s, a)] @ coupling
    else:
        coupling, schur = np.zeros((0, len(s))), g[np.ix_(s, s)]
    # min 1/2 p^T H p - r^T p, p >= 0  ==  min |L^T p - L^-1 r|^2, p >= 0 with H = L L^T
    low = np.linalg.cholesky(0.5 * (schur + schur.T))
    p_s = nnls(low.T, scipy_linalg.solve_triangular(low, rates[s], lower=True))[0]
    p = np.empty(len(rates))
    p[s], p[a] = p_s, -coupling @ p_s
    return p


class PlateMassSolver(MassWrapper):
    """The contacts' velocity problem (``methods/contact/friction.py``) under the massive method's mass matrix
    ``M + sum_c m_c b_c b_c^T`` over the cables :meth:`hold` names (taut, their plates moving with them),
    answered exactly by the project's backends (``make_solver``, ``BlockMassSolver`` where ``M`` has rods'
    blocks) with every plate a node of its own: mass ``m_c``, velocity ``de_c`` along the cable, held there by
    an equality row ``b_c . v - n_c . u_c = 0`` (the plate rides on its cable). ``min 1/2 |v - v0|_M^2 + 1/2
    sum m_c (de_c - de0_c)^2`` on that row is ``min 1/2 |v - v0|^2`` in the augmented matrix, so the answer
    and the rows' multipliers are those of the augmented-mass QP; the plates' rows' multipliers are the plates'
    momentum changes (the cables' share of the contact impulse). :meth:`inverse` applies ``(M + B^T diag(m_c)
    B)^-1`` by Woodbury's form (``G = B M^-1 B^T + diag(1/m_c)``, the plates' Delassus matrix, factored once per
    :meth:`hold`). ``mass`` (the scale of the contacts' projection form) is each node's ``1 / (M^-1)_pp``."""

    def __init__(self, system: System, plates: np.ndarray, name: str | None = None):
        self.system = system
        fi = np.flatnonzero(system.free)
        self.n_free = len(fi)
        self._fi = fi
        self._index = np.full(system.n_nodes + 1, -1)   # system node -> free index (fixed: -1)
        self._index[fi] = np.arange(len(fi))
        self._massive = np.flatnonzero(plates > 0)      # the cables that carry a plate, in order: its node
        self._plates = plates[self._massive]
        self._slot = np.full(len(plates), -1)           # cable -> its plate (-1: none)
        self._slot[self._massive] = np.arange(len(self._massive))
        op = system.mass
        k = len(self._plates)
        if op.consistent:   # the rods' blocks, and the plates as nodes without one
            aug = SimpleNamespace(diagonal=np.concatenate([op.diagonal, self._plates]),
                                  partner=np.concatenate([op.partner, np.full(k, -1)]),
                                  cross=np.concatenate([op.cross, np.zeros(k)]),
                                  inv_diagonal=np.concatenate([op.inv_diagonal, 1.0 / self._plates]),
                                  inv_cross=np.concatenate([op.inv_cross, np.zeros(k)]),
                                  free=np.concatenate([system.free, np.ones(k, dtype=bool)]))
            self.inner = BlockMassSolver(aug, aug.free, name)
        else:
            self.inner = make_solver(name, np.concatenate([system.masses[fi], self._plates]))
        self.name = self.inner.name
        self.inv_mass = np.repeat(op.inv_diagonal[fi], 3)
        self.mass = 1.0 / self.inv_mass
        self.hold(np.zeros(0, dtype=int), np.zeros((0, 3)))

    def hold(self, cables: np.ndarray, directions: np.ndarray) -> None:
        """The cables (k,) whose plates move with them, their unit vectors (k, 3), for the next solves."""
        keep = self._slot[cables] >= 0
        cables, directions = cables[keep], directions[keep]
        k, slot = len(cables), self._slot[cables]
        ends = self._index[self.system.cable_ends[cables]]
        self._held = (cables, directions, ends, slot)
        self._rows = Rows(np.column_stack([ends, self.n_free + slot]), directions, np.zeros(k), k,
                          np.tile([-1.0, 1.0, -1.0], (k, 1)))
        self._factor = None

    def _node_inverse(self, p: np.ndarray) -> np.ndarray:
        """``M^-1 p`` (the structure's, ``System.mass``) for free-node vectors ``p`` (n_free, 3, ...)."""
        full = np.zeros((self.system.n_nodes,) + p.shape[1:])
        full[self._fi] = p
        return self.system.mass.solve(full)[self._fi]

    def _rates(self, v: np.ndarray) -> np.ndarray:
        """``b_c . v`` (k,) of the held cables for free-node velocities ``v`` (n_free, 3)."""
        _, n, ends, _ = self._held
        vv = np.vstack([v, np.zeros((1, 3))])
        return np.einsum("ij,ij->i", vv[ends[:, 1]] - vv[ends[:, 0]], n)

    def inverse(self, p: np.ndarray) -> np.ndarray:
        shape = p.shape
        out = self._node_inverse(p.reshape((self.n_free, 3) + shape[1:]))
        cables, n, ends, slot = self._held
        if len(cables):
            if self._factor is None:   # B (k, n_free, 3), M^-1 B^T and G's Cholesky factor
                k = len(cables)
                b = np.zeros((k, self.n_free + 1, 3))
                b[np.arange(k), np.where(ends[:, 0] < 0, self.n_free, ends[:, 0])] -= n
                b[np.arange(k), np.where(ends[:, 1] < 0, self.n_free, ends[:, 1])] += n
                b = b[:, :-1]
                w = np.moveaxis(self._node_inverse(np.moveaxis(b, 0, -1)), -1, 0)
                g = np.einsum("inj,knj->ik", b, w) + np.diag(1.0 / self._plates[slot])
                self._factor = b, w, scipy_linalg.cho_factor(g)
            b, w, factor = self._factor
            y = scipy_linalg.cho_solve(factor, np.tensordot(b, out, axes=([1, 2], [0, 1])))
            out = out - np.tensordot(w, y, axes=([0], [0]))
        return out.reshape(shape)

    def _augment(self, v: np.ndarray) -> np.ndarray:
        """Free-node velocities ``v`` (n_free, 3) with every plate's (its cable's rate along it; at rest where
        not held): (n_free + plates, 3)."""
        out = np.zeros((self.n_free + len(self._plates), 3))
        out[: self.n_free] = v.reshape(-1, 3)
        cables, n, _, slot = self._held
        out[self.n_free + slot] = self._rates(v.reshape(-1, 3))[:, None] * n
        return out

    def _augment_rows(self, rows: Rows) -> Rows:
        """The plates' equality rows, then ``rows`` (as general rows on the augmented nodes)."""
        if rows.weights is None:
            nodes, weights = rows.nodes, np.tile([-1.0, 1.0], (len(rows), 1))
        else:
            nodes, weights = rows.nodes, rows.weights
        width = max(3, nodes.shape[1])
        pad = width - nodes.shape[1]
        nodes = np.pad(nodes, ((0, 0), (0, pad)), constant_values=-1)
        weights = np.pad(weights, ((0, 0), (0, pad)))
        mine = self._rows
        k = len(mine)
        return Rows(np.vstack([np.pad(mine.nodes, ((0, 0), (0, width - 3)), constant_values=-1), nodes]),
                    np.vstack([mine.directions, rows.directions]), np.concatenate([mine.targets, rows.targets]),
                    k + rows.n_eq, np.vstack([np.pad(mine.weights, ((0, 0), (0, width - 3))), weights]))

    def _augment_multipliers(self, v, y, v0) -> np.ndarray:
        """The plates' rows' multipliers (their momentum changes ``m_c (de - de0)``), then ``y``."""
        slot = self._held[3]
        return np.concatenate([self._plates[slot] * (self._rates(v.reshape(-1, 3)) - self._rates(v0.reshape(-1, 3))),
                               y])

    def solve(self, v0, rows, warm=None):
        k = len(self._rows)
        warm = None if warm is None else np.concatenate([np.ones(k, dtype=bool), warm])
        u, y = self.inner.solve(self._augment(v0), self._augment_rows(rows), warm)
        return u[: self.n_free], y[k:]

    def _check(self, v, y, v0, rows: Rows) -> None:
        self.inner._check(self._augment(v), self._augment_multipliers(v, y, v0), self._augment(v0),
                          self._augment_rows(rows))

    def _residuals_reference(self, v, y, v0, rows: Rows):
        return self.inner._residuals_reference(self._augment(v), self._augment_multipliers(v, y, v0),
                                               self._augment(v0), self._augment_rows(rows))

    def describe(self) -> dict:
        return {**self.inner.describe(), "mass": "cable plates as nodes on equality rows"}


class _PlateRigidStruts(RigidStruts):
    """SHAKE and RATTLE (``methods/rigid.py``) under the plate-augmented mass: a push along a strut moves the nodes
    by ``(M + sum m_c b_c b_c^T)^-1`` (``inverse``: node vectors (N, 3, k) to the same; the plates of the cables
    held then move with them), which couples the struts that a plate or a rod's block joins: SHAKE's lengths by
    Newton's method on all of them (from zero, as the class-k struts' in ``RigidStruts``), RATTLE's rates by one
    dense solve. Without plates held it is ``M^-1`` itself, the rods' blocks included."""

    def __init__(self, system: System, inverse):
        super().__init__(system)
        self._inverse = inverse

    def _responses(self, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Each strut's unit push (``+n`` on its end a, ``-n`` on b, as ``RigidStruts._push``): the nodes' moves
        (N, 3, count) and the struts' vectors' (count, 3, count)."""
        k = np.arange(self.count)
        push = np.zeros((self._system.n_nodes, 3, self.count))
        push[self.ends[:, 0], :, k] += directions
        push[self.ends[:, 1], :, k] -= directions
        moves = self._inverse(push)
        return moves, moves[self.ends[:, 1]] - moves[self.ends[:, 0]]

    def project_positions(self, x_start, x_pred, directions=None):
        n0 = self._system.geometry(x_start, self.ends)[2] if directions is None else directions
        moves, turns = self._responses(n0)
        r = x_pred[self.ends[:, 1]] - x_pred[self.ends[:, 0]]
        gamma = np.zeros(self.count)
        for _ in range(_NEWTON_MAX_ITER):
            r_new = r + np.einsum("idj,j->id", turns, gamma)
            g = np.einsum("ij,ij->i", r_new, r_new) - self.length_sq
            if np.max(np.abs(g) / self.length_sq) < _NEWTON_TOL:
                break
            gamma -= np.linalg.solve(2.0 * np.einsum("id,idj->ij", r_new, turns), g)
        return np.einsum("ndj,j->nd", moves, gamma)

    def project_velocities(self, x, v, directions=None):
        n = self._system.geometry(x, self.ends)[2] if directions is None else directions
        moves, turns = self._responses(n)
        rate = self._system.member_rates(v, n, self.ends)
        mu = np.linalg.solve(np.einsum("id,idj->ij", n, turns), -rate)
        return np.einsum("ndj,j->nd", moves, mu)


class _PlateStepper(Stepper):
    """The elastic method's located stepper with the plates' events resolved where each part ends."""

    def __init__(self, base, events, order: int, system, dt: float, locate: bool):
        super().__init__(base, order, system, dt, locate)
        self.resolve = events


class MassiveMethod(StepMethod):
    """Options: ``order`` 2 (velocity Verlet) or 4 (Suzuki's composition of five), ``locate_switches``
    (default True: snaps, releases and slack/taut switches located inside the step; False: resolved at the
    end of the step they happen in, first order). ``losses`` (J): the plates' energy lost since the reset.
    ``compiled``: step with the numba kernel (True) or the numpy reference (False)."""

    name = "massive"
    options = ("order", "locate_switches")

    def __init__(self, system: System, dt: float, *, order: int = 2, locate_switches: bool | None = None,
                 compiled: bool = True):
        super().__init__(system, dt)
        scene = system.scene
        missing = [c.name for c in scene.cables if c.stiffness is None]
        if missing:
            raise ValueError(f"method 'massive' needs a stiffness for every cable; missing for {missing}")
        if len(system.attached):
            raise ValueError(f"method 'massive' does not take a cable attached along a strut yet (cable "
                             f"{scene.cable_names[system.attached[0]]!r}); use method 'elastic'")
        if isinstance(order, bool) or order not in STABILITY:
            raise ValueError(f"order must be one of {sorted(STABILITY)}, got {order!r}")
        if not (locate_switches is None or isinstance(locate_switches, (bool, np.bool_))):
            raise ValueError(f"locate_switches must be True, False or None (automatic), got {locate_switches!r}")
        contacts = scene.ground is not None or scene.contact_response.response
        if contacts and (order != 2 or locate_switches):
            raise ValueError("method 'massive' steps a scene with a ground or a contact response by plain Verlet, its "
                             "events at the step's end: order 4 and located switches are not available with contacts")
        self.order = int(order)
        self.locate_switches = not contacts if locate_switches is None else bool(locate_switches)
        # the plates only add mass: the massless cables' highest frequency bounds the method's
        self.omega_max = system.max_frequency(scene.positions, include_cables=True)
        check_stable("massive", self.order, self.dt, self.omega_max, "use a smaller dt")
        self.plates = scene.cable_masses
        self._massive = self.plates > 0
        self._damped = bool(np.any(system.cable_damping > 0))
        self._rest = np.empty(system.n_members)
        self._rest[: system.n_struts] = system.strut_rest
        self.stepper = _PlateStepper(self.verlet, self._events, self.order, system, self.dt, self.locate_switches)
        self._cache: _Forces | None = None
        self._step_loss = 0.0
        self.losses = 0.0
        # contacts: the elastic method's contact impulses at each half-kick (ContactSet.drift_step, settle_step),
        # their velocity problems under the plate-augmented mass (PlateMassSolver); stepped by the reference
        self.ground = None
        self._contact = None   # the ground's impulses of the last step (N, 3) N*s, or None
        self._pairs = None     # the member contacts' of the last step (ContactSet.pair_impulses), or None
        # rigid struts: SHAKE/RATTLE under the same mass (the plates held at the projection), in the reference
        self._plate_solver = PlateMassSolver(system, self.plates)
        self.rigid = _PlateRigidStruts(system, self._effective_inverse)
        if contacts:
            self.ground = ContactSet(system, self._plate_solver)
        self.compiled = bool(compiled) and self.ground is None and not self.rigid.count
        # member-contact detection inside the compiled loop (loop_detects), as the elastic method's: the detector
        # whose state it moves on (set by the simulator around advance) and the events of the last advance
        self.detection = None
        self.found = None
        self._no_detection = detection_kernels.no_detection()
        if self.compiled:
            self._set_up_kernel()

    def _set_up_kernel(self) -> None:
        """The kernel's system arrays and workspaces; compiled (or loaded from numba's cache) now, not in the
        first step."""
        sys = self.system
        n, nc, m = sys.n_nodes, sys.n_cables, sys.n_members
        em = elastic_kernels.model_arrays(sys, RigidStruts(sys))   # by name: the elastic model has more fields
        self._model = (em.ends, em.stiffness, em.floor, em.strut_rest, em.damping, em.inv_mass, em.gravity_force,
                       em.rigid_members, np.ascontiguousarray(self.plates), *self._plate_layout(), BAND, self._damped)

        def workspace():
            return (np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty(nc), np.empty((m, 3)),
                    np.empty(nc, dtype=bool), np.empty(nc), np.empty(nc), np.zeros(nc, dtype=bool))

        self._start, self._trial = workspace(), workspace()
        self._scratch = kernels.make_scratch(n, nc, int(np.count_nonzero(self._massive)))
        self._weights = np.array(WEIGHTS[self.order])
        self._fresh = True   # the start workspace's record is not the state's: compute it
        scene = sys.scene
        state = State(scene.positions, scene.velocities, scene.cable_rest_lengths, np.zeros((n, 3)))
        self._step_compiled(state)
        self.advance(state, 1, 1, np.empty((1, n, 3)), np.empty((1, n, 3)), np.empty((1, nc)),
                     np.empty((1, nc), dtype=bool))
        self._fresh, self.losses = True, 0.0

    def _plate_layout(self) -> tuple:
        """The kernel's layout of the plates' ``G`` (its module docstring): a row for every cable that carries a
        plate, in the reverse Cuthill-McKee order of the graph in which two cables sharing a node are joined (so
        that the Cholesky factor's envelope, fixed for the scene, stays narrow), and every such coupling once.
        Returns ``rows`` (nc,) (cable -> row, -1: no plate), ``plated`` (k,) (row -> cable), ``envelope`` (k,)
        (each row's first column), ``pairs`` (P, 3) (row, row before it, node) int64 and ``signs`` (P,) (+1 where
        the node is the same end of both cables, else -1)."""
        ends = self.system.cable_ends
        cables = np.flatnonzero(self._massive)
        k = len(cables)
        shared = [(i, j, node) for i in range(k) for j in range(i + 1, k)
                  for node in sorted(set(ends[cables[i]]) & set(ends[cables[j]]))]
        links = np.array(shared, dtype=np.int64).reshape(-1, 3)
        graph = scipy_sparse.coo_matrix((np.ones(len(links)), (links[:, 0], links[:, 1])), shape=(k, k))
        plated = cables[reverse_cuthill_mckee(graph.tocsr(), symmetric_mode=False)] if k else cables
        rows = np.full(len(ends), -1, dtype=np.int64)
        rows[plated] = np.arange(k)
        pairs = np.empty((len(links), 3), dtype=np.int64)
        signs = np.empty(len(links))
        envelope = np.arange(k, dtype=np.int64)
        for q, (i, j, node) in enumerate(links):
            a, b = rows[cables[i]], rows[cables[j]]
            pairs[q] = max(a, b), min(a, b), node
            signs[q] = 1.0 if (ends[cables[i], 0] == node) == (ends[cables[j], 0] == node) else -1.0
            envelope[max(a, b)] = min(envelope[max(a, b)], min(a, b))
        return rows, plated, envelope, pairs, signs

    def _at_state(self, state: State):
        """The start workspace at ``state``'s positions and velocities (its forces recomputed after an input),
        and the rest lengths and external forces as the kernel takes them."""
        ws = self._start
        ws[0][...], ws[1][...] = state.positions, state.velocities
        rest = np.ascontiguousarray(state.rest_lengths, dtype=float)
        ext = np.ascontiguousarray(state.external_forces, dtype=float)
        if self._fresh:
            kernels.forces(ws[0], ws[1], rest, ext, self._model, self._scratch, False, ws[2:])
            self._fresh = False
        return ws, rest, ext

    def _step_compiled(self, state: State) -> tuple[MethodStep, float]:
        ws, rest, ext = self._at_state(state)
        impulses = np.empty(self.system.n_cables)
        loss = kernels.massive_step(ws, self._trial, self.dt, self._weights, self.locate_switches, MIN_SPLIT * self.dt,
                                    rest, ext, self._model, self.system.masses, self.system.free, self._scratch,
                                    impulses)
        self._start, self._trial = self._trial, ws   # the step's end is the next one's start
        ws = self._start
        return MethodStep(ws[0].copy(), ws[1].copy(), impulses, ws[6] < 0), loss

    # ------------------------------------------------------------------ the mass
    def inverse_mass(self, f: np.ndarray) -> np.ndarray:
        """The structure's ``M^-1`` applied to node vectors ``f`` (N, 3) or (k, N, 3) (forces or impulses): the
        one place this method applies it (``System.mass``; fixed nodes: 0)."""
        if f.ndim == 2:
            return self.system.mass.solve(f)
        return np.moveaxis(self.system.mass.solve(np.moveaxis(f, 0, -1)), -1, 0)

    def _rows(self, ends: np.ndarray, n: np.ndarray) -> np.ndarray:
        """The compatibility vectors ``b`` of members with ``ends`` (k, 2) as node vectors (k, N, 3), ``n`` (k, 3)
        their unit vectors."""
        b = np.zeros((len(ends), self.system.n_nodes, 3))
        k = np.arange(len(ends))
        b[k, ends[:, 0]] -= n
        b[k, ends[:, 1]] += n
        return b

    def _delassus(self, cables: np.ndarray, n: np.ndarray) -> np.ndarray:
        """``G = B M^-1 B^T + diag(1/m_c)`` (k, k) over ``cables`` (dense: the kernel builds it node by node)."""
        b = self._rows(self.system.cable_ends[cables], n)
        return np.einsum("inj,knj->ik", b, self.inverse_mass(b)) + np.diag(1.0 / self.plates[cables])

    # ------------------------------------------------------------------ forces
    def switch_state(self, e: np.ndarray, rate: np.ndarray, rest: np.ndarray) -> np.ndarray:
        """(n_cables,) bool: taut in the sense of the events (a plate on the cable): elongation ``e`` (m)
        above ``BAND`` of the rest length, or within it and lengthening at ``rate`` (m/s)."""
        band = BAND * rest
        return (e > band) | ((e >= -band) & (rate > 0.0))

    def accelerations(self, x: np.ndarray, v: np.ndarray, state: State, held: np.ndarray | None = None) -> _Forces:
        """The forces at ``x``, ``v`` (N, 3): the taut cables (:meth:`switch_state`), or those of ``held``
        (n_cables,) bool where given (the set of the part that ends here: a switch at its end comes after its
        closing kick), damped and with their plates."""
        sys = self.system
        rest = self._rest
        rest[sys.n_struts:] = state.rest_lengths
        _, length, n = sys.geometry(x)
        t = sys.stiffness * np.maximum(length - rest, sys.floor)
        nc = n[sys.n_struts:]
        rate = sys.member_rates(v, nc, sys.cable_ends)
        cables = t[sys.n_struts:]
        e = length[sys.n_struts:] - state.rest_lengths
        taut = self.switch_state(e, rate, state.rest_lengths)
        if held is None:
            held = taut
        if self._damped:
            cables += np.where(held, sys.cable_damping * rate, 0.0)
            np.maximum(cables, 0.0, out=cables)   # a damped cable never pushes
        f = sys.assemble(t[:, None] * n) + sys.gravity_force + state.external_forces
        acc = self.inverse_mass(f)
        tensions = cables.copy()
        plated = np.flatnonzero(held & self._massive)
        if len(plated):
            # the plates' inertial forces y = m_c d2e/dt2: (B M^-1 B^T + diag(1/m_c)) y = B M^-1 f + q
            ends = sys.cable_ends[plated]
            dv = v[ends[:, 1]] - v[ends[:, 0]]
            q = (np.einsum("ij,ij->i", dv, dv) - rate[plated] ** 2) / length[sys.n_struts + plated]
            g = self._delassus(plated, nc[plated])
            rhs = np.einsum("ij,ij->i", acc[ends[:, 1]] - acc[ends[:, 0]], nc[plated]) + q
            y = np.linalg.solve(g, rhs)
            # a = M^-1 (f - B^T y): the plates pull on the nodes as tensions would
            pull = np.zeros_like(t)
            pull[sys.n_struts + plated] = y
            acc = self.inverse_mass(f + sys.assemble(pull[:, None] * n))
            tensions[plated] += y
        return _Forces(acc, tensions, n, ~taut, e, rate, held)

    def verlet(self, x: np.ndarray, v: np.ndarray, start: _Forces, h: float, state: State):
        """One velocity-Verlet step of ``h`` (s) from ``x``, ``v`` (N, 3) with the forces ``start`` at them;
        the velocity-dependent forces at the predicted end velocity, or the closing kick corrected once (module
        docstring). Returns the end positions,
        velocities (N, 3) and forces there."""
        v_half = v + (0.5 * h) * start.acc
        rigid = self.rigid
        if self.ground is not None or rigid.count:   # the plates of the taut cables move with their nodes
            self._hold(start)
        if self.ground is not None:
            v_f = v_half + rigid.project_velocities(x, v_half, start.directions[rigid.members]) \
                if rigid.count else None
            v_half, landing_speed = self.ground.drift_step(x, v, v_half, h, rigid, v_f)
        x_new = x + h * v_half
        if rigid.count:
            dx = rigid.project_positions(x, x_new, start.directions[rigid.members])
            x_new += dx
            v_half += dx / h
        # the taut set of the step's start: a switch at its end (a snap, a release) comes after its closing kick.
        # With plates moving the forces depend on the velocity (their q, damping): evaluated once, at the end
        # velocity the start's acceleration predicts (O(h^2) off, so the kick is second order); with rigid struts
        # or contacts, at the closing kick's own velocity and corrected once (below)
        plated = bool(np.any(start.held & self._massive))
        predict = plated and self.ground is None and not rigid.count
        end = self.accelerations(x_new, v_half + (0.5 * h) * start.acc if predict else v_half, state, start.held)
        if self.ground is not None or rigid.count:
            self._hold(end)

        def close(end):   # the closing kick, and RATTLE's rates (the velocities the forces are corrected at)
            v_new = v_half + (0.5 * h) * end.acc
            if rigid.count:
                v_new += rigid.project_velocities(x_new, v_new, end.directions[rigid.members])
            return v_new

        v_new = close(end)
        if predict:   # the events read the rates at the end velocity
            end = self._rates_at(end, v_new, state)
        elif self._damped or plated:   # forces that depend on the velocity
            end = self.accelerations(x_new, v_new, state, start.held)
            v_new = close(end)
        if self.ground is not None:
            v_new = self.ground.settle_step(x_new, v_new, landing_speed, rigid)
            self._contact, self._pairs = self.ground.take_impulses(), self.ground.take_pair_impulses()
        return x_new, v_new, end

    def _rates_at(self, forces: _Forces, v: np.ndarray, state: State) -> _Forces:
        """``forces`` with its elongation rates and switch states at the velocities ``v`` (N, 3)."""
        sys = self.system
        rate = sys.member_rates(v, forces.directions[sys.n_struts:], sys.cable_ends)
        taut = self.switch_state(forces.elongations, rate, state.rest_lengths)
        return forces._replace(rates=rate, slack=~taut)

    def _hold(self, forces: _Forces) -> None:
        """The contacts' and rigid struts' mass from now: the plates of ``forces``' held cables move with them."""
        cables = np.flatnonzero(forces.held & self._massive)
        self._plate_solver.hold(cables, forces.directions[self.system.n_struts + cables])

    def _effective_inverse(self, f: np.ndarray) -> np.ndarray:
        """``(M + sum m_c b_c b_c^T)^-1`` over the cables held (:meth:`_hold`) for node vectors ``f`` (N, 3, k)."""
        free = self.system.free
        out = np.zeros_like(f)
        out[free] = self._plate_solver.inverse(f[free].reshape(-1, f.shape[-1])).reshape(-1, 3, f.shape[-1])
        return out

    # ------------------------------------------------------------------ events
    def _events(self, part, state: State):
        """The snaps and releases between the part's taut set (its end record's ``held``) and the switch state at
        its end ``part`` (``Stepper.flow``'s tuple), resolved there (``Stepper.resolve``): returns the velocities
        (N, 3), the forces there, and the snap impulses (n_cables,) N*s. The energy they remove is added to
        ``_step_loss``."""
        x, v, end = part[0], part[1], part[2]
        kicks = np.zeros(self.system.n_cables)
        if np.array_equal(end.held, ~end.slack):
            return v, end, kicks
        taut_before, taut_after = end.held & self._massive, ~end.slack & self._massive
        released = taut_before & ~taut_after
        self._step_loss += float(0.5 * np.sum(self.plates[released] * end.rates[released] ** 2))
        snapping = taut_after & ~taut_before
        if not snapping.any():
            return v, self.accelerations(x, v, state), kicks
        sys, rigid = self.system, self.rigid
        involved = np.flatnonzero(taut_after)
        n = end.directions[sys.n_struts + involved]
        rates = end.rates[involved]
        b = self._rows(sys.cable_ends[involved], n)
        g = np.einsum("inj,knj->ik", b, self.inverse_mass(b)) + np.diag(1.0 / self.plates[involved])
        rows_rates, snaps = rates, snapping[involved]
        if rigid.count:   # the rigid struts keep their length rates through the impact: rows without a plate
            dirs = end.directions[rigid.members]
            struts = self._rows(rigid.ends, dirs)
            g = np.block([[g, np.einsum("inj,knj->ik", b, self.inverse_mass(struts))],
                          [np.einsum("inj,knj->ik", struts, self.inverse_mass(b)),
                           np.einsum("inj,knj->ik", struts, self.inverse_mass(struts))]])
            b = np.concatenate([b, struts])
            rows_rates = np.concatenate([rates, sys.member_rates(v, dirs, rigid.ends)])
            snaps = np.concatenate([snaps, np.zeros(rigid.count, dtype=bool)])
        p = plate_impact(g, rows_rates, snaps)
        v = v - self.inverse_mass(np.einsum("k,knj->nj", p, b))
        p = p[: len(involved)]
        after = self.accelerations(x, v, state)
        kept = np.flatnonzero(~after.slack & self._massive)
        # what the impact took: the nodes' kinetic energy and the involved plates' (moving ones before it)
        before = 0.5 * float(np.sum(self.plates[involved] * np.where(snapping[involved], 0.0, rates) ** 2))
        self._step_loss += (self._kinetic(part[1]) + before - self._kinetic(v)
                            - 0.5 * float(np.sum(self.plates[kept] * after.rates[kept] ** 2)))
        kicks[involved] = p
        return v, after, kicks

    def _kinetic(self, v: np.ndarray) -> float:
        return self.system.mass.kinetic_energy(v)

    # ------------------------------------------------------------------ the contract
    def invalidate(self) -> None:
        self._cache = None
        self._fresh = True

    def prepare(self, state: State) -> None:
        """Initial velocities that would stretch a rigid strut lose that component (as the elastic method's), under
        the plate-augmented mass of the cables taut there (their plates moving with them)."""
        self.losses = 0.0
        if self.rigid.count:
            forces = self.accelerations(state.positions, state.velocities, state)
            self._hold(forces)
            state.velocities = state.velocities + self.rigid.project_velocities(
                state.positions, state.velocities, forces.directions[self.rigid.members])
            self._cache = None

    def _step_impl(self, state: State) -> MethodStep:
        if self.compiled:
            out, loss = self._step_compiled(state)
            self.losses += loss
            return out
        return self._step_reference(state)

    @property
    def carry_outlives_inputs(self) -> bool:
        """The loop's carry holds the losses, which no input rebuilds: the simulator rewinds before reading them."""
        return self.compiled

    def has_loop(self) -> bool:
        return self.compiled

    def loop_detects(self) -> bool:
        return self.compiled

    def advance(self, state: State, steps: int, every: int, positions: np.ndarray, velocities: np.ndarray,
                impulses: np.ndarray, slack: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ws, rest, ext = self._at_state(state)
        loss, self.found = kernels.massive_steps(ws, self._trial, self.dt, steps, every, self._weights,
                                                 self.locate_switches, MIN_SPLIT * self.dt, rest, ext, self._model,
                                                 self.system.masses, self.system.free, self._scratch, positions,
                                                 velocities, impulses, slack, self._no_detection
                                                 if self.detection is None else self.detection.state)
        self.losses += loss
        return ws[0].copy(), ws[1].copy()

    def carry(self):
        """The start workspace (None after an input: recomputed from the state) and the losses so far."""
        return (None if self._fresh else tuple(a.copy() for a in self._start)), self.losses

    def restore(self, carry) -> None:
        ws, self.losses = carry
        self._fresh = ws is None
        if ws is not None:
            for a, b in zip(self._start, ws):
                a[...] = b

    def retrace(self, state: State) -> MethodStep | None:
        if not self.compiled:
            return None
        self._cache = None
        return self._step_reference(state)

    def _step_reference(self, state: State) -> MethodStep:
        x, v = state.positions, state.velocities
        start = self._cache if self._cache is not None else self.accelerations(x, v, state)
        self._step_loss = 0.0
        x_new, v_new, end, impulses = self.stepper.step(x, v, start, self.dt, state)
        self._cache = end
        self.losses += self._step_loss
        return MethodStep(x_new, v_new, impulses, end.elongations < 0, self._contact, self._pairs)

    def plate_energy(self, positions: np.ndarray, velocities: np.ndarray, rest_lengths: np.ndarray) -> float:
        """The moving plates' kinetic energy ``sum 1/2 m_c de_c^2`` over the taut cables (J)."""
        sys = self.system
        _, length, n = sys.geometry(positions, sys.cable_ends)
        rate = sys.member_rates(velocities, n, sys.cable_ends)
        moving = self.switch_state(length - rest_lengths, rate, rest_lengths) & self._massive
        return float(0.5 * np.sum(self.plates[moving] * rate[moving] ** 2))

    strain_energy = ElasticMethod.strain_energy   # the same springs: k max(0, e) on cables, k e on struts

    def describe(self) -> dict:
        out = {"method": self.name, "dt": self.dt, "order": self.order, "locate_switches": self.locate_switches}
        if self.ground is not None:
            out["contacts"] = "numpy reference (the compiled kernel takes no ground yet)"
        return out
