"""The batched stages (swarm_env.vector.batch_step / swarm_env.vector.batch_kernel) against the per-world numpy references.

``tests/test_vector.py`` compares the engine with ``SwarmEnv``s running the same compiled kernels; here
the reference worlds run the **numpy references** (``use_compiled_kernels(False)``), with every reward
term on, worlds of different sizes in one batch (humans, maps, a robot leader), followers steered to
their slots so that formations switch, settle and are held (the metrics' Python event paths and
their counters in the batched rows), more followers than the compiled static clearance takes, and the
write-back of the rows before per-world calls.
"""

from __future__ import annotations

import numpy as np
import pytest

from swarm_env.compiled import use_compiled_kernels
from swarm_env.env import SwarmEnv
from swarm_env.scenario import RewardSpec
from swarm_env.sensing.layout import OBS_SLOT
from swarm_env.vector.batch_step import PaddedMaps
from swarm_env.vector.engine import INFO_KEYS, EnvFactory, SwarmVectorEnv

ALL_TERMS = RewardSpec(formation=1.5, collision=5.0, contact=2.0, clearance=1.0, clearance_margin=0.4,
                       smoothness=0.3, progress=2.0, approach=0.7, approach_horizon=2.0, approach_margin=0.5)


def _steer(obs: np.ndarray, rng: np.random.Generator, noise: float) -> np.ndarray:
    """``(M, N, 2)`` actions towards each follower's slot (from the observation's slot vector), plus noise."""
    slot = obs[..., OBS_SLOT].astype(np.float64)
    heading = np.arctan2(slot[..., 1], slot[..., 0])
    act = np.stack([np.clip(2.0 * slot[..., 0], -1.0, 1.0), np.clip(2.0 * heading, -1.0, 1.0)], axis=-1)
    return np.clip(act + rng.normal(0.0, noise, act.shape), -1.0, 1.0)


def _rows(d: dict, agents: list[str], key: str | None = None) -> np.ndarray:
    return np.array([d[a] if key is None else d[a][key] for a in agents])


def _metrics(m: dict) -> dict:
    return {k: v for k, v in m.items() if k != "wall_time"}


def _lockstep_vs_numpy(factories: list[EnvFactory], steps: int, seed: int, noise: float) -> dict[str, int]:
    """Step the engine (compiled, batched) and one world per factory run with the numpy references;
    assert every output is bitwise equal; return counts of what the episodes went through."""
    venv = SwarmVectorEnv.from_factories(factories)
    refs = [f() for f in factories]
    agents = refs[0].possible_agents
    seen = {"ended": 0, "settled": 0, "held": 0, "contacts": 0}
    obs, _ = venv.reset(seed=seed)
    use_compiled_kernels(False)
    try:
        for m, env in enumerate(refs):
            o, _ = env.reset(seed=seed + m)
            assert np.array_equal(obs[m], _rows(o, agents))
    finally:
        use_compiled_kernels(True)
    rng = np.random.default_rng(seed)
    for t in range(steps):
        actions = _steer(obs, rng, noise)
        obs, rew, term, trunc, infos = venv.step(actions)
        use_compiled_kernels(False)
        try:
            outs = [env.step(dict(zip(agents, actions[m]))) for m, env in enumerate(refs)]
        finally:
            use_compiled_kernels(True)
        for m, (env, (o, r, te, tr, i)) in enumerate(zip(refs, outs)):
            assert term[m] == te[agents[0]] and trunc[m] == tr[agents[0]], (t, m)
            assert np.array_equal(rew[m], _rows(r, agents)), (t, m)
            for key in INFO_KEYS:
                assert np.array_equal(infos[key][m], _rows(i, agents, key)), (t, m, key)
            seen["contacts"] += int(any(infos[k][m].any() for k in INFO_KEYS if k.startswith("contacts_")))
            if not env.agents:
                seen["ended"] += 1
                metrics = _metrics(env.episode_metrics())
                assert _metrics(infos["final_metrics"][m]) == metrics, (t, m)
                assert np.array_equal(infos["final_obs"][m], _rows(o, agents))
                seen["settled"] += sum(s["settle_time"] is not None for s in metrics["settle_times"])
                seen["held"] += sum(s["hold_fraction"] is not None and s["hold_fraction"] > 0.0
                                    for s in metrics["settle_times"])
                use_compiled_kernels(False)
                try:
                    o, _ = env.reset()
                finally:
                    use_compiled_kernels(True)
            assert np.array_equal(obs[m], _rows(o, agents)), (t, m)
        if t % 17 == 5:  # mid-episode metrics: the rows written back into the worlds
            for got, env in zip(venv.call("episode_metrics"), refs):
                assert _metrics(got) == _metrics(env.episode_metrics())
    venv.close()
    return seen


