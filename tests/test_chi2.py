"""The chi-square helper from Python, on the library's own samplers and on wrong ones."""

import numpy as np
import pytest
import viscache_rs as vc


def _u(n, seed, dims=2):
    return np.random.default_rng(seed).random((n, dims))


def test_envmap_sampler_passes_and_a_wrong_pdf_fails():
    env = vc.envmaps.sky(sun_dir=(0.3, 0.8, 0.2), sun_radiance=500.0, sun_angle=5.0, resolution=32)
    dirs, _ = env.sample(_u(200_000, 1))
    ok = vc.testing.chi2_sphere(dirs, env.pdf, resolution=32, subdivisions=1)
    assert ok["passed"] and abs(ok["integral"] - 1) < 1e-6, ok
    uniform = vc.testing.chi2_sphere(dirs, lambda d: np.full(len(d), 1 / (4 * np.pi)))
    assert not uniform["passed"] and uniform["p_value"] < 1e-12


def test_bsdf_sampler_with_rejections():
    m = vc.Material.phong((0.3, 0.3, 0.3), (0.6, 0.6, 0.6), 20.0)
    n = 100_000
    normal = np.tile([0.0, 0.6, 0.8], (n, 1))
    wo = np.tile(np.array([0.5, 0.1, 0.86]) / np.linalg.norm([0.5, 0.1, 0.86]), (n, 1))
    wi, valid = m.sample(normal, wo, _u(n, 2, 3))
    assert not valid.all(), "a tilted lobe loses samples below the surface"
    dirs = np.where(valid[:, None], wi, np.nan)

    def pdf(d):
        k = len(d)
        return m.pdf(np.tile(normal[0], (k, 1)), np.tile(wo[0], (k, 1)), d)

    out = vc.testing.chi2_sphere(dirs, pdf, resolution=32, subdivisions=6)
    assert out["passed"] and out["rejected"] == int((~valid).sum()), out


@pytest.mark.parametrize(
    ("kwargs", "exc", "needle"),
    [
        ({"dirs": np.zeros((3, 3))}, ValueError, "dirs: row 0"),
        ({"dirs": [[1, np.nan, 0]]}, ValueError, "dirs: row 0"),
        ({"dirs": np.ones((2, 2))}, ValueError, "dirs"),
        ({"pdf": 3}, TypeError, "pdf"),
        ({"pdf": lambda d: -np.ones(len(d))}, ValueError, "pdf"),
        ({"pdf": lambda d: np.ones(3)}, ValueError, "pdf"),
        ({"resolution": 0}, ValueError, "resolution"),
        ({"subdivisions": 100}, ValueError, "subdivisions"),
        ({"significance": 1.5}, ValueError, "significance"),
        ({"min_expected": 0.0}, ValueError, "min_expected"),
    ],
)
def test_bad_arguments(kwargs, exc, needle):
    args = {"dirs": [[0, 1, 0]], "pdf": lambda d: np.full(len(d), 1 / (4 * np.pi)), **kwargs}
    with pytest.raises(exc, match=needle):
        vc.testing.chi2_sphere(**args)
