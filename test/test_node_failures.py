"""A failed step does not stop the node: real QP failures of the inextensible method, each backend.

The icosahedron's rigid struts and taut inextensible cables carry a self-stress, so no cable of it can
shorten: the step after such a command fails (``QPError``) and the simulator is left as it was. The node
refuses the command after the fact and steps on; a failure with nothing to give up pauses it. Logs of
all of it replay bit for bit, failures included.
"""
import json
import re

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader

import tensegrity_sim as ts
from tensegrity_sim.cli import main
from tensegrity_sim.ros import messages as M
from tensegrity_sim.ros.log import RUN_INFO, LogRecorder
from tensegrity_sim.ros.node_logic import TOPICS, NodeSettings, SimNodeLogic
from tensegrity_sim.ros.replay import replay
from ros_helpers import FakeClock, ListLogger, positions_of, rest_lengths_msg, rewrite, wrench_msg

G = 9.81
DT = 1e-3
# the built-in icosahedron is prestressed: the inextensible method says so whenever it loads it
pytestmark = pytest.mark.filterwarnings("ignore::tensegrity_sim.LengthOffsetWarning")
LOCKED = ("the commanded shortening of c0 cannot be followed: the taut cables and rigid struts lock the "
          "structure (they carry a self-stress), so no cable can shorten unless another member gives")


def falling_icosahedron() -> ts.Scene:
    """The built-in icosahedron under gravity: it falls as a rigid body, its cables slack of nothing."""
    d = ts.load_scene("icosahedron").to_dict()
    d["gravity"] = [0.0, 0.0, -G]
    return ts.Scene.from_dict(d)


def locked_prism(c0_extra: float) -> ts.Scene:
    """prism3 with rigid struts and every cable at its length (locked by its self-stress), but c0
    ``c0_extra`` m longer (slack: the prism is a mechanism until c0 is taut again)."""
    d = ts.load_scene("prism3").to_dict()
    for member in d["struts"] + d["cables"]:
        member.pop("rest_length")
    for strut in d["struts"]:
        strut["stiffness"] = "rigid"
    d["cables"][0]["rest_length"] = ts.Scene.from_dict(d).cable_rest_lengths[0] + c0_extra
    return ts.Scene.from_dict(d)


def node(scene, path=None, solver="auto", **settings):
    """(logic on a fake clock at dt = 1 ms, what it sent, its logger, its clock); logging to ``path``."""
    sent, logger, clock = [], ListLogger(), FakeClock(t=0.0)
    sim = ts.Simulator(scene, method="inextensible", dt=DT, solver=NodeSettings(solver=solver).qp_solver)
    logic = SimNodeLogic(sim, NodeSettings(scene=scene.name, solver=solver, dt=DT, **settings),
                         transport=lambda key, msg: sent.append((key, msg)), clock=clock, logger=logger)
    if path is not None:
        logic.recorder = LogRecorder(path, logic.channels(), logic.run_info())
    return logic, sent, logger, clock


def snapshot(sim):
    return sim.time, sim.positions, sim.velocities, sim.rest_lengths, sim.external_forces


def failure_reports(sent):
    return [m.status[0] for k, m in sent if k == "diagnostics" and m.status[0].name.endswith("step failed")]


