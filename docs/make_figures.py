"""Regenerate the README's pictures: one rendered frame per built-in scenario.

    python docs/make_figures.py            # writes docs/images/*.png

Each frame comes from a seeded episode of the ``pursuit`` policy (pure pursuit
to the slot, no avoidance), stopped at the time given below. A large world with a
small swarm (``paper_cbs_switch``: 29 m x 20 m, robots 0.5 m across) is shown as a
window around the swarm at a finer scale, so that the robots stay visible in the
README (the header line of the full frame is kept above the window).
"""

from __future__ import annotations

import os
from pathlib import Path

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")

import numpy as np  # noqa: E402

import swarm_env  # noqa: E402
from swarm_env.harness.policies import load_policy  # noqa: E402
from swarm_env.harness.video import save_frame_png  # noqa: E402
from swarm_env.render import Renderer  # noqa: E402

OUT = Path(__file__).resolve().parent / "images"
#: scenario -> simulated time (s) of the frame
FRAMES = {"paper_vo_45": 16.0, "paper_cbs_switch": 120.0, "corridor": 30.0, "random": 20.0}
#: scenario -> the world window (x0, y0, x1, y1) in m shown instead of the whole world
WINDOWS = {"paper_cbs_switch": (9.0, 5.0, 23.0, 15.0)}
#: width (px) of a windowed figure, about that of the whole-world ones
WINDOW_WIDTH = 800


def frame_at(scenario: str, t: float, seed: int = 0, window: tuple[float, float, float, float] | None = None) -> np.ndarray:
    """The frame at simulated time ``t`` of a ``pursuit`` episode (with the trails of the steps before it);
    with ``window``, only that part of the world, drawn at ``WINDOW_WIDTH / window width`` pixels per
    metre, under the header line of the whole-world frame."""
    env = swarm_env.parallel_env(scenario)
    world = env.unwrapped
    policy = load_policy("pursuit", env)
    obs, _ = env.reset(seed=seed)
    policy.reset(env, seed)
    scn = world.world_state().scenario
    whole = Renderer("rgb_array", scn)
    fine = None if window is None else Renderer("rgb_array", scn, pixels_per_metre=WINDOW_WIDTH / (window[2] - window[0]))
    renderers = [r for r in (whole, fine) if r is not None]
    for r in renderers:
        r.record(world.world_state())
    while env.agents and world.world_state().time < t - 1e-9:
        obs, *_ = env.step(policy.act(obs, world.world_state()))
        for r in renderers:
            r.record(world.world_state())
    frame = whole.render(world.world_state())
    if fine is not None:
        detail = fine.render(world.world_state())
        (x0, y1), (x1, y0) = fine.world_to_pixels(np.array([window[:2], window[2:]])).round().astype(int)
        width = min(x1 - x0, frame.shape[1])
        frame = np.concatenate([frame[: whole.header, :width], detail[y0:y1, x0 : x0 + width]], axis=0)
    for r in renderers:
        r.close()
    env.close()
    return frame


def main() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    for scenario, t in FRAMES.items():
        path = OUT / f"{scenario}.png"
        save_frame_png(path, frame_at(scenario, t, window=WINDOWS.get(scenario)))
        print(f"wrote {path}")


if __name__ == "__main__":
    main()
