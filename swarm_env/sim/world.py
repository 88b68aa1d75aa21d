"""The physical world: the module that owns the pymunk space (the drive and physics kernels reach into
chipmunk through ``pymunk._chipmunk`` for its bodies' memory).

:class:`World` turns a :class:`~swarm_env.scenario.Scenario` into a pymunk
``Space`` and advances it one control period at a time:

* followers and a ``robot`` leader are dynamic discs whose wheels are modelled
  as a unicycle command ``(v, omega)``: in every physics substep the command is
  rate-limited (optional acceleration limits), the body's velocity is set along
  its heading and the solver resolves contacts, so robots push each other and
  obstacles and walls stop them; they may sink into what they hit by about one
  substep's travel before the solver pushes them out (:func:`max_overlap` states
  the bound);
* humans are kinematic discs that push robots: ``scripted`` ones follow their paths
  exactly and do not react; reactive ones (``social_force``, ``orca``) walk at a velocity
  chosen once per control step by :mod:`swarm_env.sim.humans`;
* obstacles and the four walls are static shapes;
* a ``virtual`` leader is not in the space at all (it collides with nothing).

Contacts are reported two ways per control step: *onsets* (a pair that touches
during a step and did not touch during the previous step is one new contact,
however long it stays in touch; what the metrics count as collisions) and the
pairs *in touch* at some time during the step (what reward v1 charges every
step).

Everything is deterministic: bodies are created in a fixed order, the step
size and substeps are fixed, and nothing here draws random numbers.
"""

from __future__ import annotations

import math
import threading
from typing import Any

import numpy as np
import pymunk

from swarm_env.compiled import compiled_kernels
from swarm_env.control import pursuit, vo
from swarm_env.geometry import formation as formation_lib
from swarm_env.geometry.paths import PolylinePath, human_paths, human_states, virtual_leader
from swarm_env.geometry.static_map import StaticMap
from swarm_env.scenario import Scenario
from swarm_env.sim.bodies import CP_LIB, install_python_callback, robot_body, set_body_position, set_body_velocity
from swarm_env.sim.humans import ORCACrowd, WaypointWalker, preferred_velocities, social_force_velocities
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
#: Overlap (m) the contact solver tolerates before it pushes bodies apart.
COLLISION_SLOP = 0.005
#: The leader's arrival tolerance at the end of its path (m).
LEADER_GOAL_TOLERANCE = 0.2
SLOT_MARGIN = formation_lib.SLOT_MARGIN  # re-exported: the slot projection's clearance beyond the radius
#: The robot leader's velocity-obstacle search (paper 003 Fig. 1): the search's defaults.
LEADER_VO = vo.VOParams()


#: In a pile-up (several robots pushing into one another or into an obstacle) the contact solver's
#: iterations leave part of each push unresolved for a few substeps, so the overlap exceeds a single
#: contact's bound; measured worst on paper_cbs_switch: x1.14 (robots) and x1.23 (obstacle). The
#: stated bound (:func:`max_overlap`) allows this factor; tests/test_physics.py checks it.
PILEUP_FACTOR = 1.5


def max_overlap(scenario: Scenario) -> dict[str, float]:
    """The deepest overlap (m) the physics lets a robot reach, per kind of contact: ``obstacle``
    (static obstacles and walls) and ``robot`` (another follower or a robot leader).

    pymunk has no continuous collision detection, and Chipmunk moves bodies *before* it finds
    contacts in each substep of ``h = world.dt / world.substeps`` s: a contact that begins during
    a substep is resolved only after the bodies have moved for the whole substep. So one contact
    sinks by at most what it closes in one substep, plus the overlap the solver tolerates
    (:data:`COLLISION_SLOP`):

    * a robot into an obstacle or a wall: ``v * h + slop``, with ``v`` the fastest robot speed
      (``max(robots.max_speed, leader.speed)``);
    * two robots, both driving at each other: ``2 * v * h + slop``.

    Each is multiplied by :data:`PILEUP_FACTOR` for pile-ups (an empirical allowance, not a
    derivation). On ``paper_cbs_switch`` (0.5 m/s, h = 0.125 s) that is 0.101 m (obstacle) and
    0.195 m (robot); on ``paper_vo_*`` (0.65 m/s, h = 0.025 s) 0.032 m and 0.056 m. Humans are
    kinematic (infinitely heavy): one that walks into a robot pinned against an obstacle pushes
    it in without bound, so contacts with humans are not covered. The anti-tunnelling rule
    (:func:`swarm_env.scenarios.loader.required_substeps`) keeps ``2 * v * h`` at most one radius.
    """
    h = scenario.world.dt / scenario.world.substeps
    v = max(scenario.robots.max_speed, scenario.leader.speed)
    return {"obstacle": PILEUP_FACTOR * (v * h + COLLISION_SLOP), "robot": PILEUP_FACTOR * (2 * v * h + COLLISION_SLOP)}