@pytest.mark.parametrize("solver", sorted(ts.SOLVERS))
def test_a_cable_the_structure_cannot_shorten_is_refused_after_the_fact(tmp_path, solver):
    """The falling icosahedron is told to shorten c0 (and to push n3) at 20 ms, between two ticks. The
    step fails; both messages are refused after the fact; the state is exactly what it was; the node
    keeps its schedule and the icosahedron keeps falling freely, bit for bit as a twin that never saw
    the messages, its centroid at -g t^2 / 2 (the midpoint rule is exact for a constant force). The log
    replays, with the same refusal at the same step."""
    scene = falling_icosahedron()
    logic, sent, logger, clock = node(scene, tmp_path / "run.mcap", solver)
    twin, twin_sent, _, twin_clock = node(scene, solver=solver)
    with logic.recorder:
        for k in range(1, 61):
            if k == 21:
                before = snapshot(logic.sim)
                c0 = logic.sim.rest_lengths[0]
                assert logic.receive("cable_rest_lengths", rest_lengths_msg(["c0"], [0.99 * c0])) is None
                assert logic.receive("external_wrench", wrench_msg("n3", [1.0, 0.0, 0.0])) is None
            for n, c in ((logic, clock), (twin, twin_clock)):
                c.t = k * DT + 1e-7
                n.tick()
            if k == 21:  # the one step due failed: nothing changed, and nothing is left of the messages
                assert logic.sim.step_count == 20
                for a, b in zip(before, snapshot(logic.sim)):
                    np.testing.assert_array_equal(a, b)
    assert logic.sim.step_count == twin.sim.step_count == 60  # caught up at the next tick
    assert (logic.failed_steps, logic.refused, logic.received) == (
        1, {"cable_rest_lengths": 1, "external_wrench": 1}, {"cable_rest_lengths": 1, "external_wrench": 1})
    assert not logic.paused and logic.overruns == 0
    assert len(logger.warnings) == 2 and logger.errors == []
    for warning, topic in zip(logger.warnings, ("cable_rest_lengths", "external_wrench")):
        assert warning.startswith(f"/tensegrity_sim/{topic}: refused after the fact: the step from "
                                  f"t = 0.020000 s failed: QP solver '{solver}' failed (")
        assert warning.endswith(LOCKED)
    (report,) = failure_reports(sent)
    assert report.level == M.byte(1) and report.message.startswith("the step from t = 0.020000 s failed")
    assert report.message.endswith("; the input message(s) since the previous step are refused after the fact")
    outputs = [(k, M.serialize(m, TOPICS[k].typename)) for k, m in sent if k != "diagnostics"]
    assert outputs == [(k, M.serialize(m, TOPICS[k].typename)) for k, m in twin_sent]
    np.testing.assert_array_equal(logic.sim.rest_lengths, scene.cable_rest_lengths)
    drop = logic.sim.positions[:, 2].mean() - scene.positions[:, 2].mean()
    assert drop == pytest.approx(-0.5 * G * 0.06 ** 2, rel=1e-12)

    result = replay(tmp_path / "run.mcap")
    assert result.ok, result.mismatch
    assert result.steps == 60 and result.compared["/diagnostics"] == 1
    assert result.notes == [f"2 input message(s) refused again, as in the run; the first: {logger.warnings[0]}"]


def test_a_rate_limited_reel_in_stops_where_the_structure_locks(tmp_path):
    """prism3 with rigid struts, c0 20.05 mm slack, reeled in at 0.1 m/s (0.1 mm a step) towards 5 mm
    shorter than its length. The first 200 steps reel the slack in; the 201st reels 0.05 mm past c0's
    length, which a running motor's cable lands half a step's reel (0.05 mm) behind, so it holds; the
    202nd would shorten the now taut c0 of a locked prism and fails. The target is refused after the
    fact and c0's rest length stays 0.05 mm below its length; the prism never moves, and the node steps on."""
    scene = locked_prism(0.02005)
    length = float(np.linalg.norm(np.subtract(*scene.positions[[scene.node_names.index(n) for n in
                                                                 scene.cables[0].nodes]])))
    logic, _, logger, _ = node(scene, tmp_path / "reel.mcap", max_rest_length_rate=0.1)
    with logic.recorder:
        logic.receive("cable_rest_lengths", rest_lengths_msg(["c0"], [length - 0.005]))
        results = [logic.step() for _ in range(300)]
        logic.publish()
    assert [k for k, r in enumerate(results) if r is None] == [201]
    assert logic.sim.step_count == 299 and not logic.paused
    assert logic.sim.rest_lengths[0] == pytest.approx(length - 0.00005, abs=1e-12)
    np.testing.assert_array_equal(logic.sim.rest_lengths[1:], scene.cable_rest_lengths[1:])
    np.testing.assert_array_equal(logic.sim.positions, scene.positions)
    np.testing.assert_array_equal(logic.sim.velocities, 0.0)
    assert logic.refused["cable_rest_lengths"] == 1 and len(logger.warnings) == 1
    assert logger.warnings[0].startswith("/tensegrity_sim/cable_rest_lengths: refused after the fact: the step "
                                         "from t = 0.201000 s failed: QP solver 'daqp' failed (infeasible)")
    assert logger.warnings[0].endswith(LOCKED)
    assert replay(tmp_path / "reel.mcap").ok


