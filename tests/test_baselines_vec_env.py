"""The SB3 bridge (swarm_env_baselines.vec_env): seeding, auto-reset, truncation info, fixed teams, worker processes."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

import gymnasium  # noqa: E402
from stable_baselines3 import PPO  # noqa: E402

from swarm_env.env import SwarmEnv  # noqa: E402
from swarm_env_baselines.config import policy_kwargs  # noqa: E402
from swarm_env_baselines.vec_env import EnvFactory, SwarmVecEnv, make_vec_env  # noqa: E402

SMALL = {"n_followers": 3, "n_obstacles": (1, 3), "n_humans": (0, 1), "world_size": (12.0, 12.0)}


def _actions(venv: SwarmVecEnv, rng: np.random.Generator) -> np.ndarray:
    return rng.uniform(-1, 1, (venv.num_envs, 2)).astype(np.float32)


@pytest.mark.slow
def test_seeded_reset_gives_distinct_copies_equal_to_their_own_seeds():
    venv = make_vec_env("random", 3, **SMALL)
    venv.seed(7)
    obs = venv.reset()
    n = venv.n_slots
    assert obs.shape == (3 * n, 52) and venv.num_envs == 3 * n
    for m in range(3):
        ref, _ = SwarmEnv("random", **SMALL).reset(seed=7 + m * n)
        np.testing.assert_array_equal(obs[m * n : (m + 1) * n], np.stack([ref[a] for a in sorted(ref)]))
    assert not np.array_equal(obs[:n], obs[n : 2 * n])
    # The seeds are consumed: a second reset continues each copy's own generator.
    again = venv.reset()
    assert not np.array_equal(again[:n], obs[:n])
    venv.close()


@pytest.mark.slow
def test_truncation_sets_terminal_observation_and_time_limit_flag_then_auto_resets():
    venv = make_vec_env("random", 2, max_cycles=5, **SMALL)
    venv.seed(3)
    venv.reset()
    rng = np.random.default_rng(0)
    actions = [_actions(venv, rng) for _ in range(5)]
    for a in actions[:4]:
        _, _, dones, infos = venv.step(a)
        assert not dones.any() and all("terminal_observation" not in i for i in infos)
    obs, rewards, dones, infos = venv.step(actions[4])
    assert dones.all()
    # Replay copy 0 by hand: the same last observation, then reset() without a seed.
    env = SwarmEnv("random", max_cycles=5, **SMALL)
    env.reset(seed=3)
    for a in actions:
        last, rew, term, trunc, _ = env.step({ag: a[i] for i, ag in enumerate(env.agents)})
    for i, agent in enumerate(sorted(last)):
        assert infos[i]["TimeLimit.truncated"] is True
        np.testing.assert_array_equal(infos[i]["terminal_observation"], last[agent])
        assert rewards[i] == pytest.approx(rew[agent])
        assert infos[i]["episode"]["l"] == 5
    fresh, _ = env.reset()
    np.testing.assert_array_equal(obs[:3], np.stack([fresh[a] for a in sorted(fresh)]))
    venv.close()


def test_termination_is_not_reported_as_truncation():
    kwargs = dict(SMALL, terminate_on_collision=True, max_cycles=400)
    venv = make_vec_env("random", 1, seed=2, **kwargs)
    venv.reset()
    env = SwarmEnv("random", **kwargs)
    env.reset(seed=2)
    ahead = np.tile([1.0, 0.0], (venv.num_envs, 1)).astype(np.float32)  # full speed ahead: something is hit
    returns = np.zeros(venv.num_envs)
    for t in range(400):  # noqa: B007 - t is read after the loop
        obs, rewards, dones, infos = venv.step(ahead)
        last, rew, term, trunc, _ = env.step({a: ahead[i] for i, a in enumerate(env.possible_agents)})
        returns += rewards.astype(np.float64)
        if dones.any():
            break
    assert dones.all() and env.termination == "collision" and t < 399
    assert [i["TimeLimit.truncated"] for i in infos] == [False] * venv.num_envs
    np.testing.assert_allclose([i["episode"]["r"] for i in infos], returns, rtol=1e-5)
    assert infos[0]["episode"]["l"] == t + 1
    np.testing.assert_array_equal(infos[1]["terminal_observation"], last[env.possible_agents[1]])
    fresh, _ = env.reset()  # the returned observation is already the next episode's first
    np.testing.assert_array_equal(obs, np.stack([fresh[a] for a in env.possible_agents]))
    venv.close()


def test_team_range_gives_every_slot_a_real_follower():
    kwargs = dict(n_followers=(2, 8), team_seed=5, n_obstacles=0, n_humans=0)
    venv = make_vec_env("random", 2, **kwargs)
    n = len(SwarmEnv("random", **kwargs).possible_agents)
    assert venv.n_slots == n and venv.num_envs == 2 * n
    venv.seed(3)
    venv.reset()
    assert all("reward_formation" in info for info in venv.reset_infos)  # real reset infos, no padding rows
    for _ in range(3):
        obs, rewards, dones, infos = venv.step(np.ones((2 * n, 2), np.float32))
        assert all("slot_distance" in info for info in infos) and not dones.any()
    venv.close()


def test_a_world_that_is_not_a_swarm_env_is_refused():
    with pytest.raises(TypeError, match="SwarmEnv or SafetyShield"):
        SwarmVecEnv(lambda: gymnasium.make("CartPole-v1"), 1)


def test_subprocess_copies_step_identically_to_in_process():
    def roll(n_procs: int) -> list[np.ndarray]:
        venv = make_vec_env("random", 2, n_procs=n_procs, seed=11, max_cycles=8, **SMALL)
        rng = np.random.default_rng(1)
        out = [venv.reset()]
        for _ in range(12):  # crosses an auto-reset
            obs, rew, done, _ = venv.step(_actions(venv, rng))
            out += [obs, rew, done]
        out.append(np.array(venv.get_attr("scenario_name")))
        venv.close()
        return out

    for a, b in zip(roll(1), roll(2)):
        np.testing.assert_array_equal(a, b)


def test_attribute_access_maps_sub_envs_to_copies():
    venv = make_vec_env("random", 2, **SMALL)
    venv.reset()
    n = venv.n_slots
    assert venv.get_attr("scenario_name") == ["random"] * (2 * n)
    venv.set_attr("max_cycles", 9, indices=[n])  # the second copy only
    assert venv.get_attr("max_cycles", indices=[0, n]) == [None, 9]
    assert len(venv.env_method("state", indices=[0, n])) == 2
    with pytest.raises(ValueError, match="n_procs"):
        SwarmVecEnv(EnvFactory("random", SMALL), 2, n_procs=3)
    venv.close()


def _ppo_params(seed: int) -> dict[str, np.ndarray]:
    import torch

    torch.set_num_threads(1)
    venv = make_vec_env("random", 2, max_cycles=20, **SMALL)
    model = PPO("MlpPolicy", venv, n_steps=16, batch_size=32, n_epochs=2, seed=seed, device="cpu",
                policy_kwargs=policy_kwargs((32, 32)))
    model.learn(2 * 16 * venv.num_envs)
    venv.close()
    return {k: v.detach().numpy().copy() for k, v in model.policy.state_dict().items()}


def test_same_seed_gives_identical_sb3_parameters():
    a, b, c = _ppo_params(5), _ppo_params(5), _ppo_params(6)
    assert a.keys() == b.keys()
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])
    assert any(not np.array_equal(a[k], c[k]) for k in a)
