"""DAQP's own C entry point ``daqp_quadprog`` called from numba kernels, without its Python wrapper.

``daqp.solve`` (the Cython wrapper) fills three C structs and calls ``daqp_quadprog``; of the ~60 us a
call of the icosahedron's QP costs through it, the solve itself is a few us (one iteration from the warm
start) and the rest is the wrapper's argument handling. The extension module exports its C API, so
:func:`quadprog` fills the same structs with the same inputs and calls the same function: the answer is
``daqp.solve``'s to the last bit (``test/test_daqp_kernels.py`` holds it to that on random and degenerate
problems), which matters on a locked structure, whose multipliers are not unique (``qp.py``).

The struct layouts are those of DAQP 0.11.0's ``types.h`` and ``api.h`` (x86-64 and aarch64: ``int`` 4
bytes, pointers and ``double`` 8, natural alignment), which is why setup.py pins daqp to 0.11.0:

* ``DAQPProblem`` (80 bytes): ``int n, m, ms``, then the pointers ``H, f, A, bupper, blower, sense,
  break_points`` and ``int nh, problem_type``;
* ``DAQPSettings`` (136 bytes, :class:`Settings`), made by ``daqp_default_settings`` (the defaults
  ``daqp.solve`` uses) with the caller's tolerances written over them;
* ``DAQPResult`` (64 bytes): ``double *x, *lam; double fval, soft_slack; int exitflag, iter, nodes;
  double solve_time, setup_time``.
"""
from __future__ import annotations

import ctypes

import numpy as np
from numba import njit

from .._c_calls import quadprog_at
from ._qp_kernels import dense_rows, sticking_answer, working_set_answer

__all__ = ["Settings", "entry_point", "quadprog", "solve_rows", "solve_pairs"]

class Settings(ctypes.Structure):
    """DAQP 0.11.0's ``DAQPSettings``."""

    _fields_ = [("primal_tol", ctypes.c_double), ("dual_tol", ctypes.c_double), ("zero_tol", ctypes.c_double),
                ("pivot_tol", ctypes.c_double), ("progress_tol", ctypes.c_double), ("cycle_tol", ctypes.c_int),
                ("iter_limit", ctypes.c_int), ("fval_bound", ctypes.c_double), ("eps_prox", ctypes.c_double),
                ("eta_prox", ctypes.c_double), ("rho_soft", ctypes.c_double), ("rel_subopt", ctypes.c_double),
                ("abs_subopt", ctypes.c_double), ("sing_tol", ctypes.c_double), ("refactor_tol", ctypes.c_double),
                ("time_limit", ctypes.c_double), ("w_soft", ctypes.c_double), ("eq_reduction", ctypes.c_int),
                ("presolve", ctypes.c_int)]


# where DAQP's tolerances sit in the settings struct, in doubles (working_set_answer uses them)
_PRIMAL_TOL, _DUAL_TOL, _SING_TOL = (getattr(Settings, name).offset // 8
                                     for name in ("primal_tol", "dual_tol", "sing_tol"))


def entry_point(daqp_module, settings: dict):
    """The address of ``daqp_quadprog`` in the imported ``daqp_module`` (what :func:`quadprog` calls,
    ``_c_calls.py``), and the settings struct as bytes (uint8 array): DAQP's defaults with ``settings``
    (name: value) over them."""
    library = ctypes.CDLL(daqp_module.__file__)
    defaults = library.daqp_default_settings
    defaults.restype = None
    struct = Settings()
    defaults(ctypes.byref(struct))
    for name, value in settings.items():
        setattr(struct, name, value)
    raw = np.frombuffer(bytes(struct), dtype=np.uint8).copy()
    return ctypes.cast(library.daqp_quadprog, ctypes.c_void_p).value, raw


@njit(cache=True)
def quadprog(entry, settings, hessian, f, a, bupper, blower, sense):
    """``daqp.solve(hessian, f, a, bupper, blower, sense, **settings)``: ``entry`` and ``settings`` from
    :func:`entry_point`; ``hessian`` (n, n), ``f`` (n,), ``a`` (k, n) C-contiguous, ``bupper``,
    ``blower`` (k,), ``sense`` (k,) int32 (DAQP may write to it). Returns ``x`` (n,), ``lam`` (k,), the
    exit flag and the iterations."""
    n = f.shape[0]
    m = bupper.shape[0]
    x = np.empty(n)
    lam = np.empty(m)
    problem = np.zeros(10, dtype=np.int64)
    problem[0] = n | (m << 32)             # int n, int m
    problem[1] = m - a.shape[0]            # int ms (0: every row is a row of A), padding
    problem[2] = hessian.ctypes.data
    problem[3] = f.ctypes.data
    if m:
        problem[4] = a.ctypes.data
        problem[5] = bupper.ctypes.data
        problem[6] = blower.ctypes.data
        problem[7] = sense.ctypes.data
    result = np.zeros(8, dtype=np.int64)   # break_points, nh and problem_type stay 0 (a plain QP)
    result[0] = x.ctypes.data
    if m:
        result[1] = lam.ctypes.data
    quadprog_at(entry, result, problem, settings)
    flags = result.view(np.int32)          # int exitflag, iter at bytes 32 and 36
    return x, lam, flags[8], flags[9]


