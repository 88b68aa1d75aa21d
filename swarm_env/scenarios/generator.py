"""Procedural scenarios: a random world drawn from a :class:`numpy.random.Generator`.

:func:`random_scenario` is what ``parallel_env("random", **knobs)`` uses (a fresh
world per ``reset(seed)``); its knobs are the fields of
:class:`RandomScenarioConfig`. The generator uses only the ``rng`` it is given, so
the same generator state always gives the same :class:`~swarm_env.scenario.Scenario`.
Every result is a :class:`~swarm_env.scenario.Scenario` built directly and passed
through :func:`swarm_env.scenarios.loader.validate_scenario`, the gate YAML files pass too;
:func:`swarm_env.scenarios.loader.scenario_to_dict` turns it into a YAML file that loads
back to the same scenario.

What a generated world looks like (units m, s):

* a world of ``world_size`` (by default ``auto``: 20 m x 20 m, grown for big
  formations so that the formation fits beside the path; 64 followers in a
  line take about 95 m);
* a leader (``leader_kind``) on a path of ``n_waypoints`` (2-4) waypoints with turns of at most
  60 degrees, long enough to take about 70 % of ``max_time`` at ``leader_speed``
  (shorter when the world is too small), kept away from the walls by about the
  formation's radius so the formation fits beside it;
* **feasible slot targets**: every corner is rounded by a circular arc (written
  as a polyline with one vertex per step of travel) of radius at least
  ``R = rho * v / (0.9 * max_speed - v)``, where ``rho`` is the largest slot
  distance from the leader over the schedule and ``v`` the leader speed, so a
  slot never has to move faster than ``0.9 * max_speed`` while the leader turns;
  turns are drawn smaller where such an arc does not fit (a leader at
  ``0.9 * max_speed`` or faster drives straight). A robot leader's turn rate is
  capped at ``(0.9 * max_speed - v) / rho`` for the same reason. Obstacles whose
  projection would make a slot jump faster than ``max_speed`` are dropped
  (:func:`slot_speed_violations` is the check; formation switches are jumps by
  design and excluded);
* a formation schedule of ``1 + n_switches`` entries drawn from ``shapes``
  (consecutive entries differ when there is a choice), switching at times spread
  over the leader's travel (with ``switch_reach``: timed so that every switch can be
  reached, :func:`switch_reach_times`);
* humans that walk straight lines crossing the leader's path, timed (``start_delay``)
  to reach the crossing point about when the leader does;
* obstacles (circles, rectangles, convex polygons) placed by rejection sampling,
  most of them beside the leader's path where the formation's slots will run into
  them. They keep clear of the leader's path (0.5 m for a virtual leader, radius +
  0.5 m for a robot leader), of the starting robots, of the humans' lines, of the
  walls and of each other (by a robot diameter + 0.2 m, so robots can pass).
  Sampling is bounded: when the world is too crowded fewer obstacles (or humans)
  than drawn are placed, never an infinite loop.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, field, fields
from typing import Any, Literal, cast

import numpy as np

from swarm_env.geometry.formation import (
    SLOT_MARGIN,
    formation_offsets,
    formation_start,
    reach_time,
    slot_targets,
    unprojected_slot_trajectory,
    virtual_slot_trajectory,
)
from swarm_env.geometry.paths import PolylinePath
from swarm_env.geometry.static_map import StaticMap
from swarm_env.limits import LIMITS, MAX_EPISODE_STEPS, MAX_HUMANS, MAX_ROBOTS, MAX_WORLD_SIZE
from swarm_env.scenario import (
    FORMATION_SHAPES,
    HUMAN_BEHAVIORS,
    LEADER_KINDS,
    REACTIVE_SPEED_FACTOR,
    CircleObstacle,
    FormationSpec,
    HumanSpec,
    LeaderSpec,
    PolygonObstacle,
    RectangleObstacle,
    RewardSpec,
    RobotSpec,
    Scenario,
    ScenarioError,
    SensorSpec,
    WorldSpec,
)
from swarm_env.scenarios.gates import Gate, GateLayout, gate_schedule, place_gates
from swarm_env.scenarios.loader import _parse_reward, _parse_sensors, required_substeps, validate_scenario

__all__ = [
    "RandomScenarioConfig",
    "random_scenario",
    "config_from_kwargs",
    "slot_speed_violations",
    "OBSTACLE_TYPES",
    "KNOB_LIMITS",
]

SOURCE = "random"
OBSTACLE_TYPES = ("circle", "rectangle", "polygon")
IntRange = int | tuple[int, int]
# The leader kinds of swarm_env.scenario.LeaderSpec.
LeaderKind = Literal["virtual", "robot"]


def _span(spec: IntRange) -> tuple[int, int]:
    """A knob's ``(lo, hi)`` (``RandomScenarioConfig`` stores every count as a pair after validation)."""
    return (spec, spec) if isinstance(spec, int) else spec


# Tunables of the layout that are not knobs (they shape "a sensible world", not its difficulty).
_TRAVEL_FRACTION = 0.7  # the leader's path takes this share of max_time
_MAX_TURN = math.radians(60.0)  # largest heading change at a waypoint
_PATH_ATTEMPTS = 300
_HUMAN_ATTEMPTS = 30
#: m of room a stopped walker leaves beyond touching a robot at a final slot (or the robot leader at its goal):
#: the settle tolerance (0.3 m), so that the last formation stays reachable.
_WALKER_END_CLEAR = 0.3
_OBSTACLE_TRIES = 40  # candidates per requested obstacle
# How far (m) a drawn obstacle may reach beyond its nominal bounding radius: coordinates and sizes are
# rounded to mm (a polygon's vertices by up to 0.0007 m, a rectangle's half-diagonal by 0.0005 m).
_BOUND_SLACK = 0.002
_SAMPLE_STEP = 0.1  # m between the points that stand for a path in clearance tests
_FIRST_HOLD = 0.15  # with switch_reach: the share of the leader's travel the starting formation is held at least
_SLOT_SPEED_SHARE = 0.9  # slot targets move at most this share of max_speed while the leader turns
_DEFAULT_WORLD = 20.0  # m, the side of an ``auto`` world for small formations
_PATH_ROOM = 8.0  # m of path room an ``auto`` world keeps between the formation margins

#: Upper bounds of the count knobs (inclusive): bounded work per reset whatever the input. Teams and
#: crowds are bounded as in files (swarm_env.limits); the other two bound the generator's own work.
KNOB_LIMITS = {"n_followers": MAX_ROBOTS, "n_obstacles": 100, "n_humans": MAX_HUMANS, "n_switches": 8, "n_gates": 8,
               "n_waypoints": 8}
#: How many times its reach time a gate's column switch gets when ``switch_reach`` is not set.
GATE_REACH = 3.0


# --------------------------------------------------------------------------- knob validation


