"""Gradients of a JAX run (methods/jax/elastic.py, ``rollout``) against central finite differences of the same
run, to 1e-6 relative: with respect to cable stiffness, damping, masses, initial positions and velocities,
external forces and a command schedule's rest lengths (``jax.grad`` and ``jax.jacfwd``); away from slack/taut
switches (the icosahedron at its prestress, every cable taut) and through them (thrown, its cables snapping:
the derivative of the discrete run, module docstring); and exactly zero for a cable slack all along."""
import os
from functools import partial

import numpy as np
import pytest

import tensegrity_sim as ts
from bench.cases import icosahedron_thrown, rigid_consistent
from tensegrity_sim.commands import parse_commands
from tensegrity_sim.methods.rigid import RigidStruts
from tensegrity_sim.system import System

if os.environ.get("TENSEGRITY_SIM_REQUIRE_JAX") == "1":
    import jax
else:
    jax = pytest.importorskip("jax")

from tensegrity_sim.methods.jax import elastic as jel  # noqa: E402  (imports JAX)

import jax.numpy as jnp  # noqa: E402

DT, STEPS, EVERY = 1e-3, 100, 30   # K = 4 kept steps, the last padded: the masked steps are differentiated too


def _taut_scene(seed: int) -> ts.Scene:
    """The icosahedron at its prestress with gravity, damped cables and small velocities: every cable stays taut."""
    d = ts.load_scene("icosahedron").to_dict()
    rng = np.random.default_rng(seed)
    for node in d["nodes"]:
        node["velocity"] = [float(c) for c in rng.normal(scale=0.05, size=3)]
    for c in d["cables"]:
        c["damping"] = 2.0
    d["gravity"] = [0.0, 0.0, -9.81]
    return rigid_consistent(d)


def _objective(model, x0, v0, inputs, weights, scheduled):
    """The scalar whose gradients the tests take (the last kept step's positions and velocities weighted, and the
    second kept step's positions squared) and the run's :class:`Outputs`."""
    out = jel.rollout(model, x0, v0, inputs, DT, STEPS, EVERY, scheduled=scheduled)
    return jnp.sum(weights[0] * out.x[-1]) + jnp.sum(weights[1] * out.v[-1]) + jnp.sum(out.x[1] ** 2), out


# One compile for every test of the same shapes (the scenes below are all the icosahedron in 2 copies): the
# weights are an argument, not a constant of a closure compiled per test; and the central differences take their
# values from the same compiled function as the gradient (its primal: the run itself), not from a second compile.
@partial(jax.jit, static_argnames="scheduled")
def _value_and_gradients(model, x0, v0, inputs, weights, scheduled):
    """((objective, the run's Outputs), d objective / d (model, x0, v0, inputs)), the gradient by ``jax.grad``."""
    return jax.value_and_grad(lambda *a: _objective(*a, weights, scheduled), argnums=(0, 1, 2, 3),
                              has_aux=True)(model, x0, v0, inputs)


def _problem(scenes, schedule=None):
    """The model, initial state and inputs of ``scenes`` (a batch), the objective as a plain function of them
    (for ``jax.jacfwd``) and :func:`_value_and_gradients` at them (each argument defaulting to the problem's)."""
    system = System(scenes[0])
    model = jel.model_arrays(system, RigidStruts(system))
    x0 = jnp.asarray(np.stack([s.positions for s in scenes], axis=-1))    # (N, 3, B): the batch last
    v0 = jnp.asarray(np.stack([s.velocities for s in scenes], axis=-1))
    rest = np.stack([s.cable_rest_lengths for s in scenes], axis=-1)
    ext = np.zeros(x0.shape)
    inputs = jel.held_inputs(rest, ext) if schedule is None else jel.schedule_inputs(schedule, rest, ext)
    weights = jnp.asarray(np.random.default_rng(7).normal(size=(2,) + x0.shape))
    scheduled = schedule is not None

    def objective(model=model):
        return _objective(model, x0, v0, inputs, weights, scheduled)[0]

    def loss(model=model, x0=x0, v0=v0, inputs=inputs):
        return _value_and_gradients(model, x0, v0, inputs, weights, scheduled=scheduled)

    return model, x0, v0, inputs, objective, loss


def _central(f, p, directions, eps):
    """Central differences of scalar ``f`` at ``p`` along each of ``directions`` (k, *p.shape)."""
    return np.array([(f(p + eps * d) - f(p - eps * d)) / (2 * eps) for d in directions])


