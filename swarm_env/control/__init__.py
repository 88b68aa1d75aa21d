"""Control: the velocity-obstacle search and the safety layer built on it.

:mod:`~swarm_env.control.guidance` (pure pursuit and the VO search the ``vo`` expert runs),
:mod:`~swarm_env.control.vo_kernel` (its compiled twin) and :mod:`~swarm_env.control.safety` (the shield that
replaces unsafe actions with the nearest safe ones).
"""
