"""Scripted expert policies for swarm-env (pure pursuit + VO, CBS + motion-primitive RRT).

Installed as ``swarm_env_agents`` (the repository keeps it in ``agents/``, a name many projects
use). Each expert registers itself in the ``swarm_env.policies`` entry-point group.
They read ``swarm_env``'s data types and never import pymunk.
"""
