"""Humans that react (behavior: social_force): scenario files, the random knob, the physics."""

from __future__ import annotations

import numpy as np
import pytest

from swarm_env.env import SwarmEnv
from swarm_env.scenario import REACTIVE_SPEED_FACTOR, ScenarioError
from swarm_env.scenarios.loader import scenario_from_dict, scenario_to_dict


def _crossing(behavior: str | None, mode: str = "once") -> dict:
    """One follower standing still on the line a human walks (the leader far away, virtual)."""
    human = {"path": [[3.0, 6.0], [17.0, 6.0]], "speed": 0.5, "mode": mode}
    if behavior is not None:
        human["behavior"] = behavior
    return {
        "name": "crossing",
        "world": {"size": [20.0, 12.0], "dt": 0.1, "substeps": 4, "max_time": 40.0},
        "robots": {"count": 1, "radius": 0.25, "max_speed": 0.65, "max_turn_rate": 1.0, "start": [[10.0, 6.0, 0.0]]},
        "leader": {"kind": "virtual", "path": [[2.0, 10.5], [4.0, 10.5]], "speed": 0.1},
        "formations": [{"at": 0.0, "shape": "line", "spacing": 1.0}],
        "humans": [human],
    }


def _walk(spec: dict, steps: int = 300) -> tuple[float, int, list[np.ndarray]]:
    env = SwarmEnv(scenario_from_dict(spec), max_cycles=steps)
    env.reset(seed=0)
    gap, track = np.inf, []
    while env.agents:
        env.step({a: np.zeros(2, np.float32) for a in env.agents})  # the follower stands still
        st = env.world_state()
        track.append(st.human_pos[0].copy())
        gap = min(gap, float(np.hypot(*(st.human_pos[0] - st.follower_pose[0, :2])) - 0.25 - st.human_radius[0]))
    return gap, env.episode_metrics()["collisions"]["robot_human"], track


def test_a_scripted_human_walks_through_a_robot_a_reactive_one_goes_round() -> None:
    gap_s, hits_s, _ = _walk(_crossing(None))
    gap_r, hits_r, track = _walk(_crossing("social_force"))
    assert hits_s >= 1 and gap_s < 0.0  # the path runs through the robot
    assert hits_r == 0 and gap_r > 0.0
    assert np.hypot(*(track[-1] - [17.0, 6.0])) < 0.5  # and it still gets where it was going
    speeds = np.hypot(*np.diff(np.array(track), axis=0).T) / 0.1
    assert speeds.max() <= 0.5 * REACTIVE_SPEED_FACTOR + 1e-9


def test_reactive_humans_are_deterministic_and_walk_their_modes() -> None:
    a = _walk(_crossing("social_force", "pingpong"), 600)[2]
    b = _walk(_crossing("social_force", "pingpong"), 600)[2]
    assert np.array_equal(np.array(a), np.array(b))
    xs = np.array(a)[:, 0]
    assert xs.max() > 16.5 and xs[-1] < xs.max() - 1.0  # reached the far end and turned back


def test_the_behavior_key_and_the_random_knob() -> None:
    scn = scenario_from_dict(_crossing("social_force"))
    assert scn.humans[0].behavior == "social_force" and scn.humans[0].top_speed == 0.5 * REACTIVE_SPEED_FACTOR
    assert scenario_to_dict(scn)["humans"][0]["behavior"] == "social_force"
    assert "behavior" not in scenario_to_dict(scenario_from_dict(_crossing(None)))["humans"][0]  # the default stays implicit
    with pytest.raises(ScenarioError, match=r"humans\[0\]\.behavior"):
        scenario_from_dict(_crossing("panic"))
    env = SwarmEnv("random", n_humans=(2, 2), human_behavior="social_force", max_cycles=30)
    env.reset(seed=4)
    assert {h.behavior for h in env.world_state().scenario.humans} == {"social_force"}
    while env.agents:
        env.step({a: np.zeros(2, np.float32) for a in env.agents})
    with pytest.raises(ScenarioError, match="human_behavior"):
        SwarmEnv("random", human_behavior="panic")


def test_orca_humans_go_round_a_robot_and_survive_a_copy() -> None:
    pytest.importorskip("pyrvo")
    import pickle

    gap, hits, track = _walk(_crossing("orca"))
    assert hits == 0 and gap > -0.01  # ORCA lets the human take only half the avoidance: it grazes at most
    assert np.hypot(*(track[-1] - [17.0, 6.0])) < 0.5
    env = SwarmEnv(scenario_from_dict(_crossing("orca")), max_cycles=60)
    env.reset(seed=0)
    for _ in range(20):
        env.step({a: np.zeros(2, np.float32) for a in env.agents})
    twin = pickle.loads(pickle.dumps(env))  # the RVO2 crowd is rebuilt in the copy
    for _ in range(20):
        env.step({a: np.zeros(2, np.float32) for a in env.agents})
        twin.step({a: np.zeros(2, np.float32) for a in twin.agents})
    assert np.array_equal(env.world_state().human_pos, twin.world_state().human_pos)
