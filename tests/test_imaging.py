"""The shared imaging steps: analytic references, invariants and extremes."""

from __future__ import annotations

import warnings

import pytest
import torch
import torch.nn.functional as F

from optoenc.encoders import imaging as im
from optoenc.encoders import noise
from optoenc.encoders.operator import apply_operator, scene_operator

DT = torch.float64


def brute_convolve(image: torch.Tensor, psf: torch.Tensor) -> torch.Tensor:
    """Direct double loop of the documented convolution convention."""
    H, W = image.shape
    Hp, Wp = psf.shape
    out = torch.zeros(H, W, dtype=image.dtype)
    for y in range(H):
        for x in range(W):
            for yy in range(H):
                for xx in range(W):
                    i, j = y - yy + Hp // 2, x - xx + Wp // 2
                    if 0 <= i < Hp and 0 <= j < Wp:
                        out[y, x] += image[yy, xx] * psf[i, j]
    return out


@pytest.mark.parametrize("shape,pshape", [((5, 6), (5, 6)), ((4, 7), (3, 5)), ((6, 6), (7, 4))])
def test_fft_convolve_matches_direct_sum(shape, pshape):
    g = torch.Generator().manual_seed(0)
    img, psf = torch.rand(shape, generator=g, dtype=DT), torch.rand(pshape, generator=g, dtype=DT)
    # float64 FFT round trip: errors ~1e-15 relative; 1e-12 leaves margin for the sum.
    torch.testing.assert_close(im.fft_convolve(img, psf), brute_convolve(img, psf), rtol=1e-12, atol=1e-12)


