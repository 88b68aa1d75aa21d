"""What the reward costs per step: ``SwarmEnv`` with reward v1, v1 without its clearance term, and v0.

Run: ``OPENBLAS_NUM_THREADS=1 python benchmarks/reward_cost.py [--scenario paper_cbs_switch] [--steps 2000]``.
The three envs step the same pre-drawn random actions, interleaved, ``--repeats`` times; the medians
of CPU time (``time.process_time``) and wall time per step are printed. The README's Performance
section quotes it.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import swarm_env

VARIANTS = {"v1": None, "v1 without clearance": {"clearance": 0.0}, "v0": "v0"}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="paper_cbs_switch")
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    envs = {name: swarm_env.parallel_env(args.scenario, reward=reward) for name, reward in VARIANTS.items()}
    agents = envs["v1"].possible_agents
    rng = np.random.default_rng(0)
    actions = [{a: rng.uniform(-1.0, 1.0, 2).astype(np.float32) for a in agents} for _ in range(args.steps)]
    cpu: dict[str, list[float]] = {name: [] for name in envs}
    wall: dict[str, list[float]] = {name: [] for name in envs}
    for _ in range(args.repeats):
        for name, env in envs.items():
            env.reset(seed=0)
            c0, w0 = time.process_time(), time.perf_counter()
            for act in actions:
                if not env.agents:
                    env.reset()
                env.step(act)
            cpu[name].append((time.process_time() - c0) / args.steps * 1e6)
            wall[name].append((time.perf_counter() - w0) / args.steps * 1e6)
    print(f"{args.scenario}, {args.steps} steps x {args.repeats} repeats, median per step")
    for name in envs:
        print(f"  {name:22s} CPU {np.median(cpu[name]):7.1f} us   wall {np.median(wall[name]):7.1f} us")


if __name__ == "__main__":
    main()
