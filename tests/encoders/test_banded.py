"""Products with a constant banded matrix (the scene operator's correlation tensors skip their zeros)."""

from __future__ import annotations

import pytest
import torch

from optoenc.encoders import _banded as banded
from optoenc.encoders import _operator_apply as apply
from optoenc.encoders import _operator_build as build
from optoenc.encoders import imaging as im

DT = torch.float64


@pytest.fixture
def small_is_large(monkeypatch):
    """The cases here are small; they stand for large ones: no per-block, row-copy or minimum-size overheads."""
    monkeypatch.setattr(banded, "_BLOCK_OVERHEAD", 0)
    monkeypatch.setattr(banded, "_ROW_COPY", 0)
    monkeypatch.setattr(build, "_MIN_BANDED_MACS", 0)


def band_matrix(m: int, k: int, width: int, slope: float, g: torch.Generator, zero_rows=()) -> torch.Tensor:
    """An (m, k) matrix whose row i is nonzero on ``width`` columns from ``round(i * slope)`` (clipped)."""
    a = torch.zeros(m, k, dtype=DT)
    for i in range(m):
        k0 = min(k - 1, int(round(i * slope)))
        a[i, k0 : k0 + width] = torch.rand(min(width, k - k0), generator=g, dtype=DT) + 0.1
    for i in zero_rows:
        a[i] = 0
    return a


def _poison_freed_memory(m: int, n: int) -> None:
    """Free an ``(m, n)`` block of NaNs: the product's uninitialised output reuses it, so a row left unwritten
    shows (fresh pages would read as zeros and hide it)."""
    t = torch.full((m, n), float("nan"), dtype=DT)
    del t


def test_plan_blocks_hold_every_nonzero_entry_and_skip_most_zeros(small_is_large):
    g = torch.Generator().manual_seed(0)
    a = band_matrix(300, 120, 5, 0.37, g, zero_rows=(7, 150, 151))
    plan = banded.BandPlan.of(a, 1)
    assert plan.banded
    covered = torch.zeros_like(a, dtype=torch.bool)
    for r0, r1, k0, k1 in plan.blocks:
        covered[r0:r1, k0:k1] = True
    assert bool(covered[a != 0].all())  # no nonzero entry outside a block: the product is exact
    assert plan.macs == int(covered.sum()) == plan.cost
    assert plan.macs < 0.2 * a.numel()  # a 5-wide band sloping 0.37 a row: blocks of a few rows


def test_dense_matrix_gets_one_dense_block(small_is_large):
    a = torch.rand(40, 30, dtype=DT) + 0.1
    plan = banded.BandPlan.of(a, 7)
    assert not plan.banded and plan.blocks == [(0, 40, 0, 30)] and plan.macs == 40 * 30 * 7


@pytest.mark.parametrize("zero_rows", [(), (0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 100)])
def test_banded_mm_is_the_dense_product_and_its_gradient(zero_rows, small_is_large):
    # Float64: the blocked product sums the same nonzero terms in another order, so it agrees to ~1e-16
    # relative; 1e-12 leaves room for any BLAS blocking and is far below a missed band entry (~0.1).
    g = torch.Generator().manual_seed(1)
    a = band_matrix(200, 90, 7, 0.42, g, zero_rows=zero_rows)
    b = torch.rand(90, 13, generator=g, dtype=DT, requires_grad=True)
    plan = banded.BandPlan.of(a, 13)
    assert plan.banded and (not zero_rows or not plan.covers_all_rows)  # the all-zero block is left out
    assert (plan.zero_rows is None) == (not zero_rows)
    _poison_freed_memory(200, 13)
    out = banded.banded_mm(a, b, plan)
    torch.testing.assert_close(out, a @ b, rtol=1e-12, atol=1e-12)
    assert bool((out[list(zero_rows)] == 0).all())
    assert torch.autograd.gradcheck(lambda x: banded.banded_mm(a, x, plan), (b,))


