"""Whether the batched engine's cost per world stays flat as the number of worlds grows.

    OPENBLAS_NUM_THREADS=1 python benchmarks/engine_scaling.py [--worlds 8 64 256 1024] [--rounds 100] [--steps 1]

Builds one :class:`swarm_env.vector.engine.SwarmVectorEnv` per world count (``random`` at
``swarm_env.harness.bench.BATCH_WORLD``: 8 followers, 10 obstacles, 3 humans, the worlds ``swarm-env
bench --num-envs`` steps), resets it with seed 0 and steps it with random actions drawn before the
clock starts. The engines live side by side and are stepped in turn, ``--steps`` steps each (a
slice), round after round: finely interleaved, so a change of load on a shared machine hits every
count alike. Every engine takes the same number of steps, so all are at the same point of their
episodes (world ``m`` is the same world in every engine: seed ``m``); with the defaults no episode
ends (they last hundreds of steps), so this is the cost of a step, not of building new worlds
(``random`` draws a new map and team per episode, tens of ms per world, whatever the count).
Per world count it prints:

* ``agent-steps/s``: all rounds' agent-steps over all rounds' time (wall, and this process's CPU
  time, ``time.process_time``), i.e. the mean rate, which includes costs that come back every few
  dozen steps (the cyclic garbage collector's full passes) and a median would hide;
* ``median``: the median slice's rate over CPU time (robust to a burst of load);
* ``cpu us/world-step`` and ``vs peak``: the mean CPU rate relative to the best count's (the goal:
  the largest count within 10 % of the peak);
* ``gc ms``: time spent in the cyclic garbage collector during that count's slices (``gc.callbacks``);
* ``ends``: episodes that ended (and were reset) during the slices.

``--json PATH`` writes every slice's figures.
"""

from __future__ import annotations

import argparse
import gc
import statistics
import time
from typing import Any

import numpy as np

from swarm_env.harness.bench import BATCH_WORLD
from swarm_env.jsonio import write_json
from swarm_env.vector.engine import SwarmVectorEnv


class _GcClock:
    """Seconds spent in the cyclic garbage collector since :meth:`take` was last called."""

    def __init__(self) -> None:
        self.total = 0.0
        self._t0 = 0.0

    def __call__(self, phase: str, info: dict[str, Any]) -> None:
        if phase == "start":
            self._t0 = time.perf_counter()
        else:
            self.total += time.perf_counter() - self._t0

    def take(self) -> float:
        out, self.total = self.total, 0.0
        return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--worlds", type=int, nargs="+", default=[8, 64, 256, 1024])
    p.add_argument("--rounds", type=int, default=100)
    p.add_argument("--steps", type=int, default=1, help="steps of each engine per round")
    p.add_argument("--warmup", type=int, default=5, help="steps of each engine before the clock starts")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", default=None)
    args = p.parse_args()
    cases = []
    for m in args.worlds:
        venv = SwarmVectorEnv("random", m, **BATCH_WORLD)
        venv.reset(seed=args.seed)
        actions = np.random.default_rng(args.seed).uniform(-1.0, 1.0, (8, m, venv.num_agents, 2))
        for k in range(args.warmup):  # compilation / cache load, the worlds' first steps, first allocations
            venv.step(actions[k % 8])
        cases.append((m, venv, actions, args.steps))
    n = cases[0][1].num_agents
    slices: dict[int, list[tuple[int, float, float, float, int]]] = {m: [] for m, *_ in cases}
    clock = _GcClock()
    gc.callbacks.append(clock)
    try:
        for r in range(args.rounds):
            for m, venv, actions, steps in cases:
                k = args.warmup + r * steps
                clock.take()
                t0, c0 = time.perf_counter(), time.process_time()
                ends = 0
                for _ in range(steps):
                    _, _, terminated, truncated, _ = venv.step(actions[k % 8])
                    ends += int(np.count_nonzero(terminated | truncated))
                    k += 1
                dw, dc = time.perf_counter() - t0, time.process_time() - c0
                slices[m].append((steps * m * n, dw, dc, clock.take(), ends))
    finally:
        gc.callbacks.remove(clock)
    rows = {}
    for m, got in slices.items():
        agent_steps = sum(s[0] for s in got)
        wall = agent_steps / sum(s[1] for s in got)
        cpu = agent_steps / max(sum(s[2] for s in got), 1e-9)
        median = statistics.median(s[0] / max(s[2], 1e-9) for s in got)
        rows[m] = (wall, cpu, median, 1e3 * sum(s[3] for s in got), sum(s[4] for s in got))
    peak = max(r[1] for r in rows.values())
    print(f"{'worlds':>7}{'agent-steps/s wall':>20}{'cpu':>11}{'median cpu':>12}{'cpu us/world-step':>19}"
          f"{'vs peak':>9}{'gc ms':>8}{'ends':>6}")
    for m, (wall, cpu, median, gc_ms, ends) in rows.items():
        print(f"{m:>7}{wall:>20,.0f}{cpu:>11,.0f}{median:>12,.0f}{1e6 * n / cpu:>19.1f}{cpu / peak:>9.2f}"
              f"{gc_ms:>8.0f}{ends:>6}")
    print(f"({args.rounds} rounds of {args.steps} step(s) per count, interleaved; {n} followers per world)")
    if args.json:
        write_json(args.json, {"followers": n, "slices": {m: [list(s) for s in got] for m, got in slices.items()}})
    for _, venv, _, _ in cases:
        venv.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
