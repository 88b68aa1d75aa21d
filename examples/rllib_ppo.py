"""swarm-env in RLlib (new API stack): PPO with one policy shared by every follower.

Run (after the heavy extra, see docs/clients.md)::

    python examples/rllib_ppo.py                              # paper_vo_0, 5 iterations
    python examples/rllib_ppo.py --scenario random --iterations 20

``ray.rllib.env.wrappers.pettingzoo_env.ParallelPettingZooEnv`` turns the ParallelEnv into an
RLlib ``MultiAgentEnv``; every agent id maps to the module ``"shared"``. The wrapper reads the
agent ids from one ``reset()`` when it is built, so the team must not change between episodes:
swarm-env's fixed teams (``env.agents == env.possible_agents`` after every reset) satisfy that.
Everything runs in this process (``num_env_runners=0``, ``num_learners=0``) on ``num_cpus``
Ray CPUs.
"""

from __future__ import annotations

import argparse
from typing import Any

import swarm_env

ENV_NAME = "swarm_env"
SHARED = "shared"


def env_creator(config: dict) -> Any:
    """RLlib env creator: ``config`` holds ``scenario`` and any ``swarm_env.parallel_env`` kwargs."""
    from ray.rllib.env.wrappers.pettingzoo_env import ParallelPettingZooEnv

    kwargs = dict(config)
    scenario = kwargs.pop("scenario", "paper_vo_0")
    return ParallelPettingZooEnv(swarm_env.parallel_env(scenario, **kwargs))


def build_config(
    scenario: str = "paper_vo_0",
    train_batch_size: int = 2000,
    minibatch_size: int = 250,
    num_epochs: int = 5,
    rollout_fragment_length: int | str = "auto",
    seed: int = 0,
    **env_kwargs: Any,
):
    from ray.rllib.algorithms.ppo import PPOConfig
    from ray.rllib.core.rl_module.multi_rl_module import MultiRLModuleSpec
    from ray.rllib.core.rl_module.rl_module import RLModuleSpec

    return (
        PPOConfig()
        .environment(ENV_NAME, env_config={"scenario": scenario, **env_kwargs})
        .framework("torch")
        .env_runners(num_env_runners=0, rollout_fragment_length=rollout_fragment_length)
        .learners(num_learners=0)
        .multi_agent(policies={SHARED}, policy_mapping_fn=lambda agent_id, episode, **kw: SHARED)
        .rl_module(rl_module_spec=MultiRLModuleSpec(rl_module_specs={SHARED: RLModuleSpec()}))
        .training(train_batch_size_per_learner=train_batch_size, minibatch_size=minibatch_size, num_epochs=num_epochs)
        .debugging(seed=seed)
    )


def main(scenario: str = "paper_vo_0", iterations: int = 5, num_cpus: int = 1, **kwargs: Any) -> list[dict]:
    """Train ``iterations`` PPO iterations and return their result dicts (``kwargs`` go to
    :func:`build_config`: batch sizes, ``seed`` and ``swarm_env.parallel_env`` kwargs)."""
    import ray
    from ray.tune.registry import register_env

    started = not ray.is_initialized()
    if started:
        ray.init(num_cpus=num_cpus, include_dashboard=False, log_to_driver=False)
    register_env(ENV_NAME, env_creator)
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
    args = parser.parse_args()
    for i, res in enumerate(main(args.scenario, iterations=args.iterations, seed=args.seed)):
        runners, learner = res["env_runners"], res["learners"][SHARED]
        print(f"iter {i}: env steps {runners['num_env_steps_sampled']}, "
              f"episode return {runners.get('episode_return_mean', float('nan')):.2f}, "
              f"total loss {learner['total_loss']:.3f}")
