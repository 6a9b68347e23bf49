"""DAQP's C entry point called from a kernel (``methods/qp/_daqp_kernels.py``) against ``daqp.solve``: the
same answer to the last bit, on random problems and on the degenerate ones a locked structure gives."""
import daqp
import numpy as np
import pytest

import tensegrity_sim as ts
from tensegrity_sim.methods.qp import _daqp_kernels as kernels
from tensegrity_sim.methods.qp.solvers import DaqpSolver, Rows


def _same(reference, compiled):
    """``daqp.solve``'s ``(x, fval, flag, info)`` against the kernel's ``(x, lam, flag, iterations)``: the
    exit flag and iterations always, the answer when there is one (else DAQP leaves it unwritten)."""
    x, _, flag, info = reference
    assert (compiled[2], compiled[3]) == (flag, info["iterations"])
    if flag >= 1:
        np.testing.assert_array_equal(compiled[0], x)
        np.testing.assert_array_equal(compiled[1], info["lam"])


def _problem(rng, n, k, n_eq, dependent):
    """A strictly convex QP of ``n`` unknowns and ``k`` rows, the first ``n_eq`` equalities, a warm
    start on some rows; ``dependent``: its last rows sums of earlier ones (a self-stress)."""
    root = rng.normal(size=(n, n))
    hessian = root @ root.T + n * np.eye(n)
    a = rng.normal(size=(k, n))
    for i in range(k - dependent, k):
        a[i] = a[i - 1] + a[i - 2]
    upper = rng.normal(size=k) + (a @ rng.normal(size=n))   # feasible unless equalities conflict
    lower = np.full(k, -1e30)
    lower[:n_eq] = upper[:n_eq]
    sense = rng.integers(0, 2, size=k).astype(np.int32)
    sense[:n_eq] = 5
    return hessian, rng.normal(size=n), a, upper, lower, sense


@pytest.mark.parametrize("dependent", [0, 2])
def test_quadprog_is_daqp_solve_bitwise(dependent):
    entry, raw = kernels.entry_point(daqp, DaqpSolver.settings)
    rng = np.random.default_rng(7 + dependent)
    flags = set()
    for _ in range(200):
        n = int(rng.integers(1, 25))
        k = int(rng.integers(dependent + 2, 40))
        n_eq = int(rng.integers(0, min(k - dependent, n) + 1))
        hessian, f, a, upper, lower, sense = _problem(rng, n, k, n_eq, dependent)
        reference = daqp.solve(hessian, f, a, upper, lower, sense.copy(), **DaqpSolver.settings)
        _same(reference, kernels.quadprog(entry, raw, hessian, f, a, upper, lower, sense.copy()))
        flags.add(reference[2])
    assert 1 in flags and min(flags) < 1   # solved ones and failures (infeasible, more rows than unknowns)


def test_quadprog_without_rows():
    entry, raw = kernels.entry_point(daqp, DaqpSolver.settings)
    hessian, f = 2.0 * np.eye(3), np.array([1.0, -2.0, 0.5])
    none = (np.zeros((0, 3)), np.zeros(0), np.zeros(0), np.zeros(0, dtype=np.int32))
    compiled = kernels.quadprog(entry, raw, hessian, f, *none)
    _same(daqp.solve(hessian, f, *none, **DaqpSolver.settings), compiled)
    assert compiled[1].shape == (0,)
    np.testing.assert_allclose(compiled[0], -f / 2.0, rtol=1e-15)   # the unconstrained minimum


def test_settings_struct_matches_daqp_defaults():
    """The settings struct starts from DAQP's own defaults: those ``daqp.solve`` declares."""
    import inspect
    entry, raw = kernels.entry_point(daqp, {})
    struct = kernels.Settings.from_buffer_copy(raw.tobytes())
    declared = inspect.signature(daqp.solve).parameters
    for name, _ in kernels.Settings._fields_:
        assert getattr(struct, name) == declared[name].default, name


def test_solver_rows_of_a_locked_icosahedron_bitwise():
    """The thrown icosahedron with rigid struts (rows carrying a self-stress, multipliers growing like
    1/dt): every QP of 60 steps solved by the compiled call and by ``daqp.solve`` on the same rows."""
    from bench.cases import work_precision_cases
    scene = next(c for c in work_precision_cases() if c.name == "icosahedron_thrown").scene
    with pytest.warns(ts.LengthOffsetWarning):
        sim = ts.Simulator(scene, method="inextensible", dt=1e-3, contacts=())
    solver = sim._method.solver
    seen = []
    original = solver._solve

    def both(v0, rows: Rows, warm, unit=1.0):
        fast = original(v0, rows, warm, unit)
        solver.compiled = False
        try:
            slow = original(v0, rows, warm, unit)
        finally:
            solver.compiled = True
        np.testing.assert_array_equal(fast[0], slow[0])
        np.testing.assert_array_equal(fast[1], slow[1])
        seen.append(float(np.abs(slow[1]).max()))
        return fast
    solver._solve = both
    for _ in range(60):
        sim.step()
    assert len(seen) >= 60 and max(seen) > 1.0   # multipliers far above the published ~0.1 N*s impulses
