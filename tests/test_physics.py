"""Physics invariants: nothing tunnels, robots push instead of overlapping, contacts count as onsets."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from swarm_env.env import SwarmEnv
from swarm_env.scenarios.loader import scenario_from_dict
from swarm_env.sim.world import COLLISION_SLOP


def _scenario(starts: list[list[float]], *, speed: float = 0.65, humans: list[dict] | None = None,
              substeps: int = 4, obstacles: list[dict] | None = None, accel: float | None = None) -> Any:
    return scenario_from_dict(
        {
            "name": "physics_probe",
            "world": {"size": [10.0, 10.0], "dt": 0.1, "substeps": substeps, "max_time": 30.0},
            "robots": {"count": len(starts), "radius": 0.25, "max_speed": speed, "max_turn_rate": 1.0,
                       "max_accel": accel, "start": starts},
            # The virtual leader parks in a corner so slots do not matter here.
            "leader": {"kind": "virtual", "path": [[9.0, 9.0], [9.5, 9.0]], "speed": 0.1},
            "formations": [{"at": 0.0, "shape": "line", "spacing": 0.6}],
            "obstacles": obstacles or [],
            "humans": humans or [],
        }
    )


def _drive(env: SwarmEnv, actions: dict[str, np.ndarray], steps: int) -> list[Any]:
    env.reset(seed=0)
    states = []
    for _ in range(steps):
        env.step({a: actions[a] for a in env.agents})
        states.append(env.world_state())
    return states


@pytest.mark.parametrize("speed,substeps", [(0.65, 4), (3.0, 8)])
def test_robot_driven_into_a_wall_never_passes(speed: float, substeps: int) -> None:
    env = SwarmEnv(_scenario([[1.0, 5.0, np.pi]], speed=speed, substeps=substeps))
    states = _drive(env, {"follower_0": np.array([1.0, 0.0], np.float32)}, 80)
    xs = np.array([s.follower_pose[0, 0] for s in states])
    # Without continuous collision detection a disc may sink at most one substep's travel (plus the
    # solver's slop) into the wall before the solver pushes it back out; it never crosses it.
    sink = speed * 0.1 / substeps + COLLISION_SLOP
    assert xs.min() >= 0.25 - sink - 1e-9
    assert abs(xs[-1] - (0.25 - COLLISION_SLOP)) < 1e-3  # resting against the wall
    assert env.episode_metrics()["collisions"]["robot_wall"] == 1


def test_robot_driven_into_an_obstacle_never_passes() -> None:
    obstacle = {"type": "rectangle", "center": [5.0, 5.0], "size": [0.2, 3.0], "angle": 0.0}
    env = SwarmEnv(_scenario([[3.0, 5.0, 0.0]], speed=3.0, substeps=8, obstacles=[obstacle]))
    states = _drive(env, {"follower_0": np.array([1.0, 0.0], np.float32)}, 60)
    xs = np.array([s.follower_pose[0, 0] for s in states])
    assert xs.max() <= 4.9 - 0.25 + 3.0 * 0.1 / 8 + COLLISION_SLOP
    c = env.episode_metrics()["collisions"]
    assert c["robot_obstacle"] == 1 and c["total"] == 1


def test_head_on_meeting_counts_exactly_one_collision_and_never_overlaps() -> None:
    env = SwarmEnv(_scenario([[3.0, 5.0, 0.0], [7.0, 5.0, np.pi]]))
    push = np.array([1.0, 0.0], np.float32)
    states = _drive(env, {"follower_0": push, "follower_1": push}, 100)  # they keep pushing for ~7 s
    gaps = np.array([np.linalg.norm(s.follower_pose[0, :2] - s.follower_pose[1, :2]) for s in states])
    assert gaps.min() >= 0.5 - 2 * 0.65 * 0.1 / 4 - COLLISION_SLOP
    assert gaps.min() < 0.51  # they really met
    metrics = env.episode_metrics()
    assert metrics["collisions"] == {"total": 1, "robot_robot": 1, "robot_obstacle": 0, "robot_human": 0,
                                     "robot_wall": 0}
    assert [r["collisions"] for r in metrics["per_robot"]] == [0, 1, 1]  # leader, follower_0, follower_1
    onsets = [c for s in states for c in s.contacts]
    assert len(onsets) == 1 and onsets[0].kind == "robot_robot" and {onsets[0].robot, onsets[0].other} == {0, 1}


def test_a_faster_robot_pushes_a_standing_one() -> None:
    env = SwarmEnv(_scenario([[3.0, 5.0, 0.0], [4.0, 5.0, 0.0]]))
    states = _drive(env, {"follower_0": np.array([1.0, 0.0], np.float32),
                          "follower_1": np.zeros(2, np.float32)}, 40)
    assert states[-1].follower_pose[1, 0] > 4.3  # the standing robot was pushed forward
    gap = np.linalg.norm(states[-1].follower_pose[0, :2] - states[-1].follower_pose[1, :2])
    assert gap >= 0.5 - 0.02


def test_walking_human_counts_one_robot_human_collision() -> None:
    human = {"path": [[8.0, 5.0], [1.0, 5.0]], "speed": 0.5, "radius": 0.3, "mode": "once"}
    beside = SwarmEnv(_scenario([[5.0, 6.0, 0.0]], humans=[human]))  # 1 m beside the lane: no contact
    _drive(beside, {"follower_0": np.zeros(2, np.float32)}, 150)
    assert beside.episode_metrics()["collisions"]["total"] == 0
    env2 = SwarmEnv(_scenario([[5.0, 5.1, 0.0]], humans=[human]))
    states = _drive(env2, {"follower_0": np.zeros(2, np.float32)}, 150)
    c = env2.episode_metrics()["collisions"]
    assert c["robot_human"] == 1 and c["total"] == 1
    assert any(c.kind == "robot_human" for s in states for c in s.contacts)


def test_acceleration_limit_is_enforced_per_substep() -> None:
    env = SwarmEnv(_scenario([[2.0, 5.0, 0.0]], accel=0.5))
    states = _drive(env, {"follower_0": np.array([1.0, 0.0], np.float32)}, 5)
    speeds = np.array([s.follower_twist[0, 0] for s in states])
    assert np.allclose(speeds, 0.5 * 0.1 * np.arange(1, 6), atol=1e-6)


def _deepest_overlaps(env: SwarmEnv, aim: Any, steps: int) -> dict[str, float]:
    """Drive every follower of ``env`` at full speed towards ``aim(state) -> (N, 2)`` points for ``steps``
    steps and return the deepest overlap seen after any physics substep (m), per kind of contact."""
    env.reset(seed=0)
    world, scn = env._world, env.scenario
    r, (w, h) = scn.robots.radius, scn.world.size
    static = env.world_state().static
    deepest = {"robot": 0.0, "obstacle": 0.0}
    space_step = world.space.step

    def measured_step(dt: float) -> None:  # the overlap can peak inside a control step: look after each substep
        space_step(dt)
        xy = np.array([tuple(b.position) for b in world._bodies])
        d = np.linalg.norm(xy[:, None] - xy[None], axis=-1)
        np.fill_diagonal(d, np.inf)
        deepest["robot"] = max(deepest["robot"], 2 * r - float(d.min()))
        wall = np.minimum(np.minimum(xy[:, 0], w - xy[:, 0]), np.minimum(xy[:, 1], h - xy[:, 1]))
        clearance = np.minimum(static.distance(xy, walls=False), wall)
        deepest["obstacle"] = max(deepest["obstacle"], r - float(clearance.min()))

    world.space.step = measured_step
    w_max = scn.robots.max_turn_rate
    for _ in range(steps):
        st = env.world_state()
        pose = st.follower_pose
        to = aim(st) - pose[:, :2]
        err = (np.arctan2(to[:, 1], to[:, 0]) - pose[:, 2] + np.pi) % (2 * np.pi) - np.pi
        turn = np.clip(err / (w_max * scn.world.dt), -1.0, 1.0)
        env.step({a: np.array([1.0, turn[i]], np.float32) for i, a in enumerate(env.agents)})
    return deepest


def test_overlap_on_paper_cbs_switch_stays_within_the_stated_bound() -> None:
    """README's overlap bound (swarm_env.sim.world.max_overlap), measured where it is largest: paper_cbs_switch
    (dt 0.5 s, 4 substeps: 6.25 cm of travel per substep), all 8 followers driven at full speed into one
    another (a pile-up at their centroid) and into one obstacle. Both runs must reach at least a single
    contact's depth (so the test is aggressive enough to fail) and stay within the stated bound."""
    from swarm_env.sim.world import COLLISION_SLOP, PILEUP_FACTOR, max_overlap

    env = SwarmEnv("paper_cbs_switch")
    bound = max_overlap(env.scenario)
    vh = env.scenario.robots.max_speed * env.scenario.world.dt / env.scenario.world.substeps
    assert vh == pytest.approx(0.0625)
    assert bound == pytest.approx({"robot": PILEUP_FACTOR * (2 * vh + COLLISION_SLOP),
                                   "obstacle": PILEUP_FACTOR * (vh + COLLISION_SLOP)})

    pile = _deepest_overlaps(env, lambda st: np.repeat(st.follower_pose[:, :2].mean(0, keepdims=True), 8, 0), 60)
    assert 2 * vh <= pile["robot"] <= bound["robot"], pile  # measured 0.148 m (bound 0.195 m)

    obstacle = env.scenario.obstacles[1]  # a disc 2 m beside the start of the V's outer arm
    into = _deepest_overlaps(env, lambda st: np.repeat(np.array([obstacle.center]), 8, 0), 100)
    assert vh <= into["obstacle"] <= bound["obstacle"], into  # measured 0.083 m (bound 0.101 m)
    assert into["robot"] <= bound["robot"], into
