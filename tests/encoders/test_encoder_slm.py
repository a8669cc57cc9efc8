"""Physics of the ST7735R LCD encoders (`fixed_slm`, `learned_slm`)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from optoenc.encoders import imaging
from optoenc.encoders.operator import apply_operator, scene_operator
from optoenc import devices as K
from optoenc.encoders import slm_panel
from optoenc.encoders.slm import FixedSLM, LearnedSLM, panel_image
from optoenc.errors import ConfigError

# The 48 x 64 grid (98 um pixels) aliases the spherical source wave; that is expected at this
# size and irrelevant to the layout and gradient properties checked here.
pytestmark = pytest.mark.filterwarnings("ignore::optoenc.optics.SamplingWarning")

SMALL = {"fidelity": {"grid": (48, 64)}, "sensor": {"embedding": (6, 8)}}
# A 0.37 x 0.50 mm sensor: a 4 x 1 sub-pixel block on a (12, 16) float64 grid, for gradcheck.
TINY = {
    "fidelity": {"grid": (12, 16), "dtype": "float64"},
    "sensor": {"embedding": (3, 4), "resolution": (240, 320)},
    "scene": {"object_height": 0.03},
}


def test_device_constants():
    # Derived values of REFERENCE §2, to the digits quoted there.
    assert K.ST7735R_SUBPIXELS == (384, 160)
    assert K.ST7735R_PITCH == pytest.approx((73.03e-6, 219.25e-6), abs=0.01e-6)
    assert K.ST7735R_FILL_FACTOR == pytest.approx(0.675, abs=5e-4)


@pytest.mark.parametrize("grid", [(48, 64), (200, 301), (384, 512)])
def test_fill_factor_is_resolution_independent(grid):
    enc = FixedSLM(fidelity={"grid": grid})
    dy, dx = enc.geometry.spacing
    ones = torch.ones(enc.block.shape, dtype=torch.float64)
    mask = slm_panel.rasterise(ones, enc.block, enc.geometry.grid, enc.geometry.spacing)
    block_area = enc.block.rows * K.ST7735R_PITCH[0] * enc.block.cols * K.ST7735R_PITCH[1]
    fill = float(mask.sum()) * dy * dx / block_area
    # 1 %: the required tolerance; exact fractional areas make it ~1e-12 at any grid.
    assert fill == pytest.approx(0.675, rel=0.01)
    # 1e-9: rasterisation is exact, so only rounding differs between grids.
    assert fill == pytest.approx(K.ST7735R_FILL_FACTOR, rel=1e-9)


def test_active_block_is_51_by_22_centred():
    enc = LearnedSLM(**SMALL)
    assert enc.block.shape == (51, 22)
    assert enc.logits.numel() == 1122
    panel = enc.mask()
    assert panel.shape == (384, 160)
    assert int((panel > 0).sum()) == 1122
    rows, cols = torch.nonzero(panel > 0, as_tuple=True)
    # centred on the panel (to the half sub-pixel an odd/even split allows)
    assert abs((int(rows.min()) + int(rows.max())) / 2 - 191.5) <= 0.5
    assert abs((int(cols.min()) + int(cols.max())) / 2 - 79.5) <= 0.5


def test_subpixel_row_k_carries_colour_k_mod_3():
    enc = FixedSLM(**SMALL)
    b = enc.block
    eye = torch.eye(b.rows, dtype=torch.float64)
    for j in range(b.rows):  # one active row at a time: 51 tiny matrix products
        w = eye[j][:, None].expand(b.rows, b.cols)
        m = slm_panel.rasterise(w, b, enc.geometry.grid, enc.geometry.spacing)
        energy = m.sum(dim=(1, 2))
        k = b.row0 + j
        assert energy[k % 3] > 0 and int((energy > 0).sum()) == 1, (k, energy)


def test_panel_image_maps_subpixel_rows_to_rgb():
    enc = FixedSLM(**SMALL)
    img = panel_image(enc)
    assert img.shape == (128, 160, 3) and img.dtype == np.uint8
    panel = enc.mask().numpy()
    for k in range(enc.block.row0, enc.block.row0 + enc.block.rows):
        i, c = divmod(k, 3)
        np.testing.assert_array_equal(img[i, :, c], np.round(panel[k] * 255).astype(np.uint8))
    assert img[: enc.block.row0 // 3].max() == 0  # opaque outside the block


def test_digit_size_on_the_grid():
    # REFERENCE §2: ~97 px for d2 = 4 mm on the ~12.3 um (384 x 512) grid; 0.5 px: rounding of the quoted value.
    assert FixedSLM(fidelity={"grid": (384, 512)}).object_height_px() == pytest.approx(97.8, abs=0.5)
    # the SLM's own default grid (288 x 384, ~16.4 um) scales it: same physical size
    assert FixedSLM().object_height_px() == pytest.approx(97.8 * 288 / 384, abs=0.5)


def test_pattern_seed_and_files(tmp_path):
    a, b, c = FixedSLM({"seed": 1}, **SMALL), FixedSLM({"seed": 1}, **SMALL), FixedSLM({"seed": 2}, **SMALL)
    assert torch.equal(a.mask(), b.mask()) and not torch.equal(a.mask(), c.mask())
    block = np.random.default_rng(5).uniform(size=(51, 22))
    np.save(tmp_path / "block.npy", block)
    panel = np.zeros((384, 160))
    panel[166:217, 69:91] = block
    np.save(tmp_path / "panel.npy", panel)
    m1 = FixedSLM({"pattern_path": str(tmp_path / "block.npy")}, **SMALL).mask()
    m2 = FixedSLM({"pattern_path": str(tmp_path / "panel.npy")}, **SMALL).mask()
    assert torch.equal(m1, m2) and torch.equal(m1, torch.from_numpy(panel))
    np.save(tmp_path / "bad.npy", np.zeros((10, 10)))
    with pytest.raises(ConfigError, match="encoder.pattern_path"):
        FixedSLM({"pattern_path": str(tmp_path / "bad.npy")}, **SMALL)


def test_validation_messages():
    for cls in (FixedSLM, LearnedSLM):
        with pytest.raises(ConfigError, match=r"^encoder\.d2 = 0(\.0)?: must be > 0") as err:
            cls({"d2": 0.0})
        assert "\n" not in str(err.value)
    with pytest.raises(ConfigError, match="encoder.active_subpixels.*larger than the panel"):
        FixedSLM({"active_subpixels": (400, 22)})
    with pytest.raises(ConfigError, match="encoder.pattern_path.*not found"):
        LearnedSLM({"pattern_path": "/nonexistent/pattern.npy"})
    with pytest.raises(ConfigError, match="encoder.quantize"):
        FixedSLM({"quantize": "rgb888"})


def test_rgb565_levels_per_colour():
    enc = FixedSLM({"quantize": "rgb565"}, **SMALL)
    panel = enc.mask().numpy()
    for k in range(enc.block.row0, enc.block.row0 + enc.block.rows):
        levels = 2 ** K.ST7735R_RGB565_BITS[k % 3] - 1
        # 1e-9: the quantised values are exact multiples of 1/levels up to rounding.
        np.testing.assert_allclose(panel[k] * levels, np.round(panel[k] * levels), atol=1e-9)


def test_learned_gradients_finite_at_range_ends():
    enc = LearnedSLM({"quantize": "rgb565", "learn_d2": True}, **SMALL)
    with torch.no_grad():
        enc.logits.copy_(torch.where(torch.rand(enc.logits.shape) > 0.5, 30.0, -30.0))
        enc.logits[0, 0] = 0.0  # keep some light-level variety
    scene = torch.rand(2, 1, 8, 6, generator=torch.Generator().manual_seed(0))
    out = enc(scene, noise=False)
    (out * torch.linspace(-1, 1, out.numel()).reshape(out.shape)).sum().backward()
    g = enc.logits.grad
    assert torch.isfinite(g).all() and torch.isfinite(enc.log_d2_scale.grad)
    # sigmoid'(+-30) = 9.4e-14 in float64: small but never exactly zero (no clamping).
    assert (g != 0).float().mean() > 0.9
    assert enc.log_d2_scale.grad != 0


def test_learned_gradcheck_float64():
    enc = LearnedSLM(**TINY)
    assert enc.block.shape == (4, 1)
    scene = torch.rand(1, 1, 4, 4, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    ry, rx, _ = enc._operators.geometry_factors(enc, (4, 4), enc.object_height_px(), scene.device)
    base = enc.logits.detach().clone()

    def embed(sub):
        full = torch.cat([sub, base[2:]], dim=0)
        enc.displayed_amplitudes = lambda: torch.sigmoid(full)  # instance override: bypasses the PSF cache
        gray = imaging.sensor_psf(enc.compute_psf(), 1)
        return apply_operator(scene_operator(gray, ry, rx), scene)

    sub = base[:2].clone().requires_grad_(True)
    # gradcheck's own float64 tolerances (finite differences with eps 1e-6).
    assert torch.autograd.gradcheck(embed, (sub,), eps=1e-6, atol=1e-8, rtol=1e-5)


def test_saturated_sigmoid_sub_pixel_is_stuck_under_adam_and_a_projected_one_is_not():
    # The measured failure (docs/notes/projected-mask.md): a sub-pixel whose logit reached -10 gets its amplitude's
    # gradient times w (1 - w) ~ 4.5e-5; for amplitude gradients of 1e-4 (a closed sub-pixel's were 5e-6 to 2e-2
    # in training) that is 4.5e-9, below Adam's eps (1e-8), and 100 steps at the mask's rate (1e-2) barely move
    # it. The projected amplitude, at the same place with the same gradient, moves ~lr a step, to the bound.
    # (The loss is on the amplitudes directly: the PSF's per-colour power normalisation makes "more light" no
    # objective through the optics.)
    moved = {}
    for kind in ("sigmoid", "projected"):
        enc = LearnedSLM({"parameterization": kind}, **SMALL)
        with torch.no_grad():
            if kind == "sigmoid":
                enc.logits.fill_(-10.0)
            else:
                enc.amplitudes.fill_(torch.sigmoid(torch.tensor(-10.0, dtype=torch.float64)).item())
        w0 = enc.displayed_amplitudes().detach().clone()
        opt = torch.optim.Adam(enc.parameters(), lr=1e-2)
        for _ in range(100):
            opt.zero_grad()
            (-1e-4 * enc.displayed_amplitudes().sum()).backward()  # every amplitude should rise
            opt.step()
            enc.constrain_()
        moved[kind] = (enc.displayed_amplitudes().detach() - w0).mean().item()
    assert moved["sigmoid"] < 1e-4  # w from 4.5e-5 to about 6e-5: Adam's eps dominates its denominator
    assert moved["projected"] > 0.99  # 100 steps of 1e-2 up to the bound at 1


def test_projected_amplitudes_stay_in_range_with_full_gradient_at_the_bounds():
    with_d2 = LearnedSLM({"parameterization": "projected", "learn_d2": True}, **SMALL)  # d2 learned beside it
    out = with_d2(torch.rand(2, 1, 8, 6), noise=False)
    (out * torch.randn_like(out)).sum().backward()
    assert with_d2.log_d2_scale.dtype == torch.float64 and torch.isfinite(with_d2.log_d2_scale.grad)
    two = LearnedSLM({"parameterization": "projected", "patterns": 2}, **SMALL)
    assert not hasattr(two, "logits") and two.amplitudes.shape == (2, *two.block.shape)
    torch.testing.assert_close(two.amplitudes.detach()[0], two.initial_pattern(), rtol=0, atol=0)  # pattern 0 as K = 1
    enc = LearnedSLM({"parameterization": "projected"}, **SMALL)
    opt = torch.optim.SGD(enc.parameters(), lr=1e6)  # a step far past both bounds
    out = enc(torch.rand(2, 1, 8, 6), noise=False)
    (out * torch.randn_like(out)).sum().backward()
    opt.step()
    enc.constrain_()
    a = enc.amplitudes.detach()
    assert a.min() >= 0 and a.max() <= 1 and ((a == 0) | (a == 1)).float().mean() > 0.5
    # at a bound the gradient is the amplitude's own (no sigmoid factor): non-zero, and the weights are
    # the amplitudes (no clamping inside forward)
    enc.zero_grad()
    out = enc(torch.rand(2, 1, 8, 6), noise=False)
    (out * torch.linspace(-1, 1, out.numel()).reshape(out.shape)).sum().backward()
    assert (enc.amplitudes.grad != 0).float().mean() > 0.9
    assert torch.equal(enc.displayed_amplitudes(), enc.amplitudes)


def test_learned_psf_recomputed_once_per_step_and_d2():
    enc = LearnedSLM({"learn_d2": True}, **SMALL)
    enc.train()
    assert enc.psf() is enc.psf()  # cached between steps
    opt = torch.optim.SGD(enc.parameters(), lr=1.0)
    out = enc(torch.rand(2, 1, 8, 6), noise=False)
    (out * torch.randn_like(out)).sum().backward()
    before = enc.psf()
    opt.step()
    assert enc.psf() is not before  # the step invalidates it
    assert enc.d2 != pytest.approx(4e-3, rel=1e-12) and enc.d2 > 0
    assert enc.magnification == pytest.approx(enc.d2 / 0.4)  # magnification follows the learned d2


def test_learned_d2_keeps_the_correlations_while_d2_is_unchanged(monkeypatch):
    """learn_d2 with d2 unchanged: three measurements build the scene correlations once.

    (A subclass override once dropped the base class's cache entry on every call: 3 builds, 6 tensors.)
    """
    builds = []
    real = imaging.correlation_tensor
    monkeypatch.setattr(imaging, "correlation_tensor", lambda *a, **k: builds.append(1) or real(*a, **k))
    enc = LearnedSLM({"learn_d2": True}, **SMALL)
    x = torch.rand(2, 1, 8, 6)
    with torch.no_grad():
        outs = [enc.measure(x) for _ in range(3)]
    assert len(builds) == 2  # one row and one column correlation tensor, built once
    assert torch.equal(outs[0], outs[2])
    with torch.no_grad():  # a changed d2 is a new geometry: built again
        enc.log_d2_scale.fill_(0.1)
        enc.measure(x)
    assert len(builds) == 4


@pytest.mark.parametrize("scale", [0.01, 1.0])
def test_learned_d2_steps_at_its_own_rate(scale):
    """Adam moves each parameter by about its learning rate per step, whatever its gradient: log d2 gets
    ``d2_lr_scale`` x the encoder's rate (at the mask's own rate d2 drifted from 4 to 0.3 mm in one epoch)."""
    from optoenc.decoders import Logistic
    from optoenc.training.module import EncoderDecoderModule

    enc = LearnedSLM({"learn_d2": True, "d2_lr_scale": scale}, **SMALL)
    module = EncoderDecoderModule(enc, Logistic(None, in_shape=enc.output_shape), [], lr=1e-3, encoder_lr=1e-2)
    opt = module.configure_optimizers()
    lrs = {id(p): g["lr"] for g in opt.param_groups for p in g["params"]}
    assert lrs[id(enc.logits)] == pytest.approx(1e-2) and lrs[id(enc.log_d2_scale)] == pytest.approx(1e-2 * scale)
    assert len(lrs) == sum(1 for _ in module.parameters())  # every parameter in exactly one group
    torch.manual_seed(0)
    x, y = torch.rand(8, 1, 8, 6), torch.randint(0, 10, (8,))
    for _ in range(3):
        opt.zero_grad()
        torch.nn.functional.cross_entropy(module(x), y).backward()
        opt.step()
    # Adam's step t is lr * m_t / sqrt(v_t) (bias-corrected); by Cauchy-Schwarz |m_t| / sqrt(v_t) <=
    # sqrt(sum_i w_i^2 / u_i) over the two averages' weights: 1, 1.0013 and 1.0036 for steps 1-3 with
    # betas (0.9, 0.999). So three steps move log d2 by at most 3.005 lr, whatever the gradients: 1.01 x 3 lr.
    assert 0 < abs(float(enc.log_d2_scale)) <= 3 * 1e-2 * scale * 1.01


def test_pattern_range_draws_within_it_and_the_default_is_the_plain_uniform_draw():
    """encoder.pattern_range = (low, high): the seeded draw is low + (high - low) u with the same u as the
    default (0, 1) draw (numpy's uniform), so the default pattern is unchanged to the bit; low > high is
    refused naming the setting."""
    plain = LearnedSLM(**SMALL).initial_pattern()
    u = np.random.default_rng(0).uniform(0.0, 1.0, plain.shape)
    assert torch.equal(plain, torch.from_numpy(u))
    half = LearnedSLM({"pattern_range": (0.45, 0.55)}, **SMALL)
    w = half.initial_pattern()
    assert 0.45 <= w.min() and w.max() <= 0.55 and w.max() - w.min() > 0.09  # 1122 draws span the range
    assert torch.allclose(half.initial_pattern(), torch.from_numpy(0.45 + 0.1 * u), rtol=0, atol=1e-15)
    assert torch.equal(FixedSLM({"pattern_range": (0.2, 0.2)}, **SMALL).displayed_amplitudes(), torch.full(plain.shape, 0.2, dtype=plain.dtype))
    with pytest.raises(ConfigError, match=r"encoder.pattern_range = \[0.6, 0.4\]: must be \(low, high\) with low <= high"):
        LearnedSLM({"pattern_range": (0.6, 0.4)}, **SMALL)
    with pytest.raises(ConfigError, match="pattern_range"):
        LearnedSLM({"pattern_range": (-0.1, 0.4)}, **SMALL)
