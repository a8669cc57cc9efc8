"""The imaging steps every encoder shares, as plain functions on tensors.

Scene -> object-plane placement (magnification d2/d1, inverted image) ->
convolution with the intensity PSF -> pixel integration (box average over each
sensor pixel) -> zero-mean noise at a target SNR -> optional ADC quantisation.

Conventions:
    * Images are ``(..., H, W)`` tensors; rows first, like the sensor.
    * A PSF on an ``(H, W)`` grid has its optical axis at pixel
      ``(H // 2, W // 2)``; the convolution is linear (zero padded, no
      wrap-around) and its output is cropped back to the ``(H, W)`` grid.
    * The scene is a piecewise-constant surface: pixel ``p`` of an ``n``-pixel
      scene covers ``[p, p + 1) * size / n`` of its physical extent. Placing
      it on a grid integrates that surface over each grid pixel with exact
      fractional areas, so every grid samples the same object.
    * Pixel integration averages over exact fractional areas
      (``box_matrix``); it equals ``avg_pool2d`` when the grid divides.

Because placement, convolution and integration are all linear, their
composition for a given PSF is a small matrix from scene pixels to embedding
pixels (:func:`scene_operator`), built from two 1-D correlation tensors that
depend only on the geometry. Applying it costs a matrix product per batch
and equals the fine-grid pipeline to rounding.
"""

from __future__ import annotations

import warnings

import torch
import torch.nn.functional as F

from ..errors import ConfigError, PhysicsError
from ..optics._common import next_fast_size
from . import banded

__all__ = [
    "area_matrix",
    "box_matrix",
    "point_matrix",
    "sampling_matrix",
    "SAMPLINGS",
    "placement_matrices",
    "place",
    "fft_convolve",
    "integrate",
    "subcell_psf",
    "correlation_tensor",
    "scene_operator",
    "dense_factors",
    "apply_operator",
    "add_noise",
    "snr_sigma",
    "quantize",
    "normalize_psf",
    "normalize_channels",
    "sensor_psf",
]


def area_matrix(n_in: int, n_out: int, start: float, length: float, dtype=torch.float64) -> torch.Tensor:
    """Overlap of ``n_in`` equal cells spanning ``[start, start + length)`` with unit output cells.

    Args:
        n_in: number of input cells (scene pixels along one axis).
        n_out: number of output cells (grid pixels), cell ``y`` is ``[y, y+1)``.
        start: position of the input's first edge, in output-cell units.
        length: total extent of the input, in output-cell units (> 0).

    Returns:
        ``(n_out, n_in)`` matrix: entry ``[y, p]`` is the length of the
        overlap of input cell ``p`` with output cell ``y`` (in output-cell
        units), so ``M @ v`` is the average of the piecewise-constant input
        over each output cell. Input cells outside ``[0, n_out)`` are cropped.
    """
    edges_in = start + torch.arange(n_in + 1, dtype=dtype) * (length / n_in)
    lo = torch.maximum(edges_in[:-1][None, :], torch.arange(n_out, dtype=dtype)[:, None])
    hi = torch.minimum(edges_in[1:][None, :], torch.arange(1, n_out + 1, dtype=dtype)[:, None])
    return (hi - lo).clamp_min(0)


def box_matrix(n_grid: int, n_out: int, dtype=torch.float64) -> torch.Tensor:
    """Pixel integration along one axis: ``(n_out, n_grid)`` averaging matrix.

    Output pixel ``a`` averages the grid over ``[a, a + 1) * n_grid / n_out``
    with exact fractional weights; rows sum to one.
    """
    if not 1 <= n_out <= n_grid:
        raise ConfigError("embedding", n_out, f"must be between 1 and the simulation grid size {n_grid}")
    m = area_matrix(n_grid, n_out, 0.0, float(n_out), dtype=dtype)  # grid cells in output units
    return m / m.sum(dim=1, keepdim=True)


def point_matrix(n_grid: int, n_out: int, dtype=torch.float64) -> torch.Tensor:
    """Point sampling along one axis: ``(n_out, n_grid)`` bilinear weights, no antialiasing.

    Output pixel ``a`` reads the grid at its centre, source coordinate
    ``(a + 0.5) * n_grid / n_out - 0.5`` (clamped to the grid), by linear
    interpolation between the two nearest grid samples: exactly
    ``torch.nn.functional.interpolate(mode="bilinear", align_corners=False,
    antialias=False)``, the paper's published downsampling. It reads 2 of
    every ``n_grid / n_out`` samples: fine structure aliases instead of
    averaging out, which no physical pixel does (see :func:`box_matrix`).
    """
    if not 1 <= n_out <= n_grid:
        raise ConfigError("embedding", n_out, f"must be between 1 and the simulation grid size {n_grid}")
    src = ((torch.arange(n_out, dtype=dtype) + 0.5) * (n_grid / n_out) - 0.5).clamp_min(0)
    lo = src.floor().long().clamp_max(n_grid - 1)
    hi = (lo + 1).clamp_max(n_grid - 1)
    frac = src - lo.to(dtype)
    m = torch.zeros(n_out, n_grid, dtype=dtype)
    rows = torch.arange(n_out)
    m.index_put_((rows, lo), 1 - frac, accumulate=True)
    m.index_put_((rows, hi), frac, accumulate=True)
    return m


#: How a sensor pixel reads the image on the grid (``sensor.sampling``).
SAMPLINGS = {"box": box_matrix, "point": point_matrix}


