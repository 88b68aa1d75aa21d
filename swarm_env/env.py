"""The PettingZoo parallel environment (see :class:`SwarmEnv`'s docstring: it is the spec)."""

from __future__ import annotations

import dataclasses
import functools
import math
import os
import time
import warnings
from collections.abc import Mapping
from typing import Any

import gymnasium
import numpy as np
from pettingzoo import ParallelEnv

from swarm_env.geometry.static_map import StaticMap
from swarm_env.render import Renderer
from swarm_env.scenario import RewardSpec, Scenario
from swarm_env.scenarios.families import generator_config, is_generated
from swarm_env.scenarios.generator import RandomScenarioConfig, random_scenario
from swarm_env.scenarios.loader import _parse_reward, load_scenario
from swarm_env.scoring.metrics import EpisodeMetrics
from swarm_env.scoring.rewards import (
    CONTACT_GROUPS,
    INFO_CONTACT_KEYS,
    INFO_REWARD_KEYS,
    REWARD_TERMS,
    reward_table,
    slot_distance,
    touching_per_follower,
)
from swarm_env.sensing.observations import STATE_LIMIT, Capacity, ObservationBuilder
from swarm_env.sim.world import World
from swarm_env.state import LEADER_ID, Contact, WorldState

#: Turn angles (degrees) of the discrete motion primitives (paper 000), after action 0 = stop.
PRIMITIVE_ANGLES_DEG = (0.0, 12.0, -12.0, 24.0, -24.0, 36.0, -36.0, 48.0, -48.0)
ACTION_TYPES = ("continuous", "discrete")
#: Named reward presets accepted by ``SwarmEnv(reward=...)``.
REWARD_PRESETS = {"v1": RewardSpec(), "v0": RewardSpec.v0()}


