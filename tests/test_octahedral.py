"""The equal-area octahedral map from Python: round trips, orientation, texels, bad input."""

import numpy as np
import pytest
import viscache_rs as vc


def _uniform_dirs(n, seed):
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def test_round_trip_including_poles_seams_and_signed_zeros():
    special = np.array(
        [[0, 1, 0], [0, -1, 0], [1, 0, 0], [-1, 0, 0], [0, 0, 1], [0, 0, -1],
         [-0.0, 1, -0.0], [-0.0, -1, 0.0], [1, 0, -0.0], [1, 1, 0], [1, -1, 0], [0, 1, 1],
         [1, 0, 1], [-1, 0, -1], [1, 1e-7, 1]],
        dtype=np.float64,
    )
    dirs = np.concatenate([_uniform_dirs(200_000, 0), special])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    uv = vc.octahedral.sphere_to_square(dirs)
    assert uv.shape == (len(dirs), 2) and uv.dtype == np.float32
    assert uv.min() >= 0.0 and uv.max() <= 1.0
    back = vc.octahedral.square_to_sphere(uv)
    assert np.abs(back - dirs).max() <= 1e-5


def test_orientation_and_texel_grid():
    dirs = vc.octahedral.square_to_sphere([[0.5, 0.5], [0, 0], [1, 1], [1, 0.5], [0.5, 1]])
    np.testing.assert_allclose(dirs[0], [0, 1, 0], atol=1e-6)
    np.testing.assert_allclose(dirs[1:3], [[0, -1, 0], [0, -1, 0]], atol=1e-6)
    assert dirs[3, 0] > 0.99 and dirs[4, 2] > 0.99
    t = vc.octahedral.texel_of([[0, 1, 0], [0, -1, 0]], 64)
    assert t.tolist()[0] in ([31, 31], [32, 32], [31, 32], [32, 31])
    assert t.dtype == np.int64 and t.min() >= 0 and t.max() <= 63


def test_texels_have_equal_solid_angle_by_monte_carlo():
    # Binomial counts of uniform directions per texel: chi-square against the uniform pdf.
    res, n = 16, 1_000_000
    t = vc.octahedral.texel_of(_uniform_dirs(n, 1), res)
    counts = np.bincount(t[:, 1] * res + t[:, 0], minlength=res * res)
    expected = n / res**2
    chi2 = ((counts - expected) ** 2 / expected).sum()
    # 255 degrees of freedom: mean 255, sd 22.6; 400 is 6.4 sd.
    assert chi2 < 400, chi2
    assert vc.octahedral.texel_solid_angle(64) == pytest.approx(4 * np.pi / 4096)


@pytest.mark.parametrize(
    ("call", "exc", "needle"),
    [
        (lambda: vc.octahedral.sphere_to_square([[0, 0, 0]]), ValueError, "dirs: row 0"),
        (lambda: vc.octahedral.sphere_to_square([[np.nan, 1, 0]]), ValueError, "dirs"),
        (lambda: vc.octahedral.sphere_to_square(np.ones((3, 2))), ValueError, "dirs"),
        (lambda: vc.octahedral.sphere_to_square([["a", "b", "c"]]), TypeError, "dirs"),
        (lambda: vc.octahedral.square_to_sphere([[1.5, 0.5]]), ValueError, "uv: row 0"),
        (lambda: vc.octahedral.square_to_sphere([[0.5, np.inf]]), ValueError, "uv"),
        (lambda: vc.octahedral.texel_of([[0, 1, 0]], 0), ValueError, "res"),
        (lambda: vc.octahedral.texel_of([[0, 1, 0]], 2.5), TypeError, "res"),
    ],
)
def test_bad_input_names_the_argument(call, exc, needle):
    with pytest.raises(exc, match=needle):
        call()


def test_empty_input_gives_empty_output():
    assert vc.octahedral.sphere_to_square(np.zeros((0, 3))).shape == (0, 2)
    assert vc.octahedral.square_to_sphere(np.zeros((0, 2))).shape == (0, 3)
