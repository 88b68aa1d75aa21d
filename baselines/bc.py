"""Behaviour cloning (and DAgger) from a scripted expert into PPO's own policy network.

.. code-block:: console

    swarm-env bc --expert vo --scenario random --train-seeds 0-199 --out runs/bc_vo [--seed 0] \\
        [--epochs N] [--dagger-iters K --dagger-seeds 300-499] [--env KEY=VALUE ...]

What it does, top to bottom (:func:`train_bc`):

1. **Demonstrations** of ``expert`` on the training seeds, from the cache of
   :mod:`swarm_env_baselines.demos` (recorded on first use).
2. **Split by episode**: a seeded ``val_fraction`` of the demo *episodes* (not
   transitions: consecutive steps are nearly identical, so a transition split
   would leak) is held out for validation.
3. **The network**: ``PPO("MlpPolicy", VecNormalize(make_vec_env(scenario, 1)),
   policy_kwargs=policy_kwargs(net_arch), seed=seed)``, exactly what
   ``swarm-env train sb3`` builds, so the result is a warm start for PPO
   (``--init-from``) and loads as ``bc:OUT`` / ``ppo:OUT``.
4. **Normalisation statistics from the demos**: the ``VecNormalize``'s
   ``obs_rms`` (mean, variance, count) is set from the training observations;
   a feature that is constant in the demos keeps variance 1 (it is only
   centred) instead of being blown up by ``1 / sqrt(1e-8)`` the first time it
   changes. ``ret_rms`` is set the way ``VecNormalize`` would have computed it
   while the expert played: from the running discounted returns
   ``R_t = gamma R_{t-1} + r_t`` of every agent-episode.
5. **Loss**: the negative log-likelihood of the expert's actions under the
   policy's action distribution (``policy.evaluate_actions`` on normalised
   observations), plus ``value_coef`` times the squared error of the value head
   against the discounted return (``gamma``) of the *normalised* rewards
   ``clip(r / sqrt(ret_rms.var), +-10)``, per agent-episode, i.e. in the units
   PPO's critic trains in, so fine-tuning does not start with a random critic.
   Truncated episodes are not bootstrapped: their target is just the
   discounted sum of the rewards that were seen (a small bias near the time
   limit). Adam, shuffled minibatches, ``epochs`` passes. The Gaussian's
   state-independent ``log_std`` is learned too but kept at or above
   ``log(min_std)``: the expert is deterministic, so the likelihood alone would
   shrink it to nothing and leave PPO no exploration.
6. **DAgger** (``dagger_iters > 0``): each iteration plays the current policy
   (deterministic; with probability ``dagger_beta`` per agent per step the
   expert's action is executed instead) on its share of ``dagger_seeds``
   (which must be disjoint from the training seeds), while the expert is
   ``reset(env, seed)`` per episode and asked for its action on every step
   (its internal state stays that of an expert watching this episode). Every
   visited observation is labelled with the expert's action; the labelled
   transitions join the training set (never the validation set) and training
   continues for ``dagger_epochs`` epochs. The normalisation statistics stay
   those of the expert demos. The value targets of DAgger transitions are the
   returns of the executed (learner) behaviour. The default of 8 iterations
   cut collisions against plain cloning at the same formation error, for
   about six times the training time (measurements: docs/baselines.md,
   "Behaviour cloning: why 8 DAgger iterations").
7. **Validation rollouts** (``eval_seeds``, default 500-509): after BC and
   after each DAgger iteration the policy plays those seeds through
   :func:`swarm_env.harness.episode.run_episode`; ``eval.csv`` has one row per stage.

Outputs in ``out``: ``policy.safetensors`` + ``policy.json`` (what ``bc:OUT`` loads, no pickle)
and SB3's ``model.zip`` + ``vecnormalize.pkl`` (:func:`swarm_env_baselines.model_io.save_model`), ``bc_config.json`` (the config, the
demo file and its key, package versions), ``bc_log.csv`` (per epoch: train NLL,
validation NLL, validation action MSE of the deterministic action, value
losses, the policy's std; epoch 0 is the untrained network), ``eval.csv``,
``learning_curve.png`` and ``summary.json`` (sizes and timings).

Determinism: the network is initialised by SB3's ``set_random_seed(seed)``,
the split and the minibatch order come from ``np.random.default_rng(seed)``;
the same seed and demos give identical weights (with the same torch thread
count, ``torch_threads``).
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import math
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from swarm_env.checks import DefaultsHelpFormatter
from swarm_env.env import SwarmEnv
from swarm_env.harness.episode import run_episode
from swarm_env.harness.evaluation import summarize
from swarm_env.harness.policies import PolicyError, UnknownPolicyError, load_policy
from swarm_env.jsonio import write_json
from swarm_env_baselines.config import NET_ARCH, add_dataclass_options, parse_seeds, policy_kwargs
from swarm_env_baselines.demos import Demos, _stack, append_step, episode_arrays, generate_demos, load_demos
from swarm_env_baselines.model_io import SB3Policy, save_model
from swarm_env_baselines.options import package_versions
from swarm_env_baselines.run_log import can_plot

if TYPE_CHECKING:
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecNormalize

LOG_COLUMNS = ("stage", "epoch", "n_train", "train_nll", "val_nll", "val_action_mse", "train_value_loss", "val_value_loss", "std")
EVAL_COLUMNS = ("stage", "n_train", "episodes", "success_rate", "collision_free_rate", "collisions", "collisions_ci95", "formation_error", "formation_error_ci95")


@dataclass
class BCConfig:
    """Everything that defines a behaviour-cloning run; every field is a CLI option (see the module docstring)."""

    #: Expert policy spec to imitate: vo, cbs_rrt, or NAME:ARG.
    expert: str = "vo"
    #: Built-in scenario name, a YAML path, or "random".
    scenario: str = "random"
    #: SwarmEnv keyword arguments / random-generator knobs as KEY=VALUE (YAML values), e.g. n_followers=4.
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    #: Seeds of the demonstration episodes, e.g. 0-199.
    train_seeds: str = "0-199"
    #: Output directory (policy.safetensors + policy.json, model.zip, vecnormalize.pkl, logs, plot).
    out: str = "runs/bc"
    #: Seed of the network initialisation, the episode split and the minibatch order.
    seed: int = 0
    #: Hidden layer sizes of the actor and critic MLPs (must match the PPO run it warm-starts).
    net_arch: tuple[int, ...] = NET_ARCH
    #: Passes over the demonstrations.
    epochs: int = 20
    #: Minibatch size (transitions).
    batch_size: int = 512
    #: Adam learning rate.
    learning_rate: float = 1e-3
    #: Share of the demo episodes held out for validation.
    val_fraction: float = 0.1
    #: Weight of the value-head loss (0 = leave the critic untrained).
    value_coef: float = 0.5
    #: Discount of the value targets and of the reward-normalisation statistics (use PPO's).
    gamma: float = 0.99
    #: Lower bound of the policy's action std (the learned log_std is clamped at log(min_std)).
    min_std: float = 0.1
    #: DAgger iterations after BC (0 = plain behaviour cloning; 8 measured better: docs/baselines.md).
    dagger_iters: int = 8
    #: Seeds of the DAgger rollouts, split evenly over the iterations; disjoint from train_seeds.
    dagger_seeds: str = "300-499"
    #: Probability that the expert's action is executed instead of the learner's (per agent per step).
    dagger_beta: float = 0.0
    #: Training epochs after each DAgger iteration (on all data so far).
    dagger_epochs: int = 5
    #: Validation rollout seeds on the scenario after BC and after each DAgger iteration ("" = none).
    eval_seeds: str = "500-509"
    #: Directory of the demonstration cache.
    cache_dir: str = "demos"
    #: Worker processes for recording demonstrations.
    workers: int = 1
    #: Torch threads (results are reproducible for a fixed count).
    torch_threads: int = 1
    #: Show progress bars.
    progress: bool = True

    def __post_init__(self) -> None:
        for name in ("epochs", "batch_size", "workers", "torch_threads"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        for name in ("dagger_iters", "dagger_epochs"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise ValueError(f"{name} must be a non-negative integer, got {value!r}")
        if not 0.0 <= self.val_fraction < 1.0:
            raise ValueError(f"val_fraction must be in [0, 1), got {self.val_fraction!r}")
        if not 0.0 <= self.dagger_beta <= 1.0:
            raise ValueError(f"dagger_beta must be in [0, 1], got {self.dagger_beta!r}")
        if not 0.0 < self.gamma <= 1.0:
            raise ValueError(f"gamma must be in (0, 1], got {self.gamma!r}")
        if not (self.learning_rate > 0 and self.min_std > 0 and self.value_coef >= 0):
            raise ValueError("learning_rate and min_std must be positive and value_coef non-negative")
        self.net_arch = tuple(int(n) for n in self.net_arch)
        train = set(parse_seeds(self.train_seeds))
        if self.dagger_iters:
            dagger = parse_seeds(self.dagger_seeds)
            overlap = sorted(train & set(dagger))
            if overlap:
                raise ValueError(f"dagger_seeds must be disjoint from train_seeds; both contain {overlap[:5]}")
            if len(dagger) < self.dagger_iters:
                raise ValueError(f"dagger_seeds has {len(dagger)} seeds for {self.dagger_iters} iterations: need at least one each")
        if self.eval_seeds:
            parse_seeds(self.eval_seeds)


# --------------------------------------------------------------------------- data


def split_episodes(n_episodes: int, val_fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Seeded split of episode ids ``0..n-1`` into (train, validation); at least one of each when n >= 2."""
    if n_episodes < 1:
        raise ValueError("no demonstration episodes")
    ids = np.random.default_rng(seed).permutation(n_episodes)
    n_val = int(round(val_fraction * n_episodes))
    if val_fraction > 0 and n_episodes >= 2:
        n_val = min(max(n_val, 1), n_episodes - 1)
    return np.sort(ids[n_val:]), np.sort(ids[:n_val])


