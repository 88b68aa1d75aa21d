"""Model files are safe by default, and a bad model file is one clear line (issue 14, items 1 and 6).

Loading never unpickles without the opt-in (``trust_pickle=True``, ``SWARM_ENV_TRUST_PICKLE=1``,
``--trust-pickle``): a poisoned ``model.zip`` or ``vecnormalize.pkl`` is refused and its payload
(which writes a marker file) never runs; with the opt-in, legacy directories still load (and the
payload does run: the poison is real). Truncated, corrupt and mismatched files of the SB3 loaders
(``ppo:``/``sac:``/``bc:``), of the MAPPO family and of ``rllib:`` are a ``ModelFileError`` naming
the file; the CLI prints one line and exits with code 2.
"""

from __future__ import annotations

import base64
import json
import os
import pickle
import shutil
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")
pytest.importorskip("safetensors")

from swarm_env.env import SwarmEnv  # noqa: E402
from swarm_env.harness import cli  # noqa: E402
from swarm_env.harness.episode import run_episode  # noqa: E402
from swarm_env.harness.policies import TRUST_PICKLE_ENV, ModelFileError, PolicyError, load_policy, pickle_trusted  # noqa: E402
from swarm_env_baselines import convert, model_io, safe_io  # noqa: E402
from swarm_env_baselines import train as train_mod  # noqa: E402
from swarm_env_baselines.mappo_policy import shipped_run  # noqa: E402
from tests.test_safe_io import _Payload  # noqa: E402
from tests.test_train import TINY_ENV, _tiny  # noqa: E402


@pytest.fixture(autouse=True)
def _no_ambient_trust(monkeypatch):
    """Every test starts without the opt-in, whatever the shell that runs pytest has set."""
    monkeypatch.delenv(TRUST_PICKLE_ENV, raising=False)


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    return train_mod.train(_tiny(tmp_path_factory.mktemp("runs"), eval_every=0, checkpoint_every=0))


def _legacy(run: Path, where: Path) -> Path:
    """A copy of ``run`` as an older run directory: model.zip + vecnormalize.pkl, no safe pair."""
    shutil.copytree(run, where)
    for name in (safe_io.WEIGHTS_FILE, safe_io.CONFIG_FILE):
        (where / name).unlink()
    return where


def _poison_zip(path: Path, marker: Path) -> None:
    """Rewrite ``path``'s ``data`` so that its ``policy_class`` unpickles into the payload (its readable
    ``__module__`` kept, as an attacker would keep it, so that only unpickling can tell)."""
    with zipfile.ZipFile(path) as archive:
        members = {name: archive.read(name) for name in archive.namelist()}
    data = json.loads(members["data"])
    data["policy_class"][":serialized:"] = base64.b64encode(pickle.dumps(_Payload(str(marker)))).decode()
    members["data"] = json.dumps(data).encode()
    with zipfile.ZipFile(path, "w") as archive:
        for name, content in members.items():
            archive.writestr(name, content)


def _env(**overrides) -> SwarmEnv:
    return SwarmEnv("random", **{**TINY_ENV, **overrides})


def _cli_run(spec: str, capsys, *extra: str) -> tuple[int, str]:
    code = cli.main(["run", "--scenario", "random", "--policy", spec, "--max-cycles", "5",
                     *[a for k, v in TINY_ENV.items() if k != "max_cycles" for a in ("--env", f"{k}={json.dumps(v)}")],
                     *extra])
    return code, capsys.readouterr().err


# --------------------------------------------------------------------------- item 1: safe by default


def test_the_opt_in_is_explicit(monkeypatch) -> None:
    assert not pickle_trusted()
    for value, trusted in (("1", True), ("YES", True), ("true", True), ("0", False), ("", False), ("no", False)):
        monkeypatch.setenv(TRUST_PICKLE_ENV, value)
        assert pickle_trusted() is trusted
    assert pickle_trusted(False) is False  # an explicit answer wins over the environment
    monkeypatch.delenv(TRUST_PICKLE_ENV)
    assert pickle_trusted(True) is True


