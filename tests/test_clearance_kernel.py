"""The compiled clearances (swarm_env.geometry.clearance_kernel) give the numpy references' bits."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from swarm_env.compiled import use_compiled_kernels
from swarm_env.env import SwarmEnv
from swarm_env.harness.leaderboard import _behaviour
from swarm_env.scenarios.loader import list_scenarios
from swarm_env.scoring.rewards import clearance


def _both(fn: Callable[[], Any]) -> tuple[Any, Any]:
    """``fn()`` compiled, then by the numpy references."""
    use_compiled_kernels(True)
    try:
        compiled = fn()
        use_compiled_kernels(False)
        reference = fn()
    finally:
        use_compiled_kernels(True)
    return compiled, reference


def _same(a: Any, b: Any) -> None:
    """The same bits, except that a zero's sign is free (a point exactly on a boundary: the sign of
    such a zero follows the order of a maximum's ties, which numpy's own reductions do not fix)."""
    a, b = np.atleast_1d(np.asarray(a, dtype=np.float64)), np.atleast_1d(np.asarray(b, dtype=np.float64))
    assert a.shape == b.shape
    np.testing.assert_array_equal(a, b)
    nonzero = a != 0.0
    np.testing.assert_array_equal(a[nonzero].view(np.uint64), b[nonzero].view(np.uint64))


CASES = [(name, {}) for name in list_scenarios() if name != "random"]
CASES += [("random", {"n_humans": (2, 6)}), ("random", {"n_followers": (1, 1)}), ("random", {"n_followers": (12, 16)})]


@pytest.mark.parametrize(("scenario", "kwargs"), CASES, ids=[f"{s}{'-' + str(k) if k else ''}" for s, k in CASES])
def test_clearances_and_static_distances_match_the_references(scenario: str, kwargs: dict) -> None:
    env = SwarmEnv(scenario, **kwargs)
    rng = np.random.default_rng(11)
    env.reset(seed=5)
    static = env._state.static
    W, H = static.size
    # points all over the map, outside it, on obstacle boundaries and inside obstacles
    probes = np.vstack([rng.uniform((-1.0, -1.0), (W + 1.0, H + 1.0), (300, 2)), static.circles[:, :2],
                        *(p for p in static.polygons), *(p.mean(axis=0, keepdims=True) for p in static.polygons)])
    for block in np.array_split(probes, max(1, len(probes) // 20)):
        _same(*_both(lambda b=block: static.distance(b)))
        _same(*_both(lambda b=block: static.distance_lower_bound(b)))
        minus = rng.uniform(0.0, 0.5, len(block))
        for upper in (-np.inf, -0.3, 0.0, 0.4, 2.0, np.inf):
            _same(*_both(lambda b=block, m=minus, u=upper: static.min_distance(b, m, u)))
    for t in range(150):
        state = env._state
        for below in (0.3, 1.0, np.inf):
            _same(*_both(lambda s=state, b=below: clearance(s, below=b)))
        actions = {a: rng.uniform(-1.0, 1.0, 2).astype(np.float32) for a in env.agents}
        _, _, term, trunc, _ = env.step(actions)
        if any(term.values()) or any(trunc.values()):
            env.reset(seed=t)


def test_episode_metrics_match_the_references() -> None:
    """The proximity metrics (min separation/clearance) run on the kernels: a whole episode's result
    is the same dict both ways."""
    results = []
    for flag in (True, False):
        use_compiled_kernels(flag)
        try:
            env = SwarmEnv("random", n_humans=(3, 5))
            env.reset(seed=21)
            rng = np.random.default_rng(2)
            done = False
            while not done:
                _, _, term, trunc, _ = env.step({a: rng.uniform(-1, 1, 2).astype(np.float32) for a in env.agents})
                done = any(term.values()) or any(trunc.values())
            results.append(env.episode_metrics())
        finally:
            use_compiled_kernels(True)
    compiled, reference = (_behaviour(r) for r in results)
    assert compiled["min_clearance"] < 1.0  # the episode came near something
    assert compiled == reference
