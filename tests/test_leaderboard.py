"""The leaderboard: aggregation, process pool, tables, n/a rows, worst-episode videos, the CLI."""

from __future__ import annotations

import csv
import json
import math
import statistics
import subprocess
import sys
from pathlib import Path
from typing import Any

import imageio.v2 as imageio
import pytest

import swarm_env.harness.leaderboard as lb
from swarm_env.harness.cli import main
from swarm_env.harness.leaderboard import (
    TIMING_KEYS,
    Leaderboard,
    Row,
    format_seeds,
    parse_seeds,
    record_worst_videos,
    resolve_seeds,
    run_leaderboard,
    safe_name,
)
from swarm_env.harness.policies import UnknownPolicyError

SHORT = {"max_cycles": 20}
SEEDS = {"paper_vo_0": [0, 1, 2], "random": [1000, 1001, 1002]}


@pytest.fixture(scope="module")
def board() -> Leaderboard:
    return run_leaderboard(["random", "pursuit"], ["paper_vo_0", "random"], SEEDS, env_kwargs=SHORT, progress=False)


def hand_stat(values: list[float]) -> tuple[float, float, int]:
    """Mean and 1.96 * sample std / sqrt(n), computed without numpy."""
    n = len(values)
    return statistics.fmean(values), 1.96 * statistics.stdev(values) / math.sqrt(n), n


def behaviour(metrics: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in metrics.items() if k not in TIMING_KEYS}


# --------------------------------------------------------------------------- seeds
def test_parse_and_format_seeds() -> None:
    assert parse_seeds("0-9") == list(range(10))
    assert parse_seeds("3") == [3]
    assert parse_seeds("0,5,7") == [0, 5, 7]
    assert parse_seeds(" 0-2 , 9 ") == [0, 1, 2, 9]
    for text in ("0-9", "3", "0,5,7", "0-2,9,1000-1049"):
        assert format_seeds(parse_seeds(text)) == text
    for bad in ("", "9-0", "a", "1,1", "-3", "1-", "0-2,1", "1.5"):
        with pytest.raises(ValueError):
            parse_seeds(bad)


def test_resolve_seeds_defaults_and_errors() -> None:
    seeds = resolve_seeds(["paper_vo_0", "random"], None)
    assert seeds["paper_vo_0"] == list(lb.DEFAULT_FIXED_SEEDS)
    assert seeds["random"] == list(lb.DEFAULT_RANDOM_SEEDS)
    assert min(seeds["random"]) >= 1000  # held out from training seeds
    assert resolve_seeds(["a", "b"], range(3)) == {"a": [0, 1, 2], "b": [0, 1, 2]}
    with pytest.raises(ValueError, match="missing"):
        resolve_seeds(["a", "b"], {"a": [0]})
    with pytest.raises(ValueError, match="non-negative"):
        resolve_seeds(["a"], [-1])


# --------------------------------------------------------------------------- aggregation
def test_rows_and_episodes_cover_every_policy_scenario_seed(board: Leaderboard) -> None:
    assert [(r.policy, r.scenario) for r in board.rows] == [
        ("random", "paper_vo_0"), ("random", "random"), ("pursuit", "paper_vo_0"), ("pursuit", "random")
    ]
    for r in board.rows:
        assert r.status == "ok"
        assert [e["seed"] for e in board.episodes_of(r.policy, r.scenario)] == SEEDS[r.scenario]
        assert all(e["steps"] == 20 for e in board.episodes_of(r.policy, r.scenario))


def test_aggregation_equals_hand_computation(board: Leaderboard) -> None:
    for r in board.rows:
        eps = board.episodes_of(r.policy, r.scenario)
        s = r.summary
        assert s is not None and s["episodes"] == 3
        columns = {
            "success_rate": [float(e["success"]) for e in eps],
            "collision_free_rate": [float(e["collisions"]["total"] == 0) for e in eps],
            "collisions": [float(e["collisions"]["total"]) for e in eps],
            "formation_error": [e["formation_error"]["mean"] for e in eps],
            "sim_time": [e["sim_time"] for e in eps],
            "policy_time": [e["policy_time"] for e in eps],
        }
        for key, values in columns.items():
            mean, ci, n = hand_stat(values)
            assert s[key]["n"] == n
            assert s[key]["mean"] == pytest.approx(mean, rel=1e-12, abs=1e-12), key
            assert s[key]["ci95"] == pytest.approx(ci, rel=1e-9, abs=1e-12), key
        assert s["sim_time"]["mean"] == pytest.approx(2.0)  # 20 steps of dt = 0.1 s
        assert s["settle_time"] == {"mean": None, "ci95": None, "n": 0}  # no switch within 2 s


