"""Humans that react: ``behavior: social_force`` (Helbing & Molnar 1995) and ``behavior: orca``.

A reactive human walks towards the waypoints of its path in the path's mode (``once``: stop at the
last; ``loop``: back to the first along the closing segment; ``pingpong``: back and forth), but its
velocity follows a sum of accelerations instead of the path:

* **goal**: ``(speed * e - v) / TAU`` towards the current waypoint (``e`` the unit direction;
  ``speed`` 0 once a ``once`` human has arrived, or before its ``start_delay``);
* **other bodies** (robots, the robot leader, other humans): ``A exp((r_i + r_j - d) / B)`` along
  the unit vector from the other body to the human, within ``RANGE`` m;
* **obstacles and walls**: ``A exp((r_i - c) / B)`` along the clearance gradient, ``c`` the free
  distance of the human's centre (:meth:`~swarm_env.geometry.static_map.StaticMap.nearest_obstacles`);
* **keep right**: ``SIDESTEP`` times the push of the bodies ahead, to the right of the walking
  direction (head-on, the push alone balances the goal force and the human stands forever).

Explicit Euler over one control step, the speed capped at ``REACTIVE_SPEED_FACTOR * speed``. A
waypoint counts as reached within ``REACH`` m. Pure numpy and no random numbers: deterministic.

An ``orca`` human heads for the same waypoints at its speed but lets RVO2's ORCA (the ``orca``
extra, :mod:`swarm_env.sim.rvo`) choose a collision-free velocity among all the humans and robots
(:class:`ORCACrowd`); ORCA assumes every agent shares the avoidance, and the robots do not run it:
the humans take half of what it would take to avoid them.

:class:`~swarm_env.sim.world.World` asks for the reactive humans' velocities once per control step and
moves them at those velocities during the substeps.
"""

from __future__ import annotations

import numpy as np

from swarm_env.geometry.paths import PolylinePath
from swarm_env.geometry.static_map import StaticMap
from swarm_env.scenario import REACTIVE_SPEED_FACTOR, HumanSpec
from swarm_env.sim.rvo import simulator

#: Relaxation time of the goal force (s), interaction strength (m/s^2) and range (m), after
#: Helbing & Molnar's pedestrian values scaled to a unit mass.
TAU, A, B = 0.5, 2.0, 0.3
#: Bodies farther than this (m, centre to centre) exert no force.
RANGE = 3.0
#: A waypoint within this distance (m) is reached.
REACH = 0.3
#: The share of the push from bodies ahead that turns into a step to the right.
SIDESTEP = 0.5

__all__ = ["WaypointWalker", "social_force_velocities", "ORCACrowd"]


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


class ORCACrowd:
    """RVO2 agents for every human (in scenario order) and every robot (followers, then a robot
    leader); :meth:`velocities` steps the ``orca`` humans. Not picklable (a C++ object): the
    :class:`~swarm_env.sim.world.World` that owns one drops it when copied and builds a new one."""

    #: ORCA's neighbourhood (m), neighbours, time horizons for agents and obstacles (s).
    NEIGHBOR_DIST, MAX_NEIGHBORS, HORIZON, HORIZON_STATIC = 5.0, 10, 2.0, 1.0

    def __init__(self, static: StaticMap, dt: float, human_radius: np.ndarray, human_speed: np.ndarray,
                 robot_radius: np.ndarray) -> None:
        self.sim = simulator(static, dt, self.NEIGHBOR_DIST, self.MAX_NEIGHBORS, self.HORIZON, self.HORIZON_STATIC,
                             0.3, 1.0, "humans with behavior: orca")
        for r, v in zip(human_radius.tolist(), human_speed.tolist()):
            a = self.sim.add_agent((0.0, 0.0))
            self.sim.set_agent_radius(a, r)
            self.sim.set_agent_max_speed(a, v * REACTIVE_SPEED_FACTOR)
        for r in robot_radius.tolist():
            a = self.sim.add_agent((0.0, 0.0))
            self.sim.set_agent_radius(a, r)
            self.sim.set_agent_max_speed(a, 1e3)  # robots move as they will; ORCA needs their velocity only

    def velocities(self, human_pos: np.ndarray, human_vel: np.ndarray, robot_pos: np.ndarray, robot_vel: np.ndarray,
                   controlled: np.ndarray, preferred: np.ndarray) -> np.ndarray:
        """``(len(controlled), 2)``: ORCA's velocities for the humans ``controlled`` (indices) whose
        preferred velocities are ``preferred``; everyone else keeps its current velocity."""
        sim = self.sim
        pos = np.concatenate([human_pos, robot_pos]).tolist()
        vel = np.concatenate([human_vel, robot_vel]).tolist()
        pref = [tuple(v) for v in vel]
        for k, j in enumerate(controlled.tolist()):
            pref[j] = (float(preferred[k, 0]), float(preferred[k, 1]))
        for a, (p, v, w) in enumerate(zip(pos, vel, pref)):
            sim.set_agent_position(a, (p[0], p[1]))
            sim.set_agent_velocity(a, (v[0], v[1]))
            sim.set_agent_pref_velocity(a, w)
        sim.do_step()
        return np.array([sim.get_agent_velocity(j).to_tuple() for j in controlled.tolist()], dtype=np.float64).reshape(-1, 2)


#: An ``orca`` human walking slower than this share of its preferred speed is blocked: its preferred
#: velocity turns right by ``BLOCKED_TURN`` radians (ORCA's head-on deadlock with a standing agent).
BLOCKED_SHARE, BLOCKED_TURN = 0.3, 0.5


def preferred_velocities(pos: np.ndarray, vel: np.ndarray, goals: np.ndarray, speed: np.ndarray,
                         walking: np.ndarray) -> np.ndarray:
    """``(H, 2)``: straight at each goal at ``speed`` (0 when not ``walking`` or on the goal),
    turned to the right by ``BLOCKED_TURN`` for a human going much slower than that (blocked)."""
    to_goal = goals - pos
    dist = np.hypot(to_goal[:, 0], to_goal[:, 1])
    unit = np.divide(to_goal, dist[:, None], out=np.zeros_like(to_goal), where=dist[:, None] > 1e-9)
    want = np.where(walking, np.minimum(speed, dist / 0.5), 0.0)
    pref = unit * want[:, None]
    blocked = np.hypot(vel[:, 0], vel[:, 1]) < BLOCKED_SHARE * want
    c, s = np.cos(-BLOCKED_TURN), np.sin(-BLOCKED_TURN)
    turned = np.column_stack([c * pref[:, 0] - s * pref[:, 1], s * pref[:, 0] + c * pref[:, 1]])
    return np.where(blocked[:, None], turned, pref)
