"""The package's layout: the simulation core never imports the harness, no module-level import
cycles, and the harness modules' old names still import (deprecated) as the same modules."""

from __future__ import annotations

import ast
import importlib
import sys
import warnings
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# repository directory -> installed import name
PACKAGES = {"swarm_env": "swarm_env", "agents": "swarm_env_agents", "baselines": "swarm_env_baselines"}


def _imports(path: Path, top_level_only: bool) -> set[str]:
    """The ``swarm_env*`` modules ``path`` imports (at module level only, or anywhere)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    nodes = tree.body if top_level_only else list(ast.walk(tree))
    found: set[str] = set()
    for node in nodes:
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = {f"{node.module}.{a.name}" for a in node.names}
            found.update(names)
            # `from pkg import submodule` imports the submodule (its package is already being imported)
            if not any((ROOT / Path(*_directory_parts(n))).with_suffix(".py").exists() for n in names):
                found.add(node.module)
        elif isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
    return {m for m in found if m.split(".")[0] in PACKAGES.values()}


def _directory_parts(module: str) -> list[str]:
    """Where ``module`` lives in the repository, as path parts (its installed name mapped back)."""
    top, *rest = module.split(".")
    directory = {v: k for k, v in PACKAGES.items()}.get(top, top)
    return [directory, *rest]


def _modules(directory: str) -> dict[str, Path]:
    base = ROOT / directory
    out = {}
    for path in base.rglob("*.py"):
        parts = list(path.relative_to(base).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join([PACKAGES[directory], *parts])] = path
    return out


def test_the_core_never_imports_the_harness() -> None:
    core = {name: path for name, path in _modules("swarm_env").items() if not name.startswith("swarm_env.harness")}
    assert "swarm_env.env" in core and "swarm_env.vector" in core
    offenders = {name: sorted(m for m in _imports(path, top_level_only=False)
                              if m.startswith(("swarm_env.harness", "swarm_env_agents", "swarm_env_baselines")))
                 for name, path in core.items()}
    assert not {k: v for k, v in offenders.items() if v}, offenders


@pytest.mark.parametrize("directory", sorted(PACKAGES))
def test_no_module_level_import_cycles(directory: str) -> None:
    modules = _modules(directory)
    graph = {name: {m for m in _imports(path, top_level_only=True) if m in modules and m != name}
             for name, path in modules.items()}
    state: dict[str, int] = {}  # 1 on the stack, 2 done

    def visit(node: str, stack: list[str]) -> None:
        state[node] = 1
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                pytest.fail(f"import cycle at module level: {' -> '.join(stack[stack.index(nxt):] + [nxt])}")
            if nxt not in state:
                visit(nxt, stack + [nxt])
        state[node] = 2

    for name in sorted(graph):
        if name not in state:
            visit(name, [name])
    assert len(graph) > 5


@pytest.mark.parametrize("name", ["cli", "leaderboard", "evaluation", "bench", "policies", "video", "paired", "recording"])
def test_old_harness_names_import_with_a_warning(name: str) -> None:
    new = importlib.import_module(f"swarm_env.harness.{name}")
    sys.modules.pop(f"swarm_env.{name}", None)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        old = importlib.import_module(f"swarm_env.{name}")
    assert old is new
    assert any(issubclass(w.category, DeprecationWarning) and f"swarm_env.harness.{name}" in str(w.message)
               for w in caught)
