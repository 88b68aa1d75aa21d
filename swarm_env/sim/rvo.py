"""RVO2 (the reference ORCA library, through ``pyrvo``) set up for a swarm_env map.

Shared by the ``orca`` reference policy (:mod:`swarm_env_agents.orca`) and the humans with
``behavior: orca`` (:mod:`swarm_env.sim.humans`): both need an RVO2 simulator holding the map's
obstacles. ``pyrvo`` is the ``orca`` extra; :func:`simulator` raises
:class:`~swarm_env.extras.MissingExtraError` naming it when it is missing.
"""

from __future__ import annotations

import math
from typing import Any

from swarm_env.extras import require
from swarm_env.geometry.static_map import StaticMap

#: Sides of the polygon circumscribed to a circle obstacle (RVO2 obstacles are polygons).
CIRCLE_SIDES = 16


def simulator(static: StaticMap, dt: float, neighbor_dist: float, max_neighbors: int, horizon: float,
              horizon_static: float, radius: float, max_speed: float, feature: str) -> Any:
    """A ``pyrvo.RVOSimulator`` with these agent defaults and ``static``'s obstacles and walls
    (circles as circumscribed ``CIRCLE_SIDES``-gons, the world boundary clockwise so that its
    inside is free space). ``feature`` names what needs it, for the missing-extra error."""
    pyrvo = require("pyrvo", "orca", feature)
    sim = pyrvo.RVOSimulator(float(dt), float(neighbor_dist), int(max_neighbors), float(horizon),
                             float(horizon_static), float(radius), float(max_speed))
    for cx, cy, r in static.circles.tolist():  # a circumscribed polygon keeps the agents off the disc
        rc = r / math.cos(math.pi / CIRCLE_SIDES)
        sim.add_obstacle([(cx + rc * math.cos(2 * math.pi * k / CIRCLE_SIDES),
                           cy + rc * math.sin(2 * math.pi * k / CIRCLE_SIDES)) for k in range(CIRCLE_SIDES)])
    for poly in static.polygons:  # counter-clockwise, as RVO2 wants obstacles
        sim.add_obstacle([(float(x), float(y)) for x, y in poly])
    w, h = static.size
    sim.add_obstacle([(0.0, 0.0), (0.0, h), (w, h), (w, 0.0)])
    sim.process_obstacles()
    return sim
