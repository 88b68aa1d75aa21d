"""Paired comparisons of two policies on the same episodes of a leaderboard (``leaderboard.json``).

.. code-block:: console

    python -m swarm_env.harness.paired docs/leaderboard/leaderboard.json.gz --baseline pursuit --scenario random:crowd

For every other policy it prints, per metric, the mean over the shared ``(scenario, seed)``
episodes of ``policy - baseline`` with its 95 % confidence half-width
(:func:`swarm_env.harness.evaluation.mean_ci95`: ``1.96 * s / sqrt(n)`` of the paired differences) and
whether that interval excludes zero. Pairing by seed removes the variance between worlds, which
is most of it: "fewer collisions than pursuit" is claimed only when the paired interval says so.
``--profile`` adds where each policy's collisions come from (:func:`collision_profile`).
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from swarm_env.checks import DefaultsHelpFormatter
from swarm_env.harness.evaluation import mean_ci95
from swarm_env.jsonio import read_json

#: Metric name -> how to read it from one episode's metrics.
METRICS = {
    "collisions": lambda m: m["collisions"]["total"],
    "formation_error": lambda m: m["formation_error"]["mean"],
    "success": lambda m: float(m["success"]),
}


def paired_differences(doc: dict[str, Any], policy: str, baseline: str, scenario: str | None = None) -> dict[str, dict]:
    """``{metric: {"mean", "ci95", "n", "excludes_zero"}}`` of ``policy - baseline`` over their shared episodes.

    A learned method with several training seeds (episodes carrying ``"method"``) is one policy here:
    its value on a world is the mean over its seeds' episodes on that world, so the interval is over
    worlds (the spread between training seeds is the leaderboard's method row). One seed of it is
    named as played (``"mappo:s1"``)."""
    by_key: dict[str, dict[tuple, list[dict]]] = {}
    for e in doc["episodes"]:
        if scenario is None or e["scenario"] == scenario:
            for who in {e["policy"], e.get("method") or e["policy"]}:
                by_key.setdefault(who, {}).setdefault((e["scenario"], e["seed"]), []).append(e["metrics"])
    if policy not in by_key or baseline not in by_key:
        raise ValueError(f"no episodes of {policy if policy not in by_key else baseline!r} in the leaderboard"
                         + (f" on {scenario!r}" if scenario else ""))
    shared = sorted(set(by_key[policy]) & set(by_key[baseline]))

    def value(who: str, key: tuple, read: Any) -> float:
        runs = by_key[who][key]
        return sum(read(m) for m in runs) / len(runs)

    out = {}
    for name, read in METRICS.items():
        diffs = [value(policy, k, read) - value(baseline, k, read) for k in shared]
        stats = mean_ci95(diffs)
        mean, half = stats["mean"], stats["ci95"]
        stats["excludes_zero"] = bool(mean is not None and half is not None and abs(mean) > half)
        out[name] = stats
    return out


#: The kinds of contact an episode's ``collisions`` block counts, in :func:`collision_profile`'s order.
CONTACT_KINDS = ("robot_robot", "robot_human", "robot_obstacle", "robot_wall")


def collision_profile(doc: dict[str, Any], policy: str, scenario: str | None = None) -> dict[str, Any]:
    """Where ``policy``'s collisions come from: ``{"n", "any_contact", KIND...}``, the share of its episodes with
    at least one collision (CrowdNav's collision rate) and the mean per episode of each of :data:`CONTACT_KINDS`.
    ``policy`` is a name as played (``mappo:s1``) or a learned method (every seed's episodes)."""
    episodes = [e["metrics"] for e in doc["episodes"] if (scenario is None or e["scenario"] == scenario)
                and policy in (e["policy"], e.get("method"))]
    if not episodes:
        raise ValueError(f"no episodes of {policy!r} in the leaderboard" + (f" on {scenario!r}" if scenario else ""))
    n = len(episodes)
    out: dict[str, Any] = {"n": n, "any_contact": sum(m["collisions"]["total"] > 0 for m in episodes) / n}
    for kind in CONTACT_KINDS:
        out[kind] = sum(m["collisions"].get(kind, 0) for m in episodes) / n
    return out


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m swarm_env.harness.paired``."""
    parser = argparse.ArgumentParser(formatter_class=DefaultsHelpFormatter, prog="python -m swarm_env.harness.paired", description=__doc__.splitlines()[0])
    parser.add_argument("leaderboard", help="a leaderboard.json written by swarm-env evaluate --out (or its gzip, .json.gz)")
    parser.add_argument("--baseline", default="pursuit", help="the policy every other one is compared with")
    parser.add_argument("--scenario", help="only this scenario's episodes (default: all)")
    parser.add_argument("--per-seed", action="store_true",
                        help="also one row per training seed of each learned method (e.g. mappo:s0)")
    parser.add_argument("--profile", action="store_true",
                        help="then where each policy's collisions come from: the share of episodes with any contact "
                             "and the collisions per episode by kind (robot, human, obstacle, wall)")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        doc = read_json(args.leaderboard)
        policies = []
        for p in doc["policies"]:
            seeds = sorted({e["policy"] for e in doc["episodes"] if e.get("method") == p}) if args.per_seed else []
            policies += [q for q in (p, *seeds) if q != args.baseline]
        print(f"paired differences (policy - {args.baseline}), mean ± 95 % CI" + (f", {args.scenario}" if args.scenario else ""))
        print("| policy | n | collisions / ep | formation error (m) | success |")
        print("|---|---:|---:|---:|---:|")
        for p in policies:
            d = paired_differences(doc, p, args.baseline, args.scenario)
            cells = [f"{d[m]['mean']:+.3f} ± {d[m]['ci95']:.3f}{' *' if d[m]['excludes_zero'] else ''}" for m in METRICS]
            print(f"| `{p}` | {d['collisions']['n']} | " + " | ".join(cells) + " |")
        print("(* the interval excludes zero)")
        if args.profile:
            print("\ncollision profile: share of episodes with any contact, collisions per episode by kind")
            print("| policy | n | any contact | " + " | ".join(k.replace("_", "-") for k in CONTACT_KINDS) + " |")
            print("|---|---:|---:|" + "---:|" * len(CONTACT_KINDS))
            for p in [args.baseline, *policies]:
                c = collision_profile(doc, p, args.scenario)
                print(f"| `{p}` | {c['n']} | {c['any_contact']:.2f} | " + " | ".join(f"{c[k]:.2f}" for k in CONTACT_KINDS)
                      + " |")
    except (OSError, ValueError, KeyError) as exc:
        print(f"error: {args.leaderboard}: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
