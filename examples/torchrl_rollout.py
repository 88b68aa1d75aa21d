"""swarm-env in TorchRL: wrap the ParallelEnv, check its specs, roll out a random policy.

Run (after ``pip install -e '.[dev]'``, which brings torchrl)::

    python examples/torchrl_rollout.py                       # paper_vo_0, 200 steps
    python examples/torchrl_rollout.py --scenario random --steps 100

``torchrl.envs.PettingZooWrapper`` groups the agents by name prefix: all followers land in
one group ``"follower"``, so every per-agent tensor has shape ``(steps, n_followers, ...)``.
``return_state=True`` adds the global ``state`` (``env.state()``) for centralised critics, and
the keys of the env's reset infos become ``("follower", "info", key)`` entries (TorchRL builds
its info spec from the infos of the first reset).
"""

from __future__ import annotations

import argparse
from typing import Any

import swarm_env


def make_env(scenario: str = "paper_vo_0", seed: int = 0, **env_kwargs: Any):
    """A TorchRL ``PettingZooWrapper`` around ``swarm_env.parallel_env(scenario, **env_kwargs)``."""
    from torchrl.envs import PettingZooWrapper

    return PettingZooWrapper(swarm_env.parallel_env(scenario, **env_kwargs), return_state=True, seed=seed)


def main(scenario: str = "paper_vo_0", steps: int = 200, seed: int = 0, check_specs: bool = True, **env_kwargs: Any):
    """Roll out ``steps`` random steps (reset on episode end) and return the TensorDict."""
    import torch
    from torchrl.envs.utils import check_env_specs

    env = make_env(scenario, seed=seed, **env_kwargs)
    if check_specs:
        check_env_specs(env)  # a short rollout, compared against the env's specs
    torch.manual_seed(seed)
    rollout = env.rollout(steps, break_when_any_done=False)  # no policy: random actions from the spec
    env.close()
    return rollout


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="paper_vo_0")
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    td = main(args.scenario, steps=args.steps, seed=args.seed)
    reward = td["next", "follower", "reward"]
    print(td)
    print(f"{args.scenario}: {td.batch_size[0]} steps x {reward.shape[1]} followers, "
          f"mean reward {reward.mean().item():.3f}, episodes ended: {int(td['next', 'done'].sum())}")
