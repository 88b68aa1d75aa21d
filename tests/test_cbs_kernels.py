"""The CBS + RRT planner's compiled tests (swarm_env_agents.cbs_rrt.kernels) give the numpy answers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from swarm_env.compiled import use_compiled_kernels
from swarm_env.scenarios.loader import load_scenario
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


def _bits(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64).view(np.int64)


def _interp_cases(rng: np.random.Generator, trials: int) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """``(x, xp, fp)`` triples: strictly increasing ``xp`` of 1..40 samples, values of several
    scales, query points inside and outside, on every breakpoint and one ulp either side, NaN."""
    out = []
    for _ in range(trials):
        xp = np.unique(rng.uniform(-5.0, 250.0, int(rng.integers(1, 40))))
        fp = rng.normal(0.0, 10.0, len(xp)) * rng.choice([1e-3, 1.0, 1e3])
        x = np.concatenate([rng.uniform(xp[0] - 2.0, xp[-1] + 2.0, 400), xp, np.nextafter(xp, np.inf),
                            np.nextafter(xp, -np.inf), [np.nan]])
        out.append((x, xp, fp))
    return out


@pytest.mark.slow
def test_scalar_and_compiled_interpolation_match_numpy_on_a_million_points() -> None:
    """``interp_scalar`` (plain Python) and ``kernels.interp_xy`` give ``np.interp``'s bits."""
    from swarm_env_agents.cbs_rrt import kernels
    from swarm_env_agents.cbs_rrt.timed_path import interp_scalar

    rng = np.random.default_rng(5)
    total = 0
    for x, xp, fp in _interp_cases(rng, 2200):
        ref = np.interp(x, xp, fp)
        xl, fl = xp.tolist(), fp.tolist()
        got = np.array([interp_scalar(v, xl, fl) for v in x.tolist()])
        assert (_bits(got) == _bits(ref)).all()
        fp2 = np.column_stack([fp, -fp, fp])  # (K, 3) like a path's poses
        got2 = kernels.interp_xy(x, xp, fp2)
        assert (_bits(got2[:, 0]) == _bits(ref)).all() and (_bits(got2[:, 1]) == _bits(np.interp(x, xp, -fp))).all()
        total += len(x)
    assert total >= 1_000_000


