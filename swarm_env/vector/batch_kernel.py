"""The batched engine's per-step stages for all ``M`` worlds in one compiled call each.

:class:`swarm_env.vector.engine.SwarmVectorEnv` steps ``M`` worlds of one team size ``N``. Run one world
at a time, the rewards, the metrics and the observations cost a kernel call each plus the Python
around it (``python benchmarks/engine_breakdown.py --worlds 1024``: ~95 us a world-step, a third of
the step). These kernels walk the worlds inside one call and run, per world, **the per-world
kernels themselves** (:func:`swarm_env.scoring.step_kernel.reward_into`,
:func:`swarm_env.geometry.clearance_kernel.clearance`, :func:`swarm_env.scoring.step_kernel.metrics_step`) on views
of stacked ``(M, N, ...)`` arrays (the observations' batch kernel is the sensing room's:
:func:`swarm_env.sensing.obs_kernel.observations_batch`), so each world gets exactly a ``SwarmEnv``'s bits (tested against
the per-world references in ``tests/test_batch_kernel.py`` and on whole episodes in
``tests/test_vector.py``).

Inputs that vary in size between worlds are padded with counts: humans ``(M, Hmax, ...)`` with
``hcount`` ``(M,)``, a robot leader ``(M, 1, 3)`` read where ``lrobot``, and each
world's static map in ``maps``, a :class:`~swarm_env.geometry.map_arrays.MapBatch` (from
:class:`swarm_env.vector.batch_step.PaddedMaps`).
"""

from __future__ import annotations

import numpy as np

from swarm_env.geometry.clearance_kernel import clearance, world_map
from swarm_env.kernel_cache import njit
from swarm_env.scoring.step_kernel import N_TERMS, Accumulators, Bodies, metrics_step, reward_into
from swarm_env.scoring.weights import W_CLEARANCE, W_CLEARANCE_MARGIN

_jit = njit(nogil=True, error_model="numpy")


@_jit
def rewards_batch(rows, bodies, leader, prev, action, contact, weights, maps, out):  # pragma: no cover - compiled
    """The rewards of ``M`` worlds: for world ``m``, what
    :func:`swarm_env.scoring.rewards.reward_table` returns for its state with ``prev_dist[m]`` and
    ``prev_action[m]``, written to ``floats[:N_TERMS, m]`` (the weighted terms), ``floats[N_TERMS, m]``
    (the slot distances) and ``total[m]`` (``out = (floats, total)``); then ``prev_dist[m]`` and
    ``prev_action[m]`` (``prev = (prev_dist, prev_action)``) become this step's distances and ``action[m]``
    (what ``SwarmEnv._advance`` keeps for the next step).

    ``rows`` the worlds' arrays (:class:`swarm_env.vector.batch_step.WorldRows`: ``pose``, ``slots``, ``hpos``
    read), ``bodies`` their radii and counts (:class:`swarm_env.vector.batch_step.BatchBodies`), ``leader``
    ``(M, 1, 3)`` a robot leader's ``(x, y, r)`` (read where ``bodies.lrobot``), ``action`` ``(M, N, 2)``,
    ``contact = (touching, onsets, gap)``: ``(M, N, 4)``, ``(M, N)`` and ``(M, N)`` (read where their weight is
    not 0), ``weights`` ``(M, 9)`` in :data:`swarm_env.scoring.weights.WEIGHT_COLUMNS` order with ``collision``
    already 0 in a world without contact onsets and ``contact`` 0 without bodies in touch (as ``reward_table``
    does); humans and maps padded (module docstring). The clearance term is :func:`swarm_env.geometry.clearance_kernel.clearance`
    below the margin, as in ``reward_table``.
    """
    pose, slots, hpos = rows.pose, rows.slots, rows.hpos
    radius, lrobot, hrad, hcount = bodies.radius, bodies.lrobot, bodies.hrad, bodies.hcount
    prev_dist, prev_action = prev
    touching, onsets, gap = contact
    floats, total = out
    n_worlds = pose.shape[0]
    n = pose.shape[1]
    no_dist = np.zeros(0)
    no_fdist = np.zeros((0, 0))
    no_clear = np.zeros(0)
    for m in range(n_worlds):
        hc = hcount[m]
        clear = no_clear
        if weights[m, W_CLEARANCE] != 0.0:
            clear = clearance(pose[m], radius[m], weights[m, W_CLEARANCE_MARGIN], no_fdist, leader[m, :1 if lrobot[m] else 0], hpos[m, :hc],
                              hrad[m, :hc], world_map(maps, m))
        reward_into((floats[N_TERMS, m], floats[:N_TERMS, m], total[m]), pose[m], slots[m], no_dist,
                    (prev_dist[m], prev_action[m]), action[m], (touching[m], onsets[m], gap[m]), clear, weights[m])
        for i in range(n):
            prev_dist[m, i] = floats[N_TERMS, m, i]
            prev_action[m, i, 0] = action[m, i, 0]
            prev_action[m, i, 1] = action[m, i, 1]


