"""Material.eval / sample / pdf / product_cells: formulas, consistency, conservativeness of B~,
and bad input."""

import numpy as np
import pytest
import viscache_rs as vc
from viscache_rs.metrics import luminance

RNG = np.random.default_rng(7)
N0 = np.array([0.3, 0.8, -0.5]) / np.linalg.norm([0.3, 0.8, -0.5])


def square_to_sphere(p):
    """numpy copy of the crate's equal-area octahedral map (centre +y, corners -y)."""
    u, v = 2 * p[:, 0] - 1, 2 * p[:, 1] - 1
    up, vp = np.abs(u), np.abs(v)
    sd = 1 - (up + vp)
    r = 1 - np.abs(sd)
    with np.errstate(invalid="ignore", divide="ignore"):
        phi = np.where(r == 0, 1.0, (vp - up) / r + 1) * np.pi / 4
    h = np.copysign(1 - r * r, sd)
    rad = r * np.sqrt(np.maximum(2 - r * r, 0))
    return np.stack([np.copysign(np.cos(phi), u) * rad, h, np.copysign(np.sin(phi), v) * rad], 1)


def at_angle(n, theta, az=0.4):
    t = np.cross(n, [1.0, 0, 0])
    t /= np.linalg.norm(t)
    b = np.cross(n, t)
    return np.cos(theta) * n + np.sin(theta) * (np.cos(az) * t + np.sin(az) * b)


def rep(v, k):
    return np.repeat(np.asarray(v, dtype=np.float64)[None], k, 0)


MATS = [
    vc.Material.lambert((0.8, 0.5, 0.2)),
    vc.Material.phong((0.3, 0.2, 0.1), (0.5, 0.6, 0.7), 10.0),
    vc.Material.phong((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), 1e4),
]


def test_eval_matches_the_formulas():
    k = 2000
    n = rep(N0, k)
    wo = RNG.normal(size=(k, 3))
    wi = RNG.normal(size=(k, 3))
    wo /= np.linalg.norm(wo, axis=1)[:, None]
    wi /= np.linalg.norm(wi, axis=1)[:, None]
    up = ((n * wo).sum(1) > 0) & ((n * wi).sum(1) > 0)
    f = vc.Material.lambert((0.8, 0.5, 0.2)).eval(n, wo, wi)
    assert f.shape == (k, 3) and f.dtype == np.float32
    np.testing.assert_allclose(f[up], rep([0.8, 0.5, 0.2], up.sum()) / np.pi, rtol=1e-6)
    assert np.all(f[~up] == 0)
    m = vc.Material.phong((0.3, 0.2, 0.1), (0.5, 0.6, 0.7), 20.0)
    r = 2 * (n * wo).sum(1)[:, None] * n - wo
    ca = np.maximum((r * wi).sum(1), 0)
    ref = np.array([0.3, 0.2, 0.1]) / np.pi + np.outer(22 / (2 * np.pi) * ca**20, [0.5, 0.6, 0.7])
    np.testing.assert_allclose(m.eval(n, wo, wi)[up], ref[up], rtol=1e-4, atol=1e-6)