def _unit_body(
    position: tuple[float, float],
    angle: float,
    radius: float,
    limits: tuple[float | None, float | None],
    compiled: bool = True,
) -> pymunk.Body:
    """A differential-drive robot's body (:func:`~swarm_env.sim.bodies.robot_body`) with the fastest velocity
    callback that gives the reference's bits here; ``compiled``: the compiled one where
    :mod:`swarm_env.sim.drive_kernel` is available and the compiled kernels are on."""
    body = robot_body(position, angle, radius, limits)
    _install_drive(body, compiled)
    return body


def _install_drive(body: pymunk.Body, compiled: bool = True) -> None:
    """Give ``body`` the fastest velocity callback that gives :func:`~swarm_env.sim.bodies.velocity_callback`'s
    bits here."""
    if isinstance(body.drive, list):  # a world pickled before the drive state became an array
        body.drive = np.array([math.nan if x is None else float(x) for x in body.drive])
    if compiled and compiled_kernels():
        from swarm_env.sim import drive_kernel

        if drive_kernel.install(body):
            return
    install_python_callback(body)


#: The most slots the compiled slot kernel screens (project_free's fast path takes up to this many).
_SLOT_KERNEL_MAX = 32

#: Whether :func:`_space_step` mirrors this pymunk's ``Space.step`` (written against pymunk 7).
_FAST_SPACE_STEP = CP_LIB is not None and str(pymunk.version).split(".")[0] == "7"

if CP_LIB is not None:
    _CP_SPACE_STEP = CP_LIB.cpSpaceStep
    _CP_SET_POSITION = CP_LIB.cpBodySetPosition
    _CP_SET_VELOCITY = CP_LIB.cpBodySetVelocity


_PHYSICS_KERNEL: Any = None
_SLOT_KERNEL: Any = None


def _physics_kernel() -> Any:
    """:mod:`swarm_env.sim.physics_kernel`, imported at first use (it imports numba, which the
    numpy-reference workers of the batched engine never load)."""
    global _PHYSICS_KERNEL
    if _PHYSICS_KERNEL is None:
        from swarm_env.sim import physics_kernel

        _PHYSICS_KERNEL = physics_kernel
    return _PHYSICS_KERNEL


def _slot_kernel() -> Any:
    """:mod:`swarm_env.geometry.slot_kernel`, imported at first use (as :func:`_physics_kernel`)."""
    global _SLOT_KERNEL
    if _SLOT_KERNEL is None:
        from swarm_env.geometry import slot_kernel

        _SLOT_KERNEL = slot_kernel
    return _SLOT_KERNEL


def _set_kinematic(bodies: list[pymunk.Body], pos: list[list[float]], vel: list[list[float]]) -> None:
    """Set each body's position and velocity (rows of ``pos``, ``vel``) as pymunk's property setters
    do (the same chipmunk calls), without their Python wrappers."""
    if CP_LIB is None:
        for body, p, v in zip(bodies, pos, vel):
            set_body_position(body, (p[0], p[1]))
            set_body_velocity(body, (v[0], v[1]))
        return
    set_position, set_velocity = _CP_SET_POSITION, _CP_SET_VELOCITY
    for body, p, v in zip(bodies, pos, vel):
        handle = body._body
        set_position(handle, p)
        set_velocity(handle, v)


def _snap_kinematic(bodies: list[pymunk.Body], pos: list[list[float]]) -> None:
    """Set each body's position (rows of ``pos``) as pymunk's property setter does."""
    if CP_LIB is None:
        for body, p in zip(bodies, pos):
            set_body_position(body, (p[0], p[1]))
        return
    set_position = _CP_SET_POSITION
    for body, p in zip(bodies, pos):
        set_position(body._body, p)


def _plain_step(space: pymunk.Space) -> bool:
    """Whether ``space.step`` is pymunk's own (not replaced on the instance or in a subclass, as a
    test that watches every substep does): only then may :func:`_space_step` stand in for it."""
    return getattr(space.step, "__func__", None) is pymunk.Space.step


