"""``swarm-env convert``: write the tensors + JSON files (:mod:`swarm_env_baselines.safe_io`) beside the pickles of
older SB3 run directories, so that loading them no longer unpickles anything."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from swarm_env.checks import DefaultsHelpFormatter
from swarm_env_baselines.model_io import load_model
from swarm_env_baselines.safe_io import CONFIG_FILE, WEIGHTS_FILE, save_policy

__all__ = ["main"]


def main(argv: list[str] | None = None) -> int:
    """``swarm-env convert DIR [DIR ...] [--algo ppo] --trust-pickle``: write the tensors + JSON
    files beside the ``model.zip`` / ``vecnormalize.pkl`` of older run directories.

    Converting unpickles those files once, so it asks for the same opt-in as loading them
    (``--trust-pickle`` or ``SWARM_ENV_TRUST_PICKLE=1``): run it only on files you trust (your own
    runs). Exit code 2, with one line naming the file, for a missing, corrupt or refused file.
    """
    parser = argparse.ArgumentParser(formatter_class=DefaultsHelpFormatter, prog="swarm-env convert", description=main.__doc__.split("\n\n")[0])
    parser.add_argument("dirs", nargs="+", help="run or checkpoint directories holding model.zip")
    parser.add_argument("--algo", default="ppo", help="the algorithm that saved them (ppo, sac, a2c, td3, ddpg; bc = ppo)")
    parser.add_argument("--trust-pickle", action="store_true",
                        help="unpickle the files (they can run code): only for files you trust")
    args = parser.parse_args(argv)
    for d in args.dirs:
        try:
            model, vecnorm = load_model(d, args.algo, trust_pickle=args.trust_pickle or None)  # None: SWARM_ENV_TRUST_PICKLE decides
        except (FileNotFoundError, ValueError) as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        out = save_policy(model, Path(d) if Path(d).is_dir() else Path(d).parent, type(model).__name__.lower(), vecnorm)
        print(f"wrote {out / WEIGHTS_FILE} and {out / CONFIG_FILE}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
