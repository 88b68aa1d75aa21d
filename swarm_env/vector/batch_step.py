"""The batched engine's rewards, metrics and observations of ``M`` worlds, one compiled call per stage.

:class:`BatchState` holds, as rows of ``(M, ...)`` arrays, what a :class:`~swarm_env.env.SwarmEnv`
keeps between steps for these stages: the previous slot distances and actions (the reward's
``prev_dist``/``prev_action``), the numeric accumulators of its
:class:`~swarm_env.scoring.metrics.EpisodeMetrics` (steps, times, summed errors and twists, distances
travelled, last positions, the running minima and the carried static clearance bounds, and the
step count of the formation being held), and each episode's constants (team radii, humans' radii,
reward weights, settle tolerance, limits, the static map as :class:`PaddedMaps`). :meth:`step`
then runs, for all worlds at once, :func:`swarm_env.vector.batch_kernel.rewards_batch`,
:func:`~swarm_env.sensing.obs_kernel.observations_batch` and
:func:`~swarm_env.vector.batch_kernel.metrics_batch`, and the episode end, with Python only where
something happens in a world (contacts, a formation switch or settling, the leader arriving, the
episode's end): the same bits as each world's ``SwarmEnv._advance`` + ``_account`` + observations.
:meth:`BatchState.state` gives every world's global state (``SwarmEnv.state()``) in one call of
:func:`swarm_env.sensing.state_kernel.state_batch` (it keeps each world's occupancy grid as a row).

Ownership: while the engine steps, the rows are the truth and the worlds' own ``EpisodeMetrics``
and ``_prev_dist``/``_prev_action`` lag behind; :meth:`BatchState.store` writes a row back into its
world (the engine does it before a world's final metrics and before any per-world ``call``,
``get_attr`` or ``set_attr``), :meth:`BatchState.load` reads a world into its row (after a reset, a
``set_world``, or anything that may have changed the world). Contacts, collision counts, the
formation switches' records and the leader's arrival time stay in the ``EpisodeMetrics`` objects
(they change rarely and are updated there directly).

Imports no numba itself: the kernels load on the first :meth:`BatchState.step`, which the engine
calls only with :func:`swarm_env.compiled.compiled_kernels` on (worker processes without
``worker_kernels`` keep the per-world numpy references).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from swarm_env.env import _INFO_KEYS
from swarm_env.geometry.map_arrays import MapBatch
from swarm_env.geometry.static_map import _FAST_MAX_POINTS, _SCREEN_MARGIN, StaticMap
from swarm_env.scoring.metrics import _LIPSCHITZ_SLACK
from swarm_env.scoring.rewards import (
    CONTACT_GROUPS,
    REWARD_TERMS,
    approach_gap,
    new_contacts_per_follower,
    touching_per_follower,
)
from swarm_env.scoring.weights import W_APPROACH, W_COLLISION, W_CONTACT, WEIGHT_COLUMNS, reward_weights
from swarm_env.sensing.layout import STATE_GRID
from swarm_env.sensing.observations import _GRADIENT_STEP, STATE_CLEARANCE_RANGE, STATE_LIMIT
from swarm_env.state import WorldState

if TYPE_CHECKING:
    from swarm_env.env import SwarmEnv
    from swarm_env.sensing.lidar import LidarRows

__all__ = ["BatchState", "PaddedMaps", "StepArrays"]


class PaddedMaps:
    """The static maps of ``M`` worlds as :mod:`swarm_env.geometry.clearance_kernel` takes them, one padded row
    per world (``bound`` ``(M, B, 3)`` with ``nbound``, ``circles`` ``(M, C, 3)`` with ``ncirc``, the
    polygon edge arrays ``(M, E)`` of which ``n_poly * n_edge`` are used, ``W``/``H`` ``(M,)``).

    A world's row is rewritten only when its map object changes (:meth:`set`), and the padding grows
    when a map needs more room, so a step in which a few worlds start a new episode costs a few rows,
    not a repacking of all ``M`` maps."""

    _EDGE_KEYS = ("ax", "ay", "ex", "ey", "inv_ee", "nx", "ny")

    def __init__(self, m: int) -> None:
        self.m = m
        self.rows: list[StaticMap | None] = [None] * m
        self.W = np.zeros(m)
        self.H = np.zeros(m)
        self.nbound = np.zeros(m, np.int64)
        self.ncirc = np.zeros(m, np.int64)
        self.n_poly = np.zeros(m, np.int64)
        self.n_edge = np.zeros(m, np.int64)
        self.bound = np.zeros((m, 1, 3))
        self.circles = np.zeros((m, 1, 3))
        self.edges = {k: np.zeros((m, 1)) for k in self._EDGE_KEYS}

    def set(self, b: int, static: StaticMap) -> None:
        """Make row ``b`` the map ``static`` (nothing to do if it already is)."""
        if self.rows[b] is static:
            return
        W, H, bound, circles, P, Me, *edges = static.kernel_arrays()  # a MapArrays
        self._room(len(bound), len(circles), len(edges[0]))
        self.W[b], self.H[b] = W, H
        self.nbound[b], self.ncirc[b], self.n_poly[b], self.n_edge[b] = len(bound), len(circles), P, Me
        self.bound[b, :len(bound)] = bound
        self.circles[b, :len(circles)] = circles
        for k, a in zip(self._EDGE_KEYS, edges):
            self.edges[k][b, :len(a)] = a
        self.rows[b] = static

    def _room(self, nb: int, nc: int, ne: int) -> None:
        def grown(a: np.ndarray, need: int) -> np.ndarray:
            if a.shape[1] >= need:
                return a
            out = np.zeros((a.shape[0], need, *a.shape[2:]))
            out[:, :a.shape[1]] = a
            return out

        self.bound = grown(self.bound, nb)
        self.circles = grown(self.circles, nc)
        self.edges = {k: grown(a, ne) for k, a in self.edges.items()}

    def kernel_arrays(self) -> MapBatch:
        """The worlds' maps as the batch kernels take them."""
        return MapBatch(self.W, self.H, self.bound, self.nbound, self.circles, self.ncirc, self.n_poly, self.n_edge,
                        *(self.edges[k] for k in self._EDGE_KEYS))


