"""Trunk features cached by image: a head-only fit computes each image's features once.

MetaL DAgger fits layer n alone, thousands of times, on a trunk that never changes; the images
behind those fits are read through one :class:`FeatureCache`, so the trunk sees each image once.
"""

from __future__ import annotations

import hashlib
import weakref

import numpy as np
import torch
from torch.nn.utils import parameters_to_vector

from metadagger.imitation.data import Aggregate, Dataset, images_kept
from metadagger.policies import Policy


class FeatureCache:
    """Trunk features of images, each computed once while the trunk's weights stay the same.

    Images are keyed by their bytes, so the cache can be shared by every fit on a growing
    (aggregated) dataset, and by every policy that shares the trunk (:meth:`Policy.with_own_head`);
    a change of the trunk's weights empties it. A dataset that carries its features (the ones a lane
    computed to act on its images, :mod:`metadagger.imitation.lanes`) is read as it is. A dataset's rows are
    remembered for as long as the dataset lives, so a part of an :class:`Aggregate` is hashed once,
    however many fits read it.

    Args:
        policy: the policy whose trunk computes the features.
        batch_size: images per trunk forward pass.
    """

    def __init__(self, policy: Policy, *, batch_size: int = 256):
        if batch_size < 1:
            raise ValueError(f"batch_size must be >= 1, got {batch_size}")
        self.policy = policy
        self.batch_size = batch_size
        #: images passed through the trunk so far (each distinct image once)
        self.computed = 0
        self._rows: dict[bytes, int] = {}
        self._store = torch.empty(0, policy.net.feature_dim)
        self._trunk_digest = self._digest_trunk()
        self._part_rows: weakref.WeakKeyDictionary[Dataset, torch.Tensor] = weakref.WeakKeyDictionary()

    def __len__(self) -> int:
        return len(self._rows)

    def _digest_trunk(self) -> bytes:
        weights = parameters_to_vector(self.policy.net.trunk.parameters()).detach().numpy()
        return hashlib.blake2b(weights.tobytes(), digest_size=16).digest()

    def _check_trunk(self) -> None:
        digest = self._digest_trunk()
        if digest != self._trunk_digest:
            self._rows.clear()
            self._store = self._store[:0]
            self._part_rows.clear()
            self._trunk_digest = digest

    def features(self, obs: np.ndarray) -> torch.Tensor:
        """Features (N, feature_dim) of uint8 images (N, H, W, C), computing only unseen images."""
        self._check_trunk()
        rows = self._row_indices([obs])[0]
        return self._store[rows]

    def features_of(self, data: Dataset | Aggregate) -> torch.Tensor:
        """Features (N, feature_dim) of a dataset's images, in its row order.

        A part that carries its features (:attr:`Dataset.features`: the pass that acted on its
        images computed them, on this trunk) gives them as they are: its images are never hashed
        or passed through the trunk again. The other parts give the same numbers as
        ``features(part.obs)``, without concatenating an aggregate's images or hashing a part
        already read.
        """
        self._check_trunk()
        unread = [part for part in data.parts if part.features is None and part not in self._part_rows]
        if unread:
            for part, rows in zip(unread, self._row_indices([part.obs for part in unread])):
                self._part_rows[part] = rows
        chunks = [
            torch.from_numpy(part.features) if part.features is not None else self._store[self._part_rows[part]]
            for part in data.parts
        ]
        return torch.cat(chunks)  # a copy: the caller may change it

    def _row_indices(self, images: list[np.ndarray]) -> list[torch.Tensor]:
        """The store's rows of each array of ``images``, after computing the unseen ones.

        Unseen images are passed through the trunk in the order they appear across all arrays,
        in batches of ``batch_size``: the batches (and so the numbers) are those of one call on
        the arrays' concatenation.
        """
        if not all(images_kept(obs) for obs in images):
            raise RuntimeError(
                "features were asked of images that were not kept (a laned episode keeps only the "
                "features it acted on): read them with FeatureCache.features_of from the episode's dataset"
            )
        images = [np.ascontiguousarray(obs) for obs in images]
        keys = [[hashlib.blake2b(image, digest_size=16).digest() for image in obs] for obs in images]
        missing: dict[bytes, tuple[int, int]] = {}
        for a, array_keys in enumerate(keys):
            for i, key in enumerate(array_keys):
                if key not in self._rows and key not in missing:
                    missing[key] = (a, i)
        if missing:
            where = list(missing.values())
            # no_grad rather than inference_mode: the cached tensors later feed a head that trains
            with torch.no_grad():
                chunks = [
                    self.policy.net.features(torch.from_numpy(_gather(images, where[s : s + self.batch_size])))
                    for s in range(0, len(where), self.batch_size)
                ]
            start = len(self._store)
            self._store = torch.cat([self._store, *chunks])
            self._rows.update({key: start + j for j, key in enumerate(missing)})
            self.computed += len(missing)
        return [torch.tensor([self._rows[key] for key in array_keys], dtype=torch.long) for array_keys in keys]


def _gather(images: list[np.ndarray], where: list[tuple[int, int]]) -> np.ndarray:
    """The images at ``(array, row)`` positions ``where`` (ordered by array, then row), stacked.

    Gathered a batch at a time, so that no copy of a whole aggregate's images is ever made.
    """
    first, last = where[0], where[-1]
    if first[0] == last[0] and last[1] - first[1] == len(where) - 1 and images[first[0]].flags.writeable:
        return images[first[0]][first[1] : last[1] + 1]  # consecutive rows of one array: a view
    by_array: dict[int, list[int]] = {}
    for a, row in where:
        by_array.setdefault(a, []).append(row)
    return np.concatenate([images[a][rows] for a, rows in by_array.items()])