def test_two_workers_give_the_same_metrics_as_one(board: Leaderboard, monkeypatch: pytest.MonkeyPatch) -> None:
    pool_sizes: list[int] = []
    real_pool = lb._run_pool
    monkeypatch.setattr(lb, "_run_pool", lambda jobs, workers, *rest: pool_sizes.append(workers) or real_pool(jobs, workers, *rest))
    pooled = run_leaderboard(["random", "pursuit"], ["paper_vo_0", "random"], SEEDS, env_kwargs=SHORT,
                             workers=2, progress=False)
    assert pool_sizes == [2]  # the jobs really ran in a process pool
    assert [(e["policy"], e["scenario"], e["seed"]) for e in pooled.episodes] == [
        (e["policy"], e["scenario"], e["seed"]) for e in board.episodes
    ]
    assert [behaviour(e["metrics"]) for e in pooled.episodes] == [behaviour(e["metrics"]) for e in board.episodes]
    for a, b in zip(pooled.rows, board.rows):
        assert {k: v for k, v in a.summary.items() if k != "policy_time"} == {
            k: v for k, v in b.summary.items() if k != "policy_time"
        }


# --------------------------------------------------------------------------- tables
def test_markdown_table(board: Leaderboard) -> None:
    md = board.to_markdown()
    assert "95 %" in md and "N episodes" in md
    assert "### paper_vo_0 — seeds 0-2 (N = 3)" in md and "### random — seeds 1000-1002 (N = 3)" in md
    fe = board.row("pursuit", "random").summary["formation_error"]
    line = next(line for line in md.splitlines() if line.startswith("| `pursuit` |") and f"{fe['mean']:.3f}" in line)
    assert f"{fe['mean']:.3f} ± {fe['ci95']:.3f}" in line
    assert line.count("|") == 11  # policy, acts on, 8 metric columns
    assert line.startswith("| `pursuit` | state |")
    assert "| `random` | nothing |" in md


def test_csv_parses_back_to_the_summaries(board: Leaderboard, tmp_path: Path) -> None:
    path = board.to_csv(tmp_path / "lb.csv")
    with path.open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == len(board.rows)
    for parsed, row in zip(rows, board.rows):
        assert (parsed["policy"], parsed["scenario"], parsed["status"]) == (row.policy, row.scenario, "ok")
        assert parsed["episodes"] == "3" and parsed["seeds"] == format_seeds(row.seeds)
        for key in ("success_rate", "collisions", "formation_error", "sim_time", "policy_time", "min_separation"):
            stat = row.summary[key]
            assert float(parsed[f"{key}_mean"]) == stat["mean"]  # exact: repr round-trips
            assert float(parsed[f"{key}_ci95"]) == stat["ci95"]
            assert int(parsed[f"{key}_n"]) == stat["n"]
        assert parsed["settle_time_mean"] == "" and parsed["settle_time_n"] == "0"


def test_json_holds_everything_and_reads_back(board: Leaderboard, tmp_path: Path) -> None:
    path = board.to_json(tmp_path / "lb.json")
    doc = json.loads(path.read_text())
    assert doc["seeds"] == SEEDS and doc["env_kwargs"] == SHORT
    assert len(doc["episodes"]) == 12 and "per_robot" in doc["episodes"][0]["metrics"]
    back = Leaderboard.from_json(path)
    assert back.to_markdown() == board.to_markdown()
    assert back.worst_episodes() == json.loads(json.dumps(board.worst_episodes()))


def test_refused_scenario_gives_an_na_row(tmp_path: Path) -> None:
    board = run_leaderboard(["vo", "pursuit", "zero"], ["paper_vo_0"], [0, 1],
                            env_kwargs={"action_type": "discrete", "max_cycles": 5}, progress=False)
    vo, pursuit, zero = board.rows
    assert vo.status.startswith("n/a: ") and "continuous" in vo.status and vo.summary is None
    assert pursuit.status.startswith("n/a: ")  # refuses in reset(), not in its factory
    assert zero.status == "ok" and zero.summary["episodes"] == 2
    assert {e["policy"] for e in board.episodes} == {"zero"}
    assert "| `vo` | state | n/a: " in board.to_markdown()
    with board.to_csv(tmp_path / "na.csv").open() as f:
        parsed = {r["policy"]: r for r in csv.DictReader(f)}
    assert parsed["vo"]["status"].startswith("n/a: ") and parsed["vo"]["formation_error_mean"] == ""


