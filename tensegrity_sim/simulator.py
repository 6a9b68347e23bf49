"""The simulator: one scene, one method, a state, and the public stepping API (contract §2).

Inputs are checked here, once, at the boundary; a bad argument raises ``ValueError`` naming it and
leaves the simulator exactly as it was. The methods behind it never check anything.
"""
from __future__ import annotations

from dataclasses import replace
from typing import Mapping

import numpy as np

from .contact import ActiveContact, make_detector
from .methods import State, make_method
from .results import StepResult, Trajectory
from .scene import Scene, contact_kinds
from .system import System

__all__ = ["Simulator"]


def _check_dt(dt) -> float:
    try:
        dt = float(dt)
    except (TypeError, ValueError):
        raise ValueError(f"dt must be a positive number of seconds, got {dt!r}") from None
    if not np.isfinite(dt) or dt <= 0:
        raise ValueError(f"dt must be a positive finite number of seconds, got {dt!r}")
    return dt


class Simulator:
    """Steps a :class:`Scene` with a method picked by name.

    ``method``: "elastic", "inextensible" or "auto" (then ``method_reason`` says why).
    ``dt``: the fixed step, s.
    ``contacts``: member kinds to check for contact (see ``scene.CONTACT_KINDS``), overriding the
    scene's ``contact: kinds`` (``self.scene`` is then the scene with that override); ``()`` switches
    detection off. ``contact_kinds`` is what is in use.
    ``solver``: the QP backend of the inextensible method (``methods.qp.SOLVERS``; default: chosen by
    size, ``methods.qp.choose_solver``); ``method_settings`` reports the one in use and why.
    ``order``: 2 (default) or 4, the elastic method's order (README, "Methods": which for which error);
    ``locate_switches``: the elastic method splits a step at each slack/taut switch (default: at order 4,
    and at order 2 when ``dt`` resolves the fastest vibration; ``method_settings`` says which).
    ``reel_speed``: the inextensible method's motor top speed, m/s (default 1 m/s; ``math.inf``: none):
    a faster rest-length command is followed at that speed (``applied_rest_lengths``).
    """

    def __init__(self, scene: Scene, method: str = "auto", dt: float = 1e-3, *, contacts=None,
                 solver: str | None = None, order: int | None = None, locate_switches: bool | None = None,
                 reel_speed: float | None = None):
        if not isinstance(scene, Scene):
            raise ValueError(f"scene must be a Scene (see load_scene), got {type(scene).__name__}")
        if contacts is not None:
            # the scene as run: a log embedding it (and a replay of that log) checks the same pairs
            scene = replace(scene, contact_kinds=contact_kinds(contacts, "contacts"))
        self.scene = scene
        self.dt = _check_dt(dt)
        self.system = System(scene)
        self._method, self.method_reason = make_method(self.system, method, self.dt, solver=solver, order=order,
                                                           locate_switches=locate_switches, reel_speed=reel_speed)
        # None when nothing can be in contact: then detection costs nothing at all
        self._contacts = make_detector(self.system, scene.contact_kinds)
        self._cable_index = {name: i for i, name in enumerate(scene.cable_names)}
        self._node_index = {name: i for i, name in enumerate(scene.node_names)}
        self.reset()

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Back to the scene's initial state (time 0, initial rest lengths, no external force)."""
        s = self.scene
        self._state = State(s.positions, s.velocities, s.cable_rest_lengths, np.zeros((len(s.nodes), 3)))
        self._method.prepare(self._state)
        self._method.invalidate()
        if self._contacts is not None:
            self._contacts.reset(self._state.positions)

    @property
    def method(self) -> str:
        return self._method.name

    @property
    def method_settings(self) -> dict:
        """The method's settings worth logging."""
        return self._method.describe()

    @property
    def time(self) -> float:
        """Simulation time, s (``step_count * dt``, so it does not accumulate round-off)."""
        return self._state.step_count * self.dt

    @property
    def step_count(self) -> int:
        return self._state.step_count

    @property
    def positions(self) -> np.ndarray:
        return self._state.positions.copy()

    @property
    def velocities(self) -> np.ndarray:
        return self._state.velocities.copy()

    @property
    def rest_lengths(self) -> np.ndarray:
        return self._state.rest_lengths.copy()

    @property
    def applied_rest_lengths(self) -> np.ndarray:
        """The rest lengths in effect (n_cables,) m: ``rest_lengths`` once the motors have reached them
        (the inextensible method follows a command at ``reel_speed``)."""
        return self._method.applied_rest_lengths(self._state)

    @property
    def external_forces(self) -> np.ndarray:
        return self._state.external_forces.copy()

    # ------------------------------------------------------------------ inputs
    def _by_name_or_array(self, values, argument: str, index: Mapping[str, int], width: int | None,
                          current: np.ndarray) -> np.ndarray:
        """A full new array from a partial {name: value} mapping or a complete array; checks shape,
        names and finiteness. ``width`` is None for scalars per entry, 3 for vectors."""
        shape = current.shape
        out = current.copy()
        if isinstance(values, Mapping):
            for name, value in values.items():
                if name not in index:
                    raise ValueError(f"{argument}: unknown name {name!r} (known: {', '.join(index)})")
                try:
                    arr = np.asarray(value, dtype=float)
                except (TypeError, ValueError):
                    raise ValueError(f"{argument}[{name!r}]: not a number: {value!r}") from None
                if arr.shape != (() if width is None else (width,)):
                    expected = "a number" if width is None else f"{width} numbers"
                    raise ValueError(f"{argument}[{name!r}]: expected {expected}, got shape {arr.shape}")
                out[index[name]] = arr
        else:
            try:
                arr = np.asarray(values, dtype=float)
            except (TypeError, ValueError):
                raise ValueError(f"{argument}: expected a mapping by name or an array of shape {shape}") from None
            if arr.shape != shape:
                raise ValueError(f"{argument}: expected shape {shape}, got {arr.shape}")
            out[...] = arr
        if not np.all(np.isfinite(out)):
            raise ValueError(f"{argument}: values must be finite")
        return out

    def set_rest_lengths(self, values) -> None:
        """New cable rest lengths, m: ``{cable name: length}`` (partial) or an array in cable order."""
        new = self._by_name_or_array(values, "rest_lengths", self._cable_index, None, self._state.rest_lengths)
        bad = np.flatnonzero(new <= 0)
        if bad.size:
            name = self.scene.cable_names[bad[0]]
            raise ValueError(f"rest_lengths[{name!r}]: must be > 0, got {float(new[bad[0]])!r}")
        self._state.rest_lengths = new
        self._method.invalidate()

    def set_external_forces(self, values) -> None:
        """External node forces, N: ``{node name: [fx, fy, fz]}`` (partial) or an (N, 3) array.
        Held until replaced; a force on a fixed node has no effect."""
        new = self._by_name_or_array(values, "external_forces", self._node_index, 3, self._state.external_forces)
        self._state.external_forces = new
        self._method.invalidate()

    # ------------------------------------------------------------------ stepping
    def step(self) -> StepResult:
        """Advance one step of ``dt``."""
        out = self._method.step(self._state)
        st = self._state
        contacts = () if self._contacts is None else self._contacts.step(st.positions, out.positions,
                                                                          self.time, self.dt)
        st.positions, st.velocities = out.positions, out.velocities
        st.step_count += 1
        return StepResult(
            time=self.time,
            positions=out.positions.copy(),
            velocities=out.velocities.copy(),
            impulses=out.impulses,
            tensions=out.impulses / self.dt,
            slack=self.slack() if out.slack is None else out.slack,
            contacts=contacts,
        )

    @property
    def contact_kinds(self) -> tuple[str, ...]:
        """The member kinds contact detection checks (the scene's, or the ``contacts`` override)."""
        return self.scene.contact_kinds

    def active_contacts(self) -> tuple[ActiveContact, ...]:
        """Every contact going on now (begun, not yet ended), with its current gap (negative while the
        members overlap) and closest points: the events only mark begins and ends."""
        return () if self._contacts is None else self._contacts.active(self._state.positions)

    def slack(self) -> np.ndarray:
        """(n_cables,) bool: the cables slack now, in the method's model."""
        return self._method.slack(self._state.positions, self._state.rest_lengths)

    def run(self, duration: float | None = None, *, steps: int | None = None, callback=None) -> Trajectory:
        """Run ``steps`` steps, or ``round(duration / dt)``; returns them stacked.

        ``callback(k, result)`` is called after each step (a progress bar, a command schedule).
        """
        if (duration is None) == (steps is None):
            raise ValueError("run: give exactly one of duration (s) or steps")
        if steps is None:
            d = float(duration)
            if not np.isfinite(d) or d < 0:
                raise ValueError(f"duration must be a finite number of seconds >= 0, got {duration!r}")
            steps = int(round(d / self.dt))
        if isinstance(steps, bool) or int(steps) != steps or steps < 0:
            raise ValueError(f"steps must be a whole number >= 0, got {steps!r}")
        steps = int(steps)
        n, nc = len(self.scene.nodes), len(self.scene.cables)
        time = np.empty(steps)
        pos = np.empty((steps, n, 3))
        vel = np.empty((steps, n, 3))
        imp = np.empty((steps, nc))
        slack = np.empty((steps, nc), dtype=bool)
        contacts = []
        for k in range(steps):
            r = self.step()
            time[k], pos[k], vel[k], imp[k], slack[k] = r.time, r.positions, r.velocities, r.impulses, r.slack
            contacts.extend(r.contacts)
            if callback is not None:
                callback(k, r)
        return Trajectory(time, pos, vel, imp, imp / self.dt, slack, contacts)

    # ------------------------------------------------------------------ invariants
    def energy(self) -> dict[str, float]:
        """Energies, J: kinetic, strain (what the method's model stores), gravity (``-sum m g.x``), total."""
        st, sys = self._state, self.system
        kinetic = 0.5 * float(np.sum(sys.masses[:, None] * st.velocities ** 2 * sys.free[:, None]))
        strain = self._method.strain_energy(st.positions, st.rest_lengths)
        gravity = -float(np.sum(sys.gravity_force * st.positions))
        return {"kinetic": kinetic, "strain": strain, "gravity": gravity,
                "total": kinetic + strain + gravity}

    def momentum(self) -> tuple[np.ndarray, np.ndarray]:
        """Total linear momentum (3,) kg*m/s and angular momentum about the origin (3,) kg*m^2/s,
        of the free nodes."""
        st, sys = self._state, self.system
        p = (sys.masses * sys.free)[:, None] * st.velocities
        return p.sum(axis=0), np.cross(st.positions, p).sum(axis=0)
