"""MAPPO/IPPO training throughput against the raw batched engine, in one process, interleaved.

For each number of worlds ``M`` it builds the trainer (:class:`swarm_env_baselines.mappo.Trainer`, the
config's defaults without the warm start and validation unless ``--config`` says otherwise), optionally a
peer trainer from another ``mappo.py`` (``--peer``, e.g. the trainer before a change), and a bare
:class:`swarm_env.vector.engine.SwarmVectorEnv` of the same worlds driven with uniform random actions. Each
repeat runs one PPO iteration (rollout of ``n_steps`` steps of every world, then the update) of each
trainer and ``n_steps`` engine steps, in an order that alternates between repeats; after one warm-up
iteration each, the report gives medians over the repeats of agent-steps/s by wall time and by CPU time
(``time.process_time``), the rollout/update split, and the ratios trainer / engine and trainer / peer
(medians of the per-repeat paired ratios). The medians are the steady state: all worlds of ``random`` end
their 600-step episodes together, and the iteration that holds that reset wave is an outlier the median drops.
The totals (all repeats' agent-steps over their summed wall time, ``with resets``) count it: the default 5
repeats of 128 steps span one episode, so they hold one wave, about the real rate. The engine draws its next
random worlds in a worker process as the trainer's worlds do (``--engine-no-prefetch``: by itself)::

    OPENBLAS_NUM_THREADS=1 python benchmarks/train_throughput.py --worlds 8 64 --repeats 5
    python benchmarks/train_throughput.py --worlds 8 64 --peer-commit 8ecad84 --peer-config '{"n_copies": 8}' \
        --peer-per-world-state      # against the trainer before issue 31, with its default 8 worlds
    python benchmarks/train_throughput.py --worlds 64 --sweep '{"n_epochs": [1, 2, 4], "n_minibatches": [1, 4]}'

``--breakdown K`` times the parts of ``K`` iterations instead (µs per agent-step: the engine's step and
``state()``, the forwards, the statistics, the rest of the rollout, the update). ``--sweep`` times one
trainer per combination of the given fields (each against the same engine) and
prints a table; ``--json`` writes the whole report.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy: multithreaded BLAS is slower under load

import argparse
import importlib.util
import itertools
import json
import sys
import tempfile
import time
from pathlib import Path
from statistics import median
from typing import Any


def _peer_from_commit(commit: str, tmp: str) -> Any:
    """The ``mappo`` module of ``commit`` with that commit's ``ppo_core`` (so a trainer from before an API change
    of the shared pieces loads as it was); both read with ``git show`` into ``tmp``."""
    import subprocess

    root = Path(__file__).resolve().parent.parent
    sources = {}
    for name in ("mappo", "ppo_core"):
        sources[name] = subprocess.run(["git", "show", f"{commit}:baselines/{name}.py"], cwd=root, check=True,
                                       capture_output=True, text=True).stdout
    core = Path(tmp) / "mappo_peer_core.py"
    core.write_text(sources["ppo_core"])
    _load_module(str(core), "mappo_peer_core")
    trainer = Path(tmp) / "mappo_peer.py"
    trainer.write_text(sources["mappo"].replace("from swarm_env_baselines.ppo_core import", "from mappo_peer_core import"))
    return _load_module(str(trainer), "mappo_peer")


def _load_module(path: str, name: str) -> Any:
    spec = importlib.util.spec_from_file_location(name, path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


class _TrainerRun:
    """One trainer of a module, timed an iteration (collect + update) at a time."""

    def __init__(self, module: Any, cfg_fields: dict[str, Any], tmp: str, label: str,
                 per_world_state: bool = False) -> None:
        import numpy as np
        import torch

        cfg = module.MAPPOConfig(**{"pretrain": "none", "eval_every": 0, "progress": False, **cfg_fields},
                                 runs_dir=tmp, run_name=label)
        self.trainer = module.Trainer(cfg, Path(tmp) / label)
        t = self.trainer
        if per_world_state:  # the critic's state as the engine gave it before its compiled call: world by world
            envs = t.venv._local.envs
            t.venv.state = lambda: np.stack([e.state() for e in envs])
        self.trainer.start()
        params = [*t.actor.parameters(), t.log_std, *t.critic.parameters()]
        self.optim = torch.optim.Adam(params, lr=cfg.learning_rate, eps=1e-5)
        self.agent_steps = cfg.n_steps * t.m * t.n
        self.u = 0
        self.learner: Any = None
        if getattr(cfg, "learner_process", False):  # as the training loop runs it: one rollout ahead of the update
            from swarm_env_baselines.mappo_learner import ProcessLearner

            self.learner = ProcessLearner(cfg, t.networks(), self.optim, torch.Generator().manual_seed(1).get_state())
            self.pending = t.collect(values=False)

    def iteration(self) -> dict[str, float]:
        if self.learner is not None:
            return self._pipelined_iteration()
        w0, c0 = time.perf_counter(), time.process_time()
        batch = self.trainer.collect()
        w1, c1 = time.perf_counter(), time.process_time()
        self.trainer.update(batch, self.optim, self.u, 10**6)
        w2, c2 = time.perf_counter(), time.process_time()
        self.u += 1
        return {"wall": w2 - w0, "cpu": c2 - c0, "rollout_wall": w1 - w0, "update_wall": w2 - w1,
                "rollout_cpu": c1 - c0, "update_cpu": c2 - c1}

    def _pipelined_iteration(self) -> dict[str, float]:
        """Hand the rollout collected before to the learner process, collect the next meanwhile, take the update.
        CPU time counts the learner process's as well; ``update_wall`` is the wait for it."""
        t = self.trainer
        w0, c0, l0 = time.perf_counter(), time.process_time(), self.learner.cpu_s
        batch = self.pending
        self.learner.submit(batch, t.normalised(), self.u, 10**6)
        self.pending = t.collect(values=False)
        w1, c1 = time.perf_counter(), time.process_time()
        self.learner.result(batch)
        w2, c2 = time.perf_counter(), time.process_time()
        self.u += 1
        learner_cpu = self.learner.cpu_s - l0
        return {"wall": w2 - w0, "cpu": c2 - c0 + learner_cpu, "rollout_wall": w1 - w0, "update_wall": w2 - w1,
                "rollout_cpu": c1 - c0, "update_cpu": c2 - c1 + learner_cpu}

    def close(self) -> None:
        if self.learner is not None:
            self.learner.close()
        self.trainer.close()


