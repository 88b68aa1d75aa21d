"""Imitation learning: cached expert demonstrations, behaviour cloning into PPO's network, DAgger."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

import swarm_env_baselines.demos as demos_mod
from swarm_env.env import SwarmEnv
from swarm_env.harness.episode import run_episode
from swarm_env.harness.policies import load_policy, policy_defaults
from swarm_env_baselines.bc import (
    BCConfig,
    dagger_rollouts,
    discounted_returns,
    running_returns,
    split_episodes,
    train_bc,
)
from swarm_env_baselines.demos import ARRAYS, demo_path, generate_demos, load_demos
from swarm_env_baselines.model_io import load_model

TINY = {"n_followers": 2, "max_cycles": 30}
SEEDS = list(range(16))


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("demos")


@pytest.fixture(scope="module")
def demo_file(cache):
    return generate_demos("vo", "random", SEEDS, env_kwargs=TINY, cache_dir=cache, progress=False)


def _bc(cache, out, **overrides) -> BCConfig:
    fields = dict(
        expert="vo", scenario="random", env_kwargs=TINY, train_seeds="0-15", out=str(out), epochs=20, batch_size=64, learning_rate=3e-3,
        val_fraction=0.25, eval_seeds="", dagger_iters=0, cache_dir=str(cache), progress=False,
    )
    fields.update(overrides)
    return BCConfig(**fields)


@pytest.fixture(scope="module")
def bc_dir(cache, demo_file, tmp_path_factory):
    return train_bc(_bc(cache, tmp_path_factory.mktemp("bc")))


def _log(path) -> list[dict[str, float]]:
    with open(path / "bc_log.csv", newline="") as fh:
        return [{k: float(v) for k, v in row.items()} for row in csv.DictReader(fh)]


# --------------------------------------------------------------------------- demonstrations


def test_demos_record_every_present_agent_step(demo_file):
    d = load_demos(demo_file)
    meta = json.loads(demo_file.with_suffix(".json").read_text())
    assert d.n_episodes == len(SEEDS) and list(d.episode_seeds) == SEEDS
    assert len(d) == meta["n_transitions"] == len(SEEDS) * 2 * 30  # 2 followers x 30 steps, all truncated
    assert d.obs.dtype == np.float32 and d.actions.dtype == np.float32 and d.actions.shape == (len(d), 2)
    assert d.dones.sum() == len(SEEDS) * 2 and d.truncated.sum() == len(SEEDS) * 2
    # each agent-episode is one block of steps 0..29 closed by its done flag
    assert np.all(d.step[d.dones] == 29) and np.all(d.step[np.r_[True, d.dones[:-1]]] == 0)
    assert meta["request"]["expert"] == "vo" and meta["request"]["env_kwargs"] == TINY
    assert meta["summary"]["episodes"] == len(SEEDS) and len(meta["episodes"]) == len(SEEDS)
    # the expert's first action of seed 0 is what vo does from that state
    env = SwarmEnv("random", **TINY)
    obs, _ = env.reset(seed=0)
    expert = load_policy("vo", env)
    expert.reset(env, 0)
    first = expert.act(obs, env.world_state())
    row = np.flatnonzero((d.episode == 0) & (d.agent == 0) & (d.step == 0))[0]
    np.testing.assert_array_equal(d.obs[row], obs["follower_0"])
    np.testing.assert_array_equal(d.actions[row], first["follower_0"])


def test_demo_cache_hit_and_miss(tmp_path, monkeypatch, capsys):
    calls = []
    record = demos_mod._record_episode
    monkeypatch.setattr(demos_mod, "_record_episode", lambda *a: calls.append(a[-1]) or record(*a))
    first = generate_demos("vo", "random", [0, 1], env_kwargs=TINY, cache_dir=tmp_path, progress=False)
    mtime = first.stat().st_mtime_ns
    assert calls == [0, 1]
    again = generate_demos("vo", "random", [0, 1], env_kwargs=TINY, cache_dir=tmp_path, progress=False)
    assert again == first and first.stat().st_mtime_ns == mtime and calls == [0, 1]
    assert "reusing cached" in capsys.readouterr().err
    other = generate_demos("vo", "random", [0, 2], env_kwargs=TINY, cache_dir=tmp_path, progress=False)
    knob = generate_demos("vo", "random", [0, 1], env_kwargs={**TINY, "max_cycles": 20}, cache_dir=tmp_path, progress=False)
    assert len({first, other, knob}) == 3 and calls == [0, 1, 0, 2, 0, 1]
    assert len(load_demos(knob)) == 2 * 2 * 20


@pytest.mark.slow
def test_demos_with_two_workers_equal_one_worker(tmp_path, demo_file):
    two = load_demos(generate_demos("vo", "random", SEEDS, env_kwargs=TINY, cache_dir=tmp_path, workers=2, progress=False))
    one = load_demos(demo_file)
    for name in (*ARRAYS, "episode_seeds"):
        np.testing.assert_array_equal(getattr(two, name), getattr(one, name), err_msg=name)
    strip = lambda eps: [{k: v for k, v in e.items() if k not in ("wall_time", "policy_stats")} for e in eps]  # noqa: E731
    assert strip(two.meta["episodes"]) == strip(one.meta["episodes"])


def test_demos_cli(tmp_path, capsys):
    assert demos_mod.main(["--seeds", "0-1", "--env", "n_followers=2", "--env", "max_cycles=5", "--cache-dir", str(tmp_path), "--no-progress"]) == 0
    path = capsys.readouterr().out.strip()
    assert path.endswith(".npz") and len(load_demos(path)) == 2 * 2 * 5
    assert demos_mod.main(["--seeds", "3-1", "--cache-dir", str(tmp_path)]) == 2
    assert demos_mod.main(["--expert", "no_such_policy", "--seeds", "0", "--cache-dir", str(tmp_path)]) == 2
    assert "unknown policy 'no_such_policy'" in capsys.readouterr().err


# --------------------------------------------------------------------------- behaviour cloning


def test_returns_restart_at_episode_ends():
    r = np.array([1.0, 1.0, 1.0, 2.0, 2.0])
    done = np.array([False, False, True, False, True])
    np.testing.assert_allclose(discounted_returns(r, done, 0.5), [1.75, 1.5, 1.0, 3.0, 2.0])
    np.testing.assert_allclose(running_returns(r, done, 0.5), [1.0, 1.5, 1.75, 2.0, 3.0])


def test_split_is_by_episode_and_seeded():
    train, val = split_episodes(20, 0.25, seed=3)
    assert len(val) == 5 and not set(train) & set(val) and sorted([*train, *val]) == list(range(20))
    again = split_episodes(20, 0.25, seed=3)
    assert np.array_equal(again[1], val)


def test_bc_lowers_validation_nll_and_imitates_better_than_untrained(bc_dir):
    log = _log(bc_dir)
    untrained, final = log[0], log[-1]
    assert final["val_nll"] < untrained["val_nll"] - 0.3
    assert final["val_action_mse"] < 0.5 * untrained["val_action_mse"]  # held-out episodes
    # The value head fits its training returns; 4 held-out 30-step episodes are too few to ask it to
    # generalise (their return scale depends on the drawn world), so only its fit is checked here.
    first_fit = log[1]["train_value_loss"]
    assert final["train_value_loss"] < 0.25 * first_fit and np.isfinite(final["val_value_loss"])
    assert final["std"] >= 0.1 - 1e-6
    for name in ("model.zip", "vecnormalize.pkl", "bc_config.json", "learning_curve.png", "summary.json"):
        assert (bc_dir / name).is_file(), name
    config = json.loads((bc_dir / "bc_config.json").read_text())
    assert config["split"]["val_episodes"] == 4 and config["demos"]["n_transitions"] == len(SEEDS) * 60


def test_bc_normalisation_comes_from_the_demos(bc_dir, demo_file):
    _, vecnorm = load_model(bc_dir, trust_pickle=True)
    config = json.loads((bc_dir / "bc_config.json").read_text())
    d = load_demos(demo_file)
    train_rows = ~np.isin(d.episode_seeds[d.episode], config["split"]["val_seeds"])
    assert vecnorm.obs_rms.count == train_rows.sum()
    np.testing.assert_allclose(vecnorm.obs_rms.mean, d.obs[train_rows].astype(np.float64).mean(axis=0), rtol=1e-6, atol=1e-9)
    assert vecnorm.norm_obs and vecnorm.norm_reward and vecnorm.ret_rms.count == train_rows.sum()


def test_bc_same_seed_gives_identical_weights(cache, demo_file, bc_dir, tmp_path):
    again = train_bc(_bc(cache, tmp_path / "again"))
    a, _ = load_model(bc_dir, trust_pickle=True)
    b, _ = load_model(again, trust_pickle=True)
    sa, sb = a.policy.state_dict(), b.policy.state_dict()
    assert sa.keys() == sb.keys()
    assert all(np.array_equal(sa[k].numpy(), sb[k].numpy()) for k in sa)
    other = train_bc(_bc(cache, tmp_path / "other", seed=1, epochs=1))
    c, _ = load_model(other, trust_pickle=True)
    assert not np.array_equal(c.policy.state_dict()["action_net.weight"].numpy(), sa["action_net.weight"].numpy())


def test_bc_checkpoint_loads_as_a_policy_and_plays(bc_dir):
    env = SwarmEnv("random", **TINY)
    for spec in (f"bc:{bc_dir}", f"ppo:{bc_dir}"):
        result = run_episode(env, load_policy(spec, env), seed=123)
        assert result["steps"] == 30 and result["formation_error"]["mean"] is not None


def test_dagger_rollouts_label_the_visited_states_with_the_expert(bc_dir, demo_file):
    model, vecnorm = load_model(bc_dir, trust_pickle=True)
    labelled, metrics = dagger_rollouts(model, vecnorm, "vo", "random", [0, 100], env_kwargs=TINY)
    assert len(labelled) == 2 * 2 * 30 and len(metrics) == 2 and labelled.actions.dtype == np.float32
    # step 0 of seed 0 is the demo's start state, so the label is the expert's demo action there
    d = load_demos(demo_file)
    for agent in (0, 1):
        mine = np.flatnonzero((labelled.episode == 0) & (labelled.agent == agent) & (labelled.step == 0))[0]
        demo = np.flatnonzero((d.episode == 0) & (d.agent == agent) & (d.step == 0))[0]
        np.testing.assert_array_equal(labelled.obs[mine], d.obs[demo])
        np.testing.assert_array_equal(labelled.actions[mine], d.actions[demo])
    # later the learner, not the expert, drives: the visited states leave the demo's
    later = (labelled.episode == 0) & (labelled.step == 29)
    assert not np.array_equal(labelled.obs[later], d.obs[(d.episode == 0) & (d.step == 29)])


def test_dagger_iteration_adds_labelled_transitions(cache, demo_file, tmp_path):
    out = train_bc(_bc(cache, tmp_path / "dagger", epochs=3, dagger_iters=1, dagger_seeds="300-301", dagger_epochs=2, eval_seeds="500"))
    log = _log(out)
    base = [r for r in log if r["stage"] == 0][-1]["n_train"]
    assert [r["n_train"] for r in log if r["stage"] == 1] == [base + 2 * 60] * 2
    with open(out / "eval.csv", newline="") as fh:
        assert [row["stage"] for row in csv.DictReader(fh)] == ["0", "1"]


def test_bc_config_rejects_bad_input(cache, tmp_path):
    with pytest.raises(ValueError, match="disjoint"):
        _bc(cache, tmp_path, dagger_iters=1, dagger_seeds="10-20")
    with pytest.raises(ValueError, match="epochs"):
        _bc(cache, tmp_path, epochs=0)
    from swarm_env_baselines.bc import main

    assert main(["--out", str(tmp_path / "x"), "--expert", "nope", "--train-seeds", "0", "--cache-dir", str(cache), "--no-progress"]) == 2
    assert main(["--out", str(tmp_path / "x"), "--train-seeds", "0-399", "--cache-dir", str(cache)]) == 2  # overlaps dagger seeds


def test_demo_cache_key_follows_the_experts_defaults(monkeypatch):
    """Changing an expert's default parameters (here the ``vo`` expert's avoidance rules) changes the
    cache key, so demonstrations made with the earlier defaults are not reused; an explicit override
    in the spec is part of the key too."""
    import swarm_env_agents.vo_expert as vo_expert

    before = demo_path("vo", "random", [0, 1], env_kwargs=TINY)
    assert policy_defaults("vo")["move_first"] is vo_expert.EXPERT_AVOIDANCE["move_first"]
    assert policy_defaults("shield:vo") == policy_defaults("vo")
    assert policy_defaults("pursuit") == {}
    assert policy_defaults("cbs_rrt")["lookahead_time"] == 1.0
    monkeypatch.setattr(vo_expert, "EXPERT_AVOIDANCE", {**vo_expert.EXPERT_AVOIDANCE, "recip_gap": 0.3})
    assert demo_path("vo", "random", [0, 1], env_kwargs=TINY) != before
    monkeypatch.undo()
    assert demo_path("vo", "random", [0, 1], env_kwargs=TINY) == before
    assert demo_path("vo:recip_gap=0.3", "random", [0, 1], env_kwargs=TINY) != before
