"""The semismooth Newton method of ``friction.py``'s ``FrictionalSolver._newton`` compiled: the Alart–Curnier
equation ``Phi(r)`` with its generalised Jacobian (:func:`alart_curnier`) and Newton's descent on it with the
Armijo line search and the Levenberg–Marquardt steps (:func:`newton_descend`), for a problem already
reduced to its Delassus matrix (``friction.py``'s ``alart_curnier`` and ``newton_descend`` are the plain
numpy reference: the same arithmetic, tests hold the two to 1e-12).

Why: the Newton method answers a friction solve whose modes cycle (a body rocking on an edge, its two
sticking contacts sharing an indeterminate friction). In numpy each evaluation of ``Phi`` costs ~0.1 ms of
array calls on 30–40 unknowns and Newton's line search makes a dozen of them per iteration: measured on
the inextensible roll of ``examples/roll.yaml`` (``bench/roll_cost.py``), 148 Newton solves took 0.73 s of the
run's 1.76 s, in a median of 1 iteration and at most 12.

The unknowns ``r = (y, f)``: ``y`` the multipliers of the ``n_rows`` method rows (the first ``n_eq`` of them
equalities) then of one normal row per contact, ``f`` (k, 2) each contact's friction; ``free_rates`` the rows'
rates at ``r = 0`` less their targets, ``delassus`` (n, n) the rates' change per unit of ``r``, ``rho`` (n,)
each row's effective mass, ``mu`` (k,) the friction coefficients.
"""
from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["alart_curnier", "newton_descend"]


@njit(cache=True)
def alart_curnier(r, mu, free_rates, delassus, rho, n_eq, n_rows, k):
    """``Phi(r)`` (n,) and its generalised Jacobian (n, n) (``friction.alart_curnier``)."""
    n = r.shape[0]
    n_qp = n_rows + k
    res = free_rates + delassus @ r
    phi = np.empty(n)
    jac = np.zeros((n, n))
    for i in range(n_eq):
        phi[i] = rho[i] * res[i]
        for j in range(n):
            jac[i, j] = rho[i] * delassus[i, j]
    for i in range(n_eq, n_qp):
        trial = r[i] + rho[i] * res[i]
        phi[i] = r[i] - max(trial, 0.0)
        if trial > 0:
            for j in range(n):
                jac[i, j] = -rho[i] * delassus[i, j]
        else:
            jac[i, i] = 1.0
    dz = np.empty((2, n))
    for c in range(k):
        a = n_qp + 2 * c
        b = a + 1
        nr = n_rows + c
        s = r[nr] + rho[nr] * res[nr]
        radius = mu[c] * max(s, 0.0)
        z0 = r[a] - rho[a] * res[a]
        z1 = r[b] - rho[b] * res[b]
        for j in range(n):
            dz[0, j] = -rho[a] * delassus[a, j]
            dz[1, j] = -rho[b] * delassus[b, j]
        dz[0, a] += 1.0
        dz[1, b] += 1.0
        size = np.sqrt(z0 * z0 + z1 * z1)
        out = size > radius
        d0 = z0 / max(size, 1e-300)
        d1 = z1 / max(size, 1e-300)
        if out:
            phi[a] = r[a] - radius * d0
            phi[b] = r[b] - radius * d1
            scale = radius / max(size, 1e-300)
            b00, b01, b10, b11 = 1.0 - d0 * d0, 0.0 - d0 * d1, 0.0 - d1 * d0, 1.0 - d1 * d1
        else:
            phi[a] = r[a] - z0
            phi[b] = r[b] - z1
            scale = 1.0
            b00, b01, b10, b11 = 1.0, 0.0, 0.0, 1.0
        lifting = out and s > 0
        m0 = mu[c] * d0
        m1 = mu[c] * d1
        for j in range(n):
            p0 = scale * (b00 * dz[0, j] + b01 * dz[1, j])
            p1 = scale * (b10 * dz[0, j] + b11 * dz[1, j])
            if lifting:
                ds = rho[nr] * delassus[nr, j] + (1.0 if j == nr else 0.0)
                p0 += m0 * ds
                p1 += m1 * ds
            jac[a, j] = -p0
            jac[b, j] = -p1
        jac[a, a] += 1.0
        jac[b, b] += 1.0
    return phi, jac


@njit(cache=True)
def _within(r, phi, tol, impulse_scale):
    """Whether ``max |Phi|`` is within a tenth of ``tol`` (a fraction) of the larger of ``impulse_scale`` and
    ``max |r|`` (``friction.py``'s ``within``)."""
    largest = 0.0
    for i in range(r.shape[0]):
        largest = max(largest, abs(r[i]))
    worst = 0.0
    for i in range(phi.shape[0]):
        worst = max(worst, abs(phi[i]))
    return worst <= 0.1 * (tol * max(impulse_scale, largest))


@njit(cache=True)
def newton_descend(r, mu, iterations, free_rates, delassus, rho, n_eq, n_rows, k, tol, impulse_scale, line_search,
                   dampings):
    """Newton from ``r`` until ``|Phi|`` (friction coefficients ``mu``) is within ``tol`` of the impulse
    scale (a tenth of it: :func:`_within`) or stops falling, in at most ``iterations``: ``r``, its iterations
    (``friction.newton_descend``). Each iteration takes the least-squares Newton step with an Armijo line
    search of ``line_search`` halvings on ``|Phi|^2 / 2``, else Levenberg–Marquardt steps damped tenfold more
    up to ``dampings`` times; where neither descends, ``r`` is a stationary point of the merit."""
    n = r.shape[0]
    rcond = np.finfo(np.float64).eps * n   # numpy's lstsq default (rcond=None)
    phi, jac = alart_curnier(r, mu, free_rates, delassus, rho, n_eq, n_rows, k)
    merit = 0.5 * (phi @ phi)
    trial, trial_phi, trial_jac, trial_merit = r, phi, jac, merit
    for it in range(1, iterations + 1):
        if _within(r, phi, tol, impulse_scale):
            return r, it - 1
        found = False
        step = np.linalg.lstsq(jac, -phi, rcond)[0]
        alpha = 1.0
        for _ in range(line_search):
            trial = r + alpha * step
            trial_phi, trial_jac = alart_curnier(trial, mu, free_rates, delassus, rho, n_eq, n_rows, k)
            trial_merit = 0.5 * (trial_phi @ trial_phi)
            if trial_merit <= (1.0 - 2e-4 * alpha) * merit:
                found = True
                break
            alpha *= 0.5
        if not found:
            gradient = jac.T @ phi
            gram = jac.T @ jac
            damping = 1e-10 * max(np.trace(gram) / n, 1e-300)
            for _ in range(dampings):
                trial = r - np.linalg.solve(gram + damping * np.eye(n), gradient)
                trial_phi, trial_jac = alart_curnier(trial, mu, free_rates, delassus, rho, n_eq, n_rows, k)
                trial_merit = 0.5 * (trial_phi @ trial_phi)
                if trial_merit < merit:
                    found = True
                    break
                damping *= 10.0
        if not found:
            return r, it
        r, phi, jac, merit = trial, trial_phi, trial_jac, trial_merit
    return r, iterations
