"""PettingZoo wrappers of :class:`~swarm_env.env.SwarmEnv`, and the env as other libraries build it.

:func:`rllib_env` is RLlib's env creator (``register_env("swarm_env", rllib_env)``). It lives in the package,
not in a script, so that RLlib's remote env runners on every node of a cluster import it by name (a creator
defined in an example script is pickled by reference to a module the other nodes do not have).

:class:`SafetyShield` is the safety layer any learner can use, in training and at execution:
each follower's action is replaced by the nearest safe twist of the velocity-obstacle search
the ``vo`` expert uses (:func:`swarm_env.control.safety.safe_follower_twists`: one implementation),
and every intervention is reported.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from pettingzoo.utils.wrappers import BaseParallelWrapper

from swarm_env.control.safety import AvoidanceParams, ShieldResult, shield_actions
from swarm_env.env import SwarmEnv

__all__ = ["SafetyShield", "SHIELD_INFO_KEYS", "RewardScale", "rllib_env"]

#: The infos keys the shield adds for every agent (at reset too, where they are False / 0.0 / True).
SHIELD_INFO_KEYS = ("shield_intervened", "shield_correction", "shield_feasible")


class SafetyShield(BaseParallelWrapper):
    """Replace each follower's action by the nearest safe twist (a VO safety layer).

    Before every step the learner's actions are turned into twists ``(v, omega)``, and
    :func:`~swarm_env.control.safety.safe_follower_twists` returns for each follower the safe
    twist closest to its own (unchanged when it is already safe) against the other
    followers, a robot leader, the humans and the static map over ``params.horizon``
    seconds; the env then steps with those. Observations, rewards and the episode are the
    wrapped env's: a learner trained through the shield is rewarded for what was executed.

    Infos gain, per agent (the same keys at reset):

    * ``shield_intervened`` (bool): the executed action differs from the learner's;
    * ``shield_correction`` (float): the size of the change, the Euclidean distance
      between the two normalised actions (``[-1, 1]^2`` units, at most ``2 * sqrt(2)``);
    * ``shield_feasible`` (bool): a safe candidate existed (if not, the least
      dangerous candidate, or a turn in place towards open space, was executed).

    ``episode_metrics()`` adds ``shield``: ``{"interventions", "intervention_rate",
    "mean_correction", "max_correction", "infeasible", "agent_steps"}`` over the episode,
    plus ``per_agent`` interventions. ``last_safe_actions`` holds the actions executed
    in the last step.

    Args:
        env: a :class:`~swarm_env.env.SwarmEnv` with ``action_type="continuous"`` (or a
            wrapper of one).
        params: the VO search's :class:`~swarm_env.control.safety.AvoidanceParams` (the ``vo``
            expert's defaults); ``w_heading`` is set to 0 by default so the answer is the
            candidate nearest to the learner's twist, not one that also keeps a heading.
    """

    def __init__(self, env: Any, params: AvoidanceParams | None = None) -> None:
        super().__init__(env)
        base = env.unwrapped
        if getattr(base, "action_type", None) != "continuous":
            raise ValueError("SafetyShield needs action_type='continuous': it replaces actions by safe twists (v, omega)")
        self.params = params if params is not None else AvoidanceParams(w_heading=0.0)
        self.metadata = env.metadata
        self.last_safe_actions: dict[str, np.ndarray] = {}
        self._reset_counts()

    def start_episode(self) -> None:
        """Forget the last episode's interventions (:meth:`reset` calls it; so does the batched
        engine, which resets the wrapped env itself)."""
        self._reset_counts()
        self.last_safe_actions = {}

    def _reset_counts(self) -> None:
        n = len(self.env.possible_agents)
        self._interventions = np.zeros(n, dtype=np.int64)
        self._correction_sum = 0.0
        self._correction_max = 0.0
        self._infeasible = 0
        self._agent_steps = 0

    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        obs, infos = self.env.reset(seed=seed, options=options)
        self.start_episode()
        for info in infos.values():
            info.update(shield_intervened=False, shield_correction=0.0, shield_feasible=True)
        return obs, infos

    def step(self, actions: dict[str, Any]) -> tuple[dict, dict, dict, dict, dict]:
        base = self.env.unwrapped
        agents = list(base.agents)
        shield = self.protect(base.normalised_actions(actions))  # validated as step() would
        self.last_safe_actions = {a: shield.actions[i] for i, a in enumerate(agents)}
        obs, rewards, terms, truncs, infos = self.env.step(self.last_safe_actions)
        for i, a in enumerate(agents):
            infos[a].update(
                shield_intervened=bool(shield.intervened[i]),
                shield_correction=float(shield.correction[i]),
                shield_feasible=bool(shield.feasible[i]),
            )
        return obs, rewards, terms, truncs, infos

    def protect(self, wanted: np.ndarray) -> ShieldResult:
        """The :func:`~swarm_env.control.safety.shield_actions` result for the live agents' normalised
        actions ``wanted`` ``(N, 2)`` in the current state, counted in the episode's shield
        metrics. :meth:`step` and the batched engine (:mod:`swarm_env.vector.engine`) both use it."""
        base = self.env.unwrapped
        shield = shield_actions(base.world_state(), wanted, self.params)
        index = [base.possible_agents.index(a) for a in base.agents]
        self._interventions[index] += shield.intervened
        self._correction_sum += float(shield.correction.sum())
        self._correction_max = max(self._correction_max, float(shield.correction.max(initial=0.0)))
        self._infeasible += int(np.count_nonzero(~shield.feasible))
        self._agent_steps += len(index)
        return shield

    def render(self, mode: str | None = None) -> Any:
        return self.env.render(mode) if mode is not None else self.env.render()

    def episode_metrics(self) -> dict[str, Any]:
        """The wrapped env's :meth:`~swarm_env.env.SwarmEnv.episode_metrics` plus ``shield``."""
        out = dict(self.env.episode_metrics())
        steps = self._agent_steps
        total = int(self._interventions.sum())
        out["shield"] = {
            "interventions": total,
            "intervention_rate": total / steps if steps else 0.0,
            "mean_correction": self._correction_sum / steps if steps else 0.0,
            "max_correction": self._correction_max,
            "infeasible": self._infeasible,
            "agent_steps": steps,
            "per_agent": dict(zip(self.env.possible_agents, self._interventions.tolist())),
        }
        return out

    def world_state(self) -> Any:
        return self.env.world_state()


