"""Per-step clearances of the followers, compiled with numba: the clearance reward and the
proximity metrics (:func:`swarm_env.scoring.rewards.clearance`, :class:`swarm_env.scoring.metrics.EpisodeMetrics`).

The numpy references are :meth:`swarm_env.geometry.static_map.StaticMap.distance` /
:meth:`~swarm_env.geometry.static_map.StaticMap.distance_lower_bound` and the reward's and metrics' own
numpy. For a world's eight followers they cost ~30 small numpy calls a step each (together
~20 % of a step: ``python benchmarks/engine_breakdown.py --worlds 1``); these kernels walk the
followers and the map's primitives directly.

Same bits as the references, by construction and by test (``tests/test_clearance_kernel.py``):
each distance is computed with the reference's floating-point operations in its order (the
polygon's edge projection ``t = (wx * ex + wy * ey) * inv_ee`` clamped to ``[0, 1]``, then
``sqrt(qx * qx + qy * qy)`` outside and ``-max(h)`` inside; ``sqrt(dx * dx + dy * dy) - r`` to a
circle; the wall's ``min(min(x, W - x), min(y, H - y))``), and minima and maxima are exact whatever
their order. The one freedom: a point exactly on a boundary may get ``-0.0`` where numpy gives
``0.0`` (the sign of a zero follows the order of a maximum's ties, which numpy's own SIMD
reductions do not fix either); every use compares it or subtracts a radius from it. The map arrays are :meth:`StaticMap.kernel_arrays <swarm_env.geometry.static_map.StaticMap.kernel_arrays>`.
"""

from __future__ import annotations

import math

import numpy as np

from swarm_env.geometry.map_arrays import MapArrays
from swarm_env.kernel_cache import njit

_jit = njit(nogil=True, error_model="numpy")


@_jit
def _wall(x, y, W, H):  # pragma: no cover - compiled
    """Signed distance to the world rectangle's boundary (``StaticMap._wall_sd``)."""
    inside = min(min(x, W - x), min(y, H - y))
    if inside >= 0.0:
        return inside
    ox = max(max(-x, x - W), 0.0)
    oy = max(max(-y, y - H), 0.0)
    return -math.sqrt(ox * ox + oy * oy)


@_jit
def point_distance(x, y, mp):  # pragma: no cover - compiled
    """``StaticMap.distance`` of one point (walls included); ``mp`` the map's
    :class:`~swarm_env.geometry.map_arrays.MapArrays`."""
    circles, n_poly, n_edge = mp.circles, mp.n_poly, mp.n_edge
    ax, ay, ex, ey, inv_ee, nx, ny = mp.ax, mp.ay, mp.ex, mp.ey, mp.inv_ee, mp.nx, mp.ny
    d = _wall(x, y, mp.width, mp.height)
    for c in range(len(circles)):
        dx = x - circles[c, 0]
        dy = y - circles[c, 1]
        d = min(d, math.sqrt(dx * dx + dy * dy) - circles[c, 2])
    for p in range(n_poly):
        hmax = -math.inf
        d2min = math.inf
        for m in range(n_edge):
            e = m * n_poly + p
            wx = x - ax[e]
            wy = y - ay[e]
            t = wx * ex[e] + wy * ey[e]
            t = t * inv_ee[e]
            t = min(max(t, 0.0), 1.0)
            qx = wx - t * ex[e]
            qy = wy - t * ey[e]
            d2min = min(d2min, qx * qx + qy * qy)
            hmax = max(hmax, wx * nx[e] + wy * ny[e])
        d = min(d, math.sqrt(d2min) if hmax > 0.0 else hmax)
    return d


@_jit
def distances(pos, mp):  # pragma: no cover - compiled
    """``(N,)`` :func:`point_distance` of each row of ``pos``."""
    out = np.empty(len(pos))
    for i in range(len(pos)):
        out[i] = point_distance(pos[i, 0], pos[i, 1], mp)
    return out


