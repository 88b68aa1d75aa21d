"""Reliability probes: hostile scenario inputs, each run with a time and memory limit (issue 14).

Re-creates the kinds of input that made the validator hang, eat memory or crash (huge numbers,
deep nesting, alias bombs, large and special files, bad types, derived counts, misleading
messages), a few thousand seeded random mutations of valid scenarios, and hostile knobs of the
``random`` generator, and tabulates what each one ended in:

* **clear error**: a ``ScenarioError`` whose every line is short and printable;
* **accepted, steps**: a valid scenario whose env builds, resets and steps (five steps);
* **crash**: any other exception, a ``MemoryError`` under the memory limit, or an error
  message that is not one short printable line;
* **hang**: still running after the time limit.

Run as::

    python benchmarks/reliability_probes.py --out docs/reliability.md

Probes run in a child process (``--child``) under ``resource.setrlimit(RLIMIT_AS)``; each probe
has an alarm (``--timeout`` s), and the parent kills a child that does not answer in time or
dies, records the probe it was on, and starts a new child for the rest. The figures in
``docs/reliability.md`` are this script's output; a second section probes model files.
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import os
import pickle
import queue
import random
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter, defaultdict
from pathlib import Path
from typing import Any

from swarm_env.jsonio import dumps, write_json

OUTCOMES = ("clear error", "accepted, steps", "crash", "hang")
ROOT = Path(__file__).resolve().parent.parent


# --------------------------------------------------------------------------- the probes


def _yaml(data: Any) -> str:
    import yaml

    return yaml.safe_dump(data, sort_keys=False, allow_unicode=True)


def _base() -> dict:
    from swarm_env.scenarios.loader import load_scenario, scenario_to_dict

    return scenario_to_dict(load_scenario("paper_vo_0"))


def _set(data: dict, path: tuple, value: Any) -> dict:
    out = copy.deepcopy(data)
    node = out
    for k in path[:-1]:
        node = node[k]
    node[path[-1]] = value
    return out


# Numeric keys of paper_vo_0 and the huge / tiny values written into each (as YAML text, so the
# loader's own number handling is probed too).
_NUMERIC_KEYS = [
    ("world", "size", 0), ("world", "dt"), ("world", "substeps"), ("world", "max_time"), ("robots", "count"),
    ("robots", "radius"), ("robots", "max_speed"), ("leader", "speed"), ("formations", 0, "spacing"),
    ("formations", 0, "angle"), ("obstacles", 0, "radius"), ("humans", 0, "speed"), ("sensors", "lidar_rays"),
]
_HUGE_TEXT = ["1.0e+20", "1.0e+308", "9223372036854775808", "9" * 5000, "-1", ".nan", ".inf", "1.0e-300"]


def file_probes(tmp: Path) -> list[dict]:
    """The 97-file style categories: each probe is a path (written here) and its category."""
    base = _base()
    probes: list[dict] = []

    def add(category: str, name: str, text: str | bytes | None = None, path: Path | None = None) -> None:
        p = path if path is not None else tmp / f"{len(probes):03d}_{name}.yaml"
        if text is not None:
            (p.write_bytes if isinstance(text, bytes) else p.write_text)(text)  # type: ignore[operator]
        probes.append({"kind": "file", "category": category, "name": name, "path": str(p)})

    marker = "__VALUE__"
    for key in _NUMERIC_KEYS:
        if key[0] == "obstacles" and "radius" not in base["obstacles"][0]:
            continue
        template = _yaml(_set(base, key, marker))
        for value in _HUGE_TEXT:
            add("huge or tiny numbers", f"{'.'.join(map(str, key))}={value[:12]}", template.replace(marker, value))
    add("huge or tiny numbers", "rectangle size 1e20", _yaml(_set(base, ("obstacles",), [
        {"type": "rectangle", "center": [5.0, 5.0], "size": [1e20, 1.0]}])))
    add("huge or tiny numbers", "grid columns 2**63", _yaml(_set(base, ("formations", 0), {
        "at": 0.0, "shape": "grid", "columns": 2**63})))

    for depth in (100, 1000, 20_000):
        add("deep nesting", f"{depth}-deep list", _yaml(base) + "extra: " + "[" * depth + "]" * depth + "\n")
        add("deep nesting", f"{depth}-deep mapping", _yaml(base) + "extra: " + "{a: " * depth + "1" + "}" * depth + "\n")

    def bomb(levels: int, key: str) -> str:
        lines = ['l0: &l0 ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]']
        for i in range(1, levels):
            lines.append(f"l{i}: &l{i} [" + ",".join([f"*l{i - 1}"] * 9) + "]")
        anchors = "\n".join("x_" + line for line in lines).replace("*l", "*x_l").replace("&l", "&x_l")
        body = _yaml({k: v for k, v in base.items() if k != key})
        return "anchors_holder: &holder\n" + "\n".join("  " + a for a in anchors.splitlines()) + "\n" + body \
            + f"{key}: *x_l{levels - 1}\n"

    add("alias bombs", "9-level bomb in description", bomb(9, "description"))
    add("alias bombs", "9-level bomb in obstacles", bomb(9, "obstacles"))
    add("alias bombs", "6-level bomb in humans", bomb(6, "humans"))
    add("alias bombs", "recursive alias", _yaml(base) + "extra: &r [*r]\n")

    add("large files", "2 MB comment", _yaml(base) + "#" + "x" * (2 << 20) + "\n")
    add("large files", "50 MB comment", _yaml(base) + "#" + "x" * (50 << 20) + "\n")
    add("large files", "50 MB obstacle list", _yaml(base) + "more: [" + "1," * (25 << 20) + "1]\n")
    add("large files", "1 MB flat list", "x: [" + "1," * (490 << 10) + "1]\n")

    fifo = tmp / "fifo.yaml"
    os.mkfifo(fifo)
    add("special files", "FIFO", path=fifo)
    zero = tmp / "zero.yaml"
    zero.symlink_to("/dev/zero")
    add("special files", "symlink to /dev/zero", path=zero)
    add("special files", "/dev/null", path=Path("/dev/null"))
    add("special files", "directory", path=tmp)
    add("special files", "missing file", path=tmp / "missing.yaml")
    add("special files", "system text file (/etc/passwd)", path=Path("/etc/passwd"))
    add("special files", "binary garbage", bytes(random.Random(0).randrange(256) for _ in range(4096)))
    add("special files", "UTF-16 text", _yaml(base).encode("utf-16"))
    add("special files", "empty file", "")

    bad_types = [
        (("world",), "a string"), (("world", "size"), "big"), (("robots", "count"), 2.5), (("robots", "count"), True),
        (("robots", "start"), "nowhere"), (("leader", "path"), [[1, 2]]), (("formations",), {}),
        (("formations", 0, "shape"), "vee"), (("obstacles", 0), [1, 2, 3]), (("humans", 0, "mode"), 7),
        (("sensors",), [1]), (("reward", "formation"), "1e3"), (("world", "max_time"), "1e3"),
        (("robots", "max_speed"), None), (("leader", "kind"), ["robot"]),
    ]
    for key, value in bad_types:
        add("bad types", f"{'.'.join(map(str, key))}={value!r}"[:40], _yaml(_set(base, key, value)))
    add("bad types", "top level is a list", "- 1\n- 2\n")
    add("bad types", "unknown section", _yaml({**base, "wrold": {}}))
    add("bad types", "duplicate key", _yaml(base) + "name: again\n")

    derived = [
        (("robots", "count"), 10_000), (("sensors", "lidar_rays"), 10**9), (("sensors", "neighbors"), 10**9),
        (("world", "substeps"), 10**6), (("world", "dt"), 1e-9), (("world", "max_time"), 1e12),
        (("sensors", "humans"), 10**9), (("world", "size"), [1e6, 1e6]),
    ]
    for key, value in derived:
        add("derived counts", f"{'.'.join(map(str, key))}={value!r}"[:40], _yaml(_set(base, key, value)))
    big = _set(_set(_set(base, ("robots", "count"), 64), ("sensors",), {"lidar_rays": 360, "neighbors": 63}),
               ("formations",), [{"at": 0.0, "shape": "grid", "spacing": 1.0, "columns": 8}])
    big = _set(_set(big, ("world", "size"), [60.0, 40.0]), ("leader", "path"), [[20.0, 20.0], [55.0, 20.0]])
    big = _set(_set(big, ("obstacles",), []), ("humans",), [])
    add("derived counts", "64 robots, 360 rays, 63 neighbours (at the bounds)", _yaml(big))

    messages = [
        ("name with control characters", _set(base, ("name",), "evil\x1b[2J\x07")),
        ("name with right-to-left override", _set(base, ("name",), "map\u202egnp.exe")),
        ("unknown key with bidi characters", {**base, "\u202eworld": 1}),
        ("bow-tie polygon", _set(base, ("obstacles",), [{"type": "polygon", "points": [[4, 4], [6, 6], [6, 4], [4, 6]]}])),
        ("human starting inside an obstacle", _set(base, ("humans", 0, "path", 0), list(base["obstacles"][0]["center"])
                                                   if "center" in base["obstacles"][0] else [5.0, 5.0])),
        ("neighbors above the team", _set(base, ("sensors",), {"neighbors": 40})),
    ]
    for name, data in messages:
        add("messages", name, _yaml(data))
    add("messages", "YAML merge key", _yaml(base).replace("formations:\n", "formations:\n- &f0 {at: 0.0, shape: v}\n", 1)
        .replace("- at: 0.0", "- <<: *f0\n  at: 5.0", 1))
    add("messages", "exponent without a dot (1e3)", _yaml(base).replace("max_time: 60.0", "max_time: 1e3"))
    return probes


# Seeded random mutations of valid scenarios (the same kinds as tests/test_scenario_fuzz.py).
_MUTANTS = [0, -1, 1, 2, 64, 65, 10**9, 2**63, 10**30, 1e-300, 1e6, 1e20, 1e308, -1e308, math.inf, math.nan,
            True, None, "", "x", "1e3", "\u202e", [], {}, [[]], [1, 2], [[1, 2]], {"x": 1}]


def _paths(obj: Any, prefix: tuple = ()) -> list[tuple]:
    out = [prefix] if prefix else []
    if isinstance(obj, dict):
        for k, v in obj.items():
            out += _paths(v, prefix + (k,))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            out += _paths(v, prefix + (i,))
    return out


def mutation_probes(count: int, seed: int) -> list[dict]:
    """``count`` seeded mutations (1-3 edits each) of the built-in scenarios, as dict probes."""
    from swarm_env.scenarios.loader import list_scenarios, load_scenario, scenario_to_dict

    bases = [scenario_to_dict(load_scenario(n)) for n in list_scenarios() if n != "random"]
    rng = random.Random(seed)
    probes = []
    for i in range(count):
        data = copy.deepcopy(rng.choice(bases))
        for _ in range(rng.randint(1, 3)):
            paths = _paths(data)
            path = rng.choice(paths)
            parent: Any = data
            for k in path[:-1]:
                parent = parent[k]
            op = rng.choice(["replace", "replace", "replace", "scale", "delete", "grow", "nest"])
            cur = parent[path[-1]]
            if op == "replace":
                parent[path[-1]] = rng.choice(_MUTANTS + [rng.uniform(-5, 60), rng.randint(-3, 100)])
            elif op == "scale" and isinstance(cur, (int, float)) and not isinstance(cur, bool):
                parent[path[-1]] = type(cur)(cur * rng.choice([0, -1, 10, 1000, 1e6]))
            elif op == "delete":
                del parent[path[-1]]
            elif op == "grow" and isinstance(cur, list) and cur:
                parent[path[-1]] = cur * rng.choice([2, 65, 300, 20_000])
                break  # its entries are shared: a later edit inside would multiply
            elif op == "nest":
                parent[path[-1]] = [cur]
        probes.append({"kind": "dict", "category": "random mutations", "name": f"mutation {i}", "data": data})
    return probes


def random_probes(count: int, seed: int) -> list[dict]:
    """Hostile knobs of ``parallel_env("random", ...)``, then ``count`` seeded random knob sets."""
    fixed = [
        {"n_humans": [0, 10**9]}, {"n_followers": 10**6}, {"n_obstacles": 10**9}, {"n_switches": 10**9},
        {"obstacle_size": [1e20, 1e20]}, {"spacing": [1e6, 1e6]}, {"world_size": [1e20, 1e20]},
        {"world_size": [1.0, 1.0]}, {"max_time": 1e12}, {"dt": 1e-9}, {"substeps": 10**6},
        {"radius": 1e-300}, {"max_speed": 1e308}, {"leader_speed": math.inf}, {"human_speed": [0.1, 1e308]},
        {"sensors": {"lidar_rays": 10**9}}, {"sensors": {"neighbors": 10**9}}, {"angle": [0.0, 360.0]},
        {"shapes": ["custom"]}, {"leader_kind": "ghost"}, {"n_followers": 64},
        {"n_followers": 64, "n_obstacles": 100, "n_humans": 32, "n_switches": 8},
    ]
    rng = random.Random(seed)
    knob_values: dict[str, list] = {
        "n_followers": [1, 3, 8, (1, 8), 0, 65, (0, 10**9)],
        "n_obstacles": [0, 5, 12, -1, 101],
        "n_humans": [0, 2, 4, 33],
        "n_switches": [0, 2, 9],
        "obstacle_size": [(0.3, 1.2), (2.0, 4.0), (0.0, 1.0), (1e20, 1e20)],
        "human_speed": [(0.3, 0.6), (0.1, 2.0), (0.1, 1e308)],
        "spacing": [(0.9, 1.3), (2.0, 3.0), (100.0, 100.0)],
        "angle": [(30.0, 60.0), (89.0, 91.0), (10.0, 200.0)],
        "world_size": ["auto", (10.0, 10.0), (3.0, 3.0), (1e20, 1e20)],
        "leader_kind": ["virtual", "robot", "ghost"],
        "human_behavior": ["scripted", "social_force", "walk"],
        "dt": [0.05, 0.1, 0.5, 1e-9],
        "max_time": [5.0, 60.0, 1e12],
        "radius": [0.1, 0.25, 0.6, 1e-300],
        "substeps": [1, 4, 12, 10**6],
    }
    probes = [{"kind": "random", "category": "random generator knobs", "name": dumps(k, indent=None), "knobs": k}
              for k in fixed]
    for i in range(count):
        names = rng.sample(sorted(knob_values), rng.randint(1, 4))
        knobs = {n: rng.choice(knob_values[n]) for n in names}
        probes.append({"kind": "random", "category": "random generator knobs", "name": f"draw {i}", "knobs": knobs})
    return probes


# --------------------------------------------------------------------------- running one probe (in the child)


class _Timeout(BaseException):
    """Raised by the alarm: a BaseException, so that no ``except Exception`` in the code swallows it."""


def _clean(exc: Exception) -> bool:
    """An error a person can read: every line short and printable."""
    lines = [str(e) for e in getattr(exc, "errors", (exc,))]
    return all(0 < len(t) < 2000 and t.isprintable() for t in lines)


def _step(env: Any, steps: int = 5) -> None:
    env.reset(seed=0)
    for _ in range(steps):
        if not env.agents:
            break
        env.step({a: env.action_space(a).sample() for a in env.agents})
    env.close()


def run_probe(probe: dict) -> tuple[str, str]:
    """``(outcome, detail)`` of one probe (hangs are the caller's alarm)."""
    from swarm_env import SwarmEnv
    from swarm_env.scenario import ScenarioError
    from swarm_env.scenarios.loader import load_scenario, scenario_from_dict

    try:
        if probe["kind"] == "file":
            env = SwarmEnv(load_scenario(probe["path"]))
        elif probe["kind"] == "dict":
            env = SwarmEnv(scenario_from_dict(probe["data"]))
        elif probe["kind"] == "random":
            env = SwarmEnv("random", **probe["knobs"])
        else:
            return _model_probe(probe)
        _step(env)
    except ScenarioError as exc:
        first = str(exc.errors[0])
        return ("clear error" if _clean(exc) else "crash"), first[:160]
    except MemoryError:
        return "crash", "MemoryError"
    except Exception as exc:  # noqa: BLE001 - what the probes count
        return "crash", f"{type(exc).__name__}: {str(exc)[:140]}"
    return "accepted, steps", f"max_steps {env.max_steps}"


def child(args: argparse.Namespace) -> None:
    """Run the probes of ``args.probes`` from index ``args.start``, one JSON line per outcome."""
    import resource

    limit = args.memory_gib << 30
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    # The probes hold NaN and infinities on purpose, which strict JSON cannot carry: they go to the
    # child as a pickle this process wrote into its own private temporary directory.
    probes = pickle.loads(Path(args.probes).read_bytes())

    def alarm(_sig: int, _frame: Any) -> None:
        raise _Timeout

    signal.signal(signal.SIGALRM, alarm)
    for i in range(args.start, len(probes)):
        print(dumps({"index": i, "started": True}, indent=None), flush=True)
        t0 = time.perf_counter()
        signal.alarm(args.timeout)
        try:
            outcome, detail = run_probe(probes[i])
        except _Timeout:
            outcome, detail = "hang", f"over {args.timeout} s"
        finally:
            signal.alarm(0)
        print(dumps({"index": i, "outcome": outcome, "detail": detail,
                     "seconds": round(time.perf_counter() - t0, 3)}, indent=None), flush=True)


def run_all(probes: list[dict], timeout: int, memory_gib: int, workdir: Path) -> list[dict]:
    """Each probe's result, running them in as few children as crashes and hangs allow."""
    spec = workdir / "probes.pickle"
    spec.write_bytes(pickle.dumps(probes))
    results: dict[int, dict] = {}
    start = 0
    while start < len(probes):
        cmd = [sys.executable, __file__, "--child", "--probes", str(spec), "--start", str(start),
               "--timeout", str(timeout), "--memory-gib", str(memory_gib)]
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True, cwd=ROOT)
        lines: queue.Queue = queue.Queue()
        threading.Thread(target=lambda out=proc.stdout: [lines.put(x) for x in out] + [lines.put(None)], daemon=True).start()
        current = start
        while True:
            try:
                # The alarm did not fire (a C call that ignores it), or the child cannot say so: a hang.
                line = lines.get(timeout=timeout + 30)
            except queue.Empty:
                proc.kill()
                results[current] = {"index": current, "outcome": "hang", "detail": f"killed after {timeout + 30} s"}
                current += 1
                break
            if line is None:  # the child ended
                break
            msg = json.loads(line)
            current = msg["index"]
            if "outcome" in msg:
                results[current] = msg
                current += 1
        proc.wait()
        if current < len(probes) and current not in results:  # the child died on this probe
            results[current] = {"index": current, "outcome": "crash", "detail": f"child died (exit {proc.returncode})"}
            current += 1
        start = current
    return [{**probes[i], **results[i]} for i in range(len(probes))]


