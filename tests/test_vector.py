"""The batched engine (swarm_env.vector.engine) against its reference, M independent SwarmEnvs."""

from __future__ import annotations

import sys

import numpy as np
import pytest

import swarm_env
from swarm_env.env import SwarmEnv
from swarm_env.sensing.lidar import PackedMaps, cast_rays, pack_discs, scan
from swarm_env.sensing.observations import moving_discs
from swarm_env.vector.engine import INFO_KEYS, EnvFactory, SwarmVectorEnv
from swarm_env.wrappers import SHIELD_INFO_KEYS


def _rows(d: dict, agents: list[str], key: str | None = None) -> np.ndarray:
    return np.array([d[a] if key is None else d[a][key] for a in agents])


def _lockstep(scenario: str, num_envs: int, steps: int, seed: int, discrete: bool = False, n_procs: int = 1,
              shield: bool = False, worker_kernels: bool = False, chunk: int | None = None,
              prefetch: dict | None = None, **kwargs) -> int:
    """Step a SwarmVectorEnv and num_envs SwarmEnvs with the same actions; assert every output is
    bitwise equal; return the number of episodes that ended (and were auto-reset). ``chunk``: the
    engine's physics steps that many worlds per compiled call (default: WorldBatch's). ``prefetch``: a dict
    to run the engine with ``prefetch_scenarios=True`` and receive its prefetcher's ``hits`` and ``misses``."""
    if discrete:
        kwargs["action_type"] = "discrete"
    venv = SwarmVectorEnv(scenario, num_envs, n_procs=n_procs, shield=shield, worker_kernels=worker_kernels,
                          prefetch_scenarios=prefetch is not None, **kwargs)
    if chunk is not None:
        from swarm_env.vector.world_batch import WorldBatch

        assert venv._local is not None
        venv._local._physics = WorldBatch(chunk=chunk)
    refs = [EnvFactory(scenario, kwargs, shield)() for _ in range(num_envs)]
    keys = INFO_KEYS + (SHIELD_INFO_KEYS if shield else ())
    agents = refs[0].possible_agents
    obs, infos = venv.reset(seed=seed)
    for m, env in enumerate(refs):
        o, i = env.reset(seed=seed + m)
        assert np.array_equal(obs[m], _rows(o, agents))
        for key in keys:
            assert np.array_equal(infos[key][m], _rows(i, agents, key)), key
    assert venv.episode_starts() == [{"seed": seed + m, "rng": None} for m in range(num_envs)]
    if shield:
        assert infos["shield_action"].shape == (num_envs, len(agents), 2) and not infos["shield_action"].any()
    rng = np.random.default_rng(seed)
    ended = 0
    for t in range(steps):
        if discrete:
            actions = rng.integers(0, 10, (num_envs, len(agents)))
        else:
            actions = rng.uniform(-1.0, 1.0, (num_envs, len(agents), 2)).astype(np.float32)
        obs, rew, term, trunc, infos = venv.step(actions)
        assert obs.dtype == np.float32 and obs.shape == (num_envs, len(agents), venv.single_observation_space.shape[0])
        for m, env in enumerate(refs):
            o, r, te, tr, i = env.step({a: actions[m, k] for k, a in enumerate(agents)})
            last = _rows(o, agents)
            assert term[m] == te[agents[0]] and trunc[m] == tr[agents[0]]
            assert np.array_equal(rew[m], _rows(r, agents)), (t, m)
            for key in keys:
                assert np.array_equal(infos[key][m], _rows(i, agents, key)), (t, m, key)
            if shield:  # the executed safe actions
                assert np.array_equal(infos["shield_action"][m], _rows(env.last_safe_actions, agents)), (t, m)
            if not env.agents:
                ended += 1
                assert infos["_final"][m]
                assert np.array_equal(infos["final_obs"][m], last)
                metrics = {k: v for k, v in env.episode_metrics().items() if k != "wall_time"}
                assert {k: v for k, v in infos["final_metrics"][m].items() if k != "wall_time"} == metrics
                assert np.array_equal(infos["final_state"][m], env.state())
                final_world = infos["final_world_state"][m]
                assert final_world.time == env.world_state().time
                assert np.array_equal(final_world.follower_pose, env.world_state().follower_pose)
                before = env.unwrapped._rng.bit_generator.state  # what the unseeded reset draws from
                o, _ = env.reset()  # auto-reset: the generator continues
                assert venv.episode_starts()[m] == {"seed": None, "rng": before}
                last = _rows(o, agents)
            elif "_final" in infos:
                assert not infos["_final"][m] and infos["final_metrics"][m] is None
                assert infos["final_state"][m] is None and infos["final_world_state"][m] is None
            assert np.array_equal(obs[m], last), (t, m)
        assert np.array_equal(venv.state(), np.stack([e.state() for e in refs]))
    if prefetch is not None:
        assert venv._local is not None
        prefetch.update(hits=venv._local._prefetch.hits, misses=venv._local._prefetch.misses)
    venv.close()
    return ended


