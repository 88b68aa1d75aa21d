"""Scoring: rewards and episode metrics.

:mod:`~swarm_env.scoring.rewards` (the reward terms), :mod:`~swarm_env.scoring.metrics` (collisions, formation
error, settling, success) and their compiled twin (``step_kernel``).
"""
