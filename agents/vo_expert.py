"""The decentralized pure-pursuit + velocity-obstacle expert of paper 003.

Each follower runs the block diagram of paper 003's Fig. 2 on its own, from the
privileged :class:`~swarm_env.state.WorldState`:

1. **Formation target** (Eqs. 5-6): its slot target ``state.slot_targets[i]``,
   computed by the env from the leader's pose and the active formation (and
   moved out of obstacles).
2. **Pure pursuit** (Eqs. 7-11, 3-4) towards that target, with the slot's own
   velocity as *feed-forward*: the robot pursues the point where the slot will
   be one time gap ``T`` from now, ``p* = slot + v_slot T``. Pure pursuit's
   speed is ``min(|p* - p| / T, v_max) = min(|v_slot + e / T|, v_max)`` (``e`` the
   position error), so a robot sitting on a slot that moves at ``v_slot`` keeps
   moving at ``v_slot``: a moving slot is tracked without the steady-state lag
   of the plain law (which needs an error of ``|v_slot| T`` to move at
   ``|v_slot|``, i.e. 0.25 m behind a slot moving at 0.5 m/s with the default
   ``T = 0.5`` s). ``v_slot`` is the
   rigid-body velocity of the leader's frame at the slot, ``v_L + omega_L x (slot
   - p_L)``. One deviation from Eq. 4: a target behind the robot is turned to
   in place at the full turn rate (``full_turn``). *Preview* (``preview``, 0.5 s
   by default; ``0`` for none): the led point is moved out of obstacles
   by the env's own slot rule (:meth:`~swarm_env.geometry.static_map.StaticMap.project_free`
   with clearance ``radius + SLOT_MARGIN``), and the robot steers along the arc
   towards the slot ``preview`` s ahead (also moved out of obstacles) at the
   speed of the law above, so it starts bending around an obstacle that the
   slot will skirt before the velocity obstacle has to stop it. *Look-ahead cap*
   (``lookahead``, 0.875 s by default; ``0`` for none): both points are pulled
   towards the robot to at most ``max_speed * lookahead`` from it, so a robot far
   from its slot (after a formation switch) turns towards it before it drives
   instead of leaving on a wide arc (pure pursuit's curvature is ``2 sin(alpha) /
   l``: small for a far target).
3. **Velocity obstacle** (Eq. 12): :func:`swarm_env.control.vo.vo_select_batch`
   samples candidate twists ``(v, omega)`` within the robot's limits, rejects
   every candidate whose predicted motion enters the velocity obstacle of
   another follower (reciprocal: they all run this rule), the robot leader and
   the humans (plain VO: they do not yield), the static circles, polygons (exact
   Minkowski sums, not bounding circles) and walls within the time horizon (its
   own for each: 2.5 s for the robots, 3.5 s for the humans, 1 s for the static
   map by default), and
   returns the safe candidate with the least penalty (distance to the
   pure-pursuit twist, consistency with the target direction). The env's robot
   leader uses the same functions (one implementation).

A follower whose cheapest safe candidate would be to stand still while its
slot moves on (blocked) takes the cheapest safe candidate that moves instead,
a detour, and turns in place only when none is safe (``move_first``); another
follower closer than 0.2 m beyond contact range is avoided fully rather than
reciprocally (``recip_gap``). See :data:`EXPERT_AVOIDANCE`.

When no candidate is safe the robot takes the candidate that postpones the
predicted contact longest (slower first); if that means standing still while
something comes at it, it turns in place towards the most open direction.
Each such step is counted as an *infeasible event* in :meth:`VOExpert.stats`. A follower in that state
while a walker is coming (walkers do not give way) first searches again with reversing candidates, its
robot neighbours looked for only ``reverse_horizon`` s ahead, and backs off if that postpones the contact
(``reverse``; counted as ``reverse_steps``).
A follower that has come to rest inside another robot's safety margin may
still turn in place (``allow_still_overlap`` of :func:`vo_select_batch`), so
two followers that met face to face turn away instead of standing for good.

All followers are computed in one vectorised pass (one numpy evaluation of
every candidate of every follower against its discs and the static map), but
each follower's answer depends only on its own view of the world: the policy is
decentralized; batching is an implementation detail.

Registered as ``vo`` in the ``swarm_env.policies`` entry-point group
(``swarm-env run --policy vo``); ``vo:KEY=VALUE,KEY=VALUE`` sets constructor
parameters from the command line (e.g. ``vo:horizon=4,margin=0.1``).
"""

