"""The planner's innermost tests, compiled with numba: the constraint-table lookups of
:class:`~.constraints.ConstraintTable` and the bilinear clearance of
:class:`~.distance_field.DistanceField`.

Every RRT expansion tests hundreds of primitive samples against both; the numpy versions beside
them (the references) spend most of their time in per-call overhead and ``(constraints, points)``
temporaries. These kernels walk the points once. Same results bit for bit: the clearance is the
reference's arithmetic in its order (``a + fx * (b - a)``, then ``top + fy * (c + fx * (d - c) - top)``)
and the constraint tests are comparisons of the same squared distances
(``tests/test_cbs_kernels.py``).
"""

from __future__ import annotations

import numba
import numpy as np

_jit = numba.njit(cache=True, nogil=True, error_model="numpy")


@_jit
def clearance_xy(x, y, inv, xmax, ymax, nx, values):  # pragma: no cover - compiled
    """``DistanceField.clearance_xy`` of flat ``x``/``y`` (float64, same length); ``None`` if a
    coordinate is NaN (the caller then runs the reference, which raises)."""
    out = np.empty(len(x))
    for m in range(len(x)):
        if x[m] != x[m] or y[m] != y[m]:
            return None
        gx = min(max(x[m] * inv, 0.0), xmax)
        gy = min(max(y[m] * inv, 0.0), ymax)
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
        out[m] = top + fy * (c + fx * (d - c) - top)
    return out


@_jit
def constraint_free(x, y, t, t0, inv_dt, k_max, px, py, r2, active, any_active):  # pragma: no cover - compiled
    """``ConstraintTable.free`` of flat ``x``/``y``/``t``: outside every active inflated disc at the
    nearest grid time; ``None`` if a time is NaN (the caller then runs the reference)."""
    out = np.ones(len(x), dtype=np.bool_)
    c_count = px.shape[0]
    for m in range(len(x)):
        if t[m] != t[m]:
            return None
        g = (t[m] - t0) * inv_dt + 0.5
        k = np.int64(min(max(g, 0.0), k_max))
        if not any_active[k]:
            continue
        for c in range(c_count):
            if active[c, k]:
                dx = px[c, k] - x[m]
                dy = py[c, k] - y[m]
                if dx * dx + dy * dy < r2[c]:
                    out[m] = False
                    break
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


__all__ = ["clearance_xy", "constraint_free", "constraint_still_free"]
