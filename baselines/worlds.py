"""The training worlds of a trainer on the batched engine, and how a checkpoint rebuilds them.

:class:`TrainingWorlds` wraps a :class:`~swarm_env.vector.engine.SwarmVectorEnv` and records what a checkpoint
needs to bring every world back as it is now: how its running episode began (the engine's
``episode_starts``: a seed, or the world generator's state) and every action it has executed since (an
action log of all worlds, step by step, trimmed as episodes end). The physics lives in pymunk and is
not saved; :meth:`TrainingWorlds.restore` rebuilds each world by resetting a fresh env as its episode
began and playing its actions again (the env is deterministic), then puts it in the engine
(:meth:`~swarm_env.vector.engine.SwarmVectorEnv.set_world`). Shared by :mod:`swarm_env_baselines.mappo` and
:mod:`swarm_env_baselines.sac`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from swarm_env.vector.engine import SwarmVectorEnv

__all__ = ["TrainingWorlds"]

#: Steps no running episode needs any more are dropped from the log in chunks of at least this many.
_TRIM = 256


class TrainingWorlds:
    """``factory()`` worlds stepped by one engine (``n_procs`` processes for their physics).

    Args:
        factory: builds one world (a picklable :class:`~swarm_env.vector.engine.EnvFactory`).
        n_worlds: the number of worlds ``M``.
        n_procs: worker processes of the engine (1: this process).
        prefetch: with ``n_procs = 1``, draw the next random worlds in a worker process while the worlds step
            (``SwarmVectorEnv(prefetch_scenarios=True)``): the same worlds bit for bit, without the wave of
            draws when the worlds that started together end together.
    """

    def __init__(self, factory: Callable[[], Any], n_worlds: int, n_procs: int = 1, prefetch: bool = True) -> None:
        self.factory = factory
        self.venv = SwarmVectorEnv.from_factories([factory] * n_worlds, n_procs=n_procs,
                                                  prefetch_scenarios=prefetch and n_procs == 1)
        self.m, self.n = n_worlds, self.venv.num_agents
        self.starts: list[dict[str, Any]] = [{} for _ in range(n_worlds)]
        self._log: list[np.ndarray] = []  # _log[i]: the (M, N, 2) actions of step _base + i
        self._base = 0
        self._begin = np.zeros(n_worlds, np.int64)  # the step each world's running episode began

    def reset(self, seed: int) -> np.ndarray:
        """Reset every world (world ``k`` with ``seed + k``); returns the observations ``(M, N, D)``."""
        obs, _ = self.venv.reset(seed=seed)
        self.began(list(range(self.m)))
        return obs

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """:meth:`SwarmVectorEnv.step <swarm_env.vector.engine.SwarmVectorEnv.step>`, with the actions logged and
        the worlds whose episode ended (and auto-reset) marked as beginning a new one."""
        out = self.venv.step(actions)
        self._log.append(np.array(actions, dtype=np.float32))
        ended = np.flatnonzero(out[2] | out[3]).tolist()
        if ended:
            self.began(ended)
        drop = int(self._begin.min()) - self._base
        if drop > _TRIM:
            del self._log[:drop]
            self._base += drop
        return out

    def began(self, worlds: list[int]) -> None:
        """The worlds ``worlds`` have just begun an episode (as the engine's ``episode_starts`` says)."""
        starts = self.venv.episode_starts()
        for k in worlds:
            self.starts[k] = starts[k]
        self._begin[worlds] = self._base + len(self._log)

    def episode_actions(self, k: int) -> np.ndarray:
        """``(steps, N, 2)``: every action world ``k`` executed in its running episode."""
        first = int(self._begin[k]) - self._base
        if first >= len(self._log):
            return np.zeros((0, self.n, 2), np.float32)
        return np.stack([a[k] for a in self._log[first:]])

    def checkpoint(self) -> tuple[dict[str, np.ndarray], list[dict[str, Any]]]:
        """``(arrays, episode starts)``: ``episode.<k>.actions`` for the worlds that have acted, and how each
        world's episode began (JSON values)."""
        arrays = {}
        for k in range(self.m):
            actions = self.episode_actions(k)
            if len(actions):
                arrays[f"episode.{k}.actions"] = actions
        return arrays, [dict(s) for s in self.starts]

    def restore(self, arrays: dict[str, np.ndarray], starts: list[dict[str, Any]], reset_seed: int,
                on_step: Callable[[int, Any, dict[str, np.ndarray], int], None] | None = None) -> None:
        """Rebuild every world from a :meth:`checkpoint` (``arrays`` as numpy arrays) and put it in the engine.

        ``on_step(k, env, obs, t)`` is called after world ``k``'s reset (``t`` 0) and after each action played
        again (``t`` the steps played: the trainer's experts and inputs follow the world through its episode). ``reset_seed``: the engine is
        first reset with it, so that every world has an episode while the others are replaced."""
        if len(starts) != self.m:
            raise ValueError(f"the checkpoint has {len(starts)} worlds, this run {self.m}")
        self.venv.reset(seed=reset_seed)
        agents = self.venv.possible_agents
        played = [arrays.get(f"episode.{k}.actions", np.zeros((0, self.n, 2), np.float32)) for k in range(self.m)]
        longest = max(len(p) for p in played)
        # The log with each world's episode right-aligned at its end (earlier rows are never read for it).
        log = np.zeros((longest, self.m, self.n, 2), np.float32)
        for k, start in enumerate(starts):
            env = self.factory()
            if start.get("seed") is not None:
                obs, _ = env.reset(seed=start["seed"])
            else:
                _set_world_rng(env, start["rng"])
                obs, _ = env.reset()
            if on_step is not None:
                on_step(k, env, obs, 0)
            for t, action in enumerate(played[k], 1):
                obs, *_ = env.step({a: action[i] for i, a in enumerate(agents)})
                if on_step is not None:
                    on_step(k, env, obs, t)
            log[longest - len(played[k]):, k] = played[k]
            self._begin[k] = longest - len(played[k])
            self.starts[k] = dict(start)
            self.venv.set_world(k, env, start)
        self._log, self._base = list(log), 0

    def close(self) -> None:
        self.venv.close()


def _set_world_rng(env: Any, state: dict[str, Any]) -> None:
    """Put ``env``'s world generator in ``state`` (an ``episode_starts()`` entry's ``rng`` of the engine)."""
    bit_generator = getattr(np.random, state["bit_generator"])()
    bit_generator.state = state
    env.unwrapped._rng = np.random.Generator(bit_generator)  # noqa: SLF001
