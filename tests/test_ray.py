"""Ray: ``evaluate --backend ray`` equals the local pool and keeps its fault contract (a crashed or hung
episode retried once then failed, episodes streamed to DIR/episodes.jsonl as they end, Ctrl-C and --resume);
RLlib PPO trains and its exported actor is a policy (marker ``ray``: ``pip install -e '.[rl,ray]'`` then
``python -m pytest -m ray``)."""

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

import numpy as np
import pytest
from _fault_boards import SEEDS, SHORT, behaviour, pursuit_reference, same_as_pursuit

pytestmark = pytest.mark.ray
ray = pytest.importorskip("ray")
pytest.importorskip("ray.rllib")

from swarm_env.harness.leaderboard import (  # noqa: E402
    EPISODES_FILE,
    Leaderboard,
    _behaviour,
    run_leaderboard,
)


def _episodes(board) -> list[dict]:
    """Every episode's metrics without the timings (wall and policy time differ between runs)."""
    return [{**ep, "metrics": _behaviour(ep["metrics"])} for ep in board.episodes]


def test_ray_backend_gives_the_local_results() -> None:
    args = (["pursuit", "vo"], ["random", "paper_vo_90"], {"random": [1000, 1001, 1002], "paper_vo_90": [0, 1]})
    local = run_leaderboard(*args, workers=1, progress=False)
    remote = run_leaderboard(*args, workers=2, progress=False, backend="ray")
    assert _episodes(remote) == _episodes(local)
    assert [r.summary["collisions"] for r in remote.rows] == [r.summary["collisions"] for r in local.rows]
    assert not ray.is_initialized()  # the local instance it started is shut down


def test_rllib_ppo_trains_and_its_exported_actor_is_the_modules_mean(tmp_path: Path) -> None:
    import torch

    from swarm_env.env import SwarmEnv
    from swarm_env.harness.episode import run_episode
    from swarm_env.harness.policies import load_policy
    from swarm_env_baselines.rllib_train import RLlibConfig, build_config, export_policy, load_rllib_policy, train

    cfg = RLlibConfig("paper_vo_90", {"max_cycles": 50}, total_steps=300, num_env_runners=1,
                      train_batch_size=200, minibatch_size=100, num_epochs=1, num_cpus=2)
    rows = train(cfg, tmp_path / "run", progress=False)
    assert rows and rows[-1]["env_steps"] >= 300
    for name in ("policy.safetensors", "policy.json", "train.csv", "config.json", "versions.json"):
        assert (tmp_path / "run" / name).is_file()
    assert not list((tmp_path / "run").glob("*.pkl"))

    # The exported actor acts exactly like the RLlib module's mean, on real observations.
    env = SwarmEnv("paper_vo_90")
    obs, _ = env.reset(seed=3)
    batch = np.stack([obs[a] for a in env.agents])
    ray.init(num_cpus=1, include_dashboard=False, log_to_driver=False)
    try:
        from ray.tune.registry import register_env

        from swarm_env.wrappers import rllib_env
        from swarm_env_baselines.rllib_train import ENV_NAME, SHARED

        register_env(ENV_NAME, rllib_env)
        algo = build_config(RLlibConfig("paper_vo_90", num_env_runners=0)).build_algo()
        try:
            algo.restore(str((tmp_path / "run" / "rllib_checkpoint").resolve()))
            module = algo.get_module(SHARED)
            with torch.no_grad():
                out = module.forward_inference({"obs": torch.as_tensor(batch)})["action_dist_inputs"].numpy()
            export_policy(module, tmp_path / "again", cfg)
        finally:
            algo.stop()
    finally:
        ray.shutdown()
    policy = load_rllib_policy(tmp_path / "run")
    np.testing.assert_allclose(policy.mean_actions(batch), np.clip(out[:, :2], -1, 1), rtol=0, atol=1e-6)
    assert (tmp_path / "again" / "policy.safetensors").read_bytes() == (tmp_path / "run" / "policy.safetensors").read_bytes()

    # ... and the leaderboard's path scores it like any other policy, bit for bit twice.
    spec = f"rllib:{tmp_path / 'run'}"
    first = run_episode(env, load_policy(spec, env), 5)
    second = run_episode(env, load_policy(spec, env), 5)
    assert first["formation_error"] == second["formation_error"] and first["steps"] == second["steps"]


