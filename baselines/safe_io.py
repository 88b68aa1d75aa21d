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
:class:`~swarm_env.harness.policies.ModelFileError`. Both readers, and the checks of a description before
anything is built from it, are :mod:`swarm_env_baselines.model_bounds`'s: regular files of bounded size only,
bounded JSON, at most so many float tensors of finite values, every size and number in range.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import gymnasium
import numpy as np

from swarm_env.env import PRIMITIVE_ANGLES_DEG
from swarm_env.harness.policies import ModelFileError, pickle_trusted
from swarm_env.jsonio import write_json
from swarm_env.limits import MAX_ABS_NUMBER, clip_repr, printable
from swarm_env.outputs import open_atomic, replace_dir
from swarm_env_baselines import model_bounds as mb

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
           "read_description", "check_description", "refuse_pickle", "one_line"]


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
        check_description(config)
        algo = str(config["algo"])
        obs_space = _space_from_json(config["observation_space"])
        act_space = _space_from_json(config["action_space"])
        kwargs = dict(config["policy_kwargs"])
        policy_class = algorithm_class(algo).policy_aliases["MlpPolicy"]
        policy = policy_class(obs_space, act_space, lambda _: 0.0, **kwargs)
    except Exception as exc:  # noqa: BLE001 - the checks' ValueError, and whatever SB3 raises on what passed them
        raise ValueError(f"{mb.shown(cfg_path)}: not a policy description this version can rebuild "
                         f"({one_line(exc)})") from None
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
        _check_normalization(d, None)
    except ValueError as exc:
        raise ValueError(f"{mb.shown(cfg_path)}: {one_line(exc)}") from None
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
    """Every tensor of the safetensors file ``path`` (on CPU), or a ``ValueError`` naming the file: missing, not a
    regular file, too large, not a readable safetensors file (truncated, corrupt, something else), too many tensors,
    a dtype other than float32/float64, or values that are not finite
    (:func:`swarm_env_baselines.model_bounds.read_safetensors`)."""
    try:
        return mb.read_safetensors(path)
    except FileNotFoundError:
        raise ValueError(f"{mb.shown(path)}: missing (a saved policy directory holds {WEIGHTS_FILE} and "
                         f"{CONFIG_FILE})") from None


def read_description(path: Path, fmt: str) -> dict[str, Any]:
    """The JSON object in ``path`` whose ``format`` is ``fmt``, or a ``ValueError`` naming the file: missing,
    not a regular file, too large (a ``policy.json`` at most
    :data:`~swarm_env_baselines.model_bounds.MAX_DESCRIPTION_BYTES`, another run file such as a checkpoint's
    ``state.json`` at most :data:`~swarm_env_baselines.model_bounds.MAX_STATE_BYTES`), nested too deep, not strict
    JSON (truncated, corrupt), or another format (then it says which spec loads that one)."""
    if not path.parent.is_dir():
        raise ValueError(f"{mb.shown(path.parent)}: no such directory (a saved policy directory holds {path.name} "
                         f"and {WEIGHTS_FILE})")
    limit = mb.MAX_DESCRIPTION_BYTES if path.name == CONFIG_FILE else mb.MAX_STATE_BYTES
    try:
        config = mb.read_json(path, limit, "policy description" if path.name == CONFIG_FILE else "run file")
    except FileNotFoundError:
        raise ValueError(f"{mb.shown(path)}: missing (a saved policy directory holds {path.name} and "
                         f"{WEIGHTS_FILE})") from None
    got = config.get("format") if isinstance(config, dict) else config
    if got != fmt:
        hint = LOADERS.get(got) if isinstance(got, str) else None
        raise ValueError(f"{mb.shown(path)}: format: expected {fmt!r}, got {clip_repr(got)}"
                         + (f" (load it with {hint})" if hint else ""))
    return config


#: The ``policy_kwargs`` a description may pass to SB3's policy class, and what each must be.
_BOOL_KWARGS = ("ortho_init", "use_sde", "full_std", "use_expln", "squash_output", "share_features_extractor",
                "normalize_images")
_NUMBER_KWARGS = {"log_std_init": (-20.0, 20.0), "clip_mean": (0.0, MAX_ABS_NUMBER)}
#: Most critics of an off-policy SB3 policy (``n_critics``).
MAX_CRITICS = 8
#: The discrete action space of the env (:meth:`swarm_env.env.SwarmEnv.action_space`): stop and the primitives.
DISCRETE_ACTIONS = 1 + len(PRIMITIVE_ANGLES_DEG)


