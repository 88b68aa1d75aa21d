"""Per-agent observations and the global state vector, computed from a ``WorldState``.

Every quantity is expressed in the observing follower's body frame (x forward,
y left) and clipped into the observation ``Box`` so that observations are
always inside their space. Observations never read pixels and never depend on
the render mode.

The layout of one follower's observation and of the global state: :mod:`swarm_env.sensing.layout`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from swarm_env.compiled import compiled_kernels
from swarm_env.geometry.static_map import StaticMap
from swarm_env.scenario import SensorSpec
from swarm_env.sensing.layout import (
    CLEARANCE_COLUMNS,
    COL_LEADER_HEADING,
    COL_LEADER_POS,
    COL_LEADER_VEL,
    COL_SLOT,
    COL_SWITCH,
    ENTITY,
    ENTITY_MASK,
    ENTITY_POS,
    ENTITY_VEL,
    FOLLOWER_COLUMNS,
    HUMAN_COLUMNS,
    LEADER_COLUMNS,
    OBS_OWN_TWIST,
    OBS_SLOT,
    OBS_SWITCH,
    STATE_GRID,
    TIME_COLUMNS,
    observation_layout,
)
from swarm_env.state import WorldState

if TYPE_CHECKING:  # the lidar kernel (numba) is imported on first use: batched-engine workers never load it
    from swarm_env.sensing.lidar import LidarInput, LidarRows, PackedMaps

_GRID_SAMPLES = 4  # samples per cell side when measuring a cell's occupied fraction


def state_layout(capacity: Capacity) -> dict[str, slice]:
    """Named slices of the global state vector (``env.state()``; ``env.state_layout``).

    ======================  =======  ==========================================================
    slice                   size     content
    ======================  =======  ==========================================================
    ``followers``           9 N      per follower: x / W, y / H, cos, sin of heading,
                                     v and omega / (2 * speed limit), slot x / W, slot y / H,
                                     present (1)
    ``leader``              6        x / W, y / H, cos, sin, vx, vy / (2 * speed limit)
    ``humans``              5 Hmax   per human slot: x / W, y / H, vx, vy / (2 * speed limit),
                                     present (1/0; absent rows are 0)
    ``time``                2        t / max_time, time to the next switch / max_time
    ``follower_clearance``  3 N      per follower, the nearest static surface (obstacle or
                                     wall): free distance / 5 m clipped to [0, 1], and the unit
                                     normal (nx, ny) pointing away from it (world frame)
    ``occupancy``           16 x 16  the static map: the occupied fraction of each cell of a
                                     16 x 16 grid over the world (row-major, y up from the
                                     bottom-left cell), constant during an episode
    ======================  =======  ==========================================================
    """
    n, h = capacity.max_followers, capacity.max_humans
    sizes = [("followers", FOLLOWER_COLUMNS * n), ("leader", LEADER_COLUMNS), ("humans", HUMAN_COLUMNS * h),
             ("time", TIME_COLUMNS), ("follower_clearance", CLEARANCE_COLUMNS * n), ("occupancy", STATE_GRID * STATE_GRID)]
    out: dict[str, slice] = {}
    start = 0
    for name, size in sizes:
        out[name] = slice(start, start + size)
        start += size
    return out


#: Distance (m) at which the state's follower clearance saturates at 1.
STATE_CLEARANCE_RANGE = 5.0


@dataclass(frozen=True)
class Capacity:
    """Upper bounds that fix the spaces for every scenario an env can produce.

    A fixed scenario has one capacity; the random generator's is the maximum
    over its knobs (most followers, most humans, largest world, fastest body).
    """

    max_followers: int
    max_humans: int
    world_size: tuple[float, float]
    max_time: float
    speed_limit: float  # m/s, bound on any body's speed used for clipping velocities


def _norm(v: np.ndarray, axis: int) -> np.ndarray:
    """``np.linalg.norm(v, axis=axis)`` for real ``v``: the same arithmetic, without its Python overhead."""
    return np.sqrt(np.add.reduce(v * v, axis=axis))


_NO_DISTANCES = np.zeros((0, 0))


class ObservationBuilder:
    """Builds every follower's observation (and the global state) in one vectorised pass."""

    def __init__(self, sensors: SensorSpec, capacity: Capacity) -> None:
        self.sensors = sensors
        self.capacity = capacity
        self.layout = observation_layout(sensors)
        self.size = self.layout["lidar"].stop
        w, h = capacity.world_size
        self.pos_limit = float(np.hypot(w, h))
        self.vel_limit = 2.0 * capacity.speed_limit
        self.low, self.high = self._bounds()
        k = sensors.lidar_rays
        self._ray_angles = 2.0 * np.pi * np.arange(k) / k
        self._columns: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
        self._packed_map: tuple[StaticMap, PackedMaps] | None = None
        self._single_index: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # team size -> (world, own disc) of scan()
        self.state_layout = state_layout(capacity)
        self.state_size = self.state_layout["occupancy"].stop
        self._grid: tuple[StaticMap, np.ndarray] | None = None  # (map, its occupancy grid), see _occupancy

    def _bounds(self) -> tuple[np.ndarray, np.ndarray]:
        high = np.empty(self.size, dtype=np.float32)
        high[OBS_OWN_TWIST] = 2.0  # measured twist can exceed the command limit briefly when pushed
        high[OBS_SLOT] = self.pos_limit
        high[COL_LEADER_POS:COL_LEADER_POS + 2] = self.pos_limit
        high[COL_LEADER_HEADING:COL_LEADER_HEADING + 2] = 1.0
        high[COL_LEADER_VEL:COL_LEADER_VEL + 2] = self.vel_limit
        high[OBS_SWITCH] = self.capacity.max_time
        for name in ("neighbors", "humans"):
            block = high[self.layout[name]].reshape(-1, ENTITY)
            block[:, ENTITY_POS:ENTITY_POS + 2] = self.pos_limit
            block[:, ENTITY_VEL:ENTITY_VEL + 2] = self.vel_limit
            block[:, ENTITY_MASK] = 1.0
            high[self.layout[name]] = block.ravel()
        high[self.layout["lidar"]] = 1.0
        low = -high
        low[OBS_SWITCH] = 0.0
        for name in ("neighbors", "humans"):
            block = low[self.layout[name]].reshape(-1, ENTITY)
            block[:, ENTITY_MASK] = 0.0
            low[self.layout[name]] = block.ravel()
        low[self.layout["lidar"]] = 0.0
        return low, high

    # ------------------------------------------------------------------ per agent
    def build(self, state: WorldState, lidar: np.ndarray | None = None) -> np.ndarray:
        """(N, size) float32 observations of the N followers of ``state``; ``lidar``: their
        ``(N, rays)`` scan (m) if the caller computed it (:meth:`scan`, for many worlds at once)."""
        obs = self.build_without_lidar(state)
        self.fill_lidar(obs, self.lidar([state]) if lidar is None else lidar)
        return obs

    def build_without_lidar(self, state: WorldState) -> np.ndarray:
        """:meth:`build` with the lidar columns left at 0, for :meth:`fill_lidar` to complete
        elsewhere (the batched engine's workers, which never load the lidar kernel). The clip
        and the float32 cast work entry by entry, so the two halves give :meth:`build`'s bits.

        Compiled (:mod:`swarm_env.sensing.obs_kernel`) unless :func:`swarm_env.compiled.use_compiled_kernels`
        turned the kernels off; the numpy reference :meth:`_assemble` gives the same bits."""
        if compiled_kernels():
            return self._assemble_compiled(state)
        out = self._assemble(state)
        np.clip(out, self.low, self.high, out=out)
        return out.astype(np.float32)

    def _assemble_compiled(self, state: WorldState) -> np.ndarray:
        """:meth:`build_without_lidar` by :func:`swarm_env.sensing.obs_kernel.assemble`."""
        from swarm_env.sensing.obs_kernel import EntityRows, ObsWorld, assemble

        scn = state.scenario
        n = state.n_followers
        th = state.follower_pose[:, 2]
        k = self.sensors.neighbors if n > 1 else 0
        hk = self.sensors.humans if len(state.human_pos) else 0
        rel = state.leader_pose[2] - th
        world = ObsWorld(
            state.follower_pose, state.follower_vel, state.follower_twist, state.slot_targets, state.leader_pose,
            np.asarray(state.leader_vel, dtype=np.float64), state.human_pos, state.human_vel,
            np.array([scn.robots.max_speed, scn.robots.max_turn_rate], dtype=np.float64),
            float(min(state.next_switch_time - state.time, self.capacity.max_time)),
            np.cos(th), np.sin(th), np.cos(rel), np.sin(rel))
        rows = EntityRows(k, self.layout["neighbors"].start, hk, self.layout["humans"].start)
        return assemble(world, _NO_DISTANCES, rows, self.size, self.low, self.high)  # the kernel computes distances

    def fill_lidar(self, obs: np.ndarray, lidar: np.ndarray) -> None:
        """Write the lidar columns of ``obs`` (``(..., size)`` float32, from
        :meth:`build_without_lidar`) from ``lidar`` (``(..., rays)`` m), as :meth:`build` does."""
        cols = self.layout["lidar"]
        scaled = np.divide(lidar, self.sensors.lidar_range)
        obs[..., cols] = np.clip(scaled, self.low[cols], self.high[cols], out=scaled)

    def _assemble(self, state: WorldState) -> np.ndarray:
        """(N, size) float64 observations, unclipped, lidar columns 0."""
        scn = state.scenario
        n = state.n_followers
        pose = state.follower_pose
        pos = pose[:, :2]
        th = pose[:, 2]
        c, s = np.cos(th), np.sin(th)
        out = np.zeros((n, self.size), dtype=np.float64)
        np.divide(state.follower_twist, (scn.robots.max_speed, scn.robots.max_turn_rate), out=out[:, OBS_OWN_TWIST])
        rel_heading = state.leader_pose[2] - th
        np.cos(rel_heading, out=out[:, COL_LEADER_HEADING])
        np.sin(rel_heading, out=out[:, COL_LEADER_HEADING + 1])
        out[:, COL_SWITCH] = min(state.next_switch_time - state.time, self.capacity.max_time)

        # Every world-frame vector of the observation goes through one rotation into the body
        # frames: slot, leader position, leader velocity, then per neighbour / human the
        # relative position and velocity (see _vector_columns for where each lands).
        k = self.sensors.neighbors if n > 1 else 0
        hk = self.sensors.humans if len(state.human_pos) else 0
        vec = np.zeros((n, 3 + 2 * k + 2 * hk, 2))
        np.subtract(state.slot_targets, pos, out=vec[:, 0])
        np.subtract(state.leader_pose[:2], pos, out=vec[:, 1])
        vec[:, 2] = state.leader_vel
        vel = state.follower_vel
        present = []
        if k:
            d = state.follower_distances().copy()
            np.fill_diagonal(d, np.inf)
            present.append(("neighbors", k, self._nearest(vec[:, 3:3 + 2 * k], d, pos, vel, pos, vel, k)))
        if hk:
            d = _norm(state.human_pos[None, :, :] - pos[:, None, :], 2)
            valid = self._nearest(vec[:, 3 + 2 * k:], d, state.human_pos, state.human_vel, pos, vel, hk)
            present.append(("humans", hk, valid))
        cc, ss = c[:, None], s[:, None]
        vx, vy = vec[..., 0], vec[..., 1]
        colx, coly = self._vector_columns(k, hk)
        out[:, colx] = cc * vx + ss * vy
        out[:, coly] = -ss * vx + cc * vy
        for name, count, valid in present:
            block = out[:, self.layout[name]].reshape(n, count, ENTITY)  # a view into out
            block[~valid] = 0.0  # absent rows are all zero
            block[:, :, ENTITY_MASK] = valid

        return out

    def _vector_columns(self, k: int, hk: int) -> tuple[np.ndarray, np.ndarray]:
        """Observation columns of the body-frame x and y of each vector built in :meth:`build`."""
        key = (k, hk)
        hit = self._columns.get(key)
        if hit is None:
            xs = [COL_SLOT, COL_LEADER_POS, COL_LEADER_VEL]
            for name, count in (("neighbors", k), ("humans", hk)):
                base = self.layout[name].start
                xs += [base + ENTITY * j + ENTITY_POS for j in range(count)]  # relative positions
                xs += [base + ENTITY * j + ENTITY_VEL for j in range(count)]  # relative velocities
            colx = np.array(xs, dtype=np.intp)
            hit = self._columns[key] = (colx, colx + 1)
        return hit

    @staticmethod
    def _nearest(
        vec: np.ndarray,
        dist: np.ndarray,
        other_pos: np.ndarray,
        other_vel: np.ndarray,
        pos: np.ndarray,
        vel: np.ndarray,
        k: int,
    ) -> np.ndarray:
        """Write into ``vec`` (N, 2k, 2) the world-frame relative positions (first k) and
        velocities (last k) of the k nearest entities per row of ``dist`` (N, M); return
        the (N, k) mask of entities present (rows beyond M, or at infinite distance, are not)."""
        n, m = dist.shape
        order = np.argsort(dist, axis=1, kind="stable")[:, :k]
        kk = order.shape[1]
        found = np.isfinite(dist[np.arange(n)[:, None], order])
        if kk == k:
            valid = found
        else:
            valid = np.zeros((n, k), dtype=bool)
            valid[:, :kk] = found
        np.subtract(other_pos[order], pos[:, None, :], out=vec[:, :kk])
        np.subtract(other_vel[order], vel[:, None, :], out=vec[:, k:k + kk])
        return valid

    def lidar(self, states: Sequence[WorldState], maps: PackedMaps | None = None) -> np.ndarray:
        """The lidar of every follower of ``states`` (one world each), stacked: ``(sum N, rays)``
        distances (m), in one call of the compiled kernel. ``maps``: ``PackedMaps.of`` the
        states' static maps, if the caller keeps it (otherwise packed here)."""
        if maps is None:
            maps = self._packed(states[0].static) if len(states) == 1 else _packed_maps([s.static for s in states])
        return self.scan([lidar_input(s) for s in states], maps)

    def scan(self, inputs: Sequence[LidarInput], maps: PackedMaps) -> np.ndarray:
        """``(sum N, rays)`` lidar distances (m) of worlds given as :func:`lidar_input` tuples,
        world ``w`` in the map ``w`` of ``maps``."""
        from swarm_env.sensing.lidar import pack_inputs, scan

        if len(inputs) == 1:  # one env's step: the discs laid out here, the index arrays kept per team size
            poses = inputs[0][0]
            n = len(poses)
            index = self._single_index.get(n)
            if index is None:
                index = self._single_index[n] = (np.zeros(n, dtype=np.int64), np.arange(n, dtype=np.int64))
            discs = discs_of(inputs[0])
            disc_start = np.array([0, len(discs)], dtype=np.int64)
            return scan(poses, index[0], index[1], self._ray_angles, self.sensors.lidar_range, maps, disc_start, discs)
        poses, world, own, disc_start, discs = pack_inputs(inputs)
        return scan(poses, world, own, self._ray_angles, self.sensors.lidar_range, maps, disc_start, discs)

    def scan_rows(self, rows: LidarRows, maps: PackedMaps) -> np.ndarray:
        """:meth:`scan` of worlds given as :data:`swarm_env.sensing.lidar.LidarRows` (the batched engine's
        stacked arrays; the same bits as their :func:`lidar_input` tuples)."""
        from swarm_env.sensing.lidar import pack_rows, scan

        poses, world, own, disc_start, discs = pack_rows(rows)
        return scan(poses, world, own, self._ray_angles, self.sensors.lidar_range, maps, disc_start, discs)

    def _packed(self, static: StaticMap) -> PackedMaps:
        """``PackedMaps.of([static])``, kept while the map stays the same."""
        if self._packed_map is None or self._packed_map[0] is not static:
            self._packed_map = (static, _packed_maps([static]))
        return self._packed_map[1]

    # ------------------------------------------------------------------ global
    def state_vector(self, state: WorldState) -> np.ndarray:
        """The global state for centralised critics (float32, inside ``state_bounds``)."""
        cap = self.capacity
        w, h = cap.world_size
        n = state.n_followers
        fol = np.zeros((cap.max_followers, FOLLOWER_COLUMNS))
        th = state.follower_pose[:, 2]
        fol[:n, 0] = state.follower_pose[:, 0] / w
        fol[:n, 1] = state.follower_pose[:, 1] / h
        fol[:n, 2] = np.cos(th)
        fol[:n, 3] = np.sin(th)
        fol[:n, 4:6] = state.follower_twist / self.vel_limit
        fol[:n, 6] = state.slot_targets[:, 0] / w
        fol[:n, 7] = state.slot_targets[:, 1] / h
        fol[:n, 8] = 1.0
        lp = state.leader_pose
        leader = np.array([lp[0] / w, lp[1] / h, np.cos(lp[2]), np.sin(lp[2]), *(state.leader_vel / self.vel_limit)])
        hum = np.zeros((cap.max_humans, HUMAN_COLUMNS))
        m = len(state.human_pos)
        if m:
            hum[:m, 0] = state.human_pos[:, 0] / w
            hum[:m, 1] = state.human_pos[:, 1] / h
            hum[:m, 2:4] = state.human_vel / self.vel_limit
            hum[:m, 4] = 1.0
        times = np.array([state.time / cap.max_time, min(state.next_switch_time - state.time, cap.max_time) / cap.max_time])
        near = np.zeros((cap.max_followers, CLEARANCE_COLUMNS))
        near[:n] = _clearance_features(state.static, state.follower_pose[:, :2])
        vec = np.concatenate([fol.ravel(), leader, hum.ravel(), times, near.ravel(), self._occupancy(state.static)])
        return np.clip(vec, -STATE_LIMIT, STATE_LIMIT).astype(np.float32)

    def _occupancy(self, static: StaticMap) -> np.ndarray:
        """The ``STATE_GRID``-square occupancy grid of ``static`` (computed once per map)."""
        if self._grid is not None and self._grid[0] is static:
            return self._grid[1]
        w, h = static.size
        k = STATE_GRID * _GRID_SAMPLES
        xs = (np.arange(k) + 0.5) * (w / k)
        ys = (np.arange(k) + 0.5) * (h / k)
        pts = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)  # row-major, y outer
        inside = (static.distance(pts, walls=False) < 0.0).reshape(STATE_GRID, _GRID_SAMPLES, STATE_GRID, _GRID_SAMPLES)
        grid = inside.mean(axis=(1, 3)).ravel()
        grid.flags.writeable = False
        self._grid = (static, grid)
        return grid


