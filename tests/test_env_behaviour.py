"""Determinism, pickling, action validation and the no-display guarantee of the env."""

from __future__ import annotations

import copy
import os
import pickle
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import swarm_env

EPISODE_DIGEST = textwrap.dedent(
    """
    import hashlib, sys
    import numpy as np
    import swarm_env
    from swarm_env.harness.policies import RandomPolicy

    def digest(name, seed, max_cycles=None):
        env = swarm_env.parallel_env(name, max_cycles=max_cycles)
        policy = RandomPolicy(env)
        obs, _ = env.reset(seed=seed)
        policy.reset(env, seed)
        h = hashlib.sha256()
        while env.agents:
            for a in sorted(obs):
                h.update(obs[a].tobytes())
            h.update(env.state().tobytes())
            obs, rew, term, trunc, _ = env.step(policy.act(obs, env.world_state()))
            h.update(repr(sorted(rew.items())).encode())
        h.update(repr(env.episode_metrics()["collisions"]).encode())
        return h.hexdigest()

    if __name__ == "__main__":
        print(digest(sys.argv[1], int(sys.argv[2]), int(sys.argv[3]) if len(sys.argv) > 3 else None))
    """
)


def _digest_in_process(name: str, seed: int, max_cycles: int | None = None) -> str:
    ns: dict = {}
    exec(EPISODE_DIGEST, ns)  # the same code the subprocesses run
    return ns["digest"](name, seed, max_cycles)


def _digest_in_subprocess(name: str, seed: int, hashseed: str, max_cycles: int | None = None) -> str:
    env = {**os.environ, "PYTHONHASHSEED": hashseed}
    args = [sys.executable, "-c", EPISODE_DIGEST, name, str(seed)] + ([str(max_cycles)] if max_cycles else [])
    out = subprocess.run(args, env=env, capture_output=True, text=True, check=True)
    return out.stdout.strip().splitlines()[-1]


@pytest.mark.parametrize("name,max_cycles", [("paper_vo_45", None), ("random", 150), ("paper_cbs_switch", 120)])
@pytest.mark.slow
def test_whole_episode_is_bitwise_deterministic_across_processes(name: str, max_cycles: int | None) -> None:
    here = _digest_in_process(name, 7, max_cycles)
    assert here == _digest_in_process(name, 7, max_cycles)
    assert here == _digest_in_subprocess(name, 7, "1", max_cycles)
    assert here == _digest_in_subprocess(name, 7, "12345", max_cycles)
    assert here != _digest_in_process(name, 8, max_cycles)


def test_random_scenario_differs_by_seed_and_repeats_by_seed() -> None:
    env = swarm_env.parallel_env("random")
    env.reset(seed=1)
    a = env.unwrapped.scenario
    env.reset(seed=2)
    b = env.unwrapped.scenario
    env.reset(seed=1)
    assert env.unwrapped.scenario == a != b


@pytest.mark.parametrize("clone", ["deepcopy", "pickle"])
@pytest.mark.slow
def test_running_env_clones_continue_identically(clone: str) -> None:
    env = swarm_env.parallel_env("paper_vo_0")
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    for _ in range(40):
        env.step({a: rng.uniform(-1, 1, 2).astype(np.float32) for a in env.agents})
    other = copy.deepcopy(env) if clone == "deepcopy" else pickle.loads(pickle.dumps(env))
    for _ in range(60):
        act = {a: rng.uniform(-1, 1, 2).astype(np.float32) for a in env.agents}
        o1, r1, *_ = env.step(act)
        o2, r2, *_ = other.step(act)
        for a in o1:
            assert o1[a].tobytes() == o2[a].tobytes()
        assert r1 == r2
    assert env.episode_metrics()["collisions"] == other.episode_metrics()["collisions"]


def test_rendering_env_pickles_after_a_frame() -> None:
    env = swarm_env.parallel_env("paper_vo_0", render_mode="rgb_array")
    env.reset(seed=0)
    env.step({a: env.action_space(a).sample() for a in env.agents})
    frame = env.render()
    clone = pickle.loads(pickle.dumps(env))
    assert np.array_equal(clone.render(), frame)


def test_actions_out_of_range_are_clipped_with_a_warning() -> None:
    env = swarm_env.parallel_env("paper_vo_0")
    env.reset(seed=0)
    clipped = env.unwrapped
    with pytest.warns(UserWarning, match="clipped"):
        clipped.step({a: np.array([5.0, -7.0], dtype=np.float32) for a in env.agents})
    reference = swarm_env.parallel_env("paper_vo_0")
    reference.reset(seed=0)
    reference.step({a: np.array([1.0, -1.0], dtype=np.float32) for a in reference.agents})
    assert np.array_equal(clipped.world_state().follower_pose, reference.world_state().follower_pose)


