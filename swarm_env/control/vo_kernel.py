"""The velocity-obstacle selection of :func:`swarm_env.control.vo.vo_select_batch`, compiled with numba,
and the ``vo`` expert's pure pursuit.

:class:`swarm_env.control.vo._VOBatch` is the reference: numpy, readable, one vectorised pass per
stage of the search. For the handful of robots of one world it spends most of its time in numpy's
per-call overhead on small temporaries. These kernels run the same search robot by robot,
candidate by candidate, and stop each robot at its first safe candidate of a pass, without
temporaries. Entries: :func:`select` (``_VOBatch.select_compiled``: any call of
``vo_select_batch``), :func:`follower_select` (``swarm_env.control.safety.safe_follower_twists``: the
followers' discs, masks and reciprocity built from the world's arrays, the preferred twists'
trajectories and the whole search in one call) and :func:`pursuit` (``VOExpert.preferred_twists``
without preview). With all three the ``vo`` expert's ``act()`` on paper_cbs_switch (8 followers)
takes ~0.25-0.33 ms of CPU against ~1.8-2.4 ms for the numpy reference (``python
benchmarks/vo_act.py``, ratio ~7; it was ~0.75 ms with only the search compiled).

Same bits as the reference, by construction and by test (``tests/test_vo_kernel.py`` replays every
step of several whole episodes — the whole ``act()`` — and hundreds of synthetic calls through
both): every floating-point operation is the reference's, in the reference's order (``a * b + c * d``
where it computes ``a * b``, then ``+= c * d``; ``np.sinc``'s own formula where the reference calls
it; numpy's rules for ties of signed zeros in ``np.maximum``/``np.minimum``/``np.clip``).
``hypot``, ``cos``, ``sin`` and ``%`` inside the kernels are the C library's, which numpy also
calls for float64 here (``test_the_kernels_math_is_numpys_on_this_platform`` checks 1M samples of
each: if a platform's numpy used other implementations, the two could differ in a last bit).
``arctan2`` is the exception: numpy's is a SIMD implementation that differs from the C library's
``atan2`` in the last bit for a few per cent of inputs on this machine, so :func:`pursuit` takes
numpy's bearings as an input instead of computing them.

Which candidates are tested follows the reference's passes exactly (it matters for the reported
``n_safe``, not for the answer): pass 1 the least-penalty candidate, pass 2 up to rank
``first_stage`` plus the standing candidates, pass 3 the rest; a robot left alone after a pass
tests the rest at once. A robot answered in pass 1 (its preferred twist is safe) gets neither its
candidates' penalties nor their trajectories computed.
"""

from __future__ import annotations

import math

import numpy as np

from swarm_env.kernel_cache import njit

_INF = math.inf
_TWO_PI = 2.0 * math.pi
# error_model="numpy": a division by zero gives inf/nan as in numpy instead of raising.
_jit = njit(nogil=True, error_model="numpy")
# The disc and static tests are inlined into their callers by numba (not only by LLVM): a call that takes
# the tuples of arrays costs about a microsecond (measured on paper_cbs_switch), most of the search's
# time when paid twice per candidate. Inlined into _contact (and _probe) only, not further: inlining
# _contact into its caller too made the search another ~7 % faster but its compilation ~40 % slower.
_inline = njit(nogil=True, error_model="numpy", inline="always")


@_jit
def _ray_disc(px: float, py: float, R2: float, wx: float, wy: float, limit: float, still_ok: bool) -> float:
    """``vo._ray_disc_ttc`` for one pair (its docstring has the rules)."""
    wp = wx * px + wy * py
    ww = wx * wx + wy * wy
    c = px * px + py * py - R2
    disc = wp * wp - ww * c
    hit = wp > 0.0 and disc > 0.0
    if disc < 0.0:
        disc = 0.0
    den = math.sqrt(disc) + wp
    t = c / den if hit else _INF
    if c < 0.0:
        t = _INF
        if wp > 0.0 or (not still_ok and ww == 0.0):
            t = 0.0
    if t > limit:
        t = _INF
    return t


@_inline
def _disc_row(i, times, xs, ys, discs, still_ok, probe, hs):
    """Contact time of robot ``i``'s trajectory ``(xs, ys)`` (displacements at ``times``) with its
    kept discs (``vo._rows_disc_ttc`` and the horizon cut of ``_VOBatch.contact_times``).
    ``probe``: an escape probe (plain VO, moving discs only: ``_VOBatch.escape_turns``). ``hs``: the
    static circles' cut (the static horizon, or ``static_reach``'s limit for this trajectory)."""
    rel, R, dv, h, valid, recip, own, moving = discs
    best = _INF
    n_pieces = times.shape[0] - 1
    for d in range(rel.shape[1]):
        if probe:
            if not moving[i, d]:
                continue
        elif not valid[i, d]:
            continue
        R2 = R[i, d] * R[i, d]
        rc = recip[i, d] and not probe
        dvx, dvy = dv[i, d, 0], dv[i, d, 1]
        tmin = _INF
        for k in range(n_pieces):
            tk = times[k]
            dur = times[k + 1] - tk
            sx, sy = xs[k], ys[k]
            ux = (xs[k + 1] - sx) / dur
            uy = (ys[k + 1] - sy) / dur
            ox = rel[i, d, 0] + dvx * tk
            oy = rel[i, d, 1] + dvy * tk
            if rc:
                sx = 2.0 * sx - own[i, 0] * tk
                sy = 2.0 * sy - own[i, 1] * tk
                ux = 2.0 * ux - own[i, 0]
                uy = 2.0 * uy - own[i, 1]
            t = _ray_disc(ox - sx, oy - sy, R2, ux - dvx, uy - dvy, dur, still_ok) + tk
            if t < tmin:
                tmin = t
        if tmin > (h[i, d] if moving[i, d] else hs):
            tmin = _INF
        if tmin < best:
            best = tmin
    return best


