"""The irradiance cache (survey ch. 3, issue 62 §3) from Python: parameters and bad input
(the cache unchanged after every refused call), the build over a view (coverage,
determinism for any thread count, files) and method "irradiance_cache" against the
one-bounce reference ``render(method="path", bounces=1, direct=False)``."""

from __future__ import annotations

import numpy as np
import pytest
import viscache_rs as vc

#: The small view every build and render here uses (cornell's camera at 64x48).
SIZE = (64, 48)


@pytest.fixture(scope="module")
def cornell():
    return vc.scenes.load("cornell")


@pytest.fixture(scope="module")
def small(cornell):
    return cornell.camera.with_resolution(*SIZE)


@pytest.fixture(scope="module")
def gbuffer(cornell, small):
    return cornell.scene.gbuffer(small, jitter=False, threads=2)


@pytest.fixture(scope="module")
def built(cornell, small):
    """A default cache built for the small view (threads=2), and its build report."""
    cache = vc.IrradianceCache(cornell.scene)
    report = cache.build(small, seed=3, threads=2, envmap=cornell.envmap, progress=False)
    return cache, report


@pytest.fixture(scope="module")
def reference(cornell, small):
    """The one-bounce reference: paths of one bounce without direct light, 1024 spp."""
    return vc.render(cornell, camera=small, method="path", bounces=1, direct=False,
                     spp=1024, seed=101, threads=2, progress=False)


def snapshot(cache):
    return len(cache), {k: v.copy() for k, v in cache.records().items()}


def assert_unchanged(cache, before):
    n, recs = before
    assert len(cache) == n
    after = cache.records()
    assert after.keys() == recs.keys()
    for k, v in recs.items():
        np.testing.assert_array_equal(after[k], v, err_msg=k)


# ---------------------------------------------------------------------------------------
# Construction and parameters


def test_defaults_repr_and_record_size(cornell):
    cache = vc.IrradianceCache(cornell.scene)
    p = cache.params
    assert p["a"] == pytest.approx(0.2) and p["strata"] == (16, 64)
    assert (p["r_min"], p["r_max"]) == (1.5, 32.0)
    assert p["gradients"] == "both" and p["clamp_neighbours"] is True
    assert p["secondary_spp"] == 1
    assert len(cache) == 0 and cache.scene is cornell.scene
    assert 0 < cache.record_bytes <= 120
    assert repr(cache) == 'IrradianceCache(records=0, a=0.2, strata=(16, 64), gradients="both")'
    assert all(v == 0 for v in cache.stats().values())
    recs = cache.records()
    assert recs["position"].shape == (0, 3) and recs["rotation"].shape == (0, 3, 3)
    other = vc.IrradianceCache(cornell.scene, a=0.05, strata=[4, 8], r_min=0.5, r_max=0.5,
                               gradients="none", clamp_neighbours=False, secondary_spp=3)
    q = other.params
    assert q["a"] == pytest.approx(0.05) and q["strata"] == (4, 8)
    assert (q["r_min"], q["r_max"], q["gradients"]) == (0.5, 0.5, "none")
    assert q["clamp_neighbours"] is False and q["secondary_spp"] == 3


