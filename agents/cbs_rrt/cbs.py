"""Conflict-Based Search (Sharon et al. 2015), generic over the low-level planner.

The high level searches a *constraint tree* best-first on the sum of the
robots' path costs. A node holds a set of constraints per robot and one path
per robot that respects them. Expanding a node: find the first conflict
between two robots' paths; if there is none, the node is a solution; otherwise
split it into one child per robot of the conflict, each adding a constraint
that forbids that robot its part of the conflict, and replan only that robot.

It works with any pair of objects that satisfy two small protocols:

* :class:`LowLevelPlanner` — ``plan(agent, constraints) -> path | None``,
  ``cost(agent, path) -> float``, ``stationary(agent) -> path``. The swarm uses
  a motion-primitive RRT (:mod:`swarm_env_agents.cbs_rrt.swarm`); tests plug in a grid
  space-time A* (:mod:`swarm_env_agents.cbs_rrt.grid`) and check optimal costs.
* :class:`ConflictModel` — ``first_conflict(paths, fixed)``, ``split(conflict)``
  (one ``(agent, constraint)`` per child) and ``all_conflicts(paths, fixed)``.
  A constraint may carry a ``weaker`` alternative (an attribute; a chain) that
  also excludes the conflict: when the agent cannot satisfy the constraint, the
  child is built with the next weaker one instead. The swarm uses this to ask first for
  the strong, cheap-to-search constraint "keep clear of the other robot's whole
  path" and to fall back on "keep clear of its position at the conflict".

Budgets are counts (expanded nodes, low-level calls), never wall-clock time,
so a seeded planner gives the same result on any machine.

**Fallback** (paper 000, Sec. III-C and Algorithm 1). A robot whose root plan
fails gets a *stationary* path (it stays where it is) and becomes *fixed*:
fixed robots are never replanned and conflicts with them only constrain the
other robot. When the node budget runs out with conflicts left, the robot with
the most conflicts (in the least-conflicted node seen) is *dropped from active
planning*: it is made stationary and fixed, and the search restarts from that
node's paths. Which robot: of the two robots of that node's earliest conflict,
the one with more conflicts overall (stopping a robot elsewhere in the swarm
would not resolve the conflict that blocked the search). Both fallbacks are
reported in :class:`CBSResult`. When the low-level call budget is exhausted
too, robots are dropped that way without further search until no conflict
involves a moving robot.
"""

from __future__ import annotations

import heapq
import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Generic, Protocol, TypeVar

__all__ = ["LowLevelPlanner", "ConflictModel", "CBSResult", "CBS"]

P = TypeVar("P")
C = TypeVar("C")


class LowLevelPlanner(Protocol[P, C]):
    """What CBS needs from a single-robot planner."""

    def plan(self, agent: int, constraints: Sequence[C], previous: P | None = None) -> P | None:
        """A path for ``agent`` that respects every constraint, or ``None``. ``previous`` is
        the agent's path in the parent node (``None`` at the root): a planner may repair it
        instead of planning from scratch."""
        ...

    def cost(self, agent: int, path: P) -> float:
        """The path's cost (CBS minimises the sum over robots)."""
        ...

    def stationary(self, agent: int) -> P:
        """The fallback path: ``agent`` stays where it is."""
        ...


class ConflictModel(Protocol[P, C]):
    """What CBS needs to find and split conflicts. A conflict has ``agents = (a, b)``."""

    def first_conflict(self, paths: Sequence[P], fixed: frozenset[int]) -> Any | None:
        """The earliest conflict, ignoring pairs of two fixed robots."""
        ...

    def split(self, conflict: Any) -> Sequence[tuple[int, C]]:
        """One ``(agent, constraint)`` per child node."""
        ...

    def all_conflicts(self, paths: Sequence[P], fixed: frozenset[int]) -> Sequence[Any]:
        """Every conflicting pair (one conflict each), ignoring pairs of two fixed robots."""
        ...


@dataclass
class CBSResult(Generic[P]):
    """Outcome of :meth:`CBS.solve`.

    Attributes:
        paths: one path per robot (the solution, or the fallback's paths).
        solved: no conflict left that involves a moving robot.
        cost: sum of the path costs.
        root_paths: the independent plans of the root node (no constraints): what the
            robots would do without CBS (paper 000 Fig. 3, left).
        nodes_expanded: constraint-tree nodes expanded (conflicts split), over all restarts.
        nodes_generated: child nodes created (a low-level call each that succeeded).
        low_level_calls: calls of ``planner.plan``.
        conflicts_resolved: depth of the returned node in its tree, summed over restarts:
            the conflicts its constraints resolved.
        stationary: robots whose root plan failed (stationary fallback path).
        dropped: robots removed from active planning by the budget fallback, in order.
        remaining_conflicts: conflicting pairs left in ``paths`` (0 when ``solved``).
        constraints: per robot, the constraints of the returned node.
    """

    paths: list[P]
    solved: bool
    cost: float
    root_paths: list[P]
    nodes_expanded: int = 0
    nodes_generated: int = 0
    low_level_calls: int = 0
    conflicts_resolved: int = 0
    stationary: tuple[int, ...] = ()
    dropped: tuple[int, ...] = ()
    remaining_conflicts: int = 0
    constraints: dict[int, tuple[C, ...]] = field(default_factory=dict)

    @property
    def fallback_used(self) -> bool:
        return bool(self.stationary or self.dropped)


