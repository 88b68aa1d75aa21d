"""Ship a training run as a checkpoint: copy its model-selected policy and records, write the README.

``swarm-env ship RUN_DIR --method residual_vo --seed s0`` copies, from ``RUN_DIR``,
the best validation policy (``best/policy.safetensors`` + ``best/policy.json``) and the run's
records (``config.json``, ``versions.json``, ``summary.json``, ``eval.csv``, ``train.csv``,
``pretrain.csv`` when there was a warm start, ``learning_curve.png``) into
``baselines/checkpoints/<method>/<seed>/``, then rewrites ``baselines/checkpoints/<method>/README.md``
from every seed shipped so far: the exact training command, the commit, wall time, where the time
went (warm start, rollouts, updates, validation) and the selected model's validation figures.

A run of ``swarm-env train sb3`` (its ``config.json`` names an ``algo``) ships the same way, with SB3's
training log ``logs/progress.csv`` as ``progress.csv`` in place of ``train.csv`` (SB3 does not split its
wall time, so its README gives the wall time and rate only); its safe pair loads as ``ppo:DIR``.

Rules, each an error naming the file and what was expected:

* the run finished (``summary.json`` and ``best/`` exist);
* it was trained from a clean commit (``versions.json``: ``git_dirty`` false), unless ``--allow-dirty``;
* the destination is replaced atomically (written beside it, then renamed), so an interrupted
  ship leaves the previous checkpoint whole.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import shlex
import shutil
import sys
from pathlib import Path
from typing import Any

from swarm_env.checks import DefaultsHelpFormatter
from swarm_env_baselines.mappo_policy import CHECKPOINTS
from swarm_env_baselines.safe_io import CONFIG_FILE, WEIGHTS_FILE, swap_in_dir

#: Records copied from the run directory (the ones marked optional may be absent).
RECORDS = ("config.json", "versions.json", "summary.json", "eval.csv", "train.csv", "learning_curve.png")
OPTIONAL_RECORDS = ("pretrain.csv",)
#: Records of a ``swarm-env train sb3`` run, and where its SB3 training log is (shipped as ``progress.csv``).
SB3_RECORDS = ("config.json", "versions.json", "summary.json", "eval.csv", "learning_curve.png")
SB3_LOG = Path("logs") / "progress.csv"

#: The head of each shipped method's README (what the method is; the commands come from the runs).
DESCRIPTIONS = {
    "ippo": (
        "IPPO: one actor shared by every follower, acting on the follower's own observation only, with a "
        "**local** critic (the same observation). Warm-started by DAgger from `vo` (5 rounds of 25 episodes), then "
        "PPO on the v1 reward. Executed unshielded."),
    "mappo": (
        "MAPPO: the same shared actor on observations, with a **centralised** critic reading `env.state()` "
        "(robots, humans, obstacles, leader) joined to the follower's observation. DAgger warm start from `vo`, "
        "then PPO on the v1 reward. Executed unshielded."),
    "mappo_shielded": (
        "MAPPO trained with the safety layer as a **teacher** (`--shield teach`): the env executes the actor's own "
        "actions; the VO shield computes the nearest safe twist to each sampled action, the size of that "
        "correction is a reward penalty (`--intervention-coef 1.0`) and, where the shield intervened, a loss pulls "
        "the actor's mean to the safe twist (`--imitation-coef 1.0`). The entry point `mappo_shielded` executes "
        "it through the shield; `mappo_shielded_bare` loads the same files and acts alone (observations only)."),
    "sb3_ppo": (
        "stable-baselines3's PPO trained through the project's SB3 bridge (`swarm_env_baselines.vec_env`: the "
        "batched engine's 64 worlds as 256 single-agent environments, one network shared by every follower), from "
        "scratch on the v1 reward with SB3's own `VecNormalize`. No warm start, no central critic: what a user "
        "who starts from SB3 gets with `swarm-env train sb3`. Acts on observations only; loads as `ppo:DIR` too."),
    "residual_vo": (
        "`vo`'s twist plus a learned bounded correction (at most `residual_scale` = 0.5 normalised action units), "
        "trained and executed through the safety layer (`--shield execute`), with the shield's correction as a "
        "reward penalty. The actor reads the follower's observation and `vo`'s action, so, like `vo`, it is "
        "**privileged at execution** (it needs the world state to run `vo`). Trained from scratch (no warm start: "
        "a zero correction is already `vo`)."),
    "fan_dagger": (
        "A network that acts on the follower's observation only, through a fixed avoidance sensor computed from "
        "it (`obs_expert`'s fan: the time to contact of each of 165 candidate twists against the neighbour and "
        "human rows and the lidar hits, and the pure-pursuit twist); it scores the candidates and plays the best "
        "one. Trained by DAgger on the batched engine with `obs_expert` (which reads the same observation) as the "
        "teacher: round 0 driven by the teacher, later rounds by the student, every visited state labelled with "
        "the teacher's choice (`swarm_env_baselines.fan_dagger`). `fan_dagger` executes it unshielded; "
        "`fan_dagger_shielded` loads the same files and executes them through the safety layer."),
}

__all__ = ["ShipError", "is_sb3_run", "selected", "ship_run", "time_breakdown", "write_method_readme"]


class ShipError(ValueError):
    """A run that cannot be shipped, with the file and the expectation it failed."""


def _read_json(path: Path) -> dict[str, Any]:
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise ShipError(f"{path}: missing (is the run finished?)") from None
    except json.JSONDecodeError as exc:
        raise ShipError(f"{path}: not valid JSON ({exc})") from None


def ship_run(run_dir: str | os.PathLike[str], method: str, seed: str, *, dest: Path = CHECKPOINTS,
             allow_dirty: bool = False) -> Path:
    """Copy ``run_dir``'s selected policy and records to ``dest/method/seed`` and return that directory."""
    run = Path(run_dir)
    versions = _read_json(run / "versions.json")
    _read_json(run / "summary.json")
    if versions.get("git_dirty") is not False and not allow_dirty:
        raise ShipError(f"{run / 'versions.json'}: git_dirty is {versions.get('git_dirty')!r}, expected false "
                        "(train shipped models from a clean commit, or pass --allow-dirty)")
    sb3 = is_sb3_run(run)
    names = {run / "best" / WEIGHTS_FILE: WEIGHTS_FILE, run / "best" / CONFIG_FILE: CONFIG_FILE}
    if sb3:
        names.update({run / r: r for r in SB3_RECORDS})
        names[run / SB3_LOG] = SB3_LOG.name
    else:
        names.update({run / r: r for r in RECORDS})
        names.update({run / r: r for r in OPTIONAL_RECORDS if (run / r).exists()})
    kind = "swarm-env train sb3" if sb3 else "swarm_env_baselines.mappo (or fan_dagger)"
    for f in names:
        if not f.is_file():
            raise ShipError(f"{f}: missing (expected a finished {kind} run directory)")
    target = dest / method / seed
    staging = target.with_name(f".{seed}.staging")
    shutil.rmtree(staging, ignore_errors=True)
    staging.mkdir(parents=True)
    for f, name in names.items():
        shutil.copy2(f, staging / name)
    return swap_in_dir(staging, target)