@_inline
def _static_row(i, times, xs, ys, static, circles, hs):
    """Contact time of robot ``i``'s trajectory with the static map (``vo._rows_static_ttc``:
    walls, then, with ``circles``, the static circles, then the exact polygon test behind its
    bounding-circle broad phase), cut at ``hs`` (the static horizon, or ``static_reach``'s limit)."""
    (_h_static, P, rad, wax, way, woff, circ, A, Nn, L, eux, euy, centre, bound, over_rn, over_nrm, free,
     fcols) = static
    rr = rad[i]
    px0, py0 = P[i, 0], P[i, 1]
    n_pieces = times.shape[0] - 1
    # Already within the margin of a polygon and the first piece does not move away: contact now.
    dur0 = times[1] - times[0]
    vx0 = (xs[1] - xs[0]) / dur0
    vy0 = (ys[1] - ys[0]) / dur0
    for j in range(over_rn.shape[0]):
        if over_rn[j] == i and vx0 * over_nrm[j, 0] + vy0 * over_nrm[j, 1] <= 0.0:
            return 0.0
    out = _INF
    for k in range(n_pieces):
        tk = times[k]
        dur = times[k + 1] - tk
        vx = (xs[k + 1] - xs[k]) / dur
        vy = (ys[k + 1] - ys[k]) / dur
        sx = px0 + xs[k]
        sy = py0 + ys[k]
        for w in range(wax.shape[0]):
            gap = woff[w] + wax[w] * sx + way[w] * sy - rr
            vn = wax[w] * vx + way[w] * vy
            t = gap / -vn if vn < 0.0 else _INF
            if gap < 0.0:
                t = 0.0 if vn <= 0.0 else _INF
            if t > dur:
                t = _INF
            t += tk
            if t < out:
                out = t
        if circles:
            for c in range(circ.shape[0]):
                # (vo.py passes the circles to _rows_disc_ttc as discs at rest)
                R = circ[c, 2] + rr
                ox = (circ[c, 0] - px0) + 0.0 * tk
                oy = (circ[c, 1] - py0) + 0.0 * tk
                t = _ray_disc(ox - xs[k], oy - ys[k], R * R, vx - 0.0, vy - 0.0, dur, False) + tk
                if t < out:
                    out = t
        uu = vx * vx + vy * vy
        for f in range(fcols.shape[0]):
            p = fcols[f]
            if not free[i, p]:
                continue
            cx = centre[p, 0] - sx
            cy = centre[p, 1] - sy
            ts = (cx * vx + cy * vy) / uu if uu > 0.0 else 0.0
            ts = min(max(ts, 0.0), dur)
            ex = cx - ts * vx
            ey = cy - ts * vy
            rb = bound[p] + rr
            if not ex * ex + ey * ey <= rb * rb:
                continue
            best = _INF
            for e in range(A.shape[1]):
                nx, ny = Nn[p, e, 0], Nn[p, e, 1]
                rx = sx - A[p, e, 0]
                ry = sy - A[p, e, 1]
                per = rx * nx + ry * ny
                vn = vx * nx + vy * ny
                t = (per - rr) / -vn if (vn < 0.0 and per >= rr) else _INF
                if math.isfinite(t):
                    s_hit = rx * eux[p, e] + ry * euy[p, e] + (vx * eux[p, e] + vy * euy[p, e]) * t
                    if s_hit < 0.0 or s_hit > L[p, e] or t > dur:
                        t = _INF
                else:
                    t = _INF
                tv = _ray_disc(-rx, -ry, rr * rr, vx, vy, dur, False)
                if tv < t:
                    t = tv
                if t < best:
                    best = t
            best += tk
            if best < out:
                out = best
    if out > hs:
        out = _INF
    return out


