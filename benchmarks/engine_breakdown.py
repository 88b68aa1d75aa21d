"""Where a batched step's time goes, per world, in the batched engine's own order of work.

    OPENBLAS_NUM_THREADS=1 python benchmarks/engine_breakdown.py [--worlds 64] [--steps 40] [--repeats 3]

Steps ``swarm_env.vector.SwarmVectorEnv("random", M, **swarm_env.harness.bench.BATCH_WORLD)`` with random
actions, timing each stage separately (median over repeats, microseconds per world-step):
``physics`` (pymunk substeps with the drive callbacks, the humans and the leader, the slot
targets: ``World.step``), ``snapshot`` (``World.snapshot``), ``rewards`` (contacts, then slot
distances and reward terms: ``reward_table``), ``metrics`` (``EpisodeMetrics.update`` and the episode
bookkeeping), ``observations`` (everything but the lidar), ``lidar`` (one kernel call for all
``M x N`` followers, divided by M). The stages run the engine's code in its order; auto-resets
are done outside the clock.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from swarm_env.harness.bench import BATCH_WORLD
from swarm_env.observations import lidar_input
from swarm_env.rewards import reward_table, touching_per_follower
from swarm_env.vector import SwarmVectorEnv

STAGES = ("physics", "snapshot", "rewards", "metrics", "observations", "lidar")


def one_repeat(venv: SwarmVectorEnv, actions: np.ndarray, steps: int) -> dict[str, float]:
    block = venv._local
    assert block is not None
    totals = dict.fromkeys(STAGES, 0.0)
    clock = time.perf_counter
    for k in range(steps):
        states = []
        for env, act in zip(block.envs, actions[k % len(actions)]):
            t0 = clock()
            env._world.step(act * env._speed)
            t1 = clock()
            state = env._world.snapshot()
            t2 = clock()
            touching = touching_per_follower(state)
            dist, _, _ = reward_table(state, state.scenario.reward, env._prev_dist, act, env._prev_action, touching)
            t3 = clock()
            env._state = state
            env._prev_dist, env._prev_action = dist, act
            env._metrics.update(state, 0.0, dist)
            t4 = clock()
            env._obs.build_without_lidar(state)
            t5 = clock()
            states.append(state)
            for name, dt in zip(STAGES, (t1 - t0, t2 - t1, t3 - t2, t4 - t3, t5 - t4)):
                totals[name] += dt
        t0 = clock()
        venv._scan([lidar_input(s) for s in states], range(venv.num_envs))
        totals["lidar"] += clock() - t0
        for b, env in enumerate(block.envs):  # auto-reset, off the clock
            if env._state.step >= env.max_steps:
                block._restart(b, None)
                venv._maps[b] = env._state.static
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
