"""MAPPO and IPPO on swarm_env: PPO with one decentralised actor shared by every follower.

.. code-block:: console

    swarm-env train mappo --scenario random --total-steps 2e6 --seed 0                  # MAPPO
    swarm-env train mappo --scenario random --total-steps 2e6 --seed 0 --critic local   # IPPO
    swarm-env train mappo ... --shield teach --imitation-coef 1.0   # the safety layer as a teacher
    swarm-env train mappo ... --shield execute                      # trained through the safety layer
    swarm-env train mappo ... --residual vo --shield execute        # a learned correction of vo
    swarm-env train mappo --resume runs/<run>                       # go on after Ctrl-C or a crash

A small PyTorch implementation in the CleanRL spirit, written to read top to bottom (:func:`_train_loop`:
collect, update, log, evaluate, checkpoint). The actor maps one follower's observation to a Gaussian
over its normalised twist (parameter sharing: one network for all followers); the critic is
**centralised** (``critic="central"``, MAPPO, Yu et al. 2022: the global ``env.state()`` joined to the
follower's own observation, the "agent-specific global state", :class:`~swarm_env_baselines.nets.CentralCritic`)
or **local** (``critic="local"``, IPPO: the observation alone). Observations and states are normalised
by running statistics (moved once per rollout), rewards by a running estimate of the return's scale;
truncated episodes are bootstrapped from the value of their last state; the update sees the actor
inputs exactly as normalised when the actions were drawn (``train.csv``'s ``first_ratio_error`` stays 0).

Rollouts run at the engine's speed: ``n_copies`` worlds (default 64) of the batched engine
(:class:`swarm_env.vector.engine.SwarmVectorEnv`, their physics in ``env_procs`` processes) step in one call,
the critic's global state of every world is one compiled call, and everything the trainer does per
step is over ``(worlds, followers)`` arrays: one actor forward for every agent of every world, the
rewards, return statistics and bootstraps as array operations, the values and log-probabilities of the
whole rollout in one forward each after it. Python loops over worlds remain only where an expert or
the teaching shield reads each world (``residual``, ``shield="teach"``). The PPO update runs in a learner
process (``learner_process``, the default; :mod:`swarm_env_baselines.mappo_learner`) on rollout ``k`` while
rollout ``k + 1`` is collected on the other core, or here after each rollout (``--no-learner-process``).
``tests/test_mappo_engine.py`` holds reference runs of the update here, bit for bit, for every mode and number
of worker processes (``tests/test_mappo_learner.py``: the learner process computes the same update);
``benchmarks/train_throughput.py`` measures the trainer against the raw engine (docs/performance.md,
"Training throughput"). Live metrics: ``train.csv``/``eval.csv`` and TensorBoard scalars under ``tb/``
(:mod:`swarm_env_baselines.run_log`); a progress bar in agent-steps with their rate.

Options that the shipped baselines use (docs/baselines.md gives their commands and results):

* ``pretrain`` (default ``vo``): a DAgger warm start of the actor from that expert
  (:mod:`swarm_env_baselines.imitation`, a few minutes) so that PPO starts from a policy that holds its
  slot; the observation statistics are then fixed. ``--pretrain none`` starts from scratch.
* ``shield``: the VO safety layer of :mod:`swarm_env.control.safety`. ``execute``: every world is in a
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
  anticipatory clearance term of :mod:`swarm_env.scoring.rewards`).

Data split: PPO's worlds are the generator streams of seeds ``100 * seed + copy``; DAgger's
seeds ``10000 + 1000 * seed`` onwards; model selection uses validation seeds ``500-549``
(every ``eval_every`` agent-steps, collisions costing 1 m each; the best is kept in ``best/``);
the test seeds ``1000-1049`` are left to the leaderboard.

A run directory ``<runs_dir>/<run_name>/`` holds ``config.json``, ``versions.json``,
``policy.safetensors`` + ``policy.json`` (actor, critic and normalisation statistics as
tensors and JSON: loading runs no code; :mod:`swarm_env_baselines.mappo_policy`), ``best/``,
``pretrain.csv`` (DAgger rounds), ``eval.csv`` (validation, streamed), ``train.csv`` (per update: losses,
entropy, approximate KL, clip fraction, explained variance, action std, episode return, collisions and
formation error of the episodes that ended, contact and intervention rates, rollout and update seconds,
agent-steps/s), ``tb/`` (the same as TensorBoard events), ``learning_curve.png``, ``summary.json`` and
``checkpoint/`` (the latest resumable state: :func:`resume`,
``swarm-env train mappo --resume <run dir>``; SIGINT/SIGTERM save it and the policy before exiting).
Load it with ``mappo:<run dir>`` (or ``mappo:<run dir>/best``) anywhere a policy spec is accepted.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import functools
import json
import os
import re
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from swarm_env.control.safety import AvoidanceParams, shield_actions
from swarm_env.env import SwarmEnv
from swarm_env.harness.leaderboard import parse_seeds
from swarm_env.harness.policies import load_policy
from swarm_env.jsonio import dumps
from swarm_env.vector.engine import EnvFactory
from swarm_env_baselines.checkpointing import (
    CHECKPOINT_DIR,
    StopRequest,
    TrainingInterrupted,
    csv_rows,
    optimizer_from_files,
    optimizer_to_files,
    resume_run_dir,
    start_run_dir,
    trainer_main,
    truncate_csv,
    write_checkpoint,
)
from swarm_env_baselines.imitation import DaggerSettings, dagger
from swarm_env_baselines.mappo_learner import (
    LEARNER_SEED_OFFSET,
    Batch,
    Networks,
    ProcessLearner,
    build_networks,
    make_optimizer,
    ppo_update,
)
from swarm_env_baselines.mappo_policy import (
    MAPPOPolicy,
    ResidualPolicy,
    load_run_policy,
    residual_action,
    save_run_policy,
)
from swarm_env_baselines.options import trainer_parser
from swarm_env_baselines.ppo_core import RunningMeanStd
from swarm_env_baselines.run_log import RunLog, episode_stats, finish_run
from swarm_env_baselines.validation import EVAL_COLUMNS, Validation, evaluate_policy
from swarm_env_baselines.worlds import TrainingWorlds

TRAIN_COLUMNS = ("agent_steps", "wall_s", "rollout_s", "update_s", "agent_steps_per_s", "policy_loss", "value_loss",
                 "imitation_loss", "entropy", "approx_kl", "clip_fraction", "explained_variance", "std", "mean_reward",
                 "episodes", "episode_return", "collisions_per_episode", "episode_formation_error",
                 "contacts_per_agent_step", "intervention_rate", "first_ratio_error")
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
    total_steps: int = 20_000_000
    #: Seed of the networks, the action sampling and the training worlds.
    seed: int = 0
    #: Env copies stepped together (the worlds of one batched engine, swarm_env.vector.engine); 64 measured best
    #: (docs/performance.md, "Training throughput").
    n_copies: int = 64
    #: Worker processes for the worlds' physics (1: in the training process); the results do not depend on it.
    #: Not with --residual (its experts read the worlds in this process).
    env_procs: int = 1
    #: With env_procs 1: draw the next random worlds in a worker process while the worlds step (the same worlds
    #: bit for bit: swarm_env.vector.engine.SwarmVectorEnv(prefetch_scenarios=True)).
    prefetch_worlds: bool = True
    #: Run the PPO update in a learner process of its own, on rollout k while the trainer collects rollout k + 1
    #: (a policy lag of one update; swarm_env_baselines.mappo_learner). Off: the update follows each rollout in
    #: this process, on torch_threads threads. Results differ between the two; each is deterministic.
    learner_process: bool = True
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
    #: Optimisation epochs per rollout (2 validates as well as 5 in the same wall time: docs/performance.md,
    #: "The sweep behind the defaults").
    n_epochs: int = 2
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
    eval_every: int = 2_000_000
    #: Validation seeds, e.g. 500-549.
    eval_seeds: str = "500-549"
    #: Background processes for validation (0: in the training process). Training is one thread, so on a
    #: machine with a free core 1 hides the validation time; the results are the same bit for bit.
    eval_workers: int = 0
    #: Torch threads of the PPO update (the rollout's per-step forwards always use one; the engine is idle
    #: meanwhile, so 2 uses the second core: docs/performance.md, "Training throughput"); results depend on it.
    torch_threads: int = 2
    #: Where the networks and the update run: cpu, or cuda / cuda:K when torch sees a GPU (the rollout's
    #: engine is on the CPU either way; bits differ between devices).
    device: str = "cpu"
    #: Write TensorBoard scalars under <run dir>/tb beside train.csv and eval.csv.
    tensorboard: bool = True
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
        if not isinstance(self.device, str) or not re.fullmatch(r"cpu|cuda(:\d+)?", self.device):
            raise ValueError(f"device must be cpu, cuda or cuda:K, got {self.device!r}")
        self.hidden = tuple(int(h) for h in self.hidden)

    @property
    def kind(self) -> str:
        return "mappo" if self.critic == "central" else "ippo"

    def to_json(self) -> str:
        return dumps(dataclasses.asdict(self))


# --------------------------------------------------------------------------- worlds and validation


def _world_factory(cfg: MAPPOConfig, shielded: bool) -> Any:
    return EnvFactory(cfg.scenario, {**cfg.env_kwargs, **cfg.train_env_kwargs}, shielded)


def make_env(cfg: MAPPOConfig, shielded: bool) -> Any:
    """One training world: a SwarmEnv of the run's scenario (``env_kwargs`` then ``train_env_kwargs``),
    wrapped in the safety layer if ``shielded`` (what each world of :func:`make_worlds` is)."""
    return _world_factory(cfg, shielded)()


def make_worlds(cfg: MAPPOConfig) -> Any:
    """The training worlds: :class:`~swarm_env_baselines.worlds.TrainingWorlds` of ``n_copies`` :func:`make_env`
    worlds (shielded for ``shield="execute"``), their physics in ``env_procs`` processes (1: this one)."""
    return TrainingWorlds(_world_factory(cfg, cfg.shield == "execute"), cfg.n_copies, cfg.env_procs, cfg.prefetch_worlds)


def evaluate(policy: MAPPOPolicy, cfg: MAPPOConfig, seeds: list[int]) -> dict[str, Any]:
    """Score ``policy`` on ``seeds`` (:func:`swarm_env_baselines.validation.evaluate_policy`) in the run's
    validation worlds (``env_kwargs``), through the shield when the run executes through it."""
    return evaluate_policy(policy, cfg.scenario, cfg.env_kwargs, seeds, shielded=cfg.shield == "execute")


def evaluate_saved(directory: str, cfg_json: str, seeds: list[int]) -> dict[str, Any]:
    """:func:`evaluate` of a policy saved by :meth:`Trainer.save` (what a validation worker runs: the same
    float32 weights and statistics as the live actor, so the same result bit for bit)."""
    import torch


    torch.set_num_threads(1)
    cfg = MAPPOConfig(**json.loads(cfg_json))
    env = SwarmEnv(cfg.scenario, **cfg.env_kwargs)
    policy = load_run_policy(directory, env)
    env.close()
    return evaluate(policy, cfg, seeds)


# --------------------------------------------------------------------------- training


class Trainer:
    """The state of one run: the worlds (one :class:`~swarm_env.vector.engine.SwarmVectorEnv` of ``n_copies``
    worlds), networks, statistics; :meth:`collect` then :meth:`update`.

    Every array of the rollout has the worlds and followers as axes ``(M, N)``: one actor forward per
    step for all agents, the rewards, return statistics and bootstraps over whole arrays, the critic's
    values once per rollout; Python loops over worlds remain only where an expert or the teaching shield
    reads each world's state (``residual``, ``shield="teach"``)."""

    def __init__(self, cfg: MAPPOConfig, run_dir: Path) -> None:
        import torch

        self.cfg = cfg
        self.run_dir = run_dir
        torch.set_num_threads(1)  # the rollout's per-step forwards are small: threads only add overhead
        torch.manual_seed(cfg.seed)
        torch.use_deterministic_algorithms(True)
        self.gen = torch.Generator().manual_seed(cfg.seed)  # on the CPU whatever the device: the same draws
        self.device = _torch_device(cfg.device)
        self.worlds = make_worlds(cfg)
        self.venv = self.worlds.venv
        self.agents = list(self.venv.possible_agents)
        self.n, self.m = self.venv.num_agents, cfg.n_copies
        self.obs_dim = self.venv.single_observation_space.shape[0] + (2 if cfg.residual else 0)
        self.state_dim = self.venv.state_space.shape[0] if cfg.critic == "central" else 0
        nets = build_networks(cfg, self.obs_dim, self.state_dim, self.device)
        self.actor, self.critic, self.log_std = nets.actor, nets.critic, nets.log_std
        self.obs_rms = RunningMeanStd((self.obs_dim,))
        self.state_rms = RunningMeanStd((max(self.state_dim, 1),))
        self.ret_rms = RunningMeanStd(())
        self.experts: list[Any] = []
        if cfg.residual:
            # One expert per world, given that world's env (the engine runs its worlds in this process).
            self.experts = [load_policy(cfg.residual, e) for e in self._world_envs()]
        self.shield_params: Any = None
        if cfg.shield == "teach":
            # The SafetyShield wrapper's defaults, plus the optional consistency terms of a teacher.
            self.shield_params = AvoidanceParams(w_heading=0.0, w_current=cfg.teach_w_current,
                                                 side_bias=cfg.teach_side_bias)
        self.pretrain_log: list[dict[str, float]] = []

    def networks(self) -> Networks:
        """The actor, its log standard deviation and the critic (the trainer's own, not copies)."""
        return Networks(self.actor, self.critic, self.log_std, self.device)

    def parameters(self) -> list[Any]:
        """Everything the optimiser trains: the actor, its log standard deviation, the critic."""
        return self.networks().parameters()

    def _world_envs(self, indices: list[int] | None = None) -> list[Any]:
        """The worlds' own ``SwarmEnv`` objects (what an expert's ``reset(env, seed)`` takes)."""
        return self.venv.get_attr("unwrapped", indices)

    # ---------------------------------------------------------------- warm start
    def pretrain(self) -> None:
        """DAgger from ``cfg.pretrain`` (worlds 10000 + 1000 * seed on), then fixed observation statistics."""
        cfg = self.cfg
        settings = DaggerSettings(expert=cfg.pretrain, rounds=cfg.pretrain_rounds, episodes=cfg.pretrain_episodes,
                                  epochs=cfg.pretrain_epochs, first_seed=10_000 + 1000 * cfg.seed)
        env = make_env(cfg, False)
        self.pretrain_log = dagger(env, self.actor, self.obs_rms, settings, self.gen, progress=cfg.progress)
        env.close()

    # ---------------------------------------------------------------- rollouts
    def _inputs(self, obs: np.ndarray, worlds: list[int], world_states: list[Any] | None) -> np.ndarray:
        """Actor inputs ``(K, N, D)`` of the worlds ``worlds`` from their observations ``obs`` ``(K, N, obs_dim)``:
        the observations, and for a residual the expert's actions in ``world_states`` (kept in ``base_actions``)."""
        if not self.cfg.residual:
            return obs
        assert world_states is not None
        for j, k in enumerate(worlds):  # the expert's protocol takes observations by agent (it reads their names)
            base = self.experts[k].act({a: obs[j, i] for i, a in enumerate(self.agents)}, world_states[j])
            self.base_actions[k] = np.stack([base[a] for a in self.agents])
        return np.concatenate([obs, self.base_actions[worlds]], axis=2)

    def start(self) -> None:
        """Start the first episode of every world (world ``k`` from seed ``100 * seed + k``)."""
        self._allocate()
        obs = self.worlds.reset(seed=100 * self.cfg.seed)
        self._begin_episodes(list(range(self.m)), obs)
        self._read_states()
        self._update_statistics(self.inputs, self.states)  # the first rollout is normalised by its first step

    def _allocate(self) -> None:
        m, n = self.m, self.n
        self.base_actions = np.zeros((m, n, 2), np.float32)
        self.inputs = np.zeros((m, n, self.obs_dim), np.float32)
        self.states = np.zeros((m, max(self.state_dim, 1)), np.float32)
        self.returns = np.zeros((m, n))
        self.episode_return = np.zeros(m)  # the running episode's raw reward, mean over followers

    def _begin_episodes(self, worlds: list[int], obs: np.ndarray) -> None:
        """The worlds ``worlds`` have begun an episode, with first observations ``obs`` ``(K, N, obs_dim)``:
        reset their experts and inputs."""
        envs = self._world_envs(worlds) if self.experts else []
        for k, env in zip(worlds, envs):
            self.experts[k].reset(env, None)
        self.inputs[worlds] = self._inputs(obs, worlds, None if not self.experts else
                                           [e.world_state() for e in envs])

    def _read_states(self) -> None:
        if self.state_dim:
            self.states[:] = self.venv.state()

    def normalised(self) -> tuple[np.ndarray, np.ndarray]:
        """The current inputs ``(M, N, D)`` and states ``(M, S)``, normalised by the current statistics."""
        return self.obs_rms.normalize(self.inputs), self.state_rms.normalize(self.states)

    def value(self, obs: np.ndarray, states: np.ndarray) -> np.ndarray:
        """The critic's values ``(K, N)`` of normalised inputs ``(K, N, D)`` and states ``(K, S)``."""
        return self.networks().value(obs, states)

    def collect(self, values: bool = True) -> Batch:
        """One rollout of ``n_steps`` steps of every world: per step one engine step and one actor forward
        for every agent; the values and log-probabilities of the whole rollout are then one forward each
        (``values=False``: the values are left at 0, for a learner process that computes them)."""
        import torch

        cfg, m, n = self.cfg, self.m, self.n
        batch = Batch.empty(cfg.n_steps, m, n, self.obs_dim, max(self.state_dim, 1))
        means = torch.zeros((cfg.n_steps, m, n, 2))
        raw_obs = np.zeros((cfg.n_steps, m, n, self.obs_dim), np.float32)
        raw_states = np.zeros((cfg.n_steps, m, max(self.state_dim, 1)), np.float32)
        for t in range(cfg.n_steps):
            raw_obs[t], raw_states[t] = self.inputs, self.states
            batch.obs[t], batch.states[t] = self.normalised()
            with torch.no_grad():
                mean = self.actor(torch.from_numpy(batch.obs[t]).to(self.device)).cpu()
                action = mean + self.log_std.exp().cpu() * torch.randn(mean.shape, generator=self.gen)
            means[t], batch.actions[t] = mean, action.numpy()
            sampled = np.clip(batch.actions[t], -1.0, 1.0)
            env_action = residual_action(self.base_actions, sampled, cfg.residual_scale) if cfg.residual else sampled
            self._step_worlds(env_action, batch, t)
        with torch.no_grad():  # the networks did not change during the rollout: one large forward each
            dist = torch.distributions.Normal(means, self.log_std.exp().cpu().expand_as(means))
            batch.logp[:] = dist.log_prob(torch.from_numpy(batch.actions)).sum(-1).numpy()
        if values:
            batch.values[:] = self.value(batch.obs, batch.states)
        self._update_statistics(raw_obs, raw_states)
        return batch

    def _update_statistics(self, inputs: np.ndarray, states: np.ndarray) -> None:
        """Move the input and state statistics by a rollout's raw inputs ``(..., D)`` and states ``(..., S)``.

        Once per rollout (as RLlib's filters are synchronised once per iteration), not per step: the inputs
        of a rollout are all normalised by the statistics of the rollouts before it, and the update sees
        them as they were normalised when the actions were drawn."""
        self.obs_rms.update(inputs.reshape(-1, self.obs_dim))
        if self.state_dim:
            self.state_rms.update(states.reshape(-1, self.state_dim))

    def _step_worlds(self, action: np.ndarray, batch: Batch, t: int) -> None:
        """Step every world with ``action`` (M, N, 2) and write row ``t`` of ``batch``."""
        cfg = self.cfg
        correction = None
        if cfg.shield == "teach":  # the safe action nearest to each sampled one, in the state it was sampled in
            corrections = []
            for k, state in enumerate(self.venv.call("world_state")):
                res = shield_actions(state, action[k], self.shield_params)
                batch.safe[t, k], batch.intervened[t, k] = res.actions, res.intervened
                corrections.append(res.correction)
            correction = np.stack(corrections)
        obs, rew, terms, truncs, infos = self.worlds.step(action)
        if cfg.shield == "execute":
            correction = infos["shield_correction"].astype(np.float64)
            batch.safe[t] = infos["shield_action"]
            batch.intervened[t] = correction > 0
        if correction is not None and cfg.intervention_coef:
            rew = rew - cfg.intervention_coef * correction
        batch.contacts += int(sum(infos[f"contacts_{g}"].sum() for g in ("robot", "obstacle", "human", "wall")))
        # The return-scale statistics: one update per step over every agent of every world.
        self.returns = self.returns * cfg.gamma + rew
        self.ret_rms.update(self.returns)
        scaled = np.clip(rew / np.sqrt(self.ret_rms.var + self.ret_rms.epsilon), -10.0, 10.0)
        self.episode_return += rew.mean(axis=1)
        done = terms | truncs
        ended = np.flatnonzero(done).tolist()
        if ended:
            cut = [k for k in ended if not terms[k]]
            if cut:  # bootstrap the cut-off episodes from the value of their last state, in one critic call
                finals = self._inputs(np.stack([infos["final_obs"][k] for k in cut]), cut,
                                      [infos["final_world_state"][k] for k in cut] if self.experts else None)
                last_states = (np.stack([infos["final_state"][k] for k in cut]) if self.state_dim
                               else np.zeros((len(cut), 1), np.float32))
                scaled[cut] += cfg.gamma * self.value(self.obs_rms.normalize(finals),
                                                      self.state_rms.normalize(last_states))
            self.returns[ended] = 0.0
            batch.episode_returns += self.episode_return[ended].tolist()
            batch.episode_metrics += [infos["final_metrics"][k] for k in ended]
            self.episode_return[ended] = 0.0
        batch.rewards[t] = scaled
        batch.dones[t] = done
        running = np.flatnonzero(~done).tolist()
        if running:
            self.inputs[running] = self._inputs(obs[running], running, self._world_states_of(running))
        if ended:  # the engine's auto-reset: the worlds' streams go on
            self._begin_episodes(ended, obs[ended])
        self._read_states()

    def _world_states_of(self, worlds: list[int]) -> list[Any] | None:
        """The WorldStates of ``worlds`` when an expert needs them (residual), else None."""
        return self.venv.call("world_state", indices=worlds) if self.experts else None

    # ---------------------------------------------------------------- update
    def update(self, batch: Batch, optim: Any, update_index: int, n_updates: int) -> dict[str, float]:
        """PPO epochs over the rollout (critic only during the warm-up updates), on ``torch_threads`` threads.
        Minibatches are world-steps, each with its ``N`` followers (the critic's state part is computed once
        per world-step)."""
        import torch

        cfg = self.cfg
        torch.set_num_threads(cfg.torch_threads)  # the update's large minibatches (the engine is idle meanwhile)
        try:
            return ppo_update(self.networks(), optim, self.gen, self.cfg, batch, self.value(*self.normalised()),
                              update_index, n_updates)
        finally:
            torch.set_num_threads(1)

    # ---------------------------------------------------------------- outputs
    def policy(self) -> MAPPOPolicy:
        """The current actor as a deterministic policy (with frozen copies of the statistics)."""
        import copy

        actor = self.actor if self.device.type == "cpu" else copy.deepcopy(self.actor).cpu()
        if self.cfg.residual:
            expert = load_policy(self.cfg.residual, self._world_envs([0])[0])
            return ResidualPolicy(actor, self.obs_rms.copy(), expert, self.cfg.residual_scale)
        return MAPPOPolicy(actor, self.obs_rms.copy())

    def save(self, directory: Path) -> Path:
        return save_run_policy(directory, self.actor, self.log_std, self.critic, self.obs_rms, self.state_rms, self.cfg)

    # ---------------------------------------------------------------- checkpoints
    def checkpoint_state(self, optim: Any) -> tuple[dict[str, Any], dict[str, Any]]:
        """Everything the trainer needs to go on from here, as ``(tensors, JSON values)`` for
        :func:`baselines.checkpointing.write_checkpoint` (the loop adds its counters): the networks, the
        optimizer, the statistics, the torch generators, and how each copy's episode began and went so far."""
        import torch


        tensors: dict[str, Any] = {f"actor.{k}": v for k, v in self.actor.state_dict().items()}
        tensors.update({f"critic.{k}": v for k, v in self.critic.state_dict().items()})
        tensors["log_std"] = self.log_std.detach()
        optim_tensors, optim_meta = optimizer_to_files(optim)
        tensors.update(optim_tensors)
        tensors["rng.sampling"] = self.gen.get_state()  # actions and minibatch order
        tensors["rng.torch"] = torch.get_rng_state()
        # Kept to check the rebuilt worlds against (restore), and because the returns are not rebuilt.
        tensors = {k: v.cpu() for k, v in tensors.items()}
        tensors["rollout.inputs"] = torch.from_numpy(self.inputs.copy())
        tensors["rollout.states"] = torch.from_numpy(self.states.copy())
        tensors["rollout.returns"] = torch.from_numpy(self.returns.copy())
        tensors["rollout.episode_return"] = torch.from_numpy(self.episode_return.copy())
        arrays, starts = self.worlds.checkpoint()
        tensors.update({k: torch.from_numpy(v) for k, v in arrays.items()})
        stats = {name: {**rms.to_json(), "frozen": rms.frozen}
                 for name, rms in (("obs_rms", self.obs_rms), ("state_rms", self.state_rms), ("ret_rms", self.ret_rms))}
        return tensors, {"optimizer": optim_meta, "statistics": stats, "episode_starts": starts}

    def restore(self, tensors: dict[str, Any], meta: dict[str, Any], optim: Any, source: Path) -> None:
        """Load a :meth:`checkpoint_state` (read from ``source``, named in errors) into this fresh trainer.

        The worlds cannot be saved mid-episode (their physics lives in pymunk), so each is rebuilt by
        :meth:`~swarm_env_baselines.worlds.TrainingWorlds.restore` (reset as its episode began, its actions
        played again) with its expert following it; the env is deterministic, so the world, its
        observations and the expert come back as they were. The rebuilt inputs are checked against the
        saved ones.
        """
        import torch


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
            episode_return = tensors["rollout.episode_return"].numpy()
        except (KeyError, TypeError, ValueError, RuntimeError) as exc:
            raise ValueError(f"{source}: not a checkpoint of this run's networks ({exc})") from None
        optimizer_from_files(optim, tensors, meta["optimizer"], source)
        self._allocate()
        if len(starts) != self.m or returns.shape != self.returns.shape or episode_return.shape != (self.m,):
            raise ValueError(f"{source}: the checkpoint has {len(starts)} env copies, this run {self.m}")
        self.returns[:] = returns
        self.episode_return[:] = episode_return

        def follow(k: int, env: Any, obs: dict[str, np.ndarray], t: int) -> None:
            if self.experts and t == 0:
                self.experts[k].reset(env.unwrapped, None)
            raw = np.stack([obs[a] for a in self.agents])[None]
            self.inputs[k] = self._inputs(raw, [k], [env.unwrapped.world_state()])[0]

        arrays = {k: v.numpy() for k, v in tensors.items() if k.startswith("episode.")}
        self.worlds.restore(arrays, starts, 100 * self.cfg.seed, follow)
        self._read_states()
        if not (np.array_equal(self.inputs, saved_inputs) and np.array_equal(self.states, saved_states)):
            import warnings

            warnings.warn(f"{source}: the rebuilt env copies differ from the checkpoint's (another swarm_env or "
                          "scenario?); training goes on from the rebuilt worlds", stacklevel=2)

    def close(self) -> None:
        self.worlds.close()


