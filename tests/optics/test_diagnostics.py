"""Sampling diagnostics: the numbers follow the stated formulas, warnings are given once, strict raises."""

import math
import warnings

import pytest

import optoenc.optics as o
from optoenc.errors import PhysicsError

SHAPE = (384, 512)
SPACING = (4.712e-3 / 384, 6.287e-3 / 512)


def test_paper_geometry_is_fine():
    r = o.sampling_report(SHAPE, SPACING, o.Spectrum.rgb().wavelengths, 4e-3, 0.4)
    assert r.ok, r.warnings
    assert r.band_removed == 0 and not r.subwavelength
    assert r.source_phase_step < math.pi
    assert r.padded_shape[0] >= SHAPE[0] and r.padded_shape[1] >= SHAPE[1]


def test_numbers_follow_the_formulas():
    shape, dx, lam, d = (64, 64), 4e-6, 500e-9, 40e-3
    r = o.sampling_report(shape, dx, lam, d, padding=32)
    n_p = 128
    assert r.padded_shape == (n_p, n_p)
    assert r.z_max == pytest.approx(n_p * dx**2 / lam * math.sqrt(1 - (lam / (2 * dx)) ** 2))
    assert r.fresnel_number == pytest.approx((64 * dx / 2) ** 2 / (lam * d))
    ulim = 1 / (lam * math.sqrt((2 * d / (n_p * dx)) ** 2 + 1))
    assert r.band_removed == pytest.approx(1 - (ulim * 2 * dx) ** 2)
    assert any("band limit removes" in w for w in r.warnings)
    assert o.sampling_report(shape, dx, lam, d, padding=32, method="asm").band_removed == 0


def test_source_phase_step_formula():
    shape, dx, lam, d1 = (65, 65), 10e-6, 500e-9, 0.05
    edge = 32 * dx
    k = 2 * math.pi / lam
    assert o.source_phase_step(shape, dx, lam, d1) == pytest.approx(k * dx * edge / math.hypot(edge, d1))
    assert o.source_phase_step(shape, dx, lam, math.inf) == 0


def test_out_of_range_cases_are_named():
    kinds = lambda **kw: set(o.sampling_report(**kw).kinds)  # noqa: E731
    base = dict(shape=(32, 32), spacing=5e-6, wavelength=550e-9, distance=1e-3)
    assert kinds(**base) == set()
    assert "source" in kinds(**base, d1=1e-3)
    assert "subwavelength" in kinds(**{**base, "spacing": 0.2e-6})
    assert "near" in kinds(**{**base, "distance": 0.1e-6})
    assert "aliasing" in kinds(**{**base, "distance": 1.0}, method="asm")
    assert "wraparound" in kinds(**{**base, "distance": 20e-3}, padding=0)
    assert "paraxial" in kinds(**{**base, "spacing": 0.5e-6, "distance": 20e-6}, method="fresnel")


def test_check_sampling_warns_once_and_strict_raises():
    kw = dict(shape=(17, 19), spacing=0.2e-6, wavelength=633e-9, distance=1e-5)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        o.check_sampling(**kw)
        o.check_sampling(**kw)
        o.check_sampling(**{**kw, "distance": 1.1e-5})  # same kind of problem, drifting distance: silent
    sampling = [w for w in caught if issubclass(w.category, o.SamplingWarning)]
    assert len(sampling) == 1 and "lambda/2" in str(sampling[0].message)
    with pytest.raises(PhysicsError, match="lambda/2"):
        o.check_sampling(**kw, strict=True)
    assert o.check_sampling(shape=(32, 32), spacing=5e-6, wavelength=550e-9, distance=1e-3, strict=True).ok
