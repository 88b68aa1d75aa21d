"""Bounded, total validation (issue 14, item 2): the hostile inputs the issue measured, one by one.

Each used to crash, hang or eat memory; each is now a one-line ``ScenarioError`` naming the
bound (``swarm_env.limits``) it broke, reached in bounded time. The fuzz tests
(``tests/test_scenario_fuzz.py``) check the same contract on random mutations.
"""

from __future__ import annotations

import copy
import math
import os
import re
import time
from pathlib import Path

import pytest
import yaml

from swarm_env import SwarmEnv, limits
from swarm_env.geometry.static_map import convex_ccw
from swarm_env.limits import LIMITS, clip_repr, printable
from swarm_env.scenario import ScenarioError
from swarm_env.scenarios.generator import RandomScenarioConfig
from swarm_env.scenarios.loader import load_scenario, obstacle_vertices, scenario_from_dict, scenario_to_dict

ROOT = Path(__file__).resolve().parent.parent
BASE = scenario_to_dict(load_scenario("paper_vo_0"))


def _edit(path: tuple, value: object) -> dict:
    data = copy.deepcopy(BASE)
    node = data
    for k in path[:-1]:
        node = node[k]
    node[path[-1]] = value
    return data


def _file_error(tmp_path: Path, text: str | bytes) -> ScenarioError:
    path = tmp_path / "hostile.yaml"
    (path.write_bytes if isinstance(text, bytes) else path.write_text)(text)  # type: ignore[operator]
    start = time.perf_counter()
    with pytest.raises(ScenarioError) as err:
        load_scenario(path)
    assert time.perf_counter() - start < 20.0
    for e in err.value.errors:
        assert "\n" not in str(e) and str(e).isprintable() and len(str(e)) < 600
    return err.value


def _bomb(levels: int) -> str:
    lines = ['a0: &a0 ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]']
    lines += [f"a{i}: &a{i} [" + ",".join([f"*a{i - 1}"] * 9) + "]" for i in range(1, levels)]
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------- reading a file


def test_alias_bomb_in_description_is_refused_before_expansion(tmp_path: Path) -> None:
    """Nine levels of nine aliases: 9**9 strings once expanded; refused in milliseconds."""
    body = yaml.safe_dump({k: v for k, v in BASE.items() if k != "description"})
    text = "x:\n" + "".join("  " + line + "\n" for line in _bomb(9).splitlines()) + body + "description: *a8\n"
    start = time.perf_counter()
    err = _file_error(tmp_path, text)
    assert time.perf_counter() - start < 2.0
    assert err.key == "<file>" and "MAX_YAML_NODES" in str(err)


def test_recursive_alias_is_refused(tmp_path: Path) -> None:
    err = _file_error(tmp_path, yaml.safe_dump(BASE) + "description: &d [*d]\n")
    assert "recursive alias" in str(err)


@pytest.mark.parametrize("opening, closing", [("[", "]"), ("{a: ", "}")])
def test_deep_nesting_is_refused(opening: str, closing: str, tmp_path: Path) -> None:
    err = _file_error(tmp_path, yaml.safe_dump(BASE) + "x: " + opening * 20_000 + "1" + closing * 20_000 + "\n")
    assert f"nested at most {limits.MAX_YAML_DEPTH} deep" in str(err)


def test_huge_integer_is_refused_unparsed(tmp_path: Path) -> None:
    err = _file_error(tmp_path, yaml.safe_dump(BASE).replace("count: 2", "count: " + "9" * 5000))
    assert "MAX_NUMBER_CHARS" in str(err)


def test_large_file_is_refused_before_reading(tmp_path: Path) -> None:
    err = _file_error(tmp_path, yaml.safe_dump(BASE) + "#" + "x" * (limits.MAX_FILE_BYTES + 1) + "\n")
    assert "MAX_FILE_BYTES" in str(err)


def test_special_files_are_refused(tmp_path: Path) -> None:
    fifo = tmp_path / "fifo.yaml"
    os.mkfifo(fifo)
    zero = tmp_path / "zero.yaml"
    zero.symlink_to("/dev/zero")
    for path, kind in ((fifo, "FIFO"), (zero, "device"), (tmp_path, "directory")):
        with pytest.raises(ScenarioError, match=rf"<file>: expected a regular file \(this is a {kind}\)"):
            load_scenario(path)


