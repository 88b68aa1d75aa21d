"""Loading, validating and saving scenarios (YAML files <-> :class:`~swarm_env.scenario.Scenario`).

A scenario file is YAML with the sections below. ``world``, ``robots``, ``leader``
and ``formations`` are required; everything else is optional and takes the
defaults of the dataclasses in :mod:`swarm_env.scenario`. Units are metres,
seconds and radians, except the two ``angle`` fields, which are degrees.

.. code-block:: yaml

    name: paper_vo_0            # optional, defaults to the file stem
    description: ...            # optional free text
    world:                      # the rectangle [0, W] x [0, H], closed by walls
      size: [20, 14]            # required: W, H (m)
      dt: 0.1                   # control period: one env.step (s)
      substeps: 4               # physics steps per env.step (int >= 1)
      max_time: 60.0            # episode length (s)
      settle_tolerance: 0.3     # formation counts as settled under this slot distance (m)
    robots:                     # the followers
      count: 2                  # required (int >= 1)
      radius: 0.25
      max_speed: 0.65           # m/s; paper 003's Table I prints "6.5 m/s", read as 0.65
      max_turn_rate: 1.0        # rad/s
      max_accel: null           # m/s^2, null = unlimited
      max_turn_accel: null      # rad/s^2, null = unlimited
      wheelbase: 0.5
      start: formation          # or one [x, y, theta_rad] per follower
    leader:
      kind: robot               # required: virtual (a point, paper 000) or robot (a disc, paper 003)
      path: [[2, 7], [17, 7]]   # required: >= 2 waypoints inside the world
      speed: 0.5                # required (m/s), <= robots.max_speed
      radius: 0.25              # robot leader only
      max_turn_rate: 1.0        # robot leader only (rad/s)
      lookahead: 1.0            # pure-pursuit look-ahead (m), robot leader only
      start_delay: 0            # s before the leader starts moving
    formations:                 # required, >= 1 entry; `at` strictly increasing, first at 0
      - {at: 0.0, shape: v, spacing: 1.0, angle: 45}
      - {at: 80.0, shape: custom, offsets: [[-1.0, 1.0], [-1.0, -1.0]]}
    obstacles:                  # static
      - {type: circle, center: [8, 11], radius: 0.5}
      - {type: rectangle, center: [12, 8], size: [1, 2], angle: 30}
      - {type: polygon, points: [[4, 4], [5, 4], [4.5, 5]]}   # convex, any winding
    humans:                     # walk kinematically: scripted (default) ignore robots; social_force, orca react
      - {path: [[14, 10], [4, 10]], speed: 0.5, radius: 0.3, mode: once, start_delay: 0, behavior: scripted}
    sensors: {lidar_rays: 16, lidar_range: 5.0, neighbors: 3, humans: 2}
    reward: {formation: 1.0, collision: 5.0, contact: 2.0, clearance: 1.0,
             clearance_margin: 0.2, smoothness: 0.0, progress: 0.0,  # reward v1 defaults
             approach: 0.0, approach_horizon: 2.0, approach_margin: 0.5}

Formation shapes: ``v``, ``line``, ``column``, ``wedge``, ``diamond``, ``circle``,
``grid`` (``columns``: int >= 0, 0 = automatic) and ``custom`` (``offsets``: one
``[x, y]`` per follower in the leader frame, x forward, y left). ``spacing`` (m)
is the distance between neighbouring slots, ``angle`` (degrees, in [1, 179]) the
half-opening of the ``v``/``wedge`` arms from the leader's backward axis.

Parsing checks types and ranges section by section; then :func:`validate_scenario`,
the one semantic gate (also passed by every scenario the ``random`` generator builds),
checks the rules below. The allowed keys of each section are the fields of its
dataclass in :mod:`swarm_env.scenario`.

Validation fails loudly and completely: it goes on after a bad value wherever what follows
does not depend on it, and raises one :class:`~swarm_env.scenario.ScenarioError` whose
``errors`` lists every problem found (one message line each). Each names the source (file path, or ``<dict>``), the key path (``robots.max_speed``,
``formations[1].shape``, ``obstacles[2].points``; ``<file>`` for unreadable files and
YAML syntax errors) and what was expected. Checked beyond types and ranges
(``bool`` is not a number; numbers must be finite):

* the bounds of :mod:`swarm_env.limits`, one table for every value that sets an amount of
  work or memory: the file's size (checked before reading; FIFOs, devices and directories are
  refused), YAML alias expansion and nesting, the length of written numbers, counts (robots,
  humans, obstacles, waypoints, rays, neighbours, substeps), control steps per episode
  (``max_time / dt``), the world's size, speeds and radii; each message names its bound;
* ``name`` and ``description`` without control or bidi characters; messages escape them
  anyway and cut the values they show to 80 characters;
* unknown keys (the message lists the allowed ones), duplicate YAML keys (keys brought in
  by a merge key, ``<<: *anchor``, may be overridden);
* waypoints and start poses inside the world (discs by their radius);
* consecutive waypoints distinct; polygons convex with non-zero area;
* the formation schedule: first ``at`` is 0, strictly increasing; ``offsets`` only
  and always for ``custom``, one per follower; ``columns`` only for ``grid``;
  slots of every formation at least ``2 * robots.radius`` apart (and clear of a
  robot leader's disc);
* starting poses free of obstacles, of each other, of a robot leader and of the
  humans' first waypoints; humans' first waypoints clear of obstacles;
* ``leader.speed <= robots.max_speed`` (otherwise the followers can never keep up);
* the anti-tunnelling rule (pymunk has no continuous collision detection): with
  ``v_rel = 2 * max(robots.max_speed, leader.speed) + max(human speeds)`` and
  ``r_min`` the smallest disc radius, ``v_rel * dt / substeps <= 0.5 * (2 * r_min)``;
  the error names ``world.substeps`` and the smallest value that passes.

Paper 003 (Table I) gives the followers' maximum linear velocity as "6.5 m/s" next to
0.5 m/s for the leader and mean speeds around 0.45 m/s; we read it as a typo for
0.65 m/s, which is the default of ``robots.max_speed`` and what the built-in
``paper_vo_*`` scenarios use.

The name ``random`` is not a file: random worlds come from
:func:`swarm_env.scenarios.generator.random_scenario` (or ``parallel_env("random", ...)``).
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import os
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from swarm_env.checks import did_you_mean
from swarm_env.geometry.formation import formation_offsets, formation_start
from swarm_env.geometry.static_map import StaticMap, convex_ccw
from swarm_env.limits import (
    LIMITS,
    MAX_EPISODE_STEPS,
    MAX_FILE_BYTES,
    MAX_NUMBER_CHARS,
    MAX_WORLD_SIZE,
    MAX_YAML_DEPTH,
    MAX_YAML_NODES,
    MESSAGE_VALUE_CHARS,
    MIN_OBSTACLE_SIZE,
    clip_repr,
    printable,
    unprintable_chars,
)
from swarm_env.reading import FileRefused, read_regular
from swarm_env.scenario import (
    FORMATION_SHAPES,
    HUMAN_BEHAVIORS,
    HUMAN_MODES,
    LEADER_KINDS,
    CircleObstacle,
    FormationSpec,
    HumanSpec,
    LeaderSpec,
    Obstacle,
    Point,
    PolygonObstacle,
    RectangleObstacle,
    RewardSpec,
    RobotSpec,
    Scenario,
    ScenarioError,
    SensorSpec,
    WorldSpec,
)

__all__ = [
    "BUILTIN_DIR",
    "list_scenarios",
    "load_scenario",
    "scenario_from_dict",
    "scenario_to_dict",
    "min_substeps",
    "required_substeps",
    "validate_scenario",
    "check_scenario_object",
    "start_poses",
    "obstacle_vertices",
]

#: Folder of the built-in scenario files (``<name>.yaml``).
BUILTIN_DIR: Path = Path(__file__).resolve().parent  # the built-in *.yaml files sit beside this module

RANDOM_NAME = "random"

def _keys(cls: type) -> tuple[str, ...]:
    """The YAML keys of a section: its dataclass's fields (one place for both, so they never drift)."""
    names = tuple(f.name for f in dataclasses.fields(cls))
    return ("type", *(n for n in names if n != "type")) if "type" in names else names


