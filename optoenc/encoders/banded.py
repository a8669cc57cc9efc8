"""Products with a constant banded matrix: the scene operator's geometry factors.

The 1-D correlation tensors that build the scene operator
(:func:`optoenc.encoders.imaging.correlation_tensor`) are banded: a scene row
``p`` reaches an embedding row ``a`` only through the few PSF rows ``k`` where
the box of ``a`` overlaps the placed row ``p`` shifted by ``k``. On Table 3's
augmentation canvas (24x32 embedding, 109 x 146 canvas, 288 x 384 PSF grid)
about 4 % of the entries are nonzero, and a dense product spends 96 % of its
multiply-adds on zeros.

:class:`BandPlan` cuts the rows of such a matrix ``A`` into blocks of
consecutive rows and records, for each block, the column range holding all of
its nonzero entries. ``A @ B`` is then one small dense product per block,
``A[r0:r1, k0:k1] @ B[k0:k1]``, which skips only exact zeros: the result is
the dense product's up to the order of float sums. :func:`banded_mm` is that
product with its gradient with respect to ``B`` (``A`` is geometry: constant).

:func:`column_banded_mm` is the other side: ``X @ W.T`` for a constant ``X``
whose *columns* are banded (a batch of digits on a canvas, sorted by where
they start: each canvas pixel is lit by a run of consecutive scenes), with its
gradient with respect to ``W`` (the scene operator). Its plan is the
:class:`BandPlan` of ``X.T``.
"""

from __future__ import annotations

import torch

__all__ = ["BandPlan", "banded_mm", "column_banded_mm", "row_spans"]

# Candidate row-block sizes. Larger blocks amortise each product's call overhead and feed the GEMM
# kernels more rows; smaller ones follow a sloping band more tightly. The plan takes the candidate with
# the smallest modelled cost (multiply-adds plus a per-block overhead, below).
_BLOCK_ROWS = (4, 8, 16, 32, 64)
# Per-block overhead, in multiply-adds: one small product's call, slicing and kernel set-up, forward and
# backward, take ~15 us on one AVX2 core (Table 3's column factor, 913 blocks of 4 rows: 9.0 ms forward
# for 24 M multiply-adds), ~200,000 multiply-adds of a forward product at ~30 GMAC/s (its backward doing
# as many again). On Table 3's canvas (4,672 columns in the row factor's product) that is 43 row-times-
# band-width units a block, and 4-row blocks win; a narrow product (Table 1's 28 x 28 digit at 12x16:
# 448 columns) needs wide blocks or the dense product.
_BLOCK_OVERHEAD = 200_000
# Banded products are used when their modelled cost is at most this fraction of the dense product's
# multiply-adds: one large GEMM runs closer to the machine's peak than many small ones.
_MAX_FRACTION = 0.5


