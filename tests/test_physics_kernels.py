"""The compiled physics stage (swarm_env.sim.physics_kernel, swarm_env.geometry.slot_kernel, PackedHumans.states_at)
gives its numpy / Python references' bits; World.step's fast paths give the plain path's episodes."""

from __future__ import annotations

import copy
import math
import pickle

import numpy as np
import pymunk
import pytest

from swarm_env.env import SwarmEnv
from swarm_env.geometry import formation as formation_lib
from swarm_env.geometry import slot_kernel
from swarm_env.geometry.paths import PolylinePath, human_paths, virtual_leader
from swarm_env.geometry.static_map import StaticMap
from swarm_env.scenario import HumanSpec
from swarm_env.scenarios.loader import load_scenario
from swarm_env.sim import physics_kernel
from swarm_env.sim import world as world_mod
from swarm_env.sim.human_kernel import PackedHumans


def _world(name: str, seed: int = 0, **kwargs: object) -> world_mod.World:
    env = SwarmEnv(name, **kwargs)
    env.reset(seed=seed)
    return env._world


def _reference_screen(static: StaticMap, pts: np.ndarray, c: float) -> bool:
    """project_free's first screen (StaticMap._project_fast), in numpy: no point suspect?"""
    W, H = static.size
    x, y = pts[:, 0], pts[:, 1]
    reach = c + 1e-7
    sus = np.minimum(np.minimum(x, W - x), np.minimum(y, H - y)) < reach
    if len(static._bound):
        bx, by, brad = static._bound_cols
        d2 = (x - bx) * (x - bx) + (y - by) * (y - by)
        r = brad + reach
        sus |= (d2 < r * r).any(axis=0)
    return not bool(sus.any())


# ---------------------------------------------------------------------------------- slot kernel
PATHS = [
    [(1.0, 1.0), (9.0, 1.0), (9.0, 7.0), (2.0, 7.5)],
    [(5.0, 5.0), (5.0, 5.0)],  # degenerate
    [(3.0, 2.0), (3.0, 2.0 + 1e-12), (8.0, 9.0), (8.0, 9.0), (1.5, 3.25)],  # duplicates dropped
]


@pytest.mark.parametrize("points", PATHS)
def test_virtual_slots_match_virtual_leader_and_slot_targets(points: list[tuple[float, float]]) -> None:
    path = PolylinePath(points)
    packed = slot_kernel.pack_path(path)
    scn = load_scenario("paper_cbs_switch")
    smap = StaticMap.from_obstacles(scn.world.size, scn.obstacles)
    offsets = np.ascontiguousarray(formation_lib.formation_offsets(scn.formations[0], 8), dtype=np.float64)
    clearance = 0.3 + formation_lib.SLOT_MARGIN
    screen, size_reach = smap.slot_screen(clearance)
    # times before the start delay, along the path, exactly on vertices, after the end
    times = np.concatenate([np.arange(0.0, 60.0, 0.1), path.cumulative / 0.5 + 2.0, [2.0, 1e6]])
    frees = set()
    for t in times.tolist():
        for speed in (0.5, 0.0):
            leader, targets, free = slot_kernel.virtual_slots(packed, path.length, speed, 2.0, t, offsets, screen,
                                                              size_reach)
            pose, vel, done = virtual_leader(path, speed, t, 2.0)
            assert leader[0:3].tobytes() == pose.tobytes(), t
            assert leader[3:5].tobytes() == vel.tobytes(), t
            assert bool(leader[5]) == done
            want = formation_lib.slot_targets(pose, offsets, None, 0.0)
            assert targets.tobytes() == want.tobytes(), t
            assert free == _reference_screen(smap, want, clearance)
            if free:  # the screen's promise: project_free leaves them as they are
                assert smap.project_free(want, clearance).tobytes() == want.tobytes()
            frees.add(free)
            got, free2 = slot_kernel.slots(pose, offsets, screen, size_reach)
            assert got.tobytes() == want.tobytes() and free2 == free
    if len(points) > 2:
        assert frees == {True, False}  # both outcomes exercised on the first path


