"""Run configuration: one strict omegaconf tree built from the registries.

A run config has one section per settings group::

    seed: 0
    encoder: {name: learned_slm, d2: 0.004, ...}   # the encoder's Config fields (or just `encoder: learned_slm`)
    decoder: {name: fcnn, hidden: 800, ...}
    dataset: {name: mnist, val_size: 5000, ...}
    task: {name: classification}                   # or reconstruction (task.loss: mse | l1)
    augment: {shift: {...}, rotate: {...}}         # enabled augmentations, in order
    scene / sensor / fidelity / trainer / output / privacy: {...}

The schema of each plugin section comes from the chosen plugin's ``Config``
dataclass, so a misspelled key fails with its full path and its valid
neighbours, and every value is validated against its declared range.

:func:`build_encoder` is the library's way to make one encoder from its
registry name and section overrides, without a run.
"""

from __future__ import annotations

import dataclasses
import difflib
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

import yaml
from omegaconf import DictConfig, OmegaConf
from omegaconf import errors as oc_errors

from . import limits
from .encoders.fidelity import FIDELITY_PRESETS, FidelityConfig
from .encoders.geometry import SceneConfig, SensorConfig
from .errors import ConfigError
from .plugins import get_registry
from .settings import Settings, field_value, setting

__all__ = [
    "TrainerConfig",
    "OutputConfig",
    "AdversaryConfig",
    "RunConfig",
    "DEFAULTS",
    "SECTIONS",
    "ENCODER_SECTIONS",
    "compose",
    "load_yaml",
    "build_encoder",
    "encoder_from_run",
    "to_yaml",
]


