"""The ``fan_dagger`` policy: a network that picks one of a fan of candidate twists from their times to contact.

The policy acts on each follower's observation only. A fixed sensor (no learned weights) turns the
observation into the *avoidance fan* of :meth:`swarm_env_agents.obs_expert.ObservationExpert.fan`: for each
of ``C`` candidate twists (165 at the defaults: 11 speeds x 15 turn rates), the time until the arc it drives
would touch something the observation shows (neighbour and human rows, lidar hits), and the pure-pursuit
twist towards the slot. The learned part, :func:`fan_net`, scores every candidate; the policy plays the
best-scoring one (deterministic). How the choice is made (which risk to take, when to leave the pursuit
twist, what to do when nothing is safe) is learned, by :mod:`swarm_env_baselines.fan_dagger`.

``FanNet`` (:func:`fan_net`; ``logits = trunk(x) + per_candidate(f_k)``):

* ``x`` = the normalised observation, the fan's times to contact ``min(ttc, horizon) / horizon`` and the
  pursuit twist (normalised) (:func:`fan_inputs`); ``trunk`` an MLP from ``x`` to one logit per candidate;
* ``f_k`` = candidate ``k``'s twist, its time to contact (as above) and its difference from the pursuit twist;
  ``per_candidate`` one small MLP shared by all candidates (the same rule for every candidate: a short time
  to contact scores low wherever in the fan it is).

Files (a run directory of the trainer and each of its ``best/``)::

    policy.safetensors   the network's tensors (safetensors: data only)
    policy.json          {"format": FAN_FORMAT, "config" (the run's FanDaggerConfig), "obs_rms", "fan"}

``fan`` holds the sensor's options (:class:`~swarm_env_agents.obs_expert.ObsExpertConfig` fields) and the
number of candidates. Loading reads those two files and nothing else (no pickle, no code) and checks every
size against bounds; a bad file is a :class:`~swarm_env.harness.policies.ModelFileError` naming it.

Policy specs (entry points of the ``swarm_env.policies`` group): ``fan_dagger`` (the shipped runs,
``baselines/checkpoints/fan_dagger/s<k>``: seed 0 for ``swarm-env run``, all three for a leaderboard),
``fan_dagger:s1`` one seed, ``fan_dagger:PATH`` any run directory (or its ``best/``); ``fan_dagger_shielded``
the same networks executed through the safety layer
(:class:`~swarm_env.harness.policies.ShieldedPolicy`, which reads the privileged state).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from swarm_env.harness.policies import OBSERVATIONS, ModelFileError, PolicyError
from swarm_env.jsonio import write_json
from swarm_env.limits import clip_repr
from swarm_env.state import WorldState
from swarm_env_agents.obs_expert import ObservationExpert, ObsExpertConfig
from swarm_env_baselines import model_bounds as mb
from swarm_env_baselines.mappo_policy import shipped_method_entry_point
from swarm_env_baselines.ppo_core import RunningMeanStd, mlp
from swarm_env_baselines.safe_io import CONFIG_FILE, WEIGHTS_FILE, _atomic, one_line, read_description, read_tensors

#: ``policy.json``'s format of a fan_dagger network.
FAN_FORMAT = "swarm_env.fan_dagger/1"
#: Columns of one candidate's features ``f_k``: v, omega, time to contact, v - v_pursuit, omega - omega_pursuit.
CANDIDATE_FEATURES = 5
#: Bounds a policy file must keep (a larger one is refused before anything is allocated): the widest layer of every
#: loader (:mod:`swarm_env_baselines.model_bounds`), the most layers the trainer builds (fewer than the
#: loaders' :data:`~swarm_env_baselines.model_bounds.MAX_DEPTH`) and the most candidate twists.
MAX_WIDTH, MAX_LAYERS, MAX_CANDIDATES = mb.MAX_WIDTH, 8, 4096

__all__ = ["FAN_FORMAT", "FanPolicy", "fan_inputs", "load_fan_policy", "make_fan_dagger", "make_fan_dagger_shielded",
           "fan_net", "save_fan_policy"]


def fan_net(obs_size: int, candidates: np.ndarray, hidden: tuple[int, ...], candidate_hidden: tuple[int, ...]) -> Any:
    """A ``FanNet`` (a ``torch.nn.Module``) for observations of ``obs_size`` values and the candidate twists
    ``candidates`` ``(C, 2)`` (normalised; kept in the module as the buffer ``candidates``)."""
    import torch
    import torch.nn as nn

    n_candidates = len(candidates)

    class FanNet(nn.Module):
        """Scores ``C`` candidates per row: ``trunk(x) + per_candidate(f_k)`` (the module docstring)."""

        def __init__(self) -> None:
            super().__init__()
            self.register_buffer("candidates", torch.as_tensor(np.asarray(candidates, np.float32)))
            self.trunk = mlp([obs_size + n_candidates + 2, *hidden, n_candidates])
            self.per_candidate = mlp([CANDIDATE_FEATURES, *candidate_hidden, 1])

        def forward(self, x: torch.Tensor) -> torch.Tensor:
            """``x`` ``(B, obs + C + 2)`` (:func:`fan_inputs`) -> logits ``(B, C)``."""
            ttc = x[:, obs_size:obs_size + n_candidates, None]
            pursuit = x[:, None, obs_size + n_candidates:]
            cand = self.candidates.expand(len(x), -1, -1)
            f = torch.cat([cand, ttc, cand - pursuit], dim=2)  # (B, C, CANDIDATE_FEATURES)
            return self.trunk(x) + self.per_candidate(f).squeeze(-1)

    return FanNet()


def fan_inputs(obs_norm: np.ndarray, ttc: np.ndarray, pursuit: np.ndarray, sensor: ObservationExpert) -> np.ndarray:
    """``FanNet``'s input ``(B, D + C + 2)`` float32 from normalised observations ``(B, D)``, the fan's times to
    contact ``(B, C)`` (as ``min(ttc, horizon) / horizon``) and pursuit twists ``(B, 2)`` (m/s, rad/s; normalised)
    of ``sensor`` (a reset :class:`ObservationExpert`)."""
    t = np.minimum(ttc, sensor.horizon) / sensor.horizon
    p = pursuit / np.array([sensor.v_max, sensor.w_max])
    return np.concatenate([obs_norm, t, p], axis=1).astype(np.float32)


class FanPolicy:
    """A trained ``FanNet`` controlling every follower: the best-scoring candidate of each row."""

    acts_on = OBSERVATIONS

    def __init__(self, net: Any, obs_rms: RunningMeanStd, sensor_options: dict[str, Any], name: str = "fan_dagger"
                 ) -> None:
        self.net = net
        self.obs_rms = obs_rms
        self.sensor = ObservationExpert(**sensor_options)
        self.name = name

    def reset(self, env: Any, seed: int | None) -> None:
        """Read the scenario's constants into the sensor; the env's observation must be the one trained on."""
        self.sensor.reset(env, seed)
        if self.sensor.obs_size != self.obs_rms.mean.shape[0]:
            raise PolicyError(f"policy {self.name}: trained on observations of {self.obs_rms.mean.shape[0]} values, "
                              f"this env gives {self.sensor.obs_size}")
        trained = self.net.candidates.numpy()
        if trained.shape != self.sensor.candidates.shape or not np.allclose(trained, self.sensor.candidates, atol=1e-6):
            raise PolicyError(f"policy {self.name}: trained on other candidate twists ({len(trained)}) than its sensor "
                              f"makes for this env ({len(self.sensor.cand)}): another scenario's limits?")

    def pick_rows(self, obs: np.ndarray) -> np.ndarray:
        """The candidate ``(M,)`` each observation row ``(M, D)`` plays."""
        import torch

        fan = self.sensor.fan(obs)
        x = fan_inputs(self.obs_rms.normalize(np.asarray(obs, np.float64)), fan.ttc, fan.pursuit, self.sensor)
        with torch.no_grad():
            logits = self.net(torch.from_numpy(x))
        return logits.argmax(dim=1).numpy()

    def act_rows(self, obs: np.ndarray) -> np.ndarray:
        """The actions ``(M, 2)`` float32 of observation rows ``(M, D)``."""
        return self.sensor.candidates[self.pick_rows(obs)].astype(np.float32)

    def act(self, observations: dict[str, np.ndarray], state: WorldState | None = None) -> dict[str, Any]:
        """One action per observed agent, from its own observation only (``state`` is not read)."""
        agents = list(observations)
        if not agents:
            return {}
        actions = self.act_rows(np.stack([np.asarray(observations[a], np.float64) for a in agents]))
        return dict(zip(agents, actions))


# --------------------------------------------------------------------------- files


def save_fan_policy(directory: Path, net: Any, obs_rms: RunningMeanStd, config: Any, sensor_options: dict[str, Any]
                    ) -> Path:
    """Write ``policy.safetensors`` and ``policy.json`` (the module docstring) into ``directory``, atomically."""
    from safetensors.torch import save_file

    directory.mkdir(parents=True, exist_ok=True)
    tensors = {k: v.detach().cpu().contiguous() for k, v in net.state_dict().items()}
    meta = {"format": FAN_FORMAT, "config": dataclasses.asdict(config), "obs_rms": obs_rms.to_json(),
            "fan": {"options": sensor_options, "candidates": len(net.candidates)}}
    with _atomic(directory / WEIGHTS_FILE) as tmp:
        save_file(tensors, str(tmp))
    with _atomic(directory / CONFIG_FILE) as tmp:
        write_json(tmp, meta, indent=None)
    return directory


def _sensor_options(value: Any) -> dict[str, Any]:
    """``fan.options``: known :class:`ObsExpertConfig` fields, each a bool where the field is one and a finite number
    (``null`` where the field may be ``None``) otherwise; the config's own checks then bound the numbers."""
    options = dict(mb.json_object(value, "fan.options"))
    for f in dataclasses.fields(ObsExpertConfig):
        if f.name not in options:
            continue
        where, got = f"fan.options.{f.name}", options[f.name]
        if isinstance(f.default, bool):
            if not isinstance(got, bool):
                raise ValueError(f"{where}: expected true or false, got {clip_repr(got)}")
        elif not (got is None and f.default is None):
            mb.number(got, where)
    ObsExpertConfig(**options)  # unknown or out-of-range sensor options fail here, naming the option
    return options


