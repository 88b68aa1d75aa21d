"""numba's on-disk cache for the package's kernels, invalidated by an edit to any file they are built from.

numba checks a cached kernel against the kernel's own file only: after an edit to a function it calls in another
file (``world_batch`` compiles ``physics_kernel``, ``human_kernel``, ``slot_kernel``, ... into one kernel), it
would load the old machine code. Every kernel of ``swarm_env`` and ``swarm_env_agents`` is decorated with
:func:`njit` (or :func:`cfunc`) from here, which, before the first kernel of the process is compiled or loaded,
compares one digest over the kernels' sources (:func:`sources_digest`: every file that imports numba and every
module of the two packages those files import, directly or not) with the digest stored in each cache directory,
and empties the directories that were written from other sources (:func:`refresh`). Nobody deletes
``__pycache__/*.nb*`` by hand; an upgrade that leaves old cache files behind is covered the same way.

The cache directories are numba's: ``__pycache__`` beside each kernel's file, and the folder under
``NUMBA_CACHE_DIR`` when that is set.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.util
import re
import sys
import warnings
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import numba

from swarm_env.outputs import open_atomic

#: The stamp file in each cache directory: the digest of the sources its kernels were compiled from.
STAMP = "swarm_env-kernels.sha256"
#: The packages whose kernels share the stamp (their directories: this package's and the experts', installed
#: as ``swarm_env_agents`` from ``agents/`` or beside ``swarm_env`` in site-packages).
_PACKAGES = ("swarm_env", "swarm_env_agents")
#: A kernel's file: it imports numba, or the decorators here.
_KERNEL = re.compile(r"^\s*(?:import numba\b|from numba\b|from swarm_env\.kernel_cache import)", re.M)
_IMPORT = re.compile(r"^\s*(?:from|import)\s+((?:swarm_env|swarm_env_agents)(?:\.\w+)*)", re.M)

__all__ = ["COMPILING_NOTICE", "STAMP", "cfunc", "njit", "refresh", "sources_digest"]


def _package_dirs() -> dict[str, Path]:
    """The directory of each package of :data:`_PACKAGES` that is importable here."""
    dirs = {}
    for name in _PACKAGES:
        spec = importlib.util.find_spec(name)
        if spec is not None and spec.submodule_search_locations:
            dirs[name] = Path(next(iter(spec.submodule_search_locations)))
    return dirs


def _module_files(packages: dict[str, Path]) -> dict[str, Path]:
    """Every module of ``packages`` (name -> directory) by its dotted name."""
    files = {}
    for name, root in packages.items():
        for path in root.rglob("*.py"):
            parts = (name, *path.relative_to(root).with_suffix("").parts)
            files[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return files


def sources_digest(packages: dict[str, Path]) -> tuple[str, list[Path]]:
    """The SHA-256 over the kernels' sources in ``packages`` (name -> directory), and the kernels' files.

    The sources are the files that import numba or this module's decorators and, transitively, every module of ``packages`` that one of
    them imports (at the top or inside a function: a constant or a compiled callee can come from either), read
    as bytes, in path order.
    """
    files = _module_files(packages)
    texts = {name: path.read_text(encoding="utf-8", errors="replace") for name, path in files.items()}
    kernels = sorted(name for name, text in texts.items() if _KERNEL.search(text))
    todo, seen = list(kernels), set(kernels)
    while todo:
        for imported in _IMPORT.findall(texts[todo.pop()]):
            while imported and imported not in files:  # a name inside a module: the module
                imported = imported.rpartition(".")[0]
            if imported and imported not in seen:
                seen.add(imported)
                todo.append(imported)
    digest = hashlib.sha256()
    for name in sorted(seen, key=lambda n: str(files[n])):
        digest.update(name.encode() + b"\0" + files[name].read_bytes() + b"\0")
    return digest.hexdigest(), [files[name] for name in kernels]


def refresh(cache_dirs: Iterable[Path], digest: str) -> list[Path]:
    """Empty each of ``cache_dirs`` of numba's files (``*.nbi``, ``*.nbc``) unless its stamp says ``digest``,
    then stamp it; returns the directories emptied. A missing directory is made and stamped (numba will cache
    there); one that cannot be written is left alone (numba does not cache there either)."""
    emptied = []
    for directory in cache_dirs:
        stamp = directory / STAMP
        try:
            if stamp.is_file() and stamp.read_text().strip() == digest:
                continue
            directory.mkdir(parents=True, exist_ok=True)
            for cached in [*directory.glob("*.nbi"), *directory.glob("*.nbc")]:
                cached.unlink(missing_ok=True)
            with open_atomic(stamp) as tmp:
                tmp.write_text(digest + "\n")
        except OSError:
            continue
        emptied.append(directory)
    return emptied


def _cache_dirs(kernel_files: Iterable[Path]) -> set[Path]:
    """Where numba caches the kernels of ``kernel_files``: ``__pycache__`` beside each, and its folder under
    ``NUMBA_CACHE_DIR`` (numba names it ``<parent>_<sha1 of the directory>``)."""
    dirs = set()
    user_dir = getattr(numba.config, "CACHE_DIR", "")
    for path in kernel_files:
        folder = path.resolve().parent
        dirs.add(folder / "__pycache__")
        if user_dir:
            dirs.add(Path(user_dir) / f"{folder.name}_{hashlib.sha1(str(folder).encode()).hexdigest()}")
    return dirs


#: What a person at a terminal reads while the kernels compile (1-2.5 minutes on a 2-core machine; later
#: processes load them from the cache in about a second).
COMPILING_NOTICE = ("swarm-env: compiling the simulation kernels for this version (once, about a minute or two; "
                    "later runs load them from numba's cache)")


@functools.cache
def _fresh() -> None:
    """:func:`refresh` the package's cache directories, once per process; when they were stale or new (the
    first run after an install or an upgrade) say on a terminal that the kernels compile now, so that the
    first command is not silent for a minute or two."""
    digest, kernel_files = sources_digest(_package_dirs())
    if refresh(_cache_dirs(kernel_files), digest) and sys.stderr is not None and sys.stderr.isatty():
        print(COMPILING_NOTICE, file=sys.stderr, flush=True)


def _cache_not_saved(fn: Callable[..., Any], exc: OSError) -> None:
    warnings.warn(f"swarm_env: the compiled kernel {fn.__qualname__} was not saved to numba's cache "
                  f"({exc.strerror or exc}); it runs, and compiles again in the next process", RuntimeWarning, stacklevel=3)


def _tolerant_saves(decorate: Callable[[Callable[..., Any]], Any]) -> Callable[[Callable[..., Any]], Any]:
    """``decorate`` (numba's decorator), whose kernels survive a cache file that cannot be written.

    The cache only saves the next process a compile: on a full disk (``ENOSPC``, ``EFBIG``) or a read-only
    ``__pycache__`` numba raises from the kernel's first call on Linux, and the command would stop with the
    kernel compiled and working. Here a failed save is a warning and the kernel runs (numba's ``_cache`` of the
    dispatcher is private; where it is missing, numba's own behaviour stays)."""

    def wrap(fn: Callable[..., Any]) -> Any:
        kernel = decorate(fn)
        cache = getattr(kernel, "_cache", None)
        save = getattr(cache, "save_overload", None)
        if save is not None:
            def save_or_warn(sig: Any, data: Any) -> None:
                try:
                    save(sig, data)
                except OSError as exc:
                    _cache_not_saved(fn, exc)

            cache.save_overload = save_or_warn  # type: ignore[union-attr]
        return kernel

    return wrap


def njit(**options: Any) -> Callable[[Callable[..., Any]], Any]:
    """``numba.njit(cache=True, **options)``, with the package's cache made fresh first (see the module); a
    cache file that cannot be written (a full disk) is a warning, not an error."""
    _fresh()
    return _tolerant_saves(numba.njit(cache=True, **options))


def cfunc(signature: Any, **options: Any) -> Callable[[Callable[..., Any]], Any]:
    """``numba.cfunc(signature, cache=True, **options)``, with the package's cache made fresh first; a cache
    file that cannot be written is a warning (and the callback is compiled again without the cache)."""
    _fresh()

    def decorate(fn: Callable[..., Any]) -> Any:
        try:  # numba compiles (and saves) a cfunc while decorating it
            return numba.cfunc(signature, cache=True, **options)(fn)
        except OSError as exc:
            _cache_not_saved(fn, exc)
            return numba.cfunc(signature, cache=False, **options)(fn)

    return decorate
