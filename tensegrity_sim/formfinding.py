"""Form-finding for the built-in scenes: prestressed tensegrities that start in exact static equilibrium.

Every built-in scene must sit still when simulated, so positions and rest lengths are not typed by hand:
the geometry is chosen first and the member forces are solved from the equilibrium matrix (the force
method), then each elastic member's rest length is set so that its constitutive law reproduces that force:
``L = l - t/k`` (cables: ``t > 0`` so ``L < l``; elastic struts: ``t < 0`` so ``L > l``).

- :func:`prism` -- the 3-strut twisted prism (simplex); its self-stress is the one-dimensional null space
  of the equilibrium matrix (SVD) at the classic 150-degree twist.
- :func:`icosahedron` -- the 6-strut, 24-cable expanded octahedron (SUPERball-like) with rigid struts;
  self-stress from the SVD null space, all 24 cables equally tensioned.
- :func:`tower` -- stacked twisted prisms on a fixed base under gravity; the member forces that balance
  gravity exactly at the chosen geometry, with every cable at least ``prestress`` taut and every strut
  compressed, come from a linear programme over the (statically indeterminate) equilibrium equations.
- :func:`equilibrium_residual`, :func:`member_forces` -- independent checks of a scene mapping.

Conventions (contract section 1, physics section 1): SI units; member force ``t`` is tension-positive; the
member (a, b) pushes node a with ``+t (x_b - x_a)/l`` and node b with the opposite; cables carry
``k max(0, l - L)``, elastic struts ``k (l - L)``, rigid struts whatever equilibrium needs.

``python -m tensegrity_sim.formfinding`` regenerates ``scenes/prism3.yaml``, ``scenes/icosahedron.yaml``,
``scenes/icosahedron_ground.yaml``, ``scenes/tower.yaml``, ``scenes/superball.yaml`` and
``scenes/three_bar.yaml`` next to this file.
"""

from __future__ import annotations

import math
import sys
import warnings
from pathlib import Path

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.optimize import linprog

from .methods.contact.detection import closest_points

__all__ = [
    "prism",
    "icosahedron",
    "icosahedron_ground",
    "tower",
    "superball",
    "three_bar",
    "equilibrium_residual",
    "member_forces",
    "write_builtin_scenes",
]

# Relative size below which a singular value of the equilibrium matrix counts as zero (a self-stress).
_NULL_TOL = 1e-10


# --------------------------------------------------------------------------------------------------------
# Linear algebra of pin-jointed frameworks
# --------------------------------------------------------------------------------------------------------