class RewardScale(BaseParallelWrapper):
    """Every reward multiplied by ``scale`` (a finite number > 0), for learners whose value function assumes
    returns of order 1-10.

    A follower's per-step reward is about -1 to -20 and an episode's return thousands below zero (600-step
    episodes), so a value head regressing discounted returns (``gamma = 0.99``: hundreds to thousands) starts
    with errors in the hundreds: RLlib's value loss sits at its clip (``vf_clip_param = 10``) and SB3's
    explained variance near 0. ``scale = 0.01`` brings them to units and tens. The scale changes no
    optimum (it is a positive factor); episode metrics in ``infos`` and the env's own scoring are unchanged.
    SB3 users can use ``VecNormalize(norm_reward=True)`` instead (docs/clients.md, "Reward scale").
    """

    def __init__(self, env: Any, scale: float) -> None:
        if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not (np.isfinite(scale) and scale > 0):
            raise ValueError(f"reward scale: expected a finite number > 0, got {scale!r}")
        super().__init__(env)
        self.scale = float(scale)

    def step(self, actions: dict[str, Any]) -> tuple[dict, dict, dict, dict, dict]:
        observations, rewards, terminations, truncations, infos = super().step(actions)
        return observations, {a: r * self.scale for a, r in rewards.items()}, terminations, truncations, infos


def rllib_env(config: Any) -> Any:
    """RLlib's env creator for swarm-env: ``ParallelPettingZooEnv(SwarmEnv(scenario, **kwargs))``, where
    ``config`` (RLlib's ``env_config``, a dict) holds ``scenario`` (default ``"paper_vo_0"``), optionally
    ``reward_scale`` (a :class:`RewardScale` around the env; default 1, none) and any other
    :class:`~swarm_env.env.SwarmEnv` keyword arguments. Needs the ``ray`` extra (RLlib) where it is called."""
    from ray.rllib.env.wrappers.pettingzoo_env import ParallelPettingZooEnv

    kwargs = dict(config)
    scale = kwargs.pop("reward_scale", 1.0)
    env: Any = SwarmEnv(kwargs.pop("scenario", "paper_vo_0"), **kwargs)
    if scale != 1.0:
        env = RewardScale(env, scale)
    return ParallelPettingZooEnv(env)
