"""The observation assembly of :class:`swarm_env.sensing.observations.ObservationBuilder`, compiled with numba.

:meth:`ObservationBuilder._assemble <swarm_env.sensing.observations.ObservationBuilder._assemble>` is the
reference: numpy, one vectorised pass per block of the observation. For the eight followers of a
typical world it spends nearly all its time in numpy's per-call overhead (~40 small calls, ~100 µs
a step, the largest share of a step after the physics: ``python benchmarks/engine_breakdown.py
--worlds 1``). This kernel writes the same ``(N, size)`` block follower by follower, without
temporaries, and also clips it and casts it to float32 (``build``'s last two steps).

Same bits as the reference, by construction and by test (``tests/test_obs_kernel.py`` compares
both on every state of episodes of every built-in scenario and random worlds): every
floating-point operation is the reference's, in its order (``c * vx + s * vy``, a division where
it divides), the headings' cosines and sines come from numpy as in the reference, nearest
entities are chosen as a stable sort would (ties: the lower index first), and the clip and the
cast work entry by entry. Only ``sqrt`` is computed here (correctly rounded everywhere).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from swarm_env.kernel_cache import njit
from swarm_env.sensing.layout import (
    COL_LEADER_HEADING,
    COL_LEADER_POS,
    COL_LEADER_VEL,
    COL_SLOT,
    COL_SWITCH,
    COL_TWIST,
    ENTITY,
    ENTITY_MASK,
    ENTITY_POS,
    ENTITY_VEL,
)

_jit = njit(nogil=True, error_model="numpy")


class ObsWorld(NamedTuple):
    """One world's inputs of the observation: the followers' ``pose`` ``(N, 3)``, world-frame ``vel`` ``(N, 2)``,
    ``twist`` ``(N, 2)`` and ``slots`` ``(N, 2)``; the leader's ``leader_pose`` and ``leader_vel``; the humans'
    ``human_pos``/``human_vel`` ``(H, 2)``; ``speed_scale`` ``(max_speed, max_turn_rate)``; ``switch`` the capped
    time to the next switch; ``cos_th``/``sin_th`` the followers' heading cosines/sines and ``cos_rel``/``sin_rel``
    those of the leader's heading relative to theirs (numpy's, as in the reference)."""

    pose: np.ndarray
    vel: np.ndarray
    twist: np.ndarray
    slots: np.ndarray
    leader_pose: np.ndarray
    leader_vel: np.ndarray
    human_pos: np.ndarray
    human_vel: np.ndarray
    speed_scale: np.ndarray
    switch: float
    cos_th: np.ndarray
    sin_th: np.ndarray
    cos_rel: np.ndarray
    sin_rel: np.ndarray


class EntityRows(NamedTuple):
    """How many neighbour (``k``) and human (``hk``) rows the observation has (0: none) and their first columns
    (``nb_start``, ``hu_start``; :func:`swarm_env.sensing.layout.observation_layout`)."""

    k: int
    nb_start: int
    hk: int
    hu_start: int


@_jit
def _entities(out, row, base, count, dist, other_pos, other_vel, px, py, vx, vy, c, s):  # pragma: no cover - compiled
    """Write ``count`` entity rows of follower ``row`` from ``base``: the ``count`` nearest of the
    others by ``dist`` (a stable order; infinite = absent), rotated into the body frame."""
    m = len(dist)
    taken = np.zeros(m, dtype=np.bool_)
    for j in range(count):
        col = base + ENTITY * j
        best = -1
        if j < m:
            for q in range(m):
                if not taken[q] and (best < 0 or dist[q] < dist[best]):
                    best = q
        if best < 0 or not math.isfinite(dist[best]):
            for e in range(ENTITY):
                out[row, col + e] = 0.0
            if best >= 0:
                taken[best] = True
            continue
        taken[best] = True
        dx = other_pos[best, 0] - px
        dy = other_pos[best, 1] - py
        dvx = other_vel[best, 0] - vx
        dvy = other_vel[best, 1] - vy
        out[row, col + ENTITY_POS] = c * dx + s * dy
        out[row, col + ENTITY_POS + 1] = -s * dx + c * dy
        out[row, col + ENTITY_VEL] = c * dvx + s * dvy
        out[row, col + ENTITY_VEL + 1] = -s * dvx + c * dvy
        out[row, col + ENTITY_MASK] = 1.0


@_jit
def assemble(world, fdist, rows, size, low, high):  # pragma: no cover - compiled
    """``(N, size)`` float32 observations, lidar columns 0, clipped to ``low``/``high``: what
    :meth:`~swarm_env.sensing.observations.ObservationBuilder.build_without_lidar` returns.

    ``world`` an :class:`ObsWorld`; ``fdist`` the followers' centre distances ``(N, N)`` (or ``(0, 0)``: computed
    here); ``rows`` the :class:`EntityRows`.
    """
    n = len(world.pose)
    out = np.zeros((n, size))
    fill_rows(out, world, fdist, rows)
    res = np.empty((n, size), dtype=np.float32)
    clip_cast(res, out, low, high)
    return res


@_jit
def fill_rows(out, world, fdist, rows):  # pragma: no cover - compiled
    """:func:`assemble`'s float64 rows, unclipped, written into ``out`` ``(N, size)``, which must
    hold zeros (the columns not written stay 0: the lidar and absent entities' padding)."""
    pose, vel, twist, slots, leader_pose, leader_vel, human_pos, human_vel = (
        world.pose, world.vel, world.twist, world.slots, world.leader_pose, world.leader_vel, world.human_pos,
        world.human_vel)
    speed_scale, switch, cos_th, sin_th, cos_rel, sin_rel = (
        world.speed_scale, world.switch, world.cos_th, world.sin_th, world.cos_rel, world.sin_rel)
    k, nb_start, hk, hu_start = rows
    n = len(pose)
    nh = len(human_pos)
    hd = np.empty(nh)
    nd = np.empty(n)
    for i in range(n):
        px, py = pose[i, 0], pose[i, 1]
        c, s = cos_th[i], sin_th[i]
        out[i, COL_TWIST] = twist[i, 0] / speed_scale[0]
        out[i, COL_TWIST + 1] = twist[i, 1] / speed_scale[1]
        dx = slots[i, 0] - px
        dy = slots[i, 1] - py
        out[i, COL_SLOT] = c * dx + s * dy
        out[i, COL_SLOT + 1] = -s * dx + c * dy
        dx = leader_pose[0] - px
        dy = leader_pose[1] - py
        out[i, COL_LEADER_POS] = c * dx + s * dy
        out[i, COL_LEADER_POS + 1] = -s * dx + c * dy
        out[i, COL_LEADER_HEADING] = cos_rel[i]
        out[i, COL_LEADER_HEADING + 1] = sin_rel[i]
        out[i, COL_LEADER_VEL] = c * leader_vel[0] + s * leader_vel[1]
        out[i, COL_LEADER_VEL + 1] = -s * leader_vel[0] + c * leader_vel[1]
        out[i, COL_SWITCH] = switch
        vx, vy = vel[i, 0], vel[i, 1]
        if k:
            for q in range(n):
                if q == i:
                    nd[q] = math.inf
                elif len(fdist):
                    nd[q] = fdist[i, q]
                else:  # WorldState.follower_distances' arithmetic, without the (N, N) array
                    dx = px - pose[q, 0]
                    dy = py - pose[q, 1]
                    nd[q] = math.sqrt(dx * dx + dy * dy)
            _entities(out, i, nb_start, k, nd, pose, vel, px, py, vx, vy, c, s)
        if hk:
            for q in range(nh):
                dx = human_pos[q, 0] - px
                dy = human_pos[q, 1] - py
                hd[q] = math.sqrt(dx * dx + dy * dy)
            _entities(out, i, hu_start, hk, hd, human_pos, human_vel, px, py, vx, vy, c, s)


@_jit
def clip_cast(res, out, low, high):  # pragma: no cover - compiled
    """``res[:] = float32(clip(out, low, high))`` entry by entry (``out`` ``(N, size)`` float64,
    ``res`` float32 of the same shape, ``low``/``high`` ``(size,)`` float32): the reference's
    ``np.clip`` then ``astype(np.float32)``."""
    for i in range(out.shape[0]):
        for j in range(out.shape[1]):
            x = out[i, j]
            lo = np.float64(low[j])
            hi = np.float64(high[j])
            if x < lo:
                x = lo
            if x > hi:
                x = hi
            res[i, j] = np.float32(x)



@_jit
def observations_batch(rows, heads, speed_scale, switch, hcount, entities, low, high, res):  # pragma: no cover
    """``res[m]`` = world ``m``'s :meth:`ObservationBuilder.build_without_lidar
    <swarm_env.sensing.observations.ObservationBuilder.build_without_lidar>` (float32 ``(M, N, size)``):
    :func:`fill_rows` then :func:`clip_cast` per world,
    with the inputs of ``ObservationBuilder._assemble_compiled`` stacked on a leading world axis: the worlds'
    arrays ``rows`` (:class:`swarm_env.vector.batch_step.WorldRows`), ``heads = (cos_th, sin_th, cos_rel,
    sin_rel)`` the headings' numpy cosines/sines ``(M, N)``, ``speed_scale`` ``(M, 2)``, ``switch`` ``(M,)``,
    ``hcount`` ``(M,)``. ``entities`` (:class:`EntityRows`): ``k`` neighbour rows
    for every world, ``hk`` human rows in a world with humans (``hcount[m] > 0``)."""
    pose, vel, twist, slots, leader_pose, leader_vel, hpos, hvel = (
        rows.pose, rows.vel, rows.twist, rows.slots, rows.lpose, rows.lvel, rows.hpos, rows.hvel)
    cos_th, sin_th, cos_rel, sin_rel = heads
    k, nb_start, hk, hu_start = entities
    n_worlds = pose.shape[0]
    n = pose.shape[1]
    size = res.shape[2]
    no_fdist = np.zeros((0, 0))
    out = np.empty((n, size))
    for m in range(n_worlds):
        for i in range(n):
            for j in range(size):
                out[i, j] = 0.0
        hc = hcount[m]
        hkm = hk if hc else 0
        world = ObsWorld(pose[m], vel[m], twist[m], slots[m], leader_pose[m], leader_vel[m], hpos[m, :hc], hvel[m, :hc],
                         speed_scale[m], switch[m], cos_th[m], sin_th[m], cos_rel[m], sin_rel[m])
        fill_rows(out, world, no_fdist, EntityRows(k, nb_start, hkm, hu_start))
        clip_cast(res[m], out, low, high)


__all__ = ["EntityRows", "ObsWorld", "assemble", "clip_cast", "fill_rows", "observations_batch"]
