"""Strict JSON: the one writer of every JSON document the project produces.

Python's :mod:`json` writes ``NaN``, ``Infinity`` and ``-Infinity`` by default, which
are not JSON: ``jq``, JavaScript's ``JSON.parse`` and most other readers refuse the
file. Metrics have honest non-finite values (the mean settle time of a formation
never reached, a minimum over no pairs), so every writer goes through
:func:`dumps` / :func:`write_json`, which

* write each non-finite float as ``null`` (the convention of the metrics, where
  ``null`` already means "never" or "not applicable");
* turn numpy scalars and arrays, tuples, sets and ranges into plain JSON values;
* refuse anything else with a ``TypeError`` naming the type (after ``default``, when
  given, had its chance to convert it);
* and then call :func:`json.dumps` with ``allow_nan=False``, so a value that slipped
  past the conversion fails loudly instead of writing a non-JSON file.
"""

from __future__ import annotations

import gzip
import json
import math
import os
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from swarm_env.outputs import atomic_write_text

__all__ = ["dumps", "jsonable", "read_json", "write_json"]


def jsonable(value: Any, default: Callable[[Any], Any] | None = None) -> Any:
    """``value`` as plain JSON data: dicts (keys as :func:`json.dumps` accepts them), lists,
    strings, finite floats, ints, bools and ``None``; non-finite floats become ``None``.

    ``default(obj)`` converts an object of any other type (its result is converted in turn);
    without it, such an object raises ``TypeError``.
    """
    if value is None or isinstance(value, (str, bool)):
        return value
    if isinstance(value, int):
        return int(value)  # an IntEnum or bool-like int as a plain int
    if isinstance(value, float):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, np.generic):
        return jsonable(value.item(), default)
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist(), default)
    if isinstance(value, Mapping):
        return {k if isinstance(k, (str, int, float, bool)) or k is None else str(k): jsonable(v, default)
                for k, v in value.items()}
    if isinstance(value, (list, tuple, set, frozenset, range)):
        items = sorted(value, key=repr) if isinstance(value, (set, frozenset)) else value
        return [jsonable(v, default) for v in items]
    if default is not None:
        return jsonable(default(value))
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


def dumps(value: Any, *, indent: int | None = 2, sort_keys: bool = False,
          default: Callable[[Any], Any] | None = None) -> str:
    """Strict JSON text of ``value`` (see :func:`jsonable`); never contains ``NaN`` or ``Infinity``."""
    return json.dumps(jsonable(value, default), indent=indent, sort_keys=sort_keys, allow_nan=False)


def write_json(path: str | os.PathLike[str], value: Any, *, indent: int | None = 2, sort_keys: bool = False,
               default: Callable[[Any], Any] | None = None, overwrite: bool = True,
               root: str | os.PathLike[str] | None = None) -> Path:
    """Write ``dumps(value)`` and a final newline to ``path`` atomically (:func:`swarm_env.outputs.atomic_write_text`:
    a temporary file renamed onto ``path``; a symlink at ``path`` is refused, an existing file only replaced with
    ``overwrite``, and with ``root`` a path resolving outside that directory is refused); returns the path."""
    text = dumps(value, indent=indent, sort_keys=sort_keys, default=default) + "\n"  # fails before any file is touched
    return atomic_write_text(path, text, overwrite=overwrite, root=root)


def read_json(path: str | os.PathLike[str]) -> Any:
    """The JSON document at ``path``; a name ending in ``.gz`` is read through gzip (the shipped leaderboard of the
    benchmark suite, ``docs/leaderboard/leaderboard.json.gz``, is kept compressed: its 6,880 episodes are 38 MB of
    text)."""
    p = Path(path)
    if p.name.endswith(".gz"):
        with gzip.open(p, "rt", encoding="utf-8") as fh:
            return json.load(fh)
    return json.loads(p.read_text(encoding="utf-8"))
