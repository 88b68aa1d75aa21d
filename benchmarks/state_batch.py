"""The batched engine's global state, ``SwarmVectorEnv.state()``: one compiled call against the stack of
each world's ``SwarmEnv.state()``.

    OPENBLAS_NUM_THREADS=1 python benchmarks/state_batch.py [--worlds 8 64 256] [--calls 20] [--repeats 7]

For each ``M``, steps ``SwarmVectorEnv("random", M, **swarm_env.harness.bench.BATCH_WORLD)`` a few times
(the batched rows live, the kernels compiled), checks that both give the same bits, then times, per
repeat, ``--calls`` calls of ``old`` (``np.stack([e.state() for e in envs])``, the per-world numpy
reference and what the engine did before) and ``new`` (``venv.state()``: ``BatchState.state``, one
call of :func:`swarm_env.sensing.state_kernel.state_batch`), alternating the two within a repeat so that a
noisy shared machine slows both alike. Prints the medians over repeats of one call's wall time
(``time.perf_counter``) and CPU time (``time.process_time``), in microseconds, and old / new.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy: one thread, as the engine runs

import numpy as np  # noqa: E402

from swarm_env.harness.bench import BATCH_WORLD  # noqa: E402
from swarm_env.vector.engine import SwarmVectorEnv  # noqa: E402


def measure(worlds: int, calls: int, repeats: int) -> dict[str, float]:
    """Median microseconds per call of the old and the new ``state()`` at ``worlds`` worlds:
    ``{"old_wall", "new_wall", "old_cpu", "new_cpu"}``."""
    venv = SwarmVectorEnv("random", worlds, **BATCH_WORLD)
    venv.reset(seed=0)
    actions = np.random.default_rng(0).uniform(-1.0, 1.0, (3, worlds, venv.num_agents, 2))
    for a in actions:
        venv.step(a)
    block = venv._local
    assert block is not None and block._rows_live  # the batched path is the one timed
    envs = block.envs

    def old() -> np.ndarray:
        return np.stack([e.state() for e in envs])

    if not np.array_equal(venv.state(), old()):
        raise AssertionError("the batched state differs from the worlds' own")
    runs: dict[str, list[float]] = {k: [] for k in ("old_wall", "new_wall", "old_cpu", "new_cpu")}
    for _ in range(repeats):
        for name, fn in (("old", old), ("new", venv.state)):
            w0, c0 = time.perf_counter(), time.process_time()
            for _ in range(calls):
                fn()
            runs[f"{name}_wall"].append((time.perf_counter() - w0) / calls)
            runs[f"{name}_cpu"].append((time.process_time() - c0) / calls)
    venv.close()
    return {k: 1e6 * statistics.median(v) for k, v in runs.items()}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--worlds", type=int, nargs="+", default=[8, 64, 256])
    p.add_argument("--calls", type=int, default=20)
    p.add_argument("--repeats", type=int, default=7)
    args = p.parse_args()
    print(f"{'worlds':>7}{'old wall us':>13}{'new wall us':>13}{'ratio':>7}{'old cpu us':>12}{'new cpu us':>12}"
          f"{'ratio':>7}")
    for m in args.worlds:
        r = measure(m, args.calls, args.repeats)
        print(f"{m:>7}{r['old_wall']:>13.0f}{r['new_wall']:>13.0f}{r['old_wall'] / r['new_wall']:>7.1f}"
              f"{r['old_cpu']:>12.0f}{r['new_cpu']:>12.0f}{r['old_cpu'] / r['new_cpu']:>7.1f}")
    print(f"(random at BATCH_WORLD, {BATCH_WORLD['n_followers']} followers; medians of {args.repeats} repeats "
          f"of {args.calls} calls)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
