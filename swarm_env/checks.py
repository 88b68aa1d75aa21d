"""Checks of option values shared by the experts' and the search's parameter objects: one wording for one rule.

Also :class:`DefaultsHelpFormatter`, the ``--help`` layout of every ``swarm-env`` command (one rule: each option
shows its default).

Each check raises ``ValueError`` naming the option, what was expected and what was given, prefixed by ``owner``
(``"obs_expert: horizon must be a finite number > 0, got 0"``; no prefix for ``owner=""``)."""

from __future__ import annotations

import argparse
import difflib
import math
from collections.abc import Iterable, Mapping
from typing import Any

__all__ = ["DefaultsHelpFormatter", "did_you_mean", "finite_numbers", "int_in_range"]


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


class DefaultsHelpFormatter(argparse.RawDescriptionHelpFormatter):
    """``--help`` that shows each option's default, ``(default: 4)``, after its help text, except where there is
    nothing to show (no default, an empty list, a flag) or the help already speaks of it; descriptions and
    epilogs keep their line breaks. Every ``swarm-env`` parser (the subcommands and the modules' commands) uses
    it."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        default = action.default
        # flags (a bool default) say what they do; "(default: True)" beside --no-progress would only confuse
        if (not text or "default" in text.lower() or default is None or isinstance(default, bool)
                or default == argparse.SUPPRESS or (isinstance(default, (list, tuple, dict)) and not default)):
            return action.help
        return f"{text} (default: %(default)s)"
