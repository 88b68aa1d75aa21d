"""``swarm_env.reading``: the one bounded reader of untrusted files (scenarios, records, model files, checkpoints).

Every kind of file that is not a regular one is refused without waiting and without a file object's own error
(a directory once gave ``IsADirectoryError`` through the scenario loader: ``benchmarks/reliability_probes.py``
caught it), a file over the limit is refused before it is read, and ``open_regular`` gives the size it checked.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import pytest

from swarm_env.reading import FileRefused, JSONTooDeep, open_regular, parse_json, read_regular


@pytest.fixture
def small(tmp_path: Path) -> Path:
    path = tmp_path / "small.bin"
    path.write_bytes(b"0123456789")
    return path


def test_a_regular_file_within_the_limit_is_read_whole(small: Path) -> None:
    assert read_regular(small, 10) == b"0123456789"
    with open_regular(small, 10) as (handle, size):
        assert size == 10 and handle.read(4) == b"0123"


@pytest.mark.parametrize("make, kind", [
    (lambda d: d, "directory"),
    (lambda d: (os.mkfifo(d / "fifo"), d / "fifo")[1], "FIFO"),
    (lambda d: Path("/dev/zero"), "device"),
], ids=["directory", "fifo", "device"])
@pytest.mark.parametrize("reader", ["read_regular", "open_regular"])
def test_what_is_not_a_regular_file_is_refused_without_waiting(tmp_path: Path, make, kind: str, reader: str) -> None:
    path = make(tmp_path)
    start = time.perf_counter()
    with pytest.raises(FileRefused) as info:
        if reader == "read_regular":
            read_regular(path, 100)
        else:
            with open_regular(path, 100):
                pass
    assert time.perf_counter() - start < 1.0
    assert info.value.kind == kind and f"a regular file (this is a {kind})" in str(info.value)


def test_a_file_over_the_limit_is_refused_before_reading(small: Path) -> None:
    with pytest.raises(FileRefused) as info:
        read_regular(small, 9, limit_text="(THE_LIMIT)")
    assert info.value.size == 10 and "a file of at most 9 bytes (THE_LIMIT)" in str(info.value)


def test_a_symlink_is_refused_only_when_asked(small: Path, tmp_path: Path) -> None:
    link = tmp_path / "link"
    link.symlink_to(small)
    assert read_regular(link, 100) == b"0123456789"
    with pytest.raises(FileRefused, match="this is a symbolic link"):
        read_regular(link, 100, follow_symlinks=False)


def test_missing_files_and_bad_names(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError):
        read_regular(tmp_path / "nothing", 100)
    with pytest.raises(FileRefused, match="without NUL"):
        read_regular(str(tmp_path / "a\0b"), 100)


def test_json_is_strict_and_its_depth_bounded_before_parsing() -> None:
    assert parse_json(b'{"a": [1, 2.5]}', 4) == {"a": [1, 2.5]}
    with pytest.raises(JSONTooDeep):
        parse_json(b"[" * 100_000 + b"]" * 100_000, 32)
    with pytest.raises(ValueError):
        parse_json(b"[NaN]", 4)
