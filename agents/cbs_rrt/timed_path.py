"""Timed paths ``(x, y, theta, t)``: what the planner produces and the tracker follows.

A :class:`TimedPath` is a sequence of samples with strictly increasing times.
Between two samples the robot is taken to move in a straight line at constant
speed (conflict detection interpolates linearly); after the last sample it
stays where it is (it *parks*), before the first it is at the first. The
samples come from three kinds of pieces:

* ``PRIM`` — the samples of a motion primitive (an arc, see
  :mod:`swarm_env_agents.cbs_rrt.primitives`); the path's *nodes* (the RRT tree nodes it
  went through) are the primitive boundaries;
* ``WAIT`` — standing still for a while (a node at the same pose, later);
* ``TAIL`` — following the formation goal (the predicted slot of the robot)
  sample by sample once it has been reached.

Paper 000 stores a path as a list of ``(x, y, theta, t)`` tuples:
:meth:`TimedPath.as_tuples` gives exactly that.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from swarm_env.compiled import compiled_kernels
from swarm_env_agents.cbs_rrt import kernels

__all__ = ["START", "PRIM", "WAIT", "TAIL", "TimedPath", "interp_scalar"]

START, PRIM, WAIT, TAIL = 0, 1, 2, 3
_KIND_NAMES = {START: "start", PRIM: "primitive", WAIT: "wait", TAIL: "tail"}


def interp_scalar(x: float, xp: list[float], fp: list[float]) -> float:
    """``float(np.interp(x, xp, fp))`` for one float and strictly increasing ``xp`` (non-empty, ``fp``
    as long), in plain Python: the same bits. It is numpy's ``arr_interp`` (``compiled_base.c``) step
    by step: ``fp[0]`` left of ``xp[0]``, ``fp[-1]`` from ``xp[-1]`` on, ``fp[j]`` at a breakpoint
    ``xp[j]``, otherwise ``slope * (x - xp[j]) + fp[j]`` with ``slope = (fp[j+1] - fp[j]) / (xp[j+1]
    - xp[j])`` (Python floats are the same IEEE doubles); NaN gives NaN (``fp[0]`` for one sample, as
    numpy), and a NaN result is retried from ``xp[j+1]`` as numpy does. ``tests/test_cbs_kernels.py``
    compares it with ``np.interp`` on over a million points (a numpy built to fuse the multiply-add
    would fail it). The planner asks for single positions tens of thousands of times per episode,
    where numpy's per-call overhead was most of the cost."""
    n = len(xp)
    if n == 1:  # numpy's one-sample branch: fp[0] whatever x is (NaN included)
        return fp[0]
    if x != x:
        return x
    j = bisect_right(xp, x) - 1  # the last j with xp[j] <= x (numpy's binary search, for strictly increasing xp)
    if j < 0:
        return fp[0]
    if j >= n - 1:
        return fp[n - 1]
    if xp[j] == x:
        return fp[j]
    slope = (fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j])
    out = slope * (x - xp[j]) + fp[j]
    if out != out:
        out = slope * (x - xp[j + 1]) + fp[j + 1]
        if out != out and fp[j] == fp[j + 1]:
            out = fp[j]
    return out


