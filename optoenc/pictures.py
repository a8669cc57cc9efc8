"""PNG pictures of PSFs, masks, measurements and training curves (matplotlib, Agg)."""

from __future__ import annotations

import io
from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from .rundir import atomic_write_bytes

__all__ = ["spectral_psf", "psf_rgb", "save_psf", "save_mask", "save_measurements", "save_curves"]


def _figure(figsize):
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt, plt.figure(figsize=figsize)


def _save(plt, fig, path: str | Path) -> Path:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    return atomic_write_bytes(path, buf.getvalue())


def spectral_psf(encoder) -> torch.Tensor:
    """The encoder's PSF per wavelength (R, G, B; or 1 channel if achromatic), channels keeping their relative power."""
    from .imaging import normalize_psf

    with torch.no_grad():
        return normalize_psf(encoder.compute_psf().detach(), name=f"encoder {encoder.name}")


def psf_rgb(psf: torch.Tensor, gamma: float = 0.5) -> np.ndarray:
    """A displayable ``(H, W, 3)`` or ``(H, W)`` image of a ``(C, H, W)`` PSF, peak at 1, gamma-compressed.

    Three channels are taken as R, G, B intensities at the paper's wavelengths
    and shown as sRGB through the CIE 1931 observer when colour-science is
    available (:func:`optoenc.optics.colour` helpers), else as plain RGB.
    """
    p = psf.detach().double().cpu()
    p = p / p.max().clamp_min(1e-300)
    if p.shape[0] == 3:
        try:
            from .optics.colour import spectral_to_srgb  # type: ignore
            from . import devices

            img = spectral_to_srgb(p, devices.WAVELENGTHS_RGB)
            img = img.numpy() if hasattr(img, "numpy") else np.asarray(img)
            return np.clip(img / max(img.max(), 1e-12), 0, 1) ** gamma
        except Exception:
            return np.clip(p.permute(1, 2, 0).numpy(), 0, 1) ** gamma
    return np.clip(p[0].numpy(), 0, 1) ** gamma


def save_psf(path: str | Path, psf: torch.Tensor, spacing: tuple[float, float], title: str = "") -> Path:
    """Save a PSF picture with axes in millimetres (sensor coordinates)."""
    plt, fig = _figure((6, 4.8))
    H, W = psf.shape[-2:]
    ext = [-W / 2 * spacing[1] * 1e3, W / 2 * spacing[1] * 1e3, H / 2 * spacing[0] * 1e3, -H / 2 * spacing[0] * 1e3]
    ax = fig.add_subplot(111)
    img = psf_rgb(psf)
    ax.imshow(img, extent=ext, cmap="gray" if img.ndim == 2 else None, interpolation="nearest")
    ax.set_xlabel("x on sensor [mm]")
    ax.set_ylabel("y on sensor [mm]")
    ax.set_title(title or "intensity PSF (gamma 0.5)")
    return _save(plt, fig, path)


def save_mask(path: str | Path, mask: torch.Tensor, title: str = "mask transmittance") -> Path:
    """Save a mask (``(H, W)`` transmittance, or ``(3, H, W)`` per colour)."""
    plt, fig = _figure((5, 5))
    ax = fig.add_subplot(111)
    m = mask.detach().cpu()
    if m.is_complex():  # a phase mask: show the phase delay at the middle (green) wavelength
        c = m[m.shape[0] // 2] if m.dim() == 3 else m
        phase = torch.angle(c).double().masked_fill(c.abs() == 0, float("nan"))  # opaque: no phase
        im = ax.imshow(phase.numpy(), cmap="twilight", vmin=-np.pi, vmax=np.pi, interpolation="nearest", aspect="auto")
        fig.colorbar(im, ax=ax, label="phase [rad]")
        ax.set_title(title)
        return _save(plt, fig, path)
    m = m.double()
    if m.dim() == 3 and m.shape[0] == 3:
        ax.imshow(np.clip(m.permute(1, 2, 0).numpy(), 0, 1), interpolation="nearest", aspect="auto")
    else:
        im = ax.imshow(m.squeeze().numpy(), cmap="gray", vmin=0, vmax=1, interpolation="nearest", aspect="auto")
        fig.colorbar(im, ax=ax)
    ax.set_title(title)
    return _save(plt, fig, path)


def save_measurements(
    path: str | Path, images: torch.Tensor, embeddings: torch.Tensor, labels: Sequence[int], class_names: Sequence[str] = ()
) -> Path:
    """Scenes and their sensor embeddings side by side (one column per example), titled by class name if given."""
    n = len(embeddings)
    plt, fig = _figure((1.6 * max(n, 1), 3.4))
    for i in range(n):
        ax = fig.add_subplot(2, n, i + 1)
        ax.imshow(images[i, 0].cpu().numpy(), cmap="gray")
        ax.set_title(class_names[int(labels[i])] if class_names else f"label {int(labels[i])}", fontsize=8)
        ax.axis("off")
        ax = fig.add_subplot(2, n, n + i + 1)
        e = embeddings[i].detach().cpu().float()
        ax.imshow(e[0].numpy() if e.shape[0] == 1 else (e / e.max()).permute(1, 2, 0).numpy(), cmap="gray", interpolation="nearest")
        ax.set_title(f"{tuple(e.shape[-2:])}", fontsize=8)
        ax.axis("off")
    return _save(plt, fig, path)


def save_curves(path: str | Path, metrics_csv: str | Path) -> Path | None:
    """Loss and accuracy per epoch from a run's ``metrics.csv``."""
    from .callbacks import read_metrics

    rows = read_metrics(metrics_csv)
    if not rows:
        return None
    plt, fig = _figure((8, 3.2))
    epochs = [int(r["epoch"]) + 1 for r in rows]
    for j, kind in enumerate(("loss", "acc")):
        ax = fig.add_subplot(1, 2, j + 1)
        for stage in ("train", "val"):
            ys = [float(r[f"{stage}_{kind}"]) if r.get(f"{stage}_{kind}") else float("nan") for r in rows]
            ax.plot(epochs, ys, marker="o", label=f"{stage} {kind}")
        ax.set_xlabel("epoch")
        ax.set_ylabel(kind)
        ax.legend(fontsize=8)
    return _save(plt, fig, path)
