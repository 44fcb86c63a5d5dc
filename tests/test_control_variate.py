"""The cache as a control variate (CAM08 eq. 2-3): unbiased against product sampling with good
and deliberately bad caches, alpha fixed and estimated, statistics, misses, one-pass
insertion, the lighting preview, determinism, extremes and bad input.

Agreement is judged as in test_render.py: independent seeds, per-pixel differences within
the Bonferroni z for the channel count where both estimates are in their central-limit
regime, and the whole-image mean within 4 standard errors over every pixel.
"""

import importlib
import math

import numpy as np
import pytest
import viscache_rs as vc
from conftest import bonferroni_z
from viscache_rs.metrics import luminance, luminance_variance

# The module, which the package's ``render`` function shadows.
render_module = importlib.import_module("viscache_rs.render")


@pytest.fixture(scope="module")
def garage():
    setup = vc.scenes.load("garage", detail=0.3)
    setup.camera = setup.camera.with_resolution(40, 30)
    cache = vc.VisibilityCache(setup.scene)
    cache.build(setup.camera, seed=0, progress=False)
    return setup, cache


@pytest.fixture(scope="module")
def open_cornell():
    """The Cornell box without its ceiling and light, under the garage's windows map: the
    records see sky past the walls and blocks."""
    base = vc.scenes.load("cornell")
    scene = vc.scenes.without(base, ("ceiling", "light")).scene
    camera = base.camera.with_resolution(40, 30)
    env = vc.scenes.load("garage", detail=0.1).envmap
    setup = vc.Setup(scene, camera, env, name="open-cornell")
    cache = vc.VisibilityCache(scene, preset="medium")
    cache.build(camera, seed=0, progress=False)
    return setup, cache


@pytest.fixture(scope="module")
def panels():
    """Panels under a daylight sun, which most pixels see past the panels' edges or not at
    all: the control variate takes the sun's visibility from a shadow ray at each anchor."""
    setup = vc.scenes.load("panels", detail=0.3)
    setup.camera = setup.camera.with_resolution(40, 30)
    cache = vc.VisibilityCache(setup.scene)
    cache.build(setup.camera, seed=0, progress=False)
    return setup, cache


def _clt(r):
    return (r.image > 0) & (np.sqrt(r.variance) <= 0.2 * r.image)


def _assert_agree(a, b, min_coverage, label):
    """Per-pixel (Bonferroni z, CLT pixels) and whole-image (4 SE, every pixel) agreement."""
    for r in (a, b):
        assert np.isfinite(r.image).all() and np.isfinite(r.variance).all(), label
    n_pix = a.image.shape[0] * a.image.shape[1]
    z = bonferroni_z(3 * n_pix)
    diff = a.image - b.image
    se = np.sqrt(a.variance + b.variance)
    clt = _clt(a) & _clt(b)
    assert clt.mean() >= min_coverage, f"{label}: only {clt.mean():.3f} of pixels compared"
    bad = clt & (np.abs(diff) > z * se)
    assert bad.sum() == 0, f"{label}: {bad.sum()} pixel channels beyond {z:.2f} SE"
    mean_diff = luminance(diff).mean()
    mean_se = math.sqrt(luminance_variance(a.variance + b.variance).sum()) / n_pix
    assert abs(mean_diff / mean_se) < 4, f"{label}: image means {mean_diff / mean_se:.2f} SE apart"


def _render(setup, method, spp, seed, **kw):
    return vc.render(setup, spp=spp, method=method, seed=seed, progress=False, **kw)


# CAM08's setting: every sample at the pixel's centre hit, plain product sampling.
FIXED = {"jitter": False, "technique_weights": {"product": 1}}


