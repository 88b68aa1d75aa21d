"""Classic grid multi-agent path finding for :class:`swarm_env_agents.cbs_rrt.cbs.CBS` (tests, teaching).

4-connected grid, unit-time moves and waits, sum-of-individual-costs: an agent's
cost is the time at which it reaches its goal for good (it stays there
afterwards). :class:`GridAStar` is an optimal space-time A* that respects
vertex and edge constraints; :class:`GridConflicts` finds vertex conflicts (two
agents in one cell at one time) and edge conflicts (two agents swapping cells)
and splits them the standard way (Sharon et al. 2015). With an optimal
low-level planner CBS returns a minimum sum-of-costs solution, which is what the
tests check on instances with a known optimum.
"""

from __future__ import annotations

import heapq
import itertools
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["VertexConstraint", "EdgeConstraint", "GridConflict", "GridAStar", "GridConflicts", "parse_grid"]

Cell = tuple[int, int]
GridPath = list[Cell]
_MOVES = ((0, 0), (1, 0), (-1, 0), (0, 1), (0, -1))


@dataclass(frozen=True)
class VertexConstraint:
    """The agent may not be in ``cell`` at time ``t``."""

    cell: Cell
    t: int


@dataclass(frozen=True)
class EdgeConstraint:
    """The agent may not move from ``frm`` (at ``t - 1``) to ``to`` (at ``t``)."""

    frm: Cell
    to: Cell
    t: int


@dataclass(frozen=True)
class GridConflict:
    """``kind`` ``"vertex"`` (both in ``cell`` at ``t``) or ``"edge"`` (``a`` moves ``cell -> cell2``
    while ``b`` moves ``cell2 -> cell``, arriving at ``t``)."""

    kind: str
    a: int
    b: int
    t: int
    cell: Cell
    cell2: Cell | None = None

    @property
    def agents(self) -> tuple[int, int]:
        return (self.a, self.b)

    @property
    def time(self) -> float:
        return float(self.t)


def parse_grid(rows: Sequence[str]) -> np.ndarray:
    """``["..#", ...]`` -> ``(H, W)`` boolean array, ``True`` = blocked (``#``). Cells are ``(row, col)``."""
    return np.array([[ch == "#" for ch in row] for row in rows], dtype=bool)


