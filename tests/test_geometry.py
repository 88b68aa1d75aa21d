"""Tests of swarm_env.geometry.static_map: signed distance, projection to free space, lidar."""

from __future__ import annotations

import math
import pickle

import numpy as np
import pytest

from swarm_env.geometry.static_map import (
    NO_SURFACE,
    WALL_NAMES,
    StaticMap,
    convex_ccw,
    rotate_rectangle,
)
from swarm_env.scenario import CircleObstacle, PolygonObstacle, RectangleObstacle
from swarm_env.sensing.lidar import cast_rays

SQ2 = math.sqrt(2.0)


def empty_map(w: float = 10.0, h: float = 8.0) -> StaticMap:
    return StaticMap.from_obstacles((w, h), [])


def random_map(rng: np.random.Generator, n: int = 9, size: float = 20.0) -> StaticMap:
    obs = []
    for i in range(n):
        c = tuple(rng.uniform(2.0, size - 2.0, 2))
        kind = i % 3
        if kind == 0:
            obs.append(CircleObstacle(c, float(rng.uniform(0.3, 1.2))))
        elif kind == 1:
            obs.append(RectangleObstacle(c, tuple(rng.uniform(0.4, 2.5, 2)), float(rng.uniform(-90, 90))))
        else:  # random convex polygon: points on a circle, 3..7 of them, either winding
            m = int(rng.integers(3, 8))
            a = np.sort(rng.uniform(0.0, 2 * np.pi, m))
            pts = np.c_[np.cos(a), np.sin(a)] * rng.uniform(0.5, 1.5) + c
            if rng.random() < 0.5:
                pts = pts[::-1]
            obs.append(PolygonObstacle(tuple(map(tuple, pts))))
    return StaticMap.from_obstacles((size, size), obs)


# ------------------------------------------------------------------------------------------
# polygon helpers and construction
# ------------------------------------------------------------------------------------------


def test_rotate_rectangle_corners_ccw() -> None:
    c = rotate_rectangle((1.0, 2.0), (2.0, 1.0), 90.0)
    # width now along y: corners at (1 +- 0.5, 2 +- 1)
    np.testing.assert_allclose(np.sort(c[:, 0]), [0.5, 0.5, 1.5, 1.5], atol=1e-12)
    np.testing.assert_allclose(np.sort(c[:, 1]), [1.0, 1.0, 3.0, 3.0], atol=1e-12)
    x, y = c[:, 0], c[:, 1]
    assert np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y) > 0  # CCW
    with pytest.raises(ValueError):
        rotate_rectangle((0, 0), (0.0, 1.0), 0.0)


def test_convex_ccw_fixes_cw_order() -> None:
    cw = [(0, 0), (0, 1), (1, 1), (1, 0)]
    out = convex_ccw(cw)
    np.testing.assert_array_equal(out, np.array(cw[::-1], dtype=float))
    ccw = [(0, 0), (1, 0), (1, 1), (0, 1)]
    np.testing.assert_array_equal(convex_ccw(ccw), np.array(ccw, dtype=float))
    # a closed ring (last == first) is accepted
    assert len(convex_ccw(ccw + [(0, 0)])) == 4


@pytest.mark.parametrize(
    "pts, msg",
    [
        ([(0, 0), (1, 0)], "at least 3"),
        ([(0, 0), (1, 1), (2, 2)], "zero area"),
        ([(0, 0), (2, 0), (1, 0.5), (2, 2), (0, 2)], "not convex"),  # dented square
        ([(0, 0), (2, 0), (2, 1), (1, 1), (1, 2), (0, 2)], "not convex"),  # L-shape
        ([(1, 0), (-0.809, 0.588), (0.309, -0.951), (0.309, 0.951), (-0.809, -0.588)], "not simple"),  # pentagram
        ([(0, 0, 0), (1, 0, 0), (0, 1, 0)], "shape"),
    ],
)
def test_convex_ccw_rejects(pts, msg) -> None:
    with pytest.raises(ValueError, match=msg):
        convex_ccw(pts)