def load_fan_policy(directory: str | Path, name: str | None = None) -> FanPolicy:
    """The network of a saved run directory as a :class:`FanPolicy` (reset it with an env before acting).
    Raises ``ValueError`` naming the file for a missing or bad file (sizes out of bounds, tensors that do not fit
    or are not finite, unknown sensor options)."""
    import torch

    d = Path(directory).expanduser()
    meta = read_description(d / CONFIG_FILE, FAN_FORMAT)
    try:
        config = mb.json_object(mb.get(meta, "config", ""), "config")
        hidden = mb.widths(mb.get(config, "hidden", "config"), "config.hidden", max_layers=MAX_LAYERS)
        candidate_hidden = mb.widths(mb.get(config, "candidate_hidden", "config"), "config.candidate_hidden",
                                     max_layers=MAX_LAYERS)
        inputs = mb.statistics(mb.get(meta, "obs_rms", ""), "obs_rms", max_len=mb.MAX_OBSERVATION)
        fan = mb.json_object(mb.get(meta, "fan", ""), "fan")
        n = mb.integer(mb.get(fan, "candidates", "fan"), "fan.candidates", 1, MAX_CANDIDATES)
        options = _sensor_options(mb.get(fan, "options", "fan"))
        mb.check_parameters(mb.mlp_parameters([inputs + n + 2, *hidden, n])
                            + mb.mlp_parameters([CANDIDATE_FEATURES, *candidate_hidden, 1]), "config.hidden")
        obs_rms = RunningMeanStd.from_json(meta["obs_rms"])
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise ValueError(f"{mb.shown(d / CONFIG_FILE)}: not a fan_dagger policy description "
                         f"({one_line(exc)})") from None
    net = fan_net(obs_rms.mean.shape[0], np.zeros((n, 2)), hidden, candidate_hidden)
    tensors = read_tensors(d / WEIGHTS_FILE)  # finite, bounded values only (model_bounds.read_safetensors)
    try:
        net.load_state_dict(tensors, strict=True)
    except (RuntimeError, ValueError) as exc:
        raise ValueError(f"{mb.shown(d / WEIGHTS_FILE)}: the tensors do not fit the network of {CONFIG_FILE} "
                         f"({one_line(exc)})") from None
    if not all(torch.isfinite(p).all() for p in net.parameters()):
        raise ValueError(f"{mb.shown(d / WEIGHTS_FILE)}: the network's tensors are not all finite")
    torch.set_num_threads(1)  # a small network on a few rows: threads only add overhead (and float noise)
    return FanPolicy(net.eval(), obs_rms, options, name=name or f"fan_dagger:{directory}")


def _load_run(env: Any, run: Path, label: str) -> FanPolicy:
    try:
        policy = load_fan_policy(run, name=label)
    except ValueError as exc:
        raise ModelFileError(f"policy {label}: {exc}") from None
    policy.reset(env, None)
    return policy


def _entry_point(method: str, shielded: bool, doc: str) -> Callable[..., Any]:
    """The entry point ``method[:s<k>|:PATH]`` of the shipped fan_dagger runs (``s0`` without an argument) or any
    run directory of the trainer (or its ``best/``), executed through the safety layer if ``shielded``."""
    return shipped_method_entry_point(method, "fan_dagger", _load_run, shielded, doc)


make_fan_dagger = _entry_point(
    "fan_dagger", False, "Entry point ``fan_dagger[:s<k>|:PATH]``: the shipped fan_dagger runs, or any run directory "
    "of swarm_env_baselines.fan_dagger (or its ``best/``), acting on observations only.")
make_fan_dagger_shielded = _entry_point(
    "fan_dagger_shielded", True, "Entry point ``fan_dagger_shielded[:s<k>|:PATH]``: ``fan_dagger``'s networks "
    "executed through the safety layer (swarm_env.harness.policies.ShieldedPolicy).")
