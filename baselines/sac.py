"""Shared-parameter SAC on the batched engine: one actor and one twin critic for every follower.

.. code-block:: console

    swarm-env train sac --scenario random --total-steps 2e6 --seed 0
    swarm-env train sac --resume runs/<run>          # go on after Ctrl-C or a crash
    swarm-env run --policy isac:runs/<run>/best ...  # play the best validated actor

Soft actor-critic (Haarnoja et al. 2018, with the learned temperature of the 2019 version) in the
shared-parameter form navground and PettingZoo's SISL baselines use: every follower of every world is an
agent; its transitions ``(o_i, a_i, r_i, o'_i, terminal)`` go into one replay buffer; one squashed
Gaussian actor and one pair of Q-networks of the follower's own observation and action serve all of
them (independent learners, as IPPO is for PPO). Per engine step the ``M x N`` agents act with one
actor forward and their transitions are appended as arrays; every ``train_every`` engine steps the
learner takes ``gradient_steps`` steps on minibatches of ``batch_size`` transitions.

* Inputs are normalised by running statistics of the observations (updated as transitions arrive) and
  rewards scaled by the running standard deviation of the discounted return (as :mod:`mappo` does),
  both applied when a minibatch is drawn: the buffer keeps raw observations and rewards.
* An episode cut by the time limit is bootstrapped from its last observation (``infos["final_obs"]``);
  only a termination (the leader arrived with the formation, or a collision that ends the episode)
  stops the bootstrap.
* ``learning_starts`` agent-steps of uniform random actions fill the buffer before the first update.

The run directory is :mod:`mappo`'s: ``config.json``, ``versions.json``, ``policy.safetensors`` +
``policy.json`` (tensors and JSON; loading runs no code), ``best/`` (the validation's best), ``train.csv``,
``eval.csv``, TensorBoard events under ``tb/``, ``learning_curve.png``, ``summary.json`` and
``checkpoint/`` (the networks, optimisers, temperature, statistics, generators, the replay buffer's
filled part and the worlds' episodes so far: a resumed run ends bit for bit as an uninterrupted one).
Validation is :mod:`validation`'s (seeds 500-549, formation error + 1 m per collision). Data split as
for MAPPO: training worlds are the generator streams of seeds ``100 * seed + world``.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import math
import re
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from swarm_env.harness.leaderboard import parse_seeds
from swarm_env.jsonio import dumps, write_json
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
from swarm_env_baselines.mappo import _torch_device
from swarm_env_baselines.mappo_policy import MAPPOPolicy, SquashedMeanActor, load_sac_policy
from swarm_env_baselines.options import trainer_parser
from swarm_env_baselines.ppo_core import RunningMeanStd, mlp
from swarm_env_baselines.run_log import RunLog, episode_stats, finish_run
from swarm_env_baselines.safe_io import SAC_FORMAT as FORMAT
from swarm_env_baselines.safe_io import _atomic
from swarm_env_baselines.validation import EVAL_COLUMNS, Validation, evaluate_policy
from swarm_env_baselines.worlds import TrainingWorlds

CHECKPOINT_FORMAT = "swarm_env.sac-checkpoint/1"
#: What ``--resume`` may change: the budget, and settings that leave the results as they are.
RESUME_OVERRIDES = ("total_steps", "eval_workers", "env_procs", "prefetch_worlds", "progress", "tensorboard")
#: (log_every is not among them: it decides where a checkpoint can fall.)
TRAIN_COLUMNS = ("agent_steps", "wall_s", "rollout_s", "update_s", "agent_steps_per_s", "q_loss", "policy_loss",
                 "alpha", "entropy", "q_mean", "mean_reward", "episodes", "episode_return", "collisions_per_episode",
                 "episode_formation_error", "contacts_per_agent_step")
#: The log-standard-deviation range of the actor's Gaussian before the tanh squashing.
LOG_STD_MIN, LOG_STD_MAX = -5.0, 2.0


@dataclass
class SACConfig:
    """Everything that defines a shared-parameter SAC run (each field is a command-line option)."""

    #: Built-in scenario name, a YAML path, or "random".
    scenario: str = "random"
    #: Extra SwarmEnv keyword arguments / random-generator knobs, as KEY=VALUE (YAML values).
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    #: More KEY=VALUE for the training worlds only; validation uses env_kwargs.
    train_env_kwargs: dict[str, Any] = field(default_factory=dict)
    #: Training budget in agent-steps (one follower acting once).
    total_steps: int = 2_000_000
    #: Seed of the networks, the action sampling, the minibatches and the training worlds.
    seed: int = 0
    #: Worlds stepped together by the batched engine.
    n_copies: int = 64
    #: Worker processes for the worlds' physics (1: in the training process); the results do not depend on it.
    env_procs: int = 1
    #: With env_procs 1: draw the next random worlds in a worker process while the worlds step (the same worlds
    #: bit for bit: swarm_env.vector.engine.SwarmVectorEnv(prefetch_scenarios=True)).
    prefetch_worlds: bool = True
    #: Replay buffer capacity in agent transitions.
    buffer_size: int = 500_000
    #: Agent-steps of uniform random actions before the first update.
    learning_starts: int = 25_600
    #: Transitions per minibatch.
    batch_size: int = 512
    #: Engine steps between learner phases.
    train_every: int = 1
    #: Gradient steps per learner phase.
    gradient_steps: int = 1
    #: Adam learning rate (actor, critics and temperature).
    learning_rate: float = 3e-4
    #: Discount factor.
    gamma: float = 0.99
    #: Polyak coefficient of the target critics.
    tau: float = 0.005
    #: Initial temperature of the entropy bonus.
    alpha_init: float = 0.1
    #: Target entropy of the actions (nats; the usual -dim(A) = -2).
    target_entropy: float = -2.0
    #: Hidden layer sizes of the actor and of each critic.
    hidden: tuple[int, ...] = (128, 128)
    #: Evaluate every this many agent-steps (0 = only at the end).
    eval_every: int = 400_000
    #: Validation seeds, e.g. 500-549.
    eval_seeds: str = "500-549"
    #: Background processes for validation (0: in the training process).
    eval_workers: int = 0
    #: Torch threads.
    torch_threads: int = 1
    #: Where the networks and the updates run: cpu, or cuda / cuda:K (the engine stays on the CPU).
    device: str = "cpu"
    #: Save a resumable checkpoint every this many agent-steps (0: only on SIGINT/SIGTERM and at the end).
    checkpoint_every: int = 1_000_000
    #: Write TensorBoard scalars under <run dir>/tb beside train.csv and eval.csv.
    tensorboard: bool = True
    #: A train.csv row (and the checks for validation, checkpoints and signals) every this many agent-steps.
    log_every: int = 32_768
    #: Parent directory of run directories.
    runs_dir: str = "runs"
    #: Run directory name (default: sac_<scenario>_s<seed>_<timestamp>).
    run_name: str | None = None
    #: Show a progress bar.
    progress: bool = True

    def __post_init__(self) -> None:
        for name in ("total_steps", "n_copies", "env_procs", "buffer_size", "batch_size", "train_every",
                     "gradient_steps", "torch_threads", "log_every"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive int, got {value!r}")
        for name in ("learning_starts", "eval_every", "eval_workers", "checkpoint_every"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise ValueError(f"{name} must be an int >= 0, got {value!r}")
        for name in ("learning_rate", "alpha_init"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
        if not 0.0 < self.gamma <= 1.0 or not 0.0 < self.tau <= 1.0:
            raise ValueError(f"gamma and tau must be in (0, 1], got {self.gamma!r} and {self.tau!r}")
        if not math.isfinite(self.target_entropy):
            raise ValueError(f"target_entropy must be finite, got {self.target_entropy!r}")
        if self.env_procs > self.n_copies:
            raise ValueError(f"env_procs must be at most n_copies ({self.n_copies}), got {self.env_procs}")
        if not isinstance(self.device, str) or not re.fullmatch(r"cpu|cuda(:\d+)?", self.device):
            raise ValueError(f"device must be cpu, cuda or cuda:K, got {self.device!r}")
        self.hidden = tuple(int(h) for h in self.hidden)
        if not self.hidden or min(self.hidden) < 1:
            raise ValueError(f"hidden must be positive layer sizes, got {self.hidden!r}")

    def to_json(self) -> str:
        return dumps(dataclasses.asdict(self))


# --------------------------------------------------------------------------- the replay buffer


class ReplayBuffer:
    """A ring of ``capacity`` agent transitions, appended ``(K,)`` rows at a time (raw observations and rewards)."""

    FIELDS = ("obs", "action", "reward", "next_obs", "terminal")

    def __init__(self, capacity: int, obs_dim: int) -> None:
        self.capacity = capacity
        self.obs = np.zeros((capacity, obs_dim), np.float32)
        self.action = np.zeros((capacity, 2), np.float32)
        self.reward = np.zeros(capacity, np.float32)
        self.next_obs = np.zeros((capacity, obs_dim), np.float32)
        self.terminal = np.zeros(capacity, np.float32)
        self.pos = 0  # the next row written
        self.size = 0

    def add(self, obs: np.ndarray, action: np.ndarray, reward: np.ndarray, next_obs: np.ndarray,
            terminal: np.ndarray) -> None:
        rows = (self.pos + np.arange(len(obs))) % self.capacity
        self.obs[rows], self.action[rows], self.reward[rows] = obs, action, reward
        self.next_obs[rows], self.terminal[rows] = next_obs, terminal
        self.pos = int((self.pos + len(obs)) % self.capacity)
        self.size = min(self.size + len(obs), self.capacity)

    def state(self) -> tuple[dict[str, np.ndarray], dict[str, int]]:
        """The filled rows as arrays and the ring's position, for a checkpoint."""
        return ({f"buffer.{f}": getattr(self, f)[:self.size] for f in self.FIELDS},
                {"pos": self.pos, "size": self.size})

    def load(self, arrays: dict[str, np.ndarray], meta: dict[str, int]) -> None:
        size, pos = int(meta["size"]), int(meta["pos"])
        if not 0 <= size <= self.capacity or not 0 <= pos < self.capacity:
            raise ValueError(f"buffer of {size} rows at {pos} does not fit a capacity of {self.capacity}")
        for f in self.FIELDS:
            a = arrays[f"buffer.{f}"]
            if len(a) != size or a.shape[1:] != getattr(self, f).shape[1:]:
                raise ValueError(f"buffer.{f} has shape {a.shape}, expected {size} rows")
            getattr(self, f)[:size] = a
        self.size, self.pos = size, pos