def test_from_obstacles_ids_and_segments() -> None:
    obs = [
        RectangleObstacle((2, 2), (1, 1)),
        CircleObstacle((5, 5), 1.0),
        PolygonObstacle(((7, 1), (8, 1), (7.5, 2))),
    ]
    m = StaticMap.from_obstacles((10, 8), obs)
    assert m.circle_ids.tolist() == [1]
    assert m.polygon_ids.tolist() == [0, 2]
    assert m.segments.shape == (4 + 3 + 4, 4)
    np.testing.assert_array_equal(m.segments[-4:], [[0, 0, 10, 0], [10, 0, 10, 8], [10, 8, 0, 8], [0, 8, 0, 0]])
    assert WALL_NAMES == ("bottom", "right", "top", "left")
    # per-obstacle distances come back in scenario order
    d = m.obstacle_distances(np.array([[2.0, 2.0], [5.0, 5.0]]))
    np.testing.assert_allclose(d[0], [-0.5, math.hypot(3, 3) - 1.0, d[0, 2]])
    np.testing.assert_allclose(d[1, 1], -1.0)
    with pytest.raises(ValueError, match="obstacle 0"):
        StaticMap.from_obstacles((10, 8), [PolygonObstacle(((0, 0), (1, 0)))])
    with pytest.raises(ValueError):
        StaticMap.from_obstacles((0, 8), [])


def test_map_is_read_only_and_pickles() -> None:
    m = random_map(np.random.default_rng(3))
    with pytest.raises(ValueError):
        m.circles[0, 0] = 1.0
    m2 = pickle.loads(pickle.dumps(m))
    p = np.random.default_rng(4).uniform(0, 20, (50, 2))
    np.testing.assert_array_equal(m.distance(p), m2.distance(p))


# ------------------------------------------------------------------------------------------
# signed distance
# ------------------------------------------------------------------------------------------


def test_distance_circle_sign() -> None:
    m = StaticMap.from_obstacles((10, 10), [CircleObstacle((5, 5), 1.0)])
    pts = np.array([[5, 5], [5.5, 5], [7, 5], [5, 3.5]])
    np.testing.assert_allclose(m.distance(pts, walls=False), [-1.0, -0.5, 1.0, 0.5])
    assert m.is_free(pts).tolist() == [False, False, True, True]
    assert m.is_free(pts, clearance=0.75).tolist() == [False, False, True, False]


def test_distance_rotated_rectangle_sign() -> None:
    ang = 30.0
    m = StaticMap.from_obstacles((20, 20), [RectangleObstacle((10, 10), (4.0, 2.0), ang)])
    a = math.radians(ang)
    ux = np.array([math.cos(a), math.sin(a)])  # local x (length 4)
    uy = np.array([-math.sin(a), math.cos(a)])  # local y (length 2)
    c = np.array([10.0, 10.0])
    pts = np.array([
        c,  # centre: depth = half the short side
        c + 1.5 * ux,  # inside, 0.5 from the short end and 1 from the long sides
        c + 3.0 * ux,  # outside along local x: 1 beyond the end
        c + 1.7 * uy,  # outside along local y: 0.7 beyond the side
        c + 3.0 * ux + 2.0 * uy,  # outside near a corner: distance to the corner (2, 1)
    ])
    expected = [-1.0, -0.5, 1.0, 0.7, math.hypot(1.0, 1.0)]
    np.testing.assert_allclose(m.distance(pts, walls=False), expected, atol=1e-12)


def test_distance_polygon_sign() -> None:
    tri = ((0, 0), (4, 0), (0, 4))  # right triangle, CCW
    m = StaticMap.from_obstacles((10, 10), [PolygonObstacle(tri[::-1])])  # given CW
    pts = np.array([[1, 1], [0.5, 2], [3, 3], [-1, -1], [5, 0]])
    expected = [-1.0, -0.5, (6 - 4) / SQ2, SQ2, 1.0]
    np.testing.assert_allclose(m.distance(pts, walls=False), expected, atol=1e-12)
    # point (-1, -1) is outside the world too: the wall term takes over
    assert m.distance(pts)[3] == pytest.approx(-SQ2)


