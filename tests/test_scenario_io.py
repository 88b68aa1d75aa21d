"""Scenario files: built-ins, round trips, and loud failures with file + key path."""

from __future__ import annotations

import copy
import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from swarm_env.geometry.formation import formation_offsets, slot_targets
from swarm_env.geometry.paths import PolylinePath, human_states, virtual_leader
from swarm_env.geometry.static_map import StaticMap
from swarm_env.scenario import PolygonObstacle, RewardSpec, Scenario, ScenarioError
from swarm_env.scenarios.loader import (
    BUILTIN_DIR,
    list_scenarios,
    load_scenario,
    min_substeps,
    scenario_from_dict,
    scenario_to_dict,
    start_poses,
)

BUILTINS = ["corridor", "crowd_reactive", "paper_cbs_switch", "paper_vo_0", "paper_vo_45", "paper_vo_90"]


def _minimal() -> dict:
    return {
        "world": {"size": [20, 14]},
        "robots": {"count": 2},
        "leader": {"kind": "robot", "path": [[2, 7], [17, 7]], "speed": 0.5},
        "formations": [{"at": 0.0, "shape": "v", "spacing": 1.2, "angle": 45}],
        "obstacles": [{"type": "circle", "center": [8, 11], "radius": 0.5}],
        "humans": [{"path": [[14, 10], [4, 10]]}],
    }


# --------------------------------------------------------------------------- built-ins


def test_list_scenarios_has_builtins_and_random() -> None:
    names = list_scenarios()
    assert names == sorted(names)
    assert set(BUILTINS) | {"random"} == set(names)
    assert {p.stem for p in BUILTIN_DIR.glob("*.yaml")} == set(BUILTINS)


@pytest.mark.parametrize("name", BUILTINS)
def test_builtin_loads_and_round_trips(name: str, tmp_path: Path) -> None:
    scn = load_scenario(name)
    assert isinstance(scn, Scenario)
    assert scn.name == name and scn.description
    assert scn.source.endswith(f"{name}.yaml")
    assert scn.world.substeps >= min_substeps(scn)
    data = scenario_to_dict(scn)
    assert scenario_from_dict(data, scn.source) == scn
    # ... and through a YAML file written by safe_dump (what a user saves).
    out = tmp_path / f"{name}_copy.yaml"
    out.write_text(yaml.safe_dump(data, sort_keys=False))
    again = load_scenario(out)
    assert dataclasses.replace(again, source=scn.source, name=scn.name) == scn
    assert load_scenario(str(out)) == again


@pytest.mark.parametrize("name", BUILTINS)
def test_builtin_layout_is_sound(name: str) -> None:
    """Leader paths avoid obstacles, humans walk in free space, starting slots are free."""
    scn = load_scenario(name)
    static = StaticMap.from_obstacles(scn.world.size, scn.obstacles)
    path = PolylinePath(scn.leader.path)
    pts = path.points_at(np.linspace(0.0, path.length, 2000))
    need = scn.leader.radius + 0.3 if scn.leader.kind == "robot" else 0.5
    assert static.distance(pts, walls=False).min() >= need
    assert static.wall_distance(pts).min() >= (scn.leader.radius if scn.leader.kind == "robot" else 0.0)
    for h in scn.humans:
        hp = PolylinePath(h.path)
        hpts = hp.points_at(np.linspace(0.0, hp.length, 500))
        assert static.distance(hpts, walls=False).min() >= h.radius + 0.2
    starts = start_poses(scn)
    assert starts.shape == (scn.robots.count, 3)
    assert static.distance(starts[:, :2]).min() >= scn.robots.radius