# --------------------------------------------------------------------------- the learner


class SAC:
    """One run's worlds, networks, buffer and statistics: :meth:`act_and_store` then :meth:`learn`."""

    def __init__(self, cfg: SACConfig) -> None:
        import copy

        import torch


        self.cfg = cfg
        torch.set_num_threads(cfg.torch_threads)
        torch.manual_seed(cfg.seed)
        torch.use_deterministic_algorithms(True)
        self.gen = torch.Generator().manual_seed(cfg.seed)  # actions and minibatches, on the CPU
        self.device = _torch_device(cfg.device)
        self.worlds = TrainingWorlds(EnvFactory(cfg.scenario, {**cfg.env_kwargs, **cfg.train_env_kwargs}),
                                     cfg.n_copies, cfg.env_procs, cfg.prefetch_worlds)
        self.m, self.n = self.worlds.m, self.worlds.n
        self.obs_dim = self.worlds.venv.single_observation_space.shape[0]
        d, h = self.obs_dim, cfg.hidden
        self.actor = mlp([d, *h, 4]).to(self.device)  # (mean, log std) of the pre-tanh Gaussian
        self.q = torch.nn.ModuleList([mlp([d + 2, *h, 1]), mlp([d + 2, *h, 1])]).to(self.device)
        self.q_target = copy.deepcopy(self.q).requires_grad_(False)
        self.log_alpha = torch.tensor(math.log(cfg.alpha_init), device=self.device, requires_grad=True)
        self.actor_optim = torch.optim.Adam(self.actor.parameters(), lr=cfg.learning_rate)
        self.q_optim = torch.optim.Adam(self.q.parameters(), lr=cfg.learning_rate)
        self.alpha_optim = torch.optim.Adam([self.log_alpha], lr=cfg.learning_rate)
        self.buffer = ReplayBuffer(cfg.buffer_size, d)
        self.obs_rms = RunningMeanStd((d,))
        self.ret_rms = RunningMeanStd(())
        self.returns = np.zeros((self.m, self.n))
        self.episode_return = np.zeros(self.m)
        self.obs = np.zeros((self.m, self.n, d), np.float32)
        self.agent_steps = 0

    def start(self) -> None:
        """Start the first episode of every world (world ``k`` from seed ``100 * seed + k``)."""
        self.obs = self.worlds.reset(seed=100 * self.cfg.seed)
        self.obs_rms.update(self.obs.reshape(-1, self.obs_dim))

    def _tensor(self, x: np.ndarray) -> Any:
        import torch

        return torch.from_numpy(x).to(self.device)

    def _sample(self, obs: Any) -> tuple[Any, Any]:
        """Squashed Gaussian actions of normalised observations and their log-probabilities (tanh-corrected)."""
        import torch

        mean, log_std = self.actor(obs).chunk(2, dim=-1)
        std = log_std.clamp(LOG_STD_MIN, LOG_STD_MAX).exp()
        noise = torch.randn(mean.shape, generator=self.gen).to(self.device)
        u = mean + std * noise
        action = torch.tanh(u)
        logp = torch.distributions.Normal(mean, std).log_prob(u).sum(-1)
        # log |d tanh(u) / du| = log(1 - tanh(u)^2), written stably as 2 (log 2 - u - softplus(-2u)).
        logp = logp - (2.0 * (math.log(2.0) - u - torch.nn.functional.softplus(-2.0 * u))).sum(-1)
        return action, logp

    # ---------------------------------------------------------------- acting
    def act_and_store(self, stats: dict[str, Any]) -> None:
        """One engine step of every world: act (uniformly at random before ``learning_starts``), store the
        ``M x N`` transitions, move the statistics; episodes that ended are added to ``stats``."""
        import torch

        cfg = self.cfg
        if self.agent_steps < cfg.learning_starts:
            action = (torch.rand((self.m, self.n, 2), generator=self.gen) * 2.0 - 1.0).numpy()
        else:
            with torch.no_grad():
                action, _ = self._sample(self._tensor(self.obs_rms.normalize(self.obs)))
            action = action.cpu().numpy()
        obs, rew, terms, truncs, infos = self.worlds.step(action)
        next_obs = obs
        ended = np.flatnonzero(terms | truncs).tolist()
        if ended:  # the transition's next observation is the finished episode's last one, not the new start
            next_obs = obs.copy()
            for k in ended:
                next_obs[k] = infos["final_obs"][k]
        terminal = np.repeat(terms[:, None], self.n, axis=1)
        self.buffer.add(self.obs.reshape(-1, self.obs_dim), action.reshape(-1, 2), rew.reshape(-1),
                        next_obs.reshape(-1, self.obs_dim), terminal.reshape(-1))
        self.returns = self.returns * cfg.gamma + rew
        self.ret_rms.update(self.returns)
        self.obs_rms.update(obs.reshape(-1, self.obs_dim))
        self.episode_return += rew.mean(axis=1)
        stats["contacts"] += int(sum(infos[f"contacts_{g}"].sum() for g in ("robot", "obstacle", "human", "wall")))
        stats["rewards"].append(float(rew.mean()))
        if ended:
            self.returns[ended] = 0.0
            stats["returns"] += self.episode_return[ended].tolist()
            stats["metrics"] += [infos["final_metrics"][k] for k in ended]
            self.episode_return[ended] = 0.0
        self.obs = obs
        self.agent_steps += self.m * self.n

    # ---------------------------------------------------------------- learning
    def learn(self) -> dict[str, float]:
        """``gradient_steps`` SAC updates on minibatches drawn uniformly from the buffer."""
        import torch

        cfg = self.cfg
        scale = 1.0 / math.sqrt(float(self.ret_rms.var) + self.ret_rms.epsilon)
        out = []
        for _ in range(cfg.gradient_steps):
            idx = torch.randint(self.buffer.size, (cfg.batch_size,), generator=self.gen).numpy()
            b = self.buffer
            obs = self._tensor(self.obs_rms.normalize(b.obs[idx]))
            next_obs = self._tensor(self.obs_rms.normalize(b.next_obs[idx]))
            action = self._tensor(b.action[idx])
            reward = self._tensor(np.clip(b.reward[idx] * scale, -10.0, 10.0).astype(np.float32))
            live = 1.0 - self._tensor(b.terminal[idx])
            alpha = self.log_alpha.exp().detach()
            with torch.no_grad():  # the soft Bellman target from the target critics
                next_action, next_logp = self._sample(next_obs)
                x = torch.cat([next_obs, next_action], -1)
                next_q = torch.min(self.q_target[0](x), self.q_target[1](x)).squeeze(-1) - alpha * next_logp
                target = reward + cfg.gamma * live * next_q
            x = torch.cat([obs, action], -1)
            q1, q2 = self.q[0](x).squeeze(-1), self.q[1](x).squeeze(-1)
            q_loss = 0.5 * ((q1 - target).pow(2).mean() + (q2 - target).pow(2).mean())
            self.q_optim.zero_grad()
            q_loss.backward()
            self.q_optim.step()
            new_action, logp = self._sample(obs)
            x = torch.cat([obs, new_action], -1)
            q_new = torch.min(self.q[0](x), self.q[1](x)).squeeze(-1)
            pi_loss = (alpha * logp - q_new).mean()
            self.actor_optim.zero_grad()
            pi_loss.backward()
            self.actor_optim.step()
            alpha_loss = -(self.log_alpha * (logp.detach() + cfg.target_entropy)).mean()
            self.alpha_optim.zero_grad()
            alpha_loss.backward()
            self.alpha_optim.step()
            with torch.no_grad():
                for p, pt in zip(self.q.parameters(), self.q_target.parameters()):
                    pt.mul_(1.0 - cfg.tau).add_(p, alpha=cfg.tau)
            out.append((q_loss.item(), pi_loss.item(), float(alpha), -logp.mean().item(), q1.mean().item()))
        s = np.mean(out, axis=0)
        return {"q_loss": s[0], "policy_loss": s[1], "alpha": s[2], "entropy": s[3], "q_mean": s[4]}

    # ---------------------------------------------------------------- outputs
    def policy(self) -> Any:
        """The current actor as a deterministic policy (``tanh`` of its mean, with a frozen copy of the statistics)."""
        import copy


        return MAPPOPolicy(SquashedMeanActor(copy.deepcopy(self.actor).cpu()), self.obs_rms.copy(), name="isac")

    def save(self, directory: Path) -> Path:
        """``policy.safetensors`` (actor and critics) and ``policy.json`` into ``directory``, atomically."""
        from safetensors.torch import save_file


        directory.mkdir(parents=True, exist_ok=True)
        tensors = {f"actor.{k}": v.detach().cpu().contiguous() for k, v in self.actor.state_dict().items()}
        tensors.update({f"q.{k}": v.detach().cpu().contiguous() for k, v in self.q.state_dict().items()})
        meta = {"format": FORMAT, "config": dataclasses.asdict(self.cfg), "obs_rms": self.obs_rms.to_json()}
        with _atomic(directory / "policy.safetensors") as tmp:
            save_file(tensors, str(tmp))
        with _atomic(directory / "policy.json") as tmp:
            write_json(tmp, meta, indent=None)
        return directory

    def checkpoint_state(self) -> tuple[dict[str, Any], dict[str, Any]]:
        """Everything needed to go on bit for bit: ``(tensors, JSON values)``."""
        import torch


        tensors: dict[str, Any] = {f"actor.{k}": v for k, v in self.actor.state_dict().items()}
        tensors.update({f"q.{k}": v for k, v in self.q.state_dict().items()})
        tensors.update({f"q_target.{k}": v for k, v in self.q_target.state_dict().items()})
        tensors["log_alpha"] = self.log_alpha.detach().reshape(1)
        optim_meta = {}
        for name in ("actor_optim", "q_optim", "alpha_optim"):
            t, optim_meta[name] = optimizer_to_files(getattr(self, name), prefix=name)
            tensors.update(t)
        tensors = {k: v.cpu() for k, v in tensors.items()}
        tensors["rng.sampling"] = self.gen.get_state()
        tensors["rng.torch"] = torch.get_rng_state()
        buffer_arrays, buffer_meta = self.buffer.state()
        world_arrays, starts = self.worlds.checkpoint()
        for k, v in {**buffer_arrays, **world_arrays}.items():
            tensors[k] = torch.from_numpy(np.ascontiguousarray(v))
        tensors["rollout.obs"] = torch.from_numpy(self.obs.copy())
        tensors["rollout.returns"] = torch.from_numpy(self.returns.copy())
        tensors["rollout.episode_return"] = torch.from_numpy(self.episode_return.copy())
        stats = {name: getattr(self, name).to_json() for name in ("obs_rms", "ret_rms")}
        return tensors, {"optimizers": optim_meta, "statistics": stats, "buffer": buffer_meta,
                         "episode_starts": starts, "agent_steps": self.agent_steps}

    def restore(self, tensors: dict[str, Any], meta: dict[str, Any], source: Path) -> None:
        """Load a :meth:`checkpoint_state` (read from ``source``, named in errors); the worlds are rebuilt by
        :meth:`~swarm_env_baselines.worlds.TrainingWorlds.restore` and checked against the saved observations."""
        import torch


        def part(prefix: str) -> dict[str, Any]:
            return {k[len(prefix):]: v for k, v in tensors.items() if k.startswith(prefix)}

        try:
            self.actor.load_state_dict(part("actor."), strict=True)
            self.q.load_state_dict(part("q."), strict=True)
            self.q_target.load_state_dict(part("q_target."), strict=True)
            with torch.no_grad():
                self.log_alpha.copy_(tensors["log_alpha"].reshape(()))
            self.gen.set_state(tensors["rng.sampling"])
            torch.set_rng_state(tensors["rng.torch"])
            self.obs_rms = RunningMeanStd.from_json(meta["statistics"]["obs_rms"])
            self.ret_rms = RunningMeanStd.from_json(meta["statistics"]["ret_rms"])
            self.buffer.load({k: v.numpy() for k, v in tensors.items() if k.startswith("buffer.")}, meta["buffer"])
            self.returns[:] = tensors["rollout.returns"].numpy()
            self.episode_return[:] = tensors["rollout.episode_return"].numpy()
            saved_obs = tensors["rollout.obs"].numpy()
            self.agent_steps = int(meta["agent_steps"])
            starts = meta["episode_starts"]
        except (KeyError, TypeError, ValueError, RuntimeError) as exc:
            raise ValueError(f"{source}: not a checkpoint of this run's networks ({exc})") from None
        for name in ("actor_optim", "q_optim", "alpha_optim"):
            optimizer_from_files(getattr(self, name), tensors, meta["optimizers"][name], source, prefix=name)

        def follow(k: int, env: Any, obs: dict[str, np.ndarray], t: int) -> None:
            self.obs[k] = np.stack([obs[a] for a in self.worlds.venv.possible_agents])

        self.worlds.restore({k: v.numpy() for k, v in tensors.items() if k.startswith("episode.")}, starts,
                            100 * self.cfg.seed, follow)
        if not np.array_equal(self.obs, saved_obs):
            import warnings

            warnings.warn(f"{source}: the rebuilt worlds differ from the checkpoint's (another swarm_env or "
                          "scenario?); training goes on from the rebuilt worlds", stacklevel=2)

    def close(self) -> None:
        self.worlds.close()


