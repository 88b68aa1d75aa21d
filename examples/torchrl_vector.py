"""The batched engine in TorchRL: one ``EnvBase`` with ``batch_size=[M]`` over ``SwarmVectorEnv``.

Run (after ``pip install -e '.[dev]'``, which brings torchrl)::

    python examples/torchrl_vector.py                          # 16 random worlds, 100 steps
    python examples/torchrl_vector.py --worlds 64 --steps 50

:class:`SwarmVectorTorchRL` keeps the engine's arrays and only turns them into tensors: the
followers of a world are the group ``"agents"`` (shape ``(M, N, ...)``, like VMAS's TorchRL
environments), the global state is ``"state"`` ``(M, S)``, and ``done``/``terminated``/``truncated``
are per world ``(M, 1)``. The engine resets a finished world in the same step; TorchRL wants the
last observation in ``"next"`` and the new episode's first from a later ``reset`` with a ``"_reset"``
mask: the adapter hands TorchRL the engine's ``final_obs`` and keeps the new first observation for
that reset. Resetting a world that has not finished is not supported (reset them all instead).
"""

from __future__ import annotations

import argparse
from typing import Any

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from swarm_env.vector.engine import SwarmVectorEnv


class SwarmVectorTorchRL(EnvBase):
    """``M`` swarm_env worlds as one TorchRL environment of batch size ``[M]`` (module docstring).

    Args: ``scenario``, ``num_envs`` and ``**kwargs`` as for :class:`swarm_env.vector.engine.SwarmVectorEnv`
    (``n_procs`` included).
    """

    def __init__(self, scenario: str = "random", num_envs: int = 8, **kwargs: Any) -> None:
        self.engine = SwarmVectorEnv(scenario, num_envs, **kwargs)
        m, n = self.engine.num_envs, self.engine.num_agents
        super().__init__(batch_size=torch.Size([m]), device="cpu")
        obs = self.engine.single_observation_space
        state = self.engine.state_space
        self.observation_spec = Composite(
            agents=Composite(observation=Bounded(torch.as_tensor(np.broadcast_to(obs.low, (m, n, *obs.shape)).copy()),
                                                 torch.as_tensor(np.broadcast_to(obs.high, (m, n, *obs.shape)).copy()),
                                                 shape=(m, n, *obs.shape), dtype=torch.float32), shape=(m, n)),
            state=Bounded(float(state.low.min()), float(state.high.max()), shape=(m, *state.shape), dtype=torch.float32),
            shape=(m,),
        )
        self.action_spec = Composite(agents=Composite(action=Bounded(-1.0, 1.0, shape=(m, n, 2), dtype=torch.float32),
                                                      shape=(m, n)), shape=(m,))
        self.reward_spec = Composite(agents=Composite(reward=Unbounded(shape=(m, n, 1), dtype=torch.float32),
                                                      shape=(m, n)), shape=(m,))
        self.done_spec = Composite({k: Categorical(2, shape=(m, 1), dtype=torch.bool)
                                    for k in ("done", "terminated", "truncated")}, shape=(m,))
        self._seed: int | None = None
        self._pending: dict[int, np.ndarray] = {}  # world -> first observation of its next episode
        self._started = False

    def _set_seed(self, seed: int | None) -> None:
        self._seed = seed

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs: Any) -> TensorDictBase:
        mask = None if tensordict is None or "_reset" not in tensordict.keys() else tensordict["_reset"].reshape(-1).numpy()
        if not self._started or mask is None:
            obs, _ = self.engine.reset(seed=self._seed)
            self._seed = None  # later full resets continue each world's generator
            self._pending.clear()
            self._started = True
            self._obs = obs
        else:
            for m in np.flatnonzero(mask).tolist():
                if m not in self._pending:
                    raise NotImplementedError(f"world {m} has not finished: only finished worlds can be reset alone")
                self._obs[m] = self._pending.pop(m)
        return self._td(self._obs, done=np.zeros(self.engine.num_envs, dtype=bool))

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        actions = tensordict["agents", "action"].detach().cpu().numpy()
        obs, rewards, terminated, truncated, infos = self.engine.step(actions)
        shown = obs
        if "_final" in infos:
            shown = obs.copy()
            for m in np.flatnonzero(infos["_final"]).tolist():
                self._pending[m] = obs[m].copy()
                shown[m] = infos["final_obs"][m]
        self._obs = obs
        out = self._td(shown, terminated | truncated, terminated, truncated)
        out.set(("agents", "reward"), torch.as_tensor(rewards, dtype=torch.float32).unsqueeze(-1))
        return out

    def _td(self, obs: np.ndarray, done: np.ndarray, terminated: np.ndarray | None = None,
            truncated: np.ndarray | None = None) -> TensorDict:
        m, n = self.engine.num_envs, self.engine.num_agents
        flags = {"done": done, "terminated": done if terminated is None else terminated,
                 "truncated": np.zeros_like(done) if truncated is None else truncated}
        return TensorDict(
            {"agents": TensorDict({"observation": torch.as_tensor(obs)}, batch_size=[m, n]),
             "state": torch.as_tensor(self.engine.state()),
             **{k: torch.as_tensor(v).reshape(m, 1) for k, v in flags.items()}},
            batch_size=[m],
        )

    def close(self, *, raise_if_closed: bool = True) -> None:
        self.engine.close()
        super().close(raise_if_closed=raise_if_closed)


def main(worlds: int = 16, steps: int = 100, seed: int = 0, **kwargs: Any) -> TensorDictBase:
    """Roll out ``steps`` random steps of ``worlds`` random worlds and return the TensorDict."""
    from torchrl.envs.utils import check_env_specs

    env = SwarmVectorTorchRL("random", worlds, **kwargs)
    env.set_seed(seed)
    check_env_specs(env)
    torch.manual_seed(seed)
    rollout = env.rollout(steps, break_when_any_done=False)
    env.close()
    return rollout


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--worlds", type=int, default=16)
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    td = main(args.worlds, args.steps, args.seed)
    reward = td["next", "agents", "reward"]
    print(td)
    print(f"{args.worlds} worlds x {args.steps} steps x {reward.shape[2]} followers, mean reward "
          f"{reward.mean().item():.3f}, episodes ended: {int(td['next', 'done'].sum())}")
