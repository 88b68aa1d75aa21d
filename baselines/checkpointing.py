"""Interrupting and resuming training: signals, resumable checkpoints in safe files, CSV logs.

Shared by both trainers (:mod:`swarm_env_baselines.mappo` and :mod:`swarm_env_baselines.train`):

* :class:`StopRequest` turns the first SIGINT (Ctrl-C) or SIGTERM into a request that the
  training loop honours at its next clean point (the end of an update, or of an SB3 step); a
  second signal stops at once (``KeyboardInterrupt``). The loop then saves its state and raises
  :class:`TrainingInterrupted`, whose ``exit_code`` is 130 for SIGINT and 143 for SIGTERM (128 +
  the signal number, the shell convention) and whose message says how to resume.
* :func:`write_checkpoint` / :func:`read_checkpoint`: a checkpoint directory holding
  ``state.safetensors`` (every tensor, including RNG states as uint8 tensors) and ``state.json``
  (everything else), swapped in whole so that a reader (or a resume after a crash) finds the old
  or the new checkpoint complete, never a mix. No pickle: loading runs no code.
* :func:`optimizer_to_files` / :func:`optimizer_from_files`: a torch optimizer's state in those
  two forms (Adam's moments and step counts as tensors, its hyperparameters as JSON).
* :func:`truncate_csv`: drop the rows a run logged after the checkpoint it resumes from.
"""

from __future__ import annotations

import argparse
import csv
import shutil
import signal
import sys
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from swarm_env.jsonio import dumps, write_json
from swarm_env_baselines.model_bounds import MAX_DESCRIPTION_BYTES, read_checkpoint_tensors, read_json
from swarm_env_baselines.options import package_versions
from swarm_env_baselines.run_log import RunLog
from swarm_env_baselines.safe_io import _atomic, read_description, swap_in_dir

STATE_TENSORS = "state.safetensors"
#: A run directory's resumable checkpoint (the latest only).
CHECKPOINT_DIR = "checkpoint"
STATE_JSON = "state.json"

__all__ = ["CHECKPOINT_DIR", "STATE_JSON", "STATE_TENSORS", "StopRequest", "TrainingInterrupted", "csv_rows",
           "ignore_interrupts", "optimizer_from_files", "optimizer_to_files", "read_checkpoint", "resume_run_dir",
           "start_run_dir", "trainer_main", "truncate_csv", "write_checkpoint"]


class TrainingInterrupted(Exception):
    """Training stopped on a signal after saving its state; ``str()`` says how to resume."""

    def __init__(self, signum: int, message: str) -> None:
        super().__init__(message)
        self.signum = signum
        #: The process exit status a command line should return: 128 + the signal number.
        self.exit_code = 128 + int(signum)


class StopRequest:
    """SIGINT/SIGTERM handlers for the duration of a ``with`` block.

    Outside :meth:`immediate` sections, the first signal only sets :attr:`signum` (the loop polls
    :attr:`requested` and stops cleanly); a second signal raises ``KeyboardInterrupt`` at once (stop
    without saving). Inside ``with stop.immediate(message):`` (work that cannot be saved half-way,
    e.g. a warm start) a signal raises :class:`TrainingInterrupted` with ``message`` at once. Handlers
    can only be installed in the main thread; elsewhere the object never requests a stop.
    """

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self, announce: str = "finishing the current update, then saving") -> None:
        self.signum: int | None = None
        self.announce = announce
        self._immediate: str | None = None
        self._previous: dict[int, Any] = {}

    @property
    def requested(self) -> bool:
        return self.signum is not None

    def __enter__(self) -> StopRequest:
        if threading.current_thread() is threading.main_thread():
            for s in self.SIGNALS:
                self._previous[s] = signal.signal(s, self._handle)
        return self

    def __exit__(self, *_: Any) -> None:
        for s, handler in self._previous.items():
            signal.signal(s, handler)
        self._previous.clear()

    def _handle(self, signum: int, _frame: Any) -> None:
        if self._immediate is not None:
            self.signum = signum
            raise TrainingInterrupted(signum, self._immediate)
        if self.signum is not None:
            raise KeyboardInterrupt
        self.signum = signum
        name = signal.Signals(signum).name
        print(f"\n{name}: {self.announce} (send it again to stop at once, without saving)", file=sys.stderr,
              flush=True)

    class _Immediate:
        def __init__(self, owner: StopRequest, message: str) -> None:
            self.owner, self.message = owner, message

        def __enter__(self) -> None:
            if self.owner.signum is not None:  # a signal came just before: honour it now
                raise TrainingInterrupted(self.owner.signum, self.message)
            self.owner._immediate = self.message

        def __exit__(self, *_: Any) -> None:
            self.owner._immediate = None

    def immediate(self, message: str) -> StopRequest._Immediate:
        """A section in which a signal raises :class:`TrainingInterrupted` with ``message`` at once."""
        return StopRequest._Immediate(self, message)


