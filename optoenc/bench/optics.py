"""Benchmark of the simulated SLM PSF (``optoenc bench optics``): batched versus one wavelength at a time.

For each grid size, number of wavelengths (1 or 3: R, G, B) and precision
(float32, float64) it times one :func:`optoenc.optics.intensity_psf` of a random
LCD mask in the paper's geometry (IMX477 sensor area, d1 = 0.4 m, d2 = 4 mm,
``padding="auto"``), steady state (transfer functions cached, as in training
with a fixed d2):

* ``batched_ms``: all wavelengths in one call (one batched FFT);
* ``looped_ms``: one call per wavelength;
* ``ratio``: batched / looped (< 1: batching pays);
* ``train_ms``: batched forward + backward with respect to the mask (one
  optimiser step's PSF cost).

Library code: :func:`run` returns rows, :func:`format_table` renders them; nothing
is printed here.
"""

from __future__ import annotations

import time

import torch

from ..devices import WAVELENGTHS_RGB
from ..optics import Spectrum, cell_mask, intensity_psf, padded_shape

__all__ = ["run", "format_table"]

#: Sensor area (m) and LCD geometry of the paper (REFERENCE section 2).
SENSOR_SIZE = (4.712e-3, 6.287e-3)
LCD_CELL = (73.03e-6, 219.25e-6)
LCD_FILL = (0.822, 0.821)
LCD_CELLS = (51, 22)
D1, D2 = 0.4, 4e-3


def _best_ms(*fns, repeats: int) -> list[float]:
    """Best of ``repeats`` timings of each function, in ms, after a warm-up.

    The functions are timed in turn within each repetition, so a load change
    on a shared machine affects them alike; the minimum is the least noisy
    estimate.
    """
    for fn in fns:
        fn()  # warm-up: fills the transfer-function and source caches
    best = [float("inf")] * len(fns)
    for _ in range(max(1, repeats)):
        for i, fn in enumerate(fns):
            start = time.perf_counter()
            fn()
            best[i] = min(best[i], time.perf_counter() - start)
    return [1e3 * b for b in best]


def _warm_up(cells: torch.Tensor, shape: tuple[int, int]) -> None:
    """One-off costs (FFT plans, thread pools, the autograd engine) before anything is timed."""
    spacing = (SENSOR_SIZE[0] / shape[0], SENSOR_SIZE[1] / shape[1])
    for dtype in (torch.float32, torch.float64):
        m = cell_mask(cells.to(dtype), LCD_CELL, shape, spacing, fill_factor=LCD_FILL).requires_grad_(True)
        for _ in range(2):
            intensity_psf(m, WAVELENGTHS_RGB, spacing, D1, D2, check=False).sum().backward()


def run(sizes=((384, 512), (768, 1024)), repeats: int = 3) -> list[dict]:
    """Time the PSF for each size x {1, 3} wavelengths x {float32, float64}.

    Args:
        sizes: ``(H, W)`` simulation grids covering the sensor area.
        repeats: timed repetitions per measurement (the best is reported).

    Returns:
        One dict per configuration with keys ``shape``, ``padded``,
        ``wavelengths``, ``dtype``, ``batched_ms``, ``looped_ms``, ``ratio``,
        ``train_ms``.
    """
    rows = []
    gen = torch.Generator().manual_seed(0)
    cells = (torch.rand(*LCD_CELLS, generator=gen) > 0.5).to(torch.float64)
    _warm_up(cells, tuple(int(n) for n in sizes[0]) if sizes else (8, 8))
    for shape in sizes:
        shape = tuple(int(n) for n in shape)
        spacing = (SENSOR_SIZE[0] / shape[0], SENSOR_SIZE[1] / shape[1])
        for n_wl in (1, 3):
            spectrum = Spectrum(WAVELENGTHS_RGB[:n_wl], (1.0,) * n_wl)
            for dtype in (torch.float32, torch.float64):
                mask = cell_mask(cells.to(dtype), LCD_CELL, shape, spacing, fill_factor=LCD_FILL)
                kw = dict(spacing=spacing, d1=D1, d2=D2, check=False)

                def batched():
                    with torch.no_grad():
                        return intensity_psf(mask, spectrum, **kw)

                def looped():
                    with torch.no_grad():
                        return torch.cat([intensity_psf(mask, wl, **kw) for wl in spectrum.wavelengths])

                def train():
                    m = mask.detach().requires_grad_(True)
                    intensity_psf(m, spectrum, **kw).square().sum().backward()

                b, lp, tr = _best_ms(batched, looped, train, repeats=repeats)
                rows.append(
                    {
                        "shape": shape,
                        "padded": padded_shape(shape, spacing, spectrum.wavelengths, D2),
                        "wavelengths": n_wl,
                        "dtype": str(dtype).removeprefix("torch."),
                        "batched_ms": b,
                        "looped_ms": lp,
                        "ratio": b / lp,
                        "train_ms": tr,
                    }
                )
    return rows


def format_table(rows) -> str:
    """Render :func:`run`'s rows as an aligned text table."""
    header = ("grid", "padded", "wl", "dtype", "batched ms", "looped ms", "batched/looped", "fwd+bwd ms")
    lines = [
        (
            "x".join(map(str, r["shape"])),
            "x".join(map(str, r["padded"])),
            str(r["wavelengths"]),
            r["dtype"],
            f"{r['batched_ms']:.1f}",
            f"{r['looped_ms']:.1f}",
            f"{r['ratio']:.2f}",
            f"{r['train_ms']:.1f}",
        )
        for r in rows
    ]
    widths = [max(len(h), *(len(line[i]) for line in lines)) if lines else len(h) for i, h in enumerate(header)]
    fmt = lambda cells: "  ".join(c.rjust(w) for c, w in zip(cells, widths))  # noqa: E731
    return "\n".join([fmt(header), fmt(["-" * w for w in widths]), *map(fmt, lines)])
