"""Physical constants of the devices in the paper (REFERENCE §2), in SI units.

One source of truth: encoders, sensors and tests read these, never literals.
"""

from __future__ import annotations

__all__ = [
    "IMX477_PITCH",
    "IMX477_RESOLUTION",
    "WAVELENGTHS_RGB",
    "CHANNELS_RGB",
    "GRAYSCALE_WEIGHTS",
    "SCENE_HEIGHT",
    "SCENE_DISTANCE",
    "SNR_DB",
    "EMBEDDINGS",
    "DEFAULT_GRID",
]

#: Raspberry Pi HQ camera (Sony IMX477) pixel pitch, metres.
IMX477_PITCH = 1.55e-6
#: IMX477 resolution (rows, columns): 4.712 x 6.287 mm.
IMX477_RESOLUTION = (3040, 4056)

#: The one channel <-> wavelength table (R, G, B), metres. RGB scene channels
#: are intensities at these wavelengths; never reorder.
CHANNELS_RGB = ("R", "G", "B")
WAVELENGTHS_RGB = (640e-9, 550e-9, 460e-9)
#: Grayscale weighting of the R, G, B channels (ITU-R BT.601 luma: 0.299,
#: 0.587, 0.114): a grayscale scene on a grayscale sensor sees the PSF
#: sum_c w_c PSF_c. The peers' code had a 0.144 typo; this is the only copy.
GRAYSCALE_WEIGHTS = (0.299, 0.587, 0.114)

#: Paper scene: MNIST digit of 12 cm height, 40 cm from the encoder.
SCENE_HEIGHT = 0.12
SCENE_DISTANCE = 0.40
#: Paper noise level (A.4).
SNR_DB = 40.0
#: The paper's embedding sizes (rows, columns).
EMBEDDINGS = ((24, 32), (12, 16), (6, 8), (3, 4))
#: Simulation grid that every paper embedding divides exactly (pitch ~12.27 um).
DEFAULT_GRID = (384, 512)
