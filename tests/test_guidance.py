"""Tests for swarm_env.control.pursuit and swarm_env.control.vo: pure pursuit and velocity-obstacle geometry."""

from __future__ import annotations

import math

import numpy as np
import pytest

from swarm_env.control.pursuit import lookahead_target, pure_pursuit, wrap_angle
from swarm_env.control.vo import (
    VODiscs,
    VOParams,
    VORobots,
    disc_time_to_collision,
    sample_twists,
    static_time_to_collision,
    trajectory_disc_ttc,
    twist_trajectories,
    twist_velocities,
    vo_discs_inside,
    vo_polygons_inside,
    vo_select,
    vo_select_batch,
)
from swarm_env.geometry.paths import PolylinePath
from swarm_env.geometry.static_map import StaticMap
from swarm_env.scenario import CircleObstacle, PolygonObstacle, RectangleObstacle

EMPTY_D = np.zeros((0, 3))
EMPTY_V = np.zeros((0, 2))


def unicycle_step(pose: np.ndarray, twist: np.ndarray, dt: float) -> np.ndarray:
    """Exact arc integration of a unicycle (the test's own simulator)."""
    x, y, th = pose
    v, w = twist
    if abs(w) < 1e-12:
        return np.array([x + v * dt * math.cos(th), y + v * dt * math.sin(th), th])
    th2 = th + w * dt
    return np.array([x + v / w * (math.sin(th2) - math.sin(th)), y - v / w * (math.cos(th2) - math.cos(th)), th2])


# ------------------------------------------------------------------ angles, pure pursuit
def test_wrap_angle():
    a = np.array([0.0, math.pi, -math.pi, 3 * math.pi / 2, -7.0, 20.0])
    w = wrap_angle(a)
    assert np.all(w >= -math.pi) and np.all(w < math.pi)
    np.testing.assert_allclose(np.cos(w), np.cos(a), atol=1e-12)
    np.testing.assert_allclose(np.sin(w), np.sin(a), atol=1e-12)
    assert wrap_angle(math.pi) == pytest.approx(-math.pi)
    assert isinstance(wrap_angle(1.0), float) and isinstance(wrap_angle(np.float64(4.0)), float)


def test_pure_pursuit_curvature_eq4():
    pose = np.array([1.0, 2.0, 0.3])
    for alpha, dist in [(0.2, 2.0), (-0.6, 3.0), (1.2, 5.0), (0.0, 1.0)]:
        target = pose[:2] + dist * np.array([math.cos(pose[2] + alpha), math.sin(pose[2] + alpha)])
        v, w = pure_pursuit(pose, target, v_max=0.5, omega_max=10.0, time_gap=1.0)
        assert v == pytest.approx(min(dist / 1.0, 0.5))  # Eq. 9 saturated by v_max
        assert w / v == pytest.approx(2 * math.sin(alpha) / dist)  # Eq. 4
    # close targets: v = l / time_gap
    v, w = pure_pursuit(pose, pose[:2] + [0.1, 0.0], v_max=0.5, omega_max=10.0, time_gap=0.5)
    assert v == pytest.approx(0.2)


def test_pure_pursuit_saturation():
    pose = np.array([0.0, 0.0, 0.0])
    target = np.array([0.5 * math.cos(1.0), 0.5 * math.sin(1.0)])  # alpha = 1 rad, l = 0.5
    v, w = pure_pursuit(pose, target, v_max=1.0, omega_max=0.5, time_gap=0.1)
    assert w == pytest.approx(0.5)
    assert w / v == pytest.approx(2 * math.sin(1.0) / 0.5)  # curvature kept: slowed down
    v2, w2 = pure_pursuit(pose, target, v_max=1.0, omega_max=0.5, time_gap=0.1, keep_curvature=False)
    assert (v2, w2) == pytest.approx((1.0, 0.5))
    v3, w3 = pure_pursuit(pose, -target, v_max=1.0, omega_max=0.5, time_gap=0.1)  # behind
    assert v3 == 0.0 and abs(w3) == pytest.approx(0.5)


def test_pure_pursuit_behind_turns_in_place_towards_target():
    pose = np.array([0.0, 0.0, 0.0])
    v, w = pure_pursuit(pose, np.array([-1.0, 0.5]), 0.5, 1.0, 1.0)  # behind-left
    assert v == 0.0 and w > 0
    v, w = pure_pursuit(pose, np.array([-1.0, -0.5]), 0.5, 1.0, 1.0)  # behind-right
    assert v == 0.0 and w < 0
    np.testing.assert_array_equal(pure_pursuit(pose, np.array([0.0, 0.0]), 0.5, 1.0, 1.0), [0.0, 0.0])


def test_pure_pursuit_vectorised_matches_rows():
    rng = np.random.default_rng(0)
    poses = np.column_stack([rng.uniform(-3, 3, (20, 2)), rng.uniform(-4, 4, 20)])
    targets = rng.uniform(-3, 3, (20, 2))
    out = pure_pursuit(poses, targets, 0.65, 1.0, 0.5)
    assert out.shape == (20, 2)
    for i in range(20):
        np.testing.assert_allclose(out[i], pure_pursuit(poses[i], targets[i], 0.65, 1.0, 0.5))
    assert np.all(np.abs(out[:, 1]) <= 1.0 + 1e-12) and np.all(out[:, 0] <= 0.65 + 1e-12)


