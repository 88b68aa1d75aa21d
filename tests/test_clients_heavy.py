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
        name, epochs=1, epoch_num_steps=40, collection_step_num_env_steps=20, num_train_envs=2,
        buffer_size=500, batch_size=16, warmup_steps=80, hidden=32, seed=0, max_cycles=20, **kw
    )
    stats, buf = out["stats"], out["buffer"]
    assert stats.train_step >= 40 and stats.update_step > 0
    # the AEC view: every follower took turns, the reward row holds every follower's reward
    stored = buf.sample_indices(0)  # every filled slot of the per-env sub-buffers
    assert len(stored) == len(buf) >= 80
    assert set(buf.obs.agent_id[stored]) == set(agents)
    assert buf.rew[stored].shape == (len(stored), len(agents))
    assert np.isfinite(buf.rew[stored]).all()
    # the shared Q-network moved away from its initialisation (same seed, same first draws)
    torch.manual_seed(0)
    obs_dim = swarm_env.parallel_env(name, **kw).observation_space(agents[0]).shape
    fresh = Net(state_shape=obs_dim, action_shape=10, hidden_sizes=[32, 32])
    trained = out["network"]
    assert all(torch.isfinite(p).all() for p in trained.parameters())
    assert any(not torch.equal(a, b) for a, b in zip(fresh.parameters(), trained.parameters()))
