"""The velocity-obstacle search for differential-drive robots (paper 003 Sec. II-D): the numpy reference.

One implementation used by the env's robot leader (paper 003 Fig. 1: pure pursuit along its path,
:mod:`swarm_env.control.pursuit`, then this check against obstacles, humans and robots), by the scripted VO
expert for the followers (paper 003 Fig. 2) and by the safety layer (:mod:`swarm_env.control.safety`). Its
compiled twin is :mod:`swarm_env.control.vo_kernel` (the same bits): a change to the search is made in these two
files. Everything here is a pure, vectorised numpy function.

Conventions: world frame x right, y up; a pose is ``(x, y, theta)`` with theta
counter-clockwise from +x (radians); a *twist* is the body-frame command
``(v, omega)`` (m/s, rad/s); a *velocity* is a world-frame ``(vx, vy)``.

Velocity obstacles (paper 003 Sec. II-D, Eq. 12). For a robot disc A at ``p_A``
and another disc B at ``p_B`` moving at ``v_B``, a robot velocity ``v_A`` is in
the (truncated) velocity obstacle when the relative ray
``(p_A - p_B) + (v_A - v_B) t`` enters the Minkowski sum ``B (+) -A`` — a disc of
the summed radii around B — for some ``t`` in ``[0, horizon]``. Equivalently the
relative velocity lies in the cone from A towards the enlarged B, cut off where
the collision would happen later than ``horizon``. Here the test is done in
closed form as a ray/disc intersection (no angles, no cone boundaries), which
also yields the time to collision used to rank unsafe candidates. Static
polygons use the exact Minkowski sum with the robot disc (offset edges plus
vertex discs), not bounding circles.

A unicycle cannot take an arbitrary velocity, so candidates are sampled in
twist space ``(v, omega)``. :func:`vo_select` tests each one on the motion it
predicts (``model="arc"``, default): the exact arc driven while the twist is
held for ``tau`` seconds, then a straight run at ``v`` with the heading reached,
until ``horizon`` (:func:`twist_trajectories`) — a piecewise-linear relative
ray, each piece tested in closed form. ``model="chord"`` is the textbook
reduction (the arc's mean velocity over ``tau``, :func:`twist_velocities`, held
for the whole horizon). Why the default is the arc: with the chord the only
escape from a head-on course that the test can see is slowing down (a turn of
``omega tau / 2`` rad barely changes the chord), and slowing is only "safe"
because the cone is truncated — the robot ends up standing in the path of an
oncoming human (``tests/test_guidance.py``'s head-on case: the chord model lets the
robot stand in the human's path, the arc model turns it away).

Batches: :func:`vo_select_batch` runs the selection for ``N`` robots in one
vectorised pass over one shared list of discs (``disc_mask`` says which discs
each robot avoids, so a robot can be left out of its own list); the scripted VO
expert (``swarm_env_agents.vo_expert``) drives all followers with it. :func:`vo_select`
is its ``N = 1`` case, used by the env's robot leader: one implementation.

Robots that all run this rule should mark each other ``reciprocal`` (RVO: each
takes half of the avoidance), otherwise two plain-VO robots dodge fully at the
same time, oscillate and can stall face to face. Standing still is never
chosen as the end of the story (``escape``): a blocked robot turns in place
towards the most open direction. What the rule cannot see: a human who
reverses within a metre of a robot (the discs are predicted at constant
velocity).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from functools import lru_cache
from typing import Any, NamedTuple

import numpy as np

from swarm_env.checks import finite_numbers
from swarm_env.compiled import compiled_search
from swarm_env.control.pursuit import wrap_angle
from swarm_env.geometry.static_map import StaticMap

__all__ = [
    "sample_twists",
    "twist_velocities",
    "twist_trajectories",
    "disc_time_to_collision",
    "vo_discs_inside",
    "static_time_to_collision",
    "vo_polygons_inside",
    "trajectory_disc_ttc",
    "trajectory_static_ttc",
    "VOResult",
    "vo_select",
    "VOBatchResult",
    "vo_select_batch",
    "VORobots",
    "VODiscs",
]

# vo_select_batch tests this many least-penalty candidates first (see there).
_FIRST_STAGE = 24


def turning_in_place(v: Any, omega: Any, v_max: float, omega_max: float) -> Any:
    """Whether a robot driving the twist ``(v, omega)`` is turning in place (``escape_commit``; the ``vo`` expert's
    ``escape_drive``): speed under 10 % of ``v_max``, turn rate over 10 % of ``omega_max``. Scalars give a bool,
    arrays an array of them. (The kernel has the same test.)"""
    return (abs(v) < 0.1 * v_max) & (abs(omega) > 0.1 * omega_max)


# ---------------------------------------------------------------------------- sampling
@lru_cache(maxsize=64)
def _twist_grid(v_max: float, omega_max: float, n_v: int, n_w: int, v_min: float) -> np.ndarray:
    v = np.linspace(v_min, v_max, n_v) if n_v > 1 else np.array([v_max])
    w = np.linspace(-omega_max, omega_max, n_w) if n_w > 1 else np.array([0.0])
    if v_min <= 0.0 <= v_max:
        v = np.union1d(v, [0.0])  # standing still must always be a candidate
    w = np.union1d(w, [0.0])  # so must driving straight
    grid = np.stack(np.meshgrid(v, w, indexing="ij"), axis=-1).reshape(-1, 2)
    grid.flags.writeable = False
    return grid


def sample_twists(v_max: float, omega_max: float, n_v: int = 7, n_w: int = 11, v_min: float = 0.0) -> np.ndarray:
    """Candidate twists ``(C, 2)`` ``(v, omega)``: the grid of ``n_v`` speeds evenly in
    ``[v_min, v_max]`` times ``n_w`` turn rates evenly in ``[-omega_max, omega_max]``,
    with ``v = 0`` (when in range) and ``omega = 0`` added if the grid misses them
    (so ``(0, 0)`` is always a candidate for ``v_min <= 0``). Ordered by ``v`` then
    ``omega``. ``C = 77`` for the defaults. The array is cached and read-only.
    """
    if n_v < 1 or n_w < 1:
        raise ValueError("n_v and n_w must be >= 1")
    if v_min > v_max:
        raise ValueError(f"v_min ({v_min}) must be <= v_max ({v_max})")
    return _twist_grid(float(v_max), float(omega_max), int(n_v), int(n_w), float(v_min))


def twist_velocities(theta: float | np.ndarray, twists: np.ndarray, tau: float) -> np.ndarray:
    """World-frame mean velocity ``(C, 2)`` of each twist ``(C, 2)`` held for ``tau`` s
    from heading ``theta``: the chord of the unicycle arc divided by ``tau``,
    ``v * sinc(omega tau / 2) * (cos, sin)(theta + omega tau / 2)`` (exact; the
    ``omega -> 0`` limit is ``v (cos theta, sin theta)``)."""
    tw = np.asarray(twists, dtype=np.float64).reshape(-1, 2)
    half = 0.5 * tau * tw[:, 1]
    scale = tw[:, 0] * np.sinc(half / math.pi)  # np.sinc(x) = sin(pi x) / (pi x)
    ang = theta + half
    return np.column_stack([scale * np.cos(ang), scale * np.sin(ang)])


# ---------------------------------------------------------------------------- VO: core
def _ray_disc_ttc(px, py, R2, wx, wy, limit, still_overlap_ok=False):
    """Elementwise first time ``t`` in ``[0, limit]`` with ``|w t - p| < R`` (arrays broadcast).

    ``p`` obstacle minus robot position, ``w`` robot minus obstacle velocity,
    ``R2 = R**2``. Entry time: the earlier root of ``|w|^2 t^2 - 2 (w.p) t + |p|^2 - R^2``
    in the cancellation-free form ``c / (w.p + sqrt(disc))``; it exists when
    ``w.p > 0`` (approaching) and ``disc > 0`` (not grazing). Overlapping at ``t = 0``:
    ``0`` unless the distance grows (``w.p < 0``, or ``w.p == 0`` with ``w != 0``);
    with ``still_overlap_ok`` also ``inf`` where it stays the same (``w == 0``).
    ``inf`` where there is no entry within ``limit``.
    """
    # In-place arithmetic on fresh temporaries (the same operations in the same order).
    wp = wx * px
    wp += wy * py
    ww = wx * wx
    ww += wy * wy
    c = px * px
    c += py * py
    c -= R2
    disc = wp * wp
    disc -= ww * c
    hit = wp > 0.0
    hit &= disc > 0.0
    np.maximum(disc, 0.0, out=disc)
    den = np.sqrt(disc, out=disc)
    den += wp
    t = np.full(den.shape, np.inf)
    np.divide(c, den, out=t, where=hit)
    over = c < 0.0
    if over.any():
        t[over] = np.inf
        over &= (wp > 0.0) if still_overlap_ok else (wp > 0.0) | (ww == 0.0)
        t[over] = 0.0
    t[t > limit] = np.inf
    return t


def _arc_points(v, w, t, theta):
    """Unicycle displacement after time(s) ``t`` at twist ``(v, w)`` from heading ``theta``
    (exact; ``w -> 0`` handled by sinc). Arrays broadcast; returns x, y."""
    half = 0.5 * w * t
    scale = v * t * np.sinc(half / math.pi)  # np.sinc(x) = sin(pi x) / (pi x)
    ang = theta + half
    return scale * np.cos(ang), scale * np.sin(ang)


def _trajectories_body(twists: np.ndarray, tau: float, horizon: float, n_arc: int) -> tuple[np.ndarray, np.ndarray]:
    t_hold = min(float(tau), float(horizon))
    t_arc = np.linspace(0.0, t_hold, n_arc + 1)
    v, w = twists[:, 0:1], twists[:, 1:2]
    x, y = _arc_points(v, w, t_arc, 0.0)
    pts = np.stack([x, y], axis=-1)
    if horizon <= t_hold:
        return t_arc, pts
    hd = twists[:, 1] * t_hold
    run = twists[:, 0] * (horizon - t_hold)
    last = pts[:, -1] + np.column_stack([run * np.cos(hd), run * np.sin(hd)])
    return np.append(t_arc, horizon), np.concatenate([pts, last[:, None, :]], axis=1)


@lru_cache(maxsize=64)
def _grid_trajectories(
    v_max: float, omega_max: float, n_v: int, n_w: int, v_min: float, tau: float, horizon: float, n_arc: int
) -> tuple[np.ndarray, np.ndarray]:
    times, pts = _trajectories_body(_twist_grid(v_max, omega_max, n_v, n_w, v_min), tau, horizon, n_arc)
    times.flags.writeable = False
    pts.flags.writeable = False
    return times, pts


def _trajectory_row(v: float, w: float, tau: float, horizon: float, n_arc: int, theta: float = 0.0) -> np.ndarray:
    """:func:`twist_trajectories` for one twist, in plain Python (the preferred twist
    changes every call and numpy's per-call overhead would dominate): ``(K+1, 2)``."""
    t_hold = min(tau, horizon)
    out = []
    for i in range(n_arc + 1):
        t = t_hold * i / n_arc
        half = 0.5 * w * t
        scale = v * t * (math.sin(half) / half if abs(half) > 1e-12 else 1.0)
        out.append((scale * math.cos(theta + half), scale * math.sin(theta + half)))
    if horizon > t_hold:
        run = v * (horizon - t_hold)
        x, y = out[-1]
        hd = theta + w * t_hold
        out.append((x + run * math.cos(hd), y + run * math.sin(hd)))
    return np.array(out)


def _body_velocity(v: float, w: float, tau: float) -> tuple[float, float]:
    """The mean velocity of twist ``(v, w)`` held for ``tau`` s in the robot's own frame (heading 0): the
    chord of its arc over ``tau``, ``v sinc(w tau / 2) (cos, sin)(w tau / 2)`` (:func:`twist_velocities`
    at ``theta = 0``). Plain Python (``math``): :mod:`swarm_env.control.vo_kernel` computes the same bits."""
    half = 0.5 * tau * w
    scale = v * (math.sin(half) / half if half != 0.0 else 1.0)
    return scale * math.cos(half), scale * math.sin(half)


@lru_cache(maxsize=64)
def _grid_velocities(v_max: float, omega_max: float, n_v: int, n_w: int, v_min: float, tau: float) -> np.ndarray:
    """``(G, 2)`` :func:`_body_velocity` of every twist of :func:`sample_twists`' grid (read-only, cached)."""
    grid = sample_twists(v_max, omega_max, n_v, n_w, v_min)
    out = np.array([_body_velocity(float(v), float(w), tau) for v, w in grid], dtype=np.float64).reshape(-1, 2)
    out.flags.writeable = False
    return out


def _world_trajectories(v: np.ndarray, w: np.ndarray, theta: np.ndarray, tau: float, horizon: float, n_arc: int) -> np.ndarray:
    """:func:`twist_trajectories`' points for one twist ``(v[i], w[i])`` per robot, each
    from its own heading ``theta[i]``: ``(N, K+1, 2)`` (the same numbers, fewer numpy calls)."""
    t_hold = min(float(tau), float(horizon))
    ts = np.arange(n_arc + 1) * (t_hold / n_arc)
    half = 0.5 * w[:, None] * ts
    scale = v[:, None] * ts * np.sinc(half / math.pi)
    ang = theta[:, None] + half
    extra = horizon > t_hold
    out = np.empty((len(v), n_arc + 1 + int(extra), 2))
    out[:, : n_arc + 1, 0] = scale * np.cos(ang)
    out[:, : n_arc + 1, 1] = scale * np.sin(ang)
    if extra:
        run = v * (horizon - t_hold)
        hd = theta + w * t_hold
        out[:, -1, 0] = out[:, n_arc, 0] + run * np.cos(hd)
        out[:, -1, 1] = out[:, n_arc, 1] + run * np.sin(hd)
    return out


def _rotate(pts: np.ndarray, theta: float) -> np.ndarray:
    c, s = math.cos(theta), math.sin(theta)
    x, y = pts[..., 0], pts[..., 1]
    return np.stack([c * x - s * y, s * x + c * y], axis=-1)


def twist_trajectories(
    theta: float, twists: np.ndarray, tau: float, horizon: float, n_arc: int = 2
) -> tuple[np.ndarray, np.ndarray]:
    """Predicted motion of a unicycle that holds each twist for ``tau`` s, then drives
    straight on (same ``v``, the heading reached) until ``horizon``.

    This is the trajectory each VO candidate is tested on (``model="arc"``). Its
    first part is the exact arc sampled at ``n_arc`` equal chords (the error is
    the chord sagitta ``v/omega (1 - cos(omega tau / (2 n_arc)))``, 2 cm for
    ``v = 0.65, omega = 1, tau = 1, n_arc = 2``); its second part shows where the
    chosen turn leads.

    Returns:
        times ``(K+1,)`` = ``0, tau/n_arc, ..., tau, horizon`` (no straight part if
        ``horizon <= tau``); points ``(C, K+1, 2)``: world-frame displacements from
        the start (``points[:, 0] == 0``).
    """
    tw = np.asarray(twists, dtype=np.float64).reshape(-1, 2)
    times, pts = _trajectories_body(tw, tau, horizon, n_arc)
    return times, _rotate(pts, theta)


def trajectory_disc_ttc(
    times: np.ndarray,
    points: np.ndarray,
    rel_pos: np.ndarray,
    combined_radius: np.ndarray,
    disc_vel: np.ndarray,
    reciprocal: np.ndarray | None = None,
    velocity: np.ndarray | None = None,
) -> np.ndarray:
    """``(C, D)`` first contact time of piecewise-linear robot trajectories with discs
    moving at constant velocity; ``inf`` if none before ``times[-1]``.

    ``times`` ``(K+1,)``, ``points`` ``(C, K+1, 2)`` robot displacements (see
    :func:`twist_trajectories`); ``rel_pos`` ``(D, 2)`` disc minus robot position
    now; ``combined_radius`` ``(D,)``; ``disc_vel`` ``(D, 2)``. Each piece is a
    ray/disc test with :func:`disc_time_to_collision`'s rules (overlap included).

    ``reciprocal`` ``(D,)`` bool marks discs that are robots running the same
    rule: they are tested with the *reciprocal* velocity obstacle (van den Berg
    et al., 2008) — each robot takes half of the avoidance, i.e. the candidate
    displacement ``x(t)`` becomes ``2 x(t) - velocity * t`` against that disc,
    with ``velocity`` ``(2,)`` the robot's current world velocity. This removes
    the oscillation of two plain-VO robots that both dodge fully.
    """
    pc = _pieces(times, points)
    return _pieces_disc_ttc(pc, rel_pos, combined_radius, disc_vel, reciprocal, velocity)


def _pieces(times: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, ...]:
    """Piece data of trajectories: t0 ``(K,)`` start times, dur ``(K,)``, and
    contiguous ``(C, K)`` start coordinates sx, sy and velocities ux, uy."""
    times = np.asarray(times, dtype=np.float64)
    pts = np.asarray(points, dtype=np.float64)
    t0 = times[:-1]
    dur = times[1:] - t0
    x, y = pts[..., 0], pts[..., 1]
    sx, sy = x[:, :-1], y[:, :-1]
    ux = (x[:, 1:] - sx) / dur
    uy = (y[:, 1:] - sy) / dur
    return t0, dur, np.ascontiguousarray(sx), np.ascontiguousarray(sy), ux, uy


def _pieces_disc_ttc(pc, rel_pos, combined_radius, disc_vel, reciprocal=None, velocity=None) -> np.ndarray:
    """:func:`_rows_disc_ttc` for one robot: every trajectory row sees the same discs."""
    rel = np.asarray(rel_pos, dtype=np.float64).reshape(1, -1, 2)
    dv = np.asarray(disc_vel, dtype=np.float64).reshape(1, -1, 2)
    R = np.asarray(combined_radius, dtype=np.float64).reshape(1, -1)
    recip = None
    if reciprocal is not None and np.any(reciprocal):
        recip = np.asarray(reciprocal, dtype=bool).reshape(1, -1)
    own = np.zeros((1, 2)) if velocity is None else np.asarray(velocity, dtype=np.float64).reshape(1, 2)
    return _rows_disc_ttc(pc, rel, R, dv, recip, own)


def _rows_disc_ttc(pc, rel, R, dv, recip=None, own=None, still_overlap_ok=False) -> np.ndarray:
    """``(C, D)`` first contact time of the ``C`` trajectory rows of ``pc`` (see
    :func:`_pieces`) with ``D`` discs moving at constant velocity.

    The disc data are per row or shared by all rows (leading axis ``C`` or 1):
    ``rel`` ``(., D, 2)`` disc minus robot position now, ``R`` ``(., D)`` combined
    radii, ``dv`` ``(., D, 2)`` disc velocities, ``recip`` ``(., D)`` bool or
    ``None`` (reciprocal discs see the displacement ``2 x(t) - own t``, see
    :func:`trajectory_disc_ttc`), ``own`` ``(., 2)`` the robot's current velocity.
    ``still_overlap_ok``: see :func:`_ray_disc_ttc`.
    """
    t0, dur, sx, sy, ux, uy = pc
    if rel.shape[0] == 1:  # shared by all rows: drop the leading axis (fewer, smaller temporaries)
        rel, R, dv, own = rel[0], R[0], dv[0], own[0] if own is not None else None
        recip = None if recip is None else recip[0]
    tk = t0[:, None]
    ox = rel[..., None, :, 0] + dv[..., None, :, 0] * tk  # disc at each piece start, (C or -, K, D)
    oy = rel[..., None, :, 1] + dv[..., None, :, 1] * tk
    SX, SY, UX, UY = sx[..., None], sy[..., None], ux[..., None], uy[..., None]
    if recip is not None:
        r = recip[..., None, :]
        ox_, oy_ = own[..., 0, None, None], own[..., 1, None, None]
        SX = np.where(r, 2.0 * SX - ox_ * tk, SX)
        SY = np.where(r, 2.0 * SY - oy_ * tk, SY)
        UX = np.where(r, 2.0 * UX - ox_, UX)
        UY = np.where(r, 2.0 * UY - oy_, UY)
    px, py = ox - SX, oy - SY
    wx, wy = UX - dv[..., None, :, 0], UY - dv[..., None, :, 1]
    t = _ray_disc_ttc(px, py, (R * R)[..., None, :], wx, wy, dur[:, None], still_overlap_ok)
    t += tk
    return t.min(axis=1)


# World walls as (offset, ax, ay): clearance to wall k of point (x, y) is
# offset + ax x + ay y (offsets are filled with W/H per map); order bottom, right, top, left.
_WALL_AX = np.array([0.0, -1.0, 0.0, 1.0])
_WALL_AY = np.array([1.0, 0.0, -1.0, 0.0])


def trajectory_static_ttc(
    position: np.ndarray,
    radius: float,
    times: np.ndarray,
    points: np.ndarray,
    static: StaticMap,
    circles: bool = True,
) -> np.ndarray:
    """``(C,)`` first time a disc of ``radius`` following each piecewise-linear
    trajectory (``times`` ``(K+1,)``, ``points`` ``(C, K+1, 2)`` displacements from
    ``position``) touches a static obstacle or wall; ``inf`` if none before
    ``times[-1]``.

    * Circles: ray/disc tests with radius ``r_circle + radius`` (skipped with
      ``circles=False``, for callers that add them to their moving discs).
    * Convex polygons: the exact Minkowski sum with the disc — per edge the strip
      between the edge and its copy offset outward by ``radius`` (entered through
      the offset edge from the outer side), plus a disc of ``radius`` at every
      vertex. The first entry over these parts is the first time the clearance
      drops to ``radius``. A bounding-circle broad phase only skips work.
    * Walls: the lines of the world rectangle ``[0, W] x [0, H]``.

    Already within ``radius`` of an obstacle or wall now: ``0`` unless the first
    piece moves away from it (``u . n > 0``, ``n`` the outward normal at its
    nearest surface point; for a convex obstacle the distance then keeps
    growing along that piece), in which case that obstacle is ignored for the
    candidate. Obstacles out of reach of every trajectory are culled first.
    """
    pts = np.asarray(points, dtype=np.float64)
    if pts.shape[0] == 0:
        return np.full(0, np.inf)
    ext = math.sqrt(float(np.max(pts[..., 0] ** 2 + pts[..., 1] ** 2)))  # farthest any candidate gets
    return _pieces_static_ttc(position, radius, _pieces(times, pts), ext, static, circles)


def _pieces_static_ttc(position, radius, pc, ext, static, circles=True) -> np.ndarray:
    """:func:`_rows_static_ttc` for one robot."""
    P = np.asarray(position, dtype=np.float64).reshape(1, 2)
    return _rows_static_ttc(P, np.array([float(radius)]), None, pc, ext, static, circles)


def _static_context(P: np.ndarray, rad: np.ndarray, ext: float, static: StaticMap, circles: bool) -> dict:
    """What :func:`_rows_static_ttc` needs to know about the robots themselves (not
    their candidate motions), computed once for all the row sets tested from the
    same positions: which walls, circles and polygons are in reach, each robot's
    clearance to the polygons now and, where it already overlaps one (margin
    included), the outward normal there."""
    single = P.shape[0] == 1
    reach = rad + (ext + 1e-9)  # (N,)
    ctx: dict = {"P": P, "rad": rad, "single": single}
    W, H = static.size
    off = np.array([0.0, W, H, 0.0])
    if single:
        near = off + _WALL_AX * P[0, 0] + _WALL_AY * P[0, 1] <= reach[0]
    else:
        near = (off + _WALL_AX * P[:, 0:1] + _WALL_AY * P[:, 1:2] <= reach[:, None]).any(axis=0)
    ctx["walls"] = (_WALL_AX[near], _WALL_AY[near], off[near]) if near.any() else None
    ctx["circles"] = None
    circ = static.circles
    if circles and len(circ):
        dist = np.hypot(circ[:, 0] - P[:, 0:1], circ[:, 1] - P[:, 1:2]) - circ[:, 2]  # (N, c)
        keep = dist <= reach[:, None]
        keep = keep[0] if single else keep.any(axis=0)
        if keep.any():
            ctx["circles"] = circ[keep]
    ctx["poly"] = None
    if len(static.polygons):
        g = _polygon_arrays(static)
        centre, bound = g["centre"], g["bound"]
        dc = np.hypot(centre[:, 0] - P[:, 0:1], centre[:, 1] - P[:, 1:2]) - bound  # (N, p)
        near_p = dc <= reach[:, None]
        cand = np.nonzero(near_p[0] if single else near_p.any(axis=0))[0]
        if len(cand):
            A, N, L, ux, uy = g["A"][cand], g["N"][cand], g["L"][cand], g["ux"][cand], g["uy"][cand]
            qx = P[:, 0, None, None] - A[..., 0]  # (N, p, M)
            qy = P[:, 1, None, None] - A[..., 1]
            perp = qx * N[..., 0] + qy * N[..., 1]  # signed distance to each edge line, > 0 outside
            foot = np.clip(qx * ux + qy * uy, 0.0, L)
            fx, fy = qx - foot * ux, qy - foot * uy  # from the nearest point of each edge to P
            d2 = fx * fx + fy * fy
            hmax = perp.max(axis=2)  # (N, p)
            inside = hmax <= 0.0
            sd = np.where(inside, hmax, np.sqrt(d2.min(axis=2)))  # signed clearance now
            overl = sd < rad[:, None]
            over = None
            if overl.any():
                rn, rj = np.nonzero(overl)
                nrm = N[rj, np.argmax(perp[rn, rj], axis=1)]  # centre inside: nearest edge line
                e_out = np.argmin(d2[rn, rj], axis=1)
                ox_, oy_ = fx[rn, rj, e_out], fy[rn, rj, e_out]
                dn = np.hypot(ox_, oy_)
                use = (~inside[rn, rj]) & (dn > 0.0)
                nrm[use] = np.column_stack([ox_[use], oy_[use]]) / dn[use, None]
                over = (rn, nrm)
            free = (sd <= reach[:, None]) & ~overl  # (N, p)
            fcols = np.nonzero(free[0] if single else free.any(axis=0))[0]
            ctx["poly"] = {
                "A": A, "N": N, "L": L, "ux": ux, "uy": uy,
                "centre": centre[cand], "bound": bound[cand], "over": over, "free": free, "fcols": fcols,
            }
    return ctx


def _rows_static_ttc(P, rad, ridx, pc, ext, static, circles=True, ctx=None) -> np.ndarray:
    """``(C,)`` static contact times of the trajectory rows of ``pc`` (see
    :func:`trajectory_static_ttc` for the rules) for several robots at once.

    ``P`` ``(N, 2)`` robot positions, ``rad`` ``(N,)`` their radii (margin
    included), ``ridx`` ``(C,)`` the robot of each row (``None``: ``N == 1``, all
    rows are that robot's); ``pc`` holds displacements from the row's robot;
    ``ext`` bounds how far any row gets from its robot. ``ctx``: the
    :func:`_static_context` of ``(P, rad, ext, static, circles)`` if the caller
    has it (it tests several row sets from the same positions).
    """
    if ctx is None:
        ctx = _static_context(P, rad, ext, static, circles)
    one = ridx is None
    t0, dur, sx, sy, vx, vy = pc
    Pr = P if one else P[ridx]  # (C or 1, 2)
    rr = rad if one else rad[ridx]  # (C or 1,)
    sx = Pr[:, 0:1] + sx  # piece starts in world coordinates (C, K)
    sy = Pr[:, 1:2] + sy
    out = np.full(sx.shape[0], np.inf)

    # -- walls
    if ctx["walls"] is not None:
        ax, ay, o = ctx["walls"]
        gap = o + ax * sx[..., None] + ay * sy[..., None] - rr[:, None, None]  # (C, K, w)
        vn = ax * vx[..., None] + ay * vy[..., None]  # > 0: moving away from the wall
        t = np.divide(gap, -vn, out=np.full(gap.shape, np.inf), where=vn < 0.0)
        t[gap < 0.0] = np.inf
        t[(gap < 0.0) & (vn <= 0.0)] = 0.0
        t[t > dur[:, None]] = np.inf
        t += t0[:, None]
        np.minimum(out, t.min(axis=(1, 2)), out=out)

    # -- circles
    if circles and ctx["circles"] is not None:
        ck = ctx["circles"]
        rel = ck[None, :, :2] - Pr[:, None, :]
        t = _rows_disc_ttc(pc, rel, ck[None, :, 2] + rr[:, None], np.zeros((1, len(ck), 2)))
        np.minimum(out, t.min(axis=1), out=out)

    # -- convex polygons
    pg = ctx["poly"]
    if pg is not None:
        A, N, L, ux, uy = pg["A"], pg["N"], pg["L"], pg["ux"], pg["uy"]
        if pg["over"] is not None:
            rn, nrm = pg["over"]
            bad = vx[:, 0, None] * nrm[:, 0] + vy[:, 0, None] * nrm[:, 1] <= 0.0  # first piece, (C, k)
            if not one:
                bad &= ridx[:, None] == rn
            out[bad.any(axis=1)] = 0.0
        fcols = pg["fcols"]
        if len(fcols):
            # Broad phase: which (row, piece, polygon) sweeps come within the row's
            # radius of the polygon's bounding circle at all.
            cx = pg["centre"][fcols, 0] - sx[..., None]  # (C, K, p)
            cy = pg["centre"][fcols, 1] - sy[..., None]
            uu = (vx * vx + vy * vy)[..., None]
            ts = np.divide(cx * vx[..., None] + cy * vy[..., None], uu, out=np.zeros(cx.shape), where=uu > 0.0)
            np.clip(ts, 0.0, dur[:, None], out=ts)
            ex = cx - ts * vx[..., None]
            ey = cy - ts * vy[..., None]
            rb = pg["bound"][fcols] + rr[:, None, None]
            hit = ex * ex + ey * ey <= rb * rb
            if not one:
                hit &= pg["free"][ridx][:, fcols][:, None, :]
            ci, ki, pj = np.nonzero(hit)
            if len(ci):
                pi = fcols[pj]
                r_ = (rr[ci] if not one else np.broadcast_to(rr, ci.shape))[:, None]
                a, nx, ny = A[pi], N[pi, :, 0], N[pi, :, 1]  # (n, M, ...)
                ex_, ey_, Ln = ux[pi], uy[pi], L[pi]
                wx, wy = vx[ci, ki][:, None], vy[ci, ki][:, None]
                dk = dur[ki][:, None]
                rx = sx[ci, ki][:, None] - a[..., 0]  # piece start relative to each edge start
                ry = sy[ci, ki][:, None] - a[..., 1]
                per = rx * nx + ry * ny
                vn = wx * nx + wy * ny
                t = np.divide(per - r_, -vn, out=np.full(per.shape, np.inf), where=(vn < 0.0) & (per >= r_))
                fin = np.isfinite(t)
                s_hit = rx * ex_ + ry * ey_ + np.where(fin, (wx * ex_ + wy * ey_) * np.where(fin, t, 0.0), 0.0)
                t[~fin | (s_hit < 0.0) | (s_hit > Ln) | (t > dk)] = np.inf
                # vertex discs (every vertex starts one edge)
                np.minimum(t, _ray_disc_ttc(-rx, -ry, r_ * r_, wx, wy, dk), out=t)
                np.minimum.at(out, ci, t.min(axis=1) + t0[ki])
    return out


# Per-map derived polygon arrays, keyed by id() with the map itself kept alive
# (so an id is never reused while cached). A handful of maps exist per process.
_POLY_CACHE: dict[int, tuple[StaticMap, dict]] = {}


def _polygon_arrays(static: StaticMap) -> dict:
    hit = _POLY_CACHE.get(id(static))
    if hit is not None and hit[0] is static:
        return hit[1]
    E = static.poly_edges
    L = np.sqrt(E[..., 0] ** 2 + E[..., 1] ** 2)
    inv_L = np.where(L > 0.0, 1.0 / np.maximum(L, 1e-300), 0.0)
    centre = np.array([p.mean(axis=0) for p in static.polygons]).reshape(-1, 2)
    bound = np.array([float(np.max(np.hypot(*(p - c).T))) for p, c in zip(static.polygons, centre)])
    g = {
        "A": static.poly_vertices,
        "N": static.poly_normals,
        "L": L,
        "ux": E[..., 0] * inv_L,
        "uy": E[..., 1] * inv_L,
        "centre": centre,
        "bound": bound,
    }
    if len(_POLY_CACHE) >= 32:
        _POLY_CACHE.pop(next(iter(_POLY_CACHE)))
    _POLY_CACHE[id(static)] = (static, g)
    return g


# ---------------------------------------------------------------------------- VO: discs
def disc_time_to_collision(
    rel_pos: np.ndarray, combined_radius: np.ndarray, rel_vel: np.ndarray, horizon: float = math.inf
) -> np.ndarray:
    """Time until the relative ray enters each disc: ``(C, D)``, ``inf`` if not within ``horizon``.

    ``rel_pos`` ``(D, 2)``: obstacle minus robot position; ``combined_radius``
    ``(D,)`` or scalar; ``rel_vel`` ``(C, D, 2)`` or ``(C, 2)`` (the same for every
    disc): robot velocity minus obstacle velocity. With ``p = rel_pos``,
    ``w = rel_vel``, ``R = combined_radius``, the gap closes when
    ``|w t - p| = R``: the earlier root ``t = (|p|^2 - R^2) / (w.p + sqrt((w.p)^2 -
    |w|^2 (|p|^2 - R^2)))`` (stable form), valid when ``w.p > 0`` (approaching) and
    the discriminant is positive (a grazing ray is not a collision).

    Already overlapping (``|p| < R``): ``0`` unless the velocity moves away
    (``w.p < 0``, or tangential ``w.p == 0`` with ``w != 0``, both of which grow the
    distance), then ``inf``. Zero relative velocity while overlapping is ``0``.
    """
    p = np.asarray(rel_pos, dtype=np.float64).reshape(-1, 2)
    R = np.asarray(combined_radius, dtype=np.float64)
    w = np.asarray(rel_vel, dtype=np.float64)
    if w.ndim == 2:
        w = w[:, None, :]
    px, py = p[:, 0], p[:, 1]
    wx, wy = np.broadcast_arrays(w[..., 0], w[..., 1], px)[:2]
    return _ray_disc_ttc(np.broadcast_to(px, wx.shape), np.broadcast_to(py, wx.shape), R * R, wx, wy, horizon)


def vo_discs_inside(
    rel_pos: np.ndarray, combined_radius: np.ndarray, rel_vel: np.ndarray, horizon: float
) -> np.ndarray:
    """Truncated velocity-obstacle membership (paper 003 Eq. 12) for moving discs.

    ``rel_pos`` ``(D, 2)`` obstacle position minus robot position;
    ``combined_radius`` ``(D,)`` (sum of radii + margin); ``rel_vel`` ``(C, D, 2)``
    or ``(C, 2)``: candidate robot velocity minus obstacle velocity.

    Returns ``(C, D)`` bool: True when the relative ray ``-p + w t`` comes closer
    than ``R`` for some ``t`` in ``[0, horizon]`` (closed-form ray/disc test, see
    :func:`disc_time_to_collision`). Grazing (touching at exactly ``R``) is
    outside. Discs that already overlap count as inside unless the velocity
    moves away (the distance increases from ``t = 0``), so an overlapping robot
    is only allowed to separate.
    """
    return np.isfinite(disc_time_to_collision(rel_pos, combined_radius, rel_vel, horizon))


# ---------------------------------------------------------------------------- VO: static
def static_time_to_collision(
    position: np.ndarray, radius: float, cand_vel: np.ndarray, static: StaticMap, horizon: float
) -> np.ndarray:
    """``(C,)`` time until a disc of ``radius`` at ``position`` moving in a straight
    line at each ``cand_vel`` ``(C, 2)`` touches a static obstacle or wall; ``inf``
    if not within ``horizon``. Exact Minkowski sums and the overlap rule of
    :func:`trajectory_static_ttc` (this is its one-piece case)."""
    V = np.asarray(cand_vel, dtype=np.float64).reshape(-1, 2)
    times = np.array([0.0, float(horizon)])
    pts = np.stack([np.zeros_like(V), V * float(horizon)], axis=1)
    return trajectory_static_ttc(position, radius, times, pts, static)


def vo_polygons_inside(
    position: np.ndarray, radius: float, cand_vel: np.ndarray, static: StaticMap, horizon: float
) -> np.ndarray:
    """``(C,)`` bool: moving at ``cand_vel`` ``(C, 2)`` would bring the disc (``radius``,
    margin included) at ``position`` into contact with a static polygon, circle or
    wall within ``horizon`` — i.e. the candidate lies in the static velocity
    obstacle. Polygons are treated exactly (Minkowski sum with the disc: offset
    edges plus vertex discs), not as bounding circles; see
    :func:`trajectory_static_ttc`."""
    return np.isfinite(static_time_to_collision(position, radius, cand_vel, static, horizon))


# ---------------------------------------------------------------------------- VO: selection
@dataclass(frozen=True)
class VOResult:
    """Outcome of :func:`vo_select`.

    ``twist``: ``(2,)`` chosen ``(v, omega)``. ``feasible``: a candidate outside every
    velocity obstacle existed. ``n_safe``: how many candidates were safe (1 when
    the preferred twist was accepted on :func:`vo_select`'s fast path).
    ``min_time_to_collision``: the chosen twist's time to its first predicted
    contact (``inf`` when feasible, ``<= horizon`` otherwise).
    """

    twist: np.ndarray
    feasible: bool
    n_safe: int
    min_time_to_collision: float


@dataclass(frozen=True)
class VOBatchResult:
    """Outcome of :func:`vo_select_batch` for ``N`` robots: the fields of
    :class:`VOResult` stacked per robot (``twist`` ``(N, 2)``, ``feasible``
    ``(N,)`` bool, ``n_safe`` ``(N,)`` int, ``min_time_to_collision`` ``(N,)``),
    plus ``escaped`` ``(N,)`` bool: the robot was turned in place towards open
    space (the ``escape`` rule) instead of taking the least-penalty answer, and
    ``fast`` ``(N,)`` bool: the preferred twist was accepted without evaluating
    the grid (it was tested alone and was safe); ``preferred_safe`` ``(N,)``
    bool: the preferred twist was tested and is safe (then it is the answer
    unless a ``goal_heading`` makes another candidate cheaper). With ``fast``,
    ``n_safe`` counts the safe candidates among those tested (the search stops
    at the first pass that holds one), so it is a lower bound."""

    twist: np.ndarray
    feasible: np.ndarray
    n_safe: np.ndarray
    min_time_to_collision: np.ndarray
    escaped: np.ndarray
    fast: np.ndarray
    preferred_safe: np.ndarray


@dataclass(frozen=True)
class VOParams:
    """The velocity-obstacle search's parameters, one object shared by :func:`vo_select`,
    :func:`vo_select_batch`, the env's robot leader (the defaults), the ``vo`` expert and the
    safety layer (:class:`swarm_env.control.safety.AvoidanceParams`, which adds what is about the
    followers' world). Units m, s, rad. The fields:

    * ``horizon``: VO truncation time (s) for moving discs. ``horizon_static``: the
      same for static obstacles and walls (``None``: ``horizon``; RVO2 keeps a
      separate, usually shorter, obstacle horizon; here a shorter one gave more
      contacts in random crowds, so the default is equal).
      ``margin``: added to every combined radius.
    * ``n_v`` x ``n_w``: the candidate grid, :func:`sample_twists` ``(v_max, omega_max, n_v, n_w, v_min)``
      (``v_min < 0`` adds reverse speeds), plus the preferred twist.
    * ``tau``: how long a candidate twist is assumed held (s). ``model="arc"``: the
      candidate is tested on its predicted trajectory — the arc for ``tau``
      (``n_arc`` chords), then straight on at ``v`` (:func:`twist_trajectories`).
      ``model="chord"``: on the straight line of its mean velocity over ``tau``
      (:func:`twist_velocities`), the textbook reduction; see the module
      docstring for why ``arc`` and ``tau = 1`` are the defaults.
    * ``w_pref``, ``w_heading``: penalty weights (:func:`vo_select`'s penalty). ``w_current``: commitment to
      the twist being driven, the weight of its distance from a candidate (needs a ``current`` twist). ``side_bias``: extra penalty
      per unit of normalised turn to the left of the preferred twist — a
      keep-right convention, so two robots meeting mirror-symmetrically do
      not pick mirror-image (colliding) detours.
    * ``escape``: turn towards open space instead of standing still (:func:`vo_select`'s selection rule).
    * ``allow_still_overlap``: see :func:`vo_select_batch`.
    * ``recip_gap`` (m, default 0): a reciprocal disc nearer than the combined radius
      (margin included) plus ``recip_gap`` is avoided plainly (see ``reciprocal``). Reciprocity
      assumes the other robot keeps its current velocity and takes half the avoidance; two
      robots that change course together at close range can both count on the other's half
      (two followers both switching from an escape turn to full speed towards each other).
    * ``move_first`` (default ``False``): when the least-penalty safe candidate stands still
      although the preferred twist moves (blocked), the least-penalty safe candidate that
      *moves* is taken instead, if there is one (every candidate of that robot is then
      tested); only if none is safe does the escape rule below turn it in place. Any
      standing twist is cheaper than a detour under both costs (it is nearer the preferred
      twist than driving off at an angle), so without this rule a blocked robot turns in
      place, the pursuit turns it back, and it stands for seconds while its slot moves on. ORCA (its linear
      program finds the nearest safe velocity, usually a slide along the obstacle) never
      stands while it can move.
    * ``static_reach`` (default 0: off; else a number ``s >= 1``): static obstacles (circles, polygons,
      walls) are judged by path length rather than time. A candidate of speed ``|v| > 0`` hits one if it
      reaches it within ``min(max(h_s, v_p h_s / |v|), s h_s)`` s, ``h_s`` the static horizon and ``v_p``
      the (clipped) preferred speed: within the distance the preferred twist covers in ``h_s``, or
      ``h_s`` if the candidate is faster (never less than without the rule), but not later than
      ``s h_s``. Opt-in, off for the ``vo`` expert: the preferred path runs on past the robot's goal,
      so a follower whose final slot lies just short of an obstacle or wall may find no path there
      (docs/vo_defaults.md, "``static_reach``"). Without it a slow-down "avoids" a static
      obstacle by pushing the contact past the horizon, so a follower whose slot track crosses a
      static disc crawls towards it and lags; with it only a path round the obstacle is safe (ORCA,
      whose static horizon is short, bends round at speed). Standing candidates, moving discs and the
      escape probes are unchanged. The trajectories run on straight after the horizon until ``s h_s``
      (if that is later). Needs ``model="arc"``.
    * ``w_speed`` (default 1): weight of a change of speed against a change of turn rate in the
      penalty (both normalised by their limits). With ``w_speed > 1`` a robot whose preferred twist is
      unsafe bends round at speed rather than slowing down: a slow-down "avoids" an obstacle ahead by
      pushing the contact past the horizon, so with equal weights a follower whose slot skirts a static
      disc crawls towards it and falls behind (ORCA, which takes the nearest safe *velocity*, keeps its
      speed and slides round). The ``vo`` expert uses 3.
    * ``escape_commit`` (s, default 0: off; needs ``current``): a robot that is already turning in place
      (speed under 10 % of ``v_max``, turn rate over 10 % of ``omega_max``) and escapes again keeps
      turning the same way, unless a turn the other way opens a straight run longer by more than
      ``escape_commit`` s. Without it a boxed-in robot whose probes rate the two sides alike turns left
      one step and right the next and never gets out (docs/vo_defaults.md, "``escape_commit``"). Needs
      ``current`` (:func:`vo_select_batch`). The ``vo`` expert uses 1.
    * ``fast``: test the preferred twist alone first and return it if it is safe
      (with ``goal_heading=None`` it has the least penalty, so the answer
      is the same; ``n_safe`` is then reported as 1). ``False`` always
      evaluates the whole grid (exact ``n_safe``).

    Raises ``ValueError`` for values out of range.
    """

    horizon: float = 3.0
    horizon_static: float | None = None
    margin: float = 0.05
    n_v: int = 7
    n_w: int = 11
    tau: float = 1.0
    w_pref: float = 1.0
    w_heading: float = 0.5
    v_min: float = 0.0
    side_bias: float = 0.1
    model: str = "arc"
    n_arc: int = 2
    escape: bool = True
    allow_still_overlap: bool = False
    fast: bool = True
    w_current: float = 0.0
    cost: str = "twist"
    recip_gap: float = 0.0
    move_first: bool = False
    static_reach: float = 0.0
    w_speed: float = 1.0
    escape_commit: float = 0.0

    def __post_init__(self) -> None:
        finite_numbers("", {name: getattr(self, name) for name in ("horizon", "tau")}, positive=True)
        finite_numbers("", {name: getattr(self, name) for name in ("margin", "w_pref", "w_heading", "side_bias",
                                                                   "w_current", "recip_gap", "escape_commit")},
                       positive=False)
        finite_numbers("", {"w_speed": self.w_speed}, positive=True)
        if self.horizon_static is not None and not self.horizon_static > 0:
            raise ValueError(f"horizon_static must be > 0 or None, got {self.horizon_static!r}")
        if int(self.n_v) < 1 or int(self.n_w) < 1 or int(self.n_arc) < 1:
            raise ValueError(f"n_v, n_w and n_arc must be >= 1, got {self.n_v!r}, {self.n_w!r}, {self.n_arc!r}")
        if self.model not in ("arc", "chord"):
            raise ValueError(f"model must be 'arc' or 'chord', got {self.model!r}")
        if self.cost not in ("twist", "velocity"):
            raise ValueError(f"cost must be 'twist' or 'velocity', got {self.cost!r}")
        sr = self.static_reach
        if not (isinstance(sr, (int, float)) and math.isfinite(sr) and (sr == 0 or sr >= 1)):
            raise ValueError(f"static_reach must be 0 (off) or a finite number >= 1, got {sr!r}")
        if sr and self.model != "arc":
            raise ValueError("static_reach needs model='arc'")

    @classmethod
    def names(cls) -> tuple[str, ...]:
        """The parameters' names (the dataclass fields)."""
        return tuple(f.name for f in fields(cls))

    def with_overrides(self, overrides: dict) -> VOParams:
        """A copy with ``overrides`` (parameter names) replaced; ``self`` when there are none."""
        if not overrides:
            return self
        unknown = sorted(set(overrides) - set(self.names()))
        if unknown:
            raise TypeError(f"unknown VO parameter(s) {unknown}; known: {', '.join(self.names())}")
        return replace(self, **overrides)


class VORobots(NamedTuple):
    """The robots of one :func:`vo_select_batch` call (``N`` of them).

    ``poses`` ``(N, 3)``; ``radius`` a scalar or ``(N,)`` (m); ``preferred`` ``(N, 2)`` the desired
    twists (e.g. from :func:`~swarm_env.control.pursuit.pure_pursuit`); ``v_max`` (m/s) and
    ``omega_max`` (rad/s) the twist limits. Optional: ``velocity`` ``(N, 2)`` the current world
    velocities (for reciprocal discs), ``current`` ``(N, 2)`` the twists driven now (for
    ``VOParams.w_current`` and ``escape_commit``), ``goal_heading`` ``(N,)`` the world direction each
    robot should head to (see :func:`vo_select`)."""

    poses: np.ndarray
    radius: float | np.ndarray
    preferred: np.ndarray
    v_max: float
    omega_max: float
    velocity: np.ndarray | None = None
    current: np.ndarray | None = None
    goal_heading: np.ndarray | None = None


class VODiscs(NamedTuple):
    """The moving discs (other robots, humans) of one :func:`vo_select_batch` call, shared by all robots.

    ``xyr`` ``(D, 3)`` ``x, y, radius`` (``(0, 3)`` for none); ``vel`` ``(D, 2)`` their world velocities.
    ``mask`` ``(N, D)`` bool, ``True`` where disc ``d`` is an obstacle for robot ``i`` (``False`` for the
    robot's own disc); ``None``: all. ``reciprocal`` ``(D,)`` or ``(N, D)`` bool, or one bool: the discs
    avoided reciprocally (see :func:`vo_select`). ``horizon`` ``(D,)`` the horizon (s, > 0) of each disc
    in place of ``VOParams.horizon``: a contact with disc ``d`` later than ``horizon[d]`` does not count,
    and the candidates' trajectories are traced to the longest of them (the escape probes keep
    ``VOParams.horizon``); ``None``: ``VOParams.horizon`` for all. Used to look further ahead for discs
    that will not give way (humans)."""

    xyr: np.ndarray
    vel: np.ndarray
    mask: np.ndarray | None = None
    reciprocal: np.ndarray | bool = False
    horizon: np.ndarray | None = None


def vo_select(
    pose: np.ndarray,
    radius: float,
    preferred: np.ndarray,
    discs: np.ndarray,
    disc_vel: np.ndarray,
    static: StaticMap | None,
    v_max: float,
    omega_max: float,
    params: VOParams | None = None,
    *,
    goal_heading: float | None = None,
    velocity: np.ndarray | None = None,
    reciprocal: np.ndarray | bool = False,
    **overrides: Any,
) -> VOResult:
    """Choose a safe twist close to ``preferred`` (paper 003 Sec. II-D), for one robot.

    The ``N = 1`` case of :func:`vo_select_batch` (one implementation; the
    answer is the same as that robot's row of a batch call).

    ``params`` (:class:`VOParams`, default ``VOParams()``) holds the search's parameters;
    keyword ``overrides`` replace some of them for this call (``vo_select(..., fast=False)``).

    Args:
        pose: ``(3,)`` robot pose. ``radius``: robot radius (m).
        preferred: ``(2,)`` desired twist (e.g. from :func:`pure_pursuit`); clipped
            to the limits and added to the candidates, so it is returned unchanged
            whenever it is safe.
        discs: ``(D, 3)`` ``x, y, radius`` of moving discs (other robots, humans);
            ``(0, 3)`` for none. ``disc_vel``: ``(D, 2)`` their world velocities.
        static: static obstacles and walls, or ``None``.
        v_max: speed limit (m/s); candidates are :func:`sample_twists`
            ``(v_max, omega_max, n_v, n_w, v_min)`` plus the preferred twist.
        omega_max: turn-rate limit (rad/s).
        params: the search's parameters (below); ``None``: ``VOParams()``.
        goal_heading: world direction the robot should head to (e.g. towards its
            target). ``None``: the heading the preferred twist reaches after ``tau``.
        velocity: ``(2,)`` the robot's current world velocity (for ``reciprocal``).
        reciprocal: ``(D,)`` bool (or one bool for all): discs that are robots
            running this same rule; they are avoided reciprocally, each robot
            taking half of the avoidance (:func:`trajectory_disc_ttc`). Humans and
            non-reacting robots must be ``False`` (plain VO). A reciprocal disc
            that is already within the combined radius (margin included) is
            avoided plainly: the other robot evidently did not take its half,
            and the reciprocal displacement can pass a move towards it as
            separating (two followers squeezed into contact in a jam).
        **overrides: :class:`VOParams` fields replaced for this call.

    What each parameter does is :class:`VOParams`'s docstring.

    Penalty of a candidate ``(v, w)``: ``w_pref * hypot(w_speed * (v - v_p) / v_max,
    (w - w_p) / omega_max)`` + ``w_heading * |wrap(theta + w tau - goal_heading)| / pi``
    + ``side_bias * max(w - w_p, 0) / omega_max`` (distance to the optimal
    velocity, consistency with the target direction, keep right).
    With ``cost="velocity"`` the first term is instead ``w_pref * |u - u_p| / v_max``,
    ``u`` the candidate's mean world-frame velocity over ``tau`` (:func:`twist_velocities`,
    the chord of its arc) and ``u_p`` the preferred twist's: the measure of ORCA, which
    picks the velocity nearest the preferred one. In ``(v, w)`` a detour and a slow-down
    cost alike; in velocities a robot that turns by a mean angle ``phi`` at full speed
    moves ``2 v sin(phi / 2)`` off its preferred velocity, so turning past an obstacle
    is cheaper than crawling towards it (a slow-down postpones the contact beyond the
    horizon and counts as safe, the way a follower lagged behind its slot). Opt-in, off for
    the ``vo`` expert (docs/vo_defaults.md, "``cost=velocity``").

    Static circles are tested with the moving discs; polygons and walls with
    :func:`trajectory_static_ttc` (exact Minkowski sums). Safe candidates are
    those without predicted contact within ``horizon``; the one with the least
    penalty is returned. If that one stands still (``v = 0``) although the
    preferred twist moves — blocked, a state that would repeat forever — the
    safe moving candidate with the least penalty is taken if ``move_first`` is on
    and there is one; otherwise, if ``escape`` is on, the safe standing candidate
    that turns towards the most open direction is returned instead (the direction
    allowing the longest
    straight run after turning in place for ``tau``). If nothing is safe the
    candidate with the largest time to contact is returned (ties: slower, then
    lower penalty) with ``feasible=False``; if that one stands still (something
    is coming at the robot) and ``escape`` is on, the standing candidate that
    turns towards the most open direction is returned instead. Never raises
    for well-formed inputs (``ValueError`` for
    ``tau <= 0``, ``horizon <= 0``, ``n_arc < 1`` or an unknown ``model``).

    VO is a local method: a robot whose goal lies straight behind an obstacle
    can end up circling in front of it (pure pursuit pulls it back in); give it
    a path around the obstacle (e.g. the leader's path) rather than a bare goal.
    """
    robot = VORobots(
        np.asarray(pose, dtype=np.float64).reshape(1, 3),
        radius,
        np.asarray(preferred, dtype=np.float64).reshape(1, 2),
        v_max,
        omega_max,
        velocity=None if velocity is None else np.asarray(velocity, dtype=np.float64).reshape(1, 2),
        goal_heading=None if goal_heading is None else np.array([float(goal_heading)]),
    )
    res = vo_select_batch(robot, VODiscs(discs, disc_vel, reciprocal=reciprocal), static, params, **overrides)
    return VOResult(res.twist[0], bool(res.feasible[0]), int(res.n_safe[0]), float(res.min_time_to_collision[0]))


def _rotate_each(pts: np.ndarray, theta: np.ndarray, shared: bool) -> np.ndarray:
    """Rotate body-frame points by one angle per robot, ``theta`` ``(M,)``: ``pts``
    ``(..., 2)`` shared by all robots (``shared``) or ``(M, ..., 2)`` one set per
    robot. Returns ``(M, ..., 2)``."""
    x, y = pts[..., 0], pts[..., 1]
    lead = x.ndim if shared else x.ndim - 1
    c = np.cos(theta).reshape((-1,) + (1,) * lead)
    s = np.sin(theta).reshape((-1,) + (1,) * lead)
    out = np.empty((len(theta),) + x.shape[(0 if shared else 1):] + (2,))
    np.subtract(c * x, s * y, out=out[..., 0])
    np.add(s * x, c * y, out=out[..., 1])
    return out


def vo_select_batch(
    robots: VORobots,
    discs: VODiscs,
    static: StaticMap | None,
    params: VOParams | None = None,
    **overrides: Any,
) -> VOBatchResult:
    """:func:`vo_select` for ``N`` robots in one vectorised pass (same rules, same answers).

    Every robot runs the selection of :func:`vo_select` on its own view of one
    shared list of discs; all candidate x disc and candidate x obstacle tests of
    all robots are evaluated together.

    Args:
        robots: the ``N`` robots (:class:`VORobots`: poses, radii, preferred twists, limits, and
            optionally their velocities, current twists and goal headings).
        discs: the moving discs (robots, humans) any robot may have to avoid, with which robot keeps
            which and how (:class:`VODiscs`).
        static: static obstacles and walls, or ``None``.
        params: as for :func:`vo_select`; see ``allow_still_overlap`` below.
        **overrides: as for :func:`vo_select`.

    ``params.allow_still_overlap``: a disc the robot already overlaps (margin included)
    and that does not move relative to it (both standing) is not a
    contact for a candidate that stands still (turning in place
    included) — the gap is not shrinking. By default (the rule of
    :func:`vo_select`) every candidate is then "in contact at t = 0"
    but those moving away, and two robots that came to a stop face to
    face inside each other's margin stay there for good (measured:
    near-symmetric crossings of two followers). With this option they
    may turn in place, and the escape probe rates the directions away
    from each other as open.

    With ``fast`` each robot tests its candidates in order of increasing
    penalty, in passes shared by all robots, and stops at the first pass that
    holds a safe one (every cheaper candidate was tested and is unsafe, so the
    answer is the one of testing the whole grid): first its cheapest (the
    preferred twist, whose penalty is 0 unless a ``goal_heading`` is given),
    then up to the 24th, then the rest (a lone robot left after the first pass
    tests the rest at once). The escape probes of all
    robots that need one are evaluated together. ``fast=False`` tests every
    candidate of every robot in one pass.
    """
    p = (VOParams() if params is None else params).with_overrides(overrides)
    return _VOBatch(robots, discs, static, p).select(p.fast)


class _VOBatch:
    """One :func:`vo_select_batch` call: the robots, their candidates and the discs each of them
    keeps (set up once, in ``__init__``), and the tests run on them, each a named method
    (:meth:`contact_times`, :meth:`escape_turns`, :meth:`evaluate`, ...). :meth:`select` is the
    selection rule; the arguments are :func:`vo_select_batch`'s (``params`` with its overrides applied)."""

    def __init__(self, robots: VORobots, discs: VODiscs, static: StaticMap | None, params: VOParams) -> None:
        poses, radius, preferred, v_max, omega_max = robots.poses, robots.radius, robots.preferred, robots.v_max, robots.omega_max
        velocity, current, goal_heading = robots.velocity, robots.current, robots.goal_heading
        disc_mask, reciprocal, disc_horizon = discs.mask, discs.reciprocal, discs.horizon
        tau, n_arc, model, margin, v_min = params.tau, params.n_arc, params.model, params.margin, params.v_min
        self.d = np.asarray(discs.xyr, dtype=np.float64).reshape(-1, 3)
        self.dv = np.asarray(discs.vel, dtype=np.float64).reshape(-1, 2)
        h_search = float(params.horizon)
        h_static = h_search if params.horizon_static is None else float(min(params.horizon_static, h_search))
        # Each moving disc's horizon; the trajectories are traced to the longest (`horizon` below), the escape
        # probes keep the search's own (h_probe).
        self.h_probe = h_search
        self.h_moving = _disc_horizons(disc_horizon, self.d.shape[0], self.h_probe)
        horizon = _trace_horizon(self.h_probe, None if disc_horizon is None else self.h_moving)
        n_v, n_w, w_pref, w_heading, side_bias = params.n_v, params.n_w, params.w_pref, params.w_heading, params.side_bias
        escape, allow_still_overlap, w_current = params.escape, params.allow_still_overlap, params.w_current
        self.static, self.v_max, self.omega_max, self.v_min = static, v_max, omega_max, v_min
        self.horizon, self.h_static, self.tau, self.model, self.n_arc = horizon, h_static, tau, model, n_arc
        self.n_v, self.n_w, self.w_pref, self.w_heading, self.side_bias = n_v, n_w, w_pref, w_heading, side_bias
        self.escape, self.allow_still_overlap, self.goal_heading = escape, allow_still_overlap, goal_heading
        self.current, self.w_current, self.cost, self.recip_gap = current, w_current, params.cost, params.recip_gap
        self.move_first, self.static_reach = params.move_first, params.static_reach
        self.w_speed, self.escape_commit = params.w_speed, float(params.escape_commit)
        # The trajectories' end (static_reach: past the horizon; the moving discs are still cut at the horizon).
        t_end = self.t_end = _reach_end(params, horizon)
        self.t_cut = _reach_cut(params)
        poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
        self.poses = poses
        n = self.n = poses.shape[0]
        theta = self.theta = poses[:, 2]
        if isinstance(radius, (float, int)):
            rad = np.full(n, radius + margin)
        else:
            rad = np.asarray(radius, dtype=np.float64).reshape(-1) + margin
            if rad.shape[0] != n:
                rad = np.full(n, float(rad[0]))
        self.rad = rad
        pref = np.asarray(preferred, dtype=np.float64).reshape(n, 2)
        pv = self.pv = np.minimum(np.maximum(pref[:, 0], v_min), v_max)
        pw = self.pw = np.minimum(np.maximum(pref[:, 1], -omega_max), omega_max)
        if model == "arc":
            self.times, self.body = _grid_trajectories(
                float(v_max), float(omega_max), int(n_v), int(n_w), float(v_min), float(tau), float(t_end), int(n_arc)
            )
            if n == 1:  # numpy's per-call overhead dominates for one row: plain Python
                self.pref_pts = _trajectory_row(float(pv[0]), float(pw[0]), tau, t_end, n_arc, float(theta[0]))[None]
            else:
                self.pref_pts = _world_trajectories(pv, pw, theta, tau, t_end, n_arc)
        else:
            self.times = np.array([0.0, horizon])
            self.pref_pts = np.zeros((n, 2, 2))
            self.pref_pts[:, 1] = twist_velocities(theta, np.column_stack([pv, pw]), tau) * horizon
        # No trajectory gets farther than its path length, |v| horizon (cheap, rotation-free bound).
        self.ext = max(abs(v_min), abs(v_max)) * horizon
        vel = None if velocity is None else np.asarray(velocity, dtype=np.float64).reshape(n, 2)

        self.vel = vel
        self.poses2 = poses[:, :2]
        self.whole = n == 1  # then every row is robot 0's and the (1, ...) arrays broadcast as they are
        self.reciprocal, self.disc_mask = reciprocal, disc_mask

    def prepare(self) -> None:
        """The numpy reference's view of the discs and the static map (the compiled search builds its own):
        each robot's kept discs, padded to ``n_keep`` (``rel_k``, ``R_k``, ``dv_k``, ``h_k``, ``valid``,
        ``recip_k``, ``moving_k``, ``own_k``), and the static context."""
        n, poses, rad, ext, vel, static = self.n, self.poses, self.rad, self.ext, self.vel, self.static
        horizon, h_static, reciprocal, disc_mask = self.horizon, self.h_static, self.reciprocal, self.disc_mask
        # Moving discs and static circles in one list; each robot keeps those some of its
        # candidates can meet (and that disc_mask allows).
        d, dv = self.d, self.dv
        n_moving = d.shape[0]
        if static is not None and len(static.circles):
            sc = static.circles
            d = np.concatenate([d, sc])
            dv = np.concatenate([dv, np.zeros((len(sc), 2))])
        h_disc = np.full(d.shape[0], h_static)  # the static circles'
        h_disc[:n_moving] = self.h_moving
        rel = d[None, :, :2] - poses[:, None, :2]  # (N, D, 2)
        R = d[:, 2] + rad[:, None]  # (N, D)
        spd_h = np.hypot(dv[:, 0], dv[:, 1]) * h_disc  # (how far each disc gets within its horizon)
        recip = None
        if reciprocal is not False and np.any(reciprocal):
            recip = np.zeros((n, d.shape[0]), dtype=bool)
            recip[:, :n_moving] = np.asarray(reciprocal, dtype=bool)
            own = np.zeros(n) if vel is None else np.hypot(vel[:, 0], vel[:, 1])
            reach = np.where(recip, 2.0 * ext + own[:, None] * horizon, ext) + spd_h + R
        else:
            reach = (ext + spd_h) + R
        keep = rel[..., 0] ** 2 + rel[..., 1] ** 2 <= reach * reach
        if disc_mask is not None:
            mask = np.ones((n, d.shape[0]), dtype=bool)
            mask[:, :n_moving] = np.asarray(disc_mask, dtype=bool).reshape(n, n_moving)
            keep &= mask
        self.valid = None  # (N, n_keep) bool where the padded lists hold a real disc; None: no padding
        if n == 1:
            kidx = np.flatnonzero(keep[0])
            self.n_keep = len(kidx)
            self.rel_k, self.R_k, self.dv_k, self.h_k = rel[:, kidx], R[:, kidx], dv[kidx][None], h_disc[kidx][None]
            recip_k = None if recip is None else recip[:, kidx]
            self.moving_k = (kidx < n_moving)[None]
        else:
            self.n_keep = int(keep.sum(axis=1).max(initial=0))
            # Each robot's kept discs first (in their original order), padded to n_keep.
            kidx = np.argsort(~keep, axis=1, kind="stable")[:, :self.n_keep]
            rows = np.arange(n)[:, None]
            valid = self.valid = keep[rows, kidx]
            self.rel_k, self.R_k, self.dv_k, self.h_k = rel[rows, kidx], R[rows, kidx], dv[kidx], h_disc[kidx]
            recip_k = None if recip is None else recip[rows, kidx] & valid
            self.moving_k = valid & (kidx < n_moving)
        if recip_k is not None:
            # Within the combined radius of a reciprocal disc already (margin included),
            # reciprocity is dropped: the other robot evidently did not take its half, and
            # the reciprocal displacement 2 x(t) - v t can pass a move towards it as separating.
            # recip_gap widens that zone: closer than the combined radius plus recip_gap, avoided plainly.
            near = self.R_k + self.recip_gap
            recip_k = recip_k & (self.rel_k[..., 0] ** 2 + self.rel_k[..., 1] ** 2 > near * near)
        self.recip_k = recip_k
        self.own_k = np.zeros((n, 2)) if vel is None else vel
        # (circles=True: the escape probes test the static circles with the map; the grid with the discs)
        self.static_ctx = None if static is None else _static_context(self.poses2, rad, ext, static, circles=True)

    # ------------------------------------------------------------------ tests
    def contact_times(self, sub: np.ndarray, pts: np.ndarray, per: int, speed: np.ndarray | None = None) -> np.ndarray:
        """Contact time of trajectory rows ``pts`` ``(len(sub) * per, K+1, 2)``: ``per``
        consecutive rows for each robot of ``sub``; ``speed`` ``(len(sub) * per,)`` their candidates'
        speeds (for ``static_reach``; needed then)."""
        pc = _pieces(self.times, pts)
        hs = None  # static_reach: each row's static horizon
        if self.static_reach:
            assert speed is not None
            pv_rows = self.pv[sub[0]] if len(sub) == 1 else np.repeat(self.pv[sub], per)
            hs = _static_limits(speed, pv_rows, self.h_static, self.t_cut)
        ttc = np.full(pts.shape[0], np.inf)
        m = len(sub)
        # The robot of each row (None: one robot only, its (1, ...) arrays broadcast as they are).
        rows = None if self.whole else (np.full(pts.shape[0], sub[0]) if m == 1 else np.repeat(sub, per))
        if self.n_keep:
            if self.whole:
                rc, rl, rR, rdv, rown, rh, rvalid = (self.recip_k, self.rel_k, self.R_k, self.dv_k, self.own_k,
                                                     self.h_k, self.valid)
            else:
                r1 = sub if m == 1 else rows  # one robot: its (1, ...) slices broadcast over the rows
                rc = None if self.recip_k is None else self.recip_k[r1]
                rl, rR, rdv, rown, rh = self.rel_k[r1], self.R_k[r1], self.dv_k[r1], self.own_k[r1], self.h_k[r1]
                rvalid = None if self.valid is None else self.valid[r1]
            if rc is not None and not rc.any():
                rc = None
            t = _rows_disc_ttc(pc, rl, rR, rdv, rc, rown, self.allow_still_overlap)
            if hs is not None:  # the static circles' limit per row
                rm = self.moving_k if self.whole else self.moving_k[r1]
                rh = np.where(rm, rh, hs[:, None])
            far = t > rh
            if rvalid is not None:
                far |= ~rvalid
            t[far] = np.inf
            ttc = t.min(axis=1)
        if self.static is not None:
            ts = _rows_static_ttc(self.poses2, self.rad, rows, pc, self.ext, self.static, circles=False,
                                  ctx=self.static_ctx)
            ts[ts > (self.h_static if hs is None else hs)] = np.inf
            np.minimum(ttc, ts, out=ttc)
        return ttc

    def escape_turns(self, requests: list) -> list[int]:
        """Turn in place towards the most open direction, for several robots at once.

        For each request ``(k, eligible)`` (robot ``k``) pick, among its
        eligible standing (``v = 0``) candidates, the one whose heading after
        ``tau`` allows the longest straight run at ``v_max``; ties (several fully
        open directions) go to the least penalty. Used when standing still is
        the best the VO offers but would repeat forever (blocked) or only
        postpone a contact (something moving at the robot). Plain VO throughout
        (a probe is not a commitment).

        Probes: against the moving discs, turn in place for ``tau`` then run
        straight until ``horizon`` (the discs move meanwhile); against the
        static map (circles included), a straight run from the current position
        for ``horizon - tau`` s (``horizon`` if that is shorter than ``tau``). The
        static probe starts moving at once so that a robot already within the
        margin of an obstacle rates the directions leading away from it as
        open: by the overlap rule a probe that starts by standing still is "in
        contact at t = 0" in every direction, and the robot kept turning back
        towards the obstacle (measured: a follower stuck for the rest of an
        episode of paper_cbs_switch at an obstacle between it and its slot).
        """
        twists, tau, horizon, v_max = self.twists, self.tau, self.h_probe, self.v_max
        req_k, req_c = [], []
        for r, (k, eligible) in enumerate(requests):
            stop = np.flatnonzero(eligible & (twists[k, :, 0] == 0.0))
            req_k.append(np.full(len(stop), r))
            req_c.append(stop)
        rq = np.concatenate(req_k)
        cand = np.concatenate(req_c)
        ks = robot = np.array([k for k, _ in requests])[rq]
        hd = self.theta[robot] + twists[ks, cand, 1] * tau
        cos_h, sin_h = np.cos(hd), np.sin(hd)
        ttc_p = np.full(len(rq), np.inf)
        if self.n_keep:
            run = v_max * max(horizon - tau, 0.0)
            times3 = np.array([0.0, tau, max(horizon, tau + 1e-9)])
            pts = np.zeros((len(rq), 3, 2))
            pts[:, 2, 0] = run * cos_h
            pts[:, 2, 1] = run * sin_h
            rows = robot if self.n > 1 else np.zeros(1, dtype=np.intp)
            t = _rows_disc_ttc(_pieces(times3, pts), self.rel_k[rows], self.R_k[rows], self.dv_k[rows], None, None,
                               self.allow_still_overlap)
            t[(t > self.h_k[rows]) | ~self.moving_k[rows]] = np.inf
            ttc_p = t.min(axis=1)
        if self.static is not None:
            t_run = horizon - tau if horizon > 2.0 * tau else horizon
            pts = np.zeros((len(rq), 2, 2))
            pts[:, 1, 0] = v_max * t_run * cos_h
            pts[:, 1, 1] = v_max * t_run * sin_h
            # (the batch's static context: its reach, ext >= v_max t_run, covers the probes)
            ts = _rows_static_ttc(self.poses2, self.rad, None if self.whole else robot,
                                  _pieces(np.array([0.0, t_run]), pts), self.ext, self.static, circles=True,
                                  ctx=self.static_ctx)
            ts[ts > self.h_static] = np.inf
            np.minimum(ttc_p, ts, out=ttc_p)
        pen = self.penalty[ks, cand]
        cur = None if self.escape_commit <= 0.0 or self.current is None else \
            np.asarray(self.current, dtype=np.float64).reshape(self.n, 2)
        out = []
        for r in range(len(requests)):
            rows_r = np.flatnonzero(rq == r)
            if cur is not None:
                # escape_commit: a robot already turning in place keeps turning that way unless the other way
                # is open for longer by more than escape_commit s (no left-right dithering in front of a block).
                k = requests[r][0]
                if turning_in_place(float(cur[k, 0]), float(cur[k, 1]), self.v_max, self.omega_max):
                    same = rows_r[twists[k, cand[rows_r], 1] * cur[k, 1] > 0.0]
                    if len(same) and ttc_p[same].max() >= ttc_p[rows_r].max() - self.escape_commit:
                        rows_r = same
            out.append(int(cand[rows_r[np.lexsort((pen[rows_r], -ttc_p[rows_r]))[0]]]))
        return out

    # ------------------------------------------------------------------ the candidate grid
    def _candidates(self) -> None:
        """Each robot's candidates (its preferred twist first, then the grid), their penalties
        and penalty order, and the bookkeeping of the passes (``ttc``: nan = not tested)."""
        n, theta, tau, v_max, omega_max = self.n, self.theta, self.tau, self.v_max, self.omega_max
        pv, pw = self.pv, self.pw
        grid = sample_twists(v_max, omega_max, self.n_v, self.n_w, self.v_min)
        g1 = self.g1 = grid.shape[0] + 1
        twists = self.twists = np.empty((n, g1, 2))
        twists[:, 0, 0], twists[:, 0, 1] = pv, pw  # the preferred twist first: it wins ties
        twists[:, 1:] = grid
        gh = theta + pw * tau if self.goal_heading is None else np.asarray(self.goal_heading, dtype=np.float64).reshape(n)
        dv_ = (twists[..., 0] - pv[:, None]) / (v_max if v_max > 0 else 1.0)
        dw_ = (twists[..., 1] - pw[:, None]) / (omega_max if omega_max > 0 else 1.0)
        head = np.abs(wrap_angle(theta[:, None] + twists[..., 1] * tau - gh[:, None])) / math.pi
        if self.cost == "velocity":
            # Distance between mean world-frame velocities, rotation-free: measured in each robot's own frame.
            vs = v_max if v_max > 0 else 1.0
            uv = np.empty((n, g1, 2))
            uv[:, 0] = [_body_velocity(float(a), float(b), tau) for a, b in zip(pv, pw)]
            uv[:, 1:] = _grid_velocities(v_max, omega_max, self.n_v, self.n_w, self.v_min, tau)
            near = np.hypot((uv[..., 0] - uv[:, :1, 0]) / vs, (uv[..., 1] - uv[:, :1, 1]) / vs)
        else:
            near = np.hypot(self.w_speed * dv_, dw_)
        penalty = self.w_pref * near + self.w_heading * head + self.side_bias * np.maximum(dw_, 0.0)
        if self.w_current and self.current is not None:
            # Commitment: among the alternatives to the preferred twist, prefer those close to the twist the
            # robot is driving now, so that an avoidance manoeuvre, once begun, is kept (no left-right flips).
            cur = np.asarray(self.current, dtype=np.float64).reshape(n, 2)
            dcv = (twists[..., 0] - cur[:, :1]) / (v_max if v_max > 0 else 1.0)
            dcw = (twists[..., 1] - cur[:, 1:]) / (omega_max if omega_max > 0 else 1.0)
            penalty[:, 1:] += self.w_current * np.hypot(dcv, dcw)[:, 1:]
        self.penalty = penalty
        self.order = np.argsort(penalty, axis=1, kind="stable")  # stable: ties keep grid order (preferred first)
        self.pts: np.ndarray | None = None  # (N, g1, K+1, 2) trajectories, built when more than the preferred twists are tested
        self.ttc = np.full((n, g1), np.nan)  # nan: not tested
        # Standing candidates (v = 0) all have the same trajectory (none) whatever their turn
        # rate, hence the same contact time: one of them, (0, 0), is tested with a robot's
        # second pass and its result copied to the others (the escape rule needs them).
        self.still = np.flatnonzero((grid[:, 0] == 0.0) & (grid[:, 1] == 0.0)) + 1
        self.zero = twists[:, :, 0] == 0.0

    def all_points(self) -> np.ndarray:
        """``(N, g1, K+1, 2)`` the world-frame trajectory of every candidate of every robot."""
        n, theta = self.n, self.theta
        if self.model == "arc":
            rot = _rotate(self.body, float(theta[0]))[None] if n == 1 else _rotate_each(self.body, theta, True)
            return np.concatenate([self.pref_pts[:, None], rot], axis=1)
        mv = twist_velocities(np.repeat(theta, self.g1), self.twists.reshape(-1, 2), self.tau)
        return np.stack([np.zeros_like(mv), mv * self.horizon], axis=1).reshape(n, self.g1, 2, 2)

    def evaluate(self, robots: np.ndarray, cols: np.ndarray) -> None:
        """Contact times of candidates ``cols`` ``(len(robots), h)`` of ``robots`` into ``ttc``."""
        h = cols.shape[1]
        if self.pts is None:
            self.pts = self.all_points()
        pts = self.pts
        rows_pts = pts[robots[:, None], cols].reshape(len(robots) * h, *pts.shape[2:])
        speed = self.twists[robots[:, None], cols, 0].reshape(-1) if self.static_reach else None
        self.ttc[robots[:, None], cols] = self.contact_times(robots, rows_pts, h, speed).reshape(len(robots), h)

    def evaluate_ranks(self, robots: np.ndarray, lo: np.ndarray, hi: np.ndarray, extra: np.ndarray | None = None) -> None:
        """Test each robot's candidates of penalty rank ``lo[k] <= rank < hi[k]`` (lists of
        unequal length are padded by repeating their last candidate: tested twice, harmless),
        and the candidates ``extra`` of every robot."""
        go = hi > lo
        robots, lo, hi = robots[go], lo[go], hi[go]
        if not len(robots):
            return
        h = int((hi - lo).max())
        ranks = np.minimum(lo[:, None] + np.arange(h), hi[:, None] - 1)
        cols = self.order[robots[:, None], ranks]
        if extra is not None and len(extra):
            cols = np.concatenate([cols, np.broadcast_to(extra, (len(robots), len(extra)))], axis=1)
        self.evaluate(robots, cols)

    # ------------------------------------------------------------------ the rule
    def select(self, fast: bool) -> VOBatchResult:
        """The selection of :func:`vo_select_batch` (see its docstring)."""
        if compiled_search():
            return self.select_compiled(fast)
        self.prepare()
        n, pv, pw = self.n, self.pv, self.pw
        ttc0 = None
        if fast and self.goal_heading is None:
            # The preferred twist has penalty 0, the minimum: where it is safe it is the answer.
            ttc0 = self.contact_times(np.arange(n), self.pref_pts, 1, pv)
            if np.isinf(ttc0).all():
                out = np.empty((n, 2))
                out[:, 0], out[:, 1] = pv, pw
                ok = np.ones(n, dtype=bool)
                return VOBatchResult(out, ok, np.ones(n, dtype=np.int64), np.full(n, np.inf), ~ok, ok, ok.copy())
        self._candidates()
        g1, ttc, twists, penalty = self.g1, self.ttc, self.twists, self.penalty
        if ttc0 is not None:
            ttc[:, 0] = ttc0

        # Candidates are tested in order of increasing penalty, in passes, and a robot
        # stops at the first pass that holds a safe candidate: every cheaper one was
        # tested and is unsafe, so the answer is the one testing the whole grid gives.
        # Pass 1: each robot's least-penalty candidate (the preferred twist unless a
        # goal_heading is given: the fast path); pass 2: up to rank _FIRST_STAGE; pass 3: the rest. A
        # single robot left after pass 1 tests the rest at once (a pass costs more than
        # the rows it saves). ``fast=False``: the whole grid in one pass.
        everyone = np.arange(n)
        if not fast:
            self.evaluate(everyone, self.order)
            done = np.full(n, g1)
        else:
            done = np.ones(n, dtype=np.intp)
            if ttc0 is None:  # (otherwise pass 1, the preferred twists alone, was done above)
                self.evaluate_ranks(everyone, np.zeros(n, dtype=np.intp), done)
            for target in (min(_FIRST_STAGE, g1), g1):
                tested = np.arange(g1) < done[:, None]
                pending = everyone[~(np.isinf(np.take_along_axis(ttc, self.order, axis=1)) & tested).any(axis=1)]
                if not len(pending):
                    break
                if len(pending) == 1:
                    target = g1
                hi = np.full(len(pending), target)
                self.evaluate_ranks(pending, done[pending], hi, self.still if self.escape and target < g1 else None)
                done[pending] = np.maximum(done[pending], hi)
                if target == g1:
                    break

        zero = self.zero
        known = zero & ~np.isnan(ttc)
        if known.any():
            rows_z = np.flatnonzero(known.any(axis=1))
            ttc_z = np.where(known[rows_z], ttc[rows_z], -np.inf).max(axis=1)  # (all known ones are equal)
            ttc[rows_z] = np.where(zero[rows_z], ttc_z[:, None], ttc[rows_z])
        feasible = np.ones(n, dtype=bool)
        ttc_out = np.full(n, np.inf)
        escaped = np.zeros(n, dtype=bool)
        pref_safe = np.isinf(ttc[:, 0])
        accepted = pref_safe & (done == 1)
        safe = np.isinf(ttc)
        n_safe = np.count_nonzero(safe, axis=1)
        choice = np.argmin(np.where(safe, penalty, np.inf), axis=1)
        requests = []  # (k, eligible standing candidates) of the robots that escape
        chosen_v = twists[everyone, choice, 0]
        if self.move_first:
            # Blocked (the least-penalty safe candidate stands although the preferred twist moves): the
            # least-penalty safe candidate that moves, if any, before the escape turn. Its candidates not
            # tested yet are tested now (fast passes stop at the first safe one, here a standing one).
            stuck = np.flatnonzero((n_safe > 0) & (chosen_v <= 0.0) & (pv > 0.0))
            if len(stuck):
                untested = np.isnan(ttc[stuck])
                cnt = untested.sum(axis=1)
                if cnt.any():
                    h = int(cnt.max())
                    cols = np.argsort(~untested, axis=1, kind="stable")[:, :h]
                    cols = np.where(np.arange(h) < cnt[:, None], cols, cols[:, :1])  # pad: repeat the first
                    self.evaluate(stuck[cnt > 0], cols[cnt > 0])
                go = np.isinf(ttc[stuck]) & (twists[stuck, :, 0] > 0.0)
                alt = np.argmin(np.where(go, penalty[stuck], np.inf), axis=1)
                moved = go.any(axis=1)
                choice[stuck[moved]] = alt[moved]
                chosen_v = twists[everyone, choice, 0]
        # Escapes turn in place: a robot whose choice stands (v == 0; a reversing choice with v_min < 0 was
        # tested and is kept) while its preferred twist moves, or which has nothing safe.
        special = (n_safe == 0) | ((chosen_v == 0.0) & (pv > 0.0)) if self.escape else n_safe == 0
        for k in np.flatnonzero(special).tolist():  # rare: resolved robot by robot
            tw = twists[k]
            j = choice[k]
            if n_safe[k]:
                requests.append((k, None))  # None: its safe candidates (known once all standing ones are tested)
                continue
            # lexsort: last key is primary -> largest ttc, then slowest, then least penalty.
            tt = ttc[k]
            j = choice[k] = int(np.lexsort((penalty[k], np.abs(tw[:, 0]), -tt))[0])
            if self.escape and tw[j, 0] == 0.0:
                # Standing still only postpones the contact (something is coming at the
                # robot): turn in place towards the most open direction, to run next.
                requests.append((k, (tt == tt[j]) & (tw[:, 0] == 0.0)))
        if requests:
            # The escape rule needs to know which standing candidates are safe: test those not tested yet.
            ks = np.array([k for k, _ in requests])
            untested = np.isnan(ttc[ks]) & (twists[ks, :, 0] == 0.0)
            if untested.any():
                cnt = untested.sum(axis=1)
                h = int(cnt.max())
                cols = np.argsort(~untested, axis=1, kind="stable")[:, :h]
                cols = np.where(np.arange(h) < cnt[:, None], cols, cols[:, :1])  # pad: repeat the first
                has = cnt > 0
                self.evaluate(ks[has], cols[has])
            requests = [(k, np.isinf(ttc[k]) if eligible is None else eligible) for k, eligible in requests]
            for (k, _), j in zip(requests, self.escape_turns(requests)):
                choice[k] = j
                escaped[k] = True
        choice = np.asarray(choice)
        twist_out = twists[everyone, choice]
        none_safe = n_safe == 0
        feasible[none_safe] = False
        ttc_out[none_safe] = ttc[everyone, choice][none_safe]
        n_safe[accepted] = 1
        return VOBatchResult(twist_out, feasible, n_safe, ttc_out, escaped, accepted, pref_safe)

    # ------------------------------------------------------------------ the compiled twin
    def select_compiled(self, fast: bool) -> VOBatchResult:
        """:meth:`select` by :mod:`swarm_env.control.vo_kernel`: the same rule and bits. What numpy computes
        here (as :meth:`select` does) is what is not correctly rounded the same way in the kernel —
        the preferred twists' trajectories and (chord model) the candidates'; the kernel keeps the
        discs, builds the static context, computes the penalties and their order, and runs the
        contact tests, the passes and the escape probes."""
        from swarm_env.control import vo_kernel

        n = self.n
        c = np.ascontiguousarray
        grid, times, body = _kernel_plan(float(self.v_max), float(self.omega_max), int(self.n_v), int(self.n_w),
                                         float(self.v_min), float(self.tau), float(self.t_end), self.model,
                                         int(self.n_arc))
        if self.model == "arc":
            theta = self.theta
            if n == 1:  # as all_points: math.cos for one robot
                cos_t, sin_t = np.array([math.cos(float(theta[0]))]), np.array([math.sin(float(theta[0]))])
            else:
                cos_t, sin_t = np.cos(theta), np.sin(theta)
            trajectories = (body, cos_t, sin_t, _NO_TRAJECTORIES)
        else:
            self._candidates()
            trajectories = (body, _E1, _E1, c(self.all_points(), dtype=np.float64))
        has_current = bool(self.w_current) and self.current is not None
        commit = self.escape_commit > 0.0 and self.current is not None
        has_goal = self.goal_heading is not None
        search = (float(self.tau), float(self.v_max), float(self.omega_max), float(self.w_pref), float(self.w_heading),
                  float(self.side_bias), float(self.w_current), has_current,
                  _f64(self.current).reshape(n, 2) if has_current or commit else np.zeros((n, 2)), has_goal,
                  _f64(self.goal_heading).reshape(n) if has_goal else _E1, self.cost == "velocity",
                  _kernel_velocities(float(self.v_max), float(self.omega_max), int(self.n_v), int(self.n_w),
                                     float(self.v_min), float(self.tau)), bool(self.move_first),
                  bool(self.static_reach), float(self.t_cut), float(self.w_speed), float(self.escape_commit) if commit else 0.0)
        plan = (times, _f64(self.pref_pts), trajectories, grid)
        robots = (_f64(self.pv), _f64(self.pw), _f64(self.theta))
        flags = (bool(fast), bool(self.escape), _FIRST_STAGE, bool(self.allow_still_overlap))
        twist, feasible, n_safe, ttc_out, escaped, accepted, pref_safe = vo_kernel.select(
            self._kernel_world(), plan, robots, search, flags, (float(self.v_max), float(self.tau), float(self.h_probe)))
        return VOBatchResult(twist, feasible, n_safe, ttc_out, escaped, accepted, pref_safe)

    def _kernel_world(self) -> tuple:
        """The robots, the discs and the static map as :mod:`swarm_env.control.vo_kernel` takes them (writeable
        copies throughout, as :func:`swarm_env.control.vo_kernel.follower_select` builds its own: one compiled
        search for both)."""
        n = self.n
        d, dv, vel = self.d, self.dv, self.vel
        n_moving = d.shape[0]
        spd_h = np.hypot(dv[:, 0], dv[:, 1]) * self.h_moving
        reciprocal = self.reciprocal
        has_recip = bool(reciprocal is not False and np.any(reciprocal))
        if has_recip:
            recip_in = np.array(np.broadcast_to(np.asarray(reciprocal, dtype=bool), (n, n_moving)), order="C")
            own_speed = np.zeros(n) if vel is None else np.hypot(vel[:, 0], vel[:, 1])
        else:
            recip_in, own_speed = np.zeros((n, n_moving), dtype=bool), np.zeros(n)
        has_mask = self.disc_mask is not None
        mask = np.array(np.asarray(self.disc_mask, dtype=bool).reshape(n, n_moving), order="C") if has_mask else recip_in
        own_vel = np.zeros((n, 2)) if vel is None else _f64(vel)
        return ((_f64(self.poses2), _f64(self.rad), float(self.ext), float(self.horizon), float(self.h_static), _f64(d),
                 _f64(dv), spd_h, _f64(self.h_moving), has_recip, recip_in, _f64(own_speed), own_vel, has_mask, mask,
                 self.static is not None)
                + _kernel_map(self.static) + (float(self.recip_gap),))


def _reach_cut(params: VOParams) -> float:
    """``static_reach``'s latest static cut (s), ``s h_s`` (``h_s`` the static horizon); ``h_s`` when off."""
    horizon = float(params.horizon)
    h_static = float(horizon if params.horizon_static is None else min(params.horizon_static, horizon))
    return h_static * float(params.static_reach) if params.static_reach else h_static


def _reach_end(params: VOParams, trace: float | None = None) -> float:
    """How far in time (s) the candidates' trajectories run: ``trace`` (the longest disc horizon,
    :func:`_trace_horizon`; ``None``: ``params.horizon``), or with ``static_reach`` to its latest cut
    (:func:`_reach_cut`) if that is later (``vo_kernel.follower_select`` computes the same)."""
    horizon = float(params.horizon if trace is None else trace)
    return max(horizon, _reach_cut(params)) if params.static_reach else horizon


def _trace_horizon(horizon: float, disc_horizon: np.ndarray | None) -> float:
    """The time (s) the candidates are traced to: the longest of ``horizon`` and the discs' own horizons."""
    if disc_horizon is None or not len(disc_horizon):
        return float(horizon)
    return max(float(horizon), float(np.max(disc_horizon)))


def _disc_horizons(disc_horizon: np.ndarray | None, n_discs: int, horizon: float) -> np.ndarray:
    """``(D,)`` each moving disc's horizon: ``disc_horizon`` checked, or ``horizon`` for all."""
    if disc_horizon is None:
        return np.full(n_discs, float(horizon))
    h = np.array(disc_horizon, dtype=np.float64).reshape(-1)
    if h.shape[0] != n_discs:
        raise ValueError(f"VODiscs.horizon must hold one horizon per disc ({n_discs}), got {h.shape[0]}")
    if not np.all(np.isfinite(h) & (h > 0)):
        raise ValueError(f"VODiscs.horizon must be finite numbers > 0 (s), got {h.tolist()}")
    return h


def _static_limits(speed: np.ndarray, pv: np.ndarray, h_static: float, t_cut: float) -> np.ndarray:
    """``static_reach``'s static horizon per trajectory (see :func:`vo_select`): ``min(max(h_s,
    (v_p h_s) / |v|), t_cut)`` for ``|v| > 0``, ``h_s`` for a standing one. ``speed`` and ``pv`` (the
    robot's clipped preferred speed) broadcast. :mod:`swarm_env.control.vo_kernel` computes the same bits."""
    v = np.abs(speed)
    moves = v > 0.0
    lim = np.minimum(np.maximum(h_static, (pv * h_static) / np.where(moves, v, 1.0)), t_cut)
    return np.where(moves, lim, h_static)


def _f64(a: Any) -> np.ndarray:
    """A writeable C-ordered float64 copy of ``a`` (one array type for the kernels whatever the input)."""
    return np.array(a, dtype=np.float64, order="C")


@lru_cache(maxsize=64)
def _kernel_plan(v_max: float, omega_max: float, n_v: int, n_w: int, v_min: float, tau: float, horizon: float,
                 model: str, n_arc: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(grid, times, body)`` for :mod:`swarm_env.control.vo_kernel`: the candidate grid (:func:`sample_twists`),
    the trajectories' times and (arc model) the grid's body-frame trajectories ``(G, K+1, 2)``
    (``_grid_trajectories``; empty for the chord model). Writeable copies of the cached read-only
    arrays, so that the kernels see one array type whatever the caller (never written to)."""
    grid = np.array(sample_twists(v_max, omega_max, n_v, n_w, v_min), dtype=np.float64, order="C")  # (checks them)
    if model == "arc":
        times, body = (np.array(a, dtype=np.float64, order="C")
                       for a in _grid_trajectories(v_max, omega_max, n_v, n_w, v_min, tau, horizon, n_arc))
    else:
        times, body = np.array([0.0, horizon]), _NO_BODY
    return grid, times, body


@lru_cache(maxsize=64)
def _kernel_velocities(v_max: float, omega_max: float, n_v: int, n_w: int, v_min: float, tau: float) -> np.ndarray:
    """A writeable copy of :func:`_grid_velocities` for :mod:`swarm_env.control.vo_kernel` (``cost="velocity"``;
    passed whatever the cost, so that the kernels compile once)."""
    return np.array(_grid_velocities(v_max, omega_max, n_v, n_w, v_min, tau), dtype=np.float64, order="C")


_FOLLOWER_PLANS: dict[tuple[int, float], tuple] = {}


def _follower_plan(params: VOParams, v_max: float, omega_max: float, trace: float | None = None) -> tuple:
    """What :func:`swarm_env.control.vo_kernel.follower_select` takes besides the world for ``params`` (arc
    model), the limits and ``trace`` (the time the candidates are traced to, :func:`_trace_horizon`;
    ``None``: ``params.horizon``): ``(plan, scalars, flags)`` (see there), cached per ``params`` object
    and ``trace`` (the values are those :class:`_VOBatch` derives from them)."""
    p = params
    horizon = p.horizon
    trace = float(horizon if trace is None else trace)
    key = (id(params), trace)
    hit = _FOLLOWER_PLANS.get(key)
    if hit is not None and hit[0] is params and hit[1] == v_max and hit[2] == omega_max:
        return hit[3]
    h_static = float(horizon if p.horizon_static is None else min(p.horizon_static, horizon))
    ext = max(abs(p.v_min), abs(v_max)) * trace  # as _VOBatch.__init__
    t_end = _reach_end(p, trace)
    plan = (*_kernel_plan(float(v_max), float(omega_max), int(p.n_v), int(p.n_w), float(p.v_min), float(p.tau),
                          float(t_end), "arc", int(p.n_arc)),
            _kernel_velocities(float(v_max), float(omega_max), int(p.n_v), int(p.n_w), float(p.v_min), float(p.tau)))
    scalars = (float(p.margin), float(horizon), h_static, float(ext), float(p.tau), int(p.n_arc),
               float(p.v_min), float(v_max), float(omega_max), float(p.w_pref), float(p.w_heading),
               float(p.side_bias), float(p.w_current), float(p.recip_gap), _reach_cut(p), float(p.w_speed),
               float(p.escape_commit), trace, float(getattr(p, "robot_margin", 0.0)))
    reciprocal = bool(getattr(p, "reciprocal", False))  # (safety.AvoidanceParams': the followers avoid each other so)
    flags = (bool(p.fast), bool(p.escape), bool(p.allow_still_overlap), reciprocal, bool(p.w_current), _FIRST_STAGE,
             p.cost == "velocity", bool(p.move_first), bool(p.static_reach))
    value = (plan, scalars, flags)
    if len(_FOLLOWER_PLANS) >= 32:
        _FOLLOWER_PLANS.pop(next(iter(_FOLLOWER_PLANS)))
    _FOLLOWER_PLANS[key] = (params, v_max, omega_max, value)  # (params kept alive: its id stays unique)
    return value


def _kernel_map(static: StaticMap | None) -> tuple:
    """``(W, H, circles, polygon A, N, L, ux, uy, centre, bound)`` of ``static`` as writeable contiguous
    arrays (one set of types whatever the map, so the kernel compiles once), cached with the map's
    polygon arrays; empty ones for no map."""
    if static is None:
        return _NO_MAP
    g = _polygon_arrays(static)
    if "kernel" not in g:
        c = np.array  # copies: the map's own arrays are read-only, a different type for numba
        W, H = static.size
        circles = static.circles.reshape(-1, 3)
        g["kernel"] = (float(W), float(H), c(circles, dtype=np.float64, order="C"),
                       *(c(g[k], dtype=np.float64, order="C") for k in ("A", "N", "L", "ux", "uy", "centre", "bound")))
    return g["kernel"]


_E1 = np.empty(0)
_NO_BODY = np.empty((0, 1, 2))
_NO_TRAJECTORIES = np.empty((0, 1, 1, 2))
_NO_MAP = (0.0, 0.0, np.empty((0, 3)), np.empty((0, 1, 2)), np.empty((0, 1, 2)), np.empty((0, 1)), np.empty((0, 1)),
           np.empty((0, 1)), np.empty((0, 2)), np.empty(0))
