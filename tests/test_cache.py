"""Embedding cache: warm hits, and never a stale entry when the physics changes."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from optoenc.training import cache
from optoenc.config import encoder_from_run, compose


@pytest.fixture
def cache_root(tmp_path, monkeypatch):
    monkeypatch.setenv(cache.ENV, str(tmp_path / "cache"))
    return tmp_path / "cache"


def key_for(encoder_name="diffuser", overrides=(), dataset_token="d"):
    run = compose(overrides=list(overrides), names={"encoder": encoder_name})
    return cache.embedding_key(encoder_from_run(run), run.dataset, dataset_token)


def test_store_load_round_trip_and_corruption_is_detected(cache_root):
    t = {"train": torch.arange(6.0).reshape(2, 3)}
    path = cache.store("ab" * 32, t)
    assert torch.equal(cache.load("ab" * 32)["train"], t["train"])
    raw = bytearray(path.read_bytes())
    raw[-5] ^= 0xFF  # flip a byte of the payload
    path.write_bytes(bytes(raw))
    with pytest.warns(UserWarning, match="corrupt"):
        assert cache.load("ab" * 32) is None
    assert not path.exists()  # removed, so the next run recomputes


def test_cached_computes_once(cache_root):
    calls = []

    def compute():
        calls.append(1)
        return {"x": torch.ones(2)}

    _, hit1 = cache.cached("cd" * 32, compute)
    _, hit2 = cache.cached("cd" * 32, compute)
    assert (hit1, hit2) == (False, True) and len(calls) == 1


@pytest.mark.parametrize(
    "encoder,change",
    [
        ("diffuser", "encoder.d2=5e-3"),  # a distance
        ("diffuser", "scene.distance=0.5"),
        ("diffuser", "sensor.snr_db=20"),  # the SNR
        ("diffuser", "sensor.embedding=[12,16]"),
        ("diffuser", "fidelity.preset=fast"),
        ("fixed_slm", "encoder.seed=1"),  # the seed of a fixed pattern
        ("coded_aperture", "encoder.feature_size=3.1e-5"),
    ],
)
def test_any_physical_change_changes_the_key(cache_root, encoder, change):
    assert key_for(encoder) == key_for(encoder)  # deterministic
    assert key_for(encoder, [change]) != key_for(encoder)


def test_psf_file_contents_change_the_key(cache_root, tmp_path):
    psf = np.zeros((30, 40))
    psf[10:20, 10:30] = 1.0
    path = tmp_path / "psf.npy"
    np.save(path, psf)
    k1 = key_for("diffuser", [f"encoder.psf_path={path}"])
    psf[12, 12] = 5.0  # same file name, new contents
    np.save(path, psf)
    assert key_for("diffuser", [f"encoder.psf_path={path}"]) != k1


def test_dataset_change_changes_the_key(cache_root):
    assert key_for(dataset_token="a") != key_for(dataset_token="b")


def test_warm_cache_is_used_by_a_run(cache_root, tmp_path, quick):
    from optoenc.training import build

    run = compose(overrides=quick, names={"encoder": "diffuser", "decoder": "logistic"})
    a = build(run)
    files = list(cache_root.rglob("*.pt"))
    assert len(files) == 1
    b = build(run)  # second build: a cache hit gives identical tensors
    for split in ("train", "val", "test"):
        assert torch.equal(a.loaders[split].dataset.tensors[0], b.loaders[split].dataset.tensors[0])
    assert list(cache_root.rglob("*.pt")) == files


PLUGIN = '''
import torch
from optoenc import OpticalEncoder


def profile(r):  # module-level helper: the class body below never changes
    return 1 {sign} torch.cos(r)


class Ring(OpticalEncoder):
    name = "ring_probe"

    def compute_psf(self):
        H, W = self.geometry.grid
        y = torch.arange(H, dtype=torch.float64)[:, None] - H // 2
        x = torch.arange(W, dtype=torch.float64)[None, :] - W // 2
        return (profile(torch.hypot(y, x) / 3.0) + 1e-3)[None].to(self.optics_dtype)
'''


def _plugin_encoder(tmp_path, sign):
    import importlib.util
    import inspect
    import sys

    path = tmp_path / f"ring_{'plus' if sign == '+' else 'minus'}.py"
    path.write_text(PLUGIN.format(sign=sign))
    spec = importlib.util.spec_from_file_location(path.stem, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[path.stem] = mod
    spec.loader.exec_module(mod)
    enc = mod.Ring(fidelity={"grid": (48, 64)}, sensor={"embedding": (6, 8)})
    return enc, inspect.getsource(mod.Ring)


def test_a_plugin_helper_change_changes_the_key(cache_root, tmp_path):
    # A source-keyed cache hashed the class's source: identical here, so a changed helper
    # (1 + cos -> 1 - cos) was served stale embeddings. The key now follows the PSF and probe embeddings.
    from optoenc.datasets.mnist import MNISTConfig

    plus, src_plus = _plugin_encoder(tmp_path, "+")
    minus, src_minus = _plugin_encoder(tmp_path, "-")
    assert src_plus == src_minus
    scenes = torch.rand(4, 1, 28, 28, generator=torch.Generator().manual_seed(0))
    k_plus = cache.embedding_key(plus, MNISTConfig(), "d", scenes=scenes)
    assert k_plus == cache.embedding_key(_plugin_encoder(tmp_path, "+")[0], MNISTConfig(), "d", scenes=scenes)
    assert cache.embedding_key(minus, MNISTConfig(), "d", scenes=scenes) != k_plus


def test_an_overridden_measure_changes_the_key(cache_root):
    # The probe embeddings catch encoders whose embeddings are not the PSF's convolution.
    from optoenc.datasets.mnist import MNISTConfig

    run = compose(names={"encoder": "diffuser"})
    enc = encoder_from_run(run)
    k = cache.embedding_key(enc, MNISTConfig(), "d")
    measure = enc.measure
    enc.measure = lambda scene, height=None, method="auto": measure(scene, height, method).square()
    assert cache.embedding_key(enc, MNISTConfig(), "d") != k


def test_tensor_digest_ignores_last_bit_rounding_but_not_physics():
    t = torch.rand(64, 64, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    assert cache.tensor_digest(t) == cache.tensor_digest(t.clone())
    # 1e-9 of the peak is a real change: 2^-40 ~ 9e-13 resolves it.
    t2 = t.clone()
    t2[3, 3] += 1e-9
    assert cache.tensor_digest(t2) != cache.tensor_digest(t)


def _read_only_folder(tmp_path):
    """A folder nobody may create entries in: a chmod-ed one for an ordinary user; for root (whom chmod does not
    stop), a path in sysfs, which the kernel refuses to everybody."""
    import os
    from pathlib import Path

    if os.geteuid() != 0:
        d = tmp_path / "read-only"
        d.mkdir()
        d.chmod(0o500)
        return d / "cache"
    try:
        os.mkdir("/sys/optoenc-probe")
    except OSError:
        return Path("/sys/optoenc-cache")
    os.rmdir("/sys/optoenc-probe")
    pytest.skip("no folder here that refuses writes even to root")


def test_a_read_only_cache_folder_runs_without_the_cache_and_warns_once(tmp_path, monkeypatch):
    # OPTOENC_CACHE_DIR pointing at a read-only place stopped the run at the first write; now the run goes on
    # without the cache, with one warning for the process however many entries it computes.
    import warnings

    monkeypatch.setenv(cache.ENV, str(_read_only_folder(tmp_path)))
    monkeypatch.setattr(cache, "_UNWRITABLE", set())
    computed = []
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for key in ("a" * 64, "b" * 64):
            out, hit = cache.cached(key, lambda: computed.append(key) or {"train": torch.ones(2)})
            assert not hit and torch.equal(out["train"], torch.ones(2))
    lines = [str(w.message) for w in caught if "embedding cache" in str(w.message)]
    assert len(lines) == 1 and "running without it" in lines[0] and cache.ENV in lines[0], lines
    assert computed == ["a" * 64, "b" * 64]
