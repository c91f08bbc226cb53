"""``bench numerics``: how often lanes' batched forwards change an action against batch-1 forwards."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from metadagger.errors import UserError
from metadagger.policies import Policy


def batch_one_outputs(policy: Policy, obs: np.ndarray) -> torch.Tensor:
    """The policy's outputs on each image alone, at batch 1: how an episode without lanes acts."""
    with torch.inference_mode():
        return torch.cat([policy.net.act_outputs(torch.from_numpy(o[None])) for o in obs])


def laned_outputs(policy: Policy, obs: np.ndarray, width: int) -> torch.Tensor:
    """The policy's outputs as lanes of ``width`` compute them: the trunk on zero-padded batches of
    ``width`` images, then the head on each row alone (:class:`~metadagger.imitation.lanes.Lanes`)."""
    net, rows = policy.net, []
    batch = np.zeros((width, *obs.shape[1:]), dtype=np.uint8)
    with torch.inference_mode():
        for start in range(0, len(obs), width):
            chunk = obs[start : start + width]
            batch[:] = 0
            batch[: len(chunk)] = chunk
            features = net.trunk(net.preprocess(torch.from_numpy(batch)))
            rows += [F.linear(features[i : i + 1], net.head.weight, net.head.bias) for i in range(len(chunk))]
    return torch.cat(rows)


def bench_numerics(run: str | Path, *, width: int = 32, states: int = 100_000, first_seed: int = 30000) -> dict:
    """pi*'s actions on the states of its own episodes (seeds from ``first_seed`` up, until
    ``states`` states), at batch 1 and in lanes of ``width``: the share of states whose action
    changes (a different class, or any different bit of a continuous action) and the size of the
    output differences (each state's largest, over its outputs: their median, 99th percentile and
    maximum; for a continuous action, what the bits that changed amount to). The run's artifacts
    are untouched."""
    from metadagger.imitation.lanes import MAX_LANES
    from metadagger.imitation.rollouts import rollout
    from metadagger.metal_dagger.pistar import load_pistar
    from metadagger.pipeline.run_config import load_run
    from metadagger.pipeline.stage_inputs import run_task
    from metadagger.runfolder.layout import RunLayout
    from metadagger.utils.progress import note

    if not 1 <= width <= MAX_LANES or states < 1:
        raise UserError(f"bench numerics needs --lanes from 1 to {MAX_LANES} and --states >= 1, got {width}, {states}")
    config = load_run(run)
    task = run_task(config)
    policy = load_pistar(RunLayout(run))
    torch.set_num_threads(1)
    counted, changed, differences, seeds = 0, 0, [], []
    env = task.make_env()
    while counted < states:
        seed = first_seed + len(seeds)
        obs = rollout(env, seed=seed, policy=policy, max_steps=config.max_episode_steps).obs
        alone, laned = batch_one_outputs(policy, obs), laned_outputs(policy, obs, width)
        if policy.discrete:
            changed += int((alone.argmax(dim=1) != laned.argmax(dim=1)).sum())
        else:
            changed += int((alone != laned).any(dim=1).sum())
        differences.append((alone - laned).abs().amax(dim=1).double().numpy())
        counted += len(obs)
        seeds.append(seed)
        if len(seeds) % 10 == 0 or counted >= states:
            note(f"bench numerics: {counted}/{states} states, {changed} actions changed")
    env.close()
    return {
        "task": config.task,
        "run": str(run),
        "width": width,
        "seeds": [seeds[0], seeds[-1]],
        "states": counted,
        "actions_changed": changed,
        "share_changed": changed / counted,
        "median_output_difference": float(np.median(np.concatenate(differences))),
        "p99_output_difference": float(np.quantile(np.concatenate(differences), 0.99)),
        "largest_output_difference": float(np.concatenate(differences).max()),
    }