@_jit
def _keep_discs(world):
    """Each robot's discs that some of its candidates can meet (``_VOBatch.prepare``): the moving discs,
    then the static circles, kept in that order and padded to the longest list (``valid`` False)."""
    (P, rad, ext, horizon, h_static, d, dv, spd_h, hd, has_recip, recip_in, own_speed, own_vel, has_mask, mask,
     has_static, W, H, circ, A, Nn, L, eux, euy, centre, bound, recip_gap) = world
    n = P.shape[0]
    n_moving = d.shape[0]
    n_all = n_moving + circ.shape[0]
    keep = np.zeros((n, n_all), dtype=np.bool_)
    n_keep = 0
    for i in range(n):
        count = 0
        for j in range(n_all):
            moving = j < n_moving
            if moving:
                x, y, r, s = d[j, 0], d[j, 1], d[j, 2], spd_h[j]
            else:
                x, y, r, s = circ[j - n_moving, 0], circ[j - n_moving, 1], circ[j - n_moving, 2], 0.0
            relx, rely = x - P[i, 0], y - P[i, 1]
            R = r + rad[i]
            if has_recip:
                reach = ((2.0 * ext + own_speed[i] * horizon) if (moving and recip_in[i, j]) else ext) + s + R
            else:
                reach = (ext + s) + R
            ok = relx * relx + rely * rely <= reach * reach
            if has_mask and moving and not mask[i, j]:
                ok = False
            keep[i, j] = ok
            count += ok
        n_keep = max(n_keep, count)
    rel = np.zeros((n, n_keep, 2))
    Rk = np.zeros((n, n_keep))
    dvk = np.zeros((n, n_keep, 2))
    hk = np.full((n, n_keep), _INF)
    valid = np.zeros((n, n_keep), dtype=np.bool_)
    recip = np.zeros((n, n_keep), dtype=np.bool_)
    moving_k = np.zeros((n, n_keep), dtype=np.bool_)
    for i in range(n):
        q = 0
        for j in range(n_all):
            if not keep[i, j]:
                continue
            moving = j < n_moving
            if moving:
                x, y, r = d[j, 0], d[j, 1], d[j, 2]
                dvk[i, q, 0], dvk[i, q, 1] = dv[j, 0], dv[j, 1]
            else:
                x, y, r = circ[j - n_moving, 0], circ[j - n_moving, 1], circ[j - n_moving, 2]
            relx, rely = x - P[i, 0], y - P[i, 1]
            R = r + rad[i]
            rel[i, q, 0], rel[i, q, 1] = relx, rely
            Rk[i, q] = R
            hk[i, q] = hd[j] if moving else h_static
            valid[i, q] = True
            moving_k[i, q] = moving
            # Within the combined radius (plus recip_gap) of a reciprocal disc already: avoided plainly (see vo.py).
            near = R + recip_gap
            recip[i, q] = has_recip and moving and recip_in[i, j] and relx * relx + rely * rely > near * near
            q += 1
    return rel, Rk, dvk, hk, valid, recip, own_vel, moving_k


@_jit
def _static_context(world):
    """``vo._static_context`` (circles included): the walls, circles and polygons in reach of
    some robot, the polygons each robot is free of (``free`` ``(N, P)``, ``fcols``), and the robots
    already within their margin of a polygon with the outward normal there (``over_rn``, ``over_nrm``)."""
    (P, rad, ext, horizon, h_static, d, dv, spd_h, hd, has_recip, recip_in, own_speed, own_vel, has_mask, mask,
     has_static, W, H, circ, A, Nn, L, eux, euy, centre, bound, _recip_gap) = world
    n = P.shape[0]
    wall_ax = np.array([0.0, -1.0, 0.0, 1.0])
    wall_ay = np.array([1.0, 0.0, -1.0, 0.0])
    wall_off = np.array([0.0, W, H, 0.0])
    near = np.zeros(4, dtype=np.bool_)
    for w in range(4):
        for i in range(n):
            if wall_off[w] + wall_ax[w] * P[i, 0] + wall_ay[w] * P[i, 1] <= rad[i] + (ext + 1e-9):
                near[w] = True
                break
    nw = int(near.sum())
    wax, way, woff = np.empty(nw), np.empty(nw), np.empty(nw)
    q = 0
    for w in range(4):
        if near[w]:
            wax[q], way[q], woff[q] = wall_ax[w], wall_ay[w], wall_off[w]
            q += 1
    keep_c = np.zeros(circ.shape[0], dtype=np.bool_)
    for c in range(circ.shape[0]):
        for i in range(n):
            if math.hypot(circ[c, 0] - P[i, 0], circ[c, 1] - P[i, 1]) - circ[c, 2] <= rad[i] + (ext + 1e-9):
                keep_c[c] = True
                break
    circ_k = circ[keep_c]
    n_poly = centre.shape[0]
    free = np.zeros((n, n_poly), dtype=np.bool_)
    any_free = np.zeros(n_poly, dtype=np.bool_)
    over_rn = np.empty(n * n_poly, dtype=np.int64)
    over_nrm = np.empty((n * n_poly, 2))
    n_over = 0
    n_edges = A.shape[1]
    for p in range(n_poly):
        cand = False
        for i in range(n):
            if math.hypot(centre[p, 0] - P[i, 0], centre[p, 1] - P[i, 1]) - bound[p] <= rad[i] + (ext + 1e-9):
                cand = True
                break
        if not cand:
            continue
        for i in range(n):
            hmax, e_max, d2min = -_INF, 0, _INF
            fx_min, fy_min = 0.0, 0.0
            for e in range(n_edges):
                qx = P[i, 0] - A[p, e, 0]
                qy = P[i, 1] - A[p, e, 1]
                perp = qx * Nn[p, e, 0] + qy * Nn[p, e, 1]
                foot = min(max(qx * eux[p, e] + qy * euy[p, e], 0.0), L[p, e])
                fx = qx - foot * eux[p, e]
                fy = qy - foot * euy[p, e]
                d2 = fx * fx + fy * fy
                if e == 0 or perp > hmax:
                    hmax, e_max = perp, e
                if e == 0 or d2 < d2min:
                    d2min, fx_min, fy_min = d2, fx, fy
            inside = hmax <= 0.0
            sd = hmax if inside else math.sqrt(d2min)
            reach = rad[i] + (ext + 1e-9)
            if sd < rad[i]:
                nx, ny = Nn[p, e_max, 0], Nn[p, e_max, 1]
                dn = math.hypot(fx_min, fy_min)
                if not inside and dn > 0.0:
                    nx, ny = fx_min / dn, fy_min / dn
                over_rn[n_over] = i
                over_nrm[n_over, 0], over_nrm[n_over, 1] = nx, ny
                n_over += 1
            elif sd <= reach:
                free[i, p] = True
                any_free[p] = True
    fcols = np.flatnonzero(any_free)
    return (h_static, P, rad, wax, way, woff, circ_k, A, Nn, L, eux, euy, centre, bound, over_rn[:n_over],
            over_nrm[:n_over], free, fcols)


