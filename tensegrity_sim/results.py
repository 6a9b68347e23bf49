"""What a step and a run return (contract §2)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ContactEvent", "StepResult", "Trajectory"]


@dataclass(frozen=True)
class ContactEvent:
    """The beginning or end of a contact between two members.

    kind: "begin" or "end". members: (name_a, name_b). time: s, simulation time at which it happened.
    point_a, point_b: closest points (3,) m. normal: unit (3,), from a to b.
    distance: m, segment distance minus both radii (negative is penetration).
    """

    kind: str
    members: tuple[str, str]
    time: float
    point_a: np.ndarray
    point_b: np.ndarray
    normal: np.ndarray
    distance: float


@dataclass(frozen=True)
class StepResult:
    """One step. time: s at the end of the step. positions, velocities: (N, 3) m, m/s at the end.
    impulses: (n_cables,) N*s over the step, snaps included. tensions: impulses / dt, N.
    slack: (n_cables,) bool at the end. contacts: ContactEvents that happened in the step."""

    time: float
    positions: np.ndarray
    velocities: np.ndarray
    impulses: np.ndarray
    tensions: np.ndarray
    slack: np.ndarray
    contacts: tuple[ContactEvent, ...] = ()


@dataclass(frozen=True)
class Trajectory:
    """K steps stacked: time (K,), positions and velocities (K, N, 3), impulses, tensions, slack
    (K, n_cables); contacts: every ContactEvent of the run, in time order."""

    time: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray
    impulses: np.ndarray
    tensions: np.ndarray
    slack: np.ndarray
    contacts: list[ContactEvent]
