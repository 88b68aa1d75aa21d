"""The SB3 bridge (baselines.vec_env): seeding, auto-reset, truncation info, inactive slots, subprocesses."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

import gymnasium  # noqa: E402
from stable_baselines3 import PPO  # noqa: E402

from baselines.config import policy_kwargs  # noqa: E402
from baselines.vec_env import EnvFactory, SwarmVecEnv, make_vec_env  # noqa: E402
from swarm_env.env import SwarmEnv  # noqa: E402

SMALL = {"n_followers": 3, "n_obstacles": (1, 3), "n_humans": (0, 1), "world_size": (12.0, 12.0)}


def _actions(venv: SwarmVecEnv, rng: np.random.Generator) -> np.ndarray:
    return rng.uniform(-1, 1, (venv.num_envs, 2)).astype(np.float32)


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


class _TerminatingEnv:
    """A minimal two-agent ParallelEnv stand-in that terminates (not truncates) after 3 steps."""

    possible_agents = ["follower_0", "follower_1"]
    render_mode = None

    def __init__(self) -> None:
        self.agents: list[str] = []
        self.t = 0

    def observation_space(self, agent: str) -> gymnasium.spaces.Box:
        return gymnasium.spaces.Box(-1, 1, (52,), np.float32)

    def action_space(self, agent: str) -> gymnasium.spaces.Box:
        return gymnasium.spaces.Box(-1, 1, (2,), np.float32)

    def reset(self, seed=None, options=None):
        self.agents, self.t = list(self.possible_agents), 0
        return {a: np.full(52, 0.0, np.float32) for a in self.agents}, {a: {} for a in self.agents}

    def step(self, actions):
        self.t += 1
        obs = {a: np.full(52, self.t / 10, np.float32) for a in self.agents}
        done = self.t == 3
        out = (obs, dict.fromkeys(self.agents, 1.0), dict.fromkeys(self.agents, done), dict.fromkeys(self.agents, False))
        infos = {a: {} for a in self.agents}
        if done:
            self.agents = []
        return (*out, infos)

    def close(self) -> None:
        pass


def test_termination_is_not_reported_as_truncation():
    venv = SwarmVecEnv(_TerminatingEnv, 1)
    venv.reset()
    for _ in range(3):
        obs, rewards, dones, infos = venv.step(np.zeros((2, 2), np.float32))
    assert dones.all()
    assert [i["TimeLimit.truncated"] for i in infos] == [False, False]
    assert [i["episode"]["r"] for i in infos] == [3.0, 3.0]
    np.testing.assert_array_equal(infos[0]["terminal_observation"], np.full(52, 0.3, np.float32))
    np.testing.assert_array_equal(obs, 0.0)  # already the next episode's first observation


class _AgentDeathEnv(_TerminatingEnv):
    """A stand-in whose reset leaves one possible agent out (what swarm_env_v0's random did)."""

    def reset(self, seed=None, options=None):
        self.agents, self.t = ["follower_0"], 0
        return {"follower_0": np.zeros(52, np.float32)}, {"follower_0": {}}


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


def test_a_copy_that_leaves_an_agent_out_is_refused():
    venv = SwarmVecEnv(_AgentDeathEnv, 1)
    with pytest.raises(RuntimeError, match="expected all of"):
        venv.reset()


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
