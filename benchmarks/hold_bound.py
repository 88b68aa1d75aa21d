"""Can any follower hold the ``paper_cbs_switch`` grid >= 90 % of the time? (issue 12 item 1)

    python benchmarks/hold_bound.py                          # seeds 0-7, ~2 min (cbs_rrt is played)
    python benchmarks/hold_bound.py --settle 95.5,134.5     # bounds for given settle times only (s)
    python benchmarks/hold_bound.py --json /tmp/bound.json --h 0.025
    python benchmarks/hold_bound.py --settle 12.5 --margins 0.30,0.58 --margins 0.33,0.61

Issue 12's target: after the formation switch is reached (``settle_times[i]["settle_time"]``), every
follower stays within ``world.settle_tolerance`` (0.3 m) of the env's slot target
(``WorldState.slot_targets``) in >= 90 % of the remaining steps (``hold_fraction``,
:mod:`swarm_env.scoring.metrics`). This script decides whether that is possible at all for followers with
the robots' limits, ignoring the other robots, by computing what an *ideal* follower achieves.

1. **Slots.** ``paper_cbs_switch`` has a virtual leader, so the slot targets are a function of time
   and the map only: :func:`swarm_env.geometry.formation.virtual_slot_trajectory`. ``--check-env`` plays the
   env with two different policies and seeds and checks the recorded ``slot_targets`` are bitwise
   the same as that trajectory (they do not depend on the followers or the seed).
2. **Jumps.** Every step after the switch in which a slot moves more than ``max_speed * dt``
   (0.25 m, what a follower can move) is listed with its cause: ``switch`` (the formation changed),
   ``leader turn`` (the leader's heading jumped at a path vertex: the unprojected slot moved),
   ``obstacle flip`` (the slot is pushed out of an obstacle on another side or face than one step
   before: the push direction turned by > 45 degrees in one step, a discontinuity of the
   nearest-point projection), ``obstacle sweep`` (pushed out on the same side, but the push moved
   fast), ``obstacle enter/leave`` (projected in one of the two steps only).
3. **Point bound (optimal).** A point follower moving at most ``max_speed * dt`` per step, whose
   disc (robot radius) never overlaps an obstacle or wall, starts on its slot at the settle time
   ``S`` and maximises the number of steps within the tolerance until the leader is done
   (t = 185 s, where a settled episode ends). Solved exactly by dynamic programming on a lattice of
   pitch ``h`` (backward: ``V_k(p) = held_k(p) + max_{|q-p| <= v dt} V_{k+1}(q)``), twice:

   * ``upper``: every constant relaxed by the lattice error (tolerance + h/sqrt2, step + h*sqrt2,
     clearance - h/sqrt2), so any continuous trajectory rounds to a lattice path it allows: an
     upper bound for each follower; the swarm's bound is the smallest follower's (all followers
     must be within the tolerance in the same step);
   * ``lower``: exact constants (clearance + 0.03 m so the straight segment between two lattice
     points cannot clip an obstacle corner, checked afterwards by sampling): each follower's optimal
     lattice path is a real trajectory, and the fraction of steps in which *all* eight paths are
     within the tolerance is achieved.

4. **Unicycle (achievable).** A differential-drive robot with the env's exact kinematics (|v| <=
   ``max_speed``, |omega| <= ``max_turn_rate``, reversing allowed, ``world.substeps`` Euler substeps
   where the first one still moves with the last step's velocity, as pymunk integrates; checked
   against the env) tracks the ``lower`` point path with a 5-step look-ahead over a grid of
   commands (the later four steps repeat one command), starting at rest on its slot facing the
   leader's heading (or turned by 45, 90, 135 degrees, whichever holds most). Its fraction is achieved by a real robot (robot-robot contacts ignored; the closest
   pair of ideal robots is printed).
5. Also a **greedy point** (each step: the free point within ``v dt`` nearest to the next slot),
   the policy the issue first thought of.
6. **Robots that keep apart.** ``no-hit``: prioritised point paths (each follower's exact DP treats
   the ones planned before it as moving discs; best of the orders 0..N-1 and N-1..0) that never
   touch. ``j FLOOR/SEP`` (:func:`joint_paths`, ``--margins``): point paths whose centres keep
   ``FLOOR`` m from obstacles and ``SEP`` m from each other at every step, planned for the whole
   formation: prioritised, then rounds of best responses that count only the steps in which *every*
   follower is within tolerance. By default twice: contact-free (``r + 0.03``, ``2 r + 0.06``: the
   chord allowance keeps the discs apart between steps too) and with the ``cbs_rrt`` shield's
   margin (0.05 m) added to both, the gap the expert keeps. These are achieved by real points (not
   bounds from above: best responses are not a joint optimum).

For each settle time ``S`` (the ``cbs_rrt`` expert's per seed, played here unless ``--settle`` is
given, plus the ideal follower's own earliest settling and t = 167) the hold fractions of all of
these are printed beside ``cbs_rrt``'s own, and for ``cbs_rrt`` the steps it lost are split into
those an ideal follower loses too (slot jumps no follower can follow) and the rest.

Results (2026-12-03, deterministic; ``python benchmarks/hold_bound.py --check-env`` at h = 0.05 m,
~9 min on the loaded 2-core machine, and ``--settle 33.5,80,84,87 --h 0.025`` for the edge cases):

* The slots are the same bits for every seed and policy; so "per seed" differs only by the settle
  time ``S`` of the policy played.
* Slot jumps after the switch: the leader's turn at t = 124.5 (all 8 slots, 0.66-2.04 m), follower
  0's flip round obstacle 9 at t = 179.5 (1.36 m, push turned 154 deg), face changes of the 45-deg
  square obstacle 5 at t = 105.5 / 114.0 (0.72 m), sweeps round obstacle 7 at 145.5-146.0 and
  153.5-154.5 (0.28-0.38 m per step), obstacle 8 at 168.5 (0.26 m).
* cbs_rrt's settle times (seeds 0, 1, 3, 5, 6, 7: S = 54.5, 64, 58, 56, 15.5, 56.5 s): achievable
  (point lower / unicycle) 0.951/0.951, 0.940/0.940, 0.947/0.947, 0.949/0.949, 0.928/0.922,
  0.949/0.949 against cbs_rrt's 0.14, 0.02, 0.09, 0.17, 0.12, 0.07. Seed 2 settled after the leader
  stopped (held 1.00 trivially), seed 4 never. vo (S = 33.5): point 0.910, unicycle 0.896, upper
  0.965, vo 0.30.
* Robots that keep apart (2026-12-05, ``python benchmarks/hold_bound.py --settle 12.5,16,20``, 2.5 min;
  the ``ideal earliest`` row is 5.5 s): the joint point plans hold 0.912-0.925 contact-free but only
  0.860-0.880 when they keep the shield's 0.05 m to obstacles and to each other (S = 12.5: 0.919 vs
  0.866; the obstacle margin alone 0.892, the robots' alone 0.914: ``--margins 0.33,0.56``,
  ``--margins 0.28,0.61``). The margins cost the steps at 114-116.5 (follower 3's slot flips round
  a corner of the square obstacle 5: kept 0.05 m off it, the way round is longer) and 145.5-146
  and 154 (slots pushed within 0.36 m of each other round obstacle 7), besides what every follower
  loses (105.5, 114, the turn at 123-127, the flip at 179.5-182). Projecting the slots farther out
  of the obstacles (``SLOT_MARGIN`` 0.10 or 0.15 instead of 0.05, a throwaway script) leaves this
  unchanged (0.866, 0.860). A controller that keeps the expert's margins needs joint plans better
  than these best responses to reach 90 %, and real robots lose more than points.
* What came of it (2026-12-05): ``cbs_rrt`` (``hold_plan``, on by default) plans such joint paths
  (:func:`swarm_env_agents.cbs_rrt.hold_plan.joint_paths`, which :func:`joint_paths` here calls,
  with 0.01 / 0.02 m more than contact-free) from where the robots are and tracks them with the
  robots' kinematics, without the shield while it holds: seeds 0-7 hold 0.910-0.918 in the env,
  collision-free (``python benchmarks/hold_bound.py --settle 14``, 77 s: ``j0.28/0.56`` 0.918 from
  S = 14 s; ``j0.33/0.61`` 0.863).
* Settling late is what makes 90 % impossible: the flip at t = 179.5 alone costs 4-5 steps, so with
  S = 87 (t = 167, the latest issue 12 allows) even the relaxed upper bound is 0.892 (h = 0.025;
  lower 0.865); at S = 80 (t = 160) the point and the unicycle achieve 0.902.
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from swarm_env.geometry.formation import SLOT_MARGIN, unprojected_slot_trajectory, virtual_slot_trajectory
from swarm_env.geometry.paths import PolylinePath, virtual_leader
from swarm_env.geometry.static_map import StaticMap
from swarm_env.jsonio import write_json
from swarm_env.scenario import Scenario
from swarm_env.scenarios.loader import load_scenario
from swarm_env_agents.cbs_rrt import hold_plan
from swarm_env_agents.cbs_rrt.hold_plan import CHORD_ALLOWANCE, Lattice, PointDP, half_widths, substep_rollout


# --------------------------------------------------------------------------- slots and jumps
@dataclass(frozen=True)
class SlotRecord:
    """The env's slot targets at ``t = k dt``, ``k = 0..steps``, and what they are made of."""

    scenario: Scenario
    static: StaticMap
    slots: np.ndarray  # (K+1, N, 2) projected out of obstacles: WorldState.slot_targets
    raw: np.ndarray  # (K+1, N, 2) before the projection
    formation: np.ndarray  # (K+1,) active formation index
    heading: np.ndarray  # (K+1,) the leader's heading
    dt: float
    done_step: int  # first step at which the leader is done (a settled episode ends there)