def _packed_maps(maps: Sequence[StaticMap]) -> PackedMaps:
    from swarm_env.sensing.lidar import PackedMaps

    return PackedMaps.of(maps)


def lidar_input(state: WorldState) -> LidarInput:
    """The :data:`LidarInput` of ``state``: its arrays as they are (the lidar packs many worlds
    in one pass, :func:`swarm_env.sensing.lidar.pack_inputs`; the discs are those of :func:`moving_discs`)."""
    leader = None
    if state.leader_is_robot:
        leader = (float(state.leader_pose[0]), float(state.leader_pose[1]), float(state.leader_radius))
    return state.follower_pose, state.follower_radius, state.human_pos, state.human_radius, leader


def moving_discs(state: WorldState) -> np.ndarray:
    """``(D, 3)`` ``(x, y, r)`` of the moving bodies the lidar sees: the followers (in order,
    first), a robot leader, then the humans."""
    return discs_of(lidar_input(state))


def discs_of(lidar: LidarInput) -> np.ndarray:
    """:func:`moving_discs` of a world given as its :data:`LidarInput` (the one place of the layout;
    :func:`swarm_env.sensing.lidar.pack_inputs` lays out many worlds the same way, tested against this)."""
    poses, radii, humans, human_radii, leader = lidar
    n = len(poses)
    discs = np.empty((n + (leader is not None) + len(humans), 3))
    discs[:n, :2] = poses[:, :2]
    discs[:n, 2] = radii
    if leader is not None:
        discs[n] = leader
    if len(humans):
        discs[len(discs) - len(humans):, :2] = humans
        discs[len(discs) - len(humans):, 2] = human_radii
    return discs


