"""MAPPO's learner process (swarm_env_baselines.mappo_learner.ProcessLearner): the update it computes is the
training process's own, bit for bit; runs with it are deterministic and resume bit for bit."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("torch")
pytest.importorskip("safetensors")

import torch  # noqa: E402

from swarm_env_baselines import mappo  # noqa: E402
from swarm_env_baselines.mappo_learner import Batch, LearnerError, ProcessLearner, make_optimizer, ppo_update  # noqa: E402

ENV = {"n_followers": 2, "n_obstacles": 1, "n_humans": 1, "max_cycles": 20}
BASE = dict(env_kwargs=ENV, total_steps=5 * 3 * 24 * 2, n_copies=3, n_steps=24, n_epochs=2, hidden=(16, 16),
            pretrain="none", eval_every=0, progress=False, seed=3, prefetch_worlds=False)


def _load(path: Path) -> dict[str, np.ndarray]:
    from safetensors.numpy import load_file

    return load_file(str(path))


def _same_files(a: Path, b: Path) -> None:
    for name in ("policy.safetensors", "checkpoint/state.safetensors"):
        x, y = _load(a / name), _load(b / name)
        assert x.keys() == y.keys(), name
        assert all(np.array_equal(x[k], y[k]) for k in x), name


@pytest.mark.parametrize("critic", ["central", "local"])
@pytest.mark.slow
def test_the_learner_process_computes_the_training_process_update(critic: str, tmp_path: Path) -> None:
    """The same rollout, networks, optimiser and generator give the same parameters, statistics and values."""
    cfg = mappo.MAPPOConfig(**BASE, critic=critic, runs_dir=str(tmp_path), run_name="x")
    trainer = mappo.Trainer(cfg, tmp_path / "x")
    try:
        trainer.start()
        batch = trainer.collect()  # values from the trainer's critic, as the inline update uses them
        last = trainer.normalised()
        nets = trainer.networks()
        optim = make_optimizer(cfg, nets)
        gen = torch.Generator().manual_seed(11)
        learner = ProcessLearner(cfg, nets, optim, gen.get_state())
        try:
            sent = Batch(**{**batch.arrays(), "values": np.zeros_like(batch.values)})  # the learner computes them
            learner.submit(sent, last, 0, 5)
            torch.set_num_threads(1)  # as in the learner process
            expected = ppo_update(nets, optim, gen, cfg, batch, trainer.value(*last), 0, 5)
            inline = {k: v.copy() for k, v in nets.tensors().items()}
            got = learner.result(sent)  # loads the learner's parameters into `nets`
            assert got == expected
            assert np.array_equal(sent.values, batch.values)
            assert all(np.array_equal(inline[k], v) for k, v in nets.tensors().items())
            gen_state = learner.state()
            assert torch.equal(gen_state, gen.get_state())
        finally:
            learner.close()
    finally:
        trainer.close()


@pytest.mark.slow
def test_a_run_with_a_learner_process_is_deterministic_and_resumes_bit_for_bit(tmp_path: Path, monkeypatch) -> None:
    """Two runs of one seed end with the same files; a run that crashed after its third update and was resumed
    (the checkpoint holds the rollout collected but not learned from) ends as the uninterrupted one."""
    cfg = {**BASE, "checkpoint_every": 1, "runs_dir": str(tmp_path)}
    whole = mappo.train(mappo.MAPPOConfig(**cfg, run_name="whole"))
    again = mappo.train(mappo.MAPPOConfig(**cfg, run_name="again"))
    _same_files(whole, again)
    original = ProcessLearner.result

    def result(self, batch):
        stats = original(self, batch)
        result.calls += 1
        if result.calls == 3:
            raise RuntimeError("simulated crash")
        return stats

    result.calls = 0
    with monkeypatch.context() as m:
        m.setattr(ProcessLearner, "result", result)
        with pytest.raises(RuntimeError, match="simulated crash"):
            mappo.train(mappo.MAPPOConfig(**cfg, run_name="parts"))
    state = json.loads((tmp_path / "parts" / "checkpoint" / "state.json").read_text())
    assert state["learner"] == "process" and state["updates"] == 2 and state["pending"]["episode_returns"] is not None
    mappo.resume(tmp_path / "parts")
    _same_files(whole, tmp_path / "parts")
    rows = [(tmp_path / r / "train.csv").read_text().splitlines() for r in ("whole", "parts")]
    assert len(rows[0]) == len(rows[1]) == 6


@pytest.mark.slow
def test_a_learner_process_that_fails_names_its_error(tmp_path: Path) -> None:
    cfg = mappo.MAPPOConfig(**BASE, runs_dir=str(tmp_path), run_name="x")
    trainer = mappo.Trainer(cfg, tmp_path / "x")
    try:
        trainer.start()
        batch = trainer.collect(values=False)
        nets = trainer.networks()
        learner = ProcessLearner(cfg, nets, make_optimizer(cfg, nets), torch.Generator().get_state())
        try:
            bad = Batch(**{**batch.arrays(), "obs": batch.obs[..., :3].copy()})  # inputs of the wrong width
            learner.submit(bad, trainer.normalised(), 0, 5)
            with pytest.raises(LearnerError, match="the learner process failed:(.|\n)*shapes"):
                learner.result(bad)
        finally:
            learner.close()
    finally:
        trainer.close()
