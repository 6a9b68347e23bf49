"""The compiled solves with a SuperLU factor (``methods/qp/_superlu_kernels.py``) against SuperLU's own
solve, and the Rayleigh-Ritz step of the self-stress rule's block inverse iteration in its two forms."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.linalg import splu

from tensegrity_sim.methods.qp._superlu_kernels import factor_arrays, lu_solve


def _matrix(n: int, symmetric: bool, seed: int):
    """A sparse, well-conditioned matrix (n, n) with ~6 entries a row, CSC: diagonally dominant if
    ``symmetric``, else its columns shuffled (dominant off the diagonal: SuperLU pivots rows)."""
    rng = np.random.default_rng(seed)
    m = sp.random(n, n, density=5.0 / n, random_state=rng, format="csr")
    if symmetric:
        m = m + m.T
    m = m + sp.diags(np.abs(m).sum(axis=1).A1 + 1.0)
    return (m if symmetric else m[:, rng.permutation(n)]).tocsc()


@pytest.mark.parametrize("symmetric", [False, True])
def test_the_kernel_solves_what_superlu_does(symmetric):
    """One right-hand side and a block of 40, dense and sparse (a unit vector: rows of zeros are
    skipped), with partial pivoting (a general matrix) and with the symmetric ordering and no pivoting
    the sparse backend uses: SuperLU's own answers to 1e-13 relative, a block's column the bits of the
    one-column solve."""
    n = 300
    m = _matrix(n, symmetric, seed=3)
    options = ({"permc_spec": "MMD_AT_PLUS_A", "diag_pivot_thresh": 0.0, "options": {"SymmetricMode": True}}
               if symmetric else {"permc_spec": "COLAMD"})
    lu = splu(m, **options)
    factor = factor_arrays(lu)
    assert symmetric or not np.array_equal(lu.perm_r, lu.perm_c)
    rng = np.random.default_rng(4)
    block = rng.standard_normal((n, 40))
    block[:, 0] = 0.0
    block[17, 0] = 1.0
    solved = lu_solve(block, *factor)
    expected = lu.solve(block)
    assert np.abs(solved - expected).max() <= 1e-13 * np.abs(expected).max()
    assert np.abs(m @ solved - block).max() <= 1e-12
    for column in (0, 1, 39):
        assert np.array_equal(lu_solve(np.ascontiguousarray(block[:, column]), *factor), solved[:, column])


def test_cholesky_qr_ritz_pairs_are_householders():
    """The self-stress rule's Rayleigh-Ritz step (``self_stress._rayleigh_ritz``) on a block of solves of
    Ritz vectors: Cholesky's QR merged into the rotation gives Householder's Ritz values to 1e-12 of the
    largest and the same span of the kept vectors (projectors 1e-12 apart), orthonormal to 1e-13; a block
    Cholesky's QR cannot take (the solves of a random block: its columns all lean to the near-null
    space) gets Householder's."""
    from tensegrity_sim.methods.inextensible.self_stress import _rayleigh_ritz
    rng = np.random.default_rng(5)
    a = sp.random(120, 90, density=0.05, random_state=rng, format="csr") + sp.eye(120, 90)
    a = sp.vstack([a, sp.random(20, 90, density=0.05, random_state=rng)]).tocsr()   # 50 self-stresses at least
    w = (a @ a.T).tocsc()
    largest = np.linalg.eigvalsh(w.toarray())[-1]
    lu = splu((w + 1e-12 * largest * sp.identity(w.shape[0])).tocsc())
    a_t = a.T.tocsr()
    theta, x = _rayleigh_ritz(a_t, lu.solve(rng.standard_normal((w.shape[0], 60))), False)
    y = lu.solve(x)
    householder = _rayleigh_ritz(a_t, y, False)
    cholesky = _rayleigh_ritz(a_t, y, True)
    assert np.abs(cholesky[0] - householder[0]).max() <= 1e-12 * largest
    kept = householder[0] < 1e-6 * largest
    assert kept.sum() >= 50
    p, q = householder[1][:, kept], cholesky[1][:, kept]
    assert np.linalg.norm(p @ (p.T @ q) - q, 2) <= 1e-12
    assert np.abs(cholesky[1].T @ cholesky[1] - np.eye(60)).max() <= 1e-13
    raw = lu.solve(rng.standard_normal((w.shape[0], 60)))
    assert np.array_equal(_rayleigh_ritz(a_t, raw, True)[1], _rayleigh_ritz(a_t, raw, False)[1])
