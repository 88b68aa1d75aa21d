"""Gates: walls across the leader's path, each with a door that the formation files through as a column.

What the generator's ``n_gates`` knob adds to a world (units m, s; the ``narrow`` family uses it):

* A **gate** stands across a straight stretch of the leader's path: two walls, rectangles ``depth`` long along
  the path, one on each side of a door ``width`` wide centred on the path. A deep gate is a corridor. Each wall
  reaches :data:`WALL_REACH` m beyond the widest slot of the formation, so the formation cannot pass beside the
  door, and stops short of the world's walls by a robot's passage.
* The formation schedule gains a **column** (the formation's spacing) before each door, ordered early enough
  that it can be reached ``reach`` times over (:func:`~swarm_env.geometry.formation.reach_time`) before the
  leader is at the door, and the formation before it again once the column's last slot is past the gate. Gates
  too close for that share one column; a column that cannot be left in time is kept to the end.
* The path is straight from where the column is settled until it has passed the gate, so the column's slots run
  through the door: a slot target never has to jump across a wall (the generator checks every slot's speed
  over the whole episode afterwards and drops a gate that makes one jump, see
  :func:`swarm_env.scenarios.generator.slot_speed_violations`).

Everything is drawn from the ``rng`` given, a bounded number of times (:data:`ATTEMPTS` per gate): a world with
no room for a gate gets fewer gates, never an endless loop.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from swarm_env.geometry.formation import SLOT_MARGIN, formation_offsets, reach_time
from swarm_env.geometry.paths import PolylinePath
from swarm_env.geometry.static_map import StaticMap, rotate_rectangle
from swarm_env.scenario import FormationSpec, RectangleObstacle, WorldSpec

__all__ = ["Gate", "GateLayout", "place_gates", "gate_schedule", "column_of", "ATTEMPTS", "WALL_REACH"]

#: Candidate positions tried per gate before the world gets one gate fewer.
ATTEMPTS = 40
#: How far (m) a wall reaches beyond the formation's widest slot disc (sideways from the path).
WALL_REACH = 1.0
# Leader travel (m) kept between the door's faces and where the column must be whole (before) or may end (after).
_MARGIN = 0.5
# Leader travel (m) before the first column order: the starting formation is held for a while.
_FIRST_ORDER = 1.0


def column_of(formation: FormationSpec) -> FormationSpec:
    """The column a gate asks for: ``formation``'s spacing, one slot behind the other."""
    return FormationSpec(at=0.0, shape="column", spacing=formation.spacing)


@dataclass(frozen=True)
class Gate:
    """One gate on the leader's path.

    Attributes:
        s: arc length (m) of the door's middle along the leader's path.
        depth: the walls' length along the path (m); a corridor when deep.
        width: the door's width (m).
        order: leader arc length at which the column is ordered.
        release: leader arc length at which the formation before it comes back.
        walls: the two wall rectangles, left of the path first.
        footprint: one rectangle over both walls and the door (what walkers keep away from: a walker standing
            in a door would close it).
    """

    s: float
    depth: float
    width: float
    order: float
    release: float
    walls: tuple[RectangleObstacle, RectangleObstacle]
    footprint: RectangleObstacle


@dataclass(frozen=True)
class GateLayout:
    """What :func:`place_gates` needs of the world and the robots.

    Attributes:
        size: the world ``(W, H)``.
        radius: the robots' disc radius.
        leader_speed, max_speed: the leader's speed and the followers' top speed (m/s).
        leader_clear: clearance a wall keeps from the leader's path outside its door (m).
        reach: how many times its reach time a column switch (and the switch back) gets.
        width, depth: the ranges the door width and the wall depth are drawn from.
        keep: ``(points (K, 2), clearance (K,))`` a wall must keep from (the robots' starting discs).
        end: the episode's length (s): a column that cannot be left in time before it stays to the end.
    """

    size: tuple[float, float]
    radius: float
    leader_speed: float
    max_speed: float
    leader_clear: float
    reach: float
    width: tuple[float, float]
    depth: tuple[float, float]
    keep: tuple[np.ndarray, np.ndarray]
    end: float


