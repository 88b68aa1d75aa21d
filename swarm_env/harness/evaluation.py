"""One evaluation path for every policy (scripted experts, RL models, random).

:func:`~swarm_env.harness.episode.run_episode` plays one seeded episode and returns its metrics;
:func:`evaluate` runs several and aggregates them into the JSON document that
``swarm-env run --json`` writes::

    {"scenario": str, "policy": str, "episodes": [per-episode metrics], "summary": {...}}
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from typing import Any

import numpy as np

from swarm_env.env import SwarmEnv
from swarm_env.harness import recording
from swarm_env.harness.episode import run_episode
from swarm_env.harness.policies import load_policy


def mean_ci95(values: Iterable[float | None]) -> dict[str, float | int | None]:
    """``{"mean", "ci95", "n"}`` of the non-``None`` values; ``ci95`` is the normal-approximation
    half-width ``1.96 * s / sqrt(n)`` (0 for n = 1, ``None`` with no values)."""
    arr = np.array([v for v in values if v is not None], dtype=float)
    if arr.size == 0:
        return {"mean": None, "ci95": None, "n": 0}
    half = float(1.96 * arr.std(ddof=1) / np.sqrt(arr.size)) if arr.size > 1 else 0.0
    return {"mean": float(arr.mean()), "ci95": half, "n": int(arr.size)}


# Two-sided 95 % quantiles of Student's t for 1..30 degrees of freedom (beyond: the normal 1.96).
_T975 = (12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160, 2.145, 2.131,
         2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064, 2.060, 2.056, 2.052, 2.048, 2.045, 2.042)


def mean_ci95_t(values: Iterable[float | None]) -> dict[str, float | int | None]:
    """Like :func:`mean_ci95` but with Student's t quantile (``t_{0.975, n-1} * s / sqrt(n)``),
    for few values: the across-training-seeds intervals of learned methods (n = 3 gives 4.303)."""
    arr = np.array([v for v in values if v is not None], dtype=float)
    if arr.size == 0:
        return {"mean": None, "ci95": None, "n": 0}
    if arr.size == 1:
        return {"mean": float(arr[0]), "ci95": 0.0, "n": 1}
    df = arr.size - 1
    t = _T975[df - 1] if df <= len(_T975) else 1.96
    return {"mean": float(arr.mean()), "ci95": float(t * arr.std(ddof=1) / np.sqrt(arr.size)), "n": int(arr.size)}


def summarize(episodes: list[dict[str, Any]]) -> dict[str, Any]:
    """Means (and 95 % normal-approximation half-widths, :func:`mean_ci95`) of the headline metrics.

    ``policy_time`` (policy wall seconds per episode) is included when the
    episodes carry it (:func:`~swarm_env.harness.episode.run_episode` results do).
    """
    settle = [s["settle_time"] for e in episodes for s in e["settle_times"]]
    hold = [s.get("hold_fraction") for e in episodes for s in e["settle_times"]]  # absent in older records
    summary = {
        "episodes": len(episodes),
        "success_rate": mean_ci95(float(e["success"]) for e in episodes),
        "collision_free_rate": mean_ci95(float(e["collisions"]["total"] == 0) for e in episodes),
        "collisions": mean_ci95(e["collisions"]["total"] for e in episodes),
        "formation_error": mean_ci95(e["formation_error"]["mean"] for e in episodes),
        "settle_time": mean_ci95(settle),
        "hold_fraction": mean_ci95(hold),
        "sim_time": mean_ci95(e["sim_time"] for e in episodes),
        "min_separation": mean_ci95(e["min_separation"] for e in episodes),
    }
    if all("policy_time" in e for e in episodes):
        summary["policy_time"] = mean_ci95(e["policy_time"] for e in episodes)
    return summary


def evaluate(
    scenario: str,
    policy_spec: str,
    episodes: int = 1,
    seed: int = 0,
    *,
    env_kwargs: dict[str, Any] | None = None,
    on_frame: Callable[[np.ndarray], None] | None = None,
    progress: bool = False,
    record_dir: str | os.PathLike[str] | None = None,
) -> dict[str, Any]:
    """Run ``episodes`` episodes (seeds ``seed, seed+1, ...``) and aggregate them.

    ``on_frame`` receives the frames of every episode in order (the env is
    made with ``render_mode="rgb_array"`` when it is given, unless
    ``env_kwargs`` sets a render mode). ``record_dir``: also record episode
    ``k`` to ``record_dir/episode_<k>/`` (:mod:`swarm_env.harness.recording`; the
    directory must not hold recorded episodes yet); the metrics are the same.
    """
    kwargs = dict(env_kwargs or {})
    if on_frame is not None:
        kwargs.setdefault("render_mode", "rgb_array")
    if record_dir is not None:
        recording.ensure_new_recording_dir(record_dir)
    env = SwarmEnv(scenario, **kwargs)
    try:
        policy = load_policy(policy_spec, env)
        seeds = range(seed, seed + episodes)
        if progress:
            from tqdm.auto import tqdm

            seeds = tqdm(seeds, desc=f"{policy_spec} on {scenario}", unit="ep")
        results = []
        for k, s in enumerate(seeds):
            if record_dir is None:
                results.append(run_episode(env, policy, s, on_frame))
                continue
            metrics, rec = recording.record_episode(env, policy, s, policy_spec=policy_spec, scenario_spec=str(scenario),
                                                    episode=k, on_frame=on_frame)
            recording.save_episode(rec, record_dir)
            results.append(metrics)
    finally:
        env.close()
    return {"scenario": env.scenario_name, "policy": policy_spec, "episodes": results, "summary": summarize(results)}
