"""The yardsticks of the mapping diagnostics on hand-made heads."""

from __future__ import annotations

import pytest
import torch

from metadagger.mapping.diagnostics import (
    canonical_heads,
    function_error,
    head_outputs,
    memorisation,
    pairwise_spread,
    weight_error,
)

CLASSES, FEATURES = 4, 3


def _head(generator: torch.Generator) -> torch.Tensor:
    return torch.randn(CLASSES * FEATURES + CLASSES, generator=generator)


def test_the_softmax_shift_changes_no_action_and_no_canonical_weight():
    g = torch.Generator().manual_seed(0)
    head, features = _head(g), torch.randn(50, FEATURES, generator=g)
    shift = torch.cat([torch.randn(FEATURES, generator=g).repeat(CLASSES), torch.full((CLASSES,), 2.5)])
    shifted = head + shift  # the same vector added to every class's row, a constant to every bias
    assert function_error(head, shifted, features, outputs=CLASSES, discrete=True) == 0.0
    torch.testing.assert_close(canonical_heads(shifted[None], CLASSES), canonical_heads(head[None], CLASSES))
    assert float(weight_error(shifted[None], head[None], outputs=CLASSES, discrete=True)) == pytest.approx(
        0.0, abs=1e-10
    )
    assert float(weight_error(shifted[None], head[None], outputs=CLASSES, discrete=False)) > 1.0


def test_function_error_counts_changed_choices_or_action_error():
    g = torch.Generator().manual_seed(1)
    head, features = _head(g), torch.randn(200, FEATURES, generator=g)
    other = _head(g)
    mismatch = function_error(head, other, features, outputs=CLASSES, discrete=True)
    choices = head_outputs(head, features, CLASSES).argmax(1) != head_outputs(other, features, CLASSES).argmax(1)
    assert mismatch == pytest.approx(float(choices.double().mean())) and 0 < mismatch < 1
    squared = function_error(head, other, features, outputs=CLASSES, discrete=False)
    diff = head_outputs(head, features, CLASSES) - head_outputs(other, features, CLASSES)
    assert squared == pytest.approx(float(diff.pow(2).mean()), rel=1e-6)


def test_memorisation_is_zero_for_a_training_example_and_large_for_the_truth():
    g = torch.Generator().manual_seed(2)
    train, truth = torch.randn(5, 8, generator=g), torch.randn(2, 8, generator=g)
    copied = torch.stack([train[3], train[0]])  # predictions that return training examples
    assert memorisation(copied, truth, train).tolist() == [0.0, 0.0]
    assert bool((memorisation(truth + 1e-3, truth, train) > 100).all())


def test_the_spread_of_identical_heads_is_zero_and_needs_two():
    g = torch.Generator().manual_seed(3)
    head, features = _head(g), torch.randn(10, FEATURES, generator=g)
    assert pairwise_spread(torch.stack([head, head, head]), features, outputs=CLASSES, discrete=True) == (0.0, 0.0)
    with pytest.raises(ValueError, match="at least 2 heads"):
        pairwise_spread(head[None], features, outputs=CLASSES, discrete=True)
    with pytest.raises(ValueError, match="not a layer with 5 outputs"):
        canonical_heads(head[None], 5)
