"""The followers' arrays of :meth:`swarm_env.world.World.snapshot`, compiled with numba.

The numpy reference is :meth:`World._follower_arrays <swarm_env.world.World._follower_arrays>`
(a dozen small numpy calls); this kernel computes the same three arrays in one pass with the same
operations (``vx * cos(a) + vy * sin(a)``, the angle wrapped as ``(a + pi) % (2 pi) - pi``; the C
library's ``cos``/``sin`` and Python's float ``%``, which numpy also uses for float64 here), so the
same bits (``tests/test_snapshot_kernel.py``).
"""

from __future__ import annotations

import math

import numba
import numpy as np

_TWO_PI = 2.0 * math.pi
_jit = numba.njit(cache=True, nogil=True, error_model="numpy")


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
        a = raw[i, 2]
        pose[i, 0] = raw[i, 0]
        pose[i, 1] = raw[i, 1]
        pose[i, 2] = (a + math.pi) % _TWO_PI - math.pi
        vel[i, 0] = raw[i, 3]
        vel[i, 1] = raw[i, 4]
        twist[i, 0] = raw[i, 3] * math.cos(a) + raw[i, 4] * math.sin(a)
        twist[i, 1] = raw[i, 5]
    return pose, vel, twist


__all__ = ["follower_arrays"]
