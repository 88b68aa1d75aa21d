"""Saved SB3 models as swarm_env policies: the ``ppo:PATH``, ``sac:PATH`` and ``bc:PATH`` entry points.

A saved model is a directory (or its ``model.zip``) holding::

    policy.safetensors + policy.json   the policy network and its observation statistics as
                                       tensors and JSON (swarm_env_baselines.safe_io): loading cannot run code
    model.zip          the SB3 model (``model.save``), for resuming and warm starts
    vecnormalize.pkl   optional: the VecNormalize statistics the model was trained with

A policy spec loads the safe files when the directory has them (every directory that
:func:`save_model` writes does) and falls back to ``model.zip`` + ``vecnormalize.pkl``
(pickles: only for files you trust) for older ones. :func:`load_model` reads the
pickled pair, for training. :class:`SB3Policy` feeds each follower's
observation through the same normalisation, then ``model.predict`` on the
stacked batch (parameter sharing), deterministic by default. ``bc`` models are
PPO-format checkpoints whose policy network was trained by behaviour cloning
(see :mod:`swarm_env_baselines.bc`).

Every spec needs a path: the v0 checkpoints that ``ppo`` and ``bc`` once loaded without one
were retired in issue 10 (trained on swarm_env_v0 from an uncommitted tree; superseded by the
shipped methods of :mod:`swarm_env_baselines.mappo_policy`), and a bare name says so.
"""

from __future__ import annotations

import pickle
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from swarm_env.policies import OBSERVATIONS, PolicyError
from swarm_env.state import WorldState

if TYPE_CHECKING:
    from stable_baselines3.common.base_class import BaseAlgorithm
    from stable_baselines3.common.vec_env import VecNormalize

    from swarm_env.env import SwarmEnv

MODEL_FILE = "model.zip"
VECNORM_FILE = "vecnormalize.pkl"
#: What a bare ``ppo`` / ``bc`` says since their v0 checkpoints were retired.
RETIRED = ("the v0 checkpoint that {algo!r} loaded without a path was retired (trained on swarm_env_v0 from an "
           "uncommitted tree); give a run directory, {algo}:PATH, or use a shipped method: ippo, mappo, "
           "mappo_shielded, residual_vo (docs/baselines.md)")


def _running_mean_std_base() -> type:
    from stable_baselines3.common.running_mean_std import RunningMeanStd

    return RunningMeanStd


class FrozenRunningMeanStd(_running_mean_std_base()):  # type: ignore[misc]
    """Observation statistics that ``VecNormalize`` cannot update (``TrainConfig.freeze_obs_stats``).

    A warm-started network was fitted to its source's normalised observations; letting the
    statistics drift with the new policy's state distribution changes its inputs under it. It lives
    here, in an importable module, because saved ``vecnormalize.pkl`` files refer to it by name.
    """

    def update(self, arr: Any) -> None:
        pass


def algorithm_class(name: str) -> type["BaseAlgorithm"]:
    """The SB3 algorithm class for ``name`` (``ppo``, ``sac``, ``a2c``, ``td3``, ``ddpg``; ``bc`` = PPO)."""
    import stable_baselines3 as sb3

    classes = {"ppo": sb3.PPO, "bc": sb3.PPO, "sac": sb3.SAC, "a2c": sb3.A2C, "td3": sb3.TD3, "ddpg": sb3.DDPG}
    try:
        return classes[name.lower()]
    except KeyError:
        raise ValueError(f"unknown algorithm {name!r}; expected one of {sorted(classes)}") from None


def resolve_model_path(path: str | Path) -> Path:
    """``path`` itself if it is a file, else ``path/model.zip``; raises ``FileNotFoundError`` naming both."""
    p = Path(path).expanduser()
    if p.is_dir():
        p = p / MODEL_FILE
    if not p.is_file():
        raise FileNotFoundError(f"no saved model at {path!s} (expected a .zip file or a directory with {MODEL_FILE})")
    return p


def save_model(model: "BaseAlgorithm", directory: str | Path, vecnorm: "VecNormalize | None" = None) -> Path:
    """Write the policy as tensors + JSON (:func:`swarm_env_baselines.safe_io.save_policy`), and ``model.zip``
    (and ``vecnormalize.pkl`` if given) for training, into ``directory``; returns the directory."""
    from swarm_env_baselines.safe_io import save_policy

    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    model.save(out / MODEL_FILE)
    if vecnorm is not None:
        vecnorm.save(str(out / VECNORM_FILE))
    save_policy(model, out, type(model).__name__.lower(), vecnorm)
    return out


