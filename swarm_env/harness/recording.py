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

A record is input from anyone (it may come with a bug report), so :func:`load_episode`
reads it within bounds and checks every field before anything runs: the episode folder
and its files must be real folders and regular files (no symbolic link, FIFO or device);
``meta.json`` at most :data:`~swarm_env.limits.MAX_FILE_BYTES` bytes, nested at most
:data:`~swarm_env.limits.MAX_YAML_DEPTH` deep, every field of its type and range (``T``,
``max_steps`` and ``K`` at most :data:`~swarm_env.limits.MAX_EPISODE_STEPS`; ``episode`` the
``k`` its folder's name gives, unless the folder was renamed to something else; ``seed`` any
integer ``>= 0``, as ``reset`` takes it: JSON's integers stop at 4,300 digits, and
``numpy.random.SeedSequence`` hashes even those in ~20 ms); ``scenario.yaml`` through
the scenario loader (:func:`swarm_env.scenarios.loader.load_scenario`, with its bounds);
each array of ``actions.npz`` of the dtype and the exact shape the episode implies, read
from its ``.npy`` header before its data, actions finite (discrete ones valid primitives),
and ``digest_steps`` exactly the steps above. Anything else is a one-line
:class:`RecordError` naming the file, the key and what was expected, with any value it
shows escaped (:func:`swarm_env.limits.clip_repr`).
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import os
import platform
import shutil
import stat
import struct
import uuid
import warnings
import zipfile
import zlib
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pymunk
import yaml

from swarm_env import __version__
from swarm_env.env import ACTION_TYPES, PRIMITIVE_ANGLES_DEG, SwarmEnv
from swarm_env.harness.episode import run_episode
from swarm_env.harness.policies import Policy
from swarm_env.jsonio import dumps
from swarm_env.limits import MAX_EPISODE_STEPS, MAX_FILE_BYTES, MAX_ROBOTS, MAX_YAML_DEPTH, clip_repr, printable
from swarm_env.outputs import replace_dir, write_error
from swarm_env.reading import FileRefused, JSONTooDeep, file_kind, parse_json, read_regular
from swarm_env.scenario import Scenario, ScenarioError
from swarm_env.scenarios.loader import load_scenario, scenario_to_dict
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
    # what the record says is shown escaped and cut: a message is one line that cannot rewrite a terminal
    changed = [f"{k} {clip_repr(recorded.get(k), 60)} -> {v}" if not isinstance(recorded.get(k), str)
               else f"{k} {printable(str(recorded.get(k)), 60)} -> {v}" for k, v in now.items() if recorded.get(k) != v]
    return f"; changed since recording: {', '.join(changed)}" if changed else ""


# --------------------------------------------------------------------------- recording
class Recorder:
    """The ``on_step`` hook of :func:`swarm_env.harness.episode.run_episode` that records an episode:
    every action (rows in ``env.possible_agents`` order) and the digests of the states at steps
    ``0, K, 2K, ...`` and at the last step (``K = digest_every``)."""

    def __init__(self, env: SwarmEnv, digest_every: int = DIGEST_EVERY) -> None:
        if (isinstance(digest_every, bool) or not isinstance(digest_every, int)
                or not 1 <= digest_every <= MAX_EPISODE_STEPS):
            raise ValueError(f"digest_every must be an int in [1, {MAX_EPISODE_STEPS}] "
                             f"(swarm_env.limits.MAX_EPISODE_STEPS), got {digest_every!r}")
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
        scn_path = tmp / _SCENARIO
        scn_path.write_text(yaml.safe_dump(scenario_to_dict(record.scenario), sort_keys=False))
        try:  # read back as load_episode reads it (the scenario loader, with its bounds)
            back: Scenario | None = load_scenario(scn_path)
        except ScenarioError:
            back = None
        if back != dataclasses.replace(record.scenario, source=str(scn_path)):
            # the replay would run another world (or none): refuse to write a record that cannot replay
            raise RecordError(f"{final / _SCENARIO}: the scenario does not survive a YAML round trip")
        with (tmp / _ACTIONS).open("wb") as f:
            np.savez_compressed(f, actions=record.actions, digest_steps=record.digest_steps, digests=record.digests)
        replace_dir(tmp, final)  # the one rule (swarm_env.outputs): no symlink replaced, old folder swapped out whole
    except OSError as exc:  # a full disk: one line, no half-written folder left
        shutil.rmtree(tmp, ignore_errors=True)
        raise write_error(final, exc, "no recording was written there") from None
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return final


