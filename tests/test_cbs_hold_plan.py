"""Holding a formation by planning it (``hold_plan``, :mod:`swarm_env_agents.cbs_rrt.hold_plan`)."""

from __future__ import annotations

import math

import numpy as np
import pytest

import swarm_env
from swarm_env.geometry.formation import virtual_slot_trajectory
from swarm_env.geometry.static_map import StaticMap
from swarm_env.harness.episode import run_episode
from swarm_env.scenario import RobotSpec, WorldSpec
from swarm_env.scenarios.loader import load_scenario
from swarm_env_agents.cbs_rrt.distance_field import DistanceField
from swarm_env_agents.cbs_rrt.hold_plan import (
    CHORD_ALLOWANCE,
    PlanTracker,
    PointModel,
    joint_paths,
    point_dp,
    substep_rollout,
    virtual_leader_done_step,
)
from swarm_env_agents.cbs_rrt.policy import CBSRRTExpert


def _tracker(field: DistanceField) -> PlanTracker:
    """A tracker of robots of radius 0.25 m at up to 0.5 m/s and 1 rad/s, steps of 0.5 s in 4 substeps."""
    robots = RobotSpec(count=2, radius=0.25, max_speed=0.5, max_turn_rate=1.0)
    world = WorldSpec(field.size, dt=0.5, substeps=4, settle_tolerance=0.3)
    return PlanTracker(field, robots, world, separation=0.52, horizon=5)


def test_point_dp_finds_the_most_steps_a_point_can_hold() -> None:
    """A slot that jumps 2 m at step 5: a point moving 0.25 m per step holds steps 0-4, then needs
    until step 10 to be within 0.32 m again (it leaves as late as it can: 10.3 + 6 x 0.25 = 11.8),
    so 8 of steps 0-12. Starting 1 m off, it is on the first slot at steps 3-4 only and, from
    10.0 m at step 4, within 0.32 m of the second at steps 11-12: 4."""
    static = StaticMap.from_obstacles((20.0, 20.0), [])
    slots = np.array([[10.0, 10.0]] * 5 + [[12.0, 10.0]] * 8)
    model = PointModel(h=0.05, tol=0.32, step=0.25, floor=0.28, separation=0.56)
    dp = point_dp(static, slots, 0, 12, model)
    assert dp.value(0) == 8
    path = dp.path(0)
    assert path.shape == (13, 2)
    assert np.all(np.hypot(*np.diff(path, axis=0).T) <= 0.25 + 1e-9)
    held = np.hypot(*(path - slots).T) <= 0.32
    assert int(held.sum()) == 8 and held[:5].all() and held[10:].all()
    late = dp.path(0, start=np.array([9.0, 10.0]))
    assert np.allclose(late[0], [9.0, 10.0])
    assert int((np.hypot(*(late - slots).T) <= 0.32).sum()) == 4
    with pytest.raises(ValueError, match="gain"):
        point_dp(static, slots, 0, 12, model, gain=np.zeros(13, dtype=int))


def test_joint_paths_keep_their_margins_and_hold_the_grid() -> None:
    """``paper_cbs_switch`` after the switch, 40 steps from t = 95 s, starting 0.2 m off the slots:
    every point keeps ``r + 0.03`` from obstacles and ``2 r + 0.06`` from the others at every step,
    moves at most a step's travel, and the whole grid is within tolerance in most steps."""
    scn = load_scenario("paper_cbs_switch")
    static = StaticMap.from_obstacles(scn.world.size, scn.obstacles)
    dt, r, tol = scn.world.dt, scn.robots.radius, scn.world.settle_tolerance
    k0, k_end = int(95 / dt), int(95 / dt) + 40
    slots, _ = virtual_slot_trajectory(scn, static, k_end + 1)
    starts = slots[k0] + np.array([0.2, 0.0])
    floor, sep = r + CHORD_ALLOWANCE, 2 * r + 2 * CHORD_ALLOWANCE
    paths = joint_paths(static, slots, k0, k_end, PointModel(0.05, tol, scn.robots.max_speed * dt, floor, sep),
                        starts=starts)
    assert paths.shape == (41, scn.robots.count, 2)
    assert np.all(np.abs(paths[0] - starts) <= 0.05 / 2 + 1e-9)  # the nearest lattice point
    assert np.all(np.hypot(*np.diff(paths, axis=0).transpose(2, 0, 1)) <= scn.robots.max_speed * dt + 1e-9)
    assert static.distance(paths).min() >= floor
    gaps = np.hypot(*(paths[:, :, None] - paths[:, None]).transpose(3, 0, 1, 2))
    gaps[:, np.arange(scn.robots.count), np.arange(scn.robots.count)] = np.inf
    assert gaps.min() >= sep
    held = np.all(np.hypot(*(paths - slots[k0 : k_end + 1]).transpose(2, 0, 1)) <= tol, axis=1)
    assert held.mean() >= 0.9


