"""MAPPO training throughput: rollout agent-steps/s and the wall and CPU time of whole updates.

Times :class:`swarm_env_baselines.mappo.Trainer` (rollouts through the batched engine) on a config
(default: :class:`~swarm_env_baselines.mappo.MAPPOConfig`'s defaults without the warm start and
validation), optionally against a peer trainer module given by path, e.g. the one that stepped a list
of SwarmEnvs::

    git show 2fb36b4:baselines/mappo.py > /tmp/mappo_before.py
    python benchmarks/mappo_rollouts.py --peer /tmp/mappo_before.py --updates 6 --repeats 3
    python benchmarks/mappo_rollouts.py --vs-config '{"env_procs": 2}'     # the physics in 2 workers

Both trainers are built with the same seed, so they do the same work (the same worlds, actions and
networks, bit for bit); their updates are interleaved (alternating which goes first), and the
report gives medians over all updates of all repeats plus the median of the per-update paired
ratios (peer / this). ``time.process_time`` is reported beside wall time: on a loaded machine the
CPU time is the steadier figure.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import sys
import tempfile
import time
from pathlib import Path
from statistics import median
from typing import Any

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def _load_peer(path: str) -> Any:
    spec = importlib.util.spec_from_file_location("mappo_peer", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["mappo_peer"] = module
    spec.loader.exec_module(module)
    return module


def _one_update(trainer: Any, optim: Any, u: int, n_updates: int) -> dict[str, float]:
    w0, c0 = time.perf_counter(), time.process_time()
    batch = trainer.collect()
    w1, c1 = time.perf_counter(), time.process_time()
    trainer.update(batch, optim, u, n_updates)
    w2, c2 = time.perf_counter(), time.process_time()
    steps = batch.actions.shape[0] * batch.actions.shape[1]
    return {"rollout_wall": w1 - w0, "rollout_cpu": c1 - c0, "update_wall": w2 - w0, "update_cpu": c2 - c0,
            "agent_steps": steps}


def run(entries: dict[str, tuple[Any, dict[str, Any]]], updates: int, repeats: int) -> dict[str, Any]:
    """``updates`` interleaved PPO updates of each trainer (name -> (mappo module, config fields)),
    ``repeats`` times with fresh trainers."""
    import torch

    rows: dict[str, list[dict[str, float]]] = {name: [] for name in entries}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(repeats):
            trainers, optims = {}, {}
            for name, (mod, cfg_kwargs) in entries.items():
                cfg = mod.MAPPOConfig(**cfg_kwargs, runs_dir=tmp, run_name=f"{name}{r}")
                trainer = mod.Trainer(cfg, Path(tmp) / f"{name}{r}")
                trainer.start()
                params = [*trainer.actor.parameters(), trainer.log_std, *trainer.critic.parameters()]
                trainers[name], optims[name] = trainer, torch.optim.Adam(params, lr=cfg.learning_rate, eps=1e-5)
            names = list(entries)
            for u in range(updates):
                for name in (names if (u + r) % 2 == 0 else names[::-1]):
                    # Sampling and minibatches use each trainer's own generator: the order changes no number.
                    rows[name].append(_one_update(trainers[name], optims[name], u, updates))
            for t in trainers.values():
                t.close()
    out: dict[str, Any] = {}
    for name, rs in rows.items():
        out[name] = {k: median(x[k] for x in rs) for k in rs[0]}
        out[name]["agent_steps_per_s"] = median(x["agent_steps"] / x["rollout_wall"] for x in rs)
    if len(rows) == 2:
        a, b = names
        out["paired_ratio_" + f"{b}_over_{a}"] = {
            k: median(y[k] / x[k] for x, y in zip(rows[a], rows[b]))
            for k in ("rollout_wall", "rollout_cpu", "update_wall", "update_cpu")}
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--peer", help="path of another mappo.py whose Trainer to time beside this one")
    parser.add_argument("--updates", type=int, default=6)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--config", default="{}", help="MAPPOConfig fields as JSON (on top of the defaults)")
    parser.add_argument("--vs-config", help="instead of --peer: this trainer with these fields changed (JSON), "
                                            "e.g. '{\"env_procs\": 2}'")
    args = parser.parse_args(argv)
    from swarm_env.jsonio import dumps  # (imports numpy: after the BLAS setting above)
    from swarm_env_baselines import mappo

    cfg_kwargs = {"pretrain": "none", "eval_every": 0, "progress": False, **json.loads(args.config)}
    entries = {"engine": (mappo, cfg_kwargs)}
    if args.peer:
        entries = {"peer": (_load_peer(args.peer), cfg_kwargs), **entries}
    elif args.vs_config:
        entries["engine_vs"] = (mappo, {**cfg_kwargs, **json.loads(args.vs_config)})
    result = run(entries, args.updates, args.repeats)
    print(dumps({"config": cfg_kwargs, "updates": args.updates, "repeats": args.repeats, **result}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
