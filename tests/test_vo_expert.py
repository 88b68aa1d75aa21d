"""Tests for the pure-pursuit + velocity-obstacle expert (agents/vo_expert.py) and
the batched VO selection it runs on (swarm_env.control.vo.vo_select_batch).

The VO geometry itself (ray/disc entry times, polygon Minkowski sums, overlap
rules, arc trajectories) is tested in tests/test_guidance.py; here: the cone's
boundary, polygons the robot must thread between, the batch against the
single-robot function, pure pursuit's curvature with the expert's
feed-forward, and the whole policy in the physics on small hand-made scenarios.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from swarm_env.control.pursuit import pure_pursuit
from swarm_env.control.safety import period_margin
from swarm_env.control.vo import (
    VODiscs,
    VORobots,
    twist_trajectories,
    vo_discs_inside,
    vo_polygons_inside,
    vo_select,
    vo_select_batch,
)
from swarm_env.env import SwarmEnv
from swarm_env.geometry.static_map import StaticMap
from swarm_env.harness.episode import run_episode
from swarm_env.harness.policies import load_policy
from swarm_env.scenario import CircleObstacle, PolygonObstacle, RectangleObstacle
from swarm_env.scenarios.loader import load_scenario, scenario_from_dict
from swarm_env_agents.vo_expert import EXPERT_AVOIDANCE, LEGACY_SPEC, VOExpert, make_policy

DATA = Path(__file__).resolve().parent / "data"


# ------------------------------------------------------------------ the VO cone
def test_disc_cone_boundary_is_the_tangent_angle():
    # Disc of combined radius R at distance d straight ahead: the (untruncated) VO
    # is the cone of half-angle asin(R / d) around the line of sight.
    d, R = 4.0, 1.0
    half = math.asin(R / d)
    rel = np.array([[d, 0.0]])
    angles = np.array([0.0, 0.5 * half, 0.99 * half, 1.01 * half, 2.0 * half, math.pi / 2, math.pi])
    cand = np.column_stack([np.cos(angles), np.sin(angles)])
    inside = vo_discs_inside(rel, np.array([R]), cand, horizon=100.0)[:, 0]
    assert inside.tolist() == [True, True, True, False, False, False, False]
    # Symmetric below the line of sight.
    cand[:, 1] *= -1.0
    assert vo_discs_inside(rel, np.array([R]), cand, horizon=100.0)[:, 0].tolist() == inside.tolist()


def test_disc_cone_is_shifted_by_the_obstacle_velocity():
    # The same disc, moving away at 1 m/s: a robot velocity straight at it is only
    # inside if faster than the disc; one that matches it sideways is never inside.
    rel, R = np.array([[3.0, 0.0]]), np.array([0.6])
    disc_vel = np.array([1.0, 0.0])
    for speed, expected in [(0.5, False), (1.0, False), (1.5, True), (3.0, True)]:
        rel_vel = np.array([[speed, 0.0]]) - disc_vel
        assert vo_discs_inside(rel, R, rel_vel, horizon=10.0)[0, 0] == expected
    # truncation: at 1.2 m/s the relative speed is 0.2 m/s; the gap of 2.4 m closes at t = 12 s
    assert not vo_discs_inside(rel, R, np.array([[1.2, 0.0]]) - disc_vel, horizon=10.0)[0, 0]
    assert vo_discs_inside(rel, R, np.array([[1.2, 0.0]]) - disc_vel, horizon=13.0)[0, 0]


@pytest.fixture(scope="module")
def gap_map() -> StaticMap:
    # Two convex polygons leaving a 1.0 m wide vertical gap at x in [5, 6]:
    # a rectangle on the left, a triangle on the right whose vertex points into the gap.
    return StaticMap.from_obstacles(
        (12.0, 10.0),
        [
            RectangleObstacle(center=(4.0, 5.0), size=(2.0, 2.0)),  # x in [3, 5], y in [4, 6]
            PolygonObstacle(points=((6.0, 5.0), (8.0, 3.5), (8.0, 6.5))),  # vertex at (6, 5)
        ],
    )


def test_polygon_vo_threading_a_gap(gap_map):
    r = 0.25
    # Straight up the middle of the gap (x = 5.5): 0.5 m from both sides -> outside the VO.
    assert not vo_polygons_inside(np.array([5.5, 1.0]), r, np.array([[0.0, 1.0]]), gap_map, 7.0)[0]
    # Up the gap 0.2 m from the rectangle's face: inside (the swept disc touches it).
    assert vo_polygons_inside(np.array([5.2, 1.0]), r, np.array([[0.0, 1.0]]), gap_map, 7.0)[0]
    # 0.2 m beside the triangle's vertex (x = 5.8): inside (the vertex disc of the Minkowski sum).
    assert vo_polygons_inside(np.array([5.8, 1.0]), r, np.array([[0.0, 1.0]]), gap_map, 7.0)[0]


def test_vo_select_goes_through_the_gap_not_into_the_vertex(gap_map):
    pose = np.array([5.5, 2.0, math.pi / 2])  # below the gap, facing up it
    res = vo_select(pose, 0.25, np.array([0.65, 0.0]), np.zeros((0, 3)), np.zeros((0, 2)), gap_map, 0.65, 1.0)
    assert res.feasible
    np.testing.assert_allclose(res.twist, [0.65, 0.0])  # straight through is safe
    pose = np.array([5.9, 3.0, math.pi / 2])  # lined up with the triangle's vertex, 2 m below it
    res = vo_select(pose, 0.25, np.array([0.65, 0.0]), np.zeros((0, 3)), np.zeros((0, 2)), gap_map, 0.65, 1.0)
    assert res.feasible and not np.allclose(res.twist, [0.65, 0.0])
    times, pts = twist_trajectories(pose[2], res.twist[None], 1.0, 3.0)
    path = pose[:2] + pts[0]
    assert gap_map.distance(path).min() >= 0.25  # the chosen motion's knots keep clear


# ------------------------------------------------------------------ batch == single
def _random_world(rng: np.random.Generator, n: int, d_extra: int):
    poses = np.column_stack([rng.uniform(1.0, 11.0, (n, 2)), rng.uniform(-math.pi, math.pi, n)])
    others = rng.uniform(1.0, 11.0, (d_extra, 2))
    discs = np.vstack([np.column_stack([poses[:, :2], np.full(n, 0.25)]), np.column_stack([others, np.full(d_extra, 0.3)])])
    vel = rng.uniform(-0.5, 0.5, (n + d_extra, 2))
    pref = np.column_stack([rng.uniform(0.0, 0.65, n), rng.uniform(-1.0, 1.0, n)])
    mask = np.ones((n, n + d_extra), dtype=bool)
    mask[np.arange(n), np.arange(n)] = False
    recip = np.r_[np.ones(n, dtype=bool), np.zeros(d_extra, dtype=bool)]
    return poses, discs, vel, pref, mask, recip


@pytest.mark.parametrize("fast, grid", [(True, (7, 11)), (False, (7, 11)), (True, (3, 3))])
def test_batch_matches_single_robot_calls(gap_map, fast, grid):
    rng = np.random.default_rng(7)
    checked_grid = 0
    kw = {"n_v": grid[0], "n_w": grid[1], "fast": fast}
    for _ in range(12):
        n = int(rng.integers(2, 9))
        poses, discs, vel, pref, mask, recip = _random_world(rng, n, int(rng.integers(0, 4)))
        batch = vo_select_batch(VORobots(poses, 0.25, pref, 0.65, 1.0, velocity=vel[:n]),
                                VODiscs(discs, vel, mask, recip), gap_map, **kw)
        for i in range(n):
            single = vo_select(poses[i], 0.25, pref[i], discs[mask[i]], vel[mask[i]], gap_map, 0.65, 1.0,
                               reciprocal=recip[mask[i]], velocity=vel[i], **kw)
            np.testing.assert_allclose(batch.twist[i], single.twist, atol=1e-12)
            assert batch.feasible[i] == single.feasible
            checked_grid += not batch.fast[i]
            if not fast:
                assert batch.n_safe[i] == single.n_safe
            if not single.feasible:
                assert batch.min_time_to_collision[i] == pytest.approx(single.min_time_to_collision)
    assert checked_grid > 5  # the grid search (not only the fast path) was compared


def test_reciprocity_is_dropped_within_the_combined_radius():
    # A robot 0.5 m from a reciprocal neighbour (combined radius 0.55 with the margin)
    # still moving towards it at 0.3 m/s: the reciprocal displacement 2 x(t) - v t of
    # a slow forward twist (0.1 m/s) points away, but the move really closes the gap.
    pose = np.array([0.0, 0.0, 0.0])
    disc, disc_vel = np.array([[0.5, 0.0, 0.25]]), np.zeros((1, 2))
    res = vo_select(pose, 0.25, np.array([0.1, 0.0]), disc, disc_vel, None, 0.65, 1.0,
                    reciprocal=True, velocity=np.array([0.3, 0.0]))
    assert res.twist[0] == 0.0  # no forward motion into the neighbour
    # Out of the combined radius reciprocity applies as usual: the same slow twist is
    # safe 1.2 m away (the neighbour is assumed to take its half).
    res = vo_select(pose, 0.25, np.array([0.1, 0.0]), np.array([[1.2, 0.0, 0.25]]), disc_vel, None, 0.65, 1.0,
                    reciprocal=True, velocity=np.array([0.3, 0.0]))
    np.testing.assert_allclose(res.twist, [0.1, 0.0])


# ------------------------------------------------------------------ pure pursuit + feed-forward
def test_pure_pursuit_curvature_is_the_arc_through_the_target():
    # Simulate the commanded arc: it passes through the target (Eq. 4).
    pose = np.array([1.0, 1.0, 0.4])
    target = np.array([3.0, 2.5])
    v, w = pure_pursuit(pose, target, v_max=0.65, omega_max=10.0, time_gap=1.0)
    radius = v / w
    centre = pose[:2] + radius * np.array([-math.sin(pose[2]), math.cos(pose[2])])
    assert np.linalg.norm(target - centre) == pytest.approx(abs(radius))
    assert np.linalg.norm(pose[:2] - centre) == pytest.approx(abs(radius))


#: The tracking law alone: no preview, no look-ahead cap (the expert's defaults add both).
PLAIN = {"preview": 0.0, "lookahead": 0.0}


def _state_like(pose, slot, leader_pose, leader_vel, leader_omega):
    """A minimal stand-in for WorldState with what preferred_twists reads."""

    class S:
        pass

    s = S()
    s.follower_pose = np.atleast_2d(np.asarray(pose, float))
    s.slot_targets = np.atleast_2d(np.asarray(slot, float))
    s.leader_pose = np.asarray(leader_pose, float)
    s.leader_vel = np.asarray(leader_vel, float)
    s.leader_twist = np.array([np.hypot(*leader_vel), leader_omega])

    class Robots:
        max_speed, max_turn_rate = 0.65, 1.0

    class Scn:
        robots = Robots()

    s.scenario = Scn()
    return s


def test_feed_forward_tracks_a_moving_slot_without_lag():
    # Sitting on a slot that moves at 0.5 m/s straight ahead: with feed-forward the
    # robot keeps 0.5 m/s (no error needed); the plain law (Eq. 9) would stop.
    st = _state_like([5.0, 5.0, 0.0], [5.0, 5.0], [6.0, 5.0, 0.0], [0.5, 0.0], 0.0)
    np.testing.assert_allclose(VOExpert(**PLAIN).preferred_twists(st)[0], [0.5, 0.0], atol=1e-12)
    np.testing.assert_allclose(VOExpert(feed_forward=False, **PLAIN).preferred_twists(st)[0], [0.0, 0.0])
    # Rotating leader frame: the slot's velocity is v_L + omega x (slot - p_L). A slot 1 m
    # to the leader's left while the leader turns in place at 0.5 rad/s moves at 0.5 m/s to -x.
    st = _state_like([5.0, 6.0, math.pi], [5.0, 6.0], [5.0, 5.0, 0.0], [0.0, 0.0], 0.5)
    v, w = VOExpert(**PLAIN).preferred_twists(st)[0]
    assert v == pytest.approx(0.5) and w == pytest.approx(0.0, abs=1e-12)


def test_feed_forward_removes_the_steady_state_lag_in_simulation():
    # A unicycle chasing a point moving at 0.5 m/s along x, with the expert's tracking law.
    def lag(feed_forward: bool) -> float:
        pose = np.array([0.0, 0.0, 0.0])
        expert = VOExpert(feed_forward=feed_forward, **PLAIN)
        for k in range(300):
            slot = np.array([0.5 * k * 0.1, 0.0])
            st = _state_like(pose, slot, slot + [1.0, 0.0], [0.5, 0.0], 0.0)
            v, w = expert.preferred_twists(st)[0]
            pose = pose + 0.1 * np.array([v * math.cos(pose[2]), v * math.sin(pose[2]), w])
        return float(np.linalg.norm(pose[:2] - slot))

    assert lag(True) < 0.06  # one step's travel of the slot: nothing left but the sampling delay
    assert lag(False) > 0.15  # the plain law needs l / T = 0.5 m/s, i.e. l = 0.25 m behind the slot


def test_preview_steers_around_an_obstacle_the_slot_will_skirt():
    # A slot moving at 0.5 m/s along y = 5 towards a disc (radius 0.4) centred 0.2 m above the
    # line: the env moves the slot below it when it gets there. The plain law drives straight
    # at it (the VO has to stop or divert the robot); with preview the robot already bends
    # right (omega < 0), at the tracking law's speed, and within the turn-rate limit.
    st = _state_like([3.0, 5.0, 0.0], [3.0, 5.0], [4.0, 5.0, 0.0], [0.5, 0.0], 0.0)
    st.static = StaticMap.from_obstacles((12.0, 10.0), [CircleObstacle(center=(3.9, 5.2), radius=0.4)])
    st.scenario.robots.radius = 0.25
    plain = VOExpert(**PLAIN).preferred_twists(st)[0]
    np.testing.assert_allclose(plain, [0.5, 0.0], atol=1e-12)
    v, w = VOExpert(preview=1.0).preferred_twists(st)[0]
    assert w < -0.1 and abs(w) <= 1.0 and 0.0 < v <= 0.5 + 1e-12
    # Nothing in the way: preview changes nothing (the point ahead lies on the same line).
    st.static = StaticMap.from_obstacles((12.0, 10.0), [])
    np.testing.assert_allclose(VOExpert(preview=1.0).preferred_twists(st)[0], plain, atol=1e-12)


def test_lookahead_turns_towards_a_far_slot_before_driving_off():
    # A slot 3 m away, 80 degrees to the left, at rest: the plain law (Eq. 9/4 with l = 3 m) drives at full
    # speed on a wide arc (omega = 2 v sin(alpha) / l), away from the slot for seconds. Capping the pursued
    # point at v_max * lookahead from the robot turns it much harder; a slot within the cap is unchanged.
    alpha = math.radians(80.0)
    far = _state_like([0.0, 0.0, 0.0], [3.0 * math.cos(alpha), 3.0 * math.sin(alpha)], [9.0, 9.0, 0.0], [0.0, 0.0], 0.0)
    v0, w0 = VOExpert(**PLAIN).preferred_twists(far)[0]
    v1, w1 = VOExpert(preview=0.0, lookahead=0.875).preferred_twists(far)[0]
    assert v0 == pytest.approx(0.65) and w0 == pytest.approx(2 * 0.65 * math.sin(alpha) / 3.0)
    assert w1 == pytest.approx(1.0) and v1 < 0.5 * v0  # full turn rate, slowed to keep to the tighter arc
    near = _state_like([0.0, 0.0, 0.0], [0.3, 0.2], [9.0, 9.0, 0.0], [0.0, 0.0], 0.0)
    np.testing.assert_array_equal(VOExpert(**PLAIN).preferred_twists(near),
                                  VOExpert(preview=0.0, lookahead=0.875).preferred_twists(near))
    with pytest.raises(ValueError, match="lookahead"):
        VOExpert(lookahead=-1.0)


@pytest.mark.slow
def test_the_defaults_bend_round_at_speed_on_paper_vo_90():
    # paper_vo_90's followers each pass a disc that lies across their slot's track. The earlier expert
    # (LEGACY_SPEC) meets it head-on and the VO slows the follower down for metres (0.152 m mean error);
    # the defaults steer along the projected slot ahead (preview), cap the pursued point (lookahead) and
    # price a slow-down above a turn (w_speed), and keep the formation better than the ORCA reference
    # does on this episode (0.0468 m, docs/vo_expert.md). Each ingredient counts.
    errors = {}
    env = SwarmEnv("paper_vo_90")
    try:
        for name, spec in (("legacy", LEGACY_SPEC), ("defaults", "vo"), ("no preview", "vo:preview=0"),
                           ("w_speed 1", "vo:w_speed=1")):
            m = run_episode(env, load_policy(spec, env), 0)
            assert m["success"] and m["collisions"]["total"] == 0, name
            errors[name] = m["formation_error"]["mean"]
    finally:
        env.close()
    assert errors["legacy"] > 0.14 and errors["no preview"] > 0.1
    assert errors["defaults"] < min(errors["w_speed 1"], 0.0468)


# ------------------------------------------------------------------ the policy in the physics
def _scenario(**over):
    base = {
        "name": "test_vo",
        "world": {"size": [12.0, 8.0], "dt": 0.1, "substeps": 4, "max_time": 30.0, "settle_tolerance": 0.3},
        "robots": {"count": 2, "radius": 0.25, "max_speed": 0.65, "max_turn_rate": 1.0},
        # a virtual leader creeping 0.2 m in 20 s: the slots stay put and the episode lasts
        "leader": {"kind": "virtual", "path": [[6.0, 4.0], [6.2, 4.0]], "speed": 0.01},
        "formations": [{"at": 0.0, "shape": "custom", "offsets": [[3.0, 0.0], [-3.0, 0.0]]}],
    }
    base.update(over)
    return scenario_from_dict(base)


CROSSINGS = {
    # follower 0 from the west slot side to the east slot, follower 1 the other way round
    "head_on": [[3.0, 4.0, 0.0], [9.2, 4.0, math.pi]],
    # follower 1 comes from the south and crosses follower 0's path at right angles,
    # both 2 m from the crossing point (5, 4)
    "perpendicular": [[3.0, 4.0, 0.0], [5.0, 2.0, math.pi / 2]],
}


@pytest.mark.parametrize("case", sorted(CROSSINGS))
def test_two_robots_crossing_do_not_collide(case):
    offsets = [[3.0, 0.0], [-3.0, 0.0]] if case == "head_on" else [[3.0, 0.0], [-1.0, 3.0]]
    scn = _scenario(
        robots={"count": 2, "radius": 0.25, "max_speed": 0.65, "max_turn_rate": 1.0, "start": CROSSINGS[case]},
        formations=[{"at": 0.0, "shape": "custom", "offsets": offsets}],
    )
    env = SwarmEnv(scn)
    m = run_episode(env, VOExpert(), seed=0)
    assert m["collisions"]["total"] == 0
    assert m["min_separation"] > 0.0
    assert m["success"]  # both reached their slots (and nothing touched)


@pytest.mark.parametrize("from_side", [False, True])
def test_human_walking_straight_at_a_robot(from_side):
    # One follower parked on its slot; a human walks a straight line through it.
    path = [[5.5, 7.5], [5.5, 0.5]] if from_side else [[11.5, 4.0], [0.5, 4.0]]
    scn = _scenario(
        robots={"count": 1, "radius": 0.25, "max_speed": 0.65, "max_turn_rate": 1.0},
        formations=[{"at": 0.0, "shape": "custom", "offsets": [[-0.5, 0.0]]}],
        humans=[{"path": path, "speed": 0.5, "radius": 0.3, "mode": "once"}],
        world={"size": [12.0, 8.0], "dt": 0.1, "substeps": 4, "max_time": 25.0, "settle_tolerance": 0.3},
    )
    env = SwarmEnv(scn)
    policy = VOExpert()
    m = run_episode(env, policy, seed=0)
    assert m["collisions"]["total"] == 0
    assert m["min_clearance"] > 0.0


def test_policy_keeps_clear_of_a_polygon_between_robot_and_slot():
    scn = _scenario(
        robots={"count": 1, "radius": 0.25, "max_speed": 0.65, "max_turn_rate": 1.0, "start": [[2.0, 4.0, 0.0]]},
        formations=[{"at": 0.0, "shape": "custom", "offsets": [[3.0, 0.0]]}],  # slot at (9, 4)
        obstacles=[{"type": "polygon", "points": [[5.0, 3.0], [6.5, 4.0], [5.0, 5.2]]}],
    )
    m = run_episode(SwarmEnv(scn), VOExpert(), seed=0)
    assert m["collisions"]["total"] == 0
    assert m["min_clearance"] > 0.0


# ------------------------------------------------------------------ registry, telemetry, determinism
def test_registry_and_policy_stats():
    env = SwarmEnv("paper_vo_45", max_cycles=40)
    policy = load_policy("vo", env)
    assert isinstance(policy, VOExpert)
    tuned = load_policy("vo:horizon=4,margin=0.1,reciprocal=false", env)
    assert (tuned.horizon, tuned.margin, tuned.reciprocal) == (4.0, 0.1, False)
    with pytest.raises(ValueError, match="unknown parameter"):
        load_policy("vo:nope=1", env)
    m = run_episode(env, policy, seed=0)
    stats = m["policy_stats"]
    assert stats["decision_time_ms"]["calls"] == m["steps"] == 40
    assert 0.0 < stats["decision_time_ms"]["median"] <= stats["decision_time_ms"]["p95"] <= stats["decision_time_ms"]["max"]
    assert stats["infeasible_events"] >= 0 and stats["escape_turns"] >= 0
    for action in policy.act({a: None for a in env.possible_agents}, env.world_state()).values():
        assert action.dtype == np.float32 and action.shape == (2,) and np.all(np.abs(action) <= 1.0)


@pytest.mark.slow
def test_a_boxed_in_follower_backs_off_from_a_human():
    """Random world 31 with the humans looked for no further than the robots (``human_horizon=0``):
    follower 1 stands inside follower 2's margin while the human walks at it, so no forward or
    standing twist is safe. Turning in place (``reverse=0``), the human walks into it; with the
    ``reverse`` fallback (on by default) it backs off, and the episode ends without a contact. The expert's default
    ``human_horizon`` (3.5 s) sees the human coming early enough to keep out of that corner."""
    results = {}
    for spec in ("vo:human_horizon=0,reverse=0", "vo:human_horizon=0", "vo:human_horizon=0,reverse_horizon=0", "vo"):
        env = SwarmEnv("random")
        results[spec] = run_episode(env, load_policy(spec, env), seed=31)
    short, backs_off, robots_far, default = results.values()
    assert short["collisions"]["robot_human"] == 1 and short["policy_stats"]["reverse_steps"] == 0
    assert backs_off["collisions"]["total"] == 0 and backs_off["success"]
    assert backs_off["policy_stats"]["reverse_steps"] > 0
    # Backing off while every neighbour is looked for its full 2.5 s (reverse_horizon=0) finds no room.
    assert robots_far["collisions"]["robot_human"] == 1
    assert default["collisions"]["total"] == 0 and default["success"]
    # Worlds without humans never back off: the same episode as without the fallback.
    env = SwarmEnv("paper_vo_45", max_cycles=60)
    plain = run_episode(env, load_policy("vo:reverse=0", env), seed=0)
    on = run_episode(env, load_policy("vo", env), seed=0)
    assert plain["formation_error"] == on["formation_error"] and on["policy_stats"]["reverse_steps"] == 0


@pytest.mark.slow
def test_a_follower_backs_off_from_a_walker_who_keeps_coming():
    """``crowd_reactive`` training world 45 (social-force walkers): without the fallback (``reverse=0``) a
    follower with no safe twist turns in place and a walker walks into it; by default it backs off (its
    robot neighbours looked for only ``reverse_horizon`` ahead: they give way) and the episode has no contact."""
    results = {}
    for spec in ("vo:reverse=0", "vo"):
        env = SwarmEnv("random:crowd_reactive")
        results[spec] = run_episode(env, load_policy(spec, env), seed=45)
    turning, default = results.values()
    assert turning["collisions"]["robot_human"] >= 1 and turning["policy_stats"]["reverse_steps"] == 0
    assert default["collisions"]["total"] == 0 and default["policy_stats"]["reverse_steps"] > 0


def test_followers_keep_room_for_a_neighbour_that_stops_within_a_long_control_period() -> None:
    """A map with a formation switch every 12-14 s and a control period of 0.2 s (``benchmarks/switch_maps.py --dt
    0.2 --prefix b``, map 6): 2 s after a v -> line switch two followers crossing to their new slots travel a few cm
    apart, one finds no safe twist and stops, and the other, which trusted its velocity for the whole period,
    runs into it (``period_margin=0``, the expert before). By default the other followers' discs grow by
    ``max_speed * (dt - 0.1)`` = 0.065 m in the search, and nobody touches. At dt <= 0.1 s nothing grows."""
    results = {}
    for spec in ("vo:period_margin=0", "vo"):
        env = SwarmEnv(load_scenario(DATA / "switch_map_dt02.yaml"), max_cycles=125)
        results[spec] = run_episode(env, load_policy(spec, env), seed=0)
    before, default = results.values()
    assert before["collisions"]["robot_robot"] == 1
    assert default["collisions"]["total"] == 0
    assert period_margin(0.65, 0.2, 0.1) == pytest.approx(0.065)
    assert period_margin(0.65, 0.1, 0.1) == 0.0 and period_margin(0.65, 0.05, 0.1) == 0.0
    assert period_margin(0.65, 0.5, 0.1) == 0.1  # paper_cbs_switch: capped
    expert = VOExpert()
    env = SwarmEnv("paper_vo_45", max_cycles=2)
    env.reset(seed=0)
    assert expert._params(env.world_state()) is expert.avoidance  # dt = 0.1 s: the same search, bit for bit
    with pytest.raises(ValueError, match="period_margin"):
        VOExpert(period_margin=-0.1)
    with pytest.raises(ValueError, match="robot_margin"):
        VOExpert(robot_margin=float("nan"))


def test_discrete_action_space_is_refused_clearly():
    env = SwarmEnv("paper_vo_0", action_type="discrete")
    with pytest.raises(ValueError, match="continuous"):
        make_policy(env, None)
    with pytest.raises(ValueError, match="continuous"):
        VOExpert().reset(env, 0)


def test_invalid_parameters():
    for bad in ({"time_gap": 0.0}, {"horizon": -1.0}, {"margin": -0.1}, {"n_v": 0}, {"preview": -1.0},
                {"preview": float("nan")}, {"reverse": -0.1}, {"reverse": 1.5}, {"reverse_horizon": -1.0},
                {"reverse_horizon": float("inf")}):
        with pytest.raises(ValueError):
            VOExpert(**bad)


def test_same_seed_same_actions():
    def actions(seed: int) -> list[np.ndarray]:
        env = SwarmEnv("random", n_followers=5, n_humans=2, max_cycles=120)
        policy = VOExpert()
        obs, _ = env.reset(seed=seed)
        policy.reset(env, seed)
        out = []
        while env.agents:
            act = policy.act(obs, env.world_state())
            out.append(np.stack([act[a] for a in sorted(act)]))
            obs, *_ = env.step(act)
        return out

    a, b = actions(3), actions(3)
    assert len(a) == len(b) == 120
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)
    assert any(not np.array_equal(x, y) for x, y in zip(a, actions(4)))


def test_one_parameter_object_for_the_search():
    """vo_select, vo_select_batch, the safety layer, VOExpert and the robot leader share VOParams."""
    from swarm_env.control.safety import AvoidanceParams
    from swarm_env.control.vo import VOParams
    from swarm_env.sim.world import LEADER_VO

    assert isinstance(AvoidanceParams(), VOParams) and LEADER_VO == VOParams()
    env = SwarmEnv("paper_vo_0")
    expert = load_policy("vo:horizon=4,model=chord,human_margin=0.1", env)
    assert expert.avoidance == AvoidanceParams(**{**EXPERT_AVOIDANCE, "horizon": 4.0, "model": "chord", "human_margin": 0.1})
    # The expert's own defaults (on top of the shared ones, which the safety layer keeps) and their opt-out.
    assert EXPERT_AVOIDANCE == {"move_first": True, "recip_gap": 0.2, "horizon": 2.5, "horizon_static": 1.0,
                                "tau": 0.7, "w_speed": 3.0, "escape_commit": 1.0, "human_horizon": 3.5}
    assert VOExpert.policy_parameters()["move_first"] is True and AvoidanceParams().move_first is False
    assert VOExpert.policy_parameters()["human_horizon"] == 3.5 and AvoidanceParams().human_horizon == 0.0
    # LEGACY_SPEC (the shipped residual_vo runs' expert) is the shared defaults without preview or look-ahead cap
    # (horizon_static = horizon is what None means).
    legacy = load_policy(LEGACY_SPEC, env)
    assert replace(legacy.avoidance, horizon_static=None) == AvoidanceParams()
    assert legacy.avoidance.horizon_static == legacy.avoidance.horizon and legacy.preview == legacy.lookahead == 0.0
    with pytest.raises(ValueError, match="cost"):
        VOParams(cost="nope")
    with pytest.raises(ValueError, match="recip_gap"):
        VOParams(recip_gap=-0.1)
    assert expert.horizon == 4.0 and set(AvoidanceParams.names()) <= set(VOExpert.policy_parameters())
    with pytest.raises(ValueError, match="unknown parameter 'speed'"):
        load_policy("vo:speed=2", env)
    with pytest.raises(TypeError, match="unknown parameter"):
        VOExpert(speed=2.0)
    with pytest.raises(ValueError, match="model"):
        VOParams(model="nope")
    pose = np.array([0.0, 0.0, 0.0])
    empty = (np.zeros((0, 3)), np.zeros((0, 2)), None, 0.65, 1.0)
    with pytest.raises(TypeError, match="unknown VO parameter"):
        vo_select(pose, 0.25, np.array([0.5, 0.0]), *empty, speed=1.0)
    # A params object and the same values as keyword overrides give the same answer.
    a = vo_select(pose, 0.25, np.array([0.5, 0.2]), *empty, VOParams(n_v=5, fast=False))
    b = vo_select(pose, 0.25, np.array([0.5, 0.2]), *empty, n_v=5, fast=False)
    assert np.array_equal(a.twist, b.twist) and a.n_safe == b.n_safe


def test_escape_drive_drives_on_instead_of_turning_back() -> None:
    """``escape_drive``: a follower turning in place one way whose target is behind it gets a straight drive at
    the pursuit's speed as its preferred twist, not the full turn back; turning the same way, or standing, it
    keeps the full turn."""
    env = SwarmEnv("random:crowd_reactive")
    env.reset(seed=33)
    state = env.world_state()
    expert = VOExpert()
    pose = state.follower_pose.copy()
    target = state.slot_targets.copy()
    target[0] = pose[0, :2] + (2.0, 1.0)  # 2.2 m away (at reset every follower stands on its slot)
    # follower 0 faces away from its target (behind it) while turning in place to the left
    d = target[0] - pose[0, :2]
    pose[0, 2] = math.atan2(d[1], d[0]) + math.pi - 0.3  # the target 0.3 rad short of dead astern, on the right
    omega_max = state.scenario.robots.max_turn_rate
    for turning, expect_drive in ((+0.5 * omega_max, True), (-0.5 * omega_max, False), (0.0, False)):
        twist = np.zeros((state.n_followers, 2))
        twist[0] = 0.0, -omega_max  # the full turn (towards the target, to the right)
        current = state.follower_twist.copy()
        current[0] = 0.0, turning
        s = replace(state, follower_pose=pose, follower_twist=current)
        out = expert._drive_on(s, target, twist, 0.65, omega_max)
        if expect_drive:
            dist = float(np.hypot(*(target[0] - pose[0, :2])))
            assert out[0, 1] == 0.0 and out[0, 0] == pytest.approx(min(dist / expert.time_gap, 0.65))
        else:
            assert np.array_equal(out[0], twist[0])
        assert np.array_equal(out[1:], twist[1:])
    assert np.array_equal(VOExpert(escape_drive=False)._drive_on(s, target, twist, 0.65, omega_max), twist)


@pytest.mark.slow
def test_escape_drive_ends_the_turn_left_turn_right_standstill() -> None:
    """``crowd_reactive`` training world 33: without ``escape_drive`` a follower stands for the rest of the episode,
    the full turn towards its slot and the escape turn towards open space taking turns; with it, it settles."""
    results = {}
    for spec in ("vo", "vo:escape_drive=false"):
        env = SwarmEnv("random:crowd_reactive")
        results[spec] = run_episode(env, load_policy(spec, env), 33)
    assert results["vo"]["success"] and results["vo"]["collisions"]["total"] == 0
    assert not results["vo:escape_drive=false"]["success"]
