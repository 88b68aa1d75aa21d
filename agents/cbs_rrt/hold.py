"""Holding a reached formation: the CBS + RRT expert's short-horizon holder (issue 12 item 1).

Where the slots are known ahead (a virtual leader) the expert plans the hold instead
(:mod:`swarm_env_agents.cbs_rrt.hold_plan`, on by default): this holder is the opt-in one for the
other cases (``hold_slots=True``).

CBS + RRT plans the way into a formation; once every follower is near its slot (within the
settle tolerance plus ``hold_capture``), :class:`CBSRRTExpert` (with ``hold_slots=True``) hands the swarm to a
:class:`SlotHolder` until the next formation switch. Replanning does not hold a formation well:
the slots keep moving (the leader turns, a slot pushed out of an obstacle sweeps round it or
flips to its other side) and every replan knocks robots in formation off their courses.
``benchmarks/hold_bound.py`` shows that an ideal follower tracking the slots directly holds
92-95 % of the time where the planner held 2-17 %.

The holder is a short-horizon search over the robots' own kinematics, robot by robot:

* **targets**: each follower's slot at ``horizon`` points ahead, the next step and then every
  ``every`` steps (:meth:`SlotHolder.steps_ahead`; the expert spreads four points over two seconds
  whatever the env's step), for a virtual leader the env's exact slots
  (:func:`swarm_env.geometry.formation.virtual_slot_trajectory`), otherwise the formation layer's predicted
  course;
* **candidates**: a grid of twists ``(v, omega)`` (reversing allowed) for the first step, then a
  second grid held for the rest of the horizon; each sequence is rolled out on exact unicycle arcs;
* **cost**: the distance to the target at every point, plus a steeper term beyond two thirds of the
  tolerance (being *inside* the tolerance is what counts), with a little extra weight on the first
  step. Where the straight line from the robot to its last target crosses an obstacle's clearance,
  the distance is the *geodesic* one (:func:`geodesic_grid`, Dijkstra on the distance field
  around the target): a slot that flips to an obstacle's far side is followed round it instead
  of being pushed towards through it;
* **safety**: a sequence that comes closer than the tracker's shield would allow (radius +
  ``shield_margin`` + one substep's travel) to an obstacle, to a moving disc (human, robot
  leader, with ``mover_margin`` more; a scripted human where its path puts it, the others at
  constant velocity) or to another follower is penalised heavily (never below what the
  robot has now: a robot already too close may move, just not closer). Robots decide one after
  another, the farthest from its slot first: a later robot keeps clear of the whole horizon of
  the earlier ones' choices, an earlier one only of the later ones' next step (they give way).

Afterwards the expert's one-step shield (:meth:`CBSRRTExpert._shield`) still checks every twist.
Deterministic: no randomness, fixed candidate grids.

What it achieves, with the command that measures it, is in
:class:`~swarm_env_agents.cbs_rrt.policy.CBSRRTExpert`'s docstring (``hold_slots``).
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass

import numpy as np

from swarm_env.kernel_cache import njit
from swarm_env.scenario import RobotSpec, WorldSpec
from swarm_env_agents.cbs_rrt.distance_field import DistanceField

__all__ = ["GeodesicMap", "SlotHolder", "geodesic_grid", "unicycle_rollout"]

_SQRT2 = math.sqrt(2.0)
_PENALTY = 1e5  # cost per metre of a safety violation: dwarfs any distance term
_UNREACHED = 50.0  # m: the geodesic distance of a point the search did not reach


@njit()
def geodesic_grid(
    values: np.ndarray, nx: int, ny: int, resolution: float, stride: int, gx: float, gy: float, free: float, half: int
) -> tuple[np.ndarray, float, float, float]:  # pragma: no cover - compiled
    """Geodesic distance to the point ``(gx, gy)`` over the free nodes of a distance field.

    A ``(2 half + 1)^2`` window of the field's nodes taken every ``stride``-th node, centred on
    the node nearest the goal; a node is free where the field's clearance is ``>= free``. Dijkstra
    with 8-connected moves (diagonals ``sqrt 2`` steps) from the goal's node, which starts at its
    distance to the goal. Returns ``(dist (w, w) [row = y, column = x], x0, y0, step)``: node
    ``(a, b)`` of the window lies at ``(x0 + a step, y0 + b step)``; unreached nodes are ``inf``.
    The 8-connected metric overestimates a straight line by at most 8 %.
    """
    step = resolution * stride
    ci = int(round(gx / step))
    cj = int(round(gy / step))
    w = 2 * half + 1
    dist = np.full((w, w), np.inf)
    i0 = ci - half
    j0 = cj - half
    dist[half, half] = math.hypot(ci * step - gx, cj * step - gy)
    heap = [(dist[half, half], half, half)]
    while heap:
        d, a, b = heapq.heappop(heap)
        if d > dist[b, a]:
            continue
        for da in (-1, 0, 1):
            for db in (-1, 0, 1):
                if da == 0 and db == 0:
                    continue
                a2 = a + da
                b2 = b + db
                if a2 < 0 or b2 < 0 or a2 >= w or b2 >= w:
                    continue
                fi = (i0 + a2) * stride
                fj = (j0 + b2) * stride
                if fi < 0 or fj < 0 or fi >= nx or fj >= ny or values[fj * nx + fi] < free:
                    continue
                nd = d + step * (_SQRT2 if da != 0 and db != 0 else 1.0)
                if nd < dist[b2, a2]:
                    dist[b2, a2] = nd
                    heapq.heappush(heap, (nd, a2, b2))
    return dist, i0 * step, j0 * step, step


@dataclass(frozen=True)
class GeodesicMap:
    """A :func:`geodesic_grid` result, read at the nearest node."""

    dist: np.ndarray
    x0: float
    y0: float
    step: float

    @classmethod
    def around(cls, field: DistanceField, goal: np.ndarray, free: float, reach: float = 3.0, stride: int = 2) -> GeodesicMap:
        """The geodesic distance to ``goal`` within ``reach`` (m) of it, on every ``stride``-th node
        of ``field``, through points of clearance ``>= free``."""
        half = int(math.ceil(reach / (field.resolution * stride)))
        return cls(*geodesic_grid(field.values, field.nx, field.ny, field.resolution, stride,
                                  float(goal[0]), float(goal[1]), float(free), half))

    def lookup(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Distances at points (any equal shapes); outside the window or unreached: ``50`` m."""
        w = self.dist.shape[0]
        a = np.rint((np.asarray(x) - self.x0) / self.step)
        b = np.rint((np.asarray(y) - self.y0) / self.step)
        inside = (a >= 0) & (a < w) & (b >= 0) & (b < w)
        d = self.dist[np.clip(b, 0, w - 1).astype(np.intp), np.clip(a, 0, w - 1).astype(np.intp)]
        return np.where(inside & np.isfinite(d), d, _UNREACHED)


