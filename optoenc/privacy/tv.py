"""Anisotropic finite differences ``Psi`` (the paper's sparsifying operator) and its adjoint.

``Psi x`` stacks the forward differences along rows and along columns of each
scene channel, without wrap-around (Neumann boundary): ``(h-1)*w + h*(w-1)``
values per channel. ``Psi^T Psi`` is the Neumann graph Laplacian.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

__all__ = ["differences", "differences_adjoint", "laplacian"]


def differences(x: torch.Tensor, shape: tuple[int, int, int]) -> torch.Tensor:
    """``Psi x`` for ``(B, S*h*w)`` flattened scenes of ``shape = (S, h, w)``: ``(B, S*((h-1)*w + h*(w-1)))``."""
    img = x.reshape(x.shape[0], *shape)
    dv = img[..., 1:, :] - img[..., :-1, :]
    dh = img[..., :, 1:] - img[..., :, :-1]
    return torch.cat([dv.reshape(x.shape[0], -1), dh.reshape(x.shape[0], -1)], dim=1)


def differences_adjoint(g: torch.Tensor, shape: tuple[int, int, int]) -> torch.Tensor:
    """``Psi^T g``: ``(B, S*((h-1)*w + h*(w-1)))`` -> ``(B, S*h*w)``."""
    S, h, w = shape
    nv = S * (h - 1) * w
    gv = g[:, :nv].reshape(g.shape[0], S, h - 1, w)
    gh = g[:, nv:].reshape(g.shape[0], S, h, w - 1)
    pv = F.pad(gv, (0, 0, 1, 1))  # (D^T g)[i] = g[i-1] - g[i], zero outside
    ph = F.pad(gh, (1, 1))
    out = (pv[..., :-1, :] - pv[..., 1:, :]) + (ph[..., :, :-1] - ph[..., :, 1:])
    return out.reshape(g.shape[0], -1)


def _second_difference(n: int, dtype) -> torch.Tensor:
    d = torch.zeros(max(n - 1, 0), n, dtype=dtype)
    idx = torch.arange(n - 1)
    d[idx, idx], d[idx, idx + 1] = -1.0, 1.0
    return d.T @ d


def laplacian(shape: tuple[int, int, int], dtype=torch.float64) -> torch.Tensor:
    """``Psi^T Psi`` as a dense ``(S*h*w, S*h*w)`` matrix (Kronecker sums, block diagonal over channels)."""
    S, h, w = shape
    lap = torch.kron(_second_difference(h, dtype), torch.eye(w, dtype=dtype)) + torch.kron(
        torch.eye(h, dtype=dtype), _second_difference(w, dtype)
    )
    return torch.block_diag(*([lap] * S))
