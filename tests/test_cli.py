"""The swarm-env command line: list, validate, run (JSON + video), bench."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import imageio.v2 as imageio
import pytest

from swarm_env.harness.cli import main

GOOD = """\
world: {size: [10, 8], dt: 0.1, substeps: 4, max_time: 5.0}
robots: {count: 2, radius: 0.25, max_speed: 0.65, max_turn_rate: 1.0}
leader: {kind: virtual, path: [[2, 4], [8, 4]], speed: 0.4}
formations:
  - {at: 0.0, shape: v, spacing: 1.0, angle: 45}
"""


def test_list_shows_scenarios_and_policies(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    for name in ("paper_vo_0", "paper_cbs_switch", "corridor", "random", "zero"):
        assert name in out
    lines = {line.split()[0]: line for line in out.splitlines() if line.startswith("  ")}
    # one line each, what the policy does (not where its code lives), no Sphinx markup
    assert "sampled velocity obstacles" in lines["vo"] and "CBS + motion-primitive RRT" in lines["cbs_rrt"]
    assert all(len(line) <= 100 and ":class:" not in line and "swarm_env_agents" not in line for line in out.splitlines())


@pytest.mark.slow
def test_console_script_is_installed() -> None:
    exe = shutil.which("swarm-env")
    assert exe, "the swarm-env console script is not on PATH (pip install -e .)"
    out = subprocess.run([exe, "list"], capture_output=True, text=True, check=True).stdout
    assert "paper_vo_45" in out


def test_validate_good_and_bad_files(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    good = tmp_path / "good.yaml"
    good.write_text(GOOD)
    assert main(["validate", str(good)]) == 0
    assert "ok: good" in capsys.readouterr().out
    bad = tmp_path / "bad.yaml"
    bad.write_text(GOOD.replace("max_speed", "max_sped"))
    assert main(["validate", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "bad.yaml" in err and "max_sped" in err


def test_validate_reports_every_error_and_accepts_random(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text(GOOD.replace("max_speed", "max_sped").replace("radius: 0.25", "radius: -0.25")
                   .replace("shape: v", "shape: vee"))
    assert main(["validate", str(bad), "random", "paper_vo_0"]) == 2
    captured = capsys.readouterr()
    lines = captured.err.splitlines()
    assert len(lines) == 3 and all(line.startswith(f"error: {bad}: ") for line in lines), lines
    assert [line.split(": ")[2] for line in lines] == ["robots.max_sped", "robots.radius", "formations[0].shape"]
    assert "ok: random (the generator" in captured.out and "ok: paper_vo_0" in captured.out


def test_run_shows_policy_stats_as_a_table_and_video_progress(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    import swarm_env.harness.cli as cli

    argv = ["run", "--scenario", "paper_vo_45", "--policy", "vo", "--max-cycles", "5", "--video", str(tmp_path / "v.mp4")]
    assert main(argv) == 0  # not at a terminal (pytest captures stderr): no progress bar
    captured = capsys.readouterr()
    assert "frame" not in captured.err
    lines = captured.out.splitlines()
    head = lines.index(next(line for line in lines if line.startswith("policy stat ")))
    assert lines[head].split() == ["policy", "stat", "value"] and set(lines[head + 1].replace(" ", "")) == {"-"}
    rows = {line.split()[0]: line.split(None, 1)[1] for line in lines[head + 2 : head + 7]}
    assert rows["decision_time_ms"].startswith("median=") and "calls=5" in rows["decision_time_ms"]
    assert set(rows) == {"decision_time_ms", "infeasible_events", "infeasible_rate", "escape_turns", "reverse_steps"}
    assert max(len(line) for line in lines[head : head + 7]) < 100  # a small table, not one long JSON line

    monkeypatch.setattr(cli, "_interactive", lambda: True)  # as at a terminal
    assert main(argv + ["--overwrite"]) == 0  # v.mp4 exists now: replaced only on request
    err = capsys.readouterr().err
    assert "video v.mp4" in err and "6/6" in err and "frame" in err  # the reset frame + 5 steps, bar at 100 %


@pytest.mark.slow
def test_run_writes_json_and_video(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out_json, out_video = tmp_path / "out.json", tmp_path / "out.mp4"
    code = main(["run", "--scenario", "paper_vo_0", "--policy", "random", "--episodes", "2", "--seed", "0",
                 "--json", str(out_json), "--video", str(out_video)])
    assert code == 0
    printed = capsys.readouterr().out
    assert "follower_1" in printed and "time to target" in printed  # the per-robot table
    assert f"wrote {out_video} (20 fps, one frame per 0.1 s step: 2x real time)" in printed
    doc = json.loads(out_json.read_text())
    assert doc["scenario"] == "paper_vo_0" and doc["policy"] == "random"
    assert [e["seed"] for e in doc["episodes"]] == [0, 1]
    assert doc["summary"]["episodes"] == 2
    steps = sum(e["steps"] for e in doc["episodes"])
    with imageio.get_reader(str(out_video)) as reader:
        frames = sum(1 for _ in reader)  # (len() of an ffmpeg reader is inf)
    assert frames == steps + 2  # one initial frame per episode


def test_run_from_a_yaml_path_and_zero_policy(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "mine.yaml"
    path.write_text(GOOD)
    assert main(["run", "--scenario", str(path), "--policy", "zero"]) == 0
    assert "mine" in capsys.readouterr().out


def test_run_rejects_unknown_policy_and_scenario(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["run", "--scenario", "paper_vo_0", "--policy", "no_such_policy"]) == 2
    assert "registered policies" in capsys.readouterr().err
    assert main(["run", "--scenario", "no_such_scenario"]) == 2
    assert "no_such_scenario" in capsys.readouterr().err


def test_bench_runs_and_reports(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    out = tmp_path / "bench.json"
    assert main(["bench", "--scenario", "paper_vo_0", "--steps", "50", "--repeats", "2", "--quiet", "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "env-steps/s" in printed
    doc = json.loads(out.read_text())
    assert len(doc[0]["env_steps_per_s"]) == 2 and all(x > 0 for x in doc[0]["env_steps_per_s"])


def test_bench_against_mpe2_prints_a_ratio(capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("mpe2")
    assert main(["bench", "--scenario", "paper_vo_0", "--steps", "30", "--repeats", "1", "--vs", "mpe2", "--quiet"]) == 0
    assert "ratio" in capsys.readouterr().out


def test_module_entry_point() -> None:
    out = subprocess.run([sys.executable, "-m", "swarm_env.harness.cli", "validate", "paper_vo_90"], capture_output=True,
                         text=True)
    assert out.returncode == 0 and "ok: paper_vo_90" in out.stdout


def test_run_human_render_under_the_dummy_driver(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["run", "--scenario", "corridor", "--policy", "zero", "--render", "human", "--max-cycles", "5"]) == 0
    assert "steps=5" in capsys.readouterr().out


def test_run_discrete_actions_and_bad_numbers(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["run", "--scenario", "paper_vo_90", "--policy", "random", "--action-type", "discrete",
                 "--max-cycles", "20"]) == 0
    capsys.readouterr()
    for argv, says in ((["run", "--episodes", "0"], "argument --episodes: expected an integer >= 1, got 0"),
                       (["run", "--seed", "-1"], "argument --seed: expected an integer >= 0, got -1"),
                       (["run", "--seed", "x"], "argument --seed: expected an integer, got 'x'"),
                       (["run", "--fps", "nan"], "argument --fps: expected a finite number > 0, got nan"),
                       (["evaluate", "--policies", "vo", "--workers", "0"], "argument --workers: expected an integer >= 1"),
                       (["bench", "--repeats", "-3"], "argument --repeats: expected an integer >= 1, got -3")):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert says in err and "Traceback" not in err, err
    assert main(["run", "--help"]) == 0


def test_reset_refuses_a_negative_seed() -> None:
    from swarm_env.env import SwarmEnv

    env = SwarmEnv("paper_vo_0")
    for bad in (-1, 1.5, "3", True):
        with pytest.raises(ValueError, match="seed must be None or an integer >= 0"):
            env.reset(seed=bad)
    env.reset(seed=0)


def test_run_rejects_a_bad_policy_argument(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["run", "--scenario", "paper_vo_0", "--policy", "pursuit:fast", "--max-cycles", "2"]) == 2
    err = capsys.readouterr().err
    assert "policy 'pursuit'" in err and "'fast'" in err


def test_run_takes_env_keyword_arguments_and_generator_knobs(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "run.json"
    code = main(["run", "--scenario", "random", "--policy", "pursuit", "--max-cycles", "5", "--json", str(out),
                 "--env", "n_followers=6", "--env", "n_humans=[0,1]", "--env", "reward=v0"])
    assert code == 0
    episode = json.loads(out.read_text())["episodes"][0]
    assert len(episode["per_robot"]) == 6 + 1  # the leader and 6 followers
    capsys.readouterr()
    assert main(["run", "--scenario", "paper_vo_0", "--env", "n_followers=6", "--max-cycles", "2"]) == 2
    assert "generator knobs apply to 'random' only" in capsys.readouterr().err
    assert main(["run", "--scenario", "random", "--env", "n_followers", "--max-cycles", "2"]) == 2
    assert "--env expects KEY=VALUE" in capsys.readouterr().err
    assert main(["run", "--scenario", "random", "--env", "n_followers=99", "--max-cycles", "2"]) == 2
    assert "n_followers: expected values in [1, 64]" in capsys.readouterr().err


def test_evaluate_applies_generator_knobs_to_random_only(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    code = main(["evaluate", "--policies", "pursuit", "--scenarios", "random", "paper_vo_0", "--seeds", "0",
                 "--max-cycles", "5", "--env", "n_followers=3", "--env", "terminate_on_collision=true",
                 "--out", str(tmp_path), "--quiet"])
    assert code == 0
    rows = json.loads((tmp_path / "leaderboard.json").read_text())
    text = json.dumps(rows)
    assert '"random"' in text and '"paper_vo_0"' in text
    assert main(["evaluate", "--policies", "pursuit", "--scenarios", "random", "--seeds", "0",
                 "--env", "n_followers=0"]) == 2


def test_names_get_a_did_you_mean(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["run", "--policy", "vvo", "--max-cycles", "2"]) == 2
    assert "unknown policy 'vvo' (did you mean 'vo'?)" in capsys.readouterr().err
    assert main(["run", "--scenario", "coridor", "--max-cycles", "2"]) == 2
    assert "(did you mean 'corridor'?)" in capsys.readouterr().err
    assert main(["evaluate", "--policies", "vo", "--scenarios", "randm", "--scenario-seeds", "random=1000"]) == 2
    err = capsys.readouterr().err
    assert "randm" in err and "(did you mean 'random'?)" in err and "--scenario-seeds" not in err  # the typo, not the seeds
    assert main(["run", "--scenario", "random:crowdd", "--max-cycles", "2"]) == 2
    assert "(did you mean 'crowd'?)" in capsys.readouterr().err


def test_evaluate_fails_on_a_bad_model_before_any_output(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "lb"
    assert main(["evaluate", "--policies", "vo", f"mappo:{tmp_path / 'nothing'}", "--scenarios", "paper_vo_0",
                 "--seeds", "0", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "no such directory" in err and "leaderboard:" not in err  # no progress bar was drawn
    assert not out.exists()  # nothing left behind to block the next run


def test_evaluate_warns_about_knobs_a_fixed_scenario_ignores(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["evaluate", "--policies", "zero", "--scenarios", "random", "paper_vo_0", "--seeds", "0",
                 "--env", "n_humans=1", "--max-cycles", "2", "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "warning: --env n_humans: generator knobs apply to the generated scenarios only; ignored for paper_vo_0" in err


def test_render_human_without_a_display_fails(tmp_path: Path) -> None:
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY", "SDL_VIDEODRIVER")}
    done = subprocess.run([sys.executable, "-m", "swarm_env.harness.cli", "run", "--render", "human", "--max-cycles", "2"],
                          capture_output=True, text=True, env=env, cwd=tmp_path, timeout=300)
    assert done.returncode == 2, done.stderr
    assert done.stderr.count("\n") == 1 and done.stderr.startswith("error: --render human needs a display")


def test_validate_echoes_no_content_of_a_file_that_is_not_a_scenario(tmp_path: Path,
                                                                         capsys: pytest.CaptureFixture[str]) -> None:
    # A password file parses as a YAML mapping ("user:hash:..." keys): one line, none of its keys shown.
    secret = tmp_path / "shadow"
    secret.write_text("".join(f"user{i}:$6$secret{i}:20228:0:99999:7:::\n" for i in range(24)))
    link = tmp_path / "scenario.yaml"
    link.symlink_to(secret)
    assert main(["validate", str(link)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "none of this mapping's 24 keys is a scenario section" in err
    assert "secret" not in err


def test_validate_shows_at_most_ten_problems_and_counts_the_rest(tmp_path: Path,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "many.yaml"
    bad.write_text("world: {size: [10, 10]}\n" + "".join(f"k{i:02d}: {i}\n" for i in range(30)))
    assert main(["validate", str(bad)]) == 2
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 11, lines  # 30 unknown keys + 3 missing sections: 10 shown, then the count
    assert lines[0].endswith("got 'k00'") and lines[-1].endswith("... and 23 more problems")


@pytest.mark.parametrize("command", [["run"], ["evaluate"], ["bench"], ["replay"], ["train", "mappo"], ["bc"]])
def test_every_help_shows_the_defaults(command: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) if command[0] in ("train", "bc") else contextlib.nullcontext():
        assert main([*command, "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "(default: " in text
    if command == ["run"]:
        assert "--fps FPS video frames per second; one frame per env step" in text and "(default: 20.0)" in text
        assert "(default: False)" not in text and "(default: None)" not in text


def test_evaluate_and_bench_take_the_one_no_progress_spelling(capsys: pytest.CaptureFixture[str]) -> None:
    for flag in ("--no-progress", "--quiet"):  # --quiet: the older spelling, still accepted
        assert main(["evaluate", "--policies", "zero", "--scenarios", "paper_vo_0", "--seeds", "0", "--max-cycles", "3",
                     flag]) == 0
        assert "leaderboard:" not in capsys.readouterr().err  # no bar