@_jit
def _contact(i, times, xs, ys, discs, static, has_static, still_ok, hs):
    """``_VOBatch.contact_times`` of one trajectory of robot ``i`` (static obstacles cut at ``hs``)."""
    ttc = _INF
    if discs[0].shape[1]:
        ttc = _disc_row(i, times, xs, ys, discs, still_ok, False, hs)
    if has_static:
        ts = _static_row(i, times, xs, ys, static, False, hs)
        if ts < ttc:
            ttc = ts
    return ttc


@_jit
def _test(i, traj, cols, lo, hi, out, times, discs, static, has_static, still_ok, speeds, pv_i, reach):
    """Contact times of robot ``i``'s trajectories ``traj[c]`` ``(K+1, 2)`` for the candidates
    ``c = cols[r]``, ``lo <= r < hi``, into ``out[c]``. The one place the contact test is inlined:
    a call per robot and pass, so the tuples of arrays are unpacked once per call, not per candidate.
    ``speeds[c]``: trajectory ``c``'s speed, ``pv_i`` the robot's preferred speed and ``reach``
    ``(static_reach, t_cut)``: the static cut per trajectory (``vo._static_limits``)."""
    h_static = static[0]
    on, t_cut = reach
    for r in range(lo, hi):
        c = cols[r]
        hs = h_static
        if on:
            v = abs(speeds[c])
            if v > 0.0:
                hs = min(max(h_static, (pv_i * h_static) / v), t_cut)
        out[c] = _contact(i, times, traj[c, :, 0], traj[c, :, 1], discs, static, has_static, still_ok, hs)


@_jit
def _probe(i, c, discs, static, has_static, still_ok, probe):
    """Escape probe of robot ``i`` turning in place to candidate ``c``'s heading (``escape_turns``)."""
    twists, theta, v_max, tau, horizon = probe
    hd = theta[i] + twists[i, c, 1] * tau
    cos_h, sin_h = math.cos(hd), math.sin(hd)
    ttc = _INF
    if discs[0].shape[1]:
        run = v_max * max(horizon - tau, 0.0)
        times3 = np.array([0.0, tau, max(horizon, tau + 1e-9)])
        xs = np.array([0.0, 0.0, run * cos_h])
        ys = np.array([0.0, 0.0, run * sin_h])
        ttc = _disc_row(i, times3, xs, ys, discs, still_ok, True, static[0])
    if has_static:
        t_run = horizon - tau if horizon > 2.0 * tau else horizon
        times2 = np.array([0.0, t_run])
        xs = np.array([0.0, v_max * t_run * cos_h])
        ys = np.array([0.0, v_max * t_run * sin_h])
        ts = _static_row(i, times2, xs, ys, static, True, static[0])
        if ts < ttc:
            ttc = ts
    return ttc


@_jit
def _candidates(i, grid, pv, pw, theta, search, twists, penalty, order):
    """``_VOBatch._candidates`` for robot ``i``: its candidates (its preferred twist first, then
    ``grid``) into ``twists[i]``, their penalties into ``penalty[i]`` and their stable penalty order
    into ``order[i]``."""
    (tau, v_max, omega_max, w_pref, w_heading, side_bias, w_current, has_current, current, has_goal, goal,
     cost_velocity, gvel, _move_first, _static_reach, _t_cut, w_speed, _commit) = search
    g1 = grid.shape[0] + 1
    v_scale = v_max if v_max > 0 else 1.0
    w_scale = omega_max if omega_max > 0 else 1.0
    # cost="velocity": the preferred twist's mean body-frame velocity over tau (vo._body_velocity)
    half = 0.5 * tau * pw[i]
    scale = pv[i] * (math.sin(half) / half if half != 0.0 else 1.0)
    ux, uy = scale * math.cos(half), scale * math.sin(half)
    twists[i, 0, 0], twists[i, 0, 1] = pv[i], pw[i]
    for c in range(g1 - 1):  # (element by element: an array slice assignment compiles numba's shape-error
        twists[i, c + 1, 0], twists[i, c + 1, 1] = grid[c, 0], grid[c, 1]  # formatting, seconds of compile time)
    gh = goal[i] if has_goal else theta[i] + pw[i] * tau
    for c in range(g1):
        tv, tw = twists[i, c, 0], twists[i, c, 1]
        dv_ = (tv - pv[i]) / v_scale
        dw_ = (tw - pw[i]) / w_scale
        head = abs((theta[i] + tw * tau - gh + math.pi) % _TWO_PI - math.pi) / math.pi
        if cost_velocity:
            cx, cy = (ux, uy) if c == 0 else (gvel[c - 1, 0], gvel[c - 1, 1])
            near = math.hypot((cx - ux) / v_scale, (cy - uy) / v_scale)
        else:
            near = math.hypot(w_speed * dv_, dw_)
        pen = w_pref * near + w_heading * head + side_bias * max(dw_, 0.0)
        if has_current and c > 0:
            # (commitment to the twist being driven: see _VOBatch._candidates)
            pen += w_current * math.hypot((tv - current[i, 0]) / v_scale, (tw - current[i, 1]) / w_scale)
        penalty[i, c] = pen
    # Stable insertion sort: ties keep grid order (the preferred twist first), as numpy's stable argsort.
    for c in range(g1):
        order[i, c] = c
        j = c
        while j > 0 and penalty[i, order[i, j - 1]] > penalty[i, c]:
            order[i, j] = order[i, j - 1]
            j -= 1
        order[i, j] = c


