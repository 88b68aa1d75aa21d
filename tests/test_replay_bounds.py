"""Tampered records (issue 35, "Records"): ``swarm-env replay DIR [--check]`` reads a record within bounds.

Every case below starts from a real record (:func:`swarm_env.harness.recording.save_episode`), tampers with
one of its files as a hostile reviewer did, and runs the replay command in this process under a time limit
(SIGALRM) and an address-space limit a little above what the process already uses: each must end in exit
code 2 and one ``error:`` line naming the file, with no traceback and no control character, quickly.
Before the record bounds these cases gave tracebacks, ran out of memory, hung, or passed ``--check``
without checking a single digest.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json
import os
import shutil
import signal
import sys
import time
import zipfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from swarm_env.env import SwarmEnv
from swarm_env.harness import recording
from swarm_env.harness.cli import main
from swarm_env.harness.policies import load_policy
from swarm_env.harness.recording import load_episode, record_episode, save_episode
from swarm_env.limits import MAX_FILE_BYTES

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="FIFOs, symlinks, SIGALRM and RLIMIT_AS are POSIX")

STEPS = 6
TIME_LIMIT_S = 60  # the alarm: a case that hangs fails here instead of hanging the suite
FAST_S = 20.0  # what each case must finish within (they take well under a second)
EXTRA_ADDRESS_SPACE = 1536 << 20  # what a case may map beyond the process's current size


@pytest.fixture(scope="module")
def records(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A small continuous and a small discrete record (one episode folder each)."""
    base = tmp_path_factory.mktemp("records")
    out = {}
    for action_type in ("continuous", "discrete"):
        env = SwarmEnv("paper_vo_0", action_type=action_type, max_cycles=STEPS)
        try:
            _, rec = record_episode(env, load_policy("random", env), 3, policy_spec="random")
        finally:
            env.close()
        out[action_type] = save_episode(rec, base / action_type)
    return out


@pytest.fixture()
def record(records: dict[str, Path], tmp_path: Path) -> Path:
    """A fresh copy of the continuous record: ``<tmp>/rec/episode_0``."""
    folder = tmp_path / "rec" / "episode_0"
    shutil.copytree(records["continuous"], folder)
    return folder


class _Hung(Exception):
    """Raised by the alarm (not an OSError, which a reader could take for a failed read)."""


@contextlib.contextmanager
def _bounded() -> Iterator[None]:
    """Fail (_Hung, MemoryError) instead of hanging or exhausting memory."""

    def on_alarm(signum: int, frame: Any) -> None:
        raise _Hung(f"the case ran past {TIME_LIMIT_S} s")

    previous = signal.signal(signal.SIGALRM, on_alarm)
    signal.alarm(TIME_LIMIT_S)
    limits = None
    try:
        import resource

        limits = resource.getrlimit(resource.RLIMIT_AS)
        with open("/proc/self/statm") as f:
            size = int(f.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
        soft = size + EXTRA_ADDRESS_SPACE
        if limits[1] == resource.RLIM_INFINITY or soft < limits[1]:
            resource.setrlimit(resource.RLIMIT_AS, (soft, limits[1]))
    except (ImportError, OSError, ValueError):
        limits = None
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
        if limits is not None:
            import resource

            resource.setrlimit(resource.RLIMIT_AS, limits)


def _replay_error(capsys: pytest.CaptureFixture[str], *argv: str) -> str:
    """Run ``swarm-env replay ARGV`` bounded; assert exit 2 and one error line, fast; return that line."""
    capsys.readouterr()
    t0 = time.perf_counter()
    with _bounded():
        code = main(["replay", *argv])
    elapsed = time.perf_counter() - t0
    captured = capsys.readouterr()
    assert code == 2, (code, captured.err[-2000:])
    lines = captured.err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), captured.err[-2000:]
    assert "Traceback" not in captured.err
    assert not any(ord(c) < 32 or 0x7F <= ord(c) < 0xA0 for c in captured.err.rstrip("\n")), repr(captured.err)
    assert elapsed < FAST_S, elapsed
    return lines[0]


# --------------------------------------------------------------------------- tampering helpers
def _meta(folder: Path) -> dict[str, Any]:
    return json.loads((folder / "meta.json").read_text())


def _set_meta(folder: Path, key: str, value: Any) -> None:
    meta = _meta(folder)
    target, _, sub = key.partition(".")
    if sub:
        meta[target][sub] = value
    else:
        meta[target] = value
    (folder / "meta.json").write_text(json.dumps(meta))


def _arrays(folder: Path) -> dict[str, np.ndarray]:
    with np.load(folder / "actions.npz") as npz:
        return {k: npz[k] for k in npz.files}


