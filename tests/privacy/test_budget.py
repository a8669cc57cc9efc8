"""The learned attackers' budget study (pairs x epochs) through its example script, on a tiny setting."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

from optoenc.privacy.report import read_table

SCRIPT = Path(__file__).resolve().parents[2] / "examples" / "privacy" / "budget_study.py"


def _script():
    spec = importlib.util.spec_from_file_location("budget_study", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.usefixtures("one_thread")
def test_budget_study_writes_one_row_per_grid_point(tmp_path, capsys):
    out = _script().main([
        "--encoder", "lens", "--out", str(tmp_path / "budget.csv"), "--pairs", "100,200,100000", "--epochs", "1,3",
        "--attacks", "learned,learned_conv", "--seeds", "1", "--probes", "20", "--gallery", "10", "--patience", "1",
        "--hidden", "24", "--channels", "12", "sensor.embedding=[6,8]", "fidelity.preset=fast", "dataset.train_size=600", "dataset.val_size=200",
        "dataset.test_size=300", f"trainer.cache_dir={tmp_path / 'cache'}",
    ])
    rows = read_table(out)
    # 100,000 pairs are clipped to the 600 training scenes: 2 attacks x 3 pair counts x 2 epoch budgets.
    grid = [(r["attack"], int(r["n_pairs"]), int(r["max_epochs"])) for r in rows]
    assert grid == [(a, n, e) for a in ("learned", "learned_conv") for n in (100, 200, 600) for e in (1, 3)]
    for r in rows:
        assert r["threat_model"] == "black_box" and r["count"] == 20 and r["attack_seeds"] == 1
        assert r["attacker_size"] == (12 if r["attack"] == "learned_conv" else 24)  # --channels, --hidden
        assert 1 <= float(r["epochs_run"]) <= r["max_epochs"] and r["val_loss"] > 0
        assert r["val_pairs"] == round(0.1 * r["n_pairs"])
        assert r["reid_ci_low"] <= r["reid_top1"] <= r["reid_ci_high"]
    assert "learned_conv  pairs    600  epochs" in capsys.readouterr().out


@pytest.mark.usefixtures("one_thread")
def test_an_interrupted_budget_study_resumes_at_its_grid_point(tmp_path, monkeypatch):
    """Finished grid points are kept in OUT.partial/ and not trained again; the resumed CSV equals an
    uninterrupted one (each grid point draws from its own seeded streams)."""
    from optoenc.privacy import evaluate as ev

    out = tmp_path / "budget.csv"
    argv = ["--encoder", "lens", "--out", str(out), "--pairs", "100,200", "--epochs", "1", "--attacks", "learned",
            "--seeds", "1", "--probes", "20", "--gallery", "10", "--hidden", "16", "sensor.embedding=[6,8]",
            "fidelity.preset=fast", "dataset.train_size=600", "dataset.val_size=200", "dataset.test_size=300",
            f"trainer.cache_dir={tmp_path / 'cache'}"]
    real, calls = ev.learned_attack, []

    def stop_at_second(*a, **k):
        calls.append(k or a[3])
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(*a, **k)

    monkeypatch.setattr(ev, "learned_attack", stop_at_second)
    with pytest.raises(KeyboardInterrupt):
        _script().main(argv)
    assert [p.name for p in out.with_suffix(".partial").iterdir()] == ["learned-100-1.pt"] and not out.exists()
    resumed = _script().main(argv)  # only the 200-pair point is trained: the third call
    assert len(calls) == 3 and not out.with_suffix(".partial").exists()
    monkeypatch.setattr(ev, "learned_attack", real)
    fresh = _script().main(argv[:3] + [str(tmp_path / "fresh.csv")] + argv[4:])
    assert resumed.read_text() == fresh.read_text() and len(read_table(fresh)) == 2