def _int_range(value: Any, name: str, minimum: int) -> tuple[int, int]:
    maximum = KNOB_LIMITS[name]
    def is_int(v: Any) -> bool:
        return isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_))

    if is_int(value):
        lo = hi = int(value)
    elif isinstance(value, (tuple, list)) and len(value) == 2 and all(is_int(v) for v in value):
        lo, hi = int(value[0]), int(value[1])
    else:
        raise ScenarioError(SOURCE, name, "an integer or an inclusive (lo, hi) pair of integers", value)
    if lo < minimum or hi > maximum or hi < lo:
        raise ScenarioError(SOURCE, name, f"values in [{minimum}, {maximum}] with lo <= hi", value)
    return (lo, hi)


def _is_real(v: Any) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))


def _as_float(v: Any) -> float:
    try:
        return float(v)
    except OverflowError:  # an int beyond float range
        return math.inf


def _float_range(
    value: Any, name: str, *, positive: bool, at_most: str, ordered: bool = True, at_least: str | None = None
) -> tuple[float, float]:
    """A pair of finite numbers within the bounds named ``at_most`` / ``at_least`` of :data:`swarm_env.limits.LIMITS`."""
    if not (isinstance(value, (tuple, list)) and len(value) == 2 and all(_is_real(v) for v in value)):
        raise ScenarioError(SOURCE, name, "a pair of numbers", value)
    lo, hi = _as_float(value[0]), _as_float(value[1])
    if not (math.isfinite(lo) and math.isfinite(hi)) or (positive and min(lo, hi) <= 0) or (ordered and hi < lo):
        raise ScenarioError(SOURCE, name, "a pair of finite positive numbers" + (" with lo <= hi" if ordered else ""), value)
    bottom = LIMITS[at_least][0] if at_least else -math.inf
    if max(lo, hi) > LIMITS[at_most][0] or min(lo, hi) < bottom:
        where = f"at least {bottom:g} (swarm_env.limits.{at_least}) and " if at_least else ""
        raise ScenarioError(SOURCE, name, f"numbers {where}at most {LIMITS[at_most][0]:g} (swarm_env.limits.{at_most})",
                            value)
    return (lo, hi)


def _names(value: Any, name: str, allowed: tuple[str, ...]) -> tuple[str, ...]:
    if isinstance(value, str) or not isinstance(value, (tuple, list)) or not value:
        raise ScenarioError(SOURCE, name, f"a non-empty list of: {', '.join(allowed)}", value)
    for v in value:
        if not isinstance(v, str) or v not in allowed:
            raise ScenarioError(SOURCE, name, f"names among: {', '.join(allowed)}", v)
    return tuple(value)


def _positive(value: Any, name: str, at_most: str, at_least: str | None = None) -> None:
    """A finite positive number within the bounds named ``at_most`` / ``at_least`` of :data:`swarm_env.limits.LIMITS`."""
    if not _is_real(value) or not math.isfinite(_as_float(value)) or value <= 0:
        raise ScenarioError(SOURCE, name, "a finite positive number", value)
    if value > LIMITS[at_most][0] or (at_least is not None and value < LIMITS[at_least][0]):
        where = f"at least {LIMITS[at_least][0]:g} (swarm_env.limits.{at_least}) and " if at_least else ""
        raise ScenarioError(SOURCE, name, f"a number {where}at most {LIMITS[at_most][0]:g} (swarm_env.limits.{at_most})",
                            value)


