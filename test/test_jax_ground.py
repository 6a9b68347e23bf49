"""The ground in JAX (methods/jax/ground.py) against the numpy reference (``Simulator(scene, method="elastic")``
with a ground: friction.py's mode fixed point, tolerance 1e-10 relative) and on test_ground.py's closed forms:
a strut sliding to a stop at ``v0^2 / (2 mu g)``, held on a slope below the friction angle, sliding down a steeper
one at ``g (sin - mu cos)``, a point mass bouncing to ``e^2 h``, the icosahedron resting on the ground."""
import os
import warnings
from functools import lru_cache

import numpy as np
import pytest

import tensegrity_sim as ts
from bench.cases import rigid_consistent
from tensegrity_sim.batch import BatchSimulator
from tensegrity_sim.scene import LumpedMassWarning
from test_ground import G, MU, strut

if os.environ.get("TENSEGRITY_SIM_REQUIRE_JAX") == "1":
    import jax  # noqa: F401
else:
    pytest.importorskip("jax")


def _jax_run(scene, steps, dt=1e-3, batch=1, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ts.LengthOffsetWarning)
        sim = BatchSimulator(scene, batch, method="elastic", dt=dt, backend="jax", **kw)
    return sim.run(steps=steps)


def _thrown_onto_the_ground(seed: int) -> ts.Scene:
    """icosahedron_ground lifted 0.3 m and thrown (1 m/s per node): it lands, rolls and its cables go slack."""
    d = ts.load_scene("icosahedron_ground").to_dict()
    rng = np.random.default_rng(seed)
    for node in d["nodes"]:
        node["velocity"] = [float(c) for c in rng.normal(scale=1.0, size=3)]
        node["position"][2] += 0.3
    return rigid_consistent(d)


@lru_cache(maxsize=None)
def _reference(seed: int) -> ts.Trajectory:
    """The numpy reference's 600 steps of ``_thrown_onto_the_ground(seed)``, every step kept (computed once: two
    tests compare with seed 1's)."""
    return ts.Simulator(_thrown_onto_the_ground(seed), method="elastic", dt=1e-3).run(steps=600)


def test_landing_and_rolling_equal_the_numpy_reference():
    scenes = [_thrown_onto_the_ground(s) for s in range(2)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ts.LengthOffsetWarning)
        batch = BatchSimulator.from_scenes(scenes, method="elastic", dt=1e-3, backend="jax")
    traj = batch.run(steps=600)
    assert np.all(traj.positions[:, :, :, 2].min(axis=(1, 2)) < 0.03)   # both landed (node radius 0.025 m)
    for b in range(len(scenes)):
        ref = _reference(b)
        assert len(ref.contacts) > 0 and ref.slack.any()
        np.testing.assert_allclose(traj.positions[b], ref.positions, rtol=0, atol=1e-9)
        np.testing.assert_allclose(traj.velocities[b], ref.velocities, rtol=0, atol=1e-8)
        np.testing.assert_allclose(traj.impulses[b], ref.impulses, rtol=0, atol=1e-10)


def test_icosahedron_rests_in_static_equilibrium():
    scene = ts.load_scene("icosahedron_ground")
    traj = _jax_run(scene, 300)
    assert np.abs(traj.positions[0] - scene.positions).max() < 1e-12


def test_sliding_strut_stops_at_the_closed_form():
    v0 = 2.0
    traj = _jax_run(strut(v0), 600)
    t_stop, d_stop = v0 / (MU * G), v0 ** 2 / (2 * MU * G)
    vx = traj.velocities[0, :, 0, 0]
    stopped = np.flatnonzero(vx == 0.0)
    assert stopped.size and abs(traj.time[stopped[0]] - t_stop) <= 0.01 * t_stop
    assert np.abs(traj.velocities[0, stopped[0]:]).max() <= 1e-15   # at rest from then on, to round-off
    assert abs(traj.positions[0, -1, 0, 0] - d_stop) <= 0.01 * d_stop
    assert np.abs(traj.positions[0, :, :, 2] - 0.01).max() <= 1e-4