def test_inputs_are_checked_before_any_episode(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(lb, "record_episode", lambda *a, **k: pytest.fail("an episode ran"))
    with pytest.raises(UnknownPolicyError, match="nope"):
        run_leaderboard(["zero", "nope"], ["paper_vo_0"], [0], progress=False)
    with pytest.raises(ValueError, match="no_such_scenario"):
        run_leaderboard(["zero"], ["paper_vo_0", "no_such_scenario"], [0], progress=False)
    with pytest.raises(ValueError, match="render_mode"):
        run_leaderboard(["zero"], ["paper_vo_0"], [0], env_kwargs={"render_mode": "rgb_array"}, progress=False)
    with pytest.raises(ValueError, match="more than once"):
        run_leaderboard(["zero", "zero"], ["paper_vo_0"], [0], progress=False)


def test_an_episode_that_raises_carries_a_note_naming_its_job(monkeypatch: pytest.MonkeyPatch) -> None:
    real = lb.record_episode

    def fails_on_seed_1(env: Any, policy: Any, seed: int, **kwargs: Any) -> Any:
        if seed == 1:
            raise RuntimeError("boom")
        return real(env, policy, seed, **kwargs)

    monkeypatch.setattr(lb, "record_episode", fails_on_seed_1)
    with pytest.raises(RuntimeError, match="boom") as info:
        run_leaderboard(["zero"], ["paper_vo_0"], [0, 1], env_kwargs={"max_cycles": 5}, progress=False)
    # the same on Python 3.10, which has no BaseException.add_note (swarm_env._compat.add_note)
    assert info.value.__notes__ == ["while evaluating policy 'zero' on scenario 'paper_vo_0', seed 1"]


# --------------------------------------------------------------------------- worst episodes and videos
def fake_episode(policy: str, seed: int, collisions: int, success: bool, error: float) -> dict[str, Any]:
    metrics = {"seed": seed, "success": success, "collisions": {"total": collisions}, "formation_error": {"mean": error}}
    return {"policy": policy, "scenario": "s", "seed": seed, "metrics": metrics}


def test_worst_episode_ranks_collisions_then_failure_then_error() -> None:
    def worst(*episodes: dict[str, Any]) -> int:
        board = Leaderboard(["p"], ["s"], {"s": []}, {}, [], list(episodes))
        (w,) = board.worst_episodes()
        return w["seed"]

    assert worst(fake_episode("p", 0, 1, False, 9.0), fake_episode("p", 1, 2, True, 0.1)) == 1
    assert worst(fake_episode("p", 0, 1, True, 9.0), fake_episode("p", 1, 1, False, 0.1)) == 1
    assert worst(fake_episode("p", 0, 0, True, 0.2), fake_episode("p", 1, 0, True, 0.3)) == 1
    assert worst(fake_episode("p", 0, 0, True, 0.2), fake_episode("p", 1, 0, True, 0.2)) == 0  # ties: first seed
    two = Leaderboard(["p"], ["s", "t"], {}, {}, [], [
        fake_episode("p", 0, 3, True, 0.1), {**fake_episode("p", 5, 0, True, 0.1), "scenario": "t"}])
    assert [e["seed"] for e in two.worst_episodes(per_scenario=True)] == [0, 5]
    assert [e["seed"] for e in two.worst_episodes(per_scenario=False)] == [0]


def test_safe_names() -> None:
    assert safe_name("ppo:runs/x/model.zip") == "ppo_runs_x_model.zip"
    assert safe_name("vo:horizon=4,margin=0.1") == "vo_horizon_4_margin_0.1"
    assert safe_name("../..") == "x"


def test_worst_episode_video_is_replayed_from_its_record(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    board = run_leaderboard(["random"], ["paper_vo_0"], [0, 1], env_kwargs={"max_cycles": 5}, progress=False)
    (worst,) = board.worst_episodes()
    assert list(board.records) == [("random", "paper_vo_0", worst["seed"])]  # only the worst episode's record is kept
    # the videos replay records: no policy runs again
    monkeypatch.setattr(lb, "load_policy", lambda *a, **k: pytest.fail("a policy was loaded"))
    (rec,) = record_worst_videos(board, tmp_path / "videos", fps=10, progress=False, records_dir=tmp_path / "records")
    name = f"random__paper_vo_0__seed{worst['seed']}"
    assert rec.reproduced and rec.seed == worst["seed"]
    assert rec.path == tmp_path / "videos" / f"{name}.mp4"
    with imageio.get_reader(str(rec.path)) as reader:
        assert sum(1 for _ in reader) == 5 + 1  # the initial frame and one per step
    assert (tmp_path / "records" / name / "episode_0" / "actions.npz").is_file()  # swarm-env replay reads it

    # a board read back from JSON holds no records: they come from records_dir, or it is an error
    board.to_json(tmp_path / "lb.json")
    again = Leaderboard.from_json(tmp_path / "lb.json")
    (rec,) = record_worst_videos(again, tmp_path / "from_disk", fps=10, progress=False, records_dir=tmp_path / "records")
    assert rec.reproduced
    with pytest.raises(ValueError, match=f"no record of the worst episode of policy 'random' on 'paper_vo_0' \\(seed {worst['seed']}\\)"):
        record_worst_videos(again, tmp_path / "none", fps=10, progress=False)

    worst["metrics"]["collisions"]["total"] += 7  # the board's episode no longer matches its record's replay
    with pytest.warns(RuntimeWarning, match="did not reproduce the board's episode"):
        (rec,) = record_worst_videos(board, tmp_path / "again", fps=10, progress=False)
    assert not rec.reproduced and rec.path.exists()


def test_recording_leaves_the_metrics_unchanged() -> None:
    """The leaderboard records every episode it plays; the metrics are those of a plain run_episode."""
    from swarm_env.env import SwarmEnv
    from swarm_env.harness.episode import run_episode
    from swarm_env.harness.policies import load_policy

    board = run_leaderboard(["random"], ["random"], [1000, 1001], env_kwargs={"max_cycles": 20}, progress=False)
    env = SwarmEnv("random", max_cycles=20)
    policy = load_policy("random", env)
    plain = [run_episode(env, policy, seed) for seed in (1000, 1001)]
    assert [lb._behaviour(e["metrics"]) for e in board.episodes] == [lb._behaviour(m) for m in plain]


# --------------------------------------------------------------------------- command line
def test_cli_writes_tables(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    code = main(["evaluate", "--policies", "zero", "random", "--scenarios", "paper_vo_0", "random", "--seeds", "0-1",
                 "--scenario-seeds", "random=1000", "--max-cycles", "5", "--out", str(out), "--quiet"])
    assert code == 0
    printed = capsys.readouterr().out
    assert "### paper_vo_0 — seeds 0-1 (N = 2)" in printed and "### random — seeds 1000 (N = 1)" in printed
    assert (out / "leaderboard.md").read_text() in printed
    doc = json.loads((out / "leaderboard.json").read_text())
    assert doc["seeds"] == {"paper_vo_0": [0, 1], "random": [1000]}
    assert len(doc["episodes"]) == 2 * (2 + 1)
    with (out / "leaderboard.csv").open() as f:
        assert len(list(csv.DictReader(f))) == 4


def test_cli_videos_replay_saved_records(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    code = main(["evaluate", "--policies", "random", "--scenarios", "paper_vo_0", "--seeds", "0", "--max-cycles", "5",
                 "--out", str(out), "--videos", "--quiet"])
    assert code == 0
    assert f"wrote {out / 'videos' / 'random__paper_vo_0__seed0.mp4'}\n" in capsys.readouterr().out
    record = out / "records" / "random__paper_vo_0__seed0"
    assert main(["replay", str(record), "--check"]) == 0  # the saved record replays on its own
    assert "random on paper_vo_0, 5 of 5 steps replayed, 6 digests checked" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--policies", "vo", "no_such_policy", "--seeds", "0"], "no_such_policy"),
        (["--policies", "zero", "--scenarios", "paper_vo_0", "no_such_scenario"], "no_such_scenario"),
        (["--policies", "zero", "--seeds", "0-x"], "0-x"),
        (["--policies", "zero", "--seeds", "5-1"], "5-1"),
        (["--policies", "zero", "--scenarios", "paper_vo_0", "--scenario-seeds", "random=0"], "random"),
        (["--policies", "zero", "--scenario-seeds", "random"], "SCENARIO=SEEDS"),
        (["--policies", "zero", "--workers", "0"], "--workers"),
        (["--policies", "zero", "--videos"], "--out"),
    ],
)
def test_cli_bad_input_exits_2_before_any_episode(
    argv: list[str], message: str, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(lb, "record_episode", lambda *a, **k: pytest.fail("an episode ran"))
    assert main(["evaluate", *argv]) == 2
    captured = capsys.readouterr()
    assert message in captured.err and captured.out == ""


def test_baselines_evaluate_help() -> None:
    proc = subprocess.run([sys.executable, "-m", "swarm_env_baselines.evaluate", "--help"], capture_output=True, text=True,
                          cwd=Path(__file__).resolve().parents[1])
    assert proc.returncode == 0, proc.stderr
    assert "--policies" in proc.stdout and "--scenario-seeds" in proc.stdout


def test_na_row_in_a_markdown_cell_escapes_pipes() -> None:
    board = Leaderboard(["p"], ["s"], {"s": [0]}, {}, [Row("p", "s", [0], None, "no | way\nat all")], [])
    assert "| `p` | ? | n/a: no \\| way at all |" in board.to_markdown()


def test_paired_differences_pair_by_seed(tmp_path, capsys) -> None:
    import json as _json

    from swarm_env.harness import paired

    def ep(policy, seed, collisions, err):
        return {"policy": policy, "scenario": "random", "seed": seed,
                "metrics": {"collisions": {"total": collisions}, "formation_error": {"mean": err}, "success": False}}

    # Large between-world variance, a constant paired difference of -1 collision.
    base = [ep("pursuit", s, 10 * s, 0.5) for s in range(6)]
    better = [ep("mine", s, 10 * s - 1, 0.5) for s in range(6)]
    doc = {"policies": ["pursuit", "mine"], "episodes": base + better}
    d = paired.paired_differences(doc, "mine", "pursuit")
    assert d["collisions"]["mean"] == -1.0 and d["collisions"]["ci95"] == 0.0 and d["collisions"]["n"] == 6
    assert d["collisions"]["excludes_zero"] and not d["formation_error"]["excludes_zero"]
    path = tmp_path / "lb.json"
    path.write_text(_json.dumps(doc))
    assert paired.main([str(path)]) == 0 and "`mine` | 6 | -1.000 ± 0.000 *" in capsys.readouterr().out
    assert paired.main([str(path), "--baseline", "nobody"]) == 2


def test_the_collision_profile_splits_contacts_by_kind(tmp_path, capsys) -> None:
    import json as _json

    from swarm_env.harness import paired

    def ep(policy, seed, method, **kinds):
        counts = {k: kinds.get(k, 0) for k in paired.CONTACT_KINDS}
        return {"policy": policy, "method": method, "scenario": "random", "seed": seed,
                "metrics": {"collisions": {"total": sum(counts.values()), **counts}, "formation_error": {"mean": 0.3},
                            "success": True}}

    doc = {"policies": ["pursuit", "m"], "episodes": [
        ep("pursuit", 0, None, robot_human=2), ep("pursuit", 1, None),
        ep("m:s0", 0, "m", robot_robot=1, robot_obstacle=1), ep("m:s0", 1, "m"),
        ep("m:s1", 0, "m"), ep("m:s1", 1, "m", robot_wall=4)]}
    c = paired.collision_profile(doc, "m")
    assert c == {"n": 4, "any_contact": 0.5, "robot_robot": 0.25, "robot_human": 0.0, "robot_obstacle": 0.25,
                 "robot_wall": 1.0}
    assert paired.collision_profile(doc, "m:s1")["any_contact"] == 0.5
    with pytest.raises(ValueError, match="no episodes of 'x'"):
        paired.collision_profile(doc, "x")
    path = tmp_path / "lb.json"
    path.write_text(_json.dumps(doc))
    assert paired.main([str(path), "--profile", "--per-seed"]) == 0
    out = capsys.readouterr().out
    assert "| `pursuit` | 2 | 0.50 | 0.00 | 1.00 | 0.00 | 0.00 |" in out and "| `m:s0` | 2 | 0.50 |" in out


# --------------------------------------------------------------------------- methods with training seeds
@pytest.fixture()
def trio(monkeypatch: pytest.MonkeyPatch) -> str:
    """A fake learned method with three 'training seeds' (pursuit with three time gaps)."""
    from swarm_env.harness import policies

    def factory(env: Any, arg: str | None = None) -> Any:
        return policies.PursuitPolicy(env, {"s0": "0.3", "s1": "0.5", "s2": "0.9"}[arg or "s0"])

    factory.training_runs = ("s0", "s1", "s2")
    monkeypatch.setitem(policies._BUILTIN, "trio", factory)
    return "trio"


def test_a_method_is_played_per_training_seed_and_aggregated_across_seeds(
        trio: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from swarm_env.harness.policies import training_runs

    assert training_runs("trio") == ("trio:s0", "trio:s1", "trio:s2")
    assert training_runs("trio:s1") == ("trio:s1",) and training_runs("pursuit") == ("pursuit",)
    board = run_leaderboard(["trio", "pursuit"], ["random"], {"random": [1000, 1001]}, env_kwargs=SHORT, progress=False)
    assert [(r.policy, r.method, r.members) for r in board.rows] == [
        ("trio", None, ["trio:s0", "trio:s1", "trio:s2"]),
        ("trio:s0", "trio", None), ("trio:s1", "trio", None), ("trio:s2", "trio", None),
        ("pursuit", None, None),
    ]
    method, *members = board.rows[:4]
    for key in ("formation_error", "collisions", "sim_time"):
        means = [m.summary[key]["mean"] for m in members]
        mean, sd = statistics.fmean(means), statistics.stdev(means)
        assert method.summary[key]["mean"] == pytest.approx(mean, rel=1e-12)
        assert method.summary[key]["ci95"] == pytest.approx(4.303 * sd / math.sqrt(3), rel=1e-9, abs=1e-12)
        assert method.summary[key]["n"] == 3
    assert method.summary["episodes"] == 6 and method.summary["training_seeds"] == 3
    assert len(set(m.summary["formation_error"]["mean"] for m in members)) == 3  # the seeds really differ
    assert len(board.episodes_of("trio", "random")) == 6
    assert {e["method"] for e in board.episodes if e["policy"].startswith("trio")} == {"trio"}

    md = board.to_markdown()
    assert "| `trio` (3 seeds) | ? |" in md and "trio:s0" not in md and "Student-t" in md  # trio does not say
    with board.to_csv(tmp_path / "lb.csv").open() as f:
        parsed = list(csv.DictReader(f))
    assert [(r["policy"], r["method"], r["training_seeds"]) for r in parsed] == [
        ("trio", "", "3"), ("trio:s0", "trio", ""), ("trio:s1", "trio", ""), ("trio:s2", "trio", ""), ("pursuit", "", "")]
    back = Leaderboard.from_json(board.to_json(tmp_path / "lb.json"))
    assert back.to_markdown() == md
    (worst,) = [w for w in board.worst_episodes() if w.get("method") == "trio"]  # one worst episode per method

    from swarm_env.harness import paired

    doc = json.loads((tmp_path / "lb.json").read_text())
    d = paired.paired_differences(doc, "trio", "pursuit", "random")
    per_world = [statistics.fmean(e["metrics"]["formation_error"]["mean"] for e in board.episodes
                                  if e.get("method") == "trio" and e["seed"] == s) for s in (1000, 1001)]
    base = [e["metrics"]["formation_error"]["mean"] for e in board.episodes if e["policy"] == "pursuit"]
    assert d["formation_error"]["n"] == 2
    assert d["formation_error"]["mean"] == pytest.approx(statistics.fmean(a - b for a, b in zip(per_world, base)))
    one = paired.paired_differences(doc, "trio:s1", "pursuit", "random")  # one training seed, as played
    seed1 = [e["metrics"]["formation_error"]["mean"] for e in board.episodes if e["policy"] == "trio:s1"]
    assert one["formation_error"]["mean"] == pytest.approx(statistics.fmean(a - b for a, b in zip(seed1, base)))
    assert paired.main([str(tmp_path / "lb.json"), "--per-seed"]) == 0
    out = capsys.readouterr().out
    assert all(f"| `{name}` | 2 |" in out for name in ("trio", "trio:s0", "trio:s1", "trio:s2"))


def test_csv_n_counts_episodes_on_every_row_a_methods_included() -> None:
    """``<metric>_n`` means one thing: episodes with a value (a method's row sums its training seeds'; its mean and
    interval are across the ``training_seeds`` seeds)."""
    board = Leaderboard.from_json(Path(__file__).resolve().parent.parent / "docs" / "leaderboard" / "random"
                                  / "leaderboard.json")
    rows = {(d["policy"], d["scenario"]): d for d in board.csv_rows()}
    method = rows[("ippo", "random")]
    members = [d for d in rows.values() if d["method"] == "ippo" and d["scenario"] == "random"]
    assert method["training_seeds"] == len(members) == 3
    for key in ("collisions", "settle_time"):
        assert method[f"{key}_n"] == sum(d[f"{key}_n"] for d in members)
    assert method["collisions_n"] == method["episodes"] == 150
    assert rows[("vo", "random")]["collisions_n"] == 50