@njit(cache=True)
def solve_rows(entry, settings, hessian, sqrt_mass, mass, nodes, directions, n_free, v0, targets, n_eq, warm, unit,
               guess):
    """``DaqpSolver._solve`` of member rows (``_qp_kernels``' layout: ``nodes`` (k, 2), ``directions``
    (k, 3), ``targets`` (k,) m/s, the first ``n_eq`` equalities), built and scaled as there: free
    velocities ``v0`` (3 n_free,) m/s, ``sqrt_mass`` and ``mass`` (3 n_free,) kg^1/2 and kg,
    ``hessian`` the identity, ``warm`` (k,) bool the rows to start active, the problem divided by
    ``unit`` m/s. With ``guess``, the working set ``warm`` is tried first
    (``_qp_kernels.working_set_answer``, at DAQP's ``primal_tol`` and ``dual_tol``, its pivots at
    ``sing_tol``, read from ``settings``); DAQP only when it is not the active set. Returns ``v``
    (3 n_free,) m/s, the multipliers (k,) N*s, DAQP's exit flag and iterations (1 and 0 for the working
    set's answer), and the working set's Cholesky factor and rows (empty when DAQP answered: see
    ``_self_stress_kernels.locked_space``, which refines with the factor)."""
    k = targets.shape[0]
    if guess:
        tolerances = settings.view(np.float64)
        # at unit scale (every compiled step's) the problem as given: dividing and multiplying by 1.0 changes
        # no bit, and the guess writes to none of its arguments
        same = unit == 1.0
        guessed, v, y, factor, rows = working_set_answer(
            nodes, directions, (1.0 / mass).reshape((n_free, 3)), (v0 if same else v0 / unit).reshape((n_free, 3)),
            targets if same else targets / unit, n_eq, warm, tolerances[_PRIMAL_TOL], tolerances[_DUAL_TOL],
            tolerances[_SING_TOL])
        if guessed:
            if not same:
                v, y = v * unit, unit * y
            return v.reshape(-1), y, 1, 0, factor, rows
    bupper = targets / unit
    a = dense_rows(nodes, directions, n_free, sqrt_mass)
    lower = np.full(k, -1e30)
    sense = np.empty(k, dtype=np.int32)
    for i in range(k):
        sense[i] = 5 if i < n_eq else np.int32(warm[i])
        if i < n_eq:
            lower[i] = targets[i] / unit
    f = -sqrt_mass * (v0 / unit)
    z, lam, flag, iterations = quadprog(entry, settings, hessian, f, a, bupper, lower, sense)
    return (z / sqrt_mass) * unit, unit * lam, flag, iterations, np.zeros((0, 0)), np.zeros(0, dtype=np.int64)


@njit(cache=True)
def solve_pairs(settings, mass, nodes, directions, v0, targets, n_eq, start, opposite):
    """The answer of rows with sign-free pairs (``_qp_kernels.sticking_answer``: the equality rows and the rows
    ``start`` (k,) bool as the working set, ``opposite`` (k,) int each pair's other row) at DAQP's
    ``primal_tol``, ``dual_tol`` and ``sing_tol`` read from ``settings``, for ``v0`` (n_free, 3) m/s and
    ``mass`` (3 n_free,) kg. Returns whether it is the QP's answer (else the caller asks DAQP), ``v``
    (3 n_free,) m/s and the multipliers (k,) N*s."""
    n_free = v0.shape[0]
    tolerances = settings.view(np.float64)
    ok, v, y = sticking_answer(nodes, directions, (1.0 / mass).reshape((n_free, 3)), v0, targets, n_eq, start,
                               opposite, tolerances[_PRIMAL_TOL], tolerances[_DUAL_TOL], tolerances[_SING_TOL])
    return ok, v.reshape(-1), y
