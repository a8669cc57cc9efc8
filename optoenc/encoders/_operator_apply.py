"""Applying the scene operator to a batch of scenes, in the layout its build returned.

One product where that is fastest; gray scenes lit on a few canvas rows (a
digit on an augmentation canvas) multiply only those rows' part of the
operator (exact: the same terms summed in another order). Private:
:class:`~optoenc.encoders.operator.SceneOperator` is the public face.
"""

from __future__ import annotations

import torch

from ..errors import ConfigError
from . import _banded, _operator_build

__all__ = ["apply_operator", "operator_rows"]


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
    scenes; each row's block multiplies its run only (:func:`_banded.row_runs_mm`; exact, the same terms
    summed in another order). Where the runs do not skip enough (scenes filling the canvas), all scenes
    for every row on a wide canvas (``_ROW_MAJOR_DENSE_WIDTH``), else None: the caller copies the operator
    into one matrix. Returns ``(product or None, the runs found or None)`` (:func:`_lit_row_runs`).
    """
    B, h, w = x.shape
    if rows.shape[1] < _MIN_SPARSE_ROWS and w < _ROW_MAJOR_DENSE_WIDTH:
        return None, None  # a small operator: the dense product at once, as _sparse_scene_product takes it
    found = None
    if B >= 2 and B * h * w * rows.shape[1] >= _operator_build._MIN_BANDED_MACS:
        found = order, s0, s1 = _lit_row_runs(x)
        runs = list(zip(s0.tolist(), s1.tolist()))
        # One product a canvas row, each with its call overhead (_banded._BLOCK_OVERHEAD, forward and
        # backward): against the dense product's multiply-adds (6x8's operator of 48 rows on a 53 x 50
        # region: 0.89x without this).
        work = sum(max(0, e - s) for s, e in runs) * w * rows.shape[1] + h * _banded._BLOCK_OVERHEAD
        if work <= _banded._MAX_FRACTION * B * h * w * rows.shape[1]:
            out = _banded.row_runs_mm(rows, x.index_select(0, order), runs)
            return out.index_select(0, torch.argsort(order)), found
    if w >= _ROW_MAJOR_DENSE_WIDTH:
        return _banded.row_runs_mm(rows, x, [(0, B)] * h), found
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
    multiplies its part of the operator by that run only (:func:`_banded.column_banded_mm`; exact, the
    same terms summed in another order): the operator and its gradient are read and written once per
    step, in products of tens of scenes. None off a CPU (a GPU runs one large product faster than many
    small ones), where the operator is small, or where the scenes fill too much of the canvas for that to
    save work. ``runs``: the scenes' :func:`_lit_row_runs`, where already found.
    """
    B, h, w = x.shape
    if B < 2 or x.device.type != "cpu" or opm.shape[0] < _MIN_SPARSE_ROWS or B * h * w * opm.shape[0] < _operator_build._MIN_BANDED_MACS:
        return None
    order, s0, s1 = _lit_row_runs(x) if runs is None else runs
    plan = _banded.BandPlan(s0.repeat_interleave(w), s1.repeat_interleave(w), B, opm.shape[0],
                           block_rows=tuple(w * r for r in _SCENE_BLOCK_ROWS))
    if not plan.banded:
        return None
    out = _banded.column_banded_mm(x.reshape(B, h * w).index_select(0, order), opm, plan)
    return out.index_select(0, torch.argsort(order))


def _lit_row_runs(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(order, s0, s1)`` of ``(B, h, w)`` scenes: sorted by their first lit row (``order``), the scenes
    lighting canvas row ``r`` lie in ``[s0[r], s1[r])`` of that order (an unlit row: ``[B, 0)``)."""
    h = x.shape[1]
    # (B, h) lit rows: a sum of absolute values is > 0 exactly when a term is (no cancellation; rounding
    # never takes a sum of positive terms to zero). 5x faster than amax and amin over a short last axis
    # (200 digits on 53 x 50 pixels: 0.17 against 0.85 ms, one AVX2 core).
    on = x.abs().sum(-1) > 0
    first, last = _banded.row_spans(on)
    order = torch.argsort(first, stable=True)
    r = torch.arange(h)[:, None]
    lit = (first[order][None] <= r) & (last[order][None] > r)  # (h, B): canvas row r lit by sorted scene s
    s0, s1 = _banded.row_spans(lit)
    return order.to(x.device), s0, s1

