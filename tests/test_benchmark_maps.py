"""benchmarks/switch_maps.py (``--broad``: switch maps that also draw the robots, the period and the walkers) and
benchmarks/family_worlds.py (``--per-world``: one digest per world), the scripts behind docs/vo_defaults.md's
broad-map comparison and docs/benchmark.md's list of the worlds ``standard/3`` changed."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from swarm_env.env import SwarmEnv
from swarm_env.scenarios.loader import load_scenario

_BENCH = Path(__file__).resolve().parents[1] / "benchmarks"


def _script(name: str) -> ModuleType:
    spec = importlib.util.spec_from_file_location(name, _BENCH / f"{name}.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod


def test_broad_maps_load_play_and_repeat(tmp_path: Path) -> None:
    sm = _script("switch_maps")
    sm.main(["--broad", "3", "--seed-base", "3000", "--prefix", "h", "--out", str(tmp_path / "a")])
    sm.main(["--broad", "3", "--seed-base", "3000", "--prefix", "h", "--out", str(tmp_path / "b")])
    for k in range(3):
        a, b = (tmp_path / d / f"h{k}.yaml" for d in ("a", "b"))
        assert a.read_bytes() == b.read_bytes()  # the same seed base writes the same files
        scn = load_scenario(a)
        assert 6 <= scn.robots.count <= 8
        assert scn.robots.radius in (0.2, 0.25, 0.3) and scn.robots.max_speed in (0.5, 0.65, 0.8)
        assert scn.robots.max_turn_rate in (0.8, 1.0, 1.5) and scn.world.dt in (0.05, 0.1, 0.15)
        gaps = [b.at - a.at for a, b in zip(scn.formations, scn.formations[1:])]
        assert gaps and all(12.0 - 0.1 <= g <= 15.0 + 0.1 for g in gaps)
        assert scn.formations[0].shape != "column"
        assert {h.behavior for h in scn.humans} <= {("scripted", "social_force", "orca")[k % 3]}
        env = SwarmEnv(scn)
        env.reset(seed=0)
        env.step({agent: np.zeros(2, dtype=np.float32) for agent in env.agents})  # each map plays
    # The 8 maps of the default mode are unchanged by the new one (docs/vo_defaults.md's b, d, e and m maps).
    sm.main(["--dt", "0.2", "--prefix", "b", "--out", str(tmp_path / "m")])
    written = (tmp_path / "m" / "b6.yaml").read_text().replace("name: b6\n", "name: switch_map_dt02\n", 1)
    assert written == (Path(__file__).parent / "data" / "switch_map_dt02.yaml").read_text()


def test_broad_needs_a_positive_count(tmp_path: Path) -> None:
    with pytest.raises(SystemExit):
        _script("switch_maps").main(["--broad", "0", "--out", str(tmp_path)])


def test_per_world_digests_name_each_world(capsys: pytest.CaptureFixture[str]) -> None:
    fw = _script("family_worlds")
    fw.main(["--families", "open", "--seeds", "1000-1001", "--per-world"])
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [(r["family"], r["seed"]) for r in rows] == [("open", 1000), ("open", 1001)]
    assert rows[0]["digest"] != rows[1]["digest"]
    again = fw.world_digests("open", [1001, 1000])
    assert [r["digest"] for r in again] == [rows[1]["digest"], rows[0]["digest"]]
