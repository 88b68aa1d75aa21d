"""The observation-only expert (``obs_expert``): registered, reads only the observations, avoids in the physics."""

from __future__ import annotations

import numpy as np
import pytest

from swarm_env.compiled import compiled_mode
from swarm_env.env import SwarmEnv
from swarm_env.harness.episode import run_episode
from swarm_env.harness.policies import PolicyError, acts_on, load_policy
from swarm_env.sensing.layout import ENTITY, ENTITY_MASK, ENTITY_POS
from swarm_env_agents.obs_expert import ObservationExpert


def test_registered_as_acting_on_observations() -> None:
    env = SwarmEnv("paper_vo_0")
    policy = load_policy("obs_expert:horizon=4,wc_step=0.5,move_rev=false", env)
    assert isinstance(policy, ObservationExpert)
    assert (policy.horizon, policy.wc_step, policy.move_rev) == (4.0, 0.5, False)
    assert acts_on("obs_expert") == "observations"
    with pytest.raises(ValueError, match="unknown parameter 'speed'"):
        load_policy("obs_expert:speed=1", env)


def test_acts_without_the_state_and_rows_of_many_worlds_match() -> None:
    """``act`` needs no world state; ``act_rows`` over the followers of several worlds (the batched engine's rows)
    gives each world's ``act``; the same observation gives the same action."""
    envs = [SwarmEnv("random", n_followers=4, n_humans=(2, 3)) for _ in range(3)]
    policy = ObservationExpert()
    observations = []
    for k, env in enumerate(envs):
        obs, _ = env.reset(seed=40 + k)
        policy.reset(env, None)
        for _ in range(30):  # drive a little so that rows, humans and lidar hits are non-trivial
            obs, *_ = env.step(policy.act(obs))
        observations.append(obs)
    rows = np.concatenate([np.stack(list(o.values())) for o in observations])
    batch = policy.act_rows(rows)
    each = np.concatenate([np.stack(list(policy.act(o, None).values())) for o in observations])
    assert batch.dtype == np.float32 and batch.shape == (12, 2)
    assert np.array_equal(batch, each)
    assert np.array_equal(policy.act_rows(rows), batch)
    assert np.all(np.abs(batch) <= 1.0)


def test_avoids_what_pursuit_hits() -> None:
    """crowd_reactive (reactive walkers, obstacles): pure pursuit to the same slots collides; the expert, from its
    observations alone, does not, and keeps the formation."""
    env = SwarmEnv("crowd_reactive")
    pursuit = run_episode(env, load_policy("pursuit", env), 0)
    expert = run_episode(env, load_policy("obs_expert", env), 0)
    assert pursuit["collisions"]["total"] > 0
    assert expert["collisions"]["total"] == 0
    assert expert["formation_error"]["mean"] < 0.45


def test_avoidance_is_what_keeps_it_clear() -> None:
    """The same expert with its contact checks cut to nothing collides where the full one does not (the check
    above can fail)."""
    env = SwarmEnv("crowd_reactive")
    blind = ObservationExpert(horizon=0.25, dt=0.25, static_horizon=0.25, t_safe=0.01, wc_step=0.0, w_ttc=0.0,
                              margin=0.0, human_margin=0.0)
    assert run_episode(env, blind, 0)["collisions"]["total"] > 0


def test_bad_inputs_are_refused() -> None:
    with pytest.raises(ValueError, match="obs_expert: horizon must be a finite number > 0"):
        ObservationExpert(horizon=0.0)
    with pytest.raises(ValueError, match="n_w must be an int"):
        ObservationExpert(n_w=1)
    with pytest.raises(ValueError, match="at least one roll-out step"):
        ObservationExpert(horizon=0.1, dt=0.25)
    with pytest.raises(ValueError, match="reverse must be in"):
        ObservationExpert(reverse=2.0)
    policy = ObservationExpert()
    with pytest.raises(PolicyError, match="before reset"):
        policy.act_rows(np.zeros((1, 52)))
    env = SwarmEnv("paper_vo_0")
    policy.reset(env, 0)
    with pytest.raises(ValueError, match="shape"):
        policy.act_rows(np.zeros((2, 7)))
    with pytest.raises(PolicyError, match="continuous"):
        load_policy("obs_expert", SwarmEnv("paper_vo_0", action_type="discrete"))