def test_the_command_line_runs_on_ray(tmp_path: Path, capsys) -> None:
    from swarm_env.harness.cli import main

    out = tmp_path / "lb"
    assert main(["evaluate", "--policies", "pursuit", "--scenarios", "paper_vo_90", "--seeds", "0", "--backend", "ray",
                 "--workers", "2", "--quiet", "--out", str(out)]) == 0
    assert "| `pursuit` |" in (out / "leaderboard.md").read_text()
    with pytest.raises(ValueError, match="ray_address needs backend='ray'"):
        run_leaderboard(["pursuit"], ["paper_vo_90"], [0], progress=False, ray_address="auto")


# --------------------------------------------------------------------------- the local pool's fault contract


@pytest.fixture(scope="module")
def pursuit_board() -> Leaderboard:
    return pursuit_reference()




def test_ray_a_crashed_or_hung_episode_costs_only_itself(faults: Path, tmp_path: Path, pursuit_board: Leaderboard) -> None:
    t0 = time.monotonic()
    board = run_leaderboard(["crash:1", "hang:1", "flaky:0,2", "pursuit"], ["paper_vo_0"], SEEDS, env_kwargs=SHORT,
                            workers=2, progress=False, backend="ray", out_dir=tmp_path / "lb",
                            episode_timeout=15.0)  # generous: a loaded machine must not time out a 20-step episode
    assert time.monotonic() - t0 < 600
    assert not ray.is_initialized()
    # crash: os._exit in the worker, twice -> failed, with the local pool's record shape
    crash, hang = board.row("crash:1", "paper_vo_0"), board.row("hang:1", "paper_vo_0")
    assert (crash.status, crash.failed, crash.summary["episodes"]) == ("ok", 1, 2)
    assert (hang.status, hang.failed, hang.summary["episodes"]) == ("ok", 1, 2)
    lost = {e["policy"]: e for e in board.failed}
    assert sorted(lost) == ["crash:1", "hang:1"]
    assert set(lost["crash:1"]) == {"policy", "scenario", "seed", "status", "error", "attempts"}
    assert (lost["crash:1"]["seed"], lost["crash:1"]["attempts"]) == (1, 2)
    assert "WorkerCrashedError" in lost["crash:1"]["error"]
    assert (lost["hang:1"]["seed"], lost["hang:1"]["attempts"]) == (1, 2)
    assert lost["hang:1"]["error"] == "timed out after 15 s (--episode-timeout)"  # as the pool words it
    # flaky dies once on seeds 0 and 2: retried in a new task, and then it plays them
    assert (faults / "flaky-0").exists() and (faults / "flaky-2").exists()
    assert board.row("flaky:0,2", "paper_vo_0").failed == 0
    # the episodes around the faults are unharmed: the same as pursuit's
    same_as_pursuit(board, "crash:1", pursuit_board, [0, 2])
    same_as_pursuit(board, "hang:1", pursuit_board, [0, 2])
    same_as_pursuit(board, "flaky:0,2", pursuit_board, SEEDS)
    same_as_pursuit(board, "pursuit", pursuit_board, SEEDS)
    # every episode streamed once; within a job in the order its episodes ended (seed order)
    lines = [json.loads(x) for x in (tmp_path / "lb" / EPISODES_FILE).read_text().splitlines()]
    assert sorted((x["policy"], x["seed"], x["status"]) for x in lines) == sorted(
        [(p, s, "failed" if (p, s) in {("crash:1", 1), ("hang:1", 1)} else "ok")
         for p in ("crash:1", "hang:1", "flaky:0,2", "pursuit") for s in SEEDS])
    for p in ("crash:1", "hang:1", "flaky:0,2", "pursuit"):
        assert [x["seed"] for x in lines if x["policy"] == p] == SEEDS


