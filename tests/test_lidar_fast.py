"""The faster lidar kernel (issue 11) gives the bits of the plain kernel it replaced.

``swarm_env.sensing.lidar.scan`` culls polygons by their bounding disc, keeps per-robot candidate arrays and
tests circles without branches; ``scan_reference`` is the previous kernel, kept verbatim. Every test
here compares the two bit for bit, on random worlds and on placements built to sit on the edges of
the culls: rays grazing discs, origins at ``max_range`` from an edge or a polygon's bounding disc,
discs overlapping, origins inside things, headings far from ``[-pi, pi]``.
"""

from __future__ import annotations

import numpy as np
import pytest

from swarm_env.env import SwarmEnv
from swarm_env.geometry.static_map import StaticMap
from swarm_env.scenario import CircleObstacle, PolygonObstacle, RectangleObstacle
from swarm_env.sensing.lidar import PackedMaps, pack_discs, pack_inputs, scan, scan_reference
from swarm_env.sensing.observations import lidar_input, moving_discs

RAYS = 2.0 * np.pi * np.arange(16) / 16


def _random_map(rng: np.random.Generator, size: tuple[float, float]) -> StaticMap:
    w, h = size
    obs: list = []
    for i in range(int(rng.integers(0, 12))):
        c = (float(rng.uniform(1.0, w - 1.0)), float(rng.uniform(1.0, h - 1.0)))
        kind = i % 3
        if kind == 0:
            obs.append(CircleObstacle(c, float(rng.uniform(0.2, 1.5))))
        elif kind == 1:
            obs.append(RectangleObstacle(c, tuple(rng.uniform(0.3, 3.0, 2)), float(rng.uniform(-90, 90))))
        else:
            m = int(rng.integers(3, 8))
            a = np.sort(rng.uniform(0.0, 2 * np.pi, m))
            pts = np.c_[np.cos(a), np.sin(a)] * rng.uniform(0.3, 2.0) + c
            obs.append(PolygonObstacle(tuple(tuple(p) for p in (pts if rng.random() < 0.5 else pts[::-1]))))
    return StaticMap.from_obstacles(size, obs)


def _edge_origins(rng: np.random.Generator, static: StaticMap, max_range: float, k: int) -> np.ndarray:
    """Origins placed on the culls' edges: at ``max_range`` (exactly, and a few ulps either side)
    from a segment's end or interior, from a polygon's bounding disc, on a vertex, on an edge."""
    out = []
    seg = static.segments
    bound = static._bound[len(static.circles):]
    for _ in range(k):
        choice = rng.integers(0, 5)
        s = seg[rng.integers(0, len(seg))]
        a, b = s[:2], s[2:]
        if choice == 0:  # max_range from an endpoint, in a random direction
            ang = rng.uniform(0, 2 * np.pi)
            p = a + max_range * np.array([np.cos(ang), np.sin(ang)])
        elif choice == 1:  # max_range from the edge's interior, along its normal
            e = b - a
            n = np.array([e[1], -e[0]]) / np.hypot(*e)
            p = a + rng.uniform(0, 1) * e + rng.choice([-1.0, 1.0]) * max_range * n
        elif choice == 2 and len(bound):  # max_range (+ radius) from a polygon's bounding disc
            c = bound[rng.integers(0, len(bound))]
            ang = rng.uniform(0, 2 * np.pi)
            p = c[:2] + (max_range + c[2]) * np.array([np.cos(ang), np.sin(ang)])
        elif choice == 3:  # on a vertex
            p = a.copy()
        else:  # on an edge
            p = a + rng.uniform(0, 1) * (b - a)
        p = p + rng.integers(-3, 4, 2) * np.spacing(np.abs(p) + 1.0)
        out.append(p)
    return np.array(out).reshape(-1, 2)


