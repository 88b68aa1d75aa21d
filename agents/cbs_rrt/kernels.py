"""The planner's innermost tests, compiled with numba: the constraint-table lookups of
:class:`~.constraints.ConstraintTable` and the bilinear clearance of
:class:`~.distance_field.DistanceField`; and the RRT's per-expansion work around them
(:class:`~.rrt.PrimitiveRRT`: a batch of random expansions, the goal joins and intercepts, the
construction of a timed path).

Every RRT expansion tests hundreds of primitive samples against both; the numpy versions beside
them (the references) spend most of their time in per-call overhead and ``(constraints, points)``
temporaries. These kernels walk the points once. Same results bit for bit: the clearance is the
reference's arithmetic in its order (``a + fx * (b - a)``, then ``top + fy * (c + fx * (d - c) - top)``)
and the constraint tests are comparisons of the same squared distances
(``tests/test_cbs_kernels.py``).

The RRT kernels follow their numpy references operation for operation (``a - b`` squared is
``(a - b) * (a - b)``, sums in the same order, ``argmin``'s first minimum), so they give the same
plans bit for bit; the plan-identity test of ``tests/test_cbs_kernels.py`` checks whole episodes.
Two libm functions are called here: ``math.cos``/``math.sin`` (numpy's float64 ``np.cos``/``np.sin``
and Python's ``math`` call the same C library) and ``math.hypot`` (numba calls the C library's
``hypot``, as numpy's ``np.hypot`` does); and the float ``%`` (numba's is Python's, ``fmod`` and a
sign fix-up, as numpy's ``remainder``). The test module checks them against numpy on millions of
inputs. ``np.arctan2`` is not one of them: numpy's own vectorised version differs from the C
library's in the last bit for a few per cent of inputs on this machine, so it stays in numpy and
its results are passed in.
"""

from __future__ import annotations

import math

import numpy as np

from swarm_env.kernel_cache import njit

_jit = njit(nogil=True, error_model="numpy")


@_jit
def _clear1(x, y, inv, xmax, ymax, nx, values):  # pragma: no cover - compiled
    """Bilinear clearance at one point (not NaN): ``DistanceField._clearance_xy``'s arithmetic."""
    gx = min(max(x * inv, 0.0), xmax)
    gy = min(max(y * inv, 0.0), ymax)
    ix = np.int64(gx)
    iy = np.int64(gy)
    fx = gx - ix
    fy = gy - iy
    k = iy * nx + ix
    a = values[k]
    b = values[k + 1]
    c = values[k + nx]
    d = values[k + nx + 1]
    top = a + fx * (b - a)
    return top + fy * (c + fx * (d - c) - top)


@_jit
def clearance_xy(x, y, inv, xmax, ymax, nx, values):  # pragma: no cover - compiled
    """``DistanceField.clearance_xy`` of flat ``x``/``y`` (float64, same length); ``None`` if a
    coordinate is NaN (the caller then runs the reference, which raises)."""
    out = np.empty(len(x))
    for m in range(len(x)):
        if x[m] != x[m] or y[m] != y[m]:
            return None
        out[m] = _clear1(x[m], y[m], inv, xmax, ymax, nx, values)
    return out


@_jit
def _free1(x, y, t, t0, inv_dt, k_max, px, py, r2, active, any_active):  # pragma: no cover - compiled
    """``ConstraintTable.free`` of one point (time not NaN)."""
    g = (t - t0) * inv_dt + 0.5
    k = np.int64(min(max(g, 0.0), k_max))
    if not any_active[k]:
        return True
    for c in range(px.shape[0]):
        if active[c, k]:
            dx = px[c, k] - x
            dy = py[c, k] - y
            if dx * dx + dy * dy < r2[c]:
                return False
    return True


@_jit
def constraint_free(x, y, t, t0, inv_dt, k_max, px, py, r2, active, any_active):  # pragma: no cover - compiled
    """``ConstraintTable.free`` of flat ``x``/``y``/``t``: outside every active inflated disc at the
    nearest grid time; ``None`` if a time is NaN (the caller then runs the reference)."""
    out = np.ones(len(x), dtype=np.bool_)
    for m in range(len(x)):
        if t[m] != t[m]:
            return None
        out[m] = _free1(x[m], y[m], t[m], t0, inv_dt, k_max, px, py, r2, active, any_active)
    return out


