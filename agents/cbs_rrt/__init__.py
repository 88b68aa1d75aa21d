"""Paper 000's centralized planner: CBS over motion-primitive RRT, with a formation layer.

Modules (one job each):

* :mod:`~swarm_env_agents.cbs_rrt.primitives` — motion primitives (exact arcs);
* :mod:`~swarm_env_agents.cbs_rrt.distance_field` — precomputed clearance grid, bilinear lookups;
* :mod:`~swarm_env_agents.cbs_rrt.timed_path` — timed paths ``(x, y, theta, t)``;
* :mod:`~swarm_env_agents.cbs_rrt.conflicts` — continuous conflict detection between timed paths;
* :mod:`~swarm_env_agents.cbs_rrt.constraints` — space-time constraints and their lookup table;
* :mod:`~swarm_env_agents.cbs_rrt.rrt` — goal-biased space-time RRT over primitives, with smoothing;
* :mod:`~swarm_env_agents.cbs_rrt.cbs` — Conflict-Based Search, generic over the low-level planner;
* :mod:`~swarm_env_agents.cbs_rrt.grid` — grid space-time A* and grid conflicts (tests, teaching);
* :mod:`~swarm_env_agents.cbs_rrt.swarm` — the swarm's CBS instance (RRT low level, timed conflicts);
* :mod:`~swarm_env_agents.cbs_rrt.goals` — the formation layer: goal courses from the leader's prediction;
* :mod:`~swarm_env_agents.cbs_rrt.policy` — :class:`CBSRRTExpert`, the swarm-env policy (``cbs_rrt``);
* :mod:`~swarm_env_agents.cbs_rrt.paper` — reproduces paper 000's figures and table.
"""

from swarm_env_agents.cbs_rrt.cbs import CBS, CBSResult
from swarm_env_agents.cbs_rrt.policy import CBSRRTExpert, make_policy

__all__ = ["CBS", "CBSResult", "CBSRRTExpert", "make_policy"]
