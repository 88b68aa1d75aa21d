"""The policy protocol and the policy registry.

A *policy* controls every follower of a :class:`~swarm_env.env.SwarmEnv`:

.. code-block:: python

    class Policy(Protocol):
        def reset(self, env: SwarmEnv, seed: int | None) -> None: ...
        def act(self, observations: dict[str, np.ndarray], state: WorldState) -> dict[str, Any]: ...

``act`` receives the agents' observations and the privileged
:class:`~swarm_env.state.WorldState` (scripted experts use the latter, learned
policies the former) and returns one action per agent in ``env.agents``. A
policy may also define ``stats() -> dict`` (telemetry that lands in the metrics
JSON under ``policy_stats``).

Anything with SB3's ``predict(observation, state=None, episode_start=None,
deterministic=False)`` method is wrapped by :class:`PredictPolicy` (the agents'
observations are stacked into one batch, parameter sharing style), so expert
policies and RL models are scored by one evaluation path.

Policies are found by name in the Python entry-point group
``swarm_env.policies``. An entry point names a factory
``factory(env: SwarmEnv, arg: str | None) -> Policy``; the spec string
``"name:arg"`` (e.g. ``ppo:runs/best.zip``) passes ``arg`` to it. This package
registers ``random``, ``zero``, ``pursuit`` (pure pursuit to the slot, no
avoidance) and ``shield:SPEC`` (any policy run through the VO safety layer of
:mod:`swarm_env.control.safety`); the experts (``vo``, ``cbs_rrt``) and RL
loaders register themselves from their own packages.
"""

from __future__ import annotations

import inspect
import os
import re
import sys
from collections.abc import Callable
from importlib.metadata import entry_points
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np

from swarm_env.checks import did_you_mean
from swarm_env.control.pursuit import pure_pursuit
from swarm_env.control.safety import AvoidanceParams, shield_actions
from swarm_env.extras import (
    DISTRIBUTION,
    MissingExtraError,
    extra_for_module,
    missing_distributions,
    missing_extra_error,
)
from swarm_env.state import WorldState

if TYPE_CHECKING:
    from swarm_env.env import SwarmEnv

ENTRY_POINT_GROUP = "swarm_env.policies"


class UnknownPolicyError(KeyError):
    """No policy of that name is registered."""


class PolicyError(ValueError):
    """A registered policy rejected its argument or the env (e.g. ``vo`` with discrete actions)."""


class PolicyArgumentError(PolicyError):
    """A policy's argument is wrong whatever the env: an unknown ``KEY``, a value of the wrong type, or one its
    class refuses (``vo:reverse=-5``). Unlike an env the policy does not fit, a saved file that names such a
    spec (a residual run's expert) is a bad file."""


class ModelFileError(PolicyError):
    """A policy's saved model is missing, unreadable (truncated, corrupt), of another algorithm or
    format, or refused because loading it would unpickle (see :func:`pickle_trusted`).

    A bad argument rather than a misfit: ``swarm-env run`` and ``evaluate`` report it in one line and
    exit with code 2, where a policy that merely does not fit a scenario becomes an ``n/a`` row.
    """


#: The environment variable that opts in to loading pickle-bearing model files (``1``, ``true`` or
#: ``yes``); ``swarm-env run/evaluate --trust-pickle`` sets it for the command and its workers.
TRUST_PICKLE_ENV = "SWARM_ENV_TRUST_PICKLE"


def pickle_trusted(trust: bool | None = None) -> bool:
    """Whether loading may unpickle model files (SB3's ``model.zip``, ``vecnormalize.pkl``).

    Unpickling runs whatever code the file names, so the answer is no unless the caller says so:
    ``trust`` when given (``True``/``False``), else whether :data:`TRUST_PICKLE_ENV` is set to
    ``1``, ``true`` or ``yes`` (any case).
    """
    if trust is not None:
        return bool(trust)
    return os.environ.get(TRUST_PICKLE_ENV, "").strip().lower() in ("1", "true", "yes")


