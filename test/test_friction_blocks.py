"""The elastic method's compiled contact step (issue 28): the block solver (``_friction_block_kernels.py``)
against its numpy twin (``friction_blocks.py``, the same arithmetic: 1e-12) and against the Coulomb law in
its projection form; the compiled ground step against the reference's QP fixed point (``friction.py``) to
that reference's tolerance on the scenes of ``test_ground.py``."""
import warnings

import numpy as np
import pytest

import tensegrity_sim as ts
from tensegrity_sim.methods.contact._friction_block_kernels import (MAX_COUPLED, MAX_ROWS, block_work, coupled_work,
                                                                    lone_contact, solve_block, solve_coupled)
from tensegrity_sim.methods.base import State
from tensegrity_sim.methods.contact.friction_blocks import (lone_contact_reference, solve_block_reference,
                                                            solve_coupled_reference)
from tensegrity_sim.methods.contact.member import tangents

from test_ground import G, MU, dropped, strut


def rod_inverse(rng):
    """``M^-1`` of a random rod's block (its diagonal at each end, its cross entry): half of them lumped (masses
    0.1-3 kg at the ends, cross 0), half a consistent block ``[[A, B], [B, C]]`` with ``A, C`` 0.1-3 kg and ``B``
    up to 0.95 of ``sqrt(A C)`` (a uniform rod's is 0.5, a mid-rod payload's nears 1)."""
    a, c = rng.uniform(0.1, 3.0, 2)
    if rng.random() < 0.5:
        return np.array([1.0 / a, 1.0 / c, 0.0])
    b = rng.uniform(0.0, 0.95) * np.sqrt(a * c)
    det = a * c - b * b
    return np.array([c / det, a / det, -b / det])


def block_inverse(inv):
    """The dense ``M^-1`` (6, 6) of a block's ``inv`` (3,)."""
    return np.kron(np.array([[inv[0], inv[2]], [inv[2], inv[1]]]), np.eye(3))


def random_block(rng):
    """A random well-posed block: a rigid strut (random direction, a random rod's mass: :func:`rod_inverse`,
    sometimes horizontal) with 0, 1 or 2 contacts, or a lone node's contact; random velocities, targets, mu and
    warm starts."""
    k = int(rng.integers(0, 3))
    strut_row = k == 0 or bool(rng.integers(0, 4))
    k = min(k, 1) if not strut_row else k
    inv = rod_inverse(rng)
    if not strut_row:
        inv[1:] = 0.0
    direction = rng.normal(size=3)
    if rng.random() < 0.3:
        direction[2] = 0.0
    direction /= np.linalg.norm(direction)
    ends = np.arange(k, dtype=np.int64) if k == 2 else rng.integers(0, 2 if strut_row else 1, size=k)
    target = 0.1 * rng.normal(size=k)
    mu = float(rng.choice([0.0, 0.2, 0.5, 1.0]))
    v = rng.normal(size=(2, 3))
    z = np.zeros(MAX_ROWS)
    s = int(strut_row)
    z[s: s + 3 * k] = rng.normal(size=3 * k) * float(rng.integers(0, 2))
    return inv, strut_row, direction, ends.astype(np.int64), target, mu, v, z


def coulomb_residual(inv, strut_row, direction, ends, target, mu, v0, v, z):
    """Independent check of a block's answer: (the strut's length rate m/s, the worst violation of the
    normal law (``min(y_n, m (v_z - w)) = 0``) and of the Coulomb law's projection form ``f = proj_disc(mu y_n)(f - m v_t)``, N*s, and of
    the momentum balance ``M (v - v0) = G^T z``)."""
    s = int(strut_row)
    rate = float(direction @ (v[1] - v[0])) if s else 0.0
    worst = 0.0
    push = np.zeros((2, 3))
    if s:
        push[0] -= z[0] * direction
        push[1] += z[0] * direction
    for c, e in enumerate(ends):
        f, y = z[s + 3 * c: s + 3 * c + 2], z[s + 3 * c + 2]
        m = 1.0 / inv[e]
        u = v[e]
        worst = max(worst, abs(min(y, m * (u[2] - target[c]))))   # the normal law's natural residual
        trial = f - m * u[:2]
        size = np.hypot(*trial)
        projected = trial * min(1.0, mu * y / size) if size > 0 else trial
        worst = max(worst, float(np.abs(f - projected).max()))
        push[e] += z[s + 3 * c: s + 3 * c + 3]
    balance = float(np.abs((v - v0).ravel() - block_inverse(inv) @ push.ravel()).max())
    return rate, worst, balance


