"""Holding a reached formation by planning it: joint space-time paths to the end (issue 12 item 1).

With a virtual leader the slot targets are a function of time and the map only
(:func:`swarm_env.geometry.formation.virtual_slot_trajectory`), so once the swarm has reached a formation
the whole rest of it is known in advance. :class:`CBSRRTExpert` (``hold_plan``, on by default)
then plans where every follower should be at every remaining step (again only if a robot falls
0.5 m off its path), and tracks that:

1. **One follower** (:func:`point_dp`): a point moving at most ``max_speed * dt`` per step on a
   lattice of pitch ``h`` whose centre keeps ``floor`` from obstacles and walls and ``separation``
   from robots already planned, maximising the steps (optionally weighted, ``gain``) it spends
   within the settle tolerance of its slot. Exact by dynamic programming backwards in time
   (``V_k(p) = gain_k held_k(p) + max_{|q - p| <= v dt} V_{k+1}(q)``; :func:`_dp_step` is the
   compiled sweep, O(R) per cell for a reach of R cells).
2. **The formation** (:func:`joint_paths`): the followers one after another, each avoiding the
   ones before it (prioritised planning), then rounds of best responses: each follower plans
   again against all the others, a step counting ``1 + bonus`` where every other follower is
   within tolerance in it, and its new path is kept only if the steps with *every* follower within
   tolerance grow. What counts for the hold fraction is the whole formation in the same step.
3. **Tracking** (:class:`PlanTracker`): each step, robot by robot, the first twist of the best
   two-twist sequence ``(u1, u2, u2, ...)`` over ``horizon`` steps on a grid of twists, rolled out
   with the env's own substep integration (:func:`substep_rollout`), scoring the distance to the
   plan, a miss of the slot where the plan holds it, an obstacle hit (prohibitive) and coming
   closer than the plans' separation to another robot (heavy; touching one over the next step is
   prohibitive: robots decided before this one where their chosen twists take them, the others on
   their plans, or where they are if they are off them). The next step's first physics substep is
   checked too: it still moves with this step's last velocity, whatever is commanded then (without
   it, 3 of 60 random worlds at dt = 0.5 s had a robot-robot contact).

The margins are the contact-free ones of ``benchmarks/hold_bound.py`` (which shares this module):
``floor = r + 0.03`` and ``separation = 2 r + 0.06`` (``0.03``: a 0.25 m chord between two lattice
points that keep this much beyond ``r`` never comes within ``r`` of a convex obstacle); the expert
adds 0.01 and 0.02 m for the tracker's errors. Keeping the CBS shield's 0.05 m on top costs 3-5 %
of the hold (``hold_bound.py``'s ``j 0.33/0.61`` column): the plan's margins replace the shield
while it holds.

Work: the expert's plan of ``paper_cbs_switch``'s grid (180 steps, 8 followers, one round of best
responses, each follower within 2.5 m of its slot: ``reach``) takes about 0.7 s of CPU; tracking,
with branch and bound over the 14,641 twist sequences per robot, about 10 ms per step.

Deterministic: no randomness; ties broken by fixed orders.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from swarm_env.geometry.paths import PolylinePath, virtual_leader
from swarm_env.geometry.static_map import StaticMap
from swarm_env.kernel_cache import njit
from swarm_env.scenario import RobotSpec, Scenario, WorldSpec
from swarm_env_agents.cbs_rrt.distance_field import DistanceField
from swarm_env_agents.cbs_rrt.kernels import _as_field, _clear1

__all__ = [
    "CHORD_ALLOWANCE",
    "Lattice",
    "PlanTracker",
    "PointDP",
    "PointModel",
    "half_widths",
    "joint_paths",
    "point_dp",
    "substep_rollout",
    "virtual_leader_done_step",
]

NEG = np.int16(-30000)  # an unreachable lattice cell's value
CHORD_ALLOWANCE = 0.03  # m: a 0.25 m chord between points this much beyond r never comes within r of a convex obstacle
GRID_MARGIN = 1.6  # m around a follower's slots that its lattice covers
_OFF_PLAN = 0.15  # m: the tracker expects a robot farther than this from its plan to stay where it is
_CONTACT_GAP = 0.005  # m: robot surfaces closer than this over the next step exclude a twist sequence


class PointModel(NamedTuple):
    """A point follower on a lattice (:func:`point_dp`, :func:`joint_paths`): the lattice pitch ``h``
    (m), the settle tolerance ``tol`` (m), how far it moves per step ``step`` (m), the smallest
    clearance ``floor`` of its centre to obstacles and walls (m) and the ``separation`` it keeps
    from the centres of robots already planned (m)."""

    h: float
    tol: float
    step: float
    floor: float
    separation: float


class _DPGrid(NamedTuple):
    """What every :func:`_dp_step` of one :func:`point_dp` reads: the lattice's ``free`` cells ``(H, W)``,
    the disc footprint's row ``half_widths``, the lattice origin ``(x0, y0)`` and pitch ``h``, the
    squared separation from other robots ``sep2`` and squared tolerance ``tol2``, and the ``reach``
    (cells) round the slot that is swept."""

    free: np.ndarray
    half_widths: np.ndarray
    x0: float
    y0: float
    h: float
    sep2: float
    tol2: float
    reach: int


@njit()
def _dp_step(vnext, grid, others, sx, sy, gain, out, rowmax):  # pragma: no cover - compiled
    """``out[y, x] = gain held(y, x) + max over the disc footprint of vnext`` on free cells within
    ``grid.reach`` cells of the slot ``(sx, sy)`` (a square), else NEG; a cell closer than
    ``sqrt(grid.sep2)`` to one of ``others (M, 2)`` (robots at this step) is not free (``grid``: a
    :class:`_DPGrid`).

    The disc footprint is row ``dy`` (``-R..R``) spanning ``|dx| <= half_widths[dy + R]``; the max
    over a row span is built up width by width (``max over [x-w-1, x+w+1] = max(rowmax_w[x-1],
    rowmax_w[x+1])``), so the cost is O(R) per cell, not O(R^2). Only the square and the footprint's
    reach round it are swept: the max of width ``w`` is exact ``w`` cells inside the swept box."""
    free, half_widths, gx0, gy0, h = grid.free, grid.half_widths, grid.x0, grid.y0, grid.h
    sep2, tol2, reach = grid.sep2, grid.tol2, grid.reach
    H, W = vnext.shape
    R = (half_widths.shape[0] - 1) // 2
    wmax = 0
    for j in range(half_widths.shape[0]):
        if half_widths[j] > wmax:
            wmax = half_widths[j]
    neg = np.int16(-30000)
    out[:, :] = neg
    cy = int(round((sy - gy0) / h))
    cx = int(round((sx - gx0) / h))
    y_lo, y_hi = max(cy - reach, 0), min(cy + reach, H - 1)
    x_lo, x_hi = max(cx - reach, 0), min(cx + reach, W - 1)
    if y_lo > y_hi or x_lo > x_hi:
        return
    by_lo, by_hi = max(y_lo - R, 0), min(y_hi + R, H - 1)
    bx_lo, bx_hi = max(x_lo - wmax, 0), min(x_hi + wmax, W - 1)
    for y in range(by_lo, by_hi + 1):
        for x in range(bx_lo, bx_hi + 1):
            rowmax[0, y, x] = vnext[y, x]
    for w in range(1, wmax + 1):
        for y in range(by_lo, by_hi + 1):
            for x in range(bx_lo, bx_hi + 1):
                m = rowmax[w - 1, y, x]
                if x > bx_lo and rowmax[w - 1, y, x - 1] > m:
                    m = rowmax[w - 1, y, x - 1]
                if x < bx_hi and rowmax[w - 1, y, x + 1] > m:
                    m = rowmax[w - 1, y, x + 1]
                rowmax[w, y, x] = m
    for y in range(y_lo, y_hi + 1):
        py = gy0 + y * h
        for x in range(x_lo, x_hi + 1):
            if not free[y, x]:
                continue
            px = gx0 + x * h
            blocked = False
            for q in range(others.shape[0]):
                if (px - others[q, 0]) ** 2 + (py - others[q, 1]) ** 2 < sep2:
                    blocked = True
                    break
            if blocked:
                continue
            best = neg
            for j in range(2 * R + 1):
                yy = y + j - R
                if yy < 0 or yy >= H:
                    continue
                v = rowmax[half_widths[j], yy, x]
                if v > best:
                    best = v
            if best == neg:
                continue
            held = gain if (px - sx) ** 2 + (py - sy) ** 2 <= tol2 else 0
            out[y, x] = best + held


@njit()
def _walk(values, j0, cy, cx, half_widths, x0, y0, h, slots):  # pragma: no cover - compiled
    """Cells ``(T, 2)`` (row, column) of the path down the DP ``values`` from cell ``(cy, cx)`` at
    index ``j0``: each step the reachable cell of largest value, ties to the one nearest the next
    slot (``slots[t]``: the slot at index ``j0 + t``), the first of equals in row-major order; a cell
    with nowhere to go (boxed in: a robot started inside the margins) stays."""
    T = values.shape[0] - j0
    H, W = values.shape[1], values.shape[2]
    R = (half_widths.shape[0] - 1) // 2
    out = np.empty((T, 2), dtype=np.int64)
    out[0, 0], out[0, 1] = cy, cx
    for t in range(1, T):
        nxt = values[j0 + t]
        sx, sy = slots[t, 0], slots[t, 1]
        best_v = -(10**9)
        best_d = np.inf
        by, bx = cy, cx
        for j in range(2 * R + 1):
            yy = cy + j - R
            if yy < 0 or yy >= H:
                continue
            w = half_widths[j]
            for xx in range(max(cx - w, 0), min(cx + w, W - 1) + 1):
                v = np.int64(nxt[yy, xx])
                d = math.hypot(x0 + xx * h - sx, y0 + yy * h - sy)
                if v > best_v or (v == best_v and d < best_d):
                    best_v, best_d, by, bx = v, d, yy, xx
        if best_v > -30000:
            cy, cx = by, bx
        out[t, 0], out[t, 1] = cy, cx
    return out


@dataclass
class Lattice:
    """One follower's lattice: cell ``(y, x)`` is the point ``(x0 + x h, y0 + y h)``."""

    x0: float
    y0: float
    h: float
    clearance: np.ndarray  # (H, W) static.distance of the cell centres (walls included)

    @staticmethod
    def extent(pts: np.ndarray, h: float) -> tuple[np.ndarray, int, int]:
        """``(lower corner, nx, ny)`` of the lattice covering ``pts (..., 2)`` and ``GRID_MARGIN`` round them."""
        pts = np.asarray(pts, dtype=np.float64).reshape(-1, 2)
        lo = pts.min(axis=0) - GRID_MARGIN
        hi = pts.max(axis=0) + GRID_MARGIN
        return lo, int(math.ceil((hi[0] - lo[0]) / h)) + 1, int(math.ceil((hi[1] - lo[1]) / h)) + 1

    @classmethod
    def around(cls, static: StaticMap, pts: np.ndarray, h: float) -> Lattice:
        """The lattice covering ``pts (..., 2)`` and ``GRID_MARGIN`` round them."""
        lo, nx, ny = cls.extent(pts, h)
        xs = lo[0] + h * np.arange(nx)
        ys = lo[1] + h * np.arange(ny)
        grid = np.stack(np.meshgrid(xs, ys), axis=-1)
        return cls(float(lo[0]), float(lo[1]), h, static.distance(grid.reshape(-1, 2)).reshape(ny, nx))

    def point(self, cell: tuple[int, int]) -> np.ndarray:
        return np.array([self.x0 + cell[1] * self.h, self.y0 + cell[0] * self.h])

    def nearest(self, p: np.ndarray) -> tuple[int, int]:
        return int(round((p[1] - self.y0) / self.h)), int(round((p[0] - self.x0) / self.h))


