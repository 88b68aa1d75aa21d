"""Our SB3 bridge: M copies of the parallel env as M x N sub-environments with parameter sharing.

:class:`SwarmVecEnv` is a stable-baselines3 :class:`~stable_baselines3.common.vec_env.VecEnv`
whose sub-environment ``m * N + i`` is agent ``follower_i`` of env copy ``m``
(``N = len(possible_agents)``). One policy network acts for every follower
(parameter sharing); SB3 sees ``M * N`` ordinary single-agent environments.

Contract (what SB3's algorithms rely on, and what SuperSuit gets wrong; see
DESIGN.md):

* **Copies are built, not cloned**: each copy is ``env_fn()``; no state or RNG is
  shared between copies.
* **Seeding goes through SB3's plumbing**: ``PPO(seed=s)`` calls
  ``vec_env.seed(s)``, which stores ``s + k`` for sub-env ``k``; at the next
  :meth:`reset` copy ``m`` is reset with the seed of its first sub-env,
  ``s + m * N``, so copies are distinct and the run is reproducible. Later
  auto-resets pass no seed: each copy's own generator continues.
* **Auto-reset with correct truncation**: when a copy's episode ends, each of
  its agents reports ``done=True`` with ``infos[k]["terminal_observation"]``
  (the last observation) and ``infos[k]["TimeLimit.truncated"]`` (``True``
  when the episode was cut by its time limit rather than terminated), so SB3
  bootstraps truncated episodes from the terminal observation. The
  observation returned for that sub-env is the first of the next episode.
  ``infos[k]["episode"] = {"r", "l", "t"}`` carries the agent's return, length
  and wall time (SB3 logs ``rollout/ep_rew_mean`` from it).
* **Fixed teams**: swarm_env_v1 keeps ``env.agents == env.possible_agents``
  after every reset, so every sub-env carries a real follower in every step
  (v0's padding slots are gone); a copy whose reset leaves an agent out raises
  ``RuntimeError``. Every copy must have the same ``possible_agents`` (for
  ``random`` with an ``n_followers`` range: the same ``team_seed``).
* **Subprocesses**: ``n_procs > 1`` spreads the copies over worker processes
  (``env_fn`` must then be picklable with cloudpickle, e.g. a
  :func:`functools.partial` or :class:`EnvFactory`). The results are identical to
  ``n_procs=1``: the same copies get the same seeds and the same actions.
"""

from __future__ import annotations

import multiprocessing as mp
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import cloudpickle
import gymnasium
import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices, VecEnvStepReturn

from swarm_env.env import SwarmEnv

EnvFn = Callable[[], SwarmEnv]


@dataclass(frozen=True)
class EnvFactory:
    """A picklable ``env_fn``: ``SwarmEnv(scenario, **kwargs)``.

    ``kwargs`` are :class:`~swarm_env.env.SwarmEnv` keyword arguments
    (``action_type``, ``max_cycles``, and for ``"random"`` the generator knobs).
    """

    scenario: str = "random"
    kwargs: dict[str, Any] = field(default_factory=dict)
    #: Wrap the env in :class:`swarm_env.wrappers.SafetyShield` (the learner acts through the VO safety layer).
    shield: bool = False

    def __call__(self) -> SwarmEnv:
        env = SwarmEnv(self.scenario, **self.kwargs)
        if self.shield:
            from swarm_env.wrappers import SafetyShield

            return SafetyShield(env)  # type: ignore[return-value]  (a ParallelEnv with SwarmEnv's attributes)
        return env


