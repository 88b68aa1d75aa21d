"""The physics stage alone: ``World.step`` in microseconds per world-step, beside the floor that
pymunk itself sets (``space.step`` x substeps and nothing else) at the batched benchmark's world
(``swarm_env.harness.bench.BATCH_WORLD``: 8 followers, 10 obstacles, 3 humans).

    OPENBLAS_NUM_THREADS=1 python benchmarks/physics_step.py [--worlds 64] [--steps 20] [--repeats 5]

Each world is reset and driven 20 random steps first (robots spread out, some contacts). Reports the
median over repeats of process CPU time (and wall time) per world-step. To compare two checkouts on
a loaded machine, run this script under each alternately (``PYTHONPATH=<checkout>``) and compare
medians.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--worlds", type=int, default=64)
    parser.add_argument("--steps", type=int, default=20, help="steps per world per repeat")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--profile", action="store_true", help="also print cProfile's top entries")
    args = parser.parse_args()

    from swarm_env.env import SwarmEnv
    from swarm_env.harness.bench import BATCH_WORLD

    rng = np.random.default_rng(0)
    worlds = []
    for seed in range(args.worlds):
        env = SwarmEnv("random", **BATCH_WORLD)
        env.reset(seed=seed)
        for _ in range(20):
            env.step({a: rng.uniform(-1, 1, 2).astype(np.float32) for a in env.agents})
        worlds.append(env._world)  # the env's World (private: this measures the stage alone)
    commands = rng.uniform(-1, 1, (args.steps, len(worlds), worlds[0].n, 2))

    floor_cpu, step_cpu, step_wall = [], [], []
    for _ in range(args.repeats):
        t = time.process_time()
        for _k in range(args.steps):
            for w in worlds:
                for _s in range(w.substeps):
                    w.space.step(w.sub_dt)
        floor_cpu.append((time.process_time() - t) / (args.steps * len(worlds)) * 1e6)
        t, tw = time.process_time(), time.perf_counter()
        for k in range(args.steps):
            for m, w in enumerate(worlds):
                w.step(commands[k, m])
        step_cpu.append((time.process_time() - t) / (args.steps * len(worlds)) * 1e6)
        step_wall.append((time.perf_counter() - tw) / (args.steps * len(worlds)) * 1e6)
    print(f"space.step x substeps: {statistics.median(floor_cpu):.1f} us/world-step (cpu)")
    print(f"World.step: {statistics.median(step_cpu):.1f} us/world-step (cpu), "
          f"{statistics.median(step_wall):.1f} (wall); repeats {[round(x, 1) for x in step_cpu]}")
    if args.profile:
        import cProfile
        import pstats

        prof = cProfile.Profile()
        prof.enable()
        for k in range(args.steps):
            for m, w in enumerate(worlds):
                w.step(commands[k, m])
        prof.disable()
        pstats.Stats(prof).sort_stats("tottime").print_stats(20)


if __name__ == "__main__":
    main()