def half_widths(radius_cells: float) -> np.ndarray:
    """Row half-widths of the lattice disc of ``radius_cells`` (rows ``-R..R``)."""
    R = int(math.floor(radius_cells + 1e-9))
    return np.array([int(math.floor(math.sqrt(max(radius_cells**2 - dy * dy, 0.0)) + 1e-9)) for dy in range(-R, R + 1)],
                    dtype=np.int64)


@dataclass
class PointDP:
    """The backward values of one follower on one lattice (``values[k - k0]`` for step ``k``)."""

    lattice: Lattice
    free: np.ndarray
    half_widths: np.ndarray
    k0: int
    values: np.ndarray  # (k_end - k0 + 1, H, W) int16: most (gain-weighted) steps within tolerance from k on
    tol: float
    step: float
    slots: np.ndarray  # (K+1, 2) this follower's slots

    def start_cell(self, k: int, start: np.ndarray | None = None) -> tuple[int, int]:
        """The free lattice cell nearest to ``start`` (default: the slot at step ``k``)."""
        p = self.slots[k] if start is None else np.asarray(start, dtype=np.float64)
        cell = self.lattice.nearest(p)
        H, W = self.free.shape
        if 0 <= cell[0] < H and 0 <= cell[1] < W and self.free[cell]:
            return cell
        ys, xs = np.nonzero(self.free)
        pts = np.column_stack([self.lattice.x0 + xs * self.lattice.h, self.lattice.y0 + ys * self.lattice.h])
        j = int(np.argmin(np.hypot(*(pts - p).T)))
        return int(ys[j]), int(xs[j])

    def value(self, k: int) -> int:
        """Most steps ``k..k_end`` within tolerance, starting on the slot at ``k``."""
        return int(self.values[k - self.k0][self.start_cell(k)])

    def path(self, k: int, start: np.ndarray | None = None) -> np.ndarray:
        """An optimal lattice path from ``start`` (default: the slot) at step ``k`` to ``k_end``
        (``(k_end - k + 1, 2)``): each step the reachable cell of largest value, ties to the one
        nearest the next slot."""
        cell = self.start_cell(k, start)
        first = self.values[k - self.k0]
        if first[cell] <= NEG and start is None:  # the slot is blocked (another robot's disc): start within tolerance
            H, W = first.shape
            xs = self.lattice.x0 + self.lattice.h * np.arange(W)
            ys = self.lattice.y0 + self.lattice.h * np.arange(H)
            d2 = (xs[None, :] - self.slots[k, 0]) ** 2 + (ys[:, None] - self.slots[k, 1]) ** 2
            score = np.where(d2 <= self.tol**2, first.astype(np.int64), -(10**9))
            cell = tuple(int(c) for c in np.unravel_index(int(np.argmax(score)), score.shape))  # type: ignore[assignment]
        lat = self.lattice
        cells = _walk(self.values, k - self.k0, cell[0], cell[1], self.half_widths, lat.x0, lat.y0, lat.h,
                      np.ascontiguousarray(self.slots[k : self.k0 + len(self.values)], dtype=np.float64))
        return np.column_stack([lat.x0 + cells[:, 1] * lat.h, lat.y0 + cells[:, 0] * lat.h])


