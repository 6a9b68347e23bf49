"""``tensegrity-sim fit`` (multiple shooting, ``methods/jax/fit.py``): a commanded log of a run with known
stiffness and damping, fitted from a nominal scene 1.3x off, recovers them to 1e-3 relative from the log's
node_poses; the sparse Jacobian is the dense one of JAX; bad input is refused in one line (exit 2)."""
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

STIFFNESS, DAMPING = 2000.0, 0.5
COMMANDS = "- time: 0.0\n  rest_lengths: {c0: 0.68}\n- time: 0.1\n  rest_lengths: {c0: 0.60}\n" \
           "- time: 0.2\n  forces: {n3: [0.0, 0.0, 15.0]}\n"


@pytest.fixture(scope="module")
def logged(tmp_path_factory):
    """prism3 thrown (cables going slack and snapping), damped, c0 reeled in and a force on n3 (commands), logged
    for 0.4 s; and the nominal scene with stiffness and damping 1.3x the truth."""
    tmp = tmp_path_factory.mktemp("fit")
    d = ts.load_scene("prism3").to_dict()
    rng = np.random.default_rng(3)
    for node in d["nodes"]:
        node["velocity"] = [float(c) for c in rng.normal(scale=1.5, size=3)]
    for c in d["cables"]:
        assert c["stiffness"] == STIFFNESS
        c["damping"] = DAMPING
    truth = rigid_consistent(d)
    (tmp / "truth.yaml").write_text(truth.to_yaml())
    d = truth.to_dict()
    for c in d["cables"]:
        c["stiffness"] *= 1.3
        c["damping"] *= 1.3
    (tmp / "nominal.yaml").write_text(ts.Scene.from_dict(d).to_yaml())
    (tmp / "commands.yaml").write_text(COMMANDS)
    assert main(["run", str(tmp / "truth.yaml"), "--method", "elastic", "--duration", "0.4", "--quiet",
                 "--commands", str(tmp / "commands.yaml"), "--log", str(tmp / "run.mcap")]) == 0
    return tmp


def test_fit_recovers_stiffness_and_damping_of_a_commanded_run(logged, capsys):
    capsys.readouterr()
    assert main(["fit", str(logged / "run.mcap"), "--params", "stiffness,damping", "--scene",
                 str(logged / "nominal.yaml"), "--out", str(logged / "fitted.yaml"), "--plot",
                 str(logged / "plots")]) == 0
    out = capsys.readouterr().out
    assert {p.name for p in (logged / "plots").iterdir()} == {f"fit_{k}.{e}" for k in ("positions", "residual")
                                                              for e in ("png", "svg")}
    fitted = ts.load_scene(logged / "fitted.yaml")
    for c in fitted.cables:
        assert abs(c.stiffness / STIFFNESS - 1) < 1e-3 and abs(c.damping / DAMPING - 1) < 1e-3, (c, out)
    lines = {line.split()[0]: line.split() for line in out.splitlines()}
    assert lines["stiffness"][1] == "2600" and lines["damping"][1] == "0.65"
    assert float(lines["stiffness"][3]) < 1.0   # the standard deviation, N/m
    before, after = float(lines["residual"][2]), float(lines["residual"][5])
    assert before > 1e-3 and after < 1e-5
    # everything else is the nominal scene's
    np.testing.assert_array_equal(fitted.positions, ts.load_scene(logged / "nominal.yaml").positions)


