"""Episode metrics (settling, per-robot table, JSON shape), the policy registry and the evaluation path."""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import pytest

import swarm_env
from swarm_env.env import SwarmEnv
from swarm_env.harness.episode import run_episode
from swarm_env.harness.evaluation import evaluate, summarize
from swarm_env.harness.policies import (
    PredictPolicy,
    RandomPolicy,
    UnknownPolicyError,
    ZeroPolicy,
    load_policy,
    registered_policies,
)
from swarm_env.scenarios.loader import scenario_from_dict
from swarm_env.state import WorldState


def _open_switch_scenario() -> Any:
    return scenario_from_dict(
        {
            "name": "open_switch",
            "world": {"size": [30.0, 12.0], "dt": 0.1, "substeps": 4, "max_time": 60.0, "settle_tolerance": 0.3},
            "robots": {"count": 3, "radius": 0.25, "max_speed": 0.65, "max_turn_rate": 1.0},
            "leader": {"kind": "virtual", "path": [[5.0, 6.0], [17.0, 6.0]], "speed": 0.4},
            "formations": [
                {"at": 0.0, "shape": "column", "spacing": 1.0},
                {"at": 10.0, "shape": "column", "spacing": 1.5},
            ],
        }
    )


def test_settle_time_and_success_with_a_tracking_policy() -> None:
    env = SwarmEnv(_open_switch_scenario())
    result = run_episode(env, load_policy("pursuit", env), seed=0)  # pure pursuit at the slots
    assert result["collisions"]["total"] == 0
    [settle] = result["settle_times"]
    assert settle["at"] == 10.0 and settle["shape"] == "column"
    assert settle["settle_time"] is not None and 0.5 < settle["settle_time"] < 15.0
    assert 0.0 < settle["hold_fraction"] <= 1.0  # (pursuit lags its moving slot: it holds ~2/3 of the time)
    assert result["success"] is True  # the leader arrived and the formation settled: terminated
    assert result["steps"] < 600
    leader = result["per_robot"][0]
    assert leader["robot"] == "leader" and abs(leader["distance"] - 12.0) < 1e-6
    assert abs(leader["time_to_target"] - 30.0) < 0.11
    assert abs(leader["avg_linear_velocity"] - 12.0 / result["sim_time"]) < 0.02
    assert len(result["per_robot"]) == 4
    assert result["formation_error"]["max"] >= result["formation_error"]["mean"] > 0
    json.dumps(result)  # JSON-ready


def test_hold_fraction_counts_the_steps_the_reached_formation_is_held() -> None:
    """Track the slots, then stop 8 s after the switch: the formation is reached, held, then lost;
    the metric must equal the fraction computed here from the env's own slot-distance infos."""
    env = SwarmEnv(_open_switch_scenario(), max_cycles=300)
    pursuit = load_policy("pursuit", env)
    obs, _ = env.reset(seed=0)
    pursuit.reset(env, 0)
    within_after_switch = []
    while env.agents:
        state = env.world_state()
        actions = pursuit.act(obs, state) if state.time < 18.0 else {a: np.zeros(2, np.float32) for a in env.agents}
        obs, _, _, _, infos = env.step(actions)
        if env.world_state().time >= 10.0 - 1e-9:
            tol = env.world_state().scenario.world.settle_tolerance
            within_after_switch.append(all(i["slot_distance"] <= tol for i in infos.values()))
    [settle] = env.episode_metrics()["settle_times"]
    first = within_after_switch.index(True)  # the step the new formation was reached
    expected = sum(within_after_switch[first:]) / len(within_after_switch[first:])
    assert settle["settle_time"] is not None
    assert settle["hold_fraction"] == pytest.approx(expected, abs=1e-12)
    assert 0.0 < settle["hold_fraction"] < 0.9  # lost when the followers stopped


def test_standing_still_never_settles_after_the_switch() -> None:
    env = SwarmEnv(_open_switch_scenario(), max_cycles=200)
    result = run_episode(env, ZeroPolicy(env), seed=0)
    assert result["settle_times"] == [{"at": 10.0, "shape": "column", "settle_time": None, "hold_fraction": None}]
    assert result["success"] is False
    assert result["per_robot"][1]["distance"] == pytest.approx(0.0, abs=1e-9)


def test_registry_lists_builtin_policies_from_entry_points() -> None:
    names = registered_policies()
    assert names["random"] == "swarm_env.harness.policies:RandomPolicy"
    assert names["zero"] == "swarm_env.harness.policies:ZeroPolicy"
    assert names["pursuit"] == "swarm_env.harness.policies:PursuitPolicy"


def test_pursuit_policy_tracks_slots_in_open_space() -> None:
    env = SwarmEnv(_open_switch_scenario())
    policy = load_policy("pursuit:0.5", env)
    result = run_episode(env, policy, seed=0)
    assert result["success"] and result["formation_error"]["mean"] < 0.3
    with pytest.raises(ValueError, match="time gap"):
        load_policy("pursuit:fast", env)