# Allowed keys per section, from the dataclasses of swarm_env.scenario.
_TOP_KEYS = tuple(k for k in _keys(Scenario) if k != "source")
_TOP_REQUIRED = ("world", "robots", "leader", "formations")
_WORLD_KEYS = _keys(WorldSpec)
_ROBOT_KEYS = _keys(RobotSpec)
_LEADER_KEYS = _keys(LeaderSpec)
_FORMATION_KEYS = _keys(FormationSpec)
_OBSTACLE_KEYS = {
    "circle": _keys(CircleObstacle),
    "rectangle": _keys(RectangleObstacle),
    "polygon": _keys(PolygonObstacle),
}
_HUMAN_KEYS = _keys(HumanSpec)
_SENSOR_KEYS = _keys(SensorSpec)
_REWARD_KEYS = _keys(RewardSpec)

# Slack for geometric comparisons of values people type with a few decimals.
_EPS = 1e-9
# The bounds of every disc radius (followers, robot leader, humans).
_RADIUS = {"at_least": "MIN_RADIUS", "at_most": "MAX_WORLD_SIZE"}
# The bounds of every speed (followers' top speed, the leader's, humans').
_SPEED = {"at_least": "MIN_SPEED", "at_most": "MAX_SPEED"}


class _Bad:
    """The value of a field that failed validation (its error is already recorded)."""

    def __repr__(self) -> str:
        return "<invalid>"


_BAD: Any = _Bad()