class _CopyBlock:
    """A few env copies stepped together; the logic shared by the in-process and subprocess paths."""

    def __init__(self, env_fns: Sequence[EnvFn]) -> None:
        self.envs = [fn() for fn in env_fns]
        first = self.envs[0]
        self.agents = list(first.possible_agents)
        for e in self.envs[1:]:
            if list(e.possible_agents) != self.agents:
                raise ValueError("every env copy must have the same possible_agents")
        self.n_slots = len(self.agents)
        self.obs_shape = first.observation_space(self.agents[0]).shape
        self._returns = np.zeros((len(self.envs), self.n_slots))
        self._lengths = np.zeros(len(self.envs), dtype=np.int64)
        self._t_start = [0.0] * len(self.envs)

    # Each method returns numpy arrays over the block's sub-envs, copy-major.
    def reset(self, seeds: Sequence[int | None], options: Sequence[dict]) -> tuple[np.ndarray, list[dict]]:
        obs = np.zeros((len(self.envs) * self.n_slots, *self.obs_shape), dtype=np.float32)
        infos: list[dict] = [{} for _ in range(len(obs))]
        for m, env in enumerate(self.envs):
            self._reset_copy(m, seeds[m], options[m] or None, obs, infos)
        return obs, infos

    def _reset_copy(self, m: int, seed: int | None, options: dict | None, obs: np.ndarray, infos: list[dict]) -> None:
        env = self.envs[m]
        observations, reset_infos = env.reset(seed=seed, options=options)
        self._returns[m] = 0.0
        self._lengths[m] = 0
        self._t_start[m] = time.perf_counter()
        if list(env.agents) != self.agents:
            raise RuntimeError(f"env copy {m} reset with agents {env.agents}, expected all of {self.agents}")
        base = m * self.n_slots
        for i, agent in enumerate(self.agents):
            obs[base + i] = observations[agent]
            infos[base + i] = dict(reset_infos[agent])

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict]]:
        n = len(self.envs) * self.n_slots
        obs = np.zeros((n, *self.obs_shape), dtype=np.float32)
        rewards = np.zeros(n, dtype=np.float32)
        dones = np.zeros(n, dtype=bool)
        infos: list[dict] = [{} for _ in range(n)]
        for m, env in enumerate(self.envs):
            base = m * self.n_slots
            act = {a: actions[base + i] for i, a in enumerate(self.agents)}
            observations, rew, term, trunc, step_infos = env.step(act)
            self._lengths[m] += 1
            episode_over = not env.agents
            for i, agent in enumerate(self.agents):
                k = base + i
                obs[k] = observations[agent]
                rewards[k] = rew[agent]
                self._returns[m, i] += rew[agent]
                info = dict(step_infos[agent])
                if episode_over:
                    dones[k] = True
                    info["terminal_observation"] = obs[k].copy()
                    info["TimeLimit.truncated"] = bool(trunc[agent] and not term[agent])
                    info["episode"] = {
                        "r": float(self._returns[m, i]),
                        "l": int(self._lengths[m]),
                        "t": round(time.perf_counter() - self._t_start[m], 6),
                    }
                infos[k] = info
            if episode_over:  # auto-reset: this copy's slots now hold the next episode's first observation
                self._reset_copy(m, None, None, obs, [{} for _ in range(n)])
        return obs, rewards, dones, infos

    def get_attr(self, name: str, copies: Sequence[int]) -> list[Any]:
        return [getattr(self.envs[m], name) for m in copies]

    def set_attr(self, name: str, value: Any, copies: Sequence[int]) -> None:
        for m in copies:
            setattr(self.envs[m], name, value)

    def env_method(self, name: str, copies: Sequence[int], args: tuple, kwargs: dict) -> list[Any]:
        return [getattr(self.envs[m], name)(*args, **kwargs) for m in copies]

    def render(self) -> list[np.ndarray | None]:
        return [env.render() for env in self.envs]

    def close(self) -> None:
        for env in self.envs:
            env.close()


def _worker(remote: Any, parent_remote: Any, payload: bytes) -> None:
    """Subprocess loop: build a block from pickled env_fns, then serve commands until 'close'."""
    parent_remote.close()
    block = _CopyBlock(cloudpickle.loads(payload))
    try:
        while True:
            cmd, data = remote.recv()
            if cmd == "close":
                block.close()
                remote.send(None)
                break
            remote.send(getattr(block, cmd)(*data))
    except (EOFError, KeyboardInterrupt):
        block.close()