def _check(grad, f, p, eps, what, n=4):
    """The gradient's projection on ``n`` random directions against central differences, 1e-6 relative."""
    rng = np.random.default_rng(3)
    directions = rng.normal(size=(n,) + np.shape(p))
    fd = _central(f, np.asarray(p), directions, eps)
    ad = np.tensordot(directions, np.asarray(grad), axes=np.ndim(p))
    np.testing.assert_allclose(ad, fd, rtol=1e-6, atol=1e-9 * np.max(np.abs(fd)), err_msg=what)
    assert np.max(np.abs(ad)) > 0, what


@pytest.mark.parametrize("regime", ["taut", "switching"])
def test_gradients_equal_central_differences(regime):
    if regime == "taut":
        scenes = [_taut_scene(s) for s in range(2)]
    else:
        scenes = [icosahedron_thrown(scale=3.0, seed=s) for s in range(2)]
    model, x0, v0, inputs, objective, loss = _problem(scenes)
    (_, out), (grad_model, grad_x0, grad_v0, grad_inputs) = loss()
    slack = np.asarray(out.slack)
    if regime == "taut":
        assert not slack.any() and not np.asarray(out.snaps).any()
    else:   # cables that are taut at one kept step and slack at another
        assert np.sum(slack.any(axis=0) & (~slack).any(axis=0)) >= 2   # (cable, copy) pairs
    value = lambda **kw: float(loss(**kw)[0][0])   # noqa: E731
    ns = len(scenes[0].struts)
    k_cables = model.stiffness[ns:]
    _check(grad_model.stiffness[ns:], lambda k: value(model=model._replace(stiffness=model.stiffness.at[ns:].set(k))),
           k_cables, 1e-4 * float(k_cables[0]), "stiffness")
    _check(grad_model.masses, lambda m: value(model=model._replace(masses=m)), model.masses, 1e-6, "masses")
    _check(grad_x0, lambda x: value(x0=x), x0, 1e-7, "initial positions")
    _check(grad_v0, lambda v: value(v0=v), v0, 1e-6, "initial velocities")
    _check(grad_inputs.ext, lambda f: value(inputs=inputs._replace(ext=f)), inputs.ext, 1e-5, "external forces")
    _check(grad_inputs.rest, lambda r: value(inputs=inputs._replace(rest=r)), inputs.rest, 1e-7, "rest lengths")
    if regime == "taut":   # forward mode too, and the damping (the thrown icosahedron has none)
        jac = jax.jacfwd(lambda c: objective(model=model._replace(damping=c)))(model.damping)
        _check(jac, lambda c: value(model=model._replace(damping=c)), model.damping, 1e-5, "damping")


def test_gradient_of_a_schedules_rest_lengths():
    scenes = [_taut_scene(s) for s in range(2)]
    c = scenes[0].cable_names
    r0 = scenes[0].cables[0].rest_length
    schedule = parse_commands([{"time": 0.0, "rest_lengths": {c[0]: r0}},
                               {"time": 0.05, "rest_lengths": {c[0]: 0.99 * r0, c[3]: scenes[0].cables[3].rest_length}},
                               {"time": 0.08, "rest_lengths": {c[3]: 0.995 * scenes[0].cables[3].rest_length}}],
                              scenes[0])
    model, x0, v0, inputs, _, loss = _problem(scenes, schedule)
    (_, out), grads = loss()
    assert not np.asarray(out.slack).any()
    _check(grads[3].rest_values, lambda values: float(loss(inputs=inputs._replace(rest_values=values))[0][0]),
           inputs.rest_values, 1e-7, "schedule rest lengths")


def test_a_cable_slack_all_along_has_no_gradient():
    """At the kink's slack side the tension law k max(0, e) is flat: a cable slack throughout the run exerts no
    force, so the derivative with respect to its stiffness and damping is exactly zero (and the others' is not)."""
    d = _taut_scene(0).to_dict()
    d["cables"][5]["rest_length"] *= 1.5   # far from taut for the whole run
    scenes = [ts.Scene.from_dict(d)] * 2
    model, x0, v0, inputs, _, loss = _problem(scenes)
    (_, out), (g, *_) = loss()
    assert np.asarray(out.slack)[:, 5].all()
    ns = len(scenes[0].struts)
    assert float(g.stiffness[ns + 5]) == 0.0 and float(g.damping[5]) == 0.0
    assert np.all(np.asarray(g.stiffness[ns:ns + 5]) != 0.0)