class SwarmEnv(ParallelEnv):
    """A leader-follower robot swarm in formation, simulated with pymunk.

    ## Description

    ``N`` differential-drive followers (the agents ``follower_0 ... follower_{N-1}``)
    must hold the slots of a formation defined in the frame of a leader that
    moves along a predefined path, while static obstacles and walking humans
    get in the way. The formation switches shape on a schedule. The leader is
    either *virtual* (a point moving exactly along its path, paper 000) or a
    *robot* that tracks its path with pure pursuit and avoids humans and
    obstacles with a velocity-obstacle rule (paper 003); it is part of the
    world, not an agent. Each follower's slot target is moved out of
    obstacles to the nearest free point (paper 000, sec. III-D d).

    ## Action space

    ``action_type="continuous"`` (default): ``Box(-1, 1, (2,), float32)``,
    mapped linearly to ``v = a[0] * max_speed`` (m/s, reversing allowed) and
    ``omega = a[1] * max_turn_rate`` (rad/s, counter-clockwise positive).
    Values outside ``[-1, 1]`` are clipped (with a one-time warning); NaN or
    infinite values, wrong shapes and unknown agents raise ``ValueError``.

    ``action_type="discrete"``: ``Discrete(10)``, paper 000's motion
    primitives: ``0`` = stop; ``1..9`` = drive forward at ``max_speed``
    while turning by ``PRIMITIVE_ANGLES_DEG[k-1]`` = 0, +12, -12, +24, -24,
    +36, -36, +48, -48 degrees over one primitive duration
    ``T_p = 48 deg / max_turn_rate`` (so the sharpest primitive turns at the
    robot's turn-rate limit; a primitive spans several steps).

    In every physics substep the command is limited to the robot's speed,
    turn-rate and (optional) acceleration limits.

    ## Observation space

    One ``Box`` (float32) per agent, in the agent's own frame, of length
    ``11 + 5 * neighbors + 5 * humans + lidar_rays`` (52 for the default
    sensors): own twist, vector to its slot, leader relative pose and
    velocity, time to the next formation switch, the ``neighbors`` nearest
    followers and ``humans`` nearest humans (relative position and velocity,
    plus a presence mask), and a lidar. See
    :mod:`swarm_env.sensing.observations` for the exact layout; the named slices are
    ``OBS_OWN_TWIST``, ``OBS_SLOT``, ``OBS_LEADER``, ``OBS_SWITCH`` and
    ``observation_layout(sensors)`` (also ``env.obs_layout``).

    ``state()`` returns a global state vector (``state_space``, float32 in
    ``[-2, 2]``) for centralised critics: every follower's normalised pose,
    twist and slot, the leader, the humans, the time, and the map: each
    follower's nearest static surface (distance and direction) and a 16 x 16
    occupancy grid of the obstacles. Named slices: ``env.state_layout``
    (:func:`swarm_env.sensing.observations.state_layout` documents each).

    ## Agents (fixed teams)

    ``possible_agents`` is fixed per env instance and every ``reset()`` makes
    ``env.agents == env.possible_agents``: no agent is ever absent, so no padding
    row reaches a learner, a normalisation statistic or a loss. For ``random``,
    ``n_followers`` (default 4) may be a range ``(lo, hi)``: the team size is then
    drawn **once, when the env is built**, from ``team_seed`` (default 0), and
    every episode of that instance has it; build instances with different
    ``team_seed`` values for a mix of team sizes.

    ## Rewards (v1)

    Per agent (see :mod:`swarm_env.scoring.rewards` for the formula; weights in the
    scenario's ``reward`` section, or ``reward=`` here)::

        r = - 1.0 * slot distance (m)
            - 5.0 * contact onsets this step
            - 2.0 * bodies in touch this step, per kind (robot, obstacle, human, wall)
            - 1.0 * max(0, 1 - clearance / 0.2 m)

    Every step of a contact is charged (v0 charged only its onset), and the
    clearance term warns inside a 0.2 m margin (CrowdNav's discomfort
    distance), where the lidar already sees the obstacle: a policy that avoids
    is scored mostly on its formation (measured in docs/environment.md, "Why
    reward v1 charges every contact step"). Each weighted term is reported in
    the infos as ``reward_<term>`` (they sum to the reward); rewards are
    Python floats. ``reward="v0"`` gives the v0 reward (``-distance - 10 *
    onsets``) for comparison with published numbers.

    ## Starting state

    The leader at the first waypoint of its path, facing the second; the
    followers on their first formation slots facing the leader's heading
    (``robots.start: formation``) or at the poses the scenario lists; humans on
    their first waypoints. Fixed scenarios are deterministic; ``random`` draws
    a new map from the generator seeded by ``reset(seed)``.

    ## Infos

    ``reset()`` and ``step()`` give every agent the same flat keys (zeros at
    reset), one number each, so that TorchRL and BenchMARL can make tensors of
    them: ``reward_<term>`` for each of :data:`swarm_env.scoring.rewards.REWARD_TERMS`
    (``reward_formation``, ``reward_collision``, ``reward_contact_robot``, ...;
    floats that sum to the reward), ``slot_distance`` (m), ``contacts_<kind>``
    for ``robot, obstacle, human, wall`` (int: bodies of that kind in touch
    during the step) and ``collision_terminated`` (bool: this step ended the
    episode by a collision). :func:`swarm_env.scoring.rewards.reward_terms` and
    :func:`~swarm_env.scoring.rewards.contact_counts` read them back as dicts.

    ## Episode end

    All agents end together. ``terminations`` are ``True`` when the leader has
    reached the end of its path and every follower is within
    ``world.settle_tolerance`` of its slot, or, with
    ``terminate_on_collision=True``, on the first step in which any follower
    touches anything (the offending agents are those with non-zero
    ``contacts_*`` infos; ``env.terminal_contacts`` lists the contacts);
    ``truncations`` are ``True`` at step ``env.max_steps`` (``world.max_time /
    dt``, or ``max_cycles`` if smaller; known from construction). Finished
    agents leave ``env.agents``. ``episode_metrics()`` then reports the metrics
    of :mod:`swarm_env.scoring.metrics` and ``termination`` (``"formation"``,
    ``"collision"`` or ``"time_limit"``).

    ## Arguments

    * ``scenario``: a built-in name (``swarm_env.list_scenarios()``), a path to
      a YAML file, a :class:`~swarm_env.scenario.Scenario`, ``"random"``, or a
      generator family ``"random:<family>"`` (:mod:`swarm_env.scenarios.families`:
      ``random:cluttered``, ``random:switching``, ...).
    * ``render_mode``: ``None``, ``"human"`` (pygame window) or ``"rgb_array"``.
    * ``action_type``: ``"continuous"`` or ``"discrete"``.
    * ``max_cycles``: optional step limit on top of ``world.max_time``.
    * ``terminate_on_collision``: end the episode (terminated) at the first
      follower contact (default ``False``).
    * ``reward``: ``None`` (the scenario's ``reward`` section, v1 defaults),
      ``"v1"``, ``"v0"``, a :class:`~swarm_env.scenario.RewardSpec` or a mapping
      of its fields.
    * ``team_seed``: for ``random`` with an ``n_followers`` range, the seed of
      the one team-size draw of this instance.
    * ``**knobs``: for ``"random"`` and its families only (on top of the family's), the fields of
      :class:`~swarm_env.scenarios.generator.RandomScenarioConfig`
      (``n_followers``, ``n_obstacles``, ``n_humans``, ...).

    ``metadata["render_fps"]`` is per instance: one frame per control step,
    ``round(1 / dt)`` (2 on ``paper_cbs_switch``), never 0; the class value 10
    is the default ``dt = 0.1 s``.

    ## Version history

    * v1, later additions: generator families (``"random:<family>"``, named presets of the
      generator's knobs; ``"random"`` draws the same worlds as before); humans that react, opt in (``behavior: social_force | orca`` per
      human, ``human_behavior`` for ``random``; :mod:`swarm_env.sim.humans`; scripted humans move
      as before); the lidar computed by a compiled kernel (its distances, so the observations,
      differ from the first v1 release's in the last bits).
    * v1: fixed teams (``random`` draws its team size once per instance, default
      4 followers); reset infos with the step infos' keys; public
      ``max_steps``; reward v1 (every contact step charged, by kind; clearance
      shaping on; ``terminate_on_collision``); ``state()`` includes the map;
      the generator's slot targets never outrun the followers, and its world
      grows with the team (up to 64 followers).
    * v0: initial release.
    """

    metadata: dict[str, Any] = {
        "name": "swarm_env_v1",
        "render_modes": ["human", "rgb_array"],
        "render_fps": 10,
        "is_parallelizable": True,
    }

    def __init__(
        self,
        scenario: str | os.PathLike[str] | Scenario = "paper_vo_0",
        *,
        render_mode: str | None = None,
        action_type: str = "continuous",
        max_cycles: int | None = None,
        terminate_on_collision: bool = False,
        reward: RewardSpec | Mapping[str, Any] | str | None = None,
        team_seed: int = 0,
        **knobs: Any,
    ) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or one of {self.metadata['render_modes']}, got {render_mode!r}")
        if action_type not in ACTION_TYPES:
            raise ValueError(f"action_type must be one of {ACTION_TYPES}, got {action_type!r}")
        if max_cycles is not None and (isinstance(max_cycles, bool) or not isinstance(max_cycles, int) or max_cycles < 1):
            raise ValueError(f"max_cycles must be a positive int, got {max_cycles!r}")
        if not isinstance(terminate_on_collision, bool):
            raise ValueError(f"terminate_on_collision must be a bool, got {terminate_on_collision!r}")
        if isinstance(team_seed, bool) or not isinstance(team_seed, (int, np.integer)) or team_seed < 0:
            raise ValueError(f"team_seed must be an int >= 0, got {team_seed!r}")
        reward_spec = _reward_spec(reward)
        self._random: RandomScenarioConfig | None = None
        if is_generated(scenario):
            cfg = generator_config(str(scenario), knobs)
            lo, hi = cfg.n_followers  # type: ignore[misc]
            if lo != hi:  # one team size per env instance, so that agents == possible_agents always
                cfg = dataclasses.replace(cfg, n_followers=int(np.random.default_rng(int(team_seed)).integers(lo, hi + 1)))
            if reward_spec is not None:
                cfg = dataclasses.replace(cfg, reward=reward_spec)
            self._random = cfg
            template = random_scenario(np.random.default_rng(0), self._random)
        else:
            if knobs:
                raise TypeError(f"unexpected keyword arguments {sorted(knobs)}: generator knobs apply to 'random' only")
            template = load_scenario(scenario)  # a Scenario object is checked as a file would be
            if reward_spec is not None:
                template = dataclasses.replace(template, reward=reward_spec)
        self._fixed = template if self._random is None else None
        self.render_mode = render_mode
        self.action_type = action_type
        self.max_cycles = max_cycles
        self.terminate_on_collision = terminate_on_collision
        self.reward_spec: RewardSpec = template.reward
        #: The step at which every episode is truncated (``world.max_time / dt``, or ``max_cycles`` if smaller).
        self.max_steps: int = _step_limit(template.world.max_time, template.world.dt, max_cycles)
        self.capacity = self._capacity(template)
        self.sensors = template.sensors
        self.scenario_name = str(scenario) if self._random else template.name
        self._obs = ObservationBuilder(self.sensors, self.capacity)
        self.obs_layout = self._obs.layout
        self.state_layout = self._obs.state_layout

        self.possible_agents = [f"follower_{i}" for i in range(self.capacity.max_followers)]
        self._agent_index = {a: i for i, a in enumerate(self.possible_agents)}
        obs_space = gymnasium.spaces.Box(self._obs.low, self._obs.high, dtype=np.float32)
        self.observation_spaces = {a: _clone_space(obs_space) for a in self.possible_agents}
        self.action_spaces = {a: self._make_action_space() for a in self.possible_agents}
        self.state_space = gymnasium.spaces.Box(
            -STATE_LIMIT, STATE_LIMIT, (self._obs.state_size,), dtype=np.float32
        )
        # One frame per control step: 1 / dt (2 on paper_cbs_switch's dt = 0.5 s), never 0.
        self.metadata = {**self.metadata, "render_fps": max(1, int(round(1.0 / template.world.dt)))}
        self.termination: str | None = None
        self.terminal_contacts: tuple[Contact, ...] = ()

        self.agents: list[str] = []
        self._rng: np.random.Generator | None = None
        self._world: World | None = None
        self._state: WorldState | None = None
        self._metrics = EpisodeMetrics()
        self._renderer: Any = None
        self._warned_clip = False
        self._static_cache: dict[int, StaticMap] = {}

    # ------------------------------------------------------------------ spaces
    def observation_space(self, agent: str) -> gymnasium.spaces.Space:
        return self.observation_spaces[agent]

    def action_space(self, agent: str) -> gymnasium.spaces.Space:
        return self.action_spaces[agent]

    def _make_action_space(self) -> gymnasium.spaces.Space:
        if self.action_type == "discrete":
            return gymnasium.spaces.Discrete(1 + len(PRIMITIVE_ANGLES_DEG))
        return gymnasium.spaces.Box(-1.0, 1.0, (2,), dtype=np.float32)

    def _capacity(self, template: Scenario) -> Capacity:
        if self._random is None:
            scn = template
            return Capacity(
                max_followers=scn.robots.count,
                max_humans=len(scn.humans),
                world_size=scn.world.size,
                max_time=scn.world.max_time,
                speed_limit=max([scn.robots.max_speed, scn.leader.speed, *(h.top_speed for h in scn.humans)]),
            )
        cfg = self._random
        return Capacity(
            max_followers=cfg.n_followers[1],  # type: ignore[index]
            max_humans=cfg.n_humans[1],  # type: ignore[index]
            world_size=cfg.resolved_world_size(),
            max_time=cfg.max_time,
            speed_limit=max(cfg.max_speed, cfg.leader_speed, cfg.top_human_speed()),
        )

    # ------------------------------------------------------------------ episode
    @property
    def scenario(self) -> Scenario:
        """The scenario of the current episode (the template before the first reset)."""
        if self._world is not None:
            return self._world.scenario
        if self._fixed is not None:
            return self._fixed
        assert self._random is not None
        return random_scenario(np.random.default_rng(0), self._random)

    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        self._start(seed)
        obs = self._obs.build(self._state)  # type: ignore[arg-type]
        observations = {a: obs[i] for i, a in enumerate(self.agents)}
        zeros = np.zeros(self._n)
        infos = self._infos(self._prev_dist, {t: zeros for t in REWARD_TERMS}, np.zeros((self._n, len(CONTACT_GROUPS))), False)
        if self.render_mode == "human":
            self.render()
        return observations, infos

    def _start(self, seed: int | None, drawn: Scenario | None = None) -> None:
        """Everything :meth:`reset` does but the observations and infos (the batched engine's reset).
        ``drawn``: this episode's random scenario, already drawn from this env's generator (which has
        been moved past the draw: :class:`swarm_env.vector.scenario_prefetch.ScenarioPrefetcher`)."""
        if seed is not None and (isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0):
            raise ValueError(f"seed must be None or an integer >= 0, got {seed!r}")
        if seed is not None or self._rng is None:
            seq = np.random.SeedSequence(seed)
            env_seq, space_seq = seq.spawn(2)
            self._rng = np.random.default_rng(env_seq)
            space_seeds = space_seq.generate_state(len(self.possible_agents))
            for agent, s in zip(self.possible_agents, space_seeds):
                self.action_spaces[agent].seed(int(s))
        scn = drawn if drawn is not None else (
            random_scenario(self._rng, self._random) if self._random is not None else self._fixed)
        assert scn is not None
        self._world = World(scn, self._static_for(scn))
        assert scn.robots.count == len(self.possible_agents)  # fixed teams (see the class docstring)
        self.agents = list(self.possible_agents)
        self._n = scn.robots.count
        self.termination = None
        self.terminal_contacts = ()
        self._speed = np.array([scn.robots.max_speed, scn.robots.max_turn_rate])
        self._state = self._world.snapshot()
        self._prev_dist = slot_distance(self._state)
        self._prev_action = np.zeros((self._n, 2))
        self._metrics = EpisodeMetrics()
        self._metrics.start(self._state)
        if self._renderer is not None:
            self._renderer.reset()
            self._renderer.record(self._state)

    def _static_for(self, scn: Scenario) -> StaticMap:
        if self._fixed is not None:  # one map for every episode of a fixed scenario
            key = 0
            if key not in self._static_cache:
                self._static_cache[key] = StaticMap.from_obstacles(scn.world.size, scn.obstacles)
            return self._static_cache[key]
        return StaticMap.from_obstacles(scn.world.size, scn.obstacles)

    def step(self, actions: dict[str, Any]) -> tuple[dict, dict, dict, dict, dict]:
        if self._world is None or self._state is None:
            raise RuntimeError("call reset() before step()")
        if not self.agents:
            raise RuntimeError("the episode is over: call reset() before step()")
        norm = self.normalised_actions(actions)
        agents = self.agents
        t0 = time.perf_counter()
        out = self._advance(norm)
        obs = self._obs.build(out.state)
        infos = self._infos(out.dist, out.table, out.touching, out.collided)
        self._account(out, time.perf_counter() - t0)
        observations = dict(zip(agents, obs))  # row views of one fresh array
        rewards = dict(zip(agents, out.reward.tolist()))  # Python floats
        terminations = dict.fromkeys(agents, out.terminated)
        truncations = dict.fromkeys(agents, out.truncated)
        if self.render_mode == "human":
            self.render()
        return observations, rewards, terminations, truncations, infos

    def _advance(self, norm: np.ndarray) -> StepOutcome:
        """One step of everything but the observations and the metrics: the physics with the
        ``(N, 2)`` normalised actions ``norm``, the rewards and the episode end. :meth:`step` and
        the batched engine (:mod:`swarm_env.vector.engine`) both call it, then :meth:`_account`."""
        assert self._world is not None
        self._world.step(norm * self._speed)
        state = self._world.snapshot()
        self._state = state
        touching = touching_per_follower(state)
        dist, table, reward = reward_table(state, state.scenario.reward, self._prev_dist, norm, self._prev_action, touching)
        self._prev_dist, self._prev_action = dist, norm
        settled = bool((dist <= state.scenario.world.settle_tolerance).all())
        collided = self.terminate_on_collision and bool(touching.any())
        terminated = bool((state.leader_done and settled) or collided)
        truncated = bool(not terminated and state.step >= self.max_steps)
        return StepOutcome(state, reward, table, dist, touching, collided, terminated, truncated)

    def _account(self, out: StepOutcome, wall_time: float) -> None:
        """Metrics, episode bookkeeping and the renderer's record of the step :meth:`_advance` made."""
        self._metrics.update(out.state, wall_time, out.dist)
        self._close_step(out.state, out.terminated, out.truncated, out.collided)

    def _close_step(self, state: WorldState, terminated: bool, truncated: bool, collided: bool) -> None:
        """The episode bookkeeping of :meth:`_account` after the metrics (the batched engine, which
        updates the metrics of all its worlds at once, calls it for the worlds that need it)."""
        self._metrics.terminated = terminated
        if terminated or truncated:
            self.termination = "collision" if collided else "formation" if terminated else "time_limit"
            if collided:
                self.terminal_contacts = tuple(c for c in state.touching if c.robot != LEADER_ID)
            self.agents = []
        if self._renderer is not None:
            self._renderer.record(state)

    def _infos(self, dist: np.ndarray, terms: dict[str, np.ndarray] | np.ndarray, touching: np.ndarray,
               collided: bool) -> dict:
        """Per-agent infos; reset and step infos have the same keys (see the class docstring)."""
        columns = [c.tolist() for c in info_columns(dist, terms, touching, collided)]
        return {a: dict(zip(_INFO_KEYS, row)) for a, row in zip(self.agents, zip(*columns))}

    def normalised_actions(self, actions: dict[str, Any]) -> np.ndarray:
        """Validate an action dict of the live agents and return it as ``(N, 2)`` normalised
        ``(v, omega)`` in ``[-1, 1]`` (rows in ``env.agents`` order; discrete primitives mapped to
        their twist), what :meth:`step` applies. Raises ``ValueError`` as :meth:`step` does."""
        if not isinstance(actions, dict):
            raise ValueError(f"actions must be a dict agent -> action, got {type(actions).__name__}")
        agents = self.agents
        if len(actions) != len(agents) or not all(a in actions for a in agents):
            unknown = set(actions) - set(agents)
            if unknown:
                raise ValueError(f"actions for agents not in env.agents: {sorted(unknown)}")
            missing = [a for a in agents if a not in actions]
            if missing:
                raise ValueError(f"missing actions for agents {missing}")
        if self.action_type == "continuous":
            # Common case first: one conversion of all actions; anything unusual (a bad shape
            # or value) goes through the per-agent checks below for a precise message.
            try:
                out = np.array([actions[a] for a in agents], dtype=np.float64)
            except (TypeError, ValueError):
                out = None
            if out is not None and out.shape == (self._n, 2) and np.isfinite(out).all():
                return self._clip_actions(out)
        out = np.zeros((self._n, 2))
        if self.action_type == "discrete":
            ks = []
            for a in self.agents:
                k = actions[a]
                if isinstance(k, np.ndarray) and k.size == 1:
                    k = k.item()
                if isinstance(k, (bool, np.bool_)) or not isinstance(k, (int, np.integer)) or not 0 <= k <= len(
                    PRIMITIVE_ANGLES_DEG
                ):
                    raise ValueError(f"{a}: discrete action must be an int in [0, {len(PRIMITIVE_ANGLES_DEG)}], got {k!r}")
                ks.append(int(k))
            return self.primitive_actions(np.array(ks))
        for i, a in enumerate(self.agents):
            try:
                arr = np.asarray(actions[a], dtype=np.float64)
            except (TypeError, ValueError) as exc:
                raise ValueError(f"{a}: action must be 2 numbers (v, omega) in [-1, 1], got {actions[a]!r}") from exc
            if arr.shape != (2,):
                raise ValueError(f"{a}: action must have shape (2,), got shape {arr.shape}")
            if not np.all(np.isfinite(arr)):
                raise ValueError(f"{a}: action must be finite, got {arr.tolist()}")
            out[i] = arr
        return self._clip_actions(out)

    def primitive_actions(self, k: np.ndarray) -> np.ndarray:
        """``(N, 2)`` normalised twists of the discrete motion primitives ``k`` ``(N,)`` (ints in
        ``[0, 9]``, already checked): 0 stops, ``k > 0`` drives at full speed turning by
        ``PRIMITIVE_ANGLES_DEG[k - 1]`` over one primitive duration."""
        return primitive_table(float(self._speed[1]))[k]

    def _clip_actions(self, out: np.ndarray) -> np.ndarray:
        self._warned_clip = clip_to_action_space(out, self._warned_clip, stacklevel=5)
        return out

    # ------------------------------------------------------------------ extras
    def state(self) -> np.ndarray:
        if self._state is None:
            raise RuntimeError("call reset() before state()")
        return self._obs.state_vector(self._state)

    def world_state(self) -> WorldState:
        """The current privileged :class:`~swarm_env.state.WorldState` (for scripted experts)."""
        if self._state is None:
            raise RuntimeError("call reset() before world_state()")
        return self._state

    def episode_metrics(self) -> dict[str, Any]:
        """Metrics of the current (or just finished) episode; see :mod:`swarm_env.scoring.metrics`."""
        if self._state is None:
            raise RuntimeError("call reset() before episode_metrics()")
        out: dict[str, Any] = {"scenario": self._state.scenario.name, **self._metrics.result()}
        out["termination"] = self.termination
        if self.termination == "collision":
            out["terminal_contacts"] = [dataclasses.asdict(c) for c in self.terminal_contacts]
        return out

    def render(self, mode: str | None = None) -> np.ndarray | None:
        """Render the current state in ``render_mode`` (set at construction, PettingZoo style).

        ``mode`` exists only for callers that pass the mode again (RLlib's PettingZoo wrapper
        calls ``render(render_mode)``); it must then equal ``render_mode``.
        """
        if mode is not None and mode != self.render_mode:
            raise ValueError(f"render mode {mode!r} differs from the env's render_mode {self.render_mode!r}, set at construction")
        if self.render_mode is None:
            gymnasium.logger.warn("render() called with render_mode=None; pass render_mode to the constructor")
            return None
        if self._state is None:
            raise RuntimeError("call reset() before render()")
        if self._renderer is None:
            self._renderer = Renderer(self.render_mode, self._state.scenario)
            self._renderer.record(self._state)
        elif self._renderer.scenario is not self._state.scenario:
            self._renderer.close()
            self._renderer = Renderer(self.render_mode, self._state.scenario)
            self._renderer.record(self._state)
        return self._renderer.render(self._state)

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


