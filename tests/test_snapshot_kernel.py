"""The compiled snapshot arrays (swarm_env.sim.snapshot_kernel) give the numpy reference's bits."""

from __future__ import annotations

import numpy as np
import pytest

from swarm_env.env import SwarmEnv
from swarm_env.sim.snapshot_kernel import follower_arrays


@pytest.mark.parametrize("scenario", ["paper_cbs_switch", "corridor", "random"])
def test_follower_arrays_match_the_reference(scenario: str) -> None:
    env = SwarmEnv(scenario)
    env.reset(seed=3)
    rng = np.random.default_rng(1)
    world = env._world
    assert world is not None
    for t in range(200):
        raw = np.ascontiguousarray(world._reader.read())
        for got, want in zip(follower_arrays(raw), world._follower_arrays(raw)):
            assert got.shape == want.shape
            assert got.tobytes() == want.tobytes(), f"step {t}"
        _, _, term, trunc, _ = env.step({a: rng.uniform(-1, 1, 2).astype(np.float32) for a in env.agents})
        if any(term.values()) or any(trunc.values()):
            env.reset(seed=t)
            world = env._world


def test_angles_far_outside_the_wrap_range_match() -> None:
    rng = np.random.default_rng(0)
    raw = rng.normal(0.0, 1.0, (64, 6))
    raw[:, 2] = np.concatenate([rng.uniform(-1e4, 1e4, 32), np.pi * np.arange(-16, 16)])
    env = SwarmEnv("paper_vo_90")
    env.reset(seed=0)
    assert env._world is not None
    env._world.n = len(raw)  # the reference sizes its twist array by the team
    for got, want in zip(follower_arrays(raw), env._world._follower_arrays(raw)):
        assert got.tobytes() == want.tobytes()