def test_ray_resume_plays_only_the_missing_episodes(tmp_path: Path) -> None:
    full = run_leaderboard(["pursuit", "zero"], ["paper_vo_0"], SEEDS, env_kwargs=SHORT, progress=False,
                           out_dir=tmp_path / "full")
    stream = (tmp_path / "full" / EPISODES_FILE).read_text().splitlines()
    part = tmp_path / "part"  # an interrupted sweep: two lines finished, the third torn mid-write by a kill
    part.mkdir()
    shutil.copy(tmp_path / "full" / "sweep.json", part / "sweep.json")
    (part / EPISODES_FILE).write_text(stream[0] + "\n" + stream[1] + "\n" + stream[2][:40])
    resumed = run_leaderboard(["pursuit", "zero"], ["paper_vo_0"], SEEDS, env_kwargs=SHORT, progress=False,
                              out_dir=part, resume=True, backend="ray", workers=2)
    assert behaviour(resumed) == behaviour(full)
    assert [r.summary["collisions"] for r in resumed.rows] == [r.summary["collisions"] for r in full.rows]
    lines = [json.loads(x) for x in (part / EPISODES_FILE).read_text().splitlines()]
    # the two kept lines, then the four missing episodes, each once: nothing was played twice
    assert [(x["policy"], x["seed"]) for x in lines[:2]] == [("pursuit", 0), ("pursuit", 1)]
    assert sorted((x["policy"], x["seed"]) for x in lines[2:]) == [("pursuit", 2), ("zero", 0), ("zero", 1), ("zero", 2)]
    assert not ray.is_initialized()


