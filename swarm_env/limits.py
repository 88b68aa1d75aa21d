"""Upper bounds of scenario values: the one table that keeps validation and episodes bounded.

A scenario file is input from anyone, so every value that sets an amount of work or memory
has a bound, checked before that work is done: reading the file (its size, YAML aliases,
nesting), parsing numbers, laying out geometry, and the counts an episode derives from the
scenario (steps, substeps, rays x robots). :mod:`swarm_env.scenarios.loader` checks files and dicts
against this table, :func:`swarm_env.scenarios.loader.validate_scenario` checks every scenario
(the ``random`` generator's too), and :class:`swarm_env.scenarios.generator.RandomScenarioConfig`
checks its knobs against the same numbers; each error message names the bound it broke.

The bounds are generous for every built-in scenario and for the generator's whole range
(1-64 followers, worlds up to about 180 m); raise one here if a real scenario needs more.
:data:`LIMITS` lists them all with what they bound (``docs/scenarios.md`` prints it).

Also here: how error messages show values (:func:`clip_repr`, :func:`printable`), so that a
hostile value never makes a message long, slow to build, or able to rewrite a terminal.
"""

from __future__ import annotations

import reprlib
import unicodedata
from typing import Any

__all__ = [
    "LIMITS",
    "MAX_FILE_BYTES",
    "MAX_YAML_NODES",
    "MAX_YAML_DEPTH",
    "MAX_NUMBER_CHARS",
    "MAX_ABS_NUMBER",
    "MAX_ROBOTS",
    "MAX_HUMANS",
    "MAX_OBSTACLES",
    "MAX_FORMATIONS",
    "MAX_WAYPOINTS",
    "MAX_POLYGON_VERTICES",
    "MAX_OBSTACLE_VERTICES",
    "MAX_LIDAR_RAYS",
    "MAX_NEIGHBORS",
    "MAX_SENSED_HUMANS",
    "MAX_SUBSTEPS",
    "MAX_EPISODE_STEPS",
    "MIN_DT",
    "MAX_DT",
    "MAX_WORLD_SIZE",
    "MIN_RADIUS",
    "MIN_OBSTACLE_SIZE",
    "MIN_FORMATION_ANGLE",
    "MAX_SPEED",
    "MIN_SPEED",
    "MAX_TURN_RATE",
    "MAX_NAME_CHARS",
    "MAX_DESCRIPTION_CHARS",
    "MESSAGE_VALUE_CHARS",
    "clip_repr",
    "printable",
    "unprintable_chars",
]

# --------------------------------------------------------------------------- reading a file
#: Largest scenario file read (bytes); checked with ``stat`` before reading. Built-in files are
#: under 3 kB and a saved 64-follower ``random`` world about 15 kB.
MAX_FILE_BYTES = 1 << 20
#: Largest number of YAML nodes a file may stand for once its aliases are expanded (what
#: ``yaml.safe_load`` would build); an alias bomb is refused before anything is built.
MAX_YAML_NODES = 100_000
#: Deepest nesting of YAML collections (the format needs 5: ``formations[i].offsets[j][k]``).
MAX_YAML_DEPTH = 16
#: Longest written number (characters): a 5000-digit integer is refused, not parsed.
MAX_NUMBER_CHARS = 40

