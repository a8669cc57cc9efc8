"""`optoenc reconstruct` and `optoenc privacy` end to end on small inputs; errors exit 2 with one line."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from optoenc.cli import main
from optoenc.config import compose
from optoenc.privacy.report import COLUMNS, read_table
from optoenc.training.rundir import atomic_write_text, write_json

SMALL = ["--sensor.embedding=[12,16]", "--fidelity.preset=fast"]


def _quick_data(tmp_path):
    return ["--dataset.train_size=600", "--dataset.val_size=200", "--dataset.test_size=300",
            f"--trainer.cache_dir={tmp_path / 'cache'}"]


def test_reconstruct_digits_and_image(tmp_path, capsys):
    out = tmp_path / "rec"
    code = main(["reconstruct", "--encoder", "fixed_slm", *SMALL, "--count", "3", "--method", "admm,pinv",
                 "--iterations", "20", "--out", str(out)])
    assert code == 0
    assert (out / "reconstruction.png").stat().st_size > 0
    rec = np.load(out / "reconstructions_admm.npy")
    assert rec.shape == (3, 1, 28, 28) and rec.min() >= 0
    assert np.load(out / "embeddings.npy").shape == (3, 1, 12, 16)
    meta = json.loads((out / "reconstruct.json").read_text())
    assert meta["admm"]["iterations"] == 20 and set(meta["metrics_mean_std"]) == {"admm", "pinv"}
    img = tmp_path / "face.png"
    Image.fromarray((np.random.default_rng(0).random((40, 30)) * 255).astype("uint8")).save(img)
    code = main(["reconstruct", "--encoder", "diffuser", *SMALL, "--image", str(img), "--scene-shape", "20x16",
                 "--out", str(tmp_path / "img")])
    assert code == 0 and np.load(tmp_path / "img" / "reconstructions_admm.npy").shape == (1, 1, 20, 16)


def test_attack_seeds_reach_the_privacy_settings():
    """--attack-seeds sets how many seeds train each learned attacker; without it the settings' default holds."""
    from optoenc.cli.main import build_parser
    from optoenc.cli.privacy import _evaluate_kw
    from optoenc.privacy.settings import PrivacyConfig

    parse = lambda *a: build_parser().parse_known_args(["privacy", "--encoder", "lens", "--out", "x", *a])[0]
    assert _evaluate_kw(parse("--attack-seeds", "1"))["config"].attack_seeds == 1
    assert _evaluate_kw(parse())["config"].attack_seeds == PrivacyConfig().attack_seeds == 3


def test_learned_attacker_options_reach_its_settings():
    """--learned-hidden/-schedule/-lr set the learned attackers (the former attacker: 256 units, constant 1e-3);
    without them the defaults hold."""
    from optoenc.cli.main import build_parser
    from optoenc.cli.privacy import _evaluate_kw
    from optoenc.privacy.settings import LearnedConfig

    parse = lambda *a: build_parser().parse_known_args(["privacy", "--encoder", "lens", "--out", "x", *a])[0]
    lc = _evaluate_kw(parse("--learned-hidden", "256", "--learned-schedule", "constant", "--learned-lr", "1e-3",
                            "--learned-inputs", "standardise"))["learned_config"]
    assert (lc.hidden, lc.schedule, lc.lr, lc.inputs) == (256, "constant", 1e-3, "standardise")
    assert _evaluate_kw(parse())["learned_config"] == LearnedConfig()