def check_description(config: dict[str, Any]) -> None:
    """Check an SB3 policy description (:data:`FORMAT`) before anything is built from it: the algorithm, an
    observation space of at most :data:`~swarm_env_baselines.model_bounds.MAX_OBSERVATION` float values with finite
    bounds, the env's action space (a twist, or its :data:`DISCRETE_ACTIONS` primitives), known ``policy_kwargs``
    of the right types, layer widths and a parameter count in bounds, and the normalisation statistics. Raises
    ``ValueError`` naming the key and what it must be."""
    algo = mb.get(config, "algo", "")
    if not isinstance(algo, str) or algo.lower() not in _ALGORITHMS:
        raise ValueError(f"algo: expected one of {', '.join(_ALGORITHMS)}, got {clip_repr(algo)}")
    n_obs = _check_box(mb.get(config, "observation_space", ""), "observation_space", None)
    act = mb.json_object(mb.get(config, "action_space", ""), "action_space")
    if act.get("type") == "Discrete":
        mb.integer(mb.get(act, "n", "action_space"), "action_space.n", DISCRETE_ACTIONS, DISCRETE_ACTIONS)
        mb.integer(act.get("start", 0), "action_space.start", 0, 0)
        n_act = DISCRETE_ACTIONS
    else:
        n_act = _check_box(act, "action_space", mb.ACTION_SIZE)
    kwargs = mb.json_object(mb.get(config, "policy_kwargs", ""), "policy_kwargs")
    for key, value in kwargs.items():
        where = f"policy_kwargs.{key}"
        if key in _BOOL_KWARGS:
            if not isinstance(value, bool):
                raise ValueError(f"{where}: expected true or false, got {clip_repr(value)}")
        elif key in _NUMBER_KWARGS:
            mb.number(value, where, *_NUMBER_KWARGS[key])
        elif key not in ("net_arch", "n_critics"):
            raise ValueError(f"policy_kwargs.{printable(str(key), 80)}: not a key this version rebuilds; "
                             f"expected some of net_arch, n_critics, {', '.join(_BOOL_KWARGS)}, "
                             f"{', '.join(_NUMBER_KWARGS)}")
    critics = mb.integer(kwargs.get("n_critics", 2), "policy_kwargs.n_critics", 1, MAX_CRITICS)
    arch = kwargs.get("net_arch", [])
    if isinstance(arch, dict):
        unknown = sorted(set(arch) - {"pi", "vf", "qf"})
        if unknown:
            raise ValueError(f"policy_kwargs.net_arch: expected the keys pi, vf, qf, got {clip_repr(unknown)}")
        nets = {k: mb.widths(arch.get(k, []), f"policy_kwargs.net_arch.{k}", 0) for k in ("pi", "vf", "qf")}
    else:
        shared = mb.widths(arch, "policy_kwargs.net_arch", 0)
        nets = {"pi": shared, "vf": shared, "qf": shared}
    # At least the parameters of the networks SB3 builds from it (outputs rounded up to two per action): on-policy,
    # the actor and the value network; off-policy, the actor and the critics, each with its target copy.
    actor = mb.mlp_parameters([n_obs, *nets["pi"], 2 * n_act])
    if algo.lower() in _ON_POLICY:
        count = actor + mb.mlp_parameters([n_obs, *nets["vf"], 1])
    else:
        count = 2 * actor + 2 * critics * mb.mlp_parameters([n_obs + n_act, *nets["qf"], 1])
    mb.check_parameters(count, "policy_kwargs.net_arch", "the policy")
    norm = config.get("normalization")
    if norm is not None:
        _check_normalization(norm, n_obs)


_ALGORITHMS = ("ppo", "bc", "sac", "a2c", "td3", "ddpg")
_ON_POLICY = ("ppo", "bc", "a2c")


def _check_box(space: Any, where: str, size: int | None) -> int:
    """Check a Box space's JSON (1-D, float32/float64, finite bounds with low <= high; ``size`` values when given,
    else at most MAX_OBSERVATION); return its size."""
    mb.json_object(space, where)
    kind = mb.get(space, "type", where)
    if kind != "Box":
        expected = "'Box' or 'Discrete'" if size is not None else "'Box'"
        raise ValueError(f"{where}.type: expected {expected}, got {clip_repr(kind)}")
    dtype = mb.get(space, "dtype", where)
    if dtype not in ("float32", "float64"):
        raise ValueError(f"{where}.dtype: expected 'float32' or 'float64', got {clip_repr(dtype)}")
    high_size = mb.MAX_OBSERVATION if size is None else size
    shape = mb.get(space, "shape", where)
    if not isinstance(shape, list) or len(shape) != 1:
        raise ValueError(f"{where}.shape: expected [n], one size, got {clip_repr(shape)}")
    n = mb.integer(shape[0], f"{where}.shape[0]", size or 1, high_size)
    low = mb.vector(mb.get(space, "low", where), f"{where}.low", n, n)
    high = mb.vector(mb.get(space, "high", where), f"{where}.high", n, n)
    if not (low <= high).all():
        raise ValueError(f"{where}: expected low <= high, got low {clip_repr(low.tolist())}, high "
                         f"{clip_repr(high.tolist())}")
    return n


def _check_normalization(d: Any, n_obs: int | None) -> None:
    """Check the ``normalization`` block (SB3's VecNormalize statistics as JSON) for observations of ``n_obs``."""
    mb.json_object(d, "normalization")
    norm_obs = d.get("norm_obs", True)
    if not isinstance(norm_obs, bool):
        raise ValueError(f"normalization.norm_obs: expected true or false, got {clip_repr(norm_obs)}")
    mb.statistics(d, "normalization", n_obs, mb.MAX_OBSERVATION, clip_key="clip_obs")
    ret = d.get("returns")
    if ret is not None:
        mb.json_object(ret, "normalization.returns")
        mb.number(mb.get(ret, "mean", "normalization.returns"), "normalization.returns.mean")
        mb.number(mb.get(ret, "var", "normalization.returns"), "normalization.returns.var", 0.0)
        mb.number(mb.get(ret, "count", "normalization.returns"), "normalization.returns.count", 0.0)



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
