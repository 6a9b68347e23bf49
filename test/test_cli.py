"""The command line and the command schedule format."""
import subprocess
import sys

import numpy as np
import pytest
import yaml

import tensegrity_sim as ts
from tensegrity_sim.cli import main, simulate
from tensegrity_sim.commands import CommandError, parse_commands
from conftest import deadband_dict


def test_main_job_shows_slack_and_snaps_and_says_where_it_wrote(tmp_path, monkeypatch, capsys):
    """``run --plot --view`` without a scene: prism3 with its demo schedule, logged, plotted, and a page.
    By 3.2 s the side cables were reeled out (every cable slackens) and back in (every cable snaps taut)."""
    monkeypatch.chdir(tmp_path)
    assert main(["run", "--duration", "3.2", "--quiet", "--plot", "--view"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert "scene            prism3" in lines and "simulated        3.2 s in 3200 steps" in lines
    assert "steps/s" in lines[5] and "max tension" in lines[7] and "the commands' work included" in lines[10]
    assert lines[6].startswith("kernels          ")   # apart from the stepping: compiled, or loaded from the cache
    switches = int(lines[8].split()[1])
    assert switches >= 2 * 9  # each of the 9 cables went slack, then taut
    [log] = [line.split()[1] for line in lines if line.startswith("log ")]
    assert (tmp_path / log).stat().st_size > 0
    [plots] = [line for line in lines if line.startswith("plots ")]
    stem = log.split("/")[-1][:-len(".mcap")]
    assert plots.split()[1] == f"plots/{stem}/"
    for name in ("tensions", "impulses", "energy", "contacts"):
        assert (tmp_path / "plots" / stem / f"{name}.png").stat().st_size > 0
    [page] = [line for line in lines if line.startswith("page ")]
    assert page.split()[1] == f"plots/{stem}.html" and (tmp_path / "plots" / f"{stem}.html").exists()


def test_run_refuses_bad_scene_with_exit_2(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text("nodes: []\n")
    assert main(["run", str(bad)]) == 2
    assert "bad.yaml: nodes: must be a non-empty list" in capsys.readouterr().err


def test_console_script_help():
    out = subprocess.run([sys.executable, "-m", "tensegrity_sim.cli", "run", "--help"],
                         capture_output=True, text=True, check=True).stdout
    assert "--commands" in out and "--duration" in out


def test_schedule_interpolates_and_holds():
    scene = ts.Scene.from_dict(deadband_dict())
    sched = parse_commands([
        {"time": 0.0, "rest_lengths": {"cl": 1.0}},
        {"time": 1.0, "rest_lengths": {"cl": 0.8}, "forces": {"mass": [0, 0, 2.0]}},
        {"time": 2.0, "forces": {"mass": [0, 0, 0.0]}},
    ], scene)
    base = scene.cable_rest_lengths
    np.testing.assert_allclose(sched.rest_lengths_at(0.25, base), [0.95, 1.1])
    np.testing.assert_allclose(sched.rest_lengths_at(5.0, base), [0.8, 1.1])
    assert sched.forces_at(0.5) is None
    np.testing.assert_array_equal(sched.forces_at(1.5)[1], [0, 0, 2.0])
    np.testing.assert_array_equal(sched.forces_at(2.0)[1], [0, 0, 0.0])


def test_schedule_applied_by_simulate():
    """A constant force from t = 0 changes the momentum by exactly f * t (contract: impulse balance)."""
    scene = ts.Scene.from_dict(deadband_dict(v0=0.0))
    sim = ts.Simulator(scene, method="elastic", dt=1e-3)
    sched = parse_commands([{"time": 0.0, "forces": {"mass": [0.0, 0.0, 4.0]}}], scene)
    summary = simulate(sim, 100, sched)
    assert summary.steps == 100
    assert sim.momentum()[0][2] == pytest.approx(0.4, rel=1e-12)


@pytest.mark.parametrize("points, message", [
    ([{"time": 0.0, "rest_lengths": {"zz": 1.0}}], "point[0]: rest_lengths: unknown cable 'zz'"),
    ([{"time": 0.0, "rest_lengths": {"cl": -1.0}}], "point[0]: rest_lengths['cl'] must be > 0, got -1.0"),
    ([{"time": 1.0}, {"time": 0.5}], "point[1]: time must be >= 0 and increase strictly, got 0.5 after 1.0"),
    ([{"time": 0.0, "forces": {"mass": [1, 2]}}], "point[0]: forces['mass'] must be 3 numbers, got [1, 2]"),
    ([{"time": 0.0, "speed": 1}], "point[0]: unknown key 'speed' (allowed: forces, rest_lengths, time)"),
    ([{"rest_lengths": {}}], "point[0]: missing required key 'time'"),
])
def test_schedule_refusals(points, message):
    with pytest.raises(CommandError) as err:
        parse_commands(points, ts.Scene.from_dict(deadband_dict()), "cmds.yaml")
    assert str(err.value) == f"cmds.yaml: {message}"


def test_run_with_commands_file(tmp_path, capsys):
    cmds = tmp_path / "cmds.yaml"
    cmds.write_text(yaml.safe_dump([{"time": 0.0, "rest_lengths": {"c0": 0.5}}]))
    scene = ts.load_scene("prism3")
    assert "c0" in scene.cable_names
    assert main(["run", "prism3", "--duration", "0.1", "--commands", str(cmds), "--quiet"]) == 0
    assert "switches" in capsys.readouterr().out


def test_plot_and_view_of_a_run_too_short_to_publish_say_so(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["run", "--duration", "0.004", "--quiet", "--plot", "--view"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert "plots            none: the run ended before its first publication (there is nothing to draw)" in out
    assert not (tmp_path / "plots").exists()


def test_a_warning_is_one_line_and_info_lists_the_settings_one_per_line(tmp_path, capsys):
    log = tmp_path / "ico.mcap"
    assert main(["run", "icosahedron", "--method", "inextensible", "--duration", "0.02", "--quiet",
                 "--log", str(log)]) == 0
    captured = capsys.readouterr()
    assert captured.err.splitlines() == [
        "tensegrity-sim run: warning: inextensible cables: 24 cables start longer than their rest length "
        "(prestress); their length limits are rest length + that stretch (largest 0.130506 m, 'c22'), kept "
        "when rest lengths are commanded"]
    assert [line for line in captured.out.splitlines() if line.startswith("log")] == [f"log              {log}"]
    assert main(["info", str(log)]) == 0
    out = capsys.readouterr().out.splitlines()
    first = out.index("settings")
    assert "  solver         daqp" in out[first:first + 20]
    assert "  length_offsets 24 cables, 0.130506 m to 0.130506 m (c22); the log's metadata has each" in out