@pytest.mark.parametrize("name, direction", [("paper_vo_0", 180.0), ("paper_vo_45", 135.0), ("paper_vo_90", 90.0)])
def test_paper_vo_humans_meet_the_formation_half_way(name: str, direction: float) -> None:
    scn = load_scenario(name)
    assert scn.leader.kind == "robot" and scn.leader.speed == 0.5 and scn.robots.count == 2
    assert scn.robots.max_speed == 0.65 and scn.world.dt == 0.1
    assert len(scn.obstacles) == 2 and len(scn.humans) == 2
    for h in scn.humans:
        d = np.subtract(h.path[-1], h.path[0])
        assert math.degrees(math.atan2(d[1], d[0])) == pytest.approx(direction, abs=0.5)
    # Half-way (t = 13-16 s, x ~ 8.5-10) the humans' centre passes within 0.6 m of the nominal leader.
    times = np.arange(10.0, 20.0, 0.1)
    gaps = []
    for t in times:
        pos, _ = human_states(scn.humans, t)
        lead, _, _ = virtual_leader(PolylinePath(scn.leader.path), scn.leader.speed, t)
        gaps.append(np.linalg.norm(pos.mean(axis=0) - lead[:2]))
    assert min(gaps) < 0.6
    assert 13.0 <= times[int(np.argmin(gaps))] <= 16.0
    # The three files differ only in the humans.
    base = scenario_to_dict(load_scenario("paper_vo_0"))
    mine = scenario_to_dict(scn)
    for key in ("world", "robots", "leader", "formations", "obstacles", "sensors", "reward"):
        assert mine[key] == base[key]


def test_paper_vo_obstacles_block_follower_tracks_not_leader() -> None:
    scn = load_scenario("paper_vo_0")
    static = StaticMap.from_obstacles(scn.world.size, scn.obstacles)
    path = PolylinePath(scn.leader.path)
    off = formation_offsets(scn.formations[0], 2)
    blocked = set()
    for t in np.arange(0.0, 30.0, 0.1):
        pose, _, _ = virtual_leader(path, scn.leader.speed, t)
        slots = slot_targets(pose, off, None, 0.0)
        blocked |= set(np.flatnonzero(static.distance(slots, walls=False) < scn.robots.radius).tolist())
    assert blocked == {0, 1}  # each follower has to deviate once


def test_paper_cbs_switch_matches_fig2() -> None:
    scn = load_scenario("paper_cbs_switch")
    assert scn.leader.kind == "virtual" and scn.robots.count == 8 and len(scn.obstacles) == 10
    assert {o.type for o in scn.obstacles} == {"circle", "rectangle"}
    assert [f.at for f in scn.formations] == [0.0, 80.0]
    assert scn.formations[0].shape != scn.formations[1].shape
    assert scn.world.dt == 0.5 and scn.world.substeps == 4 and scn.world.max_time == 240.0
    path = PolylinePath(scn.leader.path)
    assert 170.0 <= path.length / scn.leader.speed <= 210.0
    assert "167" in scn.description and "80" in scn.description
    # Every obstacle swallows some nominal slot at some time (the "gray regions" matter).
    static = StaticMap.from_obstacles(scn.world.size, scn.obstacles)
    hit = set()
    for t in np.arange(0.0, 200.0, 0.5):
        pose, _, _ = virtual_leader(path, scn.leader.speed, t)
        f = scn.formations[1] if t >= 80.0 else scn.formations[0]
        slots = slot_targets(pose, formation_offsets(f, 8), None, 0.0)
        d = static.obstacle_distances(slots)
        hit |= set(np.flatnonzero((d < scn.robots.radius).any(axis=0)).tolist())
    assert hit == set(range(10))


