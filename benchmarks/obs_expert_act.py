"""Benchmark: the observation-only expert's ``act()`` for all followers, next to one ``env.step``, and its
``act_rows`` over the followers of many worlds at once (the batched engine's rows, for teaching).

    OPENBLAS_NUM_THREADS=1 python benchmarks/obs_expert_act.py --reference   # random seed 0 (4 followers), paper_cbs_switch (8)
    python benchmarks/obs_expert_act.py --repeat 5 --scenarios crowd_reactive --rows 512

Per scenario one seeded episode is played with the expert (default options), timing every ``env.step``; every
observation it was shown is kept and ``act()`` is timed on each ``--repeat`` times (the median per state kept).
Reported over the states, in microseconds of CPU time (``time.process_time``) and of wall time: median and p95 of
``act()`` and of ``env.step`` (the peer measured in the same run). Then ``--rows`` observation rows drawn from the
episode's states are stacked and ``act_rows`` is timed on them: agent-actions per second of CPU time.

The expert's choice runs compiled (:mod:`swarm_env_agents.obs_expert_kernel`, the default); ``--reference`` times
its numpy reference too (``compiled_mode(kernels=False)``), interleaved with the compiled one call by call (one row
each in the table; the same actions). The compiled kernel is compiled or loaded from numba's cache before any
timing. Timings are of this machine and this run: compare numbers from the same run only.
"""

from __future__ import annotations

import argparse
import platform
import time
from collections.abc import Callable

import numpy as np

from swarm_env.compiled import compiled_mode
from swarm_env.env import SwarmEnv
from swarm_env_agents.obs_expert import ObservationExpert

SCENARIOS = ("random", "paper_cbs_switch")


def _timed(fn: Callable[[], object], repeat: int, modes: tuple[str, ...]) -> dict[str, tuple[float, float]]:
    """Median CPU and wall seconds of ``repeat`` calls of ``fn`` per mode (``compiled`` or ``reference``), the
    modes' calls interleaved."""
    cpu: dict[str, list[float]] = {mode: [] for mode in modes}
    wall: dict[str, list[float]] = {mode: [] for mode in modes}
    for _ in range(repeat):
        for mode in modes:
            with compiled_mode(kernels=mode == "compiled"):
                c, w = time.process_time(), time.perf_counter()
                fn()
                cpu[mode].append(time.process_time() - c)
                wall[mode].append(time.perf_counter() - w)
    return {mode: (float(np.median(cpu[mode])), float(np.median(wall[mode]))) for mode in modes}


def bench(scenario: str, repeat: int, rows: int, modes: tuple[str, ...]) -> dict[str, dict[str, float]]:
    """Per mode: the figures of the table (see the module)."""
    env = SwarmEnv(scenario)
    policy = ObservationExpert()
    obs, _ = env.reset(seed=0)
    policy.reset(env, 0)
    states, step_cpu, step_wall = [], [], []
    while env.agents:
        states.append(obs)
        action = policy.act(obs)
        c, w = time.process_time(), time.perf_counter()
        obs, *_ = env.step(action)
        step_cpu.append(time.process_time() - c)
        step_wall.append(time.perf_counter() - w)
    per_state = [_timed(lambda o=o: policy.act(o), repeat, modes) for o in states]
    stacked = np.concatenate([np.stack(list(o.values())) for o in states])
    pick = np.random.default_rng(0).choice(len(stacked), size=rows, replace=rows > len(stacked))
    batch = _timed(lambda: policy.act_rows(stacked[pick]), repeat, modes)
    us = 1e6
    out = {}
    for mode in modes:
        act = np.array([t[mode] for t in per_state])  # (states, 2)
        out[mode] = {
            "followers": len(states[0]), "states": len(states),
            "act_cpu_median_us": float(np.median(act[:, 0])) * us,
            "act_cpu_p95_us": float(np.percentile(act[:, 0], 95)) * us,
            "act_wall_median_us": float(np.median(act[:, 1])) * us,
            "step_cpu_median_us": float(np.median(step_cpu)) * us,
            "step_cpu_p95_us": float(np.percentile(step_cpu, 95)) * us,
            "step_wall_median_us": float(np.median(step_wall)) * us,
            "rows": rows, "rows_per_cpu_s": rows / batch[mode][0],
        }
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=3, help="timings of act() per state (median kept)")
    ap.add_argument("--scenarios", nargs="*", default=list(SCENARIOS))
    ap.add_argument("--rows", type=int, default=512, help="observation rows for act_rows (e.g. 64 worlds x 8)")
    ap.add_argument("--reference", action="store_true",
                    help="time the numpy reference too (kernels off), interleaved with the compiled kernel")
    args = ap.parse_args()
    modes = ("reference", "compiled") if args.reference else ("compiled",)
    print(f"# {platform.processor() or platform.machine()}, python {platform.python_version()}")
    print("| scenario | followers | expert | act() CPU median / p95 (us) | act() wall median (us) | env.step CPU median "
          "/ p95 (us) | env.step wall median (us) | act_rows: rows | agent-actions / CPU s |")
    print("|---|---:|---|---:|---:|---:|---:|---:|---:|")
    for scenario in args.scenarios:
        for mode, r in bench(scenario, args.repeat, args.rows, modes).items():
            print(f"| {scenario} | {r['followers']} | {mode} | {r['act_cpu_median_us']:.0f} / {r['act_cpu_p95_us']:.0f} | "
                  f"{r['act_wall_median_us']:.0f} | {r['step_cpu_median_us']:.0f} / {r['step_cpu_p95_us']:.0f} | "
                  f"{r['step_wall_median_us']:.0f} | {r['rows']} | {r['rows_per_cpu_s']:.0f} |")


if __name__ == "__main__":
    main()