def record_slots(scn: Scenario) -> SlotRecord:
    """The slot trajectory of a virtual-leader scenario up to ``world.max_time``."""
    if scn.leader.kind != "virtual":
        raise ValueError("record_slots: the slots of a robot leader depend on its motion; needs a virtual leader")
    dt = scn.world.dt
    steps = int(round(scn.world.max_time / dt))
    static = StaticMap.from_obstacles(scn.world.size, scn.obstacles)
    raw, index = unprojected_slot_trajectory(scn, steps)
    slots, _ = virtual_slot_trajectory(scn, static, steps, (raw, index))
    line = PolylinePath(scn.leader.path)
    heading = np.array([virtual_leader(line, scn.leader.speed, k * dt, scn.leader.start_delay)[0][2] for k in range(steps + 1)])
    done_step = hold_plan.virtual_leader_done_step(scn, steps)
    return SlotRecord(scn, static, slots, raw, index, heading, dt, done_step)


def check_env_slots(rec: SlotRecord, seeds: tuple[int, ...] = (0, 3)) -> float:
    """Largest |env slot - recorded slot| over episodes played with ``pursuit`` (first seed) and
    ``zero`` (the others): 0.0 means the slots depend neither on the followers nor on the seed."""
    from swarm_env.env import SwarmEnv
    from swarm_env.harness.policies import PursuitPolicy, ZeroPolicy

    worst = 0.0
    for j, seed in enumerate(seeds):
        env = SwarmEnv(rec.scenario)
        obs, _ = env.reset(seed=seed)
        policy = PursuitPolicy(env) if j == 0 else ZeroPolicy(env)
        policy.reset(env, seed)
        got = [env.world_state().slot_targets.copy()]
        while env.agents:
            obs, *_ = env.step(policy.act(obs, env.world_state()))
            got.append(env.world_state().slot_targets.copy())
        worst = max(worst, float(np.abs(np.array(got) - rec.slots[: len(got)]).max()))
    return worst


