"""The ``auto`` precisions: bfloat16 only where the machine multiplies it natively, and a warning where not.

The machine is simulated by replacing its CPU flags (and hiding any GPU), so both branches run on every
machine: an AVX2-only CPU emulates bfloat16 (about 4x slower than float32, ``optoenc bench precision``),
AMX or AVX512-BF16 do it natively.
"""

from __future__ import annotations

import warnings

import pytest
import torch

from optoenc import hardware
from optoenc.config import compose
from optoenc.encoders.fidelity import FidelityConfig
from optoenc.sweep.collect import precision

AVX2 = frozenset({"fma", "avx", "avx2"})
AMX = AVX2 | {"avx512f", "avx512_bf16", "amx_bf16", "amx_tile"}


@pytest.fixture(params=[AVX2, AMX], ids=["avx2", "amx"])
def cpu(request, monkeypatch):
    monkeypatch.setattr(hardware, "cpu_flags", lambda: request.param)
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    return request.param is AMX


def test_auto_resolves_to_bfloat16_only_where_native(cpu):
    assert hardware.native_bfloat16("cpu") is cpu and hardware.native_bfloat16("auto") is cpu
    assert hardware.native_bfloat16("mps") is False
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # 'auto' never warns: it only picks what is fast
        assert hardware.operator_dtype("auto") == ("bfloat16" if cpu else "same")
        assert hardware.trainer_precision("auto", "cpu") == ("bf16-mixed" if cpu else "32-true")
        knobs = FidelityConfig(operator_dtype="auto").resolved()
    assert knobs.operator_dtype == ("bfloat16" if cpu else "same")  # what the encoder (and summary.json) holds


def test_matrix_units_only_with_amx(cpu, monkeypatch):
    assert hardware.matrix_units() is cpu
    # AVX512-BF16 alone multiplies bfloat16 natively but has no matrix unit: the banded build stays there
    monkeypatch.setattr(hardware, "cpu_flags", lambda: AVX2 | {"avx512f", "avx512_bf16"})
    assert hardware.native_bfloat16("cpu") and not hardware.matrix_units()


def test_explicit_bfloat16_is_kept_but_warns_where_emulated(cpu):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert hardware.operator_dtype("bfloat16") == "bfloat16"  # a measured knob: never overridden
        assert hardware.trainer_precision("bf16-mixed") == "bf16-mixed"
        assert hardware.trainer_precision("32-true") == "32-true" and hardware.operator_dtype("same") == "same"
    slow = [str(w.message) for w in caught if issubclass(w.category, hardware.SlowPrecisionWarning)]
    if cpu:
        assert slow == []
    else:
        assert len(slow) == 2
        assert slow[0].startswith("fidelity.operator_dtype=bfloat16: this CPU (AVX2, no AMX or AVX512-BF16)")
        assert slow[1].startswith("trainer.precision=bf16-mixed:") and "'auto'" in slow[1]


def test_cpu_flags_are_read_from_this_machine():
    flags = hardware.cpu_flags()
    assert isinstance(flags, frozenset)
    try:
        text = open("/proc/cpuinfo").read()
    except OSError:
        pytest.skip("no /proc/cpuinfo here")
    lines = [ln for ln in text.splitlines() if ln.startswith("flags")]
    if not lines:
        pytest.skip("no flags line in /proc/cpuinfo (not x86)")
    assert flags and flags == frozenset(lines[0].split(":", 1)[1].split())  # every flag, no partial words


def test_run_config_accepts_auto_and_the_collected_precision_is_the_one_that_ran():
    run = compose(overrides=["trainer.precision=auto", "fidelity.operator_dtype=auto"])
    assert run.trainer.precision == "auto" and run.fidelity.operator_dtype == "auto"
    # The table's precision column: what summary.json recorded (resolved on the machine that ran it) ...
    ran = {"fidelity": {"dtype": "float32", "operator_dtype": "bfloat16"}, "precision": "bf16-mixed"}
    assert precision(run, ran) == "bfloat16/bf16-mixed"
    assert precision(run, {"fidelity": {"dtype": "float32", "operator_dtype": "same"}, "precision": "32-true"}) == "float32/32-true"
    # ... and the configuration's where a cell has not run yet.
    assert precision(run) == "auto/auto"


def test_a_run_records_where_it_ran(cpu):
    """``describe`` (``summary.json``'s ``hardware``): the device, its model, torch's threads and whether it
    multiplies bfloat16 natively, the flag following the CPU's (simulated) features."""
    hw = hardware.describe(torch.device("cpu"))
    assert hw["device"] == "cpu" and hw["name"] == hardware.cpu_model() and hw["name"]
    assert hw["threads"] == torch.get_num_threads() and hw["torch"] == torch.__version__
    assert hw["native_bfloat16"] is cpu