class _Errors:
    """The problems of one scenario, gathered so that one pass reports all of them.

    ``ok(fn, *args, **kwargs)`` calls ``fn`` and returns its value, or records the
    :class:`ScenarioError` it raised and returns ``_BAD``; it does not call ``fn`` at
    all when an argument is ``_BAD``, so a check that depends on an invalid value is
    skipped instead of reporting a consequence of an error already recorded.
    """

    def __init__(self) -> None:
        self.errors: list[ScenarioError] = []

    def __call__(self, fn: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
        if any(a is _BAD for a in args) or any(v is _BAD for v in kwargs.values()):
            return _BAD
        try:
            return fn(*args, **kwargs)
        except ScenarioError as exc:
            self.add(exc)
            return _BAD

    def add(self, exc: ScenarioError) -> None:
        self.errors.extend(exc.errors)

    @staticmethod
    def all(values: tuple) -> Any:
        """``values``, or ``_BAD`` if one of them is."""
        return _BAD if any(v is _BAD for v in values) else values

    def raise_all(self) -> None:
        if self.errors:
            raise ScenarioError.several(self.errors)


# --------------------------------------------------------------------------- public API


def list_scenarios() -> list[str]:
    """Names accepted by :func:`swarm_env.parallel_env`: the built-in YAML stems plus ``"random"``, sorted."""
    names = {p.stem for p in BUILTIN_DIR.glob("*.yaml")}
    names.add(RANDOM_NAME)
    return sorted(names)


def load_scenario(spec: str | os.PathLike[str] | Mapping[str, Any] | Scenario) -> Scenario:
    """Load and validate a scenario.

    ``spec`` is a built-in name (see :func:`list_scenarios`), a path to a YAML file,
    an already-parsed mapping (validated with source ``<dict>``) or a
    :class:`Scenario` (one built in Python passes the same gate as a file: see
    :func:`check_scenario_object`). ``"random"`` is refused: random worlds are drawn
    per episode by :func:`swarm_env.scenarios.generator.random_scenario`.

    Raises :class:`ScenarioError` for anything invalid, including missing files and
    YAML syntax errors (key ``<file>``).
    """
    if isinstance(spec, Scenario):
        return check_scenario_object(spec)
    if isinstance(spec, Mapping):
        return scenario_from_dict(spec)
    if not isinstance(spec, (str, os.PathLike)):
        raise ScenarioError("<argument>", "<file>", "a scenario name, a YAML path, a mapping or a Scenario", spec)
    text = os.fspath(spec)
    if text == RANDOM_NAME or text.startswith(RANDOM_NAME + ":"):
        raise ScenarioError(
            text,
            "<file>",
            f"a scenario file; {text!r} is generated per episode: use "
            "swarm_env.scenarios.generator.random_scenario(rng, config) or parallel_env('random', **knobs) "
            "(a family: parallel_env('random:<family>'))",
        )
    path = Path(text)
    looks_like_name = isinstance(spec, str) and path.suffix == "" and len(path.parts) == 1
    if looks_like_name:
        builtin = BUILTIN_DIR / f"{text}.yaml"
        if builtin.is_file():
            path = builtin
        elif not path.is_file():
            raise ScenarioError(
                text, "<file>", f"a built-in scenario name (one of {list_scenarios()}) or a path to a YAML "
                f"file{did_you_mean(text, list_scenarios())}"
            )
    return _load_file(path)


def scenario_from_dict(data: Mapping[str, Any], source: str = "<dict>") -> Scenario:
    """Validate a parsed scenario mapping (the YAML format above) and build the :class:`Scenario`.

    ``source`` names the origin in error messages and is stored in
    ``Scenario.source``; when it is a file path, ``name`` defaults to its stem.
    """
    src = str(source)
    if not isinstance(data, Mapping):
        raise ScenarioError(src, "<top level>", "a mapping of sections", _short(data))
    if data and not any(isinstance(k, str) and k in _TOP_KEYS for k in data):
        # Some other file that happens to parse as a mapping (/etc/shadow does): one line, and none of its
        # keys echoed, instead of an "unknown section" error per line of it.
        raise ScenarioError(src, "<top level>", "a YAML mapping of scenario sections (world, robots, leader, formations); "
                            f"none of this mapping's {len(data)} keys is a scenario section")
    ok = _Errors()
    _check_keys(src, data, "", _TOP_KEYS, _TOP_REQUIRED, ok)

    default_name = Path(src).stem if src not in ("<dict>", "") and not src.startswith("<") else "custom"
    name = ok(_string, src, data.get("name", default_name), "name", nonempty=True, at_most="MAX_NAME_CHARS")
    description = ok(_string, src, data.get("description", ""), "description", at_most="MAX_DESCRIPTION_CHARS",
                     allowed="\n\t\r")

    world = ok(_parse_world, src, data.get("world", _BAD), ok)
    robots = ok(_parse_robots, src, data.get("robots", _BAD), ok)
    leader = ok(_parse_leader, src, data.get("leader", _BAD), ok)
    count = robots.count if isinstance(robots, RobotSpec) else _plain_count(data.get("robots"))
    formations = ok(_parse_formations, src, data.get("formations", _BAD), count, ok)
    obstacles = ok(_parse_list, src, data.get("obstacles", []), "obstacles", _parse_obstacle, "MAX_OBSTACLES", ok)
    humans = ok(_parse_list, src, data.get("humans", []), "humans", _parse_human, "MAX_HUMANS", ok)
    sensors = ok(_parse_sensors, src, data.get("sensors", {}), ok)
    reward = ok(_parse_reward, src, data.get("reward", {}), ok)
    ok.raise_all()  # a scenario is built only from sections that all parsed

    scn = Scenario(
        name=name,
        world=world,
        robots=robots,
        leader=leader,
        formations=formations,
        obstacles=obstacles,
        humans=humans,
        sensors=sensors,
        reward=reward,
        description=description,
        source=src,
    )
    return validate_scenario(scn)


def check_scenario_object(scn: Scenario) -> Scenario:
    """The full gate for a :class:`Scenario` built in Python (``SwarmEnv(Scenario(...))``).

    Its fields are written out as the YAML mapping (:func:`scenario_to_dict`) and parsed back
    (:func:`scenario_from_dict`), so types, ranges, the bounds of :mod:`swarm_env.limits` and the
    semantic checks of :func:`validate_scenario` all apply, as for a file. Returns ``scn`` itself
    when it was valid (every valid scenario survives the round trip unchanged), or raises
    :class:`ScenarioError` naming ``scn.source``; a field of the wrong kind (a string where a
    number belongs, a number where a list does) is reported under the key ``<object>``.
    """
    src = str(scn.source)
    try:
        data = scenario_to_dict(scn)
    except (TypeError, ValueError, OverflowError, AttributeError, IndexError, KeyError) as exc:
        raise ScenarioError(src, "<object>", "a Scenario whose fields have the documented types "
                            "(swarm_env.scenario)", str(exc)) from None
    checked = scenario_from_dict(data, src)
    try:
        same = bool(checked == scn)
    except (ValueError, TypeError):  # numpy arrays in the fields: their == is elementwise
        same = False
    return scn if same else checked


def validate_scenario(scn: Scenario) -> Scenario:
    """The semantic gate every scenario passes, from a file, a dict or the ``random`` generator.

    Checks what types and ranges cannot: geometry inside the world, distinct waypoints,
    convex polygons, the formation schedule, slot spacing, free starting poses, the
    leader's speed and the anti-tunnelling rule (the list in this module's docstring).
    Returns ``scn`` unchanged, or raises :class:`ScenarioError` naming ``scn.source``
    and the key path.
    """
    src = scn.source
    ok = _Errors()
    _check_bounds(src, scn, ok)
    ok.raise_all()  # the checks below take time with the sizes: only within the bounds
    ok(_check_world, src, scn)
    _check_geometry(src, scn, ok)
    _check_schedule(src, scn, ok)
    _cross_check(src, scn, ok)
    ok.raise_all()
    return scn


def scenario_to_dict(scn: Scenario) -> dict[str, Any]:
    """The YAML-format mapping of ``scn`` (plain lists, floats, ints, strings).

    Every field is written explicitly, so ``scenario_from_dict(scenario_to_dict(s), s.source) == s``
    for any valid scenario; ``yaml.safe_dump`` can write the result.
    """
    w, r, ld = scn.world, scn.robots, scn.leader
    start: Any = "formation" if r.start == "formation" else [_floats(p) for p in r.start]
    out: dict[str, Any] = {
        "name": scn.name,
        "description": scn.description,
        "world": {
            "size": _floats(w.size),
            "dt": float(w.dt),
            "substeps": int(w.substeps),
            "max_time": float(w.max_time),
            "settle_tolerance": float(w.settle_tolerance),
        },
        "robots": {
            "count": int(r.count),
            "radius": float(r.radius),
            "max_speed": float(r.max_speed),
            "max_turn_rate": float(r.max_turn_rate),
            "max_accel": None if r.max_accel is None else float(r.max_accel),
            "max_turn_accel": None if r.max_turn_accel is None else float(r.max_turn_accel),
            "wheelbase": float(r.wheelbase),
            "start": start,
        },
        "leader": {
            "kind": ld.kind,
            "path": [_floats(p) for p in ld.path],
            "speed": float(ld.speed),
            "radius": float(ld.radius),
            "max_turn_rate": float(ld.max_turn_rate),
            "lookahead": float(ld.lookahead),
            "start_delay": float(ld.start_delay),
        },
        "formations": [_formation_to_dict(f) for f in scn.formations],
        "obstacles": [_obstacle_to_dict(o) for o in scn.obstacles],
        "humans": [
            {
                "path": [_floats(p) for p in h.path],
                "speed": float(h.speed),
                "radius": float(h.radius),
                "mode": h.mode,
                "start_delay": float(h.start_delay),
                **({"behavior": h.behavior} if h.behavior != HumanSpec.behavior else {}),
            }
            for h in scn.humans
        ],
        "sensors": {
            "lidar_rays": int(scn.sensors.lidar_rays),
            "lidar_range": float(scn.sensors.lidar_range),
            "neighbors": int(scn.sensors.neighbors),
            "humans": int(scn.sensors.humans),
        },
        "reward": {k: float(getattr(scn.reward, k)) for k in _REWARD_KEYS},
    }
    return out


def min_substeps(scn: Scenario) -> int:
    """The smallest ``world.substeps`` that satisfies the anti-tunnelling rule for ``scn``."""
    v_rel, r_min = _tunnel_terms(scn)
    return required_substeps(v_rel, r_min, scn.world.dt)


def required_substeps(v_rel: float, r_min: float, dt: float) -> int:
    """The anti-tunnelling rule (the one place it is written; pymunk has no continuous collision
    detection): the smallest ``substeps`` with ``v_rel * dt / substeps <= 0.5 * (2 * r_min)``,
    for the largest closing speed ``v_rel`` (m/s) and the smallest disc radius ``r_min`` (m)."""
    return max(1, math.ceil(v_rel * dt / r_min - 1e-9))


# --------------------------------------------------------------------------- file loading


_MERGE_TAG = "tag:yaml.org,2002:merge"


class _StrictLoader(yaml.SafeLoader):
    """SafeLoader that refuses duplicate mapping keys (PyYAML silently keeps the last one) and
    whatever would make loading unbounded (see :mod:`swarm_env.limits`): collections nested
    deeper than ``MAX_YAML_DEPTH``, documents that stand for more than ``MAX_YAML_NODES``
    nodes once their aliases are expanded (alias bombs; recursive aliases are refused too),
    and numbers written with more than ``MAX_NUMBER_CHARS`` characters.
    """

    def __init__(self, stream: str) -> None:
        super().__init__(stream)
        self._depth = 0
        self._nodes = 0

    def compose_node(self, parent: Any, index: Any) -> Any:
        # The composer recurses once per level: bound the depth before Python's recursion limit does.
        if self.check_event(yaml.AliasEvent):
            return super().compose_node(parent, index)
        self._nodes += 1
        mark = self.peek_event().start_mark
        if self._nodes > MAX_YAML_NODES:
            raise yaml.composer.ComposerError(
                None, None, f"more than {MAX_YAML_NODES} nodes (swarm_env.limits.MAX_YAML_NODES)", mark
            )
        if not self.check_event(yaml.SequenceStartEvent, yaml.MappingStartEvent):
            return super().compose_node(parent, index)
        self._depth += 1
        try:
            if self._depth > MAX_YAML_DEPTH:
                raise yaml.composer.ComposerError(
                    None, None, f"collections nested at most {MAX_YAML_DEPTH} deep (swarm_env.limits.MAX_YAML_DEPTH)",
                    mark,
                )
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1

    def get_single_data(self) -> Any:
        node = self.get_single_node()
        if node is None:
            return None
        _check_expansion(node)  # before anything is constructed (or repr'd in a message)
        return self.construct_document(node)


def _children(node: yaml.Node) -> list[yaml.Node]:
    if isinstance(node, yaml.SequenceNode):
        return list(node.value)
    if isinstance(node, yaml.MappingNode):
        return [n for pair in node.value for n in pair]
    return []


def _check_expansion(root: yaml.Node) -> None:
    """Raise a ComposerError when the node graph ``root`` (aliases are shared nodes) expands to
    more than ``MAX_YAML_NODES`` nodes or contains itself. Each node is visited once: the
    expanded size of a node is memoised, so a nine-level alias bomb costs nine visits, not 10**9."""
    size: dict[int, int] = {}
    open_nodes: set[int] = set()  # the nodes on the current path (a node met again there is a cycle)
    stack: list[tuple[yaml.Node, bool]] = [(root, False)]
    while stack:
        node, done = stack.pop()
        key = id(node)
        if done:
            open_nodes.discard(key)
            total = 1 + sum(size[id(c)] for c in _children(node))
            if total > MAX_YAML_NODES:
                raise yaml.composer.ComposerError(
                    None, None,
                    f"aliases that expand to at most {MAX_YAML_NODES} nodes (swarm_env.limits.MAX_YAML_NODES); "
                    "this one expands to more", node.start_mark,
                )
            size[key] = total
            continue
        if key in size:
            continue
        if key in open_nodes:
            raise yaml.composer.ComposerError(None, None, "no recursive alias (a collection inside itself)",
                                              node.start_mark)
        open_nodes.add(key)
        stack.append((node, True))
        stack.extend((c, False) for c in _children(node) if id(c) not in size)


def _construct_strict_mapping(loader: _StrictLoader, node: yaml.MappingNode, deep: bool = False) -> dict:
    # Duplicates among the keys written in this mapping; keys brought in by a merge (<<: *base)
    # may be overridden by written ones, as YAML's merge key means.
    seen: set = set()
    for key_node, _ in node.value:
        if key_node.tag == _MERGE_TAG:
            continue
        key = loader.construct_object(key_node, deep=True)
        try:
            duplicate = key in seen
            seen.add(key)
        except TypeError:  # an unhashable key: let PyYAML produce its own error
            break
        if duplicate:
            raise yaml.constructor.ConstructorError(
                "while constructing a mapping", node.start_mark, f"found duplicate key {clip_repr(key)}",
                key_node.start_mark,
            )
    loader.flatten_mapping(node)
    return loader.construct_mapping(node, deep=deep)


def _bounded_number(construct: Callable[[Any, Any], Any]) -> Callable[[Any, Any], Any]:
    """A number constructor that first refuses scalars longer than ``MAX_NUMBER_CHARS``
    (Python's int() of a 5000-digit string raises; sexagesimal ints loop over their parts)."""

    def construct_bounded(loader: _StrictLoader, node: yaml.ScalarNode) -> Any:
        if len(node.value) > MAX_NUMBER_CHARS:
            raise yaml.constructor.ConstructorError(
                None, None,
                f"a number written with at most {MAX_NUMBER_CHARS} characters (swarm_env.limits.MAX_NUMBER_CHARS), "
                f"got {len(node.value)}", node.start_mark,
            )
        return construct(loader, node)

    return construct_bounded


_StrictLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_strict_mapping)
_StrictLoader.add_constructor("tag:yaml.org,2002:int", _bounded_number(yaml.SafeLoader.construct_yaml_int))
_StrictLoader.add_constructor("tag:yaml.org,2002:float", _bounded_number(yaml.SafeLoader.construct_yaml_float))


