"""The fan_dagger learner (swarm_env_baselines.fan_dagger, .fan_policy): the avoidance fan it reads, a tiny run end to
end, the policy it saves, determinism, a resumed run ending bit for bit as an uninterrupted one, bad files."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("safetensors")

from swarm_env.compiled import compiled_mode  # noqa: E402
from swarm_env.env import SwarmEnv  # noqa: E402
from swarm_env.harness.episode import run_episode  # noqa: E402
from swarm_env.harness.policies import OBSERVATIONS, ModelFileError, PolicyError, load_policy  # noqa: E402
from swarm_env_agents.obs_expert import ObservationExpert  # noqa: E402
from swarm_env_baselines import fan_dagger  # noqa: E402
from swarm_env_baselines.fan_policy import load_fan_policy  # noqa: E402

TINY_ENV = {"n_followers": 2, "n_obstacles": 1, "n_humans": 1, "max_cycles": 30}


def _cfg(tmp_path, **overrides) -> fan_dagger.FanDaggerConfig:
    base = dict(env_kwargs=dict(TINY_ENV), rounds=2, round_steps=20, n_worlds=3, epochs=2, batch_size=32,
                hidden=(16,), candidate_hidden=(8,), eval_seeds="500-501", eval_workers=0, torch_threads=1,
                runs_dir=str(tmp_path), run_name="tiny", progress=False)
    return fan_dagger.FanDaggerConfig(**{**base, **overrides})


def _episode_rows(env: SwarmEnv, expert: ObservationExpert, seed: int, steps: int) -> np.ndarray:
    obs, _ = env.reset(seed=seed)
    expert.reset(env, seed)
    rows = []
    for _ in range(steps):
        if not env.agents:
            break
        o = np.stack([np.asarray(v, np.float64) for v in obs.values()])
        rows.append(o)
        obs, *_ = env.step(dict(zip(obs, expert.act_rows(o))))
    return np.concatenate(rows)


@pytest.mark.slow
def test_the_fan_is_the_experts_own_and_the_same_compiled_or_not() -> None:
    """fan(): the compiled times to contact equal the numpy reference's bit for bit, the pick is act_rows' choice,
    and a candidate the expert picks is one it judged safe wherever any was (ttc >= t_safe)."""
    env = SwarmEnv("random", n_followers=4, n_humans=(2, 3))
    expert = ObservationExpert()
    rows = _episode_rows(env, expert, 40, 120)
    fast = expert.fan(rows)
    with compiled_mode(kernels=False):
        slow = expert.fan(rows)
    assert np.array_equal(fast.ttc, slow.ttc) and np.array_equal(fast.pick, slow.pick)
    assert np.array_equal(fast.pursuit, slow.pursuit)
    assert np.array_equal(expert.act_rows(rows), expert.candidates[fast.pick].astype(np.float32))
    some_safe = (fast.ttc >= expert.t_safe).any(axis=1)
    assert some_safe.any() and (fast.ttc[some_safe, fast.pick[some_safe]] >= expert.t_safe).all()
    assert (fast.ttc < expert.horizon).any()  # something was in the way on this episode
    with pytest.raises(ValueError, match=r"shape \(M, 52\)"):
        expert.fan(rows[:, :10])


def test_a_tiny_run_is_complete_and_plays_as_fan_dagger(tmp_path) -> None:
    run = fan_dagger.train(_cfg(tmp_path))
    for name in ("config.json", "versions.json", "policy.safetensors", "policy.json", "eval.csv", "train.csv",
                 "summary.json", "learning_curve.png", "checkpoint/state.json", "best/policy.json"):
        assert (run / name).is_file(), name
    rows = list(csv.DictReader(open(run / "train.csv")))
    assert [r["driver"] for r in rows] == ["teacher", "student"]
    assert [int(r["labels"]) for r in rows] == [120, 240]  # 20 steps x 3 worlds x 2 followers per round
    assert float(rows[0]["agree_own"]) == 1.0 and 0.0 <= float(rows[1]["agree_own"]) <= 1.0
    assert [int(r["agent_steps"]) for r in csv.DictReader(open(run / "eval.csv"))] == [120, 240]
    env = SwarmEnv("random", **TINY_ENV)
    policy = load_policy(f"fan_dagger:{run}/best", env)
    assert policy.acts_on == OBSERVATIONS
    result = run_episode(env, policy, seed=1000)
    assert result["steps"] == 30 and np.isfinite(result["formation_error"]["mean"])
    obs, _ = env.reset(seed=3)
    actions = policy.act(obs, None)  # the state is not read
    cand = policy.sensor.candidates
    assert all(any(np.allclose(a, c) for c in cand) for a in actions.values())
    with pytest.raises(PolicyError, match="trained on observations of"):
        load_policy(f"fan_dagger:{run}", SwarmEnv("random", **TINY_ENV, sensors={"lidar_rays": 8}))


@pytest.mark.slow
def test_the_same_seed_learns_the_same_network_and_a_resumed_run_ends_as_an_uninterrupted_one(tmp_path,
                                                                                             monkeypatch) -> None:
    from safetensors.numpy import load_file

    whole = fan_dagger.train(_cfg(tmp_path, run_name="whole", rounds=3))
    again = fan_dagger.train(_cfg(tmp_path, run_name="again", rounds=3))
    other = fan_dagger.train(_cfg(tmp_path, run_name="other", rounds=3, seed=1))
    a, b, c = (load_file(str(r / "policy.safetensors")) for r in (whole, again, other))
    assert all(np.array_equal(a[k], b[k]) for k in a)
    assert any(not np.array_equal(a[k], c[k]) for k in a)

    original = fan_dagger.collect
    calls = {"n": 0}

    def collect(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 3:  # in round 2, after the checkpoint of round 1
            raise RuntimeError("simulated crash")
        return original(*args, **kwargs)

    with monkeypatch.context() as m:
        m.setattr(fan_dagger, "collect", collect)
        with pytest.raises(RuntimeError, match="simulated crash"):
            fan_dagger.train(_cfg(tmp_path, run_name="parts", rounds=3))
    state = json.loads((tmp_path / "parts" / "checkpoint" / "state.json").read_text())
    assert state["rounds_done"] == 2
    fan_dagger.resume(tmp_path / "parts")
    parts = load_file(str(tmp_path / "parts" / "policy.safetensors"))
    assert all(np.array_equal(a[k], parts[k]) for k in a)
    def scores(run):  # eval.csv without its wall-clock column
        return [{k: v for k, v in r.items() if k != "wall_s"} for r in csv.DictReader(open(run / "eval.csv"))]

    assert scores(tmp_path / "parts") == scores(whole)
    with pytest.raises(ValueError, match="the run is complete"):
        fan_dagger.resume(tmp_path / "parts")
    with pytest.raises(ValueError, match="cannot change"):
        fan_dagger.resume(tmp_path / "parts", seed=4)


def test_bad_policy_files_are_refused_naming_the_file(tmp_path) -> None:
    run = fan_dagger.train(_cfg(tmp_path, rounds=1))
    env = SwarmEnv("random", **TINY_ENV)

    def edited(name: str, change) -> str:
        d = tmp_path / name
        d.mkdir()
        meta = json.loads((run / "policy.json").read_text())
        change(meta)
        (d / "policy.json").write_text(json.dumps(meta))
        (d / "policy.safetensors").write_bytes((run / "policy.safetensors").read_bytes())
        return str(d)

    cases = {
        "wide": (lambda m: m["config"].update(hidden=[10 ** 6]), "widths must be integers in 1-4096"),
        "deep": (lambda m: m["config"].update(hidden=[4] * 100), "1-8 layer widths"),
        "many": (lambda m: m["fan"].update(candidates=10 ** 9), "fan.candidates"),
        "option": (lambda m: m["fan"]["options"].update(bogus=1), "bogus"),
        "nan_rms": (lambda m: m["obs_rms"].update(mean=[float("nan")] * len(m["obs_rms"]["mean"])), "finite"),
        "shape": (lambda m: m["config"].update(hidden=[17]), "do not fit"),
    }
    for name, (change, message) in cases.items():
        with pytest.raises(ModelFileError, match=message):
            load_policy(f"fan_dagger:{edited(name, change)}", env)
    nan_dir = tmp_path / "nan"
    nan_dir.mkdir()
    (nan_dir / "policy.json").write_bytes((run / "policy.json").read_bytes())
    from safetensors.numpy import load_file, save_file

    tensors = load_file(str(run / "policy.safetensors"))
    first = next(k for k in tensors if k.startswith("trunk"))
    tensors[first] = np.full_like(tensors[first], np.nan)
    save_file(tensors, str(nan_dir / "policy.safetensors"))
    with pytest.raises(ValueError, match="not all finite"):
        load_fan_policy(nan_dir)
    with pytest.raises(ModelFileError, match="format"):
        load_policy(f"fan_dagger:{edited('mappo', lambda m: m.update(format='swarm_env.mappo/1'))}", env)


def test_bad_options_are_refused() -> None:
    for bad, message in (({"rounds": 0}, "rounds must be a positive int"), ({"teacher": {"n_v": 0}}, "n_v"),
                         ({"hidden": (0,)}, "hidden"), ({"teacher": {"nope": 1}}, "nope"),
                         ({"learning_rate": float("nan")}, "learning_rate")):
        with pytest.raises((ValueError, TypeError), match=message):
            fan_dagger.FanDaggerConfig(**bad)
