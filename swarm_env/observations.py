"""Per-agent observations and the global state vector, computed from a ``WorldState``.

Every quantity is expressed in the observing follower's body frame (x forward,
y left) and clipped into the observation ``Box`` so that observations are
always inside their space. Observations never read pixels and never depend on
the render mode.

Layout of one follower's observation (``float32``, length
``11 + 5 * neighbors + 5 * humans + lidar_rays``):

======================  =====  ================================================
slice                   size   content
======================  =====  ================================================
``OBS_OWN_TWIST``       2      own (v / max_speed, omega / max_turn_rate)
``OBS_SLOT``            2      vector to the own slot target (m)
``OBS_LEADER``          6      leader position (m), (cos, sin) of its relative
                               heading, leader velocity (m/s)
``OBS_SWITCH``          1      seconds to the next formation switch (capped at
                               ``max_time``; the cap when none is scheduled)
neighbours              5 k    k nearest other followers: dx, dy (m), dvx, dvy
                               (m/s), present-mask (1/0); absent rows are 0
humans                  5 h    h nearest humans, same 5 columns
lidar                   R      ray distance / lidar_range in [0, 1], rays
                               evenly spaced from straight ahead,
                               counter-clockwise; hits obstacles, walls,
                               robots (the leader included) and humans
======================  =====  ================================================

:func:`observation_layout` returns the named slices for a given sensor spec.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from swarm_env.geometry import cast_rays
from swarm_env.scenario import SensorSpec
from swarm_env.state import WorldState

OBS_OWN_TWIST = slice(0, 2)
OBS_SLOT = slice(2, 4)
OBS_LEADER = slice(4, 10)
OBS_SWITCH = slice(10, 11)
_FIXED = 11
_ENTITY = 5  # dx, dy, dvx, dvy, mask


def observation_layout(sensors: SensorSpec) -> dict[str, slice]:
    """Named slices of the observation vector for ``sensors``."""
    k, h, r = sensors.neighbors, sensors.humans, sensors.lidar_rays
    nb = slice(_FIXED, _FIXED + _ENTITY * k)
    hu = slice(nb.stop, nb.stop + _ENTITY * h)
    li = slice(hu.stop, hu.stop + r)
    return {
        "own_twist": OBS_OWN_TWIST,
        "slot": OBS_SLOT,
        "leader": OBS_LEADER,
        "switch": OBS_SWITCH,
        "neighbors": nb,
        "humans": hu,
        "lidar": li,
    }


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
        # Global state: per follower (x, y, cos, sin, v, omega, slot x, slot y, present),
        # leader (x, y, cos, sin, vx, vy), per human (x, y, vx, vy, present), time, next switch.
        self.state_size = 9 * capacity.max_followers + 6 + 5 * capacity.max_humans + 2

    def _bounds(self) -> tuple[np.ndarray, np.ndarray]:
        high = np.empty(self.size, dtype=np.float32)
        high[OBS_OWN_TWIST] = 2.0  # measured twist can exceed the command limit briefly when pushed
        high[OBS_SLOT] = self.pos_limit
        high[4:6] = self.pos_limit
        high[6:8] = 1.0
        high[8:10] = self.vel_limit
        high[OBS_SWITCH] = self.capacity.max_time
        for name in ("neighbors", "humans"):
            block = high[self.layout[name]].reshape(-1, _ENTITY)
            block[:, 0:2] = self.pos_limit
            block[:, 2:4] = self.vel_limit
            block[:, 4] = 1.0
            high[self.layout[name]] = block.ravel()
        high[self.layout["lidar"]] = 1.0
        low = -high
        low[OBS_SWITCH] = 0.0
        for name in ("neighbors", "humans"):
            block = low[self.layout[name]].reshape(-1, _ENTITY)
            block[:, 4] = 0.0
            low[self.layout[name]] = block.ravel()
        low[self.layout["lidar"]] = 0.0
        return low, high

    # ------------------------------------------------------------------ per agent
    def build(self, state: WorldState) -> np.ndarray:
        """(N, size) float32 observations of the N followers of ``state``."""
        scn = state.scenario
        n = state.n_followers
        pos = state.follower_pose[:, :2]
        th = state.follower_pose[:, 2]
        c, s = np.cos(th), np.sin(th)
        out = np.zeros((n, self.size), dtype=np.float64)

        out[:, 0] = state.follower_twist[:, 0] / scn.robots.max_speed
        out[:, 1] = state.follower_twist[:, 1] / scn.robots.max_turn_rate
        out[:, OBS_SLOT] = _to_body(state.slot_targets - pos, c, s)
        out[:, 4:6] = _to_body(state.leader_pose[None, :2] - pos, c, s)
        rel_heading = state.leader_pose[2] - th
        out[:, 6] = np.cos(rel_heading)
        out[:, 7] = np.sin(rel_heading)
        out[:, 8:10] = _to_body(np.broadcast_to(state.leader_vel, (n, 2)), c, s)
        out[:, 10] = min(state.next_switch_time - state.time, self.capacity.max_time)

        vel = state.follower_vel
        k = self.sensors.neighbors
        if k and n > 1:
            d = np.linalg.norm(pos[None, :, :] - pos[:, None, :], axis=2)
            np.fill_diagonal(d, np.inf)
            self._nearest(out[:, self.layout["neighbors"]], d, pos, vel, pos, vel, c, s, k)
        h = self.sensors.humans
        if h and len(state.human_pos):
            d = np.linalg.norm(state.human_pos[None, :, :] - pos[:, None, :], axis=2)
            self._nearest(out[:, self.layout["humans"]], d, state.human_pos, state.human_vel, pos, vel, c, s, h)

        out[:, self.layout["lidar"]] = self._lidar(state) / self.sensors.lidar_range
        np.clip(out, self.low, self.high, out=out)
        return out.astype(np.float32)

    def _nearest(
        self,
        block: np.ndarray,
        dist: np.ndarray,
        other_pos: np.ndarray,
        other_vel: np.ndarray,
        pos: np.ndarray,
        vel: np.ndarray,
        c: np.ndarray,
        s: np.ndarray,
        k: int,
    ) -> None:
        """Fill ``block`` (N, 5k view) with the k nearest entities per row of ``dist`` (N, M)."""
        n, m = dist.shape
        order = np.argsort(dist, axis=1, kind="stable")[:, :k]
        valid = np.isfinite(np.take_along_axis(dist, order, axis=1))
        rel_p = other_pos[order] - pos[:, None, :]
        rel_v = other_vel[order] - vel[:, None, :]
        cc, ss = c[:, None], s[:, None]
        rows = np.zeros((n, k, _ENTITY))
        kk = order.shape[1]
        rows[:, :kk, 0] = cc * rel_p[..., 0] + ss * rel_p[..., 1]
        rows[:, :kk, 1] = -ss * rel_p[..., 0] + cc * rel_p[..., 1]
        rows[:, :kk, 2] = cc * rel_v[..., 0] + ss * rel_v[..., 1]
        rows[:, :kk, 3] = -ss * rel_v[..., 0] + cc * rel_v[..., 1]
        rows[:, :kk, 4] = 1.0
        rows[:, :kk][~valid] = 0.0
        block[:] = rows.reshape(n, k * _ENTITY)

    def _lidar(self, state: WorldState) -> np.ndarray:
        n = state.n_followers
        r = self.sensors.lidar_rays
        discs = [np.column_stack([state.follower_pose[:, :2], state.follower_radius])]
        if state.leader_is_robot:
            discs.append(np.array([[state.leader_pose[0], state.leader_pose[1], state.leader_radius]]))
        if len(state.human_pos):
            discs.append(np.column_stack([state.human_pos, state.human_radius]))
        origins = np.repeat(state.follower_pose[:, :2], r, axis=0)
        angles = (state.follower_pose[:, 2:3] + self._ray_angles[None, :]).ravel()
        exclude = np.repeat(np.arange(n), r)
        dist = cast_rays(origins, angles, self.sensors.lidar_range, state.static, np.vstack(discs), exclude)
        return dist.reshape(n, r)

    # ------------------------------------------------------------------ global
    def state_vector(self, state: WorldState) -> np.ndarray:
        """The global state for centralised critics (float32, inside ``state_bounds``)."""
        cap = self.capacity
        w, h = cap.world_size
        n = state.n_followers
        fol = np.zeros((cap.max_followers, 9))
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
        hum = np.zeros((cap.max_humans, 5))
        m = len(state.human_pos)
        if m:
            hum[:m, 0] = state.human_pos[:, 0] / w
            hum[:m, 1] = state.human_pos[:, 1] / h
            hum[:m, 2:4] = state.human_vel / self.vel_limit
            hum[:m, 4] = 1.0
        times = np.array([state.time / cap.max_time, min(state.next_switch_time - state.time, cap.max_time) / cap.max_time])
        vec = np.concatenate([fol.ravel(), leader, hum.ravel(), times])
        return np.clip(vec, -STATE_LIMIT, STATE_LIMIT).astype(np.float32)


#: Bound of every global-state entry (positions are normalised by the world size).
STATE_LIMIT = 2.0


def _to_body(vec: np.ndarray, c: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Rotate world-frame vectors (N, 2) into the body frames given by cos/sin (N,)."""
    return np.stack([c * vec[:, 0] + s * vec[:, 1], -s * vec[:, 0] + c * vec[:, 1]], axis=1)
