"""swarm-env in AgileRL: IPPO with one network shared by the followers, a custom training loop.

Run (after the heavy extra, see docs/clients.md)::

    python examples/agilerl_ippo.py                          # paper_vo_0, 10 updates
    python examples/agilerl_ippo.py --scenario random --updates 50 --num-envs 4

AgileRL groups agents by name prefix, so ``follower_0 ... follower_{N-1}`` share one actor and
one critic (the group ``"follower"``). The loop below is AgileRL's on-policy multi-agent loop
(``agilerl.training.train_multi_agent_on_policy``) without the evolutionary part: collect
``learn_step`` steps from an ``AsyncPettingZooVecEnv`` (one subprocess per env copy), clip the
Gaussian actions to the action box, then ``IPPO.learn``. It checks every action is finite
before the env sees it (swarm-env raises ``ValueError`` on NaN actions).
"""

from __future__ import annotations

import argparse
from functools import partial
from typing import Any

import numpy as np

import swarm_env


def main(
    scenario: str = "paper_vo_0",
    updates: int = 10,
    num_envs: int = 2,
    learn_step: int = 512,
    batch_size: int = 128,
    update_epochs: int = 4,
    hidden: int = 64,
    seed: int = 0,
    **env_kwargs: Any,
) -> dict[str, Any]:
    """Run ``updates`` IPPO updates of ``learn_step`` steps each; return the agent and statistics."""
    import torch
    from agilerl.algorithms import IPPO
    from agilerl.vector.pz_async_vec_env import AsyncPettingZooVecEnv

    torch.manual_seed(seed)
    vec = AsyncPettingZooVecEnv([partial(swarm_env.parallel_env, scenario, **env_kwargs) for _ in range(num_envs)])
    agent_ids = list(vec.possible_agents)
    agent = IPPO(
        observation_spaces=[vec.single_observation_space(a) for a in agent_ids],
        action_spaces=[vec.single_action_space(a) for a in agent_ids],
        agent_ids=agent_ids,
        batch_size=batch_size,
        learn_step=learn_step,
        update_epochs=update_epochs,
        net_config={"encoder_config": {"hidden_size": [hidden]}, "head_config": {"hidden_size": [hidden]}},
        device="cpu",
    )
    low, high = vec.single_action_space(agent_ids[0]).low, vec.single_action_space(agent_ids[0]).high

    losses: list[float] = []
    rewards_seen: list[np.ndarray] = []
    steps = 0
    obs, info = vec.reset(seed=seed)
    try:
        for _ in range(updates):
            fields = ("states", "actions", "log_probs", "rewards", "dones", "values")
            rollout: dict[str, dict[str, list]] = {f: {a: [] for a in agent_ids} for f in fields}
            done = {a: np.zeros(num_envs) for a in agent_ids}
            for _ in range(-(learn_step // -num_envs)):  # ceil(learn_step / num_envs) vector steps
                action, log_prob, _entropy, value = agent.get_action(obs=obs, infos=info)
                for a, act in action.items():
                    if not np.isfinite(act).all():
                        raise FloatingPointError(f"IPPO produced a non-finite action for {a}: {act}")
                clipped = {a: np.clip(act, low, high) for a, act in action.items()}
                next_obs, reward, termination, truncation, info = vec.step(clipped)
                for a in obs:
                    for f, v in zip(fields, (obs[a], action[a], log_prob[a], reward[a], done[a], value[a])):
                        rollout[f][a].append(v)
                rewards_seen.append(np.column_stack([np.asarray(reward[a]).ravel() for a in agent_ids]))
                done = {a: np.logical_or(termination[a], truncation[a]).astype(float) for a in termination}
                obs = next_obs
                steps += num_envs
            loss = agent.learn((*(rollout[f] for f in fields), next_obs, done))
            losses.append(float(np.mean(list(loss.values()))))
    finally:
        vec.close()
    return {"agent": agent, "losses": losses, "rewards": np.concatenate(rewards_seen), "steps": steps}


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="paper_vo_0")
    parser.add_argument("--updates", type=int, default=10)
    parser.add_argument("--num-envs", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    out = main(args.scenario, updates=args.updates, num_envs=args.num_envs, seed=args.seed)
    print(f"{args.scenario}: {out['steps']} vector-env steps, mean reward {out['rewards'].mean():.3f}, "
          f"losses {[round(x, 3) for x in out['losses']]}")