def test_no_creep_below_the_friction_angle_and_the_closed_form_above():
    held = _jax_run(strut(theta=np.arctan(0.9 * MU)), 1000)
    assert np.abs(held.positions[0] - held.positions[0, 0]).max() < 1e-6
    theta = np.arctan(1.2 * MU)
    slide = _jax_run(strut(theta=theta), 500)
    v = slide.velocities[0, :, 0, 0]
    accel = (v[-1] - v[99]) / (slide.time[-1] - slide.time[99])
    expected = G * (np.sin(theta) - MU * np.cos(theta))
    assert abs(accel - expected) <= 0.01 * expected
    assert np.abs(slide.positions[0, :, :, 2] - 0.01).max() <= 1e-4


@pytest.mark.parametrize("e", [0.0, 0.5])
def test_point_mass_bounces_to_e_squared_h(e):
    scene = ts.Scene.from_dict({"gravity": [0, 0, -G], "ground": {"friction": 0.5, "restitution": e},
                                "nodes": [{"name": "p", "position": [0, 0, 1.0], "mass": 1.0}]})
    traj = _jax_run(scene, 1000)
    z = traj.positions[0, :, 0, 2]
    after = traj.time > np.sqrt(2.0 / G) + 2e-3
    assert z.min() >= -1e-12
    assert abs(z[after].max() - e * e) <= 1e-3


def test_rolling_under_a_schedule_equals_the_numpy_reference():
    """examples/roll.yaml's rest-length ramps on icosahedron_ground, evaluated inside the JAX run, against the
    numba batch with the same schedule evaluated inside its compiled ground loop (``test_ground.py`` holds that
    loop to a Simulator commanded step by step, and to the numpy reference)."""
    from pathlib import Path

    from tensegrity_sim.commands import load_commands

    scene = ts.load_scene("icosahedron_ground")
    schedule = load_commands(Path(__file__).resolve().parents[1] / "examples" / "roll.yaml", scene)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ts.LengthOffsetWarning)
        ref = BatchSimulator(scene, 1, method="elastic", dt=1e-3).run(steps=800, every=10, commands=schedule)
        sim = BatchSimulator(scene, 1, method="elastic", dt=1e-3, backend="jax")
    traj = sim.run(steps=800, every=10, commands=schedule)
    assert np.abs(ref.positions[0, -1] - scene.positions).max() > 0.05   # it moved: reeled in, tipping
    np.testing.assert_allclose(traj.positions, ref.positions, rtol=0, atol=1e-9)
    # the reference's contact solve holds to 1e-10 relative per step: cable impulses of ~1 N*s over 10 steps
    np.testing.assert_allclose(traj.impulses, ref.impulses, rtol=0, atol=1e-9)
    # the rest lengths in effect: the schedule's at the last step's start
    np.testing.assert_allclose(sim.rest_lengths[0], schedule.rest_lengths_at(0.799, scene.cable_rest_lengths),
                               rtol=0, atol=1e-14)


def _reeling(scene: ts.Scene):
    """Three of ``scene``'s cables reeled to 60 % over 0.4 s and held: its rods land, tip and slide."""
    from tensegrity_sim.commands import parse_commands

    rest = dict(zip(scene.cable_names, scene.cable_rest_lengths))
    points = [{"time": t, "rest_lengths": {c: float(f * rest[c]) for c in scene.cable_names[:3]}}
              for t, f in ((0.0, 1.0), (0.4, 0.6))]
    return parse_commands(points, scene, "reel")


