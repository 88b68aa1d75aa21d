"""Scripted expert policies for swarm-env (pure pursuit + VO, CBS + motion-primitive RRT).

The experts arrive with their own issues; each registers itself in the ``swarm_env.policies``
entry-point group. They read ``swarm_env``'s data types and never import pymunk.
"""
