"""Visibility correlation (CAM08 sec. 4.1) from Python: maps against ray-by-ray
`scene.occluded`, rho and the bins against numpy, pair sampling against a brute-force
nearest-neighbour search, the Fig. 4 local mean against numpy, bad input, and a tiny run of
the `correlation` experiment."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
import viscache_rs as vc
from viscache_rs import analysis
from viscache_rs.experiments import ExperimentContext


@pytest.fixture(scope="module")
def dynamics():
    return vc.scenes.load("dynamics")


@pytest.fixture(scope="module")
def small(dynamics):
    """Maps (16 x 16) at the first hits of a 20 x 15 G-buffer: ~300 points."""
    cam = dynamics.camera.with_resolution(20, 15)
    g = dynamics.scene.gbuffer(cam, seed=1)
    hit = np.isfinite(g["depth"]).ravel()
    p = g["position"].reshape(-1, 3)[hit]
    n = g["normal"].reshape(-1, 3)[hit]
    return p, n, analysis.visibility_maps(dynamics.scene, p, n, resolution=16, threads=2)


def numpy_pearson(bits: np.ndarray) -> np.ndarray:
    """All-pairs Pearson of (N, R, R) bool maps directly from the definition (NaN where a
    map is constant)."""
    x = bits.reshape(len(bits), -1).astype(np.float64)
    x = x - x.mean(axis=1, keepdims=True)
    norm = np.sqrt((x * x).sum(axis=1))
    with np.errstate(invalid="ignore", divide="ignore"):
        return (x @ x.T) / np.outer(norm, norm)


def geometry(p, n, i, j):
    d = np.linalg.norm(p[i].astype(np.float64) - p[j].astype(np.float64), axis=-1)
    nn = n.astype(np.float64)
    nn /= np.linalg.norm(nn, axis=1, keepdims=True)
    c = np.clip((nn[i] * nn[j]).sum(-1), -1, 1)
    return d, np.degrees(np.arccos(c))


@pytest.mark.parametrize("resolution", [2, 16])
def test_maps_equal_ray_by_ray_occlusion(dynamics, resolution):
    scene = dynamics.scene
    pts = np.array([[0.0, 0.0, 0.0], [1.5, 0.0, -2.0], [-3.0, 0.0, 1.0]], np.float32)
    nrm = np.array([[0, 1, 0], [0.1, 1, 0.2], [0, 1, 0]], np.float32)
    maps = analysis.visibility_maps(scene, pts, nrm, resolution=resolution)
    dirs = vc.VisibilityCache(scene, resolution=resolution).directions()
    bits = maps.bits()
    assert bits.shape == (3, resolution, resolution) and bits.dtype == bool
    for k in range(3):
        n = nrm[k] / np.linalg.norm(nrm[k])
        origin = scene.offset_points(pts[k][None], n[None])[0]
        want = np.zeros(resolution * resolution, bool)
        for z, d in enumerate(dirs):
            if float(np.dot(n, d)) > 0.0:
                want[z] = not scene.occluded(origin[None], d[None])[0]
        np.testing.assert_array_equal(bits[k].ravel(), want)
    np.testing.assert_array_equal(maps.bits([2, 0]), bits[[2, 0]])
    np.testing.assert_allclose(maps.visible_fraction(), bits.mean(axis=(1, 2)))
    np.testing.assert_allclose(maps.points, pts)
    np.testing.assert_allclose(np.linalg.norm(maps.normals, axis=1), 1.0, rtol=1e-6)


def test_pair_correlations_equal_numpy(small):
    p, n, maps = small
    rho = numpy_pearson(maps.bits())
    rng = np.random.default_rng(0)
    pairs = rng.integers(0, len(p), size=(500, 2))
    got = analysis.pair_correlations(maps, pairs)
    want = rho[pairs[:, 0], pairs[:, 1]]
    # The popcount form is exact up to one rounding; numpy sums R^2 = 256 products.
    np.testing.assert_allclose(got["rho"], want, rtol=0, atol=1e-12)
    assert np.isnan(got["rho"]).sum() == np.isnan(want).sum()
    d, t = geometry(p, n, pairs[:, 0], pairs[:, 1])
    np.testing.assert_allclose(got["distance"], d, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(got["theta_deg"], t, atol=1e-3)
    # Identical maps correlate fully.
    ok = ~np.isnan(np.diag(rho))
    same = np.flatnonzero(ok)[:5]
    np.testing.assert_allclose(
        analysis.pair_correlations(maps, np.stack([same, same], 1))["rho"], 1.0
    )


def numpy_bins(rho, d, t, de, te):
    """count, mean, std, undefined per (d, theta) bin, numpy.histogram's edges."""
    di = np.searchsorted(de, d, side="right") - 1
    di[d == de[-1]] = len(de) - 2
    ti = np.searchsorted(te, t, side="right") - 1
    ti[t == te[-1]] = len(te) - 2
    inside = (d >= de[0]) & (d <= de[-1]) & (t >= te[0]) & (t <= te[-1])
    shape = (len(de) - 1, len(te) - 1)
    count = np.zeros(shape, np.int64)
    undefined = np.zeros(shape, np.int64)
    mean = np.full(shape, np.nan)
    std = np.full(shape, np.nan)
    for a in range(shape[0]):
        for b in range(shape[1]):
            sel = inside & (di == a) & (ti == b)
            r = rho[sel]
            undefined[a, b] = np.isnan(r).sum()
            r = r[~np.isnan(r)]
            count[a, b] = len(r)
            if len(r):
                mean[a, b], std[a, b] = r.mean(), r.std()
    return count, mean, std, undefined, int((~inside).sum())