class InlineLearner:
    """The update in the training process, right after each rollout (:meth:`Trainer.update`); the interface of
    :class:`~swarm_env_baselines.mappo_learner.ProcessLearner`."""

    def __init__(self, trainer: Trainer, optim: Any) -> None:
        self._trainer, self._optim = trainer, optim
        self._stats: dict[str, float] = {}

    def submit(self, batch: Batch, last: tuple[np.ndarray, np.ndarray], update_index: int, n_updates: int) -> None:
        self._stats = self._trainer.update(batch, self._optim, update_index, n_updates)

    def result(self, batch: Batch) -> dict[str, float]:
        return self._stats

    def state(self) -> None:
        return None  # the trainer's own optimiser and generator are the whole state

    def close(self) -> None:
        pass


def learner_generator(cfg: MAPPOConfig, checkpoint: tuple[dict[str, Any], dict[str, Any]] | None) -> Any:
    """The state of a learner process's minibatch-order generator: the checkpoint's, or a fresh one of the seed."""
    import torch

    if checkpoint is not None:
        try:
            return checkpoint[0]["rng.learner"]
        except KeyError:
            raise ValueError("the checkpoint has no learner-process generator (rng.learner)") from None
    return torch.Generator().manual_seed(cfg.seed + LEARNER_SEED_OFFSET).get_state()


