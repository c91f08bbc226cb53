"""MetaL DAgger on one seed, top to bottom: every per-seed step of the method, in one place.

Every protocol starts a seed the same way: pi*'s trunk, frozen, with a fresh head of the seed's
own (:class:`SeedLearner`), driving the seed's env. The steps (docs/method.md):

1. :func:`demonstration` -- the expert drives the seed once; each of its steps is one query
   (:func:`demonstration_share`: its first steps only, a smaller budget).
2. :func:`bc_head` -- the head fitted by BC on the demonstration: w_BC (paper 3.4.2).
3. :func:`seed_context` and :func:`map_head` -- a mapper's head for the seed from w_BC (and, for
   a mapper that reads one, the seed's context): MDM, no further query (paper 4.1).
4. :func:`dagger_rounds` -- roll out, choose the states to label (every one, or a gate's
   choice), label them, aggregate, refit the head; one :class:`Round` after each refit.
   Its controls at equal labels (DART) are in :mod:`metadagger.metal_dagger.controls`.
5. :func:`one_shot` -- a head refitted on the demonstration from an initialisation: MDI's
   one-shot head (paper 4.2, Table 6 step 5).

The protocols are these steps in different orders: a pair is 1, 2, 4 (every state labelled);
MDM is 1, 2, 3 (and 5 for a mapped head that fails); MDI is 1, 2, 3, 5, then one round of 4 from
the saved initialisation; the query benchmark runs them all. Rollouts are deterministic (an
episode depends only on its seed and the head), so a head's rollout that ends one step is the
one the next step starts from, and nothing is rolled out twice.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import math
from dataclasses import dataclass
from typing import Any, Callable, Iterator, Protocol, Sequence, TypeVar

import numpy as np
import torch

from metadagger.errors import UserError
from metadagger.imitation.bc import BCConfig, fit_bc, head_fit
from metadagger.imitation.data import Aggregate, Dataset, take_rows
from metadagger.imitation.early_stop import CosineEarlyStop
from metadagger.imitation.features import FeatureCache
from metadagger.imitation.gate_view import Episode, GateMemory, Labelled, LearnerView
from metadagger.imitation.gates import Gate
from metadagger.imitation.head_fits import Prior, fit_heads, head_outputs
from metadagger.imitation.lanes import EpisodeRequest, Lane, Lanes, current_lane, run_chains
from metadagger.imitation.rollouts import ActionNoise, Trajectory, rollout
from metadagger.metal_dagger.pistar import cached_pistar, head_from_pistar
from metadagger.policies import Policy
from metadagger.tasks.base import Task

#: What a context is made of, in order (the pairs' stamp records it).
CONTEXT_PARTS = ("demonstration feature mean", "bc rollout feature mean")

T = TypeVar("T")


class HeadMapper(Protocol):
    """What step 3 needs of a mapper (:class:`~metadagger.mapping.mappers.Mapper` is one)."""

    @property
    def needs_context(self) -> bool:
        """Whether the mapper reads the seed's context beside w_BC."""

    def __call__(self, w_bc: np.ndarray, context: np.ndarray | None = None) -> np.ndarray:
        """The mapped head of ``w_bc``."""