def test_a_poisoned_model_zip_is_refused_without_running_its_payload(run, tmp_path, capsys) -> None:
    d = _legacy(run, tmp_path / "evil")
    marker = tmp_path / "payload_ran"
    _poison_zip(d / model_io.MODEL_FILE, marker)
    with pytest.raises(ModelFileError, match=r"model\.zip: loading it would unpickle .* refused"):
        load_policy(f"ppo:{d}", _env())
    with pytest.raises(ModelFileError, match="refused"):
        load_policy(f"bc:{d / model_io.MODEL_FILE}", _env())
    with pytest.raises(ModelFileError, match="refused"):
        model_io.load_model(d)
    code, err = _cli_run(f"ppo:{d}", capsys)
    assert code == 2 and err.count("\n") == 1 and str(d / model_io.MODEL_FILE) in err and "--trust-pickle" in err
    assert not marker.exists()
    # The poison is real: with the opt-in the payload runs (and SB3 then fails on what it built).
    with pytest.raises(ModelFileError, match="could not load it"):
        model_io.load_model(d, trust_pickle=True)
    assert marker.exists()


def test_a_poisoned_statistics_file_is_refused_without_running_its_payload(run, tmp_path) -> None:
    marker = tmp_path / "payload_ran"
    d = _legacy(run, tmp_path / "evil")
    (d / model_io.VECNORM_FILE).write_bytes(pickle.dumps(_Payload(str(marker))))
    with pytest.raises(ModelFileError, match="refused"):
        load_policy(f"ppo:{d}", _env())
    # A warm start reads model.zip's tensors safely but would have to unpickle the statistics.
    with pytest.raises(ModelFileError, match=r"vecnormalize\.pkl: loading it would unpickle"):
        model_io.load_warm_start(d, "ppo")
    assert train_mod.main(["--init-from", str(d), "--runs-dir", str(tmp_path / "runs"), "--total-steps", "64",
                           "--no-progress"]) == 2
    assert not marker.exists()
    # Beside the safe pair the pickle is never read, for scoring or for a warm start.
    beside = tmp_path / "beside"
    shutil.copytree(run, beside)
    (beside / model_io.VECNORM_FILE).write_bytes(pickle.dumps(_Payload(str(marker))))
    assert run_episode(_env(), load_policy(f"ppo:{beside}", _env()), seed=1000)["steps"] == 30
    weights, obs_rms, ret_rms = model_io.load_warm_start(beside, "ppo")
    assert weights and obs_rms is not None and ret_rms is not None
    assert not marker.exists()
    with pytest.raises(ModelFileError, match="not SB3's VecNormalize"):  # the poison is real
        model_io.load_warm_start(d, "ppo", trust_pickle=True)
    assert marker.exists()


def test_the_opt_in_still_loads_legacy_directories(run, tmp_path, capsys, monkeypatch) -> None:
    d = _legacy(run, tmp_path / "old")
    model, vecnorm = model_io.load_model(d, trust_pickle=True)
    assert vecnorm is not None and model.observation_space.shape == (52,)
    code, err = _cli_run(f"ppo:{d}", capsys, "--trust-pickle")
    assert code == 0, err
    assert TRUST_PICKLE_ENV not in os.environ  # the CLI's opt-in ends with the command
    monkeypatch.setenv(TRUST_PICKLE_ENV, "1")
    assert run_episode(_env(), load_policy(f"ppo:{d}", _env()), seed=1000)["steps"] == 30
    weights, obs_rms, _ = model_io.load_warm_start(d, "ppo")
    np.testing.assert_array_equal(obs_rms.mean, vecnorm.obs_rms.mean)
    for k, v in model.policy.state_dict().items():
        np.testing.assert_array_equal(weights[k].numpy(), v.numpy())


