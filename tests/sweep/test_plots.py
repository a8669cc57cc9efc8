"""The sweep's accuracy figure: one line per encoder, the paper's figures dashed beside them where given."""

from __future__ import annotations

from optoenc.sweep import plots


def _row(encoder, embedding, acc, paper=None):
    return {"encoder": encoder, "embedding": embedding, "decoder": "fcnn", "transform": "original", "test_acc": acc,
            "test_acc_std": None, "paper_acc": paper}


def test_accuracy_figure_draws_the_paper_dashed_where_given(tmp_path, monkeypatch):
    drawn = {}

    def keep(plt, fig, path):
        drawn["lines"] = [(line.get_label(), line.get_linestyle(), list(line.get_ydata()))
                          for ax in fig.axes for line in ax.get_lines()]
        plt.close(fig)
        return path

    monkeypatch.setattr(plots, "save_figure", keep)
    rows = [_row("lens", "24x32", 98.0, 97.7), _row("lens", "6x8", 73.0, 41.8), _row("diffuser", "24x32", 97.0),
            _row("diffuser", "6x8", 85.0)]
    assert plots.accuracy_vs_embedding(rows, tmp_path / "a.png") == tmp_path / "a.png"
    dashed = [line for line in drawn["lines"] if line[1] == "--"]
    assert dashed == [("lens (paper)", "--", [41.8, 97.7])]  # small embedding first; none for the diffuser
    assert plots.accuracy_vs_embedding([], tmp_path / "b.png") is None
