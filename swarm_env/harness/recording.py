"""Record episodes and replay them bit for bit, without the policy.

A *record* holds what it takes to re-simulate one episode: the resolved
scenario (the world the episode ran in, written out as YAML, so a ``random``
world never goes through the generator again), the seed, the policy spec, the
env options that touch the simulation, every action the policy took, and a
digest of the world state every ``digest_every`` steps. :func:`replay` builds
a fresh env from the record, feeds it the recorded actions and compares the
digests; :func:`check` raises :class:`ReplayDivergence` at the first step whose
digest differs (the code or the platform changed), naming that step.

.. code-block:: python

    from swarm_env.harness.recording import check, load_recording, record_episode, replay, save_episode

    metrics, rec = record_episode(env, policy, seed=3, policy_spec="vo")
    save_episode(rec, "rec")                      # rec/episode_0/...
    for rec in load_recording("rec"):
        check(rec)                                # raises ReplayDivergence naming the step
        result = replay(rec, on_frame=writer.append)   # frames need render_mode="rgb_array"

From the command line: ``swarm-env run ... --record DIR`` and
``swarm-env replay DIR [--video out.mp4] [--check]``.

On-disk format (:data:`FORMAT_VERSION` 1). A recording directory holds one
folder per episode, ``episode_<k>`` (``k`` = the episode's index in its run)::

    DIR/episode_<k>/meta.json      {"format": "swarm_env.harness.recording", "version": 1,
                                    "episode": k, "seed": int | null, "policy": spec,
                                    "scenario": the scenario as given ("random", a name, a path),
                                    "env": {"action_type", "max_steps", "terminate_on_collision"},
                                    "steps": T, "digest_every": K,
                                    "digest": how the digest is made (text),
                                    "platform": {"swarm_env", "python", "numpy", "pymunk", "system", "machine"},
                                    "metrics": the episode's metrics as run_episode returned them (reference only)}
    DIR/episode_<k>/scenario.yaml  the resolved scenario (swarm_env.scenarios.loader.scenario_to_dict)
    DIR/episode_<k>/actions.npz    actions: (T, N, 2) float64 (continuous) or (T, N) int64 (discrete),
                                   rows in env.possible_agents order, as the policy gave them
                                   (before the env's clipping); digest_steps: (D,) int64;
                                   digests: (D, 32) uint8

Step ``s`` means the state after ``s`` calls of ``env.step`` (step 0 is the
state after ``reset``); ``actions[s - 1]`` led to it. Digests are taken at
every step ``s`` with ``s % K == 0`` and at the last step ``T``.
:func:`state_digest` says what they cover. An episode folder is written under a
temporary name and renamed into place, so a reader never sees half of one.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import platform
import shutil
import uuid
import warnings
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pymunk
import yaml

from swarm_env import __version__
from swarm_env.env import SwarmEnv
from swarm_env.harness.episode import run_episode
from swarm_env.harness.policies import Policy
from swarm_env.jsonio import dumps
from swarm_env.outputs import replace_dir
from swarm_env.scenario import Scenario
from swarm_env.scenarios.loader import scenario_from_dict, scenario_to_dict
from swarm_env.state import CONTACT_KINDS, WorldState

FORMAT = "swarm_env.harness.recording"
#: The version of the on-disk format this module writes and reads.
FORMAT_VERSION = 1
#: Default digest interval: every step, so a divergence is named at the exact step.
DIGEST_EVERY = 1
DIGEST_DESCRIPTION = (
    "sha256 of, in order: step and formation index (int64), time (float64), leader_done (uint8); "
    "follower pose, velocity, twist; leader pose, velocity, twist; human positions, velocities; "
    "slot targets (float64, little-endian); contact onsets, then pairs in touch (each: int64 count, then kind, robot, "
    "other per contact)"
)
EPISODE_PREFIX = "episode_"
_META, _SCENARIO, _ACTIONS = "meta.json", "scenario.yaml", "actions.npz"


class RecordError(ValueError):
    """A recording is missing, unreadable, of another format version, or inconsistent."""


@dataclasses.dataclass(frozen=True)
class EpisodeRecord:
    """One recorded episode (the fields of the on-disk format in the module docstring)."""

    episode: int
    seed: int | None
    policy: str
    scenario_spec: str
    scenario: Scenario
    action_type: str
    max_steps: int
    terminate_on_collision: bool
    digest_every: int
    actions: np.ndarray
    digest_steps: np.ndarray
    digests: np.ndarray
    metrics: dict[str, Any]
    platform: dict[str, str]

    @property
    def steps(self) -> int:
        """``T``: the number of ``env.step`` calls of the episode."""
        return int(self.actions.shape[0])


@dataclasses.dataclass(frozen=True)
class Divergence:
    """Where a replay first differed from its record.

    ``step``: the first step found to differ; ``recorded``/``replayed``: the two digests there
    (hex), or ``None`` when the episode lengths differ (``detail`` says how); ``last_match``: the
    last digest step that matched (``None`` if none did); ``platform_note``: what changed in the
    platform since the recording (empty if nothing did).
    """

    episode: int
    seed: int | None
    step: int
    detail: str
    recorded: str | None = None
    replayed: str | None = None
    last_match: int | None = None
    platform_note: str = ""

    def message(self) -> str:
        """The one-line report: ``replay: step S of episode K (seed N) diverges from the record (...)``."""
        what = self.detail
        if self.last_match is not None and self.last_match < self.step - 1:  # digests every K > 1 steps
            what += f"; step {self.last_match} matched"
        return (f"replay: step {self.step} of episode {self.episode} (seed {self.seed}) diverges from the record "
                f"({what}){self.platform_note}")


class ReplayDivergence(RuntimeError):
    """Raised by :func:`check` at the first divergence; ``divergence`` says where, ``str()`` is its one-line message."""

    def __init__(self, divergence: Divergence) -> None:
        self.divergence = divergence
        super().__init__(divergence.message())


@dataclasses.dataclass(frozen=True)
class ReplayResult:
    """What :func:`replay` gives back: the replayed episode's metrics (``run_episode``'s, timings
    included), how many steps ran, how many digests were compared and the first divergence (or ``None``)."""

    record: EpisodeRecord
    metrics: dict[str, Any]
    steps: int
    digests_checked: int
    divergence: Divergence | None

    @property
    def ok(self) -> bool:
        return self.divergence is None


# --------------------------------------------------------------------------- digests
def _le(a: np.ndarray | float) -> bytes:
    return np.ascontiguousarray(a, dtype="<f8").tobytes()


def state_digest(state: WorldState) -> bytes:
    """The 32-byte sha256 digest of ``state`` (:data:`DIGEST_DESCRIPTION`): equal digests mean the
    same positions, angles, velocities and contacts to the last bit."""
    h = hashlib.sha256()
    h.update(np.array([state.step, state.formation_index], dtype="<i8").tobytes())
    h.update(_le(state.time))
    h.update(bytes([bool(state.leader_done)]))
    for a in (state.follower_pose, state.follower_vel, state.follower_twist, state.leader_pose, state.leader_vel,
              state.leader_twist, state.human_pos, state.human_vel, state.slot_targets):
        h.update(_le(a))
    for contacts in (state.contacts, state.touching):
        rows = [(CONTACT_KINDS.index(c.kind), c.robot, c.other) for c in contacts]
        h.update(np.array([len(rows)], dtype="<i8").tobytes())  # the count first: the two lists' boundary is unambiguous
        h.update(np.array(rows, dtype="<i8").reshape(-1, 3).tobytes())
    return h.digest()


def _platform() -> dict[str, str]:
    return {"swarm_env": __version__, "python": platform.python_version(), "numpy": np.__version__,
            "pymunk": str(pymunk.version), "system": platform.system(), "machine": platform.machine()}


def _platform_note(recorded: Mapping[str, str]) -> str:
    now = _platform()
    changed = [f"{k} {recorded.get(k)} -> {v}" for k, v in now.items() if recorded.get(k) != v]
    return f"; changed since recording: {', '.join(changed)}" if changed else ""


# --------------------------------------------------------------------------- recording
class Recorder:
    """The ``on_step`` hook of :func:`swarm_env.harness.episode.run_episode` that records an episode:
    every action (rows in ``env.possible_agents`` order) and the digests of the states at steps
    ``0, K, 2K, ...`` and at the last step (``K = digest_every``)."""

    def __init__(self, env: SwarmEnv, digest_every: int = DIGEST_EVERY) -> None:
        if isinstance(digest_every, bool) or not isinstance(digest_every, int) or digest_every < 1:
            raise ValueError(f"digest_every must be an int >= 1, got {digest_every!r}")
        self.env = env
        self.digest_every = digest_every
        self._actions: list[np.ndarray] = []
        self._digests: dict[int, bytes] = {}

    def __call__(self, actions: Mapping[str, Any] | None) -> None:
        env = self.env
        if actions is None:  # right after reset
            self._actions, self._digests = [], {}
        elif env.action_type == "discrete":  # ints, or size-1 arrays as the env accepts them
            self._actions.append(np.array([np.asarray(actions[a]).item() for a in env.possible_agents], dtype=np.int64))
        else:  # float64, as the env converts them: the replay feeds the env the very same numbers
            self._actions.append(np.array([np.asarray(actions[a], dtype=np.float64) for a in env.possible_agents]))
        state = env.world_state()
        if state.step % self.digest_every == 0 or not env.agents:
            self._digests[state.step] = state_digest(state)

    def record(self, *, episode: int, seed: int | None, policy: str, scenario_spec: str,
               metrics: Mapping[str, Any]) -> EpisodeRecord:
        """The :class:`EpisodeRecord` of the episode just played (call after ``run_episode`` returns)."""
        env = self.env
        n = len(env.possible_agents)
        shape = (0, n) if env.action_type == "discrete" else (0, n, 2)
        actions = np.stack(self._actions) if self._actions else np.zeros(shape)
        steps = sorted(self._digests)
        return EpisodeRecord(
            episode=int(episode), seed=None if seed is None else int(seed), policy=str(policy),
            scenario_spec=str(scenario_spec), scenario=env.scenario, action_type=env.action_type,
            max_steps=int(env.max_steps), terminate_on_collision=bool(env.terminate_on_collision),
            digest_every=self.digest_every, actions=actions, digest_steps=np.array(steps, dtype=np.int64),
            digests=np.array([np.frombuffer(self._digests[s], dtype=np.uint8) for s in steps], dtype=np.uint8).reshape(-1, 32),
            metrics=dict(metrics), platform=_platform(),
        )


def record_episode(
    env: SwarmEnv,
    policy: Policy,
    seed: int | None,
    *,
    policy_spec: str,
    scenario_spec: str | None = None,
    episode: int = 0,
    digest_every: int = DIGEST_EVERY,
    on_frame: Callable[[np.ndarray], None] | None = None,
) -> tuple[dict[str, Any], EpisodeRecord]:
    """Play one episode exactly as :func:`swarm_env.harness.episode.run_episode` does (the same metrics)
    and record it. ``policy_spec`` and ``scenario_spec`` (default: ``env.scenario_name``) are
    stored for reference; ``episode`` is the episode's index in its run (it names its folder)."""
    recorder = Recorder(env, digest_every)
    metrics = run_episode(env, policy, seed, on_frame, on_step=recorder)
    rec = recorder.record(episode=episode, seed=seed, policy=policy_spec,
                          scenario_spec=env.scenario_name if scenario_spec is None else scenario_spec, metrics=metrics)
    return metrics, rec


