"""swarm-env in the heavy outside clients: RLlib, BenchMARL, AgileRL, Tianshou (marker ``clients``).

Skipped by the default run (``addopts`` deselects the marker) and, library by library, when the
library is missing. Install and run (docs/clients.md)::

    pip install -e '.[clients]' && pip install --no-deps benchmarl==1.5.2
    python -m pytest -m clients

Each test runs the library's example from ``examples/`` with a tiny budget, on a fixed scenario
and on ``random`` with a team-size range, and checks what the library collected and learned.
"""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest
import torch

import swarm_env
from tests.test_clients import leaf_keys, load_example, one_torch_thread  # noqa: F401 (an autouse fixture)

pytestmark = [
    pytest.mark.clients,
    pytest.mark.filterwarnings("ignore::DeprecationWarning"),
    pytest.mark.filterwarnings("ignore::FutureWarning"),
    pytest.mark.filterwarnings("ignore:PettingZoo in TorchRL is tested:UserWarning"),
]

CASES = [
    pytest.param("paper_vo_0", {}, id="paper_vo_0"),
    pytest.param("random", {"n_followers": (2, 8), "team_seed": 1}, id="random-range"),
]


def agents_of(name: str, kw: dict) -> list[str]:
    return swarm_env.parallel_env(name, **kw).possible_agents


@pytest.mark.parametrize("name,kw", CASES)
def test_rllib_ppo_shared_policy(name, kw):
    pytest.importorskip("ray.rllib")
    agents = agents_of(name, kw)
    results = load_example("rllib_ppo").main(
        name, iterations=1, num_cpus=1, train_batch_size=40, minibatch_size=20, num_epochs=1,
        rollout_fragment_length=20, max_cycles=20, **kw
    )
    (res,) = results
    runners, learners = res["env_runners"], res["learners"]
    assert runners["num_env_steps_sampled"] >= 40
    # every follower sampled, each as many steps as the env (a fixed team acts together)
    per_agent = {a: int(v) for a, v in runners["num_agent_steps_sampled"].items()}
    assert set(per_agent) == set(agents)
    assert set(per_agent.values()) == {int(runners["num_env_steps_sampled"])}
    # one module, "shared", trained on all of them
    assert set(learners) - {"__all_modules__"} == {"shared"}
    assert np.isfinite(learners["shared"]["total_loss"])
    assert learners["shared"]["num_module_steps_trained"] > 0


@pytest.mark.parametrize("name,kw", CASES)
def test_benchmarl_mappo_one_iteration(name, kw, tmp_path):
    if importlib.util.find_spec("benchmarl") is None:  # not importorskip: the example must import it first
        pytest.skip("benchmarl is not installed (pip install --no-deps benchmarl==1.5.2)")
    agents = agents_of(name, kw)
    example = load_example("benchmarl_mappo")  # aliases torchrl's SyncDataCollector, then imports benchmarl
    exp = example.build_experiment(
        name, iterations=1, frames_per_batch=40, n_envs=2, minibatch_size=20, minibatch_iters=1,
        max_cycles=20, save_folder=str(tmp_path), **kw
    )
    assert exp.group_map == {"follower": agents}
    assert exp.max_steps == 20
    assert exp.state_spec is not None and list(exp.state_spec.keys()) == ["state"]
    _, reset_infos = swarm_env.parallel_env(name, **kw).reset(seed=0)
    info_keys = {k if isinstance(k, tuple) else (k,) for k in exp.info_spec["follower", "info"].keys(True, True)}
    assert leaf_keys(reset_infos[agents[0]]) <= info_keys
    before = [p.detach().clone() for p in exp.policy.parameters()]
    exp.run()
    assert exp.n_iters_performed == 1 and exp.total_frames == 40
    assert np.isfinite(exp.mean_return)
    after = list(exp.policy.parameters())
    assert all(torch.isfinite(p).all() for p in after)
    assert any(not torch.equal(a, b) for a, b in zip(before, after))  # MAPPO updated the shared policy


def test_benchmarl_env_copies_play_their_own_worlds():
    """BenchMARL builds each SerialEnv copy from one factory and one experiment seed: each copy must draw its own
    random worlds (not the same world in every copy at every reset), and the same seed must give the same worlds."""
    if importlib.util.find_spec("benchmarl") is None:
        pytest.skip("benchmarl is not installed (pip install --no-deps benchmarl==1.5.2)")
    from torchrl.envs import SerialEnv

    example = load_example("benchmarl_mappo")
    task = example.SwarmEnvTask(name="swarm_env", config={"scenario": "random", "max_cycles": 5})

    def worlds(seed: int) -> list[list[bytes]]:
        env = SerialEnv(3, task.get_env_fun(3, True, seed, "cpu"))
        try:
            return [[bytes(s.numpy()) for s in env.reset()["state"]] for _ in range(2)]
        finally:
            env.close()

    first = worlds(0)
    for states in first:
        assert len(set(states)) == 3, "two copies reset to the same world"
    assert first[0] != first[1]  # a new world at the next reset
    assert worlds(0) == first and worlds(1) != first