def test_bins_equal_numpy_for_all_pairs_and_sampled_pairs(small):
    p, n, maps = small
    rho = numpy_pearson(maps.bits())
    de = np.array([0.0, 0.5, 1.0, 2.0, 4.0, 8.0])
    te = np.array([0.0, 2.0, 10.0, 45.0, 91.0])
    i, j = np.triu_indices(len(p), 1)
    d, t = geometry(p, n, i, j)
    got = analysis.correlation_bins(maps, de, te, threads=2)
    count, mean, std, undefined, outside = numpy_bins(rho[i, j], d, t, de, te)
    assert got["pairs"] == len(i) and got["outside"] == outside
    np.testing.assert_array_equal(got["count"], count)
    np.testing.assert_array_equal(got["undefined"], undefined)
    # Means of <= 45k values in [-1, 1]: a few hundred ulps at most either way.
    np.testing.assert_allclose(got["mean"], mean, rtol=0, atol=1e-11)
    np.testing.assert_allclose(got["std"], std, rtol=0, atol=1e-9)
    assert (count > 0).sum() >= 8
    np.testing.assert_array_equal(got["distance_edges"], de)

    pairs = analysis.sample_pairs(maps, neighbours=6, far=6, seed=3)
    got = analysis.correlation_bins(maps, de, te, pairs=pairs, threads=1)
    i, j = pairs[:, 0].astype(int), pairs[:, 1].astype(int)
    d, t = geometry(p, n, i, j)
    count, mean, std, undefined, outside = numpy_bins(rho[i, j], d, t, de, te)
    np.testing.assert_array_equal(got["count"], count)
    np.testing.assert_allclose(got["mean"], mean, rtol=0, atol=1e-11)
    np.testing.assert_allclose(got["std"], std, rtol=0, atol=1e-9)
    two = analysis.correlation_bins(maps, de, te, pairs=pairs, threads=2)
    for k in ("count", "mean", "std", "undefined"):
        np.testing.assert_array_equal(two[k], got[k])


def test_sample_pairs_are_nearest_neighbours_then_far_partners(small):
    p, _, maps = small
    pairs = analysis.sample_pairs(maps, neighbours=4, far=3, far_range=(0.1, 20.0), seed=1)
    assert pairs.dtype == np.uint32 and pairs.shape[1] == 2
    assert np.all(pairs[:, 0] != pairs[:, 1])
    np.testing.assert_array_equal(pairs, analysis.sample_pairs(
        maps, neighbours=4, far=3, far_range=(0.1, 20.0), seed=1, threads=2))
    assert not np.array_equal(pairs, analysis.sample_pairs(
        maps, neighbours=4, far=3, far_range=(0.1, 20.0), seed=2))
    d2 = ((p[:, None].astype(np.float64) - p[None]) ** 2).sum(-1)
    np.fill_diagonal(d2, np.inf)
    starts = np.searchsorted(pairs[:, 0], np.arange(len(p)))
    for i in range(0, len(p), 17):
        mine = pairs[starts[i]:starts[i] + 4]
        assert np.all(mine[:, 0] == i)
        np.testing.assert_allclose(d2[i, mine[:, 1]], np.sort(d2[i])[:4], rtol=1e-5)


def test_local_correlation_equals_numpy(small):
    p, n, maps = small
    rho = numpy_pearson(maps.bits())
    out = analysis.local_correlation(maps, 1.0, 20.0, threads=2)
    i, j = np.meshgrid(np.arange(len(p)), np.arange(len(p)), indexing="ij")
    d, t = geometry(p, n, i.ravel(), j.ravel())
    near = ((d <= 1.0) & (t < 20.0)).reshape(len(p), len(p))
    np.fill_diagonal(near, False)
    r = np.where(near, rho, np.nan)
    count = (~np.isnan(r)).sum(1)
    np.testing.assert_array_equal(out["count"], count)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # rows without partners: NaN
        want = np.nanmean(r, axis=1)
    np.testing.assert_allclose(out["mean"], want, rtol=0, atol=1e-12)
    assert (count > 0).sum() > len(p) // 2