def test_plan_tracker_follows_a_path_and_keeps_off_obstacles() -> None:
    """A robot at rest, facing east, on a plan going east at 0.2 m per step is on the plan within a
    few steps and stays there; a plan through a wall's clearance is not followed into it."""
    field = DistanceField.build(StaticMap.from_obstacles((10.0, 6.0), []), 0.05)
    tracker = _tracker(field)
    plan = np.array([[1.0 + 0.2 * k, 3.0] for k in range(40)])[:, None, :]
    state = np.array([[1.0, 3.0, 0.0, 0.0, 0.0, 0.0]])
    off = []
    for k in range(25):
        tw = tracker.twists(state, plan[k : k + 6], plan[k : k + 6])
        state, _ = substep_rollout(state, tw, 4, 0.125)
        off.append(math.hypot(*(state[0, :2] - plan[k + 1, 0])))
    assert max(off[3:]) < 0.1
    wall = np.array([[9.0 + 0.2 * k, 3.0] for k in range(12)])[:, None, :]  # runs into the world's east edge
    state = np.array([[9.0, 3.0, 0.0, 0.0, 0.0, 0.0]])
    for k in range(6):
        tw = tracker.twists(state, wall[k : k + 6], wall[k : k + 6])
        state, subs = substep_rollout(state, tw, 4, 0.125)
        assert field.clearance_xy(subs[..., 0], subs[..., 1]).min() >= 0.25 + 0.01 - field.error_bound
    with pytest.raises(ValueError, match="shape"):
        tracker.twists(state, wall[:3], wall[:3])


@pytest.mark.slow
def test_expert_plans_the_hold_only_with_a_virtual_leader_and_long_steps() -> None:
    """By default the expert plans a reached formation where the slots are known ahead (a virtual
    leader), no human walks about (the plan has none in it) and a step moves a robot at least four
    lattice cells (``paper_cbs_switch``: 0.25 m). The random worlds (dt = 0.1 s), and any with
    humans, keep CBS: nothing is held there unless ``hold_slots`` asks for it."""
    scn = load_scenario("paper_cbs_switch")
    assert virtual_leader_done_step(scn, 10_000) * scn.world.dt == pytest.approx(185.0)
    assert CBSRRTExpert().hold_plan is True and CBSRRTExpert().hold_slots is False
    paper = CBSRRTExpert()
    run_episode(swarm_env.parallel_env("paper_cbs_switch", max_cycles=30), paper, 0)  # starts in its V
    assert paper.stats()["hold_plans"] >= 1 and paper.stats()["hold_steps"] >= 25
    off = CBSRRTExpert(hold_plan=False)
    run_episode(swarm_env.parallel_env("paper_cbs_switch", max_cycles=30), off, 0)
    assert off.stats()["hold_plans"] == 0 and off.stats()["hold_steps"] == 0
    for knobs, plans in (({}, False), ({"dt": 0.5, "substeps": 4, "n_humans": 2}, False),
                         ({"dt": 0.5, "substeps": 4, "n_humans": 0}, True)):
        rnd = CBSRRTExpert()
        run_episode(swarm_env.parallel_env("random", n_followers=3, max_time=30.0, leader_kind="virtual", **knobs), rnd, 5)
        assert (rnd.stats()["hold_plans"] > 0) is plans, knobs


def test_plan_tracker_never_drives_two_robots_into_each_other() -> None:
    """Two robots driving at each other at full speed, each with a plan straight through the other:
    neither the step's substeps nor the next step's first one (which still moves with this step's
    velocity, whatever is commanded) ever brings them into contact."""
    field = DistanceField.build(StaticMap.from_obstacles((12.0, 6.0), []), 0.05)
    tracker = _tracker(field)
    east = np.array([[3.0 + 0.25 * k, 3.0] for k in range(30)])
    west = np.array([[4.2 - 0.25 * k, 3.0] for k in range(30)])
    plan = np.stack([east, west], axis=1)  # (K, 2, 2)
    state = np.array([[3.0, 3.0, 0.0, 0.5, 0.0, 0.0], [4.2, 3.0, math.pi, -0.5, 0.0, 0.0]])
    closest = np.inf
    for k in range(12):
        tw = tracker.twists(state, plan[k : k + 6], plan[k : k + 6])
        state, subs = substep_rollout(state, tw, 4, 0.125)
        closest = min(closest, float(np.hypot(*(subs[:, 0] - subs[:, 1]).T).min()))
    assert closest >= 0.5