@pytest.mark.slow
def test_batched_stages_match_numpy_references_with_every_term_and_mixed_worlds() -> None:
    base = dict(n_followers=5, max_time=6.0, n_switches=2, reward=ALL_TERMS, n_obstacles=(2, 8))
    factories = [
        EnvFactory("random", {**base, "n_humans": (0, 3)}),  # 0 to 3 humans: padded rows
        EnvFactory("random", {**base, "n_humans": 2, "leader_kind": "robot"}),
        EnvFactory("random", {**base, "n_humans": (0, 3), "obstacle_types": ("circle",)}),
        EnvFactory("random", {**base, "n_humans": 3, "terminate_on_collision": True}),
        EnvFactory("random", {**base, "n_humans": (0, 3), "world_size": (14.0, 10.0)}),
    ]
    seen = _lockstep_vs_numpy(factories, 130, seed=11, noise=0.05)
    # The paths exercised: episode ends and restarts, formations switched, reached and held, contacts.
    assert seen["ended"] >= 5 and seen["settled"] >= 1 and seen["held"] >= 1 and seen["contacts"] >= 1, seen


def test_more_followers_than_the_compiled_static_clearance_takes() -> None:
    # 34 followers > geometry._FAST_MAX_POINTS: the metrics' static clearance falls back to numpy.
    kwargs = dict(n_followers=34, max_time=2.0, n_humans=2, n_switches=0)
    seen = _lockstep_vs_numpy([EnvFactory("random", kwargs)] * 2, 22, seed=3, noise=0.3)
    assert seen["ended"] == 2


def test_set_attr_and_set_world_reload_the_rows() -> None:
    kwargs = dict(n_followers=3, max_cycles=30, n_humans=1)
    venv = SwarmVectorEnv("random", 2, **kwargs)
    refs = [SwarmEnv("random", **kwargs) for _ in range(2)]
    venv.reset(seed=4)
    for m, env in enumerate(refs):
        env.reset(seed=4 + m)
    rng = np.random.default_rng(0)
    for t in range(40):
        if t == 8:  # a change made from outside reaches the batched rows (the episode end here)
            venv.set_attr("max_steps", 12, indices=[1])
            refs[1].max_steps = 12
        a = rng.uniform(-1, 1, (2, 3, 2))
        _, rew, term, trunc, _ = venv.step(a)
        for m, env in enumerate(refs):
            _, r, te, tr, _ = env.step(dict(zip(env.agents, a[m])))
            assert np.array_equal(rew[m], _rows(r, env.possible_agents)) and term[m] == te["follower_0"]
            assert trunc[m] == tr["follower_0"], (t, m)
            if not env.agents:
                env.reset()
    venv.close()


def test_padded_maps_keep_each_worlds_arrays_when_they_grow() -> None:
    small = SwarmEnv("random", n_obstacles=1, obstacle_types=("circle",))
    big = SwarmEnv("random", n_obstacles=12)
    small.reset(seed=0)
    big.reset(seed=0)
    maps = PaddedMaps(3)
    maps.set(0, small.world_state().static)
    maps.set(2, big.world_state().static)  # grows every padded array
    maps.set(1, small.world_state().static)
    W, H, bound, nbound, circles, ncirc, n_poly, n_edge, *edges = maps.kernel_arrays()
    for b, env in ((0, small), (1, small), (2, big)):
        ref = env.world_state().static.kernel_arrays()
        assert (W[b], H[b], n_poly[b], n_edge[b]) == (ref[0], ref[1], ref[4], ref[5])
        assert np.array_equal(bound[b, :nbound[b]], ref[2]) and np.array_equal(circles[b, :ncirc[b]], ref[3])
        for got, want in zip(edges, ref[6:]):
            assert np.array_equal(got[b, :len(want)], want)