def test_distance_walls_and_shapes() -> None:
    m = empty_map(10, 8)
    pts = np.array([[5, 4], [1, 7.5], [-1, 4], [11, 10]])
    np.testing.assert_allclose(m.distance(pts), [4, 0.5, -1.0, -math.hypot(1, 2)])
    assert np.all(np.isinf(m.distance(pts, walls=False)))
    assert m.distance(np.zeros((3, 5, 2))).shape == (3, 5)
    assert m.distance(np.array([5.0, 4.0])).shape == ()


def test_distance_padded_polygons_match_single_maps() -> None:
    """Padding polygons of different vertex counts must not change anyone's distance."""
    rng = np.random.default_rng(11)
    m = random_map(rng, n=12)
    pts = rng.uniform(-1, 21, (300, 2))
    d_all = m.obstacle_distances(pts)
    for pid, poly in zip(m.polygon_ids, m.polygons):
        single = StaticMap.from_obstacles((20, 20), [PolygonObstacle(tuple(map(tuple, poly)))])
        np.testing.assert_allclose(d_all[:, pid], single.distance(pts, walls=False), atol=1e-12)
    expected = np.minimum(d_all.min(axis=1), m.wall_distance(pts))
    np.testing.assert_allclose(m.distance(pts), expected, atol=1e-12)


def test_nearest_obstacle_normals() -> None:
    m = StaticMap.from_obstacles((10, 10), [CircleObstacle((3, 3), 1.0), RectangleObstacle((7, 7), (2, 2))])
    d, n = m.nearest_obstacle(np.array([3.0, 5.0]))
    assert d == pytest.approx(1.0)
    np.testing.assert_allclose(n, [0, 1])
    d, n = m.nearest_obstacle(np.array([7.0, 7.8]))  # inside the square, near its top
    assert d == pytest.approx(-0.2)
    np.testing.assert_allclose(n, [0, 1], atol=1e-12)
    d, n = m.nearest_obstacle(np.array([9.0, 9.0]))  # outside, nearest the square's corner
    assert d == pytest.approx(1.0)  # the top and right walls are also at distance 1 ...
    d, n = m.nearest_obstacle(np.array([8.5, 8.5]))  # ... here the corner is nearer (0.707)
    assert d == pytest.approx(0.5 * SQ2)
    np.testing.assert_allclose(n, [1 / SQ2, 1 / SQ2])
    d, n, ids = m.nearest_obstacles(np.array([[5.0, 0.2], [-1.0, 5.0], [3.0, 5.0]]))
    np.testing.assert_allclose(d, [0.2, -1.0, 1.0])
    np.testing.assert_allclose(n, [[0, 1], [1, 0], [0, 1]])
    assert ids.tolist() == [-1, -4, 0]  # bottom wall, left wall, obstacle 0
    # the normal is the gradient of distance: a small step along it raises the clearance
    rng = np.random.default_rng(5)
    p = rng.uniform(0.5, 9.5, (200, 2))
    d, n, _ = m.nearest_obstacles(p)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0)
    np.testing.assert_allclose(d, m.distance(p))
    step = 1e-4
    assert np.all(m.distance(p + step * n) > d + 0.5 * step)
    d0, n0, i0 = StaticMap.from_obstacles((10, 10), []).nearest_obstacles(p[:2], walls=False)
    assert np.all(np.isinf(d0)) and np.all(n0 == 0) and np.all(i0 == NO_SURFACE)


# ------------------------------------------------------------------------------------------
# projection to free space
# ------------------------------------------------------------------------------------------


def test_project_free_leaves_free_points_unchanged() -> None:
    m = StaticMap.from_obstacles((10, 10), [CircleObstacle((5, 5), 1.0)])
    pts = np.array([[2.0, 2.0], [5.0, 6.5], [8.123456789, 1.5]])
    out = m.project_free(pts, clearance=0.5)
    np.testing.assert_array_equal(out, pts)
    assert out is not pts


def test_project_free_circle_inside_and_band() -> None:
    m = StaticMap.from_obstacles((10, 10), [CircleObstacle((5, 5), 1.0)])
    pts = np.array([[5.5, 5.0], [5.0, 6.2], [5.0, 3.9]])  # inside; band above; band below
    out = m.project_free(pts, clearance=0.3)
    np.testing.assert_allclose(out, [[6.3, 5.0], [5.0, 6.3], [5.0, 3.7]], atol=1e-8)
    np.testing.assert_allclose(m.distance(out), 0.3, atol=1e-8)
    assert np.all(m.is_free(out, 0.3))


