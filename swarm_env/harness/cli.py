"""The ``swarm-env`` command line: ``list``, ``validate``, ``run``, ``bench``, ``evaluate``, and the
commands of the experts and baselines (``train``, ``bc``, ``demos``, ``ship``, ``curves``, ``convert``,
``reproduce``; see :data:`MODULE_COMMANDS`).

Exit codes: 0 success, 2 bad input (unknown scenario or policy, invalid
scenario file, bad option, a missing, corrupt or refused model file, an optional extra that is not
installed), 1 anything else.

``run`` and ``evaluate`` refuse model files that would be unpickled (SB3's ``model.zip``
without the ``policy.safetensors`` + ``policy.json`` beside it, ``vecnormalize.pkl``):
unpickling runs any code the file carries. ``--trust-pickle`` loads them anyway, for
files from a source you trust (see docs/baselines.md, "Model files and safety").
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import importlib
import math
import os
import shutil
import statistics
import sys
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

import swarm_env
from swarm_env.checks import DefaultsHelpFormatter
from swarm_env.env import SwarmEnv, env_kwargs_for
from swarm_env.extras import MissingExtraError, extra_for_module, missing_distributions, missing_extra_error
from swarm_env.harness import bench, recording
from swarm_env.harness.evaluation import evaluate
from swarm_env.harness.leaderboard import (
    Leaderboard,
    SweepInterrupted,
    default_seeds,
    parse_seeds,
    read_sweep,
    record_worst_videos,
    run_leaderboard,
    validate_inputs,
)
from swarm_env.harness.policies import (
    TRUST_PICKLE_ENV,
    PolicyError,
    UnknownPolicyError,
    policy_extra,
    policy_summary,
    registered_policies,
)
from swarm_env.harness.recording import ensure_new_recording_dir
from swarm_env.harness.suite import SUITES, Suite, get_suite, result_markdown, suite_result
from swarm_env.harness.video import VideoWriter
from swarm_env.jsonio import write_json
from swarm_env.limits import printable
from swarm_env.outputs import OutputError, atomic_write_text, check_target, write_error
from swarm_env.render import window_driver_missing
from swarm_env.scenario import ScenarioError
from swarm_env.scenarios.families import FAMILIES, generator_config, is_generated
from swarm_env.scenarios.generator import random_scenario
from swarm_env.scenarios.loader import list_scenarios, load_scenario


def _table(rows: list[list[str]], header: list[str]) -> str:
    widths = [max(len(str(x)) for x in col) for col in zip(header, *rows)]
    line = "  ".join(h.ljust(w) for h, w in zip(header, widths))
    sep = "  ".join("-" * w for w in widths)
    body = ["  ".join(str(x).rjust(w) if i else str(x).ljust(w) for i, (x, w) in enumerate(zip(r, widths))) for r in rows]
    return "\n".join([line, sep, *body])


def _fmt(x: Any, digits: int = 3) -> str:
    if x is None:
        return "-"
    if isinstance(x, float):
        return f"{x:.{digits}f}"
    return str(x)


def format_per_robot(episode: dict[str, Any]) -> str:
    """Paper-003-style per-robot table (Tables II-IV) of one episode's metrics."""
    header = ["robot", "avg v (m/s)", "avg w (rad/s)", "distance (m)", "time to target (s)", "formation err (m)", "collisions"]
    rows = [
        [
            r["robot"],
            _fmt(r["avg_linear_velocity"]),
            _fmt(r["avg_angular_velocity"]),
            _fmt(r["distance"]),
            _fmt(r["time_to_target"], 1),
            _fmt(r["formation_error"]),
            _fmt(r["collisions"]),
        ]
        for r in episode["per_robot"]
    ]
    return _table(rows, header)


def format_episode(episode: dict[str, Any]) -> str:
    c = episode["collisions"]
    settle = ", ".join(
        f"t={s['at']:g}s {s['shape']}: {_fmt(s['settle_time'], 1)}" for s in episode["settle_times"]
    ) or "-"
    return (
        f"seed {episode['seed']}: success={episode['success']} steps={episode['steps']} "
        f"sim_time={episode['sim_time']:.1f}s wall={episode['wall_time']:.2f}s  "
        f"collisions={c['total']} (robot {c['robot_robot']}, obstacle {c['robot_obstacle']}, "
        f"human {c['robot_human']}, wall {c['robot_wall']})  "
        f"formation error mean={episode['formation_error']['mean']:.3f} m max={episode['formation_error']['max']:.3f} m  "
        f"min separation={_fmt(episode['min_separation'])} m  settle: {settle}"
    )


def format_policy_stats(stats: dict[str, Any]) -> str:
    """A policy's ``stats()`` telemetry as a two-column table: one row per entry, a nested mapping
    on one row as ``key=value`` pairs, floats to 3 significant digits."""

    def value(x: Any) -> str:
        if isinstance(x, dict):
            return ", ".join(f"{k}={value(v)}" for k, v in x.items()) or "-"
        if isinstance(x, (list, tuple)):
            return "[" + ", ".join(value(v) for v in x) + "]"
        if isinstance(x, float):
            return f"{x:.3g}"
        return _fmt(x)

    rows = [("policy stat", "value")] + [(str(k), value(v)) for k, v in stats.items()]
    w = max(len(k) for k, _ in rows)
    rows.insert(1, ("-" * w, "-" * max(len(v) for _, v in rows)))
    return "\n".join(f"{k.ljust(w)}  {v}" for k, v in rows)