def _identical(policy: ObservationExpert, rows: np.ndarray) -> np.ndarray:
    """``act_rows`` compiled and as the numpy reference: the same actions, bit for bit."""
    with compiled_mode(kernels=False):
        reference = policy.act_rows(rows)
    compiled = policy.act_rows(rows)
    assert compiled.dtype == np.float32 and np.array_equal(compiled, reference), np.flatnonzero(
        (compiled != reference).any(axis=1))
    return reference


def _blank(policy: ObservationExpert, rows: np.ndarray) -> np.ndarray:
    """``rows`` with nothing seen: no neighbour, no human, no lidar hit."""
    rows = rows.copy()
    rows[:, policy.neighbours] = 0.0
    rows[:, policy.humans] = 0.0
    rows[:, policy.lidar] = 1.0
    return rows


def _crowded(policy: ObservationExpert, n: int, seed: int) -> np.ndarray:
    """``n`` made-up rows: neighbours and humans close and moving, lidar walls and scattered hits; many leave no
    candidate safe (the fallback and ``_clearest``)."""
    rng = np.random.default_rng(seed)
    rows = rng.uniform(-1.0, 1.0, (n, policy.obs_size))
    for block in (policy.neighbours, policy.humans):
        entities = rows[:, block].reshape(n, -1, ENTITY)
        entities[..., ENTITY_MASK] = rng.random(entities.shape[:2]) < 0.6
        entities[..., ENTITY_POS:ENTITY_POS + 2] = rng.uniform(-1.2, 1.2, (*entities.shape[:2], 2))
        rows[:, block] = entities.reshape(n, -1)
    lidar = rng.uniform(0.02, 1.0, (n, policy.lidar.stop - policy.lidar.start))
    lidar[rng.random(lidar.shape) < 0.4] = 1.0
    wall = rng.random(n) < 0.3  # one surface seen by consecutive rays: filled and extended
    lidar[wall] = np.clip(0.1 + 0.02 * np.arange(lidar.shape[1]) + rng.normal(0.0, 0.005, lidar[wall].shape), 0, 1)
    rows[:, policy.lidar] = lidar
    return rows


@pytest.mark.parametrize(("scenario", "seed", "steps"), [
    ("random", 40, 80), ("crowd_reactive", 41, 100), ("paper_cbs_switch", 42, 60), ("corridor", 40, 60)])
def test_compiled_choice_is_the_reference(scenario: str, seed: int, steps: int) -> None:
    """swarm_env_agents.obs_expert_kernel gives the numpy reference's actions bit for bit: on every step of an
    episode, on all its rows at once, on rows that see nothing, and on crowded made-up rows (nothing safe)."""
    env = SwarmEnv(scenario, **({"n_followers": 4, "n_humans": (2, 3)} if scenario == "random" else {}))
    policy = ObservationExpert()
    obs, _ = env.reset(seed=seed)
    policy.reset(env, seed)
    seen = []
    for _ in range(steps):
        if not env.agents:
            break
        rows = np.stack([np.asarray(o, dtype=np.float64) for o in obs.values()])
        seen.append(rows)
        obs, *_ = env.step(dict(zip(obs, _identical(policy, rows))))
    rows = np.concatenate(seen)
    _identical(policy, rows)
    _identical(policy, _blank(policy, rows[:20]))
    calls = []
    reference_clearest = policy._clearest
    policy._clearest = lambda *a: calls.append(1) or reference_clearest(*a)
    _identical(policy, _crowded(policy, 400, seed))
    assert calls  # the fallback was compared too


def test_compiled_choice_is_the_reference_with_other_options() -> None:
    env = SwarmEnv("random", n_followers=4, n_humans=(2, 3))
    for options in ({"band": False, "side_fill": 0.0, "fb_clear": 0.0, "wc_step": 0.0, "n_rev": 0, "n_w": 8},
                    {"drop_seen": False, "move_first": False, "move_rev": False, "robot_horizon": 3.0, "fill": 0.7,
                     "static_horizon": 4.0, "t_safe": 3.0, "fb_clear": 3.0, "horizon": 4}):
        policy = ObservationExpert(**options)
        obs, _ = env.reset(seed=42)
        policy.reset(env, 42)
        for _ in range(60):
            rows = np.stack([np.asarray(o, dtype=np.float64) for o in obs.values()])
            obs, *_ = env.step(dict(zip(obs, _identical(policy, rows))))
        _identical(policy, _crowded(policy, 300, 7))
        _identical(policy, _blank(policy, _crowded(policy, 10, 8)))
