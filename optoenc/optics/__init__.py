"""Wave-optics core: pure, differentiable functions on torch tensors (SI units).

Propagation (band-limited angular spectrum, ASM, Fresnel) with a
compute/apply split and an LRU cache, input fields (point sources, plane
waves, Gaussian beams), thin elements (lenses, apertures, cell masks, phase
masks), separable propagation of masks on a lattice, an explicit :class:`Spectrum`, the intensity PSF of a mask, sampling
diagnostics, and colour pictures of spectral PSFs. No configuration system or
registry lives here; see ``docs/optics.md`` for the conventions.

Importing this package imports torch only; ``colour-science`` is imported
lazily by the colour functions.
"""

from .colour import colour_matching, spectral_to_srgb, spectral_to_xyz, wavelength_to_srgb
from .diagnostics import SamplingReport, SamplingWarning, check_sampling, sampling_report
from .elements import cell_factors, cell_mask, circular_aperture, phase_mask, rect_aperture, thin_lens
from .propagation import (
    METHODS,
    apply_transfer_function,
    cache_info,
    clear_cache,
    compute_transfer_function,
    next_fast_size,
    padded_shape,
    propagate,
)
from .psf import NORMALIZATIONS, intensity_psf, sensor_field
from .separable import axis_operator, axis_propagator, cross_phase, separable_field, source_factor
from .sources import coordinates, gaussian_beam, plane_wave, point_source, source_phase_step
from .spectrum import VISIBLE_BAND, Spectrum

__all__ = [
    # propagation
    "METHODS",
    "propagate",
    "compute_transfer_function",
    "apply_transfer_function",
    "padded_shape",
    "next_fast_size",
    "cache_info",
    "clear_cache",
    # sources
    "coordinates",
    "plane_wave",
    "point_source",
    "gaussian_beam",
    "source_phase_step",
    # elements
    "thin_lens",
    "circular_aperture",
    "rect_aperture",
    "cell_mask",
    "cell_factors",
    "phase_mask",
    # spectra and colour
    "Spectrum",
    "VISIBLE_BAND",
    "colour_matching",
    "spectral_to_xyz",
    "spectral_to_srgb",
    "wavelength_to_srgb",
    # PSF
    "NORMALIZATIONS",
    "intensity_psf",
    "sensor_field",
    # separable masks, axis by axis
    "axis_propagator",
    "source_factor",
    "axis_operator",
    "separable_field",
    "cross_phase",
    # diagnostics
    "SamplingReport",
    "SamplingWarning",
    "sampling_report",
    "check_sampling",
]