@pytest.mark.parametrize("scenario", [s for s in swarm_env.list_scenarios() if s != "random"])
def test_each_builtin_scenario_matches_swarm_env_bitwise(scenario: str) -> None:
    assert _lockstep(scenario, 3, 45, seed=7, max_cycles=20) >= 3


@pytest.mark.slow
def test_fifty_random_worlds_match_swarm_env_bitwise() -> None:
    # 50 worlds, seeds 1000-1049, each ending once (max_cycles) and continuing after its auto-reset.
    assert _lockstep("random", 50, 30, seed=1000, max_cycles=25) == 50


def test_worlds_in_several_physics_chunks_with_different_human_counts() -> None:
    """The batched stages and the lidar read the physics' stacked blocks and the rows (not the
    snapshots): chunks of 2 worlds with 0 to 3 humans each, episodes ending and restarting with other
    counts, the same bits."""
    assert _lockstep("random", 7, 30, seed=70, max_cycles=12, n_humans=(0, 3), chunk=2) >= 14


def test_random_with_humans_and_robot_leader_and_discrete_actions() -> None:
    assert _lockstep("random", 4, 30, seed=3, discrete=True, max_cycles=12, n_humans=(2, 4), leader_kind="robot") >= 8


def test_scenarios_drawn_ahead_give_the_same_bits() -> None:
    """``prefetch_scenarios=True``: the next random worlds are drawn in a worker process; the episodes are the
    reference's bit for bit, and most restarts took a drawn scenario (the reference envs step slowly enough
    for the worker; a restart that finds none draws its own, with the same result)."""
    stats: dict = {}
    assert _lockstep("random", 6, 60, seed=90, max_cycles=12, n_humans=(0, 2), prefetch=stats) == 6 * 5
    assert stats["hits"] + stats["misses"] == 6 * 5, stats  # every restart asked (how many hit is timing)


def test_a_prefetched_scenario_is_the_local_draw_and_moves_the_generator_alike() -> None:
    import time

    from swarm_env.scenarios.generator import config_from_kwargs, random_scenario
    from swarm_env.vector.scenario_prefetch import ScenarioPrefetcher

    config = config_from_kwargs(n_followers=3, n_humans=(0, 2))
    prefetcher = ScenarioPrefetcher()
    try:
        rng, local = np.random.default_rng(5), np.random.default_rng(5)
        random_scenario(rng, config), random_scenario(local, config)  # both one episode in
        prefetcher.submit("w", rng, config)
        deadline = time.monotonic() + 120
        while not prefetcher.ready("w"):
            assert time.monotonic() < deadline, "the worker did not answer"
            time.sleep(0.01)
        other = np.random.default_rng(6)
        before = other.bit_generator.state
        assert prefetcher.take("w", other) is None and other.bit_generator.state == before  # another state: a miss
        prefetcher.submit("w", rng, config)
        while not prefetcher.ready("w"):
            assert time.monotonic() < deadline, "the worker did not answer"
            time.sleep(0.01)
        drawn = prefetcher.take("w", rng)
        assert drawn == random_scenario(local, config)  # the local draw, bit for bit
        assert rng.bit_generator.state == local.bit_generator.state  # the generator moved past it alike
        assert (prefetcher.hits, prefetcher.misses) == (1, 1)
        assert prefetcher.take("w", rng) is None  # taken once
    finally:
        prefetcher.close()
    assert prefetcher._proc.poll() is not None  # the worker ended with it
    with pytest.raises(ValueError, match="prefetch_scenarios needs n_procs=1"):
        SwarmVectorEnv("random", 2, n_procs=2, prefetch_scenarios=True)
    with pytest.raises(ValueError, match="prefetch_scenarios must be a bool"):
        SwarmVectorEnv("random", 2, prefetch_scenarios="yes")  # type: ignore[arg-type]


