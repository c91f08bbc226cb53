"""What the benchmark measures the method against on one seed, beside its steps in
:mod:`metadagger.metal_dagger.method`: DART at DAgger's labels (more demonstrations, the expert's
executed action perturbed, instead of labels on the learner's states), and the expert's states held
out of every fit, on which a head's loss says whether it fits the expert where it was shown."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Iterator, Sequence

import numpy as np
import torch

from metadagger.imitation.bc import BCConfig
from metadagger.imitation.data import Aggregate, Dataset, take_rows
from metadagger.imitation.head_fits import head_outputs
from metadagger.imitation.rollouts import ActionNoise, Trajectory
from metadagger.metal_dagger.method import SeedLearner


@dataclass(frozen=True)
class DartRound:
    """DART at one of DAgger's budgets: the head refitted on the demonstration and the perturbed
    episodes' labels up to the budget, and its rollout."""

    index: int
    """The DAgger round whose cumulative labels are the budget (1-based)."""
    head: np.ndarray
    rollout: Trajectory
    queries: int
    """Expert queries, the demonstration's included: the budget, or fewer where ``episodes`` ran out."""
    episodes: list[int]
    """The labelled steps of each perturbed episode so far (the first of each, the last one cut at the budget)."""


def dart_rounds(
    learner: SeedLearner,
    *,
    start: np.ndarray,
    demo: Trajectory,
    budgets: Sequence[int],
    scale: float,
    fit: BCConfig,
    early_stop: float | None = None,
    origin: np.ndarray | None = None,
) -> Iterator[DartRound]:
    """DAgger's control at equal labels (DART, Laskey et al. 2017): at each of ``budgets`` (DAgger's
    cumulative queries after each round, ascending), the expert has driven further episodes of the
    seed, its executed action perturbed (:class:`~metadagger.imitation.rollouts.ActionNoise` at
    ``scale``; episode k's perturbations seeded by the seed and k), every visited state labelled with
    its unperturbed action, until the demonstration and those labels hold the budget, the last
    episode cut there. The head is refitted from ``start`` on all of it, as often as DAgger has
    refitted by then (the round's index, each a refit as BC refitted's), and rolled out.

    Args:
        learner: the seed's learner.
        start: the head every budget's refits begin from (w_BC).
        demo: the demonstration.
        budgets: cumulative expert queries, the demonstration's included, one per round.
        scale: the perturbation (a probability with classes, a standard deviation with vectors).
        fit: the refit of every round (DAgger's), its batches seeded.
        early_stop: the cosine early stop of each budget's rollout.
        origin: the head a refit starts from where ``fit.refit_from`` says so (the seed's fresh head).
    """
    demonstration_data = demo.to_dataset()
    stream: list[Dataset] = []  # the perturbed episodes so far, in the order driven
    held = 0
    for index, budget in enumerate(budgets, start=1):
        while len(demonstration_data) + held < budget:
            episode = learner.demonstrate(ActionNoise(scale, stream=(learner.seed, len(stream))))
            stream.append(episode.to_dataset())
            held += len(stream[-1])
        room, taken = max(0, budget - len(demonstration_data)), []
        for episode_data in stream:
            if room == 0:
                break
            taken.append(min(room, len(episode_data)))
            room -= taken[-1]
        data = Aggregate([demonstration_data, *(_first_rows(d, n) for d, n in zip(stream, taken))])
        learner.load(start)
        for refit in range(1, index + 1):
            learner.start_refit(fit, origin)
            learner.fit(data, fit, called=f"DART's refit {refit} at round {index}'s labels")
        head = learner.head()
        yield DartRound(index, head, learner.roll(head, early_stop=early_stop), len(data), taken)


def _first_rows(data: Dataset, n: int) -> Dataset:
    """The first ``n`` rows of ``data``."""
    keep = np.arange(len(data)) < n
    return Dataset(
        obs=take_rows(data.obs, keep),
        labels=data.labels[:n],
        features=None if data.features is None else data.features[:n],
    )


def held_out(demo: Trajectory, every: int) -> tuple[Trajectory, Dataset]:
    """The demonstration without every ``every``-th step (steps ``every - 1``, ``2 every - 1``, ...),
    as if the expert had not been asked there, and those steps as a dataset of the expert's own
    states: a held-out set for :func:`expert_loss`. Its outcome stays the whole episode's."""
    if every < 2 or demo.steps < every:
        raise ValueError(f"holding out every {every}-th step needs every >= 2 and at least that many steps")
    held = np.arange(demo.steps) % every == every - 1
    keep = ~held
    features = demo.features
    kept = dataclasses.replace(
        demo,
        obs=take_rows(demo.obs, keep),
        expert_labels=demo.expert_labels[keep],
        learner_actions=demo.learner_actions[keep],
        step_rewards=demo.step_rewards[keep],
        steps=int(keep.sum()),
        expert_queries=int(keep.sum()),
        features=None if features is None else features[keep],
    )
    out = Dataset(
        obs=take_rows(demo.obs, held),
        labels=demo.expert_labels[held],
        features=None if features is None else features[held],
    )
    return kept, out


def expert_loss(learner: SeedLearner, head: np.ndarray, states: Dataset) -> float:
    """``head``'s mean loss on ``states`` labelled by the expert: cross-entropy on classes, the
    squared error on action vectors (the fits' own losses)."""
    features = learner.cache.features_of(states)
    outputs = head_outputs(
        torch.from_numpy(np.ascontiguousarray(head)), features, int(learner.policy.net.head.out_features)
    )
    labels = torch.from_numpy(np.ascontiguousarray(states.labels))
    if learner.policy.discrete:
        return float(torch.nn.functional.cross_entropy(outputs.double(), labels))
    return float(torch.nn.functional.mse_loss(outputs.double(), labels.double()))
