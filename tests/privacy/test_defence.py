"""Defence measurement: the variable-pattern attacks end to end, and the defence table against its baseline."""

from __future__ import annotations

import pytest

from optoenc.cli import main
from optoenc.privacy.defence import defence_rows, markdown
from optoenc.privacy.report import read_table
from optoenc.training.rundir import atomic_write_text

pytestmark = pytest.mark.filterwarnings("ignore::optoenc.optics.SamplingWarning")


def _run_dir(root, name, patterns, weight):
    d = root / name
    atomic_write_text(d / "config.yaml", f"encoder:\n  patterns: {patterns}\nprivacy:\n  adversary_weight: {weight}\n"
                                         "trainer:\n  max_epochs: 5\n")
    return d


def _rows(psnr, ssim, reid, acc):
    return [{"encoder": "learned_slm", "embedding": "24x32", "attack": "admm", "n_pairs": "", "psnr": psnr, "ssim": ssim,
             "reid_top1": reid, "reid_top1_se": 0.01, "readability": 0.9, "test_acc": acc, "count": 300, "run": "r"}]


def test_defence_rows_against_the_baseline(tmp_path):
    cells = [(_run_dir(tmp_path, "k4", 4, 0), _rows(14.0, 0.5, 0.25, 0.94)),
             (_run_dir(tmp_path, "k1", 1, 0), _rows(28.0, 1.0, 1.0, 0.95)),
             (_run_dir(tmp_path, "l10", 1, 10), _rows(21.0, 0.8, 0.5, 0.93))]
    one = _rows(7.0, 0.25, 0.0, 0.94)[0] | {"attack": "learned_one"}
    cells[0][1].append(one)
    cells[1][1].append(_rows(14.0, 0.5, 0.5, 0.95)[0] | {"attack": "learned"})
    cells[0][1].append(_rows(7.0, 0.25, 0.5, 0.94)[0] | {"attack": "plaintext", "n_pairs": 1000})
    cells[1][1].append(_rows(28.0, 1.0, 1.0, 0.95)[0] | {"attack": "plaintext", "n_pairs": 1000.0})  # read back
    out = defence_rows(cells)
    assert [r["psnr_drop"] for r in out if r["attack"] == "plaintext" and r["patterns"] == 4] == [pytest.approx(0.75)]
    # learned_one (K = 4 only) is compared with the baseline's learned attacker
    assert [r["psnr_drop"] for r in out if r["attack"] == "learned_one"] == [pytest.approx(0.5)]
    rows = {(r["patterns"], r["adversary_weight"]): r for r in out if r["attack"] == "admm"}
    base, k4, lam = rows[(1, 0.0)], rows[(4, 0.0)], rows[(1, 10.0)]
    assert base["psnr_drop"] == 0 and base["epochs"] == 5
    # Relative drops 1 - value / baseline, rate changes in absolute terms (exact decimal arithmetic aside).
    assert k4["psnr_drop"] == pytest.approx(0.5) and k4["ssim_drop"] == pytest.approx(0.5)
    assert k4["reid_change"] == pytest.approx(-0.75) and k4["acc_change"] == pytest.approx(-0.01)
    assert lam["psnr_drop"] == pytest.approx(0.25) and lam["reid_change"] == pytest.approx(-0.5)
    assert "| 24x32 | 4 | 0 | 0 | 94.0 | admm | 14.0 | 0.50 | 25.0 +- 1.0 | 90.0 | +50.0 | +50.0 | -75.0 | -1.0 |" in markdown(
        list(rows.values()))


@pytest.mark.slow
def test_variable_pattern_attacks_end_to_end(tmp_path, capsys):
    data = ["--dataset.train_size=600", "--dataset.val_size=200", "--dataset.test_size=300",
            f"--trainer.cache_dir={tmp_path / 'cache'}", "--sensor.embedding=[6,8]", "--fidelity.preset=fast"]
    args = ["--attacks", "admm,admm_search,learned,learned_one", "--count", "20", "--gallery", "10",
            "--learned-pairs", "200", "--learned-epochs", "1", "--iterations", "20"]
    assert main(["privacy", "--encoder", "learned_slm", "--encoder.patterns=2", "--out", str(tmp_path / "k2"), *args, *data]) == 0
    k2 = {r["attack"]: r for r in read_table(tmp_path / "k2" / "privacy.csv")}
    assert set(k2) == {"mean_scene", "admm", "admm_search", "learned", "learned_one"}
    capsys.readouterr()
    assert main(["privacy", "--encoder", "learned_slm", "--out", str(tmp_path / "k1"), *args, *data]) == 0
    k1 = {r["attack"]: r for r in read_table(tmp_path / "k1" / "privacy.csv")}
    # One pattern: the index-search and one-pattern attackers are the plain ones, not repeated, and a note says so.
    assert set(k1) == {"mean_scene", "admm", "learned"}
    notes = [line for line in capsys.readouterr().err.splitlines() if "note:" in line]
    assert notes == ["  note: admm_search not run: learned_slm shows one pattern, where it is the same attack as admm",
                     "  note: learned_one not run: learned_slm shows one pattern, where it is the same attack as learned"]
    # Pattern 0 of the K = 2 camera is the K = 1 pattern, but the captures differ (half through pattern 1).
    assert k1["admm"]["psnr"] != k2["admm"]["psnr"]
    capsys.readouterr()
    assert main(["privacy", "--encoder", "learned_slm", "--defence", "--out", str(tmp_path / "x"), *args, *data]) == 2
    assert "--defence" in capsys.readouterr().err
