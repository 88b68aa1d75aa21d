"""DAgger: distil a privileged expert into an observation-only actor (the PPO warm start).

:func:`dagger` trains an actor network (an MLP from one follower's observation to its
normalised twist) in rounds. Round 0: the expert drives ``episodes`` episodes and labels
every follower-step with its own action; later rounds: the *student* drives (its mean action)
and the expert labels the states the student visits (Ross et al. 2011), so the student learns
to recover from its own mistakes. After each round the student is fitted to all labels so far
(mean squared error, Adam). The observation statistics come from round 0 and stay fixed.

:mod:`swarm_env_baselines.mappo` uses it to warm-start PPO (``--pretrain vo``): a few minutes of DAgger
teach the network to hold its slot, which PPO from scratch needs millions of steps for. It
does not teach avoidance: a DAgger student of ``vo`` has about as many collisions as ``pursuit``
(docs/baselines.md, "What was tried toward the unshielded target"), because the
velocity-obstacle choice is a discontinuous function of the state that flips between sides
from one step to the next; PPO and the safety layer have to add the avoidance.

Worlds: round ``r`` plays seeds ``first_seed + r * episodes ... + episodes - 1`` of the
scenario (the mappo trainer passes seeds from 10000 up: disjoint from validation 500-549 and
test 1000-1049).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from swarm_env.harness.policies import load_policy
from swarm_env_baselines.ppo_core import RunningMeanStd


@dataclass(frozen=True)
class DaggerSettings:
    """One DAgger warm start: ``rounds`` rounds of ``episodes`` episodes (round 0 driven by the
    expert), each followed by ``epochs`` epochs of fitting on every label so far."""

    expert: str = "vo"
    rounds: int = 5
    episodes: int = 25
    epochs: int = 10
    learning_rate: float = 1e-3
    batch_size: int = 512
    first_seed: int = 10_000


def rollouts(env: Any, expert: Any, seeds: list[int], student: Any | None) -> tuple[np.ndarray, np.ndarray]:
    """Play one episode per seed: the expert drives when ``student`` is ``None``, else the student
    (a callable from stacked observations ``(N, D)`` to actions ``(N, 2)``). Returns every visited
    follower observation and the expert's action for it: ``(obs (T, D), labels (T, 2))``."""
    agents = list(env.possible_agents)
    xs: list[np.ndarray] = []
    ys: list[np.ndarray] = []
    for seed in seeds:
        obs, _ = env.reset(seed=seed)
        expert.reset(env, seed)
        while env.agents:
            o = np.stack([obs[a] for a in agents])
            labels = expert.act(obs, env.world_state())
            y = np.stack([np.asarray(labels[a], dtype=np.float32) for a in agents])
            xs.append(o)
            ys.append(y)
            act = y if student is None else student(o)
            obs, *_ = env.step({a: act[i] for i, a in enumerate(agents)})
    return np.concatenate(xs), np.concatenate(ys)


def fit(actor: Any, obs_rms: RunningMeanStd, obs: np.ndarray, labels: np.ndarray, settings: DaggerSettings,
        generator: Any) -> float:
    """``settings.epochs`` epochs of MSE regression of ``actor`` on ``(obs, labels)``; the last epoch's mean loss."""
    import torch

    x = torch.as_tensor(obs_rms.normalize(obs))
    y = torch.as_tensor(labels)
    optim = torch.optim.Adam(actor.parameters(), lr=settings.learning_rate)
    n = len(x)
    mean_loss = 0.0
    for _ in range(settings.epochs):
        order = torch.randperm(n, generator=generator)
        total = 0.0
        for start in range(0, n, settings.batch_size):
            idx = order[start:start + settings.batch_size]
            loss = (actor(x[idx]) - y[idx]).pow(2).sum(-1).mean()
            optim.zero_grad()
            loss.backward()
            optim.step()
            total += loss.item() * len(idx)
        mean_loss = total / n
    return mean_loss


def dagger(env: Any, actor: Any, obs_rms: RunningMeanStd, settings: DaggerSettings, generator: Any,
           progress: bool = False) -> list[dict[str, float]]:
    """Train ``actor`` in place by DAgger on ``env`` and set ``obs_rms`` from round 0 (then frozen).

    Returns one log row per round: samples so far, final loss, rollout and fit seconds.
    """
    import torch


    expert = load_policy(settings.expert, env)

    def student(o: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return np.clip(actor(torch.as_tensor(obs_rms.normalize(o))).numpy(), -1.0, 1.0)

    log: list[dict[str, float]] = []
    xs: list[np.ndarray] = []
    ys: list[np.ndarray] = []
    for r in range(settings.rounds):
        t0 = time.perf_counter()
        first = settings.first_seed + r * settings.episodes
        x, y = rollouts(env, expert, list(range(first, first + settings.episodes)), None if r == 0 else student)
        if r == 0:
            obs_rms.update(x)
            obs_rms.frozen = True
        xs.append(x)
        ys.append(y)
        t1 = time.perf_counter()
        loss = fit(actor, obs_rms, np.concatenate(xs), np.concatenate(ys), settings, generator)
        log.append({"round": r, "samples": int(sum(len(a) for a in xs)), "loss": loss,
                    "rollout_s": round(t1 - t0, 1), "fit_s": round(time.perf_counter() - t1, 1)})
        if progress:
            print(f"dagger round {r}: {log[-1]['samples']} samples, loss {loss:.4f}", flush=True)
    return log
