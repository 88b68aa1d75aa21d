"""Checks of option values shared by the experts' and the search's parameter objects: one wording for one rule.

Each raises ``ValueError`` naming the option, what was expected and what was given, prefixed by ``owner``
(``"obs_expert: horizon must be a finite number > 0, got 0"``; no prefix for ``owner=""``)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

__all__ = ["finite_numbers", "int_in_range"]


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
