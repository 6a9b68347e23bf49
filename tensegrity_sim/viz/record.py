"""A run at its publications, as arrays: what the figures and the 3-D page draw. Made from a log by
:func:`tensegrity_sim.ros.record.read_log` (the figures and the page need no ROS or MCAP themselves)."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..results import ContactEvent
from ..scene import Scene
from ..system import System

__all__ = ["RunRecord"]


@dataclass(frozen=True)
class RunRecord:
    """A run at its publications (K of them), from a log.

    times: (K,) s. positions: (K, N, 3) m, scene node order. lengths, tensions: (K, C) m, N, scene cable
    order. impulses: (K, C) N*s, summed over the steps since the previous publication. contacts: every
    contact event in time order. energy: name -> (K,) J (kinetic, strain, gravity, total), empty until
    :func:`with_energy`; energy_note says why it stops early if it does.
    """

    path: Path
    scene: Scene
    method: str
    dt: float
    times: np.ndarray
    positions: np.ndarray
    lengths: np.ndarray
    tensions: np.ndarray
    impulses: np.ndarray
    contacts: tuple[ContactEvent, ...]
    ground: float | None = None       # the height of the ground plane z = h, m, if the scene has one
    energy: dict[str, np.ndarray] = field(default_factory=dict)
    energy_note: str = ""

    @property
    def slack(self) -> np.ndarray:
        """(K, C) bool: the cable carries no tension."""
        return self.tensions == 0.0

    @property
    def snaps(self) -> tuple[np.ndarray, np.ndarray]:
        """(publication index, cable index) of every slack-to-taut change, in time order."""
        slack = self.slack
        k, c = np.nonzero(slack[:-1] & ~slack[1:])
        return k + 1, c

    @property
    def system(self) -> System:
        """The scene's member arrays (``strut_ends``, ``cable_ends``, ``free``)."""
        return System(self.scene)

    @property
    def title(self) -> str:
        """Scene, method and step, for figure titles."""
        return f"{self.scene.name} - {self.method}, dt = {self.dt:g} s"
