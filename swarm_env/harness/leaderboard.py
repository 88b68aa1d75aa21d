"""One leaderboard: policies x scenarios x seeds through the one evaluation path.

:func:`run_leaderboard` plays every policy spec (``vo``, ``cbs_rrt``,
``random``, ``ppo:PATH``, ... anything :func:`swarm_env.harness.policies.load_policy`
builds) on every scenario for that scenario's seeds, each episode through
:func:`swarm_env.harness.episode.run_episode`, and returns a :class:`Leaderboard`:
one :class:`Row` per policy x scenario with the mean and 95 % confidence
interval of the headline metrics, plus every episode's metrics.

.. code-block:: python

    board = run_leaderboard(["random", "vo"], ["paper_vo_0", "random"],
                            {"paper_vo_0": range(5), "random": range(1000, 1050)}, workers=2)
    print(board.to_markdown())
    board.to_csv("leaderboard.csv"); board.to_json("leaderboard.json")
    record_worst_videos(board, "videos", records_dir="records")

Seeds. A fixed scenario (``paper_vo_0``, ...) is deterministic: only a
stochastic policy makes its seeds differ, so few seeds suffice
(:data:`DEFAULT_FIXED_SEEDS`). ``random`` draws a new world per seed; its
default seeds (:data:`DEFAULT_RANDOM_SEEDS`, 1000 and up) are held out from
training, which uses seeds below 1000.

Jobs. Each (policy, scenario) pair is one job: one fresh env and one fresh
policy that play the job's seeds in order. ``workers > 1`` runs jobs in a
process pool (``spawn``: no state inherited from the parent), which gives the
same metrics as ``workers=1`` because a job does not depend on where it runs;
only the timings (``wall_time``, ``policy_time``, ``policy_stats``) differ.

Faults. In the pool and on Ray a worker that dies or whose episode exceeds the per-episode timeout
costs only that episode (tried once more, then counted in :attr:`Row.failed` and listed in
:attr:`Leaderboard.failed`); with ``out_dir`` every finished episode is streamed to
``out_dir/episodes.jsonl``, ``resume=True`` plays only the missing ones, and Ctrl-C raises
:class:`SweepInterrupted` carrying the board of what is done (see :func:`run_leaderboard`).

Records. Every episode is recorded as it is played (:mod:`swarm_env.harness.recording`: its actions
and state digests; the metrics are those of an unrecorded run), and each job keeps the record
of its worst episode (:func:`badness`) in :attr:`Leaderboard.records`, so that
:func:`record_worst_videos` renders the worst episodes by replaying their records, without
running a policy again.

A policy that refuses a scenario (a :class:`~swarm_env.harness.policies.PolicyError`,
e.g. ``vo`` with ``action_type="discrete"``) gives a row marked ``n/a: reason``. A bad
model file (:class:`~swarm_env.harness.policies.ModelFileError`: missing, corrupt, of another
algorithm, or a pickle without the opt-in) is no misfit: it stops the leaderboard.

Training seeds. A learned method shipped with several training seeds (a factory with
``training_runs``, see :func:`swarm_env.harness.policies.training_runs`) is named by its bare name,
e.g. ``mappo``: each seed (``mappo:s0``, ``mappo:s1``, ...) is played as its own job and
gets its own *member* row (``Row.method`` names the method), and the method row aggregates
them: per metric, the mean of the seeds' means with a Student-t 95 % interval across
seeds (:func:`aggregate_training_seeds`). The Markdown table shows the method row; the CSV
and JSON hold both.
"""

from __future__ import annotations

import contextlib
import csv
import hashlib
import json
import multiprocessing
import os
import re
import time
import warnings
from collections.abc import Callable, Generator, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import numpy as np

from swarm_env._compat import add_note
from swarm_env.checks import did_you_mean
from swarm_env.env import SwarmEnv, env_kwargs_for
from swarm_env.extras import require
from swarm_env.harness.evaluation import mean_ci95_t, summarize
from swarm_env.harness.policies import (
    TRUST_PICKLE_ENV,
    ModelFileError,
    PolicyError,
    UnknownPolicyError,
    acts_on,
    load_policy,
    pickle_trusted,
    registered_policies,
    training_runs,
)
from swarm_env.harness.provenance import provenance, provenance_line
from swarm_env.harness.recording import EpisodeRecord, load_episode, record_episode, replay, save_episode
from swarm_env.harness.video import VideoWriter
from swarm_env.jsonio import dumps, read_json, write_json
from swarm_env.limits import clip_repr
from swarm_env.outputs import (
    OutputError,
    append_line,
    atomic_write_bytes,
    atomic_write_text,
    directory_lock,
    ensure_dir,
)
from swarm_env.scenarios.families import is_generated

#: Seeds of a fixed scenario when none are given (deterministic up to the policy's own randomness).
DEFAULT_FIXED_SEEDS: tuple[int, ...] = tuple(range(0, 5))
#: Seeds of ``random`` when none are given: held out (training draws seeds below 1000).
DEFAULT_RANDOM_SEEDS: tuple[int, ...] = tuple(range(1000, 1050))

#: Fields of an episode's metrics that measure this machine, not the policy's behaviour.
TIMING_KEYS = ("wall_time", "policy_time", "policy_stats")


@dataclass(frozen=True)
class Metric:
    """One aggregated column: summary key, table header, decimals in the Markdown table."""

    key: str
    label: str
    digits: int
    in_markdown: bool = True


#: The leaderboard's columns, in order (keys of :func:`swarm_env.harness.evaluation.summarize`).
METRICS: tuple[Metric, ...] = (
    Metric("success_rate", "success", 2),
    Metric("collision_free_rate", "collision-free", 2),
    Metric("collisions", "collisions / ep", 2),
    Metric("formation_error", "formation error (m)", 3),
    Metric("settle_time", "settle time (s)", 1),
    Metric("hold_fraction", "held after settling", 2),
    Metric("sim_time", "episode time (s)", 1),
    Metric("policy_time", "policy time (s / ep)", 3),
    Metric("min_separation", "min separation (m)", 3, in_markdown=False),
)


# --------------------------------------------------------------------------- seeds
def parse_seeds(text: str) -> list[int]:
    """Parse ``"0-9"``, ``"3"``, ``"0,5,7"`` or mixes (``"0-4,10"``) into a list of seeds.

    Raises ``ValueError`` naming the bad part: seeds are non-negative integers, a range
    ``A-B`` needs ``A <= B``, and no seed may appear twice.
    """
    seeds: list[int] = []
    parts = [p.strip() for p in str(text).split(",")]
    if not any(parts):
        raise ValueError(f"empty seed list {text!r}; expected e.g. '0-9', '3' or '0,5,7'")
    for part in parts:
        m = re.fullmatch(r"(\d+)(?:\s*-\s*(\d+))?", part)
        if m is None:
            raise ValueError(f"bad seed range {part!r} in {text!r}; expected N, A-B or a comma list of them (e.g. '0-9', '0,5,7')")
        lo = int(m.group(1))
        hi = int(m.group(2)) if m.group(2) is not None else lo
        if hi < lo:
            raise ValueError(f"bad seed range {part!r} in {text!r}: the end is below the start")
        seeds.extend(range(lo, hi + 1))
    dup = sorted({s for s in seeds if seeds.count(s) > 1}) if len(set(seeds)) != len(seeds) else []
    if dup:
        raise ValueError(f"seed list {text!r} repeats seed(s) {dup}")
    return seeds


def format_seeds(seeds: Iterable[int]) -> str:
    """The inverse of :func:`parse_seeds`: ``[0, 1, 2, 5]`` -> ``"0-2,5"``."""
    seeds = list(seeds)
    runs: list[str] = []
    i = 0
    while i < len(seeds):
        j = i
        while j + 1 < len(seeds) and seeds[j + 1] == seeds[j] + 1:
            j += 1
        runs.append(str(seeds[i]) if i == j else f"{seeds[i]}-{seeds[j]}")
        i = j + 1
    return ",".join(runs)


def default_seeds(scenario: str) -> list[int]:
    """:data:`DEFAULT_RANDOM_SEEDS` for ``"random"`` and its families (``"random:<family>"``),
    :data:`DEFAULT_FIXED_SEEDS` for any fixed scenario."""
    return list(DEFAULT_RANDOM_SEEDS if is_generated(scenario) else DEFAULT_FIXED_SEEDS)


