"""Record and replay (swarm_env.harness.recording): the files, a replay in a fresh process, divergences named at
their step, videos of replays, and the run/replay command line."""

from __future__ import annotations

import dataclasses
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import imageio.v2 as imageio
import numpy as np
import pytest

from swarm_env.env import SwarmEnv
from swarm_env.harness.cli import main
from swarm_env.harness.episode import run_episode
from swarm_env.harness.leaderboard import _behaviour
from swarm_env.harness.policies import load_policy
from swarm_env.harness.recording import (
    FORMAT_VERSION,
    RecordError,
    ReplayDivergence,
    check,
    load_episode,
    load_recording,
    record_episode,
    replay,
    save_episode,
    state_digest,
)

# A random world with reactive humans (they read the robots, so any difference feeds back) and a random policy.
REACTIVE = ["--scenario", "random", "--env", "n_humans=2", "--env", "human_behavior=social_force", "--policy", "random"]
STEPS = 25


def _record(tmp_path: Path, *extra: str, episodes: int = 2) -> Path:
    out = tmp_path / "rec"
    argv = ["run", *REACTIVE, "--episodes", str(episodes), "--seed", "3", "--max-cycles", str(STEPS), "--record", str(out)]
    assert main([*argv, *extra]) == 0
    return out


def _tamper(folder: Path, **arrays: np.ndarray) -> None:
    """Rewrite arrays of an episode's actions.npz (what an edited or corrupted file would hold)."""
    with np.load(folder / "actions.npz") as npz:
        data = {k: npz[k] for k in npz.files}
    data.update(arrays)
    np.savez(folder / "actions.npz", **data)


def _edit_meta(folder: Path, **changes: object) -> None:
    meta = json.loads((folder / "meta.json").read_text())
    for key, value in changes.items():
        target, _, sub = key.partition("__")
        if sub:
            meta[target][sub] = value
        else:
            meta[target] = value
    (folder / "meta.json").write_text(json.dumps(meta))