def point_dp(static: StaticMap, slots: np.ndarray, k0: int, k_end: int, model: PointModel,
             others: np.ndarray | None = None, gain: np.ndarray | None = None, lattice: Lattice | None = None,
             reach: float | None = None) -> PointDP:
    """Solve one point follower's DP from step ``k0`` to ``k_end`` (see the module docstring).

    ``slots (K+1, 2)``: its slot at every step; ``model``: the lattice pitch, the settle tolerance,
    how far it moves per step and the margins it keeps (:class:`PointModel`);
    ``others (k_end - k0 + 1, M, 2)``: robots already planned, whose centres it keeps
    ``model.separation`` from at every step; ``gain (k_end - k0 + 1,)``: what a step within tolerance is
    worth (ints >= 1 summing to <= 30000, default 1: the values count steps); ``lattice``: reuse
    one (it depends on ``slots[k0 : k_end + 1]`` and ``h`` only); ``reach``: only points within
    this of the slot in each coordinate are considered (m; default: the whole lattice). The values
    are then those of a follower that never strays farther: much less work on a long course."""
    h, tol, step, floor, separation = model
    n = k_end - k0 + 1
    lat = Lattice.around(static, slots[k0 : k_end + 1], h) if lattice is None else lattice
    free = lat.clearance >= floor
    g = np.ones(n, dtype=np.int64) if gain is None else np.asarray(gain, dtype=np.int64)
    if len(g) != n or g.min() < 1 or g.sum() > 30000:  # int16 values
        raise ValueError(f"point_dp: gain must be {n} ints >= 1 summing to <= 30000")
    hw = half_widths(step / h)
    H, W = free.shape
    values = np.empty((n, H, W), dtype=np.int16)
    rowmax = np.empty((int(hw.max()) + 1, H, W), dtype=np.int16)
    mates = np.zeros((n, 0, 2)) if others is None else np.ascontiguousarray(others, dtype=np.float64)
    cells = max(H, W) if reach is None else int(math.ceil(reach / h))
    grid = _DPGrid(free, hw, float(lat.x0), float(lat.y0), float(h), float(separation * separation), float(tol**2),
                   int(cells))
    after_end = np.zeros((H, W), dtype=np.int16)  # the last step: only its own hold counts
    for k in range(k_end, k0 - 1, -1):
        vnext = after_end if k == k_end else values[k + 1 - k0]
        _dp_step(vnext, grid, mates[k - k0], float(slots[k, 0]), float(slots[k, 1]), int(g[k - k0]), values[k - k0],
                 rowmax)
    return PointDP(lat, free, hw, k0, values, tol, step, slots)