@pytest.mark.parametrize(
    ("kwargs", "error", "name"),
    [
        ({"a": 0.0}, ValueError, "a"),
        ({"a": -0.1}, ValueError, "a"),
        ({"a": float("nan")}, ValueError, "a"),
        ({"a": 1.0001}, ValueError, "a"),
        ({"a": float("inf")}, ValueError, "a"),
        ({"a": "0.2"}, TypeError, "a"),
        ({"strata": (0, 4)}, ValueError, "strata"),
        ({"strata": (4, 0)}, ValueError, "strata"),
        ({"strata": (2.5, 4)}, TypeError, "strata"),
        ({"strata": (True, 4)}, TypeError, "strata"),
        ({"strata": "ab"}, TypeError, "strata"),
        ({"strata": (4,)}, TypeError, "strata"),
        ({"strata": (4, 4, 4)}, TypeError, "strata"),
        ({"strata": (300, 300)}, ValueError, "strata"),
        ({"r_min": 5.0, "r_max": 2.0}, ValueError, "r_max"),
        ({"r_min": 0.0}, ValueError, "r_min"),
        ({"r_min": -1.0}, ValueError, "r_min"),
        ({"r_min": float("nan")}, ValueError, "r_min"),
        ({"r_max": float("inf")}, ValueError, "r_max"),
        ({"secondary_spp": 0}, ValueError, "secondary_spp"),
        ({"secondary_spp": -2}, ValueError, "secondary_spp"),
        ({"secondary_spp": 1.5}, TypeError, "secondary_spp"),
        ({"gradients": "all"}, ValueError, "gradients"),
        ({"gradients": "Both"}, ValueError, "gradients"),
        ({"gradients": 2}, TypeError, "gradients"),
        ({"clamp_neighbours": "yes"}, TypeError, "clamp_neighbours"),
    ],
)
def test_bad_parameters_name_the_argument(cornell, kwargs, error, name):
    with pytest.raises(error, match=f"^{name}:"):
        vc.IrradianceCache(cornell.scene, **kwargs)


def test_r_min_above_r_max_says_both(cornell):
    with pytest.raises(ValueError, match=r"r_max: .*>= r_min \(5\), got 2"):
        vc.IrradianceCache(cornell.scene, r_min=5.0, r_max=2.0)


# ---------------------------------------------------------------------------------------
# Bad input to calls: refused, naming the argument, the cache as it was


POINTS = np.array([[0.0, 0.0, 0.0], [0.1, 0.2, 0.3]])
NORMALS = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])

BAD_LOOKUPS = [
    (np.zeros((2, 2)), NORMALS, ValueError, "points"),
    (POINTS.ravel(), NORMALS, ValueError, "points"),
    (np.array([[0.0, np.nan, 0.0], [0, 0, 0]]), NORMALS, ValueError, "points"),
    (np.array([[0.0, np.inf, 0.0], [0, 0, 0]]), NORMALS, ValueError, "points"),
    (np.full((2, 3), "x"), NORMALS, TypeError, "points"),
    ([[0, 0, "a"], [0, 0, 0]], NORMALS, TypeError, "points"),
    (POINTS, NORMALS[:1], ValueError, "normals"),
    (POINTS, np.zeros((2, 3)), ValueError, "normals"),
    (POINTS, np.full((2, 3), np.nan), ValueError, "normals"),
    (POINTS, np.full((2, 3), "x"), TypeError, "normals"),
    (POINTS, np.zeros((2, 4)), ValueError, "normals"),
]


@pytest.mark.parametrize(("points", "normals", "error", "name"), BAD_LOOKUPS)
def test_bad_lookups_name_the_argument_and_change_nothing(built, points, normals, error,
                                                          name):
    cache, _ = built
    before = snapshot(cache)
    with pytest.raises(error, match=f"^{name}:"):
        cache.lookup(points, normals)
    assert_unchanged(cache, before)


@pytest.mark.parametrize(
    ("kwargs", "error", "name"),
    [
        ({"point": [0.0, np.nan, 0.0]}, ValueError, "point"),
        ({"point": [0.0, 0.0]}, ValueError, "point"),
        ({"point": "abc"}, TypeError, "point"),
        ({"normal": [0.0, 0.0, 0.0]}, ValueError, "normal"),
        ({"normal": [np.inf, 1.0, 0.0]}, ValueError, "normal"),
        ({"footprint": -1.0}, ValueError, "footprint"),
        ({"footprint": 0.0}, ValueError, "footprint"),
        ({"footprint": float("nan")}, ValueError, "footprint"),
    ],
)
def test_bad_inserts_name_the_argument_and_change_nothing(cornell, built, kwargs, error, name):
    cache, _ = built
    before = snapshot(cache)
    stats = cache.stats()
    args = {"point": [0.0, 0.01, 0.0], "normal": [0.0, 1.0, 0.0], **kwargs}
    with pytest.raises(error, match=f"^{name}:"):
        cache.insert(envmap=cornell.envmap, **args)
    assert_unchanged(cache, before)
    assert cache.stats() == stats