def discounted_returns(rewards: np.ndarray, dones: np.ndarray, gamma: float) -> np.ndarray:
    """``G_t = r_t + gamma G_{t+1}`` within each block that ``dones`` closes (no bootstrap after it)."""
    out = np.zeros(len(rewards), dtype=np.float64)
    acc = 0.0
    for t in range(len(rewards) - 1, -1, -1):
        if dones[t]:
            acc = 0.0
        acc = float(rewards[t]) + gamma * acc
        out[t] = acc
    return out


def running_returns(rewards: np.ndarray, dones: np.ndarray, gamma: float) -> np.ndarray:
    """``R_t = gamma R_{t-1} + r_t``, restarted after each ``done``: what ``VecNormalize`` feeds ``ret_rms``."""
    out = np.zeros(len(rewards), dtype=np.float64)
    acc = 0.0
    for t in range(len(rewards)):
        acc = gamma * acc + float(rewards[t])
        out[t] = acc
        if dones[t]:
            acc = 0.0
    return out


def fit_normalization(vecnorm: VecNormalize, demos: Demos, gamma: float) -> None:
    """Set ``vecnorm.obs_rms`` and ``ret_rms`` from demonstrations (see the module docstring, step 4)."""
    obs = demos.obs.astype(np.float64)
    var = obs.var(axis=0)
    var[var < 1e-8] = 1.0  # constant in the demos: centre it, do not divide by ~0
    vecnorm.obs_rms.mean = obs.mean(axis=0)
    vecnorm.obs_rms.var = var
    vecnorm.obs_rms.count = float(len(obs))
    ret = running_returns(demos.rewards, demos.dones, gamma)
    vecnorm.ret_rms.mean = np.float64(ret.mean())
    vecnorm.ret_rms.var = np.float64(max(ret.var(), 1e-8))
    vecnorm.ret_rms.count = float(len(ret))


