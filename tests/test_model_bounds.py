"""Hostile model files are refused quickly, before any large allocation, in one line (issue 35, item 2).

A copy of a shipped run directory (and of an ``rllib:`` and an ``isac:`` directory built from one) is tampered with
in each of the ways a hostile reviewer found (:mod:`swarm_env_baselines.model_bounds`): oversized, negative, string
and 100,000 hidden layers; a deeply nested or 10 GB sparse ``policy.json``; FIFOs in place of the files; NaN and
infinite normalisation statistics; a residual given as an object, one whose expert is itself or another residual
run; NaN, huge and integer weights; a safetensors header declaring 1 TB, 200,000 tensors, a 10 GB sparse weights
file; an SB3 description with dtype ``V100000000``, million-unit layers, non-finite statistics or another action
size. Each must raise :class:`~swarm_env.harness.policies.ModelFileError` through ``load_policy`` (what ``swarm-env
run`` builds a policy with) within :data:`BUDGET_S` seconds and without raising the process's peak memory by more
than :data:`PEAK_MB`; ``swarm-env run`` prints one line and exits with code 2.
"""

from __future__ import annotations

import json
import os
import re
import resource
import shutil
import signal
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, cast

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")
pytest.importorskip("safetensors")

from safetensors.numpy import load_file, save_file  # noqa: E402

from swarm_env.env import SwarmEnv  # noqa: E402
from swarm_env.harness import cli  # noqa: E402
from swarm_env.harness.policies import ModelFileError, load_policy  # noqa: E402
from swarm_env_baselines.mappo_policy import shipped_run  # noqa: E402
from swarm_env_baselines.safe_io import RLLIB_FORMAT, SAC_FORMAT  # noqa: E402
from tests.test_train import TINY_ENV  # noqa: E402

#: Seconds one refusal may take (each takes well under a tenth of one here); a hang is interrupted at this point.
BUDGET_S = 3.0
#: How much one refusal may raise the process's peak memory (MB).
PEAK_MB = 200
#: A 10 GB sparse file (no disk used).
TEN_GB = 10 << 30
#: The spec prefix of each kind of run directory.
SPECS = {"mappo": "mappo", "residual_vo": "residual_vo", "fan_dagger": "fan_dagger", "sb3_ppo": "ppo",
         "rllib": "rllib", "isac": "isac"}


def _env() -> SwarmEnv:
    return SwarmEnv("random", **cast(dict[str, Any], TINY_ENV))


