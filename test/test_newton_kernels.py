"""The compiled semismooth Newton method of the friction solver (``methods/contact/_newton_kernels.py``) against
its numpy reference (``friction.alart_curnier``, ``friction.newton_descend``): the Alart–Curnier equation and
its Jacobian on random problems through each of its branches, and Newton's descent on the problems the
friction solver met where its modes cycled (a prism thrown onto the ground, the inextensible roll), each to
1e-12 of the problem's impulses."""
import warnings
from pathlib import Path

import numpy as np
import pytest
import throw_cases as T

import tensegrity_sim as ts
from tensegrity_sim.commands import load_commands
from tensegrity_sim.methods.contact import _newton_kernels as K
from tensegrity_sim.methods.contact import friction as F

ROOT = Path(__file__).resolve().parents[1]


def _problem(rng, n_rows, k):
    """A random Delassus problem of ``n_rows`` rows and ``k`` contacts (n = n_rows + 3 k unknowns): the rows a random
    map of 3 n velocities, a positive definite inverse mass, rates, effective masses and friction coefficients."""
    n = n_rows + 3 * k
    rates = rng.normal(size=(n, 3 * n))
    delassus = rates @ np.diag(rng.uniform(0.5, 2.0, 3 * n)) @ rates.T
    rho = 1.0 / np.abs(np.diag(delassus))
    return rng.normal(size=n), delassus, rho, rng.uniform(0.2, 1.5, k)


@pytest.mark.parametrize("seed", range(6))
def test_the_equation_and_its_jacobian_match_the_reference(seed):
    rng = np.random.default_rng(seed)
    n_rows, n_eq, k = 5, 2, 3
    free_rates, delassus, rho, mu = _problem(rng, n_rows, k)
    branches = set()
    for _ in range(40):
        r = rng.normal(size=len(free_rates)) * rng.choice([0.1, 1.0, 10.0])
        phi, jac = K.alart_curnier(r, mu, free_rates, delassus, rho, n_eq, n_rows, k)
        phi_ref, jac_ref = F.alart_curnier(r, mu, free_rates, delassus, rho, n_eq, n_rows, k)
        scale = max(np.abs(phi_ref).max(), 1.0)
        assert np.abs(phi - phi_ref).max() <= 1e-12 * scale
        assert np.abs(jac - jac_ref).max() <= 1e-12 * max(np.abs(jac_ref).max(), 1.0)
        # which pieces the iterate lies in: rows acting or not, discs inside, on their edge with the normal
        # lifting them, or out with no normal impulse
        res = free_rates + delassus @ r
        trial = r[n_eq:n_rows + k] + rho[n_eq:n_rows + k] * res[n_eq:n_rows + k]
        branches |= {("acting", bool(t > 0)) for t in trial}
        s = trial[n_rows - n_eq:]
        t = r[n_rows + k:] - rho[n_rows + k:] * res[n_rows + k:]
        size = np.hypot(t[0::2], t[1::2])
        branches |= {("disc", bool(z > mu[c] * max(s[c], 0.0)), bool(s[c] > 0)) for c, z in enumerate(size)}
    assert {("acting", True), ("acting", False), ("disc", True, True), ("disc", False, True),
            ("disc", True, False)} <= branches


def _recorded(monkeypatch, run) -> list[tuple]:
    """The arguments of every Newton descent the friction solver takes while ``run()`` steps (``r`` copied:
    the kernel changes none of its inputs, the copy keeps the test independent of that)."""
    calls = []
    descend = F.newton_kernels.newton_descend

    def recording(r, *args):
        calls.append((r.copy(), *args))
        return descend(r, *args)

    monkeypatch.setattr(F.newton_kernels, "newton_descend", recording)
    run()
    monkeypatch.undo()
    return calls


def _throw_33():
    """test_throws.py's throw 33 (prism3, inextensible): its modes cycle within 100 steps."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        case = T.random_throw(np.random.default_rng([28, 33]), steps=100)
        sim = ts.Simulator(T.throw_scene(case), method=case["method"], dt=1e-3)
    for _ in range(100):
        sim.step()


def _roll():
    """The inextensible roll of examples/roll.yaml to 0.13 s into its let-out (1.43 s), the icosahedron rocking on
    its edges: the Newton method answers a hundred of its friction solves."""
    scene = ts.load_scene("icosahedron_ground")
    schedule = load_commands(ROOT / "examples" / "roll.yaml", scene)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sim = ts.Simulator(scene, method="inextensible", dt=1e-3, contacts=())
    base = sim.rest_lengths
    for _ in range(1430):
        sim.set_rest_lengths(schedule.rest_lengths_at(sim.time, base))
        sim.step()


@pytest.mark.parametrize("run", [_throw_33, _roll], ids=["throw 33", "roll"])
def test_newton_descents_match_the_reference(run, monkeypatch):
    calls = _recorded(monkeypatch, run)
    assert calls
    iterations = 0
    for r0, mu, its, free_rates, delassus, rho, n_eq, n_rows, k, tol, scale, line_search, dampings in calls:
        args = (mu, its, free_rates, delassus, rho, n_eq, n_rows, k, tol, scale, line_search, dampings)
        r, taken = K.newton_descend(r0.copy(), *args)
        r_ref, taken_ref = F.newton_descend(r0.copy(), *args)
        assert taken == taken_ref
        assert np.abs(r - r_ref).max() <= 1e-12 * max(np.abs(r_ref).max(), scale)
        iterations += taken
    assert iterations >= len(calls)   # Newton stepped (not only starts already within tolerance)