class _EngineRun:
    """The bare engine of the same worlds, ``steps`` steps of uniform random actions at a time."""

    def __init__(self, scenario: str, worlds: int, env_kwargs: dict[str, Any], steps: int, prefetch: bool) -> None:
        import numpy as np

        from swarm_env.vector.engine import SwarmVectorEnv

        self.venv = SwarmVectorEnv(scenario, num_envs=worlds, prefetch_scenarios=prefetch, **env_kwargs)
        self.venv.reset(seed=0)
        self.rng = np.random.default_rng(0)
        self.steps = steps
        self.agent_steps = steps * worlds * self.venv.num_agents
        self.shape = (worlds, self.venv.num_agents, 2)

    def iteration(self) -> dict[str, float]:
        actions = self.rng.uniform(-1.0, 1.0, (self.steps, *self.shape))
        w0, c0 = time.perf_counter(), time.process_time()
        for a in actions:
            self.venv.step(a)
        return {"wall": time.perf_counter() - w0, "cpu": time.process_time() - c0}

    def close(self) -> None:
        self.venv.close()


def breakdown(module: Any, fields: dict[str, Any], iterations: int) -> dict[str, float]:
    """Microseconds per agent-step of the parts of a trainer iteration (after a warm-up iteration): within
    the rollout, the engine's ``step`` and ``state()``, the actor and critic forwards, the running statistics
    (updates and normalisation) and the rest (the trainer's own array code); then the whole update."""
    import collections

    acc: dict[str, float] = collections.defaultdict(float)

    def timed(name: str, f: Any) -> Any:
        def g(*a: Any, **k: Any) -> Any:
            t = time.perf_counter()
            try:
                return f(*a, **k)
            finally:
                acc[name] += time.perf_counter() - t
        return g

    with tempfile.TemporaryDirectory() as tmp:
        # The parts of the loop in one process (with a learner process the update would run beside the rollout).
        run = _TrainerRun(module, {**fields, "learner_process": False}, tmp, "breakdown")
        run.iteration()
        t = run.trainer
        targets = [(t.venv, "step", "engine step"), (t.venv, "state", "engine state()"),
                   (t.actor, "forward", "actor forward"), (t.critic, "forward", "critic forward"),
                   (t.obs_rms, "update", "statistics"), (t.state_rms, "update", "statistics"),
                   (t.ret_rms, "update", "statistics"), (t.obs_rms, "normalize", "statistics"),
                   (t.state_rms, "normalize", "statistics")]
        for _ in range(iterations):
            for obj, attr, name in targets:  # instance attributes shadow the methods during the rollout only
                setattr(obj, attr, timed(name, getattr(obj, attr)))
            w = time.perf_counter()
            batch = t.collect()
            acc["rollout"] += time.perf_counter() - w
            for obj, attr, _ in targets:
                delattr(obj, attr)
            w = time.perf_counter()
            t.update(batch, run.optim, run.u, 10**6)
            acc["update"] += time.perf_counter() - w
            run.u += 1
        run.close()
    steps = run.agent_steps * iterations
    parts = ("engine step", "engine state()", "actor forward", "critic forward", "statistics")
    acc["rest of the rollout"] = acc["rollout"] - sum(acc[k] for k in parts)
    return {k: 1e6 * v / steps for k, v in acc.items()}