def _yaml_problem(exc: Exception) -> str:
    """A YAML error as one short line: what, and where (line, column), never the file's text."""
    if isinstance(exc, yaml.MarkedYAMLError):
        what = "; ".join(str(p) for p in (exc.context, exc.problem) if p)
        mark = exc.problem_mark or exc.context_mark
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        return printable(what, 200) + where
    return printable(f"{type(exc).__name__}: {exc}", 200)


def _read_text(path: Path) -> str:
    """The text of the scenario file ``path``, read only when it is a regular file of at most
    ``MAX_FILE_BYTES`` bytes (a FIFO, a device such as /dev/zero, a directory or a symlink to
    one of them is refused before reading: :func:`swarm_env.reading.read_regular`)."""
    src = str(path)
    try:
        raw = read_regular(path, MAX_FILE_BYTES, limit_text="(swarm_env.limits.MAX_FILE_BYTES)")
    except FileNotFoundError:
        raise ScenarioError(src, "<file>", "an existing scenario file (not found)") from None
    except FileRefused as exc:
        raise ScenarioError(src, "<file>", exc.expected, exc.got) from None
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ScenarioError(src, "<file>", f"a UTF-8 text file (byte {exc.start} is not UTF-8)") from None


def _load_file(path: Path) -> Scenario:
    src = str(path)
    text = _read_text(path)
    try:
        data = yaml.load(text, Loader=_StrictLoader)  # noqa: S506 - SafeLoader subclass
    except (yaml.YAMLError, ValueError, OverflowError, TypeError) as exc:
        # ValueError and friends: constructors of YAML 1.1 types (a timestamp such as 2001-02-30).
        raise ScenarioError(src, "<file>", "valid YAML: " + _yaml_problem(exc)) from None
    if data is None:
        raise ScenarioError(src, "<file>", "a YAML mapping of sections (the file is empty)")
    if not isinstance(data, Mapping):
        # Not the value itself: a text file that is not a scenario would have its first line echoed.
        raise ScenarioError(src, "<top level>", "a YAML mapping of scenario sections (world, robots, leader, formations); "
                            f"this file holds a {type(data).__name__}")
    return scenario_from_dict(data, source=src)


# --------------------------------------------------------------------------- sections


def _alone(parse: Callable[..., Any], src: str, value: Any) -> Any:
    """``parse(src, value, ok)`` with its own collector: its value, or all its errors raised as one."""
    ok = _Errors()
    out = ok(parse, src, value, ok)
    ok.raise_all()
    return out


def _parse_world(src: str, value: Any, ok: _Errors) -> WorldSpec:
    m = _mapping(src, value, "world")
    _check_keys(src, m, "world", _WORLD_KEYS, ("size",), ok)
    size = ok(_sizes, src, m.get("size", _BAD), "world.size", "a positive size (m)")
    dt = ok(_number, src, m.get("dt", WorldSpec.dt), "world.dt", positive=True, at_most="MAX_DT", at_least="MIN_DT")
    substeps = ok(_integer, src, m.get("substeps", WorldSpec.substeps), "world.substeps", minimum=1,
                  at_most="MAX_SUBSTEPS")
    max_time = ok(_number, src, m.get("max_time", WorldSpec.max_time), "world.max_time", positive=True)
    tol = ok(_number, src, m.get("settle_tolerance", WorldSpec.settle_tolerance), "world.settle_tolerance", positive=True,
             at_most="MAX_WORLD_SIZE")
    return ok(WorldSpec, size=size, dt=dt, substeps=substeps, max_time=max_time, settle_tolerance=tol)


def _parse_robots(src: str, value: Any, ok: _Errors) -> RobotSpec:
    m = _mapping(src, value, "robots")
    _check_keys(src, m, "robots", _ROBOT_KEYS, ("count",), ok)
    count = ok(_integer, src, m.get("count", _BAD), "robots.count", minimum=1, at_most="MAX_ROBOTS")
    radius = ok(_number, src, m.get("radius", RobotSpec.radius), "robots.radius", positive=True, **_RADIUS)
    max_speed = ok(_number, src, m.get("max_speed", RobotSpec.max_speed), "robots.max_speed", positive=True, **_SPEED)
    max_turn = ok(_number, src, m.get("max_turn_rate", RobotSpec.max_turn_rate), "robots.max_turn_rate", positive=True,
                  at_most="MAX_TURN_RATE")
    max_accel = ok(_optional_positive, src, m.get("max_accel", RobotSpec.max_accel), "robots.max_accel")
    max_turn_accel = ok(_optional_positive, src, m.get("max_turn_accel", RobotSpec.max_turn_accel), "robots.max_turn_accel")
    wheelbase = ok(_number, src, m.get("wheelbase", RobotSpec.wheelbase), "robots.wheelbase", positive=True,
                   at_most="MAX_WORLD_SIZE")
    start = ok(_start, src, m.get("start", "formation"), count, ok)
    return ok(
        RobotSpec,
        count=count,
        radius=radius,
        max_speed=max_speed,
        max_turn_rate=max_turn,
        max_accel=max_accel,
        max_turn_accel=max_turn_accel,
        wheelbase=wheelbase,
        start=start,
    )


def _start(src: str, raw_start: Any, count: int, ok: _Errors) -> Any:
    """``robots.start``: ``"formation"`` or one checked ``[x, y, theta]`` pose per follower."""
    if isinstance(raw_start, str):
        if raw_start != "formation":
            raise ScenarioError(src, "robots.start", "'formation' or a list of [x, y, theta] poses", raw_start)
        return "formation"
    poses = _sequence(src, raw_start, "robots.start", "'formation' or a list of [x, y, theta] poses", "MAX_ROBOTS", "poses")
    if len(poses) != count:
        raise ScenarioError(
            src, "robots.start", f"one [x, y, theta] pose per follower (robots.count = {count})", f"{len(poses)} poses"
        )
    return ok.all(tuple(ok(_numbers, src, p, f"robots.start[{i}]", 3, "[x, y, theta_rad]") for i, p in enumerate(poses)))


def _parse_leader(src: str, value: Any, ok: _Errors) -> LeaderSpec:
    m = _mapping(src, value, "leader")
    _check_keys(src, m, "leader", _LEADER_KEYS, ("kind", "path", "speed"), ok)
    kind = ok(_choice, src, m.get("kind", _BAD), "leader.kind", LEADER_KINDS)
    speed = ok(_number, src, m.get("speed", _BAD), "leader.speed", positive=True, **_SPEED)
    radius = ok(_number, src, m.get("radius", LeaderSpec.radius), "leader.radius", positive=True, **_RADIUS)
    max_turn = ok(_number, src, m.get("max_turn_rate", LeaderSpec.max_turn_rate), "leader.max_turn_rate", positive=True,
                  at_most="MAX_TURN_RATE")
    lookahead = ok(_number, src, m.get("lookahead", LeaderSpec.lookahead), "leader.lookahead", positive=True,
                   at_most="MAX_WORLD_SIZE")
    delay = ok(_number, src, m.get("start_delay", LeaderSpec.start_delay), "leader.start_delay", nonnegative=True)
    path = ok(_path, src, m.get("path", _BAD), "leader.path", ok)
    return ok(
        LeaderSpec, kind=kind, path=path, speed=speed, radius=radius, max_turn_rate=max_turn, lookahead=lookahead,
        start_delay=delay,
    )


def _plain_count(robots: Any) -> int | None:
    """``robots.count`` when it is valid although another robots key is not (``None``: unknown)."""
    n = robots.get("count") if isinstance(robots, Mapping) else None
    if not isinstance(n, numbers.Integral) or isinstance(n, (bool, np.bool_)):
        return None
    return int(n) if 1 <= int(n) <= _limit("MAX_ROBOTS") else None


def _parse_formations(src: str, value: Any, count: int | None, ok: _Errors) -> tuple[FormationSpec, ...]:
    """``count`` is ``robots.count`` (``None`` when that is invalid: the offsets are then not counted)."""
    items = _sequence(src, value, "formations", "a list of at least one formation entry", "MAX_FORMATIONS", "entries")
    if not items:
        raise ScenarioError(src, "formations", "at least one formation entry (the one active at t = 0)", [])
    return ok.all(tuple(ok(_parse_formation, src, item, f"formations[{i}]", count, ok) for i, item in enumerate(items)))