def unicycle_rollout(
    x: np.ndarray, y: np.ndarray, th: np.ndarray, v: np.ndarray, w: np.ndarray, dt: float, steps: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Poses after each of ``steps`` steps of ``dt`` at constant twists ``(v, w)`` on exact arcs.

    Inputs broadcast together; returns ``(x, y, theta)``, each of shape ``broadcast + (steps,)``."""
    x, y, th, v, w = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in (x, y, th, v, w)))
    turning = np.abs(w) > 1e-9
    ws = np.where(turning, w, 1.0)
    out = np.empty((3, *x.shape, steps))
    for k in range(steps):
        th2 = th + w * dt
        x = np.where(turning, x + v / ws * (np.sin(th2) - np.sin(th)), x + v * np.cos(th) * dt)
        y = np.where(turning, y - v / ws * (np.cos(th2) - np.cos(th)), y + v * np.sin(th) * dt)
        th = th2
        out[0, ..., k], out[1, ..., k], out[2, ..., k] = x, y, th
    return out[0], out[1], out[2]


class SlotHolder:
    """Twists that keep followers on moving slot targets (see the module docstring).

    Args:
        field: the static map's distance field.
        robots: the followers: their radius (m), max_speed (m/s) and max_turn_rate (rad/s).
        world: the env's step ``dt`` (s), its physics substeps (a new command takes effect one
            substep, ``dt / substeps``, late, so that much travel at top speed is added to every
            margin) and the formation's settle tolerance (m).
        shield_margin: the gap (m) kept to obstacles, robots and moving discs, as the shield does.
        horizon: points looked ahead (>= 2): one step, then ``horizon - 1`` more, ``every`` steps
            apart.
        every: env steps between the later points (a short ``dt`` still looks ahead far enough
            to see a human coming, at the same cost).
        samples: speeds and turn rates per candidate grid (odd: zero is one of them).
        mover_margin: extra gap (m) kept to humans and a robot leader: their predictions are
            uncertain and they do not give way.
    """

    def __init__(
        self,
        field: DistanceField,
        robots: RobotSpec,
        world: WorldSpec,
        *,
        shield_margin: float,
        horizon: int = 5,
        every: int = 1,
        samples: int = 9,
        mover_margin: float = 0.2,
    ) -> None:
        if horizon < 2:
            raise ValueError(f"horizon must be >= 2 points, got {horizon!r}")
        if not isinstance(every, int) or every < 1:
            raise ValueError(f"every must be an int >= 1 (steps), got {every!r}")
        if samples < 3 or samples % 2 == 0:
            raise ValueError(f"samples must be an odd number >= 3, got {samples!r}")
        self.field = field
        self.radius = float(robots.radius)
        self.dt = float(world.dt)
        self.horizon = int(horizon)
        self.every = every
        self.tolerance = float(world.settle_tolerance)
        max_speed, max_turn_rate = robots.max_speed, robots.max_turn_rate
        lag = max_speed * (world.dt / world.substeps)
        # The shield's own thresholds (a substep's travel at top speed included) plus a centimetre:
        # twists chosen here do not trip it.
        self.obstacle_gap = self.radius + shield_margin + lag + 0.01
        self.robot_gap = 2.0 * self.radius + shield_margin + 2.0 * lag + 0.01
        self.mover_gap = float(shield_margin) + lag + 0.01 + float(mover_margin)  # beyond the two radii
        v, w = np.meshgrid(np.linspace(-max_speed, max_speed, samples),
                           np.linspace(-max_turn_rate, max_turn_rate, samples), indexing="ij")
        self._v, self._w = v.ravel(), w.ravel()

    def _own_cost(
        self, i: int, pose: np.ndarray, X: np.ndarray, Y: np.ndarray, targets: np.ndarray, clearance: np.ndarray,
        clear_now: float, movers: tuple[np.ndarray, np.ndarray] | None,
    ) -> np.ndarray:
        """Robot ``i``'s cost of each candidate sequence ``X, Y (S, horizon)`` before the other
        followers are considered: the distance to its targets (geodesic where the straight way to
        the last one is blocked), obstacles (``clearance (S,)``: each sequence's smallest) and
        the moving discs."""
        d = np.hypot(X - targets[:, i, 0], Y - targets[:, i, 1])
        goal = targets[-1, i]
        seg = np.linspace(0.0, 1.0, 12)
        line = self.field.clearance_xy(pose[i, 0] + seg * (goal[0] - pose[i, 0]), pose[i, 1] + seg * (goal[1] - pose[i, 1]))
        if line.min() < self.radius + 0.02:  # the straight way is blocked: go round
            d = GeodesicMap.around(self.field, goal, self.radius + 0.04).lookup(X, Y)
        # Steeper beyond two thirds of the tolerance (the step counts as held or not there, with
        # a third left for the physics' error); the next step weighs a little more (it is the one
        # that will be driven). Weights chosen on paper_cbs_switch seed 0.
        inner = self.tolerance * (2.0 / 3.0)
        cost = (d + 4.0 * np.maximum(d - inner, 0.0)).sum(axis=1) + 0.3 * d[:, 0]
        cost += _PENALTY * np.maximum(min(self.obstacle_gap, clear_now) - clearance, 0.0)
        if movers is not None and len(movers[0]):
            mxy, mrad = movers
            for m in range(len(mxy)):
                need = self.radius + float(mrad[m]) + self.mover_gap
                d_now = math.hypot(pose[i, 0] - mxy[m, 0, 0], pose[i, 1] - mxy[m, 0, 1])
                gap = np.hypot(X - mxy[m, 1:, 0], Y - mxy[m, 1:, 1]).min(axis=1)
                cost += _PENALTY * np.maximum(min(need, d_now) - gap, 0.0)
        return cost

    def steps_ahead(self) -> np.ndarray:
        """The env steps ``(horizon,)`` after now at which the candidates are scored:
        ``1, 1 + every, 1 + 2 every, ...``."""
        return 1 + self.every * np.arange(self.horizon)

    def twists(
        self,
        pose: np.ndarray,
        twist_now: np.ndarray,
        targets: np.ndarray,
        movers: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> np.ndarray:
        """``(N, 2)`` twists for followers at ``pose (N, 3)`` moving at ``twist_now (N, 2)``,
        whose slots will be at ``targets (horizon, N, 2)`` at :meth:`steps_ahead`;
        ``movers = (xy (M, horizon + 1, 2), radius (M,))``: humans and a robot leader, now and
        where they are predicted then; kept ``mover_margin`` farther away than the rest."""
        H, dt = self.horizon, self.dt
        n = len(pose)
        C = len(self._v)
        # Sequences: first twist (C) x later twist (C), flattened first-major.
        x1, y1, t1 = unicycle_rollout(pose[:, 0:1], pose[:, 1:2], pose[:, 2:3], self._v, self._w, dt, 1)
        v2, w2 = np.tile(self._v, C), np.tile(self._w, C)
        first = np.repeat(np.arange(C), C)
        later_steps = unicycle_rollout(x1[:, first, 0], y1[:, first, 0], t1[:, first, 0], v2, w2, dt * self.every, H - 1)
        xs = np.concatenate([x1[:, first], later_steps[0]], axis=2)  # (N, C*C, H)
        ys = np.concatenate([y1[:, first], later_steps[1]], axis=2)
        clearance = self.field.clearance_xy(xs, ys).min(axis=2)  # (N, C*C)
        clear_now = self.field.clearance_xy(pose[:, 0], pose[:, 1])
        now_x, now_y, _ = unicycle_rollout(pose[:, 0], pose[:, 1], pose[:, 2], twist_now[:, 0], twist_now[:, 1], dt, 1)
        err_now = np.hypot(pose[:, 0] - targets[0, :, 0], pose[:, 1] - targets[0, :, 1])
        out = np.zeros((n, 2))
        decided: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        for i in np.argsort(-err_now, kind="stable").tolist():
            X, Y = xs[i], ys[i]
            cost = self._own_cost(i, pose, X, Y, targets, clearance[i], float(clear_now[i]), movers)
            for j in range(n):
                if j == i:
                    continue
                d_now = math.hypot(pose[i, 0] - pose[j, 0], pose[i, 1] - pose[j, 1])
                if j in decided:  # keep clear of its whole chosen horizon
                    ox, oy = decided[j]
                    gap = np.hypot(X - ox, Y - oy).min(axis=1)
                else:  # it decides later and gives way: only its next step at its current twist
                    gap = np.hypot(X[:, 0] - now_x[j, 0], Y[:, 0] - now_y[j, 0])
                cost += _PENALTY * np.maximum(min(self.robot_gap, d_now) - gap, 0.0)
            b = int(np.argmin(cost))
            out[i] = self._v[b // C], self._w[b // C]
            decided[i] = (X[b], Y[b])
        return out
