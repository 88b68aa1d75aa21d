"""Fuzzing the scenario validator and the ``random`` generator's knobs (hypothesis).

The contract (issue 14): whatever a scenario file or dict holds, validation ends in either a
valid scenario, whose env builds, resets and steps, or a :class:`ScenarioError` whose messages
are short printable lines; never another exception, never a hang. The same for every
combination of ``parallel_env("random", **knobs)``. The bounds that make this hold are in
:mod:`swarm_env.limits`.

The test suite runs 2,000 scenario mutations (among the slow tests, ``-m slow``) and 300 knob draws,
derandomised (the same examples every run, so CI never meets a new one by chance); ``python -m pytest
-m fuzz`` runs ten times as many with fresh random examples.
"""

from __future__ import annotations

import copy
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from swarm_env import SwarmEnv
from swarm_env.limits import MESSAGE_VALUE_CHARS
from swarm_env.scenario import ScenarioError
from swarm_env.scenarios.loader import load_scenario, scenario_from_dict, scenario_to_dict

BASES = {name: scenario_to_dict(load_scenario(name)) for name in ("paper_vo_0", "paper_cbs_switch", "crowd_reactive")}
# A custom formation and explicit start poses, so that those keys are mutated too.
_custom = copy.deepcopy(BASES["paper_vo_0"])
_custom["formations"].append({"at": 30.0, "shape": "custom", "offsets": [[-1.0, 1.0], [-1.0, -1.0]]})
_custom["formations"].append({"at": 40.0, "shape": "grid", "spacing": 1.0, "columns": 1})
_custom["robots"]["start"] = [[2.0, 5.0, 0.0], [2.0, 9.0, 0.0]]
BASES["custom"] = _custom

# The longest an example may take: far beyond any valid one (a few ms to validate, ~0.1 s for the
# largest env) even on a loaded machine, far below a hang.
SLOW_S = 120.0

HOSTILE_SCALARS = [
    0, -1, 1, 2, 63, 64, 65, 361, 10_000, 2**31, 2**63, 10**30, -(10**30), 10**400,
    0.0, -0.0, 1e-300, 1e-9, 1e-3, 0.5, 1e6, 1e7, 1e20, 1e308, -1e308, math.inf, -math.inf, math.nan,
    True, False, None, "", "x", "1e3", "1.0e+3", "formation", "evil\u202e\x1b[31m", "a" * 500,
    [], {}, [[]], [1, 2], [1, 2, 3], [[1, 2]], {"x": 1},
]

hostile = st.one_of(
    st.sampled_from(HOSTILE_SCALARS),
    st.integers(min_value=-(2**70), max_value=2**70),
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(min_value=-5.0, max_value=80.0),  # near the valid values: mutations that may be accepted
    st.text(max_size=6),
    st.lists(st.floats(min_value=-5.0, max_value=40.0), min_size=0, max_size=4),
    st.lists(st.lists(st.floats(min_value=-5.0, max_value=40.0), min_size=2, max_size=2), min_size=0, max_size=5),
)


def _paths(obj: Any, prefix: tuple = ()) -> list[tuple]:
    """Every key path into ``obj`` (a parsed scenario: dicts and lists)."""
    out = [prefix] if prefix else []
    if isinstance(obj, dict):
        for k, v in obj.items():
            out += _paths(v, prefix + (k,))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            out += _paths(v, prefix + (i,))
    return out


PATHS = {name: _paths(d) for name, d in BASES.items()}