def clip_to_action_space(actions: np.ndarray, warned: bool, stacklevel: int) -> bool:
    """Clip normalised ``actions`` to ``[-1, 1]`` in place, warning the first time (``warned``
    False) that something was clipped. Returns whether the warning has been given now. The rule of
    :meth:`SwarmEnv.step` and of the batched engine (:mod:`swarm_env.vector.engine`)."""
    if np.abs(actions).max(initial=0.0) > 1.0:
        if not warned:
            warnings.warn("actions outside [-1, 1] are clipped to the action space", stacklevel=stacklevel)
            warned = True
        np.clip(actions, -1.0, 1.0, out=actions)
    return warned


@functools.lru_cache(maxsize=32)
def primitive_table(max_turn_rate: float) -> np.ndarray:
    """``(10, 2)`` normalised ``(v, omega)`` of each discrete action: 0 stops; ``k > 0`` drives at
    full speed turning by ``PRIMITIVE_ANGLES_DEG[k - 1]`` over one primitive duration
    ``T_p = 48 deg / max_turn_rate`` (so the sharpest primitive turns at the rate limit)."""
    duration = math.radians(max(abs(a) for a in PRIMITIVE_ANGLES_DEG)) / max_turn_rate
    out = np.zeros((1 + len(PRIMITIVE_ANGLES_DEG), 2))
    for k, angle in enumerate(PRIMITIVE_ANGLES_DEG, 1):
        out[k] = (1.0, math.radians(angle) / duration / max_turn_rate)
    out.flags.writeable = False  # cached: shared by every caller
    return out


