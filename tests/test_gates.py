"""Gates (swarm_env.scenarios.gates): walls with a door across the leader's path, filed through as a column."""

from __future__ import annotations

import math

import numpy as np
import pytest

from swarm_env.geometry.formation import (
    SLOT_MARGIN,
    active_formation,
    formation_offsets,
    reach_time,
    unprojected_slot_trajectory,
)
from swarm_env.geometry.paths import PolylinePath
from swarm_env.geometry.static_map import StaticMap
from swarm_env.scenario import FormationSpec, RectangleObstacle, ScenarioError, WorldSpec
from swarm_env.scenarios.families import FAMILIES
from swarm_env.scenarios.gates import GateLayout, gate_schedule, place_gates
from swarm_env.scenarios.generator import config_from_kwargs, random_scenario, slot_speed_violations
from swarm_env.scenarios.loader import scenario_from_dict, scenario_to_dict, start_poses

V = FormationSpec(at=0.0, shape="v", spacing=1.0, angle=45.0)


def _layout(**over) -> GateLayout:
    kw = dict(size=(30.0, 30.0), radius=0.25, leader_speed=0.4, max_speed=0.65, leader_clear=0.5, reach=3.0,
              width=(1.0, 1.6), depth=(0.3, 3.0), keep=(np.zeros((0, 2)), np.zeros(0)), end=100.0)
    kw.update(over)
    return GateLayout(**kw)  # type: ignore[arg-type]


def _door(a: RectangleObstacle, b: RectangleObstacle) -> tuple[np.ndarray, np.ndarray, float, tuple[float, float]]:
    """A gate's frame from its two walls (left, right): along, normal, depth, (right inner edge, left inner edge)
    as offsets along ``normal`` from the origin."""
    th = math.radians(a.angle)
    u, n = np.array([math.cos(th), math.sin(th)]), np.array([-math.sin(th), math.cos(th)])
    left = float(n @ np.asarray(a.center)) - a.size[1] / 2.0
    right = float(n @ np.asarray(b.center)) + b.size[1] / 2.0
    return u, n, a.size[0], (right, left)


def test_gates_on_a_straight_path_stand_across_it_with_a_door_on_it() -> None:
    line = PolylinePath([(2.0, 15.0), (28.0, 15.0)])
    gates = place_gates(np.random.default_rng(0), line, 2, V, 4, _layout())
    assert len(gates) == 2
    for g in gates:
        a, b = g.walls
        assert a.angle == b.angle == 0.0  # across a path heading +x
        u, n, depth, (right, left) = _door(a, b)
        assert depth == g.depth and 0.3 <= depth <= 3.0
        assert left - right == pytest.approx(g.width, abs=2e-3) and 1.0 <= g.width <= 1.6
        assert right < 15.0 < left  # the door is on the path
        assert a.center[0] == pytest.approx(line.point_at(g.s)[0], abs=1e-3)
        # the walls reach a metre beyond the V's widest slot disc
        widest = float(np.max(np.hypot(*formation_offsets(V, 4).T)))
        assert a.size[1] + g.width / 2 == pytest.approx(widest + 0.25 + 1.0, abs=2e-3)
        # the column is ordered before the door, early enough to be reached 3 times over, and released after
        # its last slot (4 x 1 m behind the leader) is past the far face
        column = formation_offsets(FormationSpec(at=0.0, shape="column", spacing=1.0), 4)
        need = 3.0 * reach_time(formation_offsets(V, 4), column, 0.4, 0.65, WorldSpec.settle_tolerance)
        assert (g.s - depth / 2 - g.order) / 0.4 >= need
        assert g.release - (g.s + depth / 2) >= 4.0 + 0.3
    a, b = sorted(gates, key=lambda g: g.s)
    assert b.s - b.depth / 2 - (0.3 + 0.5) - 0.5 >= a.release  # door stretches apart (the column whole 0.8 m before)


