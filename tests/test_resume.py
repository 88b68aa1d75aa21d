"""Interrupting and resuming training (swarm_env_baselines.checkpointing, swarm-env train mappo --resume, swarm-env train sb3
--resume): a stopped and resumed MAPPO run ends bit for bit where an uninterrupted one does; SIGINT saves
a loadable policy and exits 130 with the resume command; checkpoints hold no pickle."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from swarm_env.harness.policies import ModelFileError

pytest.importorskip("torch")
pytest.importorskip("safetensors")

from swarm_env.env import SwarmEnv  # noqa: E402
from swarm_env.harness.episode import run_episode  # noqa: E402
from swarm_env.harness.policies import load_policy  # noqa: E402
from swarm_env_baselines import mappo  # noqa: E402
from swarm_env_baselines.checkpointing import StopRequest, TrainingInterrupted  # noqa: E402
from swarm_env_baselines.mappo_learner import ProcessLearner  # noqa: E402

TINY_ENV = {"n_followers": 2, "n_obstacles": 1, "n_humans": 1, "max_cycles": 30}
ROOT = Path(__file__).resolve().parent.parent
#: train.csv columns that are clocks (everything else must match exactly).
CLOCKS = ("wall_s", "rollout_s", "update_s", "agent_steps_per_s")


def _cfg(tmp_path, **overrides) -> mappo.MAPPOConfig:
    base = dict(env_kwargs=dict(TINY_ENV), total_steps=640, n_copies=2, n_steps=32, n_epochs=2, hidden=(16, 16),
                eval_every=256, eval_seeds="500-501", runs_dir=str(tmp_path), progress=False, pretrain_rounds=2,
                pretrain_episodes=2, pretrain_epochs=1, checkpoint_every=2, prefetch_worlds=False,
                learner_process=False)
    return mappo.MAPPOConfig(**{**base, **overrides})


def _tensors(path: Path) -> dict[str, np.ndarray]:
    from safetensors.numpy import load_file

    return load_file(str(path))


def _assert_same_tensors(a: Path, b: Path) -> None:
    ta, tb = _tensors(a), _tensors(b)
    assert ta.keys() == tb.keys()
    different = [k for k in ta if not np.array_equal(ta[k], tb[k])]
    assert not different, f"{a} and {b} differ in {different}"


def _rows(path: Path) -> list[dict[str, str]]:
    return [{k: v for k, v in r.items() if k not in CLOCKS} for r in csv.DictReader(open(path))]


def _stop_at(monkeypatch, update_index: int, how: str) -> None:
    """Make update ``update_index`` end the run: ``sigint`` sends the process SIGINT during it (the trainer
    finishes the update and saves), ``crash`` raises after it (nothing saved since the last checkpoint)."""
    original = mappo.Trainer.update
    original_submit = ProcessLearner.submit

    def update(self, batch, optim, u, n_updates):
        if u == update_index and how == "sigint":
            signal.raise_signal(signal.SIGINT)
        stats = original(self, batch, optim, u, n_updates)
        if u == update_index and how == "crash":
            raise RuntimeError("simulated crash")
        return stats

    def submit(self, batch, last, u, n_updates):  # with a learner process: while it updates
        assert how == "sigint"
        original_submit(self, batch, last, u, n_updates)
        if u == update_index:
            signal.raise_signal(signal.SIGINT)

    monkeypatch.setattr(mappo.Trainer, "update", update)
    monkeypatch.setattr(ProcessLearner, "submit", submit)


@pytest.mark.filterwarnings("error:.*rebuilt env copies differ")
@pytest.mark.parametrize("overrides, how", [
    # DAgger warm start, teaching shield with an annealed imitation term, validation and best/ selection.
    ({"shield": "teach", "intervention_coef": 1.0, "imitation_coef": 1.0, "imitation_anneal": 0.5}, "sigint"),
    # A residual of vo (its expert replayed with the worlds), executed through the shield; a hard stop.
    ({"residual": "vo", "pretrain": "none", "shield": "execute", "critic": "local", "eval_every": 0}, "crash"),
    # The update in a learner process: the checkpoint keeps the rollout collected while it updated.
    ({"learner_process": True}, "sigint"),
])
@pytest.mark.slow
def test_a_stopped_and_resumed_run_ends_bit_for_bit_like_an_uninterrupted_one(tmp_path, monkeypatch, overrides,
                                                                               how) -> None:
    whole = mappo.train(_cfg(tmp_path, run_name="whole", **overrides))
    with monkeypatch.context() as m:
        # SIGINT in update 3 of 5 (32 steps each; a clean stop after it), or a crash after update 4 (back to the
        # checkpoint after update 2): mid-episode (30-step episodes) in every copy either way.
        _stop_at(m, 2 if how == "sigint" else 3, how)
        if how == "sigint":
            with pytest.raises(TrainingInterrupted, match="--resume") as stopped:
                mappo.train(_cfg(tmp_path, run_name="parts", **overrides))
            assert stopped.value.exit_code == 130
        else:
            with pytest.raises(RuntimeError, match="simulated crash"):
                mappo.train(_cfg(tmp_path, run_name="parts", **overrides))
    parts = tmp_path / "parts"
    state = json.loads((parts / "checkpoint" / "state.json").read_text())
    assert state["updates"] == (3 if how == "sigint" else 2)  # a crash goes back to the last periodic checkpoint
    assert sorted(p.name for p in (parts / "checkpoint").iterdir()) == ["state.json", "state.safetensors"]
    if how == "crash":
        assert len(_rows(parts / "train.csv")) == 3 and state["csv_rows"]["train.csv"] == 2  # one to drop
    assert mappo.resume(parts) == parts
    _assert_same_tensors(whole / "policy.safetensors", parts / "policy.safetensors")
    _assert_same_tensors(whole / "checkpoint" / "state.safetensors", parts / "checkpoint" / "state.safetensors")
    assert _rows(whole / "train.csv") == _rows(parts / "train.csv")
    assert _rows(whole / "eval.csv") == _rows(parts / "eval.csv")
    if (whole / "best").exists():
        _assert_same_tensors(whole / "best" / "policy.safetensors", parts / "best" / "policy.safetensors")
    summary = json.loads((parts / "summary.json").read_text())
    whole_summary = json.loads((whole / "summary.json").read_text())
    assert summary["agent_steps"] == 640 and summary["best_score"] == whole_summary["best_score"]


def test_resume_refuses_other_settings_and_a_finished_run_trains_further(tmp_path) -> None:
    run = mappo.train(_cfg(tmp_path, run_name="r", total_steps=256, eval_every=0, pretrain="none"))
    with pytest.raises(FileExistsError, match=f"--resume {run}"):
        mappo.train(_cfg(tmp_path, run_name="r", total_steps=256, eval_every=0, pretrain="none"))
    with pytest.raises(ValueError, match="--seed cannot change"):
        mappo.resume(run, seed=3)
    with pytest.raises(ValueError, match="the run is complete"):
        mappo.resume(run)
    with pytest.raises(FileNotFoundError, match="no run there"):
        mappo.resume(tmp_path / "nowhere")
    mappo.resume(run, total_steps=512)
    assert json.loads((run / "summary.json").read_text())["agent_steps"] == 512
    assert json.loads((run / "config.json").read_text())["total_steps"] == 512
    assert len(list(csv.DictReader(open(run / "train.csv")))) == 4


def test_stop_request_turns_signals_into_a_clean_stop_then_an_immediate_one() -> None:
    with StopRequest() as stop:
        signal.raise_signal(signal.SIGTERM)
        assert stop.requested and stop.signum == signal.SIGTERM
        with pytest.raises(KeyboardInterrupt):
            signal.raise_signal(signal.SIGINT)  # a second signal: stop at once
    fresh = StopRequest()
    with fresh, pytest.raises(TrainingInterrupted, match="warm start") as exc:
        with fresh.immediate("interrupted during the warm start"):
            signal.raise_signal(signal.SIGTERM)
    assert exc.value.exit_code == 143
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # the handlers are put back


@pytest.mark.slow
def test_ctrl_c_saves_a_loadable_policy_and_exits_130_with_the_resume_command(tmp_path) -> None:
    """The command line under a real SIGINT, sent once the first periodic checkpoint exists."""
    args = [sys.executable, "-m", "baselines.mappo", "--env", "n_followers=2", "--env", "n_obstacles=1", "--env",
            "n_humans=0", "--env", "max_cycles=30", "--pretrain", "none", "--total-steps", "10000000", "--n-copies",
            "2", "--n-steps", "32", "--hidden", "16", "16", "--eval-every", "0", "--eval-seeds", "500-501",
            "--checkpoint-every", "1", "--no-progress", "--runs-dir", str(tmp_path), "--run-name", "x"]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen(args, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    state = tmp_path / "x" / "checkpoint" / "state.json"
    deadline = time.monotonic() + 180
    try:
        while not (state.is_file() and json.loads(state.read_text())["updates"] >= 1):
            assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
            time.sleep(0.2)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == 130, err
    last = err.strip().splitlines()[-1]
    assert f"swarm-env train mappo --resume {tmp_path / 'x'}" in last
    steps = json.loads(state.read_text())["agent_steps"]
    world = SwarmEnv("random", **{**TINY_ENV, "n_humans": 0})
    assert run_episode(world, load_policy(f"mappo:{tmp_path / 'x'}", world), seed=1000)["steps"] == 30
    again = subprocess.run(args, cwd=ROOT, env=env, capture_output=True, text=True, timeout=120)
    assert again.returncode == 2 and "--resume" in again.stderr
    assert mappo.main(["--resume", str(tmp_path / "x"), "--total-steps", str(steps + 128), "--no-progress"]) == 0
    assert json.loads((tmp_path / "x" / "summary.json").read_text())["agent_steps"] == steps + 128


def test_sb3_ctrl_c_saves_the_model_and_resume_goes_on_to_the_budget(tmp_path, monkeypatch) -> None:
    pytest.importorskip("stable_baselines3")
    from swarm_env_baselines import callbacks
    from swarm_env_baselines import train as train_mod
    from swarm_env_baselines.config import TrainConfig

    cfg = TrainConfig(env_kwargs={"n_followers": 2, "n_obstacles": 1, "n_humans": 0, "world_size": [10.0, 10.0],
                                  "max_cycles": 30}, total_steps=1024, n_copies=2, n_steps=32, batch_size=64,
                      n_epochs=1, net_arch=(16, 16), eval_every=256, eval_seeds="500-501", checkpoint_every=256,
                      runs_dir=str(tmp_path), run_name="sb3", progress=False)
    original = callbacks.StopCallback._on_step

    def on_step(self) -> bool:
        if self.num_timesteps == 260:  # 4 sub-envs, rollouts of 128 steps: inside the third rollout
            signal.raise_signal(signal.SIGINT)
        return original(self)

    with monkeypatch.context() as m:
        m.setattr(callbacks.StopCallback, "_on_step", on_step)
        with pytest.raises(TrainingInterrupted, match="swarm-env train sb3 --resume") as stopped:
            train_mod.train(cfg)
    assert stopped.value.exit_code == 130
    run = tmp_path / "sb3"
    # The rollout under way and its update were completed; the next rollout stopped at its first step.
    assert train_mod.latest_model(run) == run
    saved = (run / "model.zip").read_bytes()
    (run / "model.zip").write_bytes(saved[: len(saved) // 2])  # cut short by a hard stop: the checkpoint is next
    assert train_mod.latest_model(run) == run / "checkpoints" / "step_256"
    (run / "model.zip").write_bytes(saved)
    world = SwarmEnv("random", **cfg.env_kwargs)
    assert run_episode(world, load_policy(f"ppo:{run}", world), seed=1000)["steps"] == 30
    with pytest.raises(FileExistsError, match=f"--resume {run}"):
        train_mod.train(cfg)
    assert train_mod.main(["--resume", str(run), "--seed", "1"]) == 2
    with pytest.raises(ModelFileError, match="--trust-pickle"):  # SB3's model.zip is a pickle: opt in
        train_mod.resume(run)
    assert train_mod.resume(run, trust_pickle=True) == run
    summary = json.loads((run / "summary.json").read_text())
    assert summary["agent_steps"] >= 1024
    steps = [int(r["agent_steps"]) for r in csv.DictReader(open(run / "eval.csv"))]
    # One row per evaluation (the interrupted model's included), none repeated by the resumed run.
    assert steps == sorted(set(steps)) and 388 in steps and steps[-1] == summary["agent_steps"]
    assert summary["best_score"] == min(float(r["score"]) for r in csv.DictReader(open(run / "eval.csv")))


@pytest.mark.slow
def test_validation_in_a_worker_survives_a_crash_and_resume(tmp_path, monkeypatch) -> None:
    """With eval_workers=1 a checkpoint can fall while a validation is still with the worker: it lists it
    and keeps its snapshot, and the resumed run scores it again; eval.csv and best/ come out as unbroken."""
    import concurrent.futures

    overrides = dict(pretrain="none", eval_every=256, eval_workers=1, checkpoint_every=1)
    whole = mappo.train(_cfg(tmp_path, run_name="whole", **overrides))
    with monkeypatch.context() as m:
        # Results are collected only when the trainer waits for them: every checkpoint finds evaluations pending.
        m.setattr(concurrent.futures.Future, "done", lambda self: False)
        _stop_at(m, 3, "crash")
        with pytest.raises(RuntimeError, match="simulated crash"):
            mappo.train(_cfg(tmp_path, run_name="parts", **overrides))
    parts = tmp_path / "parts"
    state = json.loads((parts / "checkpoint" / "state.json").read_text())
    assert [p[0] for p in state["pending_evals"]] == [0, 256] and state["history"] == []
    for steps, _ in state["pending_evals"]:
        assert (parts / "evals" / str(steps) / "policy.json").is_file()
    mappo.resume(parts)
    assert _rows(whole / "eval.csv") == _rows(parts / "eval.csv") and len(_rows(whole / "eval.csv")) == 4
    _assert_same_tensors(whole / "best" / "policy.safetensors", parts / "best" / "policy.safetensors")
    _assert_same_tensors(whole / "policy.safetensors", parts / "policy.safetensors")
    assert not (parts / "evals").exists()
