"""swarm-env through outside clients of the default suite: TorchRL, SuperSuit + SB3, PettingZoo's own tests.

Every built-in scenario (``swarm_env.list_scenarios()``, ``random`` with its defaults included)
plus ``random`` with a team-size range is run through each client, and what the client hands a
learner is compared with what the raw env returns for the same seed and actions. The example
scripts ``examples/torchrl_rollout.py`` and ``examples/supersuit_sb3.py`` are what runs here.
The heavy clients (RLlib, BenchMARL, AgileRL, Tianshou) are in ``test_clients_heavy.py``.
"""

from __future__ import annotations

import importlib.util
import sys
import types
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch

import swarm_env

pytestmark = pytest.mark.filterwarnings("ignore:PettingZoo in TorchRL is tested:UserWarning")

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"

CASES = [pytest.param(name, {}, id=name) for name in swarm_env.list_scenarios()] + [
    pytest.param("random", {"n_followers": (2, 8), "team_seed": 1}, id="random-range")
]


def load_example(name: str) -> types.ModuleType:
    """Import ``examples/<name>.py`` (not a package) as a module."""
    spec = importlib.util.spec_from_file_location(f"swarm_env_example_{name}", EXAMPLES / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


@pytest.fixture(autouse=True)
def one_torch_thread():
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


def make(name: str, kw: dict, **extra):
    return swarm_env.parallel_env(name, **kw, **extra)


def seeded_actions(n_agents: int, steps: int, seed: int) -> np.ndarray:
    """(steps, n_agents, 2) float32 actions in [-1, 1]."""
    return np.random.default_rng(seed).uniform(-1.0, 1.0, (steps, n_agents, 2)).astype(np.float32)


def raw_run(name: str, kw: dict, seed: int, actions: np.ndarray, **extra) -> dict:
    """Reset the raw env with ``seed`` and play ``actions``; stack what it returns (agents in
    ``possible_agents`` order). Resets with no seed when an episode ends, as the clients do."""
    env = make(name, kw, **extra)
    obs, infos = env.reset(seed=seed)
    agents = env.possible_agents
    out = {"obs0": np.stack([obs[a] for a in agents]), "state0": env.state(), "reset_infos": infos,
           "obs": [], "rewards": [], "terminated": [], "truncated": [], "states": []}
    for act in actions:
        if not env.agents:
            env.reset()
        obs, rew, term, trunc, _ = env.step({a: act[i] for i, a in enumerate(agents)})
        out["obs"].append(np.stack([obs[a] for a in agents]))
        out["rewards"].append([rew[a] for a in agents])
        out["terminated"].append([term[a] for a in agents])
        out["truncated"].append([trunc[a] for a in agents])
        out["states"].append(env.state())
    for k in ("obs", "rewards", "terminated", "truncated", "states"):
        out[k] = np.asarray(out[k])
    return out


def leaf_keys(d: dict, prefix: tuple = ()) -> set[tuple]:
    keys: set[tuple] = set()
    for k, v in d.items():
        keys |= leaf_keys(v, prefix + (k,)) if isinstance(v, dict) else {prefix + (k,)}
    return keys


# ---------------------------------------------------------------------------------------- TorchRL
@pytest.mark.parametrize("name,kw", CASES)
def test_torchrl_example_rollout(name, kw):
    """examples/torchrl_rollout.py: check_env_specs passes and a 50-step rollout has the env's shapes."""
    raw = make(name, kw)
    n, obs_dim = len(raw.possible_agents), raw.observation_space(raw.possible_agents[0]).shape[0]
    td = load_example("torchrl_rollout").main(name, steps=50, max_cycles=20, **kw)
    assert td.batch_size == torch.Size([50])
    assert td["follower", "observation"].shape == (50, n, obs_dim)
    assert td["follower", "action"].shape == (50, n, 2)
    assert td["next", "follower", "reward"].shape == (50, n, 1)
    assert td["state"].shape == (50, *raw.state_space.shape)
    assert torch.isfinite(td["next", "follower", "reward"]).all()
    assert torch.isfinite(td["next", "follower", "observation"]).all()
    # max_cycles=20: the episodes end (truncated) exactly after steps 20 and 40, and restart
    done = td["next", "done"].squeeze(-1)
    assert done.nonzero().flatten().tolist() == [19, 39]
    assert td["next", "truncated"].squeeze(-1)[[19, 39]].all()


@pytest.mark.parametrize("name,kw", CASES)
def test_torchrl_matches_raw_env(name, kw):
    """The wrapper's specs follow the env's spaces and reset infos, and a seeded rollout returns
    exactly what the raw env returns for the same seed and actions."""
    from torchrl.envs.utils import check_env_specs

    steps, seed = 50, 7
    raw = make(name, kw)
    agents = raw.possible_agents
    env = load_example("torchrl_rollout").make_env(name, seed=0, max_cycles=60, **kw)
    check_env_specs(env)
    assert env.group_map == {"follower": agents}
    assert env.observation_spec["state"].shape == raw.state_space.shape

    _, reset_infos = raw.reset(seed=seed)
    expected_info = leaf_keys(reset_infos[agents[0]])
    assert expected_info, "reset infos are empty: TorchRL builds no info spec, so step infos are dropped"
    info_spec = env.observation_spec["follower"]["info"]
    got_info = {k if isinstance(k, tuple) else (k,) for k in info_spec.keys(True, True)}
    assert expected_info <= got_info

    actions = seeded_actions(len(agents), steps, seed)
    ref = raw_run(name, kw, seed, actions, max_cycles=60)
    counter = iter(range(steps))

    def policy(td):
        td["follower", "action"] = torch.as_tensor(actions[next(counter)])
        return td

    td0 = env.reset(seed=seed)
    rollout = env.rollout(steps, policy=policy, tensordict=td0, auto_reset=False)
    assert rollout.batch_size == torch.Size([steps])
    np.testing.assert_allclose(rollout["follower", "observation"][0].numpy(), ref["obs0"])
    np.testing.assert_allclose(rollout["state"][0].numpy(), ref["state0"])
    np.testing.assert_allclose(rollout["follower", "action"].numpy(), actions)
    reward = rollout["next", "follower", "reward"].squeeze(-1).numpy()
    assert np.isfinite(reward).all()
    np.testing.assert_allclose(reward, ref["rewards"].astype(np.float32), rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(rollout["next", "follower", "observation"].numpy(), ref["obs"], rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(rollout["next", "state"].numpy(), ref["states"], rtol=1e-6, atol=1e-6)
    assert not rollout["next", "done"].any()  # 50 < max_cycles=60


@pytest.mark.parametrize("name,kw", CASES)
def test_torchrl_truncates_at_max_steps(name, kw):
    env = load_example("torchrl_rollout").make_env(name, seed=0, max_cycles=10, **kw)
    assert env.max_steps == 10  # TorchRL forwards the ParallelEnv's attribute
    rollout = env.rollout(100)  # stops at the first done
    assert rollout.batch_size == torch.Size([10])
    assert rollout["next", "truncated"][-1].item() and rollout["next", "follower", "truncated"][-1].all()
    assert not rollout["next", "terminated"][-1].item()


# ------------------------------------------------------------------------------ SuperSuit + SB3
@pytest.mark.parametrize("name,kw", CASES)
def test_supersuit_vec_env_matches_raw_env(name, kw):
    """pettingzoo_env_to_vec_env_v1: one slot per agent, the raw env's rewards for the same seed
    and actions, the terminal observation kept at the episode end, then an automatic reset."""
    import supersuit as ss

    horizon, steps, seed = 15, 20, 11
    raw = make(name, kw)
    agents = raw.possible_agents
    vec = ss.pettingzoo_env_to_vec_env_v1(make(name, kw, max_cycles=horizon))
    assert vec.num_envs == len(agents)
    obs, infos = vec.reset(seed=seed)
    actions = seeded_actions(len(agents), steps, seed)
    ref = raw_run(name, kw, seed, actions, max_cycles=horizon)
    np.testing.assert_allclose(obs, ref["obs0"])
    assert all(set(i) == set(ref["reset_infos"][a]) for i, a in zip(infos, agents))
    for t in range(steps):
        obs, rew, term, trunc, infos = vec.step(actions[t])
        assert rew.dtype == np.float32 and np.isfinite(rew).all()
        np.testing.assert_allclose(rew, ref["rewards"][t].astype(np.float32), rtol=1e-6, atol=1e-6)
        np.testing.assert_array_equal(term.astype(bool), ref["terminated"][t])
        np.testing.assert_array_equal(trunc.astype(bool), ref["truncated"][t])
        if t == horizon - 1:  # the episode ends: SuperSuit keeps the last obs and resets the env
            assert trunc.all()
            np.testing.assert_allclose(np.stack([i["terminal_observation"] for i in infos]), ref["obs"][t])
        else:
            assert not trunc.any()
            np.testing.assert_allclose(obs, ref["obs"][t], rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("name,kw", CASES)
def test_supersuit_sb3_ppo_example(name, kw):
    """examples/supersuit_sb3.py: 2 env copies x N followers as SB3 slots, two PPO updates."""
    n = len(make(name, kw).possible_agents)
    n_steps = 8
    slots = 2 * n
    model = load_example("supersuit_sb3").main(
        name, total_timesteps=2 * n_steps * slots, copies=2, n_steps=n_steps, batch_size=n_steps * slots,
        n_epochs=1, num_cpus=0, max_cycles=12, **kw
    )
    venv = model.get_env()
    assert venv.num_envs == slots
    assert model.num_timesteps == 2 * n_steps * slots
    assert model.rollout_buffer.rewards.shape == (n_steps, slots)
    assert np.isfinite(model.rollout_buffer.rewards).all() and (model.rollout_buffer.rewards != 0).any()
    assert np.abs(model.rollout_buffer.rewards).max() < 1.0  # scaled by 0.01: unscaled, a step costs 2-20
    logged = model.logger.name_to_value
    assert np.isfinite(logged["train/value_loss"]) and np.isfinite(logged["train/policy_gradient_loss"])
    venv.close()


# ------------------------------------------------------------------------- PettingZoo test suite
class ScenarioModule:
    """What ``pettingzoo.test.max_cycles_test`` expects of an env module: ``parallel_env(max_cycles=)``
    and ``env(max_cycles=)``, with PettingZoo's usual default of ``max_cycles`` given (1,000 here;
    the env truncates at ``min(max_cycles, world.max_time / dt)``)."""

    DEFAULT_MAX_CYCLES = 1000

    def __init__(self, name: str, kw: dict):
        self.name, self.kw = name, kw

    def parallel_env(self, max_cycles: int = DEFAULT_MAX_CYCLES):
        return swarm_env.parallel_env(self.name, max_cycles=max_cycles, **self.kw)

    def env(self, max_cycles: int = DEFAULT_MAX_CYCLES):
        return swarm_env.env(self.name, max_cycles=max_cycles, **self.kw)


@pytest.mark.parametrize("name,kw", CASES)
def test_pettingzoo_max_cycles_test(name, kw):
    from pettingzoo.test import max_cycles_test

    module = ScenarioModule(name, kw)
    max_cycles_test(module)  # max_cycles=4: 4 parallel steps, 5 AEC turns per agent
    assert module.parallel_env().max_steps == min(1000, make(name, kw).max_steps)
    assert module.parallel_env(max_cycles=4).max_steps == 4


@pytest.mark.parametrize("name,kw", CASES)
def test_pettingzoo_parallel_seed_test(name, kw):
    from gymnasium.utils.env_checker import data_equivalence
    from pettingzoo.test import parallel_seed_test

    parallel_seed_test(lambda: make(name, kw, max_cycles=30))
    # parallel_seed_test stops after one step (it checks `any(terminations)` of a non-empty
    # dict); compare two seeded envs over two whole episodes as well.
    env1, env2 = make(name, kw, max_cycles=15), make(name, kw, max_cycles=15)
    for episode in range(2):
        seed = 42 if episode == 0 else None  # the second episode continues the seeded stream
        assert data_equivalence(env1.reset(seed=seed), env2.reset(seed=seed))
        assert env1.agents == env1.possible_agents
        while env1.agents:
            acts = {a: env1.action_space(a).sample() for a in env1.agents}
            assert data_equivalence(acts, {a: env2.action_space(a).sample() for a in env2.agents})
            assert data_equivalence(env1.step(acts), env2.step(acts))
        assert env2.agents == []


@pytest.mark.parametrize("name,kw", CASES)
def test_pettingzoo_state_test(name, kw):
    from pettingzoo.test import state_test

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        state_test(swarm_env.env(name, max_cycles=20, **kw), make(name, kw, max_cycles=20), num_cycles=25)
    problems = [str(w.message) for w in caught if "state" in str(w.message).lower()]
    assert not problems, problems  # NaN / inf / shape / all-zero state warnings


@pytest.mark.slow
def test_torchrl_batched_engine_specs_and_bits():
    """examples/torchrl_vector.py: TorchRL's check_env_specs passes, and a rollout across episode
    ends shows, world by world, exactly what a SwarmEnv shows for the same actions."""
    from swarm_env.env import SwarmEnv

    module = load_example("torchrl_vector")
    kwargs = {"max_cycles": 7, "n_followers": 3}
    env = module.SwarmVectorTorchRL("random", 3, **kwargs)
    env.set_seed(21)
    from torchrl.envs.utils import check_env_specs

    check_env_specs(env)
    env.set_seed(21)
    torch.manual_seed(0)
    td = env.rollout(16, break_when_any_done=False)  # crosses two episode ends per world
    env.close()
    assert td.batch_size == torch.Size([3, 16])
    assert int(td["next", "done"].sum()) == 6
    for m in range(3):
        ref = SwarmEnv("random", **kwargs)
        obs, _ = ref.reset(seed=21 + m)
        for t in range(16):
            agents = ref.possible_agents
            np.testing.assert_array_equal(td["agents", "observation"][m, t].numpy(), np.stack([obs[a] for a in agents]))
            action = td["agents", "action"][m, t].numpy()
            obs, rew, term, trunc, _ = ref.step({a: action[i] for i, a in enumerate(agents)})
            np.testing.assert_array_equal(td["next", "agents", "observation"][m, t].numpy(), np.stack([obs[a] for a in agents]))
            np.testing.assert_array_equal(td["next", "agents", "reward"][m, t, :, 0].numpy(),
                                          np.float32([rew[a] for a in agents]))
            assert bool(td["next", "truncated"][m, t]) == trunc[agents[0]]
            if not ref.agents:
                obs, _ = ref.reset()


def test_reward_scale_multiplies_every_reward_and_nothing_else() -> None:
    """swarm_env.wrappers.RewardScale (docs/clients.md, "Reward scale"): the same episode, rewards x scale;
    observations, flags and infos untouched; PettingZoo's parallel API test passes through it."""
    from pettingzoo.test import parallel_api_test

    from swarm_env.wrappers import RewardScale

    plain, scaled = swarm_env.parallel_env("paper_vo_0", max_cycles=15), RewardScale(
        swarm_env.parallel_env("paper_vo_0", max_cycles=15), 0.01)
    (o1, _), (o2, _) = plain.reset(seed=4), scaled.reset(seed=4)
    assert all(np.array_equal(o1[a], o2[a]) for a in o1)
    while plain.agents:
        actions = {a: np.array([0.5, 0.1], dtype=np.float32) for a in plain.agents}
        s1, s2 = plain.step(actions), scaled.step(actions)
        assert all(np.array_equal(s1[0][a], s2[0][a]) for a in s1[0])
        assert {a: r * 0.01 for a, r in s1[1].items()} == s2[1] and s1[2:4] == s2[2:4]
    parallel_api_test(RewardScale(swarm_env.parallel_env("paper_vo_0", max_cycles=15), 0.1), num_cycles=20)
    for bad in (0.0, -1.0, float("nan"), float("inf"), True, "0.1"):
        with pytest.raises(ValueError, match="reward scale: expected a finite number > 0"):
            RewardScale(swarm_env.parallel_env("paper_vo_0"), bad)  # type: ignore[arg-type]
