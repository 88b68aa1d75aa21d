"""The batched engine: M worlds of one scenario family stepped by one call, arrays in and out.

:class:`SwarmVectorEnv` holds ``M`` worlds (each a :class:`~swarm_env.env.SwarmEnv` with its own
pymunk space, generator and metrics, optionally in a :class:`~swarm_env.wrappers.SafetyShield`)
and exposes them as one environment with a leading batch axis, the shape TorchRL/BenchMARL
(``batch_size=[M]``), SB3's ``VecEnv`` (:mod:`swarm_env_baselines.vec_env` is built on it) and hand-written
PPO loops want::

    venv = SwarmVectorEnv("random", num_envs=64)
    obs, infos = venv.reset(seed=0)                    # obs: (M, N, obs_dim) float32
    obs, rew, term, trunc, infos = venv.step(actions)  # actions: (M, N, 2) in [-1, 1]

What is batched: the lidar of all ``M x N`` followers is one call of the compiled kernel
(:mod:`swarm_env.sensing.lidar`), in this process; with the compiled kernels on, the rewards, the metrics
and the observations (without the lidar) of a block's worlds are one compiled call per stage too
(:mod:`swarm_env.vector.batch_step`, :mod:`swarm_env.vector.batch_kernel`), with Python only in the worlds where
something happens (contacts, a formation switch, an episode's end), and so is the global state of
all worlds (:meth:`SwarmVectorEnv.state`, :mod:`swarm_env.sensing.state_kernel`); observations, rewards and
infos come back as arrays and no per-agent dict is built. The physics stays pymunk, one space per
world; one compiled call steps all of a block's spaces and takes their snapshots (``_physics_stage``,
:mod:`swarm_env.vector.world_batch`; worlds it cannot take, e.g. with reactive humans, step by themselves),
in this process or, with ``n_procs > 1``, in worker processes that each own a contiguous block of worlds. Workers import
neither torch nor the lidar kernel (numba): they return the observations without their lidar
columns plus what the lidar needs, and this process fills them in (about 30 MiB of private memory
per worker). They run the per-step kernels' numpy references world by world (``SwarmEnv._advance``,
``_account``) unless ``worker_kernels=True``, which loads numba in them and runs the batched stages
(faster, about 120 MiB more per worker).

Either way each world gets the arithmetic of a ``SwarmEnv`` (the batched stages call the per-world
kernels on each world's rows), so world ``m`` is **bitwise equal** to a ``SwarmEnv`` reset with
``seed + m`` and given the same actions, for any ``n_procs`` (tested on every built-in scenario and
50 ``random`` seeds in ``tests/test_vector.py``, against the numpy references in
``tests/test_batch_kernel.py``). While the engine steps, a world's ``EpisodeMetrics`` and previous
distances/actions live in the engine's rows; ``call``, ``get_attr`` and ``set_attr`` write them back
into the worlds first (a ``SwarmEnv`` object taken out with ``get_attr("unwrapped")`` shows metrics as
of that call).

Contract:

* **Fixed teams**: every world has the same ``N`` (``possible_agents``); for ``random`` with an
  ``n_followers`` range each world draws its team size from ``team_seed`` like a ``SwarmEnv``
  (the same for all worlds unless the factories differ).
* **Seeding**: ``reset(seed=s)`` resets world ``m`` with ``s + m``; a sequence gives one seed per
  world (``None`` entries continue that world's generator); ``reset()`` continues every world's.
* **Auto-reset in the same step** (SB3's, and Gymnasium's ``SAME_STEP`` mode): when world
  ``m``'s episode ends, ``terminated[m]`` or ``truncated[m]`` is ``True``, ``obs[m]`` is already
  the first observation of its next episode (reset without a seed: its generator continues),
  ``infos["_final"][m]`` is ``True``, ``infos["final_obs"][m]`` holds the last observation of the
  finished episode and ``infos["final_metrics"][m]`` its ``episode_metrics()``.
  Also for learners that bootstrap or consult an expert at the end of an episode:
  ``infos["final_state"][m]`` is the finished episode's last :meth:`~swarm_env.env.SwarmEnv.state`
  and ``infos["final_world_state"][m]`` its last :class:`~swarm_env.state.WorldState` (lists,
  ``None`` for worlds that did not end).
* **Infos** are ``(M, N)`` arrays under the keys of a ``SwarmEnv``'s per-agent infos
  (:data:`INFO_KEYS`), plus the :data:`~swarm_env.wrappers.SHIELD_INFO_KEYS` for shielded worlds
  and ``infos["shield_action"]``, ``(M, N, 2)`` float32: the safe actions the worlds executed
  (zeros at reset), what ``SafetyShield.last_safe_actions`` holds for a single env.
* **Episodes can be rebuilt**: :meth:`~SwarmVectorEnv.episode_starts` says how each world's
  episode began (its seed, or its generator's state before an unseeded reset), and
  :meth:`~SwarmVectorEnv.set_world` puts a world rebuilt elsewhere (e.g. a ``SwarmEnv`` reset
  the same way and given the same actions) in place of world ``m``: how a trainer resumes from a
  checkpoint without pickling physics.
"""

from __future__ import annotations

import subprocess
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import gymnasium
import numpy as np

