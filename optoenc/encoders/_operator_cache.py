"""One encoder's scene-operator cache and choice of algorithm (private to :mod:`optoenc.encoders.operator`).

:class:`OperatorCache` keeps the geometry's correlation tensors and the whole
scene's operator for the current PSF, and chooses how to measure: the
fine-grid FFT path or the operator, the scenes' support region, the banded
build with sorted rows held canvas row by canvas row, the matrix-unit build.
:class:`_Paths` switches a speed-up off, for the tests that it gives the plain
path's numbers and ``benchmarks/operator_paths.py``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch

from .. import hardware
from ..errors import ConfigError
from . import _banded, imaging
from ._operator_apply import apply_operator
from ._operator_build import dense_factors, scene_operator

__all__ = ["OperatorCache"]

#: Up to this many operator entries the operator is always used; above it only while it is smaller than what
#: the fine-grid (FFT) path would allocate for the batch, and never above _HARD_MAX_OPERATOR_ENTRIES (1 GiB).
_MAX_OPERATOR_ENTRIES = 40_000_000
_HARD_MAX_OPERATOR_ENTRIES = 2**28
#: The fine-grid path convolves at most this many padded complex samples at once (~1 GiB); larger batches go
#: in chunks.
_DIRECT_CHUNK_SAMPLES = 2**26
#: Scene geometries whose correlation tensors are kept (oldest dropped first).
_MAX_GEOMETRIES = 4
#: The operator of the scenes' support region is built when that costs less than this fraction of the whole
#: operator's multiply-adds (a margin for the slicing copies).
_REGION_GAIN = 0.8


@dataclass(frozen=True)
class _Paths:
    """The speed-ups the operator may take (each exact up to the order of float sums); all on: where they pay.

    A field off forces the plain path of that step, for the tests of each speed-up and
    ``benchmarks/operator_paths.py``:

    * ``support_regions``: the operator of the batch's nonzero pixels only, where cheaper (:meth:`OperatorCache.support_region`);
    * ``banded``: the build skips the correlation tensors' zeros, and gray scenes lit on a few canvas rows multiply
      only those rows (:mod:`._banded`);
    * ``sorted_rows``: the banded build takes the rows in the order of their bands, in taller blocks;
    * ``row_major``: the sorted build's operator is held and applied canvas row by canvas row, without copies;
    * ``matrix_units``: a bfloat16 operator on a CPU with matrix units (AMX) is built by dense products in the
      layout one product applies.
    """

    support_regions: bool = True
    banded: bool = True
    sorted_rows: bool = True
    row_major: bool = True
    matrix_units: bool = True


#: Every speed-up off: the reference the speed-ups are tested and timed against.
_PLAIN = _Paths(False, False, False, False, False)


class OperatorCache:
    """One encoder's scene-operator caches and choice of algorithm (the encoder holds it as ``_operators``).

    Holds no reference to the encoder (its methods take it): no reference cycle keeps a graph alive.
    """

    def __init__(self) -> None:
        self.paths = _Paths()
        #: Correlation tensors per geometry: ``key -> [ry, rx, spans, dense factors or None]``.
        self.factors: dict[Any, list] = {}
        #: ``(key, operator)`` of the whole scene's operator for the current PSF, or None.
        self.whole: tuple[Any, torch.Tensor] | None = None

    def forget_operator(self) -> None:
        """Drop the cached whole-scene operator (its PSF changed)."""
        self.whole = None

    def clear(self) -> None:
        """Drop every cache (the encoder's precision or device changed)."""
        self.factors.clear()
        self.whole = None

    # ----------------------------------------------------------------- building
    def geometry_factors(self, enc, scene_shape: tuple[int, int], height_px: float, device, dense: bool = False):
        """``(ry, rx, spans)``: the correlation tensors and their row spans (:func:`_banded.row_spans`), cached.

        ``dense``: instead, their :func:`dense_factors` (the matrix-unit build's), made on first use and
        cached in the same entry.
        """
        key = (scene_shape, round(height_px, 9), enc.operator_dtype, str(device), enc.sensor.sampling)
        if key not in self.factors:
            H, W = enc.geometry.grid
            a, b = enc.geometry.embedding
            s = enc.subcells
            # s > 1: the scene is placed and integrated on an s-times finer grid while the
            # PSF's grid values are cell averages: the scene keeps its sub-pixel structure.
            py, px = imaging.placement_matrices(scene_shape, (H * s, W * s), height_px * s, pixel_aspect=enc.pixel_aspect)
            sampling = enc.sensor.sampling
            ry = imaging.correlation_tensor(imaging.sampling_matrix(H * s, a, sampling), py, H, sub=s)
            rx = imaging.correlation_tensor(imaging.sampling_matrix(W * s, b, sampling), px, W, sub=s)
            # Bounded: a learned d2 changes the height every step.
            stale = list(self.factors)
            for k in stale[: max(0, len(stale) - _MAX_GEOMETRIES + 1)]:
                del self.factors[k]
            ry, rx = ry.to(device, enc.operator_dtype), rx.to(device, enc.operator_dtype)
            # Where each flattened row's nonzero entries lie: the banded build's plan (scene_operator).
            spans = tuple(_banded.row_spans(r.reshape(-1, r.shape[-1])) for r in (ry, rx))
            # ry held as (h, a, Hp), its (a, h, Hp) view: the sorted build reads it in canvas-row order
            # without a copy, also cut to a region's rows (scene_operator).
            ry = ry.transpose(0, 1).contiguous().transpose(0, 1)
            self.factors[key] = [ry, rx, spans, None]  # None: the dense factors, made on first use
        entry = self.factors[key]
        if not dense:
            return tuple(entry[:3])
        if entry[3] is None:
            entry[3] = dense_factors(entry[0], entry[1])
        return entry[3]

    def uses_matrix_units(self, enc, device) -> bool:
        """Whether the operator is built by dense products for the CPU's matrix units: a bfloat16 operator on a
        CPU with them (the one place this is decided; ``scene_operator`` does as told)."""
        return (self.paths.matrix_units and enc.operator_dtype == torch.bfloat16 and torch.device(device).type == "cpu"
                and hardware.matrix_units())

    @staticmethod
    def _region_spans(spans, scene_shape, region):
        """The row spans of the correlation tensors cut to the scene ``region`` (None: all of them)."""
        if region is None:
            return spans
        r0, r1, c0, c1 = region
        h, w = scene_shape

        def cut(pair, n, i0, i1):  # the rows (embedding row, scene row i0..i1) of a flattened (out, n) tensor
            return tuple(t.reshape(-1, n)[:, i0:i1].reshape(-1) for t in pair)

        return cut(spans[0], h, r0, r1), cut(spans[1], w, c0, c1)

    def tensor(self, enc, scene_shape: tuple[int, int], height: float | None = None,
               region: tuple[int, int, int, int] | None = None) -> torch.Tensor:
        """The ``(C, a, b, h, w)`` operator (:meth:`SceneOperator.tensor`); ``region``: its columns of scene pixels
        ``[r0, r1) x [c0, c1)`` only, ``(C, a, b, r1 - r0, c1 - c0)``, not cached."""
        psf = enc.psf()
        height_px = enc.object_height_px(height)
        ry, rx, spans = self.geometry_factors(enc, tuple(scene_shape), height_px, psf.device)
        spans = self._region_spans(spans, tuple(scene_shape), region) if self.paths.banded else False
        units = self.uses_matrix_units(enc, psf.device)
        sort_rows, row_major = self.paths.sorted_rows, self.paths.row_major
        if region is not None:
            r0, r1, c0, c1 = region
            return scene_operator(psf.to(enc.operator_dtype), ry[:, r0:r1], rx[:, c0:c1], spans, sort_rows, row_major, units)
        key = (tuple(scene_shape), height, enc._state_key())
        if self.whole is not None and self.whole[0] == key:
            return self.whole[1]
        factors = self.geometry_factors(enc, tuple(scene_shape), height_px, psf.device, dense=True) if units else None
        op = scene_operator(psf.to(enc.operator_dtype), ry, rx, spans, sort_rows, row_major, units, factors)
        self.whole = (key, op)
        return op

    # ----------------------------------------------------------------- the choice of algorithm
    def support_region(self, enc, scene: torch.Tensor, height: float | None = None) -> tuple[int, int, int, int] | None:
        """The region :meth:`measure` builds its operator for: the batch's nonzero pixels, or None (all).

        Zero pixels contribute nothing, so the operator restricted to the
        bounding box of the pixels that are nonzero in any scene of the batch
        gives the same embeddings (and gradients) as the whole operator. It is
        used where it costs fewer multiply-adds than the whole one: building
        ``(a, h, Hp)`` correlations into a PSF costs ``C a h Hp Wp + C a b h w Wp``
        and applying it ``B C a b h w``; the whole operator is free to build
        while it is cached (a fixed PSF), never while a learned PSF changes every
        step. On an augmentation canvas (the field of view, ~20 times a digit)
        a rotated or rescaled digit covers a few percent of the pixels.
        """
        if not self.paths.support_regions:
            return None
        h, w = scene.shape[-2:]
        flat = scene.detach().flatten(0, -3)
        on = (flat.amax(0) > 0) | (flat.amin(0) < 0)  # (h, w); two reductions: 7x cheaper than ne().any()
        rows, cols = on.any(1).nonzero(), on.any(0).nonzero()
        if len(rows) == 0:
            return (0, 1, 0, 1)  # all dark: any single pixel gives the zero embedding
        r0, r1, c0, c1 = int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
        return self.cheaper_region(enc, len(scene), (h, w), height, (r0, r1, c0, c1))

    def cheaper_region(self, enc, batch: int, shape: tuple[int, int], height, region) -> tuple[int, int, int, int] | None:
        """``region`` where its operator costs fewer multiply-adds than the whole scene's, else None."""
        (h, w), (r0, r1, c0, c1) = shape, region
        if (r1 - r0, c1 - c0) == (h, w):
            return None
        C, (a, b), (Hp, Wp) = enc.channels, enc.geometry.embedding, enc.geometry.grid
        build = lambda n, m: C * a * n * Hp * Wp + C * a * b * n * m * Wp  # noqa: E731
        apply = lambda n, m: batch * C * a * b * n * m  # noqa: E731
        whole_cached = self.whole is not None and self.whole[0] == ((h, w), height, enc._state_key())
        whole = (0 if whole_cached else build(h, w)) + apply(h, w)
        part = build(r1 - r0, c1 - c0) + apply(r1 - r0, c1 - c0)
        return (r0, r1, c0, c1) if part < _REGION_GAIN * whole else None

    @staticmethod
    def padded_samples(enc) -> int:
        """Complex samples per image and channel of the fine-grid path's zero-padded convolution (about)."""
        return 4 * enc.geometry.grid[0] * enc.geometry.grid[1] * enc.subcells**2

    def auto_method(self, enc, batch: int, scene_shape: tuple[int, int]) -> str:
        """``measure``'s ``"auto"`` choice for ``batch`` scenes of ``scene_shape`` pixels.

        The operator (one matrix product per batch) up to :data:`_MAX_OPERATOR_ENTRIES` entries, and
        beyond while it takes less memory than the fine-grid path would for the batch (a wide
        augmentation canvas on a fine grid: the FFT path needed ~20 GB per 1000 scenes); the
        fine-grid path above 1 GiB of operator.
        """
        a, b = enc.geometry.embedding
        entries = enc.channels * a * b * scene_shape[0] * scene_shape[1]
        # A batch's tail (fewer scenes) makes the same choice as its siblings: counted as at least 64 scenes.
        direct = max(batch, 64) * enc.channels * self.padded_samples(enc)
        if entries <= _MAX_OPERATOR_ENTRIES or entries <= min(direct, _HARD_MAX_OPERATOR_ENTRIES):
            return "operator"
        return "direct"

    # ----------------------------------------------------------------- measuring
    def measure(self, enc, scene: torch.Tensor, height: float | None, method: str) -> torch.Tensor:
        """Noise-free embeddings of checked ``(B, C, h, w)`` intensities, in the optics' precision (autocast off)."""
        a, b = enc.geometry.embedding
        if method == "auto":
            method = self.auto_method(enc, len(scene), tuple(scene.shape[-2:]))
        x = scene.to(enc.optics_dtype)
        if method == "operator":
            region = self.support_region(enc, x, height)
            op = self.tensor(enc, scene.shape[-2:], height, region)
            if region is not None:
                r0, r1, c0, c1 = region
                x = x[..., r0:r1, c0:c1]
            return apply_operator(op, x.to(op.dtype), self.paths.banded).to(enc.optics_dtype)
        if method == "direct":
            s = enc.subcells  # the same sub-pixel scene geometry as the operator
            grid = tuple(n * s for n in enc.geometry.grid)
            psf = imaging.subcell_psf(enc.psf(), s)
            step = max(1, _DIRECT_CHUNK_SAMPLES // (enc.channels * self.padded_samples(enc)))
            return torch.cat([
                imaging.integrate(imaging.fft_convolve(
                    imaging.place(x[i : i + step], grid, enc.object_height_px(height) * s, pixel_aspect=enc.pixel_aspect),
                    psf[None]), (a, b), enc.sensor.sampling)
                for i in range(0, len(x), step)])
        raise ConfigError("method", method, "one of 'auto', 'operator', 'direct'")

    def measure_laid(self, enc, x: torch.Tensor, region: tuple[int, int, int, int], scene_shape: tuple[int, int],
                     height, laid) -> torch.Tensor:
        """Embeddings of scenes zero outside ``region`` (:meth:`SceneOperator.apply_window`, ``apply_pasted``):
        ``laid(dtype, whole)`` lays out their pixels in ``dtype``, over ``region`` or (``whole``) the whole scene."""
        H, W = scene_shape
        if self.paths.support_regions and self.auto_method(enc, len(x), (H, W)) == "operator":
            with torch.autocast(x.device.type, enabled=False):  # the optics keep their own precisions
                if self.cheaper_region(enc, len(x), (H, W), height, region) == region:
                    op = self.tensor(enc, (H, W), height, region)
                    scenes = laid(op.dtype, False)
                else:
                    # The whole scene's operator: the region holds every nonzero pixel and is no cheaper, so no
                    # part of it is looked for (measure's support_region: a scan of the whole canvas), and the
                    # scenes are laid out in the operator's precision at once (a float padding and its conversion:
                    # ~4 ms of Table 3's 24x32 shift step on one core).
                    op = self.tensor(enc, (H, W), height)
                    scenes = laid(op.dtype, True)
                out = apply_operator(op, scenes, self.paths.banded).to(enc.optics_dtype)
            return out.to(x.dtype)
        return enc.measure(laid(x.dtype, True), height)
