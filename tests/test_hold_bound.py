"""benchmarks/hold_bound.py, the feasibility bound of issue 12's hold target: its slot record is the
env's, its kinematics are the env's, and its lattice DP gives valid paths bracketed by its relaxation."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from swarm_env.env import SwarmEnv
from swarm_env.scenarios.loader import load_scenario

_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "hold_bound.py"


@pytest.fixture(scope="module")
def hb():
    spec = importlib.util.spec_from_file_location("hold_bound", _PATH)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules["hold_bound"] = mod  # dataclasses look their module up
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def rec(hb):
    return hb.record_slots(load_scenario("paper_cbs_switch"))


def test_slot_record_is_the_envs(hb, rec):
    """The recorded slots are the env's, bitwise, whatever the followers do and the seed."""
    for seed, v in ((0, 0.0), (5, 0.4)):
        env = SwarmEnv(load_scenario("paper_cbs_switch"))
        env.reset(seed=seed)
        for k in range(1, 41):
            env.step({a: np.array([v, 0.3], dtype=np.float32) for a in env.agents})
            assert np.array_equal(env.world_state().slot_targets, rec.slots[k])
    assert rec.done_step == 370  # 22.18 m at 0.12 m/s: done at t = 185.0


def test_unicycle_rollout_is_the_envs_kinematics(hb):
    """One follower driven from rest by three commands lands where the env puts it (no contacts)."""
    scn = load_scenario("paper_cbs_switch")
    env = SwarmEnv(scn)
    env.reset(seed=0)
    world = env._world
    pose = env.world_state().follower_pose[0]
    state = np.array([pose[0], pose[1], pose[2], 0.0, 0.0, 0.0])
    for cmd in ((0.5, 1.0), (0.5, -1.0), (-0.3, 0.5)):
        command = np.zeros((scn.robots.count, 2))
        command[0] = cmd
        world.step(command)
        state, _ = hb.substep_rollout(state, np.array(cmd), scn.world.substeps, scn.world.dt / scn.world.substeps)
        got = world.snapshot().follower_pose[0]
        assert np.allclose(state[:3], got, atol=1e-9), (state, got)


def test_jumps_name_the_leader_turn_and_the_flip(hb, rec):
    jumps = hb.slot_jumps(rec, 0.25, 161, 370)
    turn = [j for j in jumps if j.t == 124.5]
    assert sorted(j.follower for j in turn) == list(range(8))
    assert all(j.cause == "leader turn" for j in turn)
    [flip] = [j for j in jumps if j.t == 179.5]
    assert (flip.follower, flip.cause, flip.obstacle) == (0, "obstacle flip", 9)
    assert flip.size > 1.0 and flip.push_turn_deg > 150.0


def test_point_dp_paths_are_valid_and_bracketed(hb, rec):
    """Around follower 0's flip at t = 179.5: the exact DP's path moves at most v dt per step, keeps
    its disc off the obstacles, holds its slot in exactly the steps its value says; the relaxed DP's
    value is at least that, and even it cannot hold every step (the flip costs steps)."""
    k0, k_end = 345, 370
    lo = hb.point_dp(rec, 0, k0, k_end, 0.05, relax=False)
    up = hb.point_dp(rec, 0, k0, k_end, 0.05, relax=True)
    path = lo.path(k0)
    assert path.shape == (k_end - k0 + 1, 2)
    assert np.all(np.hypot(*np.diff(path, axis=0).T) <= 0.25 + 1e-9)
    radius = rec.scenario.robots.radius
    fine = np.concatenate([path[:-1] + np.diff(path, axis=0) * f for f in np.linspace(0, 1, 11)])
    assert rec.static.distance(fine).min() >= radius
    held = int((np.hypot(*(path - rec.slots[k0 : k_end + 1, 0]).T) <= 0.3).sum())
    assert held == lo.value(k0)
    assert lo.value(k0) <= up.value(k0) < k_end - k0 + 1
    assert up.value(k0) >= k_end - k0 + 1 - 5  # and the flip is not hopeless: a few steps


def test_prioritised_paths_keep_robots_apart(hb, rec):
    k_s, k_end = 355, 370
    paths = hb.prioritised_paths(rec, k_s, k_end, 0.05, list(range(8)))
    fine = np.concatenate([paths[:-1] + np.diff(paths, axis=0) * f for f in np.linspace(0, 1, 9)])
    assert hb.min_pair_distance(fine) >= 2 * rec.scenario.robots.radius
    assert not np.isnan(paths).any()


def test_joint_paths_keep_their_margins_and_never_hold_less(hb, rec):
    """Best responses over the shield's margins: every path keeps the floor from obstacles and the
    separation from the others at every step (and between steps the margins less the chord's
    sagitta), and the whole formation holds at least as often as the prioritised start."""
    k_s, k_end = 220, 262  # t = 110 .. 131: obstacle 5's face change and the leader's turn
    floor, sep = 0.33, 0.61
    start = hb.prioritised_paths(rec, k_s, k_end, 0.05, list(range(8)), (floor, sep))
    paths = hb.joint_paths(rec, k_s, k_end, 0.05, (floor, sep))
    assert paths.shape == (k_end - k_s + 1, 8, 2) and not np.isnan(paths).any()
    assert np.all(np.hypot(*np.diff(paths, axis=0).transpose(2, 0, 1)) <= 0.25 + 1e-9)
    assert rec.static.distance(paths[1:]).min() >= floor
    assert hb.min_pair_distance(paths[1:]) >= sep
    fine = np.concatenate([paths[1:-1] + np.diff(paths[1:], axis=0) * f for f in np.linspace(0, 1, 9)])
    assert rec.static.distance(fine).min() >= floor - 0.03
    assert hb.min_pair_distance(fine) >= sep - 0.06
    window = rec.slots[k_s : k_end + 1]
    held, _ = hb.hold_of(paths, window, 0.3)
    before, _ = hb.hold_of(start, window, 0.3)
    assert before <= held < 1.0  # the turn costs steps, with any plan
    with pytest.raises(ValueError, match="gain"):
        hb.point_dp(rec, 0, k_s, k_end, 0.05, relax=False, gain=np.zeros(k_end - k_s + 1, dtype=int))
