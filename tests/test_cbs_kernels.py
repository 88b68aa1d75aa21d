"""The CBS + RRT planner's compiled tests (swarm_env_agents.cbs_rrt.kernels) give the numpy answers."""

from __future__ import annotations

import numpy as np
import pytest

from swarm_env.compiled import use_compiled_kernels
from swarm_env.scenario_io import load_scenario
from swarm_env_agents.cbs_rrt.constraints import Constraint, ConstraintTable
from swarm_env_agents.cbs_rrt.distance_field import DistanceField


def _both(fn):
    use_compiled_kernels(True)
    try:
        a = fn()
        use_compiled_kernels(False)
        b = fn()
    finally:
        use_compiled_kernels(True)
    return a, b


def test_distance_field_clearance_matches() -> None:
    from swarm_env.env import SwarmEnv

    env = SwarmEnv("paper_cbs_switch")
    env.reset(seed=0)
    field = DistanceField.build(env._state.static, 0.05)
    rng = np.random.default_rng(0)
    W, H = env._state.static.size
    for shape in ((500,), (7, 33), (0,)):
        x = rng.uniform(-2.0, W + 2.0, shape)
        y = rng.uniform(-2.0, H + 2.0, shape)
        a, b = _both(lambda: field.clearance_xy(x, y))
        assert a.shape == b.shape == shape
        assert a.tobytes() == b.tobytes()
    with pytest.raises(IndexError), np.errstate(invalid="ignore"):  # NaN: the reference's error, no wild read
        field.clearance_xy(np.array([np.nan]), np.array([1.0]))


def _table(rng: np.random.Generator, count: int) -> ConstraintTable:
    cons = []
    for k in range(count):
        n = int(rng.integers(2, 12))
        t = np.sort(rng.uniform(0.0, 20.0, n)) + np.arange(n) * 1e-3  # strictly increasing
        cons.append(Constraint(agent=0, t=t, xy=rng.uniform(0.0, 10.0, (n, 2)), radius=float(rng.uniform(0.2, 0.6)),
                               other=k))
    return ConstraintTable(cons, 0.0, 20.0)


def test_constraint_tables_match() -> None:
    rng = np.random.default_rng(1)
    checked = blocked = 0
    for count in (1, 3, 9):
        table = _table(rng, count)
        for _ in range(20):
            x = rng.uniform(0.0, 10.0, 300)
            y = rng.uniform(0.0, 10.0, 300)
            t = rng.uniform(-1.0, 22.0, 300)
            a, b = _both(lambda: table.free(x, y, t))
            assert a.dtype == b.dtype == bool and (a == b).all()
            blocked += int((~a).sum())
            for m in range(0, 300, 15):
                t0, t1 = sorted(rng.uniform(-1.0, 22.0, 2).tolist())
                a1, b1 = _both(lambda: table.still_free(float(x[m]), float(y[m]), t0, t1))
                assert a1 == b1
                checked += 1
    assert blocked > 0 and checked > 0


@pytest.mark.slow
def test_cbs_expert_plans_the_same_with_and_without_the_kernels() -> None:
    """A whole episode through the formation switch: the same metrics and planner counters."""
    import swarm_env
    from swarm_env.harness.evaluation import run_episode
    from swarm_env.harness.leaderboard import _behaviour
    from swarm_env_agents.cbs_rrt.policy import CBSRRTExpert

    def episode() -> tuple[dict, dict]:
        env = swarm_env.parallel_env("paper_cbs_switch", max_cycles=200)
        result = run_episode(env, CBSRRTExpert(), 2)
        stats = result["policy_stats"]
        counters = {k: stats[k] for k in ("replans", "cbs_nodes_expanded", "low_level_calls", "rrt_iterations")}
        return _behaviour(result), counters

    (a, ca), (b, cb) = _both(episode)
    assert load_scenario("paper_cbs_switch").formations[1].at < 200 * 0.5  # the switch is inside the episode
    assert ca["replans"] > 5
    assert ca == cb
    assert {k: v for k, v in a.items() if k != "policy_stats"} == {k: v for k, v in b.items() if k != "policy_stats"}
