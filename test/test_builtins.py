"""Every built-in scene starts in static equilibrium: left alone it stays at rest, with either method; the
built-in robots roll under their schedules."""
import warnings

import numpy as np
import pytest

import tensegrity_sim as ts
from tensegrity_sim.methods.inextensible.method import LengthOffsetWarning
from tensegrity_sim.scene import LumpedMassWarning


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


@pytest.mark.parametrize("name, duration, distance", [("superball", 12.0, 2.5), ("three_bar", 4.0, 0.3)])
def test_builtin_robots_roll_under_their_schedules(name, duration, distance):
    """tensegrity_sim/schedules/NAME_roll.yaml rolls the robot: its centre of mass moves ``distance`` m or more
    over the ground (measured, the rods with their consistent mass: superball 2.96 m in 12 s, three rolls; three_bar
    0.32 m in 4 s, tipped over an edge onto its side) and stays on the ground; once the schedule has ended, its
    energy only falls (the cables' damping and the ground's friction; no input). Whether a cable is slack at the
    end is no law: superball still bounces on its cables at 12 s, one of them slackening and tautening with it."""
    from importlib import resources

    from tensegrity_sim.commands import load_commands
    scene = ts.load_scene(name)
    with warnings.catch_warnings():
        warnings.simplefilter("error", LumpedMassWarning)   # the rods keep their blocks on the ground
        sim = ts.Simulator(scene, method="elastic", dt=1e-3)
    with resources.as_file(resources.files("tensegrity_sim.schedules") / f"{name}_roll.yaml") as path:
        commands = load_commands(path, scene)
    mass = scene.masses[:, None]
    start = (mass * sim.positions).sum(axis=0) / mass.sum()
    end = max(float(times[-1]) for times in commands.rest_times)
    driven = sim.run(duration=end, commands=commands)
    after_schedule = sim.energy()["total"]
    coasting = sim.run(duration=duration - end)
    moved = (mass * sim.positions).sum(axis=0) / mass.sum() - start
    assert np.linalg.norm(moved[:2]) > distance
    assert min(driven.positions[:, :, 2].min(), coasting.positions[:, :, 2].min()) > scene.ground.height
    assert sim.energy()["total"] < after_schedule