class SeedLearner:
    """pi*'s frozen trunk with a head of its own, in one env of the task, on one seed.

    Args:
        task: the task whose learner env is rolled out.
        pistar: path of pi* (loaded once per process).
        seed: the env seed of every rollout.
        head_init_seed: the seed of the fresh (Xavier) head (:meth:`BCConfig.head_init_seed`).
    """

    def __init__(self, task: Task, pistar: str, seed: int, *, head_init_seed: int) -> None:
        self.task = task
        self.seed = seed
        self.policy: Policy = head_from_pistar(cached_pistar(pistar), head_init_seed)
        self.cache = FeatureCache(self.policy)
        # made inside a chain (:func:`~metadagger.metal_dagger.lane_blocks.run_block`), its episodes go to
        # the chain's lane
        self._lane = current_lane()
        self.env: Any = task.make_env() if self._lane is None else None

    def fork(self, lane: Lane) -> SeedLearner:
        """A learner of the same seed with a head of its own (a copy of the current one), sharing this
        one's trunk and feature cache, whose episodes and fits go to ``lane`` (a chain's, of
        :func:`~metadagger.imitation.lanes.run_chains`)."""
        twin = copy.copy(self)
        twin.policy, twin.env, twin._lane = self.policy.with_own_head(), None, lane
        return twin

    def head(self) -> np.ndarray:
        """The current head as a flat float32 vector (a copy)."""
        return self.policy.head_vector().numpy().copy()

    def load(self, head: np.ndarray | torch.Tensor) -> None:
        """Make ``head`` the current head (copied)."""
        self.policy.load_head_vector(torch.as_tensor(head))

    def roll(self, head: np.ndarray | None = None, *, early_stop: float | None = None) -> Trajectory:
        """One episode of the seed with ``head`` (default: the current one), every visited state
        labelled by the expert; cut as a failure by a cosine early stop at ``early_stop``."""
        if head is not None:
            self.load(head)
        if self._lane is not None:
            return self._in_lane(EpisodeRequest(self.seed, self.head(), early_stop))
        stop = None if early_stop is None else CosineEarlyStop(threshold=early_stop)
        return rollout(self.env, seed=self.seed, policy=self.policy, early_stop=stop)

    def demonstrate(self, noise: ActionNoise | None = None) -> Trajectory:
        """One episode of the seed driven by the expert (its executed action perturbed by ``noise``,
        DART's, where one is given; every state labelled with its own action)."""
        if self._lane is not None:
            return self._in_lane(EpisodeRequest(self.seed, None, noise=noise))
        return rollout(self.env, seed=self.seed, policy=None, noise=noise)

    def _in_lane(self, request: EpisodeRequest) -> Trajectory:
        # the trajectory carries the features the lane acted on: every later fit, gate and context
        # reads them (FeatureCache.features_of), never the images again
        return self._lane.roll(request)  # type: ignore[union-attr]

    def fit(self, data: Dataset | Aggregate, config: BCConfig, *, called: str, prior: Prior | None = None) -> None:
        """Fit the current head (BC, :func:`~metadagger.imitation.bc.fit_bc`) on ``data``; in a chain's
        lane, a head-only fit runs batched with the other chains' fits. With a ``prior`` (a Gaussian
        prior on the head, :class:`~metadagger.imitation.head_fits.Prior`), the head-only fit adds
        it to its loss, and always runs in the batched kernel, in a lane or alone."""
        if prior is None and (self._lane is None or not config.head_only):
            fit_bc(self.policy, data, config, cache=self.cache, called=called)
            return
        request = dataclasses.replace(head_fit(self.policy, data, config, self.cache, called=called), prior=prior)
        if self._lane is not None:
            self.load(self._lane.fit(request).head)
        else:
            out_dim = int(self.policy.net.head.out_features)
            [fitted] = fit_heads([request], out_dim=out_dim, discrete=self.policy.discrete)
            self.load(fitted.head)

    def start_refit(self, fit: BCConfig, origin: np.ndarray | None) -> None:
        """Before a refit of ``fit``: load ``origin`` where ``fit.refit_from`` says the refit starts
        there (:attr:`BCConfig.refit_from`); otherwise the refit continues the current head."""
        if fit.refit_from == "origin":
            if origin is None:
                raise ValueError("a refit from the origin needs origin= (the head the seed's fits began from)")
            self.load(origin)

    def close(self) -> None:
        """Close the env."""
        if self.env is not None:
            self.env.close()

    def __enter__(self) -> SeedLearner:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def run_steps(learner: SeedLearner, steps: Sequence[Callable[[SeedLearner], T]], lanes: Lanes | None) -> list[T]:
    """Run each of ``steps`` (a function of a learner) on the seed; their results in order.

    Without ``lanes``, one after another on ``learner`` itself, every episode in its env. With
    them, each on a :meth:`~SeedLearner.fork` of ``learner`` in a chain of its own, their episodes
    stepped together in the lanes (:func:`~metadagger.imitation.lanes.run_chains`): a step must
    then load every head it starts from, as it would after another step on the same learner.
    """
    if lanes is None:
        return [step(learner) for step in steps]
    return run_chains(lanes, [functools.partial(_on_fork, learner, step) for step in steps])


def _on_fork(learner: SeedLearner, step: Callable[[SeedLearner], T], lane: Lane) -> T:
    return step(learner.fork(lane))


def demonstration(learner: SeedLearner) -> Trajectory:
    """Step 1: the expert drives the seed once; every step is one query."""
    return learner.demonstrate()


def demonstration_share(demo: Trajectory, fraction: float) -> Trajectory:
    """Step 1 on a smaller budget: the demonstration's first ``ceil(fraction * T)`` steps (at least
    one), as if the expert had been stopped there; its outcome stays the whole episode's."""
    if not 0.0 < fraction <= 1.0:
        raise ValueError(f"a demonstration share must be in (0, 1], got {fraction!r}")
    n = max(1, math.ceil(fraction * demo.steps))
    if n == demo.steps:
        return demo
    return dataclasses.replace(
        demo,
        obs=demo.obs[:n],
        expert_labels=demo.expert_labels[:n],
        learner_actions=demo.learner_actions[:n],
        step_rewards=demo.step_rewards[:n],
        reward=float(demo.step_rewards[:n].sum()),
        steps=n,
        expert_queries=n,
        features=None if demo.features is None else demo.features[:n],
        final_obs=demo.obs[n],
        final_label=demo.expert_labels[n],
        terminated=False,
    )