@_jit
def constraint_still_free(x, y, k0, k1, px, py, r2, active):  # pragma: no cover - compiled
    """``ConstraintTable.still_free`` over grid columns ``k0:k1``."""
    for c in range(px.shape[0]):
        for k in range(k0, k1):
            if active[c, k]:
                dx = px[c, k] - x
                dy = py[c, k] - y
                if dx * dx + dy * dy < r2[c]:
                    return False
    return True



@_jit
def build_path(nx, ny, nth, nt, nk, cs, sn, local, sample_t, wait_prim, depart, add_wait, tail_t, tail_xy,
               tail_h):  # pragma: no cover - compiled
    """The samples of ``PrimitiveRRT._build``'s path through nodes ``(nx, ny, nth)`` at times ``nt``
    reached by primitives ``nk`` (``wait_prim``: a wait; ``cs``/``sn``: cosine and sine of each
    node's heading), then, if ``add_wait``, a wait until ``depart`` and the goal course's tail.

    The reference's arithmetic in its order: a primitive's samples are ``t + sample_t[k]`` and
    ``(x + c lx - s ly, y + s lx + c ly, th + lth)``; samples closer than 1e-9 s to the previous one
    are dropped. Returns ``(ok, t, pose, kind, nodes)``: ``nodes`` indexes the samples before that
    drop, as the reference's does; ``ok`` is False when the kept times are not strictly increasing
    (the caller then runs the reference, which raises)."""
    m_nodes = len(nx)
    n_samp = local.shape[1]
    size = 1
    for i in range(1, m_nodes):
        size += 1 if nk[i] == wait_prim else n_samp
    size += (1 if add_wait else 0) + len(tail_t)
    t = np.empty(size)
    pose = np.empty((size, 3))
    kind = np.empty(size, dtype=np.int8)
    nodes = np.empty(m_nodes, dtype=np.int64)
    t[0] = nt[0]
    pose[0, 0] = nx[0]
    pose[0, 1] = ny[0]
    pose[0, 2] = nth[0]
    kind[0] = 0  # START
    nodes[0] = 0
    m = 1
    for i in range(1, m_nodes):
        k = nk[i]
        if k == wait_prim:
            t[m] = nt[i]
            pose[m, 0] = nx[i]
            pose[m, 1] = ny[i]
            pose[m, 2] = nth[i]
            kind[m] = 2  # WAIT
            m += 1
        else:
            x = nx[i - 1]
            y = ny[i - 1]
            th = nth[i - 1]
            c = cs[i - 1]
            s = sn[i - 1]
            tp = nt[i - 1]
            for j in range(n_samp):
                lx = local[k, j, 0]
                ly = local[k, j, 1]
                t[m] = tp + sample_t[k, j]
                pose[m, 0] = x + c * lx - s * ly
                pose[m, 1] = y + s * lx + c * ly
                pose[m, 2] = th + local[k, j, 2]
                kind[m] = 1  # PRIM
                m += 1
        nodes[i] = m - 1
    if add_wait:
        t[m] = depart
        pose[m, 0] = nx[m_nodes - 1]
        pose[m, 1] = ny[m_nodes - 1]
        pose[m, 2] = nth[m_nodes - 1]
        kind[m] = 2  # WAIT
        m += 1
    for j in range(len(tail_t)):
        t[m] = tail_t[j]
        pose[m, 0] = tail_xy[j, 0]
        pose[m, 1] = tail_xy[j, 1]
        pose[m, 2] = tail_h[j]
        kind[m] = 3  # TAIL
        m += 1
    keep = np.ones(size, dtype=np.bool_)
    for i in range(1, size):
        keep[i] = t[i] - t[i - 1] > 1e-9
    w = 0
    ok = True
    for i in range(size):
        if keep[i]:
            if w > 0 and not t[i] > t[w - 1]:
                ok = False
            t[w] = t[i]
            pose[w, 0] = pose[i, 0]
            pose[w, 1] = pose[i, 1]
            pose[w, 2] = pose[i, 2]
            kind[w] = kind[i]
            w += 1
    return ok, t[:w], pose[:w], kind[:w], nodes


