"""``SwarmVectorEnv.state()`` in one compiled call (swarm_env.sensing.state_kernel via BatchState.state) against
each world's own ``SwarmEnv.state()`` (ObservationBuilder.state_vector), bit for bit."""

from __future__ import annotations

from collections.abc import Iterator, Sequence

import numpy as np
import pytest

import swarm_env
from swarm_env.compiled import use_compiled_kernels
from swarm_env.env import SwarmEnv
from swarm_env.vector.batch_step import BatchState
from swarm_env.vector.engine import EnvFactory, SwarmVectorEnv


def _same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal float32 arrays, and equal bit patterns but for the sign of a zero (the one freedom
    of StaticMap.distance, see swarm_env.sensing.state_kernel)."""
    if a.dtype != np.float32 or b.dtype != np.float32 or not np.array_equal(a, b):
        return False
    zero = (a == 0.0) & (b == 0.0)
    return bool(np.array_equal(a.view(np.uint32)[~zero], b.view(np.uint32)[~zero]))


@pytest.fixture()
def kernel_calls(monkeypatch: pytest.MonkeyPatch) -> Iterator[list[int]]:
    """Counts the batched state calls that returned an array (the compiled path was taken)."""
    calls: list[int] = []
    real = BatchState.state

    def counted(self: BatchState, envs: Sequence[SwarmEnv]) -> np.ndarray | None:
        out = real(self, envs)
        if out is not None:
            calls.append(len(envs))
        return out

    monkeypatch.setattr(BatchState, "state", counted)
    yield calls


def _lockstep_state(scenario: str, num_envs: int, steps: int, seed: int, **kwargs) -> tuple[int, int]:
    """Step a SwarmVectorEnv and ``num_envs`` reference SwarmEnvs with the same actions; after the
    reset and every step assert ``venv.state()`` has the bits of the references' stacked ``state()``.
    Returns (steps checked with the engine's rows live, episodes that ended and auto-reset)."""
    venv = SwarmVectorEnv(scenario, num_envs, **kwargs)
    refs = [EnvFactory(scenario, kwargs)() for _ in range(num_envs)]
    agents = refs[0].possible_agents
    venv.reset(seed=seed)
    for m, env in enumerate(refs):
        env.reset(seed=seed + m)
    assert _same_bits(venv.state(), np.stack([e.state() for e in refs]))
    rng = np.random.default_rng(seed)
    live = ended = 0
    for t in range(steps):
        actions = rng.uniform(-1.0, 1.0, (num_envs, len(agents), 2)).astype(np.float32)
        venv.step(actions)
        for m, env in enumerate(refs):
            env.step({a: actions[m, k] for k, a in enumerate(agents)})
            if not env.agents:
                env.reset()  # the engine's auto-reset: the generator continues
                ended += 1
        state = venv.state()
        assert state.shape == (num_envs, venv.state_space.shape[0])
        assert _same_bits(state, np.stack([e.state() for e in refs])), (t, scenario, kwargs)
        live += bool(venv._local is not None and venv._local._rows_live)
    venv.close()
    return live, ended


@pytest.mark.parametrize("scenario", [s for s in swarm_env.list_scenarios() if s != "random"])
def test_builtin_scenarios_state_matches_swarm_env_bitwise(scenario: str, kernel_calls: list[int]) -> None:
    live, ended = _lockstep_state(scenario, 3, 24, seed=11, max_cycles=9)
    assert live == 24 and ended >= 6 and len(kernel_calls) == 24


@pytest.mark.parametrize(("n_followers", "num_envs", "seed", "knobs"), [
    (1, 10, 2000, {"n_humans": (0, 2)}),
    (3, 14, 2010, {"n_humans": (1, 4), "leader_kind": "robot"}),
    (6, 12, 2024, {"n_humans": (0, 3), "n_obstacles": 12}),  # 30 probes: the reference's compiled distance
    (8, 14, 2036, {"n_humans": (2, 5), "leader_kind": "robot"}),  # 40 probes: its numpy distance
])
@pytest.mark.slow
def test_fifty_random_worlds_state_matches_swarm_env_bitwise(n_followers: int, num_envs: int, seed: int,
                                                             knobs: dict, kernel_calls: list[int]) -> None:
    # 50 worlds in all (seeds 2000-2049), team sizes 1-8, with and without humans and a robot leader;
    # short episodes, so each world ends and restarts (new map, new humans) within the run.
    live, ended = _lockstep_state("random", num_envs, 26, seed=seed, max_cycles=11, n_followers=n_followers, **knobs)
    assert live == 26 and ended >= 2 * num_envs and len(kernel_calls) == 26


def test_compiled_kernels_off_stacks_the_worlds_states(kernel_calls: list[int]) -> None:
    use_compiled_kernels(False)
    try:
        live, ended = _lockstep_state("random", 4, 14, seed=77, max_cycles=6, n_humans=(1, 3))
    finally:
        use_compiled_kernels(True)
    assert live == 0 and ended >= 8 and not kernel_calls


def test_switching_paths_mid_run_and_per_world_calls_keep_the_bits(kernel_calls: list[int]) -> None:
    """The kernels switched off and on between steps, and a per-world call (which writes the rows back
    and leaves them not live until the next step): every state() is the worlds' own."""
    venv = SwarmVectorEnv("random", 5, max_cycles=7, n_humans=(0, 3))
    venv.reset(seed=300)
    envs = venv.get_attr("unwrapped")
    rng = np.random.default_rng(0)
    try:
        for t in range(16):
            use_compiled_kernels(t % 4 != 3)
            venv.step(rng.uniform(-1.0, 1.0, (5, venv.num_agents, 2)))
            if t % 5 == 2:
                venv.call("episode_metrics")
            assert _same_bits(venv.state(), np.stack([e.state() for e in envs])), t
    finally:
        use_compiled_kernels(True)
    assert 0 < len(kernel_calls) < 16
    venv.close()


def test_worlds_of_different_capacities_fall_back_to_their_own_states(kernel_calls: list[int]) -> None:
    factories = [EnvFactory("random", {"world_size": size, "n_followers": 3, "max_cycles": 5})
                 for size in ((18.0, 14.0), (24.0, 20.0))]
    venv = SwarmVectorEnv.from_factories(factories)
    venv.reset(seed=5)
    envs = venv.get_attr("unwrapped")
    for _ in range(8):
        venv.step(np.zeros((2, 3, 2)))
        assert _same_bits(venv.state(), np.stack([e.state() for e in envs]))
    assert not kernel_calls  # the capacities (world sizes) differ: one layout cannot serve both
    venv.close()