def test_an_unbuilt_cache_needs_a_footprint_to_insert(cornell):
    cache = vc.IrradianceCache(cornell.scene, strata=(2, 4))
    with pytest.raises(ValueError, match="^footprint: the cache has not been built"):
        cache.insert([0.0, 0.01, 0.0], [0, 1, 0], envmap=cornell.envmap)
    assert len(cache) == 0


def test_bad_build_arguments_change_nothing(cornell, small, built):
    cache, _ = built
    before = snapshot(cache)
    kw = {"envmap": cornell.envmap, "progress": False}
    with pytest.raises(ValueError, match="^camera"):
        cache.build(**kw)
    with pytest.raises(ValueError, match="^time_budget"):
        cache.build(small, time_budget=-1.0, **kw)
    with pytest.raises(ValueError, match="^threads"):
        cache.build(small, threads=0, **kw)
    with pytest.raises(ValueError, match="^seed"):
        cache.build(small, seed=-1, **kw)
    garage = vc.scenes.load("garage")
    with pytest.raises(ValueError, match="gbuffer|scene"):
        cache.build(gbuffer=garage.scene.gbuffer(small, jitter=False), **kw)
    assert_unchanged(cache, before)


# ---------------------------------------------------------------------------------------
# Building over a view


def test_build_report_counts_rays_and_records(built):
    cache, r = built
    m, n = cache.params["strata"]
    assert r["records"] == len(cache) == r["inserted"] > 0 and r["complete"]
    assert r["pixels"] == SIZE[0] * SIZE[1]
    assert 0 < r["points"] <= r["pixels"]
    assert r["hemisphere_rays"] == (r["inserted"] + r["discarded"]) * m * n
    assert r["secondary_rays"] > 0 and r["rays"] == r["hemisphere_rays"] + r["secondary_rays"]
    assert r["seconds"] > 0
    # Sparse: far fewer records than the points they serve.
    assert r["records"] < r["points"] / 3
    s = cache.stats()
    assert s["records_inserted"] == r["inserted"] and s["hemisphere_rays"] == r["hemisphere_rays"]
    recs = cache.records()
    assert recs["position"].shape == (len(cache), 3)
    assert np.all(np.isfinite(recs["irradiance"])) and np.all(recs["irradiance"] >= 0)
    assert np.all(recs["radius"] > 0) and np.all(np.isfinite(recs["radius"]))
    np.testing.assert_allclose(np.linalg.norm(recs["normal"], axis=1), 1.0, atol=1e-5)
    # Gradients lie in the record's tangent plane.
    for key in ("rotation", "translation"):
        along = np.einsum("ncx,nx->nc", recs[key], recs["normal"])
        scale = np.abs(recs[key]).max(axis=2) + 1e-12
        assert np.all(np.abs(along) <= 1e-3 * scale + 1e-6), key
    assert f"records={len(cache)}" in repr(cache)
    assert cache.memory_bytes() >= len(cache) * cache.record_bytes


def test_every_diffuse_pixel_of_the_view_is_covered(built, gbuffer):
    cache, report = built
    obj = gbuffer["object"].ravel()
    hit = obj >= 0
    found = cache.lookup(gbuffer["position"].reshape(-1, 3)[hit],
                         gbuffer["normal"].reshape(-1, 3)[hit], threads=2)
    # Cornell is all Lambert: every hit is a point records are made for.
    assert hit.sum() == report["points"]
    missing = np.isnan(found["irradiance"]).any(axis=1)
    assert missing.sum() == 0, f"{missing.sum()} of {hit.sum()} pixels have no usable record"
    assert np.all(found["weight_sum"] > 0) and np.all(found["records"] >= 1)
    assert np.all(found["irradiance"] >= 0)
    # `ids` lists exactly the records used, in id order, -1 after.
    ids = found["ids"]
    assert np.all((ids >= 0).sum(axis=1) == found["records"])
    used = ids[ids >= 0]
    assert used.max() < len(cache)


