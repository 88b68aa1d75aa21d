"""Would a learner *process* reach trainer / engine 0.5? The ceiling of MAPPO's rollout with the update elsewhere.

An asynchronous learner (the update of rollout ``k`` in a second process while rollout ``k + 1`` is collected) can
make the trainer at most as fast as its rollout alone, and the rollout then shares the machine with a busy learner.
This times exactly that ceiling, in one run, interleaved repeat by repeat (``random``, 64 worlds, the trainer's
defaults, no warm start):

* ``rollout alone``: ``Trainer.collect()`` with nothing else running;
* ``rollout + busy learner``: the same while a second process runs the PPO update of a trainer of the same
  configuration (one torch thread) in a loop, as a learner process would;
* ``trainer``: one iteration as the trainer runs it today (rollout, then the update on two threads);
* ``engine``: the raw engine of the same worlds, random actions (the denominator of the issue's target).

::

    OPENBLAS_NUM_THREADS=1 python benchmarks/learner_process_probe.py --repeats 8

The rollout here still holds the critic's forward over the whole rollout (a learner process would take it over),
so "rollout + busy learner" is the ceiling to within that part (6 % of an iteration, docs/performance.md).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy: multithreaded BLAS is slower under load

import argparse
import multiprocessing as mp
import sys
import tempfile
import time
from pathlib import Path
from statistics import median
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))


def _busy_learner(run: Any, stop: Any, ready: Any) -> None:
    """Update a trainer's networks on one of its rollouts, again and again, while ``run`` is set."""
    import torch

    from swarm_env_baselines import mappo

    tmp = tempfile.mkdtemp()
    cfg = mappo.MAPPOConfig(pretrain="none", eval_every=0, progress=False, runs_dir=tmp, run_name="learner",
                            torch_threads=1, prefetch_worlds=False)
    trainer = mappo.Trainer(cfg, Path(tmp) / "learner")
    trainer.start()
    batch = trainer.collect()
    optim = torch.optim.Adam(trainer.parameters(), lr=cfg.learning_rate, eps=1e-5)
    ready.set()
    while not stop.is_set():
        if run.wait(0.05):
            trainer.update(batch, optim, 1, 10**6)
    trainer.close()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=8, help="repeats of each kind (one 128-step rollout each)")
    args = parser.parse_args(argv)

    from train_throughput import _EngineRun, _TrainerRun

    from swarm_env_baselines import mappo

    ctx = mp.get_context("spawn")
    run, stop, ready = ctx.Event(), ctx.Event(), ctx.Event()
    learner = ctx.Process(target=_busy_learner, args=(run, stop, ready), daemon=True)
    learner.start()
    ready.wait()
    tmp = tempfile.mkdtemp()
    trainer = _TrainerRun(mappo, {"n_copies": 64}, tmp, "collector")
    engine = _EngineRun("random", 64, {}, 128, True)
    rates: dict[str, list[float]] = {"rollout alone": [], "rollout + busy learner": [], "trainer": [], "engine": []}
    cpu: dict[str, list[float]] = {k: [] for k in rates}
    for r in range(args.repeats):
        for kind in rates:
            (run.set if kind == "rollout + busy learner" else run.clear)()
            time.sleep(0.2)  # the learner finishes or starts its update
            w, c = time.perf_counter(), time.process_time()
            if kind == "engine":
                engine.iteration()
                steps = engine.agent_steps
            elif kind == "trainer":
                trainer.iteration()
                steps = trainer.agent_steps
            else:
                trainer.trainer.collect()
                steps = trainer.agent_steps
            rates[kind].append(steps / (time.perf_counter() - w))
            cpu[kind].append(steps / (time.process_time() - c))
        print(f"repeat {r}: " + ", ".join(f"{k} {v[-1]:,.0f}" for k, v in rates.items()), flush=True)
    stop.set()
    run.clear()
    learner.join(timeout=30)
    ref = median(rates["engine"])
    print("medians, agent-steps/s (CPU time) and / engine:")
    for kind in rates:
        print(f"  {kind:24s} {median(rates[kind]):9,.0f} ({median(cpu[kind]):9,.0f})  {median(rates[kind]) / ref:.2f}")
    trainer.close()
    engine.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
