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

Where the band does not slope steadily down the rows (the row correlation tensor of the scene
operator, whose rows ``(a, h)`` restart their band at every embedding row ``a``), a plan may take the
rows in the order of their spans (``sort_rows``): each block is then a set of rows, not necessarily
consecutive, whose spans start together. Its product runs into a small buffer whose rows are copied to
their places; the blocks are taller for the same band, and a product of a few tall rows runs much
closer to the GEMM kernels' rate than one of four (Table 3's row factor on one AVX2 core, forward: 21.4 ms
in 524 blocks of 4 rows; 15.0 ms in 127 blocks of 16 sorted rows and 13.4 ms in 64 of 32, the plan's
choice, copies included). Plans weigh the copies and take sorted rows only where clearly cheaper
(``_ROW_COPY``, ``_SORT_MARGIN``); :func:`cached_plan` keeps them for the same spans.

:func:`column_banded_mm` is the other side: ``X @ W.T`` for a constant ``X``
whose *columns* are banded (a batch of digits on a canvas, sorted by where
they start: each canvas pixel is lit by a run of consecutive scenes), with its
gradient with respect to ``W`` (the scene operator). Its plan is the
:class:`BandPlan` of ``X.T``.

:func:`row_runs_mm` is the same product for an operator held canvas row by canvas row (``(h, r, w)``,
each row's ``(r, w)`` block contiguous: the layout the build produces with its rows sorted, see
:func:`optoenc.encoders.operator.scene_operator`): one product per canvas row, with the run of scenes
that light it.
"""

from __future__ import annotations

import copy
import threading
from collections import OrderedDict

import numpy as np
import torch

__all__ = ["BandPlan", "banded_mm", "cached_plan", "column_banded_mm", "row_runs_mm", "row_spans"]

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
# A plan over sorted rows copies every output row once from its block's buffer (and gathers every
# gradient row once backward): about 0.4 ns an entry on one AVX2 core (Table 3's row factor: 5 ms for its
# 12 M entries), against the ~0.07 ns a modelled multiply-add costs in the consecutive plan's short
# products there (22 ms for 218 M multiply-adds and 524 blocks), so ~6; 4, as the taller blocks' products
# also run faster a multiply-add than the model counts. Each of its blocks also makes a second call (the
# copy), priced as one more block.
_ROW_COPY = 4
# Sorted rows are taken where the model puts them at most at this fraction of the consecutive plan's cost:
# near a tie the model is not that exact (Table 1's 12x16 row product, 336 rows by 448 columns: modelled
# 2 % cheaper sorted, measured 3 % dearer in the training step).
_SORT_MARGIN = 0.9


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
        sort_rows: also weigh blocks of the rows sorted by their spans (for :func:`banded_mm` only;
            :func:`column_banded_mm` needs consecutive columns).

    Attributes:
        blocks: ``[(r0, r1, k0, k1), ...]``: rows ``[r0, r1)`` are zero outside
            columns ``[k0, k1)``; all-zero blocks are left out. Where blocks would
            not save enough (:attr:`banded` False), one block: the whole matrix.
        macs: multiply-adds of the product (``n sum (r1 - r0) (k1 - k0)``).
        cost: ``macs`` plus the per-block overhead (for sorted rows also their copies), in multiply-adds.
        banded: whether the plan skips zeros (False: one dense product).
        order: ``(m,)`` the rows in the order the blocks count them (block ``(r0, r1, k0, k1)`` holds
            rows ``order[r0:r1]``), or None: consecutive rows.
        tallest: the tallest block's rows (the buffer a sorted plan's products run into).
        zero_rows: ``(n,)`` int64, the rows no block holds (all zero in the product), or None: none.
    """

    def __init__(self, first: torch.Tensor, last: torch.Tensor, k: int, n: int, block_rows=_BLOCK_ROWS,
                 sort_rows: bool = False):
        m, k, n = int(first.numel()), int(k), int(n)
        self.shape = (m, k)
        # numpy: a learned encoder plans its build every step, and these are a few thousand integers
        # (a torch call's overhead per candidate cost ~0.3 ms a plan, 5 % of a small cell's step).
        first, last = np.asarray(first, dtype=np.int64), np.asarray(last, dtype=np.int64)
        orders = [None]
        if sort_rows:  # by where each row's span starts, then ends (all-zero rows, [k, 0), come last)
            orders.append(np.argsort(first * (k + 1) + last, kind="stable"))
        best, plain = None, None
        for order in orders:
            if order is not None:
                plain = best
            fo, lo = (first, last) if order is None else (first[order], last[order])
            for rows in block_rows:
                nb = -(-m // rows)
                pad = nb * rows - m
                f = np.concatenate([fo, np.full(pad, k)]).reshape(nb, rows).min(1)
                l_ = np.concatenate([lo, np.zeros(pad, dtype=np.int64)]).reshape(nb, rows).max(1)
                live = l_ > f
                sizes = np.full(nb, rows)
                sizes[-1] = rows - pad
                macs = n * int((sizes * (l_ - f))[live].sum())
                cost = macs + _BLOCK_OVERHEAD * int(live.sum())
                if order is not None:  # the rows' copies, and a second call (the copy) for every block
                    cost += _ROW_COPY * n * int(sizes[live].sum()) + _BLOCK_OVERHEAD * int(live.sum())
                    if cost > _SORT_MARGIN * plain[0]:
                        continue
                if best is None or cost < best[0]:
                    best = (cost, rows, f, l_, live, macs, order)
        cost, rows, f, l_, live, macs, order = best
        self.banded = cost <= _MAX_FRACTION * m * k * n
        self.order = torch.from_numpy(order) if self.banded and order is not None else None
        if self.banded:
            idx = np.flatnonzero(live).tolist()
            f, l_ = f.tolist(), l_.tolist()
            self.blocks = [(i * rows, min(m, (i + 1) * rows), f[i], l_[i]) for i in idx]
            self.macs, self.cost = macs, cost
        else:
            self.blocks = [(0, m, 0, k)]
            self.macs = self.cost = m * k * n
        # The rows no block holds (all-zero rows), zeroed alone: zeroing the whole product first cost 5 ms a
        # step on Table 3's 49-MB operator, whose all-zero rows (embedding rows out of a canvas row's reach)
        # are a few percent.
        self.zero_rows = None
        if sum(r1 - r0 for r0, r1, _, _ in self.blocks) < m:
            held = np.zeros(m, dtype=bool)
            for r0, r1, _, _ in self.blocks:
                held[r0:r1] = True
            rows = np.flatnonzero(~held) if order is None or not self.banded else order[~held]
            self.zero_rows = torch.from_numpy(np.ascontiguousarray(rows, dtype=np.int64))
        self.tallest = max(r1 - r0 for r0, r1, _, _ in self.blocks)
        self._regrouped: dict[int, BandPlan] = {}

    @property
    def covers_all_rows(self) -> bool:
        """Whether every row lies in some block (no row is zeroed alone)."""
        return self.zero_rows is None

    def regrouped(self, groups: int) -> "BandPlan":
        """This plan for the matrix with its rows ``(g, i)`` (``groups`` x ``m / groups``) in the order ``(i, g)``.

        The same blocks of the same rows, each row found at its new place: the blocks gather their rows
        and place their products there (as a sorted plan does). Kept on this plan for the next call.
        """
        m = self.shape[0]
        if groups < 1 or m % groups:
            raise ValueError(f"regrouped: {m} rows are not {groups} groups")
        cache = self._regrouped
        if groups not in cache:
            size = m // groups
            old = torch.arange(m)
            place = (old % size) * groups + old // size  # new index of each old row
            plan = copy.copy(self)
            plan._regrouped = {}
            plan.order = place if self.order is None else place[self.order]
            plan.zero_rows = None if self.zero_rows is None else place[self.zero_rows]
            if not self.banded:  # one dense block over rows in their new order: a plain product again
                plan.order = None
            cache[groups] = plan
        return cache[groups]

    @classmethod
    def of(cls, a: torch.Tensor, n: int, sort_rows: bool = False) -> "BandPlan":
        """The plan of matrix ``a`` multiplying a factor of ``n`` columns."""
        return cls(*row_spans(a), a.shape[1], n, sort_rows=sort_rows)


_PLANS: OrderedDict = OrderedDict()
_PLANS_LOCK = threading.Lock()
# Plans kept: a learned encoder plans its build every step, from the spans of the whole scene (the same
# every step) or of the batch's support region (a few distinct regions over an epoch, mostly the same).
_MAX_PLANS = 32


def cached_plan(first: torch.Tensor, last: torch.Tensor, k: int, n: int, sort_rows: bool = False) -> BandPlan:
    """``BandPlan(first, last, k, n, sort_rows=sort_rows)``, the same object again for the same arguments.

    Planning costs 0.1-0.7 ms (a few thousand spans, ten candidate blockings), 1-5 % of a learned cell's
    step; the last ``_MAX_PLANS`` plans are kept (least recently used dropped). Plans are read-only.
    """
    # int64 bytes: spans of another integer dtype are the same key (and bytes of unequal spans never match)
    key = (np.asarray(first, dtype=np.int64).tobytes(), np.asarray(last, dtype=np.int64).tobytes(), int(k), int(n), bool(sort_rows),
           _BLOCK_ROWS, _BLOCK_OVERHEAD, _MAX_FRACTION, _ROW_COPY, _SORT_MARGIN)
    with _PLANS_LOCK:
        plan = _PLANS.get(key)
        if plan is not None:
            _PLANS.move_to_end(key)
            return plan
    plan = BandPlan(first, last, k, n, sort_rows=sort_rows)
    with _PLANS_LOCK:
        _PLANS[key] = plan
        while len(_PLANS) > _MAX_PLANS:
            _PLANS.popitem(last=False)
    return plan


class _BandedMM(torch.autograd.Function):
    @staticmethod
    def forward(ctx, b, a, plan):
        out = b.new_empty(a.shape[0], b.shape[1])
        if plan.zero_rows is not None:
            out.index_fill_(0, plan.zero_rows.to(out.device), 0)
        if plan.order is None:
            for r0, r1, k0, k1 in plan.blocks:
                torch.mm(a[r0:r1, k0:k1], b[k0:k1], out=out[r0:r1])
        else:
            order = plan.order.to(a.device)
            a = a.index_select(0, order)  # the rows in the plan's order
            buf = b.new_empty(plan.tallest, b.shape[1])
            for r0, r1, k0, k1 in plan.blocks:
                rows = buf[: r1 - r0]
                torch.mm(a[r0:r1, k0:k1], b[k0:k1], out=rows)
                out.index_copy_(0, order[r0:r1], rows)
        ctx.save_for_backward(a)
        ctx.plan, ctx.b_shape = plan, b.shape
        return out

    @staticmethod
    def backward(ctx, grad):
        (a,) = ctx.saved_tensors  # in the plan's row order
        gb = None
        if ctx.needs_input_grad[0]:
            gb = grad.new_zeros(ctx.b_shape)
            grad = grad.contiguous()
            plan = ctx.plan
            if plan.order is None:
                for r0, r1, k0, k1 in plan.blocks:
                    gb[k0:k1].addmm_(a[r0:r1, k0:k1].T, grad[r0:r1])
            else:
                order = plan.order.to(grad.device)
                buf = grad.new_empty(plan.tallest, grad.shape[1])
                for r0, r1, k0, k1 in plan.blocks:
                    rows = torch.index_select(grad, 0, order[r0:r1], out=buf[: r1 - r0])
                    gb[k0:k1].addmm_(a[r0:r1, k0:k1].T, rows)
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
    if plan.order is not None:
        raise ValueError("column_banded_mm: the plan must take consecutive columns (made without sort_rows)")
    if plan.shape != (x.shape[1], x.shape[0]):
        raise ValueError(f"column_banded_mm: the plan is for a {plan.shape} matrix, not the transpose of {tuple(x.shape)}")
    return _ColumnBandedMM.apply(w, x.contiguous(), plan)


class _RowRunsMM(torch.autograd.Function):
    @staticmethod
    def forward(ctx, m, xs, runs):
        out = xs.new_zeros(xs.shape[0], m.shape[1])
        for p, (s0, s1) in enumerate(runs):
            if s1 > s0:
                out[s0:s1].addmm_(xs[s0:s1, p], m[p].T)
        ctx.save_for_backward(xs)
        ctx.runs, ctx.m_shape = runs, m.shape
        return out

    @staticmethod
    def backward(ctx, grad):
        (xs,) = ctx.saved_tensors
        gm = None
        if ctx.needs_input_grad[0]:
            # Each canvas row's block of the gradient is written once (no zeroing first), unlit rows zeroed.
            grad = grad.contiguous()
            gm = grad.new_empty(ctx.m_shape)
            for p, (s0, s1) in enumerate(ctx.runs):
                if s1 > s0:
                    torch.mm(grad[s0:s1].T, xs[s0:s1, p], out=gm[p])
                else:
                    gm[p].zero_()
        return gm, None, None


def row_runs_mm(m: torch.Tensor, xs: torch.Tensor, runs) -> torch.Tensor:
    """``sum_p xs[:, p] @ m[p].T``: ``(B, h, w)`` constant scenes through an ``(h, r, w)`` operator -> ``(B, r)``.

    ``m[p]`` is the operator's part for canvas row ``p``; ``runs[p] = (s0, s1)``: only scenes ``s0:s1`` may
    be nonzero in row ``p`` (the others' row ``p`` is skipped, so it must be zero; ``(0, B)`` for all).
    One product per canvas row, each reading its contiguous ``(r, w)`` block once for the run, and writing
    its block of the gradient once. Differentiable with respect to ``m`` only.
    """
    if xs.requires_grad:
        raise ValueError("row_runs_mm: the scenes are a constant here; they must not require a gradient")
    if m.dim() != 3 or xs.dim() != 3 or xs.shape[1:] != (m.shape[0], m.shape[2]) or len(runs) != m.shape[0]:
        raise ValueError(f"row_runs_mm: shapes {tuple(m.shape)} and {tuple(xs.shape)} with {len(runs)} runs do not multiply")
    return _RowRunsMM.apply(m.contiguous(), xs, _bucketed(runs, xs.shape[0], _RUN_QUANTUM.get(m.dtype, 1)))


#: Run lengths rounded up to a multiple of this, per dtype: bfloat16 products go through oneDNN, which
#: compiles a kernel for every new shape (and keeps 1024); a stored rescaled dataset's runs of every length
#: from 1 to B, times its window widths, thrash that cache (24x32 rescale drawn once: 94 ms a step against
#: 36 ms in float32, on an AMX CPU). float32 goes through MKL's BLAS, which compiles nothing: exact runs.
_RUN_QUANTUM = {torch.bfloat16: 16, torch.float16: 16}


def _bucketed(runs, batch: int, quantum: int) -> list[tuple[int, int]]:
    """``runs`` widened to lengths that are multiples of ``quantum`` (or ``batch``), within ``[0, batch]``.

    Widening only adds scenes whose row is zero in that run's canvas row (allowed: a scene outside a run
    must be zero there, a scene inside may be), so the product is unchanged.
    """
    out = []
    for s0, s1 in runs:
        s0, s1 = int(s0), int(s1)
        if quantum > 1 and s1 > s0:
            n = min(batch, -(-(s1 - s0) // quantum) * quantum)
            s1 = min(batch, s0 + n)
            s0 = s1 - n
        out.append((s0, s1))
    return out
