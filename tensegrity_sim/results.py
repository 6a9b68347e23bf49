"""What a step and a run return (contract §2)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["ContactEvent", "StepResult", "Trajectory"]


@dataclass(frozen=True)
class ContactEvent:
    """The beginning or end of a contact between two members.

    kind: "begin" or "end". members: (name_a, name_b). time: s, simulation time at which it happened.
    point_a, point_b: closest points (3,) m. normal: unit (3,), from a to b.
    distance: m, segment distance minus both radii (negative is penetration).
    normal_impulse: N*s, the contact's normal impulse over the step of the event (0 without a response).
    tangential_impulse: (3,) N*s, its friction impulse over that step (zero without a response).
    A ground contact names ``(node name, "ground")``; its points are the node's lowest point and the
    ground below it, its normal points down (from the node to the ground).
    """

    kind: str
    members: tuple[str, str]
    time: float
    point_a: np.ndarray
    point_b: np.ndarray
    normal: np.ndarray
    distance: float
    normal_impulse: float = 0.0
    tangential_impulse: np.ndarray = field(default_factory=lambda: np.zeros(3))


@dataclass(frozen=True)
class StepResult:
    """One step. time: s at the end of the step. positions, velocities: (N, 3) m, m/s at the end.
    impulses: (n_cables,) N*s over the step, snaps included. tensions: impulses / dt, N.
    slack: (n_cables,) bool at the end. contacts: ContactEvents that happened in the step.
    contact_impulses: (N, 3) N*s, the ground's impulse on each node over the step (z: normal, x/y:
    friction); zeros without a ground."""

    time: float
    positions: np.ndarray
    velocities: np.ndarray
    impulses: np.ndarray
    tensions: np.ndarray
    slack: np.ndarray
    contacts: tuple[ContactEvent, ...] = ()
    contact_impulses: np.ndarray | None = None


_new = object.__new__
_set = object.__setattr__


def step_result(time, positions, velocities, impulses, tensions, slack, contacts, contact_impulses) -> StepResult:
    """A :class:`StepResult` of these fields, made in a third of the dataclass constructor's time (its
    frozen ``__init__`` sets each field through ``object.__setattr__``): the per-step cost of
    ``Simulator.step``. The instance is the same frozen dataclass (equality, ``replace``, ``fields``)."""
    r = _new(StepResult)
    _set(r, "__dict__", {"time": time, "positions": positions, "velocities": velocities, "impulses": impulses,
                         "tensions": tensions, "slack": slack, "contacts": contacts,
                         "contact_impulses": contact_impulses})
    return r


@dataclass(frozen=True)
class Trajectory:
    """K steps stacked: time (K,), positions and velocities (K, N, 3), impulses, tensions, slack
    (K, n_cables); contacts: every ContactEvent of the run, in time order; contact_impulses (K, N, 3)
    N*s, the ground's impulses per step."""

    time: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray
    impulses: np.ndarray
    tensions: np.ndarray
    slack: np.ndarray
    contacts: list[ContactEvent]
    contact_impulses: np.ndarray | None = None
