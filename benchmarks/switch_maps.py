"""Scenario files with frequent formation switches, as issue 34's hidden maps are described: a new shape every
12-14 s through line, circle, column, wedge, grid, diamond and v, 6-8 followers behind a virtual leader at 0.35 m/s
on a path with 0-2 turns, 3-6 obstacles 1.4-2.8 m from the path, 2-4 walkers crossing it (social force on the odd
maps). Deterministic: map k draws from ``numpy.random.default_rng(seed_base + k)``.

The maps the ``vo`` expert's ``period_margin`` was chosen on (docs/vo_defaults.md) are::

    python benchmarks/switch_maps.py --dt 0.2 --prefix b --out DIR            # b0-b7
    python benchmarks/switch_maps.py --dt 0.25 --prefix d --out DIR           # d0-d7
    python benchmarks/switch_maps.py --dt 0.2 --seed-base 200 --prefix e --out DIR   # e0-e7
    python benchmarks/switch_maps.py --dt 0.1 --prefix m --out DIR            # m0-m7 (the default period)

``--broad N`` writes N maps that also draw what the issue does not say (map k from ``default_rng(seed_base + k)``):
a path with 0-2 turns, 6-8 followers, spacing 0.7-1.2 m, every shape in a random order (``v`` and ``wedge`` at 30,
45 or 60 degrees), a switch every 12-15 s, robots of radius 0.2-0.3 m, top speed 0.5-0.8 m/s and turn rate
0.8-1.5 rad/s, a control period of 0.05, 0.1 (twice as likely) or 0.15 s, walkers scripted, social-force or ORCA (by
map, in turn) and on half the maps one more walking the path head-on. The comparison of docs/vo_defaults.md
("The broad switch maps") is::

    python benchmarks/switch_maps.py --broad 160 --seed-base 3000 --prefix h --out maps/h

Many of these switches come sooner than their reach time (``swarm_env.scenarios.generator.switch_reach_times``),
so no policy settles every one: they are for contacts, not for settle times.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np
import yaml

CYCLE = ["line", "circle", "column", "wedge", "grid", "diamond", "v"]
#: Each map's leader path (m) and team size.
PATHS = [
    [[5, 10], [12, 12], [21, 9], [28, 11]],
    [[5, 6], [14, 9], [28, 12]],
    [[5, 12], [10, 10], [18, 12], [28, 9]],
    [[5, 9], [28, 9]],
    [[5, 5], [11, 8], [19, 12], [28, 14]],
    [[5, 11], [13, 9], [28, 11]],
    [[5, 14], [12, 12], [20, 9], [28, 8]],
    [[5, 8], [15, 11], [28, 9]],
]
COUNTS = [6, 7, 8, 6, 7, 8, 7, 6]
SPEED = 0.35  # the leader's (m/s)


def _segment_distance(p: list[float], a: list[float], b: list[float]) -> float:
    pa, pb, pp = np.asarray(a, float), np.asarray(b, float), np.asarray(p, float)
    d = pb - pa
    t = np.clip(np.dot(pp - pa, d) / np.dot(d, d), 0, 1)
    return float(np.linalg.norm(pp - (pa + t * d)))


def _path_distance(p: list[float], path: list[list[float]]) -> float:
    return min(_segment_distance(p, path[i], path[i + 1]) for i in range(len(path) - 1))


def _point_at(path: list[list[float]], s: float) -> tuple[list[float], float]:
    """The point at arc length ``s`` and the heading there."""
    for a, b in zip(path, path[1:]):
        length = math.dist(a, b)
        if s <= length:
            return [a[0] + (b[0] - a[0]) * s / length, a[1] + (b[1] - a[1]) * s / length], math.atan2(b[1] - a[1], b[0] - a[0])
        s -= length
    return list(path[-1]), 0.0


def _formations(rng: np.random.Generator, k: int, travel: float) -> list[dict]:
    """Every shape in turn from map k's (never a column first), a new one every 12-14 s until the leader stops."""
    forms: list[dict] = []
    at, i = 0.0, k % len(CYCLE)
    if CYCLE[i] == "column":
        i += 1
    while at < travel + 4:
        shape = CYCLE[i % len(CYCLE)]
        f: dict = {"at": round(at, 1), "shape": shape, "spacing": 1.0}
        if shape in ("v", "wedge"):
            f["angle"] = 45.0
        forms.append(f)
        i += 1
        at += float(rng.uniform(12, 14))
    return forms