@dataclasses.dataclass(slots=True)  # not frozen: its __init__ is a fifth of a frozen one's, once per world-step
class StepOutcome:
    """What one step produced besides the observations (see :meth:`SwarmEnv._advance`)."""

    state: WorldState
    reward: np.ndarray  # (N,)
    table: np.ndarray  # (len(REWARD_TERMS), N): each weighted reward term, in REWARD_TERMS order
    dist: np.ndarray  # (N,) slot distances (m)
    touching: np.ndarray  # (N, len(CONTACT_GROUPS)) bodies in touch during the step
    collided: bool  # the step ended the episode by a collision (terminate_on_collision)
    terminated: bool
    truncated: bool

    @property
    def terms(self) -> dict[str, np.ndarray]:
        """``{term: (N,)}`` of :data:`~swarm_env.scoring.rewards.REWARD_TERMS` (rows of ``table``)."""
        return dict(zip(REWARD_TERMS, self.table))


_INFO_KEYS = (*INFO_REWARD_KEYS, "slot_distance", *INFO_CONTACT_KEYS, "collision_terminated")


def info_columns(dist: np.ndarray, terms: dict[str, np.ndarray] | np.ndarray, touching: np.ndarray,
                 collided: bool) -> list[np.ndarray]:
    """The per-agent infos of a step as ``(N,)`` arrays, one per key of ``_INFO_KEYS`` in order:
    reward terms and slot distance (float64), contacts per group (int64), the collision flag (bool).
    ``terms``: ``{term: (N,)}`` or the ``(len(REWARD_TERMS), N)`` table of the terms in order."""
    columns = [terms[t] for t in REWARD_TERMS] if isinstance(terms, dict) else list(terms)
    columns.append(dist)
    columns += list(touching.T.astype(np.int64))
    columns.append(np.full(len(dist), collided))
    return columns