# --------------------------------------------------------------------------- reading a record
# A record is read within the scenario files' bounds (swarm_env.limits), no new numbers: meta.json is a small JSON
# file as a scenario file is a small YAML one (MAX_FILE_BYTES, MAX_YAML_DEPTH), and actions.npz holds at most the
# arrays of a MAX_EPISODE_STEPS-step episode of MAX_ROBOTS followers.
_DIGEST_BYTES = 32
#: Room for an .npy header (version 1.0 headers are at most 64 KiB; longer ones are refused).
_NPY_HEADER_BYTES = 1 << 16
_MAX_ARRAY_BYTES = MAX_EPISODE_STEPS * MAX_ROBOTS * 2 * 8 + (MAX_EPISODE_STEPS + 1) * (8 + _DIGEST_BYTES)
#: The largest actions.npz: the largest arrays, their headers and the zip's, and deflate's worst case on
#: incompressible data (a few bytes per 16 KiB block; an eighth is ample).
_MAX_ACTIONS_BYTES = _MAX_ARRAY_BYTES + _MAX_ARRAY_BYTES // 8 + 4 * _NPY_HEADER_BYTES
#: What reading a zip member or an .npy header raises for a corrupt file (never a traceback).
_CORRUPT = (zipfile.BadZipFile, zipfile.LargeZipFile, zlib.error, struct.error, OSError, EOFError, ValueError,
            KeyError, TypeError, OverflowError, RuntimeError, NotImplementedError, SyntaxError, RecursionError)
_ABSENT = object()


def _error(path: str | os.PathLike[str], key: str, expected: str, got: Any = _ABSENT) -> RecordError:
    """``RecordError("<path>: <key>: expected <expected>[, got <value>]")``: one line, the value escaped and cut."""
    got_txt = "" if got is _ABSENT else f", got {clip_repr(got)}"
    return RecordError(f"{printable(os.fspath(path), 300)}: {printable(key, 100)}: expected {expected}{got_txt}")


def _lstat(path: Path, what: str) -> os.stat_result:
    try:
        return os.lstat(path)
    except FileNotFoundError:
        raise _error(path, "<file>", f"{what} (not found)") from None
    except OSError as exc:
        raise _error(path, "<file>", f"{what} ({printable(exc.strerror or str(exc), 200)})") from None


def _check_regular(path: Path, what: str) -> None:
    """Refuse ``path`` unless it is a regular file itself: no symbolic link (not even to a regular file: a
    record is a self-contained folder), FIFO or device. Only ``lstat``: nothing is opened, nothing waits."""
    mode = _lstat(path, what).st_mode
    if not stat.S_ISREG(mode):
        raise _error(path, "<file>", f"{what}, a regular file (this is a {file_kind(mode)})")


def _check_folder(folder: Path) -> None:
    mode = _lstat(folder, "an episode folder").st_mode
    if not stat.S_ISDIR(mode):
        raise _error(folder, "<folder>", f"an episode folder, a real directory (this is a {file_kind(mode)})")


def _one_line(exc: ScenarioError) -> str:
    """The first problem of a scenario error (it names the file, the key and what was expected), on one line."""
    more = len(exc.errors) - 1
    first = (str(exc.errors[0]).splitlines() or [""])[0]
    return first + (f" (and {more} more problem{'s' if more > 1 else ''})" if more else "")


def _read_meta(path: Path) -> dict[str, Any]:
    raw = _read_bytes(path, MAX_FILE_BYTES, "(swarm_env.limits.MAX_FILE_BYTES)", "a recording's meta.json")
    try:
        meta = parse_json(raw, MAX_YAML_DEPTH)  # the one JSON rule: depth bounded before parsing, strict numbers
    except JSONTooDeep:
        raise _error(path, "<file>", f"JSON nested at most {MAX_YAML_DEPTH} deep (swarm_env.limits.MAX_YAML_DEPTH)"
                     ) from None
    except ValueError as exc:
        raise _error(path, "<file>", f"a recording's meta.json in JSON ({printable(str(exc), 200)})") from None
    if not isinstance(meta, dict):
        raise _error(path, "<top level>", "a JSON object (a recording's meta.json)", f"a {type(meta).__name__}")
    return meta