def test_lookup_at_a_record_gives_its_irradiance(built):
    cache, _ = built
    recs = cache.records()
    k = np.arange(0, len(cache), max(1, len(cache) // 16))
    found = cache.lookup(recs["position"][k], recs["normal"][k])
    assert np.all(found["weight_sum"] == np.inf)
    # The mean of the records at exactly that point and normal: its own E (ids are unique
    # points in a build over distinct pixels).
    np.testing.assert_array_equal(found["irradiance"], recs["irradiance"][k])


def test_records_are_bit_identical_for_any_thread_count(cornell, small, built):
    cache2, _ = built
    cache1 = vc.IrradianceCache(cornell.scene)
    r1 = cache1.build(small, seed=3, threads=1, envmap=cornell.envmap, progress=False)
    assert r1["records"] == len(cache2)
    a, b = cache1.records(), cache2.records()
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    assert cache1.stats() == cache2.stats()


def test_a_second_build_adds_nothing(cornell, small):
    cache = vc.IrradianceCache(cornell.scene, strata=(4, 16))
    first = cache.build(small, seed=1, threads=2, envmap=cornell.envmap, progress=False)
    again = cache.build(small, seed=1, threads=2, envmap=cornell.envmap, progress=False)
    assert first["inserted"] > 0
    assert again["inserted"] == 0 and again["hemisphere_rays"] == 0
    assert again["records"] == first["records"]


def test_save_and_load_round_trip(tmp_path, cornell, built, gbuffer):
    cache, _ = built
    path = tmp_path / "cornell.vcir"
    cache.save(path)
    loaded = vc.IrradianceCache.load(path, cornell.scene)
    assert isinstance(loaded, vc.IrradianceCache)
    assert len(loaded) == len(cache) and loaded.params == cache.params
    a, b = cache.records(), loaded.records()
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    pts = gbuffer["position"].reshape(-1, 3)[gbuffer["object"].ravel() >= 0]
    nrm = gbuffer["normal"].reshape(-1, 3)[gbuffer["object"].ravel() >= 0]
    x, y = cache.lookup(pts, nrm), loaded.lookup(pts, nrm)
    np.testing.assert_array_equal(x["irradiance"], y["irradiance"])
    # The last build's footprint is kept: an insert without one works.
    loaded.insert([0.0, 0.01, 0.0], [0, 1, 0], envmap=cornell.envmap)
    assert len(loaded) == len(cache) + 1


def test_load_refuses_another_scene_and_corrupted_files(tmp_path, cornell, built):
    cache, _ = built
    path = tmp_path / "c.vcir"
    cache.save(path)
    garage = vc.scenes.load("garage")
    with pytest.raises(ValueError, match="scene|fingerprint"):
        vc.IrradianceCache.load(path, garage.scene)
    raw = path.read_bytes()
    for cut in (0, 7, 40, len(raw) // 2, len(raw) - 1):
        (tmp_path / "cut.vcir").write_bytes(raw[:cut])
        with pytest.raises(ValueError, match="cut.vcir"):
            vc.IrradianceCache.load(tmp_path / "cut.vcir", cornell.scene)
    flipped = bytearray(raw)
    flipped[len(raw) // 3] ^= 0x40
    (tmp_path / "flip.vcir").write_bytes(bytes(flipped))
    with pytest.raises(ValueError, match="flip.vcir"):
        vc.IrradianceCache.load(tmp_path / "flip.vcir", cornell.scene)
    # A file whose checksum holds but whose first record's radius is negative (format v1:
    # records from byte 64, R_i the tenth float).
    body = bytearray(raw[:-8])
    body[64 + 36:64 + 40] = np.float32(-1.0).tobytes()
    forged = bytes(body) + _fnv1a64(bytes(body)).to_bytes(8, "little")
    (tmp_path / "forged.vcir").write_bytes(forged)
    with pytest.raises(ValueError, match="radius"):
        vc.IrradianceCache.load(tmp_path / "forged.vcir", cornell.scene)
    with pytest.raises(FileNotFoundError):
        vc.IrradianceCache.load(tmp_path / "missing.vcir", cornell.scene)


def _fnv1a64(data: bytes) -> int:
    """The file's trailing checksum (FNV-1a 64), to forge files that pass it."""
    h = 0xCBF29CE484222325
    for b in data:
        h = ((h ^ b) * 0x100000001B3) & 0xFFFFFFFFFFFFFFFF
    return h


# ---------------------------------------------------------------------------------------
# Method "irradiance_cache"


def test_method_is_registered():
    rows = {m["name"]: m for m in vc.methods()}
    assert "irradiance_cache" in rows


def test_wrong_caches_and_arguments_are_refused(cornell, small):
    kw = {"camera": small, "spp": 1, "progress": False}
    ic = vc.IrradianceCache(cornell.scene)
    vis = vc.VisibilityCache(cornell.scene, resolution=8)
    with pytest.raises(ValueError, match="^cache:.*IrradianceCache"):
        vc.render(cornell, method="irradiance_cache", direct=False, cache=vis, **kw)
    with pytest.raises(ValueError, match="^cache:.*VisibilityCache"):
        vc.render(cornell, method="cv", cache=ic, **kw)
    with pytest.raises(TypeError, match="^cache:"):
        vc.render(cornell, method="irradiance_cache", cache="mine", **kw)
    with pytest.raises(ValueError, match="^a:"):
        vc.render(cornell, method="mis", a=0.2, **kw)
    with pytest.raises(ValueError, match="^strata:"):
        vc.render(cornell, method="path", strata=(4, 4), **kw)
    with pytest.raises(ValueError, match="^bounces:"):
        vc.render(cornell, method="irradiance_cache", bounces=2, **kw)
    with pytest.raises(ValueError, match="^a:"):
        vc.render(cornell, method="irradiance_cache", a=1.5, **kw)
    with pytest.raises(ValueError, match="^cache:"):
        vc.render(cornell, method="irradiance_cache", cache=ic, a=0.1, **kw)
    assert len(ic) == 0 and len(vis) == 0


def ic_render(setup, camera, **kw):
    args = {"method": "irradiance_cache", "direct": False, "spp": 4, "seed": 5,
            "threads": 2, "progress": False, **kw}
    return vc.render(setup, camera=camera, **args)


@pytest.fixture(scope="module")
def ic_default(cornell, small):
    return ic_render(cornell, small)


def test_render_matches_the_one_bounce_reference(ic_default, reference):
    res, s = ic_default, ic_default.stats
    assert s["method"] == "irradiance_cache" and s["records"] > 0
    assert s["build_complete"] and s["seconds"] >= s["build_seconds"] > 0
    # Jittered hits a pixel's records do not reach take a path (counted).
    assert 0 <= s["irradiance_misses"] < s["irradiance_lookups"]
    # Biased, but close: relMSE of the indirect image (the reference's own noise taken
    # out) and the image mean per channel.
    err = vc.metrics.relmse(res.image, reference.image, reference.variance)
    assert err < RELMSE_BOUND, err
    mean, want = res.image.mean(axis=(0, 1)), reference.image.mean(axis=(0, 1))
    np.testing.assert_allclose(mean, want, rtol=MEAN_RTOL)


#: relMSE of the default cache (a = 0.2) against the 1024-spp reference on cornell at
#: 64x48, 4 spp, seed 5: measured 5.6e-4 to 5.8e-4 (seeds 5, 6); the bound leaves ~3x.
RELMSE_BOUND = 2e-3
#: The image mean's relative error per channel: measured under 0.7% (a = 0.4: 1.5%).
MEAN_RTOL = 0.03


def test_every_anchor_finds_a_record(cornell, gbuffer):
    # Samples at the pixels' centres (jitter=False) are the G-buffer's points, which the
    # build covers: none takes a path.
    res = vc.render(cornell, gbuffer=gbuffer, method="irradiance_cache", direct=False,
                    spp=2, jitter=False, seed=5, threads=2, progress=False)
    assert res.stats["irradiance_lookups"] > 0
    assert res.stats["irradiance_misses"] == 0


def per_pixel(cornell, size=(32, 24)):
    """A view's G-buffer points and normals, and E there from a cache with a record at
    every pixel (a = 0.01: no record reaches a neighbouring pixel)."""
    g = cornell.scene.gbuffer(cornell.camera.with_resolution(*size), jitter=False, threads=2)
    hit = g["object"].ravel() >= 0
    pts, nrm = g["position"].reshape(-1, 3)[hit], g["normal"].reshape(-1, 3)[hit]
    exact = vc.IrradianceCache(cornell.scene, a=0.01)
    rep = exact.build(gbuffer=g, seed=2, threads=2, envmap=cornell.envmap, progress=False)
    assert rep["records"] == hit.sum()
    found = exact.lookup(pts, nrm)
    assert np.all(found["weight_sum"] == np.inf)
    return g, pts, nrm, found["irradiance"]


@pytest.fixture(scope="module")
def pixels(cornell):
    return per_pixel(cornell)


def interpolation_error(cornell, pixels, **params):
    """relMSE (RGB) of a cache's E at the points against the per-pixel records. Records
    are keyed by pixel, so a record made for a pixel is that pixel's record in the exact
    cache: what is left is the interpolation's error alone."""
    g, pts, nrm, want = pixels
    cache = vc.IrradianceCache(cornell.scene, **params)
    cache.build(gbuffer=g, seed=2, threads=2, envmap=cornell.envmap, progress=False)
    got = cache.lookup(pts, nrm)["irradiance"]
    assert not np.isnan(got).any()
    return vc.metrics.relmse(got[None], want[None]), len(cache)


def test_interpolation_error_falls_with_a(cornell, pixels):
    errs, counts = {}, {}
    for a in (0.4, 0.2, 0.1, 0.05):
        errs[a], counts[a] = interpolation_error(cornell, pixels, a=a)
    assert counts[0.4] < counts[0.2] < counts[0.1] < counts[0.05], counts
    assert errs[0.4] > errs[0.2] > errs[0.1] > errs[0.05] > 0, errs


@pytest.mark.parametrize("a", [0.4, 0.1])
def test_gradients_do_not_raise_the_interpolation_error(cornell, pixels, a):
    none, _ = interpolation_error(cornell, pixels, a=a, gradients="none")
    rotation, _ = interpolation_error(cornell, pixels, a=a, gradients="rotation")
    both, _ = interpolation_error(cornell, pixels, a=a, gradients="both")
    # Measured at 32x24: a = 0.4 4.9e-3 (none) and 2.2e-3 (both), a = 0.1 2.9e-4 and
    # 9.2e-5. The box's walls are planes, so the records that serve a point share its
    # normal and the rotational term is 0 up to rounding.
    assert both < none, (none, both)
    assert rotation <= none * (1 + 1e-4), (none, rotation)


def test_smaller_a_means_more_records(cornell, small):
    res = {a: ic_render(cornell, small, a=a, strata=(4, 16)) for a in (0.4, 0.1)}
    assert res[0.1].stats["records"] > 2 * res[0.4].stats["records"]
    tiny = ic_render(cornell, small.with_resolution(16, 12), a=0.01, strata=(4, 8))
    # a -> 0: a record for every pixel.
    assert tiny.stats["records"] == 16 * 12


def test_render_error_falls_as_a_falls(cornell, small, reference):
    err = {a: vc.metrics.relmse(ic_render(cornell, small, a=a).image, reference.image,
                                reference.variance) for a in (0.4, 0.1)}
    assert err[0.1] < err[0.4], err


def test_a_given_cache_is_grown_and_reused(cornell, small):
    cache = vc.IrradianceCache(cornell.scene, a=0.3, strata=(8, 16))
    first = ic_render(cornell, small, cache=cache)
    n = len(cache)
    assert n > 0 and first.stats["records"] == n and first.stats["records_inserted"] == n
    again = ic_render(cornell, small, cache=cache, seed=6)
    assert len(cache) == n and again.stats["records_inserted"] == 0
    # A bigger view of the same box needs more records: the cache grows.
    ic_render(cornell, small.with_resolution(128, 96), cache=cache)
    assert len(cache) > n
    garage = vc.scenes.load("garage")
    with pytest.raises(ValueError, match="^cache:"):
        ic_render(garage, garage.camera.with_resolution(8, 6), cache=cache)


def test_same_seed_same_image_for_any_thread_count(cornell, small, ic_default):
    one = ic_render(cornell, small, threads=1)
    np.testing.assert_array_equal(one.image, ic_default.image)
    np.testing.assert_array_equal(one.variance, ic_default.variance)
    assert one.stats["records"] == ic_default.stats["records"]