def resolve_seeds(
    scenarios: Sequence[str], seeds: Sequence[int] | Mapping[str, Sequence[int]] | None
) -> dict[str, list[int]]:
    """Seeds per scenario: ``None`` -> :func:`default_seeds`; a sequence -> the same for all;
    a mapping -> per scenario (it must name exactly the scenarios). Raises ``ValueError``."""
    if seeds is None:
        out = {s: default_seeds(s) for s in scenarios}
    elif isinstance(seeds, Mapping):
        missing = [s for s in scenarios if s not in seeds]
        extra = [s for s in seeds if s not in scenarios]
        if missing or extra:
            raise ValueError(
                f"seeds per scenario must name exactly the scenarios {list(scenarios)}; "
                f"missing {missing}, not evaluated {extra}"
            )
        out = {s: list(seeds[s]) for s in scenarios}
    else:
        out = {s: list(seeds) for s in scenarios}
    for scenario, values in out.items():
        if not values:
            raise ValueError(f"scenario {scenario!r}: no seeds")
        for v in values:
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 0:
                raise ValueError(f"scenario {scenario!r}: seeds must be non-negative ints, got {v!r}")
        if len(set(values)) != len(values):
            raise ValueError(f"scenario {scenario!r}: seed list repeats a seed")
        out[scenario] = [int(v) for v in values]
    return out


# --------------------------------------------------------------------------- validation
def validate_inputs(policies: Sequence[str], scenarios: Sequence[str], env_kwargs: Mapping[str, Any] | None = None) -> None:
    """Check every policy name and scenario before any episode runs.

    Raises :class:`~swarm_env.harness.policies.UnknownPolicyError` for an unregistered policy name
    (the part before ``:``), :class:`~swarm_env.scenario.ScenarioError` for an unknown or
    invalid scenario, and ``ValueError`` for an empty or repeated list entry or env arguments
    the env rejects. A policy's *argument* and its fit to each env are checked when its job
    starts (a refusal becomes an ``n/a`` row).
    """
    for kind, items in (("policies", policies), ("scenarios", scenarios)):
        if isinstance(items, str):
            raise ValueError(f"{kind} must be a list of strings, got the string {items!r}")
        if not items:
            raise ValueError(f"no {kind} to evaluate")
        repeated = sorted({x for x in items if list(items).count(x) > 1})
        if repeated:
            raise ValueError(f"{kind} listed more than once: {repeated}")
    known = registered_policies()
    for spec in policies:
        if not isinstance(spec, str):
            raise ValueError(f"policy specs must be strings like 'vo' or 'ppo:PATH', got {spec!r}")
        name = spec.partition(":")[0]
        if name not in known:
            raise UnknownPolicyError(f"unknown policy {name!r}{did_you_mean(name, known)}; registered policies: "
                                     f"{', '.join(known)}")
    kwargs = dict(env_kwargs or {})
    if "render_mode" in kwargs:
        raise ValueError("env_kwargs must not set render_mode: episodes run headless; record_worst_videos renders")
    for scenario in scenarios:
        try:
            SwarmEnv(scenario, **env_kwargs_for(scenario, kwargs)).close()
        except TypeError as exc:  # e.g. random-generator knobs with a fixed scenario
            raise ValueError(f"scenario {scenario!r}: {exc}") from None


# --------------------------------------------------------------------------- running
@dataclass(frozen=True)
class _Job:
    policy: str
    scenario: str
    seeds: tuple[int, ...]
    env_kwargs: dict[str, Any]


#: ``on_episode(seed, metrics, record)``: one finished episode of a job.
_OnEpisode = Callable[[int, dict[str, Any], EpisodeRecord], None]


def _play_job(job: _Job) -> Generator[tuple[Any, ...], None, None]:
    """Play one (policy, scenario) job with one fresh env and policy, yielding ``("episode", seed, metrics,
    record)`` as each episode ends and then ``("done", na_reason)``: ``None``, or the reason the policy refuses
    the scenario (then no episode ran). A Python exception (a :class:`ModelFileError` included) propagates.

    These are the messages a pool worker sends and a Ray task puts on its queue, so every backend plays a job alike."""
    env = SwarmEnv(job.scenario, **env_kwargs_for(job.scenario, job.env_kwargs))
    try:
        try:
            policy = load_policy(job.policy, env)
        except ModelFileError:
            raise  # the same file fails on every scenario: a bad argument, reported as such
        except PolicyError as exc:
            yield ("done", str(exc))
            return
        # Some policies refuse an env in reset() (ValueError), not in their factory; probe once so
        # that this too gives an n/a row. run_episode resets both again with the same seed.
        env.reset(seed=job.seeds[0])
        try:
            policy.reset(env, job.seeds[0])
        except ValueError as exc:
            yield ("done", str(exc) if str(exc).startswith("policy ") else f"policy {job.policy!r}: {exc}")
            return
        ran = 0
        for seed in job.seeds:
            try:
                metrics, rec = record_episode(env, policy, seed, policy_spec=job.policy, scenario_spec=job.scenario)
            except PolicyError as exc:
                if ran:  # a refusal after some episodes ran is a fault, not a misfit
                    raise
                yield ("done", str(exc))
                return
            except Exception as exc:
                add_note(exc, f"while evaluating policy {job.policy!r} on scenario {job.scenario!r}, seed {seed}")
                raise
            ran += 1
            yield ("episode", seed, metrics, rec)
        yield ("done", None)
    finally:
        env.close()


def _run_job(job: _Job, on_episode: _OnEpisode) -> str | None:
    """:func:`_play_job` in this process, reporting each finished episode to ``on_episode`` as it ends; returns
    ``None``, or the reason the policy refuses the scenario (no episode ran)."""
    with contextlib.closing(_play_job(job)) as messages:  # closed (the env too) if on_episode raises
        for kind, *payload in messages:
            if kind == "done":
                return cast("str | None", payload[0])
            on_episode(*payload)
    raise AssertionError("_play_job ended without its 'done' message")  # pragma: no cover - it always sends one


# --------------------------------------------------------------------------- the sweep's bookkeeping
SWEEP_FILE = "sweep.json"
EPISODES_FILE = "episodes.jsonl"
SWEEP_FORMAT = "swarm_env.sweep/1"
#: Files of a leaderboard directory that mark it as holding results (``--overwrite`` or ``--resume`` needed).
RESULT_FILES = (SWEEP_FILE, EPISODES_FILE, "leaderboard.json", "leaderboard.csv", "leaderboard.md", "suite.json", "suite.md")
#: Attempts an episode gets when its worker dies or exceeds the episode timeout (the first try and one retry).
MAX_ATTEMPTS = 2
#: Seconds a new pool worker may take to start (import swarm-env) on top of the episode timeout.
STARTUP_GRACE = 120.0


def default_episode_timeout(max_steps: int) -> float:
    """The per-episode timeout (seconds) when none is given: ``60 + 0.1 * max_steps``. The slowest
    episodes of the shipped leaderboard take about 1 ms per step (``docs/leaderboard/random/leaderboard.json``),
    so this leaves a hundredfold margin per step plus a minute for loading a policy."""
    return 60.0 + 0.1 * max_steps


class SweepInterrupted(KeyboardInterrupt):
    """Ctrl-C during :func:`run_leaderboard`: ``board`` holds the episodes finished so far (the
    rows of unfinished jobs count their missing episodes as ``pending``)."""

    def __init__(self, board: Leaderboard) -> None:
        super().__init__("interrupted")
        self.board = board


