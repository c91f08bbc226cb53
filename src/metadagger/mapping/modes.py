"""The ``modes`` mapper kind: pick the training pairs' cluster of w_DA that w_BC points to.

Where seeds fall into groups that need different heads (a task family whose cars are mirrored
or not), the mean w_DA of every seed is no seed's head, but the mean w_DA of the seed's own group
may be. This kind clusters the standardised training w_DA into K groups (k-means, k-means++
seeding from a fixed generator), fits a ridge classifier from standardised w_BC to the group
(one-hot targets, dual solve as :mod:`metadagger.mapping.ridge`), and maps a w_BC to the mean w_DA
of the group its classifier scores highest. K = 1 is the mean-DA control.

K (1 to :data:`MAX_GROUPS`) and the classifier's λ are chosen together by 5-fold
cross-validation on the training pairs only (clusters and classifier refitted in every fold),
scored by the weight-space error of the predicted head; the grid is fixed in advance.
"""

from __future__ import annotations

import torch
from torch import nn

from metadagger.mapping.ridge import RELATIVE_ALPHAS, DualRidge, alpha_scale, fold_masks

#: The largest number of groups tried.
MAX_GROUPS = 6
#: k-means restarts (the lowest within-group error is kept) and iterations per restart.
RESTARTS, ITERATIONS = 8, 50


class GroupMeans(nn.Module):
    """``x -> means[argmax(x W + b)]``; unused groups have bias -inf (state kept in buffers)."""

    def __init__(self, dim: int) -> None:
        super().__init__()
        self.register_buffer("weight", torch.zeros(dim, MAX_GROUPS))
        self.register_buffer("bias", torch.full((MAX_GROUPS,), float("-inf")))
        self.register_buffer("means", torch.zeros(MAX_GROUPS, dim))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.means[torch.argmax(x @ self.weight + self.bias, dim=1)]


def build_modes(dim: int, **_: object) -> dict[str, nn.Module]:
    """The untrained :class:`GroupMeans`, set by :func:`fit_modes`."""
    return {"modes": GroupMeans(dim)}


def _distances(y: torch.Tensor, centres: torch.Tensor) -> torch.Tensor:
    """Euclidean distances [N, k], each summed and rooted pair by pair: cdist's matrix-product form
    roots with MKL's vector math, whose bits depend on the CPU (docs/determinism.md)."""
    return torch.cdist(y, centres, compute_mode="donot_use_mm_for_euclid_dist")


def _kmeans(y: torch.Tensor, k: int) -> torch.Tensor:
    """Group labels of the rows of ``y`` (float64) into ``k`` groups; deterministic."""
    generator = torch.Generator().manual_seed(0)
    best, best_error = torch.zeros(len(y), dtype=torch.long), float("inf")
    for _ in range(RESTARTS):
        centres = y[torch.randint(len(y), (1,), generator=generator)]
        while len(centres) < k:  # k-means++: the next centre far from the chosen ones
            distance = _distances(y, centres).min(dim=1).values.pow(2)
            pick = (
                torch.multinomial(distance / distance.sum(), 1, generator=generator)
                if distance.sum() > 0
                else torch.zeros(1, dtype=torch.long)
            )
            centres = torch.cat([centres, y[pick]])
        for _ in range(ITERATIONS):
            labels = _distances(y, centres).argmin(dim=1)
            moved = torch.stack([y[labels == j].mean(dim=0) if (labels == j).any() else centres[j] for j in range(k)])
            if torch.equal(moved, centres):
                break
            centres = moved
        error = float((y - centres[labels]).pow(2).sum())
        if error < best_error:
            best, best_error = labels, error
    return best


class _Classifier:
    """Groups of the rows ``y`` (k-means), their means, and a ridge from rows ``x`` to one-hot groups."""

    def __init__(self, x: torch.Tensor, y: torch.Tensor, k: int) -> None:
        _, labels = torch.unique(_kmeans(y, k), return_inverse=True)  # empty groups dropped
        self.k = int(labels.max()) + 1
        self.means = torch.stack([y[labels == j].mean(dim=0) for j in range(self.k)])
        self.ridge = DualRidge(x, nn.functional.one_hot(labels, self.k).to(x.dtype))

    def predict(self, x: torch.Tensor, alpha: float) -> torch.Tensor:
        return self.means[self.ridge.predict(x, alpha).argmax(dim=1)]


def fit_modes(core: nn.Module, x: torch.Tensor, y: torch.Tensor) -> dict[str, float]:
    """Set ``core`` (a :class:`GroupMeans`) from standardised training rows ``x`` (w_BC) and ``y``
    (w_DA); K and λ by cross-validation. Returns the chosen ``groups``, ``alpha`` (absolute and
    relative) and the cross-validated mean squared error."""
    x64, y64 = x.to(torch.float64), y.to(torch.float64)
    n = len(x64)
    scale = alpha_scale(x64)
    grid = [(k, relative) for k in range(1, MAX_GROUPS + 1) for relative in RELATIVE_ALPHAS]
    errors = torch.zeros(len(grid), dtype=torch.float64)
    for held in fold_masks(n):
        fits = {k: _Classifier(x64[~held], y64[~held], k) for k in range(1, min(MAX_GROUPS, int((~held).sum())) + 1)}
        for i, (k, relative) in enumerate(grid):
            errors[i] += (
                (fits[k].predict(x64[held], relative * scale) - y64[held]).pow(2).sum() if k in fits else float("inf")
            )
    errors /= n * x.shape[1]
    k, relative = grid[int(torch.argmin(errors))]
    fit = _Classifier(x64, y64, k)
    k = fit.k
    with torch.no_grad():
        core.weight.zero_()
        core.bias.fill_(float("-inf"))
        core.means.zero_()
        coefficients = fit.ridge.coefficients(relative * scale)
        core.weight[:, :k] = coefficients.to(torch.float32)
        core.bias[:k] = (fit.ridge.u_mean - fit.ridge.x_mean @ coefficients).to(torch.float32)
        core.means[:k] = fit.means.to(torch.float32)
    return {"groups": k, "alpha": relative * scale, "relative_alpha": relative, "cv_mse": float(errors.min())}