def _clearance_features(static: StaticMap, pos: np.ndarray) -> np.ndarray:
    """``(N, 3)``: free distance to the nearest static surface / ``STATE_CLEARANCE_RANGE`` in
    ``[0, 1]``, and the unit gradient of that distance (pointing away from the surface), by
    central differences of 0.1 mm: one :meth:`StaticMap.distance` call on ``5 N`` points
    (a sixth of :meth:`StaticMap.nearest_obstacles`' cost); ``(0, 0)`` where the gradient
    vanishes (exactly between two surfaces)."""
    h = _GRADIENT_STEP
    n = len(pos)
    probes = np.concatenate([pos, pos + (h, 0.0), pos - (h, 0.0), pos + (0.0, h), pos - (0.0, h)])
    d = static.distance(probes).reshape(5, n)
    grad = np.column_stack([d[1] - d[2], d[3] - d[4]])
    norm = np.sqrt(np.add.reduce(grad * grad, axis=1))
    unit = np.divide(grad, norm[:, None], out=np.zeros_like(grad), where=norm[:, None] > 0.0)
    return np.column_stack([np.clip(d[0] / STATE_CLEARANCE_RANGE, 0.0, 1.0), unit])


_GRADIENT_STEP = 1e-4  # m


#: Bound of every global-state entry (positions are normalised by the world size).
STATE_LIMIT = 2.0