@lru_cache(maxsize=None)
def _reeling_runs(name: str):
    """``name`` reeling (``_reeling``) on the ground for 600 steps, kept every 10: the scene, the JAX batch of one
    and its trajectory, and the numba batch's (computed once: two tests compare with three_bar's)."""
    scene = ts.load_scene(name)
    schedule = _reeling(scene)
    with warnings.catch_warnings():
        warnings.simplefilter("error", LumpedMassWarning)
        ref = BatchSimulator(scene, 1, method="elastic", dt=1e-3).run(steps=600, every=10, commands=schedule)
        sim = BatchSimulator(scene, 1, method="elastic", dt=1e-3, backend="jax")
    return scene, sim, sim.run(steps=600, every=10, commands=schedule), ref


@pytest.mark.parametrize("name", ["three_bar", "superball"])
def test_rods_on_the_ground_take_their_blocks_as_the_numba_batch_does(name):
    """The built-in robots whose rods carry their mass along them (three_bar: a motor at each rod's middle, end
    caps; superball: uniform rods, end caps) reeling three cables on the ground: the JAX ground's block Gauss-Seidel
    with the rods' 2x2 mass blocks (``M^-1``'s diagonal and cross entries; ``ground.block_sweeps`` sweeps) against
    the numba batch's block Newton, to the tolerance of the icosahedron's comparison above. Measured: 7e-15 m and
    5e-13 m/s over 1,000 steps of each (at 60 sweeps, three_bar's block converging at rate 0.79: 6e-9 m)."""
    scene, sim, traj, ref = _reeling_runs(name)
    assert sim.system.mass.consistent
    assert np.abs(ref.positions[0, -1] - scene.positions).max() > 0.05   # it moved
    np.testing.assert_allclose(traj.positions, ref.positions, rtol=0, atol=1e-9)
    np.testing.assert_allclose(traj.velocities, ref.velocities, rtol=0, atol=1e-8)
    np.testing.assert_allclose(traj.impulses, ref.impulses, rtol=0, atol=1e-9)


def test_gradients_through_rods_on_the_ground_equal_central_differences():
    """``jax.grad`` of a run of three_bar reeling on the ground (its rods' blocks in the contact solve) with respect
    to the lumped masses, the blocks' cross entries and the cable stiffness: finite, and equal to central
    differences of the same run to 1e-6 relative (the contacts keep their modes: the run is smooth in them)."""
    import jax
    import jax.numpy as jnp

    from tensegrity_sim.methods.jax import elastic as jel
    from tensegrity_sim.methods.rigid import RigidStruts
    from tensegrity_sim.system import System
    from test_jax_grad import _check

    scene = ts.load_scene("three_bar")
    system = System(scene)
    model = jel.model_arrays(system, RigidStruts(system))
    assert np.any(np.asarray(model.mass_block) > 0)
    x0, v0 = jnp.asarray(scene.positions[..., None]), jnp.asarray(scene.velocities[..., None])
    inputs = jel.schedule_inputs(_reeling(scene), scene.cable_rest_lengths[:, None], np.zeros(x0.shape))
    weights = jnp.asarray(np.random.default_rng(5).normal(size=(2,) + x0.shape))

    @jax.jit
    def loss(model):
        out = jel.rollout(model, x0, v0, inputs, 1e-3, 80, 40, scheduled=True)
        return jnp.sum(weights[0] * out.x[-1]) + jnp.sum(weights[1] * out.v[-1])

    grad = jax.grad(loss)(model)
    value = lambda m: float(loss(m))   # noqa: E731
    for field, eps in (("masses", 1e-6), ("mass_block", 1e-6), ("stiffness", 1e-2)):
        g = getattr(grad, field)
        assert np.all(np.isfinite(np.asarray(g))), field
        _check(g, lambda p, f=field: value(model._replace(**{f: p})), getattr(model, field), eps, field)


