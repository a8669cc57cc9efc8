"""Decoders for reconstruction: a U-Net, and physics-informed solvers on the encoder's differentiable operator.

* ``unet``: the (normalised) embedding upsampled bilinearly to the scene grid, then a small U-Net
  (``levels`` halvings, ``width`` channels at full resolution, doubling per level) from the embedding's
  channels to the scene's. Scenes of any size (padded to a multiple of ``2^levels``, cropped back).
* ``tikhonov``: ``x = argmin ||A x - y||^2 + lambda s ||x||^2`` in closed form, ``A`` the encoder's
  operator as a matrix in the training graph (:meth:`SceneOperator.matrix_in_graph
  <optoenc.encoders.operator.SceneOperator.matrix_in_graph>`), ``s = ||A||_F^2 / n`` (the mean eigenvalue
  of ``A^T A``, so ``lambda`` is relative to the operator's scale) and ``log lambda`` learned. The solve
  runs in float64 on the smaller of the ``m x m`` or ``n x n`` systems (``m`` embedding readings, ``n``
  scene pixels), so gradients reach the mask.
* ``unrolled_admm``: ``iterations`` unrolled steps of ADMM for ``min ||A x - y||^2 + i(z >= 0)`` with
  ``x = z`` (scaled dual ``u``), as in LenslessPiCam's unrolled ADMM: the x-update solves the normal
  equations ``(A^T A + rho_k s I) x = A^T y + rho_k s (z - u)`` exactly, the z-update is a gradient
  step of size ``tau_k`` on a smoothed total variation followed by the non-negativity prox (ReLU); each
  ``log rho_k`` and ``tau_k`` is learned.

Either physics-informed decoder may be followed by the U-Net as a residual denoiser
(``decoder.denoiser=unet``: ``x + unet(x)`` on the scene grid). The closed-form solves hold the ``m x n``
operator matrix: meant for scenes up to a few thousand pixels per channel (MNIST's 28 x 28 at 24 x 32:
a 768 x 784 matrix); the U-Net alone has no such limit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from . import DecoderConfig, ImageDecoder
from ..errors import ConfigError
from ..settings import setting

__all__ = ["UNetBody", "UNetConfig", "UNet", "PhysicsConfig", "TikhonovConfig", "Tikhonov", "UnrolledADMMConfig",
           "UnrolledADMM", "regularised_solve"]


def _block(cin: int, cout: int) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, 3, padding=1, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True),
                         nn.Conv2d(cout, cout, 3, padding=1, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True))


class UNetBody(nn.Module):
    """A U-Net ``(B, cin, h, w) -> (B, cout, h, w)``: ``levels`` max-pool halvings, bilinear upsampling, skip
    connections; the input padded (replicated edges) to a multiple of ``2^levels`` and the output cropped back."""

    def __init__(self, cin: int, cout: int, width: int = 16, levels: int = 2):
        super().__init__()
        self.levels = int(levels)
        chans = [width * 2**k for k in range(levels + 1)]
        self.down = nn.ModuleList([_block(cin, chans[0])] + [_block(chans[k - 1], chans[k]) for k in range(1, levels + 1)])
        self.up = nn.ModuleList([_block(chans[k + 1] + chans[k], chans[k]) for k in reversed(range(levels))])
        self.out = nn.Conv2d(chans[0], cout, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h, w = x.shape[-2:]
        m = 2**self.levels
        ph, pw = -h % m, -w % m
        if ph or pw:
            x = F.pad(x, (0, pw, 0, ph), mode="replicate")
        skips = []
        for k, block in enumerate(self.down):
            x = block(x if k == 0 else F.max_pool2d(x, 2))
            skips.append(x)
        skips.pop()
        for block in self.up:
            skip = skips.pop()
            x = F.interpolate(x, size=skip.shape[-2:], mode="bilinear", align_corners=False)
            x = block(torch.cat([x, skip], 1))
        return self.out(x)[..., :h, :w]


@dataclass
class UNetConfig(DecoderConfig):
    width: int = setting(16, "U-Net channels at full resolution (doubled at each level)", ge=1, le=512)
    levels: int = setting(2, "U-Net levels (halvings of the scene grid)", ge=1, le=5)


class _Upsampled(nn.Module):
    def __init__(self, body: nn.Module, size: tuple[int, int]):
        super().__init__()
        self.body, self.size = body, tuple(size)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.body(F.interpolate(x, size=self.size, mode="bilinear", align_corners=False))


class UNet(ImageDecoder):
    """U-Net: the embedding upsampled to the scene grid, then a small U-Net to the scene's channels."""

    name = "unet"
    Config = UNetConfig

    def build(self) -> nn.Module:
        S, h, w = self.out_shape
        return _Upsampled(UNetBody(self.in_shape[0], S, self.config.width, self.config.levels), (h, w))


