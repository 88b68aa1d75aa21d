"""RL baselines for swarm-env (torch, stable-baselines3): training, imitation, evaluation.

Installed as ``swarm_env_baselines`` (the repository keeps it in ``baselines/``; ``baselines`` is
OpenAI Baselines' import name). Its dependencies come with the ``rl`` extra
(``pip install 'swarm-env[rl]'``). Modules, one job each:

* :mod:`swarm_env_baselines.ppo_core`, :mod:`swarm_env_baselines.mappo`, :mod:`swarm_env_baselines.imitation` —
  ``swarm-env train mappo``: MAPPO/IPPO in PyTorch (shared actor, central or local critic), a DAgger warm
  start, the VO safety layer as executor or teacher, residual policies.
* :mod:`swarm_env_baselines.mappo_policy` — MAPPO runs and the shipped methods (``ippo``, ``mappo``,
  ``mappo_shielded``, ``mappo_shielded_bare``, ``residual_vo``) as policies, from tensors + JSON.
* :mod:`swarm_env_baselines.ship` — ``swarm-env ship``: a finished run into ``checkpoints/<method>/s<k>``
  with its records and README.
* :mod:`swarm_env_baselines.vec_env` — our SB3 ``VecEnv`` bridge: M env copies as M x N
  sub-environments with parameter sharing, seeded through SB3, with correct
  truncation info, optionally in subprocesses.
* :mod:`swarm_env_baselines.config`, :mod:`swarm_env_baselines.train`, :mod:`swarm_env_baselines.callbacks`,
  :mod:`swarm_env_baselines.plots` — ``swarm-env train sb3``: a typed config, run
  directories, evaluation on validation seeds, checkpoints, learning curves.
* :mod:`swarm_env_baselines.demos`, :mod:`swarm_env_baselines.bc` — cached expert demonstrations
  (``swarm-env demos``) and behaviour cloning + DAgger into PPO's policy
  network (``swarm-env bc``).
* :mod:`swarm_env_baselines.model_io` — saved models as the ``ppo``, ``bc`` and ``sac``
  policies of the ``swarm_env.policies`` registry.
* :mod:`swarm_env_baselines.evaluate` — ``python -m swarm_env_baselines.evaluate``, the leaderboard
  command (the same as ``swarm-env evaluate``).

Nothing here is imported by ``swarm_env_agents`` or by the simulation core (``tests/test_layout.py`` checks the
core); the harness finds the policies through their entry points and `swarm-env` its commands by module name.
"""
