"""Privacy-aware training (`privacy.adversary_weight`): the min-max objective's gradients."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F
from torch import nn

from optoenc.config import compose
from optoenc.errors import ConfigError
from optoenc.training.adversary import Adversary, AdversaryConfig, AdversaryObjective, from_config


def _toy():
    """Encoder: one gain theta on fixed features s; decoder: fixed linear; adversary: identity linear.

    At theta = 0.5 the adversary's reconstruction theta * s of the scene s improves with theta
    (dMSE/dtheta = 2 (theta - 1) mean(s^2) < 0), and so does the classifier (the true class has
    the largest logit; scaling the logits up lowers the cross-entropy: dCE/dtheta < 0).
    """
    g = torch.Generator().manual_seed(0)
    s = torch.rand(8, 1, 2, 2, generator=g, dtype=torch.float64) + 0.5
    w = torch.tensor([[1.0, 1.0, 1.0, 1.0], [-1.0, -1.0, -1.0, -1.0]], dtype=torch.float64)
    labels = torch.zeros(8, dtype=torch.long)  # class 0: the logit w0 . y is the larger one for y > 0
    adv = nn.Linear(4, 4, bias=False).double()
    with torch.no_grad():
        adv.weight.copy_(torch.eye(4))
    net = nn.Sequential(nn.Flatten(), adv, nn.Unflatten(1, (1, 2, 2)))
    return s, labels, w, net


def _grads(weight: float):
    s, labels, w, net = _toy()
    theta = torch.tensor(0.5, dtype=torch.float64, requires_grad=True)
    y = theta * s
    ce = F.cross_entropy(y.reshape(8, -1) @ w.T, labels)
    obj = AdversaryObjective(weight, net)
    loss, mse = obj.objective(ce, y, s)
    loss.backward()
    return theta.grad.item(), net[1].weight.grad.clone(), ce, mse


def test_adversary_term_flips_the_encoders_gradient():
    g_plain, adv_plain, _, _ = _grads(0.0)
    s, _, _, _ = _toy()
    d_mse = 2 * (0.5 - 1) * float((s**2).mean())  # analytic dMSE/dtheta of the toy
    assert g_plain < 0 and d_mse < 0  # both sides want a larger gain here
    lam = 3 * abs(g_plain) / abs(d_mse)
    g_adv, adv_grad, _, _ = _grads(lam)
    # The encoder receives dCE - lambda dMSE (float64, so 1e-10 relative is rounding) ...
    assert g_adv == pytest.approx(g_plain - lam * d_mse, rel=1e-10)
    # ... which here points the other way: the encoder now spoils the reconstruction.
    assert g_adv > 0
    # The adversary learns from its own loss only: the same gradient whatever lambda.
    assert torch.allclose(adv_grad, adv_plain, rtol=1e-12, atol=0)


def test_weight_zero_is_plain_training_for_the_encoder():
    g0, _, _, _ = _grads(0.0)
    s, labels, w, _ = _toy()
    theta = torch.tensor(0.5, dtype=torch.float64, requires_grad=True)
    F.cross_entropy((theta * s).reshape(8, -1) @ w.T, labels).backward()
    assert g0 == pytest.approx(theta.grad.item(), rel=1e-12)


def test_adversary_standardises_each_embedding():
    adv = Adversary((1, 3, 4), (1, 5, 5), hidden=8)
    y = torch.rand(4, 1, 3, 4, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        out = adv(y)
    assert out.shape == (4, 1, 5, 5) and float(out.min()) >= 0 and float(out.max()) <= 1
    # Brightness and contrast of the embedding do not change the adversary's answer (float32: 1e-5).
    assert torch.allclose(adv(7.0 * y + 3.0), out, atol=1e-5)


@pytest.mark.parametrize("value, words", [("-1", ">= 0"), ("nan", "finite"), ("inf", "finite"), ("x", "Float")])
def test_bad_weight_is_named(value, words):
    with pytest.raises(ConfigError, match=rf"^privacy\.adversary_weight = .*({words})"):
        compose(overrides=[f"privacy.adversary_weight={value}"])
    with pytest.raises(ConfigError, match=r"^privacy\.adversary_weight"):
        AdversaryObjective(float(value) if value != "x" else value, nn.Identity())


def test_from_config():
    class Fixed:
        learnable, name, output_shape = False, "lens", (1, 6, 8)

    class Learned(Fixed):
        learnable, name = True, "learned_slm"

    assert from_config(AdversaryConfig(), Learned(), (1, 28, 28)) is None  # weight 0: nothing built
    obj = from_config(AdversaryConfig(adversary_weight=2.0), Learned(), (1, 28, 28))
    assert obj.weight == 2.0 and obj.net(torch.rand(3, 1, 6, 8)).shape == (3, 1, 28, 28)
    with pytest.raises(ConfigError, match=r"^privacy\.adversary_weight = 2\.0: needs a learnable encoder"):
        from_config(AdversaryConfig(adversary_weight=2.0), Fixed(), (1, 28, 28))


@pytest.mark.filterwarnings("ignore")  # self.log outside a Trainer; the 48 x 64 grid's sampling warning
def test_training_module_hook():
    """The training step returns CE - lambda * MSE + MSE (same value, split gradients) and steps the adversary too."""
    from optoenc.encoders.slm import LearnedSLM
    from optoenc.plugins import get_registry
    from optoenc.training.module import EncoderDecoderModule

    enc = LearnedSLM(None, fidelity={"grid": (48, 64)}, sensor={"embedding": (6, 8)})
    cls = get_registry("decoder").get("fcnn")
    dec = cls(cls.Config(), in_shape=enc.output_shape, num_classes=10, learnable_encoder=True)
    adv = from_config(AdversaryConfig(adversary_weight=5.0, adversary_lr=3e-4), enc, (1, 28, 28))
    module = EncoderDecoderModule(enc, dec, adversary=adv)
    x, y = torch.rand(4, 1, 28, 28, generator=torch.Generator().manual_seed(0)), torch.arange(4)
    torch.manual_seed(0)
    loss = module.training_step((x, y), 0)
    torch.manual_seed(0)  # the same noise draw
    emb = module.embed(x, augment=True)
    ce, mse = F.cross_entropy(module.decoder(emb), y), F.mse_loss(adv.net(emb), x)
    # float32 losses of order one: 1e-5 is rounding
    assert float(loss) == pytest.approx(float(ce + (1 - 5.0) * mse), abs=1e-5)
    groups = module.configure_optimizers().param_groups
    assert groups[-1]["lr"] == 3e-4 and {id(p) for p in groups[-1]["params"]} == {id(p) for p in adv.parameters()}
    plain = EncoderDecoderModule(enc, dec)
    torch.manual_seed(0)
    assert float(plain.training_step((x, y), 0)) == pytest.approx(float(ce), abs=1e-5)
    assert len(plain.configure_optimizers().param_groups) == 2