def test_corridor_gap_is_narrower_than_the_formation() -> None:
    scn = load_scenario("corridor")
    assert scn.robots.count == 4
    shapes = [f.shape for f in scn.formations]
    assert shapes[1] == "column" and shapes[0] == shapes[2] != "column"
    static = StaticMap.from_obstacles(scn.world.size, scn.obstacles)
    # Free vertical extent at the wall's x: the gap.
    ys = np.linspace(0.0, scn.world.size[1], 2401)
    free = static.distance(np.column_stack([np.full_like(ys, 12.0), ys]), walls=False) > 0
    gap = free.sum() * (ys[1] - ys[0])
    v = formation_offsets(scn.formations[0], 4)
    width = v[:, 1].max() - v[:, 1].min() + 2 * scn.robots.radius
    assert 1.4 < gap < width
    # The column switch happens before the leader reaches the wall, the V after the last slot passed it.
    path = PolylinePath(scn.leader.path)
    t_wall = (11.7 - scn.leader.path[0][0]) / scn.leader.speed
    assert scn.formations[1].at < t_wall
    col = formation_offsets(scn.formations[1], 4)
    lead_x = scn.leader.path[0][0] + scn.leader.speed * scn.formations[2].at
    assert lead_x + col[:, 0].min() > 12.3 + scn.robots.radius
    assert path.length / scn.leader.speed < scn.world.max_time


# --------------------------------------------------------------------------- load_scenario entry points


def test_load_random_is_refused_with_a_pointer() -> None:
    with pytest.raises(ScenarioError, match="random_scenario"):
        load_scenario("random")


def test_unknown_name_lists_builtins() -> None:
    with pytest.raises(ScenarioError) as err:
        load_scenario("no_such_scenario")
    assert "paper_vo_0" in str(err.value) and err.value.key == "<file>"


def test_mapping_and_scenario_inputs() -> None:
    scn = load_scenario(_minimal())
    assert scn.source == "<dict>" and scn.name == "custom"
    assert load_scenario(scn) is scn
    assert scn.robots.max_speed == 0.65 and scn.humans[0].mode == "once"


def test_name_defaults_to_file_stem(tmp_path: Path) -> None:
    path = tmp_path / "my_map.yaml"
    path.write_text(yaml.safe_dump(_minimal()))
    assert load_scenario(path).name == "my_map"


def test_polygon_is_stored_counter_clockwise() -> None:
    data = _minimal()
    data["obstacles"] = [{"type": "polygon", "points": [[4, 4], [4.5, 5], [5, 4]]}]  # clockwise
    (ob,) = scenario_from_dict(data).obstacles
    assert isinstance(ob, PolygonObstacle)
    p = np.array(ob.points)
    area2 = np.dot(p[:, 0], np.roll(p[:, 1], -1)) - np.dot(np.roll(p[:, 0], -1), p[:, 1])
    assert area2 > 0


def test_empty_optional_sections_take_defaults() -> None:
    text = yaml.safe_dump(_minimal()) + "sensors:\nreward:\n"
    scn = scenario_from_dict(yaml.safe_load(text))
    assert scn.sensors.lidar_rays == 16 and scn.reward == RewardSpec()


def test_numpy_values_are_accepted() -> None:
    data = _minimal()
    data["world"]["size"] = np.array([20.0, 14.0])
    data["robots"]["count"] = np.int64(2)
    scn = scenario_from_dict(data)
    assert scn.world.size == (20.0, 14.0) and type(scn.robots.count) is int


# --------------------------------------------------------------------------- failures


def _set(path: str, value):
    def edit(d: dict) -> None:
        keys = path.split(".")
        for k in keys[:-1]:
            d = d[int(k)] if isinstance(d, list) else d[k]
        last = keys[-1]
        if isinstance(d, list):
            d[int(last)] = value
        else:
            d[last] = value

    return edit


def _delete(path: str):
    def edit(d: dict) -> None:
        keys = path.split(".")
        for k in keys[:-1]:
            d = d[k]
        del d[keys[-1]]

    return edit


def _add_formation(entry: dict):
    def edit(d: dict) -> None:
        d["formations"].append(entry)

    return edit


