"""Packaging and names: the installed import names, the module commands of ``swarm-env``, ``--version``,
one-line errors for missing extras, shipped checkpoints by name from any directory, and the built
wheel and sdist (``-m slow``)."""

from __future__ import annotations

import importlib
import importlib.metadata
import json
import shutil
import subprocess
import sys
import tarfile
import zipfile
from pathlib import Path

import pytest

import swarm_env
from swarm_env import extras
from swarm_env.extras import MissingExtraError
from swarm_env.harness.cli import MODULE_COMMANDS, main
from swarm_env.harness.policies import load_policy, policy_extra

ROOT = Path(__file__).resolve().parents[1]
INSTALLED = {"swarm_env": ROOT / "swarm_env", "swarm_env_agents": ROOT / "agents",
             "swarm_env_baselines": ROOT / "baselines"}


def test_version_is_the_package_version(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--version"]) == 0  # argparse's exit, returned as the command's code
    assert capsys.readouterr().out.strip() == f"swarm-env {swarm_env.__version__}"
    assert importlib.metadata.version("swarm-env") == swarm_env.__version__  # pyproject reads it from there


@pytest.mark.parametrize("words", sorted(MODULE_COMMANDS), ids=" ".join)
def test_every_module_command_prints_its_own_help(words: tuple[str, ...], capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("torch")
    with pytest.raises(SystemExit) as exit_:
        main([*words, "--help"])
    assert exit_.value.code == 0
    assert capsys.readouterr().out.startswith(f"usage: swarm-env {' '.join(words)} ")


def test_a_module_command_gets_the_rest_of_the_command_line(monkeypatch: pytest.MonkeyPatch) -> None:
    pytest.importorskip("torch")
    module = importlib.import_module(MODULE_COMMANDS[("train", "mappo")][0])
    seen: list[list[str]] = []
    monkeypatch.setattr(module, "main", lambda argv: seen.append(argv) or 3)
    assert main(["train", "mappo", "--scenario", "random", "--seed", "4"]) == 3
    assert seen == [["--scenario", "random", "--seed", "4"]]


def test_a_command_group_lists_its_commands(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["train", "--help"]) == 0
    out = capsys.readouterr().out
    assert all(name in out for name in ("mappo", "sb3", "rllib"))
    assert main(["reproduce"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: reproduce needs a command") and "cbs_rrt" in err and "vo" in err
    assert main(["reproduce", "orca"]) == 2
    assert "unknown reproduce command 'orca'" in capsys.readouterr().err


def test_top_level_help_lists_the_module_commands(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    for word in ("train", "bc", "demos", "ship", "curves", "convert", "reproduce", "--version"):
        assert word in out


def _without(monkeypatch: pytest.MonkeyPatch, missing: str, *reimported: str) -> None:
    """Make ``import missing`` fail as if it were not installed (its distribution too, for the package
    metadata), and forget the modules that import it."""
    installed = extras._installed
    distribution = missing.replace("_", "-")
    monkeypatch.setattr(extras, "_installed", lambda dist: dist != distribution and installed(dist))
    for name in [m for m in sys.modules if m == missing or m.startswith(missing + ".")] or [missing]:
        monkeypatch.setitem(sys.modules, name, None)  # None in sys.modules: importing it raises ModuleNotFoundError
    for name in [m for m in sys.modules if m.startswith(reimported)]:
        monkeypatch.delitem(sys.modules, name)


@pytest.mark.parametrize(("spec", "missing"), [("ppo:runs/x", "stable_baselines3"), ("mappo", "torch"),
                                               ("rllib:runs/x", "torch")])
def test_a_policy_without_its_extra_fails_in_one_line(spec: str, missing: str, monkeypatch: pytest.MonkeyPatch,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    _without(monkeypatch, missing, "swarm_env_baselines")
    with pytest.raises(MissingExtraError, match=r"policy '\w+' needs the optional extra: pip install 'swarm-env\[rl\]'"):
        load_policy(spec, swarm_env.SwarmEnv("paper_vo_0"))
    assert main(["run", "--policy", spec, "--max-cycles", "1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "pip install 'swarm-env[rl]'" in err and missing in err


def test_an_import_error_with_the_extra_installed_keeps_its_traceback(monkeypatch: pytest.MonkeyPatch) -> None:
    pytest.importorskip("stable_baselines3")
    monkeypatch.setitem(sys.modules, "swarm_env_baselines.model_io", None)  # a broken module, not a missing extra
    with pytest.raises(ModuleNotFoundError, match="swarm_env_baselines.model_io"):
        load_policy("ppo:runs/x", swarm_env.SwarmEnv("paper_vo_0"))


def test_a_module_command_without_its_extra_fails_in_one_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    _without(monkeypatch, "torch", "swarm_env_baselines")
    assert main(["train", "mappo", "--runs-dir", str(tmp_path), "--total-steps", "64", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert err.startswith("error: swarm-env train mappo needs the optional extra: pip install 'swarm-env[rl]'")


def test_list_marks_the_policies_whose_extra_is_missing(monkeypatch: pytest.MonkeyPatch,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    # Only stable-baselines3 is missing; every other distribution counts as installed, so that the lines are the
    # same on a core install without torch (the Python 3.10/3.12/3.13 checks) as with the rl extra.
    monkeypatch.setattr(extras, "_installed", lambda dist: dist != "stable-baselines3")
    assert main(["list"]) == 0
    lines = {line.split()[0]: line for line in capsys.readouterr().out.splitlines() if line.startswith("  ")}
    for name in ("ppo", "sac", "bc", "mappo", "residual_vo"):
        assert policy_extra(name) == ("swarm-env", "rl")
        assert "not installed: pip install 'swarm-env[rl]' for stable-baselines3" in lines[name]
    for name in ("vo", "cbs_rrt", "pursuit", "random"):
        assert "not installed" not in lines[name]


def test_the_extras_are_read_from_the_package_metadata() -> None:
    assert extras.extra_for_module("stable_baselines3.common.vec_env") == "rl"
    assert extras.extra_for_module("torch") == "rl"  # the first extra that has it, in pyproject's order
    assert extras.extra_for_module("pyrvo") == "orca"
    assert extras.extra_for_module("ray") == "ray"
    assert extras.extra_for_module("numpy") is None and extras.extra_for_module(None) is None
    assert extras.missing_distributions("no_such_extra") == []


@pytest.mark.parametrize("spec", ["mappo:s2", "mappo_shielded_bare:s1", "residual_vo"])
def test_a_shipped_checkpoint_loads_by_name_from_any_directory(spec: str, tmp_path: Path,
                                                              monkeypatch: pytest.MonkeyPatch,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("torch")
    monkeypatch.chdir(tmp_path)
    assert main(["run", "--policy", spec, "--scenario", "paper_vo_0", "--max-cycles", "3"]) == 0
    assert f"of {spec} on paper_vo_0" in capsys.readouterr().out


def test_no_module_imports_the_repository_directory_names(tmp_path: Path) -> None:
    """Every installed module imports, from outside the checkout, without ``agents`` or ``baselines``
    (those would be another project's packages, or fail, in a user's environment)."""
    pytest.importorskip("torch")
    code = """
import importlib, json, pkgutil, sys
names = []
for top in ("swarm_env_agents", "swarm_env_baselines"):
    package = importlib.import_module(top)
    for info in pkgutil.walk_packages(package.__path__, top + "."):
        importlib.import_module(info.name)
        names.append(info.name)
print(json.dumps({"imported": names, "foreign": sorted(m for m in sys.modules if m.split(".")[0] in ("agents", "baselines"))}))
"""
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, check=True,
                         timeout=300)
    doc = json.loads(out.stdout)
    assert doc["foreign"] == []
    assert {"swarm_env_agents.cbs_rrt.policy", "swarm_env_baselines.mappo", "swarm_env_baselines.rllib_train"} <= set(doc["imported"])


def _source_packages() -> set[str]:
    """Installed names of the repository's Python packages (directories with an ``__init__.py``)."""
    return {".".join([name, *init.parent.relative_to(directory).parts])
            for name, directory in INSTALLED.items() for init in directory.rglob("__init__.py")}


def _shipped_files() -> set[str]:
    """Wheel paths of the shipped checkpoints and scenarios, from git (what a checkout has)."""
    listed = subprocess.run(["git", "ls-files", "baselines/checkpoints", "swarm_env/scenarios"], cwd=ROOT,
                            capture_output=True, text=True, check=True).stdout.split()
    return {f.replace("baselines/", "swarm_env_baselines/", 1) for f in listed}


@pytest.mark.slow
def test_the_wheel_and_sdist_install_unique_names_and_the_license(tmp_path: Path) -> None:
    """Built by setuptools' own backend (no network): the wheel holds swarm_env, swarm_env_agents and
    swarm_env_baselines only (no top-level agents/baselines), every package and shipped checkpoint,
    entry points into the installed names, and the LICENSE; the sdist holds the LICENSE too."""
    if not (ROOT / ".git").exists():
        pytest.skip("needs a git checkout")
    # The backend is imported from this environment (no isolated build): it must meet [build-system] requires
    # (the dev extra installs it; torch and tensorboard require it too).
    pytest.importorskip("setuptools", minversion="77")
    # Built from a copy of the checkout's files (tracked or not ignored), so that the build leaves no build/
    # or egg-info behind in the checkout and sees no stray build products.
    source = tmp_path / "src"
    listed = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard"], cwd=ROOT,
                            capture_output=True, text=True, check=True).stdout.splitlines()
    for name in listed:
        if (ROOT / name).is_file():
            (source / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / name, source / name)
    built = tmp_path / "built.txt"  # the backend prints its log on stdout: the names go to a file
    code = ("import sys, setuptools.build_meta as b; from pathlib import Path; "
            "out, built = sys.argv[1:3]; "  # before the backend rewrites sys.argv
            "Path(built).write_text(b.build_wheel(out) + ' ' + b.build_sdist(out))")
    out = subprocess.run([sys.executable, "-c", code, str(tmp_path), str(built)], cwd=source, capture_output=True,
                         text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    wheel_name, sdist_name = built.read_text().split()
    names = zipfile.ZipFile(tmp_path / wheel_name).namelist()
    dist_info = f"swarm_env-{swarm_env.__version__}.dist-info"
    assert {n.split("/")[0] for n in names} == {"swarm_env", "swarm_env_agents", "swarm_env_baselines", dist_info}
    assert f"{dist_info}/licenses/LICENSE" in names
    packages = {n.rsplit("/", 1)[0].replace("/", ".") for n in names if n.endswith("/__init__.py")}
    assert packages == _source_packages()
    assert _shipped_files() <= set(names)
    entry_points = zipfile.ZipFile(tmp_path / wheel_name).read(f"{dist_info}/entry_points.txt").decode()
    targets = [line.split("=", 1)[1].strip() for line in entry_points.splitlines() if "=" in line]
    assert targets and all(t.startswith(("swarm_env.", "swarm_env_agents.", "swarm_env_baselines.")) for t in targets)
    with tarfile.open(tmp_path / sdist_name) as sdist:
        assert f"swarm_env-{swarm_env.__version__}/LICENSE" in sdist.getnames()
