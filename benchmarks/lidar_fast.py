"""The batched engine's lidar per world-step, before and after the faster kernel (issue 11), interleaved.

    OPENBLAS_NUM_THREADS=1 python benchmarks/lidar_fast.py [--worlds 64 1024] [--calls 5] [--repeats 7]

For each ``M``, steps ``SwarmVectorEnv("random", M, **BATCH_WORLD)`` a few times with random actions,
then times, in alternation (before, after, before, after, ...), what one step's lidar costs the
engine from its worlds' states to the distances of all ``M x N`` followers:

* ``before``: the previous path: per world ``(follower poses, moving_discs(state))``, packed with
  per-world ``np.arange``/``np.repeat``/``pack_discs``, then ``scan_reference`` (the previous kernel);
* ``after``: ``SwarmVectorEnv._scan([lidar_input(s) for s in states])`` (``pack_inputs`` + ``scan``);
* ``kernel``: ``scan`` alone on already packed inputs (the rest of ``after`` is the gathering).

Prints the medians over repeats in microseconds per world-step, wall and process CPU time, and
checks that both paths give the same bits. Time the two in one run: the ratio is what holds on a
machine shared with other work, the absolute figures are not.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import numpy as np

from swarm_env.harness.bench import BATCH_WORLD
from swarm_env.sensing.lidar import pack_discs, pack_inputs, scan, scan_reference
from swarm_env.sensing.observations import lidar_input, moving_discs
from swarm_env.vector.engine import SwarmVectorEnv


def paths(m: int) -> dict[str, Callable[[], np.ndarray]]:
    venv = SwarmVectorEnv("random", m, **BATCH_WORLD)
    venv.reset(seed=0)
    rng = np.random.default_rng(0)
    for _ in range(5):
        venv.step(rng.uniform(-1.0, 1.0, (m, venv.num_agents, 2)))
    assert venv._local is not None
    states = [e._state for e in venv._local.envs]
    builder = venv._obs
    angles, max_range = builder._ray_angles, builder.sensors.lidar_range
    worlds = range(m)
    venv._scan([lidar_input(s) for s in states], worlds)  # packs the maps (kept while they stay)
    assert venv._packed is not None
    maps = venv._packed[1]

    def before() -> np.ndarray:
        inputs = [(s.follower_pose, moving_discs(s)) for s in states]
        counts = [len(p) for p, _ in inputs]
        world = np.repeat(np.arange(len(inputs)), counts)
        poses = np.concatenate([p for p, _ in inputs])
        own = np.concatenate([np.arange(n) for n in counts])
        disc_start, discs = pack_discs([d for _, d in inputs])
        return scan_reference(poses, world, own, angles, max_range, maps, disc_start, discs)

    def after() -> np.ndarray:
        return venv._scan([lidar_input(s) for s in states], worlds)

    packed = pack_inputs([lidar_input(s) for s in states])

    def kernel() -> np.ndarray:
        poses, world, own, disc_start, discs = packed
        return scan(poses, world, own, angles, max_range, maps, disc_start, discs)

    return {"before": before, "after": after, "kernel": kernel}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--worlds", type=int, nargs="+", default=[64, 1024])
    p.add_argument("--calls", type=int, default=5)
    p.add_argument("--repeats", type=int, default=7)
    args = p.parse_args()
    print(f"{'worlds':>6} {'path':<8}{'wall us/world-step':>20}{'cpu us/world-step':>19}")
    for m in args.worlds:
        fns = paths(m)
        assert np.array_equal(fns["before"](), fns["after"]()), "the two paths differ"
        wall: dict[str, list[float]] = {k: [] for k in fns}
        cpu: dict[str, list[float]] = {k: [] for k in fns}
        for _ in range(args.repeats):
            for name, fn in fns.items():  # interleaved: each repeat times every path once
                t0, c0 = time.perf_counter(), time.process_time()
                for _ in range(args.calls):
                    fn()
                wall[name].append((time.perf_counter() - t0) / (args.calls * m) * 1e6)
                cpu[name].append((time.process_time() - c0) / (args.calls * m) * 1e6)
        for name in fns:
            print(f"{m:>6} {name:<8}{statistics.median(wall[name]):>20.2f}{statistics.median(cpu[name]):>19.2f}")
        ratio = statistics.median(b / a for b, a in zip(cpu["before"], cpu["after"]))
        print(f"{m:>6} before/after (cpu, median of per-repeat ratios): {ratio:.2f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
