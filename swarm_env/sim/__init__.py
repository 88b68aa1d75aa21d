"""Simulation: the pymunk world, its robots and walkers, and the compiled physics.

:mod:`~swarm_env.sim.world` (``World``: bodies, the drive law, the leader's trajectory, stepping),
:mod:`~swarm_env.sim.humans` (walkers: scripted paths, social force, ORCA through :mod:`~swarm_env.sim.rvo`),
and the compiled twins (``drive_kernel``, ``physics_kernel``, ``human_kernel``, ``snapshot_kernel``).
"""
