"""Pure pursuit for differential-drive robots (paper 003 Eqs. 3-4, 9, 11): the preferred twist towards a
target point, a carrot on a path, and the velocity of a slot carried by the leader.

Used by the env's robot leader (paper 003 Fig. 1: pure pursuit along its path, then the velocity-obstacle
check of :mod:`swarm_env.control.vo`) and by the scripted experts for the followers (paper 003 Fig. 2). Every
function is pure and vectorised numpy.

Conventions: world frame x right, y up; a pose is ``(x, y, theta)`` with theta
counter-clockwise from +x (radians); a *twist* is the body-frame command
``(v, omega)`` (m/s, rad/s); a *velocity* is a world-frame ``(vx, vy)``.
"""

from __future__ import annotations

import math

import numpy as np

from swarm_env.geometry.paths import PolylinePath

__all__ = ["wrap_angle", "pure_pursuit", "slot_velocities", "lookahead_target"]

_TWO_PI = 2.0 * math.pi
# Below this distance (m) the target counts as reached: the pursuit angle is undefined.
_EPS_DIST = 1e-9


def wrap_angle(a):
    """Wrap angle(s) to ``[-pi, pi)``. A Python/numpy scalar gives a float, an array an array."""
    if isinstance(a, (float, int)):
        return (a + math.pi) % _TWO_PI - math.pi
    out = np.mod(np.asarray(a, dtype=np.float64) + math.pi, _TWO_PI) - math.pi
    return float(out) if out.ndim == 0 else out


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


def slot_velocities(leader_pose: np.ndarray, leader_vel: np.ndarray, leader_omega: float, slots: np.ndarray) -> np.ndarray:
    """``(N, 2)`` world velocity of each slot ``slots`` ``(N, 2)`` carried by the leader's frame:
    ``v_L + omega_L x (slot - p_L)`` (the feed-forward of a follower tracking a moving slot)."""
    v_slot = np.empty_like(slots)
    v_slot[:, 0] = leader_vel[0] - leader_omega * (slots[:, 1] - leader_pose[1])
    v_slot[:, 1] = leader_vel[1] + leader_omega * (slots[:, 0] - leader_pose[0])
    return v_slot


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
