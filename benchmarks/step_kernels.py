"""A step of one SwarmEnv with the compiled per-step kernels and with their numpy references.

    OPENBLAS_NUM_THREADS=1 python benchmarks/step_kernels.py [--steps 1000] [--repeats 5]

The kernels (``swarm_env.compiled``: the observations' assembly, the clearances, the snapshot's
arrays, the scripted humans and the robots' velocity callback) give the references' bits; this measures what they buy.
Two envs of each scenario, one built with the kernels on and one with them off (the velocity
callback is chosen when a world is built), are stepped with the same random actions, alternating
repeat by repeat; the table gives the median microseconds per env step over CPU time
(``time.process_time``) and over wall time.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from swarm_env.compiled import use_compiled_kernels
from swarm_env.env import SwarmEnv
from swarm_env.harness.bench import BATCH_WORLD

CASES = {"paper_cbs_switch": ("paper_cbs_switch", {}), "random (bench world)": ("random", BATCH_WORLD)}


def _loop(env: SwarmEnv, actions: np.ndarray, seed: int) -> tuple[float, float]:
    env.reset(seed=seed)
    agents = list(env.possible_agents)
    t0, c0 = time.perf_counter(), time.process_time()
    for k in range(len(actions)):
        if not env.agents:
            env.reset()
        env.step(dict(zip(agents, actions[k])))
    return (time.process_time() - c0) / len(actions) * 1e6, (time.perf_counter() - t0) / len(actions) * 1e6


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)
    print(f"{'scenario':<22} {'kernels':<10} {'CPU us/step':>12} {'wall us/step':>13}")
    for label, (scenario, kwargs) in CASES.items():
        envs = {}
        for flag in (True, False):
            use_compiled_kernels(flag)
            envs[flag] = SwarmEnv(scenario, **kwargs)
            envs[flag].reset(seed=0)
        n = envs[True].num_agents
        actions = np.random.default_rng(0).uniform(-1, 1, (args.steps, n, 2)).astype(np.float32)
        cpu: dict[bool, list[float]] = {True: [], False: []}
        wall: dict[bool, list[float]] = {True: [], False: []}
        for flag in (True, False):  # warm-up
            use_compiled_kernels(flag)
            _loop(envs[flag], actions[:100], 0)
        for r in range(args.repeats):
            for flag in (True, False):
                use_compiled_kernels(flag)
                c, w = _loop(envs[flag], actions, r)
                cpu[flag].append(c)
                wall[flag].append(w)
        use_compiled_kernels(True)
        for flag, name in ((True, "compiled"), (False, "numpy")):
            print(f"{label:<22} {name:<10} {statistics.median(cpu[flag]):>12.0f} {statistics.median(wall[flag]):>13.0f}")
        print(f"{label:<22} {'ratio':<10} {statistics.median(cpu[False]) / statistics.median(cpu[True]):>11.2f}x "
              f"{statistics.median(wall[False]) / statistics.median(wall[True]):>12.2f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