@pytest.fixture(scope="module")
def bases(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """One untampered run directory of each kind, each checked to load (and every loader imported once, so that no
    case pays for an import)."""
    import torch

    from swarm_env_baselines.ppo_core import mlp

    root = tmp_path_factory.mktemp("bases")
    out = {name: Path(shutil.copytree(shipped_run(name, "s0"), root / name))
           for name in ("mappo", "residual_vo", "fan_dagger", "sb3_ppo")}
    mappo = json.loads((out["mappo"] / "policy.json").read_text())
    actor = {k: v for k, v in load_file(out["mappo"] / "policy.safetensors").items() if k.startswith("actor.")}
    out["rllib"] = root / "rllib"
    out["rllib"].mkdir()
    save_file(actor, out["rllib"] / "policy.safetensors")
    (out["rllib"] / "policy.json").write_text(json.dumps({"format": RLLIB_FORMAT, "sizes": [52, 128, 128, 2],
                                                          "activation": "tanh", "config": {}}))
    out["isac"] = root / "isac"
    out["isac"].mkdir()
    torch.manual_seed(0)
    net = mlp([52, 16, 4])
    save_file({f"actor.{k}": v.detach().numpy() for k, v in net.state_dict().items()},
              out["isac"] / "policy.safetensors")
    (out["isac"] / "policy.json").write_text(json.dumps({"format": SAC_FORMAT, "config": {"hidden": [16]},
                                                         "obs_rms": mappo["obs_rms"]}))
    env = _env()
    for name, d in out.items():
        load_policy(f"{SPECS[name]}:{d}", env)
    return out


# --------------------------------------------------------------------------- tampering


def _edit(edit: Callable[[dict[str, Any]], Any]) -> Callable[[Path], None]:
    """Rewrite ``policy.json`` with ``edit`` applied (non-finite floats written as NaN / Infinity)."""

    def tamper(d: Path) -> None:
        meta = json.loads((d / "policy.json").read_text())
        edit(meta)
        (d / "policy.json").write_text(json.dumps(meta))

    return tamper


def _text(old: str, new: str) -> Callable[[Path], None]:
    def tamper(d: Path) -> None:
        text = (d / "policy.json").read_text()
        assert old in text
        (d / "policy.json").write_text(text.replace(old, new, 1))

    return tamper


def _tensor(key: str, change: Callable[[np.ndarray], np.ndarray]) -> Callable[[Path], None]:
    """Rewrite ``policy.safetensors`` with the tensor ``key`` changed (safetensors.numpy.save_file)."""

    def tamper(d: Path) -> None:
        tensors = load_file(d / "policy.safetensors")
        tensors[key] = change(tensors[key].copy())
        save_file(tensors, d / "policy.safetensors")

    return tamper


def _first(value: float) -> Callable[[np.ndarray], np.ndarray]:
    def change(a: np.ndarray) -> np.ndarray:
        a.flat[0] = value
        return a

    return change


def _fifo(name: str) -> Callable[[Path], None]:
    def tamper(d: Path) -> None:
        (d / name).unlink()
        os.mkfifo(d / name)

    return tamper


def _sparse(name: str) -> Callable[[Path], None]:
    """Extend the file to 10 GB with a hole (its start, the real content, kept)."""

    def tamper(d: Path) -> None:
        os.truncate(d / name, TEN_GB)

    return tamper


def _deep_json(d: Path) -> None:
    (d / "policy.json").write_text("[" * 100_000 + "]" * 100_000)


def _raw_weights(header: bytes, declared: int | None = None) -> Callable[[Path], None]:
    def tamper(d: Path) -> None:
        padded = header + b" " * (-len(header) % 8)
        length = len(padded) if declared is None else declared
        (d / "policy.safetensors").write_bytes(length.to_bytes(8, "little") + padded)

    return tamper


_MANY_ENTRIES = json.dumps({f"t{i}": {"dtype": "F32", "shape": [0], "data_offsets": [0, 0]}
                            for i in range(200_000)}).encode()


def _self_expert(d: Path) -> None:
    _edit(lambda m: m["config"].update(residual=f"mappo:{d}"))(d)


def _set(path: str, value: Any) -> Callable[[dict[str, Any]], None]:
    """Set the key at the dotted ``path`` (``config.hidden``, ``obs_rms.var.0``) to ``value``."""
    *parents, last = path.split(".")

    def edit(meta: dict[str, Any]) -> None:
        obj: Any = meta
        for p in parents:
            obj = obj[int(p)] if isinstance(obj, list) else obj[p]
        obj[int(last) if isinstance(obj, list) else last] = value

    return edit


def _box(n: int) -> dict[str, Any]:
    return {"type": "Box", "shape": [n], "dtype": "float32", "low": [-1.0] * n, "high": [1.0] * n}


FINITE = "expected a finite number, got"
NOT_RESIDUAL = r"policy\.json: config\.residual: expected the spec of an expert that is not itself a residual run"

#: (id, base, tamper, what the one line must say).
CASES: list[tuple[str, str, Callable[[Path], None], str]] = [
    # architecture
    ("mappo-widths-1e6", "mappo", _edit(_set("config.hidden", [1_000_000, 1_000_000])), r"config\.hidden: expected"),
    ("mappo-width-negative", "mappo", _edit(_set("config.hidden", [-128, 128])), r"config\.hidden: expected"),
    ("mappo-width-strings", "mappo", _edit(_set("config.hidden", ["128", "128"])), r"config\.hidden: expected"),
    ("mappo-100k-layers", "mappo", _edit(_set("config.hidden", [256] * 100_000)),
     r"config\.hidden: expected a list of 1-16 layer widths"),
    ("sb3-net-arch-1e6", "sb3_ppo", _edit(_set("policy_kwargs.net_arch", {"pi": [1_000_000] * 2, "vf": [64]})),
     r"net_arch\.pi: expected"),
    ("sb3-net-arch-negative", "sb3_ppo", _edit(_set("policy_kwargs.net_arch.pi", [-5])), r"net_arch\.pi: expected"),
    ("sb3-action-size-3", "sb3_ppo", _edit(_set("action_space", _box(3))), r"action_space\.shape\[0\]: expected"),
    ("sb3-dtype-V100000000", "sb3_ppo", _edit(_set("observation_space.dtype", "V100000000")),
     r"observation_space\.dtype: expected"),
    ("rllib-sizes-1e6", "rllib", _edit(_set("sizes", [52, 1_000_000, 1_000_000, 2])), r"hidden widths\): expected"),
    ("rllib-size-negative", "rllib", _edit(_set("sizes", [52, -1, 2])), r"hidden widths\): expected"),
    ("isac-width-strings", "isac", _edit(_set("config.hidden", ["16"])), r"config\.hidden: expected"),
    # the description file
    ("json-nested-100k", "mappo", _deep_json, r"nested 100000 deep"),
    ("json-sparse-10GB", "mappo", _sparse("policy.json"), r"10,737,418,240 bytes, more than"),
    ("json-fifo", "mappo", _fifo("policy.json"), r"policy\.json: a FIFO, not a regular file"),
    # normalisation statistics and other numbers
    ("mappo-epsilon-nan", "mappo", _edit(_set("obs_rms.epsilon", float("nan"))), rf"obs_rms\.epsilon: {FINITE} nan"),
    ("mappo-clip-inf", "mappo", _edit(_set("obs_rms.clip", float("inf"))), rf"obs_rms\.clip: {FINITE} inf"),
    ("mappo-clip-1e400", "mappo", _text('"clip": 10.0', '"clip": 1e400'), rf"obs_rms\.clip: {FINITE} inf"),
    ("isac-epsilon-nan", "isac", _edit(_set("obs_rms.epsilon", float("nan"))), rf"obs_rms\.epsilon: {FINITE} nan"),
    ("fan-clip-inf", "fan_dagger", _edit(_set("obs_rms.clip", float("-inf"))), rf"obs_rms\.clip: {FINITE} -inf"),
    ("fan-option-bool-string", "fan_dagger", _edit(_set("fan.options", {"drop_seen": "no"})),
     r"fan\.options\.drop_seen: expected true or false"),
    ("sb3-clip-obs-nan", "sb3_ppo", _edit(_set("normalization.clip_obs", float("nan"))),
     r"normalization\.clip_obs: expected a finite number, got nan"),
    ("sb3-var-negative", "sb3_ppo", _edit(_set("normalization.var.0", -1.0)), r"normalization\.var\[0\]: expected"),
    ("sb3-normalization-list", "sb3_ppo", _edit(_set("normalization", [1, 2])),
     r"normalization: expected a JSON object"),
    # residual runs
    ("residual-as-object", "mappo", _edit(lambda m: m["config"].update(residual={"spec": "vo"}, residual_scale=0.5)),
     r"config\.residual: expected a policy spec"),
    ("residual-scale-nan", "residual_vo", _edit(_set("config.residual_scale", float("nan"))),
     r"config\.residual_scale: expected a finite number, got nan"),
    ("residual-scale-string", "residual_vo", _edit(_set("config.residual_scale", "0.5")),
     r"config\.residual_scale: expected a finite number"),
    ("residual-expert-is-itself", "residual_vo", _self_expert, NOT_RESIDUAL),
    ("residual-expert-is-residual", "residual_vo", _edit(_set("config.residual", "residual_vo")), NOT_RESIDUAL),
    ("residual-expert-unknown-argument", "residual_vo", _edit(_set("config.residual", "vo:bogus=1")),
     r"config\.residual: policy 'vo': unknown parameter 'bogus'"),
    ("residual-expert-argument-out-of-range", "residual_vo", _edit(_set("config.residual", "vo:reverse=-5")),
     r"config\.residual: policy 'vo:reverse=-5': reverse must be a number in \[0, 1\]"),
    # the weights file
    ("weights-nan", "mappo", _tensor("actor.0.weight", _first(np.nan)), r"actor\.0\.weight'?: not all finite"),
    ("weights-huge", "mappo", _tensor("actor.2.weight", _first(1e30)), r"actor\.2\.weight'?: a value of magnitude"),
    ("weights-int64", "mappo", _tensor("actor.0.bias", lambda a: a.astype(np.int64)), r"dtype 'I64', expected"),
    ("weights-nan-sb3", "sb3_ppo", _tensor("action_net.weight", _first(np.nan)), r"not all finite"),
    ("weights-nan-rllib", "rllib", _tensor("actor.4.bias", _first(np.inf)), r"not all finite"),
    ("weights-header-1TB", "mappo", _raw_weights(b"{}", declared=1 << 40), r"header of 1,099,511,627,776 bytes"),
    ("weights-200k-entries", "mappo", _raw_weights(_MANY_ENTRIES), r"bytes, more than"),
    ("weights-sparse-10GB", "fan_dagger", _sparse("policy.safetensors"), r"10,737,418,240 bytes, more than"),
    ("weights-fifo", "mappo", _fifo("policy.safetensors"), r"policy\.safetensors: a FIFO, not a regular file"),
]


class _TooSlow(Exception):
    pass


@pytest.fixture()
def deadline() -> Iterator[None]:
    """Interrupt the test after BUDGET_S seconds (a loader that hangs fails instead of blocking the suite)."""

    def stop(signum: int, frame: Any) -> None:
        raise _TooSlow(f"still loading after {BUDGET_S} s")

    previous = signal.signal(signal.SIGALRM, stop)
    signal.setitimer(signal.ITIMER_REAL, BUDGET_S)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # kB on Linux


@pytest.mark.parametrize(("base", "tamper", "says"), [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_a_hostile_model_file_is_refused_quickly_in_one_line(bases, tmp_path, base, tamper, says, deadline) -> None:
    d = Path(shutil.copytree(bases[base], tmp_path / "run"))
    tamper(d)
    env = _env()
    peak, start = _peak_mb(), time.perf_counter()
    with pytest.raises(ModelFileError, match=says) as info:
        load_policy(f"{SPECS[base]}:{d}", env)
    took = time.perf_counter() - start
    message = str(info.value)
    assert "\n" not in message and len(message) < 1500 and str(d) in message
    assert took < BUDGET_S and _peak_mb() - peak < PEAK_MB


@pytest.mark.parametrize("case", ["json-nested-100k", "residual-expert-is-itself", "weights-nan"])
def test_the_cli_reports_a_hostile_model_file_in_one_line(bases, tmp_path, capsys, case, deadline) -> None:
    _, base, tamper, says = next(c for c in CASES if c[0] == case)
    d = Path(shutil.copytree(bases[base], tmp_path / "run"))
    tamper(d)
    code = cli.main(["run", "--scenario", "random", "--policy", f"{SPECS[base]}:{d}", "--max-cycles", "5",
                     *[a for k, v in TINY_ENV.items() if k != "max_cycles" for a in ("--env", f"{k}={json.dumps(v)}")]])
    captured = capsys.readouterr()
    assert code == 2 and captured.err.count("\n") == 1 and str(d) in captured.err, captured.err
    assert re.search(says, captured.err)
    assert captured.out == ""
