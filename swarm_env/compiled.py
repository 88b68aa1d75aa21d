"""One switch for the compiled (numba) per-step kernels of the core: the observations' assembly
(:mod:`swarm_env.sensing.obs_kernel`), the followers' clearances and static distances
(:mod:`swarm_env.geometry.clearance_kernel`), the snapshot's arrays (:mod:`swarm_env.sim.snapshot_kernel`), the
scripted humans (:mod:`swarm_env.sim.human_kernel`), a control step's physics substeps with chipmunk
called from compiled code (:mod:`swarm_env.sim.physics_kernel`), the virtual leader and the slot targets
(:mod:`swarm_env.geometry.slot_kernel`), the rewards and the metrics of a step (:mod:`swarm_env.scoring.step_kernel`),
the robots' velocity callback (:mod:`swarm_env.sim.drive_kernel`, chosen when a world is built), the
physics and snapshots of many worlds in one call (:mod:`swarm_env.vector.world_batch`), and the batched
engine's global state of many worlds (:mod:`swarm_env.sensing.state_kernel`).

Each kernel has a numpy reference beside it that gives the same bits (their tests compare the
two on whole episodes). The references import no numba, which is why the batched engine's worker
processes (:mod:`swarm_env.vector.worker`) switch the kernels off: the workers' memory target. The
velocity-obstacle search (:func:`swarm_env.control.vo.vo_select_batch` and
:mod:`swarm_env.control.vo_kernel`) has a switch of its own here, as the experts' tests compare it alone.

This module holds the only state of the choice: :func:`compiled_mode` sets it for a block and restores it after;
:func:`use_compiled_kernels` and :func:`use_compiled_search` set it for the process (a worker at its start).
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

_KERNELS = True
_SEARCH = True


def use_compiled_kernels(flag: bool) -> None:
    """Run the per-step kernels compiled (``True``, the default) or as their numpy references
    (``False``) from now on in this process: the same results either way."""
    global _KERNELS
    _KERNELS = bool(flag)


def use_compiled_search(flag: bool) -> None:
    """Run the velocity-obstacle search compiled (``True``, the default) or as its numpy reference (``False``)
    from now on in this process. Both give the same bits (``tests/test_vo_kernel.py``); the reference imports no
    numba, which is why the batched engine's worker processes use it."""
    global _SEARCH
    _SEARCH = bool(flag)


def compiled_kernels() -> bool:
    """Whether the per-step kernels run compiled (see :func:`use_compiled_kernels`)."""
    return _KERNELS


def compiled_search() -> bool:
    """Whether the velocity-obstacle search runs compiled (see :func:`use_compiled_search`)."""
    return _SEARCH


@contextmanager
def compiled_mode(kernels: bool | None = None, search: bool | None = None) -> Iterator[None]:
    """Run the block with the per-step kernels and/or the search compiled (``True``) or as references
    (``False``); ``None`` leaves that switch as it is. The previous choice comes back on exit, exception or not::

        with compiled_mode(kernels=False):
            env.step(actions)  # the numpy references
    """
    before = (_KERNELS, _SEARCH)
    if kernels is not None:
        use_compiled_kernels(kernels)
    if search is not None:
        use_compiled_search(search)
    try:
        yield
    finally:
        use_compiled_kernels(before[0])
        use_compiled_search(before[1])


__all__ = ["compiled_kernels", "compiled_mode", "compiled_search", "use_compiled_kernels", "use_compiled_search"]
