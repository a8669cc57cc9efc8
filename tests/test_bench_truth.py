"""The bench's truth (grid-free Fresnel PSFs of rectangles, Richardson limits) and the published paper pipeline."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from optoenc.bench import pipeline, published
from optoenc.bench import settings as bench_settings
from optoenc.bench import truth as T

pytestmark = pytest.mark.filterwarnings("ignore::optoenc.optics.diagnostics.SamplingWarning")

D1, D2 = 0.4, 4e-3


def _cells(rows, cols, amp):
    return T.RectCells(np.asarray(rows, float), np.asarray(cols, float), np.asarray(amp, float))


def test_fresnel_rectangle_shadow_intensity_and_power():
    # a 1 x 1.5 mm open rectangle: deep inside its shadow the intensity is the diverging beam's (d1 / (d1 + d2))^2,
    # and the power reaching a window that holds all the diffracted light equals the open area (Fresnel is unitary)
    cells = _cells([[-0.5e-3, 0.5e-3]], [[-0.75e-3, 0.75e-3]], np.ones((3, 1, 1)))
    grid, spacing = (120, 160), (20e-6, 20e-6)
    psf = T.fresnel_psf(cells, grid, spacing, D1, D2, quadrature=24)
    centre = psf[:, 55:65, 75:85].mean(axis=(1, 2))
    # 2 %: the edge ripples (amplitude ~ 1 / (pi u), u ~ 15 at 0.45 mm from the edge) average out over the block
    np.testing.assert_allclose(centre, (D1 / (D1 + D2)) ** 2, rtol=0.02)
    power = psf.sum(axis=(1, 2)) * spacing[0] * spacing[1]
    # 0.5 %: the diffracted tails beyond the 2.4 x 3.2 mm window (~ lambda d2 / (pi^2 x) per edge)
    np.testing.assert_allclose(power, 1e-3 * 1.5e-3, rtol=5e-3)


def test_separable_pixel_integral_equals_brute_force_quadrature():
    # the SVD / K^2 separable pixel integral is exact: same as integrating |U|^2 on a 2-D node lattice
    rng = np.random.default_rng(0)
    rows = np.array([[-150e-6, -90e-6], [-70e-6, -10e-6], [10e-6, 70e-6]])
    cols = np.array([[-120e-6, 60e-6], [100e-6, 280e-6]])
    amp = rng.uniform(0, 1, (3, 3, 2))
    grid, spacing, q = (24, 32), (15e-6, 15e-6), 6
    fast = T.fresnel_psf(_cells(rows, cols, amp), grid, spacing, D1, D2, quadrature=q)
    a = 1 / D1 + 1 / D2
    ys, wy = T._nodes(grid[0], spacing[0], q)
    xs, wx = T._nodes(grid[1], spacing[1], q)
    for c, lam in enumerate((640e-9, 550e-9, 460e-9)):
        u = T._fresnel_factor(ys, rows, a, D2, lam) @ amp[c] @ T._fresnel_factor(xs, cols, a, D2, lam).T
        brute = (np.abs(u) ** 2 * wy[:, None] * wx[None, :]).reshape(grid[0], q, grid[1], q).sum(axis=(1, 3))
        np.testing.assert_allclose(fast[c], brute / (4 * (a * D2) ** 2), rtol=1e-9, atol=1e-12 * brute.max())


def test_fresnel_agrees_with_the_exact_kernel_for_lcd_rows():
    # Five LCD rows (73 um pitch, 60 um open), 4 mm behind: the paraxial (Fresnel) and the exact
    # (Rayleigh-Sommerfeld angular spectrum) intensities, as the embedding sees them (smoothed by a scene
    # pixel and an embedding pixel), agree to 0.1 %; without the smoothing they differ by percents (fringes).
    edges = np.stack([np.arange(5) * 73e-6 - 30e-6, np.arange(5) * 73e-6 + 30e-6], axis=1) - 146e-6
    amp = np.array([0.2, 1.0, 0.5, 0.8, 0.3])
    seen = T.fresnel_vs_exact_1d(edges, amp, 640e-9, D1, D2, 1.55e-6, smooth=(41e-6, 196e-6), step=0.1e-6)
    raw = T.fresnel_vs_exact_1d(edges, amp, 640e-9, D1, D2, 1.55e-6, step=0.1e-6)
    assert seen < 1e-3 < raw


def test_richardson_recovers_the_limit_and_order():
    g = torch.Generator().manual_seed(0)
    exact, c = (torch.rand(4, 1, 3, 3, generator=g, dtype=torch.float64) for _ in range(2))
    levels = [exact + c * h**1.5 for h in (4.0, 2.0, 1.0)]
    limit, p, corr = T.richardson(levels)
    assert p == pytest.approx(1.5, rel=1e-9)
    assert float((limit - exact).norm() / exact.norm()) < 1e-12
    assert corr == pytest.approx(float((levels[-1] - exact).norm() / exact.norm()), rel=1e-9)


def test_truth_routes_and_their_error_estimates(monkeypatch):
    monkeypatch.setattr(T, "QUADRATURE", 1)  # 1 node per sensor pixel: plenty on a 96-row grid for a routing test
    x = torch.rand(2, 1, 28, 28, generator=torch.Generator().manual_seed(1))
    lens = T.truth("lens", x, (6, 8), grid=(96, 128))
    assert lens.method == "analytic" and 0 <= lens.error < 1e-3
    slm = T.truth("fixed_slm", x, (6, 8), grid=(96, 128), kernel_check=False)
    assert slm.method == "fresnel-rect" and slm.embeddings.shape == (2, 1, 6, 8) and slm.error > 0
    pm = T.truth("phase_mask", x, (6, 8), grid=(96, 128))
    assert pm.method == "richardson" and 0.5 <= pm.order <= 4


# ----------------------------------------------------------------------------- the published paper pipeline


def test_published_placement_is_bilinear_inverted_and_centred():
    scene = torch.zeros(1, 1, 4, 4)
    scene[..., 0, 0] = 1.0  # top-left pixel
    out = published.place_bilinear(scene, (20, 30), 8.0)
    assert out.shape == (1, 1, 20, 30)
    rows, cols = torch.nonzero(out[0, 0] > 0, as_tuple=True)
    assert rows.min() >= 6 and cols.min() >= 11  # pasted at ((20 - 8) // 2, (30 - 8) // 2)
    assert rows.max() == 13 and cols.max() == 18  # inverted: the top-left pixel lands bottom-right
    assert published.fft_size((380, 507)) == published.FFT_SIZE == (759, 1013)


def test_published_convolution_with_a_centred_delta_is_the_identity():
    img = torch.rand(1, 12, 16, generator=torch.Generator().manual_seed(2))
    psf = torch.zeros(1, 12, 16)
    psf[0, 6, 8] = 1.0  # the axis at (H // 2, W // 2)
    spec = torch.fft.fft2(psf, s=published.fft_size((12, 16)))
    torch.testing.assert_close(published._convolve_one(img, spec, (12, 16)), img, atol=1e-6, rtol=0)


def test_published_forward_recomputes_the_psf_and_samples_bilinearly():
    enc = bench_settings.build_encoder("fixed_slm", bench_settings.paper_setting((48, 64)), (6, 8))
    calls = []
    orig = enc.compute_psf
    enc.compute_psf = lambda: calls.append(1) or orig()
    x = torch.rand(3, 1, 28, 28, generator=torch.Generator().manual_seed(3))
    with torch.no_grad():
        a = published.published_forward(enc, x, noise=False)
        b = published.published_forward(enc, x, noise=False)
    assert len(calls) == 2 and a.shape == (3, 1, 6, 8) and torch.equal(a, b)
    # not the box integration of the same grid: bilinear downsampling without antialiasing samples 4 pixels
    direct = enc.measure(x, method="direct")
    assert bench_settings.relative_error(a, direct) > 1e-3


# ----------------------------------------------------------------------------- encoder hooks the bench uses


def test_one_wavelength_uses_the_field_spacing_when_oversampled():
    # the old bench propagated the one-wavelength point with the grid spacing on the 3x finer field grid
    from optoenc.encoders import slm_panel
    from optoenc.optics import intensity_psf

    # the 2-D propagation, which intensity_psf below computes (axis by axis is tested in tests/optics/test_separable.py)
    s = bench_settings.Setting("w", "sweep", (48, 64), "float64", "auto", wavelengths=1, oversample=3, propagation="blas")
    enc = bench_settings.build_encoder("fixed_slm", s, (6, 8))
    m = slm_panel.rasterise(enc.displayed_amplitudes().double(), enc.block, enc.field_grid, enc.field_spacing)[1]
    q = intensity_psf(m, (550e-9,), enc.field_spacing, enc.scene_config.distance, enc.d2, normalize="power")
    q = torch.nn.functional.avg_pool2d(q.reshape(1, 1, *q.shape[-2:])[..., : 48 * 3, : 64 * 3], 3)[0]
    torch.testing.assert_close(enc.psf(), q / q.sum(), rtol=1e-10, atol=1e-14)


def test_wavelength_chunks_give_the_same_psf():
    s = bench_settings.Setting("w", "sweep", (48, 64), "float64", "auto", oversample=3)
    one, all3 = bench_settings.build_encoder("coded_aperture", s, (6, 8)), bench_settings.build_encoder("coded_aperture", s, (6, 8))
    one.wavelength_chunk = 1
    torch.testing.assert_close(one.psf(), all3.psf(), rtol=1e-12, atol=0)
    assert math.isclose(float(one.psf().sum()), 1.0)


def test_convergence_study_rows(monkeypatch):
    from optoenc.bench import converge

    monkeypatch.setattr(T, "QUADRATURE", 1)
    rows = converge.study(["lens"], levels=((24, 32), (48, 64), (96, 128)), digits=2, embedding=(6, 8))
    assert [r["level"] for r in rows] == ["24x32", "48x64", "96x128", "limit", "truth"]
    assert rows[0]["error_vs_previous"] is None and rows[1]["error_vs_previous"] > 0
    assert rows[-1]["error_vs_truth"] == 0 and rows[-1]["truth_method"] == "analytic"
    # the lens's refined simulation is its truth's route on the finest level: equal there
    assert rows[2]["error_vs_truth"] < 1e-9
    assert "limit" in converge.format_table(rows)


@pytest.mark.slow  # a paper step at 380 x 507 per repeat: plumbing, but ~5 s
def test_interleaved_speed_reports_min_median_and_load():
    from optoenc.bench import speed

    res = speed.interleaved("learned_slm", "fast", threads=(1,), repeats=2, per_paper=2, batch=4)
    r = res["threads"][1]
    assert len(r["paper_s"]) == 2 and len(r["step_s"]) == 4
    assert r["ratio_min"] == pytest.approx(r["paper_min"] / r["step_min"]) and r["ratio_min"] > 1
    assert "load" in speed.format_speed(res)
