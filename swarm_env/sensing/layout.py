"""The columns of a follower's observation and of the global state: the one layout that the numpy references
(:mod:`swarm_env.sensing.observations`) and their compiled twins (:mod:`~swarm_env.sensing.obs_kernel`,
:mod:`~swarm_env.sensing.state_kernel`) write by. A kernel reads its columns from here (numba takes these
module-level integers as constants), never from literals of its own.

Layout of one follower's observation (``float32``, length
``11 + 5 * neighbors + 5 * humans + lidar_rays``):

======================  =====  ================================================
slice                   size   content
======================  =====  ================================================
``OBS_OWN_TWIST``       2      own (v / max_speed, omega / max_turn_rate)
``OBS_SLOT``            2      vector to the own slot target (m)
``OBS_LEADER``          6      leader position (m), (cos, sin) of its relative
                               heading, leader velocity (m/s)
``OBS_SWITCH``          1      seconds to the next formation switch (capped at
                               ``max_time``; the cap when none is scheduled)
neighbours              5 k    k nearest other followers: dx, dy (m), dvx, dvy
                               (m/s), present-mask (1/0); absent rows are 0
humans                  5 h    h nearest humans, same 5 columns
lidar                   R      ray distance / lidar_range in [0, 1], rays
                               evenly spaced from straight ahead,
                               counter-clockwise; hits obstacles, walls,
                               robots (the leader included) and humans
======================  =====  ================================================

:func:`observation_layout` returns the named slices for a given sensor spec. The global state's blocks are
:func:`swarm_env.sensing.observations.state_layout`'s, each as wide as the ``*_COLUMNS`` below say.
"""

from __future__ import annotations

from swarm_env.scenario import SensorSpec

#: The own twist's two columns: v / max_speed, omega / max_turn_rate.
COL_TWIST = 0
#: The vector to the own slot (body frame, m): x, y.
COL_SLOT = 2
#: The leader's position relative to the follower (body frame, m): x, y.
COL_LEADER_POS = 4
#: cos, sin of the leader's heading relative to the follower's.
COL_LEADER_HEADING = 6
#: The leader's velocity (body frame, m/s): x, y.
COL_LEADER_VEL = 8
#: Seconds to the next formation switch.
COL_SWITCH = 10
#: Columns before the first neighbour row.
FIXED = 11

OBS_OWN_TWIST = slice(COL_TWIST, COL_TWIST + 2)
OBS_SLOT = slice(COL_SLOT, COL_SLOT + 2)
OBS_LEADER = slice(COL_LEADER_POS, COL_LEADER_VEL + 2)
OBS_SWITCH = slice(COL_SWITCH, FIXED)

#: Columns of one neighbour or human row, and where in it: the relative position (x, y), the relative
#: velocity (x, y), both in the body frame, and the present-mask.
ENTITY = 5
ENTITY_POS = 0
ENTITY_VEL = 2
ENTITY_MASK = 4

#: Columns per follower in the state's ``followers`` block: x / W, y / H, cos, sin, v / vlim,
#: omega / vlim, slot x / W, slot y / H, present.
FOLLOWER_COLUMNS = 9
#: Columns of the ``leader`` block: x / W, y / H, cos, sin, vx / vlim, vy / vlim.
LEADER_COLUMNS = 6
#: Columns per human slot in the ``humans`` block: x / W, y / H, vx / vlim, vy / vlim, present.
HUMAN_COLUMNS = 5
#: Columns of the ``time`` block: t / max_time, time to the next switch / max_time.
TIME_COLUMNS = 2
#: Columns per follower in the ``follower_clearance`` block: clearance / range, nx, ny.
CLEARANCE_COLUMNS = 3
#: Cells per side of the global state's occupancy grid of the static map.
STATE_GRID = 16


def observation_layout(sensors: SensorSpec) -> dict[str, slice]:
    """Named slices of the observation vector for ``sensors``."""
    k, h, r = sensors.neighbors, sensors.humans, sensors.lidar_rays
    nb = slice(FIXED, FIXED + ENTITY * k)
    hu = slice(nb.stop, nb.stop + ENTITY * h)
    li = slice(hu.stop, hu.stop + r)
    return {
        "own_twist": OBS_OWN_TWIST,
        "slot": OBS_SLOT,
        "leader": OBS_LEADER,
        "switch": OBS_SWITCH,
        "neighbors": nb,
        "humans": hu,
        "lidar": li,
    }


__all__ = ["CLEARANCE_COLUMNS", "COL_LEADER_HEADING", "COL_LEADER_POS", "COL_LEADER_VEL", "COL_SLOT", "COL_SWITCH",
           "COL_TWIST", "ENTITY", "ENTITY_MASK", "ENTITY_POS", "ENTITY_VEL", "FIXED", "FOLLOWER_COLUMNS", "HUMAN_COLUMNS",
           "LEADER_COLUMNS", "OBS_LEADER", "OBS_OWN_TWIST", "OBS_SLOT", "OBS_SWITCH", "STATE_GRID", "TIME_COLUMNS",
           "observation_layout"]
