"""SB3 callbacks of a training run: progress bar, periodic evaluation on validation seeds, checkpoints,
a clean stop on SIGINT/SIGTERM. Each picks up where a resumed run left off (``model.num_timesteps``).

The evaluation callback scores the current model through the same path as the
leaderboard (:func:`swarm_env.harness.episode.run_episode` with
:class:`~swarm_env_baselines.model_io.SB3Policy`), so "eval" numbers during training and
leaderboard numbers mean the same thing.
"""

from __future__ import annotations

import csv
import pickle
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecNormalize

from swarm_env.env import SwarmEnv
from swarm_env.harness.episode import run_episode
from swarm_env.harness.evaluation import summarize
from swarm_env.harness.policies import ShieldedPolicy
from swarm_env_baselines.checkpointing import truncate_csv
from swarm_env_baselines.model_io import SB3Policy, save_model

#: Model selection score = formation error (m) + this many metres per collision (lower is better).
COLLISION_COST_M = 0.1

EVAL_COLUMNS = (
    "agent_steps",
    "wall_s",
    "score",
    "formation_error",
    "formation_error_ci95",
    "collisions",
    "collisions_ci95",
    "success_rate",
    "collision_free_rate",
    "train_ep_rew_mean",
)


def steps_to_take(model: Any, budget: int) -> int:
    """Agent-steps SB3's ``learn`` takes for a budget of ``budget`` more steps: it stops only
    between whole rollouts, once ``num_timesteps`` reaches the budget, so it rounds the budget
    up to a whole number of rollouts (``n_steps * num_envs`` for on-policy algorithms,
    ``train_freq * num_envs`` for off-policy ones counting steps); ``budget`` otherwise."""
    n_envs = int(model.get_env().num_envs)
    per = getattr(model, "n_steps", None)  # on-policy (PPO, A2C)
    freq = getattr(model, "train_freq", None)  # off-policy (SAC, TD3): a TrainFreq(frequency, unit)
    if per is None and freq is not None and getattr(freq.unit, "value", freq.unit) == "step":
        per = freq.frequency
    if not per:
        return int(budget)
    chunk = int(per) * n_envs
    return -(-int(budget) // chunk) * chunk


class TqdmCallback(BaseCallback):
    """A tqdm bar over agent-steps, showing the mean training episode return.

    Its total is what SB3 will actually take (:func:`steps_to_take`), so it ends at 100 %
    instead of running past the requested ``total``.
    """

    def __init__(self, total: int) -> None:
        super().__init__()
        self.total = total
        self._bar: Any = None

    def _on_training_start(self) -> None:
        from tqdm.auto import tqdm

        # learn() has set _total_timesteps (num_timesteps added when it continues a run, which the bar
        # starts from).
        done = self.model.num_timesteps
        budget = getattr(self.model, "_total_timesteps", self.total) - done
        self._bar = tqdm(total=done + steps_to_take(self.model, budget), initial=done, unit="step", unit_scale=True,
                         desc="train", dynamic_ncols=True)

    def _on_step(self) -> bool:
        n = self.training_env.num_envs
        if self._bar.n + n > self._bar.total:  # an off-policy run counting episodes: no bound known ahead
            self._bar.total = self._bar.n + n
        self._bar.update(n)
        buf = self.model.ep_info_buffer
        if buf and self.n_calls % 50 == 0:
            self._bar.set_postfix(ep_rew=f"{np.mean([e['r'] for e in buf]):.1f}", refresh=False)
        return True

    def _on_training_end(self) -> None:
        self._bar.close()


def _frozen_normalizer(vecnorm: VecNormalize | None) -> VecNormalize | None:
    """A snapshot of the running statistics (training keeps updating the original)."""
    if vecnorm is None:
        return None
    snap = pickle.loads(pickle.dumps(vecnorm))  # VecNormalize pickles without its venv
    snap.training = False
    return snap


def score_episodes(episodes: list[dict[str, Any]]) -> dict[str, Any]:
    """Summary of evaluation episodes plus the model-selection ``score`` (see :data:`COLLISION_COST_M`)."""
    s = summarize(episodes)
    s["score"] = s["formation_error"]["mean"] + COLLISION_COST_M * s["collisions"]["mean"]
    return s


class EvalCallback(BaseCallback):
    """Every ``every`` agent-steps: play the validation seeds, log, keep the best model, append ``eval.csv``."""

    def __init__(
        self,
        every: int,
        scenario: str,
        env_kwargs: dict[str, Any],
        seeds: Sequence[int],
        run_dir: Path,
        vecnorm: VecNormalize | None,
        shield: bool = False,
    ) -> None:
        super().__init__()
        self.shield = shield
        self.every = every
        self.scenario = scenario
        self.env_kwargs = env_kwargs
        self.seeds = list(seeds)
        self.run_dir = run_dir
        self.vecnorm = vecnorm
        self.best_score = float("inf")
        self._next = 0
        self._t0 = time.perf_counter()
        self._csv = run_dir / "eval.csv"
        self.history: list[dict[str, Any]] = []

    def _on_training_start(self) -> None:
        self._t0 = time.perf_counter()
        self._next = self.num_timesteps  # evaluate the starting point too (a warm start's is informative)
        if not self._csv.exists():
            with open(self._csv, "w", newline="") as fh:
                csv.writer(fh).writerow(EVAL_COLUMNS)
        elif self.num_timesteps:  # a resumed run: its evaluations up to here count, later ones are dropped
            self._resume_history()

    def _resume_history(self) -> None:
        with open(self._csv, newline="") as fh:
            rows = [r for r in csv.DictReader(fh) if int(r["agent_steps"]) <= self.num_timesteps]
        truncate_csv(self._csv, len(rows))
        self.history = [{k: int(v) if k == "agent_steps" else float(v) for k, v in r.items()} for r in rows]
        if self.history:
            self.best_score = min(r["score"] for r in self.history)
            self._next = self.history[-1]["agent_steps"] + self.every
            self._t0 -= self.history[-1]["wall_s"]

    def _on_step(self) -> bool:
        if self.num_timesteps >= self._next:
            self._next = self.num_timesteps + self.every
            self.evaluate()
        return True

    def _on_training_end(self) -> None:
        if not self.history or self.history[-1]["agent_steps"] != self.num_timesteps:
            self.evaluate()

    def evaluate(self) -> dict[str, Any]:
        policy: Any = SB3Policy(self.model, _frozen_normalizer(self.vecnorm), name="current model")
        if self.shield:  # scored as it acts in training: through the safety layer
            policy = ShieldedPolicy.around(policy)
        env = SwarmEnv(self.scenario, **self.env_kwargs)
        try:
            episodes = [run_episode(env, policy, s) for s in self.seeds]
        finally:
            env.close()
        s = score_episodes(episodes)
        buf = self.model.ep_info_buffer
        row = {
            "agent_steps": int(self.num_timesteps),
            "wall_s": round(time.perf_counter() - self._t0, 1),
            "score": s["score"],
            "formation_error": s["formation_error"]["mean"],
            "formation_error_ci95": s["formation_error"]["ci95"],
            "collisions": s["collisions"]["mean"],
            "collisions_ci95": s["collisions"]["ci95"],
            "success_rate": s["success_rate"]["mean"],
            "collision_free_rate": s["collision_free_rate"]["mean"],
            "train_ep_rew_mean": float(np.mean([e["r"] for e in buf])) if buf else float("nan"),
        }
        self.history.append(row)
        with open(self._csv, "a", newline="") as fh:
            csv.writer(fh).writerow([row[c] for c in EVAL_COLUMNS])
        for key in ("score", "formation_error", "collisions", "success_rate", "collision_free_rate"):
            self.logger.record(f"eval/{key}", row[key])
        if row["score"] < self.best_score:
            self.best_score = row["score"]
            save_model(self.model, self.run_dir / "best", self.vecnorm)  # the statistics it was just scored with
        return row


class CheckpointCallback(BaseCallback):
    """Save ``checkpoints/step_<n>/`` (model + VecNormalize statistics) every ``every`` agent-steps."""

    def __init__(self, every: int, run_dir: Path, vecnorm: VecNormalize | None) -> None:
        super().__init__()
        self.every = every
        self.run_dir = run_dir
        self.vecnorm = vecnorm
        self._next = every

    def _on_training_start(self) -> None:
        self._next = (self.num_timesteps // self.every + 1) * self.every  # a resumed run: the next multiple

    def _on_step(self) -> bool:
        if self.num_timesteps >= self._next:
            self._next += self.every
            save_model(self.model, self.run_dir / "checkpoints" / f"step_{self.num_timesteps}", self.vecnorm)
        return True


class StopCallback(BaseCallback):
    """Ends ``learn`` cleanly once ``stop`` (a :class:`baselines.checkpointing.StopRequest`) has caught a
    signal: at the first step of the next rollout, so the current rollout and its update complete."""

    def __init__(self, stop: Any) -> None:
        super().__init__()
        self.stop = stop
        self._stopping = False

    def _on_rollout_start(self) -> None:
        self._stopping = self.stop.requested

    def _on_step(self) -> bool:
        return not self._stopping
