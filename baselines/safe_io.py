"""Policies saved as tensors plus JSON: a format whose loading cannot run code.

A policy directory in this format holds::

    policy.safetensors   every tensor of the SB3 policy network (safetensors: data only)
    policy.json          what is needed to rebuild it: the algorithm, the observation and action
                         spaces, SB3's policy_kwargs, and the observation normalisation statistics

SB3's own ``model.zip`` stores parts of the model with cloudpickle and ``VecNormalize`` pickles
itself; unpickling either can run arbitrary code. :func:`save_policy` writes the network and the
statistics in this format beside them (``swarm_env_baselines.model_io.save_model`` does it for every saved
model), and :func:`load_policy_dir` rebuilds the policy from it with no pickle involved, for
scoring; :func:`saved_statistics` gives the normalisation statistics (observations and returns)
to a warm start. Training state (optimizer, replay buffer, schedules) is not part of the format.

Every reader here raises ``ValueError`` with one line naming the file and what is wrong
(:func:`read_tensors`, :func:`read_description`); the policy loaders turn it into a
:class:`~swarm_env.harness.policies.ModelFileError`.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import gymnasium
import numpy as np

from swarm_env.harness.policies import ModelFileError, pickle_trusted
from swarm_env.jsonio import write_json
from swarm_env.outputs import open_atomic, replace_dir

if TYPE_CHECKING:
    from stable_baselines3.common.base_class import BaseAlgorithm
    from stable_baselines3.common.vec_env import VecNormalize

FORMAT = "swarm_env.sb3-policy/1"
#: The formats of the other run descriptions this package writes (each its own ``policy.json``).
MAPPO_FORMAT = "swarm_env.mappo/1"
SAC_FORMAT = "swarm_env.sac/1"
RLLIB_FORMAT = "swarm_env.rllib/1"
#: The policy specs that load a description of each format (for the error that meets the wrong one).
LOADERS = {FORMAT: "ppo:PATH, sac:PATH or bc:PATH", RLLIB_FORMAT: "rllib:PATH", SAC_FORMAT: "isac:PATH",
           MAPPO_FORMAT: "mappo:PATH, ippo:PATH, mappo_shielded:PATH or residual_vo:PATH"}
#: Every saved policy directory's two files: the tensors and their description.
WEIGHTS_FILE = "policy.safetensors"
CONFIG_FILE = "policy.json"

__all__ = ["FORMAT", "MAPPO_FORMAT", "SAC_FORMAT", "RLLIB_FORMAT", "LOADERS", "WEIGHTS_FILE", "CONFIG_FILE", "ObsNormalizer",
           "algorithm_class", "save_policy", "load_policy_dir", "has_safe_policy", "saved_statistics", "read_tensors",
           "read_description", "refuse_pickle", "one_line"]


class ObsNormalizer:
    """``VecNormalize.normalize_obs`` from saved statistics: ``clip((obs - mean) / sqrt(var + eps), +-clip)``
    as float32, the same arithmetic as stable-baselines3, without a pickled VecNormalize."""

    def __init__(self, mean: np.ndarray, var: np.ndarray, epsilon: float, clip_obs: float) -> None:
        self.mean = np.asarray(mean, dtype=np.float64)
        self.var = np.asarray(var, dtype=np.float64)
        self.epsilon = float(epsilon)
        self.clip_obs = float(clip_obs)

    def normalize_obs(self, obs: np.ndarray) -> np.ndarray:
        return np.clip((obs - self.mean) / np.sqrt(self.var + self.epsilon), -self.clip_obs, self.clip_obs).astype(np.float32)


def has_safe_policy(directory: str | Path) -> bool:
    """Whether ``directory`` holds a policy in this format."""
    d = Path(directory)
    return (d / WEIGHTS_FILE).is_file() and (d / CONFIG_FILE).is_file()


def save_policy(model: BaseAlgorithm, directory: str | Path, algo: str, vecnorm: VecNormalize | None = None) -> Path:
    """Write ``policy.safetensors`` and ``policy.json`` for ``model`` (trained with ``algo``) into ``directory``.

    Both files are written to a temporary name in ``directory`` and renamed, so a reader never
    sees half a file. Returns the directory.
    """
    from safetensors.torch import save_file

    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    tensors = {k: v.detach().cpu().contiguous() for k, v in model.policy.state_dict().items()}
    config: dict[str, Any] = {
        "format": FORMAT,
        "algo": algo,
        "observation_space": _space_to_json(model.observation_space),
        "action_space": _space_to_json(model.action_space),
        "policy_kwargs": _jsonable(model.policy_kwargs),
        "normalization": _normalization_to_json(vecnorm),
    }
    with _atomic(out / WEIGHTS_FILE) as tmp:
        save_file(tensors, str(tmp))
    with _atomic(out / CONFIG_FILE) as tmp:
        write_json(tmp, config, indent=1)
    return out


def algorithm_class(name: str) -> type[BaseAlgorithm]:
    """The SB3 algorithm class for ``name`` (``ppo``, ``sac``, ``a2c``, ``td3``, ``ddpg``; ``bc`` = PPO)."""
    import stable_baselines3 as sb3

    classes = {"ppo": sb3.PPO, "bc": sb3.PPO, "sac": sb3.SAC, "a2c": sb3.A2C, "td3": sb3.TD3, "ddpg": sb3.DDPG}
    try:
        return classes[name.lower()]
    except KeyError:
        raise ValueError(f"unknown algorithm {name!r}; expected one of {sorted(classes)}") from None


def load_policy_dir(directory: str | Path) -> tuple[Any, ObsNormalizer | None, str]:
    """Rebuild ``(SB3 policy on CPU, observation normalizer or None, algo)`` from ``directory``.

    Raises ``ValueError`` naming the file and what is wrong (a missing or unreadable file, unknown
    format, a missing key, tensors that do not fit the network).
    """
    d = Path(directory)
    cfg_path = d / CONFIG_FILE
    config = read_description(cfg_path, FORMAT)
    try:
        algo = str(config["algo"])
        obs_space = _space_from_json(config["observation_space"])
        act_space = _space_from_json(config["action_space"])
        kwargs = dict(config["policy_kwargs"])
        policy_class = algorithm_class(algo).policy_aliases["MlpPolicy"]
        policy = policy_class(obs_space, act_space, lambda _: 0.0, **kwargs)
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{cfg_path}: not a policy description this version can rebuild ({one_line(exc)})") from None
    state = read_tensors(d / WEIGHTS_FILE)
    try:
        policy.load_state_dict(state, strict=True)
    except (RuntimeError, ValueError) as exc:  # missing/unexpected keys, shape mismatches
        raise ValueError(f"{d / WEIGHTS_FILE}: the tensors do not fit the network of {cfg_path.name} ({one_line(exc)})") from None
    policy.set_training_mode(False)
    return policy, _normalization_from_json(config.get("normalization"), cfg_path), algo


def saved_statistics(directory: str | Path) -> tuple[Any, Any]:
    """``(observation statistics, return statistics)`` of the policy saved in ``directory``, as
    stable-baselines3 ``RunningMeanStd`` objects (what ``VecNormalize.obs_rms`` / ``ret_rms`` hold),
    each ``None`` when not saved (no normalisation; a file written before the returns were saved).
    No pickle involved; ``ValueError`` naming ``policy.json`` for a bad description.
    """
    from stable_baselines3.common.running_mean_std import RunningMeanStd

    cfg_path = Path(directory) / CONFIG_FILE
    d = read_description(cfg_path, FORMAT).get("normalization")
    if d is None:
        return None, None
    try:
        obs = RunningMeanStd(shape=np.shape(d["mean"]))
        obs.mean, obs.var, obs.count = np.asarray(d["mean"], np.float64), np.asarray(d["var"], np.float64), float(d["count"])
        ret = None
        if d.get("returns") is not None:
            ret = RunningMeanStd(shape=())
            r = d["returns"]
            ret.mean, ret.var, ret.count = np.float64(r["mean"]), np.float64(r["var"]), float(r["count"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{cfg_path}: normalization: {one_line(exc)}") from None
    if obs.var.shape != obs.mean.shape:
        raise ValueError(f"{cfg_path}: normalization: mean has shape {obs.mean.shape}, var {obs.var.shape}")
    return obs, ret


def read_tensors(path: Path) -> dict[str, Any]:
    """Every tensor of the safetensors file ``path`` (on CPU), or a ``ValueError`` naming the file:
    missing, or not a readable safetensors file (truncated, corrupt, something else)."""
    from safetensors.torch import load_file

    if not path.is_file():
        raise ValueError(f"{path}: missing (a saved policy directory holds {WEIGHTS_FILE} and {CONFIG_FILE})")
    try:
        return load_file(str(path), device="cpu")
    except Exception as exc:  # noqa: BLE001 - safetensors raises its own error types (and OSError); all mean "bad file"
        raise ValueError(f"{path}: not a readable safetensors file, truncated or corrupt ({one_line(exc)})") from None


def read_description(path: Path, fmt: str) -> dict[str, Any]:
    """The JSON object in ``path`` whose ``format`` is ``fmt``, or a ``ValueError`` naming the file: missing,
    not JSON (truncated, corrupt), or another format (then it says which spec loads that one)."""
    if not path.parent.is_dir():
        raise ValueError(f"{path.parent}: no such directory (a saved policy directory holds {path.name} and {WEIGHTS_FILE})")
    if not path.is_file():
        raise ValueError(f"{path}: missing (a saved policy directory holds {path.name} and {WEIGHTS_FILE})")
    try:
        config = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path}: not a readable JSON policy description ({one_line(exc)})") from None
    got = config.get("format") if isinstance(config, dict) else config
    if got != fmt:
        hint = LOADERS.get(got) if isinstance(got, str) else None
        raise ValueError(f"{path}: format: expected {fmt!r}, got {got!r}" + (f" (load it with {hint})" if hint else ""))
    return config



def refuse_pickle(path: Path, what: str, trust_pickle: bool | None, convert: bool = True) -> None:
    """Raise a :class:`~swarm_env.harness.policies.ModelFileError` about ``path`` (which would unpickle ``what``)
    unless pickles are trusted (:func:`swarm_env.harness.policies.pickle_trusted` of ``trust_pickle``); the
    message says how to opt in and, with ``convert``, how to convert the directory once instead."""
    if pickle_trusted(trust_pickle):
        return
    remedy = (f", or convert it once: swarm-env convert {path.parent} --trust-pickle" if convert else "")
    raise ModelFileError(f"{path}: loading it would unpickle {what}, and unpickling runs any code the file carries; "
                         f"refused. If you trust its source, opt in with --trust-pickle, SWARM_ENV_TRUST_PICKLE=1 or "
                         f"trust_pickle=True in Python{remedy} (docs/baselines.md, 'Model files and safety')")


def one_line(exc: BaseException) -> str:
    """``exc`` as one line for an error message: its type when the text says nothing, whitespace runs
    (torch's multi-line state-dict reports) folded, at most 300 characters."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if len(text) <= 300 else text[:297] + "..."


# --------------------------------------------------------------------------- helpers


# The one atomic-write rule of the project (temp file in the same directory, renamed on success,
# removed on failure, no symlink followed): swarm_env.outputs.open_atomic, under the name the
# model writers here and in mappo_policy / rllib_train use.
_atomic = open_atomic


#: Replace a directory by a finished sibling (the old one moved aside first): :func:`swarm_env.outputs.replace_dir`.
swap_in_dir = replace_dir


def _space_to_json(space: gymnasium.Space) -> dict[str, Any]:
    if isinstance(space, gymnasium.spaces.Box):
        return {"type": "Box", "shape": list(space.shape), "dtype": str(space.dtype),
                "low": space.low.ravel().tolist(), "high": space.high.ravel().tolist()}
    if isinstance(space, gymnasium.spaces.Discrete):
        return {"type": "Discrete", "n": int(space.n), "start": int(space.start)}
    raise ValueError(f"cannot describe a {type(space).__name__} space in {CONFIG_FILE}")


def _space_from_json(d: dict[str, Any]) -> gymnasium.Space:
    if d["type"] == "Box":
        shape = tuple(int(v) for v in d["shape"])
        low = np.asarray(d["low"], dtype=d["dtype"]).reshape(shape)
        high = np.asarray(d["high"], dtype=d["dtype"]).reshape(shape)
        return gymnasium.spaces.Box(low, high, shape, dtype=d["dtype"])
    if d["type"] == "Discrete":
        return gymnasium.spaces.Discrete(int(d["n"]), start=int(d.get("start", 0)))
    raise ValueError(f"unknown space type {d['type']!r}")


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, (bool, int, str)) or value is None:
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    raise ValueError(f"policy_kwargs value {value!r} ({type(value).__name__}) has no JSON form")


def _normalization_to_json(vecnorm: VecNormalize | None) -> dict[str, Any] | None:
    # Everything a warm start takes from VecNormalize (observation and return statistics), so that it
    # never needs vecnormalize.pkl; "norm_obs": false keeps the statistics but the policy reads raw inputs.
    if vecnorm is None:
        return None
    rms, ret = vecnorm.obs_rms, vecnorm.ret_rms
    return {"norm_obs": bool(vecnorm.norm_obs),
            "mean": np.asarray(rms.mean, dtype=np.float64).tolist(), "var": np.asarray(rms.var, dtype=np.float64).tolist(),
            "count": float(rms.count), "epsilon": float(vecnorm.epsilon), "clip_obs": float(vecnorm.clip_obs),
            "returns": {"mean": float(ret.mean), "var": float(ret.var), "count": float(ret.count)}}


def _normalization_from_json(d: dict[str, Any] | None, source: Path) -> ObsNormalizer | None:
    if d is None or not d.get("norm_obs", True):  # files written before "norm_obs" had no block without it
        return None
    try:
        return ObsNormalizer(np.asarray(d["mean"]), np.asarray(d["var"]), d["epsilon"], d["clip_obs"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{source}: normalization: {exc}") from None
