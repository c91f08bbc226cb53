"""A seed's context: what its own data says about it, without a further expert label.

The ``conditioned`` mapper kind (:mod:`metadagger.mapping.registry`) receives, beside w_BC, a
summary of two sets of states of the seed: the demonstration (already labelled: BC was fitted on
it) and one rollout of the BC head (the states it drifts to; visited, never labelled). The
context is the mean trunk feature of each set, concatenated: ``[mean over the demonstration,
mean over the BC rollout]``, ``2 x feature_dim`` float32 numbers.

The BC rollout is the one the pair procedure already makes: DAgger's first round rolls out the
BC head under the pairs' early-stop rule (``pairs.early_stop``), so making a pair's context costs
no further env step. Evaluation rolls the BC head out the same way, once per seed, and reports
that rollout's env steps; its expert labels are never used.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from metadagger.imitation.bc import FeatureCache
from metadagger.imitation.early_stop import CosineEarlyStop
from metadagger.imitation.rollouts import Trajectory, rollout
from metadagger.policies import Policy

#: What a context is made of, in order (the pairs' stamp records it).
CONTEXT_PARTS = ("demonstration feature mean", "bc rollout feature mean")


def seed_context(cache: FeatureCache, demonstration: np.ndarray, bc_rollout: np.ndarray) -> np.ndarray:
    """The context of a seed: mean trunk features of the ``demonstration``'s images, then of the
    ``bc_rollout``'s (uint8 images ``(N, H, W, C)``, ``N >= 1`` each); ``[2 x feature_dim]`` float32."""
    for name, images in (("demonstration", demonstration), ("bc_rollout", bc_rollout)):
        if len(images) == 0:
            raise ValueError(f"seed_context needs at least one image of the {name}, got none")
    means = [cache.features(images).to(torch.float64).mean(dim=0) for images in (demonstration, bc_rollout)]
    return torch.cat(means).to(torch.float32).numpy()


def bc_rollout(env: Any, policy: Policy, seed: int, early_stop: float | None) -> Trajectory:
    """The BC head's rollout that a context summarises: ``policy`` (its head set to w_BC) on
    ``seed``, cut by the pairs' early-stop threshold where one is set (as DAgger's first round)."""
    stop = None if early_stop is None else CosineEarlyStop(threshold=early_stop)
    return rollout(env, seed=seed, policy=policy, early_stop=stop)
