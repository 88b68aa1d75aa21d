"""The shipped checkpoints (baselines/checkpoints/) load through the registry and score one episode.

Two kinds: the v0 SB3 checkpoints (``ppo``, ``bc``, ``ppo_from_bc``: one directory each, trained on
swarm_env_v0) and the methods of :mod:`baselines.mappo` (``checkpoints/<method>/s<k>``, three
training seeds each, whose test episodes in ``docs/leaderboard/leaderboard.json`` must replay bit for bit).
"""

from __future__ import annotations

import json

import pytest

pytest.importorskip("stable_baselines3")

from baselines.mappo_policy import CHECKPOINTS, SHIPPED_SEEDS  # noqa: E402
from baselines.model_io import CHECKPOINT_DIR, SHIPPED, SB3Policy  # noqa: E402
from swarm_env.env import SwarmEnv  # noqa: E402
from swarm_env.evaluation import run_episode  # noqa: E402
from swarm_env.leaderboard import _behaviour, _json_roundtrip  # noqa: E402
from swarm_env.policies import load_policy  # noqa: E402

#: The v0 SB3 checkpoints (kept loadable; docs/baselines.md marks them v0).
SHIPPED_DIRS = [CHECKPOINT_DIR / name for name in ("bc_vo_random", "ppo_from_bc", "ppo_random")]
#: The methods of baselines.mappo, one directory per training seed.
METHODS = ("ippo", "mappo", "mappo_shielded", "residual_vo")
LEADERBOARD = CHECKPOINTS.parents[1] / "docs" / "leaderboard" / "leaderboard.json"


def _spec(directory) -> str:
    return f"{directory.name.split('_')[0]}:{directory}"  # ppo_* -> ppo:, bc_* -> bc:


def test_the_default_policies_are_shipped():
    assert set(SHIPPED) == {"ppo", "bc"} and all(path in SHIPPED_DIRS for path in SHIPPED.values())


@pytest.mark.parametrize("directory", SHIPPED_DIRS, ids=[p.name for p in SHIPPED_DIRS])
def test_shipped_checkpoint_is_small_documented_and_loads(directory):
    files = {p.name for p in directory.iterdir()}
    assert {"model.zip", "vecnormalize.pkl", "README.md", "learning_curve.png"} <= files
    assert sum(p.stat().st_size for p in directory.iterdir()) < 5e6  # "a few MB at most"
    assert "python -m baselines." in (directory / "README.md").read_text()  # the command that made it
    policy = load_policy(_spec(directory), SwarmEnv("random"))
    assert isinstance(policy, SB3Policy) and policy.vecnorm is not None


@pytest.mark.parametrize("name", ["ppo", "bc", f"ppo:{CHECKPOINT_DIR / 'ppo_from_bc'}"])
def test_shipped_policy_holds_the_formation_on_a_held_out_world(name):
    # Seed 1000 is a test world (training < 1000). A random policy drifts ~10 m from its slots here;
    # a policy that learnt anything stays within a metre on average.
    env = SwarmEnv("random")
    result = run_episode(env, load_policy(name, env), seed=1000)
    assert result["formation_error"]["mean"] < 1.0
    random_result = run_episode(env, load_policy("random", env), seed=1000)
    assert random_result["formation_error"]["mean"] > 5.0


def test_shipped_ppo_records_its_training_run():
    directory = SHIPPED["ppo"]
    config = json.loads((directory / "config.json").read_text())
    assert config["algo"] == "ppo" and config["scenario"] == "random"
    summary = json.loads((directory / "summary.json").read_text())
    assert summary["agent_steps"] >= 1_000_000 and summary["wall_s"] > 0


@pytest.mark.parametrize("method", METHODS)
def test_a_shipped_method_has_three_clean_safe_seeds(method):
    readme = (CHECKPOINTS / method / "README.md").read_text()
    assert "python -m baselines.mappo" in readme and "| s2 |" in readme
    for seed in SHIPPED_SEEDS:
        d = CHECKPOINTS / method / seed
        files = {p.name for p in d.iterdir()}
        assert {"policy.safetensors", "policy.json", "config.json", "versions.json", "eval.csv", "train.csv"} <= files
        assert not {f for f in files if f.endswith((".pkl", ".zip", ".pt"))}  # tensors + JSON only
        versions = json.loads((d / "versions.json").read_text())
        assert versions["git_dirty"] is False and len(versions["git_commit"]) == 40
        config = json.loads((d / "config.json").read_text())
        assert config["seed"] == int(seed[1:]) and config["eval_seeds"] == "500-549"  # selection off the test seeds
        assert json.loads((d / "summary.json").read_text())["wall_s"] < 3600  # the 60 min budget


def _stored_test_episodes() -> dict[tuple[str, int], dict]:
    doc = json.loads(LEADERBOARD.read_text())
    return {(e["policy"], e["seed"]): e["metrics"] for e in doc["episodes"] if e["scenario"] == "random"}


@pytest.mark.parametrize("spec", [f"{m}:s{k}" for m in (*METHODS, "mappo_shielded_bare") for k in (0, 2)])
def test_a_shipped_method_replays_its_leaderboard_episode_bit_for_bit(spec):
    stored = _stored_test_episodes()[(spec, 1000)]
    env = SwarmEnv("random")
    played = run_episode(env, load_policy(spec, env), seed=1000)
    # _behaviour: every metric but the timings, compared as the JSON file stores them
    assert _json_roundtrip(_behaviour(played)) == _json_roundtrip(_behaviour(stored))
