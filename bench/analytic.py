"""Small scenes whose motion is known in closed form, and that motion (for tests and benchmarks).

Each ``*_dict`` builds a scene mapping (contract §1); each ``*_exact`` gives the exact state at time ``t``
in the model named, so that an error against it is the simulator's error and nothing else.
"""
from __future__ import annotations

import math

import numpy as np

__all__ = [
    "bungee_dict", "bungee_constants", "bungee_exact",
    "deadband_dict", "deadband_exact",
    "snap_pair_dict", "snap_pair_exact",
    "drop_slide_dict", "drop_slide_exact",
    "plate_snap_dict", "plate_snap_exact",
]


# ---------------------------------------------------------------------------------------------- bungee
def bungee_dict(k=100.0, m=1.0, rest=1.0, drop=0.5, g=9.81, damping=0.0):
    """A mass hanging on one tension-only cable from a fixed anchor at the origin, released at rest
    ``drop`` m below the anchor (so it falls freely before the cable snaps taut)."""
    return {
        "name": "bungee",
        "gravity": [0.0, 0.0, -g],
        "nodes": [
            {"name": "anchor", "position": [0.0, 0.0, 0.0], "fixed": True},
            {"name": "mass", "position": [0.0, 0.0, -drop], "mass": m},
        ],
        "cables": [{"name": "c", "nodes": ["anchor", "mass"], "stiffness": k, "rest_length": rest,
                    "damping": damping}],
    }


def bungee_constants(k=100.0, m=1.0, rest=1.0, drop=0.5, g=9.81):
    """(period s, lowest height m) of the undamped elastic bungee of :func:`bungee_dict`."""
    t1 = math.sqrt(2 * (rest - drop) / g)
    v1 = g * t1
    w = math.sqrt(k / m)
    ys = m * g / k
    alpha = math.atan2(v1 / w, ys)
    period = 2 * t1 + (2 * math.pi - 2 * alpha) / w
    lowest = -rest - (ys + math.hypot(ys, v1 / w))
    return period, lowest


def bungee_exact(t, k=100.0, m=1.0, rest=1.0, drop=0.5, g=9.81):
    """Height z (m) and vertical velocity vz (m/s) of the elastic bungee mass at time ``t`` (s):
    free fall, a taut harmonic swing about the stretched equilibrium, a free rise; periodic."""
    t1 = math.sqrt(2 * (rest - drop) / g)        # the cable snaps taut
    v1 = g * t1
    w = math.sqrt(k / m)
    ys = m * g / k
    alpha = math.atan2(v1 / w, ys)
    taut = (2 * math.pi - 2 * alpha) / w          # time spent taut
    t = t % (2 * t1 + taut)
    if t <= t1:
        return -drop - 0.5 * g * t * t, -g * t
    if t <= t1 + taut:
        tau = t - t1
        return (-rest - (ys * (1 - math.cos(w * tau)) + (v1 / w) * math.sin(w * tau)),
                -(ys * w * math.sin(w * tau) + v1 * math.cos(w * tau)))
    tau = t - t1 - taut
    return -rest + v1 * tau - 0.5 * g * tau * tau, v1 - g * tau


# -------------------------------------------------------------------------------------------- dead band
def deadband_dict(k=50.0, m=2.0, half_gap=1.0, slack=0.1, v0=0.5):
    """A mass between two fixed anchors on the x axis, each cable slack by ``slack`` at the centre."""
    return {
        "name": "deadband",
        "nodes": [
            {"name": "left", "position": [-half_gap, 0.0, 0.0], "fixed": True},
            {"name": "mass", "position": [0.0, 0.0, 0.0], "mass": m, "velocity": [v0, 0.0, 0.0]},
            {"name": "right", "position": [half_gap, 0.0, 0.0], "fixed": True},
        ],
        "cables": [
            {"name": "cl", "nodes": ["left", "mass"], "stiffness": k, "rest_length": half_gap + slack},
            {"name": "cr", "nodes": ["mass", "right"], "stiffness": k, "rest_length": half_gap + slack},
        ],
    }


def deadband_exact(t, k=50.0, m=2.0, slack=0.1, v0=0.5):
    """Elastic model of :func:`deadband_dict`: the mass's x (m) at time ``t`` (s) and each cable's
    impulse (2,) N*s accumulated over [0, t]. A glide across the dead band at +-v0, then half a
    harmonic period against one cable (which gives back the momentum: impulse ``2 m v0``)."""
    w = math.sqrt(k / m)
    half = math.pi / w
    glide = 2 * slack / v0
    period = 2 * half + 2 * glide
    cycles, t = divmod(t, period)
    impulse = np.full(2, 2 * m * v0 * cycles)
    # phases from x = 0 moving right: glide to +slack, left cable taut, glide back, right cable taut, glide to 0
    if t <= glide / 2:
        return v0 * t, impulse
    t -= glide / 2
    if t <= half:
        impulse[0] += m * v0 * (1 - math.cos(w * t))
        return slack + (v0 / w) * math.sin(w * t), impulse
    impulse[0] += 2 * m * v0
    t -= half
    if t <= glide:
        return slack - v0 * t, impulse
    t -= glide
    if t <= half:
        impulse[1] += m * v0 * (1 - math.cos(w * t))
        return -slack - (v0 / w) * math.sin(w * t), impulse
    impulse[1] += 2 * m * v0
    return -slack + v0 * (t - half), impulse


