"""What every trainer's command line and run directory share: dataclass fields as options, versions.

* :func:`add_dataclass_options`: one command-line option per field of a config dataclass, its help
  the ``#:`` comment above the field (:func:`field_help`).
* :func:`package_versions`: the interpreter, platform, package versions and git commit a run was made
  with (``versions.json`` of every run directory).

Imports neither stable-baselines3 nor torch.
"""

from __future__ import annotations

import argparse
import dataclasses
import platform
import sys
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

from swarm_env.checks import DefaultsHelpFormatter
from swarm_env.harness.cli import parse_env_item
from swarm_env.harness.provenance import git_state

__all__ = ["PACKAGES", "add_dataclass_options", "field_help", "int_arg", "package_versions", "trainer_parser"]

PACKAGES = ("swarm-env", "numpy", "torch", "stable-baselines3", "gymnasium", "pettingzoo", "pymunk", "tensorboard")


def package_versions() -> dict[str, Any]:
    """Interpreter, platform, package versions and the git commit of the working directory (if any)."""
    versions: dict[str, Any] = {"python": sys.version.split()[0], "platform": platform.platform()}
    for pkg in PACKAGES:
        try:
            versions[pkg] = version(pkg)
        except PackageNotFoundError:
            versions[pkg] = None
    versions["git_commit"], versions["git_dirty"] = git_state(Path(__file__).resolve().parent.parent)
    versions["argv"] = sys.argv
    return versions



def field_help(cls: type) -> dict[str, str]:
    """The ``#:`` comment above each dataclass field, by field name (the CLI help text)."""
    import inspect

    lines = inspect.getsource(cls).splitlines()
    helps: dict[str, str] = {}
    pending: list[str] = []
    for line in lines:
        stripped = line.strip()
        if stripped.startswith("#:"):
            pending.append(stripped[2:].strip())
            continue
        name = stripped.split(":", 1)[0]
        if pending and name.isidentifier():
            helps[name] = " ".join(pending)
        pending = []
    return helps


def int_arg(text: str) -> int:
    """An integer option that may be written as 2e6 or 2_000_000."""
    import argparse

    try:
        value = float(text.replace("_", ""))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if not value.is_integer():
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}")
    return int(value)


def add_dataclass_options(parser: argparse.ArgumentParser, cls: type, *, required: tuple[str, ...] = ()) -> None:
    """One option per field of the dataclass ``cls`` (``total_steps`` -> ``--total-steps``).

    Help text = the field's ``#:`` comment plus its default; options left out
    are absent from the parsed namespace (``argparse.SUPPRESS``), so the
    dataclass's own defaults apply. Bools get ``--x/--no-x``, ints accept
    ``2e6``, tuples take several ints, and a field named ``env_kwargs`` (``x_env_kwargs``)
    becomes a repeatable ``--env KEY=VALUE`` (``--x-env``; YAML values) collected as a list of pairs.
    """
    import argparse


    def env_item(text: str) -> tuple[str, Any]:
        try:
            return parse_env_item(text)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    helps = field_help(cls)
    for f in dataclasses.fields(cls):
        flag = "--" + f.name.replace("_", "-")
        default = f.default if f.default is not dataclasses.MISSING else f.default_factory()  # type: ignore[misc]
        shown = list(default) if isinstance(default, tuple) else default
        kwargs: dict[str, Any] = {"help": f"{helps.get(f.name, '')} (default: {shown})", "default": argparse.SUPPRESS}
        if f.name.endswith("env_kwargs"):  # env_kwargs -> --env, train_env_kwargs -> --train-env
            env_flag = "--" + f.name[: -len("_kwargs")].replace("_", "-")
            parser.add_argument(env_flag, dest=f.name, type=env_item, action="append", metavar="KEY=VALUE", **kwargs)
        elif isinstance(default, bool):
            parser.add_argument(flag, action=argparse.BooleanOptionalAction, **kwargs)
        elif isinstance(default, int):
            parser.add_argument(flag, type=int_arg, **kwargs)
        elif isinstance(default, float):
            parser.add_argument(flag, type=float, **kwargs)
        elif isinstance(default, tuple):
            parser.add_argument(flag, type=int, nargs="+", **kwargs)
        else:
            parser.add_argument(flag, type=str, required=f.name in required, **kwargs)


def trainer_parser(prog: str, doc: str | None, config: type, resume_overrides: tuple[str, ...]) -> argparse.ArgumentParser:
    """The command line of a trainer: one option per field of ``config`` and ``--resume RUN_DIR`` (with which only
    the fields ``resume_overrides`` may be given)."""
    parser = argparse.ArgumentParser(formatter_class=DefaultsHelpFormatter, prog=prog, description=(doc or "").split("\n\n")[0])
    allowed = ", ".join("--" + name.replace("_", "-") for name in resume_overrides)
    parser.add_argument("--resume", metavar="RUN_DIR", default=argparse.SUPPRESS,
                        help=f"go on with this run from its latest checkpoint (its config.json; only {allowed} may be "
                             "given with it)")
    add_dataclass_options(parser, config)
    return parser
