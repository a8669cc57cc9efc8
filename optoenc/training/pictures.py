"""PNG pictures of PSFs, masks, measurements and training curves (matplotlib, Agg)."""

from __future__ import annotations

import io
from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from .rundir import atomic_write_bytes

__all__ = ["new_figure", "save_figure", "spectral_psf", "psf_rgb", "save_psf", "save_mask", "mask_spacing", "save_measurements", "save_rows", "save_curves"]


def new_figure(figsize):
    """``(pyplot, figure)``: a new figure of ``figsize`` inches on the non-interactive Agg backend."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt, plt.figure(figsize=figsize)


def save_figure(plt, fig, path: str | Path) -> Path:
    """Write ``fig`` as a PNG at ``path`` atomically (a reader never sees half a picture), close it; the path."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    return atomic_write_bytes(path, buf.getvalue())


def spectral_psf(encoder) -> torch.Tensor:
    """The encoder's PSF per wavelength (R, G, B; or 1 channel if achromatic), channels keeping their relative power."""
    from ..encoders.imaging import normalize_psf

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
            from ..optics.colour import spectral_to_srgb  # type: ignore
            from .. import devices

            img = spectral_to_srgb(p, devices.WAVELENGTHS_RGB)
            img = img.numpy() if hasattr(img, "numpy") else np.asarray(img)
            return np.clip(img / max(img.max(), 1e-12), 0, 1) ** gamma
        except Exception:
            return np.clip(p.permute(1, 2, 0).numpy(), 0, 1) ** gamma
    return np.clip(p[0].numpy(), 0, 1) ** gamma


def _extent_mm(shape: Sequence[int], spacing: Sequence[float] | None) -> list[float] | None:
    """``imshow`` extent in millimetres, centred on the optical axis (rows down), or None without a spacing."""
    if spacing is None:
        return None
    H, W = shape[-2:]
    return [-W / 2 * spacing[1] * 1e3, W / 2 * spacing[1] * 1e3, H / 2 * spacing[0] * 1e3, -H / 2 * spacing[0] * 1e3]


def _axes_labels(ax, where: str, physical: bool) -> None:
    if physical:
        ax.set_xlabel(f"x {where} [mm]")
        ax.set_ylabel(f"y {where} [mm]")
    else:
        ax.set_xlabel("column [samples]")
        ax.set_ylabel("row [samples]")


def _gray_bar(fig, ax, label: str, norm=None):
    """A colour bar for a gray image (or a gray ramp standing for an RGB image's brightness)."""
    import matplotlib.cm as cm
    import matplotlib.colors as mcolors

    sm = cm.ScalarMappable(norm=norm or mcolors.Normalize(0, 1), cmap="gray")
    return fig.colorbar(sm, ax=ax, label=label, fraction=0.046, pad=0.04)


def _figsize(shape: Sequence[int], spacing: Sequence[float] | None, width: float = 5.5) -> tuple[float, float]:
    """A figure size keeping the picture's true aspect (plus room for labels and the colour bar)."""
    H, W = shape[-2:]
    dy, dx = spacing if spacing is not None else (1.0, 1.0)
    aspect = (H * dy) / (W * dx)
    return width + 1.2, max(2.5, min(12.0, width * aspect + 1.0))


def save_psf(path: str | Path, psf: torch.Tensor, spacing: tuple[float, float], title: str = "") -> Path:
    """Save a PSF picture: axes in millimetres on the sensor, true aspect, colour bar of normalised intensity."""
    import matplotlib.colors as mcolors

    H, W = psf.shape[-2:]
    plt, fig = new_figure(_figsize((H, W), spacing))
    ax = fig.add_subplot(111)
    img = psf_rgb(psf)  # peak 1, gamma 0.5 for display
    ax.imshow(img, extent=_extent_mm((H, W), spacing), cmap="gray" if img.ndim == 2 else None, vmin=0, vmax=1,
              interpolation="nearest")
    _axes_labels(ax, "on sensor", True)
    kind = "sRGB brightness" if img.ndim == 3 else "intensity"
    # the bar's ticks are intensities (normalised to the peak) on the gamma-0.5 display scale
    _gray_bar(fig, ax, f"{kind} (normalised to peak; gamma 0.5 display)", mcolors.PowerNorm(0.5, vmin=0, vmax=1))
    ax.set_title(title or "intensity PSF")
    return save_figure(plt, fig, path)


