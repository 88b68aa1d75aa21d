"""Would a learner thread pay? MAPPO's update of rollout ``k`` on a second thread while rollout ``k + 1`` is collected.

Two trainers of the same defaults (``random``, 64 worlds, no warm start): one runs the loop as it is (collect,
then update on ``torch_threads`` threads); the other collects while a thread updates *copies* of its networks on
the previous rollout (the learned parameters are not fed back: this times the overlap, it does not train).
Blocks of ``--block`` iterations alternate between the two, each overlapped block ending drained (its last
update counted); the report gives medians of agent-steps/s by wall and CPU time and the median paired ratio::

    OPENBLAS_NUM_THREADS=1 python benchmarks/overlap_probe.py --repeats 6
    OPENBLAS_NUM_THREADS=1 python benchmarks/overlap_probe.py --switch-interval 0.0005   # hand the GIL over faster

The rollout is Python and numba (whose kernels release the GIL), the update torch; both need the GIL
between their operations, which is what the ratio measures.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy: multithreaded BLAS is slower under load

import argparse
import copy
import sys
import tempfile
import threading
import time
from pathlib import Path
from statistics import median
from typing import Any


def _trainer(tmp: str, name: str) -> tuple[Any, Any, Any]:
    import torch

    from swarm_env_baselines import mappo

    cfg = mappo.MAPPOConfig(pretrain="none", eval_every=0, progress=False, runs_dir=tmp, run_name=name)
    trainer = mappo.Trainer(cfg, Path(tmp) / name)
    trainer.start()
    return trainer, torch.optim.Adam(trainer.parameters(), lr=cfg.learning_rate, eps=1e-5), cfg


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=6, help="blocks of each kind")
    parser.add_argument("--block", type=int, default=4, help="iterations (rollout + update) per block")
    parser.add_argument("--switch-interval", type=float, default=sys.getswitchinterval(),
                        help="sys.setswitchinterval: how often Python hands the GIL to another thread (s)")
    args = parser.parse_args(argv)

    import torch

    from swarm_env_baselines import mappo

    sys.setswitchinterval(args.switch_interval)
    tmp = tempfile.mkdtemp()
    seq, seq_optim, cfg = _trainer(tmp, "sequential")
    ovl, _, _ = _trainer(tmp, "overlapped")
    learner = copy.copy(ovl)  # the learner's own networks, optimiser and generator
    learner.actor, learner.critic = copy.deepcopy(ovl.actor), copy.deepcopy(ovl.critic)
    learner.log_std = torch.nn.Parameter(ovl.log_std.detach().clone())
    learner.gen = torch.Generator().manual_seed(cfg.seed + 1)
    learner_optim = torch.optim.Adam(learner.parameters(), lr=cfg.learning_rate, eps=1e-5)

    def learn(batch: Any, u: int) -> None:  # the update as the trainer runs it, on the learner's copies
        mappo.ppo_update(learner.networks(), learner_optim, learner.gen, cfg, batch,
                         learner.value(*learner.normalised()), u, 10**6)

    seq.update(seq.collect(), seq_optim, 0, 10**6)  # warm-up of both
    learn(ovl.collect(), 0)

    pending: threading.Thread | None = None
    results: dict[str, list[tuple[float, float]]] = {"sequential": [], "overlapped": []}
    steps = cfg.n_steps * seq.m * seq.n * args.block
    u = 1
    for r in range(args.repeats):
        for name in (("sequential", "overlapped") if r % 2 == 0 else ("overlapped", "sequential")):
            w, c = time.perf_counter(), time.process_time()
            for _ in range(args.block):
                if name == "sequential":
                    seq.update(seq.collect(), seq_optim, u, 10**6)
                else:
                    batch = ovl.collect()
                    if pending is not None:
                        pending.join()
                    pending = threading.Thread(target=learn, args=(batch, u))
                    pending.start()
                u += 1
            if pending is not None:
                pending.join()
                pending = None
            results[name].append((steps / (time.perf_counter() - w), steps / (time.process_time() - c)))
    for name, rows in results.items():
        print(f"{name:11s} {median(x[0] for x in rows):9,.0f} agent-steps/s (CPU {median(x[1] for x in rows):9,.0f})")
    ratio = median(a[0] / b[0] for a, b in zip(results["overlapped"], results["sequential"]))
    print(f"overlapped / sequential {ratio:.2f} (switch interval {args.switch_interval:g} s)")
    seq.close()
    ovl.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