def _obstacles(rng: np.random.Generator, path: list[list[float]]) -> list[dict]:
    """3-6 obstacles 1.4-2.8 m from the path, 2.5 m apart, none within 6 m of its start."""
    obs: list[dict] = []
    n_obs = int(rng.integers(3, 7))
    for _ in range(5000):
        if len(obs) >= n_obs:
            break
        p = [float(rng.uniform(6, 26)), float(rng.uniform(2, 18))]
        if not 1.4 <= _path_distance(p, path) <= 2.8:
            continue
        if any(math.dist(p, o["center"]) < 2.5 for o in obs) or math.dist(p, path[0]) < 6:
            continue
        centre = [round(p[0], 2), round(p[1], 2)]
        if rng.uniform() < 0.6:
            obs.append({"type": "circle", "center": centre, "radius": round(float(rng.uniform(0.3, 0.5)), 2)})
        else:
            size = [round(float(rng.uniform(0.6, 1.0)), 2), round(float(rng.uniform(0.5, 0.9)), 2)]
            obs.append({"type": "rectangle", "center": centre, "size": size, "angle": round(float(rng.uniform(-60, 60)), 0)})
    return obs


def _walkers(rng: np.random.Generator, path: list[list[float]], length: float, social: bool) -> list[dict]:
    """2-4 walkers crossing the path square to it, timed to meet the formation there."""
    humans = []
    for _ in range(int(rng.integers(2, 5))):
        s = float(rng.uniform(0.25, 0.85)) * length
        c, th = _point_at(path, s)
        nx, ny = -math.sin(th), math.cos(th)
        side = 1 if rng.uniform() < 0.5 else -1
        a = [min(max(c[0] + side * 6 * nx, 1.0), 30.0), min(max(c[1] + side * 6 * ny, 1.0), 21.0)]
        b = [min(max(c[0] - side * 6 * nx, 1.0), 30.0), min(max(c[1] - side * 6 * ny, 1.0), 21.0)]
        speed = round(float(rng.uniform(0.4, 0.6)), 2)
        delay = max(0.0, s / SPEED - 6 / speed + float(rng.uniform(-3, 6)))
        walker: dict = {"path": [[round(a[0], 2), round(a[1], 2)], [round(b[0], 2), round(b[1], 2)]], "speed": speed,
                        "start_delay": round(delay, 1)}
        if social:
            walker["behavior"] = "social_force"
        humans.append(walker)
    return humans


def _broad_path(rng: np.random.Generator) -> list[list[float]]:
    """A leader path from x = 5 to x = 28 m with 0-2 turns, its corners at y = 6-15 m."""
    xs = np.linspace(5, 28, int(rng.integers(0, 3)) + 2)
    return [[float(round(x, 1)), float(round(rng.uniform(6, 15), 1))] for x in xs]


def _broad_formations(rng: np.random.Generator, travel: float, spacing: float) -> list[dict]:
    """Every shape in a random order (never a column first), a new one every 12-15 s until the leader stops."""
    order = [str(s) for s in rng.permutation(CYCLE)]
    if order[0] == "column":
        order = order[1:] + order[:1]
    forms: list[dict] = []
    at, i = 0.0, 0
    while at < travel + 4:
        shape = order[i % len(order)]
        f: dict = {"at": round(at, 1), "shape": shape, "spacing": spacing}
        if shape in ("v", "wedge"):
            f["angle"] = float(rng.choice([30.0, 45.0, 60.0]))
        forms.append(f)
        i += 1
        at += float(rng.uniform(12, 15))
    return forms