@dataclass(frozen=True)
class Jump:
    """A slot that moved more than a follower can in one step."""

    t: float  # time of the step's end (the slot at t - dt moved to here)
    follower: int
    size: float  # m
    cause: str
    obstacle: int | None  # the obstacle the slot is pushed out of (None: walls or none)
    push_turn_deg: float | None  # how far the push direction turned (obstacle causes)


def slot_jumps(rec: SlotRecord, step_limit: float, k_from: int, k_to: int) -> list[Jump]:
    """The slot moves larger than ``step_limit`` between steps ``k_from..k_to`` (see module docstring)."""
    out: list[Jump] = []
    d = np.hypot(*(rec.slots[1:] - rec.slots[:-1]).transpose(2, 0, 1))  # (K, N): move into step k+1
    draw = np.hypot(*(rec.raw[1:] - rec.raw[:-1]).transpose(2, 0, 1))
    push = rec.slots - rec.raw
    for k, i in zip(*np.nonzero(d > step_limit)):
        if not k_from <= k + 1 <= k_to:
            continue
        turn = None
        obstacle = None
        if rec.formation[k] != rec.formation[k + 1]:
            cause = "switch"
        elif abs(rec.heading[k + 1] - rec.heading[k]) > 1e-12 and draw[k, i] > step_limit:
            cause = "leader turn"
        else:
            a, b = push[k, i], push[k + 1, i]
            na, nb = float(np.hypot(*a)), float(np.hypot(*b))
            if na < 1e-12 or nb < 1e-12:
                cause = "obstacle enter/leave"
            else:
                turn = math.degrees(math.acos(max(-1.0, min(1.0, float(a @ b) / (na * nb)))))
                cause = "obstacle flip" if turn > 45.0 else "obstacle sweep"
        dist = rec.static.obstacle_distances(rec.raw[k + 1, i][None])[0]
        if len(dist) and dist.min() < rec.scenario.robots.radius + SLOT_MARGIN + 1e-9:
            obstacle = int(np.argmin(dist))  # the raw slot lies within this obstacle's clearance
        out.append(Jump(round((k + 1) * rec.dt, 9), int(i), float(d[k, i]), cause, obstacle, turn))
    return out


# --------------------------------------------------------------------------- the lattice DP
def point_dp(rec: SlotRecord, i: int, k0: int, k_end: int, h: float, relax: bool,
             others: np.ndarray | None = None, margins: tuple[float, float] | None = None,
             gain: np.ndarray | None = None) -> PointDP:
    """Follower ``i``'s DP from step ``k0`` to ``k_end`` (:func:`swarm_env_agents.cbs_rrt.hold_plan.point_dp`).

    ``relax``: every constant relaxed by the lattice error (the ``upper`` bound; no ``others``).
    Otherwise the exact constants: the centre keeps ``r + 0.03`` from obstacles and, from the
    ``others (k_end - k0 + 1, M, 2)`` already planned, ``2 r + 0.06`` (0.06 m: two 0.25 m moves
    between two step ends cannot then bring the centres within ``2 r``, the same chord argument as
    for obstacles); ``margins = (floor, separation)`` replaces those two. ``gain``: what a step
    within tolerance is worth."""
    robots = rec.scenario.robots
    tol = rec.scenario.world.settle_tolerance
    step = robots.max_speed * rec.dt
    e = h / math.sqrt(2.0)
    floor, sep = (robots.radius + CHORD_ALLOWANCE, 2.0 * robots.radius + 2.0 * CHORD_ALLOWANCE) if margins is None else margins
    if relax:
        tol, step, floor = tol + e, step + 2.0 * e, robots.radius - e
    return hold_plan.point_dp(rec.static, rec.slots[:, i], k0, k_end, hold_plan.PointModel(h, tol, step, floor, sep),
                              others, gain)


