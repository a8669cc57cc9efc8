"""What a sweep collects from its cells."""

from __future__ import annotations


def test_collected_rows_name_each_cells_draw_mode(tmp_path):
    # Table 3's augment_mode column: "once" (the paper's protocol) or "epoch", from trainer.augment_draw; it
    # used to read a setting that does not exist and said "per_epoch" for every cell.
    from optoenc import sweep

    spec_file = tmp_path / "s.yaml"
    spec_file.write_text(
        "name: s\nbase: {decoder: logistic, trainer: {max_epochs: 1}}\n"
        "axes:\n  - encoder: [lens]\n    augment: [shift, null]\n    trainer.augment_draw: [once, epoch]\n"
    )
    spec = sweep.load_spec(spec_file)
    rows = sweep.cell_rows(spec, sweep.plan(spec, tmp_path / "out"))
    got = {(r["transform"], r["augment_mode"]) for r in rows}
    assert got == {("shift", "once"), ("shift", "epoch"), ("original", "")}
