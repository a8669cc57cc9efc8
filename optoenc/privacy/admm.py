"""ADMM for the paper's reconstruction problem (eq. ``lensless_inverse``).

    x_hat = argmin_{x >= 0} 1/2 ||y - A x||^2 + tau ||Psi x||_1

with ``A`` the encoder's scene operator and ``Psi`` anisotropic finite
differences (:mod:`optoenc.privacy.tv`). Splitting ``u = Psi x`` and
``w = x`` (scaled dual variables ``du``, ``dw``), each iteration is

    x  = (A^T A + mu_tv Psi^T Psi + mu_nonneg I)^-1 (A^T y + mu_tv Psi^T (u - du) + mu_nonneg (w - dw))
    u  = soft(Psi x + du, tau / mu_tv)
    w  = max(x + dw, 0)
    du += Psi x - u;   dw += x - w

The x-step is exact: the small dense matrix is inverted once in float64 and
the iterations run as float32 matrix products on the whole batch (scenes are
in [0, 1]; float32 rounding is far below the 40 dB noise). The problem is solved for
the operator scaled to unit spectral norm (``A / ||A||``, ``y / ||A||``: the
same minimiser with ``tau`` scaled by ``||A||^2``), so one ``tau`` and one
pair of penalties suit every encoder whatever its light throughput. The
returned estimate is ``w`` (non-negative by construction).
"""

from __future__ import annotations


import torch

from .settings import ADMMConfig
from ..encoders.operator import SceneOperator
from .operators import DTYPE
from .tv import differences, differences_adjoint, laplacian

__all__ = ["ADMMConfig", "admm", "objective"]


def _soft(v: torch.Tensor, t: float) -> torch.Tensor:
    return torch.sign(v) * (v.abs() - t).clamp_min(0)


def objective(op: SceneOperator, x: torch.Tensor, y: torch.Tensor, tau: float) -> torch.Tensor:
    """Per-example value of the (unit-norm scaled) objective at ``x`` (``inf`` where ``x`` has a negative entry)."""
    s = op.norm()
    r = op.forward(x) / s - y.to(DTYPE) / s
    xf = x.reshape(x.shape[0], -1).to(DTYPE)
    val = 0.5 * r.flatten(1).pow(2).sum(1) + tau * differences(xf, op.scene_shape).abs().sum(1)
    return torch.where((xf < 0).any(1), torch.full_like(val, float("inf")), val)


@torch.no_grad()
def admm(op: SceneOperator, y: torch.Tensor, config: ADMMConfig | None = None) -> torch.Tensor:
    """Reconstruct ``(B, S, h, w)`` scenes from ``(B, C, a, b)`` embeddings ``y`` (see the module docstring)."""
    cfg = config or ADMMConfig()
    s = op.norm()
    Y = y.reshape(y.shape[0], -1).to(DTYPE)
    n, shape = op.shape[1], op.scene_shape
    M = op.gram() / s**2 + cfg.mu_tv * laplacian(shape) + cfg.mu_nonneg * torch.eye(n, dtype=DTYPE)
    minv = torch.linalg.inv(M).to(torch.float32)
    aty = (Y @ op.matrix / s**2).to(torch.float32)
    x = torch.zeros(Y.shape[0], n, dtype=torch.float32)
    w, dw = x.clone(), x.clone()
    u = differences(x, shape)
    du = u.clone()
    for _ in range(cfg.iterations):
        rhs = aty + cfg.mu_tv * differences_adjoint(u - du, shape) + cfg.mu_nonneg * (w - dw)
        x = rhs @ minv  # minv is symmetric
        px = differences(x, shape)
        u = _soft(px + du, cfg.tau / cfg.mu_tv)
        w = (x + dw).clamp_min(0)
        du += px - u
        dw += x - w
    return w.reshape(-1, *shape).to(DTYPE)
