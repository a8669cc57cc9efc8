"""Linear baselines: Tikhonov-regularised least squares and the truncated-SVD pseudo-inverse."""

from __future__ import annotations


import torch

from .settings import TikhonovConfig
from ..encoders.operator import SceneOperator
from .operators import DTYPE

__all__ = ["TikhonovConfig", "tikhonov", "pseudo_inverse"]


@torch.no_grad()
def tikhonov(op: SceneOperator, y: torch.Tensor, lam: float | None = None) -> torch.Tensor:
    """``(A^T A + lam ||A||^2 I)^-1 A^T y``: the regularised least-squares estimate (may be negative)."""
    lam = TikhonovConfig().lam if lam is None else lam
    s = op.norm()
    M = op.gram() / s**2 + lam * torch.eye(op.shape[1], dtype=DTYPE)
    rhs = (y.reshape(y.shape[0], -1).to(DTYPE) @ op.matrix) / s**2
    return torch.linalg.solve(M, rhs.T).T.reshape(-1, *op.scene_shape)


@torch.no_grad()
def pseudo_inverse(op: SceneOperator, y: torch.Tensor, rcond: float | None = None) -> torch.Tensor:
    """``A^+ y`` with singular values below ``rcond * sigma_max`` dropped (minimum-norm least squares).

    Computed in scene space from the eigendecomposition of ``A^T A`` (its
    eigenvalues are the squared singular values), never an SVD of the tall matrix.
    """
    rcond = TikhonovConfig().rcond if rcond is None else rcond
    evals, vecs = torch.linalg.eigh(op.gram())
    keep = evals > (rcond**2) * evals[-1]
    v = vecs[:, keep]
    aty = y.reshape(y.shape[0], -1).to(DTYPE) @ op.matrix
    return ((aty @ v) / evals[keep] @ v.T).reshape(-1, *op.scene_shape)
