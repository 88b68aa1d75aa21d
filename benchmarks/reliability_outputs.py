"""Reliability probes of outputs and parallel evaluation (issue 14, items 3 and 4).

Each probe does one hostile thing to a command's outputs or to an ``evaluate`` sweep and says what it
ended in:

* **clear error**: the specified outcome: a one-line refusal that left every file outside the output as it
  was (a symlink at the target, a path leading outside ``--out``, an existing file without
  ``--overwrite``), no file under the final name of a killed writer, or, for a sweep, the fault costing only
  its episode (reported as failed), exit code 130 with the partial results on Ctrl-C, ``--resume`` giving the
  uninterrupted results;
* **crash**: anything else (a traceback, a file written or changed where it must not be, lost episodes);
* **hang**: the probe's subprocess still running after its time limit.

:func:`probes` returns one row per category, ``{"probe", "tried", "clear_error", "crash", "hang"}`` (the
counts of probes tried and of each outcome), for ``benchmarks/reliability_probes.py``'s table. Run alone::

    python benchmarks/reliability_outputs.py            # every category (the sweep probes take minutes)
    python benchmarks/reliability_outputs.py --quick    # without the sweep probes
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
CLI = [sys.executable, "-m", "swarm_env.harness.cli"]
TIMEOUT = 600  # seconds per subprocess: a probe still running then is a hang


class _Hang(Exception):
    pass


def _cli(args: list[str], env: dict[str, str] | None = None, timeout: float = TIMEOUT) -> subprocess.CompletedProcess:
    try:
        return subprocess.run(CLI + args, capture_output=True, text=True, timeout=timeout, cwd=ROOT,
                              env={**os.environ, "SDL_VIDEODRIVER": "dummy", **(env or {})})
    except subprocess.TimeoutExpired:
        raise _Hang from None


def _one_line_error(proc: subprocess.CompletedProcess, *needles: str) -> bool:
    err = proc.stderr.strip()
    return proc.returncode == 2 and err.count("\n") == 0 and err.startswith("error:") and all(n in err for n in needles)


# --------------------------------------------------------------------------- the probes of each category
def _symlink_probes(tmp: Path) -> list[tuple[str, Callable[[], bool]]]:
    """A symlink at the output path of each writer: refused, the linked file untouched."""
    from swarm_env.harness.leaderboard import run_leaderboard
    from swarm_env.harness.video import VideoWriter
    from swarm_env.jsonio import write_json
    from swarm_env.outputs import OutputError, append_line

    def linked(name: str) -> tuple[Path, Path]:
        victim = tmp / f"victim-{name}"
        victim.write_text("keep")
        link = tmp / name
        link.symlink_to(victim)
        return link, victim

    def api(name: str, write: Callable[[Path], Any]) -> Callable[[], bool]:
        def probe() -> bool:
            link, victim = linked(name)
            try:
                write(link)
            except OutputError:
                return victim.read_text() == "keep"
            return False
        return probe

    def cli(name: str, args: Callable[[Path], list[str]]) -> Callable[[], bool]:
        def probe() -> bool:
            link, victim = linked(name)
            proc = _cli(args(link) + ["--overwrite"])  # even with --overwrite: a link is never written through
            return _one_line_error(proc, "symbolic link") and victim.read_text() == "keep"
        return probe

    board_dir = tmp / "board"

    def board_md(link: Path) -> None:
        board_dir.mkdir(exist_ok=True)
        target = board_dir / "leaderboard.md"
        target.symlink_to(link.resolve())
        try:
            run_leaderboard(["zero"], ["paper_vo_0"], [0], env_kwargs={"max_cycles": 2}, progress=False).write(board_dir)
        finally:
            target.unlink()

    return [
        ("write_json", api("a.json", lambda p: write_json(p, {"a": 1}))),
        ("VideoWriter", api("a.mp4", lambda p: VideoWriter(p, fps=10))),
        ("episodes.jsonl append", api("a.jsonl", lambda p: append_line(p, "{}"))),
        ("leaderboard.md in --out", api("b.md", board_md)),
        ("run --json", cli("r.json", lambda p: ["run", "--policy", "zero", "--max-cycles", "2", "--json", str(p)])),
        ("run --video", cli("r.mp4", lambda p: ["run", "--policy", "zero", "--max-cycles", "2", "--video", str(p)])),
    ]


def _outside_probes(tmp: Path) -> list[tuple[str, Callable[[], bool]]]:
    """Paths under ``--out DIR`` that would lead outside it: refused, nothing written elsewhere."""
    from swarm_env.harness.leaderboard import Leaderboard, record_worst_videos, run_leaderboard
    from swarm_env.jsonio import write_json
    from swarm_env.outputs import OutputError, atomic_write_text

    def setup(name: str) -> tuple[Path, Path]:
        out, elsewhere = tmp / f"out-{name}", tmp / f"elsewhere-{name}"
        out.mkdir()
        elsewhere.mkdir()
        return out, elsewhere

    def refused(write: Callable[[Path, Path], Any], name: str) -> Callable[[], bool]:
        def probe() -> bool:
            out, elsewhere = setup(name)
            try:
                write(out, elsewhere)
            except OutputError:
                return not any(elsewhere.iterdir()) and not (tmp / "escaped.json").exists()
            return False
        return probe

    def videos(out: Path, elsewhere: Path) -> None:
        board: Leaderboard = run_leaderboard(["zero"], ["paper_vo_0"], [0], env_kwargs={"max_cycles": 2}, progress=False)
        (out / "videos").symlink_to(elsewhere, target_is_directory=True)
        record_worst_videos(board, out / "videos", progress=False, records_dir=out / "records", root=out)

    def records(out: Path, elsewhere: Path) -> None:
        board = run_leaderboard(["zero"], ["paper_vo_0"], [0], env_kwargs={"max_cycles": 2}, progress=False)
        (out / "records").symlink_to(elsewhere, target_is_directory=True)
        record_worst_videos(board, out / "videos", progress=False, records_dir=out / "records", root=out)

    def subdir(out: Path, elsewhere: Path) -> None:
        (out / "sub").symlink_to(elsewhere, target_is_directory=True)
        atomic_write_text(out / "sub" / "x.csv", "x", root=out)

    return [
        ("symlinked videos/ under --out", refused(videos, "videos")),
        ("symlinked records/ under --out", refused(records, "records")),
        ("symlinked sub-folder", refused(subdir, "sub")),
        ("'..' in a generated name", refused(lambda out, _: write_json(out / ".." / "escaped.json", {}, root=out), "dots")),
    ]


def _clobber_probes(tmp: Path) -> list[tuple[str, Callable[[], bool]]]:
    """An existing output without ``--overwrite``: refused before any episode, the file as it was."""
    def existing(name: str, args: Callable[[Path], list[str]], *needles: str) -> Callable[[], bool]:
        def probe() -> bool:
            target = tmp / name
            if name.endswith("/"):
                target.mkdir()
                (target / "leaderboard.json").write_text("mine")
                keep = target / "leaderboard.json"
            else:
                target.write_text("mine")
                keep = target
            proc = _cli(args(target))
            return _one_line_error(proc, *needles) and keep.read_text() == "mine"
        return probe

    return [
        ("run --json", existing("c.json", lambda p: ["run", "--policy", "zero", "--max-cycles", "2", "--json", str(p)],
                                "exists", "--overwrite")),
        ("run --video", existing("c.mp4", lambda p: ["run", "--policy", "zero", "--max-cycles", "2", "--video", str(p)],
                                 "exists", "--overwrite")),
        ("bench --json", existing("b.json", lambda p: ["bench", "--steps", "10", "--repeats", "1", "--json", str(p)],
                                  "exists")),
        ("evaluate --out DIR with results", existing("lb/", lambda p: [
            "evaluate", "--policies", "zero", "--scenarios", "paper_vo_0", "--seeds", "0", "--quiet", "--out", str(p)],
            "--overwrite", "--resume")),
    ]


def _killed_writer_probes(tmp: Path) -> list[tuple[str, Callable[[], bool]]]:
    """A writer stopped mid-file: nothing under the final name."""
    from swarm_env.harness.video import VideoWriter

    def exception_mid_encoding() -> bool:
        path = tmp / "e.mp4"
        try:
            with VideoWriter(path, fps=10) as video:
                for _ in range(5):
                    video.append(np.zeros((32, 32, 3), np.uint8))
                raise RuntimeError("stop")
        except RuntimeError:
            pass
        left = [p.name for p in tmp.iterdir() if p.name == path.name or p.name.startswith(".e.mp4")]
        if left:
            raise AssertionError(f"left behind: {', '.join(left)}")
        return True

    def signal_mid_run(sig: int) -> Callable[[], bool]:
        def probe() -> bool:
            path = tmp / f"k{sig}.mp4"
            proc = subprocess.Popen(CLI + ["run", "--scenario", "paper_cbs_switch", "--policy", "vo", "--video", str(path)],
                                    preexec_fn=_default_sigint,
                                    cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                                    env={**os.environ, "SDL_VIDEODRIVER": "dummy"})
            deadline = time.monotonic() + TIMEOUT
            while time.monotonic() < deadline and proc.poll() is None:
                temps = [p for p in tmp.iterdir() if p.name.startswith(f".{path.name}.") and p.stat().st_size > 0]
                if temps:  # the encoder is writing
                    break
                time.sleep(0.2)
            else:
                proc.kill()
                raise _Hang
            proc.send_signal(sig)
            _, err = proc.communicate(timeout=TIMEOUT)
            clean_exit = sig == signal.SIGKILL or (proc.returncode == 130 and err.strip() == "interrupted")
            if not clean_exit or path.exists():  # say what was found: a flake must be diagnosable from the report
                tail = " ".join(err.split())[-160:].replace("|", "/").replace("`", "'")
                raise AssertionError(f"exit {proc.returncode}, final file {'left' if path.exists() else 'absent'}, "
                                     f"stderr ...{tail}")
            return True
        return probe

    return [
        ("exception while encoding", exception_mid_encoding),
        ("run --video, SIGINT while encoding", signal_mid_run(signal.SIGINT)),
        ("run --video, SIGKILL while encoding", signal_mid_run(signal.SIGKILL)),
    ]


def _fault_site(tmp: Path) -> dict[str, str]:
    """The test fault policies (crash, hang, flaky, slow) registered through an entry point on PYTHONPATH."""
    site = tmp / "site"
    site.mkdir(exist_ok=True)
    shutil.copy(ROOT / "tests" / "_fault_policies.py", site / "swarm_env_fault_policies.py")
    info = site / "swarm_env_fault_policies-0.dist-info"
    info.mkdir(exist_ok=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: swarm-env-fault-policies\nVersion: 0\n")
    (info / "entry_points.txt").write_text("[swarm_env.policies]\n" + "".join(
        f"{m} = swarm_env_fault_policies:{m.title()}\n" for m in ("crash", "hang", "flaky", "slow")))
    return {"PYTHONPATH": os.pathsep.join([str(site), os.environ.get("PYTHONPATH", "")]), "SWARM_ENV_FAULT_DIR": str(site)}


def _sweep_probes(tmp: Path) -> list[tuple[str, Callable[[], bool]]]:
    """Dead, hung and interrupted ``evaluate --workers 2`` sweeps."""
    env = _fault_site(tmp)
    base = ["evaluate", "--scenarios", "paper_vo_0", "--seeds", "0-2", "--max-cycles", "20", "--workers", "2", "--quiet"]

    def faulty(spec: str, *extra: str, failed: int) -> Callable[[], bool]:
        def probe() -> bool:
            out = tmp / f"lb-{spec.replace(':', '-').replace(',', '-')}"
            proc = _cli(base + ["--policies", spec, "pursuit", "--out", str(out), *extra], env=env)
            if proc.returncode != 0:
                return False
            doc = json.loads((out / "leaderboard.json").read_text())
            return len(doc.get("failed", [])) == failed and len(doc["episodes"]) == 6 - failed
        return probe

    def interrupted() -> bool:
        out = tmp / "lb-int"
        proc = subprocess.Popen(CLI + base + ["--policies", "slow:0,1,2", "--out", str(out)], cwd=ROOT,
                                preexec_fn=_default_sigint,
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                                env={**os.environ, **env, "SWARM_ENV_FAULT_SLEEP": "30"})
        stream = out / "episodes.jsonl"
        deadline = time.monotonic() + TIMEOUT
        while not (stream.is_file() and stream.read_text().count("\n") >= 1):
            if time.monotonic() > deadline or proc.poll() is not None:
                proc.kill()
                raise _Hang
            time.sleep(0.2)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=TIMEOUT)
        if proc.returncode != 130 or err.strip().count("\n") or not err.startswith("interrupted:"):
            return False
        resumed = _cli(["evaluate", "--resume", str(out), "--quiet"], env={**env, "SWARM_ENV_FAULT_SLEEP": "0"})
        doc = json.loads((out / "leaderboard.json").read_text())
        return resumed.returncode == 0 and [e["seed"] for e in doc["episodes"]] == [0, 1, 2]

    return [
        ("a worker dies (os._exit) on one episode", faulty("crash:1", failed=1)),
        ("a worker dies once, then the retry succeeds", faulty("flaky:1", failed=0)),
        ("a worker hangs (--episode-timeout 15)", faulty("hang:1", "--episode-timeout", "15", failed=1)),
        ("Ctrl-C mid-sweep, then --resume", interrupted),
    ]


CATEGORIES: dict[str, Callable[[Path], list[tuple[str, Callable[[], bool]]]]] = {
    "output: symlink at the target": _symlink_probes,
    "output: path leading outside --out": _outside_probes,
    "output: existing file without --overwrite": _clobber_probes,
    "output: writer killed mid-file": _killed_writer_probes,
    "evaluate: dead, hung or interrupted workers": _sweep_probes,
}


def _default_sigint() -> None:
    """In a probe's child: SIGINT handled by default, as at a terminal (a script started in the background
    inherits an ignored SIGINT, and its Ctrl-C probes would then test nothing)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def probes(quick: bool = False, details: list[dict[str, Any]] | None = None) -> list[dict[str, Any]]:
    """One row per category: ``{"probe", "tried", "clear_error", "crash", "hang"}``. ``quick`` leaves out the
    sweep probes (minutes); ``details``, when given, receives ``{"category", "probe", "outcome", "error"}`` per probe."""
    rows = []
    with tempfile.TemporaryDirectory(prefix="swarm-env-outputs-") as tmp_name:
        for category, make in CATEGORIES.items():
            if quick and category.startswith("evaluate"):
                continue
            where = Path(tmp_name) / str(len(rows))
            where.mkdir()
            row = {"probe": category, "tried": 0, "clear_error": 0, "crash": 0, "hang": 0}
            for name, probe in make(where):
                row["tried"] += 1
                error = ""
                try:
                    outcome = "clear_error" if probe() else "crash"
                except _Hang:
                    outcome = "hang"
                except Exception as exc:  # noqa: BLE001 - any other exception is what the probe looks for
                    outcome, error = "crash", f"{type(exc).__name__}: {exc}"
                row[outcome] += 1
                if details is not None:
                    details.append({"category": category, "probe": name, "outcome": outcome, "error": error})
            rows.append(row)
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="leave out the sweep probes (they take minutes)")
    args = parser.parse_args(argv)
    details: list[dict[str, Any]] = []
    rows = probes(args.quick, details)
    print("| probe | tried | clear error | crash | hang |\n|---|---:|---:|---:|---:|")
    for r in rows:
        print(f"| {r['probe']} | {r['tried']} | {r['clear_error']} | {r['crash']} | {r['hang']} |")
    for d in details:
        if d["outcome"] != "clear_error":
            print(f"{d['outcome']}: {d['category']}: {d['probe']} {d['error']}", file=sys.stderr)
    return 0 if all(r["crash"] == r["hang"] == 0 for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