BAD_CASES = [
    ("unknown_key", _set("robots.max_sped", 0.5), "robots.max_sped", "max_speed"),
    ("unknown_section", _set("robot", {}), "robot", "formations"),
    ("wrong_type", _set("robots.radius", "big"), "robots.radius", "positive number"),
    ("bool_number", _set("world.dt", True), "world.dt", "number"),
    ("bool_int", _set("robots.count", True), "robots.count", "integer"),
    ("float_int", _set("world.substeps", 4.0), "world.substeps", "integer"),
    ("exponent_text", _set("world.max_time", "1e3"), "world.max_time", "1.0e3"),
    ("non_finite", _set("world.max_time", float("inf")), "world.max_time", "finite"),
    ("nan", _set("leader.speed", float("nan")), "leader.speed", "finite"),
    ("negative_speed", _set("leader.speed", -0.5), "leader.speed", "positive"),
    ("zero_radius", _set("robots.radius", 0), "robots.radius", "positive"),
    ("zero_size", _set("world.size", [20, 0]), "world.size[1]", "positive"),
    ("size_len", _set("world.size", [20]), "world.size", "[x, y]"),
    ("zero_count", _set("robots.count", 0), "robots.count", ">= 1"),
    ("missing_section", _delete("leader"), "leader", "required"),
    ("missing_key", _delete("leader.speed"), "leader.speed", "required"),
    ("missing_size", _delete("world.size"), "world.size", "required"),
    ("leader_kind", _set("leader.kind", "drone"), "leader.kind", "virtual"),
    ("path_one_point", _set("leader.path", [[2, 7]]), "leader.path", "at least 2"),
    ("path_outside", _set("leader.path", [[2, 7], [25, 7]]), "leader.path[1]", "inside the world"),
    ("path_disc_outside", _set("leader.path", [[2, 7], [19.9, 7]]), "leader.path[1]", "radius"),
    ("path_repeat", _set("leader.path", [[2, 7], [2, 7], [9, 7]]), "leader.path[1]", "different"),
    ("leader_faster", _set("leader.speed", 0.8), "leader.speed", "max_speed"),
    ("start_len", _set("robots.start", [[1, 1, 0]]), "robots.start", "one [x, y, theta] pose per follower"),
    ("start_word", _set("robots.start", "line"), "robots.start", "formation"),
    ("start_outside", _set("robots.start", [[1, 1, 0], [30, 1, 0]]), "robots.start[1]", "inside the world"),
    ("start_overlap", _set("robots.start", [[5, 5, 0], [5.3, 5, 0]]), "robots.start[1]", "overlapping"),
    ("start_in_obstacle", _set("robots.start", [[8, 11, 0], [5, 5, 0]]), "robots.start[0]", "obstacles"),
    ("slot_in_obstacle", _set("obstacles.0.center", [1.15, 7.85]), "robots.start", "obstacles"),
    ("slot_outside", _set("leader.path", [[0.5, 7], [17, 7]]), "robots.start", "inside the world"),
    ("first_at", _set("formations.0.at", 1.0), "formations[0].at", "0.0"),
    ("at_order", _add_formation({"at": 0.0, "shape": "line"}), "formations[1].at", "strictly after"),
    ("no_formations", _set("formations", []), "formations", "at least one"),
    ("unknown_shape", _set("formations.0.shape", "triangle"), "formations[0].shape", "'wedge'"),
    ("custom_missing", _add_formation({"at": 5.0, "shape": "custom"}), "formations[1].offsets", "required"),
    ("custom_count", _add_formation({"at": 5.0, "shape": "custom", "offsets": [[-1, 1]]}), "formations[1].offsets", "one [x, y] offset per follower"),
    ("custom_overlap", _add_formation({"at": 5.0, "shape": "custom", "offsets": [[-1, 0], [-1.2, 0]]}), "formations[1].offsets", "apart"),
    ("offsets_on_v", _set("formations.0.offsets", [[-1, 1], [-1, -1]]), "formations[0].offsets", "custom"),
    ("columns_on_v", _set("formations.0.columns", 2), "formations[0].columns", "grid"),
    ("spacing_tight", _set("formations.0.spacing", 0.3), "formations[0].spacing", "apart"),
    ("angle_range", _set("formations.0.angle", 180), "formations[0].angle", "within [1, 179]"),
    ("wedge_90", _set("formations.0", {"at": 0.0, "shape": "wedge", "angle": 90}), "formations[0].angle", "90"),
    ("obstacle_type", _set("obstacles.0", {"type": "triangle"}), "obstacles[0].type", "polygon"),
    ("obstacle_no_type", _set("obstacles.0", {"center": [1, 1]}), "obstacles[0].type", "required"),
    ("obstacle_key", _set("obstacles.0.size", [1, 1]), "obstacles[0].size", "center, radius"),
    ("rect_size", _set("obstacles.0", {"type": "rectangle", "center": [8, 11], "size": [1, -2]}), "obstacles[0].size[1]", "positive"),
    ("polygon_two_points", _set("obstacles.0", {"type": "polygon", "points": [[4, 4], [5, 4]]}), "obstacles[0].points", "at least 3"),
    ("polygon_non_convex", _set("obstacles.0", {"type": "polygon", "points": [[4, 4], [6, 4], [5, 5], [6, 6], [4, 6]]}), "obstacles[0].points", "convex"),
    ("polygon_flat", _set("obstacles.0", {"type": "polygon", "points": [[4, 4], [5, 4], [6, 4]]}), "obstacles[0].points", "area"),
    ("obstacle_outside", _set("obstacles.0.center", [30, 11]), "obstacles[0].center", "inside the world"),
    ("human_mode", _set("humans.0.mode", "run"), "humans[0].mode", "pingpong"),
    ("human_speed", _set("humans.0.speed", 0), "humans[0].speed", "positive"),
    ("human_path", _set("humans.0.path", [[14, 10], [24, 10]]), "humans[0].path[1]", "inside the world"),
    ("human_on_leader", _set("humans.0.path", [[2.2, 7], [4, 10]]), "humans[0].path[0]", "robot leader"),
    ("sensor_rays", _set("sensors", {"lidar_rays": 0}), "sensors.lidar_rays", ">= 1"),
    ("sensor_neg", _set("sensors", {"neighbors": -1}), "sensors.neighbors", ">= 0"),
    ("sensor_key", _set("sensors", {"lidar": 3}), "sensors.lidar", "lidar_rays"),
    ("reward_neg", _set("reward", {"collision": -1}), "reward.collision", "non-negative"),
    ("substeps_low", _set("world", {"size": [20, 14], "dt": 1.0, "substeps": 1}), "world.substeps", "at least 8"),
    ("max_time_short", _set("world", {"size": [20, 14], "dt": 0.1, "max_time": 0.05}), "world.max_time", "control period"),
    ("accel_bool", _set("robots.max_accel", False), "robots.max_accel", "null"),
]


