"""The ``ridge`` mapper kind: closed-form ridge regression of the update w_DA - w_BC on w_BC.

The baseline any learned mapper must beat. It works in the standardised space of the ``all``
scaler (fitted on w_BC and w_DA together), where the update keeps its meaning:
``u = y - x = ū + (x - x̄) A``, with ``A`` shrunk toward zero (so toward "add the mean training
update to w_BC"). With N training pairs and d head weights (N << d here) the solve is the dual
``A = Xc^T (Xc Xc^T + λ I)^-1 Uc``: an N x N eigendecomposition per fold.

The regularisation λ is chosen by 5-fold cross-validation on the training pairs only, over a
grid that is fixed in advance and scaled by the mean non-zero eigenvalue of ``Xc Xc^T`` (so it
does not depend on the head's size); the chosen value is saved with the mapper.

The same fit serves the ``conditioned`` kind, whose rows are ``[x, c]``: the standardised w_BC
followed by the standardised seed context (k more columns). The update is still ``y - x``; the
context columns enter only the regression, multiplied by a weight chosen with λ by the same
cross-validation from :data:`CONTEXT_WEIGHTS` (0 gives the plain ridge map, so the context is used
only where it predicts held-out updates better).
"""

from __future__ import annotations

import torch
from torch import nn

#: λ as a multiple of the mean non-zero eigenvalue of the training Gram matrix; fixed in advance.
RELATIVE_ALPHAS = (1e-3, 1e-2, 1e-1, 1.0, 10.0, 100.0, 1000.0)
#: Cross-validation folds (row i of the training pairs is in fold i % FOLDS).
FOLDS = 5
#: Weights of the context columns, as multiples of sqrt(d / k), which gives the d head columns and
#: the k context columns the same total variance; fixed in advance.
CONTEXT_WEIGHTS = (0.0, 0.25, 1.0, 4.0)


def build_ridge(
    dim: int, *, context_dim: int = 0, generator: torch.Generator | None = None, **_: object
) -> dict[str, nn.Module]:
    """The one affine map from standardised w_BC (and, with ``context_dim``, the standardised
    context) to standardised w_DA, set by :func:`fit_ridge`."""
    return {"ridge": nn.Linear(dim + context_dim, dim)}


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
    """Set ``core`` (an ``nn.Linear(d + k, d)``) to the ridge map from ``x`` ``[N, d + k]`` to
    ``y`` ``[N, d]`` (standardised training rows; the first d columns of ``x`` are w_BC's, any
    further k a context's); λ, and the context columns' weight when k > 0, by :data:`FOLDS`-fold
    cross-validation over :data:`RELATIVE_ALPHAS` (and :data:`CONTEXT_WEIGHTS`). Returns the chosen
    ``alpha`` (absolute and relative to the mean eigenvalue), ``context_weight`` when k > 0, and
    the cross-validated mean squared error of the update."""
    d = y.shape[1]
    x64 = x.to(torch.float64)
    u64 = (y - x[:, :d]).to(torch.float64)
    n, k = len(x64), x.shape[1] - d
    weights = CONTEXT_WEIGHTS if k > 0 else (None,)
    balance = (d / k) ** 0.5 if k > 0 else 1.0
    best: tuple[float, float | None, float] | None = None
    for weight in weights:
        z = x64 if weight is None else _weighted(x64, d, weight * balance)
        scale = alpha_scale(z)
        errors = torch.zeros(len(RELATIVE_ALPHAS), dtype=torch.float64)
        for held in fold_masks(n):
            dual = DualRidge(z[~held], u64[~held])
            for i, relative in enumerate(RELATIVE_ALPHAS):
                errors[i] += (dual.predict(z[held], relative * scale) - u64[held]).pow(2).sum()
        errors /= n * d
        i = int(torch.argmin(errors))
        if best is None or float(errors[i]) < best[2]:
            best = (RELATIVE_ALPHAS[i], weight, float(errors[i]))
    relative, weight, cv_mse = best
    z = x64 if weight is None else _weighted(x64, d, weight * balance)
    scale = alpha_scale(z)
    dual = DualRidge(z, u64)
    a = dual.coefficients(relative * scale)
    # the map of z = x S (S scales the context columns) is the map of x with coefficients S A
    effective = a if weight is None else _weighted(a.T, d, weight * balance).T
    identity = torch.eye(d + k, d, dtype=torch.float64)
    with torch.no_grad():
        core.weight.copy_((identity + effective).T.to(torch.float32))
        core.bias.copy_((dual.u_mean - dual.x_mean @ a).to(torch.float32))
    chosen = {"alpha": relative * scale, "relative_alpha": relative, "cv_mse": cv_mse}
    return chosen if weight is None else {**chosen, "context_weight": weight}


def _weighted(x: torch.Tensor, d: int, weight: float) -> torch.Tensor:
    """``x`` with the columns after the first ``d`` multiplied by ``weight``."""
    return torch.cat([x[:, :d], x[:, d:] * weight], dim=1)