@pytest.mark.parametrize("argv,needle", [
    (["reconstruct", "--encoder", "lens", "--method", "magic", "--out", "x"], "--method"),
    (["reconstruct", "--encoder", "lens"], "--out"),
    (["reconstruct", "--run", "/nonexistent/run"], "not a run directory"),
    (["reconstruct", "--encoder", "lens", "--image", "/nonexistent.png", "--out", "x"], "cannot read"),
    (["privacy", "--encoder", "lens", "--attacks", "guess", "--out", "x"], "--attacks"),
    (["privacy", "--sweep", "/nonexistent"], "--sweep"),
    (["privacy", "--encoder", "lens", "--match", "*fcnn*", "--out", "x"], "--match"),
    (["privacy", "--encoder", "lens", "--attack-seeds", "0", "--out", "x"], "attack_seeds"),
    (["privacy", "--encoder", "lens", "--learned-schedule", "cosine", "--out", "x"], "schedule"),
    (["privacy", "--encoder", "lens", "--learned-inputs", "pca", "--out", "x"], "inputs"),
])
def test_errors_are_one_line(argv, needle, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert needle in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def _fake_run(root, name, encoder, emb, acc, extra):
    """A run directory of a fixed encoder as `optoenc fit` leaves it (no checkpoint needed for a fixed encoder)."""
    run = compose(overrides=[o[2:] for o in extra] + [f"sensor.embedding=[{emb[0]},{emb[1]}]", "fidelity.preset=fast"],
                  names={"encoder": encoder})
    d = root / name
    atomic_write_text(d / "config.yaml", run.to_yaml())
    write_json(d / "summary.json", {"test_acc": acc})
    return d


def test_sweep_cells_match_a_pattern(tmp_path):
    """--match picks run directories by name; a sweep's folder stands for its cells/; no match is a named error."""
    from optoenc.errors import ConfigError
    from optoenc.privacy.report import sweep_cells

    cells = tmp_path / "sweep" / "cells"
    for name in ("encoder=lens,decoder=fcnn,seed=0", "encoder=lens,decoder=fcnn,seed=1", "encoder=lens,decoder=logistic,seed=0"):
        write_json(cells / name / "summary.json", {"test_acc": 0.5})
        atomic_write_text(cells / name / "config.yaml", "{}\n")
    (cells / "unfinished").mkdir()
    assert [p.name for p in sweep_cells(tmp_path / "sweep")] == sorted(p.name for p in cells.iterdir())[:3]
    assert [p.name for p in sweep_cells(cells, "*decoder=fcnn,seed=0")] == ["encoder=lens,decoder=fcnn,seed=0"]
    with pytest.raises(ConfigError, match="--match"):
        sweep_cells(cells, "*decoder=unet*")


@pytest.mark.slow
def test_privacy_sweep_table_and_plot(tmp_path, capsys):
    extra = _quick_data(tmp_path)
    sweep = tmp_path / "sweep"
    _fake_run(sweep, "lens-12x16", "lens", (12, 16), 0.9, extra)
    _fake_run(sweep, "lens-3x4", "lens", (3, 4), 0.5, extra)
    args = ["privacy", "--sweep", str(sweep), "--attacks", "admm,learned,learned_conv,plaintext", "--count", "20", "--gallery", "10",
            "--plaintext-n", "50", "--learned-pairs", "200", "--learned-epochs", "1", "--iterations", "20"]
    assert main(args) == 0
    rows = read_table(sweep / "privacy" / "privacy.csv")
    assert {r["attack"] for r in rows} == {"mean_scene", "admm", "learned", "learned_conv", "plaintext"}
    assert {r["embedding"] for r in rows} == {"12x16", "3x4"} and all(k in rows[0] for k in COLUMNS)
    for r in rows:
        assert 0 <= r["reid_top1"] <= 1 and 0 <= r["readability"] <= 1 and r["count"] == 20
    # more sensor pixels per scene pixel, more leak: ADMM on the 12x16 lens beats the 3x4 lens and
    # the no-information floor (the mean scene, re-identified at chance, 1/10, on average)
    admm = {r["embedding"]: r for r in rows if r["attack"] == "admm"}
    floor = {r["embedding"]: r for r in rows if r["attack"] == "mean_scene"}
    assert admm["12x16"]["psnr"] > admm["3x4"]["psnr"]
    assert admm["12x16"]["reid_top1"] > floor["12x16"]["reid_top1"] + 0.3
    assert (sweep / "privacy" / "privacy_utility_learned.png").stat().st_size > 0
    assert (sweep / "privacy" / "privacy_utility.png").stat().st_size > 0
    assert (sweep / "lens-3x4" / "privacy" / "recon_admm.png").is_file()
    md = (sweep / "privacy" / "privacy.md").read_text()
    assert "| lens | 12x16 | 90.0 % | known_mask | admm | - |" in md
    # Every row names its threat model and gives its rates' Wilson intervals around the rate.
    assert {(r["attack"], r["threat_model"]) for r in rows} >= {("admm", "known_mask"), ("learned", "black_box"),
                                                                ("learned_conv", "black_box"), ("plaintext", "plaintext")}
    for r in rows:
        assert r["reid_ci_low"] <= r["reid_top1"] <= r["reid_ci_high"]
        assert r["readability_ci_low"] <= r["readability"] <= r["readability_ci_high"]
    # The learned attacker records its budget: 200 pairs (20 held out), 1 epoch at most, 3 seeds (the default).
    for r in (r for r in rows if r["attack"] in ("learned", "learned_conv")):
        assert (r["n_pairs"], r["val_pairs"], r["max_epochs"], r["epochs_run"], r["attack_seeds"]) == (200, 20, 1, "1;1;1", 3)
        assert r["val_loss"] > 0 and len(r["reid_seeds"].split(";")) == 3
    best = read_table(sweep / "privacy" / "privacy_best.csv")
    assert [(r["embedding"], r["threat_model"]) for r in best] == [
        (e, t) for e in ("12x16", "3x4") for t in ("known_mask", "plaintext", "black_box")]
    assert md.startswith("## Strongest attack per threat model")


def test_an_interrupted_measurement_resumes_at_the_attack_it_was_in(tmp_path, monkeypatch, one_thread):
    """Finished attacks are kept in privacy/partial/ and not run again; the resumed table equals an uninterrupted
    one (every attack draws from its own seeded streams); a kept attack of other settings or other training scenes
    is measured again."""
    from optoenc.cli.main import build_parser
    from optoenc.cli.privacy import _evaluate_kw
    from optoenc.privacy import evaluate as ev
    from optoenc.privacy.report import PARTIAL_DIR, measure_run

    extra = _quick_data(tmp_path)
    run = _fake_run(tmp_path / "sweep", "lens-3x4", "lens", (3, 4), 0.5, extra)
    argv = ["privacy", "--run", str(run), "--attacks", "admm,plaintext,learned", "--count", "20", "--gallery", "10",
            "--plaintext-n", "50", "--learned-pairs", "100", "--learned-epochs", "1", "--attack-seeds", "1"]
    kw = lambda *more: _evaluate_kw(build_parser().parse_known_args(argv + list(more))[0])  # noqa: E731
    partial = run / "privacy" / PARTIAL_DIR

    def stop(*_a, **_k):
        raise KeyboardInterrupt

    with monkeypatch.context() as m:
        m.setattr(ev, "learned_attack", stop)
        with pytest.raises(KeyboardInterrupt):
            measure_run(run, kw())
    assert sorted(p.name for p in partial.iterdir()) == ["admm.pt", "plaintext.pt"]
    assert not (run / "privacy" / "privacy.csv").exists()
    with monkeypatch.context() as m:
        m.setattr(ev, "admm", stop)  # admm and plaintext (whose inversion is ADMM) must come from the store
        with pytest.raises(KeyboardInterrupt):  # ... but not when the settings differ: 30 ADMM iterations
            measure_run(run, kw("--iterations", "30"))
        with pytest.raises(KeyboardInterrupt):  # ... nor when the attackers' training scenes differ (same probes)
            measure_run(run, kw(), overrides=["dataset.train_size=500"])
        resumed = measure_run(run, kw())
    assert not partial.exists()
    fresh = measure_run(run, kw(), out=tmp_path / "fresh")
    # The same computations on the same thread count: equal to the last bit, not merely close.
    assert resumed == fresh and [r["attack"] for r in fresh] == ["mean_scene", "admm", "plaintext", "learned"]
