"""Fuzz targets of every public boundary, for test/test_fuzz.py (CI) and scripts/fuzz.py (a longer run).

Each target takes hypothesis-drawn input, calls the boundary as a careless or hostile user would, and
sorts the outcome into :data:`TALLY` as ``accepted`` (it took the input, and then every check of what it
holds passed), ``refused`` (the project's error naming what is wrong, nothing changed) or ``crashed``
(any other exception, or a refused call that changed something; re-raised so hypothesis shrinks it).
"""
from __future__ import annotations

import contextlib
import io
import math
import warnings
from collections import Counter

import numpy as np
import yaml
from hypothesis import strategies as st
from ros_helpers import positions_of, prism

import tensegrity_sim as ts
from tensegrity_sim.commands import CommandError, parse_commands
from tensegrity_sim.ros import messages as M
from tensegrity_sim.ros.messages import TYPESTORE
from tensegrity_sim.ros.node_logic import RUNTIME_PARAMETERS, TOPICS, NodeSettings, SimNodeLogic

TALLY: Counter = Counter()  # (target, "accepted" | "refused" | "crashed") -> cases


@contextlib.contextmanager
def outcome(target: str, refusals: tuple[type[BaseException], ...]):
    """Count one case of ``target``: a clean return is accepted (unless the block appends "refused" to the
    list it is given: a refusal returned rather than raised), an exception of ``refusals`` refused,
    anything else a crash (counted and re-raised)."""
    verdict: list[str] = []
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # class-k, length offsets, numpy overflow while a step blows up
            yield verdict
    except refusals as exc:
        assert str(exc), f"{target}: {type(exc).__name__} without a message"
        TALLY[target, "refused"] += 1
        return
    except BaseException:
        TALLY[target, "crashed"] += 1
        raise
    TALLY[target, verdict[0] if verdict else "accepted"] += 1


# --------------------------------------------------------------------------- values
FLOATS = st.one_of(st.floats(allow_nan=True, allow_infinity=True),
                   st.sampled_from([0.0, -0.0, 5e-324, 1e-300, 1e-9, 1.0, 1e150, 1e300, 1.7976931348623157e308]))
INTS = st.one_of(st.integers(-10, 10), st.integers(), st.just(10 ** 400))
TEXT = st.one_of(st.text(max_size=12), st.sampled_from(["a\n", "n0", "c0", "rigid", "auto", "", "é", "1e999"]))
SCALARS = st.one_of(st.none(), st.booleans(), INTS, FLOATS, TEXT)
VALUES = st.recursive(SCALARS, lambda inner: st.one_of(st.lists(inner, max_size=4),
                                                       st.dictionaries(TEXT, inner, max_size=4)),
                      max_leaves=12)
NUMBER_LISTS = st.lists(FLOATS, min_size=0, max_size=4)


def _mutate(draw, tree):
    """``tree`` (a YAML-like value) with one random change: a value replaced, a key removed or added."""
    if isinstance(tree, dict) and tree:
        key = draw(st.sampled_from(sorted(tree, key=str)))
        action = draw(st.sampled_from(["descend", "descend", "replace", "remove", "add"]))
        out = dict(tree)
        if action == "descend":
            out[key] = _mutate(draw, tree[key])
        elif action == "replace":
            out[key] = draw(VALUES)
        elif action == "remove":
            del out[key]
        else:
            out[draw(TEXT)] = draw(VALUES)
        return out
    if isinstance(tree, list) and tree:
        i = draw(st.integers(0, len(tree) - 1))
        out = list(tree)
        action = draw(st.sampled_from(["descend", "descend", "replace", "remove", "duplicate"]))
        if action == "descend":
            out[i] = _mutate(draw, tree[i])
        elif action == "replace":
            out[i] = draw(VALUES)
        elif action == "remove":
            del out[i]
        else:
            out.insert(i, tree[i])
        return out
    return draw(st.one_of(VALUES, FLOATS))  # a leaf: anything, or a float of any size