# --------------------------------------------------------------------------- values
#: Largest magnitude of any number of a scenario that has no tighter bound below (angles,
#: times, reward weights, accelerations): keeps every derived quantity finite.
MAX_ABS_NUMBER = 1e6
#: Largest ``robots.count`` (the ``random`` generator's ``n_followers`` range ends here too).
MAX_ROBOTS = 64
#: Most humans (``humans`` entries; the generator's ``n_humans``).
MAX_HUMANS = 32
#: Most obstacles (``obstacles`` entries).
MAX_OBSTACLES = 256
#: Most entries of the formation schedule.
MAX_FORMATIONS = 64
#: Most waypoints of one path (the leader's or a human's).
MAX_WAYPOINTS = 10_000
#: Most vertices of one polygon obstacle.
MAX_POLYGON_VERTICES = 64
#: Most obstacle vertices in one scenario, all obstacles together (a polygon counts its points, a rectangle
#: 4, a circle 1): a derived bound on the work of a step. The free-space geometry pairs every boundary piece
#: with every other (a matrix of (2 x vertices)^2 entries), and every lidar ray, clearance query and expert's
#: shield scans the edges: 256 polygons of 64 points (16,384 vertices) cost 0.085 s of CPU per env step with
#: 64 followers, 360 rays and 100 substeps, 32 polygons (this bound) 0.0097 s (``python benchmarks/scenario_cost.py
#: --polygons 32 256``); ``cbs_rrt`` took 2.2 s per step on ``paper_vo_0`` given the 256 polygons. The ``random``
#: generator draws at most 600 vertices, the built-in scenarios at most 22.
MAX_OBSTACLE_VERTICES = 2048
#: Most lidar rays per follower (``sensors.lidar_rays``).
MAX_LIDAR_RAYS = 360
#: Most neighbour rows in an observation (``sensors.neighbors``). Rows beyond ``robots.count - 1``
#: are allowed and always absent (zeros, present-mask 0): the observation size does not depend
#: on the team, so a policy can be used across team sizes.
MAX_NEIGHBORS = MAX_ROBOTS - 1
#: Most human rows in an observation (``sensors.humans``); rows beyond the humans present are absent.
MAX_SENSED_HUMANS = MAX_HUMANS
#: Most physics substeps per control step (``world.substeps``).
MAX_SUBSTEPS = 100
#: Most control steps per episode, ``floor(world.max_time / world.dt)`` (built-ins: at most 700).
MAX_EPISODE_STEPS = 10_000
#: Shortest control period ``world.dt`` (s).
MIN_DT = 1e-3
#: Longest control period ``world.dt`` (s).
MAX_DT = 10.0
#: Largest side of the world (m); also bounds every length (radii, spacings, ranges, sizes).
MAX_WORLD_SIZE = 1000.0
#: Smallest disc radius (m) of followers, the robot leader and humans.
MIN_RADIUS = 0.01
#: Smallest side of a rectangle obstacle and radius of a circle obstacle (m): a thinner one is a
#: degenerate shape to the geometry.
MIN_OBSTACLE_SIZE = 1e-3
#: Narrowest ``v``/``wedge`` half-opening (degrees); the widest is ``180 - MIN_FORMATION_ANGLE``
#: (a slot's distance grows as ``1 / sin(angle)``).
MIN_FORMATION_ANGLE = 1.0
#: Largest speed (m/s) of followers, the leader and humans.
MAX_SPEED = 20.0
#: Smallest speed (m/s) of followers, the leader and humans (times are lengths over speeds).
MIN_SPEED = 1e-3
#: Largest turn rate (rad/s) of followers and the robot leader.
MAX_TURN_RATE = 100.0
#: Longest ``name`` (characters); names must also be printable (no control or bidi characters).
MAX_NAME_CHARS = 100
#: Longest ``description`` (characters); printable, line breaks and tabs allowed.
MAX_DESCRIPTION_CHARS = 10_000

# --------------------------------------------------------------------------- messages
#: Longest shown value in an error message (characters); longer ones end in ``...``.
MESSAGE_VALUE_CHARS = 80

