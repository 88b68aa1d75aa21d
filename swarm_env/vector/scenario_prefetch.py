"""The next random worlds drawn in a background process, with the same bits.

A ``random`` :class:`~swarm_env.env.SwarmEnv` draws each episode's scenario from its own generator
(``SwarmEnv._rng``) and uses that generator for nothing else, so the next episode's scenario is fixed
the moment an episode begins: ``random_scenario(the generator as it is now, config)``. Drawing it costs
several milliseconds (the generator's rejection sampling and the scenario's validation), and all the
worlds of a batch that started together time out together, so their draws arrive as one wave.

:class:`ScenarioPrefetcher` draws them in one worker process while the worlds step: :meth:`submit` sends
a world's generator state as its episode begins; when the world starts its next episode, :meth:`take`
returns the drawn scenario (and moves the world's generator to the state after the draw) if that job
started from exactly the generator's current state and has come back, and ``None`` otherwise, when the
world draws it itself. The scenario is the same either way, so the timing of the worker never changes
a result (``tests/test_vector.py``).

The worker is a fresh interpreter (``python -m swarm_env.vector.scenario_prefetch ADDRESS``), started as the
engine's workers are (:mod:`swarm_env.worker_process`).
"""

from __future__ import annotations

import subprocess
import sys
from collections import deque
from collections.abc import Mapping
from multiprocessing.connection import Connection
from typing import Any

import numpy as np

from swarm_env.scenario import Scenario
from swarm_env.scenarios.generator import RandomScenarioConfig, random_scenario
from swarm_env.worker_process import connect, start_worker

__all__ = ["ScenarioPrefetcher"]

#: Jobs sent to the worker and not answered yet, at most: the rest wait here. Sends stay far below a socket's
#: buffer, so this process never blocks on one while the worker blocks sending answers nobody reads.
_IN_FLIGHT = 8


class ScenarioPrefetcher:
    """One worker process that draws random scenarios ahead; see the module docstring.

    ``hits`` and ``misses`` count the :meth:`take` calls that found their scenario drawn or not.
    """

    def __init__(self) -> None:
        self._proc, conn = start_worker("swarm_env.vector.scenario_prefetch")
        self._conn: Connection | None = conn
        self._asked: dict[Any, Mapping[str, Any]] = {}  # key -> the generator state its pending job started from
        self._drawn: dict[Any, tuple[Mapping[str, Any], Scenario, Mapping[str, Any]]] = {}  # key -> (from, scenario, after)
        self._waiting: deque[tuple[Any, Mapping[str, Any], RandomScenarioConfig]] = deque()  # not sent yet
        self._in_flight = 0
        self.hits = self.misses = 0

    def submit(self, key: Any, rng: np.random.Generator, config: RandomScenarioConfig) -> None:
        """Draw ``random_scenario(rng, config)`` for ``key`` in the worker, from ``rng``'s current state (``rng``
        itself is not moved). A job of ``key`` still pending is superseded."""
        if self._conn is None:
            return
        state = rng.bit_generator.state
        self._asked[key] = state
        self._drawn.pop(key, None)
        self._waiting.append((key, state, config))
        self.poll()

    def take(self, key: Any, rng: np.random.Generator) -> Scenario | None:
        """The scenario drawn for ``key`` from ``rng``'s current state, ``rng`` moved past the draw; or ``None``
        (nothing drawn yet, or drawn from another state): then ``rng`` is untouched and the caller draws."""
        self.poll()
        self._asked.pop(key, None)
        got = self._drawn.pop(key, None)
        if got is None or got[0] != rng.bit_generator.state:
            self.misses += 1
            return None
        rng.bit_generator.state = got[2]
        self.hits += 1
        return got[1]

    def ready(self, key: Any) -> bool:
        """Whether ``key``'s scenario has come back (collecting what has, without waiting)."""
        self.poll()
        return key in self._drawn

    def poll(self) -> None:
        """Collect the drawn scenarios that have come back and send waiting jobs (without waiting)."""
        conn = self._conn
        try:
            while conn is not None and conn.poll():
                key, before, scenario, after = conn.recv()
                self._in_flight -= 1
                if self._asked.get(key) == before:  # not superseded since
                    self._drawn[key] = (before, scenario, after)
            while conn is not None and self._waiting and self._in_flight < _IN_FLIGHT:
                key, state, config = self._waiting.popleft()
                if self._asked.get(key) == state:  # superseded or taken jobs are not sent
                    conn.send((key, state, config))
                    self._in_flight += 1
        except (EOFError, OSError, ValueError):  # the worker is gone: the worlds draw their own from now on
            self._stop()

    def _stop(self) -> None:
        if self._conn is not None:
            self._conn.close()
            self._conn = None

    def close(self) -> None:
        """Stop the worker (it ends when its connection closes)."""
        self._stop()
        try:
            self._proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self._proc.kill()

    def __del__(self) -> None:
        if getattr(self, "_conn", None) is not None:
            self.close()


def serve(address: str) -> None:
    """The worker: for each ``(key, state, config)`` received, send back ``(key, state, scenario, state after)``."""
    conn = connect(address)
    try:
        while True:
            key, state, config = conn.recv()
            rng = np.random.Generator(getattr(np.random, state["bit_generator"])())
            rng.bit_generator.state = state
            scenario = random_scenario(rng, config)
            conn.send((key, state, scenario, rng.bit_generator.state))
    except (EOFError, ConnectionError, KeyboardInterrupt):
        pass  # the engine is gone: nothing left to draw
    finally:
        conn.close()


if __name__ == "__main__":
    serve(sys.argv[1])