def regularised_solve(M: torch.Tensor, rhs: torch.Tensor, lam: torch.Tensor, spectrum=None) -> torch.Tensor:
    """``(M^T M + lam I)^{-1} rhs`` for ``rhs`` ``(B, n)`` and ``M`` ``(m, n)``, differentiable; through the
    ``m x m`` system where ``m < n`` (Woodbury: ``(rhs - M^T (M M^T + lam I)^{-1} M rhs) / lam``).

    ``spectrum``: :func:`gram_spectrum` of ``M``, for a fixed ``M``: the solve is then two products with its
    eigenvectors for any ``lam`` (no factorisation; no gradient with respect to ``M``)."""
    m, n = M.shape
    if spectrum is not None:
        ev, V = spectrum
        if n <= m:
            return ((rhs @ V) / (ev + lam)) @ V.T
        return (rhs - (((rhs @ M.T) @ V) / (ev + lam)) @ V.T @ M) / lam
    if n <= m:
        K = M.T @ M + lam * torch.eye(n, dtype=M.dtype, device=M.device)
        return torch.linalg.solve(K, rhs.T).T
    K = M @ M.T + lam * torch.eye(m, dtype=M.dtype, device=M.device)
    return (rhs - torch.linalg.solve(K, (rhs @ M.T).T).T @ M) / lam


