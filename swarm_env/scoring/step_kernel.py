"""The per-step reward terms and metric accumulators, compiled with numba.

Two kernels replace a few dozen small numpy calls of a step with one call each:

* :func:`reward_table` - the slot distances and every weighted term of
  :data:`swarm_env.scoring.rewards.REWARD_TERMS` with their sum; the numpy reference is
  :func:`swarm_env.scoring.rewards.reward_table` with :func:`swarm_env.compiled.use_compiled_kernels` off.
* :func:`metrics_step` - the accumulators of :meth:`swarm_env.scoring.metrics.EpisodeMetrics.update`
  (summed slot error and twists, distance travelled) and the robot-robot and robot-human
  parts of its proximity minima; the numpy reference is ``EpisodeMetrics``' own code with
  :func:`swarm_env.compiled.use_compiled_kernels` off.

Both do the numpy reference's operations in its order (``sqrt(dx * dx + dy * dy)``,
``(d - r_i) - r_j``, ``(-w) * x``, the terms added to ``0.0`` in ``REWARD_TERMS`` order, IEEE
``sqrt``, no fused multiply-add), so they give the same bits (``tests/test_step_kernel.py``).
A NaN propagates as numpy's ``min``/``max`` would, so the callers' Python ``min``/``max`` treat it
the same way.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from swarm_env.geometry.clearance_kernel import lower_bounds, static_min_distance
from swarm_env.kernel_cache import njit
from swarm_env.scoring.weights import (
    W_APPROACH,
    W_APPROACH_MARGIN,
    W_CLEARANCE,
    W_CLEARANCE_MARGIN,
    W_COLLISION,
    W_CONTACT,
    W_FORMATION,
    W_PROGRESS,
    W_SMOOTHNESS,
)

_jit = njit(nogil=True, error_model="numpy")

#: Rows of :func:`reward_table`'s table (= ``len(swarm_env.scoring.rewards.REWARD_TERMS)``).
N_TERMS = 10


class Accumulators(NamedTuple):
    """One world's running sums, updated in place by :func:`metrics_step`: the slot errors ``err_sum`` ``(N,)``,
    the twists ``twist_sum`` ``(N + 1, 2)`` and the distances travelled ``dist_sum`` ``(N + 1,)`` (the leader
    last), and the last positions ``prev_pos`` ``(N + 1, 2)``."""

    err_sum: np.ndarray
    twist_sum: np.ndarray
    dist_sum: np.ndarray
    prev_pos: np.ndarray


class Bodies(NamedTuple):
    """One world's robots and humans at a step: the followers' ``pose`` ``(N, 3)``, ``twist`` ``(N, 2)`` and
    ``radius`` ``(N,)``; the leader's ``l_pose``, ``l_twist``, ``l_radius`` (0 unless a robot) and
    ``leader_robot``; the humans' ``h_pos`` ``(H, 2)`` and ``h_radius`` ``(H,)``."""

    pose: np.ndarray
    twist: np.ndarray
    radius: np.ndarray
    l_pose: np.ndarray
    l_twist: np.ndarray
    l_radius: float
    leader_robot: bool
    h_pos: np.ndarray
    h_radius: np.ndarray


class Screening(NamedTuple):
    """How :func:`metrics_step` screens the static clearance: the carried lower bounds' ``slack`` (m), the
    exact distance's ``screen`` margin (m), and the most followers (``fast_max``) the kernel measures itself."""

    slack: float
    screen: float
    fast_max: int


@_jit
def reward_table(pose, slots, dist_in, prev, action, contact, clear, weights):  # pragma: no cover - compiled
    """``(dist (N,), table (N_TERMS, N), total (N,))`` of one step.

    ``dist_in``: the slot distances if known, else an empty array (then they are computed from
    ``pose`` ``(N, 3)`` and ``slots`` ``(N, 2)``). ``prev = (prev_dist, prev_action)`` the previous
    step's, ``action`` ``(N, 2)``, ``contact = (touching, onsets, gap)`` ``(N, 4)``, ``(N,)``, ``(N,)``,
    ``clear`` ``(N,)``, ``weights`` ``(9,)`` in :data:`swarm_env.scoring.weights.WEIGHT_COLUMNS` order. A term
    whose weight is 0 is a row of ``+0.0`` and is not added; the callers pass a collision weight of 0 without
    contact onsets and a contact weight of 0 without bodies in touch. ``onsets``, ``clear`` and ``gap`` are read
    only when their weight is not 0.
    """
    n = len(pose)
    dist = np.empty(n)
    table = np.empty((N_TERMS, n))
    total = np.empty(n)
    reward_into((dist, table, total), pose, slots, dist_in, prev, action, contact, clear, weights)
    return dist, table, total