def mask_spacing(encoder, mask: torch.Tensor) -> tuple[float, float] | None:
    """Physical sample spacing (metres) of ``encoder.mask()``'s samples, or None when unknown.

    An encoder may declare ``mask_spacing``; else a mask on the encoder's field
    grid (or simulation grid) has that grid's spacing.
    """
    declared = getattr(encoder, "mask_spacing", None)
    if declared is not None:
        return tuple(declared)
    shape = tuple(mask.shape[-2:])
    if getattr(encoder, "field_grid", None) is not None and shape == tuple(encoder.field_grid):
        return tuple(encoder.field_spacing)
    if shape == tuple(encoder.geometry.grid):
        return tuple(encoder.geometry.spacing)
    return None


def save_mask(
    path: str | Path, mask: torch.Tensor, title: str = "mask transmittance", spacing: tuple[float, float] | None = None,
    throughput: float | None = None,
) -> Path:
    """Save a mask: ``(H, W)`` transmittance, ``(3, H, W)`` per colour, or complex (drawn as its phase).

    Args:
        spacing: physical sample spacing (rows, columns) in metres: axes in
            millimetres at the true aspect (see :func:`mask_spacing`); None:
            axes in samples, still square samples.
        throughput: the encoder's light throughput (:meth:`~optoenc.encoders.base.OpticalEncoder.throughput`),
            stated under the title; None: not stated.
    """
    m = mask.detach().cpu()
    plt, fig = new_figure(_figsize(m.shape, spacing))
    ax = fig.add_subplot(111)
    ext = _extent_mm(m.shape, spacing)
    if m.is_complex():  # a phase mask: show the phase delay at the middle (green) wavelength
        from .. import devices

        c = m[m.shape[0] // 2] if m.dim() == 3 else m
        phase = torch.angle(c).double().masked_fill(c.abs() == 0, float("nan"))  # opaque: no phase
        im = ax.imshow(phase.numpy(), cmap="twilight", vmin=-np.pi, vmax=np.pi, interpolation="nearest", extent=ext)
        lam = f" at {devices.WAVELENGTHS_RGB[1] * 1e9:.0f} nm" if m.dim() == 3 else ""
        fig.colorbar(im, ax=ax, label=f"phase delay{lam} [rad] (blank: opaque)", fraction=0.046, pad=0.04)
    else:
        m = m.double()
        if m.dim() == 3 and m.shape[0] == 3:
            ax.imshow(np.clip(m.permute(1, 2, 0).numpy(), 0, 1), interpolation="nearest", extent=ext)
            _gray_bar(fig, ax, "amplitude transmittance per colour filter (0 opaque, 1 clear)")
        else:
            im = ax.imshow(m.squeeze().numpy(), cmap="gray", vmin=0, vmax=1, interpolation="nearest", extent=ext)
            fig.colorbar(im, ax=ax, label="amplitude transmittance (0 opaque, 1 clear)", fraction=0.046, pad=0.04)
    _axes_labels(ax, "on mask", spacing is not None)
    _zoom_to_light(ax, m, ext)
    if throughput is not None:
        title = f"{title}\nthroughput {throughput:.3g} (of a fully open aperture's light)"
    ax.set_title(title)
    return save_figure(plt, fig, path)


def _zoom_to_light(ax, m: torch.Tensor, ext) -> None:
    """Where light passes through less than a quarter of the drawn area (a small aperture on a large grid), the
    axes show the part that passes it, with a margin of a tenth of its size: the mask's pattern stays visible."""
    lit = (m.abs() > 0) if m.dim() == 2 else (m.abs() > 0).any(0)
    if not lit.any() or lit.double().mean() >= 0.25:
        return
    H, W = lit.shape
    rows, cols = lit.any(1).nonzero().flatten(), lit.any(0).nonzero().flatten()
    r0, r1, c0, c1 = int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
    mr, mc = max(1, (r1 - r0) // 10), max(1, (c1 - c0) // 10)
    r0, r1, c0, c1 = max(0, r0 - mr), min(H, r1 + mr), max(0, c0 - mc), min(W, c1 + mc)
    if ext is None:  # axes in samples: pixel centres at integers
        ax.set_xlim(c0 - 0.5, c1 - 0.5)
        ax.set_ylim(r1 - 0.5, r0 - 0.5)
        return
    x = lambda c: ext[0] + (ext[1] - ext[0]) * c / W  # noqa: E731
    y = lambda r: ext[3] + (ext[2] - ext[3]) * r / H  # noqa: E731  (rows run down from the top edge ext[3])
    ax.set_xlim(x(c0), x(c1))
    ax.set_ylim(y(r1), y(r0))


def save_measurements(
    path: str | Path,
    images: torch.Tensor,
    embeddings: torch.Tensor,
    labels: Sequence[int],
    class_names: Sequence[str] = (),
    scene_height: float | None = None,
    sensor_size: tuple[float, float] | None = None,
) -> Path:
    """Scenes (top row) and their sensor embeddings (bottom row), one column per example, each at its true aspect.

    Args:
        scene_height: physical height of a scene (metres): scene axes in mm.
        sensor_size: physical sensor (height, width) in metres: embedding axes in mm.
    """
    n = len(embeddings)
    h, w = images.shape[-2:]
    a, b = embeddings.shape[-2:]
    s_sp = None if scene_height is None else (scene_height / h, scene_height / h)
    e_sp = None if sensor_size is None else (sensor_size[0] / a, sensor_size[1] / b)
    plt, fig = new_figure((1.7 * max(n, 1) + 1.6, 4.2))
    grid = fig.add_gridspec(2, n + 1, width_ratios=[1] * n + [0.08], hspace=0.35, wspace=0.15)
    for i in range(n):
        ax = fig.add_subplot(grid[0, i])
        ax.imshow(images[i, 0].cpu().float().numpy(), cmap="gray", vmin=0, vmax=1, extent=_extent_mm((h, w), s_sp))
        ax.set_title(class_names[int(labels[i])] if class_names else f"label {int(labels[i])}", fontsize=8)
        ax2 = fig.add_subplot(grid[1, i])
        e = embeddings[i].detach().cpu().float()
        e = e / e.max().clamp_min(1e-30)  # each example normalised to its peak
        ax2.imshow(e[0].numpy() if e.shape[0] == 1 else e.clamp(0, 1).permute(1, 2, 0).numpy(), cmap="gray", vmin=0, vmax=1,
                   interpolation="nearest", extent=_extent_mm((a, b), e_sp))
        for axis in (ax, ax2):
            axis.tick_params(labelsize=6)
            if i:
                axis.set_yticklabels([])
        if i == 0:
            unit = " [mm]" if s_sp else " [px]"
            ax.set_ylabel(f"scene{unit}", fontsize=8)
            ax2.set_ylabel(f"sensor embedding {a} x {b}{' [mm]' if e_sp else ' [px]'}", fontsize=8)
    fig.colorbar(_mappable(), cax=fig.add_subplot(grid[0, n]), label="intensity (0 to 1)")
    fig.colorbar(_mappable(), cax=fig.add_subplot(grid[1, n]), label="normalised to peak")
    return save_figure(plt, fig, path)


def save_rows(path: str | Path, rows: Sequence[tuple[str, torch.Tensor]], title: str = "") -> Path:
    """A grid of images in [0, 1]: one row per ``(title, (N, C, h, w) images)``, one column per example (gray for
    one channel, RGB for three; a task's pictures, e.g. scene / embedding / reconstruction)."""
    n = max(len(t) for _, t in rows)
    plt, fig = new_figure((1.5 * max(n, 1) + 0.6, 1.6 * len(rows) + 0.4))
    for r, (name, images) in enumerate(rows):
        for i in range(len(images)):
            ax = fig.add_subplot(len(rows), n, r * n + i + 1)
            im = images[i].detach().cpu().float().clamp(0, 1)
            ax.imshow(im[0].numpy() if im.shape[0] != 3 else im.permute(1, 2, 0).numpy(), cmap="gray", vmin=0, vmax=1,
                      interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            if i == 0:
                ax.set_ylabel(name, fontsize=7)
    if title:
        fig.suptitle(title, fontsize=9)
    return save_figure(plt, fig, path)


def _mappable():
    import matplotlib.cm as cm
    import matplotlib.colors as mcolors

    return cm.ScalarMappable(norm=mcolors.Normalize(0, 1), cmap="gray")


def save_curves(path: str | Path, metrics_csv: str | Path) -> Path | None:
    """Loss and accuracy per epoch from a run's ``metrics.csv``."""
    from .callbacks import read_metrics

    rows = read_metrics(metrics_csv)
    if not rows:
        return None
    plt, fig = new_figure((8, 3.2))
    from matplotlib.ticker import MaxNLocator

    epochs = [int(r["epoch"]) for r in rows]  # the epoch numbers of metrics.csv (0 = the first epoch)
    for j, kind in enumerate(("loss", "acc")):
        ax = fig.add_subplot(1, 2, j + 1)
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        for stage in ("train", "val"):
            ys = [float(r[f"{stage}_{kind}"]) if r.get(f"{stage}_{kind}") else float("nan") for r in rows]
            ax.plot(epochs, ys, marker="o", label=f"{stage} {kind}")
        ax.set_xlabel("epoch (as in metrics.csv)")
        ax.set_ylabel({"loss": "cross-entropy loss", "acc": "accuracy (fraction correct)"}[kind])
        ax.legend(fontsize=8)
    return save_figure(plt, fig, path)
