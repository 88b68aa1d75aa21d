"""swarm-env in RLlib (new API stack): PPO with one policy shared by every follower.

Run (after the heavy extra, see docs/clients.md)::

    python examples/rllib_ppo.py                              # paper_vo_0, 5 iterations
    python examples/rllib_ppo.py --scenario random --iterations 20
    python examples/rllib_ppo.py --address auto --env-runners 4   # on a running `ray start` cluster

``ray.rllib.env.wrappers.pettingzoo_env.ParallelPettingZooEnv`` turns the ParallelEnv into an
RLlib ``MultiAgentEnv``; every agent id maps to the module ``"shared"``. The wrapper reads the
agent ids from one ``reset()`` when it is built, so the team must not change between episodes:
swarm-env's fixed teams (``env.agents == env.possible_agents`` after every reset) satisfy that.
The env creator is the package's :func:`swarm_env.wrappers.rllib_env`, so remote env runners on any
node (with swarm-env installed) import it by name.

Without ``--address`` a new local Ray instance is started with ``--num-cpus`` CPUs (``address="local"``:
a ``ray start`` cluster on this machine is left alone) and everything runs in this process
(``--env-runners 0``, no remote learner). With ``--address auto`` (or ``HOST:PORT``) the example joins
that cluster and samples with ``--env-runners`` remote runners.

Rewards: a follower's per-step reward is about -1 to -20 and an episode's return thousands below zero,
which pins RLlib's value loss at its clip (``vf_clip_param``, 10) unless it is scaled. ``--reward-scale``
(default 0.01) multiplies every reward before RLlib sees it (``swarm_env.wrappers.rllib_env``'s
``reward_scale``, :class:`swarm_env.wrappers.RewardScale`); docs/clients.md, "Reward scale".
"""

from __future__ import annotations

import argparse
from typing import Any

from swarm_env.wrappers import rllib_env

ENV_NAME = "swarm_env"
SHARED = "shared"


def build_config(
    scenario: str = "paper_vo_0",
    train_batch_size: int = 2000,
    minibatch_size: int = 250,
    num_epochs: int = 5,
    rollout_fragment_length: int | str = "auto",
    seed: int = 0,
    env_runners: int = 0,
    reward_scale: float = 0.01,
    **env_kwargs: Any,
):
    from ray.rllib.algorithms.ppo import PPOConfig
    from ray.rllib.core.rl_module.multi_rl_module import MultiRLModuleSpec
    from ray.rllib.core.rl_module.rl_module import RLModuleSpec

    return (
        PPOConfig()
        .environment(ENV_NAME, env_config={"scenario": scenario, "reward_scale": reward_scale, **env_kwargs})
        .framework("torch")
        .env_runners(num_env_runners=env_runners, rollout_fragment_length=rollout_fragment_length)
        .learners(num_learners=0)
        .multi_agent(policies={SHARED}, policy_mapping_fn=lambda agent_id, episode, **kw: SHARED)
        .rl_module(rl_module_spec=MultiRLModuleSpec(rl_module_specs={SHARED: RLModuleSpec()}))
        .training(train_batch_size_per_learner=train_batch_size, minibatch_size=minibatch_size, num_epochs=num_epochs)
        .debugging(seed=seed)
    )


def main(scenario: str = "paper_vo_0", iterations: int = 5, num_cpus: int = 1, address: str | None = None,
         **kwargs: Any) -> list[dict]:
    """Train ``iterations`` PPO iterations and return their result dicts (``kwargs`` go to
    :func:`build_config`: batch sizes, ``seed``, ``env_runners``, ``reward_scale`` and ``SwarmEnv`` kwargs).
    ``address``: a running cluster to join; ``None`` starts a new local instance with ``num_cpus`` CPUs."""
    import ray
    from ray.tune.registry import register_env

    started = not ray.is_initialized()
    if started and address is None:
        # "local": a new instance even where a `ray start` cluster is up (ray.init(num_cpus=...) would try to
        # join that cluster and fail: a cluster's CPUs are not set by the driver)
        ray.init(address="local", num_cpus=num_cpus, include_dashboard=False, log_to_driver=False)
    elif started:
        ray.init(address=address, log_to_driver=False)
    register_env(ENV_NAME, rllib_env)
    algo = build_config(scenario, **kwargs).build_algo()
    try:
        results = [algo.train() for _ in range(iterations)]
    finally:
        algo.stop()
        if started:
            ray.shutdown()
    return results


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="paper_vo_0")
    parser.add_argument("--iterations", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--num-cpus", type=int, default=1, help="CPUs of the local Ray instance (no --address)")
    parser.add_argument("--address", default=None, help="a running Ray cluster to join: auto or HOST:PORT")
    parser.add_argument("--env-runners", type=int, default=0, help="remote env runners (0: sample in this process)")
    parser.add_argument("--reward-scale", type=float, default=0.01, help="factor on every reward (docs/clients.md)")
    args = parser.parse_args()
    results = main(args.scenario, iterations=args.iterations, num_cpus=args.num_cpus, address=args.address,
                   seed=args.seed, env_runners=args.env_runners, reward_scale=args.reward_scale)
    for i, res in enumerate(results):
        runners, learner = res["env_runners"], res["learners"][SHARED]
        print(f"iter {i}: env steps {runners['num_env_steps_sampled']}, "
              f"episode return {runners.get('episode_return_mean', float('nan')):.2f}, "
              f"total loss {learner['total_loss']:.3f}")
