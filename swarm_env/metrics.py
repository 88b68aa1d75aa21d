"""Episode metrics, accumulated step by step from ``WorldState`` snapshots.

``EpisodeMetrics.result()`` returns a JSON-ready dict:

* ``success`` - the episode terminated (the leader finished its path and the
  formation settled) with zero collisions of any kind;
* ``steps``, ``sim_time`` (s), ``wall_time`` (s spent in ``env.step``);
* ``collisions`` - ``{total, robot_robot, robot_obstacle, robot_human,
  robot_wall}`` counted as contact onsets (a pair that stays in touch for ten
  steps is one collision);
* ``formation_error`` - ``{mean, max, per_robot}``: distance of each follower
  to its slot target (m), averaged over steps (``per_robot``) and over steps
  and followers (``mean``), and the largest single value (``max``);
* ``settle_times`` - one entry per formation switch that happened (schedule
  entries with ``at > 0``): ``{at, shape, settle_time}``, the seconds from the
  switch until every follower was within ``world.settle_tolerance`` of its new
  slot, ``null`` if that never happened before the episode ended or the next
  switch;
* ``min_separation`` - the smallest surface gap between two robots (m, negative
  would mean overlap); ``min_clearance`` - the smallest surface gap between a
  follower and an obstacle, a wall or a human;
* ``per_robot`` - the table of paper 003's Tables II-IV: one row for the
  leader and one per follower with average linear and angular velocity,
  distance travelled, formation error (followers), collisions, and for the
  leader its time to target (s, ``null`` if it never arrived).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from swarm_env.rewards import slot_distance
from swarm_env.state import CONTACT_KINDS, LEADER_ID, WorldState


class EpisodeMetrics:
    """Accumulates one episode's metrics; call :meth:`start` then :meth:`update` each step."""

    def __init__(self) -> None:
        self._started = False

    def start(self, state: WorldState) -> None:
        n = state.n_followers
        self.n = n
        self.tolerance = state.scenario.world.settle_tolerance
        self.steps = 0
        self.sim_time = 0.0
        self.wall_time = 0.0
        self.collisions = {k: 0 for k in CONTACT_KINDS}
        self.robot_collisions = np.zeros(n + 1, dtype=int)  # last entry: the leader
        self.err_sum = np.zeros(n)
        self.err_max = 0.0
        self.v_sum = np.zeros(n + 1)
        self.w_sum = np.zeros(n + 1)
        self.dist = np.zeros(n + 1)
        self.prev_pos = self._positions(state)
        self.min_sep = math.inf
        self.min_clear = math.inf
        self.leader_arrival: float | None = None
        self.settle: list[dict[str, Any]] = []
        self._pending: dict[str, Any] | None = None
        self.terminated = False
        self._started = True
        self._observe_proximity(state)

    @staticmethod
    def _positions(state: WorldState) -> np.ndarray:
        return np.vstack([state.follower_pose[:, :2], state.leader_pose[None, :2]])

    def update(self, state: WorldState, wall_time: float = 0.0) -> None:
        """Account for the step that produced ``state``."""
        if not self._started:
            raise RuntimeError("EpisodeMetrics.update() called before start()")
        self.steps += 1
        self.sim_time = state.time
        self.wall_time += wall_time
        for c in state.contacts:
            self.collisions[c.kind] += 1
            self.robot_collisions[c.robot if c.robot != LEADER_ID else self.n] += 1
            if c.kind == "robot_robot":
                self.robot_collisions[c.other if c.other != LEADER_ID else self.n] += 1
        err = slot_distance(state)
        self.err_sum += err
        self.err_max = max(self.err_max, float(err.max(initial=0.0)))
        self.v_sum[: self.n] += state.follower_twist[:, 0]
        self.w_sum[: self.n] += state.follower_twist[:, 1]
        self.v_sum[self.n] += state.leader_twist[0]
        self.w_sum[self.n] += state.leader_twist[1]
        pos = self._positions(state)
        self.dist += np.linalg.norm(pos - self.prev_pos, axis=1)
        self.prev_pos = pos
        if state.leader_done and self.leader_arrival is None:
            self.leader_arrival = state.time
        self._observe_proximity(state)
        self._observe_settling(state, err)

    def _observe_proximity(self, state: WorldState) -> None:
        pos = state.follower_pose[:, :2]
        r = state.follower_radius
        robots = [np.column_stack([pos, r])]
        if state.leader_is_robot:
            robots.append(np.array([[*state.leader_pose[:2], state.leader_radius]]))
        allr = np.vstack(robots)
        if len(allr) > 1:
            d = np.linalg.norm(allr[:, None, :2] - allr[None, :, :2], axis=2) - allr[:, None, 2] - allr[None, :, 2]
            iu = np.triu_indices(len(allr), 1)
            self.min_sep = min(self.min_sep, float(d[iu].min()))
        clear = state.static.distance(pos) - r
        if len(state.human_pos):
            dh = np.linalg.norm(pos[:, None, :] - state.human_pos[None, :, :], axis=2) - r[:, None] - state.human_radius
            clear = np.minimum(clear, dh.min(axis=1))
        if len(clear):
            self.min_clear = min(self.min_clear, float(clear.min()))

    def _observe_settling(self, state: WorldState, err: np.ndarray) -> None:
        formations = state.scenario.formations
        k = state.formation_index
        if k > 0 and (self._pending is None or self._pending["index"] != k) and not any(
            s["index"] == k for s in self.settle
        ):
            entry = {"index": k, "at": formations[k].at, "shape": formations[k].shape, "settle_time": None}
            self.settle.append(entry)
            self._pending = entry
        if self._pending is not None and self._pending["index"] == k and bool(np.all(err <= self.tolerance)):
            self._pending["settle_time"] = round(state.time - self._pending["at"], 9)
            self._pending = None

    def result(self) -> dict[str, Any]:
        """The JSON-ready metrics dict (see the module docstring)."""
        steps = max(self.steps, 1)
        per_err = self.err_sum / steps
        total = int(sum(self.collisions.values()))
        rows: list[dict[str, Any]] = [
            {
                "robot": "leader",
                "avg_linear_velocity": float(self.v_sum[self.n] / steps),
                "avg_angular_velocity": float(self.w_sum[self.n] / steps),
                "distance": float(self.dist[self.n]),
                "time_to_target": self.leader_arrival,
                "formation_error": None,
                "collisions": int(self.robot_collisions[self.n]),
            }
        ]
        for i in range(self.n):
            rows.append(
                {
                    "robot": f"follower_{i}",
                    "avg_linear_velocity": float(self.v_sum[i] / steps),
                    "avg_angular_velocity": float(self.w_sum[i] / steps),
                    "distance": float(self.dist[i]),
                    "time_to_target": None,
                    "formation_error": float(per_err[i]),
                    "collisions": int(self.robot_collisions[i]),
                }
            )
        return {
            "success": bool(self.terminated and total == 0),
            "steps": self.steps,
            "sim_time": float(self.sim_time),
            "wall_time": float(self.wall_time),
            "collisions": {"total": total, **{k: int(v) for k, v in self.collisions.items()}},
            "formation_error": {
                "mean": float(per_err.mean()) if self.n else 0.0,
                "max": float(self.err_max),
                "per_robot": [float(e) for e in per_err],
            },
            "settle_times": [{k: v for k, v in s.items() if k != "index"} for s in self.settle],
            "min_separation": _finite_or_none(self.min_sep),
            "min_clearance": _finite_or_none(self.min_clear),
            "per_robot": rows,
        }


def _finite_or_none(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None
