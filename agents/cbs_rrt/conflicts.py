"""Continuous conflict detection between timed paths.

Two robots are *in conflict* when their centres come closer than a threshold
``D`` (``2 * radius + margin``) at the same time. Paths are piecewise linear in
time (see :mod:`swarm_env_agents.cbs_rrt.timed_path`), so over the common time interval
of two paths, between consecutive breakpoints of either, both robots move in
straight lines at constant speeds and their relative position
``r(s) = r0 + s dr`` (``s in [0, 1]``) is linear: the first time ``|r| < D`` is
the smaller root of a quadratic, and the closest approach is the clamped
minimum of ``|r(s)|``. Nothing is checked only at sample times: two paths that
cross between samples are caught (tests/test_cbs_rrt.py has that case).

All pairs of ``N`` paths are screened first on a common time grid (a broad
phase): within a grid interval of length ``dt`` a robot moves at most
``vmax * dt``, so the distance of two robots there is at least
``(d_k + d_{k+1} - (v_i + v_j) dt) / 2`` (``d_k`` the distances at the interval's
ends). Only pairs whose bound drops below ``D`` somewhere get the exact check.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from swarm_env_agents.cbs_rrt.timed_path import TimedPath

__all__ = [
    "Conflict",
    "first_entry",
    "closest_approach",
    "pair_first_conflict",
    "pair_min_distance",
    "find_conflicts",
    "conflict_counts",
]


def first_entry(r0: np.ndarray, dr: np.ndarray, threshold: float | np.ndarray) -> np.ndarray:
    """For linear relative motions ``r(s) = r0 + s dr`` (``(M, 2)`` each, ``s in [0, 1]``),
    the smallest ``s`` with ``|r(s)| < threshold``, or ``inf`` where there is none.
    Grazing exactly at ``threshold`` is not an entry."""
    r0 = np.asarray(r0, dtype=np.float64).reshape(-1, 2)
    dr = np.asarray(dr, dtype=np.float64).reshape(-1, 2)
    D = np.asarray(threshold, dtype=np.float64)
    a = dr[:, 0] * dr[:, 0] + dr[:, 1] * dr[:, 1]
    b = 2.0 * (r0[:, 0] * dr[:, 0] + r0[:, 1] * dr[:, 1])
    c = r0[:, 0] * r0[:, 0] + r0[:, 1] * r0[:, 1] - D * D
    out = np.full(len(r0), np.inf)
    inside = c < 0.0
    out[inside] = 0.0
    disc = b * b - 4.0 * a * c
    moving = (~inside) & (a > 0.0) & (disc > 0.0) & (b < 0.0)
    if np.any(moving):
        s1 = (-b[moving] - np.sqrt(disc[moving])) / (2.0 * a[moving])
        s1 = np.where(s1 <= 1.0, np.maximum(s1, 0.0), np.inf)
        out[moving] = s1
    return out


def closest_approach(r0: np.ndarray, dr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Minimum of ``|r0 + s dr|`` over ``s in [0, 1]`` for each row: ``(distance, s)``."""
    r0 = np.asarray(r0, dtype=np.float64).reshape(-1, 2)
    dr = np.asarray(dr, dtype=np.float64).reshape(-1, 2)
    a = dr[:, 0] * dr[:, 0] + dr[:, 1] * dr[:, 1]
    b = r0[:, 0] * dr[:, 0] + r0[:, 1] * dr[:, 1]
    s = np.where(a > 0.0, np.clip(-b / np.where(a > 0.0, a, 1.0), 0.0, 1.0), 0.0)
    r = r0 + s[:, None] * dr
    return np.hypot(r[:, 0], r[:, 1]), s


def _relative(a: TimedPath, b: TimedPath, t_lo: float, t_hi: float) -> tuple[np.ndarray, np.ndarray]:
    """Merged breakpoints in ``[t_lo, t_hi]`` and the relative position ``a - b`` at each."""
    ts = np.concatenate([a.t, b.t])
    ts = ts[(ts > t_lo) & (ts < t_hi)]
    ts = np.unique(np.concatenate([[t_lo], ts, [t_hi]]))
    return ts, a.position_at(ts) - b.position_at(ts)


def pair_first_conflict(a: TimedPath, b: TimedPath, threshold: float, t_lo: float, t_hi: float) -> float | None:
    """First time in ``[t_lo, t_hi]`` at which ``a`` and ``b`` are closer than ``threshold``
    (exact for piecewise-linear paths), or ``None``."""
    if not t_hi > t_lo:
        r = a.position_at(t_lo) - b.position_at(t_lo)
        return float(t_lo) if math.hypot(r[0], r[1]) < threshold else None
    ts, r = _relative(a, b, t_lo, t_hi)
    s = first_entry(r[:-1], np.diff(r, axis=0), threshold)
    hit = np.flatnonzero(np.isfinite(s))
    if len(hit) == 0:
        return None
    k = int(hit[0])
    return float(ts[k] + s[k] * (ts[k + 1] - ts[k]))


