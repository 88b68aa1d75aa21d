"""One seeded episode of a policy: the loop every evaluation, recording and training validation runs."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from swarm_env.env import SwarmEnv
from swarm_env.harness.policies import Policy


def run_episode(
    env: SwarmEnv,
    policy: Policy,
    seed: int | None,
    on_frame: Callable[[np.ndarray], None] | None = None,
    on_step: Callable[[dict[str, Any] | None], None] | None = None,
) -> dict[str, Any]:
    """Play one episode of ``policy`` in ``env`` from ``reset(seed)``.

    ``on_frame`` (if given, and the env renders ``rgb_array``) receives every
    frame, the initial one included. ``on_step`` (if given) is called with
    ``None`` after the reset and with the actions dict after every
    ``env.step`` that applied it (:mod:`swarm_env.harness.recording` records through
    it); an exception it raises ends the episode and propagates. Returns
    ``env.episode_metrics()`` plus ``seed``, ``policy_time`` (s spent in
    ``policy.act``) and, if the policy has ``stats()``, ``policy_stats``.
    """
    obs, _ = env.reset(seed=seed)
    policy.reset(env, seed)
    policy_time = 0.0

    def emit() -> None:
        if on_frame is not None:
            frame = env.render()
            if frame is not None:
                on_frame(frame)

    emit()
    if on_step is not None:
        on_step(None)
    while env.agents:
        t0 = time.perf_counter()
        actions = policy.act(obs, env.world_state())
        policy_time += time.perf_counter() - t0
        obs, _, _, _, _ = env.step(actions)
        if on_step is not None:
            on_step(actions)
        emit()
    result = {"seed": seed, **env.episode_metrics(), "policy_time": policy_time}
    stats = getattr(policy, "stats", None)
    if callable(stats):
        result["policy_stats"] = stats()
    return result
