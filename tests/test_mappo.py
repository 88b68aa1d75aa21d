"""MAPPO / IPPO (baselines.mappo): the estimator, the statistics, a tiny run end to end, determinism."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("torch")
pytest.importorskip("safetensors")

from baselines import mappo  # noqa: E402
from swarm_env.env import SwarmEnv  # noqa: E402
from swarm_env.evaluation import run_episode  # noqa: E402
from swarm_env.policies import PolicyError, load_policy  # noqa: E402

TINY_ENV = {"n_followers": 2, "n_obstacles": 1, "n_humans": 0, "max_cycles": 30}


def _cfg(tmp_path, **overrides) -> mappo.MAPPOConfig:
    base = dict(env_kwargs=dict(TINY_ENV), total_steps=1024, n_copies=2, n_steps=32, n_epochs=2, hidden=(16, 16),
                eval_every=512, eval_seeds="500-501", runs_dir=str(tmp_path), run_name="tiny", progress=False)
    return mappo.MAPPOConfig(**{**base, **overrides})


def test_gae_matches_a_hand_computation() -> None:
    r = np.array([[1.0], [1.0], [1.0]])
    v = np.array([[0.5], [0.5], [0.5]])
    done = np.array([[0.0], [1.0], [0.0]])  # the episode ends after step 1; step 2 starts a new one
    adv = mappo.gae(r, v, done, np.array([2.0]), gamma=0.9, lam=0.8)
    d2 = 1.0 + 0.9 * 2.0 - 0.5
    d1 = 1.0 - 0.5  # no bootstrap across the end
    d0 = 1.0 + 0.9 * 0.5 - 0.5
    np.testing.assert_allclose(adv[:, 0], [d0 + 0.9 * 0.8 * d1, d1, d2])


def test_running_statistics_match_numpy() -> None:
    rng = np.random.default_rng(0)
    data = rng.normal(3.0, 2.0, (1000, 4))
    rms = mappo.RunningMeanStd((4,))
    for chunk in np.array_split(data, 7):
        rms.update(chunk)
    np.testing.assert_allclose(rms.mean, data.mean(axis=0), rtol=1e-6)
    np.testing.assert_allclose(rms.var, data.var(axis=0), rtol=1e-3)
    again = mappo.RunningMeanStd.from_json(json.loads(json.dumps(rms.to_json())))
    np.testing.assert_array_equal(again.normalize(data), rms.normalize(data))


def test_a_tiny_run_is_complete_and_loads_as_a_policy(tmp_path) -> None:
    run = mappo.train(_cfg(tmp_path))
    for name in ("config.json", "versions.json", "policy.safetensors", "policy.json", "eval.csv", "train.csv", "summary.json",
                 "learning_curve.png"):
        assert (run / name).is_file(), name
    assert (run / "best" / "policy.safetensors").is_file()
    summary = json.loads((run / "summary.json").read_text())
    assert summary["agent_steps"] == 1024 and summary["final"]["agent_steps"] == 1024
    env = SwarmEnv("random", **TINY_ENV)
    policy = load_policy(f"mappo:{run}", env)
    result = run_episode(env, policy, seed=1000)
    assert result["steps"] == 30 and np.isfinite(result["formation_error"]["mean"])
    with pytest.raises(PolicyError, match="trained on observations of shape"):
        load_policy(f"mappo:{run}", SwarmEnv("random", **TINY_ENV, sensors={"lidar_rays": 8}))
    with pytest.raises(PolicyError, match="needs a run directory"):
        load_policy("mappo", env)


def test_the_same_seed_trains_the_same_network_and_another_seed_does_not(tmp_path) -> None:
    from safetensors.numpy import load_file

    a = mappo.train(_cfg(tmp_path, run_name="a", eval_every=0))
    b = mappo.train(_cfg(tmp_path, run_name="b", eval_every=0))
    c = mappo.train(_cfg(tmp_path, run_name="c", eval_every=0, seed=1))
    ta, tb, tc = (load_file(str(r / "policy.safetensors")) for r in (a, b, c))
    assert all(np.array_equal(ta[k], tb[k]) for k in ta)
    assert any(not np.array_equal(ta[k], tc[k]) for k in ta)


@pytest.mark.parametrize("overrides", [{"critic": "local"}, {"shield": True}])
def test_ippo_and_the_shielded_variant_train(tmp_path, overrides) -> None:
    run = mappo.train(_cfg(tmp_path, total_steps=512, eval_every=0, **overrides))
    assert json.loads((run / "config.json").read_text())[next(iter(overrides))] == next(iter(overrides.values()))
    spec = f"shield:mappo:{run}" if overrides.get("shield") else f"mappo:{run}"
    result = run_episode(SwarmEnv("random", **TINY_ENV), load_policy(spec, SwarmEnv("random", **TINY_ENV)), seed=1001)
    assert result["steps"] == 30


def test_bad_input_is_refused(tmp_path, capsys) -> None:
    with pytest.raises(ValueError, match="critic must be"):
        mappo.MAPPOConfig(critic="global")
    assert mappo.main(["--total-steps", "0", "--runs-dir", str(tmp_path)]) == 2
    assert "total_steps must be a positive int" in capsys.readouterr().err
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "policy.json").write_text("{}")
    with pytest.raises(PolicyError, match="format: expected"):
        load_policy(f"mappo:{bad}", SwarmEnv("random", **TINY_ENV))


def test_the_update_starts_on_the_policy_that_collected_the_data(tmp_path) -> None:
    import csv

    run = mappo.train(_cfg(tmp_path, eval_every=0))
    rows = list(csv.DictReader(open(run / "train.csv")))
    assert rows and all(float(r["first_ratio_error"]) < 1e-5 for r in rows)