def _unit_vectors(X: np.ndarray, members: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lengths (m) and unit vectors from end a to end b of every member; ``members`` is (m, 2) int."""
    d = X[members[:, 1]] - X[members[:, 0]]
    l = np.linalg.norm(d, axis=1)
    return l, d / l[:, None]


def _equilibrium_matrix(X: np.ndarray, members: np.ndarray, free: np.ndarray) -> sp.csr_matrix:
    """Sparse equilibrium matrix ``A`` (3F x m) on the free nodes.

    Column i holds the force that a unit tension in member i puts on the free nodes, so the net internal
    force is ``A @ t`` (N) and static equilibrium under external loads ``f`` reads ``A t + f = 0``.
    ``free`` maps node index -> row block (or -1 for a fixed node).
    """
    _, n = _unit_vectors(X, members)
    rows, cols, vals = [], [], []
    m = np.arange(len(members))
    for end, sign in ((0, 1.0), (1, -1.0)):
        blk = free[members[:, end]]
        ok = blk >= 0
        for c in range(3):
            rows.append(3 * blk[ok] + c)
            cols.append(m[ok])
            vals.append(sign * n[ok, c])
    nfree = int((free >= 0).sum())
    return sp.csr_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(3 * nfree, len(members))
    )


def _tangent_stiffness(X, members, t, k, free) -> np.ndarray:
    """Dense tangent stiffness (N/m) on the free degrees of freedom.

    Per member: material part ``k n n^T`` plus geometric part ``(t/l)(I - n n^T)``; a compressed strut's
    geometric part is negative, which is what can make a heavy tower buckle.
    """
    l, n = _unit_vectors(X, members)
    eye = np.eye(3)
    blocks = k[:, None, None] * n[:, :, None] * n[:, None, :] + (t / l)[:, None, None] * (
        eye - n[:, :, None] * n[:, None, :]
    )
    nfree = int((free >= 0).sum())
    K = np.zeros((3 * nfree, 3 * nfree))
    for p_end in (0, 1):
        for q_end in (0, 1):
            sign = 1.0 if p_end == q_end else -1.0
            bp, bq = free[members[:, p_end]], free[members[:, q_end]]
            for i in np.nonzero((bp >= 0) & (bq >= 0))[0]:
                K[3 * bp[i]:3 * bp[i] + 3, 3 * bq[i]:3 * bq[i] + 3] += sign * blocks[i]
    return K


def _rigid_body_basis(X: np.ndarray) -> np.ndarray:
    """Orthonormal basis (3N x 6) of the rigid-body motions of a free-floating node set."""
    N = len(X)
    c = X - X.mean(axis=0)
    B = np.zeros((3 * N, 6))
    for a in range(3):
        B[a::3, a] = 1.0
        e = np.zeros(3)
        e[a] = 1.0
        B[:, 3 + a] = np.cross(e, c).ravel()
    q, _ = np.linalg.qr(B)
    return q


def _min_stiffness_eigenvalue(K: np.ndarray, rigid_basis: np.ndarray | None = None) -> float:
    """Smallest eigenvalue (N/m) of K, restricted to motions orthogonal to ``rigid_basis`` if given."""
    if rigid_basis is not None:
        # Project onto the complement of the rigid-body modes, which carry no stiffness by construction.
        P = np.linalg.svd(rigid_basis, full_matrices=True)[0][:, rigid_basis.shape[1]:]
        K = P.T @ K @ P
    return float(np.linalg.eigvalsh(0.5 * (K + K.T))[0])


def _self_stress(A: np.ndarray) -> np.ndarray:
    """The single self-stress (unit vector of member forces) of a framework, from the SVD null space of A.

    Raises if the null space is not exactly one-dimensional: the built-ins rely on a unique prestress mode.
    """
    _, s, Vt = np.linalg.svd(A)
    m = A.shape[1]
    s_full = np.zeros(m)
    s_full[: len(s)] = s
    null = np.nonzero(s_full < _NULL_TOL * s_full[0])[0]
    if len(null) != 1:
        raise RuntimeError(f"expected a 1-D self-stress, found {len(null)} (singular values {s_full})")
    return Vt[null[0]]


def _min_clearance(X, members, radii) -> float:
    """Smallest surface gap (m) between two members that share no node (negative: they overlap)."""
    members = np.asarray(members)
    i, j = np.triu_indices(len(members), 1)
    share = (members[i, 0, None] == members[j]).any(axis=1) | (members[i, 1, None] == members[j]).any(axis=1)
    i, j = i[~share], j[~share]
    if len(i) == 0:
        return math.inf
    # Cheap bounding-sphere cull first, so a 100-stage tower is checked in well under a second.
    mid = 0.5 * (X[members[:, 0]] + X[members[:, 1]])
    half = 0.5 * np.linalg.norm(X[members[:, 1]] - X[members[:, 0]], axis=1) + radii
    near = np.linalg.norm(mid[i] - mid[j], axis=1) < half[i] + half[j]
    i, j = i[near], j[near]
    if len(i) == 0:
        return math.inf
    d = closest_points(X[members[i, 0]], X[members[i, 1]], X[members[j, 0]], X[members[j, 1]])[0]
    return float((d - radii[i] - radii[j]).min())


# --------------------------------------------------------------------------------------------------------
# Scene assembly
# --------------------------------------------------------------------------------------------------------

def _floats(v) -> list[float]:
    """Plain Python floats (yaml.safe_dump refuses numpy scalars; repr keeps full precision)."""
    return [float(x) for x in v]


def _scene(name, X, gravity, masses, fixed, struts, cables) -> dict:
    """Assemble a contract-section-1 mapping.

    ``struts``/``cables``: lists of dicts with keys a, b, stiffness ("rigid" or N/m), rest_length (m),
    radius (m). All mass sits on the nodes (strut mass 0), so the loader's half-and-half lumping is moot.
    """
    nodes = []
    for p, x in enumerate(X):
        node = {"name": f"n{p}", "position": _floats(x), "mass": float(masses[p])}
        if fixed[p]:
            node["fixed"] = True
        nodes.append(node)

    def member(prefix, i, m):
        return {
            "name": f"{prefix}{i}",
            "nodes": [f"n{m['a']}", f"n{m['b']}"],
            "stiffness": m["stiffness"] if m["stiffness"] == "rigid" else float(m["stiffness"]),
            "rest_length": float(m["rest_length"]),
            "radius": float(m["radius"]),
        }

    return {
        "name": name,
        "gravity": _floats(gravity),
        "nodes": nodes,
        "struts": [member("s", i, m) for i, m in enumerate(struts)],
        "cables": [member("c", i, m) for i, m in enumerate(cables)],
    }


def _rest_lengths(l: np.ndarray, t: np.ndarray, k: np.ndarray) -> np.ndarray:
    """Rest lengths (m) such that ``k (l - L) = t`` reproduces the solved force; refuses L <= 0."""
    L = l - t / k
    if np.any(L <= 0.0):
        raise ValueError("prestress too high for the stiffness: a rest length would be <= 0")
    return L


# --------------------------------------------------------------------------------------------------------
# Built-ins
# --------------------------------------------------------------------------------------------------------

def prism(
    strut_length: float = 1.0,
    radius: float = 0.4,
    twist_deg: float = 150.0,
    cable_tension: float = 40.0,
    node_mass: float = 0.5,
    strut_stiffness: float = 2.0e4,
    cable_stiffness: float = 2.0e3,
    strut_radius: float = 0.015,
    cable_radius: float = 0.003,
    name: str = "prism3",
) -> dict:
    """The 3-strut twisted prism (simplex), free-floating, no gravity, in exact self-equilibrium.

    Bottom triangle ``n0..n2`` at z = 0 and top triangle ``n3..n5`` on circles of ``radius`` (m); top node j
    is rotated by ``twist_deg`` from bottom node j and strut j joins them; the height is chosen so every
    strut is ``strut_length`` (m) long. Cables: bottom ring, top ring, and the three side cables joining
    bottom node j+1 to top node j. The twist must be 150 degrees (the simplex condition) for a self-stress
    to exist; it is taken from the SVD null space of the equilibrium matrix and scaled so that the most
    tensioned cable carries ``cable_tension`` (N). Elastic struts (N/m) get ``L = l - t/k > l``.
    """
    a = math.radians(twist_deg)
    chord = 2.0 * radius * math.sin(a / 2.0)
    if chord >= strut_length:
        raise ValueError("radius too large for the strut length")
    h = math.sqrt(strut_length**2 - chord**2)
    th = [2.0 * math.pi * j / 3.0 for j in range(3)]
    X = np.array(
        [[radius * math.cos(t), radius * math.sin(t), 0.0] for t in th]
        + [[radius * math.cos(t + a), radius * math.sin(t + a), h] for t in th]
    )
    struts = [(j, 3 + j) for j in range(3)]
    cables = (
        [(j, (j + 1) % 3) for j in range(3)]
        + [(3 + j, 3 + (j + 1) % 3) for j in range(3)]
        + [((j + 1) % 3, 3 + j) for j in range(3)]
    )
    members = np.array(struts + cables)
    free = np.arange(6)
    A = _equilibrium_matrix(X, members, free).toarray()
    s = _self_stress(A)
    ns = len(struts)
    # The null vector's sign is arbitrary; orient it so cables pull, then check struts push.
    s = s if s[ns:].sum() > 0 else -s
    t = s * (cable_tension / s[ns:].max())
    if t[ns:].min() <= 0.0 or t[:ns].max() >= 0.0:
        raise RuntimeError("self-stress is not a proper prestress (cables must pull, struts push)")
    l, _ = _unit_vectors(X, members)
    k = np.r_[np.full(ns, strut_stiffness), np.full(len(cables), cable_stiffness)]
    L = _rest_lengths(l, t, k)
    K = _tangent_stiffness(X, members, t, k, free)
    if _min_stiffness_eigenvalue(K, _rigid_body_basis(X)) <= 0.0:
        raise RuntimeError("prism equilibrium is not stable")
    def mk(i, kk, r):
        return {"a": members[i, 0], "b": members[i, 1], "stiffness": kk, "rest_length": L[i], "radius": r}

    return _scene(
        name,
        X,
        (0.0, 0.0, 0.0),
        np.full(6, node_mass),
        np.zeros(6, bool),
        [mk(i, strut_stiffness, strut_radius) for i in range(ns)],
        [mk(ns + i, cable_stiffness, cable_radius) for i in range(len(cables))],
    )


def icosahedron(
    strut_length: float = 1.684,
    strut_mass: float = 3.5,
    cable_tension: float = 80.0,
    cable_stiffness: float = 613.0,
    strut_radius: float = 0.025,
    cable_radius: float = 0.003,
    name: str = "icosahedron",
) -> dict:
    """The 6-strut, 24-cable expanded octahedron (SUPERball-like), rigid struts, no gravity, free-floating.

    Three pairs of parallel struts along x, y, z (``strut_length`` m), each pair separated by half the strut
    length and centred on the origin: nodes ``(+-b, 0, +-a)``, ``(+-a, +-b, 0)``, ``(0, +-a, +-b)`` with
    ``b = strut_length/2``, ``a = b/2``. In this symmetric geometry all 24 cables have length
    ``b*sqrt(3/2)`` and the equilibrium matrix has a 1-D self-stress (SVD null space), in which all cables
    carry the same tension, scaled to ``cable_tension`` (N). Each strut's ``strut_mass`` (kg) is lumped half
    on each end node. Cable rest length ``L = l - t/k``.
    """
    b = 0.5 * strut_length
    a = 0.5 * b
    X = []
    for s1 in (1.0, -1.0):  # strut along x at (y=0, z=s1*a): nodes (+b, 0, s1 a), (-b, 0, s1 a)
        X += [[b, 0.0, s1 * a], [-b, 0.0, s1 * a]]
    for s1 in (1.0, -1.0):  # along y at (z=0, x=s1*a)
        X += [[s1 * a, b, 0.0], [s1 * a, -b, 0.0]]
    for s1 in (1.0, -1.0):  # along z at (x=0, y=s1*a)
        X += [[0.0, s1 * a, b], [0.0, s1 * a, -b]]
    X = np.array(X)
    struts = [(2 * i, 2 * i + 1) for i in range(6)]
    # Each node's four cables go to the nearest nodes not on its own strut pair (distance b*sqrt(3/2)).
    D = np.linalg.norm(X[:, None] - X[None], axis=2)
    lc = b * math.sqrt(1.5)
    cables = [(p, q) for p in range(12) for q in range(p + 1, 12) if abs(D[p, q] - lc) < 1e-9 * lc]
    if len(cables) != 24:
        raise RuntimeError(f"expected 24 cables, found {len(cables)}")
    members = np.array(struts + cables)
    free = np.arange(12)
    A = _equilibrium_matrix(X, members, free).toarray()
    s = _self_stress(A)
    ns = 6
    s = s if s[ns:].sum() > 0 else -s
    t = s * (cable_tension / s[ns:].max())
    if t[ns:].min() <= 0.0 or t[:ns].max() >= 0.0:
        raise RuntimeError("self-stress is not a proper prestress")
    l, _ = _unit_vectors(X, members)
    Lc = _rest_lengths(l[ns:], t[ns:], np.full(24, cable_stiffness))
    # Stability with rigid struts: emulate rigidity by a very stiff strut in the tangent stiffness.
    k = np.r_[np.full(ns, 1e9), np.full(24, cable_stiffness)]
    if _min_stiffness_eigenvalue(_tangent_stiffness(X, members, t, k, free), _rigid_body_basis(X)) <= 0.0:
        raise RuntimeError("icosahedron equilibrium is not stable")
    return _scene(
        name,
        X,
        (0.0, 0.0, 0.0),
        np.full(12, 0.5 * strut_mass),
        np.zeros(12, bool),
        [
            {"a": p, "b": q, "stiffness": "rigid", "rest_length": l[i], "radius": strut_radius}
            for i, (p, q) in enumerate(struts)
        ],
        [
            {"a": p, "b": q, "stiffness": cable_stiffness, "rest_length": Lc[i], "radius": cable_radius}
            for i, (p, q) in enumerate(cables)
        ],
    )


def _settle_on_face(X, weight, members, cable, k, rest, strut_lengths, strut_forces, face):
    """Positions (N, 3) m at which the structure, its ``face`` nodes held where they are (by the ground
    and friction), is in static equilibrium under node weights ``weight`` (N,) N, elastic cables
    (``k``, ``rest``) and rigid struts (``strut_lengths``). The expanded octahedron has an infinitesimal
    mechanism that only its prestress stiffens, so a load in general needs the geometry to give a little;
    Newton's method (scipy's hybrid Powell) finds where. Unknowns: the other nodes' positions and the
    struts' forces (initial guess ``strut_forces``)."""
    from scipy.optimize import root
    others = np.setdiff1d(np.arange(len(X)), face)
    index = np.full(len(X), -1)
    index[others] = np.arange(len(others))
    n_other = len(others)

    def residual(z):
        Y = X.copy()
        Y[others] = z[: 3 * n_other].reshape(-1, 3)
        l, _ = _unit_vectors(Y, members)
        t = np.empty(len(members))
        t[~cable] = z[3 * n_other:]
        t[cable] = k[cable] * np.maximum(l[cable] - rest, 0.0)
        force = (_equilibrium_matrix(Y, members, index) @ t).reshape(-1, 3)
        force[:, 2] -= weight[others]
        return np.concatenate([force.ravel(), l[~cable] - strut_lengths])

    sol = root(residual, np.concatenate([X[others].ravel(), strut_forces]), method="hybr", tol=1e-14)
    # judged by its residual: hybr may stop short of its own xtol with the residual already at round-off
    if np.abs(residual(sol.x)).max() > 1e-9:
        raise RuntimeError(f"no static equilibrium on the face: {sol.message}")
    Y = X.copy()
    Y[others] = sol.x[: 3 * n_other].reshape(-1, 3)
    return Y


