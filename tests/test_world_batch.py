"""swarm_env.vector.world_batch: the physics and snapshots of M worlds in one call give, bit for bit, what
``World.step`` then ``World.snapshot`` give world by world, and leave the worlds in the same state."""

from __future__ import annotations

import copy
import pickle
from typing import Any

import numpy as np
import pytest

from swarm_env.compiled import compiled_kernels, use_compiled_kernels
from swarm_env.env import SwarmEnv
from swarm_env.geometry.static_map import StaticMap
from swarm_env.harness.bench import BATCH_WORLD
from swarm_env.scenarios.loader import list_scenarios
from swarm_env.sim import drive_kernel
from swarm_env.sim.world import World
from swarm_env.state import WorldState
from swarm_env.vector import world_batch
from swarm_env.vector.world_batch import WorldBatch, step_and_snapshot


def _envs(specs: list[tuple[str, dict[str, Any], int]]) -> list[SwarmEnv]:
    out = []
    for name, kwargs, seed in specs:
        env = SwarmEnv(name, **kwargs)
        env.reset(seed=seed)
        out.append(env)
    return out


def _worlds(specs: list[tuple[str, dict[str, Any], int]]) -> list[World]:
    return [e._world for e in _envs(specs)]  # type: ignore[misc]


def assert_same_state(a: WorldState, b: WorldState, world: World) -> None:
    """Every field of two snapshots equal: arrays by dtype, shape, bytes and read-only flag; the map and
    the scenario ``world``'s own objects; the rest by type and value."""
    assert type(b) is WorldState
    assert list(a.__dict__) == list(b.__dict__)
    for key, x in a.__dict__.items():
        y = b.__dict__[key]
        if isinstance(x, np.ndarray):
            assert isinstance(y, np.ndarray), key
            assert (x.dtype, x.shape, x.tobytes()) == (y.dtype, y.shape, y.tobytes()), key
            assert x.flags.writeable == y.flags.writeable, key
            assert y.flags.c_contiguous, key
        elif key in ("static", "scenario"):
            assert y is getattr(world, key) and type(x) is type(y), key  # (the reference has its own copy)
        elif key == "_derived":
            assert y == {} and y is not x
        else:
            assert type(x) is type(y) and x == y, (key, x, y)


def assert_stacked(batch: WorldBatch, states: list[WorldState]) -> None:
    """``batch.last_arrays()`` is the snapshots' fields stacked, bit for bit (``None`` unless every
    world took the batched path), in new writeable arrays."""
    got = batch.last_arrays()
    if batch.last_batched != len(states):
        assert got is None
        return
    assert got is not None
    h = max(len(s.human_pos) for s in states)

    def padded(a: np.ndarray) -> np.ndarray:
        return np.concatenate([a, np.zeros((h - len(a), 2))])

    want = {
        "pose": np.stack([s.follower_pose for s in states]), "vel": np.stack([s.follower_vel for s in states]),
        "twist": np.stack([s.follower_twist for s in states]), "slots": np.stack([s.slot_targets for s in states]),
        "lpose": np.stack([s.leader_pose for s in states]), "lvel": np.stack([s.leader_vel for s in states]),
        "ltwist": np.stack([s.leader_twist for s in states]),
        "hpos": np.stack([padded(s.human_pos) for s in states]), "hvel": np.stack([padded(s.human_vel) for s in states]),
        "hcount": np.array([len(s.human_pos) for s in states], dtype=np.int64),
        "time": np.array([s.time for s in states]), "step": np.array([s.step for s in states], dtype=np.int64),
        "leader_done": np.array([s.leader_done for s in states]),
        "k": np.array([s.formation_index for s in states], dtype=np.int64),
        "next_switch": np.array([s.next_switch_time for s in states]),
    }
    assert set(got) == set(want) | {"touching", "contacts"}
    for key, x in want.items():
        y = got[key]
        assert (x.dtype, x.shape, x.tobytes()) == (y.dtype, y.shape, y.tobytes()), key
        assert y.flags.writeable and y.flags.c_contiguous, key
    assert got["touching"] == [m for m, s in enumerate(states) if s.touching]
    assert got["contacts"] == [m for m, s in enumerate(states) if s.contacts]