@dataclass
class TrainerConfig(Settings):
    """Optimisation and loop settings (REFERENCE §3 defaults)."""

    max_epochs: int = setting(50, "training epochs", ge=1)
    batch_size: int = setting(200, "examples per optimiser step", ge=1)
    lr: float = setting(1e-3, "Adam learning rate (encoder and decoder); above 10 Adam's steps overflow float32", gt=0, le=10)
    encoder_lr: Optional[float] = setting(
        1e-2,
        "Adam learning rate of the encoder's parameters (null: lr). Higher than the decoder's because learned "
        "masks are sigmoid logits: at 1e-2 a sub-pixel can cross its range within an epoch, at 1e-3 it barely moves",
        gt=0, le=10,
    )
    weight_decay: float = setting(
        0.0, "decoupled weight decay (AdamW) of the decoder's weight matrices, per unit learning rate (each step "
        "multiplies them by 1 - lr x weight_decay); biases, normalisation and the encoder are not decayed; 0: Adam, "
        "the paper's", ge=0, le=100,
    )
    precompute: bool = setting(True, "encode the dataset once for fixed, non-augmented encoders (noise still drawn per batch)")
    cache: bool = setting(True, "cache precomputed embeddings on disk (keyed by everything that affects them)")
    cache_dir: Optional[str] = setting(None, "embedding cache folder (null: $OPTOENC_CACHE_DIR or ~/.cache/optoenc)")
    eval_batch_size: int = setting(1000, "examples per batch when encoding or evaluating", ge=1)
    progress: bool = setting(True, "show progress bars")
    threads: Optional[int] = setting(None, "torch CPU threads (null: torch's default; at most 4 x the CPU cores)", ge=1)
    accelerator: str = setting(
        "auto", "Lightning accelerator: 'auto' uses a GPU where one is present", choices=("cpu", "gpu", "cuda", "mps", "auto")
    )
    devices: str = setting(
        "1", "Lightning devices per node: a count ('1', '2'), 'auto', or a list of indices ('0,1')"
    )
    strategy: str = setting(
        "auto", "Lightning strategy ('auto', 'ddp', 'ddp_spawn', 'fsdp', ...): several CPU processes or GPUs"
    )
    num_nodes: int = setting(1, "machines for distributed training (Lightning's num_nodes)", ge=1, le=4096)
    precision: str = setting(
        "32-true", "Lightning precision ('32-true', '16-mixed', 'bf16-mixed', '64-true'; 'auto': 'bf16-mixed' where "
        "the device multiplies bfloat16 natively (CPU AMX or AVX512-BF16, CUDA compute capability 8.0+), else "
        "'32-true'); the optics keep fidelity.dtype",
        choices=("32-true", "32", "16-mixed", "bf16-mixed", "64-true", "64", "transformer-engine", "auto"),
    )
    logger: str = setting(
        "csv", "experiment logger beside metrics.csv: 'csv' (Lightning's CSVLogger, under logs/), 'tensorboard', "
        "'mlflow' (SQLite tracking store, see mlflow_uri) or 'none'; tensorboard and mlflow are optional extras "
        "(pip install 'optoenc[tracking]')", choices=("csv", "tensorboard", "mlflow", "none"),
    )
    mlflow_uri: Optional[str] = setting(
        None, "MLflow tracking URI (null: sqlite:///<output.root>/mlflow.db)"
    )
    verify_preset: Optional[str] = setting(
        "reference", "after training, re-evaluate the final encoder at this fidelity preset (null: skip)",
        choices=tuple(FIDELITY_PRESETS),
    )
    limit_train_batches: Optional[float] = setting(
        None, "smoke tests: train on this fraction of the batches per epoch (< 1), or this many batches (a whole "
        "number >= 1); null: all (Lightning's limit_train_batches)", gt=0,
    )
    limit_val_batches: Optional[float] = setting(None, "as limit_train_batches, for validation", gt=0)
    limit_test_batches: Optional[float] = setting(None, "as limit_train_batches, for the test", gt=0)
    augment_draw: str = setting(
        "epoch", "augmentations: 'epoch' redraws every transform every epoch; 'once' draws one transform per "
        "example, kept for all epochs, for train, validation and test (the paper's robustness protocol)",
        choices=("epoch", "once"),
    )
    loop: str = setting(
        "auto", "training loop: 'batch' hands Lightning every mini-batch; 'epoch' hands it a whole shuffled "
        "epoch of precomputed embeddings and steps through its mini-batches in one call (the same batches, noise "
        "and updates, without Lightning's per-step hooks; train_loss_step is not logged): for fixed encoders in "
        "one process; 'auto': 'epoch' wherever it applies, else 'batch'", choices=("auto", "batch", "epoch"),
    )
    test_every_epoch: bool = setting(
        False, "also measure test accuracy after every epoch (metrics.csv column test_acc; the paper's "
        "'best test over epochs' figure, reported only beside the validation-selected one)"
    )

    def __post_init__(self) -> None:
        super().__post_init__()
        limits.check_threads("threads", self.threads)
        for stage in ("train", "val", "test"):
            v = getattr(self, f"limit_{stage}_batches")
            if v is not None and v >= 1 and v != int(v):
                raise ConfigError(f"limit_{stage}_batches", v, "must be a fraction < 1 or a whole number of batches")

    def batch_limit(self, stage: str) -> int | float:
        """Lightning's ``limit_<stage>_batches``: all (1.0), a fraction (float < 1) or a number of batches (int)."""
        v = getattr(self, f"limit_{stage}_batches")
        return 1.0 if v is None else int(v) if v >= 1 else float(v)


@dataclass
class OutputConfig(Settings):
    """Where runs are written."""

    root: str = setting("runs", "folder holding the run directories")
    name: Optional[str] = setting(None, "run directory name (null: <encoder>-<decoder>-<timestamp>)")
    examples: int = setting(8, "example measurements drawn as pictures", ge=0, le=64)


