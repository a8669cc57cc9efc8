"""Run every attacker against one encoder and measure it on the test split (library entry point).

Example::

    from optoenc.privacy import evaluate
    result = evaluate.evaluate(encoder, splits)       # encoder: any linear OpticalEncoder
    for row in result.rows: print(row["attack"], row["psnr"], row["reid_top1"])
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from typing import Any, Callable, Optional

import torch

from ..errors import ConfigError
from .settings import PrivacyConfig
from . import metrics
from .admm import ADMMConfig, admm
from .attacks import ATTACKS, LearnedConfig, PLAINTEXT_RIDGE, estimate_operator, train_inverter
from . import patterns
from .reader import reader
from .tikhonov import TikhonovConfig, pseudo_inverse

__all__ = ["PrivacyConfig", "Result", "evaluate", "dataset_token"]


@dataclass
class Result:
    """Rows (one per attack, plaintext once per N), and example arrays for pictures."""

    rows: list[dict[str, Any]]
    scenes: torch.Tensor
    labels: torch.Tensor
    embeddings: torch.Tensor
    examples: dict[str, torch.Tensor] = field(default_factory=dict)


def dataset_token(splits) -> str:
    """The dataset's content digest (hashing the tensors when the dataset gives none)."""
    if splits.digest:
        return splits.digest
    h = hashlib.sha256()
    for k in ("train", "val", "test"):
        h.update(getattr(splits, k).images.contiguous().numpy().tobytes())
    return h.hexdigest()


def _noise(encoder) -> Callable[[torch.Tensor, torch.Generator], torch.Tensor]:
    return lambda clean, g: encoder.add_sensor_noise(clean.float(), generator=g)


def evaluate(
    encoder,
    splits,
    attacks: tuple[str, ...] = ATTACKS,
    config: Optional[PrivacyConfig] = None,
    admm_config: Optional[ADMMConfig] = None,
    learned_config: Optional[LearnedConfig] = None,
    linear_config: Optional[TikhonovConfig] = None,
    cache_root: str | None = None,
    progress: Callable[[str], None] | None = None,
) -> Result:
    """Attack ``encoder``'s noisy test embeddings with each of ``attacks`` and measure the reconstructions.

    Every row has ``attack``, ``n_pairs`` (plaintext only), ``psnr``/``psnr_std``,
    ``ssim``/``ssim_std`` (mean and standard deviation over images),
    ``readability``/``readability_se`` and ``reid_top1``/``reid_se`` (rates
    and binomial standard errors) and ``count``. A ``mean_scene`` row (the
    mean training scene for every input: no information) is the floor.
    """
    cfg = config or PrivacyConfig()
    unknown = sorted(set(attacks) - set(ATTACKS))
    if unknown:
        raise ConfigError("attacks", unknown[0], f"one of {', '.join(ATTACKS)}")
    say = progress or (lambda _msg: None)
    x_pool, y_pool = splits.test
    n = min(cfg.count, len(x_pool))
    x, labels = x_pool[:n].double(), y_pool[:n]
    scene_shape = tuple(x.shape[-2:])
    # One operator per displayed pattern (one for every single-pattern encoder), and the pattern of
    # each capture (all 0 then): see optoenc.privacy.patterns for the threat models.
    ops = patterns.operators(encoder, scene_shape, scene_channels=x.shape[1])
    K = len(ops)
    gen = lambda k: torch.Generator().manual_seed(cfg.seed * 1009 + k)  # noqa: E731
    noise = _noise(encoder)
    shown = patterns.draw(n, K, gen(3))
    y = noise(patterns.capture(ops, x, shown), gen(1))
    gallery = metrics.reid_gallery(labels, y_pool, torch.arange(n), cfg.gallery, cfg.seed)
    say("reader")
    read = reader(splits, dataset_token(splits), cache_root, seed=cfg.seed)
    rows, examples = [], {}

    def measure(name: str, recon: torch.Tensor, **extra) -> None:
        recon = recon.float().clamp(0, 1)
        with torch.no_grad():
            readable = (read(recon).argmax(1) == labels).float()
        row = {"attack": name, **extra}
        for key, vals, binary in (
            ("psnr", metrics.psnr(recon, x), False),
            ("ssim", metrics.ssim(recon, x), False),
            ("readability", readable, True),
            ("reid_top1", metrics.reid_top1(recon, x_pool, gallery), True),
        ):
            m, s = metrics.summarize(vals, binary)
            row[key], row[f"{key}_{'se' if binary else 'std'}"] = m, s
        row["count"] = n
        rows.append(row)
        if cfg.examples:
            examples[name + (f"_n{extra['n_pairs']}" if "n_pairs" in extra else "")] = recon[: cfg.examples]

    xt = splits.train[0]
    measure("mean_scene", xt.double().mean(0, keepdim=True).expand_as(x))
    for name in attacks:
        say(name)
        if name == "admm":
            measure(name, patterns.grouped(lambda op, v: admm(op, v, admm_config), ops, y, shown))
        elif name == "admm_search":
            if K == 1:
                continue  # one pattern: the same attacker as "admm"
            # All K patterns known, not which one made a capture: ADMM with each, keep the best data fit.
            recs = torch.stack([admm(op, y, admm_config) for op in ops])
            resid = torch.stack([(op.forward(r) - y.to(r.dtype)).flatten(1).norm(dim=1) for op, r in zip(ops, recs)])
            measure(name, recs[resid.argmin(0), torch.arange(n)])
        elif name == "pinv":
            rcond = (linear_config or TikhonovConfig()).rcond
            measure(name, patterns.grouped(lambda op, v: pseudo_inverse(op, v, rcond), ops, y, shown))
        elif name in ("learned", "learned_one"):
            if name == "learned_one" and K == 1:
                continue  # one pattern: the same attacker as "learned"
            lc = learned_config or LearnedConfig()
            scenes = xt[: lc.pairs]
            # learned: pairs captured with the patterns the camera drew; learned_one: through pattern 0 only.
            seen = patterns.draw(len(scenes), K if name == "learned" else 1, gen(4))
            model = train_inverter(patterns.capture(ops, scenes.double(), seen), scenes, noise, lc, seed=cfg.seed)
            with torch.no_grad():
                measure(name, model(y))
        elif name == "plaintext":
            for k in cfg.plaintext_n:
                k = min(int(k), len(xt))
                known = xt[-k:].double()  # the attacker's pairs: training scenes through the camera, noise included
                clean = patterns.capture(ops, known, patterns.draw(k, K, gen(5)))
                est = estimate_operator(known, noise(clean, gen(2)), PLAINTEXT_RIDGE)
                measure(name, admm(est, y, admm_config), n_pairs=k)
    return Result(rows, x[: cfg.examples].float(), labels[: cfg.examples], y[: cfg.examples].float(), examples)
