"""MAPPO's training on the batched engine (swarm_env_baselines.mappo.Trainer over swarm_env.vector.engine.SwarmVectorEnv)
is bit for bit its reference runs, whatever the number of worker processes for the worlds' physics.

``tests/data/mappo_reference.json`` holds reference runs of the vectorised trainer (re-baselined deliberately with
issue 31's rollouts over whole ``(worlds, followers)`` arrays: one return-statistics update per step for all
agents, input statistics moved once per rollout, values and log-probabilities of a rollout in one forward, a
critic whose first layer is split between the global state and the observation). Regenerate with ``python
tests/test_mappo_engine.py`` only when the training itself is meant to change. Each case runs a few PPO
updates on worlds short enough that every copy ends (and auto-resets) episodes inside the rollouts, so the
truncation bootstrap, the auto-reset and the reward scaling are all exercised; every update's batch and losses
and the final networks and statistics must come out bit for bit.

torch's CPU kernels give other last bits on other CPUs (``tests/_numerics.py``), so the file also keeps the same
runs recorded on other machines under ``by_numerics`` (``python tests/test_mappo_engine.py --this-machine``
adds this machine's: record it from the same trainer, on a commit whose references pass elsewhere).
"""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("torch")
pytest.importorskip("safetensors")

from _numerics import fingerprint  # noqa: E402

from swarm_env_agents.vo_expert import LEGACY_SPEC  # noqa: E402
from swarm_env_baselines import mappo  # noqa: E402

DATA = Path(__file__).resolve().parent / "data" / "mappo_reference.json"
#: Short episodes (20 steps) in rollouts of 24: every copy ends episodes by the time limit, some by collisions.
ENV = {"n_followers": 2, "n_obstacles": 1, "n_humans": 1, "max_cycles": 20}
BASE = dict(env_kwargs=ENV, total_steps=3 * 3 * 24 * 2, n_copies=3, n_steps=24, n_epochs=2, hidden=(16, 16),
            pretrain="none", eval_every=0, progress=False, seed=3)
CASES: dict[str, dict[str, Any]] = {
    "ippo": {"critic": "local"},
    # A crowded small world ending episodes at the first collision: terminations (not bootstrapped) as well.
    "mappo_collision_ends": {"critic": "central", "env_kwargs": {**ENV, "n_obstacles": 3, "n_humans": 3,
                                                                "world_size": [8.0, 8.0], "terminate_on_collision": True}},
    "shield_execute": {"shield": "execute", "intervention_coef": 1.0},
    "shield_teach": {"shield": "teach", "intervention_coef": 1.0, "imitation_coef": 1.0, "imitation_anneal": 0.5,
                     "teach_w_current": 0.2},
    # (the expert the reference was recorded with: vo before issue 12, LEGACY_SPEC)
    "residual_vo": {"residual": LEGACY_SPEC, "shield": "execute", "critic": "local",
                    "intervention_coef": 0.5},
}


def _digest(*arrays: Any) -> str:
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(str((a.dtype, a.shape)).encode())
        h.update(a.tobytes())
    return h.hexdigest()[:24]


def run_case(name: str, tmp_path: Path, env_procs: int = 1) -> dict[str, Any]:
    """The trainer's loop (``_train_loop`` without files): every update's batch digest and losses, then
    digests of the networks, the optimizer's moments and the statistics."""
    import torch

    extra = {"env_procs": env_procs} if env_procs > 1 else {}  # (the recording trainer had no such option)
    cfg = mappo.MAPPOConfig(**{**BASE, **CASES[name], **extra, "runs_dir": str(tmp_path), "run_name": name})
    trainer = mappo.Trainer(cfg, tmp_path / name)
    params = trainer.parameters()
    optim = torch.optim.Adam(params, lr=cfg.learning_rate, eps=1e-5)
    batch_size = cfg.n_steps * trainer.m * trainer.n
    n_updates = cfg.total_steps // batch_size
    rows = []
    try:
        trainer.start()
        for u in range(n_updates):
            batch = trainer.collect()
            row = {"batch": _digest(batch.obs, batch.states, batch.actions, batch.logp, batch.values, batch.rewards,
                                    batch.dones, batch.safe, batch.intervened),
                   "contacts": int(batch.contacts), "dones": int(batch.dones.sum()),
                   "intervened": int(batch.intervened.sum())}
            stats = trainer.update(batch, optim, u, n_updates)
            row.update({k: float(v).hex() for k, v in sorted(stats.items())})
            row["episodes"] = len(batch.episode_metrics)
            rows.append(row)
        nets = [p.detach().numpy() for p in params]
        moments = [s[k].numpy() for s in optim.state.values() for k in ("exp_avg", "exp_avg_sq")]
        stats_json = json.dumps({n: getattr(trainer, n).to_json() for n in ("obs_rms", "state_rms", "ret_rms")},
                                sort_keys=True)
        final = {"networks": _digest(*nets), "adam": _digest(*moments),
                 "statistics": hashlib.sha256(stats_json.encode()).hexdigest()[:24],
                 "inputs": _digest(trainer.inputs, trainer.states, trainer.returns)}
    finally:
        trainer.close()
    return {"updates": rows, "final": final}