@_jit
def metrics_batch(err, tol, acc, bodies, rows, wall, screening, maps, out):  # pragma: no cover - compiled
    """One :meth:`EpisodeMetrics.update <swarm_env.scoring.metrics.EpisodeMetrics.update>` of ``M`` worlds'
    accumulators held as rows of arrays (``acc``, :class:`swarm_env.vector.batch_step.MetricRows`), in place.

    ``bodies`` the worlds' radii and counts (:class:`swarm_env.vector.batch_step.BatchBodies`), ``rows`` their
    arrays this step (:class:`swarm_env.vector.batch_step.WorldRows`), ``wall`` the step's wall time, ``screening``
    a :class:`swarm_env.scoring.step_kernel.Screening`, ``maps`` a :class:`~swarm_env.geometry.map_arrays.MapBatch`,
    ``out = (within_out, event_out, status_out, hum_out)`` ``(M,)`` each.

    Per world ``m``: :func:`swarm_env.scoring.step_kernel.metrics_step` on its rows (``err`` the slot
    distances ``(M, N)``, ``tol`` the settle tolerances ``(M,)``), then what
    ``EpisodeMetrics._update_compiled`` does with its result: ``steps += 1``, ``sim_time = time``,
    ``wall_time += wall``, ``err_max = max(err_max, step max)`` and ``min_sep = min(min_sep, step
    min)`` with Python's ``max``/``min`` semantics (the first argument kept unless the second
    compares greater/smaller, so a NaN never replaces a number), the carried static lower bounds
    ``lb[m]`` (valid where ``lb_valid[m]``) and ``min_clear``, then the human gaps where the world
    has humans. ``status_out[m]`` is ``metrics_step``'s status: at 2 the caller still owes
    ``min_clear[m] = StaticMap.min_distance(...)`` and then ``min(min_clear, hum_out[m])`` (with humans).

    The formation settling stays Python (``EpisodeMetrics._observe_settling``) where something
    happens: ``event_out[m]`` is set when the formation index ``k_now[m]`` differs from
    ``last_k[m]`` (the index the Python code last saw) or the pending switch ``pending_k[m]`` is
    reached this step (``within_out[m]``: every slot error within ``tol``). Elsewhere the step is
    counted here in the held-formation counters ``hold_n``/``hold_in`` when ``hold_key[m] ==
    k_now[m]`` (what ``_observe_settling`` would count).
    """
    (err_sum, twist_sum, travelled, prev_pos, lb, lb_valid, min_clear, min_sep, err_max, steps, sim_time, wall_time,
     last_k, pending_k, hold_key, hold_n, hold_in) = acc
    radius, l_radius, leader_robot, hrad, hcount = bodies
    pose, f_twist, l_twist, l_pose = rows.pose, rows.twist, rows.ltwist, rows.lpose
    hpos, time, k_now = rows.hpos, rows.time, rows.k
    within_out, event_out, status_out, hum_out = out
    n_worlds = pose.shape[0]
    n = pose.shape[1]
    no_lb = np.zeros(0)
    for m in range(n_worlds):
        hc = hcount[m]
        robot = leader_robot[m]
        lbm = lb[m] if lb_valid[m] else no_lb
        lr = l_radius[m] if robot else 0.0
        e_max, within, sep, hum, lb_out, status, clear = metrics_step(
            err[m], tol[m], Accumulators(err_sum[m], twist_sum[m], travelled[m], prev_pos[m]),
            Bodies(pose[m], f_twist[m], radius[m], l_pose[m], l_twist[m], lr, robot, hpos[m, :hc], hrad[m, :hc]), lbm,
            min_clear[m], screening, world_map(maps, m))
        steps[m] += 1
        sim_time[m] = time[m]
        wall_time[m] += wall
        if e_max > err_max[m]:  # err_max = max(err_max, e_max)
            err_max[m] = e_max
        if sep < min_sep[m]:  # min_sep = min(min_sep, sep)
            min_sep[m] = sep
        status_out[m] = status
        hum_out[m] = hum
        if status < 3:
            for i in range(n):
                lb[m, i] = lb_out[i]
            lb_valid[m] = True
            if status == 1:
                min_clear[m] = clear
            if status != 2 and hc > 0 and hum < min_clear[m]:
                min_clear[m] = hum
        k = k_now[m]
        event = k != last_k[m] or (pending_k[m] == k and within)
        if not event and hold_key[m] == k:
            hold_n[m] += 1
            if within:
                hold_in[m] += 1
        event_out[m] = event
        within_out[m] = within


__all__ = ["metrics_batch", "rewards_batch"]