@_jit
def reward_into(out, pose, slots, dist_in, prev, action, contact, clear, weights):  # pragma: no cover - compiled
    """:func:`reward_table` written into ``out = (dist, table, total)``: ``(N,)``, ``(N_TERMS, N)``, ``(N,)`` (any
    contents before; views into larger arrays are fine): one world's row of the batched engine's kernel
    (:func:`swarm_env.vector.batch_kernel.rewards_batch`) and ``reward_table``'s body."""
    dist, table, total = out
    prev_dist, prev_action = prev
    touching, onsets, gap = contact
    w_formation, w_collision, w_contact = weights[W_FORMATION], weights[W_COLLISION], weights[W_CONTACT]
    w_clearance, clearance_margin = weights[W_CLEARANCE], weights[W_CLEARANCE_MARGIN]
    w_smoothness, w_progress = weights[W_SMOOTHNESS], weights[W_PROGRESS]
    w_approach, approach_margin = weights[W_APPROACH], weights[W_APPROACH_MARGIN]
    n = len(pose)
    if len(dist_in) == n:
        for i in range(n):
            dist[i] = dist_in[i]
    else:
        for i in range(n):
            dx = pose[i, 0] - slots[i, 0]
            dy = pose[i, 1] - slots[i, 1]
            dist[i] = math.sqrt(dx * dx + dy * dy)
    for t in range(N_TERMS):
        for i in range(n):
            table[t, i] = 0.0
    for i in range(n):
        total[i] = 0.0
    if w_formation != 0.0:
        w = -w_formation
        for i in range(n):
            table[0, i] = w * dist[i]
            total[i] += table[0, i]
    if w_collision != 0.0:
        w = -w_collision
        for i in range(n):
            table[1, i] = w * onsets[i]
            total[i] += table[1, i]
    if w_contact != 0.0:
        w = -w_contact
        for g in range(4):
            for i in range(n):
                table[2 + g, i] = w * touching[i, g]
                total[i] += table[2 + g, i]
    if w_clearance != 0.0:
        w = -w_clearance
        for i in range(n):
            x = 1.0 - clear[i] / clearance_margin
            if x < 0.0:  # np.clip(x, 0.0, None): NaN stays NaN
                x = 0.0
            table[6, i] = w * x
            total[i] += table[6, i]
    if w_smoothness != 0.0:
        w = -w_smoothness
        for i in range(n):
            d0 = action[i, 0] - prev_action[i, 0]
            d1 = action[i, 1] - prev_action[i, 1]
            table[7, i] = w * (d0 * d0 + d1 * d1)
            total[i] += table[7, i]
    if w_progress != 0.0:
        for i in range(n):
            table[8, i] = w_progress * (prev_dist[i] - dist[i])
            total[i] += table[8, i]
    if w_approach != 0.0:
        w = -w_approach
        for i in range(n):
            x = 1.0 - gap[i] / approach_margin
            if x < 0.0:
                x = 0.0
            table[9, i] = w * x
            total[i] += table[9, i]