def test_compiled_libm_calls_match_numpy_on_millions_of_inputs() -> None:
    """The kernels call ``math.cos``/``math.sin``/``math.hypot`` and Python's float ``%`` where the numpy
    references call ``np.cos``/``np.sin``/``np.hypot``/``np.remainder``: the same bits (``np.arctan2`` is
    not among them: it differs)."""
    import math

    import numba

    @numba.njit(cache=False)
    def libm(a: np.ndarray, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        c = np.empty(len(a))
        s = np.empty(len(a))
        h = np.empty(len(a))
        r = np.empty(len(a))
        for i in range(len(a)):
            c[i] = math.cos(a[i])
            s[i] = math.sin(a[i])
            h[i] = math.hypot(x[i], y[i])
            r[i] = a[i] % (2.0 * math.pi)
        return c, s, h, r

    rng = np.random.default_rng(9)
    # Headings (not wrapped along a path: they wander), coordinate differences of points in a world,
    # and some tiny and huge values.
    a = np.concatenate([rng.uniform(-np.pi, np.pi, 600_000), rng.uniform(-60.0, 60.0, 400_000),
                        rng.normal(0.0, 1e-3, 50_000), rng.uniform(-1e4, 1e4, 50_000)])
    x = np.concatenate([rng.uniform(-60.0, 60.0, 1_000_000), rng.normal(0.0, 1e-3, 100_000)])
    y = rng.permutation(np.concatenate([rng.uniform(-60.0, 60.0, 1_000_000), rng.normal(0.0, 1e-3, 100_000)]))
    a = np.concatenate([a, np.arange(-20, 21) * 2.0 * np.pi, [0.0, -0.0, np.pi, -np.pi]])  # exact multiples
    x, y = np.resize(x, len(a)), np.resize(y, len(a))
    c, s, h, r = libm(a, x, y)
    assert (_bits(r) == _bits(a % (2.0 * np.pi))).all()
    assert (_bits(c) == _bits(np.cos(a))).all()
    assert (_bits(s) == _bits(np.sin(a))).all()
    assert (_bits(h) == _bits(np.hypot(x, y))).all()


def _compare_paths(a, b) -> None:  # noqa: ANN001 - TimedPath | None
    assert (a is None) == (b is None)
    if a is None:
        return
    for name in ("t", "pose", "kind", "nodes", "node_prim"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes(), name
    assert (a.reached, math.isnan(a.goal_time) or a.goal_time) == (b.reached, math.isnan(b.goal_time) or b.goal_time)
    assert a.vmax == b.vmax


@pytest.mark.slow
def test_rrt_plans_and_repairs_match_the_numpy_reference() -> None:
    """Many RRT calls on the paper's map (moving goals, moving constraints, starts inside the buffer
    zone) and repairs of their paths: the compiled planner returns the numpy planner's trees and
    paths bit for bit, and the same single- and many-time positions."""
    from swarm_env.geometry.static_map import StaticMap
    from swarm_env_agents.cbs_rrt.distance_field import distance_field
    from swarm_env_agents.cbs_rrt.primitives import MotionPrimitives
    from swarm_env_agents.cbs_rrt.rrt import GoalSpec, PrimitiveRRT, RRTConfig

    scn = load_scenario("paper_cbs_switch")
    static = StaticMap.from_obstacles(scn.world.size, scn.obstacles)
    field = distance_field(static, 0.05)
    prims = MotionPrimitives.for_robot(0.5, 1.0, spin_deg=(45.0, -45.0, 90.0, -90.0))
    rrt = PrimitiveRRT(prims, field, buffer=0.4, config=RRTConfig(max_iterations=250), floor=0.3)
    W, H = static.size
    rng = np.random.default_rng(11)
    plans = reached = relaxed = repaired = 0
    while plans < 40:
        start = np.array([*rng.uniform((1.0, 1.0), (W - 1.0, H - 1.0)), rng.uniform(-4.0, 4.0)])
        clear = float(field.clearance(start[:2]))
        if clear < 0.3 or (plans % 4 == 0) != (clear < 0.4):  # every fourth start inside the buffer zone
            continue
        relaxed += int(clear < 0.4)
        t0 = float(rng.uniform(0.0, 50.0))
        t = t0 + np.arange(121) * 0.25
        g0 = start[:2] + rng.uniform(-6.0, 6.0, 2)
        vel = rng.uniform(-0.4, 0.4, 2) * rng.choice([0.0, 1.0])
        goal = GoalSpec(t, g0 + (t - t0)[:, None] * vel, np.full(len(t), math.atan2(vel[1], vel[0])),
                        int(rng.integers(60, 121)))
        cons = []
        for k in range(int(rng.integers(0, 4))):
            ts = np.sort(rng.uniform(t0, t[-1], 6)) + np.arange(6) * 1e-3
            mid = (start[:2] + g0) / 2 + rng.uniform(-2.0, 2.0, 2)
            cons.append(Constraint(0, ts, mid + rng.uniform(-1.5, 1.5, (6, 2)), float(rng.uniform(0.4, 0.8)), k))
        table = ConstraintTable(cons, t0, float(t[-1]))
        seed = int(rng.integers(1 << 30))

        def plan(rrt=rrt, start=start, t0=t0, goal=goal, table=table, seed=seed):  # noqa: ANN001, ANN202
            res = rrt.plan(start, t0, goal, table, np.random.default_rng(seed), keep_tree=True)
            return res, (rrt._goal.at(t - 0.1), res.path.position_at(t[::7] + 0.05) if res.path else None,
                         [res.path.position_at(float(v)) for v in t[::13]] if res.path else None)

        (a, extra_a), (b, extra_b) = _both(plan)
        assert (a.reached, a.iterations, a.nodes, a.smoothed) == (b.reached, b.iterations, b.nodes, b.smoothed)
        assert a.tree_xy.tobytes() == b.tree_xy.tobytes() and a.tree_parent.tobytes() == b.tree_parent.tobytes()
        _compare_paths(a.path, b.path)
        assert _bits(extra_a[0]).tobytes() == _bits(extra_b[0]).tobytes()
        if a.path is not None:
            assert extra_a[1].tobytes() == extra_b[1].tobytes()
            assert np.array(extra_a[2]).tobytes() == np.array(extra_b[2]).tobytes()
        plans += 1
        reached += int(a.reached)
        if a.path is not None and a.reached:
            # A robot crossing this path: repair it by waiting.
            mid_t = float(a.path.t[len(a.path.t) // 3])
            blocker = Constraint.at_point(0, a.path.position_at(mid_t), mid_t - 1.0, mid_t + 1.0, 0.5)
            table2 = ConstraintTable([*cons, blocker], t0, float(t[-1]))
            fa, fb = _both(lambda table2=table2, path=a.path, goal=goal: rrt.repair(path, goal, table2))
            _compare_paths(fa, fb)
            repaired += int(fa is not None and fa is not a.path)
    assert reached >= 10 and repaired >= 3 and relaxed >= 1


def _fingerprint(scenario: str, seed: int, **env_kwargs: object) -> dict:
    """One whole episode of the expert, reduced to what must not change when the planner gets
    faster: every planner counter of ``policy_stats`` (timings left out), a SHA-256 of every
    action taken (float32 bytes, agents in order, step by step) and a SHA-256 of every plan
    made (each replan's paths: times, poses, kinds, nodes, primitives, goal times)."""
    import hashlib

    import swarm_env
    from swarm_env.harness.episode import run_episode
    from swarm_env_agents.cbs_rrt.policy import CBSRRTExpert

    env = swarm_env.parallel_env(scenario, **env_kwargs)
    # Without the planned hold, CBS keeps planning after paper_cbs_switch's formations are reached:
    # more of the planner's kernels are exercised (the hold has its own tests, tests/test_cbs_hold_plan.py).
    policy = CBSRRTExpert(hold_plan=False)
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
            "evade_steps": 0,
            "reverse_steps": 0,
            "hold_steps": 0,
            "hold_releases": 0,
            "hold_plans": 0,
            "hold_plan_s": 0.0,
            "hold_plan_cpu_s": 0.0,
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
            "evade_steps": 26,
            "reverse_steps": 0,  # humans near, never boxed in: the same plans and actions as before the back-off
            "hold_steps": 0,
            "hold_releases": 0,
            "hold_plans": 0,
            "hold_plan_s": 0.0,
            "hold_plan_cpu_s": 0.0,
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
    from swarm_env.harness.episode import run_episode
    from swarm_env.harness.leaderboard import _behaviour
    from swarm_env_agents.cbs_rrt.policy import CBSRRTExpert

    def episode() -> tuple[dict, dict]:
        env = swarm_env.parallel_env("paper_cbs_switch", max_cycles=200)
        result = run_episode(env, CBSRRTExpert(hold_plan=False), 2)  # CBS plans all the way (see _fingerprint)
        stats = result["policy_stats"]
        counters = {k: stats[k] for k in ("replans", "cbs_nodes_expanded", "low_level_calls", "rrt_iterations")}
        return _behaviour(result), counters

    (a, ca), (b, cb) = _both(episode)
    assert load_scenario("paper_cbs_switch").formations[1].at < 200 * 0.5  # the switch is inside the episode
    assert ca["replans"] > 5
    assert ca == cb
    assert {k: v for k, v in a.items() if k != "policy_stats"} == {k: v for k, v in b.items() if k != "policy_stats"}
