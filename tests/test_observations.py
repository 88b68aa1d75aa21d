"""The vectorised observation builder against a plain per-follower reference of the documented layout."""

from __future__ import annotations

import math

import numpy as np
import pytest

from swarm_env.env import SwarmEnv
from swarm_env.sensing.lidar import cast_rays
from swarm_env.sensing.observations import ObservationBuilder
from swarm_env.state import WorldState


def _reference(builder: ObservationBuilder, state: WorldState) -> np.ndarray:
    """One follower at a time, straight from the table in swarm_env.sensing.observations."""
    scn, sens, lay = state.scenario, builder.sensors, builder.layout
    n = state.n_followers
    out = np.zeros((n, builder.size))
    discs = [(*state.follower_pose[j, :2], state.follower_radius[j]) for j in range(n)]
    if state.leader_is_robot:
        discs.append((*state.leader_pose[:2], state.leader_radius))
    discs += [(*state.human_pos[h], state.human_radius[h]) for h in range(len(state.human_pos))]
    for i in range(n):
        x, y, th = state.follower_pose[i]
        c, s = math.cos(th), math.sin(th)

        def body(v: np.ndarray) -> tuple[float, float]:
            return c * v[0] + s * v[1], -s * v[0] + c * v[1]

        me = np.array([x, y])
        out[i, 0] = state.follower_twist[i, 0] / scn.robots.max_speed
        out[i, 1] = state.follower_twist[i, 1] / scn.robots.max_turn_rate
        out[i, 2:4] = body(state.slot_targets[i] - me)
        out[i, 4:6] = body(state.leader_pose[:2] - me)
        out[i, 6:8] = math.cos(state.leader_pose[2] - th), math.sin(state.leader_pose[2] - th)
        out[i, 8:10] = body(state.leader_vel)
        out[i, 10] = min(state.next_switch_time - state.time, builder.capacity.max_time)
        groups = [
            ("neighbors", sens.neighbors, state.follower_pose[:, :2], state.follower_vel, [j for j in range(n) if j != i]),
            ("humans", sens.humans, state.human_pos, state.human_vel, list(range(len(state.human_pos)))),
        ]
        for name, k, p, v, ids in groups:
            # Nearest first, ties by index; the distance is sqrt(dx^2 + dy^2) computed as the builder
            # does (np.hypot rounds differently and may order two equidistant slots the other way).
            ids = sorted(ids, key=lambda j: (float(np.sqrt(np.add.reduce((p[j] - me) ** 2))), j))[:k]
            for slot, j in enumerate(ids):
                col = lay[name].start + 5 * slot
                out[i, col:col + 2] = body(p[j] - me)
                out[i, col + 2:col + 4] = body(v[j] - state.follower_vel[i])
                out[i, col + 4] = 1.0
        angles = th + 2.0 * np.pi * np.arange(sens.lidar_rays) / sens.lidar_rays
        ranges = cast_rays(np.tile(me, (len(angles), 1)), angles, sens.lidar_range, state.static,
                           np.array(discs), np.full(len(angles), i))
        out[i, lay["lidar"]] = ranges / sens.lidar_range
    return np.clip(out, builder.low, builder.high).astype(np.float32)


@pytest.mark.parametrize(
    "name, knobs",
    [("paper_cbs_switch", {}), ("paper_vo_0", {}), ("corridor", {}), ("random", {"n_humans": (1, 1)}),
     ("random", {"n_humans": (3, 3), "n_followers": (5, 5)})],
)
def test_observations_match_the_per_follower_reference(name: str, knobs: dict) -> None:
    env = SwarmEnv(name, **knobs)
    env.reset(seed=2)
    rng = np.random.default_rng(0)
    for step in range(40):
        state = env.world_state()
        got = env._obs.build(state)
        np.testing.assert_allclose(got, _reference(env._obs, state), rtol=1e-6, atol=1e-6, err_msg=f"step {step}")
        if not env.agents:
            break
        env.step({a: rng.uniform(-1.0, 1.0, 2).astype(np.float32) for a in env.agents})
