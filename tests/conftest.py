"""Test-wide settings: headless rendering and a non-interactive plotting backend; every test starts with the
compiled kernels and search and leaves them so; the ``faults`` fixture."""

import os
import shutil
from collections.abc import Iterator
from pathlib import Path

import pytest

from swarm_env.compiled import compiled_mode

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("SDL_AUDIODRIVER", "dummy")
os.environ.setdefault("MPLBACKEND", "Agg")
os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")


@pytest.fixture(autouse=True)
def _compiled_restored() -> Iterator[None]:
    """A test that switches to the numpy references (:mod:`swarm_env.compiled`) cannot leak the choice."""
    with compiled_mode(kernels=True, search=True):
        yield


@pytest.fixture()
def faults(tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch) -> Path:
    """Register crash / hang / flaky / slow (tests/_fault_policies.py) through an entry point that this
    process, its spawned pool workers and subprocesses all see (a ``*.dist-info`` on the path)."""
    site = tmp_path_factory.mktemp("site")
    shutil.copy(Path(__file__).with_name("_fault_policies.py"), site / "swarm_env_fault_policies.py")
    info = site / "swarm_env_fault_policies-0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: swarm-env-fault-policies\nVersion: 0\n")
    (info / "entry_points.txt").write_text(
        "[swarm_env.policies]\n" + "".join(f"{m} = swarm_env_fault_policies:{m.title()}\n"
                                           for m in ("crash", "hang", "flaky", "slow")))
    monkeypatch.syspath_prepend(str(site))  # spawned workers start with this process's sys.path
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(site), os.environ.get("PYTHONPATH", "")]))
    monkeypatch.setenv("SWARM_ENV_FAULT_DIR", str(site))
    return site