@dataclass
class _Tensors:
    """A demonstration set ready for the network: normalised observations, actions, value targets."""

    obs: torch.Tensor
    actions: torch.Tensor
    targets: torch.Tensor

    def __len__(self) -> int:
        return int(self.obs.shape[0])


def _tensors(demos: Demos, vecnorm: VecNormalize, gamma: float) -> _Tensors:
    import torch

    obs = vecnorm.normalize_obs(demos.obs)
    rewards = vecnorm.normalize_reward(demos.rewards.astype(np.float64))
    targets = discounted_returns(rewards, demos.dones, gamma)
    if np.issubdtype(demos.actions.dtype, np.integer):
        actions = torch.as_tensor(demos.actions, dtype=torch.long)
    else:  # the env clips continuous actions to [-1, 1]: that is the action the expert took
        actions = torch.as_tensor(np.clip(demos.actions, -1.0, 1.0), dtype=torch.float32)
    return _Tensors(torch.as_tensor(obs, dtype=torch.float32), actions, torch.as_tensor(targets, dtype=torch.float32))


# --------------------------------------------------------------------------- model


def make_bc_model(scenario: str, env_kwargs: dict[str, Any], net_arch: Sequence[int], seed: int, gamma: float = 0.99) -> tuple[PPO, VecNormalize]:
    """The PPO model (CPU) and the VecNormalize wrapper that ``swarm_env_baselines.train`` would build for this env."""
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecNormalize

    from swarm_env_baselines.vec_env import make_vec_env

    venv = make_vec_env(scenario, 1, **env_kwargs)
    vecnorm = VecNormalize(venv, norm_obs=True, norm_reward=True, gamma=gamma)
    model = PPO("MlpPolicy", vecnorm, policy_kwargs=policy_kwargs(tuple(net_arch), "bc"), gamma=gamma, seed=seed, device="cpu", verbose=0)
    return model, vecnorm