def test_sweeps_stopping_at_a_tolerance_equal_the_reference_and_the_fixed_counts_tangents():
    """The ground's tolerance mode (``fit``'s: warm-started sweeps on the problem with each strut's length row
    eliminated, stopping at ``TOLERANCE``) on the icosahedron thrown onto the ground (landing, rolling, cables
    going slack): positions as the numpy reference's, and the forward-mode tangent of the run with respect to every
    cable's stiffness as the fixed count's (whose sweeps converge to round-off)."""
    import jax
    import jax.numpy as jnp

    from tensegrity_sim.methods.jax import elastic as jel
    from tensegrity_sim.methods.jax.ground import TOLERANCE
    from tensegrity_sim.methods.rigid import RigidStruts
    from tensegrity_sim.system import System

    scene = _thrown_onto_the_ground(1)
    system = System(scene)
    fixed = jel.model_arrays(system, RigidStruts(system))
    stopping = fixed._replace(ground=fixed.ground._replace(tolerance=TOLERANCE))
    x0, v0 = jnp.asarray(scene.positions[..., None]), jnp.asarray(scene.velocities[..., None])
    inputs = jel.held_inputs(scene.cable_rest_lengths[:, None], jnp.zeros_like(x0))

    def run(model, factor):
        scaled = model._replace(stiffness=model.stiffness * factor)
        return jel.rollout(scaled, x0, v0, inputs, 1e-3, 600, every=10).x[..., 0]

    ref = _reference(1)
    assert len(ref.contacts) > 0 and ref.slack.any()
    x_stop, dx_stop = jax.jvp(lambda k: run(stopping, k), (1.0,), (1.0,))
    x_fixed, dx_fixed = jax.jvp(lambda k: run(fixed, k), (1.0,), (1.0,))
    kept = np.rint(ref.time / 1e-3).astype(int) % 10 == 0   # the rollout keeps steps 10, 20, ..., 600
    np.testing.assert_allclose(np.asarray(x_stop), ref.positions[kept], rtol=0, atol=1e-9)
    np.testing.assert_allclose(np.asarray(x_stop), np.asarray(x_fixed), rtol=0, atol=1e-10)
    scale = np.abs(np.asarray(dx_fixed)).max()
    assert scale > 1e-3   # the stiffness moves the run
    np.testing.assert_allclose(np.asarray(dx_stop), np.asarray(dx_fixed), rtol=0, atol=1e-7 * scale)


def test_sweeps_stopping_at_a_tolerance_take_the_rods_blocks():
    """The tolerance mode on a scene whose rods carry their 2x2 mass blocks (three_bar reeling three cables on the
    ground: its rods land, tip and slide) takes the plain block sweeps, warm-started and stopping at ``TOLERANCE``:
    the same run as the fixed count's (``block_sweeps``; the JAX batch's run of the test above), to round-off, and
    so the numba batch's."""
    import jax.numpy as jnp

    from tensegrity_sim.methods.jax import elastic as jel
    from tensegrity_sim.methods.jax.ground import TOLERANCE
    from tensegrity_sim.methods.rigid import RigidStruts
    from tensegrity_sim.system import System

    scene, _, traj, _ = _reeling_runs("three_bar")   # the fixed count's run: the JAX batch's
    system = System(scene)
    fixed = jel.model_arrays(system, RigidStruts(system))
    assert np.any(np.asarray(fixed.mass_block) > 0) and fixed.ground.tolerance == 0   # the batch's model: a fixed count
    stopping = fixed._replace(ground=fixed.ground._replace(tolerance=TOLERANCE))
    x0, v0 = jnp.asarray(scene.positions[..., None]), jnp.asarray(scene.velocities[..., None])
    inputs = jel.schedule_inputs(_reeling(scene), scene.cable_rest_lengths[:, None], np.zeros(x0.shape))
    run = np.asarray(jel.rollout(stopping, x0, v0, inputs, 1e-3, 600, 10, scheduled=True).x[..., 0])
    assert np.abs(traj.positions[0, -1] - scene.positions).max() > 0.05   # it moved
    np.testing.assert_allclose(run, traj.positions[0], rtol=0, atol=1e-10)   # steps 10, 20, ..., 600 of both