def prioritised_paths(rec: SlotRecord, k_s: int, k_end: int, h: float, order: list[int],
                      margins: tuple[float, float] | None = None) -> np.ndarray:
    """Collision-free point paths ``(k_end - k_s + 1, N, 2)`` from the slots at ``k_s``: followers
    in ``order`` each solve the exact DP (``margins`` as in :func:`point_dp`) treating the ones
    before them as moving discs. Achieved by real points; not optimal (prioritised planning)."""
    n = rec.slots.shape[1]
    paths = np.full((k_end - k_s + 1, n, 2), np.nan)
    done: list[int] = []
    for i in order:
        dp = point_dp(rec, i, k_s, k_end, h, relax=False, others=paths[:, done], margins=margins)
        paths[:, i] = dp.path(k_s)
        done.append(i)
    return paths


def joint_paths(rec: SlotRecord, k_s: int, k_end: int, h: float, margins: tuple[float, float],
                rounds: int = 3, bonus: int = 16) -> np.ndarray:
    """Point paths ``(k_end - k_s + 1, N, 2)`` from the slots at ``k_s`` keeping ``margins = (floor,
    separation)`` that hold the whole formation in as many steps as
    :func:`swarm_env_agents.cbs_rrt.hold_plan.joint_paths` finds (prioritised, then best responses:
    what ``cbs_rrt:hold_plan=true`` plans). Achieved by real points (a lower bound of what
    followers keeping those margins can hold)."""
    robots = rec.scenario.robots
    model = hold_plan.PointModel(h, rec.scenario.world.settle_tolerance, robots.max_speed * rec.dt, margins[0], margins[1])
    return hold_plan.joint_paths(rec.static, rec.slots, k_s, k_end, model, rounds=rounds, bonus=bonus)


# --------------------------------------------------------------------------- greedy point, unicycle
def point_greedy(rec: SlotRecord, i: int, k: int, k_end: int, n_dirs: int = 72) -> np.ndarray:
    """Greedy point follower ``i`` from its slot at step ``k``: each step, of the points within
    ``v dt`` (the target itself if reachable, else 72 directions x 5 lengths) whose disc is clear of
    obstacles, the one nearest to the next slot."""
    robots = rec.scenario.robots
    step = robots.max_speed * rec.dt
    p = rec.slots[k, i].copy()
    out = [p.copy()]
    ang = np.linspace(0.0, 2.0 * math.pi, n_dirs, endpoint=False)
    lens = step * np.array([0.2, 0.4, 0.6, 0.8, 1.0])
    cand_off = (lens[:, None, None] * np.stack([np.cos(ang), np.sin(ang)], axis=-1)[None]).reshape(-1, 2)
    for kk in range(k, k_end):
        s = rec.slots[kk + 1, i]
        d = s - p
        n = float(np.hypot(*d))
        cand = np.vstack([s[None] if n <= step else (p + d * (step / n))[None], p + cand_off, p[None]])
        ok = rec.static.distance(cand) >= robots.radius + CHORD_ALLOWANCE
        cand = cand[ok]
        p = cand[int(np.argmin(np.hypot(*(cand - s).T)))].copy()
        out.append(p.copy())
    return np.array(out)


def unicycle_track(rec: SlotRecord, i: int, k: int, ref: np.ndarray, lattice: Lattice, heading: float,
                   horizon: int = 5, n_v: int = 11, n_w: int = 11) -> tuple[np.ndarray, float]:
    """Unicycle follower ``i`` from its slot at step ``k`` (at rest, facing ``heading``) tracking
    ``ref`` (``ref[j]``: the point path at step ``k + j``). Each step it plays the first command of
    the best sequence ``(u1, u2, u2, ...)`` (``horizon`` steps) over an ``n_v x n_w`` command grid,
    scoring at each step a miss of the slot (beyond 0.28 m) heavily, the distance to ``ref``
    lightly, and any substep point whose disc touches an obstacle prohibitively (lattice clearance
    minus its error). Returns the positions ``(len(ref), 2)`` and the smallest true clearance (robot
    surface to obstacle) along the trajectory (sampled)."""
    robots = rec.scenario.robots
    scn = rec.scenario
    substeps = scn.world.substeps
    sub_dt = rec.dt / substeps
    tol = scn.world.settle_tolerance
    vs = np.linspace(-robots.max_speed, robots.max_speed, n_v)
    ws = np.linspace(-robots.max_turn_rate, robots.max_turn_rate, n_w)
    u = np.stack(np.meshgrid(vs, ws, indexing="ij"), axis=-1).reshape(-1, 2)  # (U, 2)
    U = len(u)
    seq1 = np.repeat(u, U, axis=0)  # (U*U, 2): first command
    seq2 = np.tile(u, (U, 1))  # the later ones
    e = lattice.h / math.sqrt(2.0)
    clr = lattice.clearance
    Hc, Wc = clr.shape

    def clearance(pts: np.ndarray) -> np.ndarray:
        cx = np.clip(np.rint((pts[..., 0] - lattice.x0) / lattice.h).astype(np.intp), 0, Wc - 1)
        cy = np.clip(np.rint((pts[..., 1] - lattice.y0) / lattice.h).astype(np.intp), 0, Hc - 1)
        return clr[cy, cx] - e  # 1-Lipschitz: the true clearance is at least this

    state = np.array([*rec.slots[k, i], heading, 0.0, 0.0, 0.0])
    out = [state[:2].copy()]
    n = len(ref)
    for j in range(n - 1):
        st = np.broadcast_to(state, (U * U, 6))
        cost = np.zeros(U * U)
        cmds = seq1
        for look in range(1, horizon + 1):
            kk = min(j + look, n - 1)
            st, sub = substep_rollout(st, cmds, substeps, sub_dt)
            p = st[:, :2]
            s = rec.slots[k + kk, i]
            miss = np.maximum(np.hypot(*(p - s).T) - (tol - 0.02), 0.0)
            weight = 1.0 / look  # nearer steps first: later ones are only a rough plan
            cost += weight * (100.0 * miss + np.sum((p - ref[kk]) ** 2, axis=1))
            hit = (clearance(sub) < robots.radius).any(axis=0)
            cost += np.where(hit, 1e6, 0.0)
            cmds = seq2
        best = int(np.argmin(cost))
        state, _ = substep_rollout(state, seq1[best], substeps, sub_dt)
        out.append(state[:2].copy())
    path = np.array(out)
    fine = np.concatenate([path[:-1] + (path[1:] - path[:-1]) * f for f in np.linspace(0, 1, 9)])
    return path, float(rec.static.distance(fine).min() - robots.radius)


