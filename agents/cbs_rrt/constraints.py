"""Space-time constraints from CBS, and their vectorised table for the low-level planner.

Paper 000 stores a constraint as ``[x, y, t]``: a position the robot must avoid
at a time. In continuous time a single instant is too weak (the replanned robot
would slip through a moment later), so a :class:`Constraint` here is a *moving
forbidden disc*: robot ``agent`` must keep at least ``radius`` between its
centre and the point ``c(t)`` for every ``t`` in ``[t[0], t[-1]]``, where ``c``
interpolates the samples ``(t, xy)`` linearly. The disc follows the other robot
of the conflict along its planned path over a time window (a standing robot
gives a disc that does not move), so a sequence of ``[x, y, t]`` samples, as in
the paper, with a radius.

:class:`ConstraintTable` packs all constraints of one robot on a regular time
grid so that a batch of ``(x, y, t)`` points is tested against all of them in a
few numpy operations (the RRT tests every candidate primitive this way).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from swarm_env.compiled import compiled_kernels
from swarm_env_agents.cbs_rrt import kernels
from swarm_env_agents.cbs_rrt.conflicts import pair_first_conflict
from swarm_env_agents.cbs_rrt.timed_path import START, TimedPath

__all__ = ["Constraint", "ConstraintTable"]

# Placeholders of a table without constraints, for the kernels' fixed argument types.
_NO_XY = np.zeros((1, 1))
_NO_R2 = np.zeros(1)
_NO_ACTIVE = np.zeros((1, 1), dtype=bool)
_NO_ANY = np.zeros(1, dtype=bool)


@dataclass(frozen=True, eq=False)
class Constraint:
    """Robot ``agent`` must stay ``>= radius`` from the moving point ``(t, xy)`` during
    ``[t[0], t[-1]]`` (linear between samples). ``other`` is the robot whose path the disc
    follows (``-1`` if none), for reports. ``weaker``: an alternative that also excludes the
    conflict this constraint came from, for CBS to use when the robot cannot satisfy this one
    (see :class:`swarm_env_agents.cbs_rrt.cbs.CBS`)."""

    agent: int
    t: np.ndarray
    xy: np.ndarray
    radius: float
    other: int = -1
    weaker: Constraint | None = None

    def __post_init__(self) -> None:
        t = np.ascontiguousarray(self.t, dtype=np.float64).reshape(-1)
        xy = np.ascontiguousarray(self.xy, dtype=np.float64).reshape(-1, 2)
        if len(t) == 0 or len(t) != len(xy):
            raise ValueError("a constraint needs as many positions as times (at least one)")
        if len(t) > 1 and not np.all(np.diff(t) > 0):
            raise ValueError("constraint times must be strictly increasing")
        t.flags.writeable = False
        xy.flags.writeable = False
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "xy", xy)

    @classmethod
    def avoid_path(
        cls, agent: int, path: TimedPath, t_start: float, t_end: float, radius: float, other: int = -1
    ) -> Constraint:
        """The disc of ``radius`` that follows ``path`` over ``[t_start, t_end]`` (exactly: all of
        the path's breakpoints inside the window are kept)."""
        if not t_end > t_start:
            t_end = t_start + 1e-6
        inner = path.t[(path.t > t_start) & (path.t < t_end)]
        ts = np.concatenate([[t_start], inner, [t_end]])
        return cls(agent, ts, path.position_at(ts), float(radius), other)

    @classmethod
    def at_point(
        cls, agent: int, xy: np.ndarray, t_start: float, t_end: float, radius: float, other: int = -1
    ) -> Constraint:
        """A disc that does not move: ``agent`` must keep ``radius`` from ``xy`` during
        ``[t_start, t_end]`` (paper 000's ``[x, y, t]`` constraint, held over an interval)."""
        if not t_end > t_start:
            t_end = t_start + 1e-6
        p = np.asarray(xy, dtype=np.float64).reshape(1, 2)
        return cls(agent, np.array([t_start, t_end]), np.vstack([p, p]), float(radius), other)

    @property
    def t_start(self) -> float:
        return float(self.t[0])

    @property
    def t_end(self) -> float:
        return float(self.t[-1])

    def as_path(self) -> TimedPath:
        """The disc's centre as a timed path (for exact checks)."""
        n = len(self.t)
        pose = np.column_stack([self.xy, np.zeros(n)])
        return TimedPath(self.t, pose, [START] + [1] * (n - 1), [0], [-1])

    def violated_by(self, path: TimedPath) -> bool:
        """Exact continuous test: does ``path`` come closer than ``radius`` to the disc's centre
        during the constraint's window?"""
        return pair_first_conflict(path, self.as_path(), self.radius, self.t_start, self.t_end) is not None


class ConstraintTable:
    """All constraints of one robot, sampled every ``dt`` seconds over ``[t0, t1]``.

    :meth:`free` tests points ``(x, y, t)`` against every constraint at once. A point is
    compared with the disc centre at the nearest grid time, so the disc is inflated by
    ``slack`` (m) to cover the centre's motion within ``dt / 2`` (0.05 m covers 1 m/s
    at the default ``dt = 0.1``) and the spacing of the planner's samples; a constraint
    counts as active from ``dt`` before its window to ``dt`` after it. :attr:`kernel` is the
    table as the compiled kernels take it (a :class:`.kernels.Cons`, as the plain tuple of
    :func:`.kernels.plain`).
    """

    def __init__(
        self, constraints: Sequence[Constraint], t0: float, t1: float, dt: float = 0.1, slack: float = 0.05
    ) -> None:
        self.t0 = float(t0)
        self.dt = float(dt)
        self._inv_dt = 1.0 / self.dt
        self.constraints = tuple(constraints)
        k = max(2, int(math.ceil((float(t1) - self.t0) / dt - 1e-9)) + 1)
        self.k = k
        grid = self.t0 + np.arange(k) * dt
        c = len(self.constraints)
        self.count = c
        if c == 0:
            # The kernels' argument types are fixed: placeholders of the real arrays' types, never read.
            self.kernel = kernels.plain(kernels.Cons(False, self.t0, self._inv_dt, float(k - 1), _NO_XY, _NO_XY, _NO_R2,
                                                     _NO_ACTIVE, _NO_ANY))
            return
        self.px = np.empty((c, k))
        self.py = np.empty((c, k))
        self.active = np.empty((c, k), dtype=bool)
        r = np.empty(c)
        for i, con in enumerate(self.constraints):  # construction: once per low-level call
            self.px[i] = np.interp(grid, con.t, con.xy[:, 0])
            self.py[i] = np.interp(grid, con.t, con.xy[:, 1])
            self.active[i] = (grid >= con.t_start - dt) & (grid <= con.t_end + dt)
            r[i] = con.radius + slack
        self.r2 = (r * r)[:, None]
        self._r2_flat = np.ascontiguousarray(self.r2[:, 0])
        # Grid columns where some constraint is active: points at other times skip the test.
        self.any_active = self.active.any(axis=0)
        self.kernel = kernels.plain(kernels.Cons(True, self.t0, self._inv_dt, float(k - 1), self.px, self.py,
                                                 self._r2_flat, self.active, self.any_active))

    def free(self, x: np.ndarray, y: np.ndarray, t: np.ndarray) -> np.ndarray:
        """``(M,)`` booleans: point ``m`` at ``(x[m], y[m])`` and time ``t[m]`` is outside every
        (inflated) active disc."""
        x = np.asarray(x, dtype=np.float64)
        if self.count == 0:
            return np.ones(x.shape, dtype=bool)
        if compiled_kernels():  # the same answers, see .kernels
            ya = np.asarray(y, dtype=np.float64)
            ta = np.asarray(t, dtype=np.float64)
            if ya.shape != x.shape or ta.shape != x.shape:  # scalars or broadcasting: the rare case
                ya, ta = np.broadcast_to(ya, x.shape), np.broadcast_to(ta, x.shape)
            out = kernels.constraint_free(x.ravel(), ya.ravel(), ta.ravel(), self.kernel)
            if out is not None:
                return out.reshape(x.shape)
        g = (np.asarray(t, dtype=np.float64) - self.t0) * self._inv_dt + 0.5
        k = np.minimum(np.maximum(g, 0.0), self.k - 1).astype(np.int64)  # nearest grid time
        if not self.any_active[k].any():
            return np.ones(x.shape, dtype=bool)
        dx = self.px[:, k] - x
        dy = self.py[:, k] - np.asarray(y, dtype=np.float64)
        hit = (dx * dx + dy * dy < self.r2) & self.active[:, k]
        return ~hit.any(axis=0)

    def all_free(self, x: np.ndarray, y: np.ndarray, t: np.ndarray) -> bool:
        return bool(self.free(x, y, t).all())

    def still_free(self, x: float, y: float, t_from: float, t_to: float) -> bool:
        """Can a robot stand at ``(x, y)`` from ``t_from`` to ``t_to`` (every grid time in
        between, and the nearest grid times of both ends)?"""
        if self.count == 0 or t_to < t_from:
            return True
        k0 = min(max(int((t_from - self.t0) * self._inv_dt + 0.5), 0), self.k - 1)
        k1 = min(max(int((t_to - self.t0) * self._inv_dt + 0.5), 0), self.k - 1) + 1
        if compiled_kernels():  # the same answer, see .kernels
            return bool(kernels.constraint_still_free(float(x), float(y), k0, k1, self.kernel))
        act = self.active[:, k0:k1]
        if not act.any():
            return True
        dx = self.px[:, k0:k1] - x
        dy = self.py[:, k0:k1] - y
        return not bool(((dx * dx + dy * dy < self.r2) & act).any())
