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


@dataclass(frozen=True)
class BenchResult:
    name: str
    agents: int
    env_steps_per_s: list[float]  # one figure per repeat

    @property
    def median(self) -> float:
        return statistics.median(self.env_steps_per_s)

    @property
    def agent_steps_per_s(self) -> float:
        return self.median * self.agents


def _time_loop(env: Any, actions: list[dict[str, Any]], seed: int) -> float:
    """Env steps per second of stepping ``env`` through ``actions``."""
    env.reset(seed=seed)
    t0 = time.perf_counter()
    for act in actions:
        if not env.agents:
            env.reset()
        env.step({a: act[a] for a in env.agents})
    return len(actions) / (time.perf_counter() - t0)


def _swarm_case(scenario: str, steps: int, seed: int) -> tuple[Any, list[dict[str, Any]]]:
    from swarm_env.env import SwarmEnv

    env = SwarmEnv(scenario)
    rng = np.random.default_rng(seed)
    raw = rng.uniform(-1.0, 1.0, size=(steps, len(env.possible_agents), 2)).astype(np.float32)
    actions = [{a: raw[t, i] for i, a in enumerate(env.possible_agents)} for t in range(steps)]
    return env, actions


def _mpe2_case(n_agents: int, steps: int, seed: int) -> tuple[Any, list[dict[str, Any]]]:
    try:
        from mpe2 import simple_spread_v3
    except ImportError as exc:  # optional extra
        raise RuntimeError("--vs mpe2 needs the optional extra: pip install 'swarm-env[bench]'") from exc
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
    for r in range(repeats):
        for name, e, a in cases:
            figures[name].append(_time_loop(e, a, seed + r))
            if progress is not None:
                progress(f"repeat {r + 1}/{repeats} {name}: {figures[name][-1]:,.0f} env-steps/s")
    return [BenchResult(name, len(e.possible_agents), figures[name]) for name, e, _ in cases]