def test_a_failure_with_nothing_to_give_up_pauses_the_node(tmp_path):
    """OSQP reports the feasible step of a pushed icosahedron infeasible (qp.py: a known false
    infeasibility), and keeps doing so from the same state. Nothing came in since the last step, so
    the node pauses with the reason on /diagnostics (ERROR), in its log and in the logger; ticks do
    nothing, a single step fails again and says why; a reset and a resume step on. Both log files
    replay bit for bit, every failed attempt included (a failed OSQP solve changes its warm start)."""
    scene = ts.load_scene("icosahedron")
    logic, sent, logger, clock = node(scene, tmp_path / "stuck.mcap", "osqp")
    with logic.recorder:
        logic.receive("external_wrench", wrench_msg("n0", [0.0, 0.0, 30.0]))
        for k in range(1, 6):
            clock.t = k * DT + 1e-7
            logic.tick()
        assert logic.sim.step_count == 1 and logic.paused and logic.failed_steps == 1
        reason = ("the step from t = 0.001000 s failed: QP solver 'osqp' failed (primal infeasible): after 50 ADMM "
                  "iterations; paused: change the inputs and resume, or reset")
        assert logic.failure == reason and logger.errors == [reason] and logger.warnings == []
        logic.publish_diagnostics()
        reports = [m.status[0] for k, m in sent if k == "diagnostics"]
        assert [(s.name, s.level, s.message) for s in reports] == [
            ("tensegrity_sim: step failed", M.byte(2), reason), ("tensegrity_sim: stepping", M.byte(2), reason)]
        assert {kv.key: kv.value for kv in reports[1].values}["failed_steps"] == "1"
        assert logic.single_step() == (False, "step failed: QP solver 'osqp' failed (primal infeasible): after 50 "
                                              "ADMM iterations (see /diagnostics)")
        assert logic.sim.step_count == 1 and logic.failed_steps == 2
        assert logic.reset() == (True, f"reset to the scene's initial state; now logging to "
                                       f"{tmp_path / 'stuck_reset1.mcap'}")
        assert logic.failure is None and logic.resume()[0]
        for k in range(6, 56):
            clock.t = k * DT + 1e-7
            logic.tick()
        logic.recorder.finish()
    assert logic.sim.step_count == 50 and logic.failed_steps == 2 and not logic.paused
    np.testing.assert_allclose(logic.sim.positions, scene.positions, rtol=0, atol=1e-15)  # at rest again
    first, second = (replay(p) for p in logic.recorder.paths)
    assert first.ok and first.steps == 1 and first.compared == {"/diagnostics": 2}
    assert first.notes == [f"2 failed step(s) paused the run again; the first: {reason}"]
    assert second.ok and second.steps == 50 and second.compared["/tensegrity_sim/node_poses"] == 5


def test_replay_catches_a_failure_that_does_not_happen_and_one_that_is_not_logged(tmp_path):
    scene = falling_icosahedron()
    logic, _, _, _ = node(scene, tmp_path / "run.mcap")
    with logic.recorder:
        for k in range(40):
            if k == 15:
                logic.receive("cable_rest_lengths", rest_lengths_msg(["c0"], [0.99 * logic.sim.rest_lengths[0]]))
            logic._advance()
    assert logic.failed_steps == 1 and logic.sim.step_count == 39

    def harmless(topic, index, msg):  # the command made a no-op: the step it failed no longer fails
        if topic == "/tensegrity_sim/cable_rest_lengths":
            msg.position = np.array(scene.cable_rest_lengths[:1])
        return msg

    rewrite(tmp_path / "run.mcap", tmp_path / "harmless.mcap", harmless)
    m = replay(tmp_path / "harmless.mcap").mismatch
    assert (m.step, m.time_ns, m.topic, m.replayed) == (16, 15_000_000, "/diagnostics", "the step succeeded")
    assert m.logged.startswith("the step from t = 0.015000 s failed: QP solver 'daqp' failed (infeasible)")

    rewrite(tmp_path / "run.mcap", tmp_path / "unlogged.mcap",
            lambda topic, index, msg: None if topic == "/diagnostics" else msg)
    m = replay(tmp_path / "unlogged.mcap").mismatch
    assert (m.step, m.time_ns, m.topic, m.field, m.logged) == (15, 15_000_000, "/diagnostics", "message", "none")
    assert m.replayed.startswith("a failed step: QP solver 'daqp' failed (infeasible)") and m.replayed.endswith(LOCKED)