def test_the_schedule_orders_a_column_per_gate_merges_close_ones_and_keeps_one_it_cannot_leave() -> None:
    line = PolylinePath([(2.0, 15.0), (28.0, 15.0)])
    layout = _layout()
    gates = place_gates(np.random.default_rng(3), line, 2, V, 4, layout)
    assert len(gates) == 2
    sched = gate_schedule(V, gates, 4, layout, 0.1)
    shapes = [f.shape for f in sched]
    assert shapes[0] == "v" and shapes[1] == "column" and all(f.spacing == 1.0 for f in sched)
    assert all(x != y for x, y in zip(shapes, shapes[1:]))
    assert all(a.at < b.at for a, b in zip(sched, sched[1:]))
    first = min(gates, key=lambda g: g.order)
    assert sched[1].at <= first.order / 0.4 and sched[1].at > first.order / 0.4 - 0.1
    # the leader is never inside a door's stretch (plus the column behind it) without the column
    for g in gates:
        for s in np.arange(g.s - g.depth / 2, g.release, 0.05):
            assert sched[active_formation(sched, s / 0.4)].shape == "column"
    # no time to settle back before the end: the column stays
    kept = gate_schedule(V, gates, 4, _layout(end=max(g.release for g in gates) / 0.4 + 1.0), 0.1)
    assert kept[-1].shape == "column"
    # a column formation needs no switch
    assert gate_schedule(FormationSpec(at=0.0, shape="column", spacing=1.0), gates, 4, layout, 0.1) == [
        FormationSpec(at=0.0, shape="column", spacing=1.0)]


def test_no_room_means_fewer_gates_never_a_loop() -> None:
    short = PolylinePath([(2.0, 15.0), (6.0, 15.0)])  # too short for a V to become a column before a door
    assert place_gates(np.random.default_rng(0), short, 3, V, 4, _layout()) == []
    line = PolylinePath([(2.0, 15.0), (28.0, 15.0)])
    starts = np.array([[10.0, 15.0]])  # a robot the walls must keep 5 m from: no gate fits where it can go
    layout = _layout(keep=(starts, np.array([30.0])))
    assert place_gates(np.random.default_rng(0), line, 2, V, 4, layout) == []


@pytest.mark.parametrize("seed", range(12))
def test_narrow_worlds_file_through_every_door_as_a_column(seed: int) -> None:
    cfg = FAMILIES["narrow"].config()
    scn = random_scenario(np.random.default_rng(seed), cfg)
    assert scenario_from_dict(scenario_to_dict(scn), scn.source) == scn
    assert len(slot_speed_violations(scn)) == 0
    gates = int(scn.description.split(" gates")[0].rsplit(", ", 1)[-1])
    walls = scn.obstacles[:2 * gates]  # the gates' walls come first
    assert gates <= 2 and all(isinstance(w, RectangleObstacle) for w in walls)
    steps = int(scn.world.max_time / scn.world.dt)
    slots, index = unprojected_slot_trajectory(scn, steps)
    clear = scn.robots.radius + SLOT_MARGIN
    static = StaticMap.from_obstacles(scn.world.size, scn.obstacles)
    starts = start_poses(scn)[:, :2]
    assert static.distance(starts, walls=False).min() >= scn.robots.radius + 0.3 - 1e-9
    for j in range(gates):
        a, b = walls[2 * j], walls[2 * j + 1]
        u, n, depth, (right, left) = _door(a, b)
        assert 1.0 - 2e-3 <= left - right <= 1.6 + 2e-3
        along = (slots - np.asarray(a.center)) @ u
        across = slots @ n
        in_door = (np.abs(along) <= depth / 2 + clear) & (across > right - clear) & (across < left + clear)
        k_in = np.flatnonzero(in_door.any(axis=1))
        assert len(k_in)  # the formation goes through the door
        for k in k_in:  # every slot target in a door belongs to a column, and fits through it
            assert scn.formations[index[k]].shape == "column"
        pts = slots[in_door]
        wall_map = StaticMap.from_obstacles(scn.world.size, [a, b])
        assert wall_map.obstacle_distances(pts).min() >= clear - 1e-9
    for h in scn.humans:  # walkers keep clear of the walls (and of the doors: see gates.Gate.footprint)
        hp = PolylinePath(h.path)
        assert static.distance(hp.points_at(np.linspace(0, hp.length, 100)), walls=False).min() >= h.radius + 0.2


def test_most_narrow_worlds_get_a_gate_and_other_knobs_draw_no_gate() -> None:
    cfg = FAMILIES["narrow"].config()
    descriptions = [random_scenario(np.random.default_rng(s), cfg).description for s in range(30)]
    assert sum(" 0 gates" not in d for d in descriptions) >= 27
    assert "gates" not in random_scenario(np.random.default_rng(0)).description


@pytest.mark.parametrize("knobs, key", [
    ({"n_gates": 1, "n_switches": (0, 1)}, "n_switches"),
    ({"n_gates": 1, "n_switches": 0, "gate_width": (0.5, 1.0)}, "gate_width"),
    ({"n_gates": 9, "n_switches": 0}, "n_gates"),
    ({"n_gates": 1, "n_switches": 0, "gate_depth": (0.0, 1.0)}, "gate_depth"),
])
def test_bad_gate_knobs(knobs: dict, key: str) -> None:
    with pytest.raises(ScenarioError) as err:
        config_from_kwargs(**knobs)
    assert err.value.key == key
