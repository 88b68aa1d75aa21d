"""The formation layer (paper 000 Sec. III-D): every follower's planning goal over time.

At a replanning time ``t0`` the layer predicts the leader's pose on a time grid
``t0, t0 + dt, ..., t1`` — exactly for a virtual leader (it moves along its
path at constant speed, :func:`swarm_env.geometry.paths.virtual_leader`), by constant
speed along the path from its current projection for a robot leader — and
composes it with the formation active at each grid time
(:func:`swarm_env.geometry.formation.active_formation`, ``formation_offsets``): the
*slot course* of each follower, including the switches scheduled inside the
window. Then, as the paper does for the current slot targets:

1. a slot whose clearance is below ``clearance`` (the planner's buffer: radius +
   margin) is moved to the nearest point that has it
   (:meth:`swarm_env.geometry.static_map.StaticMap.project_free`);
2. two slots closer than ``separation`` (two radii + the conflict margin) at the
   same time — two projected slots can land on each other — are pushed apart
   symmetrically and projected again (a few rounds). So the formation's own
   goals never ask two robots to overlap; CBS only has to order the way there.

A course *jumps* where its goal moves faster than a robot can follow
(:class:`JumpRule`'s ``speed``): at a formation switch, where the leader's polyline turns (the
whole formation rotates at once) and where a projected slot flips to the other
side of an obstacle. With a ``window > 0`` a fast step is only a jump if the
course also moves farther than ``window_speed * window + lag`` within
some stretch of at most ``window`` seconds: a slot that briefly sweeps round an
obstacle a little faster than a robot drives is followed by a tracker that
aims ahead (it lags by less than ``lag``), not replanned as a jump. The part before the first jump is what a robot can track;
:attr:`GoalWindow.piece_end` marks it and the planner replans when it ends.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from swarm_env.geometry.formation import formation_offsets
from swarm_env.geometry.paths import PolylinePath
from swarm_env.geometry.static_map import StaticMap
from swarm_env.scenario import Scenario

__all__ = ["GoalWindow", "FormationGoals", "JumpRule"]

_CHUNK = 256  # samples per cached chunk of a virtual leader's goal table


@dataclass(frozen=True, eq=False)
class GoalWindow:
    """Planning goals of all followers over ``[t[0], t[-1]]``.

    Attributes:
        t: ``(K,)`` grid times (s), ``t[0]`` the replanning time.
        xy: ``(N, K, 2)`` goal positions (slots moved out of obstacles and apart).
        raw: ``(N, K, 2)`` the formation's slots before any adjustment.
        heading: ``(K,)`` the predicted leader heading (rad).
        leader: ``(K, 3)`` the predicted leader pose.
        formation: ``(K,)`` index of the active formation.
        piece_end: ``(N,)`` index of the last sample before each course's first jump
            (``K - 1`` if none).
    """

    t: np.ndarray
    xy: np.ndarray
    raw: np.ndarray
    heading: np.ndarray
    leader: np.ndarray
    formation: np.ndarray
    piece_end: np.ndarray

    def at(self, i: int, time: float) -> np.ndarray:
        """Goal of follower ``i`` at ``time`` (linear between samples, clamped)."""
        return np.array([np.interp(time, self.t, self.xy[i, :, 0]), np.interp(time, self.t, self.xy[i, :, 1])])


@dataclass(frozen=True)
class JumpRule:
    """When a goal course jumps (see the module docstring).

    Attributes:
        speed: a goal moving faster than this between two samples jumps (m/s).
        window: ``0``: every such fast step is a jump; ``> 0``: only one inside a stretch of at
            most this long (s) over which the goal moves farther than ``window_speed * window + lag``.
        lag: the lag (m) a tracker may take on a short fast stretch of a course.
        window_speed: the robot's top speed for that test (m/s; ``None``: ``speed``).
        chord_clearance: with ``window > 0``, a fast step whose straight chord comes closer than
            this to an obstacle is a jump whatever its length (m; ``None``: the goals'
            ``clearance - 0.05``).
    """

    speed: float = 0.4
    window: float = 0.0
    lag: float = 0.3
    window_speed: float | None = None
    chord_clearance: float | None = None


class FormationGoals:
    """Slot courses for one scenario (see the module docstring).

    Args:
        scenario: the scenario (leader path and speed, formation schedule, follower count).
        static: its static map.
        clearance: minimum clearance of a goal from obstacles and walls (m).
        separation: minimum distance between two goals at one time (m).
        dt: grid step (s).
        jumps: when a course jumps (:class:`JumpRule`; kept as ``jump_speed``, ``jump_window``,
            ``jump_lag``, ``window_speed`` and ``chord_clearance``, the defaults filled in).
        separation_rounds: push-apart rounds.
    """

    def __init__(
        self,
        scenario: Scenario,
        static: StaticMap,
        *,
        clearance: float,
        separation: float,
        dt: float = 0.25,
        jumps: JumpRule = JumpRule(),
        separation_rounds: int = 8,
    ) -> None:
        self.scenario = scenario
        self.static = static
        self.clearance = float(clearance)
        self.separation = float(separation)
        self.dt = float(dt)
        self.jump_speed = float(jumps.speed)
        self.jump_window = float(jumps.window)
        self.jump_lag = float(jumps.lag)
        self.chord_clearance = self.clearance - 0.05 if jumps.chord_clearance is None else float(jumps.chord_clearance)
        self.window_speed = self.jump_speed if jumps.window_speed is None else float(jumps.window_speed)
        self.rounds = int(separation_rounds)
        self.n = scenario.robots.count
        self.path = PolylinePath(scenario.leader.path)
        self.ats = np.array([f.at for f in scenario.formations], dtype=np.float64)
        self.offsets = np.stack([formation_offsets(f, self.n) for f in scenario.formations])  # (F, N, 2)
        self._leader_s = 0.0  # robot leader: progress along the path (monotone)
        self._chunks: dict[int, tuple[np.ndarray, ...]] = {}  # virtual leader: cached grid chunks

    def reset(self) -> None:
        self._leader_s = 0.0

    # ------------------------------------------------------------------ leader
    def leader_poses(self, times: np.ndarray, leader_pose: np.ndarray | None = None, t0: float = 0.0) -> np.ndarray:
        """Predicted leader poses ``(K, 3)`` at ``times``.

        Virtual leader (``leader_pose`` ignored): ``s = speed * max(t - start_delay, 0)``
        along the path, the heading of the segment under it (outgoing at a vertex) —
        the same as :func:`swarm_env.geometry.paths.virtual_leader`. Robot leader: its projection on
        the path at ``t0`` (from ``leader_pose``) advanced at ``speed``.
        """
        spec = self.scenario.leader
        times = np.asarray(times, dtype=np.float64)
        if spec.kind == "virtual" or leader_pose is None:
            s = spec.speed * np.maximum(times - spec.start_delay, 0.0)
        else:
            s_now = self.path.project(np.asarray(leader_pose)[:2], s_min=self._leader_s, s_max=self._leader_s + 5.0)
            self._leader_s = max(self._leader_s, s_now)
            start = max(float(t0), spec.start_delay)
            s = self._leader_s + spec.speed * np.maximum(times - start, 0.0)
        s = np.clip(s, 0.0, self.path.length)
        xy = self.path.points_at(s)
        nseg = len(self.path.headings)
        seg = np.clip(np.searchsorted(self.path.cumulative, s, side="right") - 1, 0, nseg - 1)
        return np.column_stack([xy, self.path.headings[seg]])

    # ------------------------------------------------------------------ goals
    def _samples(self, t: np.ndarray, leader_pose: np.ndarray | None, t0: float) -> tuple[np.ndarray, ...]:
        """Leader poses ``(K, 3)``, formation indices ``(K,)``, raw and adjusted slots ``(K, N, 2)``."""
        leader = self.leader_poses(t, leader_pose, t0)
        form = np.clip(np.searchsorted(self.ats, t, side="right") - 1, 0, len(self.ats) - 1)
        off = self.offsets[form]  # (K, N, 2)
        c = np.cos(leader[:, 2])[:, None]
        s = np.sin(leader[:, 2])[:, None]
        raw = np.empty_like(off)
        raw[..., 0] = leader[:, None, 0] + c * off[..., 0] - s * off[..., 1]
        raw[..., 1] = leader[:, None, 1] + s * off[..., 0] + c * off[..., 1]
        return leader, form, raw, self._adjust(raw, leader[:, 2])

    def _cached(self, k0: int, k1: int) -> tuple[np.ndarray, ...]:
        """Virtual leader: samples ``k0..k1`` of the global grid ``k dt``, computed in chunks
        once (every sample depends on its time only, so slicing is exact)."""
        out = []
        for c in range(k0 // _CHUNK, k1 // _CHUNK + 1):
            chunk = self._chunks.get(c)
            if chunk is None:
                t = np.arange(c * _CHUNK, (c + 1) * _CHUNK) * self.dt
                chunk = self._chunks[c] = self._samples(t, None, 0.0)
            lo = max(k0 - c * _CHUNK, 0)
            hi = min(k1 - c * _CHUNK, _CHUNK - 1) + 1
            out.append(tuple(a[lo:hi] for a in chunk))
        return tuple(np.concatenate(parts) for parts in zip(*out))

    def window(self, t0: float, t1: float, leader_pose: np.ndarray | None = None) -> GoalWindow:
        """Goals of every follower on the grid ``t0 + k dt`` up to ``t1`` (at least 2 samples)."""
        k = max(1, int(math.ceil((t1 - t0) / self.dt - 1e-9)))
        g0 = t0 / self.dt
        if self.scenario.leader.kind == "virtual" and abs(g0 - round(g0)) < 1e-6 and t0 >= 0:
            k0 = int(round(g0))
            leader, form, raw, xy = self._cached(k0, k0 + k)
            t = (k0 + np.arange(k + 1)) * self.dt
        else:
            t = t0 + np.arange(k + 1) * self.dt
            leader, form, raw, xy = self._samples(t, leader_pose, t0)
        xy = np.ascontiguousarray(xy.transpose(1, 0, 2))  # (N, K, 2)
        raw = np.ascontiguousarray(raw.transpose(1, 0, 2))
        step = np.hypot(*np.moveaxis(np.diff(xy, axis=1), 2, 0))  # (N, K-1)
        jump = self._jumps(xy, step)
        has = jump.any(axis=1)
        piece_end = np.where(has, jump.argmax(axis=1), len(t) - 1)
        for a in (t, xy, raw, leader, form, piece_end):
            a.flags.writeable = False
        return GoalWindow(t, xy, raw, leader[:, 2].copy(), leader, form, piece_end)

    def _jumps(self, xy: np.ndarray, step: np.ndarray) -> np.ndarray:
        """``(N, K-1)`` whether the step from each sample to the next is a jump (module docstring)."""
        jump = step > self.jump_speed * self.dt
        m_max = int(round(self.jump_window / self.dt))
        if m_max < 1 or not jump.any():
            return jump
        reach = self.window_speed * m_max * self.dt + self.jump_lag
        K1 = step.shape[1]
        far = np.zeros_like(jump)  # the step lies inside a stretch the course covers too fast
        for m in range(1, min(m_max, K1) + 1):
            d = xy[:, m:, :] - xy[:, :-m, :]  # (N, K-m, 2): stretch k..k+m
            over = np.sqrt(np.add.reduce(d * d, axis=2)) > reach
            for j in range(m):  # steps k+j, j < m, lie inside stretch k..k+m
                far[:, j:j + K1 - m + 1] |= over
        # A fast step whose straight chord cuts into the clearance a goal keeps (a slot flipping
        # to the other side of an obstacle) cannot be driven whatever its length.
        i, k = np.nonzero(jump & ~far)
        if len(i):
            a, b = xy[i, k], xy[i, k + 1]
            f = np.array([0.25, 0.5, 0.75])[:, None, None]
            pts = (a[None] + f * (b - a)[None]).reshape(-1, 2)
            clear = self.static.distance(pts).reshape(3, -1).min(axis=0)
            far[i[clear < self.chord_clearance], k[clear < self.chord_clearance]] = True
        return jump & far

    def _adjust(self, slots: np.ndarray, heading: np.ndarray) -> np.ndarray:
        """Move ``(K, N, 2)`` slots out of obstacles and apart from each other."""
        K, N, _ = slots.shape
        flat = slots.reshape(-1, 2)
        xy = self.static.project_free(flat, self.clearance).reshape(K, N, 2)
        if N < 2 or self.separation <= 0:
            return xy
        eye = np.eye(N, dtype=bool)[None]
        # Deterministic push direction for coincident slots: across the leader's heading.
        across = np.stack([-np.sin(heading), np.cos(heading)], axis=1)[:, None, None, :]
        order = np.sign(np.arange(N)[None, :, None] - np.arange(N)[None, None, :]).astype(float)[..., None]
        for _ in range(self.rounds):
            diff = xy[:, :, None, :] - xy[:, None, :, :]  # (K, N, N, 2): i - j
            dist = np.sqrt(np.add.reduce(diff * diff, axis=3))
            over = np.where(eye, 0.0, np.maximum(self.separation - dist, 0.0))
            if not over.any():
                break
            tiny = dist < 1e-9
            unit = np.where(tiny[..., None], across * order, diff / np.where(tiny, 1.0, dist)[..., None])
            push = 0.5 * np.einsum("knm,knmc->knc", over, unit)
            moved = over.any(axis=2)
            xy = xy + push
            xy[moved] = self.static.project_free(xy[moved], self.clearance)
        return xy
