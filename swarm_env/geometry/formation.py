"""Formation geometry: slot offsets, the formation schedule, slot targets.

Pure functions. Offsets live in the *leader frame*: x forward along the
leader's heading, y to its left (metres). A follower ``k`` is assigned slot
``k`` (the env and experts may re-assign; these functions only give geometry).

Paper 000 (Sec. III-D): the schedule maps a time stamp to a formation; the
targets are the leader's pose composed with the active formation's offsets; a
target inside an obstacle is moved to the nearest free point (least-squares
projection). Paper 003 (Sec. II-C, Eqs. 5-6): the V formation.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from functools import lru_cache

import numpy as np

from swarm_env.geometry.paths import PolylinePath
from swarm_env.geometry.static_map import StaticMap
from swarm_env.scenario import FormationSpec, Scenario

#: Extra clearance (m) beyond the robot radius kept between a slot target and obstacles.
SLOT_MARGIN = 0.05

__all__ = [
    "formation_offsets",
    "active_formation",
    "next_switch_time",
    "slot_targets",
    "arm_unit",
    "reach_time",
    "SHAPES",
]

SHAPES = ("v", "line", "column", "wedge", "diamond", "circle", "grid", "custom")


def arm_unit(spacing: float, angle_deg: float, wedge: bool = False) -> float:
    """Distance between consecutive slots along a ``v``/``wedge`` arm (m).

    ``spacing`` for half-openings ``30 <= angle <= 150`` degrees (exactly paper
    003's ``d``). For narrower V's the left and right slots of a pair would be
    closer than ``spacing`` (their gap is ``2 d sin(angle)``), so the arm step is
    stretched to ``spacing / (2 sin(angle))``. A wedge also needs its rows
    ``2 d |cos(angle)|`` apart, so for wedges it is at least
    ``spacing / (2 |cos(angle)|)`` (binding above 60 degrees).
    """
    phi = math.radians(angle_deg)
    factor = max(1.0, 1.0 / (2.0 * math.sin(phi)))
    if wedge:
        c = abs(math.cos(phi))
        factor = max(factor, 1.0 / (2.0 * c)) if c > 1e-12 else math.inf
    return spacing * factor


def _centre_out(m: int) -> list[int]:
    """Order of the ``m`` lateral positions of a row (0 = leftmost): centre first,
    then alternating left/right outwards, so a partially filled row stays
    near-symmetric."""
    if m <= 0:
        return []
    order = []
    if m % 2 == 1:
        c = m // 2
        order.append(c)
        for k in range(1, c + 1):
            order += [c - k, c + k]
    else:
        left, right = m // 2 - 1, m // 2
        for k in range(m // 2):
            order += [left - k, right + k]
    return order


def _v(n: int, spacing: float, angle: float) -> np.ndarray:
    phi = math.radians(angle)
    unit = arm_unit(spacing, angle)
    k = np.arange(n)
    d = unit * np.ceil((k + 1) / 2.0)
    side = np.where(k % 2 == 0, 1.0, -1.0)  # even k left (+y), odd k right
    return np.column_stack([-d * math.cos(phi), side * d * math.sin(phi)])


def _rows(n: int, row_x, row_width, row_count) -> np.ndarray:
    """Fill rows r = 1, 2, ... (``row_count(r)`` slots evenly between
    ``+row_width(r)/2`` (left) and ``-row_width(r)/2``, at ``x = row_x(r)``) in
    centre-out order until ``n`` slots exist."""
    out: list[tuple[float, float]] = []
    r = 1
    while len(out) < n:
        m = row_count(r)
        x = row_x(r)
        half = row_width(r) / 2.0
        for j in _centre_out(m):
            if len(out) == n:
                break
            y = half - (2.0 * half * j / (m - 1) if m > 1 else half)
            out.append((x, y))
        r += 1
    return np.array(out, dtype=np.float64).reshape(n, 2)


def _wedge(n: int, spacing: float, angle: float) -> np.ndarray:
    phi = math.radians(angle)
    unit = arm_unit(spacing, angle, wedge=True)
    h = unit * math.cos(phi)  # row pitch along x (negative h: rows ahead for angle > 90)
    w = 2.0 * unit * math.sin(phi)  # lateral pitch inside a row
    return _rows(n, lambda r: -r * h, lambda r: r * w, lambda r: r + 1)


def _diamond(n: int, spacing: float) -> np.ndarray:
    # Square lattice rotated 45 degrees with the leader on its front corner:
    # lattice (i, j) -> (-(i + j) a, (i - j) a), a = spacing / sqrt(2), so
    # neighbours are `spacing` apart. The smallest (m+1) x (m+1) diamond with
    # enough slots is filled row by row (depth i + j), centre-out in a row.
    a = spacing / math.sqrt(2.0)
    m = 1
    while (m + 1) ** 2 - 1 < n:
        m += 1
    out: list[tuple[float, float]] = []
    depth = 1
    while len(out) < n:
        lat = [(i, depth - i) for i in range(max(0, depth - m), min(depth, m) + 1)]
        lat.sort(key=lambda ij: -(ij[0] - ij[1]))  # leftmost (largest y) first
        for idx in _centre_out(len(lat)):
            if len(out) == n:
                break
            i, j = lat[idx]
            out.append((-(i + j) * a, (i - j) * a))
        depth += 1
    return np.array(out, dtype=np.float64).reshape(n, 2)


def _circle(n: int, spacing: float) -> np.ndarray:
    radius = spacing if n < 6 else spacing / (2.0 * math.sin(math.pi / n))
    ang = math.pi + 2.0 * math.pi * np.arange(n) / max(n, 1)
    return np.column_stack([radius * np.cos(ang), radius * np.sin(ang)])


def _grid(n: int, spacing: float, columns: int) -> np.ndarray:
    c = columns if columns > 0 else max(1, math.ceil(math.sqrt(n)))
    k = np.arange(n)
    row = k // c
    col = k % c
    full_rows = n // c
    # A partial last row is centred rather than left-aligned.
    m = np.where(row < full_rows, c, n - full_rows * c)
    y = ((m - 1) / 2.0 - col) * spacing
    x = -(row + 1) * spacing
    return np.column_stack([x, y]).astype(np.float64)


@lru_cache(maxsize=256)
def _offsets_cached(spec: FormationSpec, n: int) -> np.ndarray:
    shape = spec.shape
    s = float(spec.spacing)
    if shape == "custom":
        if spec.offsets is None or len(spec.offsets) != n:
            got = None if spec.offsets is None else len(spec.offsets)
            raise ValueError(f"custom formation needs {n} offsets (one per follower), got {got}")
        out = np.array(spec.offsets, dtype=np.float64).reshape(n, 2)
    else:
        if not math.isfinite(s) or s < 0.0:
            raise ValueError(f"formation spacing must be >= 0, got {spec.spacing!r}")
        if n == 0:
            out = np.zeros((0, 2))
        elif shape == "v":
            if not 0.0 < spec.angle < 180.0:
                raise ValueError(f"v formation angle must be in (0, 180) degrees, got {spec.angle!r}")
            out = _v(n, s, float(spec.angle))
        elif shape == "wedge":
            if not 0.0 < spec.angle < 180.0 or spec.angle == 90.0:
                raise ValueError(f"wedge formation angle must be in (0, 180) degrees, not 90, got {spec.angle!r}")
            out = _wedge(n, s, float(spec.angle))
        elif shape == "line":
            y = ((n - 1) / 2.0 - np.arange(n)) * s
            out = np.column_stack([np.full(n, -s), y])
        elif shape == "column":
            out = np.column_stack([-s * (np.arange(n) + 1.0), np.zeros(n)])
        elif shape == "diamond":
            out = _diamond(n, s)
        elif shape == "circle":
            out = _circle(n, s)
        elif shape == "grid":
            if spec.columns < 0:
                raise ValueError(f"grid columns must be >= 0, got {spec.columns!r}")
            out = _grid(n, s, int(spec.columns))
        else:
            raise ValueError(f"unknown formation shape {shape!r}; expected one of {', '.join(SHAPES)}")
    out = np.ascontiguousarray(out, dtype=np.float64)
    out.flags.writeable = False
    return out


def formation_offsets(spec: FormationSpec, n: int) -> np.ndarray:
    """Slot offsets ``(n, 2)`` in the leader frame (x forward, y left), metres.

    ``s = spec.spacing``, ``phi = spec.angle`` (degrees). Shapes:

    * ``v`` — paper 003 Eqs. 5-6. Follower ``k`` sits ``d_k = u * ceil((k+1)/2)``
      along an arm at ``phi`` from the leader's backward axis:
      ``(-d_k cos phi, +d_k sin phi)`` for even ``k`` (left arm),
      ``(-d_k cos phi, -d_k sin phi)`` for odd ``k`` (right arm). The world target
      is then ``x_L - d cos(theta_L -+ phi)``, ``y_L - d sin(theta_L -+ phi)``
      (Eq. 5-6 with ``+phi`` on the right arm). ``u = s`` for
      ``30 <= phi <= 150``; for narrower V's ``u = s / (2 sin phi)`` so a
      left/right pair stays ``s`` apart (see :func:`arm_unit`).
      ``phi > 90`` gives an inverted V ahead of the leader.
    * ``wedge`` — a filled V: row ``r = 1, 2, ...`` at ``x = -r u cos phi`` holds
      ``r + 1`` slots evenly spread between the two arms (so its ends are the
      V's slots); rows fill centre-out. ``u`` is the V's, also stretched to
      ``s / (2 |cos phi|)`` above 60 degrees so rows ``r`` and ``r + 2`` stay
      ``s`` apart. ``phi == 90`` is rejected (rows would coincide).
    * ``line`` — abreast at ``x = -s`` (one spacing behind the leader, so the
      leader is not in the line), ``y = ((n-1)/2 - k) s``: left to right,
      centred on ``y = 0``.
    * ``column`` — single file behind the leader: ``(-(k+1) s, 0)``.
    * ``diamond`` — a square lattice rotated 45 degrees (neighbours ``s`` apart)
      with the leader on its front corner: lattice ``(i, j)`` ->
      ``(-(i+j) s/sqrt2, (i-j) s/sqrt2)``, ``0 <= i, j <= m`` for the smallest
      ``m`` with ``(m+1)^2 - 1 >= n``, filled by depth ``i + j``, centre-out in
      a row. ``n = 3`` is the classic diamond ``(-a, +-a), (-2a, 0)``; ``n = 8``
      fills the 3x3 diamond.
    * ``circle`` — ``n`` slots evenly on a circle around the leader, slot 0
      directly behind it, then counter-clockwise (seen from above) — so some
      slots are ahead of the leader. Radius ``s`` for ``n < 6``, otherwise
      ``s / (2 sin(pi/n))`` (neighbours exactly ``s`` apart).
    * ``grid`` — rows of ``c = spec.columns`` (0: ``ceil(sqrt n)``) slots,
      row ``r`` at ``x = -(r+1) s``, slots ``s`` apart left to right, centred on
      ``y = 0`` (a partial last row is centred too).
    * ``custom`` — ``spec.offsets`` as given.

    For every generated shape with ``s > 0`` the slots are pairwise at least
    ``s`` apart and at least ``s`` from the leader (the origin). ``custom``
    offsets are not checked.

    Raises:
        ValueError: unknown shape, ``custom`` without exactly ``n`` offsets,
            negative spacing, a ``v``/``wedge`` angle outside ``(0, 180)``
            (or 90 for a wedge), negative grid columns.
    """
    if n < 0:
        raise ValueError(f"number of followers must be >= 0, got {n}")
    try:
        return np.array(_offsets_cached(spec, int(n)))
    except TypeError:  # unhashable spec (e.g. offsets given as lists): compute uncached
        return np.array(_offsets_cached.__wrapped__(spec, int(n)))


def reach_time(before: np.ndarray, after: np.ndarray, leader_speed: float, max_speed: float,
               tolerance: float) -> float:
    """A lower bound on the seconds until every follower can be within ``tolerance`` of its new slot.

    ``before`` and ``after`` are the slot offsets ``(n, 2)`` in the leader's frame (x ahead) of follower ``k``
    before and after a switch (slot ``k`` stays follower ``k``'s). A follower's velocity relative to a leader
    going straight at ``leader_speed`` lies in the disc of radius ``max_speed`` around ``(-leader_speed, 0)``:
    along the unit direction ``e`` to its new slot it closes at most at ``c = -v_L e_x + sqrt(v^2 - v_L^2 (1 -
    e_x^2))`` m/s (slowest straight ahead: ``v - v_L``). Turning, acceleration and avoidance only add time."""
    d = np.asarray(after, float) - np.asarray(before, float)
    dist = np.hypot(d[:, 0], d[:, 1])
    need = np.maximum(dist - tolerance, 0.0)
    if not np.any(need > 0):
        return 0.0
    e_x = np.where(dist > 0, d[:, 0] / np.maximum(dist, 1e-12), 0.0)
    closing = -leader_speed * e_x + np.sqrt(np.maximum(max_speed ** 2 - leader_speed ** 2 * (1.0 - e_x ** 2), 0.0))
    with np.errstate(divide="ignore"):
        times = np.where(need > 0, need / np.maximum(closing, 1e-9), 0.0)
    return float(times.max())


def active_formation(formations: Sequence[FormationSpec], t: float) -> int:
    """Index of the formation active at time ``t``: the last entry with ``at <= t``
    (0 if none has started yet). The schedule is expected sorted by ``at``
    (scenario loading enforces it); for a sorted schedule this is the entry
    whose interval ``[at_i, at_{i+1})`` contains ``t``.

    Raises:
        ValueError: empty schedule.
    """
    if len(formations) == 0:
        raise ValueError("formation schedule is empty")
    idx = 0
    for i, f in enumerate(formations):
        if f.at <= t:
            idx = i
    return idx


def next_switch_time(formations: Sequence[FormationSpec], t: float) -> float:
    """``at`` of the first scheduled formation with ``at > t`` (the smallest such
    ``at``), or ``inf`` when no switch is left."""
    later = [float(f.at) for f in formations if f.at > t]
    return min(later) if later else math.inf


def formation_start(
    path: Sequence[Sequence[float]] | np.ndarray,
    offsets: np.ndarray,
    static: StaticMap | None = None,
    clearance: float = 0.0,
) -> np.ndarray:
    """``(n, 3)`` starting poses ``(x, y, theta)`` on the slots of ``offsets`` around a leader
    standing on ``path[0]`` and facing ``path[1]``, each follower facing the leader's heading.
    The one rule for ``robots.start: formation``: the world starts the followers there with the
    slots moved out of obstacles (``static``, ``clearance``: see :func:`slot_targets`); scenario
    validation checks the unprojected slots (``static=None``)."""
    p0 = np.asarray(path[0], dtype=np.float64)
    p1 = np.asarray(path[1], dtype=np.float64)
    d = p1 - p0
    heading = float(np.arctan2(d[1], d[0]))  # as PolylinePath computes it (math.atan2 can differ by an ulp)
    xy = slot_targets(np.array([p0[0], p0[1], heading]), offsets, static, clearance)
    return np.column_stack([xy, np.full(len(xy), heading)])


def slot_targets(
    leader_pose: np.ndarray, offsets: np.ndarray, static: StaticMap | None, clearance: float
) -> np.ndarray:
    """World positions ``(n, 2)`` of the slots for a leader at ``(x, y, theta)``.

    ``target_k = (x, y) + R(theta) offset_k``. A target whose signed clearance
    (``static.distance``, walls included) is below ``clearance`` — typically the
    follower radius plus a margin — is moved to the nearest point with that
    clearance (``static.project_free``), paper 000 Sec. III-D d). Two projected
    slots may end up close to each other; resolving that is the controller's
    job. ``static=None`` skips the projection.
    """
    pose = np.asarray(leader_pose, dtype=np.float64)
    off = np.asarray(offsets, dtype=np.float64).reshape(-1, 2)
    c, s = math.cos(pose[2]), math.sin(pose[2])
    out = np.empty_like(off)
    out[:, 0] = pose[0] + c * off[:, 0] - s * off[:, 1]
    out[:, 1] = pose[1] + s * off[:, 0] + c * off[:, 1]
    if static is not None and out.shape[0] > 0:
        bad = static.distance(out) < clearance
        if np.any(bad):
            out[bad] = static.project_free(out[bad], clearance)
    return out


def virtual_slot_trajectory(
    scn: Scenario, static: StaticMap, steps: int, raw: tuple[np.ndarray, np.ndarray] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """The slot targets a virtual leader gives at ``t = k * dt`` for ``k = 0..steps``.

    Returns ``(slots (steps + 1, N, 2), formation index (steps + 1,))``: exactly what
    :class:`~swarm_env.sim.world.World` computes each step (the same leader, the same
    offsets, the same projection out of obstacles with clearance ``radius +
    SLOT_MARGIN``), for all steps at once. For a robot leader this is its *nominal*
    motion (as if it tracked the path exactly). ``raw`` is a previous
    :func:`unprojected_slot_trajectory` of the same scenario, to project it again
    against another ``static`` without recomputing it.
    """
    pts, index = raw if raw is not None else unprojected_slot_trajectory(scn, steps)
    slots = static.project_free(pts.reshape(-1, 2), scn.robots.radius + SLOT_MARGIN).reshape(pts.shape)
    return slots, index


def unprojected_slot_trajectory(scn: Scenario, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`virtual_slot_trajectory` before the projection out of obstacles.

    Row ``k`` is ``slot_targets(virtual_leader(path, speed, k * dt, start_delay) pose,
    offsets[active_formation(formations, k * dt)], None, 0.0)``; the rows are computed in one compiled
    call (:func:`swarm_env.geometry.slot_kernel.slot_trajectory`, the same bits: the random scenario generator
    asks for a whole episode of them per map, which step by step in Python took ~40 % of a reset).
    """
    from swarm_env.geometry import slot_kernel  # numba: imported where it is first needed, as World does

    line = PolylinePath(scn.leader.path)
    offsets = np.stack([formation_offsets(f, scn.robots.count) for f in scn.formations])
    ats = np.array([f.at for f in scn.formations], dtype=np.float64)
    return slot_kernel.slot_trajectory(slot_kernel.pack_path(line), line.length, scn.leader.speed,
                                       scn.leader.start_delay, scn.world.dt, offsets, ats, steps)
