"""docs/library.md holds: its example trains, and each call the page documents does what the page says."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest
import torch

import optoenc
from optoenc.errors import ConfigError, DataError

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "library_loop.py"


def _example():
    spec = importlib.util.spec_from_file_location("library_loop", EXAMPLE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_example_loop_trains(capsys):
    """A few steps lower the training loss (seeded: the same numbers every run), and the operator is the measure."""
    out = _example().main(steps=20)
    assert out["after"] < out["before"] - 0.1, out  # 2.48 -> 1.93 measured; 0.1 is far above rounding
    assert out["operator_matches"]
    assert "training loss" in capsys.readouterr().out


@pytest.fixture(scope="module")
def enc():
    return optoenc.build_encoder("learned_slm", sensor={"embedding": [6, 8]}, fidelity={"preset": "fast"})


def test_forward_without_noise_is_measure(enc):
    x = torch.rand(3, 1, 28, 28)
    with torch.no_grad():
        assert torch.equal(enc(x, noise=False), enc.measure(x))
        torch.manual_seed(1)
        noisy = enc(x)
        assert not torch.equal(noisy, enc.measure(x))  # the sensor noise is drawn unless noise=False


def test_psf_and_operator_shapes(enc):
    with torch.no_grad():
        psf = enc.psf()
        op = enc.operator((28, 28))
    assert psf.shape == (1, *enc.geometry.grid) and float(psf.min()) >= 0
    assert op.shape == (1 * 6 * 8, 28 * 28)


def test_bad_scenes_are_refused_in_one_line(enc):
    with pytest.raises(DataError, match="must be >= 0"):
        enc.measure(-torch.rand(1, 1, 28, 28))
    with pytest.raises(ConfigError) as err:
        enc.measure(torch.rand(1, 2, 28, 28))  # neither gray nor R, G, B (an RGB scene is measured as its luminance)
    assert "gray" in str(err.value) and "\n" not in str(err.value)


def test_the_operator_as_a_matrix_and_its_adjoint(enc):
    """``<M x, y> = <x, M^T y>`` for the float64 matrix, and ``M x`` is the measurement (to float32 rounding)."""
    x, y = torch.rand(2, 1, 28, 28, dtype=torch.float64), torch.rand(2, 1, 6, 8, dtype=torch.float64)
    with torch.no_grad():
        op = enc.operator((28, 28))
        lhs = (op.forward(x) * y).sum()
        rhs = (x * op.adjoint(y)).sum()
        torch.testing.assert_close(lhs, rhs, rtol=1e-12, atol=0)  # the same sums in another order
        measured = enc.measure(x.float()).double()
        torch.testing.assert_close(op.forward(x), measured, rtol=1e-4, atol=1e-6 * float(measured.abs().max()))


def test_one_mask_accessor_whatever_the_parameterisation():
    kw = {"sensor": {"embedding": [6, 8]}, "fidelity": {"preset": "fast"}}
    fixed = optoenc.build_encoder("fixed_slm", **kw).displayed_amplitudes()
    sig = optoenc.build_encoder("learned_slm", **kw)
    proj = optoenc.build_encoder("learned_slm", encoder={"parameterization": "projected"}, **kw)
    assert fixed.shape == sig.displayed_amplitudes().shape == proj.displayed_amplitudes().shape
    torch.testing.assert_close(sig.displayed_amplitudes(), fixed, rtol=0, atol=2.3e-16)  # the documented 1.1e-16
    assert torch.equal(proj.displayed_amplitudes(), fixed)  # the amplitudes themselves: exact
    assert sig.displayed_amplitudes().requires_grad and proj.displayed_amplitudes().requires_grad
    with torch.no_grad():
        proj.amplitudes.add_(0.7)  # an optimiser step that leaves [0, 1]
    proj.constrain_()
    w = proj.displayed_amplitudes().detach()
    assert float(w.min()) >= 0.0 and float(w.max()) == 1.0


def test_to_float64_moves_the_optics_and_half_precision_is_refused():
    enc = optoenc.build_encoder("lens", sensor={"embedding": [6, 8]}, fidelity={"preset": "fast"})
    assert enc.optics_dtype == torch.float32
    enc = enc.to(torch.float64)
    assert enc.optics_dtype == torch.float64 and enc.psf().dtype == torch.float64
    assert enc.measure(torch.rand(1, 1, 28, 28, dtype=torch.float64)).dtype == torch.float64
    with pytest.raises(ConfigError, match="float32 or float64"):
        enc.half()


def test_every_documented_error_is_an_optoenc_error():
    for name in ("ConfigError", "DataError", "PluginError", "PhysicsError"):
        assert issubclass(getattr(optoenc, name), optoenc.OptoencError)


def test_public_api_is_light_to_import_and_every_name_resolves():
    import subprocess
    import sys

    code = "import sys, optoenc; print(sorted(m for m in ('torch', 'lightning', 'optoenc.plugins') if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"  # neither torch nor the plugin host until a name is used
    for name in optoenc.__all__:
        assert getattr(optoenc, name) is not None, name
