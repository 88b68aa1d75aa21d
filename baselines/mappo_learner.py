"""MAPPO's update: PPO on one rollout, in the training process or in a learner process of its own.

:func:`ppo_update` is the update of one rollout (:class:`Batch`) by a set of :class:`Networks`. The trainer
(:mod:`swarm_env_baselines.mappo`) calls it in its own process, after each rollout (``learner_process=False``),
or hands each rollout to a :class:`ProcessLearner`: a second interpreter (``python -m
swarm_env_baselines.mappo_learner``) holding its own copy of the networks, the optimiser and the generator of
the minibatch order, which updates on rollout ``k`` while the trainer collects rollout ``k + 1`` on the other
core, then sends the new parameters back. Rollout ``k + 1`` is therefore drawn by the networks of one update
before (a policy lag of one update, as in Sample Factory's APPO; PPO's ratio is taken against the policy that
drew the actions, so ``first_ratio_error`` in ``train.csv`` measures the lag). The learner process computes the
rollout's values itself, with the critic it updates next.

Both ways are deterministic for a seed; they differ from each other (the lag, and a generator of their own for
the learner process's minibatch order).
"""

from __future__ import annotations

import json
import sys
import time
import traceback
import types
from dataclasses import dataclass, field, fields
from typing import Any, Protocol

import numpy as np

from swarm_env.worker_process import connect, start_worker
from swarm_env_baselines.ppo_core import explained_variance, gae, mlp, ppo_policy_loss, ratio_stats

__all__ = ["Batch", "Networks", "ProcessLearner", "UpdateConfig", "build_networks", "ppo_update"]

#: Seed offset of the learner process's minibatch-order generator (the trainer's own draws the actions).
LEARNER_SEED_OFFSET = 1_000_003


class UpdateConfig(Protocol):
    """The fields of :class:`~swarm_env_baselines.mappo.MAPPOConfig` that the networks and the update read."""

    hidden: tuple[int, ...]
    residual: str | None
    log_std_init: float
    gamma: float
    gae_lambda: float
    clip_range: float
    n_epochs: int
    n_minibatches: int
    ent_coef: float
    vf_coef: float
    max_grad_norm: float
    imitation_coef: float
    imitation_anneal: float
    critic_warmup: int
    learning_rate: float
    device: str


@dataclass
class Batch:
    """One rollout of ``T`` steps of ``M`` worlds of ``N`` followers, as the update needs it.

    Arrays keep the ``(T, M, ...)`` axes: the critic's global state is stored once per world-step,
    and the update's minibatches are sets of world-steps (each with its ``N`` followers)."""

    obs: np.ndarray  # (T, M, N, D) actor inputs, normalised as when the actions were drawn
    states: np.ndarray  # (T, M, S) critic states, normalised likewise (S = 1 and unused for IPPO)
    actions: np.ndarray  # (T, M, N, 2) sampled actions (before clipping)
    logp: np.ndarray  # (T, M, N)
    values: np.ndarray  # (T, M, N)
    rewards: np.ndarray  # (T, M, N) scaled, truncation bootstraps folded in
    dones: np.ndarray  # (T, M) the world's episode ended after this step
    safe: np.ndarray  # (T, M, N, 2) the shield's actions (teach/execute)
    intervened: np.ndarray  # (T, M, N) float 0/1
    contacts: int = 0
    #: The episodes that ended in this rollout: their return (raw reward summed, mean over followers)
    #: and final metrics (collisions, formation error).
    episode_returns: list[float] = field(default_factory=list)
    episode_metrics: list[dict[str, Any]] = field(default_factory=list)

    @classmethod
    def empty(cls, t: int, m: int, n: int, d: int, s: int) -> Batch:
        f32 = np.float32
        return cls(np.zeros((t, m, n, d), f32), np.zeros((t, m, s), f32), np.zeros((t, m, n, 2), f32),
                   np.zeros((t, m, n), f32), np.zeros((t, m, n), f32), np.zeros((t, m, n)), np.zeros((t, m)),
                   np.zeros((t, m, n, 2), f32), np.zeros((t, m, n), f32))

    def arrays(self) -> dict[str, np.ndarray]:
        """The rollout's arrays by field name (what the update reads; the episode lists stay with the trainer)."""
        return {f.name: getattr(self, f.name) for f in fields(self) if isinstance(getattr(self, f.name), np.ndarray)}

    @staticmethod
    def to_checkpoint(batch: Batch | None) -> tuple[dict[str, Any], dict[str, Any]]:
        """``(tensors, JSON values)`` that keep ``batch`` (a rollout not yet learned from) in a checkpoint:
        ``pending.<field>`` tensors and a ``pending`` entry (None: no such rollout)."""
        import torch

        if batch is None:
            return {}, {"pending": None}
        tensors = {f"pending.{k}": torch.from_numpy(np.ascontiguousarray(v)) for k, v in batch.arrays().items()}
        return tensors, {"pending": {"contacts": batch.contacts, "episode_returns": batch.episode_returns,
                                     "episode_metrics": batch.episode_metrics}}

    @classmethod
    def from_checkpoint(cls, tensors: dict[str, Any], meta: dict[str, Any], source: Any) -> Batch | None:
        """The rollout :meth:`to_checkpoint` kept (None if none); ``ValueError`` naming ``source`` if it is
        incomplete."""
        pending = meta.get("pending")
        if pending is None:
            return None
        try:
            arrays = {f.name: tensors[f"pending.{f.name}"].numpy() for f in fields(cls)
                      if f.name not in ("contacts", "episode_returns", "episode_metrics")}
            return cls(**arrays, contacts=int(pending["contacts"]), episode_returns=list(pending["episode_returns"]),
                       episode_metrics=list(pending["episode_metrics"]))
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise ValueError(f"{source}: the checkpoint's pending rollout is incomplete ({exc})") from None