@pytest.mark.parametrize("alpha", [1.0, "estimate"])
@pytest.mark.parametrize("which", ["garage", "open_cornell", "panels"])
def test_cv_agrees_with_product(request, which, alpha):
    setup, cache = request.getfixturevalue(which)
    # Product sampling's sun through the panels' gaps needs more samples for most pixels'
    # means to be normal enough to compare.
    spp = 1024 if which == "panels" else 256
    product = _render(setup, "product", spp, seed=21)
    cv = _render(setup, "cv", spp, seed=22, cache=cache, alpha=alpha)
    _assert_agree(cv, product, 0.45, f"{which} alpha={alpha}")
    # The cache was used, and it helped; under the daylight map each anchor traced its sun.
    assert cv.stats["records_per_point"] > 1.0
    assert (cv.stats["sun_rays"] > 0) == (which == "panels")
    assert (luminance_variance(cv.variance).mean()
            < 0.8 * luminance_variance(product.variance).mean())


def test_each_lobe_keeps_its_colour_in_the_control_variate(garage):
    # Garage's blue car: blue paint under a grey coat, so a channel of f over its luminance
    # changes with direction. With one colour ratio per point (the albedo's) the control
    # variate left 0.83x product sampling's blue variance on the car (R 0.73, G 0.68; these
    # seeds); with each lobe's part of L B~ V~ in its own colour, 0.19 (R 0.68, G 0.70).
    setup, cache = garage
    scene = setup.scene
    car = [i for i in range(scene.num_objects)
           if scene.material(i) == vc.Material.phong((0.05, 0.1, 0.45), (0.3, 0.3, 0.3), 60)]
    assert len(car) == 1
    on_car = np.asarray(scene.gbuffer(setup.camera, jitter=False)["object"]) == car[0]
    assert on_car.sum() > 100
    product = _render(setup, "product", 64, seed=11)
    cv = _render(setup, "cv", 64, seed=21, cache=cache)
    ratio = cv.variance[on_car].sum(axis=0) / product.variance[on_car].sum(axis=0)
    assert ratio[2] < 0.4 and np.all(ratio < 1.0), ratio


def test_cv_agrees_with_product_in_the_closed_cornell_box():
    # Lit by its ceiling light only: every record is all-occluded, J = 0, and the control
    # variate must leave the area light's estimate alone. (Unchecked: the default check
    # sees no map there and keeps no record at all.)
    setup = vc.scenes.load("cornell")
    setup.camera = setup.camera.with_resolution(40, 30)
    cache = vc.VisibilityCache(setup.scene, check_coherence=False)
    cache.build(setup.camera, seed=0, progress=False)
    assert cache.records()["ao"].max() == 0.0
    product = _render(setup, "product", 128, seed=31)
    for alpha in (1.0, "estimate"):
        cv = _render(setup, "cv", 128, seed=32, cache=cache, alpha=alpha)
        _assert_agree(cv, product, 0.9, f"closed cornell alpha={alpha}")


@pytest.mark.parametrize("alpha", [1.0, "estimate"])
def test_a_bad_cache_adds_variance_never_bias(garage, alpha):
    # Records traced without the roof see the bright windows everywhere under it: the
    # control variate is badly wrong, yet the estimate stays unbiased.
    setup, _ = garage
    roofless = vc.scenes.without(setup, ("roof",)).scene
    wrong = vc.VisibilityCache(roofless)
    wrong.build(setup.camera, seed=0, progress=False)
    wrong.bind(setup.scene)  # on purpose: another geometry's records
    product = _render(setup, "product", 256, seed=41)
    cv = _render(setup, "cv", 256, seed=42, cache=wrong, alpha=alpha)
    _assert_agree(cv, product, 0.4, f"roofless records alpha={alpha}")
    assert cv.stats["miss_rate"] > 0.1
    if alpha == "estimate":
        # The neighbours see that W predicts Z badly and turn the control variate down.
        assert np.mean(cv.stats["mean_alpha"]) < 0.9


def test_records_of_another_scene_keep_it_unbiased(open_cornell):
    # The open Cornell box's records used in the garage: a few land within reach, most
    # points find none (plain product sampling there).
    setup = vc.scenes.load("garage", detail=0.3)
    setup.camera = setup.camera.with_resolution(40, 30)
    own, cache = open_cornell
    cache.bind(setup.scene)  # on purpose: another scene's records
    try:
        product = _render(setup, "product", 128, seed=51)
        cv = _render(setup, "cv", 128, seed=52, cache=cache, alpha=1.0)
    finally:
        cache.bind(own.scene)
    _assert_agree(cv, product, 0.4, "cornell records in the garage")