def _interactive() -> bool:
    """Progress bars only for a person at a terminal: not in pipes, logs or CI."""
    return sys.stderr.isatty() and not os.environ.get("CI")


def _print_scenario_error(exc: ScenarioError) -> None:
    for line in str(exc).splitlines():  # every problem found, one line each, the first ScenarioError.MAX_MESSAGE_LINES
        print(f"error: {line}", file=sys.stderr)


def cmd_list(args: argparse.Namespace) -> int:
    width = max(100, shutil.get_terminal_size((100, 24)).columns)  # one line per entry, cut to the terminal

    def row(name: str, text: str) -> None:
        print(printable(f"  {name:<19} {' '.join(text.split())}", width))

    print("scenarios:")
    for name in list_scenarios():
        if name == "random":
            desc = "procedural generator seeded by reset(seed); knobs as parallel_env keyword arguments"
        else:
            desc = load_scenario(name).description
        row(name, desc)
    print("families (random:<family>, or fixed scenarios grouped; swarm_env.scenarios.families):")
    for family in FAMILIES.values():
        where = "random:" + family.name if family.generated else " ".join(family.scenarios)
        row(family.name, f"[{family.difficulty}] ({where}) {family.description}")
    print("policies (swarm-env run --policy NAME[:ARG]; docs/baselines.md):")
    for name, target in registered_policies().items():
        declared = policy_extra(name)  # (distribution, extras): a third party's policy names its own package
        missing = missing_distributions(declared[1], declared[0]) if declared else []
        if declared and missing:
            row(name, f"(not installed: pip install '{declared[0]}[{declared[1]}]' for {', '.join(missing)}) {target}")
        else:
            row(name, policy_summary(name) or target)
    return 0


def cmd_validate(args: argparse.Namespace) -> int:
    status = 0
    for spec in args.files:
        try:
            if is_generated(spec):  # a generator, not a file: check that its configuration builds a world
                import numpy as np

                scn = random_scenario(np.random.default_rng(0), generator_config(spec, {}))
                print(f"ok: {spec} (the generator; seed 0 draws {scn.robots.count} followers, {len(scn.obstacles)} "
                      f"obstacles, {len(scn.humans)} humans, {len(scn.formations)} formations, dt={scn.world.dt:g}s)")
                continue
            scn = load_scenario(spec)
        except ScenarioError as exc:
            _print_scenario_error(exc)
            status = 2
            continue
        print(
            f"ok: {scn.name} ({scn.robots.count} followers, {scn.leader.kind} leader, {len(scn.obstacles)} obstacles, "
            f"{len(scn.humans)} humans, {len(scn.formations)} formations, dt={scn.world.dt:g}s, max_time={scn.world.max_time:g}s)"
        )
    return status


ENV_HELP = ("a SwarmEnv keyword argument or random-generator knob, the value read as YAML "
            "(e.g. n_followers=16, n_humans=[0,3], terminate_on_collision=true, reward=v0); repeatable")


def parse_env_item(item: str) -> tuple[str, Any]:
    """``"n_humans=[0,2]"`` -> ``("n_humans", [0, 2])`` (the value parsed as YAML); ``ValueError`` otherwise."""
    import yaml

    key, sep, value = item.partition("=")
    if not sep or not key.isidentifier():
        raise ValueError(f"--env expects KEY=VALUE (e.g. n_followers=4), got {item!r}")
    try:
        return key, yaml.safe_load(value)
    except yaml.YAMLError as exc:
        raise ValueError(f"--env {key}: the value is not valid YAML ({' '.join(str(exc).split())})") from None


def parse_env_items(items: Iterable[str]) -> dict[str, Any]:
    """``["n_followers=2", "n_humans=[0,2]"]`` -> keyword arguments (values parsed as YAML)."""
    return dict(parse_env_item(item) for item in items)


