"""The batched engine: many worlds stepped in one call.

:mod:`~swarm_env.vector.engine` (``SwarmVectorEnv``, ``EnvFactory``), its worker processes
(:mod:`~swarm_env.vector.worker`), the batched physics and step (``world_batch``, ``batch_step``,
``batch_kernel``) and the scenario prefetcher (``scenario_prefetch``).
"""
