"""Tests for swarm_env.geometry.formation: slot offsets, schedule, slot targets."""

from __future__ import annotations

import math

import numpy as np
import pytest

from swarm_env.geometry.formation import active_formation, formation_offsets, next_switch_time, slot_targets
from swarm_env.geometry.static_map import StaticMap
from swarm_env.scenario import CircleObstacle, FormationSpec, RectangleObstacle

GENERATED = ["v", "line", "column", "wedge", "diamond", "circle", "grid"]


def _check_spacing(off: np.ndarray, n: int, spacing: float) -> None:
    assert off.shape == (n, 2)
    assert np.all(np.isfinite(off))
    # none at (or closer than spacing to) the leader
    assert np.min(np.linalg.norm(off, axis=1)) >= spacing * 0.99
    if n > 1:
        d = np.linalg.norm(off[:, None, :] - off[None, :, :], axis=2)
        d[np.arange(n), np.arange(n)] = np.inf
        assert d.min() >= spacing * 0.99


@pytest.mark.parametrize("shape", GENERATED)
@pytest.mark.parametrize("n", [1, 2, 3, 4, 5, 7, 8, 9, 12, 16])
def test_shapes_distinct_and_spaced(shape, n):
    for spacing in (0.6, 1.5):
        off = formation_offsets(FormationSpec(at=0.0, shape=shape, spacing=spacing), n)
        _check_spacing(off, n, spacing)


@pytest.mark.parametrize("shape", ["v", "wedge"])
@pytest.mark.parametrize("angle", [10.0, 25.0, 45.0, 60.0, 75.0, 89.0, 120.0, 170.0])
def test_v_and_wedge_spacing_for_any_angle(shape, angle):
    for n in (2, 5, 9, 14):
        off = formation_offsets(FormationSpec(at=0.0, shape=shape, spacing=1.0, angle=angle), n)
        _check_spacing(off, n, 1.0)


def test_v_matches_paper_eqs_5_6():
    d, phi_deg = 1.2, 40.0
    phi = math.radians(phi_deg)
    off = formation_offsets(FormationSpec(at=0.0, shape="v", spacing=d, angle=phi_deg), 6)
    xl, yl, th = 3.0, -2.0, 0.7
    world = slot_targets(np.array([xl, yl, th]), off, None, 0.0)
    for k in range(6):
        dk = d * math.ceil((k + 1) / 2)
        # Eq. 5-6: x_T = x_L - d cos(theta_L + phi), y_T = y_L - d sin(theta_L + phi);
        # +phi is the right arm (odd k), -phi the left arm (even k).
        sgn = -1.0 if k % 2 == 0 else 1.0
        expect = [xl - dk * math.cos(th + sgn * phi), yl - dk * math.sin(th + sgn * phi)]
        np.testing.assert_allclose(world[k], expect, atol=1e-12)
    # leader frame: left arm has y > 0
    assert off[0, 1] > 0 > off[1, 1]


def test_line_column_grid_layout():
    s = 0.8
    line = formation_offsets(FormationSpec(0.0, "line", spacing=s), 3)
    np.testing.assert_allclose(line, [[-s, s], [-s, 0], [-s, -s]])
    col = formation_offsets(FormationSpec(0.0, "column", spacing=s), 3)
    np.testing.assert_allclose(col, [[-s, 0], [-2 * s, 0], [-3 * s, 0]])
    grid = formation_offsets(FormationSpec(0.0, "grid", spacing=1.0, columns=2), 5)
    np.testing.assert_allclose(grid, [[-1, 0.5], [-1, -0.5], [-2, 0.5], [-2, -0.5], [-3, 0]])
    auto = formation_offsets(FormationSpec(0.0, "grid", spacing=1.0), 9)  # 3 x 3
    assert sorted(set(auto[:, 0])) == [-3.0, -2.0, -1.0]


