"""Cosine early stop for Fetch rollouts (paper section 3.4.2).

A learner rollout is killed and counted as a failure once the accumulated cosine distance
between the learner's displacements and the expert's labels passes a threshold, so DAgger's
aggregated data is not flooded with states the expert would never visit. The accumulated and
per-action distances are what the paper's Figure 5 plots.
"""

from __future__ import annotations

import math

import numpy as np

from metadagger.errors import UserError

#: Default threshold on the accumulated cosine distance of one 50-step Fetch episode (with the
#: default :data:`MIN_LABEL_NORM`). Measured on seeds 0-49 (docs/fetch.md): the expert plus
#: Gaussian noise of s.d. 0.1 on every action reaches at most 12.1 (all 50 succeed); uniformly
#: random actions reach 40-59 and a policy repeating its first label 28-92 (all fail), and 20
#: stops those by step 21 and 16 (medians), half-way through the episode.
DEFAULT_THRESHOLD = 20.0
#: Default dead zone on the expert's label. The scripted expert is a proportional controller:
#: once the cube is at the goal its labels shrink towards zero and their direction is noise, so
#: without a dead zone a successful noisy expert accumulates 14-31 over an episode, as much
#: as a failing policy.
MIN_LABEL_NORM = 0.1
#: Vectors shorter than this have no direction.
ZERO_NORM = 1e-6


def cosine_distance(learner_action: np.ndarray, expert_label: np.ndarray) -> float:
    """``1 - cos`` of the angle between two displacement vectors, in [0, 2].

    A vector shorter than :data:`ZERO_NORM` has no direction: two such vectors agree (0, both
    say "stay"); one of them against a real displacement counts as orthogonal (1).
    """
    a = np.asarray(learner_action, dtype=np.float64).reshape(-1)
    b = np.asarray(expert_label, dtype=np.float64).reshape(-1)
    if a.shape != b.shape:
        raise ValueError(f"learner action and expert label must have the same shape, got {a.shape} and {b.shape}")
    norm_a, norm_b = float(np.linalg.norm(a)), float(np.linalg.norm(b))
    if norm_a < ZERO_NORM and norm_b < ZERO_NORM:
        return 0.0
    if norm_a < ZERO_NORM or norm_b < ZERO_NORM:
        return 1.0
    cos = float(np.dot(a, b)) / (norm_a * norm_b)
    return 1.0 - min(1.0, max(-1.0, cos))


def check_threshold(name: str, value: float | None) -> None:
    """Raise a :class:`~metadagger.errors.UserError` naming config field ``name`` unless
    ``value`` is None (early stop off) or a finite number > 0."""
    if value is not None and not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
        raise UserError(f"{name} must be a finite number > 0 or null (no early stop), got {value!r}")


class CosineEarlyStop:
    """Accumulates the cosine distance between learner actions and expert labels over an episode.

    Usage: ``reset()`` at the start of each episode, then ``if stop.update(a, y): break`` after
    every step. Once the accumulated distance passes the threshold, ``update`` keeps returning
    True until the next ``reset``.

    Args:
        threshold: Accumulated distance (sum of ``1 - cos`` per action) above which the episode
            stops; see :data:`DEFAULT_THRESHOLD`.
        min_label_norm: Actions whose expert label is shorter than this count as distance 0:
            the expert wants to stay put and has no direction to disagree with (see
            :data:`MIN_LABEL_NORM`). 0 gives the plain accumulated cosine distance.
    """

    def __init__(self, *, threshold: float = DEFAULT_THRESHOLD, min_label_norm: float = MIN_LABEL_NORM):
        if not math.isfinite(threshold) or threshold <= 0:
            raise ValueError(f"threshold must be a finite number > 0, got {threshold}")
        if not math.isfinite(min_label_norm) or min_label_norm < 0:
            raise ValueError(f"min_label_norm must be a finite number >= 0, got {min_label_norm}")
        self.threshold = float(threshold)
        self.min_label_norm = float(min_label_norm)
        self._distances: list[float] = []

    def reset(self) -> None:
        """Forget the current episode."""
        self._distances = []

    def update(self, learner_action: np.ndarray, expert_label: np.ndarray) -> bool:
        """Add one action's distance; True once the accumulated distance exceeds the threshold."""
        distance = cosine_distance(learner_action, expert_label)
        if float(np.linalg.norm(np.asarray(expert_label, dtype=np.float64))) < self.min_label_norm:
            distance = 0.0
        self._distances.append(distance)
        return self.stopped

    @property
    def stopped(self) -> bool:
        """Whether the accumulated distance has passed the threshold."""
        return self.total > self.threshold

    @property
    def total(self) -> float:
        """Accumulated cosine distance of the episode so far."""
        return float(sum(self._distances))

    @property
    def mean(self) -> float:
        """Average cosine distance per action (0 before the first update)."""
        return self.total / len(self._distances) if self._distances else 0.0

    @property
    def distances(self) -> list[float]:
        """Per-action cosine distances of the episode so far, in order."""
        return list(self._distances)

    @property
    def steps(self) -> int:
        """Number of actions seen since the last reset."""
        return len(self._distances)
