"""MAPPO and IPPO on swarm_env: PPO with one decentralised actor shared by every follower.

.. code-block:: console

    python -m baselines.mappo --scenario random --total-steps 2e6 --seed 0                  # MAPPO
    python -m baselines.mappo --scenario random --total-steps 2e6 --seed 0 --critic local   # IPPO
    python -m baselines.mappo --scenario random --total-steps 2e6 --seed 0 --shield         # through the safety layer

A small PyTorch implementation in the CleanRL spirit, written to read top to bottom. The
actor maps one follower's observation to a Gaussian over its normalised twist (parameter
sharing: one network for all followers); the critic is **centralised** (``critic="central"``,
MAPPO, Yu et al. 2022: the global ``env.state()`` joined to the follower's own observation,
the "agent-specific global state") or **local** (``critic="local"``, IPPO: the observation
alone). Observations and states are normalised by running statistics, rewards by a running
estimate of the return's scale; truncated episodes are bootstrapped from the value of their
last state. With ``shield`` every copy is a :class:`swarm_env.wrappers.SafetyShield`, so the
learner is trained on what the safety layer executes (score the result as ``shield:mappo:DIR``).

Why not BenchMARL or TorchRL: both run here (``docs/clients.md``), but BenchMARL pins an old
TorchRL and pulls a CUDA torch unless installed by hand, and neither can use this repository's
evaluation path during training; a 300-line trainer keeps the baseline in the default
install, deterministic, and scored by the same ``run_episode`` as the leaderboard.

Data split (as the SB3 baselines): training worlds are the generator streams of seeds
``100 * seed + copy`` (below 500), model selection uses validation seeds ``500-549``
(every ``eval_every`` agent-steps; the best score is kept in ``best/``), and the test seeds
``1000-1049`` are left to the leaderboard.

A run directory ``<runs_dir>/<run_name>/`` holds ``config.json``, ``versions.json``,
``policy.safetensors`` + ``policy.json`` (actor, critic and normalisation statistics as
tensors and JSON: loading runs no code), ``best/``, ``eval.csv`` (validation, streamed),
``train.csv`` (losses, action std, contact rate per update), ``learning_curve.png`` and
``summary.json``. Load it
with ``mappo:<run dir>`` (or ``mappo:<run dir>/best``) anywhere a policy spec is accepted.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from swarm_env.state import WorldState

FORMAT = "swarm_env.mappo/1"
WEIGHTS_FILE = "policy.safetensors"
CONFIG_FILE = "policy.json"
#: Model selection: a collision costs as much as this many metres of mean formation error.
COLLISION_COST_M = 1.0
EVAL_COLUMNS = ("agent_steps", "wall_s", "score", "formation_error", "formation_error_ci95", "collisions",
                "collisions_ci95", "success_rate")


@dataclass
class MAPPOConfig:
    """Everything that defines a MAPPO/IPPO run."""

    #: Built-in scenario name, a YAML path, or "random".
    scenario: str = "random"
    #: Extra SwarmEnv keyword arguments / random-generator knobs, as KEY=VALUE (YAML values).
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    #: Critic input: central (MAPPO: env.state() + own observation) or local (IPPO: own observation).
    critic: str = "central"
    #: Train and evaluate through the VO safety layer (swarm_env.wrappers.SafetyShield).
    shield: bool = False
    #: Training budget in agent-steps (one follower acting once).
    total_steps: int = 2_000_000
    #: Seed of the networks, the action sampling and the training worlds.
    seed: int = 0
    #: Env copies stepped together.
    n_copies: int = 8
    #: Rollout length per copy between updates.
    n_steps: int = 128
    #: Adam learning rate.
    learning_rate: float = 3e-4
    #: Discount factor.
    gamma: float = 0.99
    #: GAE lambda.
    gae_lambda: float = 0.95
    #: Clip range of the policy ratio.
    clip_range: float = 0.2
    #: Optimisation epochs per rollout.
    n_epochs: int = 5
    #: Minibatches per epoch.
    n_minibatches: int = 4
    #: Entropy bonus coefficient.
    ent_coef: float = 0.0
    #: Value loss coefficient.
    vf_coef: float = 0.5
    #: Gradient norm clip.
    max_grad_norm: float = 0.5
    #: Hidden layer sizes of the actor and of the critic.
    hidden: tuple[int, ...] = (128, 128)
    #: Initial log standard deviation of the actions (on the [-1, 1] action range).
    log_std_init: float = -0.5
    #: Evaluate every this many agent-steps (0 = only at the end).
    eval_every: int = 400_000
    #: Validation seeds, e.g. 500-549.
    eval_seeds: str = "500-549"
    #: Torch threads (1 is fastest for these small networks).
    torch_threads: int = 1
    #: Parent directory of run directories.
    runs_dir: str = "runs"
    #: Run directory name (default: mappo|ippo_<scenario>_s<seed>_<timestamp>).
    run_name: str | None = None
    #: Show a progress bar.
    progress: bool = True

    def __post_init__(self) -> None:
        if self.critic not in ("central", "local"):
            raise ValueError(f"critic must be 'central' or 'local', got {self.critic!r}")
        for name in ("total_steps", "n_copies", "n_steps", "n_epochs", "n_minibatches", "torch_threads"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive int, got {value!r}")
        self.hidden = tuple(int(h) for h in self.hidden)

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), indent=2)


# --------------------------------------------------------------------------- normalisation


class RunningMeanStd:
    """Running mean and variance of batches (Chan et al.'s parallel update), in float64."""

    def __init__(self, shape: tuple[int, ...], epsilon: float = 1e-8, clip: float = 10.0) -> None:
        self.mean = np.zeros(shape)
        self.var = np.ones(shape)
        self.count = 1e-4
        self.epsilon = epsilon
        self.clip = clip

    def update(self, batch: np.ndarray) -> None:
        x = np.asarray(batch, dtype=np.float64).reshape(-1, *self.mean.shape)
        b_mean, b_var, n = x.mean(axis=0), x.var(axis=0), x.shape[0]
        delta = b_mean - self.mean
        total = self.count + n
        self.mean = self.mean + delta * n / total
        self.var = (self.var * self.count + b_var * n + delta**2 * self.count * n / total) / total
        self.count = total

    def normalize(self, x: np.ndarray) -> np.ndarray:
        return np.clip((x - self.mean) / np.sqrt(self.var + self.epsilon), -self.clip, self.clip).astype(np.float32)

    def to_json(self) -> dict[str, Any]:
        return {"mean": self.mean.tolist(), "var": self.var.tolist(), "count": self.count, "epsilon": self.epsilon, "clip": self.clip}

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> "RunningMeanStd":
        rms = cls(tuple(np.asarray(d["mean"]).shape), float(d["epsilon"]), float(d["clip"]))
        rms.mean, rms.var, rms.count = np.asarray(d["mean"], dtype=np.float64), np.asarray(d["var"], dtype=np.float64), float(d["count"])
        return rms


# --------------------------------------------------------------------------- networks


def _mlp(sizes: list[int]) -> Any:
    import torch.nn as nn

    layers: list[Any] = []
    for i in range(len(sizes) - 1):
        layers.append(nn.Linear(sizes[i], sizes[i + 1]))
        if i < len(sizes) - 2:
            layers.append(nn.Tanh())
    return nn.Sequential(*layers)


def make_networks(obs_dim: int, state_dim: int, cfg: MAPPOConfig) -> tuple[Any, Any, Any]:
    """``(actor mean MLP, log_std parameter, critic MLP)``; the critic sees ``state + obs`` (central) or ``obs``."""
    import torch

    actor = _mlp([obs_dim, *cfg.hidden, 2])
    log_std = torch.nn.Parameter(torch.full((2,), float(cfg.log_std_init)))
    critic_in = obs_dim + (state_dim if cfg.critic == "central" else 0)
    critic = _mlp([critic_in, *cfg.hidden, 1])
    return actor, log_std, critic


def gae(rewards: np.ndarray, values: np.ndarray, dones: np.ndarray, last_values: np.ndarray, gamma: float, lam: float) -> np.ndarray:
    """Generalised advantage estimates ``(T, B)``.

    ``rewards``, ``values``, ``dones`` are ``(T, B)``: ``dones[t]`` means the episode ended
    after step ``t`` (a truncated episode's bootstrap is already folded into its last
    reward), ``last_values`` ``(B,)`` the values after the last step.
    """
    T = len(rewards)
    adv = np.zeros_like(rewards, dtype=np.float64)
    last = np.zeros(rewards.shape[1])
    for t in reversed(range(T)):
        next_value = last_values if t == T - 1 else values[t + 1]
        live = 1.0 - dones[t]
        delta = rewards[t] + gamma * next_value * live - values[t]
        last = delta + gamma * lam * live * last
        adv[t] = last
    return adv


# --------------------------------------------------------------------------- the policy as a swarm_env policy


class MAPPOPolicy:
    """A trained actor controlling every follower (deterministic: the Gaussian's mean)."""

    def __init__(self, actor: Any, obs_rms: RunningMeanStd, name: str = "mappo") -> None:
        self.actor = actor
        self.obs_rms = obs_rms
        self.name = name

    def reset(self, env: Any, seed: int | None) -> None:
        from swarm_env.policies import PolicyError

        agent = env.possible_agents[0]
        want = self.obs_rms.mean.shape
        have = env.observation_space(agent).shape
        if want != have:
            raise PolicyError(f"{self.name} was trained on observations of shape {want}, this env gives {have}")
        if env.unwrapped.action_type != "continuous":
            raise PolicyError(f"{self.name} acts in the continuous action space; this env is {env.unwrapped.action_type!r}")

    def act(self, observations: dict[str, np.ndarray], state: WorldState) -> dict[str, Any]:
        import torch

        agents = list(observations)
        if not agents:
            return {}
        x = torch.as_tensor(self.obs_rms.normalize(np.stack([observations[a] for a in agents])))
        with torch.no_grad():
            mean = self.actor(x).numpy()
        action = np.clip(mean, -1.0, 1.0).astype(np.float32)
        return {a: action[i] for i, a in enumerate(agents)}


def save_run_policy(directory: Path, actor: Any, log_std: Any, critic: Any, obs_rms: RunningMeanStd,
                    state_rms: RunningMeanStd, cfg: MAPPOConfig) -> Path:
    """Write ``policy.safetensors`` (actor, log_std, critic) and ``policy.json`` into ``directory``."""
    from safetensors.torch import save_file

    from baselines.safe_io import _atomic

    directory.mkdir(parents=True, exist_ok=True)
    tensors = {f"actor.{k}": v.detach().contiguous() for k, v in actor.state_dict().items()}
    tensors.update({f"critic.{k}": v.detach().contiguous() for k, v in critic.state_dict().items()})
    tensors["log_std"] = log_std.detach().contiguous()
    meta = {"format": FORMAT, "config": dataclasses.asdict(cfg), "obs_rms": obs_rms.to_json(), "state_rms": state_rms.to_json()}
    with _atomic(directory / WEIGHTS_FILE) as tmp:
        save_file(tensors, str(tmp))
    with _atomic(directory / CONFIG_FILE) as tmp:
        tmp.write_text(json.dumps(meta) + "\n")
    return directory


def load_run_policy(directory: str | Path) -> MAPPOPolicy:
    """The actor of a saved run as a :class:`MAPPOPolicy` (no pickle involved)."""
    import torch
    from safetensors.torch import load_file

    from baselines.safe_io import read_description

    d = Path(directory).expanduser()
    cfg_path = d / CONFIG_FILE
    meta = read_description(cfg_path, FORMAT)
    hidden = [int(h) for h in meta["config"]["hidden"]]
    obs_rms = RunningMeanStd.from_json(meta["obs_rms"])
    actor = _mlp([obs_rms.mean.shape[0], *hidden, 2])
    try:
        tensors = load_file(str(d / WEIGHTS_FILE), device="cpu")
        actor.load_state_dict({k[len("actor."):]: v for k, v in tensors.items() if k.startswith("actor.")}, strict=True)
    except Exception as exc:  # noqa: BLE001 - any failure here means a bad file
        raise ValueError(f"{d / WEIGHTS_FILE}: the tensors do not fit the actor of {cfg_path.name} ({exc})") from None
    actor.eval()
    torch.set_num_threads(1)  # scoring a small MLP on a few observations: threads only add overhead
    return MAPPOPolicy(actor, obs_rms, name=f"mappo:{directory}")


def make_policy(env: Any, arg: str | None = None) -> MAPPOPolicy:
    """Entry point ``mappo:PATH`` (a run directory or its ``best/``)."""
    from swarm_env.policies import PolicyError

    if not arg:
        raise PolicyError("policy 'mappo' needs a run directory: mappo:PATH")
    try:
        policy = load_run_policy(arg)
    except (FileNotFoundError, ValueError) as exc:
        raise PolicyError(f"policy mappo:{arg}: {exc}") from None
    policy.reset(env, None)
    return policy


# --------------------------------------------------------------------------- training


def _make_env(cfg: MAPPOConfig) -> Any:
    from swarm_env.env import SwarmEnv

    env = SwarmEnv(cfg.scenario, **cfg.env_kwargs)
    if cfg.shield:
        from swarm_env.wrappers import SafetyShield

        env = SafetyShield(env)
    return env


def evaluate(policy: MAPPOPolicy, cfg: MAPPOConfig, seeds: list[int]) -> dict[str, Any]:
    """Score ``policy`` on ``seeds`` with the leaderboard's episode loop (through the shield if ``cfg.shield``)."""
    from swarm_env.env import SwarmEnv
    from swarm_env.evaluation import run_episode, summarize
    from swarm_env.policies import ShieldedPolicy

    env = SwarmEnv(cfg.scenario, **cfg.env_kwargs)
    scored: Any = ShieldedPolicy.around(policy) if cfg.shield else policy
    episodes = [run_episode(env, scored, s) for s in seeds]
    env.close()
    s = summarize(episodes)
    s["score"] = s["formation_error"]["mean"] + COLLISION_COST_M * s["collisions"]["mean"]
    return s


def train(cfg: MAPPOConfig) -> Path:
    """Run ``cfg`` to completion and return the run directory."""
    import torch
    from tqdm import tqdm

    from baselines.config import parse_seeds
    from baselines.train import package_versions

    torch.set_num_threads(cfg.torch_threads)
    torch.manual_seed(cfg.seed)
    torch.use_deterministic_algorithms(True)
    kind = "mappo" if cfg.critic == "central" else "ippo"
    stamp = time.strftime("%Y%m%d-%H%M%S", time.gmtime())
    run_dir = Path(cfg.runs_dir) / (cfg.run_name or f"{kind}_{Path(cfg.scenario).stem}_s{cfg.seed}_{stamp}")
    if (run_dir / "config.json").exists():
        raise FileExistsError(f"run directory {run_dir} already holds a run; pick another --run-name")
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "config.json").write_text(cfg.to_json() + "\n")
    (run_dir / "versions.json").write_text(json.dumps(package_versions(), indent=2) + "\n")
    eval_seeds = parse_seeds(cfg.eval_seeds)

    envs = [_make_env(cfg) for _ in range(cfg.n_copies)]
    agents = list(envs[0].possible_agents)
    n, m = len(agents), cfg.n_copies
    obs_dim = envs[0].observation_space(agents[0]).shape[0]
    state_dim = envs[0].state_space.shape[0]
    actor, log_std, critic = make_networks(obs_dim, state_dim, cfg)
    params = [*actor.parameters(), log_std, *critic.parameters()]
    optim = torch.optim.Adam(params, lr=cfg.learning_rate, eps=1e-5)
    gen = torch.Generator().manual_seed(cfg.seed)
    obs_rms, state_rms, ret_rms = RunningMeanStd((obs_dim,)), RunningMeanStd((state_dim,)), RunningMeanStd(())
    returns = np.zeros((m, n))

    def observe(e: Any, o: dict) -> tuple[np.ndarray, np.ndarray]:
        return np.stack([o[a] for a in agents]), e.state()

    obs = np.zeros((m, n, obs_dim), np.float32)
    states = np.zeros((m, state_dim), np.float32)
    for k, e in enumerate(envs):
        o, _ = e.reset(seed=100 * cfg.seed + k)
        obs[k], states[k] = observe(e, o)

    def critic_input(o: np.ndarray, s: np.ndarray) -> Any:
        x = obs_rms.normalize(o).reshape(-1, obs_dim)
        if cfg.critic == "central":
            x = np.concatenate([np.repeat(state_rms.normalize(s), n, axis=0), x], axis=1)
        return torch.as_tensor(x)

    batch = cfg.n_steps * m * n
    n_updates = max(1, cfg.total_steps // batch)
    best = float("inf")
    history: list[dict[str, Any]] = []
    t0 = time.perf_counter()
    steps_done = 0
    next_eval = cfg.eval_every if cfg.eval_every else None
    with open(run_dir / "eval.csv", "w", newline="") as fh:
        csv.writer(fh).writerow(EVAL_COLUMNS)
    train_log = open(run_dir / "train.csv", "w", newline="")
    train_csv = csv.writer(train_log)
    train_csv.writerow(["agent_steps", "wall_s", "policy_loss", "value_loss", "entropy", "std", "mean_reward",
                        "contacts_per_agent_step", "first_ratio_error"])
    bar = tqdm(total=n_updates * batch, unit="step", disable=not cfg.progress, desc=kind)

    def evaluate_and_keep() -> None:
        nonlocal best
        frozen = RunningMeanStd.from_json(obs_rms.to_json())
        s = evaluate(MAPPOPolicy(actor, frozen), cfg, eval_seeds)
        row = {"agent_steps": steps_done, "wall_s": round(time.perf_counter() - t0, 1), "score": s["score"],
               "formation_error": s["formation_error"]["mean"], "formation_error_ci95": s["formation_error"]["ci95"],
               "collisions": s["collisions"]["mean"],
               "collisions_ci95": s["collisions"]["ci95"], "success_rate": s["success_rate"]["mean"]}
        history.append(row)
        with open(run_dir / "eval.csv", "a", newline="") as fh:  # streamed: the learning curve so far
            csv.writer(fh).writerow([row[c] for c in EVAL_COLUMNS])
        if row["score"] < best:
            best = row["score"]
            save_run_policy(run_dir / "best", actor, log_std, critic, obs_rms, state_rms, cfg)

    try:
        for _update in range(n_updates):
            # The actor's inputs as normalised when the actions were drawn: the update must see the same
            # inputs, or the probability ratio starts away from 1 (the statistics move during a rollout).
            buf_x = np.zeros((cfg.n_steps, m * n, obs_dim), np.float32)
            buf_crit = []
            buf_act = np.zeros((cfg.n_steps, m * n, 2), np.float32)
            buf_logp = np.zeros((cfg.n_steps, m * n), np.float32)
            buf_val = np.zeros((cfg.n_steps, m * n))
            buf_rew = np.zeros((cfg.n_steps, m * n))
            buf_done = np.zeros((cfg.n_steps, m * n))
            contacts = 0
            for t in range(cfg.n_steps):
                obs_rms.update(obs.reshape(-1, obs_dim))
                state_rms.update(states)
                x = torch.as_tensor(obs_rms.normalize(obs).reshape(-1, obs_dim))
                cin = critic_input(obs, states)
                with torch.no_grad():
                    mean = actor(x)
                    std = log_std.exp().expand_as(mean)
                    action = mean + std * torch.randn(mean.shape, generator=gen)
                    logp = torch.distributions.Normal(mean, std).log_prob(action).sum(-1)
                    value = critic(cin).squeeze(-1)
                buf_x[t], buf_act[t], buf_logp[t], buf_val[t] = x.numpy(), action.numpy(), logp.numpy(), value.numpy()
                buf_crit.append(cin)
                env_action = np.clip(action.numpy(), -1.0, 1.0).reshape(m, n, 2)
                for k, e in enumerate(envs):
                    o, r, term, trunc, info = e.step({a: env_action[k, i] for i, a in enumerate(agents)})
                    rew = np.array([r[a] for a in agents])
                    contacts += sum(sum(info[a][f"contacts_{g}"] for g in ("robot", "obstacle", "human", "wall")) for a in agents)
                    returns[k] = returns[k] * cfg.gamma + rew
                    ret_rms.update(returns[k])
                    done = not e.agents
                    o_next, s_next = observe(e, o)
                    scaled = np.clip(rew / np.sqrt(ret_rms.var + ret_rms.epsilon), -10.0, 10.0)
                    if done:
                        if any(trunc.values()) and not any(term.values()):  # bootstrap a cut-off episode
                            with torch.no_grad():
                                scaled = scaled + cfg.gamma * critic(critic_input(o_next[None], s_next[None])).squeeze(-1).numpy()
                        returns[k] = 0.0
                        o2, _ = e.reset()
                        o_next, s_next = observe(e, o2)
                    buf_rew[t, k * n:(k + 1) * n] = scaled
                    buf_done[t, k * n:(k + 1) * n] = float(done)
                    obs[k], states[k] = o_next, s_next
            with torch.no_grad():
                last_val = critic(critic_input(obs, states)).squeeze(-1).numpy()
            adv = gae(buf_rew, buf_val, buf_done, last_val, cfg.gamma, cfg.gae_lambda)
            ret = adv + buf_val

            # ---- PPO update on the flattened (step, follower) samples
            b_x = torch.as_tensor(buf_x.reshape(-1, obs_dim))
            b_c = torch.cat(buf_crit)
            b_a = torch.as_tensor(buf_act.reshape(-1, 2))
            b_logp = torch.as_tensor(buf_logp.reshape(-1))
            b_adv = torch.as_tensor(adv.reshape(-1), dtype=torch.float32)
            b_ret = torch.as_tensor(ret.reshape(-1), dtype=torch.float32)
            size = b_x.shape[0]
            mb = max(1, size // cfg.n_minibatches)
            stats = []
            ratio0 = None  # the first minibatch's ratio: exactly 1 before any update (checked by the tests)
            for _epoch in range(cfg.n_epochs):
                order = torch.randperm(size, generator=gen)
                for start in range(0, size, mb):
                    idx = order[start:start + mb]
                    mean = actor(b_x[idx])
                    dist = torch.distributions.Normal(mean, log_std.exp().expand_as(mean))
                    logp = dist.log_prob(b_a[idx]).sum(-1)
                    ratio = (logp - b_logp[idx]).exp()
                    if ratio0 is None:
                        ratio0 = float((ratio.detach() - 1.0).abs().max())
                    a = b_adv[idx]
                    a = (a - a.mean()) / (a.std() + 1e-8)
                    pg = -torch.min(ratio * a, ratio.clamp(1 - cfg.clip_range, 1 + cfg.clip_range) * a).mean()
                    v_loss = 0.5 * (critic(b_c[idx]).squeeze(-1) - b_ret[idx]).pow(2).mean()
                    entropy = dist.entropy().sum(-1).mean()
                    loss = pg + cfg.vf_coef * v_loss - cfg.ent_coef * entropy
                    optim.zero_grad()
                    loss.backward()
                    torch.nn.utils.clip_grad_norm_(params, cfg.max_grad_norm)
                    optim.step()
                    stats.append((pg.item(), v_loss.item(), entropy.item()))
            steps_done += batch
            bar.update(batch)
            s = np.mean(stats, axis=0)
            train_csv.writerow([steps_done, round(time.perf_counter() - t0, 1), f"{s[0]:.5f}", f"{s[1]:.5f}", f"{s[2]:.4f}",
                                f"{float(log_std.detach().exp().mean()):.4f}", f"{buf_rew.mean():.5f}", f"{contacts / batch:.5f}", f"{ratio0:.2e}"])
            train_log.flush()
            if next_eval is not None and steps_done >= next_eval:
                next_eval += cfg.eval_every
                evaluate_and_keep()
    finally:
        bar.close()
        train_log.close()
        for e in envs:
            e.close()
    if not history or history[-1]["agent_steps"] != steps_done:
        evaluate_and_keep()
    wall = time.perf_counter() - t0
    save_run_policy(run_dir, actor, log_std, critic, obs_rms, state_rms, cfg)
    summary = {"agent_steps": steps_done, "wall_s": round(wall, 1), "steps_per_s": round(steps_done / wall, 1),
               "best_score": best, "final": history[-1]}
    (run_dir / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    from baselines.plots import plot_learning_curve

    plot_learning_curve(run_dir / "eval.csv", run_dir / "learning_curve.png", title=run_dir.name)
    return run_dir


def build_parser() -> argparse.ArgumentParser:
    from baselines.config import add_dataclass_options

    parser = argparse.ArgumentParser(prog="python -m baselines.mappo", description=__doc__.split("\n\n")[0])
    add_dataclass_options(parser, MAPPOConfig)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = vars(build_parser().parse_args(argv))
    if "env_kwargs" in args:
        args["env_kwargs"] = dict(args["env_kwargs"])
    try:
        cfg = MAPPOConfig(**args)
        run = train(cfg)
    except (TypeError, ValueError, FileExistsError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(run)
    print((run / "summary.json").read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
