"""The formation slots of a world, compiled with numba: the virtual leader's pose, the slot targets
around the leader, and the screen that tells whether any slot needs projecting out of an obstacle.

Every control step :class:`~swarm_env.sim.world.World` moves the leader, places the slots around it
(:func:`swarm_env.geometry.formation.slot_targets`) and moves the slots that lie too close to an obstacle
(:meth:`swarm_env.geometry.static_map.StaticMap.project_free`). Done with small numpy arrays and Python floats
that was about a quarter of the physics step; nearly always no slot needs projecting, and the
projection's own first screen (:meth:`~swarm_env.geometry.static_map.StaticMap._project_fast`) says so. This
module runs the pose, the slot placement and that screen in one kernel call; only when the screen
finds a suspect slot does the world hand the targets to ``project_free`` (which then returns what
it returns for them anyway: the screen only decides whether to ask it).

Same bits as the references (``tests/test_slot_kernel.py``, and whole episodes in
``tests/test_step_digests.py``): :func:`virtual_slots` is :func:`swarm_env.geometry.paths.virtual_leader`
followed by :func:`~swarm_env.geometry.formation.slot_targets` with the same operations in the same order
(Python's ``min``/``max`` as explicit comparisons, ``bisect_right`` as a linear scan, the C
library's ``cos``/``sin`` as Python's ``math`` calls them); the screen evaluates the very
comparisons of ``_project_fast``'s screen (:meth:`~swarm_env.geometry.static_map.StaticMap.slot_screen`).

Kernels take one world's arrays; the inner functions (``_virtual_pose``, ``_place_slots``,
``_screen``) are what a batched engine would loop over with a leading world axis.
"""

from __future__ import annotations

import math

import numpy as np

from swarm_env.geometry.paths import PolylinePath
from swarm_env.kernel_cache import njit

_jit = njit(nogil=True, error_model="numpy")


def pack_path(path: PolylinePath) -> np.ndarray:
    """``(M, 6)`` rows ``(x, y, cumulative, ux, uy, heading)`` of ``path``'s vertices; the segment
    columns of row ``i`` describe segment ``i`` (the last row's repeat the last segment's)."""
    pts = path.points
    m = len(pts)
    seg = len(path.headings)
    out = np.empty((m, 6), dtype=np.float64)
    out[:, 0:2] = pts
    out[:, 2] = path.cumulative
    unit = path._unit
    out[:seg, 3:5] = unit
    out[:seg, 5] = path.headings
    out[seg:, 3:5] = unit[seg - 1]
    out[seg:, 5] = path.headings[seg - 1]
    return out


@_jit
def _segment(path, s):  # pragma: no cover - compiled
    """PolylinePath._segment: ``bisect_right(cumulative, s) - 1`` clipped to the segments."""
    m = path.shape[0]
    right = 0
    while right < m and path[right, 2] <= s:
        right += 1
    i = right - 1
    last = m - 2
    if i < 0:
        i = 0
    elif i > last:
        i = last
    return i


@_jit
def _virtual_pose(path, length, speed, t, delay, out):  # pragma: no cover - compiled
    """:func:`swarm_env.geometry.paths.virtual_leader` into ``out`` = ``(x, y, heading, vx, vy, done)``."""
    moved = t - delay
    if 0.0 > moved:  # max(moved, 0.0), as Python picks
        moved = 0.0
    moved = moved * speed
    done = moved >= length
    s = moved
    if length < s:  # min(moved, length)
        s = length
    # point_at(s) and heading_at(s) clip s to [0, length] again (no-ops, kept for the same bits)
    if 0.0 > s:
        s = 0.0
    if length < s:
        s = length
    i = _segment(path, s)
    ds = s - path[i, 2]
    x = path[i, 0] + ds * path[i, 3]
    y = path[i, 1] + ds * path[i, 4]
    h = path[i, 5]
    moving = (not done) and t >= delay and speed > 0.0
    v = speed if moving else 0.0
    out[0] = x
    out[1] = y
    out[2] = h
    out[3] = v * math.cos(h)
    out[4] = v * math.sin(h)
    out[5] = 1.0 if done else 0.0


@_jit
def _place_slots(px, py, heading, offsets, out):  # pragma: no cover - compiled
    """formation.slot_targets without the projection: ``(x, y) + R(heading) offset``."""
    c = math.cos(heading)
    s = math.sin(heading)
    for k in range(offsets.shape[0]):
        ox = offsets[k, 0]
        oy = offsets[k, 1]
        out[k, 0] = px + c * ox - s * oy
        out[k, 1] = py + s * ox + c * oy


