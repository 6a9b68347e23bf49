"""The plain numpy implementation of ``_friction_block_kernels.py``'s block solvers (the same algorithm and
arithmetic: the semismooth Newton with Levenberg–Marquardt damping on the Alart–Curnier form of one
block's frictional contact problem, a strut's block or a coupled one; see that module's docstring), the
reference the compiled kernels must match to 1e-12 in tests."""
from __future__ import annotations

import numpy as np

from ._friction_block_kernels import (_ARMIJO, _DAMPING_GROWTH, _MAX_DAMPING, _MIN_DAMPING, _MIN_STEP,
                                      _NEWTON_PIVOT, BLOCK_TOL, MAX_NEWTON, RELAXED_TOL)

__all__ = ["solve_block_reference", "solve_coupled_reference", "lone_contact_reference"]


def lone_contact_reference(inv: float, v: np.ndarray, target: float, mu: float):
    """A node on no rigid strut: ``(v + inv z, z)`` with ``z = (f_x, f_y, y_n)`` N*s (the closed form of
    ``lone_contact``) for its velocity ``v`` (3,) m/s."""
    m = 1.0 / inv
    y = max(0.0, m * (target - v[2]))
    f = -m * v[:2]
    size = np.hypot(*f)
    if size > mu * y:
        f = f * (mu * y / size)
    z = np.array([f[0], f[1], y])
    return v + inv * z, z


def _residual(s, k, rho, target, mu, w, u0, z):
    """``phi`` (q,), its generalised Jacobian (q, q) and ``|phi|^2 / 2`` (the kernel's ``_residual`` and
    ``_jacobian``, which it computes only where the Newton steps: the same numbers)."""
    q = len(z)
    u = u0 + w @ z
    phi = np.empty(q)
    jac = np.zeros((q, q))
    eye = np.eye(q)
    phi[:s] = rho[:s] * u[:s]
    jac[:s] = rho[:s, None] * w[:s]
    for c in range(k):
        o = s + 3 * c
        r, n, t = rho[o], o + 2, slice(o, o + 2)
        qn = z[n] - r * (u[n] - target[c])
        yp = max(qn, 0.0)
        phi[n] = z[n] - yp
        dyp = eye[n] - r * w[n] if qn > 0.0 else np.zeros(q)
        jac[n] = eye[n] - dyp
        qt = z[t] - r * u[t]
        dqt = eye[t] - r * w[t]
        size = np.hypot(*qt)
        bound = mu[c] * yp
        if size <= bound:
            phi[t] = z[t] - qt
            jac[t] = eye[t] - dqt
        else:
            hat = qt / size
            phi[t] = z[t] - bound * hat
            jac[t] = eye[t] - ((bound / size) * (dqt - np.outer(hat, hat @ dqt)) + np.outer(hat, mu[c] * dyp))
    return phi, jac, 0.5 * float(phi @ phi)


def _sticking(s, k, rho, target, mu, u, z) -> bool:
    """Whether every contact sticks at ``z`` (``u`` its rows' velocities): the kernel's ``_sticking``."""
    for c in range(k):
        o = s + 3 * c
        r, n = rho[o], o + 2
        qn = z[n] - r * (u[n] - target[c])
        if not (qn > 0.0 and np.hypot(z[o] - r * u[o], z[o + 1] - r * u[o + 1]) <= mu[c] * qn):
            return False
    return True


def _definite(a: np.ndarray, floor: float) -> bool:
    """Whether the kernel's ``L D L^T`` factorisation (``_factor_solve``, the same operations in the same
    order) of the symmetric ``a`` (q, q) finds every pivot above ``floor`` times its diagonal entry. (The two
    matrices agree to round-off, so where a pivot is at the floor's level the twin and the kernel may decide
    differently.)"""
    q = len(a)
    low = np.zeros((q, q))
    pivots = np.zeros(q)
    scaled = np.zeros(q)
    for j in range(q):
        d = a[j, j]
        for p in range(j):
            scaled[p] = low[j, p] * pivots[p]
            d -= low[j, p] * scaled[p]
        if not d > floor * a[j, j]:
            return False
        pivots[j] = d
        inverse = 1.0 / d
        for i in range(j + 1, q):
            e = a[i, j]
            for p in range(j):
                e -= low[i, p] * scaled[p]
            low[i, j] = e * inverse
    return True


def _strut_contact_solve(w, rho, r):
    """The kernel's ``_strut_contact_solve``: ``W^-1 r`` for a strut's block with one ground contact, by
    eliminating the contact's rows, or None where ``S`` is not comfortably positive."""
    b = w[0, 1:4]
    schur = w[0, 0] - rho[1] * (b[0] * b[0] + b[1] * b[1] + b[2] * b[2])
    if not schur > _NEWTON_PIVOT * w[0, 0]:
        return None
    d0 = (r[0] - rho[1] * (b[0] * r[1] + b[1] * r[2] + b[2] * r[3])) / schur
    return np.concatenate([[d0], rho[1] * (r[1:4] - b * d0)])


