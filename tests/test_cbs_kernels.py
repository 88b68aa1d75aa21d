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


def _fingerprint(scenario: str, seed: int, **env_kwargs: object) -> dict:
    """One whole episode of the expert, reduced to what must not change when the planner gets
    faster: every planner counter of ``policy_stats`` (timings left out), a SHA-256 of every
    action taken (float32 bytes, agents in order, step by step) and a SHA-256 of every plan
    made (each replan's paths: times, poses, kinds, nodes, primitives, goal times)."""
    import hashlib

    import swarm_env
    from swarm_env.harness.evaluation import run_episode
    from swarm_env_agents.cbs_rrt.policy import CBSRRTExpert

    env = swarm_env.parallel_env(scenario, **env_kwargs)
    policy = CBSRRTExpert()
    actions = hashlib.sha256()
    plans = hashlib.sha256()
    seen: list[object] = [None]
    steps = [0]

    def on_step(acts: dict | None) -> None:
        if acts is None:
            return
        steps[0] += 1
        for agent in sorted(acts):
            actions.update(agent.encode())
            actions.update(np.asarray(acts[agent], dtype=np.float32).tobytes())
        if policy.last is not seen[0]:  # a replan happened in this step's act()
            seen[0] = policy.last
            plans.update(np.float64(policy.last.time).tobytes())
            for path in policy.last.result.paths:
                for arr in (path.t, path.pose, path.kind, path.nodes, path.node_prim):
                    plans.update(arr.tobytes())
                plans.update(np.float64(path.goal_time).tobytes() + bytes([path.reached]))

    result = run_episode(env, policy, seed, on_step=on_step)
    stats = {k: v for k, v in result["policy_stats"].items() if k not in ("planning_time_ms", "planning_cpu_ms")}
    return {"stats": stats, "steps": steps[0], "actions": actions.hexdigest(), "plans": plans.hexdigest()}


# Recorded from the planner before its speed-ups (commit "plan-identity test"): a faster planner must
# make the same plans bit for bit, so the same actions. (Floating point: x86-64 Linux, numpy 2.4; the
# env's own determinism tests pin the rest.) Regenerate only for an intended change of behaviour:
#   python -c "import sys; sys.path.insert(0, 'tests'); import test_cbs_kernels as t; print(t._fingerprint(...))"
RECORDED: dict[str, dict] = {
    "paper_cbs_switch": {
        "stats": {
            "replans": 55,
            "replan_reasons": {"initial": 1, "switch": 1, "goal_jump": 25, "horizon": 1, "rolling": 8, "deviation": 17,
                               "goal_moved": 0, "retry": 6},
            "cbs_nodes_expanded": 170,
            "cbs_nodes_expanded_max": 16,
            "conflicts_resolved": 105,
            "low_level_calls": 721,
            "repairs": 101,
            "rrt_iterations": 31635,
            "fallbacks": {"stationary": 0, "dropped": 11, "partial": 2, "unsolved": 1},
            "shield_stops": 6,
            "tracking_gap_m": {"mean": 0.019619061119383732, "p95": 0.0646327747702831, "max": 0.1927848984841682},
        },
        "steps": 406,
        "actions": "1cee083db35cc7262196e7ba7bbd05eb44e98a015b8a369f6a21cd9346a00e77",
        "plans": "95bc46eaa55dabe310159ce84922703141801768400ab9b7547291459be3675f",
    },
    "random": {
        "stats": {
            "replans": 20,
            "replan_reasons": {"initial": 1, "switch": 1, "goal_jump": 5, "horizon": 0, "rolling": 0, "deviation": 9,
                               "goal_moved": 2, "retry": 3},
            "cbs_nodes_expanded": 53,
            "cbs_nodes_expanded_max": 10,
            "conflicts_resolved": 37,
            "low_level_calls": 276,
            "repairs": 28,
            "rrt_iterations": 17491,
            "fallbacks": {"stationary": 0, "dropped": 11, "partial": 17, "unsolved": 0},
            "shield_stops": 0,
            "tracking_gap_m": {"mean": 0.0275039411797639, "p95": 0.12418267722931209, "max": 0.1938657685414053},
        },
        "steps": 291,
        "actions": "a652635905dde854526e87c70bd78e779651165a36b1abb0a9a5d6c1ed5ec700",
        "plans": "4a90455918b9039c7549d40c24253b360e4703b5ecf84ca1534e594399b9d650",
    },
}

EPISODES = {
    "paper_cbs_switch": ("paper_cbs_switch", 0, {}),
    "random": ("random", 3, {"n_followers": 6, "n_humans": 2, "n_switches": 1, "leader_kind": "robot",
                             "max_time": 30.0}),
}


@pytest.mark.slow
@pytest.mark.parametrize("compiled", [True, False], ids=["kernels", "numpy"])
@pytest.mark.parametrize("name", sorted(EPISODES))
def test_cbs_expert_makes_the_recorded_plans(name: str, compiled: bool) -> None:
    """Whole episodes (``paper_cbs_switch`` through its formation switch, and a short random one with
    humans, a robot leader and a switch): the planner's counters and the digests of its plans and
    actions are the recorded ones, with the compiled kernels and with their numpy references."""
    scenario, seed, kwargs = EPISODES[name]
    use_compiled_kernels(compiled)
    try:
        got = _fingerprint(scenario, seed, **kwargs)
    finally:
        use_compiled_kernels(True)
    want = RECORDED[name]
    assert got["stats"]["replans"] > 5
    assert got["stats"] == want["stats"]
    assert (got["steps"], got["plans"], got["actions"]) == (want["steps"], want["plans"], want["actions"])


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