def test_text_file_that_is_not_a_scenario_is_not_echoed(tmp_path: Path) -> None:
    err = _file_error(tmp_path, "root:x:0:0:root:/root:/bin/bash\n")
    assert "root" not in str(err).replace(str(tmp_path), "") and "holds a str" in str(err)


def test_invalid_timestamp_is_a_yaml_error(tmp_path: Path) -> None:
    err = _file_error(tmp_path, yaml.safe_dump(BASE) + "x: 2001-02-30\n")
    assert err.key == "<file>"


def test_merge_keys_are_not_duplicates(tmp_path: Path) -> None:
    text = yaml.safe_dump({k: v for k, v in BASE.items() if k != "formations"}) + (
        "formations:\n  - &f0 {at: 0.0, shape: v, spacing: 1.2}\n  - {<<: *f0, at: 30.0, shape: line}\n"
    )
    path = tmp_path / "merge.yaml"
    path.write_text(text)
    scn = load_scenario(path)
    assert scn.formations[1].shape == "line" and scn.formations[1].spacing == 1.2
    # A key written twice in one mapping is still refused.
    with pytest.raises(ScenarioError, match="duplicate key 'at'"):
        path.write_text(text + "  - {at: 40.0, at: 50.0, shape: v}\n")
        load_scenario(path)


# --------------------------------------------------------------------------- values and derived counts


@pytest.mark.parametrize("path, value, bound", [
    (("obstacles", 0), {"type": "rectangle", "center": [5.0, 5.0], "size": [1e20, 1.0]}, "MAX_ABS_NUMBER"),
    (("robots", "max_speed"), 1e308, "MAX_SPEED"),
    (("formations", 0), {"at": 0.0, "shape": "grid", "columns": 2**63}, "MAX_ROBOTS"),
    (("robots", "count"), 10_000, "MAX_ROBOTS"),
    (("sensors", "lidar_rays"), 10**9, "MAX_LIDAR_RAYS"),
    (("sensors", "neighbors"), 10**9, "MAX_NEIGHBORS"),
    (("world", "substeps"), 10**6, "MAX_SUBSTEPS"),
    (("world", "dt"), 1e-9, "MIN_DT"),
    (("world", "max_time"), 1e12, "MAX_ABS_NUMBER"),
    (("world", "max_time"), 1e5, "MAX_EPISODE_STEPS"),
    (("world", "size"), [5000.0, 14.0], "MAX_WORLD_SIZE"),
    (("robots", "radius"), 1e-9, "MIN_RADIUS"),
    (("leader", "speed"), 1e-300, "MIN_SPEED"),
    (("obstacles", 0), {"type": "rectangle", "center": [5.0, 5.0], "size": [1e-300, 1.0]}, "MIN_OBSTACLE_SIZE"),
    (("leader", "path"), [[2.0, 7.0], [17.0, 7.0]] * 6000, "MAX_WAYPOINTS"),
])
def test_values_beyond_their_bound_name_it(path: tuple, value: object, bound: str) -> None:
    start = time.perf_counter()
    with pytest.raises(ScenarioError) as err:
        scenario_from_dict(_edit(path, value))
    assert time.perf_counter() - start < 2.0
    assert f"swarm_env.limits.{bound}" in str(err.value)


def test_every_builtin_and_the_generator_range_fit_the_bounds() -> None:
    """At the bounds: 64 followers with 360 rays and 63 neighbours build and step."""
    data = _edit(("robots", "count"), 64)
    data.update(sensors={"lidar_rays": 360, "lidar_range": 5.0, "neighbors": 63, "humans": 2}, obstacles=[], humans=[])
    data["world"]["size"] = [60.0, 40.0]
    data["leader"]["path"] = [[20.0, 20.0], [55.0, 20.0]]
    data["formations"] = [{"at": 0.0, "shape": "grid", "spacing": 1.0, "columns": 8}]
    env = SwarmEnv(scenario_from_dict(data))
    obs, _ = env.reset(seed=0)
    env.step({a: env.action_space(a).sample() for a in env.agents})
    assert len(obs) == 64
    RandomScenarioConfig(n_followers=(1, 64), n_humans=(0, 32))  # the generator's whole documented range


def _ring(cx: float, cy: float, n: int, r: float = 0.05) -> list[list[float]]:
    return [[round(cx + r * math.cos(2 * math.pi * k / n), 4), round(cy + r * math.sin(2 * math.pi * k / n), 4)]
            for k in range(n)]


