"""Where the reward comes from: each reward term of the infos (``reward_<term>``) per agent-step, by policy.

Run: ``OPENBLAS_NUM_THREADS=1 python benchmarks/reward_terms.py [--episodes 20] [--reward v1]``.
For each policy it plays ``random`` (default knobs) on seeds 1000.. and prints the mean of every
term per agent-step, the share of the penalty that contacts and onsets make up, the fraction of
agent-steps spent in contact and the fraction of those the reward penalises. The figures in
``SwarmEnv``'s docstring ("Rewards (v1)") come from this script.
"""

from __future__ import annotations

import argparse

import numpy as np

import swarm_env
from swarm_env.harness.policies import load_policy
from swarm_env.scoring.rewards import CONTACT_GROUPS, REWARD_TERMS, contact_counts, reward_terms


def measure(policy_name: str, reward: str, seeds: range) -> dict[str, float]:
    sums = dict.fromkeys(REWARD_TERMS, 0.0)
    steps = contact_steps = penalised = 0
    for seed in seeds:
        env = swarm_env.parallel_env("random", reward=reward)
        obs, _ = env.reset(seed=seed)
        policy = load_policy(policy_name, env)
        policy.reset(env, seed)
        while env.agents:
            obs, _, _, _, infos = env.step(policy.act(obs, env.world_state()))
            for info in infos.values():
                terms = reward_terms(info)
                for t, v in terms.items():
                    sums[t] += v
                touching = sum(contact_counts(info).values()) > 0
                contact_steps += touching
                charged = terms["collision"] < 0 or any(terms[f"contact_{g}"] < 0 for g in CONTACT_GROUPS)
                penalised += touching and charged
                steps += 1
    out = {t: v / steps for t, v in sums.items()}
    penalty = -sum(v for v in out.values() if v < 0)
    contact = -(out["collision"] + sum(out[f"contact_{g}"] for g in CONTACT_GROUPS))
    out["contact_share"] = contact / penalty if penalty else 0.0
    out["formation_share"] = -out["formation"] / penalty if penalty else 0.0
    out["contact_steps"] = contact_steps / steps
    out["penalised_contact_steps"] = penalised / contact_steps if contact_steps else float("nan")
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--reward", default="v1", choices=["v1", "v0"])
    parser.add_argument("--policies", nargs="+", default=["pursuit", "vo", "zero"])
    args = parser.parse_args()
    seeds = range(1000, 1000 + args.episodes)
    cols = [t for t in REWARD_TERMS] + ["contact_share", "formation_share", "contact_steps", "penalised_contact_steps"]
    print(f"reward {args.reward}, random seeds {seeds.start}-{seeds.stop - 1}, per agent-step")
    print("| policy | " + " | ".join(cols) + " |")
    print("|---" * (len(cols) + 1) + "|")
    for name in args.policies:
        row = measure(name, args.reward, seeds)
        print(f"| {name} | " + " | ".join(f"{row[c]:.4f}" if np.isfinite(row[c]) else "n/a" for c in cols) + " |")


if __name__ == "__main__":
    main()
