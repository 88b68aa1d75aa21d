"""Ray: ``evaluate --backend ray`` equals the local pool; RLlib PPO trains and its exported actor is a
policy (marker ``ray``: ``pip install -e '.[rl,ray]'`` then ``python -m pytest -m ray``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.ray
ray = pytest.importorskip("ray")
pytest.importorskip("ray.rllib")

from swarm_env.harness.leaderboard import _behaviour, run_leaderboard  # noqa: E402


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
    from swarm_env.harness.evaluation import run_episode
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

        from swarm_env_baselines.rllib_train import ENV_NAME, SHARED, _env_creator

        register_env(ENV_NAME, _env_creator)
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
