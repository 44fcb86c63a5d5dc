"""The error metrics (viscache_rs.metrics): known answers, channels counted alike, the
reference's own variance, NaN handling and bad input."""

import math

import numpy as np
import pytest
from viscache_rs import metrics


def test_relmse_known_answers_and_channels_count_alike():
    ref = np.ones((4, 5, 3))
    img = ref.copy()
    img[..., 2] += 0.5  # only blue is off
    # (0.5^2) / (1 + 1e-2) in one channel of three.
    want = 0.25 / 1.01 / 3
    assert metrics.relmse(img, ref) == pytest.approx(want)
    per = metrics.relmse_per_channel(img, ref)
    assert per == pytest.approx([0.0, 0.0, 0.25 / 1.01])
    # A black reference pixel is measured against the floor 1e-2, not divided by zero.
    black = np.zeros((1, 1, 3))
    assert metrics.relmse(black + 0.1, black) == pytest.approx(0.01 / 1e-2)


def test_the_references_own_variance_is_subtracted():
    rng = np.random.default_rng(3)
    truth = rng.uniform(0.5, 2.0, (30, 40, 3))
    var = np.full_like(truth, 1e-3)
    ref = truth + rng.normal(0, math.sqrt(1e-3), truth.shape)
    img = truth + rng.normal(0, math.sqrt(4e-3), truth.shape)
    raw = metrics.relmse(img, ref)
    corrected = metrics.relmse(img, ref, var)
    exact = float(np.mean(4e-3 / (truth**2 + 1e-2)))
    # The raw figure carries the reference's noise; the corrected one is near the truth.
    assert raw > 1.15 * exact
    assert corrected == pytest.approx(exact, rel=0.1)


def test_nan_reference_pixels_are_left_out_and_bad_input_is_named():
    ref = np.ones((2, 2, 3))
    ref[0, 0] = np.nan
    img = np.ones((2, 2, 3))
    img[0, 0] = 123.0
    assert metrics.relmse(img, ref) == 0.0
    img[1, 1, 0] = np.nan
    with pytest.raises(ValueError, match="image"):
        metrics.relmse(img, ref)
    with pytest.raises(ValueError, match="image"):
        metrics.relmse(np.ones((2, 2, 3)), np.ones((2, 3, 3)))
    with pytest.raises(ValueError, match="image"):
        metrics.relmse(np.ones((2, 2)), np.ones((2, 2)))
    with pytest.raises(ValueError, match="reference_variance"):
        metrics.relmse(np.ones((2, 2, 3)), np.ones((2, 2, 3)), -np.ones((2, 2, 3)))


def test_efficiency_variance_ratio_and_suite_summary():
    assert metrics.efficiency(0.5, 4.0) == pytest.approx(0.5)
    assert math.isnan(metrics.efficiency(0.0, 1.0))
    a = np.ones((3, 3, 3)) * np.array([1.0, 2.0, 4.0])
    b = np.ones((3, 3, 3)) * 2.0
    ratios, mean = metrics.variance_ratio(a, b)
    assert ratios == pytest.approx([0.5, 1.0, 2.0]) and mean == pytest.approx(3.5 / 3)
    s = metrics.worst_and_mean({"a": 0.5, "b": 2.0, "c": 1.0})
    assert s["worst"] == "b" and s["worst_value"] == 2.0 and s["geomean"] == pytest.approx(1.0)
    assert metrics.worst_and_mean({"a": 3.0, "b": 1.0}, higher_is_worse=False)["worst"] == "b"
    with pytest.raises(ValueError, match="values"):
        metrics.worst_and_mean({"a": float("nan")})
    assert metrics.LUMINANCE.sum() == pytest.approx(1.0)


