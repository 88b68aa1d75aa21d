"""``WorldState``: the frozen snapshot of the world after each step.

It is the one data type that flows out of :class:`swarm_env.sim.world.World`:
observations, rewards, metrics, the renderer and the scripted experts all read
it (experts read it as privileged information, like CrowdNav's ``FullState``).
Arrays are read-only copies; nothing in here refers back to pymunk.

Conventions: poses are ``(x, y, theta)`` in the world frame (theta in radians,
counter-clockwise from +x, wrapped to ``[-pi, pi)``); ``*_vel`` are world-frame
linear velocities ``(vx, vy)``; ``*_twist`` are body-frame ``(v, omega)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from swarm_env.geometry.static_map import StaticMap
from swarm_env.scenario import Scenario

ContactKind = Literal["robot_robot", "robot_obstacle", "robot_human", "robot_wall"]
CONTACT_KINDS: tuple[ContactKind, ...] = ("robot_robot", "robot_obstacle", "robot_human", "robot_wall")

#: Robot index used for the leader in contacts and per-robot tables (followers are 0..N-1).
LEADER_ID = -1


@dataclass(frozen=True)
class Contact:
    """A contact of the last step: its onset (``WorldState.contacts``) or a pair in touch
    (``WorldState.touching``).

    ``robot`` is a follower index or :data:`LEADER_ID`; ``other`` is the index of
    the other robot (follower index or ``LEADER_ID``), human, obstacle, or wall
    (0 bottom, 1 right, 2 top, 3 left), according to ``kind``.
    """

    kind: ContactKind
    robot: int
    other: int


@dataclass(frozen=True)
class WorldState:
    """Everything an expert may know about the world at ``time``."""

    time: float
    step: int
    follower_pose: np.ndarray  # (N, 3)
    follower_vel: np.ndarray  # (N, 2) world frame
    follower_twist: np.ndarray  # (N, 2) (v, omega)
    follower_radius: np.ndarray  # (N,)
    leader_pose: np.ndarray  # (3,)
    leader_vel: np.ndarray  # (2,)
    leader_twist: np.ndarray  # (2,)
    leader_radius: float  # 0.0 for a virtual leader
    leader_done: bool  # the leader reached the end of its path
    human_pos: np.ndarray  # (H, 2)
    human_vel: np.ndarray  # (H, 2)
    human_radius: np.ndarray  # (H,)
    slot_targets: np.ndarray  # (N, 2) current slot targets, moved out of obstacles
    formation_index: int  # index into scenario.formations of the active formation
    next_switch_time: float  # time of the next formation switch, inf if none
    contacts: tuple[Contact, ...]  # contact onsets during the last step
    static: StaticMap
    scenario: Scenario
    # Every pair in touch at some time during the last step (onsets included), sorted like
    # ``contacts``; the per-step contact penalty of reward v1 counts these.
    touching: tuple[Contact, ...] = ()
    # Derived arrays computed on first use and shared by the readers of this snapshot.
    _derived: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    @property
    def n_followers(self) -> int:
        return int(self.follower_pose.shape[0])

    @property
    def leader_is_robot(self) -> bool:
        return self.scenario.leader.kind == "robot"

    def follower_distances(self) -> np.ndarray:
        """(N, N) read-only distances between followers (m), computed once per snapshot
        (observations and metrics both need them): ``[i, j] = |p_i - p_j|``."""
        d = self._derived.get("follower_distances")
        if d is None:
            pos = self.follower_pose[:, :2]
            diff = pos[:, None, :] - pos[None, :, :]
            d = np.sqrt(np.add.reduce(diff * diff, axis=2))  # = np.linalg.norm(diff, axis=2)
            d.flags.writeable = False
            self._derived["follower_distances"] = d
        return d

    @classmethod
    def build(cls, **fields: object) -> WorldState:
        """A new snapshot of the given fields (every field of the class, by name; ``_derived`` is
        added empty) without the frozen dataclass's ``__init__``: the fields go straight into the
        instance's ``__dict__``, what that ``__init__`` stores with one ``object.__setattr__`` each, at a
        tenth of its cost. What :meth:`World.snapshot <swarm_env.sim.world.World.snapshot>` and the batched
        engine's physics (:mod:`swarm_env.vector.world_batch`) build once per world-step."""
        state = object.__new__(cls)
        state.__dict__.update(fields, _derived={})
        return state

    def robot_positions(self) -> np.ndarray:
        """Positions of all physical robots, followers first then the robot leader (if any)."""
        if self.leader_is_robot:
            return np.vstack([self.follower_pose[:, :2], self.leader_pose[None, :2]])
        return self.follower_pose[:, :2]
