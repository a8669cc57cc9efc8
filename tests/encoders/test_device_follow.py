"""An encoder's PSF and operator follow ``.to(device)``, also for a fixed encoder with no parameters or buffers.

Found on a CUDA machine (session 24): the lens and the diffuser kept returning the PSF cached on the CPU after
``.to("cuda")``, because their caches were keyed by parameters and buffers they do not have. The ``meta`` device
stands in for CUDA here (it exists on every machine and holds shapes only): after ``.to("meta")`` the PSF must be
rebuilt there, which the normalisation's finiteness check refuses ("cannot be called on meta tensors"), while the
bug returned the cached CPU PSF without a word. The CUDA check itself is the conformance kit's ``device`` check
(run on an H100 in session 24: 8 of 8 encoders).
"""

import pytest
from optoenc.plugins import get_registry
from optoenc.testing import make_encoder

FIXED = ["lens", "diffuser", "coded_aperture", "fixed_slm", "phase_mask"]


@pytest.mark.parametrize("name", FIXED)
def test_a_cached_psf_and_operator_follow_the_module_to_another_device(name):
    enc = make_encoder(get_registry("encoder").get(name))
    assert enc.psf().device.type == "cpu" and enc.operator((28, 28)).tensor().device.type == "cpu"  # both now cached
    enc.to("meta")
    assert enc.device.type == "meta"
    for build in (enc.psf, lambda: enc.operator((28, 28)).tensor()):
        with pytest.raises(RuntimeError, match="meta tensors"):  # rebuilt on meta, not the cached CPU tensor
            build()


def test_the_device_anchor_is_not_saved():
    """The empty buffer that tracks the device is not part of a checkpoint (old checkpoints still load)."""
    enc = make_encoder(get_registry("encoder").get("lens"))
    assert not any("anchor" in k for k in enc.state_dict())
