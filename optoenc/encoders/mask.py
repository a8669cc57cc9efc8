"""`MaskEncoder`: the public base of every encoder whose PSF is propagated from a mask.

Coded aperture, LCD/SLM and phase-mask encoders (and mask plugins) supply a
transmittance on the wave-field grid (the simulation grid refined
``fidelity.psf_oversample`` times); the PSF is point source at ``d1`` ->
mask -> band-limited angular spectrum over ``d2`` -> ``|U|^2`` at the R, G,
B wavelengths in one batched FFT, integrated over each grid pixel; a mask of
cells on a lattice (:attr:`MaskEncoder.separable`, the LCDs) may instead be
propagated axis by axis (:meth:`MaskEncoder.separable_psf`). A new
amplitude mask is a subclass with :meth:`MaskEncoder.mask`, a phase mask one
with :meth:`MaskEncoder.phase`; see docs/plugin-authoring.md. :meth:`MaskEncoder.field_mask`
is the transmittance on the field grid for every mask encoder.
"""

from __future__ import annotations

import math

import torch

from .. import devices
from ..optics import axis_operator, check_sampling, cross_phase, intensity_psf, padded_shape
from ..optics.psf import check_energy
from ..optics.separable import real_operators, separable_intensity
from .base import OpticalEncoder
from .imaging import psf_power

__all__ = ["MaskEncoder", "AUTO_CHUNK_SAMPLES", "SEPARABLE_MAX_PHASE"]

#: With ``wavelength_chunk`` None, the wavelengths are propagated one at a time once the padded field of all of
#: them together exceeds this many samples (2**24: 256 MB per complex128 copy). The transfer function's float64
#: temporaries scale with the batch: the coded aperture's ``reference`` field (3 x 4.0k x 5.4k) peaked at 8.2 GB
#: all at once, 3.4 GB one at a time; the PSF is the same to float rounding.
AUTO_CHUNK_SAMPLES = 2**24
#: ``fidelity.propagation = "separable"``: the largest phase (radians) the axis-by-axis factorisation may drop
#: (:func:`optoenc.optics.cross_phase`); beyond it the 2-D BLAS is used. The ST7735R LCD at the paper's
#: geometry drops 3.5e-3 rad, and its PSF differs from the 2-D BLAS one by 1.0e-5 (relative L2).
SEPARABLE_MAX_PHASE = 0.01


