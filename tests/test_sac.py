"""Shared-parameter SAC on the batched engine (swarm_env_baselines.sac): a tiny run end to end, the policy it
saves, determinism, a resumed run ending bit for bit as an uninterrupted one, the squashed Gaussian's
log-probability, bad input."""

from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("safetensors")

from swarm_env.env import SwarmEnv  # noqa: E402
from swarm_env.harness.episode import run_episode  # noqa: E402
from swarm_env.harness.policies import ModelFileError, PolicyError, load_policy  # noqa: E402
from swarm_env_baselines import sac  # noqa: E402

TINY_ENV = {"n_followers": 2, "n_obstacles": 1, "n_humans": 1, "max_cycles": 30}


def _cfg(tmp_path, **overrides) -> sac.SACConfig:
    base = dict(env_kwargs=dict(TINY_ENV), total_steps=1200, n_copies=3, buffer_size=600, learning_starts=240,
                batch_size=32, hidden=(16, 16), eval_every=600, eval_seeds="500-501", runs_dir=str(tmp_path),
                run_name="tiny", progress=False, checkpoint_every=0, log_every=60, prefetch_worlds=False)
    return sac.SACConfig(**{**base, **overrides})


def test_a_tiny_run_is_complete_and_plays_as_isac(tmp_path) -> None:
    run = sac.train(_cfg(tmp_path))
    for name in ("config.json", "versions.json", "policy.safetensors", "policy.json", "eval.csv", "train.csv",
                 "summary.json", "learning_curve.png", "checkpoint/state.json", "best/policy.json"):
        assert (run / name).is_file(), name
    assert list((run / "tb").glob("events.out.tfevents.*")), "TensorBoard events"
    evals = [int(r["agent_steps"]) for r in csv.DictReader(open(run / "eval.csv"))]
    assert evals == [0, 600, 1200]
    rows = list(csv.DictReader(open(run / "train.csv")))
    assert rows and all(math.isfinite(float(r["q_loss"])) for r in rows if r["q_loss"] != "nan")
    assert float(rows[-1]["alpha"]) > 0
    env = SwarmEnv("random", **TINY_ENV)
    policy = load_policy(f"isac:{run}/best", env)
    result = run_episode(env, policy, seed=1000)
    assert result["steps"] == 30 and np.isfinite(result["formation_error"]["mean"])
    with pytest.raises(PolicyError, match="trained on inputs of size"):
        load_policy(f"isac:{run}", SwarmEnv("random", **TINY_ENV, sensors={"lidar_rays": 8}))
    with pytest.raises(ModelFileError, match="format"):  # a MAPPO description is refused, naming its loader
        (tmp_path / "other").mkdir()
        (tmp_path / "other" / "policy.json").write_text(json.dumps({"format": "swarm_env.mappo/1"}))
        load_policy(f"isac:{tmp_path / 'other'}", env)


@pytest.mark.slow
def test_the_same_seed_learns_the_same_networks_and_a_resumed_run_ends_as_an_uninterrupted_one(tmp_path,
                                                                                              monkeypatch) -> None:
    from safetensors.numpy import load_file

    whole = sac.train(_cfg(tmp_path, run_name="whole", eval_every=0))
    again = sac.train(_cfg(tmp_path, run_name="again", eval_every=0))
    other = sac.train(_cfg(tmp_path, run_name="other", eval_every=0, seed=1))
    a, b, c = (load_file(str(r / "policy.safetensors")) for r in (whole, again, other))
    assert all(np.array_equal(a[k], b[k]) for k in a)
    assert any(not np.array_equal(a[k], c[k]) for k in a)

    # A crash after a checkpoint half-way (worlds mid-episode, the buffer part-full), then --resume.
    original = sac.SAC.learn
    calls = {"n": 0}

    def learn(self):
        calls["n"] += 1
        if calls["n"] == 100:  # engine step 140 (840 agent-steps), after the checkpoint at 540
            raise RuntimeError("simulated crash")
        return original(self)

    cfg = _cfg(tmp_path, run_name="parts", eval_every=0, checkpoint_every=540)
    with monkeypatch.context() as m:
        m.setattr(sac.SAC, "learn", learn)
        with pytest.raises(RuntimeError, match="simulated crash"):
            sac.train(cfg)
    state = json.loads((tmp_path / "parts" / "checkpoint" / "state.json").read_text())
    assert state["agent_steps"] == 540 and 0 < state["buffer"]["size"] <= 600
    with _no_rebuild_warning():
        sac.resume(tmp_path / "parts")
    parts = load_file(str(tmp_path / "parts" / "policy.safetensors"))
    assert all(np.array_equal(a[k], parts[k]) for k in a)
    # The checkpoint names the equal final state too (the buffer, the optimisers, the generators).
    ca = load_file(str(whole / "checkpoint" / "state.safetensors"))
    cb = load_file(str(tmp_path / "parts" / "checkpoint" / "state.safetensors"))
    assert ca.keys() == cb.keys() and all(np.array_equal(ca[k], cb[k]) for k in ca)


class _no_rebuild_warning:
    """Fails the test if the rebuilt worlds differ from the checkpoint's (the restore's warning)."""

    def __enter__(self) -> None:
        import warnings

        self._ctx = warnings.catch_warnings()
        self._ctx.__enter__()
        warnings.filterwarnings("error", message=".*rebuilt worlds differ")

    def __exit__(self, *exc) -> None:
        self._ctx.__exit__(*exc)


def test_the_squashed_log_probability_is_the_change_of_variables() -> None:
    """log p(a) of a = tanh(u), u ~ N(mean, std): the Gaussian's density minus log |da/du| = log(1 - a^2)."""
    learner = sac.SAC.__new__(sac.SAC)
    learner.device = torch.device("cpu")
    learner.gen = torch.Generator().manual_seed(0)
    learner.actor = lambda x: x  # (mean, log std) given directly
    params = torch.tensor([[0.3, -1.2, -0.5, 0.1], [2.0, 0.0, -3.0, -4.0]])
    action, logp = learner._sample(params)
    mean, log_std = params.chunk(2, dim=-1)
    u = torch.atanh(action.double())
    gauss = torch.distributions.Normal(mean.double(), log_std.double().exp()).log_prob(u).sum(-1)
    expected = gauss - torch.log(1 - action.double() ** 2).sum(-1)
    assert torch.allclose(logp.double(), expected, atol=1e-3)


def test_bad_configs_are_refused(tmp_path) -> None:
    with pytest.raises(ValueError, match="batch_size must be a positive int"):
        sac.SACConfig(batch_size=0)
    with pytest.raises(ValueError, match="gamma and tau"):
        sac.SACConfig(tau=0.0)
    with pytest.raises(ValueError, match="device must be"):
        sac.SACConfig(device="tpu")
    with pytest.raises(ValueError, match="at most n_copies"):
        sac.SACConfig(n_copies=2, env_procs=3)
    if not torch.cuda.is_available():
        with pytest.raises(ValueError, match="torch sees no GPU"):
            sac.train(_cfg(tmp_path, device="cuda"))
    with pytest.raises(FileNotFoundError, match="config.json|no checkpoint"):
        sac.resume(tmp_path / "nowhere")