@dataclass(frozen=True)
class RandomScenarioConfig:
    """Knobs of :func:`random_scenario` (all keyword arguments of ``parallel_env("random", ...)``).

    An ``int | (lo, hi)`` knob is a fixed value or an inclusive range drawn
    uniformly; a ``(lo, hi)`` float knob is drawn uniformly in ``[lo, hi]``.

    Attributes:
        n_followers: number of followers (at most 64). ``SwarmEnv`` draws a range once per
            env instance (its ``team_seed``), so every episode of one env has the same team.
        n_obstacles: number of obstacles to place (fewer if the world is too crowded).
        obstacle_size: range of an obstacle's size (m): a circle's diameter, a rectangle's
            diagonal, the diameter of a polygon's circumscribed circle.
        obstacle_types: which of ``circle``, ``rectangle``, ``polygon`` to draw from.
        n_humans: number of humans (fewer if their lines do not fit).
        human_speed: range of human walking speeds (m/s).
        human_radius: human disc radius (m).
        human_behavior: how the humans move, one of :data:`swarm_env.scenario.HUMAN_BEHAVIORS`
            (``scripted``: along their lines, ignoring robots; ``social_force``: they react).
        shapes: formation shapes to draw from (any of
            :data:`swarm_env.scenario.FORMATION_SHAPES` except ``custom``).
        spacing: range of the formation spacing (m); raised to ``2 * radius + 0.1``.
        angle: range of the ``v``/``wedge`` arm half-opening (degrees).
        n_switches: number of formation switches after the first formation.
        n_waypoints: number of the leader path's drawn waypoints (2: a straight path; each more is a turn).
        switch_reach: ``None`` (the default): switches spread evenly over the leader's travel. A number
            ``k``: each new formation lasts at least ``k`` times its reach time, the least time in which
            every follower could be within the settle tolerance of its new slot at top speed
            (:func:`switch_reach_times`), so that every switch can be reached and held; while they do not
            fit in the leader's travel, the switch that needs the most time is dropped.
        n_gates: number of gates (:mod:`swarm_env.scenarios.gates`): walls across straight stretches of the
            leader's path, each with a door the formation files through as a column (ordered before the door,
            released after it, each given ``switch_reach`` (else :data:`GATE_REACH`) times its reach time).
            Fewer where they do not fit. The gates make the schedule: with gates, ``n_switches`` must be 0.
        gate_width: range of a door's width (m), at least ``2 * (radius + 0.05) + 0.1`` so a column's slot
            target fits through.
        gate_depth: range of a gate's depth along the path (m): a door in a wall, or a corridor when deep.
        world_size: ``(W, H)`` (m), or ``"auto"`` (the default): a square of
            ``max(20, 2 * (rho + radius + 0.3) + 8)`` m where ``rho`` is the largest slot radius any
            drawable formation of the largest team can have (see :meth:`resolved_world_size`).
        leader_kind: ``virtual`` or ``robot``.
        leader_speed: leader speed (m/s), at most ``max_speed``.
        max_time, dt, substeps: episode length and time stepping (see ``WorldSpec``).
        radius, max_speed, max_turn_rate: follower (and robot leader) disc radius,
            speed and turn-rate limits. ``max_speed`` defaults to paper 003's 0.65 m/s
            (its Table I prints 6.5 m/s, read as 0.65).
        sensors, reward: ``SensorSpec`` / ``RewardSpec`` or a mapping of their fields.
    """

    n_followers: IntRange = 4
    n_obstacles: IntRange = (3, 10)
    obstacle_size: tuple[float, float] = (0.3, 1.2)
    obstacle_types: tuple[str, ...] = OBSTACLE_TYPES
    n_humans: IntRange = (0, 3)
    human_speed: tuple[float, float] = (0.3, 0.6)
    human_radius: float = 0.3
    human_behavior: str = "scripted"
    shapes: tuple[str, ...] = ("v", "line", "column", "wedge", "diamond", "circle", "grid")
    spacing: tuple[float, float] = (0.9, 1.3)
    angle: tuple[float, float] = (30.0, 60.0)
    n_switches: IntRange = (0, 2)
    n_waypoints: IntRange = (2, 4)
    switch_reach: float | None = None
    n_gates: IntRange = 0
    gate_width: tuple[float, float] = (1.0, 1.6)
    gate_depth: tuple[float, float] = (0.3, 0.6)
    world_size: tuple[float, float] | str = "auto"
    leader_kind: str = "virtual"
    leader_speed: float = 0.4
    max_time: float = 60.0
    dt: float = 0.1
    substeps: int = 4
    radius: float = 0.25
    max_speed: float = 0.65
    max_turn_rate: float = 1.0
    sensors: SensorSpec = field(default_factory=SensorSpec)
    reward: RewardSpec = field(default_factory=RewardSpec)

    def __post_init__(self) -> None:
        put = object.__setattr__  # frozen: normalise lists to tuples once, here
        put(self, "n_followers", _int_range(self.n_followers, "n_followers", 1))
        put(self, "n_obstacles", _int_range(self.n_obstacles, "n_obstacles", 0))
        put(self, "n_humans", _int_range(self.n_humans, "n_humans", 0))
        put(self, "n_switches", _int_range(self.n_switches, "n_switches", 0))
        put(self, "n_gates", _int_range(self.n_gates, "n_gates", 0))
        put(self, "n_waypoints", _int_range(self.n_waypoints, "n_waypoints", 2))
        put(self, "obstacle_size", _float_range(self.obstacle_size, "obstacle_size", positive=True, at_most="MAX_WORLD_SIZE"))
        put(self, "human_speed", _float_range(self.human_speed, "human_speed", positive=True, at_most="MAX_SPEED",
                                              at_least="MIN_SPEED"))
        put(self, "spacing", _float_range(self.spacing, "spacing", positive=True, at_most="MAX_WORLD_SIZE"))
        put(self, "gate_width", _float_range(self.gate_width, "gate_width", positive=True, at_most="MAX_WORLD_SIZE"))
        put(self, "gate_depth", _float_range(self.gate_depth, "gate_depth", positive=True, at_most="MAX_WORLD_SIZE"))
        put(self, "angle", _float_range(self.angle, "angle", positive=True, at_most="MAX_ABS_NUMBER"))
        lo = LIMITS["MIN_FORMATION_ANGLE"][0]
        if not (lo <= self.angle[0] and self.angle[1] <= 180.0 - lo):
            raise ScenarioError(SOURCE, "angle", f"a range of degrees within [{lo:g}, {180 - lo:g}] "
                                "(swarm_env.limits.MIN_FORMATION_ANGLE)", self.angle)
        if isinstance(self.world_size, str):
            if self.world_size != "auto":
                raise ScenarioError(SOURCE, "world_size", "'auto' or a (W, H) pair of numbers", self.world_size)
        else:
            put(self, "world_size", _float_range(self.world_size, "world_size", positive=True, ordered=False,
                                                 at_most="MAX_WORLD_SIZE"))
        put(self, "obstacle_types", _names(self.obstacle_types, "obstacle_types", OBSTACLE_TYPES))
        put(self, "shapes", _names(self.shapes, "shapes", tuple(s for s in FORMATION_SHAPES if s != "custom")))
        if not isinstance(self.leader_kind, str) or self.leader_kind not in LEADER_KINDS:
            raise ScenarioError(SOURCE, "leader_kind", f"one of {', '.join(LEADER_KINDS)}", self.leader_kind)
        if not isinstance(self.human_behavior, str) or self.human_behavior not in HUMAN_BEHAVIORS:
            raise ScenarioError(SOURCE, "human_behavior", f"one of {', '.join(HUMAN_BEHAVIORS)}", self.human_behavior)
        bounds = {
            "human_radius": ("MAX_WORLD_SIZE", "MIN_RADIUS"),
            "radius": ("MAX_WORLD_SIZE", "MIN_RADIUS"),
            "leader_speed": ("MAX_SPEED", "MIN_SPEED"),
            "max_speed": ("MAX_SPEED", "MIN_SPEED"),
            "max_turn_rate": ("MAX_TURN_RATE", None),
            "dt": ("MAX_DT", "MIN_DT"),
            "max_time": ("MAX_ABS_NUMBER", None),
        }
        for name, (at_most, at_least) in bounds.items():
            _positive(getattr(self, name), name, at_most, at_least)
        steps = math.floor(self.max_time / self.dt + 1e-9)
        if steps > MAX_EPISODE_STEPS:
            raise ScenarioError(SOURCE, "max_time", f"at most {MAX_EPISODE_STEPS} control steps per episode "
                                f"(swarm_env.limits.MAX_EPISODE_STEPS): max_time / dt = {steps}", self.max_time)
        if self.max_time < self.dt:
            raise ScenarioError(SOURCE, "max_time", f"at least one control period (dt = {self.dt:g})", self.max_time)
        max_sub = int(LIMITS["MAX_SUBSTEPS"][0])
        if isinstance(self.substeps, bool) or not isinstance(self.substeps, int) or not 1 <= self.substeps <= max_sub:
            raise ScenarioError(SOURCE, "substeps", f"an integer in [1, {max_sub}] (swarm_env.limits.MAX_SUBSTEPS)",
                                self.substeps)
        if self.switch_reach is not None and (not _is_real(self.switch_reach) or not 1.0 <= self.switch_reach <= 100.0):
            raise ScenarioError(SOURCE, "switch_reach", "null or a number in [1, 100] (times the reach time)",
                                self.switch_reach)
        if self.n_gates[1] > 0:  # type: ignore[index]
            if self.n_switches[1] > 0:  # type: ignore[index]
                raise ScenarioError(SOURCE, "n_switches", "0 with n_gates (the gates make the formation schedule: "
                                    "pass n_switches=0)",
                                    self.n_switches)
            door = 2.0 * (self.radius + SLOT_MARGIN) + 0.1
            if self.gate_width[0] < door:
                raise ScenarioError(SOURCE, "gate_width", f"doors at least {door:g} m wide (a column's slot target, "
                                    f"radius {self.radius:g} m + 0.05 m, with 0.05 m to spare on each side)",
                                    self.gate_width)
        if self.leader_speed > self.max_speed:
            raise ScenarioError(SOURCE, "leader_speed", f"at most max_speed = {self.max_speed}", self.leader_speed)
        if not isinstance(self.sensors, SensorSpec):
            put(self, "sensors", _parse_sensors(SOURCE, self.sensors))
        if not isinstance(self.reward, RewardSpec):
            put(self, "reward", _parse_reward(SOURCE, self.reward))
        # The anti-tunnelling rule of the loader (swarm_env.scenarios.loader), for the fastest humans this config can draw.
        humans = _span(self.n_humans)[1] > 0
        v_rel = 2.0 * max(self.max_speed, self.leader_speed) + (self.top_human_speed() if humans else 0.0)
        r_min = min(self.radius, self.human_radius) if humans else self.radius
        need = required_substeps(v_rel, r_min, self.dt)
        if self.substeps < need:
            raise ScenarioError(
                SOURCE, "substeps", f"at least {need} (v_rel * dt / substeps <= r_min, v_rel = {v_rel:g} m/s)", self.substeps
            )
        side = max(self.resolved_world_size())
        if side > MAX_WORLD_SIZE:  # an auto world grown for a wide formation (checked before any drawing)
            raise ScenarioError(SOURCE, "spacing", f"a formation that fits a world of at most {MAX_WORLD_SIZE:g} m "
                                f"(swarm_env.limits.MAX_WORLD_SIZE; it needs {side:g} m)", self.spacing)


    def top_human_speed(self) -> float:
        """The fastest a human of this config can walk (m/s; a reactive one may exceed its speed)."""
        return self.human_speed[1] * (REACTIVE_SPEED_FACTOR if self.human_behavior != "scripted" else 1.0)

    def resolved_world_size(self) -> tuple[float, float]:
        """``world_size``, with ``"auto"`` resolved: big enough that the widest formation this
        config can draw (largest team, largest spacing, any allowed shape and angle) fits
        beside ``_PATH_ROOM`` m of leader path, and never smaller than 20 m x 20 m."""
        if self.world_size != "auto":
            return self.world_size  # type: ignore[return-value]
        n = self.n_followers[1]  # type: ignore[index]
        rho = 0.0
        for shape in self.shapes:
            for angle in (self.angle if shape in ("v", "wedge") else (45.0,)):
                if shape == "wedge" and angle == 90.0:
                    angle = 89.0
                off = formation_offsets(FormationSpec(at=0.0, shape=shape, spacing=self.spacing[1], angle=angle), n)
                rho = max(rho, float(np.max(np.hypot(off[:, 0], off[:, 1]), initial=0.0)))
        side = round(max(_DEFAULT_WORLD, 2.0 * (rho + self.radius + 0.3) + _PATH_ROOM), 1)
        return (side, side)


