"""Train an SB3 policy on the swarm env in one command.

.. code-block:: console

    swarm-env train sb3 --algo ppo --scenario random --total-steps 2e6 --seed 0
    swarm-env train sb3 --resume runs/<run> --trust-pickle   # go on after Ctrl-C (which saves the model) or a crash

Every :class:`~swarm_env_baselines.config.TrainConfig` field is an option (``--help`` lists
them with their documentation). A run writes a directory
``<runs_dir>/<run_name>/``::

    config.json        the exact TrainConfig (swarm-env train sb3 --config it repeats the run)
    versions.json      python, platform, package versions, git commit, command line
    policy.safetensors the final policy network and, in policy.json, its observation/return
    policy.json        statistics: what ppo:<run dir> and --init-from read (no pickle involved)
    model.zip          the final (or interrupted) SB3 model (+ vecnormalize.pkl), for SB3's own tools and
                       --resume (pickles)
    best/              the model with the best validation score (see swarm_env_baselines.callbacks)
    checkpoints/       periodic checkpoints
    eval.csv           validation metrics over training (the learning curve's data)
    learning_curve.png validation formation error and collisions over agent-steps
    logs/              SB3 logger output: progress.csv and TensorBoard event files
                       (tensorboard --logdir runs/; a resumed run logs into logs/resumed_<agent-steps>/)

Load the result as a policy with ``ppo:<run dir>`` (or ``ppo:<run dir>/best``)
anywhere a policy spec is accepted, e.g. ``swarm-env evaluate``. ``--init-from`` reads a run's
safe files; a directory that has only the pickles (``vecnormalize.pkl``) needs ``--trust-pickle``
(see :mod:`swarm_env_baselines.model_io`).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from swarm_env.checks import DefaultsHelpFormatter
from swarm_env.jsonio import dumps, write_json
from swarm_env_baselines.checkpointing import (
    StopRequest,
    TrainingInterrupted,
    claim_run_dir,
    resume_config,
    run_training,
)
from swarm_env_baselines.config import TrainConfig, add_dataclass_options, parse_seeds, policy_kwargs
from swarm_env_baselines.model_io import (
    MODEL_FILE,
    VECNORM_FILE,
    FrozenRunningMeanStd,
    algorithm_class,
    load_warm_start,
    save_model,
)
from swarm_env_baselines.options import package_versions
from swarm_env_baselines.run_log import draw_learning_curve
from swarm_env_baselines.safe_io import refuse_pickle


def _env_kwargs(cfg: TrainConfig) -> dict[str, Any]:
    return {**cfg.env_kwargs, "action_type": cfg.action_type}


def _make_model(cfg: TrainConfig, venv: Any, log_dir: Path) -> Any:
    cls = algorithm_class(cfg.algo)
    common: dict[str, Any] = {
        "learning_rate": cfg.learning_rate,
        "gamma": cfg.gamma,
        "seed": cfg.seed,
        "device": "cpu",
        "verbose": 0,
        "policy_kwargs": policy_kwargs(cfg.net_arch, cfg.algo, cfg.log_std_init),
    }
    if cfg.algo in ("ppo", "a2c"):
        common.update(n_steps=cfg.n_steps, gae_lambda=cfg.gae_lambda, ent_coef=cfg.ent_coef)
        if cfg.algo == "ppo":
            common.update(batch_size=cfg.batch_size, n_epochs=cfg.n_epochs, clip_range=cfg.clip_range)
    else:
        # One env step yields num_envs transitions; a few gradient steps per env step keeps the
        # update-to-data ratio near SB3's single-env default without making each step slow.
        common.update(
            batch_size=cfg.batch_size,
            buffer_size=cfg.buffer_size,
            train_freq=1,
            gradient_steps=max(1, venv.num_envs // 16),
            learning_starts=10 * venv.num_envs,
        )
    model = cls("MlpPolicy", venv, **common)
    from stable_baselines3.common.logger import configure

    model.set_logger(configure(str(log_dir), ["csv", "tensorboard"]))
    return model


def _warm_start(model: Any, venv: Any, cfg: TrainConfig, trust_pickle: bool | None = None) -> None:
    """Copy a saved model's weights (and VecNormalize observation and return statistics) into ``model``
    (:func:`swarm_env_baselines.model_io.load_warm_start`: a pickle only with ``trust_pickle``)."""
    assert cfg.init_from is not None
    weights, obs_rms, ret_rms = load_warm_start(cfg.init_from, cfg.algo, trust_pickle=trust_pickle)
    try:
        model.policy.load_state_dict(weights)
    except RuntimeError as exc:
        raise ValueError(
            f"--init-from {cfg.init_from}: its network does not match this run's (net_arch={list(cfg.net_arch)}, "
            f"algo={cfg.algo}): {str(exc).splitlines()[0]}"
        ) from None
    if hasattr(venv, "obs_rms"):
        # Observation statistics the weights expect, and the return scale the critic was fitted in
        # (a BC checkpoint's critic is trained on rewards normalised by its ret_rms).
        if obs_rms is not None:
            venv.obs_rms = obs_rms.copy()
        if ret_rms is not None:
            venv.ret_rms = ret_rms.copy()


def train(cfg: TrainConfig, *, trust_pickle: bool | None = None) -> Path:
    """Run ``cfg`` to completion in a new run directory and return it. ``trust_pickle``: whether
    ``init_from`` may be unpickled (:func:`swarm_env.harness.policies.pickle_trusted`; default:
    ``SWARM_ENV_TRUST_PICKLE``).

    On SIGINT or SIGTERM the model finishes its current rollout (and update), is saved as the final
    model (``ppo:<run dir>`` loads it) and :class:`~swarm_env_baselines.checkpointing.TrainingInterrupted` is
    raised; :func:`resume` goes on from there. Raises ``FileExistsError`` if the run directory already
    holds a run.
    """
    stamp = datetime.now(timezone.utc).strftime("%Y%m%d-%H%M%S")
    name = cfg.run_name or f"{cfg.algo}_{Path(cfg.scenario).stem}_s{cfg.seed}_{stamp}"
    run_dir = Path(cfg.runs_dir) / name
    claim_run_dir(run_dir)
    (run_dir / "config.json").write_text(cfg.to_json() + "\n")
    write_json(run_dir / "versions.json", package_versions())
    return _learn(cfg, run_dir, None, trust_pickle)


#: What ``--resume`` may change: the budget and the progress bar.
RESUME_OVERRIDES = ("total_steps", "progress")


def resume(run_dir: str | Path, *, trust_pickle: bool | None = None, **overrides: Any) -> Path:
    """Go on with the run in ``run_dir`` from its latest saved model (:func:`latest_model`) to its ``total_steps``.

    SB3's own ``load`` brings back the networks, the optimizer and the step count (``learn`` goes on
    with ``reset_num_timesteps=False``), and the run's ``vecnormalize.pkl`` the normalisation
    statistics. Not restored (SB3 does not save them): the env worlds (reset), the RNG states
    (re-seeded with ``seed + agent-steps``) and an off-policy replay buffer (refilled), so a resumed
    run follows a different but equally valid path than an unbroken one. ``model.zip`` and
    ``vecnormalize.pkl`` are pickle-bearing, so resuming needs ``trust_pickle`` (or
    ``SWARM_ENV_TRUST_PICKLE=1``, :func:`swarm_env.harness.policies.pickle_trusted`): resume only your own
    runs. ``overrides`` may set only :data:`RESUME_OVERRIDES`.
    """
    run_dir = Path(run_dir)
    cfg_path = resume_config(run_dir, overrides, RESUME_OVERRIDES)
    cfg = dataclasses.replace(TrainConfig.from_json(cfg_path), **overrides)
    source = latest_model(run_dir)
    refuse_pickle(source / "model.zip", "an SB3 model to resume it (and vecnormalize.pkl beside it)", trust_pickle,
                  convert=False)
    if overrides:
        (run_dir / "config.json").write_text(cfg.to_json() + "\n")
    return _learn(cfg, run_dir, source, True)


def latest_model(run_dir: Path) -> Path:
    """The directory among ``run_dir`` (the final or interrupted model) and ``run_dir/checkpoints/step_*``
    whose ``model.zip`` has the most agent-steps (read from the zip's JSON ``data``, nothing unpickled)."""
    import zipfile


    def steps(d: Path) -> int | None:
        try:
            with zipfile.ZipFile(d / MODEL_FILE) as z:
                return int(json.loads(z.read("data"))["num_timesteps"])
        except (OSError, KeyError, ValueError, zipfile.BadZipFile) as exc:
            # SB3 writes model.zip in place: one cut short by a hard stop is passed over for an older one.
            print(f"warning: {d / MODEL_FILE} is not a readable SB3 model ({exc}); skipped", file=sys.stderr)
            return None

    dirs = [d for d in (run_dir, *sorted((run_dir / "checkpoints").glob("step_*"))) if (d / MODEL_FILE).is_file()]
    found = [(n, d) for d in dirs if (n := steps(d)) is not None]
    if not found:
        raise FileNotFoundError(f"--resume {run_dir}: no readable saved model in it ({MODEL_FILE} or "
                                f"checkpoints/step_*/{MODEL_FILE})")
    return max(found, key=lambda item: item[0])[1]


def _learn(cfg: TrainConfig, run_dir: Path, source: Path | None, trust_pickle: bool | None) -> Path:
    """The training of :func:`train` (``source`` None: a new model; ``trust_pickle`` for ``init_from``)
    and :func:`resume` (from ``source``, whose pickles the caller agreed to load)."""
    import torch
    from stable_baselines3.common.callbacks import CallbackList
    from stable_baselines3.common.logger import configure
    from stable_baselines3.common.vec_env import VecNormalize

    from swarm_env_baselines.callbacks import CheckpointCallback, EvalCallback, StopCallback, TqdmCallback
    from swarm_env_baselines.vec_env import make_vec_env

    torch.set_num_threads(cfg.torch_threads)
    env_kwargs = _env_kwargs(cfg)
    venv: Any = make_vec_env(cfg.scenario, cfg.n_copies, n_procs=cfg.n_procs, shield=cfg.shield, **env_kwargs)
    vecnorm = None
    if source is None:
        if cfg.norm_obs or cfg.norm_reward:
            venv = vecnorm = VecNormalize(venv, norm_obs=cfg.norm_obs, norm_reward=cfg.norm_reward, gamma=cfg.gamma)
        model = _make_model(cfg, venv, run_dir / "logs")
        if cfg.init_from:
            _warm_start(model, venv, cfg, trust_pickle)
        if cfg.freeze_obs_stats and vecnorm is not None:
            frozen = FrozenRunningMeanStd(shape=vecnorm.obs_rms.mean.shape)
            frozen.mean, frozen.var, frozen.count = vecnorm.obs_rms.mean.copy(), vecnorm.obs_rms.var.copy(), vecnorm.obs_rms.count
            vecnorm.obs_rms = frozen
    else:
        if cfg.norm_obs or cfg.norm_reward:  # the statistics as saved (frozen ones stay frozen)
            venv = vecnorm = VecNormalize.load(str(source / VECNORM_FILE), venv)
            vecnorm.training = True
        model = algorithm_class(cfg.algo).load(source / "model.zip", env=venv, device="cpu")
        model.set_random_seed(cfg.seed + model.num_timesteps)  # torch, numpy and the worlds' next reset
        model.set_logger(configure(str(run_dir / "logs" / f"resumed_{model.num_timesteps}"), ["csv", "tensorboard"]))
        if model.num_timesteps >= cfg.total_steps:
            venv.close()
            raise ValueError(f"--resume {run_dir}: the run is complete ({model.num_timesteps} agent-steps, "
                             f"total_steps {cfg.total_steps}); pass a larger --total-steps to train it further")
        print(f"resuming {run_dir} from {source} ({model.num_timesteps} agent-steps)", file=sys.stderr)
    start_steps = int(model.num_timesteps)

    stop = StopRequest("finishing the current rollout, then saving")
    callbacks: list[Any] = [StopCallback(stop)]
    evaluator = None
    if cfg.eval_every:
        evaluator = EvalCallback(
            cfg.eval_every, cfg.scenario, env_kwargs, parse_seeds(cfg.eval_seeds), run_dir, vecnorm, shield=cfg.shield
        )
        callbacks.append(evaluator)
    if cfg.checkpoint_every:
        callbacks.append(CheckpointCallback(cfg.checkpoint_every, run_dir, vecnorm))
    if cfg.progress:
        callbacks.append(TqdmCallback(cfg.total_steps))

    t0 = time.perf_counter()
    try:
        with stop:
            model.learn(total_timesteps=cfg.total_steps - start_steps, callback=CallbackList(callbacks),
                        reset_num_timesteps=source is None)
    finally:
        venv.close()
    wall = time.perf_counter() - t0
    save_model(model, run_dir, vecnorm)
    if stop.requested:
        raise TrainingInterrupted(stop.signum, (
            f"interrupted at {model.num_timesteps} of {cfg.total_steps} agent-steps; saved {run_dir}/model.zip "
            f"(and the policy files). Resume with: swarm-env train sb3 --resume {run_dir} --trust-pickle"))
    steps = model.num_timesteps - start_steps
    summary = {"agent_steps": int(model.num_timesteps), "wall_s": round(wall, 1), "steps_per_s": round(steps / wall, 1)}
    if evaluator is not None and evaluator.history:
        summary["final_eval"] = evaluator.history[-1]
        summary["best_score"] = evaluator.best_score
        draw_learning_curve(run_dir)
    write_json(run_dir / "summary.json", summary)
    return run_dir


# --------------------------------------------------------------------------- command line


def build_parser() -> argparse.ArgumentParser:
    """One option per :class:`TrainConfig` field, its help text taken from the field's ``#:`` comment."""
    parser = argparse.ArgumentParser(formatter_class=DefaultsHelpFormatter, 
        prog="swarm-env train sb3",
        description="Train an SB3 policy (parameter sharing over all followers) on the swarm env.",
    )
    parser.add_argument("--config", help="start from this config.json (e.g. a previous run's); options override it")
    parser.add_argument("--trust-pickle", action="store_true",
                        help="let --init-from unpickle a directory that has only model.zip + vecnormalize.pkl "
                             "(unpickling runs any code in the file: only for files you trust)")
    parser.add_argument("--resume", metavar="RUN_DIR",
                        help="go on with this run from its latest saved model (its config.json; only --total-steps "
                             "and --progress may be given with it)")
    add_dataclass_options(parser, TrainConfig)
    return parser


def config_from_args(argv: list[str] | None = None) -> TrainConfig:
    args = vars(build_parser().parse_args(argv))
    args.pop("trust_pickle", None)  # how to load files, not part of the run's configuration
    args.pop("resume", None)
    base: dict[str, Any] = {}
    config_path = args.pop("config", None)
    if config_path:
        base = dataclasses.asdict(TrainConfig.from_json(config_path))
        base["run_name"] = None  # a repeated run gets its own directory
    if "env_kwargs" in args:
        args["env_kwargs"] = {**base.get("env_kwargs", {}), **dict(args["env_kwargs"])}
    return TrainConfig(**{**base, **args})


def main(argv: list[str] | None = None) -> int:
    args = vars(build_parser().parse_args(argv))
    trust = args.pop("trust_pickle", False) or None

    def start() -> Path:
        if args.get("resume"):
            if args.get("config"):
                raise ValueError("--resume continues the run's own config.json: drop --config")
            return resume(args["resume"], trust_pickle=trust,
                          **{k: v for k, v in args.items() if k not in ("resume", "config")})
        return train(config_from_args(argv), trust_pickle=trust)

    run_dir = run_training(start)
    if isinstance(run_dir, int):
        return run_dir
    print(run_dir)
    summary = json.loads((run_dir / "summary.json").read_text())
    print(dumps(summary))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
