"""Sensing: what an agent observes and what the central critic reads.

:mod:`~swarm_env.sensing.observations` (the observation vector and its layout), :mod:`~swarm_env.sensing.lidar`
(the range sensor), and the compiled twins (``obs_kernel``; ``state_kernel``, the critic's global state of many
worlds in one call).
"""
