"""An independent truth for the fidelity benchmark: PSFs without a wave-field grid, embeddings without approximation.

The bench measures every simulation setting against embeddings computed here,
by a route that shares no discretisation with the encoders' wave-field
simulation:

* **Piecewise-constant amplitude masks** (the LCD's rectangular cells, the
  MLS coded aperture's squares): the field of a point source at ``d1``
  through a rectangle, ``d2`` before the sensor, is under the Fresnel
  approximation a product of two 1-D Fresnel integrals (:func:`fresnel_psf`).
  Completing the square, ``U(y) ∝ sum_k A_k prod_axes [E(u_hi) - E(u_lo)]``
  with ``E(u) = C(u) + i S(u)``, ``u = sqrt(2 a / lambda) (edge - y / (a d2))``
  and ``a = 1 / d1 + 1 / d2``. No grid enters the field: the intensity
  ``|U|^2`` is evaluated at Gauss-Legendre nodes inside each sensor pixel and
  integrated over the pixel. For a lattice of cells the sum is a matrix
  product ``F_y A F_x^T``, cheap at full sensor resolution.
* **The lens**: its analytic pattern (Airy disk and defocus blur disk,
  :func:`optoenc.encoders.lens.airy_pixel_psf`), pixel-integrated on the full
  sensor grid.
* **A measured PSF** (the diffuser): the file is piecewise constant at its
  own resolution, area-resampled exactly onto the full sensor grid.
* **Other masks** (smooth phase plates): no closed form; the truth is the
  Richardson extrapolation of the band-limited angular spectrum (the exact
  Rayleigh-Sommerfeld kernel) over successively halved grid pitches, up to
  the full sensor (:mod:`optoenc.bench.converge`).

The embedding of a piecewise-constant scene with a pixel-integrated PSF is
then the exact linear operator (:func:`optoenc.encoders.operator.scene_operator`) on
the truth's grid: place, convolve and integrate, with the PSF taken constant
within each of its (1.55 um) pixels. That last step and the pixel quadrature
are the truth's only approximations; :func:`truth` measures them by
computing the truth at two grids (and two quadratures) and reports the
difference as the truth's estimated error.

Fresnel vs the exact kernel: the light reaching a sensor point comes from
within a few Fresnel zones ``sqrt(lambda d2)`` (<= 50 um) of its geometric
shadow, where the paraxial phase error ``pi r^4 / (4 lambda d2^3)`` is below
1e-3 rad; the source's spherical wave is paraxial to 1e-4 rad. The
convergence study shows it numerically: the band-limited angular spectrum
(exact kernel) extrapolated to zero pitch agrees with the Fresnel truth to
within the figures it prints.

Memory: each wavelength is computed on its own, in row blocks; the full
3040 x 4056 sensor takes ~1.5 GB.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Optional

import numpy as np
import torch

from .. import devices
from ..encoders import imaging, operator
from .settings import TRUTH_GRID, build_encoder, embed, truth_setting

__all__ = [
    "RectCells", "rect_cells", "fresnel_psf", "fresnel_vs_exact_1d", "kernel_error", "SENSOR_GRID",
    "embed_with_psf", "truth_psf", "richardson", "Truth", "truth",
]  # fmt: skip

#: The full sensor grid (IMX477 pixels): the truth's finest grid.
SENSOR_GRID = TRUTH_GRID
#: Gauss-Legendre nodes per 1.55 um sensor pixel and axis of the pixel-integrated Fresnel intensity
#: (scaled with the pixel size on coarser grids): ~0.2 um apart, several per period of the finest fringe
#: (measured on fixed_slm: 4 -> 8 nodes changes the embeddings by 2e-4, 8 -> 16 by 1e-9).
QUADRATURE = 8


@dataclass(frozen=True)
class RectCells:
    """A lattice of open rectangles with amplitudes: the mask of a piecewise-constant amplitude encoder.

    Attributes:
        rows: ``(R, 2)`` float64 ``[lo, hi]`` of each lattice row's open part, metres from the axis.
        cols: ``(C, 2)`` the same for the columns.
        amplitude: ``(3, R, C)`` amplitude transmittance of cell ``(r, c)`` at the R, G, B wavelengths.
    """

    rows: np.ndarray
    cols: np.ndarray
    amplitude: np.ndarray


def _edges(n: int, pitch: float, open_size: float) -> np.ndarray:
    centre = (np.arange(n) - (n - 1) / 2) * pitch  # as optoenc.optics.cell_mask (offset 0)
    return np.stack([centre - open_size / 2, centre + open_size / 2], axis=1)


def rect_cells(enc) -> Optional[RectCells]:
    """The :class:`RectCells` of a built-in piecewise-constant amplitude encoder, or None for any other."""
    from .. import devices as K
    from ..encoders.coded_aperture import CodedAperture
    from ..encoders.slm import _SLMBase

    if isinstance(enc, _SLMBase):
        b = enc.block
        with torch.no_grad():
            w = enc.displayed_amplitudes().detach().double().cpu().numpy()
        onehot = np.eye(3)[b.colours].T  # (3, rows): ideal colour filters
        return RectCells(_edges(b.rows, K.ST7735R_PITCH[0], K.ST7735R_CELL[0]),
                         _edges(b.cols, K.ST7735R_PITCH[1], K.ST7735R_CELL[1]), onehot[:, :, None] * w[None])
    if isinstance(enc, CodedAperture):
        cells = enc.cells.double().cpu().numpy()
        f = float(enc.config.feature_size)
        e_r, e_c = _edges(cells.shape[0], f, f), _edges(cells.shape[1], f, f)
        return RectCells(e_r, e_c, np.broadcast_to(cells, (3, *cells.shape)).copy())
    return None


def _nodes(n: int, spacing: float, q: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Legendre nodes (``n * q``, metres, axis at pixel ``n // 2``'s centre) and their weights (sum 1 per pixel)."""
    x, w = np.polynomial.legendre.leggauss(q)
    centres = (np.arange(n) - n // 2) * spacing
    return (centres[:, None] + x[None, :] * spacing / 2).reshape(-1), np.tile(w / 2, n)


def _fresnel_factor(points: np.ndarray, edges: np.ndarray, a: float, d2: float, wavelength: float) -> np.ndarray:
    """``(P, R)``: the 1-D Fresnel integral of each open interval seen from each sensor point (common factors dropped)."""
    from scipy.special import fresnel

    scale = math.sqrt(2 * a / wavelength)
    centre = points / (a * d2)  # the point's geometric shadow on the mask plane
    s_hi, c_hi = fresnel(scale * (edges[None, :, 1] - centre[:, None]))
    s_lo, c_lo = fresnel(scale * (edges[None, :, 0] - centre[:, None]))
    return (c_hi - c_lo) + 1j * (s_hi - s_lo)


def fresnel_psf(cells: RectCells, grid: tuple[int, int], spacing: tuple[float, float], d1: float, d2: float,
                wavelengths=devices.WAVELENGTHS_RGB, quadrature: int = QUADRATURE) -> np.ndarray:
    """Pixel-integrated Fresnel intensity PSF of a lattice of rectangles, ``(C, H, W)`` float64.

    Channel ``c`` is on one power scale for all wavelengths: the intensity per
    unit incident intensity at the mask (a fully open mask gives
    ``(d1 / (d1 + d2))^2`` in its shadow), averaged over each sensor pixel.

    The pixel integral is separable, hence exact up to 1-D quadrature: with
    the amplitudes' singular value decomposition ``A = sum_k s_k u_k v_k^T``
    the field is ``U(y, x) = sum_k f_k(y) g_k(x)``, so
    ``int_pixel |U|^2 = sum_kl [int f_k conj(f_l) dy] [int g_k conj(g_l) dx]``:
    each 1-D integral uses ``quadrature`` Gauss-Legendre nodes per pixel
    (the default resolves the finest Fresnel fringes on the sensor, ~0.4 um,
    with several nodes per period).
    """
    H, W = (int(n) for n in grid)
    a = 1.0 / d1 + 1.0 / d2
    q = int(quadrature)
    ys, wy = _nodes(H, spacing[0], q)
    xs, wx = _nodes(W, spacing[1], q)
    out = np.zeros((len(wavelengths), H, W))
    for c, lam in enumerate(wavelengths):
        amp = np.asarray(cells.amplitude[c], dtype=np.float64)
        live_r, live_c = np.flatnonzero(np.abs(amp).sum(1) > 0), np.flatnonzero(np.abs(amp).sum(0) > 0)
        if not len(live_r):
            continue
        amp = amp[np.ix_(live_r, live_c)]
        u, s, vt = np.linalg.svd(amp, full_matrices=False)
        k = max(1, int((s > s[0] * 1e-13).sum()))  # exact rank (an MLS pattern is an outer product: 1)
        f = _fresnel_factor(ys, cells.rows[live_r], a, d2, lam) @ (u[:, :k] * s[:k])  # (H q, k)
        g = _fresnel_factor(xs, cells.cols[live_c], a, d2, lam) @ vt[:k].T  # (W q, k)
        py = np.einsum("iqk,iql->ikl", (f * wy[:, None]).reshape(H, q, k), f.conj().reshape(H, q, k))
        px = np.einsum("jqk,jql->jkl", (g * wx[:, None]).reshape(W, q, k), g.conj().reshape(W, q, k))
        out[c] = (py.reshape(H, k * k) @ px.reshape(W, k * k).T).real
    return out / (4 * (a * d2) ** 2)  # |1 / (i lambda d2)|^2 (lambda / 2a)^2: no wavelength left


def embed_with_psf(psf: torch.Tensor, grid_spacing: tuple[float, float], images: torch.Tensor, height_m: float,
                   embedding: tuple[int, int]) -> torch.Tensor:
    """Noise-free float64 embeddings ``(B, C, a, b)`` of ``images`` for a pixel-integrated PSF ``(C, H, W)``.

    The exact scene operator (:func:`optoenc.encoders.operator.scene_operator`) on the
    PSF's grid: the scene is a piecewise-constant surface ``height_m`` tall on
    the sensor, centred and inverted, placed with exact areas.
    """
    C, H, W = psf.shape
    dy, dx = grid_spacing
    h, w = images.shape[-2:]
    py, px = imaging.placement_matrices((h, w), (H, W), height_m / dy, pixel_aspect=dy / dx)
    ry = imaging.correlation_tensor(imaging.box_matrix(H, embedding[0]), py, H)
    rx = imaging.correlation_tensor(imaging.box_matrix(W, embedding[1]), px, W)
    op = operator.scene_operator(psf.double(), ry, rx)
    return operator.apply_operator(op, images.double())


def _sensor_spacing(enc, grid) -> tuple[float, float]:
    h, w = enc.sensor.size
    return (h / grid[0], w / grid[1])


def _refined(name: str, grid, embedding, setup):
    enc = build_encoder(name, truth_setting(grid), embedding, setup)
    if hasattr(enc, "wavelength_chunk"):
        enc.wavelength_chunk = 1  # one wavelength at a time: the full sensor fits in a few GB
    return enc


def truth_psf(enc, grid: tuple[int, int] = SENSOR_GRID, quadrature: Optional[int] = None) -> tuple[Optional[torch.Tensor], str]:
    """``((C, H, W) float64 sensor PSF on ``grid``, method)`` by a grid-free route for ``enc``, if it has one.

    ``method``: ``"fresnel-rect"`` (piecewise-constant amplitude masks, see
    :func:`fresnel_psf`; ``quadrature`` Gauss-Legendre nodes per physical
    sensor pixel and axis), ``"analytic"`` (the lens), ``"measured"`` (a PSF
    file), or ``""`` and None when ``enc`` has none.
    """
    from ..encoders.diffuser import Diffuser
    from ..encoders.lens import Lens

    spacing = _sensor_spacing(enc, grid)
    cells = rect_cells(enc)
    if cells is not None:
        per_pixel = QUADRATURE if quadrature is None else quadrature
        q = math.ceil(per_pixel * max(spacing) / enc.sensor.pixel_pitch - 1e-9)  # nodes per grid pixel
        raw = torch.from_numpy(fresnel_psf(cells, grid, spacing, enc.scene_config.distance, enc.d2, quadrature=q))
        method = "fresnel-rect"
    elif isinstance(enc, (Lens, Diffuser)):
        fine = _refined(enc.name, grid, tuple(enc.sensor.embedding),
                        {"config": enc.config, "scene": enc.scene_config, "sensor": enc.sensor})
        with torch.no_grad():
            raw = fine.compute_psf().double()
        method = "analytic" if isinstance(enc, Lens) else "measured"
    else:
        return None, ""
    return imaging.sensor_psf(raw, enc.channels, name=f"truth {enc.name}"), method


@dataclass
class Truth:
    """The truth's embeddings for one encoder and how far they are from exact.

    Attributes:
        embeddings: ``(B, C, a, b)`` float64.
        error: estimated relative L2 error of ``embeddings``: for the
            grid-free routes the difference to the same truth on a grid of
            twice the pitch (the PSF is exact per pixel; only the operator's
            constant-per-pixel PSF converges, quadratically) plus, for the
            Fresnel route, the Fresnel-vs-exact-kernel difference
            (:func:`fresnel_vs_exact_1d`, summed over both axes); for the
            extrapolated route, the size of the Richardson correction.
        method: ``"fresnel-rect"``, ``"analytic"``, ``"measured"``,
            ``"richardson"`` (the encoder's own simulation on the truth's
            grid and its halvings, extrapolated) or ``"refined"`` (the
            encoder on the truth's grid; another non-propagated encoder).
        grid: the truth's finest grid.
        seconds: wall time.
        fresnel_vs_exact: the Fresnel route's kernel term (else None).
        order: the observed convergence order (Richardson route, else None).
    """

    embeddings: torch.Tensor
    error: float
    method: str
    grid: tuple[int, int]
    seconds: float
    fresnel_vs_exact: Optional[float] = None
    order: Optional[float] = None


def _rel(a: torch.Tensor, b: torch.Tensor) -> float:
    return float((a - b).norm() / b.norm().clamp_min(1e-300))


def kernel_error(enc) -> float:
    """Fresnel vs the exact kernel for ``enc``'s rectangle lattice (:func:`fresnel_vs_exact_1d`), both axes summed.

    At the longest (R, 640 nm) wavelength, which diffracts most, with each
    axis's mean amplitude profile of that colour, smoothed as the embedding
    sees it (the scene pixel and the embedding pixel on the sensor).
    """
    cells = rect_cells(enc)
    amp = np.asarray(cells.amplitude[0])
    smooth = (enc.scene_config.object_height * enc.magnification / 28, enc.sensor.size[0] / enc.sensor.embedding[0])
    wl = max(devices.WAVELENGTHS_RGB)
    return sum(fresnel_vs_exact_1d(edges, prof, wl, enc.scene_config.distance, enc.d2, enc.sensor.pixel_pitch, smooth)
               for edges, prof in ((cells.rows, amp.mean(1)), (cells.cols, amp.mean(0))) if prof.any())


def richardson(levels: list[torch.Tensor]) -> tuple[torch.Tensor, float, float]:
    """``(limit, order, correction)`` from embeddings on grids of pitch ``4h, 2h, h`` (the last three of ``levels``).

    The order ``p = log2(|E2 - E1| / |E3 - E2|)`` (clamped to [0.5, 4]) and
    ``E_inf = E3 + (E3 - E2) / (2^p - 1)``; ``correction`` is
    ``|E_inf - E3| / |E_inf|``, the estimated error of the finest level.
    """
    e1, e2, e3 = levels[-3:]
    d1, d2 = float((e2 - e1).norm()), float((e3 - e2).norm())
    p = min(4.0, max(0.5, math.log2(d1 / d2))) if d1 > 0 and d2 > 0 else 4.0
    limit = e3 + (e3 - e2) / (2**p - 1)
    return limit, p, _rel(e3, limit)


def truth(name: str, images: torch.Tensor, embedding: tuple[int, int], setup: Optional[dict] = None,
          grid: tuple[int, int] = SENSOR_GRID, kernel_check: bool = True) -> Truth:
    """The truth's embeddings of ``images`` for encoder ``name`` (its ``setup``: config, scene, sensor).

    Grid-free PSFs (:func:`truth_psf`) where there is one, on ``grid`` and on
    half of it for the estimated error; otherwise the encoder's own
    simulation (float64, padding ``auto``) on ``grid``, ``grid / 2`` and
    ``grid / 4``, Richardson-extrapolated (mask encoders) or on ``grid`` and
    ``grid / 2`` (others). ``kernel_check``: add the Fresnel-vs-exact term
    (about a minute for the LCD).
    """
    t0 = time.perf_counter()
    enc = _refined(name, grid, embedding, setup)
    height = enc.scene_config.object_height * enc.magnification
    half = (grid[0] // 2, grid[1] // 2)
    psf, method = truth_psf(enc, grid)
    if psf is not None:
        best = embed_with_psf(psf, _sensor_spacing(enc, grid), images, height, embedding)
        del psf
        psf2, _ = truth_psf(enc, half)
        err = _rel(embed_with_psf(psf2, _sensor_spacing(enc, half), images, height, embedding), best)
        del psf2
        kern = kernel_error(enc) if method == "fresnel-rect" and kernel_check else None
        return Truth(best, err + (kern or 0.0), method, tuple(grid), time.perf_counter() - t0, fresnel_vs_exact=kern)
    from ..encoders.mask import MaskEncoder

    grids = [grid, half] + ([(grid[0] // 4, grid[1] // 4)] if isinstance(enc, MaskEncoder) else [])
    levels = []
    for g in reversed(grids):  # coarse to fine
        e = enc if g == grid else _refined(name, g, embedding, setup)
        levels.append(embed(e, images))
        del e
    if len(levels) == 3:
        limit, p, corr = richardson(levels)
        return Truth(limit, corr, "richardson", tuple(grid), time.perf_counter() - t0, order=p)
    return Truth(levels[-1], _rel(levels[-2], levels[-1]), "refined", tuple(grid), time.perf_counter() - t0)


def fresnel_vs_exact_1d(edges: np.ndarray, amplitude: np.ndarray, wavelength: float, d1: float, d2: float,
                        pixel: float, smooth: tuple[float, ...] = (), step: float = 0.05e-6) -> float:
    """Relative L2 difference of the Fresnel and the exact (Rayleigh-Sommerfeld) intensity behind a 1-D mask.

    The 1-D analogue of one axis of :func:`fresnel_psf`: open intervals
    ``edges`` (``(R, 2)``, metres) with ``amplitude`` (``(R,)``), lit by a
    point source at ``d1``, seen ``d2`` behind. The exact field is the
    angular spectrum of the whole propagating spectrum (``|f| < 1 / lambda``,
    no band limit, no paraxial step), sampled every ``step`` (0.05 um: the
    spectrum reaches 10 cycles/um, past the evanescent cut-off), on a window
    wide enough for light at 60 degrees; the source's spherical wave is
    exact there and paraxial in the Fresnel integral. Both intensities are
    averaged over ``pixel``-wide sensor pixels and then box-smoothed by each
    width in ``smooth`` (e.g. the scene pixel and the embedding pixel on
    the sensor: what the embedding sees).
    """
    from scipy.special import fresnel

    lo, hi = float(edges[:, 0].min()), float(edges[:, 1].max())
    half = max(abs(lo), abs(hi)) + 2.0 * d2  # tan(60 deg) ~ 1.7: the propagating light stays inside
    n = int(2 ** math.ceil(math.log2(2 * half / step)))
    x = (np.arange(n) - n // 2) * step
    # exact area-weighted raster of the intervals at the fine step
    t = np.zeros(n)
    for (a_lo, a_hi), amp in zip(edges, amplitude):
        cover = np.clip(np.minimum(x + step / 2, a_hi) - np.maximum(x - step / 2, a_lo), 0, None) / step
        t += amp * cover
    k = 2 * math.pi / wavelength
    u1 = t * np.exp(1j * k * (np.sqrt(x * x + d1 * d1) - d1))
    f = np.fft.fftfreq(n, step)
    kz = 2 * math.pi * np.sqrt(np.maximum(0.0, 1.0 / wavelength**2 - f * f))
    prop = np.where(np.abs(f) < 1.0 / wavelength, np.exp(1j * kz * d2), 0.0)
    u2 = np.fft.ifft(np.fft.fft(np.fft.ifftshift(u1)) * prop)
    exact = np.abs(np.fft.fftshift(u2)) ** 2
    # Fresnel: the same completion of the square as fresnel_psf, at the fine points
    a = 1.0 / d1 + 1.0 / d2
    scale = math.sqrt(2 * a / wavelength)
    centre = x / (a * d2)
    field = np.zeros(n, dtype=complex)
    for (a_lo, a_hi), amp in zip(edges, amplitude):
        s_hi, c_hi = fresnel(scale * (a_hi - centre))
        s_lo, c_lo = fresnel(scale * (a_lo - centre))
        field += amp * ((c_hi - c_lo) + 1j * (s_hi - s_lo))
    paraxial = np.abs(field) ** 2 / (2 * a * d2)

    def seen(i: np.ndarray) -> np.ndarray:
        m = int(round(pixel / step))
        out = np.convolve(i, np.ones(m) / m, mode="same")
        for w in smooth:
            m = max(1, int(round(w / step)))
            out = np.convolve(out, np.ones(m) / m, mode="same")
        return out[:: max(1, int(round(pixel / step)))]

    e, p = seen(exact), seen(paraxial)
    return float(np.linalg.norm(p - e) / np.linalg.norm(e))
