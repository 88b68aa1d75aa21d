"""Old module names that still import: the harness modules moved to :mod:`swarm_env.harness` in 0.1.

``import swarm_env.cli`` (and the other old names below) gives the module itself, ``swarm_env.harness.cli``,
with a ``DeprecationWarning``; the old names go in 0.2. A finder on ``sys.meta_path`` serves them,
so there is no file at the old path (``python -m swarm_env.cli`` is ``python -m swarm_env.harness.cli``
now).
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import importlib.util
import sys
import warnings
from types import ModuleType

MOVED = {f"swarm_env.{name}": f"swarm_env.harness.{name}"
         for name in ("cli", "leaderboard", "evaluation", "bench", "policies", "video", "paired", "recording")}


class _MovedModules(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Serves each old name of :data:`MOVED` as the module at its new name."""

    def find_spec(self, fullname: str, path: object = None, target: object = None) -> importlib.machinery.ModuleSpec | None:
        if fullname not in MOVED:
            return None
        return importlib.util.spec_from_loader(fullname, self)

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType:
        new = MOVED[spec.name]
        warnings.warn(f"{spec.name} moved to {new}; the old name will be removed in swarm-env 0.2",
                      DeprecationWarning, stacklevel=2)
        return importlib.import_module(new)  # the same module object under both names

    def exec_module(self, module: ModuleType) -> None:
        pass  # already executed under its new name


def install() -> None:
    """Put the finder on ``sys.meta_path`` (once)."""
    if not any(isinstance(f, _MovedModules) for f in sys.meta_path):
        sys.meta_path.append(_MovedModules())