class WorldRows(NamedTuple):
    """The arrays of :class:`StepArrays` as the batch kernels read them (by name), stacked on a world axis."""

    pose: np.ndarray
    vel: np.ndarray
    twist: np.ndarray
    slots: np.ndarray
    lpose: np.ndarray
    lvel: np.ndarray
    ltwist: np.ndarray
    time: np.ndarray
    k: np.ndarray
    next_switch: np.ndarray
    hpos: np.ndarray
    hvel: np.ndarray


class BatchBodies(NamedTuple):
    """The worlds' bodies that stay for an episode (rows of :class:`BatchState`): the followers' ``radius``
    ``(M, N)``, the leader's ``lradius`` and whether it is a robot ``lrobot`` ``(M,)``, the humans' radii
    ``hrad`` ``(M, Hmax)`` and counts ``hcount`` ``(M,)``."""

    radius: np.ndarray
    lradius: np.ndarray
    lrobot: np.ndarray
    hrad: np.ndarray
    hcount: np.ndarray


class MetricRows(NamedTuple):
    """``EpisodeMetrics``' accumulators of the worlds as rows of :class:`BatchState` (updated in place by
    :func:`swarm_env.vector.batch_kernel.metrics_batch`)."""

    err_sum: np.ndarray
    twist_sum: np.ndarray
    travelled: np.ndarray
    prev_pos: np.ndarray
    lb: np.ndarray
    lb_valid: np.ndarray
    min_clear: np.ndarray
    min_sep: np.ndarray
    err_max: np.ndarray
    steps: np.ndarray
    sim_time: np.ndarray
    wall_time: np.ndarray
    last_k: np.ndarray
    pending_k: np.ndarray
    hold_key: np.ndarray
    hold_n: np.ndarray
    hold_in: np.ndarray


