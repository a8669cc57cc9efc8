"""The encoder API a library user calls: clear errors for bad scenes, ``.to(dtype)``, the mask accessors,
the learned SLM's start, and the scene operator as a matrix."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from optoenc.encoders.coded_aperture import CodedAperture
from optoenc.encoders.lens import Lens
from optoenc.encoders.operator import SceneOperator
from optoenc.encoders.slm import EDGE_LOGIT, FixedSLM, LearnedSLM
from optoenc.errors import ConfigError, DataError

pytestmark = pytest.mark.filterwarnings("ignore")  # the small grid's sampling warning

SMALL = {"fidelity": {"grid": (48, 64)}, "sensor": {"embedding": (6, 8)}}


def test_negative_scene_is_one_clear_error():
    enc = Lens(**SMALL)
    x = torch.rand(2, 1, 28, 28)
    x[1, 0, 3, 4] = -0.25
    with pytest.raises(DataError, match=r"^scene minimum = -0\.25: must be >= 0 \(intensities\)$"):
        enc(x, noise=False)
    with pytest.raises(DataError, match="must be >= 0"):
        enc.operator((40, 52)).apply_window(-torch.rand(2, 1, 5, 5), (3, 3))
    assert enc.measure(torch.zeros(1, 1, 28, 28)).abs().max() == 0  # zero (and -0.0) is an intensity


def test_channel_mismatch_follows_the_documented_rule():
    """An RGB scene on a gray sensor is measured as its Rec. 709 luminance, a gray scene on an RGB sensor as
    achromatic light; a scene that is neither gray nor R, G, B is refused."""
    x = torch.rand(1, 3, 28, 28)
    gray = Lens(**SMALL)
    luminance = (x * torch.tensor([0.2126, 0.7152, 0.0722])[:, None, None]).sum(1, keepdim=True)
    assert torch.equal(gray.measure(x), gray.measure(luminance))
    rgb = Lens(fidelity=SMALL["fidelity"], sensor={"embedding": (6, 8), "color": "rgb"})
    with pytest.raises(ConfigError) as err:
        rgb.measure(torch.rand(1, 2, 28, 28))
    assert str(err.value) == "scene channels = 2: must be 1 (gray) or 3 (R, G, B), whatever the sensor (sensor.color)"
    assert rgb.measure(x).shape == (1, 3, 6, 8)


def test_to_float64_moves_the_optics_and_gives_the_float64_encoders_numbers():
    """``.double()`` computes in float64 as an encoder built with ``fidelity.dtype=float64`` does: the same
    PSF and embeddings to the bit (the lens has no parameters: nothing is rounded through float32)."""
    x = torch.rand(3, 1, 28, 28, dtype=torch.float64)
    enc = Lens(**SMALL)
    with torch.no_grad():
        enc.measure(x.float())  # caches a float32 PSF and operator, which the conversion must drop
    enc = enc.double()
    ref = Lens(fidelity={**SMALL["fidelity"], "dtype": "float64"}, sensor=SMALL["sensor"])
    assert enc.optics_dtype == enc.operator_dtype == torch.float64 and enc.knobs == ref.knobs
    with torch.no_grad():
        assert torch.equal(enc.psf(), ref.psf()) and torch.equal(enc.measure(x), ref.measure(x))
    back = enc.float()
    assert back.optics_dtype == torch.float32 and back.psf().dtype == torch.float32
    with pytest.raises(ConfigError, match=r"^encoder dtype = 'bfloat16': the optics compute in float32 or float64"):
        enc.bfloat16()


def test_learned_mask_to_float64_has_float64_optics_and_gradients():
    enc = LearnedSLM(**SMALL).to(torch.float64)
    assert enc.optics_dtype == torch.float64 and enc.logits.dtype == torch.float64
    out = enc(torch.rand(2, 1, 28, 28, dtype=torch.float64), noise=False)
    assert out.dtype == torch.float64 and enc.psf().dtype == torch.float64
    out.sum().backward()
    assert torch.isfinite(enc.logits.grad).all()
    bf16 = LearnedSLM({}, fidelity={**SMALL["fidelity"], "operator_dtype": "bfloat16"}, sensor=SMALL["sensor"]).double()
    assert bf16.operator_dtype == torch.bfloat16  # an explicit operator precision is kept


@pytest.mark.parametrize("seed", [0, 3])
def test_learned_slm_starts_from_fixed_slms_pattern(seed):
    """The same displayed amplitudes (sigmoid: to float64 rounding, 1.1e-16 measured; projected: exactly) and,
    through the float32 optics, the same embeddings to the bit."""
    fixed = FixedSLM({"seed": seed}, **SMALL)
    sig = LearnedSLM({"seed": seed}, **SMALL)
    proj = LearnedSLM({"seed": seed, "parameterization": "projected"}, **SMALL)
    w = fixed.displayed_amplitudes()
    torch.testing.assert_close(sig.displayed_amplitudes().detach(), w, rtol=0, atol=2.3e-16)
    assert torch.equal(proj.displayed_amplitudes().detach(), w)
    x = torch.rand(4, 1, 28, 28, generator=torch.Generator().manual_seed(seed))
    with torch.no_grad():
        assert torch.equal(sig(x, noise=False), fixed(x, noise=False))


def test_pattern_values_of_exactly_0_and_1_start_at_finite_logits(tmp_path):
    pattern = np.random.default_rng(0).uniform(0, 1, LearnedSLM(**SMALL).block.shape)
    pattern[0, 0], pattern[1, 1] = 0.0, 1.0
    np.save(tmp_path / "p.npy", pattern)
    enc = LearnedSLM({"pattern_path": str(tmp_path / "p.npy")}, **SMALL)
    assert torch.isfinite(enc.logits).all() and enc.logits[0, 0] == -EDGE_LOGIT and enc.logits[1, 1] == EDGE_LOGIT
    torch.testing.assert_close(enc.displayed_amplitudes().detach(), torch.from_numpy(pattern), rtol=0, atol=2.3e-16)


def test_mask_and_field_mask_across_mask_encoders():
    """mask(): the element as displayed (the LCD: its 384 x 160 sub-pixels); field_mask(): always the field grid's
    transmittance that is propagated (the 2-D propagation of it is the LCD's PSF, to the bit)."""
    slm = FixedSLM({}, fidelity={**SMALL["fidelity"], "propagation": "blas"}, sensor=SMALL["sensor"])
    assert slm.mask().shape == (384, 160)
    field = slm.field_mask()
    assert field.shape == (3, *slm.field_grid) and field.dtype == slm.optics_dtype
    assert torch.equal(slm.propagated_psf(field, slm.d2), slm.compute_psf())
    coded = CodedAperture(**SMALL)
    assert tuple(coded.mask().shape[-2:]) == coded.field_grid and torch.equal(coded.field_mask(), coded.mask())


def test_scene_operator_is_the_measurement_and_its_adjoint():
    enc = LearnedSLM(**SMALL)
    op = enc.operator((28, 28))
    assert op.shape == (48, 784) and op.scene_shape == (1, 28, 28) and op.embedding_shape == (1, 6, 8)
    x, y = torch.rand(3, 1, 28, 28, dtype=torch.float64), torch.rand(3, 1, 6, 8, dtype=torch.float64)
    # float64 dot-product test: the same sums in another order (1e-12 relative)
    torch.testing.assert_close((op.forward(x) * y).sum(), (x * op.adjoint(y)).sum(), rtol=1e-12, atol=0)
    with torch.no_grad():
        assert torch.equal(op(x.float()), enc.measure(x.float()))
        dense = op.tensor().detach().double().reshape(48, 784)
    assert torch.equal(op.dense(), dense)
    frozen = op.frozen()
    with torch.no_grad():
        enc.logits.add_(1.0)  # an optimiser step: the live operator follows, the snapshot does not
    assert not torch.equal(op.dense(), dense) and torch.equal(frozen.dense(), dense)
    with pytest.raises(ConfigError, match=r"^operator = \(4, 5\): must be \(6, 9\)"):
        SceneOperator.from_matrix(torch.zeros(4, 5), (1, 3, 3), (1, 2, 3))
