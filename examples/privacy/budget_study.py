"""Budget study of the learned attackers: re-identification over training pairs x maximum epochs, as a CSV.

    python examples/privacy/budget_study.py --run RUN_DIR --out budget.csv
    python examples/privacy/budget_study.py --encoder fixed_slm sensor.embedding=[6,8] --out budget.csv \
        --pairs 1000,10000,60000 --epochs 5,15,50 --attacks learned,learned_conv --seeds 3 --probes 1000

Settings after the options (``section.key=value``) change the run's configuration, e.g. a smaller dataset
for a quick check: ``dataset.train_size=600 dataset.val_size=200 dataset.test_size=300``. Each grid point trains
the attacker afresh with early stopping on a validation part of its pairs; the CSV has the privacy table's
columns (``n_pairs``, ``max_epochs``, ``epochs_run``, ``val_loss``, ``reid_top1`` with its Wilson interval, ...).
Re-identification has levelled off where a row with more pairs or more epochs re-identifies less than 3 points
more than the row before it. The attackers are the library's defaults (the table's attacker) unless
``--hidden``, ``--channels``, ``--lr``, ``--schedule`` or ``--inputs`` say otherwise: the check that the table's
attacker is converged is the same grid point with four times the maximum epochs (``--epochs 200``) or a wider MLP
(``--hidden 2048``) changing re-identification by less than 3 points; the former table attacker is
``--hidden 256 --schedule constant --lr 1e-3 --inputs standardise`` (regenerate.sh names every study). An
interrupted study keeps its finished grid
points in ``OUT.partial/`` and resumes there (removed once the CSV is written).
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

from optoenc.config import compose, encoder_from_run
from optoenc.plugins import get_registry
from optoenc.privacy.budget import budget_study
from optoenc.privacy.report import load_run, write_table
from optoenc.privacy.settings import INPUTS, SCHEDULES, LearnedConfig, PrivacyConfig


def _ints(text: str) -> tuple[int, ...]:
    return tuple(int(v) for v in text.split(",") if v.strip())


def main(argv: list[str] | None = None) -> Path:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--run", help="run directory of `optoenc fit` (its trained encoder and dataset)")
    src.add_argument("--encoder", help="an encoder by registry name")
    p.add_argument("--out", required=True, help="CSV file to write")
    p.add_argument("--pairs", default="1000,10000,60000", help="pair counts (validation part included)")
    p.add_argument("--epochs", default="5,15,50", help="maximum epochs")
    p.add_argument("--attacks", default="learned,learned_conv", help="learned attacks, comma-separated")
    p.add_argument("--seeds", type=int, default=PrivacyConfig().attack_seeds, help="attacker seeds per grid point")
    p.add_argument("--probes", type=int, default=PrivacyConfig().count, help="test scenes attacked")
    p.add_argument("--gallery", type=int, default=PrivacyConfig().gallery, help="re-identification gallery size")
    p.add_argument("--patience", type=int, default=LearnedConfig().patience, help="early-stopping patience")
    p.add_argument("--hidden", type=int, default=LearnedConfig().hidden, help="the MLP attacker's hidden units per layer")
    p.add_argument("--channels", type=int, default=LearnedConfig().channels,
                   help="the convolutional attacker's channels in its first feature map")
    p.add_argument("--lr", type=float, default=LearnedConfig().lr, help="the attackers' Adam learning rate "
                   "(one_cycle: its peak)")
    p.add_argument("--schedule", default=LearnedConfig().schedule, choices=SCHEDULES,
                   help="the attackers' learning-rate schedule")
    p.add_argument("--inputs", default=LearnedConfig().inputs, choices=INPUTS,
                   help="the attackers' input scaling")
    p.add_argument("overrides", nargs="*", help="section.key=value settings of the run")
    args = p.parse_args(argv)
    if args.run:
        run, encoder, summary = load_run(args.run, args.overrides)
        label, acc = Path(args.run).name, summary.get("test_acc", float("nan"))
    else:
        run = compose(overrides=list(args.overrides), names={"encoder": args.encoder})
        encoder, label, acc = encoder_from_run(run).eval(), args.encoder, float("nan")
    splits = get_registry("dataset").get(run.names["dataset"])(run.dataset).load()
    partial = Path(args.out).with_suffix(".partial")
    rows = budget_study(
        encoder, splits, _ints(args.pairs), _ints(args.epochs), tuple(a for a in args.attacks.split(",") if a),
        config=PrivacyConfig(count=args.probes, gallery=args.gallery, attack_seeds=args.seeds),
        learned_config=LearnedConfig(patience=args.patience, hidden=args.hidden, channels=args.channels, lr=args.lr,
                                     schedule=args.schedule, inputs=args.inputs), cache_root=run.trainer.cache_dir,
        progress=lambda msg: print(f"  {msg} ...", file=sys.stderr), label=label, test_acc=acc,
        resume_dir=partial,
    )
    for r in rows:
        print(f"{r['attack']:13s} pairs {r['n_pairs']:6d}  epochs {r['epochs_run']}/{r['max_epochs']}  "
              f"val loss {r['val_loss']:.4f}  re-id {100 * r['reid_top1']:.1f} % "
              f"[{100 * r['reid_ci_low']:.1f}, {100 * r['reid_ci_high']:.1f}]")
    path = write_table(rows, args.out)
    shutil.rmtree(partial, ignore_errors=True)
    return path


if __name__ == "__main__":
    print(main())
