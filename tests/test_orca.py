"""The ORCA reference policy (swarm_env_agents.orca, RVO2 through pyrvo)."""

from __future__ import annotations

import sys

import pytest

from swarm_env.env import SwarmEnv
from swarm_env.extras import MissingExtraError
from swarm_env.harness.episode import run_episode
from swarm_env.harness.policies import acts_on, load_policy


def test_orca_follows_the_formation_without_collisions() -> None:
    pytest.importorskip("pyrvo")
    env = SwarmEnv("paper_vo_90")
    result = run_episode(env, load_policy("orca", env), seed=0)
    assert result["collisions"]["total"] == 0 and result["success"]
    assert result["formation_error"]["mean"] < 0.2
    assert result["policy_stats"]["decision_time_ms"]["calls"] == result["steps"]


def test_orca_avoids_and_is_deterministic() -> None:
    """Random worlds with humans: ORCA avoids (pursuit, which does not, collides on these worlds),
    and the same seed gives the same episode."""
    pytest.importorskip("pyrvo")
    env = SwarmEnv("random", n_humans=(2, 3))
    totals = {}
    for spec in ("orca", "pursuit"):
        totals[spec] = sum(run_episode(env, load_policy(spec, env), seed)["collisions"]["total"] for seed in range(1000, 1004))
    assert totals["orca"] < totals["pursuit"]
    a = run_episode(env, load_policy("orca", env), 1001)
    b = run_episode(env, load_policy("orca", env), 1001)
    assert a["formation_error"] == b["formation_error"] and a["steps"] == b["steps"]


def test_orca_parameters_discrete_envs_and_the_missing_extra(monkeypatch) -> None:
    env = SwarmEnv("paper_vo_90")
    assert acts_on("orca") == "state"
    with pytest.raises(ValueError, match="unknown parameter"):
        load_policy("orca:speed=3", env)
    with pytest.raises(ValueError, match="horizon"):
        load_policy("orca:horizon=0", env)
    with pytest.raises(ValueError, match="continuous"):
        load_policy("orca", SwarmEnv("paper_vo_90", action_type="discrete"))
    monkeypatch.setitem(sys.modules, "pyrvo", None)  # as if not installed
    policy = load_policy("orca", env)
    with pytest.raises(MissingExtraError, match=r"swarm-env\[orca\]"):
        policy.reset(env, 0)