@runtime_checkable
class Policy(Protocol):
    def reset(self, env: SwarmEnv, seed: int | None) -> None: ...

    def act(self, observations: dict[str, np.ndarray], state: WorldState) -> dict[str, Any]: ...


#: What a policy acts on, for the leaderboard's "acts on" column (a factory's ``acts_on`` attribute,
#: see :func:`acts_on`).
OBSERVATIONS, STATE, NOTHING = "observations", "state", "nothing"


class RandomPolicy:
    """Uniformly random actions from each agent's action space (seeded by ``reset``)."""

    acts_on = NOTHING

    def __init__(self, env: SwarmEnv, arg: str | None = None) -> None:
        if arg:
            raise ValueError(f"policy 'random' takes no argument, got {arg!r}")
        self._spaces: dict[str, Any] = {}

    def reset(self, env: SwarmEnv, seed: int | None) -> None:
        self._spaces = {a: env.action_space(a) for a in env.possible_agents}
        seq = np.random.SeedSequence(seed)
        for a, s in zip(env.possible_agents, seq.generate_state(len(env.possible_agents))):
            self._spaces[a].seed(int(s))

    def act(self, observations: dict[str, np.ndarray], state: WorldState) -> dict[str, Any]:
        return {a: self._spaces[a].sample() for a in observations}


class ZeroPolicy:
    """Every follower stands still (continuous ``[0, 0]`` or the discrete stop primitive)."""

    acts_on = NOTHING

    def __init__(self, env: SwarmEnv, arg: str | None = None) -> None:
        if arg:
            raise ValueError(f"policy 'zero' takes no argument, got {arg!r}")
        self._discrete = env.action_type == "discrete"

    def reset(self, env: SwarmEnv, seed: int | None) -> None:
        self._discrete = env.action_type == "discrete"

    def act(self, observations: dict[str, np.ndarray], state: WorldState) -> dict[str, Any]:
        if self._discrete:
            return {a: 0 for a in observations}
        return {a: np.zeros(2, dtype=np.float32) for a in observations}


class PursuitPolicy:
    """Pure pursuit straight at each follower's slot target, with no collision avoidance.

    The paper-003 tracking law (:func:`swarm_env.control.pursuit.pure_pursuit`) alone: a
    reference point for what the experts' avoidance layers add. ``arg`` is the
    time gap in seconds (default 0.5): the speed command is ``distance / gap``.
    """

    acts_on = STATE

    def __init__(self, env: SwarmEnv, arg: str | None = None) -> None:
        try:
            self.time_gap = 0.5 if arg is None else float(arg)
        except ValueError:
            raise ValueError(f"policy 'pursuit' takes a time gap in seconds, got {arg!r}") from None
        if not self.time_gap > 0:
            raise ValueError(f"policy 'pursuit' needs a positive time gap, got {arg!r}")
        self.reset(env, None)  # refuse a discrete env now, before any episode

    def reset(self, env: SwarmEnv, seed: int | None) -> None:
        if env.action_type == "discrete":
            raise PolicyError("policy 'pursuit' drives the continuous action space only")

    def act(self, observations: dict[str, np.ndarray], state: WorldState) -> dict[str, Any]:
        robots = state.scenario.robots
        limits = np.array([robots.max_speed, robots.max_turn_rate])
        twist = pure_pursuit(state.follower_pose, state.slot_targets, limits[0], limits[1], self.time_gap)
        action = (twist / limits).astype(np.float32)
        return {a: action[int(a.rsplit("_", 1)[1])] for a in observations}