# --------------------------------------------------------------------------- files
def save_episode(record: EpisodeRecord, directory: str | os.PathLike[str]) -> Path:
    """Write ``record`` to ``directory/episode_<k>/`` (replacing an older folder of that name) and
    return that folder. The folder is written under a temporary name and renamed into place."""
    root = Path(directory)
    root.mkdir(parents=True, exist_ok=True)
    final = root / f"{EPISODE_PREFIX}{record.episode}"
    if final.is_symlink():
        raise RecordError(f"{final}: is a symbolic link; refusing to write a recording through it")
    tmp = root / f".{final.name}.tmp-{os.getpid()}-{uuid.uuid4().hex[:8]}"  # mkdir, unlike mkdtemp, honours the umask
    tmp.mkdir()
    try:
        meta = {
            "format": FORMAT, "version": FORMAT_VERSION, "episode": record.episode, "seed": record.seed,
            "policy": record.policy, "scenario": record.scenario_spec,
            "env": {"action_type": record.action_type, "max_steps": record.max_steps,
                    "terminate_on_collision": record.terminate_on_collision},
            "steps": record.steps, "digest_every": record.digest_every, "digest": DIGEST_DESCRIPTION,
            "platform": record.platform, "metrics": record.metrics,
        }
        (tmp / _META).write_text(dumps(meta, indent=1) + "\n")
        text = yaml.safe_dump(scenario_to_dict(record.scenario), sort_keys=False)
        if _scenario_from_yaml(text, str(tmp / _SCENARIO)) != dataclasses.replace(record.scenario, source=str(tmp / _SCENARIO)):
            # the replay would run another world: refuse to write a record that cannot replay
            raise RecordError(f"{final / _SCENARIO}: the scenario does not survive a YAML round trip")
        (tmp / _SCENARIO).write_text(text)
        with (tmp / _ACTIONS).open("wb") as f:
            np.savez_compressed(f, actions=record.actions, digest_steps=record.digest_steps, digests=record.digests)
        replace_dir(tmp, final)  # the one rule (swarm_env.outputs): no symlink replaced, old folder swapped out whole
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return final


