"""The operator of a batch's nonzero pixels (the scene operator's support regions, a private choice of
:mod:`optoenc.encoders.operator`): the same embeddings and gradients as the whole scene's operator, built where
it is cheaper, and only there."""

from __future__ import annotations

import dataclasses
import warnings

import pytest
import torch

from optoenc.encoders.slm import FixedSLM, LearnedSLM


def _support_regions(enc, on: bool) -> None:
    enc._operators.paths = dataclasses.replace(enc._operators.paths, support_regions=on)


def _region(enc, x, height):
    return enc._operators.support_region(enc, x, height)


def _encoder(cls, dtype="float32"):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the small grid's sampling warning
        return cls(None, fidelity={"grid": (48, 64), "dtype": dtype}, sensor={"embedding": (6, 8)})


def _canvases(batch=5, shape=(40, 52), box=(7, 21, 30, 47), seed=0):
    """Random scenes nonzero only inside ``box = (r0, r1, c0, c1)`` of a larger canvas."""
    g = torch.Generator().manual_seed(seed)
    x = torch.zeros(batch, 1, *shape, dtype=torch.float64)
    r0, r1, c0, c1 = box
    x[..., r0:r1, c0:c1] = torch.rand(batch, 1, r1 - r0, c1 - c0, generator=g, dtype=torch.float64)
    return x


def test_region_is_the_support_bounding_box_across_the_batch():
    enc = _encoder(LearnedSLM)
    x = _canvases()
    x[0, 0, 7, 30] = x[1, 0, 20, 46] = 0.5  # the box's corners, set in different examples
    assert _region(enc, x, 0.05) == (7, 21, 30, 47)
    assert _region(enc, torch.zeros_like(x), 0.05) == (0, 1, 0, 1)  # dark: one pixel suffices
    full = torch.ones(2, 1, 40, 52, dtype=torch.float64)
    assert _region(enc, full, 0.05) is None  # nothing to cut


@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_support_operator_gives_the_whole_operators_embeddings_and_gradients(dtype):
    """Zero pixels contribute nothing: cutting them away changes only the summation order.

    float64 optics: 1e-12 relative is rounding of sums of ~1e3 terms; float32: 1e-5 relative, a few hundred
    ulps of the largest embedding pixel (1e-4 for the gradient, summed over the 240 embedding pixels too).
    """
    x = _canvases().to(getattr(torch, dtype))
    results = []
    for cut in (True, False):
        enc = _encoder(LearnedSLM, dtype)
        _support_regions(enc, cut)
        emb = enc.measure(x, height=0.05)
        (emb * torch.linspace(0.5, 1.5, emb.numel(), dtype=emb.dtype).reshape(emb.shape)).sum().backward()
        results.append((emb.detach(), enc.logits.grad.clone()))
    tol = dict(rtol=1e-12, atol=1e-15) if dtype == "float64" else dict(rtol=1e-5, atol=1e-7 * float(results[1][0].abs().max()))
    torch.testing.assert_close(results[0][0], results[1][0], **tol)
    gtol = tol if dtype == "float64" else dict(rtol=1e-4, atol=1e-5 * float(results[1][1].abs().max()))
    torch.testing.assert_close(results[0][1], results[1][1], **gtol)
    assert results[1][0].abs().max() > 0  # the window's light reaches the sensor: not a comparison of zeros


def test_region_is_used_only_where_cheaper():
    """A learned PSF rebuilds the operator anyway: the small window wins. A fixed encoder's cached whole
    operator costs nothing to build, so a few scenes filling most of it keep it, and so does a small window
    seen by a few scenes (building its operator costs more than applying the cached one), but not by 200."""
    learned = _encoder(LearnedSLM)
    small = _canvases(batch=2)
    assert _region(learned, small, 0.05) == (7, 21, 30, 47)
    fixed = _encoder(FixedSLM)
    fixed.eval()
    wide = _canvases(batch=2, box=(1, 39, 1, 51))
    with torch.no_grad():
        fixed.measure(torch.ones(1, 1, 40, 52, dtype=torch.float64), height=0.05)  # caches the whole operator
        assert _region(fixed, wide, 0.05) is None
        assert _region(fixed, small, 0.05) is None
        assert _region(fixed, _canvases(batch=200), 0.05) == (7, 21, 30, 47)


