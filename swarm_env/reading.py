"""Reading an input file within bounds: the one rule every reader of untrusted files follows.

Scenario files (:mod:`swarm_env.scenarios.loader`), episode records (:mod:`swarm_env.harness.recording`) and
saved models (``swarm_env_baselines.model_bounds``) are input from anyone. :func:`read_regular` reads one

* only if it is a regular file: a FIFO, a device such as ``/dev/zero``, a socket or a directory is refused
  (opened without blocking, so a FIFO with no writer never stalls the reader; with ``follow_symlinks=False`` a
  symbolic link is refused too);
* only up to ``limit`` bytes: the size is checked with ``fstat`` before reading, and a file that grows while it
  is read is cut at ``limit + 1`` bytes and refused, so memory stays bounded whatever the file claims.

Every refusal is a :class:`FileRefused` (a ``ValueError``) carrying what was expected and what was found, which
each reader words as its own error type (a scenario's ``ScenarioError``, a record's ``RecordError``, a model's
``ModelFileError``). :func:`file_kind` names a file type the same way everywhere ("a FIFO", "a device").

:func:`parse_json` is the one rule for JSON from such files (a record's ``meta.json``, a model's ``policy.json``
and safetensors header): nesting bounded before the parser sees it, and strict numbers (no ``NaN``/``Infinity``).
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import re
import stat
from collections.abc import Iterator
from typing import Any, BinaryIO

import numpy as np

from swarm_env.limits import printable

__all__ = ["FileRefused", "JSONTooDeep", "file_kind", "open_regular", "parse_json", "read_regular"]


class FileRefused(ValueError):
    """A file :func:`read_regular` did not read: ``expected`` says what it must be (``"a regular file (this is a
    FIFO)"``, ``"a file of at most 1048576 bytes"``, ``"a readable file (Permission denied)"``), ``got`` what was
    found where that helps (``"5000000 bytes"``), else ``None``."""

    def __init__(self, path: str | os.PathLike[str], expected: str, got: str | None = None, *,
                 kind: str | None = None, size: int | None = None) -> None:
        self.path = os.fspath(path)
        self.expected = expected
        self.got = got
        #: the file's kind (:func:`file_kind`) when it is not a regular file, its size when it is too large
        self.kind, self.size = kind, size
        super().__init__(f"{self.path}: expected {expected}" + (f", got {got}" if got else ""))


def file_kind(mode: int) -> str:
    """The kind of a file that is not a regular one, from its ``st_mode``: ``"directory"``, ``"FIFO"``,
    ``"device"``, ``"socket"``, ``"symbolic link"`` or ``"special file"``."""
    return ("directory" if stat.S_ISDIR(mode) else "FIFO" if stat.S_ISFIFO(mode)
            else "device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else "socket" if stat.S_ISSOCK(mode)
            else "symbolic link" if stat.S_ISLNK(mode) else "special file")


@contextlib.contextmanager
def open_regular(path: str | os.PathLike[str], limit: int, *, limit_text: str = "",
                 follow_symlinks: bool = True) -> Iterator[tuple[BinaryIO, int]]:
    """``(file, size)`` of the regular file ``path`` of at most ``limit`` bytes, opened for reading in binary (the
    checks of :func:`read_regular`, without reading it: for a reader that needs only a part, such as a header).
    Raises ``FileNotFoundError`` for a missing file and :class:`FileRefused` for every other refusal."""
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOCTTY", 0) | getattr(os, "O_CLOEXEC", 0)
    if not follow_symlinks:
        flags |= getattr(os, "O_NOFOLLOW", 0)
    try:
        fd = os.open(path, flags)
    except FileNotFoundError:
        raise
    except ValueError:  # a NUL character in the name
        raise FileRefused(path, "a path without NUL characters") from None
    except OSError as exc:
        if not follow_symlinks and os.path.islink(path):
            raise FileRefused(path, "a regular file (this is a symbolic link)", kind="symbolic link") from None
        raise FileRefused(path, f"a readable file ({exc.strerror or exc})") from None
    try:  # checked on the descriptor before a file object is made (which would refuse a directory its own way)
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            kind = file_kind(st.st_mode)
            raise FileRefused(path, f"a regular file (this is a {kind})", kind=kind)
        if st.st_size > limit:
            raise FileRefused(path, _too_big(limit, limit_text), f"{st.st_size} bytes", size=st.st_size)
    except BaseException as exc:
        os.close(fd)
        if isinstance(exc, OSError):
            raise FileRefused(path, f"a readable file ({exc.strerror or exc})") from None
        raise
    with os.fdopen(fd, "rb", buffering=0) as handle:
        try:
            yield handle, st.st_size
        except OSError as exc:
            raise FileRefused(path, f"a readable file ({exc.strerror or exc})") from None


def _too_big(limit: int, limit_text: str) -> str:
    return f"a file of at most {limit} bytes" + (f" {limit_text}" if limit_text else "")


def read_regular(path: str | os.PathLike[str], limit: int, *, limit_text: str = "",
                 follow_symlinks: bool = True) -> bytes:
    """The bytes of the regular file ``path``, at most ``limit`` of them (see the module). ``limit_text`` follows
    the number in the message of a file too large (``"(swarm_env.limits.MAX_FILE_BYTES)"``). Raises
    ``FileNotFoundError`` for a missing file and :class:`FileRefused` for every other refusal."""
    with open_regular(path, limit, limit_text=limit_text, follow_symlinks=follow_symlinks) as (handle, _):
        chunks: list[bytes] = []
        left = limit + 1  # a file that grows after fstat is still cut here
        while left > 0:
            chunk = handle.read(min(left, 1 << 20))
            if not chunk:
                break
            chunks.append(chunk)
            left -= len(chunk)
    if left <= 0:
        raise FileRefused(path, _too_big(limit, limit_text), "a file that grew while it was read")
    return b"".join(chunks)


class JSONTooDeep(ValueError):
    """JSON nested deeper than allowed (:func:`parse_json`): ``depth`` (``None`` when the parser found it) and
    ``limit``."""

    def __init__(self, depth: int | None, limit: int) -> None:
        self.depth, self.limit = depth, limit
        super().__init__(f"JSON nested {depth} deep, deeper than {limit}" if depth is not None
                         else f"JSON nested deeper than {limit}")


_STRING = re.compile(rb'"(?:[^"\\]|\\.)*"', re.DOTALL)
_NOT_BRACKET = re.compile(rb"[^\[\]{}]")


def _non_finite(value: Any) -> tuple[str, float] | None:
    """``(key path, value)`` of the first non-finite float in the JSON value ``value`` (document order), or ``None``."""
    stack: list[tuple[str, Any]] = [("", value)]
    while stack:
        path, v = stack.pop()
        if isinstance(v, float) and not math.isfinite(v):
            return path or "the document", v
        if isinstance(v, dict):
            stack.extend((f"{path}.{printable(k, 80)}" if path else printable(k, 80), x)
                         for k, x in reversed(v.items()))
        elif isinstance(v, list):
            stack.extend((f"{path}[{i}]", x) for i, x in reversed(list(enumerate(v))))
    return None


def parse_json(data: bytes, max_depth: int) -> Any:
    """The JSON value of ``data`` (UTF-8), nesting at most ``max_depth`` deep (checked before parsing, so a deep
    document never reaches the parser's recursion) and strict: a ``NaN``, ``Infinity`` or ``-Infinity``, or a number
    beyond the float range (``1e400``), is refused naming its key. Raises ``ValueError`` (one line) for anything
    else."""
    brackets = _NOT_BRACKET.sub(b"", _STRING.sub(b"", data))
    if brackets:
        steps = np.where(np.isin(np.frombuffer(brackets, np.uint8), (ord("["), ord("{"))), 1, -1)
        depth = int(np.cumsum(steps).max())
        if depth > max_depth:
            raise JSONTooDeep(depth, max_depth)
    try:
        value = json.loads(data.decode("utf-8"))
    except RecursionError:  # unreachable after the depth check; kept so that no parser recursion escapes
        raise JSONTooDeep(None, max_depth) from None
    except UnicodeDecodeError as exc:
        raise ValueError(f"not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    except json.JSONDecodeError as exc:
        raise ValueError(f"not JSON ({exc.msg}: line {exc.lineno} column {exc.colno})") from None
    except ValueError as exc:  # an integer of more digits than Python converts
        raise ValueError(f"not JSON ({printable(str(exc), 120)})") from None
    bad = _non_finite(value)
    if bad is not None:
        raise ValueError(f"{bad[0]}: expected a finite number, got {bad[1]!r} (NaN, Infinity and numbers beyond the "
                         "float range are not JSON numbers)")
    return value