class PredictPolicy:
    """Adapts an SB3-style model (``predict(obs_batch, deterministic=...)``) to :class:`Policy`."""

    def __init__(self, model: Any, deterministic: bool = True) -> None:
        if not callable(getattr(model, "predict", None)):
            raise TypeError(f"{type(model).__name__} has no predict() method")
        self.model = model
        self.deterministic = deterministic

    def reset(self, env: SwarmEnv, seed: int | None) -> None:
        pass

    def act(self, observations: dict[str, np.ndarray], state: WorldState) -> dict[str, Any]:
        agents = list(observations)
        if not agents:
            return {}
        batch = np.stack([observations[a] for a in agents])
        actions, _ = self.model.predict(batch, deterministic=self.deterministic)
        return {a: actions[i] for i, a in enumerate(agents)}


def expert_factory(name: str, cls: type, acts_on: str = STATE) -> Callable[..., Any]:
    """The entry-point factory of a scripted expert class ``cls`` registered as ``name``:
    ``factory(env, arg)`` builds ``cls(**parse_policy_kwargs(name, arg, cls))`` and, for a
    discrete-action env, calls its ``reset`` at once so that its refusal (a ``ValueError``) comes
    now rather than at the first episode. ``acts_on``: what the expert reads (:data:`STATE`, the
    privileged world state, or :data:`OBSERVATIONS`, the agents' own observations only)."""

    def factory(env: SwarmEnv, arg: str | None = None) -> Any:
        kwargs = parse_policy_kwargs(name, arg, cls)
        try:
            policy = cls(**kwargs)
        except ValueError as exc:  # a value in range for its type but refused by the class: still the argument
            label = f"{name}:{arg}" if arg else name
            raise PolicyArgumentError(str(exc) if str(exc).startswith("policy ") else f"policy {label!r}: {exc}"
                                      ) from None
        if env.action_type != "continuous":
            policy.reset(env, None)  # raises the explanatory ValueError now, not at the first episode
        return policy

    factory.acts_on = acts_on  # type: ignore[attr-defined]
    factory.policy_class = cls  # type: ignore[attr-defined]  # policy_defaults() reads it
    factory.__name__ = factory.__qualname__ = f"make_{name}"
    factory.__doc__ = f"Entry point ``{name}[:KEY=VALUE,...]``: :class:`{cls.__module__}.{cls.__name__}`."
    return factory


def parse_policy_kwargs(name: str, arg: str | None, cls: type) -> dict[str, Any]:
    """Parse a policy argument ``"key=value,key=value"`` into keyword arguments of ``cls``.

    The parameters and their defaults are ``cls.policy_parameters()`` if ``cls`` has it (a
    class whose ``__init__`` forwards ``**kwargs``), else the keyword-only parameters of
    ``cls.__init__``. Each value is converted to the type of the parameter's default:
    ``bool`` (true/false/1/0), ``int``, ``float``, ``str``, a ``None`` default takes a number
    or ``none``, and a tuple default takes ``;``-separated numbers (``angles=0;12;-12``).
    Raises :class:`PolicyArgumentError` (a ``ValueError``) naming the policy, the key and what was expected.
    """
    declared = getattr(cls, "policy_parameters", None)
    params = dict(declared()) if callable(declared) else {
        p.name: p.default
        for p in inspect.signature(cls).parameters.values()
        if p.kind is inspect.Parameter.KEYWORD_ONLY
    }
    kwargs: dict[str, Any] = {}
    for item in filter(None, (part.strip() for part in (arg or "").split(","))):
        key, sep, value = (x.strip() for x in item.partition("="))
        if not sep:
            raise PolicyArgumentError(f"policy {name!r}: expected KEY=VALUE, got {item!r}")
        if key not in params:
            raise PolicyArgumentError(f"policy {name!r}: unknown parameter {key!r}; known: {', '.join(params)}")
        default = params[key]
        try:
            if isinstance(default, bool):
                if value.lower() not in ("true", "false", "1", "0"):
                    raise ValueError("expected true or false")
                kwargs[key] = value.lower() in ("true", "1")
            elif isinstance(default, int):
                kwargs[key] = int(value)
            elif isinstance(default, tuple):
                kwargs[key] = tuple(float(v) for v in value.split(";") if v.strip())
            elif isinstance(default, str):
                kwargs[key] = value
            elif default is None and value.lower() == "none":
                kwargs[key] = None
            else:
                kwargs[key] = float(value)
        except ValueError as exc:
            kind = type(default).__name__ if default is not None else "a number or none"
            raise PolicyArgumentError(f"policy {name!r}: {key}={value!r}: expected {kind} ({exc})") from None
    return kwargs