def _value(path: Path, mapping: Mapping[str, Any], key: str, name: str | None = None) -> Any:
    if key not in mapping:
        raise _error(path, name or key, "a value (required key missing)")
    return mapping[key]


def _int(path: Path, value: Any, key: str, lo: int, hi: int | None = None, bound: str = "") -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < lo or (hi is not None and value > hi):
        span = f">= {lo}" if hi is None else f"in [{lo}, {hi}]"
        raise _error(path, key, f"an integer {span}{bound}", value)
    return value


def _str(path: Path, value: Any, key: str) -> str:
    if not isinstance(value, str):
        raise _error(path, key, "a string", value)
    return value


def _meta_fields(path: Path, meta: Mapping[str, Any]) -> tuple[dict[str, Any], int]:
    """The :class:`EpisodeRecord` fields held by ``meta.json``, each checked, and ``T`` (its ``steps``)."""
    if meta.get("format") != FORMAT:
        raise _error(path, "format", repr(FORMAT), meta.get("format"))
    if not (type(meta.get("version")) is int and meta.get("version") == FORMAT_VERSION):
        raise _error(path, "version", f"{FORMAT_VERSION} (this swarm-env reads only that)", meta.get("version"))
    env = _value(path, meta, "env")
    if not isinstance(env, dict):
        raise _error(path, "env", "an object {action_type, max_steps, terminate_on_collision}", env)
    seed = _value(path, meta, "seed")
    if seed is not None:
        _int(path, seed, "seed", 0, bound=" or null (the seed of reset)")
    action_type = _value(path, env, "action_type", "env.action_type")
    if action_type not in ACTION_TYPES:
        raise _error(path, "env.action_type", f"one of {', '.join(ACTION_TYPES)}", action_type)
    terminate = _value(path, env, "terminate_on_collision", "env.terminate_on_collision")
    if not isinstance(terminate, bool):
        raise _error(path, "env.terminate_on_collision", "true or false", terminate)
    bound = " (swarm_env.limits.MAX_EPISODE_STEPS)"
    platform_info = meta.get("platform") or {}
    if not isinstance(platform_info, dict) or not all(isinstance(v, str) for v in platform_info.values()):
        raise _error(path, "platform", "an object of strings (what the recording ran on)", platform_info)
    metrics = meta.get("metrics") or {}
    if not isinstance(metrics, dict):
        raise _error(path, "metrics", "an object (the recorded episode's metrics)", metrics)
    fields = dict(
        episode=_int(path, _value(path, meta, "episode"), "episode", 0), seed=seed,
        policy=_str(path, _value(path, meta, "policy"), "policy"),
        scenario_spec=_str(path, _value(path, meta, "scenario"), "scenario"), action_type=action_type,
        max_steps=_int(path, _value(path, env, "max_steps", "env.max_steps"), "env.max_steps", 1, MAX_EPISODE_STEPS,
                       bound),
        terminate_on_collision=terminate,
        digest_every=_int(path, _value(path, meta, "digest_every"), "digest_every", 1, MAX_EPISODE_STEPS, bound),
        metrics=metrics, platform=platform_info,
    )
    steps = _int(path, _value(path, meta, "steps"), "steps", 1, MAX_EPISODE_STEPS, bound)
    return fields, steps


def _read_scenario(path: Path) -> Scenario:
    _check_regular(path, "the recorded scenario")
    try:
        return load_scenario(path)  # a Path is always a file: the loader's bounds on size, nesting, aliases, values
    except ScenarioError as exc:
        raise RecordError(_one_line(exc)) from None


