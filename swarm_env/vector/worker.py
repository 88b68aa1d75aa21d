"""A worker process of :class:`swarm_env.vector.engine.SwarmVectorEnv` (``n_procs > 1``).

Started by the engine as ``python -m swarm_env.vector.worker ADDRESS [--compiled]`` with the
connection's authentication key on standard input; receives the pickled world factories, then serves
``reset`` / ``step`` / ``state`` / ``call`` / ``close`` until told to stop or the engine goes
away. Imports neither torch nor numba by default: the engine fills the lidar columns itself, and the
velocity-obstacle search (robot leaders, the safety layer) and the per-step kernels (physics,
rewards, metrics, observations, ...) run their numpy references here, which give the compiled bits
(``swarm_env.compiled.use_compiled_search``, ``swarm_env.compiled.use_compiled_kernels``). With
``--compiled`` (``SwarmVectorEnv(..., worker_kernels=True)``) they run compiled: faster, with numba
loaded in the worker (more memory).
"""

from __future__ import annotations

import pickle
import sys
import traceback
from typing import Any

from swarm_env.compiled import use_compiled_kernels, use_compiled_search
from swarm_env.vector.engine import _WorldBlock
from swarm_env.worker_process import connect


def serve(address: str, compiled: bool = False) -> None:
    """Serve one block of worlds; ``compiled``: run the compiled kernels and search (loads numba)."""
    use_compiled_search(compiled)
    use_compiled_kernels(compiled)

    conn = connect(address)
    block: Any = None
    try:
        try:
            block = _WorldBlock(pickle.loads(conn.recv()))
            conn.send((True, block.describe()))
        except Exception:  # noqa: BLE001 - reported to the engine, which raises it
            conn.send((False, traceback.format_exc()))
            return
        while True:
            cmd, args = conn.recv()
            if cmd == "close":
                block.close()
                conn.send((True, None))
                return
            try:
                conn.send((True, getattr(block, cmd)(*args)))
            except Exception:  # noqa: BLE001 - the engine raises it with this traceback
                conn.send((False, traceback.format_exc()))
    except (EOFError, ConnectionError, KeyboardInterrupt):
        pass  # the engine is gone (or interrupted with it): nothing left to serve
    finally:
        conn.close()


def main() -> None:
    serve(sys.argv[1], compiled="--compiled" in sys.argv[2:])


if __name__ == "__main__":
    main()