@pytest.mark.slow
def test_worker_processes_give_the_same_bits() -> None:
    assert _lockstep("random", 5, 30, seed=40, n_procs=2, max_cycles=25, n_humans=(1, 3)) == 5


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc/PID/maps")
@pytest.mark.slow
def test_workers_with_compiled_kernels_give_the_same_bits() -> None:
    """``worker_kernels=True``: the workers run the compiled kernels (numba is loaded in them) and the
    results are still a ``SwarmEnv``'s bits, shielded worlds (the compiled search) included."""
    assert _lockstep("random", 4, 30, seed=41, n_procs=2, worker_kernels=True, max_cycles=25, n_humans=(1, 3)) == 4
    assert _lockstep("paper_vo_45", 2, 12, seed=0, shield=True, n_procs=2, worker_kernels=True, max_cycles=10) == 2
    venv = SwarmVectorEnv("paper_vo_0", 2, n_procs=2, worker_kernels=True)
    venv.reset(seed=0)
    venv.step(np.zeros((2, venv.num_agents, 2)))
    for remote in venv._remotes:
        with open(f"/proc/{remote.proc.pid}/maps") as f:
            assert "llvmlite" in f.read()
    venv.close()
    with pytest.raises(ValueError, match="worker_kernels"):
        SwarmVectorEnv("paper_vo_0", 2, n_procs=2, worker_kernels="yes")


def test_shielded_worlds_match_safety_shield_bitwise() -> None:
    assert _lockstep("random", 3, 25, seed=60, shield=True, max_cycles=20, n_humans=(2, 3)) == 3
    assert _lockstep("paper_vo_45", 2, 12, seed=0, shield=True, n_procs=2, max_cycles=10) == 2


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc/PID/maps")
def test_workers_load_neither_torch_nor_numba_and_end_with_the_engine() -> None:
    try:
        import torch  # noqa: F401 - loaded here, in the parent: the workers must still not load it
    except ModuleNotFoundError:  # a core install (no `rl` extra, e.g. Python 3.10/3.12 here): numba's half still holds
        pass

    venv = SwarmVectorEnv("paper_vo_0", 2, n_procs=2)
    venv.reset(seed=0)
    venv.step(np.zeros((2, venv.num_agents, 2)))
    for remote in venv._remotes:
        with open(f"/proc/{remote.proc.pid}/maps") as f:
            libraries = f.read()
        assert "pymunk" in libraries  # the worker does the physics
        assert "libtorch" not in libraries and "llvmlite" not in libraries
    venv.close()
    assert all(r.proc.poll() is not None for r in venv._remotes)


def test_seeds_and_auto_reset_contract() -> None:
    venv = SwarmVectorEnv("random", 3, max_cycles=5)
    a, _ = venv.reset(seed=[11, 12, 13])
    b, _ = venv.reset(seed=11)
    assert np.array_equal(a, b)  # an int seed s gives world m the seed s + m
    zeros = np.zeros((3, venv.num_agents, 2))
    for _ in range(4):
        _, _, term, trunc, infos = venv.step(zeros)
        assert not (term | trunc).any() and "_final" not in infos
    obs, _, term, trunc, infos = venv.step(zeros)
    assert trunc.all() and not term.any() and infos["_final"].all()
    assert [m["termination"] for m in infos["final_metrics"]] == ["time_limit"] * 3
    assert not np.array_equal(obs, infos["final_obs"])  # obs is the next episode's first


def test_bad_input_gets_a_clear_error() -> None:
    with pytest.raises(ValueError, match="num_envs"):
        SwarmVectorEnv("paper_vo_0", 0)
    venv = SwarmVectorEnv("random", 2, n_followers=4)
    with pytest.raises(RuntimeError, match="reset"):
        venv.step(np.zeros((2, venv.num_agents, 2)))
    venv.reset(seed=0)
    with pytest.raises(ValueError, match=r"shape \(2, 4, 2\)"):
        venv.step(np.zeros((2, 3, 2)))
    bad = np.zeros((2, venv.num_agents, 2))
    bad[1, 2, 0] = np.nan
    with pytest.raises(ValueError, match="world 1, follower 2"):
        venv.step(bad)
    with pytest.raises(ValueError, match="seed"):
        venv.reset(seed=[1, 2, 3])
    with pytest.raises(ValueError, match="same team"):
        SwarmVectorEnv.from_factories([EnvFactory("random", {"n_followers": 3}), EnvFactory("random", {"n_followers": 4})])
    with pytest.raises(ValueError, match="n_procs"):
        SwarmVectorEnv("paper_vo_0", 2, n_procs=3)
    with pytest.warns(UserWarning, match="clipped"):
        venv.step(np.full((2, venv.num_agents, 2), 1.5))


