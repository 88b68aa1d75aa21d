"""A training checkpoint is read within bounds on ``--resume`` (issue 35: the last unbounded model-file read).

``swarm_env_baselines.model_bounds.read_checkpoint_tensors`` reads ``state.safetensors``: a regular file of at most
``MAX_CHECKPOINT_BYTES``, its header read before anything else and checked (dtypes, tensor count, sizes, offsets
that fill the file exactly), then mapped, every floating-point value finite. ``config.json`` is read as a bounded
strict JSON object. A tampered checkpoint gives one ``ValueError`` naming the file, quickly, and
``swarm-env train mappo --resume`` turns it into one line and exit code 2.
"""

from __future__ import annotations

import json
import os
import struct
import time
from pathlib import Path

import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("safetensors")

from safetensors.torch import save_file  # noqa: E402

from swarm_env_baselines import mappo  # noqa: E402
from swarm_env_baselines import model_bounds as mb  # noqa: E402
from swarm_env_baselines.checkpointing import CHECKPOINT_DIR, STATE_TENSORS  # noqa: E402

#: A tampered file is refused within this many seconds (reading it whole would take far longer for the sparse ones).
BUDGET_S = 2.0


def _write(path: Path, header: dict, payload: bytes = b"") -> Path:
    raw = json.dumps(header).encode()
    path.write_bytes(struct.pack("<Q", len(raw)) + raw + payload)
    return path


@pytest.fixture
def good(tmp_path: Path) -> Path:
    path = tmp_path / "state.safetensors"
    save_file({"actor.w": torch.ones(3, 4), "rng.state": torch.arange(16, dtype=torch.uint8),
               "step": torch.tensor([7], dtype=torch.int64), "flags": torch.tensor([True, False])}, str(path))
    return path


def test_a_well_formed_checkpoint_is_read_whole(good: Path) -> None:
    tensors = mb.read_checkpoint_tensors(good)
    assert sorted(tensors) == ["actor.w", "flags", "rng.state", "step"]
    assert torch.equal(tensors["rng.state"], torch.arange(16, dtype=torch.uint8))
    assert int(tensors["step"][0]) == 7


def _nan(tmp: Path, good: Path) -> Path:
    path = tmp / "nan.safetensors"
    save_file({"actor.w": torch.tensor([1.0, float("nan")])}, str(path))
    return path


def _inf64(tmp: Path, good: Path) -> Path:
    path = tmp / "inf.safetensors"
    save_file({"optim.0.exp_avg": torch.tensor([float("inf")], dtype=torch.float64)}, str(path))
    return path


def _truncated(tmp: Path, good: Path) -> Path:
    path = tmp / "cut.safetensors"
    path.write_bytes(good.read_bytes()[:-5])
    return path


def _padded(tmp: Path, good: Path) -> Path:
    path = tmp / "padded.safetensors"
    path.write_bytes(good.read_bytes() + b"\0" * 64)
    return path


def _sparse_huge_header(tmp: Path, good: Path) -> Path:
    path = tmp / "header.safetensors"
    with open(path, "wb") as f:
        f.write(struct.pack("<Q", 50 << 20))  # a 50 MB header announced
        f.truncate(8 + (50 << 20))
    return path


def _huge_shape(tmp: Path, good: Path) -> Path:
    return _write(tmp / "shape.safetensors", {"x": {"dtype": "F32", "shape": [1 << 20, 1 << 20],
                                                    "data_offsets": [0, 4]}}, b"\0" * 4)


def _object_dtype(tmp: Path, good: Path) -> Path:
    return _write(tmp / "dtype.safetensors", {"x": {"dtype": "V100000000", "shape": [1], "data_offsets": [0, 4]}},
                  b"\0" * 4)


def _too_many(tmp: Path, good: Path) -> Path:
    n = mb.MAX_CHECKPOINT_TENSORS + 1
    header = {f"t{i}": {"dtype": "U8", "shape": [1], "data_offsets": [i, i + 1]} for i in range(n)}
    return _write(tmp / "many.safetensors", header, b"\0" * n)


def _lying_offsets(tmp: Path, good: Path) -> Path:
    return _write(tmp / "offsets.safetensors", {"x": {"dtype": "F32", "shape": [4], "data_offsets": [0, 4]}},
                  b"\0" * 4)


def _deep_header(tmp: Path, good: Path) -> Path:
    raw = b"[" * 100_000 + b"]" * 100_000
    path = tmp / "deep.safetensors"
    path.write_bytes(struct.pack("<Q", len(raw)) + raw)
    return path


def _fifo(tmp: Path, good: Path) -> Path:
    path = tmp / "fifo.safetensors"
    os.mkfifo(path)
    return path


def _sparse_huge_file(tmp: Path, good: Path) -> Path:
    path = tmp / "sparse.safetensors"
    with open(path, "wb") as f:
        f.truncate(mb.MAX_CHECKPOINT_BYTES + 1)
    return path


@pytest.mark.parametrize("tamper, says", [
    (_nan, "not all finite"), (_inf64, "not all finite"), (_truncated, "truncated or corrupt"),
    (_padded, "truncated or corrupt"), (_sparse_huge_header, "refused before reading it"),
    (_huge_shape, "values, more than 2,147,483,648"), (_object_dtype, "dtype 'V100000000'"),
    (_too_many, "tensors, more than the 4,096 a checkpoint may hold"), (_lying_offsets, "data_offsets"),
    (_deep_header, "nested"), (_fifo, "a FIFO, not a regular file"), (_sparse_huge_file, "refused before reading"),
], ids=lambda v: getattr(v, "__name__", "")[1:] if callable(v) else None)
def test_a_tampered_checkpoint_is_refused_quickly_in_one_line(tmp_path: Path, good: Path, tamper, says: str) -> None:
    path = tamper(tmp_path, good)
    start = time.perf_counter()
    with pytest.raises(ValueError) as info:
        mb.read_checkpoint_tensors(path)
    assert time.perf_counter() - start < BUDGET_S
    message = str(info.value)
    assert says in message and message.startswith(str(path)) and "\n" not in message


def test_resume_from_a_tampered_checkpoint_or_config_is_one_line_exit_2(tmp_path: Path, capsys) -> None:
    from swarm_env_baselines.mappo import main

    cfg = mappo.MAPPOConfig(env_kwargs={"n_followers": 2, "n_obstacles": 1, "n_humans": 1, "max_cycles": 30},
                            total_steps=128, n_copies=2, n_steps=32, n_epochs=1, hidden=(8, 8), eval_every=0,
                            runs_dir=str(tmp_path), run_name="r", progress=False, pretrain="none",
                            checkpoint_every=1, prefetch_worlds=False, learner_process=False)
    run = mappo.train(cfg)
    state = run / CHECKPOINT_DIR / STATE_TENSORS
    tensors = mb.read_checkpoint_tensors(state)
    name = next(k for k, v in tensors.items() if v.is_floating_point() and v.numel())
    tensors[name] = tensors[name].clone()
    tensors[name].view(-1)[0] = float("nan")
    save_file(tensors, str(state))
    before = state.read_bytes()
    assert main(["--resume", str(run), "--total-steps", "256"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not all finite" in err[0] and str(state) in err[0]

    config = run / "config.json"
    config.write_text("[" * 10_000 + "]" * 10_000)
    assert main(["--resume", str(run), "--total-steps", "256"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "config.json" in err[0] and "nested" in err[0]
    assert state.read_bytes() == before and config.read_text().startswith("[[[")  # nothing was written over
