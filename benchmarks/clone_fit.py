"""How well can an observation-only network fit the ``vo`` expert? A behaviour-cloning diagnostic.

    OPENBLAS_NUM_THREADS=1 python benchmarks/clone_fit.py                 # 128x128 and 512x512x512, ~2.5 min

Plays ``vo`` on ``random`` worlds (training seeds 10000-10059, held-out 10060-10074: the DAgger
warm start's seed range), records every follower's observation and ``vo``'s normalised action,
fits an MLP of each requested size with DAgger's own fitting (:func:`swarm_env_baselines.imitation.fit`)
and prints the training and held-out MSE. A held-out error that does not fall with capacity says
the clone's limit is not the network's size.
"""

from __future__ import annotations

import argparse
import time


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--train-worlds", type=int, default=60)
    parser.add_argument("--test-worlds", type=int, default=15)
    parser.add_argument("--epochs", type=int, default=20)
    parser.add_argument("--hidden", nargs="+", default=["128,128", "512,512,512"], help="layer sizes, one net each")
    args = parser.parse_args()

    import torch

    from swarm_env.env import SwarmEnv
    from swarm_env.harness.policies import load_policy
    from swarm_env_baselines.imitation import DaggerSettings, fit, rollouts
    from swarm_env_baselines.ppo_core import RunningMeanStd, mlp

    torch.set_num_threads(1)
    torch.manual_seed(0)
    env = SwarmEnv("random")
    expert = load_policy("vo", env)
    t0 = time.perf_counter()
    # The expert drives (no student): the samples of DAgger's first round.
    x_train, y_train = rollouts(env, expert, list(range(10_000, 10_000 + args.train_worlds)), None)
    held = 10_000 + args.train_worlds
    x_test, y_test = rollouts(env, expert, list(range(held, held + args.test_worlds)), None)
    print(f"{len(x_train):,} training and {len(x_test):,} held-out samples in {time.perf_counter() - t0:.0f} s")
    rms = RunningMeanStd((x_train.shape[1],))
    rms.update(x_train)
    settings = DaggerSettings(epochs=args.epochs)
    xtr, ytr = torch.as_tensor(rms.normalize(x_train)).float(), torch.as_tensor(y_train)
    xte, yte = torch.as_tensor(rms.normalize(x_test)).float(), torch.as_tensor(y_test)
    for spec in args.hidden:
        hidden = [int(h) for h in spec.split(",")]
        net = mlp([xtr.shape[1], *hidden, 2])
        t0 = time.perf_counter()
        fit(net, rms, x_train, y_train, settings, torch.Generator().manual_seed(0))  # DAgger's own fitting
        with torch.no_grad():
            mse_train = (net(xtr) - ytr).pow(2).sum(-1).mean().item()
            mse_test = (net(xte) - yte).pow(2).sum(-1).mean().item()
        print(f"hidden {spec:>12s}: training MSE {mse_train:.4f}, held-out MSE {mse_test:.4f} "
              f"({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
