"""Regenerate the README's pictures: one rendered frame per built-in scenario.

    python docs/make_figures.py            # writes docs/images/*.png

Each frame comes from a seeded episode of the ``pursuit`` policy (pure pursuit
to the slot, no avoidance), stopped at the time given below.
"""

from __future__ import annotations

import os
from pathlib import Path

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")

import numpy as np  # noqa: E402

import swarm_env  # noqa: E402
from swarm_env.policies import load_policy  # noqa: E402
from swarm_env.video import save_frame_png  # noqa: E402

OUT = Path(__file__).resolve().parent / "images"
#: scenario -> simulated time (s) of the frame
FRAMES = {"paper_vo_45": 16.0, "paper_cbs_switch": 120.0, "corridor": 30.0, "random": 20.0}


def frame_at(scenario: str, t: float, seed: int = 0) -> np.ndarray:
    env = swarm_env.parallel_env(scenario, render_mode="rgb_array")
    policy = load_policy("pursuit", env)
    obs, _ = env.reset(seed=seed)
    policy.reset(env, seed)
    while env.agents and env.unwrapped.world_state().time < t - 1e-9:
        obs, *_ = env.step(policy.act(obs, env.unwrapped.world_state()))
    frame = env.render()
    env.close()
    return frame


def main() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    for scenario, t in FRAMES.items():
        path = OUT / f"{scenario}.png"
        save_frame_png(path, frame_at(scenario, t))
        print(f"wrote {path}")


if __name__ == "__main__":
    main()