def _grazing_discs(rng: np.random.Generator, origins: np.ndarray, headings: np.ndarray) -> np.ndarray:
    """Discs tangent to a ray of a robot (the centre at exactly ``r`` from the ray's line), or
    touching the origin's ``max_range`` circle, or overlapping each other."""
    discs = []
    for o, th in zip(origins, headings):
        ray = th + RAYS[rng.integers(0, len(RAYS))]
        d = np.array([np.cos(ray), np.sin(ray)])
        r = float(rng.uniform(0.05, 0.6))
        along = float(rng.uniform(0.5, 6.0))
        side = rng.choice([-1.0, 1.0]) * r * (1.0 + rng.integers(-2, 3) * 2.0**-52)
        discs.append([*(o + along * d + side * np.array([-d[1], d[0]])), r])
    discs = np.array(discs)
    overlap = discs[rng.integers(0, len(discs), len(discs) // 3)].copy()
    overlap[:, :2] += rng.uniform(-0.2, 0.2, (len(overlap), 2))
    return np.concatenate([discs, overlap])


def _check_world_batch(rng: np.random.Generator, n_worlds: int, max_range: float) -> tuple[np.ndarray, int]:
    sizes = [(float(rng.uniform(6, 30)), float(rng.uniform(6, 20))) for _ in range(n_worlds)]
    maps = [_random_map(rng, s) for s in sizes]
    poses, world, own, per_world = [], [], [], []
    for w, (static, (sw, sh)) in enumerate(zip(maps, sizes)):
        n = int(rng.integers(0, 10))
        free = np.c_[rng.uniform(0.1, sw - 0.1, n), rng.uniform(0.1, sh - 0.1, n)]
        edge = _edge_origins(rng, static, max_range, int(rng.integers(0, 8)))
        xy = np.concatenate([free, edge])
        heading = rng.uniform(-np.pi, np.pi, len(xy)) + rng.choice([0.0, 2 * np.pi, -40 * np.pi, 1e3], len(xy))
        robots = np.c_[xy, rng.uniform(0.1, 0.4, len(xy))]
        others = _grazing_discs(rng, xy, heading) if len(xy) else np.zeros((0, 3))
        per_world.append(np.concatenate([robots, others]))
        poses.append(np.c_[xy, heading])
        world += [w] * len(xy)
        own += list(range(len(xy)))
    start, discs = pack_discs(per_world)
    packed = PackedMaps.of(maps)
    args = (np.concatenate(poses), np.array(world, dtype=np.int64), np.array(own, dtype=np.int64), RAYS, max_range,
            packed, start, discs)
    got, want = scan(*args), scan_reference(*args)
    assert got.shape == want.shape
    assert np.array_equal(got.view(np.int64), want.view(np.int64))  # bits, -0.0 included
    return got, len(got)


@pytest.mark.parametrize("max_range", [5.0, 2.5, 12.0])
def test_fast_kernel_equals_reference_on_random_worlds(max_range: float) -> None:
    rng = np.random.default_rng(int(max_range * 10))
    results = [_check_world_batch(rng, 40, max_range)[0] for _ in range(4)]
    d = np.concatenate(results)
    # the worlds exercise every outcome: misses, hits, zeros (origins inside things), grazing hits
    assert np.any(d == max_range) and np.any(d == 0.0) and np.any((d > 0.0) & (d < max_range))


def test_fast_kernel_equals_reference_in_the_batched_engine_world() -> None:
    """The benchmark world (random, 8 followers, humans) after some random steps, and a robot leader."""
    from swarm_env.harness.bench import BATCH_WORLD
    from swarm_env.vector.engine import SwarmVectorEnv

    venv = SwarmVectorEnv("random", 8, **BATCH_WORLD)
    venv.reset(seed=3)
    rng = np.random.default_rng(3)
    envs = [SwarmEnv("paper_vo_0"), SwarmEnv("random", n_followers=5, n_humans=(0, 0))]
    for m, env in enumerate(envs):
        env.reset(seed=m)
    for _ in range(6):
        venv.step(rng.uniform(-1, 1, (8, venv.num_agents, 2)))
        for env in envs:
            env.step({a: env.action_space(a).sample() for a in env.agents})
        states = [e._state for e in venv._local.envs] + [env.world_state() for env in envs]  # type: ignore[union-attr]
        packed = PackedMaps.of([s.static for s in states])
        poses, world, own, start, discs = pack_inputs([lidar_input(s) for s in states])
        got = scan(poses, world, own, RAYS, 5.0, packed, start, discs)
        want = scan_reference(poses, world, own, RAYS, 5.0, packed, start, discs)
        assert np.array_equal(got, want)


def test_pack_inputs_lays_out_the_discs_of_moving_discs() -> None:
    """One pass over many worlds gives the arrays the per-world packing gave (a robot leader, no humans)."""
    envs = [SwarmEnv("paper_vo_0"), SwarmEnv("random", n_humans=(0, 0)), SwarmEnv("random", n_humans=(2, 4))]
    states = []
    for m, env in enumerate(envs):
        env.reset(seed=7 + m)
        states.append(env.world_state())
    assert states[0].leader_is_robot and not len(states[1].human_pos)
    poses, world, own, start, discs = pack_inputs([lidar_input(s) for s in states])
    want_start, want_discs = pack_discs([moving_discs(s) for s in states])
    assert np.array_equal(start, want_start) and np.array_equal(discs, want_discs)
    assert np.array_equal(poses, np.concatenate([s.follower_pose for s in states]))
    assert np.array_equal(world, np.repeat(np.arange(3), [s.n_followers for s in states]))
    assert np.array_equal(own, np.concatenate([np.arange(s.n_followers) for s in states]))
    one = pack_inputs([lidar_input(states[0])])
    assert np.array_equal(one[4], moving_discs(states[0])) and np.array_equal(one[2], np.arange(states[0].n_followers))


def test_packed_maps_index_each_polygons_edges_and_the_walls() -> None:
    rng = np.random.default_rng(5)
    maps = [_random_map(rng, (20.0, 12.0)) for _ in range(6)] + [StaticMap.from_obstacles((5.0, 5.0), [])]
    packed = PackedMaps.of(maps)
    for w, static in enumerate(maps):
        rows = packed.segments[packed.seg_start[w]:packed.seg_start[w + 1]]
        assert np.array_equal(rows, static.segments)
        p0 = packed.poly_start[w]
        for p, count in enumerate(static.poly_counts):
            first, stop = packed.poly_edges[p0 + p]
            assert stop - first == count
            assert np.array_equal(packed.segments[first, :2], static.poly_vertices[p, 0])
        assert packed.seg_start[w + 1] - packed.wall_start[w] == 4  # the walls come last


def _same_packing(a: PackedMaps, b: PackedMaps) -> None:
    for key in ("seg_start", "segments", "circ_start", "circles", "poly_start", "poly_normals", "poly_offsets",
                "poly_bound", "poly_edges", "wall_start", "widths"):
        x, y = getattr(a, key), getattr(b, key)
        assert (x.dtype, x.shape, x.tobytes()) == (y.dtype, y.shape, y.tobytes()), key
        assert y.flags.c_contiguous, key


def test_replacing_some_worlds_maps_packs_what_packing_them_all_gives() -> None:
    """``PackedMaps.replaced`` (the batched engine's update when a few worlds start a new episode) gives
    ``PackedMaps.of``'s arrays exactly: changes at the ends and in the middle, runs of neighbours, maps
    without obstacles, and a change of the padded polygon width (which repacks everything)."""
    rng = np.random.default_rng(11)
    pool = [_random_map(rng, (20.0, 12.0)) for _ in range(40)] + [StaticMap.from_obstacles((5.0, 5.0), [])]
    maps = [pool[int(k)] for k in rng.integers(0, len(pool), 24)]
    packed = PackedMaps.of(maps)
    widths = {packed.poly_normals.shape[1]}
    for trial in range(60):
        k = int(rng.integers(1, 6))
        changed = [0, 23] if trial == 0 else rng.choice(24, k, replace=False).tolist()
        for w in changed:
            maps[w] = pool[int(rng.integers(0, len(pool)))]
        packed = packed.replaced(maps, changed)
        _same_packing(PackedMaps.of(maps), packed)
        widths.add(packed.poly_normals.shape[1])
    assert packed.replaced(maps, []) is packed
    # the padded polygon width Mmax grows and shrinks (repacked from scratch), or stays while a wide map
    # remains elsewhere (replaced): the same arrays either way
    wide = max(pool, key=lambda m: m.poly_normals.shape[1])
    maps = [pool[-1]] * 24  # no polygons: Mmax 1
    packed = PackedMaps.of(maps)
    for w, static in ((5, wide), (9, wide), (5, pool[-1]), (9, pool[-1])):
        maps[w] = static
        packed = packed.replaced(maps, [w])
        _same_packing(PackedMaps.of(maps), packed)
        widths.add(packed.poly_normals.shape[1])
    assert len(widths) > 1
    # the scans agree too
    poses = np.c_[rng.uniform(0, 20, (48, 2)), rng.uniform(-np.pi, np.pi, 48)]
    world = np.repeat(np.arange(24), 2)
    own = np.zeros(48, dtype=np.int64)
    start, discs = pack_discs([np.c_[poses[2 * w:2 * w + 2, :2], np.full(2, 0.2)] for w in range(24)])
    got = scan(poses, world, own, RAYS, 5.0, packed, start, discs)
    assert got.tobytes() == scan(poses, world, own, RAYS, 5.0, PackedMaps.of(maps), start, discs).tobytes()
