"""Optional extras: one clear error when a feature's extra is not installed."""

from __future__ import annotations

import importlib
from types import ModuleType

__all__ = ["MissingExtraError", "require"]


class MissingExtraError(RuntimeError):
    """A feature needs an optional extra that is not installed (the message names the pip command)."""


def require(module: str, extra: str, feature: str) -> ModuleType:
    """Import ``module``, or raise :class:`MissingExtraError` saying ``feature`` needs
    ``pip install 'swarm-env[extra]'``."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise MissingExtraError(f"{feature} needs the optional extra: pip install 'swarm-env[{extra}]' "
                                f"(or pip install -e '.[{extra}]' in a checkout); {exc}") from None
