"""Planning-time benchmark of the CBS + motion-primitive RRT expert (paper 000, issue 4).

    python benchmarks/cbs_rrt_bench.py                 # paper scenario + scaling, a few minutes
    python benchmarks/cbs_rrt_bench.py --quick         # fewer seeds
    python benchmarks/cbs_rrt_bench.py --json out.json
    python benchmarks/cbs_rrt_bench.py --quick --plot docs/cbs_rrt/scaling.png   # the report's scaling figure

Part 1 plays ``paper_cbs_switch`` (8 followers, 10 obstacles, V -> grid at t = 80 s)
for several seeds and prints, per seed and as medians over seeds: the total planning
time of the whole episode (wall seconds spent in planning), per-replan time (median,
p95, max), the same in CPU time of the process (``CPU s``, ``CPU p95``: what a shared
machine inflates least; issue 12's targets are CPU figures), the number of replans, the real-time factor (simulated seconds per wall
second: of the whole episode, env stepping included, and of the planner alone),
collisions, the settle time after the switch and the hold fraction after it. The paper's planner needed 300-360 s
per scenario. ``CPU s`` is the whole episode's planning: the CBS replans and the plans of a
reached formation (``hold_plan``: one per formation, about 0.7 s each, shown as ``hold s``); the
per-replan figures are the CBS replans' (the events of real-time replanning).

Part 2 measures how per-replan time (wall, and CPU: ``CPU med``, ``CPU p95``) grows with
the swarm: the ``random`` generator with 4, 8, 16 and 32 followers (no humans, a world
that grows with the swarm), a few seeds each.

Budgets are iteration counts, so the plans do not depend on the machine; only the
timings do. The machine may be shared: every figure is a median over seeds (and over
the replans of an episode).
"""

from __future__ import annotations

import argparse
import statistics
import time
from typing import Any

import swarm_env
from swarm_env.harness.episode import run_episode
from swarm_env.jsonio import dumps
from swarm_env_agents.cbs_rrt.policy import CBSRRTExpert


def episode(env: Any, seed: int, **kwargs: Any) -> dict[str, Any]:
    """One episode with a fresh expert; the timing figures of one row."""
    policy = CBSRRTExpert(**kwargs)
    t0 = time.perf_counter()
    result = run_episode(env, policy, seed)
    wall = time.perf_counter() - t0
    stats = result["policy_stats"]
    ms = stats["planning_time_ms"]
    cpu = stats["planning_cpu_ms"]
    planning = float(ms["total_s"]) + float(stats["hold_plan_s"])  # the CBS replans and the plans of the holds
    sim = float(result["sim_time"])
    return {
        "seed": seed,
        "sim_time_s": sim,
        "episode_wall_s": wall,
        "planning_total_s": planning,
        "replans": stats["replans"],
        "replan_ms_median": ms["median"],
        "replan_ms_p95": ms["p95"],
        "replan_ms_max": ms["max"],
        "planning_cpu_s": float(cpu["total_s"]) + float(stats["hold_plan_cpu_s"]),
        "hold_plans": stats["hold_plans"],
        "hold_plan_cpu_s": float(stats["hold_plan_cpu_s"]),
        "hold_fractions": [s["hold_fraction"] for s in result["settle_times"]],
        "replan_cpu_ms_median": cpu["median"],
        "replan_cpu_ms_p95": cpu["p95"],
        "replan_cpu_ms_max": cpu["max"],
        "rtf_episode": sim / wall,
        "rtf_planning": sim / max(planning, 1e-9),
        "collisions": result["collisions"]["total"],
        "settle_times": [s["settle_time"] for s in result["settle_times"]],
        "success": result["success"],
        "formation_error": result["formation_error"]["mean"],
        "cbs_nodes_expanded": stats["cbs_nodes_expanded"],
        "low_level_calls": stats["low_level_calls"],
        "rrt_iterations": stats["rrt_iterations"],
        "fallbacks": stats["fallbacks"],
        "shield_stops": stats["shield_stops"],
        "tracking_gap_max_m": stats["tracking_gap_m"]["max"],
    }


