"""MAPPO and IPPO on swarm_env: PPO with one decentralised actor shared by every follower.

.. code-block:: console

    swarm-env train mappo --scenario random --total-steps 2e6 --seed 0                  # MAPPO
    swarm-env train mappo --scenario random --total-steps 2e6 --seed 0 --critic local   # IPPO
    swarm-env train mappo ... --shield teach --imitation-coef 1.0   # the safety layer as a teacher
    swarm-env train mappo ... --shield execute                      # trained through the safety layer
    swarm-env train mappo ... --residual vo --shield execute        # a learned correction of vo
    swarm-env train mappo --resume runs/<run>                       # go on after Ctrl-C or a crash

A small PyTorch implementation in the CleanRL spirit, written to read top to bottom. The
actor maps one follower's observation to a Gaussian over its normalised twist (parameter
sharing: one network for all followers); the critic is **centralised** (``critic="central"``,
MAPPO, Yu et al. 2022: the global ``env.state()`` joined to the follower's own observation,
the "agent-specific global state") or **local** (``critic="local"``, IPPO: the observation
alone). Observations and states are normalised by running statistics, rewards by a running
estimate of the return's scale; truncated episodes are bootstrapped from the value of their
last state; the update sees the actor inputs exactly as normalised when the actions were
drawn (``train.csv``'s ``first_ratio_error`` stays 0).

Rollouts go through the batched engine (:class:`swarm_env.vector.SwarmVectorEnv`, ``n_copies``
worlds, their physics in ``env_procs`` processes): one call steps every world, observations,
rewards and infos come back as arrays, and a finished world is reset in the same step (its
generator going on). The training is bit for bit what the earlier loop over ``n_copies`` separate
``SwarmEnv`` objects gave (``tests/test_mappo_engine.py`` holds reference runs of that loop).

Options that the shipped baselines use (docs/baselines.md gives their commands and results):

* ``pretrain`` (default ``vo``): a DAgger warm start of the actor from that expert
  (:mod:`swarm_env_baselines.imitation`, a few minutes) so that PPO starts from a policy that holds its
  slot; the observation statistics are then fixed. ``--pretrain none`` starts from scratch.
* ``shield``: the VO safety layer of :mod:`swarm_env.safety`. ``execute``: every world is in a
  :class:`swarm_env.wrappers.SafetyShield` (the engine's ``shield=True``), the env executes the safe
  actions and the policy is scored through it. ``teach``: the env executes the learner's own actions, but the shield
  computes the safe action nearest to each sampled one; ``intervention_coef`` charges the size
  of that correction as a reward penalty, and ``imitation_coef`` adds a loss pulling the actor's
  mean to the safe action wherever the shield intervened (decayed to 0 over the first
  ``imitation_anneal`` of the training), so that the policy learns to act safely *alone*.
* ``residual`` (e.g. ``vo``): the executed action is ``clip(expert + residual_scale *
  clip(sample))``; the actor reads the observation and the expert's action (privileged at
  execution, like the expert).
* Reward shaping goes through the env's reward (``--env 'reward={approach: 5.0}'``: the
  anticipatory clearance term of :mod:`swarm_env.rewards`).

Data split: PPO's worlds are the generator streams of seeds ``100 * seed + copy``; DAgger's
seeds ``10000 + 1000 * seed`` onwards; model selection uses validation seeds ``500-549``
(every ``eval_every`` agent-steps, collisions costing 1 m each; the best is kept in ``best/``);
the test seeds ``1000-1049`` are left to the leaderboard.

A run directory ``<runs_dir>/<run_name>/`` holds ``config.json``, ``versions.json``,
``policy.safetensors`` + ``policy.json`` (actor, critic and normalisation statistics as
tensors and JSON: loading runs no code; :mod:`swarm_env_baselines.mappo_policy`), ``best/``,
``pretrain.csv`` (DAgger rounds), ``eval.csv`` (validation, streamed), ``train.csv`` (losses,
action std, contact and intervention rates per update, time spent in rollouts and updates),
``learning_curve.png``, ``summary.json`` and ``checkpoint/`` (the latest resumable state: :func:`resume`,
``swarm-env train mappo --resume <run dir>``; SIGINT/SIGTERM save it and the policy before exiting).
Load it with ``mappo:<run dir>`` (or ``mappo:<run dir>/best``) anywhere a policy spec is accepted.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from swarm_env.jsonio import dumps, write_json
from swarm_env_baselines.mappo_policy import MAPPOPolicy, ResidualPolicy, residual_action, save_run_policy
from swarm_env_baselines.ppo_core import RunningMeanStd, gae, mlp, ppo_policy_loss

#: Model selection: a collision costs as much as this many metres of mean formation error.
COLLISION_COST_M = 1.0
EVAL_COLUMNS = ("agent_steps", "wall_s", "score", "formation_error", "formation_error_ci95", "collisions",
                "collisions_ci95", "success_rate")
TRAIN_COLUMNS = ("agent_steps", "wall_s", "rollout_s", "update_s", "policy_loss", "value_loss", "imitation_loss",
                 "entropy", "std", "mean_reward", "contacts_per_agent_step", "intervention_rate", "first_ratio_error")
SHIELD_MODES = ("off", "teach", "execute")


@dataclass
class MAPPOConfig:
    """Everything that defines a MAPPO/IPPO run (each field is a command-line option)."""

    #: Built-in scenario name, a YAML path, or "random".
    scenario: str = "random"
    #: Extra SwarmEnv keyword arguments / random-generator knobs, as KEY=VALUE (YAML values).
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    #: More KEY=VALUE for the training worlds only (e.g. a training reward or denser crowds); validation uses env_kwargs.
    train_env_kwargs: dict[str, Any] = field(default_factory=dict)
    #: Critic input: central (MAPPO: env.state() + own observation) or local (IPPO: own observation).
    critic: str = "central"
    #: DAgger warm start of the actor from this expert policy ("none": from scratch).
    pretrain: str = "vo"
    #: DAgger rounds (the first driven by the expert).
    pretrain_rounds: int = 5
    #: Episodes per DAgger round.
    pretrain_episodes: int = 25
    #: Fitting epochs after each DAgger round.
    pretrain_epochs: int = 10
    #: The VO safety layer: off, teach (corrections as penalty and imitation targets), execute (the env runs them).
    shield: str = "off"
    #: Reward penalty per unit of shield correction (normalised action distance), with a shield.
    intervention_coef: float = 0.0
    #: Weight of the loss pulling the actor's mean to the shield's safe action where it intervened.
    imitation_coef: float = 0.0
    #: Fraction of the training over which imitation_coef decays linearly to 0 (0: constant).
    imitation_anneal: float = 0.0
    #: Teaching shield: weight of staying close to the current twist (commits to one side when avoiding).
    teach_w_current: float = 0.0
    #: Teaching shield: keep-right tie breaker (consistent sides in head-on encounters).
    teach_side_bias: float = 0.0
    #: Residual learning: the actor adds a bounded correction to this expert's action (e.g. vo).
    residual: str | None = None
    #: Largest residual correction (normalised action units).
    residual_scale: float = 0.5
    #: Training budget in agent-steps (one follower acting once), after the warm start.
    total_steps: int = 2_000_000
    #: Seed of the networks, the action sampling and the training worlds.
    seed: int = 0
    #: Env copies stepped together (the worlds of one batched engine, swarm_env.vector).
    n_copies: int = 8
    #: Worker processes for the worlds' physics (1: in the training process); the results do not depend on it.
    #: Not with --residual (its experts read the worlds in this process).
    env_procs: int = 1
    #: Rollout length per copy between updates.
    n_steps: int = 128
    #: Adam learning rate.
    learning_rate: float = 3e-4
    #: Discount factor.
    gamma: float = 0.99
    #: GAE lambda.
    gae_lambda: float = 0.95
    #: Clip range of the policy ratio.
    clip_range: float = 0.2
    #: Optimisation epochs per rollout.
    n_epochs: int = 5
    #: Minibatches per epoch.
    n_minibatches: int = 4
    #: Entropy bonus coefficient.
    ent_coef: float = 0.0
    #: Value loss coefficient.
    vf_coef: float = 0.5
    #: Gradient norm clip.
    max_grad_norm: float = 0.5
    #: Hidden layer sizes of the actor and of the critic.
    hidden: tuple[int, ...] = (128, 128)
    #: Initial log standard deviation of the actions (on the [-1, 1] action range).
    log_std_init: float = -0.5
    #: Updates that train the critic alone before the actor learns (lets a warm-started actor keep its skill).
    critic_warmup: int = 0
    #: Evaluate every this many agent-steps (0 = only at the end).
    eval_every: int = 400_000
    #: Validation seeds, e.g. 500-549.
    eval_seeds: str = "500-549"
    #: Background processes for validation (0: in the training process). Training is one thread, so on a
    #: machine with a free core 1 hides the validation time; the results are the same bit for bit.
    eval_workers: int = 0
    #: Torch threads (1 is fastest for these small networks).
    torch_threads: int = 1
    #: Save a resumable checkpoint (checkpoint/) every this many PPO updates (0: only after the warm start, on
    #: SIGINT/SIGTERM and at the end).
    checkpoint_every: int = 10
    #: Parent directory of run directories.
    runs_dir: str = "runs"
    #: Run directory name (default: mappo|ippo_<scenario>_s<seed>_<timestamp>).
    run_name: str | None = None
    #: Show a progress bar.
    progress: bool = True

    def __post_init__(self) -> None:
        if self.critic not in ("central", "local"):
            raise ValueError(f"critic must be 'central' or 'local', got {self.critic!r}")
        if self.shield not in SHIELD_MODES:
            raise ValueError(f"shield must be one of {', '.join(SHIELD_MODES)}, got {self.shield!r}")
        if self.pretrain in ("", "none", "None"):
            self.pretrain = "none"
        for name in ("total_steps", "n_copies", "n_steps", "n_epochs", "n_minibatches", "torch_threads", "env_procs"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive int, got {value!r}")
        for name in ("pretrain_rounds", "pretrain_episodes", "pretrain_epochs", "critic_warmup", "eval_every",
                     "eval_workers", "checkpoint_every"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise ValueError(f"{name} must be an int >= 0, got {value!r}")
        for name in ("intervention_coef", "imitation_coef", "residual_scale"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and np.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")
        if not 0.0 <= self.imitation_anneal <= 1.0:
            raise ValueError(f"imitation_anneal must be in [0, 1], got {self.imitation_anneal!r}")
        if self.shield == "off" and (self.intervention_coef or self.imitation_coef):
            raise ValueError("intervention_coef and imitation_coef need a shield (--shield teach or execute)")
        if self.env_procs > self.n_copies:
            raise ValueError(f"env_procs must be at most n_copies ({self.n_copies}), got {self.env_procs}")
        if self.residual and self.env_procs > 1:
            raise ValueError("a residual policy's experts read the worlds in the training process: use --env-procs 1")
        if self.residual and self.pretrain != "none":
            raise ValueError("a residual policy starts from its expert (zero correction): use --pretrain none")
        self.hidden = tuple(int(h) for h in self.hidden)

    @property
    def kind(self) -> str:
        return "mappo" if self.critic == "central" else "ippo"

    def to_json(self) -> str:
        return dumps(dataclasses.asdict(self))


# --------------------------------------------------------------------------- evaluation


def _world_factory(cfg: MAPPOConfig, shielded: bool) -> Any:
    from swarm_env.vector import EnvFactory

    return EnvFactory(cfg.scenario, {**cfg.env_kwargs, **cfg.train_env_kwargs}, shielded)


def make_env(cfg: MAPPOConfig, shielded: bool) -> Any:
    """One training world: a SwarmEnv of the run's scenario (``env_kwargs`` then ``train_env_kwargs``),
    wrapped in the safety layer if ``shielded`` (what each world of :func:`make_engine` is)."""
    return _world_factory(cfg, shielded)()


def make_engine(cfg: MAPPOConfig) -> Any:
    """The training worlds: a :class:`~swarm_env.vector.SwarmVectorEnv` of ``n_copies`` :func:`make_env`
    worlds (shielded for ``shield="execute"``), their physics in ``env_procs`` processes (1: this one)."""
    from swarm_env.vector import SwarmVectorEnv

    return SwarmVectorEnv.from_factories([_world_factory(cfg, cfg.shield == "execute")] * cfg.n_copies,
                                         n_procs=cfg.env_procs)


def evaluate(policy: MAPPOPolicy, cfg: MAPPOConfig, seeds: list[int]) -> dict[str, Any]:
    """Score ``policy`` on ``seeds`` with the leaderboard's episode loop, through the shield when the run
    executes through it (``shield="execute"``); ``score`` is formation error + 1 m per collision."""
    from swarm_env.env import SwarmEnv
    from swarm_env.harness.evaluation import run_episode, summarize
    from swarm_env.harness.policies import ShieldedPolicy

    env = SwarmEnv(cfg.scenario, **cfg.env_kwargs)
    scored: Any = ShieldedPolicy.around(policy) if cfg.shield == "execute" else policy
    episodes = [run_episode(env, scored, s) for s in seeds]
    env.close()
    s = summarize(episodes)
    s["score"] = s["formation_error"]["mean"] + COLLISION_COST_M * s["collisions"]["mean"]
    return s


def evaluate_saved(directory: str, cfg_json: str, seeds: list[int]) -> dict[str, Any]:
    """:func:`evaluate` of a policy saved by :meth:`Trainer.save` (what a validation worker runs: the same
    float32 weights and statistics as the live actor, so the same result bit for bit)."""
    import torch

    from swarm_env.env import SwarmEnv
    from swarm_env_baselines.mappo_policy import load_run_policy

    torch.set_num_threads(1)
    cfg = MAPPOConfig(**json.loads(cfg_json))
    env = SwarmEnv(cfg.scenario, **cfg.env_kwargs)
    policy = load_run_policy(directory, env)
    env.close()
    return evaluate(policy, cfg, seeds)


def _replace_dir(src: Path, dst: Path) -> None:
    """Make ``dst`` a copy of ``src``, swapped in whole (a reader never sees half a model)."""
    import shutil

    from swarm_env_baselines.safe_io import swap_in_dir

    tmp = dst.with_name(f".{dst.name}.tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    shutil.copytree(src, tmp)
    swap_in_dir(tmp, dst)


# --------------------------------------------------------------------------- training


@dataclass
class Batch:
    """One rollout of ``T`` steps of ``B = copies x followers`` agents, as the update needs it."""

    actor_in: np.ndarray  # (T, B, D) actor inputs, normalised as when the actions were drawn
    critic_in: list[Any]  # T tensors (B, C)
    actions: np.ndarray  # (T, B, 2) sampled actions (before clipping)
    logp: np.ndarray  # (T, B)
    values: np.ndarray  # (T, B)
    rewards: np.ndarray  # (T, B) scaled, bootstraps folded in
    dones: np.ndarray  # (T, B)
    safe: np.ndarray  # (T, B, 2) the shield's actions (teach/execute)
    intervened: np.ndarray  # (T, B) float 0/1
    contacts: int = 0

    @classmethod
    def empty(cls, t: int, b: int, d: int) -> Batch:
        return cls(np.zeros((t, b, d), np.float32), [], np.zeros((t, b, 2), np.float32), np.zeros((t, b), np.float32),
                   np.zeros((t, b)), np.zeros((t, b)), np.zeros((t, b)), np.zeros((t, b, 2), np.float32),
                   np.zeros((t, b), np.float32))


class Trainer:
    """The state of one run: the worlds (one :class:`~swarm_env.vector.SwarmVectorEnv` of ``n_copies``
    worlds), networks, statistics; :meth:`collect` then :meth:`update`."""

    def __init__(self, cfg: MAPPOConfig, run_dir: Path) -> None:
        import torch

        self.cfg = cfg
        self.run_dir = run_dir
        torch.set_num_threads(cfg.torch_threads)
        torch.manual_seed(cfg.seed)
        torch.use_deterministic_algorithms(True)
        self.gen = torch.Generator().manual_seed(cfg.seed)
        self.venv = make_engine(cfg)
        self.agents = list(self.venv.possible_agents)
        self.n, self.m = self.venv.num_agents, cfg.n_copies
        self.obs_dim = self.venv.single_observation_space.shape[0] + (2 if cfg.residual else 0)
        self.state_dim = self.venv.state_space.shape[0] if cfg.critic == "central" else 0
        self.actor = mlp([self.obs_dim, *cfg.hidden, 2])
        self.log_std = torch.nn.Parameter(torch.full((2,), float(cfg.log_std_init)))
        self.critic = mlp([self.obs_dim + self.state_dim, *cfg.hidden, 1])
        if cfg.residual:  # start at the expert: a zero correction
            with torch.no_grad():
                self.actor[-1].weight.mul_(0.01)
                self.actor[-1].bias.zero_()
        self.obs_rms = RunningMeanStd((self.obs_dim,))
        self.state_rms = RunningMeanStd((max(self.state_dim, 1),))
        self.ret_rms = RunningMeanStd(())
        self.experts: list[Any] = []
        if cfg.residual:
            from swarm_env.harness.policies import load_policy

            # One expert per world, given that world's env (the engine runs its worlds in this process).
            self.experts = [load_policy(cfg.residual, e) for e in self._world_envs()]
        self.shield_params: Any = None
        if cfg.shield == "teach":
            from swarm_env.safety import AvoidanceParams

            # The SafetyShield wrapper's defaults, plus the optional consistency terms of a teacher.
            self.shield_params = AvoidanceParams(w_heading=0.0, w_current=cfg.teach_w_current,
                                                 side_bias=cfg.teach_side_bias)
        self.pretrain_log: list[dict[str, float]] = []

    def _world_envs(self, indices: list[int] | None = None) -> list[Any]:
        """The worlds' own ``SwarmEnv`` objects (what an expert's ``reset(env, seed)`` takes)."""
        return self.venv.get_attr("unwrapped", indices)

    # ---------------------------------------------------------------- warm start
    def pretrain(self) -> None:
        """DAgger from ``cfg.pretrain`` (worlds 10000 + 1000 * seed on), then fixed observation statistics."""
        from swarm_env_baselines.imitation import DaggerSettings, dagger

        cfg = self.cfg
        settings = DaggerSettings(expert=cfg.pretrain, rounds=cfg.pretrain_rounds, episodes=cfg.pretrain_episodes,
                                  epochs=cfg.pretrain_epochs, first_seed=10_000 + 1000 * cfg.seed)
        env = make_env(cfg, False)
        self.pretrain_log = dagger(env, self.actor, self.obs_rms, settings, self.gen, progress=cfg.progress)
        env.close()

    # ---------------------------------------------------------------- rollouts
    def _inputs(self, k: int, obs: np.ndarray, world_state: Any) -> np.ndarray:
        """Actor inputs (N, D) of copy ``k`` from its observations ``obs`` (N, obs_dim): the observations,
        and for a residual the expert's actions in ``world_state`` (kept in ``base_actions``)."""
        if not self.cfg.residual:
            return obs
        # The expert's protocol takes observations by agent (it reads only their names).
        base = self.experts[k].act({a: obs[i] for i, a in enumerate(self.agents)}, world_state)
        self.base_actions[k] = np.stack([base[a] for a in self.agents])
        return np.concatenate([obs, self.base_actions[k]], axis=1)

    def _world_states(self) -> list[Any]:
        """Every world's current WorldState when an expert needs them (residual), else Nones."""
        return self.venv.call("world_state") if self.cfg.residual else [None] * self.m

    def start(self) -> None:
        """Start the first episode of every world (world ``k`` from seed ``100 * seed + k``)."""
        self._allocate()
        obs, _ = self.venv.reset(seed=100 * self.cfg.seed)
        states = self._world_states()
        for k, start in enumerate(self.venv.episode_starts()):
            self._begin_episode(k, start, obs[k], states[k])
        self._read_states()

    def _allocate(self) -> None:
        m, n = self.m, self.n
        self.base_actions = np.zeros((m, n, 2), np.float32)
        self.inputs = np.zeros((m, n, self.obs_dim), np.float32)
        self.states = np.zeros((m, max(self.state_dim, 1)), np.float32)
        self.returns = np.zeros((m, n))
        # What a checkpoint needs to rebuild each world as it is now (see :meth:`restore`): how its episode
        # began (the engine's episode_starts), and every action the world has executed since.
        self.episode_starts: list[dict[str, Any]] = [{} for _ in range(m)]
        self.episode_actions: list[list[np.ndarray]] = [[] for _ in range(m)]

    def _begin_episode(self, k: int, start: dict[str, Any], obs: np.ndarray, world_state: Any) -> None:
        """World ``k`` has begun an episode as ``start`` says (the engine's :meth:`episode_starts` entry), with
        first observations ``obs``: reset its expert and its inputs, forget the last episode's actions."""
        if self.experts:
            self.experts[k].reset(self._world_envs([k])[0], None)
        self.episode_starts[k], self.episode_actions[k] = start, []
        self.inputs[k] = self._inputs(k, obs, world_state)

    def _read_states(self) -> None:
        if self.state_dim:
            self.states[:] = self.venv.state()

    def critic_input(self, inputs: np.ndarray, states: np.ndarray) -> Any:
        import torch

        x = self.obs_rms.normalize(inputs).reshape(-1, self.obs_dim)
        if self.state_dim:
            x = np.concatenate([np.repeat(self.state_rms.normalize(states), self.n, axis=0), x], axis=1)
        return torch.as_tensor(x)

    def collect(self) -> Batch:
        """One rollout of ``n_steps`` steps of every world, one engine step each."""
        import torch

        cfg, m, n = self.cfg, self.m, self.n
        batch = Batch.empty(cfg.n_steps, m * n, self.obs_dim)
        for t in range(cfg.n_steps):
            self.obs_rms.update(self.inputs.reshape(-1, self.obs_dim))
            if self.state_dim:
                self.state_rms.update(self.states)
            x = torch.as_tensor(self.obs_rms.normalize(self.inputs).reshape(-1, self.obs_dim))
            cin = self.critic_input(self.inputs, self.states)
            with torch.no_grad():
                mean = self.actor(x)
                std = self.log_std.exp().expand_as(mean)
                action = mean + std * torch.randn(mean.shape, generator=self.gen)
                logp = torch.distributions.Normal(mean, std).log_prob(action).sum(-1)
                value = self.critic(cin).squeeze(-1)
            batch.actor_in[t], batch.actions[t], batch.logp[t], batch.values[t] = x.numpy(), action.numpy(), logp.numpy(), value.numpy()
            batch.critic_in.append(cin)
            sampled = np.clip(action.numpy(), -1.0, 1.0).reshape(m, n, 2)
            env_action = residual_action(self.base_actions, sampled, cfg.residual_scale) if cfg.residual else sampled
            self._step_worlds(env_action, batch, t)
        return batch

    def _step_worlds(self, action: np.ndarray, batch: Batch, t: int) -> None:
        """Step every world with ``action`` (M, N, 2) and write row ``t`` of ``batch``."""
        import torch

        cfg, m, n = self.cfg, self.m, self.n
        correction = None
        if cfg.shield == "teach":  # the safe action nearest to each sampled one, in the state it was sampled in
            from swarm_env.safety import shield_actions

            corrections = []
            for k, state in enumerate(self.venv.call("world_state")):
                res = shield_actions(state, action[k], self.shield_params)
                cols = slice(k * n, (k + 1) * n)
                batch.safe[t, cols], batch.intervened[t, cols] = res.actions, res.intervened
                corrections.append(res.correction)
            correction = np.stack(corrections)  # the shield's own dtype, as the penalty always had it
        obs, rew, terms, truncs, infos = self.venv.step(action)
        for k in range(m):
            self.episode_actions[k].append(np.array(action[k]))
        if cfg.shield == "execute":
            # float64 as the per-agent infos' Python floats were: the penalty below keeps its bits.
            correction = infos["shield_correction"].astype(np.float64)
            batch.safe[t] = infos["shield_action"].reshape(m * n, 2)
            batch.intervened[t] = (correction > 0).reshape(m * n)
        if correction is not None and cfg.intervention_coef:
            rew = rew - cfg.intervention_coef * correction
        batch.contacts += int(sum(infos[f"contacts_{g}"].sum() for g in ("robot", "obstacle", "human", "wall")))
        done = terms | truncs
        states = self._world_states()
        starts = self.venv.episode_starts() if done.any() else None
        # The return-scale statistics move world by world, in world order: each world's rewards are scaled
        # by the statistics after its own update (as when the worlds were stepped one by one).
        for k in range(m):
            cols = slice(k * n, (k + 1) * n)
            self.returns[k] = self.returns[k] * cfg.gamma + rew[k]
            self.ret_rms.update(self.returns[k])
            scaled = np.clip(rew[k] / np.sqrt(self.ret_rms.var + self.ret_rms.epsilon), -10.0, 10.0)
            if done[k]:
                if truncs[k] and not terms[k]:  # bootstrap a cut-off episode from its last state
                    last_in = self._inputs(k, infos["final_obs"][k], infos["final_world_state"][k])
                    last_state = infos["final_state"][k] if self.state_dim else np.zeros(1, np.float32)
                    with torch.no_grad():
                        scaled = scaled + cfg.gamma * self.critic(
                            self.critic_input(last_in[None], last_state[None])).squeeze(-1).numpy()
                self.returns[k] = 0.0
                assert starts is not None
                self._begin_episode(k, starts[k], obs[k], states[k])  # the engine's auto-reset: the stream goes on
            else:
                self.inputs[k] = self._inputs(k, obs[k], states[k])
            batch.rewards[t, cols] = scaled
            batch.dones[t, cols] = float(done[k])
        self._read_states()

    # ---------------------------------------------------------------- update
    def update(self, batch: Batch, optim: Any, update_index: int, n_updates: int) -> dict[str, float]:
        """PPO epochs over the rollout (critic only during the warm-up updates)."""
        import torch

        cfg = self.cfg
        with torch.no_grad():
            last_val = self.critic(self.critic_input(self.inputs, self.states)).squeeze(-1).numpy()
        adv = gae(batch.rewards, batch.values, batch.dones, last_val, cfg.gamma, cfg.gae_lambda)
        ret = adv + batch.values
        b_x = torch.as_tensor(batch.actor_in.reshape(-1, self.obs_dim))
        b_c = torch.cat(batch.critic_in)
        b_a = torch.as_tensor(batch.actions.reshape(-1, 2))
        b_logp = torch.as_tensor(batch.logp.reshape(-1))
        b_adv = torch.as_tensor(adv.reshape(-1), dtype=torch.float32)
        b_ret = torch.as_tensor(ret.reshape(-1), dtype=torch.float32)
        b_safe = torch.as_tensor(batch.safe.reshape(-1, 2))
        b_int = torch.as_tensor(batch.intervened.reshape(-1))
        im_coef = cfg.imitation_coef
        if cfg.imitation_anneal:
            im_coef *= max(0.0, 1.0 - update_index / (cfg.imitation_anneal * n_updates))
        actor_learns = update_index >= cfg.critic_warmup
        params = [*self.actor.parameters(), self.log_std, *self.critic.parameters()]
        size = b_x.shape[0]
        mb = max(1, size // cfg.n_minibatches)
        stats = []
        ratio0 = None  # the first minibatch's |ratio - 1|: 0 before any update (checked by the tests)
        for _epoch in range(cfg.n_epochs):
            order = torch.randperm(size, generator=self.gen)
            for start in range(0, size, mb):
                idx = order[start:start + mb]
                mean = self.actor(b_x[idx])
                dist = torch.distributions.Normal(mean, self.log_std.exp().expand_as(mean))
                pg, ratio_err = ppo_policy_loss(dist.log_prob(b_a[idx]).sum(-1), b_logp[idx], b_adv[idx], cfg.clip_range)
                if ratio0 is None:
                    ratio0 = ratio_err
                v_loss = 0.5 * (self.critic(b_c[idx]).squeeze(-1) - b_ret[idx]).pow(2).mean()
                entropy = dist.entropy().sum(-1).mean()
                # The imitation term averages over the whole minibatch (zero where the shield let the action
                # pass), so its weight relative to PPO's loss is the intervention rate times imitation_coef.
                im = (b_int[idx] * (mean - b_safe[idx]).pow(2).sum(-1)).sum() / len(idx)
                loss = cfg.vf_coef * v_loss
                if actor_learns:
                    loss = loss + pg - cfg.ent_coef * entropy + im_coef * im
                optim.zero_grad()
                loss.backward()
                torch.nn.utils.clip_grad_norm_(params, cfg.max_grad_norm)
                optim.step()
                stats.append((pg.item(), v_loss.item(), im.item(), entropy.item()))
        s = np.mean(stats, axis=0)
        return {"policy_loss": s[0], "value_loss": s[1], "imitation_loss": s[2], "entropy": s[3],
                "std": float(self.log_std.detach().exp().mean()), "first_ratio_error": ratio0 or 0.0}

    # ---------------------------------------------------------------- outputs
    def policy(self) -> MAPPOPolicy:
        """The current actor as a deterministic policy (with frozen copies of the statistics)."""
        if self.cfg.residual:
            from swarm_env.harness.policies import load_policy

            expert = load_policy(self.cfg.residual, self._world_envs([0])[0])
            return ResidualPolicy(self.actor, self.obs_rms.copy(), expert, self.cfg.residual_scale)
        return MAPPOPolicy(self.actor, self.obs_rms.copy())

    def save(self, directory: Path) -> Path:
        return save_run_policy(directory, self.actor, self.log_std, self.critic, self.obs_rms, self.state_rms, self.cfg)

    # ---------------------------------------------------------------- checkpoints
    def checkpoint_state(self, optim: Any) -> tuple[dict[str, Any], dict[str, Any]]:
        """Everything the trainer needs to go on from here, as ``(tensors, JSON values)`` for
        :func:`baselines.checkpointing.write_checkpoint` (the loop adds its counters): the networks, the
        optimizer, the statistics, the torch generators, and how each copy's episode began and went so far."""
        import torch

        from swarm_env_baselines.checkpointing import optimizer_to_files

        tensors: dict[str, Any] = {f"actor.{k}": v for k, v in self.actor.state_dict().items()}
        tensors.update({f"critic.{k}": v for k, v in self.critic.state_dict().items()})
        tensors["log_std"] = self.log_std.detach()
        optim_tensors, optim_meta = optimizer_to_files(optim)
        tensors.update(optim_tensors)
        tensors["rng.sampling"] = self.gen.get_state()  # actions and minibatch order
        tensors["rng.torch"] = torch.get_rng_state()
        # Kept to check the rebuilt worlds against (restore), and because the returns are not rebuilt.
        tensors["rollout.inputs"] = torch.from_numpy(self.inputs.copy())
        tensors["rollout.states"] = torch.from_numpy(self.states.copy())
        tensors["rollout.returns"] = torch.from_numpy(self.returns.copy())
        for k, actions in enumerate(self.episode_actions):
            if actions:
                tensors[f"episode.{k}.actions"] = torch.from_numpy(np.stack(actions))
        stats = {name: {**rms.to_json(), "frozen": rms.frozen}
                 for name, rms in (("obs_rms", self.obs_rms), ("state_rms", self.state_rms), ("ret_rms", self.ret_rms))}
        return tensors, {"optimizer": optim_meta, "statistics": stats, "episode_starts": self.episode_starts}

    def restore(self, tensors: dict[str, Any], meta: dict[str, Any], optim: Any, source: Path) -> None:
        """Load a :meth:`checkpoint_state` (read from ``source``, named in errors) into this fresh trainer.

        The worlds cannot be saved mid-episode (their physics lives in pymunk), so each is rebuilt: a
        fresh env (:func:`make_env`) is reset as the world's episode began (the seed, or the world
        generator's state) and every action it executed since is played again, with its expert; the
        env is deterministic, so the world, its observations and the expert come back as they were, and
        it takes the world's place in the engine (:meth:`~swarm_env.vector.SwarmVectorEnv.set_world`).
        The rebuilt inputs are checked against the saved ones.
        """
        import torch

        from swarm_env_baselines.checkpointing import optimizer_from_files

        try:
            self.actor.load_state_dict({k[6:]: v for k, v in tensors.items() if k.startswith("actor.")}, strict=True)
            self.critic.load_state_dict({k[7:]: v for k, v in tensors.items() if k.startswith("critic.")}, strict=True)
            with torch.no_grad():
                self.log_std.copy_(tensors["log_std"])
            self.gen.set_state(tensors["rng.sampling"])
            torch.set_rng_state(tensors["rng.torch"])
            stats = meta["statistics"]
            for name in ("obs_rms", "state_rms", "ret_rms"):
                rms = RunningMeanStd.from_json(stats[name])
                rms.frozen = bool(stats[name]["frozen"])
                setattr(self, name, rms)
            starts = meta["episode_starts"]
            saved_inputs, saved_states = tensors["rollout.inputs"].numpy(), tensors["rollout.states"].numpy()
            returns = tensors["rollout.returns"].numpy()
        except (KeyError, TypeError, ValueError, RuntimeError) as exc:
            raise ValueError(f"{source}: not a checkpoint of this run's networks ({exc})") from None
        optimizer_from_files(optim, tensors, meta["optimizer"], source)
        self._allocate()
        if len(starts) != self.m or returns.shape != self.returns.shape:
            raise ValueError(f"{source}: the checkpoint has {len(starts)} env copies, this run {self.m}")
        self.returns[:] = returns
        self.venv.reset(seed=100 * self.cfg.seed)  # every world gets an episode; each is then replaced
        agents = self.agents
        for k, start in enumerate(starts):
            env = make_env(self.cfg, self.cfg.shield == "execute")
            if start.get("seed") is not None:
                obs, _ = env.reset(seed=start["seed"])
            else:
                _set_world_rng(env, start["rng"])
                obs, _ = env.reset()
            if self.experts:
                self.experts[k].reset(env.unwrapped, None)
            self.inputs[k] = self._inputs(k, np.stack([obs[a] for a in agents]), env.unwrapped.world_state())
            actions = tensors.get(f"episode.{k}.actions")
            for action in ([] if actions is None else actions.numpy()):
                obs, *_ = env.step({a: action[i] for i, a in enumerate(agents)})
                self.episode_actions[k].append(np.array(action))
                self.inputs[k] = self._inputs(k, np.stack([obs[a] for a in agents]), env.unwrapped.world_state())
            self.episode_starts[k] = start
            self.venv.set_world(k, env, start)
        self._read_states()
        if not (np.array_equal(self.inputs, saved_inputs) and np.array_equal(self.states, saved_states)):
            import warnings

            warnings.warn(f"{source}: the rebuilt env copies differ from the checkpoint's (another swarm_env or "
                          "scenario?); training goes on from the rebuilt worlds", stacklevel=2)

    def close(self) -> None:
        self.venv.close()


def _set_world_rng(env: Any, state: dict[str, Any]) -> None:
    """Put ``env``'s world generator in ``state`` (an ``episode_starts()`` entry's ``rng`` of the engine)."""
    bit_generator = getattr(np.random, state["bit_generator"])()
    bit_generator.state = state
    env.unwrapped._rng = np.random.Generator(bit_generator)  # noqa: SLF001


def _write_row(path: Path, columns: tuple[str, ...], row: dict[str, Any]) -> None:
    with open(path, "a", newline="") as fh:  # streamed: readable while the run goes on
        csv.writer(fh).writerow([row[c] for c in columns])


def _fmt(x: Any) -> Any:
    return f"{x:.6g}" if isinstance(x, float) else x


#: The run directory's resumable checkpoint (the latest only; :meth:`Trainer.checkpoint_state`).
CHECKPOINT_DIR = "checkpoint"
CHECKPOINT_FORMAT = "swarm_env.mappo-checkpoint/1"
#: What ``--resume`` may change: the budget, and settings that leave the results as they are.
RESUME_OVERRIDES = ("total_steps", "eval_workers", "env_procs", "progress")


def train(cfg: MAPPOConfig) -> Path:
    """Run ``cfg`` to completion in a new run directory and return it.

    Saves a resumable checkpoint under ``checkpoint/`` every ``cfg.checkpoint_every`` updates, after
    the warm start, and at the end. On SIGINT or SIGTERM it finishes the current update, saves the
    checkpoint and the policy files (``mappo:<run dir>`` loads them), and raises
    :class:`~swarm_env_baselines.checkpointing.TrainingInterrupted`; :func:`resume` goes on from there.
    Raises ``FileExistsError`` if the run directory already holds a run.
    """
    from swarm_env_baselines.checkpointing import claim_run_dir
    from swarm_env_baselines.train import package_versions

    stamp = time.strftime("%Y%m%d-%H%M%S", time.gmtime())
    run_dir = Path(cfg.runs_dir) / (cfg.run_name or f"{cfg.kind}_{Path(cfg.scenario).stem}_s{cfg.seed}_{stamp}")
    claim_run_dir(run_dir)
    (run_dir / "config.json").write_text(cfg.to_json() + "\n")
    write_json(run_dir / "versions.json", package_versions())
    for name, columns in (("eval.csv", EVAL_COLUMNS), ("train.csv", TRAIN_COLUMNS)):
        with open(run_dir / name, "w", newline="") as fh:
            csv.writer(fh).writerow(columns)
    return _run(cfg, run_dir, None)


def resume(run_dir: str | Path, **overrides: Any) -> Path:
    """Go on with the run in ``run_dir`` from its latest checkpoint, to its ``total_steps``; return the run directory.

    Restores the networks, the optimizer, the statistics, the update and step counters (so the
    imitation and warm-up schedules), the torch generators and the env copies (see
    :meth:`Trainer.restore`): with the same ``total_steps``, the run ends with the same networks, bit
    for bit, as if it had never stopped. ``overrides`` may set only :data:`RESUME_OVERRIDES` (a
    larger ``total_steps`` trains a finished run further; it is written to ``config.json``).
    Raises ``FileNotFoundError`` / ``ValueError`` naming the file for a missing or bad checkpoint.
    """
    from swarm_env_baselines.checkpointing import read_checkpoint, resume_config

    run_dir = Path(run_dir)
    cfg_path = resume_config(run_dir, overrides, RESUME_OVERRIDES)
    try:
        saved = json.loads(cfg_path.read_text())
        cfg = MAPPOConfig(**{**saved, **overrides})
    except (ValueError, TypeError) as exc:
        raise ValueError(f"{cfg_path}: not a baselines.mappo config ({exc})") from None
    checkpoint = run_dir / CHECKPOINT_DIR
    if not (checkpoint / "state.json").is_file():
        raise FileNotFoundError(f"--resume {run_dir}: no checkpoint in it (the run stopped before its first one, "
                                f"during the warm start): start a new run")
    state = read_checkpoint(checkpoint, CHECKPOINT_FORMAT)
    if overrides:
        from swarm_env_baselines.safe_io import _atomic

        with _atomic(cfg_path) as tmp:
            tmp.write_text(cfg.to_json() + "\n")
    return _run(cfg, run_dir, state)


def _run(cfg: MAPPOConfig, run_dir: Path, checkpoint: tuple[dict[str, Any], dict[str, Any]] | None) -> Path:
    """The training loop of :func:`train` (``checkpoint`` None: from the start) and :func:`resume`."""
    from swarm_env_baselines.checkpointing import StopRequest

    with StopRequest() as stop:
        return _train_loop(cfg, run_dir, checkpoint, stop)


def _train_loop(cfg: MAPPOConfig, run_dir: Path, checkpoint: tuple[dict[str, Any], dict[str, Any]] | None,
                stop: Any) -> Path:
    import torch
    from tqdm import tqdm

    from swarm_env_baselines.checkpointing import TrainingInterrupted, csv_rows, truncate_csv, write_checkpoint
    from swarm_env_baselines.config import parse_seeds

    eval_seeds = parse_seeds(cfg.eval_seeds)
    trainer = Trainer(cfg, run_dir)
    params = [*trainer.actor.parameters(), trainer.log_std, *trainer.critic.parameters()]
    optim = torch.optim.Adam(params, lr=cfg.learning_rate, eps=1e-5)
    batch_size = cfg.n_steps * trainer.m * trainer.n
    n_updates = max(1, cfg.total_steps // batch_size)
    best = float("inf")
    history: list[dict[str, Any]] = []
    steps_done = updates_done = 0
    last_eval: int | None = None
    next_eval = cfg.eval_every or None
    # Evaluations handed to a worker and not yet recorded: (agent-steps, wall_s, snapshot dir, future).
    pending: list[tuple[int, float, Path, Any]] = []
    resubmit: list[tuple[int, float]] = []
    if checkpoint is None:
        t0 = time.perf_counter()
        if cfg.pretrain != "none":
            # DAgger cannot stop half-way and save: a signal ends the run at once.
            with stop.immediate(f"interrupted during the warm start: nothing to resume yet; start again with another "
                                f"--run-name (or delete {run_dir})"):
                trainer.pretrain()
            with open(run_dir / "pretrain.csv", "w", newline="") as fh:
                w = csv.DictWriter(fh, fieldnames=list(trainer.pretrain_log[0]))
                w.writeheader()
                w.writerows(trainer.pretrain_log)
        pretrain_s = time.perf_counter() - t0
        trainer.start()
    else:
        try:  # the envs are open: close them on a refusal
            tensors, meta = checkpoint
            source = run_dir / CHECKPOINT_DIR
            try:
                steps_done, updates_done = int(meta["agent_steps"]), int(meta["updates"])
                best = float("inf") if meta["best"] is None else float(meta["best"])
                history, last_eval, next_eval = list(meta["history"]), meta["last_eval"], meta["next_eval"]
                pretrain_s, t0 = float(meta["pretrain_s"]), time.perf_counter() - float(meta["wall_s"])
                resubmit = [(int(s), float(w)) for s, w in meta["pending_evals"]]
                rows = {name: int(meta["csv_rows"][name]) for name in ("train.csv", "eval.csv")}
            except (KeyError, TypeError, ValueError) as exc:
                raise ValueError(f"{source / 'state.json'}: {exc}") from None
            if updates_done >= n_updates and not resubmit:
                raise ValueError(f"--resume {run_dir}: the run is complete ({steps_done} agent-steps, total_steps "
                                 f"{cfg.total_steps}); pass a larger --total-steps to train it further")
            for name, count in rows.items():  # drop what was logged after the checkpoint
                truncate_csv(run_dir / name, count)
            print(f"resuming {run_dir} at update {updates_done} of {n_updates} ({steps_done} agent-steps)",
                  file=sys.stderr)
            trainer.restore(tensors, meta, optim, source)
        except BaseException:
            trainer.close()
            raise
    # Validation in background processes (cfg.eval_workers): each evaluation point saves a snapshot under
    # evals/, a worker scores it, and results are recorded in order as they arrive.
    pool = None
    if cfg.eval_workers:
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        from swarm_env_baselines.checkpointing import ignore_interrupts

        pool = ProcessPoolExecutor(cfg.eval_workers, mp_context=mp.get_context("spawn"), initializer=ignore_interrupts)

    def record(steps: int, wall_s: float, s: dict[str, Any], keep: Callable[[], Any]) -> None:
        nonlocal best
        row = {"agent_steps": steps, "wall_s": wall_s, "score": s["score"],
               "formation_error": s["formation_error"]["mean"], "formation_error_ci95": s["formation_error"]["ci95"],
               "collisions": s["collisions"]["mean"], "collisions_ci95": s["collisions"]["ci95"],
               "success_rate": s["success_rate"]["mean"]}
        history.append(row)
        _write_row(run_dir / "eval.csv", EVAL_COLUMNS, row)
        if row["score"] < best:
            best = row["score"]
            keep()

    def collect_results(wait: bool) -> None:
        while pending and (wait or pending[0][3].done()):
            steps, wall_s, snapshot, future = pending.pop(0)
            record(steps, wall_s, future.result(), lambda snapshot=snapshot: _replace_dir(snapshot, run_dir / "best"))

    def submit(steps: int, wall_s: float, snapshot: Path) -> None:
        if pool is None:  # a resumed run's pending evaluation, now without workers
            record(steps, wall_s, evaluate_saved(str(snapshot), cfg.to_json(), eval_seeds),
                   lambda: _replace_dir(snapshot, run_dir / "best"))
            return
        pending.append((steps, wall_s, snapshot, pool.submit(evaluate_saved, str(snapshot), cfg.to_json(), eval_seeds)))

    def evaluate_and_keep() -> None:
        nonlocal last_eval
        last_eval = steps_done
        wall_s = round(time.perf_counter() - t0, 1)
        if pool is None:
            summary = evaluate(trainer.policy(), cfg, eval_seeds)
            record(steps_done, wall_s, summary, lambda: trainer.save(run_dir / "best"))
            return
        submit(steps_done, wall_s, trainer.save(run_dir / "evals" / str(steps_done)))
        collect_results(wait=False)

    def save_checkpoint() -> None:
        # Evaluations still with a worker are listed, their snapshots kept: a resume scores them again.
        tensors, meta = trainer.checkpoint_state(optim)
        meta = {"format": CHECKPOINT_FORMAT, "updates": updates_done, "agent_steps": steps_done,
                "best": best if np.isfinite(best) else None,
                "history": history, "last_eval": last_eval, "next_eval": next_eval, "pretrain_s": pretrain_s,
                "wall_s": time.perf_counter() - t0, "pending_evals": [[p[0], p[1]] for p in pending],
                "csv_rows": {name: csv_rows(run_dir / name) for name in ("train.csv", "eval.csv")}, **meta}
        write_checkpoint(run_dir / CHECKPOINT_DIR, tensors, meta)

    finished = False
    bar = tqdm(total=n_updates * batch_size, initial=steps_done, unit="step", disable=not cfg.progress, desc=cfg.kind)
    try:
        for steps, wall_s in resubmit:
            snapshot = run_dir / "evals" / str(steps)
            if (snapshot / "policy.json").is_file():
                submit(steps, wall_s, snapshot)
            else:
                print(f"warning: {snapshot} is gone: the evaluation at {steps} agent-steps is skipped", file=sys.stderr)
        if checkpoint is None:
            if cfg.eval_every:
                evaluate_and_keep()  # the starting point (after the warm start)
            save_checkpoint()
        for u in range(updates_done, n_updates):
            t_roll = time.perf_counter()
            batch = trainer.collect()
            t_upd = time.perf_counter()
            stats = trainer.update(batch, optim, u, n_updates)
            steps_done += batch_size
            updates_done = u + 1
            bar.update(batch_size)
            row = {"agent_steps": steps_done, "wall_s": round(time.perf_counter() - t0, 1),
                   "rollout_s": round(t_upd - t_roll, 3), "update_s": round(time.perf_counter() - t_upd, 3),
                   "mean_reward": float(batch.rewards.mean()), "contacts_per_agent_step": batch.contacts / batch_size,
                   "intervention_rate": float(batch.intervened.mean()), **stats}
            _write_row(run_dir / "train.csv", TRAIN_COLUMNS, {k: _fmt(v) for k, v in row.items()})
            if next_eval is not None and steps_done >= next_eval:
                next_eval += cfg.eval_every
                evaluate_and_keep()
            collect_results(wait=False)
            if stop.requested:
                collect_results(wait=True)
                save_checkpoint()
                trainer.save(run_dir)
                finished = True  # a clean stop: nothing pending, evals/ may go
                raise TrainingInterrupted(stop.signum, (
                    f"interrupted at {steps_done} of {n_updates * batch_size} agent-steps; saved {run_dir}/policy.* "
                    f"and {run_dir / CHECKPOINT_DIR}/. Resume with: swarm-env train mappo --resume {run_dir}"))
            if cfg.checkpoint_every and updates_done % cfg.checkpoint_every == 0 and updates_done < n_updates:
                save_checkpoint()
        if last_eval != steps_done:  # the final policy is always scored
            evaluate_and_keep()
        collect_results(wait=True)
        save_checkpoint()  # a finished run can be trained further (--resume with a larger --total-steps)
        finished = True
    finally:
        bar.close()
        trainer.close()
        if pool is not None:
            pool.shutdown(cancel_futures=True)
        if finished:
            import shutil

            shutil.rmtree(run_dir / "evals", ignore_errors=True)
    wall = time.perf_counter() - t0
    trainer.save(run_dir)
    summary = {"agent_steps": steps_done, "wall_s": round(wall, 1), "pretrain_s": round(pretrain_s, 1),
               "steps_per_s": round(steps_done / (wall - pretrain_s), 1), "best_score": best,
               "best": min(history, key=lambda r: r["score"]), "final": history[-1]}
    write_json(run_dir / "summary.json", summary)
    from swarm_env_baselines.plots import plot_learning_curve

    plot_learning_curve(run_dir / "eval.csv", run_dir / "learning_curve.png", title=run_dir.name)
    return run_dir


def build_parser() -> argparse.ArgumentParser:
    from swarm_env_baselines.config import add_dataclass_options

    parser = argparse.ArgumentParser(prog="swarm-env train mappo", description=__doc__.split("\n\n")[0])
    parser.add_argument("--resume", metavar="RUN_DIR", default=argparse.SUPPRESS,
                        help="go on with this run from its latest checkpoint (its config.json; only --total-steps, "
                             "--eval-workers, --env-procs and --progress may be given with it)")
    add_dataclass_options(parser, MAPPOConfig)
    return parser


def main(argv: list[str] | None = None) -> int:
    from swarm_env_baselines.checkpointing import run_training

    args = vars(build_parser().parse_args(argv))
    for name in ("env_kwargs", "train_env_kwargs"):
        if name in args:
            args[name] = dict(args[name])
    if "resume" in args:
        where = args.pop("resume")
        run = run_training(lambda: resume(where, **args))
    else:
        run = run_training(lambda: train(MAPPOConfig(**args)))
    if isinstance(run, int):
        return run
    print(run)
    print((run / "summary.json").read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
