"""The same tensegrity in MuJoCo, the simulator users would otherwise pick (benchmark-only dependency).

The model is the scene's own export, :func:`tensegrity_sim.io.mjcf.scene_to_mjcf` (``Scene.to_mjcf()``; its
docstring says how each part is modelled), without the visual-only capsules; this module reads and writes
its state in node terms, steps it and measures it. What matters for the benchmarks:

* A rigid strut is a free body with the strut's exact mass, centre of mass and inertia normal to its axis.
  MuJoCo needs a positive inertia about the axis too, so ``axial_inertia`` (relative to the transverse
  inertia, default 1e-6) is added: no cable acts off the axis, so the exact motion has no axial torque and
  the axial spin stays zero whatever that inertia; :func:`axial_inertia_effect` measures its round-off.
  A capsule's contact with the ground is another matter: its friction acts at the surface, off the axis, and
  spins the strut about it (this simulator's nodes touch the ground at the node); on a rolling robot that spin
  makes MuJoCo's Euler step unstable, ``implicitfast`` not (``bench/bench_envs.py``).
* An elastic cable is a dead-band tendon spring (``springlength = "0 L"``), an inextensible one a limited
  tendon with ``solreflimit = "2*dt zeta"``: with the default damping ratio ``zeta = 1`` a snap rebounds
  with a restitution of about 0.1 at every step size (the constraint's dynamics scale with ``dt``, so it
  does not converge to the inelastic snap); ``zeta = 30`` brings the snap-pair's impulse error down to
  2e-4 N*s of 1.5 (measured), so the benchmarks run both.
* With a ground: a plane with the scene's friction that struts' capsules and point masses touch, elliptic
  cones and ``impratio`` (default 100, MuJoCo's advice for little slip). With ``strut_contacts=True`` (and
  no ground) the struts' capsules collide with each other (frictionless): what this simulator's default
  strut-strut detection checks, for a like-for-like cost of contact detection (MuJoCo also responds to a
  contact; this simulator, by default, only reports it).

Cable damping is refused here (MuJoCo's tendon damping acts also while slack, so the two would differ).
"""
from __future__ import annotations

import numpy as np

import tensegrity_sim as ts
from tensegrity_sim.io.mjcf import INTEGRATORS, scene_to_mjcf
from tensegrity_sim.system import System

from .reference import Final

__all__ = ["INTEGRATORS", "MujocoPeer", "axial_inertia_effect"]

_CHUNK = 20_000     # steps per rollout call in run_measured (bounds the memory of the recorded states)


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

        self._mj = mujoco
        self.scene, self.system, self.cable_model, self.dt = scene, System(scene), model, float(dt)
        self.integrator = integrator
        self.impratio = float(impratio)
        self.strut_contacts = bool(strut_contacts)
        if np.any(self.system.cable_damping > 0):
            raise ValueError("MujocoPeer: cable damping is not modelled (MuJoCo's tendon damping acts also when slack)")
        self.xml = scene_to_mjcf(scene, cable_model=model, dt=dt, integrator=integrator, axial_inertia=axial_inertia,
                                 limit_dampratio=limit_dampratio, impratio=impratio, strut_contacts=strut_contacts,
                                 visual=False)
        self.model = mujoco.MjModel.from_xml_string(self.xml)
        self.data = mujoco.MjData(self.model)
        self._sites = np.array([self.model.site(n).id for n in scene.node_names])
        self._tendons = np.array([self.model.tendon(c).id for c in scene.cable_names])
        self._cable_k = self.system.stiffness[self.system.n_struts:]
        self.reset()

    # ------------------------------------------------------------------------------- state
    def reset(self) -> None:
        """The scene's initial state: ``qpos0`` holds the positions; velocities from the node velocities
        (a rigid strut gets its centre-of-mass velocity and ``omega = d x (v_b - v_a) / |d|^2``)."""
        mj, m, d = self._mj, self.model, self.data
        mj.mj_resetData(m, d)
        v, names, x = self.scene.velocities, self.scene.node_names, self.scene.positions
        for j in range(m.njnt):
            body = m.jnt_bodyid[j]
            adr = m.jnt_dofadr[j]
            if m.jnt_type[j] == mj.mjtJoint.mjJNT_SLIDE:   # a point mass, named after its node
                d.qvel[adr] = v[names.index(m.body(body).name)] @ m.jnt_axis[j]
            else:  # free joint of a rigid strut (named after it): body frame = world frame at t = 0
                a, b = self.system.strut_ends[self.scene.strut_names.index(m.body(body).name)]
                r = x[b] - x[a]
                along = (m.body_pos[body] - x[a]) @ r / (r @ r)   # where its centre of mass is, from a to b
                d.qvel[adr:adr + 3] = v[a] + along * (v[b] - v[a])
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