def test_bad_input_names_the_argument(dynamics, small):
    scene = dynamics.scene
    p, n, maps = small
    with pytest.raises(ValueError, match="points"):
        analysis.visibility_maps(scene, np.zeros((0, 3)), np.zeros((0, 3)))
    with pytest.raises(ValueError, match="points"):
        analysis.visibility_maps(scene, np.zeros((2, 2)), np.ones((2, 3)))
    with pytest.raises(ValueError, match="points"):
        analysis.visibility_maps(scene, [[0, np.nan, 0]], [[0, 1, 0]])
    with pytest.raises(TypeError, match="points"):
        analysis.visibility_maps(scene, [["a", "b", "c"]], [[0, 1, 0]])
    with pytest.raises(ValueError, match="normals"):
        analysis.visibility_maps(scene, [[0, 0, 0]], [[0, 0, 0]])
    with pytest.raises(ValueError, match="normals"):
        analysis.visibility_maps(scene, [[0, 0, 0], [1, 0, 0]], [[0, 1, 0]])
    with pytest.raises(ValueError, match="resolution"):
        analysis.visibility_maps(scene, [[0, 0, 0]], [[0, 1, 0]], resolution=24)
    with pytest.raises(ValueError, match="threads"):
        analysis.visibility_maps(scene, [[0, 0, 0]], [[0, 1, 0]], threads=0)
    with pytest.raises(ValueError, match="distance_edges"):
        analysis.correlation_bins(maps, [1.0, 0.5], [0, 90])
    with pytest.raises(ValueError, match="distance_edges"):
        analysis.correlation_bins(maps, [0.0], [0, 90])
    with pytest.raises(ValueError, match="distance_edges"):
        analysis.correlation_bins(maps, [0.0, np.nan], [0, 90])
    with pytest.raises(ValueError, match="theta_edges"):
        analysis.correlation_bins(maps, [0, 1], [0, 200])
    with pytest.raises(ValueError, match="theta_edges"):
        analysis.correlation_bins(maps, [0, 1], [[0, 90]])
    with pytest.raises(ValueError, match="pairs"):
        analysis.correlation_bins(maps, [0, 1], [0, 90], pairs=[[0, len(p)]])
    with pytest.raises(ValueError, match="pairs"):
        analysis.correlation_bins(maps, [0, 1], [0, 90], pairs=[[0, -1]])
    with pytest.raises(ValueError, match="pairs"):
        analysis.pair_correlations(maps, [0, 1])
    with pytest.raises(TypeError, match="pairs"):
        analysis.pair_correlations(maps, [[0.5, 1.0]])
    with pytest.raises(ValueError, match="points"):
        analysis.sample_pairs(analysis.visibility_maps(scene, p[:1], n[:1], resolution=2))
    with pytest.raises(ValueError, match="far_min"):
        analysis.sample_pairs(maps, far_range=(0.0, 1.0))
    with pytest.raises(ValueError, match="far_max"):
        analysis.sample_pairs(maps, far_range=(1.0, 0.5))
    with pytest.raises(ValueError, match="far_range"):
        analysis.sample_pairs(maps, far_range=(1.0, 2.0, 3.0))
    with pytest.raises(ValueError, match="neighbours"):
        analysis.sample_pairs(maps, neighbours=-1)
    with pytest.raises(TypeError, match="far"):
        analysis.sample_pairs(maps, far=1.5)
    with pytest.raises(ValueError, match="d_max"):
        analysis.local_correlation(maps, -1.0, 10.0)
    with pytest.raises(ValueError, match="theta_max_deg"):
        analysis.local_correlation(maps, 1.0, 0.0)
    with pytest.raises(TypeError, match="d_max"):
        analysis.local_correlation(maps, "x", 10.0)
    with pytest.raises(ValueError, match="indices"):
        maps.bits([len(p)])


def test_correlation_experiment_tiny_run(tmp_path):
    from viscache_rs.experiments import correlation

    ctx = ExperimentContext(name="correlation", out=tmp_path / "correlation", quick=True,
                            threads=2, progress=False)
    s = correlation.Settings(width=32, height=24, resolution=8, neighbours=6, far=6,
                             d_bins=8, theta_step=30.0)
    correlation.run(ctx, scenes=("dynamics",), settings=s)
    ctx.finish()
    out = tmp_path / "correlation"
    data = json.loads((out / "results.json").read_text())
    r = data["dynamics"]
    assert r["points"] > 500 and r["pairs"] >= r["points"] * 6
    count = np.array(r["heatmap"]["count"])
    assert count.shape == (8, 6) and count.sum() > 0
    c = r["summary"]["small_d_theta_lt_2"]
    # Nearby, equally oriented points on open ground see nearly the same sky.
    assert c["count"] > 0 and c["mean"] > 0.5
    assert (out / "dynamics_correlation.png").read_bytes().startswith(b"\x89PNG")
    assert (out / "dynamics_local.png").stat().st_size > 0
    assert (out / r["local"]["exr"]).read_bytes().startswith(b"\x76\x2f\x31\x01")  # EXR
    assert "image" not in r["local"]
    assert "Visibility correlation per scene" in (out / "results.md").read_text()
