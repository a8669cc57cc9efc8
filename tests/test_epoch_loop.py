"""trainer.loop = 'epoch': a whole epoch of precomputed embeddings per Lightning step, trained exactly as per batch."""

from __future__ import annotations

import pytest
import torch

from optoenc.cli import main
from optoenc.config import compose
from optoenc.errors import ConfigError
from optoenc.training import fit
from optoenc.training.callbacks import read_metrics
from optoenc.training.epoch_loop import batch_count, resolve_loop
from optoenc.training.loaders import make_loader

TINY = ["dataset.val_size=100", "dataset.test_size=100", "sensor.embedding=[6,8]", "fidelity.grid=[48,64]",
        "trainer.progress=false", "trainer.verify_preset=null", "output.examples=0", "trainer.test_every_epoch=true"]


@pytest.mark.parametrize("n", [1, 2, 199, 200, 201, 399, 400, 401, 450, 1000])
@pytest.mark.parametrize("batch_size", [1, 2, 200])
def test_batch_count_is_the_per_batch_loaders_length(n, batch_size):
    # The epoch loop must step through exactly the batches the per-batch loader yields (a last batch
    # of one example is dropped for BatchNorm, any other ragged one kept).
    loader = make_loader(torch.zeros(n, 1), torch.zeros(n, dtype=torch.long), batch_size, shuffle=True)
    assert batch_count(n, batch_size) == len(loader) == len(list(loader))


@pytest.mark.parametrize("n", [401, 450])
def test_the_whole_epoch_batch_gathers_the_per_batch_loaders_batches(n):
    # The epoch loop's one batch is the tensors whole plus the epoch's order; gathering its mini-batches by
    # that order must give exactly the per-batch loader's batches, epoch after epoch (the same permutation).
    x, y, u = torch.randn(n, 3), torch.arange(n), torch.rand(n, 2)
    per_batch = make_loader(x, y, 200, shuffle=True, seed=3, extra=(u,))
    whole = make_loader(x, y, 200, shuffle=True, seed=3, extra=(u,), whole_epoch=True)
    for epoch in (0, 1):
        for loader in (per_batch, whole):
            loader.sampler.set_epoch(epoch)  # as Lightning does before every epoch
        (batch,) = list(whole)
        assert batch[0] is x and batch[1] is y and batch[2] is u  # whole and unpermuted: no copy an epoch
        order = batch[-1]
        expected = list(per_batch)
        assert batch_count(len(order), 200) == len(expected)
        for b, (xb, yb, ub) in enumerate(expected):
            idx = order[b * 200 : (b + 1) * 200]
            assert torch.equal(x[idx], xb) and torch.equal(y[idx], yb) and torch.equal(u[idx], ub)


def test_batch_count_applies_lightnings_limit():
    # Lightning's limit_train_batches: a fraction (floored, at least one batch) or a number of batches.
    assert batch_count(1000, 100, 0.25) == 2 and batch_count(1000, 100, 0.01) == 1
    assert batch_count(1000, 100, 3) == 3 and batch_count(1000, 100, 50) == 10 and batch_count(1000, 100, 1.0) == 10


