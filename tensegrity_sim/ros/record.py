"""A log's run as arrays, for the plots and the 3-D page (``tensegrity-sim plot`` / ``view``).

:func:`read_log` reads what a log holds at every publication: node positions (``~/node_poses``),
cable lengths and tensions (``~/cable_states``), impulses summed since the previous publication
(``~/cable_impulses``) and every contact event (``~/contacts``), with the scene and settings embedded
in the log. It works on logs from ``tensegrity-sim run --log`` and from the node alike (same topics).

A cable is *slack* in a publication when its tension is exactly zero, as ``tensegrity-sim info``
counts it; a *snap* is a slack-to-taut change between two consecutive publications. The energy terms
need the velocities, which a log does not hold: :func:`with_energy` recomputes them by replaying the
log (bit for bit, :func:`~tensegrity_sim.ros.replay.replay`) and reading the simulator at each
publication.
"""
from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import yaml

from ..results import ContactEvent
from ..scene import Scene
from ..viz.record import RunRecord
from .log_reader import LogError, LogReader
from .contact_messages import decode_contacts
from .interface import TOPICS
from .replay import _decode, _run_info, replay

__all__ = ["RunRecord", "read_log", "with_energy"]


def read_log(path: str | Path) -> RunRecord:
    """The publications of the log at ``path`` as a :class:`RunRecord` (no energy: see :func:`with_energy`).

    An unfinished log (cut off by a crash) gives the publications it holds whole. Raises
    :class:`~tensegrity_sim.ros.log_reader.LogError` naming the file when it is not a readable
    tensegrity_sim log or holds no publication (:class:`~.log_reader.LogCorruptError` for a corrupt record)."""
    path = Path(path)
    with LogReader(path) as reader:
        info = _run_info(reader, path)
        scene_dict = yaml.safe_load(info["scene_yaml"])
        scene = Scene.from_dict(scene_dict, source=f"{path} (embedded scene)")
        topics = json.loads(info["topics"])
        wanted = {topics[k]: k for k in ("node_poses", "cable_states", "cable_impulses", "contacts")}
        columns: dict[str, list] = {k: [] for k in ("poses", "states", "impulses", "times", "impulse_times")}
        contacts: list[ContactEvent] = []
        for message in reader.messages():
            key = wanted.get(message.topic)
            if key is None:
                continue
            msg = _decode(path, message, TOPICS[key].typename)
            if key == "node_poses":
                columns["poses"].append([(p.position.x, p.position.y, p.position.z) for p in msg.poses])
            elif key == "cable_states":
                columns["times"].append(message.log_time)
                columns["states"].append((np.asarray(msg.position, dtype=float), np.asarray(msg.effort, dtype=float)))
            elif key == "cable_impulses":
                columns["impulse_times"].append(message.log_time)
                columns["impulses"].append(np.asarray(msg.effort, dtype=float))
            else:
                contacts.extend(decode_contacts(msg))
    # a log cut off while writing a publication: keep the publications that are whole
    k = min(len(columns["poses"]), len(columns["states"]), len(columns["impulses"]))
    if k == 0:
        raise LogError(f"{path}: no publication (node_poses, cable_states and cable_impulses) in the log")
    if columns["times"][:k] != columns["impulse_times"][:k]:
        raise LogError(f"{path}: cable_states and cable_impulses are not published together")
    n_cables = len(scene.cables)
    states = columns["states"][:k]
    ground = scene_dict.get("ground")
    return RunRecord(
        path=path, scene=scene, method=info["method"], dt=float(info["dt"]),
        times=np.array(columns["times"][:k], dtype=np.int64) * 1e-9,
        positions=np.array(columns["poses"][:k], dtype=float).reshape(k, len(scene.nodes), 3),
        lengths=np.array([s[0] for s in states]).reshape(k, n_cables),
        tensions=np.array([s[1] for s in states]).reshape(k, n_cables),
        impulses=np.array(columns["impulses"][:k]).reshape(k, n_cables),
        contacts=tuple(sorted(contacts, key=lambda e: e.time)),
        ground=float(ground.get("height", 0.0)) if isinstance(ground, dict) else None,
    )


def with_energy(record: RunRecord) -> RunRecord:
    """``record`` with its energy terms (J) at every publication, recomputed by replaying its log.

    Where the replay stops reproducing the log (a log written on another numpy/BLAS build may round
    differently), the energy stops there and ``energy_note`` says so."""
    values: list[dict[str, float]] = []
    report = replay(record.path, on_publication=lambda sim: values.append(sim.energy()))
    k = min(len(values), len(record.times))
    energy = {name: np.array([v[name] for v in values[:k]]) for name in ("kinetic", "strain", "gravity", "total")}
    note = "" if report.ok else f"energy up to t = {record.times[k - 1] if k else 0.0:.3f} s: replay {report.mismatch}"
    return replace(record, energy=energy, energy_note=note)