class _Sweep:
    """What is done: finished and failed episodes, refusals, the worst record of each job; each new
    result is appended to ``<out>/episodes.jsonl`` when there is an output directory."""

    def __init__(self, out: Path | None, tick: Callable[[int], None]) -> None:
        self.out = out
        self.tick = tick
        self.ok: dict[tuple[str, str, int], dict[str, Any]] = {}
        self.failed: dict[tuple[str, str, int], dict[str, Any]] = {}
        self.na: dict[tuple[str, str], str] = {}
        self.worst: dict[tuple[str, str], EpisodeRecord] = {}
        self.order: dict[tuple[str, str], list[int]] = {}  # each job's seeds, for the first-seed tie rule

    def _stream(self, entry: dict[str, Any]) -> None:
        if self.out is not None:
            append_line(self.out / EPISODES_FILE, dumps(entry, indent=None), root=self.out)

    def episode(self, job: _Job, seed: int, metrics: dict[str, Any], rec: EpisodeRecord | None) -> None:
        self.ok[(job.policy, job.scenario, seed)] = metrics
        self._stream({"policy": job.policy, "scenario": job.scenario, "seed": seed, "status": "ok", "metrics": metrics})
        if rec is not None:
            key = (job.policy, job.scenario)
            old = self.worst.get(key)
            seeds = self.order[key]
            # strictly worse, or as bad and an earlier seed: the first seed on ties, whatever order episodes came in
            if old is None or badness(metrics) > badness(old.metrics) or (
                    badness(metrics) == badness(old.metrics) and seeds.index(seed) < seeds.index(int(old.seed or 0))):
                self.worst[key] = rec
        self.tick(1)

    def fail(self, job: _Job, seed: int, error: str, attempts: int) -> None:
        entry = {"policy": job.policy, "scenario": job.scenario, "seed": seed, "status": "failed", "error": error,
                 "attempts": attempts}
        self.failed[(job.policy, job.scenario, seed)] = entry
        self._stream(entry)
        self.tick(1)

    def refuse(self, job: _Job, reason: str) -> None:
        self.na[(job.policy, job.scenario)] = reason
        self._stream({"policy": job.policy, "scenario": job.scenario, "status": "n/a", "reason": reason})

    def remaining(self, job: _Job) -> tuple[int, ...]:
        """The job's seeds with no result yet."""
        if (job.policy, job.scenario) in self.na:
            return ()
        return tuple(s for s in job.seeds
                     if (job.policy, job.scenario, s) not in self.ok and (job.policy, job.scenario, s) not in self.failed)

    def load(self, path: Path) -> None:
        """Read the results a previous run streamed to ``path``; a torn last line (a crash mid-write) is
        dropped from the file. A bad line elsewhere, or a second result for an episode (two runs wrote the
        file at once, or it was edited), is a ``ValueError`` naming the file and the line numbers."""
        if not path.is_file():
            return
        data = path.read_bytes()
        lines = data.split(b"\n")
        good_until = 0
        first_line: dict[tuple[Any, ...], int] = {}
        for i, raw in enumerate(lines):
            if not raw.strip():
                good_until += len(raw) + (1 if i < len(lines) - 1 else 0)
                continue
            try:
                entry = _result_entry(json.loads(raw))
            except ValueError as exc:
                if i == len(lines) - 1:  # the torn last line of a killed run: drop it
                    break
                raise ValueError(f"{path}: line {i + 1}: not a result line ({exc})") from None
            key = (entry["policy"], entry["scenario"])
            episode = key if entry["status"] == "n/a" else key + (entry["seed"],)
            if episode in first_line:
                raise ValueError(f"{path}: line {i + 1}: a second result for {' '.join(map(str, episode))} (the first is "
                                 f"on line {first_line[episode]}); two runs wrote this sweep at once, or the file was "
                                 "edited: keep one of the two lines")
            first_line[episode] = i + 1
            if entry["status"] == "n/a":
                self.na[key] = entry["reason"]
            elif entry["status"] == "ok":
                self.ok[key + (entry["seed"],)] = entry["metrics"]
            else:
                self.failed[key + (entry["seed"],)] = entry
            good_until += len(raw) + (1 if i < len(lines) - 1 else 0)
        if good_until < len(data):
            atomic_write_bytes(path, data[:good_until], root=path.parent)


def _result_entry(entry: Any) -> dict[str, Any]:
    """``entry`` (one parsed line of ``episodes.jsonl``) once its fields have the types :class:`_Sweep` writes,
    else a ``ValueError`` saying which field is wrong."""
    if not isinstance(entry, dict) or entry.get("status") not in ("ok", "failed", "n/a"):
        raise ValueError("not an episode entry: expected an object with status 'ok', 'failed' or 'n/a'")
    by_status: dict[str, dict[str, type]] = {"ok": {"seed": int, "metrics": dict}, "failed": {"seed": int, "error": str},
                                             "n/a": {"reason": str}}
    fields = {"policy": str, "scenario": str, **by_status[entry["status"]]}
    for name, kind in fields.items():
        value = entry.get(name)
        if not isinstance(value, kind) or isinstance(value, bool):
            raise ValueError(f"{name}: expected {'an integer' if kind is int else 'a ' + kind.__name__}, "
                             f"got {clip_repr(value)}")
    return entry


def _sweep_spec(policies: Sequence[str], scenarios: Sequence[str], seed_map: Mapping[str, list[int]],
                env_kwargs: Mapping[str, Any], suite: Mapping[str, Any] | None = None) -> dict[str, Any]:
    # what defines the episodes of a sweep (workers, timeouts and the backend do not change them), and the
    # benchmark suite they make up, if any (swarm_env.harness.suite)
    spec = {"format": SWEEP_FORMAT, "policies": list(policies), "scenarios": list(scenarios), "seeds": dict(seed_map),
            "env_kwargs": dict(env_kwargs)}
    if suite is not None:
        spec["suite"] = dict(suite)
    return json.loads(dumps(spec, indent=None))


def read_sweep(directory: str | os.PathLike[str]) -> dict[str, Any]:
    """The sweep spec stored in ``directory/sweep.json`` (policies, scenarios, seeds, env_kwargs), or a
    ``ValueError`` naming the file: missing (not a sweep directory), unreadable, or of another format."""
    path = Path(directory) / SWEEP_FILE
    if not path.is_file():
        raise ValueError(f"{path}: missing; --resume needs a directory an earlier 'swarm-env evaluate --out' wrote")
    try:
        spec = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path}: not readable JSON ({exc})") from None
    if not isinstance(spec, dict) or spec.get("format") != SWEEP_FORMAT:
        raise ValueError(f"{path}: format: expected {SWEEP_FORMAT!r}, got {spec.get('format') if isinstance(spec, dict) else spec!r}")
    for key in ("policies", "scenarios", "seeds", "env_kwargs"):
        if key not in spec:
            raise ValueError(f"{path}: missing key {key!r}")
    return spec


def _prepare_out(out: Path, spec: dict[str, Any], resume: bool, overwrite: bool) -> None:
    """Make ``out`` ready for streaming: a new sweep (refusing old results unless ``overwrite``) or, with
    ``resume``, the same sweep as the one stored there."""
    if resume:
        stored = read_sweep(out)
        for key in ("policies", "scenarios", "seeds", "env_kwargs", "suite"):
            if stored.get(key) != spec.get(key):
                raise ValueError(f"{out / SWEEP_FILE}: {key} {stored.get(key)!r} differ from this command's {spec.get(key)!r}; "
                                 "--resume finishes the same sweep (drop the differing options or use another --out)")
        return
    ensure_dir(out)
    found = [name for name in RESULT_FILES if (out / name).exists() or (out / name).is_symlink()]
    if found and not overwrite:
        raise OutputError(f"{out}: holds results ({', '.join(found)}); pass --overwrite to start again "
                          f"or --resume {out} to finish that sweep")
    atomic_write_bytes(out / EPISODES_FILE, b"", root=out)  # a new sweep starts from no episodes
    write_json(out / SWEEP_FILE, spec, indent=1, root=out)