class ShieldedPolicy:
    """``shield:SPEC``: the policy ``SPEC`` with every action replaced by the nearest safe one.

    The same safety layer as :class:`swarm_env.wrappers.SafetyShield` (one function,
    :func:`swarm_env.control.safety.shield_actions`), applied at execution time to any registered
    policy, e.g. ``shield:pursuit`` or ``shield:ppo:runs/x``. The shield reads the
    privileged world state, like the experts. ``stats()`` reports the interventions
    (they land in the leaderboard's ``policy_stats``).
    """

    def __init__(self, env: SwarmEnv, arg: str | None = None) -> None:
        if not arg:
            raise ValueError("policy 'shield' wraps another policy: write shield:SPEC, e.g. shield:pursuit")
        if env.action_type != "continuous":
            raise PolicyError("policy 'shield' needs action_type='continuous': it replaces actions by safe twists")
        self.inner: Any = load_policy(arg, env)
        self.params = AvoidanceParams(w_heading=0.0)
        self._reset_stats()

    @classmethod
    def around(cls, inner: Any) -> ShieldedPolicy:
        """The shield around a policy object (e.g. a model being trained) instead of a spec."""
        self = cls.__new__(cls)
        self.inner = inner if isinstance(inner, Policy) else PredictPolicy(inner)
        self.params = AvoidanceParams(w_heading=0.0)
        self._reset_stats()
        return self

    def _reset_stats(self) -> None:
        self._interventions = 0
        self._agent_steps = 0
        self._correction = 0.0
        self._infeasible = 0

    def reset(self, env: SwarmEnv, seed: int | None) -> None:
        self.inner.reset(env, seed)
        self._reset_stats()

    def act(self, observations: dict[str, np.ndarray], state: WorldState) -> dict[str, Any]:
        actions = self.inner.act(observations, state)
        n = state.n_followers
        wanted = np.zeros((n, 2))
        rows = {a: int(a.rsplit("_", 1)[1]) for a in actions}
        for a, i in rows.items():
            wanted[i] = np.clip(np.asarray(actions[a], dtype=np.float64).reshape(2), -1.0, 1.0)
        shield = shield_actions(state, wanted, self.params)
        live = list(rows.values())
        self._interventions += int(shield.intervened[live].sum())
        self._correction += float(shield.correction[live].sum())
        self._infeasible += int(np.count_nonzero(~shield.feasible[live]))
        self._agent_steps += len(live)
        return {a: shield.actions[i] for a, i in rows.items()}

    def stats(self) -> dict[str, Any]:
        inner = self.inner.stats() if callable(getattr(self.inner, "stats", None)) else None
        steps = self._agent_steps
        out: dict[str, Any] = {
            "shield_interventions": self._interventions,
            "shield_intervention_rate": self._interventions / steps if steps else 0.0,
            "shield_mean_correction": self._correction / steps if steps else 0.0,
            "shield_infeasible": self._infeasible,
        }
        if inner:
            out["inner"] = inner
        return out


_BUILTIN: dict[str, Callable[..., Any]] = {
    "random": RandomPolicy,
    "zero": ZeroPolicy,
    "pursuit": PursuitPolicy,
    "shield": ShieldedPolicy,
}


def registered_policies() -> dict[str, str]:
    """Name -> ``module:attr`` of every policy in the entry-point group (plus the built-ins)."""
    found = {name: f"{fn.__module__}:{fn.__qualname__}" for name, fn in _BUILTIN.items()}
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        found[ep.name] = f"{ep.module}:{ep.attr}"
    return dict(sorted(found.items()))


