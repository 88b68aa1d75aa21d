"""An expert that acts on the agents' observations only: the sensing counterpart of ``vo``.

``vo`` and ``cbs_rrt`` read the privileged world state (every robot's pose, the static map, the
humans' true positions). This expert reads exactly what an RL agent receives, the observation
vector of :func:`swarm_env.sensing.layout.observation_layout` (own twist, slot vector, leader block,
the nearest neighbours' and humans' rows, the lidar), plus the constants of the scenario that an
agent is built with (the robots' speed and turn-rate limits and radius, the humans' radius, the
lidar's range and ray count, whether the leader is a robot, the control step). It is the reference
for what observation-only control can do, and a teacher whose inputs a learner shares.

Per follower and control step (all followers, and any number of worlds' followers, in one numpy
pass: :meth:`ObservationExpert.act_rows`):

1. **Tracking.** Pure pursuit (:func:`~swarm_env.control.pursuit.pure_pursuit`, time gap ``time_gap``)
   in the body frame towards the slot vector led by the leader's velocity (``slot + lead * v_leader``).
2. **Candidates.** ``n_v`` forward speeds in ``[0, v_max]``, ``n_rev`` reversing speeds down to
   ``-reverse * v_max``, times ``n_w`` turn rates in ``[-omega_max, omega_max]``; each rolled out as
   the arc it drives, sampled every ``dt`` s up to ``horizon``.
3. **Time to contact** of every candidate with what the observation shows, each point moving at
   constant velocity: the neighbour rows (their relative velocities made absolute with the own
   twist) within the combined radius plus ``margin``, looked for ``robot_horizon`` s ahead; the human
   rows within the combined radius plus ``human_margin``; a robot leader (the leader block); the
   lidar hits as static points (``static_horizon``) within the radius plus the larger of ``margin`` and
   ``static_hold * v_max * dt_control`` (a command is held for a whole control step), with points
   filled every ``fill`` m between two adjacent rays that hit one surface (the ray gaps would let a
   trajectory through a wall), a hit whose neighbouring ray sees no continuation of its surface
   extended sideways by ``side_fill`` (the surface between two rays 22.5 degrees apart is unseen), and
   the hits on the rows' own bodies dropped (``drop_seen``: those move, and the rows say how). With
   ``band``, a point already within its contact distance is a contact only once the arc comes nearer
   than now (or touches): inside the margin, moving along or away is safe.
4. **The next step's worst case** (``wc_step``): a neighbour of the same limits may drive
   ``wc_step * v_max * dt_control`` straight at this robot in the coming step, so a candidate that
   ends the step nearer a neighbour than twice the radius plus that distance, and nearer than now,
   is unsafe. Two robots that both keep the rule cannot touch at the next step whatever the other
   commands; without it, two close followers dithered (forward and reverse at tiny speeds), their
   rows' relative velocities flipped sign every step, and the constant-velocity prediction missed
   the contact.
5. **Choice.** The cheapest safe candidate (time to contact ``>= t_safe``), the cost being
   ``hypot(w_speed (v - v_p) / v_max, (w - w_p) / omega_max)`` (distance to the pursuit twist),
   ``+ w_ttc (horizon - ttc) / horizon`` (a short time to contact costs), ``+ w_rev max(-v, 0) / v_max``.
   Blocked (the cheapest safe candidate stands while the pursuit moves) with ``move_first``: the
   cheapest safe candidate that moves (reversing too, with ``move_rev``). Nothing safe: of the latest
   contacts, the one keeping the most clearance over the next ``fb_clear`` s, then the cheapest (the
   cheapest alone drove a reversing follower forward into a human walking at it).

Deterministic (no random numbers), stateless between steps, continuous actions
``(v / v_max, omega / omega_max)`` as float32. Measured in docs/obs_expert.md.

The choice runs compiled (:func:`swarm_env_agents.obs_expert_kernel.choose`, all rows in one call) unless
:func:`swarm_env.compiled.use_compiled_kernels` turned the kernels off; the numpy code here (``_choose`` and what it
calls) is its reference, and the two give the same actions bit for bit (``tests/test_obs_expert.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from swarm_env.checks import finite_numbers, int_in_range
from swarm_env.compiled import compiled_kernels
from swarm_env.control.pursuit import pure_pursuit
from swarm_env.harness.policies import OBSERVATIONS, PolicyError, expert_factory
from swarm_env.sensing.layout import (
    COL_LEADER_POS,
    COL_LEADER_VEL,
    COL_SLOT,
    COL_TWIST,
    ENTITY,
    ENTITY_MASK,
    ENTITY_POS,
    ENTITY_VEL,
)

if TYPE_CHECKING:
    from swarm_env.env import SwarmEnv
    from swarm_env.state import WorldState

__all__ = ["Fan", "ObsExpertConfig", "ObservationExpert", "make_policy"]

#: Extra radius (m) around a row's body within which lidar hits are taken for that body (``drop_seen``).
_SEEN_PAD = 0.1
#: Rows of :meth:`ObservationExpert.act_rows` evaluated together: bounds the ``(rows, candidates, times,
#: points)`` temporaries (about 40 MB at the defaults).
_CHUNK = 16


@dataclass(frozen=True)
class ObsExpertConfig:
    """The options of :class:`ObservationExpert` (``obs_expert:KEY=VALUE`` on the command line); units m, s, rad.

    Tracking: ``time_gap`` (pure pursuit's ``T``, > 0), ``lead`` (s: the slot is led by the leader's velocity
    times this).
    Candidates: ``n_v`` forward speeds (>= 2), ``n_w`` turn rates (>= 2; odd keeps a straight one), ``reverse``
    (the fastest reverse speed as a share of ``v_max``, in ``[0, 1]``), ``n_rev`` reverse speeds (0: none),
    ``dt`` (s, the roll-out's sampling step), ``horizon`` (s).
    Contacts: ``margin`` (m, robots), ``human_margin`` (m), ``robot_horizon`` (s; ``None``: ``horizon``),
    ``static_horizon`` (s, lidar points), ``static_hold`` (the lidar points' margin is at least this share of
    one control step's travel at top speed), ``fill`` (m between filled lidar points), ``side_fill`` (m; 0: off),
    ``drop_seen``, ``band``, ``wc_step`` (the share of a neighbour's top speed assumed driven at this robot in the
    next step; 0: off).
    Choice: ``t_safe`` (s), ``w_ttc``, ``w_speed``, ``w_rev``, ``move_first``, ``move_rev``, ``fb_clear`` (s; 0:
    the cheapest of the latest contacts).
    What each does: the module docstring. Raises ``ValueError`` for values out of range.
    """

    time_gap: float = 0.5
    lead: float = 0.5
    n_v: int = 9
    n_w: int = 15
    reverse: float = 0.3
    n_rev: int = 2
    dt: float = 0.25
    horizon: float = 6.0
    margin: float = 0.05
    human_margin: float = 0.1
    robot_horizon: float | None = None
    static_horizon: float = 2.0
    fill: float = 0.3
    drop_seen: bool = True
    wc_step: float = 1.0
    t_safe: float = 1.5
    w_ttc: float = 4.0
    w_speed: float = 1.0
    w_rev: float = 1.0
    move_first: bool = True
    move_rev: bool = True
    band: bool = True
    static_hold: float = 0.6
    side_fill: float = 0.1
    fb_clear: float = 1.0

    def __post_init__(self) -> None:
        positive = ["time_gap", "dt", "horizon", "static_horizon", "fill", "t_safe"]
        if self.robot_horizon is not None:
            positive.append("robot_horizon")
        finite_numbers("obs_expert", {name: getattr(self, name) for name in positive}, positive=True)
        non_negative = ("lead", "margin", "human_margin", "wc_step", "w_ttc", "w_speed", "w_rev", "static_hold",
                        "side_fill", "fb_clear")
        finite_numbers("obs_expert", {name: getattr(self, name) for name in non_negative}, positive=False)
        if not 0.0 <= self.reverse <= 1.0:
            raise ValueError(f"obs_expert: reverse must be in [0, 1] (a share of max_speed), got {self.reverse!r}")
        int_in_range("obs_expert", {"n_v": self.n_v, "n_w": self.n_w}, 2, 64)
        int_in_range("obs_expert", {"n_rev": self.n_rev}, 0, 64)
        if self.horizon < self.dt:
            raise ValueError(f"obs_expert: horizon ({self.horizon!r} s) must be at least one roll-out step dt ({self.dt!r} s)")
        if self.horizon / self.dt > 200:
            raise ValueError(f"obs_expert: horizon / dt must be <= 200 roll-out samples, got {self.horizon / self.dt:g}")


class ObservationExpert:
    """Pure pursuit + sampled arcs checked against what the observation shows (the module docstring).

    A :class:`swarm_env.harness.policies.Policy` (``reset(env, seed)``, ``act(observations, state)``);
    ``state`` is not read. Options: every field of :class:`ObsExpertConfig`, as a keyword
    (``ObservationExpert(wc_step=0)``), a whole ``config``, or both (the keywords replace the config's fields);
    each is also an attribute (``expert.horizon``; ``robot_horizon`` resolved to a number).
    """

    def __init__(self, config: ObsExpertConfig | None = None, **options: Any) -> None:
        cfg = self.config = ObsExpertConfig(**options) if config is None else replace(config, **options)
        for f in fields(cfg):  # each option is an attribute too (expert.horizon)
            setattr(self, f.name, getattr(cfg, f.name))
        self.robot_horizon = cfg.horizon if cfg.robot_horizon is None else cfg.robot_horizon
        self._ready = False

    @classmethod
    def policy_parameters(cls) -> dict[str, Any]:
        """Every option ``obs_expert:KEY=VALUE`` accepts, with its default (:class:`ObsExpertConfig`)."""
        return {f.name: f.default for f in fields(ObsExpertConfig)}

    # ------------------------------------------------------------------ the scenario's constants

    def reset(self, env: SwarmEnv, seed: int | None) -> None:
        """Read the scenario's constants (limits, radii, lidar, leader kind, control step) and build the
        candidates' arcs. ``seed`` is ignored (the expert draws no random numbers)."""
        if env.action_type != "continuous":
            raise PolicyError("policy 'obs_expert' drives the continuous action space only")
        scn = env.scenario
        robots = scn.robots
        self.v_max, self.w_max, self.radius = float(robots.max_speed), float(robots.max_turn_rate), float(robots.radius)
        self.leader_robot = scn.leader.kind == "robot"
        self.leader_radius = float(scn.leader.radius)
        self.human_radius = max((float(h.radius) for h in scn.humans), default=0.0)  # the largest: conservative
        self.ctrl_dt = float(scn.world.dt)
        layout = env.obs_layout
        self.obs_size = int(env.observation_space(env.possible_agents[0]).shape[0])
        self.neighbours, self.humans, self.lidar = layout["neighbors"], layout["humans"], layout["lidar"]
        sensors = scn.sensors
        self.lidar_range = float(sensors.lidar_range)
        n_rays = int(sensors.lidar_rays)
        angles = 2.0 * np.pi * np.arange(n_rays) / n_rays
        self.ray_angle = angles
        self.ray_dir = np.stack([np.cos(angles), np.sin(angles)], axis=1)  # (R, 2), body frame
        # The widest gap between two adjacent rays' hits, and so the most points filled into one gap.
        widest = 2.0 * self.lidar_range * math.sin(math.pi / max(n_rays, 2))
        self.fill_max = max(1, math.ceil(widest / self.fill) - 1)
        speeds = np.linspace(0.0, self.v_max, self.n_v)
        if self.reverse > 0 and self.n_rev > 0:
            speeds = np.concatenate([np.linspace(-self.reverse * self.v_max, 0.0, self.n_rev + 1)[:-1], speeds])
        turns = np.linspace(-self.w_max, self.w_max, self.n_w)
        v, w = (g.ravel() for g in np.meshgrid(speeds, turns, indexing="ij"))
        self.cand = np.stack([v, w], axis=1)  # (C, 2)
        self.top_speed = float(np.abs(v).max())
        self.times = np.arange(1, int(round(self.horizon / self.dt)) + 1) * self.dt  # (T,)
        self.arcs = _arcs(v, w, self.times)  # (C, T, 2)
        self.step_end = _arcs(v, w, np.array([self.ctrl_dt]))[:, 0]  # (C, 2): where one control step ends
        self._bundles = self._kernel_bundles()
        self._ready = True

    # ------------------------------------------------------------------ acting

    def act(self, observations: dict[str, np.ndarray], state: WorldState | None = None) -> dict[str, Any]:
        """One action per observed agent, from its own observation only (``state`` is not read)."""
        if not self._ready:
            raise PolicyError("ObservationExpert.act before reset(env, seed)")
        agents = list(observations)
        if not agents:
            return {}
        actions = self.act_rows(np.stack([np.asarray(observations[a], dtype=np.float64) for a in agents]))
        return dict(zip(agents, actions))

    def act_rows(self, obs: np.ndarray) -> np.ndarray:
        """The actions ``(M, 2)`` float32 of ``M`` observation rows ``(M, obs_size)`` of this scenario (any
        followers of any worlds built from it: the batched engine's ``(worlds * followers, obs_size)``)."""
        return self._twists(self.fan(obs).pick)

    def fan(self, obs: np.ndarray) -> Fan:
        """Stages 1-5 of the module docstring for ``M`` observation rows ``(M, obs_size)``: every candidate's time to
        contact (the avoidance sensor a learner can be given: :mod:`swarm_env_baselines.fan_dagger`), the pure-pursuit
        twists and the candidate this expert picks. The candidates' twists are :attr:`candidates`."""
        if not self._ready:
            raise PolicyError("ObservationExpert.fan before reset(env, seed)")
        obs = np.asarray(obs, dtype=np.float64)
        if obs.ndim != 2 or obs.shape[1] != self.obs_size:
            raise ValueError(f"the observation rows must have shape (M, {self.obs_size}), got {obs.shape}")
        pursuit = np.empty((len(obs), 2))
        for start in range(0, len(obs), _CHUNK):  # in the reference's chunks: the same calls on the same data
            pursuit[start:start + _CHUNK] = self._pursuit(obs[start:start + _CHUNK])
        ttc = np.empty((len(obs), len(self.cand)))
        if compiled_kernels():  # the same bits, see swarm_env_agents.obs_expert_kernel
            from swarm_env_agents.obs_expert_kernel import choose

            pick = choose(np.ascontiguousarray(obs), pursuit, *self._bundles, ttc)
            return Fan(ttc, pursuit, pick)
        pick = np.empty(len(obs), dtype=np.int64)
        for start in range(0, len(obs), _CHUNK):
            rows = slice(start, start + _CHUNK)
            pick[rows], ttc[rows] = self._choose(obs[rows], pursuit[rows])
        return Fan(ttc, pursuit, pick)

    @property
    def candidates(self) -> np.ndarray:
        """The candidate twists as actions ``(C, 2)`` (``v / v_max``, ``omega / omega_max``), in :meth:`fan`'s order."""
        return self.cand / np.array([self.v_max, self.w_max])

    def _pursuit(self, obs: np.ndarray) -> np.ndarray:
        """The pure-pursuit twists ``(M, 2)`` of rows ``obs``: towards the slot led by the leader's velocity."""
        target = obs[:, COL_SLOT:COL_SLOT + 2] + obs[:, COL_LEADER_VEL:COL_LEADER_VEL + 2] * self.lead
        return pure_pursuit(np.zeros((len(obs), 3)), target, self.v_max, self.w_max, self.time_gap)

    def _twists(self, pick: np.ndarray) -> np.ndarray:
        """The candidates ``pick`` ``(M,)`` as actions: twists normalised, ``(M, 2)`` float32."""
        twist = self.cand[pick]
        return (twist / np.array([self.v_max, self.w_max])).astype(np.float32)

    def _kernel_bundles(self) -> tuple[tuple, tuple, tuple, tuple]:
        """The constants of :func:`swarm_env_agents.obs_expert_kernel.choose` as plain tuples of the items of its
        ``Geometry``, ``Bodies``, ``Lidar`` and ``Choice`` (the reference's own values, computed as it does)."""
        r, n_rays = self.radius, len(self.ray_dir)
        others = (r, self.human_radius, self.leader_radius)
        hard = [r + other for other in others]
        margins = (self.margin, self.human_margin, self.margin)
        box = np.concatenate([np.minimum.accumulate(self.arcs[..., :1], axis=1),
                              np.maximum.accumulate(self.arcs[..., :1], axis=1),
                              np.minimum.accumulate(self.arcs[..., 1:], axis=1),
                              np.maximum.accumulate(self.arcs[..., 1:], axis=1)], axis=2)  # (C, T, 4)
        geometry = tuple(np.ascontiguousarray(a, dtype=np.float64) for a in
                         (self.cand, self.arcs[..., 0], self.arcs[..., 1], box, self.times, self.step_end, self.ray_dir, self.ray_angle))
        bodies = (float(self.v_max), self.neighbours.start, (self.neighbours.stop - self.neighbours.start) // ENTITY,
                  self.humans.start, (self.humans.stop - self.humans.start) // ENTITY, bool(self.leader_robot),
                  np.array(hard, dtype=np.float64), np.array([h + m for h, m in zip(hard, margins)], dtype=np.float64),
                  np.array([other + _SEEN_PAD for other in others], dtype=np.float64),
                  np.array([self.robot_horizon, self.horizon, self.robot_horizon], dtype=np.float64))
        lidar = (self.lidar.start, float(self.lidar_range), float(self.lidar_range * 0.999), float(self.fill),
                 int(self.fill_max), float(self.side_fill), float(2.0 * np.pi / max(n_rays, 1)), bool(self.drop_seen),
                 float(r + max(self.margin, self.static_hold * self.v_max * self.ctrl_dt)), float(r),
                 float(self.static_horizon))
        n_clear = max(1, int(np.searchsorted(self.times, self.fb_clear + 1e-9, side="right")))
        choice = (bool(self.band), float(self.top_speed), bool(self.wc_step > 0),
                  float(2.0 * r + self.wc_step * self.v_max * self.ctrl_dt), float(self.v_max), float(self.w_max),
                  float(self.w_speed), float(self.w_ttc), float(self.w_rev), float(self.horizon), float(self.t_safe),
                  bool(self.move_first), bool(self.move_rev), bool(self.fb_clear > 0), n_clear)
        return geometry, bodies, lidar, choice

    def _choose(self, obs: np.ndarray, pursuit: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`fan` of at most ``_CHUNK`` rows given their pursuit twists: ``(pick (M,), ttc (M, C))``, the numpy
        reference of :func:`swarm_env_agents.obs_expert_kernel.choose`."""
        own_v = obs[:, COL_TWIST] * self.v_max
        leader_vel = obs[:, COL_LEADER_VEL:COL_LEADER_VEL + 2]
        movers, seen = self._movers(obs, own_v, leader_vel)
        lidar = self._lidar_points(obs, movers.pos, seen)
        ttc = np.minimum(self._contact(movers), self._contact(lidar))
        if self.wc_step > 0:
            ttc = np.where(self._next_step_unsafe(obs), 0.0, ttc)
        return self._select(ttc, pursuit, movers, lidar), ttc

    def _contact(self, pts: _Points) -> np.ndarray:
        """Each candidate's time to contact ``(M, C)`` with ``pts``; with ``band``, a point already within its
        contact distance counts only once the arc comes nearer than now (or within ``pts.hard``)."""
        reach = pts.reach
        if self.band:
            now = np.hypot(pts.pos[..., 0], pts.pos[..., 1])
            reach = np.where(reach > 0, np.maximum(np.minimum(reach, now - 1e-3), pts.hard), reach)
        return _first_contact(self.arcs, self.times, self.top_speed, pts.pos, pts.vel, reach, pts.horizon)

    def _rows(self, obs: np.ndarray, block: slice) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The entity rows of a block: positions ``(M, K, 2)``, relative velocities ``(M, K, 2)``, mask ``(M, K)``."""
        rows = obs[:, block].reshape(len(obs), -1, ENTITY)
        return (rows[..., ENTITY_POS:ENTITY_POS + 2], rows[..., ENTITY_VEL:ENTITY_VEL + 2],
                rows[..., ENTITY_MASK] > 0.5)

    def _movers(self, obs: np.ndarray, own_v: np.ndarray, leader_vel: np.ndarray) -> tuple[_Points, np.ndarray]:
        """The moving bodies every row sees (neighbour rows, human rows, a robot leader), padded to one count, their
        velocities made absolute in the body frame; and the radii ``(M, P)`` within which a lidar hit belongs to
        one of them (``drop_seen``; negative: padding)."""
        own = np.stack([own_v, np.zeros_like(own_v)], axis=1)[:, None, :]
        parts = []
        for block, other, margin, horizon in ((self.neighbours, self.radius, self.margin, self.robot_horizon),
                                              (self.humans, self.human_radius, self.human_margin, self.horizon)):
            pos, rel, mask = self._rows(obs, block)
            parts.append((pos, rel + own, mask, self.radius + other, margin, horizon, other + _SEEN_PAD))
        if self.leader_robot:  # the leader block: position and absolute velocity in this body frame
            parts.append((obs[:, None, COL_LEADER_POS:COL_LEADER_POS + 2], leader_vel[:, None, :],
                          np.ones((len(obs), 1), dtype=bool), self.radius + self.leader_radius, self.margin,
                          self.robot_horizon, self.leader_radius + _SEEN_PAD))
        mask = np.concatenate([p[2] for p in parts], axis=1)

        def column(k: int) -> np.ndarray:  # a per-kind constant, one value per padded row
            return np.concatenate([np.full(p[2].shape, float(p[k])) for p in parts], axis=1)

        hard = column(3)
        movers = _Points(np.concatenate([p[0] for p in parts], axis=1), np.concatenate([p[1] for p in parts], axis=1),
                         np.where(mask, hard + column(4), -1.0), hard, column(5))
        return movers, np.where(mask, column(6), -1.0)

    def _lidar_points(self, obs: np.ndarray, movers: np.ndarray, seen: np.ndarray) -> _Points:
        """The lidar's hits as static points (body frame; contact distance the radius plus ``margin`` or
        ``static_hold * v_max * dt_control``, whichever is larger): each ray's hit; up to ``fill_max`` points filled
        between two adjacent rays that hit one surface (their ranges differ by less than half their gap plus
        0.3 m, and the gap is wider than ``fill``); with ``side_fill``, a hit whose neighbouring ray sees no
        continuation of its surface extended sideways at its range by ``side_fill / 2`` and ``side_fill`` m
        (at most 3/4 of the way to that ray). Hits within a moving body's radius (plus ``_SEEN_PAD``) are
        dropped with ``drop_seen``."""
        m = len(obs)
        ranges = obs[:, self.lidar] * self.lidar_range  # (M, R)
        hit = ranges < self.lidar_range * 0.999
        p0 = ranges[..., None] * self.ray_dir  # (M, R, 2)
        pieces, valid = [p0], [hit]
        ray_gap = 2.0 * np.pi / len(self.ray_dir)
        for side in (1, -1):  # the next ray (counter-clockwise), then the previous one
            p1 = np.roll(p0, -side, axis=1)
            gap = np.hypot(*(p1 - p0).transpose(2, 0, 1))
            same = hit & np.roll(hit, -side, axis=1) & (
                np.abs(ranges - np.roll(ranges, -side, axis=1)) < 0.5 * np.maximum(gap, 1e-9) + 0.3)
            if side == 1:  # fill the gap to the next ray (each gap once)
                k = np.ceil(gap / self.fill)  # the gap in k pieces: k - 1 points inside
                j = np.arange(1, self.fill_max + 1)
                frac = j / np.maximum(k, 1.0)[..., None]  # (M, R, F)
                pieces.append((p0[:, :, None, :] + frac[..., None] * (p1 - p0)[:, :, None, :]).reshape(m, -1, 2))
                valid.append((same[..., None] & (gap > self.fill)[..., None] & (j < k[..., None])).reshape(m, -1))
            if self.side_fill > 0:
                edge = hit & ~same
                for share in (0.5, 1.0):
                    phi = np.minimum(share * self.side_fill / np.maximum(ranges, 1e-6), 0.75 * ray_gap)
                    angle = self.ray_angle[None, :] + side * phi
                    pieces.append(np.stack([ranges * np.cos(angle), ranges * np.sin(angle)], axis=2))
                    valid.append(edge)
        pts = np.concatenate(pieces, axis=1)
        ok = np.concatenate(valid, axis=1)
        if self.drop_seen and movers.shape[1]:
            d2 = ((pts[:, :, None, :] - movers[:, None, :, :]) ** 2).sum(axis=3)  # (M, L, P)
            ok &= ~(d2 < np.where(seen > 0, seen * seen, -1.0)[:, None, :]).any(axis=2)
        reach = self.radius + max(self.margin, self.static_hold * self.v_max * self.ctrl_dt)
        return _Points(pts, np.zeros_like(pts), np.where(ok, reach, -1.0), np.full(ok.shape, self.radius),
                       np.full(ok.shape, self.static_horizon))

    def _next_step_unsafe(self, obs: np.ndarray) -> np.ndarray:
        """``(M, C)``: candidates that end the next control step nearer a neighbour row than twice the radius plus
        ``wc_step * v_max * dt_control``, and nearer than now (``wc_step`` in the module docstring)."""
        pos, _, mask = self._rows(obs, self.neighbours)
        now = np.hypot(pos[..., 0], pos[..., 1])  # (M, K)
        then = np.hypot(self.step_end[None, :, None, 0] - pos[:, None, :, 0],
                        self.step_end[None, :, None, 1] - pos[:, None, :, 1])  # (M, C, K)
        limit = np.minimum(now - 1e-6, 2.0 * self.radius + self.wc_step * self.v_max * self.ctrl_dt)
        return ((then < limit[:, None, :]) & mask[:, None, :]).any(axis=2)

    def _select(self, ttc: np.ndarray, pursuit: np.ndarray, movers: _Points, lidar: _Points) -> np.ndarray:
        """The chosen candidates ``(M,)`` from each candidate's time to contact ``(M, C)``."""
        v, w = self.cand[:, 0], self.cand[:, 1]
        cost = np.hypot(self.w_speed * (v[None] - pursuit[:, :1]) / self.v_max, (w[None] - pursuit[:, 1:]) / self.w_max)
        cost = cost + self.w_ttc * (self.horizon - np.minimum(ttc, self.horizon)) / self.horizon
        cost = cost + self.w_rev * np.maximum(-v, 0.0)[None] / self.v_max
        safe = ttc >= self.t_safe
        any_safe = safe.any(axis=1)
        pick = np.argmin(np.where(safe, cost, np.inf), axis=1)
        moving = safe & ((np.abs(v) if self.move_rev else v)[None] > 1e-9)
        blocked = (self.move_first & (v[pick] <= 1e-9) & (pursuit[:, 0] > 1e-3) & moving.any(axis=1))
        pick = np.where(blocked, np.argmin(np.where(moving, cost, np.inf), axis=1), pick)
        latest = ttc >= ttc.max(axis=1, keepdims=True)
        pick = np.where(any_safe, pick, np.argmin(np.where(latest, cost, np.inf), axis=1))
        if self.fb_clear > 0:
            for i in np.flatnonzero(~any_safe):
                pick[i] = self._clearest(i, latest[i], cost[i], movers, lidar, pick[i])
        return pick

    def _clearest(self, i: int, latest: np.ndarray, cost: np.ndarray, movers: _Points, lidar: _Points,
                  cheapest: int) -> int:
        """Row ``i`` with nothing safe (``fb_clear``): of the latest-contact candidates, those keeping the most
        clearance (distance less the contact distance, worst over the row's points and the first ``fb_clear`` s;
        within 1 mm), then the cheapest. Without it the cheapest of them drove a reversing follower forward into
        a human walking at it (every candidate's contact 0.25 s away)."""
        ties = np.flatnonzero(latest)
        pos = np.concatenate([movers.pos[i], lidar.pos[i]])
        vel = np.concatenate([movers.vel[i], lidar.vel[i]])
        reach = np.concatenate([movers.reach[i], lidar.reach[i]])
        real = reach > 0
        if len(ties) < 2 or not real.any():
            return cheapest
        times = self.times[:max(1, int(np.searchsorted(self.times, self.fb_clear + 1e-9, side="right")))]
        other = pos[real][None] + times[:, None, None] * vel[real][None]  # (Tc, E, 2)
        gap = self.arcs[ties, :len(times), None, :] - other[None]  # (ties, Tc, E, 2)
        clear = (np.hypot(gap[..., 0], gap[..., 1]) - reach[real]).min(axis=(1, 2))
        top = ties[clear >= clear.max() - 1e-3]
        return int(top[np.argmin(cost[top])])


class Fan(NamedTuple):
    """:meth:`ObservationExpert.fan` of ``M`` rows over the ``C`` candidates."""

    #: Each candidate's time to contact (s), ``(M, C)``; ``horizon`` or more: none within the horizon; ``0``: unsafe
    #: at the next step (``wc_step``).
    ttc: np.ndarray
    #: The pure-pursuit twists ``(M, 2)`` (m/s, rad/s) the candidates are scored against.
    pursuit: np.ndarray
    #: The candidate this expert picks per row, ``(M,)`` int64.
    pick: np.ndarray


class _Points(NamedTuple):
    """Points a row's candidates are checked against, padded to one count ``P`` for all rows: positions and
    velocities in the body frame ``(M, P, 2)``, contact distances ``(M, P)`` (negative: padding), the distances
    that are a contact whatever the ``band`` rule (the bodies' radii, no margin) and horizons (s), ``(M, P)``."""

    pos: np.ndarray
    vel: np.ndarray
    reach: np.ndarray
    hard: np.ndarray
    horizon: np.ndarray


def _arcs(v: np.ndarray, w: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Body-frame positions ``(C, T, 2)`` of twists ``(v, w)`` (``(C,)`` each) held from the origin, at ``times``."""
    straight = np.abs(w) < 1e-9
    w_safe = np.where(straight, 1.0, w)[:, None]
    x = np.where(straight[:, None], v[:, None] * times, v[:, None] / w_safe * np.sin(w[:, None] * times))
    y = np.where(straight[:, None], 0.0, v[:, None] / w_safe * (1.0 - np.cos(w[:, None] * times)))
    return np.stack([x, y], axis=-1)


def _first_contact(arcs: np.ndarray, times: np.ndarray, speed: float, pts: np.ndarray, vel: np.ndarray,
                   reach: np.ndarray, horizon: np.ndarray) -> np.ndarray:
    """The first sampled time ``(M, C)`` at which each candidate's arc ``arcs (C, T, 2)`` (of speeds up to ``speed``
    in absolute value) comes within ``reach``
    ``(M, P)`` of a point moving from ``pts`` ``(M, P, 2)`` at ``vel``, counting only contacts no later than the
    point's ``horizon`` ``(M, P)``; ``inf`` for none. A negative ``reach`` is padding (never a contact).

    Only the points some arc can reach are tested (most lidar hits are far): an arc runs at most ``|v| t`` from
    the origin and ``|v| <= speed``, so a point whose distance
    less the two speeds times its horizon is still beyond ``reach`` cannot be met. They are gathered to the
    front, and the arcs cut at the latest horizon among them."""
    m, c = len(pts), len(arcs)
    cut = np.minimum(horizon, times[-1] if len(times) else 0.0)
    near = (reach > 0) & (np.hypot(pts[..., 0], pts[..., 1]) - (np.hypot(vel[..., 0], vel[..., 1]) + speed) * cut
                          < reach)
    width = int(near.sum(axis=1).max()) if m else 0
    if width == 0:
        return np.full((m, c), np.inf)
    order = np.argsort(~near, axis=1, kind="stable")[:, :width]  # the reachable points first, in order
    pts, vel = (np.take_along_axis(a, order[..., None], axis=1) for a in (pts, vel))
    horizon = np.take_along_axis(horizon, order, axis=1)
    reach = np.where(np.take_along_axis(near, order, axis=1), np.take_along_axis(reach, order, axis=1), -1.0)
    n_t = int(np.searchsorted(times, float(np.where(reach > 0, horizon, 0.0).max()) + 1e-9, side="right"))
    times, arcs = times[:n_t], arcs[:, :n_t]
    moved = pts[:, None, :, :] + times[None, :, None, None] * vel[:, None, :, :]  # (M, T, P, 2)
    dx = arcs[None, :, :, None, 0] - moved[:, None, :, :, 0]  # (M, C, T, P)
    dy = arcs[None, :, :, None, 1] - moved[:, None, :, :, 1]
    within = (times[None, :, None] <= horizon[:, None, :])  # (M, T, P)
    r2 = np.where(reach > 0, reach * reach, -1.0)
    hit = ((dx * dx + dy * dy < r2[:, None, None, :]) & within[:, None]).any(axis=3)  # (M, C, T)
    return np.where(hit.any(axis=2), times[np.argmax(hit, axis=2)], np.inf)


make_policy = expert_factory("obs_expert", ObservationExpert, acts_on=OBSERVATIONS)
