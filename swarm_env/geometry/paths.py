"""Polyline paths and the motion of things that follow them exactly.

* :class:`PolylinePath` — an immutable polyline parametrised by arc length ``s``
  (metres from the first point). Used for the leader's path, the humans' paths
  and pure pursuit's carrot (:func:`swarm_env.control.pursuit.lookahead_target`).
* :func:`virtual_leader` — the paper-000 leader: a point moving along the path at
  constant speed, a pure function of time.
* :func:`human_states` — the humans' positions and velocities, a pure function of
  time (modes ``once``, ``loop``, ``pingpong``), so replaying a step or a substep
  never accumulates drift.

Units: metres, seconds, radians. World frame: x right, y up, headings
counter-clockwise from +x.
"""

from __future__ import annotations

import math
from bisect import bisect_left, bisect_right
from collections.abc import Sequence
from functools import lru_cache

import numpy as np

from swarm_env.scenario import HumanSpec

__all__ = ["PolylinePath", "virtual_leader", "human_states"]

# Segments shorter than this are dropped: their heading is undefined.
_MIN_SEGMENT = 1e-9


class PolylinePath:
    """An immutable, arc-length parametrised polyline.

    Args:
        points: at least two ``(x, y)`` points. Consecutive duplicates
            (segments shorter than 1e-9 m) are dropped. If every point
            coincides the path is *degenerate*: ``length == 0``,
            ``point_at`` always returns that point and ``heading_at`` returns 0.

    Attributes (read-only):
        points: ``(M, 2)`` float64 vertices after dropping duplicates.
        length: total arc length (m).
        cumulative: ``(M,)`` arc length at each vertex (``cumulative[0] == 0``).
        headings: ``(M-1,)`` heading (rad) of each segment.

    Raises:
        ValueError: fewer than two points, wrong shape, or non-finite values.
    """

    __slots__ = ("_points", "_cum", "_cum_list", "_seg", "_seglen", "_unit", "_headings", "_length")
    _points: np.ndarray
    _cum: np.ndarray
    _cum_list: list[float]
    _seg: np.ndarray
    _seglen: np.ndarray
    _unit: np.ndarray
    _headings: np.ndarray
    _length: float

    def __init__(self, points: Sequence[tuple[float, float]] | np.ndarray) -> None:
        pts = np.array(points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 2 or pts.shape[0] < 2:
            raise ValueError(f"PolylinePath needs >= 2 points of shape (M, 2), got shape {pts.shape}")
        if not np.all(np.isfinite(pts)):
            raise ValueError("PolylinePath points must be finite")
        seg = np.diff(pts, axis=0)
        keep = np.hypot(seg[:, 0], seg[:, 1]) > _MIN_SEGMENT
        pts = np.vstack([pts[:1], pts[1:][keep]]) if keep.any() else np.vstack([pts[:1], pts[:1]])
        seg = np.diff(pts, axis=0)
        seglen = np.hypot(seg[:, 0], seg[:, 1])
        degenerate = not bool(np.any(seglen > 0.0))
        # Degenerate: one zero-length "segment" with heading 0 (unit vector +x
        # only so that projections are well defined; length is 0 anyway).
        unit = np.array([[1.0, 0.0]]) if degenerate else seg / seglen[:, None]
        cum = np.concatenate([[0.0], np.cumsum(seglen)])
        headings = np.zeros(1) if degenerate else np.arctan2(seg[:, 1], seg[:, 0])
        for a in (pts, seg, seglen, unit, cum, headings):
            a.flags.writeable = False
        object.__setattr__(self, "_points", pts)
        object.__setattr__(self, "_seg", seg)
        object.__setattr__(self, "_seglen", seglen)
        object.__setattr__(self, "_unit", unit)
        object.__setattr__(self, "_cum", cum)
        object.__setattr__(self, "_cum_list", cum.tolist())
        object.__setattr__(self, "_headings", headings)
        object.__setattr__(self, "_length", float(cum[-1]))

    def __setattr__(self, name: str, value: object) -> None:
        raise AttributeError("PolylinePath is immutable")

    def __repr__(self) -> str:
        return f"PolylinePath({self._points.shape[0]} points, length={self._length:.3f})"

    def __reduce__(self):  # pickles via the constructor (slots + immutability)
        return (PolylinePath, (self._points.tolist(),))

    # ------------------------------------------------------------------ fields
    @property
    def points(self) -> np.ndarray:
        return self._points

    @property
    def length(self) -> float:
        return self._length

    @property
    def cumulative(self) -> np.ndarray:
        return self._cum

    @property
    def headings(self) -> np.ndarray:
        return self._headings

    # ---------------------------------------------------------------- queries
    def _segment(self, s: float) -> int:
        """Index of the segment containing arc length ``s`` (already clipped).

        At an interior vertex the *outgoing* segment is returned; at the end
        of the path the last segment.
        """
        i = bisect_right(self._cum_list, s) - 1
        last = len(self._cum_list) - 2
        return 0 if i < 0 else (last if i > last else i)

    def point_at(self, s: float) -> np.ndarray:
        """The ``(2,)`` point at arc length ``s``, ``s`` clipped to ``[0, length]``."""
        s = min(max(float(s), 0.0), self._length)
        i = self._segment(s)
        a = self._points[i]
        ds = s - self._cum_list[i]
        u = self._unit[i]
        return np.array([a[0] + ds * u[0], a[1] + ds * u[1]])

    def points_at(self, s: np.ndarray) -> np.ndarray:
        """Vectorised :meth:`point_at`: ``(K,)`` arc lengths -> ``(K, 2)`` points."""
        s = np.clip(np.asarray(s, dtype=np.float64), 0.0, self._length)
        i = np.clip(np.searchsorted(self._cum, s, side="right") - 1, 0, len(self._seglen) - 1)
        return self._points[i] + (s - self._cum[i])[..., None] * self._unit[i]

    def heading_at(self, s: float) -> float:
        """Heading (rad, in ``[-pi, pi]``) of the segment at arc length ``s``.

        At an interior vertex the outgoing segment's heading; beyond the ends
        the first/last segment's heading.
        """
        s = min(max(float(s), 0.0), self._length)
        return float(self._headings[self._segment(s)])

    def heading_before(self, s: float) -> float:
        """Like :meth:`heading_at` but at an interior vertex the *incoming* segment's heading."""
        s = min(max(float(s), 0.0), self._length)
        i = bisect_left(self._cum_list, s) - 1
        i = min(max(i, 0), len(self._cum_list) - 2)
        return float(self._headings[i])

    def project(self, p: np.ndarray, s_min: float = 0.0, s_max: float | None = None) -> float:
        """Arc length of the point of the path closest to ``p`` within ``[s_min, s_max]``.

        ``s_max=None`` means ``length``; both bounds are clipped to
        ``[0, length]`` (and ``s_max`` to at least ``s_min``). Ties (a point
        equidistant from two parts of the path) resolve to the smallest ``s``,
        which keeps progress along self-crossing paths monotone.
        """
        length = self._length
        lo = min(max(float(s_min), 0.0), length)
        hi = length if s_max is None else min(max(float(s_max), lo), length)
        cum = self._cum
        # Per segment: the admissible arc-length interval, the unconstrained
        # foot of the perpendicular, clipped into that interval.
        seg_lo = np.maximum(cum[:-1], lo)
        seg_hi = np.minimum(cum[1:], hi)
        valid = seg_lo <= seg_hi
        q = np.asarray(p, dtype=np.float64)[:2] - self._points[:-1]
        t = q[:, 0] * self._unit[:, 0] + q[:, 1] * self._unit[:, 1]
        s_cand = np.clip(cum[:-1] + t, seg_lo, np.maximum(seg_hi, seg_lo))
        along = s_cand - cum[:-1]
        dx = q[:, 0] - along * self._unit[:, 0]
        dy = q[:, 1] - along * self._unit[:, 1]
        d2 = np.where(valid, dx * dx + dy * dy, np.inf)
        if not np.any(valid):  # only when lo == hi at a vertex with rounding; fall back to lo
            return lo
        return float(s_cand[int(np.argmin(d2))])


def virtual_leader(
    path: PolylinePath, speed: float, t: float, start_delay: float = 0.0
) -> tuple[np.ndarray, np.ndarray, bool]:
    """The paper-000 virtual leader at time ``t``: constant ``speed`` along ``path``.

    It waits on the first point (heading of the first segment) until
    ``start_delay``, then travels ``s = speed * (t - start_delay)`` metres.

    Returns:
        pose: ``(3,)`` ``(x, y, heading)``; the heading is the direction of the
            segment under the leader (the last segment once done).
        velocity: ``(2,)`` world-frame velocity; zero before ``start_delay`` and
            once done.
        done: ``True`` once the leader has reached the end of the path
            (``s >= length``); a degenerate path is done immediately.
    """
    moved = max(float(t) - float(start_delay), 0.0) * float(speed)
    length = path.length
    done = moved >= length
    s = min(moved, length)
    p = path.point_at(s)
    h = path.heading_at(s)
    moving = (not done) and float(t) >= float(start_delay) and speed > 0.0
    v = float(speed) if moving else 0.0
    return (
        np.array([p[0], p[1], h]),
        np.array([v * math.cos(h), v * math.sin(h)]),
        bool(done),
    )


@lru_cache(maxsize=512)
def _human_path(points: tuple[tuple[float, float], ...], closed: bool) -> PolylinePath:
    """Cached path of a human (HumanSpec is frozen, so its path tuple is a key).

    ``closed`` appends the first point so that ``loop`` walks the closing segment.
    """
    pts = list(points)
    if closed and (pts[0][0] != pts[-1][0] or pts[0][1] != pts[-1][1]):
        pts.append(pts[0])
    if len(pts) == 1:
        pts.append(pts[0])
    return PolylinePath(pts)


def human_paths(humans: Sequence[HumanSpec]) -> list[PolylinePath]:
    """Each human's walking path (for ``loop``, closed), as :func:`human_states` walks it; a
    caller stepping the same humans many times (a :class:`~swarm_env.sim.world.World`) passes them
    in rather than relying on the shared cache, which thrashes with more than 512 paths."""
    out = []
    for h in humans:
        try:
            out.append(_human_path(h.path, h.mode == "loop"))
        except TypeError:  # unhashable (lists): normalise to a tuple key
            out.append(_human_path(tuple((float(x), float(y)) for x, y in h.path), h.mode == "loop"))
    return out


def human_states(humans: Sequence[HumanSpec], t: float, paths: Sequence[PolylinePath] | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Positions ``(H, 2)`` and world velocities ``(H, 2)`` of the humans at time ``t``.

    A pure function of ``t``. Each human stands on its first waypoint (zero
    velocity) until ``start_delay``, then walks ``d = speed * (t - start_delay)``
    metres:

    * ``once``: along the path, then stands on the last waypoint (zero velocity).
    * ``loop``: along the path and back to the first waypoint along the closing
      segment, forever (``s = d mod loop_length``).
    * ``pingpong``: along the path and back the same way, forever
      (period ``2 * length``; the velocity is reversed on the way back).

    At a vertex the velocity is that of the outgoing segment. A human with a
    zero-length path or zero speed stands still. ``paths``: :func:`human_paths` of ``humans``,
    if the caller keeps them.
    """
    n = len(humans)
    pos = np.zeros((n, 2))
    vel = np.zeros((n, 2))
    for k, (h, path) in enumerate(zip(humans, human_paths(humans) if paths is None else paths)):
        length = path.length
        elapsed = float(t) - float(h.start_delay)
        if elapsed <= 0.0 or h.speed <= 0.0 or length <= 0.0:
            pos[k] = path.points[0]
            continue
        d = h.speed * elapsed
        sign = 1.0
        if h.mode == "once":
            if d >= length:
                pos[k] = path.points[-1]
                continue
            s = d
        elif h.mode == "loop":
            s = math.fmod(d, length)
        elif h.mode == "pingpong":
            u = math.fmod(d, 2.0 * length)
            if u < length:
                s = u
            else:  # walking back: position at 2L - u, heading reversed
                s, sign = 2.0 * length - u, -1.0
        else:
            raise ValueError(f"unknown human mode {h.mode!r}; expected one of once, loop, pingpong")
        pos[k] = path.point_at(s)
        # Walking back, the segment under the human is the one *ending* at s
        # when s sits on a vertex.
        heading = path.heading_at(s) if sign > 0 else path.heading_before(s)
        vel[k] = (sign * h.speed * math.cos(heading), sign * h.speed * math.sin(heading))
    return pos, vel