@_jit
def _arc_points(i, pts, pref_pts, body, cos_t, sin_t):
    """``_VOBatch.all_points`` of robot ``i`` for the arc model, into ``pts[i]``: the preferred twist's
    trajectory, then the grid's body-frame trajectories rotated by the robot's heading."""
    k1 = pref_pts.shape[1]
    for k in range(k1):
        pts[i, 0, k, 0], pts[i, 0, k, 1] = pref_pts[i, k, 0], pref_pts[i, k, 1]
    c, s = cos_t[i], sin_t[i]
    for j in range(body.shape[0]):
        for k in range(k1):
            x, y = body[j, k, 0], body[j, k, 1]
            pts[i, j + 1, k, 0] = c * x - s * y
            pts[i, j + 1, k, 1] = s * x + c * y


@_jit
def _search(discs, static, has_static, plan, robots, search, flags, probe):
    """The selection rule of ``_VOBatch.select`` on the robots' kept discs and static context.

    ``plan`` ``(times, pref_pts, trajectories, grid)``: the trajectories' sample times, ``pref_pts``
    ``(N, K+1, 2)`` the preferred twists' trajectories, ``trajectories`` the grid's,
    ``(body, cos_t, sin_t, every)``: the arc model's body-frame trajectories ``(G, K+1, 2)`` and the
    cosine and sine of each robot's heading, or (``body`` empty) ``every`` candidate's world-frame
    trajectory ``(N, G+1, K+1, 2)`` (the chord model); ``grid`` the candidate twists; ``search`` the
    penalty's terms (:func:`_candidates`; after the goal headings, ``cost_velocity`` and the grid's mean body-frame
    velocities select and feed ``VOParams.cost="velocity"``, ``move_first`` is ``VOParams.move_first``, then
    ``static_reach``'s two terms, ``w_speed`` and ``escape_commit``, whose test reads the ``current`` twists).

    Returns ``twist`` ``(N, 2)``, ``feasible``, ``n_safe``, ``ttc_out``, ``escaped``, ``accepted``,
    ``pref_safe`` (see :class:`~swarm_env.control.vo.VOBatchResult`). ``robots`` ``(pv, pw, theta)``: the
    clipped preferred twists and the headings; ``flags`` ``(fast, escape, first_stage, still_ok)``.
    """
    times, pref_pts, trajectories, grid = plan
    pv, pw, theta = robots
    fast, escape, first_stage, still_ok = flags
    has_goal = search[9]
    move_first = search[13]
    reach = (search[14], search[15])
    v_max, omega_max, current, commit = search[1], search[2], search[8], search[17]
    body, cos_t, sin_t, every = trajectories
    n = pv.shape[0]
    g1 = grid.shape[0] + 1
    ttc = np.full((n, g1), np.nan)
    done = np.ones(n, dtype=np.int64)
    # Robots that search beyond their preferred twist. With the fast path (pass 1: the preferred twists
    # alone) a robot whose preferred twist is safe is answered by it (its penalty, 0, is the least: see
    # _VOBatch.select) and needs neither its candidates nor their trajectories.
    need = np.ones(n, dtype=np.bool_)
    if fast and not has_goal:
        idx = np.arange(n)
        ttc0 = np.empty(n)
        for i in range(n):
            _test(i, pref_pts, idx, i, i + 1, ttc0, times, discs, static, has_static, still_ok, pv, pv[i], reach)
            ttc[i, 0] = ttc0[i]
            need[i] = ttc0[i] != _INF
        pass_one = True
    else:
        pass_one = False
    twists = np.zeros((n, g1, 2))
    penalty = np.zeros((n, g1))
    order = np.zeros((n, g1), dtype=np.int64)
    arc = body.shape[0] > 0
    pts = np.empty((n, g1, pref_pts.shape[1], 2)) if arc else every
    for i in range(n):
        if need[i]:
            _candidates(i, grid, pv, pw, theta, search, twists, penalty, order)
            if arc:
                _arc_points(i, pts, pref_pts, body, cos_t, sin_t)
    n_still = 0
    for c in range(grid.shape[0]):
        n_still += grid[c, 0] == 0.0 and grid[c, 1] == 0.0
    still = np.empty(n_still, dtype=np.int64)
    q = 0
    for c in range(grid.shape[0]):
        if grid[c, 0] == 0.0 and grid[c, 1] == 0.0:
            still[q] = c + 1
            q += 1

    if not fast:
        for i in range(n):
            _test(i, pts[i], order[i], 0, g1, ttc[i], times, discs, static, has_static, still_ok,
                      twists[i, :, 0], pv[i], reach)
            done[i] = g1
    else:
        if not pass_one:
            for i in range(n):
                _test(i, pts[i], order[i], 0, 1, ttc[i], times, discs, static, has_static, still_ok,
                      twists[i, :, 0], pv[i], reach)
        pending = np.empty(n, dtype=np.int64)
        for stage in range(2):
            target = min(first_stage, g1) if stage == 0 else g1
            m = 0
            for i in range(n):
                if not need[i]:
                    continue
                safe = False
                for r in range(done[i]):
                    if ttc[i, order[i, r]] == _INF:
                        safe = True
                        break
                if not safe:
                    pending[m] = i
                    m += 1
            if m == 0:
                break
            if m == 1:
                target = g1
            for q in range(m):
                i = pending[q]
                if target <= done[i]:
                    continue
                _test(i, pts[i], order[i], done[i], target, ttc[i], times, discs, static, has_static, still_ok,
                      twists[i, :, 0], pv[i], reach)
                if escape and target < g1:
                    _test(i, pts[i], still, 0, n_still, ttc[i], times, discs, static, has_static, still_ok,
                      twists[i, :, 0], pv[i], reach)
                done[i] = target
            if target == g1:
                break

    # Standing candidates share one trajectory (none), hence one contact time.
    for i in range(n):
        if not need[i]:
            continue
        known = False
        tz = -_INF
        for c in range(g1):
            if twists[i, c, 0] == 0.0 and not math.isnan(ttc[i, c]):
                known = True
                if ttc[i, c] > tz:
                    tz = ttc[i, c]
        if known:
            for c in range(g1):
                if twists[i, c, 0] == 0.0:
                    ttc[i, c] = tz

    choice = np.zeros(n, dtype=np.int64)
    n_safe = np.zeros(n, dtype=np.int64)
    feasible = np.ones(n, dtype=np.bool_)
    ttc_out = np.full(n, _INF)
    escaped = np.zeros(n, dtype=np.bool_)
    pref_safe = np.zeros(n, dtype=np.bool_)
    accepted = np.zeros(n, dtype=np.bool_)
    request = np.zeros(n, dtype=np.int64)  # 0: none, 1: escape among the safe, 2: among the least dangerous
    for i in range(n):
        if not need[i]:  # answered by its preferred twist in pass 1
            pref_safe[i] = accepted[i] = True
            n_safe[i] = 1
            continue
        pref_safe[i] = ttc[i, 0] == _INF
        accepted[i] = pref_safe[i] and done[i] == 1
        best = _INF
        for c in range(g1):
            if ttc[i, c] == _INF:
                n_safe[i] += 1
                if penalty[i, c] < best:
                    best = penalty[i, c]
                    choice[i] = c
        if n_safe[i] > 0:
            if move_first and twists[i, choice[i], 0] <= 0.0 and pv[i] > 0.0:
                # Blocked: the least-penalty safe candidate that moves, if any (every candidate tested).
                m_un = 0
                for c in range(g1):
                    m_un += math.isnan(ttc[i, c])
                if m_un:
                    cols = np.empty(m_un, dtype=np.int64)
                    q = 0
                    for c in range(g1):
                        if math.isnan(ttc[i, c]):
                            cols[q] = c
                            q += 1
                    _test(i, pts[i], cols, 0, m_un, ttc[i], times, discs, static, has_static, still_ok,
                      twists[i, :, 0], pv[i], reach)
                best = _INF
                alt = -1
                for c in range(g1):
                    if ttc[i, c] == _INF and twists[i, c, 0] > 0.0 and penalty[i, c] < best:
                        best = penalty[i, c]
                        alt = c
                if alt >= 0:
                    choice[i] = alt
            if escape and twists[i, choice[i], 0] == 0.0 and pv[i] > 0.0:
                request[i] = 1
            continue
        # Nothing safe: the largest time to contact, then the slowest, then the least penalty.
        j = 0
        for c in range(1, g1):
            a, b = ttc[i, c], ttc[i, j]
            if a > b or (a == b and (abs(twists[i, c, 0]) < abs(twists[i, j, 0]) or (
                    abs(twists[i, c, 0]) == abs(twists[i, j, 0]) and penalty[i, c] < penalty[i, j]))):
                j = c
        choice[i] = j
        if escape and twists[i, j, 0] == 0.0:
            request[i] = 2
    for i in range(n):
        if request[i] == 0:
            continue
        # The escape rule needs every standing candidate's contact time.
        for c in range(g1):
            if math.isnan(ttc[i, c]) and twists[i, c, 0] == 0.0:
                _test(i, pts[i], np.array([c]), 0, 1, ttc[i], times, discs, static, has_static, still_ok,
                      twists[i, :, 0], pv[i], reach)
    for i in range(n):
        if request[i] == 0:
            continue
        j0 = choice[i]
        best_c = -1
        best_t = 0.0
        # escape_commit (vo._VOBatch.escape_turns): a robot already turning in place keeps turning that
        # way unless the other way is open for longer by more than escape_commit s.
        turning = commit > 0.0 and abs(current[i, 0]) < 0.1 * v_max and abs(current[i, 1]) > 0.1 * omega_max
        probe_t = np.full(g1, -1.0)
        best_all = -1.0
        best_same = -1.0
        for c in range(g1):
            if twists[i, c, 0] != 0.0:  # escapes turn in place
                continue
            eligible = ttc[i, c] == _INF if request[i] == 1 else ttc[i, c] == ttc[i, j0]
            if not eligible:
                continue
            t = _probe(i, c, discs, static, has_static, still_ok, (twists, theta) + probe)
            probe_t[c] = t
            if t > best_all:
                best_all = t
            if turning and twists[i, c, 1] * current[i, 1] > 0.0 and t > best_same:
                best_same = t
        only_same = turning and best_same >= 0.0 and best_same >= best_all - commit
        for c in range(g1):
            if probe_t[c] < 0.0 or (only_same and not twists[i, c, 1] * current[i, 1] > 0.0):
                continue
            t = probe_t[c]
            if best_c < 0 or t > best_t or (t == best_t and penalty[i, c] < penalty[i, best_c]):
                best_c, best_t = c, t
        choice[i] = best_c
        escaped[i] = True
    twist = np.empty((n, 2))
    for i in range(n):
        if n_safe[i] == 0:
            feasible[i] = False
            ttc_out[i] = ttc[i, choice[i]]
        if accepted[i]:
            n_safe[i] = 1
        if need[i]:
            twist[i, 0], twist[i, 1] = twists[i, choice[i], 0], twists[i, choice[i], 1]
        else:
            twist[i, 0], twist[i, 1] = pv[i], pw[i]
    return twist, feasible, n_safe, ttc_out, escaped, accepted, pref_safe