def _space_step(space: pymunk.Space, dt: float) -> None:
    """``space.step(dt)`` for a space with no bodies left to check (``space._bodies_to_check``
    empty) that is not threaded: what pymunk 7's ``Space.step`` does, with its Python work
    skipped where there is none (nothing added or removed during the step, no post-step
    callbacks). The space is locked during chipmunk's step, so collision callbacks that add or
    remove objects defer them as they do under ``Space.step``."""
    space._locked = True
    try:
        _CP_SPACE_STEP(space._space, dt)
        space._removed_shapes.clear()
    finally:
        space._locked = False
    if space._add_later or space._remove_later or space._post_step_callbacks:
        _finish_step(space)


def _finish_step(space: pymunk.Space) -> None:
    """The end of pymunk 7's ``Space.step``: add and remove what callbacks deferred, then run the
    post-step callbacks (the same order as pymunk)."""
    space.add(*space._add_later)
    space._add_later.clear()
    removed = set()
    while space._remove_later:
        to_remove, _ = space._remove_later.popitem()
        if to_remove not in removed:
            removed.add(to_remove)
            space._remove(to_remove)
    for key in space._post_step_callbacks:
        space._post_step_callbacks[key](space)
    space._post_step_callbacks.clear()


# pymunk.batch.Buffer never frees its C arrays, so there is one per thread (a buffer is
# filled and copied out within one read; cffi releases the GIL during the C call).
_BATCH_BUFFERS = threading.local()


def _batch_buffer() -> Any:
    buf = getattr(_BATCH_BUFFERS, "buffer", None)
    if buf is None:
        import pymunk.batch as pb

        buf = _BATCH_BUFFERS.buffer = pb.Buffer()
    return buf