@pytest.mark.parametrize("m", MATS, ids=["lambert", "phong10", "phong1e4"])
@pytest.mark.parametrize("theta", [0.0, 1.0, 1.55])
def test_pdf_is_the_density_of_sample(m, theta):
    # Importance-sampled estimate of ∫ pdf over the accepted region is the acceptance rate,
    # and f cos / pdf averages to the albedo (≤ 1).
    k = 200_000
    n = rep(N0, k)
    wo = rep(at_angle(N0, theta), k)
    wi, valid = m.sample(n, wo, RNG.random((k, 3)))
    assert wi.shape == (k, 3) and valid.dtype == np.bool_
    assert np.all(wi[~valid] == 0)
    p = m.pdf(n[valid], wo[valid], wi[valid])
    assert p.dtype == np.float64 and np.all(p > 0)
    assert np.all((wi[valid] @ N0) > 0)
    # ∫ pdf over the sphere by uniform sampling equals the acceptance rate.
    d = RNG.normal(size=(k, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    x = m.pdf(n, wo, d) * 4 * np.pi
    se = x.std() / np.sqrt(k)
    if theta == 0.0 or m.kind == "lambert":
        assert (
            abs(x.mean() - valid.mean())
            < 4 * se + 4 * np.sqrt(valid.mean() * (1 - valid.mean()) / k) + 1e-3
        )
    f = m.eval(n[valid], wo[valid], wi[valid])
    est = np.zeros((k, 3))
    est[valid] = f * (wi[valid] @ N0)[:, None] / p[:, None]
    mean, se = est.mean(0), est.std(0) / np.sqrt(k)
    assert np.all(mean <= 1 + 4 * se + 1e-9)
    if m.kind == "lambert":
        np.testing.assert_allclose(mean, [0.8, 0.5, 0.2], atol=1e-5)


def cell_points(res, sub):
    """Directions of a sub x sub grid in every cell of a res x res grid: (res, res, sub², 3)."""
    g = (np.arange(res * sub) + 0.5) / (res * sub)
    uu, vv = np.meshgrid(g, g)  # [y, x]
    d = square_to_sphere(np.stack([uu.ravel(), vv.ravel()], 1))
    d = d.reshape(res, sub, res, sub, 3).transpose(0, 2, 1, 3, 4).reshape(res, res, sub * sub, 3)
    return d


@pytest.mark.parametrize("m", MATS, ids=["lambert", "phong10", "phong1e4"])
def test_product_cells_conservative_and_row_major(m):
    res, sub = 32, 8
    pts = cell_points(res, sub).reshape(-1, 3)
    for i in range(6):
        n = RNG.normal(size=3)
        n /= np.linalg.norm(n)
        wo = at_angle(n, [0.0, 0.7, 1.4, 1.5607, 1.5697, 1.2][i], az=i)
        b = m.product_cells(n, wo)
        assert b.shape == (res, res) and b.dtype == np.float32
        assert np.all(b >= 0) and np.all(np.isfinite(b))
        f = m.eval(rep(n, len(pts)), rep(wo, len(pts)), pts)
        g = luminance(f) * np.maximum(pts @ n, 0)
        g = g.reshape(res, res, sub * sub)
        positive = (g > 0).any(2)
        assert np.all(b[positive] > 0), np.argwhere(positive & (b == 0))
        # Row-major order: the cell means and B~ agree in mass and place.
        mean = g.mean(2)
        assert np.corrcoef(mean.ravel(), b.ravel())[0, 1] > 0.5
        below = (pts @ n <= 0).reshape(res, res, -1).all(2)
        assert b[below].sum() <= 2e-3 * b.sum()


def test_product_cells_levels():
    m = MATS[1]
    for level in (1, 2, 3, 5, 8):
        b = m.product_cells(N0, at_angle(N0, 0.5), level=level)
        assert b.shape == (2**level, 2**level)
        assert b.sum() > 0
    assert m.product_cells(N0, -N0).sum() == 0  # viewer below the surface


@pytest.mark.parametrize(
    "call, exc, name",
    [
        (
            lambda m: m.eval(np.ones((2, 2)), np.ones((2, 3)), np.ones((2, 3))),
            ValueError,
            "normals",
        ),
        (lambda m: m.eval(np.ones((2, 3)), np.ones((3, 3)), np.ones((2, 3))), ValueError, "wo"),
        (lambda m: m.eval(np.ones((2, 3)), np.ones((2, 3)), np.zeros((2, 3))), ValueError, "wi"),
        (
            lambda m: m.eval(np.ones((2, 3)), np.full((2, 3), np.nan), np.ones((2, 3))),
            ValueError,
            "wo",
        ),
        (
            lambda m: m.eval(np.ones((2, 3), bool), np.ones((2, 3)), np.ones((2, 3))),
            TypeError,
            "normals",
        ),
        (lambda m: m.pdf(np.ones((2, 3)), np.ones((2, 3)), "x"), TypeError, "wi"),
        (
            lambda m: m.sample(np.ones((2, 3)), np.ones((2, 3)), np.full((2, 3), 1.5)),
            ValueError,
            "u",
        ),
        (
            lambda m: m.sample(np.ones((2, 3)), np.ones((2, 3)), np.full((2, 3), np.nan)),
            ValueError,
            "u",
        ),
        (lambda m: m.sample(np.ones((2, 3)), np.ones((2, 3)), np.ones((1, 3))), ValueError, "u"),
        (lambda m: m.product_cells((0, 0, 0), (0, 1, 0)), ValueError, "normal"),
        (lambda m: m.product_cells((0, 1, 0), (0, np.nan, 0)), ValueError, "wo"),
        (lambda m: m.product_cells((0, 1, 0), (0, 1)), ValueError, "wo"),
        (lambda m: m.product_cells((0, 1, 0), (0, 1, 0), level=0), ValueError, "level"),
        (lambda m: m.product_cells((0, 1, 0), (0, 1, 0), level=9), ValueError, "level"),
        (lambda m: m.product_cells((0, 1, 0), (0, 1, 0), level=2.5), TypeError, "level"),
        (lambda m: m.product_cells((0, 1, 0), (0, 1, 0), level=True), TypeError, "level"),
    ],
)
def test_bad_input_names_the_argument(call, exc, name):
    for m in MATS[:2]:
        with pytest.raises(exc, match=f"^{name}"):
            call(m)


def test_empty_batches():
    m = MATS[1]
    e = np.zeros((0, 3))
    assert m.eval(e, e, e).shape == (0, 3)
    assert m.pdf(e, e, e).shape == (0,)
    wi, ok = m.sample(e, e, e)
    assert wi.shape == (0, 3) and ok.shape == (0,)