def _set_arrays(folder: Path, **arrays: np.ndarray) -> None:
    data = _arrays(folder)
    data.update(arrays)
    with (folder / "actions.npz").open("wb") as f:
        np.savez(f, **data)


def _npy_header_only(shape: tuple[int, ...], descr: str = "<f8", data: bytes = b"\0" * 64) -> bytes:
    """An .npy whose header claims ``shape`` but which holds only ``data``."""
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": descr, "fortran_order": False, "shape": shape})
    return buf.getvalue() + data


def _replace_member(folder: Path, name: str, content: bytes) -> None:
    arrays = _arrays(folder)
    with zipfile.ZipFile(folder / "actions.npz", "w", zipfile.ZIP_DEFLATED) as zf:
        for key, value in arrays.items():
            if key == name:
                zf.writestr(f"{key}.npy", content)
            else:
                buf = io.BytesIO()
                np.lib.format.write_array(buf, value)
                zf.writestr(f"{key}.npy", buf.getvalue())


def _zip_bomb(folder: Path) -> None:
    # the right header and data, then 50 MB of zeros (50 kB compressed): the member says it inflates to 50 MB
    actions = _arrays(folder)["actions"]
    buf = io.BytesIO()
    np.lib.format.write_array(buf, actions)
    _replace_member(folder, "actions", buf.getvalue() + bytes(50 << 20))


def _sparse(path: Path, size: int = 10**10) -> None:
    """``path`` keeps its text and grows (sparsely: no disk used) to ``size`` bytes."""
    with path.open("r+b") as f:
        f.truncate(size)


def _fifo(path: Path) -> None:
    path.unlink()
    os.mkfifo(path)


def _to_symlink(path: Path, target: Path | str | None = None) -> None:
    """Replace ``path`` with a symlink (to a copy of it kept elsewhere unless ``target`` is given)."""
    if target is None:
        target = path.parent.parent / f"elsewhere_{path.name}"
        shutil.move(str(path), target)
    else:
        path.unlink()
    path.symlink_to(target)


def _bad_action(value: float) -> Callable[[Path], None]:
    def tamper(folder: Path) -> None:
        actions = _arrays(folder)["actions"].copy()
        actions[2, 0, 1] = value
        _set_arrays(folder, actions=actions)
    return tamper


def _nested_meta(depth: int) -> Callable[[Path], None]:
    def tamper(folder: Path) -> None:
        text = (folder / "meta.json").read_text()
        head, _, _ = text.rpartition("}")
        (folder / "meta.json").write_text(head + ', "extra": ' + "[" * depth + "]" * depth + "}")
    return tamper


def _nested_scenario(folder: Path) -> None:
    depth = 100_000
    with (folder / "scenario.yaml").open("a") as f:
        f.write("extra: " + "[" * depth + "]" * depth + "\n")


def _big_scenario(folder: Path) -> None:
    # valid YAML (a long comment), just over the scenario files' size bound: parsed, it would replay fine
    with (folder / "scenario.yaml").open("a") as f:
        f.write("# " + "x" * (MAX_FILE_BYTES + 10) + "\n")


def _emptied_digests(folder: Path) -> None:
    _set_arrays(folder, digest_steps=np.zeros(0, dtype=np.int64), digests=np.zeros((0, 32), dtype=np.uint8))


def _digest_steps(values: Callable[[np.ndarray], np.ndarray]) -> Callable[[Path], None]:
    def tamper(folder: Path) -> None:
        _set_arrays(folder, digest_steps=values(_arrays(folder)["digest_steps"]))
    return tamper


def _first_digest_only(folder: Path) -> None:
    # the digests of every later step dropped: a check of step 0 alone would pass whatever the actions are
    arrays = _arrays(folder)
    _set_arrays(folder, digest_steps=arrays["digest_steps"][:1], digests=arrays["digests"][:1])


def _not_a_zip(folder: Path) -> None:
    (folder / "actions.npz").write_bytes(b"PK\x03\x04 this is no zip file " * 20)


def _npy_not_npz(folder: Path) -> None:
    actions = _arrays(folder)["actions"]
    with (folder / "actions.npz").open("wb") as f:
        np.save(f, actions)


def _meta_seed_nan(folder: Path) -> None:
    text = (folder / "meta.json").read_text()
    (folder / "meta.json").write_text(text.replace('"seed": 3', '"seed": NaN', 1))


