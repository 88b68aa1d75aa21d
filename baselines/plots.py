"""Learning-curve figures from a run's ``eval.csv`` (matplotlib, headless)."""

from __future__ import annotations

import csv
from collections.abc import Mapping
from pathlib import Path

from swarm_env.checks import DefaultsHelpFormatter
from swarm_env.harness.leaderboard import parse_seeds, run_leaderboard
from swarm_env_baselines.mappo_policy import CHECKPOINTS


def read_eval_csv(path: str | Path) -> dict[str, list[float]]:
    """Columns of an ``eval.csv`` written by :class:`swarm_env_baselines.callbacks.EvalCallback`, as float lists."""
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    if not rows:
        raise ValueError(f"{path}: no evaluation rows yet")
    return {key: [float(r[key]) if r[key] not in ("", "None") else float("nan") for r in rows] for key in rows[0]}


def _shared_legend(fig, axes) -> None:
    """One legend for both panels, below them: inside an axis it hid the curves it describes."""
    handles, labels = axes[0].get_legend_handles_labels()
    seen = dict(zip(labels, handles))
    for ax in axes[1:]:
        for h, label in zip(*ax.get_legend_handles_labels()):
            seen.setdefault(label, h)
    fig.legend(list(seen.values()), list(seen), loc="outside lower center", ncol=min(len(seen), 4), fontsize=8,
               frameon=False)


def plot_learning_curve(
    eval_csv: str | Path,
    out_png: str | Path,
    *,
    title: str = "",
    references: Mapping[str, Mapping[str, float]] | None = None,
    marks: Mapping[str, float] | None = None,
) -> Path:
    """Validation formation error and collisions per episode against agent-steps, with 95 % CI bands.

    ``references`` optionally draws horizontal lines, e.g.
    ``{"vo": {"formation_error": 0.31, "collisions": 0.0}}`` for an expert's level;
    ``marks`` draws labelled vertical lines at agent-steps, e.g. ``{"fine-tuning": 8e6}``.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    data = read_eval_csv(eval_csv)
    steps = np.array(data["agent_steps"]) / 1e6
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.2), layout="constrained")
    for ax, key, label in (
        (axes[0], "formation_error", "formation error (m)"),
        (axes[1], "collisions", "collisions per episode"),
    ):
        mean = np.array(data[key])
        ci = np.nan_to_num(np.array(data[f"{key}_ci95"]))
        ax.plot(steps, mean, marker="o", ms=3, label="policy (validation seeds)")
        ax.fill_between(steps, mean - ci, mean + ci, alpha=0.25)
        for i, (name, values) in enumerate((references or {}).items()):
            if key in values:
                ax.axhline(values[key], ls="--", lw=1, color=f"C{i + 1}", label=name)
        for mark, at in (marks or {}).items():  # written up the line from the top: marks close together stay apart
            ax.axvline(at / 1e6, ls=":", lw=1, color="gray")
            ax.annotate(mark, (at / 1e6, 1), xycoords=("data", "axes fraction"), xytext=(-2, -3),
                        textcoords="offset points", rotation=90, ha="right", va="top", fontsize=7, color="gray")
        ax.set_xlabel("agent-steps (millions)")
        ax.set_ylabel(label)
        ax.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
    _shared_legend(fig, axes)
    if title:
        fig.suptitle(title, fontsize=10)
    out = Path(out_png)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def plot_methods_learning_curves(
    runs: Mapping[str, list[str | Path]],
    out_png: str | Path,
    *,
    title: str = "",
    references: Mapping[str, Mapping[str, float]] | None = None,
) -> Path:
    """Validation formation error and collisions per episode against agent-steps for several methods,
    each trained with several seeds: ``runs`` maps a method name to its seeds' ``eval.csv`` files.

    Each method is drawn as the mean over its seeds (a line) and the band between the seeds' lowest and
    highest value at each evaluation (shaded); seeds are compared at the evaluations they all reached.
    ``references`` draws horizontal lines as in :func:`plot_learning_curve`.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.6), layout="constrained")
    for i, (method, paths) in enumerate(runs.items()):
        curves = [read_eval_csv(p) for p in paths]
        n = min(len(c["agent_steps"]) for c in curves)
        steps = np.array(curves[0]["agent_steps"][:n]) / 1e6
        for ax, key in ((axes[0], "formation_error"), (axes[1], "collisions")):
            values = np.array([c[key][:n] for c in curves])
            ax.plot(steps, values.mean(axis=0), color=f"C{i}", marker="o", ms=2.5, label=f"{method} ({len(curves)} seeds)")
            ax.fill_between(steps, values.min(axis=0), values.max(axis=0), color=f"C{i}", alpha=0.2)
    for ax, key, label in ((axes[0], "formation_error", "formation error (m)"), (axes[1], "collisions", "collisions per episode")):
        for j, (name, values) in enumerate((references or {}).items()):
            if key in values:
                ax.axhline(values[key], ls="--", lw=1, color=f"C{len(runs) + j}", label=name)
        ax.set_xlabel("agent-steps (millions)")
        ax.set_ylabel(label)
        ax.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
    _shared_legend(fig, axes)
    if title:
        fig.suptitle(title, fontsize=10)
    out = Path(out_png)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def shipped_eval_csvs(methods: list[str]) -> dict[str, list[Path]]:
    """Each shipped method's training seeds' ``eval.csv`` (``baselines/checkpoints/<method>/s<k>/``)."""
    found = {m: sorted((CHECKPOINTS / m).glob("s*/eval.csv")) for m in methods}
    missing = [m for m, paths in found.items() if not paths]
    if missing:
        raise ValueError(f"no shipped eval.csv under {CHECKPOINTS} for: {', '.join(missing)}")
    return found


def main(argv: list[str] | None = None) -> int:
    """``swarm-env curves``: the learning curves of the shipped methods in one figure."""
    import argparse
    import sys

    parser = argparse.ArgumentParser(formatter_class=DefaultsHelpFormatter, 
        prog="swarm-env curves",
        description="Validation learning curves (mean and min-max band over training seeds) of shipped methods, "
                    "with reference policies scored on the same validation worlds.")
    parser.add_argument("--methods", nargs="+", default=["ippo", "mappo", "mappo_shielded", "residual_vo"])
    parser.add_argument("--references", nargs="*", default=["vo", "pursuit"], help="policies drawn as levels")
    parser.add_argument("--reference-seeds", default="500-549", help="the validation seeds of the runs")
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--out", required=True, help="PNG to write")
    args = parser.parse_args(argv)
    try:
        runs = shipped_eval_csvs(args.methods)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    references = {}
    if args.references:
        board = run_leaderboard(args.references, ["random"], {"random": parse_seeds(args.reference_seeds)},
                                workers=args.workers, progress=True)
        references = {f"{r.policy} (same worlds)": {"formation_error": r.summary["formation_error"]["mean"],
                                                    "collisions": r.summary["collisions"]["mean"]} for r in board.rows}
    # A shield-taught run is validated (and selected) acting alone, without the shield.
    labels = {m: f"{m} (acting alone)" if m == "mappo_shielded" else m for m in runs}
    out = plot_methods_learning_curves({labels[m]: p for m, p in runs.items()}, args.out,
                                       title=f"validation seeds {args.reference_seeds}", references=references)
    print(out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