from __future__ import annotations

import dataclasses
import inspect
import math
import time
from typing import TYPE_CHECKING, Any

import numpy as np

from swarm_env.compiled import compiled_search
from swarm_env.control.pursuit import pure_pursuit, slot_velocities
from swarm_env.control.safety import AvoidanceParams, back_off, period_margin, reversing_params, safe_follower_twists
from swarm_env.control.vo import turning_in_place
from swarm_env.geometry.formation import SLOT_MARGIN
from swarm_env.harness.policies import expert_factory
from swarm_env.state import WorldState

if TYPE_CHECKING:
    from swarm_env.env import SwarmEnv

__all__ = ["EXPERT_AVOIDANCE", "LEGACY_SPEC", "VOExpert", "make_policy"]

#: Where the expert's avoidance defaults differ from :class:`~swarm_env.control.safety.AvoidanceParams`' (which the
#: safety layer keeps; see :func:`swarm_env.control.vo.vo_select` for each):
#:
#: * ``move_first``: a blocked follower drives off on a safe detour before it turns in place;
#: * ``recip_gap=0.2``: another follower nearer than the combined radius plus 0.2 m is avoided plainly
#:   (``move_first`` alone brought two followers of paper_cbs_switch, dt = 0.5 s, into contact);
#: * ``horizon=2.5``, ``horizon_static=1.0``, ``tau=0.7``: shorter horizons (ORCA's are 2 s and 1 s), so a
#:   follower keeps its speed until an obstacle is near and then bends round it;
#: * ``w_speed=3``: a change of speed costs three times a change of turn rate, so the follower bends round
#:   rather than slowing down (a slow-down only pushes the contact past the horizon);
#: * ``escape_commit=1``: a follower turning in place to escape keeps its direction (no left-right dithering);
#: * ``human_horizon=3.5``: the humans, who do not give way, are looked for 3.5 s ahead (the robots 2.5 s), so a
#:   follower steps aside before a human walking at it has boxed it in against a neighbour or an obstacle
#:   (fewer contacts, the same formation error: docs/vo_defaults.md).
#:
#: With the tracking defaults ``preview=0.5, lookahead=0.875``. Measured against the earlier expert and
#: ORCA in docs/vo_expert.md ("Against ORCA"). ``LEGACY_SPEC`` is the earlier expert.
EXPERT_AVOIDANCE: dict[str, Any] = {"move_first": True, "recip_gap": 0.2, "horizon": 2.5, "horizon_static": 1.0,
                                    "tau": 0.7, "w_speed": 3.0, "escape_commit": 1.0, "human_horizon": 3.5}

#: The expert before issue 12 (AvoidanceParams' defaults, no preview, no look-ahead cap, no backing off): the one
#: the shipped ``residual_vo`` runs were trained with, which their files name as their residual's expert.
LEGACY_SPEC = ("vo:move_first=false,recip_gap=0,horizon=3,horizon_static=3,tau=1,w_speed=1,escape_commit=0,"
               "preview=0,lookahead=0,human_horizon=0,reverse=0,period_margin=0,escape_drive=false")


def _bearing_error(pose: np.ndarray, d: np.ndarray) -> np.ndarray:
    """``(N,)`` angle (rad, in ``[-pi, pi)``) from each robot's heading ``pose[:, 2]`` to the direction ``d``
    ``(N, 2)`` of its target: positive to the left."""
    alpha = np.arctan2(d[:, 1], d[:, 0]) - pose[:, 2]
    return (alpha + math.pi) % (2.0 * math.pi) - math.pi


