"""What the standard library gained after Python 3.10, the oldest version this package supports.

Each helper behaves exactly as the newer built-in on the versions that have it, and does the closest
thing on the older ones.
"""

from __future__ import annotations

import sys

__all__ = ["add_note"]


def add_note(exc: BaseException, note: str) -> None:
    """Attach ``note`` to ``exc``: :meth:`BaseException.add_note` on Python 3.11 and later.

    Python 3.10 has no ``add_note``; there the note is appended to ``exc.__notes__`` (a list, created
    when missing), the attribute that 3.11's ``add_note`` fills. Readers of ``__notes__`` (pytest, the
    ``exceptiongroup`` backport's traceback printer) then show it; 3.10's own traceback printer does not.
    Raises ``TypeError`` when ``note`` is not a ``str``, as ``add_note`` does.
    """
    if sys.version_info >= (3, 11):
        exc.add_note(note)
        return
    if not isinstance(note, str):
        raise TypeError(f"note must be a str, not {type(note).__name__}")
    notes = getattr(exc, "__notes__", None)
    if notes is None:
        notes = []
        exc.__notes__ = notes  # type: ignore[attr-defined, unused-ignore]  # not in 3.10's typeshed
    notes.append(note)
