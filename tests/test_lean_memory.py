"""Memory-lean paths give the same numbers: the FFT correlation tensor and the per-wavelength propagation of large fields."""

from __future__ import annotations

import pytest
import torch

from optoenc.encoders import imaging as im

DT = torch.float64


def brute_correlation(box: torch.Tensor, place: torch.Tensor, n_psf: int, sub: int) -> torch.Tensor:
    """``R[a, p, k]``: the documented definition, by loops (the PSF cell ``k`` spread evenly over ``sub`` fine cells)."""
    n_out, n_grid = box.shape
    n_scene = place.shape[1]
    c = (n_psf // 2) * sub + sub // 2  # the PSF axis on the fine grid
    out = torch.zeros(n_out, n_scene, n_psf, dtype=DT)
    for k in range(n_psf):
        for f in range(sub):
            shift = k * sub + f - c  # fine-cell offset of this sub-cell of PSF cell k from the axis
            for y in range(n_grid):
                if 0 <= y - shift < n_grid:
                    out[:, :, k] += box[:, y, None] * place[y - shift][None, :] / sub
    return out


@pytest.mark.parametrize("n_grid,n_out,n_psf,sub,height,sampling", [
    (24, 4, 24, 1, 9.3, "box"), (30, 5, 13, 1, 7.0, "box"), (12, 3, 20, 1, 5.5, "point"),
    (10, 2, 10, 3, 4.1, "box"), (8, 4, 8, 5, 6.6, "point"),
])  # fmt: skip
def test_correlation_tensor_matches_its_definition(n_grid, n_out, n_psf, sub, height, sampling):
    place = im.placement_matrices((5, 5), (n_grid * sub, n_grid * sub), height * sub)[0]
    box = im.sampling_matrix(n_grid * sub, n_out, sampling)
    got = im.correlation_tensor(box, place, n_psf, sub=sub)
    # float64 FFT correlation: rounding ~1e-16 of the largest entry; 1e-12 leaves margin.
    torch.testing.assert_close(got, brute_correlation(box, place, n_psf, sub), rtol=0, atol=1e-12 * float(box.max()))


@pytest.mark.parametrize("sampling", ["box", "point"])
def test_correlation_tensor_holds_exact_zeros_not_rounding_noise(sampling):
    # The geometry of the 24x32 learned-SLM augmentation canvas along one axis (288-pixel PSF grid, a
    # 109-pixel canvas): the FFT left ~1e-35 where the answer is 0, whose float32 products with a PSF are
    # subnormal (10x slower matrix products on x86). Every entry is now 0 or a real overlap: the
    # smallest possible nonzero overlap here is far above 1e-12 of the largest (slivers of 1/109 pixel).
    place = im.placement_matrices((109, 146), (288, 384), 286.0)[0]
    got = im.correlation_tensor(im.sampling_matrix(288, 24, sampling), place, 288)
    nonzero = got[got != 0].abs()
    assert nonzero.numel() > 0 and float(nonzero.min()) > 1e-12 * float(got.abs().max())
    assert not bool((got.to(torch.float32) * 1e-5).abs().lt(torch.finfo(torch.float32).tiny).logical_and(got != 0).any())


@pytest.mark.filterwarnings("ignore:optics sampling")  # a 48 x 64 grid aliases the source; the same in both
def test_large_fields_propagate_one_wavelength_at_a_time_with_the_same_psf(monkeypatch):
    from optoenc.bench import settings as bench_settings
    from optoenc.encoders import mask as mask_mod

    calls = []
    real = mask_mod.intensity_psf
    monkeypatch.setattr(mask_mod, "intensity_psf", lambda m, wl, *a, **k: calls.append(len(wl)) or real(m, wl, *a, **k))
    s = bench_settings.Setting("w", "sweep", (48, 64), "float64", "auto", oversample=3)
    batched = bench_settings.build_encoder("coded_aperture", s, (6, 8)).psf()
    assert calls == [3]  # a small field: all wavelengths in one FFT batch
    calls.clear()
    monkeypatch.setattr(mask_mod, "AUTO_CHUNK_SAMPLES", 0)  # every field is "large"
    chunked = bench_settings.build_encoder("coded_aperture", s, (6, 8)).psf()
    assert calls == [1, 1, 1]
    # the same propagation per wavelength (its own auto padding): float rounding apart
    torch.testing.assert_close(chunked, batched, rtol=1e-12, atol=0)