def bc_head(
    learner: SeedLearner, demo: Dataset, fit: BCConfig, *, called: str = "the BC head's fit", prior: Prior | None = None
) -> np.ndarray:
    """Step 2: fit the learner's current head (a fresh one: w_BC) by BC on the demonstration (with
    a Gaussian ``prior`` on the head, where one is given)."""
    learner.fit(demo, fit, called=called, prior=prior)
    return learner.head()


def seed_context(
    cache: FeatureCache, demonstration: np.ndarray | Dataset, bc_rollout: np.ndarray | Dataset
) -> np.ndarray:
    """Step 3's context: what the seed's own data says about it, without a further label.

    The mean trunk feature of the ``demonstration``'s images, then of the ``bc_rollout``'s: one
    rollout of w_BC (visited, never labelled), the one DAgger's first round starts from, cut by
    the pairs' early stop. Each is uint8 images ``(N, H, W, C)`` or a dataset (whose carried
    features are read where it has them), ``N >= 1``; the context is ``2 x feature_dim`` float32
    numbers (:data:`CONTEXT_PARTS`).
    """
    for name, images in (("demonstration", demonstration), ("bc_rollout", bc_rollout)):
        if len(images) == 0:
            raise ValueError(f"seed_context needs at least one image of the {name}, got none")
    means = [_features(cache, part).to(torch.float64).mean(dim=0) for part in (demonstration, bc_rollout)]
    return torch.cat(means).to(torch.float32).numpy()


def _features(cache: FeatureCache, data: np.ndarray | Dataset) -> torch.Tensor:
    """Trunk features of images, or of a dataset (its carried features where it has them)."""
    return cache.features_of(data) if isinstance(data, Dataset) else cache.features(data)


def map_head(mapper: HeadMapper, w_bc: np.ndarray, context: np.ndarray | None) -> np.ndarray:
    """Step 3: the mapper's head for the seed (MDM: used as it is, with no further query)."""
    return mapper(w_bc, context if mapper.needs_context else None)


@dataclass(frozen=True)
class Round:
    """One DAgger round: the states labelled, then the refitted head and its rollout."""

    index: int
    """1-based."""
    labelled: Dataset | None
    """The states this round labelled (None: the gate chose none, and the head was not refitted)."""
    head: np.ndarray
    """The head after the round's refit."""
    rollout: Trajectory
    """That head's rollout (the one the next round labels)."""
    queries: int
    """Expert queries so far, the demonstration's included."""
    asked: np.ndarray
    """Which steps of the labelled rollout were labelled: int64 step indices, ascending (the query ledger)."""
    scores: np.ndarray | None
    """The gate's score at each of those steps, where the gate has one (float64); None otherwise."""


Labeller = Callable[[int, Trajectory, np.ndarray], np.ndarray]
"""Who answers a round's queries: ``labeller(round, rollout, asked)`` gives the labels of the rollout's
steps ``asked`` (ascending int64 indices), in the layout of its ``expert_labels``."""