@_jit
def _search_left(a, v):  # pragma: no cover - compiled
    """``np.searchsorted(a, v, side="left")`` for sorted ``a`` and ``v`` not NaN."""
    lo = 0
    hi = len(a)
    while lo < hi:
        mid = (lo + hi) >> 1
        if a[mid] < v:
            lo = mid + 1
        else:
            hi = mid
    return lo


@_jit
def _expand_node(px, py, c, s, pt, lx, ly, lt, n_prims, n_samp,
                 f_inv, f_xmax, f_ymax, f_nx, f_values,
                 buffer, relax, sx, sy, c0, slope, rdist, floor,
                 has_cons, t0, inv_dt, k_max, cpx, cpy, r2, active, any_active,
                 sok, cok, ex, ey):  # pragma: no cover - compiled
    """Every primitive from the pose at ``(px, py)`` with heading cosine/sine ``c``/``s`` at time
    ``pt``: fills ``sok``/``cok`` (every sample keeps the buffer / the constraints; both start
    True) and the end points ``ex``/``ey``. The sample ``q`` is at ``(px + c lx - s ly, py + s lx
    + c ly)`` (``MotionPrimitives.expand``'s arithmetic) and time ``pt + lt[q]``; the buffer rule is
    ``PrimitiveRRT._static_ok``'s. False for a NaN coordinate."""
    last = n_samp - 1
    for k in range(n_prims):
        for m in range(n_samp):
            q = k * n_samp + m
            x = px + c * lx[q] - s * ly[q]
            y = py + s * lx[q] + c * ly[q]
            if x != x or y != y:
                return False
            if m == last:
                ex[k] = x
                ey[k] = y
            if sok[k]:
                clear = _clear1(x, y, f_inv, f_xmax, f_ymax, f_nx, f_values)
                if relax:
                    d = math.hypot(x - sx, y - sy)
                    need = c0 + slope * max(d - rdist, 0.0)
                    sok[k] = clear >= max(min(buffer, need), floor)
                else:
                    sok[k] = clear >= buffer
            if has_cons and cok[k]:
                cok[k] = _free1(x, y, pt + lt[q], t0, inv_dt, k_max, cpx, cpy, r2, active, any_active)
    return True


@_jit
def candidates(x, y, c, s, t, lx, ly, lt, n_prims, n_samp,
               f_inv, f_xmax, f_ymax, f_nx, f_values,
               buffer, relax, sx, sy, c0, slope, rdist, floor,
               has_cons, t0, inv_dt, k_max, cpx, cpy, r2, active, any_active):  # pragma: no cover - compiled
    """``PrimitiveRRT._candidates`` from one pose: ``(ok, sok, cok, ex, ey)`` (see :func:`_expand_node`)."""
    sok = np.ones(n_prims, dtype=np.bool_)
    cok = np.ones(n_prims, dtype=np.bool_)
    ex = np.empty(n_prims)
    ey = np.empty(n_prims)
    ok = _expand_node(x, y, c, s, t, lx, ly, lt, n_prims, n_samp, f_inv, f_xmax, f_ymax, f_nx, f_values,
                      buffer, relax, sx, sy, c0, slope, rdist, floor,
                      has_cons, t0, inv_dt, k_max, cpx, cpy, r2, active, any_active, sok, cok, ex, ey)
    return ok, sok, cok, ex, ey


@_jit
def _still_free(x, y, t_from, t_to, has_cons, t0, inv_dt, k_max, px, py, r2, active):  # pragma: no cover - compiled
    """``PrimitiveRRT._still_free`` (and ``ConstraintTable.still_free``'s grid columns)."""
    if not has_cons or t_to <= t_from:
        return True
    k_last = np.int64(k_max)
    k0 = min(max(np.int64((t_from - t0) * inv_dt + 0.5), 0), k_last)
    k1 = min(max(np.int64((t_to - t0) * inv_dt + 0.5), 0), k_last) + 1
    return constraint_still_free(x, y, k0, k1, px, py, r2, active)