def test_sparse_jacobian_is_the_dense_one(logged):
    """The Jacobian assembled from the windows' tangents (one per parameter and start-state coordinate, seeded
    in every window at once) against ``jax.jacfwd`` of the whole residual, on the commanded log."""
    import jax
    import jax.numpy as jnp

    from tensegrity_sim.methods.jax.fit import Observed, _Problem, parse_parameters
    from tensegrity_sim.ros.fit_log import read_observed

    scene = ts.load_scene(logged / "nominal.yaml")
    _, obs = read_observed(logged / "run.mcap", scene)
    k = 23   # 0.23 s: a reel-in and the force in three windows
    obs = Observed(obs.dt, obs.steps[:k], obs.positions[:k], obs.rest[:obs.steps[k - 1]],
                   obs.forces[:obs.steps[k - 1]])
    problem = _Problem(scene, obs, parse_parameters("stiffness,damping", scene), 8, 10.0, prior=0.5)
    assert problem.windows == 3 and len(problem.prior_rows) == 2
    z = np.concatenate([problem.p0, problem.state0.ravel()]) * 1.001

    def residual(z):
        p, state = z[:problem.n_params], z[problem.n_params:].reshape(problem.windows, -1)
        xs, xe, ve = problem.pieces(p, state, problem.data)
        obs_rows = (xs - problem.target) * problem.obs_mask[:, None, None, :]
        nf = problem.nf
        x_next = jnp.moveaxis(state[1:, :3 * nf].reshape(-1, nf, 3), 0, -1)
        v_next = jnp.moveaxis(state[1:, 3 * nf:].reshape(-1, nf, 3), 0, -1)
        cont = jnp.stack([problem.cw * (xe[..., :-1] - x_next), problem.cw * problem.tau * (ve[..., :-1] - v_next)])
        return jnp.concatenate([jnp.moveaxis(obs_rows, -1, 0).ravel(), state[0, :3 * nf] - problem.target_start(),
                                jnp.moveaxis(cont, -1, 0).ravel(), problem.prior_weight * (p - 1.0)])

    np.testing.assert_allclose(np.asarray(residual(jnp.asarray(z))), problem.residual(z), rtol=0, atol=1e-15)
    dense = np.asarray(jax.jacfwd(residual)(jnp.asarray(z)))
    np.testing.assert_allclose(problem.jacobian(z).toarray(), dense, rtol=1e-12, atol=1e-12 * np.abs(dense).max())
    # the parameters alone, the start states held: the dense Jacobian's first columns
    p, state = z[:problem.n_params], z[problem.n_params:].reshape(problem.windows, -1)
    np.testing.assert_allclose(problem.parameter_jacobian(p, state), dense[:, :problem.n_params], rtol=1e-12,
                               atol=1e-12 * np.abs(dense).max())
    # the chord: the start states' columns those at z, the parameters' new
    moved = z.copy()
    moved[:problem.n_params] *= 1.02
    chord = problem.jacobian(moved, states=False).toarray()
    exact = np.asarray(jax.jacfwd(residual)(jnp.asarray(moved)))
    np.testing.assert_array_equal(chord[:, problem.n_params:], problem.jacobian(z).toarray()[:, problem.n_params:])
    np.testing.assert_allclose(chord[:, :problem.n_params], exact[:, :problem.n_params], rtol=1e-12,
                               atol=1e-12 * np.abs(exact).max())
    assert np.abs(chord - exact).max() > 1e-9 * np.abs(exact).max()   # the states' columns did move


SPREAD = """
import sys
import jax
import numpy as np
import tensegrity_sim as ts
from tensegrity_sim.methods.jax.fit import Observed, _Problem, parse_parameters, spread_over_cores
from tensegrity_sim.ros.fit_log import read_observed

assert spread_over_cores()                      # before JAX has run: it sets the CPU's devices
jax.config.update("jax_num_cpu_devices", 3)     # 3: the 2 parameters' seeds padded with a zero one
scene = ts.load_scene(sys.argv[1])
_, obs = read_observed(sys.argv[2], scene)
k = 23
obs = Observed(obs.dt, obs.steps[:k], obs.positions[:k], obs.rest[:obs.steps[k - 1]], obs.forces[:obs.steps[k - 1]])
problem = _Problem(scene, obs, parse_parameters("stiffness,damping", scene), 8, 10.0)
z = np.concatenate([problem.p0, problem.state0.ravel()]) * 1.001
np.save(sys.argv[3], problem.jacobian(z).toarray())
assert problem.devices == jax.device_count() == 3 and not spread_over_cores()   # JAX has run: nothing changes
"""