def _back_time(formation: FormationSpec, n: int, layout: GateLayout) -> float:
    """``layout.reach`` times the reach time from the column back to ``formation``."""
    return layout.reach * reach_time(formation_offsets(column_of(formation), n), formation_offsets(formation, n),
                                     layout.leader_speed, layout.max_speed, WorldSpec.settle_tolerance)


def place_gates(rng: np.random.Generator, line: PolylinePath, count: int, formation: FormationSpec, n: int,
                layout: GateLayout) -> list[Gate]:
    """Up to ``count`` gates on ``line`` for ``n`` followers in ``formation``, in the order they were placed.

    Each gate's column stretch, from where its column is ordered to where it may end, lies on one straight
    segment of ``line`` (to the path's end where the column cannot be left before ``layout.end``: a column turns
    too fast for its last slots) and overlaps no other gate's; its walls keep ``layout.leader_clear`` from the rest of the
    path, ``layout.keep``'s clearances from its points and a robot's passage from the world's walls and the other
    gates' walls."""
    v = layout.leader_speed
    tol = WorldSpec.settle_tolerance
    clear = layout.radius + SLOT_MARGIN
    offsets = formation_offsets(formation, n)
    column = formation_offsets(column_of(formation), n)
    widest = float(np.max(np.hypot(offsets[:, 0], offsets[:, 1]), initial=0.0))
    ahead = max(float(np.max(offsets[:, 0], initial=0.0)), 0.0)  # slots ahead of the leader meet a wall first
    to_column = 0.0 if formation.shape == "column" else layout.reach * reach_time(
        offsets, column, v, layout.max_speed, tol)
    whole_before = ahead + clear + _MARGIN  # the column is whole this far (leader travel) before the near face
    lead_in = whole_before + v * to_column
    lead_out = max(n * formation.spacing, widest) + clear + _MARGIN  # the last slot, or any slot after, is past
    back = _back_time(formation, n, layout)
    reach_out = widest + layout.radius + WALL_REACH  # a wall's far end, sideways from the path
    gap = 2.0 * layout.radius + 0.2  # a robot passes between a wall and the world's wall, or another gate's
    cum = line.cumulative
    samples_s = np.linspace(0.0, line.length, max(2, int(math.ceil(line.length / 0.1)) + 1))
    samples = line.points_at(samples_s)
    placed: list[Gate] = []
    walls_map: StaticMap | None = None
    for _ in range(count):
        for _attempt in range(ATTEMPTS):
            depth = round(float(rng.uniform(*layout.depth)), 3)
            width = round(float(rng.uniform(*layout.width)), 3)
            # The column's stretch [s - depth/2 - lead_in, s + depth/2 + lead_out] lies within one segment (a
            # rounded corner is many short ones; a column's last slots would swing too fast there): s is drawn
            # uniformly over the segments' room for it.
            lo = cum[:-1] + depth / 2.0 + lead_in
            room = np.maximum(cum[1:] - depth / 2.0 - lead_out - lo, 0.0)
            if not np.any(room > 0.0):
                continue
            u = float(rng.uniform(0.0, float(room.sum())))
            upto = np.cumsum(room)  # the room of segments 0..k
            seg = min(int(np.searchsorted(upto, u, side="right")), len(room) - 1)
            s = float(lo[seg] + min(u - (float(upto[seg]) - room[seg]), room[seg]))
            order, release = s - depth / 2.0 - lead_in, s + depth / 2.0 + lead_out
            if order < _FIRST_ORDER:
                continue
            if release / v + back > layout.end and seg != len(room) - 1:
                continue  # the column stays to the end: the path must not turn after it
            start = s - depth / 2.0 - whole_before
            if any(start - _MARGIN < g.release and g.s - g.depth / 2.0 - whole_before - _MARGIN < release for g in placed):
                continue  # the door stretches overlap (close gates share a column: their windows may)
            built = _walls(line, s, depth, width, reach_out, gap, layout.size)
            if built is None:
                continue
            walls, footprint = built
            one = StaticMap.from_obstacles(layout.size, walls)
            dist = one.obstacle_distances(samples).min(axis=1)
            outside = np.abs(samples_s - s) > depth / 2.0 + 0.05
            if np.any(dist[outside] < layout.leader_clear):
                continue  # a wall across another part of the path
            points, need = layout.keep
            if len(points) and np.any(one.obstacle_distances(points).min(axis=1) < need):
                continue
            if walls_map is not None and np.any(walls_map.obstacle_distances(_outline(walls)).min(axis=1) < gap):
                continue
            placed.append(Gate(s=s, depth=depth, width=width, order=order, release=release, walls=walls,
                               footprint=footprint))
            walls_map = StaticMap.from_obstacles(layout.size, [w for g in placed for w in g.walls])
            break
    return placed


