"""The typed training configuration; its field docs are the ``swarm-env train sb3`` CLI help.

Every field of :class:`TrainConfig` is a command-line option (``total_steps`` ->
``--total-steps``); the help text of each option is the ``#:`` comment above
the field. A run directory records the config as ``config.json`` and
:func:`TrainConfig.from_json` reads it back, so a run can be repeated exactly.

Data split used by the shipped baselines (``scenario="random"``):

* training: copy ``m`` of ``n_copies`` starts from ``reset(seed + m * N)``
  (``N`` = followers per copy) and then continues its own generator, so the
  training worlds are the streams of those seeds;
* validation (periodic evaluation, best-model selection): ``eval_seeds``,
  default 500-509;
* test (the leaderboard): seeds 1000 and up, never used in training or model
  selection, plus the fixed paper scenarios, never seen at all.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from swarm_env.harness.leaderboard import parse_seeds
from swarm_env.jsonio import dumps
from swarm_env_baselines.model_io import algorithm_class
from swarm_env_baselines.options import add_dataclass_options, field_help, int_arg

__all__ = ["NET_ARCH", "TrainConfig", "add_dataclass_options", "field_help", "int_arg", "parse_seeds", "policy_kwargs"]

#: Network shared by every follower (actor and critic each get this MLP); BC uses the same.
NET_ARCH: tuple[int, ...] = (128, 128)


def policy_kwargs(net_arch: tuple[int, ...] = NET_ARCH, algo: str = "ppo", log_std_init: float = 0.0) -> dict[str, Any]:
    """SB3 ``policy_kwargs`` for ``algo`` with hidden layers ``net_arch`` (and, for the on-policy
    algorithms, the initial log standard deviation of the Gaussian actions)."""
    arch = list(net_arch)
    if algo in ("ppo", "a2c", "bc"):
        return {"net_arch": {"pi": arch, "vf": arch}, "log_std_init": log_std_init}
    return {"net_arch": {"pi": arch, "qf": arch}}


@dataclass
class TrainConfig:
    """Everything that defines a training run (see the module docstring for the data split)."""

    #: SB3 algorithm: ppo, sac, a2c, td3 or ddpg.
    algo: str = "ppo"
    #: Built-in scenario name, a YAML path, or "random".
    scenario: str = "random"
    #: Extra SwarmEnv keyword arguments / random-generator knobs, as KEY=VALUE (YAML values), e.g. n_followers=[2,8].
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    #: Action space of the followers: continuous or discrete (SAC/TD3/DDPG need continuous).
    action_type: str = "continuous"
    #: Act through the VO safety layer (swarm_env.wrappers.SafetyShield) in training and evaluation; score the
    #: result as shield:ppo:RUN_DIR.
    shield: bool = False
    #: Training budget in agent-steps (SB3 timesteps: one follower acting once).
    total_steps: int = 2_000_000
    #: Seed of the algorithm (torch, action sampling) and of the training worlds.
    seed: int = 0
    #: Env copies stepped together; sub-environments = n_copies x followers per copy.
    n_copies: int = 8
    #: Worker processes for the env copies (1 = in-process).
    n_procs: int = 1
    #: Hidden layer sizes of the shared actor and critic MLPs.
    net_arch: tuple[int, ...] = NET_ARCH
    #: PPO/A2C: initial log std of the Gaussian actions (0 -> std 1 on the [-1, 1] action range).
    log_std_init: float = 0.0
    #: Learning rate (constant).
    learning_rate: float = 3e-4
    #: Discount factor.
    gamma: float = 0.99
    #: PPO/A2C: rollout length per sub-environment between updates.
    n_steps: int = 128
    #: Minibatch size (PPO) / replay batch size (SAC, TD3, DDPG).
    batch_size: int = 2048
    #: PPO: optimisation epochs per rollout.
    n_epochs: int = 5
    #: PPO/A2C: entropy bonus coefficient.
    ent_coef: float = 0.0
    #: PPO: clip range of the policy ratio.
    clip_range: float = 0.2
    #: PPO/A2C: GAE lambda.
    gae_lambda: float = 0.95
    #: Off-policy: replay buffer size (transitions).
    buffer_size: int = 1_000_000
    #: Normalise observations with VecNormalize running statistics.
    norm_obs: bool = True
    #: Normalise rewards with VecNormalize (by a running estimate of the return's std).
    norm_reward: bool = True
    #: Start from this saved model (e.g. a BC checkpoint directory): its weights and VecNormalize statistics.
    init_from: str | None = None
    #: Keep the observation statistics fixed (at init_from's, if given) instead of updating them while training.
    freeze_obs_stats: bool = False
    #: Evaluate every this many agent-steps (0 = never).
    eval_every: int = 200_000
    #: Validation seeds of the periodic evaluation, e.g. 500-509.
    eval_seeds: str = "500-509"
    #: Save a checkpoint every this many agent-steps (0 = only the final model).
    checkpoint_every: int = 500_000
    #: Torch threads (1 is fastest for these small networks on a shared CPU).
    torch_threads: int = 1
    #: Parent directory of run directories.
    runs_dir: str = "runs"
    #: Run directory name (default: <algo>_<scenario>_s<seed>_<timestamp>).
    run_name: str | None = None
    #: Show a progress bar.
    progress: bool = True

    def __post_init__(self) -> None:
        algorithm_class(self.algo)  # raises on an unknown name
        if self.action_type not in ("continuous", "discrete"):
            raise ValueError(f"action_type must be 'continuous' or 'discrete', got {self.action_type!r}")
        if self.algo in ("sac", "td3", "ddpg") and self.action_type != "continuous":
            raise ValueError(f"{self.algo} needs action_type='continuous'")
        for name in ("total_steps", "n_copies", "n_procs", "n_steps", "batch_size", "n_epochs", "torch_threads"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        if self.n_procs > self.n_copies:
            raise ValueError(f"n_procs ({self.n_procs}) cannot exceed n_copies ({self.n_copies})")
        parse_seeds(self.eval_seeds)
        self.net_arch = tuple(int(n) for n in self.net_arch)

    def to_json(self) -> str:
        return dumps(dataclasses.asdict(self), sort_keys=True)

    @classmethod
    def from_json(cls, path: str | Path) -> TrainConfig:
        data = json.loads(Path(path).read_text())
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"{path}: unknown config keys {unknown}; expected some of {sorted(known)}")
        return cls(**data)