@_jit
def explore_add(X, T, parent, prim, n, uniq, inv, sok, cok, ex, ey, best, found, angles, durations, wait_prim,
                wait_step, t_end, has_cons, t0, inv_dt, k_max, cpx, cpy, r2, active):  # pragma: no cover - compiled
    """``explore``'s additions to the tree (``X``, ``T``, ``parent``, ``prim``, ``n`` nodes) from
    :func:`explore_batch`'s answer, in sample order: each sample's best primitive from its node,
    or, where constraints block every primitive that the obstacles allow, a wait of ``wait_step``
    (if the robot may stand there that long and it ends by ``t_end``); a (node, primitive) pair
    once. Returns ``(n, added)``."""
    b = len(inv)
    n_prims = sok.shape[1]
    added = np.empty(b, dtype=np.int64)
    n_added = 0
    seen_u = np.empty(b, dtype=np.int64)
    seen_k = np.empty(b, dtype=np.int64)
    n_seen = 0
    for j in range(b):
        u = inv[j]
        k = best[j] if found[j] else wait_prim
        dup = False
        for q in range(n_seen):
            if seen_u[q] == u and seen_k[q] == k:
                dup = True
                break
        if dup:
            continue
        i = uniq[u]
        if k == wait_prim:
            blocked = False
            for kk in range(n_prims):
                if sok[u, kk] and not cok[u, kk]:
                    blocked = True
                    break
            t_to = T[i] + wait_step
            if not blocked or t_to > t_end:
                continue
            if not _still_free(X[i, 0], X[i, 1], T[i], t_to, has_cons, t0, inv_dt, k_max, cpx, cpy, r2, active):
                continue
            X[n, 0] = X[i, 0]
            X[n, 1] = X[i, 1]
            X[n, 2] = X[i, 2]
            T[n] = t_to
        else:
            X[n, 0] = ex[u, k]
            X[n, 1] = ey[u, k]
            X[n, 2] = X[i, 2] + angles[k]
            T[n] = T[i] + durations[k]
        seen_u[n_seen] = u
        seen_k[n_seen] = k
        n_seen += 1
        parent[n] = i
        prim[n] = k
        added[n_added] = n
        n_added += 1
        n += 1
    return n, added[:n_added]


@_jit
def explore_batch(X, n, qx, qy, atan, hw, lx, ly, lt, n_prims, n_samp, T,
                  f_inv, f_xmax, f_ymax, f_nx, f_values,
                  buffer, relax, sx, sy, c0, slope, rdist, floor,
                  has_cons, t0, inv_dt, k_max, cpx, cpy, r2, active, any_active):  # pragma: no cover - compiled
    """The vectorised part of ``PrimitiveRRT.plan``'s ``explore`` for samples ``(qx, qy)`` (``b``
    of them) and the tree ``X[:n]``, ``T[:n]``; ``atan[j, i]``: the direction from node ``i`` to
    sample ``j`` (numpy's arctan2, computed by the caller), wrapped against the node's heading here
    as the reference does (``(atan - th + pi) % (2 pi) - pi``: Python's float ``%``, which is numpy's
    ``remainder``: ``fmod`` and the sign fix-up).

    Returns ``(ok, uniq, inv, sok, cok, ex, ey, best, found)``: the distinct nearest nodes ``uniq``
    (sorted) and each sample's index into them (``np.unique``'s ``inverse``); per distinct node and
    primitive, whether every sample point keeps the buffer (``sok``) and the constraints (``cok``)
    and the end point (``ex``, ``ey``); per sample the primitive whose valid end is nearest to it
    (``best``) and whether there is one (``found``). ``ok`` is False for a NaN coordinate (the
    caller then runs the reference)."""
    b = len(qx)
    parents = np.empty(b, dtype=np.int64)
    for j in range(b):
        best = 0
        bv = 0.0
        for i in range(n):
            dx = X[i, 0] - qx[j]
            dy = X[i, 1] - qy[j]
            a = hw * abs((atan[j, i] - X[i, 2] + math.pi) % (2.0 * math.pi) - math.pi)
            v = (dx * dx + dy * dy) + a * a
            if v != v:  # argmin's first NaN
                best = i
                break
            if i == 0 or v < bv:
                bv = v
                best = i
        parents[j] = best
    srt = np.sort(parents)
    uniq = np.empty(b, dtype=np.int64)
    n_u = 0
    for j in range(b):
        if n_u == 0 or srt[j] != uniq[n_u - 1]:
            uniq[n_u] = srt[j]
            n_u += 1
    uniq = uniq[:n_u]
    inv = np.empty(b, dtype=np.int64)
    for j in range(b):
        for u in range(n_u):
            if uniq[u] == parents[j]:
                inv[j] = u
                break
    sok = np.ones((n_u, n_prims), dtype=np.bool_)
    cok = np.ones((n_u, n_prims), dtype=np.bool_)
    ex = np.empty((n_u, n_prims))
    ey = np.empty((n_u, n_prims))
    for u in range(n_u):
        i = uniq[u]
        if not _expand_node(X[i, 0], X[i, 1], math.cos(X[i, 2]), math.sin(X[i, 2]), T[i], lx, ly, lt, n_prims, n_samp,
                            f_inv, f_xmax, f_ymax, f_nx, f_values, buffer, relax, sx, sy, c0, slope, rdist, floor,
                            has_cons, t0, inv_dt, k_max, cpx, cpy, r2, active, any_active, sok[u], cok[u], ex[u], ey[u]):
            return False, uniq, inv, sok, cok, ex, ey, parents, sok[0]
    best_k = np.zeros(b, dtype=np.int64)
    found = np.zeros(b, dtype=np.bool_)
    for j in range(b):
        u = inv[j]
        bv = np.inf
        for k in range(n_prims):
            if sok[u, k] and cok[u, k]:
                dx = ex[u, k] - qx[j]
                dy = ey[u, k] - qy[j]
                v = dx * dx + dy * dy
                if v < bv:
                    bv = v
                    best_k[j] = k
                    found[j] = True
    return True, uniq, inv, sok, cok, ex, ey, best_k, found