class StepArrays:
    """The per-step arrays of ``M`` snapshots (what the stages read), stacked on a world axis: those of
    :class:`WorldRows` (:meth:`rows`), each world's ``step`` and ``leader_done``, and the worlds whose snapshot has
    pairs in touch (``touching``) or contact onsets (``contacts``)."""

    step: np.ndarray
    leader_done: np.ndarray
    touching: list[int]
    contacts: list[int]

    def __init__(self, states: Sequence[WorldState], hmax: int, hcount: np.ndarray) -> None:
        m = len(states)
        n = len(states[0].follower_pose)
        # np.concatenate then a reshape: np.stack's per-array views cost it four times as much.
        self.pose = np.concatenate([s.follower_pose for s in states]).reshape(m, n, 3)
        self.vel = np.concatenate([s.follower_vel for s in states]).reshape(m, n, 2)
        self.twist = np.concatenate([s.follower_twist for s in states]).reshape(m, n, 2)
        self.slots = np.concatenate([s.slot_targets for s in states]).reshape(m, n, 2)
        self.lpose = np.concatenate([s.leader_pose for s in states]).reshape(m, 3)
        self.lvel = np.concatenate([s.leader_vel for s in states]).reshape(m, 2).astype(np.float64, copy=False)
        self.ltwist = np.concatenate([s.leader_twist for s in states]).reshape(m, 2)
        self.time = np.array([s.time for s in states], dtype=np.float64)
        self.step = np.array([s.step for s in states], dtype=np.int64)
        self.leader_done = np.array([s.leader_done for s in states], dtype=bool)
        self.k = np.array([s.formation_index for s in states], dtype=np.int64)
        self.next_switch = np.array([s.next_switch_time for s in states], dtype=np.float64)
        self.touching = [b for b, s in enumerate(states) if s.touching]
        self.contacts = [b for b in self.touching if states[b].contacts]
        self.hpos = np.zeros((m, hmax, 2))
        self.hvel = np.zeros((m, hmax, 2))
        if hmax and hcount.any():
            total = sum(len(s.human_pos) for s in states)
            if total != hcount.sum():  # the counts are an episode's constants, loaded at its start
                raise RuntimeError(f"the worlds have {total} humans, the batch's rows {int(hcount.sum())}")
            if (hcount == hmax).all():
                self.hpos = np.concatenate([s.human_pos for s in states]).reshape(m, hmax, 2)
                self.hvel = np.concatenate([s.human_vel for s in states]).reshape(m, hmax, 2)
            else:  # padded: world w's humans in its first hcount[w] rows
                world = np.repeat(np.arange(m), hcount)
                slot = np.arange(len(world)) - np.repeat(np.cumsum(hcount) - hcount, hcount)
                self.hpos[world, slot] = np.concatenate([s.human_pos for s in states])
                self.hvel[world, slot] = np.concatenate([s.human_vel for s in states])

    def rows(self) -> WorldRows:
        """The arrays as one bundle for the kernels."""
        return WorldRows(*(getattr(self, name) for name in WorldRows._fields))

    @classmethod
    def of_blocks(cls, blocks: dict[str, Any], hmax: int, hcount: np.ndarray) -> StepArrays:
        """The same arrays from :meth:`swarm_env.vector.world_batch.WorldBatch.last_arrays` (the physics
        kernel's stacked blocks: no per-world array to gather), humans padded to ``hmax`` rows."""
        self = cls.__new__(cls)
        if not np.array_equal(blocks["hcount"], hcount):  # the counts are an episode's constants, loaded at its start
            raise RuntimeError(f"the worlds have {int(blocks['hcount'].sum())} humans, the batch's rows "
                               f"{int(hcount.sum())}")
        for key in ("pose", "vel", "twist", "slots", "lpose", "lvel", "ltwist", "time", "step", "leader_done", "k",
                    "next_switch", "touching", "contacts"):
            setattr(self, key, blocks[key])
        for key in ("hpos", "hvel"):
            got = blocks[key]
            if got.shape[1] != hmax:  # (the physics pads to the most humans of a world, the rows to capacity)
                out = np.zeros((len(got), hmax, 2))
                out[:, :got.shape[1]] = got
                got = out
            setattr(self, key, got)
        return self


