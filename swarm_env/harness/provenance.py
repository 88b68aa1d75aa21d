"""Where a result came from: the command, the package version, the git commit and the date.

A table that a paper cites must say how to make it again. :func:`provenance` is what the leaderboard and the
suite write beside their numbers (``leaderboard.json``'s and ``suite.json``'s ``provenance``, a line under
each Markdown title); :func:`git_state` is the one place that asks git (the training runs' ``versions.json``
use it too).
"""

from __future__ import annotations

import datetime
import shlex
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import swarm_env

__all__ = ["git_state", "provenance", "provenance_line"]

#: The repository a git checkout of the package lives in (the parent of ``swarm_env/``); an installed wheel has none.
_ROOT = Path(__file__).resolve().parents[2]


def git_state(root: str | Path = _ROOT) -> tuple[str | None, bool | None]:
    """``(commit, dirty)`` of the git work tree at ``root``: the ``HEAD`` commit and whether anything tracked or
    untracked differs from it; ``(None, None)`` outside a work tree or without git (bounded: 5 s per call)."""
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True, timeout=5)
        if commit.returncode != 0 or not commit.stdout.strip():
            return None, None
        status = subprocess.run(["git", "status", "--porcelain"], cwd=root, capture_output=True, text=True, timeout=5)
    except (OSError, subprocess.SubprocessError):
        return None, None
    return commit.stdout.strip(), bool(status.stdout.strip()) if status.returncode == 0 else None


#: The file names ``sys.argv[0]`` has when the command line is swarm-env's (the console script, or ``python -m
#: swarm_env.harness.cli``): only then is the command line the thing to cite.
_CLI_NAMES = ("swarm-env", "cli.py")


def provenance(argv: Sequence[str] | None = None) -> dict[str, Any]:
    """``{"command", "swarm_env", "git_commit", "git_dirty", "date"}`` of this process: the ``swarm-env`` command
    line as a shell would take it (``argv``, default ``sys.argv``; ``None`` when the process is not the
    ``swarm-env`` command, e.g. a script or a notebook calling the library), the package version, the checkout's
    commit (``None`` for an installed wheel) and the UTC time."""
    args = list(sys.argv if argv is None else argv)
    command = shlex.join(["swarm-env", *args[1:]]) if args and Path(args[0]).name in _CLI_NAMES else None
    commit, dirty = git_state()
    return {"command": command, "swarm_env": swarm_env.__version__, "git_commit": commit, "git_dirty": dirty,
            "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")}


def provenance_line(p: dict[str, Any]) -> str:
    """One Markdown line for a :func:`provenance` dict: ``Written by `COMMAND` (swarm-env V, commit C, DATE).``
    (``Written from Python (...)`` when there is no command line to cite.)"""
    commit = p.get("git_commit")
    where = "no git checkout" if not commit else f"commit {commit[:10]}{' + local changes' if p.get('git_dirty') else ''}"
    who = f"by `{p['command']}`" if p.get("command") else "from Python"
    return f"Written {who} (swarm-env {p.get('swarm_env')}, {where}, {p.get('date')})."
