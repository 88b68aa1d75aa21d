"""The followers' arrays of :meth:`swarm_env.sim.world.World.snapshot`, compiled with numba.

The numpy reference is :meth:`World._follower_arrays <swarm_env.sim.world.World._follower_arrays>`
(a dozen small numpy calls); this kernel computes the same three arrays in one pass with the same
operations (``vx * cos(a) + vy * sin(a)``, the angle wrapped as ``(a + pi) % (2 pi) - pi``; the C
library's ``cos``/``sin`` and Python's float ``%``, which numpy also uses for float64 here), so the
same bits (``tests/test_snapshot_kernel.py``).
"""

from __future__ import annotations

import math

import numpy as np

from swarm_env.kernel_cache import njit

_TWO_PI = 2.0 * math.pi
_jit = njit(nogil=True, error_model="numpy")


@_jit
def follower_arrays(raw):  # pragma: no cover - compiled
    """``(pose (N, 3), vel (N, 2), twist (N, 2))`` from ``raw`` ``(N, 6)`` rows ``(x, y, angle, vx,
    vy, omega)``: the pose with its angle wrapped to ``[-pi, pi)``, the world-frame velocity and the
    twist (forward speed, angular velocity)."""
    n = len(raw)
    pose = np.empty((n, 3))
    vel = np.empty((n, 2))
    twist = np.empty((n, 2))
    for i in range(n):
        fill_follower(raw[i, 0], raw[i, 1], raw[i, 2], raw[i, 3], raw[i, 4], raw[i, 5], pose[i], vel[i], twist[i])
    return pose, vel, twist


@_jit
def fill_follower(x, y, a, vx, vy, omega, pose, vel, twist):  # pragma: no cover - compiled
    """One follower's rows of :func:`follower_arrays` from its body's ``(x, y, angle, vx, vy,
    omega)``, written into ``pose`` (3,), ``vel`` (2,), ``twist`` (2,) (callable from other kernels:
    :mod:`swarm_env.vector.world_batch` reads the bodies itself)."""
    pose[0] = x
    pose[1] = y
    pose[2] = (a + math.pi) % _TWO_PI - math.pi
    vel[0] = vx
    vel[1] = vy
    twist[0] = vx * math.cos(a) + vy * math.sin(a)
    twist[1] = omega


__all__ = ["fill_follower", "follower_arrays"]
