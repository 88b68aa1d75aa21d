"""A run's live records: ``train.csv`` and ``eval.csv`` (streamed, readable while the run goes on) and the
same scalars as TensorBoard events under ``<run dir>/tb`` (``tensorboard --logdir runs``).

TensorBoard tags group the columns: ``train/*`` (losses, entropy, approximate KL, clip fraction,
explained variance, action std), ``rollout/*`` (episode return, collisions per episode, formation
error, contact rate, intervention rate), ``eval/*`` (the validation score and its parts) and
``time/*`` (agent-steps per second, rollout and update seconds), each against agent-steps. Without the
``tensorboard`` package (the ``rl`` extra brings it) the CSV files are written alone, with one warning.
"""

from __future__ import annotations

import csv
import math
import warnings
from pathlib import Path
from typing import Any

from swarm_env.jsonio import write_json
from swarm_env_baselines.plots import plot_learning_curve

__all__ = ["RunLog", "TB_GROUPS", "can_plot", "draw_learning_curve", "episode_stats", "finish_run"]

#: The TensorBoard group of each column (columns not listed go to ``train/``).
TB_GROUPS = {
    "episode_return": "rollout", "collisions_per_episode": "rollout", "episode_formation_error": "rollout",
    "episodes": "rollout", "contacts_per_agent_step": "rollout", "intervention_rate": "rollout",
    "mean_reward": "rollout", "agent_steps_per_s": "time", "rollout_s": "time", "update_s": "time",
}


class RunLog:
    """Appends rows to ``train.csv``/``eval.csv`` (headers written by :meth:`create`) and mirrors them to TensorBoard.

    ``purge_step``: on a resumed run, TensorBoard drops the events logged at or after this step by the
    interrupted run (the CSV files are truncated by the checkpoint code)."""

    def __init__(self, run_dir: Path, train_columns: tuple[str, ...], eval_columns: tuple[str, ...],
                 tensorboard: bool = True, purge_step: int | None = None) -> None:
        self.run_dir = run_dir
        self.columns = {"train.csv": train_columns, "eval.csv": eval_columns}
        self.writer: Any = None
        if tensorboard:
            try:
                from torch.utils.tensorboard import SummaryWriter
            except ImportError:  # (torch without the tensorboard package)
                warnings.warn("tensorboard is not installed: train.csv and eval.csv only "
                              "(pip install 'swarm-env[rl]' brings it)", stacklevel=2)
            else:
                self.writer = SummaryWriter(str(run_dir / "tb"), purge_step=purge_step)

    @staticmethod
    def create(run_dir: Path, train_columns: tuple[str, ...], eval_columns: tuple[str, ...]) -> None:
        """Write the two CSV files' headers (a new run)."""
        for name, columns in (("eval.csv", eval_columns), ("train.csv", train_columns)):
            with open(run_dir / name, "w", newline="") as fh:
                csv.writer(fh).writerow(columns)

    def train(self, row: dict[str, Any]) -> None:
        self._write("train.csv", row, lambda key: f"{TB_GROUPS.get(key, 'train')}/{key}")

    def eval(self, row: dict[str, Any]) -> None:
        self._write("eval.csv", row, lambda key: f"eval/{key}")

    def _write(self, name: str, row: dict[str, Any], tag: Any) -> None:
        columns = self.columns[name]
        with open(self.run_dir / name, "a", newline="") as fh:  # streamed: readable while the run goes on
            csv.writer(fh).writerow([_fmt(row[c]) for c in columns])
        if self.writer is not None:
            step = int(row["agent_steps"])
            for key in columns:
                value = row[key]
                if key not in ("agent_steps", "wall_s") and isinstance(value, (int, float)) and math.isfinite(value):
                    self.writer.add_scalar(tag(key), value, step)
            self.writer.flush()

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()


def episode_stats(returns: list[float], metrics: list[dict[str, Any]]) -> dict[str, float]:
    """The episodes that ended in a logging window: how many, their mean return (raw reward summed, mean
    over followers), collisions and formation error (NaN when none ended)."""
    nan = float("nan")
    if not metrics:
        return {"episodes": 0, "episode_return": nan, "collisions_per_episode": nan, "episode_formation_error": nan}
    n = len(metrics)
    return {"episodes": n, "episode_return": sum(returns) / n,
            "collisions_per_episode": sum(e["collisions"]["total"] for e in metrics) / n,
            "episode_formation_error": sum(e["formation_error"]["mean"] for e in metrics) / n}


def finish_run(run_dir: Path, summary: dict[str, Any], history: list[dict[str, Any]]) -> None:
    """A finished run's ``summary.json`` (``summary`` plus the best and the final validation rows of ``history``)
    and ``learning_curve.png`` (from ``eval.csv``)."""
    write_json(run_dir / "summary.json", {**summary, "best": min(history, key=lambda r: r["score"]),
                                          "final": history[-1]})
    draw_learning_curve(run_dir)


def draw_learning_curve(run_dir: Path) -> Path | None:
    """``run_dir/learning_curve.png`` from ``run_dir/eval.csv``; without matplotlib (the ``plots`` extra) one
    warning and None: a finished run must not end in an error for want of its picture."""
    if not can_plot(run_dir / "learning_curve.png", "eval.csv"):
        return None
    return plot_learning_curve(run_dir / "eval.csv", run_dir / "learning_curve.png", title=run_dir.name)


def can_plot(png: Path, source: str) -> bool:
    """Whether matplotlib (the ``plots`` extra) is there to draw ``png``; if not, one warning naming ``source``, the
    file that holds the same numbers."""
    try:
        import matplotlib  # noqa: F401 - the plots extra, optional here
    except ImportError:
        warnings.warn(f"{png} not drawn: matplotlib is missing (pip install 'swarm-env[plots]'); {source} holds the "
                      "same numbers", stacklevel=3)
        return False
    return True


def _fmt(x: Any) -> Any:
    return f"{x:.6g}" if isinstance(x, float) else x