def gram_spectrum(M: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Eigenvalues and eigenvectors of the smaller Gram matrix of ``M`` (``M^T M`` where ``n <= m``, else
    ``M M^T``), detached: what :func:`regularised_solve` needs to solve for any ``lam`` without a factorisation."""
    M = M.detach()
    m, n = M.shape
    ev, V = torch.linalg.eigh(M.T @ M if n <= m else M @ M.T)
    return ev.clamp_min(0), V  # a Gram matrix is positive semi-definite: rounding's negative eigenvalues are 0


@dataclass
class PhysicsConfig(DecoderConfig):
    denoiser: str = setting("none", "after the physics-informed solve: 'unet' (a residual U-Net on the scene grid) or "
                            "'none'", choices=("none", "unet"))
    width: int = setting(16, "the denoiser U-Net's channels at full resolution", ge=1, le=512)
    levels: int = setting(2, "the denoiser U-Net's levels", ge=1, le=5)


class _Physics(ImageDecoder):
    """Base of the physics-informed decoders: the raw measurement, the operator matrix, an optional denoiser."""

    needs_encoder = True

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        if self.norm_kind != "none":
            raise ConfigError("decoder.embedding_norm", self.config.embedding_norm,
                              f"{self.name} reads the raw measurement (y = A x): use 'auto' or 'none'")
        if tuple(self.encoder.output_shape) != self.in_shape:
            raise ConfigError("decoder in_shape", self.in_shape, f"must be the encoder's output {self.encoder.output_shape}")
        S = self.out_shape[0]
        self.denoiser = UNetBody(S, S, self.config.width, self.config.levels) if self.config.denoiser == "unet" else None

    def build(self) -> nn.Module:
        return nn.Identity()

    def matrix(self) -> torch.Tensor:
        """The operator ``A`` ``(m, n)`` in float64, in the graph of the encoder's parameters."""
        S, h, w = self.out_shape
        return self.encoder.operator((h, w), scene_channels=S).matrix_in_graph(torch.float64)

    def spectrum(self, M: torch.Tensor):
        """:func:`gram_spectrum` of ``M`` where the encoder is fixed (its operator cannot change while it trains,
        so one eigendecomposition serves every step: a solve is then products only), kept while ``M`` holds the
        same values; None for a learnable encoder (its solves stay factorisations in the mask's graph)."""
        if getattr(self.encoder, "learnable", True):
            return None
        cached = getattr(self, "_spectrum", None)
        if cached is None or cached[0].shape != M.shape or cached[0].device != M.device or not torch.equal(cached[0], M):
            cached = (M.detach().clone(), gram_spectrum(M))
            self._spectrum = cached  # a plain attribute: not in the state dict, rebuilt after loading
        return cached[1]

    def solve(self, y: torch.Tensor, M: torch.Tensor) -> torch.Tensor:
        """``(B, m)`` float64 measurements -> ``(B, n)`` scenes."""
        raise NotImplementedError

    def forward(self, embedding: torch.Tensor) -> torch.Tensor:
        M = self.matrix()
        x = self.solve(embedding.flatten(1).to(M.dtype), M).to(embedding.dtype).view(-1, *self.out_shape)
        return x if self.denoiser is None else x + self.denoiser(x)


@dataclass
class TikhonovConfig(PhysicsConfig):
    lam: float = setting(1e-2, "starting regularisation weight lambda, relative to the operator's mean "
                         "eigenvalue ||A||_F^2 / n", gt=0)
    learn_lambda: bool = setting(True, "learn log lambda with the other parameters")


class Tikhonov(_Physics):
    """Tikhonov: argmin ||Ax - y||^2 + lambda ||x||^2 in closed form on the encoder's operator, lambda learned."""

    name = "tikhonov"
    Config = TikhonovConfig

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.log_lambda = nn.Parameter(torch.tensor(math.log(self.config.lam)), requires_grad=self.config.learn_lambda)

    def solve(self, y: torch.Tensor, M: torch.Tensor) -> torch.Tensor:
        m, n = M.shape
        lam = self.log_lambda.to(M.dtype).exp() * (M * M).sum() / n
        spectrum = self.spectrum(M)
        if n <= m:
            return regularised_solve(M, y @ M, lam, spectrum)
        if spectrum is not None:
            ev, V = spectrum
            return ((y @ V) / (ev + lam)) @ V.T @ M
        K = M @ M.T + lam * torch.eye(m, dtype=M.dtype, device=M.device)
        return torch.linalg.solve(K, y.T).T @ M  # M^T (M M^T + lam I)^{-1} y: the same x, the smaller system


@dataclass
class UnrolledADMMConfig(PhysicsConfig):
    iterations: int = setting(5, "unrolled ADMM iterations K", ge=1, le=100)
    rho: float = setting(1e-1, "starting penalty rho of every iteration, relative to the operator's mean eigenvalue", gt=0)
    tv: float = setting(0.0, "starting step of every iteration's smoothed total-variation step (learned)", ge=0)


def _tv_gradient(x: torch.Tensor, eps: float = 1e-3) -> torch.Tensor:
    """Gradient of the smoothed isotropic total variation ``sum sqrt(dx^2 + dy^2 + eps^2)`` of ``(B, S, h, w)``."""
    dx = F.pad(x[..., :, 1:] - x[..., :, :-1], (0, 1))
    dy = F.pad(x[..., 1:, :] - x[..., :-1, :], (0, 0, 0, 1))
    mag = torch.sqrt(dx * dx + dy * dy + eps * eps)
    px, py = dx / mag, dy / mag
    div = (px - F.pad(px[..., :, :-1], (1, 0))) + (py - F.pad(py[..., :-1, :], (0, 0, 1, 0)))
    return -div


class UnrolledADMM(_Physics):
    """Unrolled ADMM: K iterations (normal-equation x-update, TV step and non-negativity), step sizes learned."""

    name = "unrolled_admm"
    Config = UnrolledADMMConfig

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        K = self.config.iterations
        self.log_rho = nn.Parameter(torch.full((K,), math.log(self.config.rho)))
        self.tau = nn.Parameter(torch.full((K,), float(self.config.tv)))

    def solve(self, y: torch.Tensor, M: torch.Tensor) -> torch.Tensor:
        n = M.shape[1]
        s = (M * M).sum() / n
        aty = y @ M
        z = torch.zeros_like(aty)
        u = torch.zeros_like(aty)
        shape = (-1, *self.out_shape)
        spectrum = self.spectrum(M)
        for k in range(self.config.iterations):
            rho = self.log_rho[k].to(M.dtype).exp() * s
            x = regularised_solve(M, aty + rho * (z - u), rho, spectrum)
            v = x + u
            v = v - self.tau[k].to(M.dtype) * _tv_gradient(v.view(shape)).flatten(1)
            z = F.relu(v)
            u = u + x - z
        return z
