"""Many copies of one structure stepped together: :class:`BatchSimulator`.

A batch is ``B`` copies of one scene's structure (topology, masses, stiffnesses, radii) that differ in
their state (positions, velocities, rest lengths) and inputs (rest-length commands, external forces).
Every array a user sees has the batch as its **leading** axis, ``(B, N, 3)``, ``(B, n_cables)``, and a
run returns ``(B, K, ...)`` (mujoco rollout's "nbatch x nstep" order). Inside, the elastic method keeps
the batch as the *last* axis (:mod:`.methods.elastic_batch`) so that one step of all copies is a few
array operations, and with a ground steps every copy in the compiled ground loop, the copies spread over
all cores (with a member contact response too: a copy's steps with an armed member pair are taken by the
reference, as in a ``Simulator``); the inextensible method solves one QP per copy and so steps a
:class:`~tensegrity_sim.simulator.Simulator` per copy (style rule 8: a ``Simulator`` is a batch of one), the
copies' compiled steps run together on every core (``InextensibleMethod.advance_copies``: each copy's own
numbers; a step its kernel leaves to Python is taken by that copy's method after it).

Each copy equals a single ``Simulator`` run from the same state with the same inputs (to round-off;
``test/test_batch.py`` requires 1e-10). A step that fails in one copy (a QP without a solution, a
non-finite result: what makes ``Simulator.step`` raise a ``StepError``) stops that copy only: its index
and reason (the error's message) are in ``failures``, its state stays the last good one, its entries in
later step results are NaN (slack False) and the other copies go on.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, replace
from typing import Mapping

import numpy as np

from .checks import float_array, time_step
from .commands import CommandSchedule
from .methods.contact.detection import CompiledDetector, make_detector
from .methods.contact.friction import TOUCH_TOL
from .methods.contact.ground import GroundDetector, walk_copies
from .methods import StepError, check_backend, choose_method
from .methods.elastic.method import ElasticMethod
from .methods.elastic.batch import ElasticBatch
from .methods.inextensible.method import InextensibleMethod
from .results import ContactEvent
from .scene import Scene, contact_kinds
from .methods.base import State
from .simulator import Simulator, _walk, absurd_speed, non_finite_report, run_plan
from .system import System

__all__ = ["BatchSimulator", "BatchStepResult", "BatchTrajectory", "TRAJECTORY_FIELDS", "structure_of"]

# the per-step arrays a run may keep (BatchSimulator.run's ``fields``; "impulses" brings the tensions)
TRAJECTORY_FIELDS = ("positions", "velocities", "impulses", "slack")

# run() steps in chunks whose per-step arrays hold about this many numbers (positions and velocities
# of every step of the chunk, ~16 MB each): the compiled loop runs a whole chunk, the contact detectors,
# the peaks and the kept steps then go through it as arrays
_CHUNK_NUMBERS = 2_000_000


@dataclass(frozen=True)
class BatchStepResult:
    """One step of every copy. time: s at the step's end (the same for all copies).
    positions, velocities: (B, N, 3) m, m/s. impulses: (B, n_cables) N*s over the step; tensions:
    impulses / dt, N. slack: (B, n_cables) bool. contacts: B tuples of ContactEvents. failed: (B,) bool,
    the copies stopped by a failure (their numbers are NaN)."""

    time: float
    positions: np.ndarray
    velocities: np.ndarray
    impulses: np.ndarray
    tensions: np.ndarray
    slack: np.ndarray
    contacts: tuple[tuple[ContactEvent, ...], ...]
    failed: np.ndarray


@dataclass(frozen=True)
class BatchTrajectory:
    """K kept steps of B copies (see ``run``): time (K,) s; positions, velocities (B, K, N, 3); impulses
    (summed since the previous kept step), tensions (their mean), slack (B, K, n_cables); contacts: per
    copy, every ContactEvent of the run (kept or not); failures: {copy index: reason} of copies stopped
    by a failure.
    Over every step, recorded or not: peak_tensions (B, n_cables) N, each cable's largest step tension
    (``impulses / dt``); snaps (B, n_cables), how often each cable went from slack to taut between
    consecutive step ends (the run's start counts as the first).
    The per-step arrays are in ``run``'s ``dtype``, None where its ``fields`` left them out (tensions with the
    impulses)."""

    time: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray
    impulses: np.ndarray
    tensions: np.ndarray
    slack: np.ndarray
    contacts: list[list[ContactEvent]]
    failures: dict[int, str]
    peak_tensions: np.ndarray
    snaps: np.ndarray


def _storage(dtype, fields) -> tuple[np.dtype, tuple[str, ...]]:
    """``run``'s ``dtype`` and ``fields`` checked: the storage dtype and the kept fields in their order."""
    try:
        store = None if dtype is None else np.dtype(dtype)
    except TypeError:
        store = None
    if store not in (np.dtype(np.float64), np.dtype(np.float32)):
        raise ValueError(f"dtype must be 'float64' or 'float32' (the kept arrays' storage), got {dtype!r}")
    if isinstance(fields, str) or not isinstance(fields, (list, tuple, set, frozenset)):
        raise ValueError(f"fields must be a list of {', '.join(TRAJECTORY_FIELDS)}, got {fields!r}")
    for f in fields:
        if f not in TRAJECTORY_FIELDS:
            raise ValueError(f"fields: unknown field {f!r} (known: {', '.join(TRAJECTORY_FIELDS)})")
    if len(set(fields)) != len(fields):
        raise ValueError(f"fields: a field named twice in {fields!r}")
    return store, tuple(f for f in TRAJECTORY_FIELDS if f in fields)