def sawtooth_matrix(groups: int, rows: int, k: int, width: int, g: torch.Generator) -> torch.Tensor:
    """Rows ``(i, j)`` (``groups`` x ``rows``) nonzero on ``width`` columns from ``k0 = 9 i + 40 - 2 j``:
    the row correlation tensor's shape, whose band climbs back at every embedding row ``i``."""
    a = torch.zeros(groups * rows, k, dtype=DT)
    for i in range(groups):
        for j in range(rows):
            k0 = min(k - 1, max(0, 9 * i + 40 - 2 * j))
            a[i * rows + j, k0 : k0 + width] = torch.rand(min(width, k - k0), generator=g, dtype=DT) + 0.1
    return a


@pytest.mark.slow
def test_sorted_plan_follows_a_band_that_restarts_and_is_the_dense_product(small_is_large):
    # A band that climbs back every 20 rows: blocks of consecutive rows straddle the jumps, blocks of rows
    # sorted by their span do not, so the sorted plan is taken, with fewer multiply-adds. Its product and
    # gradient equal the dense ones (float64, the same terms in another order: 1e-12), every nonzero entry
    # lies in some block, and all-zero rows (placed anywhere) come out exactly zero.
    g = torch.Generator().manual_seed(6)
    a = sawtooth_matrix(12, 20, 150, 6, g)
    a[[3, 77, 200]] = 0
    b = torch.rand(150, 9, generator=g, dtype=DT, requires_grad=True)
    plain, srt = banded.BandPlan.of(a, 9), banded.BandPlan.of(a, 9, sort_rows=True)
    assert plain.order is None and srt.order is not None
    # Blocks of 4 consecutive rows of a band sloping 2 a row span 12 columns for 6 nonzero (more across a
    # jump); sorted rows starting within a few columns of each other span ~8 (0.62 of the plain plan here).
    assert srt.macs < 0.7 * plain.macs
    covered = torch.zeros_like(a, dtype=torch.bool)
    for r0, r1, k0, k1 in srt.blocks:
        covered[srt.order[r0:r1], k0:k1] = True
    assert bool(covered[a != 0].all())
    held = {int(i) for r0, r1, _, _ in srt.blocks for i in srt.order[r0:r1]}
    alone = set() if srt.zero_rows is None else set(srt.zero_rows.tolist())
    assert alone == set(range(a.shape[0])) - held <= {3, 77, 200}  # rows no block writes are zeroed alone
    _poison_freed_memory(a.shape[0], 9)
    out = banded.banded_mm(a, b, srt)
    torch.testing.assert_close(out, a @ b, rtol=1e-12, atol=1e-12)
    assert bool((out[[3, 77, 200]] == 0).all())
    assert torch.autograd.gradcheck(lambda x: banded.banded_mm(a, x, srt), (b,))
    with pytest.raises(ValueError, match="consecutive"):
        banded.column_banded_mm(a.T.contiguous(), torch.rand(4, 240, dtype=DT), srt)


def test_sorted_rows_weighed_with_their_copies(monkeypatch):
    # With the real overheads, a band that slopes steadily keeps its consecutive rows (sorting them gives
    # the same blocks, and the copies would only add cost), multiplying a factor wide enough for blocks to
    # pay (as test_plan_weighs_the_per_block_overhead_against_the_work_it_saves); the sawtooth keeps them
    # too when a row's copy is priced above any band it could save.
    g = torch.Generator().manual_seed(7)
    steady = banded.BandPlan.of(band_matrix(300, 120, 5, 0.37, g), 100_000, sort_rows=True)
    assert steady.banded and steady.order is None
    saw = sawtooth_matrix(12, 20, 150, 6, g)
    monkeypatch.setattr(banded, "_BLOCK_OVERHEAD", 0)
    monkeypatch.setattr(banded, "_ROW_COPY", 0)
    assert banded.BandPlan.of(saw, 9, sort_rows=True).order is not None
    monkeypatch.setattr(banded, "_ROW_COPY", 150)  # a row's copy dearer than its whole width
    assert banded.BandPlan.of(saw, 9, sort_rows=True).order is None
    # A near tie is left consecutive (_SORT_MARGIN): a short row tensor (4 embedding rows of 6 scene rows)
    # whose sorted plan is modelled 5 % cheaper, copies free, takes its rows sorted only without the margin.
    monkeypatch.setattr(banded, "_ROW_COPY", 0)
    ry, _ = _canvas_correlations((48, 240), (6, 120), (4, 24), 20.0)
    first, last = banded.row_spans(ry.reshape(-1, 48))
    plain = banded.BandPlan(first, last, 48, 24 * 120)
    assert banded.BandPlan(first, last, 48, 24 * 120, sort_rows=True).order is None
    monkeypatch.setattr(banded, "_SORT_MARGIN", 1.0)
    near = banded.BandPlan(first, last, 48, 24 * 120, sort_rows=True)
    assert near.order is not None and 0.9 * plain.cost < near.cost < plain.cost