_ROLE = re.compile(r":(?:class|func|meth|mod|data|attr|exc|obj):`~?(?:[\w.]*\.)?([^`.]+)`")
_SENTENCE_END = re.compile(r"(?<=[a-z0-9)`])\.(?:\s|$)")


def _first_sentence(doc: str | None) -> str:
    """The first sentence of ``doc`` on one line, as written (Sphinx roles included)."""
    text = " ".join((doc or "").strip().split("\n\n")[0].split())
    end = _SENTENCE_END.search(text)
    return text[: end.start() + 1] if end else text


def policy_summary(name: str) -> str:
    """One line about the registered policy ``name``: its factory's first sentence, less the ``Entry point
    ``name[:ARG]``: `` prefix the factories share, or, where that only names a class, the class's own first
    sentence; Sphinx roles shown by their last name. ``""`` where the factory cannot be loaded (a missing
    extra: ``swarm-env list`` says so instead)."""
    try:
        factory = _factory(name)
    except Exception:  # noqa: BLE001 - a missing extra or a broken third-party package: nothing to show
        return ""
    summary = _first_sentence(factory.__doc__)
    usage, sep, rest = summary.partition(": ")
    if sep and (usage.startswith("Entry point") or usage.startswith(f"``{name}")):
        summary = rest
    named = re.fullmatch(r":class:`~?([\w.]+)\.(\w+)`\.?", summary)
    if named:  # the factory names its class: that class's first sentence says what the policy does
        module = sys.modules.get(named.group(1))
        summary = _first_sentence(getattr(getattr(module, named.group(2), None), "__doc__", None)) or summary
    return _ROLE.sub(r"\1", summary).replace("``", "`")


def policy_extra(name: str) -> tuple[str, str] | None:
    """``(distribution, extras)``: the optional extra that the registered policy ``name`` needs, as its
    entry point declares it (``ppo = "pkg.module:factory [rl]"`` in ``swarm-env``'s pyproject.toml ->
    ``("swarm-env", "rl")``; several extras joined by commas), or ``None``."""
    for ep in entry_points(group=ENTRY_POINT_GROUP, name=name):
        if not ep.extras:
            return None
        return (ep.dist.name if ep.dist is not None else DISTRIBUTION), ",".join(ep.extras)
    return None


def _missing_extra(name: str, exc: ImportError) -> Exception:
    """The one-line :class:`~swarm_env.extras.MissingExtraError` for a policy whose import failed: naming
    the extra its entry point declares if that one is not (fully) installed, else swarm-env's extra that
    installs the missing module; ``exc`` itself otherwise (an import error with every extra in place is a
    bug, not a missing extra, and keeps its traceback)."""
    declared = policy_extra(name)
    if declared and missing_distributions(declared[1], declared[0]):
        return missing_extra_error(declared[1], f"policy {name!r}", str(exc), declared[0])
    found = extra_for_module(getattr(exc, "name", None))
    return missing_extra_error(found, f"policy {name!r}", str(exc)) if found else exc


def _factory(name: str) -> Callable[..., Any]:
    """The factory registered as ``name`` (entry points first, then the built-ins). Raises
    :class:`~swarm_env.extras.MissingExtraError` when its module needs an extra that is not installed."""
    for ep in entry_points(group=ENTRY_POINT_GROUP, name=name):
        try:
            return ep.load()
        except ImportError as exc:
            error = _missing_extra(name, exc)
            if error is exc:
                raise
            raise error from None
    factory = _BUILTIN.get(name)
    if factory is None:
        known = registered_policies()
        raise UnknownPolicyError(f"unknown policy {name!r}{did_you_mean(name, known)}; registered policies: "
                                 f"{', '.join(known)}")
    return factory


