"""Every built-in scene starts in static equilibrium: left alone it stays at rest, with either method."""
import warnings

import numpy as np
import pytest

import tensegrity_sim as ts
from tensegrity_sim.methods.inextensible.method import LengthOffsetWarning


@pytest.mark.parametrize("name", ts.builtin_scenes())
@pytest.mark.parametrize("method", ["elastic", "inextensible"])
def test_builtin_stays_at_rest(name, method):
    scene = ts.load_scene(name)
    with warnings.catch_warnings():
        # the inextensible method turns the cables' prestress stretch into length offsets, and says so
        warnings.simplefilter("ignore", LengthOffsetWarning)
        sim = ts.Simulator(scene, method=method, dt=1e-3)
    x0 = sim.positions
    traj = sim.run(steps=1000)
    assert np.max(np.abs(traj.positions - x0)) < 1e-9
    # every cable of a built-in carries its prestress: none slack at rest
    assert not traj.slack.any()
    if method == "elastic":
        assert np.all(traj.tensions > 0)
        return
    # Inextensible cables: the tensions balance the loads at every free node. Where rigid struts
    # share the load they are not reported, and a structure locked by a self-stress of its cables and
    # rigid struts has no unique tensions (at rest with no load the QP returns zero).
    assert np.all(traj.tensions >= 0)
    if not sim.system.rigid.any():
        sys = sim.system
        _, length, n = sys.geometry(x0)
        strut_t = sys.stiffness[: sys.n_struts] * (length[: sys.n_struts] - sys.strut_rest)
        tension = np.concatenate([strut_t, traj.tensions[-1]])
        force = sys.gravity_force + sys.assemble(tension[:, None] * n)
        assert np.max(np.abs(force[sys.free])) < 1e-9 * np.max(np.abs(tension))


def test_builtins_list():
    assert {"prism3", "icosahedron", "tower"} <= set(ts.builtin_scenes())
