"""Pure pursuit and velocity-obstacle geometry for differential-drive robots.

One implementation used by the env's robot leader (paper 003 Fig. 1: pure
pursuit along its path, then a velocity-obstacle check against obstacles,
humans and robots) and by the scripted VO expert for the followers (paper 003
Fig. 2). Everything is a pure, vectorised numpy function.

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
twist space ``(v, omega)`` and mapped to the world-frame mean velocity of the
arc driven during ``tau`` seconds (:func:`twist_velocities`); that velocity is
what is tested against the cones (the usual VO-for-nonholonomic reduction).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from swarm_env.geometry import StaticMap
from swarm_env.paths import PolylinePath

__all__ = [
    "wrap_angle",
    "pure_pursuit",
    "lookahead_target",
    "sample_twists",
    "twist_velocities",
    "disc_time_to_collision",
    "vo_discs_inside",
    "static_time_to_collision",
    "vo_polygons_inside",
    "VOResult",
    "vo_select",
]

_TWO_PI = 2.0 * math.pi
# Below this distance (m) the target counts as reached: the pursuit angle is undefined.
_EPS_DIST = 1e-9


def wrap_angle(a):
    """Wrap angle(s) to ``[-pi, pi)``. A Python/numpy scalar gives a float, an array an array."""
    if isinstance(a, (float, int)):
        return (a + math.pi) % _TWO_PI - math.pi
    out = np.mod(np.asarray(a, dtype=np.float64) + math.pi, _TWO_PI) - math.pi
    return float(out) if out.ndim == 0 else out


# ---------------------------------------------------------------------------- pure pursuit
def pure_pursuit(
    pose: np.ndarray,
    target: np.ndarray,
    v_max: float,
    omega_max: float,
    time_gap: float,
    *,
    keep_curvature: bool = True,
) -> np.ndarray:
    """Pure-pursuit twist towards a target point (paper 003 Eqs. 3-4, 9, 11).

    Vectorised: ``pose`` ``(N, 3)`` or ``(3,)``, ``target`` ``(N, 2)`` or ``(2,)``
    (broadcast against each other) -> twist ``(N, 2)`` or ``(2,)`` ``(v, omega)``.

    With ``l`` the distance to the target and ``alpha = wrap(atan2(yT - y, xT - x) - theta)``:

    * ``|alpha| <= pi/2`` (target ahead): ``v = min(l / time_gap, v_max)`` (Eq. 9's
      distance over a time gap, saturated) and ``omega = v * 2 sin(alpha) / l``
      (Eq. 4: the arc through the target tangent to the heading has curvature
      ``2 sin(alpha) / l``). If ``|omega|`` exceeds ``omega_max`` it is saturated;
      with ``keep_curvature`` (default) ``v`` is reduced as well so that
      ``omega / v`` stays ``2 sin(alpha) / l`` — the robot keeps to the arc through
      the target instead of orbiting it (slows down in sharp turns).
      ``keep_curvature=False`` clips ``omega`` only.
    * ``|alpha| > pi/2`` (target behind): driving forward would take the robot
      away, so ``v = 0`` (``v`` scaled by ``max(cos alpha, 0)``) and it turns in
      place towards the target with ``omega = sign(alpha) * min(omega_max,
      2 v_nom / l)`` — the turn rate Eq. 4 gives at ``|alpha| = pi/2``, so omega
      is continuous there.
    * ``l < 1e-9``: zero twist.

    Raises:
        ValueError: ``time_gap <= 0`` or negative limits.
    """
    if not time_gap > 0.0:
        raise ValueError(f"time_gap must be > 0, got {time_gap!r}")
    if v_max < 0.0 or omega_max < 0.0:
        raise ValueError("v_max and omega_max must be >= 0")
    pose = np.asarray(pose, dtype=np.float64)
    target = np.asarray(target, dtype=np.float64)
    single = pose.ndim == 1 and target.ndim == 1
    P = pose.reshape(-1, 3)
    T = target.reshape(-1, 2)
    dx = T[:, 0] - P[:, 0]
    dy = T[:, 1] - P[:, 1]
    dist = np.hypot(dx, dy)
    alpha = wrap_angle(np.arctan2(dy, dx) - P[:, 2])
    reached = dist < _EPS_DIST
    safe_l = np.where(reached, 1.0, dist)
    v_nom = np.where(reached, 0.0, np.minimum(dist / time_gap, v_max))
    kappa = 2.0 * np.sin(alpha) / safe_l
    ahead = np.abs(alpha) <= 0.5 * math.pi
    v = np.where(ahead, v_nom, 0.0)
    omega = v * kappa
    sat = np.abs(omega) > omega_max
    if keep_curvature:
        v = np.where(sat, omega_max / np.where(sat, np.abs(kappa), 1.0), v)
    omega = np.clip(omega, -omega_max, omega_max)
    turn = np.where(alpha >= 0.0, 1.0, -1.0) * np.minimum(omega_max, 2.0 * v_nom / safe_l)
    omega = np.where(ahead, omega, turn)
    out = np.column_stack([v, omega])
    out[reached] = 0.0
    return out[0] if single else out


def lookahead_target(
    path: PolylinePath,
    position: np.ndarray,
    s_progress: float,
    lookahead: float,
    window: float | None = None,
) -> tuple[np.ndarray, float]:
    """Pure pursuit's carrot on a path, with monotone progress.

    Projects ``position`` onto the part of ``path`` between ``s_progress`` and
    ``s_progress + window`` (default ``window = 2 * lookahead + 1`` m: far more
    than a robot advances in one step, short enough that a path passing near
    itself is not short-cut), then returns the point ``lookahead`` metres further
    along (the path's end point once beyond it) and the new progress
    ``s >= s_progress``. Feed ``s`` back as ``s_progress`` next step.

    Returns:
        carrot ``(2,)`` world point, new progress ``s`` (m of arc length).
    """
    if window is None:
        window = 2.0 * lookahead + 1.0
    s_progress = float(s_progress)
    s = max(path.project(position, s_min=s_progress, s_max=s_progress + window), s_progress)
    s = min(s, path.length)
    return path.point_at(s + lookahead), s


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


def twist_velocities(theta: float, twists: np.ndarray, tau: float) -> np.ndarray:
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
def _ray_disc_ttc(px, py, R2, wx, wy, limit):
    """Elementwise first time ``t`` in ``[0, limit]`` with ``|w t - p| < R`` (arrays broadcast).

    ``p`` obstacle minus robot position, ``w`` robot minus obstacle velocity,
    ``R2 = R**2``. Entry time: the earlier root of ``|w|^2 t^2 - 2 (w.p) t + |p|^2 - R^2``
    in the cancellation-free form ``c / (w.p + sqrt(disc))``; it exists when
    ``w.p > 0`` (approaching) and ``disc > 0`` (not grazing). Overlapping at ``t = 0``:
    ``0`` unless the distance grows (``w.p < 0``, or ``w.p == 0`` with ``w != 0``).
    ``inf`` where there is no entry within ``limit``.
    """
    wp = wx * px + wy * py
    ww = wx * wx + wy * wy
    c = px * px + py * py - R2
    disc = wp * wp - ww * c
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where((wp > 0.0) & (disc > 0.0), c / (wp + np.sqrt(np.maximum(disc, 0.0))), np.inf)
    t = np.where(c < 0.0, np.where((wp > 0.0) | (ww == 0.0), 0.0, np.inf), t)
    return np.where(t <= limit, t, np.inf)


def twist_trajectories(
    theta: float, twists: np.ndarray, tau: float, horizon: float, n_arc: int = 2
) -> tuple[np.ndarray, np.ndarray]:
    """Predicted motion of a unicycle that holds each twist for ``tau`` s, then drives
    straight on (at the same ``v``, with the heading reached) until ``horizon``.

    This is the trajectory each VO candidate is tested on: its first part is the
    exact arc (sampled at ``n_arc`` equal chords, so the error is the chord
    sagitta, ``v/omega (1 - cos(omega tau / 2 n_arc))`` <= 2 cm for
    ``v = 0.65, omega = 1, tau = 1, n_arc = 2``), its second part shows where the
    chosen turn leads — a robot can only leave a head-on course by turning, and
    a straight-line VO of the chord alone cannot see that.

    Returns:
        times ``(K+1,)`` (``0 ... tau ... horizon``; no straight part if
        ``horizon <= tau``), points ``(C, K+1, 2)`` displacements from the start.
    """
    tw = np.asarray(twists, dtype=np.float64).reshape(-1, 2)
    t_hold = min(float(tau), float(horizon))
    t_arc = np.linspace(0.0, t_hold, n_arc + 1)
    v, w = tw[:, 0:1], tw[:, 1:2]
    half = 0.5 * w * t_arc  # (C, n_arc+1)
    scale = v * t_arc * np.sinc(half / math.pi)
    ang = theta + half
    pts = np.stack([scale * np.cos(ang), scale * np.sin(ang)], axis=-1)
    if horizon <= t_hold:
        return t_arc, pts
    hd = theta + tw[:, 1] * t_hold
    run = tw[:, 0] * (horizon - t_hold)
    last = pts[:, -1] + np.column_stack([run * np.cos(hd), run * np.sin(hd)])
    return np.append(t_arc, horizon), np.concatenate([pts, last[:, None, :]], axis=1)


def trajectory_disc_ttc(
    times: np.ndarray,
    points: np.ndarray,
    rel_pos: np.ndarray,
    combined_radius: np.ndarray,
    disc_vel: np.ndarray,
) -> np.ndarray:
    """``(C, D)`` first contact time of piecewise-linear robot trajectories with
    discs moving at constant velocity; ``inf`` if none before ``times[-1]``.

    ``times`` ``(K+1,)``, ``points`` ``(C, K+1, 2)`` robot displacements (see
    :func:`twist_trajectories`); ``rel_pos`` ``(D, 2)`` disc minus robot position
    now; ``combined_radius`` ``(D,)``; ``disc_vel`` ``(D, 2)``. Each segment is a
    ray/disc test (:func:`disc_time_to_collision`'s rule, overlap included).
    """
    times = np.asarray(times, dtype=np.float64)
    t0 = times[:-1]
    dur = np.diff(times)
    seg_v = np.diff(points, axis=1) / dur[None, :, None]  # (C, K, 2)
    rel = np.asarray(rel_pos, dtype=np.float64).reshape(-1, 2)
    dv = np.asarray(disc_vel, dtype=np.float64).reshape(-1, 2)
    R = np.broadcast_to(np.asarray(combined_radius, dtype=np.float64), (rel.shape[0],))
    # disc minus robot at each segment start, (C, K, D)
    ox = rel[:, 0] + dv[:, 0] * t0[:, None]  # (K, D)
    oy = rel[:, 1] + dv[:, 1] * t0[:, None]
    px = ox - points[:, :-1, 0, None]
    py = oy - points[:, :-1, 1, None]
    wx = seg_v[:, :, 0, None] - dv[:, 0]
    wy = seg_v[:, :, 1, None] - dv[:, 1]
    t = _ray_disc_ttc(px, py, R * R, wx, wy, dur[:, None]) + t0[:, None]
    return t.min(axis=1)


def trajectory_static_ttc(
    position: np.ndarray, radius: float, times: np.ndarray, points: np.ndarray, static: StaticMap
) -> np.ndarray:
    """``(C,)`` first time a disc of ``radius`` following each piecewise-linear
    trajectory (``times`` ``(K+1,)``, ``points`` ``(C, K+1, 2)`` displacements from
    ``position``) touches a static obstacle or wall; ``inf`` if none before
    ``times[-1]``.

    * Circles: ray/disc tests with radius ``r_circle + radius``.
    * Convex polygons: the exact Minkowski sum with the disc — per edge the strip
      between the edge and its copy offset outward by ``radius`` (entered through
      the offset edge from the outer side), plus a disc of ``radius`` at every
      vertex. The first entry over these parts is the first time the clearance
      drops to ``radius``.
    * Walls: the lines of the world rectangle ``[0, W] x [0, H]``.

    Already within ``radius`` of an obstacle or wall now: ``0`` unless the first
    segment moves away from it (``u . n > 0``, ``n`` the outward normal at its
    nearest surface point; for a convex obstacle the distance then keeps
    growing along that segment), in which case that obstacle is ignored for
    this candidate. Obstacles out of reach within ``times[-1]`` at the longest
    trajectory are culled first.
    """
    P = np.asarray(position, dtype=np.float64).reshape(2)
    times = np.asarray(times, dtype=np.float64)
    pts = np.asarray(points, dtype=np.float64)
    C = pts.shape[0]
    out = np.full(C, np.inf)
    if C == 0:
        return out
    t0 = times[:-1]
    dur = np.diff(times)
    seg_v = np.diff(pts, axis=1) / dur[None, :, None]  # (C, K, 2)
    sx = P[0] + pts[:, :-1, 0]  # segment starts (C, K)
    sy = P[1] + pts[:, :-1, 1]
    vx, vy = seg_v[..., 0], seg_v[..., 1]
    ext = np.sqrt(np.max(np.sum((pts - pts[:, :1]) ** 2, axis=2)))  # farthest any candidate gets
    reach = radius + ext + 1e-9

    # -- walls: distance of the segment start to each wall line, inward normals
    W, H = static.size
    d_now = np.array([P[1], W - P[0], H - P[1], P[0]])
    for k in np.nonzero(d_now <= reach)[0]:
        if k == 0:
            gap, vn = sy - radius, vy
        elif k == 1:
            gap, vn = (W - sx) - radius, -vx
        elif k == 2:
            gap, vn = (H - sy) - radius, -vy
        else:
            gap, vn = sx - radius, vx
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(vn < 0.0, gap / -vn, np.inf)
        t = np.where(gap < 0.0, np.where(vn > 0.0, np.inf, 0.0), t)
        t = np.where(t <= dur, t + t0, np.inf)
        np.minimum(out, t.min(axis=1), out=out)

    # -- circles
    circ = static.circles
    if len(circ):
        rel = circ[:, :2] - P
        keep = np.hypot(rel[:, 0], rel[:, 1]) - circ[:, 2] <= reach
        if np.any(keep):
            t = trajectory_disc_ttc(times, pts, rel[keep], circ[keep, 2] + radius, np.zeros((int(keep.sum()), 2)))
            np.minimum(out, t.min(axis=1), out=out)

    # -- convex polygons (padded arrays: a repeated last edge changes no minimum)
    if len(static.polygons):
        g = _polygon_arrays(static)
        A, N, L, ux, uy = g["A"], g["N"], g["L"], g["ux"], g["uy"]
        qx = P[0] - A[..., 0]
        qy = P[1] - A[..., 1]
        along = qx * ux + qy * uy  # (P, M)
        perp = qx * N[..., 0] + qy * N[..., 1]  # signed distance to the edge line, > 0 outside
        foot = np.clip(along, 0.0, L)
        fx, fy = qx - foot * ux, qy - foot * uy  # from the nearest point of the edge to P
        d2 = fx * fx + fy * fy
        hmax = perp.max(axis=1)
        inside = hmax <= 0.0
        sd = np.where(inside, hmax, np.sqrt(d2.min(axis=1)))  # (P,) signed clearance now
        keep = sd <= reach
        overl = keep & (sd < radius)
        if np.any(overl):
            rows = np.nonzero(overl)[0]
            nrm = N[rows, np.argmax(perp[rows], axis=1)].copy()  # centre inside: nearest edge line
            e_out = np.argmin(d2[rows], axis=1)
            ox_, oy_ = fx[rows, e_out], fy[rows, e_out]
            dn = np.hypot(ox_, oy_)
            ok = (~inside[rows]) & (dn > 0.0)
            nrm[ok] = np.column_stack([ox_[ok], oy_[ok]]) / dn[ok, None]
            vn = vx[:, 0, None] * nrm[:, 0] + vy[:, 0, None] * nrm[:, 1]  # first segment, (C, k)
            np.minimum(out, np.where(vn > 0.0, np.inf, 0.0).min(axis=1), out=out)
        free = np.nonzero(keep & ~overl)[0]
        if len(free):
            # Broad phase: which (candidate, segment, polygon) sweeps come within
            # `radius` of the polygon's bounding circle at all.
            cx = g["centre"][free, 0] - sx[..., None]  # (C, K, p)
            cy = g["centre"][free, 1] - sy[..., None]
            uu = (vx * vx + vy * vy)[..., None]
            with np.errstate(divide="ignore", invalid="ignore"):
                ts = np.clip((cx * vx[..., None] + cy * vy[..., None]) / uu, 0.0, dur[:, None])
            ts = np.where(uu > 0.0, ts, 0.0)
            ex = cx - ts * vx[..., None]
            ey = cy - ts * vy[..., None]
            rb = g["bound"][free] + radius
            ci, ki, pj = np.nonzero(ex * ex + ey * ey <= rb * rb)
            if len(ci):
                pi = free[pj]
                a = A[pi]  # (n, M, 2)
                nx, ny = N[pi, :, 0], N[pi, :, 1]
                ex_, ey_ = ux[pi], uy[pi]
                Ln = L[pi]
                s0x, s0y = sx[ci, ki][:, None], sy[ci, ki][:, None]
                wx, wy = vx[ci, ki][:, None], vy[ci, ki][:, None]
                dk = dur[ki][:, None]
                rx = s0x - a[..., 0]  # segment start relative to each edge start, (n, M)
                ry = s0y - a[..., 1]
                per = rx * nx + ry * ny
                vn = wx * nx + wy * ny
                with np.errstate(divide="ignore", invalid="ignore"):
                    t = np.where((vn < 0.0) & (per >= radius), (per - radius) / -vn, np.inf)
                    s_hit = (rx * ex_ + ry * ey_) + (wx * ex_ + wy * ey_) * t  # nan/inf: compares False
                t = np.where((s_hit >= 0.0) & (s_hit <= Ln) & (t <= dk), t, np.inf)
                # vertex discs (every vertex starts one edge)
                tv = _ray_disc_ttc(-rx, -ry, radius * radius, wx, wy, dk)
                tloc = np.minimum(t, tv).min(axis=1) + t0[ki]
                np.minimum.at(out, ci, tloc)
    return out


# Per-map derived polygon arrays, keyed by id() with the map itself kept alive
# (so an id is never reused while cached). A handful of maps exist per process.
_POLY_CACHE: dict[int, tuple[StaticMap, dict]] = {}


def _polygon_arrays(static: StaticMap) -> dict:
    hit = _POLY_CACHE.get(id(static))
    if hit is not None and hit[0] is static:
        return hit[1]
    A = static.poly_vertices
    E = static.poly_edges
    L = np.sqrt(E[..., 0] ** 2 + E[..., 1] ** 2)
    inv_L = np.where(L > 0.0, 1.0 / np.maximum(L, 1e-300), 0.0)
    centre = np.array([p.mean(axis=0) for p in static.polygons]).reshape(-1, 2)
    bound = np.array([np.max(np.hypot(*(p - c).T)) for p, c in zip(static.polygons, centre)])
    g = {
        "A": A, "N": static.poly_normals, "L": L, "ux": E[..., 0] * inv_L, "uy": E[..., 1] * inv_L,
        "centre": centre, "bound": bound,
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
    R = np.broadcast_to(np.asarray(combined_radius, dtype=np.float64), (p.shape[0],))
    w = np.asarray(rel_vel, dtype=np.float64)
    if w.ndim == 2:
        w = w[:, None, :]
    return _ray_disc_ttc(p[:, 0], p[:, 1], R * R, w[..., 0], w[..., 1], horizon)


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
    :func:`trajectory_static_ttc` (this is its one-segment case)."""
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
    velocity obstacle existed. ``n_safe``: how many candidates were safe.
    ``min_time_to_collision``: the chosen twist's time to its first collision
    (``inf`` when feasible, ``<= horizon`` otherwise).
    """

    twist: np.ndarray
    feasible: bool
    n_safe: int
    min_time_to_collision: float


def vo_select(
    pose: np.ndarray,
    radius: float,
    preferred: np.ndarray,
    discs: np.ndarray,
    disc_vel: np.ndarray,
    static: StaticMap | None,
    v_max: float,
    omega_max: float,
    *,
    horizon: float = 3.0,
    margin: float = 0.05,
    n_v: int = 7,
    n_w: int = 11,
    tau: float = 1.0,
    w_pref: float = 1.0,
    w_heading: float = 0.5,
    v_min: float = 0.0,
    goal_heading: float | None = None,
    side_bias: float = 0.1,
    model: str = "arc",
    n_arc: int = 2,
    escape: bool = True,
    velocity: np.ndarray | None = None,
    reciprocal: np.ndarray | bool = False,
) -> VOResult:
    """Choose a safe twist close to ``preferred`` (paper 003 Sec. II-D).

    Args:
        pose: ``(3,)`` robot pose. ``radius``: robot radius (m).
        preferred: ``(2,)`` desired twist (e.g. from :func:`pure_pursuit`); clipped
            to the limits and added to the candidates, so it is returned unchanged
            whenever it is safe and within limits.
        discs: ``(D, 3)`` ``x, y, radius`` of moving discs (other robots, humans);
            ``(0, 3)`` for none. ``disc_vel``: ``(D, 2)`` their world velocities.
        static: static obstacles and walls, or ``None``.
        v_max, omega_max: limits; candidates are :func:`sample_twists`
            ``(v_max, omega_max, n_v, n_w, v_min)`` plus the preferred twist.
        horizon: VO truncation time (s). ``margin``: added to every combined radius.
        tau: each candidate twist is tested as the mean velocity of its arc over
            ``tau`` s (:func:`twist_velocities`).
        w_pref, w_heading: penalty weights (see below).
        goal_heading: world direction the robot should head to (e.g. towards its
            target). ``None``: the heading the preferred twist reaches after ``tau``.

    Penalty of a candidate ``(v, w)``: ``w_pref * hypot((v - v_p) / v_max,
    (w - w_p) / omega_max)`` + ``w_heading * |wrap(theta + w tau - goal_heading)| / pi``
    (distance to the optimal velocity and consistency with the target direction).

    Safe candidates are those outside every disc VO (:func:`vo_discs_inside`) and
    the static VO (:func:`vo_polygons_inside`) within ``horizon``; the one with
    the least penalty is returned. If none is safe the candidate with the
    largest time to collision is returned (ties: slower, then lower penalty)
    with ``feasible=False`` — typically slowing down or turning in place. Never
    raises for well-formed inputs.
    """
    pose = np.asarray(pose, dtype=np.float64).reshape(3)
    theta = float(pose[2])
    pref = np.asarray(preferred, dtype=np.float64).reshape(2)
    pref = np.array([min(max(pref[0], v_min), v_max), min(max(pref[1], -omega_max), omega_max)])
    grid = sample_twists(v_max, omega_max, n_v, n_w, v_min)
    twists = np.vstack([pref[None, :], grid])  # the preferred twist first: it wins ties
    C = twists.shape[0]
    if model == "arc":
        times, pts = twist_trajectories(theta, twists, tau, horizon, n_arc)
    elif model == "chord":
        vel = twist_velocities(theta, twists, tau)
        times = np.array([0.0, horizon])
        pts = np.stack([np.zeros_like(vel), vel * horizon], axis=1)
    else:
        raise ValueError(f"model must be 'arc' or 'chord', got {model!r}")

    ttc = np.full(C, np.inf)
    d = np.asarray(discs, dtype=np.float64).reshape(-1, 3)
    if d.shape[0]:
        dv = np.asarray(disc_vel, dtype=np.float64).reshape(-1, 2)
        rel = d[:, :2] - pose[:2]
        R = d[:, 2] + radius + margin
        # Cull discs that no candidate can meet within the horizon.
        ext = float(np.sqrt(np.max(np.sum(pts * pts, axis=2))))
        reach = ext + np.hypot(dv[:, 0], dv[:, 1]) * horizon + R
        keep = rel[:, 0] ** 2 + rel[:, 1] ** 2 <= reach * reach
        recip = np.broadcast_to(np.asarray(reciprocal, dtype=bool), (d.shape[0],))
        plain = keep & ~recip
        if np.any(plain):
            ttc = trajectory_disc_ttc(times, pts, rel[plain], R[plain], dv[plain]).min(axis=1)
        both = keep & recip
        if np.any(both):
            # Reciprocal VO: the other robot takes half of the avoidance, so test
            # 2 v - v_now against its VO (van den Berg et al. 2008): displacement 2 x(t) - v_now t.
            own = np.zeros(2) if velocity is None else np.asarray(velocity, dtype=np.float64).reshape(2)
            pts_r = 2.0 * pts - own[None, None, :] * times[None, :, None]
            np.minimum(ttc, trajectory_disc_ttc(times, pts_r, rel[both], R[both], dv[both]).min(axis=1), out=ttc)
    if static is not None:
        np.minimum(ttc, trajectory_static_ttc(pose[:2], radius + margin, times, pts, static), out=ttc)
    ttc[ttc > horizon] = np.inf

    if goal_heading is None:
        goal_heading = theta + pref[1] * tau
    dv_ = (twists[:, 0] - pref[0]) / (v_max if v_max > 0 else 1.0)
    dw_ = (twists[:, 1] - pref[1]) / (omega_max if omega_max > 0 else 1.0)
    head = np.abs(wrap_angle(theta + twists[:, 1] * tau - goal_heading)) / math.pi
    penalty = w_pref * np.hypot(dv_, dw_) + w_heading * head + side_bias * np.maximum(dw_, 0.0)

    safe = np.isinf(ttc)
    n_safe = int(np.count_nonzero(safe))
    if n_safe:
        idx = int(np.argmin(np.where(safe, penalty, np.inf)))
        if twists[idx, 0] <= 0.0 < pref[0] and escape:
            idx = _escape_turn(
                pose, radius + margin, twists, safe, penalty, d, disc_vel, static, tau, horizon, v_max, pref[0]
            )
        return VOResult(twists[idx].copy(), True, n_safe, math.inf)
    # lexsort: last key is primary -> largest ttc, then slowest, then least penalty.
    idx = int(np.lexsort((penalty, np.abs(twists[:, 0]), -ttc))[0])
    return VOResult(twists[idx].copy(), False, 0, float(ttc[idx]))


def _escape_turn(
    pose: np.ndarray,
    rad: float,
    twists: np.ndarray,
    safe: np.ndarray,
    penalty: np.ndarray,
    discs: np.ndarray,
    disc_vel: np.ndarray,
    static: StaticMap | None,
    tau: float,
    horizon: float,
    v_max: float,
    v_pref: float,
) -> int:
    """Blocked: the robot wants to move but only standing still is safe. Standing
    still with the preferred turn rate is a fixed point (nothing changes, so the
    next step is blocked again), so instead turn in place towards the most open
    direction: among the safe ``v = 0`` candidates, pick the one whose heading
    after ``tau`` allows the longest straight run at ``max(v_pref, v_max / 2)``
    (probe: turn in place for ``tau``, then drive straight until ``horizon``);
    ties (several fully open directions) go to the least penalty."""
    stop = np.nonzero(safe & (twists[:, 0] <= 0.0))[0]
    theta = float(pose[2])
    hd = theta + twists[stop, 1] * tau
    run = max(v_pref, 0.5 * v_max) * max(horizon - tau, 0.0)
    times = np.array([0.0, tau, max(horizon, tau + 1e-9)])
    pts = np.zeros((len(stop), 3, 2))
    pts[:, 2, 0] = run * np.cos(hd)
    pts[:, 2, 1] = run * np.sin(hd)
    ttc = np.full(len(stop), np.inf)
    if discs.shape[0]:
        dv = np.asarray(disc_vel, dtype=np.float64).reshape(-1, 2)
        ttc = trajectory_disc_ttc(times, pts, discs[:, :2] - pose[:2], discs[:, 2] + rad, dv).min(axis=1)
    if static is not None:
        np.minimum(ttc, trajectory_static_ttc(pose[:2], rad, times, pts, static), out=ttc)
    best = np.lexsort((penalty[stop], -ttc))[0]
    return int(stop[best])