@dataclass
class Networks:
    """The actor, its log standard deviation and the critic, on ``device``."""

    actor: Any
    critic: Any
    log_std: Any
    device: Any

    def parameters(self) -> list[Any]:
        """Everything the optimiser trains: the actor, its log standard deviation, the critic."""
        return [*self.actor.parameters(), self.log_std, *self.critic.parameters()]

    def tensor(self, x: np.ndarray) -> Any:
        """A numpy array as a tensor on the networks' device (no copy on the CPU)."""
        import torch

        return torch.from_numpy(x).to(self.device)

    def value(self, obs: np.ndarray, states: np.ndarray) -> np.ndarray:
        """The critic's values ``(K, N)`` of normalised inputs ``(K, N, D)`` and states ``(K, S)``."""
        import torch

        with torch.no_grad():
            return self.critic(self.tensor(states), self.tensor(obs)).cpu().numpy()

    def tensors(self) -> dict[str, np.ndarray]:
        """The parameters as CPU arrays, named ``actor.*``, ``critic.*`` and ``log_std``."""
        out = {f"actor.{k}": v.detach().cpu().numpy() for k, v in self.actor.state_dict().items()}
        out.update({f"critic.{k}": v.detach().cpu().numpy() for k, v in self.critic.state_dict().items()})
        out["log_std"] = self.log_std.detach().cpu().numpy()
        return out

    def load(self, tensors: dict[str, np.ndarray]) -> None:
        """Set the parameters to :meth:`tensors`' output (every name, no other)."""
        import torch

        self.actor.load_state_dict({k[6:]: torch.from_numpy(v) for k, v in tensors.items() if k.startswith("actor.")},
                                   strict=True)
        self.critic.load_state_dict({k[7:]: torch.from_numpy(v) for k, v in tensors.items()
                                     if k.startswith("critic.")}, strict=True)
        with torch.no_grad():
            self.log_std.copy_(torch.from_numpy(tensors["log_std"]))


def build_networks(cfg: UpdateConfig, obs_dim: int, state_dim: int, device: Any) -> Networks:
    """Fresh networks from the current torch seed: the actor ``obs_dim -> hidden -> 2``, the critic
    (:func:`~swarm_env_baselines.nets.make_critic`: central when ``state_dim`` > 0), ``log_std`` at
    ``cfg.log_std_init``. A residual actor starts at a zero correction."""
    import torch

    from swarm_env_baselines.nets import make_critic

    actor = mlp([obs_dim, *cfg.hidden, 2])
    critic = make_critic(state_dim, obs_dim, tuple(cfg.hidden))
    if cfg.residual:  # start at the expert: a zero correction
        with torch.no_grad():
            actor[-1].weight.mul_(0.01)
            actor[-1].bias.zero_()
    actor.to(device)
    critic.to(device)
    log_std = torch.nn.Parameter(torch.full((2,), float(cfg.log_std_init), device=device))
    return Networks(actor, critic, log_std, device)


