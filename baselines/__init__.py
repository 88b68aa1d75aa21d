"""RL baselines for swarm-env (stable-baselines3): training, imitation, evaluation.

Installed with the ``rl`` extra (``pip install -e '.[rl]'``).
"""