# A small scene with every key of the schema (small: building and stepping it is most of a case's cost)
BASE_SCENE = {
    "name": "fuzz", "gravity": [0.0, 0.0, -9.81], "contact": {"kinds": ["strut_strut", "strut_cable"]},
    "nodes": [{"name": "n0", "position": [0.0, 0.0, 0.0], "fixed": True},
              {"name": "n1", "position": [1.0, 0.0, 0.0], "mass": 1.0, "velocity": [0.0, 0.1, 0.0]},
              {"name": "n2", "position": [0.0, 1.0, 0.0], "mass": 1.0, "fixed": False}],
    "struts": [{"name": "s0", "nodes": ["n0", "n1"], "stiffness": 1.0e4, "mass": 0.5, "radius": 0.01}],
    "cables": [{"name": "c0", "nodes": ["n1", "n2"], "stiffness": 100.0, "rest_length": 1.2, "damping": 0.1},
               {"name": "c1", "nodes": ["n2", "n0"], "stiffness": 100.0, "radius": 0.002}],
}


@st.composite
def scene_dicts(draw):
    """:data:`BASE_SCENE` with 1-3 random changes."""
    tree = BASE_SCENE
    for _ in range(draw(st.integers(1, 3))):
        tree = _mutate(draw, tree)
    return tree


@st.composite
def scene_texts(draw):
    """YAML texts: a scene's text with characters changed, nested deep, or not UTF-8 at all (bytes)."""
    base = yaml.safe_dump(BASE_SCENE, sort_keys=False, default_flow_style=None)
    kind = draw(st.sampled_from(["edit", "edit", "bytes", "dump"]))
    if kind == "edit":
        text = base
        for _ in range(draw(st.integers(1, 4))):
            i = draw(st.integers(0, len(text)))
            text = text[:i] + draw(st.text(max_size=6)) + text[i + draw(st.integers(0, 6)):]
        return text
    if kind == "bytes":
        return base.encode()[: draw(st.integers(0, 200))] + draw(st.binary(min_size=1, max_size=8)) + b"\xff"
    return yaml.safe_dump(draw(scene_dicts()), sort_keys=False)


def check_scene(scene: ts.Scene) -> None:
    """What an accepted scene must hold: finite arrays, positive free masses, an exact round trip, and a
    simulator that builds and steps (or refuses with the project's errors)."""
    for a in (scene.positions, scene.velocities, scene.masses, scene.cable_rest_lengths):
        assert np.all(np.isfinite(a))
    assert all(s.rigid or math.isfinite(s.rest_length) for s in scene.struts)
    assert ts.Scene.from_dict(scene.to_dict()) == scene
    for name in scene.node_names + scene.strut_names + scene.cable_names:
        assert name.isascii() and (name[0].isalpha() or name[0] == "_") and name.replace("_", "a").isalnum()
    try:
        sim = ts.Simulator(scene, dt=1e-3)
    except (ts.SceneError, ValueError):
        return
    try:
        sim.run(steps=3)
    except ts.StepError:
        pass
    assert np.all(np.isfinite(sim.positions)) and np.all(np.isfinite(sim.velocities))


def fuzz_scene_dict(mapping) -> None:
    with outcome("scene dict", (ts.SceneError,)):
        check_scene(ts.Scene.from_dict(mapping, source="fuzz"))


def fuzz_scene_file(tmp_dir, text) -> None:
    path = tmp_dir / "fuzz.yaml"
    if isinstance(text, bytes):
        path.write_bytes(text)
    else:
        path.write_text(text, encoding="utf-8", errors="surrogatepass")
    with outcome("scene file", (ts.SceneError,)):
        try:
            check_scene(ts.load_scene(path))
        except ts.SceneError as exc:
            assert str(path) in str(exc), f"the file is not named: {exc}"
            raise


# --------------------------------------------------------------------------- the Python API
def deadband() -> ts.Scene:
    from bench.analytic import deadband_dict
    return ts.Scene.from_dict(deadband_dict())


ARRAYS = st.one_of(
    st.integers(0, 4).flatmap(lambda n: st.lists(st.lists(FLOATS, min_size=3, max_size=3), min_size=n, max_size=n)),
    NUMBER_LISTS, VALUES,
    st.dictionaries(st.sampled_from(["left", "mass", "right", "cl", "cr", "ghost"]),
                    st.one_of(FLOATS, NUMBER_LISTS, VALUES), max_size=3),
    st.sampled_from([{"mass": [1e300, 0.0, 0.0]}, {"mass": [0.0, -1.7e308, 1e308]}, {"cl": 1e300}, {"cr": 1e-300},
                     {"left": [1e300, 1e300, 1e300]}]),  # finite but absurd: the step must not give NaN
    st.sampled_from([np.zeros((3, 3)), np.full((3, 3), 1e300), np.full(2, 1e300), np.array(["a", "b"]),
                     np.zeros(2, dtype=complex), np.ones((2, 1)), np.array([1e-300, 1e300])]),
)

