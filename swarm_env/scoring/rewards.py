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
          - w_approach   * max(0, 1 - approach_gap_i / approach_margin)

``touching_i[kind]`` is the number of bodies of that kind (``robot``,
``obstacle``, ``human``, ``wall``) the follower touched at some time during the
step: a contact that lasts 13 steps is charged 13 times (under reward v0 it was
charged once, at its onset). ``clearance_i`` is the free distance between the
follower's disc and the nearest obstacle, wall, human or other robot;
``approach_gap_i`` (:func:`approach_gap`) the smallest gap it will have to another
moving body within ``approach_horizon`` seconds if both keep their velocities (off
in v1: a shaping term for training, which warns seconds before a contact where
clearance warns centimetres before). Weights
come from :class:`~swarm_env.scenario.RewardSpec`. Every term of
:data:`REWARD_TERMS` is reported in the agent's infos as ``reward_<term>``
(:data:`INFO_REWARD_KEYS`; :func:`reward_terms` reads them back as a dict) and
they sum to the reward. Infos are flat (one number per key) because TorchRL's
and BenchMARL's PettingZoo wrappers turn every info value into a tensor.
"""

from __future__ import annotations

import numpy as np

from swarm_env.compiled import compiled_kernels
from swarm_env.scenario import RewardSpec
from swarm_env.scoring.weights import W_COLLISION, W_CONTACT, reward_weights
from swarm_env.state import LEADER_ID, WorldState

#: What a follower can touch, in the order of the ``contact_*`` terms and of the ``contacts_*`` infos.
CONTACT_GROUPS = ("robot", "obstacle", "human", "wall")
_NO_LEADER = np.zeros((0, 3))  # clearance_kernel's "no robot leader"
_NO_DISTANCES = np.zeros((0, 0))
_NO_VALUES = np.zeros(0)  # an unused (N,) input of the reward kernel
_GROUP_OF_KIND = {"robot_robot": 0, "robot_obstacle": 1, "robot_human": 2, "robot_wall": 3}
REWARD_TERMS = (
    "formation",
    "collision",
    *(f"contact_{g}" for g in CONTACT_GROUPS),
    "clearance",
    "smoothness",
    "progress",
    "approach",
)


#: The infos keys of the reward terms (``infos[agent]["reward_formation"]``, ...), in REWARD_TERMS order.
INFO_REWARD_KEYS = tuple(f"reward_{t}" for t in REWARD_TERMS)
#: The infos keys of the bodies in touch during the step, per kind (``infos[agent]["contacts_robot"]``, ...).
INFO_CONTACT_KEYS = tuple(f"contacts_{g}" for g in CONTACT_GROUPS)


def reward_terms(info: dict) -> dict[str, float]:
    """``{term: value}`` of one agent's infos (the ``reward_<term>`` keys), in REWARD_TERMS order."""
    return {t: info[k] for t, k in zip(REWARD_TERMS, INFO_REWARD_KEYS)}


def contact_counts(info: dict) -> dict[str, int]:
    """``{kind: bodies in touch}`` of one agent's infos (the ``contacts_<kind>`` keys)."""
    return {g: info[k] for g, k in zip(CONTACT_GROUPS, INFO_CONTACT_KEYS)}


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


def clearance(state: WorldState, below: float = np.inf) -> np.ndarray:
    """(N,) free distance from each follower's disc to the nearest other body or static surface (m).

    Exact where the result is below ``below``; elsewhere it may be any value ``>= below``
    (the static clearance of a follower whose cheap lower bound is already ``>= below`` is
    not computed: the clearance reward only needs the followers inside its margin).
    """
    if compiled_kernels():  # the same bits, see swarm_env.geometry.clearance_kernel
        from swarm_env.geometry.clearance_kernel import clearance as compiled

        if state.leader_is_robot:
            leader = np.array([[state.leader_pose[0], state.leader_pose[1], state.leader_radius]])
        else:
            leader = _NO_LEADER
        return compiled(state.follower_pose, state.follower_radius, float(below),
                        _NO_DISTANCES, leader, state.human_pos,  # the kernel computes the distances
                        state.human_radius, state.static.kernel_arrays())
    pos = state.follower_pose[:, :2]
    r = state.follower_radius
    static = state.static
    if np.isfinite(below):
        best = static.distance_lower_bound(pos) - r  # <= the exact static clearance
        near = np.flatnonzero(best < below)
        if len(near):
            best[near] = static.distance(pos[near]) - r[near]
    else:
        best = static.distance(pos) - r
    if len(pos) > 1:
        gap = state.follower_distances() - r[:, None]  # a new array (the distances are shared read-only)
        gap -= r[None, :]
        np.fill_diagonal(gap, np.inf)  # not oneself
        np.minimum(best, gap.min(axis=1), out=best)
    if state.leader_is_robot:
        d = pos - state.leader_pose[:2]
        np.minimum(best, np.sqrt(np.add.reduce(d * d, axis=1)) - r - state.leader_radius, out=best)
    if len(state.human_pos):
        d = pos[:, None, :] - state.human_pos[None, :, :]
        gap = np.sqrt(np.add.reduce(d * d, axis=2)) - r[:, None] - state.human_radius[None, :]
        np.minimum(best, gap.min(axis=1), out=best)
    return best


