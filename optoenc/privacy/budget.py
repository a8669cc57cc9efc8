"""Budget study of the learned attackers: re-identification over a grid of training pairs x maximum epochs.

Shows where an attacker has converged: where more pairs or more epochs no longer raise re-identification.
Each grid point trains the attacker afresh (validation split, early stopping: ``epochs_run`` may stay below
the maximum) with ``attack_seeds`` seeds, and attacks the same probes (:func:`optoenc.privacy.evaluate.target`).

Example::

    rows = budget_study(encoder, splits, pairs=(1000, 10000, 60000), epochs=(5, 15, 50))
    optoenc.privacy.report.write_table(rows, "budget.csv")

``examples/privacy/budget_study.py`` runs it for a run directory or an encoder name.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, Callable, Optional, Sequence

from ..errors import ConfigError
from .settings import LEARNED, LearnedConfig, PrivacyConfig

__all__ = ["budget_study"]


def budget_study(encoder, splits, pairs: Sequence[int] = (1000, 10000, 60000), epochs: Sequence[int] = (5, 15, 50),
                 attacks: Sequence[str] = ("learned", "learned_conv"), config: Optional[PrivacyConfig] = None,
                 learned_config: Optional[LearnedConfig] = None, cache_root: str | None = None,
                 progress: Callable[[str], None] | None = None, label: str = "",
                 test_acc: float = float("nan"), resume_dir: str | Path | None = None) -> list[dict[str, Any]]:
    """One row per attack, pair count and maximum epochs (the privacy table's columns,
    :data:`optoenc.privacy.report.COLUMNS`).

    Pair counts above the training split's size are clipped to it (once: a repeated count is measured once).

    Args:
        pairs: the attackers' (embedding, scene) pairs, validation part included.
        epochs: maximum epochs (early stopping as in ``learned_config``).
        attacks: learned attacks (``learned``, ``learned_conv``, ``learned_one``).
        learned_config: the other attacker settings (its ``pairs`` and ``epochs`` are the grid's).
        label: the ``run`` column (e.g. the run directory's name); ``test_acc``: the encoder's accuracy, if known.
        resume_dir: a folder keeping each finished grid point (:class:`~optoenc.privacy.evaluate.AttackStore`):
            a study interrupted and started again with it measures only the points not yet kept.
    """
    from .evaluate import AttackStore, learned_attack, store_token, target

    for a in attacks:
        if a not in LEARNED:
            raise ConfigError("attacks", a, f"one of the learned attacks {', '.join(LEARNED)}")
    if not pairs or not epochs:
        raise ConfigError("budget grid", (tuple(pairs), tuple(epochs)), "needs at least one pair count and one epoch count")
    say = progress or (lambda _msg: None)
    base = learned_config or LearnedConfig()
    tgt = target(encoder, splits, config, cache_root, say)
    train = splits.train[0]
    counts = sorted({min(int(p), len(train)) for p in pairs})
    a, b = encoder.geometry.embedding
    store = None if resume_dir is None else AttackStore(resume_dir, store_token(tgt.y, train, tgt.config, base, label,
                                                                                 test_acc))
    rows = []
    for attack in attacks:
        for n in counts:
            for e in sorted({int(v) for v in epochs}):
                key = f"{attack}-{n}-{e}"
                kept = store.load(key) if store else None
                if kept is not None:
                    say(f"{attack}: {n} pairs, at most {e} epochs (kept from an earlier, interrupted study)")
                    rows += kept[0]
                    continue
                say(f"{attack}: {n} pairs, at most {e} epochs")
                recons, budget = learned_attack(tgt, attack, train, dataclasses.replace(base, pairs=n, epochs=e))
                row = tgt.measure(attack, recons, **budget)
                rows.append({"encoder": encoder.name, "embedding": f"{a}x{b}", "test_acc": test_acc, "run": label, **row})
                if store:
                    store.save(key, rows[-1:], {})
    return rows