# --------------------------------------------------------------------------- the policy and its files


def evaluate_saved(directory: str, cfg_json: str, seeds: list[int]) -> dict[str, Any]:
    """The validation of a saved snapshot (what a validation worker runs)."""
    import torch


    torch.set_num_threads(1)
    cfg = SACConfig(**json.loads(cfg_json))
    return evaluate_policy(load_sac_policy(directory), cfg.scenario, cfg.env_kwargs, seeds)


# --------------------------------------------------------------------------- the training loop


def train(cfg: SACConfig) -> Path:
    """Run ``cfg`` to completion in a new run directory and return it (see the module docstring);
    SIGINT/SIGTERM save a checkpoint and the policy, and :func:`resume` goes on from there."""
    run_dir = start_run_dir(cfg, f"sac_{Path(cfg.scenario).stem}_s{cfg.seed}", TRAIN_COLUMNS, EVAL_COLUMNS)
    return _run(cfg, run_dir, None)


def resume(run_dir: str | Path, **overrides: Any) -> Path:
    """Go on with the run in ``run_dir`` from its latest checkpoint (only :data:`RESUME_OVERRIDES` may change)."""
    cfg, state = resume_run_dir(run_dir, overrides, RESUME_OVERRIDES, SACConfig, CHECKPOINT_FORMAT)
    return _run(cfg, Path(run_dir), state)


