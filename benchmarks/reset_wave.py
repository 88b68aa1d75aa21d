"""What an episode start costs the batched engine on ``random``, with and without the next worlds drawn ahead.

Every world of a batch that started together ends its episode at the same step, so their restarts come as one
wave. Two measurements at ``--worlds`` worlds (default 64):

* ``reset``: the median wall time of ``venv.reset(seed=s)`` over ``--repeats`` seeds: every world drawn,
  validated and built in this process (what a wave cost before the worlds drew ahead);
* ``steps``: ``--steps`` steps of uniform random actions (two episode ends of the default 600-step episodes),
  with ``prefetch_scenarios`` off and on, alternating: the median step, the slowest steps (the waves), the
  prefetcher's hits and misses, and the worker's memory (``/proc/PID/smaps_rollup``, Linux)::

    OPENBLAS_NUM_THREADS=1 python benchmarks/reset_wave.py
    OPENBLAS_NUM_THREADS=1 python benchmarks/reset_wave.py --only reset   # also runs at commits before prefetching
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy: multithreaded BLAS is slower under load

import argparse
import time
from pathlib import Path
from statistics import median
from typing import Any


def _reset_wave(worlds: int, repeats: int) -> list[float]:
    from swarm_env.vector.engine import SwarmVectorEnv

    venv = SwarmVectorEnv("random", num_envs=worlds)
    venv.reset(seed=0)  # warm-up: compilation, first allocations
    times = []
    for s in range(1, repeats + 1):
        t = time.perf_counter()
        venv.reset(seed=s)
        times.append(time.perf_counter() - t)
    venv.close()
    return times


def _memory(pid: int) -> str:
    rollup = Path(f"/proc/{pid}/smaps_rollup")
    if not rollup.exists():
        return "n/a"
    fields = {line.split(":")[0]: int(line.split()[1]) for line in rollup.read_text().splitlines()[1:]}
    return f"PSS {fields['Pss'] / 1024:.0f} MiB, private {(fields['Private_Clean'] + fields['Private_Dirty']) / 1024:.0f} MiB"


def _steps(worlds: int, steps: int, prefetch: bool) -> dict[str, Any]:
    import numpy as np

    from swarm_env.vector.engine import SwarmVectorEnv

    venv = SwarmVectorEnv("random", num_envs=worlds, prefetch_scenarios=prefetch)
    venv.reset(seed=0)
    actions = np.random.default_rng(0).uniform(-1.0, 1.0, (8, worlds, venv.num_agents, 2))
    times = []
    for k in range(steps):
        t = time.perf_counter()
        venv.step(actions[k % 8])
        times.append(time.perf_counter() - t)
    out: dict[str, Any] = {"median_ms": 1e3 * median(times[1:]), "slowest_ms": sorted(1e3 * t for t in times[1:])[-2:],
                           "total_s": sum(times[1:])}
    prefetcher = venv._local._prefetch if venv._local is not None else None
    if prefetcher is not None:
        out.update(hits=prefetcher.hits, misses=prefetcher.misses, worker=_memory(prefetcher._proc.pid))
    venv.close()
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--worlds", type=int, default=64)
    parser.add_argument("--repeats", type=int, default=7, help="seeded resets timed")
    parser.add_argument("--steps", type=int, default=1300, help="steps per run of the step measurement")
    parser.add_argument("--runs", type=int, default=2, help="runs of each kind (off, on) in the step measurement")
    parser.add_argument("--only", choices=("reset", "steps"))
    args = parser.parse_args(argv)
    if args.only != "steps":
        times = _reset_wave(args.worlds, args.repeats)
        print(f"reset of {args.worlds} worlds: median {median(times):.3f} s ({min(times):.3f}-{max(times):.3f}) "
              f"over {len(times)} seeds")
    if args.only != "reset":
        for r in range(args.runs):
            for prefetch in ((False, True) if r % 2 == 0 else (True, False)):
                res = _steps(args.worlds, args.steps, prefetch)
                extra = (f", hits {res['hits']}, misses {res['misses']}, worker {res['worker']}"
                         if prefetch else "")
                print(f"prefetch {'on ' if prefetch else 'off'}: {args.steps} steps {res['total_s']:.2f} s, median step "
                      f"{res['median_ms']:.2f} ms, two slowest {res['slowest_ms'][0]:.0f} / {res['slowest_ms'][1]:.0f} ms"
                      + extra, flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