# name -> (tamper, the file the error line names, a fragment it holds)
CASES: dict[str, tuple[Callable[[Path], None], str, str]] = {
    # gave a Python traceback
    "nan action": (_bad_action(float("nan")), "actions.npz", "actions: expected finite numbers (step 3, follower 0)"),
    "inf action": (_bad_action(float("inf")), "actions.npz", "actions: expected finite numbers"),
    "bad zip": (_not_a_zip, "actions.npz", "expected a zip file of arrays"),
    "npy instead of npz": (_npy_not_npz, "actions.npz", "expected a zip file of arrays"),
    "max_steps 0": (lambda d: _set_meta(d, "env.max_steps", 0), "meta.json", "env.max_steps: expected an integer in [1, "),
    "max_steps -1": (lambda d: _set_meta(d, "env.max_steps", -1), "meta.json", "env.max_steps: expected an integer"),
    "string seed": (lambda d: _set_meta(d, "seed", "3"), "meta.json", "seed: expected an integer >= 0 or null"),
    "NaN seed": (_meta_seed_nan, "meta.json", "seed: expected a finite number, got nan"),
    "meta nested 100000 deep": (_nested_meta(100_000), "meta.json", "JSON nested at most 16 deep"),
    "scenario nested 100000 deep": (_nested_scenario, "scenario.yaml", "nested at most 16 deep"),
    "bad action_type": (lambda d: _set_meta(d, "env.action_type", "telepathic"), "meta.json",
                        "env.action_type: expected one of continuous, discrete"),
    # ran out of memory
    "member claims 5.96 GiB": (lambda d: _replace_member(d, "actions", _npy_header_only((400_000_000, 1, 2))),
                               "actions.npz", "actions: expected shape (6, 2, 2)"),
    "member inflates to 50 MB": (_zip_bomb, "actions.npz", "actions: expected an array of shape (6, 2, 2)"),
    "header of 1e12 rows": (lambda d: _replace_member(d, "digests", _npy_header_only((10**12, 32), "|u1")),
                            "actions.npz", "digests: expected shape (7, 32)"),
    "10 GB sparse meta.json": (lambda d: _sparse(d / "meta.json"), "meta.json", "MAX_FILE_BYTES"),
    "10 GB sparse scenario.yaml": (lambda d: _sparse(d / "scenario.yaml"), "scenario.yaml", "MAX_FILE_BYTES"),
    # hung
    "meta.json a FIFO": (lambda d: _fifo(d / "meta.json"), "meta.json", "a regular file (this is a FIFO)"),
    "scenario.yaml a FIFO": (lambda d: _fifo(d / "scenario.yaml"), "scenario.yaml", "a regular file (this is a FIFO)"),
    "actions.npz a FIFO": (lambda d: _fifo(d / "actions.npz"), "actions.npz", "a regular file (this is a FIFO)"),
    "scenario.yaml -> /dev/zero": (lambda d: _to_symlink(d / "scenario.yaml", "/dev/zero"), "scenario.yaml",
                                   "this is a symbolic link"),
    "scenario.yaml over the size bound": (_big_scenario, "scenario.yaml", "MAX_FILE_BYTES"),
    # --check passed having checked no digest
    "digests emptied": (_emptied_digests, "actions.npz", "the record holds no digests: nothing could be checked"),
    "digest_steps negative": (_digest_steps(lambda s: s - 100), "actions.npz", "digest_steps[0]: expected 0"),
    "digest_steps huge": (_digest_steps(lambda s: s + 10**12), "actions.npz", "digest_steps[0]: expected 0"),
    "digest_steps NaN": (_digest_steps(lambda s: np.full(s.shape, np.nan)), "actions.npz",
                         "digest_steps: expected int64"),
    "digest_steps a subset": (_first_digest_only, "actions.npz", "digest_steps: expected shape (7,)"),
    "digest_every 0": (lambda d: _set_meta(d, "digest_every", 0), "meta.json", "digest_every: expected an integer in [1, "),
    "digest_every 10**300": (lambda d: _set_meta(d, "digest_every", 10**300), "meta.json",
                             "digest_every: expected an integer in [1, "),
    # the record says it is another episode than its folder does
    "episode 5 in episode_0": (lambda d: _set_meta(d, "episode", 5), "meta.json",
                               "episode: expected 0 (the episode its folder episode_0 names), got 5"),
    # ran, with another value than the record's
    "terminate_on_collision a string": (lambda d: _set_meta(d, "env.terminate_on_collision", "no"), "meta.json",
                                        "env.terminate_on_collision: expected true or false"),
    "meta nested 20 deep": (_nested_meta(20), "meta.json", "JSON nested at most 16 deep"),
    # symbolic links were followed
    "meta.json a symlink": (lambda d: _to_symlink(d / "meta.json"), "meta.json", "this is a symbolic link"),
    "scenario.yaml a symlink": (lambda d: _to_symlink(d / "scenario.yaml"), "scenario.yaml", "this is a symbolic link"),
    "actions.npz a symlink": (lambda d: _to_symlink(d / "actions.npz"), "actions.npz", "this is a symbolic link"),
    "episode folder a symlink": (lambda d: _to_symlink(d), "episode_0", "this is a symbolic link"),
}