from swarm_env.compiled import compiled_kernels
from swarm_env.env import _INFO_KEYS, StepOutcome, SwarmEnv, clip_to_action_space, info_columns, primitive_table
from swarm_env.geometry.static_map import StaticMap
from swarm_env.scoring.rewards import CONTACT_GROUPS, REWARD_TERMS
from swarm_env.sensing.observations import ObservationBuilder, lidar_input
from swarm_env.state import WorldState
from swarm_env.vector.batch_step import BatchState
from swarm_env.vector.scenario_prefetch import ScenarioPrefetcher
from swarm_env.worker_process import start_worker
from swarm_env.wrappers import SHIELD_INFO_KEYS, SafetyShield

if TYPE_CHECKING:  # the lidar kernel (numba) is imported on first use: workers without kernels never load it
    from swarm_env.sensing.lidar import LidarInput, LidarRows, PackedMaps

__all__ = ["SwarmVectorEnv", "EnvFactory", "INFO_KEYS"]

#: The per-agent info keys, each an ``(M, N)`` array in :meth:`SwarmVectorEnv.step`'s infos.
INFO_KEYS = _INFO_KEYS

World = SwarmEnv | SafetyShield
Seed = int | None


@dataclass(frozen=True)
class EnvFactory:
    """A picklable world builder: ``SwarmEnv(scenario, **kwargs)``, in a
    :class:`~swarm_env.wrappers.SafetyShield` if ``shield``. What worker processes receive."""

    scenario: Any = "random"
    kwargs: dict[str, Any] = field(default_factory=dict)
    #: Wrap the env in :class:`swarm_env.wrappers.SafetyShield` (the learner acts through the VO safety layer).
    shield: bool = False

    def __call__(self) -> World:
        env = SwarmEnv(self.scenario, **self.kwargs)
        return SafetyShield(env) if self.shield else env


# ---------------------------------------------------------------------------------------- blocks


@dataclass
class _BlockResult:
    """What a block of ``B`` worlds returns from a reset or a step (see :class:`_WorldBlock`)."""

    obs: np.ndarray  # (B, N, D) float32, lidar columns still 0
    # What the lidar needs of every world's current state: observations.lidar_input per world, or the same
    # for all worlds as lidar.LidarRows (the batched stages build it from their rows).
    scans: list[LidarInput] | LidarRows
    maps: dict[int, StaticMap]  # worlds (block index) whose map changed since the last result
    rewards: np.ndarray | None = None  # (B, N)
    terminated: np.ndarray | None = None  # (B,)
    truncated: np.ndarray | None = None
    infos: dict[str, np.ndarray] = field(default_factory=dict)  # (B, N) each
    # Worlds whose episode ended in this step: (block index, last obs without lidar, its scan input, metrics,
    # last state() vector, last WorldState).
    final: list[tuple[int, np.ndarray, LidarInput, dict[str, Any], np.ndarray, Any]] = field(
        default_factory=list)


