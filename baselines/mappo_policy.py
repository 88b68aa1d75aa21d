"""Trained MAPPO/IPPO actors as swarm_env policies, their files, and the shipped checkpoints.

A run directory of :mod:`swarm_env_baselines.mappo` (and each of its ``best/``) holds::

    policy.safetensors   actor, log_std and critic tensors (safetensors: data only)
    policy.json          {"format", "config" (the run's MAPPOConfig), "obs_rms", "state_rms"}

Loading reads those two files and nothing else: no pickle, no code; a missing, truncated or
corrupt file, or another kind of policy's, is a :class:`~swarm_env.harness.policies.ModelFileError`
naming the file (``swarm-env run`` exits with code 2). Every file, size and number is checked against
:mod:`swarm_env_baselines.model_bounds` before anything is built; a residual run's expert may not itself be a
residual run (nor the run itself). The policy acts with the
actor's mean (deterministic), on one torch thread, so an episode is the same bit for bit in
any process (``tests/test_mappo.py`` checks it across processes).

Policy specs (entry points of the ``swarm_env.policies`` group):

* ``ippo``, ``mappo``, ``mappo_shielded``, ``residual_vo`` — the shipped methods
  (``baselines/checkpoints/<method>/s<k>``), each trained with three seeds: the bare name is
  seed 0 for ``swarm-env run`` and all three seeds for a leaderboard
  (:func:`swarm_env.harness.policies.training_runs`), ``NAME:s1`` one seed, ``NAME:PATH`` any run
  directory of :mod:`swarm_env_baselines.mappo` (or its ``best/``; a residual run brings its expert along). ``mappo_shielded`` and ``residual_vo`` execute through the safety layer
  (:class:`swarm_env.harness.policies.ShieldedPolicy`), as they were trained; ``mappo_shielded_bare``
  is ``mappo_shielded``'s networks acting alone.
"""

from __future__ import annotations

import contextvars
import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from swarm_env.harness.policies import (
    OBSERVATIONS,
    STATE,
    ModelFileError,
    PolicyArgumentError,
    PolicyError,
    ShieldedPolicy,
    UnknownPolicyError,
    load_policy,
)
from swarm_env.jsonio import write_json
from swarm_env.limits import clip_repr, printable
from swarm_env.state import WorldState
from swarm_env_baselines import model_bounds as mb
from swarm_env_baselines.ppo_core import RunningMeanStd, mlp
from swarm_env_baselines.safe_io import (
    CONFIG_FILE,
    SAC_FORMAT,
    WEIGHTS_FILE,
    _atomic,
    one_line,
    read_description,
    read_tensors,
)
from swarm_env_baselines.safe_io import MAPPO_FORMAT as FORMAT

#: Where the shipped runs live: ``CHECKPOINTS / <method> / s<k>``.
CHECKPOINTS = Path(__file__).resolve().parent / "checkpoints"
#: The training seeds shipped for every method.
SHIPPED_SEEDS = ("s0", "s1", "s2")

__all__ = ["MAPPOPolicy", "ResidualPolicy", "SquashedMeanActor", "load_run_policy", "load_sac_policy", "save_run_policy",
           "shipped_run", "shipped_method_entry_point"]