def test_pure_pursuit_reaches_a_target_behind():
    pose = np.array([0.0, 0.0, 0.0])
    target = np.array([-2.0, 1.0])
    for _ in range(400):
        pose = unicycle_step(pose, pure_pursuit(pose, target, 0.65, 1.0, 1.0), 0.1)
    assert np.linalg.norm(pose[:2] - target) < 0.05


def test_lookahead_target_monotone_progress():
    path = PolylinePath([(0, 0), (10, 0), (10, 10)])
    carrot, s = lookahead_target(path, np.array([2.0, 0.5]), 0.0, 1.0)
    assert s == pytest.approx(2.0)
    np.testing.assert_allclose(carrot, [3.0, 0.0])
    carrot, s2 = lookahead_target(path, np.array([1.0, 0.0]), s, 1.0)  # robot fell behind
    assert s2 == pytest.approx(2.0)  # progress never decreases
    carrot, s3 = lookahead_target(path, np.array([9.8, 0.1]), 9.0, 1.0)
    np.testing.assert_allclose(carrot, [10.0, 0.8])  # around the corner
    carrot, s4 = lookahead_target(path, np.array([10.0, 9.9]), 19.0, 1.0)
    np.testing.assert_allclose(carrot, [10.0, 10.0])  # clipped to the end
    # a far-away part of the path is not short-cut thanks to the window
    _, s5 = lookahead_target(path, np.array([10.0, 0.0]) + [0.0, 9.0], 0.0, 1.0)
    assert s5 <= 3.0


# ------------------------------------------------------------------ sampling
def test_sample_twists_and_velocities():
    tw = sample_twists(0.65, 1.0)
    assert tw.shape == (77, 2)
    assert np.any(np.all(tw == 0.0, axis=1))
    assert tw[:, 0].min() == 0.0 and tw[:, 0].max() == pytest.approx(0.65)
    assert tw[:, 1].min() == pytest.approx(-1.0) and tw[:, 1].max() == pytest.approx(1.0)
    assert np.any(np.all(sample_twists(0.5, 1.0, n_v=4, n_w=4) == 0.0, axis=1))  # 0 added
    theta, tau = 0.4, 0.5
    vel = twist_velocities(theta, tw, tau)
    for (v, w), mean in zip(tw, vel):
        end = unicycle_step(np.array([0.0, 0.0, theta]), (v, w), tau)
        np.testing.assert_allclose(mean, end[:2] / tau, atol=1e-12)


def test_twist_trajectories_follow_the_unicycle():
    tw = sample_twists(0.65, 1.0)
    times, pts = twist_trajectories(0.7, tw, 1.0, 3.0, n_arc=2)
    np.testing.assert_allclose(times, [0.0, 0.5, 1.0, 3.0])
    assert pts.shape == (77, 4, 2)
    for c, (v, w) in enumerate(tw):
        p = np.array([0.0, 0.0, 0.7])
        for k, t in enumerate(times[1:3], start=1):  # the arc part
            np.testing.assert_allclose(pts[c, k], unicycle_step(p, (v, w), t)[:2], atol=1e-12)
        end_arc = unicycle_step(p, (v, w), 1.0)  # then straight on with the heading reached
        straight = end_arc[:2] + 2.0 * v * np.array([math.cos(end_arc[2]), math.sin(end_arc[2])])
        np.testing.assert_allclose(pts[c, 3], straight, atol=1e-12)


def test_preferred_row_matches_vectorised_trajectories():
    from swarm_env.control.vo import _trajectory_row

    for v, w, theta in [(0.5, 0.0, 0.3), (0.65, -1.0, -2.0), (0.0, 0.7, 1.0), (0.2, 1e-14, 0.0)]:
        _, pts = twist_trajectories(theta, np.array([[v, w]]), 1.0, 3.0, 2)
        np.testing.assert_allclose(_trajectory_row(v, w, 1.0, 3.0, 2, theta), pts[0], atol=1e-12)
    _, pts = twist_trajectories(0.4, np.array([[0.5, 0.5]]), 3.0, 2.0, 3)  # horizon <= tau: arc only
    np.testing.assert_allclose(_trajectory_row(0.5, 0.5, 3.0, 2.0, 3, 0.4), pts[0], atol=1e-12)


