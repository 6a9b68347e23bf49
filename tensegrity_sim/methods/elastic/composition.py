"""Accuracy options of the elastic method, built only from its primitive ``verlet(x, v, start, h, state)``:
one velocity-Verlet/RATTLE step of any size ``h`` returning the end positions, velocities and forces.
This is the plain numpy reference; ``_composition_kernels.py`` is the same arithmetic compiled (numba),
which tests require to match it to 1e-12.

**Order 4: a symmetric composition.** A step of ``h`` is five Verlet steps of ``w_i h`` with Suzuki's
weights ``(w, w, 1 - 4w, w, w)``, ``w = 1 / (4 - 4^(1/3))`` (Hairer, Lubich & Wanner, *Geometric
Numerical Integration*, II.4). Every stage is symplectic, time-reversible and applies equal-and-opposite
member forces, so the composition is too: momentum stays exact, rigid struts hold their length, and
the error is O(h^4). Suzuki rather than Yoshida's triple jump ``(1.35, -1.70, 1.35)``: its stages never leave the step's
interval (the partial sums of the weights stay in [0, 1]), so a part that ends at a located switch never
looks beyond it; Yoshida's first stage overshoots by 35 % and crosses the switch (bungee, 2 s at 1 ms:
1.4e-6 m against Suzuki's 2.9e-12 m, measured). Its largest weight is 0.66 instead of 1.70, and its
stability interval on a harmonic oscillator is ``omega h < 2.72`` instead of 1.57 (``STABILITY``).

**Located switches.** The cable force ``k max(0, e)`` has a kink where a cable goes slack or taut. A step
containing the kink has a local error O(h^2 theta (1 - theta)) that depends on where in the step it falls:
the global error stays O(h^2) for Verlet but the ratio of errors between two step sizes scatters (1.5 to
44 on the bungee), and order 4 drops to 2. So a step whose end differs from its start in some cable's
slack/taut state is split at the switch:

1. *Where.* For each cable that changed, the switch time is the root of its elongation on the Verlet
   position polynomial ``x + t v + t^2 a / 2`` (safeguarded Newton, bracketed by the step): exact for
   Verlet without rigid struts, O(h^3) otherwise. The earliest root is refined with Newton's method on
   the step itself, ``e(flow(s)) = 0``, the slope being the cable's rate at the trial end (for the
   composition it is exact to O(s^4), so two iterations reach ``LOCATE_TOL``).
2. *Split.* The step goes to the switch (where the cable's force is zero on both sides), then on; each
   part sees a smooth force, so it keeps its order. At most ``MAX_SWITCHES`` splits per step; a switch
   closer than ``MIN_SPLIT`` (relative to ``dt``) to a part's start or end is left in it (its error,
   ``k |de/dt| (MIN_SPLIT dt)^2``, is below round-off).
3. *Cost.* Only steps that contain a switch pay: a trial step, usually one located part (Verlet) or two
   to three (order 4, rigid struts), and the rest of the step.

What it gives up: the split step's size depends on the state, so the step map is symplectic in pieces
but not as a whole; when the step does not resolve the fastest vibration the energy random-walks
(measured in ``methods/elastic/method.py``: locate at order 2 only where ``omega_max dt <= 0.2``). A cable that goes taut and slack again inside one step (a graze) is not
split: both its ends are on the same side.
"""
from __future__ import annotations

import numpy as np

__all__ = ["WEIGHTS", "STABILITY", "Stepper", "check_stable", "MAX_SWITCHES", "MIN_SPLIT", "LOCATE_TOL"]

_SUZUKI_W = 1.0 / (4.0 - 4.0 ** (1.0 / 3.0))
# the stage weights of one step, per order
WEIGHTS = {2: (1.0,), 4: (_SUZUKI_W, _SUZUKI_W, 1.0 - 4.0 * _SUZUKI_W, _SUZUKI_W, _SUZUKI_W)}


# omega_max * dt must stay below this: the largest omega h at which the composed Verlet map of a harmonic
# oscillator keeps |trace| < 2 (Verlet: 2 exactly; Suzuki's composition: 2.7218..., rounded down;
# test_composition.py::test_stability_limits computes both)
STABILITY = {2: 2.0, 4: 2.72}

MAX_SWITCHES = 4      # located splits per step
MIN_SPLIT = 1e-6      # relative to dt: a switch this close to a part's ends is not split off
LOCATE_TOL = 1e-13    # relative to the rest length: a located switch leaves |e| below this
_POLY_ITER = 8        # safeguarded Newton iterations on the position polynomial (quadratic convergence)
_FLOW_ITER = 6        # Newton iterations on the step itself (0 for Verlet without rigid struts)


def check_stable(name: str, order: int, dt: float, omega_max: float, advice: str) -> None:
    """Refuse a step ``dt`` (s) beyond the stability limit of the explicit method ``name`` composed to ``order``,
    ``omega_max`` (rad/s) that of its stiffest members, with a ValueError ending with ``advice``."""
    limit = STABILITY[order]
    if omega_max * dt >= limit:
        raise ValueError(
            f"dt={dt!r} s is beyond the stability limit of the explicit {name} method (order {order}): dt must be < "
            f"{limit:g}/omega_max = {limit / omega_max:.6g} s (omega_max = {omega_max:.6g} rad/s from the stiffest "
            f"members); {advice}")