def dagger_rounds(
    learner: SeedLearner,
    *,
    start: np.ndarray,
    first_rollout: Trajectory,
    demo: Trajectory,
    rounds: int,
    fit: BCConfig,
    gate: Gate | None = None,
    early_stop: float | None = None,
    prior: Prior | None = None,
    reference: np.ndarray | None = None,
    origin: np.ndarray | None = None,
    labeller: Labeller | None = None,
) -> Iterator[Round]:
    """Step 4: ``rounds`` DAgger rounds from head ``start``, whose rollout ``first_rollout`` round 1 labels.

    Each round labels the states of the last rollout that ``gate`` selects (all of them without
    one: plain DAgger), adds them to the demonstration and the earlier rounds' labels, refits the
    head on all of it (continuing from the current head, or from ``origin`` where
    ``fit.refit_from`` says so), and rolls the refitted head out.

    Args:
        learner: the seed's learner.
        start: the head the rounds start from (w_BC for the pairs).
        first_rollout: ``start``'s rollout, made with the same ``early_stop``.
        demo: the demonstration (on its states the learner's action is the expert's label).
        rounds: R >= 1.
        fit: the head-only refit of every round (its ``seed`` orders the batches).
        gate: the query rule (:mod:`metadagger.imitation.gates`); its randomness is seeded by the
            env seed. None labels every visited state.
        early_stop: the cosine early stop of the rollouts.
        prior: a Gaussian prior every round's refit adds to its loss (:mod:`metadagger.mapping.priors`).
        reference: the head a gate that compares heads compares the current one with (a mapper's
            for the seed, or a constant head).
        origin: the head every refit starts from where ``fit.refit_from`` is ``origin`` (the seed's
            fresh head for DAgger from BC; MDI's saved initialisation).
        labeller: who labels the chosen states (a person at a page: :mod:`metadagger.label`);
            None: the task's scripted expert, whose labels the rollout carries.
    """
    if gate is not None and gate.reads_reference and reference is None:
        raise UserError(f"{type(gate).__name__} compares the current head with a reference head; pass reference=")
    generator = torch.Generator().manual_seed(learner.seed)
    data = Aggregate([demo.to_dataset()])
    actions = demo.expert_labels
    queries = len(data)
    # what a gate may know of the run: the demonstration first, then each rollout it has gated
    memory = (
        GateMemory()
        if gate is None
        else GateMemory([Episode(learner.cache.features_of(demo.to_dataset()), bool(demo.success))])
    )
    learner.load(start)
    trajectory = first_rollout
    for index in range(1, rounds + 1):
        scores = None
        if gate is None:
            keep = np.ones(trajectory.steps, dtype=bool)
        else:
            keep, scores = _gate_mask(gate, learner, data, actions, trajectory, generator, memory, reference)
        labelled = None
        if keep.any():
            labelled = Dataset(
                obs=take_rows(trajectory.obs, keep),
                labels=trajectory.expert_labels[keep]
                if labeller is None
                else labeller(index, trajectory, np.flatnonzero(keep)),
                features=None if trajectory.features is None else trajectory.features[keep],
            )
            data = data.append(labelled)
            actions = np.concatenate([actions, trajectory.learner_actions[keep]])
            queries += int(keep.sum())
            learner.start_refit(fit, origin)
            learner.fit(data, fit, called=f"DAgger round {index}'s refit", prior=prior)
        head = learner.head()
        if labelled is not None:
            trajectory = learner.roll(head, early_stop=early_stop)
        # else the head is the one ``trajectory`` was rolled out with, and an episode depends only
        # on its seed and head: rolling it out again would give the same episode
        asked = np.flatnonzero(keep)
        yield Round(
            index=index,
            labelled=labelled,
            head=head,
            rollout=trajectory,
            queries=queries,
            asked=asked,
            scores=None if scores is None else scores[asked],
        )


def _gate_mask(
    gate: Gate,
    learner: SeedLearner,
    data: Aggregate,
    actions: np.ndarray,
    trajectory: Trajectory,
    generator: torch.Generator,
    memory: GateMemory,
    reference: np.ndarray | None,
) -> tuple[np.ndarray, np.ndarray | None]:
    """The states of ``trajectory`` that ``gate`` chooses to label, from the round's
    :class:`~metadagger.imitation.gate_view.LearnerView` (everything labelled so far, the run's
    finished episodes in ``memory``, to which ``trajectory`` is then added); and the scores it chose
    them by, where it has some. Only a gate that declares it sees ``reference``, and only a
    reference gate (the oracle) the expert's labels of the round's states."""
    labelled = Labelled(
        features=learner.cache.features_of(data), labels=_tensor(data.labels), learner_actions=_tensor(actions)
    )
    features = learner.cache.features_of(trajectory.to_dataset())
    head = torch.from_numpy(learner.head())
    view = LearnerView(
        features=features,
        outputs=head_outputs(head, features, int(learner.policy.net.head.out_features)),
        actions=_tensor(trajectory.learner_actions),
        head=head,
        labelled=labelled,
        generator=generator,
        memory=memory,
        reference=torch.as_tensor(reference, dtype=torch.float32) if gate.reads_reference else None,
        expert_labels=_tensor(trajectory.expert_labels) if gate.reads_expert else None,
    )
    chosen = gate.choose(view)
    memory.episodes.append(Episode(features=features, succeeded=bool(trajectory.success)))
    scores = None if chosen.scores is None else chosen.scores.double().numpy()
    return chosen.mask.numpy(), scores


def _tensor(values: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(values))


def one_shot(learner: SeedLearner, init: np.ndarray, demo: Dataset, fit: BCConfig) -> np.ndarray:
    """Step 5: the head ``init`` refitted by BC on the demonstration (no further query)."""
    learner.load(init)
    return bc_head(learner, demo, fit, called="the one-shot refit")


def seeded(fit: BCConfig, seed: int) -> BCConfig:
    """``fit`` with its batch order seeded by ``seed`` (every per-seed fit is seeded by its env seed)."""
    return dataclasses.replace(fit, seed=seed)