class GridAStar:
    """Optimal space-time A* for one agent on a grid (a CBS :class:`LowLevelPlanner`).

    Args:
        blocked: ``(H, W)`` booleans, ``True`` for walls.
        starts, goals: one cell per agent.
    """

    def __init__(self, blocked: np.ndarray, starts: Sequence[Cell], goals: Sequence[Cell]) -> None:
        self.blocked = np.asarray(blocked, dtype=bool)
        self.starts = [tuple(map(int, s)) for s in starts]
        self.goals = [tuple(map(int, g)) for g in goals]
        self._h = [self._bfs(g) for g in self.goals]
        self.expansions = 0

    def _free(self, c: Cell) -> bool:
        r, k = c
        return 0 <= r < self.blocked.shape[0] and 0 <= k < self.blocked.shape[1] and not self.blocked[r, k]

    def _bfs(self, goal: Cell) -> dict[Cell, int]:
        dist = {goal: 0}
        queue = deque([goal])
        while queue:
            c = queue.popleft()
            for dr, dc in _MOVES[1:]:
                n = (c[0] + dr, c[1] + dc)
                if n not in dist and self._free(n):
                    dist[n] = dist[c] + 1
                    queue.append(n)
        return dist

    def plan(
        self, agent: int, constraints: Sequence[VertexConstraint | EdgeConstraint], previous: GridPath | None = None
    ) -> GridPath | None:
        """An optimal path under ``constraints`` (``previous`` is ignored: A* is exact)."""
        start, goal, h = self.starts[agent], self.goals[agent], self._h[agent]
        if start not in h:
            return None
        vertex = {(c.cell, c.t) for c in constraints if isinstance(c, VertexConstraint)}
        edge = {(c.frm, c.to, c.t) for c in constraints if isinstance(c, EdgeConstraint)}
        # The agent must be able to stay at its goal from its arrival on.
        last_goal_block = max((c.t for c in constraints if isinstance(c, VertexConstraint) and c.cell == goal), default=-1)
        horizon = int(self.blocked.size + max((c.t for c in constraints), default=0) + 2)
        if (start, 0) in vertex:
            return None
        tie = itertools.count()
        heap = [(h[start], next(tie), 0, start)]
        parent: dict[tuple[Cell, int], tuple[Cell, int] | None] = {(start, 0): None}
        while heap:
            _, _, t, c = heapq.heappop(heap)
            self.expansions += 1
            if c == goal and t > last_goal_block:
                path = [c]
                key = (c, t)
                while parent[key] is not None:
                    key = parent[key]
                    path.append(key[0])
                return path[::-1]
            if t >= horizon:
                continue
            for dr, dc in _MOVES:
                n = (c[0] + dr, c[1] + dc)
                if not self._free(n) or n not in h:
                    continue
                nt = t + 1
                if (n, nt) in vertex or (c, n, nt) in edge or (n, nt) in parent:
                    continue
                parent[(n, nt)] = (c, t)
                heapq.heappush(heap, (nt + h[n], next(tie), nt, n))
        return None

    def cost(self, agent: int, path: GridPath) -> float:
        """Arrival time at the goal for good (trailing waits at the goal are free)."""
        goal = self.goals[agent]
        k = len(path) - 1
        while k > 0 and path[k - 1] == goal and path[k] == goal:
            k -= 1
        return float(k) if path[-1] == goal else float("inf")

    def stationary(self, agent: int) -> GridPath:
        return [self.starts[agent]]


def _at(path: GridPath, t: int) -> Cell:
    return path[t] if t < len(path) else path[-1]


class GridConflicts:
    """Vertex and edge conflicts between grid paths (a CBS :class:`ConflictModel`)."""

    def _conflicts(self, paths: Sequence[GridPath], fixed: frozenset[int], first: bool) -> list[GridConflict]:
        n = len(paths)
        horizon = max(len(p) for p in paths)
        out: list[GridConflict] = []
        seen: set[tuple[int, int]] = set()
        for t in range(horizon):
            for a in range(n):
                for b in range(a + 1, n):
                    if (a in fixed and b in fixed) or (a, b) in seen:
                        continue
                    ca, cb = _at(paths[a], t), _at(paths[b], t)
                    c = None
                    if ca == cb:
                        c = GridConflict("vertex", a, b, t, ca)
                    elif t > 0 and _at(paths[a], t - 1) == cb and _at(paths[b], t - 1) == ca:
                        c = GridConflict("edge", a, b, t, cb, ca)
                    if c is not None:
                        if first:
                            return [c]
                        out.append(c)
                        seen.add((a, b))
        return out

    def first_conflict(self, paths: Sequence[GridPath], fixed: frozenset[int] = frozenset()) -> GridConflict | None:
        found = self._conflicts(paths, fixed, True)
        return found[0] if found else None

    def all_conflicts(self, paths: Sequence[GridPath], fixed: frozenset[int] = frozenset()) -> list[GridConflict]:
        return self._conflicts(paths, fixed, False)

    def split(self, c: GridConflict) -> list[tuple[int, VertexConstraint | EdgeConstraint]]:
        if c.kind == "vertex":
            return [(c.a, VertexConstraint(c.cell, c.t)), (c.b, VertexConstraint(c.cell, c.t))]
        assert c.cell2 is not None
        a_from, a_to = c.cell, c.cell2
        return [(c.a, EdgeConstraint(a_from, a_to, c.t)), (c.b, EdgeConstraint(a_to, a_from, c.t))]