class Stepper:
    """One step of the elastic method from the primitive ``base(x, v, start, h, state) -> (x, v, end)``:
    composed to ``order``, split at slack/taut switches when ``locate``.

    ``start``/``end`` are the primitive's force records (``acc`` (N, 3), ``cable_tensions``,
    ``elongations`` (n_cables,), ``directions`` (m, 3), ``slack`` (n_cables,) bool)."""

    def __init__(self, base, order: int, system, dt: float, locate: bool):
        self.base = base
        self.weights = WEIGHTS[order]
        self.locate = locate
        self.min_split = MIN_SPLIT * dt
        self._ends = system.cable_ends
        self._first_cable = system.n_struts   # cables' rows in the member arrays

    def flow(self, x, v, start, h, state):
        """The composed step of ``h`` (s): end positions, velocities (N, 3), end forces, and each
        cable's impulse over it (n_cables,) N*s (each stage's trapezoidal ``w h (t_0 + t_1) / 2``)."""
        impulses = 0.0
        for w in self.weights:
            x, v, end = self.base(x, v, start, w * h, state)
            impulses = impulses + (0.5 * w * h) * (start.cable_tensions + end.cable_tensions)
            start = end
        return x, v, start, impulses

    def step(self, x, v, start, h, state):
        """One step of ``h`` (s), split at the switches inside it; returns what :meth:`flow` does."""
        trial = self.flow(x, v, start, h, state)
        impulses, remaining = 0.0, h
        for _ in range(MAX_SWITCHES if self.locate else 0):
            changed = trial[2].slack != start.slack
            if not changed.any():
                break
            cable, guess = self._first_switch(x, v, start, trial[2], changed, remaining, state.rest_lengths)
            if cable < 0:
                break
            s, part = self._locate(x, v, start, cable, guess, remaining, state)
            v, start, kicks = self.resolve(part, state)
            x = part[0]
            impulses = impulses + part[3] + kicks
            remaining -= s
            trial = self.flow(x, v, start, remaining, state)
        # a switch not located (none, a graze, one at a part's very end) is resolved at the step's end
        v, end, kicks = self.resolve(trial, state)
        return trial[0], v, end, impulses + trial[3] + kicks

    def resolve(self, part, state):
        """What happens where a part (a :meth:`flow` tuple) ends: its velocities (N, 3), forces and impulses
        (n_cables,) N*s. Massless cables: nothing (the massive method's plates take impacts there)."""
        return part[1], part[2], 0.0

    def _first_switch(self, x, v, start, end, changed, span, rest):
        """The cable (index, or -1) whose switch comes first among ``changed`` ones, and its time (s)
        from ``x`` on the position polynomial ``x + t v + t^2 acc / 2`` within ``(0, span)``."""
        cables = np.flatnonzero(changed)
        ends = self._ends[cables]
        d = x[ends[:, 1]] - x[ends[:, 0]]
        u = v[ends[:, 1]] - v[ends[:, 0]]
        a = start.acc[ends[:, 1]] - start.acc[ends[:, 0]]
        rest2 = rest[cables] ** 2
        e0, e1 = start.elongations[cables], end.elongations[cables]
        # first guess: the elongation interpolated linearly between the ends of the trial
        t = span * e0 / (e0 - e1)
        g0 = np.einsum("ij,ij->i", d, d) - rest2
        p = d + span * u + (0.5 * span * span) * a
        bracketed = (np.einsum("ij,ij->i", p, p) - rest2) * g0 <= 0
        lo, hi = np.zeros_like(t), np.full_like(t, span)
        for _ in range(_POLY_ITER):
            p = d + t[:, None] * u + (0.5 * t * t)[:, None] * a
            g = np.einsum("ij,ij->i", p, p) - rest2
            slope = 2.0 * np.einsum("ij,ij->i", p, u + t[:, None] * a)
            same = g * g0 > 0
            lo = np.where(same, t, lo)
            hi = np.where(same, hi, t)
            with np.errstate(divide="ignore", invalid="ignore"):
                t_new = t - g / slope
            inside = (t_new > lo) & (t_new < hi)
            t = np.where(bracketed, np.where(inside, t_new, 0.5 * (lo + hi)), t)
        valid = (t > self.min_split) & (t < span - self.min_split)
        if not valid.any():
            return -1, 0.0
        k = int(np.argmin(np.where(valid, t, np.inf)))
        return int(cables[k]), float(t[k])

    def _locate(self, x, v, start, cable, s, span, state):
        """Newton's method on ``e_cable(flow(s)) = 0`` for ``s`` in ``(0, span)``, from ``s``, the slope
        being the cable's elongation rate at the part's end; bisection where Newton leaves the bracket
        (the cable's state differs at 0 and ``span``). Returns ``s`` (s) and the part's :meth:`flow`."""
        e0 = start.elongations[cable]
        a, b = self._ends[cable]
        tol = LOCATE_TOL * state.rest_lengths[cable]
        lo, hi = 0.0, span
        for _ in range(_FLOW_ITER):
            part = self.flow(x, v, start, s, state)
            e = part[2].elongations[cable]
            if abs(e) <= tol:
                break
            if e * e0 > 0:
                lo = s
            else:
                hi = s
            rate = float(part[2].directions[self._first_cable + cable] @ (part[1][b] - part[1][a]))
            s_new = s - e / rate if rate != 0.0 else lo
            s = s_new if lo < s_new < hi else 0.5 * (lo + hi)
        else:
            part = self.flow(x, v, start, s, state)
        return s, part
