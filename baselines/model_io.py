"""Saved SB3 models as swarm_env policies: the ``ppo:PATH``, ``sac:PATH`` and ``bc:PATH`` entry points.

A saved model is a directory holding::

    policy.safetensors + policy.json   the policy network, its observation and return statistics,
                                       as tensors and JSON (swarm_env_baselines.safe_io): loading cannot run code
    model.zip          the SB3 model (``model.save``), for SB3's own tools and for resuming training
    vecnormalize.pkl   the VecNormalize object the model was trained with (SB3's format)

``model.zip`` keeps parts of the model as cloudpickle blobs and ``vecnormalize.pkl`` is a pickle:
unpickling either runs whatever code the file carries. So everything swarm_env reads by default
comes from the safe pair: a policy spec loads it (``PATH`` may be the directory or its
``model.zip``), and a warm start (:func:`load_warm_start`) takes the network's tensors and the
statistics from it, or, for an older directory without it, the tensors from ``model.zip``'s
``policy.pth`` (read by torch with ``weights_only=True``: data only). What must unpickle, an older
directory as a policy, its ``vecnormalize.pkl``, and :func:`load_model` (the whole SB3 model), is
refused with a :class:`~swarm_env.harness.policies.ModelFileError` unless the caller opts in
(:func:`swarm_env.harness.policies.pickle_trusted`: ``trust_pickle=True``, ``SWARM_ENV_TRUST_PICKLE=1``,
or ``--trust-pickle`` on the command lines). ``swarm-env convert DIR --trust-pickle``
converts such a directory once.

Every file problem (missing, truncated or corrupt, another algorithm's model, a refused pickle, a size or
number outside :mod:`swarm_env_baselines.model_bounds`) is a ``ModelFileError`` with one line naming the file;
the CLI exits with code 2 on it.
:class:`SB3Policy` feeds each follower's observation through the same normalisation, then
``model.predict`` on the stacked batch (parameter sharing), deterministic by default. ``bc``
models are PPO-format checkpoints whose policy network was trained by behaviour cloning (see
:mod:`swarm_env_baselines.bc`).

Every spec needs a path: the v0 checkpoints that ``ppo`` and ``bc`` once loaded without one
were retired in issue 10 (trained on swarm_env_v0 from an uncommitted tree; superseded by the
shipped methods of :mod:`swarm_env_baselines.mappo_policy`), and a bare name says so.
"""

from __future__ import annotations

import json
import pickle
import zipfile
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from swarm_env.harness.policies import OBSERVATIONS, ModelFileError, PolicyError
from swarm_env.limits import printable
from swarm_env.state import WorldState
from swarm_env_baselines.mappo_policy import SHIPPED_SEEDS, shipped_run
from swarm_env_baselines.model_bounds import shown
from swarm_env_baselines.safe_io import (
    CONFIG_FILE,
    WEIGHTS_FILE,
    algorithm_class,
    check_description,
    has_safe_policy,
    load_policy_dir,
    one_line,
    read_description,
    read_tensors,
    refuse_pickle,
    save_policy,
    saved_statistics,
)
from swarm_env_baselines.safe_io import FORMAT as SAFE_FORMAT

if TYPE_CHECKING:
    from stable_baselines3.common.base_class import BaseAlgorithm
    from stable_baselines3.common.vec_env import VecNormalize

    from swarm_env.env import SwarmEnv

MODEL_FILE = "model.zip"
VECNORM_FILE = "vecnormalize.pkl"
#: What a bare ``ppo`` / ``bc`` says since their v0 checkpoints were retired.
RETIRED = ("the v0 checkpoint that {algo!r} loaded without a path was retired (trained on swarm_env_v0 from an "
           "uncommitted tree); give a run directory, {algo}:PATH, or use a shipped method: ippo, mappo, "
           "mappo_shielded, residual_vo, sb3_ppo (docs/baselines.md)")


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



def same_family(a: str, b: str) -> bool:
    """Whether algorithms ``a`` and ``b`` save the same kind of network (``bc`` checkpoints are PPO's)."""
    return algorithm_class(a) is algorithm_class(b)


def resolve_model_path(path: str | Path) -> Path:
    """``path`` itself if it is a file, else ``path/model.zip``; raises ``FileNotFoundError`` naming both."""
    p = Path(path).expanduser()
    if p.is_dir():
        p = p / MODEL_FILE
    if not p.is_file():
        raise FileNotFoundError(f"no saved model at {path!s} (expected a run directory with policy.safetensors + "
                                f"policy.json, or with {MODEL_FILE}, or a .zip file)")
    return p


