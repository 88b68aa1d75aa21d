"""What the fault tests of both evaluation backends (tests/test_eval_faults.py: the local pool,
tests/test_ray.py: Ray) compare: a board's episodes without their timings, and the fault policies'
finished episodes against plain pursuit's (the fault policies play pursuit except where they fail)."""

from __future__ import annotations

import json
from typing import Any

from swarm_env.harness.leaderboard import TIMING_KEYS, Leaderboard, run_leaderboard

SHORT = {"max_cycles": 20}  # 20-step episodes: the fault tests time the faults, not the episodes
SEEDS = [0, 1, 2]


def behaviour(board: Leaderboard) -> list[tuple[str, str, int, dict[str, Any]]]:
    """The episodes without their timings, as JSON stores them (a resumed board reads some back from JSON)."""
    return [(e["policy"], e["scenario"], e["seed"],
             json.loads(json.dumps({k: v for k, v in e["metrics"].items() if k not in TIMING_KEYS})))
            for e in board.episodes]


def pursuit_reference() -> Leaderboard:
    """Plain pursuit on the fault tests' episodes, played in this process."""
    return run_leaderboard(["pursuit"], ["paper_vo_0"], SEEDS, env_kwargs=SHORT, progress=False)


def same_as_pursuit(board: Leaderboard, policy: str, pursuit_board: Leaderboard, seeds: list[int]) -> None:
    """``policy``'s episodes on ``board`` are those of ``seeds``, each equal to pursuit's."""
    want = {s: m for (_, _, s, m) in behaviour(pursuit_board)}
    got = [(s, m) for (p, _, s, m) in behaviour(board) if p == policy]
    assert [s for s, _ in got] == seeds
    assert all(m == want[s] for s, m in got)
