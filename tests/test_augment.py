"""Object-plane augmentations: canvas placement, shapes, reproducibility and physical invariants."""

from __future__ import annotations

import math

import pytest
import torch

from optoenc.augment import (
    BUILTIN, Compose, ObjectState, Perspective, Rescale, Rotate, Shift, canvas_geometry, to_canvas,
)
from optoenc.errors import ConfigError

# The paper's lensless setting, small: digit 12 cm (28 px), FOV 0.4712 x 0.6287 m.
GEOM = canvas_geometry(0.12, (28, 28), 0.4712, 0.6287, min_pitch=1.227e-3)


def _digits(b=6, seed=0):
    """Digit-like scenes: random strokes on a zero background, a 2-px empty border (like MNIST)."""
    g = torch.Generator().manual_seed(seed)
    x = torch.zeros(b, 1, 28, 28)
    x[..., 4:24, 6:22] = (torch.rand(b, 1, 20, 16, generator=g) > 0.6).float() * torch.rand(b, 1, 20, 16, generator=g)
    return x


def _extent(img, dim):
    """Number of rows (dim=-2) or columns (dim=-1) holding any intensity, per example."""
    other = -1 if dim == -2 else -2
    return (img.sum(dim=(1, other)) > 1e-6).sum(-1).float()


def test_canvas_geometry():
    assert GEOM.pitch == pytest.approx(0.12 / 28)
    # floor: the canvas never reaches past the field of view (nothing gets cropped by the sensor)
    assert GEOM.shape == (math.floor(0.4712 / GEOM.pitch), math.floor(0.6287 / GEOM.pitch)) == (109, 146)
    assert GEOM.height <= 0.4712 and 0.4712 - GEOM.height < GEOM.pitch
    fine = canvas_geometry(0.12, (28, 28), 3.77, 5.03, min_pitch=9.8e-3)  # coded aperture: grid-limited
    assert fine.pitch == 9.8e-3 and fine.shape == (384, 513)
    with pytest.raises(ConfigError, match="fov_height"):
        canvas_geometry(0.12, (28, 28), 0.0, 1.0)


def test_to_canvas_embeds_exactly_at_object_pitch():
    x = _digits()
    c = to_canvas(x, GEOM)
    assert c.shape == (6, 1, 109, 146)
    top, left, rows, cols = GEOM.object_box()
    assert (rows, cols) == pytest.approx((28, 28)) and top == int(top) and left == int(left)
    inner = c[..., int(top) : int(top) + 28, int(left) : int(left) + 28]
    assert torch.equal(inner, x)
    rest = c.clone()
    rest[..., int(top) : int(top) + 28, int(left) : int(left) + 28] = 0
    assert not rest.any()
    # Centred to within half a pixel.
    assert abs(top + 14 - 54.5) <= 0.5 and abs(left + 14 - 73) <= 0.5


def test_to_canvas_area_resampling_preserves_intensity_integral():
    coarse = canvas_geometry(0.12, (28, 28), 0.4712, 0.6287, min_pitch=0.12 / 28 * 2.5)
    x = _digits()
    c = to_canvas(x, coarse)
    # Each canvas pixel averages the scene over its area: sum * pitch^2 is the physical integral.
    ratio = c.sum((1, 2, 3)) * coarse.pitch**2 / (x.sum((1, 2, 3)) * (0.12 / 28) ** 2)
    assert torch.allclose(ratio, torch.ones(6), atol=1e-5)
    assert c.min() >= 0


@pytest.mark.parametrize("cls", BUILTIN)
def test_shapes_finite_reproducible_and_redrawn(cls):
    c = to_canvas(_digits(), GEOM)
    aug = cls()
    torch.manual_seed(123)
    a = aug(c, GEOM, 0.12)
    torch.manual_seed(123)
    b = aug(c, GEOM, 0.12)
    nxt = aug(c, GEOM, 0.12)
    assert a.shape == c.shape and a.dtype == c.dtype
    assert torch.isfinite(a).all() and a.min() >= 0
    assert torch.equal(a, b)
    assert not torch.equal(a, nxt)
    # Per-example parameters: the same digit twice in a batch is transformed differently.
    twice = aug(c[:1].expand(2, -1, -1, -1).contiguous(), GEOM)
    assert not torch.allclose(twice[0], twice[1])


