"""Benchmark suites: scenario families x fixed seeds with train / validation / test splits, and their scores.

A :class:`Suite` names families (:mod:`swarm_env.scenarios.families`) and the seeds of each split; it has a
version, bumped whenever a family's knobs, the generator or the seeds change, so that a score can cite
``standard/3``. :func:`run_suite` plays policies on one split through the leaderboard
(:func:`~swarm_env.harness.leaderboard.run_leaderboard`: the same episodes, workers, faults and
``--resume``) and :func:`suite_result` turns the board into one table per family and an aggregate.

.. code-block:: console

    swarm-env evaluate --suite standard --policies vo cbs_rrt --workers 2 --out results/standard
    swarm-env evaluate --suite quick --policies my_policy --out q          # a minute or two

Splits (the protocol, docs/benchmark.md): **train** on any seed outside the reserved blocks
:data:`VALIDATION_BLOCK` and :data:`TEST_BLOCK` (``SwarmEnv("random:<family>").reset(seed=s)``); **tune**
and select on the suite's validation seeds; **report** the test split once, after all tuning. A fixed family
(the paper scenarios, the corridor) is deterministic: its seeds differ only for stochastic policies.

The result (``suite.json``, :data:`RESULT_FORMAT`) holds, per policy and family, the mean ± 95 % CI of the
collision rate (the share of episodes with any contact), collisions per episode, formation error, success
and the hold fraction after settling, and per policy the aggregate: the unweighted mean over families of
each metric, and the number of families with no collision at all.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any

from swarm_env.checks import DefaultsHelpFormatter
from swarm_env.harness.evaluation import mean_ci95
from swarm_env.harness.leaderboard import Leaderboard, Metric, aggregate_training_seeds, format_seeds, run_leaderboard
from swarm_env.harness.provenance import provenance_line
from swarm_env.jsonio import write_json
from swarm_env.scenarios.families import FAMILIES

#: ``suite.json``'s format tag.
RESULT_FORMAT = "swarm_env.suite_result/1"
#: The splits a suite defines seeds for (train is a rule, not a list: see :data:`TRAIN_RULE`).
SPLITS = ("validation", "test")
#: Seeds reserved for validation (every suite's validation seeds lie here).
VALIDATION_BLOCK = range(500, 1000)
#: Seeds reserved for testing (every suite's test seeds lie here; the rest of the block is kept unseen).
TEST_BLOCK = range(1000, 2000)
TRAIN_RULE = (f"any seed outside {VALIDATION_BLOCK.start}-{VALIDATION_BLOCK.stop - 1} (validation) and "
              f"{TEST_BLOCK.start}-{TEST_BLOCK.stop - 1} (test)")


#: The suite's columns (per episode: any contact, contacts, mean distance to the slot, success, hold fraction).
METRICS: tuple[Metric, ...] = (
    Metric("collision_rate", "collision rate", 2),
    Metric("collisions", "collisions / ep", 2),
    Metric("formation_error", "formation error (m)", 3),
    Metric("success_rate", "success", 2),
    Metric("hold_fraction", "held after settling", 2),
)


@dataclass(frozen=True)
class Suite:
    """Families and the seeds of each split.

    Attributes:
        name, version: what a score cites (``standard/3``).
        description: one sentence.
        families: names in :data:`~swarm_env.scenarios.families.FAMILIES`, in table order.
        validation, test: the seeds of a generator family's worlds in each split.
        fixed_seeds: the seeds of a fixed family's scenarios (any split: they are deterministic).
        env_kwargs: the env options every episode uses.
    """

    name: str
    version: int
    description: str
    families: tuple[str, ...]
    validation: tuple[int, ...]
    test: tuple[int, ...]
    fixed_seeds: tuple[int, ...] = (0, 1, 2)
    env_kwargs: Mapping[str, Any] = field(default_factory=lambda: {"action_type": "continuous"})

    def __post_init__(self) -> None:
        unknown = [f for f in self.families if f not in FAMILIES]
        if unknown:
            raise ValueError(f"suite {self.name!r}: unknown families {unknown}; known: {list(FAMILIES)}")
        for split, block in (("validation", VALIDATION_BLOCK), ("test", TEST_BLOCK)):
            seeds = getattr(self, split)
            if not seeds or any(s not in block for s in seeds):
                raise ValueError(f"suite {self.name!r}: {split} seeds must be non-empty and in "
                                 f"{block.start}-{block.stop - 1}")
        object.__setattr__(self, "env_kwargs", MappingProxyType(dict(self.env_kwargs)))

    @property
    def label(self) -> str:
        """``name/version``."""
        return f"{self.name}/{self.version}"

    def scenarios(self) -> list[str]:
        """Every scenario the suite plays, family by family."""
        return [s for f in self.families for s in FAMILIES[f].scenario_names]

    def seeds(self, split: str) -> dict[str, list[int]]:
        """Scenario -> seeds of ``split`` (``validation`` or ``test``)."""
        if split not in SPLITS:
            raise ValueError(f"split must be one of {SPLITS} (train: {TRAIN_RULE}), got {split!r}")
        out: dict[str, list[int]] = {}
        for name in self.families:
            family = FAMILIES[name]
            for scenario in family.scenario_names:
                out[scenario] = list(getattr(self, split) if family.generated else self.fixed_seeds)
        return out

    def key(self, split: str) -> dict[str, Any]:
        """What a sweep directory stores of the suite (``sweep.json``): the name, version and split, which with the
        scenarios and seeds define its episodes (the descriptions and difficulties do not)."""
        return {"name": self.name, "version": self.version, "split": split}

    def spec(self, split: str) -> dict[str, Any]:
        """What ``suite.json`` records of the suite: enough to cite and to rerun it."""
        return {**self.key(split), "description": self.description,
                "train": TRAIN_RULE,
                "families": {f: {"difficulty": FAMILIES[f].difficulty, "description": FAMILIES[f].description,
                                 "scenarios": list(FAMILIES[f].scenario_names), "knobs": dict(FAMILIES[f].knobs)}
                             for f in self.families}}


_ALL = tuple(FAMILIES)

#: The suites, by name.
SUITES: Mapping[str, Suite] = MappingProxyType({s.name: s for s in (
    Suite("standard", 3, "every family, 20 test worlds each (the paper scenarios and the corridor at seeds 0-2)",
          _ALL, validation=tuple(range(500, 520)), test=tuple(range(1000, 1020))),
    Suite("quick", 1, "a smoke test for CI: six families, two test worlds each, the fixed ones at seed 0",
          ("open", "cluttered", "crowd", "switching", "robot_leader", "paper"),
          validation=(500,), test=(1000, 1001), fixed_seeds=(0,)),
)})


def get_suite(name: str) -> Suite:
    """The suite called ``name``, or a ``ValueError`` listing the known ones."""
    if name not in SUITES:
        raise ValueError(f"unknown suite {name!r}; known suites: {', '.join(SUITES)}")
    return SUITES[name]


def run_suite(policies: list[str], suite: Suite, split: str = "test", **leaderboard_kwargs: Any) -> Leaderboard:
    """Play ``policies`` on ``split`` of ``suite``: :func:`~swarm_env.harness.leaderboard.run_leaderboard` with the
    suite's scenarios, seeds and env options (``workers``, ``out_dir``, ``resume``, ... pass through)."""
    return run_leaderboard(policies, suite.scenarios(), suite.seeds(split), env_kwargs=dict(suite.env_kwargs),
                           suite=suite.key(split), **leaderboard_kwargs)