def measure(runs: dict[str, Any], repeats: int) -> dict[str, dict[str, float]]:
    """Warm up each run once, then ``repeats`` interleaved iterations; medians and paired ratios."""
    for run in runs.values():
        run.iteration()
    rows: dict[str, list[dict[str, float]]] = {name: [] for name in runs}
    names = list(runs)
    for r in range(repeats):
        for name in (names if r % 2 == 0 else names[::-1]):
            row = runs[name].iteration()
            row["steps_per_s"] = runs[name].agent_steps / row["wall"]
            row["steps_per_cpu_s"] = runs[name].agent_steps / row["cpu"]
            rows[name].append(row)
    out = {name: {k: median(x[k] for x in rs) for k in rs[0]} for name, rs in rows.items()}
    for name, rs in rows.items():  # totals: the reset waves counted (medians drop the iteration that holds one)
        out[name]["total_steps_per_s"] = runs[name].agent_steps * len(rs) / sum(x["wall"] for x in rs)
    for name in names:
        if name != "engine":
            out[name]["total_ratio_to_engine"] = out[name]["total_steps_per_s"] / out["engine"]["total_steps_per_s"]
    for name in names:
        if name != "engine":
            out[name]["ratio_to_engine"] = median(a["steps_per_s"] / b["steps_per_s"]
                                                  for a, b in zip(rows[name], rows["engine"]))
            out[name]["cpu_ratio_to_engine"] = median(a["steps_per_cpu_s"] / b["steps_per_cpu_s"]
                                                      for a, b in zip(rows[name], rows["engine"]))
    if "peer" in rows:
        out["trainer"]["ratio_to_peer"] = median(a["steps_per_s"] / b["steps_per_s"]
                                                 for a, b in zip(rows["trainer"], rows["peer"]))
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--worlds", type=int, nargs="+", default=[8, 64])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--config", default="{}", help="MAPPOConfig fields as JSON (n_copies is set by --worlds)")
    parser.add_argument("--peer", help="path of another mappo.py whose Trainer to time beside this one")
    parser.add_argument("--peer-commit", help="instead of --peer: the trainer of this git commit (its mappo.py and "
                                              "ppo_core.py)")
    parser.add_argument("--peer-config", default="{}", help="the peer's MAPPOConfig fields as JSON (on --config), "
                                                            "e.g. its own default number of worlds")
    parser.add_argument("--peer-per-world-state", action="store_true",
                        help="give the peer the engine's state() as it was before issue 31 (one world at a time)")
    parser.add_argument("--sweep", help="JSON {field: [values]}: one trainer per combination, against the engine")
    parser.add_argument("--breakdown", type=int, metavar="ITERATIONS",
                        help="instead: time the parts of this many trainer iterations at each --worlds")
    parser.add_argument("--engine-no-prefetch", action="store_true",
                        help="the raw engine draws its next random worlds itself (default: in a worker process, as "
                             "the trainer's worlds do: SwarmVectorEnv(prefetch_scenarios=True))")
    parser.add_argument("--json", help="write the report here")
    args = parser.parse_args(argv)

    from swarm_env.jsonio import dumps, write_json  # (imports numpy: after the BLAS setting above)
    from swarm_env_baselines import mappo

    base = json.loads(args.config)
    peer_dir = tempfile.TemporaryDirectory()
    peer = (_peer_from_commit(args.peer_commit, peer_dir.name) if args.peer_commit
            else _load_module(args.peer, "mappo_peer") if args.peer else None)
    report: dict[str, Any] = {"config": base, "repeats": args.repeats, "results": []}
    if args.breakdown:
        for m in args.worlds:
            parts = breakdown(mappo, {**base, "n_copies": m}, args.breakdown)
            report["results"].append({"worlds": m, "breakdown_us_per_agent_step": parts})
            print(f"M={m}: " + ", ".join(f"{k} {v:.2f}" for k, v in parts.items()) + " (µs per agent-step)")
        if args.json:
            write_json(args.json, report, indent=1)
        return 0
    for m in args.worlds:
        variants = [{}]
        if args.sweep:
            grid = json.loads(args.sweep)
            variants = [dict(zip(grid, values)) for values in itertools.product(*grid.values())]
        for variant in variants:
            fields = {**base, "n_copies": m, **variant}
            cfg = mappo.MAPPOConfig(**{"pretrain": "none", **fields})
            with tempfile.TemporaryDirectory() as tmp:
                runs: dict[str, Any] = {"trainer": _TrainerRun(mappo, fields, tmp, "trainer")}
                if peer is not None:
                    runs["peer"] = _TrainerRun(peer, {**fields, **json.loads(args.peer_config)}, tmp, "peer",
                                               args.peer_per_world_state)
                env_kwargs = {**cfg.env_kwargs, **cfg.train_env_kwargs}
                runs["engine"] = _EngineRun(cfg.scenario, m, env_kwargs, cfg.n_steps, not args.engine_no_prefetch)
                try:
                    result = measure(runs, args.repeats)
                finally:
                    for run in runs.values():
                        run.close()
            report["results"].append({"worlds": m, "variant": variant, **result})
            t, e = result["trainer"], result["engine"]
            line = (f"M={m:5d} {dumps(variant, indent=None) if variant else '':40s} trainer {t['steps_per_s']:9,.0f} "
                    f"agent-steps/s (rollout {t['rollout_wall']:.2f} s, update {t['update_wall']:.2f} s)  engine "
                    f"{e['steps_per_s']:9,.0f}  trainer/engine {t['ratio_to_engine']:.2f} (CPU "
                    f"{t['cpu_ratio_to_engine']:.2f}); with resets trainer {t['total_steps_per_s']:9,.0f} engine "
                    f"{e['total_steps_per_s']:9,.0f} ({t['total_ratio_to_engine']:.2f})")
            if "peer" in result:
                line += (f"  peer {result['peer']['steps_per_s']:9,.0f}  trainer/peer {t['ratio_to_peer']:.2f} (with "
                         f"resets {t['total_steps_per_s'] / result['peer']['total_steps_per_s']:.2f})")
            print(line, flush=True)
    if args.json:
        write_json(args.json, report, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