def _parse_formation(src: str, item: Any, key: str, count: int | None, ok: _Errors) -> FormationSpec:
    m = _mapping(src, item, key)
    _check_keys(src, m, key, _FORMATION_KEYS, ("at", "shape"), ok)
    at = ok(_number, src, m.get("at", _BAD), f"{key}.at", nonnegative=True)
    shape = ok(_choice, src, m.get("shape", _BAD), f"{key}.shape", FORMATION_SHAPES)
    spacing = ok(_number, src, m.get("spacing", FormationSpec.spacing), f"{key}.spacing", positive=True,
                 at_most="MAX_WORLD_SIZE")
    angle = ok(_number, src, m.get("angle", FormationSpec.angle), f"{key}.angle")
    columns = ok(_integer, src, m.get("columns", FormationSpec.columns), f"{key}.columns", minimum=0,
                 at_most="MAX_ROBOTS")
    offsets = ok(_offsets_of, src, m, key, shape, count, ok)
    return ok(FormationSpec, at=at, shape=shape, spacing=spacing, angle=angle, offsets=offsets, columns=columns)


def _offsets_of(src: str, m: Mapping[str, Any], key: str, shape: str, count: int | None, ok: _Errors) -> Any:
    """A formation's ``offsets``: required (one per follower) for ``custom``, refused otherwise."""
    if shape != "custom":
        if m.get("offsets") is not None:
            raise ScenarioError(
                src, f"{key}.offsets", f"no offsets for shape {shape!r} (offsets are for shape 'custom' only)", "offsets"
            )
        return None
    per = "per follower" if count is None else f"per follower (robots.count = {count})"
    if "offsets" not in m or m["offsets"] is None:
        n = "one" if count is None else str(count)
        raise ScenarioError(src, f"{key}.offsets", f"a list of {n} [x, y] offsets (required by shape 'custom')")
    pts = _sequence(src, m["offsets"], f"{key}.offsets", "a list of [x, y] offsets", "MAX_ROBOTS", "offsets")
    if count is not None and len(pts) != count:
        raise ScenarioError(src, f"{key}.offsets", f"one [x, y] offset {per}", f"{len(pts)} offsets")
    return ok.all(tuple(ok(_point, src, p, f"{key}.offsets[{j}]") for j, p in enumerate(pts)))


def _parse_obstacle(src: str, value: Any, key: str, ok: _Errors) -> Obstacle:
    m = _mapping(src, value, key)
    if "type" not in m:
        raise ScenarioError(
            src, f"{key}.type", "one of " + ", ".join(repr(t) for t in _OBSTACLE_KEYS) + " (required key missing)"
        )
    kind = _choice(src, m["type"], f"{key}.type", tuple(_OBSTACLE_KEYS))
    allowed = _OBSTACLE_KEYS[kind]
    _check_keys(src, m, key, allowed, allowed[:-1] if kind == "rectangle" else allowed, ok)
    if kind == "circle":
        center = ok(_point, src, m.get("center", _BAD), f"{key}.center")
        radius = ok(_number, src, m.get("radius", _BAD), f"{key}.radius", positive=True, at_most="MAX_WORLD_SIZE",
                    at_least="MIN_OBSTACLE_SIZE")
        return ok(CircleObstacle, center=center, radius=radius)
    if kind == "rectangle":
        center = ok(_point, src, m.get("center", _BAD), f"{key}.center")
        size = ok(_sizes, src, m.get("size", _BAD), f"{key}.size", "a positive side length (m)")
        angle = ok(_number, src, m.get("angle", RectangleObstacle.angle), f"{key}.angle")
        return ok(RectangleObstacle, center=center, size=size, angle=angle)
    if "points" not in m:
        return _BAD  # reported by _check_keys
    pts = _sequence(src, m["points"], f"{key}.points", "a list of at least 3 [x, y] vertices", "MAX_POLYGON_VERTICES",
                    "vertices")
    if len(pts) < 3:
        raise ScenarioError(src, f"{key}.points", "at least 3 [x, y] vertices of a convex polygon", f"{len(pts)} points")
    points = ok.all(tuple(ok(_point, src, p, f"{key}.points[{j}]") for j, p in enumerate(pts)))
    return ok(PolygonObstacle, points=ok(_convex_ccw, src, points, f"{key}.points"))


def _parse_human(src: str, value: Any, key: str, ok: _Errors) -> HumanSpec:
    m = _mapping(src, value, key)
    _check_keys(src, m, key, _HUMAN_KEYS, ("path",), ok)
    speed = ok(_number, src, m.get("speed", HumanSpec.speed), f"{key}.speed", positive=True, **_SPEED)
    radius = ok(_number, src, m.get("radius", HumanSpec.radius), f"{key}.radius", positive=True, **_RADIUS)
    mode = ok(_choice, src, m.get("mode", HumanSpec.mode), f"{key}.mode", HUMAN_MODES)
    delay = ok(_number, src, m.get("start_delay", HumanSpec.start_delay), f"{key}.start_delay", nonnegative=True)
    behavior = ok(_choice, src, m.get("behavior", HumanSpec.behavior), f"{key}.behavior", HUMAN_BEHAVIORS)
    path = ok(_path, src, m.get("path", _BAD), f"{key}.path", ok)
    return ok(HumanSpec, path=path, speed=speed, radius=radius, mode=mode, start_delay=delay, behavior=behavior)


def _parse_sensors(src: str, value: Any, ok: _Errors | None = None) -> SensorSpec:
    """The ``sensors`` section; without ``ok`` (callers outside a file: env and generator arguments) its
    errors are raised together."""
    if ok is None:
        return _alone(_parse_sensors, src, value)
    m = _mapping(src, value, "sensors")
    _check_keys(src, m, "sensors", _SENSOR_KEYS, (), ok)
    d = SensorSpec()
    return ok(
        SensorSpec,
        lidar_rays=ok(_integer, src, m.get("lidar_rays", d.lidar_rays), "sensors.lidar_rays", minimum=1,
                      at_most="MAX_LIDAR_RAYS"),
        lidar_range=ok(_number, src, m.get("lidar_range", d.lidar_range), "sensors.lidar_range", positive=True,
                       at_most="MAX_WORLD_SIZE"),
        neighbors=ok(_integer, src, m.get("neighbors", d.neighbors), "sensors.neighbors", minimum=0,
                     at_most="MAX_NEIGHBORS"),
        humans=ok(_integer, src, m.get("humans", d.humans), "sensors.humans", minimum=0, at_most="MAX_SENSED_HUMANS"),
    )


def _parse_reward(src: str, value: Any, ok: _Errors | None = None) -> RewardSpec:
    """The ``reward`` section; without ``ok``, as :func:`_parse_sensors`."""
    if ok is None:
        return _alone(_parse_reward, src, value)
    m = _mapping(src, value, "reward")
    _check_keys(src, m, "reward", _REWARD_KEYS, (), ok)
    d = RewardSpec()
    # Weights are magnitudes: the sign of each term is fixed by the env (penalty or bonus).
    vals = {k: ok(_number, src, m.get(k, getattr(d, k)), f"reward.{k}", nonnegative=True) for k in _REWARD_KEYS}
    for k in ("clearance_margin", "approach_margin"):  # divisors of their terms
        if vals[k] is not _BAD and not vals[k] > 0:
            ok.add(ScenarioError(src, f"reward.{k}", "a number > 0 (m)", vals[k]))
            vals[k] = _BAD
    return ok(RewardSpec, **vals)


# --------------------------------------------------------------------------- cross-section checks