def test_trajectory_disc_ttc_matches_brute_force_and_reciprocity():
    times, pts = twist_trajectories(0.0, sample_twists(0.65, 1.0, n_v=3, n_w=5), 1.0, 3.0)
    rel = np.array([[1.5, 0.3], [0.5, -1.5], [-1.0, 0.0]])
    R = np.array([0.55, 0.6, 0.55])
    dv = np.array([[-0.4, 0.0], [0.0, 0.5], [0.3, 0.0]])
    ttc = trajectory_disc_ttc(times, pts, rel, R, dv)
    t = np.linspace(0.0, 3.0, 3001)
    for c in range(pts.shape[0]):
        robot = np.stack([np.interp(t, times, pts[c, :, 0]), np.interp(t, times, pts[c, :, 1])], axis=1)
        for d in range(3):
            gap = np.linalg.norm(rel[d] + dv[d] * t[:, None] - robot, axis=1) - R[d]
            hit = np.nonzero(gap < 0)[0]
            if len(hit):
                assert ttc[c, d] == pytest.approx(t[hit[0]], abs=2e-3)
            else:
                assert np.isinf(ttc[c, d]) or gap.min() < 1e-3
    # reciprocal: the displacement against a marked disc is 2 x(t) - v_now t
    own = np.array([0.3, 0.1])
    rec = trajectory_disc_ttc(times, pts, rel, R, dv, np.array([True, False, True]), own)
    pts2 = 2.0 * pts - own * times[None, :, None]
    np.testing.assert_allclose(rec[:, [0, 2]], trajectory_disc_ttc(times, pts2, rel, R, dv)[:, [0, 2]])
    np.testing.assert_allclose(rec[:, 1], ttc[:, 1])


# ------------------------------------------------------------------ VO: discs
def test_disc_vo_basic_cases():
    rel_pos = np.array([[5.0, 0.0]])
    R = np.array([1.0])
    cand = np.array(
        [
            [1.0, 0.0],  # straight at it: collides at t = 4
            [0.0, 1.0],  # parallel, far: misses
            [-1.0, 0.0],  # moving away
            [0.5, 0.0],  # straight at it but collides at t = 8 > horizon
            [1.0, 0.25],  # misses by more than... no: grazes inside (distance 5 sin(atan .25) = 1.21 > 1)
        ]
    )
    inside = vo_discs_inside(rel_pos, R, cand, horizon=5.0)
    assert inside[:, 0].tolist() == [True, False, False, False, False]
    ttc = disc_time_to_collision(rel_pos, R, cand, 5.0)
    assert ttc[0, 0] == pytest.approx(4.0)
    assert np.isinf(ttc[1:, 0]).all()


def test_disc_vo_with_obstacle_velocity_and_overlap():
    # Obstacle ahead coming towards a standing robot: rel_vel = 0 - (-1, 0)
    rel = np.array([[3.0, 0.0]])
    assert vo_discs_inside(rel, np.array([1.0]), np.array([[[1.0, 0.0]]]), 3.0)[0, 0]
    # same, but the robot runs away at the obstacle's speed: never closes
    assert not vo_discs_inside(rel, np.array([1.0]), np.array([[[0.0, 0.0]]]), 3.0)[0, 0]
    # overlapping: inside unless separating
    ov = np.array([[0.5, 0.0]])
    cand = np.array([[1.0, 0.0], [0.0, 0.0], [-0.2, 0.0], [0.0, 1.0]])
    assert vo_discs_inside(ov, np.array([1.0]), cand, 3.0)[:, 0].tolist() == [True, True, False, False]


def test_disc_ttc_matches_brute_force():
    rng = np.random.default_rng(1)
    rel = rng.uniform(-4, 4, (12, 2))
    R = rng.uniform(0.3, 1.2, 12)
    w = rng.uniform(-2, 2, (30, 12, 2))
    ttc = disc_time_to_collision(rel, R, w, 3.0)
    t = np.linspace(0.0, 3.0, 6001)
    for c in range(30):
        for d in range(12):
            gap = np.linalg.norm(w[c, d] * t[:, None] - rel[d], axis=1) - R[d]
            hit = np.nonzero(gap < 0.0)[0]
            if len(hit) == 0:
                assert np.isinf(ttc[c, d]) or ttc[c, d] > 3.0 - 1e-3 or gap.min() > -1e-3
            else:
                assert ttc[c, d] == pytest.approx(t[hit[0]], abs=1e-3)
    # (C, 2) candidate velocities broadcast to every disc
    np.testing.assert_array_equal(
        disc_time_to_collision(rel, R, w[:, 0], 3.0),
        disc_time_to_collision(rel, R, np.repeat(w[:, :1], 12, axis=1), 3.0),
    )


# ------------------------------------------------------------------ VO: static geometry
@pytest.fixture(scope="module")
def static_map() -> StaticMap:
    return StaticMap.from_obstacles(
        (20.0, 12.0),
        [
            RectangleObstacle(center=(10.0, 6.0), size=(2.0, 4.0)),  # x in [9, 11], y in [4, 8]
            RectangleObstacle(center=(4.0, 9.0), size=(2.0, 1.0), angle=30.0),
            CircleObstacle(center=(15.0, 3.0), radius=1.0),
            PolygonObstacle(points=((16.0, 8.0), (18.0, 8.5), (17.0, 10.5))),
        ],
    )