def test_luminance_its_variance_and_auto_exposure():
    from viscache_rs.io import auto_exposure

    rgb = np.zeros((2, 3, 3), dtype=np.float32)
    rgb[..., 1] = 1.0
    lum = metrics.luminance(rgb)
    assert lum.shape == (2, 3) and lum.dtype == np.float64
    assert lum == pytest.approx(np.full((2, 3), 0.7152))
    assert metrics.luminance(np.ones(3)) == pytest.approx(1.0)
    # Independent channels: w^2-weighted; grey variance 1 gives sum of w^2, less than 1.
    var = metrics.luminance_variance(np.ones((4, 3)))
    assert var == pytest.approx(np.full(4, float((metrics.LUMINANCE**2).sum())))
    assert metrics.luminance_variance(np.array([0.0, 0.0, 2.0])) == pytest.approx(
        2.0 * 0.0722**2)
    # Median luminance to 0.18; a mostly black image keeps exposure 1.
    assert auto_exposure(np.full((4, 4, 3), 0.5)) == pytest.approx(0.36)
    assert auto_exposure(np.full((4, 4, 3), 0.5), key=0.5) == pytest.approx(1.0)
    assert auto_exposure(np.zeros((4, 4, 3))) == 1.0


def test_mean_and_relative_variance():
    v = np.ones((2, 2, 3)) * np.array([1.0, 2.0, 3.0])
    # Every channel counts the same; float32 input is accumulated in float64.
    assert metrics.mean_variance(v) == pytest.approx(2.0)
    assert metrics.mean_variance(v.astype(np.float32)) == metrics.mean_variance(v)
    # Undefined pixels (NaN, inf) are left out; nothing defined gives NaN.
    w = v.copy()
    w[0, 0] = np.nan
    w[1, 1, 2] = np.inf
    assert metrics.mean_variance(w) == pytest.approx((1 + 2 + 3 + 1 + 2 + 3 + 1 + 2) / 8)
    assert math.isnan(metrics.mean_variance(np.full((1, 1, 3), np.nan)))
    # relative_variance: variance / (ref^2 + 1e-2), and the share relmse subtracts.
    ref = np.full((2, 2, 3), 3.0)
    assert metrics.relative_variance(v, ref) == pytest.approx(2.0 / 9.01)
    black = np.zeros((1, 1, 3))
    assert metrics.relative_variance(np.full((1, 1, 3), 1e-4), black) == pytest.approx(1e-2)
    img = ref + 0.3
    assert metrics.relmse(img, ref) - metrics.relmse(img, ref, v) == pytest.approx(
        metrics.relative_variance(v, ref))
    ref[0, 0] = np.nan  # no surface: left out
    assert metrics.relative_variance(np.ones((2, 2, 3)), ref) == pytest.approx(1 / 9.01)
    with pytest.raises(ValueError, match="variance"):
        metrics.relative_variance(np.ones((2, 2, 3)), np.ones((2, 3, 3)))


def test_scalar_errors_known_answers_nan_pixels_and_bad_input():
    ref = np.full((3, 4), 0.5, dtype=np.float32)
    img = ref.copy()
    img[0, 0] = 0.9  # one pixel off by 0.4
    ref[2, 3] = img[2, 3] = np.nan  # no surface in either: left out
    e = metrics.scalar_errors(img, ref)
    assert e["pixels"] == 11
    assert e["rmse"] == pytest.approx(0.4 / math.sqrt(11), rel=1e-6)
    assert e["relative_rmse"] == pytest.approx(e["rmse"] / 0.5, rel=1e-6)
    assert e["max_error"] == pytest.approx(0.4, rel=1e-6)
    assert e["bias"] == pytest.approx(0.4 / 11, rel=1e-6)
    assert e["mean_ao"] == pytest.approx(0.5)
    assert metrics.scalar_errors(ref, ref)["rmse"] == 0.0
    with pytest.raises(ValueError, match="image"):
        metrics.scalar_errors(img, ref[:2])
    with pytest.raises(ValueError, match="image"):
        metrics.scalar_errors(np.full((2, 2), np.nan), np.full((2, 2), np.nan))
