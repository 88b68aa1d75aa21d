"""The numerical pieces of PPO shared by :mod:`swarm_env_baselines.mappo` and :mod:`swarm_env_baselines.imitation`.

Running statistics (observation and return normalisation), generalised advantage estimation,
the MLPs, and the clipped PPO loss. Nothing here touches an env.
"""

from __future__ import annotations

from typing import Any

import numpy as np


class RunningMeanStd:
    """Running mean and variance of batches (Chan et al.'s parallel update), in float64.

    :meth:`normalize` returns ``clip((x - mean) / sqrt(var + epsilon), -clip, clip)`` as float32.
    ``frozen`` statistics ignore :meth:`update` (a policy warm-started by imitation keeps the
    statistics its network was fitted with).
    """

    def __init__(self, shape: tuple[int, ...], epsilon: float = 1e-8, clip: float = 10.0) -> None:
        self.mean = np.zeros(shape)
        self.var = np.ones(shape)
        self.count = 1e-4
        self.epsilon = epsilon
        self.clip = clip
        self.frozen = False

    def update(self, batch: np.ndarray) -> None:
        if self.frozen:
            return
        x = np.asarray(batch, dtype=np.float64).reshape(-1, *self.mean.shape)
        b_mean, b_var, n = x.mean(axis=0), x.var(axis=0), x.shape[0]
        delta = b_mean - self.mean
        total = self.count + n
        self.mean = self.mean + delta * n / total
        self.var = (self.var * self.count + b_var * n + delta**2 * self.count * n / total) / total
        self.count = total

    def normalize(self, x: np.ndarray) -> np.ndarray:
        return np.clip((x - self.mean) / np.sqrt(self.var + self.epsilon), -self.clip, self.clip).astype(np.float32)

    def to_json(self) -> dict[str, Any]:
        return {"mean": self.mean.tolist(), "var": self.var.tolist(), "count": self.count, "epsilon": self.epsilon,
                "clip": self.clip}

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> RunningMeanStd:
        mean = np.asarray(d["mean"], dtype=np.float64)
        var = np.asarray(d["var"], dtype=np.float64)
        if mean.shape != var.shape or not (np.isfinite(mean).all() and np.isfinite(var).all() and (var >= 0).all()):
            raise ValueError("normalisation statistics: mean and var must be finite arrays of one shape, var >= 0")
        rms = cls(mean.shape, float(d["epsilon"]), float(d["clip"]))
        rms.mean, rms.var, rms.count = mean, var, float(d["count"])
        return rms

    def copy(self) -> RunningMeanStd:
        return RunningMeanStd.from_json(self.to_json())


def mlp(sizes: list[int]) -> Any:
    """``Linear -> Tanh -> ... -> Linear`` through ``sizes`` (no activation after the last layer)."""
    import torch.nn as nn

    layers: list[Any] = []
    for i in range(len(sizes) - 1):
        layers.append(nn.Linear(sizes[i], sizes[i + 1]))
        if i < len(sizes) - 2:
            layers.append(nn.Tanh())
    return nn.Sequential(*layers)


def gae(rewards: np.ndarray, values: np.ndarray, dones: np.ndarray, last_values: np.ndarray, gamma: float, lam: float) -> np.ndarray:
    """Generalised advantage estimates ``(T, B)``.

    ``rewards``, ``values``, ``dones`` are ``(T, B)``: ``dones[t]`` means the episode ended
    after step ``t`` (a truncated episode's bootstrap is already folded into its last
    reward), ``last_values`` ``(B,)`` the values after the last step.
    """
    T = len(rewards)
    adv = np.zeros_like(rewards, dtype=np.float64)
    last = np.zeros(rewards.shape[1])
    for t in reversed(range(T)):
        next_value = last_values if t == T - 1 else values[t + 1]
        live = 1.0 - dones[t]
        delta = rewards[t] + gamma * next_value * live - values[t]
        last = delta + gamma * lam * live * last
        adv[t] = last
    return adv


def ppo_policy_loss(logp: Any, old_logp: Any, advantages: Any, clip_range: float) -> tuple[Any, Any]:
    """The clipped surrogate loss (to minimise) on one minibatch, with advantages normalised
    within it, and the probability ratios (detached) for the diagnostics of :func:`ratio_stats`."""
    import torch

    ratio = (logp - old_logp).exp()
    a = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
    loss = -torch.min(ratio * a, ratio.clamp(1 - clip_range, 1 + clip_range) * a).mean()
    return loss, ratio.detach()


def ratio_stats(ratio: Any, clip_range: float) -> tuple[float, float, float]:
    """``(max |ratio - 1|, approximate KL, clip fraction)`` of a minibatch's probability ratios.

    The KL is Schulman's unbiased low-variance estimator ``E[(r - 1) - log r]`` of KL(old || new);
    the clip fraction is the share of samples whose ratio left ``[1 - clip, 1 + clip]``."""
    dev = ratio - 1.0
    return float(dev.abs().max()), float((dev - ratio.log()).mean()), float((dev.abs() > clip_range).float().mean())


def explained_variance(values: np.ndarray, returns: np.ndarray) -> float:
    """``1 - Var(returns - values) / Var(returns)`` (NaN when the returns do not vary): 1 is a perfect
    critic, 0 one no better than the mean, negative one worse."""
    var = float(np.var(returns))
    return float("nan") if var == 0.0 else 1.0 - float(np.var(returns - values)) / var

