"""Member-member contact response (``contact: response: true``): the geometry of the contact rows that
``methods/contact/friction.py`` adds to a method's velocity problem beside the ground's.

**Rows.** Two capsules (members of the scene's ``contact: kinds`` with a radius > 0, no shared node) touch where
their segments come within ``r_a + r_b``; at a configuration ``x`` their closest points are ``p_a = (1 - s) x_a0
+ s x_a1`` and ``p_b = (1 - t) x_b0 + t x_b1``
(:func:`~tensegrity_sim.methods.contact.detection.contact_geometry`), with the unit normal ``n`` from a to b and
the gap ``g = |p_b - p_a| - r_a - r_b``. The contact's relative velocity is that of the two material points, ``u
= sum_j w_j v_j`` over the four nodes with the weights ``w = (-(1 - s), -s, 1 - t, t)``, so the contact is one
general row of ``methods/qp/solvers.py`` (four node entries) and its impulse ``P`` acts as ``w_j P`` on node
``j``: the impulses on a and b are equal and opposite, and they act at the contact's points, so linear momentum
is exact and angular momentum is exact when the points coincide (in contact, up to the gap). ``(s, t, n)`` are
frozen over a sub-step, taken at the configuration the method arms the contacts at, like a cable's direction at
the midpoint.

**Targets** are the ground's with ``n . u`` for ``v_z``: the rate that closes the gap exactly by the
sub-step's end, ``n . u >= -g / half``, capped at the reversal of the rate at the sub-step's start (no
positive work, and the QP stays feasible); Newton's law ``n . u+ >= -e n . u-`` at an impact. Unlike the
flat ground, a pair whose members turn drifts: the row is exact to first order only, so a resting pair of
turning members sinks by ``O((h omega)^2 r)`` per step (measured 2e-9 m per 1 ms step for a strut turning
at 0.44 rad/s in the elastic method), which the cap would never correct. A penetration deeper than
``TOUCH_TOL`` is therefore pushed back to ``-TOUCH_TOL`` (a target of at most ``TOUCH_TOL / half``, so
the energy this can add is below ``m (TOUCH_TOL / h)^2 / 2`` per step: 5e-13 J for 1 kg at 1 ms).
Friction: the same Coulomb disc and mode fixed point as the ground, in the tangent plane of ``n``
(``tangents``), with the scene's ``contact: friction``.

**Impacts** are located like the ground's landings: a pair out of contact at the sub-step's start whose
capsules meet on the straight path from ``x`` to the free motion's end (exact without forces; the
parabola of a node under gravity differs from it by ``O(tau^2)``) cuts the sub-step where they meet, found
by the certified continuous search of ``methods/contact/detection.py``
(:func:`~tensegrity_sim.methods.contact.detection.transitions`).

**Pairs.** Only pairs whose boxes overlap are examined (sort and sweep, ``contact.box_pairs``), with boxes
spanning the members' motion over the sub-step plus their radii; cost grows with the pairs near each other.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .detection import ContactDetector, box_pairs, contact_geometry, transitions
from ...system import System

__all__ = ["MemberContacts", "Armed", "tangents"]


@dataclass
class Armed:
    """Member contacts armed for the next solves (k of them).

    keys: (k,) int, ``i * n_members + j`` for the pair of members ``i < j`` (system order).
    nodes: (k, 4) system node indices ``(a0, a1, b0, b1)``; weights: (k, 4) ``(-(1-s), -s, 1-t, t)``.
    normals: (k, 3) unit, from a to b. targets: (k,) m/s, ``n . u >= targets``. touching: (k,) bool.
    """

    keys: np.ndarray
    nodes: np.ndarray
    weights: np.ndarray
    normals: np.ndarray
    targets: np.ndarray
    touching: np.ndarray


def tangents(normals: np.ndarray) -> np.ndarray:
    """(k, 2, 3) an orthonormal basis of the plane normal to each of ``normals`` (k, 3)."""
    axis = np.eye(3)[np.argmin(np.abs(normals), axis=1)]   # the axis least aligned with n
    t1 = np.cross(normals, axis)
    t1 /= np.linalg.norm(t1, axis=1)[:, None]
    return np.stack([t1, np.cross(normals, t1)], axis=1)


class MemberContacts:
    """Which member pairs are in contact or about to be, their rows and targets (module docstring)."""

    def __init__(self, system: System):
        self.system = system
        self.detector = ContactDetector(system, system.scene.contact_kinds)   # eligibility, radii
        self.mu = system.scene.contact_response.friction
        self.restitution = system.scene.contact_response.restitution
        self.members = self.detector.members
        self._ends = system.ends
        self._n_members = system.n_members
        self._landing = {}   # key -> closing speed (m/s) of pairs that may land in the current elastic step

    # ------------------------------------------------------------------ pairs
    def candidates(self, x0: np.ndarray, x1: np.ndarray, pad: float) -> tuple[np.ndarray, np.ndarray]:
        """Eligible pairs ``(i, j)``, ``i < j`` (system member indices), whose capsules' boxes over positions
        ``x0`` and ``x1`` (N, 3) m, grown by ``pad`` m, overlap."""
        m = self.members
        e0, e1 = x0[self._ends[m]], x1[self._ends[m]]
        grow = self.detector.radius[m, None] + pad
        lo = np.minimum(e0.min(axis=1), e1.min(axis=1)) - grow
        hi = np.maximum(e0.max(axis=1), e1.max(axis=1)) + grow
        bi, bj = box_pairs(lo, hi)
        i, j = np.minimum(m[bi], m[bj]), np.maximum(m[bi], m[bj])
        ok = self.detector.eligible(i, j)
        key = np.unique(i[ok] * self._n_members + j[ok])
        return key // self._n_members, key % self._n_members

    def frames(self, x: np.ndarray, i: np.ndarray, j: np.ndarray):
        """At ``x`` (N, 3) for the pairs ``(i, j)`` (k,): nodes (k, 4), weights (k, 4), normals (k, 3), gaps (k,) m."""
        nodes = np.concatenate([self._ends[i], self._ends[j]], axis=1)
        _, _, normal, gap, s, t = contact_geometry(x[nodes], self.detector.radius[i] + self.detector.radius[j])
        weights = np.stack([s - 1.0, -s, 1.0 - t, t], axis=1)
        return nodes, weights, normal, gap

    @staticmethod
    def rates(v: np.ndarray, nodes: np.ndarray, weights: np.ndarray, normals: np.ndarray) -> np.ndarray:
        """Normal rates ``n . u`` (k,) m/s of contacts for node velocities ``v`` (N, 3)."""
        return np.einsum("kj,kjd,kd->k", weights, v[nodes], normals)

    def _armed(self, i, j, nodes, weights, normals, targets, touching) -> Armed:
        return Armed(i * self._n_members + j, nodes, weights, normals, targets, touching)

    @staticmethod
    def _speed(v: np.ndarray) -> float:
        return float(np.abs(v).max(initial=0.0))

    # ------------------------------------------------------------------ arming
    def arm_step(self, x_m: np.ndarray, v: np.ndarray, v0: np.ndarray, half: float, touch_tol: float) -> Armed:
        """The pairs that may touch by the end of a sub-step ending at ``x_m + half * v_f`` (as
        ``ContactSet.arm_step``): gap ``g`` at ``x_m`` minus ``half`` times the closing free rate within
        ``touch_tol``; each targets ``-g / half``, capped at the reversal of its rate for ``v`` (N, 3).
        Also records, for the elastic step's closing kick, the closing speed of those not touching."""
        reach = half * (self._speed(v0) + self._speed(v))
        i, j = self.candidates(x_m, x_m, reach + touch_tol)
        nodes, weights, normals, gap = self.frames(x_m, i, j)
        rate0 = self.rates(v0, nodes, weights, normals)
        armed = gap - half * np.abs(rate0) <= touch_tol
        target = np.minimum(-gap / half, -self.rates(v, nodes, weights, normals))
        # the rows are linear at frozen (s, t, n), so a turning pair drifts inwards by O((h omega)^2 r) per
        # step, which the cap alone would never correct: a penetration deeper than touch_tol is pushed back
        # to touch_tol (the only push the stabiliser makes: at most touch_tol / half m/s)
        np.maximum(target, -(gap + touch_tol) / half, out=target)
        touching = gap <= touch_tol
        out = self._armed(i[armed], j[armed], nodes[armed], weights[armed], normals[armed], target[armed],
                          touching[armed])
        landing = armed & ~touching
        self._landing = dict(zip((i[landing] * self._n_members + j[landing]).tolist(),
                                 np.maximum(-rate0[landing], 0.0).tolist()))
        return out

    def _touching(self, x: np.ndarray, touch_tol: float):
        i, j = self.candidates(x, x, touch_tol)
        nodes, weights, normals, gap = self.frames(x, i, j)
        keep = gap <= touch_tol
        return i[keep], j[keep], nodes[keep], weights[keep], normals[keep]

    def arm_impact(self, x: np.ndarray, v: np.ndarray, dt: float, touch_tol: float) -> tuple[Armed, bool]:
        """The pairs touching at ``x``: those closing by more than ``touch_tol`` per step ``dt`` get Newton's law
        ``n . u+ >= -e n . u-``, the others ``n . u+ >= 0``. Returns them and whether any impacts."""
        i, j, nodes, weights, normals = self._touching(x, touch_tol)
        rate = self.rates(v, nodes, weights, normals)
        impacting = rate * dt < -touch_tol
        return (self._armed(i, j, nodes, weights, normals, np.where(impacting, -self.restitution * rate, 0.0),
                            np.ones(len(i), dtype=bool)), bool(impacting.any()))

    def arm_settle(self, x: np.ndarray, touch_tol: float) -> Armed:
        """The pairs touching at the end of an elastic step: ``n . u >= 0``, or ``e`` times the closing speed
        before the drift's impulse stopped them for those that landed in this step."""
        i, j, nodes, weights, normals = self._touching(x, touch_tol)
        keys = i * self._n_members + j
        landing = np.array([self._landing.get(k, 0.0) for k in keys.tolist()])
        return self._armed(i, j, nodes, weights, normals, self.restitution * landing, np.ones(len(i), dtype=bool))

    def first_impact(self, x: np.ndarray, v: np.ndarray, v0: np.ndarray, tau: float, touch_tol: float) -> float:
        """Fraction of the sub-step (0, 1] at which the first pair apart at ``x`` (gap above ``touch_tol``)
        meets on the straight path to the free motion's end ``x + tau (v + v0) / 2``; 1.0 if none does."""
        x_end = x + (0.5 * tau) * (v + v0)
        i, j = self.candidates(x, x_end, 0.0)
        if not len(i):
            return 1.0
        nodes = np.concatenate([self._ends[i], self._ends[j]], axis=1)
        radii = self.detector.radius[i] + self.detector.radius[j]
        apart = contact_geometry(x[nodes], radii)[3] > touch_tol
        if not apart.any():
            return 1.0
        _, when, begin, _, _ = transitions(x[nodes[apart]], x_end[nodes[apart]], radii[apart],
                                              np.zeros(int(apart.sum()), dtype=bool))
        return float(np.min(when[begin], initial=1.0))
