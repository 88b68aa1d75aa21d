"""Scenario families (swarm_env.scenarios.families), reachable switches, and benchmark suites (swarm_env.harness.suite)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from swarm_env.env import SwarmEnv, env_kwargs_for
from swarm_env.harness.cli import main
from swarm_env.harness.suite import (
    RESULT_FORMAT,
    SUITES,
    TEST_BLOCK,
    VALIDATION_BLOCK,
    Suite,
    collision_record,
    get_suite,
    new_collisions,
    result_markdown,
    run_suite,
    suite_result,
)
from swarm_env.harness.suite import main as suite_main
from swarm_env.scenario import ScenarioError
from swarm_env.scenarios.families import FAMILIES, Family, generated_names, generator_config
from swarm_env.scenarios.generator import RandomScenarioConfig, random_scenario, reach_time, switch_reach_times
from swarm_env.scenarios.loader import list_scenarios, load_scenario


# --------------------------------------------------------------------------- families
@pytest.mark.parametrize("name", [f.name for f in FAMILIES.values() if f.generated])
def test_generator_family_draws_worlds_with_its_knobs(name: str) -> None:
    family = FAMILIES[name]
    env = SwarmEnv(f"random:{name}")
    assert env.scenario_name == f"random:{name}"
    cfg = family.config()
    for seed in (1000, 1001):
        env.reset(seed=seed)
        scn = env.scenario
        lo, hi = cfg.n_followers  # type: ignore[misc]
        assert lo <= scn.robots.count <= hi
        assert scn.leader.kind == cfg.leader_kind and scn.world.max_time == cfg.max_time
        walls = 2 * cfg.n_gates[1]  # type: ignore[index]  # a gate is two wall rectangles
        assert len(scn.humans) <= cfg.n_humans[1] and len(scn.obstacles) <= cfg.n_obstacles[1] + walls  # type: ignore[index]
        assert all(h.behavior == cfg.human_behavior for h in scn.humans)
    env.close()


def test_family_knobs_are_the_generator_with_overrides() -> None:
    cfg = generator_config("random:cluttered", {"n_humans": 0})
    assert cfg.n_obstacles == (14, 20) and cfg.n_humans == (0, 0)
    assert cfg == RandomScenarioConfig(**{**FAMILIES["cluttered"].knobs, "n_humans": 0})
    # a family's env draws exactly the worlds of "random" with the family's knobs
    a, b = SwarmEnv("random:crowd"), SwarmEnv("random", **FAMILIES["crowd"].knobs)
    oa, _ = a.reset(seed=1003)
    ob, _ = b.reset(seed=1003)
    assert a.scenario == b.scenario
    assert all(np.array_equal(oa[k], ob[k]) for k in oa)
    # "mixed" is the generator's defaults: the leaderboard's "random" worlds, unchanged
    m, r = SwarmEnv("random:mixed"), SwarmEnv("random")
    m.reset(seed=1000)
    r.reset(seed=1000)
    assert m.scenario == r.scenario
    assert env_kwargs_for("random:open", {"n_humans": 1, "max_cycles": 5}) == {"n_humans": 1, "max_cycles": 5}
    assert env_kwargs_for("corridor", {"n_humans": 1, "max_cycles": 5}) == {"max_cycles": 5}


def test_unknown_or_fixed_family_names_are_refused() -> None:
    with pytest.raises(ScenarioError, match=r"random:nope.*a generator family \(random:mixed, random:open"):
        SwarmEnv("random:nope")
    with pytest.raises(ScenarioError, match="a generator family"):
        SwarmEnv("random:paper")  # a fixed family has no generator
    with pytest.raises(ScenarioError, match="generated per episode"):
        load_scenario("random:open")
    with pytest.raises(ValueError, match="not generated"):
        FAMILIES["paper"].config()
    with pytest.raises(ValueError, match="difficulty"):
        Family("x", "d", "impossible")
    with pytest.raises(ValueError, match="not both"):
        Family("x", "d", "easy", knobs={"n_humans": 0}, scenarios=("corridor",))


def test_fixed_families_name_built_in_scenarios() -> None:
    built_in = set(list_scenarios())
    for family in FAMILIES.values():
        assert family.scenario_names
        if not family.generated:
            assert set(family.scenarios) <= built_in, family.name
    assert generated_names()[0] == "random" and "random:switching" in generated_names()


# --------------------------------------------------------------------------- reachable switches
def test_reach_time_is_the_closing_speed_bound() -> None:
    before = np.array([[0.0, 0.0], [-1.0, 0.0]])
    # straight ahead by 2 m: closing at max_speed - leader_speed; the tolerance is free
    t = reach_time(before, before + [[2.3, 0.0], [0.0, 0.0]], leader_speed=0.4, max_speed=0.65, tolerance=0.3)
    assert t == pytest.approx(2.0 / 0.25)
    # straight back: closing at max_speed + leader_speed
    assert reach_time(before, before - [[2.3, 0.0], [0.0, 0.0]], 0.4, 0.65, 0.3) == pytest.approx(2.0 / 1.05)
    # sideways: sqrt(v^2 - v_L^2)
    assert reach_time(before, before + [[0.0, 2.3], [0.0, 0.0]], 0.4, 0.65, 0.3) == pytest.approx(2.0 / np.sqrt(0.65 ** 2 - 0.16))
    assert reach_time(before, before + 0.2, 0.4, 0.65, 0.3) == 0.0  # within the tolerance already


def test_switching_family_leaves_each_switch_its_reach_time() -> None:
    cfg = FAMILIES["switching"].config()
    counts = []
    for seed in range(1000, 1012):
        scn = random_scenario(np.random.default_rng(seed), cfg)
        reach = switch_reach_times(scn)
        ends = [f.at for f in scn.formations[1:]] + [scn.formations[-1].at + 1e9]
        for k, need in enumerate(reach):
            assert ends[k + 1] - ends[k] >= cfg.switch_reach * need - 0.1 - 1e-9, (seed, k)  # type: ignore[operator]
        shapes = [(f.shape, f.spacing, f.angle) for f in scn.formations]
        assert all(a != b for a, b in zip(shapes, shapes[1:]))  # every entry is a real change
        assert scn.formations[-1].at <= 0.7 * scn.world.max_time  # every switch within the leader's travel
        counts.append(len(scn.formations) - 1)
    assert np.mean(counts) >= 2.5  # switching worlds switch


def test_default_generator_ignores_reach() -> None:
    cfg = RandomScenarioConfig(n_switches=2)
    assert cfg.switch_reach is None
    with pytest.raises(ScenarioError, match="switch_reach"):
        RandomScenarioConfig(switch_reach=0.5)


# --------------------------------------------------------------------------- suites
def test_suites_keep_their_splits_apart() -> None:
    for suite in SUITES.values():
        assert all(s in VALIDATION_BLOCK for s in suite.validation)
        assert all(s in TEST_BLOCK for s in suite.test)
        test = suite.seeds("test")
        assert set(test) == set(suite.scenarios())
        for name in suite.families:
            for scenario in FAMILIES[name].scenario_names:
                assert test[scenario] == list(suite.test if FAMILIES[name].generated else suite.fixed_seeds)
    assert len(get_suite("standard").test) >= 20 and set(get_suite("standard").families) == set(FAMILIES)
    with pytest.raises(ValueError, match="unknown suite 'nope'; known suites: standard, quick"):
        get_suite("nope")
    with pytest.raises(ValueError, match="split must be one of"):
        get_suite("quick").seeds("train")
    with pytest.raises(ValueError, match="test seeds must be non-empty and in 1000-1999"):
        Suite("x", 1, "d", ("open",), validation=(500,), test=(5,))
    with pytest.raises(ValueError, match="unknown families"):
        Suite("x", 1, "d", ("opn",), validation=(500,), test=(1000,))


TINY = Suite("tiny", 1, "two families, one world each", ("open", "corridor"), validation=(500,), test=(1000,),
             fixed_seeds=(0,), env_kwargs={"action_type": "continuous", "max_cycles": 30})


def test_suite_result_scores_each_family_and_the_aggregate(tmp_path) -> None:
    board = run_suite(["pursuit", "zero"], TINY, "test", progress=False, out_dir=tmp_path / "s")
    assert board.scenarios == ["random:open", "corridor"]
    result = suite_result(board, TINY, "test")
    assert result["format"] == RESULT_FORMAT and result["suite"]["name"] == "tiny" and result["suite"]["split"] == "test"
    rows = {(r["policy"], r["family"]): r for r in result["results"]}
    assert set(rows) == {(p, f) for p in ("pursuit", "zero") for f in ("open", "corridor")}
    for (policy, family), row in rows.items():
        episodes = [e["metrics"] for e in board.episodes
                    if e["policy"] == policy and e["scenario"] in FAMILIES[family].scenario_names]
        s = row["summary"]
        assert s["episodes"] == len(episodes) == 1
        assert s["collisions"]["mean"] == episodes[0]["collisions"]["total"]
        assert s["collision_rate"]["mean"] == float(episodes[0]["collisions"]["total"] > 0)
        assert s["formation_error"]["mean"] == pytest.approx(episodes[0]["formation_error"]["mean"])
    agg = {a["policy"]: a for a in result["aggregate"]}
    zero = [rows[("zero", f)]["summary"]["formation_error"]["mean"] for f in ("open", "corridor")]
    assert agg["zero"]["formation_error"] == pytest.approx(sum(zero) / 2)
    assert agg["zero"]["families"] == 2
    md = result_markdown(result)
    assert "## open (easy)" in md and "## corridor (medium)" in md and "| `zero` | 2/2 |" in md
    spec = json.loads((tmp_path / "s" / "sweep.json").read_text())
    assert spec["suite"]["name"] == "tiny"


def test_cli_suite_writes_and_resumes(tmp_path, capsys, monkeypatch) -> None:
    import swarm_env.harness.suite as suite_mod

    monkeypatch.setattr(suite_mod, "SUITES", {**SUITES, "tiny": TINY})
    import swarm_env.harness.cli as cli

    monkeypatch.setattr(cli, "SUITES", suite_mod.SUITES)
    out = tmp_path / "q"
    assert main(["evaluate", "--suite", "tiny", "--policies", "pursuit", "--out", str(out), "--quiet"]) == 0
    first = json.loads((out / "suite.json").read_text())
    assert "# Suite `tiny/1`, test split" in (out / "suite.md").read_text()
    assert [r["family"] for r in first["results"]] == ["open", "corridor"]
    # a resumed suite sweep scores the suite again, from the stored episodes
    assert main(["evaluate", "--resume", str(out), "--quiet"]) == 0
    again = json.loads((out / "suite.json").read_text())
    assert again["results"] == first["results"] and again["aggregate"] == first["aggregate"]
    capsys.readouterr()
    assert main(["evaluate", "--suite", "tiny", "--policies", "pursuit", "--scenarios", "corridor"]) == 2
    assert "--suite fixes the scenarios, seeds and env options; drop --scenarios" in capsys.readouterr().err
    assert main(["evaluate", "--policies", "pursuit", "--split", "test"]) == 2
    assert "--split needs --suite" in capsys.readouterr().err


# --------------------------------------------------------------------------- no silent regressions
QUICK_REFERENCE = "tests/data/quick_suite_collisions.json"


@pytest.mark.slow
def test_quick_suite_experts_collide_no_more_than_recorded() -> None:
    """The experts on the quick suite's test split: an episode with more collisions than the stored reference
    fails. After a deliberate change, rerun and store the reference with the commands in docs/benchmark.md
    ("No silent regressions"), with the standard suite's table before and after in the CHANGELOG."""
    board = run_suite(["vo", "cbs_rrt", "obs_expert"], SUITES["quick"], "test", workers=2, progress=False)
    reference = json.loads(open(QUICK_REFERENCE).read())
    assert new_collisions(board.to_dict(), reference) == []
    # the reference holds every episode of the run (so that it is the run's, not a hand-written one)
    played = collision_record(board.to_dict())["collisions"]
    assert {p: set(s) for p, s in played.items()} == {p: set(s) for p, s in reference["collisions"].items()}


