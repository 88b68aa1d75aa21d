"""Multi-agent PPO with RLlib on Ray: one policy shared by every follower, on this machine or a cluster.

    swarm-env train rllib --total-steps 200000 --num-env-runners 2 --out runs/rllib_ppo
    swarm-env train rllib --address auto --num-env-runners 16 ...   # on a running cluster

RLlib's new API stack: :class:`ray.rllib.env.wrappers.pettingzoo_env.ParallelPettingZooEnv` over
:class:`swarm_env.env.SwarmEnv` (fixed teams keep its one-reset agent list valid), every agent id
mapped to the module ``"shared"``, RLlib's default PPO module (two 256-unit tanh layers for the
actor and for the critic). ``--num-env-runners`` remote env runners collect experience wherever
the cluster has CPUs; the learner runs in this process.

Outputs in ``--out`` (written atomically):

* ``policy.safetensors`` + ``policy.json``: the shared actor exported as tensors and JSON, the
  ``rllib:DIR`` policy spec (:func:`make_rllib_policy`): ``swarm-env run/evaluate --policies
  rllib:runs/rllib_ppo`` scores it like any expert, acting with the Gaussian's mean, without Ray
  and without unpickling anything;
* ``train.csv``: one row per iteration (agent-steps, env steps, mean episode return, wall time);
* ``config.json`` and ``versions.json`` (the command's settings, package versions, git commit);
* ``rllib_checkpoint/``: RLlib's own checkpoint, to continue training with ``--resume``. It
  contains pickles, so ``--resume`` also needs ``--trust-pickle`` (or ``SWARM_ENV_TRUST_PICKLE=1``):
  resume only runs you made.

A centralised critic (MAPPO) is not offered here: RLlib's new stack would need a custom
``MultiRLModule`` plus a learner connector that adds the global state to every agent's batch;
:mod:`swarm_env_baselines.mappo` has one.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import io
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from swarm_env.checks import DefaultsHelpFormatter
from swarm_env.harness.policies import ModelFileError
from swarm_env.jsonio import write_json
from swarm_env.limits import clip_repr
from swarm_env.wrappers import rllib_env
from swarm_env_baselines import model_bounds as mb
from swarm_env_baselines.mappo_policy import MAPPOPolicy, directory_entry_point
from swarm_env_baselines.options import package_versions
from swarm_env_baselines.ppo_core import mlp
from swarm_env_baselines.safe_io import (
    CONFIG_FILE,
    WEIGHTS_FILE,
    _atomic,
    one_line,
    read_description,
    read_tensors,
    refuse_pickle,
)
from swarm_env_baselines.safe_io import RLLIB_FORMAT as FORMAT

SHARED = "shared"
ENV_NAME = "swarm_env_rllib"

__all__ = ["RLlibConfig", "train", "export_policy", "load_rllib_policy", "make_rllib_policy"]


@dataclasses.dataclass
class RLlibConfig:
    """Settings of one RLlib training run (the command's flags)."""

    scenario: str = "random"
    env_kwargs: dict[str, Any] = dataclasses.field(default_factory=dict)
    total_steps: int = 200_000  # env steps (each step is one action per follower)
    num_env_runners: int = 1
    envs_per_runner: int = 1
    train_batch_size: int = 4000  # agent-steps per iteration
    minibatch_size: int = 500
    num_epochs: int = 5
    lr: float = 3e-4
    seed: int = 0
    address: str | None = None  # a running cluster; None: a local Ray instance with num_cpus CPUs
    num_cpus: int = 2


def _map_to_shared(agent_id: Any, episode: Any = None, **kwargs: Any) -> str:
    return SHARED


def build_config(cfg: RLlibConfig) -> Any:
    """RLlib's ``PPOConfig`` for ``cfg``: one shared module, ``num_env_runners`` remote runners."""
    from ray.rllib.algorithms.ppo import PPOConfig
    from ray.rllib.core.rl_module.multi_rl_module import MultiRLModuleSpec
    from ray.rllib.core.rl_module.rl_module import RLModuleSpec

    return (
        PPOConfig()
        .environment(ENV_NAME, env_config={"scenario": cfg.scenario, **cfg.env_kwargs})
        .framework("torch")
        .env_runners(num_env_runners=cfg.num_env_runners, num_envs_per_env_runner=cfg.envs_per_runner,
                     num_cpus_per_env_runner=1)
        .learners(num_learners=0)
        .multi_agent(policies={SHARED}, policy_mapping_fn=_map_to_shared)
        .rl_module(rl_module_spec=MultiRLModuleSpec(rl_module_specs={SHARED: RLModuleSpec()}))
        .training(train_batch_size_per_learner=cfg.train_batch_size, minibatch_size=cfg.minibatch_size,
                  num_epochs=cfg.num_epochs, lr=cfg.lr)
        .debugging(seed=cfg.seed)
    )


# --------------------------------------------------------------------------- the exported actor


def export_policy(module: Any, directory: Path, cfg: RLlibConfig) -> Path:
    """Write the shared module's actor (encoder + the mean rows of its head) as
    ``policy.safetensors`` + ``policy.json`` in ``directory``, atomically."""
    import torch
    from safetensors.torch import save_file


    parts = list(module.encoder.actor_encoder.modules()) + list(module.pi.modules())
    leaves = [m for m in parts if not list(m.children())]
    kinds = "".join("L" if isinstance(m, torch.nn.Linear) else "T" if isinstance(m, torch.nn.Tanh) else "?" for m in leaves)
    if not kinds.endswith("L") or kinds[:-1] != "LT" * (len(kinds) // 2):
        raise ValueError(f"export_policy expects RLlib's default PPO module (a tanh MLP), got layers {kinds!r}")
    linears = [m for m in leaves if isinstance(m, torch.nn.Linear)]
    action_dim = linears[-1].out_features // 2  # the head outputs the mean, then the log std
    sizes = [linears[0].in_features, *(m.out_features for m in linears[:-1]), action_dim]
    tensors = {}
    for k, layer in enumerate(linears):
        w, b = layer.weight.detach(), layer.bias.detach()
        if k == len(linears) - 1:
            w, b = w[:action_dim], b[:action_dim]
        tensors[f"actor.{2 * k}.weight"] = w.contiguous().clone()
        tensors[f"actor.{2 * k}.bias"] = b.contiguous().clone()
    directory.mkdir(parents=True, exist_ok=True)
    with _atomic(directory / WEIGHTS_FILE) as tmp:
        save_file(tensors, str(tmp))
    meta = {"format": FORMAT, "sizes": sizes, "activation": "tanh", "config": dataclasses.asdict(cfg)}
    with _atomic(directory / CONFIG_FILE) as tmp:
        write_json(tmp, meta, indent=None)
    return directory


class _Unnormalised:
    """RLlib's default PPO reads raw observations: the identity where a MAPPO actor normalises."""

    def __init__(self, size: int) -> None:
        self.mean = np.zeros(size)

    def normalize(self, x: np.ndarray) -> np.ndarray:
        return np.asarray(x, dtype=np.float32)


def load_rllib_policy(directory: str | Path, name: str | None = None) -> Any:
    """The exported actor of an RLlib run as a policy acting with its mean (no Ray, no pickle)."""
    import torch


    d = Path(directory).expanduser()
    meta = read_description(d / CONFIG_FILE, FORMAT)
    try:
        activation = mb.get(meta, "activation", "")
        if activation != "tanh":
            raise ValueError(f"activation: expected 'tanh' (RLlib's default PPO module), got {clip_repr(activation)}")
        sizes = mb.get(meta, "sizes", "")
        if not isinstance(sizes, list) or not 3 <= len(sizes) <= mb.MAX_DEPTH + 2:
            raise ValueError(f"sizes: expected [inputs, 1-{mb.MAX_DEPTH} hidden widths, {mb.ACTION_SIZE}], got "
                             f"{clip_repr(sizes)}")
        mb.integer(sizes[0], "sizes[0] (the observation size)", 1, mb.MAX_OBSERVATION)
        mb.widths(sizes[1:-1], "sizes[1:-1] (the hidden widths)")
        mb.integer(sizes[-1], "sizes[-1] (the action size)", mb.ACTION_SIZE, mb.ACTION_SIZE)
        mb.check_parameters(mb.mlp_parameters(sizes), "sizes", "the actor")
    except ValueError as exc:
        raise ValueError(f"{mb.shown(d / CONFIG_FILE)}: not an exported RLlib actor ({one_line(exc)})") from None
    actor = mlp(sizes)
    tensors = read_tensors(d / WEIGHTS_FILE)  # finite, bounded values only (model_bounds.read_safetensors)
    try:
        actor.load_state_dict({k[len("actor."):]: v for k, v in tensors.items()}, strict=True)
    except (RuntimeError, ValueError) as exc:  # missing/unexpected keys, shape mismatches
        raise ValueError(f"{mb.shown(d / WEIGHTS_FILE)}: the tensors do not fit the actor of {CONFIG_FILE} "
                         f"({one_line(exc)})") from None
    actor.eval()
    torch.set_num_threads(1)
    return MAPPOPolicy(actor, _Unnormalised(sizes[0]), name=name or f"rllib:{directory}")  # type: ignore[arg-type]


make_rllib_policy = directory_entry_point(
    "rllib", load_rllib_policy, "policy 'rllib' needs a run directory: rllib:DIR (written by swarm-env train rllib)",
    "Entry point ``rllib:DIR``: the actor exported by ``swarm-env train rllib --out DIR``.")


# --------------------------------------------------------------------------- training


def train(cfg: RLlibConfig, out: Path, resume: bool = False, progress: bool = True,
          trust_pickle: bool | None = None) -> list[dict[str, Any]]:
    """Train until ``cfg.total_steps`` env steps, then export the actor into ``out`` (see the module
    docstring). Returns the per-iteration rows of ``train.csv``. ``resume`` restores RLlib's checkpoint,
    which unpickles: refused (a :class:`~swarm_env.harness.policies.ModelFileError`) unless ``trust_pickle``
    (:func:`swarm_env.harness.policies.pickle_trusted`)."""
    if resume:
        refuse_pickle(out / "rllib_checkpoint", "RLlib's checkpoint (pickled state)", trust_pickle, convert=False)
    import ray
    from ray.tune.registry import register_env


    out.mkdir(parents=True, exist_ok=True)
    started = not ray.is_initialized()
    if started:
        if cfg.address is None:
            # "local": a new instance even where a `ray start` cluster is up (which ray.init would try to join)
            ray.init(address="local", num_cpus=cfg.num_cpus, include_dashboard=False, log_to_driver=False)
        else:
            ray.init(address=cfg.address, log_to_driver=False)
    register_env(ENV_NAME, rllib_env)  # the package's creator: remote env runners on any node import it
    algo = build_config(cfg).build_algo()
    checkpoint = out / "rllib_checkpoint"
    rows: list[dict[str, Any]] = []
    try:
        if resume:
            if not checkpoint.is_dir():
                raise FileNotFoundError(f"--resume: no RLlib checkpoint in {checkpoint}")
            algo.restore(str(checkpoint.resolve()))
        t0 = time.perf_counter()
        env_steps = 0
        from tqdm.auto import tqdm

        with tqdm(total=cfg.total_steps, desc="rllib ppo", unit="step", disable=not progress) as bar:
            while env_steps < cfg.total_steps:
                result = algo.train()
                runners = result["env_runners"]
                done = int(runners.get("num_env_steps_sampled_lifetime", 0))
                bar.total = max(bar.total, done)  # the last iteration samples a whole batch past the budget
                bar.update(max(0, done - env_steps))
                env_steps = done
                agent_steps = runners.get("num_agent_steps_sampled_lifetime", 0)  # per agent id, or a total
                rows.append({"iteration": len(rows) + 1, "env_steps": env_steps,
                             "agent_steps": int(sum(agent_steps.values()) if isinstance(agent_steps, dict) else agent_steps),
                             "episode_return_mean": float(runners.get("episode_return_mean", float("nan"))),
                             "wall_s": round(time.perf_counter() - t0, 3)})
                bar.set_postfix(ret=f"{rows[-1]['episode_return_mean']:.1f}")
        algo.save(str(checkpoint.resolve()))
        export_policy(algo.get_module(SHARED), out, cfg)
    finally:
        algo.stop()
        if started:
            ray.shutdown()
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(rows[0]) if rows else ["iteration"])
    writer.writeheader()
    writer.writerows(rows)
    with _atomic(out / "train.csv") as tmp:
        tmp.write_text(buf.getvalue())
    with _atomic(out / "config.json") as tmp:
        write_json(tmp, dataclasses.asdict(cfg))
    with _atomic(out / "versions.json") as tmp:
        write_json(tmp, {**package_versions(), "ray": ray.__version__})
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(formatter_class=DefaultsHelpFormatter, prog="swarm-env train rllib", description=__doc__.splitlines()[0])
    p.add_argument("--scenario", default="random")
    p.add_argument("--env", action="append", default=[], metavar="KEY=VALUE",
                   help="SwarmEnv keyword (repeatable; values are YAML: n_followers=4, n_humans=[0,3])")
    p.add_argument("--total-steps", type=int, default=RLlibConfig.total_steps, help="env steps to train for")
    p.add_argument("--num-env-runners", type=int, default=RLlibConfig.num_env_runners,
                   help="remote env runners (each one CPU, anywhere on the cluster)")
    p.add_argument("--envs-per-runner", type=int, default=RLlibConfig.envs_per_runner)
    p.add_argument("--train-batch-size", type=int, default=RLlibConfig.train_batch_size)
    p.add_argument("--minibatch-size", type=int, default=RLlibConfig.minibatch_size)
    p.add_argument("--num-epochs", type=int, default=RLlibConfig.num_epochs)
    p.add_argument("--lr", type=float, default=RLlibConfig.lr)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--address", help="join a running Ray cluster ('auto', 'HOST:6379'); default: a local instance")
    p.add_argument("--num-cpus", type=int, default=RLlibConfig.num_cpus, help="CPUs of the local Ray instance")
    p.add_argument("--out", required=True, help="run directory (the exported policy is rllib:OUT)")
    p.add_argument("--resume", action="store_true", help="continue from OUT/rllib_checkpoint (with --trust-pickle)")
    p.add_argument("--trust-pickle", action="store_true",
                   help="let --resume unpickle RLlib's checkpoint (it can run code: only runs you made)")
    p.add_argument("--no-progress", action="store_true")
    args = p.parse_args(argv)
    import yaml


    env_kwargs = {}
    for item in args.env:
        key, sep, value = item.partition("=")
        if not sep:
            p.error(f"--env expects KEY=VALUE, got {item!r}")
        env_kwargs[key] = yaml.safe_load(value)
        if isinstance(env_kwargs[key], list):
            env_kwargs[key] = tuple(env_kwargs[key])
    cfg = RLlibConfig(args.scenario, env_kwargs, args.total_steps, args.num_env_runners, args.envs_per_runner,
                      args.train_batch_size, args.minibatch_size, args.num_epochs, args.lr, args.seed, args.address,
                      args.num_cpus)
    try:
        rows = train(cfg, Path(args.out), resume=args.resume, progress=not args.no_progress,
                     trust_pickle=args.trust_pickle or None)
    except (ModelFileError, FileNotFoundError) as exc:  # a refused or missing checkpoint
        print(f"error: {exc}", file=sys.stderr)
        return 2
    last = rows[-1] if rows else {}
    print(f"{len(rows)} iterations, {last.get('env_steps', 0)} env steps in {last.get('wall_s', 0)} s; "
          f"policy: rllib:{args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
