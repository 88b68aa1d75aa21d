"""Checks of option values shared by the experts' and the search's parameter objects: one wording for one rule.

Each raises ``ValueError`` naming the option, what was expected and what was given, prefixed by ``owner``
(``"obs_expert: horizon must be a finite number > 0, got 0"``; no prefix for ``owner=""``)."""

from __future__ import annotations

import difflib
import math
from collections.abc import Iterable, Mapping
from typing import Any

__all__ = ["did_you_mean", "finite_numbers", "int_in_range"]


def finite_numbers(owner: str, values: Mapping[str, Any], *, positive: bool) -> None:
    """Every value is an int or float, finite and ``> 0`` (``positive``) or ``>= 0``; the first that is not raises."""
    for name, value in values.items():
        if not (isinstance(value, (int, float)) and math.isfinite(value) and (value > 0 if positive else value >= 0)):
            raise ValueError(f"{_prefix(owner)}{name} must be a finite number {'>' if positive else '>='} 0, "
                             f"got {value!r}")


def int_in_range(owner: str, values: Mapping[str, Any], low: int, high: int | None = None) -> None:
    """Every value is an int (not a bool) in ``[low, high]`` (``high`` ``None``: no upper bound)."""
    for name, value in values.items():
        if isinstance(value, bool) or not isinstance(value, int) or value < low or (high is not None and value > high):
            span = f">= {low}" if high is None else f"in [{low}, {high}]"
            raise ValueError(f"{_prefix(owner)}{name} must be an int {span}, got {value!r}")


def _prefix(owner: str) -> str:
    return f"{owner}: " if owner else ""


def did_you_mean(word: object, choices: Iterable[str]) -> str:
    """``" (did you mean 'vo'?)"`` for the closest of ``choices`` to a mistyped ``word``, or ``""`` when none is
    close (or ``word`` is not a short string: a typo is short)."""
    if not isinstance(word, str) or len(word) > 100:
        return ""
    close = difflib.get_close_matches(word, list(choices), n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""
