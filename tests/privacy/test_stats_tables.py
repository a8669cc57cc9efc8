"""Wilson intervals, the table's threat-model and budget columns, and the strongest attack per threat model."""

from __future__ import annotations

import math

import pytest

from optoenc.errors import ConfigError
from optoenc.privacy.report import COLUMNS, best_markdown, best_per_threat_model, markdown, read_table, write_table
from optoenc.privacy.settings import ATTACKS, THREAT_MODEL, THREAT_MODELS
from optoenc.privacy.stats import wilson

Z95 = 1.959963984540054  # the two-sided 95 % normal quantile


def _closed_form(hits: int, n: int) -> tuple[float, float]:
    """Wilson's interval in its closed form (2 n p + z^2 -+ z sqrt(z^2 + 4 n p (1 - p))) / (2 (n + z^2))."""
    p, z2 = hits / n, Z95 * Z95
    root = Z95 * math.sqrt(z2 + 4 * n * p * (1 - p))
    return (2 * n * p + z2 - root) / (2 * (n + z2)), (2 * n * p + z2 + root) / (2 * (n + z2))


@pytest.mark.parametrize("hits,n,published", [
    (0, 100, (0.0, 0.0370)),  # 0 %: an upper bound, not "0 +- 0"
    (100, 100, (0.9630, 1.0)),
    (50, 100, (0.4038, 0.5962)),
    (1, 1000, (0.0001766, 0.005643)),
])
def test_wilson_against_hand_computed_values(hits, n, published):
    """``published``: the interval worked by hand from the closed form, to four significant digits."""
    low, high = wilson(hits / n, n)
    ref = _closed_form(hits, n)
    # The two algebraic forms agree to rounding; the hand-worked values to their last digit.
    assert low == pytest.approx(ref[0], abs=1e-12) and high == pytest.approx(ref[1], abs=1e-12)
    assert low == pytest.approx(published[0], abs=6e-5) and high == pytest.approx(published[1], abs=6e-5)


def test_wilson_narrows_with_probes_and_rejects_bad_input():
    widths = [wilson(0.3, n)[1] - wilson(0.3, n)[0] for n in (100, 1000, 10000)]
    assert widths[0] > widths[1] > widths[2]
    assert widths[1] == pytest.approx(2 * Z95 * math.sqrt(0.3 * 0.7 / 1000), rel=0.01)  # large n: the normal one
    for rate, n in ((0.5, 0), (1.2, 10)):
        with pytest.raises(ConfigError):
            wilson(rate, n)


def test_every_attack_has_a_threat_model():
    assert set(ATTACKS) <= set(THREAT_MODEL)
    assert {THREAT_MODEL[a] for a in ATTACKS} == set(THREAT_MODELS)
    assert THREAT_MODEL["learned_conv"] == "black_box" and THREAT_MODEL["pinv"] == "known_mask"


def _row(attack, reid, psnr=15.0, readability=0.5, run="lens-6x8", **extra):
    lo, hi = wilson(reid, 1000)
    return {"encoder": "lens", "embedding": "6x8", "run": run, "attack": attack, "threat_model": THREAT_MODEL[attack],
            "n_pairs": "", "psnr": psnr, "psnr_std": 1.0, "ssim": 0.5, "ssim_std": 0.1, "readability": readability,
            "readability_se": 0.01, "readability_ci_low": 0.45, "readability_ci_high": 0.55, "reid_top1": reid,
            "reid_top1_se": 0.01, "reid_ci_low": lo, "reid_ci_high": hi, "test_acc": 0.9, "count": 1000, **extra}


def _cell(run="lens-6x8"):
    learned = dict(n_pairs=60000, val_pairs=6000, max_epochs=50, epochs_run="12;14;11", val_loss=0.03, attack_seeds=3,
                   reid_seeds="0.5;0.52;0.49")
    return [
        _row("mean_scene", 0.9, run=run),  # the floor scores high here on purpose: it must not count
        _row("admm", 0.05, run=run), _row("pinv", 0.20, run=run),
        _row("plaintext", 0.12, run=run, n_pairs=100), _row("plaintext", 0.30, run=run, n_pairs=10000),
        _row("plaintext", 0.30, psnr=12.0, run=run, n_pairs=1000),  # ties on re-id and readability: lower PSNR loses
        _row("learned", 0.51, run=run, **learned), _row("learned_conv", 0.40, run=run, **learned),
    ]


def test_best_per_threat_model_picks_the_highest_reidentification():
    rows = _cell() + _cell("lens-24x32")
    best = best_per_threat_model(rows)
    assert [(r["run"], r["threat_model"], r["attack"]) for r in best] == [
        (run, t, a) for run in ("lens-6x8", "lens-24x32")
        for t, a in (("known_mask", "pinv"), ("plaintext", "plaintext"), ("black_box", "learned"))]
    by = {r["threat_model"]: r for r in best[:3]}
    assert by["plaintext"]["n_pairs"] == 10000 and by["black_box"]["reid_top1"] == 0.51
    # No better row under the same threat model exists in its cell.
    for b in best:
        assert all(r["reid_top1"] <= b["reid_top1"] for r in rows
                   if r["run"] == b["run"] and r["threat_model"] == b["threat_model"])
    # A table read back without the threat_model column: taken from the attack.
    assert [r["attack"] for r in best_per_threat_model([{**r, "threat_model": ""} for r in rows[:8]])] == [
        "pinv", "plaintext", "learned"]
    assert "| lens | 6x8 | 90.0 % | black_box | learned | 54000+6000 pairs, 12;14;11/50 ep, 3 seeds | 51.0 [47.9, 54.1] |" \
        in best_markdown(rows)


def test_table_columns_round_trip_and_intervals_in_markdown(tmp_path):
    rows = _cell() + [_row("admm", 0.0), _row("pinv", 1.0)]
    assert {"threat_model", "n_pairs", "val_pairs", "max_epochs", "epochs_run", "val_loss", "attack_seeds", "reid_ci_low",
            "reid_ci_high", "readability_ci_low", "readability_ci_high", "reid_seeds"} <= set(COLUMNS)
    back = read_table(write_table(rows, tmp_path / "t.csv", tmp_path / "t.md"))
    learned = next(r for r in back if r["attack"] == "learned")
    assert learned["epochs_run"] == "12;14;11" and learned["max_epochs"] == 50.0 and learned["reid_seeds"] == "0.5;0.52;0.49"
    assert learned["threat_model"] == "black_box" and learned["val_loss"] == pytest.approx(0.03)
    md = markdown(back)
    # 0 % and 100 % of 1000 probes: their intervals, never "+- 0.0"
    assert "| 0.0 [0.0, 0.4] |" in md and "| 100.0 [99.6, 100.0] |" in md and "+- 0.0 %" not in md
    assert "| plaintext | N=10000 |" in md
    assert (tmp_path / "t.md").read_text().startswith("## Strongest attack per threat model")
