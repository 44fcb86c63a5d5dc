"""The project's error metrics, one definition each (experiments, benches, the CLI and
tests use these).

- :func:`relmse`: relative mean squared error on RGB against a reference: the mean over
  pixels and channels of ``(x - ref)^2 / (ref^2 + 1e-2)``, minus the reference's own share
  ``var_ref / (ref^2 + 1e-2)`` when its per-pixel variance is given (so a noisy reference
  does not count against the image). Every channel counts the same: no luminance weighting
  that would hide one. :func:`relmse_per_channel` gives the three channels.
- :func:`efficiency`: ``1 / (relmse * seconds)``.
- :func:`variance_ratio`: per-channel ratio of mean per-pixel variances (an estimator
  against a baseline at equal samples) and their mean.
- :func:`worst_and_mean`: a suite's worst scene beside its geometric mean.
- :func:`mean_variance`: the mean over pixels and channels of a per-pixel variance (an
  image's own noise figure at equal samples); :func:`relative_variance`: the same divided
  by ``ref^2 + 1e-2`` per pixel, the image's own estimate of its relMSE.
- :func:`scalar_errors`: RMSE, RMSE / mean, max error and bias of a one-channel image
  (ambient occlusion) against a reference.
- :data:`LUMINANCE`, :func:`luminance`, :func:`luminance_variance`: Rec. 709 luminance of
  linear RGB and the variance of a luminance estimate (exposure, whole-image checks in
  tests; never an error figure, which would weight blue down).

Pixels where the reference is NaN (no surface in an AO image, say) are left out of every
mean; a NaN in the image where the reference is finite is an error.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

__all__ = [
    "DENOMINATOR_FLOOR",
    "LUMINANCE",
    "efficiency",
    "luminance",
    "luminance_variance",
    "mean_variance",
    "relative_variance",
    "relmse",
    "relmse_per_channel",
    "scalar_errors",
    "variance_ratio",
    "worst_and_mean",
]

#: Rec. 709 luminance weights of linear RGB (the one copy in Python; the Rust core's is
#: ``lights::envmap::LUMINANCE``, the same three numbers).
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])

#: The ``1e-2`` in ``(x - ref)^2 / (ref^2 + 1e-2)``: keeps black pixels from dominating.
DENOMINATOR_FLOOR = 1e-2


def _images(image, reference, reference_variance=None):
    x = np.asarray(image, dtype=np.float64)
    ref = np.asarray(reference, dtype=np.float64)
    if x.shape != ref.shape:
        raise ValueError(f"image: shape {x.shape} differs from the reference's {ref.shape}")
    if x.ndim != 3 or x.shape[-1] != 3:
        raise ValueError(f"image: expected an (H, W, 3) RGB image, got shape {x.shape}")
    var = None
    if reference_variance is not None:
        var = np.asarray(reference_variance, dtype=np.float64)
        if var.shape != ref.shape:
            raise ValueError(f"reference_variance: shape {var.shape} differs from the "
                             f"reference's {ref.shape}")
        if np.any(var[np.isfinite(ref)] < 0):
            raise ValueError("reference_variance: must be non-negative")
    keep = np.isfinite(ref)
    if np.any(~np.isfinite(x) & keep):
        raise ValueError("image: NaN or infinite where the reference is finite")
    return x, ref, var, keep


def relmse_per_channel(image, reference, reference_variance=None) -> np.ndarray:
    """Relative MSE of each RGB channel, shape (3,) (module docstring)."""
    x, ref, var, keep = _images(image, reference, reference_variance)
    den = ref * ref + DENOMINATOR_FLOOR
    err = np.where(keep, (x - ref) ** 2 / den, 0.0)
    if var is not None:
        err = err - np.where(keep, np.nan_to_num(var, posinf=0.0) / den, 0.0)
    count = keep.sum(axis=(0, 1))
    return err.sum(axis=(0, 1)) / np.maximum(count, 1)


def relmse(image, reference, reference_variance=None) -> float:
    """Relative MSE on RGB, the mean over pixels and channels (module docstring)."""
    x, ref, var, keep = _images(image, reference, reference_variance)
    per_channel = relmse_per_channel(x, ref, var)
    count = keep.sum(axis=(0, 1))
    return float((per_channel * count).sum() / max(count.sum(), 1))


def efficiency(error: float, seconds: float) -> float:
    """``1 / (error * seconds)``; NaN unless both are positive."""
    if not (error > 0 and seconds > 0):
        return math.nan
    return 1.0 / (error * seconds)


def variance_ratio(variance, baseline_variance) -> tuple[np.ndarray, float]:
    """Per-channel ratio of the mean per-pixel variance of ``variance`` to that of
    ``baseline_variance`` (both (H, W, 3)), and the mean of the three ratios. Non-finite
    pixels (fewer than two samples, no surface) are left out of both."""
    a = np.asarray(variance, dtype=np.float64)
    b = np.asarray(baseline_variance, dtype=np.float64)
    if a.shape != b.shape or a.ndim != 3 or a.shape[-1] != 3:
        raise ValueError(f"variance: expected two (H, W, 3) images of one shape, got {a.shape} "
                         f"and {b.shape}")
    keep = np.isfinite(a) & np.isfinite(b)
    num = np.where(keep, a, 0.0).sum(axis=(0, 1))
    den = np.where(keep, b, 0.0).sum(axis=(0, 1))
    ratios = np.divide(num, den, out=np.full(3, np.nan), where=den > 0)
    return ratios, float(np.mean(ratios))


def worst_and_mean(values: Mapping[str, float], higher_is_worse: bool = True
                   ) -> dict[str, object]:
    """The worst entry of a suite (name and value) beside the geometric mean of all
    (``higher_is_worse=False`` for figures like efficiency or speed ratios)."""
    items = [(k, float(v)) for k, v in values.items() if np.isfinite(v) and v > 0]
    if not items:
        raise ValueError("values: need at least one positive finite figure")
    worst = max(items, key=lambda kv: kv[1]) if higher_is_worse else min(
        items, key=lambda kv: kv[1])
    geomean = math.exp(sum(math.log(v) for _, v in items) / len(items))
    return {"worst": worst[0], "worst_value": worst[1], "geomean": geomean,
            "count": len(items)}


def luminance(rgb) -> np.ndarray:
    """Rec. 709 luminance of linear RGB: an (..., 3) array -> (...), in float64."""
    return np.asarray(rgb, dtype=np.float64) @ LUMINANCE


def luminance_variance(variance) -> np.ndarray:
    """Variance of the luminance of a pixel from its per-channel variances (..., 3) ->
    (...): ``sum_c w_c^2 var_c`` with the :data:`LUMINANCE` weights ``w``, in float64.
    It treats the channels' errors as independent; one sample drives all three, so their
    errors are positively correlated and the true variance is up to
    ``(sum_c w_c sqrt(var_c))^2``: a standard error from this is on the small side (a
    test that uses it is stricter, never looser)."""
    return np.asarray(variance, dtype=np.float64) @ (LUMINANCE * LUMINANCE)


def mean_variance(variance) -> float:
    """Mean over pixels and channels of a per-pixel variance (of the mean), accumulated in
    float64; non-finite entries (fewer than two samples, no surface) are left out, NaN when
    none is finite. Every channel counts the same."""
    v = np.asarray(variance, dtype=np.float64)
    keep = np.isfinite(v)
    return float(np.mean(v[keep])) if keep.any() else math.nan


def relative_variance(variance, reference) -> float:
    """Mean over pixels and channels of ``variance / (ref^2 + 1e-2)``: an image's own
    estimate of its relMSE against ``reference`` (the expected relMSE of an unbiased image
    with this per-pixel variance of the mean), and the share :func:`relmse` subtracts for a
    reference's own variance. Pixels where the reference is NaN are left out."""
    v = np.asarray(variance, dtype=np.float64)
    ref = np.asarray(reference, dtype=np.float64)
    if v.shape != ref.shape:
        raise ValueError(f"variance: shape {v.shape} differs from the reference's {ref.shape}")
    keep = np.isfinite(ref)
    share = v / (ref * ref + DENOMINATOR_FLOOR)
    return float(np.mean(share[keep])) if keep.any() else math.nan


def scalar_errors(image, reference) -> dict[str, float]:
    """Errors of a one-channel image (ambient occlusion in [0, 1]) against a reference,
    over the pixels where both are finite (no surface: NaN in both): ``rmse``,
    ``relative_rmse`` (RMSE / the reference's mean), ``max_error`` (largest ``|error|``),
    ``bias`` (mean error), ``mean_ao`` (the reference's mean) and ``pixels`` (how many
    were compared). A scalar image has no channel to hide, so RMSE is the figure here; RGB
    images use :func:`relmse`."""
    x = np.asarray(image)
    ref = np.asarray(reference)
    if x.shape != ref.shape:
        raise ValueError(f"image: shape {x.shape} differs from the reference's {ref.shape}")
    m = np.isfinite(x) & np.isfinite(ref)
    if not m.any():
        raise ValueError("image: no pixel where both the image and the reference are finite")
    e = x[m].astype(np.float64) - ref[m]
    mean = float(ref[m].mean())
    rmse = float(np.sqrt(np.mean(e * e)))
    return {"rmse": rmse, "relative_rmse": rmse / mean, "max_error": float(np.abs(e).max()),
            "bias": float(e.mean()), "mean_ao": mean, "pixels": int(m.sum())}
