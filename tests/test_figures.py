"""The documentation figures: labelled axes with units, legends that hide no curve, robots large enough to see."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

matplotlib = pytest.importorskip("matplotlib")
matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def _overlap(a, b) -> bool:
    return a.x0 < b.x1 and b.x0 < a.x1 and a.y0 < b.y1 and b.y0 < a.y1


def test_vo_paths_figure_has_axes_in_metres_and_humans_apart_from_followers() -> None:
    from swarm_env.scenarios.loader import load_scenario
    from swarm_env_agents.vo_paper import paths_figure

    t = np.linspace(0, 1, 20)
    tr = {
        "leader": np.stack([2 + 10 * t, np.full_like(t, 7), 0 * t], axis=1),
        "pose": np.stack([np.stack([1 + 10 * t, np.full_like(t, 6 + 2 * i), 0 * t], axis=1) for i in range(2)], axis=1),
        "humans": np.stack([np.stack([14 - 10 * t, np.full_like(t, 10 - 6 * j)], axis=1) for j in range(2)], axis=1),
    }
    fig = paths_figure("paper_vo_45", tr, load_scenario("paper_vo_45"))
    ax = fig.axes[0]
    assert ax.get_xlabel() == "x (m)" and ax.get_ylabel() == "y (m)"
    colours = {line.get_label(): matplotlib.colors.to_hex(line.get_color()) for line in ax.get_lines()}
    human = colours["humans"]
    assert all(c != human for label, c in colours.items() if label.startswith("Robot")), colours
    plt.close(fig)


def _eval_csv(path: Path) -> Path:
    rows = ["agent_steps,formation_error,formation_error_ci95,collisions,collisions_ci95"]
    for k in range(8):
        rows.append(f"{k * 100000},{1.0 / (k + 1):.3f},0.05,{3.0 - 0.3 * k:.2f},0.4")
    path.write_text("\n".join(rows) + "\n")
    return path


@pytest.mark.parametrize("kind", ["one run", "methods"])
def test_learning_curve_legend_sits_outside_the_panels(kind: str, tmp_path: Path,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    from swarm_env_baselines import plots

    figures: list = []
    monkeypatch.setattr(plt, "close", lambda fig=None: figures.append(fig))
    refs = {"vo": {"formation_error": 0.25, "collisions": 0.0}, "pursuit": {"formation_error": 0.36, "collisions": 3.3}}
    csv = _eval_csv(tmp_path / "eval.csv")
    if kind == "one run":
        plots.plot_learning_curve(csv, tmp_path / "lc.png", title="t", references=refs,
                                  marks={"fine-tuning": 3e5, "shield on": 3.2e5})
    else:
        plots.plot_methods_learning_curves({"a": [csv, csv], "b": [csv]}, tmp_path / "lc.png", title="t", references=refs)
    assert (tmp_path / "lc.png").is_file()
    fig = figures[-1]
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    assert all(ax.get_legend() is None for ax in fig.axes)  # no legend inside a panel
    (legend,) = fig.legends
    box = legend.get_window_extent(renderer)
    for ax in fig.axes:
        assert not _overlap(box, ax.get_window_extent(renderer)), "the legend covers a panel"
        assert ax.get_ylabel() and "(millions)" in ax.get_xlabel()
    if kind == "one run":  # two marks 20,000 steps apart: their labels do not overlap
        texts = [t for t in fig.axes[0].texts if t.get_text() in ("fine-tuning", "shield on")]
        a, b = (t.get_window_extent(renderer) for t in texts)
        assert not _overlap(a, b)
    plt.close(fig)


def test_paper_cbs_switch_figure_shows_the_robots_large() -> None:
    """make_figures shows paper_cbs_switch through a window at a finer scale: a follower is a disc of about
    14 px radius (0.25 m at 800 px / 14 m), not the 7 px of the whole 29 m world in 800 px."""
    spec = importlib.util.spec_from_file_location("make_figures", ROOT / "docs" / "make_figures.py")
    make_figures = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(make_figures)
    from swarm_env.render import follower_colour

    def disc_pixels(frame: np.ndarray) -> int:
        return int(np.all(frame == np.array(follower_colour(0), dtype=np.uint8), axis=-1).sum())

    x0, y0, x1, y1 = make_figures.WINDOWS["paper_cbs_switch"]
    near_start = (0.0, y0, x1 - x0, y1)  # the same scale, around the followers' start (a short episode)
    whole = make_figures.frame_at("paper_cbs_switch", 2.0)
    window = make_figures.frame_at("paper_cbs_switch", 2.0, window=near_start)
    assert window.shape[1] == whole.shape[1] == 800
    assert disc_pixels(window) >= 3 * disc_pixels(whole) > 0
    assert disc_pixels(window) > 0.6 * np.pi * 14**2
