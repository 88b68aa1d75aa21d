"""Safe outputs (swarm_env.outputs): atomic writes, no symlink followed, nothing written outside the
named directory, no existing file replaced without --overwrite, no truncated video under its final name."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from swarm_env.harness.cli import main
from swarm_env.jsonio import write_json
from swarm_env.outputs import (
    OutputError,
    append_line,
    atomic_write_text,
    check_target,
    ensure_dir,
    open_atomic,
    save_figure,
)


def leftovers(directory: Path) -> list[str]:
    """Temporary files an atomic writer left behind."""
    return sorted(p.name for p in directory.iterdir() if ".tmp" in p.name)


# --------------------------------------------------------------------------- the rule
def test_atomic_write_replaces_whole_and_keeps_the_mode(tmp_path: Path) -> None:
    target = tmp_path / "a.txt"
    target.write_text("old")
    atomic_write_text(target, "new")
    assert target.read_text() == "new" and leftovers(tmp_path) == []
    assert target.stat().st_mode & 0o777 == (0o666 & ~_umask())  # as open(path, "w") would make it


def _umask() -> int:
    import os

    mask = os.umask(0)
    os.umask(mask)
    return mask


def test_a_symlink_at_the_target_is_refused_and_its_file_untouched(tmp_path: Path) -> None:
    outside = tmp_path / "outside.json"
    outside.write_text("keep")
    link = tmp_path / "out.json"
    link.symlink_to(outside)
    for write in (lambda: write_json(link, {"a": 1}), lambda: atomic_write_text(link, "x"),
                  lambda: append_line(link, "x")):
        with pytest.raises(OutputError, match="symbolic link"):
            write()
    assert outside.read_text() == "keep" and link.is_symlink()
    dangling = tmp_path / "dangling.json"
    dangling.symlink_to(tmp_path / "nowhere.json")
    with pytest.raises(OutputError, match="symbolic link"):
        write_json(dangling, {})
    assert not (tmp_path / "nowhere.json").exists()


def test_nothing_is_written_outside_the_named_directory(tmp_path: Path) -> None:
    out, elsewhere = tmp_path / "out", tmp_path / "elsewhere"
    out.mkdir()
    elsewhere.mkdir()
    (out / "videos").symlink_to(elsewhere, target_is_directory=True)
    with pytest.raises(OutputError, match="outside the output directory"):
        atomic_write_text(out / "videos" / "a.mp4", "x", root=out)
    with pytest.raises(OutputError, match="outside the output directory"):
        write_json(out / ".." / "escape.json", {}, root=out)
    with pytest.raises(OutputError, match="symbolic link"):
        ensure_dir(out / "videos", root=out)
    assert list(elsewhere.iterdir()) == [] and not (tmp_path / "escape.json").exists()
    ensure_dir(out / "sub", root=out)
    assert atomic_write_text(out / "sub" / "ok.txt", "x", root=out).read_text() == "x"


def test_no_clobber_without_overwrite(tmp_path: Path) -> None:
    target = tmp_path / "r.json"
    write_json(target, {"a": 1}, overwrite=False)
    with pytest.raises(OutputError, match="exists.*--overwrite"):
        write_json(target, {"a": 2}, overwrite=False)
    assert json.loads(target.read_text()) == {"a": 1}
    write_json(target, {"a": 2}, overwrite=True)
    assert json.loads(target.read_text()) == {"a": 2}
    with pytest.raises(OutputError, match="is a directory"):
        check_target(tmp_path)


def test_a_failed_writer_leaves_the_old_file_and_no_temporary(tmp_path: Path) -> None:
    target = tmp_path / "r.txt"
    target.write_text("old")
    with pytest.raises(RuntimeError):
        with open_atomic(target) as tmp:
            tmp.write_text("half")
            raise RuntimeError("killed mid-write")
    assert target.read_text() == "old" and leftovers(tmp_path) == []
    with pytest.raises(TypeError):  # not JSON: fails before any file is touched
        write_json(tmp_path / "bad.json", {"x": object()})
    assert not (tmp_path / "bad.json").exists() and leftovers(tmp_path) == []


def test_save_figure_keeps_the_format_of_the_suffix(tmp_path: Path) -> None:
    matplotlib = pytest.importorskip("matplotlib")
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, _ = plt.subplots()
    save_figure(fig, tmp_path / "f.png")
    plt.close(fig)
    assert (tmp_path / "f.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and leftovers(tmp_path) == []


# --------------------------------------------------------------------------- videos
def test_a_video_interrupted_mid_encoding_leaves_no_file(tmp_path: Path) -> None:
    pytest.importorskip("imageio_ffmpeg")
    from swarm_env.harness.video import VideoWriter

    path = tmp_path / "run.mp4"
    frame = np.zeros((32, 48, 3), np.uint8)
    with pytest.raises(KeyboardInterrupt):
        with VideoWriter(path, fps=10) as video:
            for _ in range(5):
                video.append(frame)
            raise KeyboardInterrupt  # Ctrl-C (or any failure) while frames are being encoded
    assert not path.exists() and leftovers(tmp_path) == []
    with VideoWriter(path, fps=10) as video:
        video.append(frame)
    assert path.stat().st_size > 0 and leftovers(tmp_path) == []
    with pytest.raises(OutputError, match="exists"):
        VideoWriter(path, fps=10, overwrite=False)


def test_cli_run_video_killed_mid_episode_leaves_no_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    pytest.importorskip("imageio_ffmpeg")
    import swarm_env.harness.cli as cli

    def dies_midway(*args: Any, on_frame: Any = None, **kwargs: Any) -> Any:
        for _ in range(3):
            on_frame(np.zeros((40, 40, 3), np.uint8))
        raise RuntimeError("the process is dying")

    monkeypatch.setattr(cli, "evaluate", dies_midway)
    video = tmp_path / "run.mp4"
    with pytest.raises(RuntimeError, match="dying"):
        main(["run", "--policy", "zero", "--max-cycles", "3", "--video", str(video)])
    assert not video.exists() and leftovers(tmp_path) == []


# --------------------------------------------------------------------------- the commands
def test_cli_run_json_needs_overwrite_to_replace(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    report = tmp_path / "r.json"
    report.write_text("mine")
    argv = ["run", "--policy", "zero", "--max-cycles", "2", "--json", str(report)]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "exists" in err and "--overwrite" in err
    assert report.read_text() == "mine"
    assert main(argv + ["--overwrite"]) == 0
    assert json.loads(report.read_text())["policy"] == "zero"
    link = tmp_path / "link.json"
    link.symlink_to(tmp_path / "target.json")
    assert main(["run", "--policy", "zero", "--max-cycles", "2", "--json", str(link), "--overwrite"]) == 2
    assert "symbolic link" in capsys.readouterr().err and not (tmp_path / "target.json").exists()


def test_leaderboard_files_refuse_a_symlink_inside_out(tmp_path: Path) -> None:
    from swarm_env.harness.leaderboard import run_leaderboard

    board = run_leaderboard(["zero"], ["paper_vo_0"], [0], env_kwargs={"max_cycles": 3}, progress=False)
    out, outside = tmp_path / "lb", tmp_path / "outside.md"
    out.mkdir()
    outside.write_text("keep")
    (out / "leaderboard.md").symlink_to(outside)
    with pytest.raises(OutputError, match="symbolic link"):
        board.write(out)
    assert outside.read_text() == "keep"
    (out / "leaderboard.md").unlink()
    assert [p.name for p in board.write(out)] == ["leaderboard.md", "leaderboard.csv", "leaderboard.json"]
    assert leftovers(out) == []
