"""Per-agent rewards: the paper-000 cost shape plus optional shaping terms.

The paper's cost is ``C(s, a) = sum_i dist(s_i, G_i) + lambda * collisions``;
each follower receives its own share of it as a (negative) reward::

    r_i = - w_formation  * |p_i - slot_i|                    (m)
          - w_collision  * new_contacts_i                    (count, this step)
          - w_clearance  * max(0, 1 - clearance_i / margin)  (0 when clear by margin)
          - w_smoothness * |a_i - a_i_prev|^2                (normalised action)
          + w_progress   * (|p_i - slot_i|_prev - |p_i - slot_i|)

``clearance_i`` is the free distance between the follower's disc and the
nearest obstacle, wall, human or other robot. Weights come from
:class:`~swarm_env.scenario.RewardSpec`; the optional ones default to 0.
"""

from __future__ import annotations

import numpy as np

from swarm_env.scenario import RewardSpec
from swarm_env.state import LEADER_ID, WorldState

REWARD_TERMS = ("formation", "collision", "clearance", "smoothness", "progress")


def slot_distance(state: WorldState) -> np.ndarray:
    """(N,) distance of each follower to its slot target (m)."""
    d = state.follower_pose[:, :2] - state.slot_targets
    return np.sqrt(np.add.reduce(d * d, axis=1))  # = np.linalg.norm(d, axis=1), without its overhead


def new_contacts_per_follower(state: WorldState) -> np.ndarray:
    """(N,) number of contact onsets in the last step that involve each follower."""
    counts = np.zeros(state.n_followers)
    for c in state.contacts:
        if c.robot != LEADER_ID:
            counts[c.robot] += 1
        if c.kind == "robot_robot" and c.other != LEADER_ID:
            counts[c.other] += 1
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
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Total reward (N,) and each weighted term (N,) for the last step.

    ``dist``/``prev_dist`` are slot distances after/before the step,
    ``action``/``prev_action`` the normalised actions (N, 2) of this and the
    previous step.
    """
    terms = {
        "formation": -spec.formation * dist,
        "collision": -spec.collision * new_contacts_per_follower(state),
        "clearance": np.zeros_like(dist),
        "smoothness": -spec.smoothness * np.add.reduce((action - prev_action) ** 2, axis=1),
        "progress": spec.progress * (prev_dist - dist),
    }
    if spec.clearance:
        intrusion = np.clip(1.0 - clearance(state) / spec.clearance_margin, 0.0, None)
        terms["clearance"] = -spec.clearance * intrusion
    total = terms["formation"] + terms["collision"] + terms["clearance"] + terms["smoothness"] + terms["progress"]
    return total, terms
