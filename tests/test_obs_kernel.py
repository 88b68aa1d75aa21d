"""The compiled observation assembly (swarm_env.sensing.obs_kernel) gives the numpy reference's bits."""

from __future__ import annotations

import numpy as np
import pytest

from swarm_env.compiled import use_compiled_kernels
from swarm_env.env import SwarmEnv
from swarm_env.scenarios.loader import list_scenarios
from swarm_env.sensing import observations


def _both(builder: observations.ObservationBuilder, state) -> tuple[np.ndarray, np.ndarray]:
    use_compiled_kernels(True)
    try:
        compiled = builder.build_without_lidar(state)
        use_compiled_kernels(False)
        reference = builder.build_without_lidar(state)
    finally:
        use_compiled_kernels(True)
    return compiled, reference


def _episode_states(env: SwarmEnv, seed: int, steps: int):
    """The states of ``steps`` steps of random actions (a fresh episode at each end)."""
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)
    yield env._state
    for _ in range(steps):
        actions = {a: rng.uniform(-1.0, 1.0, 2).astype(np.float32) for a in env.agents}
        _, _, term, trunc, _ = env.step(actions)
        yield env._state
        if any(term.values()) or any(trunc.values()):
            env.reset(seed=int(rng.integers(1 << 30)))


CASES = [(name, {}) for name in list_scenarios() if name != "random"]
CASES += [("random", {"n_humans": (2, 6)}), ("random", {"n_followers": (1, 1)}), ("random", {"n_followers": (12, 16)})]


@pytest.mark.parametrize(("scenario", "kwargs"), CASES, ids=[f"{s}{'-' + str(k) if k else ''}" for s, k in CASES])
def test_compiled_assembly_gives_the_reference_bits(scenario: str, kwargs: dict) -> None:
    env = SwarmEnv(scenario, **kwargs)
    builder = env._obs
    compared = 0
    for t, state in enumerate(_episode_states(env, seed=7, steps=120)):
        compiled, reference = _both(builder, state)
        assert compiled.dtype == reference.dtype == np.float32
        assert compiled.shape == reference.shape
        mismatch = compiled.view(np.uint32) != reference.view(np.uint32)
        assert not mismatch.any(), f"{scenario} step {t}: columns {np.flatnonzero(mismatch.any(axis=0))} differ"
        compared += 1
    assert compared == 121


def test_compiled_assembly_covers_crowds_and_absent_entities() -> None:
    """More humans and neighbours than sensed, fewer than sensed, and states pushed to the clip bounds."""
    for kwargs in ({"n_humans": (8, 10), "n_followers": (2, 2)}, {"n_humans": (0, 0), "n_followers": (3, 3)}):
        env = SwarmEnv("random", **kwargs)
        for state in _episode_states(env, seed=3, steps=30):
            compiled, reference = _both(env._obs, state)
            np.testing.assert_array_equal(compiled.view(np.uint32), reference.view(np.uint32))
            assert (compiled >= env._obs.low).all() and (compiled <= env._obs.high).all()


def test_build_is_build_without_lidar_then_fill_lidar() -> None:
    env = SwarmEnv("paper_cbs_switch")
    env.reset(seed=0)
    state = env._state
    full = env._obs.build(state)
    half = env._obs.build_without_lidar(state)
    assert not half[:, env._obs.layout["lidar"]].any()
    env._obs.fill_lidar(half, env._obs.lidar([state]))
    np.testing.assert_array_equal(full.view(np.uint32), half.view(np.uint32))
    assert full[:, env._obs.layout["lidar"]].any()