def test_polygon_vo_rectangle(static_map):
    P = np.array([7.0, 6.0])
    r = 0.3
    cand = np.array(
        [
            [1.0, 0.0],  # into the face: gap 2 - 0.3 = 1.7 m -> t = 1.7 s
            [0.5, 0.0],  # t = 3.4 s > horizon
            [0.0, 1.0],  # parallel to the face 2 m away
            [-1.0, 0.0],  # away
            [1.0, 1.0],  # towards the upper corner (9, 8): passes... through its vertex disc
        ]
    )
    inside = vo_polygons_inside(P, r, cand, static_map, 3.0)
    assert inside.tolist() == [True, False, False, False, True]
    ttc = static_time_to_collision(P, r, cand, static_map, 3.0)
    assert ttc[0] == pytest.approx(1.7)
    # parallel to the face at a distance slightly above the radius: outside
    P2 = np.array([8.6, 1.0])  # 0.4 m left of the face x = 9
    assert not vo_polygons_inside(P2, r, np.array([[0.0, 1.0]]), static_map, 10.0)[0]
    # ... and slightly below: inside (the swept disc touches the face)
    P3 = np.array([8.8, 1.0])
    assert vo_polygons_inside(P3, r, np.array([[0.0, 1.0]]), static_map, 10.0)[0]


def test_polygon_vo_is_not_a_bounding_circle(static_map):
    # Gliding 0.5 m above the rectangle's top face (y = 8) with radius 0.3: clear of
    # it, although the path crosses the rectangle's bounding circle (centre (10, 6),
    # radius sqrt(5)) inflated by the radius.
    P = np.array([6.0, 8.5])
    v = np.array([[1.0, 0.0]])
    assert not vo_polygons_inside(P, 0.3, v, static_map, 6.0)[0]  # (the triangle is 9.9 s away)
    assert np.linalg.norm(P + v[0] * 4.0 - [10.0, 6.0]) < math.sqrt(5) + 0.3
    # a little lower (0.25 m above the face) it is inside
    assert vo_polygons_inside(np.array([6.0, 8.25]), 0.3, v, static_map, 6.0)[0]


def test_static_ttc_matches_brute_force(static_map):
    rng = np.random.default_rng(2)
    r = 0.3
    t = np.linspace(0.0, 4.0, 4001)
    n_checked = 0
    for _ in range(60):
        P = rng.uniform([0.5, 0.5], [19.5, 11.5])
        if static_map.distance(P[None])[0] < r + 1e-3:
            continue
        V = rng.uniform(-2.0, 2.0, (8, 2))
        ttc = static_time_to_collision(P, r, V, static_map, 4.0)
        for c in range(8):
            path = P + V[c] * t[:, None]
            gap = static_map.distance(path) - r
            hit = np.nonzero(gap < 0.0)[0]
            if len(hit):
                assert ttc[c] == pytest.approx(t[hit[0]], abs=2e-3)
                n_checked += 1
            else:
                assert np.isinf(ttc[c]) or gap.min() < 1e-2
    assert n_checked > 30  # the test exercised real collisions


def test_static_overlap_rule(static_map):
    # Robot touching the rectangle's left face (centre 0.2 m from it, radius 0.3)
    P = np.array([8.8, 6.0])
    cand = np.array([[1.0, 0.0], [0.0, 0.0], [-0.5, 0.0], [0.0, 0.5]])
    inside = vo_polygons_inside(P, 0.3, cand, static_map, 3.0)
    assert inside.tolist() == [True, True, False, True]  # only leaving is allowed
    # Overlapping the bottom wall
    Pw = np.array([3.0, 0.2])
    inside = vo_polygons_inside(Pw, 0.3, np.array([[0.0, 0.5], [0.0, -0.5], [1.0, 0.0]]), static_map, 3.0)
    assert inside.tolist() == [False, True, True]


# ------------------------------------------------------------------ vo_select
def test_vo_select_free_returns_preferred(static_map):
    pose = np.array([2.0, 2.0, 0.3])
    pref = np.array([0.41, 0.13])  # off the sampling grid
    res = vo_select(pose, 0.25, pref, EMPTY_D, EMPTY_V, static_map, 0.65, 1.0, fast=False)
    assert res.feasible and res.n_safe == 78  # 77 grid twists + the preferred one
    np.testing.assert_allclose(res.twist, pref)
    assert res.min_time_to_collision == math.inf
    for st in (static_map, None):  # fast path: same answer
        res = vo_select(pose, 0.25, pref, EMPTY_D, EMPTY_V, st, 0.65, 1.0)
        np.testing.assert_allclose(res.twist, pref)
        assert res.feasible
    # out-of-limit preferences are clipped
    res = vo_select(pose, 0.25, np.array([2.0, -3.0]), EMPTY_D, EMPTY_V, None, 0.65, 1.0)
    np.testing.assert_allclose(res.twist, [0.65, -1.0])