@pytest.mark.parametrize("case, edit, key, fragment", BAD_CASES, ids=[c[0] for c in BAD_CASES])
def test_bad_file_names_file_and_key(case: str, edit, key: str, fragment: str, tmp_path: Path) -> None:
    data = copy.deepcopy(_minimal())
    edit(data)
    path = tmp_path / f"bad_{case}.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False) if case != "exponent_text" else
                    yaml.safe_dump(data).replace("'1e3'", "1e3"))
    with pytest.raises(ScenarioError) as err:
        load_scenario(path)
    msg = str(err.value)
    assert err.value.key == key, msg
    assert len(err.value.errors) == 1, msg  # one mistake, one error: nothing reported as its consequence
    assert f"bad_{case}.yaml" in msg and key in msg, msg
    assert fragment in msg, msg
    # The same mapping, validated directly, names <dict> and the same key.
    if case != "exponent_text":
        with pytest.raises(ScenarioError) as err2:
            scenario_from_dict(data)
        assert err2.value.key == key and str(err2.value).startswith("<dict>")


def test_yaml_syntax_error(tmp_path: Path) -> None:
    path = tmp_path / "broken.yaml"
    path.write_text("world: {size: [20, 14]\nrobots: [\n")
    with pytest.raises(ScenarioError) as err:
        load_scenario(path)
    assert err.value.key == "<file>" and "broken.yaml" in str(err.value) and "YAML" in str(err.value)