def _median(rows: list[dict[str, Any]], key: str) -> float:
    vals = [r[key] for r in rows if r[key] is not None]
    return float(statistics.median(vals)) if vals else float("nan")


def paper(seeds: list[int]) -> list[dict[str, Any]]:
    env = swarm_env.parallel_env("paper_cbs_switch")
    rows = []
    print("paper_cbs_switch: 8 followers, 10 obstacles, V -> 3-column grid at t = 80 s, 240 s")
    header = (
        f"{'seed':>4} {'plan total s':>12} {'replans':>7} {'med ms':>7} {'p95 ms':>7} {'max ms':>7} "
        f"{'RTF ep':>7} {'RTF plan':>8} {'coll':>4} {'settle s':>8} {'held':>5} {'CPU s':>6} {'hold s':>6} {'CPU p95':>7}"
    )
    print(header)
    for seed in seeds:
        r = episode(env, seed)
        rows.append(r)
        settle = r["settle_times"][0] if r["settle_times"] else None
        held = r["hold_fractions"][0] if r["hold_fractions"] and r["hold_fractions"][0] is not None else None
        print(
            f"{seed:>4} {r['planning_total_s']:>12.2f} {r['replans']:>7} {r['replan_ms_median']:>7.0f} "
            f"{r['replan_ms_p95']:>7.0f} {r['replan_ms_max']:>7.0f} {r['rtf_episode']:>7.1f} "
            f"{r['rtf_planning']:>8.1f} {r['collisions']:>4} {settle if settle is not None else 'never':>8} "
            f"{'-' if held is None else f'{held:.3f}':>5} {r['planning_cpu_s']:>6.2f} {r['hold_plan_cpu_s']:>6.2f} "
            f"{r['replan_cpu_ms_p95']:>7.0f}"
        )
    settles = [r["settle_times"][0] for r in rows if r["settle_times"] and r["settle_times"][0] is not None]
    print(
        f"median over {len(rows)} seeds: planning {_median(rows, 'planning_total_s'):.2f} s per episode "
        f"(paper: 300-360 s), per replan median {_median(rows, 'replan_ms_median'):.0f} ms, "
        f"p95 {_median(rows, 'replan_ms_p95'):.0f} ms, max {_median(rows, 'replan_ms_max'):.0f} ms; "
        f"real-time factor {_median(rows, 'rtf_episode'):.0f}x (episode), {_median(rows, 'rtf_planning'):.0f}x "
        f"(planner); collisions {sum(r['collisions'] for r in rows)} in total; settle after the switch "
        f"{statistics.median(settles) if settles else float('nan'):.1f} s median "
        f"({len(settles)}/{len(rows)} settled; paper: 87 s); CPU time: planning "
        f"{_median(rows, 'planning_cpu_s'):.2f} s per episode, per replan median "
        f"{_median(rows, 'replan_cpu_ms_median'):.0f} ms, p95 {_median(rows, 'replan_cpu_ms_p95'):.0f} ms"
    )
    return rows


SCALING = {4: (16.0, 16.0), 8: (20.0, 20.0), 16: (28.0, 28.0), 32: (40.0, 40.0)}