class _WorldBlock:
    """Worlds stepped one after the other, everything but the lidar (which needs the kernel)."""

    def __init__(self, factories: Sequence[Callable[[], World]], prefetch: bool = False) -> None:
        self.worlds = [f() for f in factories]
        self.envs: list[SwarmEnv] = [w.unwrapped for w in self.worlds]
        for w, e in zip(self.worlds, self.envs):
            if not isinstance(e, SwarmEnv) or not (w is e or isinstance(w, SafetyShield) and w.env is e):
                raise TypeError(f"a world must be a SwarmEnv or SafetyShield(SwarmEnv), got {type(w).__name__}")
        shielded = {isinstance(w, SafetyShield) for w in self.worlds}
        if len(shielded) > 1:
            raise ValueError("either every world is in a SafetyShield or none is (the infos must have the same keys)")
        self.shielded = shielded.pop()
        self._sent: list[StaticMap | None] = [None] * len(self.worlds)
        # The random worlds' next scenarios, drawn ahead in a worker process (started at the first restart).
        self._prefetch: ScenarioPrefetcher | None = None
        self._want_prefetch = prefetch and any(e._random is not None for e in self.envs)
        # How each world's current episode began (episode_starts): {"seed": s, "rng": None} for a seeded
        # reset, {"seed": None, "rng": generator state} for an unseeded one.
        self.starts: list[dict[str, Any]] = [{} for _ in self.worlds]
        # The batched stages' rows (swarm_env.vector.batch_step), made on the first batched step. While
        # `_rows_live`, they hold the truth of the worlds' metrics and previous distances/actions
        # (the worlds' own copies lag; _sync_out writes them back).
        self._rows: BatchState | None = None
        self._rows_live = False
        # The batched physics and snapshot (swarm_env.vector.world_batch, which imports numba: built on the first
        # batched step); the worlds' current ``World`` objects are handed to it every step.
        self._physics: Any = None

    def describe(self) -> dict[str, Any]:
        e = self.envs[0]
        return {"agents": [list(x.possible_agents) for x in self.envs], "action_type": e.action_type,
                "sensors": e.sensors, "capacity": e.capacity, "obs_space": e.observation_space(e.possible_agents[0]),
                "act_space": e.action_space(e.possible_agents[0]), "state_space": e.state_space,
                "metadata": e.metadata, "shielded": self.shielded,
                "primitives": primitive_table(e.scenario.robots.max_turn_rate)}

    def reset(self, seeds: Sequence[Seed]) -> _BlockResult:
        for b, s in enumerate(seeds):
            self._restart(b, s)
        zeros = np.zeros(len(self.envs[0].possible_agents))
        obs = np.stack([e._obs.build_without_lidar(e._state) for e in self.envs])  # type: ignore[arg-type]
        out = _BlockResult(obs, [lidar_input(e._state) for e in self.envs], self._changed_maps())  # type: ignore[arg-type]
        terms = dict.fromkeys(REWARD_TERMS, zeros)
        touching = np.zeros((len(zeros), len(CONTACT_GROUPS)))
        out.infos = _stack_columns([info_columns(e._prev_dist, terms, touching, False) for e in self.envs], INFO_KEYS)
        if self.shielded:
            out.infos.update(_stack_columns([[zeros > 0, zeros, zeros == 0] for _ in self.envs], SHIELD_INFO_KEYS))
            out.infos["shield_action"] = np.zeros((len(self.envs), len(zeros), 2), np.float32)
        return out

    def step(self, norm: np.ndarray) -> _BlockResult:
        """Step every world with the ``(B, N, 2)`` normalised actions ``norm``: the batched stages
        (:meth:`_step_batched`) with the compiled kernels on, else world by world (the numpy references)."""
        if self._prefetch is not None:
            self._prefetch.poll()  # keep the worker's replies flowing between episode ends
        if compiled_kernels():
            return self._step_batched(norm)
        self._sync_out()
        return self._step_per_world(norm)

    def _step_batched(self, norm: np.ndarray) -> _BlockResult:
        """:meth:`_step_per_world`'s results with the rewards, metrics and observations of all worlds in
        one compiled call per stage (:class:`swarm_env.vector.batch_step.BatchState`): the same bits.

        Python touches each world as few times as it can (at 1,024 worlds a pass over the worlds'
        objects misses the caches at every world): the physics (:mod:`swarm_env.vector.world_batch`) stores
        each world's snapshot chunk by chunk, and the stages, the lidar's input and the maps read the
        physics' stacked blocks and the rows (:meth:`BatchState.arrays_of`, :meth:`BatchState.lidar_rows`)
        instead of ``M`` snapshots."""
        if self._rows is None:
            self._rows = BatchState(self.envs)
        rows = self._rows
        reloaded = not self._rows_live
        if reloaded:
            for b, e in enumerate(self.envs):
                rows.load(b, e)
            self._rows_live = True
        t0 = time.perf_counter()
        shield_cols = []
        safe = []
        if self.shielded:
            acts = np.empty_like(norm, dtype=np.float64)
            for b, (w, act) in enumerate(zip(self.worlds, norm)):
                res = w.protect(act)
                acts[b] = res.actions  # what SafetyShield.step hands the env, as float64
                shield_cols.append([res.intervened, res.correction, res.feasible])
                safe.append(res.actions)
        else:
            acts = np.ascontiguousarray(norm, dtype=np.float64)
        if self._physics is None:
            from swarm_env.vector.world_batch import WorldBatch  # numba: only where the compiled kernels are on
            self._physics = WorldBatch()
        envs = self.envs
        drawn: list[int] = []

        def settle(indices: list[int], states: list[WorldState]) -> None:
            # each world's new snapshot as soon as its chunk is done (its objects still in the caches; the
            # previous snapshots are freed chunk by chunk), and the worlds with a renderer (BatchState.finish)
            for b in indices:
                e = envs[b]
                e._state = states[b]
                if e._renderer is not None:
                    drawn.append(b)

        states = _physics_stage(envs, acts, self._physics, speed=rows.speed, on_states=settle)
        wall = (time.perf_counter() - t0) / len(envs)  # the physics' share; the rest is counted below
        t1 = time.perf_counter()
        blocks = self._physics.last_arrays()
        a = rows.arrays_of(blocks) if blocks is not None else rows.gather(states)
        obs, rewards, terminated, truncated, infos = rows.step(envs, states, acts, wall, a=a, drawn=sorted(drawn))
        if self.shielded:
            infos.update(_stack_columns(shield_cols, SHIELD_INFO_KEYS))
            infos["shield_action"] = np.stack(safe)
        rows.wall_time += (time.perf_counter() - t1) / len(envs)
        final = []
        fresh = {}
        for b in np.flatnonzero(terminated | truncated).tolist():
            w, e, st = self.worlds[b], envs[b], states[b]
            rows.store(b, e)
            final.append((b, obs[b].copy(), lidar_input(st), w.episode_metrics(), e.state(), st))
            self._restart(b, None)
            assert e._state is not None
            fresh[b] = e._state
            obs[b] = e._obs.build_without_lidar(e._state)
        # the maps change only where a world started a new episode (or anything, while the rows were not live)
        maps = self._changed_maps(None if reloaded else list(fresh))
        return _BlockResult(
            obs, rows.lidar_rows(a, fresh), maps,
            rewards=rewards, terminated=terminated, truncated=truncated, infos=infos, final=final,
        )

    def _sync_out(self) -> None:
        """Write the batched rows back into the worlds (before anything reads or steps them one by one);
        the rows are read again before the next batched step."""
        if self._rows_live:
            assert self._rows is not None
            for b, e in enumerate(self.envs):
                self._rows.store(b, e)
            self._rows_live = False

    def _step_per_world(self, norm: np.ndarray) -> _BlockResult:
        shield_cols = []
        safe = []
        outcomes: list[StepOutcome] = []
        t0 = time.perf_counter()
        for w, e, act in zip(self.worlds, self.envs, norm):
            if self.shielded:
                res = w.protect(act)
                act = res.actions.astype(np.float64)  # what SafetyShield.step hands the env, as float64
                shield_cols.append([res.intervened, res.correction, res.feasible])
                safe.append(res.actions)
            outcomes.append(e._advance(act))
        obs = np.stack([e._obs.build_without_lidar(o.state) for e, o in zip(self.envs, outcomes)])
        wall = (time.perf_counter() - t0) / len(self.envs)  # the block's wall time, shared equally
        infos = _info_arrays(outcomes)
        if self.shielded:
            infos.update(_stack_columns(shield_cols, SHIELD_INFO_KEYS))
            infos["shield_action"] = np.stack(safe)
        final = []
        for b, (w, e, o) in enumerate(zip(self.worlds, self.envs, outcomes)):
            e._account(o, wall)
            if o.terminated or o.truncated:
                final.append((b, obs[b].copy(), lidar_input(o.state), w.episode_metrics(), e.state(), o.state))
                self._restart(b, None)
                obs[b] = e._obs.build_without_lidar(e._state)  # type: ignore[arg-type]
        return _BlockResult(
            obs, [lidar_input(e._state) for e in self.envs], self._changed_maps(),  # type: ignore[arg-type]
            rewards=np.stack([o.reward for o in outcomes]),
            terminated=np.array([o.terminated for o in outcomes]),
            truncated=np.array([o.truncated for o in outcomes]),
            infos=infos, final=final,
        )

    def _restart(self, b: int, seed: Seed) -> None:
        """Reset world ``b`` as its ``reset(seed)`` would, without building observations there."""
        env = self.envs[b]
        rng = env._rng
        self.starts[b] = {"seed": seed, "rng": None if seed is not None or rng is None else rng.bit_generator.state}
        drawn = None
        if self._want_prefetch and self._prefetch is None:
            self._prefetch = ScenarioPrefetcher()
        if self._prefetch is not None and env._random is not None:
            if seed is None and rng is not None:
                drawn = self._prefetch.take(b, rng)  # the scenario env._start would draw, or None
            env._start(seed, drawn)
            assert env._rng is not None  # _start made one if there was none
            self._prefetch.submit(b, env._rng, env._random)  # the next episode's, from the state after this draw
        else:
            env._start(seed)
        if self.shielded:
            self.worlds[b].start_episode()
        if self._rows_live:
            assert self._rows is not None
            self._rows.load(b, self.envs[b])

    def _changed_maps(self, worlds: Sequence[int] | None = None) -> dict[int, StaticMap]:
        """The worlds (of ``worlds``, all by default) whose map is not the last one sent, with their map."""
        out = {}
        envs = self.envs
        for b in range(len(envs)) if worlds is None else worlds:
            static = envs[b]._state.static  # type: ignore[union-attr]
            if static is not self._sent[b]:
                out[b] = self._sent[b] = static
        return out

    def state(self) -> np.ndarray:
        """``(B, state_dim)`` float32: each world's ``SwarmEnv.state()`` of its current snapshot. While
        the batched rows are live (compiled kernels on, after the first batched step and until a
        per-world ``call``/``get_attr``/``set_attr`` writes them back), one compiled call for all worlds
        (:meth:`BatchState.state <swarm_env.vector.batch_step.BatchState.state>`, the same bits); otherwise,
        or when the worlds' capacities differ, the worlds' own, stacked."""
        if compiled_kernels() and self._rows_live:
            assert self._rows is not None
            out = self._rows.state(self.envs)
            if out is not None:
                return out
        return np.stack([e.state() for e in self.envs])

    def episode_starts(self) -> list[dict[str, Any]]:
        return [dict(s) for s in self.starts]

    def set_world(self, b: int, world: World, start: dict[str, Any]) -> StaticMap:
        """Put ``world`` (reset and stepped elsewhere) in place of world ``b``; return its map."""
        e = world.unwrapped
        if not isinstance(e, SwarmEnv) or isinstance(world, SafetyShield) != self.shielded:
            kind = "a SafetyShield(SwarmEnv)" if self.shielded else "a SwarmEnv"
            raise TypeError(f"world {b} must be {kind} like the others, got {type(world).__name__}")
        if list(e.possible_agents) != list(self.envs[b].possible_agents) or e._state is None or not e.agents:
            raise ValueError("the new world needs the same team and an episode under way (reset, not ended)")
        self.worlds[b].close()
        self.worlds[b], self.envs[b], self.starts[b] = world, e, dict(start)
        self._sent[b] = e._state.static
        if self._rows_live:
            assert self._rows is not None
            self._rows.load(b, e)
        return e._state.static

    def set_world_pickled(self, b: int, data: bytes, start: dict[str, Any]) -> StaticMap:
        """:meth:`set_world` of a world pickled by the engine (worker processes)."""
        import pickle

        return self.set_world(b, pickle.loads(data), start)

    def call(self, indices: Sequence[int], method: str, args: tuple, kwargs: dict) -> list[Any]:
        if method not in _STATE_READERS:  # anything else may read or change the metrics: the worlds are the truth
            self._sync_out()
        return [getattr(self.worlds[b], method)(*args, **kwargs) for b in indices]

    def get_attr(self, indices: Sequence[int], name: str) -> list[Any]:
        self._sync_out()
        return [getattr(self.worlds[b], name) for b in indices]

    def set_attr(self, indices: Sequence[int], name: str, value: Any) -> list[None]:
        self._sync_out()
        for b in indices:
            setattr(self.worlds[b], name, value)
        return [None] * len(indices)

    def close(self) -> None:
        for w in self.worlds:
            w.close()
        if self._prefetch is not None:
            self._prefetch.close()
            self._prefetch = None