@_jit
def _screen(pts, screen, size_reach):  # pragma: no cover - compiled
    """``True`` when ``project_free`` leaves every point of ``pts`` unchanged by its first screen:
    finite, at least ``reach`` from the walls and outside every obstacle's screening disc."""
    w = size_reach[0]
    h = size_reach[1]
    reach = size_reach[2]
    for k in range(pts.shape[0]):
        x = pts[k, 0]
        y = pts[k, 1]
        if not (math.isfinite(x) and math.isfinite(y)):
            return False  # project_free raises: let it
        if x < reach or w - x < reach or y < reach or h - y < reach:
            return False
        for b in range(screen.shape[0]):
            dx = x - screen[b, 0]
            dy = y - screen[b, 1]
            if dx * dx + dy * dy < screen[b, 2]:
                return False
    return True


@_jit
def _virtual_slots(path, params, offsets, screen, size_reach):  # pragma: no cover - compiled
    leader = np.empty(6)
    _virtual_pose(path, params[0], params[1], params[3], params[2], leader)
    targets = np.empty((offsets.shape[0], 2))
    _place_slots(leader[0], leader[1], leader[2], offsets, targets)
    return leader, targets, _screen(targets, screen, size_reach)


@_jit
def _slots(pose, offsets, screen, size_reach):  # pragma: no cover - compiled
    targets = np.empty((offsets.shape[0], 2))
    _place_slots(pose[0], pose[1], pose[2], offsets, targets)
    return targets, _screen(targets, screen, size_reach)


@_jit
def _slot_trajectory(path, params, offsets, ats, raw, index):  # pragma: no cover - compiled
    """Rows ``k = 0..len(raw) - 1`` of the unprojected slots at ``t = k * dt``: ``_virtual_pose``, the
    formation whose ``at`` is the last ``<= t`` (formation.active_formation), ``_place_slots``."""
    leader = np.empty(6)
    for k in range(raw.shape[0]):
        t = k * params[3]
        _virtual_pose(path, params[0], params[1], t, params[2], leader)
        f = 0
        for i in range(ats.shape[0]):
            if ats[i] <= t:
                f = i
        index[k] = f
        _place_slots(leader[0], leader[1], leader[2], offsets[f], raw[k])


def slot_trajectory(path: np.ndarray, length: float, speed: float, delay: float, dt: float, offsets: np.ndarray,
                    ats: np.ndarray, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """The unprojected slots of a virtual leader at ``t = k * dt`` for ``k = 0..steps``, in one call:
    :func:`virtual_slots` at every step with the formation schedule applied.

    Args:
        path: :func:`pack_path` of the leader's path; ``length`` its length.
        speed, delay: the leader's speed and start delay; ``dt`` the control step.
        offsets: ``(F, n, 2)`` float64 offsets of the ``F`` formations of the schedule.
        ats: ``(F,)`` their start times (sorted).

    Returns:
        ``(slots (steps + 1, n, 2), formation index (steps + 1,))``, bit for bit what
        :func:`swarm_env.geometry.formation.unprojected_slot_trajectory` defines step by step.
    """
    raw = np.empty((steps + 1, offsets.shape[1], 2))
    index = np.empty(steps + 1, dtype=np.intp)
    params = np.array([float(length), float(speed), float(delay), float(dt)])
    _slot_trajectory(path, params, np.ascontiguousarray(offsets, dtype=np.float64),
                     np.ascontiguousarray(ats, dtype=np.float64), raw, index)
    return raw, index


def virtual_slots(path: np.ndarray, length: float, speed: float, delay: float, t: float, offsets: np.ndarray,
                  screen: np.ndarray, size_reach: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool]:
    """The virtual leader at time ``t`` and the slots around it, in one call.

    Args:
        path: :func:`pack_path` of the leader's path; ``length`` its length.
        speed, delay: the leader's speed and start delay.
        offsets: ``(n, 2)`` float64 formation offsets (C-contiguous).
        screen, size_reach: :meth:`~swarm_env.geometry.static_map.StaticMap.slot_screen` of the clearance.

    Returns:
        ``leader`` ``(6,)``: ``(x, y, heading, vx, vy, done)`` as :func:`~swarm_env.geometry.paths.virtual_leader`
        gives pose, velocity and done (1.0/0.0); ``targets`` ``(n, 2)``: the unprojected slots; ``free``:
        every target passes the screen, so ``project_free(targets)`` would return them unchanged.
    """
    params = np.array([float(length), float(speed), float(delay), float(t)])
    leader, targets, free = _virtual_slots(path, params, offsets, screen, size_reach)
    return leader, targets, bool(free)


def slots(pose: np.ndarray, offsets: np.ndarray, screen: np.ndarray, size_reach: np.ndarray
          ) -> tuple[np.ndarray, bool]:
    """``(targets (n, 2), free)`` for a leader at ``pose`` ``(x, y, heading)``: as :func:`virtual_slots`."""
    targets, free = _slots(np.ascontiguousarray(pose, dtype=np.float64), offsets, screen, size_reach)
    return targets, bool(free)


__all__ = ["pack_path", "slot_trajectory", "slots", "virtual_slots"]