@pytest.mark.filterwarnings("ignore")  # the small grid's sampling warning
@pytest.mark.parametrize(
    "encoder,decoder,extra",
    [
        ("lens", "fcnn", ["dataset.train_size=450"]),  # BatchNorm; a ragged last batch of 50
        ("diffuser", "logistic", ["dataset.train_size=401"]),  # a last batch of one: dropped
        ("lens", "fcnn", ["dataset.train_size=1000", "trainer.limit_train_batches=3"]),
        ("lens", "logistic", ["dataset.train_size=1000", "trainer.limit_train_batches=0.5"]),
        # bfloat16 products (Lightning's autocast around the whole epoch): each mini-batch must multiply by the
        # weights as they are after the previous step, not by the bfloat16 copies autocast cached at the first.
        ("lens", "fcnn", ["dataset.train_size=1000", "trainer.precision=bf16-mixed"]),
        # One torch thread: the epoch loop draws each mini-batch's noise ahead on a helper thread, from a
        # generator of its own seeded as the batch loop reseeds the default one (a ragged last batch of 50).
        ("lens", "fcnn", ["dataset.train_size=450", "trainer.threads=1"]),
        ("diffuser", "logistic", ["dataset.train_size=1000", "trainer.threads=1", "trainer.precision=bf16-mixed"]),
        # Dropout draws from the default generator after the noise: the epoch loop hands the default generator
        # the helper's state after its draw, so the dropout masks are the per-batch loop's. AdamW's decay.
        ("lens", "fcnn", ["dataset.train_size=450", "trainer.threads=1", "decoder.dropout=0.5", "trainer.weight_decay=0.1"]),
    ],
)
def test_the_epoch_loop_trains_exactly_as_the_batch_loop(tmp_path, encoder, decoder, extra, restore_threads):
    # The same batches in the same order, the same per-batch seeds (so the same noise) and the same
    # Adam updates: the weights after two epochs are bit for bit the batch loop's, and so are every
    # metric of metrics.csv but the time. Exact equality: the same float operations on the same
    # tensors in the same order.
    runs = {}
    for loop in ("batch", "epoch"):
        run = compose(overrides=[*TINY, *extra, "trainer.max_epochs=2", f"trainer.loop={loop}"],
                      names={"encoder": encoder, "decoder": decoder}, seed=5)
        summary = fit(run, tmp_path / loop)
        assert summary["loop"] == loop
        ckpt = {w: torch.load(tmp_path / loop / "checkpoints" / f"{w}.ckpt", weights_only=False) for w in ("last", "best")}
        rows = [{k: v for k, v in r.items() if k != "time_s"} for r in read_metrics(tmp_path / loop / "metrics.csv")]
        runs[loop] = (summary, ckpt, rows)
    (sb, cb, rb), (se, ce, re_) = runs["batch"], runs["epoch"]
    for which in ("last", "best"):  # the checkpoints are written at the same epochs; Lightning counts one step
        wb, we = cb[which]["state_dict"], ce[which]["state_dict"]  # an epoch under the epoch loop
        assert wb.keys() == we.keys() and all(torch.equal(wb[k], we[k]) for k in wb)
        assert ce[which]["epoch"] == cb[which]["epoch"]
        assert ce[which]["global_step"] == ce[which]["epoch"] + 1 < cb[which]["global_step"]
    assert cb["last"]["epoch"] == 1
    assert rb == re_ and len(re_) == 2 and all(r["test_acc"] for r in re_)
    assert (sb["test_acc"], sb["best_epoch"]) == (se["test_acc"], se["best_epoch"]) and se["best_epoch"] is not None


@pytest.fixture
def restore_threads():
    """torch's thread count as it was before the test (a run's trainer.threads sets it for the process)."""
    n = torch.get_num_threads()
    yield
    torch.set_num_threads(n)


def test_the_noise_is_drawn_ahead_only_with_one_torch_thread(restore_threads):
    # The helper thread pays where a core is left free of torch's own threads; with two it shares one and
    # the split elementwise products wait for it. Plugin noise (no sigma) is never drawn ahead.
    from optoenc.training.epoch_loop import _draws_ahead

    x, sigma = torch.rand(4, 1, 6, 8), torch.ones(4, 1, 1, 1)
    torch.set_num_threads(1)
    assert _draws_ahead(sigma, x) and not _draws_ahead(None, x)
    torch.set_num_threads(2)
    assert not _draws_ahead(sigma, x)


def test_the_noise_drawn_ahead_is_the_reseeded_default_generators():
    # What add_noise draws from the default generator reseeded for batch b, the helper draws from its own
    # generator: the same numbers, batch by batch, a ragged last batch included.
    from optoenc.training.epoch_loop import _noise_ahead

    x = torch.rand(5, 1, 6, 8)
    from optoenc.training.seeding import train_batch_seed

    seeds = [train_batch_seed(1000, 3, b) for b in range(3)]
    ahead = list(_noise_ahead(seeds, [2, 2, 1], x))
    for b, (drawn, after) in enumerate(ahead):
        torch.default_generator.manual_seed(train_batch_seed(1000, 3, b))
        assert torch.equal(drawn, torch.randn(drawn.shape)) and len(drawn) == [2, 2, 1][b]
        # and the state it leaves is the default generator's after the same draw: what comes next is the same
        assert torch.equal(after, torch.default_generator.get_state())


