"""The shipped checkpoints (baselines/checkpoints/) load through the registry and score one episode."""

from __future__ import annotations

import json

import pytest

pytest.importorskip("stable_baselines3")

from baselines.model_io import CHECKPOINT_DIR, SHIPPED, SB3Policy  # noqa: E402
from swarm_env.env import SwarmEnv  # noqa: E402
from swarm_env.evaluation import run_episode  # noqa: E402
from swarm_env.policies import load_policy  # noqa: E402


SHIPPED_DIRS = sorted(p for p in CHECKPOINT_DIR.iterdir() if p.is_dir())


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