@_jit
def point_lower_bound(x, y, W, H, bound):  # pragma: no cover - compiled
    """``StaticMap.distance_lower_bound`` of one point."""
    lb = min(min(x, W - x), min(y, H - y))
    if lb < 0.0:
        lb = -math.inf
    for b in range(len(bound)):
        dx = x - bound[b, 0]
        dy = y - bound[b, 1]
        lb = min(lb, math.sqrt(dx * dx + dy * dy) - bound[b, 2])
    return lb


@_jit
def lower_bounds(pos, W, H, bound):  # pragma: no cover - compiled
    """``(N,)`` :func:`point_lower_bound` of each row of ``pos``."""
    out = np.empty(len(pos))
    for i in range(len(pos)):
        out[i] = point_lower_bound(pos[i, 0], pos[i, 1], W, H, bound)
    return out


@_jit
def static_min_distance(pos, minus, upper, lower, screen, mp):  # pragma: no cover - compiled
    """``StaticMap.min_distance(pos, minus, upper, lower)`` for finite ``upper`` (``screen``: its
    screening margin): the exact distance only where ``lower - minus < upper + screen``."""
    best = upper
    for i in range(len(pos)):
        if lower[i] - minus[i] < upper + screen:
            d = point_distance(pos[i, 0], pos[i, 1], mp)
            best = min(best, d - minus[i])
    return best


@_jit
def clearance(pos, r, below, fdist, leader, human_pos, human_r, mp):  # pragma: no cover - compiled
    """``swarm_env.scoring.rewards.clearance``: ``(N,)`` free distance of each follower's disc.

    ``fdist`` the followers' centre distances ``(N, N)`` (or ``(0, 0)``: computed here); ``leader`` ``(1, 3)`` ``(x, y, radius)``
    of a robot leader or ``(0, 3)``; exact where below ``below`` (``inf``: everywhere)."""
    n = len(pos)
    out = np.empty(n)
    finite = math.isfinite(below)
    for i in range(n):
        x, y, ri = pos[i, 0], pos[i, 1], r[i]
        best = point_lower_bound(x, y, mp.width, mp.height, mp.bound) - ri if finite else below
        if not finite or best < below:
            best = point_distance(x, y, mp) - ri
        if n > 1:
            gap = math.inf
            for j in range(n):
                if j != i:
                    if len(fdist):
                        c = fdist[i, j]
                    else:  # WorldState.follower_distances' arithmetic, without the (N, N) array
                        dx = x - pos[j, 0]
                        dy = y - pos[j, 1]
                        c = math.sqrt(dx * dx + dy * dy)
                    gap = min(gap, c - ri - r[j])
            best = min(best, gap)
        for q in range(len(leader)):
            dx = x - leader[q, 0]
            dy = y - leader[q, 1]
            best = min(best, math.sqrt(dx * dx + dy * dy) - ri - leader[q, 2])
        if len(human_pos):
            gap = math.inf
            for h in range(len(human_pos)):
                dx = x - human_pos[h, 0]
                dy = y - human_pos[h, 1]
                gap = min(gap, math.sqrt(dx * dx + dy * dy) - ri - human_r[h])
            best = min(best, gap)
        out[i] = best
    return out



@_jit
def world_map(maps, m):  # pragma: no cover - compiled
    """World ``m``'s :class:`~swarm_env.geometry.map_arrays.MapArrays` from a
    :class:`~swarm_env.geometry.map_arrays.MapBatch` (views, no copies)."""
    return MapArrays(maps.width[m], maps.height[m], maps.bound[m, :maps.nbound[m]], maps.circles[m, :maps.ncirc[m]],
                     maps.n_poly[m], maps.n_edge[m], maps.ax[m], maps.ay[m], maps.ex[m], maps.ey[m], maps.inv_ee[m],
                     maps.nx[m], maps.ny[m])


__all__ = ["clearance", "distances", "lower_bounds", "point_distance", "point_lower_bound", "static_min_distance",
           "world_map"]