@pytest.mark.parametrize(
    "bad,match",
    [
        (np.array([np.nan, 0.0]), "finite"),
        (np.array([np.inf, 0.0]), "finite"),
        (np.zeros(3), "shape"),
        ("fast", "2 numbers"),
    ],
)
def test_invalid_continuous_actions_raise_clear_errors(bad: object, match: str) -> None:
    env = swarm_env.parallel_env("paper_vo_0")
    env.reset(seed=0)
    before = env.unwrapped.world_state()
    actions = {a: np.zeros(2, dtype=np.float32) for a in env.agents}
    actions[env.agents[0]] = bad
    with pytest.raises(ValueError, match=match):
        env.step(actions)
    assert env.unwrapped.world_state() is before  # nothing was stepped


def test_action_dict_must_match_agents() -> None:
    env = swarm_env.parallel_env("paper_vo_0")
    env.reset(seed=0)
    with pytest.raises(ValueError, match="missing actions"):
        env.step({env.agents[0]: np.zeros(2, dtype=np.float32)})
    with pytest.raises(ValueError, match="not in env.agents"):
        env.step({**{a: np.zeros(2, dtype=np.float32) for a in env.agents}, "follower_99": np.zeros(2)})


@pytest.mark.parametrize("bad", [10, -1, 2.5, True])
def test_invalid_discrete_actions_raise(bad: object) -> None:
    env = swarm_env.parallel_env("paper_vo_0", action_type="discrete")
    env.reset(seed=0)
    actions = {a: 0 for a in env.agents}
    actions[env.agents[0]] = bad
    with pytest.raises(ValueError, match="discrete action"):
        env.step(actions)


def test_discrete_primitive_turns_at_the_documented_rate() -> None:
    env = swarm_env.parallel_env("paper_vo_0", action_type="discrete")
    env.reset(seed=0)
    spec = env.unwrapped.scenario.robots
    env.step({a: 8 for a in env.agents})  # +48 degrees primitive: turns at max_turn_rate
    th0 = env.unwrapped.world_state().follower_pose[:, 2].copy()
    env.step({a: 8 for a in env.agents})  # (the first step lags one physics substep)
    th1 = env.unwrapped.world_state().follower_pose[:, 2]
    assert np.allclose(th1 - th0, spec.max_turn_rate * env.unwrapped.scenario.world.dt, atol=1e-6)


def test_bad_constructor_arguments() -> None:
    with pytest.raises(ValueError, match="render_mode"):
        swarm_env.parallel_env("paper_vo_0", render_mode="window")
    with pytest.raises(ValueError, match="action_type"):
        swarm_env.parallel_env("paper_vo_0", action_type="joystick")
    with pytest.raises(TypeError, match="random"):
        swarm_env.parallel_env("paper_vo_0", n_obstacles=3)
    with pytest.raises(swarm_env.ScenarioError):
        swarm_env.parallel_env("no_such_scenario")


def test_no_pygame_without_render_mode() -> None:
    code = textwrap.dedent(
        """
        import sys, swarm_env
        env = swarm_env.parallel_env("paper_vo_0")
        env.reset(seed=0)
        while env.agents:
            env.step({a: env.action_space(a).sample() for a in env.agents})
        env.unwrapped.episode_metrics()
        assert "pygame" not in sys.modules, "pygame was imported"
        print("ok")
        """
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr


def test_quickstart_flow_from_the_issue() -> None:
    env = swarm_env.parallel_env("paper_vo_0", render_mode="rgb_array")
    obs, infos = env.reset(seed=0)
    while env.agents:
        actions = {a: env.action_space(a).sample() for a in env.agents}
        obs, rewards, terminations, truncations, infos = env.step(actions)
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
    metrics = env.unwrapped.episode_metrics()
    for key in ("success", "steps", "sim_time", "wall_time", "collisions", "formation_error", "settle_times",
                "min_separation", "per_robot"):
        assert key in metrics
    assert metrics["steps"] == 600 or metrics["success"]
    aec = swarm_env.env("paper_cbs_switch")
    aec.reset(seed=0)
    assert aec.agents == [f"follower_{i}" for i in range(8)]
