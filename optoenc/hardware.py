"""What this machine multiplies fast: the ``auto`` precisions, and a warning where bfloat16 is slow.

bfloat16 matrix products are several times faster than float32 on CPUs with
AMX or AVX512-BF16 units and on CUDA GPUs from compute capability 8.0; on
a CPU without them (AVX2 only, say) torch emulates them and they are 4-10
times *slower* (``optoenc bench precision`` measures both). A spec that
wants the fast products on every machine says ``auto``:

- ``fidelity.operator_dtype: auto`` -> ``bfloat16`` where native, else
  ``same`` (the optics' dtype);
- ``trainer.precision: auto`` -> ``bf16-mixed`` where native, else
  ``32-true``.

The resolved values are what a run records (its ``summary.json``). Where the CPU has a bfloat16
matrix unit (AMX, :func:`matrix_units`), a bfloat16 scene operator is built by dense products, which
that unit runs faster than many small ones (:func:`optoenc.encoders.operator.scene_operator`).
"""

from __future__ import annotations

import functools
import warnings
from pathlib import Path

__all__ = ["cpu_flags", "cpu_model", "describe", "matrix_units", "native_bfloat16", "operator_dtype", "trainer_precision", "SlowPrecisionWarning"]

#: CPU feature flags (Linux ``/proc/cpuinfo``) of native bfloat16 matrix products.
BF16_CPU_FLAGS = frozenset({"amx_bf16", "avx512_bf16"})
#: CPU feature flag of a bfloat16 matrix unit (Intel AMX): one large bfloat16 product runs at ~550 GMAC/s on one
#: core of the development machine, ~6x float32's, and far above many small products (banded blocks: ~16).
MATRIX_UNIT_FLAG = "amx_bf16"
_GPU = ("gpu", "cuda", "auto")


class SlowPrecisionWarning(UserWarning):
    """bfloat16 asked for explicitly on hardware that emulates it (slower than float32)."""


def _cpuinfo(field: str) -> str | None:
    """The first ``field : value`` of ``/proc/cpuinfo`` (None where there is no such file or field)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith(field):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return None


@functools.lru_cache(maxsize=1)
def cpu_flags() -> frozenset[str]:
    """This CPU's feature flags from ``/proc/cpuinfo`` (empty where there is none)."""
    return frozenset((_cpuinfo("flags") or "").split())


def matrix_units() -> bool:
    """Whether this CPU multiplies bfloat16 matrices in a matrix unit (AMX: :data:`MATRIX_UNIT_FLAG`)."""
    return MATRIX_UNIT_FLAG in cpu_flags()


@functools.lru_cache(maxsize=1)
def cpu_model() -> str:
    """This CPU's model name from ``/proc/cpuinfo`` (else :func:`platform.processor`, else ``"unknown"``)."""
    import platform

    return _cpuinfo("model name") or platform.processor() or "unknown"


def describe(device) -> dict[str, object]:
    """Where a run ran, for its ``summary.json``: results differ between devices (other kernels, other random
    streams from the same seed), so a run says which it had.

    ``device`` (a :class:`torch.device` or its name): the training process's device. Returns ``device`` (its
    type), ``name`` (the GPU's or the CPU's model), ``threads`` (torch's intra-op threads), ``torch`` (its
    version) and ``native_bfloat16`` (:func:`native_bfloat16` of that device).
    """
    import torch

    device = torch.device(device)
    names = {"cuda": lambda: torch.cuda.get_device_name(device), "cpu": cpu_model}
    return {
        "device": device.type,
        "name": names.get(device.type, lambda: device.type)(),
        "threads": torch.get_num_threads(),
        "torch": torch.__version__,
        "native_bfloat16": native_bfloat16(device.type),  # an accelerator name: 'cuda', 'cpu', 'mps'
    }


def _cuda_used(accelerator: str) -> bool:
    import torch

    return accelerator in _GPU and torch.cuda.is_available()


def native_bfloat16(accelerator: str = "auto") -> bool:
    """Whether the device a run with ``trainer.accelerator=accelerator`` uses multiplies bfloat16 natively.

    ``auto``, ``gpu``, ``cuda``: a CUDA GPU where one is present (compute capability 8.0 or newer), else the
    CPU; ``cpu``: AMX or AVX512-BF16 in :func:`cpu_flags`; ``mps``: no.
    """
    if _cuda_used(accelerator):
        import torch

        return bool(torch.cuda.is_bf16_supported(including_emulation=False))
    if accelerator == "mps":
        return False
    return bool(BF16_CPU_FLAGS & cpu_flags())


def _where(accelerator: str) -> str:
    if _cuda_used(accelerator):
        return "this GPU"
    flags = cpu_flags()
    isa = next((f.upper() for f in ("avx512f", "avx2", "avx") if f in flags), "")
    return f"this CPU ({isa}, no AMX or AVX512-BF16)" if isa else "this CPU (no AMX or AVX512-BF16)"


def _warn_slow(key: str, value: str, accelerator: str) -> None:
    warnings.warn(
        f"{key}={value}: {_where(accelerator)} emulates bfloat16: products 4-10x slower than float32 (optoenc bench precision); "
        f"'auto' uses bfloat16 only where it is native",
        SlowPrecisionWarning, stacklevel=3,
    )


def operator_dtype(value: str, accelerator: str = "auto") -> str:
    """``fidelity.operator_dtype`` resolved: ``auto`` -> ``bfloat16`` where native, else ``same``.

    An explicit ``bfloat16`` stays (it is a measured knob) but warns where it is emulated.
    """
    if value == "auto":
        return "bfloat16" if native_bfloat16(accelerator) else "same"
    if value == "bfloat16" and not native_bfloat16(accelerator):
        _warn_slow("fidelity.operator_dtype", value, accelerator)
    return value


def trainer_precision(value: str, accelerator: str = "auto") -> str:
    """``trainer.precision`` resolved: ``auto`` -> ``bf16-mixed`` where native, else ``32-true``."""
    if value == "auto":
        return "bf16-mixed" if native_bfloat16(accelerator) else "32-true"
    if value.startswith("bf16") and not native_bfloat16(accelerator):
        _warn_slow("trainer.precision", value, accelerator)
    return value
