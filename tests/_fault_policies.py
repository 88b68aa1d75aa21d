"""Policies that fail on purpose, for tests/test_eval_faults.py (registered there through an entry point
in a temporary ``*.dist-info``, so that spawned pool workers and subprocesses find them too).

Each plays :class:`~swarm_env.harness.policies.PursuitPolicy` except on the seeds named by its argument
(``crash:1,2``), where its first ``act`` of the episode

* ``crash``: ends the process at once (``os._exit``, as a segfault or the OOM killer would);
* ``hang``: sleeps for an hour (a deadlock);
* ``flaky``: ends the process the first time only (a marker file in ``$SWARM_ENV_FAULT_DIR`` remembers it);
* ``slow``: sleeps ``$SWARM_ENV_FAULT_SLEEP`` seconds (default 1), then plays (to interrupt a sweep midway).
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

from swarm_env.harness.policies import PursuitPolicy


class _Faulty(PursuitPolicy):
    mode = ""

    def __init__(self, env: Any, arg: str | None = None) -> None:
        super().__init__(env)
        self.bad = {int(s) for s in (arg or "").split(",") if s}
        self.seed: int | None = None
        self.fired = False

    def reset(self, env: Any, seed: int | None) -> None:
        super().reset(env, seed)
        self.seed, self.fired = seed, False

    def act(self, observations: Any, state: Any) -> dict[str, Any]:
        if self.seed in self.bad and not self.fired:
            self.fired = True
            if self.mode == "crash":
                os._exit(3)
            if self.mode == "hang":
                time.sleep(3600)
            if self.mode == "flaky":
                marker = Path(os.environ["SWARM_ENV_FAULT_DIR"]) / f"flaky-{self.seed}"
                if not marker.exists():
                    marker.touch()
                    os._exit(3)
            if self.mode == "slow":
                time.sleep(float(os.environ.get("SWARM_ENV_FAULT_SLEEP", "1")))
        return super().act(observations, state)


class Crash(_Faulty):
    mode = "crash"


class Hang(_Faulty):
    mode = "hang"


class Flaky(_Faulty):
    mode = "flaky"


class Slow(_Faulty):
    mode = "slow"