def _read_bytes(path: Path, limit: int, limit_text: str, what: str) -> bytes:
    """The bytes of the regular file ``path`` (no symbolic link) if it holds at most ``limit``
    (:func:`swarm_env.reading.read_regular`: checked with fstat before reading, a FIFO never waited on)."""
    _check_regular(path, what)
    try:
        return read_regular(path, limit, limit_text=limit_text, follow_symlinks=False)
    except FileNotFoundError:
        raise _error(path, "<file>", f"{what} (not found)") from None
    except FileRefused as exc:
        raise _error(path, "<file>", exc.expected, *(() if exc.got is None else (exc.got,))) from None


def _read_member(path: Path, zf: zipfile.ZipFile, name: str, shape: tuple[int, ...], kinds: str,
                 itemsizes: tuple[int, ...], dtype_text: str, what: str, if_empty: str = "") -> np.ndarray:
    """The array ``name`` of the npz ``zf``, read only once its ``.npy`` header says ``shape`` and a dtype of one of
    ``kinds`` and ``itemsizes``: nothing larger than the episode is ever allocated or decompressed. ``if_empty``
    is added to the message when the array is empty and should not be."""
    member = f"{name}.npy"
    if member not in zf.NameToInfo:
        raise _error(path, name, f"an array {name} ({member} in the zip file)", "none")
    # The size the zip says the member decompresses to bounds what reading it can decompress (a zip bomb, or an
    # .npy 2.0 header that claims gigabytes): at most the array's largest data and a header.
    largest = int(np.prod(shape, dtype=np.int64)) * max(itemsizes) + _NPY_HEADER_BYTES
    declared = zf.NameToInfo[member].file_size
    if declared > largest:
        raise _error(path, name, f"an array of shape {shape} ({what}): at most {largest} bytes as .npy",
                     f"{declared} bytes")
    try:
        with zf.open(member) as fp:
            version = np.lib.format.read_magic(fp)
            if version == (1, 0):
                got_shape, fortran, dtype = np.lib.format.read_array_header_1_0(fp)
            elif version == (2, 0):
                got_shape, fortran, dtype = np.lib.format.read_array_header_2_0(fp)
            else:
                raise ValueError(f"an .npy file of version 1.0 or 2.0, not {version}")
            if dtype.kind not in kinds or dtype.itemsize not in itemsizes:  # never an object or structured dtype
                raise _error(path, name, f"{dtype_text} ({what})", str(dtype))
            if tuple(got_shape) != shape:
                note = f"; {if_empty}" if if_empty and 0 in got_shape else ""
                raise _error(path, name, f"shape {shape} ({what}){note}", tuple(got_shape))
            size = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
            data = fp.read(size)
    except RecordError:
        raise
    except _CORRUPT as exc:
        raise _error(path, name, f"an array stored as .npy ({printable(f'{type(exc).__name__}: {exc}', 200)})") from None
    if len(data) != size:
        raise _error(path, name, f"{size} bytes of data for shape {shape} (the member is cut short)", f"{len(data)} bytes")
    flat = np.frombuffer(data, dtype=dtype)
    return np.array(flat.reshape(shape, order="F" if fortran else "C"), dtype=dtype.newbyteorder("="))


def _digest_schedule(steps: int, digest_every: int) -> list[int]:
    """The steps whose digests a record of ``steps`` steps taken every ``digest_every`` holds: ``0, K, 2K, ...``
    and the last step."""
    return sorted(set(range(0, steps + 1, digest_every)) | {steps})


