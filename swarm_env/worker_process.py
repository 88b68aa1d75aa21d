"""Starting a worker as a fresh interpreter connected back over an authenticated local socket.

The engine's workers (:mod:`swarm_env.vector.worker`) and the scenario prefetcher
(:mod:`swarm_env.vector.scenario_prefetch`) are started this way rather than by ``multiprocessing``: a spawned or
forkserver child re-imports the parent's ``__main__`` (a training script importing torch), and a forked
one inherits torch's threads. The worker reads the connection's key from its standard input and connects
to the address given as its first argument (:func:`connect`).
"""

from __future__ import annotations

import os
import subprocess
import sys
from multiprocessing.connection import Client, Connection, Listener

__all__ = ["connect", "start_worker"]


def start_worker(module: str, *args: str) -> tuple[subprocess.Popen, Connection]:
    """Run ``python -m module ADDRESS *args`` with one BLAS/OpenMP thread and return it with its connection."""
    authkey = os.urandom(32)
    with Listener(authkey=authkey) as listener:
        env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
        proc = subprocess.Popen([sys.executable, "-m", module, str(listener.address), *args], stdin=subprocess.PIPE,
                                env=env)
        assert proc.stdin is not None
        proc.stdin.write(authkey.hex().encode() + b"\n")
        proc.stdin.close()
        return proc, listener.accept()


def connect(address: str) -> Connection:
    """The worker's side: connect to ``address`` with the key on standard input."""
    return Client(address, authkey=bytes.fromhex(sys.stdin.readline().strip()))