def test_the_converter_asks_for_the_opt_in(run, tmp_path, capsys) -> None:
    d = _legacy(run, tmp_path / "old")
    assert convert.main([str(d)]) == 2
    assert "refused" in capsys.readouterr().err and not safe_io.has_safe_policy(d)
    assert convert.main([str(d), "--trust-pickle"]) == 0 and safe_io.has_safe_policy(d)
    assert run_episode(_env(), load_policy(f"ppo:{d}", _env()), seed=1000)["steps"] == 30  # no opt-in needed now


def test_a_warm_start_needs_no_pickle_and_matches_the_trusted_one(run, tmp_path) -> None:
    """The safe pair holds all a warm start takes: the same tensors and statistics as the pickles."""
    model, vecnorm = model_io.load_model(run, trust_pickle=True)
    weights, obs_rms, ret_rms = model_io.load_warm_start(run, "ppo")
    for k, v in model.policy.state_dict().items():
        np.testing.assert_array_equal(weights[k].numpy(), v.numpy())
    np.testing.assert_array_equal(obs_rms.mean, vecnorm.obs_rms.mean)
    np.testing.assert_array_equal(obs_rms.var, vecnorm.obs_rms.var)
    assert obs_rms.count == vecnorm.obs_rms.count and ret_rms.var == vecnorm.ret_rms.var
    with pytest.raises(ModelFileError, match="holds a ppo policy, not a sac one"):
        model_io.load_warm_start(run, "sac")


# --------------------------------------------------------------------------- item 6: clear errors


