"""The throughput benchmarks behind ``swarm-env bench`` (tiny budgets: they check the plumbing,
not the speed; the figures come from the commands in docs/performance.md)."""

from __future__ import annotations

import json

import pytest

from swarm_env.extras import MissingExtraError
from swarm_env.harness.bench import run_batched_bench, run_followers_bench
from swarm_env.harness.cli import main


def test_batched_bench_reports_each_size_for_the_engine() -> None:
    results = run_batched_bench((1, 3), repeats=2, budget=6)
    assert [(r.name, r.num_envs, r.agents) for r in results] == [("swarm_env.vector.engine", 1, 8), ("swarm_env.vector.engine", 3, 8)]
    assert all(len(r.wall) == 2 and r.median_wall > 0 and r.median_cpu > 0 for r in results)


def test_followers_bench_reports_each_team_size() -> None:
    results = run_followers_bench((2, 5), steps=5, repeats=1)
    assert [r.agents for r in results] == [2, 5] and all(r.median_wall > 0 for r in results)


def test_unknown_peer_is_refused() -> None:
    with pytest.raises(ValueError, match="vmas"):
        run_batched_bench((1,), peer="mpe2")


def test_cli_followers_table_and_json(tmp_path, capsys) -> None:
    out = tmp_path / "bench.json"
    assert main(["bench", "--followers", "2", "--repeats", "1", "--quiet", "--json", str(out)]) == 0
    assert "swarm_env:random(n_followers=2)" in capsys.readouterr().out
    doc = json.loads(out.read_text())
    assert doc[0]["agents"] == 2 and len(doc[0]["wall"]) == 1


def test_vmas_peer_says_which_extra_is_missing(monkeypatch) -> None:
    import sys

    monkeypatch.setitem(sys.modules, "vmas", None)  # as if not installed
    with pytest.raises(MissingExtraError, match=r"swarm-env\[rl,vmas\]"):
        run_batched_bench((1,), repeats=1, budget=5, peer="vmas")


def test_cli_names_the_missing_extra_in_one_line(monkeypatch, capsys) -> None:
    import sys

    monkeypatch.setitem(sys.modules, "ray", None)
    assert main(["evaluate", "--policies", "zero", "--scenarios", "paper_vo_90", "--backend", "ray", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "pip install 'swarm-env[ray]'" in err[0]
