"""The privacy-utility figures: each threat model's panel plots its own strongest attacks, with their intervals."""

from __future__ import annotations

from optoenc.privacy import pictures
from optoenc.privacy.settings import THREAT_MODELS


def _best(encoder, embedding, threat, acc, reid, low, high):
    return {"encoder": encoder, "embedding": embedding, "threat_model": threat, "attack": "x", "test_acc": acc,
            "reid_top1": reid, "reid_ci_low": low, "reid_ci_high": high}


def test_threat_panels_plot_their_own_rows_with_wilson_bars(monkeypatch, tmp_path):
    drawn = {}

    def keep(plt, fig, path):
        drawn["axes"] = [(ax.get_title(), [(c.get_label(), list(c.lines[0].get_xdata())) for c in ax.containers],
                          [list(c.lines[2][0].get_segments()) for c in ax.containers]) for ax in fig.axes]
        plt.close(fig)
        return path

    monkeypatch.setattr(pictures, "save_figure", keep)
    best = [_best("lens", "24x32", "known_mask", 0.98, 0.99, 0.98, 0.995),
            _best("lens", "6x8", "known_mask", 0.73, 0.10, 0.08, 0.12),
            _best("lens", "24x32", "black_box", 0.98, 0.40, 0.37, 0.43),
            _best("diffuser", "6x8", "black_box", 0.85, 0.05, 0.04, 0.07)]
    pictures.save_threat_frontiers(tmp_path / "f.png", best, THREAT_MODELS, chance=0.01)
    known, plain, black = drawn["axes"]
    assert known[0] == "threat model: known_mask" and known[1] == [("lens", [10.0, 99.0])]  # small embedding first
    assert plain[1] == []  # no plaintext rows: an empty panel, not another model's rows
    assert sorted(black[1]) == [("diffuser", [5.0]), ("lens", [40.0])]
    # the 6x8 lens point's horizontal bar spans its Wilson interval, 8 % to 12 % (1e-9: 100 * 0.08 in binary floats)
    bars = [seg for segs in known[2] for seg in segs]
    assert any(abs(seg[0][0] - 8.0) < 1e-9 and abs(seg[1][0] - 12.0) < 1e-9 for seg in bars)
