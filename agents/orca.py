"""ORCA (optimal reciprocal collision avoidance, van den Berg et al. 2011) as an outside reference.

The followers' avoidance comes from RVO2, the reference ORCA library, through its Python binding
`pyrvo <https://pypi.org/project/pyrvo/>`_ (``pip install 'swarm-env[orca]'``); this module only
feeds it and turns its answer into unicycle commands, so that the leaderboard can compare the
project's experts with the method most crowd and swarm papers compare against.

Every step, from the privileged :class:`~swarm_env.state.WorldState` (like ``vo``):

1. **Preferred velocity**: the same formation tracking as ``vo`` in holonomic form: the point
   ``p* = slot + v_slot T`` (the slot led by its own velocity over the time gap ``T``), pursued at
   ``min(|p* - p| / T, v_max)``.
2. **ORCA**: one RVO2 step with every follower as an agent (radius + ``margin``), the robot
   leader and the humans as agents whose preferred velocity is their current one (RVO2 assumes
   every agent shares the avoidance, so the followers under-avoid the humans, who never react:
   that is ORCA's contract, kept as it is), and the static obstacles as RVO2 polygons (circles as
   circumscribed 16-gons) inside the walls.
3. **Unicycle**: the new holonomic velocity ``u`` becomes the pure-pursuit twist towards
   ``p + u T`` (paper 003's Eqs. 3-4, the same law ``vo`` uses), so a velocity behind the robot
   turns it in place first.

Deterministic (RVO2 draws no random numbers). Registered as ``orca``; ``orca:KEY=VALUE,...`` sets
the parameters below.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any

import numpy as np

from swarm_env.checks import finite_numbers, int_in_range
from swarm_env.control.pursuit import pure_pursuit, slot_velocities
from swarm_env.extras import require
from swarm_env.harness.policies import expert_factory
from swarm_env.sim.rvo import simulator
from swarm_env.state import WorldState

if TYPE_CHECKING:
    from swarm_env.env import SwarmEnv

__all__ = ["ORCAPolicy", "make_policy"]

class ORCAPolicy:
    """Formation tracking with RVO2's ORCA for avoidance (see the module docstring).

    Keyword-only parameters: ``time_gap`` (s, the tracking law's ``T``), ``horizon`` (s, ORCA's
    time horizon for other agents), ``horizon_static`` (s, for obstacles), ``neighbor_dist`` (m),
    ``max_neighbors``, ``margin`` (m, added to every radius).

    Raises ``ValueError`` for bad parameters and, from :meth:`reset`, for a discrete-action env.
    """

    def __init__(self, *, time_gap: float = 0.5, horizon: float = 2.0, horizon_static: float = 1.0,
                 neighbor_dist: float = 5.0, max_neighbors: int = 10, margin: float = 0.05) -> None:
        finite_numbers("orca", {"time_gap": time_gap, "horizon": horizon, "horizon_static": horizon_static,
                                "neighbor_dist": neighbor_dist}, positive=True)
        finite_numbers("orca", {"margin": margin}, positive=False)
        int_in_range("orca", {"max_neighbors": max_neighbors}, 1)
        self.time_gap = float(time_gap)
        self.horizon = float(horizon)
        self.horizon_static = float(horizon_static)
        self.neighbor_dist = float(neighbor_dist)
        self.max_neighbors = int(max_neighbors)
        self.margin = float(margin)
        self._sim: Any = None
        self._static: Any = None
        self._times: list[float] = []

    # ------------------------------------------------------------------ Policy protocol
    def reset(self, env: SwarmEnv, seed: int | None) -> None:
        """Start an episode (the RVO2 world is built at the first ``act``). ``seed`` is unused."""
        if getattr(env, "action_type", "continuous") != "continuous":
            raise ValueError("orca drives the continuous action space only (it commands speeds and turn rates); "
                             "make the env with action_type='continuous'")
        require("pyrvo", "orca", "the orca policy")
        self._sim = None
        self._static = None
        self._times = []

    def act(self, observations: dict[str, np.ndarray], state: WorldState) -> dict[str, Any]:
        t0 = time.perf_counter()
        if self._sim is None or self._static is not state.static:
            self._build(state)
        robots = state.scenario.robots
        n = state.n_followers
        sim = self._sim
        pref = self._preferred_velocities(state)
        for i in range(n):
            sim.set_agent_position(i, (float(state.follower_pose[i, 0]), float(state.follower_pose[i, 1])))
            sim.set_agent_velocity(i, (float(state.follower_vel[i, 0]), float(state.follower_vel[i, 1])))
            sim.set_agent_pref_velocity(i, (float(pref[i, 0]), float(pref[i, 1])))
        others = self._others(state)
        for k, (x, y, vx, vy) in enumerate(others.tolist()):
            sim.set_agent_position(n + k, (x, y))
            sim.set_agent_velocity(n + k, (vx, vy))
            sim.set_agent_pref_velocity(n + k, (vx, vy))
        sim.do_step()
        new = np.array([tuple(sim.get_agent_velocity(i).to_tuple()) for i in range(n)], dtype=np.float64).reshape(n, 2)
        target = state.follower_pose[:, :2] + new * self.time_gap
        twist = pure_pursuit(state.follower_pose, target, float(robots.max_speed), float(robots.max_turn_rate),
                             self.time_gap)
        action = np.clip(twist / (robots.max_speed, robots.max_turn_rate), -1.0, 1.0).astype(np.float32)
        self._times.append(time.perf_counter() - t0)
        return {a: action[int(a.rsplit("_", 1)[1])] for a in observations}

    def stats(self) -> dict[str, Any]:
        """Decision time per call (ms): median, p95, max, mean, calls."""
        if not self._times:
            return {"decision_time_ms": None}
        ms = np.array(self._times) * 1e3
        return {"decision_time_ms": {"median": float(np.median(ms)), "p95": float(np.percentile(ms, 95)),
                                     "max": float(ms.max()), "mean": float(ms.mean()), "calls": len(ms)}}

    # ------------------------------------------------------------------ internals
    def _preferred_velocities(self, state: WorldState) -> np.ndarray:
        slots = state.slot_targets
        v_slot = slot_velocities(state.leader_pose, state.leader_vel, float(state.leader_twist[1]), slots)
        want = (slots + v_slot * self.time_gap - state.follower_pose[:, :2]) / self.time_gap
        speed = np.hypot(want[:, 0], want[:, 1])
        v_max = float(state.scenario.robots.max_speed)
        scale = np.where(speed > v_max, v_max / np.maximum(speed, 1e-12), 1.0)
        return want * scale[:, None]

    @staticmethod
    def _others(state: WorldState) -> np.ndarray:
        """``(K, 4)`` ``(x, y, vx, vy)`` of the robot leader (if any) and the humans, in that order."""
        rows = []
        if state.leader_is_robot:
            rows.append([*state.leader_pose[:2], *state.leader_vel])
        rows += [[*p, *v] for p, v in zip(state.human_pos.tolist(), state.human_vel.tolist())]
        return np.array(rows, dtype=np.float64).reshape(-1, 4)

    def _build(self, state: WorldState) -> None:
        robots = state.scenario.robots
        sim = simulator(state.static, float(state.scenario.world.dt), self.neighbor_dist, self.max_neighbors,
                        self.horizon, self.horizon_static, float(robots.radius) + self.margin, float(robots.max_speed),
                        "the orca policy")
        for i in range(state.n_followers):
            sim.add_agent((float(state.follower_pose[i, 0]), float(state.follower_pose[i, 1])))
        if state.leader_is_robot:
            a = sim.add_agent((float(state.leader_pose[0]), float(state.leader_pose[1])))
            sim.set_agent_radius(a, float(state.leader_radius) + self.margin)
            sim.set_agent_max_speed(a, 1e3)  # moves as it will, ORCA only needs its velocity
        for p, r in zip(state.human_pos.tolist(), state.human_radius.tolist()):
            a = sim.add_agent((p[0], p[1]))
            sim.set_agent_radius(a, r + self.margin)
            sim.set_agent_max_speed(a, 1e3)
        self._sim = sim
        self._static = state.static


#: Entry-point factory (``swarm_env.policies`` group, name ``orca``): ``orca[:KEY=VALUE,...]``.
make_policy = expert_factory("orca", ORCAPolicy)