def test_auto_picks_the_epoch_loop_only_where_it_applies():
    common = dict(world=1, strategy="auto", precision="32-true", adversary=False)
    assert resolve_loop("auto", precomputed=True, **common) == "epoch"
    assert resolve_loop("auto", precomputed=False, **common) == "batch"  # a learned encoder: scenes per batch
    assert resolve_loop("auto", precomputed=True, **{**common, "world": 2}) == "batch"  # DDP: one backward per forward
    assert resolve_loop("auto", precomputed=True, **{**common, "strategy": "ddp"}) == "batch"
    assert resolve_loop("auto", precomputed=True, **{**common, "adversary": True}) == "batch"
    assert resolve_loop("auto", precomputed=True, **{**common, "precision": "16-mixed"}) == "batch"  # gradient scaler
    assert resolve_loop("auto", precomputed=True, **{**common, "precision": "bf16-mixed"}) == "epoch"
    assert resolve_loop("batch", precomputed=True, **common) == "batch"
    with pytest.raises(ConfigError, match=r"trainer\.loop.*epoch.*precomputed"):
        resolve_loop("epoch", precomputed=False, **common)
    with pytest.raises(ConfigError, match=r"trainer\.loop.*16-mixed"):
        resolve_loop("epoch", precomputed=True, **{**common, "precision": "16-mixed"})


def test_cli_refuses_the_epoch_loop_for_a_learned_encoder_with_one_line(tmp_path, capsys):
    code = main(["fit", "--encoder", "learned_slm", "--decoder", "logistic", "--trainer.loop=epoch",
                 f"--output.root={tmp_path}", *[f"--{o}" for o in TINY]])
    lines = capsys.readouterr().err.strip().splitlines()
    # The CLI names the run directory it was about to use, then the one error line.
    assert code == 2 and len(lines) == 2 and lines[0].startswith("run directory: "), lines
    assert lines[1].startswith("optoenc: error:") and "trainer.loop = 'epoch'" in lines[1] and "'batch'" in lines[1]
    assert not any(p.is_file() for p in tmp_path.rglob("*"))  # refused before anything is written


@pytest.mark.parametrize("shape", [(1, 3, 4), (1, 24, 32), (3, 6, 8)])
def test_the_noise_level_computed_once_is_the_per_batch_one_bit_for_bit(shape):
    # The epoch loop computes each example's noise level once for the whole split and reuses it every epoch;
    # the per-batch loop computes it batch by batch. Each example's variance is its own reduction, so the
    # numbers must be identical, and so the noisy embeddings drawn with the same seed.
    from optoenc.encoders.noise import add_noise, snr_sigma

    g = torch.Generator().manual_seed(1)
    x = torch.rand(1000, *shape, generator=g) ** 3
    whole = snr_sigma(x, 40.0)
    idx = torch.randperm(1000, generator=g)[:200]
    assert torch.equal(whole.index_select(0, idx), snr_sigma(x[idx], 40.0))
    a = add_noise(x[idx], 40.0, generator=torch.Generator().manual_seed(7))
    b = add_noise(x[idx], 40.0, generator=torch.Generator().manual_seed(7), sigma=whole.index_select(0, idx))
    assert torch.equal(a, b) and not torch.equal(a, x[idx])
    # Draws handed in (the epoch loop's, drawn ahead) give the sums drawing them there gives.
    n = torch.randn(x[idx].shape, generator=torch.Generator().manual_seed(7))
    assert torch.equal(add_noise(x[idx], 40.0, sigma=whole.index_select(0, idx), noise=n), a)
    with pytest.raises(ValueError, match="noise: shape"):
        add_noise(x[idx], 40.0, noise=n[:-1])


def test_an_encoder_with_its_own_noise_gets_no_precomputed_noise_level():
    # A plugin may override add_sensor_noise with the older signature (no sigma): the epoch loop passes a
    # precomputed noise level only where noise_sigma gives one, so such an encoder must give none.
    from optoenc.encoders.diffuser import Diffuser

    class OwnNoise(Diffuser):
        def add_sensor_noise(self, clean, generator=None):
            return clean + 0.0

    x = torch.rand(4, *Diffuser().output_shape)
    assert Diffuser().noise_sigma(x) is not None
    assert OwnNoise().noise_sigma(x) is None
