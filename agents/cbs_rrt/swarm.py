"""The swarm's CBS instance: the RRT as low-level planner and continuous conflicts between timed paths.

One replanning of the whole swarm at time ``t0`` over ``[t0, t1]`` is a CBS
problem (:class:`swarm_env_agents.cbs_rrt.cbs.CBS`) made of

* :class:`RRTLowLevel` — plans one robot with :class:`~swarm_env_agents.cbs_rrt.rrt.PrimitiveRRT`
  from its current pose to its moving formation goal under its constraints;
  the cost of a path is paper 000's ``dist(s_i, G_i)`` summed over the window:
  the integral of the distance to the goal (m s), so CBS prefers the solution
  that keeps the formation best;
* :class:`TimedConflicts` — the first conflict between two timed paths
  (:func:`~swarm_env_agents.cbs_rrt.conflicts.find_conflicts`, continuous), split into two
  children: robot ``a`` must keep clear of robot ``b``'s planned path (all of it,
  or failing that around the conflict, or failing that of ``b``'s position at
  the conflict for a few seconds), or the other way round
  (:class:`~swarm_env_agents.cbs_rrt.constraints.Constraint`, see :meth:`TimedConflicts.split`).
  A robot that CBS has fixed (stationary) is avoided over the whole window.

A child is first made by *repairing* the robot's path in the parent node with
waits (:meth:`~swarm_env_agents.cbs_rrt.rrt.PrimitiveRRT.repair`); only if that fails is
the RRT run again, with a smaller budget than at the root and without partial
paths.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from swarm_env_agents.cbs_rrt.conflicts import Conflict, find_conflicts, pair_min_distance
from swarm_env_agents.cbs_rrt.constraints import Constraint, ConstraintTable
from swarm_env_agents.cbs_rrt.rrt import GoalSpec, PrimitiveRRT
from swarm_env_agents.cbs_rrt.timed_path import TimedPath

__all__ = ["LowLevelOptions", "RRTLowLevel", "SplitRule", "TimedConflicts", "PathConflict"]


@dataclass(frozen=True)
class LowLevelOptions:
    """How :class:`RRTLowLevel` plans.

    Attributes:
        constraint_dt, constraint_slack: see :class:`ConstraintTable`.
        child_iterations: RRT budget under constraints (CBS children; default: the RRT's own);
            children get no partial paths (a partial path only costs CBS a detour).
        strong_iterations: RRT budget for a constraint that has a weaker alternative (default:
            ``child_iterations``).
        park_until: a partial root path must let the robot stay at its end until then
            (default: the horizon; the expert uses the end of the checked window).
    """

    constraint_dt: float = 0.1
    constraint_slack: float = 0.05
    child_iterations: int | None = None
    strong_iterations: int | None = None
    park_until: float | None = None


class RRTLowLevel:
    """CBS low-level planner: one :class:`PrimitiveRRT` call per robot and constraint set.

    Args:
        rrt: the planner (static map, primitives and buffer inside).
        poses: ``(N, 3)`` current poses.
        t0, t1: the planning window (s).
        goals: one :class:`GoalSpec` per robot on a common grid covering ``[t0, t1]``.
        rng: the generator every RRT call draws from (in call order: deterministic).
        options: budgets, the constraint table's grid and the partial paths' parking time
            (:class:`LowLevelOptions`).
        extra_constraints: constraints every robot always has (the humans' and a robot
            leader's predicted motion), on top of CBS's.
    """

    def __init__(
        self,
        rrt: PrimitiveRRT,
        poses: np.ndarray,
        t0: float,
        t1: float,
        goals: Sequence[GoalSpec],
        rng: np.random.Generator,
        *,
        options: LowLevelOptions = LowLevelOptions(),
        extra_constraints: Sequence[Constraint] = (),
    ) -> None:
        self.rrt = rrt
        self.park_until = options.park_until
        self.extra = tuple(extra_constraints)
        full = rrt.config.max_iterations
        child, strong = options.child_iterations, options.strong_iterations
        self.child_iterations = full if child is None else int(child)
        self.strong_iterations = self.child_iterations if strong is None else int(strong)
        self.poses = np.asarray(poses, dtype=np.float64)
        self.t0, self.t1 = float(t0), float(t1)
        self.goals = list(goals)
        self.rng = rng
        self.constraint_dt = options.constraint_dt
        self.constraint_slack = options.constraint_slack
        self.calls = 0
        self.iterations = 0
        self.partial = 0
        self.failed = 0
        self.repaired = 0
        self.log: list[tuple[int, bool, bool]] = []  # (iterations, failed, reached) per RRT call

    def plan(
        self, agent: int, constraints: Sequence[Constraint], previous: TimedPath | None = None
    ) -> TimedPath | None:
        """A path for ``agent`` under ``constraints``: ``previous`` (its path in the parent CBS
        node) repaired by waiting if that works (:meth:`PrimitiveRRT.repair`), otherwise a
        new RRT."""
        table = ConstraintTable(
            self.extra + tuple(constraints), self.t0, self.t1, self.constraint_dt, self.constraint_slack
        )
        # The planners test constraints at sample points; the newest constraint (the one that
        # must exclude the conflict just found) is also checked exactly, so that CBS never
        # gets back a path with the same conflict.
        newest = constraints[-1] if constraints else None
        if previous is not None:
            fixed = self.rrt.repair(previous, self.goals[agent], table)
            if fixed is not None and fixed is not previous and not (newest and newest.violated_by(fixed)):
                self.repaired += 1
                return fixed
        if not constraints:
            # The root: full budget; a partial path (the robot gets as close as it safely can,
            # and can stay there until the next replan) is better than standing still.
            budget, partial = None, True
        elif newest is not None and newest.weaker is not None:
            budget, partial = self.strong_iterations, False  # a strong constraint: a short try
        else:
            budget, partial = self.child_iterations, False
        res = self.rrt.plan(
            self.poses[agent], self.t0, self.goals[agent], table, self.rng, max_iterations=budget,
            allow_partial=partial, park_until=self.park_until,
        )
        self.calls += 1
        self.iterations += res.iterations
        self.log.append((res.iterations, res.path is None, res.reached))
        path = res.path
        if path is not None and newest is not None and newest.violated_by(path):
            path = None
        if path is None:
            self.failed += 1
        elif not path.reached:
            self.partial += 1
        return path

    def cost(self, agent: int, path: TimedPath) -> float:
        g = self.goals[agent]
        p = path.position_at(g.t)
        err = np.hypot(p[:, 0] - g.xy_eff[:, 0], p[:, 1] - g.xy_eff[:, 1])
        return float(g.dt * (err.sum() - 0.5 * (err[0] + err[-1])))  # trapezoid rule on the even grid

    def stationary(self, agent: int) -> TimedPath:
        return TimedPath.stationary(self.poses[agent], self.t0)


@dataclass(frozen=True)
class PathConflict:
    """A :class:`Conflict` with the two paths it was found on (the split needs them)."""

    conflict: Conflict
    path_a: TimedPath
    path_b: TimedPath
    fixed: frozenset[int]

    @property
    def agents(self) -> tuple[int, int]:
        return self.conflict.agents

    @property
    def time(self) -> float:
        return self.conflict.time


@dataclass(frozen=True)
class SplitRule:
    """The constraints :meth:`TimedConflicts.split` makes of a conflict.

    Attributes:
        window_before, window_after: the constraint covers ``[t_c - before, t_c + after]``
            around the conflict time ``t_c`` (clipped to the window).
        strong: offer the strong constraint (the other robot's whole path) first.
        min_radius: the weak constraint's radius is never below this (two radii + a little).
        start_room: the weak disc stops this short of the constrained robot's start (the
            constraint table's slack + 1 cm).
    """

    window_before: float = 0.5
    window_after: float = 2.0
    strong: bool = True
    min_radius: float = 0.0
    start_room: float = 0.06


class TimedConflicts:
    """CBS conflict model for timed paths (see the module docstring).

    Args:
        thresholds: ``(N, N)`` conflict distances (m); usually ``2 r + margin``, lowered for
            pairs that already stand closer at ``t0`` so they may stay but not close in.
        t0, t1: the window checked (s).
        grid_dt: broad-phase step of :func:`find_conflicts`.
        t_plan: end of the plans (the strong constraint lasts until then; default ``t1``).
        until: ``(N,)`` time after which each robot's path stops counting (``inf``: never): a
            robot whose goal course jumps will be replanned then, so where its plan parks it
            after that is no obstacle to anyone (it only counts for a short margin).
        rule: the constraints a conflict is split into (:class:`SplitRule`).
    """

    def __init__(
        self,
        thresholds: np.ndarray,
        t0: float,
        t1: float,
        *,
        grid_dt: float = 0.25,
        t_plan: float | None = None,
        until: np.ndarray | None = None,
        rule: SplitRule = SplitRule(),
    ) -> None:
        self.strong = rule.strong
        self.min_radius = float(rule.min_radius)
        self.start_room = float(rule.start_room)
        self.t_plan = float(t1 if t_plan is None else max(t_plan, t1))
        self.until = None if until is None else np.asarray(until, dtype=np.float64)
        self.D = np.asarray(thresholds, dtype=np.float64)
        self.t0, self.t1 = float(t0), float(t1)
        self.before = float(rule.window_before)
        self.after = float(rule.window_after)
        self.grid_dt = float(grid_dt)
        self.checks = 0

    def _skip(self, n: int, fixed: frozenset[int]) -> np.ndarray | None:
        if len(fixed) < 2:
            return None
        f = np.zeros(n, dtype=bool)
        f[list(fixed)] = True
        return f[:, None] & f[None, :]

    def first_conflict(self, paths: Sequence[TimedPath], fixed: frozenset[int] = frozenset()) -> PathConflict | None:
        self.checks += 1
        found = find_conflicts(
            paths, self.D, self.t0, self.t1, grid_dt=self.grid_dt, first_only=True, skip=self._skip(len(paths), fixed),
            until=self.until,
        )
        if not found:
            return None
        c = found[0]
        return PathConflict(c, paths[c.a], paths[c.b], fixed)

    def all_conflicts(self, paths: Sequence[TimedPath], fixed: frozenset[int] = frozenset()) -> list[Conflict]:
        self.checks += 1
        return find_conflicts(
            paths, self.D, self.t0, self.t1, grid_dt=self.grid_dt, skip=self._skip(len(paths), fixed), until=self.until
        )

    def split(self, pc: PathConflict) -> list[tuple[int, Constraint]]:
        """Child ``a``: keep ``D`` from robot ``b``'s planned path from ``t_c - before`` to the end
        of the plans (``b`` goes first); if ``a`` cannot, the weaker alternatives in turn: ``b``'s
        path over ``[t_c - before, t_m + after]`` only (``t_m``: closest approach), then a disc
        that does not move at ``b``'s position at ``t_m`` over that interval (the continuous
        form of a vertex constraint: ``a`` may just wait or step aside — what two robots that
        start face to face need; shrunk so that ``a`` may stay where it is, and dropped if that
        no longer excludes the conflict). Child ``b`` likewise. Every form excludes the
        conflict. A fixed (stationary) robot is avoided over the whole window."""
        c = pc.conflict
        lo = max(self.t0, c.time - self.before)
        # The weak constraint is placed where the two robots come closest (not at the first
        # contact with the conflict distance, where it would not exclude the conflict).
        d_m, t_m = pair_min_distance(pc.path_a, pc.path_b, c.time, min(self.t1, c.time + self.after))
        hi = min(self.t1, t_m + self.after)
        pos = {c.a: pc.path_a.position_at(t_m), c.b: pc.path_b.position_at(t_m)}
        out = []
        for agent, other, other_pos, other_path in ((c.a, c.b, pos[c.b], pc.path_b), (c.b, c.a, pos[c.a], pc.path_a)):
            end = self.t_plan if self.until is None else min(self.t_plan, float(self.until[other]))
            if other in pc.fixed:
                con = Constraint.avoid_path(agent, other_path, self.t0, max(end, self.t1), c.threshold, other)
            else:
                # The weak disc never covers the constrained robot's own start (it may always
                # stay where it is), however close the other robot comes to it.
                own = pc.path_a if agent == c.a else pc.path_b
                gap = float(np.hypot(*(own.position_at(self.t0) - np.asarray(other_pos))))
                radius = max(min(c.threshold, gap - self.start_room), self.min_radius)
                weak = Constraint.at_point(agent, np.array(other_pos), lo, min(hi, max(end, lo + 1e-3)), radius, other)
                if radius <= d_m + 1e-6:
                    weak = None  # shrunk so far it no longer excludes the conflict: useless
                if self.strong:
                    # Until the plans' horizon, not just the checked window: yielding by waiting
                    # until the window is over would only hand the conflict to the next replan.
                    strong = Constraint.avoid_path(agent, other_path, lo, max(end, lo + 1e-3), c.threshold, other)
                    # Waiting for a robot that does not move gains nothing: no weak alternative.
                    span = strong.xy - strong.xy[0]
                    moves = float(np.hypot(span[:, 0], span[:, 1]).max()) > 0.1
                    weak = weak if moves else None
                    # In between: the other robot's path around the conflict only.
                    mid = Constraint.avoid_path(agent, other_path, lo, min(hi, max(end, lo + 1e-3)), c.threshold, other)
                    mid = Constraint(agent, mid.t, mid.xy, mid.radius, other, weak)
                    con = Constraint(strong.agent, strong.t, strong.xy, strong.radius, other, mid)
                else:
                    con = weak if weak is not None else Constraint.avoid_path(
                        agent, other_path, lo, min(hi, max(end, lo + 1e-3)), c.threshold, other
                    )
            out.append((agent, con))
        return out