def _check_bounds(src: str, scn: Scenario, ok: _Errors) -> None:
    """The bounds of :mod:`swarm_env.limits` that set the work of validating and simulating ``scn``,
    for scenarios built in Python (the ``random`` generator's): a file's values were checked
    one by one as they were parsed. Also the derived count: control steps per episode."""
    w, r, se = scn.world, scn.robots, scn.sensors
    counts = (
        (r.count, "robots.count", "MAX_ROBOTS", "followers"),
        (len(scn.humans), "humans", "MAX_HUMANS", "entries"),
        (len(scn.obstacles), "obstacles", "MAX_OBSTACLES", "entries"),
        (len(scn.formations), "formations", "MAX_FORMATIONS", "entries"),
        (len(scn.leader.path), "leader.path", "MAX_WAYPOINTS", "waypoints"),
        (w.substeps, "world.substeps", "MAX_SUBSTEPS", "substeps"),
        (se.lidar_rays, "sensors.lidar_rays", "MAX_LIDAR_RAYS", "rays"),
        (se.neighbors, "sensors.neighbors", "MAX_NEIGHBORS", "rows"),
        (se.humans, "sensors.humans", "MAX_SENSED_HUMANS", "rows"),
    )
    for n, key, limit, what in counts:
        ok(_count_limit, src, int(n), key, limit, what)
    if len(scn.obstacles) <= _limit("MAX_OBSTACLES"):
        ok(_count_limit, src, obstacle_vertices(scn), "obstacles", "MAX_OBSTACLE_VERTICES",
           "obstacle vertices")
    for i, side in enumerate(w.size):
        if not 0.0 < side <= MAX_WORLD_SIZE:
            ok.add(ScenarioError(src, f"world.size[{i}]", f"a positive size (m) of at most {_bound_text('MAX_WORLD_SIZE')}",
                                 side))
    if not (math.isfinite(w.dt) and math.isfinite(w.max_time)) or not _limit("MIN_DT") <= w.dt <= _limit("MAX_DT"):
        ok.add(ScenarioError(src, "world.dt", f"a control period in [{_limit('MIN_DT'):g}, {_limit('MAX_DT'):g}] s "
                             "(swarm_env.limits.MIN_DT, MAX_DT) and a finite max_time", w.dt))
        return
    steps = math.floor(w.max_time / w.dt + 1e-9)
    if steps > MAX_EPISODE_STEPS:
        ok.add(ScenarioError(
            src, "world.max_time",
            f"at most {_bound_text('MAX_EPISODE_STEPS')} control steps per episode: max_time / dt = "
            f"{w.max_time:g} / {w.dt:g} = {steps} steps (shorten max_time or lengthen dt)",
            w.max_time,
        ))


def obstacle_vertices(scn: Scenario) -> int:
    """The vertices of ``scn``'s obstacles all together, as :data:`swarm_env.limits.MAX_OBSTACLE_VERTICES`
    counts them: a polygon its points, a rectangle 4, a circle 1."""
    return sum(len(o.points) if isinstance(o, PolygonObstacle) else 4 if isinstance(o, RectangleObstacle) else 1
               for o in scn.obstacles)


def _check_world(src: str, scn: Scenario) -> None:
    w = scn.world
    if w.max_time < w.dt:
        raise ScenarioError(src, "world.max_time", f"at least one control period (world.dt = {w.dt})", w.max_time)


def _check_geometry(src: str, scn: Scenario, ok: _Errors) -> None:
    """Every point of the scenario inside the world (discs by their radius); paths of distinct
    waypoints; polygons convex, stored counter-clockwise."""
    world, r = scn.world, scn.robots
    if r.start != "formation":
        for i, pose in enumerate(r.start):
            ok(_inside, src, (pose[0], pose[1]), r.radius, world, f"robots.start[{i}]", "follower disc")
    ld = scn.leader
    # A virtual leader is a point; a robot leader's whole disc must fit in the world.
    robot = ld.kind == "robot"
    _check_path(src, ld.path, "leader.path", world, ld.radius if robot else 0.0, "robot leader disc" if robot else "waypoint",
                ok)
    for k, o in enumerate(scn.obstacles):
        key = f"obstacles[{k}]"
        if isinstance(o, PolygonObstacle):
            for j, p in enumerate(o.points):
                ok(_inside, src, p, 0.0, world, f"{key}.points[{j}]", "polygon vertex")
            ok(_check_ccw, src, o.points, f"{key}.points")
        else:
            ok(_inside, src, o.center, 0.0, world, f"{key}.center", "obstacle centre")
    for j, h in enumerate(scn.humans):
        _check_path(src, h.path, f"humans[{j}].path", world, h.radius, "human disc", ok)


def _check_ccw(src: str, points: Sequence[Point], key: str) -> None:
    if _convex_ccw(src, points, key) != tuple(points):
        raise ScenarioError(src, key, "convex polygon vertices in counter-clockwise order", list(points))


def _check_schedule(src: str, scn: Scenario, ok: _Errors) -> None:
    """The formation schedule: first at 0, strictly increasing; shape parameters that apply."""
    prev_at = -math.inf
    for i, f in enumerate(scn.formations):
        key = f"formations[{i}]"
        if i == 0 and f.at != 0.0:
            ok.add(ScenarioError(src, f"{key}.at", "0.0 for the first formation (one must be active from the start)", f.at))
        elif f.at <= prev_at:
            ok.add(ScenarioError(src, f"{key}.at", f"a time strictly after the previous entry's at = {prev_at}", f.at))
        prev_at = f.at
        lo = _limit("MIN_FORMATION_ANGLE")
        if not lo <= f.angle <= 180.0 - lo:
            ok.add(ScenarioError(src, f"{key}.angle", f"an arm half-opening in degrees within [{lo:g}, {180 - lo:g}] "
                                 "(swarm_env.limits.MIN_FORMATION_ANGLE)", f.angle))
        if f.shape == "wedge" and f.angle == 90.0:
            ok.add(ScenarioError(
                src, f"{key}.angle", "a wedge half-opening other than 90 degrees (its rows would coincide)", f.angle
            ))
        if f.columns and f.shape != "grid":
            ok.add(ScenarioError(src, f"{key}.columns", f"no columns for shape {f.shape!r} (only 'grid' uses them)",
                                 f.columns))
        if f.shape == "custom" and (f.offsets is None or len(f.offsets) != scn.robots.count):
            got = "none" if f.offsets is None else f"{len(f.offsets)} offsets"
            ok.add(ScenarioError(src, f"{key}.offsets",
                                 f"one [x, y] offset per follower (robots.count = {scn.robots.count})", got))


def _tunnel_terms(scn: Scenario) -> tuple[float, float]:
    """``(v_rel, r_min)`` of the anti-tunnelling rule (see the module docstring)."""
    v_max = max(scn.robots.max_speed, scn.leader.speed)
    v_human = max((h.top_speed for h in scn.humans), default=0.0)
    radii = [scn.robots.radius] + [h.radius for h in scn.humans]
    if scn.leader.kind == "robot":
        radii.append(scn.leader.radius)
    return 2.0 * v_max + v_human, min(radii)


def _cross_check(src: str, scn: Scenario, ok: _Errors) -> None:
    r, ld, w = scn.robots, scn.leader, scn.world
    if ld.speed > r.max_speed + _EPS:
        ok.add(ScenarioError(
            src, "leader.speed", f"at most robots.max_speed = {r.max_speed} (followers could never keep up)", ld.speed
        ))

    v_rel, r_min = _tunnel_terms(scn)
    need = min_substeps(scn)
    if w.substeps < need:
        ok.add(ScenarioError(
            src,
            "world.substeps",
            f"at least {need}: the anti-tunnelling rule needs v_rel * dt / substeps <= r_min with "
            f"v_rel = {v_rel:g} m/s, dt = {w.dt:g} s, r_min = {r_min:g} m",
            w.substeps,
        ))

    for i in range(len(scn.formations)):  # only formations whose own parameters passed (they are laid out here)
        if not any(e.key.startswith(f"formations[{i}].") for e in ok.errors):
            ok(_check_slots, src, scn, i)
    if not ok.errors:  # the starting poses come from the first formation and the path: only once those are sound
        ok(_check_start, src, scn)


def _offsets(src: str, scn: Scenario, i: int) -> np.ndarray:
    try:
        return np.asarray(formation_offsets(scn.formations[i], scn.robots.count), dtype=np.float64)
    except ValueError as exc:  # e.g. a wedge at exactly 90 degrees
        raise ScenarioError(src, f"formations[{i}]", f"a formation that can be laid out ({exc})") from None


def _check_slots(src: str, scn: Scenario, i: int) -> None:
    """The slots of formation ``i`` must leave room for the follower discs (and a robot leader's disc)."""
    r = scn.robots.radius
    f = scn.formations[i]
    key = f"formations[{i}]." + ("offsets" if f.shape == "custom" else "spacing")
    got = [list(p) for p in f.offsets] if f.offsets is not None else f.spacing
    off = _offsets(src, scn, i)
    if off.shape[0] > 1:
        d = np.linalg.norm(off[:, None, :] - off[None, :, :], axis=-1)
        d[np.diag_indices_from(d)] = np.inf
        a, b = np.unravel_index(int(np.argmin(d)), d.shape)
        if d[a, b] < 2.0 * r - 1e-6:
            raise ScenarioError(
                src,
                key,
                f"slots at least 2 * robots.radius = {2 * r:g} m apart (slots {a} and {b} are {d[a, b]:.3g} m apart)",
                got,
            )
    if scn.leader.kind == "robot":
        norms = np.linalg.norm(off, axis=1)
        k = int(np.argmin(norms))
        need = r + scn.leader.radius
        if norms[k] < need - 1e-6:
            raise ScenarioError(
                src,
                key,
                f"slots at least robots.radius + leader.radius = {need:g} m from the robot leader "
                f"(slot {k} is {norms[k]:.3g} m from it)",
                got,
            )