def pair_min_distance(a: TimedPath, b: TimedPath, t_lo: float, t_hi: float) -> tuple[float, float]:
    """Closest approach of ``a`` and ``b`` over ``[t_lo, t_hi]``: ``(distance, time)``."""
    if not t_hi > t_lo:
        r = a.position_at(t_lo) - b.position_at(t_lo)
        return float(math.hypot(r[0], r[1])), float(t_lo)
    ts, r = _relative(a, b, t_lo, t_hi)
    d, s = closest_approach(r[:-1], np.diff(r, axis=0))
    k = int(np.argmin(d))
    return float(d[k]), float(ts[k] + s[k] * (ts[k + 1] - ts[k]))


@dataclass(frozen=True)
class Conflict:
    """Robots ``a < b`` come closer than ``threshold`` first at ``time`` (at ``pos_a``, ``pos_b``)."""

    a: int
    b: int
    time: float
    pos_a: tuple[float, float]
    pos_b: tuple[float, float]
    threshold: float

    @property
    def agents(self) -> tuple[int, int]:
        return (self.a, self.b)


def _thresholds(threshold: float | np.ndarray, n: int) -> np.ndarray:
    D = np.asarray(threshold, dtype=np.float64)
    if D.ndim == 0:
        return np.full((n, n), float(D))
    if D.shape != (n, n):
        raise ValueError(f"threshold must be a scalar or ({n}, {n}), got {D.shape}")
    return D


def find_conflicts(
    paths: Sequence[TimedPath],
    threshold: float | np.ndarray,
    t_lo: float,
    t_hi: float,
    *,
    grid_dt: float = 0.25,
    first_only: bool = False,
    skip: np.ndarray | None = None,
    until: np.ndarray | None = None,
) -> list[Conflict]:
    """Conflicts between every pair of ``paths`` over ``[t_lo, t_hi]``, earliest first.

    Args:
        threshold: conflict distance ``D`` (m), a scalar or a symmetric ``(N, N)`` matrix.
        grid_dt: time step of the broad phase (s); only affects speed, not results.
        first_only: return at most the earliest conflict (faster).
        skip: optional ``(N, N)`` boolean matrix; pairs marked ``True`` are ignored.
        until: optional ``(N,)`` times after which a robot's path no longer counts (a pair is
            checked until the earlier of its two).

    Returns one :class:`Conflict` per conflicting pair (its first entry time).
    """
    n = len(paths)
    if n < 2:
        return []
    D = _thresholds(threshold, n)
    if t_hi > t_lo:
        k = max(1, int(math.ceil((t_hi - t_lo) / grid_dt - 1e-9)))
        grid = np.linspace(t_lo, t_hi, k + 1)
    else:
        grid = np.array([t_lo, t_lo])
    dt = float(grid[1] - grid[0])
    P = np.empty((n, len(grid), 2))
    for i, p in enumerate(paths):
        P[i, :, 0] = np.interp(grid, p.t, p.pose[:, 0])
        P[i, :, 1] = np.interp(grid, p.t, p.pose[:, 1])
    vm = np.array([p.vmax for p in paths])
    ii, jj = np.triu_indices(n, 1)
    if skip is not None:
        keep = ~np.asarray(skip, dtype=bool)[ii, jj]
        ii, jj = ii[keep], jj[keep]
    if len(ii) == 0:
        return []
    diff = P[ii] - P[jj]
    d = np.sqrt(np.add.reduce(diff * diff, axis=2))  # (pairs, G)
    slack = (vm[ii] + vm[jj])[:, None] * dt
    lb = 0.5 * (d[:, :-1] + d[:, 1:] - slack)
    Dp = D[ii, jj]
    flag = lb < Dp[:, None]
    if until is not None:
        u = np.minimum(np.asarray(until, dtype=np.float64)[ii], np.asarray(until, dtype=np.float64)[jj])
        flag &= grid[None, :-1] < u[:, None]
    else:
        u = None
    cand = np.flatnonzero(flag.any(axis=1))
    if len(cand) == 0:
        return []
    first_flag = flag[cand].argmax(axis=1)
    last_flag = flag.shape[1] - 1 - flag[cand][:, ::-1].argmax(axis=1)
    order = np.argsort(first_flag, kind="stable")
    out: list[Conflict] = []
    best = math.inf
    for idx in order.tolist():
        c = int(cand[idx])
        lo = float(grid[first_flag[idx]])
        if first_only and lo >= best:
            break  # every later candidate starts after the best conflict found
        hi = float(grid[last_flag[idx] + 1])
        if u is not None:
            hi = min(hi, float(u[c]))
        i, j = int(ii[c]), int(jj[c])
        tc = pair_first_conflict(paths[i], paths[j], float(Dp[c]), lo, hi)
        if tc is None:
            continue
        pa = paths[i].position_at(tc)
        pb = paths[j].position_at(tc)
        conflict = Conflict(i, j, tc, (float(pa[0]), float(pa[1])), (float(pb[0]), float(pb[1])), float(Dp[c]))
        if first_only:
            if tc < best:
                best = tc
                out = [conflict]
        else:
            out.append(conflict)
    out.sort(key=lambda c: (c.time, c.a, c.b))
    return out


def conflict_counts(conflicts: Sequence[Conflict], n: int) -> np.ndarray:
    """``(n,)`` number of conflicting pairs each robot is part of."""
    counts = np.zeros(n, dtype=np.int64)
    for c in conflicts:
        counts[c.a] += 1
        counts[c.b] += 1
    return counts
