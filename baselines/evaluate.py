"""``python -m swarm_env_baselines.evaluate ...``: the leaderboard command, same as ``swarm-env evaluate ...``.

One implementation lives in :mod:`swarm_env.harness.leaderboard` (and :func:`swarm_env.harness.cli.cmd_evaluate`);
this module forwards its arguments there. RL models take part as registered policies
(``ppo:PATH``, ``bc:PATH``, ... in the ``swarm_env.policies`` entry-point group), like the experts.
"""

from __future__ import annotations

import sys

from swarm_env.harness.cli import main as swarm_env_main


def main(argv: list[str] | None = None) -> int:
    """Run ``swarm-env evaluate`` with ``argv`` (default: ``sys.argv[1:]``); returns the exit code."""
    return swarm_env_main(["evaluate", *(sys.argv[1:] if argv is None else argv)])


if __name__ == "__main__":
    sys.exit(main())