def icosahedron_ground(friction: float = 0.8, cable_tension: float = 80.0, gravity: float = 9.81,
                       cap_radius: float | None = None, name: str = "icosahedron_ground") -> dict:
    """The :func:`icosahedron` resting on one of its closed cable faces on the ground ``z = 0`` (Coulomb
    ``friction``), under ``gravity`` (m/s^2, along -z), in exact static equilibrium for both methods.

    The structure is turned so that the face ``n0 n4 n8`` (three nodes joined pairwise by cables) lies
    flat at the bottom, its nodes at the struts' radius above the ground (a node touches the ground at its
    position minus its largest member radius) and the centre of mass above the origin. The ground pushes
    only on those three nodes; their vertical reactions follow from the statics of the whole (vertical
    force and the two moments about the centre of mass). The member forces then solve ``A t + f = 0`` for
    gravity plus reactions, plus the multiple of the self-stress that makes the cables' mean tension
    ``cable_tension`` (N); the cable rest lengths are ``l - t/k``. The structure has an infinitesimal
    mechanism, so that is not yet equilibrium: the nodes off the face then settle to where it is
    (:func:`_settle_on_face`, a few mm), with the face held by the ground and friction. ``cap_radius`` (m):
    the face nodes touch the ground at that radius (end caps of their own) instead of the struts'.
    """
    base = icosahedron(cable_tension=cable_tension, name=name)
    X, mass, _, members, kind, k, _ = _parse(base)
    face = [0, 4, 8]
    normal = np.cross(X[face[1]] - X[face[0]], X[face[2]] - X[face[0]])
    normal /= np.linalg.norm(normal)
    if normal @ X[face].mean(axis=0) < 0:
        normal = -normal
    # Rodrigues: the rotation that takes the face's outward normal to -z
    down = np.array([0.0, 0.0, -1.0])
    axis = np.cross(normal, down)
    sin, cos = np.linalg.norm(axis), float(normal @ down)
    cross = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    R = np.eye(3) + cross + cross @ cross * ((1 - cos) / sin ** 2)
    X = X @ R.T
    radius = max(m["radius"] for m in base["struts"] + base["cables"]) if cap_radius is None else cap_radius
    centre = (mass[:, None] * X).sum(axis=0) / mass.sum()
    X -= np.array([centre[0], centre[1], X[face, 2].min() - radius])
    X[face, 2] = radius   # exactly on the ground (the rotation leaves round-off)
    weight = mass.sum() * gravity
    # reactions: sum = weight, no moment about the centre of mass (x and y)
    lever = np.vstack([np.ones(3), X[face, 0], X[face, 1]])
    reactions = np.linalg.solve(lever, [weight, 0.0, 0.0])
    f = np.zeros((len(X), 3))
    f[:, 2] = -mass * gravity
    f[face, 2] += reactions
    free = np.arange(len(X))
    A = _equilibrium_matrix(X, members, free).toarray()
    t = np.linalg.lstsq(A, -f.ravel(), rcond=None)[0]
    s = _self_stress(A)
    cable = kind == "cable"
    s = s if s[cable].sum() > 0 else -s
    t += s * (cable_tension - t[cable].mean()) / s[cable].mean()
    if t[cable].min() <= 0.0:
        raise RuntimeError("the cables cannot all be taut under this load")
    l, _ = _unit_vectors(X, members)
    rest = _rest_lengths(l[cable], t[cable], k[cable])
    X = _settle_on_face(X, mass * gravity, members, cable, k, rest, l[~cable], t[~cable], face)
    l, _ = _unit_vectors(X, members)
    scene = _scene(name, X, (0.0, 0.0, -gravity), mass, np.zeros(len(X), bool),
                   [{"a": a, "b": b, "stiffness": "rigid", "rest_length": l[i], "radius": m["radius"]}
                    for i, ((a, b), m) in enumerate(zip(members[~cable], base["struts"]))],
                   [{"a": a, "b": b, "stiffness": k[cable][i], "rest_length": rest[i], "radius": m["radius"]}
                    for i, ((a, b), m) in enumerate(zip(members[cable], base["cables"]))])
    scene["ground"] = {"height": 0.0, "friction": float(friction), "restitution": 0.0}
    return scene