def ppo_update(nets: Networks, optim: Any, gen: Any, cfg: UpdateConfig, batch: Batch, last_val: np.ndarray,
               update_index: int, n_updates: int) -> dict[str, float]:
    """PPO epochs over ``batch`` (minibatch order from ``gen``; the critic alone during ``cfg.critic_warmup``
    updates); ``last_val`` ``(M, N)`` bootstraps the rollout's last step. Minibatches are world-steps, each with
    its ``N`` followers (the critic's state part is computed once per world-step). Returns the update's statistics
    (means over its minibatches)."""
    import torch

    T, m, n, obs_dim = batch.obs.shape
    dones = np.repeat(batch.dones[:, :, None], n, axis=2)
    adv = gae(batch.rewards.reshape(T, -1), batch.values.reshape(T, -1), dones.reshape(T, -1),
              last_val.reshape(-1), cfg.gamma, cfg.gae_lambda).reshape(T, m, n)
    ret = adv + batch.values
    size = T * m
    b_x = nets.tensor(batch.obs.reshape(size, n, obs_dim))
    b_s = nets.tensor(batch.states.reshape(size, -1))
    b_a = nets.tensor(batch.actions.reshape(size, n, 2))
    b_logp = nets.tensor(batch.logp.reshape(size, n))
    b_adv = nets.tensor(adv.reshape(size, n).astype(np.float32))
    b_ret = nets.tensor(ret.reshape(size, n).astype(np.float32))
    b_safe = nets.tensor(batch.safe.reshape(size, n, 2))
    b_int = nets.tensor(batch.intervened.reshape(size, n))
    im_coef = cfg.imitation_coef
    if cfg.imitation_anneal:
        im_coef *= max(0.0, 1.0 - update_index / (cfg.imitation_anneal * n_updates))
    actor_learns = update_index >= cfg.critic_warmup
    params = nets.parameters()
    mb = max(1, size // cfg.n_minibatches)
    stats = []
    ratio0 = None  # the first minibatch's |ratio - 1|: 0 when the rollout's policy is the one updated
    for _epoch in range(cfg.n_epochs):
        order = torch.randperm(size, generator=gen)
        for start in range(0, size, mb):
            idx = order[start:start + mb].to(nets.device)
            mean = nets.actor(b_x[idx])
            dist = torch.distributions.Normal(mean, nets.log_std.exp().expand_as(mean))
            pg, ratio = ppo_policy_loss(dist.log_prob(b_a[idx]).sum(-1).reshape(-1), b_logp[idx].reshape(-1),
                                        b_adv[idx].reshape(-1), cfg.clip_range)
            ratio_err, kl, clipped = ratio_stats(ratio, cfg.clip_range)
            if ratio0 is None:
                ratio0 = ratio_err
            v_loss = 0.5 * (nets.critic(b_s[idx], b_x[idx]) - b_ret[idx]).pow(2).mean()
            entropy = dist.entropy().sum(-1).mean()
            # The imitation term averages over the whole minibatch (zero where the shield let the action
            # pass), so its weight relative to PPO's loss is the intervention rate times imitation_coef.
            im = (b_int[idx] * (mean - b_safe[idx]).pow(2).sum(-1)).sum() / b_int[idx].numel()
            loss = cfg.vf_coef * v_loss
            if actor_learns:
                loss = loss + pg - cfg.ent_coef * entropy + im_coef * im
            optim.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(params, cfg.max_grad_norm)
            optim.step()
            stats.append((pg.item(), v_loss.item(), im.item(), entropy.item(), kl, clipped))
    s = np.mean(stats, axis=0)
    return {"policy_loss": s[0], "value_loss": s[1], "imitation_loss": s[2], "entropy": s[3],
            "approx_kl": s[4], "clip_fraction": s[5],
            "explained_variance": explained_variance(batch.values.ravel(), ret.ravel()),
            "std": float(nets.log_std.detach().exp().mean()), "first_ratio_error": ratio0 or 0.0}


def make_optimizer(cfg: UpdateConfig, nets: Networks) -> Any:
    """The update's Adam (one definition for the trainer and the learner process)."""
    import torch

    return torch.optim.Adam(nets.parameters(), lr=cfg.learning_rate, eps=1e-5)


# --------------------------------------------------------------------------- the learner process


class LearnerError(RuntimeError):
    """The learner process failed; the message holds its traceback."""


class ProcessLearner:
    """The update in a second interpreter, one rollout behind the collection.

    :meth:`submit` sends a rollout (its values left to the learner) and returns at once; :meth:`result` waits
    for that update and loads the new parameters into the trainer's networks. Between the two the trainer
    collects its next rollout. :meth:`state` gives what a checkpoint needs from the process (the optimiser's
    state, loaded into the trainer's optimiser, and the minibatch generator's state).
    """

    def __init__(self, cfg: Any, nets: Networks, optim: Any, gen_state: Any) -> None:
        self._proc, self._conn = start_worker("swarm_env_baselines.mappo_learner")
        self._nets = nets
        self._optim = optim
        self._pending = False
        #: CPU seconds the learner process has used (as of the last :meth:`result`).
        self.cpu_s = 0.0
        config = json.loads(cfg.to_json())  # the fields as JSON values (the learner sees them as attributes)
        self._conn.send(("init", config, nets.tensors(), _arrays(optim.state_dict()), np.asarray(gen_state)))
        self._reply("ready")

    def submit(self, batch: Batch, last: tuple[np.ndarray, np.ndarray], update_index: int, n_updates: int) -> None:
        """Start the update of ``batch`` (``last``: the normalised inputs and states after its last step)."""
        assert not self._pending, "submit() twice without result()"
        self._conn.send(("update", batch.arrays(), *last, update_index, n_updates))
        self._pending = True

    def result(self, batch: Batch) -> dict[str, float]:
        """Wait for the update, load its parameters into the trainer's networks and ``batch.values`` with the
        values it computed; return its statistics."""
        stats, tensors, values, self.cpu_s = self._reply("done")
        self._pending = False
        self._nets.load(tensors)
        batch.values[:] = values
        return stats

    def state(self) -> Any:
        """Load the process's optimiser state into the trainer's optimiser; return its generator's state."""
        import torch

        self._conn.send(("state",))
        optim_state, gen_state = self._reply("state")
        self._optim.load_state_dict(_tensors(optim_state))
        return torch.from_numpy(gen_state)

    def close(self) -> None:
        try:
            self._conn.send(("close",))
        except (OSError, ValueError):
            pass
        self._conn.close()
        try:
            self._proc.wait(timeout=30)
        except Exception:  # noqa: BLE001 - a learner that does not stop is killed
            self._proc.kill()

    def _reply(self, kind: str) -> Any:
        try:
            msg = self._conn.recv()
        except EOFError:
            raise LearnerError(f"the learner process exited (code {self._proc.poll()})") from None
        if msg[0] == "error":
            raise LearnerError(f"the learner process failed:\n{msg[1]}")
        assert msg[0] == kind, msg[0]
        return msg[1] if len(msg) == 2 else msg[1:]


def _serve(conn: Any) -> None:
    """The learner process: ``init``, then ``update``/``state`` requests until ``close``."""
    import signal

    import torch

    # The trainer handles Ctrl-C and SIGTERM (it finishes the update and saves); a signal sent to the whole process
    # group must not kill its learner first. The learner ends when the trainer closes the connection.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    torch.set_num_threads(1)  # the other core collects
    torch.use_deterministic_algorithms(True)
    _, config, tensors, optim_state, gen_state = conn.recv()
    cfg = types.SimpleNamespace(**{**config, "hidden": tuple(config["hidden"])})
    device = torch.device(cfg.device)
    nets = build_networks(cfg, int(tensors["actor.0.weight"].shape[1]), _state_dim(tensors), device)
    nets.load(tensors)
    optim = make_optimizer(cfg, nets)
    optim.load_state_dict(_tensors(optim_state))
    gen = torch.Generator()
    gen.set_state(torch.from_numpy(gen_state))
    conn.send(("ready",))
    while True:
        msg = conn.recv()
        if msg[0] == "close":
            return
        try:
            if msg[0] == "state":
                conn.send(("state", _arrays(optim.state_dict()), gen.get_state().numpy()))
                continue
            _, arrays, last_obs, last_states, update_index, n_updates = msg
            batch = Batch(**arrays)
            batch.values = nets.value(batch.obs, batch.states)  # the critic that is updated next
            stats = ppo_update(nets, optim, gen, cfg, batch, nets.value(last_obs, last_states), update_index,
                               n_updates)
            conn.send(("done", stats, nets.tensors(), batch.values, time.process_time()))
        except Exception:  # noqa: BLE001 - reported to the trainer, which raises it
            conn.send(("error", traceback.format_exc()))
            return


def _arrays(tree: Any) -> Any:
    """``tree`` (dicts, lists, tuples) with its tensors as numpy arrays: what goes over the connection (torch's own
    pickling of tensors would pass them through shared-memory file descriptors)."""
    import torch

    if isinstance(tree, torch.Tensor):
        return tree.detach().cpu().numpy()
    if isinstance(tree, dict):
        return {k: _arrays(v) for k, v in tree.items()}
    if isinstance(tree, (list, tuple)):
        return type(tree)(_arrays(v) for v in tree)
    return tree


def _tensors(tree: Any) -> Any:
    """The inverse of :func:`_arrays`."""
    import torch

    if isinstance(tree, np.ndarray):
        return torch.from_numpy(tree)
    if isinstance(tree, dict):
        return {k: _tensors(v) for k, v in tree.items()}
    if isinstance(tree, (list, tuple)):
        return type(tree)(_tensors(v) for v in tree)
    return tree


def _state_dim(tensors: dict[str, np.ndarray]) -> int:
    """The critic's state size from its parameters (0: a local critic)."""
    weight = tensors.get("critic.state_in.weight")
    return 0 if weight is None else int(weight.shape[1])


def main(argv: list[str] | None = None) -> int:
    """``python -m swarm_env_baselines.mappo_learner ADDRESS`` (started by :class:`ProcessLearner`)."""
    args = sys.argv[1:] if argv is None else argv
    conn = connect(args[0])
    try:
        _serve(conn)
    except (EOFError, OSError):  # the trainer went away
        return 1
    finally:
        conn.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
