"""Provenance of written results (swarm_env.harness.provenance) and the compressed leaderboard reader (jsonio.read_json)."""

from __future__ import annotations

import datetime
import gzip
import json
from pathlib import Path

import pytest

import swarm_env
from swarm_env.harness.cli import main
from swarm_env.harness.provenance import git_state, provenance, provenance_line
from swarm_env.jsonio import read_json


def test_provenance_names_the_swarm_env_command_version_commit_and_date() -> None:
    p = provenance(["/usr/local/bin/swarm-env", "evaluate", "--out", "my dir"])
    assert p["command"] == "swarm-env evaluate --out 'my dir'"  # as a shell takes it back
    assert p["swarm_env"] == swarm_env.__version__
    assert p["git_commit"] is None or len(p["git_commit"]) == 40
    assert datetime.datetime.fromisoformat(p["date"]).tzinfo is not None
    assert provenance_line(p).startswith("Written by `swarm-env evaluate --out 'my dir'` (swarm-env ")
    # a script or a notebook calling the library has no command line worth citing
    other = provenance(["/x/ipykernel_launcher.py", "-f", "/tmp/k.json"])
    assert other["command"] is None and provenance_line(other).startswith("Written from Python (")


def test_git_state_outside_a_work_tree(tmp_path: Path) -> None:
    assert git_state(tmp_path) == (None, None)


def test_evaluate_writes_its_provenance(tmp_path: Path) -> None:
    out = tmp_path / "lb"
    assert main(["evaluate", "--policies", "zero", "--scenarios", "paper_vo_0", "--seeds", "0", "--max-cycles", "2",
                 "--quiet", "--out", str(out)]) == 0
    doc = json.loads((out / "leaderboard.json").read_text())
    assert doc["provenance"]["swarm_env"] == swarm_env.__version__ and "date" in doc["provenance"]
    md = (out / "leaderboard.md").read_text()
    assert md.startswith("Written ") and md.rstrip().splitlines()[-1].startswith("Each cell:")  # legend after tables


def test_read_json_reads_gzip(tmp_path: Path) -> None:
    doc = {"episodes": [{"seed": 1}], "x": [1.5, None]}
    (tmp_path / "a.json").write_text(json.dumps(doc))
    with gzip.open(tmp_path / "a.json.gz", "wt") as fh:
        json.dump(doc, fh)
    assert read_json(tmp_path / "a.json") == read_json(tmp_path / "a.json.gz") == doc
    with pytest.raises(FileNotFoundError):
        read_json(tmp_path / "missing.json.gz")