def test_vo_select_deviates_from_disc_ahead():
    pose = np.array([0.0, 0.0, 0.0])
    disc = np.array([[2.0, 0.0, 0.3]])
    res = vo_select(pose, 0.25, np.array([0.65, 0.0]), disc, np.zeros((1, 2)), None, 0.65, 1.0)
    assert res.feasible
    assert not np.allclose(res.twist, [0.65, 0.0])
    vel = twist_velocities(0.0, res.twist[None], 0.5)
    rel = disc[:, :2] - pose[:2]
    assert not vo_discs_inside(rel, np.array([0.3 + 0.25 + 0.05]), vel, 3.0)[0, 0]


def test_vo_select_infeasible_never_raises():
    pose = np.array([5.0, 5.0, 0.0])
    # surrounded by overlapping discs approaching from every side
    ang = np.linspace(0, 2 * math.pi, 12, endpoint=False)
    ring = np.column_stack([5 + 0.6 * np.cos(ang), 5 + 0.6 * np.sin(ang), np.full(12, 0.3)])
    vel = -0.5 * np.column_stack([np.cos(ang), np.sin(ang)])
    res = vo_select(pose, 0.25, np.array([0.5, 0.0]), ring, vel, None, 0.65, 1.0)
    assert not res.feasible and res.n_safe == 0
    assert res.min_time_to_collision <= 3.0
    assert res.twist.shape == (2,) and np.all(np.isfinite(res.twist))
    assert res.twist[0] == 0.0  # nothing helps: at least do not drive into it


def test_vo_select_escape_turns_towards_open_space(static_map):
    # Facing the rectangle's left face from 0.45 m (centre to face), goal behind it:
    # every forward twist is unsafe, standing is safe. Rather than stand still
    # forever the robot turns in place (towards the open side).
    pose = np.array([8.55, 6.5, 0.0])
    pref = np.array([0.65, 0.0])
    res = vo_select(pose, 0.25, pref, EMPTY_D, EMPTY_V, static_map, 0.65, 1.0)
    assert res.feasible and res.twist[0] == 0.0 and abs(res.twist[1]) > 0.0
    stuck = vo_select(pose, 0.25, pref, EMPTY_D, EMPTY_V, static_map, 0.65, 1.0, escape=False)
    np.testing.assert_allclose(stuck.twist, [0.0, 0.0])


def test_vo_select_chord_model_and_odd_inputs():
    pose = np.array([0.0, 0.0, 0.0])
    disc = np.array([[2.0, 0.0, 0.3]])
    res = vo_select(pose, 0.25, np.array([0.65, 0.0]), disc, np.zeros((1, 2)), None, 0.65, 1.0,
                    model="chord", tau=0.5)
    assert res.feasible and not np.allclose(res.twist, [0.65, 0.0])
    with pytest.raises(ValueError):
        vo_select(pose, 0.25, np.zeros(2), disc, np.zeros((1, 2)), None, 0.65, 1.0, model="nope")
    # zero limits, no discs, custom goal heading: still an answer
    res = vo_select(pose, 0.25, np.zeros(2), EMPTY_D, EMPTY_V, None, 0.0, 0.0, goal_heading=1.0)
    np.testing.assert_allclose(res.twist, [0.0, 0.0])


def _run_vo_sim(starts, goals, humans, static, steps=300, dt=0.1, radius=0.25, human_r=0.3, reciprocal=False, **kw):
    """Unicycle robots heading to goals with pure pursuit + vo_select; humans walk straight.
    Returns final poses and the smallest robot-robot and robot-human centre distances."""
    poses = np.array(starts, dtype=float)
    hpos = np.array([h[0] for h in humans], dtype=float).reshape(-1, 2)
    hvel = np.array([h[1] for h in humans], dtype=float).reshape(-1, 2)
    n = len(poses)
    vel = np.zeros((n, 2))
    min_rr, min_rh = math.inf, math.inf
    for _ in range(steps):
        twists = []
        for i in range(n):
            pref = pure_pursuit(poses[i], np.asarray(goals[i], float), 0.65, 1.0, 1.0)
            others = [j for j in range(n) if j != i]
            discs = np.vstack([
                np.column_stack([poses[others, :2], np.full(len(others), radius)]),
                np.column_stack([hpos, np.full(len(hpos), human_r)]),
            ])
            dvel = np.vstack([vel[others], hvel])
            recip = np.r_[np.full(len(others), reciprocal), np.zeros(len(hpos), bool)]
            res = vo_select(poses[i], radius, pref, discs, dvel, static, 0.65, 1.0,
                            velocity=vel[i], reciprocal=recip, **kw)
            twists.append(res.twist)
        new = np.array([unicycle_step(poses[i], twists[i], dt) for i in range(n)])
        vel = (new[:, :2] - poses[:, :2]) / dt
        poses = new
        hpos = hpos + hvel * dt
        for i in range(n):
            for j in range(i + 1, n):
                min_rr = min(min_rr, float(np.linalg.norm(poses[i, :2] - poses[j, :2])))
            if len(hpos):
                min_rh = min(min_rh, float(np.linalg.norm(hpos - poses[i, :2], axis=1).min()))
    return poses, min_rr, min_rh


