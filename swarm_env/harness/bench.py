"""Environment throughput benchmark (``swarm-env bench``).

Steps an env with uniformly random actions that are drawn *before* the
clock starts (so the figure is the env's cost, not the sampler's), resetting
whenever an episode ends, and reports the median over several repeats. With
``peer="mpe2"`` the same loop runs MPE2's ``simple_spread_v3`` with as many
agents in the same process, interleaved with ours, so the ratio is measured
under the same machine load.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from swarm_env.env import SwarmEnv
from swarm_env.extras import require
from swarm_env.outputs import save_figure
from swarm_env.vector.engine import SwarmVectorEnv


@dataclass(frozen=True)
class BenchResult:
    name: str
    agents: int
    env_steps_per_s: list[float]  # one figure per repeat, over wall time
    cpu_env_steps_per_s: list[float]  # the same repeats over this process's CPU time

    @property
    def median(self) -> float:
        return statistics.median(self.env_steps_per_s)

    @property
    def cpu_median(self) -> float:
        return statistics.median(self.cpu_env_steps_per_s)

    @property
    def agent_steps_per_s(self) -> float:
        return self.median * self.agents


def _time_loop(env: Any, actions: list[dict[str, Any]], seed: int) -> tuple[float, float]:
    """Env steps per second of stepping ``env`` through ``actions``: over wall time, over CPU time."""
    env.reset(seed=seed)
    t0, c0 = time.perf_counter(), time.process_time()
    for act in actions:
        if not env.agents:
            env.reset()
        env.step({a: act[a] for a in env.agents})
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    return len(actions) / wall, len(actions) / max(cpu, 1e-9)


def _swarm_case(scenario: str, steps: int, seed: int) -> tuple[Any, list[dict[str, Any]]]:
    env = SwarmEnv(scenario)
    rng = np.random.default_rng(seed)
    raw = rng.uniform(-1.0, 1.0, size=(steps, len(env.possible_agents), 2)).astype(np.float32)
    actions = [{a: raw[t, i] for i, a in enumerate(env.possible_agents)} for t in range(steps)]
    return env, actions


def _mpe2_case(n_agents: int, steps: int, seed: int) -> tuple[Any, list[dict[str, Any]]]:
    simple_spread_v3 = require("mpe2.simple_spread_v3", "bench", "--vs mpe2")
    env = simple_spread_v3.parallel_env(N=n_agents, max_cycles=25)
    rng = np.random.default_rng(seed)
    raw = rng.integers(0, 5, size=(steps, n_agents))
    actions = [{a: int(raw[t, i]) for i, a in enumerate(env.possible_agents)} for t in range(steps)]
    return env, actions


def run_bench(
    scenario: str = "paper_cbs_switch",
    steps: int = 2000,
    repeats: int = 5,
    seed: int = 0,
    peer: str | None = None,
    progress: Callable[[str], None] | None = None,
) -> list[BenchResult]:
    """Median env-steps/s of ``scenario`` (and of ``peer`` in the same run, interleaved)."""
    env, actions = _swarm_case(scenario, steps, seed)
    cases: list[tuple[str, Any, list[dict[str, Any]]]] = [(f"swarm_env:{scenario}", env, actions)]
    if peer == "mpe2":
        penv, pactions = _mpe2_case(len(env.possible_agents), steps, seed)
        cases.append((f"mpe2:simple_spread_v3(N={len(penv.possible_agents)})", penv, pactions))
    elif peer is not None:
        raise ValueError(f"unknown peer {peer!r}; supported: mpe2")
    for _, e, a in cases:  # warm-up: imports, caches, first allocations
        _time_loop(e, a[: min(200, len(a))], seed)
    figures: dict[str, list[float]] = {name: [] for name, _, _ in cases}
    cpu: dict[str, list[float]] = {name: [] for name, _, _ in cases}
    for r in range(repeats):
        for name, e, a in cases:
            wall_rate, cpu_rate = _time_loop(e, a, seed + r)
            figures[name].append(wall_rate)
            cpu[name].append(cpu_rate)
            if progress is not None:
                progress(f"repeat {r + 1}/{repeats} {name}: {wall_rate:,.0f} env-steps/s ({cpu_rate:,.0f} per CPU s)")
    return [BenchResult(name, len(e.possible_agents), figures[name], cpu[name]) for name, e, _ in cases]


# ------------------------------------------------------------------------------ batched engine

#: The batched benchmark's worlds: ``random`` at ``paper_cbs_switch``'s size (29 x 20 m, 8 followers,
#: 10 obstacles, 16-ray lidar) with 3 walking humans, a new map every episode.
BATCH_WORLD: dict[str, Any] = {"n_followers": 8, "n_obstacles": 10, "n_humans": 3, "world_size": (29.0, 20.0)}
BATCH_SIZES = (1, 8, 64, 256, 1024)


@dataclass(frozen=True)
class BatchResult:
    name: str
    num_envs: int
    agents: int
    wall: list[float]  # agent-steps/s per repeat, over wall time
    cpu: list[float]  # agent-steps/s per repeat, over this process's CPU time

    @property
    def median_wall(self) -> float:
        return statistics.median(self.wall)

    @property
    def median_cpu(self) -> float:
        return statistics.median(self.cpu)


def _batch_steps(num_envs: int, budget: int) -> int:
    """Steps per repeat: about ``budget`` world-steps, at least 5 steps."""
    return max(5, -(-budget // num_envs))


def _time_steps(step: Callable[[int], Any], steps: int, agent_steps_per_step: int) -> tuple[float, float]:
    t0, c0 = time.perf_counter(), time.process_time()
    for k in range(steps):
        step(k)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    return steps * agent_steps_per_step / wall, steps * agent_steps_per_step / max(cpu, 1e-9)


def _swarm_batch(num_envs: int, seed: int, n_procs: int = 1,
                 worker_kernels: bool = False) -> tuple[Any, Callable[[int], Any], int]:
    venv = SwarmVectorEnv("random", num_envs, n_procs=n_procs, worker_kernels=worker_kernels, **BATCH_WORLD)
    venv.reset(seed=seed)
    rng = np.random.default_rng(seed)
    actions = rng.uniform(-1.0, 1.0, (8, num_envs, venv.num_agents, 2))  # drawn before the clock starts
    return venv, lambda k: venv.step(actions[k % 8]), num_envs * venv.num_agents


def _vmas_batch(num_envs: int, seed: int) -> tuple[Any, Callable[[int], Any], int]:
    torch = require("torch", "rl,vmas", "--vs vmas")  # VMAS runs on torch
    vmas = require("vmas", "rl,vmas", "--vs vmas")
    torch.set_num_threads(1)
    n = BATCH_WORLD["n_followers"]
    env = vmas.make_env("navigation", num_envs=num_envs, device="cpu", continuous_actions=True, n_agents=n,
                        n_lidar_rays=16, seed=seed)
    env.reset()
    gen = torch.Generator().manual_seed(seed)
    actions = [[torch.rand(num_envs, 2, generator=gen) * 2 - 1 for _ in range(n)] for _ in range(8)]
    return env, lambda k: env.step(actions[k % 8]), num_envs * n


def run_batched_bench(
    sizes: tuple[int, ...] = BATCH_SIZES,
    repeats: int = 3,
    budget: int = 1024,
    seed: int = 0,
    peer: str | None = None,
    n_procs: int = 1,
    progress: Callable[[str], None] | None = None,
    worker_kernels: bool = False,
) -> list[BatchResult]:
    """Agent-steps/s of :class:`~swarm_env.vector.engine.SwarmVectorEnv` on :data:`BATCH_WORLD` for each
    batch size (and of VMAS ``navigation`` with 8 agents and 16 lidar rays, with ``peer="vmas"``),
    interleaved repeat by repeat, ``budget`` world-steps per repeat (at least 5 steps).
    ``n_procs`` and ``worker_kernels`` are the engine's arguments."""
    if peer not in (None, "vmas"):
        raise ValueError(f"unknown peer {peer!r} for the batched bench; supported: vmas")
    out = []
    for m in sizes:
        label = f"(n_procs={n_procs}{', worker_kernels' if worker_kernels else ''})" if n_procs > 1 else ""
        cases = [("swarm_env.vector.engine" + label, *_swarm_batch(m, seed, n_procs, worker_kernels))]
        if peer == "vmas":
            cases.append(("vmas:navigation", *_vmas_batch(m, seed)))
        steps = _batch_steps(m, budget)
        for _, _, step, _ in cases:  # warm-up: compilation, caches, first allocations
            for k in range(2):
                step(k)
        figures: dict[str, tuple[list[float], list[float]]] = {name: ([], []) for name, *_ in cases}
        for r in range(repeats):
            for name, _, step, per_step in cases:
                wall, cpu = _time_steps(step, steps, per_step)
                if "n_procs" in name:
                    cpu = float("nan")  # the workers' CPU time is not this process's
                figures[name][0].append(wall)
                figures[name][1].append(cpu)
                if progress is not None:
                    progress(f"M={m} repeat {r + 1}/{repeats} {name}: {wall:,.0f} agent-steps/s (cpu {cpu:,.0f})")
        for name, env, _, per_step in cases:
            out.append(BatchResult(name, m, per_step // m, *figures[name]))
            close = getattr(env, "close", None)
            if callable(close) and name.startswith("swarm_env"):
                close()
    return out


def run_followers_bench(
    followers: tuple[int, ...] = (8, 32, 64),
    steps: int = 300,
    repeats: int = 3,
    seed: int = 0,
    progress: Callable[[str], None] | None = None,
) -> list[BatchResult]:
    """Agent-steps/s of one :class:`~swarm_env.env.SwarmEnv` (``random`` worlds, 10 obstacles, 3
    humans, the generator's world size for the team) per team size, interleaved: the cost per
    follower should stay flat as the team grows."""
    cases = []
    for n in followers:
        env = SwarmEnv("random", n_followers=n, n_obstacles=10, n_humans=3)
        env.reset(seed=seed)
        rng = np.random.default_rng(seed)
        raw = rng.uniform(-1.0, 1.0, (8, n, 2)).astype(np.float32)
        acts = [dict(zip(env.possible_agents, raw[k])) for k in range(8)]

        def step(k: int, env: Any = env, acts: list = acts) -> None:
            if not env.agents:
                env.reset()
            env.step(acts[k % 8])

        step(0)
        cases.append((f"swarm_env:random(n_followers={n})", n, step))
    figures: dict[str, tuple[list[float], list[float]]] = {name: ([], []) for name, _, _ in cases}
    for r in range(repeats):
        for name, n, step in cases:
            wall, cpu = _time_steps(step, steps, n)
            figures[name][0].append(wall)
            figures[name][1].append(cpu)
            if progress is not None:
                progress(f"repeat {r + 1}/{repeats} {name}: {wall:,.0f} agent-steps/s")
    return [BatchResult(name, 1, n, *figures[name]) for name, n, _ in cases]


def plot_batched(results: list[BatchResult], path: str, *, overwrite: bool = True) -> None:
    """Agent-steps/s against the batch size M (log-log), one line per engine: median over the
    repeats, with the repeats' range as a band (the ``plots`` extra: matplotlib). Written atomically
    (:func:`swarm_env.outputs.open_atomic`; an existing file is replaced only with ``overwrite``)."""
    require("matplotlib", "plots", "--plot").use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6.4, 4.2), dpi=120)
    for name in dict.fromkeys(r.name for r in results if r.num_envs > 0 and not r.name.startswith("swarm_env:")):
        rows = sorted((r for r in results if r.name == name), key=lambda r: r.num_envs)
        m = [r.num_envs for r in rows]
        ax.plot(m, [r.median_wall for r in rows], marker="o", label=name)
        ax.fill_between(m, [min(r.wall) for r in rows], [max(r.wall) for r in rows], alpha=0.2)
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    ax.set_xlabel("worlds stepped together (M)")
    ax.set_ylabel("agent-steps / s (wall, 1 thread)")
    ax.set_title("Batched throughput, 8 agents per world, 16 lidar rays")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    try:
        save_figure(fig, path, overwrite=overwrite)
    finally:
        plt.close(fig)
