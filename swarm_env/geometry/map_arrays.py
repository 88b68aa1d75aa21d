"""A static map as the compiled kernels read it: one typed bundle of arrays per map (:class:`MapArrays`, from
:meth:`swarm_env.geometry.static_map.StaticMap.kernel_arrays`) and one per batch of maps (:class:`MapBatch`, from
the batched engine's padded rows). numba takes either as one argument and reads its fields by name."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class MapArrays(NamedTuple):
    """One static map: the world's ``width`` and ``height``, the obstacles' bounding discs ``bound`` ``(B, 3)``
    (:meth:`~swarm_env.geometry.static_map.StaticMap.distance_lower_bound`'s), the ``circles`` ``(C, 3)``, and the
    polygons' padded edges (``n_poly`` polygons of ``n_edge`` edges, edge-major: edge ``e`` of polygon ``p`` at
    index ``e * n_poly + p``): start points ``ax``/``ay``, edge vectors ``ex``/``ey`` with
    ``inv_ee = 1 / (ex^2 + ey^2)``, outward unit normals ``nx``/``ny``."""

    width: float
    height: float
    bound: np.ndarray
    circles: np.ndarray
    n_poly: int
    n_edge: int
    ax: np.ndarray
    ay: np.ndarray
    ex: np.ndarray
    ey: np.ndarray
    inv_ee: np.ndarray
    nx: np.ndarray
    ny: np.ndarray


class MapBatch(NamedTuple):
    """The :class:`MapArrays` of ``M`` worlds, one padded row each: ``width``/``height``/``n_poly``/``n_edge``
    ``(M,)``, ``bound`` ``(M, B, 3)`` of which ``nbound[m]`` rows are world ``m``'s, ``circles`` ``(M, C, 3)`` with
    ``ncirc``, the edge arrays ``(M, E)``. :func:`swarm_env.geometry.clearance_kernel.world_map` takes out one
    world's."""

    width: np.ndarray
    height: np.ndarray
    bound: np.ndarray
    nbound: np.ndarray
    circles: np.ndarray
    ncirc: np.ndarray
    n_poly: np.ndarray
    n_edge: np.ndarray
    ax: np.ndarray
    ay: np.ndarray
    ex: np.ndarray
    ey: np.ndarray
    inv_ee: np.ndarray
    nx: np.ndarray
    ny: np.ndarray


__all__ = ["MapArrays", "MapBatch"]
