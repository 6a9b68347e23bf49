"""Ground contacts as events (contract §5): a node begins touching the ground when its gap
(``methods/contact/friction.py``: height above the ground minus its radius) drops to ``TOUCH_TOL`` and ends when
it rises above it. Events and active contacts name the pair ``(node name, "ground")``: the node is what
touches (its largest member's capsule end), and two ends of one strut are two contacts.
"""
from __future__ import annotations

import numpy as np

from .detection import ActiveContact
from .friction import TOUCH_TOL
from ...results import ContactEvent
from ...system import System

__all__ = ["GroundDetector", "GROUND", "walk_copies"]

GROUND = "ground"
_DOWN = np.array([0.0, 0.0, -1.0])


class GroundDetector:
    """Begin/end events of the nodes' ground contacts, and the contacts going on (with the impulses of
    the last step). A begin's time is where the node's free path from the step's start (its velocity
    and gravity) reaches the ground, as the methods locate an impact; an end's is interpolated linearly
    between the step's two gaps."""

    def __init__(self, system: System):
        self.names = system.scene.node_names
        self.height = system.scene.ground.height
        self.radii = system.scene.node_radii
        self.free = system.free
        self.gravity = float(system.scene.gravity[2])
        self.reset(system.scene.positions)

    def gaps(self, x: np.ndarray) -> np.ndarray:
        return x[:, 2] - self.radii - self.height

    def reset(self, positions: np.ndarray) -> None:
        """No contact known at ``positions``: nodes touching there begin at the next step's start."""
        self._inside = np.zeros(len(self.names), dtype=bool)
        self._since = np.full(len(self.names), np.nan)
        self.impulses = np.zeros((len(self.names), 3))

    def _event(self, kind: str, p: int, x: np.ndarray, time: float, gap: float) -> ContactEvent:
        point = x[p].copy()
        ground = point.copy()
        ground[2] = self.height
        point[2] -= self.radii[p]
        return ContactEvent(kind, (self.names[p], GROUND), time, point, ground, _DOWN.copy(), gap,
                            float(self.impulses[p, 2]), self.impulses[p].copy() * [1.0, 1.0, 0.0])

    def step(self, x0: np.ndarray, x1: np.ndarray, v0: np.ndarray, t0: float, dt: float,
             impulses: np.ndarray | None) -> tuple[ContactEvent, ...]:
        """The events (time order) of a step from ``x0`` to ``x1`` (N, 3) m starting at ``t0`` s with
        velocities ``v0`` (N, 3) m/s; ``impulses`` (N, 3) N*s: the ground's impulses of the step (or None)."""
        self.impulses = np.zeros_like(self.impulses) if impulses is None else impulses
        g0, g1 = self.gaps(x0), self.gaps(x1)
        now = ((g1 <= TOUCH_TOL) | (self.impulses[:, 2] > 0)) & self.free
        changed = np.flatnonzero(now != self._inside)
        if not changed.size:
            return ()
        # the crossing of TOUCH_TOL on the straight path between the step's ends (0 if already there)
        frac = np.clip(np.divide(g0[changed] - TOUCH_TOL, g0[changed] - g1[changed],
                                 out=np.zeros(changed.size), where=g0[changed] != g1[changed]), 0.0, 1.0)
        # a landing: the small root of g0 + vz t + a t^2 / 2 = TOUCH_TOL on the free path
        g, vz, a = g0[changed] - TOUCH_TOL, v0[changed, 2], self.gravity
        disc = np.sqrt(np.maximum(vz * vz - 2.0 * a * g, 0.0))
        path = np.divide(2.0 * g, (-vz + disc) * dt, out=np.full(changed.size, np.nan), where=(-vz + disc) > 0)
        landing = now[changed] & (g > 0) & np.isfinite(path)
        frac[landing] = np.clip(path[landing], 0.0, 1.0)
        events = []
        for p, f in sorted(zip(changed, frac), key=lambda pf: (pf[1], pf[0])):
            time = float(t0 + f * dt)
            xp = (1.0 - f) * x0 + f * x1   # the points: on the straight path (the gap is ~0 at a landing)
            kind = "begin" if now[p] else "end"
            if now[p]:
                self._since[p] = time
            events.append(self._event(kind, int(p), xp, time, float((1.0 - f) * g0[p] + f * g1[p])))
        self._inside = now
        return tuple(events)

    def walk(self, x0: np.ndarray, v0: np.ndarray, positions: np.ndarray, velocities: np.ndarray,
             impulses: np.ndarray, t0: float, dt: float) -> list[ContactEvent]:
        """The events of consecutive steps from ``x0``, ``v0`` (N, 3) to ``positions``, ``velocities``
        (K, N, 3) in turn, with the ground's ``impulses`` (K, N, 3) N*s of each, the first starting at
        ``t0`` s: :meth:`step` called for the steps where a node's contact begins or ends only (the others
        would return no event and change nothing but the last impulses), found for all steps at once."""
        events: list[ContactEvent] = []
        for per_step in walk_copies([self], x0[..., None], v0[..., None], positions[..., None],
                                    velocities[..., None], impulses[..., None], t0, dt):
            events.extend(per_step[0])
        return events

    def changes(self, positions: np.ndarray, impulses: np.ndarray) -> np.ndarray:
        """(K,) bool: the consecutive steps to ``positions`` (K, N, 3) with ``impulses`` (K, N, 3) at which
        :meth:`step` would find an event; at the others it only keeps the impulses (``impulses = ...``)."""
        now = (positions[:, :, 2] - self.radii - self.height <= TOUCH_TOL) | (impulses[:, :, 2] > 0)
        now &= self.free
        changed = np.empty(len(now), dtype=bool)
        changed[0] = (now[0] != self._inside).any()
        changed[1:] = (now[1:] != now[:-1]).any(axis=1)
        return changed

    def active(self, positions: np.ndarray) -> tuple[ActiveContact, ...]:
        """Every node touching the ground now, with its gap and the last step's impulses."""
        out = []
        for p in np.flatnonzero(self._inside):
            e = self._event("begin", int(p), positions, float(self._since[p]), float(self.gaps(positions)[p]))
            out.append(ActiveContact(e.members, e.time, e.point_a, e.point_b, e.normal, e.distance,
                                     e.normal_impulse, e.tangential_impulse))
        return tuple(out)


