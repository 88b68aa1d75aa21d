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
  switch; and ``hold_fraction``, the fraction of the steps from that moment until
  the next switch (or the episode's end) in which every follower was within the
  tolerance (the reached formation *held*, not just touched; ``null`` if it was
  never reached);
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

from swarm_env.compiled import compiled_kernels
from swarm_env.geometry.static_map import _FAST_MAX_POINTS, _SCREEN_MARGIN
from swarm_env.scoring.rewards import slot_distance
from swarm_env.state import CONTACT_KINDS, LEADER_ID, WorldState

# Slack (m) per step of the carried clearance bounds: covers rounding, far below any clearance that matters.
_LIPSCHITZ_SLACK = 1e-9
_NO_VALUES = np.zeros(0)


def _norm(v: np.ndarray, axis: int) -> np.ndarray:
    """``np.linalg.norm(v, axis=axis)`` for real ``v``: the same arithmetic, without its Python overhead."""
    return np.sqrt(np.add.reduce(v * v, axis=axis))


class EpisodeMetrics:
    """Accumulates one episode's metrics; call :meth:`start` then :meth:`update` each step."""

    def __init__(self) -> None:
        self._started = False
        self._pairs: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._static_lb: np.ndarray | None = None  # per follower: a lower bound of its static clearance

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
        self.twist_sum = np.zeros((n + 1, 2))  # summed (v, omega) per robot, the leader last
        self.dist = np.zeros(n + 1)
        self.prev_pos = self._positions(state)
        self.min_sep = math.inf
        self.min_clear = math.inf
        self.leader_arrival: float | None = None
        self.settle: list[dict[str, Any]] = []
        self._switches: set[int] = set()  # the formation indices in settle
        self._pending: dict[str, Any] | None = None
        self._hold: dict[int, list[int]] = {}  # formation index -> [steps since reached, steps held]
        self.terminated = False
        self._static_lb = None
        self._started = True
        self._observe_proximity(state)

    @property
    def v_sum(self) -> np.ndarray:
        return self.twist_sum[:, 0]

    @property
    def w_sum(self) -> np.ndarray:
        return self.twist_sum[:, 1]

    @staticmethod
    def _positions(state: WorldState) -> np.ndarray:
        n = len(state.follower_pose)
        pos = np.empty((n + 1, 2))
        pos[:n] = state.follower_pose[:, :2]
        pos[n] = state.leader_pose[:2]
        return pos

    def update(self, state: WorldState, wall_time: float = 0.0, slot_dist: np.ndarray | None = None) -> None:
        """Account for the step that produced ``state``.

        ``slot_dist``: ``rewards.slot_distance(state)`` if the caller has it already.
        """
        if not self._started:
            raise RuntimeError("EpisodeMetrics.update() called before start()")
        self.steps += 1
        self.sim_time = state.time
        self.wall_time += wall_time
        self.count_contacts(state)
        err = slot_distance(state) if slot_dist is None else slot_dist
        if compiled_kernels():  # the same bits, see swarm_env.scoring.step_kernel
            self._update_compiled(state, err)
            return
        self.err_sum += err
        self.err_max = max(self.err_max, float(err.max(initial=0.0)))
        twist_sum = self.twist_sum
        twist_sum[: self.n] += state.follower_twist
        twist_sum[self.n] += state.leader_twist
        pos = self._positions(state)
        moved = _norm(pos - self.prev_pos, 1)
        self.dist += moved
        self.prev_pos = pos
        if state.leader_done and self.leader_arrival is None:
            self.leader_arrival = state.time
        self._observe_proximity(state, moved[: self.n])
        self._observe_settling(state, err)

    def count_contacts(self, state: WorldState) -> None:
        """Count the contact onsets of ``state`` (part of :meth:`update`; the batched engine, which
        does the rest of the update for all its worlds at once, calls it for worlds with contacts)."""
        for c in state.contacts:
            self.collisions[c.kind] += 1
            self.robot_collisions[c.robot if c.robot != LEADER_ID else self.n] += 1
            if c.kind == "robot_robot":
                self.robot_collisions[c.other if c.other != LEADER_ID else self.n] += 1

    def _update_compiled(self, state: WorldState, err: np.ndarray) -> None:
        """The rest of :meth:`update` with :func:`swarm_env.scoring.step_kernel.metrics_step`: the same
        operations as the numpy code below, in one call."""
        from swarm_env.scoring.step_kernel import Accumulators, Bodies, Screening, metrics_step

        pos = state.follower_pose
        r = state.follower_radius
        lb = self._static_lb
        robot = state.leader_is_robot
        static = state.static
        bodies = Bodies(pos, state.follower_twist, r, state.leader_pose, state.leader_twist,
                        float(state.leader_radius) if robot else 0.0, robot, state.human_pos, state.human_radius)
        err_max, within, sep, hum, lb_out, status, clear = metrics_step(
            err, float(self.tolerance), Accumulators(self.err_sum, self.twist_sum, self.dist, self.prev_pos), bodies,
            _NO_VALUES if lb is None else lb, float(self.min_clear),
            Screening(_LIPSCHITZ_SLACK, _SCREEN_MARGIN, _FAST_MAX_POINTS), static.kernel_arrays())
        self.err_max = max(self.err_max, err_max)
        if state.leader_done and self.leader_arrival is None:
            self.leader_arrival = state.time
        self.min_sep = min(self.min_sep, sep)
        if status < 3:
            self._static_lb = lb_out
            if status == 1:
                self.min_clear = clear
            elif status == 2:
                self.min_clear = static.min_distance(pos[:, :2], r, self.min_clear, lower=lb_out)
            if len(state.human_pos):
                self.min_clear = min(self.min_clear, hum)
        self._observe_settling(state, err, within)

    def _observe_proximity(self, state: WorldState, moved: np.ndarray | None = None) -> None:
        """Lower ``min_sep`` / ``min_clear``; ``moved``: each follower's displacement since the last call."""
        pos = state.follower_pose[:, :2]
        r = state.follower_radius
        if state.leader_is_robot:
            all_pos = np.vstack([pos, state.leader_pose[None, :2]])
            all_r = np.append(r, state.leader_radius)
        else:
            all_pos, all_r = pos, r
        m = len(all_pos)
        if m > 1:
            centres = _norm(all_pos[:, None, :] - all_pos[None, :, :], 2) if m > len(pos) else state.follower_distances()
            d = centres - all_r[:, None] - all_r[None, :]
            iu = self._pairs.get(m)
            if iu is None:
                iu = self._pairs[m] = np.triu_indices(m, 1)
            self.min_sep = min(self.min_sep, float(d[iu].min()))
        if len(pos):
            # Only the running minimum is kept, so the static clearance is computed exactly
            # just for the followers that could lower it (same result as min(distance - r)).
            # A lower bound of each follower's clearance carries over from the last step
            # (the clearance is 1-Lipschitz: it drops by at most the distance moved); while
            # no follower can go below the minimum, nothing at all is computed.
            lb = self._static_lb
            if lb is not None and moved is not None and len(lb) == len(pos):
                lb = lb - moved - _LIPSCHITZ_SLACK
                if (lb - r).min() >= self.min_clear + _LIPSCHITZ_SLACK:
                    self._static_lb = lb
                    lb = None
                else:
                    lb = self._static_lb = state.static.distance_lower_bound(pos)
            else:
                lb = self._static_lb = state.static.distance_lower_bound(pos)
            if lb is not None:
                self.min_clear = state.static.min_distance(pos, r, self.min_clear, lower=lb)
        if len(state.human_pos) and len(pos):
            dh = _norm(pos[:, None, :] - state.human_pos[None, :, :], 2) - r[:, None] - state.human_radius
            self.min_clear = min(self.min_clear, float(dh.min()))

    def _observe_settling(self, state: WorldState, err: np.ndarray, within: bool | None = None) -> None:
        """``within``: ``all(err <= tolerance)`` if the caller has it already."""
        formations = state.scenario.formations
        k = state.formation_index
        if k > 0 and (self._pending is None or self._pending["index"] != k) and k not in self._switches:
            entry = {"index": k, "at": formations[k].at, "shape": formations[k].shape, "settle_time": None}
            self.settle.append(entry)
            self._switches.add(k)
            self._pending = entry
        if within is None:
            within = bool(np.all(err <= self.tolerance))
        if self._pending is not None and self._pending["index"] == k and within:
            self._pending["settle_time"] = round(state.time - self._pending["at"], 9)
            self._pending = None
            self._hold[k] = [0, 0]
        counts = self._hold.get(k)
        if counts is not None:  # the current formation was reached: count the steps it is held
            counts[0] += 1
            counts[1] += within

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
            "settle_times": [{**{k: v for k, v in s.items() if k != "index"}, "hold_fraction": self._hold_fraction(s["index"])}
                             for s in self.settle],
            "min_separation": _finite_or_none(self.min_sep),
            "min_clearance": _finite_or_none(self.min_clear),
            "per_robot": rows,
        }


    def _hold_fraction(self, index: int) -> float | None:
        counts = self._hold.get(index)
        return counts[1] / counts[0] if counts else None


def _finite_or_none(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None