def test_registry_names_and_configs():
    assert [cls.name for cls in BUILTIN] == ["shift", "rescale", "rotate", "perspective"]
    for cls in BUILTIN:
        assert cls.summary() and cls().config == cls.Config()
    assert Rescale().config.min_height == 0.02 and Rescale().config.max_height == 0.20
    assert Rotate().config.max_angle == 90.0
    assert (Perspective().config.distortion, Perspective().config.p) == (0.5, 1.0)
    with pytest.raises(ConfigError, match=r"augment\.rescale\.max_height"):
        Rescale({"min_height": 0.1, "max_height": 0.05})
    with pytest.raises(ConfigError, match=r"augment\.perspective\.distortion"):
        Perspective({"distortion": 1.5})


def test_shift_keeps_object_fully_visible():
    # Shift is an exact area resampling with unit scale: it moves intensity, never creates or
    # drops any, as long as the object stays on the canvas. So the sum is preserved to float
    # rounding only if the whole object stayed in view.
    c = to_canvas(_digits(32), GEOM)
    torch.manual_seed(0)
    out = Shift()(c, GEOM)
    assert torch.allclose(out.sum((1, 2, 3)), c.sum((1, 2, 3)), rtol=1e-5)
    # Positions spread over the field of view.
    rows = (out.sum((1, 3)) * torch.arange(109.0)).sum(-1) / out.sum((1, 2, 3))
    assert rows.max() - rows.min() > 40
    # An object larger than the FOV (minus margin) is left where it is.
    stuck = Shift({"margin": 0.3})(c, GEOM)
    assert torch.allclose(stuck, c, atol=1e-6)


def test_rescale_scales_sum_and_extent():
    x = _digits()
    c = to_canvas(x, GEOM)
    for h in (0.06, 0.18):
        out = Rescale({"min_height": h, "max_height": h})(c, GEOM, 0.12)
        s = h / 0.12
        # Area resampling: intensity per area unchanged, area x s^2 (object stays on the canvas).
        assert torch.allclose(out.sum((1, 2, 3)), s**2 * c.sum((1, 2, 3)), rtol=1e-5)
        assert torch.allclose(_extent(out, -2), s * _extent(c, -2), atol=2)
    torch.manual_seed(0)
    one = c[:1].expand(256, -1, -1, -1)
    out = Rescale()(one, GEOM, 0.12)  # scale ~ U[1/6, 5/3]
    mean_s2 = ((0.20**3 - 0.02**3) / (3 * (0.20 - 0.02))) / 0.12**2  # E[s^2]
    ratio = out.sum((1, 2, 3)) / c[0].sum()
    assert ratio.mean().item() == pytest.approx(mean_s2, rel=0.1)


def test_rotate_preserves_intensity_and_isotropic_blob():
    c = to_canvas(_digits(16), GEOM)
    torch.manual_seed(0)
    out = Rotate()(c, GEOM)
    # Bilinear interpolation conserves the sum up to sampling error of the sharp strokes.
    assert torch.allclose(out.sum((1, 2, 3)), c.sum((1, 2, 3)), rtol=0.05)
    assert torch.allclose(Rotate({"max_angle": 0.0})(c, GEOM), c, atol=1e-5)
    # A Gaussian centred on the object is invariant under rotation about the object's centre.
    top, left, rows, cols = GEOM.object_box()
    yy, xx = torch.meshgrid(torch.arange(109.0) + 0.5, torch.arange(146.0) + 0.5, indexing="ij")
    blob = torch.exp(-((yy - top - rows / 2) ** 2 + (xx - left - cols / 2) ** 2) / (2 * 5.0**2))
    blob = blob.expand(4, 1, -1, -1).contiguous()
    out = Rotate()(blob, GEOM)
    assert torch.allclose(out, blob, atol=1e-2)  # bilinear smoothing at the peak: ~f''/8
    for dim in (-2, -1):
        pos = torch.arange(blob.shape[dim], dtype=torch.float32) + 0.5
        other = -1 if dim == -2 else -2
        centroid = lambda im: (im.sum((1, other)) * pos).sum(-1) / im.sum((1, 2, 3))
        assert torch.allclose(centroid(out), centroid(blob), atol=1e-3)


def test_perspective_shrinks_inside_object_box():
    c = to_canvas(_digits(16), GEOM)
    torch.manual_seed(0)
    out = Perspective()(c, GEOM)
    assert torch.isfinite(out).all() and out.min() >= 0
    # Corners move inward: the content stays within the object's box and loses area.
    top, left, rows, cols = GEOM.object_box()
    box = torch.zeros_like(c, dtype=torch.bool)
    box[..., int(top) - 1 : int(top) + 29, int(left) - 1 : int(left) + 29] = True
    assert out[~box].abs().max() < 1e-6
    assert (out.sum((1, 2, 3)) < c.sum((1, 2, 3))).all()
    assert torch.allclose(Perspective({"p": 0.0})(c, GEOM), c, atol=1e-4)


