"""Model selection on the validation seeds, shared by the trainers on the batched engine (MAPPO/IPPO, SAC).

A run scores its policy every ``eval_every`` agent-steps on the validation seeds (default 500-549) with
the leaderboard's episode loop, keeps the best-scoring snapshot in ``best/`` and streams one row per
evaluation to ``eval.csv``. The score is the mean formation error plus :data:`COLLISION_COST_M` metres per
collision (lower is better). The test seeds (1000 on) are the leaderboard's and never seen here.

:class:`Validation` does this in the training process, or in background processes (``workers`` > 0:
each evaluation point is saved as a snapshot directory and scored by a worker while training goes on;
results are recorded in order as they arrive, the same numbers bit for bit), and carries what a
checkpoint needs to go on after an interruption (:meth:`Validation.state`, :meth:`Validation.resume`).
"""

from __future__ import annotations

import shutil
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from swarm_env.env import SwarmEnv
from swarm_env.harness.episode import run_episode
from swarm_env.harness.evaluation import summarize
from swarm_env.harness.policies import ShieldedPolicy
from swarm_env_baselines.checkpointing import ignore_interrupts
from swarm_env_baselines.safe_io import swap_in_dir

#: Model selection: a collision costs as much as this many metres of mean formation error.
COLLISION_COST_M = 1.0
EVAL_COLUMNS = ("agent_steps", "wall_s", "score", "formation_error", "formation_error_ci95", "collisions",
                "collisions_ci95", "success_rate")

__all__ = ["COLLISION_COST_M", "EVAL_COLUMNS", "Validation", "evaluate_policy", "replace_dir"]


def evaluate_policy(policy: Any, scenario: Any, env_kwargs: dict[str, Any], seeds: list[int],
                    shielded: bool = False) -> dict[str, Any]:
    """Score ``policy`` on ``seeds`` of ``SwarmEnv(scenario, **env_kwargs)`` with the leaderboard's episode
    loop (through the safety layer if ``shielded``); the summary of
    :func:`swarm_env.harness.evaluation.summarize` plus ``score``."""
    env = SwarmEnv(scenario, **env_kwargs)
    scored: Any = ShieldedPolicy.around(policy) if shielded else policy
    try:
        episodes = [run_episode(env, scored, s) for s in seeds]
    finally:
        env.close()
    s = summarize(episodes)
    s["score"] = s["formation_error"]["mean"] + COLLISION_COST_M * s["collisions"]["mean"]
    return s


def replace_dir(src: Path, dst: Path) -> None:
    """Make ``dst`` a copy of ``src``, swapped in whole (a reader never sees half a model)."""
    tmp = dst.with_name(f".{dst.name}.tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    shutil.copytree(src, tmp)
    swap_in_dir(tmp, dst)


class Validation:
    """Evaluations of one run, in order, with the best kept in ``run_dir/best``.

    Args:
        run_dir: the run directory (``best/`` and, with workers, ``evals/<agent-steps>/`` snapshots).
        score_live: scores the trainer's live policy in this process (no workers).
        score_saved: a picklable ``f(snapshot_dir) -> summary`` a worker runs on a saved snapshot.
        record: called with each evaluation's ``eval.csv`` row, in order.
        workers: background processes (0: score in the training process).
    """

    def __init__(self, run_dir: Path, score_live: Callable[[], dict[str, Any]],
                 score_saved: Callable[[str], dict[str, Any]], record: Callable[[dict[str, Any]], None],
                 workers: int = 0) -> None:
        self.run_dir = run_dir
        self.score_live = score_live
        self.score_saved = score_saved
        self.record_row = record
        self.best = float("inf")
        self.history: list[dict[str, Any]] = []
        self.last_eval: int | None = None
        # Evaluations handed to a worker and not yet recorded: (agent-steps, wall_s, snapshot dir, future).
        self.pending: list[tuple[int, float, Path, Any]] = []
        self.pool = None
        if workers:
            import multiprocessing as mp
            from concurrent.futures import ProcessPoolExecutor


            self.pool = ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn"), initializer=ignore_interrupts)

    def _record(self, steps: int, wall_s: float, s: dict[str, Any], keep: Callable[[], Any]) -> None:
        row = {"agent_steps": steps, "wall_s": wall_s, "score": s["score"],
               "formation_error": s["formation_error"]["mean"], "formation_error_ci95": s["formation_error"]["ci95"],
               "collisions": s["collisions"]["mean"], "collisions_ci95": s["collisions"]["ci95"],
               "success_rate": s["success_rate"]["mean"]}
        self.history.append(row)
        self.record_row(row)
        if row["score"] < self.best:
            self.best = row["score"]
            keep()

    def evaluate(self, steps: int, wall_s: float, save: Callable[[Path], Path]) -> None:
        """Score the policy as it is after ``steps`` agent-steps; ``save(directory)`` writes its files."""
        self.last_eval = steps
        if self.pool is None:
            self._record(steps, wall_s, self.score_live(), lambda: save(self.run_dir / "best"))
            return
        self._submit(steps, wall_s, save(self.run_dir / "evals" / str(steps)))
        self.collect(wait=False)

    def _submit(self, steps: int, wall_s: float, snapshot: Path) -> None:
        if self.pool is None:  # a resumed run's pending evaluation, now without workers
            self._record(steps, wall_s, self.score_saved(str(snapshot)), lambda: replace_dir(snapshot, self.run_dir / "best"))
            return
        self.pending.append((steps, wall_s, snapshot, self.pool.submit(self.score_saved, str(snapshot))))

    def collect(self, wait: bool) -> None:
        """Record the finished evaluations (in order; ``wait``: all of them)."""
        while self.pending and (wait or self.pending[0][3].done()):
            steps, wall_s, snapshot, future = self.pending.pop(0)
            self._record(steps, wall_s, future.result(), lambda snapshot=snapshot: replace_dir(snapshot, self.run_dir / "best"))

    def state(self) -> dict[str, Any]:
        """JSON values for a checkpoint: the best score, the history, and the evaluations still pending
        (their snapshots are kept: :meth:`resume` scores them again)."""
        return {"best": self.best if self.best != float("inf") else None, "history": self.history,
                "last_eval": self.last_eval, "pending_evals": [[p[0], p[1]] for p in self.pending]}

    def resume(self, meta: dict[str, Any]) -> None:
        """Go on from a checkpoint's :meth:`state` (raises ``KeyError``/``TypeError``/``ValueError`` on a bad one)."""
        self.best = float("inf") if meta["best"] is None else float(meta["best"])
        self.history, self.last_eval = list(meta["history"]), meta["last_eval"]
        for steps, wall_s in [(int(s), float(w)) for s, w in meta["pending_evals"]]:
            snapshot = self.run_dir / "evals" / str(steps)
            if (snapshot / "policy.json").is_file():
                self._submit(steps, wall_s, snapshot)
            else:
                print(f"warning: {snapshot} is gone: the evaluation at {steps} agent-steps is skipped", file=sys.stderr)

    def close(self, finished: bool) -> None:
        """Stop the workers; a finished run's snapshots go (an interrupted run keeps those still pending)."""
        if self.pool is not None:
            self.pool.shutdown(cancel_futures=True)
        if finished:
            shutil.rmtree(self.run_dir / "evals", ignore_errors=True)
