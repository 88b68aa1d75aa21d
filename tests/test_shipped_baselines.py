"""The shipped checkpoints (baselines/checkpoints/<method>/s<k>: the methods of :mod:`swarm_env_baselines.mappo`,
the SB3 baseline ``sb3_ppo`` and ``fan_dagger``, three training seeds each) are clean, safe and documented, and their test episodes in
``docs/leaderboard/random/leaderboard.json`` (the 50 held-out random worlds) replay bit for bit. The v0 SB3 checkpoints are retired.

A learned policy's actions come from torch's CPU kernels, whose last bits depend on the CPU
(``tests/_numerics.py``): on a machine whose numerics differ from the leaderboard's, the replays are compared
with ``tests/data/learned_replays.json``, the same episodes recorded on such a machine (``python
tests/test_shipped_baselines.py`` adds this machine's).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

pytest.importorskip("stable_baselines3")

from _numerics import fingerprint  # noqa: E402

from swarm_env.env import SwarmEnv  # noqa: E402
from swarm_env.harness.episode import run_episode  # noqa: E402
from swarm_env.harness.leaderboard import _behaviour, _json_roundtrip  # noqa: E402
from swarm_env.harness.policies import PolicyError, load_policy  # noqa: E402
from swarm_env_baselines.mappo_policy import CHECKPOINTS, SHIPPED_SEEDS  # noqa: E402

#: The methods of swarm_env_baselines.mappo, one directory per training seed.
MAPPO_METHODS = ("ippo", "mappo", "mappo_shielded", "residual_vo")
#: The methods trained by ``swarm-env train sb3`` (their training log is SB3's ``progress.csv``).
SB3_METHODS = ("sb3_ppo",)
#: The methods of swarm_env_baselines.fan_dagger.
FAN_METHODS = ("fan_dagger",)
METHODS = MAPPO_METHODS + SB3_METHODS + FAN_METHODS
LEADERBOARD = CHECKPOINTS.parents[1] / "docs" / "leaderboard" / "random" / "leaderboard.json"
#: The replayed episodes recorded on machines whose numerics differ from the leaderboard's: fingerprint -> spec -> metrics.
REPLAYS = Path(__file__).resolve().parent / "data" / "learned_replays.json"
#: The replayed episodes: seeds s0 and s2 of every method on test world 1000.
REPLAYED = [f"{m}:s{k}" for m in (*METHODS, "mappo_shielded_bare", "fan_dagger_shielded") for k in (0, 2)]


def test_only_the_methods_are_shipped_and_no_pickles():
    assert sorted(p.name for p in CHECKPOINTS.iterdir() if p.is_dir()) == sorted(METHODS)
    assert not [p for p in CHECKPOINTS.rglob("*") if p.suffix in (".pkl", ".zip", ".pt")]


@pytest.mark.parametrize("name", ["ppo", "bc"])
def test_a_retired_v0_name_says_what_to_use_instead(name):
    with pytest.raises(PolicyError, match="retired.*mappo"):
        load_policy(name, SwarmEnv("random"))


@pytest.mark.parametrize("method", METHODS)
def test_a_shipped_method_has_three_clean_safe_seeds(method):
    readme = (CHECKPOINTS / method / "README.md").read_text()
    # The MAPPO methods were trained before the rename (ship.training_command), the others with the command.
    command = ("swarm-env train sb3" if method in SB3_METHODS else "swarm-env train fan_dagger"
               if method in FAN_METHODS else "python -m baselines.mappo")
    assert command in readme and "| s2 |" in readme
    log = "progress.csv" if method in SB3_METHODS else "train.csv"
    for seed in SHIPPED_SEEDS:
        d = CHECKPOINTS / method / seed
        files = {p.name for p in d.iterdir()}
        assert {"policy.safetensors", "policy.json", "config.json", "versions.json", "eval.csv", log} <= files
        assert not {f for f in files if f.endswith((".pkl", ".zip", ".pt"))}  # tensors + JSON only
        versions = json.loads((d / "versions.json").read_text())
        assert versions["git_dirty"] is False and len(versions["git_commit"]) == 40
        config = json.loads((d / "config.json").read_text())
        assert config["seed"] == int(seed[1:]) and config["eval_seeds"] == "500-549"  # selection off the test seeds
        assert json.loads((d / "summary.json").read_text())["wall_s"] < 3600  # the 60 min budget


def _stored_test_episodes() -> dict[tuple[str, int], dict]:
    """``(spec, seed) -> metrics`` of the leaderboard's random episodes, or of the replays recorded on a machine
    with this one's numerics."""
    here = json.loads(REPLAYS.read_text()).get(fingerprint()) if REPLAYS.exists() else None
    if here is not None:
        return {(spec, 1000): metrics for spec, metrics in here.items()}
    doc = json.loads(LEADERBOARD.read_text())
    return {(e["policy"], e["seed"]): e["metrics"] for e in doc["episodes"] if e["scenario"] == "random"}


@pytest.mark.parametrize("spec", REPLAYED)
@pytest.mark.slow
def test_a_shipped_method_replays_its_leaderboard_episode_bit_for_bit(spec):
    stored = _stored_test_episodes().get((spec, 1000))
    if stored is None:  # a method shipped after this machine's replays were recorded
        pytest.skip(f"{spec}: no replay recorded for this machine's numerics ({fingerprint()}); see the module docstring")
    env = SwarmEnv("random")
    played = run_episode(env, load_policy(spec, env), seed=1000)
    # _behaviour: every metric but the timings, compared as the JSON file stores them
    assert _json_roundtrip(_behaviour(played)) == _json_roundtrip(_behaviour(stored))


if __name__ == "__main__":  # record this machine's replays (from a commit whose replays pass on the leaderboard's)
    from swarm_env.jsonio import write_json

    data = json.loads(REPLAYS.read_text()) if REPLAYS.exists() else {}
    env = SwarmEnv("random")
    data[fingerprint()] = {spec: _json_roundtrip(_behaviour(run_episode(env, load_policy(spec, env), seed=1000)))
                           for spec in REPLAYED}
    write_json(REPLAYS, data, indent=1)
    print(f"wrote {REPLAYS}")
