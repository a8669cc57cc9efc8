"""`diffuser`: a lensless camera with a measured diffuser PSF (DiffuserCam)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import torch

from ..errors import ConfigError
from ..settings import setting
from . import psf_files
from .base import EncoderConfig, OpticalEncoder

__all__ = ["Diffuser", "DiffuserConfig"]


@dataclass
class DiffuserConfig(EncoderConfig):
    d2: float = setting(4e-3, "diffuser-to-sensor distance d2 (sets the magnification)", unit="m", gt=0)
    psf_path: Optional[str] = setting(
        None, "measured PSF file (PNG, TIFF or NPY) spanning the sensor; null: the bundled DiffuserCam PSF"
    )
    background: Optional[float] = setting(
        None, "background level subtracted from the raw PSF, in file counts; null: mean of the dark corners", ge=0
    )

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.psf_path is not None and not Path(self.psf_path).is_file():
            raise ConfigError("psf_path", self.psf_path, "file not found")


class Diffuser(OpticalEncoder):
    """Measured diffuser PSF (DiffuserCam, double-sided tape ~4 mm from the sensor)."""

    name = "diffuser"
    Config = DiffuserConfig
    learnable = False
    #: Measured against the converged truth (``optoenc bench``: the file
    #: resampled exactly onto the full sensor): the caustics of the measured
    #: PSF need finer grids than the shared table's; ``default`` 576 x 768 is
    #: 0.70 %, ``reference`` 1536 x 2048 is 0.16 % (768 x 1024: 0.48 %). A
    #: fixed PSF costs nothing per step, and little to resample.
    fidelity_presets = {"default": {"grid": (576, 768)}, "reference": {"grid": (1536, 2048)}}
    linear = True

    @property
    def psf_path(self) -> str:
        return str(self.config.psf_path or psf_files.bundled_psf_path())

    def compute_psf(self) -> torch.Tensor:
        return psf_files.measured_psf(self.psf_path, self.config.background, self.geometry.grid).to(self.optics_dtype)

    def cache_token(self) -> str:
        """What, beyond the config, determines this encoder's PSF: the file's contents."""
        return psf_files.file_digest(self.psf_path)