def is_sb3_run(run: Path) -> bool:
    """Whether ``run`` (a run directory or a shipped seed) is a ``swarm-env train sb3`` run: its config names an ``algo``."""
    return "algo" in _read_json(run / "config.json")


def selected(seed_dir: Path) -> dict[str, Any]:
    """The validation row of the shipped model: ``summary.json``'s ``best`` (a MAPPO run), or for an SB3 run the
    first row of ``eval.csv`` with the lowest score (the model its ``EvalCallback`` kept in ``best/``)."""
    summary = _read_json(seed_dir / "summary.json")
    if "best" in summary:
        return dict(summary["best"])
    with open(seed_dir / "eval.csv", newline="") as fh:
        rows = [{k: int(v) if k == "agent_steps" else float(v) for k, v in r.items()} for r in csv.DictReader(fh)]
    if not rows:
        raise ShipError(f"{seed_dir / 'eval.csv'}: no validation rows")
    return min(rows, key=lambda r: r["score"])  # min keeps the first of equal scores, as the callback's strict <


def time_breakdown(seed_dir: Path) -> dict[str, float]:
    """Seconds spent in the warm start, rollouts, updates (a fan_dagger run's fits) and validation (the rest of
    the wall time)."""
    summary = _read_json(seed_dir / "summary.json")
    rollout = update = 0.0
    with open(seed_dir / "train.csv", newline="") as fh:
        for row in csv.DictReader(fh):
            rollout += float(row["rollout_s"])
            update += float(row["update_s"] if "update_s" in row else row["fit_s"])  # fan_dagger: the fits
    wall, pretrain = float(summary["wall_s"]), float(summary.get("pretrain_s", 0.0))
    return {"wall": wall, "pretrain": pretrain, "rollout": rollout, "update": update,
            "validation": max(0.0, wall - pretrain - rollout - update)}


def training_command(versions: dict[str, Any]) -> str:
    """The command line that trained a run, from its recorded ``argv``: ``swarm-env ...`` for a run
    started by the ``swarm-env`` command, ``python -m <package>.mappo ...`` for one started as a
    module (``python -m baselines.mappo`` from a checkout's root was the command before the installed
    package was named ``swarm_env_baselines``; the shipped seeds were trained that way), and
    ``swarm-env train mappo ...`` with the recorded arguments otherwise (a run started from Python)."""
    argv = [str(a) for a in versions.get("argv") or [""]]
    launcher = Path(argv[0])
    if launcher.name == "swarm-env":
        return shlex.join(["swarm-env", *argv[1:]])
    if launcher.name == "mappo.py":
        return shlex.join(["python", "-m", f"{launcher.parent.name}.mappo", *argv[1:]])
    return shlex.join(["swarm-env", "train", "mappo", *argv[1:]])


