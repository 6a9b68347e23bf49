"""Compiled twin of encoding a publication's outputs with their :class:`~.cdr.CdrTemplate` objects (the
plain reference, :mod:`.publication`, which tests require this to match byte for byte), with numba."""
from __future__ import annotations

from numba import njit

from .._system_kernels import member_kinematics

__all__ = ["write_publication", "LAYOUT"]

# the entries of write_publication's ``layout`` (indices into the buffer's float64 or uint32 view)
LAYOUT = ("stamp_clock", "stamp_node_poses", "stamp_cable_states", "stamp_cable_impulses",  # uint32: sec
          "positions", "pose_stride", "lengths", "rates", "tensions", "impulses",            # float64
          "n_nodes")


@njit(cache=True, _nrt=False)
def write_publication(f64, u32, layout, x, v, nodes, weights, tensions, impulses, sec, nanosec):
    """Write one publication into the buffer seen as ``f64`` (float64) and ``u32`` (uint32) at the places
    ``layout`` gives (:data:`LAYOUT`, int64): each message's stamp (``sec`` at ``u32[stamp]``, ``nanosec``
    after it; 0 <= sec < 2**31 writes the int32's bits), the node positions ``x`` (N, 3) m (pose i at
    ``positions + i * pose_stride``), the cable lengths (m) and elongation rates (m/s) of the cables whose ends
    lie at ``nodes`` (nc, 2, 2) with ``weights`` (nc, 2) (``member_kinematics``) from ``x`` and velocities
    ``v`` (N, 3), the ``tensions`` (nc,) N and the impulse sums (nc,) N*s.
    ValueError for arrays of other sizes than the layout's (nothing written)."""
    n = nodes.shape[0]
    if x.shape[0] != layout[10] or v.shape[0] != layout[10] or tensions.shape[0] != n or impulses.shape[0] != n:
        raise ValueError("write_publication: arrays of other sizes than the layout's")
    for k in range(4):
        u32[layout[k]] = sec
        u32[layout[k] + 1] = nanosec
    p = layout[4]
    stride = layout[5]
    for i in range(x.shape[0]):
        for j in range(3):
            f64[p + i * stride + j] = x[i, j]
    member_kinematics(x, v, nodes, weights, f64[layout[6]:layout[6] + n], f64[layout[7]:layout[7] + n])
    # element by element: a slice assignment would cost 3 s of numba compilation on a first run
    for i in range(n):
        f64[layout[8] + i] = tensions[i]
        f64[layout[9] + i] = impulses[i]
