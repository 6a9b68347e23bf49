"""Reference solutions of the elastic-cable model (physics.md §4) by scipy's DOP853, restarted at
every slack/taut switch, and the step-halving limit of any simulator.

Between switches the elastic model is a smooth ODE: with the set of taut cables held fixed, every
tension is ``k (l - L)``, a smooth function of the positions. A fixed-step scheme integrates across the
kink of ``k max(0, l - L)``; here each switch is located by an event (DOP853's dense output, root found
to round-off) and the integration restarts from it with the new set, so the 8th-order method keeps its
order and the tolerance means what it says.

Rigid struts are holonomic constraints ``|x_b - x_a| = L``. They are enforced at the acceleration level
(the index-1 form): at every right-hand-side evaluation the strut tensions ``lambda`` solve
``(W o n n^T) lambda = n . (d2 x_b - d2 x_a)_free + |v_b - v_a|^2 / l`` with ``W = S M^-1 S^T``, an
independent formulation of what RATTLE does in the simulator. The constraint drifts only by the ODE
solver's error (reported as ``strut_drift``).

The state vector is ``[x (3N), v (3N), I (n_cables)]`` where ``I`` is each cable's impulse ``int t dt``
since ``t = 0`` (N*s), so the impulse is integrated to the same tolerance as the motion.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

import tensegrity_sim as ts
from tensegrity_sim.system import System

__all__ = ["Final", "ElasticReference"]

_SWITCH_BIAS = 1e-14   # relative to the rest length, see ElasticReference._events


@dataclass(frozen=True)
class Final:
    """A state at the final time: positions, velocities (N, 3) m, m/s (velocities None where not
    needed); impulses (n_cables,) N*s summed over the run. ``switches``: slack/taut switches located
    (reference only; -1 if not counted)."""

    positions: np.ndarray
    velocities: np.ndarray | None
    impulses: np.ndarray
    switches: int = -1


class ElasticReference:
    """The elastic model of ``scene`` as an ODE for ``solve_ivp``; :meth:`solve` integrates it."""

    def __init__(self, scene: ts.Scene):
        sys = System(scene)
        if np.any(sys.cable_damping > 0):
            raise ValueError("ElasticReference: cable damping is not modelled (the reference is for undamped scenes)")
        if np.any(np.isnan(sys.stiffness[sys.n_struts:])):
            raise ValueError("ElasticReference: every cable needs a stiffness")
        self.scene, self.system = scene, sys
        self.n, self.nc = sys.n_nodes, sys.n_cables
        elastic = ~sys.rigid
        self._elastic_ends = sys.strut_ends[elastic]
        self._elastic_k = sys.stiffness[: sys.n_struts][elastic]
        self._elastic_rest = sys.strut_rest[elastic]
        moving = sys.inv_mass[sys.strut_ends[:, 0]] + sys.inv_mass[sys.strut_ends[:, 1]] > 0
        self._rigid_ends = sys.strut_ends[sys.rigid & moving]
        self._rigid_rest = sys.strut_rest[sys.rigid & moving]
        inc = np.asarray(sys.incidence_matrix(self._rigid_ends).todense()) if sys.sparse \
            else sys.incidence_matrix(self._rigid_ends)
        self._rigid_inc = inc                                    # (N, nr): +1 at a, -1 at b
        self._w = inc.T @ (sys.inv_mass[:, None] * inc)          # W = S M^-1 S^T, (nr, nr)
        self._member_ends = np.vstack([self._elastic_ends, sys.cable_ends])
        self._inc = np.asarray(sys.incidence_matrix(self._member_ends).todense()) if sys.sparse \
            else sys.incidence_matrix(self._member_ends)
        self._k = np.concatenate([self._elastic_k, sys.stiffness[sys.n_struts:]])
        self._rest = np.concatenate([self._elastic_rest, scene.cable_rest_lengths])
        self._ns = len(self._elastic_ends)

    # ----------------------------------------------------------------------- the ODE
    def _rhs(self, y: np.ndarray, taut: np.ndarray) -> np.ndarray:
        n, sys = self.n, self.system
        x = y[: 3 * n].reshape(n, 3)
        v = y[3 * n: 6 * n].reshape(n, 3)
        d = x[self._member_ends[:, 1]] - x[self._member_ends[:, 0]]
        length = np.sqrt(np.einsum("ij,ij->i", d, d))
        t = self._k * (length - self._rest)
        t[self._ns:] *= taut                                       # the fixed active set of this segment
        f = self._inc @ ((t / length)[:, None] * d) + sys.gravity_force
        a = sys.inv_mass[:, None] * f
        if len(self._rigid_ends):
            ends = self._rigid_ends
            r = x[ends[:, 1]] - x[ends[:, 0]]
            lr = np.sqrt(np.einsum("ij,ij->i", r, r))
            nr = r / lr[:, None]
            dv = v[ends[:, 1]] - v[ends[:, 0]]
            rhs = np.einsum("ij,ij->i", nr, a[ends[:, 1]] - a[ends[:, 0]]) + np.einsum("ij,ij->i", dv, dv) / lr
            lam = np.linalg.solve(self._w * (nr @ nr.T), rhs)
            a = a + sys.inv_mass[:, None] * (self._rigid_inc @ (lam[:, None] * nr))
        return np.concatenate([v.ravel(), a.ravel(), t[self._ns:]])

    def _cable_state(self, y: np.ndarray):
        """Cable elongations (nc,) m and elongation rates (nc,) m/s of state ``y``."""
        n, ends = self.n, self.system.cable_ends
        x = y[: 3 * n].reshape(n, 3)
        v = y[3 * n: 6 * n].reshape(n, 3)
        d = x[ends[:, 1]] - x[ends[:, 0]]
        length = np.linalg.norm(d, axis=1)
        return length - self.scene.cable_rest_lengths, np.einsum("ij,ij->i", d, v[ends[:, 1]] - v[ends[:, 0]]) / length

    def _taut(self, y: np.ndarray) -> np.ndarray:
        """Which cables are taut from state ``y`` on: elongation > 0, or, within 1e-9 of the rest length
        (where the dense output that located a switch is only accurate to the tolerance), elongating."""
        e, rate = self._cable_state(y)
        near = np.abs(e) <= 1e-9 * self.scene.cable_rest_lengths
        return np.where(near, rate > 0, e > 0).astype(float)

    # ----------------------------------------------------------------------- integration
    def initial_state(self) -> np.ndarray:
        s = self.scene
        return np.concatenate([s.positions.ravel(), s.velocities.ravel(), np.zeros(self.nc)])

    def _elongation(self, c: int, y: np.ndarray) -> float:
        ends = self.system.cable_ends[c]
        xa, xb = y[3 * ends[0]: 3 * ends[0] + 3], y[3 * ends[1]: 3 * ends[1] + 3]
        return float(np.linalg.norm(xb - xa)) - self.scene.cable_rest_lengths[c]

    def _rate(self, c: int, y: np.ndarray) -> float:
        n, ends = self.n, self.system.cable_ends[c]
        d = y[3 * ends[1]: 3 * ends[1] + 3] - y[3 * ends[0]: 3 * ends[0] + 3]
        w = y[3 * (n + ends[1]): 3 * (n + ends[1]) + 3] - y[3 * (n + ends[0]): 3 * (n + ends[0]) + 3]
        return float(d @ w)

    def _events(self, taut: np.ndarray) -> list:
        """Per cable: a terminal event at its switch (a taut cable can only go slack, and back), and a
        recording event at every extremum of its length (for the excursions between two steps)."""
        events = []
        for c in range(self.nc):
            # biased by 1e-14 L to the far side, so that a restart exactly at a switch (elongation 0.0)
            # cannot fire again at once; it delays a switch by 1e-14 L / rate, nothing measurable
            bias = _SWITCH_BIAS * self.scene.cable_rest_lengths[c] * (1.0 if taut[c] else -1.0)

            def switch(_t, y, c=c, bias=bias):
                return self._elongation(c, y) + bias
            switch.terminal, switch.direction = True, -1.0 if taut[c] else 1.0
            events.append(switch)
        for c in range(self.nc):
            def extremum(_t, y, c=c):
                return self._rate(c, y)
            extremum.terminal = False
            events.append(extremum)
        return events

    def _missed_switch(self, sol, taut: np.ndarray, t_start: float):
        """The earliest switch that happened between two of DOP853's steps and came back before the next
        (a length extremum on the wrong side of the rest length), as (time, cable), or None."""
        found = None
        for c in range(self.nc):
            last = t_start
            bias = _SWITCH_BIAS * self.scene.cable_rest_lengths[c] * (1.0 if taut[c] else -1.0)

            def switch(s, c=c, bias=bias):
                return self._elongation(c, sol.sol(s)) + bias
            for te, ye in zip(sol.t_events[self.nc + c], sol.y_events[self.nc + c]):
                g = self._elongation(c, ye) + bias
                if (g > 0) != bool(taut[c]):
                    # between the previous extremum and this one the length is monotone: one root (none if
                    # the segment started on the wrong side within the switch tolerance of _taut)
                    same_side = (switch(last) > 0) == (g > 0)
                    root = last if same_side else brentq(switch, last, te, xtol=1e-15, rtol=1e-15)
                    if found is None or root < found[0]:
                        found = (root, c)
                    break
                last = te
        return found

    def solve(self, t_end: float, *, rtol: float = 1e-12, atol: float = 1e-12, max_step: float | None = None,
              max_switches: int = 100_000) -> Final:
        """Integrate from the scene's initial state to ``t_end`` (s) and return the final state.

        Switches are events: scipy finds them from sign changes between DOP853's steps, so a cable that
        goes taut and slack again within one step would be missed (on the thrown icosahedron unbounded
        steps missed two, a 7e-7 m final error). Every extremum of every cable's length is therefore
        recorded too; an extremum on the wrong side of the rest length reveals such an excursion, whose
        start is then found on the dense output and the integration restarted there. Two extrema of one
        cable within one step are excluded by ``max_step`` (s), by default ``0.1 / omega_max`` (all
        cables counted taut). The initial velocities must already respect rigid struts (no component
        along a strut), as the simulator's ``prepare`` makes them (see ``bench.cases.rigid_consistent``).
        """
        if max_step is None:
            omega = self.system.max_frequency(self.scene.positions, include_cables=True)
            max_step = 0.1 / omega if omega > 0 else np.inf
        y = self.initial_state()
        self._check_rigid_velocities(y)
        t, switches = 0.0, 0
        taut = self._taut(y)
        while True:
            sol = solve_ivp(lambda _t, yy: self._rhs(yy, taut), (t, t_end), y, method="DOP853", rtol=rtol,
                            atol=atol, max_step=max_step, events=self._events(taut), dense_output=True)
            if sol.status == -1:
                raise RuntimeError(f"ElasticReference: DOP853 failed at t={sol.t[-1]!r}: {sol.message}")
            missed = self._missed_switch(sol, taut, t)
            if missed is not None:
                t, fired = missed
                y = sol.sol(t)
            elif sol.status == 1:
                fired = next(c for c, times in enumerate(sol.t_events[: self.nc]) if len(times))
                y, t = sol.y[:, -1], sol.t[-1]
            else:
                y = sol.y[:, -1]
                break
            was = taut[fired]
            taut = self._taut(y)        # cables switching at the same instant are caught here
            taut[fired] = 1.0 - was     # the one whose event fired has crossed, whatever round-off says
            switches += 1
            if switches > max_switches:
                raise RuntimeError(f"ElasticReference: more than {max_switches} switches before t={t_end}")
        n = self.n
        return Final(y[: 3 * n].reshape(n, 3).copy(), y[3 * n: 6 * n].reshape(n, 3).copy(),
                     y[6 * n:].copy(), switches)

    def strut_drift(self, final: Final) -> float:
        """Largest relative length error of a rigid strut at ``final`` (0 without rigid struts)."""
        if not len(self._rigid_ends):
            return 0.0
        x = final.positions
        length = np.linalg.norm(x[self._rigid_ends[:, 1]] - x[self._rigid_ends[:, 0]], axis=1)
        return float(np.max(np.abs(length / self._rigid_rest - 1.0)))

    def _check_rigid_velocities(self, y: np.ndarray) -> None:
        if not len(self._rigid_ends):
            return
        n, ends = self.n, self._rigid_ends
        x = y[: 3 * n].reshape(n, 3)
        v = y[3 * n: 6 * n].reshape(n, 3)
        r = x[ends[:, 1]] - x[ends[:, 0]]
        rate = np.einsum("ij,ij->i", r, v[ends[:, 1]] - v[ends[:, 0]]) / np.linalg.norm(r, axis=1)
        scale = np.max(np.abs(v)) + 1e-300
        if np.max(np.abs(rate)) > 1e-12 * scale:
            raise ValueError("ElasticReference: initial velocities stretch a rigid strut; remove that component "
                             "first (see bench.cases.rigid_consistent)")