def test_all_visible_records_neither_help_nor_hurt():
    # A grey Lambert plane under a grey sky, nothing above it: every record sees the whole
    # upper hemisphere, so V = V~ = 1 (except in the texels the horizon cuts, where a
    # record's bit is its pattern direction's, which may lie below the plane). Then
    # W = g/p - J = L_ns - J = 0 and product sampling's variance, all of it from B/B~,
    # stays: with the same samples the two estimates and their variances coincide up to
    # the horizon texels.
    scene = vc.Scene()
    v = np.array([[-50, 0, -50], [50, 0, -50], [50, 0, 50], [-50, 0, 50]], np.float32)
    scene.add_mesh(v, np.array([[0, 2, 1], [0, 3, 2]]), material=vc.Material.lambert((0.5,) * 3))
    camera = vc.Camera.look_at((0, 3, 5), (0, 0, 0), width=24, height=18)
    sky = vc.envmaps.sky(sun_dir=(0.3, 1.0, -0.5), sun_radiance=2e3, resolution=64,
                         zenith=(0.5, 0.5, 0.5), horizon=(1.0, 1.0, 1.0))
    setup = vc.Setup(scene, camera, sky)
    # 32^2 records, one per product cell (finer records would resolve the horizon's cells
    # and help a little).
    cache = vc.VisibilityCache(scene, preset="medium")
    cache.build(camera, progress=False)
    assert cache.records()["ao"].min() > 0.999
    # With plain product sampling at fixed points g/p is the constant L_ns V~ (the mixture
    # of a jittered render would make it vary).
    product = _render(setup, "product", 64, seed=61, **FIXED)
    cv = _render(setup, "cv", 64, seed=61, cache=cache, **FIXED)
    assert cv.stats["miss_rate"] < 0.01
    assert np.allclose(cv.image, product.image, rtol=0.05)
    ratio = luminance_variance(cv.variance).mean() / luminance_variance(product.variance).mean()
    assert 0.9 < ratio < 1.1, ratio
    independent = _render(setup, "cv", 64, seed=62, cache=cache, **FIXED)
    _assert_agree(independent, product, 0.9, "open plane")
    jittered = _render(setup, "cv", 64, seed=63, cache=cache)
    _assert_agree(jittered, _render(setup, "product", 64, seed=64), 0.9, "open plane, jitter")


def test_stats_report_the_cache_work_and_misses_reach_the_records(garage):
    setup, _ = garage
    cache = vc.VisibilityCache(setup.scene)
    cache.build(setup.camera, seed=0, progress=False)
    before = cache.records()["uses"].sum()
    r = _render(setup, "cv", 8, seed=3, cache=cache)
    s = r.stats
    n = setup.camera.width * setup.camera.height
    for key in ("lookup_seconds", "control_seconds", "product_seconds", "shading_seconds"):
        assert s[key] > 0, key
    # One lookup per pixel, at its anchor (the hit through its centre); a primary ray per
    # sample besides.
    assert s["cache_points"] <= n and s["primary_rays"] == 9 * n
    assert 0 < s["unmatched_samples"] < 0.2 * 8 * n
    assert 1.0 <= s["records_per_point"] <= 4.0
    # Odd columns share their left neighbour's lookup where the points nearly coincide.
    assert 0 < s["shared_lookups"] < 0.5 * s["cache_points"] + 1
    # ... and on garage's flat diffuse walls and ground, their J as well.
    assert 0 < s["reused_integrals"] <= s["shared_lookups"]
    assert s["record_uses"] > 0 and 0.0 <= s["miss_rate"] < 0.2
    recs = cache.records()
    assert recs["uses"].sum() - before == s["record_uses"]
    assert recs["misses"].sum() == s["record_misses"]
    assert r.alpha.shape == r.image.shape and np.all(r.alpha == 1.0)
    est = _render(setup, "cv", 8, seed=3, cache=cache, alpha="estimate")
    assert est.stats["alpha"] == "estimate"
    assert (est.alpha >= 0).all() and (est.alpha <= 2).all()
    assert np.allclose(est.alpha.mean(axis=(0, 1)), est.stats["mean_alpha"])
    # Without a cache, "cv" builds one and says what it cost, where its samples repay it:
    # 500 records (the bootstrap) cost about as much as 150k product samples, which 2 spp
    # of 40x30 pixels do not repay (the check predicts it and inserts none) and 256 do.
    built = _render(setup, "cv", 256, seed=3)
    assert built.stats["cache_records"] > 0 and built.stats["cache_seconds"] > 0
    assert built.stats["cache_predicted_gain"] > 1 and not built.stats["cache_incoherent"]
    few = _render(setup, "cv", 2, seed=3)
    assert few.stats["cache_records"] == 0 and few.stats["cache_incoherent"]
    assert few.stats["cache_predicted_gain"] < 1


