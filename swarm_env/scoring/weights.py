"""A reward spec's weights as one float vector: the form the compiled reward kernels read
(:func:`swarm_env.scoring.step_kernel.reward_table`, :func:`swarm_env.vector.batch_kernel.rewards_batch`)."""

from __future__ import annotations

import numpy as np

from swarm_env.scenario import RewardSpec

#: The vector's entries, in order: the weights and margins of :class:`~swarm_env.scenario.RewardSpec`.
WEIGHT_COLUMNS = ("formation", "collision", "contact", "clearance", "clearance_margin", "smoothness", "progress",
                  "approach", "approach_margin")
W_FORMATION, W_COLLISION, W_CONTACT, W_CLEARANCE, W_CLEARANCE_MARGIN, W_SMOOTHNESS, W_PROGRESS, W_APPROACH, \
    W_APPROACH_MARGIN = range(len(WEIGHT_COLUMNS))


def reward_weights(spec: RewardSpec) -> np.ndarray:
    """``(9,)`` float64: ``spec``'s entries of :data:`WEIGHT_COLUMNS`. A step without contact onsets uses
    ``collision = 0`` and one without bodies in touch ``contact = 0`` (the callers set them)."""
    return np.array([float(getattr(spec, name)) for name in WEIGHT_COLUMNS], dtype=np.float64)


__all__ = ["WEIGHT_COLUMNS", "W_APPROACH", "W_APPROACH_MARGIN", "W_CLEARANCE", "W_CLEARANCE_MARGIN", "W_COLLISION",
           "W_CONTACT", "W_FORMATION", "W_PROGRESS", "W_SMOOTHNESS", "reward_weights"]