def test_cached_plan_is_reused_for_the_same_spans_only(monkeypatch):
    # The same spans and sizes give the same plan object (a learned encoder plans every step); another
    # width, sorting choice or span gives another plan; the oldest plans are dropped beyond _MAX_PLANS;
    # and a plan made under other overheads is not reused (its blocks could differ).
    monkeypatch.setattr(banded, "_PLANS", type(banded._PLANS)())
    monkeypatch.setattr(banded, "_MAX_PLANS", 3)
    g = torch.Generator().manual_seed(8)
    first, last = banded.row_spans(sawtooth_matrix(12, 20, 150, 6, g))
    p = banded.cached_plan(first, last, 150, 9)
    assert banded.cached_plan(first.clone(), last.clone(), 150, 9) is p
    assert banded.cached_plan(first.int(), last.int(), 150, 9) is p  # the same spans in another integer dtype
    assert banded.cached_plan(first, last, 150, 10) is not p
    assert banded.cached_plan(first, last, 150, 9, sort_rows=True) is not p
    moved = last.clone()
    moved[5] += 1
    assert banded.cached_plan(first, moved, 150, 9) is not p  # a fourth plan: p, the oldest, is dropped
    assert len(banded._PLANS) == 3
    assert banded.cached_plan(first, last, 150, 9) is not p
    q = banded.cached_plan(first, last, 150, 9)
    monkeypatch.setattr(banded, "_BLOCK_OVERHEAD", 0)
    assert banded.cached_plan(first, last, 150, 9) is not q


def test_column_banded_mm_is_the_dense_product_and_its_gradient(small_is_large):
    # x's columns are banded (x.T is a band matrix) with all-zero columns at both ends and in the middle:
    # x @ w.T and its gradient with respect to w equal the dense ones (float64, the same terms in another
    # order: 1e-12), the gradient is exactly zero on the columns no block covers (written, not left as
    # uninitialised memory), and gradcheck passes.
    g = torch.Generator().manual_seed(3)
    zero = [*range(0, 8), *range(56, 64), *range(112, 120)]  # whole blocks of the plan's smallest sizes
    x = band_matrix(120, 40, 6, 0.3, g, zero_rows=zero).T.contiguous()  # (40, 120)
    w = torch.rand(11, 120, generator=g, dtype=DT, requires_grad=True)
    plan = banded.BandPlan.of(x.T, 11)
    assert plan.banded and not plan.covers_all_rows
    out = banded.column_banded_mm(x, w, plan)
    torch.testing.assert_close(out, x @ w.T, rtol=1e-12, atol=1e-12)
    wgt = torch.randn(40, 11, generator=g, dtype=DT)
    (g1,) = torch.autograd.grad((out * wgt).sum(), w)
    torch.testing.assert_close(g1, wgt.T @ x, rtol=1e-12, atol=1e-12)
    assert bool((g1[:, zero] == 0).all())
    assert torch.autograd.gradcheck(lambda v: banded.column_banded_mm(x, v, plan), (w,))
    with pytest.raises(ValueError, match="constant"):
        banded.column_banded_mm(x.clone().requires_grad_(), w)
    with pytest.raises(ValueError, match="plan is for"):
        banded.column_banded_mm(x, w, banded.BandPlan.of(x, 11))


