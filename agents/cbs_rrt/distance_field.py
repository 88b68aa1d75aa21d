"""A precomputed grid of a static map's signed clearance, with vectorised bilinear lookups.

The planner checks thousands of points per replan against the obstacles; asking
:meth:`swarm_env.geometry.static_map.StaticMap.distance` each time would loop over every
obstacle edge for every point. Instead the clearance (walls included) is
sampled once on a regular grid covering the world ``[0, W] x [0, H]`` and read
back by bilinear interpolation: a lookup costs the same whatever the number of
obstacles.

Accuracy: the clearance is 1-Lipschitz, so the bilinear value at a point differs
from the exact clearance by at most the weighted mean distance to the four
cell corners, ``<= resolution / sqrt(2)`` (:attr:`DistanceField.error_bound`);
:meth:`DistanceField.lower_bound` subtracts it. Points outside the world read the
value at the nearest border cell (<= 0 there), so they are never free.

Fields are cached per :class:`StaticMap` object and resolution
(:func:`distance_field`): a fixed scenario builds its field once.
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass, field

import numpy as np

from swarm_env.compiled import compiled_kernels
from swarm_env.geometry.static_map import StaticMap
from swarm_env_agents.cbs_rrt import kernels

__all__ = ["DistanceField", "distance_field"]


@dataclass(frozen=True, eq=False)
class DistanceField:
    """Signed clearance of a :class:`StaticMap` sampled on a grid (build with :meth:`build`).

    Attributes:
        resolution: grid spacing (m).
        nx, ny: number of grid nodes along x and y (node ``(i, j)`` is at ``(i h, j h)``,
            the last row/column may lie slightly beyond the world).
        values: ``(ny * nx,)`` flat row-major clearances (m), read-only.
        size: the world ``(W, H)``.
        kernel: the field as the compiled kernels take it (a :class:`.kernels.Field`, as the plain tuple
            of :func:`.kernels.plain`), built once.
    """

    resolution: float
    nx: int
    ny: int
    values: np.ndarray = field(repr=False)
    size: tuple[float, float]
    _inv: float = field(init=False, repr=False)
    _xmax: float = field(init=False, repr=False)
    _ymax: float = field(init=False, repr=False)
    kernel: tuple = field(init=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_inv", 1.0 / self.resolution)
        # Largest grid coordinate whose cell (floor) still has a right/top neighbour.
        object.__setattr__(self, "_xmax", (self.nx - 1) * (1.0 - 1e-12))
        object.__setattr__(self, "_ymax", (self.ny - 1) * (1.0 - 1e-12))
        bundle = kernels.Field(self._inv, self._xmax, self._ymax, int(self.nx), self.values)
        object.__setattr__(self, "kernel", kernels.plain(bundle))

    @classmethod
    def build(cls, static: StaticMap, resolution: float = 0.05) -> DistanceField:
        """Sample ``static.distance`` (walls included) on a grid of spacing ``resolution``."""
        if not (math.isfinite(resolution) and resolution > 0):
            raise ValueError(f"resolution must be > 0, got {resolution!r}")
        W, H = static.size
        nx = int(math.ceil(W / resolution - 1e-9)) + 1
        ny = int(math.ceil(H / resolution - 1e-9)) + 1
        xs = np.arange(nx) * resolution
        ys = np.arange(ny) * resolution
        grid = np.empty((ny * nx, 2))
        grid[:, 0] = np.tile(xs, ny)
        grid[:, 1] = np.repeat(ys, nx)
        values = np.ascontiguousarray(static.distance(grid), dtype=np.float64)
        values.flags.writeable = False
        return cls(float(resolution), nx, ny, values, (float(W), float(H)))

    @property
    def error_bound(self) -> float:
        """Largest possible ``|clearance(p) - exact(p)|`` inside the world (m)."""
        return self.resolution / math.sqrt(2.0)

    def clearance_xy(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Bilinear clearance at points given as two arrays of equal shape (m): compiled
        (:mod:`.kernels`, the same bits) unless :func:`swarm_env.compiled.use_compiled_kernels`
        turned the kernels off."""
        if compiled_kernels():
            xa = np.asarray(x, dtype=np.float64)
            out = kernels.clearance_xy(np.ascontiguousarray(xa).ravel(),
                                       np.ascontiguousarray(y, dtype=np.float64).ravel(), self.kernel)
            if out is not None:
                return out.reshape(xa.shape)
        return self._clearance_xy(x, y)

    def _clearance_xy(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """The numpy reference of :meth:`clearance_xy`."""
        # Grid coordinates clamped into the grid (no extrapolation): ufuncs, not np.clip, whose
        # Python-level overhead dominated this hot function.
        gx = np.minimum(np.maximum(np.asarray(x, dtype=np.float64) * self._inv, 0.0), self._xmax)
        gy = np.minimum(np.maximum(np.asarray(y, dtype=np.float64) * self._inv, 0.0), self._ymax)
        ix = gx.astype(np.int64)
        iy = gy.astype(np.int64)
        fx = gx - ix
        fy = gy - iy
        k = iy * self.nx + ix
        v = self.values
        a = v[k]
        b = v[k + 1]
        c = v[k + self.nx]
        d = v[k + self.nx + 1]
        top = a + fx * (b - a)
        return top + fy * (c + fx * (d - c) - top)

    def clearance(self, points: np.ndarray) -> np.ndarray:
        """``(..., 2) -> (...)`` bilinear signed clearance (m)."""
        p = np.asarray(points, dtype=np.float64)
        return self.clearance_xy(p[..., 0], p[..., 1])

    def lower_bound(self, points: np.ndarray) -> np.ndarray:
        """``(..., 2) -> (...)`` a guaranteed lower bound of the exact clearance inside the world."""
        return self.clearance(points) - self.error_bound


_CACHE: weakref.WeakKeyDictionary[StaticMap, dict[float, DistanceField]] = weakref.WeakKeyDictionary()


def distance_field(static: StaticMap, resolution: float = 0.05) -> DistanceField:
    """The :class:`DistanceField` of ``static`` at ``resolution``, built on first use and
    cached for as long as the map object lives."""
    per_map = _CACHE.get(static)
    if per_map is None:
        per_map = {}
        _CACHE[static] = per_map
    df = per_map.get(float(resolution))
    if df is None:
        df = per_map[float(resolution)] = DistanceField.build(static, resolution)
    return df