class BCTrainer:
    """Adam on ``model.policy``: NLL of expert actions + ``value_coef`` x value MSE (see the module docstring)."""

    def __init__(self, model: PPO, *, learning_rate: float, batch_size: int, value_coef: float, min_std: float, seed: int) -> None:
        import torch

        self.model = model
        self.policy = model.policy
        self.batch_size = batch_size
        self.value_coef = value_coef
        self.log_std_min = math.log(min_std)
        self.optimizer = torch.optim.Adam(self.policy.parameters(), lr=learning_rate)
        self.rng = np.random.default_rng(seed)
        self._clamp_log_std()
        low, high = getattr(model.action_space, "low", None), getattr(model.action_space, "high", None)
        self._bounds = None if low is None else (torch.as_tensor(low), torch.as_tensor(high))

    def _clamp_log_std(self) -> None:
        import torch

        log_std = getattr(self.policy, "log_std", None)
        if log_std is not None:
            with torch.no_grad():
                log_std.clamp_(min=self.log_std_min)

    def std(self) -> float:
        log_std = getattr(self.policy, "log_std", None)
        return float("nan") if log_std is None else float(log_std.detach().exp().mean())

    def train_epoch(self, data: _Tensors) -> tuple[float, float]:
        """One shuffled pass; mean (NLL, value loss) over the minibatches."""
        import torch

        self.policy.set_training_mode(True)
        order = torch.as_tensor(self.rng.permutation(len(data)))
        nll_sum = value_sum = 0.0
        batches = 0
        for start in range(0, len(data), self.batch_size):
            idx = order[start : start + self.batch_size]
            values, log_prob, _ = self.policy.evaluate_actions(data.obs[idx], data.actions[idx])
            nll = -log_prob.mean()
            value_loss = torch.nn.functional.mse_loss(values.flatten(), data.targets[idx])
            loss = nll + self.value_coef * value_loss
            self.optimizer.zero_grad()
            loss.backward()
            self.optimizer.step()
            self._clamp_log_std()
            nll_sum += nll.item()
            value_sum += value_loss.item()
            batches += 1
        return nll_sum / max(batches, 1), value_sum / max(batches, 1)

    def evaluate(self, data: _Tensors, chunk: int = 16384) -> dict[str, float]:
        """Mean NLL, action MSE of the deterministic (clipped) action, value MSE on ``data``."""
        import torch

        if len(data) == 0:
            return {"nll": float("nan"), "action_mse": float("nan"), "value_loss": float("nan")}
        self.policy.set_training_mode(False)
        nll = mse = vloss = 0.0
        with torch.no_grad():
            for start in range(0, len(data), chunk):
                obs, act = data.obs[start : start + chunk], data.actions[start : start + chunk]
                values, log_prob, _ = self.policy.evaluate_actions(obs, act)
                mean_action = self.policy._predict(obs, deterministic=True)
                if self._bounds is not None:
                    mean_action = torch.clamp(mean_action.float(), self._bounds[0], self._bounds[1])
                    err = ((mean_action - act) ** 2).mean(dim=1)
                else:  # discrete: the error rate of the most likely action
                    err = (mean_action.flatten() != act).float()
                nll -= float(log_prob.sum())
                mse += float(err.sum())
                vloss += float(((values.flatten() - data.targets[start : start + chunk]) ** 2).sum())
        n = len(data)
        return {"nll": nll / n, "action_mse": mse / n, "value_loss": vloss / n}