def test_banded_mm_refuses_a_learned_band_or_a_wrong_plan():
    a = torch.eye(5, dtype=DT)
    with pytest.raises(ValueError, match="constant"):
        banded.banded_mm(a.clone().requires_grad_(), torch.rand(5, 2, dtype=DT))
    with pytest.raises(ValueError, match="plan"):
        banded.banded_mm(a, torch.rand(5, 2, dtype=DT), banded.BandPlan.of(torch.eye(6, dtype=DT), 2))


def _canvas_correlations(grid, scene, emb, height):
    py, px = im.placement_matrices(scene, grid, height)
    ry = im.correlation_tensor(im.box_matrix(grid[0], emb[0]), py, grid[0])
    rx = im.correlation_tensor(im.box_matrix(grid[1], emb[1]), px, grid[1])
    return ry, rx


@pytest.mark.parametrize(
    "grid,scene,emb,height,sorts",
    [
        ((96, 128), (60, 70), (8, 10), 90.0, True),  # a canvas larger than the grid's embedding pixels (Table 3)
        ((48, 240), (6, 120), (4, 24), 20.0, False),  # few scene rows, many columns: 24 rows, nothing to sort
    ],
)
def test_banded_scene_operator_is_the_dense_one_and_the_fine_grid_pipeline(grid, scene, emb, height, sorts, monkeypatch,
                                                                         small_is_large):
    # Real correlation tensors of a scene much larger than an embedding pixel are banded; the banded build
    # must give the dense build's operator and gradient (float64: same terms, other order of sums; 1e-12)
    # and the fine-grid pipeline's embeddings (place -> FFT convolution -> integrate; rounding ~1e-14).
    import warnings

    warnings.simplefilter("ignore")  # the canvas may overfill the field of view: cropping is part of the map
    g = torch.Generator().manual_seed(4)
    ry, rx = _canvas_correlations(grid, scene, emb, height)
    psf = torch.rand(2, *grid, generator=g, dtype=DT, requires_grad=True)
    calls = []
    real = banded.banded_mm
    monkeypatch.setattr(banded, "banded_mm", lambda a, b, plan=None: calls.append((a.shape, plan.order is not None)) or real(a, b, plan))
    op = build.scene_operator(psf, ry, rx)
    assert len(calls) == 2, "the banded build was not taken"
    assert calls[0][0] == (rx.shape[0] * rx.shape[1], rx.shape[2])  # columns first (the cheap layout copy)
    # The row tensor's band restarts at every embedding row: on the canvas its rows are taken sorted.
    assert calls[1][1] == sorts
    consecutive = build.scene_operator(psf, ry, rx, sort_rows=False)
    assert not any(srt for _, srt in calls[2:])
    dense = build.scene_operator(psf, ry.detach().clone().requires_grad_(), rx)  # dense path
    assert len(calls) == 4  # a correlation tensor that requires a gradient takes the dense products
    torch.testing.assert_close(op, dense, rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(consecutive, dense, rtol=1e-12, atol=1e-12)
    x = torch.rand(3, 1, *scene, generator=g, dtype=DT)
    ref = im.integrate(im.fft_convolve(im.place(x, grid, height), psf), emb)
    torch.testing.assert_close(apply.apply_operator(op, x), ref, rtol=1e-11, atol=1e-11)
    w = torch.randn(3, 2, *emb, generator=g, dtype=DT)
    (g_band,) = torch.autograd.grad((apply.apply_operator(op, x) * w).sum(), psf)
    (g_ref,) = torch.autograd.grad((ref * w).sum(), psf)
    torch.testing.assert_close(g_band, g_ref, rtol=1e-10, atol=1e-12)


def test_sparse_scene_product_is_the_dense_apply_and_its_gradient(monkeypatch, small_is_large):
    # Digits at random positions on a canvas (zero elsewhere), one all-zero scene: the operator applied to
    # their nonzero rows only must equal the dense product and give the same gradient with respect to the
    # operator (float64; same terms in another order: 1e-12), with the scenes' order restored.
    g = torch.Generator().manual_seed(5)
    B, (C, a, b), (h, w) = 9, (1, 16, 10), (40, 30)
    x = torch.zeros(B, 1, h, w, dtype=DT)
    for i in range(B - 1):
        r, c = (int(v) for v in torch.randint(0, 32, (2,), generator=g))
        x[i, 0, r : r + 8, min(c, 22) : min(c, 22) + 8] = torch.rand(8, 8, generator=g, dtype=DT)
    op = torch.rand(C, a, b, h, w, generator=g, dtype=DT, requires_grad=True)
    calls = []
    real = banded.column_banded_mm
    monkeypatch.setattr(banded, "column_banded_mm", lambda *args, **kw: calls.append(1) or real(*args, **kw))
    out = apply.apply_operator(op, x)
    assert calls, "the sparse product was not taken"
    dense = apply.apply_operator(op, x, skip_zeros=False)
    assert len(calls) == 1
    torch.testing.assert_close(out, dense, rtol=1e-12, atol=1e-12)
    assert bool((out[B - 1] == 0).all())
    wgt = torch.randn_like(dense)
    (g1,) = torch.autograd.grad((out * wgt).sum(), op)
    (g2,) = torch.autograd.grad((dense * wgt).sum(), op)
    torch.testing.assert_close(g1, g2, rtol=1e-12, atol=1e-12)
    small = torch.rand(1, 16, 2, 40, 30, dtype=DT, requires_grad=True)  # gradcheck on a 160-row operator
    assert torch.autograd.gradcheck(lambda o: apply.apply_operator(o, x[:3]), (small,), fast_mode=True)
    xg = x.clone().requires_grad_()  # a scene that is learned (an attack's reconstruction): the dense product
    n = len(calls)
    apply.apply_operator(op, xg)
    assert len(calls) == n


def test_small_products_stay_dense(monkeypatch, small_is_large):
    # Below _MIN_BANDED_MACS the plans and copies cost more than the zeros skipped: the dense products, for
    # a case that is banded (the same case takes the banded build with the gate at 0, above).
    calls = []
    real = banded.banded_mm
    monkeypatch.setattr(banded, "banded_mm", lambda *args, **kw: calls.append(1) or real(*args, **kw))
    monkeypatch.setattr(build, "_MIN_BANDED_MACS", 10**9)
    ry, rx = _canvas_correlations((96, 128), (60, 70), (8, 10), 90.0)
    assert banded.BandPlan.of(rx.reshape(-1, 128), 96).banded
    op = build.scene_operator(torch.rand(1, 96, 128, dtype=DT), ry, rx)
    x = torch.zeros(4, 1, 60, 70, dtype=DT)
    x[:, :, :5] = 1
    apply.apply_operator(op, x)
    assert not calls


def test_plan_weighs_the_per_block_overhead_against_the_work_it_saves():
    # The same band: multiplying a narrow factor, a block's call overhead outweighs the zeros it skips (one
    # dense block); multiplying a wide one, the blocks win (banded._BLOCK_OVERHEAD: ~15 us a block).
    a = band_matrix(300, 120, 5, 0.37, torch.Generator().manual_seed(0))
    assert not banded.BandPlan.of(a, 10).banded
    wide = banded.BandPlan.of(a, 100_000)
    assert wide.banded and wide.cost == wide.macs + banded._BLOCK_OVERHEAD * len(wide.blocks)


@pytest.mark.filterwarnings("ignore")  # the small grid's sampling warning
def test_encoder_region_spans_are_those_of_the_region_tensors():
    # The encoder caches the row spans of its whole correlation tensors and cuts them for a support region;
    # the cut must be the spans of the region's own tensors (else the banded build would miss entries).
    from optoenc.config import encoder_from_run, compose

    run = compose(names={"encoder": "learned_slm", "decoder": "logistic"},
                  overrides=["sensor.embedding=[6,8]", "fidelity.grid=[48,64]"])
    enc = encoder_from_run(run)
    shape, hpx = (30, 40), enc.object_height_px(None) * 2.5
    ry, rx, spans = enc._operators.geometry_factors(enc, shape, hpx, "cpu")
    for region in (None, (3, 17, 5, 33), (0, 30, 39, 40)):
        (fy, ly), (fx, lx) = enc._operators._region_spans(spans, shape, region)
        r0, r1, c0, c1 = region or (0, 30, 0, 40)
        for (f, l_), t in (((fy, ly), ry[:, r0:r1]), ((fx, lx), rx[:, c0:c1])):
            ef, el = banded.row_spans(t.reshape(-1, t.shape[-1]))
            assert torch.equal(f, ef) and torch.equal(l_, el)


def test_row_runs_mm_is_the_dense_product_and_its_gradient():
    # Scenes sorted by their first lit row; row p multiplies only its run of scenes (whose others are zero
    # in row p). Float64, the same terms in another order: 1e-12 (a skipped nonzero row would be ~0.1).
    g = torch.Generator().manual_seed(8)
    B, h, r, w = 7, 12, 5, 9
    xs = torch.zeros(B, h, w, dtype=DT)
    runs = []
    for p in range(h):
        s0, s1 = min(p // 2, B), min(p // 2 + 3, B)
        runs.append((s0, s1) if p != 5 else (B, 0))  # row 5: lit by no scene
        if p != 5:
            xs[s0:s1, p] = torch.rand(s1 - s0, w, generator=g, dtype=DT)
    m = torch.rand(h, r, w, generator=g, dtype=DT, requires_grad=True)
    out = banded.row_runs_mm(m, xs, runs)
    dense = xs.reshape(B, h * w) @ m.permute(1, 0, 2).reshape(r, h * w).T
    torch.testing.assert_close(out, dense, rtol=1e-12, atol=1e-12)
    assert torch.autograd.gradcheck(lambda v: banded.row_runs_mm(v, xs, runs), (m,))
    _poison_freed_memory(h * r, w)  # the unlit row's gradient block is zeroed, not left as found
    (gm,) = torch.autograd.grad(out.sum(), m)
    assert bool((gm[5] == 0).all())
    with pytest.raises(ValueError, match="constant"):
        banded.row_runs_mm(m, xs.clone().requires_grad_(), runs)
    with pytest.raises(ValueError, match="do not multiply"):
        banded.row_runs_mm(m, xs, runs[:-1])


def test_bucketed_runs_cover_their_run_with_few_lengths_and_keep_the_product(monkeypatch):
    # bfloat16 runs are widened to multiples of 16 (oneDNN compiles a kernel per shape): every widened run
    # holds its run, stays inside the batch, has a length that is a multiple of 16 or the whole batch; unlit
    # rows stay empty. Widening adds only scenes that are zero in that row, so the product is the same:
    # forced on a float64 product, the same terms plus exact zeros (1e-12).
    B = 40
    runs = [(0, 1), (3, 20), (30, 40), (39, 40), (0, 40), (B, 0), (5, 5), (25, 38)]
    wide = banded._bucketed(runs, B, 16)
    for (s0, s1), (t0, t1) in zip(runs, wide):
        if s1 <= s0:
            assert t1 <= t0
            continue
        assert 0 <= t0 <= s0 and s1 <= t1 <= B
        assert (t1 - t0) % 16 == 0 or t1 - t0 == B
    assert banded._bucketed(runs, B, 1) == runs  # float32: exact runs
    g = torch.Generator().manual_seed(12)
    h, r, w = len(runs), 4, 6
    xs = torch.zeros(B, h, w, dtype=DT)
    for p, (s0, s1) in enumerate(runs):
        if s1 > s0:
            xs[s0:s1, p] = torch.rand(s1 - s0, w, generator=g, dtype=DT)
    m = torch.rand(h, r, w, generator=g, dtype=DT, requires_grad=True)
    exact = banded.row_runs_mm(m, xs, runs)
    (g_exact,) = torch.autograd.grad(exact.sum(), m)
    monkeypatch.setitem(banded._RUN_QUANTUM, DT, 16)
    widened = banded.row_runs_mm(m, xs, runs)
    (g_wide,) = torch.autograd.grad(widened.sum(), m)
    torch.testing.assert_close(widened, exact, rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(g_wide, g_exact, rtol=1e-12, atol=1e-12)
    assert banded._RUN_QUANTUM[torch.bfloat16] > 1  # the dtype whose products compile kernels per shape


@pytest.mark.slow
def test_regrouped_plan_is_the_same_product_in_the_other_row_order(small_is_large):
    # Rows (g, i) of a sawtooth band, planned sorted, then taken in the order (i, g): the same blocks must
    # give the product of the regrouped matrix (float64: 1e-12), zero rows included, for a consecutive plan too.
    g = torch.Generator().manual_seed(9)
    a = sawtooth_matrix(12, 20, 150, 6, g)
    a[[3, 77, 200]] = 0
    b = torch.rand(150, 9, generator=g, dtype=DT, requires_grad=True)
    swapped = a.reshape(12, 20, 150).transpose(0, 1).reshape(240, 150)
    for plan in (banded.BandPlan.of(a, 9, sort_rows=True), banded.BandPlan.of(a, 9)):
        moved = plan.regrouped(12)
        assert moved is plan.regrouped(12) and moved.blocks == plan.blocks
        _poison_freed_memory(240, 9)
        out = banded.banded_mm(swapped, b, moved)
        torch.testing.assert_close(out, swapped @ b, rtol=1e-12, atol=1e-12)
        assert torch.autograd.gradcheck(lambda v: banded.banded_mm(swapped, v, moved), (b,))
    with pytest.raises(ValueError, match="groups"):
        plan.regrouped(7)


@pytest.mark.parametrize("scenes", ["shifted digits", "dense, wide", "dense, narrow"])
def test_canvas_row_operator_applies_as_the_contiguous_one(scenes, monkeypatch, small_is_large):
    # The sorted build returns its operator as a view held canvas row by canvas row; applied to scenes it
    # must give the contiguous operator's embeddings and the same gradient with respect to the PSF (float64,
    # same terms, other order: 1e-12), whichever product it takes: the runs of lit rows (digits at random
    # rows), every scene row by row (a wide canvas: the width threshold lowered to this case's 70 columns),
    # or the copy into one matrix (narrow).
    import warnings

    warnings.simplefilter("ignore")  # the canvas overfills the field of view: cropping is part of the map
    monkeypatch.setattr(apply, "_ROW_MAJOR_DENSE_WIDTH", 64 if scenes == "dense, wide" else 10**9)
    g = torch.Generator().manual_seed(10)
    ry, rx = _canvas_correlations((96, 128), (60, 70), (8, 10), 90.0)
    ry = ry.transpose(0, 1).contiguous().transpose(0, 1)  # held (h, a, Hp), as the encoders cache it
    psf = torch.rand(2, 96, 128, generator=g, dtype=DT, requires_grad=True)
    x = torch.zeros(6, 1, 60, 70, dtype=DT)
    if scenes == "shifted digits":
        for i in range(5):  # the sixth stays dark
            r, c = (int(v) for v in torch.randint(0, 50, (2,), generator=g))
            x[i, 0, r : r + 8, c : c + 8] = torch.rand(8, 8, generator=g, dtype=DT)
    else:
        x.uniform_(generator=g)
    calls = []
    real = banded.row_runs_mm
    monkeypatch.setattr(banded, "row_runs_mm", lambda m, xs, runs: calls.append(len(xs)) or real(m, xs, runs))
    op = build.scene_operator(psf, ry, rx)
    ref = build.scene_operator(psf, ry, rx, row_major=False)
    assert apply.operator_rows(op) is not None and apply.operator_rows(ref) is None and ref.is_contiguous()
    torch.testing.assert_close(op, ref, rtol=0, atol=0)  # the same products, only held differently
    wgt = torch.randn(6, 2, 8, 10, generator=g, dtype=DT)
    out, out_ref = apply.apply_operator(op, x), apply.apply_operator(ref, x)
    assert bool(calls) == (scenes != "dense, narrow")
    torch.testing.assert_close(out, out_ref, rtol=1e-12, atol=1e-12)
    (g1,) = torch.autograd.grad((apply.apply_operator(op, x) * wgt).sum(), psf)
    (g2,) = torch.autograd.grad((out_ref * wgt).sum(), psf)
    torch.testing.assert_close(g1, g2, rtol=1e-12, atol=1e-12)
    if scenes == "shifted digits":
        assert bool((out[5] == 0).all())