CROSSINGS = [
    ([(2.0, 10.0, 0.0), (6.0, 6.0, math.pi / 2)], [(10.0, 10.0), (6.0, 14.0)]),  # perpendicular, mirror-symmetric
    ([(2.0, 10.0, 0.0), (12.0, 10.0, math.pi)], [(12.0, 10.0), (2.0, 10.0)]),  # head-on swap
    ([(2.0, 9.8, 0.0), (9.0, 4.0, 2.0)], [(12.0, 10.0), (5.0, 15.0)]),  # oblique
]


@pytest.mark.parametrize("case", range(len(CROSSINGS)))
def test_sim_two_robots_crossing_reciprocal(case):
    empty = StaticMap.from_obstacles((20.0, 20.0), [])
    starts, goals = CROSSINGS[case]
    poses, min_rr, _ = _run_vo_sim(starts, goals, [], empty, steps=400, reciprocal=True)
    assert min_rr >= 0.5  # sum of radii
    for p, g in zip(poses, goals):
        assert np.linalg.norm(p[:2] - g) < 0.5  # and both got there


@pytest.mark.parametrize("case", range(len(CROSSINGS)))
def test_sim_two_robots_crossing_plain_vo_is_safe(case):
    # Plain VO (each robot dodges fully) may stall in a symmetric meeting, but never collides.
    empty = StaticMap.from_obstacles((20.0, 20.0), [])
    starts, goals = CROSSINGS[case]
    _, min_rr, _ = _run_vo_sim(starts, goals, [], empty, steps=400, reciprocal=False)
    assert min_rr >= 0.5


def test_sim_robots_around_static_obstacles(static_map):
    starts = [(1.0, 6.0, 0.0), (19.0, 6.5, math.pi), (10.0, 1.0, math.pi / 2)]
    goals = [(19.0, 6.0), (1.0, 6.5), (10.0, 11.0)]  # all through the central rectangle
    poses = np.array(starts)
    vel = np.zeros((3, 2))
    worst = math.inf
    for _ in range(500):
        tw = []
        for i in range(3):
            o = [j for j in range(3) if j != i]
            discs = np.column_stack([poses[o, :2], np.full(2, 0.25)])
            pref = pure_pursuit(poses[i], np.asarray(goals[i]), 0.65, 1.0, 1.0)
            tw.append(vo_select(poses[i], 0.25, pref, discs, vel[o], static_map, 0.65, 1.0,
                                velocity=vel[i], reciprocal=True).twist)
        new = np.array([unicycle_step(poses[i], tw[i], 0.1) for i in range(3)])
        vel = (new[:, :2] - poses[:, :2]) / 0.1
        poses = new
        worst = min(worst, float(static_map.distance(poses[:, :2]).min()))
    assert worst >= 0.25  # never touched an obstacle or wall


def test_sim_human_walking_at_robot():
    empty = StaticMap.from_obstacles((20.0, 20.0), [])
    # human walks straight at the robot along its path
    starts = [(2.0, 10.0, 0.0)]
    goals = [(16.0, 10.0)]
    humans = [((14.0, 10.0), (-0.5, 0.0))]
    poses, _, min_rh = _run_vo_sim(starts, goals, humans, empty, steps=350)
    assert min_rh >= 0.55  # robot radius + human radius
    assert np.linalg.norm(poses[0, :2] - goals[0]) < 0.5
    # human walks at a standing robot
    _, _, min_rh = _run_vo_sim([(8.0, 10.0, 0.0)], [(8.0, 10.0)], [((14.0, 10.0), (-0.5, 0.0))], empty, steps=200)
    assert min_rh >= 0.55


def test_vo_select_move_first_takes_a_safe_detour_before_the_escape_turn(static_map):
    # 0.55 m from the rectangle's left face (centre to face), goal behind it: every forward twist is
    # unsafe and standing is the cheapest safe candidate, so by default the robot turns in place.
    # With move_first it creeps off on a turning arc instead, and that arc is itself safe (a safe
    # preferred twist comes back unchanged).
    pose = np.array([8.45, 6.5, 0.0])
    pref = np.array([0.65, 0.0])
    turn = vo_select(pose, 0.25, pref, EMPTY_D, EMPTY_V, static_map, 0.65, 1.0)
    assert turn.feasible and turn.twist[0] == 0.0 and turn.twist[1] != 0.0
    for fast in (True, False):
        detour = vo_select(pose, 0.25, pref, EMPTY_D, EMPTY_V, static_map, 0.65, 1.0, move_first=True, fast=fast)
        assert detour.feasible and detour.twist[0] > 0.0 and detour.twist[1] != 0.0
        again = vo_select(pose, 0.25, detour.twist, EMPTY_D, EMPTY_V, static_map, 0.65, 1.0)
        np.testing.assert_array_equal(again.twist, detour.twist)
    # Nothing that moves is safe (closer to the face): move_first changes nothing.
    near = np.array([8.5, 6.5, 0.0])
    np.testing.assert_array_equal(vo_select(near, 0.25, pref, EMPTY_D, EMPTY_V, static_map, 0.65, 1.0).twist,
                                  vo_select(near, 0.25, pref, EMPTY_D, EMPTY_V, static_map, 0.65, 1.0,
                                            move_first=True).twist)