def _end_caps(scene: dict, cap_mass: float, cap_radius: float, payload: float = 0.0) -> dict:
    """``scene`` (every node carrying its struts' mass, as :func:`_scene` writes it) with that mass moved
    onto the struts, uniform and a ``payload`` (kg) at mid-strut, leaving ``cap_mass`` (kg) and ``cap_radius``
    (m) on each end node: each end carries the same weight as before (the row sums of the strut's consistent
    block: half the strut's and half the payload's), so the equilibrium is unchanged."""
    share = {n["name"]: n["mass"] for n in scene["nodes"]}
    for s in scene["struts"]:
        a, b = s["nodes"]
        if abs(share[a] - share[b]) > 1e-12 * share[a]:
            raise ValueError("the ends of a strut must carry the same mass to move it onto the strut")
        s["mass"] = 2.0 * (share[a] - cap_mass) - payload
        if s["mass"] < 0.0:
            raise ValueError("end caps and payload heavier than the strut's share")
        if payload:
            s["payloads"] = [{"at": 0.5, "mass": payload}]
    for n in scene["nodes"]:
        n["mass"], n["radius"] = cap_mass, cap_radius
    return scene


def superball(cap_mass: float = 0.35, cap_radius: float = 0.05, friction: float = 0.99) -> dict:
    """NTRT's SUPERball layout on the ground: the six-rod, 24-cable expanded octahedron of :func:`icosahedron`
    with SUPERball's numbers (rods 1.684 m and 3.5 kg, cables 613 N/m: NTRT's ``SuperBall.yaml`` in metres,
    Bruce et al., "SUPERball: Exploring tensegrities for planetary probes", i-SAIRAS 2014), every cable
    actuated. Each rod is a 2.8 kg uniform tube with 0.35 kg end caps of ``cap_radius`` (m; they touch the
    ground), resting on the cable triangle n0 n4 n8 in exact static equilibrium (:func:`icosahedron_ground`,
    whose nodes carry the same weight), ground friction ``friction`` (NTRT's rods: 0.99)."""
    scene = icosahedron_ground(friction=friction, cap_radius=cap_radius, name="superball")
    return _end_caps(scene, cap_mass, cap_radius)