def test_project_free_rotated_rectangle_and_polygon() -> None:
    ang = 30.0
    a = math.radians(ang)
    ux = np.array([math.cos(a), math.sin(a)])
    uy = np.array([-math.sin(a), math.cos(a)])
    c = np.array([10.0, 10.0])
    tri = ((2, 2), (6, 2), (2, 6))
    m = StaticMap.from_obstacles((20, 20), [RectangleObstacle(tuple(c), (4.0, 2.0), ang), PolygonObstacle(tri)])
    p = c + 1.5 * ux + 0.2 * uy  # inside; the nearest side is the short end (0.5 away)
    out = m.project_free(p[None], clearance=0.25)[0]
    np.testing.assert_allclose(out, c + 2.25 * ux + 0.2 * uy, atol=1e-8)
    q = np.array([[2.5, 3.0]])  # inside the triangle, 0.5 from the left edge x = 2
    np.testing.assert_allclose(m.project_free(q, 0.1), [[1.9, 3.0]], atol=1e-8)


def test_project_free_outside_world_is_clamped() -> None:
    m = empty_map(10, 8)
    pts = np.array([[-3.0, 4.0], [12.0, 9.0], [5.0, 7.9]])
    out = m.project_free(pts, clearance=0.4)
    np.testing.assert_allclose(out, [[0.4, 4.0], [9.6, 7.6], [5.0, 7.6]], atol=1e-8)


def test_project_free_overlapping_circles_lands_on_crease() -> None:
    m = StaticMap.from_obstacles((10, 10), [CircleObstacle((4.0, 5.0), 1.0), CircleObstacle((5.2, 5.0), 1.0)])
    p = np.array([[4.6, 5.1]])  # inside both
    out = m.project_free(p, clearance=0.2)[0]
    # inflated radii 1.2, centres 1.2 apart: the creases are at (4.6, 5 +- 1.2 * sin 60deg)
    np.testing.assert_allclose(out, [4.6, 5.0 + 1.2 * math.sqrt(3) / 2], atol=1e-8)
    assert m.is_free(out, 0.2)
    # projecting out of one circle alone would have landed in the other one
    assert not m.is_free(np.array([4.0 + 1.2 * 0.6 / math.hypot(0.6, 0.1), 5.0]), 0.2)


def test_project_free_is_nearest_free_point_on_random_maps() -> None:
    """Compare with a brute-force search over a dense grid of free points."""
    rng = np.random.default_rng(7)
    for _ in range(3):
        m = random_map(rng, n=10, size=12.0)
        clearance = float(rng.uniform(0.0, 0.4))
        pts = rng.uniform(-0.5, 12.5, (400, 2))
        out = m.project_free(pts, clearance)
        assert np.all(m.is_free(out, clearance))
        moved = ~m.is_free(pts, clearance)
        assert moved.sum() > 20
        np.testing.assert_array_equal(out[~moved], pts[~moved])
        # the nearest free point lies on the free set's boundary
        np.testing.assert_allclose(m.distance(out[moved]), clearance, atol=1e-6)
        h = 0.04
        g = np.arange(0.0, 12.0 + h / 2, h)
        grid = np.stack(np.meshgrid(g, g), axis=-1).reshape(-1, 2)
        grid = grid[m.is_free(grid, clearance)]
        for p, q in zip(pts[moved], out[moved]):
            best = np.sqrt(np.min(np.sum((grid - p) ** 2, axis=1)))
            assert np.linalg.norm(q - p) <= best + 1e-6, (p, q, best)
        np.testing.assert_array_equal(m.project_free(pts, clearance), out)  # deterministic


def _exact_projection(m: StaticMap, pts: np.ndarray, clearance: float) -> np.ndarray:
    """project_free() through the vectorised exact search only (no fast path)."""
    out = pts.copy()
    bad = ~(m.distance(pts) >= clearance)
    if np.any(bad):
        out[bad] = m._project_exact(pts[bad], clearance)
    return out