def test_compose_keeps_rescaled_object_in_view():
    c = to_canvas(_digits(32), GEOM)
    torch.manual_seed(1)
    big = Compose([Rescale({"min_height": 0.2, "max_height": 0.2}), Shift()])(c, GEOM)
    s = 0.2 / 0.12
    assert torch.allclose(big.sum((1, 2, 3)), s**2 * c.sum((1, 2, 3)), rtol=1e-5)
    torch.manual_seed(1)
    allfour = Compose([cls() for cls in BUILTIN])(c, GEOM)
    assert allfour.shape == c.shape and torch.isfinite(allfour).all() and allfour.min() >= 0


@pytest.mark.parametrize("names", [["shift"], ["rescale"], ["rotate"], ["perspective"], ["rescale", "shift"],
                                   ["shift", "rotate"], ["rotate", "shift"], ["rescale", "shift", "perspective"]])
def test_place_folds_leading_resamplings_into_the_placement_with_the_same_result(names):
    # Compose.place resamples the (rows x 28) placement matrices instead of every canvas: the same linear map
    # (R P) x Q^T = R (P x Q^T), so only rounding differs. Shift and rescale alone, against the float64 canvas
    # path: the float32 canvas path is off by its cumulative sums' rounding (row sums up to ~30 x 6e-8, ~2e-6);
    # place resamples in float64 and multiplies once in float32: within 1e-6 (values <= 1). With kornia's
    # warps (float32 bilinear, ~1.4e-5 from their float64 selves here) both paths share that rounding: 3e-5.
    augs = [next(c() for c in BUILTIN if c.name == n) for n in names]
    comp = Compose(augs)
    g = torch.Generator().manual_seed(4)
    scenes = torch.rand(6, 1, 28, 28, generator=g)
    u = torch.rand(6, comp.n_random, generator=g, dtype=torch.float64)
    got = comp.place(scenes, GEOM, 0.12, u)
    expect = comp(to_canvas(scenes, GEOM), GEOM, 0.12, u)
    assert got.dtype == torch.float32 and got.shape == expect.shape and float(got.min()) >= 0
    torch.testing.assert_close(got, expect, rtol=0, atol=3e-5)
    if set(names) <= {"shift", "rescale"}:
        truth = comp(to_canvas(scenes.double(), GEOM), GEOM, 0.12, u)
        torch.testing.assert_close(got.double(), truth, rtol=0, atol=1e-6)
    assert float((got - to_canvas(scenes, GEOM)).abs().max()) > 1e-2  # something was transformed


def test_perspective_about_the_field_moves_and_shrinks_the_object():
    # The paper applied torchvision's RandomPerspective (distortion 0.5) to its whole padded object plane:
    # the field's corners move inward by up to a quarter of its size, so a centred object is displaced
    # and shrunk as well as distorted; about the object it stays in its own box.
    c = to_canvas(_digits(64), GEOM)
    u = Perspective().draw(64)
    obj = Perspective().apply(c, GEOM, ObjectState.initial(GEOM, 64), u)[0]
    field = Perspective({"about": "field"}).apply(c, GEOM, ObjectState.initial(GEOM, 64), u)[0]
    rows = torch.arange(GEOM.shape[0], dtype=c.dtype)[:, None]
    cols = torch.arange(GEOM.shape[1], dtype=c.dtype)
    def centroid(im):
        m = im.sum((1, 2, 3))
        return torch.stack([(im[:, 0] * rows).sum((1, 2)) / m, (im[:, 0] * cols).sum((1, 2)) / m], 1)
    move_obj = (centroid(obj) - centroid(c)).norm(dim=1)
    move_field = (centroid(field) - centroid(c)).norm(dim=1)
    # The field is ~4-5x the object's size: its corner moves (up to a quarter of the field) carry the object
    # several pixels on average; about the object the centroid moves by a fraction of the 28-px box.
    assert move_field.mean() > 3 * move_obj.mean() and move_field.mean() > 3.0
    # A homography that maps the field into itself shrinks what it carries: less light on the canvas.
    assert (field.sum((1, 2, 3)) < c.sum((1, 2, 3))).all()
    # Where the object fills the field, the two are the same transform.
    tight = canvas_geometry(0.12, (28, 28), 0.12, 0.12)
    ct = to_canvas(_digits(4), tight)
    ut = Perspective().draw(4)
    a = Perspective().apply(ct, tight, ObjectState.initial(tight, 4), ut)[0]
    b = Perspective({"about": "field"}).apply(ct, tight, ObjectState.initial(tight, 4), ut)[0]
    torch.testing.assert_close(a, b, atol=1e-5, rtol=1e-5)


