"""The scene -> embedding operator of an encoder: apply, adjoint, the dense matrix, their caches.

Placement on the grid, convolution with the PSF and pixel integration are
linear, so for a given PSF the noise-free measurement of an ``(h, w)`` scene
is one matrix, the ``(C, a, b, h, w)`` tensor ``A`` with
``embedding[c, a, b] = sum_pq A[c, a, b, p, q] scene[p, q]`` (exact for a
piecewise-constant scene: it equals place -> convolve -> integrate on the
simulation grid, :mod:`optoenc.encoders.imaging`).

:class:`SceneOperator` is that map for one scene shape and height, as a
library user and the reconstruction attacks see it::

    op = encoder.operator((28, 28))        # follows the encoder's parameters
    y = op(x)                             # (B, 1, 28, 28) -> (B, C, a, b), as encoder.measure(x)
    A = op.tensor()                       # (C, a, b, 28, 28), differentiable
    M = op.dense()                        # (C a b, 28 * 28) float64, detached
    x_back = op.adjoint(y)                # M^T y, float64

How the operator is built and applied is this module's business and no
setting's: the fine-grid FFT path or the matrix, the scenes' support region,
a banded build with sorted rows held canvas row by canvas row, dense
bfloat16 products on a CPU's matrix units. Each is taken where it pays and
gives the same numbers as the plain path up to the order of float sums
(tests/encoders/test_operator_paths.py; benchmarks/operator_paths.py times
them). The caches (the geometry's correlation tensors, the whole scene's
operator until a parameter changes) live in the encoder's
:class:`~optoenc.encoders._operator_cache.OperatorCache`.
"""

from __future__ import annotations

from typing import Any

import torch

from ..errors import ConfigError
from . import imaging
from ._operator_apply import apply_operator
from ._operator_build import scene_operator
from .sensor import mosaic_matrix

__all__ = ["SceneOperator", "DENSE_DTYPE", "scene_operator", "apply_operator"]

#: Dtype of :meth:`SceneOperator.dense` and the linear algebra on it (reconstruction: small matrices, exact solves).
DENSE_DTYPE = torch.float64


def _numel(shape) -> int:
    out = 1
    for s in shape:
        out *= int(s)
    return out


def _flat(t: torch.Tensor, shape, name: str) -> torch.Tensor:
    if tuple(t.shape[1:]) != tuple(shape):
        raise ConfigError(name, tuple(t.shape), f"must be (batch, {', '.join(str(s) for s in shape)})")
    return t.reshape(t.shape[0], -1).to(DENSE_DTYPE)