def config_from_kwargs(**kwargs: Any) -> RandomScenarioConfig:
    """A :class:`RandomScenarioConfig` from keyword knobs; an unknown knob raises
    :class:`ScenarioError` (a ``ValueError``) that lists the known ones."""
    known = [f.name for f in fields(RandomScenarioConfig)]
    for k in kwargs:
        if k not in known:
            raise ScenarioError(SOURCE, k, "a knob of the random scenario: " + ", ".join(known), k)
    return RandomScenarioConfig(**kwargs)


def random_scenario(rng: np.random.Generator, config: RandomScenarioConfig = RandomScenarioConfig()) -> Scenario:
    """Draw a valid random :class:`Scenario` using only ``rng`` (see the module docstring).

    Same ``rng`` state and ``config`` -> an identical scenario. Raises
    :class:`ScenarioError` only when ``config`` makes a scenario impossible (a world
    too small for the formation's starting slots).
    """
    cfg = config
    W, H = cfg.resolved_world_size()
    r = cfg.radius
    n = _draw_int(rng, cfg.n_followers)
    n_obs = _draw_int(rng, cfg.n_obstacles)
    n_hum = _draw_int(rng, cfg.n_humans)
    n_sw = _draw_int(rng, cfg.n_switches)

    formations = _draw_formations(rng, cfg, n_sw)
    offsets = [formation_offsets(f, n) for f in formations]
    rho = max(float(np.max(np.hypot(o[:, 0], o[:, 1]), initial=0.0)) for o in offsets)  # largest slot radius
    extent = rho + r
    v_slot = _SLOT_SPEED_SHARE * cfg.max_speed - cfg.leader_speed  # what turning may add to a slot's speed
    # Smallest corner radius that keeps every slot under v_slot + leader speed (inf: drive straight).
    # The factor 1.1 covers the polyline's discrete heading steps (see _round_corners).
    min_radius = 1.1 * rho * cfg.leader_speed / v_slot if v_slot > 0 else math.inf

    path, start_xy = _draw_path(rng, cfg, (W, H), offsets[0], extent, min_radius)
    line = PolylinePath(path)
    travel = line.length / cfg.leader_speed
    if cfg.switch_reach is None:
        # Switches are spread over the leader's actual travel time, one per stratum, so they
        # are strictly increasing and at least ~0.4 * travel / (n_sw + 1) apart.
        for i in range(1, len(formations)):
            at = round(travel * (i + float(rng.uniform(-0.3, 0.3))) / len(formations), 1)
            at = max(at, round(formations[i - 1].at + cfg.dt, 6))  # very short travels: keep them increasing
            formations[i] = dataclasses.replace(formations[i], at=at)
    else:
        formations = _reachable_switches(rng, formations, offsets, travel, cfg)
    leader_clear = (r + 0.5) if cfg.leader_kind == "robot" else 0.5
    # Discs present at t = 0 (followers, and the robot leader) with their radii.
    start_discs = [(p, r) for p in start_xy]
    if cfg.leader_kind == "robot":
        start_discs.append((np.asarray(path[0]), r))
    gates: list[Gate] = []
    n_gates = _draw_int(rng, cfg.n_gates)
    if n_gates:
        layout = GateLayout(
            size=(W, H), radius=r, leader_speed=cfg.leader_speed, max_speed=cfg.max_speed, leader_clear=leader_clear,
            reach=cfg.switch_reach if cfg.switch_reach is not None else GATE_REACH, width=cfg.gate_width,
            depth=cfg.gate_depth, keep=(np.array([p for p, _ in start_discs]), np.array([rad + 0.3 for _, rad in start_discs])),
            end=cfg.max_time)
        gates = place_gates(rng, line, n_gates, formations[0], n, layout)
        formations = gate_schedule(formations[0], gates, n, layout, cfg.dt)
    footprints = StaticMap.from_obstacles((W, H), [g.footprint for g in gates]) if gates else None

    humans = _draw_humans(rng, cfg, (W, H), line, n_hum, start_discs, footprints,
                          _final_discs(line, formations[-1], n, cfg.leader_kind == "robot"))

    # Clearance constraints for obstacles: sample points with the clearance each needs.
    pts = [_samples(line), np.array([p for p, _ in start_discs])]
    need = [np.full(len(pts[0]), leader_clear), np.array([rad + 0.3 for _, rad in start_discs])]
    for h in humans:
        hp = _samples(PolylinePath(h.path))
        pts.append(hp)
        need.append(np.full(len(hp), cfg.human_radius + 0.2))

    # A robot leader turns at most as fast as keeps its outermost slot under the same speed share.
    leader_turn = cfg.max_turn_rate
    if cfg.leader_kind == "robot" and rho > 0:
        leader_turn = min(leader_turn, max(v_slot, 0.05 * cfg.max_speed) / rho)
    scn = Scenario(
        name="random",
        world=WorldSpec(size=(float(W), float(H)), dt=cfg.dt, substeps=cfg.substeps, max_time=cfg.max_time),
        robots=RobotSpec(count=n, radius=r, max_speed=cfg.max_speed, max_turn_rate=cfg.max_turn_rate),
        leader=LeaderSpec(
            kind=cast(LeaderKind, cfg.leader_kind), path=path, speed=cfg.leader_speed, radius=r, max_turn_rate=round(leader_turn, 6)
        ),
        formations=tuple(formations),
        obstacles=(),
        humans=tuple(humans),
        sensors=cfg.sensors,
        reward=cfg.reward,
        source=SOURCE,
    )
    steps = int(math.floor(cfg.max_time / cfg.dt + 1e-9))
    raw = unprojected_slot_trajectory(scn, steps)
    if gates:
        scn, raw, gates = _gates_slots_follow(scn, raw, gates, formations[0], layout)
    gate_walls = [w for g in gates for w in g.walls]
    walls = StaticMap.from_obstacles((W, H), gate_walls) if gates else None

    # A candidate whose bounding disc stays the projection's clearance away from every unprojected slot moves
    # none of them (project_free leaves free points untouched), so it passes exactly when the unprojected slots
    # do; most candidates are such, and this skips building their map (what the check below costs) and
    # projecting thousands of points. Only when no slot comes near a wall: there the walls alone move slots.
    clear = r + SLOT_MARGIN  # virtual_slot_trajectory's clearance
    raw_xy = raw[0].reshape(-1, 2)
    off_walls = bool(np.all(np.minimum(np.minimum(raw_xy[:, 0], W - raw_xy[:, 0]),
                                       np.minimum(raw_xy[:, 1], H - raw_xy[:, 1])) >= clear + _BOUND_SLACK))
    raw_follows = not len(_violations(scn, *raw))

    def slots_can_follow(obstacle: Any, centre: np.ndarray, rho: float) -> bool:
        """Whether this obstacle alone makes no slot jump (see _without_jumps)."""
        if off_walls:
            d2 = (raw_xy[:, 0] - centre[0]) ** 2 + (raw_xy[:, 1] - centre[1]) ** 2
            if float(d2.min()) >= (rho + clear + _BOUND_SLACK) ** 2:
                return raw_follows
        static = StaticMap.from_obstacles((W, H), [obstacle])
        return not len(_violations(scn, *virtual_slot_trajectory(scn, static, steps, raw)))

    obstacles = _draw_obstacles(
        rng, cfg, (W, H), n_obs, line, extent, np.vstack(pts), np.concatenate(need), slots_can_follow, walls
    )
    kept = [obstacles[k] for k in _without_jumps(scn, [(o,) for o in obstacles], raw, gate_walls)]
    shapes = " -> ".join(f"{f.shape}@{f.at:g}s" for f in scn.formations)
    doors = f", {len(gates)} gates" if cfg.n_gates[1] else ""  # type: ignore[index]
    description = (
        f"random: {n} followers behind a {cfg.leader_kind} leader ({line.length:.1f} m at "
        f"{cfg.leader_speed:g} m/s), {len(kept)} obstacles{doors}, {len(humans)} humans; formations {shapes}"
    )
    return validate_scenario(dataclasses.replace(scn, obstacles=(*gate_walls, *kept), description=description))