def _reference() -> dict[str, Any]:
    """The reference runs recorded on a machine with this one's numerics, else the first recording."""
    data = json.loads(DATA.read_text())
    return data.get("by_numerics", {}).get(fingerprint(), data)


@pytest.mark.parametrize("name, env_procs", [(name, 1) for name in CASES] + [("shield_teach", 2),
                                                                           ("mappo_collision_ends", 3)])
@pytest.mark.slow
def test_training_is_bit_for_bit_the_reference_trainers(name: str, env_procs: int, tmp_path: Path) -> None:
    """In the training process and with the worlds' physics in worker processes (env_procs)."""
    expected = _reference()[name]
    got = run_case(name, tmp_path, env_procs)
    assert all(r["dones"] for r in got["updates"])  # episodes ended (and auto-reset) inside every rollout
    if name == "mappo_collision_ends":  # more than the time limit's one episode end per copy and rollout
        assert sum(r["dones"] for r in got["updates"]) > 3 * 3 * ENV["n_followers"]
    for u, (a, b) in enumerate(zip(got["updates"], expected["updates"], strict=True)):
        assert a == b, f"update {u}"
    assert got["final"] == expected["final"]


@pytest.mark.filterwarnings("error:.*rebuilt env copies differ")
@pytest.mark.slow
def test_a_run_resumed_with_its_worlds_in_worker_processes_ends_as_an_uninterrupted_one(tmp_path: Path,
                                                                                        monkeypatch) -> None:
    """The checkpoint's worlds are rebuilt by replay and handed to the engine's workers (set_world): the resumed
    run (env_procs 2) ends with the networks and checkpoint of the uninterrupted one (env_procs 1), bit for bit."""
    from safetensors.numpy import load_file

    cfg = {**BASE, **CASES["shield_execute"], "total_steps": 5 * 3 * 24 * 2, "checkpoint_every": 1,
           "runs_dir": str(tmp_path), "learner_process": False}  # (the update here: Trainer.update is patched)
    whole = mappo.train(mappo.MAPPOConfig(**cfg, run_name="whole"))
    original = mappo.Trainer.update

    def update(self, batch, optim, u, n_updates):
        stats = original(self, batch, optim, u, n_updates)
        if u == 2:  # back to the checkpoint after 48 steps: every world 8 steps into its third episode
            raise RuntimeError("simulated crash")
        return stats

    with monkeypatch.context() as m:
        m.setattr(mappo.Trainer, "update", update)
        with pytest.raises(RuntimeError, match="simulated crash"):
            mappo.train(mappo.MAPPOConfig(**cfg, run_name="parts"))
    parts = tmp_path / "parts"
    starts = json.loads((parts / "checkpoint" / "state.json").read_text())["episode_starts"]
    assert all(s["seed"] is None and s["rng"] for s in starts)  # generator states of auto-resets
    mappo.resume(parts, env_procs=2)
    for name in ("policy.safetensors", "checkpoint/state.safetensors"):
        a, b = load_file(str(whole / name)), load_file(str(parts / name))
        assert a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a), name


def test_env_procs_is_checked() -> None:
    with pytest.raises(ValueError, match="at most n_copies"):
        mappo.MAPPOConfig(n_copies=2, env_procs=3)
    with pytest.raises(ValueError, match="--env-procs 1"):
        mappo.MAPPOConfig(residual="vo", pretrain="none", env_procs=2)
    with pytest.raises(ValueError, match="env_procs must be a positive int"):
        mappo.MAPPOConfig(env_procs=0)


if __name__ == "__main__":  # regenerate the reference (only when the training is meant to change)
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        runs = {name: run_case(name, Path(tmp)) for name in CASES}
    if "--this-machine" in sys.argv:  # add this machine's runs beside the others
        data = json.loads(DATA.read_text())
        data.setdefault("by_numerics", {})[fingerprint()] = runs
    else:
        data = runs
    DATA.parent.mkdir(exist_ok=True)
    DATA.write_text(json.dumps(data, indent=1, sort_keys=True) + "\n")
    print(f"wrote {DATA}", file=sys.stderr)
