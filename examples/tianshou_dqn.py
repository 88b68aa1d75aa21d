"""swarm-env in Tianshou 2: DQN on the discrete motion primitives, one Q-network shared by all followers.

Run (after the heavy extra, see docs/clients.md)::

    python examples/tianshou_dqn.py                          # paper_vo_0, 2 epochs
    python examples/tianshou_dqn.py --scenario corridor --epochs 10

Tianshou's multi-agent API is turn-based: ``tianshou.env.PettingZooEnv`` wraps the **AEC**
view (``swarm_env.env(...)``, PettingZoo's ``parallel_to_aec``), so one Tianshou step is one
follower's move and an episode of ``T`` env steps is ``T * n_followers`` Tianshou steps.
``MultiAgentOffPolicyAlgorithm`` dispatches each agent's transitions to that agent's algorithm;
giving every agent the *same* ``DQN`` object makes the Q-network shared. ``action_type="discrete"``
selects swarm-env's ``Discrete(10)`` motion primitives (paper 000).
"""

from __future__ import annotations

import argparse
from functools import partial
from typing import Any

import swarm_env


def make_env(scenario: str = "paper_vo_0", **env_kwargs: Any):
    from tianshou.env.pettingzoo_env import PettingZooEnv

    return PettingZooEnv(swarm_env.env(scenario, action_type="discrete", **env_kwargs))


def main(
    scenario: str = "paper_vo_0",
    epochs: int = 2,
    epoch_num_steps: int = 2000,
    collection_step_num_env_steps: int = 100,
    num_train_envs: int = 2,
    buffer_size: int = 20_000,
    batch_size: int = 64,
    warmup_steps: int = 500,
    hidden: int = 64,
    seed: int = 0,
    **env_kwargs: Any,
) -> dict[str, Any]:
    """Train a shared DQN; return the algorithm, the collector statistics and Tianshou's InfoStats."""
    import numpy as np
    import torch
    from tianshou.algorithm import DQN, MultiAgentOffPolicyAlgorithm
    from tianshou.algorithm.modelfree.dqn import DiscreteQLearningPolicy
    from tianshou.algorithm.optim import AdamOptimizerFactory
    from tianshou.data import Collector, CollectStats, VectorReplayBuffer
    from tianshou.env import DummyVectorEnv
    from tianshou.trainer import OffPolicyTrainerParams
    from tianshou.utils.net.common import Net

    np.random.seed(seed)
    torch.manual_seed(seed)
    env_fn = partial(make_env, scenario, **env_kwargs)
    env = env_fn()
    net = Net(state_shape=env.observation_space.shape, action_shape=env.action_space.n, hidden_sizes=[hidden, hidden])
    policy = DiscreteQLearningPolicy(model=net, action_space=env.action_space, eps_training=0.1, eps_inference=0.0)
    dqn = DQN(policy=policy, optim=AdamOptimizerFactory(lr=1e-3), gamma=0.99, target_update_freq=200)
    algorithm = MultiAgentOffPolicyAlgorithm(algorithms=[dqn] * len(env.agents), env=env)  # one DQN for all

    train_envs = DummyVectorEnv([env_fn for _ in range(num_train_envs)])
    train_envs.seed(seed)
    collector = Collector[CollectStats](
        algorithm, train_envs, VectorReplayBuffer(buffer_size, num_train_envs), exploration_noise=True
    )
    collector.reset()
    warmup = collector.collect(n_step=warmup_steps)
    stats = algorithm.run_training(
        OffPolicyTrainerParams(
            training_collector=collector,
            test_collector=None,
            max_epochs=epochs,
            epoch_num_steps=epoch_num_steps,
            collection_step_num_env_steps=collection_step_num_env_steps,
            batch_size=batch_size,
            update_step_num_gradient_steps_per_sample=0.1,
            multi_agent_return_reduction=lambda returns: returns.mean(axis=1),  # team mean per episode
            show_progress=False,
            verbose=False,
        )
    )
    train_envs.close()
    return {"algorithm": algorithm, "network": net, "warmup": warmup, "stats": stats, "buffer": collector.buffer}


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="paper_vo_0")
    parser.add_argument("--epochs", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    out = main(args.scenario, epochs=args.epochs, seed=args.seed)
    s = out["stats"]
    print(f"{args.scenario}: {s.train_step} Tianshou steps, {s.update_step} updates, "
          f"{s.timing.total_time:.1f} s")
