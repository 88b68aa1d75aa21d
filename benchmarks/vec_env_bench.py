"""Throughput of the SB3 bridge against its peer, the bare parallel env stepped in a loop.

    python benchmarks/vec_env_bench.py [--scenario random] [--copies 8] [--steps 300] [--repeats 5]

Prints agent-steps per second (one follower acting once; for ``random``, whose
episodes have 2-8 followers, only present followers count) for:

* ``env``: ``n_copies`` bare :class:`~swarm_env.env.SwarmEnv` copies stepped in
  a Python loop with dict actions (what any bridge must at least do);
* ``bridge``: :class:`swarm_env_baselines.vec_env.SwarmVecEnv` with the same copies, in
  process (``n_procs=1``) and over two worker processes (``n_procs=2``).

Medians over ``--repeats`` runs, measured in the same process so the ratios
are comparable on a noisy shared machine.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from swarm_env.env import SwarmEnv
from swarm_env_baselines.vec_env import make_vec_env


def bench_env(scenario: str, copies: int, steps: int, seed: int) -> float:
    envs = [SwarmEnv(scenario) for _ in range(copies)]
    n_slots = len(envs[0].possible_agents)
    for m, env in enumerate(envs):
        env.reset(seed=seed + m * n_slots)  # the worlds the bridge's copies get
    rng = np.random.default_rng(seed)
    agent_steps = 0
    t0 = time.perf_counter()
    for _ in range(steps):
        for env in envs:
            if not env.agents:
                env.reset()
            actions = dict(zip(env.agents, rng.uniform(-1, 1, (len(env.agents), 2)).astype(np.float32)))
            agent_steps += len(actions)
            env.step(actions)
    return agent_steps / (time.perf_counter() - t0)


def bench_bridge(scenario: str, copies: int, steps: int, seed: int, n_procs: int) -> float:
    venv = make_vec_env(scenario, copies, n_procs=n_procs, seed=seed)
    venv.reset()
    rng = np.random.default_rng(seed)
    agent_steps = 0
    t0 = time.perf_counter()
    for _ in range(steps):
        _, _, _, infos = venv.step(rng.uniform(-1, 1, (venv.num_envs, 2)).astype(np.float32))
        agent_steps += len(infos)  # fixed teams: every sub-env is a real follower
    rate = agent_steps / (time.perf_counter() - t0)
    venv.close()
    return rate


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scenario", default="random")
    parser.add_argument("--copies", type=int, default=8)
    parser.add_argument("--steps", type=int, default=300, help="vector steps per repeat")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    runs: dict[str, list[float]] = {"env": [], "bridge n_procs=1": [], "bridge n_procs=2": []}
    for r in range(args.repeats):
        seed = args.seed + 1000 * r
        runs["env"].append(bench_env(args.scenario, args.copies, args.steps, seed))
        runs["bridge n_procs=1"].append(bench_bridge(args.scenario, args.copies, args.steps, seed, 1))
        runs["bridge n_procs=2"].append(bench_bridge(args.scenario, args.copies, args.steps, seed, 2))
    base = statistics.median(runs["env"])
    print(f"{args.scenario}, {args.copies} copies, {args.steps} steps x {args.repeats} repeats (median agent-steps/s)")
    for name, values in runs.items():
        med = statistics.median(values)
        print(f"  {name:<18} {med:>10,.0f}   x{med / base:.2f} of env")


if __name__ == "__main__":
    main()
