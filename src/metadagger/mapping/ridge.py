"""The ``ridge`` mapper kind: closed-form ridge regression of the update w_DA - w_BC on w_BC.

The baseline any learned mapper must beat. It works in the standardised space of the ``all``
scaler (fitted on w_BC and w_DA together), where the update keeps its meaning:
``u = y - x = ū + (x - x̄) A``, with ``A`` shrunk toward zero (so toward "add the mean training
update to w_BC"). With N training pairs and d head weights (N << d here) the solve is the dual
``A = Xc^T (Xc Xc^T + λ I)^-1 Uc``: an N x N eigendecomposition per fold.

The regularisation λ is chosen by 5-fold cross-validation on the training pairs only, over a
grid that is fixed in advance and scaled by the mean non-zero eigenvalue of ``Xc Xc^T`` (so it
does not depend on the head's size); the chosen value is saved with the mapper.
"""

from __future__ import annotations

import torch
from torch import nn

#: λ as a multiple of the mean non-zero eigenvalue of the training Gram matrix; fixed in advance.
RELATIVE_ALPHAS = (1e-3, 1e-2, 1e-1, 1.0, 10.0, 100.0, 1000.0)
#: Cross-validation folds (row i of the training pairs is in fold i % FOLDS).
FOLDS = 5


def build_ridge(dim: int, *, generator: torch.Generator | None = None, **_: object) -> dict[str, nn.Module]:
    """The one affine map from standardised w_BC to standardised w_DA, set by :func:`fit_ridge`."""
    return {"ridge": nn.Linear(dim, dim)}


class DualRidge:
    """The dual ridge solution on training rows ``x`` and targets ``u`` (float64), for any λ."""

    def __init__(self, x: torch.Tensor, u: torch.Tensor) -> None:
        self.x_mean, self.u_mean = x.mean(dim=0), u.mean(dim=0)
        self.xc = x - self.x_mean
        values, self.vectors = torch.linalg.eigh(self.xc @ self.xc.T)
        self.values = values.clamp_min(0.0)
        self.projected = self.vectors.T @ (u - self.u_mean)

    def coefficients(self, alpha: float) -> torch.Tensor:
        """``A = Xc^T V diag(1 / (e + α)) V^T Uc`` (d x d)."""
        return self.xc.T @ (self.vectors @ (self.projected / (self.values + alpha)[:, None]))

    def predict(self, x: torch.Tensor, alpha: float) -> torch.Tensor:
        """The targets predicted for rows ``x``."""
        return self.u_mean + (x - self.x_mean) @ self.coefficients(alpha)


def alpha_scale(x: torch.Tensor) -> float:
    """The unit of :data:`RELATIVE_ALPHAS`: the mean non-zero eigenvalue of the centred Gram matrix
    of rows ``x`` (its rank is at most min(N, d)); 1 when ``x`` does not vary."""
    scale = float((x - x.mean(dim=0)).pow(2).sum()) / min(x.shape)
    return scale if scale > 0 else 1.0


def fold_masks(n: int) -> list[torch.Tensor]:
    """The held-out rows of each cross-validation fold (row i is in fold i mod :data:`FOLDS`)."""
    folds = torch.arange(n) % min(FOLDS, n)
    return [folds == fold for fold in range(min(FOLDS, n))]


def fit_ridge(core: nn.Module, x: torch.Tensor, y: torch.Tensor) -> dict[str, float]:
    """Set ``core`` (an ``nn.Linear(d, d)``) to the ridge map from ``x`` to ``y`` (standardised
    training rows ``[N, d]``); λ by :data:`FOLDS`-fold cross-validation over
    :data:`RELATIVE_ALPHAS`. Returns the chosen ``alpha`` (absolute and relative to the mean
    eigenvalue) and its cross-validated mean squared error of the update."""
    x64, u64 = x.to(torch.float64), (y - x).to(torch.float64)
    n = len(x64)
    scale = alpha_scale(x64)
    errors = torch.zeros(len(RELATIVE_ALPHAS), dtype=torch.float64)
    for held in fold_masks(n):
        dual = DualRidge(x64[~held], u64[~held])
        for i, relative in enumerate(RELATIVE_ALPHAS):
            errors[i] += (dual.predict(x64[held], relative * scale) - u64[held]).pow(2).sum()
    errors /= n * x.shape[1]
    relative = RELATIVE_ALPHAS[int(torch.argmin(errors))]
    dual = DualRidge(x64, u64)
    a = dual.coefficients(relative * scale)
    with torch.no_grad():
        core.weight.copy_((torch.eye(a.shape[0], dtype=torch.float64) + a.T).to(torch.float32))
        core.bias.copy_((dual.u_mean - dual.x_mean @ a).to(torch.float32))
    return {"alpha": relative * scale, "relative_alpha": relative, "cv_mse": float(errors.min())}