@_jit
def near_goal(X, T, new, gt, gxy, max_wait, tol2):  # pragma: no cover - compiled
    """For each new node ``new[m]``: is some goal sample within ``sqrt(tol2)`` at a time in
    ``(T, T + max_wait]`` (the reference's squared distances; finite inputs)?"""
    out = np.zeros(len(new), dtype=np.bool_)
    for m in range(len(new)):
        i = new[m]
        t = T[i]
        hi = t + max_wait
        for k in range(len(gt)):
            if gt[k] > t and gt[k] <= hi:
                dx = gxy[k, 0] - X[i, 0]
                dy = gxy[k, 1] - X[i, 1]
                if dx * dx + dy * dy <= tol2:
                    out[m] = True
                    break
    return out


@_jit
def join_candidates(x, y, t, th, gt, gxy, fast, gdir, tail_ok, use_tail, max_wait, tol, follow, cos_join,
                    out_k, out_dep):  # pragma: no cover - compiled
    """``PrimitiveRRT._join``'s candidate goal samples (at most ``len(out_k)``, earliest first) written
    to ``out_k``/``out_dep`` (sample, departure time); returns how many."""
    n_goal = len(gt)
    k_lo = _search_left(gt, t + 1e-9)
    if k_lo >= n_goal:
        return 0
    k_hi = min(n_goal, _search_left(gt, (t + max_wait) + 1e-9) + 1)
    any_fast = False
    for k in range(k_lo, k_hi):
        if fast[k]:
            any_fast = True
            break
    c = math.cos(th) if any_fast else 0.0
    s = math.sin(th) if any_fast else 0.0
    count = 0
    for k in range(k_lo, k_hi):
        d = math.hypot(gxy[k, 0] - x, gxy[k, 1] - y)
        dep = gt[k] - d / follow
        ok = d <= tol and dep >= t
        if ok and fast[k]:
            ok = c * gdir[k, 0] + s * gdir[k, 1] >= cos_join
        if ok and use_tail:
            ok = tail_ok[k]
        if ok:
            out_k[count] = k
            out_dep[count] = dep
            count += 1
            if count == len(out_k):
                break
    return count


@_jit
def intercept(x, y, t, gt, gxy, speed, tail_ok, use_tail):  # pragma: no cover - compiled
    """``PrimitiveRRT._intercept``: the index of the first goal sample after ``t`` reachable at
    ``0.8 * speed`` (and joinable for good where ``use_tail``), else the last."""
    n_goal = len(gt)
    for k in range(min(_search_left(gt, t + 1e-9), n_goal - 1), n_goal):
        reach = (gt[k] - t) * speed * 0.8
        if math.hypot(gxy[k, 0] - x, gxy[k, 1] - y) <= reach and (not use_tail or tail_ok[k]):
            return k
    return n_goal - 1