# --------------------------------------------------------------------------- model files


def model_probes(tmp: Path) -> list[dict]:
    """Poisoned, truncated and mismatched model files of the shipped MAPPO policy (needs the ``rl`` extra)."""
    try:
        from swarm_env_baselines.mappo_policy import shipped_run
    except ImportError:
        return []
    run = Path(shipped_run("mappo", "s0"))
    probes = []

    def variant(name: str, edit: Any) -> None:
        import shutil

        where = tmp / f"model_{len(probes):02d}"
        shutil.copytree(run, where)
        edit(where)
        probes.append({"kind": "model", "category": "model files", "name": name, "path": str(where)})

    def files(where: Path, suffix: str) -> list[Path]:
        return sorted(where.glob(f"*{suffix}"))

    def truncate(where: Path) -> None:
        for f in files(where, ".safetensors"):
            f.write_bytes(f.read_bytes()[: len(f.read_bytes()) // 2])

    def garbage(where: Path) -> None:
        for f in files(where, ".safetensors"):
            f.write_bytes(bytes(random.Random(1).randrange(256) for _ in range(4096)))

    def empty(where: Path) -> None:
        for f in files(where, ".safetensors"):
            f.write_bytes(b"")

    def bad_json(where: Path) -> None:
        for f in files(where, ".json"):
            f.write_text("{not json")

    def mismatched(where: Path) -> None:
        def grow(v: Any) -> Any:  # every size in the description, made larger than the weights
            if isinstance(v, dict):
                return {k: grow(x) for k, x in v.items()}
            if isinstance(v, list):
                return [grow(x) for x in v]
            return v * 2 + 1 if isinstance(v, int) and not isinstance(v, bool) and v > 1 else v

        for f in files(where, ".json"):
            write_json(f, grow(json.loads(f.read_text())))

    def pickle_only(where: Path) -> None:
        for f in files(where, ".safetensors"):
            f.unlink()
        (where / "model.pt").write_bytes(pickle.dumps({"weights": [1, 2, 3]}))

    def removed(where: Path) -> None:
        for f in list(where.iterdir()):
            if f.is_file():
                f.unlink()

    for name, edit in [("truncated weights", truncate), ("garbage weights", garbage), ("empty weights", empty),
                       ("config that is not JSON", bad_json), ("config with other sizes", mismatched),
                       ("a pickle instead of weights", pickle_only), ("empty directory", removed),
                       ("intact shipped run (control)", lambda where: None)]:
        variant(name, edit)
    return probes


def _model_probe(probe: dict) -> tuple[str, str]:
    """Load ``mappo:<dir>`` and act once on its env: a ``ModelFileError`` line is a clear error."""
    from swarm_env import SwarmEnv
    from swarm_env.harness.policies import PolicyError, load_policy

    try:
        env = SwarmEnv("random")
        policy = load_policy(f"mappo:{probe['path']}", env)
        obs, _ = env.reset(seed=0)
        policy.reset(env, seed=0)
        policy.act(obs, env.world_state())
    except PolicyError as exc:  # ModelFileError is one
        return ("clear error" if _clean(exc) and "\n" not in str(exc) else "crash"), str(exc)[:160]
    except Exception as exc:  # noqa: BLE001
        return "crash", f"{type(exc).__name__}: {str(exc)[:140]}"
    return "accepted, steps", "loaded and acted"


# --------------------------------------------------------------------------- the report


def table(results: list[dict]) -> str:
    by: dict[str, Counter] = defaultdict(Counter)
    for r in results:
        by[r["category"]][r["outcome"]] += 1
    head = "| category | tried | " + " | ".join(OUTCOMES) + " |\n|---|---:|" + "---:|" * len(OUTCOMES) + "\n"
    rows = []
    total: Counter = Counter()
    for cat, counts in by.items():
        total.update(counts)
        rows.append(f"| {cat} | {sum(counts.values())} | " + " | ".join(str(counts[o]) for o in OUTCOMES) + " |")
    rows.append(f"| **all** | **{sum(total.values())}** | " + " | ".join(f"**{total[o]}**" for o in OUTCOMES) + " |")
    return head + "\n".join(rows) + "\n"


_DRAWN = ("random mutations", "random generator knobs")


def examples(results: list[dict], per_category: int = 3) -> str:
    """A few messages per category, every hand-made probe that was accepted, and every crash and
    hang (there should be none)."""
    lines = []
    seen: Counter = Counter()
    for r in results:
        shown = r["outcome"] in ("crash", "hang") or (r["outcome"] == "accepted, steps" and r["category"] not in _DRAWN)
        if shown or (r["outcome"] == "clear error" and seen[r["category"]] < per_category):
            seen[r["category"]] += 1
            detail = r["detail"].replace("|", "\\|").replace(str(r.get("path", "\0")), "FILE")
            lines.append(f"| {r['category']} | {r['name'][:50].replace('|', '/')} | {r['outcome']} | `{detail}` |")
    return "| category | probe | outcome | first message |\n|---|---|---|---|\n" + "\n".join(lines) + "\n"


def outputs_table(rows: list[dict]) -> str:
    """The rows of ``reliability_outputs.probes()`` (already counted per category) as a Markdown table."""
    head = "| probe | tried | clear error | crash | hang |\n|---|---:|---:|---:|---:|\n"
    body = "".join(f"| {r['probe']} | {r['tried']} | {r['clear_error']} | {r['crash']} | {r['hang']} |\n" for r in rows)
    total = {k: sum(r[k] for r in rows) for k in ("tried", "clear_error", "crash", "hang")}
    return head + body + f"| **all** | **{total['tried']}** | **{total['clear_error']}** | **{total['crash']}** | **{total['hang']}** |\n"


def outputs_failures(details: list[dict]) -> str:
    """The output probes that did not end as specified, each with what it found (empty if none)."""
    bad = [d for d in details if d["outcome"] != "clear_error"]
    if not bad:
        return ""
    rows = "".join(f"| {d['category']} | {d['probe']} | {d['outcome']} | `{d['error'] or '-'}` |\n" for d in bad)
    return "\nProbes that did not end as specified:\n\n| category | probe | outcome | what it found |\n|---|---|---|---|\n" + rows


def report(scenario: list[dict], models: list[dict], args: argparse.Namespace, seconds: float,
           outputs: list[dict] | None = None, output_details: list[dict] | None = None) -> str:
    from swarm_env import limits

    cmd = "python benchmarks/reliability_probes.py --out docs/reliability.md"
    slowest = max(scenario, key=lambda r: r.get("seconds", 0.0))
    text = f"""# Reliability probes

What the scenario validator does with hostile input: every probe below ran in a child process
limited to {args.memory_gib} GiB of address space and {args.timeout} s, and ended in one of

* **clear error**: a `ScenarioError` (or, for model files, a `ModelFileError`) whose every line is
  short and printable;
* **accepted, steps**: a valid scenario whose env builds, resets and steps five times;
* **crash**: any other exception, a `MemoryError`, or a message that is not a short printable line;
* **hang**: over the time limit.

Produced by ({args.mutations} mutations with seed {args.seed}, {args.random_draws} random knob sets; the
run took {seconds:.0f} s on a shared 2-core machine, so its times are rough):

```bash
{cmd}
```

The bounds that make every probe end (file size, YAML aliases and nesting, counts, rays, steps
per episode, world size, ...) are one table, `swarm_env.limits` (listed in
[Scenario files](scenarios.md)). `tests/test_scenario_fuzz.py` checks the same contract with
hypothesis in CI (2,000 mutations among the slow tests, `python -m pytest -m slow`; `-m fuzz` for ten times as many).

## Scenarios

{table(scenario)}
The slowest probe took {slowest.get('seconds', 0.0):.2f} s ({slowest['category']}: {slowest['name'][:60]}).

The categories re-create those of issue 14's 97 hostile files: numbers out of range (written
into the file, so a 5000-digit integer reaches the YAML loader), nesting 100 to 20,000 deep,
alias bombs (nine levels of nine: 9^9 strings from a 1 kB file) and a recursive alias, files of
2 and 50 MB, special files (a FIFO, a symlink to `/dev/zero`, `/dev/null`, a directory, a system
text file), wrong types, derived counts (10,000 robots, 10^9 rays or neighbours, 10^6 substeps,
episodes of 10^10 steps), and the misleading messages the issue listed. Then seeded random
mutations of the built-in scenarios (values replaced, scaled, deleted, lists grown to 20,000
entries, nested), and knobs of `parallel_env("random", ...)`.

Issue 14 measured, before these bounds: of 97 hostile files, 63 clear errors, 6 tracebacks, 4
hangs, 2 `MemoryError`s and 5 files accepted that then hung or ran out of memory at run time; of
5,000 random mutations, 10 crashes, 2 `MemoryError`s and 1 hang; and `parallel_env("random",
n_humans=(0, 10**9))` hung.

Examples (a few clear errors per category, every hand-made probe that was accepted, and every
crash and hang, if any):

{examples(scenario)}
## Model files

Another part of the suite makes model loading safe (`swarm_env_baselines.model_io`,
`mappo_policy`: a bad file is one `ModelFileError` line). Probes: copies of the shipped
MAPPO run with its files truncated, replaced, emptied, mismatched or swapped for a pickle,
loaded as `mappo:DIR` and asked for one action.

{table(models) if models else "Not run: the `rl` extra is not installed."}
{examples(models, per_category=10) if models else ""}
## Outputs and interrupted sweeps

Probes of issue 14's items 3 and 4 (`benchmarks/reliability_outputs.py`, run from this script; each
probe is a command or a call in a subprocess): a symlink at an output path, a path leading outside
`--out`, an existing file without `--overwrite`, a writer killed mid-file, and `evaluate` sweeps whose
worker dies, hangs or is interrupted with Ctrl-C (then `--resume`). "Clear error" is the specified
outcome: a one-line refusal that leaves every other file as it was, no file under a killed writer's final
name, or a fault that costs only its episode, exit code 130 with the partial results, and a resumed sweep
equal to an uninterrupted one.

{outputs_table(outputs) if outputs else "Not run (`--no-outputs`)."}{outputs_failures(output_details or [])}
Limits in force (`swarm_env.limits.LIMITS`): {", ".join(f"{k} = {v[0]:,}" if isinstance(v[0], int) else f"{k} = {v[0]:g}" for k, v in limits.LIMITS.items())}.
"""
    return text


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, help="write the Markdown report here (else print it)")
    parser.add_argument("--mutations", type=int, default=5000, help="seeded random mutations (default 5000)")
    parser.add_argument("--random-draws", type=int, default=200, help="random knob sets (default 200)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--timeout", type=int, default=60, help="seconds per probe (default 60)")
    parser.add_argument("--memory-gib", type=int, default=4, help="address-space limit of the child (GiB)")
    parser.add_argument("--no-models", action="store_true", help="skip the model-file probes")
    parser.add_argument("--no-outputs", action="store_true", help="skip the output and sweep probes (they take minutes)")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--probes", help=argparse.SUPPRESS)
    parser.add_argument("--start", type=int, default=0, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        child(args)
        return 0
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="swarm-probes-") as tmp_name:
        tmp = Path(tmp_name)
        probes = file_probes(tmp) + mutation_probes(args.mutations, args.seed) + random_probes(args.random_draws, args.seed)
        print(f"{len(probes)} scenario probes", file=sys.stderr)
        scenario = run_all(probes, args.timeout, args.memory_gib, tmp)
        models = [] if args.no_models else model_probes(tmp)
        model_results = run_all(models, args.timeout, args.memory_gib, tmp) if models else []
    outputs = None
    if not args.no_outputs:
        from reliability_outputs import probes as output_probes  # this directory's sibling script

        output_details: list[dict] = []
        outputs = output_probes(details=output_details)
    text = report(scenario, model_results, args, time.perf_counter() - t0, outputs,
                  output_details if outputs else None)
    if args.out:
        from swarm_env.outputs import atomic_write_text

        atomic_write_text(args.out, text)
        print(f"wrote {args.out}", file=sys.stderr)
    else:
        print(text)
    print(table(scenario), file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
