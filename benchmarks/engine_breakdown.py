"""Where a batched step's time goes, per world, in the batched engine's own order of work.

    OPENBLAS_NUM_THREADS=1 python benchmarks/engine_breakdown.py [--worlds 64] [--steps 40] [--repeats 3]

Steps ``swarm_env.vector.engine.SwarmVectorEnv("random", M, **swarm_env.harness.bench.BATCH_WORLD)`` with random
actions, timing each stage separately (median over repeats, microseconds per world-step):
``physics`` (pymunk substeps with the drive callbacks, the humans and the leader, the slot
targets and the snapshots: ``World.step`` + ``World.snapshot`` of all worlds in one compiled call,
:mod:`swarm_env.vector.world_batch`, as the engine's ``_physics_stage``), then the batched stages of :class:`swarm_env.vector.batch_step.BatchState`, each one call for all ``M`` worlds:
``rewards`` (contacts, slot distances, reward terms: ``BatchState.rewards``), ``metrics``
(``EpisodeMetrics.update`` of every world: ``BatchState.metrics``), ``observations`` (everything but
the lidar: ``BatchState.observations``), ``glue`` (the physics' stacked arrays,
``WorldBatch.last_arrays`` + ``BatchState.arrays_of``, and the episode end and infos,
``BatchState.finish``), and ``lidar`` (its inputs from the rows, ``BatchState.lidar_rows``, one kernel
call for all ``M x N`` followers, and the observations' lidar columns, divided by M). The stages run the engine's code in its
order; auto-resets are done outside the clock.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from swarm_env.harness.bench import BATCH_WORLD
from swarm_env.vector.engine import SwarmVectorEnv, _physics_stage

STAGES = ("physics", "rewards", "metrics", "observations", "glue", "lidar")


def one_repeat(venv: SwarmVectorEnv, actions: np.ndarray, steps: int) -> dict[str, float]:
    block = venv._local
    assert block is not None and block._rows is not None and block._rows_live  # warmed up by venv.step
    rows = block._rows
    envs = block.envs
    totals = dict.fromkeys(STAGES, 0.0)
    clock = time.perf_counter

    def settle(indices: list[int], states: list) -> None:  # as the engine: each chunk's snapshots stored at once
        for b in indices:
            envs[b]._state = states[b]

    for k in range(steps):
        acts = actions[k % len(actions)]
        t0 = clock()
        states = _physics_stage(envs, acts, block._physics, speed=rows.speed, on_states=settle)
        totals["physics"] += clock() - t0
        t0 = clock()
        blocks = block._physics.last_arrays()
        a = rows.arrays_of(blocks) if blocks is not None else rows.gather(states)
        t1 = clock()
        floats, _, touching = rows.rewards(envs, states, a, acts)
        t2 = clock()
        within = rows.metrics(envs, states, a, floats[-1], 0.0)
        t3 = clock()
        obs = rows.observations(envs, states, a)
        t4 = clock()
        terminated, truncated, _ = rows.finish(envs, states, a, floats, touching, within)
        t5 = clock()
        for name, dt in (("glue", t1 - t0 + t5 - t4), ("rewards", t2 - t1), ("metrics", t3 - t2),
                         ("observations", t4 - t3)):
            totals[name] += dt
        ended = np.flatnonzero(terminated | truncated).tolist()
        for b in ended:  # auto-reset, off the clock
            block._restart(int(b), None)
            venv._maps[b] = envs[b]._state.static
        fresh = {b: envs[b]._state for b in ended}
        t0 = clock()
        lidar = venv._obs.scan_rows(rows.lidar_rows(a, fresh), venv._packed_batch())
        venv._obs.fill_lidar(obs, lidar.reshape(venv.num_envs, venv.num_agents, -1))
        totals["lidar"] += clock() - t0
    return {name: 1e6 * total / (steps * venv.num_envs) for name, total in totals.items()}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--worlds", type=int, default=64)
    p.add_argument("--steps", type=int, default=40)
    p.add_argument("--repeats", type=int, default=3)
    args = p.parse_args()
    venv = SwarmVectorEnv("random", args.worlds, **BATCH_WORLD)
    venv.reset(seed=0)
    actions = np.random.default_rng(0).uniform(-1.0, 1.0, (8, args.worlds, venv.num_agents, 2))
    for k in range(3):
        venv.step(actions[k])
    runs = [one_repeat(venv, actions, args.steps) for _ in range(args.repeats)]
    total = 0.0
    print(f"{'stage':<14}{'us / world-step':>16}")
    for name in STAGES:
        value = statistics.median(r[name] for r in runs)
        total += value
        print(f"{name:<14}{value:>16.1f}")
    print(f"{'sum':<14}{total:>16.1f}   ({args.worlds} worlds of random at BATCH_WORLD, {venv.num_agents} followers)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