@pytest.mark.parametrize("n_procs", [1, 2])
@pytest.mark.slow
def test_numpy_reference_path_of_the_block_gives_the_batched_bits(n_procs: int) -> None:
    """The block's per-world path (the kernels switched off, as in worker processes) and its batched
    path, switched between in the middle of episodes, give the same results as an engine that never
    switched."""
    kwargs = dict(n_followers=4, max_cycles=15, n_humans=(0, 2), reward=ALL_TERMS)
    a = SwarmVectorEnv("random", 3, **kwargs)
    b = SwarmVectorEnv("random", 3, n_procs=n_procs, **kwargs)
    a.reset(seed=2)
    b.reset(seed=2)
    rng = np.random.default_rng(1)
    for t in range(35):
        act = rng.uniform(-1, 1, (3, 4, 2))
        out_a = a.step(act)
        use_compiled_kernels(t % 10 < 5)
        try:
            out_b = b.step(act)
        finally:
            use_compiled_kernels(True)
        for x, y in zip(out_a[:4], out_b[:4]):
            assert np.array_equal(x, y), t
        for key in INFO_KEYS:
            assert np.array_equal(out_a[4][key], out_b[4][key]), (t, key)
    assert [_metrics(m) for m in a.call("episode_metrics")] == [_metrics(m) for m in b.call("episode_metrics")]
    a.close()
    b.close()


def test_batched_metrics_follow_switches_settling_holding_and_arrival_like_episode_metrics() -> None:
    """Snapshots edited so that formations switch, are reached, held, left and reached again, and the
    leader arrives, in a different rhythm per world: BatchState.metrics (the rows, Python only at the
    events) against EpisodeMetrics.update with the numpy references, result() for result()."""
    import dataclasses

    from swarm_env.scoring.metrics import EpisodeMetrics
    from swarm_env.scoring.rewards import slot_distance
    from swarm_env.vector.batch_step import BatchState

    envs = [SwarmEnv("random", n_followers=4, n_switches=2, n_humans=(0, 2)) for _ in range(4)]
    episodes = []
    for m, env in enumerate(envs):
        env.reset(seed=next(s for s in range(100 * m, 100 * m + 100) if env.reset(seed=s) and
                            len(env.scenario.formations) == 3))  # an episode with two switches
        rng = np.random.default_rng(m)
        tol = env.scenario.world.settle_tolerance
        states = [env.world_state()]
        for t in range(60):
            env.step(dict(zip(env.agents, rng.uniform(-1, 1, (4, 2)))))
            s = env.world_state()
            k = 0 if t < 5 + m else 1 if t < 30 else 2
            near = (t // (2 + m)) % 3 != 0  # within the tolerance two steps in three (per world rhythm)
            offset = rng.uniform(-0.5, 0.5, (4, 2)) * (tol if near else 20 * tol)
            states.append(dataclasses.replace(s, formation_index=k, leader_done=t >= 40 + 3 * m,
                                              slot_targets=s.follower_pose[:, :2] + offset))
        episodes.append(states)
    refs = []
    use_compiled_kernels(False)
    try:
        for states in episodes:
            met = EpisodeMetrics()
            met.start(states[0])
            for s in states[1:]:
                met.update(s, 0.0, slot_distance(s))
            refs.append(met.result())
    finally:
        use_compiled_kernels(True)
    for env, states in zip(envs, episodes):
        env._state = states[0]
        env._metrics = EpisodeMetrics()
        env._metrics.start(states[0])
    rows = BatchState(envs)
    for b, env in enumerate(envs):
        rows.load(b, env)
    for t in range(1, 61):
        states = [ep[t] for ep in episodes]
        a = rows.gather(states)
        rows.metrics(envs, states, a, np.stack([slot_distance(s) for s in states]), 0.0)
    for b, (env, ref) in enumerate(zip(envs, refs)):
        rows.store(b, env)
        got = env._metrics.result()
        assert got == ref
        assert any(s["hold_fraction"] not in (None, 1.0) for s in got["settle_times"]), got["settle_times"]
        assert got["per_robot"][0]["time_to_target"] is not None
