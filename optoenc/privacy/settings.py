"""Settings of reconstruction and privacy measurement: the one table of their defaults.

Kept free of torch so that the command line can show the defaults without loading it.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..settings import Settings, setting

__all__ = [
    "ADMMConfig", "TikhonovConfig", "LearnedConfig", "PrivacyConfig", "ATTACKS", "LEARNED", "METHODS", "THREAT_MODELS",
    "THREAT_MODEL", "LOSSES", "SCHEDULES", "INPUTS",
]  # fmt: skip

#: Attack names, in table order.
ATTACKS = ("admm", "learned", "learned_conv", "plaintext", "pinv", "learned_one", "admm_search")
#: The learned (trained inversion network) attacks -> their network: an MLP or the convolutional decoder.
LEARNED = {"learned": "mlp", "learned_conv": "conv", "learned_one": "mlp"}
#: Threat models, in table order: the attacker knows the mask (hence the scene operator); has N plaintext
#: (scene, embedding) pairs and no mask; is black-box (public training scenes and the camera's embeddings of
#: them, trains an inversion network).
THREAT_MODELS = ("known_mask", "plaintext", "black_box")
#: Each attack's threat model (``mean_scene``, the no-information floor, has none: ``""``).
THREAT_MODEL = {
    "admm": "known_mask", "pinv": "known_mask", "admm_search": "known_mask", "tikhonov": "known_mask",
    "plaintext": "plaintext", "learned": "black_box", "learned_conv": "black_box", "learned_one": "black_box",
    "mean_scene": "",
}  # fmt: skip
#: Training losses of the learned attackers.
LOSSES = ("mse", "l1")
#: Learning-rate schedules of the learned attackers.
SCHEDULES = ("constant", "one_cycle")
#: How the learned attackers scale embeddings before their network (:func:`optoenc.privacy.inverters.scaling`).
INPUTS = ("whiten", "standardise")
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
    """The learned inversion attackers (``learned``: an MLP; ``learned_conv``: a fully connected layer to a small
    feature map, then transposed convolutions), trained on (embedding, scene) pairs of the training split with a
    held-out validation part and early stopping (the state of the best validation loss is kept).

    The defaults had the lowest validation loss of the attackers tried: MLP 1024 units with a one-cycle schedule to
    3e-3 on the fixed LCD 6x8 camera, where the former default (256 units, constant 1e-3) was furthest from
    converged; whitened inputs on the coded aperture 24x32, whose pixels are strongly correlated (docs/privacy.md,
    "Are the attackers converged?")."""

    pairs: int = setting(60000, "(embedding, scene) pairs from the training split, validation part included "
                         "(at most the split's size)", ge=2)
    epochs: int = setting(50, "maximum training epochs (fresh sensor noise every epoch; training stops earlier when "
                          "the validation loss has not improved for `patience` epochs)", ge=1)
    patience: int = setting(5, "epochs without a lower validation loss before training stops (constant schedule; "
                            "one_cycle runs to its end, the lowest validation loss's state kept either way)", ge=1)
    val_fraction: float = setting(0.1, "fraction of the pairs held out to validate (at least one pair)", gt=0, lt=1)
    loss: str = setting("mse", "training and validation loss: mse or l1", choices=LOSSES)
    hidden: int = setting(1024, "learned (MLP): units of each of the two hidden layers", ge=1)
    channels: int = setting(32, "learned_conv: channels of the first feature map (halved by each transposed "
                            "convolution, at least 8)", ge=1)
    lr: float = setting(3e-3, "Adam learning rate (one_cycle: its peak)", gt=0)
    schedule: str = setting("one_cycle", "learning rate over training: constant, or one_cycle (torch's OneCycleLR "
                            "over `epochs`: 5 % warm-up to `lr`, cosine annealing to lr / 2.5e5)", choices=SCHEDULES)
    batch_size: int = setting(128, "pairs per optimiser step", ge=1)
    inputs: str = setting("whiten", "how embeddings are scaled before the network: whiten (minus the training "
                          "embeddings' mean, times the inverse square root of their covariance) or standardise (one "
                          "scalar mean and standard deviation)", choices=INPUTS)
    device: str = setting("auto", "where the attackers train: auto (cuda when available, else cpu), cpu or cuda "
                          "(the sensor noise is drawn on the CPU either way)", choices=("auto", "cpu", "cuda"))


@dataclass
class PrivacyConfig(Settings):
    """What `optoenc privacy` measures and on how many digits."""

    count: int = setting(1000, "probes: test scenes attacked and measured (the first ones of the test split)", ge=1)
    gallery: int = setting(100, "re-identification gallery: the true scene and gallery-1 others of its class", ge=2)
    plaintext_n: tuple[int, ...] = setting((100, 1000, 10000), "plaintext attack: numbers of known pairs", ge=1)
    attack_seeds: int = setting(3, "learned attackers: trained with this many seeds (seed, seed+1, ...); a row gives "
                                "the mean over them", ge=1)
    seed: int = setting(0, "seed of the sensor noise, the patterns shown, the galleries, the readability classifier "
                        "and the first learned attacker")
    examples: int = setting(8, "example reconstructions kept for pictures", ge=0)