class MAPPOPolicy:
    """A trained actor controlling every follower with its Gaussian's mean (deterministic)."""

    def __init__(self, actor: Any, obs_rms: RunningMeanStd, name: str = "mappo") -> None:
        self.actor = actor
        self.obs_rms = obs_rms
        self.name = name

    def reset(self, env: Any, seed: int | None) -> None:
        base = env.unwrapped
        have = base.observation_space(base.possible_agents[0]).shape[0] + self.extra_inputs
        want = self.obs_rms.mean.shape[0]
        if want != have:
            raise PolicyError(f"{self.name} was trained on inputs of size {want}, this env gives {have}")
        if base.action_type != "continuous":
            raise PolicyError(f"{self.name} acts in the continuous action space; this env is {base.action_type!r}")

    #: Inputs the actor reads beyond the observation (a residual actor also reads its expert's action).
    extra_inputs = 0

    def mean_actions(self, inputs: np.ndarray) -> np.ndarray:
        """The actor's mean for a batch of raw (unnormalised) inputs, clipped to ``[-1, 1]``."""
        import torch

        with torch.no_grad():
            mean = self.actor(torch.as_tensor(self.obs_rms.normalize(inputs))).numpy()
        return np.clip(mean, -1.0, 1.0)

    def act(self, observations: dict[str, np.ndarray], state: WorldState) -> dict[str, Any]:
        agents = list(observations)
        if not agents:
            return {}
        action = self.mean_actions(np.stack([observations[a] for a in agents])).astype(np.float32)
        return {a: action[i] for i, a in enumerate(agents)}


class ResidualPolicy(MAPPOPolicy):
    """``clip(expert action + scale * actor mean)``: a bounded learned correction of an expert.

    The actor reads the observation and the expert's action; the expert (e.g. ``vo``) reads the
    privileged world state, so this policy is privileged at execution like the expert.
    """

    extra_inputs = 2

    def __init__(self, actor: Any, obs_rms: RunningMeanStd, expert: Any, scale: float, name: str = "residual") -> None:
        super().__init__(actor, obs_rms, name)
        self.expert = expert
        self.scale = float(scale)

    def reset(self, env: Any, seed: int | None) -> None:
        super().reset(env, seed)
        self.expert.reset(env, seed)

    def act(self, observations: dict[str, np.ndarray], state: WorldState) -> dict[str, Any]:
        agents = list(observations)
        if not agents:
            return {}
        base_actions = self.expert.act(observations, state)
        base = np.stack([np.asarray(base_actions[a], dtype=np.float32) for a in agents])
        inputs = np.concatenate([np.stack([observations[a] for a in agents]), base], axis=1)
        action = residual_action(base, self.mean_actions(inputs), self.scale).astype(np.float32)
        return {a: action[i] for i, a in enumerate(agents)}


class SquashedMeanActor:
    """A SAC actor (outputs ``(mean, log std)`` of a pre-tanh Gaussian) as the deterministic map
    ``tanh(mean)`` that :class:`MAPPOPolicy` plays."""

    def __init__(self, net: Any) -> None:
        self.net = net

    def __call__(self, x: Any) -> Any:
        import torch

        return torch.tanh(self.net(x)[..., :2])


def residual_action(base: np.ndarray, residual: np.ndarray, scale: float) -> np.ndarray:
    """The executed action of a residual policy: ``clip(base + scale * clip(residual, -1, 1), -1, 1)``."""
    return np.clip(base + scale * np.clip(residual, -1.0, 1.0), -1.0, 1.0)


# --------------------------------------------------------------------------- files


def save_run_policy(directory: Path, actor: Any, log_std: Any, critic: Any, obs_rms: RunningMeanStd,
                    state_rms: RunningMeanStd, config: Any) -> Path:
    """Write ``policy.safetensors`` (actor, log_std, critic) and ``policy.json`` into ``directory``, atomically."""
    from safetensors.torch import save_file


    directory.mkdir(parents=True, exist_ok=True)
    tensors = {f"actor.{k}": v.detach().cpu().contiguous() for k, v in actor.state_dict().items()}
    tensors.update({f"critic.{k}": v.detach().cpu().contiguous() for k, v in critic.state_dict().items()})
    tensors["log_std"] = log_std.detach().cpu().contiguous()
    meta = {"format": FORMAT, "config": dataclasses.asdict(config), "obs_rms": obs_rms.to_json(),
            "state_rms": state_rms.to_json()}
    with _atomic(directory / WEIGHTS_FILE) as tmp:
        save_file(tensors, str(tmp))
    with _atomic(directory / CONFIG_FILE) as tmp:
        write_json(tmp, meta, indent=None)
    return directory