def _gates_slots_follow(scn: Scenario, raw: tuple[np.ndarray, np.ndarray], gates: list[Gate], formation: FormationSpec,
                        layout: GateLayout) -> tuple[Scenario, tuple[np.ndarray, np.ndarray], list[Gate]]:
    """``(scn, raw, gates)`` less the gates that make a slot target move faster than ``max_speed``, with the
    schedule and the :func:`unprojected_slot_trajectory` ``raw`` of the gates kept: a column that turns with the
    path (the gate whose column was ordered last before it goes), or walls that make a slot jump
    (:func:`_without_jumps`). One gate or more fewer each round: bounded by the number of gates."""
    steps = raw[0].shape[0] - 1
    dt, speed = scn.world.dt, scn.leader.speed
    while gates:
        turning = _violations(scn, *raw)
        if len(turning):
            leader_at = float(turning[0, 0]) * dt * speed  # (a virtual leader: arc length = speed * time)
            ordered = [i for i, g in enumerate(gates) if g.order <= leader_at]
            kept = [g for i, g in enumerate(gates) if i != (ordered[-1] if ordered else len(gates) - 1)]
        else:
            kept = [gates[k] for k in _without_jumps(scn, [g.walls for g in gates], raw)]
            if len(kept) == len(gates):
                break
        gates = kept
        scn = dataclasses.replace(scn, formations=tuple(gate_schedule(formation, gates, scn.robots.count, layout, dt)))
        raw = unprojected_slot_trajectory(scn, steps)
    return scn, raw, gates


def slot_speed_violations(scn: Scenario, static: StaticMap | None = None) -> np.ndarray:
    """``(K, 2)`` rows ``(step, follower)`` where the slot target moves faster than
    ``robots.max_speed`` between step ``step - 1`` and ``step`` (with a virtual leader's
    exact motion, a robot leader's nominal one), over the whole episode.

    Steps at which the formation switches are excluded: a switch is a new target by
    design (the metrics time how long the followers take to settle on it). An empty
    result means no follower is ever asked to move faster than it can.
    """
    static = static if static is not None else StaticMap.from_obstacles(scn.world.size, scn.obstacles)
    steps = int(math.floor(scn.world.max_time / scn.world.dt + 1e-9))
    slots, index = virtual_slot_trajectory(scn, static, steps)
    return _violations(scn, slots, index)


def _violations(scn: Scenario, slots: np.ndarray, index: np.ndarray) -> np.ndarray:
    step = np.hypot(*np.moveaxis(np.diff(slots, axis=0), -1, 0))  # (steps, N)
    too_fast = step > scn.robots.max_speed * scn.world.dt * (1.0 + 1e-9)
    too_fast &= (index[1:] == index[:-1])[:, None]
    k, i = np.nonzero(too_fast)
    return np.column_stack([k + 1, i])