def joint_paths(static: StaticMap, slots: np.ndarray, k_s: int, k_end: int, model: PointModel,
                starts: np.ndarray | None = None, rounds: int = 3, bonus: int = 16,
                reach: float | None = None) -> np.ndarray:
    """Point paths ``(k_end - k_s + 1, N, 2)`` from ``starts (N, 2)`` (default: the slots) at step
    ``k_s`` of followers ``model`` (:class:`PointModel`: they keep ``model.floor`` from obstacles and
    ``model.separation`` from each other) that hold the *whole* formation (``slots (K+1, N, 2)``) in
    as many steps as this finds: prioritised in index order, then up to ``rounds`` rounds of best
    responses (module docstring). Achieved by real points (a lower bound of what followers keeping
    those margins can hold). ``reach``: as in :func:`point_dp`, widened to take in the starts (with
    1 m to spare)."""
    h, tol = model.h, model.tol
    n = slots.shape[1]
    window = slots[k_s : k_end + 1]
    ends = window[:1] if starts is None else np.asarray(starts, dtype=np.float64)[None]
    lattices = [Lattice.around(static, np.vstack([window[:, i], ends[:, i]]), h) for i in range(n)]
    if reach is not None and starts is not None:
        reach = max(reach, float(np.abs(ends[0] - window[0]).max()) + 1.0)

    def plan(i: int, others: np.ndarray, gain: np.ndarray | None = None) -> np.ndarray:
        dp = point_dp(static, slots[:, i], k_s, k_end, model, others, gain, lattices[i], reach)
        return dp.path(k_s, None if starts is None else starts[i])

    paths = np.full((k_end - k_s + 1, n, 2), np.nan)
    for i in range(n):
        paths[:, i] = plan(i, paths[:, :i])
    within = np.hypot(*(paths - window).transpose(2, 0, 1)) <= tol  # (steps, N)
    score = int(within.all(axis=1).sum())
    for _ in range(rounds):
        gained = False
        for i in range(n):
            rest = [j for j in range(n) if j != i]
            gain = 1 + bonus * within[:, rest].all(axis=1).astype(np.int64)
            path = plan(i, paths[:, rest], gain)
            mine = np.hypot(*(path - window[:, i]).T) <= tol
            new = int((within[:, rest].all(axis=1) & mine).sum())
            if new > score:
                paths[:, i], within[:, i], score, gained = path, mine, new, True
        if not gained:
            break
    return paths