def resultant(strut_row, direction, ends, z):
    """``G^T z`` (2, 3) N*s: the impulse on each end of a block's answer ``z`` (unique where ``z`` is not)."""
    s = int(strut_row)
    push = np.zeros((2, 3))
    if s:
        push[0] -= z[0] * direction
        push[1] += z[0] * direction
    for c, e in enumerate(ends):
        push[e] += z[s + 3 * c: s + 3 * c + 3]
    return push


def test_block_kernel_matches_its_numpy_twin_and_meets_the_coulomb_law():
    rng = np.random.default_rng(28)
    work = block_work()
    solved = 0
    for _ in range(2000):
        inv, strut_row, direction, ends, target, mu, v, z = random_block(rng)
        v_ref, z_ref, it_ref = solve_block_reference(inv, strut_row, direction, ends, target, mu, v, z)
        v_k, z_k = v.copy(), z.copy()
        it = solve_block(inv, strut_row, direction, ends, target, len(ends), mu, v_k, z_k, work)
        assert (it < 0) == (it_ref < 0)
        if it < 0:
            continue
        solved += 1
        scale = max(1.0, float(np.abs(v).max()))
        np.testing.assert_allclose(v_k, v_ref, rtol=0, atol=1e-12 * scale)
        impulse = scale / inv[:2][inv[:2] > 0].min()
        if len(ends) < 2 or direction[2] != 0.0:   # a strut lying on both ends: its friction along it is shared
            np.testing.assert_allclose(z_k[: len(z_ref)], z_ref, rtol=0, atol=1e-12 * impulse)   # indeterminately
        np.testing.assert_allclose(resultant(strut_row, direction, ends, z_k),
                                   resultant(strut_row, direction, ends, z_ref), rtol=0, atol=1e-12 * impulse)
        rate, law, balance = coulomb_residual(inv, strut_row, direction, ends, target, mu, v, v_k, z_k)
        assert abs(rate) <= 1e-12 * scale
        assert law <= 1e-11 * impulse
        assert balance <= 1e-13 * scale
    # the damped Newton answers nearly every random block (what it leaves goes to the reference: see below)
    assert solved >= 0.99 * 2000


def test_lone_contact_is_the_closed_form():
    rng = np.random.default_rng(1)
    for _ in range(200):
        inv, v, target, mu = 1.0 / rng.uniform(0.1, 3.0), rng.normal(size=3), 0.1 * rng.normal(), rng.uniform(0, 1)
        v_ref, z_ref = lone_contact_reference(inv, v, target, mu)
        v_k, z_k = v.copy(), np.empty(3)
        lone_contact(inv, v_k, target, mu, z_k)
        np.testing.assert_allclose(v_k, v_ref, rtol=0, atol=1e-15)
        np.testing.assert_allclose(z_k, z_ref, rtol=0, atol=1e-15)
        # the law: no sinking below the target, friction inside the disc, sticking unless on its edge
        assert v_k[2] >= target - 1e-15 and z_k[2] >= 0.0
        assert np.hypot(*z_k[:2]) <= mu * z_k[2] * (1 + 1e-12) + 1e-300
        assert np.hypot(*v_k[:2]) <= 1e-15 or np.hypot(*z_k[:2]) >= mu * z_k[2] * (1 - 1e-12)