#: World methods that read only the current WorldState (``_state``, set every step): a ``call`` of
#: them needs no write-back of the batched rows.
_STATE_READERS = frozenset({"world_state", "state"})


def _physics_stage(envs: Sequence[SwarmEnv], norm: np.ndarray, batch: Any = None, speed: np.ndarray | None = None,
                   on_states: Callable[[list[int], list[WorldState]], None] | None = None) -> list[WorldState]:
    """Step every world's physics with its ``(N, 2)`` row of the normalised actions ``norm`` and
    return the snapshots: what ``SwarmEnv._advance`` does before the rewards. With a
    :class:`swarm_env.vector.world_batch.WorldBatch` ``batch``, in one compiled call for the worlds it can
    take (the same bits); without, world by world. ``speed``: ``(M, 2)``, each world's ``e._speed``
    (the batched rows hold them; looked up here if not given). ``on_states``: as for
    :meth:`WorldBatch.step_and_snapshot <swarm_env.vector.world_batch.WorldBatch.step_and_snapshot>`."""
    if batch is not None:
        if speed is None:
            speed = np.stack([e._speed for e in envs])
        worlds = [e._world for e in envs]
        return batch.step_and_snapshot(norm * speed[:, None, :], worlds=worlds, on_states=on_states)
    out = []
    for e, act in zip(envs, norm):
        world = e._world
        assert world is not None
        world.step(act * e._speed)
        out.append(world.snapshot())
    if on_states is not None:
        on_states(list(range(len(out))), out)
    return out