@_jit
def select(world, plan, robots, search, flags, probe):
    """``_VOBatch.select``: the whole search (pass 1 included) of the robots, discs and map of ``world``
    (as ``_VOBatch._kernel_world`` packs them). The other arguments are :func:`_search`'s."""
    discs = _keep_discs(world)
    static = _static_context(world)
    return _search(discs, static, world[15], plan, robots, search, flags, probe)


@_jit
def _np_max(a, b):
    """``np.maximum`` of two floats, ties included: ``b`` unless ``a > b`` (or ``a`` is nan)."""
    return a if (a > b or a != a) else b


@_jit
def _np_min(a, b):
    """``np.minimum`` of two floats, ties included: ``b`` unless ``a < b`` (or ``a`` is nan)."""
    return a if (a < b or a != a) else b


@_jit
def _preferred_trajectories(pv, pw, theta, tau, horizon, n_arc):
    """The preferred twists' trajectories ``(N, K+1, 2)`` of ``_VOBatch.__init__`` (arc model): for one
    robot ``vo._trajectory_row``'s plain-Python formula, for several ``_world_trajectories``'
    numpy one (``np.sinc``, whose rounding differs from ``sin(h) / h``: both are kept)."""
    n = pv.shape[0]
    t_hold = horizon if horizon < tau else tau  # Python's min(tau, horizon)
    extra = horizon > t_hold
    out = np.empty((n, n_arc + 1 + int(extra), 2))
    eps = np.finfo(np.float64).eps
    for i in range(n):
        v, w, th = pv[i], pw[i], theta[i]
        for k in range(n_arc + 1):
            if n == 1:
                t = t_hold * k / n_arc
                half = 0.5 * w * t
                scale = v * t * (math.sin(half) / half if abs(half) > 1e-12 else 1.0)
            else:
                t = k * (t_hold / n_arc)
                half = 0.5 * w * t
                x = math.pi * (half / math.pi)  # np.sinc(half / pi): sin(pi x) / (pi x), eps for 0
                y = x if x != 0.0 else eps
                scale = v * t * (math.sin(y) / y)
            out[i, k, 0] = scale * math.cos(th + half)
            out[i, k, 1] = scale * math.sin(th + half)
        if extra:
            run = v * (horizon - t_hold)
            hd = th + w * t_hold
            out[i, n_arc + 1, 0] = out[i, n_arc, 0] + run * math.cos(hd)
            out[i, n_arc + 1, 1] = out[i, n_arc, 1] + run * math.sin(hd)
    return out


