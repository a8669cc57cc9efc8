"""Physics of the `lens` encoder (diffraction-limited thin lens, optional defocus or measured PSF)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.special import j1

from optoenc import devices as K
from optoenc.encoders.lens import Lens, airy_pixel_psf
from optoenc.errors import ConfigError

SMALL = {"fidelity": {"grid": (48, 64)}, "sensor": {"embedding": (6, 8)}}


def _rms_radius(psf: torch.Tensor, spacing, within: float = float("inf")) -> float:
    """RMS radius of the PSF's power inside radius ``within`` (the Airy tail's r^-3 makes the full second
    moment grow with the window)."""
    H, W = psf.shape
    y = (torch.arange(H, dtype=torch.float64) - H // 2)[:, None] * spacing[0]
    x = (torch.arange(W, dtype=torch.float64) - W // 2)[None, :] * spacing[1]
    q = psf.double() * ((y * y + x * x) <= within**2)
    q = q / q.sum()
    return float((q * (y * y + x * x)).sum().sqrt())


def test_thin_lens_geometry_and_digit_size():
    enc = Lens()
    assert enc.focal_length == pytest.approx(K.LENS_FOCAL_LENGTH)
    assert enc.focal_length == pytest.approx(7.39e-3, abs=5e-6)
    assert enc.focus_distance == K.LENS_FOCUS == 0.40  # the paper's setting
    assert enc.blur_diameter == pytest.approx(0.0, abs=1e-12)  # the default scene is at the focus distance
    # REFERENCE §2: ~183-184 px for d2 = 7.53 mm on the ~12.3 um grid (1 px: rounding of the quoted value).
    assert enc.object_height_px() == pytest.approx(184, abs=1.0)


def test_airy_profile_matches_analytic():
    lam, n = 550e-9, 1.2
    step = lam * n / 3  # 3 pixels per lambda N, supersampled 2x inside each
    q = airy_pixel_psf(lam, n, (step, step))
    c = q.shape[0] // 2
    r = np.arange(12) * step
    x = np.pi * r / (lam * n)
    ref = np.where(x > 0, (2 * j1(x) / np.where(x > 0, x, 1)) ** 2, 1.0)
    # 3 % of the peak: averaging over a lambda N / 3 pixel smooths the pattern by ~1 %.
    np.testing.assert_allclose(q[c, c : c + 12] / q[c, c], ref, atol=0.03)
    assert q.sum() == pytest.approx(1.0)


def test_psf_is_centred_and_blur_grows_with_wavelength():
    enc = Lens()  # only a small window is simulated: cheap at the default grid
    psf = enc.compute_psf()
    H, W = enc.geometry.grid
    for c in range(3):
        assert int(psf[c].argmax()) == (H // 2) * W + W // 2
    centre = [float(psf[c, H // 2, W // 2] / psf[c].sum()) for c in range(3)]
    rms = [_rms_radius(psf[c], enc.geometry.spacing, within=3 * max(enc.geometry.spacing)) for c in range(3)]
    assert centre[0] < centre[1] < centre[2]  # R spreads most: a swapped table fails
    assert rms[0] > rms[1] > rms[2]
    # at F1.2 the Airy disk (~1 um) is far below a 12 um pixel: > 95 % stays in the centre pixel
    assert min(centre) > 0.95


def test_defocus_blur_disk():
    enc = Lens({"focus_distance": 0.4}, scene={"distance": 0.2})  # a small window on the default grid
    radius = enc.blur_diameter / 2
    assert radius > 2 * max(enc.geometry.spacing)
    psf = enc.compute_psf()[1]
    dy, dx = enc.geometry.spacing
    # a uniform disk has E[r^2] = R^2 / 2; the pixel box adds (dy^2 + dx^2) / 12.
    expected = np.sqrt(radius**2 / 2 + (dy * dy + dx * dx) / 12)
    # 3 %: the Airy rings inside 1.5 radii and the disk's rasterisation add a little spread.
    assert _rms_radius(psf, enc.geometry.spacing, within=1.5 * radius) == pytest.approx(expected, rel=0.03)


@pytest.mark.parametrize("d1", [0.2, 1.0])
def test_lens_is_focused_once_and_defocuses_other_distances(d1):
    """The lens stays focused at 0.40 m: a scene at 0.2 m or 1 m sees the thin-lens blur disk D |d2 - v| / v."""
    f = 1.0 / (1.0 / 0.40 + 1.0 / K.LENS_D2)  # focused at 0.40 m, independently of the encoder's code
    D = f / K.LENS_F_NUMBER
    v = 1.0 / (1.0 / f - 1.0 / d1)
    b = D * abs(K.LENS_D2 - v) / v  # 116 um at 0.2 m, 70 um at 1 m
    enc = Lens(scene={"distance": d1}, fidelity={"grid": (768, 1024)})  # 5.9 um pixels: the disk spans >= 11 px
    assert enc.blur_diameter == pytest.approx(b, rel=1e-12)
    assert b > 60e-6
    psf = enc.compute_psf()[1]
    dy, dx = enc.geometry.spacing
    expected = np.sqrt(b**2 / 8 + (dy * dy + dx * dx) / 12)  # uniform disk E[r^2] = (b/2)^2 / 2, plus the pixel box
    # 3 %: the Airy rings inside 1.5 blur radii (< 0.4 % of the power) and the disk's rasterisation on the
    # pixel grid add a little spread; a lens refocused on the scene (blur 0) has an rms radius of ~2 um there.
    assert _rms_radius(psf, enc.geometry.spacing, within=0.75 * b) == pytest.approx(expected, rel=0.03)


def test_airy_rings_beyond_the_window_carry_the_missing_power():
    from scipy.special import j0

    enc = Lens(fidelity={"grid": (768, 1024)})
    psf = enc.compute_psf()
    lam_n = K.LENS_D2 / enc.aperture_diameter * 550e-9
    H, W = enc.geometry.grid
    dy, dx = enc.geometry.spacing
    y = (torch.arange(H, dtype=torch.float64) - H // 2)[:, None] * dy
    x = (torch.arange(W, dtype=torch.float64) - W // 2)[None, :] * dx
    r = 100e-6  # far outside the 60 lambda N (~40 um) window
    outside = float(psf[1][(y * y + x * x) > r * r].sum())
    # exact Airy power beyond radius r: J0(x)^2 + J1(x)^2 at x = pi r / (lambda N), minus what leaves the grid
    # (~2 lambda N / (pi^2 r_grid)); 3 %: pixel-centre sampling of the r^-3 tail and the circle on a pixel grid.
    xr = np.pi * r / lam_n
    beyond = 2 * lam_n / (np.pi**2 * 0.25 * (H * dy + W * dx))
    assert outside == pytest.approx(j0(xr) ** 2 + j1(xr) ** 2 - beyond, rel=0.03)
    assert float(psf[1].double().sum()) == pytest.approx(1 - beyond, rel=1e-6)  # power on the sensor (float32)


def test_measured_psf_file(tmp_path):
    raw = np.zeros((96, 128))
    raw[48, 64] = 10.0
    raw[40:44, 60:62] = 1.0
    np.save(tmp_path / "lens_psf.npy", raw)
    enc = Lens({"psf_path": str(tmp_path / "lens_psf.npy"), "background": 0.0}, **SMALL)
    psf = enc.psf()
    assert psf.shape == (1, 48, 64)
    assert float(psf.sum()) == pytest.approx(1.0, rel=1e-5)  # float32 sum
    assert int(psf[0].argmax()) == 24 * 64 + 32
    assert enc.cache_token()
    with pytest.raises(ConfigError, match=r"^encoder\.psf_path = '/nonexistent/psf.npy': file not found"):
        Lens({"psf_path": "/nonexistent/psf.npy"})


def test_validation():
    with pytest.raises(ConfigError, match=r"^encoder\.d2 = 0(\.0)?: must be > 0"):
        Lens({"d2": 0.0})
    with pytest.raises(ConfigError, match=r"^encoder\.f_number"):
        Lens({"f_number": -2})
    with pytest.raises(ConfigError, match=r"^encoder\.focus_distance"):
        Lens({"focus_distance": 0.0})