def row_spans(a: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """For each row of an ``(m, k)`` matrix, ``[first, last)``: the columns holding its nonzero entries.

    An all-zero row gets the empty span ``[k, 0)``.
    """
    if a.dim() != 2:
        raise ValueError(f"row_spans needs a matrix, got shape {tuple(a.shape)}")
    k = a.shape[1]
    nz = a != 0
    cols = torch.arange(k, device=a.device)
    first = torch.where(nz, cols, k).amin(dim=1)
    last = torch.where(nz, cols, -1).amax(dim=1) + 1
    return first.cpu(), last.cpu()


class BandPlan:
    """Row blocks of a constant ``(m, k)`` matrix and the column range of each block's nonzero entries.

    Args:
        first, last: ``(m,)`` per-row spans of the nonzero entries (:func:`row_spans`).
        k: the matrix's number of columns.
        n: the number of columns of the factor it multiplies (the work per row-times-column unit).
        block_rows: the candidate block sizes, in rows (default ``_BLOCK_ROWS``).

    Attributes:
        blocks: ``[(r0, r1, k0, k1), ...]``: rows ``[r0, r1)`` are zero outside
            columns ``[k0, k1)``; all-zero blocks are left out. Where blocks would
            not save enough (:attr:`banded` False), one block: the whole matrix.
        macs: multiply-adds of the product (``n sum (r1 - r0) (k1 - k0)``).
        cost: ``macs`` plus the per-block overhead, in multiply-adds.
        banded: whether the plan skips zeros (False: one dense product).
    """

    def __init__(self, first: torch.Tensor, last: torch.Tensor, k: int, n: int, block_rows=_BLOCK_ROWS):
        m, k, n = int(first.numel()), int(k), int(n)
        self.shape = (m, k)
        best = None
        for rows in block_rows:
            nb = -(-m // rows)
            pad = nb * rows - m
            f = torch.cat([first, first.new_full((pad,), k)]).reshape(nb, rows).amin(1)
            l_ = torch.cat([last, last.new_zeros(pad)]).reshape(nb, rows).amax(1)
            live = l_ > f
            sizes = torch.full((nb,), rows)
            sizes[-1] = rows - pad
            macs = n * int((sizes * (l_ - f).clamp_min(0))[live].sum())
            cost = macs + _BLOCK_OVERHEAD * int(live.sum())
            if best is None or cost < best[0]:
                best = (cost, rows, f, l_, live, macs)
        cost, rows, f, l_, live, macs = best
        self.banded = cost <= _MAX_FRACTION * m * k * n
        if self.banded:
            idx = torch.nonzero(live).flatten().tolist()
            f, l_ = f.tolist(), l_.tolist()
            self.blocks = [(i * rows, min(m, (i + 1) * rows), f[i], l_[i]) for i in idx]
            self.macs, self.cost = macs, cost
        else:
            self.blocks = [(0, m, 0, k)]
            self.macs = self.cost = m * k * n
        self.covers_all_rows = sum(r1 - r0 for r0, r1, _, _ in self.blocks) == m

    @classmethod
    def of(cls, a: torch.Tensor, n: int) -> "BandPlan":
        """The plan of matrix ``a`` multiplying a factor of ``n`` columns."""
        return cls(*row_spans(a), a.shape[1], n)


class _BandedMM(torch.autograd.Function):
    @staticmethod
    def forward(ctx, b, a, plan):
        out = (b.new_empty if plan.covers_all_rows else b.new_zeros)(a.shape[0], b.shape[1])
        for r0, r1, k0, k1 in plan.blocks:
            torch.mm(a[r0:r1, k0:k1], b[k0:k1], out=out[r0:r1])
        ctx.save_for_backward(a)
        ctx.plan, ctx.b_shape = plan, b.shape
        return out

    @staticmethod
    def backward(ctx, grad):
        (a,) = ctx.saved_tensors
        gb = None
        if ctx.needs_input_grad[0]:
            gb = grad.new_zeros(ctx.b_shape)
            grad = grad.contiguous()
            for r0, r1, k0, k1 in ctx.plan.blocks:
                gb[k0:k1].addmm_(a[r0:r1, k0:k1].T, grad[r0:r1])
        return gb, None, None


class _ColumnBandedMM(torch.autograd.Function):
    @staticmethod
    def forward(ctx, w, x, plan):
        out = x.new_zeros(x.shape[0], w.shape[0])
        for c0, c1, s0, s1 in plan.blocks:
            out[s0:s1].addmm_(x[s0:s1, c0:c1], w[:, c0:c1].T)
        ctx.save_for_backward(x)
        ctx.plan, ctx.w_shape = plan, w.shape
        return out

    @staticmethod
    def backward(ctx, grad):
        (x,) = ctx.saved_tensors
        gw = None
        if ctx.needs_input_grad[0]:
            # The blocks' column ranges do not overlap: each is written once (beta=0 ignores what the
            # uninitialised memory holds) and only the columns no block covers are zeroed.
            gw = grad.new_empty(ctx.w_shape)
            grad = grad.contiguous()
            done = 0
            for c0, c1, s0, s1 in ctx.plan.blocks:
                gw[:, done:c0].zero_()
                gw[:, c0:c1].addmm_(grad[s0:s1].T, x[s0:s1, c0:c1], beta=0)
                done = c1
            gw[:, done:].zero_()
        return gw, None, None


def banded_mm(a: torch.Tensor, b: torch.Tensor, plan: BandPlan | None = None) -> torch.Tensor:
    """``a @ b`` for a constant banded ``(m, k)`` matrix ``a`` and a ``(k, n)`` matrix ``b``.

    Differentiable with respect to ``b`` only (``a`` must not require a
    gradient). ``plan`` is ``BandPlan.of(a, n)``, computed here when not given.
    Rows of ``a`` that are all zero give zero rows.
    """
    if a.requires_grad:
        raise ValueError("banded_mm: the banded factor is a constant; it must not require a gradient")
    if a.dim() != 2 or b.dim() != 2 or a.shape[1] != b.shape[0]:
        raise ValueError(f"banded_mm: shapes {tuple(a.shape)} and {tuple(b.shape)} do not multiply")
    plan = BandPlan.of(a, b.shape[1]) if plan is None else plan
    if plan.shape != tuple(a.shape):
        raise ValueError(f"banded_mm: the plan is for a {plan.shape} matrix, not {tuple(a.shape)}")
    return _BandedMM.apply(b.contiguous(), a, plan)


def column_banded_mm(x: torch.Tensor, w: torch.Tensor, plan: BandPlan | None = None) -> torch.Tensor:
    """``x @ w.T`` for a constant ``(m, k)`` matrix ``x`` whose columns are banded, and an ``(n, k)`` ``w``.

    Each column of ``x`` is nonzero in a run of rows only (a canvas pixel is lit by a run of the scenes
    sorted by where they start): ``plan`` is the :class:`BandPlan` of ``x.T``, whose blocks of columns
    ``[c0, c1)`` each multiply their rows ``[s0, s1)`` only, ``x[s0:s1, c0:c1] @ w[:, c0:c1].T``. Each
    block's product reads its part of ``w`` once for all the rows it serves, and writes its part of the
    gradient once (a plan over the rows of ``x`` re-reads and re-writes the same columns of ``w`` and of
    its gradient for every block of a few rows). Differentiable with respect to ``w`` only; ``w`` is
    read in its own layout (no copy) and its gradient comes out in it.
    """
    if x.requires_grad:
        raise ValueError("column_banded_mm: the banded factor is a constant; it must not require a gradient")
    if x.dim() != 2 or w.dim() != 2 or x.shape[1] != w.shape[1]:
        raise ValueError(f"column_banded_mm: shapes {tuple(x.shape)} and {tuple(w.shape)} (transposed) do not multiply")
    plan = BandPlan.of(x.T, w.shape[0]) if plan is None else plan
    if plan.shape != (x.shape[1], x.shape[0]):
        raise ValueError(f"column_banded_mm: the plan is for a {plan.shape} matrix, not the transpose of {tuple(x.shape)}")
    return _ColumnBandedMM.apply(w, x.contiguous(), plan)