def ignore_interrupts() -> None:
    """Process-pool initializer: a worker ignores SIGINT (Ctrl-C reaches the whole process group;
    the parent decides when to stop and shuts its workers down itself)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


# --------------------------------------------------------------------------- checkpoint files


def run_training(start: Callable[[], Path]) -> Path | int:
    """A trainer's command line around ``start()`` (a new run or ``--resume``): its run directory, or the exit
    code after one line on stderr: the signal's code (130/143) for :class:`TrainingInterrupted`, 130 for a
    second Ctrl-C (nothing saved since the last checkpoint), 2 for a bad option, run name or file."""
    try:
        return start()
    except TrainingInterrupted as exc:
        print(exc, file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print("stopped at once: nothing saved since the last checkpoint", file=sys.stderr)
        return 130
    except (ValueError, TypeError, FileExistsError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


def claim_run_dir(run_dir: Path) -> Path:
    """Create ``run_dir`` for a new run; ``FileExistsError`` pointing to ``--resume`` if it holds one already."""
    if (run_dir / "config.json").exists():
        raise FileExistsError(f"run directory {run_dir} already holds a run; pick another --run-name, "
                              f"or continue it with --resume {run_dir}")
    run_dir.mkdir(parents=True, exist_ok=True)
    return run_dir


def resume_config(run_dir: str | Path, overrides: dict[str, Any], allowed: tuple[str, ...]) -> Path:
    """The ``config.json`` of the run ``--resume`` continues: ``FileNotFoundError`` if ``run_dir`` holds no run,
    ``ValueError`` if ``overrides`` set anything but the ``allowed`` fields (the rest of a run is what it was)."""
    cfg_path = Path(run_dir) / "config.json"
    if not cfg_path.is_file():
        raise FileNotFoundError(f"--resume {run_dir}: no run there ({cfg_path} not found)")
    bad = sorted(set(overrides) - set(allowed))
    if bad:
        flags = ", ".join("--" + b.replace("_", "-") for b in bad)
        can = ", ".join("--" + b.replace("_", "-") for b in allowed)
        raise ValueError(f"--resume continues {cfg_path} as it is: {flags} cannot change (only {can} can)")
    return cfg_path


def start_run_dir(cfg: Any, default_name: str, train_columns: tuple[str, ...], eval_columns: tuple[str, ...]) -> Path:
    """A new run directory for the config ``cfg`` (its ``runs_dir``/``run_name``, else ``default_name`` plus a UTC
    time stamp): ``config.json``, ``versions.json`` and the CSV logs' headers. ``FileExistsError`` if it holds a run."""
    import time


    stamp = time.strftime("%Y%m%d-%H%M%S", time.gmtime())
    run_dir = claim_run_dir(Path(cfg.runs_dir) / (cfg.run_name or f"{default_name}_{stamp}"))
    (run_dir / "config.json").write_text(cfg.to_json() + "\n")
    write_json(run_dir / "versions.json", package_versions())
    RunLog.create(run_dir, train_columns, eval_columns)
    return run_dir


def resume_run_dir(run_dir: str | Path, overrides: dict[str, Any], allowed: tuple[str, ...], config: type,
                   checkpoint_format: str) -> tuple[Any, tuple[dict[str, Any], dict[str, Any]]]:
    """``(config, checkpoint)`` of the run ``--resume`` continues: its ``config.json`` with ``overrides`` (only the
    ``allowed`` fields; written back if any) and its latest checkpoint (``run_dir/checkpoint``, of
    ``checkpoint_format``). ``FileNotFoundError``/``ValueError`` naming the file for a missing or bad one."""
    run_dir = Path(run_dir)
    cfg_path = resume_config(run_dir, overrides, allowed)
    saved = read_json(cfg_path, MAX_DESCRIPTION_BYTES, "run config")  # bounded, strict JSON; errors name the file
    try:
        if not isinstance(saved, dict):
            raise ValueError(f"expected a JSON object, got {type(saved).__name__}")
        cfg = config(**{**saved, **overrides})
    except (ValueError, TypeError) as exc:
        raise ValueError(f"{cfg_path}: not a {config.__name__} ({exc})") from None
    checkpoint = run_dir / CHECKPOINT_DIR
    if not (checkpoint / STATE_JSON).is_file():
        raise FileNotFoundError(f"--resume {run_dir}: no checkpoint in it (the run stopped before its first one): "
                                "start a new run")
    state = read_checkpoint(checkpoint, checkpoint_format)
    if overrides:
        with _atomic(cfg_path) as tmp:
            tmp.write_text(cfg.to_json() + "\n")
    return cfg, state