API_CALLS = st.lists(st.one_of(
    st.tuples(st.just("set_rest_lengths"), ARRAYS),
    st.tuples(st.just("set_external_forces"), ARRAYS),
    st.tuples(st.just("run_steps"), st.one_of(INTS, FLOATS, TEXT, st.just(None))),
    st.tuples(st.just("run_duration"), st.one_of(INTS, FLOATS, TEXT)),
    st.tuples(st.just("step"), st.none()),
), min_size=1, max_size=6)


def _snapshot(sim: ts.Simulator):
    return (sim.step_count, sim.positions.tobytes(), sim.velocities.tobytes(), sim.rest_lengths.tobytes(),
            sim.external_forces.tobytes())


MAX_FUZZ_STEPS = 50  # a valid run longer than this is not run (the fuzz is about inputs, not long runs)


def fuzz_api(dt, method, calls) -> None:
    with outcome("Simulator()", (ValueError, ts.SceneError)):
        sim = ts.Simulator(deadband(), method=method, dt=dt)
    if "sim" not in locals():
        return
    for name, value in calls:
        before = _snapshot(sim)
        refusals = (ValueError,) if name.startswith("set") else (ValueError, ts.StepError)
        with outcome(f"Simulator.{name.split('_')[0] if name.startswith('run') else name}", refusals):
            try:
                if name == "set_rest_lengths":
                    sim.set_rest_lengths(value)
                elif name == "set_external_forces":
                    sim.set_external_forces(value)
                elif name == "step":
                    sim.step()
                elif name == "run_steps":
                    if isinstance(value, (int, float)) and not isinstance(value, bool) and 0 <= value < 1e30:
                        value = value % MAX_FUZZ_STEPS if value == int(value) else value
                    sim.run(steps=value)
                else:
                    if isinstance(value, (int, float)) and not isinstance(value, bool) and 0 <= value < 1e30:
                        value = value % (MAX_FUZZ_STEPS * sim.dt)
                    sim.run(duration=value)
            except (ValueError, ts.StepError):
                if name.startswith("set") or name == "step":
                    assert _snapshot(sim) == before, f"{name} refused but changed the state"
                raise
        assert np.all(np.isfinite(sim.positions)) and np.all(np.isfinite(sim.velocities))


# --------------------------------------------------------------------------- the node
class _Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        self.t += 1e-4
        return self.t


class _Quiet:
    def warning(self, text):
        assert text and "\n" not in text

    error = warning


NODE_NAMES = st.one_of(st.sampled_from(["n0", "n1", "n5", "c0", ""]), TEXT, VALUES)
JOINT_STATES = st.builds(
    lambda names, pos, vel, eff: (names, pos, vel, eff),
    st.one_of(st.lists(st.sampled_from(["c0", "c1", "c2", "c8", "s0", "x"]), max_size=4), VALUES),
    st.one_of(NUMBER_LISTS, VALUES), st.one_of(st.just([]), NUMBER_LISTS, VALUES), st.one_of(st.just([]), VALUES))
WRENCHES = st.tuples(NODE_NAMES, st.one_of(st.lists(FLOATS, min_size=3, max_size=3), VALUES),
                     st.one_of(st.just([0.0, 0.0, 0.0]), st.lists(FLOATS, min_size=3, max_size=3), VALUES))


def _careless(typename, **fields):
    """A message holding whatever field values were drawn (of any Python type: a careless publisher's). Always
    rosbags' class, also where rclpy imports: rclpy's classes check types on construction, so with them no
    such message could even be built, and the node would never be tried with it."""
    return TYPESTORE.types[typename](**fields)


def _header(frame):
    return _careless("std_msgs/msg/Header", stamp=_careless("builtin_interfaces/msg/Time", sec=0, nanosec=0),
                     frame_id=frame)


def _joint_state(names, pos, vel, eff):
    return _careless("sensor_msgs/msg/JointState", header=_header(""), name=names, position=pos, velocity=vel,
                     effort=eff)