#: Every bound above: ``name -> (value, what it bounds)``; the documentation's table.
LIMITS: dict[str, tuple[float, str]] = {
    "MAX_FILE_BYTES": (MAX_FILE_BYTES, "size of a scenario file (bytes), checked before reading"),
    "MAX_YAML_NODES": (MAX_YAML_NODES, "YAML nodes once aliases are expanded (alias bombs)"),
    "MAX_YAML_DEPTH": (MAX_YAML_DEPTH, "nesting depth of YAML collections"),
    "MAX_NUMBER_CHARS": (MAX_NUMBER_CHARS, "characters of one written number"),
    "MAX_ABS_NUMBER": (MAX_ABS_NUMBER, "magnitude of any other number (angles, times, weights, accelerations)"),
    "MAX_ROBOTS": (MAX_ROBOTS, "robots.count; the generator's n_followers"),
    "MAX_HUMANS": (MAX_HUMANS, "humans entries; the generator's n_humans"),
    "MAX_OBSTACLES": (MAX_OBSTACLES, "obstacles entries"),
    "MAX_FORMATIONS": (MAX_FORMATIONS, "formations entries"),
    "MAX_WAYPOINTS": (MAX_WAYPOINTS, "waypoints of one path"),
    "MAX_POLYGON_VERTICES": (MAX_POLYGON_VERTICES, "vertices of one polygon"),
    "MAX_OBSTACLE_VERTICES": (MAX_OBSTACLE_VERTICES, "obstacle vertices of a scenario, all obstacles together "
                              "(polygon: its points, rectangle: 4, circle: 1)"),
    "MAX_LIDAR_RAYS": (MAX_LIDAR_RAYS, "sensors.lidar_rays"),
    "MAX_NEIGHBORS": (MAX_NEIGHBORS, "sensors.neighbors (rows past robots.count - 1 are absent)"),
    "MAX_SENSED_HUMANS": (MAX_SENSED_HUMANS, "sensors.humans (rows past the humans present are absent)"),
    "MAX_SUBSTEPS": (MAX_SUBSTEPS, "world.substeps"),
    "MAX_EPISODE_STEPS": (MAX_EPISODE_STEPS, "control steps per episode, floor(world.max_time / world.dt)"),
    "MIN_DT": (MIN_DT, "shortest world.dt (s)"),
    "MAX_DT": (MAX_DT, "longest world.dt (s)"),
    "MAX_WORLD_SIZE": (MAX_WORLD_SIZE, "world.size sides and every length (m)"),
    "MIN_RADIUS": (MIN_RADIUS, "smallest disc radius (m): followers, robot leader, humans"),
    "MIN_OBSTACLE_SIZE": (MIN_OBSTACLE_SIZE, "smallest rectangle side and circle-obstacle radius (m)"),
    "MIN_FORMATION_ANGLE": (MIN_FORMATION_ANGLE, "formation angle in [MIN, 180 - MIN] degrees"),
    "MAX_SPEED": (MAX_SPEED, "speeds (m/s): robots.max_speed, leader.speed, human speed"),
    "MIN_SPEED": (MIN_SPEED, "smallest of the same speeds (m/s)"),
    "MAX_TURN_RATE": (MAX_TURN_RATE, "turn rates (rad/s)"),
    "MAX_NAME_CHARS": (MAX_NAME_CHARS, "characters of name"),
    "MAX_DESCRIPTION_CHARS": (MAX_DESCRIPTION_CHARS, "characters of description"),
    "MESSAGE_VALUE_CHARS": (MESSAGE_VALUE_CHARS, "characters of a value shown in an error message"),
}


# --------------------------------------------------------------------------- showing values

# Unicode categories that are never shown raw: controls (Cc), format characters (Cf: the
# bidi overrides and isolates, zero-width joiners), separators other than the space (Zl, Zp),
# surrogates and unassigned code points.
_HIDDEN = {"Cc", "Cf", "Cs", "Co", "Cn", "Zl", "Zp"}


def unprintable_chars(text: str, allowed: str = "") -> list[str]:
    """The distinct characters of ``text`` that :func:`printable` would escape, less ``allowed``."""
    return sorted({c for c in text if c not in allowed and unicodedata.category(c) in _HIDDEN})


def printable(text: str, limit: int | None = None) -> str:
    """``text`` with control, bidi and other invisible characters written as ``\\x..``/``\\u..``
    escapes, cut to ``limit`` characters (ending in ``...``) when given. Safe to print."""
    out = "".join(
        c if unicodedata.category(c) not in _HIDDEN else (f"\\x{ord(c):02x}" if ord(c) < 0x100 else f"\\u{ord(c):04x}"
                                                         if ord(c) < 0x10000 else f"\\U{ord(c):08x}")
        for c in (text if limit is None else text[: 4 * limit])
    )
    if limit is not None and (len(out) > limit or len(text) > 4 * limit):
        out = out[: max(limit - 3, 0)] + "..."
    return out


class _BoundedRepr(reprlib.Repr):
    """``reprlib`` with small per-level limits, and integers too long for ``repr`` shown by size."""

    def __init__(self) -> None:
        super().__init__()
        self.maxlevel = 3
        self.maxstring = MESSAGE_VALUE_CHARS
        self.maxother = MESSAGE_VALUE_CHARS
        self.maxlong = MESSAGE_VALUE_CHARS

    def repr_int(self, x: int, level: int) -> str:
        if x.bit_length() > 256:  # Python refuses str() of ints over 4300 digits; never build it
            return f"<an integer of {x.bit_length()} bits>"
        return super().repr_int(x, level)


_REPR = _BoundedRepr()


def clip_repr(value: Any, limit: int = MESSAGE_VALUE_CHARS) -> str:
    """A ``repr`` of ``value`` of at most ``limit`` characters, in time and memory bounded by
    the limits of ``reprlib`` (a few elements per level, three levels), whatever ``value`` is:
    an alias bomb, a self-containing list, a 5000-digit integer. Invisible characters are escaped."""
    try:
        text = _REPR.repr(value)
    except Exception:  # noqa: BLE001 - a value whose __repr__ fails still gets a message
        text = f"<{type(value).__name__}>"
    return printable(text, limit)