@pytest.mark.parametrize("names", [["rotate"], ["perspective"], ["rescale", "rotate"], ["rotate", "perspective"]])
def test_place_window_holds_everything_the_transforms_make_nonzero(names):
    # Rotate and perspective (about the object) transform only a window around the objects: the whole canvas,
    # transformed, is exactly zero outside it, and the window is the canvas's part (kornia's float32 bilinear
    # warps at shifted coordinates: the 3e-5 of the test above).
    augs = [next(c() for c in BUILTIN if c.name == n) for n in names]
    comp = Compose(augs)
    g = torch.Generator().manual_seed(5)
    scenes = _digits(8, seed=5)
    u = torch.rand(8, comp.n_random, generator=g, dtype=torch.float64)
    window, (r0, c0) = comp.place_window(scenes, GEOM, 0.12, u)
    h, w = window.shape[-2:]
    assert h * w < 0.3 * GEOM.shape[0] * GEOM.shape[1]  # a digit's reach, not the field of view
    whole = comp(to_canvas(scenes, GEOM), GEOM, 0.12, u)
    outside = whole.clone()
    outside[..., r0 : r0 + h, c0 : c0 + w] = 0
    assert float(outside.abs().max()) == 0.0
    torch.testing.assert_close(window, whole[..., r0 : r0 + h, c0 : c0 + w], rtol=0, atol=3e-5)


def test_place_window_is_the_whole_canvas_where_a_transform_reaches_anywhere():
    comp = Compose([Shift(), Perspective({"about": "field"})])
    window, corner = comp.place_window(_digits(2), GEOM, 0.12, torch.rand(2, comp.n_random, dtype=torch.float64))
    assert tuple(window.shape[-2:]) == tuple(GEOM.shape) and corner == (0, 0)


@pytest.mark.parametrize("expanded", [False, True])
def test_resampling_a_range_of_cells_gives_exactly_those_cells(expanded):
    # place_window resamples the placement matrices only over the window's rows and columns, and integrates
    # a placement shared by every example once: the cells it keeps must be the whole resampling's, bit for bit.
    from optoenc.augment import _resample_axis

    g = torch.Generator().manual_seed(2)
    img = torch.rand(1 if expanded else 5, 1, 40, 7, generator=g, dtype=torch.float64)
    img = img.expand(5, -1, -1, -1) if expanded else img
    start, scale = torch.rand(5, generator=g, dtype=torch.float64) * 9 - 3, 0.5 + torch.rand(5, generator=g, dtype=torch.float64)
    whole = _resample_axis(img, -2, start, scale)
    dense = _resample_axis(img.contiguous(), -2, start, scale)
    assert torch.equal(whole, dense)
    for lo, hi in [(0, 40), (3, 17), (39, 40)]:
        assert torch.equal(_resample_axis(img, -2, start, scale, (lo, hi)), whole[:, :, lo:hi])


@pytest.mark.parametrize("expanded", [False, True])
def test_each_examples_own_cells_are_the_whole_resamplings(expanded):
    # place_window resamples each example's band of cells only (cells = (first, count)): bit for bit the
    # whole resampling's cells, and the band (_band) holds every cell the whole resampling makes nonzero,
    # for shifts, shrinks and enlargements, inputs that are zero near their ends, and bands cut by the range.
    from optoenc.augment import _band, _resample_axis

    g = torch.Generator().manual_seed(3)
    img = torch.zeros(1 if expanded else 6, 1, 40, 7, dtype=torch.float64)
    img[:, :, 9:23] = torch.rand(img.shape[0], 1, 14, 7, generator=g, dtype=torch.float64)
    img = img.expand(6, -1, -1, -1) if expanded else img
    start = torch.tensor([-20.0, -3.3, 0.0, 7.71, 15.5, 30.2], dtype=torch.float64)
    scale = torch.tensor([1.0, 1.0, 0.37, 1.0, 2.9, 1.3], dtype=torch.float64)
    whole = _resample_axis(img, -2, start, scale)
    for lo, hi in [(0, 40), (5, 33)]:
        first, count = _band(img, start, scale, lo, hi)
        assert count < hi - lo  # a band, not the range
        band = _resample_axis(img, -2, start, scale, (first, count))
        for b in range(6):
            f = int(first[b])
            assert lo <= f and f + count <= hi
            assert torch.equal(band[b, :, :], whole[b, :, f : f + count])
            outside = whole[b, :, lo:hi].clone()
            outside[:, f - lo : f - lo + count] = 0
            assert float(outside.abs().max()) == 0.0  # exactly zero: nothing of the object is dropped