def start_poses(scn: Scenario) -> np.ndarray:
    """``(N, 3)`` starting poses ``(x, y, theta)`` of the followers.

    Explicit ``robots.start`` poses, or with ``start: formation`` the slots of
    ``formations[0]`` around a leader standing on ``path[0]`` facing ``path[1]``
    (no obstacle projection), each follower facing the leader's heading.
    """
    r = scn.robots
    if r.start != "formation":
        return np.asarray(r.start, dtype=np.float64).reshape(-1, 3)
    return formation_start(scn.leader.path, formation_offsets(scn.formations[0], r.count))


def _check_start(src: str, scn: Scenario) -> None:
    """Starting discs inside the world and clear of obstacles, each other, a robot leader and the humans."""
    r = scn.robots.radius
    explicit = scn.robots.start != "formation"
    poses = start_poses(scn)
    xy = poses[:, :2]

    def fail(i: int, why: str) -> None:
        if explicit:
            raise ScenarioError(src, f"robots.start[{i}]", why, [float(v) for v in poses[i]])
        raise ScenarioError(
            src, "robots.start", why + " with start: formation (move the path start or give explicit poses)", "formation"
        )

    w, h = scn.world.size
    for i, (x, y) in enumerate(xy):
        if not (r - 1e-9 <= x <= w - r + 1e-9 and r - 1e-9 <= y <= h - r + 1e-9):
            fail(i, f"follower discs inside the world [0, {w:g}] x [0, {h:g}] (follower {i} starts at ({x:.3g}, {y:.3g}))")
    if scn.obstacles:
        static = StaticMap.from_obstacles(scn.world.size, scn.obstacles)
        dist = static.distance(xy, walls=False)
        bad = np.flatnonzero(dist < r - 1e-6)
        if bad.size:
            i = int(bad[0])
            fail(i, f"follower discs clear of obstacles (follower {i} at ({xy[i, 0]:.3g}, {xy[i, 1]:.3g}) is "
                    f"{dist[i]:.3g} m from one, radius {r:g})")
        for j, hum in enumerate(scn.humans):  # a human that starts inside an obstacle is stuck (or pushed out)
            dh = float(static.distance(np.asarray(hum.path[0], dtype=np.float64), walls=False))
            if dh < hum.radius - 1e-6:
                raise ScenarioError(
                    src, f"humans[{j}].path[0]", f"a human start clear of obstacles (its disc of radius {hum.radius:g} m "
                    f"is {dh:.3g} m from one)", list(hum.path[0]),
                )
        if scn.leader.kind == "robot":
            d0 = float(static.distance(np.asarray(scn.leader.path[0], dtype=np.float64), walls=False))
            if d0 < scn.leader.radius - 1e-6:
                raise ScenarioError(
                    src, "leader.path[0]", f"a robot leader start clear of obstacles ({d0:.3g} m from one)",
                    list(scn.leader.path[0]),
                )
    if len(xy) > 1:
        d = np.linalg.norm(xy[:, None, :] - xy[None, :, :], axis=-1)
        d[np.diag_indices_from(d)] = np.inf
        a, b = np.unravel_index(int(np.argmin(d)), d.shape)
        if d[a, b] < 2 * r - 1e-6:
            fail(int(b), f"non-overlapping follower discs (followers {a} and {b} start {d[a, b]:.3g} m apart)")
    # Other discs present at t = 0: the robot leader and the humans on their first waypoints.
    others: list[tuple[str, np.ndarray, float]] = []
    if scn.leader.kind == "robot":
        others.append(("the robot leader", np.asarray(scn.leader.path[0], dtype=np.float64), scn.leader.radius))
    for j, hum in enumerate(scn.humans):
        others.append((f"humans[{j}]", np.asarray(hum.path[0], dtype=np.float64), hum.radius))
    for name, p, rad in others:
        d = np.linalg.norm(xy - p, axis=1)
        i = int(np.argmin(d))
        if d[i] < r + rad - 1e-6:
            fail(i, f"follower discs clear of {name} at ({p[0]:.3g}, {p[1]:.3g}) (follower {i} is {d[i]:.3g} m away)")
    if scn.leader.kind == "robot":
        p = np.asarray(scn.leader.path[0], dtype=np.float64)
        for j, hum in enumerate(scn.humans):
            dd = float(np.linalg.norm(np.asarray(hum.path[0]) - p))
            if dd < hum.radius + scn.leader.radius - 1e-6:
                raise ScenarioError(
                    src, f"humans[{j}].path[0]", f"a human start clear of the robot leader's start ({dd:.3g} m away)",
                    list(hum.path[0]),
                )


# --------------------------------------------------------------------------- geometry helpers


def _convex_ccw(src: str, points: Sequence[Point], key: str) -> tuple[Point, ...]:
    """``points`` counter-clockwise (via :func:`swarm_env.geometry.static_map.convex_ccw`), or a ScenarioError.

    Collinear vertices are allowed; zero-area, non-convex and self-intersecting
    vertex orders are not.
    """
    try:
        out = convex_ccw(np.asarray(points, dtype=np.float64))
    except ValueError as exc:
        raise ScenarioError(
            src, key, f"the vertices of a convex polygon with non-zero area, in boundary order ({exc})",
            [list(p) for p in points],
        ) from None
    return tuple((float(x), float(y)) for x, y in np.asarray(out, dtype=np.float64))


def _path(src: str, value: Any, key: str, ok: _Errors) -> tuple[Point, ...]:
    pts = _sequence(src, value, key, "a list of at least 2 [x, y] waypoints", "MAX_WAYPOINTS", "waypoints")
    if len(pts) < 2:
        raise ScenarioError(src, key, "at least 2 [x, y] waypoints", f"{len(pts)} points")
    return ok.all(tuple(ok(_point, src, p, f"{key}[{i}]") for i, p in enumerate(pts)))


def _check_path(
    src: str, path: Sequence[Point], key: str, world: WorldSpec, margin: float, what: str, ok: _Errors
) -> None:
    if len(path) < 2:
        ok.add(ScenarioError(src, key, "at least 2 [x, y] waypoints", f"{len(path)} points"))
        return
    for i, p in enumerate(path):
        ok(_inside, src, p, margin, world, f"{key}[{i}]", what)
        if i and math.dist(p, path[i - 1]) < 1e-9:
            ok.add(ScenarioError(src, f"{key}[{i}]", "a waypoint different from the previous one", list(p)))


def _inside(src: str, p: Point, margin: float, world: WorldSpec, key: str, what: str) -> None:
    w, h = world.size
    if not (margin - 1e-9 <= p[0] <= w - margin + 1e-9 and margin - 1e-9 <= p[1] <= h - margin + 1e-9):
        extra = f" (a {what} of radius {margin:g} must fit)" if margin > 0 else ""
        raise ScenarioError(
            src,
            key,
            f"a point inside the world [{margin:g}, {w - margin:g}] x [{margin:g}, {h - margin:g}]{extra}",
            list(p),
        )


# --------------------------------------------------------------------------- value helpers


class _Shown:
    """A value as an error message shows it (its bounded repr), standing in for a large one."""

    def __init__(self, text: str) -> None:
        self.text = text

    def __repr__(self) -> str:
        return self.text


def _short(value: Any) -> Any:
    """``value`` itself when it is a scalar, else its bounded repr (:func:`swarm_env.limits.clip_repr`):
    an error never holds on to, or walks the whole of, a huge or self-containing structure."""
    if value is None or isinstance(value, (bool, float, str)) or (isinstance(value, int) and value.bit_length() <= 256):
        return value
    return _Shown(clip_repr(value))


def _is_number(value: Any) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))


def _limit(name: str) -> float:
    """The value of the bound ``name`` of :data:`swarm_env.limits.LIMITS`."""
    return LIMITS[name][0]


def _bound_text(name: str) -> str:
    """How a message names a bound: its value and where it is defined."""
    return f"{_limit(name):g} (swarm_env.limits.{name})"


