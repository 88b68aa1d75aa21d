"""Policies as tensors + JSON (swarm_env_baselines.safe_io): written by every save, loaded without unpickling anything."""

from __future__ import annotations

import json
import pickle

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")
pytest.importorskip("safetensors")

import torch  # noqa: E402

from swarm_env.env import SwarmEnv  # noqa: E402
from swarm_env.harness.episode import run_episode  # noqa: E402
from swarm_env.harness.policies import PolicyError, load_policy  # noqa: E402
from swarm_env_baselines import convert, model_io, safe_io  # noqa: E402
from swarm_env_baselines import train as train_mod  # noqa: E402
from tests.test_train import TINY_ENV, _tiny  # noqa: E402


class _Payload:
    """Unpickling this writes a marker file: what an attacker's pickle would do instead."""

    def __init__(self, marker: str) -> None:
        self.marker = marker

    def __reduce__(self):
        return (open, (self.marker, "w"))


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    return train_mod.train(_tiny(tmp_path_factory.mktemp("runs"), checkpoint_every=0))


def test_every_saved_model_has_the_safe_files(run) -> None:
    for d in (run, run / "best"):
        assert safe_io.has_safe_policy(d)
        config = json.loads((d / safe_io.CONFIG_FILE).read_text())
        assert config["format"] == safe_io.FORMAT and config["algo"] == "ppo"
        assert config["normalization"] is not None and len(config["normalization"]["mean"]) == 52


def test_scoring_never_unpickles(run, tmp_path) -> None:
    import shutil

    d = tmp_path / "poisoned"
    shutil.copytree(run, d)
    marker = tmp_path / "payload_ran"
    (d / model_io.VECNORM_FILE).write_bytes(pickle.dumps(_Payload(str(marker))))
    (d / model_io.MODEL_FILE).write_bytes(b"not a zip at all")
    env = SwarmEnv("random", **TINY_ENV)
    policy = load_policy(f"ppo:{d}", env)
    result = run_episode(env, policy, seed=1000)
    assert result["steps"] == 30 and not marker.exists()


def test_the_safe_policy_acts_like_the_pickled_model(run) -> None:
    torch.set_num_threads(1)
    model, vecnorm = model_io.load_model(run, trust_pickle=True)
    policy, norm, algo = safe_io.load_policy_dir(run)
    obs = np.random.default_rng(0).uniform(-4, 4, (128, 52)).astype(np.float32)
    np.testing.assert_array_equal(vecnorm.normalize_obs(obs), norm.normalize_obs(obs))
    expected, _ = model.predict(vecnorm.normalize_obs(obs), deterministic=True)
    got, _ = policy.predict(norm.normalize_obs(obs), deterministic=True)
    np.testing.assert_array_equal(expected, got)
    assert algo == "ppo"


def test_bad_safe_files_are_clear_errors(run, tmp_path) -> None:
    import shutil

    env = SwarmEnv("random", **TINY_ENV)
    d = tmp_path / "bad"
    shutil.copytree(run, d)
    (d / safe_io.WEIGHTS_FILE).write_bytes(b"\x00" * 100)
    with pytest.raises(PolicyError, match="policy.safetensors: not a readable safetensors file"):
        load_policy(f"ppo:{d}", env)
    shutil.copy(run / safe_io.WEIGHTS_FILE, d / safe_io.WEIGHTS_FILE)
    (d / safe_io.CONFIG_FILE).write_text('{"format": "something else"}')
    with pytest.raises(PolicyError, match="format: expected"):
        load_policy(f"ppo:{d}", env)
    shutil.copy(run / safe_io.CONFIG_FILE, d / safe_io.CONFIG_FILE)
    with pytest.raises(PolicyError, match="holds a ppo policy; load it as ppo:"):
        load_policy(f"sac:{d}", env)


def test_the_converter_writes_safe_files_for_an_old_run(run, tmp_path, capsys) -> None:
    import shutil

    d = tmp_path / "old"
    shutil.copytree(run, d)
    for f in (safe_io.WEIGHTS_FILE, safe_io.CONFIG_FILE):
        (d / f).unlink()
    assert convert.main([str(d), "--trust-pickle"]) == 0 and safe_io.has_safe_policy(d)
    assert "wrote" in capsys.readouterr().out
    assert convert.main([str(tmp_path / "missing"), "--trust-pickle"]) == 2
