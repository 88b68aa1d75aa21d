"""The compiled velocity-obstacle search (swarm_env.control.vo_kernel) gives the numpy reference's bits.

Every field of the result (the twists, feasibility, ``n_safe``, the reported time to contact, the
escape and fast-path flags) is compared exactly: on every state the ``vo`` expert saw in whole
episodes of several scenarios (static maps with circles and polygons, robot leaders, reactive
humans), where the whole ``act()`` — the compiled pursuit (``vo_kernel.pursuit``), the one-call
search of the followers (``vo_kernel.follower_select``), the actions and the telemetry — is
compared too; on synthetic calls covering the options the experts do not use (``fast=False``, a
goal heading, the commitment term, the chord model, no map, one robot, masks, infeasible crowds);
on the safety layer's arbitrary preferred twists; and on the pursuit's corner cases. The kernels
call the C library's ``hypot``, ``sin``, ``cos`` and ``fmod`` where the reference calls numpy:
``test_the_kernels_math_is_numpys_on_this_platform`` says whether that holds here.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from swarm_env.compiled import compiled_kernels, compiled_mode, compiled_search
from swarm_env.control import vo, vo_kernel
from swarm_env.control.safety import AvoidanceParams, safe_follower_twists, shield_actions
from swarm_env.control.vo import VOBatchResult, VODiscs, VOParams, VORobots, vo_select, vo_select_batch
from swarm_env.env import SwarmEnv
from swarm_env.geometry.static_map import StaticMap
from swarm_env.scenario import CircleObstacle, PolygonObstacle, RectangleObstacle
from swarm_env.state import WorldState
from swarm_env_agents.vo_expert import VOExpert

FIELDS = ("twist", "feasible", "n_safe", "min_time_to_collision", "escaped", "fast", "preferred_safe")


def _both(call):
    """``call()`` with the reference, then compiled."""
    with compiled_mode(search=False):
        ref = call()
    return ref, call()


def _assert_same(ref: VOBatchResult, fast: VOBatchResult, where: str) -> None:
    for name in FIELDS:
        a, b = np.asarray(getattr(ref, name)), np.asarray(getattr(fast, name))
        assert a.dtype.kind == b.dtype.kind and a.shape == b.shape, f"{where}: {name} {a!r} vs {b!r}"
        assert np.array_equal(a, b), f"{where}: {name} differs: reference {a!r}, compiled {b!r}"
        assert a.tobytes() == b.tobytes(), f"{where}: {name} differs in its bits (signed zeros?)"


def _same_array(a: np.ndarray, b: np.ndarray, where: str) -> None:
    a, b = np.asarray(a), np.asarray(b)
    assert a.dtype == b.dtype and a.shape == b.shape, f"{where}: {a!r} vs {b!r}"
    assert a.tobytes() == b.tobytes(), f"{where}: reference {a!r}, compiled {b!r}"


def _act_both(ref_policy: VOExpert, policy: VOExpert, obs: dict, state: WorldState) -> tuple[dict, dict]:
    """``act()`` of two experts with the same parameters, the first on the reference path."""
    with compiled_mode(search=False):
        ref = ref_policy.act(obs, state)
    return ref, policy.act(obs, state)


@pytest.mark.parametrize(("scenario", "seed", "avoidance"), [
    ("paper_vo_0", 0, {}),  # a robot leader, humans crossing
    ("paper_vo_45", 0, {}),
    ("paper_vo_90", 0, {}),
    ("paper_cbs_switch", 0, {}),  # 8 followers, 10 obstacles (polygons), the switch, infeasible steps, escapes
    ("corridor", 0, {}),  # a wall with a door: polygons, standing robots, escapes
    ("crowd_reactive", 0, {}),  # reactive humans
    ("random", 1003, {}),
    ("random", 31, {}),  # a human walking at a boxed-in follower (the humans' longer horizon)
    ("paper_vo_90", 0, {"static_reach": 3.0}),  # static obstacles judged by path length (opt-in)
    ("paper_cbs_switch", 0, {"static_reach": 6.0}),
    # the expert before issue 12 (no preview: the compiled pursuit; no speed weight, no escape commitment)
    ("paper_cbs_switch", 0, {"preview": 0.0, "lookahead": 0.0, "w_speed": 1.0, "escape_commit": 0.0}),
])
@pytest.mark.slow
def test_expert_act_gives_the_same_bits(scenario: str, seed: int, avoidance: dict) -> None:
    # Every step of a whole episode: the preferred twists, every field of the search, the actions
    # act() returns (dtype, keys and bits) and, at the end, the telemetry.
    env = SwarmEnv(scenario)
    ref_policy, policy = VOExpert(**avoidance), VOExpert(**avoidance)
    obs, _ = env.reset(seed=seed)
    ref_policy.reset(env, seed)
    policy.reset(env, seed)
    compared = not_fast = 0
    while env.agents:
        state = env.world_state()
        where = f"{scenario} step {compared}"
        pref_ref, pref = _both(lambda: policy.preferred_twists(state))
        _same_array(pref_ref, pref, f"{where}: preferred twists")
        ref, fast = _both(lambda: safe_follower_twists(state, pref_ref, policy.avoidance))
        _assert_same(ref, fast, where)
        a_ref, action = _act_both(ref_policy, policy, obs, state)
        assert list(a_ref) == list(action), where
        for agent in a_ref:
            _same_array(a_ref[agent], action[agent], f"{where}: action of {agent}")
        compared += 1
        not_fast += not ref.fast.all()
        obs, *_ = env.step(action)
    assert compared >= 300 and not_fast >= 10  # the passes, not only the fast path, were compared
    ref_stats, stats = ref_policy.stats(), policy.stats()
    del ref_stats["decision_time_ms"], stats["decision_time_ms"]
    assert ref_stats == stats


def _followers(state: WorldState, keep: np.ndarray) -> WorldState:
    """``state`` with only the followers ``keep``."""
    return replace(state, follower_pose=state.follower_pose[keep], follower_vel=state.follower_vel[keep],
                   follower_twist=state.follower_twist[keep], follower_radius=state.follower_radius[keep],
                   slot_targets=state.slot_targets[keep])


@pytest.fixture(scope="module")
def switch_states() -> list[WorldState]:
    """Every 4th state of an episode of paper_cbs_switch driven by the expert."""
    env = SwarmEnv("paper_cbs_switch", max_cycles=240)
    policy = VOExpert()
    obs, _ = env.reset(seed=0)
    policy.reset(env, 0)
    states = []
    while env.agents:
        state = env.world_state()
        if state.step % 4 == 0:
            states.append(state)
        obs, *_ = env.step(policy.act(obs, state))
    return states


def test_the_safety_layer_gives_the_same_bits(switch_states: list[WorldState]) -> None:
    # Arbitrary wanted actions (a learner's): beyond the limits, exactly on them, zeros of both signs
    # (the clipping to the limits keeps numpy's rules for ties), with and without reciprocity and
    # the commitment term, and for subsets of the team down to one follower (the one-robot trajectory
    # formula) and none.
    rng = np.random.default_rng(3)
    variants = [AvoidanceParams(), AvoidanceParams(reciprocal=False, w_current=0.3, side_bias=0.1),
                AvoidanceParams(v_min=-0.2, margin=0.0, allow_still_overlap=False, escape=False, horizon_static=1.5),
                AvoidanceParams(fast=False, n_v=4, n_w=7, tau=0.5, n_arc=3),
                AvoidanceParams(cost="velocity", recip_gap=0.2), AvoidanceParams(move_first=True, recip_gap=0.2),
                AvoidanceParams(cost="velocity", w_current=0.3, tau=0.5, v_min=-0.2, recip_gap=0.5, move_first=True),
                AvoidanceParams(move_first=True, recip_gap=0.2, static_reach=6.0),
                AvoidanceParams(static_reach=2.0, horizon_static=2.0, v_min=-0.2, tau=0.5),
                AvoidanceParams(w_speed=3.0, escape_commit=1.0, move_first=True, recip_gap=0.2, tau=0.7),
                AvoidanceParams(move_first=True, recip_gap=0.2, robot_margin=0.065)]
    sizes = set()
    for k, full in enumerate(switch_states):
        n_all = full.n_followers
        keep = np.sort(rng.choice(n_all, size=int(rng.integers(0, n_all + 1)), replace=False)) if k % 3 else np.arange(n_all)
        state = _followers(full, keep)
        n = state.n_followers
        sizes.add(n)
        wanted = rng.uniform(-1.3, 1.3, (n, 2))
        special = np.array([0.0, -0.0, 1.0, -1.0, 1.3])
        pick = rng.random((n, 2)) < 0.3
        wanted[pick] = rng.choice(special, size=int(pick.sum()))
        params = variants[k % len(variants)]
        ref, fast = _both(lambda: shield_actions(state, wanted, params))
        for name in ("actions", "correction", "intervened", "feasible"):
            _same_array(getattr(ref, name), getattr(fast, name), f"state {k} ({n} followers): {name}")
        robots = state.scenario.robots
        twists = wanted * np.array([robots.max_speed, robots.max_turn_rate])
        ref_r, fast_r = _both(lambda: safe_follower_twists(state, twists, params))
        _assert_same(ref_r, fast_r, f"state {k} ({n} followers)")
    assert {0, 1, 2, 8} <= sizes


def test_the_pursuit_gives_the_same_bits(switch_states: list[WorldState]) -> None:
    # The compiled pursuit against the expert's numpy code on many followers at once: targets all
    # around (ahead, behind, exactly behind, on the robot, within the arrival radius, far), with and
    # without feed-forward, the full turn, and zero limits.
    rng = np.random.default_rng(5)
    base = switch_states[len(switch_states) // 2]
    m = 20000
    pose = np.column_stack([rng.uniform(0.0, 20.0, m), rng.uniform(0.0, 20.0, m), rng.uniform(-math.pi, math.pi, m)])
    scale = np.where(np.arange(m)[:, None] < 2000, 10.0 ** rng.uniform(-10, 0, (m, 1)), 10.0 ** rng.uniform(-1, 1.5, (m, 1)))
    offset = rng.normal(0.0, 1.0, (m, 2)) * scale  # (the first 2000 near or within the arrival radius)
    slots = pose[:, :2] + offset
    slots[:200] = pose[:200, :2]  # on the robot
    back = np.column_stack([np.cos(pose[200:400, 2] + math.pi), np.sin(pose[200:400, 2] + math.pi)])
    slots[200:400] = pose[200:400, :2] + back * rng.uniform(0.1, 3.0, (200, 1))  # (nearly) exactly behind
    pose[400:600, 2] = np.arctan2(offset[400:600, 1], offset[400:600, 0]) + np.array([0.5, -0.5]).repeat(100) * math.pi
    for a in (pose, slots):
        a.flags.writeable = False
    rng_state = replace(base, follower_pose=pose, slot_targets=slots, follower_vel=np.zeros((m, 2)),
                        follower_twist=np.zeros((m, 2)), follower_radius=np.full(m, 0.25))
    still = replace(rng_state, leader_vel=np.zeros(2), leader_twist=np.zeros(2))  # feed-forward adds exactly 0
    robots = base.scenario.robots
    limits = replace(rng_state, scenario=replace(base.scenario, robots=replace(robots, max_turn_rate=0.0, max_speed=0.0)))
    for name, state in (("moving leader", rng_state), ("leader at rest", still), ("zero limits", limits)):
        for kw in ({}, {"feed_forward": False}, {"full_turn": False}, {"arrive_radius": 0.5, "time_gap": 0.2},
                   {"feed_forward": False, "full_turn": False, "arrive_radius": 0.0}, {"lookahead": 0.0}):
            policy = VOExpert(**{"preview": 0.0, **kw})  # (the compiled pursuit is the path without preview)
            ref, fast = _both(lambda: policy.preferred_twists(state))
            _same_array(ref, fast, f"pursuit, {name}, {kw}")
            if name == "leader at rest" and kw == {"lookahead": 0.0}:  # (the plain law: the cases it covers)
                assert (ref[:200] == 0.0).all()  # on the robot
                turning = (ref[:, 0] == 0.0) & (np.abs(ref[:, 1]) == robots.max_turn_rate)
                assert turning[200:400].all() and turning.sum() > m // 5  # behind: full turn in place
                assert ((ref[:, 0] > 0.0) & (np.abs(ref[:, 1]) < robots.max_turn_rate)).sum() > m // 5


def test_the_preferred_trajectories_give_the_same_bits() -> None:
    # The preferred twists' trajectories the kernel builds: numpy's formula (np.sinc) for several
    # robots, the plain-Python one (sin(h) / h) for one, as the reference.
    rng = np.random.default_rng(11)
    m = 100000
    v = rng.uniform(-0.3, 1.0, m)
    w = np.where(rng.random(m) < 0.1, 0.0, rng.uniform(-2.0, 2.0, m)) * 10.0 ** rng.uniform(-13, 0, m)
    theta = rng.uniform(-math.pi, math.pi, m)
    for tau, horizon, n_arc in ((1.0, 3.0, 2), (0.5, 3.0, 3), (2.0, 1.5, 1), (1.0, 1.0, 2)):
        _same_array(vo._world_trajectories(v, w, theta, tau, horizon, n_arc),
                    vo_kernel._preferred_trajectories(v, w, theta, tau, horizon, n_arc), f"batch {tau, horizon, n_arc}")
        for k in range(0, m, 97):
            row = vo._trajectory_row(float(v[k]), float(w[k]), tau, horizon, n_arc, float(theta[k]))[None]
            _same_array(row, vo_kernel._preferred_trajectories(v[k:k + 1], w[k:k + 1], theta[k:k + 1], tau, horizon, n_arc),
                        f"one robot {k} {tau, horizon, n_arc}")


def test_the_kernels_math_is_numpys_on_this_platform() -> None:
    # The kernels call the C library's hypot, sin, cos and floating-point modulo where the reference
    # calls numpy's float64 loops; on this platform they agree bit for bit (1M samples each, over the
    # ranges the search meets and beyond). numpy's arctan2 (a SIMD implementation here) does NOT agree
    # with the C library's atan2 for a few per cent of inputs, which is why vo_kernel.pursuit takes
    # numpy's bearing as an input. If this test fails, the kernels' answers may differ from the
    # reference's in a last bit on this platform: run the search with compiled_mode(search=False).
    numba = pytest.importorskip("numba")

    @numba.njit
    def libm(x, y, a):
        out = np.empty((5, x.shape[0]))
        for i in range(x.shape[0]):
            out[0, i] = math.hypot(x[i], y[i])
            out[1, i] = math.sin(a[i])
            out[2, i] = math.cos(a[i])
            out[3, i] = (a[i] + math.pi) % (2.0 * math.pi) - math.pi
            z = math.pi * (a[i] / math.pi)
            z = z if z != 0.0 else np.finfo(np.float64).eps
            out[4, i] = math.sin(z) / z
        return out

    rng = np.random.default_rng(0)
    n = 1_000_000
    x = rng.normal(0.0, 1.0, n) * 10.0 ** rng.uniform(-8, 3, n)
    y = rng.normal(0.0, 1.0, n) * 10.0 ** rng.uniform(-8, 3, n)
    a = rng.normal(0.0, 1.0, n) * 10.0 ** rng.uniform(-12, 2, n)
    a[:1000] = 0.0
    got = libm(x, y, a)
    for k, (name, want) in enumerate([("hypot", np.hypot(x, y)), ("sin", np.sin(a)), ("cos", np.cos(a)),
                                      ("wrap", np.mod(a + math.pi, 2.0 * math.pi) - math.pi),
                                      ("sinc", np.sinc(a / math.pi))]):
        differ = np.count_nonzero(got[k].view(np.int64) != want.view(np.int64))
        assert differ == 0, f"the C library's {name} differs from numpy's on {differ} of {n} samples"


@pytest.fixture(scope="module")
def clutter() -> StaticMap:
    return StaticMap.from_obstacles(
        (12.0, 9.0),
        [CircleObstacle(center=(4.0, 4.5), radius=0.6), RectangleObstacle(center=(7.0, 3.0), size=(1.0, 2.0), angle=30.0),
         PolygonObstacle(points=((8.0, 6.0), (9.5, 6.2), (8.8, 7.5))), CircleObstacle(center=(2.0, 7.0), radius=0.4)],
    )


def test_synthetic_calls_give_the_same_bits(clutter: StaticMap) -> None:
    rng = np.random.default_rng(7)
    for trial in range(150):
        n = int(rng.integers(1, 7))
        n_d = int(rng.integers(0, 6))
        poses = np.column_stack([rng.uniform(1.0, 11.0, n), rng.uniform(1.0, 8.0, n), rng.uniform(-3.2, 3.2, n)])
        # discs: the robots themselves (masked out of their own lists) and some others, some moving fast
        others = np.column_stack([rng.uniform(0.5, 11.5, n_d), rng.uniform(0.5, 8.5, n_d), rng.uniform(0.2, 0.5, n_d)])
        discs = np.vstack([np.column_stack([poses[:, :2], np.full(n, 0.25)]), others])
        vel = rng.normal(0.0, 0.5, (n + n_d, 2))
        mask = np.ones((n, n + n_d), dtype=bool)
        mask[np.arange(n), np.arange(n)] = False
        preferred = np.column_stack([rng.uniform(-0.2, 0.8, n), rng.uniform(-1.5, 1.5, n)])
        params = VOParams(
            horizon=float(rng.choice([1.5, 3.0])),
            horizon_static=None if rng.random() < 0.5 else 2.0,
            margin=float(rng.choice([0.0, 0.05, 0.2])),
            n_v=int(rng.integers(2, 8)), n_w=int(rng.integers(3, 12)),
            tau=float(rng.choice([0.5, 1.0])),
            v_min=float(rng.choice([0.0, -0.2])),
            side_bias=float(rng.choice([0.0, 0.1])),
            model=str(rng.choice(["arc", "chord"])),
            escape=bool(rng.random() < 0.8),
            allow_still_overlap=bool(rng.random() < 0.5),
            fast=bool(rng.random() < 0.7),
            w_current=float(rng.choice([0.0, 0.3])),
            cost=str(rng.choice(["twist", "velocity"])),
            recip_gap=float(rng.choice([0.0, 0.3])),
            move_first=bool(rng.random() < 0.5),
            w_speed=float(rng.choice([1.0, 3.0])),
            escape_commit=float(rng.choice([0.0, 0.5, 100.0])),
        )
        if params.model == "arc" and rng.random() < 0.5:
            params = replace(params, static_reach=float(rng.choice([1.0, 2.0, 6.0])))
        kwargs = dict(
            disc_mask=mask,
            goal_heading=rng.uniform(-3.0, 3.0, n) if rng.random() < 0.3 else None,
            velocity=vel[:n] if rng.random() < 0.7 else None,
            reciprocal=rng.random(n + n_d) < 0.5 if rng.random() < 0.5 else bool(rng.random() < 0.5),
            current=(preferred + rng.normal(0.0, 0.2, (n, 2)) if rng.random() < 0.5 else
                     np.column_stack([np.zeros(n), rng.choice([-0.8, 0.8], n)])) if rng.random() < 0.7 else None,
            # per-disc horizons (the expert's longer one for humans), some past the search's own
            disc_horizon=rng.choice([1.0, params.horizon, 3.5], n + n_d) if rng.random() < 0.4 else None,
        )
        static = None if rng.random() < 0.2 else clutter

        def call():
            robots = VORobots(poses, 0.25, preferred, 0.65, 1.0, velocity=kwargs["velocity"], current=kwargs["current"],
                              goal_heading=kwargs["goal_heading"])
            disc_set = VODiscs(discs, vel, kwargs["disc_mask"], kwargs["reciprocal"], kwargs["disc_horizon"])
            return vo_select_batch(robots, disc_set, static, params)

        ref, fast = _both(call)
        _assert_same(ref, fast, f"trial {trial}")


def test_single_robot_and_a_crowd_give_the_same_bits(clutter: StaticMap) -> None:
    # vo_select (the robot leader's call), boxed in by discs so that nothing is safe: the least dangerous
    # candidate and the escape turn.
    ring = np.array([[6.0 + 0.7 * np.cos(a), 4.5 + 0.7 * np.sin(a), 0.3] for a in np.linspace(0, 2 * np.pi, 7)[:-1]])
    towards = -(ring[:, :2] - [6.0, 4.5]) * 0.3
    for escape in (True, False):
        def call():
            r = vo_select(np.array([6.0, 4.5, 0.3]), 0.25, np.array([0.6, 0.2]), ring, towards, clutter, 0.65, 1.0,
                          escape=escape)
            return VOBatchResult(r.twist[None], np.array([r.feasible]), np.array([r.n_safe]),
                                 np.array([r.min_time_to_collision]), np.zeros(1, bool), np.zeros(1, bool),
                                 np.zeros(1, bool))

        ref, fast = _both(call)
        _assert_same(ref, fast, f"boxed in, escape={escape}")
        assert not ref.feasible[0]


def test_the_switch_is_honoured_and_restored() -> None:
    assert compiled_search() and compiled_kernels()
    with pytest.raises(RuntimeError), compiled_mode(search=False):
        assert not compiled_search() and compiled_kernels()
        raise RuntimeError
    assert compiled_search() and compiled_kernels()
    with compiled_mode(kernels=False, search=False):
        assert not compiled_search() and not compiled_kernels()
    assert compiled_search() and compiled_kernels()


def test_an_escape_with_reverse_candidates_only_turns_in_place() -> None:
    """With ``v_min < 0`` the candidate grid has reversing twists; the escape rule turns in place
    (``v = 0``: the only twists its probes test), never returns a reversing twist it did not
    probe, and both search paths agree. On random world 5 the rule fires once (before the fix it
    returned a reversing twist at step 192 of world 27)."""
    env = SwarmEnv("random")
    policy = VOExpert(v_min=-0.325, n_v=9)
    obs, _ = env.reset(seed=5)
    policy.reset(env, 5)
    escapes = reversing = 0
    while env.agents:
        state = env.world_state()
        pref = policy.preferred_twists(state)
        ref, fast = _both(lambda: safe_follower_twists(state, pref, policy.avoidance))
        _assert_same(ref, fast, f"step {state.step}")
        escapes += int(ref.escaped.sum())
        assert np.all(ref.twist[ref.escaped, 0] == 0.0), f"step {state.step}: an escape reverses"
        reversing += int((ref.twist[:, 0] < 0.0).sum())
        obs, *_ = env.step(policy.act(obs, state))
    assert escapes >= 1 and reversing >= 1  # the rule fired, and reversing twists were chosen elsewhere
