"""Command schedules for offline runs (``tensegrity-sim run --commands FILE``).

The format (YAML) is a list of points in time, each setting the rest length of some cables and/or
the external force on some nodes::

    # times in s, rest lengths in m, forces in N (world axes)
    - time: 0.0
      rest_lengths: {c0: 0.95, c1: 0.95}
    - time: 0.5
      rest_lengths: {c0: 0.80}
      forces: {n3: [0.0, 0.0, 20.0]}
    - time: 1.0
      rest_lengths: {c0: 0.95}
      forces: {n3: [0.0, 0.0, 0.0]}

Rest lengths are linear between a cable's own points, held at its first value before it and at its
last value after it; cables never named keep the scene's rest length. Forces are steps: a node's force
holds from its point until the next point that names that node. Times must increase strictly.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .checks import describe, read_yaml, real
from .scene import Scene

__all__ = ["CommandError", "CommandSchedule", "load_commands"]


class CommandError(ValueError):
    """A command schedule that cannot be used; the message names the file, the point and the field."""


@dataclass(frozen=True)
class CommandSchedule:
    """Rest-length ramps and force steps for one scene.

    rest_times / rest_values: per scheduled cable index, its points (s) and rest lengths (m).
    force_times: (K,) s; force_values: (K, N, 3) N, the full force array from each point on.
    """

    rest_cables: np.ndarray
    rest_times: tuple[np.ndarray, ...]
    rest_values: tuple[np.ndarray, ...]
    force_times: np.ndarray
    force_values: np.ndarray

    def rest_lengths_at(self, t: float, base: np.ndarray) -> np.ndarray:
        """Every cable's rest length (n_cables,) m at time ``t``; ``base`` for unscheduled cables."""
        out = base.copy()
        for i, ts, vs in zip(self.rest_cables, self.rest_times, self.rest_values):
            out[i] = np.interp(t, ts, vs)
        return out

    def forces_at(self, t: float) -> np.ndarray | None:
        """The external forces (N, 3) N in effect at ``t``, or None before the first force point."""
        k = np.searchsorted(self.force_times, t, side="right") - 1
        return None if k < 0 else self.force_values[k]

    def inputs_at(self, times: np.ndarray, base: np.ndarray, forces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The rest lengths (T, n_cables, ...) m and external forces (T, N, 3, ...) N at each of ``times`` (T,) s,
        the very numbers :meth:`rest_lengths_at` and :meth:`forces_at` give one time at a time: ``base``
        (n_cables, ...) for the cables it does not name, ``forces`` (N, 3, ...) before its first force point
        (trailing axes: copies of a batch, each with its own base and forces)."""
        rest = np.repeat(base[None], len(times), axis=0)
        trailing = (slice(None),) + (None,) * (base.ndim - 1)
        for i, ts, vs in zip(self.rest_cables, self.rest_times, self.rest_values):
            rest[:, i] = np.interp(times, ts, vs)[trailing]
        k = np.searchsorted(self.force_times, times, side="right") - 1
        ext = np.repeat(forces[None], len(times), axis=0)
        after = k >= 0
        if after.any():
            ext[after] = self.force_values[k[after]][(...,) + (None,) * (forces.ndim - 2)]
        return rest, ext

    def apply(self, target, t: float, base: np.ndarray, forces: np.ndarray) -> None:
        """Set on ``target`` (a ``Simulator``, or what steps it for the node's offline driver) the inputs in
        effect at ``t`` (:meth:`inputs_at`, ``base`` and ``forces`` as there), each only where it differs from
        ``target``'s: how ``tensegrity-sim run --commands`` and ``Simulator.run(commands=...)`` step one at a time."""
        rest, ext = (a[0] for a in self.inputs_at(np.array([t]), base, forces))
        if not np.array_equal(rest, target.rest_lengths):
            target.set_rest_lengths(rest)
        if not np.array_equal(ext, target.external_forces):
            target.set_external_forces(ext)

    def fits(self, n_nodes: int) -> None:
        """Refuse (ValueError) a schedule made for another scene's node count."""
        if self.force_values.shape[1:] != (n_nodes, 3):
            raise ValueError(f"commands: a schedule for {self.force_values.shape[1]} nodes, the scene has {n_nodes}")


def _fail(source: str, where: str, msg: str) -> CommandError:
    return CommandError(f"{source}: {where}: {msg}")


def _finite(source, where, fld, value) -> float:
    try:
        return real(value, fld)
    except ValueError as exc:
        raise _fail(source, where, str(exc)) from None


def _mapping(source, where, fld, value) -> dict:
    """An optional ``{name: value}`` entry of a point: a mapping, or nothing (absent, null)."""
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise _fail(source, where, f"{fld} must be a mapping by name, got {describe(value)}")
    return value


def parse_commands(points: Any, scene: Scene, source: str = "<commands>") -> CommandSchedule:
    """Validate a schedule (the YAML content) against ``scene``."""
    if not isinstance(points, list) or not points:
        raise CommandError(f"{source}: must be a non-empty list of points")
    cables = {n: i for i, n in enumerate(scene.cable_names)}
    nodes = {n: i for i, n in enumerate(scene.node_names)}
    rest: dict[int, list[tuple[float, float]]] = {}
    force_times: list[float] = []
    force_values: list[np.ndarray] = []
    current = np.zeros((len(nodes), 3))
    last = -math.inf
    for k, point in enumerate(points):
        where = f"point[{k}]"
        if not isinstance(point, dict):
            raise _fail(source, where, "must be a mapping with time, rest_lengths and/or forces")
        unknown = [key for key in point if key not in ("time", "rest_lengths", "forces")]
        if unknown:
            raise _fail(source, where, f"unknown key {describe(unknown[0])} (allowed: forces, rest_lengths, time)")
        if "time" not in point:
            raise _fail(source, where, "missing required key 'time'")
        t = _finite(source, where, "time", point["time"])
        if t < 0 or t <= last:
            raise _fail(source, where, f"time must be >= 0 and increase strictly, got {t!r} after {last!r}")
        last = t
        for name, value in _mapping(source, where, "rest_lengths", point.get("rest_lengths")).items():
            if not isinstance(name, str) or name not in cables:
                raise _fail(source, where, f"rest_lengths: unknown cable {describe(name)}")
            length = _finite(source, where, f"rest_lengths[{name!r}]", value)
            if length <= 0:
                raise _fail(source, where, f"rest_lengths[{name!r}] must be > 0, got {length!r}")
            rest.setdefault(cables[name], []).append((t, length))
        forces = _mapping(source, where, "forces", point.get("forces"))
        if forces:
            for name, value in forces.items():
                if not isinstance(name, str) or name not in nodes:
                    raise _fail(source, where, f"forces: unknown node {describe(name)}")
                if not isinstance(value, (list, tuple)) or len(value) != 3:
                    raise _fail(source, where, f"forces[{name!r}] must be 3 numbers, got {describe(value)}")
                current[nodes[name]] = [_finite(source, where, f"forces[{name!r}]", v) for v in value]
            force_times.append(t)
            force_values.append(current.copy())
    order = sorted(rest)
    return CommandSchedule(
        rest_cables=np.array(order, dtype=np.intp),
        rest_times=tuple(np.array([p[0] for p in rest[i]]) for i in order),
        rest_values=tuple(np.array([p[1] for p in rest[i]]) for i in order),
        force_times=np.array(force_times),
        force_values=np.array(force_values).reshape(-1, len(nodes), 3),
    )


def load_commands(path: str | Path, scene: Scene) -> CommandSchedule:
    """Read and validate a schedule file for ``scene``."""
    return parse_commands(read_yaml(path, CommandError), scene, str(path))