@dataclass
class AdversaryConfig(Settings):
    """Privacy-aware training (`fit`, section `privacy`): the encoder trained against a reconstruction adversary.

    Objective per batch: cross-entropy - ``adversary_weight`` * the adversary's reconstruction MSE, the
    adversary (an MLP from the noisy embedding to the scene) trained alongside on its own MSE
    (:mod:`optoenc.training.adversary`). 0 (the default) is plain training, nothing added.
    """

    adversary_weight: float = setting(0.0, "weight lambda of the adversary's reconstruction MSE subtracted from the "
                                      "classifier loss; 0: off (plain training)", ge=0)
    adversary_hidden: int = setting(256, "units of each of the adversary's two hidden layers", ge=1)
    adversary_lr: float = setting(1e-3, "the adversary's Adam learning rate", gt=0)


#: The one table of default plugin names.
DEFAULTS = {"encoder": "learned_slm", "decoder": "fcnn", "dataset": "mnist", "task": "classification"}

#: Sections whose schema is fixed (not chosen by a plugin name): the one table of them.
SECTIONS: dict[str, type] = {
    "scene": SceneConfig,
    "sensor": SensorConfig,
    "fidelity": FidelityConfig,
    "trainer": TrainerConfig,
    "output": OutputConfig,
    "privacy": AdversaryConfig,
}
#: The sections an encoder is built from (its own settings, then the shared ones it reads).
ENCODER_SECTIONS = ("encoder", "scene", "sensor", "fidelity")
_PLUGIN_SECTIONS = ("encoder", "decoder", "dataset", "task")


@dataclass
class RunConfig:
    """A resolved run: names plus validated settings objects."""

    seed: int
    names: dict[str, str]
    encoder: Any
    decoder: Any
    dataset: Any
    augment: dict[str, Any]
    scene: SceneConfig
    sensor: SensorConfig
    fidelity: FidelityConfig
    trainer: TrainerConfig
    output: OutputConfig
    tree: DictConfig
    #: When ``fidelity.preset`` was ``auto``: the measured decision (error, cost).
    fidelity_auto: Optional[dict] = None
    #: Privacy-aware training (section ``privacy``, :mod:`optoenc.training.adversary`); off by default.
    privacy: AdversaryConfig = dataclasses.field(default_factory=AdversaryConfig)
    #: The task's settings (section ``task``, :mod:`optoenc.tasks`; its name in ``names["task"]``).
    task: Any = None

    def to_yaml(self) -> str:
        return to_yaml(self.tree)


def to_yaml(tree: DictConfig) -> str:
    return OmegaConf.to_yaml(tree, resolve=True)


def _node(cls: type, name: str | None = None) -> DictConfig:
    node = OmegaConf.structured(cls)
    if name is not None:
        OmegaConf.set_struct(node, False)
        node["name"] = name
        OmegaConf.set_struct(node, True)
    return node


def _keys_at(tree: DictConfig, path: str) -> list[str]:
    node: Any = tree
    for part in path.split(".")[:-1]:
        if isinstance(node, DictConfig) and part in node:
            node = node[part]
        else:
            break
    return [str(k) for k in node.keys()] if isinstance(node, DictConfig) else []


def _leaves(node: Any, prefix: str = ""):
    """``(dotted path, value)`` of every leaf of a plain nested dict (lists are leaves)."""
    if isinstance(node, dict) and node:
        for k, v in node.items():
            yield from _leaves(v, f"{prefix}.{k}" if prefix else str(k))
    else:
        yield prefix, node


def _nested(path: str, value: Any) -> dict:
    out: Any = value
    for part in reversed(path.split(".")):
        out = {part: out}
    return out


def _message(err: Exception) -> str:
    """omegaconf's first message line without its unfilled ``$VALUE`` templates."""
    msg = str(err).splitlines()[0]
    m = re.match(r"\w+ length (\d+) does not match type hint length (\d+)", msg)
    if m:
        return f"must have {m.group(2)} values, not {m.group(1)}"
    msg = msg.replace("Value '$VALUE' of type '$VALUE_TYPE' could not", "an element could not")
    return msg.replace("$VALUE", "the value")