@pytest.mark.parametrize("name,kw", CASES)
def test_agilerl_ippo_training_loop(name, kw):
    pytest.importorskip("agilerl")
    agents = agents_of(name, kw)
    out = load_example("agilerl_ippo").main(
        name, updates=2, num_envs=2, learn_step=32, batch_size=16, update_epochs=1, hidden=32, max_cycles=10, **kw
    )  # raises FloatingPointError on any non-finite action
    agent = out["agent"]
    assert list(agent.actors.keys()) == ["follower"]  # one network shared by the followers
    assert agent.agent_ids == agents
    assert out["steps"] == 2 * 32
    # (vector steps * envs, agents); AgileRL marks absent agents with NaN: a fixed team has none
    assert out["rewards"].shape == (2 * 16 * 2, len(agents))  # 2 updates x 16 vector steps x 2 envs
    assert np.isfinite(out["rewards"]).all()
    assert len(out["losses"]) == 2 and np.isfinite(out["losses"]).all()


@pytest.mark.parametrize("name,kw", CASES)
def test_tianshou_shared_dqn(name, kw):
    pytest.importorskip("tianshou")
    from tianshou.utils.net.common import Net

    agents = agents_of(name, kw)
    out = load_example("tianshou_dqn").main(
        name, epochs=1, epoch_num_steps=40, collection_step_num_env_steps=20, num_train_worlds=2,
        buffer_size=500, batch_size=16, warmup_steps=80, hidden=32, seed=0, max_cycles=20, **kw
    )
    stats, buf = out["stats"], out["buffer"]
    assert stats.train_step >= 40 and stats.update_step > 0
    assert out["followers"] == len(agents) and buf.buffer_num == 2 * len(agents)  # one sub-buffer per follower
    stored = buf.sample_indices(0)  # every filled slot of the per-follower sub-buffers
    assert len(stored) == len(buf) >= 80
    assert buf.rew[stored].shape == (len(stored),) and np.isfinite(buf.rew[stored]).all()
    # the shared Q-network moved away from its initialisation (same seed, same first draws)
    torch.manual_seed(0)
    obs_dim = swarm_env.parallel_env(name, **kw).observation_space(agents[0]).shape
    fresh = Net(state_shape=obs_dim, action_shape=10, hidden_sizes=[32, 32])
    trained = out["network"]
    assert all(torch.isfinite(p).all() for p in trained.parameters())
    assert any(not torch.equal(a, b) for a, b in zip(fresh.parameters(), trained.parameters()))


@pytest.mark.parametrize("name,kw", CASES)
def test_tianshou_transitions_are_each_followers_own(name, kw):
    """Every follower's transition holds its own reward and its own next observation: collected through the
    example's FollowerVectorEnv, the buffer equals a parallel env stepped with the same actions, follower by
    follower (through Tianshou's AEC ``PettingZooEnv`` followers 0..N-2 got reward 0 and the next follower's
    observation)."""
    pytest.importorskip("tianshou")
    from tianshou.algorithm.modelfree.dqn import DiscreteQLearningPolicy
    from tianshou.data import Collector, CollectStats, VectorReplayBuffer
    from tianshou.utils.net.common import Net

    example = load_example("tianshou_dqn")
    envs = example.FollowerVectorEnv(lambda: example.make_env(name, max_cycles=12, **kw), 1)
    envs.seed(5)
    n = envs.n
    space = envs.action_space[0]
    policy = DiscreteQLearningPolicy(model=Net(state_shape=envs.observation_space[0].shape, action_shape=space.n),
                                     action_space=space, eps_training=1.0)
    buf = VectorReplayBuffer(200, n)
    collector = Collector[CollectStats](policy, envs, buf, exploration_noise=True)
    collector.reset()
    collector.collect(n_step=10 * n)
    ref = example.make_env(name, max_cycles=12, **kw)
    obs, _ = ref.reset(seed=5)
    agents = list(ref.possible_agents)
    per = [buf.buffers[i] for i in range(n)]
    steps = len(per[0])
    assert steps == 10 and all(len(b) == steps for b in per)
    rewards_seen = np.zeros(n)
    for t in range(steps):
        for i, a in enumerate(agents):
            assert np.array_equal(per[i].obs[t], obs[a]), f"step {t}: follower {i}'s observation"
        obs, rew, *_ = ref.step({a: int(per[i].act[t]) for i, a in enumerate(agents)})
        for i, a in enumerate(agents):
            assert per[i].rew[t] == rew[a], f"step {t}: follower {i}'s reward"
            assert np.array_equal(per[i].obs_next[t], obs[a]), f"step {t}: follower {i}'s next observation"
            rewards_seen[i] += abs(rew[a])
    assert (rewards_seen > 0).all()  # every follower's transitions carry reward, not only the last one's
    envs.close()