def random_coupled(rng):
    """A random coupled block: rigid struts A (nodes 0, 1) and B (2, 3) and a cable C (lone nodes 4, 5); the
    member contacts A-B and, sometimes, B-C (random normals and contact points); ground contacts on a random
    subset of the nodes; random masses, velocities, targets, mu (ground and members apart) and warm starts.
    Returns the arguments of ``solve_coupled`` (``g`` in its scratch's shape) and the contacts' normal rows."""
    inv = np.zeros((6, 2))
    inv[:, 0] = 1.0 / rng.uniform(0.1, 3.0, 6)
    for i in range(2):   # the struts' ends: a random rod's block each (rod_inverse)
        diagonal_a, diagonal_c, cross = rod_inverse(rng)
        inv[2 * i: 2 * i + 2] = [[diagonal_a, cross], [diagonal_c, cross]]
    struts = [rng.normal(size=3) for _ in range(2)]
    grounded = np.flatnonzero(rng.random(6) < 0.4)
    pairs = [(0, 1, 2, 3)] + ([(2, 3, 4, 5)] if rng.random() < 0.5 else [])
    s, k = 2, len(grounded) + len(pairs)
    g = np.zeros((MAX_COUPLED, 3 * (MAX_COUPLED // 3 + 1)))
    for i, d in enumerate(struts):
        d /= np.linalg.norm(d)
        g[i, 6 * i: 6 * i + 3], g[i, 6 * i + 3: 6 * i + 6] = -d, d
    row = s
    for p in grounded:
        g[row: row + 3, 3 * p: 3 * p + 3] = np.eye(3)
        row += 3
    for nodes in pairs:
        normal = rng.normal(size=3)
        normal /= np.linalg.norm(normal)
        frame = np.vstack([tangents(normal[None])[0], normal])
        a, b = rng.uniform(0, 1, 2)
        for node, w in zip(nodes, (a - 1.0, -a, 1.0 - b, b)):
            g[row: row + 3, 3 * node: 3 * node + 3] = w * frame
        row += 3
    target = 0.1 * rng.normal(size=k)
    mu = np.concatenate([np.full(len(grounded), rng.choice([0.0, 0.3, 1.0])),
                         np.full(len(pairs), rng.choice([0.0, 0.5, 1.2]))])
    v = rng.normal(size=(6, 3))
    z = np.zeros(MAX_COUPLED)
    z[s: s + 3 * k] = 0.01 * rng.normal(size=3 * k) * float(rng.integers(0, 2))
    return inv, g, 6, s, k, target, mu, v, z


def test_coupled_block_kernel_matches_its_numpy_twin_and_meets_the_coulomb_law():
    """``solve_coupled`` (two struts and a cable joined by member contacts, with ground contacts) against its
    numpy twin to 1e-12, and its answer against the laws independently: the struts' length rates 0, each
    contact's normal law ``min(y_n, m (u_n - w)) = 0`` and Coulomb's projection form ``f = proj_disc(mu y_n)(f
    - m u_t)`` in its frame (``m = 1 / W_nn``, its effective mass), and the momentum balance ``M (v - v0) = G^T
    z``."""
    rng = np.random.default_rng(11)
    work = coupled_work()
    solved = 0
    for _ in range(600):
        inv, g, nb, s, k, target, mu, v, z = random_coupled(rng)
        v_ref, z_ref, it_ref = solve_coupled_reference(inv, g, s, k, target, mu, v, z)
        v_k, z_k = v.copy(), z.copy()
        it = solve_coupled(inv, g, nb, s, k, target, mu, v_k, z_k, work)
        assert it == it_ref
        if it < 0:
            np.testing.assert_array_equal(v_k, v)
            continue
        solved += 1
        q = s + 3 * k
        scale = max(1.0, float(np.abs(v).max()))
        impulse = scale / inv[:, 0].min()
        inverse = np.diag(np.repeat(inv[:, 0], 3))
        inverse[:6, :6], inverse[6:12, 6:12] = block_inverse(inv[[0, 1, 0], [0, 0, 1]]), \
            block_inverse(inv[[2, 3, 2], [0, 0, 1]])
        np.testing.assert_allclose(v_k, v_ref, rtol=0, atol=1e-12 * scale)
        np.testing.assert_allclose(z_k[:q], z_ref, rtol=0, atol=1e-12 * impulse)
        rows = g[:q, : 3 * nb]
        u = rows @ v_k.ravel()
        assert np.abs(u[:s]).max() <= 1e-11 * scale   # phi_0 = u_0 / W_00 to the impulse tolerance
        delassus = rows @ inverse @ rows.T
        for c in range(k):
            o = s + 3 * c
            m = 1.0 / delassus[o + 2, o + 2]
            f, y = z_k[o: o + 2], z_k[o + 2]
            assert abs(min(y, m * (u[o + 2] - target[c]))) <= 1e-11 * impulse
            trial = f - m * u[o: o + 2]
            size = np.hypot(*trial)
            projected = trial * min(1.0, mu[c] * y / size) if size > 0 else trial
            assert np.abs(f - projected).max() <= 1e-11 * impulse
        balance = (v_k - v).ravel() - inverse @ (rows.T @ z_k[:q])
        assert np.abs(balance).max() <= 1e-13 * scale
    assert solved >= 0.98 * 600   # measured 591 with the rods' blocks (the rest goes to the reference)


def _scenes():
    point = ts.Scene.from_dict({"gravity": [0, 0, -G], "ground": {"friction": 0.5, "restitution": 0.0},
                                "nodes": [{"name": "p", "position": [0, 0, 0.05], "mass": 1.0, "velocity": [1, 0, 0]}]})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return {"sliding strut": strut(2.0), "holding incline": strut(theta=np.arctan(0.9 * MU)),
                "sliding incline": strut(2.0, theta=0.3), "landing point": point,
                "dropped icosahedron": dropped(lift=0.05, damping=300.0),
                "icosahedron at rest": ts.load_scene("icosahedron_ground")}


@pytest.mark.parametrize("name", list(_scenes()))
def test_compiled_ground_step_agrees_with_the_qp_fixed_point(name):
    """Along the reference's trajectory, each step taken from the same state by the compiled block solver
    and by friction.py's QP fixed point (both answer to their tolerances: FIXED_POINT_TOL = 1e-10 relative
    to the impulse scale) gives the same velocities, positions and ground impulses."""
    scene = _scenes()[name]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        reference = ts.Simulator(scene, method="elastic", dt=1e-3)
        compiled = ts.Simulator(scene, method="elastic", dt=1e-3)
    reference._method.compiled = False
    assert compiled._method.has_ground_loop()
    method = compiled._method
    # (bodies, N): each moving rigid strut's two ends, each other node alone
    group = np.where(method._ground_model.node_strut >= 0, method._ground_model.node_strut, 0)
    group = np.where(method._ground_model.node_strut >= 0, group, method.rigid.count + np.arange(len(group)))
    by_body = (np.unique(group)[:, None] == group[None]).astype(float)
    contacted = 0
    for _ in range(300):
        st = reference._state
        method.invalidate()
        mine = method.step(State(st.positions.copy(), st.velocities.copy(), st.rest_lengths.copy(),
                                 st.external_forces.copy(), st.step_count))
        reference._method.invalidate()   # both from the forces at the state (damping: at its velocities)
        theirs = reference.step()
        scale = max(1.0, float(np.abs(st.velocities).max()))
        np.testing.assert_allclose(mine.velocities, theirs.velocities, rtol=0, atol=1e-8 * scale)
        np.testing.assert_allclose(mine.positions, theirs.positions, rtol=0, atol=1e-11 * scale)
        # the normal impulses node by node; the friction summed over each rigid strut's two ends (a strut
        # sticking on both ends may share the friction along it in any way: statically indeterminate)
        weight = float(scene.masses.max()) * G * 1e-3
        np.testing.assert_allclose(mine.contact_impulses[:, 2], theirs.contact_impulses[:, 2], rtol=0,
                                   atol=1e-8 * weight * scale)
        np.testing.assert_allclose(by_body @ mine.contact_impulses, by_body @ theirs.contact_impulses, rtol=0,
                                   atol=1e-8 * weight * scale)
        contacted += bool(np.abs(theirs.contact_impulses).max() > 0)
    assert contacted >= 50 and method.fallbacks == 0


def test_a_block_whose_damped_matrix_is_not_definite_is_damped_more_and_solved():
    """Regression: strut A of ``test_member_contact.across`` coming to rest on the ground at both ends
    (the friction along it statically indeterminate: ``J`` singular) with ``|phi|`` already small, so that
    ``J^T J + nu I`` (``nu`` 1e-20) is not definite in floating point: the kernel's Cholesky met a negative
    pivot, its NaN passed the convergence test (``max`` ignores NaN) and the step's velocities were NaN; then
    the block was left to the reference. Now ``nu`` is raised until the matrix is definite: the kernel and its
    twin solve the block, to the same numbers, meeting the law."""
    direction = np.array([0.976349877261514, 0.21619647816610393, 0.0])
    v = np.array([[0.0, 0.0, -0.0049050000000000005], [0.0, 0.0, -0.0049050000000000005]])
    z = np.array([0.0, -8.414808548100362e-05, 0.00018160221569561182, 0.0049050000000000005,
                  -0.0001631096628726393, 6.828086776367975e-05, 0.0049050000000000005])
    inv, ends, target = np.array([1.0, 1.0, 0.0]), np.array([0, 1]), np.zeros(2)
    v_k, z_k = v.copy(), z.copy()
    it = solve_block(inv, True, direction, ends, target, 2, 0.2, v_k, z_k, block_work())
    v_ref, z_ref, it_ref = solve_block_reference(inv, True, direction, ends, target, 0.2, v, z)
    assert it == it_ref >= 0
    np.testing.assert_allclose(v_k, v_ref, rtol=0, atol=1e-15)
    np.testing.assert_allclose(z_k, z_ref, rtol=0, atol=1e-15)
    rate, law, balance = coulomb_residual(inv, True, direction, ends, target, 0.2, v, v_k, z_k)
    assert abs(rate) <= 1e-15 and law <= 1e-15 and balance <= 1e-17
    assert np.abs(v_k).max() <= 1e-15   # it comes to rest: its weight's impulse held by the ground