def test_ray_streams_episodes_and_ctrl_c_writes_partial_results_then_resume_finishes(
        faults: Path, tmp_path: Path, pursuit_board: Leaderboard) -> None:
    out = tmp_path / "lb"
    cli = [sys.executable, "-m", "swarm_env.harness.cli", "evaluate"]
    cmd = cli + ["--policies", "slow:1,2", "--scenarios", "paper_vo_0", "--seeds", "0-2", "--max-cycles", "20",
                 "--backend", "ray", "--workers", "2", "--quiet", "--out", str(out)]
    env = {**os.environ, "SWARM_ENV_FAULT_SLEEP": "300"}
    # (SIGINT handled by default in the child, as at a terminal: a runner that started this suite in the
    # background would otherwise pass its ignored SIGINT on to it)
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    stream = out / EPISODES_FILE
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and not (stream.is_file() and stream.read_text().count("\n") >= 1):
        time.sleep(0.2)
    # seed 0 is in the stream while seed 1 sleeps in the same job's task: episodes stream as they end, not per job
    assert proc.poll() is None and [json.loads(x)["seed"] for x in stream.read_text().splitlines()] == [0]
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, stderr
    # the last line is ours (Ray may log its start above it)
    assert stderr.strip().splitlines()[-1].startswith("interrupted: 1 of 3 episodes done"), stderr
    partial = json.loads((out / "leaderboard.json").read_text())
    assert [e["seed"] for e in partial["episodes"]] == [0] and partial["rows"][0]["pending"] == 2
    env["SWARM_ENV_FAULT_SLEEP"] = "0"
    done = subprocess.run(cli + ["--resume", str(out), "--backend", "ray", "--workers", "2", "--quiet"],
                          env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    board = Leaderboard.from_json(out / "leaderboard.json")
    assert board.rows[0].pending == 0 and board.failed == []
    same_as_pursuit(board, "slow:1,2", pursuit_board, SEEDS)
    assert [json.loads(x)["seed"] for x in stream.read_text().splitlines()] == SEEDS  # seed 0 was not played again


def test_ray_ctrl_c_cancels_the_tasks_on_an_instance_it_did_not_start(faults: Path,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    import swarm_env.harness.leaderboard as lb

    real = lb._Sweep.episode

    def episode_then_ctrl_c(self: Any, *args: Any) -> None:  # Ctrl-C right after the first episode is recorded
        real(self, *args)
        raise KeyboardInterrupt

    monkeypatch.setattr(lb._Sweep, "episode", episode_then_ctrl_c)
    monkeypatch.setenv("SWARM_ENV_FAULT_SLEEP", "300")  # before ray.init: its workers take this environment
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        # slow:1 plays seed 0 and then sleeps; slow:0 sleeps at once: both tasks hold a CPU when Ctrl-C comes
        with pytest.raises(lb.SweepInterrupted) as info:
            run_leaderboard(["slow:1", "slow:0"], ["paper_vo_0"], SEEDS, env_kwargs=SHORT, progress=False,
                            backend="ray")
        board = info.value.board
        assert [(e["policy"], e["seed"]) for e in board.episodes] == [("slow:1", 0)]
        assert [r.pending for r in board.rows] == [2, 3]
        assert ray.is_initialized()  # not ours to shut down
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and ray.available_resources().get("CPU", 0) < 2:
            time.sleep(0.2)
        assert ray.available_resources().get("CPU", 0) == 2  # both sleeping tasks were cancelled
    finally:
        ray.shutdown()


def test_ray_a_lost_node_costs_only_its_episodes(faults: Path, pursuit_board: Leaderboard,
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    """A local two-node cluster; the worker node is removed (its raylet killed) right after the first episode.
    The sweep ends with every episode played: those lost with the node again on the head, the results path
    (the queue actor, kept on the driver's node) untouched."""
    from ray.cluster_utils import Cluster

    import swarm_env.harness.leaderboard as lb

    monkeypatch.setenv("SWARM_ENV_FAULT_SLEEP", "10")  # before the nodes start: their workers take this environment
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1})
    worker = cluster.add_node(num_cpus=2)
    cluster.wait_for_nodes()
    real = lb._Sweep.episode
    removed: list[bool] = []

    def episode_then_lose_the_node(self: Any, *args: Any) -> None:
        real(self, *args)
        if not removed:
            removed.append(True)
            cluster.remove_node(worker, allow_graceful=False)

    monkeypatch.setattr(lb._Sweep, "episode", episode_then_lose_the_node)
    ray.init(address=cluster.address, log_to_driver=False)
    try:
        board = run_leaderboard(["slow:1", "slow:2", "pursuit"], ["paper_vo_0"], SEEDS, env_kwargs=SHORT,
                                progress=False, backend="ray", episode_timeout=120.0)
    finally:
        ray.shutdown()
        cluster.shutdown()
    assert removed and len(board.rows) == 3  # a sweep that lost its results path raised instead
    assert [r.pending for r in board.rows] == [0, 0, 0]
    for policy in ("slow:1", "slow:2", "pursuit"):  # each episode played (twice at most), as pursuit plays it
        seeds = [s for (p, _, s, _) in behaviour(board) if p == policy]
        failed = [e["seed"] for e in board.failed if e["policy"] == policy]
        assert sorted(seeds + failed) == SEEDS
    same_as_pursuit(board, "pursuit", pursuit_board, [s for (p, _, s, _) in behaviour(board) if p == "pursuit"])


def test_the_rllib_example_runs_on_a_cluster_with_remote_env_runners() -> None:
    """examples/rllib_ppo.py joins a running two-node cluster (``address``), samples with a remote env runner
    that imports the package's env creator (swarm_env.wrappers.rllib_env), and scales the rewards."""
    from ray.cluster_utils import Cluster
    from test_clients import load_example

    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1})
    cluster.add_node(num_cpus=1)
    cluster.wait_for_nodes()
    try:
        (res,) = load_example("rllib_ppo").main(
            "paper_vo_0", iterations=1, address=cluster.address, env_runners=1, train_batch_size=40,
            minibatch_size=20, num_epochs=1, rollout_fragment_length=20, max_cycles=20, reward_scale=0.01)
    finally:
        ray.shutdown()
        cluster.shutdown()
    runners = res["env_runners"]
    assert runners["num_env_steps_sampled"] >= 40
    # the scaled rewards: a 20-step episode of two followers returns tenths, not tens, below zero
    assert -20.0 < runners["episode_return_mean"] < 0.0