def scaling(seeds: list[int], sizes: dict[int, tuple[float, float]] = SCALING) -> list[dict[str, Any]]:
    print("\nrandom generator (no humans, virtual leader, 60 s): per-replan time against swarm size")
    print(
        f"{'N':>3} {'world':>9} {'replans':>7} {'med ms':>7} {'p95 ms':>7} {'max ms':>7} {'plan s':>7} {'coll':>4} "
        f"{'CPU med':>7} {'CPU p95':>7}"
    )
    out = []
    for n, world in sizes.items():
        env = swarm_env.parallel_env("random", n_followers=n, world_size=world, n_humans=0, max_time=60.0)
        rows = [episode(env, s) for s in seeds]
        row = {
            "n_followers": n,
            "world_size": list(world),
            "episodes": rows,
            "replans": _median(rows, "replans"),
            "replan_ms_median": _median(rows, "replan_ms_median"),
            "replan_ms_p95": _median(rows, "replan_ms_p95"),
            "replan_ms_max": _median(rows, "replan_ms_max"),
            "planning_total_s": _median(rows, "planning_total_s"),
            "replan_cpu_ms_median": _median(rows, "replan_cpu_ms_median"),
            "replan_cpu_ms_p95": _median(rows, "replan_cpu_ms_p95"),
            "collisions": sum(r["collisions"] for r in rows),
        }
        out.append(row)
        print(
            f"{n:>3} {world[0]:>4.0f}x{world[1]:<4.0f} {row['replans']:>7.0f} {row['replan_ms_median']:>7.0f} "
            f"{row['replan_ms_p95']:>7.0f} {row['replan_ms_max']:>7.0f} {row['planning_total_s']:>7.2f} "
            f"{row['collisions']:>4} {row['replan_cpu_ms_median']:>7.0f} {row['replan_cpu_ms_p95']:>7.0f}"
        )
    return out


# Issue 12's real-time targets (CPU ms per replan): (followers, statistic) -> bound.
TARGETS = {(8, "p95"): 100.0, (32, "median"): 100.0, (32, "p95"): 300.0}


def plot_scaling(rows: list[dict[str, Any]], path: str) -> None:
    """Per-replan CPU time (median and p95 over each size's seeds) against the swarm size, log-log, with the
    targets and a line of linear growth through the smallest swarm's median."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = [r["n_followers"] for r in rows]
    med = [r["replan_cpu_ms_median"] for r in rows]
    p95 = [r["replan_cpu_ms_p95"] for r in rows]
    fig, ax = plt.subplots(figsize=(6.0, 4.2))
    ax.plot(n, med, "o-", label="per-replan CPU time, median")
    ax.plot(n, p95, "s--", label="per-replan CPU time, p95")
    ax.plot(n, [med[0] * k / n[0] for k in n], ":", color="gray", label="linear growth (from the smallest swarm)")
    for (k, stat), bound in TARGETS.items():
        ax.plot([k], [bound], "v" if stat == "median" else "^", color="red", ms=9)
        ax.annotate(f"target {stat} <= {bound:.0f} ms", (k, bound), textcoords="offset points", xytext=(6, -3),
                    fontsize=8, color="red")
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    ax.set_xticks(n, [str(k) for k in n])
    ax.set_xlabel("followers")
    ax.set_ylabel("CPU time per replan (ms)")
    ax.set_title("cbs_rrt planning time against swarm size (random worlds, 60 s)", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=5, help="paper-scenario seeds (default 5)")
    parser.add_argument("--scaling-seeds", type=int, default=3, help="seeds per swarm size (default 3)")
    parser.add_argument("--quick", action="store_true", help="3 paper seeds, 1 seed per size")
    parser.add_argument("--no-scaling", action="store_true", help="skip part 2")
    parser.add_argument("--json", help="write all rows to this JSON file")
    parser.add_argument("--plot", help="write the scaling figure (part 2) to this image file (needs matplotlib)")
    args = parser.parse_args(argv)
    if args.plot and args.no_scaling:
        parser.error("--plot draws part 2: drop --no-scaling")
    n_paper, n_scale = (3, 1) if args.quick else (args.seeds, args.scaling_seeds)
    report: dict[str, Any] = {"paper_cbs_switch": paper(list(range(n_paper)))}
    if not args.no_scaling:
        report["scaling"] = scaling(list(range(n_scale)))
        if args.plot:
            plot_scaling(report["scaling"], args.plot)
    if args.json:
        with open(args.json, "w") as fh:
            fh.write(dumps(report, indent=1, default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