# --------------------------------------------------------------------------- the local process pool
def _worker_main(conn: Any) -> None:
    """A pool worker: play the jobs it is sent, streaming ``("episode", seed, metrics, record)`` and then
    ``("done", na_reason)`` back, or ``("raise", exception)``; ``None`` stops it."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle: it stops the workers
    while True:
        job = conn.recv()
        if job is None:
            return
        conn.send(("started",))  # the episode timeout counts from here, not from the worker's (slow) start-up
        try:
            reason = _run_job(job, lambda seed, metrics, rec: conn.send(("episode", seed, metrics, rec)))
            conn.send(("done", reason))
        except Exception as exc:  # noqa: BLE001 - carried to the parent, which raises it
            try:
                conn.send(("raise", exc))
            except Exception:  # noqa: BLE001 - an exception that does not pickle travels as its text
                conn.send(("raise", RuntimeError(f"{type(exc).__name__}: {exc}")))


class _Slot:
    """One worker process, the job it plays and when its current episode started."""

    def __init__(self, ctx: Any) -> None:
        self.conn, child = ctx.Pipe()
        self.proc = ctx.Process(target=_worker_main, args=(child,), daemon=True)
        self.proc.start()
        child.close()
        self.job: _Job | None = None
        self.since = 0.0
        self.started = False  # whether the worker has begun its job (it may still be importing)

    def assign(self, job: _Job) -> None:
        self.job, self.since, self.started = job, time.monotonic(), False
        self.conn.send(job)

    def stop(self, kill: bool = False) -> None:
        if kill:
            self.proc.kill()
        else:
            try:
                self.conn.send(None)
            except OSError:
                pass
        self.proc.join(timeout=None if kill else 5)
        if self.proc.is_alive():
            self.proc.kill()
            self.proc.join()
        self.conn.close()


def _run_pool(jobs: list[_Job], workers: int, sweep: _Sweep, episode_timeout: float | None = None) -> None:
    """Play ``jobs`` on ``workers`` ``spawn`` processes (no state inherited from the parent), each job's
    episodes reported to ``sweep`` as they finish.

    A worker that dies (a crash, ``os._exit``, the OOM killer) or whose current episode runs longer
    than ``episode_timeout`` seconds (then it is killed) costs only that episode: it is tried again
    once in a fresh worker (:data:`MAX_ATTEMPTS`) and otherwise recorded as failed; the job goes on
    with its remaining seeds. A Python exception in a job stops the pool and is raised here.
    """
    from multiprocessing.connection import wait as wait_any

    ctx = multiprocessing.get_context("spawn")
    queue_: list[_Job] = list(jobs)
    attempts: dict[tuple[str, str, int], int] = {}
    slots = [_Slot(ctx) for _ in range(workers)]
    try:
        while queue_ or any(s.job is not None for s in slots):
            for slot in slots:
                if slot.job is None and queue_:
                    slot.assign(queue_.pop(0))
            busy = [s for s in slots if s.job is not None]
            ready = wait_any([s.conn for s in busy] + [s.proc.sentinel for s in busy], timeout=0.2)
            for i, slot in enumerate(slots):
                job = slot.job
                if job is None:
                    continue
                lost: str | None = None
                # dead first, then drain: whatever a dead worker sent before dying is in the pipe by now
                dead = not slot.proc.is_alive()
                for kind, *payload in _messages(slot.conn):
                    if kind == "started":
                        slot.started, slot.since = True, time.monotonic()
                    elif kind == "episode":
                        sweep.episode(job, *payload)
                        slot.since = time.monotonic()
                    elif kind == "done":
                        if payload[0] is not None:
                            sweep.refuse(job, payload[0])
                        slot.job = None
                    else:  # "raise": a Python exception in the job stops the leaderboard, as in this process
                        raise payload[0]
                if slot.job is None:
                    continue
                if dead:
                    slot.proc.join()
                    code = slot.proc.exitcode
                    lost = (f"worker killed by signal {-code}" if code is not None and code < 0
                            else f"worker exited with code {code}")
                elif episode_timeout is not None and time.monotonic() - slot.since > (
                        episode_timeout if slot.started else episode_timeout + STARTUP_GRACE):
                    lost = f"timed out after {episode_timeout:g} s (--episode-timeout)"
                if lost is None:
                    continue
                slot.stop(kill=True)
                slots[i] = _Slot(ctx)
                rest = _lose_episode(sweep, job, lost, attempts)
                if rest is not None:
                    queue_.insert(0, rest)
            del ready  # only a wake-up: every slot is polled above
    finally:
        for slot in slots:
            slot.stop(kill=slot.job is not None)


def _lose_episode(sweep: _Sweep, job: _Job, lost: str, attempts: dict[tuple[str, str, int], int]) -> _Job | None:
    """Count a lost attempt of the episode ``job`` was playing when its worker died or timed out (the first of
    its seeds without a result: a job plays its seeds in order), record it as failed after :data:`MAX_ATTEMPTS`
    attempts, and return the job of the seeds still to play (``None`` when none are left)."""
    left = sweep.remaining(job)
    if not left:
        return None
    seed = left[0]
    key = (job.policy, job.scenario, seed)
    attempts[key] = attempts.get(key, 0) + 1
    if attempts[key] >= MAX_ATTEMPTS:
        sweep.fail(job, seed, lost, attempts[key])
        left = left[1:]
    return _Job(job.policy, job.scenario, left, job.env_kwargs) if left else None


def _messages(conn: Any) -> list[tuple[Any, ...]]:
    """The messages waiting on a worker's pipe, up to its job's ``"done"``; fewer if the worker died mid-message
    (its exit is seen by the caller)."""
    got: list[tuple[Any, ...]] = []
    try:
        while conn.poll():
            got.append(conn.recv())
            if got[-1][0] in ("done", "raise"):
                break
    except (EOFError, OSError):
        pass
    return got


def _ray_job(job: _Job, task_id: int, queue: Any) -> None:
    """The Ray task of one job: puts ``(task_id, "started")`` on ``queue`` (a ``ray.util.queue.Queue``) once it
    runs (the episode timeout counts from here, not from a worker's start-up), then ``(task_id, *message)`` for
    each of :func:`_play_job`'s messages as it happens. ``put`` returns once the queue holds the message, so a
    task that has ended has delivered all of its messages."""
    queue.put((task_id, "started"))
    for message in _play_job(job):
        queue.put((task_id, *message))


@dataclass
class _RayTask:
    """A job's Ray task in flight: its job, when its current episode (or, before ``started``, the task) began,
    whether it has begun and whether its job's ``"done"`` came."""

    ref: Any
    job: _Job
    since: float
    started: bool = False
    done: bool = False


def _run_ray(jobs: list[_Job], address: str | None, num_cpus: int, sweep: _Sweep,
             episode_timeout: float | None = None) -> None:
    """Play ``jobs`` as Ray tasks, each job's episodes reported to ``sweep`` as they finish, with the local
    pool's fault rules (:func:`_run_pool`).

    ``address``: an existing cluster (``"auto"``, ``"ray://..."``, ``"HOST:PORT"``); ``None`` starts a local
    Ray instance with ``num_cpus`` CPUs (shut down at the end; an instance already running in this process is
    used and left running). Every node needs swarm-env (and the policies' extras) installed.

    A task whose worker dies (``WorkerCrashedError`` and Ray's other system errors: a lost node, the memory
    monitor) or whose current episode runs longer than ``episode_timeout`` seconds (then it is cancelled with
    ``ray.cancel(force=True)``, which kills its worker) costs only that episode: it is played again once in a
    new task (:data:`MAX_ATTEMPTS`; Ray's own retries are off) and otherwise recorded as failed; the job goes on
    with its remaining seeds. A task not started yet is given ``episode_timeout`` + :data:`STARTUP_GRACE`. At
    most as many tasks are in flight as the cluster has CPUs, so a submitted task starts at once. A Python
    exception in a job stops the sweep and is raised here (a :class:`ModelFileError` as itself). Whenever this
    returns or raises (Ctrl-C's ``KeyboardInterrupt`` included), the tasks still running are cancelled.
    """
    # One task per job, as in the pool, rather than one per episode: a job plays its seeds with one env and one
    # policy (_play_job: a policy file loaded and the refusal probe run once per job, not per episode; an episode
    # does not depend on the ones before it, so the metrics are the same either way), and the retry rule is the
    # pool's own (_lose_episode: the episode lost is the job's first without a result). The price: a sweep runs
    # at most one task per job at a time, as the pool does. The episodes come back through one
    # ray.util.queue.Queue (an actor) as they end rather than as a streaming generator's items, because Ray
    # Client (--ray-address ray://...) does not support streaming generators (ray-project/ray#43357).
    ray = require("ray", "ray", "--backend ray")
    started = not ray.is_initialized()
    if started:
        # The pickle opt-in travels to the workers (on a cluster they do not inherit this process's environment).
        trust = {"runtime_env": {"env_vars": {TRUST_PICKLE_ENV: "1"}}} if pickle_trusted() else {}
        if address is None:
            # address="local": a new instance, even where `ray start` left a cluster this would otherwise join
            ray.init(address="local", num_cpus=num_cpus, include_dashboard=False, log_to_driver=False, **trust)
        else:
            ray.init(address=address, log_to_driver=False, **trust)
    from ray.util.queue import Queue

    queue: Any = None
    running: dict[int, _RayTask] = {}  # task id -> its task
    try:
        from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

        # The queue holds no CPU (every CPU can run a job) and lives on the driver's node: a lost worker node
        # must cost only its episodes, never the results path (placed by Ray's default on the killed node, the
        # queue took the sweep down with it).
        here = NodeAffinitySchedulingStrategy(node_id=ray.get_runtime_context().get_node_id(), soft=False)
        queue = Queue(actor_options={"num_cpus": 0, "scheduling_strategy": here})
        task = ray.remote(num_cpus=1, max_retries=0)(_ray_job)
        capacity = max(1, int(ray.cluster_resources().get("CPU", 1)))
        waiting: list[_Job] = list(jobs)
        attempts: dict[tuple[str, str, int], int] = {}
        next_id = 0
        while waiting or running:
            while waiting and len(running) < capacity:
                job = waiting.pop(0)
                running[next_id] = _RayTask(task.remote(job, next_id, queue), job, time.monotonic())
                next_id += 1
            refs = [t.ref for t in running.values()]
            ray.wait(refs, num_returns=1, timeout=0.2)  # a wake-up when a task ends; episodes come by the queue
            # ended first, then the queue: a task that has ended has put all of its messages there
            ended, _ = ray.wait(refs, num_returns=len(refs), timeout=0)
            _drain_ray_queue(queue, running, sweep)
            ended_set = set(ended)
            for task_id, t in list(running.items()):
                lost: str | None = None
                if t.ref in ended_set:
                    lost = _ray_task_result(ray, t.ref)
                    if lost is None and not t.done:  # not seen: a job's task sends "done" or raises
                        lost = "the Ray task ended before its job did"
                elif t.done:  # its job is finished; the task is returning
                    pass
                elif episode_timeout is not None and time.monotonic() - t.since > (
                        episode_timeout if t.started else episode_timeout + STARTUP_GRACE):
                    ray.cancel(t.ref, force=True)
                    lost = f"timed out after {episode_timeout:g} s (--episode-timeout)"
                else:
                    continue
                del running[task_id]  # a given-up task's later messages are dropped: its episode is played again
                if lost is not None:
                    rest = _lose_episode(sweep, t.job, lost, attempts)
                    if rest is not None:
                        waiting.insert(0, rest)
    finally:
        for t in running.values():  # Ctrl-C or an exception: stop what still runs (a cluster's tasks would go on)
            try:
                ray.cancel(t.ref, force=True)
            except Exception:  # noqa: BLE001 - already finished or gone; nothing left to stop
                pass
        if queue is not None:
            try:
                queue.shutdown(force=True)
            except Exception:  # noqa: BLE001 - gone with its node; nothing left to stop
                pass
        if started:
            ray.shutdown()


def _drain_ray_queue(queue: Any, running: Mapping[int, _RayTask], sweep: _Sweep) -> None:
    """Report the messages waiting in ``queue`` (from :func:`_ray_job`) to ``sweep``: episodes, refusals, and
    each task's start and end (``started``, ``done``); those of a task no longer running are dropped."""
    n = queue.qsize()
    for task_id, kind, *payload in queue.get_nowait_batch(n) if n else []:
        t = running.get(task_id)
        if t is None or t.done:  # a task given up (timed out): its episode is played again elsewhere
            continue
        if kind == "started":
            t.started, t.since = True, time.monotonic()
        elif kind == "episode":
            sweep.episode(t.job, *payload)
            t.since = time.monotonic()
        else:  # "done"
            if payload[0] is not None:
                sweep.refuse(t.job, payload[0])
            t.done = True


def _ray_task_result(ray: Any, ref: Any) -> str | None:
    """``None`` when the task ended normally; why its episode is lost when its worker died. A Python exception
    in the job is raised here, a :class:`ModelFileError` as itself (its one line, not Ray's remote traceback)."""
    try:
        ray.get(ref)
    except ray.exceptions.RayTaskError as exc:
        if isinstance(exc.cause, ModelFileError):
            raise exc.cause from None
        if isinstance(exc.cause, KeyboardInterrupt):  # a Ctrl-C that reached the worker too: the sweep's
            raise KeyboardInterrupt from None
        raise
    except ray.exceptions.RayError as exc:  # the worker, not the job: WorkerCrashedError, a lost node, OOM
        text = (str(exc).strip().splitlines() or [""])[0][:200]
        return f"Ray worker died ({type(exc).__name__}: {text})"
    return None


def run_leaderboard(
    policies: list[str],
    scenarios: list[str],
    seeds: Sequence[int] | Mapping[str, Sequence[int]] | None = None,
    *,
    env_kwargs: dict[str, Any] | None = None,
    workers: int = 1,
    progress: bool = True,
    backend: str = "local",
    ray_address: str | None = None,
    out_dir: str | os.PathLike[str] | None = None,
    resume: bool = False,
    overwrite: bool = False,
    episode_timeout: float | None = None,
    suite: Mapping[str, Any] | None = None,
) -> Leaderboard:
    """Evaluate every policy spec on every scenario for its seeds.

    * ``seeds``: one sequence for every scenario, a mapping scenario -> seeds, or ``None``
      for :func:`default_seeds` (see :func:`resolve_seeds`).
    * ``env_kwargs``: passed to every :class:`~swarm_env.env.SwarmEnv` (``action_type``,
      ``max_cycles``, ``reward``, ...; random-generator knobs go to ``random`` only, see
      :func:`swarm_env.env.env_kwargs_for`); not ``render_mode``.
    * ``workers``: jobs (one per policy x scenario) run in a ``spawn`` process pool of this
      size when > 1; the metrics equal those of ``workers=1``. In the pool a worker that dies or
      hangs costs only its current episode, tried once more and otherwise counted as failed
      (:func:`_run_pool`); ``episode_timeout`` (seconds; default :func:`default_episode_timeout`
      of the longest episode) bounds each episode there. With ``workers=1`` episodes run in this
      process, with no isolation and no timeout.
    * ``progress``: a tqdm bar over episodes on stderr.
    * ``backend``: ``"local"`` (this process, or the pool above) or ``"ray"``: the same jobs as
      Ray tasks on the cluster at ``ray_address`` (or on a local Ray instance with ``workers``
      CPUs when ``ray_address`` is ``None``); the metrics equal the local ones, and the pool's
      fault rules hold there too (:func:`_run_ray`): ``episode_timeout`` bounds each episode, a
      dead or timed-out task costs only its episode, episodes stream to ``out_dir`` as they end.
    * ``out_dir``: stream every finished episode as one JSON line to ``out_dir/episodes.jsonl``
      and store the sweep's spec in ``out_dir/sweep.json``. A directory that already holds results
      is refused (:class:`~swarm_env.outputs.OutputError`) unless ``overwrite`` (start again) or
      ``resume`` (play only the episodes with no result there, after checking that the spec is the
      same; a resumed sweep gives the same leaderboard as an uninterrupted one). The directory is held
      (:func:`~swarm_env.outputs.directory_lock`) while the sweep runs: a second sweep on it, say two
      ``evaluate --resume DIR`` at once, is refused with an ``OutputError`` before it plays anything.
    * ``suite``: the benchmark suite these scenarios and seeds make up (:func:`swarm_env.harness.suite.run_suite`
      passes its name, version and split), stored in ``out_dir/sweep.json`` so that ``--resume`` scores it again.

    All inputs are validated (:func:`validate_inputs`) before any episode runs. Ctrl-C raises
    :class:`SweepInterrupted` (a ``KeyboardInterrupt``) carrying the board of the finished episodes.
    """
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"workers must be an int >= 1, got {workers!r}")
    if backend not in ("local", "ray"):
        raise ValueError(f"backend must be 'local' or 'ray', got {backend!r}")
    if ray_address is not None and backend != "ray":
        raise ValueError("ray_address needs backend='ray'")
    if episode_timeout is not None and not episode_timeout > 0:
        raise ValueError(f"episode_timeout must be > 0 seconds, got {episode_timeout!r}")
    if resume and out_dir is None:
        raise ValueError("resume needs out_dir (the directory of the sweep to finish)")
    kwargs = dict(env_kwargs or {})
    validate_inputs(policies, scenarios, kwargs)
    seed_map = resolve_seeds(scenarios, seeds)
    members = {p: training_runs(p) for p in policies}
    jobs = [_Job(m, s, tuple(seed_map[s]), kwargs) for p in policies for m in members[p] for s in scenarios]
    method_of = {m: p for p in policies for m in members[p] if len(members[p]) > 1}
    _probe_policies([m for p in policies for m in members[p]], scenarios[0], kwargs)
    out = None if out_dir is None else Path(out_dir)
    with contextlib.ExitStack() as held:
        if out is not None:
            if not resume:
                ensure_dir(out)
            elif not out.is_dir():
                raise ValueError(f"{out}: missing; --resume needs a directory an earlier 'swarm-env evaluate --out' wrote")
            # one sweep writes a directory at a time: a second evaluate --resume on it would play the same episodes
            held.enter_context(directory_lock(out, "another swarm-env evaluate"))
            _prepare_out(out, _sweep_spec(policies, scenarios, seed_map, kwargs, suite), resume, overwrite)
        return _sweep_locked(policies, scenarios, seed_map, kwargs, jobs, members, method_of, out, resume, backend,
                             ray_address, workers, episode_timeout, progress)


