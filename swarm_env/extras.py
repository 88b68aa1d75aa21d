"""Optional extras: one clear error when a feature's extra is not installed.

The extras and what they install are read from this distribution's own metadata (its
``pyproject.toml``'s ``[project.optional-dependencies]``), so no list of them is kept here.
"""

from __future__ import annotations

import importlib
import re
from importlib import metadata
from types import ModuleType

__all__ = ["MissingExtraError", "require", "missing_extra_error", "extra_for_module", "missing_distributions"]

#: This project's distribution name (what ``pip install`` takes).
DISTRIBUTION = "swarm-env"


class MissingExtraError(RuntimeError):
    """A feature needs an optional extra that is not installed (the message names the pip command)."""


def missing_extra_error(extra: str, feature: str, detail: str, distribution: str = DISTRIBUTION) -> MissingExtraError:
    """The one-line error saying that ``feature`` needs ``pip install 'swarm-env[extra]'`` (``detail``:
    what failed, e.g. ``No module named 'torch'``; ``distribution``: whose extra it is)."""
    return MissingExtraError(f"{feature} needs the optional extra: pip install '{distribution}[{extra}]' "
                             f"(or pip install -e '.[{extra}]' in a checkout); {detail}")


def require(module: str, extra: str, feature: str) -> ModuleType:
    """Import ``module``, or raise :class:`MissingExtraError` saying ``feature`` needs
    ``pip install 'swarm-env[extra]'``."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise missing_extra_error(extra, feature, str(exc)) from None


def _normalize(name: str) -> str:
    """A distribution or module name in the form PEP 503 compares (``stable_baselines3`` -> ``stable-baselines3``)."""
    return re.sub(r"[-_.]+", "-", name).lower()


def _extra_distributions(distribution: str = DISTRIBUTION) -> dict[str, list[str]]:
    """Extra -> the normalised names of the distributions it installs, in ``pyproject.toml``'s order;
    empty when ``distribution`` is not installed (e.g. a bare checkout on ``sys.path``)."""
    try:
        requirements = metadata.requires(distribution) or []
    except metadata.PackageNotFoundError:
        return {}
    extras: dict[str, list[str]] = {}
    for req in requirements:
        name = re.match(r"\s*([A-Za-z0-9][A-Za-z0-9._-]*)", req)
        extra = re.search(r"""extra\s*==\s*["']([^"']+)["']""", req)
        if name and extra:
            extras.setdefault(extra.group(1), []).append(_normalize(name.group(1)))
    return extras


def _installed(distribution: str) -> bool:
    try:
        metadata.distribution(distribution)
    except metadata.PackageNotFoundError:
        return False
    return True


def extra_for_module(module: str | None) -> str | None:
    """The first extra (in ``pyproject.toml``'s order) that installs the top-level package of ``module``
    (``"stable_baselines3.common"`` -> ``"rl"``), or ``None``. A package is matched to the
    distribution of the same normalised name, which holds for every module the extras provide."""
    if not module:
        return None
    top = _normalize(module.split(".")[0])
    for extra, distributions in _extra_distributions().items():
        if top in distributions:
            return extra
    return None


def missing_distributions(extras: str, distribution: str = DISTRIBUTION) -> list[str]:
    """The distributions that ``distribution``'s ``extras`` (one name, or several joined by commas as pip
    writes them: ``"rl,ray"``) install and that are not installed; ``[]`` when all are, or when the extra
    is unknown."""
    wanted = _extra_distributions(distribution)
    missing: list[str] = []
    for extra in filter(None, (e.strip() for e in extras.split(","))):
        missing += [d for d in wanted.get(extra, []) if d not in missing and not _installed(d)]
    return missing