def best_unicycle(rec: SlotRecord, i: int, k: int, ref: np.ndarray, lattice: Lattice,
                  n_headings: int = 4) -> tuple[np.ndarray, float, float]:
    """:func:`unicycle_track` from up to ``n_headings`` start headings (the leader's first, then
    turned by multiples of 180/n degrees: reversing is allowed, so heading + 180 is the same robot);
    the one holding its slot in most steps (the first of equals; no other is tried once one holds
    as many as ``ref``). Returns ``(positions, min clearance, start heading)``."""
    tol = rec.scenario.world.settle_tolerance
    target = int((np.hypot(*(ref - rec.slots[k : k + len(ref), i]).T) <= tol).sum())
    best: tuple[int, np.ndarray, float, float] | None = None
    for m in range(n_headings):
        heading = float(rec.heading[k] + math.pi * m / n_headings)
        path, clear = unicycle_track(rec, i, k, ref, lattice, heading)
        held = int((np.hypot(*(path - rec.slots[k : k + len(path), i]).T) <= tol).sum())
        if best is None or held > best[0]:
            best = (held, path, clear, heading)
        if held >= target:
            break
    assert best is not None
    return best[1], best[2], best[3]


# --------------------------------------------------------------------------- hold fractions
def hold_of(paths: np.ndarray, slots: np.ndarray, tol: float) -> tuple[float, np.ndarray]:
    """``(hold fraction, all-within mask per step)`` of follower paths ``(T, N, 2)`` against ``slots (T, N, 2)``."""
    within = np.all(np.hypot(*(paths - slots).transpose(2, 0, 1)) <= tol, axis=1)
    return float(within.mean()), within


def min_pair_distance(paths: np.ndarray) -> float:
    """Smallest centre distance between two followers over the steps of ``paths (T, N, 2)``."""
    return float(pair_distances(paths).min())


def pair_distances(paths: np.ndarray) -> np.ndarray:
    """``(T, N, N)`` centre distances between followers (``inf`` on the diagonal)."""
    d = np.hypot(*(paths[:, :, None, :] - paths[:, None, :, :]).transpose(3, 0, 1, 2))
    n = paths.shape[1]
    d[:, np.arange(n), np.arange(n)] = np.inf
    return d


def contacts(paths: np.ndarray, t0: float, dt: float, contact: float) -> list[tuple[float, int, int, float]]:
    """``(t, i, j, centre distance)`` of every step and pair of ``paths`` closer than ``contact``."""
    d = pair_distances(paths)
    return [(round(t0 + k * dt, 9), int(i), int(j), float(d[k, i, j])) for k, i, j in zip(*np.nonzero(d < contact)) if i < j]


@dataclass
class Bound:
    """The ideal followers' hold fractions from one settle time."""

    settle: float  # s after the switch
    steps: int  # steps counted (settle step .. leader done)
    upper: float  # point DP relaxed: no follower can do better
    lower: float  # point DP exact, all followers' optimal paths together: achieved
    unicycle: float  # unicycle tracking the lower paths: achieved by a robot
    greedy: float  # greedy point
    lost_lower: list[float] = field(default_factory=list)  # times of the steps the lower bound loses
    lost_unicycle: list[float] = field(default_factory=list)
    unicycle_min_clearance: float = math.inf
    min_pair_lower: float = math.inf  # m, centres: 2 r = 0.5 is contact
    min_pair_unicycle: float = math.inf
    contacts_lower: list[tuple[float, int, int, float]] = field(default_factory=list)  # (t, i, j, centre distance)
    collision_free: float | None = None  # prioritised point paths that never touch each other: achieved
    collision_free_min_pair: float | None = None  # their closest centres, sampled between steps too
    lost_collision_free: list[float] = field(default_factory=list)
    per_follower_upper: list[float] = field(default_factory=list)
    joint: dict[str, float] = field(default_factory=dict)  # "floor/separation" -> joint_paths' hold: achieved
    lost_joint: dict[str, list[float]] = field(default_factory=dict)


