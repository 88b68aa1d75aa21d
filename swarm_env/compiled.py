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
velocity-obstacle search has its own switch (:func:`swarm_env.control.guidance.use_compiled_search`).
"""

from __future__ import annotations

_ENABLED = True


def use_compiled_kernels(flag: bool) -> None:
    """Run the per-step kernels compiled (``True``, the default) or as their numpy references
    (``False``): the same results either way."""
    global _ENABLED
    _ENABLED = bool(flag)


def compiled_kernels() -> bool:
    """Whether the per-step kernels run compiled (see :func:`use_compiled_kernels`)."""
    return _ENABLED


__all__ = ["compiled_kernels", "use_compiled_kernels"]