class SceneOperator:
    """The linear map from ``(B, S, h, w)`` scenes to ``(B, C, a, b)`` noise-free embeddings.

    Made by :meth:`OpticalEncoder.operator <optoenc.encoders.base.OpticalEncoder.operator>` (it follows the
    encoder's parameters: a learned mask's operator changes with every optimiser step), by :meth:`frozen` (a
    snapshot), or from a matrix (:meth:`from_matrix`, e.g. an operator estimated from scene / embedding pairs).

    Two ways to use it:

    * as the encoder measures: :meth:`apply` (also ``op(x)``), :meth:`apply_window`, :meth:`apply_pasted`
      and :meth:`tensor` run in the encoder's precisions (``fidelity.dtype``, ``fidelity.operator_dtype``),
      differentiable with respect to the scenes and the encoder's parameters;
    * as a matrix, for reconstruction: :meth:`dense` (``(C a b, S h w)``, float64, detached), and
      :meth:`forward`, :meth:`adjoint`, :meth:`gram` and :meth:`norm` on it: exact float64 linear algebra.

    ``S`` scene channels: 1 (a gray scene, seen by every sensor channel) or ``C`` (a colour scene, channel
    ``c`` seen by sensor channel ``c``: :meth:`dense` is block diagonal).

    Attributes:
        encoder: the encoder (None for a snapshot or a matrix).
        height: the scene's physical height, metres (None: the encoder's ``scene.object_height``).
    """

    def __init__(self, encoder, scene_shape: tuple[int, int], height: float | None = None, scene_channels: int = 1):
        h, w = (int(v) for v in scene_shape)
        C, a, b = encoder.output_shape
        if scene_channels not in (1, encoder.channels):
            raise ConfigError("scene channels", scene_channels, f"must be 1 or the sensor's {encoder.channels}")
        encoder._check_height(height)
        self.encoder = encoder
        self.height = height
        self._scene_shape = (int(scene_channels), h, w)
        self._embedding_shape = (C, a, b)
        self._matrix: torch.Tensor | None = None
        self._cache: dict[str, Any] = {}

    @classmethod
    def from_matrix(cls, matrix: torch.Tensor, scene_shape: tuple[int, int, int],
                    embedding_shape: tuple[int, int, int]) -> "SceneOperator":
        """A map given by its ``(C a b, S h w)`` matrix (held detached, in float64).

        Raises:
            ConfigError: the matrix's shape does not match the two shapes.
        """
        m, n = matrix.shape
        if m != _numel(embedding_shape) or n != _numel(scene_shape):
            raise ConfigError(
                "operator", tuple(matrix.shape),
                f"must be ({_numel(embedding_shape)}, {_numel(scene_shape)}) for scenes "
                f"{tuple(scene_shape)} and embeddings {tuple(embedding_shape)}",
            )
        op = cls.__new__(cls)
        op.encoder, op.height = None, None
        op._scene_shape = tuple(int(s) for s in scene_shape)
        op._embedding_shape = tuple(int(s) for s in embedding_shape)
        op._matrix = matrix.detach().to(DENSE_DTYPE)
        op._cache = {}
        return op

    # ----------------------------------------------------------------- shapes
    @property
    def scene_shape(self) -> tuple[int, int, int]:
        """``(S, h, w)`` of one scene."""
        return self._scene_shape

    @property
    def embedding_shape(self) -> tuple[int, int, int]:
        """``(C, a, b)`` of one embedding."""
        return self._embedding_shape

    @property
    def shape(self) -> tuple[int, int]:
        """``(C a b, S h w)``: the shape of :meth:`dense`."""
        return (_numel(self._embedding_shape), _numel(self._scene_shape))

    def __repr__(self) -> str:
        src = "matrix" if self.encoder is None else f"encoder={self.encoder.name!r}"
        return f"SceneOperator({src}, scene_shape={self.scene_shape}, embedding_shape={self.embedding_shape})"

    # ----------------------------------------------------------------- as the encoder measures
    def apply(self, scene: torch.Tensor) -> torch.Tensor:
        """Noise-free embeddings ``(B, C, a, b)`` of ``(B, S, h, w)`` scenes: ``encoder.measure(scene, height)``.

        The same numbers as :meth:`OpticalEncoder.measure <optoenc.encoders.base.OpticalEncoder.measure>`,
        differentiable; for a snapshot or a matrix, :meth:`forward`.
        """
        if self.encoder is None:
            return self.forward(scene)
        if tuple(scene.shape[-2:]) != self._scene_shape[1:]:
            raise ConfigError("scene", tuple(scene.shape), f"must be (batch, channels, {self._scene_shape[1]}, {self._scene_shape[2]})")
        return self.encoder.measure(scene, self.height)

    __call__ = apply

    def _encoder(self, what: str):
        if self.encoder is None:
            raise ConfigError("operator", "a matrix", f"{what} needs an encoder's operator (not a snapshot or a matrix)")
        return self.encoder

    def apply_window(self, windows: torch.Tensor, corner: tuple[int, int]) -> torch.Tensor:
        """:meth:`apply` of scenes that are zero outside one window, given the window's pixels.

        ``windows`` ``(B, C, h, w)`` are the scenes' pixels ``[r0, r0 + h) x [c0, c0 + w)``, ``corner =
        (r0, c0)``; every other pixel is zero. The same numbers as :meth:`apply` of the whole scenes, without
        building them: the operator of the window alone where that is cheaper.

        Raises:
            ConfigError: the window does not lie within the scene.
        """
        enc = self._encoder("apply_window")
        r0, c0 = (int(v) for v in corner)
        h, w = windows.shape[-2:]
        H, W = self._scene_shape[1:]
        if r0 < 0 or c0 < 0 or r0 + h > H or c0 + w > W:
            raise ConfigError("window", (r0, c0, h, w), f"must lie within the {H} x {W} scene")
        x = enc._checked_scene(windows)

        def laid(dtype, whole: bool) -> torch.Tensor:
            v = _in_optics(enc, x, dtype)
            if not whole:
                return v.to(dtype)
            scenes = x.new_zeros(*x.shape[:2], H, W, dtype=dtype)
            scenes[..., r0 : r0 + h, c0 : c0 + w] = v
            return scenes

        return enc._read_out(enc._operators.measure_laid(enc, x, (r0, r0 + h, c0, c0 + w), (H, W), self.height, laid))

    def apply_pasted(self, windows: torch.Tensor, offsets: torch.Tensor, part: tuple[int, int, int, int]) -> torch.Tensor:
        """:meth:`apply` of scenes that are zero but for one window each, pasted at its own offset.

        ``windows`` ``(B, C, h, w)``: example ``b``'s pixels from ``offsets[b]`` (row, column; ``(B, 2)``
        integers) on; every window lies in ``part = (r0, r1, c0, c1)``. The same numbers as
        :meth:`apply_window` of the windows pasted on ``part``, without that intermediate: the windows are
        pasted where the operator reads them, in its precision (a shifted digit's window is ~5 % of Table 3's
        canvas).

        Raises:
            ConfigError: a window outside ``part``, or ``part`` outside the scene.
        """
        enc = self._encoder("apply_pasted")
        r0, r1, c0, c1 = (int(v) for v in part)
        h, w = windows.shape[-2:]
        H, W = self._scene_shape[1:]
        offsets = offsets.to(windows.device, torch.long)
        lo, hi = offsets.amin(0).tolist(), (offsets.amax(0) + torch.tensor([h, w], device=offsets.device)).tolist()
        if r0 < 0 or c0 < 0 or r1 > H or c1 > W or lo[0] < r0 or lo[1] < c0 or hi[0] > r1 or hi[1] > c1:
            raise ConfigError("windows", (tuple(lo), tuple(hi)),
                              f"must lie within the part {(r0, r1, c0, c1)} of the {H} x {W} scene")
        x = enc._checked_scene(windows)

        def laid(dtype, whole: bool) -> torch.Tensor:
            v = _in_optics(enc, x, dtype).to(dtype)
            if whole:
                return imaging.paste(v, offsets, (H, W))
            return imaging.paste(v, offsets - torch.tensor([r0, c0], device=offsets.device), (r1 - r0, c1 - c0))

        return enc._read_out(enc._operators.measure_laid(enc, x, (r0, r1, c0, c1), (H, W), self.height, laid))

    def tensor(self, region: tuple[int, int, int, int] | None = None) -> torch.Tensor:
        """The ``(C, a, b, h, w)`` operator ``A``: ``embedding[c, a, b] = sum_pq A[c, a, b, p, q] scene[p, q]``.

        ``C`` counts the sensor's colour planes: for a Bayer sensor the three planes before the mosaic
        (:func:`optoenc.encoders.sensor.mosaic`; :meth:`dense` includes it).

        Built in ``fidelity.operator_dtype`` on the encoder's device, differentiable with respect to its
        parameters, cached until a parameter changes. It may be a view of another layout (the layout its
        build and product use): ``.reshape`` or ``.contiguous()`` copies it where a flat matrix is needed.

        Args:
            region: ``(r0, r1, c0, c1)``: only the columns of scene pixels ``[r0, r1) x [c0, c1)``, a
                ``(C, a, b, r1 - r0, c1 - c0)`` tensor (not cached), equal to ``tensor()[..., r0:r1, c0:c1]``
                for a fraction of its cost.
        """
        enc = self._encoder("tensor")
        return enc._operators.tensor(enc, self._scene_shape[1:], self.height, region)

    # ----------------------------------------------------------------- as a matrix
    def _state(self):
        # The encoder's parameters and buffers (versions, storage), its device and pattern: not grad mode.
        return None if self.encoder is None else self.encoder._state_key()[1:]

    def dense(self) -> torch.Tensor:
        """``(C a b, S h w)`` float64 matrix of the map, detached (recomputed when the encoder's parameters change).

        Row ``(c, a, b)``, column ``(s, p, q)`` (row-major flattening of the shapes); for ``S = C`` block
        diagonal (scene channel ``c`` reaches sensor channel ``c`` only).
        """
        if self.encoder is None:
            return self._matrix
        state = self._state()
        if self._cache.get("state") != state:
            with torch.no_grad():
                matrix = self._as_matrix(self.tensor().detach().to(DENSE_DTYPE))
            self._cache = {"state": state, "dense": matrix}
        return self._cache["dense"]

    def _as_matrix(self, op: torch.Tensor) -> torch.Tensor:
        """The ``(C a b, S h w)`` matrix of a ``(C, a, b, h, w)`` operator tensor (its dtype, its graph)."""
        C, a, b, h, w = op.shape
        flat = op.reshape(C, a * b, h * w)
        matrix = flat.reshape(C * a * b, h * w) if self._scene_shape[0] == 1 else torch.block_diag(*flat)
        if self.encoder.sensor.color == "bayer":  # the mosaic of the colour planes
            matrix = mosaic_matrix((a, b), op.dtype).to(matrix.device) @ matrix
        return matrix

    def matrix_in_graph(self, dtype: torch.dtype = DENSE_DTYPE) -> torch.Tensor:
        """:meth:`dense` in ``dtype`` and differentiable with respect to the encoder's parameters (not cached
        here; :meth:`tensor` is): for reconstruction inside a training graph (physics-informed decoders), so a
        learned mask is trained through the solve."""
        self._encoder("matrix_in_graph")
        return self._as_matrix(self.tensor().to(dtype))

    @property
    def matrix(self) -> torch.Tensor:
        """:meth:`dense`."""
        return self.dense()

    def frozen(self) -> "SceneOperator":
        """A snapshot of this map as it is now (:meth:`from_matrix` of :meth:`dense`): it no longer follows the encoder."""
        return SceneOperator.from_matrix(self.dense(), self._scene_shape, self._embedding_shape)

    def forward(self, scene: torch.Tensor) -> torch.Tensor:
        """``(B, S, h, w)`` scenes -> ``(B, C, a, b)`` embeddings, float64: ``dense() @ x``."""
        x = _flat(scene, self._scene_shape, "scene")
        return (x @ self.dense().T).reshape(-1, *self._embedding_shape)

    def adjoint(self, embedding: torch.Tensor) -> torch.Tensor:
        """The transpose of :meth:`forward`: ``(B, C, a, b)`` -> ``(B, S, h, w)`` (back-projection), float64."""
        y = _flat(embedding, self._embedding_shape, "embedding")
        return (y @ self.dense()).reshape(-1, *self._scene_shape)

    def gram(self) -> torch.Tensor:
        """``A^T A``, ``(S h w, S h w)`` float64 (kept while the map is unchanged)."""
        dense = self.dense()
        if self._cache.get("gram_of") is not dense:
            self._cache.update(gram_of=dense, gram=dense.T @ dense, norm=None)
        return self._cache["gram"]

    def norm(self) -> float:
        """Spectral norm (largest singular value), from the Gram matrix's largest eigenvalue."""
        gram = self.gram()
        if self._cache.get("norm") is None:
            self._cache["norm"] = float(torch.linalg.eigvalsh(gram)[-1].clamp_min(0).sqrt())
        return self._cache["norm"]


def _in_optics(enc, x: torch.Tensor, dtype) -> torch.Tensor:
    """``x`` rounded through the optics' precision on its way to ``dtype``, as ``measure`` rounds it; as it is where
    it is already in either (a bfloat16 window from autocast: the same values)."""
    return x if x.dtype in (enc.optics_dtype, dtype) else x.to(enc.optics_dtype)
