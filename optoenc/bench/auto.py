"""``fidelity.preset: auto`` for runs: the cheapest measured setting within a tolerance.

The first run of an encoder configuration measures it with ``optoenc bench``'s
machinery (presets and single-knob sweeps against the float64 high-fidelity
reference, on the run's own encoder, scene and sensor settings; about a
minute and several GB for a mask encoder) and caches the decision on disk,
keyed by everything that affects it. Later runs read the decision.

The decision is stored and returned as explicit knobs (every knob of
:class:`optoenc.encoders.fidelity.Knobs` set, ``psf_oversample`` included, after the
encoder's own ``fidelity_presets``), so a run uses exactly the setting that
was measured, whatever the preset tables say later.
"""

from __future__ import annotations

import hashlib
import json
from typing import Any, Callable

from .. import __version__
from ..encoders.fidelity import FidelityConfig
from ..errors import ConfigError
from ..settings import to_dict
from ..training.cache import cache_dir
from ..training.rundir import write_json

__all__ = ["resolve", "decision_key"]

#: Test digits the error is measured on (fewer than the benchmark's 256: a decision, not a report).
DIGITS = 64
#: Version of the stored decision (2: explicit knobs, psf_oversample included; 3: measured on the run's own
#: dataset against the converged truth).
FORMAT = 3


def decision_key(run) -> str:
    """Digest of what the decision depends on."""
    material = {
        "format": FORMAT,
        "version": __version__,
        "encoder": run.names["encoder"],
        "config": to_dict(run.encoder),
        "scene": to_dict(run.scene),
        "sensor": to_dict(run.sensor),
        "tolerance": run.fidelity.tolerance,
        "dataset": run.names.get("dataset"),
        "dataset_config": to_dict(run.dataset) if getattr(run, "dataset", None) is not None else None,
    }
    return hashlib.sha256(json.dumps(material, sort_keys=True, default=str).encode()).hexdigest()


def resolve(run, root: str | None = None, measure: Callable[..., Any] | None = None) -> tuple[FidelityConfig, dict]:
    """The fidelity for ``run`` when its preset is ``auto``.

    Args:
        run: a :class:`optoenc.config.RunConfig` with ``fidelity.preset == "auto"``.
        root: cache folder (default :func:`optoenc.training.cache.cache_dir`'s parent).
        measure: ``auto_select``-like callable (for tests); default
            :func:`optoenc.bench.choose.auto_select`.

    Returns:
        ``(fidelity, info)``: explicit knobs, and the measured error and cost.

    Raises:
        ConfigError: no measured setting meets the tolerance (the message
            names the most accurate one).
    """
    name = run.names["encoder"]
    path = cache_dir(root).parent / "fidelity" / f"{decision_key(run)}.json"
    if path.exists():
        try:
            info = json.loads(path.read_text())
            f = FidelityConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in info["fidelity"].items()})
            return f.replace(tolerance=run.fidelity.tolerance), info
        except (ValueError, KeyError, TypeError, ConfigError):
            path.unlink(missing_ok=True)  # a corrupt decision is measured again
    if measure is None:
        from .choose import auto_select as measure
    setup = {"config": run.encoder, "scene": run.scene, "sensor": run.sensor}
    from ..plugins import get_registry

    # the run's own scenes (and classes, for the decoder step timed): not MNIST whatever the dataset
    splits = get_registry("dataset").get(run.names["dataset"])(run.dataset).load()
    try:
        choice = measure(
            name,
            run.fidelity.tolerance,
            digits=DIGITS,
            embedding=tuple(run.sensor.embedding),
            setups={name: setup},
            splits=splits,
        )
    except ConfigError as err:
        raise ConfigError("fidelity.tolerance", run.fidelity.tolerance, f"not met by any measured setting of {name}: {err.allowed}") from None

    presets = getattr(get_registry("encoder").get(name), "fidelity_presets", {})
    chosen = choice.fidelity
    knobs = chosen.resolved(presets)  # every knob explicit, psf_oversample included
    f = knobs.fidelity(preset=chosen.preset, tolerance=run.fidelity.tolerance)
    info = {
        "fidelity": {k: v for k, v in to_dict(f).items() if k != "tolerance"},
        "knobs": knobs.to_dict(),
        "tolerance": run.fidelity.tolerance,
        "error": float(choice.row.get("error", float("nan"))),
        "step_s": choice.row.get("step_s"),
        "encode_s": choice.row.get("encode_s"),
        "considered": choice.considered,
    }
    write_json(path, info)
    return f, info