@pytest.mark.parametrize("points", PATHS)
def test_unprojected_slot_trajectory_is_the_leader_step_by_step(points: list[tuple[float, float]]) -> None:
    """The compiled trajectory (slot_kernel.slot_trajectory) is, row by row, virtual_leader at k * dt, the
    formation active then and slot_targets: the definition the random generator's checks rely on."""
    import dataclasses

    scn = load_scenario("paper_cbs_switch")  # a formation switch mid-episode
    scn = dataclasses.replace(scn, leader=dataclasses.replace(scn.leader, path=tuple(points), start_delay=1.5))
    steps = 2000
    raw, index = formation_lib.unprojected_slot_trajectory(scn, steps)
    assert raw.shape == (steps + 1, scn.robots.count, 2) and index.shape == (steps + 1,)
    line = PolylinePath(scn.leader.path)
    offsets = [formation_lib.formation_offsets(f, scn.robots.count) for f in scn.formations]
    for k in range(steps + 1):
        t = k * scn.world.dt
        pose = virtual_leader(line, scn.leader.speed, t, scn.leader.start_delay)[0]
        f = formation_lib.active_formation(scn.formations, t)
        assert index[k] == f, k
        assert raw[k].tobytes() == formation_lib.slot_targets(pose, offsets[f], None, 0.0).tobytes(), k
    assert len(set(index.tolist())) == len(scn.formations) > 1  # the switch is in the trajectory


def test_slot_screen_rejects_non_finite_and_wall_points() -> None:
    smap = StaticMap(size=(10.0, 8.0), circles=np.array([[5.0, 4.0, 1.0]]), circle_ids=np.array([0]),
                     polygons=(), polygon_ids=np.zeros(0, dtype=np.int64))
    screen, size_reach = smap.slot_screen(0.5)
    offsets = np.zeros((1, 2))
    for pose, want in (((2.0, 2.0, 0.0), True), ((0.2, 2.0, 0.0), False), ((5.0, 2.6, 0.0), False),
                       ((math.nan, 2.0, 0.0), False), ((9.6, 7.0, 1.0), False)):
        targets, free = slot_kernel.slots(np.array(pose), offsets, screen, size_reach)
        assert free is want
        if np.isfinite(targets).all():
            assert free == _reference_screen(smap, targets, 0.5)


# ---------------------------------------------------------------------------------- humans
def test_states_at_rows_are_states() -> None:
    rng = np.random.default_rng(3)
    humans = [HumanSpec(path=tuple(map(tuple, rng.uniform(0, 20, (int(rng.integers(1, 5)), 2)).tolist())),
                        speed=float(rng.choice([0.0, 0.8, 1.3])), start_delay=float(rng.choice([0.0, 2.0])),
                        mode=str(rng.choice(["once", "loop", "pingpong"])), radius=0.3) for _ in range(25)]
    packed = PackedHumans(humans, human_paths(humans))
    times = np.concatenate([np.arange(0.0, 120.0, 0.025), rng.uniform(0, 1e4, 50)])
    pos, vel = packed.states_at(times)
    assert pos.shape == vel.shape == (len(times), len(humans), 2)
    for k, t in enumerate(times.tolist()):
        p, v = packed.states(t)
        assert pos[k].tobytes() == p.tobytes() and vel[k].tobytes() == v.tobytes()


# ---------------------------------------------------------------------------------- physics kernel
def test_clip_commands_is_python_min_max() -> None:
    rng = np.random.default_rng(0)
    cmd = rng.uniform(-3.0, 3.0, (64, 2))
    cmd[:6] = [[0.65, -1.0], [-0.65, 1.0], [-0.0, 0.0], [math.nan, 2.0], [math.inf, -math.inf], [0.649, -0.999]]
    drives = np.full((65, 6), 7.0)
    physics_kernel.clip_commands(cmd, 0.65, 1.0, drives)
    for i, (v, w) in enumerate(cmd.tolist()):
        want = (min(max(v, -0.65), 0.65), min(max(w, -1.0), 1.0))
        assert np.array([drives[i, 0], drives[i, 1]]).tobytes() == np.array(want).tobytes()
    assert (drives[:, 2:] == 7.0).all() and (drives[64] == 7.0).all()  # nothing else written