def test_cv_without_a_cache_builds_no_more_records_than_its_samples_repay():
    """The cache ``render(method="cv")`` builds for itself holds at most one record per
    ``SAMPLES_PER_RECORD`` samples of the render (and at least the bootstrap's)."""
    setup = vc.scenes.load("garage", detail=0.3)
    setup.camera = setup.camera.with_resolution(128, 96)
    pixels = 128 * 96
    uncapped = vc.VisibilityCache(setup.scene, nearest_hits=False)
    uncapped.build(setup.camera, seed=0, progress=False)
    startup = uncapped.params["n_startup"]
    assert len(uncapped) > startup
    # 16 spp: fewer records than the bootstrap's by the samples, which still repay those.
    few = _render(setup, "cv", 16, seed=0, jitter=False)
    assert pixels * 16 // render_module.SAMPLES_PER_RECORD < startup
    assert few.stats["cache_records"] == startup
    # Enough samples for every record the view asks for: the same cache as without a cap.
    spp = -(-len(uncapped) * render_module.SAMPLES_PER_RECORD // pixels)
    many = _render(setup, "cv", spp, seed=0, jitter=False)
    assert many.stats["cache_records"] == len(uncapped)
    # A time budget beside spp: the spp still caps the records (a budget the build cannot
    # spend on any machine; the render stops at its 16 spp).
    budget = _render(setup, "cv", 16, seed=0, jitter=False, time_budget=20.0)
    assert budget.stats["cache_planned_spp"] == few.stats["cache_planned_spp"] == 16
    assert budget.stats["cache_records"] == startup
    # A budget alone: a pilot of product sampling estimates the samples it allows, and
    # the records' cap and the coherence check's predicted gain are those of that spp.
    open_ended = vc.render(setup, method="cv", time_budget=0.5, seed=0, jitter=False,
                           progress=False)
    planned = open_ended.stats["cache_planned_spp"]
    assert isinstance(planned, int) and planned >= 1
    cap = min(uncapped.params["max_records"],
              max(startup, pixels * planned // render_module.SAMPLES_PER_RECORD))
    assert open_ended.stats["cache_records"] <= cap
    alike = vc.VisibilityCache(setup.scene, nearest_hits=False, max_records=cap)
    check = alike.build(setup.camera, seed=0, progress=False, spp=planned, time_budget=1e-9)
    assert open_ended.stats["cache_predicted_gain"] == pytest.approx(check["predicted_gain"],
                                                                     rel=1e-6)


def test_no_records_means_product_sampling_and_one_pass_insertion(garage):
    setup, _ = garage
    empty = vc.VisibilityCache(setup.scene)
    product = _render(setup, "product", 4, seed=5)
    cv = _render(setup, "cv", 4, seed=5, cache=empty)
    # Same seed, no records: the same samples, the same image.
    assert np.array_equal(cv.image, product.image)
    n_hit = cv.stats["cache_points"]
    assert cv.stats["points_without_records"] == n_hit > 0
    assert len(empty) == 0
    once = _render(setup, "cv", 4, seed=5, cache=empty, insert_missing=True)
    assert once.stats["inserted_records"] == len(empty) > 0
    again = _render(setup, "cv", 4, seed=5, cache=empty)
    assert again.stats["points_without_records"] < 0.1 * n_hit


@pytest.mark.parametrize("alpha", [1.0, "estimate"])
def test_bit_identical_for_any_thread_count(garage, alpha, tmp_path):
    # Each run starts from the same saved cache (a render adds miss counts to its records).
    setup, cache = garage
    cache.save(tmp_path / "cache.vc")
    runs = []
    for threads in (1, 2):
        c = vc.VisibilityCache.load(tmp_path / "cache.vc", setup.scene)
        runs.append(_render(setup, "cv", 3, seed=7, cache=c, alpha=alpha, threads=threads))
    a, b = runs
    assert np.array_equal(a.image, b.image) and np.array_equal(a.variance, b.variance)
    assert np.array_equal(a.alpha, b.alpha)
    j = [_render(setup, "cv", 2, seed=7, cache=cache, jitter=True, threads=t) for t in (1, 2)]
    assert np.array_equal(j[0].image, j[1].image)


def test_fixed_point_cv_agrees_with_fixed_point_product(garage):
    setup, cache = garage
    product = _render(setup, "product", 256, seed=71, **FIXED)
    cv = _render(setup, "cv", 256, seed=72, cache=cache, **FIXED)
    _assert_agree(cv, product, 0.4, "fixed points")
    assert cv.stats["primary_rays"] == setup.camera.width * setup.camera.height


def test_jittered_samples_across_silhouettes_stay_unbiased():
    # Thin posts and a box in front of a wall, seen at 40 x 30: many pixels hold two
    # objects, so many samples hit another surface than their pixel's anchor (the product
    # and records of the anchor are then wrong for them). Against MIS, which does no
    # per-pixel work, every pixel must agree.
    scene = vc.Scene()
    grey = vc.Material.lambert((0.6, 0.6, 0.6))
    quad = np.array([[0, 1, 2], [0, 2, 3]])
    wall = np.array([[-6, 0, -2], [6, 0, -2], [6, 6, -2], [-6, 6, -2]], np.float32)
    ground = np.array([[-6, 0, -2], [-6, 0, 6], [6, 0, 6], [6, 0, -2]], np.float32)
    scene.add_mesh(wall, quad, material=grey, name="wall")
    scene.add_mesh(ground, quad, material=grey, name="ground")
    for k, x in enumerate(np.linspace(-3, 3, 7)):
        post = vc.Material.phong((0.3, 0.2, 0.1), (0.5, 0.5, 0.5), 40.0)
        box = np.array([[x - 0.04, 0, 0.5], [x + 0.04, 0, 0.5], [x + 0.04, 3, 0.5],
                        [x - 0.04, 3, 0.5]], np.float32)
        scene.add_mesh(box, quad, material=post, name=f"post{k}")
    camera = vc.Camera.look_at((0, 2, 7), (0, 1.5, 0), width=40, height=30)
    sky = vc.envmaps.sky(sun_dir=(0.5, 0.6, 0.6), sun_radiance=2e3, resolution=64)
    setup = vc.Setup(scene, camera, sky)
    cache = vc.VisibilityCache(scene)
    cache.build(camera, progress=False)
    mis = _render(setup, "mis", 512, seed=81)
    for method, extra in (("product", {}), ("cv", {"cache": cache}),
                          ("cv", {"cache": cache, "alpha": "estimate"})):
        r = _render(setup, method, 512, seed=82, **extra)
        _assert_agree(r, mis, 0.5, f"{method} {extra.keys()}")
        if method == "cv":
            assert r.stats["unmatched_samples"] > 0.02 * 512 * 40 * 30


def test_preview_is_j_and_traces_no_rays(garage):
    setup, cache = garage
    view = vc.LightingPreview(setup.scene, setup.camera)
    assert view.size == (setup.camera.width, setup.camera.height)
    view.prepare(cache, setup.envmap)  # the transfer (traces a few records to choose V~)
    setup.scene.counting = True
    try:
        setup.scene.reset_counters()
        a = view.render(cache, setup.envmap)
        b = view.render(cache, setup.envmap.rotated(90.0))
        c = view.render(cache, vc.envmaps.constant((0.0, 0.0, 0.0), resolution=8))
        assert setup.scene.counters()["rays"] == 0
    finally:
        setup.scene.counting = False
    assert a.shape == (30, 40, 3) and np.isfinite(a).all() and (a >= 0).all()
    assert not np.allclose(a, b)
    assert (c == 0).all()
    # J approximates the rendered image (CAM08 Fig. 11: blotchy but right on average).
    ref = _render(setup, "product", 64, seed=9)
    assert abs(luminance(a).mean() / luminance(ref.image).mean() - 1) < 0.15
    assert np.array_equal(vc.preview(setup, cache), view.render(cache, setup.envmap, direct=True))


def test_extreme_lighting_stays_finite(garage):
    setup, cache = garage
    maps = [
        vc.envmaps.constant((0.0, 0.0, 0.0), resolution=16),
        vc.envmaps.constant((1.0, 2.0, 3.0), resolution=1),
        vc.envmaps.sky(sun_dir=(0.3, 1.0, -0.5), sun_radiance=1e6, resolution=64),
    ]
    for env in maps:
        for alpha in (1.0, "estimate"):
            r = _render(setup, "cv", 2, seed=1, cache=cache, envmap=env, alpha=alpha)
            assert np.isfinite(r.image).all() and np.isfinite(r.variance).all()
    black = _render(setup, "cv", 2, seed=1, cache=cache, envmap=maps[0])
    assert (black.image == 0).all()


@pytest.mark.parametrize(
    ("kwargs", "exc", "needle"),
    [
        ({"alpha": -0.5}, ValueError, "alpha"),
        ({"alpha": 3.0}, ValueError, "alpha"),
        ({"alpha": float("nan")}, ValueError, "alpha"),
        ({"alpha": "optimal"}, ValueError, "alpha"),
        ({"alpha": True}, TypeError, "alpha"),
        ({"alpha": "estimate", "alpha_radius": 0}, ValueError, "alpha_radius"),
        ({"alpha_radius": 2.5}, TypeError, "alpha_radius"),
    ],
)
def test_bad_arguments_name_themselves(garage, kwargs, exc, needle):
    setup, cache = garage
    with pytest.raises(exc, match=needle):
        _render(setup, "cv", 1, seed=0, cache=cache, **kwargs)


def test_cache_with_other_methods_is_refused(garage):
    setup, cache = garage
    with pytest.raises(ValueError, match="cache"):
        _render(setup, "product", 1, seed=0, cache=cache)
    with pytest.raises(TypeError, match="cache"):
        vc._core.render(setup.scene, setup.envmap, setup.camera, 1, "cv", cache=setup.scene)
    with pytest.raises(ValueError, match="^cache: method \"product\" takes no cache"):
        vc._core.render(setup.scene, setup.envmap, setup.camera, 1, "product", cache=cache)
    # Without a cache the core builds one for the view (render::own_cache), as vc.render
    # does: a Rust caller gets the same render.
    small = setup.camera.with_resolution(32, 24)
    own = vc._core.render(setup.scene, setup.envmap, small, 4, "cv", jitter=False)
    same = vc.render(setup, camera=small, spp=4, method="cv", jitter=False, progress=False)
    assert own["stats"]["cache_planned_spp"] == same.stats["cache_planned_spp"] == 4
    assert own["stats"]["cache_records"] == same.stats["cache_records"]
    np.testing.assert_array_equal(own["image"], same.image)


def test_scenes_without_drops_objects_and_names_unknown_ones():
    base = vc.scenes.load("cornell")
    open_box = vc.scenes.without(base, ("ceiling", "light"), name="open")
    assert open_box.name == "open"
    names = open_box.scene.object_names()
    assert "ceiling" not in names and "light" not in names
    assert set(names) == set(base.scene.object_names()) - {"ceiling", "light"}
    kept = np.isin(base.scene.object_ids(), [base.scene.object_names().index(n) for n in names])
    assert open_box.scene.num_triangles == int(kept.sum())
    with pytest.raises(ValueError, match="drop"):
        vc.scenes.without(base, ("chimney",))
