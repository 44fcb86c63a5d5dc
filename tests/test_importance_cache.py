"""The importance cache (survey ch. 6, issue 65 §2-§3) from Python: method
"importance_cache" unbiased against the exact sum ``method="vpl"`` (every pixel and the
image, alpha-max and balance, records of this view and of another), the rows' order F <= U
<= B at each record, lookups, files, the same bits on any thread count, bad input with the
cache unchanged."""

from __future__ import annotations

import numpy as np
import pytest
import viscache_rs as vc

SIZE = (12, 9)
SPP = 600


@pytest.fixture(scope="module")
def cornell():
    return vc.scenes.load("cornell", detail=0.25)


@pytest.fixture(scope="module")
def small(cornell):
    return cornell.camera.with_resolution(*SIZE)


@pytest.fixture(scope="module")
def lights(cornell):
    return vc.VPLs.trace(cornell, count=200, seed=4, importance=False, threads=2)


@pytest.fixture(scope="module")
def built(cornell, lights, small):
    cache = vc.ImportanceCache(cornell.scene, lights, spacing=4)
    report = cache.build(small, threads=2, progress=False)
    return cache, report


@pytest.fixture(scope="module")
def exact(cornell, lights, small):
    return vc.render(cornell, camera=small, method="vpl", vpls=lights, spp=SPP, threads=2)


def within_4_se(res, ref, label):
    """Every pixel and the image sum within 4 SE of ``ref`` at the same first hits (the
    difference is the draws' noise, whose variance the estimate's own bounds). Lights only
    row C owns at a pixel are drawn rarely (heavy tails): at 32 samples some pixels had
    drawn none of them yet (zero sample variance), hence ``SPP`` = 600."""
    d = res.image.astype(np.float64) - ref.image
    se = np.sqrt(res.variance.astype(np.float64))
    bad = np.abs(d) > 4 * se + 1e-6 * np.abs(ref.image)
    assert not bad.any(), f"{label}: {bad.sum()} values off, worst {np.abs(d / se).max()} SE"
    assert abs(d.sum()) <= 4 * np.sqrt(res.variance.astype(np.float64).sum()), label


def test_build_report_and_records(built, lights):
    cache, report = built
    assert report["complete"] and report["records"] == len(cache) > 0
    assert report["grid"] > 0 and report["pairs"] >= report["records"] * len(lights)
    rec = cache.records()
    n = len(lights)
    assert rec["F"].shape == rec["U"].shape == rec["B"].shape == (len(cache), n)
    tol = 1e-5 * rec["U"].sum(axis=1, keepdims=True)
    assert (rec["F"] <= rec["U"] + tol).all()
    assert (rec["B"] >= rec["U"] - 1e-5 * rec["B"].sum(axis=1, keepdims=True)).all()
    assert (rec["radius"] > 0).all()
    # Rows take at most 12 bytes per light and record (less where sparse), plus the index.
    assert 0 < cache.memory_bytes() <= 12 * n * len(cache) + 4096 * len(cache)


@pytest.mark.parametrize("combine", ["alpha_max", "balance"])
def test_unbiased_against_the_exact_sum(cornell, lights, small, built, exact, combine):
    res = vc.render(cornell, camera=small, method="importance_cache", vpls=lights, spp=SPP,
                    vpl_samples=4, combine=combine, spacing=4, threads=2)
    within_4_se(res, exact, combine)
    assert res.stats["records"] > 0 and res.stats["build_seconds"] > 0
    assert res.stats["seconds"] >= res.stats["build_seconds"]
    # Records built for another view cost variance, never bias.
    other = vc.Camera.look_at([0.2, 0.6, 0.9], [0.5, 0.3, 0.0], fov_deg=70, width=10, height=8)
    foreign = vc.ImportanceCache(cornell.scene, lights, spacing=3)
    foreign.build(other, threads=2, progress=False)
    res = vc.render(cornell, camera=small, method="importance_cache", cache=foreign,
                    spp=SPP, vpl_samples=4, combine=combine, threads=2)
    within_4_se(res, exact, combine + " (another view)")


def test_the_same_bits_on_any_thread_count(cornell, lights, small, built):
    cache, _ = built
    a, b = (vc.render(cornell, camera=small, method="importance_cache", cache=cache, spp=2,
                      vpl_samples=4, threads=t) for t in (1, 2))
    assert np.array_equal(a.image, b.image)
    c1 = vc.ImportanceCache(cornell.scene, lights, spacing=4)
    c1.build(small, threads=1, progress=False)
    r1, r2 = c1.records(), cache.records()
    assert all(np.array_equal(r1[k], r2[k]) for k in r1)