def _wrench(frame, force, torque):
    def vec(v):
        if isinstance(v, list) and len(v) == 3:
            return _careless("geometry_msgs/msg/Vector3", x=v[0], y=v[1], z=v[2])
        return v
    return _careless("geometry_msgs/msg/WrenchStamped", header=_header(frame),
                     wrench=_careless("geometry_msgs/msg/Wrench", force=vec(force), torque=vec(torque)))


NODE_ACTIONS = st.lists(st.one_of(
    st.tuples(st.just("rest_lengths"), JOINT_STATES),
    st.tuples(st.just("wrench"), WRENCHES),
    st.tuples(st.just("wrong_message"), st.tuples(st.sampled_from(["cable_rest_lengths", "external_wrench"]),
                                                  VALUES)),
    st.tuples(st.just("update"), st.dictionaries(st.sampled_from(RUNTIME_PARAMETERS + ("dt", "nope")),
                                                 st.one_of(FLOATS, INTS, VALUES), max_size=2)),
    st.tuples(st.just("service"), st.sampled_from(["pause", "resume", "single_step", "reset"])),
    st.tuples(st.just("tick"), st.none()),
    st.tuples(st.just("command"), st.one_of(
        st.tuples(st.sampled_from(["set", "set", "reset", "pause", "resume", "step", ""]),
                  st.sampled_from(RUNTIME_PARAMETERS + ("dt", "scene", "x")),
                  st.one_of(st.sampled_from(["1e999", "nan", "-1", "0", "1e-300", "1e300", "5"]), TEXT))
        .map(" ".join), TEXT)),
), min_size=1, max_size=8)

_NODE_SCENE = None


def fuzz_node(settings_changes, actions) -> None:
    global _NODE_SCENE
    if _NODE_SCENE is None:
        _NODE_SCENE = prism()
    with outcome("NodeSettings", (ValueError,)):
        settings = NodeSettings(**{"log_path": "", **settings_changes})
    if "settings" not in locals():
        return
    with outcome("Simulator", (ValueError,)):   # a dt the settings take may be past the method's stability limit
        sim = ts.Simulator(_NODE_SCENE, method="elastic", dt=settings.dt)
    if "sim" not in locals():
        return
    sent = []
    logic = SimNodeLogic(sim, settings,
                         transport=lambda key, data: sent.append((key, data)), raw_transport=True,
                         clock=_Clock(), logger=_Quiet())
    for action, value in actions:
        before = _snapshot(logic.sim)
        if action in ("rest_lengths", "wrench", "wrong_message"):
            with outcome("node message", ()) as verdict:
                if action == "rest_lengths":
                    key, message = "cable_rest_lengths", _joint_state(*value)
                elif action == "wrench":
                    key, message = "external_wrench", _wrench(*value)
                else:
                    key, message = value
                reason = logic.receive(key, message)
                assert reason is None or (isinstance(reason, str) and reason), reason
                if reason is not None:
                    assert _snapshot(logic.sim) == before, "a refused message changed the state"
                    verdict.append("refused")
        elif action == "update":
            with outcome("node parameter update", (ValueError,)):
                logic.update(**value)
        elif action == "command":  # the DDS node's ~/command
            from tensegrity_sim.ros.dds_node import run_command
            with outcome("node command", ()) as verdict:
                result = run_command(logic, value)
                assert ": ok: " in result or ": failed: " in result, result
                if ": failed: " in result:
                    verdict.append("refused")
        elif action == "service":
            with outcome("node service", ()) as verdict:
                ok, text = getattr(logic, value)()
                assert isinstance(ok, bool) and text
                if not ok:
                    verdict.append("refused")
        else:
            with outcome("node tick", ()):
                start = logic._clock.t
                logic.tick()
                assert logic._clock.t - start < 1.0, "a tick ran for more than a second of its clock"
        assert np.all(np.isfinite(logic.sim.positions)), "NaN reached the node's state"
    for key, data in sent:  # nothing non-finite is ever published
        if key == "node_poses":
            assert np.all(np.isfinite(positions_of(M.deserialize(data, TOPICS[key].typename))))
        elif key in ("cable_states", "cable_impulses"):
            msg = M.deserialize(data, TOPICS[key].typename)
            assert all(np.all(np.isfinite(np.asarray(a, dtype=float))) for a in (msg.position, msg.velocity,
                                                                                msg.effort))


