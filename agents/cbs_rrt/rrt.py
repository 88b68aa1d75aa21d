"""Goal-biased RRT over motion primitives, in space-time, towards a moving goal (paper 000 Sec. III-B).

One robot, one call of :meth:`PrimitiveRRT.plan`:

* **Tree.** Nodes are poses ``(x, y, theta)`` with a time ``t``; the root is the
  robot's pose at the replanning time. An expansion picks a sample ``q`` (the
  goal with probability ``goal_bias``, otherwise uniformly in a box around the
  start and the goal's course), finds the nearest node, applies *every*
  primitive to it and keeps the valid one whose end is nearest to ``q``
  (paper: "expanding the tree using the motion primitives to generate a set of
  candidate nodes"). A goal-biased expansion keeps extending towards the goal
  for up to ``connect_steps`` primitives while it gets closer. Random
  expansions are done ``batch`` at a time in one vectorised pass (nearest
  nodes, every primitive of every parent, validity), which is what makes the
  tree cheap to grow in Python.
* **Validity.** Every sample point of a primitive must keep the robot's
  ``buffer`` (radius + margin, the paper's buffer zone) from obstacles and walls,
  read from a :class:`~swarm_env_agents.cbs_rrt.distance_field.DistanceField` in one
  vectorised lookup per expansion, and lie outside every CBS constraint at its
  time (:class:`~swarm_env_agents.cbs_rrt.constraints.ConstraintTable`). A robot that
  starts inside the buffer may leave it (the required clearance grows with the
  distance from the start, see ``RRTConfig``). When constraints block every primitive but the
  robot could stand still, a *wait* node (same pose, ``wait_step`` later) is
  added: waiting is how robots give way in space-time.
* **Moving goal.** The goal is a timed course (:class:`GoalSpec`, the robot's
  predicted formation slot). A node *joins* the goal when some course point
  ``G(t_k)`` with ``t_k`` at most ``max_wait`` later is within
  ``goal_tolerance`` and reachable in time (the robot may wait for its slot to
  arrive); the path then follows the course (the *tail*) to the horizon. The
  wait, the junction and the tail must respect the constraints too.
* **Smoothing.** The raw branch is re-driven from the start with primitives
  that head for the furthest waypoint of the branch in line of sight; the
  result replaces the branch if it joins the goal no later. Every edge stays a
  legal primitive (kinematically feasible by construction).
* **Repair.** :meth:`PrimitiveRRT.repair` makes an existing path respect new
  constraints by inserting a wait before the first violation (CBS tries that
  before a new search: two robots crossing is usually resolved by one waiting).
* **Budget.** ``max_iterations`` expansions (an iteration count, never time).
  Without a join the best *partial* path is returned (to the node nearest its
  goal where the robot can safely stay until ``park_until``), or ``None`` when
  the robot cannot even stay where it is (or partial paths are not wanted).

All randomness comes from the ``numpy.random.Generator`` passed to ``plan``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from swarm_env.compiled import compiled_kernels
from swarm_env_agents.cbs_rrt import kernels
from swarm_env_agents.cbs_rrt.constraints import ConstraintTable
from swarm_env_agents.cbs_rrt.distance_field import DistanceField
from swarm_env_agents.cbs_rrt.primitives import MotionPrimitives
from swarm_env_agents.cbs_rrt.timed_path import PRIM, START, TAIL, WAIT, TimedPath

__all__ = ["GoalSpec", "RRTConfig", "RRTResult", "PrimitiveRRT"]

_WAIT_PRIM = -2
_JUNCTION_S = np.linspace(0.0, 1.0, 5)  # points checked along the junction move onto the goal
_VISIBLE_S = np.linspace(0.0, 1.0, 12)[None, :]  # points checked along a line of sight
_EMPTY = np.empty(0)  # no tail (the compiled _build)
_EMPTY2 = np.empty((0, 2))


@dataclass(frozen=True, eq=False)
class GoalSpec:
    """The moving goal of one robot over one planning window.

    Attributes:
        t: ``(K,)`` evenly spaced times covering the window (s).
        xy: ``(K, 2)`` goal positions.
        heading: ``(K,)`` goal headings (the leader's heading; for the tail's poses).
        piece_end: index of the last sample the robot can follow continuously; from
            there on the goal stays at ``xy[piece_end]`` (the *effective* goal ``xy_eff``).
        slow: goal speed (m/s) up to which a robot may join it whatever its heading
            (``dir``: unit direction of the goal's motion at each sample, ``fast``: faster
            than ``slow``).
    """

    t: np.ndarray
    xy: np.ndarray
    heading: np.ndarray
    piece_end: int
    slow: float = 0.15
    xy_eff: np.ndarray = field(init=False, repr=False)
    dir: np.ndarray = field(init=False, repr=False)
    fast: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        t = np.ascontiguousarray(self.t, dtype=np.float64)
        xy = np.ascontiguousarray(self.xy, dtype=np.float64).reshape(-1, 2)
        if len(t) < 2 or len(t) != len(xy):
            raise ValueError("a goal spec needs >= 2 samples and one position per time")
        end = int(min(max(self.piece_end, 0), len(t) - 1))
        eff = xy.copy()
        eff[end + 1:] = xy[end]
        step = np.diff(eff, axis=0, append=eff[-1:])  # motion from each sample to the next
        speed = np.hypot(step[:, 0], step[:, 1]) / max(float(t[1] - t[0]), 1e-12)
        unit = step / np.maximum(np.hypot(step[:, 0], step[:, 1]), 1e-12)[:, None]
        object.__setattr__(self, "dir", unit)
        object.__setattr__(self, "fast", speed > self.slow)
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "xy", xy)
        object.__setattr__(self, "heading", np.ascontiguousarray(self.heading, dtype=np.float64))
        object.__setattr__(self, "piece_end", end)
        object.__setattr__(self, "xy_eff", eff)

    @property
    def dt(self) -> float:
        return float(self.t[1] - self.t[0])

    def at(self, times: np.ndarray | float) -> np.ndarray:
        """Effective goal positions at ``times`` (linear between samples, clamped)."""
        tt = np.asarray(times, dtype=np.float64)
        if compiled_kernels():  # np.interp's values, see .kernels.interp_xy
            return kernels.interp_xy(np.ascontiguousarray(tt).reshape(-1), self.t, self.xy_eff).reshape(tt.shape + (2,))
        return np.stack([np.interp(tt, self.t, self.xy_eff[:, 0]), np.interp(tt, self.t, self.xy_eff[:, 1])], axis=-1)

    def index_after(self, time: float) -> int:
        """Index of the first sample strictly after ``time`` (``K`` if none)."""
        return int(np.searchsorted(self.t, time + 1e-9, side="left"))


@dataclass(frozen=True)
class RRTConfig:
    """Tuning of :class:`PrimitiveRRT` (see the module docstring).

    Attributes:
        max_iterations: expansions per call (the budget).
        goal_bias: probability of sampling the goal.
        goal_tolerance: a node joins the goal within this distance (m).
        connect_steps: extra primitives towards the goal after a goal-biased expansion.
        sample_margin: the sampling box extends this far around the start and goal course (m).
        max_wait: the longest a node may wait for its goal to come within tolerance (s).
        wait_step: duration of a wait node (s).
        smoothing: run the smoothing pass.
        follow_speed: speed of the junction move onto the goal (m/s); ``None``: the primitives' speed.
        heading_weight: metres per radian of heading error in the nearest-node metric.
        batch: random expansions done together in one vectorised pass (each counts as one
            iteration of the budget).
        join_angle: largest heading error (degrees) to join a fast-moving goal.
        stall_limit: give up after this many consecutive expansions that added no node.
        relax_drop, relax_distance, relax_slope: a robot starting inside the buffer zone
            (clearance ``c`` below ``buffer``) needs only ``c - relax_drop`` within
            ``relax_distance`` of its start, then ``relax_slope`` more per metre, up to ``buffer``.
    """

    max_iterations: int = 300
    goal_bias: float = 0.3
    goal_tolerance: float = 0.3
    connect_steps: int = 10
    sample_margin: float = 2.0
    max_wait: float = 8.0
    wait_step: float = 1.0
    smoothing: bool = True
    follow_speed: float | None = None
    heading_weight: float = 0.3
    batch: int = 8
    join_angle: float = 60.0
    stall_limit: int = 25
    relax_drop: float = 0.05
    relax_distance: float = 0.5
    relax_slope: float = 0.5


@dataclass
class RRTResult:
    """``path`` (``None`` if the robot cannot even stay put), ``reached`` (joined the goal),
    ``iterations`` (expansions used), ``nodes`` (tree size), ``smoothed`` (smoothing kept)."""

    path: TimedPath | None
    reached: bool
    iterations: int
    nodes: int
    smoothed: bool = False
    tree_xy: np.ndarray | None = None
    tree_parent: np.ndarray | None = None


class _Tree:
    """The RRT's nodes, grown by :meth:`add`: poses ``X`` ``(cap, 3)``, times ``T``, each node's ``parent`` and the
    primitive that reached it (``prim``; ``-1`` at the root, ``_WAIT_PRIM`` for a wait), and the goal-directed
    extensions that failed from it (``fails``). ``n`` nodes are in use. ``arrays``: the first four as the compiled
    kernels take them (a :class:`.kernels.Tree` of the same arrays, as a :func:`.kernels.plain` tuple)."""

    def __init__(self, cap: int, root: tuple[float, float, float], t0: float) -> None:
        self.cap = cap
        self.X = np.empty((cap, 3))
        self.T = np.empty(cap)
        self.parent = np.empty(cap, dtype=np.int64)
        self.prim = np.empty(cap, dtype=np.int64)
        self.fails = np.zeros(cap, dtype=np.int64)
        self.X[0] = root
        self.T[0] = t0
        self.parent[0] = -1
        self.prim[0] = -1
        self.n = 1
        self.arrays = kernels.plain(kernels.Tree(self.X, self.T, self.parent, self.prim))

    def add(self, i: int, pose: np.ndarray, t: float, k: int) -> int:
        """A node at ``pose`` and time ``t``, reached from node ``i`` by primitive ``k``; returns its index."""
        n = self.n
        self.X[n] = pose
        self.T[n] = t
        self.parent[n] = i
        self.prim[n] = k
        self.n = n + 1
        return n

    def chain(self, node: int) -> list[int]:
        """The nodes from the root to ``node``."""
        out = []
        k = node
        while k >= 0:
            out.append(k)
            k = int(self.parent[k])
        out.reverse()
        return out


class PrimitiveRRT:
    """The low-level planner of one robot (see the module docstring).

    Args:
        primitives: the motion primitives.
        field: distance field of the static map.
        buffer: required clearance of the robot's centre from obstacles and walls
            (radius + margin, m).
        config: :class:`RRTConfig`.
        floor: the clearance below which nothing is ever allowed, even for a robot that
            starts inside the buffer zone (m; default: ``buffer``, no relaxation).
    """

    def __init__(
        self,
        primitives: MotionPrimitives,
        field: DistanceField,
        buffer: float,
        config: RRTConfig = RRTConfig(),
        floor: float | None = None,
    ):
        self.prims = primitives
        self.field = field
        self.buffer = float(buffer)
        self.floor = float(buffer if floor is None else min(floor, buffer))
        self.config = config
        S, P = primitives.samples, primitives.count
        self._S, self._P = S, P
        self._lt = primitives.sample_t.ravel()  # (P*S,) sample time offsets
        self._follow = float(config.follow_speed or primitives.speed)
        self._cos_join = math.cos(math.radians(config.join_angle))

    # ------------------------------------------------------------------ validity
    def _static_ok(self, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
        clear = self.field.clearance_xy(xs, ys)
        if self._relax:
            # Started inside the buffer zone: near the start the clearance may drop a little
            # below the start's (tracking leaves robots a few mm inside it all the time), then
            # the full buffer comes back with the distance travelled.
            cfg = self.config
            d = np.hypot(xs - self._sx, ys - self._sy)
            need = self._c0 + cfg.relax_slope * np.maximum(d - cfg.relax_distance, 0.0)
            return clear >= np.maximum(np.minimum(self.buffer, need), self._floor)
        return clear >= self.buffer

    def _candidates(
        self, x: float, y: float, th: float, t: float
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
        """All primitives from a pose: ``ends (P, 3)``, ``static_ok (P,)``, ``cons_ok (P,)``, samples
        (``None, None`` from the compiled version, :func:`.kernels.candidates`: the same answers)."""
        if compiled_kernels():
            x, y, th = float(x), float(y), float(th)
            ok, sok, cok, ex, ey = kernels.candidates(x, y, math.cos(th), math.sin(th), float(t), self._search)
            if ok:
                ends = np.empty((self._P, 3))
                ends[:, 0] = ex
                ends[:, 1] = ey
                ends[:, 2] = th + self.prims.angles
                return ends, sok, cok, None, None
        xs, ys, ends = self.prims.expand((x, y, th))
        P, S = self._P, self._S
        sok = self._static_ok(xs, ys).reshape(P, S).all(axis=1)
        if self._cons.count:
            cok = self._cons.free(xs, ys, t + self._lt).reshape(P, S).all(axis=1)
        else:
            cok = np.ones(P, dtype=bool)
        return ends, sok, cok, xs, ys

    def _still_free(self, x: float, y: float, t_from: float, t_to: float) -> bool:
        """Can the robot stand at ``(x, y)`` from ``t_from`` to ``t_to`` without violating a constraint?"""
        if self._cons.count == 0 or t_to <= t_from:
            return True
        return self._cons.still_free(float(x), float(y), t_from, t_to)

    # ------------------------------------------------------------------ goal
    def _join(self, x: float, y: float, t: float, th: float) -> tuple[int, float] | None:
        """The earliest goal sample ``k`` a robot standing at ``(x, y)`` with heading ``th`` at
        ``t`` can join: ``(k, depart)`` — wait until ``depart``, move straight to ``G(t_k)``,
        then follow. Where the goal moves faster than ``GoalSpec.slow`` the robot must face
        within ``join_angle`` of its motion (a unicycle cannot follow a course sideways; it
        turns in place first, with a spin primitive)."""
        g = self._goal
        if compiled_kernels():  # the same join, see .kernels.join
            k, dep = kernels.join(float(x), float(y), float(t), float(th), self._goal_kernel, self._cons.kernel)
            if k >= 0:
                return int(k), float(dep)
            if k == -1:
                return None
        k_lo = g.index_after(t)
        K = len(g.t)
        if k_lo >= K:
            return None
        k_hi = min(K, g.index_after(t + self.config.max_wait) + 1)
        G = g.xy_eff[k_lo:k_hi]
        d = np.hypot(G[:, 0] - x, G[:, 1] - y)
        depart = g.t[k_lo:k_hi] - d / self._follow
        ok = (d <= self.config.goal_tolerance) & (depart >= t)
        fast = g.fast[k_lo:k_hi]
        if fast.any():
            facing = np.cos(th) * g.dir[k_lo:k_hi, 0] + np.sin(th) * g.dir[k_lo:k_hi, 1] >= self._cos_join
            ok &= ~fast | facing
        if self._cons.count:
            ok &= self._tail_ok[k_lo:k_hi]
        for j in np.flatnonzero(ok)[:4].tolist():  # the first few joinable samples
            k = k_lo + j
            if self._cons.count == 0 or self._join_free(x, y, t, float(depart[j]), k):
                return k, float(depart[j])
        return None

    def _join_free(self, x: float, y: float, t: float, depart: float, k: int) -> bool:
        """Waiting at ``(x, y)`` until ``depart`` and the junction to ``G(t_k)`` respect the
        constraints (the tail from ``k`` is known to: ``_tail_ok``)."""
        if not self._still_free(x, y, t, depart):
            return False
        g = self._goal
        s = _JUNCTION_S
        jx = x + s * (g.xy_eff[k, 0] - x)
        jy = y + s * (g.xy_eff[k, 1] - y)
        jt = depart + s * (g.t[k] - depart)
        return self._cons.all_free(jx, jy, jt)

    def _intercept(self, x: float, y: float, t: float) -> np.ndarray:
        """Where to head from ``(x, y)`` at ``t`` to meet the goal: the course point whose
        time allows reaching it at the primitives' speed (first such sample)."""
        g = self._goal
        if compiled_kernels():  # the same sample, see .kernels.intercept
            return g.xy_eff[kernels.intercept(float(x), float(y), float(t), self._goal_kernel)]
        k_lo = min(g.index_after(t), len(g.t) - 1)
        G = g.xy_eff[k_lo:]
        reach = (g.t[k_lo:] - t) * self.prims.speed * 0.8
        d = np.hypot(G[:, 0] - x, G[:, 1] - y)
        admissible = d <= reach
        if self._cons.count:
            admissible &= self._tail_ok[k_lo:]  # only where the goal may be joined for good
        ok = np.flatnonzero(admissible)
        return G[int(ok[0])] if len(ok) else G[-1]

    def _bind(self, goal: GoalSpec, constraints: ConstraintTable) -> None:
        self._goal = goal
        self._cons = constraints
        if constraints.count:
            # _tail_ok[k]: following the goal course from sample k on respects every constraint.
            free = constraints.free(goal.xy_eff[:, 0], goal.xy_eff[:, 1], goal.t)
            self._tail_ok = np.ascontiguousarray(np.flip(np.logical_and.accumulate(np.flip(free))))
        # The goal as the compiled _join, _intercept and _joins take it (bound once per call; a plain tuple,
        # which numba types faster on these frequent calls: see .kernels.plain).
        tail = self._tail_ok if constraints.count else goal.fast  # (a placeholder of the same type)
        cfg = self.config
        self._goal_kernel = kernels.plain(kernels.Goal(
            goal.t, goal.xy_eff, goal.fast, goal.dir, tail, constraints.count > 0, cfg.max_wait, cfg.goal_tolerance,
            cfg.goal_tolerance ** 2, self._follow, self._cos_join, self.prims.speed, _JUNCTION_S, 4,
        ))

    # ------------------------------------------------------------------ plan
    def plan(
        self,
        start: np.ndarray,
        t0: float,
        goal: GoalSpec,
        constraints: ConstraintTable,
        rng: np.random.Generator,
        *,
        keep_tree: bool = False,
        max_iterations: int | None = None,
        allow_partial: bool = True,
        park_until: float | None = None,
    ) -> RRTResult:
        """Plan from ``start`` ``(x, y, theta)`` at time ``t0`` to join ``goal`` (see the module
        docstring). ``constraints`` must cover the goal's time span. ``max_iterations``
        overrides the configured budget; ``allow_partial=False`` returns no path rather than
        a partial one when the goal is not joined; a partial path must let the robot stay at
        its end until ``park_until`` (default: the goal's horizon)."""
        cfg = self.config
        budget = cfg.max_iterations if max_iterations is None else int(max_iterations)
        self._bind(goal, constraints)
        sx, sy, sth = (float(v) for v in start)
        self._prepare(sx, sy, goal)
        tree = _Tree(64 + budget * (cfg.connect_steps + 2), (sx, sy, sth), t0)
        join = self._join(sx, sy, t0, sth)
        if join is not None:
            return self._result(tree, 0, join, 0, keep_tree)
        if constraints.count and not self._tail_ok.any() and not allow_partial:
            # The constraints cover the goal course until the horizon: no node can ever join it,
            # and a tree that cannot join only yields a partial path. Let the caller relax them.
            return RRTResult(None, False, 0, 1)
        # Sampling box: start and goal course, with a margin, inside the world.
        course = goal.xy_eff
        W, H = self.field.size
        lo = np.maximum(np.minimum(course.min(axis=0), (sx, sy)) - cfg.sample_margin, (0.0, 0.0))
        hi = np.minimum(np.maximum(course.max(axis=0), (sx, sy)) + cfg.sample_margin, (W, H))
        span = hi - lo

        it = 0
        stalled = 0  # consecutive iterations that added nothing
        while it < budget:
            if tree.n + cfg.connect_steps + cfg.batch + 2 >= tree.cap or stalled >= cfg.stall_limit:
                break  # a tree that stopped growing will not reach the goal: give up early
            if not rng.random() < cfg.goal_bias:
                b = min(cfg.batch, budget - it)
                it += b
                count, found = self._explore(tree, lo + rng.random((b, 2)) * span)
                stalled = stalled + b if count == 0 else 0
                if found is not None:
                    return self._result(tree, found[0], found[1], it, keep_tree)
                continue
            it += 1
            n_before = tree.n
            found = self._grow_to_goal(tree)
            stalled = stalled + 1 if tree.n == n_before else 0
            if found is not None:
                return self._result(tree, found[0], found[1], it, keep_tree)

        # Budget spent: the best node where the robot may stay until the horizon.
        if not allow_partial:
            return RRTResult(None, False, it, tree.n)
        n, X, T = tree.n, tree.X, tree.T
        g_at = goal.at(T[:n])
        err = np.hypot(X[:n, 0] - g_at[:, 0], X[:n, 1] - g_at[:, 1])
        park = self._t_end if park_until is None else min(self._t_end, float(park_until))
        for k in np.argsort(err, kind="stable").tolist():
            if self._still_free(X[k, 0], X[k, 1], T[k], max(park, T[k])):
                return self._result(tree, int(k), None, it, keep_tree)
        return RRTResult(None, False, it, n)

    def _prepare(self, sx: float, sy: float, goal: GoalSpec) -> None:
        """What one :meth:`plan` from ``(sx, sy)`` to ``goal`` reads on every expansion: the start's clearance rule
        (a start below the buffer may not get worse), the goal course, and the compiled kernels' arguments."""
        cfg = self.config
        self._sx, self._sy = sx, sy
        c0 = float(self.field.clearance_xy(np.array([sx]), np.array([sy]))[0])
        self._relax = c0 < self.buffer
        self._c0 = c0 - cfg.relax_drop
        # Below the floor already (pushed there): it may not get any worse.
        self._floor = min(self.floor, c0 - 0.005)
        self._t_end = float(goal.t[-1])
        # What the compiled _candidates and _explore read on every expansion (bound once per call; a plain tuple,
        # which numba types faster: see .kernels.plain).
        rule = kernels.Buffer(self.buffer, self._relax, sx, sy, self._c0, cfg.relax_slope, cfg.relax_distance,
                              self._floor)
        self._search = kernels.plain(kernels.Search(self.prims.kernel, self.field.kernel, rule, self._cons.kernel,
                                                    cfg.heading_weight, _WAIT_PRIM, cfg.wait_step, self._t_end))
        self._compiled = compiled_kernels()

    def _result(self, tree: _Tree, node: int, join: tuple[int, float] | None, it: int, keep_tree: bool) -> RRTResult:
        """The path from the root to ``node`` (then along the goal course from ``join``), smoothed when it joins."""
        nodes = [(tree.X[k].copy(), float(tree.T[k]), int(tree.prim[k])) for k in tree.chain(node)]
        smoothed = False
        if join is not None and self.config.smoothing and len(nodes) > 2:
            better = self._smooth(nodes, join)
            if better is not None:
                nodes, join = better
                smoothed = True
        path = self._build(nodes, join)
        n = tree.n
        kept = (tree.X[:n].copy(), tree.parent[:n].copy()) if keep_tree else (None, None)
        return RRTResult(path, join is not None, it, n, smoothed, kept[0], kept[1])

    def _extend(self, tree: _Tree, i: int, qx: float, qy: float) -> int:
        """Add the valid primitive from node ``i`` that ends nearest ``q``; when constraints
        block every primitive that the obstacles allow, wait ``wait_step`` in place instead."""
        cfg = self.config
        X, T = tree.X, tree.T
        x, y, th = X[i]
        ends, sok, cok, _, _ = self._candidates(x, y, th, T[i])
        valid = sok & cok
        if not valid.any():
            if (sok & ~cok).any() and T[i] + cfg.wait_step <= self._t_end and self._still_free(
                x, y, T[i], T[i] + cfg.wait_step
            ):
                return tree.add(i, X[i].copy(), T[i] + cfg.wait_step, _WAIT_PRIM)
            return -1
        d = (ends[:, 0] - qx) ** 2 + (ends[:, 1] - qy) ** 2
        d[~valid] = np.inf
        k = int(np.argmin(d))
        return tree.add(i, ends[k], T[i] + self.prims.durations[k], k)

    def _grow_to_goal(self, tree: _Tree) -> tuple[int, tuple[int, float]] | None:
        """One goal-biased iteration: from the node nearest its goal (skipping nodes that keep failing to get
        closer), extend towards its intercept point, then keep connecting while the tree gets closer. Returns
        ``(node, join)`` when a node joins the goal course."""
        X, T, fails = tree.X, tree.T, tree.fails
        t_end = self._t_end
        i = self._nearest_to_goal(X, T, tree.n, fails)
        q = self._intercept(X[i, 0], X[i, 1], T[i])
        new = self._extend(tree, i, float(q[0]), float(q[1]))
        if new < 0 or T[new] > t_end:
            fails[i] += 1
            return None
        join = self._join(X[new, 0], X[new, 1], T[new], X[new, 2])
        if join is not None:
            return new, join
        prev = math.hypot(X[new, 0] - q[0], X[new, 1] - q[1])
        for _ in range(self.config.connect_steps):
            q = self._intercept(X[new, 0], X[new, 1], T[new])
            nxt = self._extend(tree, new, float(q[0]), float(q[1]))
            if nxt < 0 or T[nxt] > t_end:
                break
            dist = math.hypot(X[nxt, 0] - q[0], X[nxt, 1] - q[1])
            new = nxt
            join = self._join(X[new, 0], X[new, 1], T[new], X[new, 2])
            if join is not None:
                return new, join
            if dist >= prev and tree.prim[nxt] != _WAIT_PRIM:
                fails[i] += 1
                break
            prev = dist
        return None

    def _expand_batch(self, tree: _Tree, qx: np.ndarray, qy: np.ndarray) -> tuple[np.ndarray, ...]:
        """Nearest nodes of the samples and all primitives from them (the items of a :class:`.kernels.Batch`,
        a plain tuple from the compiled version): ``uniq`` (distinct nodes), ``inv`` (each sample's index into
        ``uniq``), ``sok``/``cok`` ``(U, P)`` (static / constraint validity), ``ex``/``ey`` ``(U, P)`` end points,
        ``best`` (each sample's nearest valid primitive end) and ``found`` (it has one)."""
        cfg, prims = self.config, self.prims
        X, T, n = tree.X, tree.T, tree.n
        lx, ly, lt, P, S = prims._lx, prims._ly, self._lt, self._P, self._S
        qx2, qy2 = qx[:, None], qy[:, None]
        atan = np.arctan2(qy2 - X[:n, 1], qx2 - X[:n, 0])  # numpy's (not the C library's) bits, see .kernels
        if self._compiled:  # the same answers, see .kernels.explore_batch
            out = kernels.explore_batch(tree.arrays, n, qx, qy, atan, self._search)
            if out[0]:
                return out[1:]
        ang = np.abs((atan - X[:n, 2] + np.pi) % (2.0 * np.pi) - np.pi)
        d = (X[:n, 0] - qx2) ** 2 + (X[:n, 1] - qy2) ** 2
        parents = np.argmin(d + (cfg.heading_weight * ang) ** 2, axis=1)
        uniq, inv = np.unique(parents, return_inverse=True)
        px, py, pth, pt = X[uniq, 0:1], X[uniq, 1:2], X[uniq, 2:3], T[uniq, None]
        c, s_ = np.cos(pth), np.sin(pth)
        xs = px + c * lx - s_ * ly  # (U, P*S)
        ys = py + s_ * lx + c * ly
        sok = self._static_ok(xs.ravel(), ys.ravel()).reshape(len(uniq), P, S).all(axis=2)
        if self._cons.count:
            cok = self._cons.free(xs.ravel(), ys.ravel(), (pt + lt).ravel()).reshape(len(uniq), P, S).all(axis=2)
        else:
            cok = np.ones_like(sok)
        valid = sok & cok
        last = S - 1
        ex, ey = xs[:, last::S], ys[:, last::S]  # (U, P) end points
        dd = (ex[inv] - qx2) ** 2 + (ey[inv] - qy2) ** 2  # (b, P)
        dd[~valid[inv]] = np.inf
        best = np.argmin(dd, axis=1)
        found = np.isfinite(dd[np.arange(len(best)), best])
        return kernels.Batch(uniq, inv, sok, cok, ex, ey, best, found)

    def _explore(self, tree: _Tree, samples: np.ndarray) -> tuple[int, tuple[int, tuple[int, float]] | None]:
        """One random expansion per row of ``samples`` ``(b, 2)`` in one vectorised pass (the same rule as
        :meth:`_extend` for each sample): returns the number of nodes added and the first join found."""
        cfg, prims = self.config, self.prims
        X, T = tree.X, tree.T
        batch = self._expand_batch(tree, samples[:, 0].copy(), samples[:, 1].copy())
        if self._compiled:  # the same nodes in the same order, see .kernels.explore_add
            tree.n, new = kernels.explore_add(tree.arrays, tree.n, batch, self._search)
            return self._joins(tree, new)
        uniq, inv, sok, cok, ex, ey, best, found = batch
        uniq_l, inv_l, best_l, found_l = uniq.tolist(), inv.tolist(), best.tolist(), found.tolist()
        added = []
        seen: set[tuple[int, int]] = set()
        for j in range(len(samples)):
            u = inv_l[j]
            k = best_l[j]
            if not found_l[j]:
                k = _WAIT_PRIM
                i = uniq_l[u]
                if (u, k) in seen or not (sok[u] & ~cok[u]).any() or T[i] + cfg.wait_step > self._t_end:
                    continue
                if not self._still_free(X[i, 0], X[i, 1], T[i], T[i] + cfg.wait_step):
                    continue
                seen.add((u, k))
                added.append(tree.add(i, X[i].copy(), T[i] + cfg.wait_step, k))
                continue
            if (u, k) in seen:
                continue
            seen.add((u, k))
            i = uniq_l[u]
            pose = np.array([ex[u, k], ey[u, k], X[i, 2] + prims.angles[k]])
            added.append(tree.add(i, pose, T[i] + prims.durations[k], k))
        return self._joins(tree, np.array(added, dtype=np.int64))

    def _joins(self, tree: _Tree, new: np.ndarray) -> tuple[int, tuple[int, tuple[int, float]] | None]:
        """:meth:`_explore`'s answer for the nodes it added (``new``): their number and the first
        join found. Only nodes within tolerance of some course point in their waiting window
        are tried."""
        if not len(new):
            return 0, None
        cfg = self.config
        X, T = tree.X, tree.T
        if self._compiled:
            near = np.flatnonzero(kernels.near_goal(tree.arrays, new, self._goal_kernel))
        else:
            gt, gxy = self._goal.t, self._goal.xy_eff
            gx = (gxy[:, 0][None, :] - X[new, 0:1]) ** 2 + (gxy[:, 1][None, :] - X[new, 1:2]) ** 2
            window = (gt[None, :] > T[new, None]) & (gt[None, :] <= T[new, None] + cfg.max_wait)
            near = np.flatnonzero(np.where(window, gx, np.inf).min(axis=1) <= cfg.goal_tolerance ** 2)
        for m in near.tolist():
            k_new = int(new[m])
            if T[k_new] <= self._t_end:
                join = self._join(X[k_new, 0], X[k_new, 1], T[k_new], X[k_new, 2])
                if join is not None:
                    return len(new), (k_new, join)
        return len(new), None

    def _heading_cost(self, X: np.ndarray, n: int, qx: np.ndarray, qy: np.ndarray) -> np.ndarray:
        """``(heading_weight * |angle between each node's heading and the direction to q|)^2``:
        breaks ties between nodes at one position (a spin keeps the position) in favour of
        the one that faces ``q``."""
        ang = np.arctan2(qy - X[:n, 1], qx - X[:n, 0]) - X[:n, 2]
        ang = np.abs((ang + np.pi) % (2.0 * np.pi) - np.pi)
        return (self.config.heading_weight * ang) ** 2

    def _nearest(self, X: np.ndarray, n: int, q: np.ndarray) -> int:
        d = (X[:n, 0] - q[0]) ** 2 + (X[:n, 1] - q[1]) ** 2 + self._heading_cost(X, n, q[0], q[1])
        return int(np.argmin(d))

    def repair(
        self,
        path: TimedPath,
        goal: GoalSpec,
        constraints: ConstraintTable,
        waits: tuple[float, ...] = (0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0),
        max_nodes: int = 3,
    ) -> TimedPath | None:
        """Make ``path`` respect ``constraints`` by waiting, without search: insert a wait of
        each duration in ``waits`` at one of the last ``max_nodes`` nodes before the first
        violation, shift the rest of the branch, re-join the goal course, and return the
        first such path that violates nothing (``path`` itself if it already complies), or
        ``None``. CBS's usual conflict — two robots crossing — is resolved this way by one
        of them waiting, at almost no cost."""
        self._bind(goal, constraints)
        ok = constraints.free(path.pose[:, 0], path.pose[:, 1], path.t)
        if ok.all() and self._path_free(path):
            return path
        if not path.reached:
            return None
        first_bad = int(np.argmin(ok))
        idx = path.nodes.tolist()
        nodes = [(path.pose[k].copy(), float(path.t[k]), int(p)) for k, p in zip(idx, path.node_prim.tolist())]
        t0 = float(goal.t[0])
        before = [j for j, k in enumerate(idx) if k < first_bad and path.t[k] >= t0 - 1e-9]
        for j in sorted(before, reverse=True)[:max_nodes]:
            pose_j, t_j, _ = nodes[j]
            for w in waits:
                shifted = nodes[: j + 1] + [(pose_j.copy(), t_j + w, _WAIT_PRIM)]
                shifted += [(p, t + w, k) for p, t, k in nodes[j + 1:]]
                last_pose, last_t, _ = shifted[-1]
                if last_t > goal.t[-1]:
                    break
                join = self._join(last_pose[0], last_pose[1], last_t, last_pose[2])
                if join is None:
                    continue
                cand = self._build(shifted, join)
                if self._path_free(cand):
                    return cand
        return None

    def _path_free(self, path: TimedPath) -> bool:
        """``path`` respects the bound constraints at every one of its samples and at every
        constraint-grid time in between (a wait is one sample at each end)."""
        cons = self._cons
        if cons.count == 0:
            return True
        grid = np.arange(path.t0, path.t_end, cons.dt)
        ts = np.concatenate([path.t, grid])
        if compiled_kernels():  # the same answer, see .kernels.path_free
            free = kernels.path_free(ts, path.t, path.pose, cons.kernel)
            if free >= 0:
                return bool(free)
        xy = path.position_at(ts)
        return cons.all_free(xy[:, 0], xy[:, 1], ts)

    def _nearest_to_goal(self, X: np.ndarray, T: np.ndarray, n: int, fails: np.ndarray) -> int:
        g = self._goal.at(T[:n])
        d = (X[:n, 0] - g[:, 0]) ** 2 + (X[:n, 1] - g[:, 1]) ** 2 + self._heading_cost(X, n, g[:, 0], g[:, 1])
        d[fails[:n] >= 2] += 1e6  # dead ends: let other nodes try
        return int(np.argmin(d))

    # ------------------------------------------------------------------ smoothing
    def _visible(self, x: float, y: float, targets: np.ndarray) -> np.ndarray:
        """Which straight segments from ``(x, y)`` to ``targets (J, 2)`` keep the buffer."""
        s = _VISIBLE_S
        px = x + s * (targets[:, :1] - x)
        py = y + s * (targets[:, 1:] - y)
        return self._static_ok(px.ravel(), py.ravel()).reshape(px.shape).all(axis=1)

    def _smooth(
        self, nodes: list[tuple[np.ndarray, float, int]], join: tuple[int, float]
    ) -> tuple[list[tuple[np.ndarray, float, int]], tuple[int, float]] | None:
        """Re-drive the branch with primitives aimed at its furthest visible waypoint."""
        if any(p == _WAIT_PRIM for _, _, p in nodes):
            return None  # waits encode the timing CBS asked for: keep the branch
        W = np.array([p[:2] for p, _, _ in nodes])
        pose = nodes[0][0].copy()
        t = nodes[0][1]
        out = [nodes[0]]
        anchor = 0
        durations = self.prims.durations
        raw_join_time = self._goal.t[join[0]]
        for _ in range(len(nodes) - 1):
            rest = W[anchor + 1:]
            if len(rest):
                vis = self._visible(pose[0], pose[1], rest)
                j = anchor + 1 + (int(np.flatnonzero(vis)[-1]) if vis.any() else 0)
                target = W[j]
            else:  # past the branch's last waypoint: head for the goal
                j = anchor
                target = self._intercept(pose[0], pose[1], t)
            ends, sok, cok, _, _ = self._candidates(pose[0], pose[1], pose[2], t)
            valid = sok & cok
            if not valid.any():
                return None
            d = (ends[:, 0] - target[0]) ** 2 + (ends[:, 1] - target[1]) ** 2
            d[~valid] = np.inf
            k = int(np.argmin(d))
            pose = ends[k].copy()
            t += float(durations[k])
            out.append((pose.copy(), t, k))
            new_join = self._join(pose[0], pose[1], t, pose[2])
            if new_join is not None:
                if self._goal.t[new_join[0]] <= raw_join_time + 1e-9:
                    return out, new_join
                return None
            seg = W[anchor: j + 1]
            anchor = anchor + int(np.argmin((seg[:, 0] - pose[0]) ** 2 + (seg[:, 1] - pose[1]) ** 2))
        return None

    # ------------------------------------------------------------------ output
    def _build(self, nodes: list[tuple[np.ndarray, float, int]], join: tuple[int, float] | None) -> TimedPath:
        """The timed path through ``nodes`` (``(pose, time, primitive)``; the first is the start)
        and, with ``join = (k, depart)``, a wait until ``depart`` and the goal course from sample
        ``k``: compiled (:func:`.kernels.build_path`, the same bits) unless the kernels are off."""
        if compiled_kernels():
            path = self._build_compiled(nodes, join)
            if path is not None:
                return path
        return self._build_reference(nodes, join)

    def _build_compiled(self, nodes: list[tuple[np.ndarray, float, int]], join: tuple[int, float] | None
                        ) -> TimedPath | None:
        prims = self.prims
        pose = np.array([p for p, _, _ in nodes], dtype=np.float64).reshape(-1, 3)
        ths = pose[:, 2].tolist()
        # math.cos/sin: what MotionPrimitives.poses uses (Python's libm; numba's is the same C library,
        # but the values are passed in so that nothing depends on that).
        cs = np.array([math.cos(v) for v in ths])
        sn = np.array([math.sin(v) for v in ths])
        nt = np.array([t for _, t, _ in nodes], dtype=np.float64)
        nk = np.array([k for _, _, k in nodes], dtype=np.int64)
        goal_time = math.nan
        if join is not None:
            g = self._goal
            k, depart = join
            t_last = nodes[-1][1]
            add_wait = bool(depart > t_last + 1e-6 and g.t[k] > depart + 1e-6)
            tail_t, tail_xy, tail_h = g.t[k:], g.xy_eff[k:], g.heading[k:]
            goal_time = float(g.t[k])
        else:
            depart, add_wait = 0.0, False
            tail_t, tail_xy, tail_h = _EMPTY, _EMPTY2, _EMPTY
        branch = kernels.Branch(pose[:, 0].copy(), pose[:, 1].copy(), pose[:, 2].copy(), nt, nk, cs, sn)
        tail = kernels.Tail(add_wait, float(depart), tail_t, tail_xy, tail_h)
        ok, t_all, pose_all, kind_all, node_idx = kernels.build_path(branch, prims.kernel, tail, _WAIT_PRIM)
        if not ok:
            return None
        return TimedPath._trusted(t_all, pose_all, kind_all, node_idx, nk,
                                  goal_time, join is not None)

    def _build_reference(self, nodes: list[tuple[np.ndarray, float, int]], join: tuple[int, float] | None
                         ) -> TimedPath:
        """The numpy reference of :meth:`_build`."""
        prims = self.prims
        S = prims.samples
        ts = [np.array([nodes[0][1]])]
        poses = [nodes[0][0][None, :]]
        kinds = [np.array([START])]
        node_idx = [0]
        node_prim = [-1]
        count = 1
        for (p_prev, t_prev, _), (p, t, k) in zip(nodes[:-1], nodes[1:]):
            if k == _WAIT_PRIM:
                ts.append(np.array([t]))
                poses.append(p[None, :])
                kinds.append(np.array([WAIT]))
                count += 1
            else:
                ts.append(t_prev + prims.sample_t[k])
                poses.append(prims.poses(p_prev, k))
                kinds.append(np.full(S, PRIM))
                count += S
            node_idx.append(count - 1)
            node_prim.append(k)
        goal_time = math.nan
        if join is not None:
            g = self._goal
            k, depart = join
            p_last, t_last, _ = nodes[-1]
            if depart > t_last + 1e-6 and g.t[k] > depart + 1e-6:
                ts.append(np.array([depart]))
                poses.append(p_last[None, :])
                kinds.append(np.array([WAIT]))
            tail_t = g.t[k:]
            tail = np.column_stack([g.xy_eff[k:], g.heading[k:]])
            ts.append(tail_t)
            poses.append(tail)
            kinds.append(np.full(len(tail_t), TAIL))
            goal_time = float(g.t[k])
        t_all = np.concatenate(ts)
        pose_all = np.vstack(poses)
        # Guard strict monotonicity (a junction at the very time of the last node).
        keep = np.concatenate([[True], np.diff(t_all) > 1e-9])
        if not keep.all():
            t_all, pose_all = t_all[keep], pose_all[keep]
            kind_all = np.concatenate(kinds)[keep]
        else:
            kind_all = np.concatenate(kinds)
        return TimedPath(t_all, pose_all, kind_all, node_idx, node_prim, goal_time, join is not None)