def bound_from(rec: SlotRecord, dps_up: list[PointDP], dps_lo: list[PointDP], k_s: int, k_end: int,
               h: float, collision_free: bool = True, margins: tuple[tuple[float, float], ...] = ()) -> Bound:
    """The :class:`Bound` for a formation reached at step ``k_s`` (``collision_free``: also the
    prioritised collision-free point paths, best of two orders, 0..N-1 and N-1..0; ``margins``:
    also :func:`joint_paths` keeping each ``(floor, separation)``)."""
    n_steps = k_end - k_s + 1
    tol = rec.scenario.world.settle_tolerance
    slots = rec.slots[k_s : k_end + 1]
    per_up = [dp.value(k_s) / n_steps for dp in dps_up]
    lo_paths = np.stack([dp.path(k_s) for dp in dps_lo], axis=1)
    lower, lo_mask = hold_of(lo_paths, slots, tol)
    uni = [best_unicycle(rec, i, k_s, lo_paths[:, i], dps_lo[i].lattice) for i in range(len(dps_lo))]
    uni_paths = np.stack([p for p, _, _ in uni], axis=1)
    unicycle, uni_mask = hold_of(uni_paths, slots, tol)
    greedy_paths = np.stack([point_greedy(rec, i, k_s, k_end) for i in range(len(dps_lo))], axis=1)
    greedy, _ = hold_of(greedy_paths, slots, tol)
    t = (k_s + np.arange(n_steps)) * rec.dt
    cf: tuple[float, float, list[float]] | None = None
    if collision_free:
        n = len(dps_lo)
        for order in (list(range(n)), list(range(n - 1, -1, -1))):
            paths = prioritised_paths(rec, k_s, k_end, h, order)
            frac, mask = hold_of(paths, slots, tol)
            fine = np.concatenate([paths[:-1] + (paths[1:] - paths[:-1]) * f for f in np.linspace(0, 1, 9)])
            if cf is None or frac > cf[0]:
                cf = (frac, min_pair_distance(fine), [float(x) for x in t[~mask]])
    joint: dict[str, float] = {}
    lost_joint: dict[str, list[float]] = {}
    for m in margins:
        frac, mask = hold_of(joint_paths(rec, k_s, k_end, h, m), slots, tol)
        joint[_margin_key(m)], lost_joint[_margin_key(m)] = frac, [float(x) for x in t[~mask]]
    return Bound(
        joint=joint, lost_joint=lost_joint,
        settle=round(k_s * rec.dt - float(rec.scenario.formations[int(rec.formation[k_s])].at), 9), steps=n_steps,
        upper=min(per_up), lower=lower, unicycle=unicycle, greedy=greedy,
        lost_lower=[float(x) for x in t[~lo_mask]], lost_unicycle=[float(x) for x in t[~uni_mask]],
        unicycle_min_clearance=min(c for _, c, _ in uni), min_pair_lower=min_pair_distance(lo_paths),
        min_pair_unicycle=min_pair_distance(uni_paths), per_follower_upper=per_up,
        contacts_lower=contacts(lo_paths, k_s * rec.dt, rec.dt, 2.0 * rec.scenario.robots.radius),
        collision_free=None if cf is None else cf[0], collision_free_min_pair=None if cf is None else cf[1],
        lost_collision_free=[] if cf is None else cf[2],
    )


def earliest_settle(rec: SlotRecord, k_switch: int, k_end: int, h: float) -> int:
    """The first step at which point followers starting on their old slots one step before the
    switch can all be within the tolerance (a lattice reachability search with the exact constants
    of the ``lower`` DP, so it is achievable; ignores the other robots)."""
    tol = rec.scenario.world.settle_tolerance
    robots = rec.scenario.robots
    worst = k_switch
    for i in range(rec.slots.shape[1]):
        lat = Lattice.around(rec.static, rec.slots[k_switch - 1 : k_end + 1, i], h)
        free = lat.clearance >= robots.radius + CHORD_ALLOWANCE
        hw = half_widths(robots.max_speed * rec.dt / h)
        reach = np.zeros(free.shape, dtype=bool)
        reach[lat.nearest(rec.slots[k_switch - 1, i])] = True
        H, W = free.shape
        ys, xs = np.mgrid[0:H, 0:W]
        pts_x, pts_y = lat.x0 + xs * h, lat.y0 + ys * h
        k = k_switch - 1
        while True:
            k += 1
            grown = np.zeros_like(reach)
            R = (len(hw) - 1) // 2
            for j, dy in enumerate(range(-R, R + 1)):
                for dx in range(-int(hw[j]), int(hw[j]) + 1):
                    src = reach[max(-dy, 0) : H - max(dy, 0), max(-dx, 0) : W - max(dx, 0)]
                    grown[max(dy, 0) : H - max(-dy, 0), max(dx, 0) : W - max(-dx, 0)] |= src
            reach = grown & free
            s = rec.slots[k, i]
            if ((pts_x - s[0]) ** 2 + (pts_y - s[1]) ** 2 <= tol**2)[reach].any() or k >= k_end:
                break
        worst = max(worst, k)
    return worst


