"""The global state of ``M`` worlds (``SwarmEnv.state()`` of each) in one compiled call.

The reference is :meth:`ObservationBuilder.state_vector
<swarm_env.sensing.observations.ObservationBuilder.state_vector>`: numpy, per world, whose follower
clearance (:func:`swarm_env.sensing.observations._clearance_features`: one ``StaticMap.distance`` call on
``5 N`` probe points and central differences) costs most of it; stacking it over 64 worlds costs
more than a whole batched engine step. :func:`state_batch` writes the ``(M, state_size)`` float32
rows of all worlds from the engine's stacked snapshot arrays (:class:`swarm_env.vector.batch_step.StepArrays`)
and its per-world padded maps (:class:`swarm_env.vector.batch_step.PaddedMaps`);
:meth:`swarm_env.vector.batch_step.BatchState.state` is its caller.

Same bits as the reference, by construction and by test (``tests/test_state_kernel.py``, and every
step of ``tests/test_vector.py``'s lockstep runs): every entry is the reference's float64 arithmetic
in its order (a position divided by the world size, a velocity by twice the speed limit, Python's
``min(next_switch - time, max_time) / max_time``, the gradient ``(d(x + h, y) - d(x - h, y),
d(x, y + h) - d(x, y - h))`` normalised by ``sqrt(gx * gx + gy * gy)`` where that is above 0), each
static distance is :func:`swarm_env.geometry.clearance_kernel.point_distance`, which gives
``StaticMap.distance``'s bits, and the clips (``[0, 1]`` for the clearance, ``[-limit, limit]`` for
the whole vector) and the float32 cast work entry by entry, as ``np.clip`` and ``astype`` do. The
headings' cosines and sines are numpy's, computed by the caller as the reference does (the
kernel's libm could round differently), and the occupancy grid is the builder's own
(:meth:`ObservationBuilder._occupancy <swarm_env.sensing.observations.ObservationBuilder._occupancy>`), one
row per world. The one freedom is ``StaticMap.distance``'s: a probe exactly on a boundary may give
``-0.0`` where the reference has ``0.0`` (equal under ``==``).

The layout is :func:`swarm_env.sensing.observations.state_layout`'s: the caller passes each block's first
column; the columns of one follower, leader or human within its block are :mod:`swarm_env.sensing.layout`'s
``*_COLUMNS``, in the order ``state_vector`` writes them (the caller checks the layout's block sizes against them).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from swarm_env.geometry.clearance_kernel import point_distance, world_map
from swarm_env.kernel_cache import njit
from swarm_env.sensing.layout import CLEARANCE_COLUMNS, FOLLOWER_COLUMNS, HUMAN_COLUMNS

_jit = njit(nogil=True, error_model="numpy")


class Headings(NamedTuple):
    """The cosines and sines of the followers' headings ``(M, N)`` and of the leader's ``(M,)``, computed by numpy
    as the reference does (numba's libm could round differently)."""

    cos_th: np.ndarray
    sin_th: np.ndarray
    cos_lead: np.ndarray
    sin_lead: np.ndarray


class StateScales(NamedTuple):
    """The observation builder's constants of the state: ``width``/``height`` its capacity's world size,
    ``vel_limit`` twice its speed limit, ``max_time``, ``clear_range`` (``STATE_CLEARANCE_RANGE``), ``step`` (the
    clearance gradient's ``_GRADIENT_STEP``), ``limit`` (``STATE_LIMIT``)."""

    width: float
    height: float
    vel_limit: float
    max_time: float
    clear_range: float
    step: float
    limit: float


class StateColumns(NamedTuple):
    """Each block's first column in :func:`swarm_env.sensing.observations.state_layout`."""

    followers: int
    leader: int
    humans: int
    time: int
    clearance: int
    occupancy: int


@_jit
def _put(out, j, v, limit):  # pragma: no cover - compiled
    """``out[j] = float32(clip(v, -limit, limit))``: ``np.clip``'s result entry by entry (a NaN stays NaN)."""
    if v < -limit:
        v = -limit
    elif v > limit:
        v = limit
    out[j] = np.float32(v)


@_jit
def state_batch(rows, heads, hcount, occupancy, maps, scales, cols, out):  # pragma: no cover - compiled
    """``out[m]`` = world ``m``'s ``ObservationBuilder.state_vector`` (float32 ``(M, state_size)``).

    ``rows`` the worlds' arrays, stacked on a leading world axis (read by name: ``pose`` ``(M, N, 3)``,
    ``twist`` and ``slots`` ``(M, N, 2)``, ``lpose`` ``(M, 3)``, ``lvel`` ``(M, 2)``, ``time`` and ``next_switch``
    ``(M,)``, humans padded ``hpos``/``hvel`` ``(M, Hmax, 2)``; :class:`swarm_env.vector.batch_step.WorldRows`),
    ``heads`` their :class:`Headings`, ``hcount`` ``(M,)`` the humans of each world, ``occupancy``
    ``(M, STATE_GRID ** 2)`` each world's grid, ``maps`` the worlds' maps (a
    :class:`~swarm_env.geometry.map_arrays.MapBatch`), ``scales`` a :class:`StateScales`, ``cols`` a
    :class:`StateColumns` (the caller checks that the blocks have room for ``N`` followers and ``hcount``
    humans). Rows and slots beyond a world's followers and humans are 0.
    """
    pose, twist, slots, lpose, lvel = rows.pose, rows.twist, rows.slots, rows.lpose, rows.lvel
    time, next_switch, hpos, hvel = rows.time, rows.next_switch, rows.hpos, rows.hvel
    cos_th, sin_th, cos_lead, sin_lead = heads
    width, height, vel_limit, max_time, clear_range, step, limit = scales
    fol_start, lead_start, hum_start, time_start, clear_start, occ_start = cols
    n_worlds = pose.shape[0]
    n = pose.shape[1]
    size = out.shape[1]
    for m in range(n_worlds):
        row = out[m]
        for j in range(size):
            row[j] = 0.0
        for i in range(n):
            c = fol_start + FOLLOWER_COLUMNS * i
            _put(row, c, pose[m, i, 0] / width, limit)
            _put(row, c + 1, pose[m, i, 1] / height, limit)
            _put(row, c + 2, cos_th[m, i], limit)
            _put(row, c + 3, sin_th[m, i], limit)
            _put(row, c + 4, twist[m, i, 0] / vel_limit, limit)
            _put(row, c + 5, twist[m, i, 1] / vel_limit, limit)
            _put(row, c + 6, slots[m, i, 0] / width, limit)
            _put(row, c + 7, slots[m, i, 1] / height, limit)
            _put(row, c + 8, 1.0, limit)
        _put(row, lead_start, lpose[m, 0] / width, limit)
        _put(row, lead_start + 1, lpose[m, 1] / height, limit)
        _put(row, lead_start + 2, cos_lead[m], limit)
        _put(row, lead_start + 3, sin_lead[m], limit)
        _put(row, lead_start + 4, lvel[m, 0] / vel_limit, limit)
        _put(row, lead_start + 5, lvel[m, 1] / vel_limit, limit)
        for h in range(hcount[m]):
            c = hum_start + HUMAN_COLUMNS * h
            _put(row, c, hpos[m, h, 0] / width, limit)
            _put(row, c + 1, hpos[m, h, 1] / height, limit)
            _put(row, c + 2, hvel[m, h, 0] / vel_limit, limit)
            _put(row, c + 3, hvel[m, h, 1] / vel_limit, limit)
            _put(row, c + 4, 1.0, limit)
        _put(row, time_start, time[m] / max_time, limit)
        to_switch = next_switch[m] - time[m]
        if max_time < to_switch:  # Python's min(to_switch, max_time): the first unless the second is smaller
            to_switch = max_time
        _put(row, time_start + 1, to_switch / max_time, limit)
        mp = world_map(maps, m)
        for i in range(n):
            x = pose[m, i, 0]
            y = pose[m, i, 1]
            # The reference's probes: pos, pos + (h, 0), pos - (h, 0), pos + (0, h), pos - (0, h), with
            # the 0.0 added too (it only changes the sign of a zero, kept for the same bits).
            d0 = point_distance(x, y, mp)
            d1 = point_distance(x + step, y + 0.0, mp)
            d2 = point_distance(x - step, y - 0.0, mp)
            d3 = point_distance(x + 0.0, y + step, mp)
            d4 = point_distance(x - 0.0, y - step, mp)
            gx = d1 - d2
            gy = d3 - d4
            norm = math.sqrt(gx * gx + gy * gy)
            free = d0 / clear_range
            if free < 0.0:
                free = 0.0
            elif free > 1.0:
                free = 1.0
            c = clear_start + CLEARANCE_COLUMNS * i
            _put(row, c, free, limit)
            if norm > 0.0:  # else (0, 0): the gradient vanishes exactly between two surfaces
                _put(row, c + 1, gx / norm, limit)
                _put(row, c + 2, gy / norm, limit)
        for j in range(occupancy.shape[1]):
            _put(row, occ_start + j, occupancy[m, j], limit)


__all__ = ["Headings", "StateColumns", "StateScales", "state_batch"]