@pytest.mark.parametrize("check", [True, False], ids=["check", "replay"])
@pytest.mark.parametrize("case", list(CASES))
def test_a_tampered_record_is_one_error_line(case: str, check: bool, record: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    tamper, filename, fragment = CASES[case]
    tamper(record)
    line = _replay_error(capsys, str(record.parent), *(["--check"] if check else []))
    assert f"episode_0/{filename}" in line or (filename == "episode_0" and "rec/episode_0:" in line), line
    assert fragment in line, line


def test_a_record_folder_renamed_by_hand_still_replays(record: Path, capsys: pytest.CaptureFixture[str]) -> None:
    renamed = record.parent / "bug_report"
    record.rename(renamed)
    assert main(["replay", str(renamed), "--check"]) == 0, capsys.readouterr()


def test_the_episode_folder_given_as_a_symlink(record: Path, capsys: pytest.CaptureFixture[str]) -> None:
    link = record.parent.parent / "link"
    link.symlink_to(record, target_is_directory=True)
    line = _replay_error(capsys, str(link), "--check")
    assert f"{link}: <folder>: expected an episode folder, a real directory (this is a symbolic link)" in line


def test_discrete_actions_out_of_range(records: dict[str, Path], tmp_path: Path,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    folder = tmp_path / "rec" / "episode_0"
    shutil.copytree(records["discrete"], folder)
    actions = _arrays(folder)["actions"].copy()
    actions[4, 1] = 10  # the env has primitives 0..9
    _set_arrays(folder, actions=actions)
    line = _replay_error(capsys, str(folder), "--check")
    assert "actions.npz: actions: expected discrete actions in [0, 9] (step 5, follower 1), got 10" in line


def test_control_characters_from_the_record_never_reach_the_terminal(record: Path,
                                                                      capsys: pytest.CaptureFixture[str]) -> None:
    # in what a replay prints: policy, scenario spec and the platform note of a divergence
    meta = _meta(record)
    meta.update(policy="random\x1b]0;owned\x07", scenario="paper\x1b[2J\u202evo_0")
    meta["platform"]["numpy"] = "9\x1b[31m"
    (record / "meta.json").write_text(json.dumps(meta))
    actions = _arrays(record)["actions"].copy()
    actions[1] = -actions[1] if np.any(actions[1]) else 1.0
    _set_arrays(record, actions=actions)
    capsys.readouterr()
    assert main(["replay", str(record), "--check"]) == 1
    captured = capsys.readouterr()
    assert "random\\x1b]0;owned\\x07 on paper\\x1b[2J\\u202evo_0" in captured.out
    assert "numpy 9\\x1b[31m ->" in captured.err
    for text in (captured.out, captured.err):
        assert "\x1b" not in text and "\x07" not in text and "\u202e" not in text
    # and in error messages
    _set_meta(record, "seed", "\x1b[2J")
    line = _replay_error(capsys, str(record))
    assert "seed: expected an integer >= 0 or null (the seed of reset), got '\\x1b[2J'" in line


def test_check_fails_when_no_digest_was_checked(record: Path, monkeypatch: pytest.MonkeyPatch,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    # a record without digests (made in Python: load_episode refuses one) checks nothing: not a pass
    rec = dataclasses.replace(load_episode(record), digest_steps=np.zeros(0, dtype=np.int64),
                              digests=np.zeros((0, 32), dtype=np.uint8))
    monkeypatch.setattr(recording, "load_recording", lambda directory: [rec])
    line = _replay_error(capsys, str(record), "--check")
    assert line == "error: replay --check: episode 0: no digests were checked (the record holds none at the steps replayed)"
    assert main(["replay", str(record)]) == 0  # without --check the replay (of a video) goes on
    assert f"{STEPS} of {STEPS} steps replayed, 0 digests checked" in capsys.readouterr().out


def test_untampered_records_still_replay(records: dict[str, Path], tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    root = tmp_path / "rec"
    shutil.copytree(records["continuous"], root / "episode_0")
    shutil.copytree(records["discrete"], root / "episode_1")
    _set_meta(root / "episode_1", "episode", 1)  # recorded alone as episode 0; its folder and meta.json must agree
    (root / "episode_\u00b2").mkdir()  # not an episode folder (a Unicode digit, which int() refuses): skipped
    (root / ".episode_2.tmp-1-abc").mkdir()  # a temporary folder of a writer: skipped
    capsys.readouterr()
    assert main(["replay", str(root), "--check"]) == 0
    out = capsys.readouterr().out
    for k in (0, 1):  # in the folders' order
        assert out.count(f"episode {k}: random on paper_vo_0, {STEPS} of {STEPS} steps replayed, {STEPS + 1} digests "
                         "checked") == 1
