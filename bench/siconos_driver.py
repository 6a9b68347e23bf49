"""Siconos 4.4 (Debian's ``python3-siconos``) stepping an inextensible-cable scene: run by Debian's own
``/usr/bin/python3`` (Siconos needs Debian's numpy), driven by :mod:`bench.siconos_peer` through JSON on
stdin and stdout. Imports nothing of tensegrity_sim.

Model: one ``LagrangianLinearTIDS`` holding every free node (diagonal mass, constant external force);
each cable a ``LagrangianLinearTIR`` with ``NewtonImpactNSL(e = 0)`` on the gap ``y = L - n.(x_b - x_a)``
(``>= 0``; its multiplier is the cable's impulse, N*s); each rigid strut the same relation with
``EqualityConditionNSL`` (an MLCP then). The relations are linear in ``q`` with the unit vector ``n``
frozen, so they are re-linearised at every step's start (a Python subclass of
``LagrangianScleronomousR`` segfaults in 4.4.0). Moreau--Jean with ``theta`` (0.5: the midpoint rule).

Input: {"masses": [n_free], "q": [3 n_free], "v": [...], "force": [...], "dt", "steps", "theta",
"cables": [[a, b, L], ...], "struts": [[a, b, L], ...], "fixed": {"index": [x, y, z]}} where a node index
``>= 0`` is a free node and ``-1 - j`` is fixed node ``j``. Output: {"q", "v", "impulses" (summed over
the run, per cable), "cable_overshoot_m" (largest ``|d| - L`` of a cable at any step's end),
"strut_error_m" (largest ``| |d| - L |`` of a rigid strut), "steps"}.
"""
import json
import sys

import numpy as np


def _end(q, fixed, i):
    return q[3 * i: 3 * i + 3] if i >= 0 else np.asarray(fixed[str(-1 - i)], dtype=float)


def _linearise(q, fixed, n_dof, a, b, length):
    """(1, n_dof) row H and offset e of the gap ``L - n.(x_b - x_a)`` at ``q``."""
    d = _end(q, fixed, b) - _end(q, fixed, a)
    n = d / np.linalg.norm(d)
    h = np.zeros((1, n_dof))
    e = length
    for node, sign in ((a, 1.0), (b, -1.0)):
        if node >= 0:
            h[0, 3 * node: 3 * node + 3] = sign * n
        else:
            e -= sign * float(n @ _end(q, fixed, node))
    return h, np.array([e])


def _lengths(q, fixed, members):
    return np.array([np.linalg.norm(_end(q, fixed, b) - _end(q, fixed, a)) for a, b, _ in members])


def run(spec: dict) -> dict:
    import siconos.kernel as sk
    q0, v0 = np.asarray(spec["q"], dtype=float), np.asarray(spec["v"], dtype=float)
    n_dof, dt, steps, fixed = len(q0), float(spec["dt"]), int(spec["steps"]), spec["fixed"]
    mass = np.diag(np.repeat(np.asarray(spec["masses"], dtype=float), 3))
    ds = sk.LagrangianLinearTIDS(q0, v0, mass)
    ds.setFExtPtr(np.asarray(spec["force"], dtype=float))
    nsds = sk.NonSmoothDynamicalSystem(0.0, dt * steps)
    nsds.insertDynamicalSystem(ds)
    members = [(int(a), int(b), float(length), True) for a, b, length in spec["cables"]]
    members += [(int(a), int(b), float(length), False) for a, b, length in spec["struts"]]
    relations, interactions = [], []
    for a, b, length, cable in members:
        h, e = _linearise(q0, fixed, n_dof, a, b, length)
        rel = sk.LagrangianLinearTIR(h, e)
        law = sk.NewtonImpactNSL(0.0) if cable else sk.EqualityConditionNSL(1)
        inter = sk.Interaction(law, rel)
        nsds.link(inter, ds)
        relations.append(rel)
        interactions.append(inter)
    osi = sk.MoreauJeanOSI(float(spec["theta"]))
    problem = sk.MLCP() if spec["struts"] else sk.LCP()
    sim = sk.TimeStepping(nsds, sk.TimeDiscretisation(0.0, dt), osi, problem)
    n_cables = len(spec["cables"])
    impulses = np.zeros(n_cables)
    overshoot, strut_error = 0.0, 0.0
    cables = [m[:3] for m in members[:n_cables]]
    struts = [m[:3] for m in members[n_cables:]]
    for _ in range(steps):
        q = np.array(ds.q())
        for rel, (a, b, length, _) in zip(relations, members):
            h, e = _linearise(q, fixed, n_dof, a, b, length)
            rel.setJachqPtr(h)
            rel.setEPtr(e)
        sim.computeOneStep()
        impulses += [float(inter.lambda_(1)[0]) for inter in interactions[:n_cables]]
        sim.nextStep()
        q = np.array(ds.q())
        if cables:
            overshoot = max(overshoot, float(np.max(_lengths(q, fixed, cables) - [c[2] for c in cables])))
        if struts:
            strut_error = max(strut_error, float(np.max(np.abs(_lengths(q, fixed, struts) - [s[2] for s in struts]))))
    return {"q": np.array(ds.q()).tolist(), "v": np.array(ds.velocity()).tolist(), "impulses": impulses.tolist(),
            "cable_overshoot_m": overshoot, "strut_error_m": strut_error, "steps": steps}


if __name__ == "__main__":
    json.dump(run(json.load(sys.stdin)), sys.stdout)
