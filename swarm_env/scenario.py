"""The scenario: an immutable description of one swarm-env world.

A :class:`Scenario` is what a YAML file (see :mod:`swarm_env.scenarios.loader`) or the
procedural generator (:mod:`swarm_env.scenarios.generator`) produces and what
:class:`swarm_env.sim.world.World` consumes. Every field is a frozen dataclass or a
tuple, so a scenario can be hashed, shared between envs and pickled.

Units: metres, seconds, radians, except where a field says degrees (formation
``angle`` and rectangle ``angle`` are degrees because people write them so in
files).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from swarm_env.limits import clip_repr, printable

Point = tuple[float, float]
Pose = tuple[float, float, float]

LEADER_KINDS = ("virtual", "robot")
HUMAN_MODES = ("once", "loop", "pingpong")
#: How a human moves: ``scripted`` walks its path exactly and ignores everyone (paper 003's
#: humans); ``social_force`` walks towards its path's waypoints and is pushed away from robots,
#: other humans and obstacles (Helbing & Molnar 1995); ``orca`` walks towards them avoiding
#: everyone with RVO2's ORCA (the ``orca`` extra). See :mod:`swarm_env.sim.humans`.
HUMAN_BEHAVIORS = ("scripted", "social_force", "orca")
#: A reactive human's speed never exceeds this multiple of its walking ``speed`` (the
#: anti-tunnelling rule and the observation bounds count with it).
REACTIVE_SPEED_FACTOR = 1.3
FORMATION_SHAPES = ("v", "line", "column", "wedge", "diamond", "circle", "grid", "custom")


class ScenarioError(ValueError):
    """A scenario file or dict is malformed.

    The message names the source (file path or ``<dict>``), the key path
    (e.g. ``robots.max_speed``) and what was expected. It is one line, safe to print:
    control and bidi characters are escaped, and the value shown (``got``) is cut to
    :data:`swarm_env.limits.MESSAGE_VALUE_CHARS` characters, built in bounded time.

    Validation reports every problem it finds, not only the first: ``errors`` holds
    them all (one :class:`ScenarioError` each, in file order; ``(self,)`` for a single
    one). An error made by :meth:`several` takes ``source``, ``key``, ``expected`` and
    ``got`` from the first problem, and its message is one line per problem, the first
    :data:`MAX_MESSAGE_LINES` of them and then a line counting the rest (``errors`` keeps all).
    """

    #: Most problems written in the message of an error made by :meth:`several`.
    MAX_MESSAGE_LINES = 10

    def __init__(self, source: str, key: str, expected: str, got: object = None) -> None:
        self.source = source
        self.key = key
        self.expected = expected
        self.got = got
        self.errors: tuple[ScenarioError, ...] = (self,)
        got_txt = "" if got is None else f", got {clip_repr(got)}"
        # Keys, sources and expectations can quote the file (an unknown key, a path): escaped, and
        # bounded so that one line stays one line.
        super().__init__(f"{printable(str(source), 200)}: {printable(str(key), 200)}: "
                         f"expected {printable(str(expected), 1000)}{got_txt}")

    @classmethod
    def several(cls, errors: list[ScenarioError] | tuple[ScenarioError, ...]) -> ScenarioError:
        """One error carrying all of ``errors`` (non-empty; nested ones are flattened):
        the error itself when there is only one."""
        flat = tuple(e for err in errors for e in err.errors)
        if not flat:
            raise ValueError("ScenarioError.several needs at least one error")
        if len(flat) == 1:
            return flat[0]
        first = flat[0]
        combined = cls(first.source, first.key, first.expected, first.got)
        combined.errors = flat
        shown = [str(e) for e in flat[: cls.MAX_MESSAGE_LINES]]
        if len(flat) > cls.MAX_MESSAGE_LINES:
            shown.append(f"{printable(str(first.source), 200)}: ... and {len(flat) - cls.MAX_MESSAGE_LINES} more problems")
        combined.args = ("\n".join(shown),)
        return combined


@dataclass(frozen=True)
class WorldSpec:
    """The world rectangle ``[0, W] x [0, H]`` (closed by walls) and time stepping.

    ``dt`` is the control period (one ``env.step``); the physics runs
    ``substeps`` steps of ``dt / substeps``. ``settle_tolerance`` is the slot
    distance (m) under which every follower must be for the formation to count
    as settled (termination and ``settle_times``).
    """

    size: Point
    dt: float = 0.1
    substeps: int = 4
    max_time: float = 60.0
    settle_tolerance: float = 0.3


@dataclass(frozen=True)
class RobotSpec:
    """The followers: ``count`` identical differential-drive discs.

    ``max_accel`` (m/s^2) and ``max_turn_accel`` (rad/s^2) are optional rate
    limits applied in every physics substep; ``None`` means unlimited.
    ``start`` is ``"formation"`` (each follower starts on its first slot,
    facing the leader's heading) or one ``(x, y, theta)`` pose per follower.
    """

    count: int
    radius: float = 0.25
    max_speed: float = 0.65
    max_turn_rate: float = 1.0
    max_accel: float | None = None
    max_turn_accel: float | None = None
    wheelbase: float = 0.5
    start: Literal["formation"] | tuple[Pose, ...] = "formation"


@dataclass(frozen=True)
class LeaderSpec:
    """The leader, moving along the polyline ``path`` at ``speed``.

    ``kind="virtual"``: a point that moves exactly along the path (paper 000);
    it collides with nothing. ``kind="robot"``: a physical differential-drive
    disc of ``radius`` that tracks the path with pure pursuit (``lookahead``
    metres ahead) and avoids obstacles and humans with a velocity-obstacle
    rule (paper 003); ``max_turn_rate`` bounds its turn rate.
    ``start_delay`` seconds pass before the leader starts moving.
    """

    kind: Literal["virtual", "robot"]
    path: tuple[Point, ...]
    speed: float
    radius: float = 0.25
    max_turn_rate: float = 1.0
    lookahead: float = 1.0
    start_delay: float = 0.0


@dataclass(frozen=True)
class FormationSpec:
    """One entry of the formation schedule, active from time ``at`` (s).

    Slot offsets live in the leader frame (x forward, y left). ``spacing`` is
    the distance between neighbouring slots (m); ``angle`` (degrees) is the
    half-opening of the ``v`` and ``wedge`` arms measured from the leader's
    backward axis; ``offsets`` (one ``(x, y)`` per follower) is used by
    ``shape="custom"`` only. ``columns`` is used by ``grid`` (0 = automatic).
    """

    at: float
    shape: str
    spacing: float = 1.0
    angle: float = 45.0
    offsets: tuple[Point, ...] | None = None
    columns: int = 0


@dataclass(frozen=True)
class CircleObstacle:
    center: Point
    radius: float
    type: Literal["circle"] = "circle"


@dataclass(frozen=True)
class RectangleObstacle:
    """A rectangle of ``size = (width, height)`` centred on ``center``, rotated by ``angle`` degrees."""

    center: Point
    size: Point
    angle: float = 0.0
    type: Literal["rectangle"] = "rectangle"


@dataclass(frozen=True)
class PolygonObstacle:
    """A convex polygon; ``points`` in either winding order (stored counter-clockwise)."""

    points: tuple[Point, ...]
    type: Literal["polygon"] = "polygon"


Obstacle = CircleObstacle | RectangleObstacle | PolygonObstacle


@dataclass(frozen=True)
class HumanSpec:
    """A walking human: a disc moved kinematically along ``path`` at ``speed``.

    ``mode``: ``once`` stops at the last waypoint, ``loop`` jumps back along
    the closing segment to the first, ``pingpong`` walks the path back and
    forth. The human stands on the first waypoint for ``start_delay`` seconds.
    ``behavior``: ``scripted`` (default) humans do not react to robots; ``social_force``
    and ``orca`` humans head for the same waypoints in the same modes but give way to
    robots, other humans and obstacles (:mod:`swarm_env.sim.humans`), at most
    ``REACTIVE_SPEED_FACTOR * speed``.
    """

    path: tuple[Point, ...]
    speed: float = 0.5
    radius: float = 0.3
    mode: Literal["once", "loop", "pingpong"] = "once"
    start_delay: float = 0.0
    behavior: Literal["scripted", "social_force", "orca"] = "scripted"

    @property
    def top_speed(self) -> float:
        """The fastest this human can walk (m/s)."""
        return self.speed * (REACTIVE_SPEED_FACTOR if self.behavior != "scripted" else 1.0)


@dataclass(frozen=True)
class SensorSpec:
    """What each follower observes: a ``lidar_rays``-ray lidar of ``lidar_range`` m,
    the ``neighbors`` nearest other robots and the ``humans`` nearest humans."""

    lidar_rays: int = 16
    lidar_range: float = 5.0
    neighbors: int = 3
    humans: int = 2


@dataclass(frozen=True)
class RewardSpec:
    """Weights of the per-agent reward terms (see :mod:`swarm_env.scoring.rewards` for the formula).

    All weights are magnitudes (the env fixes each term's sign):

    * ``formation`` multiplies the distance to the slot target (m);
    * ``collision`` the number of contact *onsets* of the follower in the step
      (the paper-000 event count);
    * ``contact`` the number of bodies the follower *is touching* during the
      step (obstacles, walls, humans, robots): charged on every step of a
      contact, not only its first (reward v1);
    * ``clearance`` the intrusion ``max(0, 1 - clearance / clearance_margin)``
      into a margin of ``clearance_margin`` m of free space around the disc;
    * ``smoothness`` the squared change of the normalised action;
    * ``progress`` (a bonus) the decrease of the slot distance;
    * ``approach`` the intrusion ``max(0, 1 - gap / approach_margin)`` of the
      smallest surface gap to another moving body (follower, robot leader,
      human) at their closest point of approach within ``approach_horizon``
      seconds, both keeping their current velocities: an anticipatory clearance
      that warns of a contact before it happens (0 in v1; a training-time
      shaping term of the learned baselines).

    The defaults are reward v1 (see ``SwarmEnv``'s docstring for why);
    :meth:`v0` gives the swarm_env_v0 weights (onsets only, no clearance).
    """

    formation: float = 1.0
    collision: float = 5.0
    contact: float = 2.0
    clearance: float = 1.0
    clearance_margin: float = 0.2
    smoothness: float = 0.0
    progress: float = 0.0
    approach: float = 0.0
    approach_horizon: float = 2.0
    approach_margin: float = 0.5

    @classmethod
    def v0(cls) -> RewardSpec:
        """The swarm_env_v0 reward: ``-formation distance - 10 * new contacts``, nothing else."""
        return cls(formation=1.0, collision=10.0, contact=0.0, clearance=0.0, clearance_margin=0.2)


@dataclass(frozen=True)
class Scenario:
    """A whole world description. ``source`` is the file it came from (for messages)."""

    name: str
    world: WorldSpec
    robots: RobotSpec
    leader: LeaderSpec
    formations: tuple[FormationSpec, ...]
    obstacles: tuple[Obstacle, ...] = ()
    humans: tuple[HumanSpec, ...] = ()
    sensors: SensorSpec = field(default_factory=SensorSpec)
    reward: RewardSpec = field(default_factory=RewardSpec)
    description: str = ""
    source: str = "<dict>"

    @property
    def n_followers(self) -> int:
        return self.robots.count