#: Bounds of a legacy SB3 ``model.zip`` (what SB3 writes: ``data``, a few ``.pth`` members and a version file),
#: checked on the sizes the archive declares before any member is inflated.
MAX_SB3_MEMBERS = 64
MAX_SB3_DATA_BYTES = 16 << 20
MAX_SB3_MEMBER_BYTES = 256 << 20


def check_sb3_zip(path: Path, algo: str) -> dict[str, Any]:
    """The plain JSON fields of the SB3 archive ``path`` (its cloudpickled ``:serialized:`` fields
    left as they are, never decoded), after checking, without unpickling anything, that it is a whole
    zip archive (every member's CRC) holding SB3's ``data`` and was saved by ``algo``'s family
    (its policy class's module, which SB3 writes in plain text). Raises :class:`ModelFileError`.
    """
    try:
        with zipfile.ZipFile(path) as archive:
            # sizes as the archive declares them (zipfile never reads a member past its declared size): a zip bomb
            # is refused before testzip() would inflate it
            members = archive.infolist()
            big = next((m for m in members if m.file_size > (MAX_SB3_DATA_BYTES if m.filename == "data"
                                                             else MAX_SB3_MEMBER_BYTES)), None)
            if big is not None or len(members) > MAX_SB3_MEMBERS:
                what = (f"member {printable(big.filename, 80)} inflates to {big.file_size:,} bytes" if big is not None
                        else f"{len(members):,} members")
                raise ModelFileError(f"{path}: not a stable-baselines3 model archive within bounds ({what}; at most "
                                     f"{MAX_SB3_MEMBERS} members, 'data' {MAX_SB3_DATA_BYTES:,} bytes, the others "
                                     f"{MAX_SB3_MEMBER_BYTES:,})")
            broken = archive.testzip()
            if broken is not None:
                raise zipfile.BadZipFile(f"member {broken} fails its CRC check")
            if "data" not in archive.namelist():  # a truncated model.zip can even read as one of its inner torch archives
                raise ModelFileError(f"{path}: not a readable stable-baselines3 model archive, truncated or corrupt, "
                                     f"or not SB3's (no 'data' member)")
            data = json.loads(archive.read("data").decode())
    except ModelFileError:
        raise
    except (zipfile.BadZipFile, OSError, EOFError, ValueError) as exc:  # zlib errors and bad JSON are ValueErrors

        raise ModelFileError(f"{path}: not a readable stable-baselines3 model archive, truncated or corrupt "
                             f"({one_line(exc)})") from None
    if not isinstance(data, dict):
        raise ModelFileError(f"{path}: not a stable-baselines3 model (its 'data' member is not a JSON object)")
    module = data.get("policy_class", {}).get("__module__") if isinstance(data.get("policy_class"), dict) else None
    want = algorithm_class(algo).policy_aliases["MlpPolicy"].__module__
    if isinstance(module, str) and module.startswith("stable_baselines3.") and module != want:
        owners = [n for n in ("ppo", "a2c", "sac", "td3") if algorithm_class(n).policy_aliases["MlpPolicy"].__module__ == module]
        kind = f"a {'/'.join(owners)} model" if owners else "another algorithm's model"
        raise ModelFileError(f"{path}: holds {kind} (its policy is from {module}), not a {algo} one")
    return data


def load_vecnormalize(path: Path, *, trust_pickle: bool | None = None) -> VecNormalize:
    """The pickled ``VecNormalize`` in ``path`` (without its venv: ``normalize_obs`` still works), in
    evaluation mode. Refused unless pickles are trusted (:func:`~swarm_env.harness.policies.pickle_trusted`);
    a :class:`ModelFileError` naming the file if it is not a readable VecNormalize pickle."""
    from stable_baselines3.common.vec_env import VecNormalize


    refuse_pickle(path, "a Python pickle (VecNormalize statistics)", trust_pickle)
    try:
        with open(path, "rb") as fh:
            vecnorm = pickle.load(fh)
    except Exception as exc:  # noqa: BLE001 - a bad pickle raises anything (UnpicklingError, EOFError, ImportError, ...)
        raise ModelFileError(f"{path}: not a readable VecNormalize pickle, truncated or corrupt "
                             f"({type(exc).__name__}: {one_line(exc)})") from None
    if not isinstance(vecnorm, VecNormalize):
        raise ModelFileError(f"{path}: holds a {type(vecnorm).__name__}, not SB3's VecNormalize statistics")
    vecnorm.training = False
    return vecnorm