# --------------------------------------------------------------------------- the experts
def play(policy_name: str, seed: int) -> tuple[dict[str, Any], np.ndarray]:
    """Play ``paper_cbs_switch`` with a registered policy; returns its metrics and its follower
    positions at every step ``(K+1, N, 2)``."""
    from swarm_env.env import SwarmEnv
    from swarm_env.harness.policies import load_policy

    env = SwarmEnv(load_scenario("paper_cbs_switch"))
    obs, _ = env.reset(seed=seed)
    policy = load_policy(policy_name, env)
    policy.reset(env, seed)
    pos = [env.world_state().follower_pose[:, :2].copy()]
    while env.agents:
        obs, *_ = env.step(policy.act(obs, env.world_state()))
        pos.append(env.world_state().follower_pose[:, :2].copy())
    return env.episode_metrics(), np.array(pos)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=8, help="cbs_rrt seeds 0..N-1 to play (default 8)")
    ap.add_argument("--settle", default="", help="comma-separated settle times (s after the switch) instead of playing cbs_rrt")
    ap.add_argument("--h", type=float, default=0.05, help="lattice pitch (m)")
    ap.add_argument("--check-env", action="store_true", help="check the env's slots equal the recorded trajectory")
    ap.add_argument("--json", default=None, help="write everything here")
    ap.add_argument("--margins", action="append", default=None, metavar="FLOOR,SEP",
                    help="joint_paths keeping centres FLOOR m from obstacles and SEP m apart (repeatable; default: "
                         "contact-free r + 0.03, 2 r + 0.06 and the cbs_rrt shield's margin added to both)")
    args = ap.parse_args()

    t0 = time.perf_counter()
    scn = load_scenario("paper_cbs_switch")
    rec = record_slots(scn)
    dt = rec.dt
    k_switch = int(round(scn.formations[1].at / dt))
    k_end = rec.done_step
    robots = scn.robots
    step_limit = robots.max_speed * dt
    margins: tuple[tuple[float, float], ...]
    if args.margins:
        parsed = [m.split(",") for m in args.margins]
        if any(len(m) != 2 for m in parsed):
            ap.error(f"--margins: FLOOR,SEP expected, got {args.margins!r}")
        margins = tuple((float(a), float(b)) for a, b in parsed)
    else:
        from swarm_env_agents.cbs_rrt.policy import CBSRRTExpert

        shield = CBSRRTExpert().shield_margin
        rad = robots.radius
        margins = ((rad + CHORD_ALLOWANCE, 2 * rad + 2 * CHORD_ALLOWANCE), (rad + shield + CHORD_ALLOWANCE, 2 * rad + shield + 2 * CHORD_ALLOWANCE))
    margins = tuple((round(a, 6), round(b, 6)) for a, b in margins)
    print(f"paper_cbs_switch: switch at step {k_switch} (t = {k_switch * dt}), leader done at step {k_end} "
          f"(t = {k_end * dt}); a follower moves <= {step_limit} m per step; tolerance {scn.world.settle_tolerance} m")
    out: dict[str, Any] = {"h": args.h, "switch_step": k_switch, "end_step": k_end}
    if args.check_env:
        worst = check_env_slots(rec)
        print(f"env slots vs recorded trajectory (pursuit seed 0, zero seed 3): max |diff| = {worst} m")
        out["env_slot_diff"] = worst

    jumps = slot_jumps(rec, step_limit, k_switch, k_end)
    print(f"\nslot jumps > {step_limit} m from the switch to the leader's stop ({len(jumps)}):")
    for jp in jumps:
        extra = f", obstacle {jp.obstacle}" if jp.obstacle is not None else ""
        extra += f", push turned {jp.push_turn_deg:.1f} deg" if jp.push_turn_deg is not None else ""
        print(f"  t = {jp.t:6.1f}  follower {jp.follower}  {jp.size:.2f} m  {jp.cause}{extra}")
    out["jumps"] = [jp.__dict__ for jp in jumps]

    # Settle times to evaluate: cbs_rrt's per seed (played), the ideal's earliest, and t = 167.
    experts: list[dict[str, Any]] = []
    settles: dict[str, float] = {}
    if args.settle:
        for x in args.settle.split(","):
            settles[f"S={float(x)}"] = float(x)
    else:
        for seed in range(args.seeds):
            m, pos = play("cbs_rrt", seed)
            [st] = m["settle_times"]
            experts.append({"policy": "cbs_rrt", "seed": seed, "settle": st["settle_time"], "hold": st["hold_fraction"],
                            "success": m["success"], "positions": pos})
            if st["settle_time"] is not None:
                settles[f"cbs_rrt seed {seed}"] = st["settle_time"]
        m, pos = play("vo", 0)
        [st] = m["settle_times"]
        experts.append({"policy": "vo", "seed": 0, "settle": st["settle_time"], "hold": st["hold_fraction"],
                        "success": m["success"], "positions": pos})
        if st["settle_time"] is not None:
            settles["vo seed 0"] = st["settle_time"]
    k_ideal = earliest_settle(rec, k_switch, k_end, args.h)
    settles["ideal earliest"] = round(k_ideal * dt - scn.formations[1].at, 9)
    settles["t = 167 (latest allowed)"] = 167.0 - scn.formations[1].at
    print(f"\nthe ideal point followers can all be within tolerance {settles['ideal earliest']} s after the switch "
          f"(t = {k_ideal * dt})")

    k_starts = {name: k_switch + int(round(s / dt)) for name, s in settles.items()}
    k0 = min([k for k in k_starts.values() if k <= k_end], default=k_end)
    t1 = time.perf_counter()
    n = robots.count
    dps_up = [point_dp(rec, i, k0, k_end, args.h, relax=True) for i in range(n)]
    dps_lo = [point_dp(rec, i, k0, k_end, args.h, relax=False) for i in range(n)]
    print(f"point DP ({n} followers x 2, steps {k0}..{k_end}, lattice {args.h} m): {time.perf_counter() - t1:.1f} s")

    print("\nhold fraction from the settle time S to the leader's stop (t = 185), ideal followers vs the expert:")
    print(f"{'settle time from':28s} {'S (s)':>6s} {'steps':>5s} {'upper':>6s} {'lower':>6s} {'unicyc':>6s} "
          f"{'greedy':>6s} {'no-hit':>6s} " + " ".join(f"{'j' + _margin_key(m):>10s}" for m in margins)
          + f" {'expert':>6s}  steps lost by the unicycle (t) | by no-hit | by each joint")
    rows = []
    for name, s in settles.items():
        k_s = k_starts[name]
        expert = next((e for e in experts if name == f"{e['policy']} seed {e['seed']}"), None)
        ehold = "" if expert is None else f"{expert['hold']:.2f}"
        if k_s > k_end:
            print(f"{name:28s} {s:6.1f}     -      (settled after the leader stopped: the episode ends at once) {ehold}")
            rows.append({"name": name, "settle": s, "after_end": True, "expert_hold": None if expert is None else expert["hold"]})
            continue
        b = bound_from(rec, dps_up, dps_lo, k_s, k_end, args.h, margins=margins)
        print(f"{name:28s} {s:6.1f} {b.steps:5d} {b.upper:6.3f} {b.lower:6.3f} {b.unicycle:6.3f} {b.greedy:6.3f} "
              f"{b.collision_free:6.3f} " + " ".join(f"{b.joint[_margin_key(m)]:10.3f}" for m in margins)
              + f" {ehold:>6s}  {_spans(b.lost_unicycle, dt)} | {_spans(b.lost_collision_free, dt)} | "
              + " | ".join(_spans(b.lost_joint[_margin_key(m)], dt) for m in margins))
        row: dict[str, Any] = {"name": name, **b.__dict__, "expert_hold": None if expert is None else expert["hold"]}
        if expert is not None:
            row.update(_gap(rec, expert["positions"], k_s, b, dt))
        rows.append(row)
    out["rows"] = rows
    print("\nchecks: unicycle min clearance to obstacles "
          f"{min(r.get('unicycle_min_clearance', math.inf) for r in rows):.3f} m; closest pair of ideal robots "
          f"(centres; 0.5 m = contact): point {min(r.get('min_pair_lower', math.inf) for r in rows):.3f} m, "
          f"unicycle {min(r.get('min_pair_unicycle', math.inf) for r in rows):.3f} m, collision-free point "
          f"{min(r.get('collision_free_min_pair') or math.inf for r in rows):.3f} m (sampled between steps)")
    slot_gap = pair_distances(rec.slots[k_switch : k_end + 1])
    k, i, j = np.unravel_index(int(np.argmin(slot_gap)), slot_gap.shape)
    print(f"closest two slots after the switch: followers {i} and {j} at t = {(k_switch + k) * dt}: {slot_gap[k, i, j]:.3f} m")
    for r in rows:
        if r.get("contacts_lower"):
            pairs = sorted({(i, j) for _, i, j, _ in r["contacts_lower"]})
            print(f"{r['name']}: ideal point robots in contact (centres < 0.5 m) in {len({c[0] for c in r['contacts_lower']})} "
                  f"steps, pairs {pairs}, at t = {_spans(sorted({c[0] for c in r['contacts_lower']}), dt)}")
    for r in rows:
        if "expert_lost" in r:
            print(f"{r['name']}: expert lost {r['expert_lost']} of {r['steps']} steps; {r['expert_lost_unavoidable']} "
                  f"of them are lost by the ideal unicycle too; steps with follower k out: {r['expert_out_by_follower']}")
    print(f"\ntotal {time.perf_counter() - t0:.0f} s")
    if args.json:
        write_json(args.json, out)


