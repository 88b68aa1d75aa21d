"""How long formation switches take against their reach bound (docs/benchmark.md, "Switches that can be reached").

For each world of a generator family (or plain ``random``), one episode of a policy; for each switch: the new
shape, the time until the next switch (or the end), the reach lower bound
(:func:`swarm_env.scenarios.generator.switch_reach_times`) and the settle time the episode measured.

.. code-block:: console

    python benchmarks/switch_reach.py --scenario random:switching --policy vo --seeds 2000-2007
    python benchmarks/switch_reach.py --scenario random --policy vo --seeds 1000-1049     # the leaderboard's worlds
    python benchmarks/switch_reach.py --scenario random:switching --env switch_reach=null  # without the knob
"""

from __future__ import annotations

import argparse

from swarm_env.env import SwarmEnv
from swarm_env.harness.cli import parse_env_items
from swarm_env.harness.episode import run_episode
from swarm_env.harness.leaderboard import parse_seeds
from swarm_env.harness.policies import load_policy
from swarm_env.scenarios.generator import switch_reach_times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="random:switching")
    parser.add_argument("--policy", default="vo")
    parser.add_argument("--seeds", default="2000-2007", help="outside the suites' test seeds by default")
    parser.add_argument("--env", action="append", default=[], metavar="KEY=VALUE", help="generator knobs")
    args = parser.parse_args()
    env = SwarmEnv(args.scenario, **dict(parse_env_items(args.env)))
    policy = load_policy(args.policy, env)
    ratios: list[float] = []
    unsettled = unreachable = tight = switches = 0
    print("seed | shape | until next (s) | reach bound (s) | settled after (s) | settle / bound")
    for seed in parse_seeds(args.seeds):
        result = run_episode(env, policy, seed=seed)
        scn = env.scenario
        bounds = switch_reach_times(scn)
        ends = [f.at for f in scn.formations[1:]] + [scn.world.max_time]
        for k, entry in enumerate(result["settle_times"]):
            gap, bound, settle = ends[k + 1] - ends[k], bounds[k], entry["settle_time"]
            switches += 1
            unreachable += gap < bound
            tight += gap < 2.0 * bound
            if settle is None:
                unsettled += 1
            elif bound > 0.5:  # ratios of near-zero bounds say nothing
                ratios.append(settle / bound)
            ratio = "" if settle is None or bound <= 0.5 else f"{settle / bound:.1f}"
            print(f"{seed} | {entry['shape']} | {gap:.1f} | {bound:.1f} | {settle} | {ratio}")
    span = f"{min(ratios):.1f}-{max(ratios):.1f}" if ratios else "-"
    print(f"{switches} switches: {unsettled} never settled, {unreachable} sooner than their bound (the next switch or "
          f"the end), {tight} sooner than twice it; "
          f"settled ones took {span} times their bound")


if __name__ == "__main__":
    main()