@pytest.mark.parametrize("names", [["shift"], ["rescale"], ["shift", "rescale"], ["rescale", "shift"], ["shift", "rotate"]])
@pytest.mark.parametrize("autocast", [False, True])
def test_place_window_by_bands_is_the_whole_windows_bit_for_bit(names, autocast, monkeypatch):
    # The bands (each object's rows and columns, pasted on the window) are the same canvases as resampling
    # the whole window, exactly: each cell is computed alone, and the placement products sum the same 28
    # terms per pixel; also in bfloat16 autocast (the training step's) and before a warp.
    import optoenc.augment as augment

    comp = Compose([next(c() for c in BUILTIN if c.name == n) for n in names])
    g = torch.Generator().manual_seed(4)
    scenes = _digits(9, seed=4)
    u = torch.rand(9, comp.n_random, generator=g, dtype=torch.float64)
    pasted = []
    real_paste = augment.paste
    monkeypatch.setattr(augment, "paste", lambda *a: pasted.append(1) or real_paste(*a))
    monkeypatch.setattr(augment, "_BAND_GAIN", 0)  # bands wherever a separable transform leads
    with torch.autocast("cpu", dtype=torch.bfloat16, enabled=autocast):
        banded, corner = comp.place_window(scenes, GEOM, 0.12, u)
        assert pasted
        monkeypatch.setattr(augment, "_BAND_GAIN", 10**9)  # never
        whole, corner2 = comp.place_window(scenes, GEOM, 0.12, u)
    assert len(pasted) == 1 and corner == corner2 and banded.dtype == whole.dtype
    assert torch.equal(banded, whole)


@pytest.mark.parametrize("dtype", [torch.bfloat16, torch.float16, torch.float32, torch.float64])
def test_paste_puts_each_window_at_its_offset_in_any_dtype(dtype):
    # Two-byte floats are scattered as their bits: the same values, signed zeros included.
    from optoenc.augment import paste

    g = torch.Generator().manual_seed(5)
    windows = (torch.rand(3, 2, 4, 5, generator=g) - 0.5).to(dtype)
    windows[0, 0, 0, 0] = -0.0
    offsets = torch.tensor([[0, 0], [3, 6], [6, 1]])
    out = paste(windows, offsets, (10, 11))
    assert out.dtype == dtype
    expect = torch.zeros(3, 2, 10, 11, dtype=dtype)
    for b, (r, c) in enumerate(offsets.tolist()):
        expect[b, :, r : r + 4, c : c + 5] = windows[b]
    assert torch.equal(out, expect)
    assert torch.signbit(out[0, 0, 0, 0])


@pytest.mark.filterwarnings("ignore")  # the small grid's sampling warning
@pytest.mark.parametrize("mixed", [False, True])
def test_training_steps_under_redrawn_shifts_are_the_same_with_bands(mixed, monkeypatch):
    # End to end: a learned SLM trained three optimiser steps on digits shifted anew every step (draws from
    # torch's global RNG, as training draws them) ends with the same mask and decoder, bit for bit, whether the
    # placement resamples each object's band (measured by SceneOperator.apply_pasted) or the whole window (apply_window),
    # in float32 and in bfloat16 autocast.
    from omegaconf import OmegaConf

    from optoenc.config import compose
    from optoenc.sweep.estimate import training_step

    cfg = OmegaConf.create({
        "encoder": {"name": "learned_slm"}, "decoder": {"name": "fcnn"}, "sensor": {"embedding": [6, 8]},
        "augment": {"shift": {}}, "fidelity": {"grid": [48, 64]},
        "trainer": {"batch_size": 16, "precision": "bf16-mixed" if mixed else "32-true"}})
    run = compose([cfg], [])
    scenes = _digits(16, seed=7)
    from optoenc.encoders import imaging

    pasted, real_paste = [], imaging.paste  # apply_pasted lays each band where the operator reads it
    monkeypatch.setattr(imaging, "paste", lambda *a: pasted.append(1) or real_paste(*a))
    params = {}
    for bands in (True, False):
        monkeypatch.setattr(Compose, "placement_bands", bands)
        torch.manual_seed(0)
        built = training_step(run, (1, 28, 28), scenes)
        for _ in range(3):
            built.step()
        params[bands] = [p.detach().clone() for p in built.module.parameters()]
        assert len(pasted) == (3 if bands else 0)  # each step placed its batch by bands, or none did
        pasted.clear()
    assert len(params[True]) > 2
    assert all(torch.equal(a, b) for a, b in zip(params[True], params[False]))
