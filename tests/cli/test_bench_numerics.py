"""bench numerics: pi*'s outputs at batch 1 against the lanes' padded batches."""

from __future__ import annotations

import numpy as np
import torch

from metadagger.cli.bench_numerics import batch_one_outputs, laned_outputs
from metadagger.policies import Policy, PolicyNet


def _policy() -> Policy:
    net = PolicyNet(obs_shape=(96, 96, 3), n_outputs=20, discrete=True)
    net.init_weights(0)
    return Policy(net=net, task="carracing")


def test_laned_outputs_do_not_depend_on_batch_mates_and_stay_near_batch_one():
    policy = _policy()
    obs = np.random.default_rng(0).integers(0, 256, size=(12, 96, 96, 3), dtype=np.uint8)
    laned = laned_outputs(policy, obs, width=8)  # a full batch of 8, then 4 rows padded with zeros
    order = np.random.default_rng(1).permutation(12)
    shuffled = laned_outputs(policy, obs[order], width=8)
    # the lanes' rule: at a fixed batch shape a row's output does not depend on the other rows
    assert torch.equal(shuffled, laned[torch.from_numpy(order)])
    alone = batch_one_outputs(policy, obs)
    assert alone.shape == laned.shape == (12, 20)
    torch.testing.assert_close(laned, alone, rtol=0, atol=1e-4)
