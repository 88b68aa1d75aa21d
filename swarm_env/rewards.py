"""Per-agent rewards: the paper-000 cost shape plus contact and shaping terms (reward v1).

The paper's cost is ``C(s, a) = sum_i dist(s_i, G_i) + lambda * collisions``;
each follower receives its own share of it as a (negative) reward, plus a
penalty for every step it spends in contact and a clearance shaping term::

    r_i = - w_formation  * |p_i - slot_i|                    (m)
          - w_collision  * new_contacts_i                    (onsets this step)
          - w_contact    * touching_i[kind]                  (one term per kind)
          - w_clearance  * max(0, 1 - clearance_i / margin)  (0 when clear by margin)
          - w_smoothness * |a_i - a_i_prev|^2                (normalised action)
          + w_progress   * (|p_i - slot_i|_prev - |p_i - slot_i|)

``touching_i[kind]`` is the number of bodies of that kind (``robot``,
``obstacle``, ``human``, ``wall``) the follower touched at some time during the
step: a contact that lasts 13 steps is charged 13 times (under reward v0 it was
charged once, at its onset). ``clearance_i`` is the free distance between the
follower's disc and the nearest obstacle, wall, human or other robot. Weights
come from :class:`~swarm_env.scenario.RewardSpec`. Every term of
:data:`REWARD_TERMS` is reported in ``infos[agent]["reward_terms"]`` and they
sum to the reward.
"""

from __future__ import annotations

import numpy as np

from swarm_env.scenario import RewardSpec
from swarm_env.state import LEADER_ID, WorldState

#: What a follower can touch, in the order of the ``contact_*`` terms and of ``infos[a]["contacts"]``.
CONTACT_GROUPS = ("robot", "obstacle", "human", "wall")
_GROUP_OF_KIND = {"robot_robot": 0, "robot_obstacle": 1, "robot_human": 2, "robot_wall": 3}
REWARD_TERMS = (
    "formation",
    "collision",
    *(f"contact_{g}" for g in CONTACT_GROUPS),
    "clearance",
    "smoothness",
    "progress",
)


def slot_distance(state: WorldState) -> np.ndarray:
    """(N,) distance of each follower to its slot target (m)."""
    d = state.follower_pose[:, :2] - state.slot_targets
    return np.sqrt(np.add.reduce(d * d, axis=1))  # = np.linalg.norm(d, axis=1), without its overhead


def new_contacts_per_follower(state: WorldState) -> np.ndarray:
    """(N,) number of contact onsets in the last step that involve each follower."""
    return _per_follower(state, state.contacts).sum(axis=1)


def touching_per_follower(state: WorldState) -> np.ndarray:
    """(N, 4) number of bodies each follower was in touch with during the last step, per
    :data:`CONTACT_GROUPS` (robot, obstacle, human, wall)."""
    return _per_follower(state, state.touching)


def _per_follower(state: WorldState, contacts: tuple) -> np.ndarray:
    counts = np.zeros((state.n_followers, len(CONTACT_GROUPS)))
    for c in contacts:
        g = _GROUP_OF_KIND[c.kind]
        if c.robot != LEADER_ID:
            counts[c.robot, g] += 1
        if g == 0 and c.other != LEADER_ID:
            counts[c.other, g] += 1
    return counts


def clearance(state: WorldState) -> np.ndarray:
    """(N,) free distance from each follower's disc to the nearest other body or static surface (m)."""
    pos = state.follower_pose[:, :2]
    r = state.follower_radius
    best = state.static.distance(pos) - r
    others = [np.column_stack([pos, r])]
    if state.leader_is_robot:
        others.append(np.array([[*state.leader_pose[:2], state.leader_radius]]))
    if len(state.human_pos):
        others.append(np.column_stack([state.human_pos, state.human_radius]))
    discs = np.vstack(others)
    gap = np.linalg.norm(pos[:, None, :] - discs[None, :, :2], axis=2) - r[:, None] - discs[None, :, 2]
    n = len(pos)
    gap[np.arange(n), np.arange(n)] = np.inf  # not oneself
    return np.minimum(best, gap.min(axis=1))


def compute_rewards(
    state: WorldState,
    spec: RewardSpec,
    dist: np.ndarray,
    prev_dist: np.ndarray,
    action: np.ndarray,
    prev_action: np.ndarray,
    touching: np.ndarray | None = None,
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Total reward (N,) and each weighted term of :data:`REWARD_TERMS` (N,) for the last step.

    ``dist``/``prev_dist`` are slot distances after/before the step,
    ``action``/``prev_action`` the normalised actions (N, 2) of this and the
    previous step, ``touching`` the (N, 4) :func:`touching_per_follower` counts
    (computed here when not given).
    """
    if touching is None:
        touching = touching_per_follower(state)
    terms = {
        "formation": -spec.formation * dist,
        "collision": -spec.collision * new_contacts_per_follower(state),
    }
    for g, name in enumerate(CONTACT_GROUPS):
        terms[f"contact_{name}"] = -spec.contact * touching[:, g]
    terms["clearance"] = np.zeros_like(dist)
    if spec.clearance:
        intrusion = np.clip(1.0 - clearance(state) / spec.clearance_margin, 0.0, None)
        terms["clearance"] = -spec.clearance * intrusion
    terms["smoothness"] = -spec.smoothness * np.add.reduce((action - prev_action) ** 2, axis=1)
    terms["progress"] = spec.progress * (prev_dist - dist)
    total = np.zeros_like(dist)
    for name in REWARD_TERMS:
        total += terms[name]
    return total, terms
