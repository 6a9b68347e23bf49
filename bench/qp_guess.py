"""A compiled warm-started QP path against DAQP, on the QPs the inextensible method solves (issue 10).

Run: ``python bench/qp_guess.py [--steps N]``.

The alternative measured: guess the active set from the hint the method passes (the rows that held in
the previous sub-step), solve the equality-constrained problem of that guess in numba (Delassus matrix
``W_GG = A_G M^-1 A_G^T``, Cholesky, ``y_G = W_GG^-1 (A_G v0 - r_G)``, ``v = v0 - M^-1 A_G^T y_G``) and
keep it only when it meets the optimality conditions (no row outside the guess violated beyond
1e-12 m/s relative, no guessed inequality row pulling). Each QP of a run is captured, then solved by
DAQP (``DaqpSolver._solve`` plus the compiled answer check, as the method does) and by the guess, in
turn; printed: the CPU time per QP of each, the share of QPs the guess answers, and how far its
answers are from DAQP's (velocity, relative to the largest free velocity; multipliers, relative to the
largest). Scenes: the thrown icosahedron with rigid struts (locked: its rows carry a self-stress, so
``W_GG`` is nearly singular) and the built-in prism with elastic struts, rattling (not locked).
"""
from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np
from numba import njit

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))   # run as a script: this checkout first

import tensegrity_sim as ts  # noqa: E402
from bench.bench_steps import agitated  # noqa: E402
from bench.cases import work_precision_cases  # noqa: E402
from tensegrity_sim.methods import _qp_kernels as kernels  # noqa: E402


@njit(cache=True)
def guess_solve(v0, nodes, directions, targets, n_eq, inv_mass, active, tol):
    """The guess ``active`` (k,) bool solved exactly and checked: ``(ok, v (n_free, 3), y (k,))``."""
    k = targets.shape[0]
    n_free = v0.shape[0]
    g = np.flatnonzero(active)
    a = kernels.dense_rows(nodes[g], directions[g], n_free, np.ones(3 * n_free))
    m = g.shape[0]
    w = (a * inv_mass) @ a.T
    rhs = a @ v0.ravel() - targets[g]
    # Cholesky W = L L^T and the two triangular solves, in loops (30 rows: no LAPACK call pays off)
    low = np.zeros((m, m))
    for j in range(m):
        d = w[j, j]
        for p in range(j):
            d -= low[j, p] * low[j, p]
        if not d > 0.0:   # not positive definite: dependent guessed rows
            return False, v0, np.zeros(k)
        low[j, j] = np.sqrt(d)
        for i in range(j + 1, m):
            s = w[i, j]
            for p in range(j):
                s -= low[i, p] * low[j, p]
            low[i, j] = s / low[j, j]
    z = np.empty(m)
    for i in range(m):
        s = rhs[i]
        for p in range(i):
            s -= low[i, p] * z[p]
        z[i] = s / low[i, i]
    y_g = np.empty(m)
    for i in range(m - 1, -1, -1):
        s = z[i]
        for p in range(i + 1, m):
            s -= low[p, i] * y_g[p]
        y_g[i] = s / low[i, i]
    v = v0.ravel() - inv_mass * (a.T @ y_g)
    y = np.zeros(k)
    y[g] = y_g
    v3 = v.reshape(n_free, 3)
    rates = kernels.row_rates(v3, nodes, directions)
    scale = max(np.abs(v0).max(), np.abs(targets).max())
    for i in range(k):
        if not active[i] and rates[i] - targets[i] > tol * scale + 1e-12:
            return False, v3, y
        if active[i] and i >= n_eq and y[i] < -tol * np.abs(y).max():
            return False, v3, y
    return True, v3, y


def captured_qps(scene, steps):
    """The (v0, rows, warm) of every QP of ``steps`` steps of ``scene`` (inextensible, dt = 1 ms)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sim = ts.Simulator(scene, method="inextensible", dt=1e-3, contacts=())
    solver = sim._method.solver
    qps = []
    original = solver.solve

    def capture(v0, rows, warm=None):
        qps.append((v0.copy(), type(rows)(rows.nodes.copy(), rows.directions.copy(), rows.targets.copy(), rows.n_eq),
                    None if warm is None else warm.copy()))
        return original(v0, rows, warm)
    solver.solve = capture
    sim.run(steps=steps, callback=lambda k, r: None)
    solver.solve = original
    return solver, qps


def measure(name, scene, steps):
    solver, qps = captured_qps(scene, steps)
    inv_mass = solver.inv_mass
    for v0, rows, warm in qps[:2]:   # compile
        guess_solve(v0, rows.nodes, rows.directions, rows.targets, rows.n_eq, inv_mass, warm, 1e-12)
    answered, dv, dy = 0, 0.0, 0.0
    t_daqp = t_guess = 0.0
    for v0, rows, warm in qps:
        start = time.process_time()
        v, y = solver.solve(v0, rows, warm)
        t_daqp += time.process_time() - start
        start = time.process_time()
        ok, vg, yg = guess_solve(v0, rows.nodes, rows.directions, rows.targets, rows.n_eq, inv_mass, warm, 1e-12)
        t_guess += time.process_time() - start
        if ok:
            answered += 1
            dv = max(dv, float(np.abs(vg - v).max() / max(np.abs(v0).max(), 1e-300)))
            dy = max(dy, float(np.abs(yg - y).max() / max(np.abs(y).max(), 1e-300)))
    n = len(qps)
    print(f"{name}: {n} QPs; DAQP + check {1e6 * t_daqp / n:.1f} us/QP, compiled guess {1e6 * t_guess / n:.1f} us/QP; "
          f"guess answered {answered / n:.0%}; against DAQP: velocity {dv:.1e}, multipliers {dy:.1e} (relative)")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=500)
    args = parser.parse_args(argv)
    icosahedron = next(c for c in work_precision_cases() if c.name == "icosahedron_thrown").scene
    measure("icosahedron thrown (rigid struts, locked)", icosahedron, args.steps)
    measure("prism3 rattling (elastic struts)", agitated(ts.load_scene("prism3"), 0.3), args.steps)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
