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
method's velocity Verlet (``verlet``), whose closing kick is corrected once where the forces depend on the
velocity (damping, the plates' ``q``): ``v1 = v_half + h/2 a(x, v_half)``, then ``a(x, v1)``, second order.
With nothing velocity-dependent it is the elastic method's arithmetic.

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
once a step, see its docstring). Not available yet (refused at construction with a message):
rigid struts (RATTLE's projections would need the plate-augmented mass), a ground and a member contact
response.

``run()`` steps in the kernel's loop (``massive_steps``, base.py's rule 10); its carry is the start workspace
(positions, velocities and the forces there) and the losses so far, so the simulator rewinds the steps it
computed ahead before an input changes or ``energy_lost`` is read (``carry_outlives_inputs``).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.linalg as scipy_linalg
import scipy.sparse as scipy_sparse
from scipy.sparse.csgraph import reverse_cuthill_mckee
from scipy.optimize import nnls

from ...system import System
from ..base import MethodStep, State, StepMethod
from ..elastic import _kernels as elastic_kernels
from ..elastic.composition import MIN_SPLIT, STABILITY, WEIGHTS, Stepper, check_stable
from ..elastic.method import ElasticMethod
from ..rigid import RigidStruts
from . import _kernels as kernels

__all__ = ["MassiveMethod", "plate_impact", "BAND"]

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
        rigid = [s.name for s in scene.struts if s.rigid]
        if rigid:
            raise ValueError(f"method 'massive' does not take rigid struts yet ({', '.join(rigid)}); give them a "
                             f"stiffness, or use method 'elastic' or 'inextensible'")
        if scene.ground is not None or scene.contact_response.response:
            raise ValueError("method 'massive' does not take a ground or a member contact response yet; use method "
                             "'elastic' or 'inextensible'")
        if len(system.attached):
            raise ValueError(f"method 'massive' does not take a cable attached along a strut yet (cable "
                             f"{scene.cable_names[system.attached[0]]!r}); use method 'elastic'")
        if isinstance(order, bool) or order not in STABILITY:
            raise ValueError(f"order must be one of {sorted(STABILITY)}, got {order!r}")
        if not (locate_switches is None or isinstance(locate_switches, (bool, np.bool_))):
            raise ValueError(f"locate_switches must be True, False or None (automatic), got {locate_switches!r}")
        self.order = int(order)
        self.locate_switches = True if locate_switches is None else bool(locate_switches)
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
        self.compiled = bool(compiled)
        if self.compiled:
            self._set_up_kernel()

    def _set_up_kernel(self) -> None:
        """The kernel's system arrays and workspaces; compiled (or loaded from numba's cache) now, not in the
        first step."""
        sys = self.system
        n, nc, m = sys.n_nodes, sys.n_cables, sys.n_members
        em = elastic_kernels.model_arrays(sys, RigidStruts(sys))   # by name: the elastic model has more fields
        self._model = (em.ends, em.stiffness, em.floor, em.strut_rest, em.damping, em.inv_mass, em.gravity_force,
                       em.rigid_members, np.ascontiguousarray(self.plates), *self._couplings(), BAND, self._damped)

        def workspace():
            return (np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty(nc), np.empty((m, 3)),
                    np.empty(nc, dtype=bool), np.empty(nc), np.empty(nc), np.zeros(nc, dtype=bool))

        self._start, self._trial = workspace(), workspace()
        self._scratch = (np.empty((n, 3)), np.empty(nc, dtype=np.int64), np.empty(nc * nc),
                         np.empty(nc, dtype=np.int64), np.empty(nc), np.empty((n, 3)), np.empty((n, 3)),
                         np.empty((n, 3)), np.empty(nc), np.empty(nc), np.empty(nc),
                         np.empty(nc, dtype=np.int64), np.empty(nc), np.empty(nc), np.empty(nc))
        self._weights = np.array(WEIGHTS[self.order])
        self._fresh = True   # the start workspace's record is not the state's: compute it
        scene = sys.scene
        state = State(scene.positions, scene.velocities, scene.cable_rest_lengths, np.zeros((n, 3)))
        self._step_compiled(state)
        self.advance(state, 1, 1, np.empty((1, n, 3)), np.empty((1, n, 3)), np.empty((1, nc)),
                     np.empty((1, nc), dtype=bool))
        self._fresh, self.losses = True, 0.0

    def _couplings(self) -> tuple[np.ndarray, np.ndarray]:
        """The plates' ``G`` couples two cables at a node they share: every such pair once, (P, 3) int64 (cable,
        cable, node), for the kernel's sparse build of it; and the cables in the reverse Cuthill-McKee order of
        that graph (nc,) int64, the order of ``G``'s rows that keeps its Cholesky factor in a narrow band."""
        ends = self.system.cable_ends
        nc = len(ends)
        rows = [(i, k, node) for i in range(nc) for k in range(i + 1, nc) for node in set(ends[i]) & set(ends[k])]
        pairs = np.array(rows, dtype=np.int64).reshape(-1, 3)
        graph = scipy_sparse.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(nc, nc))
        order = reverse_cuthill_mckee(graph.tocsr(), symmetric_mode=False)
        return pairs, np.ascontiguousarray(order, dtype=np.int64)

    def _at_state(self, state: State):
        """The start workspace at ``state``'s positions and velocities (its forces recomputed after an input),
        and the rest lengths and external forces as the kernel takes them."""
        ws = self._start
        ws[0][...], ws[1][...] = state.positions, state.velocities
        rest = np.ascontiguousarray(state.rest_lengths, dtype=float)
        ext = np.ascontiguousarray(state.external_forces, dtype=float)
        if self._fresh:
            kernels.forces(ws[0], ws[1], rest, ext, *self._model, False, False, ws[2:], *self._scratch[:5],
                           *self._scratch[6:8], *self._scratch[11:13])
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

    def _rows(self, cables: np.ndarray, n: np.ndarray) -> np.ndarray:
        """The compatibility vectors ``b_c`` of ``cables`` (k,) as node vectors (k, N, 3), ``n`` (k, 3) their
        unit vectors."""
        ends = self.system.cable_ends[cables]
        b = np.zeros((len(cables), self.system.n_nodes, 3))
        k = np.arange(len(cables))
        b[k, ends[:, 0]] -= n
        b[k, ends[:, 1]] += n
        return b

    def _delassus(self, cables: np.ndarray, n: np.ndarray) -> np.ndarray:
        """``G = B M^-1 B^T + diag(1/m_c)`` (k, k) over ``cables`` (dense: the kernel builds it node by node)."""
        b = self._rows(cables, n)
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
        the closing kick corrected once where the forces depend on the velocity. Returns the end positions,
        velocities (N, 3) and forces there."""
        v_half = v + (0.5 * h) * start.acc
        x_new = x + h * v_half
        # the taut set of the step's start: a switch at its end (a snap, a release) comes after its closing kick
        end = self.accelerations(x_new, v_half, state, start.held)
        v_new = v_half + (0.5 * h) * end.acc
        if self._damped or np.any(start.held & self._massive):   # forces that depend on the velocity
            end = self.accelerations(x_new, v_new, state, start.held)
            v_new = v_half + (0.5 * h) * end.acc
        return x_new, v_new, end

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
        involved = np.flatnonzero(taut_after)
        n = end.directions[self.system.n_struts + involved]
        g = self._delassus(involved, n)
        rates = end.rates[involved]
        p = plate_impact(g, rates, snapping[involved])
        v = v - self.inverse_mass(np.einsum("k,knj->nj", p, self._rows(involved, n)))
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
        self.losses = 0.0

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

    def advance(self, state: State, steps: int, every: int, positions: np.ndarray, velocities: np.ndarray,
                impulses: np.ndarray, slack: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ws, rest, ext = self._at_state(state)
        self.losses += kernels.massive_steps(ws, self._trial, self.dt, steps, every, self._weights,
                                             self.locate_switches, MIN_SPLIT * self.dt, rest, ext, self._model,
                                             self.system.masses, self.system.free, self._scratch, positions,
                                             velocities, impulses, slack)
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
        return MethodStep(x_new, v_new, impulses, end.elongations < 0)

    def plate_energy(self, positions: np.ndarray, velocities: np.ndarray, rest_lengths: np.ndarray) -> float:
        """The moving plates' kinetic energy ``sum 1/2 m_c de_c^2`` over the taut cables (J)."""
        sys = self.system
        _, length, n = sys.geometry(positions, sys.cable_ends)
        rate = sys.member_rates(velocities, n, sys.cable_ends)
        moving = self.switch_state(length - rest_lengths, rate, rest_lengths) & self._massive
        return float(0.5 * np.sum(self.plates[moving] * rate[moving] ** 2))

    strain_energy = ElasticMethod.strain_energy   # the same springs: k max(0, e) on cables, k e on struts

    def describe(self) -> dict:
        return {"method": self.name, "dt": self.dt, "order": self.order, "locate_switches": self.locate_switches}