def test_centred_impulse_is_identity_for_odd_and_even_sizes():
    for H, W in [(6, 8), (7, 9), (1, 5)]:
        img = torch.rand(H, W, dtype=DT)
        delta = torch.zeros(H, W, dtype=DT)
        delta[H // 2, W // 2] = 1
        torch.testing.assert_close(im.fft_convolve(img, delta), img, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize(
    "grid,psf_shape,scene,emb,height",
    [((48, 64), (48, 64), (7, 5), (6, 8), 20.3), ((45, 61), (45, 61), (6, 6), (5, 7), 17.0), ((32, 32), (17, 21), (4, 4), (4, 4), 10.0)],
)
def test_operator_equals_fine_grid_pipeline(grid, psf_shape, scene, emb, height):
    g = torch.Generator().manual_seed(1)
    psf = torch.rand(2, *psf_shape, generator=g, dtype=DT)
    x = torch.rand(3, 2, *scene, generator=g, dtype=DT)
    ref = im.integrate(im.fft_convolve(im.place(x, grid, height), psf), emb)
    py, px = im.placement_matrices(scene, grid, height)
    ry = im.correlation_tensor(im.box_matrix(grid[0], emb[0]), py, psf_shape[0])
    rx = im.correlation_tensor(im.box_matrix(grid[1], emb[1]), px, psf_shape[1])
    out = apply_operator(scene_operator(psf, ry, rx), x)
    # Two exact float64 evaluations of the same linear map: rounding only (~1e-14 of values ~50).
    torch.testing.assert_close(out, ref, rtol=1e-11, atol=1e-11)


@pytest.mark.parametrize("channels", [1, 2])
def test_operator_gradient_with_respect_to_the_psf_is_the_fine_grid_pipelines(channels):
    # The operator path's PSF gradient (what trains a learned mask) against the fine-grid pipeline's, for
    # one scene channel broadcast to the PSF's channels and one scene channel per PSF channel. Both are exact
    # maps in float64, so only rounding separates them: measured 1.1e-15 absolute on gradients up to 3.2;
    # atol 1e-12 leaves 1000x for other BLAS orders, far below a layout error (entries of order 1).
    g = torch.Generator().manual_seed(2)
    grid, scene, emb, height = (32, 40), (5, 6), (4, 5), 12.0
    psf = torch.rand(2, *grid, generator=g, dtype=DT, requires_grad=True)
    x = torch.rand(3, channels, *scene, generator=g, dtype=DT)
    w = torch.randn(3, 2, *emb, generator=g, dtype=DT)
    py, px = im.placement_matrices(scene, grid, height)
    ry = im.correlation_tensor(im.box_matrix(grid[0], emb[0]), py, grid[0])
    rx = im.correlation_tensor(im.box_matrix(grid[1], emb[1]), px, grid[1])
    (g_op,) = torch.autograd.grad((apply_operator(scene_operator(psf, ry, rx), x) * w).sum(), psf)
    ref = im.integrate(im.fft_convolve(im.place(x, grid, height), psf), emb)
    (g_ref,) = torch.autograd.grad((ref * w).sum(), psf)
    torch.testing.assert_close(g_op, g_ref, rtol=1e-10, atol=1e-12)


def test_box_integration_equals_average_pooling_when_the_grid_divides():
    x = torch.rand(2, 1, 48, 64, dtype=DT)
    for emb in [(24, 32), (12, 16), (6, 8), (3, 4), (1, 1), (48, 64)]:
        ref = F.avg_pool2d(x, (48 // emb[0], 64 // emb[1]))
        torch.testing.assert_close(im.integrate(x, emb), ref, rtol=1e-13, atol=1e-13)


def test_box_integration_with_fractional_cells_preserves_the_mean():
    x = torch.rand(1, 1, 38, 50, dtype=DT)  # 38 / 5 and 50 / 7 are not integers
    out = im.integrate(x, (5, 7))
    # Every output averages exact fractional areas, so the mean is preserved exactly (rounding only).
    torch.testing.assert_close(out.mean(), x.mean(), rtol=1e-13, atol=0)


def test_placement_conserves_integrated_intensity_and_scales_with_area():
    scene = torch.rand(28, 28, dtype=DT)
    for h in [3.5, 28.0, 97.8]:
        placed = im.place(scene, (128, 160), h)
        # Area resampling: each scene pixel covers (h/28)^2 grid pixels.
        torch.testing.assert_close(placed.sum(), scene.sum() * (h / 28) ** 2, rtol=1e-12, atol=0)


def test_placement_inverts_the_image():
    scene = torch.zeros(4, 4, dtype=DT)
    scene[0, 0] = 1  # top-left in the object plane
    placed = im.place(scene, (8, 8), 4.0)
    # the 4 x 4 scene covers grid rows/cols 2..5; its top-left pixel lands bottom-right (M < 0)
    assert placed[5, 5] == 1 and placed[2, 2] == 0


def test_object_smaller_than_a_pixel_is_finite_and_keeps_energy():
    placed = im.place(torch.ones(28, 28, dtype=DT), (16, 16), 0.3)
    assert torch.isfinite(placed).all()
    torch.testing.assert_close(placed.sum(), torch.tensor(0.09, dtype=DT), rtol=1e-12, atol=0)


def test_object_larger_than_the_field_of_view_is_cropped_with_a_warning():
    with pytest.warns(UserWarning, match="cropped"):
        placed = im.place(torch.ones(28, 28, dtype=DT), (16, 16), 40.0)
    torch.testing.assert_close(placed, torch.ones(16, 16, dtype=DT))


@pytest.mark.parametrize("snr_db", [-10.0, 0.0, 20.0, 40.0, 100.0])
def test_noise_hits_the_target_snr_and_is_zero_mean(snr_db):
    torch.manual_seed(0)
    signal = torch.rand(64, 1, 24, 32, dtype=DT) + 0.5
    noisy = noise.add_noise(signal, snr_db)
    drawn = noisy - signal
    measured = 10 * torch.log10(signal.flatten(1).var(1, unbiased=False) / drawn.flatten(1).var(1, unbiased=False))
    # 768 samples per example: the variance estimate has ~5 % relative spread, ~0.2 dB; 64 examples averaged.
    assert abs(measured.mean().item() - snr_db) < 0.1
    # zero mean: |mean| below 4 standard errors of the mean of 64*768 samples.
    sigma = drawn.std().item()
    assert abs(drawn.mean().item()) < 4 * sigma / (64 * 768) ** 0.5


def test_noise_extremes_are_finite():
    black = torch.zeros(3, 1, 4, 4)
    for model in ("gaussian", "poisson"):
        out = noise.add_noise(black, 40.0, model)
        assert torch.isfinite(out).all() and (out == 0).all()  # zero variance: zero noise
    x = torch.rand(3, 1, 4, 4)
    assert torch.equal(noise.add_noise(x, None), x)
    assert torch.equal(noise.add_noise(x, 40.0, "none"), x)
    assert torch.isfinite(noise.add_noise(x, 1000.0)).all()


def test_noise_is_differentiable_and_poisson_is_straight_through():
    x = torch.rand(2, 1, 4, 4, requires_grad=True)
    noise.add_noise(x, 10.0).sum().backward()
    torch.testing.assert_close(x.grad, torch.ones_like(x))
    x.grad = None
    noise.add_noise(x, None, "poisson", photons=100).sum().backward()
    torch.testing.assert_close(x.grad, torch.ones_like(x))


def test_noise_level_is_a_constant_in_the_backward_pass():
    # sigma(signal) = std over the example's pixels x 10^(-snr/20) scales fixed draws; the backward pass treats it
    # as a constant: the gradient of the noisy reading is exactly the identity (0 tolerance: no arithmetic on it),
    # also for an all-black example (zero variance, where sqrt's derivative is infinite).
    x = torch.stack([torch.zeros(1, 4, 4, dtype=DT), torch.rand(1, 4, 4, dtype=DT) + 0.5]).requires_grad_()
    n = torch.randn(x.shape, generator=torch.Generator().manual_seed(3), dtype=DT)
    out = noise.add_noise(x, 10.0, noise=n)
    out.sum().backward()
    assert torch.equal(out[0], x[0].detach()) and not torch.equal(out[1], x[1].detach())
    torch.testing.assert_close(x.grad, torch.ones_like(x), rtol=0, atol=0)


def test_quantize_rounds_to_levels():
    x = torch.tensor([[0.0, 0.26, 0.5, 1.0]])
    q = noise.quantize(x, 2, full_scale=1.0)  # levels 0, 1/3, 2/3, 1
    torch.testing.assert_close(q, torch.tensor([[0.0, 1 / 3, 2 / 3, 1.0]]))
    assert torch.isfinite(noise.quantize(torch.zeros(1, 4), 8)).all()


def test_zero_energy_psf_is_a_clear_error():
    from optoenc.errors import PhysicsError

    with pytest.raises(PhysicsError, match="zero energy"):
        im.normalize_psf(torch.zeros(1, 4, 4))
    with pytest.raises(PhysicsError, match="NaN"):
        im.normalize_psf(torch.full((1, 4, 4), float("nan")))


def test_embedding_larger_than_the_grid_is_rejected():
    from optoenc.errors import ConfigError

    with pytest.raises(ConfigError, match="embedding"):
        im.box_matrix(16, 17)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert im.box_matrix(16, 16).shape == (16, 16)


def _subcell_operator(psf, x, grid, emb, height, s):
    (H, W), (a, b) = grid, emb
    py, px = im.placement_matrices(tuple(x.shape[-2:]), (H * s, W * s), height * s)
    ry = im.correlation_tensor(im.box_matrix(H * s, a), py, H, sub=s)
    rx = im.correlation_tensor(im.box_matrix(W * s, b), px, W, sub=s)
    return apply_operator(scene_operator(psf, ry, rx), x)


@pytest.mark.parametrize("s", [3, 5])
def test_subcell_scene_geometry_conserves_energy_and_agrees_for_smooth_psfs(s):
    H, W = 48, 64
    yy, xx = torch.meshgrid(torch.arange(H, dtype=DT) - H // 2, torch.arange(W, dtype=DT) - W // 2, indexing="ij")
    x = torch.rand(2, 1, 7, 5, generator=torch.Generator().manual_seed(0), dtype=DT)

    def gaussian(var):
        g = torch.exp(-(yy**2 + xx**2) / var)[None]
        return g / g.sum()

    # Energy: a PSF that fits well inside the window (tails ~1e-20 at its edge) and a scene
    # inside the field: nothing leaves the grid, so the total light is the same to rounding.
    tight = gaussian(8.0)
    torch.testing.assert_close(
        _subcell_operator(tight, x, (H, W), (6, 8), 20.3, s).sum((1, 2, 3)),
        _subcell_operator(tight, x, (H, W), (6, 8), 20.3, 1).sum((1, 2, 3)),
        rtol=1e-12,
        atol=0,
    )
    # A PSF smooth over a pixel barely sees the scene's sub-pixel structure: measured 0.1 %; 0.5 % bound.
    wide = gaussian(50.0)
    r1 = _subcell_operator(wide, x, (H, W), (6, 8), 20.3, 1)
    rs = _subcell_operator(wide, x, (H, W), (6, 8), 20.3, s)
    assert ((rs - r1).norm() / r1.norm()).item() < 5e-3


def test_even_subcells_are_rejected():
    from optoenc.errors import ConfigError

    with pytest.raises(ConfigError, match="odd"):
        im.correlation_tensor(im.box_matrix(8, 2), torch.eye(8, dtype=DT), 4, sub=2)


@pytest.mark.parametrize(
    "a,h,Hp,b,w,Wp,rows_first",
    [
        (3, 4, 12, 2, 5, 9, True),  # a small scene: the row factor first
        (4, 9, 6, 3, 11, 7, False),  # a scene larger than the PSF grid (Table 3's canvas): the column factor first
    ],
)
def test_scene_operator_is_the_triple_contraction_in_either_order(a, h, Hp, b, w, Wp, rows_first):
    # The operator is sum_kl ry[a,h,k] psf[c,k,l] rx[b,w,l], computed as two products in whichever order
    # costs fewer multiply-adds; both orders must give it (float64: agreement to 1e-12 relative), and
    # the gradient with respect to the PSF must be that of the contraction (gradcheck, float64).
    assert (a * h * Wp * (Hp + b * w) <= Hp * b * w * (Wp + a * h)) == rows_first  # the case covers its branch
    g = torch.Generator().manual_seed(3)
    ry, rx = torch.rand(a, h, Hp, generator=g, dtype=torch.float64), torch.rand(b, w, Wp, generator=g, dtype=torch.float64)
    psf = torch.rand(2, Hp, Wp, generator=g, dtype=torch.float64, requires_grad=True)
    ref = torch.einsum("phk,ckl,qwl->cpqhw", ry, psf, rx)
    torch.testing.assert_close(scene_operator(psf, ry, rx), ref, rtol=1e-12, atol=0)
    assert torch.autograd.gradcheck(lambda p: scene_operator(p, ry, rx), (psf,))