def test_new_collisions_names_each_worse_episode(tmp_path, capsys) -> None:
    def doc(n: int) -> dict:
        return {"episodes": [{"policy": "vo", "scenario": "random:open", "seed": 1000,
                              "metrics": {"collisions": {"total": n}}}]}

    ref = collision_record(doc(1))
    assert new_collisions(doc(1), ref) == [] and new_collisions(doc(0), ref) == []
    assert new_collisions(doc(2), ref) == ["vo on random:open seed 1000: 2 collisions (was 1)"]
    with pytest.raises(ValueError, match="format"):
        new_collisions(doc(0), {"collisions": {}})
    d = tmp_path / "run"
    d.mkdir()
    (d / "leaderboard.json").write_text(json.dumps(doc(3)))
    (tmp_path / "ref.json").write_text(json.dumps(ref))
    assert suite_main(["check", str(d), "--against", str(tmp_path / "ref.json")]) == 1
    assert "new collision: vo on random:open seed 1000: 3 collisions (was 1)" in capsys.readouterr().out
    assert suite_main(["check", str(d), "--against", str(tmp_path / "ref.json"), "--write"]) == 0
    assert suite_main(["check", str(d), "--against", str(tmp_path / "ref.json")]) == 0
    assert suite_main(["check", str(tmp_path / "missing"), "--against", str(tmp_path / "ref.json")]) == 2