def _margin_key(m: tuple[float, float]) -> str:
    """``(0.33, 0.61)`` -> ``"0.33/0.61"``."""
    return f"{m[0]:g}/{m[1]:g}"


def _spans(times: list[float], dt: float) -> str:
    """``[124.5, 125.0, 125.5, 180.0]`` -> ``"124.5-125.5, 180.0"``."""
    if not times:
        return "-"
    parts = []
    start = prev = times[0]
    for t in times[1:] + [math.inf]:
        if t - prev > dt + 1e-9:
            parts.append(f"{start:.1f}" if start == prev else f"{start:.1f}-{prev:.1f}")
            start = t
        prev = t
    return ", ".join(parts)


def _gap(rec: SlotRecord, positions: np.ndarray, k_s: int, b: Bound, dt: float) -> dict[str, Any]:
    """How the expert's lost steps (from ``k_s`` to the leader's stop) relate to the ideal's."""
    tol = rec.scenario.world.settle_tolerance
    k_end = k_s + b.steps - 1
    err = np.hypot(*(positions[k_s : k_end + 1] - rec.slots[k_s : k_end + 1]).transpose(2, 0, 1))
    out = err > tol
    lost = np.any(out, axis=1)
    t = (k_s + np.arange(b.steps)) * dt
    unavoidable = np.isin(np.round(t, 9), np.round(b.lost_unicycle, 9))
    return {"expert_lost": int(lost.sum()), "expert_lost_unavoidable": int((lost & unavoidable).sum()),
            "expert_out_by_follower": out.sum(axis=0).tolist()}


if __name__ == "__main__":
    main()
