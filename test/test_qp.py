"""The QP backends of the inextensible method against quadprog, an independent QP solver (Goldfarb-Idnani).

The problems are built like the method builds them: one row per member, ``-n`` at one end and ``+n`` at
the other, fixed ends dropped. They include what makes the method's QPs hard: node masses differing by
1e4, equality rows (rigid struts), and dependent rows (duplicated members, more members at a node than
it has degrees of freedom), where the velocities are unique but the multipliers are not.
"""
import numpy as np
import pytest
import quadprog

from tensegrity_sim.methods import qp

SOLVERS = sorted(qp.SOLVERS)
# Relative accuracy in velocity each backend reaches on these problems (measured; see qp.py): OSQP, an
# ADMM method, stops at ~1e-7 at mass ratio 1e4 even with eps 1e-10 and polishing.
ACCURACY = {"daqp": 1e-9, "nnls": 1e-9, "osqp": 1e-6, "sparse": 1e-9}


def random_problem(seed, mass_ratio=1.0, n_free=8, n_fixed=2, n_members=18, n_eq=3, duplicates=0, star=False):
    """Free velocities v0 (n_free, 3), masses (n_free,) and Rows for members between random nodes.

    ``duplicates`` members repeat earlier ones exactly; ``star`` adds a free node tied by four members
    to four fixed nodes (four rows on three degrees of freedom)."""
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(n_free + n_fixed, 3))
    fixed = np.arange(n_free, n_free + n_fixed)
    index = np.concatenate([np.arange(n_free), -np.ones(n_fixed, dtype=int)])
    pairs = []
    while len(pairs) < n_members:
        a, b = rng.choice(n_free + n_fixed, size=2, replace=False)
        if index[a] >= 0 or index[b] >= 0:
            pairs.append((a, b))
    pairs += pairs[:duplicates]
    if star:
        x = np.vstack([x, rng.normal(size=(1, 3)), rng.normal(size=(3, 3)) * 3.0])
        index = np.concatenate([index, [n_free], -np.ones(3, dtype=int)])
        centre = n_free + n_fixed
        pairs += [(centre, f) for f in [fixed[0], centre + 1, centre + 2, centre + 3]]
        n_free += 1
    ends = np.array(pairs)
    d = x[ends[:, 1]] - x[ends[:, 0]]
    n = d / np.linalg.norm(d, axis=1)[:, None]
    # feasible by construction: a velocity meets every row, with slack on about half the inequalities
    rows = qp.Rows(index[ends], n, np.zeros(len(ends)), n_eq)
    slack = np.where(rng.random(len(ends)) < 0.5, 0.0, rng.uniform(0.0, 0.3, size=len(ends)))
    slack[:n_eq] = 0.0
    rows.targets = rows.rates(rng.normal(scale=0.3, size=(n_free, 3))) + slack
    mass = rng.uniform(0.5, 2.0, size=n_free) * np.where(rng.random(n_free) < 0.5, 1.0, mass_ratio)
    v0 = rng.normal(size=(n_free, 3))
    return v0, mass, rows


def quadprog_velocities(v0, mass, rows):
    """The same QP solved by quadprog: min 1/2 v^T M v - (M v0)^T v s.t. -A v >= -r (first n_eq equal)."""
    m = np.repeat(mass, 3)
    a = rows.dense(len(mass))
    v = quadprog.solve_qp(np.diag(m), m * v0.ravel(), -a.T, -rows.targets, rows.n_eq)[0]
    return v.reshape(-1, 3)


CASES = {
    "plain": dict(),
    "mass ratio 1e4": dict(mass_ratio=1e4),
    "no equalities": dict(n_eq=0),
    "duplicated members": dict(duplicates=4),
    "duplicated, mass ratio 1e4": dict(duplicates=4, mass_ratio=1e4),
    "four members on one node": dict(star=True, n_eq=0),
}


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("case", CASES, ids=list(CASES))
def test_velocities_match_quadprog(solver, case):
    for seed in range(4):
        v0, mass, rows = random_problem(seed, **CASES[case])
        reference = quadprog_velocities(v0, mass, rows)
        v, y = qp.make_solver(solver, mass).solve(v0, rows)
        scale = np.max(np.abs(reference))
        assert np.max(np.abs(v - reference)) < ACCURACY[solver] * scale, (solver, case, seed)
        # the multipliers are impulses along the rows: M (v - v0) = -A^T y, inequality ones >= 0
        m = np.repeat(mass, 3)
        np.testing.assert_allclose(m * (v - v0).ravel(), -rows.dense(len(mass)).T @ y,
                                   atol=ACCURACY[solver] * np.max(m * np.abs(v0).ravel()))
        assert np.all(y[rows.n_eq:] >= -ACCURACY[solver] * np.max(np.abs(y)))


@pytest.mark.parametrize("solver", SOLVERS)
def test_infeasible_rows_raise_with_status(solver):
    """Two rows on the same member asking for b.v <= -1 and b.v >= 1 (as -b.v <= -1)."""
    rows = qp.Rows(np.array([[0, -1], [-1, 0]]), np.array([[1.0, 0, 0], [1.0, 0, 0]]), np.array([-1.0, -1.0]), 0)
    with pytest.raises(qp.QPError) as err:
        qp.make_solver(solver, np.array([1.0])).solve(np.zeros((1, 3)), rows)
    assert err.value.solver == solver and err.value.status
    assert str(err.value).startswith(f"QP solver {solver!r} failed (")


def test_unknown_solver_is_refused_with_the_names():
    with pytest.raises(ValueError, match=r"solver must be one of \['daqp', 'nnls', 'osqp', 'sparse'\], got 'cvx'"):
        qp.make_solver("cvx", np.ones(2))


def test_rows_dense_and_rates_agree():
    v0, mass, rows = random_problem(7)
    v = np.random.default_rng(1).normal(size=v0.shape)
    np.testing.assert_allclose(rows.rates(v), rows.dense(len(mass)) @ v.ravel(), rtol=1e-13, atol=1e-15)
    np.testing.assert_array_equal(rows.sparse(len(mass)).toarray(), rows.dense(len(mass)))


def test_a_poor_answer_is_refused_not_returned():
    """OSQP at its own default tolerances (eps 1e-3) is off by ~1e-1 at mass ratio 1e4: the check of the
    optimality conditions refuses its answers instead of passing them on."""
    class LooseOsqp(qp.OsqpSolver):
        settings = {}

    for seed in range(4):
        v0, mass, rows = random_problem(seed, mass_ratio=1e4)
        with pytest.raises(qp.QPError) as err:
            LooseOsqp(mass).solve(v0, rows)
        assert err.value.status in ("infeasible output", "inaccurate output")