# ------------------------------------------------------------------------------------------- snap pair
def snap_pair_dict(k=1.0e3, m1=1.0, m2=3.0, rest=1.0, d0=0.8, v_rel=2.0, drift=0.3):
    """Two free masses on the x axis, ``d0`` apart (centre of mass at the origin), flying apart at
    ``v_rel`` m/s on a cable of rest length ``rest`` (so it snaps taut at ``(rest - d0)/v_rel``), with a
    common sideways drift ``drift`` m/s along y. No gravity. Serves both cable models."""
    M = m1 + m2
    return {
        "name": "snap_pair",
        "nodes": [
            {"name": "a", "position": [-d0 * m2 / M, 0.0, 0.0], "mass": m1,
             "velocity": [-v_rel * m2 / M, drift, 0.0]},
            {"name": "b", "position": [d0 * m1 / M, 0.0, 0.0], "mass": m2,
             "velocity": [v_rel * m1 / M, drift, 0.0]},
        ],
        "cables": [{"name": "c", "nodes": ["a", "b"], "stiffness": k, "rest_length": rest}],
    }


def snap_pair_exact(t, model, k=1.0e3, m1=1.0, m2=3.0, rest=1.0, d0=0.8, v_rel=2.0, drift=0.3):
    """Positions (2, 3) m and the cable's impulse (1,) N*s over [0, t] of :func:`snap_pair_dict`.

    ``model="inextensible"``: the snap is perfectly inelastic, both masses continue at the centre of
    mass's velocity with the cable at its rest length; impulse ``mu v_rel`` (``mu = m1 m2 / M``).
    ``model="elastic"``: half a harmonic period of the relative motion at ``w = sqrt(k/mu)`` with the
    cable taut, then the masses approach at ``v_rel`` with the cable slack; impulse ``2 mu v_rel``.
    Valid until the elastic pair would meet again (``t < t1 + pi/w + rest/v_rel``).
    """
    M = m1 + m2
    mu = m1 * m2 / M
    t1 = (rest - d0) / v_rel
    if t <= t1:
        s, impulse = d0 + v_rel * t, 0.0
    elif model == "inextensible":
        s, impulse = rest, mu * v_rel
    elif model == "elastic":
        w = math.sqrt(k / mu)
        tau = t - t1
        if tau <= math.pi / w:
            s, impulse = rest + (v_rel / w) * math.sin(w * tau), mu * v_rel * (1 - math.cos(w * tau))
        else:
            s, impulse = rest - v_rel * (tau - math.pi / w), 2 * mu * v_rel
        if s <= 0.0:
            raise ValueError(f"snap_pair_exact: t={t!r} s is past the time the masses meet")
    else:
        raise ValueError(f"model must be 'elastic' or 'inextensible', got {model!r}")
    x = np.array([[-s * m2 / M, drift * t, 0.0], [s * m1 / M, drift * t, 0.0]])
    return x, np.array([impulse])


# ---------------------------------------------------------------------------------------------- drop and slide
def drop_slide_dict(v0=2.0, gap=0.04, mu=0.5, g=9.81, length=1.0, radius=0.01, m=1.0):
    """A rigid strut (``m`` kg per end, capsule of ``radius``) parallel to the ground ``z = 0`` (Coulomb
    ``mu``, plastic), ``gap`` m above it, moving along its axis at ``v0``: it falls, lands flat, slides and
    stops."""
    return {
        "name": "drop_slide",
        "gravity": [0.0, 0.0, -g],
        "ground": {"height": 0.0, "friction": mu, "restitution": 0.0},
        "nodes": [{"name": "a", "position": [0.0, 0.0, gap + radius], "mass": m, "velocity": [v0, 0.0, 0.0]},
                  {"name": "b", "position": [length, 0.0, gap + radius], "mass": m, "velocity": [v0, 0.0, 0.0]}],
        "struts": [{"name": "s", "nodes": ["a", "b"], "stiffness": "rigid", "radius": radius}],
    }


