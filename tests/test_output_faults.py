"""Outputs under faults (issue 35, item 4): special files are never replaced, a full disk is one line and
leaves no torn file, every appended line is written whole, one sweep at a time writes a directory, and
``episodes.jsonl`` is checked line by line (duplicates, bad values) when a sweep is resumed."""

from __future__ import annotations

import errno
import json
import os
import resource
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from swarm_env.harness.leaderboard import EPISODES_FILE, _Sweep, run_leaderboard
from swarm_env.harness.video import VideoWriter, _check_mp4
from swarm_env.outputs import OutputError, append_line, atomic_write_text, check_target, directory_lock, open_atomic


# --------------------------------------------------------------------------- special files
def test_overwrite_never_replaces_a_fifo_or_a_device(tmp_path: Path) -> None:
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    for target in (fifo, Path("/dev/null")):
        with pytest.raises(OutputError, match="not a regular file"):
            check_target(target, overwrite=True)
        with pytest.raises(OutputError, match="not a regular file"):
            atomic_write_text(target, "x")
    assert Path(fifo).exists() and not fifo.is_file()  # still the FIFO
    with pytest.raises(OutputError, match="FIFO"):
        append_line(fifo, "x")  # O_NONBLOCK: refused at once, not waiting for a reader


def test_cli_json_to_dev_null_is_refused(capsys: pytest.CaptureFixture[str]) -> None:
    from swarm_env.harness.cli import main

    assert main(["run", "--scenario", "paper_vo_0", "--policy", "zero", "--max-cycles", "3", "--json", "/dev/null",
                 "--overwrite"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: /dev/null: is a device, not a regular file") and err.count("\n") == 1
    assert Path("/dev/null").is_char_device()


# --------------------------------------------------------------------------- failed and short writes
def test_a_failed_write_is_one_line_and_leaves_the_old_file(tmp_path: Path) -> None:
    target = tmp_path / "out.json"
    target.write_text("old")
    with pytest.raises(OutputError, match=r"out.json: cannot write \(No space left on device\); free some space"):
        with open_atomic(target) as tmp:
            tmp.write_text("partial")
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    assert target.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["out.json"]


def test_append_line_finishes_short_writes(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    real_write = os.write
    calls = []

    def three_bytes(fd: int, data: bytes | memoryview) -> int:
        calls.append(len(data))
        return real_write(fd, bytes(data[:3]))

    monkeypatch.setattr(os, "write", three_bytes)
    path = tmp_path / "episodes.jsonl"
    append_line(path, '{"a": 1}')
    append_line(path, '{"b": 22}')
    monkeypatch.undo()
    assert path.read_text() == '{"a": 1}\n{"b": 22}\n'
    assert len(calls) > 2


def test_append_line_on_a_full_disk_takes_back_its_part(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "episodes.jsonl"
    append_line(path, "first")
    real_write = os.write
    state = {"n": 0}

    def fills_up(fd: int, data: bytes | memoryview) -> int:
        state["n"] += 1
        if state["n"] == 1:
            return real_write(fd, bytes(data[:4]))  # part of the line, then the disk is full
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "write", fills_up)
    with pytest.raises(OutputError, match="No space left on device.*the line was not added"):
        append_line(path, "second line")
    monkeypatch.undo()
    assert path.read_text() == "first\n"  # no torn line for the next --resume to trip on


def _limited(limit: int, *argv: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    """``argv`` run with files limited to ``limit`` bytes (RLIMIT_FSIZE: writes past it fail with EFBIG, as on a
    full disk; Python ignores SIGXFSZ)."""

    def cap() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    env = {**os.environ, "SDL_VIDEODRIVER": "dummy", "CI": "true"}
    return subprocess.run([sys.executable, "-m", "swarm_env.harness.cli", *argv], capture_output=True, text=True,
                          cwd=cwd, env=env, preexec_fn=cap, timeout=300)


@pytest.mark.slow
def test_cli_on_a_full_disk_says_so_in_one_line(tmp_path: Path) -> None:
    out = _limited(200, "run", "--scenario", "paper_vo_0", "--policy", "zero", "--max-cycles", "5",
                   "--json", str(tmp_path / "r.json"), cwd=tmp_path)
    assert out.returncode == 2, out.stderr
    assert "Traceback" not in out.stderr
    assert f"error: {tmp_path / 'r.json'}: cannot write (File too large)" in out.stderr
    assert not (tmp_path / "r.json").exists() and not list(tmp_path.glob(".r.json*"))

    out = _limited(3000, "run", "--scenario", "paper_vo_0", "--policy", "zero", "--max-cycles", "200",
                   "--record", str(tmp_path / "rec"), cwd=tmp_path)
    assert out.returncode == 2, out.stderr
    assert "Traceback" not in out.stderr and "no recording was written there" in out.stderr
    assert list((tmp_path / "rec").iterdir()) == []  # no half-written episode folder

    sweep = tmp_path / "ev"
    out = _limited(3000, "evaluate", "--policies", "zero", "--scenarios", "paper_vo_0", "--seeds", "0-3",
                   "--max-cycles", "5", "--out", str(sweep), cwd=tmp_path)
    assert out.returncode == 2, out.stderr
    assert "Traceback" not in out.stderr and "the line was not added" in out.stderr
    text = (sweep / EPISODES_FILE).read_text()
    lines = text.splitlines()  # two whole lines (1.2 kB each) fit, the third was taken back
    assert text.endswith("\n") and len(lines) == 2 and all(json.loads(line)["status"] == "ok" for line in lines)


def _mp4(path: Path, frames: int = 6) -> None:
    with VideoWriter(path, fps=10) as video:
        for i in range(frames):
            video.append(np.full((32, 48, 3), 20 * i, dtype=np.uint8))


def test_a_truncated_mp4_is_refused_under_its_final_name(tmp_path: Path) -> None:
    good = tmp_path / "good.mp4"
    _mp4(good)
    _check_mp4(good, good)  # whole: its boxes tile the file and it has its index
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    with pytest.raises(OutputError, match="did not finish the file"):
        _check_mp4(cut, cut)


def test_a_video_on_a_full_disk_leaves_no_file(tmp_path: Path) -> None:
    script = (f"import numpy as np, sys\nfrom swarm_env.harness.video import VideoWriter\n"
              f"from swarm_env.outputs import OutputError\n"
              f"try:\n"
              f"    with VideoWriter({str(tmp_path / 'v.mp4')!r}, fps=10) as v:\n"
              f"        for i in range(40):\n"
              f"            v.append(np.random.default_rng(i).integers(0, 255, (240, 320, 3), dtype=np.uint8))\n"
              f"except OutputError as exc:\n"
              f"    print(exc); sys.exit(3)\n")

    def cap() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (20_000, 20_000))

    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, preexec_fn=cap, timeout=300)
    assert out.returncode == 3, out.stderr
    assert "v.mp4" in out.stdout and list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------- one sweep per directory
def test_directory_lock_refuses_a_second_holder_here_and_in_another_process(tmp_path: Path) -> None:
    with directory_lock(tmp_path, "a test"):
        with pytest.raises(OutputError, match="in use by a test"):
            with directory_lock(tmp_path, "a test"):
                pass
        probe = ("import sys\nfrom swarm_env.outputs import directory_lock, OutputError\n"
                 f"try:\n    directory_lock({str(tmp_path)!r}).__enter__()\nexcept OutputError:\n    sys.exit(3)\n")
        assert subprocess.run([sys.executable, "-c", probe], timeout=120).returncode == 3
    with directory_lock(tmp_path):  # released at the end of the block
        pass
    assert list(tmp_path.iterdir()) == []  # no lock file left behind


def test_a_second_resume_of_a_sweep_is_refused_before_it_plays(tmp_path: Path) -> None:
    out = tmp_path / "sweep"
    run_leaderboard(["zero"], ["paper_vo_0"], [0, 1], env_kwargs={"max_cycles": 5}, progress=False, out_dir=out)
    lines = (out / EPISODES_FILE).read_text().splitlines()
    (out / EPISODES_FILE).write_text(lines[0] + "\n")  # one episode left to play
    with directory_lock(out, "the first evaluate --resume"):
        with pytest.raises(OutputError, match="in use by another swarm-env evaluate"):
            run_leaderboard(["zero"], ["paper_vo_0"], [0, 1], env_kwargs={"max_cycles": 5}, progress=False,
                            out_dir=out, resume=True)
    assert (out / EPISODES_FILE).read_text() == lines[0] + "\n"
    board = run_leaderboard(["zero"], ["paper_vo_0"], [0, 1], env_kwargs={"max_cycles": 5}, progress=False,
                            out_dir=out, resume=True)
    assert len((out / EPISODES_FILE).read_text().splitlines()) == 2 and board.rows


# --------------------------------------------------------------------------- reading episodes.jsonl
def _line(**entry: object) -> str:
    return json.dumps({"policy": "zero", "scenario": "paper_vo_0", "status": "ok", "seed": 0, "metrics": {}, **entry})


@pytest.mark.parametrize(("lines", "match"), [
    ([_line(), _line(seed=1), _line()], r"line 3: a second result for zero paper_vo_0 0 \(the first is on line 1\)"),
    ([_line(seed="x"), _line(seed=1)], r"line 1: not a result line \(seed: expected an integer, got 'x'\)"),
    ([_line(seed=True), _line(seed=1)], r"line 1: .*seed: expected an integer, got True"),
    ([_line(metrics=[1]), _line(seed=1)], r"line 1: .*metrics: expected a dict, got \[1\]"),
    ([_line(policy=None), _line(seed=1)], r"line 1: .*policy: expected a str, got None"),
    ([_line(status="n/a", reason=3), _line(seed=1)], r"line 1: .*reason: expected a str, got 3"),
])
def test_resume_names_the_file_and_line_of_a_bad_or_duplicated_result(tmp_path: Path, lines: list[str],
                                                                       match: str) -> None:
    path = tmp_path / EPISODES_FILE
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(ValueError, match=match) as info:
        _Sweep(None, lambda n: None).load(path)
    assert str(info.value).startswith(f"{path}: line ")
