"""The lidar: rays from every robot against the static map and the moving discs, compiled with numba.

One kernel serves a single :class:`~swarm_env.env.SwarmEnv` and the batched engine
(:mod:`swarm_env.vector.engine`) alike, so both give the same bits: a scan is computed robot by robot,
and a robot's rays never see another world's geometry. Worlds are packed into flat arrays
(:class:`PackedMaps`, :func:`pack_discs` or :func:`pack_inputs`) with a start index per world.

Why numba and not numpy: every robot's rays share one origin, so the geometry that can matter
to a robot (within ``max_range`` of it) is found once per robot and only those primitives are
tested against its rays. The cost per robot then stays flat as the team grows (numpy's
all-rays-against-all-discs matmul grows with N^2), and there are no large temporaries
(measurements: docs/performance.md, "Cost per follower").

:func:`scan` skips a polygon's edges when its bounding disc is certainly out of range, puts each
robot's candidates in small contiguous arrays with their per-robot terms computed once, and
tests rays against circles without branches; :func:`scan_reference` keeps the previous kernel,
which tests/test_lidar_fast.py compares bit for bit.
The batched engine gathers its worlds with :func:`pack_rows` (one compiled loop over its stacked
per-world arrays, :data:`LidarRows`) instead of one ``moving_discs`` array per world.

Semantics (per ray, distance from the origin along the unit direction, clipped to
``max_range``; ``max_range`` where nothing is hit):

* a segment (obstacle edge or wall) is hit where the ray crosses it at ``t >= 0``; a ray
  parallel to a segment does not hit it (its neighbouring edges are hit instead);
* a circle or disc ahead of the origin is hit at its first crossing; a ray starting inside a
  circle, disc or polygon reports 0, except for the robot's own disc, which is ignored.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from swarm_env.geometry.static_map import StaticMap
from swarm_env.kernel_cache import njit

#: What the lidar needs of a world besides its static map (:func:`swarm_env.sensing.observations.lidar_input`):
#: follower poses ``(N, 3)`` and radii ``(N,)``, human positions ``(H, 2)`` and radii ``(H,)``, and the leader's
#: disc ``(x, y, r)`` if the leader is a robot (else ``None``). References to the state's own arrays: no copy.
LidarInput = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, "tuple[float, float, float] | None"]


@dataclass(frozen=True)
class PackedMaps:
    """The static maps of several worlds in flat arrays; world ``w``'s rows of ``segments`` are
    ``seg_start[w]:seg_start[w + 1]``, and the same for ``circles`` and the polygon arrays.

    ``segments`` ``(S, 4)`` edges and walls; ``circles`` ``(K, 3)``; ``poly_normals`` ``(P, Mmax, 2)``
    and ``poly_offsets`` ``(P, Mmax)`` (a point is inside polygon ``p`` iff every
    ``normal . point - offset < 0``; padded as in :class:`~swarm_env.geometry.static_map.StaticMap`);
    ``poly_bound`` ``(P, 3)`` a disc around each polygon (screens the inside test and, with a
    margin, the polygon's edges); ``poly_edges`` ``(P, 2)`` the rows ``[first, stop)`` of ``segments``
    that are polygon ``p``'s edges; ``wall_start`` ``(W,)`` the first of world ``w``'s walls (its rows
    of ``segments`` are its polygons' edges, polygon by polygon, then its walls up to
    ``seg_start[w + 1]``).
    """

    seg_start: np.ndarray
    segments: np.ndarray
    circ_start: np.ndarray
    circles: np.ndarray
    poly_start: np.ndarray
    poly_normals: np.ndarray
    poly_offsets: np.ndarray
    poly_bound: np.ndarray
    poly_edges: np.ndarray
    wall_start: np.ndarray
    #: ``(W,)`` each world's own polygon columns (``Mmax`` is their maximum; :meth:`replaced` needs them).
    widths: np.ndarray | None = None

    @classmethod
    def of(cls, maps: Sequence[StaticMap]) -> PackedMaps:
        """Pack ``maps`` (one per world, in world order; a map may repeat)."""
        widths = np.fromiter((m.poly_normals.shape[1] for m in maps), dtype=np.int64, count=len(maps))
        mmax = int(widths.max())

        def starts(counts: list[int]) -> np.ndarray:
            return np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)

        def joined(arrays: list[np.ndarray]) -> np.ndarray:  # polygon arrays padded to Mmax columns
            out = [a if a.shape[1] == mmax else np.concatenate([a] + [a[:, -1:]] * (mmax - a.shape[1]), axis=1)
                   for a in arrays]
            return np.ascontiguousarray(np.concatenate(out))

        seg_start = starts([len(m.segments) for m in maps])
        edges = [seg_start[w] + starts(list(m.poly_counts)) for w, m in enumerate(maps)]  # per world (P_w + 1,)
        return cls(
            seg_start=seg_start,
            segments=np.ascontiguousarray(np.concatenate([m.segments for m in maps])),
            circ_start=starts([len(m.circles) for m in maps]),
            circles=np.ascontiguousarray(np.concatenate([m.circles for m in maps])),
            poly_start=starts([len(m.poly_counts) for m in maps]),
            poly_normals=joined([m.poly_normals for m in maps]),
            poly_offsets=joined([m.poly_offsets for m in maps]),
            poly_bound=np.ascontiguousarray(np.concatenate([m._bound[len(m.circles):] for m in maps])),
            poly_edges=np.ascontiguousarray(np.concatenate([np.column_stack([e[:-1], e[1:]]) for e in edges]),
                                            dtype=np.int64).reshape(-1, 2),
            wall_start=np.array([e[-1] for e in edges], dtype=np.int64),
            widths=widths,
        )

    def replaced(self, maps: Sequence[StaticMap], changed: Sequence[int]) -> PackedMaps:
        """``PackedMaps.of(maps)`` (the same arrays) for ``maps`` that differ from the ones packed here
        only at the worlds ``changed``: the other worlds' rows are copied as blocks and only the changed
        worlds are packed, so a step in which a few of ``M`` worlds start a new episode (with a new map)
        costs a few memory copies rather than a repacking of ``M`` maps (``of`` spends ~25 us of
        Python per map: at 1,024 worlds, where some episode ends nearly every step, that was a quarter
        of a step). Falls back to ``of`` when the column count ``Mmax`` changes."""
        m = len(self.seg_start) - 1
        changed = sorted({int(w) for w in changed})
        if not changed:
            return self
        if self.widths is None or len(maps) != m:
            return PackedMaps.of(maps)
        widths = self.widths.copy()
        for w in changed:
            widths[w] = maps[w].poly_normals.shape[1]
        mmax = self.poly_normals.shape[1]
        if int(widths.max()) != mmax:
            return PackedMaps.of(maps)
        new = {w: PackedMaps.of([maps[w]]) for w in changed}  # each changed world alone, world-relative indices

        def padded(a: np.ndarray) -> np.ndarray:  # (as `of` pads: the last column repeated)
            return a if a.shape[1] == mmax else np.concatenate([a] + [a[:, -1:]] * (mmax - a.shape[1]), axis=1)

        def spliced(old: np.ndarray, start: np.ndarray, pieces: dict[int, np.ndarray]) -> np.ndarray:
            parts = []
            at = 0
            for w in changed:
                parts.append(old[start[at]:start[w]])  # the unchanged worlds at..w-1, as one block
                parts.append(pieces[w])
                at = w + 1
            parts.append(old[start[at]:])
            return np.ascontiguousarray(np.concatenate(parts))

        def counts(start: np.ndarray, key: str) -> np.ndarray:
            out = np.diff(start)
            for w in changed:
                out[w] = len(getattr(new[w], key)) if key != "poly_start" else len(new[w].poly_bound)
            return np.concatenate([[0], np.cumsum(out)]).astype(np.int64)

        seg_start = counts(self.seg_start, "segments")
        poly_start = counts(self.poly_start, "poly_start")
        # polygon edges and walls relative to their world's first segment, then placed anew
        old_world = np.repeat(np.arange(m), np.diff(self.poly_start))
        rel_edges = self.poly_edges - self.seg_start[old_world][:, None]
        rel_edges = spliced(rel_edges, self.poly_start, {w: p.poly_edges for w, p in new.items()})
        new_world = np.repeat(np.arange(m), np.diff(poly_start))
        rel_walls = self.wall_start - self.seg_start[:-1]
        for w, p in new.items():
            rel_walls[w] = p.wall_start[0]
        return PackedMaps(
            seg_start=seg_start,
            segments=spliced(self.segments, self.seg_start, {w: p.segments for w, p in new.items()}),
            circ_start=counts(self.circ_start, "circles"),
            circles=spliced(self.circles, self.circ_start, {w: p.circles for w, p in new.items()}),
            poly_start=poly_start,
            poly_normals=spliced(self.poly_normals, self.poly_start,
                                 {w: padded(p.poly_normals) for w, p in new.items()}),
            poly_offsets=spliced(self.poly_offsets, self.poly_start,
                                 {w: padded(p.poly_offsets) for w, p in new.items()}),
            poly_bound=spliced(self.poly_bound, self.poly_start, {w: p.poly_bound for w, p in new.items()}),
            poly_edges=np.ascontiguousarray(rel_edges + seg_start[new_world][:, None], dtype=np.int64).reshape(-1, 2),
            wall_start=rel_walls + seg_start[:-1],
            widths=widths,
        )


def pack_discs(per_world: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """``(disc_start, discs)`` for the moving discs ``(D_w, 3)`` ``(x, y, r)`` of each world."""
    counts = [len(d) for d in per_world]
    start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    discs = np.concatenate(per_world).reshape(-1, 3) if per_world else np.zeros((0, 3))
    return start, np.ascontiguousarray(discs, dtype=np.float64)


#: :func:`pack_rows`' input, the moving bodies of ``M`` worlds in flat arrays: follower poses ``(Q, 3)``
#: and radii ``(Q,)`` (world after world), human positions ``(Hq, 2)`` and radii ``(Hq,)``, followers and
#: humans per world ``(M,)`` int64 each, and each world's leader disc ``(M, 3)`` ``(x, y, r)``, ``r`` NaN
#: for a virtual leader (no disc). :func:`flat_inputs` builds it from :func:`~swarm_env.sensing.observations.lidar_input`
#: tuples; the batched engine builds it from its stacked per-world arrays (no per-world tuples).
LidarRows = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def flat_inputs(inputs: Sequence[LidarInput]) -> LidarRows:
    """The :data:`LidarRows` of the worlds ``inputs`` (:func:`swarm_env.sensing.observations.lidar_input`
    tuples, world ``w`` = ``inputs[w]``): a few concatenations over all worlds."""
    m = len(inputs)
    if m == 1:  # one env's step: no lists to join
        poses, radii, humans, human_radii, _ = inputs[0]
    else:
        poses = np.concatenate([x[0] for x in inputs])
        radii = np.concatenate([x[1] for x in inputs])
        humans = np.concatenate([x[2] for x in inputs])
        human_radii = np.concatenate([x[3] for x in inputs])
    n_fol = np.fromiter([len(x[1]) for x in inputs], dtype=np.int64, count=m)
    n_hum = np.fromiter([len(x[3]) for x in inputs], dtype=np.int64, count=m)
    leaders = np.full((m, 3), np.nan)  # NaN radius: a virtual leader (no disc)
    for w, x in enumerate(inputs):
        if x[4] is not None:
            leaders[w] = x[4]
    return poses, radii, humans, human_radii, n_fol, n_hum, leaders


def join_rows(parts: Sequence[LidarRows]) -> LidarRows:
    """The :data:`LidarRows` of several groups of worlds, one group after the other."""
    if len(parts) == 1:
        return parts[0]
    return tuple(np.concatenate([p[k] for p in parts]) for k in range(7))  # type: ignore[return-value]


def pack_inputs(
    inputs: Sequence[LidarInput],
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`scan`'s ``(poses, world, own_disc, disc_start, discs)`` for the worlds ``inputs``
    (:func:`swarm_env.sensing.observations.lidar_input` tuples, world ``w`` = ``inputs[w]``), in one pass:
    a few concatenations over all worlds (:func:`flat_inputs`), then one compiled loop that lays out
    each world's discs as :func:`swarm_env.sensing.observations.moving_discs` does (followers, a robot leader,
    humans): :func:`pack_rows`."""
    return pack_rows(flat_inputs(inputs))


def pack_rows(rows: LidarRows) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`pack_inputs` of worlds given as :data:`LidarRows`."""
    poses, radii, humans, human_radii, n_fol, n_hum, leaders = rows
    m = len(n_fol)
    q = int(n_fol.sum())
    world = np.empty(q, dtype=np.int64)
    own = np.empty(q, dtype=np.int64)
    disc_start = np.empty(m + 1, dtype=np.int64)
    discs = np.empty((q + int(n_hum.sum()) + m - int(np.isnan(leaders[:, 2]).sum()), 3))
    poses = _c(poses, np.float64).reshape(-1, 3)
    _pack(poses, _c(radii, np.float64).reshape(-1), _c(humans, np.float64).reshape(-1, 2),
          _c(human_radii, np.float64).reshape(-1), _c(n_fol, np.int64), _c(n_hum, np.int64),
          _c(leaders, np.float64), world, own, disc_start, discs)
    return poses, world, own, disc_start, discs


@njit(nogil=True)
def _pack(poses, radii, humans, human_radii, n_fol, n_hum, leaders, world, own, disc_start,
          discs):  # pragma: no cover - compiled
    q = 0
    h = 0
    d = 0
    for w in range(n_fol.shape[0]):
        disc_start[w] = d
        for i in range(n_fol[w]):
            world[q] = w
            own[q] = i  # followers come first among a world's discs
            discs[d, 0] = poses[q, 0]
            discs[d, 1] = poses[q, 1]
            discs[d, 2] = radii[q]
            q += 1
            d += 1
        if not np.isnan(leaders[w, 2]):
            discs[d, 0] = leaders[w, 0]
            discs[d, 1] = leaders[w, 1]
            discs[d, 2] = leaders[w, 2]
            d += 1
        for _i in range(n_hum[w]):
            discs[d, 0] = humans[h, 0]
            discs[d, 1] = humans[h, 1]
            discs[d, 2] = human_radii[h]
            h += 1
            d += 1
    disc_start[n_fol.shape[0]] = d


def scan(
    poses: np.ndarray,
    world: np.ndarray,
    own_disc: np.ndarray,
    ray_angles: np.ndarray,
    max_range: float,
    maps: PackedMaps,
    disc_start: np.ndarray,
    discs: np.ndarray,
) -> np.ndarray:
    """Lidar distances ``(Q, R)`` of ``Q`` robots.

    ``poses`` ``(Q, 3)`` ``(x, y, heading)``; ``world`` ``(Q,)`` each robot's world index into
    ``maps`` and ``disc_start``; ``own_disc`` ``(Q,)`` the robot's own disc as an index *within
    its world's discs* (``-1``: none); ``ray_angles`` ``(R,)`` ray directions relative to the
    heading. See the module docstring for what a ray hits.
    """
    q = len(poses)
    out = np.empty((q, len(ray_angles)))
    if q:
        f64, i64 = np.float64, np.int64
        _scan(_c(poses, f64), _c(world, i64), _c(own_disc, i64), _c(ray_angles, f64), float(max_range),
              maps.seg_start, maps.segments, maps.circ_start, maps.circles, maps.poly_start, maps.poly_normals,
              maps.poly_offsets, maps.poly_bound, maps.poly_edges, maps.wall_start, _c(disc_start, i64),
              _c(discs, f64), out)
    return out


def scan_reference(
    poses: np.ndarray,
    world: np.ndarray,
    own_disc: np.ndarray,
    ray_angles: np.ndarray,
    max_range: float,
    maps: PackedMaps,
    disc_start: np.ndarray,
    discs: np.ndarray,
) -> np.ndarray:
    """:func:`scan` by the plain kernel it replaced: every primitive of the robot's world within
    ``max_range`` is tested against every ray, with no further culling. The same bits as
    :func:`scan` (tests/test_lidar_fast.py checks it); kept as the reference and the benchmarks'
    "before"."""
    q = len(poses)
    out = np.empty((q, len(ray_angles)))
    if q:
        f64, i64 = np.float64, np.int64
        _scan_reference(_c(poses, f64), _c(world, i64), _c(own_disc, i64), _c(ray_angles, f64), float(max_range),
                        maps.seg_start, maps.segments, maps.circ_start, maps.circles, maps.poly_start,
                        maps.poly_normals, maps.poly_offsets, maps.poly_bound, _c(disc_start, i64), _c(discs, f64),
                        out)
    return out


def _c(a: np.ndarray, dtype: type) -> np.ndarray:
    """``a`` as a C-contiguous array of ``dtype`` (itself when it already is: the common case)."""
    if type(a) is np.ndarray and a.dtype == dtype and a.flags.c_contiguous:
        return a
    return np.ascontiguousarray(a, dtype=dtype)


def cast_rays(
    origins: np.ndarray,
    angles: np.ndarray,
    max_range: float,
    static: StaticMap,
    discs: np.ndarray | None = None,
    exclude: np.ndarray | None = None,
) -> np.ndarray:
    """``(R,)`` distances of single rays in one world: ``origins`` ``(R, 2)``, world-frame
    ``angles`` ``(R,)``, moving ``discs`` ``(D, 3)``, and ``exclude`` ``(R,)`` the disc each ray
    ignores (``-1``: none). The same kernel as :func:`scan`, one ray per "robot"."""
    o = np.asarray(origins, dtype=np.float64).reshape(-1, 2)
    poses = np.column_stack([o, np.asarray(angles, dtype=np.float64).reshape(-1)])
    d = np.zeros((0, 3)) if discs is None else np.asarray(discs, dtype=np.float64).reshape(-1, 3)
    own = np.full(len(o), -1) if exclude is None else np.asarray(exclude)
    disc_start, packed = pack_discs([d])
    return scan(poses, np.zeros(len(o), dtype=np.int64), own, np.zeros(1), max_range, PackedMaps.of([static]),
                disc_start, packed)[:, 0]


@njit(nogil=True, inline="always")
def _inside_polygon(ox, oy, w, poly_start, poly_normals, poly_offsets, poly_bound):  # pragma: no cover - compiled
    """Whether ``(ox, oy)`` lies strictly inside one of world ``w``'s polygons (both kernels: a lidar
    there reports 0 on every ray)."""
    for p in range(poly_start[w], poly_start[w + 1]):
        bx = ox - poly_bound[p, 0]
        by = oy - poly_bound[p, 1]
        if bx * bx + by * by > poly_bound[p, 2] * poly_bound[p, 2]:
            continue
        worst = -np.inf
        for m in range(poly_normals.shape[1]):
            h = poly_normals[p, m, 0] * ox + poly_normals[p, m, 1] * oy - poly_offsets[p, m]
            if h > worst:
                worst = h
        if worst < 0.0:
            return True
    return False


@njit(nogil=True)
def _scan(poses, world, own_disc, ray_angles, max_range, seg_start, segments, circ_start, circles, poly_start,
          poly_normals, poly_offsets, poly_bound, poly_edges, wall_start, disc_start, discs,
          out):  # pragma: no cover - compiled
    # The same tests with the same arithmetic as _scan_reference, so the same bits; faster by
    # (1) skipping a polygon's edges when its bounding disc is out of range (a margin far above
    # rounding keeps the skip conservative: the edges skipped are exactly those the reference's
    # exact closest-point test rejects), (2) copying each robot's candidate primitives into small
    # contiguous arrays with the per-robot parts of the ray tests computed once (each ray
    # recomputed them before: same operations, same operands, so the same values), and (3) a
    # circle test without branches (the reference's two early exits mispredicted about half the
    # time). The minimum over primitives is exact, so their order does not matter.
    n_rays = ray_angles.shape[0]
    max_seg = 0
    max_circ = 0
    for w in range(seg_start.shape[0] - 1):
        max_seg = max(max_seg, seg_start[w + 1] - seg_start[w])
        max_circ = max(max_circ, circ_start[w + 1] - circ_start[w] + disc_start[w + 1] - disc_start[w])
    s_wx = np.empty(max_seg)  # per candidate segment: a - o, e = b - a, and (a - o) x e
    s_wy = np.empty(max_seg)
    s_ex = np.empty(max_seg)
    s_ey = np.empty(max_seg)
    s_nt = np.empty(max_seg)
    c_vx = np.empty(max_circ)  # per candidate circle or disc: centre - o and |centre - o|^2 - r^2
    c_vy = np.empty(max_circ)
    c_cc = np.empty(max_circ)
    r2 = max_range * max_range
    for k in range(poses.shape[0]):
        w = world[k]
        ox = poses[k, 0]
        oy = poses[k, 1]
        heading = poses[k, 2]
        if _inside_polygon(ox, oy, w, poly_start, poly_normals, poly_offsets, poly_bound):  # every ray reports 0
            for r in range(n_rays):
                out[k, r] = 0.0
            continue
        # The segments within max_range of the origin: the reference's exact test, on the walls
        # and on the edges of the polygons whose bounding disc is not certainly out of range.
        ns = 0
        slack = 1e-6 * (1.0 + max_range + abs(ox) + abs(oy))
        for p in range(poly_start[w], poly_start[w + 1] + 1):
            if p < poly_start[w + 1]:
                bx = ox - poly_bound[p, 0]
                by = oy - poly_bound[p, 1]
                reach = max_range + poly_bound[p, 2] * (1.0 + 1e-9) + slack
                if bx * bx + by * by > reach * reach:
                    continue
                first = poly_edges[p, 0]
                stop = poly_edges[p, 1]
            else:  # the walls
                first = wall_start[w]
                stop = seg_start[w + 1]
            for s in range(first, stop):
                ax = segments[s, 0]
                ay = segments[s, 1]
                ex = segments[s, 2] - ax
                ey = segments[s, 3] - ay
                ee = ex * ex + ey * ey
                t = 0.0
                if ee > 0.0:
                    t = ((ox - ax) * ex + (oy - ay) * ey) / ee
                    t = min(max(t, 0.0), 1.0)
                fx = ax + t * ex - ox
                fy = ay + t * ey - oy
                if fx * fx + fy * fy < r2:
                    wx = ax - ox
                    wy = ay - oy
                    s_wx[ns] = wx
                    s_wy[ns] = wy
                    s_ex[ns] = ex
                    s_ey[ns] = ey
                    s_nt[ns] = wx * ey - wy * ex
                    ns += 1
        nc = 0
        zero = False  # the origin is inside a circle or another disc: every ray reports 0
        k0 = circ_start[w]
        n_circ = circ_start[w + 1] - k0
        d0 = disc_start[w]
        n_disc = disc_start[w + 1] - d0
        for c in range(n_circ + n_disc):
            if c < n_circ:
                cx = circles[k0 + c, 0]
                cy = circles[k0 + c, 1]
                cr = circles[k0 + c, 2]
            else:
                if c - n_circ == own_disc[k]:
                    continue
                cx = discs[d0 + c - n_circ, 0]
                cy = discs[d0 + c - n_circ, 1]
                cr = discs[d0 + c - n_circ, 2]
            vx = cx - ox
            vy = cy - oy
            cc = vx * vx + vy * vy - cr * cr
            if cc <= 0.0:
                zero = True
                break
            reach = max_range + cr
            if vx * vx + vy * vy < reach * reach:
                c_vx[nc] = vx
                c_vy[nc] = vy
                c_cc[nc] = cc
                nc += 1
        if zero:
            for r in range(n_rays):
                out[k, r] = 0.0
            continue
        for r in range(n_rays):
            ang = heading + ray_angles[r]
            dx = math.cos(ang)
            dy = math.sin(ang)
            best = max_range
            for j in range(ns):
                ex = s_ex[j]
                ey = s_ey[j]
                den = dx * ey - dy * ex  # d x e
                if den == 0.0:
                    continue  # parallel
                t = s_nt[j] / den
                u = (s_wx[j] * dy - s_wy[j] * dx) / den
                if t >= 0.0 and u >= 0.0 and u <= 1.0 and t < best:
                    best = t
            for j in range(nc):
                b = c_vx[j] * dx + c_vy[j] * dy
                disc = b * b - c_cc[j]
                # A hit where b > 0 (ahead; the origin is outside) and disc >= 0, at b - sqrt(disc):
                # max(disc, 0) only keeps the square root of a miss finite.
                t = b - math.sqrt(max(disc, 0.0))
                best = t if (b > 0.0) & (disc >= 0.0) & (t < best) else best
            out[k, r] = best


@njit(nogil=True)
def _scan_reference(poses, world, own_disc, ray_angles, max_range, seg_start, segments, circ_start, circles, poly_start,
          poly_normals, poly_offsets, poly_bound, disc_start, discs, out):  # pragma: no cover - compiled
    # The kernel before the faster one (issue 11), kept (sharing only _inside_polygon) as the reference its results are
    # compared with bit for bit (tests/test_lidar_fast.py) and timed against (benchmarks/lidar_fast.py).
    n_rays = ray_angles.shape[0]
    cand_seg = np.empty(segments.shape[0], dtype=np.int64)
    cand_circ = np.empty(circles.shape[0] + discs.shape[0], dtype=np.int64)  # circles, then discs (>= K)
    for k in range(poses.shape[0]):
        w = world[k]
        ox = poses[k, 0]
        oy = poses[k, 1]
        heading = poses[k, 2]
        if _inside_polygon(ox, oy, w, poly_start, poly_normals, poly_offsets, poly_bound):  # every ray reports 0
            for r in range(n_rays):
                out[k, r] = 0.0
            continue
        # The primitives within max_range of the origin (the rest cannot bring a ray below it).
        ns = 0
        for s in range(seg_start[w], seg_start[w + 1]):
            ax = segments[s, 0]
            ay = segments[s, 1]
            ex = segments[s, 2] - ax
            ey = segments[s, 3] - ay
            ee = ex * ex + ey * ey
            t = 0.0
            if ee > 0.0:
                t = ((ox - ax) * ex + (oy - ay) * ey) / ee
                t = min(max(t, 0.0), 1.0)
            fx = ax + t * ex - ox
            fy = ay + t * ey - oy
            if fx * fx + fy * fy < max_range * max_range:
                cand_seg[ns] = s
                ns += 1
        nc = 0
        zero = False  # the origin is inside a circle or another disc: every ray reports 0
        k0 = circ_start[w]
        n_circ = circ_start[w + 1] - k0
        d0 = disc_start[w]
        n_disc = disc_start[w + 1] - d0
        for c in range(n_circ + n_disc):
            if c < n_circ:
                cx = circles[k0 + c, 0]
                cy = circles[k0 + c, 1]
                cr = circles[k0 + c, 2]
            else:
                if c - n_circ == own_disc[k]:
                    continue
                cx = discs[d0 + c - n_circ, 0]
                cy = discs[d0 + c - n_circ, 1]
                cr = discs[d0 + c - n_circ, 2]
            vx = cx - ox
            vy = cy - oy
            cc = vx * vx + vy * vy - cr * cr
            if cc <= 0.0:
                zero = True
                break
            reach = max_range + cr
            if vx * vx + vy * vy < reach * reach:
                cand_circ[nc] = c
                nc += 1
        if zero:
            for r in range(n_rays):
                out[k, r] = 0.0
            continue
        for r in range(n_rays):
            ang = heading + ray_angles[r]
            dx = math.cos(ang)
            dy = math.sin(ang)
            best = max_range
            for j in range(ns):
                s = cand_seg[j]
                ax = segments[s, 0]
                ay = segments[s, 1]
                ex = segments[s, 2] - ax
                ey = segments[s, 3] - ay
                den = dx * ey - dy * ex  # d x e
                if den == 0.0:
                    continue  # parallel
                wx = ax - ox
                wy = ay - oy
                t = (wx * ey - wy * ex) / den
                u = (wx * dy - wy * dx) / den
                if t >= 0.0 and u >= 0.0 and u <= 1.0 and t < best:
                    best = t
            for j in range(nc):
                c = cand_circ[j]
                if c < n_circ:
                    cx = circles[k0 + c, 0]
                    cy = circles[k0 + c, 1]
                    cr = circles[k0 + c, 2]
                else:
                    cx = discs[d0 + c - n_circ, 0]
                    cy = discs[d0 + c - n_circ, 1]
                    cr = discs[d0 + c - n_circ, 2]
                vx = cx - ox
                vy = cy - oy
                b = vx * dx + vy * dy
                if b <= 0.0:
                    continue  # behind the origin (which is outside the circle)
                disc = b * b - (vx * vx + vy * vy - cr * cr)
                if disc < 0.0:
                    continue
                t = b - math.sqrt(disc)
                if t < best:
                    best = t
            out[k, r] = best
