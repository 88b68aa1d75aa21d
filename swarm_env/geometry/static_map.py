"""Static geometry: obstacles and walls as numpy arrays, signed clearance and
projection to free space (the lidar is :mod:`swarm_env.sensing.lidar`).

Everything here is pure numpy (no pymunk, no pygame) and float64. Units are
metres and radians (rectangle ``angle`` in degrees, as in scenario files). The
world is the rectangle ``[0, W] x [0, H]`` closed by four walls, indexed in the
order of :data:`WALL_NAMES`.

Conventions shared by all functions:

* *Clearance* (signed distance) of a point is its Euclidean distance to the
  nearest obstacle surface or wall, positive in free space and negative inside
  an obstacle or outside the world rectangle. Inside a single obstacle its
  magnitude is the penetration depth; where obstacles overlap the minimum over
  obstacles is taken (exact outside obstacles, a lower bound of the depth
  inside an overlap).
* Polygons (rectangles included) are convex and stored counter-clockwise.
  :class:`StaticMap` keeps them padded to ``(P, Mmax)`` by repeating each
  polygon's last edge: a repeated edge changes neither a minimum distance nor
  a half-plane test, so no masks are needed in the hot loops.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from swarm_env.compiled import compiled_kernels
from swarm_env.geometry.map_arrays import MapArrays
from swarm_env.scenario import CircleObstacle, Obstacle, PolygonObstacle, RectangleObstacle

WALL_NAMES = ("bottom", "right", "top", "left")  # wall index order 0..3

#: ``ids`` value of :meth:`StaticMap.nearest_obstacles` for walls: wall ``w`` has id ``WALL_ID0 - w``
#: (-1 bottom, -2 right, -3 top, -4 left).
WALL_ID0 = -1
#: ``ids`` value of :meth:`StaticMap.nearest_obstacles` when there is no surface at all.
NO_SURFACE = -5

# project_free() builds its candidates this far beyond the requested clearance, so
# that is_free(result, clearance) holds despite rounding (coordinates are O(100) m,
# rounding errors O(1e-13) m).
_PUSH_EPS = 1e-9
# Relative tolerance of convex_ccw()'s convexity test (sine of the turn angle).
_CONVEX_TOL = 1e-9
# At most this many clearances keep a cached candidate set in project_free().
_CACHE_SIZE = 16
# project_free() checks the feet of a point on the free set's boundary nearest-first, this many at a time.
_FEET_CHUNK = 4
# project_free()'s fast path (see StaticMap._project_fast): a point farther than this beyond
# ``clearance`` from an obstacle's bounding disc (or from the walls) is certainly free of it,
# and the certificate that no other obstacle can hold a nearer candidate keeps this margin.
# Both only need to dominate rounding (coordinates O(100) m, errors O(1e-13) m).
_SCREEN_MARGIN = 1e-7
# project_free() screens points one by one in Python when at most this many are suspect
# (the usual handful of formation slots); larger batches go straight to the vectorised search.
_FAST_MAX_POINTS = 32
# project_free() remembers this many recent small queries (formation slots) by their exact
# bits: a fixed scenario with a virtual leader replays the same slot targets every episode.
_MEMO_SIZE = 2048
# Elements per (edges, points) temporary in distance(): 12288 float64 = 96 KiB, under glibc's
# default 128 KiB mmap threshold.
_BLOCK_ELEMS = 12288


# ----------------------------------------------------------------------------------------------
# Polygon helpers
# ----------------------------------------------------------------------------------------------


def rotate_rectangle(
    center: Sequence[float], size: Sequence[float], angle_deg: float
) -> np.ndarray:
    """Corners of a ``size = (width, height)`` rectangle centred on ``center`` and rotated
    counter-clockwise by ``angle_deg`` degrees about its centre.

    Returns ``(4, 2)`` float64 corners in counter-clockwise order, starting from the
    corner that is bottom-left before rotation. Raises ``ValueError`` for a
    non-positive or non-finite size.
    """
    w, h = (float(v) for v in size)
    if not (math.isfinite(w) and math.isfinite(h) and w > 0.0 and h > 0.0):
        raise ValueError(f"rectangle size must be two positive numbers, got {tuple(size)!r}")
    a = math.radians(float(angle_deg))
    c, s = math.cos(a), math.sin(a)
    local = np.array([[-w, -h], [w, -h], [w, h], [-w, h]], dtype=np.float64) * 0.5
    rot = np.array([[c, -s], [s, c]], dtype=np.float64)
    return local @ rot.T + np.asarray(center, dtype=np.float64)


def _next(a: np.ndarray) -> np.ndarray:
    """``np.roll(a, -1, axis=0)`` (row ``i`` holds row ``i + 1``, the last the first) without np.roll's
    overhead, which dominated building the small polygons of a random map."""
    return np.concatenate((a[1:], a[:1]))


def _prev(a: np.ndarray) -> np.ndarray:
    """``np.roll(a, 1, axis=0)``: row ``i`` holds row ``i - 1``, the first the last."""
    return np.concatenate((a[-1:], a[:-1]))


def convex_ccw(points: Sequence[Sequence[float]] | np.ndarray) -> np.ndarray:
    """Validate a convex polygon and return its vertices counter-clockwise.

    ``points``: ``(M, 2)`` vertices in either winding order, ``M >= 3``. Consecutive
    repeated vertices (including last == first, a closed ring) are dropped;
    collinear vertices are kept. Raises ``ValueError`` (with the reason) when the
    input is not ``(M, 2)`` finite numbers, has fewer than 3 distinct vertices,
    has zero area, is not convex, or winds around more than once.
    Returns a new ``(M', 2)`` float64 array.
    """
    try:
        pts = np.array(points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"polygon points must be (x, y) number pairs: {exc}") from None
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise ValueError(f"polygon points must have shape (M, 2), got {pts.shape}")
    if not np.all(np.isfinite(pts)):
        raise ValueError("polygon points must be finite")
    if len(pts):
        scale = max(float(np.ptp(pts, axis=0).max()), 1e-300)
        keep = np.linalg.norm(pts - _prev(pts), axis=1) > 1e-12 * scale
        if len(pts) > 1:
            pts = pts[keep]
    if len(pts) < 3:
        raise ValueError(f"a polygon needs at least 3 distinct vertices, got {len(pts)}")
    x, y = pts[:, 0], pts[:, 1]
    area2 = float(np.dot(x, _next(y)) - np.dot(_next(x), y))
    scale = float(np.ptp(pts, axis=0).max())
    if abs(area2) <= 1e-12 * scale * scale:
        # Zero signed area: either every vertex is on one line, or the boundary crosses itself
        # so that its lobes cancel (a bow tie).
        rel = pts - pts[0]
        spread = np.abs(rel[:, 0, None] * rel[None, :, 1] - rel[:, 1, None] * rel[None, :, 0]).max()
        if spread <= 1e-12 * scale * scale:
            raise ValueError("polygon has zero area (all vertices collinear)")
        raise ValueError("polygon is self-intersecting (its boundary crosses itself, so its signed area is zero)")
    if area2 < 0.0:
        pts = pts[::-1].copy()
    e = _next(pts) - pts  # edge i goes from vertex i to vertex i+1
    e_next = _next(e)
    cross = e[:, 0] * e_next[:, 1] - e[:, 1] * e_next[:, 0]
    dot = np.einsum("ij,ij->i", e, e_next)
    lengths = np.linalg.norm(e, axis=1) * np.linalg.norm(e_next, axis=1)
    if np.any(cross < -_CONVEX_TOL * lengths):
        bad = int(np.argmax(cross < -_CONVEX_TOL * lengths))
        raise ValueError(f"polygon is not convex (reflex turn at vertex {(bad + 1) % len(pts)})")
    turning = float(np.sum(np.arctan2(cross, dot)))
    if abs(turning - 2.0 * math.pi) > 1e-6:
        raise ValueError("polygon is not simple (its boundary winds around more than once)")
    return pts


# ----------------------------------------------------------------------------------------------
# StaticMap
# ----------------------------------------------------------------------------------------------


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class StaticMap:
    """Static geometry of a scenario: obstacles and the 4 walls of ``[0,W]x[0,H]``, as numpy arrays.

    Build it with :meth:`from_obstacles`. Public fields (read-only arrays):

    * ``size``: ``(W, H)`` metres.
    * ``circles``: ``(K, 3)`` ``cx, cy, r`` of the circle obstacles; ``circle_ids``: ``(K,)``
      index of each in ``scenario.obstacles``.
    * ``polygons``: ``P`` arrays ``(M_i, 2)``, convex, counter-clockwise (rectangles and
      polygons); ``polygon_ids``: ``(P,)`` index of each in ``scenario.obstacles``.
    * ``segments``: ``(S, 4)`` ``x0, y0, x1, y1``: all polygon edges (polygon by polygon,
      edge ``i`` from vertex ``i`` to ``i+1``), then the 4 walls (bottom, right, top, left).

    Derived padded arrays (``P, Mmax`` with ``Mmax`` the largest vertex count; a
    polygon with fewer vertices repeats its last edge): ``poly_vertices`` ``(P,Mmax,2)``
    edge start points, ``poly_edges`` ``(P,Mmax,2)`` edge vectors, ``poly_normals``
    ``(P,Mmax,2)`` outward unit normals, ``poly_offsets`` ``(P,Mmax)`` = ``normal . start``
    (a point ``p`` is inside iff ``max(normal . p - offset) < 0``), ``poly_counts``
    ``(P,)`` real vertex counts, ``obstacle_count`` the number of scenario obstacles.

    Instances are immutable and safe to share between environments; the only
    mutable state is caches of :meth:`project_free` (its primitives per clearance, and
    its results for recent small queries, which are not pickled).
    """

    size: tuple[float, float]
    circles: np.ndarray
    circle_ids: np.ndarray
    polygons: tuple[np.ndarray, ...]
    polygon_ids: np.ndarray
    segments: np.ndarray = field(init=False)
    poly_vertices: np.ndarray = field(init=False, repr=False)
    poly_edges: np.ndarray = field(init=False, repr=False)
    poly_normals: np.ndarray = field(init=False, repr=False)
    poly_offsets: np.ndarray = field(init=False, repr=False)
    poly_counts: np.ndarray = field(init=False, repr=False)
    obstacle_count: int = field(init=False)
    _flat: dict = field(init=False, repr=False)
    _proj_cache: dict = field(init=False, repr=False)
    _chunk: int = field(init=False, repr=False)
    _bound: np.ndarray = field(init=False, repr=False)
    _bound_cols: tuple = field(init=False, repr=False)
    _reach2: dict = field(init=False, repr=False)
    _memo: dict = field(init=False, repr=False)
    _owner_sd_data: tuple = field(init=False, repr=False)

    # -- construction --------------------------------------------------------------------------

    def __post_init__(self) -> None:
        W, H = (float(v) for v in self.size)
        if not (math.isfinite(W) and math.isfinite(H) and W > 0.0 and H > 0.0):
            raise ValueError(f"world size must be two positive numbers, got {self.size!r}")
        put = object.__setattr__  # frozen dataclass: derived fields are set once, here
        put(self, "size", (W, H))
        circles = np.asarray(self.circles, dtype=np.float64).reshape(-1, 3)
        if np.any(~np.isfinite(circles)) or np.any(circles[:, 2] <= 0.0):
            raise ValueError("circle obstacles need finite centres and positive radii")
        put(self, "circles", _frozen(circles.copy()))
        put(self, "circle_ids", _frozen(np.asarray(self.circle_ids, dtype=np.int64).reshape(-1)))
        polys = tuple(_frozen(convex_ccw(p)) for p in self.polygons)
        put(self, "polygons", polys)
        put(self, "polygon_ids", _frozen(np.asarray(self.polygon_ids, dtype=np.int64).reshape(-1)))
        if len(self.circle_ids) != len(circles) or len(self.polygon_ids) != len(polys):
            raise ValueError("circle_ids / polygon_ids must have one entry per circle / polygon")
        ids = np.concatenate([self.circle_ids, self.polygon_ids])
        put(self, "obstacle_count", int(ids.max()) + 1 if len(ids) else 0)

        P = len(polys)
        mmax = max((len(p) for p in polys), default=1)
        verts = np.zeros((P, mmax, 2))
        edges = np.zeros((P, mmax, 2))
        for i, p in enumerate(polys):  # construction only; hot paths use the padded arrays
            m = len(p)
            e = _next(p) - p
            verts[i, :m], edges[i, :m] = p, e
            verts[i, m:], edges[i, m:] = p[-1], e[-1]  # repeat the last edge as padding
        lengths = np.linalg.norm(edges, axis=2)
        normals = np.stack([edges[..., 1], -edges[..., 0]], axis=2) / np.maximum(lengths, 1e-300)[..., None]
        offsets = np.einsum("pmk,pmk->pm", normals, verts)
        put(self, "poly_vertices", _frozen(verts))
        put(self, "poly_edges", _frozen(edges))
        put(self, "poly_normals", _frozen(normals))
        put(self, "poly_offsets", _frozen(offsets))
        put(self, "poly_counts", _frozen(np.array([len(p) for p in polys], dtype=np.int64)))

        seg_list = [np.hstack([p, _next(p)]) for p in polys]
        walls = np.array([[0, 0, W, 0], [W, 0, W, H], [W, H, 0, H], [0, H, 0, 0]], dtype=np.float64)
        put(self, "segments", _frozen(np.vstack(seg_list + [walls])))

        # Flattened edge arrays, edge-major (index m * P + p) and shaped (E, 1): the hot
        # loops work on (E, N) arrays (points last, contiguous) and reduce over the
        # padded edges with reshape(M, P, N).min(axis=0), which numpy does ~10x faster
        # than a reduction over a short last axis.
        ee = np.einsum("pmk,pmk->pm", edges, edges)
        inv_ee = np.where(ee > 0, 1.0 / np.maximum(ee, 1e-300), 0.0)

        def col(a: np.ndarray) -> np.ndarray:
            return _frozen(a.T.reshape(-1, 1))

        flat: dict[str, Any] = {
            "ax": col(verts[..., 0]), "ay": col(verts[..., 1]),
            "ex": col(edges[..., 0]), "ey": col(edges[..., 1]),
            "inv_ee": col(inv_ee),
            "nx": col(normals[..., 0]), "ny": col(normals[..., 1]),
            "off": col(offsets), "P": P, "M": mmax,
        }
        put(self, "_flat", flat)
        put(self, "_proj_cache", {})
        # distance() handles points in blocks whose (edges, points) temporaries stay under
        # 96 KiB: measured ~3x faster per point than one big block (large temporaries are
        # fresh mmap'd pages from the allocator on every call).
        put(self, "_chunk", max(32, _BLOCK_ELEMS // max(len(flat["nx"]) if P else 0, len(circles), 1)))

        # project_free()'s fast path works per "owner": obstacle k (circles first, then
        # polygons, the order of circles/polygons) and, last, the walls. A bounding disc per
        # obstacle screens points cheaply; the exact signed distance of one point to one
        # owner is then evaluated with Python floats by the very arithmetic of distance()
        # (same operations in the same order, so the same bits).
        bound = [(float(x), float(y), float(r)) for x, y, r in circles]
        for p in polys:
            centre = p.mean(axis=0)
            bound.append((float(centre[0]), float(centre[1]), float(np.sqrt(((p - centre) ** 2).sum(axis=1)).max())))
        put(self, "_bound", _frozen(np.array(bound, dtype=np.float64).reshape(-1, 3)))
        put(self, "_bound_cols", tuple(_frozen(self._bound[:, k:k + 1].copy()) for k in range(3)))  # (B, 1) each
        put(self, "_reach2", {})  # clearance -> (B, 1) squared screening radii
        put(self, "_memo", {})  # (clearance, point bytes) -> project_free() result, see _MEMO_SIZE
        poly_edges = []
        for i, p in enumerate(polys):
            rows = []
            for m in range(len(p)):
                rows.append(tuple(float(v) for v in (verts[i, m, 0], verts[i, m, 1], edges[i, m, 0], edges[i, m, 1],
                                                     inv_ee[i, m], normals[i, m, 0], normals[i, m, 1])))
            poly_edges.append(tuple(rows))
        put(self, "_owner_sd_data", (tuple(tuple(float(v) for v in row) for row in circles), tuple(poly_edges)))

    def kernel_arrays(self) -> MapArrays:
        """The map as the compiled kernels take it (:class:`MapArrays`), built once."""
        hit = self.__dict__.get("_kernel")
        if hit is None:  # built once (a cache beside the frozen fields)
            f = self._flat
            W, H = self.size
            hit = MapArrays(W, H, self._bound, self.circles, f["P"], f["M"],
                            *(np.ascontiguousarray(f[k].ravel()) for k in ("ax", "ay", "ex", "ey", "inv_ee", "nx", "ny")))
            self.__dict__["_kernel"] = hit
        return hit

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        state["_memo"] = {}  # a cache: not worth pickling
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)

    @classmethod
    def from_obstacles(cls, size: tuple[float, float], obstacles: Sequence[Obstacle]) -> StaticMap:
        """Build the map of world ``size = (W, H)`` from ``scenario.obstacles``.

        Circles go to ``circles``; rectangles (corners via :func:`rotate_rectangle`) and
        polygons (via :func:`convex_ccw`) go to ``polygons``, in scenario order, with their
        scenario index in ``circle_ids`` / ``polygon_ids``. Raises ``ValueError`` for a
        bad shape and ``TypeError`` for an unknown obstacle type.
        """
        circles: list[tuple[float, float, float]] = []
        circle_ids: list[int] = []
        polygons: list[np.ndarray] = []
        polygon_ids: list[int] = []
        for i, ob in enumerate(obstacles):
            if isinstance(ob, CircleObstacle):
                circles.append((float(ob.center[0]), float(ob.center[1]), float(ob.radius)))
                circle_ids.append(i)
            elif isinstance(ob, RectangleObstacle):
                polygons.append(rotate_rectangle(ob.center, ob.size, ob.angle))
                polygon_ids.append(i)
            elif isinstance(ob, PolygonObstacle):
                try:
                    polygons.append(convex_ccw(ob.points))
                except ValueError as exc:
                    raise ValueError(f"obstacle {i}: {exc}") from None
                polygon_ids.append(i)
            else:
                raise TypeError(f"obstacle {i}: unknown obstacle type {type(ob).__name__}")
        return cls(
            size=(float(size[0]), float(size[1])),
            circles=np.array(circles, dtype=np.float64).reshape(-1, 3),
            circle_ids=np.array(circle_ids, dtype=np.int64),
            polygons=tuple(polygons),
            polygon_ids=np.array(polygon_ids, dtype=np.int64),
        )

    # -- signed distance -----------------------------------------------------------------------

    def obstacle_distances(self, points: np.ndarray) -> np.ndarray:
        """``(N, 2) -> (N, obstacle_count)`` signed distance of each point to each obstacle,
        columns in ``scenario.obstacles`` order (negative inside). Walls are not included."""
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        out = np.empty((self.obstacle_count, len(pts)))
        if len(self.circles):
            out[self.circle_ids] = self._circle_sd(pts)
        if len(self.polygons):
            out[self.polygon_ids] = self._polygon_sd(pts)
        return out.T.copy()

    def wall_distance(self, points: np.ndarray) -> np.ndarray:
        """``(N, 2) -> (N,)`` signed distance to the world rectangle's boundary: positive
        inside ``[0,W]x[0,H]``, minus the Euclidean distance to the rectangle outside it."""
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        return self._wall_sd(pts[:, 0], pts[:, 1])

    def distance(self, points: np.ndarray, walls: bool = True) -> np.ndarray:
        """``(..., 2) -> (...)`` signed clearance: distance to the nearest obstacle surface (and
        wall if ``walls``), negative inside an obstacle or outside the world rectangle.
        ``+inf`` where there is nothing to measure (no obstacles and ``walls=False``)."""
        pts = np.asarray(points, dtype=np.float64)
        shape = pts.shape[:-1]
        pts = pts.reshape(-1, 2)
        if walls and len(pts) <= _FAST_MAX_POINTS and compiled_kernels():  # the same bits, fewer numpy calls
            from swarm_env.geometry.clearance_kernel import distances

            return distances(np.ascontiguousarray(pts), self.kernel_arrays()).reshape(shape)
        step = self._chunk
        if len(pts) <= step:
            return self._distance(pts, walls).reshape(shape)
        # Blocks keep every temporary small (see _chunk); a loop over blocks, not points.
        return np.concatenate(
            [self._distance(pts[i:i + step], walls) for i in range(0, len(pts), step)]
        ).reshape(shape)

    def _distance(self, pts: np.ndarray, walls: bool) -> np.ndarray:
        d = self._wall_sd(pts[:, 0], pts[:, 1]) if walls else np.full(len(pts), np.inf)
        if len(self.circles):
            np.minimum(d, self._circle_sd(pts).min(axis=0), out=d)
        if len(self.polygons):
            np.minimum(d, self._polygon_sd(pts).min(axis=0), out=d)
        return d

    def min_distance(
        self,
        points: np.ndarray,
        minus: np.ndarray | float = 0.0,
        upper: float = math.inf,
        lower: np.ndarray | None = None,
    ) -> float:
        """``min(upper, min_i(distance(points[i]) - minus[i]))`` as a float: the same number as
        that expression (walls included), computed faster when ``upper`` is finite.

        ``points`` ``(N, 2)``, ``minus`` ``(N,)`` or a scalar (e.g. robot radii). For a running
        minimum over many steps: a point whose lower bound (``lower``, default
        :meth:`distance_lower_bound`) minus ``minus[i]`` is not below ``upper`` cannot change
        the result, so its exact clearance is never computed.
        """
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        sub = np.asarray(minus, dtype=np.float64)
        if sub.shape != (len(pts),):
            sub = np.broadcast_to(sub, (len(pts),))
        if not len(pts):
            return float(upper)
        if math.isfinite(upper) and len(pts) <= _FAST_MAX_POINTS:
            lb = self.distance_lower_bound(pts) if lower is None else lower
            if compiled_kernels():  # the same number, see swarm_env.geometry.clearance_kernel
                from swarm_env.geometry.clearance_kernel import static_min_distance

                return float(static_min_distance(np.ascontiguousarray(pts), np.ascontiguousarray(sub), float(upper),
                                                 np.asarray(lb, dtype=np.float64), _SCREEN_MARGIN, self.kernel_arrays()))
            cand = np.flatnonzero(lb - sub < upper + _SCREEN_MARGIN)
            if len(cand) < len(pts):
                pts, sub = pts[cand], sub[cand]
            if not len(pts):
                return float(upper)
        return min(float(upper), float((self.distance(pts) - sub).min()))

    def distance_lower_bound(self, points: np.ndarray) -> np.ndarray:
        """``(N, 2) -> (N,)``: a cheap lower bound of :meth:`distance` (walls included): the
        clearance to each obstacle's bounding disc, so exact where a circle obstacle or a
        wall is nearest. Meant for skipping exact clearances that cannot matter."""
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        W, H = self.size
        if compiled_kernels():  # the same bits, see swarm_env.geometry.clearance_kernel
            from swarm_env.geometry.clearance_kernel import lower_bounds

            return lower_bounds(np.ascontiguousarray(pts), W, H, self._bound)
        x, y = pts[:, 0], pts[:, 1]
        lb = np.minimum(np.minimum(x, W - x), np.minimum(y, H - y))  # wall clearance inside the world
        if lb.min() < 0.0:  # outside the world the clearance is lower still
            lb = np.where(lb >= 0.0, lb, -np.inf)
        bd = self._bound
        if len(bd):
            dx = x - bd[:, 0, None]
            dy = y - bd[:, 1, None]
            np.minimum(lb, (np.sqrt(dx * dx + dy * dy) - bd[:, 2, None]).min(axis=0), out=lb)
        return lb

    def is_free(self, points: np.ndarray, clearance: float = 0.0) -> np.ndarray:
        """``(..., 2) -> (...)`` bool: the point's :meth:`distance` (walls included) is ``>= clearance``."""
        return self.distance(points) >= clearance

    # Internals below use a points-last layout: (K, N), (E, N), (P, N).

    def _circle_sd(self, pts: np.ndarray) -> np.ndarray:
        """``(N, 2) -> (K, N)`` signed distance to each circle."""
        c = self.circles
        dx = pts[:, 0] - c[:, 0, None]
        dy = pts[:, 1] - c[:, 1, None]
        return np.sqrt(dx * dx + dy * dy) - c[:, 2, None]

    def _polygon_parts(self, pts: np.ndarray) -> tuple[np.ndarray, ...]:
        """Per padded edge (edge-major, ``E = Mmax * P``) and point, all ``(E, N)``: the vector
        from the nearest point of the edge to the point (qx, qy), its squared length d2, and
        the half-plane value ``h = n . p - offset`` (> 0 outside the edge's half-plane)."""
        f = self._flat
        wx = pts[:, 0] - f["ax"]
        wy = pts[:, 1] - f["ay"]
        t = wx * f["ex"]
        t += wy * f["ey"]
        t *= f["inv_ee"]
        np.maximum(t, 0.0, out=t)
        np.minimum(t, 1.0, out=t)
        qx = wx - t * f["ex"]
        qy = wy - t * f["ey"]
        d2 = qx * qx
        d2 += qy * qy
        h = wx * f["nx"]
        h += wy * f["ny"]
        return qx, qy, d2, h

    def _polygon_sd(self, pts: np.ndarray) -> np.ndarray:
        """``(N, 2) -> (P, N)`` signed distance to each polygon."""
        f = self._flat
        _, _, d2, h = self._polygon_parts(pts)
        shape = (f["M"], f["P"], len(pts))
        h = h.reshape(shape).max(axis=0)
        d2 = d2.reshape(shape).min(axis=0)
        # Inside a convex polygon the nearest boundary point is the foot on the nearest
        # edge line, so the depth is exactly -max(h); outside it is the segment distance.
        return np.where(h > 0.0, np.sqrt(d2), h)

    def _wall_sd(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Signed distance to the world rectangle's boundary, ``(N,), (N,) -> (N,)``."""
        W, H = self.size
        inside = np.minimum(np.minimum(x, W - x), np.minimum(y, H - y))
        if np.all(inside >= 0.0):
            return inside
        ox = np.maximum(np.maximum(-x, x - W), 0.0)
        oy = np.maximum(np.maximum(-y, y - H), 0.0)
        return np.where(inside >= 0.0, inside, -np.sqrt(ox * ox + oy * oy))

    # -- nearest surface -----------------------------------------------------------------------

    def nearest_obstacles(
        self, points: np.ndarray, walls: bool = True
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Vectorised :meth:`nearest_obstacle`: ``(N, 2) -> (clearance (N,), normal (N, 2), ids (N,))``.

        ``normal`` is the unit gradient of the clearance: it points away from the nearest
        surface (out of an obstacle the point is inside; into the world for a wall).
        ``ids`` is the obstacle's index in ``scenario.obstacles``, ``WALL_ID0 - w`` for wall
        ``w`` (-1 bottom .. -4 left), or :data:`NO_SURFACE` (clearance ``inf``, normal 0)
        when there is nothing (no obstacles and ``walls=False``). Ties go to the first
        of: walls, circles, polygons.
        """
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        n = len(pts)
        rows = np.arange(n)
        best_d = np.full(n, np.inf)
        best_n = np.zeros((n, 2))
        best_id = np.full(n, NO_SURFACE, dtype=np.int64)

        def take(d: np.ndarray, nrm: np.ndarray, ids: np.ndarray) -> None:
            better = d < best_d
            best_d[better] = d[better]
            best_n[better] = nrm[better]
            best_id[better] = ids[better]

        if walls:
            W, H = self.size
            x, y = pts[:, 0], pts[:, 1]
            inner = np.stack([y, W - x, H - y, x], axis=1)  # bottom, right, top, left
            w = np.argmin(inner, axis=1)
            inward = np.array([[0.0, 1.0], [-1.0, 0.0], [0.0, -1.0], [1.0, 0.0]])
            nrm = inward[w].copy()
            d = inner[rows, w]
            outside = d < 0.0
            if np.any(outside):
                dvec = np.clip(pts, 0.0, [W, H]) - pts  # towards the rectangle
                dist = np.linalg.norm(dvec, axis=1)
                d = np.where(outside, -dist, d)
                nrm[outside] = dvec[outside] / dist[outside, None]
            take(d, nrm, WALL_ID0 - w)
        if len(self.circles):
            c = self.circles
            dx = pts[:, 0] - c[:, 0, None]  # (K, N)
            dy = pts[:, 1] - c[:, 1, None]
            r = np.sqrt(dx * dx + dy * dy)
            k = np.argmin(r - c[:, 2, None], axis=0)
            rk = r[k, rows]
            safe = rk > 0.0
            rs = np.where(safe, rk, 1.0)
            nrm = np.stack([np.where(safe, dx[k, rows] / rs, 1.0),  # on a centre: pick +x
                            np.where(safe, dy[k, rows] / rs, 0.0)], axis=1)
            take(rk - c[k, 2], nrm, self.circle_ids[k])
        if len(self.polygons):
            f = self._flat
            P, M = f["P"], f["M"]
            qx, qy, d2, h = (a.reshape(M, P, n) for a in self._polygon_parts(pts))
            hmax = h.max(axis=0)  # (P, N)
            sd = np.where(hmax > 0.0, np.sqrt(d2.min(axis=0)), hmax)
            p = np.argmin(sd, axis=0)
            inside = hmax[p, rows] <= 0.0
            e_in = np.argmax(h[:, p, rows], axis=0)  # nearest edge line (inside)
            e_out = np.argmin(d2[:, p, rows], axis=0)  # nearest edge segment (outside)
            nrm = self.poly_normals[p, e_in].copy()
            out = ~inside
            if np.any(out):
                v = np.stack([qx[e_out, p, rows], qy[e_out, p, rows]], axis=1)
                length = np.linalg.norm(v, axis=1)
                ok = out & (length > 0.0)
                nrm[ok] = v[ok] / length[ok, None]
            take(sd[p, rows], nrm, self.polygon_ids[p])
        return best_d, best_n, best_id

    def nearest_obstacle(self, point: np.ndarray, walls: bool = True) -> tuple[float, np.ndarray]:
        """Clearance of one ``(2,)`` point and the ``(2,)`` unit normal pointing away from the
        nearest obstacle/wall surface (see :meth:`nearest_obstacles`)."""
        d, nrm, _ = self.nearest_obstacles(np.asarray(point, dtype=np.float64).reshape(1, 2), walls)
        return float(d[0]), nrm[0]

    # -- projection to free space --------------------------------------------------------------

    def project_free(self, points: np.ndarray, clearance: float) -> np.ndarray:
        """``(..., 2) -> (..., 2)``: each point unchanged if free (:meth:`distance` ``>= clearance``),
        else moved to the nearest point whose distance is ``>= clearance`` (paper 000,
        sec. III-D d: the target is "adjusted to the nearest valid point outside the
        obstacle boundary", a least-squares projection).

        Exact up to ``1e-9`` m (the result lies that far beyond ``clearance``), for any
        overlap of obstacles and for points outside the world (walls count: the result is
        inside ``[clearance, W-clearance] x [clearance, H-clearance]``). Method: the free
        set's boundary is made of the obstacles inflated by ``clearance`` (circles of radius
        ``r+c``, polygon edges shifted by ``c`` along their normals, ``c``-circles at polygon
        vertices) and the shrunk world rectangle. The nearest free point is either the
        foot of the point on one of these primitives or a corner of the free set (an
        intersection of two primitives or a segment end); feet are computed per call, the
        free corners once per clearance (cached), and the nearest free candidate wins
        (ties: the first candidate, so results are deterministic). If no free point
        exists (free space empty at this clearance) the candidate with the largest
        clearance is returned.

        A handful of points (formation slots) first go through :meth:`_project_fast`,
        which settles most of them with the same result at a fraction of the cost, and the
        results of the last ``_MEMO_SIZE`` such queries are remembered by their exact bits
        (a fixed scenario with a virtual leader asks the same questions every episode).
        """
        pts = np.asarray(points, dtype=np.float64)
        c = float(clearance)
        if not (math.isfinite(c) and c >= 0.0):
            raise ValueError(f"clearance must be a finite number >= 0, got {clearance!r}")
        shape = pts.shape
        pts = pts.reshape(-1, 2)
        if not np.isfinite(pts).all():
            raise ValueError("project_free: points must be finite")
        if len(pts) > _FAST_MAX_POINTS:
            out = pts.copy()
            bad = np.flatnonzero(~(self.distance(pts) >= c))
        else:
            key = (c, pts.tobytes())
            hit = self._memo.get(key)
            if hit is not None:
                return hit.copy().reshape(shape)
            out = pts.copy()
            bad = self._project_fast(pts, c, out)
        if len(bad):
            out[bad] = self._project_exact(pts[bad], c)
        if len(pts) <= _FAST_MAX_POINTS and _MEMO_SIZE:
            while len(self._memo) >= _MEMO_SIZE:
                self._memo.pop(next(iter(self._memo)))  # oldest first
            self._memo[key] = out.copy()
        return out.reshape(shape)

    def slot_screen(self, clearance: float) -> tuple[np.ndarray, np.ndarray]:
        """The first screen of :meth:`project_free` for up to ``_FAST_MAX_POINTS`` points, as arrays
        for :mod:`swarm_env.geometry.slot_kernel`: ``(B, 3)`` rows ``(x, y, r2)`` (an obstacle's bounding disc
        centre and its squared screening radius) and ``(W, H, reach)``. A finite point with
        ``reach <= min(x, W - x, y, H - y)`` and ``(x - bx)**2 + (y - by)**2 >= r2`` for every row is
        one :meth:`_project_fast` leaves unchanged, computed with the same operations."""
        c = float(clearance)
        reach = c + _SCREEN_MARGIN
        bx, by, brad = (col[:, 0] for col in self._bound_cols)
        r = brad + reach
        table = np.ascontiguousarray(np.column_stack([bx, by, r * r]), dtype=np.float64).reshape(-1, 3)
        W, H = self.size
        return table, np.array([W, H, reach], dtype=np.float64)

    def _project_fast(self, pts: np.ndarray, c: float, out: np.ndarray) -> np.ndarray:
        """project_free() for a few points, writing into ``out`` the points it settles.

        Returns the indices of the points left to the exact search (:meth:`_project_exact`).
        Every point it settles gets bit for bit what the exact search would give it:

        * A point farther than ``c`` (plus a margin) from every obstacle's bounding disc and
          from the walls is free. For the others the exact clearance to the obstacles
          whose disc is near is computed (the others cannot bring it below ``c``).
        * A point that violates exactly one owner ``O`` (an obstacle, or the walls) is
          tested against ``O``'s primitives only, nearest foot first, as the exact search
          does: ``f*`` is the first foot with ``d_O(f*) >= c``, at distance ``rho``. Every
          candidate of another owner ``O2`` (a foot on its inflated boundary or a corner
          on it) has ``d_O2 <= c + eps`` and so lies at least ``d_O2(q) - c - eps`` from the
          point (``d_O2`` is 1-Lipschitz). If that exceeds ``rho`` for every other owner
          (a certificate checked with the exact or bounding-disc clearance), the exact
          search sees the same candidates up to ``f*`` and picks ``f*``: the only corners
          left to compare are the end points of ``O``'s own segments.
        * Anything else (two owners violated, a certificate that fails) is left to the
          exact search.
        """
        W, H = self.size
        x, y = pts[:, 0], pts[:, 1]
        reach = c + _SCREEN_MARGIN
        wall_in = np.minimum(np.minimum(x, W - x), np.minimum(y, H - y))  # wall clearance inside the world
        sus = wall_in < reach
        bd = self._bound
        walls = len(bd)  # owner index of the walls
        if walls:
            bx, by, brad = self._bound_cols
            dx = x - bx
            dy = y - by
            d2 = dx * dx + dy * dy  # (B, N)
            reach2 = self._reach2.get(c)
            if reach2 is None:
                if len(self._reach2) >= _CACHE_SIZE:
                    self._reach2.clear()
                r = brad + reach
                reach2 = self._reach2[c] = r * r
            near = d2 < reach2
            sus |= near.any(axis=0)
        idx = np.flatnonzero(sus)
        if not len(idx):
            return idx
        circ_sd, poly_sd = self._owner_sd_data
        k_circ = len(circ_sd)
        slow = []
        prim = None
        cp = c + _PUSH_EPS
        if walls:
            near_rows = near[:, idx].T.tolist()
            lbs = (np.sqrt(d2[:, idx]) - brad).T.tolist()  # bounding-disc lower bounds of the clearances
        else:
            near_rows = lbs = [[]] * len(idx)
        for i, (qx, qy), w_in, near_row, lb in zip(idx.tolist(), pts[idx].tolist(), wall_in[idx].tolist(), near_rows, lbs):
            near_i = [o for o, hit in enumerate(near_row) if hit]
            if w_in < reach:
                near_i.append(walls)
            sd = {o: self._owner_sd(o, qx, qy, k_circ, circ_sd, poly_sd) for o in near_i}
            viol = [o for o in near_i if not sd[o] >= c]
            if not viol:
                continue  # free: unchanged
            if len(viol) > 1:
                slow.append(i)
                continue
            o = viol[0]
            if prim is None:
                prim = self._primitives(c)
            found = self._owner_nearest_free(o, qx, qy, c, prim, k_circ, circ_sd, poly_sd)
            if found is None:
                slow.append(i)
                continue
            fd2, fx, fy = found
            # Certificate: every other owner is farther than rho (+ eps + margin) beyond c.
            limit = cp + math.sqrt(fd2) + _SCREEN_MARGIN
            ok = True
            if o != walls and not (sd[walls] if walls in sd else w_in) > limit:
                ok = False
            if ok:
                for o2 in range(walls):
                    if o2 != o and not ((sd[o2] if o2 in sd else lb[o2]) > limit):
                        ok = False
                        break
            # The end points of o's own segments are the only corners left that could win.
            if ok:
                for ex, ey in prim["owner_ends"][o]:
                    ddx, ddy = qx - ex, qy - ey
                    if not ddx * ddx + ddy * ddy > fd2:
                        ok = False
                        break
            if ok:
                out[i, 0], out[i, 1] = fx, fy
            else:
                slow.append(i)
        return np.array(slow, dtype=np.intp)

    def _owner_sd(self, o: int, x: float, y: float, k_circ: int, circ_sd: tuple, poly_sd: tuple) -> float:
        """Signed clearance of the point ``(x, y)`` to owner ``o`` alone (see
        :meth:`_project_fast`), computed exactly as :meth:`distance` computes that term."""
        if o < k_circ:
            cx, cy, r = circ_sd[o]
            dx, dy = x - cx, y - cy
            return math.sqrt(dx * dx + dy * dy) - r
        if o < k_circ + len(poly_sd):
            hmax = -math.inf
            d2min = math.inf
            for ax, ay, ex, ey, inv, nx, ny in poly_sd[o - k_circ]:
                wx, wy = x - ax, y - ay
                t = (wx * ex + wy * ey) * inv
                t = min(max(t, 0.0), 1.0)
                qx, qy = wx - t * ex, wy - t * ey
                d2 = qx * qx + qy * qy
                h = wx * nx + wy * ny
                if h > hmax:
                    hmax = h
                if d2 < d2min:
                    d2min = d2
            return math.sqrt(d2min) if hmax > 0.0 else hmax
        W, H = self.size
        inside = min(min(x, W - x), min(y, H - y))
        if inside >= 0.0:
            return inside
        ox = max(max(-x, x - W), 0.0)
        oy = max(max(-y, y - H), 0.0)
        return -math.sqrt(ox * ox + oy * oy)

    def _owner_nearest_free(
        self, o: int, qx: float, qy: float, c: float, prim: dict, k_circ: int, circ_sd: tuple, poly_sd: tuple
    ) -> tuple[float, float, float] | None:
        """The exact search restricted to owner ``o``'s primitives: its feet, nearest first
        (ties in primitive order), and the first with ``d_o >= c`` as ``(d2, x, y)``; the
        arithmetic is :meth:`_feet`'s. ``None`` if no foot is free of ``o``."""
        feet = []
        for key, cx, cy, rad in prim["owner_circles"][o]:
            dx, dy = qx - cx, qy - cy
            r = math.sqrt(dx * dx + dy * dy)
            if r > 0.0:
                ux, uy = dx / r, dy / r
            else:  # a point on a centre goes +x, as in _feet
                ux, uy = 1.0, 0.0
            fx, fy = cx + rad * ux, cy + rad * uy
            ddx, ddy = fx - qx, fy - qy
            feet.append((ddx * ddx + ddy * ddy, key, fx, fy))
        for key, ax, ay, ex, ey, inv in prim["owner_segments"][o]:
            t = ((qx - ax) * ex + (qy - ay) * ey) * inv
            t = min(max(t, 0.0), 1.0)
            fx, fy = ax + t * ex, ay + t * ey
            ddx, ddy = fx - qx, fy - qy
            feet.append((ddx * ddx + ddy * ddy, key, fx, fy))
        feet.sort()
        for fd2, _, fx, fy in feet:
            if self._owner_sd(o, fx, fy, k_circ, circ_sd, poly_sd) >= c:
                return fd2, fx, fy
        return None

    def _project_exact(self, q: np.ndarray, c: float) -> np.ndarray:
        """The nearest free points of the ``(V, 2)`` points ``q``, all known not free (see
        :meth:`project_free`): the vectorised search over every candidate."""
        prim = self._primitives(c)
        feet = self._feet(q, prim)  # (V, F, 2)
        v, nf = feet.shape[:2]
        fd2 = np.sum((feet - q[:, None, :]) ** 2, axis=2)
        rows = np.arange(v)
        # Start from the nearest free corner (corners are free by construction) ...
        best = np.zeros((v, 2))
        best_d2 = np.full(v, np.inf)
        corners = prim["corners"]
        if len(corners):
            cd2 = (q[:, 0, None] - corners[:, 0]) ** 2 + (q[:, 1, None] - corners[:, 1]) ** 2
            j = np.argmin(cd2, axis=1)
            best, best_d2 = corners[j].copy(), cd2[rows, j]
        # ... then test feet nearest-first in small chunks: a point is settled once a chunk
        # holds a free foot (later feet are farther) or only feet farther than its best.
        # Checking every foot of every point costs ~10x more on a typical map.
        order = np.argsort(fd2, axis=1, kind="stable")
        active = rows
        for s in range(0, nf, _FEET_CHUNK):
            if not len(active):
                break
            idx = order[active, s:s + _FEET_CHUNK]  # (A, k)
            cand = feet[active[:, None], idx]  # (A, k, 2)
            cd2 = fd2[active[:, None], idx]
            free = cd2 < best_d2[active, None]
            if np.any(free):
                free[free] = self.distance(cand[free]) >= c
            vd2 = np.where(free, cd2, np.inf)
            j = np.argmin(vd2, axis=1)
            vj = vd2[np.arange(len(active)), j]
            upd = vj < best_d2[active]
            best[active[upd]] = cand[upd, j[upd]]
            best_d2[active[upd]] = vj[upd]
            done = np.isfinite(vj) | (cd2[:, -1] >= best_d2[active])
            active = active[~done]
        none = ~np.isfinite(best_d2)
        if np.any(none):  # empty free space: best effort, the most clearance among the feet
            fd = self.distance(feet[none])
            best[none] = feet[none][np.arange(int(none.sum())), np.argmax(fd, axis=1)]
        return best

    def _primitives(self, c: float) -> dict:
        """Boundary primitives of the free set at clearance ``c`` (+ _PUSH_EPS) and its free
        corners; cached per clearance because scenarios use one or two clearances."""
        hit = self._proj_cache.get(c)
        if hit is not None:
            return hit
        cp = c + _PUSH_EPS
        W, H = self.size
        # Circles: inflated circle obstacles, then c-circles around every polygon vertex.
        circ = [np.column_stack([self.circles[:, :2], self.circles[:, 2] + cp])]
        circ_owner = [self.circle_ids]
        segs = []
        seg_owner = []
        for pid, poly in zip(self.polygon_ids, self.polygons):  # construction-time, cached
            circ.append(np.column_stack([poly, np.full(len(poly), cp)]))
            circ_owner.append(np.full(len(poly), pid))
            e = _next(poly) - poly
            nrm = np.stack([e[:, 1], -e[:, 0]], axis=1) / np.linalg.norm(e, axis=1)[:, None]
            segs.append(np.hstack([poly + cp * nrm, _next(poly) + cp * nrm]))
            seg_owner.append(np.full(len(poly), pid))
        lo_x, lo_y, hi_x, hi_y = cp, cp, W - cp, H - cp
        segs.append(np.array([[lo_x, lo_y, hi_x, lo_y], [hi_x, lo_y, hi_x, hi_y],
                              [hi_x, hi_y, lo_x, hi_y], [lo_x, hi_y, lo_x, lo_y]]))
        seg_owner.append(-1 - np.arange(4))  # each wall is its own owner
        circ_a = np.vstack(circ).reshape(-1, 3)
        seg_a = np.vstack(segs).reshape(-1, 4)
        circ_o = np.concatenate(circ_owner).astype(np.int64)
        seg_o = np.concatenate(seg_owner).astype(np.int64)
        corners = _corner_candidates(circ_a, circ_o, seg_a, seg_o)
        if len(corners):
            corners = corners[self.distance(corners) >= c]
        prim: dict[str, Any] = {"circles": circ_a, "segments": seg_a, "corners": _frozen(corners.reshape(-1, 2))}
        # Per owner of _project_fast (circle obstacles, polygons, then the walls): its
        # primitives as Python floats, keyed by their index among _feet's feet, and the end
        # points of its segments.
        k, p_count = len(self.circles), len(self.polygons)
        owner_c: list[list] = [[] for _ in range(k + p_count + 1)]
        owner_s: list[list] = [[] for _ in range(k + p_count + 1)]
        owner_e: list[list] = [[] for _ in range(k + p_count + 1)]
        c_owner = list(range(k)) + [k + i for i, poly in enumerate(self.polygons) for _ in range(len(poly))]
        s_owner = [k + i for i, poly in enumerate(self.polygons) for _ in range(len(poly))] + [k + p_count] * 4
        for j, (row, o) in enumerate(zip(circ_a.tolist(), c_owner)):
            owner_c[o].append((j, row[0], row[1], row[2]))
        nc = len(circ_a)
        for j, (row, o) in enumerate(zip(seg_a.tolist(), s_owner)):
            ax, ay, bx, by = row
            ex, ey = bx - ax, by - ay
            ee = ex * ex + ey * ey
            owner_s[o].append((nc + j, ax, ay, ex, ey, 1.0 / ee if ee > 0.0 else 0.0))
            owner_e[o] += [(ax, ay), (bx, by)]
        prim["owner_circles"] = tuple(tuple(v) for v in owner_c)
        prim["owner_segments"] = tuple(tuple(v) for v in owner_s)
        prim["owner_ends"] = tuple(tuple(v) for v in owner_e)
        if len(self._proj_cache) >= _CACHE_SIZE:
            self._proj_cache.pop(next(iter(self._proj_cache)))
        self._proj_cache[c] = prim
        return prim

    @staticmethod
    def _feet(q: np.ndarray, prim: dict) -> np.ndarray:
        """Nearest point of every primitive to every point: ``(V, 2) -> (V, F, 2)``."""
        circ, seg = prim["circles"], prim["segments"]
        dx = q[:, 0, None] - circ[:, 0]
        dy = q[:, 1, None] - circ[:, 1]
        r = np.sqrt(dx * dx + dy * dy)
        safe = r > 0.0
        rr = np.where(safe, r, 1.0)
        ux = np.where(safe, dx / rr, 1.0)  # a point on a centre goes +x (deterministic)
        uy = np.where(safe, dy / rr, 0.0)
        fc = np.stack([circ[:, 0] + circ[:, 2] * ux, circ[:, 1] + circ[:, 2] * uy], axis=2)
        ax, ay = seg[:, 0], seg[:, 1]
        ex, ey = seg[:, 2] - ax, seg[:, 3] - ay
        ee = ex * ex + ey * ey
        inv = np.where(ee > 0.0, 1.0 / np.where(ee > 0.0, ee, 1.0), 0.0)
        t = np.clip(((q[:, 0, None] - ax) * ex + (q[:, 1, None] - ay) * ey) * inv, 0.0, 1.0)
        fs = np.stack([ax + t * ex, ay + t * ey], axis=2)
        return np.concatenate([fc, fs], axis=1)


def _corner_candidates(circ: np.ndarray, circ_o: np.ndarray, seg: np.ndarray, seg_o: np.ndarray) -> np.ndarray:
    """Segment end points and pairwise intersections of primitives with different owners
    whose bounding boxes overlap (an inflated convex obstacle has a smooth boundary, so
    corners of the free set only arise between two owners). Returns ``(C, 2)``."""
    box_c = np.column_stack([circ[:, :2] - circ[:, 2:], circ[:, :2] + circ[:, 2:]])
    box_s = np.column_stack([np.minimum(seg[:, :2], seg[:, 2:]), np.maximum(seg[:, :2], seg[:, 2:])])
    tol = 1e-9

    def pairs(b1: np.ndarray, o1: np.ndarray, b2: np.ndarray, o2: np.ndarray, upper: bool):
        ov = ((b1[:, None, 0] <= b2[None, :, 2] + tol) & (b2[None, :, 0] <= b1[:, None, 2] + tol)
              & (b1[:, None, 1] <= b2[None, :, 3] + tol) & (b2[None, :, 1] <= b1[:, None, 3] + tol)
              & (o1[:, None] != o2[None, :]))
        if upper:
            ov &= np.triu(np.ones(ov.shape, dtype=bool), 1)
        return np.nonzero(ov)

    out = [seg[:, :2], seg[:, 2:]]
    # circle x circle
    i, j = pairs(box_c, circ_o, box_c, circ_o, True)
    if len(i):
        c1, r1, c2, r2 = circ[i, :2], circ[i, 2], circ[j, :2], circ[j, 2]
        v = c2 - c1
        d = np.linalg.norm(v, axis=1)
        ok = (d > 0) & (d <= r1 + r2) & (d >= np.abs(r1 - r2))
        c1, r1, r2, v, d = c1[ok], r1[ok], r2[ok], v[ok], d[ok]
        u = v / d[:, None]
        a = (d * d + r1 * r1 - r2 * r2) / (2 * d)
        h = np.sqrt(np.maximum(r1 * r1 - a * a, 0.0))
        base = c1 + a[:, None] * u
        perp = np.stack([-u[:, 1], u[:, 0]], axis=1)
        out += [base + h[:, None] * perp, base - h[:, None] * perp]
    # segment x segment
    i, j = pairs(box_s, seg_o, box_s, seg_o, True)
    if len(i):
        a1, e1 = seg[i, :2], seg[i, 2:] - seg[i, :2]
        a2, e2 = seg[j, :2], seg[j, 2:] - seg[j, :2]
        den = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
        w = a2 - a1
        ok = np.abs(den) > 1e-15
        den = np.where(ok, den, 1.0)
        t = (w[:, 0] * e2[:, 1] - w[:, 1] * e2[:, 0]) / den
        s = (w[:, 0] * e1[:, 1] - w[:, 1] * e1[:, 0]) / den
        ok &= (t >= 0) & (t <= 1) & (s >= 0) & (s <= 1)
        out.append(a1[ok] + t[ok, None] * e1[ok])
    # segment x circle
    i, j = pairs(box_s, seg_o, box_c, circ_o, False)
    if len(i):
        a, e = seg[i, :2], seg[i, 2:] - seg[i, :2]
        f = a - circ[j, :2]
        ee = np.einsum("ij,ij->i", e, e)
        b = np.einsum("ij,ij->i", f, e)
        cc = np.einsum("ij,ij->i", f, f) - circ[j, 2] ** 2
        disc = b * b - ee * cc
        ok = (disc >= 0) & (ee > 0)
        sq = np.sqrt(np.where(ok, disc, 0.0))
        eei = np.where(ee > 0, ee, 1.0)
        for t in ((-b - sq) / eei, (-b + sq) / eei):
            m = ok & (t >= 0) & (t <= 1)
            out.append(a[m] + t[m, None] * e[m])
    return np.vstack(out)
