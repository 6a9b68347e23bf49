"""Offline runs through the node logic, so ``tensegrity-sim run --log`` writes the log the node writes.

:func:`tensegrity_sim.cli.simulate` applies a command schedule and steps; with a log it drives a
:class:`CommandDriver` instead of the simulator: every command becomes the node's input message (a
``JointState`` of the cables whose rest length changes, a ``WrenchStamped`` per node whose force
changes), taken by :meth:`SimNodeLogic.receive` exactly as the node takes it, so it is logged and a replay
applies it at the same step; every step publishes when due, exactly as the node does.
"""
from __future__ import annotations

from contextlib import contextmanager
from typing import Iterator

import numpy as np

from ..results import StepResult
from ..simulator import Simulator
from . import messages as M
from .log import LogRecorder, SignalLatch, log_file_path
from .node_logic import NodeSettings, SimNodeLogic

__all__ = ["CommandDriver", "logged_run"]


class CommandDriver:
    """Commands as input messages, steps with publication; what ``simulate(..., driver=)`` drives.

    logic: the node logic (its recorder is the log). latch: a :class:`SignalLatch` checked before every
    step, so SIGINT/SIGTERM stop the run between steps, never inside a write.
    """

    def __init__(self, logic: SimNodeLogic, latch: SignalLatch | None = None):
        self.logic = logic
        self._latch = latch
        self._names = logic.sim.scene.cable_names
        self._nodes = logic.sim.scene.node_names

    @property
    def path(self):
        """The log file being written."""
        return self.logic.recorder.path

    @property
    def rest_lengths(self) -> np.ndarray:
        """The simulator's rest lengths (n_cables,) m, what :meth:`set_rest_lengths` compares with."""
        return self.logic.sim.rest_lengths

    @property
    def external_forces(self) -> np.ndarray:
        """The simulator's external forces (N, 3) N, what :meth:`set_external_forces` compares with."""
        return self.logic.sim.external_forces

    def _take(self, key: str, message) -> None:
        reason = self.logic.receive(key, message)
        if reason is not None:
            raise ValueError(f"{self.logic.topic_names[key]}: {reason}")

    def set_rest_lengths(self, values: np.ndarray) -> None:
        """Rest lengths (n_cables,) m, in cable order; only the cables that change are sent."""
        changed = np.flatnonzero(values != self.logic.sim.rest_lengths)
        header = M.header(self.logic.stamp_ns(), "")
        self._take("cable_rest_lengths", M.joint_state(header, [self._names[i] for i in changed], values[changed]))

    def set_external_forces(self, forces: np.ndarray) -> None:
        """External forces (N, 3) N; one wrench per node whose force changes."""
        changed = np.flatnonzero(np.any(forces != self.logic.sim.external_forces, axis=1))
        for i in changed.tolist():
            header = M.header(self.logic.stamp_ns(), self._nodes[i])
            self._take("external_wrench", M.wrench_stamped(header, forces[i]))

    def step(self) -> StepResult:
        """One step (and a publication when due). A failed step stops an offline run as it does without
        a log: its :class:`~tensegrity_sim.StepError` is raised, after the log has recorded it."""
        if self._latch is not None:
            self._latch.raise_if_signalled()
        r = self.logic.step()
        if r is None:
            raise self.logic.step_error
        if self.logic.publication_due:
            self.logic.publish()
        return r


@contextmanager
def logged_run(sim: Simulator, log_spec: str) -> Iterator[CommandDriver]:
    """A :class:`CommandDriver` for ``sim`` logging to ``log_spec`` (see :func:`log_file_path`); the log
    is finished when the block ends, however it ends (SIGINT and SIGTERM included)."""
    settings = NodeSettings(scene=sim.scene.source or sim.scene.name, method=sim.method,
                            solver=sim.method_settings.get("solver", "auto"), dt=sim.dt,
                            publish_rate=min(NodeSettings.publish_rate, 1.0 / sim.dt), log_path=log_spec)
    logic = SimNodeLogic(sim, settings)
    path = log_file_path(log_spec, sim.scene.name)
    if path is None:
        raise ValueError("--log: an empty path (give a .mcap file or a directory)")
    with SignalLatch() as latch, LogRecorder(path, logic.channels(), logic.run_info()) as recorder:
        logic.recorder = recorder
        yield CommandDriver(logic, latch)