def cmd_run(args: argparse.Namespace) -> int:
    env_kwargs: dict[str, Any] = {"action_type": args.action_type, "max_cycles": args.max_cycles}
    try:
        env_kwargs.update(parse_env_items(args.env))
        probe = SwarmEnv(args.scenario, **env_kwargs)  # bad keyword arguments fail here, before any output
        max_frames = args.episodes * (probe.max_steps + 1)  # an episode renders at most its steps and the reset
        dt = probe.scenario.world.dt
        probe.close()
        if args.record:
            ensure_new_recording_dir(args.record)  # a RecordError (a ValueError) before any episode
        _check_outputs(args, args.json)  # an OutputError (a ValueError) before any episode
        if args.render == "human" and (why := window_driver_missing()):
            raise ValueError(f"--render human needs a display: {why}; write a video instead (--video FILE.mp4), "
                             "or set SDL_VIDEODRIVER=dummy to play with an unseen window on purpose")
    except ScenarioError:
        raise  # main() reports it
    except (TypeError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if args.render == "human":
        env_kwargs["render_mode"] = "human"
    writer = None
    on_frame = None
    bar: Any = None
    if args.video:
        from tqdm.auto import tqdm


        try:
            writer = VideoWriter(args.video, fps=args.fps, overwrite=args.overwrite)
        except ValueError as exc:  # a bad suffix or fps, or an OutputError: before any episode
            print(f"error: {exc}", file=sys.stderr)
            return 2
        # A long episode takes tens of seconds to play, render and encode: show progress, frame by frame.
        bar = tqdm(total=max_frames, desc=f"video {Path(args.video).name}", unit="frame", disable=not _interactive())

        def on_frame(frame: Any) -> None:
            writer.append(frame)
            bar.update()

    finished = False
    try:
        report = evaluate(
            args.scenario,
            args.policy,
            args.episodes,
            args.seed,
            env_kwargs=env_kwargs,
            on_frame=on_frame,
            progress=args.episodes > 1 and bar is None and _interactive(),
            record_dir=args.record,
        )
        finished = True
    finally:
        if bar is not None:
            bar.total = bar.n  # episodes that end early render fewer frames than the bound
            bar.set_postfix_str("encoding" if finished else "stopped")
            bar.refresh()
        if writer is not None:
            # a run that failed or was interrupted leaves no video: a truncated one would look like a short run
            writer.close() if finished else writer.abort()
        if bar is not None:
            bar.close()
    for ep in report["episodes"]:
        print(format_episode(ep))
        print(format_per_robot(ep))
        if "policy_stats" in ep:
            print(format_policy_stats(ep["policy_stats"]))
        print()
    s = report["summary"]
    print(
        f"summary over {s['episodes']} episode(s) of {report['policy']} on {report['scenario']}: "
        f"success rate {s['success_rate']['mean']:.2f}, collisions/episode {s['collisions']['mean']:.2f}, "
        f"formation error {s['formation_error']['mean']:.3f} m"
    )
    if args.json:
        _write_json(args.json, report, args.overwrite)
    if args.video:
        print(f"wrote {args.video} ({video_speed(args.fps, dt)})")
    if args.record:
        print(f"wrote {args.record} (swarm-env replay {args.record} --check)")
    return 0


def video_speed(fps: float, dt: float) -> str:
    """How a video of one frame per env step plays: ``"20 fps, one frame per 0.1 s step: 2x real time"``."""
    return f"{fps:g} fps, one frame per {dt:g} s step: {fps * dt:.3g}x real time"


#: The ``--fps`` help of every command that writes a video.
_FPS_HELP = "video frames per second; one frame per env step, so the video plays at fps x dt real time (20 at dt 0.1 s: 2x)"


def cmd_replay(args: argparse.Namespace) -> int:
    """Re-simulate recorded episodes (:mod:`swarm_env.harness.recording`); exit 1 at a divergence with ``--check``."""
    try:
        records = recording.load_recording(args.dir)
        # checks the suffix, --fps and the output path (OutputError) before any replay
        writer = VideoWriter(args.video, fps=args.fps, overwrite=args.overwrite) if args.video else None
    except (recording.RecordError, ScenarioError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    status = 0
    finished = False
    try:
        for rec in records:
            result = recording.replay(rec, on_frame=writer.append if writer else None, stop_at_divergence=args.check)
            print(format_episode(result.metrics))
            # the policy and scenario specs come from the record's meta.json: shown escaped, cut
            print(f"episode {rec.episode}: {printable(rec.policy, 200)} on {printable(rec.scenario_spec, 200)}, "
                  f"{result.steps} of {rec.steps} steps replayed, {result.digests_checked} digests checked")
            if result.divergence is not None:
                print(("" if args.check else "warning: ") + result.divergence.message(), file=sys.stderr)
                if args.check:
                    status = 1
                    break
            if args.check and result.digests_checked == 0:  # a check that compared nothing is no pass
                print(f"error: replay --check: episode {rec.episode}: no digests were checked (the record holds none "
                      "at the steps replayed)", file=sys.stderr)
                status = 2
                break
        finished = True
    finally:
        if writer is not None:
            writer.close() if finished else writer.abort()  # no truncated video under the final name
    if args.video:
        print(f"wrote {args.video} ({video_speed(args.fps, records[0].scenario.world.dt)})")
    return status


def cmd_bench(args: argparse.Namespace) -> int:
    progress = (lambda msg: print(msg, file=sys.stderr)) if not args.quiet else None
    try:
        _check_outputs(args, args.json, args.plot)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if args.vs == "vmas" or args.num_envs or args.followers:
        return _bench_batched(args, progress)
    results = bench.run_bench(args.scenario, steps=args.steps, repeats=args.repeats, seed=args.seed, peer=args.vs,
                              progress=progress)
    rows = [
        [r.name, str(r.agents), f"{r.median:,.0f}", f"{r.cpu_median:,.0f}", f"{r.agent_steps_per_s:,.0f}",
         f"{min(r.env_steps_per_s):,.0f}-{max(r.env_steps_per_s):,.0f}"]
        for r in results
    ]
    print(_table(rows, ["env", "agents", "env-steps/s (median)", "per CPU s (median)", "agent-steps/s", "range"]))
    if len(results) == 2:
        ours, peer = results
        # the two ran back to back in each repeat: the median of the per-repeat ratios cancels most load drift
        paired = statistics.median(a / b for a, b in zip(ours.env_steps_per_s, peer.env_steps_per_s))
        paired_cpu = statistics.median(a / b for a, b in zip(ours.cpu_env_steps_per_s, peer.cpu_env_steps_per_s))
        print(f"ratio swarm_env / {peer.name}: {ours.median / peer.median:.2f}x of the medians "
              f"(CPU time: {ours.cpu_median / peer.cpu_median:.2f}x); median of the per-repeat ratios "
              f"{paired:.2f}x (CPU time: {paired_cpu:.2f}x)")
    if args.json:
        doc = [{"name": r.name, "agents": r.agents, "env_steps_per_s": r.env_steps_per_s, "median": r.median,
                "cpu_env_steps_per_s": r.cpu_env_steps_per_s, "cpu_median": r.cpu_median} for r in results]
        _write_json(args.json, doc, args.overwrite)
    return 0


def _bench_batched(args: argparse.Namespace, progress: Any) -> int:
    """``bench --vs vmas`` / ``--num-envs`` / ``--followers``: agent-steps/s tables (and a plot)."""
    if args.vs == "mpe2":
        raise SystemExit("bench: --vs mpe2 compares single envs; drop --num-envs/--followers, or use --vs vmas")
    results = []
    if args.vs == "vmas" or args.num_envs:
        sizes = tuple(args.num_envs or bench.BATCH_SIZES)
        results += bench.run_batched_bench(sizes, repeats=args.repeats, seed=args.seed, peer=args.vs,
                                           n_procs=args.n_procs, progress=progress, worker_kernels=args.worker_kernels)
    if args.followers:
        results += bench.run_followers_bench(tuple(args.followers), repeats=args.repeats, seed=args.seed, progress=progress)
    rows = [[r.name, str(r.num_envs), str(r.agents), f"{r.median_wall:,.0f}",
             f"{r.median_cpu:,.0f}" if r.median_cpu == r.median_cpu else "n/a (workers)",
             f"{1e6 / r.median_wall:,.1f}"] for r in results]
    print(_table(rows, ["engine", "worlds M", "agents/world", "agent-steps/s (wall)", "agent-steps/s (CPU)",
                        "us per agent-step"]))
    peers = {r.num_envs: r for r in results if r.name.startswith("vmas")}
    for r in results:
        if r.name.startswith("swarm_env.vector.engine") and r.num_envs in peers:
            p = peers[r.num_envs]
            print(f"M={r.num_envs}: swarm_env / vmas = {r.median_wall / p.median_wall:.2f}x wall, "
                  f"{r.median_cpu / p.median_cpu:.2f}x CPU")
    if args.json:
        _write_json(args.json, [{"name": r.name, "num_envs": r.num_envs, "agents": r.agents, "wall": r.wall,
                                 "cpu": r.cpu} for r in results], args.overwrite)
    if args.plot:
        bench.plot_batched(results, args.plot, overwrite=args.overwrite)
        print(f"wrote {args.plot}")
    return 0


def _check_outputs(args: argparse.Namespace, *paths: str | None) -> None:
    """Refuse (``OutputError``, a ``ValueError``) an output file that the command could not write safely
    (:func:`swarm_env.outputs.check_target`): checked before any work, and again when it is written."""
    for path in paths:
        if path:
            check_target(path, overwrite=args.overwrite)


def _write_json(path: str, doc: Any, overwrite: bool) -> None:
    write_json(path, doc, overwrite=overwrite)  # strict JSON (a non-finite metric as null), atomic, no symlink followed
    print(f"wrote {path}")


def _warn_ignored_knobs(scenarios: list[str], env_kwargs: dict[str, Any]) -> None:
    """One warning line when generator knobs among the env options do not apply to some scenarios (a fixed
    scenario keeps its own world: :func:`~swarm_env.env.env_kwargs_for` drops them there)."""
    fixed = [s for s in scenarios if not is_generated(s)]
    knobs = sorted(set(env_kwargs) - set(env_kwargs_for(fixed[0], env_kwargs))) if fixed else []
    if knobs:
        print(f"warning: --env {', '.join(knobs)}: generator knobs apply to the generated scenarios only; ignored "
              f"for {', '.join(fixed)}", file=sys.stderr)


def cmd_evaluate(args: argparse.Namespace) -> int:
    """The leaderboard (:mod:`swarm_env.harness.leaderboard`); every input is checked before any episode runs.

    Exit codes: 0 done, 2 a bad input (one line), 130 Ctrl-C (the finished episodes are written to
    ``--out``, and ``--resume DIR`` finishes the sweep)."""
    try:
        if args.resume and args.out and Path(args.out) != Path(args.resume):
            raise ValueError("--resume DIR writes to DIR: drop --out, or give the same directory")
        out = args.resume or args.out
        stored = read_sweep(args.resume) if args.resume else None
        if stored is None and not args.policies:
            raise ValueError("--policies is required (unless --resume DIR, which takes the sweep from DIR/sweep.json)")
        suite, split = _suite_of(args, stored)
        # With --resume, what is not given comes from the sweep being finished; what is given must match it.
        policies: list[str] = args.policies or (stored or {})["policies"]
        scenarios: list[str] = args.scenarios or (stored["scenarios"] if stored else list_scenarios())
        env_given = args.action_type is not None or args.max_cycles is not None or args.env
        if suite is not None:
            scenarios = suite.scenarios()
            env_kwargs: dict[str, Any] = dict(suite.env_kwargs)
        elif stored is not None and not env_given:
            env_kwargs = dict(stored["env_kwargs"])
        else:
            env_kwargs = {"action_type": args.action_type or "continuous"}
            if args.max_cycles is not None:
                env_kwargs["max_cycles"] = args.max_cycles
            env_kwargs.update(parse_env_items(args.env))
        if args.videos and not out:
            raise ValueError("--videos needs --out DIR (the videos go to DIR/videos/)")
        validate_inputs(policies, scenarios, env_kwargs)  # names first: a typo is blamed, not the seeds naming it
        _warn_ignored_knobs(scenarios, env_kwargs)
        common = parse_seeds(args.seeds) if args.seeds is not None else None
        seeds: dict[str, list[int]] = {}
        for item in args.scenario_seeds or []:
            name, sep, text = item.partition("=")
            if not sep or not name:
                raise ValueError(f"--scenario-seeds expects SCENARIO=SEEDS (e.g. random=1000-1049), got {item!r}")
            if name not in scenarios:
                raise ValueError(f"--scenario-seeds names {name!r}, which is not among the scenarios {scenarios}")
            if name in seeds:
                raise ValueError(f"--scenario-seeds gives {name!r} twice")
            seeds[name] = parse_seeds(text)
    except ScenarioError:
        raise  # main() reports it (as it does UnknownPolicyError)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    for scenario in scenarios:
        if suite is not None:
            seeds[scenario] = suite.seeds(split)[scenario]
        if stored is not None and common is None and not args.scenario_seeds and scenario in stored["seeds"]:
            seeds.setdefault(scenario, list(stored["seeds"][scenario]))
        seeds.setdefault(scenario, list(common) if common is not None else default_seeds(scenario))

    try:
        board = run_leaderboard(
            policies, scenarios, seeds, env_kwargs=env_kwargs, workers=args.workers, progress=not args.quiet,
            backend=args.backend, ray_address=args.ray_address, out_dir=out, resume=bool(args.resume),
            overwrite=args.overwrite, episode_timeout=args.episode_timeout,
            suite=None if suite is None else suite.key(split),
        )
    except SweepInterrupted as exc:
        board = exc.board
        done = len(board.episodes) + len(board.failed)
        total = sum(len(r.seeds) for r in board.rows if r.members is None)  # played rows, not method aggregates
        where = "nothing written (no --out)"
        if out:
            board.write(out)  # the sweep's own files: replacing them is what the directory is for
            if suite is not None:
                _write_suite(board, suite, split, out)
            where = f"wrote {out}/leaderboard.md, .csv and .json; finish with: swarm-env evaluate --resume {out}"
        print(f"interrupted: {done} of {total} episodes done; {where}", file=sys.stderr)
        return 130
    except ValueError as exc:  # OutputError (results already there, a symlink), a --resume that does not match
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(board.to_markdown() if suite is None else result_markdown(suite_result(board, suite, split)))
    print(f"{len(board.episodes)} episodes in {board.wall_time:.1f} s (wall, {args.workers} worker(s))", file=sys.stderr)
    for entry in board.failed:
        print(f"warning: episode failed after {entry['attempts']} attempts: policy {entry['policy']!r} on "
              f"{entry['scenario']!r} seed {entry['seed']}: {entry['error']}", file=sys.stderr)
    for policy in board.policies:  # likely a bad argument (e.g. a missing model file) rather than a misfit
        reasons = {r.na_reason for r in board.rows if r.policy == policy}
        if None not in reasons:
            print(f"warning: policy {policy!r} ran on no scenario: {'; '.join(sorted(str(r) for r in reasons))}", file=sys.stderr)
    if out:
        try:
            for path in board.write(out) + ([] if suite is None else _write_suite(board, suite, split, out)):
                print(f"wrote {path}")
            if args.videos:
                for rec in record_worst_videos(board, Path(out) / "videos", fps=args.fps, progress=not args.quiet,
                                               records_dir=Path(out) / "records", overwrite=True, root=out,
                                               play_missing=bool(args.resume)):
                    print(f"wrote {rec.path}" + ("" if rec.reproduced else "  (its replay differs from the board's episode)"))
        except (OutputError, ValueError) as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
    return 0


def _suite_of(args: argparse.Namespace, stored: dict[str, Any] | None) -> tuple[Suite | None, str]:
    """The benchmark suite and split of ``evaluate --suite`` (or of the sweep ``--resume`` finishes), with
    the options a suite fixes refused; ``(None, "")`` for a plain leaderboard."""
    name, split = args.suite, args.split
    if stored is not None and "suite" in stored:
        held = stored["suite"]
        if name is not None and name != held.get("name"):
            raise ValueError(f"--suite {name} differs from the suite {held.get('name')!r} of the sweep being resumed")
        name, split = held.get("name"), split or held.get("split")
        suite = get_suite(str(name))
        if suite.version != held.get("version"):
            raise ValueError(f"{args.resume}: holds suite {name}/{held.get('version')}, this swarm-env has "
                             f"{suite.label}; finish it with the version that started it")
    if name is None:
        if args.split is not None:
            raise ValueError("--split needs --suite")
        return None, ""
    fixed = [flag for flag, given in (("--scenarios", args.scenarios), ("--seeds", args.seeds),
                                      ("--scenario-seeds", args.scenario_seeds), ("--env", args.env),
                                      ("--action-type", args.action_type), ("--max-cycles", args.max_cycles))
             if given]
    if fixed:
        raise ValueError(f"--suite fixes the scenarios, seeds and env options; drop {', '.join(fixed)}")
    return get_suite(name), split or "test"


def _write_suite(board: Leaderboard, suite: Suite, split: str, out: str) -> list[Path]:
    """``out/suite.json`` and ``out/suite.md`` (atomic, like the board's files)."""
    result = suite_result(board, suite, split)
    return [write_json(Path(out) / "suite.json", result, indent=1, root=out),
            atomic_write_text(Path(out) / "suite.md", result_markdown(result), root=out)]


OVERWRITE_HELP = ("replace output files that exist (without it they are refused); outputs are always written to a "
                  "temporary file and renamed, and a symlink at an output path is refused")

TRUST_PICKLE_HELP = ("load pickle-bearing model files (SB3 model.zip without policy.safetensors + policy.json, "
                     "vecnormalize.pkl): unpickling runs any code in the file, so only for files you trust "
                     f"(the same as {TRUST_PICKLE_ENV}=1)")


@contextlib.contextmanager
def _pickle_trust(on: bool) -> Iterator[None]:
    """Set :data:`~swarm_env.harness.policies.TRUST_PICKLE_ENV` while a command runs (its worker processes
    inherit it) and restore the previous value after, so an in-process ``main()`` leaves no trace."""
    if not on:
        yield
        return
    before = os.environ.get(TRUST_PICKLE_ENV)
    os.environ[TRUST_PICKLE_ENV] = "1"
    try:
        yield
    finally:
        if before is None:
            os.environ.pop(TRUST_PICKLE_ENV, None)
        else:
            os.environ[TRUST_PICKLE_ENV] = before


#: Commands run by a module's own ``main(argv)``, which gets the rest of the command line: that module's
#: parser owns the options (``swarm-env train mappo --help`` prints them), so none is repeated here.
#: ``(words) -> (module, help)``; each module also runs as ``python -m MODULE``. The modules are named,
#: not imported, here (as the policy registry names its entry points): ``swarm_env`` itself never imports
#: ``swarm_env_agents`` or ``swarm_env_baselines``.
MODULE_COMMANDS: dict[tuple[str, ...], tuple[str, str]] = {
    ("train", "mappo"): ("swarm_env_baselines.mappo", "MAPPO / IPPO (--critic local), our PyTorch PPO: the shipped methods"),
    ("train", "sac"): ("swarm_env_baselines.sac", "shared-parameter SAC on the batched engine (policy isac:RUN)"),
    ("train", "fan_dagger"): ("swarm_env_baselines.fan_dagger", "DAgger of obs_expert into a network scoring its avoidance fan (policy fan_dagger)"),
    ("train", "sb3"): ("swarm_env_baselines.train", "stable-baselines3 PPO / SAC / A2C / TD3 with parameter sharing"),
    ("train", "rllib"): ("swarm_env_baselines.rllib_train", "RLlib's PPO on Ray, one machine or a cluster (extras rl, ray)"),
    ("bc",): ("swarm_env_baselines.bc", "behaviour cloning (+ DAgger) of a scripted expert into PPO's policy network"),
    ("demos",): ("swarm_env_baselines.demos", "record a scripted expert's demonstrations (cached .npz)"),
    ("ship",): ("swarm_env_baselines.ship", "copy a finished `train mappo` or `train sb3` run into checkpoints/<method>/s<k>"),
    ("curves",): ("swarm_env_baselines.plots", "the shipped methods' learning curves in one figure"),
    ("convert",): ("swarm_env_baselines.convert", "write tensors + JSON beside an older SB3 run's pickles"),
    ("reproduce", "vo"): ("swarm_env_agents.vo_paper", "paper 003's experiments with the vo expert (docs/vo_expert.md)"),
    ("reproduce", "cbs_rrt"): ("swarm_env_agents.cbs_rrt.paper", "paper 000's experiment with the cbs_rrt expert (docs/cbs_rrt.md)"),
}

_GROUP_HELP = {
    "train": "train a learned policy: mappo (MAPPO/IPPO), sac (shared-parameter SAC), sb3 (stable-baselines3) or rllib",
    "reproduce": "rerun a paper's experiments with its expert and write its report: vo (paper 003), cbs_rrt (paper 000)",
}


def _group_usage(group: str) -> str:
    subs = {words[1]: text for words, (_, text) in MODULE_COMMANDS.items() if words[0] == group and len(words) > 1}
    lines = [f"usage: swarm-env {group} {{{','.join(subs)}}} [OPTIONS]", "", _GROUP_HELP[group], ""]
    lines += [f"  {name:<10} {text}" for name, text in subs.items()]
    lines += ["", f"swarm-env {group} NAME --help lists NAME's options."]
    return "\n".join(lines)


def run_module_command(argv: list[str]) -> int:
    """Run the :data:`MODULE_COMMANDS` entry that ``argv`` starts with, passing it the rest of ``argv``.

    ``argv[0]`` must be a command word of the table. A group (``train``, ``reproduce``) without a known
    second word prints its usage (exit 0 for ``--help``/``-h``, else 2). The module's ``main`` returns the
    exit code (its argparse exits on ``--help`` or a bad option, as usual).
    """
    for words, (module, _) in MODULE_COMMANDS.items():
        if tuple(argv[: len(words)]) == words:
            return int(importlib.import_module(module).main(argv[len(words):]) or 0)
    group = argv[0]
    asked = argv[1:2] in (["-h"], ["--help"])
    if not asked:
        got = f"unknown {group} command {argv[1]!r}" if len(argv) > 1 else f"{group} needs a command"
        print(f"error: {got}", file=sys.stderr)
    print(_group_usage(group), file=sys.stdout if asked else sys.stderr)
    return 0 if asked else 2


def _counted(minimum: int) -> Callable[[str], int]:
    """An argparse type: an integer ``>= minimum`` (a usage error, exit 2, otherwise)."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"expected an integer >= {minimum}, got {value}")
        return value
    parse.__name__ = "integer"
    return parse


def _positive_float(text: str) -> float:
    """An argparse type: a finite number > 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a finite number > 0, got {text}")
    return value


#: argparse types: a seed (numpy's seed sequences take integers >= 0), a count of at least one.
_SEED, _COUNT = _counted(0), _counted(1)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(formatter_class=DefaultsHelpFormatter, prog="swarm-env", description="Leader-follower swarm environment (PettingZoo + pymunk).")
    p.add_argument("--version", action="version", version=f"swarm-env {swarm_env.__version__}")
    sub = p.add_subparsers(dest="command", required=True)

    sub.add_parser("list", formatter_class=DefaultsHelpFormatter, help="list built-in scenarios and registered policies").set_defaults(func=cmd_list)

    v = sub.add_parser("validate", formatter_class=DefaultsHelpFormatter, help="check scenario files; print every error found and exit 2 if there is one")
    v.add_argument("files", nargs="+", help="YAML files, built-in scenario names or 'random'")
    v.set_defaults(func=cmd_validate)

    r = sub.add_parser("run", formatter_class=DefaultsHelpFormatter, help="run a policy on a scenario and report metrics")
    r.add_argument("--scenario", default="paper_vo_0", help="built-in name, 'random', or a YAML path")
    r.add_argument("--policy", default="random", help="registered policy name, optionally name:ARG")
    r.add_argument("--episodes", type=_COUNT, default=1)
    r.add_argument("--seed", type=_SEED, default=0, help="seed of the first episode (>= 0); episode k uses seed+k")
    r.add_argument("--action-type", choices=["continuous", "discrete"], default="continuous")
    r.add_argument("--max-cycles", type=_COUNT, help="stop each episode after this many steps (default: max_time)")
    r.add_argument("--env", action="append", default=[], metavar="KEY=VALUE", help=ENV_HELP)
    r.add_argument("--json", help="write {scenario, policy, episodes, summary} to this file")
    r.add_argument("--video", help="write an .mp4 (or .gif) of all episodes to this file")
    r.add_argument("--fps", type=_positive_float, default=20.0, help=_FPS_HELP)
    r.add_argument("--render", choices=["human"], help="show a pygame window")
    r.add_argument("--record", metavar="DIR", help="record every episode to DIR/episode_<k>/ (swarm-env replay DIR)")
    r.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
    r.add_argument("--trust-pickle", action="store_true", help=TRUST_PICKLE_HELP)
    r.set_defaults(func=cmd_run)

    rp = sub.add_parser("replay", formatter_class=DefaultsHelpFormatter, help="re-simulate recorded episodes without the policy (run --record DIR)")
    rp.add_argument("dir", help="a recording directory (or one episode_<k> folder of it)")
    rp.add_argument("--video", help="write an .mp4 (or .gif) of the replayed episodes to this file")
    rp.add_argument("--fps", type=_positive_float, default=20.0, help=_FPS_HELP)
    rp.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
    rp.add_argument("--check", action="store_true",
                    help="stop at the first step whose state digest differs from the record and exit 1")
    rp.set_defaults(func=cmd_replay)

    b = sub.add_parser("bench", formatter_class=DefaultsHelpFormatter, help="env throughput with random actions (median of repeats)")
    b.add_argument("--scenario", default="paper_cbs_switch")
    b.add_argument("--steps", type=_COUNT, default=2000, help="env steps per repeat")
    b.add_argument("--repeats", type=_COUNT, default=5)
    b.add_argument("--seed", type=_SEED, default=0)
    b.add_argument("--vs", choices=["mpe2", "vmas"],
                   help="also run a peer in the same process, interleaved, and print the ratio (mpe2: one env; "
                        "vmas: the batched engine against VMAS navigation, for each --num-envs)")
    b.add_argument("--num-envs", type=_COUNT, nargs="+", metavar="M",
                   help="batched engine (swarm_env.vector.engine) at these batch sizes (default with --vs vmas: 1 8 64 256 1024)")
    b.add_argument("--followers", type=_COUNT, nargs="+", metavar="N", help="one env per team size N (cost per follower)")
    b.add_argument("--n-procs", type=_COUNT, default=1, help="worker processes of the batched engine (default 1)")
    b.add_argument("--worker-kernels", action="store_true",
                   help="with --n-procs > 1: the workers run the compiled kernels (faster, more memory)")
    b.add_argument("--plot", help="with --num-envs/--vs vmas: write agent-steps/s against M to this PNG")
    b.add_argument("--json", help="write the raw figures to this file")
    b.add_argument("--no-progress", "--quiet", dest="quiet", action="store_true",
                   help="no per-repeat progress on stderr (--quiet: the older spelling)")
    b.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
    b.set_defaults(func=cmd_bench)

    e = sub.add_parser("evaluate", formatter_class=DefaultsHelpFormatter,
        help="leaderboard: policies x scenarios x seeds -> Markdown/CSV/JSON tables (+ worst-episode videos)",
        description="Run every policy on every scenario for its seeds through one evaluation path and print a "
        "Markdown table of mean ± 95 % CI of success, collisions, formation error, settle time, episode time and "
        "policy time. Seeds: --seeds applies to every scenario not named in --scenario-seeds; without --seeds a "
        "fixed scenario gets seeds 0-4 (it is deterministic up to the policy's randomness) and 'random' gets the "
        "held-out seeds 1000-1049.",
    )
    e.add_argument("--policies", nargs="+", metavar="SPEC",
                   help="registered policy names, optionally name:ARG (e.g. vo cbs_rrt random ppo:runs/x/model.zip); "
                   "required unless --resume")
    e.add_argument("--scenarios", nargs="+", default=None, metavar="SCENARIO",
                   help="built-in names, 'random' or YAML paths (default: every built-in scenario and random)")
    e.add_argument("--seeds", metavar="SEEDS", help="seeds of every scenario: '0-9', '3' or '0,5,7' (mixes like '0-4,9' too)")
    e.add_argument("--scenario-seeds", nargs="+", metavar="SCENARIO=SEEDS",
                   help="per-scenario seeds overriding --seeds, e.g. random=1000-1049 paper_vo_0=0-2")
    e.add_argument("--suite", choices=sorted(SUITES), help="a benchmark suite (docs/benchmark.md): its families, "
                   "seeds and env options instead of --scenarios/--seeds/--env; writes DIR/suite.json and suite.md "
                   "beside the leaderboard")
    e.add_argument("--split", choices=["validation", "test"], help="with --suite: which seeds (default: test)")
    e.add_argument("--workers", type=_COUNT, default=1, help="processes running (policy, scenario) jobs in parallel "
                   "(with --backend ray and no --ray-address: the local Ray instance's CPUs)")
    e.add_argument("--backend", choices=["local", "ray"], default="local",
                   help="local: this machine's process pool; ray: Ray tasks (pip install 'swarm-env[ray]'), the same "
                   "results and the same fault handling")
    e.add_argument("--ray-address", help="with --backend ray: join this cluster ('auto', 'HOST:6379', 'ray://HOST:10001') "
                   "instead of starting a local Ray instance")
    e.add_argument("--action-type", choices=["continuous", "discrete"], default=None, help="default: continuous")
    e.add_argument("--max-cycles", type=_COUNT, help="stop each episode after this many steps (default: max_time)")
    e.add_argument("--env", action="append", default=[], metavar="KEY=VALUE",
                   help=ENV_HELP + "; generator knobs apply to the random scenario only")
    e.add_argument("--out", metavar="DIR", help="write DIR/leaderboard.md, .csv and .json; every finished episode is "
                   "streamed to DIR/episodes.jsonl as it ends (the sweep's inputs in DIR/sweep.json). A DIR that "
                   "already holds results needs --overwrite or --resume")
    e.add_argument("--resume", metavar="DIR", help="finish the interrupted sweep in DIR: play only the episodes "
                   "DIR/episodes.jsonl lacks (the policies, scenarios, seeds and env options come from DIR/sweep.json; "
                   "any given must match)")
    e.add_argument("--overwrite", action="store_true", help="replace the results already in --out DIR")
    e.add_argument("--episode-timeout", type=_positive_float, metavar="SECONDS",
                   help="with --workers >= 2 or --backend ray: kill a worker whose episode runs longer (on Ray: "
                   "cancel its task), retry the episode once, then count it as failed (default: 60 + 0.1 s per step "
                   "of the longest episode)")
    e.add_argument("--videos", action="store_true", help="also write DIR/videos/<policy>__<scenario>__seed<k>.mp4 "
                   "of each policy's worst episode per scenario (most collisions, then failure, then formation error), "
                   "replayed from its record, saved as DIR/records/<policy>__<scenario>__seed<k>/")
    e.add_argument("--fps", type=_positive_float, default=20.0, help=_FPS_HELP)
    e.add_argument("--no-progress", "--quiet", dest="quiet", action="store_true",
                   help="no progress bars (--quiet: the older spelling)")
    e.add_argument("--trust-pickle", action="store_true", help=TRUST_PICKLE_HELP)
    e.set_defaults(func=cmd_evaluate)

    # Listed for --help only: main() hands these command lines to their modules before parsing.
    for word in dict.fromkeys(words[0] for words in MODULE_COMMANDS):
        _, text = MODULE_COMMANDS.get((word,), ("", _GROUP_HELP.get(word, "")))
        sub.add_parser(word, formatter_class=DefaultsHelpFormatter, help=text, add_help=False)
    return p


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        if argv and argv[0] in {words[0] for words in MODULE_COMMANDS}:
            return run_module_command(argv)
        return _main(argv)
    except MissingExtraError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # Ctrl-C outside a command's own handling: one line, the shell's code for SIGINT
        print("interrupted", file=sys.stderr)
        return 130
    except ImportError as exc:  # an optional dependency imported where it is used, e.g. by a training command
        extra = extra_for_module(exc.name)
        if extra is None:
            raise
        command = " ".join(argv[:2]) if argv else "this command"
        print(f"error: {missing_extra_error(extra, f'swarm-env {command}', str(exc))}", file=sys.stderr)
        return 2


def _main(argv: list[str]) -> int:
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as exc:  # a usage error (argparse printed it; exit 2) or --help (0): the code, not a raise
        return exc.code if isinstance(exc.code, int) else 2
    try:
        with _pickle_trust(getattr(args, "trust_pickle", False)):
            return int(args.func(args))
    except ScenarioError as exc:
        _print_scenario_error(exc)
        return 2
    except UnknownPolicyError as exc:
        print(f"error: {exc.args[0] if exc.args else exc}", file=sys.stderr)
        return 2
    except PolicyError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except OutputError as exc:  # an unsafe or failed write (a full disk): every writer's one-line error
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        if exc.errno not in _DISK_ERRNOS:
            raise
        # a write outside swarm_env.outputs (a library's own file) on a full disk: one line, not a traceback
        print(f"error: {write_error(exc.filename or '<output>', exc, 'the command stopped')}", file=sys.stderr)
        return 2


#: The errors of a full disk or a file-size limit: reported in one line wherever the write happened.
_DISK_ERRNOS = {errno.ENOSPC, errno.EFBIG, getattr(errno, "EDQUOT", errno.ENOSPC), errno.EIO}


if __name__ == "__main__":
    sys.exit(main())
