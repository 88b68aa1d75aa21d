"""Tests for swarm_env.geometry.paths: polylines, the virtual leader, human motion."""

from __future__ import annotations

import math
import pickle

import numpy as np
import pytest

from swarm_env.geometry.paths import PolylinePath, human_states, virtual_leader
from swarm_env.scenario import HumanSpec

L_PATH = [(0.0, 0.0), (3.0, 0.0), (3.0, 0.0), (3.0, 4.0)]  # an L with a duplicate vertex


def test_length_and_duplicates_dropped():
    p = PolylinePath(L_PATH)
    assert p.length == pytest.approx(7.0)
    assert p.points.shape == (3, 2)
    np.testing.assert_allclose(p.cumulative, [0.0, 3.0, 7.0])
    np.testing.assert_allclose(p.headings, [0.0, math.pi / 2])


def test_point_at_and_clipping():
    p = PolylinePath(L_PATH)
    np.testing.assert_allclose(p.point_at(0.0), [0, 0])
    np.testing.assert_allclose(p.point_at(1.5), [1.5, 0])
    np.testing.assert_allclose(p.point_at(3.0), [3, 0])
    np.testing.assert_allclose(p.point_at(5.0), [3, 2])
    np.testing.assert_allclose(p.point_at(-1.0), [0, 0])
    np.testing.assert_allclose(p.point_at(100.0), [3, 4])
    s = np.array([-1.0, 0.0, 1.5, 3.0, 5.0, 7.0, 9.0])
    np.testing.assert_allclose(p.points_at(s), [p.point_at(x) for x in s])


def test_heading_at_vertex_is_outgoing():
    p = PolylinePath(L_PATH)
    assert p.heading_at(1.0) == pytest.approx(0.0)
    assert p.heading_at(3.0) == pytest.approx(math.pi / 2)  # at the corner: outgoing segment
    assert p.heading_before(3.0) == pytest.approx(0.0)  # incoming segment
    assert p.heading_at(7.0) == pytest.approx(math.pi / 2)
    assert p.heading_at(50.0) == pytest.approx(math.pi / 2)


def test_project_with_bounds():
    p = PolylinePath(L_PATH)
    assert p.project(np.array([1.0, -2.0])) == pytest.approx(1.0)
    assert p.project(np.array([4.0, 1.0])) == pytest.approx(4.0)
    assert p.project(np.array([10.0, 10.0])) == pytest.approx(7.0)
    # restricted window: closest admissible point
    assert p.project(np.array([1.0, 0.5]), s_min=2.0) == pytest.approx(2.0)
    assert p.project(np.array([3.0, 3.0]), s_max=4.5) == pytest.approx(4.5)
    assert p.project(np.array([3.0, 3.0]), s_min=1.0, s_max=2.0) == pytest.approx(2.0)


def test_project_self_crossing_ties_to_smallest_s():
    # A square loop: the start point is also the end point.
    p = PolylinePath([(0, 0), (2, 0), (2, 2), (0, 2), (0, 0)])
    assert p.project(np.array([0.0, 0.0])) == pytest.approx(0.0)
    assert p.project(np.array([0.0, 0.0]), s_min=1.0) == pytest.approx(8.0)


def test_immutable_and_picklable():
    p = PolylinePath(L_PATH)
    with pytest.raises(AttributeError):
        p.length = 3.0  # type: ignore[misc]
    with pytest.raises(ValueError):
        p.points[0, 0] = 5.0
    q = pickle.loads(pickle.dumps(p))
    np.testing.assert_array_equal(q.points, p.points)


def test_invalid_and_degenerate():
    with pytest.raises(ValueError):
        PolylinePath([(0.0, 0.0)])
    with pytest.raises(ValueError):
        PolylinePath([(0.0, 0.0), (math.nan, 1.0)])
    d = PolylinePath([(1.0, 2.0), (1.0, 2.0)])
    assert d.length == 0.0
    np.testing.assert_allclose(d.point_at(3.0), [1, 2])
    assert d.heading_at(0.0) == 0.0
    assert d.project(np.array([5.0, 5.0])) == 0.0


def test_virtual_leader():
    p = PolylinePath(L_PATH)
    pose, vel, done = virtual_leader(p, 0.5, 1.0, start_delay=2.0)  # still waiting
    np.testing.assert_allclose(pose, [0, 0, 0])
    np.testing.assert_allclose(vel, [0, 0])
    assert not done
    pose, vel, done = virtual_leader(p, 0.5, 4.0, start_delay=2.0)  # 1 m along
    np.testing.assert_allclose(pose, [1, 0, 0])
    np.testing.assert_allclose(vel, [0.5, 0])
    pose, vel, done = virtual_leader(p, 0.5, 12.0, start_delay=2.0)  # 5 m: on the second leg
    np.testing.assert_allclose(pose, [3, 2, math.pi / 2])
    np.testing.assert_allclose(vel, [0, 0.5], atol=1e-12)
    assert not done
    pose, vel, done = virtual_leader(p, 0.5, 30.0, start_delay=2.0)
    np.testing.assert_allclose(pose, [3, 4, math.pi / 2])
    np.testing.assert_allclose(vel, [0, 0])
    assert done


