"""swarm_env_baselines.train / config / model_io: a tiny run end to end, the CLI, warm starts, loading as a policy."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

from swarm_env.env import SwarmEnv  # noqa: E402
from swarm_env.harness.episode import run_episode  # noqa: E402
from swarm_env.harness.policies import PolicyError, load_policy  # noqa: E402
from swarm_env_baselines import train as train_mod  # noqa: E402
from swarm_env_baselines.config import TrainConfig, field_help, parse_seeds  # noqa: E402
from swarm_env_baselines.model_io import SB3Policy, load_model, load_warm_start  # noqa: E402

TINY_ENV = {"n_followers": 2, "n_obstacles": 1, "n_humans": 0, "world_size": [10.0, 10.0], "max_cycles": 30}


def _tiny(tmp_path, **overrides) -> TrainConfig:
    base = dict(
        env_kwargs=dict(TINY_ENV), total_steps=512, n_copies=2, n_steps=32, batch_size=64, n_epochs=1,
        net_arch=(16, 16), eval_every=256, eval_seeds="500-501", checkpoint_every=256, runs_dir=str(tmp_path),
        run_name="tiny", progress=False,
    )
    return TrainConfig(**{**base, **overrides})


def test_tiny_ppo_run_writes_a_complete_run_directory(tmp_path):
    run = train_mod.train(_tiny(tmp_path))
    for name in ("config.json", "versions.json", "model.zip", "vecnormalize.pkl", "eval.csv", "learning_curve.png",
                 "summary.json", "best/model.zip", "logs/progress.csv"):
        assert (run / name).is_file(), name
    assert any((run / "checkpoints").iterdir())
    assert TrainConfig.from_json(run / "config.json") == _tiny(tmp_path)
    versions = json.loads((run / "versions.json").read_text())
    assert versions["stable-baselines3"] and versions["torch"]
    summary = json.loads((run / "summary.json").read_text())
    assert summary["agent_steps"] >= 512
    rows = (run / "eval.csv").read_text().strip().splitlines()
    assert len(rows) >= 3  # header + the starting point + at least one later evaluation

    # The run loads back as a registered policy and plays an episode through the one evaluation path.
    env = SwarmEnv("random", **TINY_ENV)
    policy = load_policy(f"ppo:{run}", env)
    assert isinstance(policy, SB3Policy) and policy.vecnorm is not None
    result = run_episode(env, policy, seed=1000)
    assert result["steps"] == 30
    with pytest.raises(FileExistsError):
        train_mod.train(_tiny(tmp_path))  # never overwrite a run


def test_warm_start_copies_weights_and_normalisation(tmp_path):
    source = train_mod.train(_tiny(tmp_path, eval_every=0, checkpoint_every=0))
    src_model, src_norm = load_model(source, trust_pickle=True)
    cfg = _tiny(tmp_path, run_name="warm", init_from=str(source), total_steps=64, eval_every=0, checkpoint_every=0)
    venv = None
    model = None
    from stable_baselines3.common.vec_env import VecNormalize

    from swarm_env_baselines.vec_env import make_vec_env

    venv = VecNormalize(make_vec_env("random", 2, **TINY_ENV))
    model = train_mod._make_model(cfg, venv, tmp_path / "logs")
    train_mod._warm_start(model, venv, cfg)
    for k, v in src_model.policy.state_dict().items():
        np.testing.assert_array_equal(model.policy.state_dict()[k].numpy(), v.numpy())
    np.testing.assert_array_equal(venv.obs_rms.mean, src_norm.obs_rms.mean)
    assert venv.ret_rms.var == pytest.approx(src_norm.ret_rms.var)
    bad = _tiny(tmp_path, run_name="bad", init_from=str(source), net_arch=(8,))
    with pytest.raises(ValueError, match="does not match"):
        train_mod._warm_start(train_mod._make_model(bad, venv, tmp_path / "logs2"), venv, bad)
    venv.close()


def test_cli_parses_every_field_and_rejects_bad_input(tmp_path, capsys):
    cfg = train_mod.config_from_args(
        ["--total-steps", "2e6", "--env", "n_followers=[2,8]", "--env", "n_humans=1", "--net-arch", "64", "64",
         "--no-norm-reward", "--algo", "sac"]
    )
    assert cfg.total_steps == 2_000_000 and cfg.algo == "sac" and cfg.net_arch == (64, 64)
    assert cfg.env_kwargs == {"n_followers": [2, 8], "n_humans": 1} and cfg.norm_reward is False
    assert train_mod.main(["--algo", "dqnx"]) == 2
    assert "unknown algorithm" in capsys.readouterr().err
    assert train_mod.main(["--algo", "sac", "--action-type", "discrete"]) == 2
    with pytest.raises(SystemExit):
        train_mod.config_from_args(["--total-steps", "1.5"])
    helps = field_help(TrainConfig)
    assert set(helps) == {f for f in TrainConfig.__dataclass_fields__}  # every option documented
    help_text = train_mod.build_parser().format_help()
    assert "--eval-seeds" in help_text and "Validation seeds" in help_text


def test_config_from_json_repeats_a_run_and_names_unknown_keys(tmp_path):
    path = tmp_path / "config.json"
    path.write_text(_tiny(tmp_path).to_json())
    cfg = train_mod.config_from_args(["--config", str(path), "--seed", "3"])
    assert cfg.seed == 3 and cfg.net_arch == (16, 16) and cfg.run_name is None
    path.write_text(json.dumps({"algo": "ppo", "totl_steps": 5}))
    with pytest.raises(ValueError, match="totl_steps"):
        TrainConfig.from_json(path)


def test_parse_seeds_forms():
    assert parse_seeds("0-3") == [0, 1, 2, 3]
    assert parse_seeds("5") == [5]
    assert parse_seeds("0,5,7-8") == [0, 5, 7, 8]
    for bad in ("3-1", "a", "1-"):
        with pytest.raises(ValueError, match="seed"):
            parse_seeds(bad)


def test_model_policy_rejects_a_mismatched_env(tmp_path):
    run = train_mod.train(_tiny(tmp_path, eval_every=0, checkpoint_every=0))
    with pytest.raises(PolicyError, match="acts in"):
        load_policy(f"ppo:{run}", SwarmEnv("random", action_type="discrete", **TINY_ENV))
    with pytest.raises(PolicyError, match="no saved model"):
        load_policy(f"ppo:{tmp_path}/nowhere", SwarmEnv("random", **TINY_ENV))
    with pytest.raises(PolicyError, match="needs a model path"):
        load_policy("sac", SwarmEnv("random", **TINY_ENV))


def test_tiny_sac_run_trains_and_loads_as_a_policy(tmp_path):
    cfg = _tiny(tmp_path, algo="sac", run_name="sac", total_steps=256, batch_size=32, buffer_size=2000,
                eval_every=0, checkpoint_every=0)
    run = train_mod.train(cfg)
    env = SwarmEnv("random", **TINY_ENV)
    result = run_episode(env, load_policy(f"sac:{run}", env), seed=1000)
    assert result["steps"] == 30


def test_frozen_observation_statistics_stay_at_the_warm_start(tmp_path):
    source = train_mod.train(_tiny(tmp_path, eval_every=0, checkpoint_every=0))
    _, src_norm = load_model(source, trust_pickle=True)
    cfg = _tiny(tmp_path, run_name="frozen", init_from=str(source), freeze_obs_stats=True, eval_every=0, checkpoint_every=0)
    _, norm = load_model(train_mod.train(cfg), trust_pickle=True)
    np.testing.assert_array_equal(norm.obs_rms.mean, src_norm.obs_rms.mean)
    np.testing.assert_array_equal(norm.obs_rms.var, src_norm.obs_rms.var)
    moving = _tiny(tmp_path, run_name="moving", init_from=str(source), eval_every=0, checkpoint_every=0)
    _, moved = load_model(train_mod.train(moving), trust_pickle=True)
    assert not np.array_equal(moved.obs_rms.mean, src_norm.obs_rms.mean)


@pytest.mark.slow
def test_a_command_line_run_with_frozen_statistics_loads_elsewhere(tmp_path):
    # python -m runs train.py as __main__; the saved statistics must not refer to classes defined there.
    import subprocess
    import sys

    args = ["--total-steps", "256", "--n-copies", "2", "--n-steps", "32", "--batch-size", "64", "--n-epochs", "1",
            "--net-arch", "16", "16", "--eval-every", "0", "--checkpoint-every", "0", "--runs-dir", str(tmp_path),
            "--run-name", "cli", "--no-progress", "--freeze-obs-stats"]
    for key, value in TINY_ENV.items():
        args += ["--env", f"{key}={json.dumps(value)}"]
    subprocess.run([sys.executable, "-m", "swarm_env_baselines.train", *args], check=True, capture_output=True)
    env = SwarmEnv("random", **TINY_ENV)
    assert run_episode(env, load_policy(f"ppo:{tmp_path / 'cli'}", env), seed=1000)["steps"] == 30


def test_loading_for_training_keeps_the_thread_count_but_scoring_uses_one(tmp_path):
    import torch

    run = train_mod.train(_tiny(tmp_path, eval_every=0, checkpoint_every=0))
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        load_warm_start(run, "ppo")  # what --init-from uses: must not override --torch-threads
        load_model(run, trust_pickle=True)
        assert torch.get_num_threads() == 2
        load_policy(f"ppo:{run}", SwarmEnv("random", **TINY_ENV))  # scoring: one thread
        assert torch.get_num_threads() == 1
    finally:
        torch.set_num_threads(before)


def test_a_shielded_run_trains_and_evaluates_through_the_safety_layer(tmp_path):
    import csv

    from swarm_env.harness.policies import ShieldedPolicy

    run = train_mod.train(_tiny(tmp_path, shield=True, checkpoint_every=0))
    assert json.loads((run / "config.json").read_text())["shield"] is True
    rows = list(csv.DictReader(open(run / "eval.csv")))
    assert rows and all(float(r["collisions"]) >= 0 for r in rows)
    env = SwarmEnv("random", **TINY_ENV)
    policy = load_policy(f"shield:ppo:{run}", env)  # how a shielded run is scored
    assert isinstance(policy, ShieldedPolicy)
    result = run_episode(env, policy, seed=1000)
    assert result["steps"] == 30 and "shield_interventions" in result["policy_stats"]


def test_the_bridge_steps_shielded_copies(tmp_path):
    from swarm_env_baselines.vec_env import make_vec_env

    venv = make_vec_env("random", 2, shield=True, seed=0, **TINY_ENV)
    venv.reset()
    assert all("shield_intervened" in info for info in venv.reset_infos)
    obs, rewards, dones, infos = venv.step(np.ones((venv.num_envs, 2), np.float32))
    assert all("shield_correction" in info for info in infos)
    venv.close()


def test_progress_bar_ends_at_the_steps_actually_taken(tmp_path, capsys):
    """SB3 stops between whole rollouts (here 2 copies x 2 followers x 32 steps = 128 agent-steps), so a budget
    of 100 takes 128 steps: the bar's total is 128, and it ends at 100 %, not at 128/100."""
    run = train_mod.train(_tiny(tmp_path, total_steps=100, eval_every=0, checkpoint_every=0, progress=True))
    assert json.loads((run / "summary.json").read_text())["agent_steps"] == 128
    final = capsys.readouterr().err.replace("\r", "\n").strip().splitlines()[-1]
    assert "100%" in final and "128/128" in final, final


