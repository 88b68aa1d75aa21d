"""MAPPO / IPPO (swarm_env_baselines.mappo): the estimator, the statistics, DAgger, tiny runs end to end in every
mode (central/local critic, shield off/teach/execute, residual), determinism, the saved files."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

pytest.importorskip("torch")
pytest.importorskip("safetensors")

from swarm_env.env import SwarmEnv  # noqa: E402
from swarm_env.harness.episode import run_episode  # noqa: E402
from swarm_env.harness.policies import PolicyError, ShieldedPolicy, load_policy  # noqa: E402
from swarm_env_baselines import mappo, mappo_policy  # noqa: E402
from swarm_env_baselines.ppo_core import RunningMeanStd, gae  # noqa: E402

TINY_ENV = {"n_followers": 2, "n_obstacles": 1, "n_humans": 1, "max_cycles": 30}
TINY_PRETRAIN = {"pretrain_rounds": 2, "pretrain_episodes": 2, "pretrain_epochs": 1}


def _cfg(tmp_path, **overrides) -> mappo.MAPPOConfig:
    base = dict(env_kwargs=dict(TINY_ENV), total_steps=1024, n_copies=2, n_steps=32, n_epochs=2, hidden=(16, 16),
                eval_every=512, eval_seeds="500-501", runs_dir=str(tmp_path), run_name="tiny", progress=False,
                **TINY_PRETRAIN, prefetch_worlds=False)
    return mappo.MAPPOConfig(**{**base, **overrides})


def test_gae_matches_a_hand_computation() -> None:
    r = np.array([[1.0], [1.0], [1.0]])
    v = np.array([[0.5], [0.5], [0.5]])
    done = np.array([[0.0], [1.0], [0.0]])  # the episode ends after step 1; step 2 starts a new one
    adv = gae(r, v, done, np.array([2.0]), gamma=0.9, lam=0.8)
    d2 = 1.0 + 0.9 * 2.0 - 0.5
    d1 = 1.0 - 0.5  # no bootstrap across the end
    d0 = 1.0 + 0.9 * 0.5 - 0.5
    np.testing.assert_allclose(adv[:, 0], [d0 + 0.9 * 0.8 * d1, d1, d2])


def test_running_statistics_match_numpy_and_freeze() -> None:
    rng = np.random.default_rng(0)
    data = rng.normal(3.0, 2.0, (1000, 4))
    rms = RunningMeanStd((4,))
    for chunk in np.array_split(data, 7):
        rms.update(chunk)
    np.testing.assert_allclose(rms.mean, data.mean(axis=0), rtol=1e-6)
    np.testing.assert_allclose(rms.var, data.var(axis=0), rtol=1e-3)
    again = RunningMeanStd.from_json(json.loads(json.dumps(rms.to_json())))
    np.testing.assert_array_equal(again.normalize(data), rms.normalize(data))
    rms.frozen = True
    rms.update(data + 100.0)
    np.testing.assert_array_equal(again.normalize(data), rms.normalize(data))
    with pytest.raises(ValueError, match="finite"):
        RunningMeanStd.from_json({**rms.to_json(), "var": [1.0, -1.0, 1.0, 1.0]})


def test_dagger_warm_start_fits_the_expert_and_freezes_the_statistics() -> None:
    import torch

    from swarm_env.harness.policies import load_policy
    from swarm_env_baselines.imitation import DaggerSettings, dagger, rollouts
    from swarm_env_baselines.ppo_core import mlp

    torch.manual_seed(0)
    env = SwarmEnv("random", **TINY_ENV)
    dim = env.observation_space("follower_0").shape[0]
    actor, untrained = mlp([dim, 32, 32, 2]), mlp([dim, 32, 32, 2])
    rms = RunningMeanStd((dim,))
    settings = DaggerSettings(expert="pursuit", rounds=3, episodes=3, epochs=30)
    log = dagger(env, actor, rms, settings, torch.Generator().manual_seed(0))
    assert [r["round"] for r in log] == [0, 1, 2] and log[0]["samples"] == 3 * 2 * 30 < log[-1]["samples"]
    assert rms.frozen
    # On worlds it never saw, the student is far closer to the expert than an untrained network.
    obs, labels = rollouts(env, load_policy("pursuit", env), [900, 901], None)
    with torch.no_grad():
        x = torch.as_tensor(rms.normalize(obs))
        err, err0 = (((net(x).numpy() - labels) ** 2).sum(1).mean() for net in (actor, untrained))
    assert err < 0.25 * err0


@pytest.mark.slow
def test_a_tiny_run_is_complete_and_loads_as_a_policy(tmp_path) -> None:
    run = mappo.train(_cfg(tmp_path))
    for name in ("config.json", "versions.json", "policy.safetensors", "policy.json", "eval.csv", "train.csv",
                 "pretrain.csv", "summary.json", "learning_curve.png"):
        assert (run / name).is_file(), name
    assert (run / "best" / "policy.safetensors").is_file()
    summary = json.loads((run / "summary.json").read_text())
    assert summary["agent_steps"] == 1024 and summary["final"]["agent_steps"] == 1024
    evals = list(csv.DictReader(open(run / "eval.csv")))
    assert [int(r["agent_steps"]) for r in evals] == [0, 512, 1024]  # the warm start is the first point
    rows = list(csv.DictReader(open(run / "train.csv")))
    assert len(rows) == 8 and all(float(r["rollout_s"]) > 0 and float(r["update_s"]) >= 0 for r in rows)
    for r in rows:  # the diagnostics a researcher reads: all finite, in their ranges
        assert float(r["approx_kl"]) >= -1e-6 and 0.0 <= float(r["clip_fraction"]) <= 1.0
        assert float(r["explained_variance"]) <= 1.0 and float(r["agent_steps_per_s"]) > 0
    assert sum(int(r["episodes"]) for r in rows) == 2 * (1024 // 4 // 30)  # 2 worlds, 256 steps, 30-step episodes
    assert all(float(r["episode_return"]) < 0 for r in rows if int(r["episodes"]))
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    tb = EventAccumulator(str(run / "tb"))
    tb.Reload()
    tags = tb.Tags()["scalars"]
    for tag in ("train/approx_kl", "train/explained_variance", "rollout/collisions_per_episode", "eval/score",
                "time/agent_steps_per_s"):
        assert tag in tags, tag
    assert [e.step for e in tb.Scalars("eval/score")] == [0, 512, 1024]
    env = SwarmEnv("random", **TINY_ENV)
    policy = load_policy(f"mappo:{run}", env)
    result = run_episode(env, policy, seed=1000)
    assert result["steps"] == 30 and np.isfinite(result["formation_error"]["mean"])
    with pytest.raises(PolicyError, match="trained on inputs of size"):
        load_policy(f"mappo:{run}", SwarmEnv("random", **TINY_ENV, sensors={"lidar_rays": 8}))
    with pytest.raises(PolicyError, match="policy.json"):
        load_policy(f"mappo:{tmp_path / 'nowhere'}", env)


@pytest.mark.slow
def test_the_same_seed_trains_the_same_network_and_another_seed_does_not(tmp_path) -> None:
    from safetensors.numpy import load_file

    a = mappo.train(_cfg(tmp_path, run_name="a", eval_every=0))
    b = mappo.train(_cfg(tmp_path, run_name="b", eval_every=0))
    c = mappo.train(_cfg(tmp_path, run_name="c", eval_every=0, seed=1))
    ta, tb, tc = (load_file(str(r / "policy.safetensors")) for r in (a, b, c))
    assert all(np.array_equal(ta[k], tb[k]) for k in ta)
    assert any(not np.array_equal(ta[k], tc[k]) for k in ta)


@pytest.mark.parametrize("overrides", [
    {"critic": "local"},
    {"shield": "execute", "intervention_coef": 1.0},
    {"shield": "teach", "intervention_coef": 1.0, "imitation_coef": 1.0, "imitation_anneal": 0.5},
    {"residual": "vo", "pretrain": "none", "shield": "execute", "critic": "local"},
])
@pytest.mark.slow
def test_every_mode_trains_and_plays(tmp_path, overrides) -> None:
    run = mappo.train(_cfg(tmp_path, total_steps=512, eval_every=0, **overrides))
    config = json.loads((run / "config.json").read_text())
    assert all(config[k] == v for k, v in overrides.items())
    rows = list(csv.DictReader(open(run / "train.csv")))
    if overrides.get("shield", "off") != "off":
        assert any(float(r["intervention_rate"]) > 0 for r in rows)  # the shield did correct some actions
    if overrides.get("shield") == "teach":
        assert any(float(r["imitation_loss"]) > 0 for r in rows)
    env = SwarmEnv("random", **TINY_ENV)
    policy = load_policy(f"mappo:{run}", env)
    assert isinstance(policy, mappo_policy.ResidualPolicy) == bool(overrides.get("residual"))
    result = run_episode(env, ShieldedPolicy.around(policy), seed=1001)
    assert result["steps"] == 30


@pytest.mark.slow
def test_a_residual_policy_starts_at_its_expert(tmp_path) -> None:
    """The residual actor starts with a (near) zero correction: the first policy acts like vo."""
    run = mappo.train(_cfg(tmp_path, total_steps=128, n_steps=16, eval_every=0, residual="vo", pretrain="none",
                           critic="local", learning_rate=0.0))
    env = SwarmEnv("random", **TINY_ENV)
    residual, vo = load_policy(f"mappo:{run}", env), load_policy("vo", env)
    obs, _ = env.reset(seed=3)
    for p in (residual, vo):
        p.reset(env, 3)
    a, b = residual.act(obs, env.world_state()), vo.act(obs, env.world_state())
    assert all(np.abs(a[k] - b[k]).max() < 0.02 for k in a)


def test_a_device_torch_does_not_see_is_refused(tmp_path) -> None:
    import torch

    with pytest.raises(ValueError, match="device must be"):
        mappo.MAPPOConfig(device="gpu")
    if not torch.cuda.is_available():
        with pytest.raises(ValueError, match="torch sees no GPU"):
            mappo.train(_cfg(tmp_path, device="cuda", pretrain="none"))


def test_bad_input_is_refused(tmp_path, capsys) -> None:
    with pytest.raises(ValueError, match="critic must be"):
        mappo.MAPPOConfig(critic="global")
    with pytest.raises(ValueError, match="shield must be"):
        mappo.MAPPOConfig(shield="on")
    with pytest.raises(ValueError, match="need a shield"):
        mappo.MAPPOConfig(imitation_coef=1.0)
    with pytest.raises(ValueError, match="pretrain none"):
        mappo.MAPPOConfig(residual="vo")
    assert mappo.main(["--total-steps", "0", "--runs-dir", str(tmp_path)]) == 2
    assert "total_steps must be a positive int" in capsys.readouterr().err
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "policy.json").write_text("{}")
    with pytest.raises(PolicyError, match="format: expected"):
        load_policy(f"mappo:{bad}", SwarmEnv("random", **TINY_ENV))


@pytest.mark.slow
def test_the_update_starts_on_the_policy_that_collected_the_data(tmp_path) -> None:
    """In the training process, every update; with a learner process (one update behind), the first only."""
    run = mappo.train(_cfg(tmp_path, eval_every=0, pretrain="none", learner_process=False))
    rows = list(csv.DictReader(open(run / "train.csv")))
    assert rows and all(float(r["first_ratio_error"]) < 1e-5 for r in rows)
    run = mappo.train(_cfg(tmp_path, eval_every=0, pretrain="none", run_name="lag"))
    rows = [float(r["first_ratio_error"]) for r in csv.DictReader(open(run / "train.csv"))]
    assert len(rows) > 2 and rows[0] < 1e-5 and all(r > 1e-4 for r in rows[1:])


@pytest.mark.slow
def test_a_learned_policy_plays_the_same_episode_bit_for_bit_in_other_processes(tmp_path) -> None:
    """Learned rows of a leaderboard reproduce: one torch thread, deterministic algorithms, a fixed
    batch; other processes (another hash seed, another BLAS thread setting, a 2-worker leaderboard)
    give every metric but the timings bit for bit."""
    import os
    import subprocess
    import sys

    from swarm_env.harness.leaderboard import TIMING_KEYS, run_leaderboard

    run = mappo.train(_cfg(tmp_path, total_steps=512, eval_every=0))
    spec = f"mappo:{run}"
    env_kwargs = {k: v for k, v in TINY_ENV.items()}
    here = run_leaderboard([spec, "pursuit"], ["random"], [1000, 1001], env_kwargs=env_kwargs, progress=False)

    def behaviour(board) -> list:
        return [json.dumps({k: v for k, v in e["metrics"].items() if k not in TIMING_KEYS}, sort_keys=True)
                for e in board.episodes]

    code = (
        "import json, sys\n"
        "from swarm_env.harness.leaderboard import run_leaderboard\n"
        f"b = run_leaderboard({[spec, 'pursuit']!r}, ['random'], [1000, 1001], env_kwargs={env_kwargs!r}, "
        "workers=int(sys.argv[1]), progress=False)\n"
        "json.dump(b.to_dict(), sys.stdout)\n"
    )
    from swarm_env.harness.leaderboard import Leaderboard

    for hashseed, threads, workers in (("1", "1", 1), ("999", "2", 2)):
        env = {**os.environ, "PYTHONHASHSEED": hashseed, "OPENBLAS_NUM_THREADS": threads, "OMP_NUM_THREADS": threads}
        out = subprocess.run([sys.executable, "-c", code, str(workers)], env=env, capture_output=True, text=True,
                             check=True, timeout=300)
        doc = json.loads(out.stdout)
        there = Leaderboard(doc["policies"], doc["scenarios"], doc["seeds"], doc["env_kwargs"], [], doc["episodes"])
        assert behaviour(there) == behaviour(here)


@pytest.mark.slow
def test_a_finished_clean_run_ships_with_its_records_and_a_readme(tmp_path) -> None:
    from swarm_env_baselines import ship

    run = mappo.train(_cfg(tmp_path, total_steps=512, eval_every=256))
    versions = json.loads((run / "versions.json").read_text())
    dest = tmp_path / "checkpoints"
    if versions["git_dirty"] is not False:  # a developer's tree: the rule must refuse it by default
        with pytest.raises(ship.ShipError, match="git_dirty"):
            ship.ship_run(run, "mappo", "s0", dest=dest)
    versions["git_dirty"] = False
    (run / "versions.json").write_text(json.dumps(versions))
    target = ship.ship_run(run, "mappo", "s0", dest=dest)
    assert sorted(p.name for p in target.iterdir()) == sorted(
        ["policy.safetensors", "policy.json", *ship.RECORDS, "pretrain.csv"])
    assert (target / "policy.safetensors").read_bytes() == (run / "best" / "policy.safetensors").read_bytes()
    shipped_again = ship.ship_run(run, "mappo", "s0", dest=dest)  # replaces the old copy whole
    assert shipped_again == target and not list(target.parent.glob(".*"))
    readme = ship.write_method_readme("mappo", dest=dest).read_text()
    assert "swarm-env train mappo" in readme and "centralised" in readme
    t = ship.time_breakdown(target)
    assert t["rollout"] > 0 and t["update"] > 0 and t["wall"] >= t["rollout"] + t["update"]
    policy = load_policy(f"mappo:{target}", SwarmEnv("random", **TINY_ENV))
    assert policy.mean_actions(np.zeros((1, policy.obs_rms.mean.shape[0]))).shape == (1, 2)
    (run / "summary.json").unlink()
    with pytest.raises(ship.ShipError, match="summary.json: missing"):
        ship.ship_run(run, "mappo", "s1", dest=dest)


def test_what_each_policy_acts_on_is_declared() -> None:
    from swarm_env.harness.policies import acts_on

    assert [acts_on(s) for s in ("ippo", "mappo", "mappo_shielded_bare", "ppo", "bc:x")] == ["observations"] * 5
    assert acts_on("mappo_shielded") == "observations + shield" and acts_on("shield:ppo") == "observations + shield"
    assert acts_on("residual_vo") == "state + shield"
    assert [acts_on(s) for s in ("vo", "cbs_rrt", "pursuit", "shield:pursuit")] == ["state"] * 4
    assert acts_on("random") == "nothing" and acts_on("no_such_policy") == "?"


@pytest.mark.slow
def test_validation_in_a_background_process_gives_the_same_run(tmp_path) -> None:
    """eval_workers=1 scores saved snapshots in another process: the same eval.csv (but the clock), the same
    selected model and final networks, and no snapshot left behind."""
    from safetensors.numpy import load_file

    here = mappo.train(_cfg(tmp_path, run_name="here"))
    there = mappo.train(_cfg(tmp_path, run_name="there", eval_workers=1))

    def rows(run):
        return [{k: v for k, v in r.items() if k != "wall_s"} for r in csv.DictReader(open(run / "eval.csv"))]

    assert rows(here) == rows(there) and len(rows(here)) == 3
    for sub in ("best", "."):
        a, b = load_file(str(here / sub / "policy.safetensors")), load_file(str(there / sub / "policy.safetensors"))
        assert a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)
    a, b = (json.loads((run / "best" / "policy.json").read_text()) for run in (here, there))
    assert {k: v for k, v in a.items() if k != "config"} == {k: v for k, v in b.items() if k != "config"}
    assert not (there / "evals").exists() and not list(there.glob(".best.*"))


def test_a_run_without_matplotlib_finishes_with_a_warning_and_no_picture(tmp_path, monkeypatch) -> None:
    """The `plots` extra is optional: `pip install swarm-env[rl]` trains to the end (summary, policy, no PNG)."""
    import sys

    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib -> ImportError
    with pytest.warns(UserWarning, match=r"learning_curve.png not drawn: matplotlib is missing.*swarm-env\[plots\]"):
        run = mappo.train(_cfg(tmp_path, total_steps=256, eval_every=0, pretrain="none", learner_process=False))
    assert (run / "summary.json").is_file() and (run / "policy.safetensors").is_file()
    assert not (run / "learning_curve.png").exists()
