"""The lidar: rays from every robot against the static map and the moving discs, compiled with numba.

One kernel serves a single :class:`~swarm_env.env.SwarmEnv` and the batched engine
(:mod:`swarm_env.vector`) alike, so both give the same bits: a scan is computed robot by robot,
and a robot's rays never see another world's geometry. Worlds are packed into flat arrays
(:class:`PackedMaps`, :func:`pack_discs`) with a start index per world.

Why numba and not numpy: every robot's rays share one origin, so the geometry that can matter
to a robot (within ``max_range`` of it) is found once per robot and only those primitives are
tested against its rays. The cost per robot then stays flat as the team grows (numpy's
all-rays-against-all-discs matmul grows with N^2: its slope was 2.5 from 32 to 64 followers),
and there are no large temporaries. Measured with ``python benchmarks/lidar_bench.py``.

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

import numba
import numpy as np

from swarm_env.geometry import StaticMap


@dataclass(frozen=True)
class PackedMaps:
    """The static maps of several worlds in flat arrays; world ``w``'s rows of ``segments`` are
    ``seg_start[w]:seg_start[w + 1]``, and the same for ``circles`` and the polygon arrays.

    ``segments`` ``(S, 4)`` edges and walls; ``circles`` ``(K, 3)``; ``poly_normals`` ``(P, Mmax, 2)``
    and ``poly_offsets`` ``(P, Mmax)`` (a point is inside polygon ``p`` iff every
    ``normal . point - offset < 0``; padded as in :class:`~swarm_env.geometry.StaticMap`);
    ``poly_bound`` ``(P, 3)`` a disc around each polygon (screens the inside test).
    """

    seg_start: np.ndarray
    segments: np.ndarray
    circ_start: np.ndarray
    circles: np.ndarray
    poly_start: np.ndarray
    poly_normals: np.ndarray
    poly_offsets: np.ndarray
    poly_bound: np.ndarray

    @classmethod
    def of(cls, maps: Sequence[StaticMap]) -> PackedMaps:
        """Pack ``maps`` (one per world, in world order; a map may repeat)."""
        mmax = max(m.poly_normals.shape[1] for m in maps)

        def starts(counts: list[int]) -> np.ndarray:
            return np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)

        def joined(arrays: list[np.ndarray]) -> np.ndarray:  # polygon arrays padded to Mmax columns
            out = [a if a.shape[1] == mmax else np.concatenate([a] + [a[:, -1:]] * (mmax - a.shape[1]), axis=1)
                   for a in arrays]
            return np.ascontiguousarray(np.concatenate(out))

        return cls(
            seg_start=starts([len(m.segments) for m in maps]),
            segments=np.ascontiguousarray(np.concatenate([m.segments for m in maps])),
            circ_start=starts([len(m.circles) for m in maps]),
            circles=np.ascontiguousarray(np.concatenate([m.circles for m in maps])),
            poly_start=starts([len(m.poly_counts) for m in maps]),
            poly_normals=joined([m.poly_normals for m in maps]),
            poly_offsets=joined([m.poly_offsets for m in maps]),
            poly_bound=np.ascontiguousarray(np.concatenate([m._bound[len(m.circles):] for m in maps])),
    )


def pack_discs(per_world: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """``(disc_start, discs)`` for the moving discs ``(D_w, 3)`` ``(x, y, r)`` of each world."""
    counts = [len(d) for d in per_world]
    start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    discs = np.concatenate(per_world).reshape(-1, 3) if per_world else np.zeros((0, 3))
    return start, np.ascontiguousarray(discs, dtype=np.float64)


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
              maps.poly_offsets, maps.poly_bound, _c(disc_start, i64), _c(discs, f64), out)
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


@numba.njit(cache=True, nogil=True)
def _scan(poses, world, own_disc, ray_angles, max_range, seg_start, segments, circ_start, circles, poly_start,
          poly_normals, poly_offsets, poly_bound, disc_start, discs, out):  # pragma: no cover - compiled
    n_rays = ray_angles.shape[0]
    cand_seg = np.empty(segments.shape[0], dtype=np.int64)
    cand_circ = np.empty(circles.shape[0] + discs.shape[0], dtype=np.int64)  # circles, then discs (>= K)
    for k in range(poses.shape[0]):
        w = world[k]
        ox = poses[k, 0]
        oy = poses[k, 1]
        heading = poses[k, 2]
        # Inside a polygon: every ray reports 0.
        inside = False
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
                inside = True
                break
        if inside:
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