def _torch_device(name: str) -> Any:
    """``torch.device(name)``, refused with one line if it names a GPU that torch does not see."""
    import torch

    device = torch.device(name)
    if device.type == "cuda":
        # cuBLAS's deterministic mode (torch.use_deterministic_algorithms) needs this before its first call.
        os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")
        if not torch.cuda.is_available():
            raise ValueError(f"--device {name}: torch sees no GPU (torch.cuda.is_available() is False; this torch "
                             f"is {torch.__version__})")
        index = device.index or 0
        if index >= torch.cuda.device_count():
            raise ValueError(f"--device {name}: torch sees {torch.cuda.device_count()} GPU(s)")
    return device


CHECKPOINT_FORMAT = "swarm_env.mappo-checkpoint/1"
#: What ``--resume`` may change: the budget, and settings that leave the results as they are.
RESUME_OVERRIDES = ("total_steps", "eval_workers", "env_procs", "prefetch_worlds", "progress", "tensorboard")


def train(cfg: MAPPOConfig) -> Path:
    """Run ``cfg`` to completion in a new run directory and return it.

    Saves a resumable checkpoint under ``checkpoint/`` every ``cfg.checkpoint_every`` updates, after
    the warm start, and at the end. On SIGINT or SIGTERM it finishes the current update, saves the
    checkpoint and the policy files (``mappo:<run dir>`` loads them), and raises
    :class:`~swarm_env_baselines.checkpointing.TrainingInterrupted`; :func:`resume` goes on from there.
    Raises ``FileExistsError`` if the run directory already holds a run.
    """
    run_dir = start_run_dir(cfg, f"{cfg.kind}_{Path(cfg.scenario).stem}_s{cfg.seed}", TRAIN_COLUMNS, EVAL_COLUMNS)
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
    cfg, state = resume_run_dir(run_dir, overrides, RESUME_OVERRIDES, MAPPOConfig, CHECKPOINT_FORMAT)
    # The checkpoint says where its updates ran (runs from before the learner process have no such key).
    cfg = dataclasses.replace(cfg, learner_process=state[1].get("learner") == "process")
    return _run(cfg, Path(run_dir), state)