def _sweep_locked(policies: list[str], scenarios: list[str], seed_map: dict[str, list[int]],
                  kwargs: dict[str, Any], jobs: list[_Job], members: Mapping[str, tuple[str, ...]], method_of: dict[str, str],
                  out: Path | None, resume: bool, backend: str, ray_address: str | None, workers: int,
                  episode_timeout: float | None, progress: bool) -> Leaderboard:
    """The episodes of :func:`run_leaderboard` once its inputs are checked and its output directory is held."""
    if episode_timeout is None:
        longest = 0
        for s in scenarios:
            probe = SwarmEnv(s, **env_kwargs_for(s, kwargs))
            longest = max(longest, int(probe.max_steps))
            probe.close()
        episode_timeout = default_episode_timeout(longest)

    from tqdm.auto import tqdm

    total = sum(len(job.seeds) for job in jobs)
    t0 = time.perf_counter()

    def build() -> Leaderboard:
        return _board(policies, scenarios, seed_map, kwargs, jobs, members, method_of, sweep,
                      time.perf_counter() - t0, workers)

    with tqdm(total=total, desc="leaderboard", unit="ep", disable=not progress) as bar:
        sweep = _Sweep(out, bar.update)
        for job in jobs:
            sweep.order[(job.policy, job.scenario)] = list(job.seeds)
        if out is not None and resume:
            sweep.load(out / EPISODES_FILE)
            bar.update(total - sum(len(sweep.remaining(job)) for job in jobs))
        todo = [_Job(j.policy, j.scenario, left, j.env_kwargs) for j in jobs if (left := sweep.remaining(j))]
        try:
            if not todo:
                pass
            elif backend == "ray":
                _run_ray(todo, ray_address, workers, sweep, episode_timeout)
            elif workers == 1 or len(todo) == 1:
                for job in todo:
                    def record(seed: int, metrics: dict[str, Any], rec: Any, job: _Job = job) -> None:
                        sweep.episode(job, seed, metrics, rec)

                    reason = _run_job(job, record)
                    if reason is not None:
                        sweep.refuse(job, reason)
            else:
                _run_pool(todo, min(workers, len(todo)), sweep, episode_timeout)
        except KeyboardInterrupt:
            raise SweepInterrupted(build()) from None
        # a refused job's episodes never ran; count them so the bar ends full
        bar.update(sum(len(job.seeds) for job in jobs if (job.policy, job.scenario) in sweep.na))
    return build()