def _info_arrays(outcomes: Sequence[StepOutcome]) -> dict[str, np.ndarray]:
    """The step infos of ``B`` worlds as ``(B, N)`` arrays under :data:`INFO_KEYS`: what stacking
    each world's :func:`~swarm_env.env.info_columns` gives, written into one block per dtype."""
    b, n = len(outcomes), len(outcomes[0].dist)
    t = len(REWARD_TERMS)
    floats = np.empty((t + 1, b, n))  # the reward terms, then the slot distance
    counts = np.empty((len(CONTACT_GROUPS), b, n), np.int64)
    collided = np.empty((b, n), bool)
    for k, o in enumerate(outcomes):
        floats[:t, k] = o.table
        floats[t, k] = o.dist
        counts[:, k] = o.touching.T  # float counts cast to int64, as info_columns' astype
        collided[k] = o.collided
    return dict(zip(INFO_KEYS, [*floats, *counts, collided]))


def _stack_columns(per_world: list[list[np.ndarray]], keys: Sequence[str]) -> dict[str, np.ndarray]:
    return {key: np.stack([cols[k] for cols in per_world]) for k, key in enumerate(keys)}


class _RemoteBlock:
    """A :class:`_WorldBlock` in a worker process (``python -m swarm_env.vector.worker``), a fresh interpreter
    connected back over an authenticated local socket (:mod:`swarm_env.worker_process` says why) that imports
    neither torch nor numba unless ``compiled`` (see ``swarm_env.vector.worker``).
    """

    def __init__(self, factories: Sequence[Callable[[], World]], compiled: bool = False) -> None:
        import cloudpickle  # gymnasium's dependency: pickles lambdas and local factories

        self.proc, self.conn = start_worker("swarm_env.vector.worker", *(["--compiled"] if compiled else []))
        self.conn.send(cloudpickle.dumps(list(factories)))
        self._pending = False
        self._check(self._recv())  # the block's description, or the error that building it raised
        self.description = self._last

    def _recv(self) -> Any:
        try:
            return self.conn.recv()
        except (EOFError, ConnectionError) as exc:
            code = self.proc.poll()
            raise RuntimeError(f"a swarm_env.vector.engine worker (pid {self.proc.pid}) exited with code {code}") from exc

    def _check(self, reply: Any) -> Any:
        ok, value = reply
        if not ok:
            raise RuntimeError(f"a swarm_env.vector.engine worker failed:\n{value}")
        self._last = value
        return value

    def send(self, cmd: str, *args: Any) -> None:
        self.conn.send((cmd, args))
        self._pending = True

    def result(self) -> Any:
        self._pending = False
        return self._check(self._recv())

    def close(self) -> None:
        try:
            if self._pending:
                self._recv()
            self.conn.send(("close", ()))
            self._recv()
        except (OSError, RuntimeError):
            pass
        self.conn.close()
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()


# ---------------------------------------------------------------------------------------- engine


