"""The same tensegrity in MuJoCo, the simulator users would otherwise pick (benchmark-only dependency).

Modelling (one MJCF body per rigid strut or per free point mass; nothing else):

* A **rigid strut** is a body with a free joint, its origin at the centre of mass of its two end nodes
  (masses from the scene, strut mass lumped as in the simulator), with one site at each end. Its
  inertia is that of the two point masses, ``sum m (|r|^2 E - r r^T)``, which is zero about the strut's
  axis; MuJoCo needs positive inertia, so ``axial_inertia`` (relative to the transverse inertia, default
  1e-6) is added about the axis. No tendon attaches off the axis, so the exact motion has no axial
  torque and the axial spin stays zero whatever that inertia: its only effect is through round-off, and
  :func:`axial_inertia_effect` measures it.
* Any other free node is a body with three slide joints (a point mass: no rotational freedom).
* A fixed node is a site on the world body.
* An **elastic strut** is a spatial tendon between its end sites with ``stiffness = k`` and
  ``springlength = L`` (a two-sided spring: pushes when shorter, pulls when longer).
* An **elastic cable** is a spatial tendon with ``stiffness = k`` and ``springlength = "0 L"``: MuJoCo's
  dead band, no force for lengths in ``[0, L]`` and ``k (l - L)`` beyond, i.e. ``k max(0, l - L)``.
* An **inextensible cable** is a limited spatial tendon, ``range = "0 L_max"`` with ``L_max`` the rest
  length plus the stretch the cable has at load time (as the simulator's inextensible method takes it,
  physics.md §3). MuJoCo's limits are soft constraints: ``solreflimit = "2*dt zeta"``, a time constant of
  twice the step (the stiffest MuJoCo allows: it clamps smaller ones), default ``solimplimit``. With the
  default damping ratio ``zeta = 1`` a snap rebounds with a restitution of about 0.1 at every step
  size (the constraint's dynamics scale with ``dt``, so it does not converge to the inelastic snap);
  ``zeta = 30`` brings the snap-pair's impulse error down to 2e-4 N*s of 1.5 (measured), so the
  benchmarks run both.
* Gravity from the scene, no damping anywhere, no actuators. Contacts are disabled, unless the scene has
  a ``ground``: then it is a plane with the scene's friction, each rigid strut carries a capsule of its
  radius (massless: the body's inertia stays the point masses') and each point mass a sphere of its
  node's radius; only these touch the plane (not each other), with elliptic friction cones and
  ``impratio`` (default 100, MuJoCo's advice for little slip).
  With ``strut_contacts=True`` (and no ground) each rigid strut carries its capsule and the capsules
  collide with each other (frictionless): what this simulator's default strut-strut detection checks,
  for a like-for-like cost of contact detection (MuJoCo also responds to a contact; this simulator,
  by default, only reports it).

Cable damping is refused (MuJoCo's tendon damping acts also while slack). A node carrying two rigid
struts, or a rigid strut with a fixed end, is refused (the bench scenes need neither).
"""
from __future__ import annotations

import numpy as np

import tensegrity_sim as ts
from tensegrity_sim.system import System

from .reference import Final

__all__ = ["INTEGRATORS", "MujocoPeer", "axial_inertia_effect"]

INTEGRATORS = ("Euler", "implicitfast", "RK4")
_CHUNK = 20_000     # steps per rollout call in run_measured (bounds the memory of the recorded states)


def _fmt(values) -> str:
    return " ".join(repr(float(v)) for v in np.ravel(values))


