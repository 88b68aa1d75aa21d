"""Benchmark: the VO expert's ``act()`` for all followers, next to one ``env.step``.

    OPENBLAS_NUM_THREADS=1 python benchmarks/vo_act.py      # paper_cbs_switch (8 followers), paper_vo_0 (2)
    python benchmarks/vo_act.py --repeat 5 --scenarios paper_vo_90

Per scenario one seeded episode is played with the expert (``VOExpert()``,
default parameters), timing every ``env.step`` of it. Every state the expert
was shown is kept and ``act()`` is then timed on each of them ``--repeat``
times; the median over the repeats is kept per state (it drops scheduler
noise). Reported over the states: median, p95 and max of ``act()`` and median
and p95 of ``env.step`` (the peer: the cost of simulating one step), in
microseconds, plus how often every follower's preferred twist was safe (the
fast path). Timings are of this machine and this run: compare numbers from the
same run only. ``act()`` runs compiled (:mod:`swarm_env.control.vo_kernel`: the pure
pursuit and the search); the numpy reference (``compiled_mode(search=False)``,
same actions) is timed on the same states, interleaved with it, as its peer
("reference CPU median" and the ratio, the figure to compare on a loaded machine).
"""

from __future__ import annotations

import argparse
import platform
import time

import numpy as np

from swarm_env.compiled import compiled_mode
from swarm_env.control.safety import safe_follower_twists
from swarm_env.env import SwarmEnv
from swarm_env_agents.vo_expert import VOExpert

SCENARIOS = ("paper_cbs_switch", "paper_vo_0")


def bench(scenario: str, repeat: int) -> dict[str, float]:
    env = SwarmEnv(scenario)
    policy = VOExpert()
    obs, _ = env.reset(seed=0)
    policy.reset(env, 0)
    states, observations, step_us = [], [], []
    while env.agents:
        st = env.world_state()
        action = policy.act(obs, st)
        states.append(st)
        observations.append(obs)
        t0 = time.perf_counter()
        obs, *_ = env.step(action)
        step_us.append((time.perf_counter() - t0) * 1e6)
    env.close()
    act_us = np.empty((repeat, len(states)))
    act_cpu_us = np.empty((repeat, len(states)))
    ref_cpu_us = np.empty((repeat, len(states)))
    for r in range(repeat):
        for k, (st, ob) in enumerate(zip(states, observations)):
            with compiled_mode(search=False):
                c0 = time.process_time()
                policy.act(ob, st)
                ref_cpu_us[r, k] = (time.process_time() - c0) * 1e6
            t0, c0 = time.perf_counter(), time.process_time()
            policy.act(ob, st)
            act_us[r, k] = (time.perf_counter() - t0) * 1e6
            act_cpu_us[r, k] = (time.process_time() - c0) * 1e6
    per_state = np.median(act_us, axis=0)
    cpu_per_state = np.median(act_cpu_us, axis=0)
    ref_per_state = np.median(ref_cpu_us, axis=0)
    all_fast = np.mean([bool(np.all(_fast(policy, st))) for st in states])
    return {
        "followers": states[0].n_followers,
        "states": len(states),
        "act_median_us": float(np.median(per_state)),
        "act_p95_us": float(np.percentile(per_state, 95)),
        "act_max_us": float(per_state.max()),
        "act_cpu_median_us": float(np.median(cpu_per_state)),
        "ref_cpu_median_us": float(np.median(ref_per_state)),
        "step_median_us": float(np.median(step_us)),
        "step_p95_us": float(np.percentile(step_us, 95)),
        "all_fast": float(all_fast),
    }


def _fast(policy: VOExpert, state) -> np.ndarray:
    """Which followers' preferred twists were safe (the batch's fast path) in ``state``."""
    return safe_follower_twists(state, policy.preferred_twists(state), policy.avoidance).fast


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=3, help="timings of act() per state (median kept)")
    ap.add_argument("--scenarios", nargs="*", default=list(SCENARIOS))
    args = ap.parse_args()
    print(f"python {platform.python_version()}, numpy {np.__version__}, {platform.machine()}")
    print(f"{'scenario':<18} {'N':>2} {'states':>6}  {'act median':>10} {'p95':>6} {'max':>6} {'CPU median':>10}"
          f"  {'reference CPU median':>20} {'ratio':>5}  {'env.step median':>15} {'p95':>6}  {'all-fast states':>15}")
    for name in args.scenarios:
        r = bench(name, args.repeat)
        print(
            f"{name:<18} {r['followers']:>2} {r['states']:>6}  {r['act_median_us']:>10.0f} {r['act_p95_us']:>6.0f} "
            f"{r['act_max_us']:>6.0f} {r['act_cpu_median_us']:>10.0f}  {r['ref_cpu_median_us']:>20.0f} "
            f"{r['ref_cpu_median_us'] / r['act_cpu_median_us']:>5.1f}  {r['step_median_us']:>15.0f} {r['step_p95_us']:>6.0f}  {100 * r['all_fast']:>14.0f}%"
        )
    print("(microseconds; act() is the whole policy call for all followers, telemetry included)")


if __name__ == "__main__":
    main()