def sampling_matrix(n_grid: int, n_out: int, sampling: str = "box", dtype=torch.float64) -> torch.Tensor:
    """The ``(n_out, n_grid)`` matrix of ``sampling`` (``'box'``: :func:`box_matrix`; ``'point'``: :func:`point_matrix`)."""
    if sampling not in SAMPLINGS:
        raise ConfigError("sensor.sampling", sampling, f"one of {', '.join(SAMPLINGS)}")
    return SAMPLINGS[sampling](n_grid, n_out, dtype=dtype)


def subcell_psf(psf: torch.Tensor, sub: int) -> torch.Tensor:
    """A ``(..., H, W)`` PSF of cell averages on a grid ``sub`` (odd) times finer, for the fine-grid pipeline.

    Each cell's value is spread evenly over its ``sub x sub`` fine cells and
    the array is zero-padded at the end so that its centre index (the axis,
    see :func:`fft_convolve`) is the centre fine cell of pixel ``(H//2, W//2)``,
    matching :func:`correlation_tensor` with the same ``sub``.
    """
    if sub == 1:
        return psf
    fine = psf.repeat_interleave(sub, -2).repeat_interleave(sub, -1) / sub**2
    pads = []
    for n in reversed(psf.shape[-2:]):
        c = (n // 2) * sub + sub // 2
        length = 2 * c if 2 * c >= n * sub else 2 * c + 1
        pads += [0, length - n * sub]
    return F.pad(fine, pads)


def placement_matrices(
    scene_shape: tuple[int, int],
    grid_shape: tuple[int, int],
    height_px: float,
    invert: bool = True,
    dtype=torch.float64,
    pixel_aspect: float = 1.0,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Row and column matrices placing an ``(h, w)`` scene centred on the grid.

    Args:
        scene_shape: ``(h, w)`` scene pixels.
        grid_shape: ``(H, W)`` grid pixels.
        height_px: the scene's height on the grid, in grid pixels (may be
            fractional); the width follows from the aspect ratio.
        invert: flip both axes (the image of a camera is inverted, M < 0).
        pixel_aspect: grid pixel height / width (``dy / dx``); the scene keeps
            its physical aspect ratio on grids with non-square pixels.

    Returns:
        ``(Py, Px)`` with shapes ``(H, h)`` and ``(W, w)``; the placed scene
        is ``Py @ scene @ Px.T``.
    """
    (h, w), (H, W) = scene_shape, grid_shape
    width_px = height_px * (w / h) * pixel_aspect
    if height_px > H or width_px > W:
        warnings.warn(
            f"the object ({height_px:.1f} x {width_px:.1f} grid px) is larger than the field of view "
            f"({H} x {W} px): it is cropped",
            stacklevel=3,
        )
    py = area_matrix(h, H, (H - height_px) / 2, height_px, dtype)
    px = area_matrix(w, W, (W - width_px) / 2, width_px, dtype)
    if invert:
        py, px = py.flip(1), px.flip(1)
    return py, px


def place(
    scene: torch.Tensor, grid_shape: tuple[int, int], height_px: float, invert: bool = True, pixel_aspect: float = 1.0
) -> torch.Tensor:
    """Place a ``(..., h, w)`` scene on an ``(..., H, W)`` grid (see :func:`placement_matrices`)."""
    py, px = placement_matrices(tuple(scene.shape[-2:]), grid_shape, height_px, invert, pixel_aspect=pixel_aspect)
    py, px = py.to(scene.dtype), px.to(scene.dtype)
    return py @ scene @ px.T


def fft_convolve(image: torch.Tensor, psf: torch.Tensor) -> torch.Tensor:
    """Linear (zero-padded) convolution of ``(..., H, W)`` images with a centred PSF.

    The PSF's axis is at ``(Hp // 2, Wp // 2)``; the result has the image's
    shape: ``out[y, x] = sum image[y', x'] psf[y - y' + Hp//2, x - x' + Wp//2]``.
    """
    H, W = image.shape[-2:]
    Hp, Wp = psf.shape[-2:]
    sh, sw = next_fast_size(H + Hp - 1), next_fast_size(W + Wp - 1)
    spec = torch.fft.rfft2(image, s=(sh, sw)) * torch.fft.rfft2(psf, s=(sh, sw))
    full = torch.fft.irfft2(spec, s=(sh, sw))
    return full[..., Hp // 2 : Hp // 2 + H, Wp // 2 : Wp // 2 + W]


def integrate(image: torch.Tensor, out_shape: tuple[int, int], sampling: str = "box") -> torch.Tensor:
    """Pixel integration: average ``(..., H, W)`` over the ``out_shape`` sensor pixels (or point-sample them)."""
    H, W = image.shape[-2:]
    sy = sampling_matrix(H, out_shape[0], sampling).to(image.dtype)
    sx = sampling_matrix(W, out_shape[1], sampling).to(image.dtype)
    return sy @ image @ sx.T


def correlation_tensor(box: torch.Tensor, place_m: torch.Tensor, n_psf: int, sub: int = 1) -> torch.Tensor:
    """1-D geometry tensor linking scene pixels to embedding pixels through a PSF offset.

    ``R[a, p, k] = sum_y box[a, y] * place[y - (k - n_psf // 2), p]``: the
    weight with which PSF sample ``k`` carries scene pixel ``p`` into output
    pixel ``a`` along one axis.

    Args:
        box: ``(n_out, n_grid)`` integration matrix (:func:`box_matrix`).
        place_m: ``(n_grid, n_scene)`` placement matrix.
        n_psf: PSF length along this axis (its axis at ``n_psf // 2``).
        sub: odd; ``box`` and ``place_m`` live on a grid ``sub`` times finer
            than the PSF's, whose values are cell averages spread evenly over
            their ``sub`` fine cells: the scene keeps its sub-pixel structure.

    Returns:
        ``(n_out, n_scene, n_psf)`` tensor.
    """
    if sub < 1 or sub % 2 == 0:
        raise ConfigError("sub", sub, "must be an odd integer >= 1 (the PSF's axis at a fine cell centre)")
    n_f = n_psf * sub
    c = (n_psf // 2) * sub + sub // 2
    # A correlation: out[a, p, t] = sum_j boxpad[a, t + j] place[j, p] (t = s + left, s = k - c), by FFT:
    # conv1d with an n_grid-long kernel unfolds an (n_grid x n_f) buffer per output row (6.6 GB and 10 s for
    # a 5120-column fine grid; the FFT takes ~50 MB and ~0.1 s). Entries that are exactly zero come out
    # at ~1e-16 of the largest (float rounding); they are set back to zero below.
    left = max(0, c)
    right = max(0, n_f - 1 - c)
    inp = F.pad(box, (left, right))  # (n_out, n_grid + n_f - 1)
    n_in, n_grid = inp.shape[-1], place_m.shape[0]
    size = next_fast_size(n_in)  # >= both lengths: the circular correlation does not wrap for t < n_in - n_grid + 1
    spec = torch.fft.rfft(inp, n=size)[:, None, :] * torch.fft.rfft(place_m.T, n=size).conj()[None]
    out = torch.fft.irfft(spec, n=size)[..., : max(0, n_in - n_grid + 1)]  # (n_out, n_scene, n_f)
    out = out[:, :, :n_f] if out.shape[-1] >= n_f else F.pad(out, (0, n_f - out.shape[-1]))
    # The FFT's rounding noise (~1e-35 where the answer is 0) is not signal: in float32 its products with a
    # PSF are subnormal numbers, which x86 CPUs handle ~10x slower (measured: the 24x32 learned-SLM operator
    # on a 109x146 augmentation canvas took 1.5 s instead of 0.14 s). Below size * eps of the largest entry
    # (the FFT's error bound) an entry is an overlap no geometry produces; it becomes an exact zero.
    out = torch.where(out.abs() > out.abs().amax() * size * torch.finfo(out.dtype).eps, out, torch.zeros((), dtype=out.dtype))
    # each PSF cell spreads its value evenly over its fine cells (mass conserved)
    return out if sub == 1 else out.reshape(out.shape[0], out.shape[1], n_psf, sub).mean(-1)


# Below this many multiply-adds (~1 ms of products on one core) the dense build is a few small products and
# the banded one's plans and layout copies cost more than the zeros it skips (Table 1's 3x4: 0.90x).
_MIN_BANDED_MACS = 20_000_000


def scene_operator(psf: torch.Tensor, ry: torch.Tensor, rx: torch.Tensor, spans=None, sort_rows: bool = True,
                   row_major: bool = True, matrix_units: bool = False, factors=None) -> torch.Tensor:
    """The linear map from scene pixels to embedding pixels for a given PSF.

    Args:
        psf: ``(C, Hp, Wp)`` intensity PSF.
        ry: ``(a, h, Hp)`` row correlation tensor (:func:`correlation_tensor`).
        rx: ``(b, w, Wp)`` column correlation tensor.
        spans: optional ``(row_spans(ry), row_spans(rx))`` of the flattened
            tensors (:func:`optoenc.encoders.banded.row_spans`), to skip
            finding them; computed here when None. False: the dense
            products whatever the tensors' band (a reference).
        sort_rows: the banded build may take a correlation tensor's rows in
            the order of their spans (:class:`optoenc.encoders.banded.BandPlan`);
            False: consecutive rows only (a reference).
        row_major: where the rows are sorted, return the operator held canvas row by canvas row (below);
            False: a contiguous ``(C, a, b, h, w)`` tensor always (a reference).
        matrix_units: the dense products, in the layout that one product applies (:func:`_matrix_unit_operator`),
            whatever ``spans`` says: for a bfloat16 PSF on a CPU whose matrix units multiply bfloat16 (AMX), as the
            caller decides (:meth:`OpticalEncoder._uses_matrix_units`); any dtype gives the same operator.
        factors: ``dense_factors(ry, rx)`` where the caller keeps them (the ``matrix_units`` build).

    Returns:
        ``(C, a, b, h, w)`` operator ``A`` with
        ``embedding[c, a, b] = sum_pq A[c, a, b, p, q] scene[c, p, q]``. The banded build with sorted
        rows returns it as a view of an ``(h, a, C, b, w)`` tensor, canvas row by canvas row, which
        :func:`apply_operator` multiplies without a copy (:func:`operator_rows`); other uses that need
        the contiguous layout copy it (``.contiguous()``, ``.reshape``). ``ry`` held as ``(h, a, Hp)``
        (``ry.transpose(0, 1)`` contiguous) spares that build a copy of it.
    """
    C, (a, h, Hp), (b, w, Wp) = psf.shape[0], ry.shape, rx.shape
    if matrix_units:
        return _matrix_unit_operator(psf, dense_factors(ry, rx) if factors is None else factors, (h, w))
    rx2 = rx.reshape(b * w, Wp)
    rows_first = a * h * Wp * (Hp + b * w)  # the dense products' multiply-adds, per PSF channel
    columns_first = Hp * b * w * (Wp + a * h)
    # On a CPU only: a GPU runs one large product faster than hundreds of small ones (one launch each).
    if (spans is not False and psf.device.type == "cpu" and min(rows_first, columns_first) >= _MIN_BANDED_MACS
            and not (ry.requires_grad or rx.requires_grad)):
        sy, sx = spans if spans is not None else (banded.row_spans(ry.reshape(a * h, Hp)), banded.row_spans(rx2))
        py, px = banded.cached_plan(*sy, Hp, C * b * w, sort_rows), banded.cached_plan(*sx, Wp, C * Hp, sort_rows)
        # Small blocked products run at a fraction of one large product's rate (call overhead, short
        # inner loops): banded only where it costs at most half the multiply-adds (banded._MAX_FRACTION).
        if py.cost + px.cost <= banded._MAX_FRACTION * C * min(rows_first, columns_first):
            row_major = row_major and py.order is not None
            if row_major:  # sorted rows: the same plan over the rows in canvas-row order (h, a), see _banded_operator
                py = py.regrouped(a)
            return _banded_operator(psf, ry, rx2, py, px, (b, w), row_major)
    # Two matrix products, in the order with fewer multiply-adds, then one transposing copy into the
    # (C, a, b, h, w) layout apply_operator reads as a matrix. einsum's own plan copied the operator
    # twice more (forward and backward; docs/benchmarks.md, "Operator layout").
    if rows_first <= columns_first:
        # rows first: (C, a h, Wp), then (C a h, Wp) x (Wp, b w)
        t = torch.einsum("phk,ckl->cphl", ry, psf)
        m = t.reshape(C * a * h, Wp) @ rx2.T
    else:
        # columns first: (C Hp, Wp) x (Wp, b w), then (a h, Hp) x (C, Hp, b w). Fewer products where the
        # scene is large (Table 3's 109 x 146 canvas at 24x32: 4.0 instead of 5.0 GMAC; 1.13x forward
        # and backward on one AVX2 core), the same operator to float rounding.
        u = psf.reshape(C * Hp, Wp) @ rx2.T
        m = ry.reshape(a * h, Hp) @ u.reshape(C, Hp, b * w)
    return m.reshape(C, a, h, b, w).transpose(2, 3).contiguous()


def _banded_operator(psf, ry, rx2, py, px, bw, row_major: bool) -> torch.Tensor:
    """:func:`scene_operator` with the correlation tensors' zeros skipped (:mod:`.banded`).

    The correlation tensors are banded (a scene row reaches an embedding row through a few PSF rows
    only): on Table 3's 24x32 canvas 6 % and 5 % of their entries lie in the blocks' spans, and the
    build does 0.24 instead of 4.0 GMAC; the same operator up to the order of float sums. Columns
    first: the second product comes out with its rows those of the row tensor and its columns
    ``(C, b, w)``. (Rows first would come out as ``(b, w, C, a, h)``, a copy that moves every entry
    across the whole tensor: 69 + 84 ms forward and backward on Table 3's 12 M-entry operator, one AVX2
    core.)

    ``row_major`` (the rows sorted by band, ``py`` planned over them in canvas-row order ``(h, a)``):
    the product is ``(h, a, C, b, w)``, and the operator is returned as its ``(C, a, b, h, w)`` view, not
    copied. :func:`apply_operator` multiplies scenes by it canvas row by canvas row, each row's block
    contiguous, with no copy either way (the copy into ``(C, a, b, h, w)`` and its gradient's copy back
    took 5.6 + 7.5 ms of Table 3's 115-ms 24x32 shift step on one AVX2 core). Otherwise rows ``(a, h)``
    and a contiguous ``(C, a, b, h, w)`` copy, which keeps rows of ``w`` intact.
    """
    (C, Hp, Wp), (a, h, _), (b, w) = psf.shape, ry.shape, bw
    u = banded.banded_mm(rx2, psf.permute(2, 0, 1).reshape(Wp, C * Hp), px)  # (b w, C Hp)
    u = u.reshape(b * w, C, Hp).permute(2, 1, 0).reshape(Hp, C * b * w)
    if row_major:  # free where ry is held as (h, a, Hp), as the encoders cache it
        m = banded.banded_mm(ry.transpose(0, 1).reshape(h * a, Hp), u, py)  # (h a, C b w)
        return m.reshape(h, a, C, b, w).permute(2, 1, 3, 0, 4)
    m = banded.banded_mm(ry.reshape(a * h, Hp), u, py)  # (a h, C b w): (a, h, C, b, w)
    return m.reshape(a, h, C, b, w).permute(2, 0, 3, 1, 4).contiguous()


def paste(windows: torch.Tensor, offsets: torch.Tensor, shape: tuple[int, int]) -> torch.Tensor:
    """Canvases ``(B, C, rows, cols)``, zero but for each example's window at its offset (rows, cols).

    Two-byte floats are moved as their bits (``int16``): a copy either way, and torch's CPU scatter of
    ``bfloat16`` is ~3x slower than of ``int16`` (Table 3's shift batch: 1.2 against 0.4 ms, two threads).
    """
    B, C, h, w = windows.shape
    bits = windows.view(torch.int16) if windows.dtype in (torch.bfloat16, torch.float16) else windows
    idx = _window_index(offsets.to(windows.device, torch.long), C, (h, w), shape[1])
    out = torch.zeros(B, C, shape[0] * shape[1], dtype=bits.dtype, device=windows.device)
    out = out.scatter_(2, idx, bits.reshape(B, C, h * w)).reshape(B, C, *shape)
    return out.view(windows.dtype)


def _window_index(corners: torch.Tensor, channels: int, size: tuple[int, int], cols: int) -> torch.Tensor:
    """``(B, C, h w)`` flat canvas indices of the ``size`` windows whose top-left corners are ``corners``."""
    h, w = size
    r = corners[:, 0, None] + torch.arange(h, device=corners.device)
    c = corners[:, 1, None] + torch.arange(w, device=corners.device)
    return (r[:, :, None] * cols + c[:, None, :]).reshape(len(corners), 1, h * w).expand(-1, channels, -1)


def dense_factors(ry: torch.Tensor, rx: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """``(ry (a h, Hp), its transpose, rx (b w, Wp), its transpose)``, each contiguous: the matrix-unit build's factors."""
    (a, h, Hp), (b, w, Wp) = ry.shape, rx.shape
    ry2, rx2 = ry.reshape(a * h, Hp).contiguous(), rx.reshape(b * w, Wp).contiguous()
    return ry2, ry2.T.contiguous(), rx2, rx2.T.contiguous()


class _MatrixUnitOperator(torch.autograd.Function):
    """``(C, Hp, Wp)`` PSF -> ``(C, b, a h, w)`` operator by dense products; the factors are constants.

    Forward: one product per channel, ``ry (a h, Hp) x u (Hp, b w)``, then its ``(a h, b, w) -> (b, a h, w)``
    copy: the same operator, bit for bit, as a product per embedding column ``b`` writing the layout
    directly (Table 3's 24x32 canvas, two AMX cores: 1.02-1.23x faster alone, ``examples/paper/build_products.py``;
    1.06x on average in the training step, where the copy competes for the caches). Backward: a product per
    column, ``ry^T (Hp, a h) x grad[b] (a h, w)``. One product with the gradient's copy would be ~1.7x faster
    alone (1.11x in the step), but sums in another order (bfloat16 rounding apart), so every bfloat16 learned
    cell would train differently (docs/benchmarks.md, "One product per channel").
    """

    @staticmethod
    def forward(ctx, psf, ry2, ry2_t, rx2, rx2_t, w):
        (C, Hp, Wp), ah, b = psf.shape, ry2.shape[0], rx2.shape[0] // w
        u = (psf.reshape(C * Hp, Wp) @ rx2_t).view(C, Hp, b * w)
        out = psf.new_empty(C, b, ah, w)
        for c in range(C):
            out[c] = (ry2 @ u[c]).view(ah, b, w).transpose(0, 1)
        ctx.save_for_backward(ry2_t, rx2)
        ctx.dims = (C, Hp, Wp, b, w)
        return out

    @staticmethod
    def backward(ctx, grad):
        ry2_t, rx2 = ctx.saved_tensors
        C, Hp, Wp, b, w = ctx.dims
        grad = grad.contiguous()
        gu = grad.new_empty(C, b, Hp, w)
        for c in range(C):
            for j in range(b):
                torch.mm(ry2_t, grad[c, j], out=gu[c, j])
        gpsf = gu.transpose(1, 2).reshape(C * Hp, b * w) @ rx2
        return gpsf.view(C, Hp, Wp), None, None, None, None, None


def _matrix_unit_operator(psf: torch.Tensor, factors, hw: tuple[int, int]) -> torch.Tensor:
    """:func:`scene_operator` by dense bfloat16 products, as a CPU's matrix units (AMX) run them.

    A matrix unit multiplies one large bfloat16 product ~30 times faster per multiply-add than the banded
    build's hundreds of small ones (on the development machine's AMX, one core: ~550 against ~16 GMAC/s),
    so the dense products, 15x the banded ones' multiply-adds on Table 3's 24x32 canvas, take less time.
    Columns first, ``u = psf rx^T``, then for each embedding column ``b`` the product
    ``ry (a h, Hp) x u[:, b] (Hp, w)``: the operator comes out as ``(C, b, a, h, w)``, whose rows
    ``(C, b, a)`` are contiguous ``(h, w)`` blocks, so a batch of scenes is one product with it
    (:func:`apply_operator`) and its gradient comes back in the same layout: no copy of the operator
    either way. Returned as its ``(C, a, b, h, w)`` view. The same sums as the banded build up to their
    order (both round ``u`` and the operator to bfloat16; the zeros the banded build skips add nothing).
    """
    h, w = hw
    a, b = factors[0].shape[0] // h, factors[2].shape[0] // w
    op = _MatrixUnitOperator.apply(psf, *factors, w)
    return op.view(psf.shape[0], b, a, h, w).transpose(1, 2)


def _matrix_unit_layout(op: torch.Tensor) -> bool:
    """Whether a ``(C, a, b, h, w)`` operator is the view of a contiguous ``(C, b, a, h, w)`` one (:func:`_matrix_unit_operator`)."""
    return op.dim() == 5 and not op.is_contiguous() and op.transpose(1, 2).is_contiguous()


class _FlatApply(torch.autograd.Function):
    """``x @ op.T`` for ``(B, K)`` scenes and an ``(R, K)`` operator; the operator's gradient in its layout."""

    @staticmethod
    def forward(ctx, op, x):
        ctx.save_for_backward(op if ctx.needs_input_grad[1] else None, x if ctx.needs_input_grad[0] else None)
        return x @ op.T

    @staticmethod
    def backward(ctx, grad):
        op, x = ctx.saved_tensors
        # (R, B) x (B, K) with the transposed gradient made contiguous: a transposed left factor takes
        # bfloat16's slow path (Table 3's 24x32 canvas: 12.3 against 3.6 ms, one AMX core).
        gop = grad.to(x.dtype).T.contiguous() @ x if ctx.needs_input_grad[0] else None
        gx = grad.to(op.dtype) @ op if ctx.needs_input_grad[1] else None
        return gop, gx


def operator_rows(op: torch.Tensor) -> torch.Tensor | None:
    """The ``(h, a C b, w)`` canvas-row blocks of a ``(C, a, b, h, w)`` operator held row by row, else None.

    The banded build with sorted rows (:func:`scene_operator`) returns a view of an ``(h, a, C, b, w)``
    tensor: block ``p`` is the ``(a C b, w)`` matrix taking canvas row ``p`` to the embedding, whose rows
    are in ``(a, C, b)`` order. None for any other layout (a contiguous operator included).
    """
    if op.dim() != 5 or op.is_contiguous():
        return None
    rows = op.permute(3, 1, 0, 2, 4)
    if not rows.is_contiguous():
        return None
    h, a, C, b, w = rows.shape
    return rows.view(h, a * C * b, w)


def apply_operator(op: torch.Tensor, scene: torch.Tensor, skip_zeros: bool = True) -> torch.Tensor:
    """Apply a ``(C, a, b, h, w)`` operator to ``(B, C or 1, h, w)`` scenes -> ``(B, C, a, b)``.

    ``skip_zeros``: gray scenes whose nonzero pixels lie in a few rows (a digit on an augmentation
    canvas) multiply only those rows' part of the operator (exact); False: one dense product.
    """
    C, a, b, h, w = op.shape
    x = scene.reshape(scene.shape[0], scene.shape[1], h * w)
    if x.shape[1] not in (1, C):
        raise ConfigError("scene channels", x.shape[1], f"must be 1 or {C} (the PSF's channels)")
    if _matrix_unit_layout(op):  # one product with the (C b a, h w) matrix (_matrix_unit_operator)
        flat = op.transpose(1, 2).reshape(C, b * a, h * w)
        if x.shape[1] == 1:
            out = _FlatApply.apply(flat.reshape(C * b * a, h * w), x[:, 0])
        else:
            out = torch.bmm(x.transpose(0, 1), flat.transpose(1, 2)).transpose(0, 1)
        return out.reshape(scene.shape[0], C, b, a).transpose(2, 3).reshape(scene.shape[0], C, a, b)
    sparse = skip_zeros and x.shape[1] == 1 and not x.requires_grad
    rows = operator_rows(op) if sparse and op.device.type == "cpu" else None
    out, runs = _row_major_product(scene[:, 0], rows) if rows is not None else (None, None)
    if out is not None:  # (B, a, C, b)
        return out.reshape(scene.shape[0], a, C, b).transpose(1, 2).reshape(scene.shape[0], C, a, b)
    flat = op.reshape(C, a * b, h * w)  # a copy where op is held row by row (the product could not use that)
    # Explicit products with the operator on the right, transposed: their gradient with respect to the
    # operator comes out in the operator's own layout (einsum's transposed it, a copy of the whole operator).
    if x.shape[1] == 1:
        out = _sparse_scene_product(scene[:, 0], flat.reshape(C * a * b, h * w), runs) if sparse else None
        out = x[:, 0] @ flat.reshape(C * a * b, h * w).T if out is None else out
    else:
        out = torch.bmm(x.transpose(0, 1), flat.transpose(1, 2)).transpose(0, 1)
    return out.reshape(scene.shape[0], C, a, b)


# A canvas-row-major operator multiplies all scenes row by row (no run of lit rows to skip to) from this
# canvas width on: each row's product then has enough columns to run near one large product's rate, and
# it saves the copy into the (C, a, b, h, w) layout and back (Table 3's 109 x 146 canvas: 145 against
# 176 ms forward and backward, dense scenes, one AVX2 core); narrower, one product after the copy wins
# (41 x 40: 16.1 against 14.0 ms; 60 x 100: 54.7 against 52.1 ms).
_ROW_MAJOR_DENSE_WIDTH = 128


def _row_major_product(x: torch.Tensor, rows: torch.Tensor):
    """``(B, a C b)`` products of ``(B, h, w)`` scenes with an operator's canvas-row blocks ``(h, a C b, w)``.

    Sorted by their first lit row, the scenes lighting any one canvas row are a run of consecutive
    scenes; each row's block multiplies its run only (:func:`banded.row_runs_mm`; exact, the same terms
    summed in another order). Where the runs do not skip enough (scenes filling the canvas), all scenes
    for every row on a wide canvas (``_ROW_MAJOR_DENSE_WIDTH``), else None: the caller copies the operator
    into one matrix. Returns ``(product or None, the runs found or None)`` (:func:`_lit_row_runs`).
    """
    B, h, w = x.shape
    if rows.shape[1] < _MIN_SPARSE_ROWS and w < _ROW_MAJOR_DENSE_WIDTH:
        return None, None  # a small operator: the dense product at once, as _sparse_scene_product takes it
    found = None
    if B >= 2 and B * h * w * rows.shape[1] >= _MIN_BANDED_MACS:
        found = order, s0, s1 = _lit_row_runs(x)
        runs = list(zip(s0.tolist(), s1.tolist()))
        # One product a canvas row, each with its call overhead (banded._BLOCK_OVERHEAD, forward and
        # backward): against the dense product's multiply-adds (6x8's operator of 48 rows on a 53 x 50
        # region: 0.89x without this).
        work = sum(max(0, e - s) for s, e in runs) * w * rows.shape[1] + h * banded._BLOCK_OVERHEAD
        if work <= banded._MAX_FRACTION * B * h * w * rows.shape[1]:
            out = banded.row_runs_mm(rows, x.index_select(0, order), runs)
            return out.index_select(0, torch.argsort(order)), found
    if w >= _ROW_MAJOR_DENSE_WIDTH:
        return banded.row_runs_mm(rows, x, [(0, B)] * h), found
    return None, found


# The scenes' row scan (~0.5 ns a pixel) must be small next to the product it may save (C a b multiply-adds
# a pixel at ~30 GMAC/s): below this many operator rows the dense product is taken at once.
_MIN_SPARSE_ROWS = 128
# Candidate blocks of whole canvas rows for the scenes' product (:func:`_sparse_scene_product`).
_SCENE_BLOCK_ROWS = (1, 2, 4, 8)


def _sparse_scene_product(x: torch.Tensor, opm: torch.Tensor, runs=None) -> torch.Tensor | None:
    """``x @ opm.T`` for ``(B, h, w)`` scenes that are zero outside a few rows each, or None if not cheaper.

    A digit shifted on Table 3's canvas covers about a fifth of its rows. Sorted by their first lit row,
    the scenes lighting any one canvas row are a run of consecutive scenes, so each block of canvas rows
    multiplies its part of the operator by that run only (:func:`banded.column_banded_mm`; exact, the
    same terms summed in another order): the operator and its gradient are read and written once per
    step, in products of tens of scenes. None off a CPU (a GPU runs one large product faster than many
    small ones), where the operator is small, or where the scenes fill too much of the canvas for that to
    save work. ``runs``: the scenes' :func:`_lit_row_runs`, where already found.
    """
    B, h, w = x.shape
    if B < 2 or x.device.type != "cpu" or opm.shape[0] < _MIN_SPARSE_ROWS or B * h * w * opm.shape[0] < _MIN_BANDED_MACS:
        return None
    order, s0, s1 = _lit_row_runs(x) if runs is None else runs
    plan = banded.BandPlan(s0.repeat_interleave(w), s1.repeat_interleave(w), B, opm.shape[0],
                           block_rows=tuple(w * r for r in _SCENE_BLOCK_ROWS))
    if not plan.banded:
        return None
    out = banded.column_banded_mm(x.reshape(B, h * w).index_select(0, order), opm, plan)
    return out.index_select(0, torch.argsort(order))


def _lit_row_runs(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(order, s0, s1)`` of ``(B, h, w)`` scenes: sorted by their first lit row (``order``), the scenes
    lighting canvas row ``r`` lie in ``[s0[r], s1[r])`` of that order (an unlit row: ``[B, 0)``)."""
    h = x.shape[1]
    # (B, h) lit rows: a sum of absolute values is > 0 exactly when a term is (no cancellation; rounding
    # never takes a sum of positive terms to zero). 5x faster than amax and amin over a short last axis
    # (200 digits on 53 x 50 pixels: 0.17 against 0.85 ms, one AVX2 core).
    on = x.abs().sum(-1) > 0
    first, last = banded.row_spans(on)
    order = torch.argsort(first, stable=True)
    r = torch.arange(h)[:, None]
    lit = (first[order][None] <= r) & (last[order][None] > r)  # (h, B): canvas row r lit by sorted scene s
    s0, s1 = banded.row_spans(lit)
    return order.to(x.device), s0, s1


def snr_sigma(signal: torch.Tensor, snr_db: float) -> torch.Tensor:
    """Noise standard deviation per example for ``SNR_dB = 10 log10(var(signal) / var(noise))``.

    The variance is taken over all but the batch dimension; an all-constant
    (e.g. all-black) example gets zero noise, never NaN.
    """
    flat = signal.flatten(1)
    dev = flat - flat.mean(dim=1, keepdim=True)  # two passes: 13x faster than Tensor.var on one CPU thread
    var = (dev * dev).mean(dim=1)
    # A constant example (var 0) gets sigma 0; sqrt's infinite slope at 0 is kept out of the gradient (0, not NaN).
    lit = var > 0
    root = torch.sqrt(torch.where(lit, var, torch.ones_like(var)) * 10.0 ** (-snr_db / 10.0))
    sigma = torch.where(lit, root, torch.zeros_like(var))
    return sigma.reshape(-1, *([1] * (signal.dim() - 1)))


def add_noise(
    signal: torch.Tensor,
    snr_db: float | None,
    model: str = "gaussian",
    photons: float = 1e4,
    read_noise: float = 0.0,
    generator: torch.Generator | None = None,
    sigma: torch.Tensor | None = None,
    noise: torch.Tensor | None = None,
    level_gradient: bool = False,
) -> torch.Tensor:
    """Zero-mean sensor noise, added after pixel integration.

    Args:
        signal: ``(B, ...)`` noise-free measurement (non-negative).
        snr_db: target SNR in dB (paper A.4) for the ``gaussian`` model;
            ``None`` turns noise off.
        model: ``"gaussian"`` (differentiable, variance from the SNR),
            ``"poisson"`` (photon shot noise: the example's brightest pixel
            collects ``photons`` photons, plus Gaussian read noise of
            ``read_noise`` photo-electrons, rescaled back to signal units) or
            ``"none"``.
        generator: optional RNG for reproducible draws.
        sigma: the ``gaussian`` model's per-example standard deviation, ``snr_sigma(signal, snr_db)``, where
            the caller already has it (a fixed encoder's embeddings are the same every epoch); the same
            draws and the same sums as without it. Ignored by the other models.
        noise: the ``gaussian`` model's standard-normal draws, shaped as ``signal``, where the caller drew
            them already (what ``torch.randn`` with ``generator`` would give: the same sums); ``generator``
            is then not used. Ignored by the other models.
        level_gradient: the ``gaussian`` model's noise level ``sigma(signal)`` passes gradient to the signal:
            the exact derivative of ``signal + sigma(signal) * noise`` (an encoder learns how its pattern sets
            its own noise). False (default): ``sigma`` is a constant in the backward pass, the gradient the
            identity. The values are the same either way. Ignored with a given ``sigma``.
    """
    if model == "none" or (model == "gaussian" and snr_db is None):
        return signal
    if model == "gaussian":
        if noise is None:
            noise = torch.randn(signal.shape, generator=generator, dtype=signal.dtype, device=signal.device)
        elif noise.shape != signal.shape:
            raise ValueError(f"noise: shape {tuple(noise.shape)}, must be the signal's {tuple(signal.shape)}")
        if sigma is None:
            sigma = snr_sigma(signal if level_gradient else signal.detach(), snr_db)
        return signal + sigma * noise
    if model == "poisson":
        peak = signal.detach().flatten(1).amax(dim=1)
        # A dark example (peak 0) collects no photons: scale 1 keeps it exactly zero.
        scale = torch.where(peak > 0, photons / peak.clamp_min(torch.finfo(signal.dtype).tiny), torch.ones_like(peak))
        scale = scale.reshape(-1, *([1] * (signal.dim() - 1)))
        counts = torch.poisson((signal.detach() * scale).clamp_min(0), generator=generator)
        if read_noise > 0:
            counts = counts + read_noise * torch.randn(
                signal.shape, generator=generator, dtype=signal.dtype, device=signal.device
            )
        # Straight-through: noisy values forward, the clean gradient backward.
        return signal + (counts / scale - signal).detach()
    raise ConfigError("sensor.noise", model, "one of 'gaussian', 'poisson', 'none'")


def quantize(signal: torch.Tensor, bits: int, full_scale: torch.Tensor | float | None = None) -> torch.Tensor:
    """ADC quantisation to ``bits`` with rounding (straight-through gradient).

    ``full_scale`` defaults to each example's maximum, i.e. an auto-exposed sensor.
    """
    levels = 2**bits - 1
    if full_scale is None:
        full_scale = signal.detach().flatten(1).amax(dim=1).reshape(-1, *([1] * (signal.dim() - 1)))
    fs = torch.as_tensor(full_scale, dtype=signal.dtype, device=signal.device).clamp_min(torch.finfo(signal.dtype).tiny)
    q = torch.round((signal / fs).clamp(0, 1) * levels) / levels * fs
    return signal + (q - signal).detach()


def _checked_total(total: torch.Tensor, name: str) -> torch.Tensor:
    """A PSF's total(s), refused when not finite or not positive.

    The totals are checked instead of every pixel: a sum is finite exactly
    when every term is (a NaN or an infinite pixel makes it NaN or infinite;
    ``0 * inf`` under a zero weight is NaN), short of finite terms that
    overflow, which are refused too.
    """
    if not bool(torch.isfinite(total.detach()).all()):
        raise PhysicsError(f"{name}: the PSF has NaN or infinite values")
    if bool((total.detach() <= 0).any()):
        raise PhysicsError(f"{name}: the PSF has zero energy (all-zero or fully opaque); nothing reaches the sensor")
    return total


def _spectral_weights(psf: torch.Tensor, weights) -> torch.Tensor:
    """``(C, 1, 1)`` spectral weights of a ``(C, H, W)`` PSF (default: the gray sensor's for 3 channels)."""
    C = psf.shape[-3]
    if weights is None:
        from ..devices import GRAYSCALE_WEIGHTS

        weights = GRAYSCALE_WEIGHTS if C == 3 else (1.0,) * C
    w = torch.as_tensor(weights, dtype=psf.dtype, device=psf.device).reshape(-1)
    if w.numel() != C:
        raise ConfigError("weights", tuple(w.tolist()), f"must have one weight per PSF channel ({C})")
    return w[:, None, None]


def normalize_psf(psf: torch.Tensor, weights=None, name: str = "psf") -> torch.Tensor:
    """Scale a ``(C, H, W)`` intensity PSF by one factor shared by all channels.

    The channels keep their relative transmitted power: the factor makes the
    spectrally weighted total ``sum_c w_c sum_xy psf_c`` equal one, so the
    gray sensor's PSF ``sum_c w_c psf_c`` sums to one and an RGB sensor's
    channels keep the ratios the mask gives them (a dimmed colour filter
    passes less light). A neutral-density change (every channel scaled by the
    same factor) leaves the result unchanged: the noise is set by an SNR, so
    only relative power matters.

    Args:
        psf: ``(C, H, W)`` non-negative intensity PSF, channels on one power scale.
        weights: ``(C,)`` spectral weights of the sensor; default
            :data:`optoenc.devices.GRAYSCALE_WEIGHTS` for 3 channels, 1 for one.

    Raises:
        PhysicsError: the PSF is not finite or has no weighted energy at all.
    """
    total = (_spectral_weights(psf, weights) * psf.sum(dim=(-2, -1), keepdim=True)).sum(dim=-3, keepdim=True)
    return psf / _checked_total(total, name)


def normalize_channels(psf: torch.Tensor, name: str = "psf") -> torch.Tensor:
    """Scale each channel of a ``(C, H, W)`` PSF to sum one on its own.

    Only for PSFs whose channels are not on one power scale, e.g. a measured
    PSF whose colour balance is that of the lab's light source and sensor, not
    of the optic. Mask PSFs use :func:`normalize_psf`.

    Raises:
        PhysicsError: the PSF is not finite, or a channel has no energy.
    """
    return psf / _checked_total(psf.sum(dim=(-2, -1), keepdim=True), name)


def sensor_psf(raw: torch.Tensor, channels: int, weights=None, name: str = "psf") -> torch.Tensor:
    """The PSF a sensor with ``channels`` (1 gray, 3 RGB) sees, from a ``(C, H, W)`` spectral PSF.

    Channels are normalised jointly (:func:`normalize_psf`). A gray sensor
    sees ``sum_c w_c psf_c`` (sums to one); an RGB sensor sees the channels
    themselves (their weighted sums add to one); a 1-channel (achromatic) PSF
    is shared by all of an RGB sensor's channels (each sums to one).
    """
    w = _spectral_weights(raw, weights)
    if channels == 1 and raw.shape[-3] > 1:
        # normalize_psf, then the weighted sum, in the other order: one pass over the channels
        gray = (w * raw).sum(dim=-3, keepdim=True)
        return gray / _checked_total(gray.sum(dim=(-2, -1), keepdim=True), name)
    psf = normalize_psf(raw, weights, name=name)
    if channels > 1 and psf.shape[-3] == 1:
        return psf.expand(channels, -1, -1)
    return psf
