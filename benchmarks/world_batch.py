"""Physics + snapshot per world-step: the per-world loop (``World.step`` then ``World.snapshot``)
against :class:`swarm_env.vector.world_batch.WorldBatch` (one compiled call for all worlds), on the batched
benchmark's world (``random`` with ``swarm_env.harness.bench.BATCH_WORLD``: 8 followers, 10
obstacles, 3 scripted humans, a virtual leader).

    OPENBLAS_NUM_THREADS=1 python benchmarks/world_batch.py [--worlds 64 1024] [--steps 10] [--repeats 5]

Two copies of the same ``M`` worlds (``SwarmEnv("random", **BATCH_WORLD)`` reset with seeds
``0..M-1``, the worlds ``engine_breakdown.py``'s engine builds, then 5 random steps so every space is
past its first step) are stepped with the same random commands, the loop and the batch alternating repeat by
repeat (interleaved, so a load change on the machine hits both). Reports medians over repeats of
process CPU time and wall time, in microseconds per world-step, the CPU time of the batch's compiled
call alone (chipmunk's substeps included), and the ratio of the CPU medians;
checks at the end that both copies reached the same states.
"""

from __future__ import annotations

import argparse
import pickle
import statistics
import time
from typing import Any

import numpy as np

from swarm_env.env import SwarmEnv
from swarm_env.harness.bench import BATCH_WORLD
from swarm_env.sim.world import World
from swarm_env.vector import world_batch
from swarm_env.vector.world_batch import WorldBatch


def _worlds(m: int) -> tuple[list[World], list[World]]:
    """Two copies of the ``M`` worlds: each ``reset`` builds a new ``World`` (the env drops the old one
    untouched); both copies are pickled round trips of the same list (a world continues bit for bit
    after a round trip), so neither copy's memory is laid out more favourably than the other's."""
    env = SwarmEnv("random", **BATCH_WORLD)
    out = []
    for seed in range(m):
        env.reset(seed=seed)
        assert env._world is not None
        out.append(env._world)
    data = pickle.dumps(out)
    return pickle.loads(data), pickle.loads(data)


def run(m: int, steps: int, repeats: int) -> dict[str, float]:
    loop_worlds, batch_worlds = _worlds(m)
    batch = WorldBatch(batch_worlds)
    n = loop_worlds[0].n
    rng = np.random.default_rng(0)
    scale = np.array([loop_worlds[0].scenario.robots.max_speed, loop_worlds[0].scenario.robots.max_turn_rate])
    commands = rng.uniform(-1.0, 1.0, (8, m, n, 2)) * scale  # drawn before the clock starts
    k = 0
    for _ in range(5):  # warm-up: first steps (pymunk checks new bodies), numba compile / cache load
        for w, c in zip(loop_worlds, commands[k % 8]):
            w.step(c)
            w.snapshot()
        batch.step_and_snapshot(commands[k % 8])
        k += 1
    res: dict[str, list[float]] = {"loop_cpu": [], "loop_wall": [], "batch_cpu": [], "batch_wall": [],
                                   "kernel_cpu": []}
    per = 1e6 / (steps * m)
    kernel = world_batch._batch_step
    in_kernel = [0.0]

    def timed_kernel(*args: Any) -> Any:  # the compiled call's share of the batch's time
        t = time.process_time()
        out = kernel(*args)
        in_kernel[0] += time.process_time() - t
        return out

    world_batch._batch_step = timed_kernel
    for _ in range(repeats):
        c0, w0 = time.process_time(), time.perf_counter()
        for j in range(steps):
            for w, c in zip(loop_worlds, commands[(k + j) % 8]):
                w.step(c)
                w.snapshot()
        res["loop_cpu"].append((time.process_time() - c0) * per)
        res["loop_wall"].append((time.perf_counter() - w0) * per)
        in_kernel[0] = 0.0
        c0, w0 = time.process_time(), time.perf_counter()
        for j in range(steps):
            batch.step_and_snapshot(commands[(k + j) % 8])
        res["batch_cpu"].append((time.process_time() - c0) * per)
        res["batch_wall"].append((time.perf_counter() - w0) * per)
        res["kernel_cpu"].append(in_kernel[0] * per)
        k += steps
    world_batch._batch_step = kernel
    assert batch.last_batched == m, f"only {batch.last_batched} of {m} worlds took the batched path"
    for a, b in zip(loop_worlds, batch_worlds):  # the same states at the end (the tests check every field)
        sa, sb = a.snapshot(), b.snapshot()
        assert sa.follower_pose.tobytes() == sb.follower_pose.tobytes() and sa.step == sb.step
    return {key: statistics.median(v) for key, v in res.items()}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--worlds", type=int, nargs="+", default=[64, 1024])
    p.add_argument("--steps", type=int, default=10)
    p.add_argument("--repeats", type=int, default=5)
    args = p.parse_args()
    print(f"{'worlds':>7}{'loop cpu':>10}{'loop wall':>11}{'batch cpu':>11}{'batch wall':>12}{'of it kernel':>14}"
          f"{'cpu ratio':>11}   (us per world-step, medians)")
    for m in args.worlds:
        r = run(m, args.steps, args.repeats)
        print(f"{m:>7}{r['loop_cpu']:>10.1f}{r['loop_wall']:>11.1f}{r['batch_cpu']:>11.1f}{r['batch_wall']:>12.1f}"
              f"{r['kernel_cpu']:>14.1f}{r['loop_cpu'] / r['batch_cpu']:>10.2f}x", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