def world_digest(w: World) -> bytes:
    """The state a world carries from one step to the next (what a later step reads)."""
    raw = w._reader._read_properties()
    humans = [(tuple(b.position), tuple(b.velocity), b.angle, b.angular_velocity) for b in w._human_bodies]
    leader = w._leader_body
    lead = None if leader is None else (tuple(leader.position), leader.angle, tuple(leader.velocity),
                                        leader.angular_velocity, leader.drive.tobytes())
    arrays = [w._drives, w._slots, np.asarray(w._virtual_pose, dtype=float), np.asarray(w._virtual_vel, dtype=float),
              w._human_pos, w._human_vel, w._react_start, w._react_vel]
    return raw.tobytes() + repr((
        humans, lead, [a.tobytes() for a in arrays], [b.drive.tobytes() for b in w._bodies], w.time, w.step_count,
        w.formation_index, w._leader_done, w._leader_s, sorted(w._touching), sorted(w._touched_step),
        sorted(w._touched_prev), w._onsets, w._touching_step, len(w.space._bodies_to_check),
    )).encode()


def lockstep(ref: list[World], bat: list[World], steps: int, seed: int, batch: WorldBatch | None = None,
             scale: float = 1.0) -> tuple[WorldBatch, list[int], list[WorldState]]:
    """Step ``ref`` world by world and ``bat`` through a batch with the same commands, comparing every
    snapshot and every world's state after each step. Returns the batch, how many worlds it
    batched at each step, and the last snapshots."""
    batch = WorldBatch(bat) if batch is None else batch
    rng = np.random.default_rng(seed)
    n = ref[0].n
    batched = []
    states: list[WorldState] = []
    for _ in range(steps):
        cmd = rng.uniform(-1.0, 1.0, (len(ref), n, 2)) * scale
        delivered: list[int] = []

        def on_states(indices: list[int], got: list[Any]) -> None:
            assert indices == sorted(indices) and all(got[m] is not None for m in indices)
            delivered.extend(indices)

        states = batch.step_and_snapshot(cmd, on_states=on_states)
        assert sorted(delivered) == list(range(len(ref)))
        batched.append(batch.last_batched)
        assert_stacked(batch, states)
        for w, c, s, wb in zip(ref, cmd, states, bat):
            w.step(c)
            assert_same_state(w.snapshot(), s, wb)
            assert world_digest(w) == world_digest(wb)
    return batch, batched, states


# The built-in scenarios with M = 3 copies each (different commands per copy), random worlds with
# humans, formation switches, robot leaders and reactive humans.
RANDOM_SWITCHING = {"n_switches": 2, "max_time": 14.0, "n_humans": (0, 3)}
CASES = [(name, {}, 3, 170 if name == "paper_cbs_switch" else 160) for name in list_scenarios() if name != "random"]
CASES += [
    ("random", BATCH_WORLD, 6, 60),
    ("random", RANDOM_SWITCHING, 6, 150),
    ("random", {"n_humans": 3, "human_behavior": "social_force"}, 3, 40),
    ("random", {"n_humans": 2, "human_behavior": "orca"}, 3, 40),
    ("random", {"n_followers": 5, "leader_kind": "robot", "n_humans": 2}, 3, 40),
]


@pytest.mark.parametrize("name,kwargs,m,steps", CASES, ids=[f"{c[0]}-{i}" for i, c in enumerate(CASES)])
def test_lockstep_with_the_per_world_loop(name: str, kwargs: dict[str, Any], m: int, steps: int) -> None:
    specs = [(name, kwargs, 11 + k) for k in range(m)]
    ref, bat = _worlds(specs), _worlds(specs)
    batch, batched, _ = lockstep(ref, bat, steps, seed=len(name) + m)
    eligible = world_batch._batchable(bat[0])
    robot_or_reactive = bat[0]._leader_body is not None or len(bat[0]._reactive) > 0
    assert eligible != robot_or_reactive
    assert batched[0] == 0  # a world's first step is pymunk's own (it checks its new bodies)
    assert batched[1:] == [m if eligible else 0] * (steps - 1)