def substep_rollout(state: np.ndarray, cmds: np.ndarray, substeps: int, sub_dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Advance poses ``state (..., 6) = (x, y, a, vx, vy, w)`` by one env step with ``cmds (..., 2)``:
    in each substep the position moves with the velocity of the previous substep, then the velocity
    is set from the command along the new heading (pymunk integrates positions before the velocity
    callback runs). Returns the new state and the positions after each substep ``(substeps, ..., 2)``."""
    x, y, a, vx, vy, w = (state[..., j].copy() for j in range(6))
    v_cmd, w_cmd = cmds[..., 0], cmds[..., 1]
    pts = []
    for _ in range(substeps):
        x = x + vx * sub_dt
        y = y + vy * sub_dt
        a = a + w * sub_dt
        vx = v_cmd * np.cos(a)
        vy = v_cmd * np.sin(a)
        w = w_cmd + 0.0 * a
        pts.append(np.stack([x, y], axis=-1))
    return np.stack([x, y, a, vx, vy, w], axis=-1), np.stack(pts)


_jit_inline = njit(nogil=True, error_model="numpy", inline="always")


@_jit_inline
def _substep(x, y, ang, vx, vy, w, v_cmd, w_cmd, sub_dt):  # pragma: no cover - compiled
    """One physics substep of :func:`substep_rollout`: move with the last velocity, then set it from the command."""
    x += vx * sub_dt
    y += vy * sub_dt
    ang += w * sub_dt
    return x, y, ang, v_cmd * math.cos(ang), v_cmd * math.sin(ang), w_cmd


@_jit_inline
def _nearest(x, y, pts):  # pragma: no cover - compiled
    """Distance from ``(x, y)`` to the nearest of ``pts (M, 2)`` (``inf`` if none)."""
    gap = np.inf
    for j in range(pts.shape[0]):
        d = math.hypot(x - pts[j, 0], y - pts[j, 1])
        if d < gap:
            gap = d
    return gap


@_jit_inline
def _off_course(x, y, ref, slot, slot_counts, tol, ref_weight):  # pragma: no cover - compiled
    """Cost of ending a step at ``(x, y)``: metres off the plan's point ``ref``, and beyond ``tol - 0.02``
    of the slot where the plan holds it (``slot_counts``)."""
    c = ref_weight * math.hypot(x - ref[0], y - ref[1])
    if slot_counts:
        c += 100.0 * max(math.hypot(x - slot[0], y - slot[1]) - (tol - 0.02), 0.0)
    return c


class _Tracking(NamedTuple):
    """What :func:`_best_sequence` reads for every robot of every step (built once by :class:`PlanTracker`):
    the twists of the first step ``first (A, 2)`` and of the rest ``later (B, 2)``, the env's physics
    ``substeps`` of ``sub_dt`` seconds, the ``separation`` the plans keep (robot centres closer are
    penalised), ``contact`` (centres closer over the next step exclude a sequence), ``floor`` (the
    smallest clearance of a centre by the field), the settle tolerance ``tol`` and the cost per metre
    off the plan ``ref_weight``."""

    first: np.ndarray
    later: np.ndarray
    substeps: int
    sub_dt: float
    separation: float
    contact: float
    floor: float
    tol: float
    ref_weight: float


@njit(nogil=True, error_model="numpy")
def _first_steps(s0, plan, slots, in_tol, others, trk, field):  # pragma: no cover - compiled
    """The first step of every first twist of ``trk`` (:class:`_Tracking`) from ``s0`` (``field``: a
    :class:`.kernels.Field`): its cost
    (:func:`_best_sequence`), the state after it ``(A, 6)`` and the positions over its substeps and
    the next step's first one ``(substeps + 1, A, 2)``."""
    first, substeps, sub_dt = trk.first, trk.substeps, trk.sub_dt
    A = first.shape[0]
    subs = np.empty((substeps + 1, A, 2))
    head = np.zeros(A)
    after = np.empty((A, 6))
    for a in range(A):
        x, y, ang, vx, vy, w = s0[0], s0[1], s0[2], s0[3], s0[4], s0[5]
        hit = False
        gap = np.inf
        for m in range(substeps + 1):
            if m < substeps:
                x, y, ang, vx, vy, w = _substep(x, y, ang, vx, vy, w, first[a, 0], first[a, 1], sub_dt)
                px, py = x, y
            else:
                # The next step's first substep still moves with this step's last velocity: whatever is
                # commanded then, the robot gets there.
                px, py = x + vx * sub_dt, y + vy * sub_dt
            subs[m, a, 0] = px
            subs[m, a, 1] = py
            if _clear1(px, py, field) < trk.floor:
                hit = True
            gap = min(gap, _nearest(px, py, others[m]))
        c = _off_course(x, y, plan[1], slots[1], in_tol[1], trk.tol, trk.ref_weight)
        if hit:
            c += 1e6
        if gap < trk.separation:
            c += 1e4 * (trk.separation - gap)
        if gap < trk.contact:  # touching another robot over the next step: as bad as an obstacle
            c += 1e6
        head[a] = c
        after[a, 0], after[a, 1], after[a, 2], after[a, 3], after[a, 4], after[a, 5] = x, y, ang, vx, vy, w
    return head, after, subs


@njit(nogil=True, error_model="numpy")
def _best_sequence(s0, plan, slots, in_tol, others, mates, trk, field):  # pragma: no cover - compiled
    """The cheapest twist sequence ``(first[a], later[b], later[b], ...)`` of ``trk`` (:class:`_Tracking`)
    for one robot at ``s0 = (x, y, angle, vx, vy, w)`` tracking ``plan`` towards ``slots`` (``in_tol``:
    the plan holds the slot there) among ``others`` (over the first step's substeps) and ``mates``
    (their plans), with obstacles from ``field`` (``DistanceField.kernel``). :meth:`PlanTracker.twists`
    gives the cost. Returns its index ``a * B + b`` (the first of equals), and the positions over the
    first step's substeps for each first twist and where the next step's first substep takes it
    whatever is commanded then (``(substeps + 1, A, 2)``).

    Branch and bound: the costs after the first step are >= 0, so first twists are tried in the
    order of their first step's cost, and none is tried further once that alone exceeds the best
    total (nor a sequence once its partial sum does). Same index as scoring every sequence."""
    field = _as_field(field)  # (DistanceField.kernel: a plain tuple)
    later, substeps, sub_dt, floor = trk.later, trk.substeps, trk.sub_dt, trk.floor
    B = later.shape[0]
    H = plan.shape[0] - 1
    head, after, subs = _first_steps(s0, plan, slots, in_tol, others, trk, field)
    order = np.argsort(head, kind="mergesort")
    best = np.inf
    best_index = -1
    for a in order:
        if head[a] > best:
            break
        for b in range(B):
            x, y, ang, vx, vy, w = after[a, 0], after[a, 1], after[a, 2], after[a, 3], after[a, 4], after[a, 5]
            c = head[a]
            for look in range(2, H + 1):
                hit = False
                for _m in range(substeps):
                    x, y, ang, vx, vy, w = _substep(x, y, ang, vx, vy, w, later[b, 0], later[b, 1], sub_dt)
                    if _clear1(x, y, field) < floor:
                        hit = True
                step_cost = _off_course(x, y, plan[look], slots[look], in_tol[look], trk.tol, trk.ref_weight)
                gap = _nearest(x, y, mates[look])
                if gap < trk.separation:
                    step_cost += 1e4 * (trk.separation - gap)
                c += step_cost / look
                if hit:
                    c += 1e6
                if c > best:
                    break
            k = a * B + b
            if c < best or (c == best and k < best_index):
                best = c
                best_index = k
    return best_index, subs


class PlanTracker:
    """Twists that make followers track planned point paths (see the module docstring).

    Args:
        field: the static map's distance field.
        robots: the followers (their radius, max_speed and max_turn_rate).
        world: the env's step ``dt``, physics ``substeps`` and settle tolerance.
        separation: robot centres closer than this are penalised (m).
        clearance: robot surfaces closer than this to an obstacle (by the field's bilinear
            clearance) are excluded (m).
        horizon: steps looked ahead; grid: twists per axis of the first step (``grid**2``
            twists), later_grid: of the twist held after it (``grid**2 later_grid**2`` sequences
            in all); ref_weight: cost per metre off the plan (the slot miss costs 100 per
            metre beyond ``tolerance - 0.02``, where the plan is within tolerance).
    """

    def __init__(self, field: DistanceField, robots: RobotSpec, world: WorldSpec, separation: float,
                 clearance: float = 0.01, horizon: int = 5, grid: int = 11, later_grid: int = 11,
                 ref_weight: float = 40.0) -> None:
        if horizon < 1 or grid < 2 or later_grid < 2:
            raise ValueError(f"PlanTracker: horizon >= 1 and grids >= 2 expected, got {horizon}, {grid}, {later_grid}")
        self.field = field
        self.radius = float(robots.radius)
        self.substeps = int(world.substeps)
        self.sub_dt = float(world.dt) / self.substeps
        self.tolerance = float(world.settle_tolerance)
        self.separation = float(separation)
        self.clearance = float(clearance)
        self.horizon = int(horizon)
        self.ref_weight = float(ref_weight)

        def twist_grid(k: int) -> np.ndarray:
            vs = np.linspace(-robots.max_speed, robots.max_speed, k)
            ws = np.linspace(-robots.max_turn_rate, robots.max_turn_rate, k)
            return np.ascontiguousarray(np.stack(np.meshgrid(vs, ws, indexing="ij"), axis=-1).reshape(-1, 2))

        self._twists = twist_grid(grid)
        self._later = twist_grid(later_grid)
        self._tracking = _Tracking(self._twists, self._later, self.substeps, self.sub_dt, self.separation,
                                   2.0 * self.radius + _CONTACT_GAP, self.radius + self.clearance, self.tolerance,
                                   self.ref_weight)

    def twists(self, state: np.ndarray, plan: np.ndarray, slots: np.ndarray) -> np.ndarray:
        """``(N, 2)`` twists for robots at ``state (N, 6) = (x, y, a, vx, vy, w)`` tracking ``plan
        (horizon + 1, N, 2)`` (row 0: now) towards ``slots (horizon + 1, N, 2)``: for each robot the
        first twist of its cheapest sequence. Robots decide in index order; over the first step a
        robot keeps clear of where the ones before it go (touching one excludes a sequence) and of
        the others' plans (of where they are, for those more than 0.15 m off their plans)."""
        n = len(state)
        if plan.shape != (self.horizon + 1, n, 2) or slots.shape != plan.shape:
            raise ValueError(f"PlanTracker.twists: plan and slots of shape {(self.horizon + 1, n, 2)} expected, "
                             f"got {plan.shape} and {slots.shape}")
        out = np.zeros((n, 2))
        # Over the next step: the robots not decided yet on their plans, but one that is off its plan
        # (it could not follow it) where it is; decided robots' substeps replace these.
        ahead = np.where((np.hypot(*(state[:, :2] - plan[0]).T) > _OFF_PLAN)[:, None], state[:, :2], plan[1])
        others = np.repeat(ahead[None], self.substeps + 1, axis=0)  # (S + 1, N, 2): the substeps and the lagged one
        in_tol = np.hypot(*(plan - slots).transpose(2, 0, 1)) <= self.tolerance  # (H+1, N)
        state = np.ascontiguousarray(state, dtype=np.float64)
        for i in range(n):
            rest = [j for j in range(n) if j != i]
            best, subs = _best_sequence(
                state[i], np.ascontiguousarray(plan[:, i]), np.ascontiguousarray(slots[:, i]), in_tol[:, i],
                np.ascontiguousarray(others[:, rest]), np.ascontiguousarray(plan[:, rest]), self._tracking,
                self.field.kernel,
            )
            a = int(best) // len(self._later)
            out[i] = self._twists[a]
            others[:, i] = subs[:, a]
        return out


def virtual_leader_done_step(scn: Scenario, steps: int) -> int:
    """The first step ``<= steps`` at which a virtual leader has finished its path (``steps`` if
    it has not by then)."""
    line = PolylinePath(scn.leader.path)
    for k in range(steps + 1):
        if virtual_leader(line, scn.leader.speed, k * scn.world.dt, scn.leader.start_delay)[2]:
            return k
    return steps
