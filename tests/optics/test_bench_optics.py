"""The optics benchmark returns rows and renders them (tiny grid: a smoke test, not a timing)."""

from optoenc.bench import optics as bench_optics


def test_run_and_format_table():
    rows = bench_optics.run(sizes=((24, 32),), repeats=1)
    assert len(rows) == 4  # {1, 3} wavelengths x {float32, float64}
    keys = {"shape", "padded", "wavelengths", "dtype", "batched_ms", "looped_ms", "ratio", "train_ms"}
    for r in rows:
        assert set(r) == keys and r["shape"] == (24, 32)
        assert r["batched_ms"] > 0 and r["looped_ms"] > 0 and r["ratio"] == r["batched_ms"] / r["looped_ms"]
    table = bench_optics.format_table(rows)
    assert "batched/looped" in table and len(table.splitlines()) == 2 + len(rows)