def test_vo_select_w_speed_bends_round_instead_of_crawling(static_map):
    # 0.35 m (centre to face, plus the margin) before the rectangle's left face with a 1 s static horizon:
    # driving on at full speed is unsafe. With equal weights the cheapest safe twist keeps the heading
    # and crawls (the contact only moves past the horizon); with w_speed = 3 a slow-down costs more than
    # a turn and the robot bends away faster.
    pose = np.array([8.4, 7.6, 0.0])
    args = (pose, 0.25, np.array([0.65, 0.0]), EMPTY_D, EMPTY_V, static_map, 0.65, 1.0)
    crawl = vo_select(*args, horizon_static=1.0, tau=0.7)
    bend = vo_select(*args, horizon_static=1.0, tau=0.7, w_speed=3.0)
    assert crawl.feasible and bend.feasible
    assert crawl.twist[1] == 0.0 and crawl.twist[0] < 0.25
    assert bend.twist[1] != 0.0 and bend.twist[0] > crawl.twist[0]
    np.testing.assert_array_equal(vo_select(*args, horizon_static=1.0, tau=0.7, w_speed=1.0).twist, crawl.twist)
    with pytest.raises(ValueError, match="w_speed"):
        VOParams(w_speed=0.0)


def test_vo_select_batch_escape_commit_keeps_the_turn_in_place(static_map):
    # Facing the rectangle's left face from 0.45 m, goal behind it: the escape rule turns in place, by
    # default to the right here. A robot already turning left in place keeps turning left with
    # escape_commit (the two sides are open alike); one that is driving (not turning in place) does not.
    pose = np.array([[8.55, 6.5, 0.0]])
    pref = np.array([[0.65, 0.0]])

    def turn(current, commit):
        res = vo_select_batch(VORobots(pose, 0.25, pref, 0.65, 1.0, current=np.array([current], dtype=float)),
                              VODiscs(EMPTY_D, EMPTY_V), static_map, VOParams(escape_commit=commit))
        assert res.escaped[0] and res.twist[0, 0] == 0.0
        return res.twist[0, 1]

    assert turn((0.0, 0.8), 0.0) < 0.0 and turn((0.0, -0.8), 0.0) < 0.0
    assert turn((0.0, 0.8), 100.0) > 0.0 and turn((0.0, -0.8), 100.0) < 0.0
    assert turn((0.3, 0.8), 100.0) < 0.0  # driving, not turning in place: no commitment
    with pytest.raises(ValueError, match="escape_commit"):
        VOParams(escape_commit=-1.0)


def test_vo_select_recip_gap_avoids_a_close_robot_plainly():
    # Two robots 0.7 m apart (centres; combined radius with margin 0.55 m) closing at 0.6 m/s. Reciprocally
    # (each takes half) standing still is safe; within recip_gap the other is avoided plainly: nothing is.
    pose = np.array([0.0, 0.0, 0.0])
    other, other_vel = np.array([[0.7, 0.0, 0.25]]), np.array([[-0.3, 0.0]])
    args = (pose, 0.25, np.array([0.5, 0.0]), other, other_vel, None, 0.65, 1.0)
    kw = {"velocity": np.array([0.3, 0.0])}
    shared = vo_select(*args, reciprocal=True, **kw)
    plain = vo_select(*args, reciprocal=False, **kw)
    assert shared.feasible and not plain.feasible
    for gap, expect in ((0.1, shared), (0.2, plain), (0.5, plain)):
        res = vo_select(*args, reciprocal=True, recip_gap=gap, **kw)
        assert (res.feasible, res.n_safe, res.min_time_to_collision) == (expect.feasible, expect.n_safe,
                                                                         expect.min_time_to_collision), gap
        np.testing.assert_array_equal(res.twist, expect.twist)


def test_vo_select_velocity_cost_measures_mean_velocities():
    # cost="velocity": the penalty's distance is between mean world-frame velocities (the chord of the
    # arc over tau), whatever the heading; vo.py's plain-Python velocities are twist_velocities'.
    from swarm_env.control.vo import _body_velocity, _grid_velocities

    grid = sample_twists(0.65, 1.0, 7, 11)
    mine = _grid_velocities(0.65, 1.0, 7, 11, 0.0, 1.0)
    np.testing.assert_allclose(mine, twist_velocities(0.0, grid, 1.0), rtol=0, atol=1e-15)
    assert _body_velocity(0.5, 0.0, 1.0) == (0.5, 0.0)
    # A disc ahead: the twist cost slows down more than the velocity cost (which turns instead).
    pose = np.array([0.0, 0.0, 0.3])
    disc = np.array([[1.6 * math.cos(0.3), 1.6 * math.sin(0.3), 0.3]])
    a = vo_select(pose, 0.25, np.array([0.65, 0.0]), disc, np.zeros((1, 2)), None, 0.65, 1.0)
    b = vo_select(pose, 0.25, np.array([0.65, 0.0]), disc, np.zeros((1, 2)), None, 0.65, 1.0, cost="velocity")
    assert a.feasible and b.feasible and b.twist[0] > a.twist[0]
    with pytest.raises(ValueError, match="cost"):
        vo_select(pose, 0.25, np.array([0.65, 0.0]), disc, np.zeros((1, 2)), None, 0.65, 1.0, cost="speed")


