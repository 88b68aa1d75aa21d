"""The options of the CBS + RRT expert (:class:`~swarm_env_agents.cbs_rrt.policy.CBSRRTExpert`): one frozen,
validated dataclass, whose every field is a keyword of the expert and a ``cbs_rrt:KEY=VALUE`` option."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, fields

from swarm_env.checks import finite_numbers
from swarm_env_agents.cbs_rrt.primitives import PAPER_ANGLES_DEG

__all__ = ["CBSRRTConfig"]


@dataclass(frozen=True)
class CBSRRTConfig:
    """What the expert plans with (units m, s, degrees for angles). Measurements behind the defaults and the
    opt-in options: docs/cbs_rrt_options.md.

    Planning window and replanning:
        horizon: length of the planning window (s).
        check_margin: conflicts are checked this long past the next planned replan (s);
            also the lead with which plans are renewed before the horizon runs out.
        conflict_window: CBS resolves conflicts over at most this long from now (s); when
            conflicts remain later in the plans, the swarm is replanned (``rolling``) after
            ``conflict_window - check_margin`` — a rolling-horizon CBS: a replan never has to
            untangle a whole formation change at once.
        deviation_tolerance: replan when a robot is this far from its plan (m).
        goal_move_tolerance: replan when a slot target moved this far from its planned goal (m).
        min_replan_interval: least time between two replans for ``goal_moved``/``retry`` (s).

    Safety margins:
        robot_margin: two robots conflict below ``2 * radius + robot_margin`` (m).
        obstacle_margin: buffer zone: the RRT keeps ``radius + obstacle_margin`` from
            obstacles and walls; goals are projected to that clearance (m).

    Formation layer:
        goal_dt: time step of the goal courses (s).
        goal_tolerance: an RRT node joins its goal course within this distance (m).

    Motion primitives (paper 000 Sec. III-B):
        primitive_angles: heading changes (degrees).
        primitive_step: arc length (m); ``None``: the env's discrete primitive,
            ``max_speed * max|angle| / max_turn_rate``.
        speed_fraction: primitives are driven at this fraction of ``max_speed`` (the rest is
            the tracker's room to catch up); ``None``: ``0.7``, or more against a fast leader
            (``leader speed / max_speed + 0.25``, at most ``0.9``).
        primitive_samples: points per primitive for collision checks.
        turn_in_place: spins (degrees) added to the paper's forward primitives: without
            them a robot facing an obstacle closer than its turning radius is stuck.

    RRT:
        rrt_iterations: expansions per root call (no constraints); rrt_child_iterations: per
            call under CBS constraints; rrt_strong_iterations: per call with a strong
            constraint (it has a weaker fallback, see :mod:`swarm_env_agents.cbs_rrt.swarm`);
        goal_bias; max_wait (s);
        smoothing: run the smoothing pass.

    CBS:
        use_cbs: ``False`` plans every robot independently (no conflict resolution; the
            "without CBS" panel of paper 000 Fig. 3).
        cbs_nodes: node expansions per search; cbs_low_level_calls: low-level calls per replan;
        cbs_suboptimality: a CBS node may be expanded while its cost is within this factor of the best (>= 1);
        constraint_window: the weak constraint (a disc at the other robot's position) covers
            this long after the conflict (s).
        strong_constraints: first ask a child to keep clear of the other robot's whole path
            (see :mod:`swarm_env_agents.cbs_rrt.swarm`); ``False``: the weak constraint only.
        reuse_approach: keep a still-valid plan of a robot that is on its way to its slot as
            its CBS root path (otherwise only robots already in formation keep theirs); a
            rolling horizon that replans the approach every few seconds can otherwise keep
            postponing it.

    Formation keeping (experimental, off by default; ``formation_keeping=True, jump_window=1.0`` together, either
    alone is worse than neither):
        jump_window, jump_lag: ``jump_window > 0`` counts a fast step of a goal course as a jump
            only where the course moves farther than ``max_speed * jump_window + jump_lag``
            within ``jump_window`` or its chord cuts within ``radius + shield_margin`` of an
            obstacle (:class:`~swarm_env_agents.cbs_rrt.goals.FormationGoals`): a slot sweeping
            briefly round an obstacle is then tracked, not replanned. ``0``: every step faster
            than ``0.8 * max_speed`` is a jump.
        formation_keeping: robots in formation follow their goal course and are fixed in the
            CBS search (see :meth:`CBSRRTExpert._keepers`); keep_tolerance: how close to its
            course a robot must be to count as in formation, and how far it may then fall behind
            before a ``deviation`` replan (m; the others use ``deviation_tolerance``).

    Holding a reached formation:
        hold_plan: hold a reached formation by planning it (on by default): with a virtual
            leader, whose slots are known for the rest of the episode, once every follower is
            near its slot (``hold_capture``) the expert plans where each should be at every step
            up to the next switch or the leader's stop (joint space-time point paths on a 0.05 m
            lattice that keep contact-free margins, centres ``r + 0.04`` m from obstacles and ``2 r +
            0.08`` m apart, and maximise the steps with the whole formation within tolerance:
            :mod:`~swarm_env_agents.cbs_rrt.hold_plan`) and tracks that plan with a look-ahead
            search over the robots' exact substep kinematics; the plan's margins replace the shield
            while it holds. It plans again when a robot is 0.5 m off its path or the formation changes
            (``stats()["hold_plans"]``, ``["hold_plan_s"]``, ``["hold_plan_cpu_s"]``: wall and CPU time); CBS
            takes over again like with ``hold_slots``. Other leaders, worlds with humans (the plan has no humans
            in it), and steps too short for the lattice (less than 0.2 m of travel: the random worlds and the
            paper-003 scenarios, dt = 0.1 s) keep CBS (or ``hold_slots``' holder).
        hold_slots: (off by default; where ``hold_plan`` does not apply) once every follower is
            near its slot (``hold_capture``), a
            :class:`~swarm_env_agents.cbs_rrt.hold.SlotHolder` (a short-horizon search over the
            robots' kinematics towards their moving slots, round obstacles by geodesic distance)
            drives the swarm instead of the plans, until the next formation switch (or a stuck
            follower, ``hold_capture``), when CBS plans again. Off: on random worlds it brought
            robot-human contacts and costs 40-100 ms of CPU per step with 8 followers.
        hold_horizon: how far the holder looks ahead (s): four points, the next step and three
            more spread over the horizon in whole steps (``paper_cbs_switch``, dt = 0.5 s: the next
            four steps; the random worlds, dt = 0.1 s: steps 1, 7, 13 and 19).
        hold_capture: the holder takes over once every follower is within ``settle_tolerance +
            hold_capture`` of its slot (m), and hands back to CBS when one has been farther than
            that for 5 s (``stats()["hold_releases"]``): CBS brings the swarm close, the holder settles it.

    Tracking:
        lookahead_time: pure pursuit aims at the plan's position this far ahead (s).
        shield_margin: the tracker's safety check (``0`` disables it): a robot does not drive
            closer than this to an obstacle, another robot, a human or a robot leader over the
            next step (m).
        evade_horizon: a robot that a human, walking on at its current velocity, would come
            within ``shield_margin`` of within this time (s) even if the robot stood still takes
            the twist of the ``vo`` expert's search for that step instead of the plan's (its
            avoidance, :data:`swarm_env_agents.vo_expert.EXPERT_AVOIDANCE`, with the other
            followers as plain discs: they follow their plans); ``0`` disables it. The shield
            alone stops such a robot and the human walks into it (``stats()["evade_steps"]`` counts the
            robot-steps).
        evade_reverse: a fraction in ``[0, 1]`` (default ``0.5``; ``0`` for none). A robot stepping aside whose
            search finds no safe twist searches again with speeds down to ``-evade_reverse * max_speed``, the
            other robots looked for only ``evade_reverse_horizon`` s ahead, and backs off if that is safe or
            postpones the contact (:func:`swarm_env.control.safety.back_off`, the ``vo`` expert's ``reverse``
            rule; counted in ``stats()["reverse_steps"]``). Chosen on the training worlds of the ``crowd_reactive``
            family, where a walker that turns into a robot within a second otherwise reached it: docs/benchmark.md.
        evade_reverse_horizon: the other robots' horizon (s) in that search (default ``1.0``; ``0``: the
            avoidance's horizon).

    Other:
        field_resolution: distance-field grid step (m).
        record: keep a :class:`~swarm_env_agents.cbs_rrt.policy.ReplanRecord` of every replan in ``history``
            (figures).
    """

    horizon: float = 30.0
    check_margin: float = 1.5
    conflict_window: float = 8.0
    deviation_tolerance: float = 0.2
    goal_move_tolerance: float = 0.5
    min_replan_interval: float = 1.0
    robot_margin: float = 0.2
    obstacle_margin: float = 0.1
    goal_dt: float = 0.25
    goal_tolerance: float = 0.3
    primitive_angles: Sequence[float] = PAPER_ANGLES_DEG
    primitive_step: float | None = None
    speed_fraction: float | None = None
    primitive_samples: int = 6
    turn_in_place: Sequence[float] = (45.0, -45.0, 90.0, -90.0)
    rrt_iterations: int = 300
    rrt_child_iterations: int = 120
    rrt_strong_iterations: int = 40
    goal_bias: float = 0.3
    max_wait: float = 8.0
    smoothing: bool = True
    use_cbs: bool = True
    cbs_nodes: int = 24
    cbs_low_level_calls: int = 64
    cbs_suboptimality: float = 1.0
    constraint_window: float = 2.0
    strong_constraints: bool = True
    reuse_approach: bool = True
    lookahead_time: float = 1.0
    jump_window: float = 0.0
    jump_lag: float = 0.6
    formation_keeping: bool = False
    keep_tolerance: float = 0.3
    hold_slots: bool = False
    hold_horizon: float = 2.0
    hold_capture: float = 1.5
    hold_plan: bool = True
    shield_margin: float = 0.05
    evade_horizon: float = 3.0
    evade_reverse: float = 0.5
    evade_reverse_horizon: float = 1.0
    field_resolution: float = 0.05
    record: bool = False

    def __post_init__(self) -> None:
        positive = ("horizon", "check_margin", "conflict_window", "deviation_tolerance", "goal_move_tolerance",
                    "goal_dt", "goal_tolerance", "lookahead_time", "field_resolution", "keep_tolerance",
                    "constraint_window")
        finite_numbers("", {name: getattr(self, name) for name in positive}, positive=True)
        non_negative = ("robot_margin", "obstacle_margin", "shield_margin", "evade_horizon", "evade_reverse_horizon",
                        "min_replan_interval", "max_wait", "jump_window", "jump_lag", "hold_capture")
        finite_numbers("", {name: getattr(self, name) for name in non_negative}, positive=False)
        if not (isinstance(self.evade_reverse, (int, float)) and 0 <= self.evade_reverse <= 1):
            raise ValueError(f"evade_reverse must be a number in [0, 1] (a fraction of max_speed), got "
                             f"{self.evade_reverse!r}")
        if self.check_margin >= self.horizon:
            raise ValueError("check_margin must be smaller than horizon")
        sf = self.speed_fraction
        if sf is not None and not (isinstance(sf, (int, float)) and 0 < sf <= 1):
            raise ValueError(f"speed_fraction must be None or in (0, 1], got {sf!r}")
        if not 0 <= self.goal_bias <= 1:
            raise ValueError(f"goal_bias must be in [0, 1], got {self.goal_bias!r}")
        for name in ("rrt_iterations", "rrt_child_iterations", "rrt_strong_iterations", "cbs_nodes",
                     "cbs_low_level_calls", "primitive_samples"):
            value = getattr(self, name)
            if not isinstance(value, int) or value < (1 if name == "primitive_samples" else 0):
                raise ValueError(f"{name} must be a non-negative int, got {value!r}")
        if not (isinstance(self.cbs_suboptimality, (int, float)) and self.cbs_suboptimality >= 1.0):
            raise ValueError(f"cbs_suboptimality must be >= 1, got {self.cbs_suboptimality!r}")
        hh = self.hold_horizon
        if not (isinstance(hh, (int, float)) and math.isfinite(hh) and hh > 0):
            raise ValueError(f"hold_horizon must be a finite number > 0 (s), got {hh!r}")
        # The values as the expert reads them: numbers as float or int, flags as bool, angle lists as tuples.
        for f in fields(self):
            value, default = getattr(self, f.name), f.default
            if isinstance(default, bool):
                value = bool(value)
            elif isinstance(default, int):
                value = int(value)
            elif isinstance(default, float):
                value = float(value)
            elif isinstance(default, tuple):
                value = tuple(float(a) for a in value)
            elif f.name == "speed_fraction" and value is not None:
                value = float(value)
            object.__setattr__(self, f.name, value)
