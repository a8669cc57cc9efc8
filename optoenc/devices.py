"""Physical constants of the devices in the paper (REFERENCE §2; A.5.2, A.6), in SI units.

The one source of truth for every device constant: the sensor, the scene,
the LCD (ST7735R), the lens, the coded aperture and the phase mask.
Encoders, sensors and tests read these names, never literals.
"""

from __future__ import annotations

__all__ = [
    "IMX477_PITCH",
    "IMX477_RESOLUTION",
    "WAVELENGTHS_RGB",
    "CHANNELS_RGB",
    "GRAYSCALE_WEIGHTS",
    "LUMINANCE_WEIGHTS",
    "SCENE_HEIGHT",
    "SCENE_DISTANCE",
    "SNR_DB",
    "EMBEDDINGS",
    "DEFAULT_GRID",
    "ST7735R_PIXELS",
    "ST7735R_SUBPIXELS",
    "ST7735R_CELL",
    "ST7735R_ACTIVE_AREA",
    "ST7735R_PITCH",
    "ST7735R_FILL_FACTOR",
    "ST7735R_RGB565_BITS",
    "SLM_APERTURE",
    "SLM_D2",
    "LENS_D2",
    "LENS_FOCUS",
    "LENS_FOCAL_LENGTH",
    "LENS_F_NUMBER",
    "MLS_ORDER",
    "MLS_REPEATS",
    "MLS_FEATURE",
    "MLS_D2",
    "PHASE_MASK_D2",
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
#: Linear-light luminance weights of R, G, B (Rec. 709 primaries, those of sRGB): an RGB image or scene made
#: gray (the datasets' gray images; an RGB scene on a gray sensor, :mod:`optoenc.encoders.sensor`).
LUMINANCE_WEIGHTS = (0.2126, 0.7152, 0.0722)

#: Paper scene: MNIST digit of 12 cm height, 40 cm from the encoder.
SCENE_HEIGHT = 0.12
SCENE_DISTANCE = 0.40
#: Paper noise level (A.4).
SNR_DB = 40.0
#: The paper's embedding sizes (rows, columns).
EMBEDDINGS = ((24, 32), (12, 16), (6, 8), (3, 4))
#: Simulation grid that every paper embedding divides exactly (pitch ~12.27 um).
DEFAULT_GRID = (384, 512)

# ----------------------------------------------------------------- ST7735R LCD (Adafruit 1.8")
#: RGB pixels (rows, columns); each pixel is 3 sub-pixels (R, G, B) stacked along the rows.
ST7735R_PIXELS = (128, 160)
#: Sub-pixels (rows, columns): sub-pixel row ``k`` carries colour ``k % 3`` (R, G, B).
ST7735R_SUBPIXELS = (3 * ST7735R_PIXELS[0], ST7735R_PIXELS[1])
#: Transparent cell of one sub-pixel (rows, columns), metres (datasheet: 0.06 x 0.18 mm).
ST7735R_CELL = (0.06e-3, 0.18e-3)
#: Active area (rows, columns), metres: from the first cell's outer edge to the last's.
ST7735R_ACTIVE_AREA = (28.03e-3, 35.04e-3)
#: Sub-pixel pitch (rows, columns), metres: (active - cell) / (n - 1) = 73.03 x 219.25 um.
ST7735R_PITCH = tuple(
    (a - c) / (n - 1) for a, c, n in zip(ST7735R_ACTIVE_AREA, ST7735R_CELL, ST7735R_SUBPIXELS)
)
#: Open fraction of the panel area (opaque deadspace around each cell): 0.675.
ST7735R_FILL_FACTOR = (ST7735R_CELL[0] / ST7735R_PITCH[0]) * (ST7735R_CELL[1] / ST7735R_PITCH[1])
#: RGB565 bits per sub-pixel colour (R, G, B).
ST7735R_RGB565_BITS = (5, 6, 5)
#: Fraction of the sensor (each axis) left open by the SLM crop: 51 x 22 sub-pixels.
SLM_APERTURE = 0.8
#: SLM-to-sensor distance, metres.
SLM_D2 = 4e-3

# ----------------------------------------------------------------- lens (6 mm wide angle for the RPi HQ)
#: Lens-to-sensor distance, metres.
LENS_D2 = 7.53e-3
#: Distance the lens is focused at, metres.
LENS_FOCUS = 0.40
#: Thin-lens focal length focusing LENS_FOCUS onto LENS_D2: ~7.39 mm.
LENS_FOCAL_LENGTH = 1.0 / (1.0 / LENS_FOCUS + 1.0 / LENS_D2)
#: Aperture f-number (datasheet of the Adafruit 4563 6 mm lens: F1.2).
LENS_F_NUMBER = 1.2

# ----------------------------------------------------------------- coded aperture (FlatCam-style MLS)
#: scipy.signal.max_len_seq order: length 2**6 - 1 = 63.
MLS_ORDER = 6
#: Repetitions of the sequence along each axis (63 -> 126).
MLS_REPEATS = 2
#: Feature (mask cell) size, metres: 126 x 30 um = 3.78 mm, ~80 % of the sensor height.
MLS_FEATURE = 30e-6
#: Mask-to-sensor distance, metres (as FlatCam).
MLS_D2 = 0.5e-3

# ----------------------------------------------------------------- phase mask (PhlatCam-style)
#: Phase-mask-to-sensor distance, metres.
PHASE_MASK_D2 = 2e-3