def _read_arrays(path: Path, steps: int, n: int, action_type: str, digest_every: int
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    raw = _read_bytes(path, _MAX_ACTIONS_BYTES, "(the arrays of an episode of swarm_env.limits.MAX_EPISODE_STEPS "
                      "steps and MAX_ROBOTS followers)", "a recording's actions.npz")
    try:
        zf = zipfile.ZipFile(io.BytesIO(raw))
    except _CORRUPT as exc:
        raise _error(path, "<file>", f"a zip file of arrays actions, digest_steps, digests (numpy .npz) "
                     f"({printable(f'{type(exc).__name__}: {exc}', 200)})") from None
    with zf:
        if action_type == "discrete":
            actions = _read_member(path, zf, "actions", (steps, n), "iu", (1, 2, 4, 8), "int64",
                                   "steps, followers")
            low, high = int(actions.min(initial=0)), int(actions.max(initial=0))
            if low < 0 or high > len(PRIMITIVE_ANGLES_DEG):
                bad = np.argwhere((actions < 0) | (actions > len(PRIMITIVE_ANGLES_DEG)))[0]
                raise _error(path, "actions", f"discrete actions in [0, {len(PRIMITIVE_ANGLES_DEG)}] (step "
                             f"{bad[0] + 1}, follower {bad[1]})", int(actions[tuple(bad)]))
            actions = actions.astype(np.int64)
        else:
            actions = _read_member(path, zf, "actions", (steps, n, 2), "f", (8,), "float64",
                                   "steps, followers, 2")
            finite = np.isfinite(actions)
            if not finite.all():
                bad = np.argwhere(~finite)[0]
                raise _error(path, "actions", f"finite numbers (step {bad[0] + 1}, follower {bad[1]})",
                             float(actions[tuple(bad)]))
        want = _digest_schedule(steps, digest_every)
        steps_what = (f"one per digest: the steps s in [0, {steps}] with s % {clip_repr(digest_every)} == 0 "
                      f"(digest_every), and the last step {steps}")
        digest_steps = _read_member(path, zf, "digest_steps", (len(want),), "iu", (1, 2, 4, 8), "int64",
                                    steps_what, "the record holds no digests: nothing could be checked")
        if digest_steps.tolist() != want:
            first = next(i for i, (a, b) in enumerate(zip(digest_steps.tolist(), want)) if a != b)
            raise _error(path, f"digest_steps[{first}]", f"{want[first]} ({steps_what})", int(digest_steps[first]))
        digests = _read_member(path, zf, "digests", (len(want), _DIGEST_BYTES), "u", (1,), "uint8",
                               f"one {_DIGEST_BYTES}-byte digest per digest step",
                               "the record holds no digests: nothing could be checked")
    return actions, digest_steps.astype(np.int64), digests.astype(np.uint8)


def episode_dirs(directory: str | os.PathLike[str]) -> list[Path]:
    """The episode folders of a recording directory in episode order; ``[directory]`` itself if it
    is one episode's folder. Raises :class:`RecordError` if there is none, or if one is a symbolic link."""
    root = Path(directory)
    if os.path.lexists(root / _META):  # whatever it is: load_episode says what is wrong with it
        return [root]
    if not root.is_dir():
        raise _error(root, "<folder>", "a recording directory (no such recording directory)")
    found = []
    try:
        for p in root.iterdir():
            suffix = p.name[len(EPISODE_PREFIX):]
            if not (p.name.startswith(EPISODE_PREFIX) and suffix.isascii() and suffix.isdigit()):
                continue
            if p.is_symlink():
                raise _error(p, "<folder>", "an episode folder, a real directory (this is a symbolic link)")
            if p.is_dir():
                found.append((int(suffix), p))
    except OSError as exc:
        raise _error(root, "<folder>", f"a readable recording directory ({printable(exc.strerror or str(exc), 200)})"
                     ) from None
    if not found:
        raise RecordError(f"{printable(str(root), 300)}: expected {EPISODE_PREFIX}<k>/{_META} folders "
                          "(swarm-env run --record DIR), found none")
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
    """Read one episode folder written by :func:`save_episode`, within bounds (the module docstring).
    Raises :class:`RecordError` naming the file, the key and what was expected."""
    folder = Path(folder)
    _check_folder(folder)
    meta_path = folder / _META
    fields, steps = _meta_fields(meta_path, _read_meta(meta_path))
    suffix = folder.name[len(EPISODE_PREFIX):]
    if folder.name.startswith(EPISODE_PREFIX) and suffix.isascii() and suffix.isdigit() and int(suffix) != fields[
            "episode"]:  # a folder renamed by hand (any other name) is fine; one that names another episode is not
        raise _error(meta_path, "episode", f"{int(suffix)} (the episode its folder {folder.name} names)",
                     fields["episode"])
    scenario = _read_scenario(folder / _SCENARIO)
    actions, digest_steps, digests = _read_arrays(folder / _ACTIONS, steps, scenario.robots.count,
                                                  fields["action_type"], fields["digest_every"])
    return EpisodeRecord(scenario=scenario, actions=actions, digest_steps=digest_steps, digests=digests, **fields)


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