def test_duplicate_yaml_key(tmp_path: Path) -> None:
    path = tmp_path / "dup.yaml"
    path.write_text(yaml.safe_dump(_minimal()) + "robots: {count: 3}\n")
    with pytest.raises(ScenarioError, match="duplicate key 'robots'") as err:
        load_scenario(path)
    assert err.value.key == "<file>" and "dup.yaml" in str(err.value)


def test_missing_file(tmp_path: Path) -> None:
    path = tmp_path / "nowhere.yaml"
    with pytest.raises(ScenarioError) as err:
        load_scenario(path)
    assert err.value.key == "<file>" and "nowhere.yaml" in str(err.value)


@pytest.mark.parametrize("text, key", [("", "<file>"), ("- 1\n- 2\n", "<top level>")])
def test_empty_or_non_mapping_file(text: str, key: str, tmp_path: Path) -> None:
    path = tmp_path / "odd.yaml"
    path.write_text(text)
    with pytest.raises(ScenarioError) as err:
        load_scenario(path)
    assert err.value.key == key and "odd.yaml" in str(err.value)


def test_min_substeps_is_the_boundary() -> None:
    data = _minimal()
    data["world"] = {"size": [20, 14], "dt": 1.0, "substeps": 8}
    scn = scenario_from_dict(data)
    assert min_substeps(scn) == 8  # v_rel = 2 * 0.65 + 0.5 = 1.8 m/s, r_min = 0.25 m: 7.2 -> 8
    data["world"]["substeps"] = 7
    with pytest.raises(ScenarioError, match="at least 8"):
        scenario_from_dict(data)


def test_every_error_of_a_file_is_reported(tmp_path: Path) -> None:
    """Validation goes on after a bad value: one error per problem, in file order, each naming file and key;
    checks that depend on a bad value are skipped rather than reported."""
    data = copy.deepcopy(_minimal())
    data["world"]["size"] = [20, -14]
    data["robots"]["max_sped"] = 0.5  # unknown key
    data["robots"]["radius"] = -1.0
    data["leader"]["kind"] = "robott"
    data["formations"].append({"at": 30.0, "shape": "custom", "offsets": [[-1.0, 1.0]]})  # 1 offset, 2 robots
    data["obstacles"] = [{"type": "circle", "center": [8, 11]}, {"type": "polygon", "points": [[4, 4], [5, 4]]}]
    data["humans"] = [{"path": [[14, 10], [4, 10]], "speed": -0.5, "mode": "sometimes"}]
    path = tmp_path / "many.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    with pytest.raises(ScenarioError) as err:
        load_scenario(path)
    keys = [e.key for e in err.value.errors]
    assert keys == ["world.size[1]", "robots.max_sped", "robots.radius", "leader.kind", "formations[1].offsets",
                    "obstacles[0].radius", "obstacles[1].points", "humans[0].speed", "humans[0].mode"], keys
    lines = str(err.value).splitlines()
    assert len(lines) == len(keys) and all(line.startswith(f"{path}: {k}: expected ") for line, k in zip(lines, keys))
    assert err.value.key == "world.size[1]"  # the first problem's fields, as for a single error


def test_semantic_errors_are_all_reported() -> None:
    data = copy.deepcopy(_minimal())
    data["leader"]["path"] = [[2, 7], [2, 7], [30, 7]]  # a repeated waypoint and one outside the world
    data["formations"] = [{"at": 1.0, "shape": "v", "spacing": 1.0, "angle": 45},
                          {"at": 0.5, "shape": "line", "spacing": 1.0, "angle": 200}]
    data["leader"]["speed"] = 5.0
    with pytest.raises(ScenarioError) as err:
        scenario_from_dict(data)
    keys = [e.key for e in err.value.errors]
    for key in ("leader.path[1]", "leader.path[2]", "formations[0].at", "formations[1].at", "formations[1].angle",
                "leader.speed"):
        assert key in keys, (key, keys)
    assert len(keys) == len(set(keys)) and all(str(e).startswith("<dict>: ") for e in err.value.errors)