def _run(cfg: MAPPOConfig, run_dir: Path, checkpoint: tuple[dict[str, Any], dict[str, Any]] | None) -> Path:
    """The training loop of :func:`train` (``checkpoint`` None: from the start) and :func:`resume`."""
    with StopRequest() as stop:
        return _train_loop(cfg, run_dir, checkpoint, stop)


def _train_loop(cfg: MAPPOConfig, run_dir: Path, checkpoint: tuple[dict[str, Any], dict[str, Any]] | None,
                stop: Any) -> Path:
    """Collect a rollout of every world, update, log; evaluate and checkpoint on schedule (:class:`_Run` holds the
    run's state: the trainer, the learner, the validation, the log and the counters)."""
    from tqdm import tqdm

    run = _Run(cfg, run_dir, checkpoint, stop)
    finished = False
    bar = tqdm(total=run.n_updates * run.batch_size, initial=run.steps_done, unit="step", unit_scale=True,
               disable=not cfg.progress, desc=cfg.kind, dynamic_ncols=True)
    try:
        if checkpoint is None:
            if cfg.eval_every:
                run.evaluate_now()  # the starting point (after the warm start)
            run.save_checkpoint()
        for u in range(run.updates_done, run.n_updates):
            row = run.update(u)
            bar.update(run.batch_size)
            bar.set_postfix(ret=f"{row['episode_return']:.3g}", coll=f"{row['collisions_per_episode']:.2g}",
                            refresh=False)
            if run.next_eval is not None and run.steps_done >= run.next_eval:
                run.next_eval += cfg.eval_every
                run.evaluate_now()
            run.validation.collect(wait=False)
            if stop.requested:
                run.validation.collect(wait=True)
                run.save_checkpoint()
                run.trainer.save(run_dir)
                finished = True  # a clean stop: nothing pending, evals/ may go
                raise TrainingInterrupted(stop.signum, (
                    f"interrupted at {run.steps_done} of {run.n_updates * run.batch_size} agent-steps; saved "
                    f"{run_dir}/policy.* and {run_dir / CHECKPOINT_DIR}/. Resume with: swarm-env train mappo "
                    f"--resume {run_dir}"))
            done = run.updates_done
            if cfg.checkpoint_every and done % cfg.checkpoint_every == 0 and done < run.n_updates:
                run.save_checkpoint()
        if run.validation.last_eval != run.steps_done:  # the final policy is always scored
            run.evaluate_now()
        run.validation.collect(wait=True)
        run.save_checkpoint()  # a finished run can be trained further (--resume with a larger --total-steps)
        finished = True
    finally:
        bar.close()
        run.close(finished)

    # --- the run's files: the final policy, a summary and the learning curve
    wall = time.perf_counter() - run.t0
    run.trainer.save(run_dir)
    summary = {"agent_steps": run.steps_done, "wall_s": round(wall, 1), "pretrain_s": round(run.pretrain_s, 1),
               "steps_per_s": round(run.steps_done / (wall - run.pretrain_s), 1), "best_score": run.validation.best}
    finish_run(run_dir, summary, run.validation.history)
    return run_dir


