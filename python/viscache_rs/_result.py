"""What ``vc.render`` returns, for every method (a module of its own so that the renderers'
front ends, ``render`` and ``vpl``, share it without importing each other)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from . import display


@dataclass
class RenderResult:
    """``image`` and ``variance`` (per-pixel variance of the mean) are (H, W, 3) float32;
    ``alpha`` is the control variate's per-pixel alpha (method "cv", else None); ``stats``
    holds seconds, spp, samples, rays, per-stage CPU seconds and, for "cv", cache figures;
    ``sample_counts`` (H, W) uint32 the samples each pixel took."""

    image: np.ndarray
    variance: np.ndarray
    stats: dict[str, Any] = field(default_factory=dict)
    alpha: np.ndarray | None = None
    sample_counts: np.ndarray | None = None

    @property
    def standard_error(self) -> np.ndarray:
        """Per-pixel standard error of the mean, (H, W, 3)."""
        return np.sqrt(self.variance)

    # Jupyter shows the image; ``save`` writes EXR or PNG (``viscache_rs.display``).
    _repr_png_ = display.radiance_repr_png
    save = display.radiance_save


__all__ = ["RenderResult"]
