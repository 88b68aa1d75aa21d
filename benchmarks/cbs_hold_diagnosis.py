"""Why the CBS + RRT expert does not hold the formation after the switch (issue 12 item 1).

    python benchmarks/cbs_hold_diagnosis.py --seed 0
    python benchmarks/cbs_hold_diagnosis.py --seed 1 --policy-args lookahead_time=0.5 --from 120 --verbose

Plays ``paper_cbs_switch`` with :class:`CBSRRTExpert` (``--policy-args`` as for ``cbs_rrt:KEY=VALUE``)
and, for every step from the moment the grid is reached (or ``--from``), every follower farther
than ``world.settle_tolerance`` from its slot target is put down to one cause:

* ``course != slot``: the planner's goal course (its slot moved out of obstacles to the buffer
  clearance and pushed apart from the others) is more than 0.15 m from the env's slot target;
* ``plan not joined: <why>``: the robot's plan has not (re)joined its course yet; ``<why>`` is the
  replan that took the robot off its course — ``own course changed`` (its own course jumped: a
  leader turn, a slot flipping or sweeping round an obstacle) or ``dislodged`` (its course did not
  change: another robot's trigger replanned it), with that replan's triggers;
* ``plan != slot (joined)``: on its course but the plan is off the slot;
* ``tracking lag``: the robot is more than 0.15 m from its plan (pure pursuit lagging).

Also printed: the replans after settling by trigger, the shield stops, and the distances
robot-slot, robot-plan, plan-slot and course-slot (mean, p95, max). ``--verbose`` lists the
followers out of tolerance every second step.
"""

from __future__ import annotations

import argparse
from collections import Counter
from typing import Any

import numpy as np

from swarm_env.env import SwarmEnv
from swarm_env.harness.policies import parse_policy_kwargs
from swarm_env.scenarios.loader import load_scenario
from swarm_env_agents.cbs_rrt.policy import CBSRRTExpert

_NEAR = 0.15  # m: a plan/course this close to the slot is not the cause


def diagnose(seed: int, policy_args: dict[str, Any], t_from: float | None, verbose: bool) -> None:
    """Play one episode and print the causes (see the module docstring)."""
    env = SwarmEnv(load_scenario("paper_cbs_switch"))
    pol = CBSRRTExpert(**policy_args)
    obs, _ = env.reset(seed=seed)
    pol.reset(env, seed)
    tol = env.world_state().scenario.world.settle_tolerance
    rows: list[dict[str, Any]] = []
    why: dict[int, str] = {}
    while env.agents:
        st = env.world_state()
        t = st.time
        n_replans, n_stops = len(pol._times), pol._shield_stops
        was_on = None if pol.plans is None else [p.reached and p.goal_time <= t + 1e-9 for p in pol.plans]
        old_specs = pol._specs
        action = pol.act(obs, st)
        assert pol.plans is not None and pol._goals_now is not None
        replanned = len(pol._times) > n_replans
        if replanned and was_on is not None and pol.last is not None:
            for i, plan in enumerate(pol.plans):
                if was_on[i] and not plan.goal_time <= t + 1e-9:
                    old, new = old_specs[i], pol._specs[i]
                    sel = (new.t >= t) & (new.t <= old.t[-1])
                    own = not np.allclose(old.at(new.t[sel]), new.xy_eff[sel], atol=1e-6)
                    why[i] = f"{'own course changed' if own else 'dislodged'} ({'+'.join(pol.last.reasons)})"
        pose, slot = st.follower_pose[:, :2], st.slot_targets
        plan_xy = np.array([p.position_at(t) for p in pol.plans])
        course = np.array([pol._goals_now.at(i, t) for i in range(len(pose))])
        rows.append({
            "t": t, "form": st.formation_index, "err": np.hypot(*(pose - slot).T),
            "pose_plan": np.hypot(*(pose - plan_xy).T), "plan_slot": np.hypot(*(plan_xy - slot).T),
            "course_slot": np.hypot(*(course - slot).T),
            "joined": [p.reached and p.goal_time <= t + 1e-9 for p in pol.plans],
            "why": [why.get(i, "-") for i in range(len(pose))],
            "reasons": pol.last.reasons if replanned and pol.last is not None else (),
            "stops": pol._shield_stops - n_stops,
        })
        obs, *_ = env.step(action)
    result = env.episode_metrics()
    [settle] = result["settle_times"]
    print(f"seed {seed}: success {result['success']}, collisions {result['collisions']['total']}, "
          f"settled {settle['settle_time']} s after the switch, held {settle['hold_fraction']}")
    start = t_from if t_from is not None else (80.0 + settle["settle_time"] if settle["settle_time"] is not None else 80.0)
    after = [r for r in rows if r["t"] >= start and r["form"] == 1]
    if not after:
        return
    causes: Counter[str] = Counter()
    for r in after:
        for i in np.flatnonzero(r["err"] > tol).tolist():
            if r["course_slot"][i] > _NEAR:
                causes["course != slot"] += 1
            elif not r["joined"][i]:
                causes[f"plan not joined: {r['why'][i]}"] += 1
            elif r["plan_slot"][i] > _NEAR:
                causes["plan != slot (joined)"] += 1
            elif r["pose_plan"][i] > _NEAR:
                causes["tracking lag"] += 1
            else:
                causes["other"] += 1
    bad = sum(bool((r["err"] > tol).any()) for r in after)
    print(f"from t = {start}: {len(after)} steps, {bad} with a follower out of tolerance; follower-steps by cause:")
    for cause, count in causes.most_common():
        print(f"    {count:5d}  {cause}")
    print("replans:", dict(Counter(x for r in after for x in r["reasons"])), " shield stops:", sum(r["stops"] for r in after))
    for key, name in (("err", "robot-slot"), ("pose_plan", "robot-plan"), ("plan_slot", "plan-slot"),
                      ("course_slot", "course-slot")):
        a = np.array([r[key] for r in after])
        print(f"{name:12s} mean {a.mean():.3f}  p95 {np.percentile(a, 95):.3f}  max {a.max():.3f} m")
    if verbose:
        for r in after[::2]:
            out = [f"{i}: {r['err'][i]:.2f} m ({'on course' if r['joined'][i] else r['why'][i]})"
                   for i in np.flatnonzero(r["err"] > tol).tolist()]
            print(f"t={r['t']:.1f} {'+'.join(r['reasons'])}  " + "; ".join(out))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--policy-args", default="", help="KEY=VALUE,... for CBSRRTExpert")
    ap.add_argument("--from", dest="t_from", type=float, default=None, help="start time (default: settling)")
    ap.add_argument("--verbose", action="store_true")
    args = ap.parse_args()
    kwargs = parse_policy_kwargs("cbs_rrt", args.policy_args or None, CBSRRTExpert)
    diagnose(args.seed, kwargs, args.t_from, args.verbose)


if __name__ == "__main__":
    main()
