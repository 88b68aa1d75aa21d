"""The compiled step kernels (:mod:`swarm_env.scoring.step_kernel`) against their numpy references, bit for bit.

``tests/test_step_digests.py`` pins whole episodes under the default reward; here every reward term
is switched on (and the v0 preset), the metrics run on robot and virtual leaders, and the rare paths
of the metrics kernel (no finite running minimum, more followers than the fast path takes) are
forced, each compared with the numpy code on the same states.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np
import pytest

from swarm_env.compiled import use_compiled_kernels
from swarm_env.env import SwarmEnv
from swarm_env.scenario import RewardSpec
from swarm_env.scoring.metrics import EpisodeMetrics
from swarm_env.scoring.rewards import REWARD_TERMS, compute_rewards, reward_table, touching_per_follower
from swarm_env.state import WorldState

ALL_TERMS = RewardSpec(formation=1.5, collision=5.0, contact=2.0, clearance=1.0, clearance_margin=0.4,
                       smoothness=0.3, progress=2.0, approach=0.7, approach_horizon=2.0, approach_margin=0.5)

CASES = {
    "random_bench": ("random", 5, {"n_followers": 8, "n_obstacles": 10, "n_humans": 3, "world_size": (29.0, 20.0)}),
    "robot_leader": ("random", 6, {"n_followers": 6, "n_humans": 2, "leader_kind": "robot", "max_time": 40.0}),
    "crowd": ("crowd_reactive", 4, {}),
    "paper_vo_45": ("paper_vo_45", 1, {}),
}


def _bits(a: np.ndarray) -> bytes:
    return np.ascontiguousarray(a, dtype=np.float64).tobytes()


def _episode(name: str, steps: int, seed: int = 0):
    """(state, prev_dist, action, prev_action) of each step of a noisy episode of CASES[name]."""
    scenario, reset_seed, kwargs = CASES[name]
    env = SwarmEnv(scenario, **kwargs)
    env.reset(seed=reset_seed)
    rng = np.random.default_rng(seed)
    prev_action = np.zeros((len(env.agents), 2))
    for _ in range(steps):
        prev_dist = env._prev_dist
        # Mostly forward, so followers touch each other, obstacles and humans now and then.
        act = np.clip(rng.normal([0.6, 0.0], 0.6, (len(env.agents), 2)), -1.0, 1.0)
        env.step(dict(zip(env.agents, act)))
        yield env._state, prev_dist, act, prev_action
        prev_action = act
        if not env.agents:
            return


@pytest.mark.parametrize("spec", [ALL_TERMS, RewardSpec(), RewardSpec.v0()], ids=["all_terms", "v1", "v0"])
@pytest.mark.parametrize("name", sorted(CASES))
def test_reward_table_matches_numpy(name: str, spec: RewardSpec) -> None:
    seen_terms = np.zeros(len(REWARD_TERMS), bool)
    try:
        for state, prev_dist, act, prev_act in _episode(name, 150):
            touching = touching_per_follower(state)
            out = {}
            for compiled in (True, False):
                use_compiled_kernels(compiled)
                out[compiled] = reward_table(state, spec, prev_dist, act, prev_act, touching)
                given = reward_table(state, spec, prev_dist, act, prev_act, touching, dist=out[compiled][0])
                assert all(_bits(a) == _bits(b) for a, b in zip(out[compiled], given))
            for a, b in zip(out[True], out[False]):
                assert a.shape == b.shape and _bits(a) == _bits(b)  # signed zeros included
            seen_terms |= (out[True][1] != 0).any(axis=1)
            total, terms = compute_rewards(state, spec, out[True][0], prev_dist, act, prev_act, touching)
            assert _bits(total) == _bits(out[True][2])
            assert list(terms) == list(REWARD_TERMS)
    finally:
        use_compiled_kernels(True)
    if spec == ALL_TERMS and name == "random_bench":  # the episode exercises every branch of the kernel
        contact = [f"contact_{g}" for g in ("robot", "obstacle", "human", "wall")]
        seen = dict(zip(REWARD_TERMS, seen_terms))
        assert any(seen[t] for t in contact) and all(v for t, v in seen.items() if t not in contact), seen


def _metrics_state(m: EpisodeMetrics) -> dict:
    return {"result": m.result(), "err_sum": _bits(m.err_sum), "twist": _bits(m.twist_sum), "dist": _bits(m.dist),
            "prev_pos": _bits(m.prev_pos), "lb": None if m._static_lb is None else _bits(m._static_lb),
            "sep": m.min_sep, "clear": m.min_clear, "err_max": m.err_max}


def _metrics_in_lockstep(name: str, steps: int, seed: int, before_update: Callable[..., None] | None = None) -> int:
    """Update a compiled and a numpy ``EpisodeMetrics`` with every state of an episode and compare
    them after each update (``before_update(compiled, reference)`` may tamper with both first);
    returns the number of updates."""
    compiled, reference = EpisodeMetrics(), EpisodeMetrics()
    started = False
    try:
        for state, *_ in _episode(name, steps, seed=seed):
            if not started:
                compiled.start(state)
                reference.start(state)
                started = True
                continue
            if before_update is not None:
                before_update(compiled, reference)
            use_compiled_kernels(True)
            compiled.update(state, 0.0)
            use_compiled_kernels(False)
            reference.update(state, 0.0)
            assert _metrics_state(compiled) == _metrics_state(reference)
    finally:
        use_compiled_kernels(True)
    return compiled.steps


@pytest.mark.parametrize("name", sorted(CASES))
def test_metrics_update_matches_numpy(name: str) -> None:
    assert _metrics_in_lockstep(name, 200, seed=1) > 50


@pytest.mark.parametrize("force", ["infinite_minimum", "many_followers"])
def test_metrics_kernel_defers_to_numpy_when_the_fast_path_does_not_apply(force: str, monkeypatch) -> None:
    """``min_distance``'s numpy path (status 2): an infinite running minimum, or more followers
    than its fast path takes (forced by lowering that limit to 0)."""
    import swarm_env.scoring.metrics as metrics_mod

    def forget_the_minimum(*metrics: EpisodeMetrics) -> None:
        for m in metrics:
            m.min_clear = np.inf
            m._static_lb = None

    if force == "many_followers":
        monkeypatch.setattr(metrics_mod, "_FAST_MAX_POINTS", 0)
    tamper = forget_the_minimum if force == "infinite_minimum" else None
    assert _metrics_in_lockstep("random_bench", 60, seed=2, before_update=tamper) > 30


def test_snapshot_is_the_dataclass_built_normally() -> None:
    """``World.snapshot`` fills the frozen dataclass's ``__dict__`` directly: the same object as
    ``WorldState(**fields)``, fields in order, its derived-array cache empty and its own."""
    for state, *_ in _episode("robot_leader", 5):
        fields = {f.name: getattr(state, f.name) for f in dataclasses.fields(WorldState) if f.init}
        normal = WorldState(**fields)
        assert list(state.__dict__) == list(normal.__dict__)
        assert state == normal and state._derived is not normal._derived
        with pytest.raises(dataclasses.FrozenInstanceError):
            state.time = 1.0  # type: ignore[misc]
