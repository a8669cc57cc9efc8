"""`PatternSet`: an encoder that displays one of ``K`` patterns per capture (the variable-pattern defence).

The follow-up work on these cameras (Bezzam et al. 2022) defends a
programmable mask against attackers who estimate its operator from known
pairs, or train an inversion for it, by changing the displayed pattern
between captures. :class:`PatternSet` gives a mask encoder ``K`` patterns,
all learned jointly with one decoder that is *not told* which pattern made
an embedding:

* :attr:`active_pattern` is the pattern that :meth:`psf`, :meth:`operator`,
  :meth:`mask` and the subclass's ``displayed_amplitudes()`` refer to (0 unless
  :meth:`showing` / :meth:`select_pattern` changed it); each pattern keeps
  its own PSF and operator cache, so switching costs nothing once computed.
* :meth:`measure` of a batch draws one pattern index per example (uniform,
  from ``torch``'s global generator, which the training module reseeds per
  batch: same seed, same draws) unless ``patterns=`` gives them, and images
  each example through its pattern. With ``K = 1`` nothing is drawn and the
  encoder is exactly the single-pattern one.

A deployed camera draws the index per capture from a secret key stream
(e.g. a CSPRNG seeded by a device key) and displays that pattern; the
classifier needs no index. Round-robin also works for the classifier but
lets an attacker who knows the schedule group captures by pattern.
"""

from __future__ import annotations

from contextlib import contextmanager

import torch

from ..errors import ConfigError

__all__ = ["PatternSet", "draw_patterns"]


def draw_patterns(count: int, patterns: int, generator: torch.Generator | None = None) -> torch.Tensor:
    """``(count,)`` int64 pattern indices, uniform in ``0 .. patterns-1`` (global generator if none)."""
    return torch.randint(int(patterns), (int(count),), generator=generator)


class PatternSet:
    """Mixin for a :class:`~optoenc.encoders.mask.MaskEncoder` with :attr:`patterns` patterns (see module doc).

    The subclass sets ``self.patterns`` (``K >= 1``) before any PSF is
    computed and reads :attr:`active_pattern` in its ``displayed_amplitudes()``.
    """

    patterns: int = 1

    @property
    def active_pattern(self) -> int:
        """The pattern :meth:`psf` and :meth:`operator` refer to now."""
        return getattr(self, "_active", 0)

    def select_pattern(self, k: int) -> None:
        """Display pattern ``k`` from now on (its cached PSF and operator come back with it)."""
        k = int(k)
        if not 0 <= k < self.patterns:
            raise ConfigError("pattern", k, f"must be an index in 0..{self.patterns - 1}")
        if k == self.active_pattern:
            return
        stash = self.__dict__.setdefault("_stash", {})
        stash[self.active_pattern] = (self._psf_cache, self._operators.whole)
        self._psf_cache, self._operators.whole = stash.pop(k, (None, None))
        self._active = k

    @contextmanager
    def showing(self, k: int):
        """Context in which pattern ``k`` is displayed (the previous one afterwards)."""
        before = self.active_pattern
        self.select_pattern(k)
        try:
            yield self
        finally:
            self.select_pattern(before)

    def _state_key(self) -> tuple:
        # The pattern index is part of the cache key: a cached PSF can never serve another pattern.
        return super()._state_key() + (self.active_pattern,)

    def invalidate_psf(self) -> None:
        super().invalidate_psf()
        self.__dict__.get("_stash", {}).clear()

    def measure(self, scene: torch.Tensor, height: float | None = None, method: str = "auto",
                patterns: torch.Tensor | None = None) -> torch.Tensor:
        """Noise-free embeddings, each example through its own pattern.

        Args:
            patterns: ``(B,)`` pattern indices; ``None`` draws them
                (:func:`draw_patterns`, global generator) when ``K > 1``.
                Other arguments as :meth:`OpticalEncoder.measure`.
        """
        if patterns is None:
            if self.patterns == 1 or len(scene) == 0:
                return super().measure(scene, height, method)
            patterns = draw_patterns(len(scene), self.patterns)
        patterns = torch.as_tensor(patterns, dtype=torch.long).reshape(-1).cpu()
        if len(patterns) != len(scene):
            raise ConfigError("patterns", tuple(patterns.shape), f"must hold one index per example ({len(scene)})")
        if len(scene) and (int(patterns.min()) < 0 or int(patterns.max()) >= self.patterns):
            raise ConfigError("patterns", [int(patterns.min()), int(patterns.max())],
                              f"indices must be in 0..{self.patterns - 1}")
        order = torch.argsort(patterns, stable=True)
        parts = []
        for k in torch.unique(patterns).tolist():
            sel = order[patterns[order] == k].to(scene.device)
            with self.showing(k):
                parts.append(super().measure(scene[sel], height, method))
        inverse = torch.empty_like(order)
        inverse[order] = torch.arange(len(order))
        return torch.cat(parts)[inverse.to(parts[0].device)]
