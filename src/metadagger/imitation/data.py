"""Supervised imitation data: images and the expert's labels for them."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Sequence

import numpy as np


def unkept_images(count: int, shape: tuple[int, ...]) -> np.ndarray:
    """A stand-in for ``count`` uint8 images of ``shape`` that were not kept: read-only, every stride
    zero, so it holds no memory however long the episode (:func:`images_kept` tells it apart)."""
    return np.broadcast_to(np.zeros((), dtype=np.uint8), (count, *shape))


def images_kept(obs: np.ndarray) -> bool:
    """Whether ``obs`` holds images rather than :func:`unkept_images`' stand-in."""
    return obs.size <= 1 or any(obs.strides)


def take_rows(obs: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """``obs[rows]`` (a mask or indices), a stand-in staying a stand-in rather than a copy of zeros."""
    if images_kept(obs):
        return obs[rows]
    return unkept_images(len(np.arange(len(obs))[rows]), obs.shape[1:])


# eq=False: a dataset is compared (and hashed) by identity, so it can key the feature cache's memo
@dataclass(frozen=True, eq=False)
class Dataset:
    """Observations and expert labels, row-aligned.

    Attributes:
        obs: (N, H, W, C) uint8 images.
        labels: (N,) int64 class indices (discrete learner) or (N, d) float32 vectors (continuous).
        features: (N, feature_dim) float32 trunk features of the images, where the pass that acted
            on them computed them (lockstep lanes); a head-only fit on the same trunk reads them
            instead of the images (:meth:`~metadagger.imitation.features.FeatureCache.features_of`).
    """

    obs: np.ndarray
    labels: np.ndarray
    features: np.ndarray | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.obs, np.ndarray) or self.obs.dtype != np.uint8 or self.obs.ndim != 4:
            raise ValueError(
                "obs must be a uint8 array of shape (N, H, W, C), got "
                f"{getattr(self.obs, 'dtype', type(self.obs).__name__)} "
                f"with shape {getattr(self.obs, 'shape', None)}"
            )
        labels = self.labels
        if not isinstance(labels, np.ndarray) or not (
            (labels.dtype == np.int64 and labels.ndim == 1) or (labels.dtype == np.float32 and labels.ndim == 2)
        ):
            raise ValueError(
                f"labels must be int64 of shape (N,) or float32 of shape (N, d), got "
                f"{getattr(labels, 'dtype', type(labels).__name__)} with shape {getattr(labels, 'shape', None)}"
            )
        if len(self.obs) != len(labels):
            raise ValueError(f"obs has {len(self.obs)} rows but labels has {len(labels)}; they must match")
        features = self.features
        if features is not None and (
            not isinstance(features, np.ndarray)
            or features.dtype != np.float32
            or features.ndim != 2
            or len(features) != len(labels)
        ):
            raise ValueError(
                f"features must be float32 of shape ({len(labels)}, feature_dim), got "
                f"{getattr(features, 'dtype', type(features).__name__)} with shape {getattr(features, 'shape', None)}"
            )

    def __len__(self) -> int:
        return len(self.obs)

    @property
    def discrete(self) -> bool:
        """Whether the labels are class indices."""
        return self.labels.dtype == np.int64

    @property
    def image_shape(self) -> tuple[int, ...]:
        """The shape of one observation, (H, W, C)."""
        return tuple(self.obs.shape[1:])

    @property
    def parts(self) -> tuple[Dataset, ...]:
        """The datasets this one is made of: itself."""
        return (self,)

    def concat(self, *others: Dataset) -> Dataset:
        """This dataset followed by ``others`` (rows appended in order, images copied; no features)."""
        aggregate = Aggregate((self, *others))
        return Dataset(obs=aggregate.obs, labels=aggregate.labels)

    @classmethod
    def empty(cls, like: Dataset) -> Dataset:
        """A dataset with no rows and the same image and label shapes as ``like``."""
        return cls(obs=like.obs[:0].copy(), labels=like.labels[:0].copy())


class Aggregate:
    """Datasets appended in order and kept apart, so that appending copies no image.

    DAgger's aggregated data grows by a rollout a round; copying every image at every round
    cost more than the head-only fits on them. ``obs`` and ``labels`` are concatenated on first
    use (whole-policy fits need them); head-only fits read the trunk features part by part
    (:meth:`~metadagger.imitation.features.FeatureCache.features_of`).

    Args:
        parts: the datasets, in order (at least one; same image shape and label layout); an
            aggregate among them contributes its parts.
    """

    def __init__(self, parts: Sequence[Dataset | Aggregate]) -> None:
        parts = tuple(part for item in parts for part in item.parts)
        if not parts:
            raise ValueError("an Aggregate needs at least one dataset")
        first = parts[0]
        for other in parts[1:]:
            if (
                other.obs.shape[1:] != first.obs.shape[1:]
                or other.labels.dtype != first.labels.dtype
                or other.labels.shape[1:] != first.labels.shape[1:]
            ):
                raise ValueError(
                    f"cannot concatenate obs {other.obs.shape[1:]} / labels "
                    f"{other.labels.dtype}{other.labels.shape[1:]} "
                    f"onto obs {first.obs.shape[1:]} / labels {first.labels.dtype}{first.labels.shape[1:]}"
                )
        self.parts: tuple[Dataset, ...] = parts

    def __len__(self) -> int:
        return sum(len(part) for part in self.parts)

    @property
    def discrete(self) -> bool:
        """Whether the labels are class indices."""
        return self.parts[0].discrete

    @property
    def image_shape(self) -> tuple[int, ...]:
        """The shape of one observation, (H, W, C)."""
        return self.parts[0].image_shape

    @cached_property
    def obs(self) -> np.ndarray:
        """Every part's images, concatenated (a copy, made once)."""
        return self.parts[0].obs if len(self.parts) == 1 else np.concatenate([part.obs for part in self.parts])

    @cached_property
    def labels(self) -> np.ndarray:
        """Every part's labels, concatenated."""
        return self.parts[0].labels if len(self.parts) == 1 else np.concatenate([part.labels for part in self.parts])

    def append(self, *others: Dataset | Aggregate) -> Aggregate:
        """A new aggregate: these parts followed by ``others``'."""
        return Aggregate((*self.parts, *others))