def test_a_family_gets_the_held_out_seeds_by_default() -> None:
    from swarm_env.harness.leaderboard import DEFAULT_RANDOM_SEEDS, default_seeds

    assert default_seeds("random:crowd") == default_seeds("random") == list(DEFAULT_RANDOM_SEEDS)
    assert default_seeds("corridor") == [0, 1, 2, 3, 4]


def test_a_learned_method_is_scored_across_its_training_seeds() -> None:
    board = run_suite(["fan_dagger"], TINY, "test", progress=False)
    result = suite_result(board, TINY, "test")
    assert [r["policy"] for r in result["results"]] == ["fan_dagger", "fan_dagger"]
    for row in result["results"]:
        s = row["summary"]
        assert s["training_seeds"] == 3 and s["episodes"] == 3
        scenarios = FAMILIES[row["family"]].scenario_names
        per_seed = [float(np.mean([e["metrics"]["formation_error"]["mean"] for e in board.episodes
                                   if e["policy"] == f"fan_dagger:s{k}" and e["scenario"] in scenarios]))
                    for k in range(3)]
        assert s["formation_error"]["mean"] == pytest.approx(np.mean(per_seed))
        assert s["formation_error"]["n"] == 3


def test_the_shipped_leaderboard_is_the_standard_suite_for_every_shipped_policy() -> None:
    """docs/leaderboard: the standard suite's test split with every shipped method and the experts, and its
    suite.json is what the stored episodes (leaderboard.json.gz) score."""
    from pathlib import Path

    from swarm_env.harness.leaderboard import Leaderboard

    root = Path(__file__).resolve().parents[1] / "docs" / "leaderboard"
    result = json.loads((root / "suite.json").read_text())
    assert result["format"] == "swarm_env.suite_result/1"
    assert (result["suite"]["name"], result["suite"]["version"], result["suite"]["split"]) == ("standard", 3, "test")
    shipped = {p.name for p in (Path(__file__).resolve().parents[1] / "baselines" / "checkpoints").iterdir() if p.is_dir()}
    assert shipped | {"vo", "cbs_rrt", "obs_expert", "orca", "pursuit"} <= set(result["policies"])
    board = Leaderboard.from_json(root / "leaderboard.json.gz")
    again = suite_result(board, SUITES["standard"], "test")
    assert again["results"] == result["results"] and again["aggregate"] == result["aggregate"]
    assert all(r["status"] == "ok" for r in result["results"])  # nothing pending, nothing refused