@_jit
def _interp1(x, xp, fp, col):  # pragma: no cover - compiled
    """``np.interp(x, xp, fp[:, col])`` for one ``x`` and strictly increasing ``xp`` (numpy's
    ``arr_interp`` step by step, as :func:`.timed_path.interp_scalar`)."""
    n = len(xp)
    if n == 1:
        return fp[0, col]
    if x != x:
        return x
    if x < xp[0]:
        return fp[0, col]
    # the last j with xp[j] <= x
    lo = 0
    hi = n
    while lo < hi:
        mid = (lo + hi) >> 1
        if xp[mid] <= x:
            lo = mid + 1
        else:
            hi = mid
    j = lo - 1
    if j >= n - 1:
        return fp[n - 1, col]
    if xp[j] == x:
        return fp[j, col]
    slope = (fp[j + 1, col] - fp[j, col]) / (xp[j + 1] - xp[j])
    out = slope * (x - xp[j]) + fp[j, col]
    if out != out:
        out = slope * (x - xp[j + 1]) + fp[j + 1, col]
        if out != out and fp[j, col] == fp[j + 1, col]:
            out = fp[j, col]
    return out


@_jit
def interp_xy(times, xp, fp):  # pragma: no cover - compiled
    """``(M, 2)``: columns 0 and 1 of ``fp`` (``(K, >= 2)``) interpolated at ``times`` over ``xp``
    (``np.interp``'s values, :func:`_interp1`): ``TimedPath.position_at`` and ``GoalSpec.at``."""
    out = np.empty((len(times), 2))
    for m in range(len(times)):
        out[m, 0] = _interp1(times[m], xp, fp, 0)
        out[m, 1] = _interp1(times[m], xp, fp, 1)
    return out


@_jit
def path_free(times, xp, fp, t0, inv_dt, k_max, px, py, r2, active, any_active):  # pragma: no cover - compiled
    """``PrimitiveRRT._path_free``'s test: the path ``(xp, fp)`` at every time of ``times`` is
    outside every constraint (``ConstraintTable.free``); ``-1`` for a NaN time (the caller then
    runs the reference), else ``1``/``0``."""
    for m in range(len(times)):
        t = times[m]
        if t != t:
            return -1
        if not _free1(_interp1(t, xp, fp, 0), _interp1(t, xp, fp, 1), t, t0, inv_dt, k_max, px, py, r2, active,
                      any_active):
            return 0
    return 1


@_jit
def join(x, y, t, th, gt, gxy, fast, gdir, tail_ok, max_wait, tol, follow, cos_join, junction,
         has_cons, t0, inv_dt, k_max, px, py, r2, active, any_active, n_try):  # pragma: no cover - compiled
    """``PrimitiveRRT._join``: of the first ``n_try`` goal samples the robot may join
    (:func:`join_candidates`), the first whose wait at ``(x, y)`` from ``t`` until the departure and
    straight junction (points at fractions ``junction``) respect the constraints. Returns
    ``(k, depart)``, ``k = -1`` for none; ``k = -2`` when a junction time is NaN (the caller then
    runs the reference)."""
    out_k = np.empty(n_try, dtype=np.int64)
    out_dep = np.empty(n_try)
    count = join_candidates(x, y, t, th, gt, gxy, fast, gdir, tail_ok, has_cons, max_wait, tol, follow, cos_join,
                            out_k, out_dep)
    for c in range(count):
        k = out_k[c]
        dep = out_dep[c]
        if not has_cons:
            return k, dep
        if not _still_free(x, y, t, dep, has_cons, t0, inv_dt, k_max, px, py, r2, active):
            continue
        gx = gxy[k, 0] - x
        gy = gxy[k, 1] - y
        gtk = gt[k] - dep
        free = True
        for q in range(len(junction)):
            s = junction[q]
            jt = dep + s * gtk
            if jt != jt:
                return -2, dep
            if not _free1(x + s * gx, y + s * gy, jt, t0, inv_dt, k_max, px, py, r2, active, any_active):
                free = False
                break
        if free:
            return k, dep
    return -1, 0.0


__all__ = [
    "build_path", "candidates", "clearance_xy", "constraint_free", "constraint_still_free", "explore_add",
    "explore_batch", "intercept", "interp_xy", "join", "join_candidates", "near_goal", "path_free",
]
