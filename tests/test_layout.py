"""The package's rooms and the direction of its imports (README, "Layout").

``swarm_env`` is organised in rooms, one job each, with data flowing one way: a module may import its own room
and the rooms below it, never one above. :data:`LEVELS` is the order, lowest first; the root's modules are
placed one by one (the data types at the bottom, the env at the top). Every import counts: at module level,
inside functions (a lazy import must not hide an upward arrow or a loop) and under ``TYPE_CHECKING``.

The experts (``agents/``, installed as ``swarm_env_agents``) and the baselines (``baselines/``, as
``swarm_env_baselines``) stand above the package: the baselines may import the experts, never the reverse, and
neither package has an import loop or a lazy import of its own light modules.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "swarm_env"
#: Each installed package and its directory, lowest first: a package may import only itself and those before it.
PACKAGES = {"swarm_env": PACKAGE, "swarm_env_agents": ROOT / "agents", "swarm_env_baselines": ROOT / "baselines"}

#: Rooms and root modules, lowest first. A name is a room (a folder of swarm_env) or a module at the root.
LEVELS: list[tuple[str, ...]] = [
    ("_compat", "checks", "compiled", "extras", "jsonio", "limits", "reading", "outputs", "kernel_cache",
     "worker_process", "scenario"),
    ("geometry",),
    ("state",),
    ("control",),
    ("sim",),
    ("sensing",),
    ("scoring",),
    ("scenarios",),
    ("render",),
    ("env",),
    ("wrappers",),
    ("__init__",),
    ("vector",),
    ("harness",),
]
LEVEL = {name: i for i, names in enumerate(LEVELS) for name in names}


def _module_name(package: str, path: Path) -> str:
    parts = (package, *path.relative_to(PACKAGES[package]).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules(packages: tuple[str, ...] = ("swarm_env",)) -> dict[str, Path]:
    return {_module_name(package, p): p for package in packages for p in PACKAGES[package].rglob("*.py")
            if "__pycache__" not in p.parts}


def _imports(path: Path, modules: dict[str, Path]) -> set[str]:
    """The package's modules that ``path`` imports, wherever in the file."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            # `from package import module` imports the module; `from module import name`, the module.
            names = [f"{node.module}.{a.name}" if f"{node.module}.{a.name}" in modules else node.module
                     for a in node.names]
        else:
            continue
        for name in names:
            while name and name not in modules:  # a name inside a module: the module
                name = name.rpartition(".")[0]
            if name:
                found.add(name)
    return found


def _room(module: str) -> str:
    """The room of a module: its folder under swarm_env, or its own name at the root."""
    parts = module.split(".")
    if len(parts) == 1:
        return "__init__"
    return parts[1]


def _graph(packages: tuple[str, ...] = ("swarm_env",)) -> dict[str, set[str]]:
    modules = _modules(packages)
    return {m: _imports(p, modules) - {m} for m, p in modules.items()}


def test_every_module_has_a_room() -> None:
    missing = sorted({_room(m) for m in _modules()} - set(LEVEL))
    assert not missing, f"place these in LEVELS: {missing}"


def test_no_module_imports_a_room_above_its_own() -> None:
    upward = []
    for module, deps in _graph().items():
        for dep in deps:
            here, there = _room(module), _room(dep)
            if here != there and LEVEL[there] > LEVEL[here]:
                upward.append(f"{module} -> {dep}")
    assert not upward, "imports that run up: " + ", ".join(sorted(upward))


def test_no_import_loops() -> None:
    graph = _graph(tuple(PACKAGES))
    loops: list[list[str]] = []
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    path: list[str] = []

    def visit(m: str) -> None:
        state[m] = 1
        path.append(m)
        for d in sorted(graph.get(m, ())):
            if state.get(d) == 1:
                loops.append(path[path.index(d):] + [d])
            elif d not in state:
                visit(d)
        path.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m)
    assert not loops, "import loops: " + "; ".join(" -> ".join(loop) for loop in loops)


#: Libraries that a module may import inside a function (and so, any module of the package that imports one at
#: its top, directly or through another): optional extras and what costs seconds or a compiler to load.
HEAVY = ("numba", "llvmlite", "torch", "pygame", "imageio", "imageio_ffmpeg", "matplotlib", "ray", "rvo2", "pyrvo",
         "stable_baselines3", "safetensors", "tensorboard", "torchrl", "tensordict", "benchmarl", "vmas")


def _top_imports(path: Path) -> set[str]:
    """Every name imported at the top of ``path`` (not in a function, not under ``TYPE_CHECKING``)."""
    found: set[str] = set()

    def visit(node: ast.AST) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda, ast.ClassDef)):
                if isinstance(child, ast.ClassDef):
                    visit(child)
                continue
            if isinstance(child, ast.If) and "TYPE_CHECKING" in ast.unparse(child.test):
                continue
            if isinstance(child, ast.Import):
                found.update(a.name for a in child.names)
            elif isinstance(child, ast.ImportFrom) and child.level == 0 and child.module:
                found.update(f"{child.module}.{a.name}" for a in child.names)
            visit(child)

    visit(ast.parse(path.read_text(), str(path)))
    return found


def test_imports_inside_functions_only_defer_heavy_modules() -> None:
    """A module of the package imported inside a function must load a heavy library when imported (numba for the
    kernels, pygame for the renderer, ...): anything else belongs at the top of the file, where a loop would show."""
    modules = _modules(tuple(PACKAGES))
    heavy: dict[str, bool] = {}

    def is_heavy(module: str, seen: tuple[str, ...] = ()) -> bool:
        if module not in heavy:
            if module in seen:
                return False
            names = _top_imports(modules[module])
            own = _imports_of(names, modules) - {module}
            heavy[module] = (any(n.split(".")[0] in HEAVY for n in names)
                             or any(is_heavy(d, (*seen, module)) for d in own))
        return heavy[module]

    deferred = []
    for module, path in modules.items():
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                for inner in ast.walk(node):
                    if isinstance(inner, ast.Import):
                        names = {a.name for a in inner.names}
                    elif isinstance(inner, ast.ImportFrom) and inner.level == 0 and inner.module:
                        names = {f"{inner.module}.{a.name}" for a in inner.names}
                    else:
                        continue
                    for dep in _imports_of(names, modules):
                        if dep not in PACKAGES and not is_heavy(dep):
                            deferred.append(f"{module}:{inner.lineno} {dep}")
    assert not deferred, "move to the top of the file: " + ", ".join(sorted(set(deferred)))


def _imports_of(names: set[str], modules: dict[str, Path]) -> set[str]:
    """The package's modules among imported ``names`` (a name inside a module counts as the module)."""
    found = set()
    for name in names:
        while name and name not in modules:
            name = name.rpartition(".")[0]
        if name:
            found.add(name)
    return found


def test_the_package_imports_neither_the_experts_nor_the_baselines() -> None:
    """swarm_env finds the experts and the baselines through entry points (swarm_env.harness.policies)."""
    offenders = []
    for path in PACKAGE.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                names = [a.name for a in node.names] if isinstance(node, ast.Import) else [node.module or ""]
                if any(n.startswith(("swarm_env_agents", "swarm_env_baselines")) for n in names):
                    offenders.append(str(path.relative_to(ROOT)))
    assert not offenders, offenders


def test_each_package_imports_only_itself_and_those_below() -> None:
    order = list(PACKAGES)
    upward = [f"{m} -> {d}" for m, deps in _graph(tuple(PACKAGES)).items() for d in deps
              if order.index(d.split(".")[0]) > order.index(m.split(".")[0])]
    assert not upward, "imports that run up: " + ", ".join(sorted(upward))