def test_one_lidar_call_for_many_worlds_equals_one_per_world() -> None:
    """The kernel scans robot by robot: packing worlds together changes no bit."""
    envs = [SwarmEnv("random", n_humans=(1, 3)) for _ in range(4)]
    states = []
    for m, env in enumerate(envs):
        env.reset(seed=20 + m)
        states.append(env.world_state())
    builder = envs[0]._obs
    together = builder.lidar(states)
    apart = np.concatenate([builder.lidar([s]) for s in states])
    assert np.array_equal(together, apart)
    # ... and one robot's scan equals its rays cast one by one (the single-ray entry point).
    s = states[0]
    angles = s.follower_pose[0, 2] + builder._ray_angles
    single = cast_rays(np.repeat(s.follower_pose[:1, :2], len(angles), axis=0), angles, builder.sensors.lidar_range,
                       s.static, moving_discs(s), np.zeros(len(angles), dtype=np.int64))
    np.testing.assert_array_equal(single, together[0])
    start, discs = pack_discs([moving_discs(s)])
    assert np.array_equal(scan(s.follower_pose, np.zeros(s.n_followers, dtype=np.int64), np.arange(s.n_followers),
                               builder._ray_angles, builder.sensors.lidar_range, PackedMaps.of([s.static]), start, discs),
                          together[: s.n_followers])


def test_per_world_calls_reach_the_right_world_in_any_process() -> None:
    for n_procs in (1, 2):
        venv = SwarmVectorEnv("random", 3, n_procs=n_procs, max_cycles=9, n_followers=2)
        venv.reset(seed=5)
        venv.set_attr("max_cycles", 4, indices=[2])
        assert venv.get_attr("max_cycles") == [9, 9, 4]
        assert [s.n_followers for s in venv.call("world_state")] == [2, 2, 2]
        metrics = venv.call("episode_metrics", indices=[1])
        assert len(metrics) == 1 and metrics[0]["steps"] == 0
        with pytest.raises(IndexError, match="out of range"):
            venv.get_attr("max_cycles", indices=[3])
        venv.close()


@pytest.mark.parametrize("n_procs", [1, 2])
@pytest.mark.slow
def test_a_world_rebuilt_from_its_episode_start_and_actions_takes_its_place_bitwise(n_procs: int) -> None:
    """How a trainer resumes: a fresh world reset as episode_starts() says and given the same actions,
    put in with set_world, goes on exactly as the original (here against an engine that never stopped)."""
    import numpy.random

    kwargs = dict(max_cycles=9, n_humans=(1, 2), n_followers=3)
    whole = SwarmVectorEnv("random", 3, shield=True, **kwargs)
    rebuilt = SwarmVectorEnv("random", 3, shield=True, n_procs=n_procs, **kwargs)
    rng = np.random.default_rng(0)
    actions = [rng.uniform(-1, 1, (3, 3, 2)) for _ in range(26)]
    for venv in (whole, rebuilt):
        venv.reset(seed=30)
    history: list[list[np.ndarray]] = [[], [], []]
    for a in actions[:13]:  # every world ends its first episode at step 9: world starts are generator states
        whole.step(a)
        _, _, term, trunc, _ = rebuilt.step(a)
        for m in range(3):
            history[m] = [] if term[m] or trunc[m] else [*history[m], a[m]]
    starts = rebuilt.episode_starts()
    assert all(s["seed"] is None and s["rng"] for s in starts)
    for m in (0, 2):
        world = EnvFactory("random", kwargs, shield=True)()
        bits = getattr(numpy.random, starts[m]["rng"]["bit_generator"])()
        bits.state = starts[m]["rng"]
        world.unwrapped._rng = np.random.Generator(bits)
        world.reset()
        for a in history[m]:
            world.step(dict(zip(world.possible_agents, a)))
        rebuilt.set_world(m, world, starts[m])
    assert rebuilt.episode_starts() == starts
    for a in actions[13:]:  # the rebuilt worlds end their episode and start the next from the right stream
        out_a, out_b = whole.step(a), rebuilt.step(a)
        for x, y in zip(out_a[:4], out_b[:4]):
            assert np.array_equal(x, y)
        for key in ("shield_action", "shield_correction", "slot_distance"):
            assert np.array_equal(out_a[4][key], out_b[4][key])
        assert np.array_equal(whole.state(), rebuilt.state())
    assert [m["shield"] for m in whole.call("episode_metrics")] == [m["shield"] for m in rebuilt.call("episode_metrics")]
    with pytest.raises(TypeError, match="SafetyShield"):
        rebuilt.set_world(1, EnvFactory("random", kwargs)())
    fresh = SwarmVectorEnv("random", 2, **kwargs)
    with pytest.raises(RuntimeError, match="reset"):
        fresh.set_world(0, EnvFactory("random", kwargs)())
    for venv in (whole, rebuilt, fresh):
        venv.close()
