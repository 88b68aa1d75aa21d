"""Whole episodes of ``SwarmEnv`` against digests recorded from the code before the step speed-ups.

Speed work on the step (physics glue, humans, slots, rewards, metrics, snapshot, observations) must
not change a single bit of what the env returns. ``tests/test_vector.py`` checks the batched engine
against ``SwarmEnv`` live, which cannot catch a change made to both; this module pins ``SwarmEnv``
itself: every observation, reward, termination, truncation, info, ``state()`` and the final
``episode_metrics()`` (wall time left out) of a set of episodes, hashed step by step, must equal
the recorded digests in ``tests/data/step_digests.json``.

The episodes are driven by pure pursuit at the slot targets plus seeded noise, so robots reach and
leave their slots, touch each other, obstacles, walls and humans, and formations switch.

Regenerate the file only for an intended change of behaviour (and say so in the commit)::

    SWARM_ENV_RECORD_DIGESTS=1 python -m pytest tests/test_step_digests.py

(Floating point: x86-64 Linux, numpy 2.x; the env's own determinism tests pin the rest.)
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import swarm_env
from swarm_env.compiled import use_compiled_kernels
from swarm_env.control.pursuit import pure_pursuit
from swarm_env.jsonio import dumps, write_json

DATA = Path(__file__).parent / "data" / "step_digests.json"
RECORD = os.environ.get("SWARM_ENV_RECORD_DIGESTS") == "1"

#: name -> (scenario, reset seed, env kwargs, max steps)
EPISODES: dict[str, tuple[str, int, dict[str, Any], int]] = {
    "paper_vo_0": ("paper_vo_0", 0, {}, 300),
    "paper_vo_45": ("paper_vo_45", 1, {}, 300),
    "paper_vo_90": ("paper_vo_90", 2, {}, 300),
    "paper_cbs_switch": ("paper_cbs_switch", 0, {}, 400),
    "corridor": ("corridor", 3, {}, 300),
    "crowd_reactive": ("crowd_reactive", 4, {}, 300),
    "random_bench_world": ("random", 5, {"n_followers": 8, "n_obstacles": 10, "n_humans": 3,
                                         "world_size": (29.0, 20.0)}, 250),
    "random_robot_leader": ("random", 6, {"n_followers": 6, "n_humans": 2, "n_switches": 2,
                                          "leader_kind": "robot", "max_time": 40.0}, 300),
    "random_default": ("random", 1000, {}, 300),
    "random_collision_end": ("random", 7, {"n_followers": 5, "terminate_on_collision": True}, 300),
    "discrete_paper_vo_45": ("paper_vo_45", 8, {"action_type": "discrete"}, 200),
}


def _update(h: Any, value: Any) -> None:
    h.update(np.ascontiguousarray(np.asarray(value, dtype=np.float64)).tobytes())


def _episode_digests(scenario: str, seed: int, kwargs: dict[str, Any], max_steps: int) -> dict[str, Any]:
    kwargs = dict(kwargs)
    env_kwargs = {k: kwargs.pop(k) for k in ("action_type", "terminate_on_collision") if k in kwargs}
    env = swarm_env.parallel_env(scenario, max_cycles=max_steps, **env_kwargs, **kwargs)
    rng = np.random.default_rng(seed + 12345)
    streams = {k: hashlib.sha256() for k in ("obs", "rewards", "ends", "infos", "state")}
    obs, infos = env.reset(seed=seed)
    steps = 0
    while True:
        agents = sorted(obs)
        for a in agents:
            _update(streams["obs"], obs[a])
            info = infos[a]
            for key in sorted(info):
                _update(streams["infos"], float(info[key]))
        _update(streams["state"], env.state())
        if not env.agents:
            break
        world = env.world_state()
        robots = world.scenario.robots
        limits = np.array([robots.max_speed, robots.max_turn_rate])
        twist = pure_pursuit(world.follower_pose, world.slot_targets, limits[0], limits[1], 0.5) / limits
        noise = rng.normal(0.0, 0.35, twist.shape)
        if env.action_type == "discrete":
            n = env.action_space(env.agents[0]).n
            actions = {a: int(rng.integers(n)) for a in env.agents}
        else:
            act = np.clip(twist + noise, -1.0, 1.0).astype(np.float32)
            actions = {a: act[int(a.rsplit("_", 1)[1])] for a in env.agents}
        obs, rewards, terms, truncs, infos = env.step(actions)
        steps += 1
        for a in sorted(rewards):
            _update(streams["rewards"], rewards[a])
            _update(streams["ends"], [terms[a], truncs[a]])
    metrics = {k: v for k, v in env.episode_metrics().items() if k != "wall_time"}
    return {"steps": steps, **{k: h.hexdigest() for k, h in streams.items()},
            "metrics": hashlib.sha256(dumps(metrics, indent=None, sort_keys=True).encode()).hexdigest(),
            "success": bool(metrics["success"]), "collisions": metrics["collisions"]["total"]}


def _recorded() -> dict[str, Any]:
    return json.loads(DATA.read_text()) if DATA.exists() else {}


@pytest.mark.parametrize("compiled", [True, False], ids=["kernels", "numpy"])
@pytest.mark.parametrize("name", sorted(EPISODES))
@pytest.mark.slow
def test_episode_matches_the_recorded_digests(name: str, compiled: bool) -> None:
    """The episode's digests equal the recorded ones, with the compiled kernels and with their numpy
    references (:func:`swarm_env.compiled.use_compiled_kernels`)."""
    use_compiled_kernels(compiled)
    try:
        got = _episode_digests(*EPISODES[name])
    finally:
        use_compiled_kernels(True)
    if RECORD and compiled:
        data = _recorded()
        data[name] = got
        write_json(DATA, dict(sorted(data.items())))
        pytest.skip("recorded")
    want = _recorded().get(name)
    assert want is not None, f"no recorded digests for {name!r} in {DATA}: record them (see the module docstring)"
    assert got["steps"] > 50
    assert got == want


def test_the_recorded_episodes_exercise_the_step() -> None:
    """The recorded set covers what the step computes: contacts, successful episodes, episodes cut
    short by a collision, and every built-in scenario."""
    data = _recorded()
    assert set(data) == set(EPISODES)
    assert any(d["collisions"] > 0 for d in data.values())
    assert any(d["collisions"] == 0 for d in data.values())
    assert {s for s, *_ in EPISODES.values()} >= {"paper_vo_0", "paper_vo_45", "paper_vo_90", "paper_cbs_switch",
                                                  "corridor", "crowd_reactive", "random"}