class SwarmVecEnv(VecEnv):
    """``n_copies`` copies of a :class:`SwarmEnv` as ``n_copies * N`` SB3 sub-environments.

    Args:
        env_fn: builds one env copy (called once per copy, in the worker that owns it).
        n_copies: number of env copies ``M``.
        n_procs: worker processes (1 = everything in this process). Copies are split
            into ``n_procs`` contiguous blocks.
        start_method: multiprocessing start method for ``n_procs > 1`` (default
            ``"forkserver"`` where available, else ``"spawn"``: never ``fork``, which
            is unsafe once torch has started threads).

    The observation and action spaces are those of one agent. See the module
    docstring for seeding, truncation and fixed teams.
    """

    def __init__(self, env_fn: EnvFn, n_copies: int = 1, *, n_procs: int = 1, start_method: str | None = None) -> None:
        if not isinstance(n_copies, int) or n_copies < 1:
            raise ValueError(f"n_copies must be a positive int, got {n_copies!r}")
        if not isinstance(n_procs, int) or not 1 <= n_procs <= n_copies:
            raise ValueError(f"n_procs must be an int in [1, n_copies={n_copies}], got {n_procs!r}")
        probe = env_fn()
        agents = list(probe.possible_agents)
        obs_space = probe.observation_space(agents[0])
        act_space = probe.action_space(agents[0])
        probe.close()
        self.n_copies = n_copies
        self.n_slots = len(agents)
        self.agent_names = agents
        self.num_envs = n_copies * self.n_slots  # VecEnv.__init__ reads render_mode through get_attr

        bounds = np.linspace(0, n_copies, n_procs + 1).round().astype(int)
        self._blocks_copies = [list(range(bounds[p], bounds[p + 1])) for p in range(n_procs)]
        self._local: _CopyBlock | None = None
        self._remotes: list[Any] = []
        self._procs: list[Any] = []
        if n_procs == 1:
            self._local = _CopyBlock([env_fn] * n_copies)
        else:
            if start_method is None:
                start_method = "forkserver" if "forkserver" in mp.get_all_start_methods() else "spawn"
            ctx = mp.get_context(start_method)
            for copies in self._blocks_copies:
                remote, work_remote = ctx.Pipe()
                payload = cloudpickle.dumps([env_fn] * len(copies))
                proc = ctx.Process(target=_worker, args=(work_remote, remote, payload), daemon=True)
                proc.start()
                work_remote.close()
                self._remotes.append(remote)
                self._procs.append(proc)
        super().__init__(n_copies * self.n_slots, obs_space, act_space)
        self._actions: np.ndarray | None = None
        self.closed = False

    # ------------------------------------------------------------------ block dispatch
    def _call_all(self, cmd: str, per_block_args: list[tuple]) -> list[Any]:
        if self._local is not None:
            return [getattr(self._local, cmd)(*per_block_args[0])]
        for remote, args in zip(self._remotes, per_block_args):
            remote.send((cmd, args))
        return [remote.recv() for remote in self._remotes]

    def _slot_range(self, b: int) -> slice:
        copies = self._blocks_copies[b]
        return slice(copies[0] * self.n_slots, (copies[-1] + 1) * self.n_slots)

    # ------------------------------------------------------------------ VecEnv API
    def reset(self) -> np.ndarray:
        seeds = [self._seeds[m * self.n_slots] for m in range(self.n_copies)]
        options = [self._options[m * self.n_slots] for m in range(self.n_copies)]
        args = [([seeds[m] for m in c], [options[m] for m in c]) for c in self._blocks_copies]
        results = self._call_all("reset", args)
        obs = np.concatenate([r[0] for r in results])
        self.reset_infos = [info for r in results for info in r[1]]
        self._reset_seeds()
        self._reset_options()
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        actions = np.asarray(actions)
        if len(actions) != self.num_envs:
            raise ValueError(f"expected {self.num_envs} actions (one per sub-env), got {len(actions)}")
        self._actions = actions

    def step_wait(self) -> VecEnvStepReturn:
        if self._actions is None:
            raise RuntimeError("step_wait() called without step_async()")
        args = [(self._actions[self._slot_range(b)],) for b in range(len(self._blocks_copies))]
        self._actions = None
        results = self._call_all("step", args)
        obs = np.concatenate([r[0] for r in results])
        rewards = np.concatenate([r[1] for r in results])
        dones = np.concatenate([r[2] for r in results])
        infos = [info for r in results for info in r[3]]
        return obs, rewards, dones, infos

    def _copies_of(self, indices: VecEnvIndices) -> list[int]:
        return [k // self.n_slots for k in self._get_indices(indices)]

    def _per_copy(self, cmd: str, indices: VecEnvIndices, *extra: Any) -> list[Any]:
        """Run ``cmd`` on the copies behind ``indices``; one result per index, in order."""
        copies = self._copies_of(indices)
        wanted = sorted(set(copies))
        by_copy: dict[int, Any] = {}
        for b, block_copies in enumerate(self._blocks_copies):
            local = [m - block_copies[0] for m in wanted if m in block_copies]
            if not local:
                continue
            if self._local is not None:
                out = getattr(self._local, cmd)(*extra[:1], local, *extra[1:])
            else:
                self._remotes[b].send((cmd, (*extra[:1], local, *extra[1:])))
                out = self._remotes[b].recv()
            if out is not None:
                by_copy.update({block_copies[0] + j: v for j, v in zip(local, out)})
        return [by_copy.get(m) for m in copies]

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        return self._per_copy("get_attr", indices, attr_name)

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        copies = sorted(set(self._copies_of(indices)))
        for b, block_copies in enumerate(self._blocks_copies):
            local = [m - block_copies[0] for m in copies if m in block_copies]
            if not local:
                continue
            if self._local is not None:
                self._local.set_attr(attr_name, value, local)
            else:
                self._remotes[b].send(("set_attr", (attr_name, value, local)))
                self._remotes[b].recv()

    def env_method(self, method_name: str, *method_args: Any, indices: VecEnvIndices = None, **method_kwargs: Any) -> list[Any]:
        return self._per_copy("env_method", indices, method_name, method_args, method_kwargs)

    def env_is_wrapped(self, wrapper_class: type[gymnasium.Wrapper], indices: VecEnvIndices = None) -> list[bool]:
        return [False] * len(self._get_indices(indices))  # copies are bare ParallelEnvs

    def get_images(self) -> Sequence[np.ndarray | None]:
        frames = [f for r in self._call_all("render", [()] * len(self._blocks_copies)) for f in r]
        return [frames[k // self.n_slots] for k in range(self.num_envs)]

    def close(self) -> None:
        if self.closed:
            return
        if self._local is not None:
            self._local.close()
        for remote in self._remotes:
            try:
                remote.send(("close", ()))
                remote.recv()
            except (BrokenPipeError, EOFError):
                pass
        for proc in self._procs:
            proc.join(timeout=5)
        self.closed = True


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
