"""DAgger on the batched engine: a network that learns the observation-only expert's avoidance choice.

.. code-block:: console

    swarm-env train fan_dagger --seed 0                    # 20-30 min on 2 cores
    swarm-env train fan_dagger --resume runs/<run>         # go on after Ctrl-C or a crash
    swarm-env run --policy fan_dagger:runs/<run>/best ...  # play the best validated network

The learner is :mod:`swarm_env_baselines.fan_policy`'s network: it sees each follower's observation and
the *avoidance fan* computed from it (every candidate twist's time to contact, the pure-pursuit twist),
and scores the candidates. The teacher is ``obs_expert``, which reads the same observation; its choice
among the same candidates is the label (a cross-entropy over the candidates).

DAgger (Ross et al. 2011) on :class:`~swarm_env_baselines.worlds.TrainingWorlds`:

1. Round 0: the teacher drives ``n_worlds`` worlds for ``round_steps`` engine steps; every follower-step is
   labelled with the teacher's pick. Later rounds: the *student* drives (its best-scoring candidate) and
   the teacher labels the states the student reaches, so that the student learns to recover from its own
   mistakes (cloning alone was measured to leave 3.0 collisions per episode: docs/baselines.md).
2. After each round the network is fitted for ``epochs`` epochs on every label so far (Adam, minibatches
   of ``batch_size``, shuffled by the run's generator). Before the fit, the new round's labels measure the
   student on the states it reached itself (``agree_own``: the share of rows where it picked as the
   teacher did), the honest held-out figure of imitation.
3. Then the validation (:class:`~swarm_env_baselines.validation.Validation`, seeds 500-549, formation error
   plus 1 m per collision) scores the student; the best round is kept in ``best/``.

Observation statistics come from round 0 and stay fixed. Training worlds: round ``r`` resets world ``k``
to seed ``first_seed + 1000 * seed + r * n_worlds + k`` (disjoint from validation 500-549 and the
leaderboard's test seeds 1000-1049 at the default ``first_seed``); a world whose episode ends goes on with
its generator's next episode.

The run directory is :mod:`swarm_env_baselines.mappo`'s: ``config.json``, ``versions.json``,
``policy.safetensors`` + ``policy.json``, ``best/``, ``train.csv`` (one row per round), ``eval.csv``,
TensorBoard events under ``tb/``, ``learning_curve.png``, ``summary.json`` and ``checkpoint/`` after every
round (the network, the optimiser, the generator, every label so far as observations and picks: the fan
is computed again from them), so that ``--resume`` ends bit for bit as an uninterrupted run.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from swarm_env.env import SwarmEnv
from swarm_env.harness.leaderboard import parse_seeds
from swarm_env.jsonio import dumps
from swarm_env.vector.engine import EnvFactory
from swarm_env_agents.obs_expert import ObservationExpert, ObsExpertConfig
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
from swarm_env_baselines.fan_policy import FanPolicy, fan_inputs, fan_net, load_fan_policy, save_fan_policy
from swarm_env_baselines.options import trainer_parser
from swarm_env_baselines.ppo_core import RunningMeanStd
from swarm_env_baselines.run_log import RunLog, finish_run
from swarm_env_baselines.validation import EVAL_COLUMNS, Validation, evaluate_policy
from swarm_env_baselines.worlds import TrainingWorlds

CHECKPOINT_FORMAT = "swarm_env.fan_dagger-checkpoint/1"
#: What ``--resume`` may change: the number of rounds, and settings that leave the results as they are.
RESUME_OVERRIDES = ("rounds", "eval_workers", "progress", "tensorboard")
TRAIN_COLUMNS = ("agent_steps", "wall_s", "round", "labels", "driver", "agree_own", "contacts_per_agent_step",
                 "loss", "agree_fit", "rollout_s", "fit_s", "agent_steps_per_s")


@dataclass
class FanDaggerConfig:
    """Everything that defines a fan_dagger run (each field is a command-line option)."""

    #: Built-in scenario name, a YAML path, or "random".
    scenario: str = "random"
    #: Extra SwarmEnv keyword arguments / random-generator knobs, as KEY=VALUE (YAML values).
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    #: The teacher's (and the fan sensor's) options, obs_expert's KEY=VALUE (ObsExpertConfig fields).
    teacher: dict[str, Any] = field(default_factory=dict)
    #: DAgger rounds (the first driven by the teacher).
    rounds: int = 10
    #: Engine steps per round (each steps every follower of every world once).
    round_steps: int = 600
    #: Worlds stepped together by the batched engine.
    n_worlds: int = 32
    #: Fitting epochs over every label so far after each round.
    epochs: int = 3
    #: Rows per minibatch.
    batch_size: int = 1024
    #: Adam learning rate.
    learning_rate: float = 1e-3
    #: Hidden layer sizes of the trunk (observation + fan -> one logit per candidate).
    hidden: tuple[int, ...] = (256, 256)
    #: Hidden layer sizes of the per-candidate scorer (a candidate's features -> one logit), shared by all.
    candidate_hidden: tuple[int, ...] = (16, 16)
    #: Seed of the network, the minibatches and the training worlds.
    seed: int = 0
    #: First training-world seed (round r, world k: first_seed + 1000 seed + r n_worlds + k).
    first_seed: int = 10_000
    #: Validation seeds, e.g. 500-549.
    eval_seeds: str = "500-549"
    #: Background processes for validation (0: in the training process; 1 uses a second core).
    eval_workers: int = 1
    #: Torch threads of the fit (the rollout's forwards use the same). 2 measured no faster than 1 on this 2-core
    #: machine, and far slower while a validation worker holds the other core (docs/baselines.md).
    torch_threads: int = 1
    #: Write TensorBoard scalars under <run dir>/tb beside train.csv and eval.csv.
    tensorboard: bool = True
    #: Parent directory of run directories.
    runs_dir: str = "runs"
    #: Run directory name (default: fan_dagger_<scenario>_s<seed>_<timestamp>).
    run_name: str | None = None
    #: Show a progress bar.
    progress: bool = True

    def __post_init__(self) -> None:
        for name in ("rounds", "round_steps", "n_worlds", "epochs", "batch_size", "torch_threads"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive int, got {value!r}")
        if isinstance(self.eval_workers, bool) or not isinstance(self.eval_workers, int) or self.eval_workers < 0:
            raise ValueError(f"eval_workers must be an int >= 0, got {self.eval_workers!r}")
        if not (isinstance(self.learning_rate, (int, float)) and 0 < self.learning_rate < 1):
            raise ValueError(f"learning_rate must be in (0, 1), got {self.learning_rate!r}")
        self.hidden = tuple(int(h) for h in self.hidden)
        self.candidate_hidden = tuple(int(h) for h in self.candidate_hidden)
        for name in ("hidden", "candidate_hidden"):
            widths = getattr(self, name)
            if not widths or min(widths) < 1 or max(widths) > 4096 or len(widths) > 8:
                raise ValueError(f"{name} must be 1-8 layer widths in 1-4096, got {widths!r}")
        self.teacher = dict(self.teacher)
        ObsExpertConfig(**self.teacher)  # an unknown or bad teacher option fails here, naming it
        parse_seeds(self.eval_seeds)

    def to_json(self) -> str:
        return dumps(dataclasses.asdict(self))


def evaluate_saved(directory: str, cfg_json: str, seeds: list[int]) -> dict[str, Any]:
    """The validation of a saved snapshot (what a validation worker runs)."""
    import torch

    torch.set_num_threads(1)
    cfg = FanDaggerConfig(**json.loads(cfg_json))
    policy = load_fan_policy(directory)
    return evaluate_policy(policy, cfg.scenario, cfg.env_kwargs, seeds)


class Learner:
    """The network, its optimiser and every label so far (observations and the teacher's picks)."""

    def __init__(self, cfg: FanDaggerConfig) -> None:
        import torch

        self.cfg = cfg
        torch.manual_seed(cfg.seed)
        torch.set_num_threads(cfg.torch_threads)
        probe = SwarmEnv(cfg.scenario, **cfg.env_kwargs)
        self.sensor = ObservationExpert(**cfg.teacher)
        self.sensor.reset(probe, None)
        probe.close()
        self.net = fan_net(self.sensor.obs_size, self.sensor.candidates, cfg.hidden, cfg.candidate_hidden)
        self.optim = torch.optim.Adam(self.net.parameters(), lr=cfg.learning_rate)
        self.generator = torch.Generator().manual_seed(cfg.seed)
        self.obs_rms = RunningMeanStd((self.sensor.obs_size,))
        self.obs: list[np.ndarray] = []  # per round: (rows, D) float32
        self.picks: list[np.ndarray] = []  # per round: (rows,) int16
        self._inputs: list[Any] = []  # per round: the network's inputs as a tensor

    @property
    def labels(self) -> int:
        return sum(len(p) for p in self.picks)

    def policy(self) -> FanPolicy:
        """The student as a policy (the live network; reset it with an env before acting)."""
        return FanPolicy(self.net, self.obs_rms, dict(self.cfg.teacher))

    def student_picks(self, obs: np.ndarray, ttc: np.ndarray, pursuit: np.ndarray) -> np.ndarray:
        """The student's candidates for rows whose fan is known (``obs`` raw)."""
        import torch

        x = fan_inputs(self.obs_rms.normalize(obs), ttc, pursuit, self.sensor)
        with torch.no_grad():
            return self.net(torch.from_numpy(x)).argmax(dim=1).numpy()

    def add(self, obs: np.ndarray, picks: np.ndarray) -> None:
        """One round's labels; round 0 sets the observation statistics (then frozen)."""
        import torch

        if not self.obs:
            self.obs_rms.update(obs)
            self.obs_rms.frozen = True
        self.obs.append(obs.astype(np.float32))
        self.picks.append(picks.astype(np.int16))
        fan = self.sensor.fan(obs)
        x = fan_inputs(self.obs_rms.normalize(obs.astype(np.float64)), fan.ttc, fan.pursuit, self.sensor)
        self._inputs.append(torch.from_numpy(x))

    def fit(self) -> tuple[float, float]:
        """``epochs`` epochs of cross-entropy on every label so far: the last epoch's mean loss and agreement."""
        import torch
        import torch.nn.functional as F

        x = torch.cat(self._inputs)
        y = torch.from_numpy(np.concatenate(self.picks).astype(np.int64))
        n = len(y)
        loss_sum = agree = 0.0
        for _ in range(self.cfg.epochs):
            order = torch.randperm(n, generator=self.generator)
            loss_sum = agree = 0.0
            for start in range(0, n, self.cfg.batch_size):
                idx = order[start:start + self.cfg.batch_size]
                logits = self.net(x[idx])
                loss = F.cross_entropy(logits, y[idx])
                self.optim.zero_grad()
                loss.backward()
                self.optim.step()
                loss_sum += loss.item() * len(idx)
                agree += (logits.argmax(dim=1) == y[idx]).sum().item()
        return loss_sum / n, agree / n

    def save(self, directory: Path) -> Path:
        return save_fan_policy(directory, self.net, self.obs_rms, self.cfg, dict(self.cfg.teacher))

    def checkpoint_state(self) -> tuple[dict[str, Any], dict[str, Any]]:
        import torch

        tensors = {f"net.{k}": v for k, v in self.net.state_dict().items()}
        optim_tensors, optim_meta = optimizer_to_files(self.optim)
        tensors.update(optim_tensors)
        tensors["generator"] = self.generator.get_state()
        for r, (obs, picks) in enumerate(zip(self.obs, self.picks)):
            tensors[f"round.{r}.obs"] = torch.from_numpy(obs)
            tensors[f"round.{r}.picks"] = torch.from_numpy(picks)
        return tensors, {"obs_rms": self.obs_rms.to_json(), "rounds_done": len(self.obs), **optim_meta}

    def restore(self, tensors: dict[str, Any], meta: dict[str, Any], source: Path) -> None:
        """Go on from :meth:`checkpoint_state`'s files; ``ValueError`` naming ``source`` if they do not fit."""
        try:
            self.net.load_state_dict({k[4:]: v for k, v in tensors.items() if k.startswith("net.")}, strict=True)
            optimizer_from_files(self.optim, tensors, meta, source)
            self.generator.set_state(tensors["generator"])
            for r in range(int(meta["rounds_done"])):
                self.add(tensors[f"round.{r}.obs"].numpy(), tensors[f"round.{r}.picks"].numpy())
            self.obs_rms = RunningMeanStd.from_json(meta["obs_rms"])
            self.obs_rms.frozen = True
        except (KeyError, RuntimeError, TypeError, ValueError) as exc:
            raise ValueError(f"{source}: not a fan_dagger checkpoint of this run ({exc})") from None


def collect(learner: Learner, worlds: TrainingWorlds, cfg: FanDaggerConfig, r: int,
            bar: Any) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """Round ``r``'s rollout: every visited follower observation ``(rows, D)``, the teacher's pick for each, and
    the round's statistics (the share of rows where the student agreed with the teacher, contacts per agent-step)."""
    obs = worlds.reset(cfg.first_seed + 1000 * cfg.seed + r * cfg.n_worlds)
    m, n, d = obs.shape
    xs, ys = [], []
    agree = contacts = 0
    for _ in range(cfg.round_steps):
        rows = obs.reshape(m * n, d).astype(np.float64)
        fan = learner.sensor.fan(rows)
        drive = fan.pick if r == 0 else learner.student_picks(rows, fan.ttc, fan.pursuit)
        agree += int((drive == fan.pick).sum())
        xs.append(rows)
        ys.append(fan.pick)
        obs, _, _, _, infos = worlds.step(learner.sensor.candidates[drive].reshape(m, n, 2))
        contacts += int(sum(np.asarray(infos[k]).sum() for k in ("contacts_robot", "contacts_human",
                                                                  "contacts_obstacle", "contacts_wall")))
        bar.update(m * n)
    rows_total = cfg.round_steps * m * n
    return np.concatenate(xs), np.concatenate(ys), {"agree_own": agree / rows_total,
                                                    "contacts_per_agent_step": contacts / rows_total}


def train(cfg: FanDaggerConfig) -> Path:
    """Run ``cfg`` to completion in a new run directory and return it (the module docstring); SIGINT/SIGTERM
    save a checkpoint after the current round, and :func:`resume` goes on from there."""
    run_dir = start_run_dir(cfg, f"fan_dagger_{Path(cfg.scenario).stem}_s{cfg.seed}", TRAIN_COLUMNS, EVAL_COLUMNS)
    return _run(cfg, run_dir, None)


def resume(run_dir: str | Path, **overrides: Any) -> Path:
    """Go on with the run in ``run_dir`` from its latest checkpoint (only :data:`RESUME_OVERRIDES` may change)."""
    cfg, state = resume_run_dir(run_dir, overrides, RESUME_OVERRIDES, FanDaggerConfig, CHECKPOINT_FORMAT)
    return _run(cfg, Path(run_dir), state)


def _run(cfg: FanDaggerConfig, run_dir: Path, checkpoint: tuple[dict[str, Any], dict[str, Any]] | None) -> Path:
    from tqdm import tqdm

    learner = Learner(cfg)
    eval_seeds = parse_seeds(cfg.eval_seeds)
    log: RunLog | None = None

    def score_live() -> dict[str, Any]:
        return evaluate_policy(learner.policy(), cfg.scenario, cfg.env_kwargs, eval_seeds)

    validation = Validation(run_dir, score_live, functools.partial(evaluate_saved, cfg_json=cfg.to_json(),
                                                                   seeds=eval_seeds),
                            lambda row: log.eval(row) if log is not None else None, cfg.eval_workers)
    worlds = TrainingWorlds(EnvFactory(cfg.scenario, dict(cfg.env_kwargs)), cfg.n_worlds)
    per_round = cfg.round_steps * cfg.n_worlds * worlds.n
    first_round, wall_before = 0, 0.0
    try:
        if checkpoint is not None:
            tensors, meta = checkpoint
            source = run_dir / CHECKPOINT_DIR
            try:
                first_round, wall_before = int(meta["rounds_done"]), float(meta["wall_s"])
                if first_round >= cfg.rounds:
                    raise ValueError(f"--resume {run_dir}: the run is complete ({first_round} rounds); pass a larger "
                                     "--rounds to train it further")
                for name in ("train.csv", "eval.csv"):
                    truncate_csv(run_dir / name, int(meta["csv_rows"][name]))
                validation.resume(meta)
            except (KeyError, TypeError) as exc:
                raise ValueError(f"{source / 'state.json'}: {exc}") from None
            print(f"resuming {run_dir} after round {first_round - 1}", file=sys.stderr)
            learner.restore(tensors, meta, source)
        log = RunLog(run_dir, TRAIN_COLUMNS, EVAL_COLUMNS, cfg.tensorboard,
                     purge_step=first_round * per_round + 1 if checkpoint is not None else None)
    except BaseException:
        worlds.close()
        validation.close(finished=False)
        raise
    t0 = time.perf_counter() - wall_before

    def save_checkpoint() -> None:
        tensors, meta = learner.checkpoint_state()
        meta = {"format": CHECKPOINT_FORMAT, "wall_s": time.perf_counter() - t0,
                "csv_rows": {name: csv_rows(run_dir / name) for name in ("train.csv", "eval.csv")},
                **validation.state(), **meta}
        write_checkpoint(run_dir / CHECKPOINT_DIR, tensors, meta)

    finished = False
    bar = tqdm(total=cfg.rounds * per_round, initial=first_round * per_round, unit="step", unit_scale=True,
               disable=not cfg.progress, desc="fan_dagger", dynamic_ncols=True)
    try:
        with StopRequest("finishing the current round, then saving") as stop:
            for r in range(first_round, cfg.rounds):
                t_round = time.perf_counter()
                obs, picks, stats = collect(learner, worlds, cfg, r, bar)
                t_fit = time.perf_counter()
                learner.add(obs, picks)
                loss, agree_fit = learner.fit()
                done = time.perf_counter()
                steps = (r + 1) * per_round
                log.train({"agent_steps": steps, "wall_s": round(done - t0, 1), "round": r, "labels": learner.labels,
                           "driver": "teacher" if r == 0 else "student", **stats, "loss": loss,
                           "agree_fit": agree_fit, "rollout_s": round(t_fit - t_round, 2),
                           "fit_s": round(done - t_fit, 2), "agent_steps_per_s": per_round / (t_fit - t_round)})
                bar.set_postfix(round=r, agree=f"{stats['agree_own']:.3f}", loss=f"{loss:.3f}")
                validation.evaluate(steps, round(done - t0, 1), learner.save)
                validation.collect(wait=False)
                save_checkpoint()
                if stop.requested and r + 1 < cfg.rounds:
                    validation.collect(wait=True)
                    save_checkpoint()
                    learner.save(run_dir)
                    finished = True
                    raise TrainingInterrupted(stop.signum, (
                        f"interrupted after round {r}; saved {run_dir}/policy.* and {run_dir / CHECKPOINT_DIR}/. "
                        f"Resume with: swarm-env train fan_dagger --resume {run_dir}"))
            validation.collect(wait=True)
            save_checkpoint()
            finished = True
    finally:
        bar.close()
        worlds.close()
        validation.close(finished)
        log.close()

    wall = time.perf_counter() - t0
    learner.save(run_dir)
    steps = cfg.rounds * per_round
    finish_run(run_dir, {"agent_steps": steps, "labels": learner.labels, "wall_s": round(wall, 1),
                         "steps_per_s": round(steps / wall, 1), "best_score": validation.best}, validation.history)
    return run_dir


def build_parser() -> argparse.ArgumentParser:
    return trainer_parser("swarm-env train fan_dagger", __doc__, FanDaggerConfig, RESUME_OVERRIDES)


def main(argv: list[str] | None = None) -> int:
    return trainer_main(build_parser(), argv, FanDaggerConfig, train, resume)


if __name__ == "__main__":
    raise SystemExit(main())