def _newton(s, k, rho, target, mu, w, u0, z, scale, ground):
    """The kernel's ``_newton`` from ``z`` (q,): ``(z, iterations)``, ``-1`` unsolved."""
    q = len(z)
    tol = BLOCK_TOL * scale
    phi, jac, merit = _residual(s, k, rho, target, mu, w, u0, z)
    for it in range(MAX_NEWTON + 1):
        if np.abs(phi).max() <= tol:
            return z, it
        if it == MAX_NEWTON:
            break
        u = u0 + w @ z
        step = None
        if _sticking(s, k, rho, target, mu, u, z):   # the sticking mode's linear system: W d = t - u
            goal = np.zeros(q)
            goal[s + 2::3] = target[:k]
            if ground and s == 1 and k == 1:
                step = _strut_contact_solve(w, rho, goal - u)
            elif _definite(w, _NEWTON_PIVOT):
                step = np.linalg.solve(w, goal - u)
        tried = step is not None
        accepted = False
        if tried:
            trial = z + step
            new = _residual(s, k, rho, target, mu, w, u0, trial)[2]
            accepted = new <= merit + _ARMIJO * (-2.0 * merit)
        gram = jac.T @ jac
        if not accepted and not tried and _definite(gram, _NEWTON_PIVOT):
            # Newton's own step, whole, where it decreases the merit enough (unless it is the step just tried)
            d = np.linalg.solve(gram, -(jac.T @ phi))
            trial = z + d
            new = _residual(s, k, rho, target, mu, w, u0, trial)[2]
            accepted = new <= merit + _ARMIJO * float((jac.T @ phi) @ d)
        if not accepted:
            nu = min(2.0 * merit / (scale * scale), _MAX_DAMPING) + _MIN_DAMPING
            normal = gram + nu * np.eye(q)
            definite = _definite(normal, 0.0)
            while not definite and nu < _MAX_DAMPING:
                nu = min(nu * _DAMPING_GROWTH, _MAX_DAMPING)
                normal = gram + nu * np.eye(q)
                definite = _definite(normal, 0.0)
            if not definite:
                break
            d = np.linalg.solve(normal, -(jac.T @ phi))
            slope = float((jac.T @ phi) @ d)
            step = 1.0
            while True:
                trial = z + step * d
                new = _residual(s, k, rho, target, mu, w, u0, trial)[2]
                if new <= merit + _ARMIJO * step * slope or step <= _MIN_STEP:
                    break
                step *= 0.5
        z = trial
        phi, jac, merit = _residual(s, k, rho, target, mu, w, u0, z)
    return z, (MAX_NEWTON if np.abs(phi).max() <= RELAXED_TOL * scale else -1)


def solve_block_reference(inv: np.ndarray, strut: bool, direction: np.ndarray, ends: np.ndarray,
                          target: np.ndarray, mu: float, v: np.ndarray, z: np.ndarray):
    """``solve_block``'s answer, returned instead of written in place: ``(v, z, iterations)`` (``-1``:
    unsolved, ``v`` unchanged); the arguments as there, ``z`` (1 + 3k or 3k,) the warm start."""
    s, k = int(bool(strut)), len(ends)
    q = s + 3 * k
    g = np.zeros((q, 6))
    if s:
        g[0, :3], g[0, 3:] = -direction, direction
    for c in range(k):
        g[s + 3 * c: s + 3 * c + 3, 3 * ends[c]: 3 * ends[c] + 3] = np.eye(3)
    # the coupled block's arithmetic is the strut's (a ground row's W_nn is its end's inverse mass exactly);
    # ``inv`` (3,): the ends' diagonal entries of M^-1 and its cross entry
    inv = np.asarray(inv, dtype=float)
    return _solve_rows(np.stack([inv[:2], [inv[2]] * 2], axis=1), g, s, k, target, np.full(k, mu), v, z, True)


def solve_coupled_reference(inv: np.ndarray, g: np.ndarray, s: int, k: int, target: np.ndarray, mu: np.ndarray,
                            v: np.ndarray, z: np.ndarray):
    """``solve_coupled``'s answer, returned instead of written in place: ``(v, z, iterations)`` (``-1``:
    unsolved, ``v`` unchanged); ``inv`` (nb, 2) (``M^-1``'s diagonal and, for the ``2 s`` struts' ends, the cross
    entry with the other end), ``g`` (s + 3k, 3 nb), ``v`` (nb, 3), ``z`` (s + 3k,) the warm start, the rest as
    there."""
    return _solve_rows(inv, g, s, k, target, mu, v, z, False)


def _solve_rows(inv, g, s, k, target, mu, v, z, ground):
    """The answer of :func:`solve_coupled_reference` (its arguments); ``ground``: a strut's block of
    :func:`solve_block_reference` (the kernel's ``_newton``'s)."""
    q = s + 3 * k
    nb = len(inv)
    g = g[:q, : 3 * nb]
    z = np.array(z[:q], dtype=float)
    inverse = np.diag(np.repeat(inv[:, 0], 3))
    for i in range(0, 2 * s, 2):
        inverse[3 * i: 3 * i + 3, 3 * i + 3: 3 * i + 6] = inverse[3 * i + 3: 3 * i + 6, 3 * i: 3 * i + 3] = \
            inv[i, 1] * np.eye(3)
    u0 = g @ v.ravel()
    w = g @ inverse @ g.T
    inv = inv[:, 0]
    moving = inv > 0
    scale = max(1e-300, float(np.max(np.abs(v[moving]) / inv[moving, None], initial=0.0)))
    rho = np.empty(q)
    rho[:s] = 1.0 / np.diag(w)[:s]
    for c in range(k):
        o = s + 3 * c
        rho[o: o + 3] = 1.0 / w[o + 2, o + 2]
        scale = max(scale, abs(target[c]) * rho[o], float(np.abs(z[o: o + 3]).max()))
    z[:s] = -(u0[:s] + w[:s, s:] @ z[s:]) / np.diag(w)[:s]
    z, it = _newton(s, k, rho, target, np.asarray(mu, dtype=float), w, u0, z, scale, ground)
    if it < 0:
        return v.copy(), z, -1
    return (v.ravel() + inverse @ (g.T @ z)).reshape(-1, 3), z, it