def read_run(directory: str | Path) -> tuple[dict[str, Any], Any, RunningMeanStd]:
    """``(config dict, actor module, observation statistics)`` of a saved run directory.

    Raises ``ValueError`` (one line naming the file) for a missing or bad file.
    """
    import torch


    d = Path(directory).expanduser()
    meta = read_description(d / CONFIG_FILE, FORMAT)
    try:
        config = dict(mb.json_object(mb.get(meta, "config", ""), "config"))
        hidden = mb.widths(mb.get(config, "hidden", "config"), "config.hidden")
        residual = config.get("residual")
        if residual is not None and residual != "":
            mb.spec(residual, "config.residual")
            mb.number(mb.get(config, "residual_scale", "config"), "config.residual_scale", 0.0)  # as MAPPOConfig
        # A residual actor reads the observation and its expert's action; a plain one the observation only.
        inputs = mb.statistics(mb.get(meta, "obs_rms", ""), "obs_rms", max_len=mb.MAX_INPUTS if residual else
                               mb.MAX_OBSERVATION)
        mb.check_parameters(mb.mlp_parameters([inputs, *hidden, mb.ACTION_SIZE]), "config.hidden", "the actor")
        obs_rms = RunningMeanStd.from_json(meta["obs_rms"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{mb.shown(d / CONFIG_FILE)}: not a run description of swarm_env_baselines.mappo "
                         f"({one_line(exc)})") from None
    actor = _load_actor(d, mlp([obs_rms.mean.shape[0], *hidden, 2]))
    torch.set_num_threads(1)  # a small MLP on a few observations: threads only add overhead (and float noise)
    return config, actor, obs_rms


def _load_actor(d: Path, net: Any) -> Any:
    """``net`` with the ``actor.*`` tensors of ``d/policy.safetensors``, in eval mode; ``ValueError`` naming the
    file if they do not fit it (missing or unexpected keys, shapes)."""
    tensors = read_tensors(d / WEIGHTS_FILE)  # finite, bounded values only (model_bounds.read_safetensors)
    try:
        net.load_state_dict({k[len("actor."):]: v for k, v in tensors.items() if k.startswith("actor.")}, strict=True)
    except (RuntimeError, ValueError) as exc:  # missing/unexpected keys, shape mismatches
        raise ValueError(f"{mb.shown(d / WEIGHTS_FILE)}: the tensors do not fit the actor of {CONFIG_FILE} "
                         f"({one_line(exc)})") from None
    return net.eval()


def load_sac_policy(directory: str | Path, name: str | None = None) -> MAPPOPolicy:
    """The actor of a saved :mod:`swarm_env_baselines.sac` run (``policy.json`` of format :data:`SAC_FORMAT`)
    as a deterministic policy. Raises ``ValueError`` naming the file for a missing or bad file."""
    import torch


    d = Path(directory).expanduser()
    meta = read_description(d / CONFIG_FILE, SAC_FORMAT)
    try:
        config = mb.json_object(mb.get(meta, "config", ""), "config")
        hidden = mb.widths(mb.get(config, "hidden", "config"), "config.hidden")
        inputs = mb.statistics(mb.get(meta, "obs_rms", ""), "obs_rms", max_len=mb.MAX_OBSERVATION)
        mb.check_parameters(mb.mlp_parameters([inputs, *hidden, 2 * mb.ACTION_SIZE]), "config.hidden", "the actor")
        obs_rms = RunningMeanStd.from_json(meta["obs_rms"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{mb.shown(d / CONFIG_FILE)}: not a run description of swarm_env_baselines.sac "
                         f"({one_line(exc)})") from None
    net = _load_actor(d, mlp([obs_rms.mean.shape[0], *hidden, 4]))
    if not all(torch.isfinite(p).all() for p in net.parameters()):
        raise ValueError(f"{mb.shown(d / WEIGHTS_FILE)}: the actor's tensors are not all finite")
    torch.set_num_threads(1)
    return MAPPOPolicy(SquashedMeanActor(net), obs_rms, name=name or f"isac:{directory}")


def directory_entry_point(label: str, loader: Callable[..., MAPPOPolicy], usage: str, doc: str
                          ) -> Callable[..., MAPPOPolicy]:
    """A policy entry point ``label:DIR`` for a run directory that ``loader(DIR, name=...)`` reads: no ``DIR``
    is a :class:`PolicyError` saying ``usage``, a file ``loader`` refuses (``ValueError``) a :class:`ModelFileError`
    naming the spec; the policy acts on observations only."""

    def factory(env: Any, arg: str | None = None) -> MAPPOPolicy:
        if not arg:
            raise PolicyError(usage)
        try:
            policy = loader(arg, name=f"{label}:{arg}")
        except ValueError as exc:
            raise ModelFileError(f"policy {label}:{arg}: {exc}") from None
        policy.reset(env, None)
        return policy

    factory.acts_on = OBSERVATIONS  # type: ignore[attr-defined]
    factory.__name__ = factory.__qualname__ = f"make_{label}"
    factory.__doc__ = doc
    return factory


make_isac = directory_entry_point(
    "isac", load_sac_policy, "isac needs a run directory: isac:runs/<run> (or isac:runs/<run>/best)",
    "Entry point ``isac:PATH``: a shared-parameter SAC run directory of :mod:`swarm_env_baselines.sac` (or its "
    "``best/``), playing ``tanh`` of its actor's mean.")


def load_run_policy(directory: str | Path, env: Any | None = None, name: str | None = None) -> MAPPOPolicy:
    """The actor of a saved run as a policy (a :class:`ResidualPolicy` for a residual run, whose
    expert is built for ``env``). No pickle involved."""
    config, actor, obs_rms = read_run(directory)
    return _policy_of_run(config, actor, obs_rms, env, name or f"mappo:{directory}",
                          Path(directory).expanduser() / CONFIG_FILE)


#: The description of the residual run whose expert is being built, while it is (a residual chain is refused).
_BUILDING_EXPERT_OF: contextvars.ContextVar[Path | None] = contextvars.ContextVar("_BUILDING_EXPERT_OF", default=None)


class _ExpertIsResidual(ModelFileError):
    """A residual run loaded while another one builds its expert; that one catches it and names its own file."""

    def __init__(self, source: Path, message: str) -> None:
        super().__init__(message)
        self.source = source


def _policy_of_run(config: dict[str, Any], actor: Any, obs_rms: RunningMeanStd, env: Any | None, label: str,
                   source: Path) -> MAPPOPolicy:
    expert_spec = config.get("residual")
    if expert_spec:
        outer = _BUILDING_EXPERT_OF.get()
        if outer is not None:  # this residual run is the expert of another one (or of itself): the outer one reports it
            raise _ExpertIsResidual(source, f"policy {printable(label, 200)}: {mb.shown(source)}: a residual run, "
                                            f"loaded as the expert of the residual run {mb.shown(outer)}")
        if env is None:
            raise ValueError(f"{label}: a residual run needs the env to build its expert {clip_repr(expert_spec)}")
        token = _BUILDING_EXPERT_OF.set(source)
        try:
            expert = load_policy(expert_spec, env)
        except _ExpertIsResidual as exc:
            raise ModelFileError(
                f"policy {printable(label, 200)}: {mb.shown(source)}: config.residual: expected the spec of an expert "
                f"that is not itself a residual run, got {clip_repr(expert_spec)}, which loads the residual run "
                f"{mb.shown(exc.source)} (a chain of residual runs, or one that is its own expert, is refused)"
            ) from None
        except PolicyArgumentError as exc:  # the spec is wrong whatever the env: the file is bad, not a misfit
            raise ModelFileError(f"policy {printable(label, 200)}: {mb.shown(source)}: config.residual: {exc}"
                                 ) from None
        finally:
            _BUILDING_EXPERT_OF.reset(token)
        return ResidualPolicy(actor, obs_rms, expert, float(config["residual_scale"]), name=label)
    return MAPPOPolicy(actor, obs_rms, name=label)


# --------------------------------------------------------------------------- entry points


def _load(env: Any, path: str | Path, name: str) -> MAPPOPolicy:
    try:
        config, actor, obs_rms = read_run(path)
    except ValueError as exc:
        raise ModelFileError(f"policy {name}: {exc}") from None
    try:
        policy = _policy_of_run(config, actor, obs_rms, env, name, Path(path).expanduser() / CONFIG_FILE)
    except UnknownPolicyError as exc:
        raise ModelFileError(f"policy {name}: {mb.shown(Path(path) / CONFIG_FILE)}: its residual expert: "
                             f"{exc.args[0]}") from None
    except PolicyError:
        raise  # the residual's expert refuses the env: a misfit, not a bad file
    except ValueError as exc:
        raise PolicyError(f"policy {name}: {exc}") from None
    policy.reset(env, None)
    return policy


def shipped_run(method: str, seed: str) -> Path:
    """The directory of a shipped run: ``baselines/checkpoints/<method>/<seed>``."""
    return CHECKPOINTS / method / seed


#: ``load(env, run_dir, label) -> policy``: a shipped method's loader (raises ModelFileError on a bad file).
RunLoader = Callable[[Any, Path, str], Any]


def shipped_method_entry_point(method: str, checkpoints: str, load: RunLoader, shielded: bool, doc: str,
                               acts_on: str = OBSERVATIONS) -> Callable[..., Any]:
    """The entry point ``method[:s<k>|:PATH]`` of a shipped learned method: no argument loads the first training
    seed of ``baselines/checkpoints/<checkpoints>/``, ``s<k>`` that seed, anything else a run directory; the
    policy is executed through the safety layer if ``shielded``. ``training_runs`` lets a leaderboard play every
    seed; ``acts_on`` says what it reads."""

    def factory(env: Any, arg: str | None = None) -> Any:
        run = shipped_run(checkpoints, arg or SHIPPED_SEEDS[0]) if arg in (None, *SHIPPED_SEEDS) else Path(str(arg))
        label = method if arg is None else f"{method}:{arg}"
        policy = load(env, run, label)
        return ShieldedPolicy.around(policy) if shielded else policy

    factory.training_runs = SHIPPED_SEEDS  # type: ignore[attr-defined]
    # The shield reads the privileged state: a shielded method acts on more than its observations.
    factory.acts_on = f"{acts_on} + shield" if shielded else acts_on  # type: ignore[attr-defined]
    factory.__name__ = factory.__qualname__ = f"make_{method}"
    factory.__doc__ = doc
    return factory


def _method_factory(method: str, checkpoints: str, shielded: bool, doc: str, acts_on: str = OBSERVATIONS
                    ) -> Callable[..., Any]:
    return shipped_method_entry_point(method, checkpoints, _load, shielded, doc, acts_on)


make_ippo = _method_factory("ippo", "ippo", False, "Entry point ``ippo[:s<k>|:PATH]``: the shipped IPPO runs.")
make_mappo = _method_factory(
    "mappo", "mappo", False,
    "Entry point ``mappo[:s<k>|:PATH]``: the shipped MAPPO runs, or any run directory of swarm_env_baselines.mappo.")
make_mappo_shielded = _method_factory(
    "mappo_shielded", "mappo_shielded", True,
    "Entry point ``mappo_shielded[:s<k>|:PATH]``: the shipped shield-trained MAPPO runs, executed through the shield.")
make_mappo_shielded_bare = _method_factory(
    "mappo_shielded_bare", "mappo_shielded", False,
    "Entry point ``mappo_shielded_bare[:s<k>|:PATH]``: ``mappo_shielded``'s networks acting alone (no shield).")
make_residual_vo = _method_factory(
    "residual_vo", "residual_vo", True,
    "Entry point ``residual_vo[:s<k>|:PATH]``: ``vo`` plus a learned bounded correction, through the shield.",
    acts_on=STATE)