def env_kwargs_for(scenario: Any, kwargs: Mapping[str, Any]) -> dict[str, Any]:
    """``kwargs`` as they apply to ``scenario``: generator knobs (the fields of
    :class:`~swarm_env.scenarios.generator.RandomScenarioConfig`) are kept for ``"random"``
    and its families (``"random:<family>"``) only, everything else (``max_cycles``, ``reward``, ``terminate_on_collision``, ...)
    for every scenario. What ``swarm-env run/evaluate --env KEY=VALUE`` use, so one
    set of options can be applied to a list of scenarios."""
    if is_generated(scenario):
        return dict(kwargs)
    knobs = {f.name for f in dataclasses.fields(RandomScenarioConfig)}
    return {k: v for k, v in kwargs.items() if k not in knobs}


def _reward_spec(reward: RewardSpec | Mapping[str, Any] | str | None) -> RewardSpec | None:
    """``SwarmEnv(reward=...)``: a preset name, a :class:`RewardSpec`, a mapping of its fields, or None."""
    if reward is None or isinstance(reward, RewardSpec):
        return reward
    if isinstance(reward, str):
        if reward not in REWARD_PRESETS:
            raise ValueError(f"reward must be one of {sorted(REWARD_PRESETS)}, a RewardSpec or a mapping, got {reward!r}")
        return REWARD_PRESETS[reward]
    if isinstance(reward, Mapping):
        return _parse_reward("reward=", reward)
    raise ValueError(f"reward must be one of {sorted(REWARD_PRESETS)}, a RewardSpec or a mapping, got {reward!r}")


def _step_limit(max_time: float, dt: float, max_cycles: int | None) -> int:
    steps = int(math.floor(max_time / dt + 1e-9))
    return steps if max_cycles is None else min(steps, max_cycles)


def _clone_space(space: gymnasium.spaces.Box) -> gymnasium.spaces.Box:
    dtype: Any = space.dtype  # (gymnasium's stubs type Box.dtype more loosely than its argument)
    return gymnasium.spaces.Box(space.low.copy(), space.high.copy(), dtype=dtype)