# --------------------------------------------------------------------------- rollouts


def dagger_rollouts(
    model: PPO,
    vecnorm: VecNormalize,
    expert: str,
    scenario: str,
    seeds: Sequence[int],
    *,
    env_kwargs: dict[str, Any] | None = None,
    beta: float = 0.0,
    rng: np.random.Generator | None = None,
    progress: bool = False,
) -> tuple[Demos, list[dict[str, Any]]]:
    """Play the learner (a beta-mixture with the expert) on ``seeds``; every visited observation labelled by the expert.

    Returns the labelled transitions (same layout as :mod:`swarm_env_baselines.demos`,
    ``actions`` = the expert's) and the per-episode metrics of the executed behaviour.
    """
    from tqdm.auto import tqdm


    rng = rng if rng is not None else np.random.default_rng(0)
    env = SwarmEnv(scenario, **dict(env_kwargs or {}))
    episodes: list[dict[str, Any]] = []
    metrics: list[dict[str, Any]] = []
    try:
        teacher = load_policy(expert, env)
        learner = SB3Policy(model, vecnorm, deterministic=True, name="bc")
        index = {a: i for i, a in enumerate(env.possible_agents)}
        discrete = env.action_type == "discrete"
        for seed in tqdm(list(seeds), desc="DAgger rollouts", unit="ep", disable=not progress):
            observations, _ = env.reset(seed=int(seed))
            teacher.reset(env, int(seed))
            learner.reset(env, int(seed))
            rows: dict[str, list[Any]] = {"obs": [], "actions": [], "rewards": [], "agent": [], "step": []}
            t = 0
            truncated = False
            while env.agents:
                state = env.world_state()
                labels = teacher.act(observations, state)  # every step, so the expert's own state stays valid
                chosen = learner.act(observations, state)
                if beta > 0:
                    chosen = {a: labels[a] if rng.random() < beta else chosen[a] for a in chosen}
                next_obs, rewards, terms, truncs, _ = env.step(chosen)
                append_step(rows, observations, labels, rewards, index, t, discrete)  # the expert's labels
                if not env.agents:
                    truncated = any(truncs.values()) and not any(terms.values())
                observations = next_obs
                t += 1
            episodes.append(episode_arrays(rows, truncated, discrete, env.observation_space(env.possible_agents[0]).shape))
            metrics.append({"seed": int(seed), **env.episode_metrics()})
    finally:
        env.close()
    return _stack(episodes, [int(s) for s in seeds], {}), metrics


def evaluate_model(
    model: PPO, vecnorm: VecNormalize | None, scenario: str, seeds: Sequence[int], *, env_kwargs: dict[str, Any] | None = None, progress: bool = False
) -> dict[str, Any]:
    """:func:`swarm_env.harness.evaluation.summarize` of the deterministic policy on ``seeds`` (one evaluation path)."""
    from tqdm.auto import tqdm


    env = SwarmEnv(scenario, **dict(env_kwargs or {}))
    try:
        policy = SB3Policy(model, vecnorm, deterministic=True, name="bc")
        episodes = [run_episode(env, policy, int(s)) for s in tqdm(list(seeds), desc="validation", unit="ep", disable=not progress)]
    finally:
        env.close()
    return summarize(episodes)


def _eval_row(stage: int, n_train: int, summary: dict[str, Any]) -> dict[str, Any]:
    return {
        "stage": stage,
        "n_train": n_train,
        "episodes": summary["episodes"],
        "success_rate": summary["success_rate"]["mean"],
        "collision_free_rate": summary["collision_free_rate"]["mean"],
        "collisions": summary["collisions"]["mean"],
        "collisions_ci95": summary["collisions"]["ci95"],
        "formation_error": summary["formation_error"]["mean"],
        "formation_error_ci95": summary["formation_error"]["ci95"],
    }