def _assert_fast_path_matches_exact(m: StaticMap, pts: np.ndarray, clearance: float) -> tuple[int, int]:
    """project_free() on small batches must equal the exact search bit for bit; returns
    (points not free, points the fast path settled)."""
    ref = _exact_projection(m, pts, clearance)
    bad = ~(m.distance(pts) >= clearance)
    settled = 0
    for s in range(0, len(pts), 8):  # formation-sized batches take the fast path
        chunk = pts[s:s + 8]
        got = m.project_free(chunk, clearance)
        assert got.tobytes() == ref[s:s + 8].tobytes(), (chunk, got, ref[s:s + 8])
        scratch = chunk.copy()
        slow = m._project_fast(chunk, clearance, scratch)
        settled += int(bad[s:s + 8].sum()) - len(slow)
    return int(bad.sum()), settled


def test_project_free_fast_path_equals_exact_search_on_random_maps() -> None:
    rng = np.random.default_rng(11)
    total = settled = 0
    for _ in range(25):
        size = float(rng.uniform(6.0, 20.0))
        m = random_map(rng, n=int(rng.integers(1, 12)), size=size)
        clearance = float(rng.choice([0.0, rng.uniform(0.0, 0.6)]))
        bound = m._bound  # bounding discs: put many points in and around the obstacles
        k = rng.integers(0, len(bound), 150)
        ang = rng.uniform(0.0, 2 * np.pi, 150)
        rad = bound[k, 2] * rng.uniform(0.0, 1.6, 150)
        pts = np.vstack([
            rng.uniform(-0.5, size + 0.5, (100, 2)),
            bound[k, :2] + np.c_[np.cos(ang), np.sin(ang)] * rad[:, None],
            bound[:, :2],  # obstacle centres (ties between directions)
        ])
        b, f = _assert_fast_path_matches_exact(m, pts, clearance)
        total, settled = total + b, settled + f
    assert total > 1000
    assert settled > 0.5 * total  # the fast path does the work, not the fallback


def test_project_free_fast_path_equals_exact_search_on_lattice_ties() -> None:
    """Axis-aligned shapes at integer coordinates and lattice points: many exact ties
    between feet, corners and directions, where only identical tie-breaking agrees."""
    rng = np.random.default_rng(5)
    g = np.arange(-1.0, 11.01, 0.25)
    grid = np.stack(np.meshgrid(g, g), axis=-1).reshape(-1, 2)
    total = settled = 0
    for _ in range(12):
        obs = []
        for i in range(int(rng.integers(1, 6))):
            c = (float(rng.integers(1, 9)), float(rng.integers(1, 9)))
            if i % 3 == 0:
                obs.append(CircleObstacle(c, float(rng.choice([0.5, 1.0, 1.5]))))
            elif i % 3 == 1:
                size = (float(rng.integers(1, 4)), float(rng.integers(1, 4)))
                obs.append(RectangleObstacle(c, size, float(rng.choice([0.0, 45.0, 90.0]))))
            else:
                obs.append(PolygonObstacle(((c[0] - 1, c[1] - 1), (c[0] + 1, c[1] - 1), (c[0], c[1] + 1))))
        m = StaticMap.from_obstacles((10.0, 10.0), obs)
        extra = np.vstack([*m.polygons, m.circles[:, :2]]) if len(m.circles) else np.vstack(m.polygons)
        pts = np.vstack([grid, extra])
        b, f = _assert_fast_path_matches_exact(m, pts, float(rng.choice([0.0, 0.25, 0.5, 1.0])))
        total, settled = total + b, settled + f
    assert settled > 0.5 * total


def test_project_free_memo_returns_fresh_arrays_and_stays_bounded(monkeypatch: pytest.MonkeyPatch) -> None:
    import swarm_env.geometry.static_map as geometry

    m = random_map(np.random.default_rng(8), n=8, size=10.0)
    pts = np.random.default_rng(9).uniform(0.0, 10.0, (8, 2))
    first = m.project_free(pts, 0.3)
    again = m.project_free(pts.copy(), 0.3)  # same bits: answered from the memo
    assert again.tobytes() == first.tobytes() and again is not first
    again[:] = -1.0  # the caller owns its result
    assert m.project_free(pts, 0.3).tobytes() == first.tobytes()
    assert m.project_free(pts.reshape(4, 2, 2), 0.3).shape == (4, 2, 2)  # shape follows the query
    assert pickle.loads(pickle.dumps(m))._memo == {}
    monkeypatch.setattr(geometry, "_MEMO_SIZE", 5)
    for k in range(20):
        m.project_free(pts + 0.01 * k, 0.3)
    assert len(m._memo) <= 5


