"""What a generator family's worlds hold, and a digest of them to compare two versions of the generator.

For each family and seed range: how many worlds got how many gates (the ``narrow`` family), how many give the
formation back after their last gate, and a SHA-256 digest of the worlds (``scenario_to_dict`` as sorted JSON, ``swarm_env.jsonio.dumps``).
Run it at two commits: the same digest means the same worlds, bit for bit::

    python benchmarks/family_worlds.py --families narrow --seeds 0-99                          # gates per world
    python benchmarks/family_worlds.py --seeds 0-14 500-504 1000-1019                          # every family's digest
    python benchmarks/family_worlds.py --seeds 500-519 1000-1019 --per-world > A.txt           # one line per world

``--per-world`` prints each world's digest on its own line, so that ``diff`` of two commits' outputs names the worlds
that changed.
"""

from __future__ import annotations

import argparse
import collections
import hashlib

from swarm_env.env import SwarmEnv
from swarm_env.harness.leaderboard import parse_seeds
from swarm_env.jsonio import dumps
from swarm_env.scenarios.families import FAMILIES
from swarm_env.scenarios.loader import scenario_to_dict


def world_digests(family: str, seeds: list[int]) -> list[dict[str, object]]:
    """The digest of each of ``random:<family>``'s worlds at ``seeds``."""
    env = SwarmEnv(f"random:{family}")
    out: list[dict[str, object]] = []
    for seed in seeds:
        env.reset(seed=seed)
        text = dumps(scenario_to_dict(env.scenario), indent=None, sort_keys=True)
        out.append({"family": family, "seed": seed, "digest": hashlib.sha256(text.encode()).hexdigest()[:16]})
    env.close()
    return out


def family_worlds(family: str, seeds: list[int]) -> dict[str, object]:
    """The digest of ``random:<family>``'s worlds at ``seeds`` (as ``SwarmEnv.reset(seed=s)`` draws them), the
    count of worlds by number of gates, and how many end in the formation they started with."""
    env = SwarmEnv(f"random:{family}")
    digest = hashlib.sha256()
    gates: collections.Counter[int] = collections.Counter()
    released = 0
    for seed in seeds:
        env.reset(seed=seed)
        scn = env.scenario
        digest.update(dumps(scenario_to_dict(scn), indent=None, sort_keys=True).encode())
        if FAMILIES[family].knobs.get("n_gates"):
            columns = [f.shape == "column" for f in scn.formations]
            gates[int(scn.description.split(" gates")[0].rsplit(", ", 1)[-1])] += 1  # the description counts them
            released += int(any(columns) and not columns[-1])
    env.close()
    return {"family": family, "worlds": len(seeds), "digest": digest.hexdigest()[:16],
            **({"gates": dict(sorted(gates.items())), "formation_back": released} if gates else {})}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--families", nargs="+", default=[f.name for f in FAMILIES.values() if f.generated],
                    help="generator families (default: every one)")
    ap.add_argument("--seeds", nargs="+", default=["0-99"], help="seeds or ranges, e.g. 0-14 500-504")
    ap.add_argument("--per-world", action="store_true", help="one digest per world instead of one per family")
    args = ap.parse_args(argv)
    seeds = [s for spec in args.seeds for s in parse_seeds(spec)]
    for family in args.families:
        rows = world_digests(family, seeds) if args.per_world else [family_worlds(family, seeds)]
        for row in rows:
            print(dumps(row, indent=None))


if __name__ == "__main__":
    main()