def three_bar(strut_length: float = 0.6, radius: float = 0.2, cable_tension: float = 100.0,
              cable_stiffness: float = 2000.0, rod_mass: float = 0.15, motor_mass: float = 0.3,
              cap_mass: float = 0.05, cap_radius: float = 0.03, strut_radius: float = 0.01,
              friction: float = 0.8, gravity: float = 9.81) -> dict:
    """A 3-bar robot standing on the ground: the twisted prism of :func:`prism` (three rods of
    ``strut_length`` m on circles of ``radius`` m, 150 degree twist) with rigid rods of ``rod_mass`` kg spread
    uniformly, a motor of ``motor_mass`` kg at each rod's middle (a payload), end caps of ``cap_mass`` kg and
    ``cap_radius`` m; six actuated cables (the triangles ``c0``-``c5``, each reeled by a motor) and three
    passive ones (the sides ``c6``-``c8``), ``cable_stiffness`` N/m, prestressed by the prism's self-stress at
    ``cable_tension`` N in the most tensioned cable. The bottom triangle stands on the ground (its end caps
    touching it, held by ``friction``); the top settles under gravity to where every node is in exact static
    equilibrium (:func:`_settle_on_face`, the prism's mechanism gives a little).
    Layout: the 3-strut tensegrity prism (Snelson's simplex; NTRT's ``3Prism.yaml``), the body of the 3-bar
    robots built with a motor on each rod (e.g. Kim et al., "Rapid prototyping design and control of
    tensegrity soft robot for locomotion", ROBIO 2014)."""
    base = prism(strut_length=strut_length, radius=radius, cable_tension=cable_tension,
                 cable_stiffness=cable_stiffness, strut_radius=strut_radius, name="three_bar")
    X, _, _, members, kind, k, rest = _parse(base)
    X[:, 2] += cap_radius   # the bottom triangle's caps on the ground z = 0
    cable = kind == "cable"
    node_mass = cap_mass + 0.5 * (rod_mass + motor_mass)   # the weight each end carries (row sums)
    l, _ = _unit_vectors(X, members)
    t = member_forces(base)["struts"]
    face = [0, 1, 2]
    X = _settle_on_face(X, np.full(len(X), node_mass * gravity), members, cable, k, rest[cable], l[~cable],
                        np.array(list(t.values())), face)
    l, _ = _unit_vectors(X, members)
    if np.any(l[cable] <= rest[cable]):
        raise RuntimeError("three_bar: a cable is slack at the settled geometry")
    scene = _scene("three_bar", X, (0.0, 0.0, -gravity), np.full(len(X), node_mass), np.zeros(len(X), bool),
                   [{"a": a, "b": b, "stiffness": "rigid", "rest_length": l[i], "radius": strut_radius}
                    for i, (a, b) in enumerate(members[~cable])],
                   [{"a": a, "b": b, "stiffness": cable_stiffness, "rest_length": rest[cable][i], "radius": 0.003}
                    for i, (a, b) in enumerate(members[cable])])
    scene["ground"] = {"height": 0.0, "friction": float(friction), "restitution": 0.0}
    return _end_caps(scene, cap_mass, cap_radius, payload=motor_mass)