class _BodyReader:
    """Reads ``(x, y, angle, vx, vy, omega)`` of a list of bodies as an ``(n, 6)`` array.

    One ``pymunk.batch`` call copies the state of every body in the space (about 10x
    faster than 6 property reads per body); the rows of ``bodies`` are picked by body
    id, and the ids are checked on every read. Where ``pymunk.batch`` is missing or
    behaves differently (it is marked experimental), the properties are read instead;
    both give the same numbers. Not picklable: :class:`World` rebuilds it.
    """

    _batch_ok: bool | None = None  # pymunk.batch passed the self-test (None: not run yet)

    def __init__(self, space: pymunk.Space, bodies: list[pymunk.Body]) -> None:
        self.space = space
        self.bodies = bodies
        self._batch: Any = None
        if not self._batch_works():
            return
        import pymunk.batch as pb

        fields = self._fields()
        buf = _batch_buffer()
        buf.clear()
        pb.get_space_bodies(space, fields, buf)
        ids = bytes(buf.int_buf())
        all_ids = np.frombuffer(ids, dtype=np.uintp).tolist()
        if sorted(set(all_ids)) != sorted(all_ids) or any(b.id not in all_ids for b in bodies):
            return
        rows = np.array([all_ids.index(b.id) for b in bodies], dtype=np.intp)
        self._batch = (pb.get_space_bodies, fields, ids, rows, len(all_ids))

    @staticmethod
    def _fields() -> Any:
        import pymunk.batch as pb

        f = pb.BodyFields
        return f.BODY_ID | f.POSITION | f.ANGLE | f.VELOCITY | f.ANGULAR_VELOCITY

    @classmethod
    def _batch_works(cls) -> bool:
        """Once per process: does pymunk.batch return our 6 numbers, in our order?"""
        if cls._batch_ok is None:
            try:
                import pymunk.batch as pb

                space = pymunk.Space()
                body = pymunk.Body(1.0, 1.0)
                body.position, body.angle = (1.5, 2.5), 3.5
                body.velocity, body.angular_velocity = (4.5, 5.5), 6.5
                space.add(body, pymunk.Circle(body, 1.0))
                buf = _batch_buffer()
                buf.clear()
                pb.get_space_bodies(space, cls._fields(), buf)
                ids = np.frombuffer(bytes(buf.int_buf()), dtype=np.uintp).tolist()
                vals = np.frombuffer(bytes(buf.float_buf()), dtype=np.float64).reshape(-1, 6)
                cls._batch_ok = body.id in ids and vals[ids.index(body.id)].tolist() == [1.5, 2.5, 3.5, 4.5, 5.5, 6.5]
            except Exception:  # noqa: BLE001 - the API is marked experimental: fall back to properties
                cls._batch_ok = False
        return bool(cls._batch_ok)

    def read(self) -> np.ndarray:
        if self._batch is not None:
            get, fields, ids, rows, count = self._batch
            buf = _batch_buffer()
            buf.clear()
            get(self.space, fields, buf)
            if bytes(buf.int_buf()) == ids:
                return np.frombuffer(buf.float_buf(), dtype=np.float64).reshape(count, 6)[rows]
        return self._read_properties()

    def _read_properties(self) -> np.ndarray:
        out: list[float] = []
        for b in self.bodies:
            out.extend(b.position)
            out.append(b.angle)
            out.extend(b.velocity)
            out.append(b.angular_velocity)
        return np.array(out, dtype=np.float64).reshape(len(self.bodies), 6)


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
        self._offsets = [np.ascontiguousarray(formation_lib.formation_offsets(f, self.n), dtype=np.float64).reshape(-1, 2)
                         for f in scenario.formations]
        self._slot_screen: tuple[np.ndarray, np.ndarray] | None = None  # StaticMap.slot_screen, at first use
        self._leader_packed: np.ndarray | None = None  # slot_kernel.pack_path of the leader's path, at first use
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
        starts = self._start_poses()
        self._bodies: list[pymunk.Body] = []
        for i, (x, y, th) in enumerate(starts):
            body = _unit_body((float(x), float(y)), float(th), robots.radius, (robots.max_accel, robots.max_turn_accel))
            shape = pymunk.Circle(body, robots.radius)
            self._init_shape(shape, _FOLLOWER, i)
            self.space.add(body, shape)
            self._bodies.append(body)

        self._drives = self._pack_drives()

        self._human_bodies: list[pymunk.Body] = []
        self._human_paths = human_paths(scenario.humans)
        self._packed_humans: Any = None  # swarm_env.sim.human_kernel.PackedHumans, built at first use
        hpos, hvel = human_states(scenario.humans, 0.0, self._human_paths)
        for j, h in enumerate(scenario.humans):
            body = pymunk.Body(body_type=pymunk.Body.KINEMATIC)
            body.position = (float(hpos[j, 0]), float(hpos[j, 1]))
            shape = pymunk.Circle(body, h.radius)
            self._init_shape(shape, _HUMAN, j)
            self.space.add(body, shape)
            self._human_bodies.append(body)
        self._human_pos, self._human_vel = hpos, hvel
        self._human_radius = np.array([h.radius for h in scenario.humans], dtype=float)
        # Reactive humans (behavior social_force or orca) walk at a velocity chosen once per control step.
        self._reactive = np.array([j for j, h in enumerate(scenario.humans) if h.behavior != "scripted"], dtype=np.intp)
        self._walker = None
        if len(self._reactive):
            self._walker = WaypointWalker([scenario.humans[j] for j in self._reactive],
                                          [self._human_paths[j] for j in self._reactive])
        self._crowd: Any = None  # swarm_env.sim.humans.ORCACrowd, built at the first step of ``orca`` humans
        self._react_start = hpos[self._reactive].copy()  # their positions at the step's start
        self._react_vel = np.zeros((len(self._reactive), 2))

        # Contact bookkeeping (see the module docstring).
        self._touching: set[tuple[str, int, int]] = set()
        self._touched_step: set[tuple[str, int, int]] = set()
        self._touched_prev: set[tuple[str, int, int]] = set()
        self._onsets: tuple[Contact, ...] = ()
        self._touching_step: tuple[Contact, ...] = ()
        for robot_type in (_FOLLOWER, _LEADER):
            for other in (_FOLLOWER, _LEADER, _HUMAN, _OBSTACLE, _WALL):
                if robot_type == _LEADER and other == _FOLLOWER:
                    continue  # handled as (follower, leader)
                self.space.on_collision(robot_type, other, begin=self._on_begin, separate=self._on_separate)

        self._own_handlers = len(self.space._handlers)  # collision handlers: only this world's (see step)
        self._phys_addresses: Any = None  # physics_kernel.addresses of the space and humans, at first use
        self._phys_scripted: Any = None  # physics_kernel.scripted_step's (ptrs, consts), at first use
        self._slots = self._compute_slots()
        self._reader = _BodyReader(self.space, self._bodies)
        # Constant per-episode arrays, shared read-only by every snapshot.
        self._follower_radius = np.full(self.n, robots.radius)
        self._follower_radius.flags.writeable = False
        self._human_radius.flags.writeable = False

    # pymunk.batch buffers (and an RVO2 crowd) do not pickle: drop the reader and build a new one for the copy
    # (and give the copy's robots their fast velocity callbacks, see swarm_env.sim.bodies.install_python_callback).
    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        del state["_reader"]
        state["_crowd"] = None  # RVO2's simulator does not pickle; it is rebuilt at the next step
        state["_packed_humans"] = None  # rebuilt at first use (and a copy may land where numba is not loaded)
        state["_phys_addresses"] = state["_phys_scripted"] = None  # C addresses: the copy's bodies live elsewhere
        state["_drives"] = None  # the bodies' drive rows, packed again by __setstate__
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        state.setdefault("_slot_screen", None)  # worlds pickled before these caches existed
        state.setdefault("_leader_packed", None)
        state.setdefault("_phys_addresses", None)
        state.setdefault("_phys_scripted", None)
        state.setdefault("_own_handlers", len(state["space"]._handlers))
        self.__dict__.update(state)
        self._reader = _BodyReader(self.space, self._bodies)
        self._drives = self._pack_drives()

    def _pack_drives(self) -> np.ndarray:
        """Make the robots' drive states (``body.drive``, see :func:`~swarm_env.sim.bodies.velocity_callback`) rows of one
        ``(n + leader, 6)`` array (followers first), so a step writes every command at once, and
        give each robot its velocity callback on its row. The world owns ``body.drive``."""
        robots = self._bodies + ([self._leader_body] if self._leader_body is not None else [])
        rows = [np.asarray([math.nan if x is None else float(x) for x in b.drive], dtype=np.float64) for b in robots]
        packed = np.empty((len(robots), 6), dtype=np.float64)
        for k, row in enumerate(rows):
            packed[k] = row
        for k, body in enumerate(robots):
            body.drive = packed[k]
            _install_drive(body)
        return packed

    # ------------------------------------------------------------------ building
    @staticmethod
    def _init_shape(shape: pymunk.Shape, collision_type: int, index: int) -> None:
        shape.collision_type = collision_type
        shape.friction = 0.0  # robots slide along walls instead of being spun by them
        shape.elasticity = 0.0
        shape.swarm_id = index

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

    def _start_poses(self) -> np.ndarray:
        start = self.scenario.robots.start
        if start == "formation":
            offsets = self._offsets[self.formation_index]
            return formation_lib.formation_start(self.scenario.leader.path, offsets, self.static, self._slot_clearance)
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
        limits (if any) are applied in every substep by :func:`~swarm_env.sim.bodies.velocity_callback`.
        """
        robots = self.scenario.robots
        v_max, w_max = float(robots.max_speed), float(robots.max_turn_rate)
        compiled = self._compiled_substeps_ok() and np.shape(command) == (self.n, 2)
        if not compiled:  # (compiled: physics_kernel.substeps clips them, the same way)
            for body, (v, w) in zip(self._bodies, command.tolist()):
                drive = body.drive
                drive[0] = min(max(v, -v_max), v_max)  # = np.clip, on Python floats
                drive[1] = min(max(w, -w_max), w_max)
        if self._leader_body is not None:
            self._leader_body.drive[0:2] = self._leader_command().tolist()
        self._touched_step = set(self._touching)
        t0 = self.time
        humans = self._human_bodies
        scripted = compiled and not len(self._reactive)
        if humans and not scripted:
            if len(self._reactive):
                self._react_vel = self._reactive_velocities()
                self._react_start = self._human_pos[self._reactive].copy()
            # Every substep's human positions and velocities, and the end of the step's, at once.
            hpos, hvel = self._human_substates(t0)
        space, sub_dt = self.space, self.sub_dt
        if scripted:  # humans and physics in one call, see swarm_env.sim.physics_kernel
            kernel = _physics_kernel()
            if self._phys_scripted is None:
                space_ptr, handles = kernel.addresses(space, humans)
                self._phys_scripted = (np.concatenate([kernel.functions(), [space_ptr], handles]).astype(np.int64),
                                       np.array([sub_dt, self.dt, v_max, w_max]))
            if self._packed_humans is None:
                from swarm_env.sim.human_kernel import PackedHumans

                self._packed_humans = PackedHumans(self.scenario.humans, self._human_paths)
            ptrs, consts = self._phys_scripted
            space._locked = True
            try:
                hpos, hvel = kernel.scripted_step(ptrs, consts, t0, self.step_count, self.substeps, self._packed_humans,
                                                  np.ascontiguousarray(command, dtype=np.float64), self._drives)
                space._removed_shapes.clear()
            finally:
                space._locked = False
            if space._add_later or space._remove_later or space._post_step_callbacks:
                _finish_step(space)
        elif compiled:  # the same C calls, see swarm_env.sim.physics_kernel
            kernel = _physics_kernel()
            if self._phys_addresses is None:
                self._phys_addresses = kernel.addresses(space, humans)
            space_ptr, handles = self._phys_addresses
            if not humans:
                hpos = hvel = np.zeros((self.substeps + 1, 0, 2))
            space._locked = True
            try:
                kernel.substeps(space_ptr, sub_dt, handles, hpos, hvel, self.substeps,
                                np.ascontiguousarray(command, dtype=np.float64), v_max, w_max, self._drives)
                space._removed_shapes.clear()
            finally:
                space._locked = False
            if space._add_later or space._remove_later or space._post_step_callbacks:
                _finish_step(space)
        else:
            if humans:
                hpos_l, hvel_l = hpos.tolist(), hvel.tolist()
            fast = _FAST_SPACE_STEP and not space.threaded and _plain_step(space)
            for k in range(self.substeps):
                if humans:
                    _set_kinematic(humans, hpos_l[k], hvel_l[k])
                if fast and not space._bodies_to_check:
                    _space_step(space, sub_dt)
                else:
                    space.step(sub_dt)

        self.step_count += 1
        self.time = self.step_count * self.dt  # no accumulated float drift
        if humans:
            self._human_pos, self._human_vel = hpos[self.substeps], hvel[self.substeps]
            if not compiled:  # (compiled: the physics kernel did it)
                _snap_kinematic(humans, hpos[self.substeps].tolist())  # to the exact path (kinematic bodies integrate with round-off)
        self.formation_index = formation_lib.active_formation(self.scenario.formations, self.time)
        if self._leader_body is None and compiled_kernels():
            self._slots = self._advance_virtual_leader_and_slots()
        else:
            self._advance_leader()
            self._slots = self._compute_slots()

        self._settle_contacts()

    def _settle_contacts(self) -> None:
        """The end of a step's contact bookkeeping: the onsets and the pairs in touch of the step
        from the pairs its collision callbacks saw (see the module docstring)."""
        touched = self._touched_step
        if touched == self._touched_prev:  # the same pairs as the last step: no onset, the same list
            self._onsets = ()
        else:
            new = touched - self._touched_prev
            self._onsets = tuple(Contact(kind, i, j) for kind, i, j in sorted(new))  # type: ignore[arg-type]
            self._touching_step = tuple(Contact(kind, i, j) for kind, i, j in sorted(touched))  # type: ignore[arg-type]
        self._touched_prev = touched

    def _compiled_substeps_ok(self) -> bool:
        """Whether :func:`swarm_env.sim.physics_kernel.substeps` may run this step's substeps: the
        compiled kernels are on and work here, and pymunk's ``Space.step`` would do nothing but
        chipmunk's step in each substep (no new bodies to check, nothing deferred, no post-step
        callback, only this world's collision handlers, which defer nothing)."""
        if not (_FAST_SPACE_STEP and compiled_kernels()):
            return False
        return self._space_quiet() and _physics_kernel().available()

    def _space_quiet(self) -> bool:
        """The per-world part of :meth:`_compiled_substeps_ok`: the space is not threaded, steps with
        pymunk's own ``Space.step``, has no new bodies to check, nothing deferred, no post-step
        callback and only this world's collision handlers."""
        space = self.space
        if space.threaded or not _plain_step(space):
            return False
        if space._bodies_to_check or space._add_later or space._remove_later or space._post_step_callbacks:
            return False
        return len(space._handlers) == self._own_handlers

    def _human_substates(self, t0: float) -> tuple[np.ndarray, np.ndarray]:
        """``(positions, velocities)``, each ``(substeps + 1, H, 2)``: row ``k < substeps`` at
        substep ``k`` of the step starting at ``t0``, the last row at the end of the step
        (``(step_count + 1) * dt``). Scripted humans on their paths (one kernel call, or
        :func:`~swarm_env.geometry.paths.human_states` per time); reactive ones from their position at the
        step's start at their step velocity."""
        sub_dt = self.sub_dt
        times = [t0 + k * sub_dt for k in range(self.substeps)] + [(self.step_count + 1) * self.dt]
        since = [k * sub_dt for k in range(self.substeps)] + [self.dt]
        if compiled_kernels():  # the same bits, see swarm_env.sim.human_kernel
            if self._packed_humans is None:
                from swarm_env.sim.human_kernel import PackedHumans

                self._packed_humans = PackedHumans(self.scenario.humans, self._human_paths)
            pos, vel = self._packed_humans.states_at(np.array(times))
        else:
            rows = [human_states(self.scenario.humans, t, self._human_paths) for t in times]
            pos = np.stack([p for p, _ in rows])
            vel = np.stack([v for _, v in rows])
        if len(self._reactive):
            r = self._reactive
            pos[:, r] = self._react_start + self._react_vel * np.array(since)[:, None, None]
            vel[:, r] = self._react_vel
        return pos, vel

    def _reactive_velocities(self) -> np.ndarray:
        """The reactive humans' velocities for the coming control step (:mod:`swarm_env.sim.humans`)."""
        idx = self._reactive
        assert self._walker is not None
        pos = self._human_pos[idx]
        goals, arrived = self._walker.goals(pos)
        humans = [self.scenario.humans[j] for j in idx]
        walking = np.array([self.time >= h.start_delay for h in humans]) & ~arrived
        speed = np.array([h.speed for h in humans])
        robot_pos = [self.follower_positions()]
        robot_vel = [self.follower_velocities()]
        robot_r = [np.full(self.n, self.scenario.robots.radius)]
        if self._leader_body is not None:
            lb = self._leader_body
            robot_pos.append(np.array([[lb.position.x, lb.position.y]]))
            robot_vel.append(np.array([[lb.velocity.x, lb.velocity.y]]))
            robot_r.append(np.array([self.scenario.leader.radius]))
        rp, rv, rr = np.concatenate(robot_pos), np.concatenate(robot_vel), np.concatenate(robot_r)
        out = np.zeros((len(idx), 2))
        social = np.array([h.behavior == "social_force" for h in humans])
        if social.any():
            sf = idx[social]
            others = np.concatenate([np.column_stack([rp, rr]),
                                     np.column_stack([np.delete(self._human_pos, sf, axis=0), np.delete(self._human_radius, sf)])])
            out[social] = social_force_velocities(pos[social], self._human_vel[sf], self._human_radius[sf], speed[social],
                                                  goals[social], walking[social], others, self.static, self.dt)
        if not social.all():
            orca = ~social
            if self._crowd is None:
                speeds = np.array([h.speed for h in self.scenario.humans])
                self._crowd = ORCACrowd(self.static, self.dt, self._human_radius, speeds, rr)
            out[orca] = self._crowd.velocities(self._human_pos, self._human_vel, rp, rv, idx[orca],
                                               preferred_velocities(pos[orca], self._human_vel[idx[orca]], goals[orca],
                                                                    speed[orca], walking[orca]))
        return out

    def _leader_command(self) -> np.ndarray:
        """Paper 003 Fig. 1: pure pursuit along the path, then a velocity-obstacle check."""
        spec = self.scenario.leader
        body = self._leader_body
        assert body is not None
        if self._leader_done or self.time < spec.start_delay:
            return np.zeros(2)
        pose = np.array([body.position.x, body.position.y, body.angle])
        target, self._leader_s = pursuit.lookahead_target(self._leader_path, pose[:2], self._leader_s, spec.lookahead)
        preferred = pursuit.pure_pursuit(pose, target, spec.speed, spec.max_turn_rate, 1.0)
        discs = [self._human_pos, self.follower_positions()]
        vels = [self._human_vel, self.follower_velocities()]
        radii = np.concatenate([self._human_radius, np.full(self.n, self.scenario.robots.radius)])
        result = vo.vo_select(
            pose,
            spec.radius,
            preferred,
            np.hstack([np.vstack(discs), radii[:, None]]),
            np.vstack(vels),
            self.static,
            spec.speed,
            spec.max_turn_rate,
            LEADER_VO,
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
        # formation.slot_targets(..., static, clearance) screens the targets with
        # static.distance() and projects the bad ones; project_free() does both (a free point
        # comes back unchanged, each point independently of the others), with a cheaper screen.
        offsets = self._offsets[self.formation_index]
        if compiled_kernels() and len(offsets) <= _SLOT_KERNEL_MAX:  # the same bits, see swarm_env.geometry.slot_kernel
            screen, size_reach = self._screen()
            targets, free = _slot_kernel().slots(self.leader_pose(), offsets, screen, size_reach)
            slots = targets if free else self.static.project_free(targets, self._slot_clearance)
        else:
            targets = formation_lib.slot_targets(self.leader_pose(), offsets, None, 0.0)
            slots = self.static.project_free(targets, self._slot_clearance)  # a new array, shared read-only
        slots.flags.writeable = False  # by the snapshots
        return slots

    def _screen(self) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`StaticMap.slot_screen` of the slots' clearance (built at first use, per world)."""
        if self._slot_screen is None:
            self._slot_screen = self.static.slot_screen(self._slot_clearance)
        return self._slot_screen

    def _advance_virtual_leader_and_slots(self) -> np.ndarray:
        """:meth:`_advance_leader` then :meth:`_compute_slots` for a virtual leader, compiled: one
        kernel call (:func:`swarm_env.geometry.slot_kernel.virtual_slots`) gives the same bits."""
        offsets = self._offsets[self.formation_index]
        if len(offsets) > _SLOT_KERNEL_MAX:
            self._advance_leader()
            return self._compute_slots()
        slot_kernel = _slot_kernel()
        if self._leader_packed is None:
            self._leader_packed = slot_kernel.pack_path(self._leader_path)
        spec = self.scenario.leader
        screen, size_reach = self._screen()
        leader, targets, free = slot_kernel.virtual_slots(self._leader_packed, self._leader_path.length, spec.speed,
                                                          spec.start_delay, self.time, offsets, screen, size_reach)
        self._virtual_pose, self._virtual_vel = leader[0:3], leader[3:5]
        self._leader_done = bool(leader[5])
        slots = targets if free else self.static.project_free(targets, self._slot_clearance)
        slots.flags.writeable = False  # by the snapshots
        return slots

    # ------------------------------------------------------------------ reading
    def follower_positions(self) -> np.ndarray:
        return np.array([tuple(b.position) for b in self._bodies], dtype=float).reshape(self.n, 2)

    def follower_velocities(self) -> np.ndarray:
        return np.array([tuple(b.velocity) for b in self._bodies], dtype=float).reshape(self.n, 2)

    def leader_pose(self) -> np.ndarray:
        if self._leader_body is None:
            return np.array(self._virtual_pose, dtype=float)
        b = self._leader_body
        return np.array([b.position.x, b.position.y, float(pursuit.wrap_angle(b.angle))])

    def _follower_arrays(self, raw: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(pose, vel, twist)`` of the followers from the reader's ``(n, 6)`` rows (the numpy
        reference of :func:`swarm_env.sim.snapshot_kernel.follower_arrays`)."""
        angle = raw[:, 2]
        twist = np.empty((self.n, 2))
        np.add(raw[:, 3] * np.cos(angle), raw[:, 4] * np.sin(angle), out=twist[:, 0])  # forward speed
        twist[:, 1] = raw[:, 5]
        pose = raw[:, :3].copy()
        pose[:, 2] = pursuit.wrap_angle(angle)
        vel = raw[:, 3:5].copy()
        return pose, vel, twist

    def snapshot(self) -> WorldState:
        """A frozen copy of the current state."""
        raw = self._reader.read()  # (n, 6): x, y, angle, vx, vy, omega
        if compiled_kernels():  # the same bits, see swarm_env.sim.snapshot_kernel
            from swarm_env.sim.snapshot_kernel import follower_arrays

            pose, vel, twist = follower_arrays(np.ascontiguousarray(raw))
        else:
            pose, vel, twist = self._follower_arrays(raw)
        if self._leader_body is None:
            lpose = np.array(self._virtual_pose, dtype=float)
            lvel = np.array(self._virtual_vel, dtype=float)
            lspeed = float(np.hypot(lvel[0], lvel[1]))  # = np.hypot(*lvel), without unpacking
            ltwist = np.array([lspeed, 0.0])
            lradius = 0.0
        else:
            lb = self._leader_body
            lpose = self.leader_pose()
            lvel = np.array([lb.velocity.x, lb.velocity.y])
            ltwist = np.array([lvel[0] * math.cos(lpose[2]) + lvel[1] * math.sin(lpose[2]), lb.angular_velocity])
            lradius = float(self.scenario.leader.radius)
        human_pos = np.array(self._human_pos, dtype=float).reshape(-1, 2)
        human_vel = np.array(self._human_vel, dtype=float).reshape(-1, 2)
        for arr in (pose, vel, twist, lpose, lvel, ltwist, human_pos, human_vel):
            arr.flags.writeable = False
        return WorldState.build(
            time=self.time,
            step=self.step_count,
            follower_pose=pose,
            follower_vel=vel,
            follower_twist=twist,
            follower_radius=self._follower_radius,
            leader_pose=lpose,
            leader_vel=lvel,
            leader_twist=ltwist,
            leader_radius=lradius,
            leader_done=self._leader_done,
            human_pos=human_pos,
            human_vel=human_vel,
            human_radius=self._human_radius,
            slot_targets=self._slots,
            formation_index=self.formation_index,
            next_switch_time=formation_lib.next_switch_time(self.scenario.formations, self.time),
            contacts=self._onsets,
            static=self.static,
            scenario=self.scenario,
            touching=self._touching_step,
        )


__all__ = ["World", "COLLISION_SLOP", "LEADER_GOAL_TOLERANCE", "PILEUP_FACTOR", "SLOT_MARGIN", "max_overlap"]
