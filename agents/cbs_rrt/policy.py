"""The centralized CBS + motion-primitive RRT expert of paper 000, as a swarm-env policy.

Three layers (paper 000 Fig. 1), run from the privileged
:class:`~swarm_env.state.WorldState`:

1. **Formation control** (:mod:`swarm_env_agents.cbs_rrt.goals`): every follower's goal
   course over the planning window — its slot predicted along the leader's
   trajectory (exact for a virtual leader), with the scheduled formation
   switches, moved out of obstacles and apart from the other goals.
2. **Conflict management** (:mod:`swarm_env_agents.cbs_rrt.cbs`, :mod:`swarm_env_agents.cbs_rrt.swarm`):
   Conflict-Based Search over all followers, conflicts checked continuously
   between timed paths, with the paper's fallbacks.
3. **Individual path planning** (:mod:`swarm_env_agents.cbs_rrt.rrt`): a goal-biased RRT
   over motion primitives in space-time with a buffer zone, CBS constraints
   and smoothing; the path joins the goal course and follows it.

Every step a pure-pursuit controller (:func:`swarm_env.control.pursuit.pure_pursuit`,
shared with the rest of the project) tracks each robot's timed path: it aims at
the path's position ``lookahead_time`` seconds ahead, with the speed that
reaches it in that time, so a robot that lags speeds up and one that is early
waits. The swarm is replanned (all robots, one CBS) only when needed:

* ``initial`` — no plan yet;
* ``switch`` — the active formation changed;
* ``goal_jump`` — some robot's goal course jumped (switch, a turn of the
  leader's path, a slot flipping around an obstacle): its plan ended there;
* ``horizon`` — the plans are about to run out (``horizon - check_margin``);
* ``rolling`` — conflicts were left beyond the window CBS resolved
  (``conflict_window``), or a fallback was used: replan before it runs out;
* ``deviation`` — a robot is farther than ``deviation_tolerance`` from where its
  plan says it should be;
* ``goal_moved`` — a slot target differs from the planned goal by more than
  ``goal_move_tolerance`` (a robot leader that left its predicted course);
* ``retry`` — some robot holds a fallback (stationary or partial) plan and
  ``min_replan_interval`` has passed (doubling, up to 8 times, while it persists).

Beyond paper 000 (which has neither): humans, whose motion is a known function
of time, and a robot leader (its predicted course) are moving discs that every
robot's plan keeps clear of; and the tracker has a one-step safety check (a
robot that would come within ``shield_margin`` of an obstacle, a robot or a
human only turns in place for that step; counted in ``shield_stops``). A robot
that a human walking on at its current velocity would reach within
``evade_horizon`` even if it stood still steps aside instead: for that step its
twist is the ``vo`` expert's velocity-obstacle search's (the humans do not give
way, and a plan that waits for them is no plan; counted in ``evade_steps``), and one that the search leaves
boxed in backs off (``evade_reverse``: the ``vo`` expert's rule, :func:`swarm_env.control.safety.back_off`;
counted in ``reverse_steps``).

A reached formation is held, not replanned (issue 12 item 1): with a virtual leader the
slots are known for the rest of the episode, so once every follower is near its slot the
expert plans the whole formation to the next switch or the leader's stop in space and
time (:mod:`swarm_env_agents.cbs_rrt.hold_plan`, ``hold_plan``) and tracks that plan;
replanning knocked robots in formation off their courses at every replan (``paper_cbs_switch``
held its grid 2-17 % of the time, now 91-92 %: see ``hold_plan`` below).

Determinism: one ``numpy.random.Generator`` made in :meth:`CBSRRTExpert.reset`
from the seed; every budget is a count (RRT expansions, CBS nodes, low-level
calls), so the same seed gives the same plans on any machine. Wall-clock time
is only measured, for :meth:`CBSRRTExpert.stats`.

Registered as ``cbs_rrt`` in the ``swarm_env.policies`` entry-point group;
``cbs_rrt:KEY=VALUE,...`` sets constructor parameters from the command line
(e.g. ``cbs_rrt:use_cbs=false`` for independent RRT plans).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from swarm_env.control.pursuit import pure_pursuit
from swarm_env.control.safety import AvoidanceParams, back_off, reversing_params, safe_follower_twists
from swarm_env.control.vo import disc_time_to_collision
from swarm_env.geometry.formation import virtual_slot_trajectory
from swarm_env.geometry.paths import human_states
from swarm_env.harness.policies import expert_factory
from swarm_env.state import WorldState
from swarm_env_agents.cbs_rrt.cbs import CBS, CBSResult
from swarm_env_agents.cbs_rrt.config import CBSRRTConfig
from swarm_env_agents.cbs_rrt.constraints import Constraint
from swarm_env_agents.cbs_rrt.distance_field import distance_field
from swarm_env_agents.cbs_rrt.goals import FormationGoals, GoalWindow, JumpRule
from swarm_env_agents.cbs_rrt.hold import SlotHolder
from swarm_env_agents.cbs_rrt.hold_plan import (
    CHORD_ALLOWANCE,
    Lattice,
    PlanTracker,
    PointModel,
    joint_paths,
    virtual_leader_done_step,
)
from swarm_env_agents.cbs_rrt.primitives import MotionPrimitives
from swarm_env_agents.cbs_rrt.rrt import GoalSpec, PrimitiveRRT, RRTConfig
from swarm_env_agents.cbs_rrt.swarm import LowLevelOptions, RRTLowLevel, SplitRule, TimedConflicts
from swarm_env_agents.cbs_rrt.timed_path import START, TAIL, TimedPath
from swarm_env_agents.vo_expert import EXPERT_AVOIDANCE

if TYPE_CHECKING:
    from swarm_env.env import SwarmEnv

__all__ = ["CBSRRTExpert", "ReplanRecord", "make_policy"]

_CONSTRAINT_SLACK = 0.05  # m, ConstraintTable's inflation of the constraint discs
_SHIELD_FRACTIONS = np.array([0.25, 0.5, 0.75, 1.0])[None, :]  # points of the next step's arc checked
_HOLD_POINTS = 4  # points the formation holder scores: the next step and three more over hold_horizon
_HOLD_PATIENCE = 5.0  # s a follower may stay beyond the capture distance before the holder hands back to CBS
_PLAN_PITCH = 0.05  # m: hold_plan's lattice
_PLAN_MAX_STEPS = 400  # hold_plan plans at most this many steps ahead
_PLAN_CELL_STEPS = 2.5e7  # and at most this many lattice cells x steps (int16 values: 50 MB per follower's DP)
_PLAN_TAIL = 20  # steps planned at a time once the leader has stopped
_PLAN_DEVIATION = 0.5  # m off its planned path that makes hold_plan plan the formation again
_PLAN_RETRY = 2.0  # s between two such plans
_TRACK_STEPS = 5  # steps hold_plan's tracker looks ahead
_PLAN_ROUNDS = 1  # rounds of best responses (a second one gained nothing on paper_cbs_switch)
_PLAN_GAP = 0.02  # m the plans keep beyond contact-free (robots; half of it to obstacles) for the tracker's errors
_PLAN_REACH = 2.5  # m: a planned follower stays this close to its slot in x and y (the leader's turn moves slots 2.04 m)

REPLAN_REASONS = ("initial", "switch", "goal_jump", "horizon", "rolling", "deviation", "goal_moved", "retry")


@dataclass
class ReplanRecord:
    """One replanning of the swarm (kept when ``record=True``; the last one always): its
    time and reasons, the end of the window CBS resolved (``t_end``), the robots' poses,
    the goal courses, the CBS result (root and final paths), wall time and RRT iterations."""

    time: float
    reasons: tuple[str, ...]
    t_end: float
    poses: np.ndarray
    goals: GoalWindow
    result: CBSResult
    wall_time: float
    rrt_iterations: int


class CBSRRTExpert:
    """Centralized CBS + motion-primitive RRT planner with pure-pursuit tracking (paper 000).

    A :class:`swarm_env.harness.policies.Policy`: ``reset(env, seed)``, ``act(observations, state)
    -> {agent: action}`` (continuous actions ``(v / max_speed, omega / max_turn_rate)``,
    float32), ``stats()``. Needs the env's continuous action space.

    Options: every field of :class:`~swarm_env_agents.cbs_rrt.config.CBSRRTConfig` (documented there), as a keyword
    (``CBSRRTExpert(hold_plan=False)``), a whole ``config``, or both (the keywords replace the config's fields);
    ``cbs_rrt:KEY=VALUE`` on the command line. Each is also an attribute (``expert.horizon``); ``expert.config``
    holds them all.
    """

    def __init__(self, config: CBSRRTConfig | None = None, **options: Any) -> None:
        cfg = CBSRRTConfig(**options) if config is None else dataclasses.replace(config, **options)
        self.config = cfg
        for f in dataclasses.fields(cfg):
            setattr(self, f.name, getattr(cfg, f.name))
        # The vo expert's avoidance for a robot stepping aside; the other followers drive their plans and do not
        # take half of it (not reciprocal).
        self._evade_params = AvoidanceParams(**{**EXPERT_AVOIDANCE, "reciprocal": False})
        self._scenario: Any = None
        self._rng = np.random.default_rng(0)
        self._reset_episode()

    @classmethod
    def policy_parameters(cls) -> dict[str, Any]:
        """Every option ``cbs_rrt:KEY=VALUE`` accepts, with its default (:class:`CBSRRTConfig`)."""
        return {f.name: f.default for f in dataclasses.fields(CBSRRTConfig)}

    # ------------------------------------------------------------------ setup
    def _reset_episode(self) -> None:
        self.plans: list[TimedPath] | None = None
        self.history: list[ReplanRecord] = []
        self.last: ReplanRecord | None = None
        self._plan_formation = -1
        self._next_replan = math.inf
        self._last_replan = -math.inf
        self._goals_now: GoalWindow | None = None
        self._specs: list[GoalSpec] = []
        self._fallback_robots: set[int] = set()
        self._keeping: frozenset[int] = frozenset()
        self._retry_streak = 0
        self._retry_delay = self.min_replan_interval
        self._times: list[float] = []
        self._cpu_times: list[float] = []
        self._reasons = {r: 0 for r in REPLAN_REASONS}
        self._nodes = 0
        self._nodes_max = 0
        self._conflicts_resolved = 0
        self._calls = 0
        self._repairs = 0
        self._rrt_iterations = 0
        self._partial = 0
        self._stationary = 0
        self._dropped = 0
        self._unsolved = 0
        self._gaps: list[np.ndarray] = []
        self._shield_stops = 0
        self._evade_steps = 0
        self._reverse_steps = 0
        self._shield_others: tuple[np.ndarray, ...] | None = None
        self._held = -1  # the formation index the holder drives (-1: none reached yet)
        self._hold_steps = 0
        self._hold_releases = 0
        self._far_since = np.full(0, np.inf)  # per follower: since when it is beyond the capture distance
        self._hold_course: tuple[int, int, np.ndarray] | None = None  # hold_plan: (formation, first step, paths)
        self._hold_course_time = -math.inf
        self._hold_plans = 0
        self._hold_plan_cpu: list[float] = []
        self._hold_plan_wall: list[float] = []

    def reset(self, env: SwarmEnv, seed: int | None) -> None:
        if env.action_type != "continuous":
            raise ValueError("policy 'cbs_rrt' drives the continuous action space only (action_type='continuous')")
        self._rng = np.random.default_rng(seed)
        self._scenario = None  # set up lazily from the first state (the scenario may be new)
        self._reset_episode()

    def setup(self, state: WorldState) -> None:
        """Build the per-scenario parts from a state of it (done by :meth:`act` on the first state
        of a new scenario): motion primitives, distance field, formation layer, RRT."""
        scn = state.scenario
        robots = scn.robots
        # The goal grid must contain every step time (replans happen at steps): its step is
        # the env's dt divided by a whole number, as close to goal_dt as that allows.
        env_dt = scn.world.dt
        goal_dt = env_dt / max(1, round(env_dt / self.goal_dt))
        self._goal_dt = goal_dt
        self._radius = float(robots.radius)
        self._limits = np.array([robots.max_speed, robots.max_turn_rate], dtype=np.float64)
        fraction = self.speed_fraction
        if fraction is None:
            # 0.7 of the top speed leaves the tracker room to catch up; against a fast leader
            # the robots need more to ever reach their slots (leader speed + a quarter).
            lead = scn.leader.speed / robots.max_speed
            fraction = max(0.7, min(0.9, lead + 0.25))
        self.primitives = MotionPrimitives.for_robot(
            robots.max_speed,
            robots.max_turn_rate,
            angles_deg=self.primitive_angles,
            speed_fraction=fraction,
            step=self.primitive_step,
            samples=self.primitive_samples,
            spin_deg=self.turn_in_place,
        )
        self.field = distance_field(state.static, self.field_resolution)
        self.buffer = self._radius + self.obstacle_margin
        self.separation = 2.0 * self._radius + self.robot_margin
        self.formation = FormationGoals(
            scn,
            state.static,
            clearance=self.buffer + 0.02,  # tracking errors of a few cm stay out of the buffer zone
            # Pushed a little beyond the conflict distance: the rounds stop short of it where
            # obstacles squeeze slots together, and goals that never conflict leave CBS nothing
            # it cannot solve.
            separation=self.separation + 0.05,
            dt=goal_dt,
            jumps=JumpRule(speed=0.8 * robots.max_speed, window=self.jump_window, lag=self.jump_lag,
                           window_speed=robots.max_speed, chord_clearance=self._radius + self.shield_margin),
        )
        config = RRTConfig(
            max_iterations=self.rrt_iterations,
            goal_bias=self.goal_bias,
            goal_tolerance=self.goal_tolerance,
            max_wait=self.max_wait,
            smoothing=self.smoothing,
            follow_speed=self.primitives.speed,
        )
        # A robot that starts inside the buffer zone may move on inside it, but not down to
        # where the tracker's shield would stop it.
        floor = self._radius + self.shield_margin + 0.02
        self.rrt = PrimitiveRRT(self.primitives, self.field, self.buffer, config, floor=floor)
        self.holder = SlotHolder(
            self.field, robots, scn.world, shield_margin=self.shield_margin, horizon=_HOLD_POINTS,
            every=max(1, round((self.hold_horizon - env_dt) / (env_dt * (_HOLD_POINTS - 1)))),
        )
        self._slot_course: np.ndarray | None = None
        self._tracker: PlanTracker | None = None
        if (self.hold_slots or self.hold_plan) and scn.leader.kind == "virtual":
            # A virtual leader's slots are a function of time: the env's own, for the whole episode.
            steps = int(math.ceil(scn.world.max_time / env_dt)) + max(int(self.holder.steps_ahead()[-1]), _TRACK_STEPS) + 1
            self._slot_course = virtual_slot_trajectory(scn, state.static, steps)[0]
            self._leader_done_step = virtual_leader_done_step(scn, steps)
            # The plan's lattice must resolve a step's travel: the random worlds' dt = 0.1 s moves a robot one cell.
            # The plan has no humans in it (nor a shield): with humans about it left 26 of 60 random worlds at
            # dt = 0.5 s with a contact, CBS none.
            if self.hold_plan and robots.max_speed * env_dt >= 4 * _PLAN_PITCH and not scn.humans:
                self._tracker = PlanTracker(
                    self.field, robots, scn.world, separation=2.0 * self._radius + _PLAN_GAP, horizon=_TRACK_STEPS,
                )
        self._scenario = scn

    # ------------------------------------------------------------------ acting
    def act(self, observations: dict[str, np.ndarray], state: WorldState) -> dict[str, Any]:
        if self._scenario is not state.scenario:
            self.setup(state)
            self._reset_episode()
        if (self.hold_slots or self._tracker is not None) and self._holding(state):
            twist = self._hold(state)
        else:
            reasons = self._triggers(state)
            if reasons:
                self._replan(state, reasons)
            twist = self._track(state)
        if self.evade_horizon > 0 and len(state.human_pos):
            twist = self._evade(state, twist)
        action = np.clip(twist / self._limits, -1.0, 1.0).astype(np.float32)
        return {a: action[int(a.rsplit("_", 1)[1])] for a in observations}

    def plan(
        self, state: WorldState, reasons: Sequence[str] = ("initial",), rng: np.random.Generator | None = None
    ) -> ReplanRecord:
        """Replan the whole swarm from ``state`` now (what :meth:`act` does when a trigger
        fires) and return the record: goals, the independent root plans and the CBS result.
        ``rng`` replaces the policy's generator (figures and experiments)."""
        if rng is not None:
            self._rng = rng
        if self._scenario is not state.scenario:
            self.setup(state)
            self._reset_episode()
        self._replan(state, [r if r in REPLAN_REASONS else "initial" for r in reasons])
        assert self.last is not None
        return self.last

    def _plan_positions(self, t: float) -> np.ndarray:
        assert self.plans is not None
        return np.array([p.position_at(t) for p in self.plans])

    def _triggers(self, state: WorldState) -> list[str]:
        if self.plans is None:
            return ["initial"]
        t = state.time
        out = []
        if state.formation_index != self._plan_formation:
            out.append("switch")
        if t >= self._next_replan - 1e-9:
            out.append(self._next_reason)
        dev = np.hypot(*(state.follower_pose[:, :2] - self._plan_positions(t)).T)
        if self._keeping:  # robots in formation: the wider keep_tolerance (hysteresis)
            dev[list(self._keeping)] -= max(self.keep_tolerance - self.deviation_tolerance, 0.0)
        if np.any(dev > self.deviation_tolerance):
            out.append("deviation")
        if t - self._last_replan >= self.min_replan_interval - 1e-9:
            g = self._goals_now
            if g is not None and t <= g.t[-1]:
                gx = np.array([np.interp(t, g.t, g.xy[i, :, 0]) for i in range(len(g.xy))])
                gy = np.array([np.interp(t, g.t, g.xy[i, :, 1]) for i in range(len(g.xy))])
                moved = np.hypot(state.slot_targets[:, 0] - gx, state.slot_targets[:, 1] - gy)
                if np.any(moved > self.goal_move_tolerance):
                    out.append("goal_moved")
        if self._fallback_robots and t - self._last_replan >= self._retry_delay - 1e-9:
            out.append("retry")
        return out

    def thresholds(self, poses: np.ndarray) -> np.ndarray:
        """``(N, N)`` conflict distances for robots at ``poses``: ``2 r + robot_margin``, lowered
        for pairs already about that close."""
        return self._thresholds(poses)

    def _thresholds(self, poses: np.ndarray) -> np.ndarray:
        n = len(poses)
        diff = poses[:, None, :2] - poses[None, :, :2]
        d = np.sqrt(np.add.reduce(diff * diff, axis=2))
        D = np.full((n, n), self.separation)
        # Robots already about as close as the conflict distance may stay that close, but not
        # close in further: otherwise a conflict at t0 would be unavoidable. The extra room is
        # the constraint table's slack, so a robot's start never violates its constraints.
        room = _CONSTRAINT_SLACK + 0.01
        close = d < self.separation + room
        D[close] = np.maximum(d[close] - room, 2.0 * self._radius + 0.01)
        np.fill_diagonal(D, 0.0)
        return D

    def _replan(self, state: WorldState, reasons: list[str]) -> None:
        wall0 = time.perf_counter()
        cpu0 = time.process_time()
        t0 = float(state.time)
        poses = np.array(state.follower_pose, dtype=np.float64)
        n = len(poses)
        gw = self.formation.window(t0, t0 + self.horizon, state.leader_pose)
        K = len(gw.t)
        jump_t = np.where(gw.piece_end < K - 1, gw.t[np.minimum(gw.piece_end + 1, K - 1)], math.inf)
        renew = t0 + self.horizon - self.check_margin
        t_next = min(float(jump_t.min()), renew)
        self._next_reason = "goal_jump" if float(jump_t.min()) < renew else "horizon"
        # Conflicts matter until shortly after the next replan (t_check); CBS resolves them
        # over at most conflict_window now and the rest at a rolling replan (RHCR-style).
        t_check = min(t0 + self.horizon, t_next + self.check_margin)
        t1 = min(t_check, t0 + self.conflict_window)
        k1 = min(K - 1, max(1, int(math.ceil((t1 - t0) / self._goal_dt - 1e-9))))
        t1 = float(gw.t[k1])
        # The RRT sees the whole horizon (an approach may take longer than the time to the
        # next replan); conflicts only matter until shortly after that replan (t1).
        specs = [GoalSpec(gw.t, gw.xy[i], gw.heading, int(gw.piece_end[i])) for i in range(n)]
        movers = self._movers(state, gw)
        options = LowLevelOptions(constraint_slack=_CONSTRAINT_SLACK, child_iterations=self.rrt_child_iterations,
                                  strong_iterations=self.rrt_strong_iterations, park_until=t1 + self.check_margin)
        low = RRTLowLevel(self.rrt, poses, t0, float(gw.t[-1]), specs, self._rng, options=options,
                          extra_constraints=movers)
        # A robot whose goal course jumps is replanned then: its parked plan counts only a little
        # beyond (the check margin), not as an obstacle until the horizon.
        until = np.where(np.isfinite(jump_t), jump_t + self.check_margin, np.inf)
        rule = SplitRule(window_after=self.constraint_window, strong=self.strong_constraints,
                         min_radius=2.0 * self._radius + 0.01, start_room=_CONSTRAINT_SLACK + 0.01)
        model = TimedConflicts(self._thresholds(poses), t0, t1, t_plan=float(gw.t[-1]), until=until, rule=rule)
        reused = self._reusable(state, specs, t1, reasons)
        keep = self._keepers(state, gw, t1, reasons)
        if self.use_cbs:
            result, keep = self._solve_cbs(low, model, reused, keep, n)
        else:
            result = self._solve_alone(low, model, keep, n)
        self._keeping = frozenset(keep)
        self.plans = list(result.paths)
        self._plan_formation = state.formation_index
        self._next_replan = t_next
        if t1 < t_check - 1e-9:
            # Conflicts left beyond the resolved window (or robots on fallback plans): plan
            # again before the window runs out.
            later = model.all_conflicts(self.plans) if not result.fallback_used else [None]
            if not later:
                later = TimedConflicts(model.D, t1, t_check).all_conflicts(self.plans)
            if later:
                t_roll = t0 + max(self.conflict_window - self.check_margin, self.min_replan_interval)
                if t_roll < self._next_replan:
                    self._next_replan, self._next_reason = t_roll, "rolling"
        self._last_replan = t0
        self._goals_now = gw
        self._specs = specs
        self._fallback_robots = set(result.stationary) | set(result.dropped) | {
            i for i, p in enumerate(self.plans) if not p.reached
        }
        # Retry fallback robots after min_replan_interval, doubling the wait (up to 8x) while
        # the same deadlock persists: a stuck formation should not cost a full search a second.
        self._retry_streak = self._retry_streak + 1 if self._fallback_robots else 0
        self._retry_delay = self.min_replan_interval * 2.0 ** min(max(self._retry_streak - 1, 0), 3)
        wall = time.perf_counter() - wall0
        self._cpu_times.append(time.process_time() - cpu0)
        self._count(reasons, result, low, wall)
        record = ReplanRecord(t0, tuple(reasons), t1, poses, gw, result, wall, low.iterations)
        self.last = record
        if self.record:
            self.history.append(record)

    def _solve_cbs(self, low: RRTLowLevel, model: TimedConflicts, reused: list[TimedPath] | None,
                   keep: dict[int, TimedPath], n: int) -> tuple[CBSResult, dict[int, TimedPath]]:
        """CBS over the ``n`` robots with the robots in formation (``keep``) fixed on their paths, releasing those
        that another robot cannot get round; returns the result and the robots still kept."""
        cbs = CBS(
            low, model, max_nodes=self.cbs_nodes, max_low_level_calls=self.cbs_low_level_calls,
            suboptimality=self.cbs_suboptimality,
        )
        while True:
            initial = list(reused) if reused is not None else [None] * n
            for i, path in keep.items():
                initial[i] = path
            result = cbs.solve(n, initial, fixed=sorted(keep))
            if not keep:
                break
            # A robot in formation that still conflicts with another robot's final plan (one
            # CBS could not route round it and left standing) is planned with the rest after all.
            clash = {a for c in model.all_conflicts(result.paths) for a in c.agents if a in keep}
            if clash:
                keep = {i: p for i, p in keep.items() if i not in clash}
            else:
                failed = set(result.stationary) | set(result.dropped) | {
                    i for i, p in enumerate(result.paths) if not p.reached and i not in keep}
                if not failed:
                    break
                # Some robot found no way round the fixed ones (it would stand and wait for
                # them, maybe for ever): release the robots in formation that its own plan
                # (planned as if alone) runs into — all of them if it has none.
                roots = result.root_paths
                hit = {a for c in model.all_conflicts(roots) for a in c.agents
                       if a in keep and (set(c.agents) & failed)}
                if not hit:
                    break
                keep = {i: p for i, p in keep.items() if i not in hit}
        return result, keep

    def _solve_alone(self, low: RRTLowLevel, model: TimedConflicts, keep: dict[int, TimedPath], n: int) -> CBSResult:
        """Every robot planned as if alone (``use_cbs=False``), the robots in formation on their paths."""
        paths = []
        stationary = []
        for i in range(n):
            p = keep.get(i) or low.plan(i, ())
            if p is None:
                p = low.stationary(i)
                stationary.append(i)
            paths.append(p)
        remaining = len(model.all_conflicts(paths))
        return CBSResult(paths, remaining == 0, sum(low.cost(i, p) for i, p in enumerate(paths)), list(paths),
                         low_level_calls=n, stationary=tuple(stationary), remaining_conflicts=remaining)

    def _count(self, reasons: list[str], result: CBSResult, low: RRTLowLevel, wall: float) -> None:
        """The replan's telemetry (:meth:`stats`)."""
        self._times.append(wall)
        for r in reasons:
            self._reasons[r] += 1
        self._nodes += result.nodes_expanded
        self._nodes_max = max(self._nodes_max, result.nodes_expanded)
        self._conflicts_resolved += result.conflicts_resolved
        self._calls += low.calls
        self._repairs += low.repaired
        self._rrt_iterations += low.iterations
        self._partial += sum(1 for i, p in enumerate(self.plans) if not p.reached and i not in result.stationary
                             and i not in result.dropped)
        self._stationary += len(result.stationary)
        self._dropped += len(result.dropped)
        self._unsolved += int(not result.solved)

    def _movers(self, state: WorldState, gw: GoalWindow) -> list[Constraint]:
        """Moving discs every robot keeps clear of over the whole planning window: the humans
        (a scripted human's motion is a known function of time, :func:`swarm_env.geometry.paths.human_states`,
        and it does not give way, so plans keep out of its way well ahead; a reactive one is
        predicted at its current velocity, as the VO does) and a robot leader (its predicted
        course; it also dodges, hence a wider margin). Paper 000 has neither."""
        scn = state.scenario
        out: list[Constraint] = []
        if scn.humans:
            ts = gw.t[::2] if len(gw.t) > 2 else gw.t
            pos = np.stack([human_states(scn.humans, float(t))[0] for t in ts])  # (K, H, 2)
            reactive = [h for h, spec in enumerate(scn.humans) if spec.behavior != "scripted"]
            if reactive:  # constant velocity from now (their paths say where they head, not where they go)
                ahead = (np.asarray(ts, dtype=np.float64) - state.time)[:, None, None]
                pos[:, reactive] = state.human_pos[reactive][None] + state.human_vel[reactive][None] * ahead
            for h, spec in enumerate(scn.humans):
                out.append(Constraint(-1, ts, pos[:, h], self._radius + spec.radius + self.robot_margin))
        if state.leader_is_robot:
            out.append(Constraint(-1, gw.t, gw.leader[:, :2], self._radius + state.leader_radius + 2 * self.robot_margin))
        return out

    def _movers_ahead(
        self, state: WorldState, now: tuple[np.ndarray, np.ndarray, np.ndarray], steps: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """The holder's moving discs: ``(xy (M, len(steps) + 1, 2), radius (M,))`` now and after
        each of ``steps`` env steps. As in :meth:`_movers`: a scripted human where its path puts
        it, a reactive human and a robot leader at their current velocity."""
        pos, vel, rad = now
        ahead = state.scenario.world.dt * np.concatenate([[0], steps])
        xy = pos[:, None, :] + vel[:, None, :] * ahead[None, :, None]
        humans = state.scenario.humans
        scripted = [h for h, spec in enumerate(humans) if spec.behavior == "scripted"]
        if scripted:
            future = np.stack([human_states(humans, state.time + float(a))[0] for a in ahead], axis=1)  # (H, K, 2)
            xy[scripted] = future[scripted]
        return xy, rad

    def _reusable(
        self, state: WorldState, specs: list[GoalSpec], t1: float, reasons: list[str]
    ) -> list[TimedPath | None] | None:
        """Old plans that remain valid as CBS root paths (no low-level call needed): the robot
        is on track and already on its goal course, its plan lasts until ``t1``, and the goal
        course is unchanged over the plan. Only the other robots are planned afresh."""
        if self.plans is None or "switch" in reasons or not self._specs:
            return None
        t0 = state.time
        now = self._plan_positions(t0)
        gap = np.hypot(*(state.follower_pose[:, :2] - now).T)
        out: list[TimedPath | None] = []
        for i, (plan, old, new) in enumerate(zip(self.plans, self._specs, specs)):
            ok = (
                i not in self._fallback_robots
                and plan.reached
                and (self.reuse_approach or plan.goal_time <= t0 + 1e-9)
                and gap[i] <= self.deviation_tolerance
                and plan.t_end >= t1 - 1e-9
            )
            if ok:
                sel = (new.t >= t0 - 1e-9) & (new.t <= min(old.t[-1], plan.t_end) + 1e-9)
                g_old = old.at(new.t[sel])
                ok = bool(np.all(np.abs(g_old - new.xy_eff[sel]) < 1e-6))
            out.append(plan if ok else None)
        return out

    def _keepers(self, state: WorldState, gw: GoalWindow, t1: float, reasons: list[str]) -> dict[int, TimedPath]:
        """Formation keeping: the robots that hold their slot keep following their slot course.

        A robot is *in formation* at a replan (not at a formation switch, and only with
        ``formation_keeping``) when its last plan was a full plan that had joined its goal
        course by now, it is within ``keep_tolerance`` of its new goal course, and that course
        runs without a jump up to the end of the window CBS resolves (``t1``). Its new plan is
        the course itself from now (a :data:`~swarm_env_agents.cbs_rrt.timed_path.TAIL` path up
        to the course's first jump, then parked) — no RRT call — and it is *fixed* in the CBS
        search: the other robots plan round it, and a replan (a neighbour's course jumping, a
        robot falling behind) never hands it a detour or a wait. The formation layer keeps the
        courses apart (their separation), so robots in formation do not conflict with each other.
        :meth:`_replan` releases them where that fails: a robot in formation that CBS leaves in
        conflict, and those that the independent plan of a robot left without a full plan
        (stationary, dropped, partial) runs into, are planned with the rest in another search.
        Returns ``{robot: path}``.
        """
        if not self.formation_keeping or self.plans is None or "switch" in reasons:
            return {}
        t0 = state.time
        pos = state.follower_pose[:, :2]
        out: dict[int, TimedPath] = {}
        for i, plan in enumerate(self.plans):
            end = int(gw.piece_end[i])
            if (
                i in self._fallback_robots
                or not plan.reached
                or not plan.goal_time <= t0 + 1e-9
                or float(gw.t[end]) < t1 - 1e-9
                or math.hypot(pos[i, 0] - gw.xy[i, 0, 0], pos[i, 1] - gw.xy[i, 0, 1]) > self.keep_tolerance
            ):
                continue
            k = end + 1
            pose = np.column_stack([gw.xy[i, :k], gw.heading[:k]])
            kind = np.full(k, TAIL, dtype=np.int8)
            kind[0] = START
            out[i] = TimedPath(gw.t[:k], pose, kind, [0], [-1], t0, True)
        return out

    def _track(self, state: WorldState) -> np.ndarray:
        """Twists that make each robot follow its timed path.

        Pure pursuit (:func:`swarm_env.control.pursuit.pure_pursuit`) towards the plan's position
        ``lookahead_time`` ahead, with time gap ``lookahead_time``: on the path at the plan's
        speed the command is the plan's speed; a lagging robot speeds up. Two additions:
        where the plan barely moves over the lookahead (a spin primitive, a wait, the parked
        end) the robot turns in place to the plan's heading instead; and a robot that is
        ahead of its plan along the path's direction, with the aim point behind it, waits.
        """
        assert self.plans is not None
        t = state.time
        pose = state.follower_pose
        T = self.lookahead_time
        now = self._plan_positions(t)
        carrot = self._plan_positions(t + T)
        gap = np.hypot(pose[:, 0] - now[:, 0], pose[:, 1] - now[:, 1])
        self._gaps.append(gap)
        twist = pure_pursuit(pose, carrot, self._limits[0], self._limits[1], T)
        cx, cy = pose[:, 0], pose[:, 1]
        dx, dy = carrot[:, 0] - cx, carrot[:, 1] - cy
        c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
        moves = carrot - now  # where the plan goes over the lookahead
        ahead = ((cx - now[:, 0]) * moves[:, 0] + (cy - now[:, 1]) * moves[:, 1] > 0.0) & (dx * c + dy * s < 0.0)
        twist[ahead & (np.hypot(dx, dy) < 0.25)] = 0.0
        still = np.hypot(moves[:, 0], moves[:, 1]) < 0.05
        dt = state.scenario.world.dt
        if np.any(still):
            for i in np.flatnonzero(still & (gap < 0.1)).tolist():
                err = (self.plans[i].heading_at(t + T) - pose[i, 2] + math.pi) % (2.0 * math.pi) - math.pi
                w = math.copysign(min(self._limits[1], abs(err) / dt), err) if abs(err) > 0.05 else 0.0
                twist[i] = (0.0, w)
        self._shield_others = _movers_now(state)
        return self._shield(pose, twist, dt, state.follower_twist[:, 0], dt / state.scenario.world.substeps)

    def _holding(self, state: WorldState) -> bool:
        """Whether the holder drives now: every follower came within ``settle_tolerance +
        hold_capture`` of its slot in the active formation, and none has stayed farther than that
        for ``_HOLD_PATIENCE`` since (it is stuck: a human or an obstacle the short search cannot
        get round; then CBS plans again until the swarm is close again). A slot that jumps (the
        leader turning) is caught up with sooner."""
        k = state.formation_index
        far = np.hypot(*(state.follower_pose[:, :2] - state.slot_targets).T) > (
            state.scenario.world.settle_tolerance + self.hold_capture)
        if self._far_since.shape != far.shape:
            self._far_since = np.full(far.shape, np.inf)
        self._far_since = np.where(far, np.minimum(self._far_since, state.time), np.inf)
        if self._held == k and np.any(state.time - self._far_since >= _HOLD_PATIENCE - 1e-9):
            self._held = -1
            self._hold_releases += 1
        if self._held != k and not far.any():
            self._held = k
        return self._held == k

    def _hold(self, state: WorldState) -> np.ndarray:
        """The holder's twists towards the slots over the next ``hold_horizon`` (the env's own for
        a virtual leader, the formation layer's course otherwise), through the shield; with
        ``hold_plan`` (and a virtual leader) the tracker's twists along the formation's plan."""
        if self._tracker is not None:
            return self._hold_by_plan(state)
        scn = state.scenario
        dt = scn.world.dt
        steps = self.holder.steps_ahead()
        if self._slot_course is not None:
            k = int(round(state.time / dt))
            targets = self._slot_course[k + steps]
        else:
            per_step = int(round(dt / self._goal_dt))
            gw = self.formation.window(state.time, state.time + int(steps[-1]) * dt, state.leader_pose)
            targets = gw.xy[:, per_step * steps].transpose(1, 0, 2)
        now = _movers_now(state)
        twist = self.holder.twists(state.follower_pose, state.follower_twist, targets, self._movers_ahead(state, now, steps))
        self._hold_steps += 1
        self._shield_others = now
        return self._shield(state.follower_pose, twist, dt, state.follower_twist[:, 0], dt / scn.world.substeps)

    def _hold_by_plan(self, state: WorldState) -> np.ndarray:
        """``hold_plan``: plan the formation to the next switch or the leader's stop (at most
        ``_PLAN_MAX_STEPS`` ahead) from where the robots are, once per reached formation and again
        when a robot is ``_PLAN_DEVIATION`` off its path (at most every ``_PLAN_RETRY``) or the
        plan runs out, then track it (:mod:`~swarm_env_agents.cbs_rrt.hold_plan`). The plan's
        contact-free margins replace the shield (which would stop robots the plan takes past an
        obstacle closer than ``shield_margin``). Only used in worlds without humans (they are not in the plan)."""
        assert self._tracker is not None and self._slot_course is not None
        scn = state.scenario
        dt = scn.world.dt
        k = int(round(state.time / dt))
        pose = state.follower_pose
        course = self._hold_course
        stale = course is None or course[0] != state.formation_index or k - course[1] >= len(course[2]) - 1
        if not stale and state.time - self._hold_course_time >= _PLAN_RETRY - 1e-9:
            assert course is not None
            stale = bool(np.any(np.hypot(*(pose[:, :2] - course[2][k - course[1]]).T) > _PLAN_DEVIATION))
        if stale:
            cpu0, wall0 = time.process_time(), time.perf_counter()
            # To the leader's stop (after it, a while more: the slots stand still), the next switch, the end
            # of the course, and at most _PLAN_MAX_STEPS and _PLAN_CELL_STEPS of lattice values.
            k_end = self._leader_done_step if k + 1 < self._leader_done_step else k + _PLAN_TAIL
            k_end = min(k_end, k + _PLAN_MAX_STEPS, len(self._slot_course) - 1)
            if math.isfinite(state.next_switch_time):
                k_end = min(k_end, int(round(state.next_switch_time / dt)) - 1)
            while k_end > k + 1 and self._lattice_cells(k, k_end) * (k_end - k + 1) > _PLAN_CELL_STEPS:
                k_end = k + (k_end - k) // 2
            k_end = max(k_end, k + 1)
            r = self._radius
            model = PointModel(_PLAN_PITCH, scn.world.settle_tolerance, scn.robots.max_speed * dt,
                               floor=r + CHORD_ALLOWANCE + _PLAN_GAP / 2, separation=2.0 * (r + CHORD_ALLOWANCE) + _PLAN_GAP)
            paths = joint_paths(state.static, self._slot_course, k, k_end, model, starts=pose[:, :2],
                                rounds=_PLAN_ROUNDS, reach=_PLAN_REACH)
            course = self._hold_course = (state.formation_index, k, paths)
            self._hold_course_time = state.time
            self._hold_plans += 1
            self._hold_plan_cpu.append(time.process_time() - cpu0)
            self._hold_plan_wall.append(time.perf_counter() - wall0)
        assert course is not None
        ahead = np.arange(_TRACK_STEPS + 1)
        plan = course[2][np.minimum(k - course[1] + ahead, len(course[2]) - 1)]
        slots = self._slot_course[np.minimum(k + ahead, len(self._slot_course) - 1)]
        motion = np.column_stack([pose, state.follower_vel, state.follower_twist[:, 1]])
        self._hold_steps += 1
        return self._tracker.twists(motion, plan, slots)

    def _lattice_cells(self, k: int, k_end: int) -> float:
        """About how many cells the largest of the followers' lattices from ``k`` to ``k_end`` has."""
        assert self._slot_course is not None
        course = self._slot_course[k : k_end + 1]
        return float(max(nx * ny for _, nx, ny in (Lattice.extent(course[:, i], _PLAN_PITCH) for i in range(course.shape[1]))))

    def _evade(self, state: WorldState, twist: np.ndarray) -> np.ndarray:
        """``twist`` with the robots that a human would reach within ``evade_horizon`` (were they
        to stand still) driven by the velocity-obstacle search instead, towards their twists."""
        threat = _humans_reach(state, self.evade_horizon, self.shield_margin)
        if not threat.any():
            return twist
        res = safe_follower_twists(state, twist, self._evade_params)
        answer = res.twist
        if self.evade_reverse > 0:  # boxed in with the human coming: back off (the vo expert's rule)
            params = reversing_params(self._evade_params, self.evade_reverse, state.scenario.robots.max_speed,
                                      self.evade_reverse_horizon)
            answer, taken = back_off(state, twist, res, threat & ~res.feasible, params)
            self._reverse_steps += int(taken.sum())
        twist = twist.copy()
        twist[threat] = answer[threat]
        self._evade_steps += int(threat.sum())
        return twist

    def _shield(
        self, pose: np.ndarray, twist: np.ndarray, dt: float, speed_now: np.ndarray, sub_dt: float
    ) -> np.ndarray:
        """Last line of defence: a robot whose commanded arc over the next step would bring it
        within ``shield_margin`` of an obstacle (distance field), of another robot's commanded
        arc, or of a human or robot leader moving on at its velocity — closer than it is
        now — only turns in place this step
        (a disc that turns cannot hit anything). The plans' margins make this rare; each use
        is counted in ``stats()['shield_stops']``."""
        if self.shield_margin <= 0:
            return twist
        frac = _SHIELD_FRACTIONS * dt
        x0, y0, th = pose[:, 0:1], pose[:, 1:2], pose[:, 2:3]

        def arcs(tw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            v, w = tw[:, 0:1], tw[:, 1:2]
            turning = np.abs(w) > 1e-9
            ws = np.where(turning, w, 1.0)
            a = th + w * frac
            px = np.where(turning, x0 + v / ws * (np.sin(a) - np.sin(th)), x0 + v * np.cos(th) * frac)
            py = np.where(turning, y0 - v / ws * (np.cos(a) - np.cos(th)), y0 + v * np.sin(th) * frac)
            return px, py

        r = self._radius
        # The env applies a new command one physics substep late (the position update of a
        # substep uses the velocity set in the previous one): allow for that much travel.
        lag = np.abs(speed_now) * sub_dt
        px, py = arcs(twist)
        now = self.field.clearance_xy(pose[:, 0], pose[:, 1])
        ahead = self.field.clearance_xy(px, py).min(axis=1)
        stop = (ahead < r + self.shield_margin + lag) & (ahead < now)
        if stop.any():
            twist = twist.copy()
            twist[stop, 0] = 0.0
            px, py = arcs(twist)
        others = self._shield_others
        if others is not None and len(others[0]):
            # Humans and a robot leader, moving on at their current velocities.
            opos, ovel, orad = others
            ox = opos[:, 0:1] + ovel[:, 0:1] * frac  # (M, F)
            oy = opos[:, 1:2] + ovel[:, 1:2] * frac
            d_pred = np.sqrt((px[:, None, :] - ox[None]) ** 2 + (py[:, None, :] - oy[None]) ** 2).min(axis=2)
            d_now = np.hypot(pose[:, None, 0] - opos[None, :, 0], pose[:, None, 1] - opos[None, :, 1])
            near = ((d_pred < r + orad[None, :] + self.shield_margin + lag[:, None]) & (d_pred < d_now)).any(axis=1)
            near &= twist[:, 0] != 0.0
            if near.any():
                twist = twist.copy()
                twist[near, 0] = 0.0
                stop |= near
                px, py = arcs(twist)
        n = len(pose)
        if n > 1:
            dx = px[:, None, :] - px[None, :, :]
            dy = py[:, None, :] - py[None, :, :]
            d_pred = np.sqrt(dx * dx + dy * dy).min(axis=2)
            d_now = np.hypot(pose[:, None, 0] - pose[None, :, 0], pose[:, None, 1] - pose[None, :, 1])
            close = (d_pred < 2.0 * r + self.shield_margin + lag[:, None] + lag[None, :]) & (d_pred < d_now)
            np.fill_diagonal(close, False)
            pair = close.any(axis=1) & (twist[:, 0] != 0.0)
            if pair.any():
                twist = twist.copy()
                twist[pair, 0] = 0.0
                stop |= pair
        self._shield_stops += int(stop.sum())
        return twist

    # ------------------------------------------------------------------ telemetry
    def stats(self) -> dict[str, Any]:
        """Telemetry of the current episode (lands in the metrics JSON under ``policy_stats``).

        ``replans`` (and ``replan_reasons``), ``cbs_nodes_expanded`` (total and ``_max`` per
        replan), ``conflicts_resolved`` (constraints on the returned CBS nodes, summed),
        ``low_level_calls`` (RRT searches), ``repairs`` (CBS children made by inserting waits
        into the parent's path instead), ``rrt_iterations``, ``planning_time_ms`` (wall time per
        replan: median, p95, max, mean; ``total_s``), ``planning_cpu_ms`` (the same in CPU time of
        this process: what a shared machine does not inflate), ``fallbacks`` (``stationary``: robots whose plan failed,
        ``dropped``: robots removed from active planning, ``partial``: plans that stop short
        of the goal, ``unsolved``: replans that ended with conflicts), ``hold_steps`` (steps
        driven by the formation holder, ``hold_plan`` or ``hold_slots``), ``hold_plans`` (plans of a
        reached formation, ``hold_plan``; ``hold_plan_s`` and ``hold_plan_cpu_s`` their wall and CPU
        time), ``hold_releases`` (times it handed a
        formation back to CBS, a follower too far behind) and ``tracking_gap_m`` — the distance between each robot and its plan's position at the
        same time, over all steps (mean, p95, max).
        """
        gaps = np.concatenate(self._gaps) if self._gaps else np.zeros(0)
        return {
            "replans": len(self._times),
            "replan_reasons": dict(self._reasons),
            "cbs_nodes_expanded": self._nodes,
            "cbs_nodes_expanded_max": self._nodes_max,
            "conflicts_resolved": self._conflicts_resolved,
            "low_level_calls": self._calls,
            "repairs": self._repairs,
            "rrt_iterations": self._rrt_iterations,
            "planning_time_ms": _timing_ms(self._times),
            "planning_cpu_ms": _timing_ms(self._cpu_times),
            "fallbacks": {
                "stationary": self._stationary,
                "dropped": self._dropped,
                "partial": self._partial,
                "unsolved": self._unsolved,
            },
            "shield_stops": self._shield_stops,
            "evade_steps": self._evade_steps,
            "reverse_steps": self._reverse_steps,
            "hold_steps": self._hold_steps,
            "hold_plans": self._hold_plans,
            "hold_plan_s": round(float(sum(self._hold_plan_wall)), 3),
            "hold_plan_cpu_s": round(float(sum(self._hold_plan_cpu)), 3),
            "hold_releases": self._hold_releases,
            "tracking_gap_m": {
                "mean": float(gaps.mean()) if gaps.size else None,
                "p95": float(np.percentile(gaps, 95)) if gaps.size else None,
                "max": float(gaps.max()) if gaps.size else None,
            },
        }


def _humans_reach(state: WorldState, horizon: float, margin: float) -> np.ndarray:
    """``(N,)``: a human walking on at its current velocity comes within ``margin`` of the follower
    within ``horizon`` (s), were the follower to stand still."""
    n, n_h = len(state.follower_pose), len(state.human_pos)
    rel = (state.human_pos[None, :, :] - state.follower_pose[:, None, :2]).reshape(-1, 2)
    reach = (state.follower_radius[:, None] + np.broadcast_to(state.human_radius, (n_h,))[None, :] + margin).reshape(-1)
    closing = np.broadcast_to(-state.human_vel[None, :, :], (n, n_h, 2)).reshape(1, -1, 2)
    return (disc_time_to_collision(rel, reach, closing, horizon) <= horizon).reshape(n, n_h).any(axis=1)


def _movers_now(state: WorldState) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The moving discs a follower keeps clear of now: ``(pos (M, 2), vel (M, 2), radius (M,))`` of
    the humans and a robot leader."""
    others = [(state.human_pos, state.human_vel, state.human_radius)]
    if state.leader_is_robot:
        others.append((state.leader_pose[None, :2], state.leader_vel[None, :], np.array([state.leader_radius])))
    pos, vel, rad = (np.concatenate(parts) for parts in zip(*others))
    return pos, vel, rad


def _timing_ms(seconds: Sequence[float]) -> dict[str, Any]:
    """Per-replan durations (s) summarised in ms: ``median``, ``p95``, ``max``, ``mean`` (``None``
    without replans) and ``total_s`` (their sum, s)."""
    t = np.array(seconds, dtype=np.float64) * 1e3
    if not t.size:
        return {"median": None, "p95": None, "max": None, "mean": None, "total_s": 0.0}
    return {
        "median": float(np.median(t)),
        "p95": float(np.percentile(t, 95)),
        "max": float(t.max()),
        "mean": float(t.mean()),
        "total_s": float(t.sum() / 1e3),
    }


#: Entry-point factory (``swarm_env.policies`` group, name ``cbs_rrt``): ``cbs_rrt[:KEY=VALUE,...]`` sets
#: :class:`CBSRRTExpert` parameters, e.g. ``cbs_rrt:use_cbs=false,horizon=20``.
make_policy = expert_factory("cbs_rrt", CBSRRTExpert)