def training_runs(spec: str) -> tuple[str, ...]:
    """The specs a leaderboard plays for ``spec``: one per shipped training seed of a learned method.

    A factory that has a ``training_runs`` attribute (a tuple of its arguments, e.g.
    ``("s0", "s1", "s2")``) stands for a method trained with several seeds: its bare name
    (``"mappo"``) expands to ``("mappo:s0", "mappo:s1", "mappo:s2")``, and the leaderboard
    reports each seed and the mean across them. Any other spec (a policy without training
    seeds, or one with an argument such as ``mappo:s1`` or ``mappo:runs/x``) is itself:
    ``(spec,)``. Raises :class:`UnknownPolicyError` for an unregistered name.
    """
    name, _, arg = spec.partition(":")
    runs = getattr(_factory(name), "training_runs", None)
    if arg or not runs:
        return (spec,)
    return tuple(f"{name}:{r}" for r in runs)


def policy_defaults(spec: str) -> dict[str, Any]:
    """The default parameters of the scripted expert that ``spec`` names, what its behaviour depends on
    besides the code and ``spec``'s own ``KEY=VALUE`` overrides: the class's ``policy_parameters()``
    when it has one (the ``vo`` expert's include its avoidance defaults), else the keyword defaults of
    its constructor. ``shield:SPEC`` gives ``SPEC``'s. ``{}`` for a policy that is not an expert class
    (learned models, the built-in baselines). Raises :class:`UnknownPolicyError` for an unknown name.

    Caches keyed on a policy spec (``swarm_env_baselines.demos``) include it, so that changing an
    expert's defaults does not reuse what the earlier defaults produced.
    """
    name, _, arg = spec.partition(":")
    factory = _factory(name)
    if factory is ShieldedPolicy:
        return policy_defaults(arg) if arg else {}
    cls = getattr(factory, "policy_class", None)
    if cls is None:
        return {}
    parameters = getattr(cls, "policy_parameters", None)
    if callable(parameters):
        return dict(parameters())
    return {p.name: p.default for p in inspect.signature(cls.__init__).parameters.values()
            if p.default is not inspect.Parameter.empty}


def acts_on(spec: str) -> str:
    """What the policy ``spec`` reads when it acts: ``"observations"`` (each follower's own
    observation: deployable on robots with their own sensors), ``"state"`` (the privileged
    ``WorldState``, like the experts), ``"nothing"``, or ``"?"`` for a factory that does not say
    (its ``acts_on`` attribute) or is not installed. ``shield:SPEC`` and a policy executed through
    the safety layer read the state (the shield does) and say so: ``"observations + shield"``.
    """
    name, _, arg = spec.partition(":")
    try:
        factory = _factory(name)
    except (UnknownPolicyError, MissingExtraError):
        return "?"
    if factory is ShieldedPolicy:
        inner = acts_on(arg) if arg else "?"
        return inner if inner == STATE else f"{inner} + shield"
    return str(getattr(factory, "acts_on", "?"))


def load_policy(spec: str | Any, env: SwarmEnv) -> Policy:
    """Build a policy from ``"name"`` / ``"name:arg"`` or wrap a model object.

    Raises :class:`UnknownPolicyError` (a ``KeyError``) naming the known policies when ``name`` is
    unknown, :class:`PolicyError` (a ``ValueError``) when the factory rejects ``arg`` or the env, and
    :class:`~swarm_env.extras.MissingExtraError` (one line naming the pip command) when the policy needs
    an optional extra that is not installed.
    """
    if not isinstance(spec, str):
        if isinstance(spec, Policy):
            return spec
        return PredictPolicy(spec)
    name, _, arg = spec.partition(":")
    factory = _factory(name)
    try:
        policy = factory(env, arg or None)
    except PolicyError:
        raise
    except ImportError as exc:  # a factory that imports its extra only when called
        error = _missing_extra(name, exc)
        if error is exc:
            raise
        raise error from None
    except ValueError as exc:  # a factory's documented way to reject its argument or the env
        message = str(exc) if str(exc).startswith("policy ") else f"policy {spec!r}: {exc}"
        raise PolicyError(message) from exc
    if not isinstance(policy, Policy):
        policy = PredictPolicy(policy)
    return policy