def _changes(detectors: list[GroundDetector], positions: np.ndarray, impulses: np.ndarray) -> np.ndarray:
    """(K, B) bool: the steps to ``positions`` (K, N, 3, B) with the ground's ``impulses`` (K, N, 3, B) at
    which a node of copy b begins or ends a contact, each step compared with the one before (the first
    with what each detector knows now): where :meth:`GroundDetector.step` has something to do."""
    first = detectors[0]
    inside = np.stack([d._inside for d in detectors], axis=-1)                                   # (N, B)
    now = (positions[:, :, 2] - first.radii[:, None] - first.height <= TOUCH_TOL) | (impulses[:, :, 2] > 0)
    now &= first.free[:, None]                                                                     # (K, N, B)
    return (now != np.concatenate([inside[None], now[:-1]])).any(axis=1)


def walk_copies(detectors: list[GroundDetector], x0: np.ndarray, v0: np.ndarray, positions: np.ndarray,
                velocities: np.ndarray, impulses: np.ndarray, t0: float, dt: float) -> list[tuple[tuple, ...]]:
    """:meth:`GroundDetector.walk` of B copies (one detector each) at once: ``x0``, ``v0`` (N, 3, B),
    ``positions``, ``velocities``, ``impulses`` (K, N, 3, B). Returns each step's events per copy (K tuples
    of B tuples); a detector is called only at the steps where one of its nodes' contacts begins or ends."""
    k, n_copies = len(positions), len(detectors)
    out = [[()] * n_copies for _ in range(k)]
    if not k:
        return [tuple(row) for row in out]
    changed = _changes(detectors, positions, impulses)
    for i, b in zip(*np.nonzero(changed)):
        start_x, start_v = (x0[..., b], v0[..., b]) if i == 0 else (positions[i - 1, ..., b], velocities[i - 1, ..., b])
        out[i][b] = detectors[b].step(start_x, positions[i, ..., b], start_v, t0 + i * dt, dt, impulses[i, ..., b])
    for b, d in enumerate(detectors):
        d.impulses = impulses[-1, ..., b].copy()
    return [tuple(row) for row in out]
