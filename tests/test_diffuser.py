"""The measured-PSF diffuser: file handling, resampling, and the imaging extremes through a real encoder."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from PIL import Image

from optoenc.encoders.diffuser import Diffuser
from optoenc.errors import ConfigError
from optoenc.encoders import psf_files

SMALL = {"fidelity": {"grid": (48, 64)}, "sensor": {"embedding": (6, 8)}}


def test_bundled_psf_is_background_subtracted_and_normalised():
    enc = Diffuser(fidelity={"grid": (384, 512)})
    psf = enc.psf()
    assert psf.shape == (1, 384, 512)
    assert Diffuser().psf().shape == (1, 576, 768)  # the diffuser's own measured default grid
    torch.testing.assert_close(psf.sum(), torch.tensor(1.0), rtol=1e-5, atol=0)  # float32 sum of 2e5 values
    # dark corners: after subtracting the corner mean and clipping, the corners hold almost no energy
    corner = psf[0, :24, :32].sum() + psf[0, -24:, -32:].sum()
    assert corner < 1e-3


def test_area_resampling_conserves_energy():
    raw = np.random.default_rng(0).random((1, 120, 160))
    out = psf_files.resample_area(raw, (48, 64))
    # each output pixel averages (2.5 x 2.5) input pixels: total scales by the area ratio exactly
    torch.testing.assert_close(out.sum(), torch.tensor(raw.sum() * (48 * 64) / (120 * 160), dtype=torch.float64))


@pytest.mark.parametrize("suffix", [".npy", ".png", ".tif"])
def test_psf_path_reads_npy_png_tiff(tmp_path, suffix):
    psf = np.zeros((30, 40), dtype=np.uint16)
    psf[10:20, 15:25] = 1000
    path = tmp_path / f"psf{suffix}"
    if suffix == ".npy":
        np.save(path, psf.astype(np.float32))
    else:
        Image.fromarray(psf).save(path)
    enc = Diffuser({"psf_path": str(path), "background": 0.0}, **SMALL)
    p = enc.psf()[0]
    assert p.shape == (48, 64) and torch.isfinite(p).all()
    ys, xs = torch.nonzero(p > 0, as_tuple=True)
    # the 10 x 10 block of a 30 x 40 file spans rows 16..32 and columns 24..40 of the 48 x 64 grid
    assert ys.min() == 16 and ys.max() == 31 and xs.min() == 24 and xs.max() == 39


@pytest.mark.parametrize(
    "content,message",
    [
        (np.zeros((30, 40)), "all zero"),
        (np.full((30, 40), np.nan), "NaN"),
        (np.ones(40), "shape"),
        (np.random.default_rng(0).random((30, 90)), "aspect ratio"),
    ],
)
def test_bad_psf_files_give_clear_errors(tmp_path, content, message):
    path = tmp_path / "bad.npy"
    np.save(path, content)
    with pytest.raises(ConfigError, match=message) as err:
        Diffuser({"psf_path": str(path)}, **SMALL).psf()
    assert "psf_path" in str(err.value) and "\n" not in str(err.value)


def test_unreadable_and_missing_files(tmp_path):
    junk = tmp_path / "junk.png"
    junk.write_bytes(b"not a png")
    with pytest.raises(ConfigError, match="unreadable"):
        Diffuser({"psf_path": str(junk)}, **SMALL).psf()
    with pytest.raises(ConfigError, match="not found"):
        Diffuser({"psf_path": str(tmp_path / "none.tif")}, **SMALL)
    txt = junk.with_suffix(".txt")
    txt.write_text("1 2 3")
    with pytest.raises(ConfigError, match="must be a"):
        Diffuser({"psf_path": str(txt)}, **SMALL).psf()


def test_negative_distance_names_the_field_and_range():
    with pytest.raises(ConfigError, match=r"encoder\.d2 = -0\.004: must be > 0 m"):
        Diffuser({"d2": -4e-3})


@pytest.mark.parametrize("emb", [(1, 1), (3, 4), (48, 64)])
def test_embeddings_from_one_pixel_to_the_full_grid(emb):
    enc = Diffuser(fidelity={"grid": (48, 64)}, sensor={"embedding": emb})
    x = torch.rand(2, 1, 28, 28)
    out = enc(x)
    assert out.shape == (2, 1, *emb) and torch.isfinite(out).all()
    # operator and fine-grid paths agree (float32 rounding of sums of ~1e3 terms)
    torch.testing.assert_close(enc.measure(x, method="operator"), enc.measure(x, method="direct"), rtol=1e-4, atol=1e-6)


def test_dark_scene_and_extreme_snr_are_finite():
    for snr in (-10.0, 100.0, None):
        enc = Diffuser(sensor={"snr_db": snr}, **{"fidelity": {"grid": (48, 64)}})
        assert torch.equal(enc(torch.zeros(2, 1, 28, 28)), torch.zeros(2, 1, 24, 32))
        assert torch.isfinite(enc(torch.rand(2, 1, 28, 28))).all()


def test_tiny_and_huge_objects():
    enc = Diffuser(**SMALL)
    tiny = enc.measure(torch.ones(1, 1, 28, 28), height=1e-4)  # far below one grid pixel
    assert torch.isfinite(tiny).all() and tiny.sum() > 0
    with pytest.warns(UserWarning, match="cropped"):
        huge = enc.measure(torch.ones(1, 1, 28, 28), height=2.0)  # larger than the field of view
    assert torch.isfinite(huge).all()


@pytest.mark.parametrize("s", [1, 3])
def test_operator_equals_fine_grid_pipeline_with_subpixel_geometry(s):
    """Both imaging paths implement the same model, also when psf_oversample keeps the scene's
    sub-pixel structure (odd grid to exercise the centring). float64: rounding only."""
    enc = Diffuser(fidelity={"grid": (45, 60), "dtype": "float64", "psf_oversample": s}, sensor={"embedding": (5, 6)})
    x = torch.rand(2, 1, 28, 28, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    torch.testing.assert_close(enc.measure(x, method="operator"), enc.measure(x, method="direct"), rtol=1e-10, atol=1e-12)