def test_bad_sb3_files_are_one_line_errors_naming_the_file(run, tmp_path, capsys) -> None:
    d = _legacy(run, tmp_path / "bad")
    zip_path = d / model_io.MODEL_FILE
    whole = zip_path.read_bytes()
    # a PPO archive given to sac: found from its plain-text fields, before any opt-in or unpickling
    for trust in (False, True):
        with pytest.raises(ModelFileError, match=r"holds a ppo/a2c model \(its policy is from stable_baselines3.common.policies\), not a sac one"):
            model_io.load_model(d, "sac", trust_pickle=trust)
    code, err = _cli_run(f"sac:{d}", capsys, "--trust-pickle")
    assert code == 2 and err.count("\n") == 1 and str(zip_path) in err
    # truncated, with or without the opt-in
    zip_path.write_bytes(whole[: len(whole) // 2])
    for trust in (False, True):
        with pytest.raises(ModelFileError, match=r"model\.zip: not a readable stable-baselines3 model archive, truncated"):
            model_io.load_model(d, trust_pickle=trust)
    code, err = _cli_run(f"ppo:{d}", capsys, "--trust-pickle")
    assert code == 2 and err.count("\n") == 1 and "truncated or corrupt" in err
    # not a zip at all; a zip without SB3's data
    zip_path.write_bytes(b"PK\x03\x04 not really")
    with pytest.raises(ModelFileError, match="truncated or corrupt"):
        model_io.load_warm_start(d, "ppo")
    with zipfile.ZipFile(zip_path, "w") as archive:
        archive.writestr("hello.txt", "hi")
    with pytest.raises(ModelFileError, match="no 'data' member"):
        model_io.load_model(d, trust_pickle=True)
    # a corrupt statistics pickle (the archive whole again)
    zip_path.write_bytes(whole)
    (d / model_io.VECNORM_FILE).write_bytes(b"\x80\x04garbage")
    with pytest.raises(ModelFileError, match=r"vecnormalize\.pkl: not a readable VecNormalize pickle"):
        model_io.load_model(d, trust_pickle=True)
    code, err = _cli_run(f"ppo:{d}", capsys, "--trust-pickle")
    assert code == 2 and err.count("\n") == 1 and str(d / model_io.VECNORM_FILE) in err


def test_a_legacy_model_that_does_not_fit_the_env_is_named(run, tmp_path, monkeypatch) -> None:
    d = _legacy(run, tmp_path / "old")
    monkeypatch.setenv(TRUST_PICKLE_ENV, "1")
    with pytest.raises(PolicyError, match=r"trained on observations of shape \(52,\), this env gives"):
        load_policy(f"ppo:{d}", _env(sensors={"lidar_rays": 8}))
    with pytest.raises(PolicyError, match="acts in"):
        load_policy(f"ppo:{d}", _env(action_type="discrete"))


def test_bad_safe_pair_files_are_one_line_errors(run, tmp_path, capsys) -> None:
    d = tmp_path / "bad"
    shutil.copytree(run, d)
    weights = (d / safe_io.WEIGHTS_FILE).read_bytes()
    (d / safe_io.WEIGHTS_FILE).write_bytes(weights[: len(weights) // 2])
    with pytest.raises(ModelFileError, match=r"policy\.safetensors: not a readable safetensors file, truncated"):
        load_policy(f"ppo:{d}", _env())
    code, err = _cli_run(f"ppo:{d}", capsys)
    assert code == 2 and err.count("\n") == 1 and str(d / safe_io.WEIGHTS_FILE) in err
    (d / safe_io.WEIGHTS_FILE).write_bytes(weights)
    config = (d / safe_io.CONFIG_FILE).read_text()
    (d / safe_io.CONFIG_FILE).write_text(config[: len(config) // 2])
    with pytest.raises(ModelFileError, match=r"policy\.json: not a readable JSON policy description"):
        load_policy(f"ppo:{d}", _env())
    (d / safe_io.CONFIG_FILE).write_text(config.replace('"MlpPolicy"', '"x"').replace('"net_arch"', '"no_such_kwarg"'))
    with pytest.raises(ModelFileError, match="not a policy description this version can rebuild"):
        load_policy(f"ppo:{d}", _env())
    (d / safe_io.CONFIG_FILE).unlink()
    (d / model_io.MODEL_FILE).unlink()
    with pytest.raises(ModelFileError, match="has policy.safetensors but not policy.json"):
        load_policy(f"ppo:{d}", _env())


def test_bad_mappo_family_files_are_one_line_errors(tmp_path, capsys) -> None:
    d = tmp_path / "mappo"
    shutil.copytree(shipped_run("mappo", "s0"), d)
    weights = (d / "policy.safetensors").read_bytes()
    (d / "policy.safetensors").write_bytes(weights[:100])
    with pytest.raises(ModelFileError, match=r"policy\.safetensors: not a readable safetensors file"):
        load_policy(f"mappo:{d}", _env())
    code, err = _cli_run(f"ippo:{d}", capsys)
    assert code == 2 and err.count("\n") == 1 and str(d / "policy.safetensors") in err
    (d / "policy.safetensors").unlink()
    with pytest.raises(ModelFileError, match=r"policy\.safetensors: missing"):
        load_policy(f"mappo:{d}", _env())
    shutil.copy(shipped_run("mappo", "s0") / "policy.safetensors", d / "policy.safetensors")
    with pytest.raises(PolicyError, match="trained on inputs of size"):  # spaces: a misfit, not a bad file
        load_policy(f"mappo:{d}", _env(sensors={"lidar_rays": 8}))
    meta = json.loads((d / "policy.json").read_text())
    meta["config"]["hidden"] = [7]
    (d / "policy.json").write_text(json.dumps(meta))
    with pytest.raises(ModelFileError, match="the tensors do not fit the actor"):
        load_policy(f"mappo:{d}", _env())
    meta["config"].update(hidden=json.loads((shipped_run("mappo", "s0") / "policy.json").read_text())["config"]["hidden"],
                          residual="vo")
    meta["config"].pop("residual_scale", None)
    (d / "policy.json").write_text(json.dumps(meta))
    with pytest.raises(ModelFileError, match="residual_scale"):
        load_policy(f"mappo:{d}", _env())
    meta["config"].update(residual="no_such_expert", residual_scale=0.5)
    (d / "policy.json").write_text(json.dumps(meta))
    with pytest.raises(ModelFileError, match="its residual expert: unknown policy 'no_such_expert'"):
        load_policy(f"mappo:{d}", _env())
    sb3 = tmp_path / "sb3"  # an SB3 policy directory given to rllib: the error says what loads it
    sb3.mkdir()
    (sb3 / "policy.json").write_text(json.dumps({"format": safe_io.FORMAT}))
    with pytest.raises(ModelFileError, match=r"format: expected 'swarm_env.rllib/1'.*load it with ppo:PATH"):
        load_policy(f"rllib:{sb3}", _env())


def test_the_leaderboard_stops_on_a_bad_model_file(run, tmp_path, capsys) -> None:
    d = _legacy(run, tmp_path / "old")
    code = cli.main(["evaluate", "--policies", "zero", f"ppo:{d}", "--scenarios", "paper_vo_0", "--seeds", "0",
                     "--max-cycles", "3", "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and err.strip().count("\n") == 0 and "refused" in err
    code = cli.main(["evaluate", "--policies", f"ppo:{run}", "--scenarios", "paper_vo_0", "--seeds", "0",
                     "--max-cycles", "3", "--quiet", "--action-type", "discrete"])
    assert code == 0  # a model that does not fit the env is an n/a row, as before
    assert "n/a: " in capsys.readouterr().out


def test_resuming_an_rllib_run_asks_for_the_opt_in(tmp_path, capsys) -> None:
    """RLlib's checkpoint is pickled state: --resume is refused before Ray is even imported."""
    from swarm_env_baselines import rllib_train

    assert rllib_train.main(["--out", str(tmp_path / "run"), "--resume", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "rllib_checkpoint: loading it would unpickle RLlib's checkpoint" in err
    assert "safe_io" not in err  # no conversion to offer: the run's exported actor is already safe


@pytest.mark.ray
def test_the_ray_backend_reports_a_refused_file_in_one_line_and_passes_the_opt_in(run, tmp_path, monkeypatch) -> None:
    pytest.importorskip("ray")
    from swarm_env.harness.leaderboard import run_leaderboard

    d = _legacy(run, tmp_path / "old")
    args = ([f"ppo:{d}"], ["random"], {"random": [1000]})
    kwargs = {"env_kwargs": dict(TINY_ENV), "workers": 1, "progress": False, "backend": "ray"}
    with pytest.raises(ModelFileError, match="refused") as info:
        run_leaderboard(*args, **kwargs)
    assert type(info.value) is ModelFileError and "\n" not in str(info.value)  # the worker's error, not Ray's wrapper
    monkeypatch.setenv(TRUST_PICKLE_ENV, "1")
    board = run_leaderboard(*args, **kwargs)
    assert len(board.episodes) == 1 and board.rows[0].na_reason is None


def test_a_zip_bomb_model_zip_is_refused_before_it_is_inflated(run, tmp_path) -> None:
    """A legacy model.zip whose ``data`` inflates to 300 MB (a 0.3 MB file) is refused on the sizes it declares,
    before ``testzip`` or ``read`` would inflate it."""
    d = _legacy(run, tmp_path / "bomb")
    with zipfile.ZipFile(d / model_io.MODEL_FILE) as archive:
        members = {name: archive.read(name) for name in archive.namelist()}
    with zipfile.ZipFile(d / model_io.MODEL_FILE, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        for name, content in members.items():
            archive.writestr(name, b" " * (300 << 20) if name == "data" else content)
    assert (d / model_io.MODEL_FILE).stat().st_size < 2 << 20
    start = time.perf_counter()
    with pytest.raises(ModelFileError, match=r"model\.zip: not a stable-baselines3 model archive within bounds "
                                             r"\(member data inflates to 314,572,800 bytes"):
        load_policy(f"ppo:{d}", _env())
    assert time.perf_counter() - start < 2.0