def test_jacobian_split_over_devices_is_the_same(logged, tmp_path):
    """The tangents' seeds split over 3 CPU devices (a fresh process: ``spread_over_cores``, then 3 devices)
    give this process's Jacobian (its devices, 1 or more) to round-off; the devices can be set only before JAX
    runs."""
    import subprocess
    import sys

    from tensegrity_sim.methods.jax.fit import Observed, _Problem, parse_parameters
    from tensegrity_sim.ros.fit_log import read_observed

    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    subprocess.run([sys.executable, "-c", SPREAD, str(logged / "nominal.yaml"), str(logged / "run.mcap"),
                    str(tmp_path / "j.npy")], check=True, cwd=root, env={**os.environ, "PYTHONPATH": root})
    scene = ts.load_scene(logged / "nominal.yaml")
    _, obs = read_observed(logged / "run.mcap", scene)
    k = 23
    obs = Observed(obs.dt, obs.steps[:k], obs.positions[:k], obs.rest[:obs.steps[k - 1]],
                   obs.forces[:obs.steps[k - 1]])
    problem = _Problem(scene, obs, parse_parameters("stiffness,damping", scene), 8, 10.0)
    z = np.concatenate([problem.p0, problem.state0.ravel()]) * 1.001
    here, split = problem.jacobian(z).toarray(), np.load(tmp_path / "j.npy")
    np.testing.assert_allclose(split, here, rtol=1e-12, atol=1e-12 * np.abs(here).max())
    assert np.abs(here).max() > 1.0 and np.count_nonzero(here[:, :2]) > 100   # a Jacobian, not zeros