def test_min_distance_equals_the_plain_minimum() -> None:
    rng = np.random.default_rng(3)
    for _ in range(40):
        m = random_map(rng, n=int(rng.integers(0, 10)), size=12.0)
        pts = rng.uniform(-0.3, 12.3, (int(rng.integers(1, 12)), 2))
        radii = rng.uniform(0.0, 0.4, len(pts))
        plain = float((m.distance(pts) - radii).min())
        for upper in (math.inf, plain - 0.5, plain - 1e-12, plain, plain + 1e-12, plain + 0.3, 5.0):
            got = m.min_distance(pts, radii, upper)
            assert got == min(upper, plain), (upper, got, plain)
        assert m.min_distance(pts, 0.25) == float((m.distance(pts) - 0.25).min())
    assert m.min_distance(np.zeros((0, 2)), 0.1, 2.0) == 2.0


def test_project_free_empty_free_space_is_best_effort() -> None:
    m = empty_map(1.0, 1.0)
    out = m.project_free(np.array([[0.1, 0.9]]), clearance=0.8)  # nothing is 0.8 from all walls
    assert np.all(np.isfinite(out))
    with pytest.raises(ValueError):
        m.project_free(np.array([[0.5, 0.5]]), clearance=-1.0)


# ------------------------------------------------------------------------------------------
# lidar
# ------------------------------------------------------------------------------------------


def test_ray_hits_walls() -> None:
    m = empty_map(10, 8)
    o = np.tile([[2.0, 3.0]], (5, 1))
    ang = np.array([0.0, np.pi / 2, np.pi, -np.pi / 2, np.pi / 4])
    d = cast_rays(o, ang, 20.0, m)
    np.testing.assert_allclose(d, [8.0, 5.0, 2.0, 3.0, 5.0 * SQ2], atol=1e-12)
    assert d.dtype == np.float64


def test_ray_hits_circle() -> None:
    m = StaticMap.from_obstacles((20, 10), [CircleObstacle((6.0, 3.0), 1.0)])
    o = np.array([[2.0, 3.0], [2.0, 3.5], [2.0, 3.0], [10.0, 3.0], [6.0, 3.2]])
    ang = np.array([0.0, 0.0, np.pi, np.pi, 1.0])
    d = cast_rays(o, ang, 50.0, m)
    np.testing.assert_allclose(d, [3.0, 4.0 - math.sqrt(0.75), 2.0, 3.0, 0.0], atol=1e-12)


def test_ray_hits_rotated_rectangle() -> None:
    ang = 30.0
    a = math.radians(ang)
    c = np.array([10.0, 10.0])
    m = StaticMap.from_obstacles((20, 20), [RectangleObstacle(tuple(c), (2.0, 1.0), ang)])
    ux = np.array([math.cos(a), math.sin(a)])
    uy = np.array([-math.sin(a), math.cos(a)])
    o = np.array([c + 3.0 * ux, c + 3.0 * uy, c - 4.0 * uy + 0.3 * ux, c])
    angles = np.array([a + np.pi, a - np.pi / 2, a + np.pi / 2, 0.0])
    d = cast_rays(o, angles, 50.0, m)
    # towards the centre along local x / y: the half-size is 1 / 0.5; the last ray starts inside
    np.testing.assert_allclose(d, [2.0, 2.5, 3.5, 0.0], atol=1e-12)


