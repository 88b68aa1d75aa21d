"""The VO safety layer: swarm_env.control.safety (one implementation), the SafetyShield wrapper and shield:SPEC."""

from __future__ import annotations

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test

import swarm_env
from swarm_env.control.safety import AvoidanceParams, safe_follower_twists, shield_actions
from swarm_env.env import SwarmEnv
from swarm_env.harness.episode import run_episode
from swarm_env.harness.policies import PolicyError, load_policy
from swarm_env.wrappers import SHIELD_INFO_KEYS, SafetyShield
from tests.test_physics import _scenario

PUSH = np.array([1.0, 0.0], np.float32)


def _head_on() -> SwarmEnv:
    return SwarmEnv(_scenario([[3.0, 5.0, 0.0], [7.0, 5.0, np.pi]]))


def test_the_shield_stops_a_head_on_collision_that_happens_without_it() -> None:
    bare = _head_on()
    bare.reset(seed=0)
    for _ in range(80):
        bare.step({a: PUSH for a in bare.agents})
    assert bare.episode_metrics()["collisions"]["robot_robot"] == 1

    env = SafetyShield(_head_on())
    _, infos = env.reset(seed=0)
    assert all(tuple(k for k in info if k.startswith("shield_")) == SHIELD_INFO_KEYS for info in infos.values())
    intervened = 0
    for _ in range(80):
        _, _, _, _, infos = env.step({a: PUSH for a in env.agents})
        intervened += sum(info["shield_intervened"] for info in infos.values())
        for a, info in infos.items():
            # The reported size is the distance between what was asked and what was executed.
            assert info["shield_correction"] == pytest.approx(float(np.hypot(*(env.last_safe_actions[a] - PUSH))), abs=1e-6)
            assert info["shield_intervened"] == (info["shield_correction"] > 0)
    metrics = env.episode_metrics()
    assert metrics["collisions"]["total"] == 0 and intervened > 0
    shield = metrics["shield"]
    assert shield["interventions"] == intervened == sum(shield["per_agent"].values())
    assert shield["agent_steps"] == 160 and 0 < shield["intervention_rate"] <= 1
    assert 0 < shield["mean_correction"] <= shield["max_correction"] <= 2 * np.sqrt(2)


def test_safe_actions_pass_through_bit_for_bit() -> None:
    env = SafetyShield(swarm_env.parallel_env("paper_vo_90", max_cycles=30))
    bare = swarm_env.parallel_env("paper_vo_90", max_cycles=30)
    env.reset(seed=0)
    bare.reset(seed=0)
    slow = np.array([0.05, 0.01], np.float32)  # crawling forward in open space: always safe
    for _ in range(30):
        obs, rew, *_ , infos = env.step({a: slow for a in env.agents})
        obs_b, rew_b, *_ = bare.step({a: slow for a in bare.agents})
        assert not any(info["shield_intervened"] for info in infos.values())
        assert rew == rew_b and all(np.array_equal(obs[a], obs_b[a]) for a in obs)


def test_the_wrapped_env_passes_the_pettingzoo_api_test() -> None:
    parallel_api_test(SafetyShield(swarm_env.parallel_env("paper_vo_45")), num_cycles=60)


def test_discrete_envs_are_refused() -> None:
    with pytest.raises(ValueError, match="continuous"):
        SafetyShield(swarm_env.parallel_env("paper_vo_0", action_type="discrete"))
    with pytest.raises(PolicyError, match="continuous"):
        load_policy("shield:random", swarm_env.parallel_env("paper_vo_0", action_type="discrete"))


def test_the_vo_expert_is_the_same_avoidance() -> None:
    from swarm_env_agents.vo_expert import EXPERT_AVOIDANCE, VOExpert

    env = swarm_env.parallel_env("paper_vo_45")
    env.reset(seed=0)
    expert = VOExpert()
    for _ in range(5):
        env.step({a: np.zeros(2, np.float32) for a in env.agents})
    state = env.world_state()
    twist, feasible, _ = expert.twists(state)
    direct = safe_follower_twists(state, expert.preferred_twists(state), expert.avoidance)
    np.testing.assert_array_equal(twist, direct.twist)
    np.testing.assert_array_equal(feasible, direct.feasible)
    # the shared parameters, with the expert's own defaults on top (the safety layer keeps the shared ones)
    assert expert.avoidance == AvoidanceParams(**EXPERT_AVOIDANCE) and expert.horizon == EXPERT_AVOIDANCE["horizon"]


