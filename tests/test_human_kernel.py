"""The compiled scripted humans (swarm_env.sim.human_kernel) give swarm_env.geometry.paths.human_states' bits."""

from __future__ import annotations

import numpy as np
import pytest

from swarm_env.geometry.paths import human_paths, human_states
from swarm_env.scenario import HumanSpec
from swarm_env.scenarios.loader import list_scenarios, load_scenario
from swarm_env.sim.human_kernel import PackedHumans


def _check(humans: list[HumanSpec], times: np.ndarray) -> None:
    paths = human_paths(humans)
    packed = PackedHumans(humans, paths)
    for t in times.tolist():
        got, want = packed.states(t), human_states(humans, t, paths)
        for a, b in zip(got, want):
            assert a.shape == b.shape
            assert a.tobytes() == b.tobytes(), f"t={t}"


def test_every_mode_and_path_shape() -> None:
    rng = np.random.default_rng(0)
    humans = []
    for k in range(60):
        m = int(rng.integers(1, 6))
        path = [tuple(p) for p in rng.uniform(0, 20, (m, 2)).round(int(rng.integers(0, 3))).tolist()]
        if k % 7 == 0:
            path = path[:1] * 2  # degenerate: one point twice
        if k % 11 == 0 and len(path) > 1:
            path.insert(1, path[0])  # a repeated vertex
        humans.append(HumanSpec(path=tuple(path), speed=float(rng.choice([0.0, 0.7, 1.25, 2.0])),
                                start_delay=float(rng.choice([0.0, 1.5, 30.0])), mode=str(rng.choice(["once", "loop", "pingpong"])),
                                radius=0.3))
    # times on a fine grid, far beyond the paths' periods, and exactly at vertices of the first human
    times = np.concatenate([np.arange(0.0, 400.0, 0.025), rng.uniform(0, 5e4, 200), [0.0, 1.5, 30.0]])
    _check(humans, times)


WITH_HUMANS = [n for n in list_scenarios() if n != "random" and load_scenario(n).humans]


@pytest.mark.parametrize("name", WITH_HUMANS)
def test_built_in_scenarios(name: str) -> None:
    assert len(WITH_HUMANS) >= 3
    _check(list(load_scenario(name).humans), np.arange(0.0, 300.0, 0.025))