@pytest.mark.parametrize("obstacle", [CircleObstacle(center=(3.3, 4.5), radius=0.5),
                                      RectangleObstacle(center=(3.3, 4.5), size=(1.0, 1.0), angle=0.0)])
def test_static_reach_judges_static_obstacles_by_path_length(obstacle) -> None:
    # A robot driving at 0.6 m/s straight at a static obstacle 1.5 m of path away (margin included):
    # contact in 2.5 s, within the 3 s horizon. Without static_reach slowing down to 0.43 m/s pushes the
    # contact to 3.5 s, past the horizon, and is taken (straight on, slower); with it every straight
    # candidate reaches the obstacle within the 1.8 m the preferred twist covers in 3 s, so it turns.
    static = StaticMap.from_obstacles((12.0, 9.0), [obstacle])
    pose, pref = np.array([1.0, 4.5, 0.0]), np.array([0.6, 0.0])
    no_discs = (np.zeros((0, 3)), np.zeros((0, 2)))
    plain = vo_select(pose, 0.25, pref, *no_discs, static, 0.65, 1.0, VOParams())
    assert plain.feasible and plain.twist[1] == 0.0 and 0.0 < plain.twist[0] < 0.6
    reach = vo_select(pose, 0.25, pref, *no_discs, static, 0.65, 1.0, VOParams(static_reach=6.0))
    assert reach.feasible and reach.twist[1] != 0.0 and reach.twist[0] > plain.twist[0]
    assert reach.n_safe < plain.n_safe
    # A standing robot is not in contact: standing stays safe (the grid's v = 0 candidates).
    still = vo_select(pose, 0.25, np.array([0.0, 0.0]), *no_discs, static, 0.65, 1.0, VOParams(static_reach=6.0))
    assert still.feasible and still.twist[0] == 0.0
    if isinstance(obstacle, CircleObstacle):
        # The same disc as a (resting) moving disc: judged by time as before, static_reach or not.
        disc = np.array([[3.3, 4.5, 0.5]])
        a = vo_select(pose, 0.25, pref, disc, np.zeros((1, 2)), None, 0.65, 1.0, VOParams())
        b = vo_select(pose, 0.25, pref, disc, np.zeros((1, 2)), None, 0.65, 1.0, VOParams(static_reach=6.0))
        assert np.array_equal(a.twist, b.twist) and np.array_equal(a.twist, plain.twist)
    # Cut at s h_s: with s = 1 the slow-down is safe again (contact at 3.5 s > 3 s).
    capped = vo_select(pose, 0.25, pref, *no_discs, static, 0.65, 1.0, VOParams(static_reach=1.0))
    assert np.array_equal(capped.twist, plain.twist)
    with pytest.raises(ValueError, match="static_reach"):
        VOParams(static_reach=2.0, model="chord")
    with pytest.raises(ValueError, match="static_reach"):
        VOParams(static_reach=0.5)


def test_vo_select_batch_disc_horizon_looks_further_for_one_disc():
    # A human (radius 0.3) walks head-on at a standing robot: contact (margin 0.05 included) in 3 s. Within the
    # 2.5 s horizon standing still is safe; with that disc's own horizon of 3.5 s it is not, and the robot
    # moves off its line. A second disc with the same motion but the search's horizon changes nothing.
    pose = np.array([[0.0, 0.0, math.pi / 2]])
    human, human_vel = np.array([[3.0, 0.0, 0.3]]), np.array([[-0.8, 0.0]])
    params = VOParams(horizon=2.5)

    def select(discs, vel, disc_horizon=None):
        return vo_select_batch(VORobots(pose, 0.25, np.zeros((1, 2)), 0.65, 1.0),
                               VODiscs(discs, vel, horizon=disc_horizon), None, params)

    plain = select(human, human_vel)
    assert plain.preferred_safe[0] and np.array_equal(plain.twist[0], [0.0, 0.0])
    longer = select(human, human_vel, np.array([3.5]))
    assert longer.feasible[0] and not longer.preferred_safe[0] and longer.twist[0, 0] > 0.0
    same = select(human, human_vel, np.array([2.5]))
    assert same.preferred_safe[0] and np.array_equal(same.twist[0], plain.twist[0])
    # Two discs: only the one given the longer horizon is looked for further.
    far = np.array([[0.0, -6.0, 0.3]])
    both = select(np.vstack([human, far]), np.vstack([human_vel, [[0.0, 0.0]]]), np.array([2.5, 3.5]))
    assert both.preferred_safe[0]
    for bad, match in ((np.array([3.5, 3.5]), "one horizon per disc"), (np.array([-1.0]), "> 0"),
                       (np.array([np.nan]), "> 0")):
        with pytest.raises(ValueError, match=match):
            select(human, human_vel, bad)
