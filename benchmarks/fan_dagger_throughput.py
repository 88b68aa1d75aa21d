"""fan_dagger's rollout speed against the raw batched engine at the same number of worlds, and its fit speed.

In one process, interleaved: a student-driven DAgger round of ``--steps`` engine steps
(:func:`swarm_env_baselines.fan_dagger.collect`: the engine, the fan of every follower, the student's forward,
the teacher's label) and ``--steps`` steps of a bare :class:`~swarm_env.vector.engine.SwarmVectorEnv` of the same
worlds with uniform random actions; after one warm-up each, medians over ``--repeats`` of agent-steps/s by wall and
by CPU time (``time.process_time``) and of the paired ratio. Then one epoch of the fit over the collected labels
(samples/s): the part that dominates a run's wall time (docs/baselines.md, "How the methods were trained").

.. code-block:: console

    OPENBLAS_NUM_THREADS=1 python benchmarks/fan_dagger_throughput.py --worlds 32 --steps 100 --repeats 5
    python benchmarks/fan_dagger_throughput.py --candidate-hidden 32 32 --torch-threads 2   # the first trial's network
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy: multithreaded BLAS is slower under load

import argparse
import statistics
import time
from typing import Any

import numpy as np

from swarm_env.vector.engine import EnvFactory, SwarmVectorEnv
from swarm_env_baselines.fan_dagger import FanDaggerConfig, Learner, collect
from swarm_env_baselines.worlds import TrainingWorlds


class _NoBar:
    def update(self, n: int) -> None:
        pass


def _timed(fn: Any) -> tuple[float, float]:
    w, c = time.perf_counter(), time.process_time()
    fn()
    return time.perf_counter() - w, time.process_time() - c


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--worlds", type=int, default=FanDaggerConfig.n_worlds)
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--candidate-hidden", type=int, nargs="+", default=list(FanDaggerConfig.candidate_hidden))
    parser.add_argument("--torch-threads", type=int, default=FanDaggerConfig.torch_threads)
    args = parser.parse_args()
    cfg = FanDaggerConfig(n_worlds=args.worlds, round_steps=args.steps, eval_workers=0, progress=False,
                          candidate_hidden=tuple(args.candidate_hidden), torch_threads=args.torch_threads)
    learner = Learner(cfg)
    factory = EnvFactory(cfg.scenario, dict(cfg.env_kwargs))
    worlds = TrainingWorlds(factory, cfg.n_worlds)
    engine = SwarmVectorEnv.from_factories([factory] * cfg.n_worlds, prefetch_scenarios=True)
    rng = np.random.default_rng(0)
    per_round = args.steps * cfg.n_worlds * worlds.n
    labels: list[tuple[np.ndarray, np.ndarray]] = []

    def round_(r: int) -> None:
        labels.append(collect(learner, worlds, cfg, r, _NoBar())[:2])

    def raw() -> None:
        engine.reset(seed=cfg.first_seed)
        for _ in range(args.steps):
            engine.step(rng.uniform(-1.0, 1.0, (cfg.n_worlds, worlds.n, 2)))

    round_(0)  # the teacher's round: sets the observation statistics, as in a run
    learner.add(*labels[-1])
    raw()
    rows = []
    for k in range(args.repeats):
        pair = [("trainer", lambda k=k: round_(k + 1)), ("engine", raw)]
        times = dict((name, _timed(fn)) for name, fn in (pair if k % 2 == 0 else pair[::-1]))
        rows.append(times)
    med = {name: (statistics.median(per_round / r[name][0] for r in rows),
                  statistics.median(per_round / r[name][1] for r in rows)) for name in ("trainer", "engine")}
    ratio = statistics.median(r["engine"][0] / r["trainer"][0] for r in rows)
    print(f"{cfg.n_worlds} worlds x {worlds.n} followers, {args.steps} steps per repeat, {args.repeats} repeats")
    for name in ("trainer", "engine"):
        print(f"  {name:8s} {med[name][0]:9,.0f} agent-steps/s wall  {med[name][1]:9,.0f} per CPU s")
    print(f"  trainer / engine (wall, paired median): {ratio:.2f}")
    for obs, picks in labels[1:]:
        learner.add(obs, picks)
    n = learner.labels
    saved = learner.cfg
    learner.cfg = FanDaggerConfig(**{**saved.__dict__, "epochs": 1})
    wall, cpu = _timed(learner.fit)
    learner.cfg = saved
    print(f"  fit: one epoch over {n:,} labels in {wall:.1f} s ({n / wall:,.0f} samples/s wall, {n / cpu:,.0f} per CPU s)")
    worlds.close()
    engine.close()


if __name__ == "__main__":
    main()