def gate_schedule(formation: FormationSpec, gates: Sequence[Gate], n: int, layout: GateLayout,
                  dt: float) -> list[FormationSpec]:
    """The formation schedule with ``gates``: ``formation`` at t = 0, a column from each gate's order to its
    release (on the ``dt`` grid; leader time = arc length / speed), ``formation`` again after it when there is
    ``layout.reach`` times the reach time left before the next column (or the episode's end, ``layout.end``); else the
    column is kept."""
    if formation.shape == "column" or not gates:
        return [formation]
    v = layout.leader_speed
    back = _back_time(formation, n, layout)
    windows: list[list[float]] = []
    for gate in sorted(gates, key=lambda g: g.order):
        on, off = gate.order / v, gate.release / v
        if windows and on < windows[-1][1] + back:
            windows[-1][1] = max(windows[-1][1], off)
        else:
            windows.append([on, off])
    out = [formation]
    for on, off in windows:
        out.append(dataclasses.replace(column_of(formation), at=round(max(math.floor(on / dt), 1) * dt, 6)))
        release = round(math.ceil(off / dt) * dt, 6)
        if release + back > layout.end:
            break  # no time to settle back: the column stays
        out.append(dataclasses.replace(formation, at=release))
    return out


def _walls(line: PolylinePath, s: float, depth: float, width: float, reach_out: float, gap: float,
           size: tuple[float, float]) -> tuple[tuple[RectangleObstacle, RectangleObstacle], RectangleObstacle] | None:
    """The two walls of a gate at arc length ``s`` (left, right) and the gate's footprint, or None where a wall
    would be shorter than a robot could tell from the world's wall."""
    heading = line.heading_at(s)
    centre = line.point_at(s)
    normal = np.array([-math.sin(heading), math.cos(heading)])
    along = np.array([math.cos(heading), math.sin(heading)])
    inner = width / 2.0
    out: list[RectangleObstacle] = []
    reach: list[float] = []
    for side in (1.0, -1.0):
        # Corners of the wall's outer end must stay gap inside the world: shorten the wall until they do.
        outer = reach_out
        while outer > inner:
            ends = [centre + side * outer * normal + k * depth / 2.0 * along for k in (-1.0, 1.0)]
            if all(gap <= p[0] <= size[0] - gap and gap <= p[1] <= size[1] - gap for p in ends):
                break
            outer -= 0.1
        if outer - inner < 0.2:
            return None
        reach.append(outer)
        mid = np.round(centre + side * (inner + outer) / 2.0 * normal, 3)
        out.append(RectangleObstacle(center=(float(mid[0]), float(mid[1])),
                                     size=(round(depth, 3), round(outer - inner, 3)),
                                     angle=round(math.degrees(heading), 3)))
    mid = np.round(centre + (reach[0] - reach[1]) / 2.0 * normal, 3)
    footprint = RectangleObstacle(center=(float(mid[0]), float(mid[1])), size=(round(depth, 3), round(sum(reach), 3)),
                                  angle=round(math.degrees(heading), 3))
    return (out[0], out[1]), footprint


def _outline(walls: Sequence[RectangleObstacle]) -> np.ndarray:
    """Points every 0.1 m along the edges of the ``walls`` (to measure how close other walls come)."""
    pts: list[np.ndarray] = []
    for w in walls:
        corners = list(rotate_rectangle(w.center, w.size, w.angle))
        for p, q in zip(corners, corners[1:] + corners[:1]):
            k = max(2, int(math.ceil(float(np.linalg.norm(q - p)) / 0.1)) + 1)
            pts.append(p + np.linspace(0.0, 1.0, k)[:, None] * (q - p))
    return np.vstack(pts)
