"""Control: pure pursuit, the velocity-obstacle search and the safety layer built on it.

:mod:`~swarm_env.control.pursuit` (the tracking law), :mod:`~swarm_env.control.vo` (the VO search the ``vo``
expert and the shield run; a change to the search is made there and in its compiled twin
:mod:`~swarm_env.control.vo_kernel`) and :mod:`~swarm_env.control.safety` (the search against everything in a
world state, and the shield that replaces unsafe actions with the nearest safe ones).
"""
