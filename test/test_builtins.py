"""Every built-in scene starts in static equilibrium: left alone it stays at rest."""
import numpy as np
import pytest

import tensegrity_sim as ts


@pytest.mark.parametrize("name", ts.builtin_scenes())
@pytest.mark.parametrize("method", ["elastic"])
def test_builtin_stays_at_rest(name, method):
    scene = ts.load_scene(name)
    sim = ts.Simulator(scene, method=method, dt=1e-3)
    x0 = sim.positions
    traj = sim.run(steps=1000)
    assert np.max(np.abs(traj.positions - x0)) < 1e-9
    # every cable of a built-in carries its prestress: none slack at rest
    assert not traj.slack.any()
    assert np.all(traj.tensions > 0)


def test_builtins_list():
    assert {"prism3", "icosahedron", "tower"} <= set(ts.builtin_scenes())