def _scenario_from_yaml(text: str, source: str) -> Scenario:
    return scenario_from_dict(yaml.safe_load(text), source)


def episode_dirs(directory: str | os.PathLike[str]) -> list[Path]:
    """The episode folders of a recording directory in episode order; ``[directory]`` itself if it
    is one episode's folder. Raises :class:`RecordError` if there is none."""
    root = Path(directory)
    if (root / _META).is_file():
        return [root]
    if not root.is_dir():
        raise RecordError(f"{root}: no such recording directory")
    found = []
    for p in root.iterdir():
        suffix = p.name[len(EPISODE_PREFIX):]
        if p.is_dir() and p.name.startswith(EPISODE_PREFIX) and suffix.isdigit():
            found.append((int(suffix), p))
    if not found:
        raise RecordError(f"{root}: expected {EPISODE_PREFIX}<k>/{_META} folders (swarm-env run --record DIR), found none")
    return [p for _, p in sorted(found)]


def ensure_new_recording_dir(directory: str | os.PathLike[str]) -> None:
    """Raise :class:`RecordError` if ``directory`` already holds recorded episodes (so that one
    recording never mixes the episodes of two runs); a missing or empty directory is fine."""
    root = Path(directory)
    if root.exists() and not root.is_dir():
        raise RecordError(f"{root}: exists and is not a directory")
    if root.is_dir() and any(p.name.startswith(EPISODE_PREFIX) for p in root.iterdir()):
        raise RecordError(f"{root}: already holds recorded episodes; record into a new directory or remove them")


