"""Fault-tolerant evaluation: a dead or hung pool worker costs only its episode (retried once, then
counted as failed), finished episodes stream to DIR/episodes.jsonl, --resume finishes a sweep with the
same results, Ctrl-C exits 130 with the partial leaderboard written."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
from _fault_boards import SEEDS, SHORT, behaviour, pursuit_reference, same_as_pursuit

from swarm_env.harness.cli import main
from swarm_env.harness.leaderboard import EPISODES_FILE, TIMING_KEYS, Leaderboard, run_leaderboard
from swarm_env.outputs import OutputError


def summaries(board: Leaderboard) -> list[Any]:
    return [(r.policy, r.scenario, r.status, {k: v for k, v in (r.summary or {}).items() if k != "policy_time"})
            for r in board.rows]


@pytest.fixture(scope="module")
def pursuit_board() -> Leaderboard:
    return pursuit_reference()




# --------------------------------------------------------------------------- dead and hung workers
@pytest.mark.slow
def test_a_dead_worker_costs_only_its_episode(faults: Path, tmp_path: Path, pursuit_board: Leaderboard) -> None:
    board = run_leaderboard(["crash:1", "pursuit"], ["paper_vo_0"], SEEDS, env_kwargs=SHORT, workers=2,
                            progress=False, out_dir=tmp_path / "lb")
    row = board.row("crash:1", "paper_vo_0")
    assert (row.status, row.failed, row.summary["episodes"]) == ("ok", 1, 2)
    [lost] = board.failed
    assert (lost["seed"], lost["attempts"]) == (1, 2) and "exited with code 3" in lost["error"]
    same_as_pursuit(board, "crash:1", pursuit_board, [0, 2])  # the episodes around the crash are unharmed
    same_as_pursuit(board, "pursuit", pursuit_board, SEEDS)
    md = board.to_markdown()
    assert "| failed |" in md
    [crash_line] = [x for x in md.splitlines() if x.startswith("| `crash:1`")]
    assert crash_line.endswith("| 1 |")  # the crash row's failed column
    lines = [json.loads(x) for x in (tmp_path / "lb" / EPISODES_FILE).read_text().splitlines()]
    assert sorted((x["policy"], x.get("seed"), x["status"]) for x in lines) == sorted(
        [("crash:1", 0, "ok"), ("crash:1", 1, "failed"), ("crash:1", 2, "ok")] + [("pursuit", s, "ok") for s in SEEDS])


@pytest.mark.slow
def test_a_worker_that_dies_once_is_retried(faults: Path, pursuit_board: Leaderboard) -> None:
    board = run_leaderboard(["flaky:0,2", "pursuit"], ["paper_vo_0"], SEEDS, env_kwargs=SHORT, workers=2, progress=False)
    assert (faults / "flaky-0").exists() and (faults / "flaky-2").exists()  # both did die once
    assert board.failed == [] and board.row("flaky:0,2", "paper_vo_0").failed == 0
    same_as_pursuit(board, "flaky:0,2", pursuit_board, SEEDS)


@pytest.mark.slow
def test_a_hung_worker_times_out_is_retried_then_failed(faults: Path, pursuit_board: Leaderboard) -> None:
    t0 = time.monotonic()
    board = run_leaderboard(["hang:1", "pursuit"], ["paper_vo_0"], SEEDS, env_kwargs=SHORT, workers=2, progress=False,
                            episode_timeout=15.0)  # generous: a loaded CI machine must not time out a 20-step episode
    assert time.monotonic() - t0 < 600
    assert len(board.failed) == 1, board.failed
    [lost] = board.failed
    assert (lost["seed"], lost["attempts"]) == (1, 2) and "timed out after 15 s" in lost["error"]
    same_as_pursuit(board, "hang:1", pursuit_board, [0, 2])


# --------------------------------------------------------------------------- streaming and --resume
def test_resume_plays_only_the_missing_episodes_and_matches(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import swarm_env.harness.leaderboard as lb

    full = run_leaderboard(["pursuit", "zero"], ["paper_vo_0"], SEEDS, env_kwargs=SHORT, progress=False,
                           out_dir=tmp_path / "full")
    stream = (tmp_path / "full" / EPISODES_FILE).read_text().splitlines()
    assert len(stream) == 6 and all(json.loads(x)["status"] == "ok" for x in stream)
    # an interrupted sweep: two lines finished, the third torn mid-write by a kill
    part = tmp_path / "part"
    part.mkdir()
    shutil.copy(tmp_path / "full" / "sweep.json", part / "sweep.json")
    (part / EPISODES_FILE).write_text(stream[0] + "\n" + stream[1] + "\n" + stream[2][:40])
    played: list[int] = []
    real = lb.record_episode
    monkeypatch.setattr(lb, "record_episode", lambda env, policy, seed, **k: played.append(seed) or real(env, policy, seed, **k))
    resumed = run_leaderboard(["pursuit", "zero"], ["paper_vo_0"], SEEDS, env_kwargs=SHORT, progress=False,
                              out_dir=part, resume=True)
    assert played == [2, 0, 1, 2]  # pursuit seed 2, then zero's three seeds: nothing twice
    assert behaviour(resumed) == behaviour(full) and summaries(resumed) == summaries(full)
    lines = (part / EPISODES_FILE).read_text().splitlines()
    assert len(lines) == 6 and all(json.loads(x) for x in lines)  # the torn line was dropped, not appended to


def test_out_dir_with_results_needs_overwrite_or_resume(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "lb"
    args = ["evaluate", "--policies", "zero", "--scenarios", "paper_vo_0", "--seeds", "0", "--max-cycles", "3",
            "--quiet", "--out", str(out)]
    assert main(args) == 0
    before = (out / "leaderboard.json").read_bytes()
    capsys.readouterr()
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--overwrite" in err and "--resume" in err
    assert (out / "leaderboard.json").read_bytes() == before
    assert main(args + ["--overwrite"]) == 0
    # --resume of a finished sweep plays nothing and writes the same board; another sweep is refused
    assert main(["evaluate", "--resume", str(out), "--quiet"]) == 0

    def episodes(doc: bytes) -> list[Any]:
        return [{k: v for k, v in e["metrics"].items() if k not in TIMING_KEYS} for e in json.loads(doc)["episodes"]]

    assert episodes((out / "leaderboard.json").read_bytes()) == episodes(before)
    capsys.readouterr()
    assert main(["evaluate", "--resume", str(out), "--seeds", "0-1", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "seeds" in err and "differ" in err
    assert main(["evaluate", "--resume", str(tmp_path / "nothing"), "--quiet"]) == 2
    assert "sweep.json: missing" in capsys.readouterr().err


def test_a_symlinked_stream_is_refused(tmp_path: Path) -> None:
    out, elsewhere = tmp_path / "lb", tmp_path / "elsewhere.jsonl"
    out.mkdir()
    elsewhere.write_text("keep\n")
    (out / EPISODES_FILE).symlink_to(elsewhere)
    with pytest.raises(OutputError, match="symbolic link"):
        run_leaderboard(["zero"], ["paper_vo_0"], [0], env_kwargs={"max_cycles": 3}, progress=False, out_dir=out,
                        overwrite=True)
    assert elsewhere.read_text() == "keep\n"


# --------------------------------------------------------------------------- Ctrl-C
@pytest.mark.slow
def test_ctrl_c_exits_130_with_partial_results_and_resume_finishes(faults: Path, tmp_path: Path,
                                                                    pursuit_board: Leaderboard) -> None:
    out = tmp_path / "lb"
    cmd = [sys.executable, "-m", "swarm_env.harness.cli", "evaluate", "--policies", "slow:0,1,2", "--scenarios",
           "paper_vo_0", "--seeds", "0-2", "--max-cycles", "20", "--quiet", "--out", str(out)]
    env = {**os.environ, "SWARM_ENV_FAULT_SLEEP": "30"}
    # (SIGINT handled by default in the child, as at a terminal: a runner that started this suite in the
    # background would otherwise pass its ignored SIGINT on to it)
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    stream = out / EPISODES_FILE
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and not (stream.is_file() and stream.read_text().count("\n") >= 1):
        time.sleep(0.2)  # the first episode is done: the second is sleeping
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, stderr
    assert stderr.strip().count("\n") == 0 and stderr.startswith("interrupted: 1 of 3 episodes done")
    partial = json.loads((out / "leaderboard.json").read_text())
    assert [e["seed"] for e in partial["episodes"]] == [0] and partial["rows"][0]["pending"] == 2
    env["SWARM_ENV_FAULT_SLEEP"] = "0"
    done = subprocess.run([sys.executable, "-m", "swarm_env.harness.cli", "evaluate", "--resume", str(out), "--quiet"],
                          env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    board = Leaderboard.from_json(out / "leaderboard.json")
    assert board.rows[0].pending == 0 and board.failed == []
    same_as_pursuit(board, "slow:0,1,2", pursuit_board, SEEDS)