def test_fit_refuses_bad_input(logged, capsys, tmp_path):
    log = str(logged / "run.mcap")

    def refused(*args) -> str:
        assert main(["fit", log, *args]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1, err
        return err

    assert "unknown parameter 'inertia'" in refused("--params", "stiffness,inertia")
    assert "no cable 'nope'" in refused("--params", "damping:nope")
    assert "the scene has no ground" in refused("--params", "friction")
    assert "no node or strut 'nope'" in refused("--params", "mass:nope")
    assert "'mass:s0': it has no mass in the scene" in refused("--params", "mass:s0")
    assert "no speed limit" in refused("--params", "reel_speed")
    # a cable the log cannot see: c0 let out far beyond its span, slack at every pose
    d = ts.load_scene(logged / "nominal.yaml").to_dict()
    slack = tmp_path / "slack.yaml"
    (tmp_path / "long.yaml").write_text("- time: 0.0\n  rest_lengths: {c3: 3.0}\n")
    assert main(["run", str(logged / "truth.yaml"), "--method", "elastic", "--duration", "0.05", "--quiet",
                 "--commands", str(tmp_path / "long.yaml"), "--log", str(tmp_path / "long.mcap")]) == 0
    assert main(["fit", str(tmp_path / "long.mcap"), "--params", "stiffness:c3"]) == 2
    assert "cannot see it: cable c3 slack at every pose" in capsys.readouterr().err
    # a scene of other nodes
    other = tmp_path / "other.yaml"
    other.write_text(ts.load_scene("icosahedron").to_yaml())
    assert "its nodes and cables are not the log's" in refused("--params", "stiffness", "--scene", str(other))
    d["cables"][0]["nodes"] = d["cables"][0]["nodes"][::-1]
    slack.write_text(ts.Scene.from_dict(d).to_yaml())
    assert "not the log's" in refused("--params", "stiffness", "--scene", str(slack))
    assert "--loss" in refused("--params", "stiffness", "--loss", "l7")
    assert "prior must be >= 0" in refused("--params", "stiffness", "--prior", "-1")


def test_fit_refuses_a_log_without_poses_or_with_a_nan(logged, capsys, tmp_path):
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
    from add_pose_noise import rewrite_poses

    calls = []

    def nan_in_fifth(x):
        calls.append(1)
        return np.where(len(calls) == 5, np.nan, x)

    rewrite_poses(logged / "run.mcap", tmp_path / "nan.mcap", nan_in_fifth)
    assert main(["fit", str(tmp_path / "nan.mcap"), "--params", "stiffness"]) == 2
    err = capsys.readouterr().err
    assert "node_poses at t = 0.050000 s holds a non-finite position" in err and err.count("\n") == 1
    rewrite_poses(logged / "run.mcap", tmp_path / "none.mcap", lambda x: None)
    assert main(["fit", str(tmp_path / "none.mcap"), "--params", "stiffness"]) == 2
    assert "no node_poses in the log" in capsys.readouterr().err


def test_noise_script_and_python_api(logged, tmp_path):
    """1 mm of noise added by the script: the fit from Python estimates it (within 10 %) and recovers the
    stiffness within 3 %."""
    import subprocess
    import sys

    noisy = tmp_path / "noisy.mcap"
    subprocess.run([sys.executable, "scripts/add_pose_noise.py", str(logged / "run.mcap"), str(noisy), "--sigma",
                    "0.001"], check=True, capture_output=True, cwd=os.path.dirname(os.path.dirname(__file__)),
                   env={**os.environ, "PYTHONPATH": os.path.dirname(os.path.dirname(os.path.abspath(__file__)))})
    result = ts.fit(noisy, "stiffness", scene=logged / "nominal.yaml")
    assert abs(result.fitted[0] / STIFFNESS - 1) < 0.03
    assert abs(result.noise / 1e-3 - 1) < 0.1, result.noise


def test_rate_limited_rest_lengths_are_the_nodes(tmp_path):
    """A node run with max_rest_length_rate 0.2 m/s (the motors' reel speed), commanded: the rest lengths the
    fit replays at every step from the log's targets are the ones the node applied, to the last bit."""
    import jax.numpy as jnp

    from tensegrity_sim.cli import simulate
    from tensegrity_sim.commands import load_commands
    from tensegrity_sim.methods.jax.fit import _Problem, parse_parameters
    from tensegrity_sim.ros.fit_log import read_observed
    from tensegrity_sim.ros.log import LogRecorder
    from tensegrity_sim.ros.node_logic import NodeSettings, SimNodeLogic
    from tensegrity_sim.ros.offline import CommandDriver

    scene = ts.load_scene("prism3")
    (tmp_path / "commands.yaml").write_text(COMMANDS)
    sim = ts.Simulator(scene, method="elastic", dt=1e-3)
    settings = NodeSettings(scene="prism3", method="elastic", dt=1e-3, publish_rate=100.0,
                            log_path=str(tmp_path / "reel.mcap"), max_rest_length_rate=0.2)
    logic = SimNodeLogic(sim, settings)
    applied = []
    with LogRecorder(tmp_path / "reel.mcap", logic.channels(), logic.run_info()) as recorder:
        logic.recorder = recorder
        simulate(sim, 300, load_commands(tmp_path / "commands.yaml", scene), driver=CommandDriver(logic),
                 on_step=lambda r: applied.append(sim.rest_lengths.copy()))
    _, obs = read_observed(tmp_path / "reel.mcap")
    assert obs.reel_speed == 0.2
    unknowns = parse_parameters("reel_speed", scene, reel_speed=obs.reel_speed)
    problem = _Problem(scene, obs, unknowns, 5, 10.0)
    rest = np.asarray(problem.rest_of(jnp.ones(1), problem.data))          # (L, every, nc, W)
    replayed = np.moveaxis(rest, -1, 0).reshape(-1, len(scene.cables))      # step by step from the first pose
    first = int(obs.steps[0])
    logged = np.array(applied)[first:first + len(replayed)]
    assert np.ptp(logged[:, 0]) > 0.05    # c0 reeled in at 0.2 m/s: 0.058 m over the poses
    np.testing.assert_array_equal(replayed[:len(logged)], logged)


def test_fit_recovers_a_mass(logged, tmp_path):
    """Every mass 1.3x (prism3's node masses), fitted from the commanded log with the cables' values known."""
    d = ts.load_scene(logged / "truth.yaml").to_dict()
    for node in d["nodes"]:
        node["mass"] *= 1.3
    result = ts.fit(logged / "run.mcap", "mass", scene=ts.Scene.from_dict(d), window=10)
    assert abs(result.fitted[0] / result.start[0] * 1.3 - 1) < 1e-3, result.fitted
    np.testing.assert_allclose(result.scene.masses, ts.load_scene(logged / "truth.yaml").masses, rtol=1e-3)
