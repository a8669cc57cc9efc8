"""Each speed-up the scene operator chooses itself gives the plain path's numbers (embeddings and gradients).

The choices are private (:class:`optoenc.encoders._operator_cache._Paths`); here each is switched off alone and the
encoder's embeddings and the mask's gradient are compared, with the speed-up shown to be taken. The cases are
small, so the size gates that keep small products dense are lowered to 0 (they stand for large ones). float64
optics: the paths sum the same terms in another order, so 1e-12 relative bounds them (rounding of sums of a
few thousand terms is ~1e-14); a skipped nonzero entry would be ~1e-2.
"""

from __future__ import annotations

import dataclasses

import pytest
import torch

from optoenc import hardware
from optoenc.encoders import _banded, _operator_apply, _operator_build
from optoenc.encoders.slm import LearnedSLM

pytestmark = pytest.mark.filterwarnings("ignore")  # the small grid's sampling warning

TIGHT = dict(rtol=1e-12, atol=1e-15)


@pytest.fixture
def small_is_large(monkeypatch):
    monkeypatch.setattr(_banded, "_BLOCK_OVERHEAD", 0)
    monkeypatch.setattr(_banded, "_ROW_COPY", 0)
    monkeypatch.setattr(_operator_build, "_MIN_BANDED_MACS", 0)
    monkeypatch.setattr(_operator_apply, "_MIN_SPARSE_ROWS", 0)


def _scenes(batch=6, shape=(40, 52), seed=0):
    """Digits-like windows at different rows of a dark canvas (rows lit by runs of scenes), float64."""
    g = torch.Generator().manual_seed(seed)
    x = torch.zeros(batch, 1, *shape, dtype=torch.float64)
    for i in range(batch):
        r, c = 4 + 5 * i, 10 + 3 * i
        x[i, 0, r : r + 9, c : c + 9] = torch.rand(9, 9, generator=g, dtype=torch.float64)
    return x


#: The canvas spans most of the field of view, as an augmentation canvas does (Table 3's): there the banded
#: build sorts its rows and holds the operator canvas row by canvas row.
HEIGHT = 0.3


def _run(field: str | None, dtype="float64", operator_dtype="same"):
    enc = LearnedSLM(None, fidelity={"grid": (48, 64), "dtype": dtype, "operator_dtype": operator_dtype},
                     sensor={"embedding": (6, 8)})
    if field is not None:
        enc._operators.paths = dataclasses.replace(enc._operators.paths, **{field: False})
    x = _scenes().to(enc.optics_dtype)
    emb = enc.measure(x, HEIGHT)
    (emb * torch.linspace(0.5, 1.5, emb.numel(), dtype=emb.dtype).reshape(emb.shape)).sum().backward()
    return emb.detach(), enc.logits.grad.clone(), enc


def _same(a, b, tol=TIGHT):
    torch.testing.assert_close(a[0], b[0], **tol)
    torch.testing.assert_close(a[1], b[1], **tol)
    assert float(a[0].abs().max()) > 0 and float(a[1].abs().max()) > 0  # not a comparison of zeros


def test_support_regions_give_the_whole_operators_numbers():
    calls = []
    fast = _run(None)
    ref = _run("support_regions")
    _same(fast, ref)
    enc = fast[2]
    with torch.no_grad():
        calls.append(enc._operators.support_region(enc, _scenes(), HEIGHT))
    assert calls[0] is not None  # the region was taken


def test_banded_build_and_product_give_the_dense_numbers(small_is_large, monkeypatch):
    taken = []
    real = _banded.banded_mm
    monkeypatch.setattr(_banded, "banded_mm", lambda *a, **k: taken.append(1) or real(*a, **k))
    fast = _run(None)
    assert taken  # the banded build ran
    taken.clear()
    ref = _run("banded")
    assert not taken
    _same(fast, ref)


def test_sorted_band_rows_give_the_consecutive_rows_numbers(small_is_large, monkeypatch):
    sorted_plans = []
    real = _banded.cached_plan
    monkeypatch.setattr(_banded, "cached_plan", lambda *a, **k: sorted_plans.append(a[-1]) or real(*a, **k))
    fast = _run(None)
    assert sorted_plans and all(sorted_plans)
    sorted_plans.clear()
    ref = _run("sorted_rows")
    assert sorted_plans and not any(sorted_plans)
    _same(fast, ref)


def test_row_major_operator_gives_the_contiguous_operators_numbers(small_is_large, monkeypatch):
    layouts = []
    real = _operator_build._banded_operator
    monkeypatch.setattr(_operator_build, "_banded_operator", lambda *a: layouts.append(a[-1]) or real(*a))
    fast = _run(None)
    ref = _run("row_major")
    n = len(layouts) // 2
    assert n and all(layouts[:n]) and not any(layouts[n:])  # row-major where on, the contiguous copy where off
    _same(fast, ref)


def test_matrix_unit_build_gives_the_banded_builds_numbers(monkeypatch):
    """bfloat16 operators: both builds round u and the operator to bfloat16 and sum the same terms in another
    order; measured 0 difference on the embeddings here, bounded by one bfloat16 rounding (2**-8 relative)."""
    monkeypatch.setattr(hardware, "matrix_units", lambda: True)
    fast = _run(None, "float32", "bfloat16")
    ref = _run("matrix_units", "float32", "bfloat16")
    with torch.no_grad():
        assert _operator_apply._matrix_unit_layout(fast[2].operator((40, 52), HEIGHT).tensor())
        assert not _operator_apply._matrix_unit_layout(ref[2].operator((40, 52), HEIGHT).tensor())
    scale = float(ref[0].abs().max())
    torch.testing.assert_close(fast[0].double(), ref[0].double(), rtol=2**-8, atol=2**-8 * scale)
    gscale = float(ref[1].abs().max())
    torch.testing.assert_close(fast[1], ref[1], rtol=2**-7, atol=2**-7 * gscale)


def test_every_path_off_is_the_fine_grid_pipeline():
    """The plain operator path equals place -> FFT-convolve -> integrate on the grid (float64: 1e-10 relative,
    the FFT's rounding over a 48 x 64 grid)."""
    enc = LearnedSLM(None, fidelity={"grid": (48, 64), "dtype": "float64"}, sensor={"embedding": (6, 8)})
    enc._operators.paths = dataclasses.replace(enc._operators.paths, support_regions=False, banded=False,
                                               sorted_rows=False, row_major=False, matrix_units=False)
    x = _scenes()
    with torch.no_grad():
        a, b = enc.measure(x, HEIGHT, method="operator"), enc.measure(x, HEIGHT, method="direct")
    torch.testing.assert_close(a, b, rtol=1e-10, atol=1e-10 * float(b.abs().max()))
