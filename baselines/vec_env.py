"""Our SB3 bridge: the batched engine's M worlds as M x N sub-environments with parameter sharing.

:class:`SwarmVecEnv` is a stable-baselines3 :class:`~stable_baselines3.common.vec_env.VecEnv`
over a :class:`swarm_env.vector.engine.SwarmVectorEnv` of ``M`` worlds: sub-environment ``m * N + i``
is agent ``follower_i`` of world ``m`` (``N = len(possible_agents)``). One policy network acts
for every follower (parameter sharing); SB3 sees ``M * N`` ordinary single-agent environments.
The engine steps all worlds with one call (one lidar kernel call for all followers, arrays
throughout); this module only reshapes its arrays and builds the per-sub-env info dicts SB3 reads.

Contract (what SB3's algorithms rely on, and what SuperSuit gets wrong; see docs/baselines.md, "The SB3 bridge"):

* **Worlds are built, not cloned**: each is ``env_fn()`` (a :class:`~swarm_env.env.SwarmEnv`,
  or a :class:`~swarm_env.wrappers.SafetyShield` of one); no state or RNG is shared.
* **Seeding goes through SB3's plumbing**: ``PPO(seed=s)`` calls ``vec_env.seed(s)``, which
  stores ``s + k`` for sub-env ``k``; at the next :meth:`reset` world ``m`` is reset with the
  seed of its first sub-env, ``s + m * N``, so worlds are distinct and the run is reproducible.
  Later auto-resets pass no seed: each world's own generator continues.
* **Auto-reset with correct truncation**: when a world's episode ends, each of its agents
  reports ``done=True`` with ``infos[k]["terminal_observation"]`` (the last observation) and
  ``infos[k]["TimeLimit.truncated"]`` (``True`` when the episode was cut by its time limit
  rather than terminated), so SB3 bootstraps truncated episodes from the terminal
  observation. The observation returned for that sub-env is the first of the next episode.
  ``infos[k]["episode"] = {"r", "l", "t"}`` carries the agent's return, length and wall time
  (SB3 logs ``rollout/ep_rew_mean`` from it).
* **Fixed teams**: swarm_env_v1 keeps ``env.agents == env.possible_agents``, so every sub-env
  carries a real follower in every step; worlds with different teams are refused.
* **Worker processes**: ``n_procs > 1`` spreads the worlds' physics over worker processes
  that import neither torch nor numba (``env_fn`` must then be picklable with cloudpickle,
  e.g. :class:`EnvFactory`). The results are identical to ``n_procs=1``.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import Any

import gymnasium
import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices, VecEnvStepReturn

from swarm_env.env import SwarmEnv
from swarm_env.vector.engine import EnvFactory, SwarmVectorEnv

EnvFn = Callable[[], SwarmEnv]

__all__ = ["EnvFactory", "SwarmVecEnv", "make_vec_env"]


class SwarmVecEnv(VecEnv):
    """``n_copies`` worlds of a :class:`SwarmEnv` as ``n_copies * N`` SB3 sub-environments.

    Args:
        env_fn: builds one world (called once per world, in the process that owns it).
        n_copies: number of worlds ``M``.
        n_procs: processes stepping the physics (1 = everything in this process); the worlds
            are split into ``n_procs`` contiguous blocks (:class:`swarm_env.vector.engine.SwarmVectorEnv`).

    The observation and action spaces are those of one agent. See the module docstring for
    seeding, truncation and fixed teams.
    """

    def __init__(self, env_fn: EnvFn, n_copies: int = 1, *, n_procs: int = 1) -> None:
        if not isinstance(n_copies, int) or n_copies < 1:
            raise ValueError(f"n_copies must be a positive int, got {n_copies!r}")
        if not isinstance(n_procs, int) or not 1 <= n_procs <= n_copies:
            raise ValueError(f"n_procs must be an int in [1, n_copies={n_copies}], got {n_procs!r}")
        self.engine = SwarmVectorEnv.from_factories([env_fn] * n_copies, n_procs=n_procs)
        self.n_copies = n_copies
        self.n_slots = self.engine.num_agents
        self.agent_names = list(self.engine.possible_agents)
        self.num_envs = n_copies * self.n_slots  # VecEnv.__init__ reads render_mode through get_attr
        super().__init__(self.num_envs, self.engine.single_observation_space, self.engine.single_action_space)
        self._returns = np.zeros((n_copies, self.n_slots))
        self._lengths = np.zeros(n_copies, dtype=np.int64)
        self._t_start = np.zeros(n_copies)
        self._actions: np.ndarray | None = None
        self.closed = False

    # ------------------------------------------------------------------ VecEnv API
    def reset(self) -> np.ndarray:
        seeds = [self._seeds[m * self.n_slots] for m in range(self.n_copies)]
        obs, infos = self.engine.reset(seed=seeds)
        self.reset_infos = _info_dicts(infos, self.num_envs)
        self._returns[:] = 0.0
        self._lengths[:] = 0
        self._t_start[:] = time.perf_counter()
        self._reset_seeds()
        self._reset_options()
        return obs.reshape(self.num_envs, -1)

    def step_async(self, actions: np.ndarray) -> None:
        actions = np.asarray(actions)
        if len(actions) != self.num_envs:
            raise ValueError(f"expected {self.num_envs} actions (one per sub-env), got {len(actions)}")
        self._actions = actions

    def step_wait(self) -> VecEnvStepReturn:
        if self._actions is None:
            raise RuntimeError("step_wait() called without step_async()")
        actions = self._actions.reshape(self.n_copies, self.n_slots, *self._actions.shape[1:])
        if self.engine.action_type == "discrete":
            actions = actions.reshape(self.n_copies, self.n_slots).astype(np.int64)
        self._actions = None
        obs, rewards, terminated, truncated, infos = self.engine.step(actions)
        self._returns += rewards
        self._lengths += 1
        done = terminated | truncated
        flat_infos = _info_dicts(infos, self.num_envs)
        now = time.perf_counter()
        for m in np.flatnonzero(done).tolist():
            for i in range(self.n_slots):
                k = m * self.n_slots + i
                flat_infos[k]["terminal_observation"] = infos["final_obs"][m, i]
                flat_infos[k]["TimeLimit.truncated"] = bool(truncated[m] and not terminated[m])
                flat_infos[k]["episode"] = {"r": float(self._returns[m, i]), "l": int(self._lengths[m]),
                                            "t": round(now - self._t_start[m], 6)}
            self._returns[m] = 0.0
            self._lengths[m] = 0
            self._t_start[m] = now
        return (obs.reshape(self.num_envs, -1), rewards.ravel().astype(np.float32),
                np.repeat(done, self.n_slots), flat_infos)

    def _copies_of(self, indices: VecEnvIndices) -> list[int]:
        return [k // self.n_slots for k in self._get_indices(indices)]

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        return self.engine.get_attr(attr_name, indices=self._copies_of(indices))

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        self.engine.set_attr(attr_name, value, indices=self._copies_of(indices))

    def env_method(self, method_name: str, *method_args: Any, indices: VecEnvIndices = None, **method_kwargs: Any) -> list[Any]:
        return self.engine.call(method_name, *method_args, indices=self._copies_of(indices), **method_kwargs)

    def env_is_wrapped(self, wrapper_class: type[gymnasium.Wrapper], indices: VecEnvIndices = None) -> list[bool]:
        return [False] * len(self._get_indices(indices))  # worlds are ParallelEnvs, not gymnasium wrappers

    def get_images(self) -> Sequence[np.ndarray | None]:
        frames = self.engine.call("render")
        return [frames[k // self.n_slots] for k in range(self.num_envs)]

    def close(self) -> None:
        if not self.closed:
            self.engine.close()
            self.closed = True


def _info_dicts(infos: dict[str, Any], count: int) -> list[dict[str, Any]]:
    """One dict per sub-env of the engine's ``(M, N)`` info arrays (Python scalars, as a ``SwarmEnv`` gives)."""
    keys = [k for k, v in infos.items() if isinstance(v, np.ndarray) and v.ndim == 2]
    columns = [infos[k].ravel().tolist() for k in keys]
    return [dict(zip(keys, row)) for row in zip(*columns)] if keys else [{} for _ in range(count)]


def make_vec_env(
    scenario: str = "random",
    n_copies: int = 4,
    *,
    n_procs: int = 1,
    seed: int | None = None,
    shield: bool = False,
    **env_kwargs: Any,
) -> SwarmVecEnv:
    """Build a :class:`SwarmVecEnv` of ``SwarmEnv(scenario, **env_kwargs)`` copies (each in a
    :class:`~swarm_env.wrappers.SafetyShield` with ``shield``).

    ``seed`` (optional) is passed to :meth:`SwarmVecEnv.seed` so the first reset is
    reproducible even without an SB3 algorithm doing it.
    """
    venv = SwarmVecEnv(EnvFactory(scenario, dict(env_kwargs), shield), n_copies, n_procs=n_procs)
    if seed is not None:
        venv.seed(seed)
    return venv