class BatchState:
    """``M`` worlds' between-step state for the batched stages (module docstring)."""

    def __init__(self, envs: Sequence[SwarmEnv]) -> None:
        m = len(envs)
        n = len(envs[0].possible_agents)
        self.m, self.n = m, n
        self.hmax = max(e.capacity.max_humans for e in envs)
        obs = envs[0]._obs
        # One observation builder's bounds serve every world when they all agree (the engine's worlds
        # share sensors; factories could still differ in world size, then each world builds its own).
        self.obs_uniform = all(np.array_equal(e._obs.low, obs.low) and np.array_equal(e._obs.high, obs.high)
                               and e.capacity.max_time == obs.capacity.max_time for e in envs)
        self.obs = obs
        self.maps = PaddedMaps(m)
        # The global state (:meth:`state`): whether world b's builder has the batch's capacity (the state's
        # layout and scales; set in load, as set_world may bring another), and each world's occupancy grid
        # with the map it was computed for (a per-map constant, refreshed when the world's map changes).
        self.same_capacity = np.zeros(m, bool)
        self.occupancy = np.zeros((m, STATE_GRID * STATE_GRID))
        self._occupancy_of: list[StaticMap | None] = [None] * m
        # Reward and episode-end rows.
        self.prev_dist = np.zeros((m, n))
        self.prev_action = np.zeros((m, n, 2))
        self.weights = np.zeros((m, len(WEIGHT_COLUMNS)))  # each world's RewardSpec (swarm_env.scoring.weights)
        self.horizon = np.zeros(m)  # approach_horizon
        self.tol = np.zeros(m)
        self.radius = np.zeros((m, n))
        self.lradius = np.zeros(m)
        self.lrobot = np.zeros(m, bool)
        self.hcount = np.zeros(m, np.int64)
        self.hrad = np.zeros((m, self.hmax))
        self.speed = np.ones((m, 2))
        self.max_steps = np.zeros(m, np.int64)
        self.on_collision = np.zeros(m, bool)
        # EpisodeMetrics rows.
        self.steps = np.zeros(m, np.int64)
        self.sim_time = np.zeros(m)
        self.wall_time = np.zeros(m)
        self.err_sum = np.zeros((m, n))
        self.err_max = np.zeros(m)
        self.twist_sum = np.zeros((m, n + 1, 2))
        self.travelled = np.zeros((m, n + 1))
        self.prev_pos = np.zeros((m, n + 1, 2))
        self.min_sep = np.full(m, np.inf)
        self.min_clear = np.full(m, np.inf)
        self.lb = np.zeros((m, n))
        self.lb_valid = np.zeros(m, bool)
        self.arrived = np.zeros(m, bool)
        # Settling: the formation index the Python code last saw (-1: never), the pending switch's
        # index (-1: none), and the counters of the held formation hold_key (-1: none in the rows).
        self.last_k = np.full(m, -1, np.int64)
        self.pending_k = np.full(m, -1, np.int64)
        self.hold_key = np.full(m, -1, np.int64)
        self.hold_n = np.zeros(m, np.int64)
        self.hold_in = np.zeros(m, np.int64)

    # ------------------------------------------------------------------ sync with the worlds
    def bodies(self) -> BatchBodies:
        """The worlds' radii and counts as one bundle for the kernels."""
        return BatchBodies(self.radius, self.lradius, self.lrobot, self.hrad, self.hcount)

    def load(self, b: int, e: SwarmEnv) -> None:
        """Row ``b`` := world ``e``'s state (after its reset, or anything else that changed it)."""
        st = e._state
        assert st is not None
        scn = st.scenario
        spec = scn.reward
        if len(st.follower_pose) != self.n:
            raise ValueError(f"world {b} has {len(st.follower_pose)} followers, the batch {self.n}")
        self.maps.set(b, st.static)
        self.same_capacity[b] = e._obs.capacity == self.obs.capacity
        self.weights[b] = reward_weights(spec)
        self.horizon[b] = spec.approach_horizon
        self.tol[b] = scn.world.settle_tolerance
        self.radius[b] = st.follower_radius
        self.lrobot[b] = st.leader_is_robot
        self.lradius[b] = st.leader_radius
        h = len(st.human_pos)
        if h > self.hrad.shape[1]:
            self.hmax = h
            self.hrad = np.concatenate([self.hrad, np.zeros((self.m, h - self.hrad.shape[1]))], axis=1)
        self.hcount[b] = h
        self.hrad[b] = 0.0
        self.hrad[b, :h] = st.human_radius
        self.speed[b] = (scn.robots.max_speed, scn.robots.max_turn_rate)
        self.max_steps[b] = e.max_steps
        self.on_collision[b] = e.terminate_on_collision
        self.prev_dist[b] = e._prev_dist
        self.prev_action[b] = e._prev_action
        met = e._metrics
        self.steps[b] = met.steps
        self.sim_time[b] = met.sim_time
        self.wall_time[b] = met.wall_time
        self.err_sum[b] = met.err_sum
        self.err_max[b] = met.err_max
        self.twist_sum[b] = met.twist_sum
        self.travelled[b] = met.dist
        self.prev_pos[b] = met.prev_pos
        self.min_sep[b] = met.min_sep
        self.min_clear[b] = met.min_clear
        lb = met._static_lb
        self.lb_valid[b] = lb is not None and len(lb) == self.n
        if self.lb_valid[b]:
            self.lb[b] = lb
        self.arrived[b] = met.leader_arrival is not None
        self.last_k[b] = -1  # the next step's settling runs in Python, which reads the object's records
        self.pending_k[b] = -1
        self.hold_key[b] = -1

    def store(self, b: int, e: SwarmEnv) -> None:
        """World ``e``'s ``EpisodeMetrics`` and previous distances/actions := row ``b``."""
        met = e._metrics
        met.steps = int(self.steps[b])
        met.sim_time = float(self.sim_time[b])
        met.wall_time = float(self.wall_time[b])
        met.err_sum = self.err_sum[b].copy()
        met.err_max = float(self.err_max[b])
        met.twist_sum = self.twist_sum[b].copy()
        met.dist = self.travelled[b].copy()
        met.prev_pos = self.prev_pos[b].copy()
        met.min_sep = float(self.min_sep[b])
        met.min_clear = float(self.min_clear[b])
        met._static_lb = self.lb[b].copy() if self.lb_valid[b] else None
        self._store_hold(b, met)
        e._prev_dist = self.prev_dist[b].copy()
        e._prev_action = self.prev_action[b].copy()

    def _store_hold(self, b: int, met: Any) -> None:
        k = int(self.hold_key[b])
        if k >= 0:
            counts = met._hold[k]  # the list object the settling code updates
            counts[0], counts[1] = int(self.hold_n[b]), int(self.hold_in[b])

    # ------------------------------------------------------------------ one step
    def step(self, envs: Sequence[SwarmEnv], states: Sequence[WorldState], actions: np.ndarray, wall: float,
             a: StepArrays | None = None, drawn: Sequence[int] | None = None,
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """Rewards, metrics, episode end and observations of the step that produced ``states`` with
        the ``(M, N, 2)`` float64 normalised ``actions`` (after the physics of every world).

        Returns ``(obs (M, N, D) float32 without lidar, rewards (M, N), terminated (M,), truncated
        (M,), infos)`` with the infos of :data:`swarm_env.env._INFO_KEYS` as ``(M, N)`` arrays; the
        worlds' bookkeeping (``EpisodeMetrics`` records, ``termination``, ``agents``, renderer) is
        done, except for the finished worlds' final metrics and restart, which are the caller's
        (after :meth:`store`). ``wall``: the seconds added to each world's ``wall_time``. The stages
        are the methods below, in this order (``benchmarks/engine_breakdown.py`` times each).

        ``a``: the snapshots' arrays if the caller has them (:meth:`StepArrays.of_blocks`), else
        :meth:`gather` stacks them; ``drawn``: the worlds with a renderer, if the caller knows them
        (see :meth:`finish`)."""
        if a is None:
            a = self.gather(states)
        floats, rewards, touching = self.rewards(envs, states, a, actions)
        obs = self.observations(envs, states, a)
        within = self.metrics(envs, states, a, floats[len(REWARD_TERMS)], wall)
        terminated, truncated, infos = self.finish(envs, states, a, floats, touching, within, drawn)
        return obs, rewards, terminated, truncated, infos

    def gather(self, states: Sequence[WorldState]) -> StepArrays:
        """The snapshots' per-step arrays, stacked (humans padded to this batch's rows)."""
        return StepArrays(states, self.hmax, self.hcount)

    def arrays_of(self, blocks: dict[str, Any]) -> StepArrays:
        """:meth:`gather`'s arrays from the physics' stacked blocks
        (:meth:`swarm_env.vector.world_batch.WorldBatch.last_arrays`), the same bits without touching ``M``
        snapshots."""
        return StepArrays.of_blocks(blocks, self.hmax, self.hcount)

    def lidar_rows(self, a: StepArrays, fresh: dict[int, WorldState]) -> LidarRows:
        """The lidar's input for every world (:data:`swarm_env.sensing.lidar.LidarRows`) from the rows: what
        :func:`swarm_env.sensing.lidar.flat_inputs` gives for the worlds' ``lidar_input(e._state)`` after the
        step that produced ``a``, without a tuple per world. ``fresh``: the worlds that started a new
        episode since (their rows are loaded, ``a`` still holds their last state), with their first
        snapshot. The radii, human counts and leader discs are the rows' episode constants."""
        m, n = self.m, self.n
        pose, lpose, hpos = a.pose, a.lpose, a.hpos
        width = max(hpos.shape[1], self.hrad.shape[1])
        if fresh or hpos.shape[1] != width:
            pose, lpose = pose.copy(), lpose.copy()
            grown = np.zeros((m, width, 2))
            grown[:, :hpos.shape[1]] = hpos
            hpos = grown
            for b, st in fresh.items():
                pose[b] = st.follower_pose
                lpose[b] = st.leader_pose
                hpos[b] = 0.0
                hpos[b, :len(st.human_pos)] = st.human_pos
        hcount = self.hcount
        if self.hmax and hcount.any():
            present = np.arange(width) < hcount[:, None]
            humans, human_radii = hpos[present], self.hrad[:, :width][present]
        else:
            humans, human_radii = np.zeros((0, 2)), np.zeros(0)
        leaders = np.full((m, 3), np.nan)  # NaN radius: a virtual leader (no disc)
        robots = np.flatnonzero(self.lrobot)
        if len(robots):
            leaders[robots, :2] = lpose[robots, :2]
            leaders[robots, 2] = self.lradius[robots]
        return (pose.reshape(m * n, 3), self.radius.reshape(m * n), humans, human_radii, np.full(m, n, np.int64),
                hcount.copy(), leaders)

    def rewards(self, envs: Sequence[SwarmEnv], states: Sequence[WorldState], a: StepArrays,
                actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(floats (len(REWARD_TERMS) + 1, M, N), rewards (M, N), touching (M, N, 4))``: the weighted
        terms then the slot distances (the infos' float rows), their sums, and the bodies in touch;
        the rows' ``prev_dist``/``prev_action`` move on (Python only in worlds with contacts)."""
        from swarm_env.vector.batch_kernel import rewards_batch

        m, n = self.m, self.n
        touching = np.zeros((m, n, len(CONTACT_GROUPS)))
        onsets = np.zeros((m, n))
        weights = self.weights.copy()
        hit = a.touching
        if len(hit) < m:
            calm = np.ones(m, bool)
            calm[hit] = False
            weights[calm, W_COLLISION] = 0.0  # reward_table: no onsets, no touching -> those weights are 0
            weights[calm, W_CONTACT] = 0.0
        for b in hit:
            s = states[b]
            touching[b] = touching_per_follower(s)
            if not s.contacts:
                weights[b, W_COLLISION] = 0.0
            elif weights[b, W_COLLISION]:
                onsets[b] = new_contacts_per_follower(s)
        gap = np.zeros((m, n))
        for b in np.flatnonzero(weights[:, W_APPROACH]).tolist():
            gap[b] = approach_gap(states[b], float(self.horizon[b]))
        leader = np.empty((m, 1, 3))
        leader[:, 0, :2] = a.lpose[:, :2]
        leader[:, 0, 2] = self.lradius
        floats = np.empty((len(REWARD_TERMS) + 1, m, n))
        rewards = np.empty((m, n))
        rewards_batch(a.rows(), self.bodies(), leader, (self.prev_dist, self.prev_action), actions,
                      (touching, onsets, gap), weights, self.maps.kernel_arrays(), (floats, rewards))
        return floats, rewards, touching

    def metrics(self, envs: Sequence[SwarmEnv], states: Sequence[WorldState], a: StepArrays, dist: np.ndarray,
                wall: float) -> np.ndarray:
        """``EpisodeMetrics.update`` of every world (the rows, and the objects where an event needs
        the reference's Python); returns ``within`` ``(M,)``: every slot distance within tolerance."""
        from swarm_env.scoring.step_kernel import Screening
        from swarm_env.vector.batch_kernel import metrics_batch

        m = self.m
        within = np.zeros(m, bool)
        event = np.zeros(m, bool)
        status = np.zeros(m, np.int64)
        hum = np.zeros(m)
        acc = MetricRows(self.err_sum, self.twist_sum, self.travelled, self.prev_pos, self.lb, self.lb_valid,
                         self.min_clear, self.min_sep, self.err_max, self.steps, self.sim_time, self.wall_time,
                         self.last_k, self.pending_k, self.hold_key, self.hold_n, self.hold_in)
        metrics_batch(dist, self.tol, acc, self.bodies(), a.rows(), float(wall),
                      Screening(_LIPSCHITZ_SLACK, _SCREEN_MARGIN, _FAST_MAX_POINTS), self.maps.kernel_arrays(),
                      (within, event, status, hum))
        for b in a.contacts:  # collision counts stay in the objects
            envs[b]._metrics.count_contacts(states[b])
        for b in np.flatnonzero(status == 2).tolist():  # EpisodeMetrics._update_compiled's numpy static clearance
            s = states[b]
            self.min_clear[b] = s.static.min_distance(a.pose[b, :, :2], self.radius[b], float(self.min_clear[b]),
                                                      lower=self.lb[b].copy())
            if self.hcount[b]:
                self.min_clear[b] = min(float(self.min_clear[b]), float(hum[b]))
        for b in np.flatnonzero(a.leader_done & ~self.arrived).tolist():
            envs[b]._metrics.leader_arrival = states[b].time
            self.arrived[b] = True
        for b in np.flatnonzero(event).tolist():  # a switch, or the pending formation reached: the reference code
            met = envs[b]._metrics
            self._store_hold(b, met)
            met._observe_settling(states[b], dist[b], bool(within[b]))
            k = int(a.k[b])
            self.last_k[b] = k
            self.pending_k[b] = -1 if met._pending is None else met._pending["index"]
            counts = met._hold.get(k)
            self.hold_key[b] = -1 if counts is None else k
            if counts is not None:
                self.hold_n[b], self.hold_in[b] = counts
        return within

    def finish(self, envs: Sequence[SwarmEnv], states: Sequence[WorldState], a: StepArrays, floats: np.ndarray,
               touching: np.ndarray, within: np.ndarray, drawn: Sequence[int] | None = None,
               ) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """``(terminated, truncated, infos)`` as ``SwarmEnv._advance`` decides them, and the end of an
        episode recorded in the worlds that finished (``SwarmEnv._close_step``). ``drawn``: the worlds
        that have a renderer, ascending (``None``: looked up here)."""
        m, n = self.m, self.n
        touched = touching.reshape(m, -1).any(axis=1)
        collided = self.on_collision & touched
        terminated = (a.leader_done & within) | collided
        truncated = ~terminated & (a.step >= self.max_steps)
        counts = touching.transpose(2, 0, 1).astype(np.int64)
        infos = dict(zip(_INFO_KEYS, [*floats, *counts, np.repeat(collided[:, None], n, axis=1)]))
        for b in np.flatnonzero(terminated | truncated).tolist():
            envs[b]._close_step(states[b], bool(terminated[b]), bool(truncated[b]), bool(collided[b]))
        if drawn is None:  # (a renderer exists only after a world's render() was called)
            drawn = [b for b, e in enumerate(envs) if e._renderer is not None]
        for b in drawn:
            if not (terminated[b] or truncated[b]):
                envs[b]._close_step(states[b], False, False, False)
        return terminated, truncated, infos

    def state(self, envs: Sequence[SwarmEnv]) -> np.ndarray | None:
        """``(M, state_size)`` float32: each world's ``SwarmEnv.state()`` of its current snapshot
        (``e._state``: after a step, a finished world's first state of its next episode), in one call
        of :func:`swarm_env.sensing.state_kernel.state_batch`; the same bits as ``np.stack([e.state() for e in
        envs])``. ``None`` when one kernel cannot serve every world (a world whose capacity, hence state
        layout or scales, differs from world 0's): the caller stacks the worlds' own.

        The rows must be live (every world's current episode loaded): the human counts and maps are
        the rows'. Compiled: call it only with :func:`swarm_env.compiled.compiled_kernels` on."""
        from swarm_env.sensing import state_kernel as sk

        if not self.same_capacity.all():
            return None
        ob = self.obs
        cap = ob.capacity
        lay = ob.state_layout
        if self.n > cap.max_followers or int(self.hcount.max(initial=0)) > cap.max_humans:
            raise ValueError(f"the worlds have up to {self.n} followers and {int(self.hcount.max(initial=0))} "
                             f"humans, the state has room for {cap.max_followers} and {cap.max_humans}")
        states = []
        occupancy_of = self._occupancy_of
        for b, e in enumerate(envs):
            st = e._state
            assert st is not None
            static = st.static
            if occupancy_of[b] is not static:  # a new map: its grid from the world's builder (which caches it)
                self.occupancy[b] = e._obs._occupancy(static)
                occupancy_of[b] = static
            if self.maps.rows[b] is not static:  # (load keeps the maps current; a cheap guard)
                self.maps.set(b, static)
            states.append(st)
        a = self.gather(states)
        # The headings' cosines and sines by numpy, on views like the reference's (state_vector takes a
        # strided column of the pose and the leader's heading): numba's libm could round differently.
        th = a.pose[:, :, 2]
        lth = a.lpose[:, 2]
        w, h = cap.world_size
        out = np.empty((self.m, ob.state_size), dtype=np.float32)
        scales = sk.StateScales(float(w), float(h), float(ob.vel_limit), float(cap.max_time), STATE_CLEARANCE_RANGE,
                                _GRADIENT_STEP, STATE_LIMIT)
        cols = sk.StateColumns(lay["followers"].start, lay["leader"].start, lay["humans"].start, lay["time"].start,
                               lay["follower_clearance"].start, lay["occupancy"].start)
        heads = sk.Headings(np.cos(th), np.sin(th), np.cos(lth), np.sin(lth))
        sk.state_batch(a.rows(), heads, self.hcount, self.occupancy, self.maps.kernel_arrays(), scales, cols, out)
        return out

    def observations(self, envs: Sequence[SwarmEnv], states: Sequence[WorldState], a: StepArrays) -> np.ndarray:
        """``(M, N, D)`` float32: each world's ``build_without_lidar`` of its snapshot."""
        from swarm_env.sensing.obs_kernel import observations_batch

        return self._observations(envs, states, a, observations_batch)

    def _observations(self, envs: Sequence[SwarmEnv], states: Sequence[WorldState], a: StepArrays,
                      kernel: Any) -> np.ndarray:
        from swarm_env.sensing.obs_kernel import EntityRows

        ob = self.obs
        if not self.obs_uniform:
            return np.stack([e._obs.build_without_lidar(s) for e, s in zip(envs, states)])
        th = a.pose[:, :, 2]
        rel = a.lpose[:, 2, None] - th
        switch = np.minimum(a.next_switch - a.time, ob.capacity.max_time)
        k = ob.sensors.neighbors if self.n > 1 else 0
        out = np.empty((self.m, self.n, ob.size), dtype=np.float32)
        entities = EntityRows(k, ob.layout["neighbors"].start, ob.sensors.humans, ob.layout["humans"].start)
        kernel(a.rows(), (np.cos(th), np.sin(th), np.cos(rel), np.sin(rel)), self.speed, switch, self.hcount, entities,
               ob.low, ob.high, out)
        return out
