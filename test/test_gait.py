"""optimize-gait: the written schedule replays (run --commands) to the distance the search reported; CMA-ES keeps
its best; the gradient's objective (the JAX run) is the numba run's, and its step goes uphill; bad input exits 2."""
import numpy as np
import pytest

import tensegrity_sim as ts
from tensegrity_sim.batch import BatchSimulator
from tensegrity_sim.cli import main
from tensegrity_sim.commands import load_commands
from tensegrity_sim.optimize.gait import GaitProblem, cma_search, distances, gradient_search

SCENE = "icosahedron_ground"


def _com_xy(scene, x):
    return (scene.masses @ x / scene.masses.sum())[:2]


def test_cli_gait_replays_to_its_distance(tmp_path, capsys):
    out = tmp_path / "gait.yaml"
    assert main(["optimize-gait", SCENE, "--out", str(out), "--duration", "0.6", "--period", "0.6",
                 "--generations", "2", "--population", "4", "--quiet", "--goal", "0", "2"]) == 0
    reported = float(capsys.readouterr().out.split("CMA-ES: ")[1].split(" m")[0])
    scene = ts.load_scene(SCENE)
    commands = load_commands(out, scene)   # what run --commands reads
    sim = ts.Simulator(scene, method="elastic", dt=1e-3, contacts=())
    trajectory = sim.run(0.6, commands=commands)
    rolled = (_com_xy(scene, trajectory.positions[-1]) - _com_xy(scene, scene.positions))[1]
    assert abs(rolled - reported) < 1e-4   # the summary's 4 decimals; the run itself: the next test
    assert "replay: tensegrity-sim run" in out.read_text()


def test_cma_keeps_its_best_and_the_batch_is_the_single_run():
    scene = ts.load_scene(SCENE)
    problem = GaitProblem(scene, [4, 5, 6], (1.0, 0.0), 0.5, 0.5, 2)
    gait = cma_search(problem, generations=3, population=4, seed=1)
    assert gait.history == sorted(gait.history) and gait.history[-1] == gait.distance
    assert gait.u.shape == (3, 2) and gait.u.min() >= 0 and gait.u.max() <= 1
    # the best candidate alone, and a copy of another batch, roll the same distance (copies are independent)
    again = distances(problem, [np.zeros((3, 2)), gait.u])
    assert again[1] == gait.distance
    sim = BatchSimulator(scene, 1, method="elastic", contacts=())
    run = sim.run(steps=problem.steps, every=problem.steps, commands=problem.schedule(gait.u))
    assert abs((_com_xy(scene, run.positions[0, -1]) - _com_xy(scene, scene.positions))[0] - gait.distance) < 1e-12


def test_gradient_objective_is_the_numba_run_and_goes_uphill():
    pytest.importorskip("jax")   # the jax extra (CI's first leg installs it)
    scene = ts.load_scene(SCENE)
    problem = GaitProblem(scene, [4, 5, 6], (1.0, 0.0), 0.3, 0.3, 2)
    start = np.full((3, 2), 0.2)
    gait = gradient_search(problem, start, iterations=2)
    assert gait.history[0] == distances(problem, [start])[0]
    assert gait.distance >= gait.history[0] and gait.distance == distances(problem, [gait.u])[0]
    assert gait.distance > gait.history[0] and gait.history == sorted(gait.history)   # uphill along the gradient


@pytest.mark.parametrize("args, message", [
    (["icosahedron"], "has no ground"),
    ([SCENE, "--cables", "c4,rope"], "unknown cable 'rope'"),
    ([SCENE, "--goal", "0", "0"], "--goal must be a horizontal direction"),
    ([SCENE, "--knots", "0"], "knots must be a whole number >= 1"),
])
def test_bad_input_exits_2(tmp_path, capsys, args, message):
    out = tmp_path / "gait.yaml"
    assert main(["optimize-gait", *args, "--out", str(out)]) == 2
    assert message in capsys.readouterr().err and not out.exists()