def test_random_worlds_exercise_contacts_projection_humans_and_switches(monkeypatch: pytest.MonkeyPatch) -> None:
    """The lockstep above covers the batched path's branches: contact onsets, slots projected out of
    obstacles (project_free called by the batch), humans of different counts, formation switches."""
    calls = []
    original = StaticMap.project_free

    def spy(self: StaticMap, points: np.ndarray, clearance: float) -> np.ndarray:
        calls.append(1)
        return original(self, points, clearance)

    specs = [("random", RANDOM_SWITCHING, 40 + k) for k in range(8)]
    ref, bat = _worlds(specs), _worlds(specs)
    monkeypatch.setattr(StaticMap, "project_free", spy)
    batch, batched, _ = lockstep(ref, bat, 2, seed=0, scale=1.0)
    calls.clear()
    seen = {"contacts": 0, "switch": 0}
    rng = np.random.default_rng(1)
    for _ in range(150):
        cmd = rng.uniform(-1.0, 1.0, (8, bat[0].n, 2))
        n_calls = len(calls)
        states = batch.step_and_snapshot(cmd)
        batch_calls = len(calls) - n_calls
        for w, c, s, wb in zip(ref, cmd, states, bat):
            w.step(c)
            assert_same_state(w.snapshot(), s, wb)
            seen["contacts"] += len(s.contacts)
            seen["switch"] += s.formation_index > 0
        assert batch.last_batched == 8
        if batch_calls:
            seen["projected"] = 1
    assert seen["contacts"] > 0 and seen["switch"] > 0 and seen.get("projected")
    assert len({len(w._human_bodies) for w in bat}) > 1  # different human counts in one batch


def test_stacked_arrays_over_chunks_with_different_human_counts_and_moved_slots() -> None:
    """``last_arrays`` (what the engine's batched stages read instead of the snapshots) stacks chunks
    whose kernel blocks have different human widths (padded), and the slots moved out of obstacles;
    lockstep compares it with the stacked snapshots at every step."""
    specs = [("random", {**RANDOM_SWITCHING, "n_followers": 8}, 10 + k) for k in range(6)]
    specs.append(("paper_cbs_switch", {}, 1))  # 8 followers too: every world takes the batched path
    ref, bat = _worlds(specs), _worlds(specs)
    widths = moved = 0
    batch = WorldBatch(bat, chunk=2)
    for step in range(60):  # (paper_cbs_switch's slots are first moved at step 54)
        lockstep(ref, bat, 1, seed=step, batch=batch)
        if step:
            assert batch.last_batched == len(bat)
            widths += len({c[1][9].shape[1] for c in batch._last}) > 1
            moved += sum(len(c[2]) for c in batch._last)
    assert widths and moved


def test_mixed_eligible_and_fallback_worlds_and_replacements() -> None:
    """Batched and per-world worlds in one call, in chunks of 2; worlds replaced mid-run (as auto-reset
    does), both by passing the current worlds and by replace(); a replaced world starts on pymunk's
    first step."""
    specs = [("random", BATCH_WORLD, 1), ("random", {**BATCH_WORLD, "leader_kind": "robot"}, 2),
             ("random", BATCH_WORLD, 3), ("random", {**BATCH_WORLD, "human_behavior": "social_force"}, 4),
             ("random", BATCH_WORLD, 5)]
    ref_envs, bat_envs = _envs(specs), _envs(specs)
    ref = [e._world for e in ref_envs]
    batch = WorldBatch([e._world for e in bat_envs], chunk=2)  # type: ignore[misc]  # three compiled calls a step
    batch, batched, _ = lockstep(ref, batch.worlds, 12, seed=3, batch=batch)
    assert batched[1:] == [3] * 11
    rng = np.random.default_rng(9)
    for step in range(40):
        if step in (5, 17):  # auto-reset of worlds 0 and 3 (new World objects), seen through worlds=
            for k in (0, 3):
                ref_envs[k]._start(100 + step + k)
                bat_envs[k]._start(100 + step + k)
        if step == 23:  # an explicit replace() of world 2
            ref_envs[2]._start(7)
            bat_envs[2]._start(7)
            batch.replace(2, bat_envs[2]._world)  # type: ignore[arg-type]
        worlds = [e._world for e in bat_envs]
        cmd = rng.uniform(-1.0, 1.0, (5, 8, 2))
        states = batch.step_and_snapshot(cmd, worlds=worlds)  # type: ignore[arg-type]
        assert batch.worlds == worlds
        for e, c, s, wb in zip(ref_envs, cmd, states, worlds):
            e._world.step(c)  # type: ignore[union-attr]
            assert_same_state(e._world.snapshot(), s, wb)  # type: ignore[union-attr, arg-type]
            assert world_digest(e._world) == world_digest(wb)  # type: ignore[arg-type]
        if step in (5, 17, 23):
            assert batch.last_batched == 2  # a new world's first step is its own (world 3 is never batched)
        else:
            assert batch.last_batched == 3