@st.composite
def mutated_scenarios(draw: st.DrawFn) -> dict:
    """A built-in scenario with 1-3 mutations: a value replaced, a key deleted or added, a list
    grown (up to thousands of entries) or nested, a subtree copied elsewhere."""
    name = draw(st.sampled_from(sorted(BASES)))
    data = copy.deepcopy(BASES[name])
    for _ in range(draw(st.integers(1, 3))):
        path = draw(st.sampled_from(PATHS[name]))
        parent: Any = data
        try:
            for k in path[:-1]:
                parent = parent[k]
            last = path[-1]
            current = parent[last]
        except (KeyError, IndexError, TypeError):  # an earlier mutation changed the shape here
            continue
        if not isinstance(parent, (dict, list)):  # indexed into a string an earlier mutation wrote
            continue
        op = draw(st.sampled_from(["replace", "replace", "replace", "delete", "add_key", "grow", "nest", "swap"]))
        if op == "replace":
            parent[last] = draw(hostile)
        elif op == "delete":
            del parent[last]
        elif op == "add_key" and isinstance(current, dict):
            current[draw(st.sampled_from(["extra", "spped", "<<", "", "\u202e"]))] = draw(hostile)
        elif op == "grow" and isinstance(current, list) and current:
            parent[last] = current * draw(st.sampled_from([2, 33, 65, 300, 20_000]))
        elif op == "nest":
            parent[last] = [current] * draw(st.integers(1, 3))
        elif op == "swap":
            other = draw(st.sampled_from(PATHS[name]))
            src: Any = BASES[name]
            for k in other:
                src = src[k]
            parent[last] = copy.deepcopy(src)
    return data


def _check_error(exc: ScenarioError) -> None:
    """Every reported problem is one bounded, printable line."""
    assert exc.errors
    for err in exc.errors:
        text = str(err)
        assert "\n" not in text and text.isprintable(), repr(text)
        assert len(text) < 2000
        got = text.rpartition(", got ")[2] if ", got " in text else ""
        assert len(got) <= MESSAGE_VALUE_CHARS + 120  # the value shown is clipped (its tail may hold a count)


def _run_env(env: SwarmEnv) -> None:
    obs, _ = env.reset(seed=0)
    for agent, o in obs.items():
        assert env.observation_space(agent).contains(o)
    for _ in range(2):
        if not env.agents:  # a one-step episode
            break
        obs, rewards, _term, _trunc, _infos = env.step({a: env.action_space(a).sample() for a in env.agents})
        assert all(math.isfinite(r) for r in rewards.values())
        for agent, o in obs.items():
            assert env.observation_space(agent).contains(o)
    env.close()


def _validate_and_step(data: Any) -> bool:
    """Validate ``data``; when valid, build its env and step it. True when it was accepted."""
    start = time.perf_counter()
    try:
        scn = scenario_from_dict(data)
    except ScenarioError as exc:
        _check_error(exc)
        accepted = False
    else:
        _run_env(SwarmEnv(scn))
        accepted = True
    assert time.perf_counter() - start < SLOW_S
    return accepted


@pytest.fixture(scope="module", autouse=True)
def _warm_kernels() -> None:
    """Compile the lidar kernels once, so that no example pays for it."""
    _run_env(SwarmEnv("paper_vo_0"))


_FAST = settings(
    max_examples=2000, derandomize=True, database=None, deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.filter_too_much],
)
_LONG = settings(_FAST, max_examples=20_000, derandomize=False)


@_FAST
@given(mutated_scenarios())
@pytest.mark.slow
def test_mutated_scenario_is_valid_or_a_scenario_error(data: dict) -> None:
    _validate_and_step(data)


@pytest.mark.fuzz
@_LONG
@given(mutated_scenarios())
def test_mutated_scenario_long_run(data: dict) -> None:
    _validate_and_step(data)


@settings(_FAST, max_examples=150)
@given(data=mutated_scenarios())
def test_mutated_file_is_valid_or_a_scenario_error(data: dict, tmp_path_factory: pytest.TempPathFactory) -> None:
    """The same through a YAML file: the loader's own bounds and messages."""
    path = Path(tmp_path_factory.mktemp("fuzz")) / "mutant.yaml"
    try:
        text = yaml.safe_dump(data)
    except (yaml.YAMLError, OverflowError):  # nothing YAML can write: nothing a file can hold
        return
    path.write_text(text)
    try:
        scn = load_scenario(path)
    except ScenarioError as exc:
        _check_error(exc)
        return
    _run_env(SwarmEnv(scn))


# --------------------------------------------------------------------------- the random generator's knobs


def _pair(lo: float, hi: float) -> st.SearchStrategy:
    return st.tuples(st.floats(lo, hi), st.floats(lo, hi))