def test_lookup_and_files(cornell, lights, built, tmp_path):
    cache, _ = built
    rec = cache.records()
    found = cache.lookup(rec["position"], rec["normal"])
    assert found["ids"].shape == (len(cache), cache.params["nearest"])
    # A record's own point finds it.
    assert all(i in row for i, row in enumerate(found["ids"]))
    far = cache.lookup([[1e5, 1e5, 1e5]], [[0, 1, 0]])
    assert far["records"][0] == 0
    path = tmp_path / "imp.bin"
    cache.save(path)
    back = vc.ImportanceCache.load(path, cornell.scene, lights)
    assert len(back) == len(cache)
    assert all(np.array_equal(back.records()[k], rec[k]) for k in rec)
    fewer = vc.VPLs.trace(cornell, count=50, seed=5, importance=False, threads=2)
    with pytest.raises(ValueError, match="lights"):
        vc.ImportanceCache.load(path, cornell.scene, fewer)
    path.write_bytes(path.read_bytes()[:-3])
    with pytest.raises(ValueError, match="path"):
        vc.ImportanceCache.load(path, cornell.scene, lights)


def test_bad_input_names_the_argument(cornell, lights, small, built):
    cache, _ = built
    n = len(cache)
    for kwargs, name in [({"alpha": (0.5, 0.5, 0.5, 0.0)}, "alpha"),
                         ({"alpha": (0.5, 1.5, 0.5, 1.0)}, "alpha"),
                         ({"alpha": (0.5, 0.5, 1.0)}, "alpha"),
                         ({"nearest": 0}, "nearest"), ({"spacing": 0}, "spacing"),
                         ({"lam": -1.0}, "lam")]:
        with pytest.raises((ValueError, TypeError), match=name):
            vc.ImportanceCache(cornell.scene, lights, **kwargs)
        with pytest.raises((ValueError, TypeError), match=name):
            vc.render(cornell, camera=small, method="importance_cache", vpls=lights, **kwargs)
    with pytest.raises(ValueError, match="vpl_samples"):
        vc.render(cornell, camera=small, method="importance_cache", cache=cache, vpl_samples=0)
    with pytest.raises(ValueError, match="combine"):
        vc.render(cornell, camera=small, method="importance_cache", cache=cache,
                  combine="max")
    other = vc.scenes.load("garage", detail=0.25)
    with pytest.raises(ValueError, match="lights"):
        vc.ImportanceCache(other.scene, lights)
    with pytest.raises(ValueError, match="cache"):
        vc.render(other, camera=other.camera.with_resolution(8, 6),
                  method="importance_cache", cache=cache)
    with pytest.raises(ValueError, match="spacing"):
        vc.render(cornell, camera=small, method="mis", spacing=4)
    assert len(cache) == n


def test_indirect_only_matches_the_exact_indirect_sum(cornell, lights, small, built):
    """Without direct light the light VPLs add nothing, whether the cache holds them (a
    given cache: drawn, they cost no ray) or not (the cache built here leaves them out)."""
    cache, _ = built
    ref = vc.render(cornell, camera=small, method="vpl", vpls=lights, spp=SPP, threads=2,
                    direct=False)
    for kwargs in ({"cache": cache}, {"vpls": lights, "spacing": 4}):
        res = vc.render(cornell, camera=small, method="importance_cache", spp=SPP,
                        vpl_samples=4, threads=2, direct=False, **kwargs)
        within_4_se(res, ref, f"direct=False {sorted(kwargs)}")


def test_whole_area_lights_are_sampled_unbiased(cornell, lights, small):
    """A whole area light (``VPLs.from_area_lights``) drawn from the rows is shaded from a
    fresh point on it, as ``method="vpl"`` shades it: both estimate the same image, so each
    pixel and the image agree within 4 SE of the two estimates together."""
    mixed = vc.VPLs.from_area_lights(cornell.scene, points=4) + lights
    assert (mixed.kinds == 3).sum() == len(cornell.scene.area_lights()) >= 1
    spp = 200
    ref = vc.render(cornell, camera=small, method="vpl", vpls=mixed, spp=spp, threads=2)
    res = vc.render(cornell, camera=small, method="importance_cache", vpls=mixed, spp=spp,
                    vpl_samples=4, spacing=4, threads=2)
    d = res.image.astype(np.float64) - ref.image
    var = res.variance.astype(np.float64) + ref.variance.astype(np.float64)
    assert np.isfinite(var).all() and (var > 0).any()
    bad = np.abs(d) > 4 * np.sqrt(var) + 1e-6 * np.abs(ref.image)
    assert not bad.any(), f"{bad.sum()} values off, worst {np.abs(d / np.sqrt(var)).max()} SE"
    assert abs(d.sum()) <= 4 * np.sqrt(var.sum())
    # The area light is drawn: rows F and U give it mass at the records.
    cache = vc.ImportanceCache(cornell.scene, mixed, spacing=4)
    cache.build(small, threads=2, progress=False)
    u = cache.records()["U"]
    area = np.flatnonzero(mixed.kinds == 3)
    assert (u[:, area] > 0).any()