def write_checkpoint(directory: Path, tensors: dict[str, Any], meta: dict[str, Any]) -> Path:
    """Write ``tensors`` (name -> torch tensor) to ``directory/state.safetensors`` and ``meta`` (JSON
    values) to ``directory/state.json``, replacing a previous checkpoint there as a whole."""
    from safetensors.torch import save_file


    tmp = directory.with_name(f".{directory.name}.tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    save_file({k: v.detach().cpu().contiguous() for k, v in tensors.items()}, str(tmp / STATE_TENSORS))
    (tmp / STATE_JSON).write_text(dumps(meta, indent=1) + "\n")  # strict JSON (non-finite -> null)
    return swap_in_dir(tmp, directory)


def read_checkpoint(directory: Path, fmt: str) -> tuple[dict[str, Any], dict[str, Any]]:
    """``(tensors, meta)`` of a checkpoint written by :func:`write_checkpoint` whose ``meta["format"]``
    is ``fmt``, both read within the bounds of :mod:`swarm_env_baselines.model_bounds` (``state.json`` as a JSON run
    file, ``state.safetensors`` by :func:`~swarm_env_baselines.model_bounds.read_checkpoint_tensors`). Raises
    ``FileNotFoundError`` or ``ValueError`` naming the file."""
    meta_path, tensor_path = directory / STATE_JSON, directory / STATE_TENSORS
    if not meta_path.is_file() or not tensor_path.is_file():
        raise FileNotFoundError(f"{directory}: no checkpoint ({STATE_JSON} and {STATE_TENSORS} expected)")
    meta = read_description(meta_path, fmt)
    return read_checkpoint_tensors(tensor_path), meta  # bounded: the file, its header, dtypes, sizes, finite values


def optimizer_to_files(optim: Any, prefix: str = "optim") -> tuple[dict[str, Any], dict[str, Any]]:
    """A torch optimizer's ``state_dict`` split into tensors (``<prefix>.<param>.<key>``) and JSON
    (the param groups and any non-tensor per-parameter state)."""
    import torch

    sd = optim.state_dict()
    tensors: dict[str, Any] = {}
    plain: dict[str, dict[str, Any]] = {}
    for index, entry in sd["state"].items():
        for key, value in entry.items():
            if isinstance(value, torch.Tensor):
                tensors[f"{prefix}.{index}.{key}"] = value
            else:
                plain.setdefault(str(index), {})[key] = value
    return tensors, {"param_groups": sd["param_groups"], "plain_state": plain}


def optimizer_from_files(optim: Any, tensors: dict[str, Any], meta: dict[str, Any], source: Path,
                         prefix: str = "optim") -> None:
    """Load into ``optim`` what :func:`optimizer_to_files` wrote (``source`` names the checkpoint in errors).

    JSON turns tuples into lists; each hyperparameter is given back the type the fresh optimizer
    has for it (Adam's ``betas`` is a tuple)."""
    template = optim.state_dict()["param_groups"]
    try:
        groups = []
        for fresh, saved in zip(template, meta["param_groups"], strict=True):
            groups.append({k: tuple(v) if isinstance(fresh.get(k), tuple) else v for k, v in saved.items()})
        state: dict[int, dict[str, Any]] = {}
        for name, value in tensors.items():
            if name.startswith(prefix + "."):
                index, key = name[len(prefix) + 1:].split(".", 1)
                state.setdefault(int(index), {})[key] = value
        for index, entry in meta["plain_state"].items():
            state.setdefault(int(index), {}).update(entry)
        optim.load_state_dict({"state": state, "param_groups": groups})
    except (KeyError, TypeError, ValueError, RuntimeError) as exc:
        raise ValueError(f"{source}: the optimizer state does not fit this run's networks ({exc})") from None


# --------------------------------------------------------------------------- CSV logs


def csv_rows(path: Path) -> int:
    """Data rows (after the header) in a CSV file; 0 if it does not exist."""
    if not path.is_file():
        return 0
    with open(path, newline="") as fh:
        return max(0, sum(1 for _ in csv.reader(fh)) - 1)


def truncate_csv(path: Path, rows: int) -> None:
    """Keep the header and the first ``rows`` data rows of ``path`` (what a checkpoint had logged)."""
    with open(path, newline="") as fh:
        kept = [r for _, r in zip(range(rows + 1), csv.reader(fh))]
    with open(path, "w", newline="") as fh:
        csv.writer(fh).writerows(kept)


def trainer_main(parser: argparse.ArgumentParser, argv: list[str] | None, config: type,
                 train: Callable[[Any], Path], resume: Callable[..., Path]) -> int:
    """Parse ``argv``, then train a new run of ``config`` or resume one; print the run directory and its summary.
    Returns the process exit status (a signal's 128 + N after saving, see
    :func:`run_training`)."""
    args = vars(parser.parse_args(argv))
    for name in ("env_kwargs", "train_env_kwargs"):
        if name in args:
            args[name] = dict(args[name])
    if "resume" in args:
        where = args.pop("resume")
        run = run_training(lambda: resume(where, **args))
    else:
        run = run_training(lambda: train(config(**args)))
    if isinstance(run, int):
        return run
    print(run)
    print((run / "summary.json").read_text())
    return 0