class VOExpert:
    """Pure pursuit to the formation slot + sampled velocity obstacles, per follower.

    A :class:`swarm_env.harness.policies.Policy`: ``reset(env, seed)``, ``act(observations,
    state) -> {agent: action}`` (continuous actions ``(v / max_speed, omega /
    max_turn_rate)`` in ``[-1, 1]``, float32), ``stats()``. Deterministic: it
    draws no random numbers (``seed`` is ignored), so the same state gives the
    same actions.

    Keyword-only parameters (units m, s, rad):

    Tracking (pure pursuit, paper 003 Eqs. 7-11):
        time_gap: ``T`` of Eq. 9's ``v = min(l / T, v_max)`` (s, > 0). Smaller is
            stiffer.
        feed_forward: pursue ``slot + v_slot T`` instead of the slot itself (see
            the module docstring). ``False`` gives the plain law of the paper.
        arrive_radius: below this distance to a slot that does not move the
            robot stops instead of creeping (m).
        full_turn: when the (led) target is behind the robot (more than 90
            degrees off its heading), turn in place at the full turn rate.
            Pure pursuit's own rule turns at ``2 v / l`` there (continuous with
            Eq. 4 at 90 degrees), which is slow for a far target and let a
            follower whose slot lay beyond an obstacle alternate for minutes
            between that slow turn and the escape turn (paper_cbs_switch).
        preview: look-ahead (s) of the steering (default 0.5), ``0`` for none. With
            ``preview > 0`` (and ``feed_forward``) the pursued point ``slot + v_slot T``
            is moved out of obstacles as the env moves the slots, and the twist
            keeps pure pursuit's speed but takes the curvature of the arc to
            ``slot + v_slot preview`` (moved out of obstacles too), slowing down
            where that curvature needs more than the turn-rate limit.
        lookahead: cap (s) on the distance of the pursued points (default 0.875): each is
            pulled towards the robot to at most ``max_speed * lookahead`` from it. ``0``
            for none (Eq. 9's distance ``l`` to the slot itself).

        ``preview``, ``lookahead`` and ``w_speed`` each lower the formation error on some fixed
        scenario, and leaving out any of them, or ``escape_commit``, brings contacts on
        paper_cbs_switch (measurements: docs/vo_defaults.md; the comparison with
        the earlier expert and ORCA: docs/vo_expert.md, "Against ORCA").

    Boxed in (walkers do not give way; the other followers do):
        reverse: a fraction in ``[0, 1]`` (default ``0.5``; ``0`` for none). A follower for which no
            candidate is safe (every forward or standing twist meets something within the horizon)
            while a human could reach it within the horizon searches again with reversing candidates
            down to ``-reverse * max_speed``, and takes that search's twist if it is safe or, if nothing
            is, if it postpones the contact longer than the forward answer. Without it such a follower
            turns in place (the escape rule) and a walker who keeps coming walks into it (measured on
            the ``crowd`` and ``crowd_reactive`` families: docs/vo_defaults.md, "``reverse``"). Worlds
            without humans are unchanged bit for bit.
        reverse_horizon: the other robots' horizon (s) in that second search (default ``1.0``; ``0``:
            ``horizon``). The followers give way to each other, so while backing off from a walker
            only a robot contact within this horizon counts; the humans keep their own horizon.

    Long control periods:
        period_margin: the most (m, default ``0.1``; ``0`` for none) the other followers' discs grow by in
            the search when the scenario's control period ``dt`` is longer than 0.1 s: by ``max_speed *
            (dt - 0.1)`` (:func:`swarm_env.control.safety.period_margin`). The search trusts a neighbour's
            velocity for the whole period, and a neighbour with no safe twist stops and turns in place; with
            ``dt = 0.2`` s, followers crossing to new slots after formation switches touched (9 of 24 maps with
            switches every 12-14 s) where the fixed ``margin`` had covered it at 0.1 s. Scenarios with
            ``dt <= 0.1`` s (every generated family, the corridor, paper 003's) are unchanged bit for bit.

    Escapes:
        escape_drive: (default ``True``) a follower turning in place one way (the search's escape turn towards
            open space) whose target is behind it drives on straight, at the pursuit's speed, instead of the
            full turn back the other way (``full_turn``); the search tests that like any preferred twist. Without
            it the full turn back was always "safe" (it stands), the next escape turned the robot away again, and
            it stood turning left and right for the rest of the episode (training worlds ``large_16`` 14,
            ``crowd_reactive`` 33; docs/vo_defaults.md, "``escape_drive``").

    Avoidance (velocity obstacles, Eq. 12): any field of
    :class:`swarm_env.control.safety.AvoidanceParams` (the search's
    :class:`~swarm_env.control.vo.VOParams` plus ``human_margin``, ``human_horizon`` and ``reciprocal``), e.g.
    ``horizon``, ``margin``, ``n_v``/``n_w``, ``tau``, ``w_pref``/``w_heading``/``side_bias``,
    ``escape``, ``w_current``, ``cost``, ``recip_gap``, ``move_first``, ``static_reach``; they are kept in :attr:`avoidance`
    (and read through: ``expert.horizon``). The expert's defaults are the shared ones except
    :data:`EXPERT_AVOIDANCE`. :meth:`policy_parameters` lists everything ``vo:KEY=VALUE`` accepts.

    Raises:
        ValueError: for invalid parameters; from :meth:`reset` when the env uses
            ``action_type="discrete"`` — the motion primitives drive at full speed
            and cannot express the slow-downs and turns in place the VO search
            relies on, so the expert refuses rather than silently degrading.
    """

    def __init__(
        self,
        *,
        time_gap: float = 0.5,
        feed_forward: bool = True,
        arrive_radius: float = 0.05,
        full_turn: bool = True,
        preview: float = 0.5,
        lookahead: float = 0.875,
        reverse: float = 0.5,
        reverse_horizon: float = 1.0,
        period_margin: float = 0.1,
        escape_drive: bool = True,
        **avoidance: Any,
    ) -> None:
        if not (isinstance(time_gap, (int, float)) and math.isfinite(time_gap) and time_gap > 0):
            raise ValueError(f"time_gap must be a finite number > 0, got {time_gap!r}")
        if not (isinstance(arrive_radius, (int, float)) and math.isfinite(arrive_radius) and arrive_radius >= 0):
            raise ValueError(f"arrive_radius must be a finite number >= 0, got {arrive_radius!r}")
        if not (isinstance(preview, (int, float)) and math.isfinite(preview) and preview >= 0):
            raise ValueError(f"preview must be a finite number >= 0, got {preview!r}")
        if not (isinstance(lookahead, (int, float)) and math.isfinite(lookahead) and lookahead >= 0):
            raise ValueError(f"lookahead must be a finite number >= 0, got {lookahead!r}")
        if not (isinstance(reverse, (int, float)) and math.isfinite(reverse) and 0 <= reverse <= 1):
            raise ValueError(f"reverse must be a number in [0, 1] (a fraction of max_speed), got {reverse!r}")
        if not (isinstance(reverse_horizon, (int, float)) and math.isfinite(reverse_horizon) and reverse_horizon >= 0):
            raise ValueError(f"reverse_horizon must be a finite number >= 0 (s; 0: horizon), got {reverse_horizon!r}")
        if not (isinstance(period_margin, (int, float)) and math.isfinite(period_margin) and period_margin >= 0):
            raise ValueError(f"period_margin must be a finite number >= 0 (m), got {period_margin!r}")
        unknown = sorted(set(avoidance) - set(AvoidanceParams.names()))
        if unknown:
            raise TypeError(f"VOExpert got unknown parameter(s) {unknown}; known: {', '.join(self.policy_parameters())}")
        # The avoidance itself is swarm_env.control.safety's (shared with the SafetyShield wrapper); it checks its own values.
        # The expert's own defaults (EXPERT_AVOIDANCE) on top of the shared ones, which the shield keeps.
        self.avoidance = AvoidanceParams(**{**EXPERT_AVOIDANCE, **avoidance})
        self.time_gap = float(time_gap)
        self.feed_forward = bool(feed_forward)
        self.arrive_radius = float(arrive_radius)
        self.full_turn = bool(full_turn)
        self.preview = float(preview)
        self.lookahead = float(lookahead)
        self.reverse = float(reverse)
        self.reverse_horizon = float(reverse_horizon)
        self.period_margin = float(period_margin)
        self.escape_drive = bool(escape_drive)
        self._period: tuple[float, float, AvoidanceParams] = (-1.0, -1.0, self.avoidance)  # (max_speed, dt, params)
        self._reversing: tuple[float, AvoidanceParams] | None = None  # (max_speed, the fallback's params)
        self._index: dict[str, int] = {}
        self._reset_stats()

    @classmethod
    def policy_parameters(cls) -> dict[str, Any]:
        """Every parameter and its default: the tracking ones, then :class:`AvoidanceParams`'."""
        tracking = {p.name: p.default for p in inspect.signature(cls.__init__).parameters.values()
                    if p.kind is inspect.Parameter.KEYWORD_ONLY}
        defaults = AvoidanceParams(**EXPERT_AVOIDANCE)
        return {**tracking, **{name: getattr(defaults, name) for name in AvoidanceParams.names()}}

    def __getattr__(self, name: str) -> Any:
        """The avoidance parameters read through: ``expert.horizon`` is ``expert.avoidance.horizon``."""
        avoidance = self.__dict__.get("avoidance")
        if avoidance is not None and name in AvoidanceParams.names():
            return getattr(avoidance, name)
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    # ------------------------------------------------------------------ Policy protocol
    def reset(self, env: SwarmEnv, seed: int | None) -> None:
        """Start an episode (clears the telemetry). ``seed`` is unused: the expert is deterministic."""
        if getattr(env, "action_type", "continuous") != "continuous":
            raise ValueError(
                "the VO expert drives the continuous action space only: paper 000's motion primitives "
                "(action_type='discrete') all drive at full speed and cannot express the slow-downs and "
                "turns in place the velocity-obstacle search relies on; make the env with action_type='continuous'"
            )
        self._index = {a: int(a.rsplit("_", 1)[1]) for a in env.possible_agents}
        self._reset_stats()

    def act(self, observations: dict[str, np.ndarray], state: WorldState) -> dict[str, Any]:
        """One action per agent in ``observations`` (the env's live agents), from ``state``."""
        t0 = time.perf_counter()
        twist, feasible, escaped, backed = self._decide(state)
        limits = np.array([state.scenario.robots.max_speed, state.scenario.robots.max_turn_rate])
        action = np.clip(twist / limits, -1.0, 1.0).astype(np.float32)
        index = self._index
        out = {a: action[index[a] if a in index else int(a.rsplit("_", 1)[1])] for a in observations}
        self._times.append(time.perf_counter() - t0)
        self._infeasible += int(np.count_nonzero(~feasible))
        self._escapes += int(np.count_nonzero(escaped))
        self._reverses += int(np.count_nonzero(backed))
        self._follower_steps += len(feasible)
        return out

    def twists(self, state: WorldState) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The commanded twists ``(N, 2)`` ``(v, omega)`` of all followers, with the per
        follower flags ``feasible`` (a safe candidate existed) and ``escaped`` (turned
        in place towards open space) of the forward search. Pure: reads ``state`` only."""
        return self._decide(state)[:3]

    def _decide(self, state: WorldState) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`twists` and the flags of the followers that back off (``reverse``)."""
        preferred = self.preferred_twists(state)
        params = self._params(state)
        res = safe_follower_twists(state, preferred, params)
        if self.reverse <= 0 or res.feasible.all() or not len(state.human_pos):
            return res.twist, res.feasible, res.escaped, np.zeros(len(res.twist), dtype=bool)
        # Boxed in (no forward or standing candidate is safe) with a human coming: the other robots
        # give way (reciprocal avoidance), a human does not. Search again with reversing candidates
        # and take their answer for those followers where it is safe.
        boxed = ~res.feasible & self._human_coming(state)
        if not boxed.any():
            return res.twist, res.feasible, res.escaped, boxed
        # (Without period_margin's grown discs: backing off, only a robot contact within reverse_horizon counts, the
        # robots give way, and on the measured maps the grown discs there left followers pinned by walkers.)
        twist, take = back_off(state, preferred, res, boxed, self._reverse_params(state.scenario.robots.max_speed))
        return twist, res.feasible, res.escaped & ~take, take

    def _human_coming(self, state: WorldState) -> np.ndarray:
        """``(N,)``: a human could reach the follower within the search's horizon (the gap between
        their discs closes at their two speeds)."""
        pose = state.follower_pose
        gap = (np.hypot(pose[:, None, 0] - state.human_pos[None, :, 0], pose[:, None, 1] - state.human_pos[None, :, 1])
               - state.follower_radius[:, None] - state.human_radius[None, :])
        closing = np.hypot(*state.human_vel.T)[None, :] + state.scenario.robots.max_speed
        return np.any(gap <= self.avoidance.horizon * closing, axis=1)

    def _params(self, state: WorldState) -> AvoidanceParams:
        """The avoidance for this scenario's control period: :attr:`avoidance` with the other followers' discs grown
        by ``period_margin`` (the same object when they do not grow), cached per speed limit and period."""
        v_max, dt = float(state.scenario.robots.max_speed), float(state.scenario.world.dt)
        if self._period[:2] != (v_max, dt):
            grow = period_margin(v_max, dt, self.period_margin)
            params = dataclasses.replace(self.avoidance, robot_margin=self.avoidance.robot_margin + grow) if grow else self.avoidance
            self._period = (v_max, dt, params)
        return self._period[2]

    def _reverse_params(self, max_speed: float) -> AvoidanceParams:
        """The fallback search's parameters: the avoidance with speeds down to ``-reverse * max_speed`` and the other
        robots' horizon ``reverse_horizon`` (the humans keep theirs)."""
        if self._reversing is None or self._reversing[0] != max_speed:
            self._reversing = (max_speed, reversing_params(self.avoidance, self.reverse, max_speed,
                                                           self.reverse_horizon))
        return self._reversing[1]

    def preferred_twists(self, state: WorldState) -> np.ndarray:
        """Pure pursuit towards each follower's (led) slot target: ``(N, 2)`` twists before avoidance.

        Without preview the pursuit itself runs compiled (:func:`swarm_env.control.vo_kernel.pursuit`) unless
        :func:`swarm_env.compiled.use_compiled_search` turned the compiled search off; the numpy code
        below is its reference (same bits, ``tests/test_vo_kernel.py``)."""
        robots = state.scenario.robots
        slots = state.slot_targets
        T = self.time_gap
        v_max, omega_max = float(robots.max_speed), float(robots.max_turn_rate)
        preview = self.feed_forward and self.preview > 0.0
        if self.feed_forward:
            v_slot = slot_velocities(state.leader_pose, state.leader_vel, float(state.leader_twist[1]), slots)
            target = self._capped(state.follower_pose, slots + v_slot * T, v_max)
            if not preview and compiled_search():
                return self._drive_on(state, target, self._pursuit_compiled(state.follower_pose, target, v_max,
                                                                            omega_max), v_max, omega_max)
            if preview:
                # The env's rule for slots (world.World: radius + SLOT_MARGIN): a led point inside
                # an obstacle would steer the robot into it.
                clearance = float(robots.radius) + SLOT_MARGIN
                target = state.static.project_free(target, clearance)
        else:
            target = slots
            if compiled_search():
                return self._drive_on(state, target, self._pursuit_compiled(state.follower_pose, target, v_max,
                                                                            omega_max), v_max, omega_max)
        twist = pure_pursuit(state.follower_pose, target, v_max, omega_max, T)
        if preview:
            ahead = self._capped(state.follower_pose, state.static.project_free(slots + v_slot * self.preview, clearance),
                                 v_max)
            # Pure pursuit's speed along the arc to the point ahead (its curvature), slowed down
            # where that curvature would need more than the turn-rate limit (as pure pursuit does).
            steer = pure_pursuit(state.follower_pose, ahead, v_max, omega_max, self.preview)
            moving = steer[:, 0] > 1e-9
            kappa = np.where(moving, steer[:, 1] / np.where(moving, steer[:, 0], 1.0), 0.0)
            v = np.minimum(twist[:, 0], omega_max / np.maximum(np.abs(kappa), 1e-12))
            twist = np.where(moving[:, None], np.column_stack([v, v * kappa]), twist)
        d = target - state.follower_pose[:, :2]
        if self.full_turn:
            # Target behind (|alpha| > 90 deg): pure pursuit turns in place at 2 v / l, slow
            # for a far target; turn at the full rate instead.
            alpha = _bearing_error(state.follower_pose, d)
            behind = np.abs(alpha) > 0.5 * math.pi
            twist[behind, 0] = 0.0
            twist[behind, 1] = np.where(alpha[behind] >= 0.0, 1.0, -1.0) * float(robots.max_turn_rate)
        arrived = d[:, 0] ** 2 + d[:, 1] ** 2 < self.arrive_radius**2
        twist[arrived] = 0.0
        return self._drive_on(state, target, twist, v_max, omega_max)

    def _drive_on(self, state: WorldState, target: np.ndarray, twist: np.ndarray, v_max: float,
                  omega_max: float) -> np.ndarray:
        """``escape_drive``: ``twist`` with each follower whose full turn (``full_turn``) would turn it back against
        the way it is turning in place (an escape turn towards open space, the step before) driving on straight
        at the pursuit's speed ``min(|target - p| / time_gap, max_speed)`` instead.

        The full turn in place was always "safe" (it stands), so the VO search took it, the next step's escape
        turned the robot back towards open space, and the two took turns for the rest of the episode (measured:
        ``cluttered`` world 544, ``large_16`` world 14, ``crowd_reactive`` world 33; docs/vo_defaults.md). Driving
        on is tested by the search like any preferred twist."""
        turning = (twist[:, 0] == 0.0) & (twist[:, 1] != 0.0)  # full turns (and pure pursuit's turns in place)
        if not (self.escape_drive and self.full_turn and turning.any()):
            return twist
        cur = state.follower_twist
        turn_back = turning & turning_in_place(cur[:, 0], cur[:, 1], v_max, omega_max) & (twist[:, 1] * cur[:, 1] < 0.0)
        if not turn_back.any():
            return twist
        d = target - state.follower_pose[:, :2]
        alpha = _bearing_error(state.follower_pose, d)
        on = turn_back & (np.abs(alpha) > 0.5 * math.pi) & (d[:, 0] ** 2 + d[:, 1] ** 2 >= self.arrive_radius**2)
        if not on.any():
            return twist
        out = twist.copy()
        out[on, 0] = np.minimum(np.hypot(d[on, 0], d[on, 1]) / self.time_gap, v_max)
        out[on, 1] = 0.0
        return out

    def _capped(self, pose: np.ndarray, target: np.ndarray, v_max: float) -> np.ndarray:
        """``lookahead``: each point of ``target`` ``(N, 2)`` moved towards its robot to at most
        ``v_max * lookahead`` from it (unchanged with ``lookahead = 0``)."""
        if self.lookahead <= 0.0:
            return target
        d = target - pose[:, :2]
        dist = np.hypot(d[:, 0], d[:, 1])
        cap = v_max * self.lookahead
        scale = np.where(dist > cap, cap / np.maximum(dist, 1e-12), 1.0)
        return pose[:, :2] + d * scale[:, None]

    def _pursuit_compiled(self, pose: np.ndarray, target: np.ndarray, v_max: float, omega_max: float) -> np.ndarray:
        """:meth:`preferred_twists` without preview from the pursued points ``target`` ``(N, 2)``, by
        :func:`swarm_env.control.vo_kernel.pursuit`. The bearing of each target is numpy's ``arctan2``, as in
        the reference: the C library's ``atan2`` (what a kernel would call) differs from numpy's SIMD
        one in the last bit for a few per cent of inputs on this machine."""
        from swarm_env.control import vo_kernel

        if v_max < 0.0 or omega_max < 0.0:  # (pure_pursuit's check)
            raise ValueError("v_max and omega_max must be >= 0")
        d = target - pose[:, :2]
        return vo_kernel.pursuit(pose, target, np.arctan2(d[:, 1], d[:, 0]), v_max, omega_max, self.time_gap,
                                 self.full_turn, self.arrive_radius**2)

    # ------------------------------------------------------------------ telemetry
    def _reset_stats(self) -> None:
        self._times: list[float] = []
        self._infeasible = 0
        self._escapes = 0
        self._reverses = 0
        self._follower_steps = 0

    def stats(self) -> dict[str, Any]:
        """Telemetry of the current episode (lands under ``policy_stats`` in the metrics JSON).

        * ``decision_time_ms``: ``{median, p95, max, mean}`` wall time of one ``act()``
          call for all followers (ms), and ``calls``;
        * ``infeasible_events``: follower-steps in which no candidate was safe
          (``infeasible_rate`` per follower-step);
        * ``escape_turns``: follower-steps turned in place towards open space;
        * ``reverse_steps``: infeasible follower-steps that backed off instead (``reverse``).

        (The clearances the policy kept are the env's to measure, on every step:
        ``min_separation`` and ``min_clearance`` of ``episode_metrics()``.)
        """
        t = np.array(self._times) * 1e3
        timing = (
            {
                "median": float(np.median(t)),
                "p95": float(np.percentile(t, 95)),
                "max": float(t.max()),
                "mean": float(t.mean()),
                "calls": int(t.size),
            }
            if t.size
            else {"median": None, "p95": None, "max": None, "mean": None, "calls": 0}
        )
        steps = max(self._follower_steps, 1)
        return {
            "decision_time_ms": timing,
            "infeasible_events": self._infeasible,
            "infeasible_rate": self._infeasible / steps,
            "escape_turns": self._escapes,
            "reverse_steps": self._reverses,
        }


#: Entry-point factory (``swarm_env.policies`` group, name ``vo``): ``vo[:KEY=VALUE,...]`` sets
#: :class:`VOExpert` parameters, e.g. ``vo:horizon=4,margin=0.1``.
make_policy = expert_factory("vo", VOExpert)
