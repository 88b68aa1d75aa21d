"""swarm-env in BenchMARL: a custom task class, trained with MAPPO.

Run (after the heavy extra and ``pip install --no-deps benchmarl==1.5.2``, see docs/clients.md)::

    python examples/benchmarl_mappo.py                          # paper_vo_0, 3 iterations
    python examples/benchmarl_mappo.py --scenario corridor --iterations 10 --max-cycles 300

BenchMARL runs TorchRL envs; :class:`SwarmEnvTask` builds a ``PettingZooWrapper`` around
``swarm_env.parallel_env`` (one agent group ``"follower"``, the global ``state`` for MAPPO's
centralised critic, the reset-info keys as ``("follower", "info", key)``). The followers share
one policy (``share_policy_params``, BenchMARL's default). BenchMARL 1.5.2 imports
``torchrl.collectors.SyncDataCollector``, which TorchRL 0.13 renamed ``Collector``; the alias
below restores the old name (a no-op on TorchRL <= 0.12).
"""

from __future__ import annotations

import argparse
import itertools
import tempfile
from collections.abc import Callable
from typing import Any

import numpy as np
import torchrl.collectors

if not hasattr(torchrl.collectors, "SyncDataCollector"):  # TorchRL >= 0.13 renamed it
    torchrl.collectors.SyncDataCollector = torchrl.collectors.Collector

from benchmarl.environments.common import TaskClass  # noqa: E402
from torchrl.data import Composite  # noqa: E402
from torchrl.envs import EnvBase, PettingZooWrapper  # noqa: E402

import swarm_env  # noqa: E402


def _only(spec: Composite, groups: list[str], key: str) -> Composite:
    """``spec`` with each group reduced to its ``key`` entry and the global ``state`` removed."""
    spec = spec.clone()
    for group in groups:
        for k in list(spec[group].keys()):
            if k != key:
                del spec[group][k]
    if "state" in spec.keys():  # a TorchRL Composite: keys() lists its entries
        del spec["state"]
    return spec


class SwarmEnvTask(TaskClass):
    """A BenchMARL task for any swarm-env scenario.

    ``config``: ``scenario`` (a ``swarm_env.list_scenarios()`` name or a YAML path) plus any
    ``swarm_env.parallel_env`` keyword (``max_cycles``, ``n_followers``, ``team_seed``, ...).
    """

    def get_env_fun(self, num_envs: int, continuous_actions: bool, seed: int | None, device) -> Callable[[], EnvBase]:
        kwargs = dict(self.config)
        scenario = kwargs.pop("scenario")
        kwargs["action_type"] = "continuous" if continuous_actions else "discrete"
        # BenchMARL calls the factory once per SerialEnv copy with the same experiment seed: each copy takes
        # its own seed stream (child i of the seed's SeedSequence), or all copies would play the same world
        # at every reset of a random scenario.
        streams = np.random.SeedSequence(seed) if seed is not None else None
        copies = itertools.count()

        def make() -> EnvBase:
            copy_seed = None
            if streams is not None:
                copy_seed = int(np.random.SeedSequence(streams.entropy, spawn_key=(next(copies),)).generate_state(1)[0])
            env = swarm_env.parallel_env(scenario, **kwargs)
            return PettingZooWrapper(env, return_state=True, seed=copy_seed, device=device, categorical_actions=True)

        return make  # not vectorised: BenchMARL runs num_envs of these in a SerialEnv

    def supports_continuous_actions(self) -> bool:
        return True

    def supports_discrete_actions(self) -> bool:
        return True

    def has_render(self, env: EnvBase) -> bool:
        return False

    def max_steps(self, env: EnvBase) -> int:
        return env.base_env.max_steps  # the ParallelEnv's truncation step (TorchRL forwards the attribute)

    def group_map(self, env: EnvBase) -> dict[str, list[str]]:
        return env.group_map

    def observation_spec(self, env: EnvBase) -> Composite:
        return _only(env.observation_spec, list(self.group_map(env)), "observation")

    def info_spec(self, env: EnvBase) -> Composite | None:
        return _only(env.observation_spec, list(self.group_map(env)), "info")

    def state_spec(self, env: EnvBase) -> Composite | None:
        return Composite({"state": env.observation_spec["state"].clone()})

    def action_spec(self, env: EnvBase) -> Composite:
        return env.full_action_spec

    def action_mask_spec(self, env: EnvBase) -> Composite | None:
        return None

    @staticmethod
    def env_name() -> str:
        return "swarm_env"


def build_experiment(
    scenario: str = "paper_vo_0",
    iterations: int = 3,
    frames_per_batch: int = 2000,
    n_envs: int = 4,
    minibatch_size: int = 400,
    minibatch_iters: int = 4,
    seed: int = 0,
    save_folder: str | None = None,
    **env_kwargs: Any,
):
    """A BenchMARL MAPPO ``Experiment`` of ``iterations`` iterations of ``frames_per_batch`` frames."""
    from benchmarl.algorithms import MappoConfig
    from benchmarl.experiment import Experiment, ExperimentConfig
    from benchmarl.models.mlp import MlpConfig

    config = ExperimentConfig.get_from_yaml()  # BenchMARL's defaults, then a small CPU budget
    config.sampling_device = config.train_device = config.buffer_device = "cpu"
    config.max_n_iters, config.max_n_frames = iterations, None
    config.on_policy_collected_frames_per_batch = frames_per_batch
    config.on_policy_n_envs_per_worker = n_envs
    config.on_policy_minibatch_size = minibatch_size
    config.on_policy_n_minibatch_iters = minibatch_iters
    config.evaluation = False
    config.render = False
    config.loggers = []
    config.create_json = False
    config.checkpoint_interval = 0
    config.checkpoint_at_end = False
    config.save_folder = save_folder or tempfile.mkdtemp(prefix="benchmarl_swarm_")

    task = SwarmEnvTask(name=scenario, config={"scenario": scenario, **env_kwargs})
    return Experiment(
        task=task,
        algorithm_config=MappoConfig.get_from_yaml(),
        model_config=MlpConfig.get_from_yaml(),
        critic_model_config=MlpConfig.get_from_yaml(),
        seed=seed,
        config=config,
    )


def main(scenario: str = "paper_vo_0", iterations: int = 3, **kwargs: Any):
    """Build the experiment (``kwargs``: see :func:`build_experiment`), run it, return it."""
    experiment = build_experiment(scenario, iterations=iterations, **kwargs)
    experiment.run()
    return experiment


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="paper_vo_0")
    parser.add_argument("--iterations", type=int, default=3)
    parser.add_argument("--max-cycles", type=int, default=250, help="episode length (steps)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    # 2000 frames per iteration over 4 envs = 500 steps per env: short episodes so that some end
    exp = main(args.scenario, iterations=args.iterations, seed=args.seed, max_cycles=args.max_cycles)
    print(f"{args.scenario}: {exp.n_iters_performed} MAPPO iterations, {exp.total_frames} frames, "
          f"last mean return {exp.mean_return:.2f}; logs in {exp.folder_name}")
