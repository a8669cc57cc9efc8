"""Tests of the example plugin: optoenc's conformance kit plus the pinhole's own physics."""

from __future__ import annotations

import math

import pytest
import torch

from optoenc.testing import EncoderConformance, check_encoder
from optoenc_example import plugin
from optoenc_example.pinhole import GAUSS_AIRY, Pinhole, pinhole_psf

D1, D2, WL = 0.40, 4e-3, 550e-9


class TestPinholeConformance(EncoderConformance):
    """Every optoenc conformance check, on a small grid."""

    encoder_cls = Pinhole
    setup = {"fidelity": {"grid": (48, 64)}, "sensor": {"embedding": (6, 8)}}


def _second_moment(psf: torch.Tensor, spacing) -> float:
    """<r^2> of a PSF centred at (H // 2, W // 2), metres^2."""
    H, W = psf.shape
    y = (torch.arange(H, dtype=torch.float64) - H // 2) * spacing[0]
    x = (torch.arange(W, dtype=torch.float64) - W // 2) * spacing[1]
    p = psf / psf.sum()
    return float((p * (y[:, None] ** 2 + x[None, :] ** 2)).sum())


def test_geometric_shadow_is_the_scaled_hole():
    """No diffraction: a uniform disk of radius R = D (d1 + d2) / (2 d1), <r^2> = R^2 / 2 (+ pixel variance)."""
    D, spacing = 600e-6, (20e-6, 20e-6)
    psf = pinhole_psf(D, D1, D2, WL, spacing, (96, 128), diffraction=False)
    R = 0.5 * D * (D1 + D2) / D1
    expected = R**2 / 2 + (spacing[0] ** 2 + spacing[1] ** 2) / 12
    assert _second_moment(psf, spacing) == pytest.approx(expected, rel=0.01)


def test_tiny_hole_is_diffraction_limited():
    """A 10 um hole: the Gaussian diffraction blur dominates, <r^2> ~ 2 sigma^2 + R^2 / 2."""
    D, spacing = 10e-6, (20e-6, 20e-6)
    psf = pinhole_psf(D, D1, D2, WL, spacing, (96, 128))
    sigma = GAUSS_AIRY * WL * D2 / D
    R = 0.5 * D * (D1 + D2) / D1
    expected = 2 * sigma**2 + R**2 / 2 + (spacing[0] ** 2 + spacing[1] ** 2) / 12
    assert _second_moment(psf, spacing) == pytest.approx(expected, rel=0.02)


def test_psf_is_centred_and_symmetric():
    psf = pinhole_psf(75e-6, D1, D2, WL, (12e-6, 12e-6), (64, 64))
    peak = divmod(int(psf.argmax()), 64)
    assert peak == (32, 32)
    inner = psf[1:, 1:]  # the grid is symmetric about index 32 once row/column 0 is dropped
    assert torch.allclose(inner, inner.flip(0), atol=1e-12 * float(psf.max()))
    assert torch.allclose(inner, inner.T, atol=1e-12 * float(psf.max()))


def test_optimal_hole_is_sharpest():
    """Rayleigh: the blur is smallest near D = sqrt(2.44 lambda d2)."""
    spacing = (4e-6, 4e-6)
    best = math.sqrt(2.44 * WL * D2)
    widths = {D: _second_moment(pinhole_psf(D, D1, D2, WL, spacing, (128, 128)), spacing) for D in (best / 3, best, best * 3)}
    assert widths[best] < widths[best / 3] and widths[best] < widths[best * 3]


def test_plugin_registers_the_encoder():
    from optoenc.plugins import PluginHost

    host = PluginHost(entry_points=False)
    info = host.add(plugin, name="example")
    assert info.ok, info.error
    assert info.registered == {"encoder": ["pinhole"]}
    assert host.registry("encoder").get("pinhole") is Pinhole


def test_check_encoder_function():
    report = check_encoder(Pinhole, fidelity={"grid": (24, 32)}, sensor={"embedding": (6, 8)}, checks=["psf", "linearity"])
    assert report == {"psf": "ok", "linearity": "ok"}