def _seed_rows(method_dir: Path) -> list[tuple[str, Path]]:
    return sorted((d.name, d) for d in method_dir.iterdir() if d.is_dir() and not d.name.startswith("."))


def write_method_readme(method: str, *, dest: Path = CHECKPOINTS, description: str = "") -> Path:
    """(Re)write ``dest/method/README.md`` from every shipped seed's records."""
    method_dir = dest / method
    seeds = _seed_rows(method_dir)
    if not seeds:
        raise ShipError(f"{method_dir}: no shipped seeds")
    lines = [f"# `{method}`", ""]
    description = description or DESCRIPTIONS.get(method, "")
    if description:
        lines += [description, ""]
    lines += [
        f"Shipped training seeds: {', '.join(s for s, _ in seeds)}. `{method}` loads s0 for `swarm-env run`",
        f"and every seed for a leaderboard (mean ± 95 % CI across seeds); `{method}:s1` one seed. Each `s<k>/`",
        "holds the model selected on validation seeds 500-549 (`policy.safetensors` + `policy.json`: tensors and",
        "JSON, nothing unpickled) and the run's records (`config.json`, `versions.json`, `summary.json`,",
        "`eval.csv`, `train.csv` (SB3's `progress.csv` for an SB3 run), `learning_curve.png`, and `pretrain.csv`",
        "where there was a DAgger warm start).",
        "",
        "## How each seed was trained",
        "",
        "Run from the repository root at the commit shown, with `OPENBLAS_NUM_THREADS=1`, two or three runs side by",
        "side on the project's 2-core machine (`--runs-dir`/`--run-name` only name the output directory):",
        "",
    ]
    for name, d in seeds:
        versions = _read_json(d / "versions.json")
        lines += [f"* **{name}** (commit `{str(versions.get('git_commit'))[:10]}`, git_dirty "
                  f"{str(versions.get('git_dirty')).lower()}):", "", "  ```bash",
                  f"  {training_command(versions)}", "  ```", ""]
    lines += [
        "## Cost and selected models",
        "",
        "| seed | agent-steps | wall (s) | warm start (s) | rollouts (s) | updates (s) | validation (s) "
        "| agent-steps/s | selected at | formation error (m) | collisions / ep |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for name, d in seeds:
        summary = _read_json(d / "summary.json")
        # SB3 logs no split of its wall time: only the total and the rate.
        t = None if is_sb3_run(d) else time_breakdown(d)
        parts = (f"{t['pretrain']:.0f} | {t['rollout']:.0f} | {t['update']:.0f} | {t['validation']:.0f}"
                 if t else "- | - | - | -")
        best = selected(d)
        # Selection can keep the starting point (the warm start, or a residual's near-zero correction).
        at = "0 (the start)" if best["agent_steps"] == 0 else f"{best['agent_steps']:,}"
        lines.append(
            f"| {name} | {summary['agent_steps']:,} | {float(summary['wall_s']):.0f} | {parts} "
            f"| {summary['steps_per_s']:,.0f} | {at} "
            f"| {best['formation_error']:.3f} ± {best['formation_error_ci95']:.3f} "
            f"| {best['collisions']:.2f} ± {best['collisions_ci95']:.2f} |")
    lines += [
        "",
        "Agent-steps/s count training steps over the wall time after the warm start (validation included);",
        "rollouts = stepping the env copies and the actor, updates = the PPO epochs (`fan_dagger`: the fits after",
        "each round), validation = the 50-episode evaluations every `eval_every` agent-steps (`fan_dagger`: every round) (the rest of the wall time; `-`: an SB3 run,",
        "whose log does not split it, `progress.csv` is SB3's own). The",
        "last two columns are the selected model on the 50 validation worlds (mean ± 95 % CI); the test figures",
        "(seeds 1000-1049, never used for selection) are in [docs/baselines.md](../../../docs/baselines.md).",
        "Each seed's `learning_curve.png` plots its `eval.csv`.",
        "",
    ]
    readme = method_dir / "README.md"
    tmp = readme.with_suffix(".md.tmp")
    tmp.write_text("\n".join(lines))
    tmp.replace(readme)
    return readme


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(formatter_class=DefaultsHelpFormatter, prog="swarm-env ship", description=__doc__.split("\n\n")[0])
    parser.add_argument("run_dir", help="a finished run directory of swarm-env train mappo or train sb3")
    parser.add_argument("--method", required=True, help="checkpoint name, e.g. residual_vo")
    parser.add_argument("--seed", required=True, help="training-seed label, e.g. s0")
    parser.add_argument("--description", default="", help="one paragraph for the README's head (default: the method's own)")
    parser.add_argument("--dest", type=Path, default=CHECKPOINTS, help="checkpoints directory")
    parser.add_argument("--allow-dirty", action="store_true", help="ship a run trained from a dirty tree")
    args = parser.parse_args(argv)
    try:
        target = ship_run(args.run_dir, args.method, args.seed, dest=args.dest, allow_dirty=args.allow_dirty)
        readme = write_method_readme(args.method, dest=args.dest, description=args.description)
    except ShipError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(target)
    print(readme)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
