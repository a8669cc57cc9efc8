"""Building the scene operator: the ``(C, a, b, h, w)`` matrix from a PSF and the geometry's correlation tensors.

Three builds of the same operator (the same sums up to their order), chosen by
:mod:`optoenc.encoders.operator`: the dense products (:func:`scene_operator`'s
plain path), the banded build that skips the correlation tensors' exact zeros
(:mod:`._banded`), and the dense bfloat16 products laid out for a CPU's matrix
units. Private: :class:`~optoenc.encoders.operator.SceneOperator` is the public face.
"""

from __future__ import annotations

import torch

from . import _banded

__all__ = ["scene_operator", "dense_factors"]


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
            tensors (:func:`optoenc.encoders._banded.row_spans`), to skip
            finding them; computed here when None. False: the dense
            products whatever the tensors' band (a reference).
        sort_rows: the banded build may take a correlation tensor's rows in
            the order of their spans (:class:`optoenc.encoders._banded.BandPlan`);
            False: consecutive rows only (a reference).
        row_major: where the rows are sorted, return the operator held canvas row by canvas row (below);
            False: a contiguous ``(C, a, b, h, w)`` tensor always (a reference).
        matrix_units: the dense products, in the layout that one product applies (:func:`_matrix_unit_operator`),
            whatever ``spans`` says: for a bfloat16 PSF on a CPU whose matrix units multiply bfloat16 (AMX), as the
            caller decides (:mod:`optoenc.encoders.operator`); any dtype gives the same operator.
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
        sy, sx = spans if spans is not None else (_banded.row_spans(ry.reshape(a * h, Hp)), _banded.row_spans(rx2))
        py, px = _banded.cached_plan(*sy, Hp, C * b * w, sort_rows), _banded.cached_plan(*sx, Wp, C * Hp, sort_rows)
        # Small blocked products run at a fraction of one large product's rate (call overhead, short
        # inner loops): banded only where it costs at most half the multiply-adds (_banded._MAX_FRACTION).
        if py.cost + px.cost <= _banded._MAX_FRACTION * C * min(rows_first, columns_first):
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
    """:func:`scene_operator` with the correlation tensors' zeros skipped (:mod:`._banded`).

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
    u = _banded.banded_mm(rx2, psf.permute(2, 0, 1).reshape(Wp, C * Hp), px)  # (b w, C Hp)
    u = u.reshape(b * w, C, Hp).permute(2, 1, 0).reshape(Hp, C * b * w)
    if row_major:  # free where ry is held as (h, a, Hp), as the encoders cache it
        m = _banded.banded_mm(ry.transpose(0, 1).reshape(h * a, Hp), u, py)  # (h a, C b w)
        return m.reshape(h, a, C, b, w).permute(2, 1, 3, 0, 4)
    m = _banded.banded_mm(ry.reshape(a * h, Hp), u, py)  # (a h, C b w): (a, h, C, b, w)
    return m.reshape(a, h, C, b, w).permute(2, 0, 3, 1, 4).contiguous()



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

