"""The observation-only expert's per-row choice compiled with numba: :func:`choose` is
:meth:`ObservationExpert._choose <swarm_env_agents.obs_expert.ObservationExpert._choose>` (the numpy reference,
``swarm_env_agents.obs_expert``) for any number of rows in one call, less the pure pursuit (computed in numpy by the
caller, in the reference's chunks).

The reference builds ``(rows, candidates, times, points)`` temporaries; here each row is walked once: its moving
bodies (``_movers``), its lidar points (``_lidar_points``, filled and extended as there, the hits on the moving
bodies dropped), each candidate's first contact (``_first_contact``: the first sampled time that hits, which is the
time the reference's ``argmax`` finds; a point is searched only up to the earliest hit found so far, and skipped
where its path stays farther than its reach from the bounding box of the arc's samples, which cannot change that
time), the next step's worst case (``_next_step_unsafe``), the
choice (``_select``) and, where nothing is safe, ``_clearest``. Same actions bit for bit
(``tests/test_obs_expert.py`` compares whole episodes):

* the arithmetic is the reference's, operation for operation and in its order (``a * b / c`` is ``(a * b) / c``, a
  squared distance ``dx * dx + dy * dy``, a moved point ``p + t * v``), and the comparisons are its own (``<``,
  ``>=``, ``<=``); numba does not fuse multiplies and adds (no ``fastmath``);
* ``math.hypot``, ``math.cos`` and ``math.sin`` call the C library, as numpy's float64 ``np.hypot``, ``np.cos`` and
  ``np.sin`` do (see :mod:`swarm_env_agents.cbs_rrt.kernels`, checked in ``tests/test_cbs_kernels.py``);
* the reference's selections are kept: ``argmin`` is the first minimum (a strict ``<`` scan), a time to contact is a
  value of ``times`` (``inf`` for none), the points its padding or ``near`` filter leave out are left out here,
  and minima over points or times (the order of which the reference does not fix either) are exact.

The inputs travel as four bundles built once per :meth:`~swarm_env_agents.obs_expert.ObservationExpert.reset` and
passed as plain tuples (the expert builds them without importing numba; :func:`choose` names their items again):
:class:`Geometry` (the candidates' arrays), :class:`Bodies` (the entity blocks), :class:`Lidar` and :class:`Choice`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from swarm_env.kernel_cache import njit
from swarm_env.sensing.layout import (
    COL_LEADER_POS,
    COL_LEADER_VEL,
    COL_TWIST,
    ENTITY,
    ENTITY_MASK,
    ENTITY_POS,
    ENTITY_VEL,
)

_jit = njit(nogil=True, error_model="numpy")

__all__ = ["Bodies", "Choice", "Geometry", "Lidar", "choose"]


class Geometry(NamedTuple):
    """The candidates and the rays (the expert's ``cand``, ``arcs``, ``times``, ``step_end``, ``ray_dir``,
    ``ray_angle``; ``box`` from ``arcs``), float64, C-contiguous."""

    cand: np.ndarray  #: (C, 2) each candidate's (v, omega)
    ax: np.ndarray  #: (C, T) its arc at ``times``, body frame: x
    ay: np.ndarray  #: (C, T) and y
    box: np.ndarray  #: (C, T, 4) ``[c, t]``: the box (x min, x max, y min, y max) of the arc's samples up to ``t``
    times: np.ndarray  #: (T,) the roll-out's sample times (s)
    step_end: np.ndarray  #: (C, 2) where one control step ends
    ray_dir: np.ndarray  #: (R, 2) the rays' unit directions, body frame
    ray_angle: np.ndarray  #: (R,) the rays' angles (rad)


class Bodies(NamedTuple):
    """The moving bodies of a row (and ``v_max``, the own speed's scale): the neighbour block (``n_nb`` rows from column ``nb0``), the human block, a robot
    leader; per kind (0 neighbours, 1 humans, 2 the leader) the reference's ``_movers`` constants: the radius sum
    ``hard``, the contact distance ``reach`` (``hard + margin``), the radius ``seen`` within which a lidar hit is
    the body's (``drop_seen``) and the ``horizon`` (s)."""

    v_max: float  #: the robots' top speed (the own twist's scale)
    nb0: int
    n_nb: int
    hu0: int
    n_hu: int
    leader: bool
    hard: np.ndarray  #: (3,)
    reach: np.ndarray  #: (3,)
    seen: np.ndarray  #: (3,)
    horizon: np.ndarray  #: (3,)


class Lidar(NamedTuple):
    """The reference's ``_lidar_points`` constants: the block's first column, the range, the range below which a ray
    hits (``range * 0.999``), ``fill``, ``fill_max``, ``side_fill``, the angle between two rays, ``drop_seen``, and the
    points' contact distance, hard distance (the radius) and horizon (``static_horizon``)."""

    col0: int
    range_: float
    hit_below: float
    fill: float
    fill_max: int
    side_fill: float
    ray_gap: float
    drop_seen: bool
    reach: float
    hard: float
    horizon: float


class Choice(NamedTuple):
    """The reference's ``_contact``, ``_next_step_unsafe``, ``_select`` and ``_clearest`` constants; ``wc`` is
    ``wc_step > 0`` and ``wc_limit`` its distance ``2 radius + wc_step v_max dt_control``, ``fb`` is ``fb_clear > 0``
    and ``n_clear`` the sample times it looks at."""

    band: bool
    top_speed: float
    wc: bool
    wc_limit: float
    v_max: float
    w_max: float
    w_speed: float
    w_ttc: float
    w_rev: float
    horizon: float
    t_safe: float
    move_first: bool
    move_rev: bool
    fb: bool
    n_clear: int


@_jit
def _movers(row, b, mv):  # pragma: no cover - compiled
    """The reference's ``_movers`` for one observation ``row``: fills the columns of ``mv`` ``(8, P)`` (x, y, vx, vy
    in the body frame, the velocity made absolute with the own twist; reach, hard, horizon, seen, reach and seen -1
    where the row's mask is off) and answers ``P``."""
    own_v = row[COL_TWIST] * b.v_max
    n = 0
    for kind in range(2):
        col0 = b.nb0 if kind == 0 else b.hu0
        count = b.n_nb if kind == 0 else b.n_hu
        for k in range(count):
            c = col0 + k * ENTITY
            on = row[c + ENTITY_MASK] > 0.5
            mv[0, n] = row[c + ENTITY_POS]
            mv[1, n] = row[c + ENTITY_POS + 1]
            mv[2, n] = row[c + ENTITY_VEL] + own_v
            mv[3, n] = row[c + ENTITY_VEL + 1] + 0.0
            mv[4, n] = b.reach[kind] if on else -1.0
            mv[5, n] = b.hard[kind]
            mv[6, n] = b.horizon[kind]
            mv[7, n] = b.seen[kind] if on else -1.0
            n += 1
    if b.leader:  # the leader block: position and absolute velocity
        mv[0, n] = row[COL_LEADER_POS]
        mv[1, n] = row[COL_LEADER_POS + 1]
        mv[2, n] = row[COL_LEADER_VEL]
        mv[3, n] = row[COL_LEADER_VEL + 1]
        mv[4, n] = b.reach[2]
        mv[5, n] = b.hard[2]
        mv[6, n] = b.horizon[2]
        mv[7, n] = b.seen[2]
        n += 1
    return n


@_jit
def _keep(x, y, mv, n_mv, drop_seen):  # pragma: no cover - compiled
    """Whether a lidar point is kept: not within a moving body's ``seen`` radius (``drop_seen``; the reference's
    ``d2 < seen * seen``, ``d2`` the sum of the two squared differences)."""
    if drop_seen:
        for p in range(n_mv):
            seen = mv[7, p]
            if seen > 0:
                dx = x - mv[0, p]
                dy = y - mv[1, p]
                if dx * dx + dy * dy < seen * seen:
                    return False
    return True


@_jit
def _lidar_points(row, g, s, mv, n_mv, ranges, same, out):  # pragma: no cover - compiled
    """The reference's ``_lidar_points`` for one row: writes the kept points' x and y into ``out`` ``(2, L)`` and
    answers their count (the reference's padding, and the points it drops, are left out). ``ranges`` ``(R,)`` and
    ``same`` ``(2, R)`` are scratch."""
    n_r = ranges.shape[0]
    for k in range(n_r):
        ranges[k] = row[s.col0 + k] * s.range_
    n = 0
    for k in range(n_r):  # each ray's hit
        if ranges[k] < s.hit_below:
            x = ranges[k] * g.ray_dir[k, 0]
            y = ranges[k] * g.ray_dir[k, 1]
            if _keep(x, y, mv, n_mv, s.drop_seen):
                out[0, n] = x
                out[1, n] = y
                n += 1
    for side_i in range(2):  # the next ray (counter-clockwise), then the previous one
        side = 1 if side_i == 0 else -1
        for k in range(n_r):
            k1 = (k + side) % n_r
            r0 = ranges[k]
            r1 = ranges[k1]
            x0 = r0 * g.ray_dir[k, 0]
            y0 = r0 * g.ray_dir[k, 1]
            ex = r1 * g.ray_dir[k1, 0] - x0
            ey = r1 * g.ray_dir[k1, 1] - y0
            gap = math.hypot(ex, ey)
            same[side_i, k] = ((r0 < s.hit_below) and (r1 < s.hit_below)
                               and abs(r0 - r1) < 0.5 * max(gap, 1e-9) + 0.3)
            if side == 1 and same[side_i, k] and gap > s.fill:  # fill the gap to the next ray
                pieces = np.ceil(gap / s.fill)  # the gap in that many pieces: one point fewer inside
                den = max(pieces, 1.0)
                for j in range(1, s.fill_max + 1):
                    if j < pieces:
                        frac = j / den
                        x = x0 + frac * ex
                        y = y0 + frac * ey
                        if _keep(x, y, mv, n_mv, s.drop_seen):
                            out[0, n] = x
                            out[1, n] = y
                            n += 1
        if s.side_fill > 0:
            for k in range(n_r):
                r0 = ranges[k]
                if r0 < s.hit_below and not same[side_i, k]:  # an edge: extended sideways
                    for share in (0.5, 1.0):
                        phi = min(share * s.side_fill / max(r0, 1e-6), 0.75 * s.ray_gap)
                        angle = g.ray_angle[k] + side * phi
                        x = r0 * math.cos(angle)
                        y = r0 * math.sin(angle)
                        if _keep(x, y, mv, n_mv, s.drop_seen):
                            out[0, n] = x
                            out[1, n] = y
                            n += 1
    return n


@_jit
def _add_near(x, y, vx, vy, reach, hard, horizon, c, q, nq):  # pragma: no cover - compiled
    """One point for the contact test, as the reference's ``_contact`` and ``_first_contact`` take it (``band``,
    then the ``near`` filter, ``c`` the :class:`Choice` and ``q`` the tuple ``(xy (4, Q), r2 (Q,), n_t (Q,),
    times)``): appended at ``nq`` if some arc can reach it. Answers the new count."""
    if not reach > 0:
        return nq
    xy, r2, n_t, times = q
    if c.band:
        now = math.hypot(x, y)
        reach = max(min(reach, now - 1e-3), hard)
        if not reach > 0:
            return nq
    cut = min(horizon, times[times.shape[0] - 1] if times.shape[0] else 0.0)
    if not math.hypot(x, y) - (math.hypot(vx, vy) + c.top_speed) * cut < reach:
        return nq
    xy[0, nq] = x
    xy[1, nq] = y
    xy[2, nq] = vx
    xy[3, nq] = vy
    r2[nq] = reach * reach
    k = 0
    while k < times.shape[0] and times[k] <= horizon:
        k += 1
    n_t[nq] = k
    return nq + 1


@_jit
def _first_contact(ax, ay, box, times, q, nq, moved, ttc):  # pragma: no cover - compiled
    """The reference's ``_first_contact`` over the ``nq`` points of ``q`` (see :func:`_add_near`): each candidate's
    first sampled time within a point's squared reach ``r2`` (``dx * dx + dy * dy < r2``, the point moved to
    ``p + t v``) and no later than its horizon, into ``ttc`` ``(C,)``; ``inf`` for none. ``moved`` ``(2, Q, T)`` is
    scratch. The search for a candidate stops at the earliest time found so far, and skips a point whose path
    stays farther from the arc's bounding box (``box``, :class:`Geometry`) than the reach: both only leave out
    samples that cannot change the answer."""
    xy, r2, n_t, _ = q
    n_times = times.shape[0]
    for p in range(nq):
        for t in range(n_t[p]):
            moved[0, p, t] = xy[0, p] + times[t] * xy[2, p]
            moved[1, p, t] = xy[1, p] + times[t] * xy[3, p]
    for ci in range(ax.shape[0]):
        best = n_times
        for p in range(nq):
            stop = min(best, n_t[p])
            if stop == 0:
                continue
            rr = r2[p]
            # The arc's box up to ``stop`` and the moved point's (its ends: ``p + t v`` is monotonic in ``t``, in
            # floats too) apart by ``gap`` on one axis: every ``dx`` is at least that, so no sample can hit.
            last = stop - 1
            mx0 = moved[0, p, 0]
            mx1 = moved[0, p, last]
            my0 = moved[1, p, 0]
            my1 = moved[1, p, last]
            gap = max(box[ci, last, 0] - max(mx0, mx1), min(mx0, mx1) - box[ci, last, 1],
                      box[ci, last, 2] - max(my0, my1), min(my0, my1) - box[ci, last, 3])
            if gap > 0 and gap * gap >= rr:
                continue
            first = best  # the first sample that hits, if any (a min-reduction without a branch: vectorised)
            for t in range(stop):
                dx = ax[ci, t] - moved[0, p, t]
                dy = ay[ci, t] - moved[1, p, t]
                first = min(first, t if dx * dx + dy * dy < rr else best)
            best = first
        ttc[ci] = times[best] if best < n_times else np.inf


@_jit
def _argmin(cost, mask):  # pragma: no cover - compiled
    """``np.argmin(np.where(mask, cost, inf))``: the first masked minimum (0 where none is masked)."""
    best = np.inf
    pick = 0
    for ci in range(cost.shape[0]):
        if mask[ci] and cost[ci] < best:
            best = cost[ci]
            pick = ci
    return pick


@_jit
def _clearest(g, c, mv, n_mv, lid, n_lid, s, latest, cost, cheapest, clear):  # pragma: no cover - compiled
    """The reference's ``_clearest`` for one row with nothing safe: of the ``latest`` candidates, those keeping the
    most clearance (``hypot`` less the contact distance, the least over the real points and the first ``n_clear``
    times; within 1 mm of the best), then the cheapest. ``cheapest`` where fewer than two tie or no point is real.
    ``clear`` ``(C,)`` is scratch."""
    n_ties = 0
    for ci in range(latest.shape[0]):
        if latest[ci]:
            n_ties += 1
    real = n_lid > 0 and s.reach > 0
    for p in range(n_mv):
        if mv[4, p] > 0:
            real = True
    if n_ties < 2 or not real:
        return cheapest
    n_t = min(c.n_clear, g.times.shape[0])
    top = -np.inf
    for ci in range(latest.shape[0]):
        if not latest[ci]:
            continue
        low = np.inf
        for t in range(n_t):
            tt = g.times[t]
            ax = g.ax[ci, t]
            ay = g.ay[ci, t]
            for p in range(n_mv):
                if mv[4, p] > 0:
                    d = math.hypot(ax - (mv[0, p] + tt * mv[2, p]), ay - (mv[1, p] + tt * mv[3, p])) - mv[4, p]
                    low = min(low, d)
            if s.reach > 0:
                for p in range(n_lid):  # static: moved by t * 0.0
                    d = math.hypot(ax - (lid[0, p] + tt * 0.0), ay - (lid[1, p] + tt * 0.0)) - s.reach
                    low = min(low, d)
        clear[ci] = low
        top = max(top, low)
    floor = top - 1e-3
    best = np.inf
    pick = cheapest
    for ci in range(latest.shape[0]):
        if latest[ci] and clear[ci] >= floor and cost[ci] < best:
            best = cost[ci]
            pick = ci
    return pick


@_jit
def choose(obs, pursuit, geometry, bodies, lidar, choice, ttc_rows):  # pragma: no cover - compiled
    """The candidate each row picks, ``(M,)`` int64 (the expert's ``cand`` row): the reference's ``_choose`` for the
    rows ``obs`` ``(M, obs_size)`` float64 given their pure-pursuit twists ``pursuit`` ``(M, 2)``; the bundles as
    plain tuples (or :class:`Geometry`, :class:`Bodies`, :class:`Lidar`, :class:`Choice`). Each row's time to
    contact per candidate (after the next step's worst case, as the reference's ``_choose`` returns it) is written to
    ``ttc_rows`` ``(M, C)`` float64."""
    g = Geometry(*geometry)  # the items named again (free when compiled); a named bundle works as well
    b = Bodies(*bodies)
    s = Lidar(*lidar)
    c = Choice(*choice)
    m = obs.shape[0]
    n_c = g.cand.shape[0]
    n_times = g.times.shape[0]
    n_r = g.ray_dir.shape[0]
    n_mv_max = b.n_nb + b.n_hu + 1
    n_lid_max = n_r * (1 + s.fill_max + 4)
    mv = np.empty((8, n_mv_max))
    lid = np.empty((2, n_lid_max))
    ranges = np.empty(n_r)
    same = np.empty((2, n_r), dtype=np.bool_)
    n_q_max = n_mv_max + n_lid_max
    q = (np.empty((4, n_q_max)), np.empty(n_q_max), np.empty(n_q_max, dtype=np.int64), g.times)
    moved = np.empty((2, n_q_max, n_times))
    ttc = np.empty(n_c)
    cost = np.empty(n_c)
    safe = np.empty(n_c, dtype=np.bool_)
    moving = np.empty(n_c, dtype=np.bool_)
    latest = np.empty(n_c, dtype=np.bool_)
    clear = np.empty(n_c)
    picks = np.empty(m, dtype=np.int64)
    for i in range(m):
        row = obs[i]
        n_mv = _movers(row, b, mv)
        n_lid = _lidar_points(row, g, s, mv, n_mv, ranges, same, lid)
        nq = 0
        for p in range(n_mv):
            nq = _add_near(mv[0, p], mv[1, p], mv[2, p], mv[3, p], mv[4, p], mv[5, p], mv[6, p], c, q, nq)
        for p in range(n_lid):
            nq = _add_near(lid[0, p], lid[1, p], 0.0, 0.0, s.reach, s.hard, s.horizon, c, q, nq)
        _first_contact(g.ax, g.ay, g.box, g.times, q, nq, moved, ttc)
        if c.wc:  # the next step's worst case, against the neighbour rows
            for p in range(b.n_nb):
                col = b.nb0 + p * ENTITY
                if not row[col + ENTITY_MASK] > 0.5:
                    continue
                px = row[col + ENTITY_POS]
                py = row[col + ENTITY_POS + 1]
                limit = min(math.hypot(px, py) - 1e-6, c.wc_limit)
                if not limit > 0:  # a distance is never below it
                    continue
                for ci in range(n_c):
                    if math.hypot(g.step_end[ci, 0] - px, g.step_end[ci, 1] - py) < limit:
                        ttc[ci] = 0.0
        ttc_rows[i, :] = ttc
        # the choice (the reference's _select)
        pv = pursuit[i, 0]
        pw = pursuit[i, 1]
        any_safe = False
        any_moving = False
        t_max = -np.inf
        for ci in range(n_c):
            v = g.cand[ci, 0]
            w = g.cand[ci, 1]
            k = math.hypot(c.w_speed * (v - pv) / c.v_max, (w - pw) / c.w_max)
            k = k + c.w_ttc * (c.horizon - min(ttc[ci], c.horizon)) / c.horizon
            k = k + c.w_rev * max(-v, 0.0) / c.v_max
            cost[ci] = k
            safe[ci] = ttc[ci] >= c.t_safe
            any_safe = any_safe or safe[ci]
            moving[ci] = safe[ci] and (abs(v) if c.move_rev else v) > 1e-9
            any_moving = any_moving or moving[ci]
            t_max = max(t_max, ttc[ci])
        pick = _argmin(cost, safe)
        if c.move_first and g.cand[pick, 0] <= 1e-9 and pv > 1e-3 and any_moving:
            pick = _argmin(cost, moving)
        if not any_safe:
            for ci in range(n_c):
                latest[ci] = ttc[ci] >= t_max
            pick = _argmin(cost, latest)
            if c.fb:
                pick = _clearest(g, c, mv, n_mv, lid, n_lid, s, latest, cost, pick, clear)
        picks[i] = pick
    return picks