def _without_jumps(scn: Scenario, groups: Sequence[Sequence[Any]], raw: tuple[np.ndarray, np.ndarray],
                   fixed: Sequence[Any] = ()) -> list[int]:
    """The indices of the obstacle ``groups`` kept: those whose projection makes a slot jump faster than
    ``max_speed`` are dropped (a whole group with any of its obstacles; ``fixed`` obstacles stay).

    A slot target that enters an obstacle is moved to the nearest free point; across
    the obstacle's middle that point jumps to the other side. Candidates that do so
    alone are refused while sampling; here the groups that the offending targets
    of the whole map were pushed onto are dropped, until no such jump is left.
    ``raw`` is the scenario's :func:`unprojected_slot_trajectory`.
    """
    steps = raw[0].shape[0] - 1
    clearance = scn.robots.radius + SLOT_MARGIN
    kept = list(range(len(groups)))
    while kept:
        owner = [-1] * len(fixed) + [k for k in kept for _ in groups[k]]
        static = StaticMap.from_obstacles(scn.world.size, [*fixed, *(o for k in kept for o in groups[k])])
        slots, index = virtual_slot_trajectory(scn, static, steps, raw)
        bad = _violations(scn, slots, index)
        if not len(bad):
            break
        ends = np.concatenate([slots[bad[:, 0], bad[:, 1]], slots[bad[:, 0] - 1, bad[:, 1]]])
        near = static.obstacle_distances(ends) < clearance + 1e-6
        culprits = {owner[j] for j in np.flatnonzero(near.any(axis=0)).tolist()} - {-1}
        if not culprits:  # not a droppable obstacle's doing (cannot happen with convex walls): keep the rest
            break
        kept = [k for k in kept if k not in culprits]
    return kept


# --------------------------------------------------------------------------- drawing


def _draw_formations(rng: np.random.Generator, cfg: RandomScenarioConfig, n_sw: int) -> list[FormationSpec]:
    """``1 + n_sw`` formations (switch times are set once the path is known); consecutive shapes differ."""
    spacing_min = 2.0 * cfg.radius + 0.1
    out: list[FormationSpec] = []
    prev = ""
    for _ in range(n_sw + 1):
        choices = [s for s in cfg.shapes if s != prev] or list(cfg.shapes)
        shape = choices[int(rng.integers(len(choices)))]
        prev = shape
        spacing = round(max(spacing_min, float(rng.uniform(*cfg.spacing))), 2)
        angle = round(float(rng.uniform(*cfg.angle)), 1)
        if shape == "wedge" and angle == 90.0:  # a wedge's rows coincide at exactly 90 degrees
            angle = 89.0
        out.append(FormationSpec(at=0.0, shape=shape, spacing=spacing, angle=angle))
    return out


def switch_reach_times(scn: Scenario) -> list[float]:
    """:func:`reach_time` of each formation switch of ``scn`` (schedule entries after the first), in order."""
    n = scn.robots.count
    offsets = [formation_offsets(f, n) for f in scn.formations]
    return [reach_time(a, b, scn.leader.speed, scn.robots.max_speed, scn.world.settle_tolerance)
            for a, b in zip(offsets, offsets[1:])]


def _reachable_switches(rng: np.random.Generator, formations: list[FormationSpec], offsets: list[np.ndarray],
                        travel: float, cfg: RandomScenarioConfig) -> list[FormationSpec]:
    """Switch times such that formation ``i >= 1`` lasts at least ``cfg.switch_reach`` times its reach time and
    everything happens within the leader's ``travel`` (s); the slack is shared at random between the formations.
    While the switches do not fit, the one that needs the most time is dropped (and a formation that would
    repeat the one before it)."""
    tol = WorldSpec.settle_tolerance
    keep = list(range(len(formations)))

    def needs() -> list[float]:
        return [cfg.switch_reach * reach_time(offsets[a], offsets[b], cfg.leader_speed, cfg.max_speed, tol)  # type: ignore[operator]
                for a, b in zip(keep, keep[1:])]

    first = _FIRST_HOLD * travel  # the starting formation is held for a while too
    need = needs()
    while need and sum(need) + first > travel:
        del keep[1 + int(np.argmax(need))]
        keep = [k for i, k in enumerate(keep)  # no "switch" to the formation already held
                if i == 0 or dataclasses.replace(formations[k], at=0.0) != dataclasses.replace(formations[keep[i - 1]], at=0.0)]
        need = needs()
    kept = [formations[k] for k in keep]
    # formation 0 needs no reach, only its hold; each of the others at least its own, and at least one control step
    floor = np.array([first] + [max(m, cfg.dt) for m in need])
    share = rng.uniform(0.7, 1.3, len(floor))
    gaps = floor + (travel - floor.sum()) * share / share.sum()
    at = 0.0
    for i in range(1, len(kept)):
        at = max(math.floor((at + gaps[i - 1]) * 10.0) / 10.0, round(kept[i - 1].at + cfg.dt, 6))
        kept[i] = dataclasses.replace(kept[i], at=round(at, 6))
    return kept


def _draw_path(
    rng: np.random.Generator,
    cfg: RandomScenarioConfig,
    size: tuple[float, float],
    offsets0: np.ndarray,
    extent: float,
    min_radius: float,
) -> tuple[tuple[tuple[float, float], ...], np.ndarray]:
    """The leader's path and the followers' starting slot positions.

    ``cfg.n_waypoints`` waypoints (rounded to mm) are drawn first: the first heading, then the turns
    (at most 60 degrees, and at most what a corner arc of ``min_radius`` fits in
    half a segment), then the start point where every starting slot fits in the
    world and every later waypoint stays ``margin`` (about the formation's radius)
    from the walls. The corners are then rounded (:func:`_round_corners`).
    """
    W, H = size
    r = cfg.radius
    # Keep the path about a formation radius from the walls, but never more than a
    # fifth of the world (small worlds: slots near walls are projected inside), or
    # than leaves _PATH_ROOM of path box in a big world.
    margin = max(min(extent + 0.3, max(0.2 * min(W, H), (min(W, H) - _PATH_ROOM) / 2)), r + 0.1)
    lo = np.array([margin, margin])
    hi = np.array([W - margin, H - margin])
    length = cfg.leader_speed * _TRAVEL_FRACTION * cfg.max_time
    k = int(rng.integers(cfg.n_waypoints[0], cfg.n_waypoints[1] + 1))  # type: ignore[index]
    for attempt in range(_PATH_ATTEMPTS):
        if attempt and attempt % 75 == 0:
            length *= 0.8  # the world is too small for this path: shorten it
        # Draw the path's shape (first heading, turns); it then fixes the path up to a
        # translation, and the start points that keep every starting slot in the world
        # and every later waypoint in the margin box form a box: draw the start there.
        heading = float(rng.uniform(-math.pi, math.pi))
        box = _start_box(heading, offsets0, r + 0.05, W, H)
        turns = rng.uniform(-_MAX_TURN, _MAX_TURN, size=k - 2)
        if box is None:
            continue
        # A corner arc of min_radius needs min_radius * tan(turn / 2) of each segment next to
        # it; leave each segment at least one step of travel that is straight.
        room = length / (k - 1) / 2.0 - cfg.leader_speed * cfg.dt
        max_turn = 2.0 * math.atan(max(room, 0.0) / min_radius) if min_radius > 0 else _MAX_TURN
        turns = np.clip(turns, -max_turn, max_turn)
        heads = heading + np.concatenate([[0.0], np.cumsum(turns)])
        disp = np.cumsum((length / (k - 1)) * np.column_stack([np.cos(heads), np.sin(heads)]), axis=0)
        p_lo = np.maximum(box[0], (lo - disp).max(axis=0))
        p_hi = np.minimum(box[1], (hi - disp).min(axis=0))
        if np.any(p_hi < p_lo):
            continue
        p0 = rng.uniform(p_lo, p_hi)
        arr = np.round(np.vstack([p0, p0 + disp]), 3)
        start = formation_start(arr, offsets0)[:, :2]
        if _discs_inside(start, r, W, H) and _discs_inside(arr[1:], margin - 1e-3, W, H):
            return _round_corners(arr, min_radius, cfg.leader_speed * cfg.dt), start
    # Fallback (cramped worlds only): the straightest path that fits, along an axis or diagonal.
    best: tuple[float, np.ndarray] | None = None
    for heading in np.arange(8) * (math.pi / 4):
        box = _start_box(float(heading), offsets0, r + 0.05, W, H)
        if box is None:
            continue
        d = np.array([math.cos(heading), math.sin(heading)])
        p0 = np.clip(np.where(d > 1e-9, box[0], np.where(d < -1e-9, box[1], (box[0] + box[1]) / 2)), box[0], box[1])
        room = _ray_room(p0, d, length, margin, W, H)
        if room > 0.5 and (best is None or room > best[0]):
            best = (room, np.round(np.array([p0, p0 + room * d]), 3))
    if best is None:
        raise ScenarioError(
            SOURCE, "world_size", f"a world large enough for the formation's starting slots (radius {extent:.3g} m)", (W, H)
        )
    arr = best[1]
    return tuple((float(x), float(y)) for x, y in arr), formation_start(arr, offsets0)[:, :2]