def _probe_policies(specs: Sequence[str], scenario: str, env_kwargs: Mapping[str, Any]) -> None:
    """Load each policy once on ``scenario`` before anything is written or drawn, so that a bad model file
    (:class:`ModelFileError`) or a missing optional extra (:class:`~swarm_env.extras.MissingExtraError`) fails
    the sweep at once instead of after the progress bar, leaving an ``out_dir`` that blocks the next run. A policy
    that only refuses the scenario (another :class:`PolicyError`) is left to its jobs, which make it an n/a row."""
    env = SwarmEnv(scenario, **env_kwargs_for(scenario, env_kwargs))
    try:
        for spec in specs:
            try:
                load_policy(spec, env)
            except ModelFileError:
                raise
            except PolicyError:
                pass
    finally:
        env.close()


def _board(policies: list[str], scenarios: list[str], seed_map: dict[str, list[int]], kwargs: dict[str, Any],
           jobs: list[_Job], members: Mapping[str, tuple[str, ...]], method_of: Mapping[str, str], sweep: _Sweep,
           wall: float, workers: int) -> Leaderboard:
    """The leaderboard of what ``sweep`` holds, episodes in job and seed order (so the board does not depend
    on the order episodes finished in, nor on which of them an earlier, resumed run played)."""
    rows: list[Row] = []
    episodes: list[dict[str, Any]] = []
    failed: list[dict[str, Any]] = []
    records: dict[tuple[str, str, int], EpisodeRecord] = {}
    by_job: dict[tuple[str, str], Row] = {}
    for job in jobs:
        key = (job.policy, job.scenario)
        method = method_of.get(job.policy)
        if key in sweep.na:
            by_job[key] = Row(job.policy, job.scenario, list(job.seeds), None, sweep.na[key], method=method)
            continue
        rec = sweep.worst.get(key)
        if rec is not None:
            records[(job.policy, job.scenario, int(rec.seed))] = rec  # type: ignore[arg-type]
        done = [sweep.ok[key + (s,)] for s in job.seeds if key + (s,) in sweep.ok]
        lost = [sweep.failed[key + (s,)] for s in job.seeds if key + (s,) in sweep.failed]
        pending = len(job.seeds) - len(done) - len(lost)
        extra = {"method": method} if method else {}
        episodes.extend({"policy": job.policy, **extra, "scenario": job.scenario, "seed": ep["seed"], "metrics": ep}
                        for ep in done)
        failed.extend({**e, **extra} for e in lost)
        by_job[key] = Row(job.policy, job.scenario, list(job.seeds), summarize(done) if done else None, method=method,
                          failed=len(lost), pending=pending)
    for p in policies:  # policies outer, scenarios inner; a method row before its members' rows
        for s in scenarios:
            if len(members[p]) > 1:
                rows.append(method_row(p, [by_job[(m, s)] for m in members[p]]))
            rows.extend(by_job[(m, s)] for m in members[p])
    return Leaderboard(list(policies), list(scenarios), seed_map, kwargs, rows, episodes, wall, workers,
                       records=records, failed=failed, provenance=provenance())


def aggregate_training_seeds(summaries: Sequence[Mapping[str, Any]], metrics: Sequence[Metric] = METRICS
                             ) -> dict[str, Any]:
    """One summary across training seeds: per metric (the keys of ``metrics``, :data:`METRICS`), the mean of
    the seeds' means and its Student-t 95 % half-width across seeds
    (:func:`~swarm_env.harness.evaluation.mean_ci95_t`; ``n`` counts seeds); ``episodes`` is the total
    and ``training_seeds`` the number of seeds."""
    out: dict[str, Any] = {"episodes": sum(int(s["episodes"]) for s in summaries), "training_seeds": len(summaries)}
    for m in metrics:
        out[m.key] = mean_ci95_t((s.get(m.key) or {}).get("mean") for s in summaries)
    return out


def method_row(method: str, member_rows: Sequence[Row]) -> Row:
    """The row of a method from its training seeds' rows (n/a if any seed refused the scenario; the
    aggregate of the seeds that finished episodes, with their failed and pending counts summed)."""
    first = member_rows[0]
    names = [r.policy for r in member_rows]
    refused = [r for r in member_rows if r.na_reason is not None]
    if refused:
        return Row(method, first.scenario, first.seeds, None, refused[0].na_reason, members=names)
    played = [r.summary for r in member_rows if r.summary is not None]  # a seed with no finished episode drops out
    return Row(method, first.scenario, first.seeds, aggregate_training_seeds(played) if played else None,
               members=names, failed=sum(r.failed for r in member_rows), pending=sum(r.pending for r in member_rows))


# --------------------------------------------------------------------------- aggregation
@dataclass
class Row:
    """One policy on one scenario: ``summary`` (:func:`swarm_env.harness.evaluation.summarize`) or, if the policy
    refused the scenario, ``na_reason``.

    A learned method's training seeds each have a *member* row (``method`` names the method, e.g.
    ``mappo`` for ``mappo:s1``); the method's own row lists them in ``members`` and its summary is
    :func:`aggregate_training_seeds` of theirs (intervals across seeds, not episodes)."""

    policy: str
    scenario: str
    seeds: list[int]
    summary: dict[str, Any] | None
    na_reason: str | None = None
    method: str | None = None
    members: list[str] | None = None
    #: episodes whose worker died or timed out on every attempt (not in ``summary``)
    failed: int = 0
    #: episodes not played yet (a board of an interrupted sweep)
    pending: int = 0

    @property
    def status(self) -> str:
        """``ok`` (a summary, possibly of fewer episodes than seeds: see ``failed`` and ``pending``),
        ``n/a: reason``, ``failed`` (every episode failed) or ``pending`` (none played yet)."""
        if self.na_reason is not None:
            return f"n/a: {self.na_reason}"
        if self.summary is None:
            return "failed" if self.failed else "pending"
        return "ok"

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"policy": self.policy, "scenario": self.scenario, "seeds": self.seeds, "status": self.status,
               "na_reason": self.na_reason, "summary": self.summary}
        if self.method is not None:
            out["method"] = self.method
        if self.members is not None:
            out["members"] = self.members
        for key in ("failed", "pending"):  # only when not zero: a complete, fault-free board reads as before
            if getattr(self, key):
                out[key] = getattr(self, key)
        return out


def badness(episode: Mapping[str, Any]) -> tuple[float, bool, float]:
    """Sort key of an episode's metrics, larger is worse: collisions, then failure
    (``success`` False is worse), then mean formation error."""
    return (episode["collisions"]["total"], not episode["success"], episode["formation_error"]["mean"])


def _md_cell(text: str) -> str:
    return " ".join(str(text).split()).replace("|", "\\|")


def _fmt_stat(stat: Mapping[str, Any] | None, digits: int) -> str:
    if not stat or stat.get("mean") is None:
        return "–"
    if stat["n"] == 1:  # no spread to report from one value
        return f"{stat['mean']:.{digits}f}"
    return f"{stat['mean']:.{digits}f} ± {stat['ci95']:.{digits}f}"