@dataclass(frozen=True, eq=False)
class TimedPath:
    """A timed path (see the module docstring). Arrays are read-only.

    Attributes:
        t: ``(K,)`` strictly increasing times (s).
        pose: ``(K, 3)`` ``(x, y, theta)`` (theta continuous along primitives, not wrapped).
        kind: ``(K,)`` how each sample was reached: ``START`` (sample 0), ``PRIM``,
            ``WAIT`` or ``TAIL``.
        nodes: ``(M,)`` sample indices of the path's nodes (``nodes[0] == 0``); the
            samples between two nodes are one primitive or one wait.
        node_prim: ``(M,)`` primitive index reaching each node (``-1`` for the start,
            ``-2`` for a wait).
        goal_time: time the path joins its formation goal (start of the tail), ``nan``
            if it never does.
        reached: ``False`` for a partial path that stops short of the goal.
        vmax: the fastest speed between two samples (m/s; 0 for one sample), computed when
            first asked for (conflict detection's broad phase; most of the planner's
            candidate paths are never screened).
    """

    t: np.ndarray
    pose: np.ndarray
    kind: np.ndarray
    nodes: np.ndarray
    node_prim: np.ndarray
    goal_time: float = math.nan
    reached: bool = True

    def __post_init__(self) -> None:
        t = np.ascontiguousarray(self.t, dtype=np.float64).reshape(-1)
        pose = np.ascontiguousarray(self.pose, dtype=np.float64).reshape(-1, 3)
        if len(t) == 0 or len(t) != len(pose):
            raise ValueError("a timed path needs as many poses as times (at least one)")
        if len(t) > 1 and not np.all(np.diff(t) > 0):
            raise ValueError("timed path times must be strictly increasing")
        put = object.__setattr__
        for name, arr in (
            ("t", t),
            ("pose", pose),
            ("kind", np.asarray(self.kind, dtype=np.int8).reshape(-1)),
            ("nodes", np.asarray(self.nodes, dtype=np.int64).reshape(-1)),
            ("node_prim", np.asarray(self.node_prim, dtype=np.int64).reshape(-1)),
        ):
            arr.flags.writeable = False
            put(self, name, arr)
        if len(self.kind) != len(t) or len(self.nodes) != len(self.node_prim):
            raise ValueError("kind must have one entry per sample and node_prim one per node")

    @classmethod
    def _trusted(
        cls, t: np.ndarray, pose: np.ndarray, kind: np.ndarray, nodes: np.ndarray, node_prim: np.ndarray,
        goal_time: float, reached: bool,
    ) -> TimedPath:
        """A path from arrays that already are what ``__post_init__`` would make of them (contiguous
        float64 ``t (K,)`` strictly increasing, ``pose (K, 3)``, int8 ``kind``, int64 ``nodes`` and
        ``node_prim``, owned by the caller and handed over): the planner's own construction, which
        guarantees all of that, skips the checks and copies."""
        self = object.__new__(cls)
        put = object.__setattr__
        for name, arr in (("t", t), ("pose", pose), ("kind", kind), ("nodes", nodes), ("node_prim", node_prim)):
            arr.flags.writeable = False
            put(self, name, arr)
        put(self, "goal_time", goal_time)
        put(self, "reached", reached)
        return self

    @cached_property
    def vmax(self) -> float:
        """Fastest speed between consecutive samples (m/s), ``0.0`` for a single sample."""
        if len(self.t) < 2:
            return 0.0
        pose = self.pose
        return float((np.hypot(np.diff(pose[:, 0]), np.diff(pose[:, 1])) / np.diff(self.t)).max())

    @cached_property
    def _lists(self) -> tuple[list[float], list[float], list[float]]:
        """``t``, ``x`` and ``y`` as Python lists (single-time lookups, :func:`interp_scalar`)."""
        return self.t.tolist(), self.pose[:, 0].tolist(), self.pose[:, 1].tolist()

    # ------------------------------------------------------------------ construction
    @classmethod
    def stationary(cls, pose: np.ndarray, t0: float) -> TimedPath:
        """A robot that stays at ``pose`` from ``t0`` on."""
        return cls(np.array([t0]), np.asarray(pose, dtype=np.float64).reshape(1, 3), [START], [0], [-1], math.nan, False)

    # ------------------------------------------------------------------ queries
    @property
    def t0(self) -> float:
        return float(self.t[0])

    @property
    def t_end(self) -> float:
        """Time of the last sample (the robot parks afterwards)."""
        return float(self.t[-1])

    @property
    def xy(self) -> np.ndarray:
        return self.pose[:, :2]

    def position_at(self, times: np.ndarray | float) -> np.ndarray:
        """Positions ``(..., 2)`` at ``times`` (linear between samples, clamped outside)."""
        if isinstance(times, (float, int)):  # one time (Python or numpy float): no numpy call per coordinate
            x, y = self.xy_at(float(times))
            return np.array((x, y))
        tt = np.asarray(times, dtype=np.float64)
        if compiled_kernels():  # np.interp's values, see .kernels.interp_xy
            return kernels.interp_xy(np.ascontiguousarray(tt).reshape(-1), self.t, self.pose).reshape(tt.shape + (2,))
        return np.stack([np.interp(tt, self.t, self.pose[:, 0]), np.interp(tt, self.t, self.pose[:, 1])], axis=-1)

    def xy_at(self, time: float) -> tuple[float, float]:
        """The position at one ``time`` as two floats (the same bits as :meth:`position_at`)."""
        t, x, y = self._lists
        return interp_scalar(time, t, x), interp_scalar(time, t, y)

    def heading_at(self, time: float) -> float:
        """Heading (rad, wrapped to ``[-pi, pi)``) at ``time``, linear between samples."""
        th = float(np.interp(time, self.t, self.pose[:, 2]))
        return (th + math.pi) % (2.0 * math.pi) - math.pi

    def primitive_edges(self) -> list[tuple[int, int, int]]:
        """``(from sample, to sample, primitive index)`` of every primitive edge, in order."""
        out = []
        for a, b, k in zip(self.nodes[:-1].tolist(), self.nodes[1:].tolist(), self.node_prim[1:].tolist()):
            if k >= 0:
                out.append((a, b, k))
        return out

    def length(self) -> float:
        """Travelled distance along the samples (m)."""
        if len(self.t) < 2:
            return 0.0
        return float(np.hypot(np.diff(self.pose[:, 0]), np.diff(self.pose[:, 1])).sum())

    def as_tuples(self) -> list[tuple[float, float, float, float]]:
        """Paper 000's path format: ``[(x, y, theta, t), ...]``."""
        return [(float(x), float(y), float(th), float(t)) for (x, y, th), t in zip(self.pose.tolist(), self.t.tolist())]

    def describe(self) -> str:
        counts = {name: int(np.sum(self.kind == k)) for k, name in _KIND_NAMES.items()}
        return (
            f"TimedPath(t=[{self.t0:.2f}, {self.t_end:.2f}], samples={len(self.t)}, {counts}, "
            f"goal_time={self.goal_time:.2f}, reached={self.reached})"
        )
