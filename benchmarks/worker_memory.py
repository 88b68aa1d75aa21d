"""Memory of the batched engine's worker processes (Linux: reads /proc/PID/smaps_rollup).

    python benchmarks/worker_memory.py [--workers 8] [--worlds 16] [--scenario paper_cbs_switch] [--worker-kernels]

Starts :class:`swarm_env.vector.engine.SwarmVectorEnv` with ``--workers`` worker processes, steps it
20 times, and prints each worker's resident (RSS), proportional (PSS: shared pages split between
the processes sharing them) and private memory, and their totals. Also says whether any worker
mapped torch or numba's LLVM (it must not, unless ``--worker-kernels`` asks for the compiled kernels).
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from swarm_env.vector.engine import SwarmVectorEnv

FIELDS = ("Rss", "Pss", "Private_Clean", "Private_Dirty")


def smaps(pid: int) -> dict[str, float]:
    """MiB per field of /proc/PID/smaps_rollup."""
    out = {}
    with open(f"/proc/{pid}/smaps_rollup") as f:
        for line in f:
            key = line.split(":")[0]
            if key in FIELDS:
                out[key] = int(line.split()[1]) / 1024
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--workers", type=int, default=8)
    p.add_argument("--worlds", type=int, default=16)
    p.add_argument("--scenario", default="paper_cbs_switch")
    p.add_argument("--worker-kernels", action="store_true",
                   help="workers run the compiled kernels (SwarmVectorEnv(worker_kernels=True): numba loaded)")
    args = p.parse_args()
    if not sys.platform.startswith("linux"):
        raise SystemExit("worker_memory.py reads /proc: Linux only")
    venv = SwarmVectorEnv(args.scenario, args.worlds, n_procs=args.workers, worker_kernels=args.worker_kernels)
    try:
        venv.reset(seed=0)
        for _ in range(20):
            venv.step(np.zeros((args.worlds, venv.num_agents, 2)))
        totals = dict.fromkeys(FIELDS, 0.0)
        heavy = []
        print(f"{'pid':>8} " + " ".join(f"{k:>14}" for k in FIELDS))
        for remote in venv._remotes:
            pid = remote.proc.pid
            row = smaps(pid)
            for k in FIELDS:
                totals[k] += row[k]
            print(f"{pid:>8} " + " ".join(f"{row[k]:>11.1f} MiB" for k in FIELDS))
            with open(f"/proc/{pid}/maps") as f:
                maps = f.read()
            heavy += [name for name in ("libtorch", "llvmlite") if name in maps]
        print(f"{'total':>8} " + " ".join(f"{totals[k]:>11.1f} MiB" for k in FIELDS))
        print(f"{args.workers} workers, {args.worlds} worlds of {args.scenario}: RSS {totals['Rss'] / 1024:.2f} GiB, "
              f"PSS {totals['Pss'] / 1024:.2f} GiB; torch/numba loaded in a worker: {sorted(set(heavy)) or 'no'}")
    finally:
        venv.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
