"""Settings of reconstruction and privacy measurement: the one table of their defaults.

Kept free of torch so that the command line can show the defaults without loading it.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..settings import Settings, setting

__all__ = ["ADMMConfig", "TikhonovConfig", "LearnedConfig", "PrivacyConfig", "AdversaryConfig", "ATTACKS", "METHODS"]

#: Attack names, in table order.
ATTACKS = ("admm", "learned", "plaintext", "pinv", "learned_one", "admm_search")
#: Reconstruction methods of `optoenc reconstruct`.
METHODS = ("admm", "tikhonov", "pinv")


@dataclass
class ADMMConfig(Settings):
    """ADMM settings (the paper: 100 iterations; tau and penalties tuned on training digits, docs/privacy.md)."""

    iterations: int = setting(100, "ADMM iterations", ge=1)
    tau: float = setting(3e-6, "TV weight tau, for the operator scaled to unit spectral norm", ge=0)
    mu_tv: float = setting(1e-3, "ADMM penalty of the split u = Psi x (unit-norm operator)", gt=0)
    mu_nonneg: float = setting(1e-3, "ADMM penalty of the split w = x >= 0 (unit-norm operator)", gt=0)


@dataclass
class TikhonovConfig(Settings):
    """Linear baselines' settings, relative to the operator scaled to unit spectral norm."""

    lam: float = setting(1e-3, "Tikhonov weight lambda in 1/2||y - Ax||^2 + lam/2 ||x||^2 (unit-norm operator)", gt=0)
    rcond: float = setting(1e-3, "pseudo-inverse: singular values below rcond * the largest are dropped", gt=0, lt=1)


@dataclass
class LearnedConfig(Settings):
    """The learned inversion attacker (an MLP embedding -> scene, trained on the training split)."""

    pairs: int = setting(20000, "training (embedding, scene) pairs drawn from the training split", ge=1)
    epochs: int = setting(6, "training epochs (fresh sensor noise every epoch)", ge=1)
    hidden: int = setting(256, "units of each of the two hidden layers", ge=1)
    lr: float = setting(1e-3, "Adam learning rate", gt=0)
    batch_size: int = setting(128, "pairs per optimiser step", ge=1)


@dataclass
class PrivacyConfig(Settings):
    """What `optoenc privacy` measures and on how many digits."""

    count: int = setting(500, "test scenes attacked and measured (the first ones of the test split)", ge=1)
    gallery: int = setting(100, "re-identification gallery: the true scene and gallery-1 others of its class", ge=2)
    plaintext_n: tuple[int, ...] = setting((100, 300, 1000, 3000, 10000), "plaintext attack: numbers of known pairs", ge=1)
    seed: int = setting(0, "seed of the sensor noise, the galleries and the learned attacker")
    examples: int = setting(8, "example reconstructions kept for pictures", ge=0)


@dataclass
class AdversaryConfig(Settings):
    """Privacy-aware training (`fit`, section `privacy`): the encoder trained against a reconstruction adversary.

    Objective per batch: cross-entropy - ``adversary_weight`` * the adversary's reconstruction MSE, the
    adversary (an MLP from the noisy embedding to the scene) trained alongside on its own MSE
    (:mod:`optoenc.privacy.adversary`). 0 (the default) is plain training, nothing added.
    """

    adversary_weight: float = setting(0.0, "weight lambda of the adversary's reconstruction MSE subtracted from the "
                                      "classifier loss; 0: off (plain training)", ge=0)
    adversary_hidden: int = setting(256, "units of each of the adversary's two hidden layers", ge=1)
    adversary_lr: float = setting(1e-3, "the adversary's Adam learning rate", gt=0)
