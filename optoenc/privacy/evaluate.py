"""Run every attacker against one encoder and measure it on the test split (library entry point).

Example::

    from optoenc.privacy import evaluate
    result = evaluate.evaluate(encoder, splits)       # encoder: any linear OpticalEncoder
    for row in result.rows: print(row["attack"], row["psnr"], row["reid_top1"])
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Optional

import torch

from ..errors import ConfigError
from ..training.rundir import atomic_torch_save
from .settings import PrivacyConfig
from . import metrics
from .admm import ADMMConfig, admm
from .attacks import ATTACKS, LEARNED, THREAT_MODEL, LearnedConfig, choose_ridge, estimate_operator, train_inverter
from . import patterns
from .reader import reader
from .stats import wilson
from .tikhonov import TikhonovConfig, pseudo_inverse

__all__ = ["PrivacyConfig", "Result", "Target", "evaluate", "target", "learned_attack", "MULTI_PATTERN",
           "AttackStore", "store_token"]

#: Attacks on a camera that shows several patterns -> the attack each equals on a single-pattern camera
#: (where it is not run: its row would repeat that attack's).
MULTI_PATTERN = {"admm_search": "admm", "learned_one": "learned"}


@dataclass
class Result:
    """Rows (one per attack, plaintext once per N; :func:`evaluate` names the columns), example arrays for
    pictures, and notes on attacks not run."""

    rows: list[dict[str, Any]]
    scenes: torch.Tensor
    labels: torch.Tensor
    embeddings: torch.Tensor
    examples: dict[str, torch.Tensor] = field(default_factory=dict)
    #: One line per requested attack that does not apply to this camera (why it has no row).
    notes: list[str] = field(default_factory=list)


def _noise(encoder) -> Callable[[torch.Tensor, torch.Generator], torch.Tensor]:
    return lambda clean, g: encoder.add_sensor_noise(clean.float(), generator=g)


def _generator(seed: int, k: int) -> torch.Generator:
    return torch.Generator().manual_seed(seed * 1009 + k)


#: Scenes captured at once for a learned attacker's pairs (float64 captures, kept as float32).
_CAPTURE_CHUNK = 8192


@dataclass
class Target:
    """The probes under attack and how a reconstruction of them is scored (:func:`target`).

    Attributes:
        x: ``(n, S, h, w)`` the probe scenes (float64); ``labels``: their classes.
        y: ``(n, C, a, b)`` their noisy embeddings; ``shown``: the pattern of each capture.
        ops: one frozen operator per displayed pattern.
        pool: the test split's scenes (the re-identification galleries index it); ``gallery``: ``(n, size)``.
    """

    encoder: Any
    x: torch.Tensor
    labels: torch.Tensor
    y: torch.Tensor
    shown: torch.Tensor
    ops: list
    pool: torch.Tensor
    gallery: torch.Tensor
    read: Any
    config: PrivacyConfig

    def generator(self, k: int) -> torch.Generator:
        """The ``k``-th seeded stream of this measurement (noise, patterns, pairs)."""
        return _generator(self.config.seed, k)

    @property
    def noise(self) -> Callable[[torch.Tensor, torch.Generator], torch.Tensor]:
        return _noise(self.encoder)

    def measure(self, name: str, recons: torch.Tensor | list[torch.Tensor], **extra) -> dict[str, Any]:
        """One table row for reconstructions of the probes (a list: one per attacker seed, scored per probe and
        averaged over the seeds).

        ``psnr``/``ssim``: mean over probes, ``_std`` their spread over probes; ``readability``/``reid_top1``:
        rates, ``_se`` their binomial standard error and ``readability_ci_low/high``, ``reid_ci_low/high`` the
        Wilson 95 % interval on ``count`` probes; with several seeds ``reid_seeds``, each seed's rate.
        """
        recons = [r.float().clamp(0, 1) for r in (recons if isinstance(recons, (list, tuple)) else [recons])]
        per: dict[str, list[torch.Tensor]] = {"psnr": [], "ssim": [], "readability": [], "reid_top1": []}
        for r in recons:
            with torch.no_grad():
                per["readability"].append((self.read(r).argmax(1) == self.labels).float())
            per["psnr"].append(metrics.psnr(r, self.x))
            per["ssim"].append(metrics.ssim(r, self.x))
            per["reid_top1"].append(metrics.reid_top1(r, self.pool, self.gallery))
        n = len(self.x)
        row = {"attack": name, "threat_model": THREAT_MODEL.get(name, ""), **extra}
        for key, binary in (("psnr", False), ("ssim", False), ("readability", True), ("reid_top1", True)):
            m, s = metrics.summarize(torch.stack(per[key]).mean(0), binary)
            row[key], row[f"{key}_{'se' if binary else 'std'}"] = m, s
            if binary:
                short = "reid" if key == "reid_top1" else key
                row[f"{short}_ci_low"], row[f"{short}_ci_high"] = wilson(m, n) if m == m else (float("nan"),) * 2
        if len(recons) > 1:
            row["reid_seeds"] = ";".join(f"{float(v.mean()):.4g}" for v in per["reid_top1"])
        row["count"] = n
        return row


class AttackStore:
    """Each finished attack's rows and example reconstructions, kept in a folder so that an interrupted measurement
    resumes at the attack it was in (one ``<attack>.pt`` per attack, written atomically).

    A stored attack is reused only when its ``token`` (:func:`store_token`: the probes' embeddings, hence the
    encoder, the noise seed and the probes; the attackers' training scenes; every setting) equals the current one;
    any other file is measured again and replaced.
    """

    def __init__(self, folder: str | Path, token: str):
        self.folder, self.token = Path(folder), token

    def _path(self, name: str) -> Path:
        return self.folder / f"{name}.pt"

    def load(self, name: str) -> tuple[list[dict], dict[str, torch.Tensor]] | None:
        """The stored ``(rows, examples)`` of attack ``name``, or None (absent, unreadable or from other settings)."""
        try:
            saved = torch.load(self._path(name), map_location="cpu", weights_only=True)
        except Exception:  # absent, partly written by another writer, or not a store file: measure again
            return None
        if not isinstance(saved, dict) or saved.get("token") != self.token:
            return None
        return saved["rows"], saved["examples"]

    def save(self, name: str, rows: list[dict], examples: dict[str, torch.Tensor]) -> Path:
        # clone: an example is a slice of all the probes' reconstructions, whose whole storage torch.save would keep
        examples = {k: v.clone() for k, v in examples.items()}
        return atomic_torch_save(self._path(name), {"token": self.token, "rows": rows, "examples": examples})


def store_token(*parts) -> str:
    """The :class:`AttackStore` key of a measurement: a digest of its ``parts``, tensors by their bytes (the probes'
    noisy embeddings, the attackers' training scenes), anything else by its ``repr`` (the settings)."""
    h = hashlib.sha256()
    for p in parts:
        h.update(p.detach().cpu().contiguous().numpy().tobytes() if isinstance(p, torch.Tensor) else repr(p).encode())
    return h.hexdigest()


def target(encoder, splits, config: Optional[PrivacyConfig] = None, cache_root: str | None = None,
           progress: Callable[[str], None] | None = None) -> Target:
    """The first ``config.count`` test scenes as probes: their noisy embeddings, galleries and the reader."""
    cfg = config or PrivacyConfig()
    say = progress or (lambda _msg: None)
    x_pool, y_pool = splits.test
    n = min(cfg.count, len(x_pool))
    x, labels = x_pool[:n].double(), y_pool[:n]
    # One operator per displayed pattern (one for every single-pattern encoder), and the pattern of
    # each capture (all 0 then): see optoenc.privacy.patterns for the threat models.
    ops = patterns.operators(encoder, tuple(x.shape[-2:]), scene_channels=x.shape[1])
    shown = patterns.draw(n, len(ops), _generator(cfg.seed, 3))
    y = _noise(encoder)(patterns.capture(ops, x, shown), _generator(cfg.seed, 1))
    gallery = metrics.reid_gallery(labels, y_pool, torch.arange(n), cfg.gallery, cfg.seed)
    say("reader")
    read = reader(splits, cache_root, seed=cfg.seed)
    return Target(encoder, x, labels, y, shown, ops, x_pool, gallery, read, cfg)


def learned_attack(tgt: Target, name: str, train_scenes: torch.Tensor, learned_config: Optional[LearnedConfig] = None,
                   seeds: int | None = None) -> tuple[list[torch.Tensor], dict[str, Any]]:
    """Train the learned attacker ``name`` (``learned``, ``learned_conv``, ``learned_one``) with each of ``seeds``
    seeds (default ``config.attack_seeds``: ``seed, seed + 1, ...``) and reconstruct the probes.

    Returns:
        ``(one reconstruction per seed, the row's budget columns)``: ``n_pairs`` (pairs, validation included),
        ``val_pairs``, ``max_epochs``, ``epochs_run`` (per seed, ``;``-joined), ``val_loss`` (mean over seeds of
        the kept state's validation loss), ``attack_seeds``, ``attacker_size``, ``attacker_inputs``.
    """
    lc = learned_config or LearnedConfig()
    k = min(lc.pairs, len(train_scenes))
    scenes = train_scenes[:k]
    # learned, learned_conv: pairs captured with the patterns the camera drew; learned_one: through pattern 0 only.
    seen = patterns.draw(k, len(tgt.ops) if name != "learned_one" else 1, tgt.generator(4))
    clean = torch.cat([patterns.capture(tgt.ops, scenes[i : i + _CAPTURE_CHUNK].double(), seen[i : i + _CAPTURE_CHUNK]).float()
                       for i in range(0, k, _CAPTURE_CHUNK)])
    recons, reports = [], []
    for i in range(tgt.config.attack_seeds if seeds is None else seeds):
        model, rep = train_inverter(clean, scenes, tgt.noise, lc, seed=tgt.config.seed + i, kind=LEARNED[name])
        with torch.no_grad():
            dev = next(model.parameters()).device
            recons.append(torch.cat([model(part.to(dev)).cpu() for part in tgt.y.split(4096)]))
        reports.append(rep)
    budget = {"n_pairs": k, "val_pairs": reports[0].val_pairs, "max_epochs": lc.epochs,
              "epochs_run": ";".join(str(r.epochs_run) for r in reports),
              "val_loss": sum(r.val_loss for r in reports) / len(reports), "attack_seeds": len(reports),
              "attacker_size": lc.channels if LEARNED[name] == "conv" else lc.hidden, "attacker_inputs": lc.inputs}
    return recons, budget


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
    resume_dir: str | Path | None = None,
) -> Result:
    """Attack ``encoder``'s noisy test embeddings with each of ``attacks`` and measure the reconstructions.

    Every row has ``attack``, its ``threat_model`` (:data:`~optoenc.privacy.settings.THREAT_MODEL`),
    ``psnr``/``psnr_std``, ``ssim``/``ssim_std`` (mean and standard deviation over probes),
    ``readability``/``reid_top1`` (rates) with their binomial standard errors (``_se``) and Wilson 95 %
    intervals (``readability_ci_low/high``, ``reid_ci_low/high``), and ``count`` (probes). Plaintext rows
    give their pairs (``n_pairs``); learned rows their budget (:func:`learned_attack`), averaged over
    ``config.attack_seeds`` attackers. A ``mean_scene`` row (the mean training scene for every input: no
    information) is the floor.

    ``resume_dir``: a folder where each finished attack is kept (:class:`AttackStore`); a measurement interrupted
    and started again with the same folder and settings reuses the attacks that finished (the same rows: every
    attack draws from its own seeded streams).
    """
    cfg = config or PrivacyConfig()
    unknown = sorted(set(attacks) - set(ATTACKS))
    if unknown:
        raise ConfigError("attacks", unknown[0], f"one of {', '.join(ATTACKS)}")
    say = progress or (lambda _msg: None)
    tgt = target(encoder, splits, cfg, cache_root, say)
    x, y, ops, shown, n, K = tgt.x, tgt.y, tgt.ops, tgt.shown, len(tgt.x), len(tgt.ops)
    rows, examples, notes = [], {}, []

    def measure(name: str, recon, **extra) -> None:
        rows.append(tgt.measure(name, recon, **extra))
        if cfg.examples:
            first = recon[0] if isinstance(recon, list) else recon
            key = name + (f"_n{extra['n_pairs']}" if name == "plaintext" else "")
            examples[key] = first.float().clamp(0, 1)[: cfg.examples]

    xt = splits.train[0]
    measure("mean_scene", xt.double().mean(0, keepdim=True).expand_as(x))
    # The key: the probes' embeddings (encoder, noise seed, probes), the attackers' training scenes, every setting.
    store = None if resume_dir is None else AttackStore(
        resume_dir, store_token(y, xt, cfg, admm_config or ADMMConfig(), learned_config or LearnedConfig(),
                                 linear_config or TikhonovConfig()))
    for name in attacks:
        if K == 1 and name in MULTI_PATTERN:
            notes.append(f"{name} not run: {encoder.name} shows one pattern, where it is the same attack as "
                         f"{MULTI_PATTERN[name]}")
            continue
        kept = store.load(name) if store else None
        if kept is not None:
            say(f"{name} (kept from an earlier, interrupted measurement)")
            rows += kept[0]
            examples.update(kept[1])
            continue
        say(name)
        first_row, known_examples = len(rows), set(examples)
        if name == "admm":
            measure(name, patterns.grouped(lambda op, v: admm(op, v, admm_config), ops, y, shown))
        elif name == "admm_search":
            # All K patterns known, not which one made a capture: ADMM with each, keep the best data fit.
            recs = torch.stack([admm(op, y, admm_config) for op in ops])
            resid = torch.stack([(op.forward(r) - y.to(r.dtype)).flatten(1).norm(dim=1) for op, r in zip(ops, recs)])
            measure(name, recs[resid.argmin(0), torch.arange(n)])
        elif name == "pinv":
            rcond = (linear_config or TikhonovConfig()).rcond
            measure(name, patterns.grouped(lambda op, v: pseudo_inverse(op, v, rcond), ops, y, shown))
        elif name in LEARNED:
            recons, budget = learned_attack(tgt, name, xt, learned_config)
            measure(name, recons, **budget)
        elif name == "plaintext":
            invert = lambda op, v: admm(op, v, admm_config)  # noqa: E731  (the attack's own inversion)
            for k in cfg.plaintext_n:
                k = min(int(k), len(xt))
                known = xt[-k:].double()  # the attacker's pairs: training scenes through the camera, noise included
                clean = patterns.capture(ops, known, patterns.draw(k, K, tgt.generator(5)))
                noisy = tgt.noise(clean, tgt.generator(2))
                est = estimate_operator(known, noisy, choose_ridge(known, noisy, invert, generator=tgt.generator(6)))
                measure(name, invert(est, y), n_pairs=k)
        if store:
            store.save(name, rows[first_row:], {k: v for k, v in examples.items() if k not in known_examples})
    return Result(rows, x[: cfg.examples].float(), tgt.labels[: cfg.examples], y[: cfg.examples].float(), examples, notes)
