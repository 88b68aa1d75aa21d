"""swarm-env through SuperSuit into stable-baselines3: one PPO policy shared by every follower.

Run (after ``pip install -e '.[dev,rl]'``, which brings supersuit and stable-baselines3)::

    python examples/supersuit_sb3.py                                   # paper_vo_0, 20k steps
    python examples/supersuit_sb3.py --scenario random --total-timesteps 50000

``supersuit.pettingzoo_env_to_vec_env_v1`` turns the ParallelEnv into a vector env with one
slot per agent; ``concat_vec_envs_v1`` stacks ``copies`` of it into an SB3 ``VecEnv`` of
``copies * n_followers`` slots, so SB3's PPO trains a single (parameter-shared) policy on every
follower's experience. SuperSuit needs every agent to act in every step (no agent may leave
early): swarm-env's fixed teams satisfy that. This repository's own bridge,
``swarm_env_baselines.vec_env.SwarmVecEnv``, does the same for ``swarm-env train sb3``.

Rewards are scaled by ``--reward-scale`` (default 0.01, :class:`swarm_env.wrappers.RewardScale`): a
follower's per-step reward of about -1 to -20 gives discounted returns in the hundreds, which leave SB3's
explained variance near 0 for tens of thousands of steps (docs/clients.md, "Reward scale").
"""

from __future__ import annotations

import argparse
from typing import Any

import swarm_env
from swarm_env.wrappers import RewardScale


def make_vec_env(scenario: str = "paper_vo_0", copies: int = 2, num_cpus: int = 0, reward_scale: float = 0.01,
                 **env_kwargs: Any):
    """An SB3 ``VecEnv`` of ``copies`` envs x their followers, rewards multiplied by ``reward_scale``."""
    import supersuit as ss

    env = RewardScale(swarm_env.parallel_env(scenario, **env_kwargs), reward_scale)
    vec = ss.pettingzoo_env_to_vec_env_v1(env)
    return ss.concat_vec_envs_v1(vec, copies, num_cpus=num_cpus, base_class="stable_baselines3")


def main(
    scenario: str = "paper_vo_0",
    total_timesteps: int = 20_000,
    copies: int = 2,
    n_steps: int = 256,
    batch_size: int = 256,
    n_epochs: int = 4,
    seed: int = 0,
    num_cpus: int = 0,
    reward_scale: float = 0.01,
    **env_kwargs: Any,
):
    """Train PPO for ``total_timesteps`` agent-steps and return the model (its env attached)."""
    from stable_baselines3 import PPO
    from stable_baselines3.common.utils import set_random_seed

    vec = make_vec_env(scenario, copies=copies, num_cpus=num_cpus, reward_scale=reward_scale, **env_kwargs)
    # SuperSuit's ConcatVecEnv has no seed(), which SB3's VecEnv.seed() and PPO(seed=...) call:
    # seed python/numpy/torch here and the env copies (seed, seed + 1, ...) through a seeded reset.
    set_random_seed(seed)
    vec.venv.reset(seed=seed)
    model = PPO("MlpPolicy", vec, n_steps=n_steps, batch_size=batch_size, n_epochs=n_epochs, device="cpu", verbose=0)
    model.learn(total_timesteps=total_timesteps)
    return model


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="paper_vo_0")
    parser.add_argument("--total-timesteps", type=int, default=20_000)
    parser.add_argument("--copies", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--reward-scale", type=float, default=0.01, help="factor on every reward (docs/clients.md)")
    args = parser.parse_args()
    model = main(args.scenario, total_timesteps=args.total_timesteps, copies=args.copies, seed=args.seed,
                 reward_scale=args.reward_scale)
    print(f"{args.scenario}: PPO trained {model.num_timesteps} agent-steps on {model.get_env().num_envs} slots")
    model.get_env().close()
