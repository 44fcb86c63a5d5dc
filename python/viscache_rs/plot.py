"""Figures for notebooks and reports (matplotlib, needed only when a function here is
called).

``compare(a, b, ref=None, labels=("a", "b"), exposure=None)`` puts two images side by side
with a false-colour map of their per-pixel relMSE (the project's one error metric,
:mod:`viscache_rs.metrics`: the mean over channels of ``(x - ref)^2 / (ref^2 + 1e-2)``):

- without ``ref``: panels ``a``, ``b`` and the relMSE of ``a`` against ``b``;
- with ``ref``: panels ``a``, ``b``, ``ref`` and the relMSE of each against ``ref``, on one
  colour scale so that the two maps can be compared by eye.

Images are (H, W, 3) linear arrays or anything with such an ``image`` (``RenderResult``,
``RelightResult``); (H, W) images (``AOResult``) are shown as grey. All images are shown at
one exposure (default: :func:`~viscache_rs.io.auto_exposure` of the reference, or of ``b``
without one), so a brighter panel is a brighter image. The maps are on a log scale; pixels
without a value (NaN in the reference) are left blank. The mean relMSE of each map is in
its title.

The figure is a :class:`matplotlib.figure.Figure` made without ``pyplot``: it needs no
display and no backend (headless runs, servers, tests), is not kept alive by ``pyplot``'s
figure list, and shows itself in Jupyter (it has ``_repr_png_``). Save it with
``fig.savefig(path)``.
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from typing import Any

import numpy as np

from .io import auto_exposure, to_srgb8
from .metrics import DENOMINATOR_FLOOR

__all__ = ["compare", "relmse_map"]


def _image(x: Any, name: str) -> np.ndarray:
    """An (H, W, 3) float64 image from an array or an object with ``image``."""
    arr = getattr(x, "image", x)
    try:
        img = np.asarray(arr, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise TypeError(f"{name}: expected an image array or a result with .image, "
                        f"got {type(x).__name__}") from e
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=-1)
    if img.ndim != 3 or img.shape[-1] != 3 or img.shape[0] == 0 or img.shape[1] == 0:
        raise ValueError(f"{name}: expected an (H, W, 3) or (H, W) image, got shape "
                         f"{img.shape}")
    return img


def relmse_map(image: Any, reference: Any) -> np.ndarray:
    """Per-pixel relMSE of ``image`` against ``reference``, (H, W): the mean over the three
    channels of ``(x - ref)^2 / (ref^2 + 1e-2)`` (:mod:`viscache_rs.metrics`); NaN where
    the reference is NaN. Its mean over the finite pixels is ``metrics.relmse``."""
    x = _image(image, "image")
    ref = _image(reference, "reference")
    if x.shape != ref.shape:
        raise ValueError(f"image: shape {x.shape} differs from the reference's {ref.shape}")
    with np.errstate(invalid="ignore"):
        per_channel = (x - ref) ** 2 / (ref * ref + DENOMINATOR_FLOOR)
    return per_channel.mean(axis=-1)


def _figure_class():
    from matplotlib.figure import Figure

    class ComparisonFigure(Figure):
        """A matplotlib figure that Jupyter shows without ``pyplot``."""

        def _repr_png_(self) -> bytes:
            buf = io.BytesIO()
            self.savefig(buf, format="png")
            return buf.getvalue()

    return ComparisonFigure


def compare(a: Any, b: Any, ref: Any = None, labels: Sequence[str] = ("a", "b"),
            exposure: float | None = None, panel_inches: float = 3.2):
    """Side-by-side panels of ``a`` and ``b`` (and ``ref``) with false-colour relMSE maps;
    see the module docstring. Returns the :class:`matplotlib.figure.Figure`, whose axes are
    in ``fig.axes`` (images first, then maps, then the colour bar)."""
    from matplotlib.colors import LogNorm

    if len(labels) != 2 or not all(isinstance(s, str) for s in labels):
        raise ValueError(f"labels: expected two strings, got {labels!r}")
    if not (isinstance(panel_inches, (int, float)) and panel_inches > 0):
        raise ValueError(f"panel_inches: must be a positive number, got {panel_inches!r}")
    x, y = _image(a, "a"), _image(b, "b")
    if x.shape != y.shape:
        raise ValueError(f"b: shape {y.shape} differs from a's {x.shape}")
    images = [(x, labels[0]), (y, labels[1])]
    if ref is None:
        maps = [(relmse_map(x, y), f"relMSE of {labels[0]} against {labels[1]}")]
        shown_ref = y
    else:
        r = _image(ref, "ref")
        if r.shape != x.shape:
            raise ValueError(f"ref: shape {r.shape} differs from a's {x.shape}")
        images.append((r, "reference"))
        maps = [(relmse_map(x, r), f"relMSE of {labels[0]}"),
                (relmse_map(y, r), f"relMSE of {labels[1]}")]
        shown_ref = r
    if exposure is None:
        exposure = auto_exposure(np.nan_to_num(shown_ref, nan=0.0, posinf=0.0, neginf=0.0))
    elif not (isinstance(exposure, (int, float, np.floating)) and np.isfinite(exposure)
              and exposure > 0):
        raise ValueError(f"exposure: must be a positive finite number, got {exposure!r}")

    # One log scale for every map: from the smallest positive value (at least 1e-6 of the
    # largest, so that a few exact pixels do not stretch the scale) to the largest.
    values = np.concatenate([m[np.isfinite(m)].ravel() for m, _ in maps])
    positive = values[values > 0]
    top = float(positive.max()) if positive.size else 1.0
    bottom = max(float(positive.min()), top * 1e-6) if positive.size else top * 1e-6
    if bottom >= top:
        bottom = top / 10
    norm = LogNorm(vmin=bottom, vmax=top, clip=True)

    h, w = x.shape[:2]
    panels = len(images) + len(maps)
    fig = _figure_class()(figsize=(panel_inches * panels + 0.6,
                                   panel_inches * h / w + 0.6), layout="constrained")
    axes = fig.subplots(1, panels, squeeze=False)[0]
    for ax, (img, title) in zip(axes, images, strict=False):
        ax.imshow(to_srgb8(img, exposure), interpolation="nearest")
        ax.set_title(title)
    cmap = _map_colours()
    shown = None
    for ax, (m, title) in zip(axes[len(images):], maps, strict=True):
        finite = m[np.isfinite(m)]
        mean = float(finite.mean()) if finite.size else float("nan")
        # Exact pixels (0) would be off a log scale: shown at its bottom; NaN stays blank.
        shown = ax.imshow(np.where(m > 0, m, np.where(np.isnan(m), np.nan, bottom)),
                          cmap=cmap, norm=norm,
                          interpolation="nearest")
        ax.set_title(f"{title}\nmean {mean:.3g}")
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    fig.colorbar(shown, ax=list(axes[len(images):]), shrink=0.8, label="relMSE")
    return fig


def _map_colours():
    import matplotlib

    # NaN: no reference value, left blank.
    return matplotlib.colormaps["inferno"].with_extremes(bad="white")
