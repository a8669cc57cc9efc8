"""Object-plane augmentations (REFERENCE §3 robustness): shift, rescale, rotate, perspective.

They act on a *canvas*: the object plane over the camera's whole field of
view (FOV), sampled at ``CanvasGeometry.pitch`` metres, with the digit placed
centred at its physical size by :func:`to_canvas`. The encoder then images
the canvas as a scene of height ``CanvasGeometry.height``. Parameters are in
physical units, drawn per example from torch's global RNG at every call (so
``lightning.seed_everything`` makes them reproducible).

Shift and rescale are exact area resamplings of the piecewise-constant canvas
(total intensity preserved by a shift, scaled by ``s**2`` by a rescale, while
the object stays on the canvas); rotate and perspective use kornia's bilinear
warps. Chain several with :class:`Compose`, which tracks where the object is
(centre, bounding box, height) so that e.g. a shift after a rescale keeps the
rescaled object in view.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar, Sequence

import torch
from torch import nn

from .encoders.imaging import area_matrix, paste
from .errors import ConfigError
from .settings import Documented, Settings, coerce, setting

__all__ = [
    "CanvasGeometry", "canvas_geometry", "to_canvas", "ObjectState", "Augmentation", "SeparableAugmentation",
    "Compose",
    "Shift", "Rescale", "Rotate", "Perspective", "BUILTIN",
]


@dataclass(frozen=True)
class CanvasGeometry:
    """Sampling of the object-plane canvas (lengths in metres)."""

    shape: tuple[int, int]  #: canvas (rows, columns)
    pitch: float  #: canvas pixel pitch, m
    object_height: float  #: height of the scene image placed by :func:`to_canvas`, m
    object_width: float  #: its width (from the scene's aspect ratio), m
    fov: tuple[float, float]  #: field of view (height, width) in the object plane, m

    @property
    def height(self) -> float:
        """Physical canvas height (the scene height to give the encoder), m; >= the FOV height."""
        return self.shape[0] * self.pitch

    @property
    def width(self) -> float:
        return self.shape[1] * self.pitch

    def object_box(self) -> tuple[float, float, float, float]:
        """``(top, left, rows, cols)`` of the placed object, canvas pixels (centred; whole-pixel aligned
        along an axis where its size is a whole number of pixels, so such a scene is copied exactly)."""
        out = []
        for n, size in zip(self.shape, (self.object_height, self.object_width)):
            px = size / self.pitch
            start = (n - px) / 2
            if abs(px - round(px)) < 1e-6:
                start = math.floor(start + 1e-6)
            out.append((start, px))
        return out[0][0], out[1][0], out[0][1], out[1][1]


def canvas_geometry(
    object_height: float, scene_shape: tuple[int, int], fov_height: float, fov_width: float, min_pitch: float = 0.0
) -> CanvasGeometry:
    """The canvas covering the FOV, pitch ``max(object_height / rows, min_pitch)``.

    Args:
        object_height: physical height of the scene image, m.
        scene_shape: ``(h, w)`` scene pixels.
        fov_height, fov_width: FOV in the object plane (sensor size / magnification), m.
        min_pitch: finest useful pitch (grid spacing / magnification), m.
    """
    for key, v in (("object_height", object_height), ("fov_height", fov_height), ("fov_width", fov_width)):
        if not v > 0:
            raise ConfigError(key, v, "must be > 0 m")
    h, w = (int(s) for s in scene_shape)
    pitch = max(object_height / h, float(min_pitch))
    # Whole canvas pixels inside the field of view (floor): the canvas never
    # reaches past the sensor, so nothing placed on it is cropped.
    shape = (max(1, math.floor(fov_height / pitch + 1e-9)), max(1, math.floor(fov_width / pitch + 1e-9)))
    return CanvasGeometry(shape, pitch, float(object_height), object_height * w / h, (float(fov_height), float(fov_width)))


def to_canvas(scenes: torch.Tensor, geometry: CanvasGeometry) -> torch.Tensor:
    """Place ``(B, C, h, w)`` scenes centred on the ``(B, C, rows, cols)`` canvas at their physical size.

    Exact area resampling (each canvas pixel averages the piecewise-constant
    scene over its area); parts outside the canvas are cropped.
    """
    py, px = _placement(scenes, geometry)
    return py.to(scenes.dtype) @ scenes @ px.to(scenes.dtype).T


def _placement(scenes: torch.Tensor, geometry: CanvasGeometry) -> tuple[torch.Tensor, torch.Tensor]:
    """The float64 ``(rows, h)`` and ``(cols, w)`` area matrices placing ``scenes`` on the canvas."""
    h, w = scenes.shape[-2:]
    if abs(geometry.object_width * h / (geometry.object_height * w) - 1) > 1e-6:
        raise ConfigError("scene", tuple(scenes.shape), f"aspect ratio differs from the canvas geometry's {geometry}")
    top, left, rows, cols = geometry.object_box()
    return (area_matrix(h, geometry.shape[0], top, rows).to(scenes.device),
            area_matrix(w, geometry.shape[1], left, cols).to(scenes.device))


@dataclass
class ObjectState:
    """Where the object is on the canvas, per example: ``center`` and ``box`` ``(B, 2)`` (rows, cols) in
    canvas pixels (the canvas spans ``[0, rows) x [0, cols)``), nominal ``height`` ``(B,)`` in metres."""

    center: torch.Tensor
    box: torch.Tensor
    height: torch.Tensor

    @classmethod
    def initial(cls, geometry: CanvasGeometry, batch: int, object_height: Any = None, device=None) -> "ObjectState":
        """The object as :func:`to_canvas` placed it, of height ``object_height`` (default the geometry's)."""
        top, left, rows, cols = geometry.object_box()
        h = torch.as_tensor(geometry.object_height if object_height is None else object_height, dtype=torch.float64)
        h = h.to(device).expand(batch).clone()
        center = torch.tensor([top + rows / 2, left + cols / 2], dtype=torch.float64, device=device).expand(batch, 2)
        box = torch.stack([h, h * geometry.object_width / geometry.object_height], 1) / geometry.pitch
        return cls(center.clone(), box, h)


def _resample_axis(img: torch.Tensor, dim: int, start: torch.Tensor, scale: torch.Tensor,
                   cells: tuple[Any, int] | None = None) -> torch.Tensor:
    """Exact area resampling along ``dim`` (-2 or -1) of ``(B, C, H, W)`` images: input cell ``p`` maps to
    ``[start + scale p, start + scale (p + 1))`` (output-cell units; ``start``, ``scale`` of shape ``(B,)``).

    Uses the cumulative integral ``F`` of the piecewise-constant input, which
    is exactly linear between cell edges: ``out[y] = scale (F(x1) - F(x0))``.
    ``cells = (lo, hi)``: only output cells ``lo .. hi - 1`` (the same values); ``cells = (first, count)``
    with ``first`` a ``(B,)`` integer tensor: example ``b``'s own cells ``first[b] .. first[b] + count - 1``
    (the same values again: each output cell is computed alone). Images expanded along the batch (one
    placement for every example) are integrated once.
    """
    x = img.transpose(-1, -2) if dim == -1 else img
    B, C, n, m = x.shape
    lo, hi = (0, n) if cells is None else cells
    once = x[:1] if B > 1 and x.stride(0) == 0 else x  # the same rows for every example: one cumulative sum
    F = torch.nn.functional.pad(once.cumsum(2), (0, 0, 1, 0))[:, :, :n].expand(B, C, n, m)  # F at each cell's left edge
    if isinstance(lo, torch.Tensor):  # each example's own cells
        count = hi
        y = (lo.to(img.device)[:, None] + torch.arange(count + 1, device=img.device)).to(torch.float64)
    else:
        count = hi - lo
        y = torch.arange(lo, hi + 1, device=img.device, dtype=torch.float64)[None]
    pos = ((y - start[:, None]) / scale[:, None]).clamp(0, n)  # input coordinate of each output edge
    i = pos.floor().clamp(max=n - 1)
    t = (pos - i).to(img.dtype)[:, None, :, None]
    idx = i.long()[:, None, :, None].expand(B, C, count + 1, m)
    Fi = torch.gather(F, 2, idx) + t * torch.gather(x, 2, idx)  # exactly constant across empty cells
    out = (Fi[:, :, 1:] - Fi[:, :, :-1]) * scale.to(img.dtype)[:, None, None, None]
    out = out.clamp_min(0)
    return out.transpose(-1, -2) if dim == -1 else out


def _band(img: torch.Tensor, start: torch.Tensor, scale: torch.Tensor, lo: int, hi: int) -> tuple[torch.Tensor, int]:
    """``(first (B,), count)``: output cells ``first .. first + count - 1`` of ``[lo, hi)`` hold every cell
    that resampling ``img`` ``(B, C, n, m)`` along its rows (:func:`_resample_axis`) can make nonzero.

    An output cell whose input interval misses the input's nonzero rows is exactly zero (``F`` is exactly
    constant there), so resampling only each example's band and pasting it on a blank window
    (:func:`paste`) gives the same values as the whole range. One spare cell on each side absorbs rounding.
    """
    on = (img if img.stride(0) else img[:1]).ne(0).any(-1).any(1)  # (B or 1, n): rows with a nonzero
    n = on.shape[-1]
    rows = torch.arange(n, device=img.device)
    nz0 = torch.where(on, rows, n).amin(-1).to(torch.float64)
    nz1 = torch.where(on, rows + 1, 0).amax(-1).to(torch.float64)
    a, b = start + scale * nz0, start + scale * nz1
    first = (torch.minimum(a, b).floor() - 1).clamp(lo, hi)
    last = (torch.maximum(a, b).ceil() + 1).clamp(lo, hi)
    count = max(1, int((last - first).max()))
    return first.long().clamp(max=hi - count), count


class Augmentation(Documented, nn.Module):
    """Base class: a random object-plane transform of a canvas ``(B, C, rows, cols)``.

    Subclasses set ``name``, ``Config`` (a :class:`Settings` dataclass, SI
    units unless its help says otherwise), ``n_random`` (how many uniform
    numbers in ``[0, 1)`` one example's transform consumes) and implement
    :meth:`apply`, which draws nothing itself: its randomness is the
    ``(B, n_random)`` tensor ``u``. So a transform can be redrawn every epoch
    (``u`` fresh from torch's global RNG) or drawn once per example and kept
    (``u`` stored with the dataset: the paper's protocol,
    ``trainer.augment_draw=once``).
    """

    name: ClassVar[str] = ""
    Config: ClassVar[type] = Settings
    #: Uniform random numbers per example consumed by :meth:`apply`.
    n_random: ClassVar[int] = 0

    def __init__(self, config: Any = None):
        super().__init__()
        self.config = coerce(self.Config, config, f"augment.{self.name}")

    def apply(
        self, canvas: torch.Tensor, geometry: CanvasGeometry, state: ObjectState, u: torch.Tensor
    ) -> tuple[torch.Tensor, ObjectState]:
        """Transform the canvas of objects in ``state`` with the per-example uniforms ``u`` ``(B, n_random)``."""
        raise NotImplementedError

    def reach(self, half: torch.Tensor) -> torch.Tensor | None:
        """Where this transform's input and output can be nonzero, given where its input can.

        Args:
            half: ``(B, 2)`` half-extents (rows, cols; canvas pixels) of a box about each object's centre
                holding everything nonzero of the input.

        Returns:
            ``(B, 2)`` half-extents of a box about the same centre holding the input and the output; None
            (the default): anywhere on the canvas. :class:`Compose` transforms only the part of the canvas
            these boxes cover (a digit is a few percent of the field of view).
        """
        return None

    def draw(self, batch: int, device=None) -> torch.Tensor:
        """``(batch, n_random)`` float64 uniforms from torch's global RNG."""
        return torch.rand(batch, self.n_random, device=device).double()

    def forward(
        self, canvas: torch.Tensor, geometry: CanvasGeometry, object_height: Any = None, u: torch.Tensor | None = None
    ) -> torch.Tensor:
        """Transform a canvas made by :func:`to_canvas` (object centred, of height ``object_height`` m)."""
        state = ObjectState.initial(geometry, canvas.shape[0], object_height, canvas.device)
        u = self.draw(canvas.shape[0], canvas.device) if u is None else u.to(canvas.device, torch.float64)
        return self.apply(canvas, geometry, state, u)[0]


    def extra_repr(self) -> str:
        return f"config={self.config}"


class SeparableAugmentation(Augmentation):
    """A transform that is an exact area resampling along each axis (shift, rescale).

    Subclasses implement :meth:`resampling`; :class:`Compose` folds such
    transforms into the placement of the scene (:meth:`Compose.place`).
    """

    def resampling(self, geometry: CanvasGeometry, state: ObjectState, u: torch.Tensor):
        """``(((start_rows, scale_rows), (start_cols, scale_cols)), new_state)``: input cell ``p`` of an axis
        maps to ``[start + scale p, start + scale (p + 1))`` (canvas pixels; ``(B,)`` tensors)."""
        raise NotImplementedError

    def apply(self, canvas, geometry, state, u):
        ((t0, s0), (t1, s1)), new = self.resampling(geometry, state, u)
        return _resample_axis(_resample_axis(canvas, -2, t0, s0), -1, t1, s1), new


#: Pixels added on every side of the objects' reach in :meth:`Compose.place_window`: a bilinear warp reads
#: the pixels next to a sample (1), and pixel centres sit half a pixel inside their cells (1).
_WINDOW_MARGIN = 2


#: How many times an example's band (:func:`_band`) must fit in the window for :meth:`Compose.place_window`
#: to resample the bands and paste them (a shift: a digit in ~20x its area) rather than the whole window.
_BAND_GAIN = 4


class Compose(nn.Module):
    """Several augmentations applied in order, tracking the object between them.

    ``u`` ``(B, n_random)`` holds every augmentation's uniforms side by side, in order.
    """

    #: :meth:`place_window` resamples each object's band of the window and pastes it (the same canvases,
    #: exactly); False: the whole window (the reference ``benchmarks/operator_paths.py --paths bands`` times it against).
    placement_bands: ClassVar[bool] = True

    def __init__(self, augmentations: Sequence[Augmentation]):
        super().__init__()
        self.augmentations = nn.ModuleList(augmentations)

    @property
    def n_random(self) -> int:
        return sum(a.n_random for a in self.augmentations)

    def draw(self, batch: int, device=None) -> torch.Tensor:
        return torch.cat([a.draw(batch, device) for a in self.augmentations], dim=1)

    def forward(
        self, canvas: torch.Tensor, geometry: CanvasGeometry, object_height: Any = None, u: torch.Tensor | None = None
    ) -> torch.Tensor:
        state = ObjectState.initial(geometry, canvas.shape[0], object_height, canvas.device)
        u = self._draws(canvas.shape[0], canvas.device, u)
        return self._apply(canvas, geometry, state, u, 0, 0)

    def place(
        self, scenes: torch.Tensor, geometry: CanvasGeometry, object_height: Any = None, u: torch.Tensor | None = None
    ) -> torch.Tensor:
        """``self(to_canvas(scenes, geometry), ...)``, computed cheaply: the same canvases.

        Leading separable transforms (shift, rescale) are folded into the
        placement: resampling the canvas ``P x Q^T`` along its rows is
        ``(R P) x Q^T`` (linearity), and ``R P`` resamples only the
        ``rows x h`` placement matrix, not every canvas of the batch. The
        rest transform only the part of the canvas that can be nonzero
        (:meth:`place_window`).
        """
        window, (r0, c0) = self.place_window(scenes, geometry, object_height, u)
        if tuple(window.shape[-2:]) == tuple(geometry.shape):
            return window
        h, w = window.shape[-2:]
        out = window.new_zeros(*window.shape[:-2], *geometry.shape)
        out[..., r0 : r0 + h, c0 : c0 + w] = window
        return out

    def place_window(
        self, scenes: torch.Tensor, geometry: CanvasGeometry, object_height: Any = None, u: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, tuple[int, int]]:
        """:meth:`place`'s canvases, only the part that can be nonzero: ``(window (B, C, h, w), (row, col))``.

        The window is the bounding box, over the batch, of each object's reach
        (:meth:`Augmentation.reach`, plus :data:`_WINDOW_MARGIN` pixels for the
        bilinear warps); the canvas is zero outside it, and the warps there
        read and write zeros only. ``(row, col)``: its top-left pixel on the
        canvas. The whole canvas where a transform may reach anywhere.
        """
        placed, offsets, (r0, r1, c0, c1), local, u, i, k = self._place(scenes, geometry, object_height, u)
        if offsets is not None:  # each example's band, on the window
            placed = paste(placed, offsets - torch.tensor([r0, c0], device=offsets.device), (r1 - r0, c1 - c0))
        return self._apply(placed, geometry, local, u, i, k), (r0, c0)

    def place_bands(
        self, scenes: torch.Tensor, geometry: CanvasGeometry, object_height: Any = None, u: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor, tuple[int, int, int, int]] | None:
        """:meth:`place_window`'s canvases before any band is pasted: ``(placed, offsets, window)`` where every
        transform is a shift or rescale, else None (a warp needs the window: use :meth:`place_window`).

        ``window = (r0, r1, c0, c1)``: the canvas part :meth:`place_window` returns. ``offsets`` ``(B, 2)``: each
        example's band's top-left pixel on the canvas (rows, cols), ``placed`` the bands ``(B, C, h, w)``; or
        None where the whole window was resampled (a band would be most of it), ``placed`` that window. The same
        draws give the same canvases: :meth:`~optoenc.encoders.operator.SceneOperator.apply_pasted` measures the
        bands without pasting them on the window first.
        """
        if any(not isinstance(a, SeparableAugmentation) for a in self.augmentations):
            return None
        placed, offsets, window, _local, _u, _i, _k = self._place(scenes, geometry, object_height, u)
        return placed, offsets, window

    def _place(self, scenes, geometry, object_height, u):
        """``(placed, offsets, (r0, r1, c0, c1), local state, u, i, k)``: the leading separable transforms applied
        to the placement, by bands (``placed`` each example's band, ``offsets`` ``(B, 2)`` their canvas corners)
        or over the whole window (``offsets`` None); ``i`` transforms and ``k`` columns of ``u`` used."""
        B = scenes.shape[0]
        u = self._draws(B, scenes.device, u)
        p, q = (m.expand(B, 1, -1, -1) for m in _placement(scenes, geometry))
        resamplings, state, k = self._separable(geometry, ObjectState.initial(geometry, B, object_height, scenes.device), u)
        i = len(resamplings)
        (r0, r1), (c0, c1) = self._window(geometry, state, list(self.augmentations)[i:])
        for (t0, s0), (t1, s1) in resamplings[:-1]:
            p, q = _resample_axis(p, -2, t0, s0), _resample_axis(q, -2, t1, s1)
        offsets = None
        if i:  # the last only over each example's band of the window's rows and columns (its object)
            (t0, s0), (t1, s1) = resamplings[-1]
            rows, cols = _band(p, t0, s0, r0, r1), _band(q, t1, s1, c0, c1)
            if not self.placement_bands or rows[1] * cols[1] * _BAND_GAIN > (r1 - r0) * (c1 - c0):  # hardly larger
                rows, cols = (r0, r1), (c0, c1)
            else:
                offsets = torch.stack([rows[0], cols[0]], 1)
            p, q = _resample_axis(p, -2, t0, s0, rows), _resample_axis(q, -2, t1, s1, cols)
        else:
            p, q = p[:, :, r0:r1], q[:, :, c0:c1]
        py = p[:, 0].to(scenes.dtype)[:, None]
        qx = q[:, 0].to(scenes.dtype).transpose(-1, -2)[:, None]
        corner = torch.tensor([r0, c0], dtype=state.center.dtype, device=state.center.device)
        local = ObjectState(state.center - corner, state.box, state.height)
        return py @ scenes @ qx, offsets, (r0, r1, c0, c1), local, u, i, k

    def placed_state(self, geometry: CanvasGeometry, object_height: Any, u: torch.Tensor) -> ObjectState:
        """Where the leading shifts and rescales put each object (draws ``u`` ``(B, n_random)``): the
        centres the other transforms turn and warp about, and the boxes. Cheap: no pixels are touched."""
        u = self._draws(len(u), u.device, u)
        return self._separable(geometry, ObjectState.initial(geometry, len(u), object_height, u.device), u)[1]

    def _separable(self, geometry: CanvasGeometry, state: ObjectState, u: torch.Tensor):
        """``(resamplings, state, k)``: the leading separable transforms' resamplings in order, the object
        state they leave and how many of ``u``'s columns they used."""
        resamplings, k = [], 0
        for aug in self.augmentations:
            if not isinstance(aug, SeparableAugmentation):
                break
            resampling, state = aug.resampling(geometry, state, u[:, k : k + aug.n_random])
            resamplings.append(resampling)
            k += aug.n_random
        return resamplings, state, k

    @staticmethod
    def _window(geometry: CanvasGeometry, state: ObjectState, rest) -> tuple[tuple[int, int], tuple[int, int]]:
        """``((r0, r1), (c0, c1))``: the canvas rows and columns the transforms ``rest`` can make nonzero."""
        rows, cols = geometry.shape
        half = state.box / 2
        for aug in rest:
            half = aug.reach(half)
            if half is None:
                return (0, rows), (0, cols)
        lo = (state.center - half - _WINDOW_MARGIN).floor().amin(0)
        hi = (state.center + half + _WINDOW_MARGIN).ceil().amax(0)
        r0, c0 = (max(0, int(v)) for v in lo)
        r1, c1 = min(rows, int(hi[0])), min(cols, int(hi[1]))
        if r1 <= r0 or c1 <= c0:  # every object off the canvas: one dark pixel
            return (0, 1), (0, 1)
        return (r0, r1), (c0, c1)

    def _draws(self, batch: int, device, u: torch.Tensor | None) -> torch.Tensor:
        u = self.draw(batch, device) if u is None else u.to(device, torch.float64)
        if u.shape[-1] != self.n_random:
            raise ConfigError("augmentation draws", tuple(u.shape), f"need {self.n_random} uniforms per example")
        return u

    def _apply(self, canvas, geometry, state, u, first: int, k: int) -> torch.Tensor:
        """Apply the augmentations from index ``first`` on (their draws from column ``k``)."""
        for aug in list(self.augmentations)[first:]:
            canvas, state = aug.apply(canvas, geometry, state, u[:, k : k + aug.n_random])
            k += aug.n_random
        return canvas


@dataclass
class ShiftConfig(Settings):
    margin: float = setting(0.0, "clearance kept between the object's bounding box and the FOV edge", unit="m", ge=0)


class Shift(SeparableAugmentation):
    """Shift: uniform translation anywhere in the field of view, object fully visible."""

    name = "shift"
    Config = ShiftConfig
    n_random = 2

    def resampling(self, geometry, state, u):
        new = torch.empty_like(state.center)
        for a, (n, fov) in enumerate(zip(geometry.shape, geometry.fov)):
            half = min(fov / geometry.pitch, n) / 2
            lo = n / 2 - half + state.box[:, a] / 2 + self.config.margin / geometry.pitch
            hi = n / 2 + half - state.box[:, a] / 2 - self.config.margin / geometry.pitch
            new[:, a] = torch.where(hi >= lo, lo + u[:, a] * (hi - lo), state.center[:, a])  # too big: stays
        t, one = new - state.center, torch.ones(len(u), dtype=torch.float64, device=u.device)
        return ((t[:, 0], one), (t[:, 1], one)), ObjectState(new, state.box, state.height)


@dataclass
class RescaleConfig(Settings):
    min_height: float = setting(0.02, "smallest object height", unit="m", gt=0)
    max_height: float = setting(0.20, "largest object height", unit="m", gt=0)

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.max_height < self.min_height:
            raise ConfigError("max_height", self.max_height, f"must be >= min_height = {self.min_height:g} m")


class Rescale(SeparableAugmentation):
    """Rescale: object height ~ U[min_height, max_height], about the object's centre."""

    name = "rescale"
    Config = RescaleConfig
    n_random = 1

    def resampling(self, geometry, state, u):
        target = self.config.min_height + (self.config.max_height - self.config.min_height) * u[:, 0]
        s = target / state.height
        c = state.center
        return ((c[:, 0] * (1 - s), s), (c[:, 1] * (1 - s), s)), ObjectState(c, state.box * s[:, None], target)


@dataclass
class RotateConfig(Settings):
    max_angle: float = setting(90.0, "rotation angle ~ U[-max_angle, max_angle], in degrees", unit="deg", ge=0, le=180)


class Rotate(Augmentation):
    """Rotate: angle ~ U[-90, 90] degrees about the object's centre (bilinear)."""

    name = "rotate"
    Config = RotateConfig
    n_random = 1

    def reach(self, half):
        # A box of half-extents (a, b) turned about its centre stays in the disc of radius hypot(a, b).
        return half.norm(dim=1, keepdim=True).expand(-1, 2)

    def apply(self, canvas, geometry, state, u):
        B, dt = canvas.shape[0], canvas.dtype
        angle = self.config.max_angle * (2 * u[:, 0] - 1)
        center = (state.center.flip(1) - 0.5).to(dt)  # kornia: (x, y), pixel centres at integers
        from kornia.geometry.transform import get_rotation_matrix2d, warp_affine  # lazy: listings stay fast

        m = get_rotation_matrix2d(center, angle.to(dt), torch.ones(B, 2, dtype=dt, device=canvas.device))
        out = warp_affine(canvas, m, tuple(canvas.shape[-2:]), align_corners=True).clamp_min(0)
        c, s = torch.cos(torch.deg2rad(angle)).abs(), torch.sin(torch.deg2rad(angle)).abs()
        h, w = state.box[:, 0], state.box[:, 1]
        return out, ObjectState(state.center, torch.stack([h * c + w * s, h * s + w * c], 1), state.height)


@dataclass
class PerspectiveConfig(Settings):
    distortion: float = setting(0.5, "corner displacement, as a fraction of the box's half size", ge=0, le=1)
    p: float = setting(1.0, "probability of distorting an example", ge=0, le=1)
    about: str = setting(
        "object", "the box whose corners move: 'object' (the object's own box: a distortion of the object in "
        "place) or 'field' (the whole field of view, as torchvision's RandomPerspective on the paper's padded "
        "object plane: the object is also moved and shrunk)", choices=("object", "field"),
    )


class Perspective(Augmentation):
    """Perspective: each corner of a box moves inward by up to distortion x half its size (kornia semantics).

    The box is the object's (``about: object``, a distortion in place) or the field of view's
    (``about: field``: the paper applied torchvision's ``RandomPerspective`` to its whole padded object
    plane, which also displaces and shrinks the object).
    """

    name = "perspective"
    Config = PerspectiveConfig
    n_random = 9  # on/off, then 4 corners x (x, y)

    def reach(self, half):
        # The object's box: its corners move inward, so the box maps into itself. The field's: anywhere.
        return half if self.config.about == "object" else None

    def apply(self, canvas, geometry, state, u):
        B, dt, dev = canvas.shape[0], canvas.dtype, canvas.device
        signs = torch.tensor([[1, 1], [-1, 1], [-1, -1], [1, -1]], dtype=torch.float64, device=dev)  # TL TR BR BL
        if self.config.about == "field":  # the canvas: the field of view in whole pixels
            half = torch.tensor([geometry.shape[1] / 2, geometry.shape[0] / 2], dtype=torch.float64, device=dev)
            half = half.expand(B, 1, 2)  # (B, 1, 2) as (x, y)
            src = half - 0.5 - signs * half
        else:
            half = state.box.flip(1)[:, None, :] / 2  # (B, 1, 2) as (x, y)
            src = state.center.flip(1)[:, None, :] - 0.5 - signs * half
        on = (u[:, 0] < self.config.p).double()[:, None, None]
        shift = self.config.distortion * half * u[:, 1:].reshape(B, 4, 2) * signs * on
        from kornia.geometry.transform import get_perspective_transform, warp_perspective

        m = get_perspective_transform(src, src + shift).to(dt)
        out = warp_perspective(canvas, m, tuple(canvas.shape[-2:]), align_corners=True).clamp_min(0)
        return torch.nan_to_num(out, nan=0.0, posinf=0.0, neginf=0.0), state


#: The built-in augmentations, registered by :mod:`optoenc.plugins.builtins`.
BUILTIN = (Shift, Rescale, Rotate, Perspective)