def test_obstacle_vertices_all_together_are_bounded() -> None:
    """A derived bound (MAX_OBSTACLE_VERTICES): 33 polygons of 64 points are refused, each within its own bounds;
    32 of them (the bound exactly, 2048 vertices) are accepted."""
    grid = [(1.0 + 0.5 * (i % 16), 1.0 + 0.5 * (i // 16)) for i in range(33)]  # along the bottom, off the path
    polygons = [{"type": "polygon", "points": _ring(x, y, 64)} for x, y in grid]
    start = time.perf_counter()
    with pytest.raises(ScenarioError, match=r"obstacles: expected at most 2048 \(swarm_env.limits.MAX_OBSTACLE_VERTICES\) "
                       r"obstacle vertices, got '2112 obstacle vertices'"):
        scenario_from_dict(_edit(("obstacles",), polygons))
    assert time.perf_counter() - start < 5.0
    scn = scenario_from_dict(_edit(("obstacles",), polygons[:32]))
    assert obstacle_vertices(scn) == LIMITS["MAX_OBSTACLE_VERTICES"][0] == 2048
    mixed = [{"type": "circle", "center": [1.0, 1.0], "radius": 0.1},
             {"type": "rectangle", "center": [3.0, 1.0], "size": [0.2, 0.2]}, {"type": "polygon", "points": _ring(5, 1, 7)}]
    assert obstacle_vertices(scenario_from_dict(_edit(("obstacles",), mixed))) == 1 + 4 + 7


def test_human_starting_inside_an_obstacle_is_an_error() -> None:
    centre = next(o["center"] for o in BASE["obstacles"] if o["type"] == "circle")
    with pytest.raises(ScenarioError, match=r"humans\[0\]\.path\[0\]: expected a human start clear of obstacles"):
        scenario_from_dict(_edit(("humans", 0, "path", 0), list(centre)))


def test_neighbors_beyond_the_team_are_absent_rows() -> None:
    """The documented clamp: more neighbour rows than other followers are padding (mask 0)."""
    env = SwarmEnv(scenario_from_dict(_edit(("sensors", "neighbors"), 5)))
    obs, _ = env.reset(seed=0)
    sl = env.obs_layout["neighbors"]
    rows = next(iter(obs.values()))[sl].reshape(5, 5)
    assert rows[0, 4] == 1.0 and not rows[1:].any()  # one other follower; four absent rows


# --------------------------------------------------------------------------- messages


@pytest.mark.parametrize("name", ["evil\x1b[2J\x07", "map\u202egnp.exe", "a\u200bb"])
def test_names_with_control_or_bidi_characters_are_refused_and_escaped(name: str) -> None:
    with pytest.raises(ScenarioError) as err:
        scenario_from_dict(_edit(("name",), name))
    text = str(err.value)
    assert "name: expected a string without control, bidi" in text and text.isprintable()


def test_unknown_keys_are_escaped_in_messages() -> None:
    with pytest.raises(ScenarioError) as err:
        scenario_from_dict({**BASE, "\u202eworld\n": 1})
    assert "\\u202eworld\\x0a" in str(err.value) and str(err.value).isprintable()


def test_values_in_messages_are_clipped() -> None:
    with pytest.raises(ScenarioError) as err:
        scenario_from_dict(_edit(("world", "size"), "x" * 100_000))
    got = str(err.value).rpartition(", got ")[2]
    assert len(got) <= limits.MESSAGE_VALUE_CHARS and "..." in got


def test_clip_repr_is_bounded_for_any_value() -> None:
    bomb: list = ["lol"] * 9
    for _ in range(8):
        bomb = [bomb] * 9
    itself: list = []
    itself.append(itself)
    for value in (bomb, itself, 10**5000, "\u202e" * 10_000, {i: i for i in range(10_000)}):
        start = time.perf_counter()
        text = clip_repr(value)
        assert len(text) <= limits.MESSAGE_VALUE_CHARS and text.isprintable()
        assert time.perf_counter() - start < 0.5
    assert printable("a\x1bb\u202e") == "a\\x1bb\\u202e"


def test_exponent_hint_says_what_yaml_reads(tmp_path: Path) -> None:
    err = _file_error(tmp_path, yaml.safe_dump(BASE).replace("max_time: 60.0", "max_time: 1e3"))
    assert "write 1.0e+3" in str(err)
    path = tmp_path / "fixed.yaml"
    path.write_text(yaml.safe_dump(BASE).replace("max_time: 60.0", "max_time: 1.0e+2"))
    assert load_scenario(path).world.max_time == 100.0  # the hint's form is read as a number


def test_bow_tie_is_called_self_intersecting() -> None:
    with pytest.raises(ValueError, match="self-intersecting"):
        convex_ccw([[4, 4], [6, 6], [6, 4], [4, 6]])
    with pytest.raises(ValueError, match="collinear"):
        convex_ccw([[0, 0], [1, 1], [2, 2]])


# --------------------------------------------------------------------------- the generator's knobs


@pytest.mark.parametrize("knobs, bound", [
    ({"n_humans": (0, 10**9)}, "n_humans"),
    ({"max_time": 1e12}, "MAX_ABS_NUMBER"),
    ({"max_time": 1e5}, "MAX_EPISODE_STEPS"),
    ({"dt": 1e-9}, "MIN_DT"),
    ({"substeps": 10**6}, "MAX_SUBSTEPS"),
    ({"world_size": (1e20, 1e20)}, "MAX_WORLD_SIZE"),
    ({"spacing": (100.0, 100.0), "n_followers": 64}, "MAX_WORLD_SIZE"),
    ({"max_speed": 1e308}, "MAX_SPEED"),
    ({"radius": 1e-300}, "MIN_RADIUS"),
    ({"obstacle_size": (1e20, 1e20)}, "MAX_WORLD_SIZE"),
    ({"sensors": {"lidar_rays": 10**9}}, "MAX_LIDAR_RAYS"),
])
def test_generator_knobs_are_bounded(knobs: dict, bound: str) -> None:
    start = time.perf_counter()
    with pytest.raises(ScenarioError, match=re.escape(bound)):
        SwarmEnv("random", **knobs)
    assert time.perf_counter() - start < 2.0


# --------------------------------------------------------------------------- documentation


@pytest.mark.parametrize(
    "section, field, value, key",
    [
        ("robots", "count", 10**9, "robots.count"),
        ("robots", "max_speed", -1.0, "robots.max_speed"),
        ("world", "dt", 1e-9, "world.dt"),
        ("sensors", "lidar_rays", 10**9, "sensors.lidar_rays"),
        ("robots", "max_speed", "fast", "<object>"),
        ("leader", "path", 3.0, "<object>"),
    ],
)
def test_scenario_objects_pass_the_same_gate_as_files(section: str, field: str, value: object, key: str) -> None:
    """A Scenario built in Python (SwarmEnv(Scenario(...))) used to skip every check."""
    import dataclasses

    scn = load_scenario("paper_vo_0")
    bad = dataclasses.replace(scn, **{section: dataclasses.replace(getattr(scn, section), **{field: value})})
    started = time.perf_counter()
    with pytest.raises(ScenarioError) as err:
        SwarmEnv(bad)
    assert err.value.key == key
    assert "\n" not in str(err.value)
    assert time.perf_counter() - started < 5.0


def test_valid_scenario_objects_come_back_unchanged() -> None:
    for name in ("paper_vo_0", "paper_cbs_switch", "crowd_reactive"):
        scn = load_scenario(name)
        assert load_scenario(scn) is scn
        a, b = SwarmEnv(scn).reset(seed=3)[0], SwarmEnv(name).reset(seed=3)[0]
        assert all((a[k] == b[k]).all() for k in a)


def test_docs_list_every_bound_with_its_value() -> None:
    """docs/scenarios.md's table is LIMITS (one place: the table follows the code)."""
    doc = (ROOT / "docs" / "scenarios.md").read_text()
    for name, (value, _what) in LIMITS.items():
        shown = f"{value:,}" if isinstance(value, int) else f"{value:g}"
        assert re.search(rf"\| `{name}` \| {re.escape(shown)} \|", doc), name


def test_reliability_page_was_produced_by_the_probes_script() -> None:
    page = (ROOT / "docs" / "reliability.md").read_text()
    assert "python benchmarks/reliability_probes.py --out docs/reliability.md" in page
    total = re.search(r"\| \*\*all\*\* \| \*\*(\d+)\*\* \| \*\*(\d+)\*\* \| \*\*(\d+)\*\* \| \*\*(\d+)\*\* \| \*\*(\d+)\*\* \|",
                      page)
    assert total is not None
    tried, clear, accepted, crash, hang = map(int, total.groups())
    assert tried == clear + accepted + crash + hang and tried >= 5000
    assert crash == 0 and hang == 0