@dataclass
class Leaderboard:
    """The result of :func:`run_leaderboard`.

    ``rows``: one :class:`Row` per policy x scenario (policies outer, scenarios inner).
    ``episodes``: ``{"policy", "scenario", "seed", "metrics"}`` per episode played, where
    ``metrics`` is :func:`~swarm_env.harness.episode.run_episode`'s dict.
    ``failed``: the episodes whose worker died or timed out on every attempt (counted in the rows'
    ``failed``, left out of their summaries).
    ``records``: ``(policy, scenario, seed)`` -> the :class:`~swarm_env.harness.recording.EpisodeRecord`
    of each job's worst episode (what :func:`record_worst_videos` replays); not in the JSON, so
    empty in a board read back by :meth:`from_json`.
    """

    policies: list[str]
    scenarios: list[str]
    seeds: dict[str, list[int]]
    env_kwargs: dict[str, Any]
    rows: list[Row]
    episodes: list[dict[str, Any]]
    wall_time: float = 0.0
    workers: int = 1
    metrics: tuple[Metric, ...] = field(default=METRICS, repr=False)
    records: dict[tuple[str, str, int], EpisodeRecord] = field(default_factory=dict, repr=False, compare=False)
    #: ``{"policy", "scenario", "seed", "status": "failed", "error", "attempts"}`` per failed episode
    failed: list[dict[str, Any]] = field(default_factory=list)
    #: How the board was made (:func:`swarm_env.harness.provenance.provenance`: command, version, commit, date), or None.
    provenance: dict[str, Any] | None = None

    def row(self, policy: str, scenario: str) -> Row:
        for r in self.rows:
            if r.policy == policy and r.scenario == scenario:
                return r
        raise KeyError(f"no row for policy {policy!r} on scenario {scenario!r}")

    def episodes_of(self, policy: str, scenario: str) -> list[dict[str, Any]]:
        """The ``run_episode`` metrics of one row's episodes, in seed order (a method's: every
        training seed's, seed by seed)."""
        return [e["metrics"] for e in self.episodes
                if (e["policy"] == policy or e.get("method") == policy) and e["scenario"] == scenario]

    def worst_episodes(self, per_scenario: bool = True) -> list[dict[str, Any]]:
        """The worst episode (by :func:`badness`, the first seed on ties) of each policy x scenario
        (``per_scenario=True``) or of each policy over all scenarios; entries of :attr:`episodes`.
        A method's training seeds count as one policy (its worst episode over all of them)."""
        groups: dict[tuple[str, ...], list[dict[str, Any]]] = {}
        for e in self.episodes:
            who = e.get("method") or e["policy"]  # a method's seeds compete for its one worst episode
            key = (who, e["scenario"]) if per_scenario else (who,)
            groups.setdefault(key, []).append(e)
        # max() keeps the first of equal keys: ties go to the earliest seed
        return [max(group, key=lambda e: badness(e["metrics"])) for group in groups.values()]

    # ---------------------------------------------------------------- writers
    def to_markdown(self) -> str:
        """One table per scenario (policies as rows); cells ``mean ± 95 % CI half-width``."""
        cols = [m for m in self.metrics if m.in_markdown]
        legend = [
            "Each cell: mean ± 95 % confidence half-width (1.96·s/√N, normal approximation) over the "
            "row's N episodes (no ± when N = 1); settle time averages the formation switches that settled (switches that "
            "never settled are left out), and \"held after settling\" the fraction of the time from settling to the "
            "next switch (or the end) during which every follower stayed within the settle tolerance, over the same "
            "switches; – = nothing to average; n/a = the policy refuses the scenario. \"acts on\": "
            "`observations` = each follower's own observation only (deployable with on-board sensing); `state` = the "
            "privileged world state, like the experts; `+ shield` = executed through the VO safety layer, which "
            "reads the state.",
        ]
        trained = sorted({r.policy: len(r.members) for r in self.rows if r.members}.items())
        if trained:
            legend[0] += (" Rows marked (k seeds) are learned methods trained with k seeds: each cell is the mean of the "
                          "seeds' per-episode means ± a Student-t 95 % half-width across the seeds (the spread between "
                          "training runs); the CSV and JSON also hold one row per seed.")
        # Lost episodes get their own columns, only on a board that has some: a complete board reads as before.
        counts = [k for k in ("failed", "pending") if any(getattr(r, k) for r in self.rows)]
        if counts:
            legend[0] += (" \"failed\": episodes whose worker crashed or exceeded the episode timeout twice (left out "
                          "of the row's statistics, which cover the episodes that finished)" if "failed" in counts else "")
            legend[0] += (" \"pending\": episodes not played yet (an interrupted sweep: swarm-env evaluate --resume DIR)"
                          if "pending" in counts else "")
        # The provenance first (how to make the table again), the tables, then the legend.
        lines = [provenance_line(self.provenance)] if self.provenance else []
        for scenario in self.scenarios:
            seeds = self.seeds[scenario]
            lines += ["", f"### {scenario} — seeds {format_seeds(seeds)} (N = {len(seeds)})", ""]
            lines.append("| policy | acts on | " + " | ".join(m.label for m in cols) + "".join(f" | {k}" for k in counts)
                         + " |")
            lines.append("|---|---|" + "---:|" * (len(cols) + len(counts)))
            for r in (r for r in self.rows if r.scenario == scenario and r.method is None):
                if r.na_reason is not None:
                    cells = [f"n/a: {r.na_reason}"] + [""] * (len(cols) - 1)
                elif r.summary is None:
                    cells = [r.status] + [""] * (len(cols) - 1)
                else:
                    cells = [_fmt_stat(r.summary.get(m.key), m.digits) for m in cols]
                cells += [str(getattr(r, k)) for k in counts]
                label = f"`{r.policy}`" + (f" ({len(r.members)} seeds)" if r.members else "")
                lines.append("| " + " | ".join(_md_cell(c) for c in [label, acts_on(r.policy), *cells]) + " |")
        lines += ["", *legend]
        return "\n".join(lines).lstrip("\n") + "\n"

    def csv_rows(self) -> list[dict[str, Any]]:
        """The CSV table as dicts: policy, scenario, status, episodes, seeds, method (the method a
        training seed's row belongs to), training_seeds (on a method's row: how many), then
        ``<metric>_mean``, ``<metric>_ci95``, ``<metric>_n`` per metric (empty when n/a). ``<metric>_n`` is
        the number of episodes with a value of the metric on every row (a method's row: over all its training
        seeds); on a method's row the mean and the interval are across its ``training_seeds`` seeds. ``failed``
        and ``pending`` follow ``episodes`` on a board that has failed or pending episodes."""
        out = []
        counts = [k for k in ("failed", "pending") if any(getattr(r, k) for r in self.rows)]  # as in to_markdown
        for r in self.rows:
            d: dict[str, Any] = {"policy": r.policy, "scenario": r.scenario, "status": r.status,
                                 "episodes": 0 if r.summary is None else r.summary["episodes"],
                                 **{k: getattr(r, k) for k in counts},
                                 "seeds": format_seeds(r.seeds), "method": r.method,
                                 "training_seeds": len(r.members) if r.members else None}
            seeds_rows = [x for x in self.rows if r.members and x.policy in r.members and x.scenario == r.scenario]
            for m in self.metrics:
                stat = (r.summary or {}).get(m.key) or {}
                d[f"{m.key}_mean"] = stat.get("mean")
                d[f"{m.key}_ci95"] = stat.get("ci95")
                # episodes on every row (a method's summary counts seeds: its n is the sum of its seeds' episodes)
                n = (sum(((x.summary or {}).get(m.key) or {}).get("n", 0) for x in seeds_rows) if r.members
                     else stat.get("n", 0))
                d[f"{m.key}_n"] = n if r.summary is not None else None
            out.append(d)
        return out

    def to_csv(self, path: str | os.PathLike[str], *, overwrite: bool = True,
               root: str | os.PathLike[str] | None = None) -> Path:
        """Write :meth:`csv_rows` (numbers as ``repr`` floats, missing values empty), atomically
        (:func:`swarm_env.outputs.atomic_write_text`, whose ``overwrite`` and ``root`` rules apply)."""
        import io


        rows = self.csv_rows()
        buf = io.StringIO(newline="")
        writer = csv.DictWriter(buf, fieldnames=list(rows[0]) if rows else ["policy", "scenario", "status"])
        writer.writeheader()
        writer.writerows({k: ("" if v is None else v) for k, v in row.items()} for row in rows)
        return atomic_write_text(path, buf.getvalue(), overwrite=overwrite, root=root)

    def to_dict(self) -> dict[str, Any]:
        return {
            "policies": self.policies,
            "scenarios": self.scenarios,
            "seeds": self.seeds,
            "env_kwargs": self.env_kwargs,
            "workers": self.workers,
            "wall_time": self.wall_time,
            "rows": [r.to_dict() for r in self.rows],
            "episodes": self.episodes,
            **({"failed": self.failed} if self.failed else {}),
            **({"provenance": self.provenance} if self.provenance else {}),
        }

    def to_json(self, path: str | os.PathLike[str], *, overwrite: bool = True,
                root: str | os.PathLike[str] | None = None) -> Path:
        """Write everything: inputs, rows with their summaries, every episode's metrics (and the failed
        episodes, if any), atomically (:func:`swarm_env.outputs.atomic_write_text`)."""
        return atomic_write_text(path, dumps(self.to_dict(), indent=1), overwrite=overwrite, root=root)

    def write(self, out_dir: str | os.PathLike[str], *, overwrite: bool = True) -> list[Path]:
        """Write ``leaderboard.md``, ``.csv`` and ``.json`` into ``out_dir`` (created if missing), each
        atomically and never outside ``out_dir`` (:mod:`swarm_env.outputs`); returns their paths."""
        out = ensure_dir(out_dir)
        return [atomic_write_text(out / "leaderboard.md", self.to_markdown(), overwrite=overwrite, root=out),
                self.to_csv(out / "leaderboard.csv", overwrite=overwrite, root=out),
                self.to_json(out / "leaderboard.json", overwrite=overwrite, root=out)]

    @classmethod
    def from_json(cls, path: str | os.PathLike[str]) -> Leaderboard:
        """Read a file written by :meth:`to_json` (e.g. to record videos later), or its gzip (``.json.gz``)."""
        doc = read_json(path)
        rows = [Row(r["policy"], r["scenario"], r["seeds"], r["summary"], r["na_reason"], r.get("method"), r.get("members"),
                    r.get("failed", 0), r.get("pending", 0))
                for r in doc["rows"]]
        return cls(doc["policies"], doc["scenarios"], doc["seeds"], doc["env_kwargs"], rows, doc["episodes"],
                   doc.get("wall_time", 0.0), doc.get("workers", 1), failed=doc.get("failed", []),
                   provenance=doc.get("provenance"))