def floor_wall_setup(scale):
    """Floor y = 0 and a wall x = 1 (1.5 high), seen from above at an angle; black sky."""
    scene = vc.Scene()
    for q in ([(-10, 0, -10), (10, 0, -10), (10, 0, 10), (-10, 0, 10)],
              [(1, 0, -10), (1, 0, 10), (1, 1.5, 10), (1, 1.5, -10)]):
        scene.add_mesh(np.asarray(q, np.float32) * scale, np.array([[0, 1, 2], [0, 2, 3]]))
    cam = vc.Camera.look_at(np.multiply((-2.0, 2.0, 0.0), scale),
                            np.multiply((0.5, 0.0, 0.0), scale), fov_deg=50, width=8,
                            height=6)
    return vc.Setup(scene, cam, vc.EnvMap.constant([0.0, 0.0, 0.0], 8))


def point_lights(scale, count, seed):
    """``count`` cosine point lights over the floor facing down (some below the floor:
    behind every record), grazing ones 1e-3 above the floor facing along it, out of view
    (all at least 0.5 from the wall and the seen floor: lights next to a receiver make the
    draws heavy-tailed, which a 4-SE test misreads as bias), flux scaled by ``scale**2``
    so the image does not change with the scale."""
    rng = np.random.default_rng(seed)
    pos = np.column_stack([rng.uniform(-3, 0.5, count), rng.uniform(0.2, 2.5, count),
                           rng.uniform(-3, 3, count)])
    nrm = np.tile([0.0, -1.0, 0.0], (count, 1))
    below = rng.random(count) < 0.1
    pos[below, 1] = -0.5
    grazing = rng.random(count) < 0.1
    pos[grazing, 0] = rng.uniform(-6, -4, grazing.sum())
    pos[grazing, 1] = 1e-3
    nrm[grazing] = [1.0, -1e-3, 0.0]
    flux = rng.uniform(0.5, 1.5, (count, 3)) * (scale**2 / count * 50)
    return pos * scale, nrm, flux


def test_extremes_many_grazing_hidden_and_scaled_lights():
    """Issue 65 §3's extremes on a floor and wall: 1e5 lights (rows of at most 12 bytes each per
    record), lights grazing the receivers and lights behind every record (U and B zero:
    C samples them and they add nothing), unbiased against the exact sum over the image;
    the same scene at 1e-4 and 1e4 times the size gives the same relMSE."""
    base = floor_wall_setup(1.0)
    pos, nrm, flux = point_lights(1.0, 100_000, 3)
    many = vc.VPLs.from_lights(base.scene, pos, nrm, flux)
    exact = vc.render(base, method="vpl", vpls=many, spp=1, jitter=False, threads=2)
    cache = vc.ImportanceCache(base.scene, many, spacing=4)
    cache.build(base.camera, threads=2, progress=False)
    assert cache.memory_bytes() <= 12.1 * len(many) * len(cache)
    res = vc.render(base, method="importance_cache", cache=cache, spp=64, vpl_samples=4,
                    jitter=False, threads=2)
    assert np.isfinite(res.image).all() and np.isfinite(res.variance).all()
    d = res.image.astype(np.float64) - exact.image
    assert abs(d.sum()) <= 4 * np.sqrt(res.variance.astype(np.float64).sum())

    relmse = {}
    for scale in (1e-4, 1.0, 1e4):
        s = floor_wall_setup(scale)
        lights = vc.VPLs.from_lights(s.scene, *point_lights(scale, 300, 4))
        ref = vc.render(s, method="vpl", vpls=lights, spp=1, jitter=False, threads=2)
        img = vc.render(s, method="importance_cache", vpls=lights, spp=16, vpl_samples=4,
                        spacing=4, jitter=False, threads=2).image
        assert np.isfinite(img).all()
        relmse[scale] = vc.metrics.relmse(img, ref.image)
    assert relmse[1.0] > 0
    for scale in (1e-4, 1e4):
        assert 0.8 < relmse[scale] / relmse[1.0] < 1.25, relmse
