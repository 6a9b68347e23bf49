"""``tensegrity-sim fit``: a log of a run with known stiffness and damping, a start 30 % off, both recovered to
1e-6 relative from the log's node_poses; a commanded log and unknown parameters refused (exit 2)."""
import os

import numpy as np
import pytest

import tensegrity_sim as ts
from bench.cases import rigid_consistent
from tensegrity_sim.cli import main

if os.environ.get("TENSEGRITY_SIM_REQUIRE_JAX") == "1":
    import jax  # noqa: F401
else:
    pytest.importorskip("jax")

STIFFNESS, DAMPING = 613.0, 2.0


@pytest.fixture(scope="module")
def logged(tmp_path_factory):
    """The icosahedron, damped, tumbling gently (every cable taut), logged for 0.3 s; and a start 30 % off."""
    tmp = tmp_path_factory.mktemp("fit")
    d = ts.load_scene("icosahedron").to_dict()
    rng = np.random.default_rng(1)
    for node in d["nodes"]:
        node["velocity"] = [float(c) for c in rng.normal(scale=0.3, size=3)]
    for c in d["cables"]:
        assert c["stiffness"] == STIFFNESS
        c["damping"] = DAMPING
    truth = rigid_consistent(d)
    (tmp / "truth.yaml").write_text(truth.to_yaml())
    d = truth.to_dict()
    for c in d["cables"]:
        c["stiffness"] *= 1.3
        c["damping"] *= 1.3
    (tmp / "start.yaml").write_text(ts.Scene.from_dict(d).to_yaml())
    assert main(["run", str(tmp / "truth.yaml"), "--method", "elastic", "--duration", "0.3", "--quiet",
                 "--log", str(tmp / "run.mcap")]) == 0
    return tmp


def test_fit_recovers_stiffness_and_damping(logged, capsys):
    capsys.readouterr()
    assert main(["fit", str(logged / "run.mcap"), "--params", "stiffness,damping", "--scene",
                 str(logged / "start.yaml"), "--out", str(logged / "fitted.yaml")]) == 0
    out = capsys.readouterr().out
    fitted = ts.load_scene(logged / "fitted.yaml")
    for c in fitted.cables:
        assert abs(c.stiffness / STIFFNESS - 1) < 1e-6 and abs(c.damping / DAMPING - 1) < 1e-6, (c, out)
    lines = {line.split()[0]: line for line in out.splitlines()}
    assert lines["stiffness"].split()[1:3] == ["796.9", "->"] and lines["damping"].split()[1] == "2.6"
    before, after = (float(w) for w in lines["residual"].split()[2:6:3])
    assert before > 1e-3 and after < 1e-12
    # everything else is the logged scene's
    np.testing.assert_array_equal(fitted.velocities, ts.load_scene(logged / "truth.yaml").velocities)


def test_fit_refuses_unknown_parameters_and_a_commanded_log(logged, capsys, tmp_path):
    assert main(["fit", str(logged / "run.mcap"), "--params", "stiffness,inertia"]) == 2
    assert "unknown parameter 'inertia'" in capsys.readouterr().err
    assert main(["fit", str(logged / "run.mcap"), "--params", "damping:nope"]) == 2
    assert "no cable 'nope'" in capsys.readouterr().err
    commands = tmp_path / "commands.yaml"
    commands.write_text("- time: 0.0\n  rest_lengths: {c0: 0.9}\n")
    assert main(["run", str(logged / "truth.yaml"), "--method", "elastic", "--duration", "0.05", "--quiet",
                 "--commands", str(commands), "--log", str(tmp_path / "commanded.mcap")]) == 0
    assert main(["fit", str(tmp_path / "commanded.mcap"), "--params", "stiffness"]) == 2
    assert "the run was commanded" in capsys.readouterr().err
