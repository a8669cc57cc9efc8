"""Tasks (classification, reconstruction) and the reconstruction decoders (unet, tikhonov, unrolled_admm)."""

from __future__ import annotations

import json
import warnings

import pytest
import torch

from optoenc.config import build_encoder, compose
from optoenc.decoders.image import Tikhonov, UNet, UnrolledADMM
from optoenc.errors import ConfigError
from optoenc.plugins import get_registry
from optoenc.testing import check_task

FAST = {"preset": "fast"}


def _encoder(name: str, embedding, color: str = "gray"):
    return build_encoder(name, sensor={"embedding": list(embedding), "color": color}, fidelity=FAST)


@pytest.mark.parametrize("embedding,scene", [((3, 4), (1, 28, 28)), ((24, 32), (1, 28, 28)), ((48, 64), (1, 128, 128)),
                                             ((6, 8), (3, 20, 30))])
def test_unet_maps_every_embedding_to_the_scene(embedding, scene):
    C = 3 if scene[0] == 3 else 1
    dec = UNet(None, in_shape=(C, *embedding), out_shape=scene, learnable_encoder=True)
    out = dec(torch.rand(2, C, *embedding))
    assert out.shape == (2, *scene) and torch.isfinite(out).all()


@pytest.mark.parametrize("cls", [Tikhonov, UnrolledADMM])
@pytest.mark.parametrize("embedding,scene,denoiser", [((3, 4), (12, 12), "none"), ((24, 32), (28, 28), "unet"),
                                                      ((6, 8), (20, 28), "none")])
def test_physics_decoders_give_the_scene_shape(cls, embedding, scene, denoiser):
    enc = _encoder("diffuser", embedding)
    dec = cls({"denoiser": denoiser}, in_shape=enc.output_shape, out_shape=(1, *scene), encoder=enc)
    with torch.no_grad():
        out = dec(enc(torch.rand(2, 1, *scene)))
    assert out.shape == (2, 1, *scene) and torch.isfinite(out).all()


@pytest.mark.parametrize("color,scene_channels", [("rgb", 3), ("rgb", 1), ("bayer", 3), ("bayer", 1)])
def test_physics_decoders_on_colour_sensors(color, scene_channels):
    """RGB planes (block-diagonal operator for RGB scenes) and the Bayer mosaic (one plane: the mosaic's rows)."""
    enc = _encoder("diffuser", (6, 8), color)
    shape = (scene_channels, 12, 12)
    dec = UnrolledADMM(None, in_shape=enc.output_shape, out_shape=shape, encoder=enc)
    x = torch.rand(2, *shape)
    with torch.no_grad():
        y = enc.measure(x)
        out = dec(y)
        # the matrix in the graph reproduces the measurement, up to float32 sums taken in another order (1e-4)
        M = enc.operator((12, 12), scene_channels=scene_channels).matrix_in_graph()
        assert torch.allclose((x.flatten(1).double() @ M.T).float(), y.flatten(1), rtol=1e-4, atol=1e-6 * float(y.abs().max()))
    assert out.shape == (2, *shape) and torch.isfinite(out).all()


@pytest.mark.parametrize("cls", [Tikhonov, UnrolledADMM])
def test_the_mask_learns_through_the_physics_decoder(cls):
    """The measurement is held fixed (no graph): the only path from the loss to the mask is the decoder's operator."""
    torch.manual_seed(0)
    enc = _encoder("learned_slm", (6, 8))
    dec = cls(None, in_shape=enc.output_shape, out_shape=(1, 16, 16), encoder=enc, learnable_encoder=True)
    x = torch.rand(3, 1, 16, 16)
    with torch.no_grad():
        y = enc.measure(x)
    (dec(y) - x).pow(2).mean().backward()
    grads = [p.grad for p in enc.parameters() if p.requires_grad]
    assert grads and all(g is not None and torch.isfinite(g).all() for g in grads)
    assert max(float(g.abs().max()) for g in grads) > 0


def test_tikhonov_recovers_the_scene_of_a_well_posed_operator():
    """A lens at 24 x 32 sees a 12 x 12 scene through a 768 x 144 matrix of condition number ~2: with lambda -> 0 the
    solve is the least-squares inverse, exact up to the float32 operator's rounding (~1e-7 x the condition number;
    1e-5 leaves room). A real regularisation weight (lambda = 1, relative) is visibly biased: the test can fail."""
    enc = _encoder("lens", (24, 32))
    x = torch.rand(3, 1, 12, 12)
    with torch.no_grad():
        y = enc.measure(x)
        errors = {}
        for lam in (1e-12, 1.0):
            dec = Tikhonov({"lam": lam, "learn_lambda": False}, in_shape=enc.output_shape, out_shape=(1, 12, 12), encoder=enc)
            errors[lam] = float((dec(y) - x).norm() / x.norm())
    assert errors[1e-12] < 1e-5
    assert errors[1.0] > 0.1


@pytest.mark.parametrize("cls", [Tikhonov, UnrolledADMM])
@pytest.mark.parametrize("scene", [(12, 12), (40, 40)])  # n = 144 < m = 768 (M^T M) and n = 1600 > m (M M^T)
def test_a_fixed_operator_solves_from_one_eigendecomposition(cls, scene):
    """A fixed encoder's solves use one cached eigendecomposition of the Gram matrix instead of a factorisation
    per solve: the same reconstruction as the factorisations, and the cache follows the operator's values.
    Tolerance: each path rounds at about float64's 1.1e-16 times the regularised system's condition number
    (1e3 at 12 x 12, 1.1e4 at 40 x 40 for this diffuser with rho = 0.1), amplified through the Woodbury
    subtraction and five iterations (measured difference 1.5e-9 at 40 x 40); 1e-7 relative leaves room and
    stays 4 orders below an 8-bit grey level (3.9e-3)."""
    enc = _encoder("diffuser", (24, 32))
    dec = cls(None, in_shape=enc.output_shape, out_shape=(1, *scene), encoder=enc)
    y = enc.measure(torch.rand(3, 1, *scene)).detach()
    M = dec.matrix()
    fast = dec.solve(y.flatten(1).double(), M)
    first = dec.spectrum(M)
    assert first is not None and dec.spectrum(M.clone()) is first  # equal values: no new eigendecomposition
    assert dec.spectrum(M * 2) is not first  # other values: rebuilt
    dec.spectrum = lambda M: None  # the factorisation path, as for a learnable encoder
    slow = dec.solve(y.flatten(1).double(), M)
    assert float((fast - slow).abs().max() / slow.abs().max()) < 1e-7


