"""The physical world: the only module that imports pymunk.

:class:`World` turns a :class:`~swarm_env.scenario.Scenario` into a pymunk
``Space`` and advances it one control period at a time:

* followers and a ``robot`` leader are dynamic discs whose wheels are modelled
  as a unicycle command ``(v, omega)``: in every physics substep the command is
  rate-limited (optional acceleration limits), the body's velocity is set along
  its heading and the solver resolves contacts, so robots push each other and
  never overlap obstacles or walls;
* humans are kinematic discs that follow their paths exactly (they push robots
  and do not react);
* obstacles and the four walls are static shapes;
* a ``virtual`` leader is not in the space at all (it collides with nothing).

Contacts are counted as *onsets* per control step: a pair that touches during
a step and did not touch during the previous step is one new contact, however
long it stays in touch.

Everything is deterministic: bodies are created in a fixed order, the step
size and substeps are fixed, and nothing here draws random numbers.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pymunk

from swarm_env import formation as formation_lib
from swarm_env import guidance
from swarm_env.geometry import StaticMap
from swarm_env.paths import PolylinePath, human_states, virtual_leader
from swarm_env.scenario import Scenario
from swarm_env.state import LEADER_ID, Contact, WorldState

# Collision types (pymunk collision_type of each shape).
_FOLLOWER, _LEADER, _HUMAN, _OBSTACLE, _WALL = 1, 2, 3, 4, 5
_KIND_OF_OTHER = {
    _FOLLOWER: "robot_robot",
    _LEADER: "robot_robot",
    _HUMAN: "robot_human",
    _OBSTACLE: "robot_obstacle",
    _WALL: "robot_wall",
}
_WALL_RADIUS = 0.05  # m; walls are segments of this radius lying just outside [0,W]x[0,H]
_ROBOT_MASS = 10.0  # kg; equal masses, so two robots pushing each other split the difference
#: Overlap (m) the contact solver tolerates before it pushes bodies apart.
COLLISION_SLOP = 0.005
#: The leader's arrival tolerance at the end of its path (m).
LEADER_GOAL_TOLERANCE = 0.2
#: Extra clearance (m) beyond the robot radius kept between a slot target and obstacles.
SLOT_MARGIN = 0.05


def _drive(body: pymunk.Body, gravity: Any, damping: float, dt: float) -> None:
    """pymunk velocity callback of a differential-drive robot.

    Chipmunk integrates positions *before* it solves contacts and integrates
    velocities *after* it, so a velocity set from outside between two steps
    goes straight into the position update and pushes the robot into walls
    (measured: 0.11 m of overlap at 0.65 m/s). Setting the wheel velocity here
    lets the contact solver correct it within the same substep.

    ``body.cmd`` is the commanded ``(v, omega)``; ``body.act`` the realised one,
    moved towards the command by at most ``body.limits`` per second.
    """
    v_cmd, w_cmd = body.cmd
    v, w = body.act
    dv, dw = body.limits
    v = v_cmd if dv is None else v + min(max(v_cmd - v, -dv * dt), dv * dt)
    w = w_cmd if dw is None else w + min(max(w_cmd - w, -dw * dt), dw * dt)
    body.act = (v, w)
    a = body.angle
    body.velocity = (v * math.cos(a), v * math.sin(a))
    body.angular_velocity = w


def _unit_body(
    position: tuple[float, float], angle: float, radius: float, limits: tuple[float | None, float | None]
) -> pymunk.Body:
    body = pymunk.Body(_ROBOT_MASS, pymunk.moment_for_circle(_ROBOT_MASS, 0.0, radius))
    body.position = position
    body.angle = angle
    body.cmd = (0.0, 0.0)
    body.act = (0.0, 0.0)
    body.limits = limits
    body.velocity_func = _drive
    return body


class World:
    """A scenario simulated in pymunk.

    Args:
        scenario: the world description.
        static: its static geometry (built once per scenario and shared).

    Call :meth:`step` with one ``(v, omega)`` command per follower; read the
    result with :meth:`snapshot`.
    """

    def __init__(self, scenario: Scenario, static: StaticMap) -> None:
        self.scenario = scenario
        self.static = static
        world = scenario.world
        self.dt = world.dt
        self.substeps = world.substeps
        self.sub_dt = world.dt / world.substeps
        self.time = 0.0
        self.step_count = 0
        robots = scenario.robots
        self.n = robots.count

        self._leader_path = PolylinePath(scenario.leader.path)
        self._offsets = [formation_lib.formation_offsets(f, self.n) for f in scenario.formations]
        self._slot_clearance = robots.radius + SLOT_MARGIN

        self.space = pymunk.Space()
        self.space.gravity = (0.0, 0.0)
        # pymunk's default slop (0.1) is tuned for pixels; in metres it would let discs overlap by 10 cm.
        self.space.collision_slop = COLLISION_SLOP
        self._add_walls()
        self._add_obstacles()

        # Leader state first: the followers' start slots depend on its pose.
        self._leader_done = False
        self._leader_s = 0.0
        self._leader_body: pymunk.Body | None = None
        pose0, vel0, _ = virtual_leader(self._leader_path, scenario.leader.speed, 0.0, scenario.leader.start_delay)
        self._virtual_pose = pose0
        self._virtual_vel = vel0
        if scenario.leader.kind == "robot":
            self._leader_body = _unit_body((pose0[0], pose0[1]), float(pose0[2]), scenario.leader.radius, (None, None))
            shape = pymunk.Circle(self._leader_body, scenario.leader.radius)
            self._init_shape(shape, _LEADER, LEADER_ID)
            self.space.add(self._leader_body, shape)

        self.formation_index = formation_lib.active_formation(scenario.formations, 0.0)
        starts = self._start_poses(pose0)
        self._bodies: list[pymunk.Body] = []
        for i, (x, y, th) in enumerate(starts):
            body = _unit_body((float(x), float(y)), float(th), robots.radius, (robots.max_accel, robots.max_turn_accel))
            shape = pymunk.Circle(body, robots.radius)
            self._init_shape(shape, _FOLLOWER, i)
            self.space.add(body, shape)
            self._bodies.append(body)

        self._human_bodies: list[pymunk.Body] = []
        hpos, hvel = human_states(scenario.humans, 0.0)
        for j, h in enumerate(scenario.humans):
            body = pymunk.Body(body_type=pymunk.Body.KINEMATIC)
            body.position = (float(hpos[j, 0]), float(hpos[j, 1]))
            shape = pymunk.Circle(body, h.radius)
            self._init_shape(shape, _HUMAN, j)
            self.space.add(body, shape)
            self._human_bodies.append(body)
        self._human_pos, self._human_vel = hpos, hvel
        self._human_radius = np.array([h.radius for h in scenario.humans], dtype=float)

        # Contact bookkeeping (see the module docstring).
        self._touching: set[tuple[str, int, int]] = set()
        self._touched_step: set[tuple[str, int, int]] = set()
        self._touched_prev: set[tuple[str, int, int]] = set()
        self._onsets: tuple[Contact, ...] = ()
        for robot_type in (_FOLLOWER, _LEADER):
            for other in (_FOLLOWER, _LEADER, _HUMAN, _OBSTACLE, _WALL):
                if robot_type == _LEADER and other == _FOLLOWER:
                    continue  # handled as (follower, leader)
                self.space.on_collision(robot_type, other, begin=self._on_begin, separate=self._on_separate)

        self._slots = self._compute_slots()

    # ------------------------------------------------------------------ building
    @staticmethod
    def _init_shape(shape: pymunk.Shape, collision_type: int, index: int) -> None:
        shape.collision_type = collision_type
        shape.friction = 0.0  # robots slide along walls instead of being spun by them
        shape.elasticity = 0.0
        shape.swarm_id = index  # type: ignore[attr-defined]

    def _add_walls(self) -> None:
        w, h = self.scenario.world.size
        r = _WALL_RADIUS
        corners = [(-r, -r), (w + r, -r), (w + r, h + r), (-r, h + r)]
        for k in range(4):  # bottom, right, top, left (geometry.WALL_NAMES order)
            seg = pymunk.Segment(self.space.static_body, corners[k], corners[(k + 1) % 4], r)
            self._init_shape(seg, _WALL, k)
            self.space.add(seg)

    def _add_obstacles(self) -> None:
        body = self.space.static_body
        shapes: dict[int, pymunk.Shape] = {}
        for k, idx in enumerate(self.static.circle_ids):
            cx, cy, rad = self.static.circles[k]
            shapes[int(idx)] = pymunk.Circle(body, float(rad), (float(cx), float(cy)))
        for k, idx in enumerate(self.static.polygon_ids):
            verts = [(float(x), float(y)) for x, y in self.static.polygons[k]]
            shapes[int(idx)] = pymunk.Poly(body, verts)
        for idx in sorted(shapes):  # scenario order, for a deterministic space
            self._init_shape(shapes[idx], _OBSTACLE, idx)
            self.space.add(shapes[idx])

    def _start_poses(self, leader_pose: np.ndarray) -> np.ndarray:
        start = self.scenario.robots.start
        if start == "formation":
            slots = formation_lib.slot_targets(
                leader_pose, self._offsets[self.formation_index], self.static, self._slot_clearance
            )
            heading = np.full((self.n, 1), leader_pose[2])
            return np.hstack([slots, heading])
        return np.asarray(start, dtype=float).reshape(self.n, 3)

    # ------------------------------------------------------------------ contacts
    def _on_begin(self, arbiter: pymunk.Arbiter, space: pymunk.Space, data: Any) -> None:
        a, b = arbiter.shapes
        kind = _KIND_OF_OTHER[b.collision_type]
        i, j = a.swarm_id, b.swarm_id
        if kind == "robot_robot" and b.collision_type == _FOLLOWER and j < i:
            i, j = j, i
        key = (kind, i, j)
        self._touching.add(key)
        self._touched_step.add(key)

    def _on_separate(self, arbiter: pymunk.Arbiter, space: pymunk.Space, data: Any) -> None:
        a, b = arbiter.shapes
        kind = _KIND_OF_OTHER[b.collision_type]
        i, j = a.swarm_id, b.swarm_id
        if kind == "robot_robot" and b.collision_type == _FOLLOWER and j < i:
            i, j = j, i
        self._touching.discard((kind, i, j))

    # ------------------------------------------------------------------ stepping
    def step(self, command: np.ndarray) -> None:
        """Advance one control period with ``command`` (N, 2) = (v, omega) per follower.

        The command is clipped to the speed and turn-rate limits; acceleration
        limits (if any) are applied in every substep by :func:`_drive`.
        """
        robots = self.scenario.robots
        v = np.clip(command[:, 0], -robots.max_speed, robots.max_speed).tolist()
        w = np.clip(command[:, 1], -robots.max_turn_rate, robots.max_turn_rate).tolist()
        for body, vi, wi in zip(self._bodies, v, w):
            body.cmd = (vi, wi)
        if self._leader_body is not None:
            self._leader_body.cmd = tuple(self._leader_command().tolist())
        self._touched_step = set(self._touching)
        t0 = self.time
        for k in range(self.substeps):
            self._move_humans(t0 + k * self.sub_dt)
            self.space.step(self.sub_dt)

        self.step_count += 1
        self.time = self.step_count * self.dt  # no accumulated float drift
        self._human_pos, self._human_vel = human_states(self.scenario.humans, self.time)
        for body, p in zip(self._human_bodies, self._human_pos.tolist()):
            body.position = (p[0], p[1])  # snap to the exact path (kinematic bodies integrate with round-off)
        self._advance_leader()
        self.formation_index = formation_lib.active_formation(self.scenario.formations, self.time)
        self._slots = self._compute_slots()

        new = self._touched_step - self._touched_prev
        self._touched_prev = self._touched_step
        self._onsets = tuple(Contact(kind, i, j) for kind, i, j in sorted(new))  # type: ignore[arg-type]

    def _move_humans(self, t: float) -> None:
        if not self._human_bodies:
            return
        pos, vel = human_states(self.scenario.humans, t)
        for body, p, v in zip(self._human_bodies, pos.tolist(), vel.tolist()):
            body.position = (p[0], p[1])
            body.velocity = (v[0], v[1])

    def _leader_command(self) -> np.ndarray:
        """Paper 003 Fig. 1: pure pursuit along the path, then a velocity-obstacle check."""
        spec = self.scenario.leader
        body = self._leader_body
        assert body is not None
        if self._leader_done or self.time < spec.start_delay:
            return np.zeros(2)
        pose = np.array([body.position.x, body.position.y, body.angle])
        target, self._leader_s = guidance.lookahead_target(self._leader_path, pose[:2], self._leader_s, spec.lookahead)
        preferred = guidance.pure_pursuit(pose, target, spec.speed, spec.max_turn_rate, 1.0)
        discs = [self._human_pos, self.follower_positions()]
        vels = [self._human_vel, self.follower_velocities()]
        radii = np.concatenate([self._human_radius, np.full(self.n, self.scenario.robots.radius)])
        result = guidance.vo_select(
            pose,
            spec.radius,
            preferred,
            np.hstack([np.vstack(discs), radii[:, None]]),
            np.vstack(vels),
            self.static,
            spec.speed,
            spec.max_turn_rate,
        )
        return np.asarray(result.twist, dtype=float)

    def _advance_leader(self) -> None:
        spec = self.scenario.leader
        if self._leader_body is None:
            pose, vel, done = virtual_leader(self._leader_path, spec.speed, self.time, spec.start_delay)
            self._virtual_pose, self._virtual_vel, self._leader_done = pose, vel, bool(done)
            return
        end = self._leader_path.points[-1]
        p = self._leader_body.position
        if not self._leader_done and math.hypot(p.x - end[0], p.y - end[1]) <= LEADER_GOAL_TOLERANCE:
            self._leader_done = True
            self._leader_body.velocity = (0.0, 0.0)
            self._leader_body.angular_velocity = 0.0

    def _compute_slots(self) -> np.ndarray:
        return formation_lib.slot_targets(
            self.leader_pose(), self._offsets[self.formation_index], self.static, self._slot_clearance
        )

    # ------------------------------------------------------------------ reading
    def follower_positions(self) -> np.ndarray:
        return np.array([tuple(b.position) for b in self._bodies], dtype=float).reshape(self.n, 2)

    def follower_velocities(self) -> np.ndarray:
        return np.array([tuple(b.velocity) for b in self._bodies], dtype=float).reshape(self.n, 2)

    def leader_pose(self) -> np.ndarray:
        if self._leader_body is None:
            return np.array(self._virtual_pose, dtype=float)
        b = self._leader_body
        return np.array([b.position.x, b.position.y, float(guidance.wrap_angle(b.angle))])

    def snapshot(self) -> WorldState:
        """A frozen copy of the current state."""
        raw = np.array(
            [(b.position.x, b.position.y, b.angle, b.velocity.x, b.velocity.y, b.angular_velocity) for b in self._bodies],
            dtype=float,
        ).reshape(self.n, 6)
        pose = raw[:, :3].copy()
        pose[:, 2] = guidance.wrap_angle(pose[:, 2])
        vel = raw[:, 3:5].copy()
        speed = vel[:, 0] * np.cos(raw[:, 2]) + vel[:, 1] * np.sin(raw[:, 2])
        twist = np.stack([speed, raw[:, 5]], axis=1)
        if self._leader_body is None:
            lpose = np.array(self._virtual_pose, dtype=float)
            lvel = np.array(self._virtual_vel, dtype=float)
            lspeed = float(np.hypot(*lvel))
            ltwist = np.array([lspeed, 0.0])
            lradius = 0.0
        else:
            lb = self._leader_body
            lpose = self.leader_pose()
            lvel = np.array([lb.velocity.x, lb.velocity.y])
            ltwist = np.array([lvel[0] * math.cos(lpose[2]) + lvel[1] * math.sin(lpose[2]), lb.angular_velocity])
            lradius = float(self.scenario.leader.radius)
        arrays = dict(
            follower_pose=pose,
            follower_vel=vel,
            follower_twist=twist,
            follower_radius=np.full(self.n, self.scenario.robots.radius),
            leader_pose=lpose,
            leader_vel=lvel,
            leader_twist=ltwist,
            human_pos=np.array(self._human_pos, dtype=float).reshape(-1, 2),
            human_vel=np.array(self._human_vel, dtype=float).reshape(-1, 2),
            human_radius=self._human_radius.copy(),
            slot_targets=np.array(self._slots, dtype=float),
        )
        for arr in arrays.values():
            arr.flags.writeable = False
        return WorldState(
            time=self.time,
            step=self.step_count,
            leader_radius=lradius,
            leader_done=self._leader_done,
            formation_index=self.formation_index,
            next_switch_time=formation_lib.next_switch_time(self.scenario.formations, self.time),
            contacts=self._onsets,
            static=self.static,
            scenario=self.scenario,
            **arrays,
        )


__all__ = ["World", "COLLISION_SLOP", "LEADER_GOAL_TOLERANCE", "SLOT_MARGIN"]
