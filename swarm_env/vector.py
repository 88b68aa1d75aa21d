"""The batched engine: M worlds of one scenario family stepped by one call, arrays in and out.

:class:`SwarmVectorEnv` holds ``M`` :class:`~swarm_env.env.SwarmEnv` worlds (each with its own
pymunk space, generator and metrics) and exposes them as one environment with a leading batch
axis, the shape TorchRL/BenchMARL (``batch_size=[M]``), SB3's ``VecEnv`` (see
:mod:`baselines.vec_env`) and hand-written PPO loops want::

    venv = SwarmVectorEnv("random", num_envs=64)
    obs, infos = venv.reset(seed=0)                  # obs: (M, N, obs_dim) float32
    obs, rew, term, trunc, infos = venv.step(actions)  # actions: (M, N, 2) in [-1, 1]

What is batched and what is not: the lidar of all ``M x N`` followers is one call of the compiled
kernel (:mod:`swarm_env.lidar`), the observations, rewards and infos come back as arrays, and no
per-agent dicts are built. The physics stays pymunk, one space per world, stepped world after
world in this process. Each world runs exactly the code of a ``SwarmEnv`` (``_advance``,
``_account``) and the same lidar kernel, so world ``m`` is **bitwise equal** to a ``SwarmEnv``
reset with ``seed + m`` and given the same actions (tested on every built-in scenario and 50
``random`` seeds in ``tests/test_vector.py``).

Contract:

* **Fixed teams**: every world has the same ``N`` (``possible_agents``); for ``random`` with an
  ``n_followers`` range, each world's team size is drawn from ``team_seed`` like a ``SwarmEnv``,
  so pass a fixed ``n_followers`` (or one ``team_seed``) to get one ``N``.
* **Seeding**: ``reset(seed=s)`` resets world ``m`` with ``s + m`` (a list gives one seed per
  world); ``reset()`` without a seed continues each world's generator.
* **Auto-reset in the same step** (SB3's and Gymnasium's ``SAME_STEP`` mode): when world ``m``'s
  episode ends, ``terminated[m]`` or ``truncated[m]`` is ``True``, ``obs[m]`` is already the first
  observation of its next episode (reset without a seed: its generator continues), and
  ``infos["final_obs"][m]`` holds the last observation of the finished one, with
  ``infos["_final"][m] = True`` and ``infos["final_metrics"][m]`` its
  :meth:`~swarm_env.env.SwarmEnv.episode_metrics`.
* **Infos** are arrays ``(M, N)`` under the keys of a ``SwarmEnv``'s per-agent infos
  (``reward_<term>``, ``slot_distance``, ``contacts_<kind>``, ``collision_terminated``).

The module imports no torch (workers and engines stay light; see DESIGN.md).
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Sequence
from typing import Any

import gymnasium
import numpy as np

from swarm_env.env import _INFO_KEYS, StepOutcome, SwarmEnv, info_columns
from swarm_env.lidar import PackedMaps
from swarm_env.rewards import CONTACT_GROUPS, REWARD_TERMS
from swarm_env.state import WorldState

__all__ = ["SwarmVectorEnv", "INFO_KEYS"]

#: The per-agent info keys, each an ``(M, N)`` array in :meth:`SwarmVectorEnv.step`'s infos.
INFO_KEYS = _INFO_KEYS


class SwarmVectorEnv:
    """``num_envs`` worlds of ``scenario`` stepped together (see the module docstring).

    Args:
        scenario: as for :class:`~swarm_env.env.SwarmEnv` (a built-in name, a YAML path, a
            ``Scenario`` or ``"random"``).
        num_envs: the number of worlds ``M`` (>= 1).
        **kwargs: :class:`~swarm_env.env.SwarmEnv` keyword arguments, the same for every world
            (``render_mode`` is not supported: render a world with ``venv.envs[m]``).
    """

    def __init__(self, scenario: Any = "random", num_envs: int = 8, **kwargs: Any) -> None:
        if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
            raise ValueError(f"num_envs must be an int >= 1, got {num_envs!r}")
        if kwargs.get("render_mode") is not None:
            raise ValueError("SwarmVectorEnv does not render; render one world with venv.envs[m] instead")
        self._init_from([SwarmEnv(scenario, **kwargs) for _ in range(int(num_envs))])

    @classmethod
    def from_envs(cls, envs: Sequence[SwarmEnv]) -> "SwarmVectorEnv":
        """Batch existing :class:`~swarm_env.env.SwarmEnv` instances (fresh or not; they are
        reset by :meth:`reset`). They must share ``possible_agents``, spaces and action type."""
        self = cls.__new__(cls)
        self._init_from(list(envs))
        return self

    def _init_from(self, envs: list[SwarmEnv]) -> None:
        if not envs:
            raise ValueError("SwarmVectorEnv needs at least one world")
        for e in envs:
            if not isinstance(e, SwarmEnv):
                raise TypeError(f"SwarmVectorEnv batches SwarmEnv instances, got {type(e).__name__}")
        first = envs[0]
        for m, e in enumerate(envs[1:], 1):
            if e.possible_agents != first.possible_agents:
                raise ValueError(f"world {m} has {len(e.possible_agents)} followers, world 0 has "
                                 f"{len(first.possible_agents)}: every world needs the same team (fixed n_followers)")
            if e.action_type != first.action_type or e._obs.size != first._obs.size or e.sensors != first.sensors:
                raise ValueError(f"world {m} differs from world 0 in action type or sensors")
        self.envs = envs
        self.num_envs = len(envs)
        self.possible_agents = list(first.possible_agents)
        self.num_agents = len(self.possible_agents)
        self.action_type = first.action_type
        self.single_observation_space = first.observation_space(self.possible_agents[0])
        self.single_action_space = first.action_space(self.possible_agents[0])
        self.state_space = first.state_space
        self.metadata = first.metadata
        self._maps: tuple[list[int], PackedMaps] | None = None  # (ids of the packed StaticMaps, packing)
        self._warned_clip = False
        self._live = False

    # ------------------------------------------------------------------ episode
    def reset(self, seed: int | Sequence[int] | None = None) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Reset every world; ``seed``: ``s`` gives world ``m`` the seed ``s + m``, a sequence one
        seed per world, ``None`` continues each world's generator. Returns ``obs`` ``(M, N, D)``
        and the reset infos (zeros, the step infos' keys)."""
        seeds = self._seeds(seed)
        for env, s in zip(self.envs, seeds):
            env.reset(seed=s)
        self._live = True
        states = [e._state for e in self.envs]
        obs = self._observe(states)  # type: ignore[arg-type]
        return obs, self._reset_infos()

    def _reset_infos(self) -> dict[str, np.ndarray]:
        """The reset infos of a ``SwarmEnv`` (zero reward terms and contacts, the slot distances)."""
        n = self.num_agents
        zeros = np.zeros(n)
        terms = dict.fromkeys(REWARD_TERMS, zeros)
        per_world = [info_columns(e._prev_dist, terms, np.zeros((n, len(CONTACT_GROUPS))), False) for e in self.envs]
        return {key: np.stack([cols[k] for cols in per_world]) for k, key in enumerate(INFO_KEYS)}

    def _seeds(self, seed: int | Sequence[int] | None) -> list[int | None]:
        m = self.num_envs
        if seed is None:
            return [None] * m
        if isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
            return [int(seed) + k for k in range(m)]
        seeds = list(seed)  # type: ignore[arg-type]
        if len(seeds) != m or not all(isinstance(s, (int, np.integer)) and not isinstance(s, bool) for s in seeds):
            raise ValueError(f"seed must be None, an int or {m} ints (one per world), got {seed!r}")
        return [int(s) for s in seeds]

    def step(self, actions: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """Step every world with ``actions`` (``(M, N, 2)`` in ``[-1, 1]``, or ``(M, N)`` ints for
        ``action_type="discrete"``). Returns ``obs`` ``(M, N, D)`` float32, ``rewards`` ``(M, N)``
        float64, ``terminated`` and ``truncated`` ``(M,)`` bool, and the infos (module docstring)."""
        if not self._live:
            raise RuntimeError("call reset() before step()")
        norm = self._normalised(actions)
        m_worlds, n = self.num_envs, self.num_agents
        outcomes: list[StepOutcome] = []
        t0 = time.perf_counter()
        for env, act in zip(self.envs, norm):
            outcomes.append(env._advance(act))
        states = [o.state for o in outcomes]
        obs = self._observe(states)
        wall = (time.perf_counter() - t0) / m_worlds  # the batch's wall time, shared equally by the worlds
        rewards = np.stack([o.reward for o in outcomes])
        terminated = np.array([o.terminated for o in outcomes])
        truncated = np.array([o.truncated for o in outcomes])
        per_world = [info_columns(o.dist, o.terms, o.touching, o.collided) for o in outcomes]
        infos: dict[str, Any] = {key: np.stack([cols[k] for cols in per_world]) for k, key in enumerate(INFO_KEYS)}
        for env, out in zip(self.envs, outcomes):
            env._account(out, wall)
        done = terminated | truncated
        if done.any():
            infos["_final"] = done
            infos["final_obs"] = obs.copy()
            infos["final_metrics"] = [None] * m_worlds
            for m in np.flatnonzero(done).tolist():
                infos["final_metrics"][m] = self.envs[m].episode_metrics()
                self.envs[m].reset()
            obs[done] = self._observe([self.envs[m]._state for m in np.flatnonzero(done).tolist()])  # type: ignore[misc]
        assert obs.shape[:2] == (m_worlds, n)
        return obs, rewards, terminated, truncated, infos

    def _normalised(self, actions: Any) -> np.ndarray:
        m, n = self.num_envs, self.num_agents
        if self.action_type == "discrete":
            k = np.asarray(actions)
            if k.shape != (m, n) or not np.issubdtype(k.dtype, np.integer) or k.min() < 0 or k.max() >= self.single_action_space.n:
                raise ValueError(f"discrete actions must be ({m}, {n}) ints in [0, {self.single_action_space.n - 1}]"
                                 f", got shape {k.shape} dtype {k.dtype}")
            return np.stack([env.primitive_actions(row) for env, row in zip(self.envs, k)])
        try:
            a = np.array(actions, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"actions must be a ({m}, {n}, 2) array of numbers") from exc
        if a.shape != (m, n, 2):
            raise ValueError(f"actions must have shape ({m}, {n}, 2) (worlds, followers, (v, omega)), got {a.shape}")
        if not np.isfinite(a).all():
            bad = np.argwhere(~np.isfinite(a))[0]
            raise ValueError(f"actions must be finite: world {bad[0]}, follower {bad[1]} has {a[bad[0], bad[1]].tolist()}")
        if np.abs(a).max() > 1.0:
            if not self._warned_clip:
                warnings.warn("actions outside [-1, 1] are clipped to the action space", stacklevel=3)
                self._warned_clip = True
            np.clip(a, -1.0, 1.0, out=a)
        return a

    def _observe(self, states: Sequence[WorldState]) -> np.ndarray:
        """Observations ``(len(states), N, D)`` with one lidar call for all of them."""
        envs = self.envs if len(states) == self.num_envs else None
        builder = self.envs[0]._obs
        maps = self._packed(states) if envs is not None else None
        scans = builder.lidar(states, maps).reshape(len(states), self.num_agents, -1)
        return np.stack([builder.build(s, lidar=scan) for s, scan in zip(states, scans)])

    def _packed(self, states: Sequence[WorldState]) -> PackedMaps:
        """The static maps of all worlds packed for the lidar, repacked only when one changed."""
        ids = [id(s.static) for s in states]
        if self._maps is None or self._maps[0] != ids:
            self._maps = (ids, PackedMaps.of([s.static for s in states]))
        return self._maps[1]

    # ------------------------------------------------------------------ extras
    def state(self) -> np.ndarray:
        """``(M, state_dim)`` float32: each world's :meth:`~swarm_env.env.SwarmEnv.state`."""
        return np.stack([e.state() for e in self.envs])

    def world_states(self) -> list[WorldState]:
        """Each world's privileged :class:`~swarm_env.state.WorldState` (for scripted experts)."""
        return [e.world_state() for e in self.envs]

    def episode_metrics(self, m: int) -> dict[str, Any]:
        """World ``m``'s metrics of its current episode (finished ones come in ``final_metrics``)."""
        return self.envs[m].episode_metrics()

    def close(self) -> None:
        for e in self.envs:
            e.close()

    @property
    def observation_space(self) -> gymnasium.spaces.Box:
        """The batched observation space ``(M, N, D)``."""
        s = self.single_observation_space
        reps = (self.num_envs, self.num_agents, 1)
        return gymnasium.spaces.Box(np.tile(s.low, reps), np.tile(s.high, reps), dtype=np.float32)