# --------------------------------------------------------------------------- command schedules
COMMAND_POINTS = st.lists(st.one_of(
    st.fixed_dictionaries({"time": st.one_of(FLOATS, INTS, VALUES)}, optional={
        "rest_lengths": st.one_of(st.dictionaries(st.sampled_from(["c0", "c1", "x"]) | TEXT,
                                                  st.one_of(FLOATS, INTS, VALUES), max_size=3), VALUES),
        "forces": st.one_of(st.dictionaries(st.sampled_from(["n0", "n1", "x"]) | TEXT,
                                            st.one_of(st.lists(FLOATS, min_size=3, max_size=3), VALUES),
                                            max_size=3), VALUES)}),
    VALUES), max_size=4) | VALUES


def fuzz_commands(points) -> None:
    global _NODE_SCENE
    if _NODE_SCENE is None:
        _NODE_SCENE = prism()
    with outcome("command schedule", (CommandError,)):
        schedule = parse_commands(points, _NODE_SCENE, "fuzz.yaml")
        base = _NODE_SCENE.cable_rest_lengths
        for t in (0.0, 0.5, 1e9):
            assert np.all(np.isfinite(schedule.rest_lengths_at(t, base)))


# --------------------------------------------------------------------------- the command line
def cli_argv(tmp_dir):
    """argv for ``tensegrity-sim``: each verb with options drawn from valid, absurd and hostile values,
    file arguments among real files, missing files, directories, special files and empty strings."""
    files = [str(tmp_dir / "missing.mcap"), str(tmp_dir), "/dev/full", "/dev/null", "", "prism3", "nope",
             str(tmp_dir / "bad.yaml"), str(tmp_dir / "log.mcap"), str(tmp_dir / "plain.txt"),
             str(tmp_dir / "plain.txt" / "x.mcap"), str(tmp_dir / "dir.mcap")]
    def not_a_number(text):
        try:
            float(text)
        except ValueError:
            return True
        return False

    # valid steps and durations are kept to short runs (a valid long run is not what this fuzzes)
    bad = st.one_of(st.sampled_from(["0", "-1", "nan", "inf", "-inf", "1e-320", "1e400", "abc", "", "5e-10"]),
                    TEXT.filter(not_a_number))
    steps = st.one_of(st.sampled_from(["0.002", "0.001", "1e-3"]), bad)
    durations = st.one_of(st.sampled_from(["0.004", "0.01", "1e-9"]), bad)
    run = st.tuples(
        st.just(["run", "--duration", "0.004"]), st.one_of(st.just([]), st.sampled_from(files).map(lambda f: [f])),
        st.lists(st.one_of(
            st.tuples(st.just("--dt"), steps), st.tuples(st.just("--duration"), durations),
            st.tuples(st.just("--method"), st.sampled_from(["auto", "elastic", "inextensible", "x", ""])),
            st.tuples(st.just("--solver"), st.sampled_from(["daqp", "x"])),
            st.tuples(st.just("--contacts"), st.sampled_from(["none", "strut_strut", "x,y", "", ","])),
            st.tuples(st.just("--commands"), st.sampled_from(files)),
            st.tuples(st.just("--log"), st.sampled_from(files)),
        ), max_size=4).map(lambda opts: [a for o in opts for a in o]),
    ).map(lambda parts: [a for p in parts for a in p])
    read = st.tuples(st.sampled_from(["info", "replay", "recover"]), st.sampled_from(files),
                     st.sampled_from(files)).map(lambda t: [t[0], t[1]] + ([t[2]] if t[0] == "recover" else []))
    return st.one_of(run, read, st.lists(TEXT, max_size=3))


def fuzz_cli(argv) -> tuple[int, str]:
    """Run ``tensegrity-sim argv`` in this process; returns (exit status, stderr)."""
    from tensegrity_sim.cli import main

    err, out = io.StringIO(), io.StringIO()
    with outcome("command line", ()) as verdict:
        try:
            with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
                status = main(argv)
        except SystemExit as exc:  # argparse's own usage error
            status = exc.code
        assert status in (0, 1, 2), status
        if status == 2 and not err.getvalue().startswith("usage:"):
            lines = err.getvalue().splitlines()
            assert len(lines) == 1 and lines[0].startswith("tensegrity-sim "), err.getvalue()
        if status:
            verdict.append("refused")
    return status, err.getvalue()