def drop_slide_exact(t, v0=2.0, gap=0.04, mu=0.5, g=9.81, length=1.0, radius=0.01):
    """Positions (2, 3) m and velocities (2, 3) m/s of :func:`drop_slide_dict` at ``t``: free fall for
    ``sqrt(2 gap / g)``; the plastic landing's normal impulse ``m v_impact`` takes ``mu m v_impact`` off
    the sliding speed (Coulomb's law for impulses); then deceleration ``mu g`` to rest."""
    fall = math.sqrt(2.0 * gap / g)
    if t <= fall:
        x, z, vx, vz = v0 * t, gap + radius - 0.5 * g * t * t, v0, -g * t
    else:
        u = max(v0 - mu * g * fall, 0.0)
        slide = min(t - fall, u / (mu * g))
        x, z, vx, vz = v0 * fall + u * slide - 0.5 * mu * g * slide * slide, radius, u - mu * g * slide, 0.0
    pos = np.array([[x, 0.0, z], [x + length, 0.0, z]])
    vel = np.array([[vx, 0.0, vz], [vx, 0.0, vz]])
    return pos, vel
# ------------------------------------------------------------------------------------- slack pendulum
def sling_dict(x0=0.5, speed=2.0, length=1.0, m=1.0):
    """A 1 kg node on a slack inextensible cable of ``length`` m from a fixed anchor at the origin,
    starting at ``(x0, 0.6, 0)`` and moving at ``speed`` m/s along x; no gravity. The cable snaps taut
    at ``(0.8, 0.6, 0)`` (a 3-4-5 triangle for the default length)."""
    return {
        "name": "sling",
        "nodes": [{"name": "anchor", "position": [0.0, 0.0, 0.0], "fixed": True},
                  {"name": "m", "position": [x0, 0.6, 0.0], "mass": m, "velocity": [speed, 0.0, 0.0]}],
        "cables": [{"name": "c", "nodes": ["anchor", "m"], "rest_length": length}],
    }


def sling_exact(t, x0=0.5, speed=2.0, length=1.0, m=1.0):
    """Positions (2, 3) m and the cable's impulse (1,) N*s over [0, t] of :func:`sling_dict`: free flight
    until the snap at ``x = sqrt(L^2 - 0.36)``, which takes the radial momentum (perfectly inelastic);
    then uniform circular motion at the tangential speed ``u``, tension ``m u^2 / L``."""
    x_snap = math.sqrt(length ** 2 - 0.36)
    t_snap = (x_snap - x0) / speed
    if t <= t_snap:
        return np.array([[0.0, 0.0, 0.0], [x0 + speed * t, 0.6, 0.0]]), np.array([0.0])
    radial = speed * x_snap / length
    u = speed * 0.6 / length
    angle = math.atan2(0.6, x_snap) - (u / length) * (t - t_snap)
    x = np.array([[0.0, 0.0, 0.0], [length * math.cos(angle), length * math.sin(angle), 0.0]])
    return x, np.array([m * radial + m * u * u / length * (t - t_snap)])


# ---------------------------------------------------------------------------------------------- plate snap
def plate_snap_dict(plate=0.5, omega=10.0, m=1.0, rest=1.0, gap=0.05, v0=1.0):
    """A body of ``m`` kg ``gap`` m short of an anchored cable's rest length, moving out along it at ``v0``
    m/s; the cable carries a plate of ``plate`` kg (method "massive", physics §4b) and its stiffness makes
    the taut phase's angular frequency ``omega``; no gravity."""
    return {
        "name": "plate_snap",
        "nodes": [{"name": "a", "position": [0.0, 0.0, 0.0], "fixed": True},
                  {"name": "b", "position": [rest - gap, 0.0, 0.0], "mass": m, "velocity": [v0, 0.0, 0.0]}],
        "cables": [{"name": "c", "nodes": ["a", "b"], "stiffness": omega ** 2 * (m + plate), "rest_length": rest,
                    "mass": plate}],
    }


def plate_snap_exact(t, plate=0.5, omega=10.0, m=1.0, rest=1.0, gap=0.05, v0=1.0):
    """Positions (2, 3) m, velocities (2, 3) m/s and the cable's impulse (1,) N*s over [0, t] of
    :func:`plate_snap_dict` once the cable has let go (``t`` after ``gap/v0 + pi/omega``): the snap keeps
    ``m v0/(m + plate)`` of the speed, the body and plate swing half a period together, and the body leaves
    back out at that speed; the impulse is the body's momentum change."""
    release = gap / v0 + math.pi / omega
    if t < release:
        raise ValueError(f"plate_snap_exact: t = {t} s is before the release at {release:.6g} s")
    back = m * v0 / (m + plate)
    x = np.array([[0.0, 0.0, 0.0], [rest - back * (t - release), 0.0, 0.0]])
    v = np.array([[0.0, 0.0, 0.0], [-back, 0.0, 0.0]])
    return x, v, np.array([m * (v0 + back)])