def test_snapshots_stay_valid_and_worlds_continue_alone() -> None:
    """A snapshot's arrays do not change when the batch steps again; a world stepped by the batch
    continues identically by itself, copied or pickled."""
    specs = [("random", BATCH_WORLD, 20 + k) for k in range(4)]
    ref, bat = _worlds(specs), _worlds(specs)
    batch, _, states = lockstep(ref, bat, 10, seed=2)
    kept = [{k: v.tobytes() for k, v in s.__dict__.items() if isinstance(v, np.ndarray)} for s in states]
    lockstep(ref, bat, 5, seed=4, batch=batch)
    for s, saved in zip(states, kept):
        assert {k: v.tobytes() for k, v in s.__dict__.items() if isinstance(v, np.ndarray)} == saved
        assert not any(v.flags.writeable for k, v in s.__dict__.items()
                       if isinstance(v, np.ndarray) and k not in ("follower_radius", "human_radius"))
    copies = [copy.deepcopy(bat[0]), pickle.loads(pickle.dumps(bat[1]))]
    rng = np.random.default_rng(5)
    for _ in range(20):
        cmd = rng.uniform(-1.0, 1.0, (4, 8, 2))
        for w, c in zip(ref + bat[2:] + copies, np.concatenate([cmd, cmd[2:], cmd[:2]])):
            w.step(c)
    for a, b in zip(ref[:2], copies):
        assert world_digest(a) == world_digest(b)
    assert world_digest(ref[2]) == world_digest(bat[2])


def test_kernels_off_and_odd_commands_take_the_worlds_own_step() -> None:
    specs = [("random", BATCH_WORLD, 30 + k) for k in range(3)]
    ref, bat = _worlds(specs), _worlds(specs)
    batch, batched, _ = lockstep(ref, bat, 3, seed=1)
    assert batched[-1] == 3
    assert compiled_kernels()
    use_compiled_kernels(False)
    try:
        _, batched, _ = lockstep(ref, bat, 3, seed=2, batch=batch)
    finally:
        use_compiled_kernels(True)
    assert batched == [0, 0, 0]
    _, batched, _ = lockstep(ref, bat, 3, seed=3, batch=batch)
    assert batched == [3, 3, 3]
    with pytest.raises(ValueError, match="commands must be"):
        batch.step_and_snapshot(np.zeros((2, 8, 2)))
    # N != the worlds' n: each world's own step decides (here it takes the first n rows, as World.step does)
    wide = np.random.default_rng(0).uniform(-1, 1, (3, 9, 2))
    states = batch.step_and_snapshot(wide)
    assert batch.last_batched == 0
    for w, c, s, wb in zip(ref, wide, states, bat):
        w.step(c)
        assert_same_state(w.snapshot(), s, wb)
    states = step_and_snapshot(bat, wide[:, :8])  # the function form, on a fresh batch
    for w, c, s, wb in zip(ref, wide[:, :8], states, bat):
        w.step(c)
        assert_same_state(w.snapshot(), s, wb)


def test_a_broken_batch_fails_the_comparison(monkeypatch: pytest.MonkeyPatch) -> None:
    """The comparison is sharp: one ulp in one follower's pose, or one robot's heading off by one ulp
    in one batched world (its physics diverges), is caught."""
    specs = [("random", BATCH_WORLD, 50 + k) for k in range(3)]
    ref, bat = _worlds(specs), _worlds(specs)
    batch, _, _ = lockstep(ref, bat, 3, seed=1)
    kernel = world_batch._batch_step

    def one_ulp(*args: Any) -> Any:
        out = list(kernel(*args))
        out[0][1, 0, 0] = np.nextafter(out[0][1, 0, 0], np.inf)
        return tuple(out)

    monkeypatch.setattr(world_batch, "_batch_step", one_ulp)
    with pytest.raises(AssertionError):
        lockstep(ref, bat, 1, seed=2, batch=batch)
    monkeypatch.setattr(world_batch, "_batch_step", kernel)
    ref, bat = _worlds(specs), _worlds(specs)
    batch, _, _ = lockstep(ref, bat, 3, seed=1)
    body = bat[2]._bodies[3]
    body.angle = float(np.nextafter(body.angle, np.inf))  # one robot's heading, one ulp off
    with pytest.raises(AssertionError):
        lockstep(ref, bat, 5, seed=3, batch=batch)


def test_body_layout_probe_and_arguments() -> None:
    assert world_batch.available()
    assert drive_kernel.probe_offsets() == drive_kernel.BODY_OFFSETS
    with pytest.raises(ValueError, match="chunk"):
        WorldBatch([], chunk=0)
    batch = WorldBatch([])
    with pytest.raises(IndexError):
        batch.replace(0, _worlds([("random", BATCH_WORLD, 0)])[0])