# --------------------------------------------------------------------------- videos
def safe_name(text: str, max_len: int = 80) -> str:
    """A filesystem-safe rendering of a policy spec or scenario: ``ppo:runs/x/model.zip`` -> ``ppo_runs_x_model.zip``."""
    name = re.sub(r"[^A-Za-z0-9._-]+", "_", text).strip("._-")
    return (name or "x")[:max_len]


def _scenario_label(scenario: str) -> str:
    p = Path(scenario)
    return p.stem if p.suffix.lower() in (".yaml", ".yml") else scenario


def _behaviour(metrics: Mapping[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in metrics.items() if k not in TIMING_KEYS}


@dataclass(frozen=True)
class VideoRecord:
    """A written video of one episode; ``reproduced`` says its replay matched the record and the board's metrics."""

    path: Path
    policy: str
    scenario: str
    seed: int
    reproduced: bool


def record_worst_videos(
    board: Leaderboard,
    out_dir: str | os.PathLike[str],
    *,
    fps: float = 20.0,
    per_scenario: bool = True,
    progress: bool = True,
    records_dir: str | os.PathLike[str] | None = None,
    overwrite: bool = True,
    root: str | os.PathLike[str] | None = None,
    play_missing: bool = False,
) -> list[VideoRecord]:
    """Render each worst episode (:meth:`Leaderboard.worst_episodes`) to
    ``<out_dir>/<name>.mp4`` by replaying its record (:func:`swarm_env.harness.recording.replay`: the
    recorded actions, no policy), where ``<name>`` is ``<policy>__<scenario>__seed<k>`` made
    safe by :func:`safe_name`.

    The record comes from ``board.records`` (a board made by :func:`run_leaderboard`) or else
    from ``<records_dir>/<name>/`` (saved by an earlier call); with ``records_dir`` the board's
    records are saved there too, one recording each (``swarm-env replay <records_dir>/<name>``).
    A worst episode with no record raises ``ValueError`` naming it, unless ``play_missing``: then it is
    played again with its policy and recorded (a resumed sweep's episodes from before the interruption
    have no record). ``VideoRecord.reproduced`` says that the replay matched the record's state digests
    and the board's metrics; a
    ``RuntimeWarning`` says when it did not (the video shows the replay).

    Videos are written atomically (:class:`~swarm_env.harness.video.VideoWriter`); an existing video is
    replaced only with ``overwrite``; with ``root`` (the ``--out`` directory) no video or record is
    written where a symlink would carry it outside ``root`` (:class:`~swarm_env.outputs.OutputError`).
    """
    from tqdm.auto import tqdm


    out = ensure_dir(out_dir, root=root)
    if records_dir is not None:
        ensure_dir(records_dir, root=root)
    used: set[str] = set()
    records = []
    for entry in tqdm(board.worst_episodes(per_scenario), desc="worst-episode videos", unit="video", disable=not progress):
        policy, scenario, seed = entry["policy"], entry["scenario"], int(entry["seed"])
        name = f"{safe_name(policy)}__{safe_name(_scenario_label(scenario))}__seed{seed}"
        if name in used:  # two specs that differ only in unsafe characters
            name += "-" + hashlib.sha1(f"{policy}\0{scenario}".encode()).hexdigest()[:8]
        used.add(name)
        folder = None if records_dir is None else Path(records_dir) / name
        if folder is not None and root is not None and (folder.exists() or folder.is_symlink()):
            ensure_dir(folder, root=root)  # an existing record folder must not lead outside root
        rec = _worst_record(board, entry, folder, play_missing)
        path = out / f"{name}.mp4"
        with VideoWriter(path, fps=fps, overwrite=overwrite, root=root) as writer:
            result = replay(rec, on_frame=writer.append)
        same = result.ok and _json_roundtrip(_behaviour(result.metrics)) == _json_roundtrip(_behaviour(entry["metrics"]))
        if not same:
            why = result.divergence.message() if result.divergence is not None else (
                f"collisions {entry['metrics']['collisions']['total']} -> {result.metrics['collisions']['total']}, "
                f"success {entry['metrics']['success']} -> {result.metrics['success']}")
            warnings.warn(
                f"replaying the record of policy {policy!r} on {scenario!r} seed {seed} for its video did not "
                f"reproduce the board's episode ({why}); the video shows the replay",
                RuntimeWarning,
                stacklevel=2,
            )
        records.append(VideoRecord(path, policy, scenario, seed, same))
    return records


def _worst_record(board: Leaderboard, entry: Mapping[str, Any], folder: Path | None,
                  play_missing: bool = False) -> EpisodeRecord:
    """The record of a worst episode: from the board (then saved to ``folder``, if given), from ``folder``, or
    with ``play_missing`` from playing the episode again (then saved to ``folder``)."""
    policy, scenario, seed = entry["policy"], entry["scenario"], int(entry["seed"])
    rec = board.records.get((policy, scenario, seed))
    if rec is not None:
        if folder is not None:
            save_episode(rec, folder)
        return rec
    if folder is not None and folder.is_dir():
        rec = load_episode(folder / "episode_0")  # where save_episode put it (a leaderboard record is episode 0)
        if (rec.policy, rec.scenario_spec, rec.seed) != (policy, scenario, seed):
            raise ValueError(f"{folder}: records policy {rec.policy!r} on {rec.scenario_spec!r} seed {rec.seed}, "
                             f"not the worst episode {policy!r} on {scenario!r} seed {seed}")
        return rec
    if play_missing:
        # Played again with its policy and recorded (an episode does not depend on what ran before it in its
        # job); the caller checks the replay against the board's metrics, so a difference would be reported.
        env = SwarmEnv(scenario, **env_kwargs_for(scenario, board.env_kwargs))
        try:
            _, rec = record_episode(env, load_policy(policy, env), seed, policy_spec=policy, scenario_spec=scenario)
        finally:
            env.close()
        if folder is not None:
            save_episode(rec, folder)
        return rec
    where = f" and {folder} holds none" if folder is not None else ""
    raise ValueError(f"no record of the worst episode of policy {policy!r} on {scenario!r} (seed {seed}): the board "
                     f"holds records only when run_leaderboard made it{where}")


def _json_roundtrip(x: Any) -> Any:
    # compare as JSON would store them, so a board read back with from_json compares equal too
    return json.loads(dumps(x, indent=None))