def approach_gap(state: WorldState, horizon: float) -> np.ndarray:
    """(N,) the smallest surface gap (m) between each follower and any other moving body (the other
    followers, a robot leader, the humans) at their closest point of approach within ``horizon``
    seconds, both moving on at their current velocities (``inf`` with nothing else moving around).

    For a pair at relative position ``p`` and velocity ``v`` the closest approach is at
    ``t* = clip(-p.v / |v|^2, 0, horizon)`` and the gap is ``|p + v t*| - r_i - r_j``: the current gap
    when they separate, less when they close in. Negative values mean a predicted overlap.
    """
    pos = state.follower_pose[:, :2]
    n = len(pos)
    parts_p, parts_v, parts_r = [pos], [state.follower_vel], [state.follower_radius]
    if state.leader_is_robot:
        parts_p.append(state.leader_pose[None, :2])
        parts_v.append(np.asarray(state.leader_vel, dtype=float)[None])
        parts_r.append(np.array([state.leader_radius]))
    if len(state.human_pos):
        parts_p.append(state.human_pos)
        parts_v.append(state.human_vel)
        parts_r.append(state.human_radius)
    other_p, other_v, other_r = np.concatenate(parts_p), np.concatenate(parts_v), np.concatenate(parts_r)
    if len(other_p) == 1:
        return np.full(n, np.inf)
    p = other_p[None, :, :] - pos[:, None, :]
    v = other_v[None, :, :] - state.follower_vel[:, None, :]
    vv = np.add.reduce(v * v, axis=2)
    t = np.clip(-np.add.reduce(p * v, axis=2) / np.maximum(vv, 1e-12), 0.0, horizon)
    c = p + v * t[:, :, None]
    gap = np.sqrt(np.add.reduce(c * c, axis=2)) - state.follower_radius[:, None] - other_r[None, :]
    gap[np.arange(n), np.arange(n)] = np.inf  # not oneself
    return gap.min(axis=1)


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
    (computed here when not given). A term whose weight is 0 is reported as 0.
    """
    if touching is None:
        touching = touching_per_follower(state)
    _, table, total = reward_table(state, spec, prev_dist, action, prev_action, touching, dist)
    return total, dict(zip(REWARD_TERMS, table))


def reward_table(
    state: WorldState,
    spec: RewardSpec,
    prev_dist: np.ndarray,
    action: np.ndarray,
    prev_action: np.ndarray,
    touching: np.ndarray,
    dist: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(dist (N,), table (len(REWARD_TERMS), N), total (N,))``: the slot distances (computed
    when ``dist`` is None), each weighted term of :data:`REWARD_TERMS` as a row (``+0.0`` where
    its weight is 0) and their sum, what :func:`compute_rewards` returns as a dict. One compiled
    call (:func:`swarm_env.scoring.step_kernel.reward_table`) or its numpy reference, the same bits."""
    w_collision = spec.collision if state.contacts else 0.0
    w_contact = spec.contact if state.touching else 0.0
    onsets = new_contacts_per_follower(state) if w_collision else _NO_VALUES
    clear = clearance(state, below=spec.clearance_margin) if spec.clearance else _NO_VALUES
    gap = approach_gap(state, spec.approach_horizon) if spec.approach else _NO_VALUES
    if compiled_kernels():
        from swarm_env.scoring.step_kernel import reward_table as compiled

        weights = reward_weights(spec)
        weights[W_COLLISION], weights[W_CONTACT] = w_collision, w_contact
        return compiled(state.follower_pose, state.slot_targets, _NO_VALUES if dist is None else dist,
                        (prev_dist, prev_action), action, (touching, onsets, gap), clear, weights)
    if dist is None:
        dist = slot_distance(state)
    table = np.zeros((len(REWARD_TERMS), len(dist)))
    active = []  # the rows summed into the total, in REWARD_TERMS order
    if spec.formation:
        table[0] = -spec.formation * dist
        active.append(0)
    if w_collision:
        table[1] = -w_collision * onsets
        active.append(1)
    if w_contact:
        for g in range(len(CONTACT_GROUPS)):
            table[2 + g] = -w_contact * touching[:, g]
            active.append(2 + g)
    if spec.clearance:
        table[6] = -spec.clearance * np.clip(1.0 - clear / spec.clearance_margin, 0.0, None)
        active.append(6)
    if spec.smoothness:
        table[7] = -spec.smoothness * np.add.reduce((action - prev_action) ** 2, axis=1)
        active.append(7)
    if spec.progress:
        table[8] = spec.progress * (prev_dist - dist)
        active.append(8)
    if spec.approach:
        table[9] = -spec.approach * np.clip(1.0 - gap / spec.approach_margin, 0.0, None)
        active.append(9)
    total = np.zeros(len(dist))
    for k in active:
        total += table[k]
    return dist, table, total
