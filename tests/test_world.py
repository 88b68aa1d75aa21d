"""World internals that exist for speed: they must give exactly the numbers of the plain path."""

from __future__ import annotations

import copy
import pickle

import numpy as np
import pymunk

from swarm_env.env import SwarmEnv
from swarm_env.sim import world as world_mod
from swarm_env.sim.bodies import velocity_callback


def _world(name: str = "paper_vo_45") -> world_mod.World:
    env = SwarmEnv(name)
    env.reset(seed=0)
    return env._world


def _robots(w: world_mod.World) -> list[pymunk.Body]:
    return w._bodies + ([w._leader_body] if w._leader_body is not None else [])


def _run(w: world_mod.World, steps: int, seed: int = 1) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(steps):
        w.step(rng.uniform(-1.0, 1.0, (w.n, 2)) * 0.8)
        out.append(w._reader._read_properties())
    return out


def test_fast_velocity_callback_matches_the_python_one_bit_for_bit() -> None:
    fast = _world()
    plain = copy.deepcopy(fast)
    assert all(hasattr(b, "_fast_drive") for b in _robots(fast))
    for b in _robots(plain):
        b.velocity_func = velocity_callback  # back to pymunk's trampoline and the Python callback
    a, b = _run(fast, 60), _run(plain, 60)
    assert any(np.any(x[:, 3:] != 0.0) for x in a)  # robots moved
    for x, y in zip(a, b):
        assert x.tobytes() == y.tobytes()


def test_batch_reader_matches_body_properties() -> None:
    w = _world()
    _run(w, 20)
    assert w._reader._batch is not None  # pymunk.batch passed its self-test here
    np.testing.assert_array_equal(w._reader.read(), w._reader._read_properties())
    w._reader._batch = None  # the fallback reads the same numbers
    np.testing.assert_array_equal(w._reader.read(), w._reader._read_properties())


def test_copies_get_their_own_fast_callbacks_and_continue_identically() -> None:
    w = _world()
    _run(w, 10)
    for clone in (copy.deepcopy(w), pickle.loads(pickle.dumps(w))):
        assert all(hasattr(b, "_fast_drive") for b in _robots(clone))
        assert clone._reader.read().tobytes() == w._reader.read().tobytes()
    twin = copy.deepcopy(w)
    for x, y in zip(_run(w, 15, seed=4), _run(twin, 15, seed=4)):
        assert x.tobytes() == y.tobytes()


def test_compiled_velocity_callback_is_installed_and_matches_the_python_one_with_limits() -> None:
    from swarm_env.sim import drive_kernel

    assert drive_kernel.available()  # probed layout and self-test passed on this platform
    import dataclasses

    from swarm_env.scenarios.loader import load_scenario

    scn = load_scenario("paper_cbs_switch")
    limited = dataclasses.replace(scn, robots=dataclasses.replace(scn.robots, max_accel=0.8, max_turn_accel=2.0))
    env = SwarmEnv(limited)  # the acceleration-limited branch
    env.reset(seed=4)
    fast = env._world
    assert all(isinstance(b._fast_drive, tuple) for b in _robots(fast))  # the compiled callback
    plain = copy.deepcopy(fast)
    for b in _robots(plain):
        b.velocity_func = velocity_callback
    a, b = _run(fast, 80), _run(plain, 80)
    assert any(np.any(x[:, 3:] != 0.0) for x in a)
    for x, y in zip(a, b):
        assert x.tobytes() == y.tobytes()
    assert all(np.isfinite(r.drive[4:]).all() for r in _robots(fast))


def test_compiled_callbacks_of_copies_use_their_own_drive_state() -> None:
    w = _world()
    _run(w, 5)
    twin = copy.deepcopy(w)
    before = [b.drive.copy() for b in _robots(twin)]
    _run(w, 20, seed=9)  # stepping the original must not touch the copy's drive arrays
    for b, d in zip(_robots(twin), before):
        assert b.drive.tobytes() == d.tobytes()
        assert b._fast_drive[1] is b.drive


def test_worlds_built_with_the_kernels_off_use_the_python_level_callbacks() -> None:
    from swarm_env.compiled import use_compiled_kernels

    use_compiled_kernels(False)
    try:
        w = _world()
    finally:
        use_compiled_kernels(True)
    assert not any(isinstance(getattr(b, "_fast_drive", None), tuple) for b in _robots(w))
    fast = _world()
    for x, y in zip(_run(w, 30), _run(fast, 30)):
        assert x.tobytes() == y.tobytes()