def _tower_topology(stages, radius, height, overlap, twist, shift):
    """Geometry and members of the stacked-prism tower (see :func:`tower`)."""
    X = []
    pitch = height - overlap
    for k in range(stages):
        rot = k * (twist + shift)
        for j in range(3):
            th = 2.0 * math.pi * j / 3.0 + rot
            X.append([radius * math.cos(th), radius * math.sin(th), k * pitch])
        for j in range(3):
            th = 2.0 * math.pi * j / 3.0 + rot + twist
            X.append([radius * math.cos(th), radius * math.sin(th), k * pitch + height])
    X = np.array(X)
    struts, cables = [], []
    for k in range(stages):
        B = [6 * k + j for j in range(3)]
        T = [6 * k + 3 + j for j in range(3)]
        for j in range(3):
            struts.append((B[j], T[j]))
        for j in range(3):
            if k > 0:  # the base ring joins two fixed nodes: it would carry nothing, so it is left out
                cables.append((B[j], B[(j + 1) % 3]))
            cables.append((T[j], T[(j + 1) % 3]))
            # Both side cables: with twist > 150 degrees each stage then has a prestress in which both are
            # taut, and the stage is kinematically determinate (no soft mechanism for gravity to excite).
            cables.append((B[j], T[(j + 1) % 3]))
            cables.append((B[(j + 1) % 3], T[j]))
        if k > 0:
            Tp = [6 * (k - 1) + 3 + j for j in range(3)]
            Bp = [6 * (k - 1) + j for j in range(3)]
            for j in range(3):
                # Overlap zig-zag: this stage's bottom node hangs on the two nearest top nodes below it ...
                d = np.linalg.norm(X[Tp] - X[B[j]], axis=1)
                for q in np.argsort(d, kind="stable")[:2]:
                    cables.append((Tp[q], B[j]))
            for j in range(3):
                # ... and, so the interface can carry a self-stress (its cables must not all pull the same
                # way), the previous top node ties up to the nearest top node of this stage and this
                # bottom node ties down to the nearest bottom node of the previous stage.
                d = np.linalg.norm(X[T] - X[Tp[j]], axis=1)
                cables.append((Tp[j], T[int(np.argmin(d))]))
                d = np.linalg.norm(X[Bp] - X[B[j]], axis=1)
                cables.append((Bp[int(np.argmin(d))], B[j]))
    return X, np.array(struts), np.array(cables)


def tower(
    stages: int = 3,
    radius: float = 0.5,
    stage_height: float = 0.8,
    overlap: float = 0.3,
    twist_deg: float = 165.0,
    shift_deg: float = 60.0,
    node_mass: float = 0.5,
    strut_stiffness: float = 4.0e4,
    cable_stiffness: float = 1.0e4,
    prestress: float = 20.0,
    gravity=(0.0, 0.0, -9.81),
    strut_radius: float = 0.015,
    cable_radius: float = 0.003,
    check_stability: bool = True,
    name: str | None = None,
) -> dict:
    """A tower of ``stages`` stacked twisted prisms on a fixed base, in exact static equilibrium.

    Topology: stage k has its own six nodes (bottom ``n{6k}..n{6k+2}``, top ``n{6k+3}..n{6k+5}``), so every
    node has exactly one strut; ``6*stages`` nodes, ``3*stages`` struts, ``24*stages - 15`` cables; the
    three bottom nodes of stage 0 are fixed. Each stage is a prism of ``radius`` (m), height
    ``stage_height`` (m), top rotated by ``twist_deg`` (> 150) from its bottom, with top ring, bottom ring
    (not for the fixed base) and two side cables per face. Stage k+1 starts ``stage_height - overlap`` (m)
    above stage k, rotated by ``twist_deg + shift_deg``; its bottom nodes hang on the two nearest top nodes
    of stage k, plus one tie from each stage-k top node up to stage k+1's top and one from each stage-(k+1)
    bottom node down to stage k's bottom.

    Form-finding (force method): at this geometry the equilibrium matrix has full row rank with
    ``9*stages - 6`` independent self-stresses to spare, so a linear programme picks the member forces
    that balance ``node_mass * gravity`` exactly, keep every cable at least ``prestress`` (N) taut and
    every strut at least ``prestress`` compressed, with the least total cable tension times length; a
    minimum-norm correction then removes the LP's tolerance-level residual. Rest lengths ``L = l - t/k``
    (``strut_stiffness``, ``cable_stiffness`` in N/m).

    With ``check_stability`` the tangent stiffness on the free nodes is checked positive definite. Under
    full gravity a uniform tower eventually buckles under its own weight (the negative geometric stiffness
    of ever more compressed struts beats the bending stiffness), with the defaults beyond 15 stages:
    the equilibrium is still exact but unstable, and a ``RuntimeWarning`` says so. Pass
    ``gravity=(0, 0, 0)`` for a tall prestress-only tower, which is stable at any height.
    """
    if not isinstance(stages, (int, np.integer)) or stages < 1:
        raise ValueError(f"stages must be an integer >= 1, got {stages!r}")
    stages = int(stages)
    gravity = np.asarray(gravity, float)
    X, struts, cables = _tower_topology(
        stages, radius, stage_height, overlap, math.radians(twist_deg), math.radians(shift_deg)
    )
    members = np.vstack([struts, cables])
    ns, nc = len(struts), len(cables)
    N = len(X)
    fixed = np.zeros(N, bool)
    fixed[:3] = True
    free = np.full(N, -1)
    free[~fixed] = np.arange(N - 3)
    A = _equilibrium_matrix(X, members, free)
    f = np.tile(node_mass * gravity, N - 3)  # external load on the free nodes, N

    l, _ = _unit_vectors(X, members)
    cost = np.r_[np.zeros(ns), l[ns:]]  # least cable "material": sum of tension x length
    bounds = [(None, -prestress)] * ns + [(prestress, None)] * nc
    res = linprog(cost, A_eq=A, b_eq=-f, bounds=bounds, method="highs")
    if res.status != 0:
        raise RuntimeError(f"tower form-finding LP failed: {res.message}")
    t = res.x
    # Polish to round-off: t += A^T (A A^T)^-1 r (A has full row rank), the smallest change that zeroes
    # the residual; the LP's tolerance is ~1e-9 relative, far inside the prestress margins.
    AAt = (A @ A.T).tocsc()
    for _ in range(3):
        r = -f - A @ t
        t = t + A.T @ spla.spsolve(AAt, r)
    if t[ns:].min() < 0.5 * prestress or t[:ns].max() > -0.5 * prestress:
        raise RuntimeError("tower form-finding lost its tension/compression margins while polishing")

    k = np.r_[np.full(ns, strut_stiffness), np.full(nc, cable_stiffness)]
    L = _rest_lengths(l, t, k)
    if check_stability:
        Kt = _tangent_stiffness(X, members, t, k, free)
        try:
            np.linalg.cholesky(0.5 * (Kt + Kt.T))
        except np.linalg.LinAlgError:
            lam = float(np.linalg.eigvalsh(0.5 * (Kt + Kt.T))[0])
            warnings.warn(
                f"tower({stages}): the equilibrium is exact but unstable under gravity {gravity.tolist()} "
                f"(smallest tangent-stiffness eigenvalue {lam:.3g} N/m): the tower buckles under its own "
                "weight; use fewer stages, a wider or stiffer tower, or no gravity",
                RuntimeWarning,
                stacklevel=2,
            )
    def mk(i, kk, r):
        return {"a": members[i, 0], "b": members[i, 1], "stiffness": kk, "rest_length": L[i], "radius": r}

    return _scene(
        name or ("tower" if stages == 3 else f"tower{stages}"),
        X,
        gravity,
        np.full(N, node_mass),
        fixed,
        [mk(i, strut_stiffness, strut_radius) for i in range(ns)],
        [mk(ns + i, cable_stiffness, cable_radius) for i in range(nc)],
    )


