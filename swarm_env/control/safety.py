"""Collision avoidance of the followers as one function of the world state: the VO safety rule.

:func:`safe_follower_twists` takes each follower's preferred twist and returns the safe twist
closest to it, from the velocity-obstacle search of :func:`swarm_env.control.vo.vo_select_batch`
(paper 003, Sec. II-D) against everything a follower may hit: the other followers (avoided
reciprocally: each takes half), a robot leader, the humans (with an extra margin, since they
do not avoid robots) and the static map. A preferred twist that is already safe comes back
unchanged. It is the one implementation behind the ``vo`` expert
(:class:`swarm_env_agents.vo_expert.VOExpert`, which prefers pure pursuit of its slot) and the safety
layer any learner can use (:class:`swarm_env.wrappers.SafetyShield`, which prefers the
learner's action).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from swarm_env.compiled import compiled_search
from swarm_env.control import vo
from swarm_env.control.vo import VOBatchResult, VODiscs, VOParams, VORobots, vo_select_batch
from swarm_env.state import WorldState

__all__ = ["AvoidanceParams", "ShieldResult", "back_off", "reversing_params", "safe_follower_twists", "shield_actions"]

# A correction smaller than this (in normalised action units) is float noise, not an intervention.
_INTERVENTION_EPS = 1e-9


@dataclass(frozen=True)
class AvoidanceParams(VOParams):
    """The followers' VO search: :class:`~swarm_env.control.vo.VOParams` (see
    :func:`swarm_env.control.vo.vo_select` for each field) plus what is about their world:
    ``human_margin`` (m) added to the humans' radii on top of ``margin``, ``human_horizon`` (s: the
    horizon for the humans, who do not give way, in place of ``horizon``; ``0``, the default, keeps
    ``horizon``; see :class:`swarm_env.control.vo.VODiscs`' ``horizon``), ``robot_margin`` (m added to
    the other followers' radii, not to a follower's own, the robot leader's or the humans': room for a
    neighbour that changes its velocity within a control period, see :func:`period_margin`), and
    ``reciprocal`` (followers avoid each other reciprocally; the robot leader and the humans are always
    avoided fully). Defaults differ from the search's in two places: no keep-right bias
    (``side_bias = 0``), and ``allow_still_overlap`` on (two followers that stopped inside each
    other's margin may still turn away).
    """

    human_margin: float = 0.05
    human_horizon: float = 0.0
    robot_margin: float = 0.0
    side_bias: float = 0.0
    reciprocal: bool = True
    allow_still_overlap: bool = True

    def __post_init__(self) -> None:
        super().__post_init__()
        if not (isinstance(self.human_margin, (int, float)) and np.isfinite(self.human_margin) and self.human_margin >= 0):
            raise ValueError(f"human_margin must be a finite number >= 0, got {self.human_margin!r}")
        hh = self.human_horizon
        if not (isinstance(hh, (int, float)) and np.isfinite(hh) and hh >= 0):
            raise ValueError(f"human_horizon must be a finite number >= 0 (s; 0: horizon), got {hh!r}")
        rm = self.robot_margin
        if not (isinstance(rm, (int, float)) and np.isfinite(rm) and rm >= 0):
            raise ValueError(f"robot_margin must be a finite number >= 0 (m), got {rm!r}")

    def disc_horizons(self, n_robots: int, n_humans: int) -> np.ndarray | None:
        """The horizon of each moving disc, ``n_robots`` robots then ``n_humans`` humans
        (:class:`~swarm_env.control.vo.VODiscs`' ``horizon``); ``None`` when all share ``horizon``."""
        if not (self.human_horizon and n_humans) or self.human_horizon == self.horizon:
            return None
        h = np.full(n_robots + n_humans, float(self.horizon))
        h[n_robots:] = self.human_horizon
        return h


#: The control period (s) that the search's ``margin`` (0.05 m) covers: a neighbour that stops within one period
#: of 0.1 s at 0.65 m/s is 0.065 m nearer than the velocity obstacle assumed.
MARGIN_PERIOD = 0.1


def period_margin(max_speed: float, dt: float, cap: float) -> float:
    """``robot_margin`` for a control period of ``dt`` s: what a neighbour at ``max_speed`` covers in the part of
    the period beyond :data:`MARGIN_PERIOD`, at most ``cap`` m (0 for ``dt <= 0.1`` s).

    The velocity obstacle trusts a neighbour's velocity for the whole period; a neighbour that stops or turns in
    place meanwhile (a follower with no safe twist does) is met that much sooner. Measured (issue 34): with
    switches every 12-14 s and dt = 0.2-0.25 s, followers crossing to their new slots touched on 9 of 24 maps
    without it and none with it."""
    return min(max(float(dt) - MARGIN_PERIOD, 0.0) * float(max_speed), float(cap))


def safe_follower_twists(state: WorldState, preferred: np.ndarray, params: AvoidanceParams = AvoidanceParams()) -> VOBatchResult:
    """The safe twist closest to each follower's ``preferred`` ``(N, 2)`` ``(v, omega)``.

    Pure: reads ``state`` only. ``result.twist`` ``(N, 2)`` are the answers (within the
    robots' limits), ``result.feasible`` says whether a safe candidate existed (if not,
    the least dangerous one, or an escape turn, is returned), ``result.preferred_safe``
    whether the preferred twist itself was safe (then it is returned unchanged unless a
    heading term makes another candidate cheaper).

    Runs compiled (:func:`swarm_env.control.vo_kernel.follower_select`: the discs, the masks and the whole
    search in one call) unless :func:`swarm_env.compiled.use_compiled_search` turned the compiled
    search off; this function's numpy body below is the reference (same bits,
    ``tests/test_vo_kernel.py``).
    """
    if compiled_search() and params.model == "arc":
        return _follower_twists_compiled(state, preferred, params)
    robots = state.scenario.robots
    pose = state.follower_pose
    n = len(pose)
    has_leader = state.leader_is_robot
    n_h = len(state.human_pos)
    n_d = n + int(has_leader) + n_h
    discs = np.empty((n_d, 3))
    vel = np.empty((n_d, 2))
    discs[:n, :2] = pose[:, :2]
    discs[:n, 2] = state.follower_radius + params.robot_margin  # as the others see them (not in VORobots)
    vel[:n] = state.follower_vel
    k = n
    if has_leader:
        discs[k, :2] = state.leader_pose[:2]
        discs[k, 2] = state.leader_radius
        vel[k] = state.leader_vel
        k += 1
    if n_h:
        discs[k:, :2] = state.human_pos
        discs[k:, 2] = state.human_radius + params.human_margin
        vel[k:] = state.human_vel
    mask = np.ones((n, n_d), dtype=bool)
    mask[np.arange(n), np.arange(n)] = False  # not itself
    recip = np.zeros(n_d, dtype=bool)
    recip[:n] = params.reciprocal  # the robot leader and the humans are avoided fully
    disc_horizon = params.disc_horizons(n + int(has_leader), n_h)
    followers = VORobots(
        pose,
        state.follower_radius,
        np.asarray(preferred, dtype=np.float64),
        float(robots.max_speed),
        float(robots.max_turn_rate),
        velocity=state.follower_vel,
        current=state.follower_twist,
    )
    return vo_select_batch(followers, VODiscs(discs, vel, mask, recip, disc_horizon), state.static, params)


def _follower_twists_compiled(state: WorldState, preferred: np.ndarray, params: AvoidanceParams) -> VOBatchResult:
    """:func:`safe_follower_twists` by :func:`swarm_env.control.vo_kernel.follower_select`: the same discs (in
    the same order) and the same search, one kernel call."""
    from swarm_env.control import vo_kernel

    robots = state.scenario.robots
    v_max, omega_max = float(robots.max_speed), float(robots.max_turn_rate)
    pose = state.follower_pose
    n = len(pose)
    has_leader = state.leader_is_robot
    n_h = len(state.human_pos)
    k = n + int(has_leader)
    # One writeable array per kind (the snapshot's own are read-only, another array type for numba):
    # x, y, radius, vx, vy, horizon of every moving disc, and each follower's heading, current and preferred twists.
    moving = np.empty((k + n_h, 6))
    moving[:n, :2] = pose[:, :2]
    moving[:n, 2] = state.follower_radius
    moving[:n, 3:5] = state.follower_vel
    if has_leader:
        moving[n, :2] = state.leader_pose[:2]
        moving[n, 2] = state.leader_radius
        moving[n, 3:5] = state.leader_vel
    if n_h:
        moving[k:, :2] = state.human_pos
        moving[k:, 2] = state.human_radius + params.human_margin
        moving[k:, 3:5] = state.human_vel
    disc_horizon = params.disc_horizons(k, n_h)
    moving[:, 5] = params.horizon if disc_horizon is None else disc_horizon
    own = np.empty((n, 5))
    own[:, 0] = pose[:, 2]
    own[:, 1:3] = state.follower_twist
    own[:, 3:] = np.asarray(preferred, dtype=np.float64).reshape(n, 2)
    plan, scalars, flags = vo._follower_plan(params, v_max, omega_max,
                                                   vo._trace_horizon(params.horizon, disc_horizon))
    static = state.static
    return VOBatchResult(*vo_kernel.follower_select(moving, own, n, vo._kernel_map(static), static is not None,
                                                    plan, scalars, flags))


@dataclass(frozen=True)
class ShieldResult:
    """What :func:`shield_actions` did, per follower: the executed ``actions`` ``(N, 2)``
    float32, the ``correction`` ``(N,)`` (Euclidean distance between the wanted and the
    executed normalised action), ``intervened`` ``(N,)`` bool and ``feasible`` ``(N,)``
    bool (a safe candidate existed)."""

    actions: np.ndarray
    correction: np.ndarray
    intervened: np.ndarray
    feasible: np.ndarray


def reversing_params(params: AvoidanceParams, reverse: float, max_speed: float,
                     robot_horizon: float) -> AvoidanceParams:
    """The back-off search's parameters (:func:`back_off`): ``params`` with speeds down to ``-reverse * max_speed``
    and the other robots looked for only ``robot_horizon`` s ahead (``0``: ``params.horizon``), since they give way
    (reciprocal avoidance); the humans, who do not, keep their horizon."""
    return replace(params, v_min=-reverse * max_speed, horizon=robot_horizon or params.horizon,
                   human_horizon=params.human_horizon or params.horizon)


def back_off(state: WorldState, preferred: np.ndarray, forward: VOBatchResult, boxed: np.ndarray,
             reversing: AvoidanceParams) -> tuple[np.ndarray, np.ndarray]:
    """The rule for a follower boxed in with a human coming: ``(twists, taken)``.

    ``forward`` is :func:`safe_follower_twists`'s answer for ``preferred`` (``(N, 2)``); ``boxed`` ``(N,)`` marks the
    followers it left without a safe twist while a human is coming. They search again with reversing candidates
    (``reversing``, from :func:`reversing_params`) and take that twist if it is safe or, when nothing is, if it
    postpones the contact longer than the forward answer: backing off from a human who keeps coming beats turning
    in place in his path. ``twists`` is ``forward.twist`` with those answers; ``taken`` marks them. One rule for the
    ``vo`` expert and ``cbs_rrt``'s evasion."""
    if not boxed.any():
        return forward.twist, np.zeros(len(forward.twist), dtype=bool)
    back = safe_follower_twists(state, preferred, reversing)
    taken = boxed & (back.feasible | (back.min_time_to_collision > forward.min_time_to_collision))
    return np.where(taken[:, None], back.twist, forward.twist), taken


def shield_actions(state: WorldState, wanted: np.ndarray, params: AvoidanceParams) -> ShieldResult:
    """The safety layer: normalised actions ``wanted`` ``(N, 2)`` in ``[-1, 1]`` -> the nearest
    safe ones (:func:`safe_follower_twists` on ``wanted * (max_speed, max_turn_rate)``).
    An action that is already safe is returned bit for bit."""
    wanted = np.asarray(wanted, dtype=np.float64)
    robots = state.scenario.robots
    limits = np.array([robots.max_speed, robots.max_turn_rate])
    result = safe_follower_twists(state, wanted * limits, params)
    safe = np.clip(result.twist / limits, -1.0, 1.0)
    correction = np.hypot(safe[:, 0] - wanted[:, 0], safe[:, 1] - wanted[:, 1])
    intervened = correction > _INTERVENTION_EPS
    executed = np.where(intervened[:, None], safe, wanted).astype(np.float32)
    return ShieldResult(executed, np.where(intervened, correction, 0.0), intervened, np.asarray(result.feasible, dtype=bool))