@pytest.mark.slow
def test_shield_policy_makes_pursuit_collision_free_on_held_out_worlds() -> None:
    env = swarm_env.parallel_env("random")
    bare, shielded = load_policy("pursuit", env), load_policy("shield:pursuit", env)
    hits_bare = hits_shielded = 0
    for seed in range(1000, 1006):
        hits_bare += run_episode(env, bare, seed)["collisions"]["total"]
        result = run_episode(env, shielded, seed)
        hits_shielded += result["collisions"]["total"]
        assert result["policy_stats"]["shield_interventions"] > 0
    assert hits_bare >= 6 and hits_shielded == 0


def test_shield_actions_matches_the_wrapper() -> None:
    env = SafetyShield(swarm_env.parallel_env("random", max_cycles=40))
    env.reset(seed=3)
    rng = np.random.default_rng(0)
    for _ in range(40):
        wanted = rng.uniform(-1, 1, (len(env.agents), 2)).astype(np.float32)
        state = env.world_state()
        expected = shield_actions(state, wanted.astype(np.float64), env.params)
        env.step({a: wanted[i] for i, a in enumerate(env.agents)})
        got = np.stack([env.last_safe_actions[a] for a in env.possible_agents])
        np.testing.assert_array_equal(got, expected.actions)


def test_shield_policy_needs_an_inner_policy() -> None:
    with pytest.raises(PolicyError, match="shield:SPEC"):
        load_policy("shield", swarm_env.parallel_env("paper_vo_0"))


def test_human_horizon_gives_the_humans_their_own_horizon():
    # 0 (the safety layer's default) keeps `horizon` for everyone: no per-disc horizons at all.
    assert AvoidanceParams().disc_horizons(3, 2) is None
    assert AvoidanceParams(human_horizon=2.0, horizon=2.0).disc_horizons(3, 2) is None
    assert AvoidanceParams(human_horizon=3.5).disc_horizons(3, 0) is None  # no humans
    h = AvoidanceParams(human_horizon=3.5, horizon=2.5).disc_horizons(3, 2)
    assert h.tolist() == [2.5, 2.5, 2.5, 3.5, 3.5]
    for bad in (-1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="human_horizon"):
            AvoidanceParams(human_horizon=bad)
    # In a world with humans the longer horizon changes what is safe; in one without, nothing.
    env = SwarmEnv("paper_vo_0")
    env.reset(seed=0)
    for _ in range(80):  # the humans walk into the followers' way
        env.step({a: np.array([1.0, 0.0], dtype=np.float32) for a in env.agents})
    state = env.world_state()
    wanted = np.tile([state.scenario.robots.max_speed, 0.0], (state.n_followers, 1))
    differ = 0
    for _ in range(40):
        res = [safe_follower_twists(state, wanted, AvoidanceParams(human_horizon=hh)) for hh in (0.0, 5.0)]
        differ += not np.array_equal(res[0].twist, res[1].twist)
        env.step({a: np.array([1.0, 0.0], dtype=np.float32) for a in env.agents})
        if not env.agents:
            break
        state = env.world_state()
    assert differ > 0
    switch = SwarmEnv("paper_cbs_switch")
    switch.reset(seed=0)
    state = switch.world_state()
    wanted = np.tile([0.5, 0.2], (state.n_followers, 1))
    a, b = (safe_follower_twists(state, wanted, AvoidanceParams(human_horizon=hh)) for hh in (0.0, 5.0))
    assert np.array_equal(a.twist, b.twist) and np.array_equal(a.min_time_to_collision, b.min_time_to_collision)