# --------------------------------------------------------------------------------------------------------
# Independent checks on a scene mapping
# --------------------------------------------------------------------------------------------------------

def _parse(scene: dict):
    """Arrays from a contract-section-1 mapping: positions, total nodal masses, fixed flags, members."""
    nodes = scene["nodes"]
    index = {n["name"]: i for i, n in enumerate(nodes)}
    X = np.array([n["position"] for n in nodes], float)
    mass = np.array([float(n.get("mass", 0.0) or 0.0) for n in nodes])
    fixed = np.array([bool(n.get("fixed", False)) for n in nodes])
    members, kind, k, L = [], [], [], []
    for group in ("struts", "cables"):
        for m in scene.get(group) or []:
            a, b = index[m["nodes"][0]], index[m["nodes"][1]]
            members.append((a, b))
            rigid = group == "struts" and m["stiffness"] == "rigid"
            kind.append("rigid" if rigid else group[:-1])
            k.append(0.0 if rigid else float(m["stiffness"]))
            rest = m.get("rest_length")
            L.append(float(np.linalg.norm(X[b] - X[a])) if rest is None else float(rest))
            if group == "struts" and m.get("mass"):  # lumped half to each end, as the loader does
                mass[a] += 0.5 * float(m["mass"])
                mass[b] += 0.5 * float(m["mass"])
    return X, mass, fixed, np.array(members, int).reshape(-1, 2), np.array(kind), np.array(k), np.array(L)


def _forces(scene: dict):
    """Member forces (N, tension positive; rigid struts solved by least squares) and free-node residuals."""
    X, mass, fixed, members, kind, k, L = _parse(scene)
    g = np.asarray(scene.get("gravity") or (0.0, 0.0, 0.0), float)
    l, _ = _unit_vectors(X, members)
    t = np.where(kind == "cable", k * np.maximum(0.0, l - L), k * (l - L))
    free = np.full(len(X), -1)
    free[~fixed] = np.arange(int((~fixed).sum()))
    A = _equilibrium_matrix(X, members, free).toarray()
    rigid = kind == "rigid"
    F = (mass[~fixed, None] * g).ravel() + A[:, ~rigid] @ t[~rigid]
    # unknown forces solved by least squares: the rigid struts', and the ground's push on the free nodes
    # that touch it (at its height plus their largest member radius)
    unknown = A[:, rigid]
    if scene.get("ground") is not None:
        radius = np.zeros(len(X))
        for (a, b), m in zip(members, (scene.get("struts") or []) + (scene.get("cables") or [])):
            radius[[a, b]] = np.maximum(radius[[a, b]], float(m.get("radius", 0.0)))
        for p, node in enumerate(scene["nodes"]):   # an end cap of its own replaces its members' radius
            radius[p] = node.get("radius", radius[p])
        touching = np.flatnonzero(~fixed & (X[:, 2] - radius - scene["ground"].get("height", 0.0) <= 1e-9))
        push = np.zeros((A.shape[0], len(touching)))
        push[3 * free[touching] + 2, np.arange(len(touching))] = 1.0
        unknown = np.hstack([unknown, push])
    if unknown.shape[1]:
        solution = np.linalg.lstsq(unknown, -F, rcond=None)[0]
        t[rigid] = solution[: int(rigid.sum())]
        F = F + unknown @ solution
    return t, F.reshape(-1, 3), kind