@_jit
def metrics_step(err, tolerance, acc, bodies, lb, min_clear, screening, mp):  # pragma: no cover - compiled
    """One :meth:`EpisodeMetrics.update` of the arrays, in place, and what its proximity needs.

    Adds ``err`` (N,) to ``acc.err_sum`` (:class:`Accumulators`), the twists of ``bodies`` (:class:`Bodies`) to
    ``acc.twist_sum`` (leader last), each robot's displacement to ``acc.dist_sum``, and moves ``acc.prev_pos``
    to the new positions. Returns ``(err_max, within, sep, hum, lb_out, status, static)``: the
    step's largest error (``max(0, err)``), whether every ``err <= tolerance``, the smallest robot-robot surface gap (followers, then the
    robot leader when ``leader_robot``; ``inf`` with one robot), the smallest follower-human gap
    (``inf`` without humans), and the static clearance part:

    * ``status 0``: the lower bounds ``lb`` carried over the displacement (``lb - moved - slack``,
      ``lb_out``) all stay at or above ``min_clear + slack``: nothing else to do;
    * ``status 1``: ``lb_out`` are fresh lower bounds (``StaticMap.distance_lower_bound``) and
      ``static`` is ``StaticMap.min_distance(pos, radius, min_clear, lower=lb_out)``;
    * ``status 2``: as 1, but ``static`` is left to the caller (``min_clear`` infinite or more
      than ``fast_max`` followers: ``min_distance``'s numpy path);
    * ``status 3``: no followers.

    ``lb`` empty means no bounds to carry; ``mp`` the map's :class:`~swarm_env.geometry.map_arrays.MapArrays`,
    ``screening`` a :class:`Screening`.
    """
    err_sum, twist_sum, dist_sum, prev_pos = acc
    pose, f_twist, radius, l_pose, l_twist, l_radius, leader_robot, h_pos, h_radius = bodies
    slack, screen, fast_max = screening
    n = len(err)
    nan = False
    err_max = 0.0
    within = True
    for i in range(n):
        e = err[i]
        err_sum[i] += e
        if not e <= tolerance:  # NaN is not within, as in numpy
            within = False
        if e != e:
            nan = True
        elif e > err_max:
            err_max = e
    if nan:
        err_max = np.nan
    for i in range(n):
        twist_sum[i, 0] += f_twist[i, 0]
        twist_sum[i, 1] += f_twist[i, 1]
    twist_sum[n, 0] += l_twist[0]
    twist_sum[n, 1] += l_twist[1]
    moved = np.empty(n + 1)
    for i in range(n + 1):
        if i < n:
            x = pose[i, 0]
            y = pose[i, 1]
        else:
            x = l_pose[0]
            y = l_pose[1]
        dx = x - prev_pos[i, 0]
        dy = y - prev_pos[i, 1]
        moved[i] = math.sqrt(dx * dx + dy * dy)
        dist_sum[i] += moved[i]
        prev_pos[i, 0] = x
        prev_pos[i, 1] = y
    # Robot-robot gaps over the pairs i < j (the leader, when a robot, is the last one).
    m = n + 1 if leader_robot else n
    sep = np.inf
    nan = False
    for i in range(m):
        xi = pose[i, 0] if i < n else l_pose[0]
        yi = pose[i, 1] if i < n else l_pose[1]
        ri = radius[i] if i < n else l_radius
        for j in range(i + 1, m):
            xj = pose[j, 0] if j < n else l_pose[0]
            yj = pose[j, 1] if j < n else l_pose[1]
            rj = radius[j] if j < n else l_radius
            dx = xi - xj
            dy = yi - yj
            d = (math.sqrt(dx * dx + dy * dy) - ri) - rj
            if d != d:
                nan = True
            elif d < sep:
                sep = d
    if nan:
        sep = np.nan
    hum = np.inf
    nan = False
    for i in range(n):
        for j in range(len(h_pos)):
            dx = pose[i, 0] - h_pos[j, 0]
            dy = pose[i, 1] - h_pos[j, 1]
            d = (math.sqrt(dx * dx + dy * dy) - radius[i]) - h_radius[j]
            if d != d:
                nan = True
            elif d < hum:
                hum = d
    if nan:
        hum = np.nan
    if n == 0:
        return err_max, within, sep, hum, np.empty(0), 3, min_clear
    if len(lb) == n:
        lb_out = np.empty(n)
        carried = True
        threshold = min_clear + slack
        for i in range(n):
            lb_out[i] = (lb[i] - moved[i]) - slack
            # (lb - r).min() >= threshold, NaN failing it like numpy's min would
            if not lb_out[i] - radius[i] >= threshold:
                carried = False
        if carried:
            return err_max, within, sep, hum, lb_out, 0, min_clear
    lb_out = lower_bounds(pose, mp.width, mp.height, mp.bound)
    if not math.isfinite(min_clear) or n > fast_max:
        return err_max, within, sep, hum, lb_out, 2, min_clear
    static = static_min_distance(pose, radius, min_clear, lb_out, screen, mp)
    return err_max, within, sep, hum, lb_out, 1, static


__all__ = ["N_TERMS", "Accumulators", "Bodies", "Screening", "metrics_step", "reward_into", "reward_table"]