def write_broad_maps(out: Path, n: int, seed_base: int, prefix: str) -> None:
    """Write ``n`` maps ``out/PREFIX{k}.yaml`` whose robots, period and walkers vary too (``--broad``)."""
    out.mkdir(parents=True, exist_ok=True)
    for k in range(n):
        rng = np.random.default_rng(seed_base + k)
        path = _broad_path(rng)
        count = int(rng.integers(6, 9))
        spacing = float(rng.choice([0.7, 0.8, 0.9, 1.0, 1.2]))
        radius = float(rng.choice([0.2, 0.25, 0.3]))
        max_speed = float(rng.choice([0.5, 0.65, 0.8]))
        max_turn = float(rng.choice([0.8, 1.0, 1.5]))
        dt = float(rng.choice([0.05, 0.1, 0.1, 0.15]))
        length = sum(math.dist(a, b) for a, b in zip(path, path[1:]))
        travel = length / SPEED
        forms = _broad_formations(rng, travel, spacing)
        obs = _obstacles(rng, path)
        behavior = ["scripted", "social_force", "orca"][k % 3]
        humans = _walkers(rng, path, length, False)
        if rng.uniform() < 0.5:  # one more walking the leader's path head-on
            humans.append({"path": [[float(c) for c in path[-1]], [float(c) for c in path[0]]],
                           "speed": round(float(rng.uniform(0.4, 0.6)), 2),
                           "start_delay": round(float(rng.uniform(0, 30)), 1)})
        for h in humans:
            if behavior != "scripted":
                h["behavior"] = behavior
        humans = [h for h in humans if all(math.dist(h["path"][0], o["center"]) > 1.5 for o in obs)]
        scn = {"name": f"{prefix}{k}",
               "description": f"{count} followers spacing {spacing} {behavior} r{radius} v{max_speed} w{max_turn} dt{dt}",
               "world": {"size": [31.0, 22.0], "dt": dt, "substeps": 4, "max_time": round(travel + 45, 0),
                         "settle_tolerance": 0.3},
               "robots": {"count": count, "radius": radius, "max_speed": max_speed, "max_turn_rate": max_turn,
                          "start": "formation"},
               "leader": {"kind": "virtual", "path": path, "speed": SPEED},
               "formations": forms, "obstacles": obs, "humans": humans}
        with open(out / f"{prefix}{k}.yaml", "w") as fh:
            yaml.safe_dump(scn, fh, sort_keys=False, default_flow_style=None)
    print(f"{out}: {n} maps {prefix}0-{prefix}{n - 1}")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dt", type=float, default=0.1, help="the control period of every map (s)")
    ap.add_argument("--seed-base", type=int, default=100, help="map k draws from default_rng(seed_base + k)")
    ap.add_argument("--prefix", default="m", help="file and scenario names: PREFIX0.yaml ... PREFIX7.yaml")
    ap.add_argument("--out", type=Path, required=True, help="directory to write the files to")
    ap.add_argument("--broad", type=int, metavar="N", help="write N maps that also vary the robots, the period and "
                    "the walkers (--dt is then ignored)")
    args = ap.parse_args(argv)
    if args.broad is not None:
        if args.broad < 1:
            ap.error(f"--broad must be at least 1, got {args.broad}")
        write_broad_maps(args.out, args.broad, args.seed_base, args.prefix)
    else:
        write_maps(args.out, args.dt, args.seed_base, args.prefix)


def write_maps(out: Path, dt: float, seed_base: int, prefix: str) -> None:
    """Write the 8 maps ``out/PREFIX{k}.yaml``."""
    out.mkdir(parents=True, exist_ok=True)
    for k in range(8):
        rng = np.random.default_rng(seed_base + k)
        path, n = PATHS[k], COUNTS[k]
        length = sum(math.dist(a, b) for a, b in zip(path, path[1:]))
        travel = length / SPEED
        forms = _formations(rng, k, travel)
        obs = _obstacles(rng, path)
        social = k % 2 == 1
        humans = [h for h in _walkers(rng, path, length, social)  # none starting by an obstacle
                  if all(math.dist(h["path"][0], o["center"]) > 1.5 for o in obs)]
        scn = {"name": f"{prefix}{k}", "description": f"switching every 12-14 s, {n} followers, "
               f"{'social_force' if social else 'scripted'} walkers",
               "world": {"size": [31.0, 22.0], "dt": dt, "substeps": 4, "max_time": round(travel + 45, 0),
                         "settle_tolerance": 0.3},
               "robots": {"count": n, "radius": 0.25, "max_speed": 0.65, "max_turn_rate": 1.0, "start": "formation"},
               "leader": {"kind": "virtual", "path": path, "speed": SPEED},
               "formations": forms, "obstacles": obs, "humans": humans}
        with open(out / f"{prefix}{k}.yaml", "w") as fh:
            yaml.safe_dump(scn, fh, sort_keys=False, default_flow_style=None)
        print(f"{out / f'{prefix}{k}.yaml'}: {n} followers, {len(forms)} formations, {len(obs)} obstacles, "
              f"{len(humans)} walkers")


if __name__ == "__main__":
    main()
