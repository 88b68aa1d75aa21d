"""Time one lidar scan of all followers (the observation's most expensive part), per team size.

    OPENBLAS_NUM_THREADS=1 python benchmarks/lidar_bench.py [--followers 8 32 64] [--calls 200] [--repeats 5]

On a ``random`` world with 3 humans for each team size, times the env's own lidar call for every
follower of one state (``ObservationBuilder.lidar``; at commits before the compiled kernel the
builder's ``_lidar``), and prints the median over repeats in microseconds per call and per follower.
To compare with the numpy caster it replaced, run this file against that tree too::

    git worktree add /tmp/numpy_lidar 101a419
    PYTHONPATH=/tmp/numpy_lidar python benchmarks/lidar_bench.py
"""

from __future__ import annotations

import argparse
import statistics
import time

from swarm_env.env import SwarmEnv


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--followers", type=int, nargs="+", default=[8, 32, 64])
    p.add_argument("--calls", type=int, default=200)
    p.add_argument("--repeats", type=int, default=5)
    args = p.parse_args()
    for n in args.followers:
        env = SwarmEnv("random", n_followers=n, n_humans=(3, 3))
        env.reset(seed=1)
        state, builder = env.world_state(), env._obs
        scan = (lambda: builder.lidar([state])) if hasattr(builder, "lidar") else (lambda: builder._lidar(state))
        scan()  # compile / warm up
        times = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            for _ in range(args.calls):
                scan()
            times.append((time.perf_counter() - t0) / args.calls * 1e6)
        med = statistics.median(times)
        print(f"{n:>3} followers: {med:8.1f} us per scan, {med / n:6.2f} us per follower")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
