"""A whole-policy fit's images, each batch gathered from a dataset's parts instead of one concatenated copy.

DAgger's aggregate grows by a round's rollouts; concatenating its images for a whole-policy fit
held every image twice at the last round (pi*'s fit was the largest process of a run). A batch
gathered from the parts holds the same bytes as the same rows of the concatenation, so the fit
computes exactly what it computed on the copy.
"""

from __future__ import annotations

import warnings

import torch

from metadagger.imitation.data import Aggregate, Dataset


class ImageRows:
    """The images of ``data``'s parts, indexed as if they were one (N, H, W, C) uint8 tensor."""

    def __init__(self, data: Dataset | Aggregate) -> None:
        with warnings.catch_warnings():  # images loaded read-only are only ever read here
            warnings.filterwarnings("ignore", message="The given NumPy array is not writable")
            self.parts = [torch.from_numpy(part.obs) for part in data.parts]
        sizes = torch.tensor([len(part) for part in self.parts])
        self.ends = torch.cumsum(sizes, 0)
        self.starts = self.ends - sizes

    def __len__(self) -> int:
        return int(self.ends[-1])

    def __getitem__(self, rows: torch.Tensor) -> torch.Tensor:
        """The images of ``rows`` (int64 indices into the whole), in their order: a new tensor."""
        if len(self.parts) == 1:
            return self.parts[0][rows]
        part_of = torch.bucketize(rows, self.ends, right=True)
        batch = torch.empty((len(rows), *self.parts[0].shape[1:]), dtype=torch.uint8)
        for part in part_of.unique().tolist():
            where = part_of == part
            batch[where] = self.parts[part][rows[where] - self.starts[part]]
        return batch

    def to(self, device: torch.device | str) -> torch.Tensor:
        """Every image on ``device`` as one tensor, copied there part by part."""
        return torch.cat([part.to(device) for part in self.parts])
