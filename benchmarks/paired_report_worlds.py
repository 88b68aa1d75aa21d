"""Two policies on the VO report's random worlds, paired by world (docs/vo_defaults.md, "``reverse=0.5``").

The worlds of ``swarm-env reproduce vo`` (``agents/vo_paper.py``): ``SwarmEnv("random", n_followers=(2, 8),
n_humans=(0, 3), team_seed=seed)``, one episode per seed, optionally with reacting humans. ``swarm-env evaluate``
cannot draw a team per episode (``team_seed`` is an env option), hence this script. Prints, per policy, the
episodes with a contact and the mean formation error, then the paired difference of contacts per episode.

.. code-block:: console

    python benchmarks/paired_report_worlds.py vo vo:reverse=0 --seeds 0-299 --human-behavior social_force
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import statistics
from typing import Any

from swarm_env.harness.leaderboard import parse_seeds


def _episode(job: tuple[str, int, str | None]) -> tuple[str, int, int, float]:
    from swarm_env.env import SwarmEnv
    from swarm_env.harness.episode import run_episode
    from swarm_env.harness.policies import load_policy

    spec, seed, behavior = job
    knobs: dict[str, Any] = {"n_followers": (2, 8), "n_humans": (0, 3)}
    if behavior:
        knobs["human_behavior"] = behavior
    env = SwarmEnv("random", team_seed=seed, **knobs)
    result = run_episode(env, load_policy(spec, env), seed=seed)
    return spec, seed, int(result["collisions"]["total"]), float(result["formation_error"]["mean"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("policies", nargs=2, metavar="SPEC", help="the policy and its baseline")
    parser.add_argument("--seeds", default="0-299")
    parser.add_argument("--human-behavior", default=None, help="e.g. social_force or orca (default: scripted)")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    seeds = parse_seeds(args.seeds)
    jobs = [(spec, seed, args.human_behavior) for seed in seeds for spec in args.policies]
    with mp.get_context("spawn").Pool(args.workers) as pool:
        results = pool.map(_episode, jobs, chunksize=4)
    by = {spec: {seed: (c, fe) for s, seed, c, fe in results if s == spec} for spec in args.policies}
    for spec in args.policies:
        bad = sorted(seed for seed, (c, _) in by[spec].items() if c)
        fe = statistics.mean(fe for _, fe in by[spec].values())
        print(f"{spec}: {len(bad)} of {len(seeds)} episodes with a contact {bad}; formation error {fe:.4f} m")
    a, b = args.policies
    diff = [by[a][s][0] - by[b][s][0] for s in seeds]
    half = 1.96 * statistics.stdev(diff) / len(diff) ** 0.5 if len(diff) > 1 else float("nan")
    print(f"{a} - {b}: contacts per episode {statistics.mean(diff):+.3f} ± {half:.3f} (paired, 95 %, n = {len(diff)})")


if __name__ == "__main__":
    main()
