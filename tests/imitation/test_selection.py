"""Early stopping of a fit on held-out seeds (EpochSelector)."""

from __future__ import annotations

import copy

import pytest
import torch
from toy_task import TOY_ARCH

from metadagger.errors import UserError
from metadagger.imitation import selection
from metadagger.imitation.bc import BCConfig, fit_bc, fit_or_resume
from metadagger.imitation.collect import collect
from metadagger.imitation.data import Dataset
from metadagger.imitation.episodes import evaluate_policy
from metadagger.imitation.selection import EpochSelector
from metadagger.policies import load_policy, make_policy

HELD_OUT = tuple(range(200, 206))


def test_selector_checks_every_few_epochs_and_the_last_and_keeps_the_best(discrete_task):
    demos = Dataset.concat(*(t.to_dataset() for t in collect(discrete_task, [0, 1, 2], policy=None)))
    policy = make_policy(discrete_task, seed=4, **TOY_ARCH)
    selector = EpochSelector(discrete_task, policy, HELD_OUT, every=3, epochs=8)
    weights = {}

    def on_epoch(epoch: int) -> None:
        selector(epoch)
        weights[epoch] = copy.deepcopy(policy.net.state_dict())

    fit_bc(policy, demos, BCConfig(lr=3e-2, epochs=8, batch_size=16), on_epoch=on_epoch)
    assert sorted(weights) == list(range(1, 9))
    assert [check["epoch"] for check in selector.history] == [3, 6, 8]
    for check in selector.history:  # each count is that epoch's policy's, measured again here
        replay = make_policy(discrete_task, seed=4, **TOY_ARCH)
        replay.net.load_state_dict(weights[check["epoch"]])
        rows = evaluate_policy(discrete_task, replay, HELD_OUT, progress=False)
        assert check["successes"] == sum(row["success"] for row in rows) and check["episodes"] == len(HELD_OUT)
    best = max(check["successes"] for check in selector.history)
    chosen = [check["epoch"] for check in selector.history if check["successes"] == best][-1]
    assert selector.choice["epoch"] == chosen and selector.choice["successes"] == best
    assert chosen != 8  # this fit's last epoch is not its best, so restoring changes the weights
    selector.restore()
    assert all(torch.equal(policy.net.state_dict()[k], v) for k, v in weights[chosen].items())


def test_a_tie_goes_to_the_later_epoch(discrete_task, monkeypatch):
    counts = iter([3, 5, 5, 2])

    def rows_with_next_count(task, policy, seeds, **_):
        wins = next(counts)
        return [{"success": i < wins} for i in range(len(seeds))]

    monkeypatch.setattr(selection, "evaluate_policy", rows_with_next_count)
    policy = make_policy(discrete_task, seed=4, **TOY_ARCH)
    selector = EpochSelector(discrete_task, policy, HELD_OUT, every=1, epochs=4)
    for epoch in range(1, 5):
        selector(epoch)
    assert selector.choice["epoch"] == 3 and selector.choice["successes"] == 5


def test_fit_or_resume_saves_the_chosen_epoch(discrete_task, discrete_demo, tmp_path):
    policy = make_policy(discrete_task, seed=4, **TOY_ARCH)
    selector = EpochSelector(discrete_task, policy, HELD_OUT, every=1, epochs=3)
    fit_or_resume(
        policy,
        discrete_demo,
        BCConfig(lr=3e-3, epochs=3, batch_size=16),
        tmp_path / "pi.safetensors",
        selector=selector,
    )
    saved = load_policy(tmp_path / "pi.safetensors")
    assert all(torch.equal(a, b) for a, b in zip(saved.net.parameters(), policy.net.parameters()))
    assert len(selector.history) == 3 and selector.choice["epoch"] in (1, 2, 3)


def test_selector_rejects_bad_settings(discrete_task):
    policy = make_policy(discrete_task, seed=4, **TOY_ARCH)
    with pytest.raises(UserError, match="at least one held-out seed"):
        EpochSelector(discrete_task, policy, (), every=1, epochs=3)
    with pytest.raises(UserError, match="check interval must be >= 1"):
        EpochSelector(discrete_task, policy, HELD_OUT, every=0, epochs=3)
    with pytest.raises(UserError, match="no epoch was checked"):
        EpochSelector(discrete_task, policy, HELD_OUT, every=1, epochs=3).restore()