def _given(err: Exception) -> Any:
    """The value an omegaconf error was about (its ``value``), else what its message quotes."""
    value = getattr(err, "value", None)
    if value is not None:
        return value
    m = re.search(r"'([^'$]*)'", str(err))
    return m.group(1) if m else "(value not reported)"


def _translate(err: Exception, schema: DictConfig, user: Any = None) -> ConfigError:
    """A ConfigError naming the full key path and the value given, found leaf by leaf in ``user``."""
    culprits = []
    for path, value in _leaves(user) if isinstance(user, dict) else ():
        try:
            OmegaConf.merge(schema, _nested(path, value))
        except oc_errors.OmegaConfBaseException as leaf_err:
            culprits.append((path, value, leaf_err))
            break
    path, value, err = culprits[0] if culprits else (getattr(err, "full_key", None) or "config", _given(err), err)
    if isinstance(err, oc_errors.ConfigKeyError):
        leaf = path.split(".")[-1]
        known = _keys_at(schema, path)
        close = difflib.get_close_matches(leaf, known, n=3, cutoff=0.5)
        hint = f"did you mean {', '.join(close)}? " if close else ""
        return ConfigError(path, value, f"unknown setting; {hint}valid keys here: {', '.join(known)}")
    return ConfigError(path, value, _message(err))


#: A size written as text on the command line, ``24x32`` (YAML would read ``0x32`` as a hexadecimal number).
_SIZE_TEXT = re.compile(r"^\s*\d+(\s*[xX]\s*\d+)+\s*$")


def _names_from(user: DictConfig, cli_names: dict[str, str | None], section: str) -> str:
    if cli_names.get(section):
        return str(cli_names[section])
    node = user.get(section) if isinstance(user, DictConfig) else None
    if isinstance(node, DictConfig) and node.get("name"):
        return str(node["name"])
    if isinstance(node, str) and node:  # `encoder: diffuser`, the same as `encoder: {name: diffuser}`
        return node
    return DEFAULTS[section]


def _sequences_from_text(user: dict, classes: dict[str, type]) -> None:
    """Tuple and list settings given as text (``sensor.embedding=24x32``) made lists, in place, before the merge
    (the schema would refuse the text); :func:`optoenc.settings.field_value` reads them."""
    for section, cls in classes.items():
        node = user
        for part in section.split("."):
            node = node.get(part) if isinstance(node, dict) else None
        if not isinstance(node, dict):
            continue
        for key, value in node.items():
            if isinstance(value, str):
                try:
                    new = field_value(cls, key, value)
                except ConfigError as err:
                    raise err.with_prefix(section) from None
                if new is not value:
                    node[key] = list(new)


def load_yaml(path: str | Path, key: str = "--config") -> DictConfig:
    """A run configuration file, parsed.

    Args:
        path: the YAML file.
        key: what names the file in errors (the command line's option).

    Raises:
        ConfigError: the file is missing, is not valid YAML (one line: ``file:line:column``
            and the parser's message) or does not hold a mapping of sections.
    """
    p = Path(path)
    if not p.is_file():
        raise ConfigError(key, str(path), "file not found")
    try:
        tree = OmegaConf.load(p)
    except yaml.MarkedYAMLError as err:
        mark = err.problem_mark or err.context_mark
        where = f"{path}:{mark.line + 1}:{mark.column + 1}" if mark is not None else str(path)
        what = err.problem or err.context or "not valid YAML"
        if err.context and err.problem and err.context_mark is not None:
            what += f" ({err.context} that starts at line {err.context_mark.line + 1})"
        raise ConfigError(key, where, f"not valid YAML: {what}") from None
    except Exception as err:  # encoding errors, omegaconf's own (a key that is not a string, ...)
        raise ConfigError(key, str(path), f"not valid YAML ({str(err).splitlines()[0]})") from None
    if not isinstance(tree, DictConfig):
        raise ConfigError(key, str(path), "must hold a mapping of sections (seed:, encoder:, ...) at its top level, not a list")
    return tree


