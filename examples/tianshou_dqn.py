"""swarm-env in Tianshou 2: DQN on the discrete motion primitives, one Q-network shared by all followers.

Run (after the heavy extra, see docs/clients.md)::

    python examples/tianshou_dqn.py                          # paper_vo_0, 2 epochs
    python examples/tianshou_dqn.py --scenario corridor --epochs 10

Tianshou's own multi-agent API is turn-based: ``tianshou.env.PettingZooEnv`` wraps the AEC view, so one
Tianshou step is one follower's move. With a simultaneous-move env that teaches the wrong thing: the joint
step's rewards arrive on the last follower's turn only (followers 0..N-2 always get 0), and each follower's
"next observation" is the next follower's. So this example does not use it. :class:`FollowerVectorEnv`
presents the followers of a few worlds to Tianshou as a vector of single-agent envs (env ``k * N + i`` is
follower ``i`` of world ``k``): one Tianshou step moves every follower of every world at once, as the env
means, and each follower's transition holds its own reward and its own next observation. One ``DQN`` over
that vector is parameter sharing (one Q-network for every follower), as SuperSuit's Markov vector env gives
stable-baselines3. ``action_type="discrete"`` selects swarm-env's ``Discrete(10)`` motion primitives
(paper 000).
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

import numpy as np
from tianshou.env import BaseVectorEnv

import swarm_env


class FollowerVectorEnv(BaseVectorEnv):
    """The followers of ``n_worlds`` swarm-env worlds as one Tianshou vector env of single-agent envs.

    Env ``k * N + i`` is follower ``i`` (``possible_agents[i]``) of world ``k``. ``step`` must be given every env
    at once (a world steps with all its followers' actions); ``reset`` resets whole worlds: a world's followers
    end together (swarm-env's teams are fixed), so the collector always asks for whole worlds. World ``k``'s
    first reset uses seed ``seed + k`` (:meth:`seed`), later ones continue its own generator.

    ``BaseVectorEnv.__init__`` is not called: it builds one worker per env, and a follower is not an env of its
    own; the attributes the collector reads are set here instead.
    """

    def __init__(self, make_env: Callable[[], Any], n_worlds: int) -> None:
        if n_worlds < 1:
            raise ValueError(f"n_worlds must be >= 1, got {n_worlds}")
        self.worlds = [make_env() for _ in range(n_worlds)]
        self.agents = list(self.worlds[0].possible_agents)
        if any(list(w.possible_agents) != self.agents for w in self.worlds):
            raise ValueError("every world must have the same followers (give a team-size range a team_seed)")
        self.n = len(self.agents)
        self.env_num = self.wait_num = n_worlds * self.n
        self.timeout = None
        self.is_async = False
        self.waiting_conn: list[Any] = []
        self.waiting_id: list[int] = []
        self.ready_id = list(range(self.env_num))
        self.is_closed = False
        self._next_seeds: list[int | None] = [None] * n_worlds

    def get_env_attr(self, key: str, id: Any = None) -> list[Any]:
        ids = self._wrap_id(id)
        world, agent = self.worlds[0], self.agents[0]
        value = {"action_space": lambda: world.action_space(agent),
                 "observation_space": lambda: world.observation_space(agent)}.get(key, lambda: getattr(world, key))()
        return [value] * len(ids)

    def set_env_attr(self, key: str, value: Any, id: Any = None) -> None:
        raise NotImplementedError("the followers share their world: set attributes on the worlds themselves")

    def _worlds_of(self, ids: Any) -> list[int]:
        """The worlds whose followers ``ids`` lists, all of them and nothing else (else ValueError)."""
        ids = [int(i) for i in ids]
        worlds = sorted({i // self.n for i in ids})
        if sorted(ids) != [k * self.n + i for k in worlds for i in range(self.n)]:
            raise ValueError("FollowerVectorEnv steps and resets whole worlds: give every follower of a world "
                             "(collect by steps, n_step, not by episodes)")
        return worlds

    def seed(self, seed: int | list[int] | None = None) -> list[list[int] | None]:
        seeds = [None if seed is None else seed + k for k in range(len(self.worlds))] if not isinstance(seed, list) \
            else seed
        self._next_seeds = list(seeds)
        return [[s] if s is not None else None for s in seeds for _ in range(self.n)]

    def reset(self, env_id: Any = None, **kwargs: Any) -> tuple[np.ndarray, np.ndarray]:
        ids = self._wrap_id(env_id)
        obs: dict[int, np.ndarray] = {}
        infos: dict[int, dict] = {}
        for k in self._worlds_of(ids):
            o, info = self.worlds[k].reset(seed=self._next_seeds[k], **kwargs)
            self._next_seeds[k] = None
            for i, a in enumerate(self.agents):
                obs[k * self.n + i], infos[k * self.n + i] = o[a], info[a]
        return np.stack([obs[i] for i in ids]), np.array([infos[i] for i in ids])

    def step(self, action: Any, id: Any = None) -> tuple[np.ndarray, ...]:
        ids = self._wrap_id(id)
        if action is None or len(action) != len(ids):
            raise ValueError("FollowerVectorEnv.step needs one action per env id")
        act = dict(zip((int(i) for i in ids), np.asarray(action), strict=True))
        out: dict[int, tuple[Any, ...]] = {}
        for k in self._worlds_of(ids):
            o, r, term, trunc, info = self.worlds[k].step({a: int(act[k * self.n + i]) for i, a in enumerate(self.agents)})
            for i, a in enumerate(self.agents):
                out[k * self.n + i] = (o[a], r[a], term[a], trunc[a], {**info[a], "env_id": k * self.n + i})
        obs, rew, term, trunc, info = zip(*(out[int(i)] for i in ids), strict=True)
        return np.stack(obs), np.array(rew), np.array(term), np.array(trunc), np.array(info)

    def render(self, **kwargs: Any) -> list[Any]:
        return [w.render() for w in self.worlds]

    def close(self) -> None:
        if not self.is_closed:
            for w in self.worlds:
                w.close()
            self.is_closed = True


def make_env(scenario: str = "paper_vo_0", **env_kwargs: Any):
    return swarm_env.parallel_env(scenario, action_type="discrete", **env_kwargs)


def main(
    scenario: str = "paper_vo_0",
    epochs: int = 2,
    epoch_num_steps: int = 2000,
    collection_step_num_env_steps: int = 100,
    num_train_worlds: int = 2,
    buffer_size: int = 20_000,
    batch_size: int = 64,
    warmup_steps: int = 500,
    hidden: int = 64,
    seed: int = 0,
    **env_kwargs: Any,
) -> dict[str, Any]:
    """Train a shared DQN; return the algorithm, the network, the warm-up statistics, Tianshou's InfoStats and
    the replay buffer (one sub-buffer per follower of each world). Steps count follower transitions."""
    import torch
    from tianshou.algorithm import DQN
    from tianshou.algorithm.modelfree.dqn import DiscreteQLearningPolicy
    from tianshou.algorithm.optim import AdamOptimizerFactory
    from tianshou.data import Collector, CollectStats, VectorReplayBuffer
    from tianshou.trainer import OffPolicyTrainerParams
    from tianshou.utils.net.common import Net

    np.random.seed(seed)
    torch.manual_seed(seed)
    train_envs = FollowerVectorEnv(lambda: make_env(scenario, **env_kwargs), num_train_worlds)
    train_envs.seed(seed)
    obs_space, act_space = train_envs.observation_space[0], train_envs.action_space[0]
    net = Net(state_shape=obs_space.shape, action_shape=act_space.n, hidden_sizes=[hidden, hidden])
    policy = DiscreteQLearningPolicy(model=net, action_space=act_space, eps_training=0.1, eps_inference=0.0)
    dqn = DQN(policy=policy, optim=AdamOptimizerFactory(lr=1e-3), gamma=0.99, target_update_freq=200)
    collector = Collector[CollectStats](
        dqn, train_envs, VectorReplayBuffer(buffer_size, len(train_envs)), exploration_noise=True
    )
    collector.reset()
    warmup = collector.collect(n_step=warmup_steps)
    stats = dqn.run_training(
        OffPolicyTrainerParams(
            training_collector=collector,
            test_collector=None,
            max_epochs=epochs,
            epoch_num_steps=epoch_num_steps,
            collection_step_num_env_steps=collection_step_num_env_steps,
            batch_size=batch_size,
            update_step_num_gradient_steps_per_sample=0.1,
            show_progress=False,
            verbose=False,
        )
    )
    train_envs.close()
    return {"algorithm": dqn, "network": net, "warmup": warmup, "stats": stats, "buffer": collector.buffer,
            "followers": train_envs.n}


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="paper_vo_0")
    parser.add_argument("--epochs", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    out = main(args.scenario, epochs=args.epochs, seed=args.seed)
    s = out["stats"]
    print(f"{args.scenario}: {s.train_step} follower transitions, {s.update_step} updates, "
          f"{s.timing.total_time:.1f} s")