def test_diamond_and_circle_layout():
    a = 1.0 / math.sqrt(2.0)
    dia = formation_offsets(FormationSpec(0.0, "diamond", spacing=1.0), 3)
    np.testing.assert_allclose(dia, [[-a, a], [-a, -a], [-2 * a, 0]], atol=1e-12)
    circ = formation_offsets(FormationSpec(0.0, "circle", spacing=1.0), 8)
    r = np.linalg.norm(circ, axis=1)
    np.testing.assert_allclose(r, r[0])
    np.testing.assert_allclose(circ[0], [-r[0], 0.0], atol=1e-12)  # slot 0 directly behind


def test_custom_and_errors():
    offs = ((-1.0, 0.5), (-1.0, -0.5))
    np.testing.assert_allclose(formation_offsets(FormationSpec(0.0, "custom", offsets=offs), 2), offs)
    with pytest.raises(ValueError):
        formation_offsets(FormationSpec(0.0, "custom", offsets=offs), 3)
    with pytest.raises(ValueError):
        formation_offsets(FormationSpec(0.0, "custom"), 2)
    with pytest.raises(ValueError):
        formation_offsets(FormationSpec(0.0, "hexagon"), 2)
    with pytest.raises(ValueError):
        formation_offsets(FormationSpec(0.0, "v", spacing=-1.0), 2)
    with pytest.raises(ValueError):
        formation_offsets(FormationSpec(0.0, "v", angle=0.0), 2)


def test_offsets_returned_as_fresh_copies():
    spec = FormationSpec(0.0, "v")
    a = formation_offsets(spec, 4)
    a[:] = 0.0  # caller may scribble on its copy
    b = formation_offsets(spec, 4)
    assert np.all(np.linalg.norm(b, axis=1) > 0.5)
    assert formation_offsets(spec, 0).shape == (0, 2)


def test_schedule():
    sched = [FormationSpec(0.0, "v"), FormationSpec(80.0, "line"), FormationSpec(120.0, "column")]
    assert active_formation(sched, 0.0) == 0
    assert active_formation(sched, 79.99) == 0
    assert active_formation(sched, 80.0) == 1
    assert active_formation(sched, 500.0) == 2
    assert next_switch_time(sched, 0.0) == 80.0
    assert next_switch_time(sched, 80.0) == 120.0
    assert next_switch_time(sched, 120.0) == math.inf
    late = [FormationSpec(5.0, "v"), FormationSpec(10.0, "line")]
    assert active_formation(late, 1.0) == 0  # none started yet: the first
    with pytest.raises(ValueError):
        active_formation([], 1.0)


def test_slot_targets_rotation_and_projection():
    static = StaticMap.from_obstacles(
        (20.0, 20.0), [RectangleObstacle(center=(10.0, 8.0), size=(2.0, 2.0)), CircleObstacle((4.0, 4.0), 1.0)]
    )
    off = np.array([[-2.0, 0.0], [0.0, 2.0], [-1.0, -1.0]])
    # Leader at (10, 10) heading north: slot 0 (2 m behind) lands at (10, 8), inside the rectangle.
    pose = np.array([10.0, 10.0, math.pi / 2])
    raw = slot_targets(pose, off, None, 0.3)
    np.testing.assert_allclose(raw, [[10, 8], [8, 10], [11, 9]], atol=1e-12)
    got = slot_targets(pose, off, static, 0.3)
    np.testing.assert_allclose(got[1], raw[1])  # free slot untouched
    assert static.distance(got[0:1])[0] >= 0.3 - 1e-9  # moved out with clearance
    assert static.distance(got[2:3])[0] >= 0.3 - 1e-9
    # nearest free point: the rectangle's nearest face is 1 m away, plus the clearance
    assert np.linalg.norm(got[0] - raw[0]) == pytest.approx(1.3, abs=1e-6)
    # a slot beyond a wall is pulled inside the world
    edge = slot_targets(np.array([0.5, 10.0, 0.0]), np.array([[-2.0, 0.0]]), static, 0.3)
    np.testing.assert_allclose(edge[0], [0.3, 10.0], atol=1e-6)