def test_load_policy_errors_and_wrapping() -> None:
    env = swarm_env.parallel_env("paper_vo_0")
    assert isinstance(load_policy("random", env), RandomPolicy)
    with pytest.raises(UnknownPolicyError, match="registered policies: .*random"):
        load_policy("nope", env)
    with pytest.raises(ValueError, match="no argument"):
        load_policy("zero:3", env)

    class Model:  # anything with SB3's predict() can be scored
        def predict(self, obs: np.ndarray, deterministic: bool = True) -> tuple[np.ndarray, None]:
            return np.tile(np.array([0.5, 0.0], np.float32), (len(obs), 1)), None

    short = swarm_env.parallel_env("paper_vo_0", max_cycles=30)  # before anyone reaches an obstacle
    policy = load_policy(Model(), short)
    assert isinstance(policy, PredictPolicy)
    result = run_episode(short, policy, seed=0)
    assert result["per_robot"][1]["avg_linear_velocity"] > 0.2


def test_evaluate_aggregates_episodes_with_confidence_intervals() -> None:
    report = evaluate("paper_vo_0", "random", episodes=3, seed=5, env_kwargs={"max_cycles": 40})
    assert [e["seed"] for e in report["episodes"]] == [5, 6, 7]
    s = report["summary"]
    assert s["episodes"] == 3 and s["formation_error"]["n"] == 3 and s["formation_error"]["ci95"] >= 0
    again = evaluate("paper_vo_0", "random", episodes=3, seed=5, env_kwargs={"max_cycles": 40})

    def strip(r):
        return [{k: v for k, v in e.items() if k not in ("wall_time", "policy_time")} for e in r["episodes"]]

    assert strip(report) == strip(again)  # seeded policy + env: identical episodes


def test_summarize_handles_missing_values() -> None:
    ep = {"success": False, "collisions": {"total": 0}, "formation_error": {"mean": 1.0}, "settle_times": [],
          "sim_time": 1.0, "min_separation": None}
    s = summarize([ep])
    assert s["settle_time"] == {"mean": None, "ci95": None, "n": 0}
    assert s["formation_error"] == {"mean": 1.0, "ci95": 0.0, "n": 1}


@pytest.mark.parametrize("name", ["paper_cbs_switch", "paper_vo_0", "corridor"])
def test_min_clearance_and_separation_equal_a_brute_force_minimum(name: str) -> None:
    """The metrics skip clearances that cannot lower the running minimum: same numbers as computing all."""
    env = SwarmEnv(name)
    env.reset(seed=1)
    rng = np.random.default_rng(2)
    clear, sep = [], []

    def observe(state: WorldState) -> None:
        pos, r = state.follower_pose[:, :2], state.follower_radius
        clear.append(float((state.static.distance(pos) - r).min()))
        if len(state.human_pos):
            gap = np.linalg.norm(pos[:, None] - state.human_pos[None], axis=2) - r[:, None] - state.human_radius
            clear.append(float(gap.min()))
        discs = np.vstack([np.column_stack([pos, r]), [[*state.leader_pose[:2], state.leader_radius]]])
        discs = discs if state.leader_is_robot else discs[:-1]
        d = np.linalg.norm(discs[:, None, :2] - discs[None, :, :2], axis=2) - discs[:, None, 2] - discs[None, :, 2]
        sep.append(float(d[np.triu_indices(len(discs), 1)].min()))

    observe(env.world_state())
    for _ in range(150):
        env.step({a: rng.uniform(-1.0, 1.0, 2).astype(np.float32) for a in env.agents})
        observe(env.world_state())
    result = env.episode_metrics()
    assert result["min_clearance"] == min(clear)
    assert result["min_separation"] == min(sep)


def test_parse_policy_kwargs_converts_by_the_defaults_types() -> None:
    from swarm_env.harness.policies import parse_policy_kwargs

    class Expert:
        def __init__(self, *, gain: float = 1.0, samples: int = 7, on: bool = True, limit: float | None = None,
                     angles: tuple = (0.0, 12.0)) -> None:
            pass

    got = parse_policy_kwargs("x", "gain=2.5, samples=9,on=false,limit=none,angles=0;24;-24", Expert)
    assert got == {"gain": 2.5, "samples": 9, "on": False, "limit": None, "angles": (0.0, 24.0, -24.0)}
    assert parse_policy_kwargs("x", None, Expert) == {}
    with pytest.raises(ValueError, match="unknown parameter 'gian'; known: gain, samples"):
        parse_policy_kwargs("x", "gian=1", Expert)
    with pytest.raises(ValueError, match="samples='many': expected int"):
        parse_policy_kwargs("x", "samples=many", Expert)
    with pytest.raises(ValueError, match="expected KEY=VALUE"):
        parse_policy_kwargs("x", "gain", Expert)
