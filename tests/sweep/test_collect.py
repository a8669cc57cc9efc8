"""What a sweep collects from its cells."""

from __future__ import annotations

from optoenc import sweep


def _rows(tmp_path, spec_text: str) -> list[dict]:
    """The collected rows of a spec's (unrun) cells."""
    spec_file = tmp_path / "s.yaml"
    spec_file.write_text(spec_text)
    spec = sweep.load_spec(spec_file)
    return sweep.cell_rows(spec, sweep.plan(spec, tmp_path / "out"))


def _finish(rows, acc=lambda r: 90.0) -> list[dict]:
    for r in rows:
        r.update(state="finished", test_acc=acc(r), best_test_acc=91.0, wall_time_s=1.0)
    return sweep.aggregate(rows)


def test_collected_rows_name_each_cells_draw_mode(tmp_path):
    # Table 3's augment_mode column: "once" (the paper's protocol) or "epoch", from trainer.augment_draw; it
    # used to read a setting that does not exist and said "per_epoch" for every cell.
    rows = _rows(tmp_path, "name: s\nbase: {decoder: logistic, trainer: {max_epochs: 1}}\n"
                 "axes:\n  - encoder: [lens]\n    augment: [shift, null]\n    trainer.augment_draw: [once, epoch]\n")
    got = {(r["transform"], r["augment_mode"]) for r in rows}
    assert got == {("shift", "once"), ("shift", "epoch"), ("original", "")}


def test_cells_trained_in_bfloat16_are_labelled_and_kept_apart(tmp_path):
    # A bfloat16 cell and its float32 twin must not be averaged as if they were seeds of one cell.
    rows = _rows(tmp_path, "name: s\nbase: {encoder: lens, decoder: logistic, trainer: {max_epochs: 1}}\n"
                 "axes:\n  - fidelity.operator_dtype: [same, bfloat16]\n    trainer.precision: [32-true, bf16-mixed]\n"
                 "cells:\n  - {fidelity.preset: reference}\n")
    assert [r["precision"] for r in rows] == ["float32/32-true", "float32/bf16-mixed", "bfloat16/32-true",
                                              "bfloat16/bf16-mixed", "float64/32-true"]
    assert len(_finish(rows)) == 5


def test_a_cells_other_axis_settings_are_its_variant(tmp_path):
    # table3_paper's perspective about the field must not be averaged with (or mistaken for) Table 3's.
    rows = _rows(tmp_path, "name: s\nbase: {encoder: lens, decoder: logistic, augment: perspective, trainer: {max_epochs: 1}}\n"
                 "axes:\n  - augment.perspective.about: [object, field]\n    seed: [0, 1]\n")
    assert [r["variant"] for r in rows] == ["about=object", "about=object", "about=field", "about=field"]
    agg = _finish(rows, lambda r: 90.0 + r["seed"])
    assert [(a["variant"], a["seeds"]) for a in agg] == [("about=object", 2), ("about=field", 2)]  # seeds pooled
