"""RL baselines for swarm-env (torch, stable-baselines3): training, imitation, evaluation.

Installed with the ``rl`` extra (``pip install -e '.[rl]'``). Modules, one job each:

* :mod:`baselines.ppo_core`, :mod:`baselines.mappo`, :mod:`baselines.imitation` — ``python -m
  baselines.mappo``: MAPPO/IPPO in PyTorch (shared actor, central or local critic), a DAgger warm
  start, the VO safety layer as executor or teacher, residual policies.
* :mod:`baselines.mappo_policy` — MAPPO runs and the shipped methods (``ippo``, ``mappo``,
  ``mappo_shielded``, ``mappo_shielded_bare``, ``residual_vo``) as policies, from tensors + JSON.
* :mod:`baselines.ship` — ``python -m baselines.ship``: a finished run into ``checkpoints/<method>/s<k>``
  with its records and README.
* :mod:`baselines.vec_env` — our SB3 ``VecEnv`` bridge: M env copies as M x N
  sub-environments with parameter sharing, seeded through SB3, with correct
  truncation info, optionally in subprocesses.
* :mod:`baselines.config`, :mod:`baselines.train`, :mod:`baselines.callbacks`,
  :mod:`baselines.plots` — ``python -m baselines.train``: a typed config, run
  directories, evaluation on validation seeds, checkpoints, learning curves.
* :mod:`baselines.demos`, :mod:`baselines.bc` — cached expert demonstrations
  (``python -m baselines.demos``) and behaviour cloning + DAgger into PPO's policy
  network (``python -m baselines.bc``).
* :mod:`baselines.model_io` — saved models as the ``ppo``, ``bc`` and ``sac``
  policies of the ``swarm_env.policies`` registry.
* :mod:`baselines.evaluate` — ``python -m baselines.evaluate``, the leaderboard
  command (the same as ``swarm-env evaluate``).

Nothing here is imported by ``swarm_env`` or ``agents`` (see DESIGN.md).
"""
