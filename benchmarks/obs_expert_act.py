"""Benchmark: the observation-only expert's ``act()`` for all followers, next to one ``env.step``, and its
``act_rows`` over the followers of many worlds at once (the batched engine's rows, for teaching).

    OPENBLAS_NUM_THREADS=1 python benchmarks/obs_expert_act.py   # random seed 0 (4 followers), paper_cbs_switch (8)
    python benchmarks/obs_expert_act.py --repeat 5 --scenarios crowd_reactive --rows 512

Per scenario one seeded episode is played with the expert (default options), timing every ``env.step``; every
observation it was shown is kept and ``act()`` is timed on each ``--repeat`` times (the median per state kept).
Reported over the states, in microseconds of CPU time (``time.process_time``) and of wall time: median and p95 of
``act()`` and of ``env.step`` (the peer measured in the same run). Then ``--rows`` observation rows drawn from the
episode's states are stacked and ``act_rows`` is timed on them: agent-actions per second of CPU time. Timings are
of this machine and this run: compare numbers from the same run only.
"""

from __future__ import annotations

import argparse
import platform
import time
from collections.abc import Callable

import numpy as np

from swarm_env.env import SwarmEnv
from swarm_env_agents.obs_expert import ObservationExpert

SCENARIOS = ("random", "paper_cbs_switch")


def _timed(fn: Callable[[], object], repeat: int) -> tuple[float, float]:
    """Median CPU and wall seconds of ``repeat`` calls of ``fn``."""
    cpu, wall = [], []
    for _ in range(repeat):
        c, w = time.process_time(), time.perf_counter()
        fn()
        cpu.append(time.process_time() - c)
        wall.append(time.perf_counter() - w)
    return float(np.median(cpu)), float(np.median(wall))


def bench(scenario: str, repeat: int, rows: int) -> dict[str, float]:
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
    act = np.array([_timed(lambda o=o: policy.act(o), repeat) for o in states])  # (states, 2)
    stacked = np.concatenate([np.stack(list(o.values())) for o in states])
    pick = np.random.default_rng(0).choice(len(stacked), size=rows, replace=rows > len(stacked))
    batch_cpu, _ = _timed(lambda: policy.act_rows(stacked[pick]), repeat)
    us = 1e6
    return {
        "followers": len(states[0]), "states": len(states),
        "act_cpu_median_us": float(np.median(act[:, 0])) * us, "act_cpu_p95_us": float(np.percentile(act[:, 0], 95)) * us,
        "act_wall_median_us": float(np.median(act[:, 1])) * us,
        "step_cpu_median_us": float(np.median(step_cpu)) * us, "step_cpu_p95_us": float(np.percentile(step_cpu, 95)) * us,
        "step_wall_median_us": float(np.median(step_wall)) * us,
        "rows": rows, "rows_per_cpu_s": rows / batch_cpu,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=3, help="timings of act() per state (median kept)")
    ap.add_argument("--scenarios", nargs="*", default=list(SCENARIOS))
    ap.add_argument("--rows", type=int, default=512, help="observation rows for act_rows (e.g. 64 worlds x 8)")
    args = ap.parse_args()
    print(f"# {platform.processor() or platform.machine()}, python {platform.python_version()}")
    print("| scenario | followers | act() CPU median / p95 (us) | act() wall median (us) | env.step CPU median / p95 "
          "(us) | env.step wall median (us) | act_rows: rows | agent-actions / CPU s |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for scenario in args.scenarios:
        r = bench(scenario, args.repeat, args.rows)
        print(f"| {scenario} | {r['followers']} | {r['act_cpu_median_us']:.0f} / {r['act_cpu_p95_us']:.0f} | "
              f"{r['act_wall_median_us']:.0f} | {r['step_cpu_median_us']:.0f} / {r['step_cpu_p95_us']:.0f} | "
              f"{r['step_wall_median_us']:.0f} | {r['rows']} | {r['rows_per_cpu_s']:.0f} |")


if __name__ == "__main__":
    main()