KNOBS: dict[str, st.SearchStrategy] = {
    "n_followers": st.one_of(st.integers(-2, 70), st.tuples(st.integers(0, 8), st.integers(0, 70)),
                             st.just((0, 10**9))),
    "n_obstacles": st.one_of(st.integers(-1, 12), st.just(101), st.just((0, 10**9))),
    "n_humans": st.one_of(st.integers(-1, 4), st.just(33), st.just((0, 10**9))),
    "n_switches": st.one_of(st.integers(-1, 3), st.just(9)),
    "obstacle_size": st.one_of(_pair(0.05, 3.0), st.just((1e20, 1e20)), st.just((0.0, 1.0))),
    "human_speed": st.one_of(_pair(0.05, 1.0), st.just((0.1, 1e308))),
    "human_radius": st.one_of(st.floats(0.001, 1.0), st.just(math.nan)),
    "human_behavior": st.sampled_from(["scripted", "social_force", "walk", 3]),
    "shapes": st.one_of(st.lists(st.sampled_from(["v", "line", "column", "wedge", "diamond", "circle", "grid"]),
                                 min_size=1, max_size=3),
                        st.just(["custom"]), st.just([]), st.just("v")),
    "spacing": st.one_of(_pair(0.3, 3.0), st.just((100.0, 100.0)), st.just((1e6, 1e6))),
    "angle": st.one_of(_pair(1.0, 179.0), st.just((30.0, 200.0))),
    "world_size": st.one_of(st.just("auto"), _pair(2.0, 60.0), st.just((1e20, 1e20)), st.just("big")),
    "leader_kind": st.sampled_from(["virtual", "robot", "ghost"]),
    "leader_speed": st.one_of(st.floats(0.05, 0.7), st.just(1e308)),
    "max_time": st.one_of(st.floats(0.05, 60.0), st.just(1e12), st.just(-1.0)),
    "dt": st.one_of(st.floats(0.02, 0.5), st.just(1e-9), st.just(0.0)),
    "substeps": st.one_of(st.integers(0, 12), st.just(10**6), st.just(True)),
    "radius": st.one_of(st.floats(0.005, 0.6), st.just(1e-300)),
    "max_speed": st.one_of(st.floats(0.1, 2.0), st.just(math.inf)),
    "sensors": st.one_of(st.just({"lidar_rays": 10**9}), st.just({"neighbors": 10**9}),
                         st.fixed_dictionaries({"lidar_rays": st.integers(1, 32), "neighbors": st.integers(0, 8)}),
                         st.just("sensors")),
    "bogus_knob": st.just(1),
}


@st.composite
def knob_sets(draw: st.DrawFn) -> dict:
    """A few knobs, each from a mix of valid and hostile values."""
    names = draw(st.lists(st.sampled_from(sorted(KNOBS)), min_size=0, max_size=4, unique=True))
    knobs = {k: draw(KNOBS[k]) for k in names}
    # Keep the valid examples cheap (the generator's cost grows with team and episode length).
    if "n_followers" not in knobs:
        knobs["n_followers"] = draw(st.integers(1, 6))
    return knobs


def _random_env(knobs: dict) -> None:
    """Build, reset and step; a ScenarioError may come from the knobs or, for a world too cramped
    for the team, from the draw of an episode's world at reset."""
    start = time.perf_counter()
    try:
        _run_env(SwarmEnv("random", **knobs))
    except ScenarioError as exc:
        _check_error(exc)
    assert time.perf_counter() - start < SLOW_S


@settings(_FAST, max_examples=300)
@given(knob_sets())
def test_random_knobs_give_an_env_or_a_scenario_error(knobs: dict) -> None:
    _random_env(knobs)


@pytest.mark.fuzz
@settings(_LONG, max_examples=3000)
@given(knob_sets())
def test_random_knobs_long_run(knobs: dict) -> None:
    _random_env(knobs)


def test_numpy_integers_in_knobs_and_files_are_bounded() -> None:
    """Bounds hold for numpy scalars too (they are Integral/Real, not int/float)."""
    with pytest.raises(ScenarioError, match="n_followers"):
        SwarmEnv("random", n_followers=np.int64(10**9))
    data = copy.deepcopy(BASES["paper_vo_0"])
    data["robots"]["count"] = np.int64(2**62)
    with pytest.raises(ScenarioError, match=r"robots.count: expected an integer of at most 64 \(swarm_env.limits.MAX_ROBOTS\)"):
        scenario_from_dict(data)