def _number(
    src: str,
    value: Any,
    key: str,
    *,
    positive: bool = False,
    nonnegative: bool = False,
    at_most: str = "MAX_ABS_NUMBER",
    at_least: str | None = None,
) -> float:
    """A finite real number; ``at_most`` / ``at_least`` name its bounds in :data:`swarm_env.limits.LIMITS`
    (``at_most`` bounds the magnitude of a signed number)."""
    kind = "a positive number" if positive else "a non-negative number" if nonnegative else "a number"
    if not _is_number(value):
        hint = ""
        if isinstance(value, str):
            try:
                float(value)
                hint = (" (YAML 1.1 reads numbers with an exponent as text unless they have a dot and a signed "
                        "exponent: write 1.0e+3, not 1e3 or 1.0e3)")
            except (ValueError, OverflowError):
                pass
        raise ScenarioError(src, key, kind + hint, _short(value))
    try:
        x = float(value)
    except OverflowError:  # an integer beyond float range (from a dict: files bound their digits)
        x = math.inf if value > 0 else -math.inf
    if not math.isfinite(x):
        raise ScenarioError(src, key, "a finite " + kind.removeprefix("a "), _short(value))
    if (positive and x <= 0) or (nonnegative and x < 0):
        raise ScenarioError(src, key, kind, _short(value))
    hi = _limit(at_most)
    signed = not (positive or nonnegative)
    if (abs(x) if signed else x) > hi:
        what = "magnitude" if signed else "value"
        raise ScenarioError(src, key, f"{kind} of {what} at most {_bound_text(at_most)}", _short(value))
    if at_least is not None and x < _limit(at_least):
        raise ScenarioError(src, key, f"{kind} of at least {_bound_text(at_least)}", _short(value))
    return x


def _optional_positive(src: str, value: Any, key: str) -> float | None:
    if value is None:
        return None
    if not _is_number(value):
        raise ScenarioError(src, key, "a positive number or null (unlimited)", _short(value))
    return _number(src, value, key, positive=True)


def _count_limit(src: str, n: int, key: str, limit: str, what: str) -> None:
    """``n`` (a number of entries, items or the like) is at most the bound ``limit``."""
    if n > _limit(limit):
        raise ScenarioError(src, key, f"at most {_bound_text(limit)} {what}", f"{n} {what}")


def _integer(src: str, value: Any, key: str, *, minimum: int, at_most: str) -> int:
    """An integer in ``[minimum, LIMITS[at_most]]``."""
    hi = int(_limit(at_most))
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
        raise ScenarioError(src, key, f"an integer in [{minimum}, {hi}]", _short(value))
    if int(value) < minimum:
        raise ScenarioError(src, key, f"an integer >= {minimum}", _short(value))
    if int(value) > hi:
        raise ScenarioError(src, key, f"an integer of at most {_bound_text(at_most)}", _short(value))
    return int(value)


def _string(src: str, value: Any, key: str, *, at_most: str, nonempty: bool = False, allowed: str = "") -> str:
    """A string of at most ``LIMITS[at_most]`` characters without control, bidi or other invisible
    characters (those in ``allowed`` excepted): it is printed by ``swarm-env`` and written in files."""
    if not isinstance(value, str) or (nonempty and not value.strip()):
        raise ScenarioError(src, key, "a non-empty string" if nonempty else "a string", _short(value))
    if len(value) > _limit(at_most):
        raise ScenarioError(src, key, f"a string of at most {_bound_text(at_most)} characters",
                            f"{len(value)} characters")
    bad = unprintable_chars(value, allowed)
    if bad:
        shown = ", ".join(printable(c) for c in bad[:5])
        raise ScenarioError(src, key, "a string without control, bidi or other invisible characters "
                            f"(found {shown})", _short(value))
    return value


def _choice(src: str, value: Any, key: str, allowed: Sequence[str]) -> Any:
    if not isinstance(value, str) or value not in allowed:
        raise ScenarioError(src, key, "one of " + ", ".join(repr(a) for a in allowed), _short(value))
    return value


def _mapping(src: str, value: Any, key: str) -> Mapping[str, Any]:
    if value is None:  # an empty YAML section (`sensors:`) parses to None
        value = {}
    if not isinstance(value, Mapping):
        raise ScenarioError(src, key, "a mapping", _short(value))
    return value


def _sequence(src: str, value: Any, key: str, expected: str, at_most: str | None = None, what: str = "items") -> list[Any]:
    """A list (of at most ``LIMITS[at_most]`` ``what``, checked before it is copied)."""
    if isinstance(value, np.ndarray):
        if at_most is not None:
            _count_limit(src, len(value), key, at_most, what)
        value = value.tolist()
    if isinstance(value, (str, bytes)) or not isinstance(value, Sequence):
        raise ScenarioError(src, key, expected, _short(value))
    if at_most is not None:
        _count_limit(src, len(value), key, at_most, what)
    return list(value)


def _numbers(src: str, value: Any, key: str, n: int, form: str) -> tuple[float, ...]:
    if isinstance(value, Sequence) and not isinstance(value, (str, bytes)) and len(value) != n:
        raise ScenarioError(src, key, f"a list {form} of {n} numbers", _short(value))
    seq = _sequence(src, value, key, f"a list {form}")
    return tuple(_number(src, v, f"{key}[{i}]") for i, v in enumerate(seq))


def _point(src: str, value: Any, key: str) -> Point:
    x, y = _numbers(src, value, key, 2, "[x, y]")
    return (x, y)


def _sizes(src: str, value: Any, key: str, expected: str) -> Point:
    """A ``[w, h]`` pair of positive numbers of at most ``MAX_WORLD_SIZE`` (``expected`` says what each is)."""
    size = _point(src, value, key)
    for i, v in enumerate(size):
        if v <= 0:
            raise ScenarioError(src, f"{key}[{i}]", expected, v)
        if v < MIN_OBSTACLE_SIZE:  # world sides are far above it; a thinner rectangle is degenerate
            raise ScenarioError(src, f"{key}[{i}]", f"{expected} of at least {_bound_text('MIN_OBSTACLE_SIZE')}", v)
        if v > MAX_WORLD_SIZE:
            raise ScenarioError(src, f"{key}[{i}]", f"{expected} of at most {_bound_text('MAX_WORLD_SIZE')}", v)
    return size


def _parse_list(src: str, value: Any, key: str, parse: Callable[..., Any], at_most: str, ok: _Errors) -> tuple:
    """``parse(src, item, "key[i]", ok)`` of every item of an optional list section (``None``: empty)
    of at most ``LIMITS[at_most]`` entries."""
    if value is None:
        return ()
    items = _sequence(src, value, key, "a list", at_most, "entries")
    return ok.all(tuple(ok(parse, src, item, f"{key}[{i}]", ok) for i, item in enumerate(items)))


def _check_keys(
    src: str, m: Mapping[str, Any], key: str, allowed: Sequence[str], required: Sequence[str], ok: _Errors
) -> None:
    """Report (to ``ok``) every unknown key of the mapping ``m`` at ``key`` and every missing required one."""
    prefix = f"{key}." if key else ""
    for k in m:
        if not isinstance(k, str):
            ok.add(ScenarioError(src, f"{prefix}{clip_repr(k)}", "string keys", _short(k)))
        elif k not in allowed:
            hint = did_you_mean(k, allowed)
            where = f"the keys of {key}" if key else "the top-level sections"
            ok.add(ScenarioError(src, f"{prefix}{printable(k, MESSAGE_VALUE_CHARS)}",
                                 f"one of {where}: {', '.join(allowed)}{hint}", k))
    for k in required:
        if k not in m:
            ok.add(ScenarioError(src, f"{prefix}{k}", "a value (required key missing)"))


def _floats(p: Sequence[float]) -> list[float]:
    return [float(v) for v in p]


def _formation_to_dict(f: FormationSpec) -> dict[str, Any]:
    d: dict[str, Any] = {"at": float(f.at), "shape": f.shape, "spacing": float(f.spacing), "angle": float(f.angle)}
    if f.shape == "grid":
        d["columns"] = int(f.columns)
    if f.offsets is not None:
        d["offsets"] = [_floats(p) for p in f.offsets]
    return d


def _obstacle_to_dict(o: Obstacle) -> dict[str, Any]:
    if isinstance(o, CircleObstacle):
        return {"type": "circle", "center": _floats(o.center), "radius": float(o.radius)}
    if isinstance(o, RectangleObstacle):
        return {"type": "rectangle", "center": _floats(o.center), "size": _floats(o.size), "angle": float(o.angle)}
    return {"type": "polygon", "points": [_floats(p) for p in o.points]}