# --------------------------------------------------------------------------- the run


def _write_csv(path: Path, columns: Sequence[str], rows: list[dict[str, Any]]) -> None:
    with open(path, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(columns))
        writer.writeheader()
        for row in rows:
            writer.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in row.items()})


def plot_bc_curve(log_rows: list[dict[str, Any]], out_png: str | Path, title: str = "") -> Path:
    """Train/validation NLL and validation action MSE per epoch (DAgger stages shaded)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x = np.arange(len(log_rows))
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6), constrained_layout=True)
    axes[0].plot(x[1:], [r["train_nll"] for r in log_rows[1:]], label="train NLL")
    axes[0].plot(x, [r["val_nll"] for r in log_rows], label="validation NLL")
    axes[0].set_ylabel("negative log-likelihood of expert actions")
    axes[1].plot(x, [r["val_action_mse"] for r in log_rows], color="C2", label="validation action MSE")
    axes[1].set_ylabel("MSE of the deterministic action")
    axes[1].set_yscale("log")
    stages = [r["stage"] for r in log_rows]
    for ax in axes:
        for s in sorted(set(stages) - {0}):
            first = stages.index(s)
            ax.axvline(first - 0.5, color="grey", ls=":", lw=1)
        ax.set_xlabel("epoch (dotted: DAgger iterations)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    if title:
        fig.suptitle(title, fontsize=10)
    out = Path(out_png)
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return out


def train_bc(cfg: BCConfig) -> Path:
    """Run ``cfg`` (see the module docstring) and return the output directory."""
    import torch
    from tqdm.auto import tqdm


    torch.set_num_threads(cfg.torch_threads)
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    timings: dict[str, float] = {}

    t0 = time.perf_counter()
    demo_file = generate_demos(
        cfg.expert, cfg.scenario, parse_seeds(cfg.train_seeds), env_kwargs=cfg.env_kwargs, cache_dir=cfg.cache_dir, workers=cfg.workers, progress=cfg.progress
    )
    demos = load_demos(demo_file)
    timings["demos_s"] = time.perf_counter() - t0
    train_ids, val_ids = split_episodes(demos.n_episodes, cfg.val_fraction, cfg.seed)
    train_set, val_set = demos.select_episodes(train_ids), demos.select_episodes(val_ids)

    model, vecnorm = make_bc_model(cfg.scenario, cfg.env_kwargs, cfg.net_arch, cfg.seed, cfg.gamma)
    fit_normalization(vecnorm, train_set, cfg.gamma)
    train_t, val_t = _tensors(train_set, vecnorm, cfg.gamma), _tensors(val_set, vecnorm, cfg.gamma)
    trainer = BCTrainer(
        model, learning_rate=cfg.learning_rate, batch_size=cfg.batch_size, value_coef=cfg.value_coef, min_std=cfg.min_std, seed=cfg.seed
    )

    log_rows: list[dict[str, Any]] = []
    eval_rows: list[dict[str, Any]] = []
    eval_seeds = parse_seeds(cfg.eval_seeds) if cfg.eval_seeds else []
    dagger_chunks = np.array_split(np.asarray(parse_seeds(cfg.dagger_seeds)), cfg.dagger_iters) if cfg.dagger_iters else []
    bar = tqdm(total=cfg.epochs + cfg.dagger_iters * cfg.dagger_epochs, desc="BC epochs", unit="epoch", disable=not cfg.progress)

    def log(stage: int, epoch: int, train_nll: float, train_value: float) -> None:
        val = trainer.evaluate(val_t)
        log_rows.append(
            {
                "stage": stage, "epoch": epoch, "n_train": len(train_t), "train_nll": train_nll, "val_nll": val["nll"],
                "val_action_mse": val["action_mse"], "train_value_loss": train_value, "val_value_loss": val["value_loss"], "std": trainer.std(),
            }
        )
        bar.set_postfix(val_nll=f"{val['nll']:.3f}", mse=f"{val['action_mse']:.4f}")

    def run_epochs(stage: int, n: int) -> None:
        for _ in range(n):
            nll, value = trainer.train_epoch(train_t)
            log(stage, len(log_rows), nll, value)
            bar.update()

    def validate(stage: int) -> None:
        if eval_seeds:
            t = time.perf_counter()
            eval_rows.append(_eval_row(stage, len(train_t), evaluate_model(model, vecnorm, cfg.scenario, eval_seeds, env_kwargs=cfg.env_kwargs)))
            timings["eval_s"] = timings.get("eval_s", 0.0) + time.perf_counter() - t

    t0 = time.perf_counter()
    log(0, 0, float("nan"), float("nan"))  # the untrained network
    run_epochs(0, cfg.epochs)
    timings["bc_train_s"] = time.perf_counter() - t0
    validate(0)

    parts = [train_set]
    for it, chunk in enumerate(dagger_chunks, start=1):
        t = time.perf_counter()
        labelled, _ = dagger_rollouts(
            model, vecnorm, cfg.expert, cfg.scenario, chunk.tolist(), env_kwargs=cfg.env_kwargs, beta=cfg.dagger_beta,
            rng=np.random.default_rng([cfg.seed, it]), progress=False,
        )
        timings["dagger_rollout_s"] = timings.get("dagger_rollout_s", 0.0) + time.perf_counter() - t
        parts.append(labelled)
        train_t = _tensors(Demos.concatenate(parts), vecnorm, cfg.gamma)
        t = time.perf_counter()
        run_epochs(it, cfg.dagger_epochs)
        timings["dagger_train_s"] = timings.get("dagger_train_s", 0.0) + time.perf_counter() - t
        validate(it)
    bar.close()

    save_model(model, out, vecnorm)
    _write_csv(out / "bc_log.csv", LOG_COLUMNS, log_rows)
    if eval_rows:
        _write_csv(out / "eval.csv", EVAL_COLUMNS, eval_rows)
    if can_plot(out / "learning_curve.png", "bc_log.csv"):
        plot_bc_curve(log_rows, out / "learning_curve.png", title=f"BC of {cfg.expert} on {cfg.scenario} (seed {cfg.seed})")
    try:
        versions: dict[str, Any] = package_versions()
    except ImportError:  # the training module is optional for BC
        versions = {}
    record = {
        "config": dataclasses.asdict(cfg),
        "demos": {"path": str(demo_file), "key": demos.meta.get("key"), "n_transitions": len(demos), "n_episodes": demos.n_episodes},
        "split": {"train_episodes": len(train_ids), "val_episodes": len(val_ids), "val_seeds": demos.episode_seeds[val_ids].tolist()},
        "versions": versions,
    }
    write_json(out / "bc_config.json", record)
    summary = {
        "n_demo_transitions": len(demos),
        "n_train_transitions": len(train_t),
        "n_val_transitions": len(val_t),
        "final": log_rows[-1],
        "eval": eval_rows,
        "timings_s": {k: round(v, 1) for k, v in timings.items()},
    }
    write_json(out / "summary.json", summary)
    return out


# --------------------------------------------------------------------------- command line


def build_parser() -> argparse.ArgumentParser:
    """One option per :class:`BCConfig` field, its help text from the field's ``#:`` comment."""
    parser = argparse.ArgumentParser(formatter_class=DefaultsHelpFormatter, prog="swarm-env bc", description="Behaviour cloning (+ DAgger) of a scripted expert into PPO's policy network.")
    add_dataclass_options(parser, BCConfig, required=("out",))
    return parser


def config_from_args(argv: list[str] | None = None) -> BCConfig:
    args = vars(build_parser().parse_args(argv))
    if "env_kwargs" in args:
        args["env_kwargs"] = dict(args["env_kwargs"])
    return BCConfig(**args)


def main(argv: list[str] | None = None) -> int:
    try:
        cfg = config_from_args(argv)
        out = train_bc(cfg)
    except (ValueError, TypeError, FileNotFoundError, PolicyError, UnknownPolicyError) as exc:
        message = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc
        print(f"error: {message}", file=sys.stderr)
        return 2
    print(out)
    print((out / "summary.json").read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
