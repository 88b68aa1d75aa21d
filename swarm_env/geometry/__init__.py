"""Geometry: the static map of a world and what is computed on it.

:mod:`~swarm_env.geometry.static_map` (``StaticMap``: obstacles, walls, free-space queries, polygon operations),
:mod:`~swarm_env.geometry.paths` (the leader's and walkers' paths), :mod:`~swarm_env.geometry.formation`
(formation shapes and the followers' slots), and their compiled twins (``slot_kernel``, ``clearance_kernel``).
Imports only the package's base modules (``scenario``, ``limits``, ``compiled``).
"""