def compose(
    file_configs: list[DictConfig] | None = None,
    overrides: list[str] | None = None,
    names: dict[str, str | None] | None = None,
    augment: list[str] | None = None,
    seed: int | None = None,
) -> RunConfig:
    """Build and validate a run configuration.

    Args:
        file_configs: parsed YAML configs, merged in order (later wins).
        overrides: dotted ``key=value`` strings (``encoder.d2=4e-3``).
        names: plugin names chosen on the command line (``encoder``,
            ``decoder``, ``dataset``, ``task``); they override the files.
        augment: augmentation names to enable (overrides the files).
        seed: the run seed (overrides the files).

    Raises:
        ConfigError: unknown key (with the valid neighbours), bad type or
            value out of range; PluginError: unknown plugin name.
    """
    for i, fc in enumerate(file_configs or []):
        if not isinstance(fc, DictConfig):
            raise ConfigError(
                f"config file {i + 1}", type(fc).__name__, "must hold a mapping of sections (seed:, encoder:, ...) at its top level"
            )
    try:
        user = OmegaConf.merge(*(file_configs or [OmegaConf.create({})]))
        for item in overrides or []:
            try:
                key, eq, text = item.partition("=")
                if eq and _SIZE_TEXT.match(text):  # 24x32 stays text for the setting to read (0x32 is not hex)
                    item = f"{key}='{text.strip()}'"
                dotlist = OmegaConf.from_dotlist([item])
            except Exception as err:  # omegaconf grammar or YAML errors of one override
                raise ConfigError(item.split("=", 1)[0], item.partition("=")[2], f"not a valid value ({_message(err)})") from None
            user = OmegaConf.merge(user, dotlist)
    except oc_errors.OmegaConfBaseException as err:
        raise ConfigError(getattr(err, "full_key", None) or "config", _given(err), _message(err)) from None
    names = dict(names or {})
    for s in _PLUGIN_SECTIONS:  # `--encoder diffuser --encoder.name=lens`: two answers, neither silently wins
        given = [str(v) for k, v in (o.split("=", 1) for o in overrides or [] if "=" in o) if k.strip() == f"{s}.name"]
        if names.get(s) and given and given[-1] != str(names[s]):
            raise ConfigError(f"{s}.name", given[-1], f"conflicts with --{s} {names[s]}; give the {s} once")
    chosen = {s: _names_from(user, names, s) for s in _PLUGIN_SECTIONS}
    classes = {s: get_registry(s).get(chosen[s]) for s in _PLUGIN_SECTIONS}

    aug_reg = get_registry("augmentation")
    if augment is not None:
        aug_names = [a for a in augment if a]
    else:
        node = user.get("augment")
        aug_names = [str(k) for k in node.keys()] if isinstance(node, DictConfig) else []
    aug_classes = {a: aug_reg.get(a) for a in aug_names}

    schema = OmegaConf.create({"seed": 0})
    for s in _PLUGIN_SECTIONS:
        schema[s] = _node(classes[s].Config, chosen[s])
    schema["augment"] = OmegaConf.create({a: _node(c.Config) for a, c in aug_classes.items()})
    for s, cls in SECTIONS.items():
        schema[s] = _node(cls)
    OmegaConf.set_struct(schema, True)

    # Names were resolved above: drop them from the user tree so a file's name
    # cannot contradict the command line.
    try:
        user = OmegaConf.to_container(user, resolve=True) if isinstance(user, DictConfig) else {}
    except oc_errors.OmegaConfBaseException as err:
        key = getattr(err, "full_key", None) or "config"
        raw = dict(_leaves(OmegaConf.to_container(user, resolve=False))).get(key, _given(err))
        raise ConfigError(key, raw, f"cannot be resolved ({_message(err)})") from None
    for s in _PLUGIN_SECTIONS:
        if isinstance(user.get(s), dict):
            user[s].pop("name", None)
        elif isinstance(user.get(s), str):  # the plugin's name alone, read above
            user[s] = {}
    if augment is not None and isinstance(user.get("augment"), dict):
        user["augment"] = {k: v for k, v in user["augment"].items() if k in aug_classes}
    if isinstance(user.get("augment"), dict):
        user["augment"] = {k: (v or {}) for k, v in user["augment"].items()}
    _sequences_from_text(user, {**{s: classes[s].Config for s in _PLUGIN_SECTIONS}, **SECTIONS,
                                **{f"augment.{a}": c.Config for a, c in aug_classes.items()}})
    try:
        tree = OmegaConf.merge(schema, user)
    except oc_errors.OmegaConfBaseException as err:
        raise _translate(err, schema, user) from None
    if seed is not None:
        tree.seed = seed
    if isinstance(tree.seed, bool) or not isinstance(tree.seed, int) or not 0 <= tree.seed < 2**63:
        raise ConfigError("seed", tree.seed, "must be an integer >= 0")

    def build(section: str, cls: type, node: DictConfig) -> Any:
        data = OmegaConf.to_container(node, resolve=True)
        if section in _PLUGIN_SECTIONS:
            data.pop("name", None)  # the plugin's registry name, not one of its settings
        data = {k: tuple(v) if isinstance(v, list) else v for k, v in data.items()}
        try:
            return cls(**data)
        except ConfigError as err:
            raise err.with_prefix(section) from None

    objs = {s: build(s, classes[s].Config, tree[s]) for s in _PLUGIN_SECTIONS}
    objs.update({s: build(s, cls, tree[s]) for s, cls in SECTIONS.items()})
    augs = {a: build(f"augment.{a}", c.Config, tree.augment[a]) for a, c in aug_classes.items()}
    return RunConfig(seed=int(tree.seed), names=chosen, augment=augs, tree=tree, **objs)


