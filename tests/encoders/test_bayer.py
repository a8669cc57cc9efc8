"""Colour sensors: the Bayer mosaic, its spectral weights, and the gray <-> colour scene rules."""

from __future__ import annotations

import pytest
import torch

import optoenc
from optoenc.decoders import FCNN
from optoenc.encoders.sensor import BAYER_RESPONSE, bayer_index, bayer_response, mosaic, to_luminance

FAST = {"preset": "fast"}


def _enc(name: str, color: str, **kw):
    return optoenc.build_encoder(name, fidelity=FAST, sensor={"color": color, **kw})


def test_mosaic_is_rggb_from_the_first_pixel():
    idx = bayer_index((3, 4))
    assert idx.tolist() == [[0, 1, 0, 1], [1, 2, 1, 2], [0, 1, 0, 1]]  # R G / G B


def test_spectral_weights_are_the_documented_cameras():
    """The stored table is colour-science's Nikon 5100 sensitivities at 640 / 550 / 460 nm (7 digits kept)."""
    assert torch.allclose(torch.tensor(BAYER_RESPONSE), torch.tensor(bayer_response()), atol=1e-7, rtol=0)
    assert max(sum(row) for row in BAYER_RESPONSE) == pytest.approx(1.0, abs=1e-6)


def test_bayer_reads_one_plane_the_mosaic_of_the_colour_planes():
    """Each pixel reads sum_c BAYER_RESPONSE[k, c] of the RGB sensor's planes, k its filter: exactly the RGB
    encoder's measurement, mixed and sampled (the same operator)."""
    x = torch.rand(2, 3, 28, 28, generator=torch.Generator().manual_seed(0))
    rgb, bayer = _enc("fixed_slm", "rgb"), _enc("fixed_slm", "bayer")
    y = bayer(x, noise=False)
    assert bayer.output_shape == (1, 24, 32) and y.shape == (2, 1, 24, 32)
    planes = rgb(x, noise=False)
    response = torch.tensor(BAYER_RESPONSE)
    r, c = 1, 2  # an odd row, an even column: a green pixel
    assert float(y[0, 0, r, c]) == pytest.approx(float(response[1] @ planes[0, :, r, c]), rel=1e-5)
    assert torch.allclose(y, mosaic(planes), rtol=1e-5, atol=1e-7)
    # the operator's dense matrix includes the mosaic
    op = bayer.operator((28, 28), scene_channels=3)
    assert torch.allclose(op.forward(x.double()).float(), y, rtol=1e-4, atol=1e-6)


def test_gray_scene_on_bayer_is_achromatic_light():
    """A uniform gray scene through the lens (a PSF of unit power per wavelength): a pixel behind filter k reads
    its row sum of the responses, 1 at green, 0.441 at red, 0.909 at blue, to the lens's 0.3 % tail."""
    y = _enc("lens", "bayer")(torch.ones(1, 1, 64, 64), noise=False)[0, 0]
    sums = torch.tensor(BAYER_RESPONSE).sum(1)
    centre = y[10:14, 14:18]
    expect = sums[bayer_index((24, 32))[10:14, 14:18]]
    assert torch.allclose(centre, expect.to(centre.dtype), rtol=0.01)


def test_rgb_scene_on_gray_sensor_is_its_luminance():
    """Rec. 709 linear weights, the datasets' rule: the gray sensor measures the scene's luminance; an RGB scene
    of gray pixels measures as the gray scene."""
    x = torch.rand(2, 3, 28, 28, generator=torch.Generator().manual_seed(1))
    enc = _enc("fixed_slm", "gray")
    lum = to_luminance(x)
    assert torch.allclose(lum[:, 0], 0.2126 * x[:, 0] + 0.7152 * x[:, 1] + 0.0722 * x[:, 2])
    assert torch.equal(enc(x, noise=False), enc(lum, noise=False))
    g = x[:, :1]
    assert torch.allclose(enc(g.expand(-1, 3, -1, -1), noise=False), enc(g, noise=False), rtol=1e-6)


def test_bayer_decoder_gets_one_channel_and_gradients_reach_the_mask():
    enc = _enc("learned_slm", "bayer")
    dec = FCNN(in_shape=enc.output_shape, num_classes=10, learnable_encoder=True)
    x = torch.rand(4, 3, 28, 28)
    y = enc(x)
    assert y.shape == (4, 1, 24, 32)
    torch.nn.functional.cross_entropy(dec(y), torch.arange(4)).backward()
    assert torch.isfinite(enc.logits.grad).all() and float(enc.logits.grad.abs().max()) > 0


def test_a_bayer_run_builds_its_decoder_on_the_one_plane():
    """The run's decoder reads the mosaic: a (1, a, b) embedding, as the precomputed embeddings are."""
    from optoenc.config import compose
    from optoenc.training.run import build

    run = compose(overrides=["sensor.color=bayer", "sensor.embedding=[6,8]", "fidelity.preset=fast",
                             "dataset.train_size=20", "dataset.val_size=10", "dataset.test_size=10"],
                  names={"encoder": "fixed_slm", "decoder": "fcnn"})
    parts = build(run)
    assert parts.module.encoder.output_shape == (1, 6, 8)
    x, _ = next(iter(parts.loaders["train"]))[:2]
    assert parts.module.embed(x).shape[1:] == (1, 6, 8)
    assert parts.module.decoder(parts.module.embed(x)).shape == (len(x), 10)