@pytest.mark.parametrize("box", [(7, 21, 30, 47), (1, 40, 0, 51)], ids=["small window", "most of the scene"])
@pytest.mark.parametrize("cut", [True, False])
def test_apply_window_is_measure_of_the_whole_scene(cut, box):
    """A window's pixels in an otherwise dark scene: the same embeddings as measuring that scene (float64
    optics: 1e-12 relative, summation order only), along the window's own operator (a small window), the whole
    scene's laid out at once (a window over most of the scene is no cheaper region), or measure's own path."""
    enc = _encoder(LearnedSLM, "float64")
    _support_regions(enc, cut)
    x = _canvases(batch=200, box=box)
    r0, r1, c0, c1 = box
    assert (enc._operators.cheaper_region(enc, 200, (40, 52), 0.05, box) == box) == (box[0] == 7)  # both branches taken
    window = x[..., r0:r1, c0:c1]
    torch.testing.assert_close(enc.operator((40, 52), 0.05).apply_window(window, (r0, c0)), enc.measure(x, 0.05),
                               rtol=1e-12, atol=1e-15)


def test_apply_window_outside_the_scene_is_one_clear_error():
    from optoenc.errors import ConfigError

    enc = _encoder(LearnedSLM)
    with pytest.raises(ConfigError, match=r"^window = \(30, 40, 14, 17\): must lie within the 40 x 52 scene"):
        enc.operator((40, 52), 0.05).apply_window(torch.rand(2, 1, 14, 17), (30, 40))


@pytest.mark.parametrize("dtype", ["float64", "bfloat16"])
@pytest.mark.parametrize("box", [(7, 21, 30, 47), (1, 40, 0, 51)], ids=["small part", "most of the scene"])
@pytest.mark.parametrize("cut", [True, False])
def test_apply_pasted_is_apply_window_of_the_pasted_part_bit_for_bit(cut, box, dtype):
    """Each example's own window at its own offset inside a part: the same numbers, exactly, as pasting them on
    the part and measuring it as one window (the stored and redrawn transforms' path before apply_pasted), on
    the part's own operator (a small part), the whole scene's (most of the scene) or measure's own path."""
    from optoenc.encoders.imaging import paste

    enc = _encoder(LearnedSLM, dtype if dtype == "float64" else "float32")
    if dtype == "bfloat16":
        enc.operator_dtype = torch.bfloat16
    _support_regions(enc, cut)
    r0, r1, c0, c1 = box
    g = torch.Generator().manual_seed(3)
    h, w = 5, 6
    offsets = torch.stack([torch.randint(r0, r1 - h + 1, (200,), generator=g),
                           torch.randint(c0, c1 - w + 1, (200,), generator=g)], 1)
    offsets[0], offsets[1] = torch.tensor([r0, c0]), torch.tensor([r1 - h, c1 - w])  # the part is their bounding box
    windows = torch.rand(200, 1, h, w, generator=g, dtype=torch.float64 if dtype == "float64" else torch.float32)
    part = paste(windows, offsets - torch.tensor([r0, c0]), (r1 - r0, c1 - c0))
    assert (enc._operators.cheaper_region(enc, 200, (40, 52), 0.05, box) == box) == (box[0] == 7)  # both branches taken
    assert torch.equal(enc.operator((40, 52), 0.05).apply_pasted(windows, offsets, box),
                       enc.operator((40, 52), 0.05).apply_window(part, (r0, c0)))


def test_apply_pasted_outside_its_part_is_one_clear_error():
    from optoenc.errors import ConfigError

    enc = _encoder(LearnedSLM)
    with pytest.raises(ConfigError, match=r"^windows = \(\(3, 4\), \(8, 10\)\): must lie within the part \(5, 20, 0, 30\)"):
        enc.operator((40, 52), 0.05).apply_pasted(torch.rand(2, 1, 5, 6), torch.tensor([[3, 4], [3, 4]]), (5, 20, 0, 30))