def _round_corners(points: np.ndarray, radius: float, travel: float) -> tuple[tuple[float, float], ...]:
    """The polyline ``points`` with each interior corner replaced by a circular arc of ``radius``.

    The arc is written as a polyline whose pieces are a little longer than ``travel``
    (the leader's travel in one step), so the leader passes at most one vertex per step
    and its heading turns by at most ``1.05 * travel / radius`` per step; a slot ``rho``
    from the leader then moves at most ``travel * (1 + 1.05 * rho / radius)`` per step.
    Arc points are not rounded (mm rounding would add heading noise larger than that).
    """
    if len(points) < 3 or not math.isfinite(radius) or radius <= 0:
        return tuple((float(x), float(y)) for x, y in points)
    out: list[np.ndarray] = [points[0]]
    for j in range(1, len(points) - 1):
        a, v, b = points[j - 1], points[j], points[j + 1]
        if min(np.linalg.norm(v - a), np.linalg.norm(b - v)) < 1e-9:
            continue  # a path shorter than the mm rounding (a tiny max_time): no corner to round
        u_in = (v - a) / np.linalg.norm(v - a)
        u_out = (b - v) / np.linalg.norm(b - v)
        turn = math.atan2(u_in[0] * u_out[1] - u_in[1] * u_out[0], float(u_in @ u_out))
        if abs(turn) < 1e-9:
            continue  # no corner
        tangent = radius * math.tan(abs(turn) / 2.0)
        side = 1.0 if turn > 0 else -1.0
        normal = side * np.array([-u_in[1], u_in[0]])  # towards the arc's centre
        centre = v - tangent * u_in + radius * normal
        start_angle = math.atan2(-normal[1], -normal[0])
        pieces = max(1, int(math.floor(radius * abs(turn) / (1.05 * travel))))
        for q in range(pieces + 1):
            ang = start_angle + side * abs(turn) * q / pieces
            out.append(centre + radius * np.array([math.cos(ang), math.sin(ang)]))
    out.append(points[-1])
    return tuple((float(x), float(y)) for x, y in out)


def _start_box(heading: float, offsets0: np.ndarray, rad: float, W: float, H: float) -> tuple[np.ndarray, np.ndarray] | None:
    """Where the leader may start with ``heading`` so that every starting slot disc fits in the world."""
    c, s = math.cos(heading), math.sin(heading)
    rot = offsets0 @ np.array([[c, s], [-s, c]])
    ext_lo = np.minimum(rot.min(axis=0), 0.0)
    ext_hi = np.maximum(rot.max(axis=0), 0.0)
    lo = np.array([rad, rad]) - ext_lo
    hi = np.array([W - rad, H - rad]) - ext_hi
    if np.any(hi - lo < 1e-6):
        return None
    return lo, hi


def _final_discs(line: PolylinePath, last: FormationSpec, n: int, robot_leader: bool) -> np.ndarray:
    """``(K, 2)`` centres of where the robots stand once the leader has stopped: the last formation's slots at the
    end of the path (as the leader faces there), and the robot leader's goal."""
    end = np.asarray(line.point_at(line.length), dtype=float)
    centres = slot_targets(np.array([end[0], end[1], line.heading_at(line.length)]), formation_offsets(last, n), None, 0.0)
    return np.vstack([centres, end[None]]) if robot_leader else centres


def _draw_humans(
    rng: np.random.Generator,
    cfg: RandomScenarioConfig,
    size: tuple[float, float],
    line: PolylinePath,
    n_hum: int,
    start_discs: list[tuple[np.ndarray, float]],
    footprints: StaticMap | None = None,
    final: np.ndarray | None = None,
) -> list[HumanSpec]:
    """Humans walking straight lines that cross the leader's path, timed to meet the leader there (and keeping
    1 m from the gates' ``footprints``: nobody walks through a door, or stops in one). A walker stops at the end
    of its line; it does not stop within touching distance plus ``_WALKER_END_CLEAR`` of a ``final`` disc (robot
    radius; :func:`_final_discs`), where it would keep the last formation from settling (issue 34)."""
    W, H = size
    hr = cfg.human_radius
    out: list[HumanSpec] = []
    starts: list[np.ndarray] = []
    for _ in range(n_hum):
        for _attempt in range(_HUMAN_ATTEMPTS):
            s_c = float(rng.uniform(0.3, 0.8)) * line.length
            c = line.point_at(s_c)
            # Any direction but roughly along the leader: 0 = head-on, +-120 deg = overtaking at 60 deg.
            psi = line.heading_at(s_c) + math.pi + float(rng.uniform(-2.0 * math.pi / 3, 2.0 * math.pi / 3))
            u = np.array([math.cos(psi), math.sin(psi)])
            speed = round(float(rng.uniform(*cfg.human_speed)), 2)
            before = _ray_room(c, -u, float(rng.uniform(3.0, 6.0)), hr + 0.1, W, H)
            after = _ray_room(c, u, float(rng.uniform(2.0, 5.0)), hr + 0.1, W, H)
            if before < 1.0 or after < 1.0:
                continue
            a, b = np.round(c - before * u, 3), np.round(c + after * u, 3)
            if not (_discs_inside(a[None], hr, W, H) and _discs_inside(b[None], hr, W, H)):
                continue
            if any(np.linalg.norm(a - p) < rad + hr + 0.3 for p, rad in start_discs):
                continue
            if any(np.linalg.norm(a - q) < 2 * hr + 0.1 for q in starts):
                continue
            if footprints is not None and float(footprints.obstacle_distances(_samples(PolylinePath(np.array([a, b])))).min()) < hr + 1.0:
                continue
            if final is not None and len(final) and float(np.min(np.linalg.norm(final - b, axis=1))) < hr + cfg.radius + _WALKER_END_CLEAR:
                continue
            t_meet = s_c / cfg.leader_speed
            delay = round(max(0.0, t_meet - before / speed), 1)
            starts.append(a)
            path = ((float(a[0]), float(a[1])), (float(b[0]), float(b[1])))
            out.append(HumanSpec(path=path, speed=speed, radius=hr, mode="once", start_delay=delay,
                                 behavior=cfg.human_behavior))  # type: ignore[arg-type]
            break
    return out