def member_forces(scene: dict) -> dict:
    """Axial force (N, tension positive) of every member of a scene mapping at its given geometry.

    Elastic members from their constitutive law; rigid struts from the least-squares solution of
    equilibrium at the free nodes. Returns ``{"struts": {name: t}, "cables": {name: t}}``.
    """
    t, _, _ = _forces(scene)
    names = [m["name"] for m in scene.get("struts") or []] + [m["name"] for m in scene.get("cables") or []]
    ns = len(scene.get("struts") or [])
    return {
        "struts": {n: float(v) for n, v in zip(names[:ns], t[:ns])},
        "cables": {n: float(v) for n, v in zip(names[ns:], t[ns:])},
    }


def equilibrium_residual(scene: dict) -> float:
    """Largest norm (N) of the net force on any free node of a scene mapping at rest at its positions.

    Gravity on the lumped masses, cable ``k max(0, l - L)``, elastic strut ``k (l - L)``, and rigid-strut
    forces and the ground's vertical push on the nodes touching it chosen by least squares (so a rigid
    scene is judged by whether *some* strut forces and ground reactions balance it).
    """
    _, F, _ = _forces(scene)
    return float(np.linalg.norm(F, axis=1).max()) if len(F) else 0.0


# --------------------------------------------------------------------------------------------------------
# Writing the built-in scene files
# --------------------------------------------------------------------------------------------------------

_HEADER = (
    "# GENERATED FILE - do not edit by hand.\n"
    "# Regenerate with:  python -m tensegrity_sim.formfinding\n"
    "# (tensegrity_sim/formfinding.py, function {func}). Positions and rest lengths come from form-finding\n"
    "# and are written with full float precision so the scene starts in exact static equilibrium.\n"
)


def _dump(scene: dict, path: Path, func: str, notes: str) -> None:
    import yaml  # only needed for writing files

    text = _HEADER.format(func=func) + "".join(f"# {line}\n" for line in notes.splitlines())
    text += yaml.safe_dump(scene, default_flow_style=None, sort_keys=False, width=120)
    path.write_text(text)


def write_builtin_scenes(directory: str | Path | None = None) -> dict[str, float]:
    """(Re)write the built-in scenes (prism3, icosahedron, tower, icosahedron_ground, superball, three_bar);
    returns each file's equilibrium residual (N)."""
    directory = Path(directory) if directory is not None else Path(__file__).resolve().parent / "scenes"
    directory.mkdir(parents=True, exist_ok=True)
    out = {}
    specs = [
        (
            "prism3.yaml",
            "prism()",
            prism(),
            "3-strut twisted prism (simplex), 150 deg twist, free-floating, no gravity. Node mass 0.5 kg.\n"
            "Struts 1.0 m, elastic 2.0e4 N/m; cables 2.0e3 N/m; self-stress from the SVD null space,\n"
            "scaled so the most tensioned cable carries 40 N.",
        ),
        (
            "icosahedron.yaml",
            "icosahedron()",
            icosahedron(),
            "6-strut, 24-cable expanded octahedron (SUPERball-like), free-floating, no gravity.\n"
            "Rigid struts 1.684 m, 3.5 kg each lumped as 1.75 kg per end node; cables 613 N/m.\n"
            "Prestress: every cable carries 80 N (rest length = length - 80/613 m).",
        ),
        (
            "tower.yaml",
            "tower(3)",
            tower(3),
            "3-stage tower of twisted prisms, base nodes fixed, gravity -9.81 m/s^2 along z.\n"
            "Node mass 0.5 kg; struts elastic 4.0e4 N/m; cables 1.0e4 N/m; member forces from a linear\n"
            "programme: exact equilibrium with gravity, every cable >= 20 N, every strut <= -20 N.",
        ),
        (
            "icosahedron_ground.yaml",
            "icosahedron_ground()",
            icosahedron_ground(),
            "The icosahedron resting on its cable face n0 n4 n8 on the ground z = 0 (friction 0.8, plastic),\n"
            "gravity -9.81 m/s^2 along z: ground reactions on n0, n4, n8 balance the weight (206 N); member\n"
            "forces solve equilibrium with them plus the self-stress at a mean cable tension of 80 N.",
        ),
        (
            "superball.yaml",
            "superball()",
            superball(),
            "NTRT's SUPERball layout on the ground (sources: NTRT's resources/YamlStructures/BaseStructures/\n"
            "SuperBall.yaml; Bruce et al., i-SAIRAS 2014): six rigid rods 1.684 m, each a 2.8 kg uniform tube\n"
            "with 0.35 kg end caps of radius 0.05 m; 24 actuated cables 613 N/m at a mean tension of 80 N;\n"
            "resting on the cable triangle n0 n4 n8 (friction 0.99), in exact static equilibrium.",
        ),
        (
            "three_bar.yaml",
            "three_bar()",
            three_bar(),
            "A 3-bar robot standing on its bottom triangle (sources: the 3-strut prism, NTRT's 3Prism.yaml; 3-bar\n"
            "robots with a motor on each rod, Kim et al., ROBIO 2014): rigid rods 0.6 m of 0.15 kg uniform, a\n"
            "0.3 kg motor at mid-rod (payload), 0.05 kg end caps of radius 0.03 m; actuated cables c0-c5 (the\n"
            "triangles), passive c6-c8 (the sides), 2000 N/m, self-stress 100 N in the most tensioned cable.",
        ),
    ]
    for fname, func, scene, notes in specs:
        _dump(scene, directory / fname, func, notes)
        out[fname] = equilibrium_residual(scene)
    return out


def main(argv: list[str] | None = None) -> int:
    for fname, r in write_builtin_scenes().items():
        print(f"{fname}: max free-node residual force {r:.3e} N")
    return 0


if __name__ == "__main__":
    sys.exit(main())