def _kept_arrays(arrays: dict, fields: tuple, kept: int, store: np.dtype) -> dict[str, np.ndarray]:
    """The kept steps' arrays (kept, B, ...) of ``fields`` (and "tensions" with "impulses") in the memory order of
    the per-step ``arrays`` (steps, B, ...) the engine gives: a kept step is then one contiguous copy."""
    names = fields + (("tensions",) if "impulses" in fields else ())
    return {f: np.empty_like(arrays[f], shape=(kept,) + arrays[f].shape[1:], dtype=bool if f == "slack" else store)
            for f in names}


def structure_of(scene: Scene) -> Scene:
    """``scene`` without its initial state (node positions and velocities, cable rest lengths): two
    scenes with equal structures can be copies of one batch. Hashable."""
    return replace(scene, name="", source="",
                   nodes=tuple(replace(n, position=(0.0, 0.0, 0.0), velocity=(0.0, 0.0, 0.0)) for n in scene.nodes),
                   cables=tuple(replace(c, rest_length=0.0) for c in scene.cables))


class BatchSimulator:
    """``batch`` copies of ``scene`` stepped together (see the module docstring).

    ``method``: "elastic", "inextensible", "massive" or "auto" (decided once, on ``scene``; ``method_reason``).
    ``dt``: s. ``positions``, ``velocities``: initial states (batch, N, 3) m, m/s, or (N, 3) for all
    copies (default: the scene's); a rigid strut must keep its length. ``solver``: QP backend of the
    inextensible method. ``contacts``: member kinds checked for contact, as for ``Simulator``.
    ``backend``: where the elastic method's steps run: "numba" (default) or "jax" (``methods/jax/``, the ``jax``
    extra: on whatever device JAX finds, a command schedule evaluated inside the compiled run) in ``dtype``
    "float64" (default) or "float32".
    """

    def __init__(self, scene: Scene, batch: int, *, method: str = "auto", dt: float = 1e-3,
                 positions=None, velocities=None, solver: str | None = None, contacts=None,
                 backend: str = "numba", dtype: str | None = None):
        if not isinstance(scene, Scene):
            raise ValueError(f"scene must be a Scene (see load_scene), got {type(scene).__name__}")
        if isinstance(batch, bool) or not isinstance(batch, (int, np.integer)) or batch < 1:
            raise ValueError(f"batch must be a whole number >= 1, got {batch!r}")
        batch = int(batch)
        n = len(scene.nodes)
        x = np.broadcast_to(scene.positions, (batch, n, 3)) if positions is None else \
            self._states(positions, "positions", batch, n)
        v = np.broadcast_to(scene.velocities, (batch, n, 3)) if velocities is None else \
            self._states(velocities, "velocities", batch, n)
        if positions is None and velocities is None:
            scenes = [scene] * batch
        else:
            scenes = [self._with_state(scene, x[b], v[b], b) for b in range(batch)]
        self._build(scene, scenes, method, dt, solver, contacts, backend, dtype)

    @classmethod
    def from_scenes(cls, scenes, *, method: str = "auto", dt: float = 1e-3, solver: str | None = None,
                    contacts=None, backend: str = "numba", dtype: str | None = None) -> "BatchSimulator":
        """One copy per scene; the scenes must share their structure (:func:`structure_of`) and may
        differ in initial positions, velocities and cable rest lengths. ``method="auto"`` is decided on
        the first scene."""
        scenes = list(scenes)
        if not scenes or not all(isinstance(s, Scene) for s in scenes):
            raise ValueError("scenes must be a non-empty sequence of Scene")
        first = structure_of(scenes[0])
        for b, s in enumerate(scenes):
            if structure_of(s) != first:
                raise ValueError(f"scenes[{b}] ({s.name!r}) differs from scenes[0] in more than its initial "
                                 f"state (positions, velocities, rest lengths): it cannot share a batch")
        self = cls.__new__(cls)
        self._build(scenes[0], scenes, method, dt, solver, contacts, backend, dtype)
        return self

    @staticmethod
    def _states(values, argument: str, batch: int, n: int) -> np.ndarray:
        """Initial states (batch, N, 3) from (batch, N, 3) or (N, 3) for every copy."""
        arr = float_array(values, argument)
        if arr.shape not in ((batch, n, 3), (n, 3)):
            raise ValueError(f"{argument}: expected shape {(batch, n, 3)} (per copy) or {(n, 3)} (every copy), "
                             f"got {arr.shape}")
        return np.broadcast_to(arr, (batch, n, 3))

    @staticmethod
    def _with_state(scene: Scene, x: np.ndarray, v: np.ndarray, b: int) -> Scene:
        """``scene`` starting from copy ``b``'s positions and velocities (checked as the scene loader would)."""
        nodes = []
        for node, p, u in zip(scene.nodes, x, v):
            if node.fixed and np.any(u):
                raise ValueError(f"velocities[{b}]: fixed node {node.name!r} must have zero velocity")
            nodes.append(replace(node, position=tuple(map(float, p)), velocity=tuple(map(float, u))))
        index = {node.name: i for i, node in enumerate(scene.nodes)}
        for s in scene.struts:
            if s.rigid:
                length = float(np.linalg.norm(x[index[s.nodes[1]]] - x[index[s.nodes[0]]]))
                if abs(length - s.rest_length) > 1e-9 * s.rest_length:
                    raise ValueError(f"positions[{b}]: rigid strut {s.name!r} has length {length!r}, "
                                     f"it must keep {s.rest_length!r}")
        return replace(scene, nodes=tuple(nodes))

    def _build(self, scene, scenes, method, dt, solver, contacts, backend, dtype) -> None:
        dt = time_step(dt)
        self._known_slack = None   # (positions, rest lengths, slack) where a run's kernel found the slack (run)
        if contacts is not None:
            kinds = contact_kinds(contacts, "contacts")
            scenes = [replace(s, contact_kinds=kinds) for s in scenes]
            scene = replace(scene, contact_kinds=kinds)
        self.scene = scene
        self.batch = len(scenes)
        self.system = System(scene)
        requested = method != "auto"
        if requested:
            self.method_reason = f"{method}: requested"
        else:
            method, self.method_reason = choose_method(self.system, dt)
        check_backend(backend, method, dtype)
        if backend == "jax" and scene.contact_response.response:
            raise ValueError("backend 'jax' has no member contact response (contact: response: true); use backend "
                             "'numba'")
        self.backend = backend
        self.failures: dict[int, str] = {}
        self._no_events = ((),) * self.batch   # a step without contact events (one shared row)
        n, nc = len(scene.nodes), len(scene.cables)
        self._cable_index = {name: i for i, name in enumerate(scene.cable_names)}
        self._node_index = {name: i for i, name in enumerate(scene.node_names)}
        # the batched elastic engines step a ground (numba, JAX) and a member contact response (numba)
        if method == "elastic":
            if solver is not None and requested:
                raise ValueError(f"solver={solver!r} is an option of a method with a QP; method 'elastic' has none")
            if backend == "jax":
                from .methods.jax.engine import ElasticBatchJax   # imports JAX: only here

                self._engine = ElasticBatchJax(self.system, dt, dtype=dtype or "float64")
            else:
                self._engine = ElasticBatch(self.system, dt)
            self.dt = self._engine.dt
            self._copies = None
            self._step_count = 0
            self._x = np.stack([s.positions for s in scenes], axis=-1)
            v = np.stack([s.velocities for s in scenes], axis=-1)
            self._v = self._engine.prepare(self._x, v)
            self._rest = np.stack([s.cable_rest_lengths for s in scenes], axis=-1)
            self._f_ext = np.zeros((n, 3, self.batch))
            # with a contact response, members rest in contact at a gap of ~0: a contact ends beyond TOUCH_TOL
            self._detectors = make_detector(self.system, scene.contact_kinds,
                                            TOUCH_TOL if scene.contact_response.response else 0.0, copies=self.batch)
            if isinstance(self._detectors, list):
                for b, d in enumerate(self._detectors):
                    d.reset(np.ascontiguousarray(self._x[..., b]))
            # the ground's contact events come from the numba engine's impulses (the JAX engine reports none)
            self._grounds = (None if scene.ground is None or backend == "jax"
                             else [GroundDetector(self.system) for _ in range(self.batch)])
            for b, d in enumerate(self._grounds or ()):
                d.reset(self._x[..., b])
            self._grounds_known = True   # False after a run without ground events: the detectors start again
            # copies stopped by a non-finite step: {copy: (steps done, positions, velocities)}
            self._frozen: dict[int, tuple[int, np.ndarray, np.ndarray]] = {}
            # a copy starting at speeds no step resolves fails at its first step, as Simulator.step does
            _, length, _ = self.system.geometry(scene.positions)
            self._shortest = float(length[length > 0].min(initial=np.inf))
            for b in range(self.batch):
                reason = absurd_speed(scene, self._v[..., b], self.dt, self._shortest)
                if reason is not None:
                    self.failures[b] = f"step 1 (t = {self.dt:.6g} s): {reason}"
                    self._frozen[b] = (0, self._x[..., b].copy(), self._v[..., b].copy())
        else:
            # one QP (or one ground) per copy: a Simulator per copy, whose warnings are given once for the batch
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                self._copies = [Simulator(s, method=method, dt=dt, solver=solver) for s in scenes]
            for w in {str(w.message): w for w in caught}.values():
                warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
            self.dt = self._copies[0].dt
            self._shared_tables = None   # whether every copy's method steps with the same tables (_compiled_copies)
        self._nc = nc

    # ------------------------------------------------------------------ state
    @property
    def method(self) -> str:
        return self._engine.name if self._copies is None else self._copies[0].method

    @property
    def method_settings(self) -> dict:
        return self._engine.single.describe() if self._copies is None else self._copies[0].method_settings

    @property
    def step_count(self) -> int:
        return self._step_count if self._copies is None else self._copies[0].step_count

    @property
    def step_counts(self) -> np.ndarray:
        """(B,) int: the steps each copy has completed (a failed copy stopped counting)."""
        if self._copies is None:
            counts = np.full(self.batch, self._step_count)
            for b, (done, _, _) in self._frozen.items():
                counts[b] = done
            return counts
        return np.array([c.step_count for c in self._copies])

    @property
    def time(self) -> float:
        """Simulation time, s (``step_count * dt``)."""
        return self.step_count * self.dt

    @property
    def failed(self) -> np.ndarray:
        """(B,) bool: copies stopped by a failure (see ``failures`` for the reasons)."""
        out = np.zeros(self.batch, dtype=bool)
        out[list(self.failures)] = True
        return out

    def _gather(self, batch_last: str, per_copy: str) -> np.ndarray:
        """A state array with the batch first: from the batch-last array, or stacked from the copies."""
        if self._copies is None:
            return np.moveaxis(getattr(self, batch_last), -1, 0).copy()
        return np.stack([getattr(c, per_copy) for c in self._copies])

    def batch_last(self) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """The compiled batch's own state arrays, batch last and read only: positions, velocities (N, 3, B) and
        rest lengths (n_cables, B) (what :attr:`positions`, :attr:`velocities` and :attr:`rest_lengths` copy
        with the batch first); None where the copies are stepped one by one. Valid until the next change."""
        if self._copies is not None:
            return None
        views = tuple(a.view() for a in (self._x, self._v, self._rest))
        for a in views:
            a.flags.writeable = False
        return views

    @property
    def positions(self) -> np.ndarray:
        """(B, N, 3) m; a failed copy's last good state."""
        return self._gather("_x", "positions")

    @property
    def velocities(self) -> np.ndarray:
        """(B, N, 3) m/s."""
        return self._gather("_v", "velocities")

    @property
    def rest_lengths(self) -> np.ndarray:
        """(B, n_cables) m."""
        return self._gather("_rest", "rest_lengths")

    @property
    def external_forces(self) -> np.ndarray:
        """(B, N, 3) N."""
        return self._gather("_f_ext", "external_forces")

    # ------------------------------------------------------------------ inputs
    def _per_copy(self, values, argument: str, index: Mapping[str, int], width: int | None,
                  current: np.ndarray) -> np.ndarray:
        """The full new (B, k[, 3]) array from (B, k[, 3]), (k[, 3]) for every copy, or a partial
        ``{name: value}`` whose value is for every copy or per copy (leading axis B)."""
        b = self.batch
        item = () if width is None else (width,)
        out = current.copy()
        if isinstance(values, Mapping):
            for name, value in values.items():
                if name not in index:
                    raise ValueError(f"{argument}: unknown name {name!r} (known: {', '.join(index)})")
                arr = float_array(value, f"{argument}[{name!r}]")
                if arr.shape not in (item, (b, *item)):
                    raise ValueError(f"{argument}[{name!r}]: expected shape {item} (every copy) or "
                                     f"{(b, *item)} (per copy), got {arr.shape}")
                out[:, index[name]] = arr
        else:
            arr = float_array(values, argument)
            if arr.shape not in (current.shape, current.shape[1:]):
                raise ValueError(f"{argument}: expected shape {current.shape} (per copy) or "
                                 f"{current.shape[1:]} (every copy), got {arr.shape}")
            out[...] = arr
        return out

    def set_rest_lengths(self, values) -> None:
        """New rest lengths, m: (B, n_cables), (n_cables,) for every copy, or ``{cable: value or (B,)}``.
        Every copy takes the command (as ``Simulator.set_rest_lengths`` would)."""
        new = self._per_copy(values, "rest_lengths", self._cable_index, None, self.rest_lengths)
        bad = np.argwhere(new <= 0)
        if bad.size:
            b, i = bad[0]
            raise ValueError(f"rest_lengths[{b}][{self.scene.cable_names[i]!r}]: must be > 0, got {float(new[b, i])!r}")
        if self._copies is None:
            self._rest = np.ascontiguousarray(new.T)
            self._engine.invalidate()
        else:
            for c, row in zip(self._copies, new):
                c.set_rest_lengths(row)

    def set_external_forces(self, values) -> None:
        """External node forces, N: (B, N, 3), (N, 3) for every copy, or ``{node: (3,) or (B, 3)}``;
        held until replaced."""
        new = self._per_copy(values, "external_forces", self._node_index, 3, self.external_forces)
        if self._copies is None:
            self._f_ext = np.ascontiguousarray(np.moveaxis(new, 0, -1))
            self._engine.invalidate()
        else:
            for c, row in zip(self._copies, new):
                c.set_external_forces(row)

    def restart(self, copies, positions, velocities, rest_lengths) -> None:
        """Start ``copies`` (k,) int again from new states, as a new batch would start them, the other copies
        going on untouched: positions, velocities (k, N, 3) m, m/s and rest lengths (k, n_cables) m (checked
        as the constructor checks a state), their failures forgotten, their contact warm starts zeroed. The
        batch's clock runs on. Elastic method, numba backend only (what an environment's autoreset needs)."""
        if self._copies is not None or self.backend != "numba":
            raise ValueError("restart: only the elastic method's numba batch restarts copies")
        if self._detectors is not None:
            raise ValueError("restart: a batch that detects member contacts cannot restart copies (contacts=())")
        idx = np.asarray(copies)
        if idx.ndim != 1 or idx.dtype.kind not in "iu" or np.any((idx < 0) | (idx >= self.batch)):
            raise ValueError(f"copies: expected copy indices in [0, {self.batch}), got {copies!r}")
        n, nc, k = len(self.scene.nodes), self._nc, len(idx)
        x = self._states(positions, "positions", k, n)
        v = self._states(velocities, "velocities", k, n)
        rest = float_array(rest_lengths, "rest_lengths")
        if rest.shape != (k, nc):
            raise ValueError(f"rest_lengths: expected shape {(k, nc)}, got {rest.shape}")
        if not np.all(rest > 0):
            j, i = np.argwhere(~(rest > 0))[0]
            raise ValueError(f"rest_lengths[{j}][{self.scene.cable_names[i]!r}]: must be > 0, got {float(rest[j, i])!r}")
        for j, b in enumerate(idx):
            self._with_state(self.scene, x[j], v[j], int(b))   # the checks of a new batch's state
        # the engine's carry (forces at the last step's end) is dropped for every copy (the others' are computed
        # again from their state, the same numbers); the restarted copies' contact warm starts are zeroed
        self._engine.forget(idx)
        self._x, self._v, self._rest = (np.array(a) for a in (self._x, self._v, self._rest))   # writable copies
        self._x[..., idx] = np.moveaxis(x, 0, -1)
        self._v[..., idx] = self._engine.prepare(np.moveaxis(x, 0, -1), np.moveaxis(v, 0, -1))
        self._rest[:, idx] = rest.T
        for j, b in enumerate(idx):
            b = int(b)
            self.failures.pop(b, None)
            self._frozen.pop(b, None)
            if self._grounds is not None:
                self._grounds[b].reset(x[j])
            reason = absurd_speed(self.scene, self._v[..., b], self.dt, self._shortest)
            if reason is not None:
                at = self._step_count + 1
                self.failures[b] = f"step {at} (t = {at * self.dt:.6g} s): {reason}"
                self._frozen[b] = (self._step_count, self._x[..., b].copy(), self._v[..., b].copy())

    # ------------------------------------------------------------------ stepping
    def _advance(self, steps: int, commands=None, ground_events: bool = True):
        """``steps`` steps of every running copy, inputs held (or ``commands`` evaluated inside the engine's
        compiled run, where it ``runs_commands``): positions, velocities (steps, B, N, 3), impulses
        (steps, B, n_cables), slack (steps, B, n_cables) (views, valid until the next call) and the contacts of
        each step (steps tuples of B tuples)."""
        if self._copies is not None:
            compiled = self._compiled_copies()
            if compiled:
                return self._advance_compiled_copies(steps, compiled)
            out = [self._step_copies() for _ in range(steps)]
            return (*(np.stack([o[i] for o in out]) for i in range(4)), [o[4] for o in out])
        if commands is None:
            x_seq, v_seq, imp, slack = self._engine.advance(self._x, self._v, self._rest, self._f_ext, steps)
        else:
            x_seq, v_seq, imp, slack = self._engine.advance(self._x, self._v, self._rest, self._f_ext, steps,
                                                            commands, self._step_count)
            self._rest, self._f_ext = self._engine.inputs_in_effect
        previous, previous_v, start = self._x, self._v, self._step_count
        self._x, self._v = x_seq[-1].copy(), v_seq[-1].copy()
        self._step_count += steps
        self._guard(previous, previous_v, start, x_seq, v_seq, imp, slack)
        contacts = [self._no_events] * steps
        if self._detectors is not None:
            # a failed copy is walked up to its failure only
            stop = np.full(self.batch, steps, dtype=np.int64)
            for b, (done, _, _) in self._frozen.items():
                stop[b] = min(steps, max(0, done - start))
            xs = np.concatenate([previous[None], x_seq])

            def at(k):   # the times steps k of the chunk start, s
                return (start + k) * self.dt
            pairs = getattr(self._engine, "pairs", {})   # a response's member impulses, {(step, copy): impulses}
            if isinstance(self._detectors, list):   # a numpy detector per copy (a scene with very many pairs)
                found = {(k, b): events for b, d in enumerate(self._detectors)
                         for (k, _), events in d.walk(xs[..., b:b + 1], at, self.dt, stop[b:b + 1],
                                                      per_step={(k, 0): i for (k, c), i in pairs.items() if c == b}
                                                      ).items()}
            else:
                found = self._detectors.walk(xs, at, self.dt, stop, per_step=pairs)
            rows: dict[int, list] = {}
            for (k, b), events in found.items():
                rows.setdefault(k, [()] * self.batch)[b] = events
            for k, row in rows.items():
                contacts[k] = tuple(row)
        if self._grounds is not None and not ground_events:
            self._grounds_known = False
        elif self._grounds is not None:
            if not self._grounds_known:   # contacts known again from here: those touching begin at this chunk's start
                for b, d in enumerate(self._grounds):
                    d.reset(previous[..., b])
                self._grounds_known = True
            landed = walk_copies(self._grounds, previous, previous_v, x_seq, v_seq, self._engine.contact,
                                 start * self.dt, self.dt)
            for k, ground in landed.items():   # the steps with ground events only: a batch's step is B rows
                contacts[k] = tuple(ground if contacts[k] is self._no_events else
                                    (tuple(sorted(m + g, key=lambda e: e.time)) if g else m
                                     for m, g in zip(contacts[k], ground)))
        return (np.moveaxis(x_seq, -1, 1), np.moveaxis(v_seq, -1, 1), np.moveaxis(imp, -1, 1),
                np.moveaxis(slack, -1, 1), contacts)

    def _guard(self, previous, previous_v, start, x_seq, v_seq, imp, slack) -> None:
        """Simulator's non-finite guard, copy by copy, on a chunk of elastic steps from ``previous``,
        ``previous_v`` (N, 3, B): a copy whose step gives non-finite values fails there (the reason as NonFiniteError's
        message), keeps the state before that step, and its numbers from that step on are NaN."""
        # first one sum of the chunk's last step (a non-finite number makes it non-finite; one in any step stays
        # in every later step's positions, each the last step's plus h times a velocity, and in the forces and
        # impulses they give): summing every step of a control period of 256 rolling copies took 0.3 ms; per
        # step and copy only where it is not finite
        with np.errstate(invalid="ignore", over="ignore"):   # (inf - inf is what the sums are there to find)
            whole = sum(np.add.reduce(a[-1], axis=None) for a in (x_seq, v_seq, imp))
            if np.isfinite(whole) and not self._frozen:
                return
            sums = np.add.reduce(x_seq, axis=(1, 2)) + np.add.reduce(v_seq, axis=(1, 2)) + np.add.reduce(imp, axis=1)
        bad = ~np.isfinite(sums)                                                  # (steps, B)
        for b in np.flatnonzero(bad.any(axis=0)):
            if b in self._frozen:
                continue
            k = int(np.argmax(bad[:, b]))
            x0, v0 = (previous[..., b], previous_v[..., b]) if k == 0 else (x_seq[k - 1, ..., b], v_seq[k - 1, ..., b])
            state = State(x0.copy(), v0.copy(), self._rest[:, b].copy(), self._f_ext[..., b].copy(), start + k)
            # the report from the plain reference's take of the step, as Simulator.step makes it (how far an
            # overflow spreads within a step depends on the order of the arithmetic), or its StepError's (the
            # engine's run met it there: ElasticBatch.advance)
            try:
                with np.errstate(all="ignore"):
                    ref = ElasticMethod(self.system, self.dt, compiled=False).step(state)
                report = non_finite_report(self.scene, state, self.dt, ref.positions, ref.velocities, ref.impulses)
            except StepError as exc:
                report = str(exc)
            self.failures[int(b)] = f"step {start + k + 1} (t = {(start + k + 1) * self.dt:.6g} s): {report}"
            self._frozen[int(b)] = (start + k, state.positions, state.velocities)
        for b, (done, x0, v0) in self._frozen.items():
            k = max(0, done - start)
            x_seq[k:, ..., b] = v_seq[k:, ..., b] = imp[k:, :, b] = np.nan
            slack[k:, :, b] = False
            self._x[..., b], self._v[..., b] = x0, v0

    def step(self) -> BatchStepResult:
        """Advance every running copy by one step of ``dt``."""
        x, v, imp, slack, contacts = self._advance(1)
        imp = imp[0].copy()
        return BatchStepResult(self.time, x[0].copy(), v[0].copy(), imp, imp / self.dt, slack[0].copy(),
                               contacts[0], self.failed)

    def _compiled_copies(self) -> list[int]:
        """The running copies, where the steps of all of them go through the inextensible method's loop over the
        copies (``InextensibleMethod.advance_copies``): each copy's method has a compiled loop (on its ground
        too), the same tables as the others, and no member-contact detection to walk; else none. A copy whose
        first step's speeds are absurd fails here, as its first ``Simulator.step`` would."""
        running = [i for i in range(self.batch) if i not in self.failures]
        sims = [self._copies[i] for i in running]
        if not sims or not all(isinstance(c._method, InextensibleMethod) and c._method.has_loop()
                               and (c._ground is None or c._method.has_ground_loop())
                               and (c._contacts is None or isinstance(c._contacts, CompiledDetector)) for c in sims):
            return []
        if self._shared_tables is None:   # the tables are the structure's and the scenes': fixed at the build
            first = self._copies[0]._method
            self._shared_tables = all(first.same_tables(c._method) for c in self._copies[1:])
        if not self._shared_tables:
            return []
        for i, c in zip(running, sims):
            if c._speeds_unchecked:
                try:
                    c._check_speeds()
                except StepError as exc:
                    self.failures[i] = f"step {c.step_count + 1} (t = {c.time + c.dt:.6g} s): {exc}"
        return [i for i in running if i not in self.failures]

    def _advance_compiled_copies(self, steps: int, running: list[int]):
        """:meth:`_advance` of the ``running`` copies by ``InextensibleMethod.advance_copies`` (each copy's own
        numbers, the copies on every core), committed to each copy's ``Simulator`` as its ``run`` commits a
        compiled part; a copy whose part has a step that is not finite is put back and stepped one step at a
        time (:meth:`_step_copies`' way: it fails at that very step, with the message ``Simulator.step`` gives)."""
        b_all, n, nc = self.batch, len(self.scene.nodes), self._nc
        sims = [self._copies[i] for i in running]
        for c in sims:
            c._rewind()
        methods = [c._method for c in sims]
        carries = [m.carry() for m in methods]
        states = [c._state for c in sims]
        k = len(sims)
        pos, vel = np.empty((k, steps, n, 3)), np.empty((k, steps, n, 3))
        imp, sl = np.empty((k, steps, nc)), np.empty((k, steps, nc), dtype=bool)
        ground = None if sims[0]._ground is None else np.empty((k, steps, n, 3))
        if ground is not None or any(c._contacts is not None for c in sims):   # the events' walks start here
            start = np.stack([st.positions for st in states], axis=-1)
            start_v = np.stack([st.velocities for st in states], axis=-1)
        x, v = InextensibleMethod.advance_copies(methods, states, steps, pos, vel, imp, sl, ground)
        add = np.add.reduce
        finite = np.isfinite(add(pos.reshape(k, steps, -1), 2) + add(vel.reshape(k, steps, -1), 2) + add(imp, 2))
        count = states[0].step_count
        t0 = count * self.dt
        good = np.flatnonzero(finite.all(axis=1)).tolist()
        contacts = [[()] * b_all for _ in range(steps)]
        if ground is not None and good:
            found = walk_copies([sims[j]._ground for j in good], start[..., good], start_v[..., good],
                                np.moveaxis(pos[good], 0, -1), np.moveaxis(vel[good], 0, -1),
                                np.moveaxis(ground[good], 0, -1), t0, self.dt)
            for step, row in found.items():
                for j, events in zip(good, row):
                    contacts[step][running[j]] = events
        for j in good:   # the member contacts' events, each copy's detector walked through its steps
            detector = sims[j]._contacts
            if detector is None:
                continue
            xs = np.concatenate([start[None, ..., j], pos[j]])
            for (step, _), events in _walk(detector, xs[..., None], lambda s: (count + s) * self.dt, self.dt,
                                           {}).items():
                events, landed = tuple(events), contacts[step][running[j]]
                contacts[step][running[j]] = tuple(sorted(events + landed, key=lambda e: e.time)) if landed else events
        for j in good:
            st = states[j]
            st.positions, st.velocities = x[j].copy(), v[j].copy()
            st.step_count += steps
        if k == b_all:   # every copy running: the outputs are the loop's (no NaN rows to make)
            out_x, out_v, out_imp, out_sl = pos, vel, imp, sl
        else:
            out_x, out_v = np.full((b_all, steps, n, 3), np.nan), np.full((b_all, steps, n, 3), np.nan)
            out_imp, out_sl = np.full((b_all, steps, nc), np.nan), np.zeros((b_all, steps, nc), dtype=bool)
            out_x[running], out_v[running], out_imp[running], out_sl[running] = pos, vel, imp, sl
        for j in set(range(k)) - set(good):   # a failure inside: the copy again, one step at a time
            i, c = running[j], sims[j]
            methods[j].restore(carries[j])
            out_x[i], out_v[i], out_imp[i], out_sl[i] = np.nan, np.nan, np.nan, False
            for step in range(steps):
                try:
                    r = c.step()
                except StepError as exc:
                    self.failures[i] = f"step {c.step_count + 1} (t = {c.time + c.dt:.6g} s): {exc}"
                    break
                out_x[i, step], out_v[i, step], out_imp[i, step], out_sl[i, step] = (r.positions, r.velocities,
                                                                                     r.impulses, r.slack)
                contacts[step][i] = r.contacts
        self._step_count = max(c.step_count for c in self._copies)
        events = [tuple(row) if any(row) else self._no_events for row in contacts]
        return (np.moveaxis(out_x, 0, 1), np.moveaxis(out_v, 0, 1), np.moveaxis(out_imp, 0, 1),
                np.moveaxis(out_sl, 0, 1), events)

    def _step_copies(self):
        b, n, nc = self.batch, len(self.scene.nodes), self._nc
        x, v = np.full((b, n, 3), np.nan), np.full((b, n, 3), np.nan)
        imp, slack = np.full((b, nc), np.nan), np.zeros((b, nc), dtype=bool)
        contacts = []
        for i, c in enumerate(self._copies):
            if i in self.failures:
                contacts.append(())
                continue
            try:
                r = c.step()
            except StepError as exc:   # a QP without a solution, a result that is not finite
                self.failures[i] = f"step {c.step_count + 1} (t = {c.time + c.dt:.6g} s): {exc}"
                contacts.append(())
                continue
            x[i], v[i], imp[i], slack[i] = r.positions, r.velocities, r.impulses, r.slack
            contacts.append(r.contacts)
        # a failed copy's step count stands still; the batch's clock is that of the running ones
        self._step_count = max(c.step_count for c in self._copies)
        return x, v, imp, slack, tuple(contacts)

    def slack(self) -> np.ndarray:
        """(B, n_cables) bool: the cables slack now, in the method's model."""
        if self._copies is not None:
            if not all(type(c._method) is InextensibleMethod for c in self._copies):
                return np.stack([c.slack() for c in self._copies])
            for c in self._copies:   # Simulator.slack's, before the method is asked
                c._settle()
            return InextensibleMethod.slack_copies([c._method for c in self._copies],
                                                   np.stack([c._state.positions for c in self._copies]))
        known = self._known_slack
        if known is not None and known[0] is self._x and known[1] is self._rest:
            return known[2].copy()
        return self._engine.slack(self._x, self._rest).T.copy()

    def run(self, duration: float | None = None, *, steps: int | None = None, every: int = 1,
            commands=None, dtype="float64", fields=TRAJECTORY_FIELDS, ground_events: bool = True) -> BatchTrajectory:
        """Run ``steps`` steps, or ``round(duration / dt)``, inputs held, as ``Simulator.run``: keeps steps
        ``every``, ``2 every``, ... and the last (K of them) as (B, K, ...) arrays, a kept step's impulses
        summed over the steps since the previous kept one and its tensions their mean; over all steps
        each cable's peak tension and snaps (see :class:`BatchTrajectory`).

        ``commands``: a :class:`~tensegrity_sim.commands.CommandSchedule` for every copy, or a sequence of B
        (one per copy), applied before each step at its start time as ``tensegrity-sim run --commands`` does
        (a cable it does not name keeps its rest length at the run's start; an input is set only where it
        changed). The JAX backend and the numba batch on a ground evaluate them inside their compiled runs;
        the others step one at a time.

        The trajectory's storage (what keeping every step costs): ``dtype`` "float64" (default) or "float32",
        the kept positions, velocities, impulses and tensions rounded to it (the stepping, the peaks and snaps
        stay in the batch's own precision); ``fields``: the per-step arrays kept, any of :data:`TRAJECTORY_FIELDS`
        ("impulses" brings the tensions), the others None. The arrays have the batch first in their shape and
        are laid out in memory as the engine steps them (the elastic batch's free flight: copies last), so that
        a kept step is one contiguous copy; ``np.ascontiguousarray`` gives the copy-major order.

        ``ground_events``: False leaves the ground's contact events out of ``contacts`` (an environment's control
        period, which reads none: finding them costs a Python event per landing); the ground contacts known at a
        later run that finds them again are those that begin from its start. A run on a ground that keeps no
        field and finds no events (the environments' control period) has the compiled elastic batch sum its
        steps up in its kernel (``ElasticBatch.advance_summary``): the same state, peaks and snaps, without
        writing and reducing every step's numbers."""
        store, fields = _storage(dtype, fields)
        self._check_commands(commands)
        b, n, nc = self.batch, len(self.scene.nodes), self._nc
        size = {"positions": 3 * n * store.itemsize, "velocities": 3 * n * store.itemsize,
                "impulses": 2 * nc * store.itemsize, "slack": nc}   # bytes a copy's kept step (impulses: and tensions)
        steps, every, kept, span = run_plan(duration, steps, every, self.dt, b * sum(size[f] for f in fields) + 8)
        time = (self.step_count + kept) * self.dt
        out: dict[str, np.ndarray] = {}   # (K, B, ...) in the chunks' memory order (made at the first chunk)
        contacts: list[list[ContactEvent]] = [[] for _ in range(b)]
        peak = np.zeros((b, nc))
        snaps = np.zeros((b, nc), dtype=np.int64)
        was_slack = self.slack()
        carried = None   # the impulses summed so far of a kept step that goes on into the next chunk
        chunk = max(1, min(steps, _CHUNK_NUMBERS // max(1, b * n * 3)))
        inside = commands is not None and self._copies is None and self._engine.runs_commands()
        if commands is not None and not inside:
            chunk, base_rest = 1, self.rest_lengths   # the commands are applied here, step by step
        # keeping no step (an environment's control period): the engine's kernel sums the steps up itself where it
        # can (ElasticBatch.advance_summary), the chunk then taken whole as one step is kept
        summarised = (not fields and (commands is None or inside) and self._copies is None and self._detectors is None
                      and (self._grounds is None or not ground_events) and self._engine.summarises())
        done = 0
        found_slack = False   # whether the last steps were the summary's (its kernel found the slack cables)
        while done < steps:
            m = min(chunk, steps - done)
            if summarised and not self._frozen:
                summary = self._engine.advance_summary(self._x, self._v, self._rest, self._f_ext, m,
                                                       commands if inside else None, self._step_count, was_slack.T)
                if summary is not None:
                    self._x, self._v, chunk_peak, chunk_snaps, was_slack = summary
                    if inside:
                        self._rest, self._f_ext = self._engine.inputs_in_effect
                    self._step_count += m
                    if self._grounds is not None:   # (no ground events: the detectors start again at a run finding them)
                        self._grounds_known = False
                    np.fmax(peak, chunk_peak.T, out=peak)
                    snaps += chunk_snaps.T
                    was_slack = was_slack.T
                    done += m
                    found_slack = True
                    continue
            found_slack = False
            if commands is not None and not inside:
                self._apply_commands(commands, base_rest)
            x, v, i, sl, events = self._advance(m, commands if inside else None, ground_events)
            np.fmax(peak, np.fmax.reduce(i, axis=0), out=peak)   # fmax: a failed copy's NaN is no peak
            snaps += (np.concatenate([was_slack[None], sl[:-1]]) & ~sl).sum(axis=0)
            was_slack = sl[-1].copy()
            for per_step in events:
                if per_step is not self._no_events:
                    for c, e in enumerate(per_step):
                        contacts[c].extend(e)
            arrays = {"positions": x, "velocities": v, "impulses": i, "tensions": i, "slack": sl}
            if not out:
                out = _kept_arrays(arrays, fields, len(kept), store)
            g = done + np.arange(m)              # the chunk's steps in the run, from 0
            j = g // every                       # the kept step each one counts to
            last = (g + 1) % every == 0
            last[-1] |= done + m == steps
            for f in fields:
                if f == "impulses":              # summed in float64 over each kept step's steps, then stored
                    sums = i if every == 1 else np.add.reduceat(i, np.flatnonzero(np.diff(j, prepend=-1)), axis=0)
                    if carried is not None:
                        sums = sums.copy()
                        sums[0] += carried
                    complete = slice(j[0], j[0] + len(sums) - (not last[-1]))
                    out[f][complete] = sums[:complete.stop - complete.start]
                    out["tensions"][complete] = sums[:complete.stop - complete.start] / \
                        (span[complete, None, None] * self.dt)
                    carried = None if last[-1] else sums[-1]
                elif every == 1:
                    out[f][done:done + m] = arrays[f]
                else:
                    out[f][j[last]] = arrays[f][last]
            done += m
        if not out:   # no step
            out = _kept_arrays({"positions": np.empty((0, b, n, 3)), "velocities": np.empty((0, b, n, 3)),
                                "impulses": np.empty((0, b, nc)), "tensions": np.empty((0, b, nc)),
                                "slack": np.empty((0, b, nc), dtype=bool)}, fields, 0, store)
        # the slack cables at the end, as the kernel's summary found them: what slack() answers until the state or
        # the rest lengths change (those are then other arrays), not measured again (0.1 ms of an environment's
        # 256-copy control period)
        self._known_slack = (self._x, self._rest, was_slack) if found_slack else None
        kept_arrays = {f: np.moveaxis(out[f], 0, 1) if f in out else None for f in (*TRAJECTORY_FIELDS, "tensions")}
        return BatchTrajectory(time, kept_arrays["positions"], kept_arrays["velocities"], kept_arrays["impulses"],
                               kept_arrays["tensions"], kept_arrays["slack"], contacts, dict(self.failures),
                               peak / self.dt, snaps)

    def _check_commands(self, commands) -> None:
        if commands is None or isinstance(commands, CommandSchedule):
            return
        if not (isinstance(commands, (list, tuple)) and len(commands) == self.batch
                and all(isinstance(c, CommandSchedule) for c in commands)):
            raise ValueError(f"commands must be a CommandSchedule (see load_commands) or a sequence of {self.batch} "
                             f"(one per copy), got {type(commands).__name__}")
        for c in commands:
            if c.force_values.shape[1:] != (len(self.scene.nodes), 3):
                raise ValueError(f"commands: a schedule for {c.force_values.shape[1]} nodes, the scene has "
                                 f"{len(self.scene.nodes)}")

    def _apply_commands(self, commands, base_rest: np.ndarray) -> None:
        """Set the rest lengths and forces ``commands`` give at the next step's start time (base_rest (B, n_cables)
        for the cables they do not name), each only where it differs from what is in effect."""
        t = self.time
        per_copy = commands if isinstance(commands, (list, tuple)) else [commands] * self.batch
        rest = np.stack([c.rest_lengths_at(t, base) for c, base in zip(per_copy, base_rest)])
        if not np.array_equal(rest, self.rest_lengths):
            self.set_rest_lengths(rest)
        current = self.external_forces
        forces = np.stack([f if (f := c.forces_at(t)) is not None else now for c, now in zip(per_copy, current)])
        if not np.array_equal(forces, current):
            self.set_external_forces(forces)

    # ------------------------------------------------------------------ invariants
    def energy(self) -> dict[str, np.ndarray]:
        """Energies (B,) J per copy: kinetic, strain, gravity (``-sum m g.x``), total (as ``Simulator.energy``)."""
        if self._copies is not None:
            per = [c.energy() for c in self._copies]
            return {k: np.array([e[k] for e in per]) for k in ("kinetic", "strain", "gravity", "total")}
        sys = self.system
        kinetic = 0.5 * np.sum(self._v * sys.mass.apply(self._v), axis=(0, 1))
        strain = self._engine.strain_energy(self._x, self._rest)
        gravity = -np.sum(sys.gravity_force[:, :, None] * self._x, axis=(0, 1))
        return {"kinetic": kinetic, "strain": strain, "gravity": gravity, "total": kinetic + strain + gravity}
