"""numba's cache of the kernels follows every file they are built from (swarm_env.kernel_cache)."""

from __future__ import annotations

import io
import sys
from pathlib import Path

import pytest

from swarm_env import kernel_cache
from swarm_env.kernel_cache import STAMP, refresh, sources_digest


def _package(root: Path, files: dict[str, str]) -> dict[str, Path]:
    for name, text in files.items():
        path = root / "swarm_env" / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return {"swarm_env": root / "swarm_env"}


FILES = {
    "__init__.py": "",
    "fast.py": "import numba\nfrom swarm_env.reference import COLUMNS\n",
    "reference.py": "from swarm_env.deeper import WIDTH\nCOLUMNS = 3\n",
    "deeper.py": "WIDTH = 1\n",
    "user.py": "from swarm_env.kernel_cache import njit\n\ndef f():\n    from swarm_env.lazy import X\n",
    "lazy.py": "X = 1\n",
    "unrelated.py": "import swarm_env.fast\nY = 2\n",
}


def test_the_digest_covers_what_the_kernels_import_and_nothing_else(tmp_path: Path) -> None:
    packages = _package(tmp_path, FILES)
    digest, kernels = sources_digest(packages)
    assert sorted(p.name for p in kernels) == ["fast.py", "user.py"]
    src = packages["swarm_env"]
    for name, changed in [("deeper.py", True), ("lazy.py", True), ("reference.py", True), ("unrelated.py", False)]:
        (src / name).write_text((src / name).read_text() + "# edited\n")
        new, _ = sources_digest(packages)
        assert (new != digest) == changed, name
        digest = new


def test_a_cache_written_from_other_sources_is_emptied_once(tmp_path: Path) -> None:
    cache = tmp_path / "__pycache__"
    cache.mkdir()
    for name in ("k.f-10.py311.nbi", "k.f-10.py311.1.nbc", "k.cpython-311.pyc"):
        (cache / name).write_bytes(b"x")
    assert refresh([cache], "a") == [cache]
    assert sorted(p.name for p in cache.iterdir()) == ["k.cpython-311.pyc", STAMP]
    (cache / "k.f-10.py311.nbi").write_bytes(b"new")
    assert refresh([cache], "a") == [] and (cache / "k.f-10.py311.nbi").exists()
    assert refresh([cache], "b") == [cache] and not (cache / "k.f-10.py311.nbi").exists()
    assert (cache / STAMP).read_text().strip() == "b"


def test_a_missing_cache_directory_is_made_and_stamped(tmp_path: Path) -> None:
    cache = tmp_path / "pkg" / "__pycache__"
    assert refresh([cache], "a") == [cache] and (cache / STAMP).read_text().strip() == "a"


def test_the_package_caches_carry_the_digest_of_todays_sources() -> None:
    from swarm_env.sim import physics_kernel  # a kernel module: importing it made the caches fresh

    digest, kernels = sources_digest(kernel_cache._package_dirs())
    assert Path(physics_kernel.__file__).resolve() in {k.resolve() for k in kernels}
    for directory in kernel_cache._cache_dirs(kernels):
        assert (directory / STAMP).read_text().strip() == digest, directory



class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


@pytest.mark.parametrize(("stale", "terminal", "told"), [(True, True, True), (False, True, False), (True, False, False)])
def test_a_person_is_told_when_the_kernels_compile_and_only_then(monkeypatch: pytest.MonkeyPatch, stale: bool,
                                                                  terminal: bool, told: bool) -> None:
    """A stale or new cache (the first run after an install or an upgrade: every kernel compiles, 1-2.5 minutes)
    is announced on a terminal; a fresh cache, pipes and logs stay quiet."""
    err = _Terminal() if terminal else io.StringIO()
    monkeypatch.setattr(sys, "stderr", err)
    monkeypatch.setattr(kernel_cache, "refresh", lambda dirs, digest: [Path("cache")] if stale else [])
    kernel_cache._fresh.cache_clear()
    try:
        kernel_cache._fresh()
    finally:
        kernel_cache._fresh.cache_clear()  # the next kernel of this process refreshes for real (a no-op: stamped)
    assert (kernel_cache.COMPILING_NOTICE in err.getvalue()) is told
