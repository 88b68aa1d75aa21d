"""Where the scripted humans are, compiled with numba: :func:`swarm_env.paths.human_states` for a
world's humans in one call.

A world asks for its humans' positions and velocities in every physics substep (kinematic bodies
moved along their paths); :func:`~swarm_env.paths.human_states` answers human by human in Python
(~3 µs each, five times a step). :class:`PackedHumans` holds the humans' paths as flat arrays and
:meth:`PackedHumans.states` runs the same rules over them in one kernel call.

Same bits as the reference (``tests/test_human_kernel.py``): the same operations in the same order
(``fmod`` of the walked distance, the segment found as ``bisect`` finds it, ``a + ds * u`` along it,
``sign * speed * cos(heading)``; ``fmod``, ``cos`` and ``sin`` are the C library's, as Python's
``math`` module calls them).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numba
import numpy as np

from swarm_env.paths import PolylinePath
from swarm_env.scenario import HumanSpec

_MODES = {"once": 0, "loop": 1, "pingpong": 2}
_jit = numba.njit(cache=True, nogil=True, error_model="numpy")


class PackedHumans:
    """The walking rules and paths of a world's humans as arrays (built once per world)."""

    def __init__(self, humans: Sequence[HumanSpec], paths: Sequence[PolylinePath]) -> None:
        pts, cum, unit, head, pt_start, seg_start = [], [], [], [], [0], [0]
        for path in paths:
            pts.append(path.points)
            cum.append(path.cumulative)
            unit.append(path._unit)
            head.append(path.headings)
            pt_start.append(pt_start[-1] + len(path.points))
            seg_start.append(seg_start[-1] + len(path.headings))

        def flat(parts: list[np.ndarray], shape: tuple[int, ...]) -> np.ndarray:
            return np.ascontiguousarray(np.concatenate(parts) if parts else np.zeros(shape), dtype=np.float64)

        self.points = flat(pts, (0, 2))
        self.cum = flat(cum, (0,))
        self.unit = flat(unit, (0, 2))
        self.headings = flat(head, (0,))
        self.pt_start = np.array(pt_start, dtype=np.int64)
        self.seg_start = np.array(seg_start, dtype=np.int64)
        self.speed = np.array([float(h.speed) for h in humans], dtype=np.float64)
        self.delay = np.array([float(h.start_delay) for h in humans], dtype=np.float64)
        self.mode = np.array([_MODES[h.mode] for h in humans], dtype=np.int64)
        self.length = np.array([p.length for p in paths], dtype=np.float64)

    def states(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """``(positions (H, 2), velocities (H, 2))`` at time ``t``: what
        :func:`~swarm_env.paths.human_states` returns for these humans and paths."""
        return _states(float(t), self.points, self.cum, self.unit, self.headings, self.pt_start, self.seg_start,
                       self.speed, self.delay, self.mode, self.length)

    def states_at(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(positions (K, H, 2), velocities (K, H, 2))`` at each of the ``(K,)`` times: row ``k``
        is :meth:`states` ``(times[k])``, bit for bit, for all of a control step's substeps in one
        call (a world asks for ``substeps + 1`` times per step)."""
        return _states_many(np.ascontiguousarray(times, dtype=np.float64), self.points, self.cum, self.unit,
                            self.headings, self.pt_start, self.seg_start, self.speed, self.delay, self.mode,
                            self.length)


@_jit
def _states(t, points, cum, unit, headings, pt_start, seg_start, speed, delay, mode, length):  # pragma: no cover
    n = len(speed)
    pos = np.zeros((n, 2))
    vel = np.zeros((n, 2))
    _fill_states(t, points, cum, unit, headings, pt_start, seg_start, speed, delay, mode, length, pos, vel)
    return pos, vel


@_jit
def _states_many(times, points, cum, unit, headings, pt_start, seg_start, speed, delay, mode, length):  # pragma: no cover
    n = len(speed)
    pos = np.zeros((len(times), n, 2))
    vel = np.zeros((len(times), n, 2))
    for r in range(len(times)):
        _fill_states(times[r], points, cum, unit, headings, pt_start, seg_start, speed, delay, mode, length,
                     pos[r], vel[r])
    return pos, vel


@_jit
def _fill_states(t, points, cum, unit, headings, pt_start, seg_start, speed, delay, mode, length, pos, vel
                 ):  # pragma: no cover
    """Write the humans' positions and velocities at time ``t`` into the zeroed ``pos``, ``vel`` (H, 2)."""
    n = len(speed)
    for k in range(n):
        p0 = pt_start[k]
        n_cum = pt_start[k + 1] - p0
        g0 = seg_start[k]
        L = length[k]
        elapsed = t - delay[k]
        if elapsed <= 0.0 or speed[k] <= 0.0 or L <= 0.0:
            pos[k, 0] = points[p0, 0]
            pos[k, 1] = points[p0, 1]
            continue
        d = speed[k] * elapsed
        sign = 1.0
        if mode[k] == 0:
            if d >= L:
                pos[k, 0] = points[p0 + n_cum - 1, 0]
                pos[k, 1] = points[p0 + n_cum - 1, 1]
                continue
            s = d
        elif mode[k] == 1:
            s = np.fmod(d, L)
        else:
            u = np.fmod(d, 2.0 * L)
            if u < L:
                s = u
            else:
                s = 2.0 * L - u
                sign = -1.0
        s = min(max(s, 0.0), L)  # point_at's clip (a no-op for the s above, kept for the same bits)
        last = n_cum - 2
        # bisect_right(cum, s) - 1: the segment containing s (the outgoing one at a vertex)
        right = 0
        while right < n_cum and cum[p0 + right] <= s:
            right += 1
        i = right - 1
        if i < 0:
            i = 0
        elif i > last:
            i = last
        ds = s - cum[p0 + i]
        pos[k, 0] = points[p0 + i, 0] + ds * unit[g0 + i, 0]
        pos[k, 1] = points[p0 + i, 1] + ds * unit[g0 + i, 1]
        if sign > 0.0:
            h = headings[g0 + i]
        else:  # heading_before: bisect_left(cum, s) - 1, the segment ending at s on a vertex
            left = 0
            while left < n_cum and cum[p0 + left] < s:
                left += 1
            j = left - 1
            if j < 0:
                j = 0
            elif j > last:
                j = last
            h = headings[g0 + j]
        vel[k, 0] = sign * speed[k] * math.cos(h)
        vel[k, 1] = sign * speed[k] * math.sin(h)


__all__ = ["PackedHumans"]