def test_record_files_and_metrics(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = _record(tmp_path)
    assert "wrote" in capsys.readouterr().out
    assert sorted(p.name for p in out.iterdir()) == ["episode_0", "episode_1"]  # no temporary folders left
    meta = json.loads((out / "episode_1" / "meta.json").read_text())
    assert (meta["format"], meta["version"], meta["episode"], meta["seed"]) == ("swarm_env.harness.recording", FORMAT_VERSION, 1, 4)
    assert (meta["policy"], meta["scenario"], meta["steps"], meta["digest_every"]) == ("random", "random", STEPS, 1)
    rec = load_episode(out / "episode_1")
    # the resolved world: what the generator made for seed 4, read back from scenario.yaml
    env = SwarmEnv("random", n_humans=2, human_behavior="social_force", max_cycles=STEPS)
    env.reset(seed=4)
    assert rec.scenario == dataclasses.replace(env.scenario, source=rec.scenario.source)
    assert len(rec.scenario.humans) == 2 and {h.behavior for h in rec.scenario.humans} == {"social_force"}
    assert rec.actions.shape == (STEPS, rec.scenario.robots.count, 2) and rec.actions.dtype == np.float64
    assert rec.digest_steps.tolist() == list(range(STEPS + 1)) and rec.digests.shape == (STEPS + 1, 32)
    # replaying gives the recorded episode's metrics (timings aside)
    result = replay(rec)
    assert result.ok and result.steps == STEPS and result.digests_checked == STEPS + 1
    assert _behaviour(result.metrics) == _behaviour(rec.metrics)


def test_replay_checks_in_a_fresh_process(tmp_path: Path) -> None:
    out = _record(tmp_path)
    env = {**os.environ, "SDL_VIDEODRIVER": "dummy"}
    proc = subprocess.run([sys.executable, "-m", "swarm_env.harness.cli", "replay", str(out), "--check"],
                          capture_output=True, text=True, env=env, timeout=300)
    assert proc.returncode == 0, proc.stderr
    for k in (0, 1):
        assert f"episode {k}: random on random, {STEPS} of {STEPS} steps replayed, {STEPS + 1} digests checked" in proc.stdout
    assert "diverges" not in proc.stderr


def test_a_tampered_action_is_named_at_its_step(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = _record(tmp_path)
    capsys.readouterr()
    rec = load_episode(out / "episode_1")
    actions = rec.actions.copy()
    actions[7, 0] = [1.0, -1.0] if actions[7, 0, 0] < 0.5 else [-1.0, 1.0]  # the 8th action: it makes step 8
    _tamper(out / "episode_1", actions=actions)
    assert main(["replay", str(out), "--check"]) == 1
    captured = capsys.readouterr()
    (line,) = captured.err.splitlines()
    assert line.startswith("replay: step 8 of episode 1 (seed 4) diverges from the record (digest ")
    assert f"{rec.digests[8].tobytes().hex()[:16]} recorded" in line
    assert "episode 0: random on random" in captured.out  # episode 0 was checked first and matched

    # without --check the replay goes on to the end (for a video) and only warns
    assert main(["replay", str(out / "episode_1")]) == 0
    captured = capsys.readouterr()
    assert captured.err.startswith("warning: replay: step 8 of episode 1") and f"{STEPS} of {STEPS} steps" in captured.out


def test_a_tampered_digest_is_named_at_its_step(tmp_path: Path) -> None:
    out = _record(tmp_path, episodes=1)
    rec = load_episode(out / "episode_0")
    digests = rec.digests.copy()
    digests[12, 0] ^= 0xFF
    _tamper(out / "episode_0", digests=digests)
    with pytest.raises(ReplayDivergence, match=r"^replay: step 12 of episode 0 \(seed 3\) diverges") as info:
        check(load_episode(out / "episode_0"))
    d = info.value.divergence
    assert (d.step, d.recorded, d.replayed, d.last_match) == (12, digests[12].tobytes().hex(), rec.digests[12].tobytes().hex(), 11)
    # a record made on another platform says what changed
    _edit_meta(out / "episode_0", platform__numpy="0.0")
    with pytest.raises(ReplayDivergence, match=rf"; changed since recording: numpy 0.0 -> {re.escape(np.__version__)}$"):
        check(load_episode(out / "episode_0"))


def test_digests_every_k_steps_name_the_first_checked_step(tmp_path: Path) -> None:
    env = SwarmEnv("paper_vo_0", max_cycles=23)
    policy = load_policy("random", env)
    metrics, rec = record_episode(env, policy, 5, policy_spec="random", digest_every=5)
    assert rec.digest_steps.tolist() == [0, 5, 10, 15, 20, 23]  # every 5th step and the last
    assert _behaviour(metrics) == _behaviour(run_episode(env, load_policy("random", env), 5))  # recording changes nothing
    assert check(rec).digests_checked == 6
    actions = rec.actions.copy()
    actions[7] = -actions[7]  # makes step 8, first checked at step 10
    tampered = dataclasses.replace(rec, actions=actions)
    with pytest.raises(ReplayDivergence, match=r"replay: step 10 of episode 0 \(seed 5\) diverges .*; step 5 matched\)$"):
        check(tampered)


def test_episode_length_divergences(tmp_path: Path) -> None:
    out = _record(tmp_path, episodes=1)
    folder = out / "episode_0"
    rec = load_episode(folder)
    _edit_meta(folder, env__max_steps=20)  # the replay env now truncates earlier than the record did
    with pytest.raises(ReplayDivergence, match=r"step 21 of episode 0 .*the replayed episode ended at step 20, the recorded one at step 25"):
        check(load_episode(folder))
    _edit_meta(folder, env__max_steps=STEPS, steps=STEPS - 5)
    _tamper(folder, actions=rec.actions[: STEPS - 5], digest_steps=rec.digest_steps[: STEPS - 4], digests=rec.digests[: STEPS - 4])
    with pytest.raises(ReplayDivergence, match=r"step 21 of episode 0 .*the record ends at step 20 but the replayed episode goes on"):
        check(load_episode(folder))


def test_discrete_actions_round_trip(tmp_path: Path) -> None:
    env = SwarmEnv("paper_vo_0", action_type="discrete", max_cycles=15)
    metrics, rec = record_episode(env, load_policy("random", env), 2, policy_spec="random", episode=3)
    folder = save_episode(rec, tmp_path / "rec")
    assert folder == tmp_path / "rec" / "episode_3"
    (back,) = load_recording(tmp_path / "rec")
    assert back.actions.dtype == np.int64 and back.actions.shape == (15, 2) and back.action_type == "discrete"
    assert np.array_equal(back.actions, rec.actions) and np.array_equal(back.digests, rec.digests)
    assert _behaviour(check(back).metrics) == _behaviour(metrics)


def test_replay_renders_a_video(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = _record(tmp_path)
    video = tmp_path / "replay.mp4"
    assert main(["replay", str(out), "--video", str(video), "--fps", "10", "--check"]) == 0
    assert f"wrote {video}" in capsys.readouterr().out
    with imageio.get_reader(str(video)) as reader:
        assert sum(1 for _ in reader) == 2 * (STEPS + 1)  # per episode: the initial frame and one per step


def test_bad_recordings_and_directories(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["replay", str(tmp_path / "nothing")]) == 2
    assert "no such recording directory" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    assert main(["replay", str(tmp_path / "empty")]) == 2
    assert "episode_<k>/meta.json" in capsys.readouterr().err

    out = _record(tmp_path, episodes=1)
    capsys.readouterr()
    assert main(["replay", str(out), "--video", str(tmp_path / "x.avi")]) == 2
    assert "unsupported video format '.avi'" in capsys.readouterr().err
    # recording into a directory that already holds episodes is refused before any episode runs
    assert main(["run", *REACTIVE, "--max-cycles", "5", "--record", str(out)]) == 2
    captured = capsys.readouterr()
    assert "already holds recorded episodes" in captured.err and captured.out == ""

    _edit_meta(out / "episode_0", version=FORMAT_VERSION + 1)
    with pytest.raises(RecordError, match=r"episode_0/meta.json: version: expected 1"):
        load_episode(out / "episode_0")
    _edit_meta(out / "episode_0", version=FORMAT_VERSION, steps=STEPS + 1)
    with pytest.raises(RecordError, match=r"actions.npz: actions: expected shape \(26, "):
        load_episode(out / "episode_0")


def test_digest_covers_the_physics() -> None:
    env = SwarmEnv("crowd_reactive", max_cycles=3)
    env.reset(seed=0)
    first = env.world_state()
    assert state_digest(first) == state_digest(first) and len(state_digest(first)) == 32
    env.step({a: np.array([0.5, 0.1]) for a in env.agents})
    assert state_digest(env.world_state()) != state_digest(first)