# A 2 m leg east then a 2 m leg north; loop closes with a 2*sqrt(2) m diagonal.
H_PATH = ((0.0, 0.0), (2.0, 0.0), (2.0, 2.0))


def test_human_once():
    h = HumanSpec(path=H_PATH, speed=1.0, mode="once", start_delay=1.0)
    pos, vel = human_states([h], 0.5)
    np.testing.assert_allclose(pos, [[0, 0]])
    np.testing.assert_allclose(vel, [[0, 0]])
    pos, vel = human_states([h], 2.0)
    np.testing.assert_allclose(pos, [[1, 0]])
    np.testing.assert_allclose(vel, [[1, 0]])
    pos, vel = human_states([h], 4.0)
    np.testing.assert_allclose(pos, [[2, 1]])
    np.testing.assert_allclose(vel, [[0, 1]], atol=1e-12)
    pos, vel = human_states([h], 10.0)
    np.testing.assert_allclose(pos, [[2, 2]])
    np.testing.assert_allclose(vel, [[0, 0]])


def test_human_loop_walks_closing_segment():
    h = HumanSpec(path=H_PATH, speed=1.0, mode="loop")
    loop = 4.0 + 2.0 * math.sqrt(2.0)
    pos, vel = human_states([h], 4.0 + math.sqrt(2.0))  # middle of the closing diagonal
    np.testing.assert_allclose(pos, [[1, 1]], atol=1e-12)
    np.testing.assert_allclose(vel, [[-math.sqrt(0.5), -math.sqrt(0.5)]])
    pos, _ = human_states([h], loop + 1.0)  # second lap
    np.testing.assert_allclose(pos, [[1, 0]], atol=1e-9)


def test_human_pingpong():
    h = HumanSpec(path=H_PATH, speed=0.5, mode="pingpong")
    pos, vel = human_states([h], 6.0)  # 3 m: on the way out
    np.testing.assert_allclose(pos, [[2, 1]])
    np.testing.assert_allclose(vel, [[0, 0.5]], atol=1e-12)
    pos, vel = human_states([h], 10.0)  # 5 m: 1 m back from the end
    np.testing.assert_allclose(pos, [[2, 1]])
    np.testing.assert_allclose(vel, [[0, -0.5]], atol=1e-12)
    pos, vel = human_states([h], 12.0)  # 6 m: exactly at the corner on the way back
    np.testing.assert_allclose(pos, [[2, 0]], atol=1e-12)
    np.testing.assert_allclose(vel, [[-0.5, 0]], atol=1e-12)  # leaving the corner westwards
    pos, vel = human_states([h], 17.0)  # 8.5 m = period + 0.5 m: out again
    np.testing.assert_allclose(pos, [[0.5, 0]], atol=1e-9)
    np.testing.assert_allclose(vel, [[0.5, 0]], atol=1e-12)


def test_human_states_is_pure_and_vectorised():
    hs = [
        HumanSpec(path=H_PATH, speed=1.0, mode="once"),
        HumanSpec(path=H_PATH, speed=0.7, mode="loop", start_delay=2.0),
        HumanSpec(path=((5.0, 5.0), (5.0, 5.0)), speed=1.0),  # zero-length path: stands
    ]
    a = human_states(hs, 3.3)
    human_states(hs, 100.0)
    b = human_states(hs, 3.3)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    assert a[0].shape == (3, 2) and a[1].shape == (3, 2)
    np.testing.assert_allclose(a[0][2], [5, 5])
    one = human_states(hs[1:2], 3.3)
    np.testing.assert_array_equal(one[0][0], a[0][1])
    empty = human_states([], 1.0)
    assert empty[0].shape == (0, 2) and empty[1].shape == (0, 2)


def test_human_velocity_matches_finite_difference():
    verts = np.array([(0.0, 0.0), (3.0, 1.0), (1.0, 4.0)])
    h = HumanSpec(path=tuple(map(tuple, verts)), speed=0.8, mode="pingpong", start_delay=0.5)
    dt = 1e-6
    for t in np.linspace(0.7, 30.0, 61):
        p0, v = human_states([h], t)
        p1, _ = human_states([h], t + dt)
        assert np.linalg.norm(v[0]) == pytest.approx(0.8)
        near_vertex = np.min(np.linalg.norm(verts - p0[0], axis=1)) < 1e-5
        if not near_vertex:
            np.testing.assert_allclose((p1 - p0) / dt, v, atol=1e-4)