@dataclass
class _Node(Generic[P, C]):
    paths: list[P]
    costs: list[float]
    constraints: dict[int, tuple[C, ...]]
    depth: int

    @property
    def cost(self) -> float:
        return math.fsum(self.costs)


class CBS(Generic[P, C]):
    """Conflict-Based Search over a :class:`LowLevelPlanner` and a :class:`ConflictModel`.

    Args:
        planner: the low-level planner.
        conflicts: the conflict model.
        max_nodes: node expansions per search (per restart of the fallback).
        max_low_level_calls: low-level calls over the whole :meth:`solve`, restarts included;
            once spent, the fallback drops robots greedily without searching.
        fallback: apply the paper's fallback when the budget runs out (otherwise return the
            least-conflicted node unsolved).
        suboptimality: ``1`` (default) is CBS proper, best-first on cost. ``w > 1`` expands,
            among the open nodes within ``w`` times the cheapest cost, the one with the fewest
            conflicting pairs (the focal search of ECBS, Barer et al. 2014): solutions within
            ``w`` of the optimum (for an optimal low level), found with far fewer expansions.
    """

    def __init__(
        self,
        planner: LowLevelPlanner[P, C],
        conflicts: ConflictModel[P, C],
        *,
        max_nodes: int = 64,
        max_low_level_calls: int = 256,
        fallback: bool = True,
        suboptimality: float = 1.0,
    ) -> None:
        if max_nodes < 0 or max_low_level_calls < 0:
            raise ValueError("budgets must be >= 0")
        self.planner = planner
        self.model = conflicts
        self.max_nodes = int(max_nodes)
        self.max_low_level_calls = int(max_low_level_calls)
        self.fallback = fallback
        if not suboptimality >= 1.0:
            raise ValueError(f"suboptimality must be >= 1, got {suboptimality!r}")
        self.suboptimality = float(suboptimality)

    def solve(
        self, n_agents: int, initial_paths: Sequence[P | None] | None = None, fixed: Sequence[int] = ()
    ) -> CBSResult[P]:
        """Plan ``n_agents`` robots (ids ``0..n-1``).

        ``initial_paths``: optional per-robot root paths (``None`` entries are planned);
        a caller reuses still-valid plans this way (the root needs no low-level call for them).
        ``fixed``: robots whose root path (given in ``initial_paths``) CBS never changes: the
        others keep clear of them, and conflicts among fixed robots are not searched (as for
        robots on a fallback plan).
        """
        planner, model = self.planner, self.model
        calls = 0
        stationary: list[int] = []
        root_paths: list[P] = []
        for a in range(n_agents):
            path = initial_paths[a] if initial_paths is not None and a < len(initial_paths) else None
            if path is None:
                path = planner.plan(a, ())
                calls += 1
            if path is None:
                path = planner.stationary(a)
                stationary.append(a)
            root_paths.append(path)
        fixed = frozenset(stationary) | frozenset(fixed)
        root = _Node(list(root_paths), [planner.cost(a, p) for a, p in enumerate(root_paths)], {}, 0)

        expanded = generated = resolved = 0
        dropped: list[int] = []
        while True:
            node, stats, least = self._search(root, fixed, self.max_low_level_calls - calls)
            expanded += stats[0]
            generated += stats[1]
            calls += stats[2]
            if node is not None:
                resolved += node.depth
                return CBSResult(
                    node.paths, True, node.cost, root_paths, expanded, generated, calls, resolved,
                    tuple(stationary), tuple(dropped), 0, dict(node.constraints),
                )
            # Budget spent: drop the robot with the most conflicts from active planning — one of
            # the two robots of the earliest conflict left (stopping a robot elsewhere in the
            # swarm would not resolve it).
            resolved += least.depth
            conflicts = list(model.all_conflicts(least.paths, fixed))
            counts = [0] * n_agents
            for c in conflicts:
                a, b = c.agents
                counts[a] += 1
                counts[b] += 1
            first = min(conflicts, key=lambda c: getattr(c, "time", 0.0)) if conflicts else None
            moving = [a for a in (first.agents if first is not None else ()) if a not in fixed]
            worst = max(moving, key=lambda a: (counts[a], least.costs[a], a)) if moving else None
            if not self.fallback or worst is None:
                return CBSResult(
                    least.paths, False, least.cost, root_paths, expanded, generated, calls, resolved,
                    tuple(stationary), tuple(dropped), len(conflicts), dict(least.constraints),
                )
            dropped.append(worst)
            fixed = fixed | {worst}
            paths = list(least.paths)
            costs = list(least.costs)
            paths[worst] = planner.stationary(worst)
            costs[worst] = planner.cost(worst, paths[worst])
            root = _Node(paths, costs, {}, 0)
            if calls >= self.max_low_level_calls:
                # No budget left to search: keep dropping until no moving robot conflicts.
                while True:
                    conflicts = list(model.all_conflicts(root.paths, fixed))
                    if not conflicts:
                        return CBSResult(
                            root.paths, True, root.cost, root_paths, expanded, generated, calls, resolved,
                            tuple(stationary), tuple(dropped), 0, {},
                        )
                    counts = [0] * n_agents
                    for c in conflicts:
                        a, b = c.agents
                        counts[a] += 1
                        counts[b] += 1
                    first = min(conflicts, key=lambda c: getattr(c, "time", 0.0))
                    moving = [a for a in first.agents if a not in fixed]
                    if not moving:
                        return CBSResult(
                            root.paths, False, root.cost, root_paths, expanded, generated, calls, resolved,
                            tuple(stationary), tuple(dropped), len(conflicts), {},
                        )
                    worst = max(moving, key=lambda a: (counts[a], root.costs[a], a))
                    dropped.append(worst)
                    fixed = fixed | {worst}
                    root.paths[worst] = planner.stationary(worst)
                    root.costs[worst] = planner.cost(worst, root.paths[worst])

    def _search(
        self, root: _Node[P, C], fixed: frozenset[int], call_budget: int
    ) -> tuple[_Node[P, C] | None, tuple[int, int, int], _Node[P, C]]:
        """Best-first search from ``root``: ``(solution or None, (expanded, generated, calls),
        the least-conflicted node seen)``. Nodes are ordered by cost, ties by creation order."""
        planner, model = self.planner, self.model
        counter = itertools.count()
        heap: list[tuple[float, int, _Node[P, C]]] = [(root.cost, next(counter), root)]
        expanded = generated = calls = 0
        least = root
        least_key = math.inf
        focal = self.suboptimality > 1.0
        n_conf: dict[int, int] = {}  # focal search: conflicting pairs of each node (by id)

        def pop() -> tuple[float, int, _Node[P, C]]:
            if not focal or len(heap) == 1:
                return heapq.heappop(heap)
            # ECBS-style focal list: among the nodes within the bound of the cheapest, the one
            # with the fewest conflicting pairs (then the cheapest).
            bound = heap[0][0] * self.suboptimality + 1e-12
            best_i, best_key = 0, None
            for i, (c, tie, nd) in enumerate(heap):
                if c > bound:
                    continue
                k = n_conf.get(id(nd))
                if k is None:
                    k = n_conf[id(nd)] = len(model.all_conflicts(nd.paths, fixed))
                key = (k, c, tie)
                if best_key is None or key < best_key:
                    best_i, best_key = i, key
            entry = heap[best_i]
            heap[best_i] = heap[-1]
            heap.pop()
            heapq.heapify(heap)
            return entry

        while heap:
            entry = pop()
            node = entry[2]
            conflict = model.first_conflict(node.paths, fixed)
            if conflict is None:
                return node, (expanded, generated, calls), node
            if expanded >= self.max_nodes:
                heapq.heappush(heap, entry)
                break
            expanded += 1
            # Remember the expanded node whose first conflict comes latest (the most progress);
            # conflicts are only counted exactly for a few candidates at the end.
            key = -getattr(conflict, "time", float(node.depth))
            if key < least_key:
                least, least_key = node, key
            for agent, constraint in model.split(conflict):
                if agent in fixed:
                    continue
                if calls >= call_budget:
                    break
                base = node.constraints.get(agent, ())
                cons = base + (constraint,)
                path = planner.plan(agent, cons, node.paths[agent])
                calls += 1
                weaker = getattr(constraint, "weaker", None)
                while path is None and weaker is not None and calls < call_budget:
                    cons = base + (weaker,)
                    path = planner.plan(agent, cons, node.paths[agent])
                    calls += 1
                    weaker = getattr(weaker, "weaker", None)
                if path is None or path is node.paths[agent]:
                    continue  # no path, or the same path: the child would hold the same conflict
                paths = list(node.paths)
                costs = list(node.costs)
                paths[agent] = path
                costs[agent] = planner.cost(agent, path)
                constraints = dict(node.constraints)
                constraints[agent] = cons
                child = _Node(paths, costs, constraints, node.depth + 1)
                generated += 1
                heapq.heappush(heap, (child.cost, next(counter), child))
            if calls >= call_budget:
                break
        # Unsolved: among the nodes still open and the best one tracked, keep the one with the
        # fewest conflicting pairs (exact counts for a handful of candidates only).
        candidates = [least] + [n for _, _, n in heapq.nsmallest(3, heap)]
        best_node, best_count = least, math.inf
        for cand in candidates:
            cnt = len(model.all_conflicts(cand.paths, fixed))
            if cnt < best_count:
                best_node, best_count = cand, cnt
        return None, (expanded, generated, calls), best_node