@_jit
def follower_select(moving, own, n, static_map, has_static, plan, scalars, flags):
    """``vo.vo_select_batch`` as ``safety.safe_follower_twists`` calls it (arc model), from the
    world's arrays in one call: the discs, the reciprocity and the masks, the preferred twists' clipping
    and trajectories, then :func:`_search`.

    ``moving`` ``(D, 6)`` ``x, y, radius, vx, vy, horizon`` of the moving discs (``horizon``: the
    disc's own, ``vo.VODiscs.horizon``), the ``n`` followers first (each
    left out of its own list; reciprocal among themselves when ``reciprocal``), then the robot leader
    and the humans; ``own`` ``(n, 5)`` each follower's heading, current twist ``(v, omega)`` and
    preferred twist; ``static_map`` as ``vo._kernel_map`` gives it; ``plan`` ``(grid, times,
    body, gvel)`` the candidate grid, its body-frame trajectories and (``cost="velocity"``) mean
    body-frame velocities (``vo._grid_velocities``); ``scalars`` ``(margin, horizon,
    h_static, ext, tau, n_arc, v_min, v_max, omega_max, w_pref, w_heading, side_bias, w_current, recip_gap,
    t_cut, w_speed, escape_commit, trace, robot_margin)`` (``t_cut``: ``static_reach``'s latest static cut,
    ``vo._reach_cut``; ``trace``: the longest disc horizon, ``vo._trace_horizon``; ``horizon`` is the escape
    probes'; ``robot_margin``: added to the followers' radii as the others see them, ``safety.AvoidanceParams``);
    ``flags`` ``(fast, escape, still_ok, reciprocal, has_current, first_stage, cost_velocity, move_first,
    static_reach)``.
    Returns what :func:`_search` returns.
    """
    grid, times, body, gvel = plan
    (margin, horizon, h_static, ext, tau, n_arc, v_min, v_max, omega_max, w_pref, w_heading, side_bias,
     w_current, recip_gap, t_cut, w_speed, commit, trace, robot_margin) = scalars
    fast, escape, still_ok, reciprocal, has_current, first_stage, cost_velocity, move_first, static_reach = flags
    n_moving = moving.shape[0]
    P = np.empty((n, 2))
    rad = np.empty(n)
    own_vel = np.empty((n, 2))
    theta = np.empty(n)
    current = np.empty((n, 2))
    pv = np.empty(n)
    pw = np.empty(n)
    cos_t = np.empty(n)
    sin_t = np.empty(n)
    for i in range(n):
        P[i, 0], P[i, 1] = moving[i, 0], moving[i, 1]
        rad[i] = moving[i, 2] + margin
        own_vel[i, 0], own_vel[i, 1] = moving[i, 3], moving[i, 4]
        theta[i] = own[i, 0]
        current[i, 0], current[i, 1] = own[i, 1], own[i, 2]
        pv[i] = _np_min(_np_max(own[i, 3], v_min), v_max)
        pw[i] = _np_min(_np_max(own[i, 4], -omega_max), omega_max)
        cos_t[i], sin_t[i] = math.cos(theta[i]), math.sin(theta[i])
    d = np.empty((n_moving, 3))
    dv = np.empty((n_moving, 2))
    spd_h = np.empty(n_moving)
    hd = np.empty(n_moving)
    for j in range(n_moving):
        d[j, 0], d[j, 1], d[j, 2] = moving[j, 0], moving[j, 1], moving[j, 2] + (robot_margin if j < n else 0.0)
        dv[j, 0], dv[j, 1] = moving[j, 3], moving[j, 4]
        hd[j] = moving[j, 5]
        spd_h[j] = math.hypot(dv[j, 0], dv[j, 1]) * hd[j]
    has_recip = reciprocal and n > 0
    recip_in = np.zeros((n, n_moving), dtype=np.bool_)
    own_speed = np.zeros(n)
    mask = np.ones((n, n_moving), dtype=np.bool_)
    for i in range(n):
        mask[i, i] = False  # not itself
        if has_recip:
            own_speed[i] = math.hypot(own_vel[i, 0], own_vel[i, 1])
            for j in range(n):
                recip_in[i, j] = True  # the other followers; the robot leader and the humans are avoided fully
    has_mask = n >= 0  # (True, typed bool: see no_goal below)
    world = (P, rad, ext, trace, h_static, d, dv, spd_h, hd, has_recip, recip_in, own_speed, own_vel, has_mask, mask,
             has_static) + static_map + (recip_gap,)
    discs = _keep_discs(world)
    static = _static_context(world)
    # (vo._reach_end: the trajectories run to static_reach's latest cut if that is later)
    t_end = max(trace, t_cut) if static_reach else trace
    pref_pts = _preferred_trajectories(pv, pw, theta, tau, t_end, n_arc)
    no_goal = n < 0  # (False, typed bool rather than a literal: select and this entry share one _search)
    search = (tau, v_max, omega_max, w_pref, w_heading, side_bias, w_current, has_current, current, no_goal,
              np.empty(0), cost_velocity, gvel, move_first, static_reach, t_cut, w_speed, commit)
    trajectories = (body, cos_t, sin_t, np.empty((0, 1, 1, 2)))
    return _search(discs, static, has_static, (times, pref_pts, trajectories, grid), (pv, pw, theta), search,
                   (fast, escape, first_stage, still_ok), (v_max, tau, horizon))


