"""Scenario families: named presets of the random generator, and the fixed scenarios grouped the same way.

A *family* is a kind of task with a documented difficulty, the unit a benchmark suite
(:mod:`swarm_env.harness.suite`) reports on. A generator family is a set of knobs of
:class:`~swarm_env.scenarios.generator.RandomScenarioConfig`; ``SwarmEnv("random:<family>")`` draws its worlds
(further knobs given to the env override the family's). A fixed family lists built-in scenario files.

.. code-block:: python

    env = SwarmEnv("random:cluttered")          # 14-20 obstacles, a new world per reset(seed)
    env = SwarmEnv("random:large_16", n_humans=0)   # a family's knobs, one overridden
    FAMILIES["switching"].difficulty            # 'hard'

A family's worlds for a seed are fixed for as long as its knobs and the generator are unchanged; a change to
either is a new version of every suite that holds the family (:data:`swarm_env.harness.suite.SUITES`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

from swarm_env.checks import did_you_mean
from swarm_env.scenario import ScenarioError
from swarm_env.scenarios.generator import RandomScenarioConfig, config_from_kwargs

#: The generator's scenario name; ``random:<family>`` names a generator family.
RANDOM = "random"
_PREFIX = RANDOM + ":"

#: The difficulties a family may declare, easiest first.
DIFFICULTIES = ("easy", "medium", "hard")


@dataclass(frozen=True)
class Family:
    """One family of tasks.

    Attributes:
        name: its name (``random:<name>`` for a generator family).
        description: what its worlds hold, in one sentence.
        difficulty: one of :data:`DIFFICULTIES`, measured with ``vo`` on the standard suite's validation split
            (docs/benchmark.md: easy = no collision and formation error under 0.15 m; medium = at most 5 % of
            episodes with a contact and at most 0.3 m; hard = the rest).
        knobs: generator knobs of a generator family (none: the generator's defaults).
        scenarios: built-in scenario names of a fixed family (none: a generator family).
    """

    name: str
    description: str
    difficulty: str
    knobs: Mapping[str, Any] = field(default_factory=dict)
    scenarios: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.difficulty not in DIFFICULTIES:
            raise ValueError(f"family {self.name!r}: difficulty must be one of {DIFFICULTIES}, got {self.difficulty!r}")
        if self.scenarios and self.knobs:
            raise ValueError(f"family {self.name!r}: give generator knobs or fixed scenarios, not both")
        object.__setattr__(self, "knobs", MappingProxyType(dict(self.knobs)))

    @property
    def generated(self) -> bool:
        """Whether its worlds come from the generator (else from its fixed scenario files)."""
        return not self.scenarios

    @property
    def scenario_names(self) -> tuple[str, ...]:
        """What ``SwarmEnv`` and the leaderboard take: ``("random:<name>",)`` or the fixed scenarios."""
        return (_PREFIX + self.name,) if self.generated else self.scenarios

    def config(self, **overrides: Any) -> RandomScenarioConfig:
        """The generator configuration of a generator family, ``overrides`` on top of its knobs."""
        if not self.generated:
            raise ValueError(f"family {self.name!r} is a set of fixed scenarios {list(self.scenarios)}, not generated")
        return config_from_kwargs(**{**self.knobs, **overrides})


#: Every shape wider than a column (a gate's column is then a real change of shape).
_WIDE = ("v", "line", "wedge", "diamond", "circle", "grid")
_LARGE = {"n_obstacles": (3, 8), "n_humans": (0, 2), "n_switches": (0, 1), "switch_reach": 3.0}

#: The families, by name. Generator families use the generator's defaults for every knob they do not set
#: (4 followers, a virtual leader at 0.4 m/s, 60 s, dt 0.1 s, every shape).
FAMILIES: Mapping[str, Family] = MappingProxyType({f.name: f for f in (
    Family("mixed", "the generator's defaults: 4 followers, 3-10 obstacles, 0-3 scripted walkers, 0-2 switches "
           "(the leaderboard's `random`)", "medium"),
    Family("open", "4 followers, at most 2 obstacles, no walkers, at most one switch", "easy",
           {"n_obstacles": (0, 2), "n_humans": 0, "n_switches": (0, 1)}),
    Family("cluttered", "4 followers among 14-20 obstacles of 0.4-1.4 m, at most one walker", "medium",
           {"n_obstacles": (14, 20), "obstacle_size": (0.4, 1.4), "n_humans": (0, 1)}),
    Family("crowd", "4 followers, 1-4 obstacles, 5-8 scripted walkers at 0.3-0.7 m/s crossing the path", "hard",
           {"n_obstacles": (1, 4), "n_humans": (5, 8), "human_speed": (0.3, 0.7)}),
    Family("crowd_reactive", "as crowd, with walkers that react to the robots (social force)", "medium",
           {"n_obstacles": (1, 4), "n_humans": (5, 8), "human_speed": (0.3, 0.7), "human_behavior": "social_force"}),
    Family("switching", "6 followers behind a virtual leader at 0.35 m/s for 150 s, up to 8 switches through every "
           "shape, each new formation held at least 3 times its reach time (about 3 switches survive), "
           "2-5 obstacles, 0-2 walkers", "hard",
           {"n_followers": 6, "n_switches": 8, "switch_reach": 3.0, "max_time": 150.0, "leader_speed": 0.35,
            "n_obstacles": (2, 5), "n_humans": (0, 2)}),
    Family("large_16", "16 followers, 3-8 obstacles, 0-2 walkers, at most one reachable switch", "easy",
           {"n_followers": 16, **_LARGE}),
    Family("large_32", "32 followers, 3-8 obstacles, 0-2 walkers, at most one reachable switch", "hard",
           {"n_followers": 32, **_LARGE}),
    Family("large_64", "64 followers, 3-8 obstacles, 0-2 walkers, at most one reachable switch", "medium",
           {"n_followers": 64, **_LARGE}),
    Family("robot_leader", "the generator's defaults behind a robot leader (a body the followers can hit), with walkers "
           "that react: scripted ones, timed to cross where the leader is, walk into the scripted leader, which no "
           "follower can prevent", "medium", {"leader_kind": "robot", "human_behavior": "social_force"}),
    Family("paper", "the papers' scenarios: paper 003's three crossings and paper 000's switch (dt 0.5 s)", "medium",
           scenarios=("paper_vo_0", "paper_vo_45", "paper_vo_90", "paper_cbs_switch")),
    Family("narrow", "4 followers file through 1-2 gates across the path (where they fit: 99 of training worlds 0-99 get one), "
           "each a door of 1.0-1.6 m in a wall 0.3-3 m deep (a corridor when deep), as a column ordered before the "
           "door and released after it; a path with at most one turn, 30 m x 30 m, 100 s, 0-4 obstacles, 0-2 walkers",
           "medium",
           {"n_gates": (1, 2), "gate_depth": (0.3, 3.0), "world_size": (30.0, 30.0), "max_time": 100.0,
            "n_waypoints": (2, 3), "n_obstacles": (0, 4), "n_humans": (0, 2), "n_switches": 0, "shapes": _WIDE}),
    Family("corridor", "the built-in corridor: a formation squeezing through a door in a wall", "medium",
           scenarios=("corridor",)),
)})


def is_generated(scenario: Any) -> bool:
    """Whether ``scenario`` names the generator: ``"random"`` or ``"random:<family>"``."""
    return isinstance(scenario, str) and (scenario == RANDOM or scenario.startswith(_PREFIX))


def generator_config(scenario: str, knobs: Mapping[str, Any]) -> RandomScenarioConfig:
    """The generator configuration of ``"random"`` or ``"random:<family>"`` with ``knobs`` on top.

    Raises :class:`~swarm_env.scenario.ScenarioError` for an unknown family (listing the known ones) or a family
    of fixed scenarios."""
    if scenario == RANDOM:
        return config_from_kwargs(**knobs)
    name = scenario[len(_PREFIX):]
    family = FAMILIES.get(name)
    if family is None or not family.generated:
        generated = [f.name for f in FAMILIES.values() if f.generated]
        known = ", ".join(_PREFIX + f for f in generated)
        raise ScenarioError(scenario, "<family>", f"a generator family ({known}){did_you_mean(name, generated)}", name)
    return family.config(**knobs)


def generated_names() -> list[str]:
    """``"random"`` and every ``"random:<family>"``."""
    return [RANDOM, *(_PREFIX + f.name for f in FAMILIES.values() if f.generated)]
