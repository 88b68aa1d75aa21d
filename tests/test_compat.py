"""swarm_env._compat: the newer standard library's behaviour on Python 3.10."""

from __future__ import annotations

import sys
import types

import pytest

import swarm_env._compat as compat


def test_add_note_appends_in_order() -> None:
    exc = KeyError("k")
    assert not hasattr(exc, "__notes__")
    compat.add_note(exc, "first")
    compat.add_note(exc, "second")
    assert exc.__notes__ == ["first", "second"]
    with pytest.raises(TypeError):
        compat.add_note(exc, 3)  # type: ignore[arg-type]
    assert exc.__notes__ == ["first", "second"]


def test_the_310_fallback_matches_the_builtin(monkeypatch: pytest.MonkeyPatch) -> None:
    def notes(exc: BaseException) -> list[str]:
        compat.add_note(exc, "first")
        compat.add_note(exc, "second")
        with pytest.raises(TypeError):
            compat.add_note(exc, b"bytes")  # type: ignore[arg-type]
        return list(exc.__notes__)

    here = notes(RuntimeError("a"))
    monkeypatch.setattr(compat, "sys", types.SimpleNamespace(version_info=(3, 10, 13)))
    fallback_error = RuntimeError("a")
    assert notes(fallback_error) == here == ["first", "second"]
    if sys.version_info >= (3, 11):  # the fallback's list is the one the builtin would extend
        fallback_error.add_note("third")
        assert fallback_error.__notes__ == ["first", "second", "third"]