def test_an_offline_run_stops_at_a_failed_step_with_a_finished_log(tmp_path, capsys):
    """``run --log`` goes through the node logic: the failed step is logged, then the run stops with
    the QPError as it does without a log (exit status 2), and the log replays (with the QP backend the
    run used, which the node settings name too)."""
    commands = tmp_path / "commands.yaml"
    c0 = ts.load_scene("icosahedron").cable_rest_lengths[0]
    commands.write_text(yaml.safe_dump([{"time": 0.0295, "rest_lengths": {"c0": float(c0)}},  # c0 at 30 ms
                                        {"time": 0.03, "rest_lengths": {"c0": float(0.99 * c0)}}]))
    log = tmp_path / "run.mcap"
    assert main(["run", "icosahedron", "--method", "inextensible", "--solver", "nnls", "--duration", "0.1",
                 "--commands", str(commands), "--log", str(log), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "tensegrity-sim run: error: QP solver 'nnls' failed (infeasible output)" in err and LOCKED in err
    with open(log, "rb") as f:
        info = next(r.metadata for r in make_reader(f).iter_metadata() if r.name == RUN_INFO)
    assert json.loads(info["method_settings"])["solver"] == json.loads(info["node_settings"])["solver"] == "nnls"
    result = replay(log)
    assert result.ok and result.steps == 30 and result.compared["/diagnostics"] == 1


@pytest.mark.filterwarnings("ignore:overflow encountered", "ignore:invalid value encountered")
def test_wrench_that_divided_by_zero_in_the_kernel_is_a_clean_step_error():
    """Issue 28: a 1e20 N wrench on an icosahedron node made the compiled elastic kernel raise
    ZeroDivisionError four steps later (the strut's two ends rounded to the same far-away point: a
    length of 0 divided by; numba's Python error model raises there) and the node died with it. The
    kernels now divide as numpy does and the step's non-finite result is a NonFiniteError: the node
    pauses with the reason, naming the node and the wrench."""
    scene = ts.load_scene("icosahedron")
    logic = SimNodeLogic(ts.Simulator(scene, method="elastic", dt=DT), NodeSettings(dt=DT, log_path=""),
                         transport=lambda key, msg: None, clock=FakeClock(t=0.0), logger=ListLogger())
    assert logic.receive("external_wrench", wrench_msg("n0", [1e20, 0.0, 0.0])) is None   # accepted
    results = [logic.step() for _ in range(10)]
    failed = results.index(None)
    assert failed >= 1 and all(r is not None for r in results[:failed])   # finite, absurd steps first
    assert isinstance(logic.step_error, ts.NonFiniteError) and logic.paused
    assert re.search(r"gave non-finite values at node 'n\d+'.*largest external force 1e\+20 N at node 'n0'",
                     logic.failure)


@pytest.mark.filterwarnings("ignore:overflow encountered", "ignore:invalid value encountered")
def test_absurd_force_is_refused_after_the_fact_and_nothing_non_finite_is_published(tmp_path):
    """Issue 13: a finite but absurd wrench used to make the node publish and log NaN positions. The
    step's NonFiniteError is a failed step: the wrench is refused after the fact, the node steps on as if
    it never came, and the log replays bit for bit."""
    from ros_helpers import prism

    scene = prism()
    sent, logger = [], ListLogger()
    logic = SimNodeLogic(ts.Simulator(scene, method="elastic", dt=DT), NodeSettings(dt=DT, log_path=""),
                         transport=lambda key, msg: sent.append((key, msg)), clock=FakeClock(t=0.0), logger=logger)
    logic.recorder = LogRecorder(tmp_path / "absurd.mcap", logic.channels(), logic.run_info())
    twin = ts.Simulator(scene, method="elastic", dt=DT)
    for _ in range(3):
        logic.step()
        twin.step()
    assert logic.receive("external_wrench", wrench_msg("n1", [1e300, 0.0, 0.0])) is None  # accepted...
    assert logic.step() is None                                                        # ...the step fails
    assert isinstance(logic.step_error, ts.NonFiniteError) and not logic.paused
    assert logic.refused["external_wrench"] == 1
    # how far the overflow spreads within the step depends on the order of the arithmetic (the compiled
    # kernel's and numpy's differ): the count of other nodes is not pinned
    assert re.match(r"/tensegrity_sim/external_wrench: refused after the fact: the step from t = 0\.003000 s "
                    r"failed: the step from t = 0\.003000 s gave non-finite values at node 'n0' \(and [45] more\) "
                    r"and cable 'c0' \(and 2 more\) \(inputs: largest external force 1e\+300 N at node 'n1';",
                    logger.warnings[-1])
    assert [k for k, _ in sent] == ["diagnostics"] and sent[0][1].status[0].level == M.byte(1)
    for _ in range(10):
        r = logic.step()
        assert np.array_equal(r.positions, twin.step().positions)
    logic.publish()
    assert all(np.all(np.isfinite(positions_of(m))) for k, m in sent if k == "node_poses")
    logic.recorder.finish()
    assert replay(tmp_path / "absurd.mcap").ok