class MaskEncoder(OpticalEncoder):
    """Base of the encoders whose PSF is point source -> mask -> BLAS over ``d2`` -> ``|U|^2``.

    A subclass sets ``name``, ``Config`` (deriving from
    :class:`~optoenc.encoders.base.EncoderConfig`, which brings ``d2``) and
    the flags, and implements one of:

    * :meth:`mask`: the amplitude (real, in ``[0, 1]``) or complex
      transmittance on the field grid;
    * :meth:`phase`: the phase delay, radians; the transmittance is then
      ``aperture() * exp(1j * phase())`` (override :meth:`aperture` for an
      opening other than the whole window).

    Everything else is done here: the odd-oversampled field grid centred on
    the optical axis (:attr:`field_grid`, :attr:`field_spacing`,
    :meth:`field_coordinates`), the padding knob, the point source at ``d1``,
    propagation over ``d2`` at the R, G, B wavelengths (:meth:`propagated_psf`),
    the pixel integration and, through :meth:`mask`, the mask pictures.
    """

    #: Wavelengths propagated per FFT batch; None: all at once, or one at a time on large fields
    #: (:data:`AUTO_CHUNK_SAMPLES`); set to 1 to bound memory on very fine grids.
    wavelength_chunk: int | None = None
    #: Whether the mask is cells on a lattice that :meth:`separable_psf` can propagate axis by axis (the LCDs):
    #: ``fidelity.propagation`` applies to it (and ``optoenc bench`` sweeps that knob).
    separable: bool = False
    #: Set by :meth:`set_monochromatic`: one wavelength (metres) propagated with the G channel's mask for every
    #: colour channel; None: the R, G, B wavelengths of :data:`optoenc.devices.WAVELENGTHS_RGB`.
    monochromatic: float | None = None

    def set_monochromatic(self, wavelength: float | None) -> None:
        """Propagate one ``wavelength`` for every colour channel from now on (None: back to R, G, B)."""
        self.monochromatic = None if wavelength is None else float(wavelength)
        self.invalidate_psf()

    # ----------------------------------------------------------------- what a subclass implements
    def mask(self) -> torch.Tensor:
        """The element's transmittance, as its pictures show it: on the field grid, what is propagated.

        An element displayed on a lattice of its own may return that lattice
        instead, declaring its sample spacing as ``mask_spacing`` and giving
        the field grid's transmittance by :meth:`field_mask` (the LCD encoders:
        their 384 x 160 sub-pixels; :meth:`field_mask` is always the field grid).

        Returns:
            ``(H, W)`` (the same at every wavelength) or ``(3, H, W)`` (at the
            R, G, B wavelengths of :data:`optoenc.devices.WAVELENGTHS_RGB`),
            ``(H, W) = self.field_grid``, sample ``(i, j)`` at
            :meth:`field_coordinates` ``(y[i], x[j])``: a real amplitude in
            ``[0, 1]``, or complex. Default: ``aperture() * exp(1j * phase())``.
        """
        phi = self.phase()
        return self.aperture().to(phi.dtype) * torch.exp(1j * phi)

    def phase(self) -> torch.Tensor:
        """Phase delay of a phase mask on the field grid, radians: ``(H, W)`` or ``(3, H, W)`` (R, G, B)."""
        raise NotImplementedError(f"{type(self).__name__} must implement mask() (an amplitude) or phase()")

    def aperture(self) -> torch.Tensor:
        """Amplitude of the opening under :meth:`phase`, ``(H, W)`` on the field grid; default fully open."""
        y, x = self.field_coordinates()
        return torch.ones(len(y), len(x), dtype=y.dtype, device=y.device)

    def field_mask(self) -> torch.Tensor:
        """The transmittance on the field grid that :meth:`compute_psf` propagates (shapes as :meth:`mask`).

        Default: :meth:`mask`. A subclass whose :meth:`mask` is on a lattice of its own overrides it.
        """
        return self.mask()

    def compute_psf(self) -> torch.Tensor:
        """The propagated PSF of :meth:`field_mask` at distance ``self.d2`` (see :meth:`propagated_psf`)."""
        return self.propagated_psf(self.field_mask(), self.d2)

    def open_power(self) -> float:
        """The weighted power of :meth:`propagated_psf` of a fully transmissive window (the field grid): the
        light a fully open aperture of the same size brings to the sensor (computed once per geometry).

        A learned ``d2`` is read to 4 significant digits, so that it is not recomputed at every optimiser step:
        the open window's share of light on the sensor changes little with it (the LCD's, measured: by 2e-5 of
        itself for a 0.1 % longer d2).
        """
        d2 = float(f"{float(self.d2):.4g}")
        key = (self._wavelengths(), self.scene_config.distance, d2, self.field_grid, self.field_spacing,
               self.knobs.padding, self.optics_dtype)
        cached = getattr(self, "_open_power", None)
        if cached is None or cached[0] != key:
            with torch.no_grad():
                y, x = self.field_coordinates()
                ones = torch.ones(len(y), len(x), dtype=y.dtype, device=y.device)
                cached = self._open_power = (key, float(psf_power(self.propagated_psf(ones, d2))))
        return cached[1]

    # ----------------------------------------------------------------- the field grid
    def field_coordinates(self) -> tuple[torch.Tensor, torch.Tensor]:
        """``(y, x)``: positions of the field samples from the optical axis, metres (1-D, ``self.optics_dtype``).

        ``y[i] = (i - H // 2) * dy`` for ``(H, W) = self.field_grid`` and
        ``(dy, dx) = self.field_spacing``, on the encoder's :attr:`device`.
        """
        return tuple(
            (torch.arange(n, dtype=self.optics_dtype, device=self.device) - n // 2) * d
            for n, d in zip(self.field_grid, self.field_spacing)
        )

    @property
    def oversample(self) -> int:
        """Field samples per grid pixel and axis (``fidelity.psf_oversample``)."""
        return self.knobs.psf_oversample

    @property
    def field_grid(self) -> tuple[int, int]:
        """Grid of the wave field: the simulation grid refined ``oversample`` (odd) times per axis.

        Its centre sample (the optical axis, at index ``N // 2``) is the centre
        sub-sample of grid pixel ``n // 2``, so the pixel-integrated PSF keeps
        the grid's axis convention; the few extra samples past ``n * s`` are
        dropped after propagation.
        """
        s = self.oversample
        out = []
        for n in self.geometry.grid:
            c = (n // 2) * s + (s - 1) // 2
            out.append(2 * c if 2 * c >= n * s else 2 * c + 1)
        return tuple(out)

    @property
    def field_spacing(self) -> tuple[float, float]:
        """Sample spacing of the wave field, metres."""
        return tuple(d / self.oversample for d in self.geometry.spacing)

    def fidelity_padding(self) -> tuple[int, int] | str:
        """Zero padding per side: ``"auto"``, or grid pixels from a fraction of the grid (``fidelity.padding``)."""
        pad = self.knobs.padding
        if pad == "auto":
            return "auto"
        return tuple(math.ceil(pad * n) for n in self.field_grid)

    def _auto_chunk(self, wl, d2) -> int:
        """Wavelengths per batch when ``wavelength_chunk`` is None: all, or 1 above :data:`AUTO_CHUNK_SAMPLES`."""
        hp, wp = self._padded(float(torch.as_tensor(d2).detach().abs().max()), max(wl))
        return 1 if hp * wp * len(wl) > AUTO_CHUNK_SAMPLES else len(wl)

    def propagated_psf(self, mask: torch.Tensor, d2: float | torch.Tensor) -> torch.Tensor:
        """``(3, H, W)`` intensity PSF of an amplitude ``mask``, channels keeping their transmitted power.

        Channel ``c`` is the fraction of the power incident on the window at
        wavelength ``c`` that reaches each sensor pixel
        (``normalize="power"`` of :func:`optoenc.optics.intensity_psf`), so a
        colour whose filter is dimmed gives a dimmer channel.

        Args:
            mask: ``(H, W)`` or ``(3, H, W)`` (one per R, G, B wavelength)
                amplitude transmittance on the field grid (:attr:`field_grid`),
                real or complex.
            d2: mask-to-sensor distance, metres (a tensor may require grad).
        """
        wl = self._wavelengths()
        if self.monochromatic is not None and mask.dim() == 3 and mask.shape[0] == 3:
            mask = mask[1:2]  # the G channel's mask
        step = self.wavelength_chunk or self._auto_chunk(wl, d2)
        psf = torch.cat([
            intensity_psf(
                mask[i : i + step] if mask.dim() == 3 and mask.shape[0] > 1 else mask,
                wl[i : i + step],
                self.field_spacing,
                self.scene_config.distance,
                d2,
                padding=self.fidelity_padding(),
                normalize="power",
            ).reshape(-1, *mask.shape[-2:])
            for i in range(0, len(wl), step)
        ])  # fmt: skip
        return self._grid_psf(psf)

    def _grid_psf(self, psf: torch.Tensor) -> torch.Tensor:
        """``(3, H, W)`` on the grid from a ``(C, ...)`` field-grid PSF: integrated over each grid pixel."""
        if self.oversample > 1:  # intensity integrated over each grid pixel
            s = self.oversample
            H, W = self.geometry.grid
            psf = psf[..., : H * s, : W * s]
            psf = torch.nn.functional.avg_pool2d(psf[None] if psf.dim() == 3 else psf[None, None], s)[0]
        return psf.to(self.optics_dtype).expand(3, -1, -1) if psf.shape[0] == 1 else psf.to(self.optics_dtype)

    # ----------------------------------------------------------------- masks of cells on a lattice
    def separable_applies(self, d2: float | torch.Tensor) -> bool:
        """Whether :meth:`separable_psf` is used: the mask is :attr:`separable`, ``fidelity.propagation`` is
        ``"separable"``, ``d2`` is not learned, and the factorisation drops at most :data:`SEPARABLE_MAX_PHASE`."""
        if not self.separable or self.knobs.propagation != "separable":
            return False
        if isinstance(d2, torch.Tensor) and d2.requires_grad:
            return False
        return self._cross_phase(float(d2)) <= SEPARABLE_MAX_PHASE

    def _wavelengths(self) -> tuple[float, ...]:
        return devices.WAVELENGTHS_RGB if self.monochromatic is None else (self.monochromatic,)

    def _padded(self, d2: float, wavelength: float | None = None) -> tuple[int, int]:
        """The padded field grid for ``|d2|`` and the longest wavelength (or ``wavelength``)."""
        lam = max(self._wavelengths()) if wavelength is None else wavelength
        return padded_shape(self.field_grid, self.field_spacing, lam, abs(d2), self.fidelity_padding())

    def _cross_phase(self, d2: float) -> float:
        key = (self._wavelengths(), self.scene_config.distance, d2, self.field_grid, self.field_spacing, self.knobs.padding)
        cached = getattr(self, "_cross_phases", None)
        if cached is None or cached[0] != key:
            wl = torch.tensor(key[0], dtype=torch.float64)
            phase = cross_phase(self.field_grid, self._padded(d2), self.field_spacing, wl, key[1], d2)
            cached = self._cross_phases = (key, phase)
        return cached[1]

    def cell_factors(self) -> tuple[torch.Tensor, torch.Tensor]:
        """A :attr:`separable` mask's rasterisation factors on the field grid: ``(A_y, A_x)``, ``(H, m)`` and
        ``(W, n)``, with the mask ``A_y @ values @ A_x^T`` (:func:`optoenc.optics.cell_factors`).

        Geometry only: a function of the encoder's configuration and :attr:`field_grid`, read once per geometry
        by :meth:`separable_psf`.
        """
        raise NotImplementedError(f"{type(self).__name__} is separable: it must implement cell_factors()")

    def separable_psf(self, values: torch.Tensor, d2: float) -> torch.Tensor:
        """``(3, H, W)``: :meth:`propagated_psf` of the mask ``A_y @ values @ A_x^T``, propagated axis by axis.

        :mod:`optoenc.optics.separable`: the field is ``L_y V L_x^T`` per
        wavelength, in real arithmetic (:func:`~optoenc.optics.separable_intensity`).
        The axis operators (from :meth:`cell_factors`) are built once per
        geometry and kept, and the sampling diagnostics run when they are built.

        Args:
            values: ``(3, m, n)`` cell transmittances per R, G, B wavelength (or ``(m, n)`` for all).
            d2: mask-to-sensor distance, metres (a float: a learned ``d2`` takes :meth:`propagated_psf`).
        """
        wl = self._wavelengths()
        if self.monochromatic is not None and values.dim() == 3 and values.shape[0] == 3:
            values = values[1:2]  # the G channel's cells
        d1, d2 = self.scene_config.distance, float(d2)
        padded = self._padded(d2)
        key = (wl, d1, d2, padded, self.field_grid, self.field_spacing, self.optics_dtype, str(values.device))
        cached = getattr(self, "_axis_operators", None)
        if cached is None or cached[0] != key:
            ay, ax = self.cell_factors()
            wlt = torch.tensor(wl, dtype=torch.float64)
            ly = axis_operator(ay.cpu(), padded[0], self.field_spacing[0], wlt, d1, d2)
            lx = axis_operator(ax.cpu(), padded[1], self.field_spacing[1], wlt, d1, d2)
            # normalize="power": divided by the unit-amplitude source's power on the window, H W
            lr, bt = real_operators(ly, lx, 1.0 / (self.field_grid[0] * self.field_grid[1]), self.optics_dtype)
            check_sampling(self.field_grid, self.field_spacing, wlt, d2, d1, method="blas", padding=self.fidelity_padding())
            cached = self._axis_operators = (key, lr.to(values.device), bt.to(values.device), wlt)
        psf = separable_intensity(cached[1], values, cached[2])
        check_energy(psf, cached[3], powers_kept=True)
        return self._grid_psf(psf)