def load_model(path: str | Path, algo: str = "ppo") -> tuple["BaseAlgorithm", "VecNormalize | None"]:
    """Load a saved model (on CPU) and its VecNormalize statistics, if saved beside it."""
    model_path = resolve_model_path(path)
    model = algorithm_class(algo).load(model_path, device="cpu")
    vecnorm = None
    stats = model_path.parent / VECNORM_FILE
    if stats.is_file():
        with open(stats, "rb") as fh:
            vecnorm = pickle.load(fh)  # a VecNormalize without its venv: normalize_obs() still works
        vecnorm.training = False
    return model, vecnorm


class SB3Policy:
    """A trained SB3 model controlling every follower with one shared network.

    Args:
        model: anything with SB3's ``predict``.
        vecnorm: the ``VecNormalize`` statistics to apply to observations (or ``None``).
        deterministic: act on the mean / most likely action (default) or sample.
        name: for error messages.
    """

    def __init__(self, model: Any, vecnorm: "VecNormalize | None" = None, *, deterministic: bool = True, name: str = "model") -> None:
        self.model = model
        self.vecnorm = vecnorm
        self.deterministic = deterministic
        self.name = name

    def reset(self, env: "SwarmEnv", seed: int | None) -> None:
        agent = env.possible_agents[0]
        want_obs, have_obs = self.model.observation_space.shape, env.observation_space(agent).shape
        if want_obs != have_obs:
            raise PolicyError(
                f"{self.name} was trained on observations of shape {want_obs}, this env gives {have_obs} "
                "(different sensors in the scenario)"
            )
        want_act, have_act = self.model.action_space, env.action_space(agent)
        if type(want_act) is not type(have_act) or want_act.shape != have_act.shape:
            raise PolicyError(f"{self.name} acts in {want_act}, this env expects {have_act} (action_type={env.action_type!r})")

    def act(self, observations: dict[str, np.ndarray], state: WorldState) -> dict[str, Any]:
        agents = list(observations)
        if not agents:
            return {}
        batch = np.stack([observations[a] for a in agents])
        if self.vecnorm is not None:
            batch = self.vecnorm.normalize_obs(batch)
        actions, _ = self.model.predict(batch, deterministic=self.deterministic)
        return {a: actions[i] for i, a in enumerate(agents)}


def _make(algo: str, env: "SwarmEnv", arg: str | None) -> SB3Policy:
    if not arg:
        if algo in ("ppo", "bc"):
            raise PolicyError(f"policy {algo!r}: " + RETIRED.format(algo=algo))
        raise PolicyError(f"policy {algo!r} needs a model path: {algo}:PATH (a run directory or a .zip)")
    path = arg
    import torch

    # Scoring runs the MLP on a handful of observations per step, where torch's thread pool only adds
    # overhead: on this busy 2-core machine it made scoring ~50x slower (115 s vs 2.5 s for 10 episodes).
    # A policy loaded by name is for scoring, so the process gets one torch thread; load_model itself
    # (used by training's --init-from) leaves the thread count alone.
    torch.set_num_threads(1)
    from swarm_env_baselines.safe_io import has_safe_policy, load_policy_dir

    where = Path(path).expanduser()  # type: ignore[arg-type]
    model: Any
    if has_safe_policy(where):  # tensors + JSON: nothing to unpickle
        try:
            model, vecnorm, saved_algo = load_policy_dir(where)
        except ValueError as exc:
            raise PolicyError(f"policy {algo}:{path}: {exc}") from None
        family = {"bc": "ppo"}.get(algo, algo)
        if {"bc": "ppo"}.get(saved_algo, saved_algo) != family:
            raise PolicyError(f"policy {algo}:{path}: {where} holds a {saved_algo} policy; load it as {saved_algo}:{path}")
    else:
        try:
            model, vecnorm = load_model(path, algo)  # type: ignore[arg-type]
        except FileNotFoundError as exc:
            raise PolicyError(str(exc)) from None
    policy = SB3Policy(model, vecnorm, name=f"{algo}:{path}")
    policy.reset(env, None)  # shape checks now, so a mismatch is reported before any episode runs
    return policy


def make_ppo_policy(env: "SwarmEnv", arg: str | None = None) -> SB3Policy:
    """Entry point ``ppo:PATH``: a PPO model saved by ``swarm-env train sb3``."""
    return _make("ppo", env, arg)


def make_bc_policy(env: "SwarmEnv", arg: str | None = None) -> SB3Policy:
    """Entry point ``bc:PATH``: a behaviour-cloned policy saved by ``swarm-env bc``."""
    return _make("bc", env, arg)


def make_sac_policy(env: "SwarmEnv", arg: str | None = None) -> SB3Policy:
    """Entry point ``sac:PATH``: a SAC model."""
    return _make("sac", env, arg)


# What the leaderboard's "acts on" column says: the networks read each follower's own observation.
make_ppo_policy.acts_on = OBSERVATIONS  # type: ignore[attr-defined]
make_bc_policy.acts_on = OBSERVATIONS  # type: ignore[attr-defined]
make_sac_policy.acts_on = OBSERVATIONS  # type: ignore[attr-defined]
