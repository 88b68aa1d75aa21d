"""Strict JSON: non-finite numbers are written as null, and every JSON writer goes through swarm_env.jsonio."""

from __future__ import annotations

import ast
import json
import math
from pathlib import Path

import numpy as np
import pytest

from swarm_env.jsonio import dumps, jsonable, write_json

ROOT = Path(__file__).resolve().parents[1]

#: json.dumps calls that write nothing: (file, enclosing function) -> why.
NOT_WRITERS = {
    ("baselines/demos.py", "_jsonable"): "canonicalises a request in memory (json round trip)",
    ("baselines/demos.py", "cache_key"): "hashes a request",
}


def strict_loads(text: str) -> object:
    """json.loads that refuses NaN / Infinity, as jq and JSON.parse do."""

    def refuse(name: str) -> object:
        raise ValueError(f"non-JSON constant {name}")

    return json.loads(text, parse_constant=refuse)


def test_non_finite_floats_become_null_and_numpy_values_plain() -> None:
    doc = {
        "nan": float("nan"), "inf": math.inf, "ninf": -np.inf, "np_nan": np.float32("nan"),
        "ok": 0.25, "np_float": np.float64(1.5), "np_int": np.int64(7), "np_bool": np.bool_(True),
        "array": np.array([1.0, np.nan, 3.0]), "tuple": (1, (2.0, math.inf)), "nested": [{"x": float("nan")}],
        "none": None, "int_key": {3: "three"},
    }
    back = strict_loads(dumps(doc))
    assert back == {
        "nan": None, "inf": None, "ninf": None, "np_nan": None, "ok": 0.25, "np_float": 1.5, "np_int": 7,
        "np_bool": True, "array": [1.0, None, 3.0], "tuple": [1, [2.0, None]], "nested": [{"x": None}],
        "none": None, "int_key": {"3": "three"},
    }
    assert type(jsonable(np.int64(7))) is int and type(jsonable(np.float32(0.5))) is float


def test_unknown_types_refused_unless_default_converts(tmp_path: Path) -> None:
    with pytest.raises(TypeError, match="not JSON serialisable: object"):
        dumps({"x": object()})
    # default's result is converted too: a NaN it returns is still written as null
    assert strict_loads(dumps({"x": object()}, default=lambda o: float("nan"))) == {"x": None}
    path = write_json(tmp_path / "summary.json", {"best_score": float("nan"), "steps": 10})
    text = path.read_text()
    assert text.endswith("}\n") and "NaN" not in text and strict_loads(text) == {"best_score": None, "steps": 10}


def test_finite_documents_are_written_as_json_dumps_writes_them() -> None:
    """Routing existing writers through jsonio changes no file that was already valid JSON."""
    doc = {"a": [1, 2.5, {"b": None, "c": "x"}], "d": True, "e": 1e-300, "f": 0.1 + 0.2}
    for indent in (None, 1, 2):
        assert dumps(doc, indent=indent) == json.dumps(doc, indent=indent)
    assert dumps(doc, sort_keys=True) == json.dumps(doc, indent=2, sort_keys=True)


def test_every_json_writer_goes_through_jsonio() -> None:
    """No json.dump/json.dumps outside swarm_env/jsonio.py in the package, experts, baselines, benchmarks or
    docs scripts, except the in-memory uses listed in NOT_WRITERS."""
    found = []
    for folder in ("swarm_env", "agents", "baselines", "benchmarks", "docs"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            rel = path.relative_to(ROOT).as_posix()
            if rel == "swarm_env/jsonio.py":
                continue
            tree = ast.parse(path.read_text())
            for func in [n for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))]:
                for node in ast.walk(func):
                    if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
                            and node.func.attr in ("dump", "dumps") and isinstance(node.func.value, ast.Name)
                            and node.func.value.id == "json" and (rel, func.name) not in NOT_WRITERS):
                        found.append(f"{rel}:{node.lineno} in {func.name}()")
            for node in tree.body:  # module level
                for sub in ast.walk(node):
                    if (not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef))
                            and isinstance(sub, ast.Call) and isinstance(sub.func, ast.Attribute)
                            and sub.func.attr in ("dump", "dumps") and getattr(sub.func.value, "id", None) == "json"):
                        found.append(f"{rel}:{sub.lineno} (module level)")
    assert not found, "write JSON with swarm_env.jsonio (strict: NaN -> null), not json.dump(s): " + ", ".join(found)