def save_model(model: BaseAlgorithm, directory: str | Path, vecnorm: VecNormalize | None = None) -> Path:
    """Write the policy and its statistics as tensors + JSON (:func:`swarm_env_baselines.safe_io.save_policy`), and
    ``model.zip`` (and ``vecnormalize.pkl`` if given) for SB3's tools and resuming, into ``directory``;
    returns the directory."""
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    model.save(out / MODEL_FILE)
    if vecnorm is not None:
        vecnorm.save(str(out / VECNORM_FILE))
    save_policy(model, out, type(model).__name__.lower(), vecnorm)
    return out


def load_model(path: str | Path, algo: str = "ppo", *, trust_pickle: bool | None = None
               ) -> tuple[BaseAlgorithm, VecNormalize | None]:
    """The whole SB3 model in ``path`` (a ``.zip`` or a directory with ``model.zip``; on CPU) and the
    VecNormalize statistics saved beside it (or ``None``).

    Both unpickle, so both are refused unless pickles are trusted
    (:func:`~swarm_env.harness.policies.pickle_trusted`: ``trust_pickle`` or ``SWARM_ENV_TRUST_PICKLE``).
    Raises ``FileNotFoundError`` for a missing model and :class:`ModelFileError` (one line naming
    the file) for a refused, truncated, corrupt or other-algorithm file; a corrupt archive or another
    algorithm is reported before anything is unpickled.
    """
    model_path = resolve_model_path(path)
    check_sb3_zip(model_path, algo)
    stats = model_path.parent / VECNORM_FILE
    refuse_pickle(model_path, "the cloudpickled parts of an SB3 model" + (f" (and {VECNORM_FILE} beside it)"
                   if stats.is_file() else ""), trust_pickle)
    cls = algorithm_class(algo)
    try:
        model = cls.load(model_path, device="cpu")
    except Exception as exc:  # noqa: BLE001 - SB3 fails on a bad file with any type (AssertionError, KeyError, ...)
        raise ModelFileError(f"{model_path}: stable-baselines3 could not load it as a {algo} model "
                             f"({type(exc).__name__}: {one_line(exc)})") from None
    if not isinstance(model.policy, cls.policy_aliases["MlpPolicy"]):
        raise ModelFileError(f"{model_path}: holds a {type(model.policy).__name__}, not a {algo} policy")
    vecnorm = load_vecnormalize(stats, trust_pickle=True) if stats.is_file() else None  # trust checked above
    return model, vecnorm


def load_warm_start(path: str | Path, algo: str, *, trust_pickle: bool | None = None
                    ) -> tuple[dict[str, Any], Any, Any]:
    """What a warm start copies from a saved model: ``(policy state dict, observation statistics,
    return statistics)``, the statistics as SB3 ``RunningMeanStd`` objects or ``None``.

    From ``policy.safetensors`` + ``policy.json`` when the directory has them (no pickle); else the
    tensors of ``model.zip``'s ``policy.pth`` (torch's ``weights_only`` reader: no code) and, if
    there is a ``vecnormalize.pkl``, its statistics (a pickle: refused unless trusted). Raises
    ``FileNotFoundError`` or :class:`ModelFileError` naming the file.
    """
    p = Path(path).expanduser()
    d = p if p.is_dir() else p.parent
    if has_safe_policy(d) and (p.is_dir() or p.name == MODEL_FILE):
        try:
            description = read_description(d / CONFIG_FILE, SAFE_FORMAT)
            try:
                check_description(description)
            except ValueError as exc:
                raise ValueError(f"{shown(d / CONFIG_FILE)}: not a policy description this version can rebuild "
                                 f"({one_line(exc)})") from None
            saved = str(description["algo"])
            if not same_family(saved, algo):
                raise ValueError(f"{d / CONFIG_FILE}: holds a {saved} policy, not a {algo} one")
            weights = read_tensors(d / WEIGHTS_FILE)
            obs_rms, ret_rms = saved_statistics(d)
        except ValueError as exc:
            raise ModelFileError(str(exc)) from None
        return weights, obs_rms, ret_rms
    model_path = resolve_model_path(path)
    check_sb3_zip(model_path, algo)
    from stable_baselines3.common.save_util import load_from_zip_file

    try:
        _, params, _ = load_from_zip_file(model_path, load_data=False, device="cpu")  # tensors only, weights_only=True
        weights = params["policy"]
    except Exception as exc:  # noqa: BLE001 - torch's safe reader refuses anything but tensors, with several types
        raise ModelFileError(f"{model_path}: no readable policy tensors (policy.pth) in it ({one_line(exc)})") from None
    stats = model_path.parent / VECNORM_FILE
    if not stats.is_file():
        return weights, None, None
    vecnorm = load_vecnormalize(stats, trust_pickle=trust_pickle)
    return weights, vecnorm.obs_rms, vecnorm.ret_rms


