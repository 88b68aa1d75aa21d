"""Humans that react: the social force model (Helbing & Molnar 1995), for ``behavior: social_force``.

A reactive human walks towards the waypoints of its path in the path's mode (``once``: stop at the
last; ``loop``: back to the first along the closing segment; ``pingpong``: back and forth), but its
velocity follows a sum of accelerations instead of the path:

* **goal**: ``(speed * e - v) / TAU`` towards the current waypoint (``e`` the unit direction;
  ``speed`` 0 once a ``once`` human has arrived, or before its ``start_delay``);
* **other bodies** (robots, the robot leader, other humans): ``A exp((r_i + r_j - d) / B)`` along
  the unit vector from the other body to the human, within ``RANGE`` m;
* **obstacles and walls**: ``A exp((r_i - c) / B)`` along the clearance gradient, ``c`` the free
  distance of the human's centre (:meth:`~swarm_env.geometry.StaticMap.nearest_obstacles`);
* **keep right**: ``SIDESTEP`` times the push of the bodies ahead, to the right of the walking
  direction (head-on, the push alone balances the goal force and the human stands forever).

Explicit Euler over one control step, the speed capped at ``REACTIVE_SPEED_FACTOR * speed``. A
waypoint counts as reached within ``REACH`` m. Pure numpy and no random numbers: deterministic.
:class:`~swarm_env.world.World` calls :func:`social_force_velocities` once per control step for its
reactive humans and moves them at that velocity during the substeps.
"""

from __future__ import annotations

import numpy as np

from swarm_env.geometry import StaticMap
from swarm_env.paths import PolylinePath
from swarm_env.scenario import REACTIVE_SPEED_FACTOR, HumanSpec

#: Relaxation time of the goal force (s), interaction strength (m/s^2) and range (m), after
#: Helbing & Molnar's pedestrian values scaled to a unit mass.
TAU, A, B = 0.5, 2.0, 0.3
#: Bodies farther than this (m, centre to centre) exert no force.
RANGE = 3.0
#: A waypoint within this distance (m) is reached.
REACH = 0.3
#: The share of the push from bodies ahead that turns into a step to the right.
SIDESTEP = 0.5

__all__ = ["WaypointWalker", "social_force_velocities"]


class WaypointWalker:
    """Which waypoint each reactive human heads for, advanced as they are reached."""

    def __init__(self, humans: list[HumanSpec], paths: list[PolylinePath]) -> None:
        self.humans = humans
        self.points = [np.asarray(p.points, dtype=np.float64) for p in paths]
        # pingpong walks the path back and forth; loop's path is already closed (human_paths).
        self.target = np.array([1 if len(p) > 1 else 0 for p in self.points])
        self.step = np.ones(len(humans), dtype=np.int64)
        self.arrived = np.array([len(p) < 2 for p in self.points])

    def goals(self, pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(H, 2)`` each human's current waypoint (after advancing those reached) and ``(H,)`` bool:
        the human has arrived for good (``once`` at its last waypoint)."""
        for j, h in enumerate(self.humans):
            pts = self.points[j]
            if self.arrived[j]:
                continue
            if np.hypot(*(pts[self.target[j]] - pos[j])) <= REACH:
                nxt = self.target[j] + self.step[j]
                if 0 <= nxt < len(pts):
                    self.target[j] = nxt
                elif h.mode == "once":
                    self.arrived[j] = True
                elif h.mode == "loop":
                    self.target[j] = 1  # the closing segment brought it back to the first point
                else:  # pingpong: turn round
                    self.step[j] = -self.step[j]
                    self.target[j] += self.step[j]
        goals = np.array([self.points[j][self.target[j]] for j in range(len(self.humans))]).reshape(-1, 2)
        return goals, self.arrived.copy()


def social_force_velocities(
    pos: np.ndarray,
    vel: np.ndarray,
    radius: np.ndarray,
    speed: np.ndarray,
    goals: np.ndarray,
    walking: np.ndarray,
    others: np.ndarray,
    static: StaticMap,
    dt: float,
) -> np.ndarray:
    """``(H, 2)`` the humans' velocities for the next ``dt`` seconds.

    ``pos``, ``vel`` ``(H, 2)``, ``radius`` and ``speed`` ``(H,)`` (their walking speed),
    ``goals`` ``(H, 2)`` the waypoints they head for, ``walking`` ``(H,)`` bool (``False``: the
    goal force brings them to rest: before their start delay or arrived), ``others`` ``(K, 3)``
    ``(x, y, r)`` of the robots (the humans themselves are added here).
    """
    n = len(pos)
    if n == 0:
        return np.zeros((0, 2))
    to_goal = goals - pos
    dist = np.hypot(to_goal[:, 0], to_goal[:, 1])
    unit = np.divide(to_goal, dist[:, None], out=np.zeros_like(to_goal), where=dist[:, None] > 1e-9)
    desired = unit * np.where(walking, speed, 0.0)[:, None]
    force = (desired - vel) / TAU
    bodies = np.concatenate([np.column_stack([pos, radius]), np.asarray(others, dtype=np.float64).reshape(-1, 3)])
    diff = pos[:, None, :] - bodies[None, :, :2]  # (H, H + K, 2): from each body to each human
    d = np.hypot(diff[..., 0], diff[..., 1])
    d[np.arange(n), np.arange(n)] = np.inf  # not oneself
    near = d < RANGE
    push = np.where(near, A * np.exp((radius[:, None] + bodies[None, :, 2] - d) / B), 0.0)
    safe_d = np.where(d > 1e-9, d, np.inf)
    force += np.einsum("hk,hkc->hc", push / safe_d, diff)
    # Keep right of what is ahead: head-on, the push is straight back along the walking direction
    # and balances the goal force (the model's classic deadlock); a sideways share breaks it.
    ahead = np.einsum("hkc,hc->hk", diff, unit) < 0.0
    force += (SIDESTEP * np.where(ahead, push, 0.0).sum(axis=1))[:, None] * np.column_stack([unit[:, 1], -unit[:, 0]])
    clear, normal, _ = static.nearest_obstacles(pos)
    wall = np.where(np.isfinite(clear), A * np.exp((radius - clear) / B), 0.0)
    force += wall[:, None] * normal
    new = vel + force * dt
    cap = speed * REACTIVE_SPEED_FACTOR
    norm = np.hypot(new[:, 0], new[:, 1])
    scale = np.where(norm > cap, cap / np.maximum(norm, 1e-12), 1.0)
    return new * scale[:, None]
