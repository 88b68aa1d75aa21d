"""The critics of :mod:`swarm_env_baselines.mappo` (the actor is :func:`~swarm_env_baselines.ppo_core.mlp`).

Both take ``(state, obs)`` with ``state`` ``(..., S)`` (one row per world-step) and ``obs``
``(..., N, D)`` (the world's ``N`` followers) and return values ``(..., N)``, so a rollout keeps one
global state per world-step instead of ``N`` copies of it.
"""

from __future__ import annotations

import torch
from torch import nn

from swarm_env_baselines.ppo_core import mlp

__all__ = ["CentralCritic", "LocalCritic", "make_critic"]


class CentralCritic(nn.Module):
    """MAPPO's critic: an MLP of the agent-specific global state ``[state; obs_i]`` (Yu et al. 2022).

    The first layer is written as ``W_s state + W_o obs_i + b``, the same function as a linear layer of
    the concatenation, computed once per world-step for the state part (about 330 of the ~380 inputs
    with 4 followers) and broadcast to the followers: with ``N`` followers the first layer costs about
    ``1/N`` of the concatenated one's."""

    def __init__(self, state_dim: int, obs_dim: int, hidden: tuple[int, ...]) -> None:
        super().__init__()
        self.state_in = nn.Linear(state_dim, hidden[0])
        self.obs_in = nn.Linear(obs_dim, hidden[0], bias=False)
        self.body = nn.Sequential(nn.Tanh(), mlp([*hidden, 1]))

    def forward(self, state: torch.Tensor, obs: torch.Tensor) -> torch.Tensor:
        return self.body(self.state_in(state).unsqueeze(-2) + self.obs_in(obs)).squeeze(-1)


class LocalCritic(nn.Module):
    """IPPO's critic: an MLP of the follower's own observation (the state is ignored)."""

    def __init__(self, obs_dim: int, hidden: tuple[int, ...]) -> None:
        super().__init__()
        self.net = mlp([obs_dim, *hidden, 1])

    def forward(self, state: torch.Tensor, obs: torch.Tensor) -> torch.Tensor:
        return self.net(obs).squeeze(-1)


def make_critic(state_dim: int, obs_dim: int, hidden: tuple[int, ...]) -> nn.Module:
    """A :class:`CentralCritic` when ``state_dim`` > 0, else a :class:`LocalCritic`."""
    return CentralCritic(state_dim, obs_dim, hidden) if state_dim else LocalCritic(obs_dim, hidden)
