"""Supervised imitation data: images and the expert's labels for them."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Dataset:
    """Observations and expert labels, row-aligned.

    Attributes:
        obs: (N, H, W, C) uint8 images.
        labels: (N,) int64 class indices (discrete learner) or (N, d) float32 vectors (continuous).
    """

    obs: np.ndarray
    labels: np.ndarray

    def __post_init__(self) -> None:
        if not isinstance(self.obs, np.ndarray) or self.obs.dtype != np.uint8 or self.obs.ndim != 4:
            raise ValueError(
                f"obs must be a uint8 array of shape (N, H, W, C), got {getattr(self.obs, 'dtype', type(self.obs).__name__)} "
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

    def __len__(self) -> int:
        return len(self.obs)

    @property
    def discrete(self) -> bool:
        """Whether the labels are class indices."""
        return self.labels.dtype == np.int64

    def concat(self, *others: Dataset) -> Dataset:
        """This dataset followed by ``others`` (rows appended in order)."""
        for other in others:
            if other.obs.shape[1:] != self.obs.shape[1:] or other.labels.dtype != self.labels.dtype or other.labels.shape[1:] != self.labels.shape[1:]:
                raise ValueError(
                    f"cannot concatenate obs {other.obs.shape[1:]} / labels {other.labels.dtype}{other.labels.shape[1:]} "
                    f"onto obs {self.obs.shape[1:]} / labels {self.labels.dtype}{self.labels.shape[1:]}"
                )
        parts = (self, *others)
        return Dataset(
            obs=np.concatenate([d.obs for d in parts]), labels=np.concatenate([d.labels for d in parts])
        )

    @classmethod
    def empty(cls, like: Dataset) -> Dataset:
        """A dataset with no rows and the same image and label shapes as ``like``."""
        return cls(obs=like.obs[:0].copy(), labels=like.labels[:0].copy())