def build_encoder(name: str, **sections: Any):
    """An encoder from its registry name, each settings section its defaults unless given.

    Example::

        enc = optoenc.build_encoder("learned_slm", sensor={"embedding": [6, 8]}, fidelity={"preset": "fast"})
        lens = optoenc.build_encoder("lens", encoder={"d2": 5e-3})

    Args:
        name: the encoder's registry name (``optoenc encoders`` lists them).
        **sections: ``encoder`` (the encoder's own settings), ``scene``,
            ``sensor``, ``fidelity``: each a mapping of settings (those not
            given keep their defaults) or a settings object.

    Raises:
        PluginError: an unknown encoder name. ConfigError: an unknown section
            or setting, or a value that is not allowed.
    """
    if not isinstance(name, str):
        raise ConfigError("encoder", type(name).__name__, "must be a registry name such as 'learned_slm' (the "
                          "encoder of a RunConfig: optoenc.config.encoder_from_run)")
    for key, value in sections.items():
        if key not in ENCODER_SECTIONS:
            close = difflib.get_close_matches(key, ENCODER_SECTIONS, n=1)
            hint = f"did you mean {close[0]}? " if close else ""
            raise ConfigError(key, value, f"unknown section; {hint}an encoder is built from {', '.join(ENCODER_SECTIONS)}")
    cls = get_registry("encoder").get(name)
    return cls(sections.get("encoder"), scene=sections.get("scene"), sensor=sections.get("sensor"),
               fidelity=sections.get("fidelity"))


def encoder_from_run(run: RunConfig, fidelity: FidelityConfig | None = None):
    """The encoder of a composed run configuration (optionally at another fidelity)."""
    cls = get_registry("encoder").get(run.names["encoder"])
    return cls(run.encoder, scene=run.scene, sensor=run.sensor, fidelity=fidelity or run.fidelity)