def _draw_obstacles(
    rng: np.random.Generator,
    cfg: RandomScenarioConfig,
    size: tuple[float, float],
    n_obs: int,
    line: PolylinePath,
    extent: float,
    keep_pts: np.ndarray,
    keep_clear: np.ndarray,
    slots_can_follow: Any,
    walls: StaticMap | None = None,
) -> list[Any]:
    """Rejection-sample up to ``n_obs`` obstacles, at most ``_OBSTACLE_TRIES * n_obs`` candidates.

    A candidate must keep ``keep_clear[i]`` from each ``keep_pts[i]``: accepted at
    once when its bounding circle does, refused when its centre does not, and
    otherwise measured exactly with :class:`StaticMap` (thin rectangles and
    polygons may come closer than their bounding circle). A candidate's bounding circle keeps a robot's
    passage from the gates' ``walls``.
    """
    W, H = size
    gap = 2.0 * cfg.radius + 0.2  # a robot fits between two obstacles and between an obstacle and a wall
    accepted: list[tuple[Any, np.ndarray, float]] = []  # (obstacle, centre, bounding radius)
    for _ in range(_OBSTACLE_TRIES * n_obs):
        if len(accepted) == n_obs:
            break
        obj, centre, rho = _draw_obstacle(rng, cfg, size, line, extent)
        if not (rho + gap <= centre[0] <= W - rho - gap and rho + gap <= centre[1] <= H - rho - gap):
            continue
        if any(math.dist(centre, c2) < rho + rho2 + gap for _, c2, rho2 in accepted):
            continue
        if walls is not None and float(walls.obstacle_distances(centre[None]).min()) < rho + gap:
            continue
        slack = float(np.min(np.hypot(keep_pts[:, 0] - centre[0], keep_pts[:, 1] - centre[1]) - keep_clear))
        if slack < rho:
            if slack <= 0.0 or isinstance(obj, CircleObstacle):
                continue
            dist = StaticMap.from_obstacles((W, H), [obj]).obstacle_distances(keep_pts)[:, 0]
            if np.any(dist < keep_clear):
                continue
        if not slots_can_follow(obj, centre, rho):
            continue
        accepted.append((obj, centre, rho))
    return [a[0] for a in accepted]


def _draw_obstacle(
    rng: np.random.Generator, cfg: RandomScenarioConfig, size: tuple[float, float], line: PolylinePath, extent: float
) -> tuple[CircleObstacle | RectangleObstacle | PolygonObstacle, np.ndarray, float]:
    """One candidate: ``(obstacle, centre, bounding radius)``, coordinates rounded to mm."""
    W, H = size
    diameter = float(rng.uniform(*cfg.obstacle_size))
    rho = diameter / 2.0
    if float(rng.uniform()) < 0.7:
        # Beside the path, within the band the formation's slots sweep.
        s = float(rng.uniform(0.0, line.length))
        p = line.point_at(s)
        h = line.heading_at(s)
        side = 1.0 if float(rng.uniform()) < 0.5 else -1.0
        lateral = side * float(rng.uniform(0.5 + rho, 0.5 + rho + extent + 1.0))
        centre = p + lateral * np.array([-math.sin(h), math.cos(h)])
    else:
        centre = rng.uniform([rho, rho], [W - rho, H - rho])
    centre = np.round(centre, 3)
    kind = cfg.obstacle_types[int(rng.integers(len(cfg.obstacle_types)))]
    cx, cy = float(centre[0]), float(centre[1])
    if kind == "circle":
        obj: Any = CircleObstacle(center=(cx, cy), radius=round(rho, 3))
    elif kind == "rectangle":
        alpha = float(rng.uniform(math.radians(20.0), math.radians(70.0)))
        obj = RectangleObstacle(
            center=(cx, cy),
            size=(round(diameter * math.cos(alpha), 3), round(diameter * math.sin(alpha), 3)),
            angle=round(float(rng.uniform(0.0, 180.0)), 1),
        )
    else:
        m = int(rng.integers(3, 7))
        # Vertices on the circumscribed circle in angular order (gaps < pi) form a convex polygon.
        base = 2.0 * math.pi * np.arange(m) / m + float(rng.uniform(0.0, 2.0 * math.pi))
        ang = base + rng.uniform(-0.3, 0.3, size=m) * (math.pi / m)
        verts = np.round(centre + rho * np.column_stack([np.cos(ang), np.sin(ang)]), 3)
        obj = PolygonObstacle(points=tuple((float(x), float(y)) for x, y in verts))
    return obj, centre, rho


# --------------------------------------------------------------------------- helpers


def _discs_inside(xy: np.ndarray, rad: float, W: float, H: float) -> bool:
    return bool(np.all(xy >= rad) and np.all(xy[:, 0] <= W - rad) and np.all(xy[:, 1] <= H - rad))


def _ray_room(p: np.ndarray, u: np.ndarray, want: float, margin: float, W: float, H: float) -> float:
    """How far (<= ``want``) one can go from ``p`` along unit ``u`` staying ``margin`` inside the world."""
    t = want
    for k, size in ((0, W), (1, H)):
        if u[k] > 1e-12:
            t = min(t, (size - margin - p[k]) / u[k])
        elif u[k] < -1e-12:
            t = min(t, (margin - p[k]) / u[k])
    return max(t, 0.0)


def _samples(line: PolylinePath) -> np.ndarray:
    k = max(2, int(math.ceil(line.length / _SAMPLE_STEP)) + 1)
    return line.points_at(np.linspace(0.0, line.length, k))


def _draw_int(rng: np.random.Generator, spec: IntRange) -> int:
    lo, hi = _span(spec)
    return lo if lo == hi else int(rng.integers(lo, hi + 1))