# --------------------------------------------------------------------------- scoring
def _episode_values(metrics: Mapping[str, Any]) -> dict[str, float | None]:
    holds = [s.get("hold_fraction") for s in metrics["settle_times"] if s.get("hold_fraction") is not None]
    return {
        "collision_rate": float(metrics["collisions"]["total"] > 0),
        "collisions": float(metrics["collisions"]["total"]),
        "formation_error": float(metrics["formation_error"]["mean"]),
        "success_rate": float(metrics["success"]),
        "hold_fraction": float(sum(holds) / len(holds)) if holds else None,
    }


def _pooled(episodes: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Mean ± 95 % normal half-width over episodes (hold fraction over the episodes with a settled switch)."""
    values = [_episode_values(e) for e in episodes]
    out: dict[str, Any] = {"episodes": len(episodes)}
    for m in METRICS:
        out[m.key] = mean_ci95(v[m.key] for v in values if v[m.key] is not None)
    return out


def suite_result(board: Leaderboard, suite: Suite, split: str) -> dict[str, Any]:
    """The suite's scores from a board of :func:`run_suite` (``suite.json``; see the module docstring).

    Per policy (a learned method: over its training seeds) and family: the metrics of :data:`METRICS` pooled
    over the family's episodes; a policy that refused one of a family's scenarios gets ``status`` ``n/a``
    there. Aggregate per policy: each metric's unweighted mean over the families it played, and how many
    families it played without any collision."""
    members: dict[str, list[str]] = {}
    for row in board.rows:
        if row.members is not None:
            members[row.policy] = list(row.members)
    refused = {(r.policy, r.scenario): r.na_reason for r in board.rows if r.na_reason is not None}
    by_key: dict[tuple[str, str], list[Mapping[str, Any]]] = {}
    for e in board.episodes:
        by_key.setdefault((e["policy"], e["scenario"]), []).append(e["metrics"])

    results: list[dict[str, Any]] = []
    aggregate: list[dict[str, Any]] = []
    for policy in board.policies:
        played = members.get(policy, [policy])
        family_rows: list[dict[str, Any]] = []
        for fname in suite.families:
            scenarios = FAMILIES[fname].scenario_names
            reasons = [refused[(p, s)] for p in [policy, *played] for s in scenarios if (p, s) in refused]
            if reasons:
                family_rows.append({"policy": policy, "family": fname, "status": "n/a", "na_reason": reasons[0]})
                continue
            per_seed = [_pooled([m for s in scenarios for m in by_key.get((p, s), [])]) for p in played]
            per_seed = [s for s in per_seed if s["episodes"]]
            if not per_seed:
                family_rows.append({"policy": policy, "family": fname, "status": "pending"})
                continue
            summary = per_seed[0] if len(played) == 1 else aggregate_training_seeds(per_seed, METRICS)
            family_rows.append({"policy": policy, "family": fname, "status": "ok", "summary": summary})
        results.extend(family_rows)
        ok = [r["summary"] for r in family_rows if r["status"] == "ok"]
        agg: dict[str, Any] = {"policy": policy, "families": len(ok), "of": len(suite.families),
                               "collision_free_families": sum(1 for s in ok if s["collisions"]["mean"] == 0)}
        for m in METRICS:
            vals = [s[m.key]["mean"] for s in ok if s[m.key]["mean"] is not None]
            agg[m.key] = sum(vals) / len(vals) if vals else None
        aggregate.append(agg)
    spec = suite.spec(split)
    return {"format": RESULT_FORMAT, "suite": spec, "seeds": {s: board.seeds[s] for s in board.scenarios},
            "env_kwargs": dict(board.env_kwargs), "policies": list(board.policies), "results": results,
            "aggregate": aggregate, **({"provenance": board.provenance} if board.provenance else {})}


def _cell(stat: Mapping[str, Any] | None, digits: int) -> str:
    if not stat or stat.get("mean") is None:
        return "–"
    if stat["n"] == 1 or stat.get("ci95") is None or not math.isfinite(stat["ci95"]):
        return f"{stat['mean']:.{digits}f}"
    return f"{stat['mean']:.{digits}f} ± {stat['ci95']:.{digits}f}"


def result_markdown(result: Mapping[str, Any]) -> str:
    """The Markdown of a ``suite.json``: the aggregate table, then one table per family."""
    spec = result["suite"]
    lines = [f"# Suite `{spec['name']}/{spec['version']}`, {spec['split']} split", "",
             *([provenance_line(result["provenance"]), ""] if result.get("provenance") else []),
             f"{spec['description']}. Each cell: mean ± 95 % half-width over the family's episodes (a learned method "
             "with k training seeds: across its seeds, Student-t). Collision rate = share of episodes with any "
             "contact.", "", "## Aggregate (unweighted mean over families)", "",
             "| policy | families | collision-free families | " + " | ".join(m.label for m in METRICS) + " |",
             "|---|---:|---:|" + "---:|" * len(METRICS)]
    for a in result["aggregate"]:
        vals = " | ".join("–" if a[m.key] is None else f"{a[m.key]:.{m.digits}f}" for m in METRICS)
        lines.append(f"| `{a['policy']}` | {a['families']}/{a['of']} | {a['collision_free_families']} | {vals} |")
    for fname, fam in spec["families"].items():
        seeds = sorted({s for sc in fam["scenarios"] for s in result["seeds"][sc]})
        lines += ["", f"## {fname} ({fam['difficulty']}): {fam['description']}", "",
                  f"Scenarios {', '.join(f'`{s}`' for s in fam['scenarios'])}; seeds {format_seeds(seeds)}.", "",
                  "| policy | episodes | " + " | ".join(m.label for m in METRICS) + " |",
                  "|---|---:|" + "---:|" * len(METRICS)]
        for r in result["results"]:
            if r["family"] != fname:
                continue
            if r["status"] != "ok":
                lines.append(f"| `{r['policy']}` | {r['status']}{': ' + r['na_reason'] if r.get('na_reason') else ''} |"
                             + " |" * len(METRICS))
                continue
            s = r["summary"]
            n = f"{s['episodes']} ({s['training_seeds']} seeds)" if "training_seeds" in s else str(s["episodes"])
            lines.append(f"| `{r['policy']}` | {n} | " + " | ".join(_cell(s[m.key], m.digits) for m in METRICS) + " |")
    return "\n".join(lines) + "\n"



# --------------------------------------------------------------------------- regressions
#: ``collisions.json``'s format tag: collisions per policy, scenario and seed of a reference run.
COLLISIONS_FORMAT = "swarm_env.suite_collisions/1"


def collision_record(board_doc: Mapping[str, Any]) -> dict[str, Any]:
    """``{"format", "collisions": {policy: {scenario: {seed: collisions}}}}`` of a leaderboard's JSON."""
    table: dict[str, dict[str, dict[str, int]]] = {}
    for e in board_doc["episodes"]:
        table.setdefault(e["policy"], {}).setdefault(e["scenario"], {})[str(e["seed"])] = int(e["metrics"]["collisions"]["total"])
    return {"format": COLLISIONS_FORMAT, "collisions": table}


def new_collisions(board_doc: Mapping[str, Any], reference: Mapping[str, Any]) -> list[str]:
    """One line per episode of ``board_doc`` with more collisions than the same policy, scenario and seed had in
    ``reference`` (:func:`collision_record`); an episode the reference lacks is compared with zero."""
    if reference.get("format") != COLLISIONS_FORMAT:
        raise ValueError(f"format: expected {COLLISIONS_FORMAT!r}, got {reference.get('format')!r}")
    before = reference["collisions"]
    lines = []
    for policy, scenarios in collision_record(board_doc)["collisions"].items():
        for scenario, seeds in scenarios.items():
            for seed, n in seeds.items():
                was = before.get(policy, {}).get(scenario, {}).get(seed, 0)
                if n > was:
                    lines.append(f"{policy} on {scenario} seed {seed}: {n} collisions (was {was})")
    return lines


def main(argv: list[str] | None = None) -> int:
    """``python -m swarm_env.harness.suite check DIR --against FILE [--write]``: exit 1 listing every episode of the
    sweep in ``DIR`` with a collision ``FILE`` does not hold; ``--write`` stores ``DIR``'s collisions as ``FILE``."""
    parser = argparse.ArgumentParser(formatter_class=DefaultsHelpFormatter, prog="python -m swarm_env.harness.suite",
                                     description="Fail on collisions a reference run of a suite did not have.")
    parser.add_argument("command", choices=["check"])
    parser.add_argument("directory", help="an 'evaluate --suite ... --out DIR' directory (its leaderboard.json)")
    parser.add_argument("--against", required=True, help="the reference collisions (JSON, " + COLLISIONS_FORMAT + ")")
    parser.add_argument("--write", action="store_true", help="store DIR's collisions as the reference instead")
    args = parser.parse_args(argv)
    board_path = Path(args.directory) / "leaderboard.json"
    try:
        doc = json.loads(board_path.read_text())
        if args.write:
            print(f"wrote {write_json(args.against, collision_record(doc), indent=1)}")
            return 0
        lines = new_collisions(doc, json.loads(Path(args.against).read_text()))
    except (OSError, ValueError, KeyError, TypeError) as exc:
        print(f"error: {board_path} / {args.against}: {exc}", file=sys.stderr)
        return 2
    for line in lines:
        print(f"new collision: {line}")
    print(f"{len(lines)} episode(s) with new collisions" if lines else "no new collisions", file=sys.stderr)
    return 1 if lines else 0


if __name__ == "__main__":
    raise SystemExit(main())