@_jit
def pursuit(pose, target, heading, v_max, omega_max, time_gap, full_turn, arrive2):
    """The ``vo`` expert's preferred twists without preview (``VOExpert.preferred_twists``, its numpy
    reference): :func:`pursuit.pure_pursuit` of each follower ``pose[i]`` towards ``target[i]``
    (``keep_curvature``), then with ``full_turn`` a target behind turned to in place at ``omega_max``,
    and zero within ``sqrt(arrive2)`` of the target. ``heading`` ``(N,)`` is numpy's
    ``arctan2(target - pose)``: computed by numpy, as its SIMD ``arctan2`` differs from the C
    library's in the last bit for some inputs (the other functions here equal numpy's)."""
    n = pose.shape[0]
    out = np.empty((n, 2))
    half_pi = 0.5 * math.pi
    for i in range(n):
        dx = target[i, 0] - pose[i, 0]
        dy = target[i, 1] - pose[i, 1]
        dist = math.hypot(dx, dy)
        alpha = (heading[i] - pose[i, 2] + math.pi) % _TWO_PI - math.pi
        reached = dist < 1e-9
        safe_l = 1.0 if reached else dist
        v_nom = 0.0 if reached else _np_min(dist / time_gap, v_max)
        kappa = 2.0 * math.sin(alpha) / safe_l
        ahead = abs(alpha) <= half_pi
        v = v_nom if ahead else 0.0
        omega = v * kappa
        if abs(omega) > omega_max:
            v = omega_max / abs(kappa)
        # np.clip returns its argument unless it lies outside the bounds (signed zeros kept)
        if omega < -omega_max:
            omega = -omega_max
        elif omega > omega_max:
            omega = omega_max
        if not ahead:
            omega = (1.0 if alpha >= 0.0 else -1.0) * _np_min(omega_max, 2.0 * v_nom / safe_l)
        if reached:
            v = omega = 0.0
        if full_turn and abs(alpha) > half_pi:
            v = 0.0
            omega = (1.0 if alpha >= 0.0 else -1.0) * omega_max
        if dx * dx + dy * dy < arrive2:
            v = omega = 0.0
        out[i, 0], out[i, 1] = v, omega
    return out
