"""swarm-env: a PettingZoo environment of a leader-follower robot swarm on pymunk.

.. code-block:: python

    import swarm_env
    env = swarm_env.parallel_env("paper_vo_0", render_mode="rgb_array")
    obs, infos = env.reset(seed=0)
    while env.agents:
        actions = {a: env.action_space(a).sample() for a in env.agents}
        obs, rewards, terminations, truncations, infos = env.step(actions)
    print(env.unwrapped.episode_metrics())

``parallel_env(...)`` returns the :class:`SwarmEnv` ParallelEnv; ``env(...)``
its AEC view (``pettingzoo.utils.parallel_to_aec``); ``raw_env`` is the class.
"""

from __future__ import annotations

from typing import Any

from pettingzoo.utils.conversions import parallel_to_aec

from swarm_env.env import PRIMITIVE_ANGLES_DEG, SwarmEnv
from swarm_env.scenario import Scenario, ScenarioError
from swarm_env.scenarios.loader import list_scenarios, load_scenario
from swarm_env.sensing.layout import OBS_LEADER, OBS_OWN_TWIST, OBS_SLOT, OBS_SWITCH, observation_layout
from swarm_env.state import WorldState

__version__ = "0.1.0"

raw_env = SwarmEnv


def parallel_env(scenario: Any = "paper_vo_0", **kwargs: Any) -> SwarmEnv:
    """The PettingZoo ParallelEnv; see :class:`SwarmEnv` for the arguments."""
    return SwarmEnv(scenario, **kwargs)


def env(scenario: Any = "paper_vo_0", **kwargs: Any) -> Any:
    """The AEC view of :func:`parallel_env` (PettingZoo's ``parallel_to_aec``)."""
    return parallel_to_aec(SwarmEnv(scenario, **kwargs))


__all__ = [
    "OBS_LEADER",
    "OBS_OWN_TWIST",
    "OBS_SLOT",
    "OBS_SWITCH",
    "PRIMITIVE_ANGLES_DEG",
    "Scenario",
    "ScenarioError",
    "SwarmEnv",
    "WorldState",
    "env",
    "list_scenarios",
    "load_scenario",
    "observation_layout",
    "parallel_env",
    "raw_env",
]