def test_physics_decoders_refuse_a_normalised_embedding():
    enc = _encoder("diffuser", (6, 8))
    with pytest.raises(ConfigError, match="embedding_norm"):
        Tikhonov({"embedding_norm": "standardize"}, in_shape=enc.output_shape, out_shape=(1, 12, 12), encoder=enc)


@pytest.mark.parametrize("name", ["classification", "reconstruction"])
def test_the_task_kit_passes(name):
    report = check_task(get_registry("task").get(name))
    assert all(v == "ok" for v in report.values()), report


def _run(tmp_path, decoder: str, encoder: str, *extra: str, name: str = "r"):
    return compose(names={"task": "reconstruction", "decoder": decoder, "encoder": encoder}, overrides=[
        "dataset.train_size=96", "dataset.val_size=32", "dataset.test_size=32", "trainer.batch_size=32",
        "trainer.eval_batch_size=32", "trainer.limit_train_batches=3", "trainer.max_epochs=2", "trainer.progress=false",
        "trainer.verify_preset=null", "trainer.threads=1", "trainer.cache=false", "sensor.embedding=6x8",
        "fidelity.preset=fast", f"output.root={tmp_path}", f"output.name={name}", "output.examples=4", *extra])


def test_a_reconstruction_run_fits_resumes_and_tests(tmp_path):
    from optoenc.training import evaluate, fit

    run = _run(tmp_path, "unrolled_admm", "learned_slm", "decoder.denoiser=unet", "decoder.iterations=2")
    run_dir = tmp_path / "r"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        summary = fit(run, run_dir)
    # 3 batches an epoch: the logging interval follows (Lightning warns where it is above an epoch's batches)
    assert not [w for w in caught if "log_every_n_steps" in str(w.message)]
    for key in ("val_loss", "test_loss", "test_psnr", "test_ssim"):
        assert key in summary and summary[key] == summary[key], key  # present and not NaN
    assert 0 < summary["test_psnr"] < 60 and -1 <= summary["test_ssim"] <= 1
    assert (run_dir / "pictures" / "reconstructions.png").stat().st_size > 0
    header = (run_dir / "metrics.csv").read_text().splitlines()[0].split(",")
    assert "val_psnr" in header and "val_ssim" in header
    # resume to a third epoch from the last checkpoint
    longer = _run(tmp_path, "unrolled_admm", "learned_slm", "decoder.denoiser=unet", "decoder.iterations=2",
                  "trainer.max_epochs=3")
    resumed = fit(longer, run_dir, resume=True)
    assert len((run_dir / "metrics.csv").read_text().splitlines()) == 1 + 3
    assert json.loads((run_dir / "summary.json").read_text())["epochs"] == 3 == resumed["epochs"]
    # `optoenc test`: the best checkpoint's test scores are the summary's
    scores = evaluate(longer, run_dir, "test", "best")
    assert scores["test_psnr"] == pytest.approx(resumed["test_psnr"], rel=1e-5)


def test_a_fixed_encoder_reconstructs_from_precomputed_embeddings(tmp_path):
    from optoenc.training import build, fit

    run = _run(tmp_path, "unet", "diffuser", "decoder.width=4")
    parts = build(run)
    assert parts.precomputed and parts.loop == "batch"  # the epoch loop is classification's
    summary = fit(run, tmp_path / "r")
    assert summary["loop"] == "batch" and summary["test_psnr"] == summary["test_psnr"]


def test_the_task_and_the_decoder_must_agree(tmp_path):
    from optoenc.training import build

    with pytest.raises(ConfigError, match="image"):
        build(_run(tmp_path, "fcnn", "diffuser"))
    run = compose(names={"decoder": "unet", "encoder": "diffuser"}, overrides=["dataset.train_size=40", "dataset.val_size=10",
                                                                               "dataset.test_size=10"])
    with pytest.raises(ConfigError, match="logits"):
        build(run)
    with pytest.raises(ConfigError, match="trainer.loop"):
        build(_run(tmp_path, "unet", "diffuser", "trainer.loop=epoch"))
    with pytest.raises(ConfigError, match="privacy.adversary_weight"):  # the features reconstruction does not declare
        build(_run(tmp_path, "unet", "diffuser", "privacy.adversary_weight=0.1"))
    with pytest.raises(ConfigError, match="test_every_epoch"):
        build(_run(tmp_path, "unet", "diffuser", "trainer.test_every_epoch=true"))


def test_the_task_bench_times_both_steps():
    """`optoenc bench tasks`' measurement, on a batch of 4: both steps timed alternately, the ratio theirs."""
    from optoenc.bench.speed import format_task_steps, task_steps

    res = task_steps("learned_slm", "unet", threads=1, repeats=2, batch=4)
    assert len(res["classification_s"]) == len(res["reconstruction_s"]) == 2
    assert res["ratio_min"] == pytest.approx(res["reconstruction_min"] / res["classification_min"])
    assert "ratio min" in format_task_steps(res)
