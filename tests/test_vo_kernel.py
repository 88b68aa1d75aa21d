"""The compiled velocity-obstacle search (swarm_env.vo_kernel) gives the numpy reference's bits.

Every field of the result (the twists, feasibility, ``n_safe``, the reported time to contact, the
escape and fast-path flags) is compared exactly: on every state the ``vo`` expert saw in episodes
of several scenarios (static maps with circles and polygons, robot leaders, reactive humans), and
on synthetic calls covering the options the experts do not use (``fast=False``, a goal heading,
the commitment term, the chord model, no map, one robot, masks, infeasible crowds).
"""

from __future__ import annotations

import numpy as np
import pytest

from swarm_env import guidance
from swarm_env.env import SwarmEnv
from swarm_env.geometry import StaticMap
from swarm_env.guidance import VOBatchResult, VOParams, vo_select, vo_select_batch
from swarm_env.safety import safe_follower_twists
from swarm_env.scenario import CircleObstacle, PolygonObstacle, RectangleObstacle
from swarm_env_agents.vo_expert import VOExpert

FIELDS = ("twist", "feasible", "n_safe", "min_time_to_collision", "escaped", "fast", "preferred_safe")


def _both(call):
    """``call()`` with the reference, then compiled; the compiled search is restored whatever happens."""
    try:
        guidance.use_compiled_search(False)
        ref = call()
        guidance.use_compiled_search(True)
        return ref, call()
    finally:
        guidance.use_compiled_search(True)


def _assert_same(ref: VOBatchResult, fast: VOBatchResult, where: str) -> None:
    for name in FIELDS:
        a, b = np.asarray(getattr(ref, name)), np.asarray(getattr(fast, name))
        assert a.dtype.kind == b.dtype.kind and a.shape == b.shape, f"{where}: {name} {a!r} vs {b!r}"
        assert np.array_equal(a, b), f"{where}: {name} differs: reference {a!r}, compiled {b!r}"
        assert a.tobytes() == b.tobytes(), f"{where}: {name} differs in its bits (signed zeros?)"


@pytest.mark.parametrize(("scenario", "seed", "cycles"), [
    ("paper_cbs_switch", 0, 160),  # 8 followers, 10 obstacles (polygons), the switch
    ("paper_vo_45", 0, None),  # a robot leader, humans crossing
    ("crowd_reactive", 0, 200),  # reactive humans
    ("corridor", 0, 250),  # a wall with a door: polygons, standing robots, escapes
    ("random", 1003, 200),
])
def test_expert_states_give_the_same_bits(scenario: str, seed: int, cycles: int | None) -> None:
    env = SwarmEnv(scenario, max_cycles=cycles)
    policy = VOExpert()
    obs, _ = env.reset(seed=seed)
    policy.reset(env, seed)
    compared = not_fast = 0
    while env.agents:
        state = env.world_state()
        pref = policy.preferred_twists(state)
        ref, fast = _both(lambda: safe_follower_twists(state, pref, policy.avoidance))
        _assert_same(ref, fast, f"{scenario} step {compared}")
        compared += 1
        not_fast += not ref.fast.all()
        obs, *_ = env.step(policy.act(obs, state))
    assert compared >= 100 and not_fast >= 10  # the passes, not only the fast path, were compared


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
        )
        kwargs = dict(
            disc_mask=mask,
            goal_heading=rng.uniform(-3.0, 3.0, n) if rng.random() < 0.3 else None,
            velocity=vel[:n] if rng.random() < 0.7 else None,
            reciprocal=rng.random(n + n_d) < 0.5 if rng.random() < 0.5 else bool(rng.random() < 0.5),
            current=preferred + rng.normal(0.0, 0.2, (n, 2)) if rng.random() < 0.5 else None,
        )
        static = None if rng.random() < 0.2 else clutter

        def call():
            return vo_select_batch(poses, 0.25, preferred, discs, vel, static, 0.65, 1.0, params, **kwargs)

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


def test_the_switch_is_honoured() -> None:
    assert guidance._COMPILED
    guidance.use_compiled_search(False)
    try:
        assert not guidance._COMPILED
    finally:
        guidance.use_compiled_search(True)
