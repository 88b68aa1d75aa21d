"""Where the scripted humans are, compiled with numba: :func:`swarm_env.geometry.paths.human_states` for a
world's humans in one call.

A world asks for its humans' positions and velocities in every physics substep (kinematic bodies
moved along their paths); :func:`~swarm_env.geometry.paths.human_states` answers human by human in Python
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

import numpy as np

from swarm_env.geometry.paths import PolylinePath
from swarm_env.kernel_cache import njit
from swarm_env.scenario import HumanSpec

_MODES = {"once": 0, "loop": 1, "pingpong": 2}
_jit = njit(nogil=True, error_model="numpy")


class PackedHumans:
    """The walking rules and paths of a world's humans as three arrays (built once per world).

    * ``table`` ``(H, 7)``: per human ``speed, start_delay, mode (0 once, 1 loop, 2 pingpong),
      path length, first vertex row, vertex count, first segment row`` (the indices as floats,
      exact);
    * ``vertices`` ``(P, 3)``: every path's vertices ``x, y, cumulative arc length``;
    * ``segments`` ``(S, 3)``: every path's segments ``ux, uy, heading``.
    """

    def __init__(self, humans: Sequence[HumanSpec], paths: Sequence[PolylinePath]) -> None:
        verts, segs, rows = [], [], []
        p0 = g0 = 0
        for h, path in zip(humans, paths):
            verts.append(np.column_stack([path.points, path.cumulative]))
            segs.append(np.column_stack([path._unit, path.headings]))
            rows.append((float(h.speed), float(h.start_delay), float(_MODES[h.mode]), path.length, float(p0),
                         float(len(path.points)), float(g0)))
            p0 += len(path.points)
            g0 += len(path.headings)

        def flat(parts: list[np.ndarray]) -> np.ndarray:
            return np.ascontiguousarray(np.concatenate(parts) if parts else np.zeros((0, 3)), dtype=np.float64)

        self.table = np.array(rows, dtype=np.float64).reshape(len(rows), 7)
        self.vertices = flat(verts)
        self.segments = flat(segs)

    def states(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """``(positions (H, 2), velocities (H, 2))`` at time ``t``: what
        :func:`~swarm_env.geometry.paths.human_states` returns for these humans and paths."""
        return _states(float(t), self.table, self.vertices, self.segments)

    def states_at(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(positions (K, H, 2), velocities (K, H, 2))`` at each of the ``(K,)`` times: row ``k``
        is :meth:`states` ``(times[k])``, bit for bit, for all of a control step's substeps in one
        call (a world asks for ``substeps + 1`` times per step)."""
        return _states_many(np.ascontiguousarray(times, dtype=np.float64), self.table, self.vertices, self.segments)


@_jit
def _states(t, table, vertices, segments):  # pragma: no cover
    n = table.shape[0]
    pos = np.zeros((n, 2))
    vel = np.zeros((n, 2))
    fill_states(t, table, vertices, segments, pos, vel)
    return pos, vel


@_jit
def _states_many(times, table, vertices, segments):  # pragma: no cover
    n = table.shape[0]
    pos = np.zeros((len(times), n, 2))
    vel = np.zeros((len(times), n, 2))
    for r in range(len(times)):
        fill_states(times[r], table, vertices, segments, pos[r], vel[r])
    return pos, vel


@_jit
def fill_states(t, table, vertices, segments, pos, vel):  # pragma: no cover
    """Write the humans' positions and velocities at time ``t`` into the zeroed ``pos``, ``vel``
    ``(H, 2)`` (a :class:`PackedHumans`' arrays; callable from other kernels)."""
    n = table.shape[0]
    for k in range(n):
        speed = table[k, 0]
        mode = int(table[k, 2])
        L = table[k, 3]
        p0 = int(table[k, 4])
        n_cum = int(table[k, 5])
        g0 = int(table[k, 6])
        elapsed = t - table[k, 1]
        if elapsed <= 0.0 or speed <= 0.0 or L <= 0.0:
            pos[k, 0] = vertices[p0, 0]
            pos[k, 1] = vertices[p0, 1]
            continue
        d = speed * elapsed
        sign = 1.0
        if mode == 0:
            if d >= L:
                pos[k, 0] = vertices[p0 + n_cum - 1, 0]
                pos[k, 1] = vertices[p0 + n_cum - 1, 1]
                continue
            s = d
        elif mode == 1:
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
        while right < n_cum and vertices[p0 + right, 2] <= s:
            right += 1
        i = right - 1
        if i < 0:
            i = 0
        elif i > last:
            i = last
        ds = s - vertices[p0 + i, 2]
        pos[k, 0] = vertices[p0 + i, 0] + ds * segments[g0 + i, 0]
        pos[k, 1] = vertices[p0 + i, 1] + ds * segments[g0 + i, 1]
        if sign > 0.0:
            h = segments[g0 + i, 2]
        else:  # heading_before: bisect_left(cum, s) - 1, the segment ending at s on a vertex
            left = 0
            while left < n_cum and vertices[p0 + left, 2] < s:
                left += 1
            j = left - 1
            if j < 0:
                j = 0
            elif j > last:
                j = last
            h = segments[g0 + j, 2]
        vel[k, 0] = sign * speed * math.cos(h)
        vel[k, 1] = sign * speed * math.sin(h)


__all__ = ["PackedHumans"]