class SB3Policy:
    """A trained SB3 model controlling every follower with one shared network.

    Args:
        model: anything with SB3's ``predict``.
        vecnorm: the ``VecNormalize`` statistics to apply to observations (or ``None``).
        deterministic: act on the mean / most likely action (default) or sample.
        name: for error messages.
    """

    def __init__(self, model: Any, vecnorm: VecNormalize | None = None, *, deterministic: bool = True, name: str = "model") -> None:
        self.model = model
        self.vecnorm = vecnorm
        self.deterministic = deterministic
        self.name = name

    def reset(self, env: SwarmEnv, seed: int | None) -> None:
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


def _make(algo: str, env: SwarmEnv, arg: str | None) -> SB3Policy:
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

    where = Path(path).expanduser()
    # The directory, or the directory of its model.zip: save_model wrote the safe pair from the same model.
    safe_dir = where if where.is_dir() else where.parent if where.name == MODEL_FILE else None
    model: Any
    if safe_dir is not None and has_safe_policy(safe_dir):  # tensors + JSON: nothing to unpickle
        try:
            model, vecnorm, saved_algo = load_policy_dir(safe_dir)
        except ValueError as exc:
            raise ModelFileError(f"policy {algo}:{path}: {exc}") from None
        if not same_family(saved_algo, algo):
            raise ModelFileError(f"policy {algo}:{path}: {safe_dir} holds a {saved_algo} policy; load it as {saved_algo}:{path}")
    else:
        half = [f for f in (WEIGHTS_FILE, CONFIG_FILE) if safe_dir is not None and (safe_dir / f).is_file()]
        if half:
            missing = CONFIG_FILE if half == [WEIGHTS_FILE] else WEIGHTS_FILE
            raise ModelFileError(f"policy {algo}:{path}: {safe_dir} has {half[0]} but not {missing}")
        try:
            model, vecnorm = load_model(path, algo)
        except FileNotFoundError as exc:
            raise ModelFileError(f"policy {algo}:{path}: {exc}") from None
        except ModelFileError as exc:
            raise ModelFileError(f"policy {algo}:{path}: {exc}") from None
    policy = SB3Policy(model, vecnorm, name=f"{algo}:{path}")
    policy.reset(env, None)  # shape checks now, so a mismatch is reported before any episode runs
    return policy


def make_ppo_policy(env: SwarmEnv, arg: str | None = None) -> SB3Policy:
    """Entry point ``ppo:PATH``: a PPO model saved by ``swarm-env train sb3``."""
    return _make("ppo", env, arg)


def make_bc_policy(env: SwarmEnv, arg: str | None = None) -> SB3Policy:
    """Entry point ``bc:PATH``: a behaviour-cloned policy saved by ``swarm-env bc``."""
    return _make("bc", env, arg)


def make_sac_policy(env: SwarmEnv, arg: str | None = None) -> SB3Policy:
    """Entry point ``sac:PATH``: a SAC model."""
    return _make("sac", env, arg)


def make_sb3_ppo(env: SwarmEnv, arg: str | None = None) -> SB3Policy:
    """Entry point ``sb3_ppo[:s<k>|:PATH]``: the shipped SB3 PPO runs (``baselines/checkpoints/sb3_ppo/s<k>``,
    trained by ``swarm-env train sb3`` through the SB3 bridge), the first training seed without an argument,
    or any SB3 run directory; a leaderboard plays all three seeds."""
    run = shipped_run("sb3_ppo", arg or SHIPPED_SEEDS[0]) if arg in (None, *SHIPPED_SEEDS) else Path(arg)
    policy = _make("ppo", env, str(run))
    policy.name = "sb3_ppo" if arg is None else f"sb3_ppo:{arg}"
    return policy


make_sb3_ppo.training_runs = SHIPPED_SEEDS  # type: ignore[attr-defined]
# What the leaderboard's "acts on" column says: the networks read each follower's own observation.
make_sb3_ppo.acts_on = OBSERVATIONS  # type: ignore[attr-defined]
make_ppo_policy.acts_on = OBSERVATIONS  # type: ignore[attr-defined]
make_bc_policy.acts_on = OBSERVATIONS  # type: ignore[attr-defined]
make_sac_policy.acts_on = OBSERVATIONS  # type: ignore[attr-defined]