class SwarmVectorEnv:
    """``num_envs`` worlds of ``scenario`` stepped together (see the module docstring).

    Args:
        scenario: as for :class:`~swarm_env.env.SwarmEnv` (a built-in name, a YAML path, a
            ``Scenario`` or ``"random"``).
        num_envs: the number of worlds ``M`` (>= 1).
        n_procs: worker processes for the physics (1: everything in this process). Worlds are
            split into ``n_procs`` contiguous blocks; the results do not depend on it.
        worker_kernels: with ``n_procs > 1``, run the compiled per-step kernels in the workers too
            (the same bits). ``False`` (the default) keeps numba out of the workers (about 30 MiB of
            private memory each) at the price of their numpy references, which are slower than one
            process with the kernels; ``True`` costs about 120 MiB more per worker and pays when there
            are free cores (measured in docs/performance.md).
        shield: put every world in a :class:`~swarm_env.wrappers.SafetyShield`.
        prefetch_scenarios: with ``n_procs = 1`` and ``"random"`` worlds, draw each world's next scenario
            in a worker process while the worlds step (:mod:`swarm_env.vector.scenario_prefetch`): the same
            scenarios bit for bit, and an episode start costs the world's construction only (a random
            world's draw is several milliseconds, and worlds that started together end together). One
            more process, started at the first reset.
        **kwargs: :class:`~swarm_env.env.SwarmEnv` keyword arguments, the same for every world
            (``render_mode`` is not supported: render a world with ``SwarmEnv`` itself).

    :meth:`from_factories` batches worlds built by any picklable callables.
    """

    def __init__(self, scenario: Any = "random", num_envs: int = 8, *, n_procs: int = 1, shield: bool = False,
                 worker_kernels: bool = False, prefetch_scenarios: bool = False, **kwargs: Any) -> None:
        if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
            raise ValueError(f"num_envs must be an int >= 1, got {num_envs!r}")
        if kwargs.get("render_mode") is not None:
            raise ValueError("SwarmVectorEnv does not render; render one world with SwarmEnv(..., render_mode=...)")
        self._init_from([EnvFactory(scenario, dict(kwargs), shield)] * int(num_envs), n_procs, worker_kernels,
                        prefetch_scenarios)

    @classmethod
    def from_factories(cls, factories: Sequence[Callable[[], World]], n_procs: int = 1,
                       worker_kernels: bool = False, prefetch_scenarios: bool = False) -> SwarmVectorEnv:
        """Batch the worlds ``factories`` build (each returns a ``SwarmEnv``, or a ``SafetyShield``
        of one; picklable with cloudpickle when ``n_procs > 1``). They must have the same team,
        spaces and sensors. ``worker_kernels``, ``prefetch_scenarios``: as for the constructor."""
        self = cls.__new__(cls)
        self._init_from(list(factories), n_procs, worker_kernels, prefetch_scenarios)
        return self

    def _init_from(self, factories: list[Callable[[], World]], n_procs: int, worker_kernels: bool = False,
                   prefetch_scenarios: bool = False) -> None:
        m = len(factories)
        if m < 1:
            raise ValueError("SwarmVectorEnv needs at least one world")
        for name, flag in (("worker_kernels", worker_kernels), ("prefetch_scenarios", prefetch_scenarios)):
            if not isinstance(flag, bool):
                raise ValueError(f"{name} must be a bool, got {flag!r}")
        if prefetch_scenarios and n_procs != 1:
            raise ValueError("prefetch_scenarios needs n_procs=1 (the worlds of worker processes draw their own)")
        if isinstance(n_procs, bool) or not isinstance(n_procs, (int, np.integer)) or not 1 <= n_procs <= m:
            raise ValueError(f"n_procs must be an int in [1, num_envs={m}], got {n_procs!r}")
        bounds = np.linspace(0, m, int(n_procs) + 1).round().astype(int)
        self._spans = [(int(bounds[p]), int(bounds[p + 1])) for p in range(n_procs)]
        self._local: _WorldBlock | None = None
        self._remotes: list[_RemoteBlock] = []
        self.closed = False
        if n_procs == 1:
            self._local = _WorldBlock(factories, prefetch_scenarios)
            described = [self._local.describe()]
        else:
            try:
                for a, b in self._spans:
                    self._remotes.append(_RemoteBlock(factories[a:b], compiled=worker_kernels))
            except BaseException:
                self.close()
                raise
            described = [r.description for r in self._remotes]
        first = described[0]
        agents = [a for d in described for a in d["agents"]]
        for k, team in enumerate(agents):
            if team != agents[0]:
                self.close()
                raise ValueError(f"world {k} has {len(team)} followers, world 0 has {len(agents[0])}: every world "
                                 "needs the same team (a fixed n_followers)")
        for d in described[1:]:
            same = (d["action_type"], d["sensors"], d["shielded"]) == (first["action_type"], first["sensors"], first["shielded"])
            if not same or not np.array_equal(d["primitives"], first["primitives"]):
                self.close()
                raise ValueError("the worlds differ in action type, sensors, shield or turn rate")
        self.num_envs = m
        self.n_procs = int(n_procs)
        self.possible_agents = list(agents[0])
        self.num_agents = len(self.possible_agents)
        self.action_type: str = first["action_type"]
        self.shielded: bool = first["shielded"]
        self.single_observation_space: gymnasium.spaces.Box = first["obs_space"]
        self.single_action_space: gymnasium.spaces.Space = first["act_space"]
        self.state_space: gymnasium.spaces.Box = first["state_space"]
        self.metadata = first["metadata"]
        self._obs = ObservationBuilder(first["sensors"], first["capacity"])  # fills the lidar columns
        self._maps: list[StaticMap | None] = [None] * m
        self._packed: tuple[list[int], Any] | None = None  # (ids of the packed maps, PackedMaps)
        self._prim: np.ndarray = first["primitives"]  # (10, 2) normalised twist of each discrete action
        self._warned_clip = False
        self._live = False

    # ------------------------------------------------------------------ episode
    def reset(self, seed: int | Sequence[Seed] | None = None) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Reset every world (see the module docstring for ``seed``). Returns ``obs`` ``(M, N, D)``
        and the reset infos (the step infos' keys: zero reward terms and contacts)."""
        seeds = self._seeds(seed)
        results = self._run("reset", [(seeds[a:b],) for a, b in self._spans])
        self._live = True
        obs, infos, _ = self._merge(results)
        return obs, infos

    def step(self, actions: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """Step every world with ``actions`` (``(M, N, 2)`` in ``[-1, 1]``, or ``(M, N)`` ints for
        ``action_type="discrete"``). Returns ``obs`` ``(M, N, D)`` float32, ``rewards`` ``(M, N)``
        float64, ``terminated`` and ``truncated`` ``(M,)`` bool, and the infos (module docstring)."""
        if not self._live:
            raise RuntimeError("call reset() before step()")
        norm = self._normalised(actions)
        results = self._run("step", [(norm[a:b],) for a, b in self._spans])
        obs, infos, final = self._merge(results)
        rewards = np.concatenate([r.rewards for r in results])
        terminated = np.concatenate([r.terminated for r in results])
        truncated = np.concatenate([r.truncated for r in results])
        if final:
            done = terminated | truncated
            infos["_final"] = done
            infos["final_obs"] = obs.copy()
            for key in ("final_metrics", "final_state", "final_world_state"):
                infos[key] = [None] * self.num_envs
            for m, last, metrics, state, world_state in final:
                infos["final_obs"][m] = last
                infos["final_metrics"][m] = metrics
                infos["final_state"][m] = state
                infos["final_world_state"][m] = world_state
        return obs, rewards, terminated, truncated, infos

    def _run(self, cmd: str, per_block: list[tuple]) -> list[_BlockResult]:
        if self._local is not None:
            return [getattr(self._local, cmd)(*per_block[0])]
        for remote, args in zip(self._remotes, per_block):
            remote.send(cmd, *args)
        return [remote.result() for remote in self._remotes]

    def _merge(self, results: list[_BlockResult]) -> tuple[np.ndarray, dict[str, Any], list[tuple]]:
        """Concatenate the blocks' results and fill every lidar column with one kernel call."""
        obs = results[0].obs if len(results) == 1 else np.concatenate([r.obs for r in results])
        if len(results) == 1:
            infos = dict(results[0].infos)
        else:
            infos = {k: np.concatenate([r.infos[k] for r in results]) for k in results[0].infos}
        finals = [(a + f[0], *f[1:]) for (a, _), r in zip(self._spans, results) for f in r.final]
        final_obs = []
        if finals:  # the finished episodes' last observations, in the maps they were played in
            lidar = self._scan([f[2] for f in finals], [f[0] for f in finals])
            n = self.num_agents
            for k, (m, last, _, *rest) in enumerate(finals):
                self._obs.fill_lidar(last, lidar[k * n:(k + 1) * n])
                final_obs.append((m, last, *rest))
        for (a, _), r in zip(self._spans, results):
            for b, static in r.maps.items():
                self._maps[a + b] = static
        from swarm_env.sensing.lidar import flat_inputs, join_rows

        scans = join_rows([r.scans if isinstance(r.scans, tuple) else flat_inputs(r.scans) for r in results])
        lidar = self._obs.scan_rows(scans, self._packed_batch())
        self._obs.fill_lidar(obs, lidar.reshape(self.num_envs, self.num_agents, -1))
        return obs, infos, final_obs

    def _packed_batch(self) -> PackedMaps:
        """Every world's current map, packed for the lidar; kept while no map changes, and updated
        world by world where some do (:meth:`PackedMaps.replaced <swarm_env.sensing.lidar.PackedMaps.replaced>`:
        with many worlds some episode ends, with a new map, nearly every step)."""
        from swarm_env.sensing.lidar import PackedMaps

        ids = [id(s) for s in self._maps]
        if self._packed is None:
            self._packed = (ids, PackedMaps.of(self._maps))  # type: ignore[arg-type]
        elif self._packed[0] != ids:
            changed = [w for w, (a, b) in enumerate(zip(self._packed[0], ids)) if a != b]
            self._packed = (ids, self._packed[1].replaced(self._maps, changed))
        return self._packed[1]

    def _scan(self, inputs: list[LidarInput], worlds: Sequence[int]) -> np.ndarray:
        from swarm_env.sensing.lidar import PackedMaps

        if len(inputs) == self.num_envs:  # the whole batch: keep the packing while no map changes
            packed = self._packed_batch()
        else:
            packed = PackedMaps.of([self._maps[m] for m in worlds])  # type: ignore[misc]
        return self._obs.scan(inputs, packed)

    def _seeds(self, seed: int | Sequence[Seed] | None) -> list[Seed]:
        m = self.num_envs
        if seed is None:
            return [None] * m
        if isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
            return [int(seed) + k for k in range(m)]
        seeds = list(seed)  # type: ignore[arg-type]
        ok = all(s is None or isinstance(s, (int, np.integer)) and not isinstance(s, bool) for s in seeds)
        if len(seeds) != m or not ok:
            raise ValueError(f"seed must be None, an int or {m} ints or Nones (one per world), got {seed!r}")
        return [None if s is None else int(s) for s in seeds]

    def _normalised(self, actions: Any) -> np.ndarray:
        m, n = self.num_envs, self.num_agents
        if self.action_type == "discrete":
            k = np.asarray(actions)
            hi = self.single_action_space.n - 1  # type: ignore[attr-defined]
            if k.shape != (m, n) or not np.issubdtype(k.dtype, np.integer) or k.min() < 0 or k.max() > hi:
                raise ValueError(f"discrete actions must be ({m}, {n}) ints in [0, {hi}], got shape {k.shape} dtype {k.dtype}")
            return self._prim[k]
        try:
            a = np.array(actions, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"actions must be a ({m}, {n}, 2) array of numbers") from exc
        if a.shape != (m, n, 2):
            raise ValueError(f"actions must have shape ({m}, {n}, 2) (worlds, followers, (v, omega)), got {a.shape}")
        if not np.isfinite(a).all():
            bad = np.argwhere(~np.isfinite(a))[0]
            raise ValueError(f"actions must be finite: world {bad[0]}, follower {bad[1]} has {a[bad[0], bad[1]].tolist()}")
        self._warned_clip = clip_to_action_space(a, self._warned_clip, stacklevel=4)
        return a

    # ------------------------------------------------------------------ extras
    def state(self) -> np.ndarray:
        """``(M, state_dim)`` float32: each world's :meth:`~swarm_env.env.SwarmEnv.state`."""
        if self._local is not None:
            return self._local.state()
        for r in self._remotes:
            r.send("state")
        return np.concatenate([r.result() for r in self._remotes])

    def episode_starts(self) -> list[dict[str, Any]]:
        """How each world's current episode began, as JSON values: ``{"seed": s, "rng": None}`` after a
        seeded reset, ``{"seed": None, "rng": state}`` after an unseeded one (``state``: the world
        generator's ``bit_generator.state`` just before it drew the episode). A ``SwarmEnv`` whose
        ``_rng`` is put in that state (or that is reset with that seed) and reset draws the same episode."""
        if self._local is not None:
            return self._local.episode_starts()
        for r in self._remotes:
            r.send("episode_starts")
        return [s for r in self._remotes for s in r.result()]

    def set_world(self, m: int, world: World, start: dict[str, Any] | None = None) -> None:
        """Replace world ``m`` by ``world``, a ``SwarmEnv`` (a ``SafetyShield`` of one if the worlds are
        shielded) with the same team and an episode under way, rebuilt elsewhere; the engine goes on
        stepping it from its current state. ``start`` is what :meth:`episode_starts` reports for it
        from now on (how that episode began). With ``n_procs > 1`` the world is pickled to its worker.

        The engine must have been reset (the other worlds need an episode too); the world's next
        observation is whatever the next :meth:`step` returns (build the current one with the world
        itself if needed)."""
        if not self._live:
            raise RuntimeError("call reset() before set_world()")
        if not 0 <= m < self.num_envs:
            raise IndexError(f"world index {m} out of range for {self.num_envs} worlds")
        e = getattr(world, "unwrapped", None)
        if not isinstance(e, SwarmEnv) or isinstance(world, SafetyShield) != self.shielded:
            kind = "a SafetyShield(SwarmEnv)" if self.shielded else "a SwarmEnv"
            raise TypeError(f"world {m} must be {kind} like the others, got {type(world).__name__}")
        if list(e.possible_agents) != self.possible_agents or e._state is None or not e.agents:
            raise ValueError("the new world needs the same team and an episode under way (reset, not ended)")
        start = dict(start or {})
        if self._local is not None:
            static = self._local.set_world(m, world, start)
        else:
            import cloudpickle

            p = next(p for p, (a, b) in enumerate(self._spans) if a <= m < b)
            self._remotes[p].send("set_world_pickled", m - self._spans[p][0], cloudpickle.dumps(world), start)
            static = self._remotes[p].result()
        self._maps[m] = static
        self._packed = None  # the batch's packed maps include the replaced world's

    def call(self, method: str, *args: Any, indices: Sequence[int] | None = None, **kwargs: Any) -> list[Any]:
        """``[world.method(*args, **kwargs) for world in worlds[indices]]`` (all by default), in
        whichever process holds each world; e.g. ``call("episode_metrics")``, ``call("world_state")``."""
        return self._per_world("call", indices, method, args, kwargs)

    def get_attr(self, name: str, indices: Sequence[int] | None = None) -> list[Any]:
        """``[getattr(world, name) for world in worlds[indices]]`` (all by default)."""
        return self._per_world("get_attr", indices, name)

    def set_attr(self, name: str, value: Any, indices: Sequence[int] | None = None) -> None:
        """``setattr(world, name, value)`` for the worlds ``indices`` (all by default)."""
        self._per_world("set_attr", indices, name, value)

    def _per_world(self, cmd: str, indices: Sequence[int] | None, *payload: Any) -> list[Any]:
        wanted = list(range(self.num_envs)) if indices is None else [int(i) for i in indices]
        bad = [m for m in wanted if not 0 <= m < self.num_envs]
        if bad:
            raise IndexError(f"world indices {bad} out of range for {self.num_envs} worlds")
        out: dict[int, Any] = {}
        for p, (a, b) in enumerate(self._spans):
            mine = sorted({m for m in wanted if a <= m < b})
            if not mine:
                continue
            local = [m - a for m in mine]
            if self._local is not None:
                values = getattr(self._local, cmd)(local, *payload)
            else:
                self._remotes[p].send(cmd, local, *payload)
                values = self._remotes[p].result()
            out.update(zip(mine, values))
        return [out[m] for m in wanted]

    def close(self) -> None:
        if getattr(self, "closed", True):
            return
        self.closed = True
        if self._local is not None:
            self._local.close()
        for r in self._remotes:
            r.close()

    def __del__(self) -> None:  # worker processes end with the engine
        try:
            self.close()
        except Exception:  # noqa: BLE001 - interpreter shutdown
            pass

    @property
    def observation_space(self) -> gymnasium.spaces.Box:
        """The batched observation space ``(M, N, D)``."""
        s = self.single_observation_space
        reps = (self.num_envs, self.num_agents, 1)
        return gymnasium.spaces.Box(np.tile(s.low, reps), np.tile(s.high, reps), dtype=np.float32)