class _Run:
    """One training run's state between updates: the trainer and its optimiser, the learner (in this process or
    its own), the validation, the log, the budget in PPO updates and the counters. Built for a new run (the warm
    start, then the first worlds) or from a checkpoint (the worlds, the counters and a pending rollout)."""

    def __init__(self, cfg: MAPPOConfig, run_dir: Path, checkpoint: tuple[dict[str, Any], dict[str, Any]] | None,
                 stop: Any) -> None:
        self.cfg, self.run_dir, self.stop = cfg, run_dir, stop
        eval_seeds = parse_seeds(cfg.eval_seeds)
        self.trainer = trainer = Trainer(cfg, run_dir)
        self.optim = make_optimizer(cfg, trainer.networks())
        self.batch_size = cfg.n_steps * trainer.m * trainer.n
        self.n_updates = max(1, cfg.total_steps // self.batch_size)
        self.steps_done = self.updates_done = 0
        self.pending: Batch | None = None  # a rollout collected but not yet learned from (with a learner process)
        self.pending_s = 0.0  # the seconds its collection took
        self.next_eval = cfg.eval_every or None
        self.log: RunLog | None = None
        self.validation = Validation(run_dir, lambda: evaluate(trainer.policy(), cfg, eval_seeds),
                                     functools.partial(evaluate_saved, cfg_json=cfg.to_json(), seeds=eval_seeds),
                                     lambda row: self.log.eval(row) if self.log is not None else None,
                                     cfg.eval_workers)
        try:
            if checkpoint is None:
                self._start()
            else:
                self._resume(checkpoint)
            # The update's side: here after each rollout, or a learner process one rollout behind.
            self.learner = (ProcessLearner(cfg, trainer.networks(), self.optim, learner_generator(cfg, checkpoint))
                            if cfg.learner_process else InlineLearner(trainer, self.optim))
        except BaseException:
            trainer.close()
            self.validation.close(finished=False)
            if self.log is not None:
                self.log.close()
            raise

    def _start(self) -> None:
        """A new run: the warm start (if any), then the worlds and the log."""
        cfg, run_dir, trainer = self.cfg, self.run_dir, self.trainer
        self.t0 = time.perf_counter()
        if cfg.pretrain != "none":
            # DAgger cannot stop half-way and save: a signal ends the run at once.
            with self.stop.immediate(f"interrupted during the warm start: nothing to resume yet; start again with "
                                     f"another --run-name (or delete {run_dir})"):
                trainer.pretrain()
            with open(run_dir / "pretrain.csv", "w", newline="") as fh:
                w = csv.DictWriter(fh, fieldnames=list(trainer.pretrain_log[0]))
                w.writeheader()
                w.writerows(trainer.pretrain_log)
        self.pretrain_s = time.perf_counter() - self.t0
        trainer.start()
        self.log = RunLog(run_dir, TRAIN_COLUMNS, EVAL_COLUMNS, cfg.tensorboard)

    def _resume(self, checkpoint: tuple[dict[str, Any], dict[str, Any]]) -> None:
        """A resumed run: its counters, its logs cut back to the checkpoint, its worlds and its pending rollout."""
        cfg, run_dir = self.cfg, self.run_dir
        tensors, meta = checkpoint
        source = run_dir / CHECKPOINT_DIR
        try:
            self.steps_done, self.updates_done = int(meta["agent_steps"]), int(meta["updates"])
            self.next_eval = meta["next_eval"]
            self.pretrain_s, self.t0 = float(meta["pretrain_s"]), time.perf_counter() - float(meta["wall_s"])
            rows = {name: int(meta["csv_rows"][name]) for name in ("train.csv", "eval.csv")}
            if self.updates_done >= self.n_updates and not meta["pending_evals"]:
                raise ValueError(f"--resume {run_dir}: the run is complete ({self.steps_done} agent-steps, "
                                 f"total_steps {cfg.total_steps}); pass a larger --total-steps to train it further")
            for name, count in rows.items():  # drop what was logged after the checkpoint
                truncate_csv(run_dir / name, count)
            self.log = RunLog(run_dir, TRAIN_COLUMNS, EVAL_COLUMNS, cfg.tensorboard, purge_step=self.steps_done + 1)
            self.validation.resume(meta)
        except (KeyError, TypeError) as exc:
            raise ValueError(f"{source / 'state.json'}: {exc}") from None
        print(f"resuming {run_dir} at update {self.updates_done} of {self.n_updates} ({self.steps_done} agent-steps)",
              file=sys.stderr)
        self.trainer.restore(tensors, meta, self.optim, source)
        self.pending = Batch.from_checkpoint(tensors, meta, source)

    def update(self, u: int) -> dict[str, Any]:
        """PPO update ``u``: its rollout (collected now, or during the previous update with a learner process,
        which then gets the next one collected while it learns), the update, and the row logged to ``train.csv``."""
        cfg, trainer, batch_size = self.cfg, self.trainer, self.batch_size
        t_roll = time.perf_counter()
        if self.pending is None:
            batch = trainer.collect(values=not cfg.learner_process)
            rollout_s = collecting_s = time.perf_counter() - t_roll
        else:  # collected during the previous update
            batch, rollout_s, collecting_s = self.pending, self.pending_s, 0.0
        self.learner.submit(batch, trainer.normalised(), u, self.n_updates)
        self.pending = None
        if cfg.learner_process and u + 1 < self.n_updates:  # the next rollout while the learner updates on this one
            t_next = time.perf_counter()
            self.pending = trainer.collect(values=False)
            self.pending_s = time.perf_counter() - t_next
            collecting_s += self.pending_s
        stats = self.learner.result(batch)
        t_end = time.perf_counter()
        self.steps_done += batch_size
        self.updates_done = u + 1
        # update_s: the time spent on the update, or waiting for the learner process beyond the collection.
        row = {"agent_steps": self.steps_done, "wall_s": round(t_end - self.t0, 1), "rollout_s": round(rollout_s, 3),
               "update_s": round(t_end - t_roll - collecting_s, 3), "agent_steps_per_s": batch_size / (t_end - t_roll),
               "mean_reward": float(batch.rewards.mean()), "contacts_per_agent_step": batch.contacts / batch_size,
               "intervention_rate": float(batch.intervened.mean()),
               **episode_stats(batch.episode_returns, batch.episode_metrics), **stats}
        assert self.log is not None
        self.log.train(row)
        return row

    def evaluate_now(self) -> None:
        self.validation.evaluate(self.steps_done, round(time.perf_counter() - self.t0, 1), self.trainer.save)

    def save_checkpoint(self) -> None:
        """The run as it stands, with the pending rollout and the learner's generator, in ``checkpoint/``."""
        cfg, run_dir = self.cfg, self.run_dir
        learner_rng = self.learner.state()  # (first: it brings the learner process's optimiser state into `optim`)
        tensors, meta = self.trainer.checkpoint_state(self.optim)
        if learner_rng is not None:
            tensors["rng.learner"] = learner_rng
        pending_tensors, pending_meta = Batch.to_checkpoint(self.pending)
        tensors.update(pending_tensors)
        meta = {"format": CHECKPOINT_FORMAT, "updates": self.updates_done, "agent_steps": self.steps_done,
                "next_eval": self.next_eval, "pretrain_s": self.pretrain_s, "wall_s": time.perf_counter() - self.t0,
                "csv_rows": {name: csv_rows(run_dir / name) for name in ("train.csv", "eval.csv")},
                "learner": "process" if cfg.learner_process else "inline", **pending_meta,
                **self.validation.state(), **meta}
        write_checkpoint(run_dir / CHECKPOINT_DIR, tensors, meta)

    def close(self, finished: bool) -> None:
        self.learner.close()
        self.trainer.close()
        self.validation.close(finished)
        if self.log is not None:
            self.log.close()


def build_parser() -> argparse.ArgumentParser:
    return trainer_parser("swarm-env train mappo", __doc__, MAPPOConfig, RESUME_OVERRIDES)


def main(argv: list[str] | None = None) -> int:
    return trainer_main(build_parser(), argv, MAPPOConfig, train, resume)


if __name__ == "__main__":
    raise SystemExit(main())
