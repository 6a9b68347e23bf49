"""The sticking contacts' working set tried before DAQP (issue 47, ``_qp_kernels.sticking_answer``): each
sticking contact's ``t`` and ``-t`` rows as one sign-free pair, a pair that depends on the rows before it
dropped. Held to closed forms on small problems and to DAQP's answer (the reference the friction modes
otherwise take) on the QPs of the inextensible icosahedron resting on the ground."""
import warnings

import daqp
import numpy as np

import tensegrity_sim as ts
from tensegrity_sim.methods.contact import _friction_kernels as fk
from tensegrity_sim.methods.contact import friction as F
from tensegrity_sim.methods.qp import _daqp_kernels as dk
from tensegrity_sim.methods.qp import _qp_kernels as qk
from tensegrity_sim.methods.qp.solvers import DaqpSolver

_, SETTINGS = dk.entry_point(daqp, DaqpSolver.settings)


def _ground_rows(n_member_rows, member_nodes, member_dirs, contacts):
    """Member rows, then a normal row per contact node and its four tangential rows (friction.py's layout)."""
    nodes = [list(p) for p in member_nodes] + [[-1, c] for c in contacts]
    dirs = [list(d) for d in member_dirs] + [[0.0, 0.0, -1.0]] * len(contacts)
    for c in contacts:
        nodes += [[-1, c]] * 4
        dirs += [[1.0, 0, 0], [0, 1.0, 0], [-1.0, 0, 0], [0, -1.0, 0]]
    k = len(nodes)
    start = np.zeros(k, dtype=bool)
    start[n_member_rows:n_member_rows + len(contacts)] = True   # the loaded normal rows
    guess, opposite = fk.sticking_rows(start, n_member_rows + len(contacts), len(contacts))
    return np.array(nodes, dtype=np.int64), np.array(dirs), guess, opposite


def test_a_pair_whose_multiplier_is_negative_hands_it_to_its_opposite_row():
    """One node of 2 kg sticking, pushed into the ground and along -y: at rest, the normal impulse its
    downward momentum, the friction its tangential momentum, the -y push held by the -y row (the +y row of
    the guess came out negative)."""
    m, v0 = 2.0, np.array([[0.3, -0.2, -1.0]])
    nodes, dirs, guess, opposite = _ground_rows(0, [], [], [0])
    ok, v, y = dk.solve_pairs(SETTINGS, np.full(3, m), nodes, dirs, v0, np.zeros(len(nodes)), 0, guess, opposite)
    assert ok
    np.testing.assert_allclose(v, 0.0, atol=1e-15)
    # rows: normal, +x, +y, -x, -y
    np.testing.assert_allclose(y, [m * 1.0, m * 0.3, 0.0, 0.0, m * 0.2], rtol=1e-14, atol=0.0)


def test_a_pair_that_depends_on_the_rows_before_it_is_dropped():
    """A rigid strut along x between two sticking nodes of 1 kg moving at 0.1 m/s along x: the second node's x
    pair depends on the strut's row and the first node's x pair, so it is dropped (multiplier 0); the strut
    carries the second node's momentum, the first node's friction both."""
    m, u = 1.0, 0.1
    v0 = np.array([[u, 0.0, -1.0], [u, 0.0, -1.0]])
    nodes, dirs, guess, opposite = _ground_rows(1, [[0, 1]], [[1.0, 0, 0]], [0, 1])
    k = len(nodes)
    assert not qk.cholesky(qk.delassus(nodes, dirs, np.flatnonzero(guess | (np.arange(k) < 1)),
                                       np.ones((2, 3)) / m), 1e-14)   # dependent: a plain working set is refused
    ok, v, y = dk.solve_pairs(SETTINGS, np.full(6, m), nodes, dirs, v0, np.zeros(k), 1, guess, opposite)
    assert ok
    np.testing.assert_allclose(v, 0.0, atol=1e-15)
    expected = np.zeros(k)
    expected[0] = m * u           # the strut row, in tension: it holds node 1 back
    expected[1:3] = m * 1.0       # the normal rows
    expected[3] = 2 * m * u       # node 0's +x row: both nodes' momentum along x
    np.testing.assert_allclose(y, expected, rtol=1e-13, atol=1e-16)
    assert y[3 + 4 + 0] == 0.0    # node 1's +x row: dropped


def test_the_resting_icosahedron_s_qps_are_daqp_s_answers():
    """The mode QPs of the inextensible icosahedron resting on the ground, each solved by the sticking pairs and by
    DAQP from the same warm start: every one answered by the pairs (its friction of ~8e-11 N*s flips between the
    +x and -x rows from step to step: the plain working set of the last answer failed every step), the
    velocities DAQP's to 1e-15 m/s and the multipliers to 1e-9 of the impulse scale (the tangential rows of
    three sticking contacts on one body are dependent: the two answers share the friction among them
    differently, within round-off of the resting body's ~1e-10 N*s of friction); both meet the QP's
    optimality conditions."""
    scene = ts.load_scene("icosahedron_ground")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sim = ts.Simulator(scene, method="inextensible", dt=1e-3)
    sim.run(steps=300)
    sim._method.one_kernel = False
    captured = []
    original = F.kernels.ground_modes

    class Capture:
        def __getattr__(self, name):
            return getattr(fk, name)

        @staticmethod
        def ground_modes(*args):
            captured.append(args)
            return original(*args)

    F.kernels = Capture()
    try:
        for _ in range(20):
            sim.step()
    finally:
        F.kernels = fk
    assert len(captured) == 20
    for args in captured:
        (entry, settings, hessian, sqrt_mass, mass, v0, row_nodes, row_dirs, row_targets, n_eq, warm, _, fi, w,
         _, mu, old_stick, old_normal, *_) = args
        stick = old_stick & (old_normal > 0) & (mu > 0)
        assert stick.all()
        nodes, dirs, targets, start, _ = fk._rows(row_nodes, row_dirs, row_targets, warm, True, fi, w, stick,
                                                  old_normal > 0)
        guess, opposite = fk.sticking_rows(start, len(row_targets) + len(fi), int(stick.sum()))
        ok, v, y = dk.solve_pairs(settings, mass, nodes, dirs, v0, targets, n_eq, guess, opposite)
        z, lam, flag, _, _, _ = dk.solve_rows(entry, settings, hessian, sqrt_mass, mass, nodes, dirs, len(v0),
                                              v0.reshape(-1), targets, n_eq, start, 1.0, False)
        assert ok and flag == 1
        scale = np.abs(mass * v0.reshape(-1)).max()
        impulse = max(scale, np.abs(lam).max())
        assert np.abs(v - z).max() <= 1e-15
        assert np.abs(y - lam).max() <= 1e-9 * impulse
        for answer_v, answer_y in ((v, y), (z, lam)):
            _, violation, imp, stationarity, smallest, short = qk.answer_residuals(
                answer_v.reshape(-1, 3), answer_y, v0, nodes, dirs, targets, n_eq, mass, 1e-7)
            assert violation <= 1e-12 and short <= 1e-12
            assert stationarity <= 1e-12 * imp and smallest >= -1e-12 * imp