def test_ray_discs_and_exclude() -> None:
    m = empty_map(10, 8)
    discs = np.array([[2.0, 3.0, 0.25], [5.0, 3.0, 0.5], [2.0, 6.0, 0.3]])
    o = np.array([[2.0, 3.0], [2.0, 3.0], [2.0, 3.0], [2.0, 3.0]])
    ang = np.array([0.0, 0.0, 0.0, np.pi / 2])
    d = cast_rays(o, ang, 20.0, m, discs=discs, exclude=np.array([0, -1, 2, 0]))
    # excluded own body -> next disc at 2.5; not excluded -> 0 (starts inside);
    # excluding another disc does not hide the own body; up: the third disc at 3 - 0.3
    np.testing.assert_allclose(d, [2.5, 0.0, 0.0, 2.7], atol=1e-12)
    d_none = cast_rays(o[:1], ang[:1], 20.0, m, discs=discs)
    assert d_none[0] == 0.0


def test_ray_no_hit_returns_max_range() -> None:
    m = StaticMap.from_obstacles((100, 100), [CircleObstacle((50.0, 60.0), 1.0)])
    o = np.array([[50.0, 50.0], [50.0, 50.0], [50.0, 50.0]])
    ang = np.array([0.0, -np.pi / 2, np.pi / 2])  # nothing within 5 m; circle behind / ahead at 9
    d = cast_rays(o, ang, 5.0, m, discs=np.array([[50.0, 40.0, 0.5]]))
    np.testing.assert_array_equal(d, [5.0, 5.0, 5.0])
    assert cast_rays(o[2:], ang[2:], 20.0, m)[0] == pytest.approx(9.0)


def _brute_ray(o, ang, max_range, m: StaticMap, discs, excl) -> float:
    """One ray, the slow obvious way."""
    d = np.array([math.cos(ang), math.sin(ang)])
    best = math.inf
    for x0, y0, x1, y1 in m.segments:
        e = np.array([x1 - x0, y1 - y0])
        mat = np.array([[d[0], -e[0]], [d[1], -e[1]]])
        if abs(np.linalg.det(mat)) < 1e-12:
            continue
        t, u = np.linalg.solve(mat, np.array([x0, y0]) - o)
        if t >= 0 and 0 <= u <= 1:
            best = min(best, t)
    circles = [tuple(c) for c in m.circles] + [tuple(c) for i, c in enumerate(discs) if i != excl]
    for cx, cy, r in circles:
        f = o - np.array([cx, cy])
        if f @ f <= r * r:
            best = 0.0
            continue
        b = f @ d
        disc = b * b - (f @ f - r * r)
        if disc >= 0 and -b - math.sqrt(disc) >= 0:
            best = min(best, -b - math.sqrt(disc))
    for poly in m.polygons:
        e = np.roll(poly, -1, axis=0) - poly
        w = o - poly
        if np.all(e[:, 0] * w[:, 1] - e[:, 1] * w[:, 0] > 0):  # left of every CCW edge
            best = 0.0
    return min(best, max_range)


def test_cast_rays_matches_brute_force_on_random_map() -> None:
    rng = np.random.default_rng(2024)
    m = random_map(rng, n=12)
    n_disc = 10
    discs = np.c_[rng.uniform(1, 19, (n_disc, 2)), rng.uniform(0.2, 0.5, n_disc)]
    n_rays = 400
    owner = rng.integers(-1, n_disc, n_rays)
    origins = rng.uniform(0.5, 19.5, (n_rays, 2))
    origins[owner >= 0] = discs[owner[owner >= 0], :2]  # rays from a disc's centre exclude it
    angles = rng.uniform(-np.pi, np.pi, n_rays)
    max_range = 6.0
    got = cast_rays(origins, angles, max_range, m, discs=discs, exclude=owner)
    want = np.array([_brute_ray(o, a, max_range, m, discs, e) for o, a, e in zip(origins, angles, owner)])
    np.testing.assert_allclose(got, want, atol=1e-9)
    # the test exercises every case: hits, misses, starts inside something
    assert np.any(got == max_range) and np.any(got == 0.0) and np.any((got > 0) & (got < max_range))


def test_cast_rays_empty_inputs() -> None:
    m = empty_map()
    assert cast_rays(np.zeros((0, 2)), np.zeros(0), 5.0, m).shape == (0,)
    d = cast_rays(np.array([[5.0, 4.0]]), np.array([0.0]), 3.0, m, discs=np.zeros((0, 3)), exclude=np.array([-1]))
    np.testing.assert_array_equal(d, [3.0])
