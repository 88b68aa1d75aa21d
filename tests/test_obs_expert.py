"""The observation-only expert (``obs_expert``): registered, reads only the observations, avoids in the physics."""

from __future__ import annotations

import numpy as np
import pytest

from swarm_env.env import SwarmEnv
from swarm_env.harness.episode import run_episode
from swarm_env.harness.policies import PolicyError, acts_on, load_policy
from swarm_env_agents.obs_expert import ObservationExpert


def test_registered_as_acting_on_observations() -> None:
    env = SwarmEnv("paper_vo_0")
    policy = load_policy("obs_expert:horizon=4,wc_step=0.5,move_rev=false", env)
    assert isinstance(policy, ObservationExpert)
    assert (policy.horizon, policy.wc_step, policy.move_rev) == (4.0, 0.5, False)
    assert acts_on("obs_expert") == "observations"
    with pytest.raises(ValueError, match="unknown parameter 'speed'"):
        load_policy("obs_expert:speed=1", env)


def test_acts_without_the_state_and_rows_of_many_worlds_match() -> None:
    """``act`` needs no world state; ``act_rows`` over the followers of several worlds (the batched engine's rows)
    gives each world's ``act``; the same observation gives the same action."""
    envs = [SwarmEnv("random", n_followers=4, n_humans=(2, 3)) for _ in range(3)]
    policy = ObservationExpert()
    observations = []
    for k, env in enumerate(envs):
        obs, _ = env.reset(seed=40 + k)
        policy.reset(env, None)
        for _ in range(30):  # drive a little so that rows, humans and lidar hits are non-trivial
            obs, *_ = env.step(policy.act(obs))
        observations.append(obs)
    rows = np.concatenate([np.stack(list(o.values())) for o in observations])
    batch = policy.act_rows(rows)
    each = np.concatenate([np.stack(list(policy.act(o, None).values())) for o in observations])
    assert batch.dtype == np.float32 and batch.shape == (12, 2)
    assert np.array_equal(batch, each)
    assert np.array_equal(policy.act_rows(rows), batch)
    assert np.all(np.abs(batch) <= 1.0)


def test_avoids_what_pursuit_hits() -> None:
    """crowd_reactive (reactive walkers, obstacles): pure pursuit to the same slots collides; the expert, from its
    observations alone, does not, and keeps the formation."""
    env = SwarmEnv("crowd_reactive")
    pursuit = run_episode(env, load_policy("pursuit", env), 0)
    expert = run_episode(env, load_policy("obs_expert", env), 0)
    assert pursuit["collisions"]["total"] > 0
    assert expert["collisions"]["total"] == 0
    assert expert["formation_error"]["mean"] < 0.45


def test_avoidance_is_what_keeps_it_clear() -> None:
    """The same expert with its contact checks cut to nothing collides where the full one does not (the check
    above can fail)."""
    env = SwarmEnv("crowd_reactive")
    blind = ObservationExpert(horizon=0.25, dt=0.25, static_horizon=0.25, t_safe=0.01, wc_step=0.0, w_ttc=0.0,
                              margin=0.0, human_margin=0.0)
    assert run_episode(env, blind, 0)["collisions"]["total"] > 0


def test_bad_inputs_are_refused() -> None:
    with pytest.raises(ValueError, match="obs_expert: horizon must be a finite number > 0"):
        ObservationExpert(horizon=0.0)
    with pytest.raises(ValueError, match="n_w must be an int"):
        ObservationExpert(n_w=1)
    with pytest.raises(ValueError, match="at least one roll-out step"):
        ObservationExpert(horizon=0.1, dt=0.25)
    with pytest.raises(ValueError, match="reverse must be in"):
        ObservationExpert(reverse=2.0)
    policy = ObservationExpert()
    with pytest.raises(PolicyError, match="before reset"):
        policy.act_rows(np.zeros((1, 52)))
    env = SwarmEnv("paper_vo_0")
    policy.reset(env, 0)
    with pytest.raises(ValueError, match="shape"):
        policy.act_rows(np.zeros((2, 7)))
    with pytest.raises(PolicyError, match="continuous"):
        load_policy("obs_expert", SwarmEnv("paper_vo_0", action_type="discrete"))