def load_episode(folder: str | os.PathLike[str]) -> EpisodeRecord:
    """Read one episode folder written by :func:`save_episode`. Raises :class:`RecordError` naming
    the file and what was expected."""
    folder = Path(folder)
    meta_path = folder / _META
    try:
        meta = json.loads(meta_path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise RecordError(f"{meta_path}: expected a recording's meta.json ({exc})") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise RecordError(f"{meta_path}: format: expected {FORMAT!r}, got {meta.get('format') if isinstance(meta, dict) else meta!r}")
    if meta.get("version") != FORMAT_VERSION:
        raise RecordError(f"{meta_path}: version: expected {FORMAT_VERSION} (this swarm-env reads only that), "
                          f"got {meta.get('version')!r}")
    try:
        env = meta["env"]
        fields = dict(episode=int(meta["episode"]), seed=meta["seed"], policy=str(meta["policy"]),
                      scenario_spec=str(meta["scenario"]), action_type=str(env["action_type"]),
                      max_steps=int(env["max_steps"]), terminate_on_collision=bool(env["terminate_on_collision"]),
                      digest_every=int(meta["digest_every"]), metrics=dict(meta.get("metrics") or {}),
                      platform=dict(meta.get("platform") or {}))
        steps = int(meta["steps"])
    except (KeyError, TypeError, ValueError) as exc:
        raise RecordError(f"{meta_path}: missing or bad key {exc}") from None
    scn_path = folder / _SCENARIO
    try:
        scenario = _scenario_from_yaml(scn_path.read_text(), str(scn_path))
    except (OSError, yaml.YAMLError) as exc:
        raise RecordError(f"{scn_path}: expected the recorded scenario ({' '.join(str(exc).split())})") from None
    act_path = folder / _ACTIONS
    try:
        with np.load(act_path, allow_pickle=False) as npz:
            actions, digest_steps, digests = npz["actions"], npz["digest_steps"], npz["digests"]
    except (OSError, KeyError, ValueError) as exc:
        raise RecordError(f"{act_path}: expected arrays actions, digest_steps, digests ({exc})") from None
    n = scenario.robots.count
    want = (steps, n) if fields["action_type"] == "discrete" else (steps, n, 2)
    if actions.shape != want:
        raise RecordError(f"{act_path}: actions: expected shape {want} (steps, followers{'' if len(want) == 2 else ', 2'}), "
                          f"got {actions.shape}")
    if digests.ndim != 2 or digests.shape[1] != 32 or digest_steps.shape != (digests.shape[0],):
        raise RecordError(f"{act_path}: digests: expected (D, 32) uint8 with D digest_steps, got {digests.shape} "
                          f"and {digest_steps.shape}")
    return EpisodeRecord(scenario=scenario, actions=actions, digest_steps=digest_steps.astype(np.int64),
                         digests=digests.astype(np.uint8), **fields)


def load_recording(directory: str | os.PathLike[str]) -> list[EpisodeRecord]:
    """Every episode of a recording directory (or the one episode of an episode folder), in order."""
    return [load_episode(p) for p in episode_dirs(directory)]


# --------------------------------------------------------------------------- replay
def replay_env(record: EpisodeRecord, render_mode: str | None = None) -> SwarmEnv:
    """A fresh env that replays ``record``: its resolved scenario and the recorded env options."""
    return SwarmEnv(record.scenario, render_mode=render_mode, action_type=record.action_type,
                    max_cycles=record.max_steps, terminate_on_collision=record.terminate_on_collision)


class _Stop(Exception):
    """Ends a replay early (the record ran out, or a divergence with stop_at_divergence)."""


class _Playback:
    """A policy that plays the recorded actions and compares digests through ``on_step``."""

    def __init__(self, record: EpisodeRecord, stop_at_divergence: bool) -> None:
        self.record = record
        self.stop = stop_at_divergence
        self.expected = {int(s): bytes(d) for s, d in zip(record.digest_steps, record.digests)}
        self.env: SwarmEnv | None = None
        self.t = 0
        self.checked = 0
        self.last_match: int | None = None
        self.divergence: Divergence | None = None

    def reset(self, env: SwarmEnv, seed: int | None) -> None:
        self.env = env
        self.t = 0

    def diverged(self, step: int, detail: str, recorded: bytes | None = None, replayed: bytes | None = None) -> None:
        """Note the first divergence (later ones are consequences of it)."""
        if self.divergence is None:
            self.divergence = Divergence(
                self.record.episode, self.record.seed, step, detail, None if recorded is None else recorded.hex(),
                None if replayed is None else replayed.hex(), self.last_match, _platform_note(self.record.platform))

    def act(self, observations: Mapping[str, np.ndarray], state: WorldState) -> dict[str, Any]:
        assert self.env is not None
        if self.t >= self.record.steps:  # the recorded episode ended here
            self.diverged(self.t + 1, f"the record ends at step {self.t} but the replayed episode goes on")
            raise _Stop
        row = self.record.actions[self.t]
        self.t += 1
        if self.record.action_type == "discrete":
            return {a: int(k) for a, k in zip(self.env.possible_agents, row)}
        return {a: row[i] for i, a in enumerate(self.env.possible_agents)}

    def on_step(self, actions: Mapping[str, Any] | None) -> None:
        assert self.env is not None
        state = self.env.world_state()
        want = self.expected.get(state.step)
        if want is None:
            return
        got = state_digest(state)
        self.checked += 1
        if got == want:
            if self.divergence is None:
                self.last_match = state.step
            return
        self.diverged(state.step, f"digest {want.hex()[:16]} recorded, {got.hex()[:16]} replayed", want, got)
        if self.stop:
            raise _Stop


def replay(
    record: EpisodeRecord,
    *,
    on_frame: Callable[[np.ndarray], None] | None = None,
    stop_at_divergence: bool = False,
) -> ReplayResult:
    """Re-simulate ``record`` in a fresh env (:func:`replay_env`) from ``reset(record.seed)`` with
    the recorded actions, no policy involved, comparing the state digests at the recorded steps.

    ``on_frame`` receives every frame (the env then renders ``rgb_array``), as in ``run_episode``.
    The first difference (a digest, or an episode that ends earlier or later than the record) is
    ``result.divergence``; the replay goes on to the end of the record (so a video shows all of
    it) unless ``stop_at_divergence``. It never raises for a divergence: :func:`check` does.
    """
    env = replay_env(record, render_mode="rgb_array" if on_frame is not None else None)
    playback = _Playback(record, stop_at_divergence)
    try:
        with warnings.catch_warnings():
            # the recording run already warned about its clipped actions; the replay clips them the same way
            warnings.filterwarnings("ignore", message="actions outside", category=UserWarning)
            try:
                metrics = run_episode(env, playback, record.seed, on_frame, on_step=playback.on_step)
            except _Stop:
                metrics = {"seed": record.seed, **env.episode_metrics()}
        steps = env.world_state().step
    finally:
        env.close()
    if playback.divergence is None and steps < record.steps:  # the env ended the episode before the record did
        playback.diverged(steps + 1, f"the replayed episode ended at step {steps}, the recorded one at step {record.steps}")
    return ReplayResult(record, metrics, steps, playback.checked, playback.divergence)


def check(record: EpisodeRecord) -> ReplayResult:
    """Replay ``record`` up to its first divergence and raise :class:`ReplayDivergence` there;
    return the :class:`ReplayResult` when every digest matches."""
    result = replay(record, stop_at_divergence=True)
    if result.divergence is not None:
        raise ReplayDivergence(result.divergence)
    return result


__all__ = [
    "DIGEST_EVERY", "FORMAT_VERSION", "Divergence", "EpisodeRecord", "RecordError", "Recorder", "ReplayDivergence",
    "ReplayResult", "check", "ensure_new_recording_dir", "episode_dirs", "load_episode", "load_recording",
    "record_episode", "replay", "replay_env", "save_episode", "state_digest",
]