class MujocoPeer:
    """A scene as a MuJoCo model and data, with the state read and written in node terms.

    ``model``: "elastic" or "inextensible" (cable model); ``dt``: s; ``integrator``: one of
    :data:`INTEGRATORS`; ``axial_inertia``: a rigid strut's inertia about its axis, relative to its
    transverse inertia; ``limit_dampratio``: damping ratio of the inextensible cables' soft limits.
    """

    def __init__(self, scene: ts.Scene, *, model: str = "elastic", dt: float = 1e-3, integrator: str = "RK4",
                 axial_inertia: float = 1e-6, limit_dampratio: float = 1.0, impratio: float = 100.0,
                 strut_contacts: bool = False):
        import mujoco

        if model not in ("elastic", "inextensible"):
            raise ValueError(f"model must be 'elastic' or 'inextensible', got {model!r}")
        if integrator not in INTEGRATORS:
            raise ValueError(f"integrator must be one of {INTEGRATORS}, got {integrator!r}")
        self._mj = mujoco
        self.scene, self.system, self.cable_model, self.dt = scene, System(scene), model, float(dt)
        self.integrator = integrator
        self.impratio = float(impratio)
        self.strut_contacts = bool(strut_contacts)
        self.xml = self._mjcf(integrator, axial_inertia, limit_dampratio)
        self.model = mujoco.MjModel.from_xml_string(self.xml)
        self.data = mujoco.MjData(self.model)
        self._sites = np.array([self.model.site(f"node_{n}").id for n in scene.node_names])
        self._tendons = np.array([self.model.tendon(f"cable_{c}").id for c in scene.cable_names])
        self._cable_k = self.system.stiffness[self.system.n_struts:]
        self.reset()

    # ------------------------------------------------------------------------------- building
    def _mjcf(self, integrator: str, axial_inertia: float, limit_dampratio: float) -> str:
        scene, sys = self.scene, self.system
        if np.any(sys.cable_damping > 0):
            raise ValueError("MujocoPeer: cable damping is not modelled (MuJoCo's tendon damping acts also when slack)")
        x, masses, names = scene.positions, sys.masses, scene.node_names
        rigid_of = {}
        for i in np.flatnonzero(sys.rigid):
            a, b = sys.strut_ends[i]
            if not (sys.free[a] and sys.free[b]):
                raise ValueError(f"MujocoPeer: rigid strut {scene.strut_names[i]!r} has a fixed end (not modelled)")
            for p in (a, b):
                if p in rigid_of:
                    raise ValueError(f"MujocoPeer: node {names[p]!r} carries two rigid struts (not modelled)")
                rigid_of[p] = i
        world, bodies = [], []
        ground = scene.ground
        radii = scene.node_radii
        # what touches the ground: contype 1 against the plane's conaffinity 1, never each other
        # (MuJoCo combines two geoms' friction by the larger: the moving geoms carry the ground's too)
        touch = (f' contype="1" conaffinity="0" condim="3" friction="{ground.friction!r} 0 0"'
                 if ground is not None else "")
        # strut_contacts: the rigid struts' capsules also collide with each other (bit 2, frictionless), as
        # this simulator's default strut-strut detection checks them
        capsule = touch
        if self.strut_contacts:
            friction = ground.friction if ground is not None else 0.0
            capsule = (f' contype="{3 if ground is not None else 2}" conaffinity="2" condim="{3 if ground else 1}"'
                       f' friction="{friction!r} 0 0"')
        if ground is not None:
            world.append(f'<geom type="plane" size="0 0 1" pos="0 0 {ground.height!r}" contype="0" conaffinity="1" '
                         f'friction="{ground.friction!r} 0 0" condim="3"/>')
        for p in np.flatnonzero(~sys.free):
            world.append(f'<site name="node_{names[p]}" pos="{_fmt(x[p])}"/>')
        for p in np.flatnonzero(sys.free):
            if p in rigid_of:
                continue
            bodies.append(
                f'<body name="point_{names[p]}" pos="{_fmt(x[p])}">'
                + "".join(f'<joint type="slide" axis="{ax}"/>' for ax in ("1 0 0", "0 1 0", "0 0 1"))
                # no rotational freedom: this inertia never enters the dynamics, MuJoCo only needs it > 0
                + f'<inertial pos="0 0 0" mass="{float(masses[p])!r}" diaginertia="1e-9 1e-9 1e-9"/>'
                + (f'<geom type="sphere" size="{max(float(radii[p]), 1e-6)!r}" mass="0"{touch}/>' if touch else "")
                + f'<site name="node_{names[p]}"/></body>')
        for i in sorted(set(rigid_of.values())):
            a, b = sys.strut_ends[i]
            com = (masses[a] * x[a] + masses[b] * x[b]) / (masses[a] + masses[b])
            r = np.array([x[a] - com, x[b] - com])
            m2 = np.array([masses[a], masses[b]])
            inertia = sum(m * (r_ @ r_ * np.eye(3) - np.outer(r_, r_)) for m, r_ in zip(m2, r))
            axis = (x[b] - x[a]) / np.linalg.norm(x[b] - x[a])
            inertia += axial_inertia * float(m2 @ np.einsum("ij,ij->i", r, r)) * np.outer(axis, axis)
            full = [inertia[0, 0], inertia[1, 1], inertia[2, 2], inertia[0, 1], inertia[0, 2], inertia[1, 2]]
            bodies.append(
                f'<body name="strut_{scene.strut_names[i]}" pos="{_fmt(com)}"><freejoint/>'
                f'<inertial pos="0 0 0" mass="{float(m2.sum())!r}" fullinertia="{_fmt(full)}"/>'
                f'<site name="node_{names[a]}" pos="{_fmt(r[0])}"/><site name="node_{names[b]}" pos="{_fmt(r[1])}"/>'
                + (f'<geom type="capsule" fromto="{_fmt(np.concatenate([r[0], r[1]]))}" '
                   f'size="{max(float(scene.struts[i].radius), 1e-6)!r}" mass="0"{capsule}/>' if capsule else "")
                + "</body>")
        tendons, sensors = [], []
        moving = sys.free[sys.ends].any(axis=1)
        for i in np.flatnonzero(~sys.rigid & moving[: sys.n_struts]):
            a, b = sys.strut_ends[i]
            tendons.append(f'<spatial name="strut_{scene.strut_names[i]}" stiffness="{float(sys.stiffness[i])!r}" '
                           f'springlength="{float(sys.strut_rest[i])!r}"><site site="node_{names[a]}"/>'
                           f'<site site="node_{names[b]}"/></spatial>')
        _, length0, _ = sys.geometry(x, sys.cable_ends)
        for c, cable in enumerate(scene.cables):
            a, b = sys.cable_ends[c]
            if self.cable_model == "elastic":
                law = f'stiffness="{cable.stiffness!r}" springlength="0 {cable.rest_length!r}"'
            else:
                limit = max(cable.rest_length, float(length0[c]))
                law = f'limited="true" range="0 {limit!r}" solreflimit="{2 * self.dt!r} {float(limit_dampratio)!r}"'
            tendons.append(f'<spatial name="cable_{cable.name}" {law}><site site="node_{names[a]}"/>'
                           f'<site site="node_{names[b]}"/></spatial>')
            # what run_measured integrates into the cable's impulse; switched off while timing
            kind = "tendonpos" if self.cable_model == "elastic" else "tendonlimitfrc"
            sensors.append(f'<{kind} tendon="cable_{cable.name}"/>')
        return (
            f'<mujoco model="{scene.name}"><compiler angle="radian"/>'
            f'<option timestep="{self.dt!r}" integrator="{integrator}" gravity="{_fmt(scene.gravity)}"'
            + (f' cone="elliptic" impratio="{self.impratio!r}"></option>' if ground is not None
               else '></option>' if self.strut_contacts else '><flag contact="disable"/></option>')
            + f'<worldbody>{"".join(world)}{"".join(bodies)}</worldbody>'
            f'<tendon>{"".join(tendons)}</tendon><sensor>{"".join(sensors)}</sensor></mujoco>')

    # ------------------------------------------------------------------------------- state
    def reset(self) -> None:
        """The scene's initial state: ``qpos0`` holds the positions; velocities from the node velocities
        (a rigid strut gets its centre-of-mass velocity and ``omega = d x (v_b - v_a) / |d|^2``)."""
        mj, m, d = self._mj, self.model, self.data
        mj.mj_resetData(m, d)
        v, masses, names = self.scene.velocities, self.system.masses, self.scene.node_names
        x = self.scene.positions
        for j in range(m.njnt):
            body = m.body(m.jnt_bodyid[j]).name
            adr = m.jnt_dofadr[j]
            if m.jnt_type[j] == mj.mjtJoint.mjJNT_SLIDE:
                p = names.index(body[len("point_"):])
                d.qvel[adr] = v[p] @ m.jnt_axis[j]
            else:  # free joint of a rigid strut: body frame = world frame at t = 0
                i = self.scene.strut_names.index(body[len("strut_"):])
                a, b = self.system.strut_ends[i]
                d.qvel[adr:adr + 3] = (masses[a] * v[a] + masses[b] * v[b]) / (masses[a] + masses[b])
                r = x[b] - x[a]
                d.qvel[adr + 3:adr + 6] = np.cross(r, v[b] - v[a]) / (r @ r)
        mj.mj_forward(m, d)

    def advance(self, steps: int) -> None:
        """``steps`` steps in MuJoCo's C loop (no Python per step), sensors off: this is what is timed."""
        flag = int(self._mj.mjtDisableBit.mjDSBL_SENSOR)
        self.model.opt.disableflags |= flag
        self._mj.mj_step(self.model, self.data, nstep=steps)
        self.model.opt.disableflags &= ~flag

    @property
    def unstable(self) -> bool:
        """MuJoCo flagged a diverging acceleration (it then resets the state: the run is void)."""
        return self.data.warning[self._mj.mjtWarning.mjWARN_BADQACC].number > 0

    def positions(self) -> np.ndarray:
        """Node positions (N, 3) m of the current state."""
        self._mj.mj_kinematics(self.model, self.data)
        return self.data.site_xpos[self._sites].copy()

    def velocities(self) -> np.ndarray:
        """Node velocities (N, 3) m/s of the current state (world frame)."""
        mj, m, d = self._mj, self.model, self.data
        mj.mj_forward(m, d)
        out, res = np.empty((len(self._sites), 3)), np.empty(6)
        for k, site in enumerate(self._sites):
            mj.mj_objectVelocity(m, d, mj.mjtObj.mjOBJ_SITE, site, res, 0)
            out[k] = res[3:]
        return out

    def energy(self) -> float:
        """Kinetic + potential (springs, gravity) energy, J, computed by MuJoCo."""
        m, d = self.model, self.data
        flag = int(self._mj.mjtEnableBit.mjENBL_ENERGY)   # on only here: it costs time in every step
        m.opt.enableflags |= flag
        self._mj.mj_forward(m, d)
        m.opt.enableflags &= ~flag
        return float(d.energy.sum())

    def _cable_forces(self, sensed: np.ndarray) -> np.ndarray:
        """Each cable's force (k, n_cables) N from the cable sensors' readings (k, n_cables): tension
        ``k max(0, l - L)`` from the tendon lengths of spring cables, the limit force of limit cables."""
        if self.cable_model == "elastic":
            return self._cable_k * np.maximum(sensed - self.scene.cable_rest_lengths, 0.0)
        return sensed

    def run_measured(self, steps: int, samples: int = 100) -> tuple[Final, float]:
        """From the initial state, ``steps`` steps; returns the final state with each cable's impulse, and
        the largest energy deviation (J) over ``samples`` evenly spaced checks.

        The steps run in MuJoCo's ``rollout`` (C, in chunks), which records every step's state and the
        cable sensors, read at each step's start (a tendon length, or a limit force). MuJoCo does not
        report a tendon's impulse: it is integrated from those readings, by the trapezoid rule for
        spring cables (second order), as force times step for limit cables (exact for Euler and
        implicitfast, whose constraint force is computed once, at the start of the step; NaN under RK4,
        whose four stages' forces MuJoCo does not keep)."""
        from mujoco import rollout

        mj, m, d = self._mj, self.model, self.data
        self.reset()
        e0 = self.energy()
        spec = mj.mjtState.mjSTATE_FULLPHYSICS
        state = np.empty(mj.mj_stateSize(m, spec))
        mj.mj_getState(m, d, state, spec)
        every = max(1, steps // samples)
        de, done = 0.0, 0
        impulse = np.zeros(len(self._tendons))
        first = None
        while done < steps:
            n = min(_CHUNK, steps - done)
            states, sensed = rollout.rollout(m, d, state[None], nstep=n)
            forces = self._cable_forces(sensed[0])
            first = forces[0] if first is None else first
            impulse += forces.sum(axis=0)
            for k in range(every - 1 - done % every, n, every):
                mj.mj_setState(m, d, states[0, k], spec)
                de = max(de, abs(self.energy() - e0))
            state = states[0, -1]
            done += n
        mj.mj_setState(m, d, state, spec)
        mj.mj_forward(m, d)
        if self.cable_model == "elastic":   # trapezoid: half weight on the first and the final reading
            impulse += 0.5 * (self._cable_forces(d.sensordata[None])[0] - first)
        elif self.integrator == "RK4":
            impulse[:] = np.nan
        final = Final(self.positions(), self.velocities(), self.dt * impulse)
        return final, max(de, abs(self.energy() - e0))


def axial_inertia_effect(scene: ts.Scene, duration: float, dt: float, integrator: str = "RK4",
                         values=(1e-3, 1e-6, 1e-9)) -> dict[float, float]:
    """Largest node-position difference (m) after ``duration`` s between runs with each relative axial
    inertia of ``values`` and the run with the first one: the modelling artefact, quantified."""
    finals = {}
    for value in values:
        peer = MujocoPeer(scene, dt=dt, integrator=integrator, axial_inertia=value)
        peer.advance(int(round(duration / dt)))
        finals[value] = peer.positions()
    base = finals[values[0]]
    return {value: float(np.max(np.linalg.norm(x - base, axis=1))) for value, x in finals.items()}
