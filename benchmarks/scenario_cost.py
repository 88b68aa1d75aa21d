"""What a scenario's obstacle vertices cost a step (the measurement behind ``swarm_env.limits.MAX_OBSTACLE_VERTICES``).

A ``random:large_64`` world (64 followers) is given ``N`` round polygons of ``V`` vertices spread over the world on a
grid, ``--rays`` lidar rays, ``--substeps`` physics substeps; the env steps with zero actions (and, with
``--policy``, the policy acts too) and the script prints the median wall and CPU time per step over ``--repeats``
rounds, for each ``N`` given. Scenarios over the bound are built past the loader (``validate_scenario`` would refuse
them: the bound is lifted in this process only), so that the cost the bound prevents can be measured.

.. code-block:: console

    OPENBLAS_NUM_THREADS=1 python benchmarks/scenario_cost.py --polygons 32 256 --vertices 64 --rays 360 --substeps 100
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import time

import numpy as np

from swarm_env import limits
from swarm_env.env import SwarmEnv
from swarm_env.scenario import PolygonObstacle, Scenario
from swarm_env.scenarios.families import generator_config
from swarm_env.scenarios.generator import random_scenario
from swarm_env.scenarios.loader import obstacle_vertices


def scenario(n_polygons: int, vertices: int, rays: int, substeps: int) -> Scenario:
    """The ``random:large_64`` world of seed 3 with its obstacles replaced by ``n_polygons`` polygons (radius 0.1 m)."""
    base = random_scenario(np.random.default_rng(3), generator_config("random:large_64", {}))
    width, height = base.world.size
    side = int(np.ceil(np.sqrt(max(n_polygons, 1))))
    angles = np.linspace(0.0, 2.0 * np.pi, vertices + 1)[:-1]
    polygons = tuple(
        PolygonObstacle(points=tuple((float(cx + 0.1 * np.cos(a)), float(cy + 0.1 * np.sin(a))) for a in angles))
        for i in range(n_polygons)
        for cx, cy in [(0.5 + (i % side) * (width - 1) / side, 0.5 + (i // side) * (height - 1) / side)]
    )
    return dataclasses.replace(base, obstacles=polygons, world=dataclasses.replace(base.world, substeps=substeps),
                               sensors=dataclasses.replace(base.sensors, lidar_rays=rays))


def per_step(scn: Scenario, steps: int, policy: str | None) -> tuple[float, float]:
    """Wall and CPU seconds per step (after one warm-up step)."""
    env = SwarmEnv(scn)
    observations, _ = env.reset(seed=0)
    act = None
    if policy is not None:
        from swarm_env.harness.policies import load_policy

        act = load_policy(policy, env)
        act.reset(env, 0)
    zero = {a: np.zeros(2, np.float32) for a in env.agents}

    def step() -> None:
        nonlocal observations
        actions = zero if act is None else act.act(observations, env.world_state())
        observations = env.step(actions)[0]

    step()
    wall, cpu = time.perf_counter(), time.process_time()
    for _ in range(steps):
        step()
    return (time.perf_counter() - wall) / steps, (time.process_time() - cpu) / steps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--polygons", type=int, nargs="+", default=[32, 256])
    parser.add_argument("--vertices", type=int, default=64)
    parser.add_argument("--rays", type=int, default=360)
    parser.add_argument("--substeps", type=int, default=100)
    parser.add_argument("--steps", type=int, default=5)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--policy", default=None, help="a policy spec acting each step (default: zero actions)")
    args = parser.parse_args()
    # lifted here only, to measure what the bound prevents (the loader reads its bounds from this table)
    limits.LIMITS["MAX_OBSTACLE_VERTICES"] = (10**9, "lifted by benchmarks/scenario_cost.py")
    results: dict[int, list[tuple[float, float]]] = {n: [] for n in args.polygons}
    for _ in range(args.repeats):  # interleaved: every size in each round
        for n in args.polygons:
            results[n].append(per_step(scenario(n, args.vertices, args.rays, args.substeps), args.steps, args.policy))
    print("| polygons | vertices in all | wall s/step (median) | CPU s/step (median) |")
    print("|---:|---:|---:|---:|")
    for n, rows in results.items():
        verts = obstacle_vertices(scenario(n, args.vertices, args.rays, args.substeps))
        print(f"| {n} | {verts:,} | {statistics.median(r[0] for r in rows):.4f} | "
              f"{statistics.median(r[1] for r in rows):.4f} |")


if __name__ == "__main__":
    main()