def test_physics_kernel_available_here() -> None:
    assert physics_kernel.available()  # x86-64 / AArch64 Linux: the self-test passed


def _trace(w: world_mod.World, steps: int, seed: int) -> list[bytes]:
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(steps):
        w.step(rng.uniform(-1.0, 1.0, (w.n, 2)))
        raw = w._reader._read_properties()
        hb = [(tuple(b.position), tuple(b.velocity)) for b in w._human_bodies]
        out.append(raw.tobytes() + repr((hb, w._onsets, w._touching_step, w._slots.tobytes(), w.formation_index,
                                         w._leader_done, w._human_pos.tobytes(), w._human_vel.tobytes())).encode())
    return out


@pytest.mark.parametrize("name,kwargs", [
    ("random", {"n_followers": 8, "n_obstacles": 10, "n_humans": 3, "world_size": (29.0, 20.0)}),
    ("crowd_reactive", {}),
    ("random", {"n_followers": 6, "n_humans": 2, "leader_kind": "robot"}),
    ("paper_cbs_switch", {}),
])
def test_compiled_step_matches_the_python_step(name: str, kwargs: dict, monkeypatch: pytest.MonkeyPatch) -> None:
    fast = _world(name, 2, **kwargs)
    plain = copy.deepcopy(fast)
    a = _trace(fast, 120, 5)
    assert fast._compiled_substeps_ok()
    reactive = any(h.behavior != "scripted" for h in fast.scenario.humans)
    assert (fast._phys_scripted is None) == reactive  # scripted humans: physics_kernel.scripted_step
    monkeypatch.setattr(world_mod.World, "_compiled_substeps_ok", lambda self: False)
    monkeypatch.setattr(world_mod.World, "_advance_virtual_leader_and_slots",
                        lambda self: (self._advance_leader(), self._compute_slots())[1])
    b = _trace(plain, 120, 5)
    assert any(b"robot_" in x for x in a)  # contacts happened
    assert a == b


def test_copies_continue_identically_on_the_compiled_path() -> None:
    w = _world("crowd_reactive", 1)
    _trace(w, 15, 0)
    clones = [copy.deepcopy(w), pickle.loads(pickle.dumps(w))]
    for c in clones:
        assert c._drives is not w._drives and all(b.drive.base is c._drives for b in c._bodies)
    want = _trace(w, 40, 3)
    for c in clones:
        assert _trace(c, 40, 3) == want


def test_space_step_mirrors_pymunk_post_step_work() -> None:
    """_space_step runs what a collision callback deferred and the post-step callbacks, as Space.step."""

    def make() -> tuple[pymunk.Space, list[str]]:
        space = pymunk.Space()
        log: list[str] = []
        a = pymunk.Body(1.0, 1.0)
        a.velocity = (1.0, 0.0)
        b = pymunk.Body(1.0, 1.0)
        b.position = (1.5, 0.0)
        for body, ct in ((a, 1), (b, 2)):
            shape = pymunk.Circle(body, 0.5)
            shape.collision_type = ct
            space.add(body, shape)

        def begin(arb: pymunk.Arbiter, sp: pymunk.Space, data: object) -> None:
            extra = pymunk.Body(1.0, 1.0)
            extra.position = (len(sp.bodies) * 3.0, 5.0)
            sp.add(extra, pymunk.Circle(extra, 0.1))  # deferred: the space is locked
            sp.add_post_step_callback(lambda s, key: log.append(f"post {key} {len(s.bodies)}"), len(log))
            log.append(f"begin {len(sp.bodies)}")

        space.on_collision(1, 2, begin=begin)
        space.step(0.01)
        return space, log

    s1, log1 = make()
    s2, log2 = make()
    for _ in range(60):
        s1.step(0.02)
        world_mod._space_step(s2, 0.02)
    assert log1 == log2 and any(x.startswith("post") for x in log1)
    assert [tuple(b.position) for b in s1.bodies] == [tuple(b.position) for b in s2.bodies]