def _run(cfg: SACConfig, run_dir: Path, checkpoint: tuple[dict[str, Any], dict[str, Any]] | None) -> Path:
    from tqdm import tqdm

    # --- the learner, the validation and the records
    eval_seeds = parse_seeds(cfg.eval_seeds)
    sac = SAC(cfg)
    log: RunLog | None = None
    validation = Validation(run_dir, lambda: evaluate_policy(sac.policy(), cfg.scenario, cfg.env_kwargs, eval_seeds),
                            functools.partial(evaluate_saved, cfg_json=cfg.to_json(), seeds=eval_seeds),
                            lambda row: log.eval(row) if log is not None else None, cfg.eval_workers)
    per_step = sac.m * sac.n
    n_steps = max(1, cfg.total_steps // per_step)  # engine steps in the whole run
    step = 0
    next_eval = cfg.eval_every or None
    next_checkpoint = cfg.checkpoint_every or None
    try:
        if checkpoint is None:
            sac.start()
            log = RunLog(run_dir, TRAIN_COLUMNS, EVAL_COLUMNS, cfg.tensorboard)
            t0 = time.perf_counter()
        else:
            tensors, meta = checkpoint
            source = run_dir / CHECKPOINT_DIR
            try:
                step, next_eval, next_checkpoint = int(meta["step"]), meta["next_eval"], meta["next_checkpoint"]
                t0 = time.perf_counter() - float(meta["wall_s"])
                if step >= n_steps and not meta["pending_evals"]:
                    raise ValueError(f"--resume {run_dir}: the run is complete ({sac.m * sac.n * step} agent-steps); "
                                     "pass a larger --total-steps to train it further")
                for name in ("train.csv", "eval.csv"):
                    truncate_csv(run_dir / name, int(meta["csv_rows"][name]))
                log = RunLog(run_dir, TRAIN_COLUMNS, EVAL_COLUMNS, cfg.tensorboard, purge_step=step * per_step + 1)
                validation.resume(meta)
            except (KeyError, TypeError) as exc:
                raise ValueError(f"{source / 'state.json'}: {exc}") from None
            print(f"resuming {run_dir} at {step * per_step} agent-steps", file=sys.stderr)
            sac.restore(tensors, meta, source)
    except BaseException:
        sac.close()
        validation.close(finished=False)
        if log is not None:
            log.close()
        raise

    def save_checkpoint() -> None:
        tensors, meta = sac.checkpoint_state()
        meta = {"format": CHECKPOINT_FORMAT, "step": step, "next_eval": next_eval, "next_checkpoint": next_checkpoint,
                "wall_s": time.perf_counter() - t0,
                "csv_rows": {name: csv_rows(run_dir / name) for name in ("train.csv", "eval.csv")},
                **validation.state(), **meta}
        write_checkpoint(run_dir / CHECKPOINT_DIR, tensors, meta)

    def evaluate_now() -> None:
        validation.evaluate(sac.agent_steps, round(time.perf_counter() - t0, 1), sac.save)

    # --- the loop: act in every world, store, learn; a train.csv row every ``log_every`` agent-steps
    log_every = max(1, cfg.log_every // per_step)  # in engine steps
    finished = False
    bar = tqdm(total=n_steps * per_step, initial=step * per_step, unit="step", unit_scale=True,
               disable=not cfg.progress, desc="sac", dynamic_ncols=True)
    try:
        with StopRequest() as stop:
            if checkpoint is None and cfg.eval_every:
                evaluate_now()
            while step < n_steps:
                count = min(log_every, n_steps - step)
                row = _train_window(sac, cfg, step, count, t0)
                step += count
                log.train(row)
                bar.update(count * per_step)
                if next_eval is not None and sac.agent_steps >= next_eval:
                    next_eval += cfg.eval_every
                    evaluate_now()
                validation.collect(wait=False)
                if stop.requested:
                    validation.collect(wait=True)
                    save_checkpoint()
                    sac.save(run_dir)
                    finished = True
                    raise TrainingInterrupted(stop.signum, (
                        f"interrupted at {sac.agent_steps} agent-steps; saved {run_dir}/policy.* and "
                        f"{run_dir / CHECKPOINT_DIR}/. Resume with: swarm-env train sac --resume {run_dir}"))
                if next_checkpoint is not None and sac.agent_steps >= next_checkpoint and step < n_steps:
                    next_checkpoint += cfg.checkpoint_every
                    save_checkpoint()
            if validation.last_eval != sac.agent_steps:
                evaluate_now()
            validation.collect(wait=True)
            save_checkpoint()
            finished = True
    finally:
        bar.close()
        sac.close()
        validation.close(finished)
        log.close()

    # --- the run's files
    wall = time.perf_counter() - t0
    sac.save(run_dir)
    finish_run(run_dir, {"agent_steps": sac.agent_steps, "wall_s": round(wall, 1),
                         "steps_per_s": round(sac.agent_steps / wall, 1), "best_score": validation.best},
               validation.history)
    return run_dir


def _train_window(sac: SAC, cfg: SACConfig, step: int, count: int, t0: float) -> dict[str, Any]:
    """``count`` engine steps from engine step ``step``: act in every world and store, learn every
    ``train_every`` steps once ``learning_starts`` agent-steps are stored; returns their ``train.csv`` row."""
    window: dict[str, Any] = {"contacts": 0, "rewards": [], "returns": [], "metrics": []}
    learned: list[dict[str, float]] = []
    t_act = t_learn = 0.0
    t_start = time.perf_counter()
    for _ in range(count):
        t = time.perf_counter()
        sac.act_and_store(window)
        t_act += time.perf_counter() - t
        step += 1
        if sac.agent_steps >= cfg.learning_starts and step % cfg.train_every == 0:
            t = time.perf_counter()
            learned.append(sac.learn())
            t_learn += time.perf_counter() - t
    done_steps = len(window["rewards"]) * sac.m * sac.n
    episodes = episode_stats(window["returns"], window["metrics"])
    nan = float("nan")
    losses = ({k: float(np.mean([x[k] for x in learned])) for k in learned[0]} if learned else
              dict.fromkeys(("q_loss", "policy_loss", "alpha", "entropy", "q_mean"), nan))
    return {"agent_steps": sac.agent_steps, "wall_s": round(time.perf_counter() - t0, 1),
            "rollout_s": round(t_act, 3), "update_s": round(t_learn, 3),
            "agent_steps_per_s": done_steps / (time.perf_counter() - t_start),
            "mean_reward": float(np.mean(window["rewards"])),
            "contacts_per_agent_step": window["contacts"] / done_steps, **episodes, **losses}


def build_parser() -> argparse.ArgumentParser:
    return trainer_parser("swarm-env train sac", __doc__, SACConfig, RESUME_OVERRIDES)


def main(argv: list[str] | None = None) -> int:
    return trainer_main(build_parser(), argv, SACConfig, train, resume)


if __name__ == "__main__":
    raise SystemExit(main())