def test_an_sb3_run_ships_and_loads_as_sb3_ppo(tmp_path):
    """``swarm-env ship`` takes a finished ``train sb3`` run: the safe pair of ``best/``, its records and SB3's
    log as ``progress.csv``; the README names the command and the selected row of ``eval.csv``; the seed loads
    as ``sb3_ppo:DIR`` and acts like ``ppo:`` on the run's best model."""
    import csv

    from swarm_env.harness.policies import acts_on, training_runs
    from swarm_env_baselines import ship

    run = train_mod.train(_tiny(tmp_path, checkpoint_every=0))
    versions = json.loads((run / "versions.json").read_text())
    versions["git_dirty"] = False  # as a run from a clean commit
    (run / "versions.json").write_text(json.dumps(versions))
    dest = tmp_path / "checkpoints"
    target = ship.ship_run(run, "sb3_ppo", "s0", dest=dest)
    assert sorted(p.name for p in target.iterdir()) == sorted(
        ["policy.safetensors", "policy.json", "progress.csv", *ship.SB3_RECORDS])
    assert ship.is_sb3_run(target)
    with open(run / "eval.csv", newline="") as fh:
        scores = [float(r["score"]) for r in csv.DictReader(fh)]
    best = ship.selected(target)
    assert best["score"] == min(scores) and best["agent_steps"] >= 0
    readme = ship.write_method_readme("sb3_ppo", dest=dest).read_text()
    assert "stable-baselines3's PPO" in readme and "| s0 |" in readme and f"{best['formation_error']:.3f}" in readme

    env = SwarmEnv("random", **TINY_ENV)
    shipped, original = load_policy(f"sb3_ppo:{target}", env), load_policy(f"ppo:{run}/best", env)
    obs, _ = env.reset(seed=3)
    state = env.world_state()
    a, b = shipped.act(obs, state), original.act(obs, state)
    assert all(np.array_equal(a[k], b[k]) for k in a)
    assert shipped.name == f"sb3_ppo:{target}"
    assert training_runs("sb3_ppo") == ("sb3_ppo:s0", "sb3_ppo:s1", "sb3_ppo:s2") and acts_on("sb3_ppo") == "observations"
    (run / "logs" / "progress.csv").unlink()
    with pytest.raises(ship.ShipError, match="progress.csv: missing"):
        ship.ship_run(run, "sb3_ppo", "s1", dest=dest)
