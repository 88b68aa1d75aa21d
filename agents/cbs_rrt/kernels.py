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

The kernels take their inputs as typed bundles (``NamedTuple`` classes, one numba argument each), each
built once by the object that owns the data: :class:`Field` (``DistanceField.kernel``),
:class:`Cons` (``ConstraintTable.kernel``), :class:`Prims` (``MotionPrimitives.kernel``),
:class:`Tree` (the RRT's tree), and, per planning call, the RRT's :class:`Buffer`,
:class:`Search` and :class:`Goal`; :class:`Batch` (a batch of expansions, passed from
:func:`explore_batch` to :func:`explore_add`), :class:`Branch` and :class:`Tail` (a path to build)
carry one call's data. A bundle's fields keep one type whatever the data (floats stay floats, a
table without constraints has placeholder arrays of the real ones' types, a goal without
constraints a placeholder mask for ``tail_ok``), so one compilation serves every call. Reading a
field is reading the argument it replaces: the arithmetic, and so the bits, are the same.

The owners keep the long-lived bundles as plain tuples of the same items (:func:`plain`): numba
types a plain tuple argument several times faster than a ``NamedTuple`` one, which counts on the
RRT's frequent calls. A kernel takes either form and names the items again first thing
(:func:`_as_search`, ...), at no cost in compiled code.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from swarm_env.kernel_cache import njit

_jit = njit(nogil=True, error_model="numpy")
# The rebuilders of a bundle from its plain tuple (_as_field, ...), inlined by numba: a kernel then reads the
# items of its argument in place. (The per-sample helpers, _clear1 and _free1, are not: inlined, their field
# reads inside the callers' loops measured slower.)
_jit_inline = njit(nogil=True, error_model="numpy", inline="always")


class Field(NamedTuple):
    """A :class:`~.distance_field.DistanceField` as the kernels read it (its ``kernel``, kept :func:`plain`)."""

    inv: float  #: 1 / resolution: world metres to grid coordinates
    xmax: float  #: the largest grid x whose cell (floor) still has a right neighbour
    ymax: float  #: the largest grid y whose cell still has a top neighbour
    nx: int  #: grid nodes per row
    values: np.ndarray  #: (ny * nx,) flat row-major clearances (m)


class Cons(NamedTuple):
    """A :class:`~.constraints.ConstraintTable` as the kernels read it (its ``kernel``, kept :func:`plain`): ``C``
    constraints sampled at the ``K`` grid times ``t0 + k dt``. Without constraints (``has`` False)
    the arrays are placeholders of the same types, never read."""

    has: bool  #: any constraints
    t0: float  #: the grid's first time (s)
    inv_dt: float  #: 1 / dt
    k_max: float  #: the last grid index, K - 1 (a float: the nearest index is clamped in floats)
    px: np.ndarray  #: (C, K) the discs' centres, x
    py: np.ndarray  #: (C, K) and y
    r2: np.ndarray  #: (C,) squared inflated radii
    active: np.ndarray  #: (C, K) bool: the constraint counts at that grid time
    any_active: np.ndarray  #: (K,) bool: some constraint counts at that grid time


class Prims(NamedTuple):
    """A :class:`~.primitives.MotionPrimitives` library as the kernels read it (its ``kernel``, kept :func:`plain`):
    ``P`` primitives of ``S`` samples each, primitive-major where flattened (the samples of
    primitive ``k`` are ``[k S, (k + 1) S)``)."""

    lx: np.ndarray  #: (P * S,) local x of every sample
    ly: np.ndarray  #: (P * S,) local y
    lt: np.ndarray  #: (P * S,) time of every sample after the primitive's start (s)
    local: np.ndarray  #: (P, S, 3) local poses of the samples
    sample_t: np.ndarray  #: (P, S) the sample times again, by primitive
    angles: np.ndarray  #: (P,) heading change of each primitive (rad)
    durations: np.ndarray  #: (P,) seconds
    n_prims: int  #: P
    n_samples: int  #: S


class Buffer(NamedTuple):
    """``PrimitiveRRT._static_ok``'s rule for one planning call: a sample keeps ``buffer`` from
    obstacles, or, where the robot started inside the buffer zone (``relax``), at least
    ``max(min(buffer, c0 + slope * max(d - rdist, 0)), floor)`` at distance ``d`` from the start
    ``(sx, sy)``."""

    buffer: float
    relax: bool
    sx: float
    sy: float
    c0: float
    slope: float
    rdist: float
    floor: float


class Search(NamedTuple):
    """What every expansion of one :meth:`~.rrt.PrimitiveRRT.plan` reads: the primitives, the
    obstacles (field and buffer rule), the constraints, the nearest-node metric's metres per radian
    of heading error, the wait node (its primitive id, its duration) and the planning horizon."""

    prims: Prims
    field: Field
    rule: Buffer
    cons: Cons
    heading_weight: float
    wait_prim: int
    wait_step: float
    t_end: float


class Goal(NamedTuple):
    """One robot's moving goal (:class:`~.rrt.GoalSpec`, ``K`` samples) with the RRT's join settings,
    bound once per planning call."""

    t: np.ndarray  #: (K,) sample times
    xy: np.ndarray  #: (K, 2) the effective goal positions
    fast: np.ndarray  #: (K,) bool: the goal moves faster than a robot may join it sideways
    dir: np.ndarray  #: (K, 2) unit direction of the goal's motion
    tail_ok: np.ndarray  #: (K,) bool: following the course from there respects the constraints
    use_tail: bool  #: read ``tail_ok`` (there are constraints; otherwise it is a placeholder)
    max_wait: float  #: the longest a robot may wait for a sample (s)
    tol: float  #: join tolerance (m)
    tol2: float  #: its square
    follow: float  #: speed of the junction move (m/s)
    cos_join: float  #: cosine of the largest heading error to join a fast goal
    speed: float  #: the primitives' speed, for the intercept (m/s)
    junction: np.ndarray  #: fractions of the junction move checked against the constraints
    n_try: int  #: joinable samples tried at most


class Tree(NamedTuple):
    """The RRT's node arrays (capacity ``cap``): poses ``X (cap, 3)``, times ``T``, each node's
    ``parent`` and the primitive that reached it (``prim``)."""

    X: np.ndarray
    T: np.ndarray
    parent: np.ndarray
    prim: np.ndarray


class Batch(NamedTuple):
    """A batch of random expansions (:func:`explore_batch`'s answer, ``b`` samples): the distinct
    nearest nodes ``uniq`` (``U`` of them) and each sample's index into them (``inv``); per distinct
    node and primitive, whether every sample point keeps the buffer (``sok``) and the constraints
    (``cok``) and the end point (``ex``, ``ey``); per sample its best primitive (``best``) and
    whether there is one (``found``)."""

    uniq: np.ndarray
    inv: np.ndarray
    sok: np.ndarray
    cok: np.ndarray
    ex: np.ndarray
    ey: np.ndarray
    best: np.ndarray
    found: np.ndarray


class Branch(NamedTuple):
    """The nodes of a branch, for :func:`build_path`: poses ``(x, y, th)``, times ``t``, the
    primitive that reached each (``prim``) and the cosine and sine of each heading."""

    x: np.ndarray
    y: np.ndarray
    th: np.ndarray
    t: np.ndarray
    prim: np.ndarray
    cos: np.ndarray
    sin: np.ndarray


class Tail(NamedTuple):
    """What follows a branch that joins its goal, for :func:`build_path`: a wait until ``depart``
    (if ``add_wait``) and the goal course from the joined sample (times ``t``, positions ``xy``,
    ``heading``); empty arrays for a branch that does not join."""

    add_wait: bool
    depart: float
    t: np.ndarray
    xy: np.ndarray
    heading: np.ndarray


def plain(bundle: tuple) -> tuple:
    """``bundle`` with every ``NamedTuple`` in it (itself included) made a plain tuple of the same items: the form
    the bundles are kept and passed in. numba types a ``NamedTuple`` argument on every call by spelling out its
    class and field names (about 1 us each, nested ones included: 5 us for a :class:`Search`, most of a
    :func:`candidates` call's own cost), a plain tuple by its items only (0.6 us for a :class:`Search`); the
    kernels take either and name the items again first thing (:func:`_as_search`, ...), which costs nothing
    compiled."""
    return tuple(plain(v) if isinstance(v, tuple) else v for v in bundle)


@_jit_inline
def _as_field(f):  # pragma: no cover - compiled
    """``f`` (a :class:`Field` or its :func:`plain` tuple) as a :class:`Field`."""
    return Field(*f)


@_jit_inline
def _as_cons(c):  # pragma: no cover - compiled
    """``c`` (a :class:`Cons` or its :func:`plain` tuple) as a :class:`Cons`."""
    return Cons(*c)


@_jit_inline
def _as_prims(p):  # pragma: no cover - compiled
    """``p`` (a :class:`Prims` or its :func:`plain` tuple) as a :class:`Prims`."""
    return Prims(*p)


@_jit_inline
def _as_search(s):  # pragma: no cover - compiled
    """``s`` (a :class:`Search` or its :func:`plain` tuple) as a :class:`Search` of named bundles."""
    return Search(_as_prims(s[0]), _as_field(s[1]), Buffer(*s[2]), _as_cons(s[3]), s[4], s[5], s[6], s[7])


@_jit_inline
def _as_goal(g):  # pragma: no cover - compiled
    """``g`` (a :class:`Goal` or its :func:`plain` tuple) as a :class:`Goal`."""
    return Goal(*g)


@_jit_inline
def _as_tree(t):  # pragma: no cover - compiled
    """``t`` (a :class:`Tree` or its :func:`plain` tuple) as a :class:`Tree`."""
    return Tree(*t)


@_jit_inline
def _as_batch(b):  # pragma: no cover - compiled
    """``b`` (a :class:`Batch` or the same items in a plain tuple) as a :class:`Batch`."""
    return Batch(*b)


@_jit
def _clear1(x, y, field):  # pragma: no cover - compiled
    """Bilinear clearance at one point (not NaN): ``DistanceField._clearance_xy``'s arithmetic."""
    gx = min(max(x * field.inv, 0.0), field.xmax)
    gy = min(max(y * field.inv, 0.0), field.ymax)
    ix = np.int64(gx)
    iy = np.int64(gy)
    fx = gx - ix
    fy = gy - iy
    nx = field.nx
    values = field.values
    k = iy * nx + ix
    a = values[k]
    b = values[k + 1]
    c = values[k + nx]
    d = values[k + nx + 1]
    top = a + fx * (b - a)
    return top + fy * (c + fx * (d - c) - top)


@_jit
def clearance_xy(x, y, field):  # pragma: no cover - compiled
    """``DistanceField.clearance_xy`` of flat ``x``/``y`` (float64, same length) in ``field``
    (:class:`Field`); ``None`` if a coordinate is NaN (the caller then runs the reference, which
    raises)."""
    field = _as_field(field)
    out = np.empty(len(x))
    for m in range(len(x)):
        if x[m] != x[m] or y[m] != y[m]:
            return None
        out[m] = _clear1(x[m], y[m], field)
    return out


@_jit
def _free1(x, y, t, cons):  # pragma: no cover - compiled
    """``ConstraintTable.free`` of one point (time not NaN) in the table ``cons`` (:class:`Cons`)."""
    g = (t - cons.t0) * cons.inv_dt + 0.5
    k = np.int64(min(max(g, 0.0), cons.k_max))
    if not cons.any_active[k]:
        return True
    px = cons.px
    py = cons.py
    for c in range(px.shape[0]):
        if cons.active[c, k]:
            dx = px[c, k] - x
            dy = py[c, k] - y
            if dx * dx + dy * dy < cons.r2[c]:
                return False
    return True


@_jit
def constraint_free(x, y, t, cons):  # pragma: no cover - compiled
    """``ConstraintTable.free`` of flat ``x``/``y``/``t`` (``cons``: the table, with constraints):
    outside every active inflated disc at the nearest grid time; ``None`` if a time is NaN (the
    caller then runs the reference)."""
    cons = _as_cons(cons)
    out = np.ones(len(x), dtype=np.bool_)
    for m in range(len(x)):
        if t[m] != t[m]:
            return None
        out[m] = _free1(x[m], y[m], t[m], cons)
    return out


@_jit
def constraint_still_free(x, y, k0, k1, cons):  # pragma: no cover - compiled
    """``ConstraintTable.still_free`` over grid columns ``k0:k1`` of the table ``cons``."""
    cons = _as_cons(cons)
    px = cons.px
    py = cons.py
    for c in range(px.shape[0]):
        for k in range(k0, k1):
            if cons.active[c, k]:
                dx = px[c, k] - x
                dy = py[c, k] - y
                if dx * dx + dy * dy < cons.r2[c]:
                    return False
    return True


@_jit
def _put(t, pose, kind, m, tm, x, y, th, km):  # pragma: no cover - compiled
    """Sample ``m`` of :func:`build_path`: time ``tm``, pose ``(x, y, th)``, kind ``km``."""
    t[m] = tm
    pose[m, 0] = x
    pose[m, 1] = y
    pose[m, 2] = th
    kind[m] = km


@_jit
def _drop_repeats(t, pose, kind):  # pragma: no cover - compiled
    """Keep the first sample and every one more than 1e-9 s after the one before it (in the
    original order), compacted to the front; returns ``(ok, kept)``, ``ok`` False when the kept
    times are not strictly increasing."""
    size = len(t)
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
    return ok, w


@_jit
def build_path(branch, prims, tail, wait_prim):  # pragma: no cover - compiled
    """The samples of ``PrimitiveRRT._build``'s path through the nodes of ``branch``
    (:class:`Branch`; ``wait_prim``: the primitive id of a wait) with the primitives ``prims``,
    then, if ``tail.add_wait``, a wait until ``tail.depart``, and the goal course's tail
    (:class:`Tail`).

    The reference's arithmetic in its order: a primitive's samples are ``t + sample_t[k]`` and
    ``(x + c lx - s ly, y + s lx + c ly, th + lth)``; samples closer than 1e-9 s to the previous one
    are dropped. Returns ``(ok, t, pose, kind, nodes)``: ``nodes`` indexes the samples before that
    drop, as the reference's does; ``ok`` is False when the kept times are not strictly increasing
    (the caller then runs the reference, which raises)."""
    prims = _as_prims(prims)
    nx, ny, nth, nt, nk = branch.x, branch.y, branch.th, branch.t, branch.prim
    local = prims.local
    m_nodes = len(nx)
    n_samp = local.shape[1]
    size = 1
    for i in range(1, m_nodes):
        size += 1 if nk[i] == wait_prim else n_samp
    size += (1 if tail.add_wait else 0) + len(tail.t)
    t = np.empty(size)
    pose = np.empty((size, 3))
    kind = np.empty(size, dtype=np.int8)
    nodes = np.empty(m_nodes, dtype=np.int64)
    _put(t, pose, kind, 0, nt[0], nx[0], ny[0], nth[0], 0)  # START
    nodes[0] = 0
    m = 1
    for i in range(1, m_nodes):
        k = nk[i]
        if k == wait_prim:
            _put(t, pose, kind, m, nt[i], nx[i], ny[i], nth[i], 2)  # WAIT
            m += 1
        else:
            x = nx[i - 1]
            y = ny[i - 1]
            th = nth[i - 1]
            c = branch.cos[i - 1]
            s = branch.sin[i - 1]
            tp = nt[i - 1]
            for j in range(n_samp):
                lx = local[k, j, 0]
                ly = local[k, j, 1]
                _put(t, pose, kind, m, tp + prims.sample_t[k, j], x + c * lx - s * ly, y + s * lx + c * ly,
                     th + local[k, j, 2], 1)  # PRIM
                m += 1
        nodes[i] = m - 1
    if tail.add_wait:
        last = m_nodes - 1
        _put(t, pose, kind, m, tail.depart, nx[last], ny[last], nth[last], 2)  # WAIT
        m += 1
    for j in range(len(tail.t)):
        _put(t, pose, kind, m, tail.t[j], tail.xy[j, 0], tail.xy[j, 1], tail.heading[j], 3)  # TAIL
        m += 1
    ok, w = _drop_repeats(t, pose, kind)
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
def _static_ok(x, y, field, rule):  # pragma: no cover - compiled
    """``PrimitiveRRT._static_ok`` at one point: the clearance in ``field`` keeps the buffer rule
    ``rule`` (:class:`Buffer`)."""
    clear = _clear1(x, y, field)
    if rule.relax:
        d = math.hypot(x - rule.sx, y - rule.sy)
        need = rule.c0 + rule.slope * max(d - rule.rdist, 0.0)
        return clear >= max(min(rule.buffer, need), rule.floor)
    return clear >= rule.buffer


@_jit
def _expand_node(px, py, c, s, pt, search, sok, cok, ex, ey):  # pragma: no cover - compiled
    """Every primitive of ``search.prims`` from the pose at ``(px, py)`` with heading cosine/sine
    ``c``/``s`` at time ``pt``: fills ``sok``/``cok`` (every sample keeps the buffer / the
    constraints; both start True) and the end points ``ex``/``ey``. The sample ``q`` is at ``(px +
    c lx - s ly, py + s lx + c ly)`` (``MotionPrimitives.expand``'s arithmetic) and time ``pt +
    lt[q]``; the buffer rule is ``PrimitiveRRT._static_ok``'s. False for a NaN coordinate."""
    prims = search.prims
    cons = search.cons
    field = search.field
    rule = search.rule
    lx, ly, lt = prims.lx, prims.ly, prims.lt
    n_samp = prims.n_samples
    last = n_samp - 1
    for k in range(prims.n_prims):
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
                sok[k] = _static_ok(x, y, field, rule)
            if cons.has and cok[k]:
                cok[k] = _free1(x, y, pt + lt[q], cons)
    return True


@_jit
def candidates(x, y, c, s, t, search):  # pragma: no cover - compiled
    """``PrimitiveRRT._candidates`` from one pose under ``search`` (:class:`Search`): ``(ok, sok,
    cok, ex, ey)`` (see :func:`_expand_node`)."""
    search = _as_search(search)
    n_prims = search.prims.n_prims
    sok = np.ones(n_prims, dtype=np.bool_)
    cok = np.ones(n_prims, dtype=np.bool_)
    ex = np.empty(n_prims)
    ey = np.empty(n_prims)
    ok = _expand_node(x, y, c, s, t, search, sok, cok, ex, ey)
    return ok, sok, cok, ex, ey


@_jit
def _still_free(x, y, t_from, t_to, cons):  # pragma: no cover - compiled
    """``PrimitiveRRT._still_free`` (and ``ConstraintTable.still_free``'s grid columns)."""
    if not cons.has or t_to <= t_from:
        return True
    k_last = np.int64(cons.k_max)
    k0 = min(max(np.int64((t_from - cons.t0) * cons.inv_dt + 0.5), 0), k_last)
    k1 = min(max(np.int64((t_to - cons.t0) * cons.inv_dt + 0.5), 0), k_last) + 1
    return constraint_still_free(x, y, k0, k1, cons)


@_jit
def _blocked(sok, cok, u):  # pragma: no cover - compiled
    """Constraints block a primitive of distinct node ``u`` that the obstacles allow."""
    for kk in range(sok.shape[1]):
        if sok[u, kk] and not cok[u, kk]:
            return True
    return False


@_jit
def explore_add(tree, n, batch, search):  # pragma: no cover - compiled
    """``explore``'s additions to ``tree`` (:class:`Tree`, ``n`` nodes in use) from
    :func:`explore_batch`'s answer ``batch`` (:class:`Batch`), in sample order: each sample's best
    primitive from its node, or, where constraints block every primitive that the obstacles allow,
    a wait of ``search.wait_step`` (if the robot may stand there that long and it ends by
    ``search.t_end``); a (node, primitive) pair once. Returns ``(n, added)``."""
    tree = _as_tree(tree)
    batch = _as_batch(batch)
    search = _as_search(search)
    X, T = tree.X, tree.T
    inv = batch.inv
    wait_prim = search.wait_prim
    b = len(inv)
    added = np.empty(b, dtype=np.int64)
    n_added = 0
    seen_u = np.empty(b, dtype=np.int64)
    seen_k = np.empty(b, dtype=np.int64)
    n_seen = 0
    for j in range(b):
        u = inv[j]
        k = batch.best[j] if batch.found[j] else wait_prim
        dup = False
        for q in range(n_seen):
            if seen_u[q] == u and seen_k[q] == k:
                dup = True
                break
        if dup:
            continue
        i = batch.uniq[u]
        if k == wait_prim:
            t_to = T[i] + search.wait_step
            if not _blocked(batch.sok, batch.cok, u) or t_to > search.t_end:
                continue
            if not _still_free(X[i, 0], X[i, 1], T[i], t_to, search.cons):
                continue
            X[n, 0] = X[i, 0]
            X[n, 1] = X[i, 1]
            X[n, 2] = X[i, 2]
            T[n] = t_to
        else:
            X[n, 0] = batch.ex[u, k]
            X[n, 1] = batch.ey[u, k]
            X[n, 2] = X[i, 2] + search.prims.angles[k]
            T[n] = T[i] + search.prims.durations[k]
        seen_u[n_seen] = u
        seen_k[n_seen] = k
        n_seen += 1
        tree.parent[n] = i
        tree.prim[n] = k
        added[n_added] = n
        n_added += 1
        n += 1
    return n, added[:n_added]


@_jit
def _nearest_nodes(X, n, qx, qy, atan, hw):  # pragma: no cover - compiled
    """Each sample's nearest of the nodes ``X[:n]`` (squared distance plus ``(hw * wrapped heading
    error)^2``, ``argmin``'s first minimum or first NaN)."""
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
    return parents


@_jit
def _unique_inverse(parents):  # pragma: no cover - compiled
    """``np.unique(parents, return_inverse=True)``: the sorted distinct values and each one's index."""
    b = len(parents)
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
    return uniq, inv


@_jit
def explore_batch(tree, n, qx, qy, atan, search):  # pragma: no cover - compiled
    """The vectorised part of ``PrimitiveRRT.plan``'s ``explore`` for samples ``(qx, qy)`` (``b``
    of them) and the nodes ``tree.X[:n]``, ``tree.T[:n]`` under ``search`` (:class:`Search`);
    ``atan[j, i]``: the direction from node ``i`` to sample ``j`` (numpy's arctan2, computed by the
    caller), wrapped against the node's heading here as the reference does (``(atan - th + pi) % (2
    pi) - pi``: Python's float ``%``, which is numpy's ``remainder``: ``fmod`` and the sign fix-up).

    Returns ``(ok, uniq, inv, sok, cok, ex, ey, best, found)``: :class:`Batch`'s fields (the distinct
    nearest nodes sorted, each sample's index into them as ``np.unique``'s ``inverse``; per sample
    the primitive whose valid end is nearest to it). ``ok`` is False for a NaN coordinate (the
    caller then runs the reference)."""
    tree = _as_tree(tree)
    search = _as_search(search)
    X, T = tree.X, tree.T
    n_prims = search.prims.n_prims
    b = len(qx)
    parents = _nearest_nodes(X, n, qx, qy, atan, search.heading_weight)
    uniq, inv = _unique_inverse(parents)
    n_u = len(uniq)
    sok = np.ones((n_u, n_prims), dtype=np.bool_)
    cok = np.ones((n_u, n_prims), dtype=np.bool_)
    ex = np.empty((n_u, n_prims))
    ey = np.empty((n_u, n_prims))
    for u in range(n_u):
        i = uniq[u]
        if not _expand_node(X[i, 0], X[i, 1], math.cos(X[i, 2]), math.sin(X[i, 2]), T[i], search,
                            sok[u], cok[u], ex[u], ey[u]):
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
def near_goal(tree, new, goal):  # pragma: no cover - compiled
    """For each new node ``new[m]`` of ``tree``: is some sample of ``goal`` (:class:`Goal`) within
    ``goal.tol`` at a time in ``(T, T + max_wait]`` (the reference's squared distances, against
    ``goal.tol2``; finite inputs)?"""
    tree = _as_tree(tree)
    goal = _as_goal(goal)
    X, T = tree.X, tree.T
    gt, gxy = goal.t, goal.xy
    out = np.zeros(len(new), dtype=np.bool_)
    for m in range(len(new)):
        i = new[m]
        t = T[i]
        hi = t + goal.max_wait
        for k in range(len(gt)):
            if gt[k] > t and gt[k] <= hi:
                dx = gxy[k, 0] - X[i, 0]
                dy = gxy[k, 1] - X[i, 1]
                if dx * dx + dy * dy <= goal.tol2:
                    out[m] = True
                    break
    return out


@_jit
def join_candidates(x, y, t, th, goal, out_k, out_dep):  # pragma: no cover - compiled
    """``PrimitiveRRT._join``'s candidate samples of ``goal`` (:class:`Goal`; at most ``len(out_k)``,
    earliest first) for a robot at ``(x, y)`` with heading ``th`` at ``t``, written to
    ``out_k``/``out_dep`` (sample, departure time); returns how many."""
    goal = _as_goal(goal)
    gt, gxy = goal.t, goal.xy
    n_goal = len(gt)
    k_lo = _search_left(gt, t + 1e-9)
    if k_lo >= n_goal:
        return 0
    k_hi = min(n_goal, _search_left(gt, (t + goal.max_wait) + 1e-9) + 1)
    any_fast = False
    for k in range(k_lo, k_hi):
        if goal.fast[k]:
            any_fast = True
            break
    c = math.cos(th) if any_fast else 0.0
    s = math.sin(th) if any_fast else 0.0
    count = 0
    for k in range(k_lo, k_hi):
        d = math.hypot(gxy[k, 0] - x, gxy[k, 1] - y)
        dep = gt[k] - d / goal.follow
        ok = d <= goal.tol and dep >= t
        if ok and goal.fast[k]:
            ok = c * goal.dir[k, 0] + s * goal.dir[k, 1] >= goal.cos_join
        if ok and goal.use_tail:
            ok = goal.tail_ok[k]
        if ok:
            out_k[count] = k
            out_dep[count] = dep
            count += 1
            if count == len(out_k):
                break
    return count


@_jit
def intercept(x, y, t, goal):  # pragma: no cover - compiled
    """``PrimitiveRRT._intercept``: the index of the first sample of ``goal`` (:class:`Goal`) after
    ``t`` reachable at ``0.8 * goal.speed`` (and joinable for good where ``goal.use_tail``), else the
    last."""
    goal = _as_goal(goal)
    gt, gxy = goal.t, goal.xy
    n_goal = len(gt)
    for k in range(min(_search_left(gt, t + 1e-9), n_goal - 1), n_goal):
        reach = (gt[k] - t) * goal.speed * 0.8
        if math.hypot(gxy[k, 0] - x, gxy[k, 1] - y) <= reach and (not goal.use_tail or goal.tail_ok[k]):
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
def path_free(times, xp, fp, cons):  # pragma: no cover - compiled
    """``PrimitiveRRT._path_free``'s test: the path ``(xp, fp)`` at every time of ``times`` is
    outside every constraint of ``cons`` (``ConstraintTable.free``); ``-1`` for a NaN time (the
    caller then runs the reference), else ``1``/``0``."""
    cons = _as_cons(cons)
    for m in range(len(times)):
        t = times[m]
        if t != t:
            return -1
        if not _free1(_interp1(t, xp, fp, 0), _interp1(t, xp, fp, 1), t, cons):
            return 0
    return 1


@_jit
def _junction_free(x, y, k, dep, goal, cons):  # pragma: no cover - compiled
    """The straight junction from ``(x, y)`` at ``dep`` to sample ``k`` of ``goal`` respects ``cons``
    at the fractions ``goal.junction``: ``1``/``0``, ``-1`` when a junction time is NaN."""
    gx = goal.xy[k, 0] - x
    gy = goal.xy[k, 1] - y
    gtk = goal.t[k] - dep
    for q in range(len(goal.junction)):
        s = goal.junction[q]
        jt = dep + s * gtk
        if jt != jt:
            return -1
        if not _free1(x + s * gx, y + s * gy, jt, cons):
            return 0
    return 1


@_jit
def join(x, y, t, th, goal, cons):  # pragma: no cover - compiled
    """``PrimitiveRRT._join``: of the first ``goal.n_try`` samples of ``goal`` (:class:`Goal`) the
    robot may join (:func:`join_candidates`), the first whose wait at ``(x, y)`` from ``t`` until the
    departure and straight junction (points at fractions ``goal.junction``) respect the constraints
    ``cons``. Returns ``(k, depart)``, ``k = -1`` for none; ``k = -2`` when a junction time is NaN
    (the caller then runs the reference)."""
    goal = _as_goal(goal)
    cons = _as_cons(cons)
    out_k = np.empty(goal.n_try, dtype=np.int64)
    out_dep = np.empty(goal.n_try)
    count = join_candidates(x, y, t, th, goal, out_k, out_dep)
    for c in range(count):
        k = out_k[c]
        dep = out_dep[c]
        if not cons.has:
            return k, dep
        if not _still_free(x, y, t, dep, cons):
            continue
        free = _junction_free(x, y, k, dep, goal, cons)
        if free < 0:
            return -2, dep
        if free:
            return k, dep
    return -1, 0.0


__all__ = [
    "Batch", "Branch", "Buffer", "Cons", "Field", "Goal", "Prims", "Search", "Tail", "Tree", "build_path",
    "candidates", "clearance_xy", "constraint_free", "constraint_still_free", "explore_add", "explore_batch",
    "intercept", "interp_xy", "join", "join_candidates", "near_goal", "path_free", "plain",
]
