"""The baseline renderer: the four estimators agree, the furnace test, extremes, determinism,
time budgets, progress and bad input.

Agreement is judged with the standard errors each render measures. Each method renders
with its own seed, so the estimates are independent and two unbiased ones differ by less
than z * sqrt(SE_a^2 + SE_b^2). Over many pixel channels some honest differences exceed
4 SE (p = 6.3e-5 each for Gaussian errors), so per-pixel tests use the Bonferroni
threshold for the channel count instead: the z with P(|Z| > z) * channels = 1e-3.

The Gaussian model needs a pixel's estimate to be in its central-limit regime. Where light
arrives along paths a method rarely samples (BSDF sampling of Cornell's small lamp; light
sampling of the dim sky that the garage roof's underside sees only through grazing gaps),
a few hundred samples may never find it, and the sample variance then understates the error
by orders of magnitude. Per-pixel comparisons are therefore made where both estimates have
a relative standard error of at most 20%, and the tests assert how many pixels that covers;
the whole-image comparison uses every pixel.
"""

import math

import numpy as np
import pytest
import viscache_rs as vc
from conftest import bonferroni_z, student_t_bonferroni
from viscache_rs.metrics import luminance, luminance_variance

METHODS = ["env", "bsdf", "mis", "product"]


@pytest.fixture(scope="module")
def small_setups():
    out = {}
    for name in ("cornell", "garage"):
        setup = vc.scenes.load(name, detail=0.3)
        setup.camera = setup.camera.with_resolution(40, 30)
        out[name] = setup
    return out


def _render(setup, method, spp, seed=0, **kw):
    return vc.render(setup, spp=spp, method=method, seed=seed, progress=False, **kw)


# Samples per pixel, and the fraction of pixel channels in the CLT regime each method must
# reach (measured at these sample counts: cornell 0.955 / 0.04 / 0.955, garage 0.55 / 0.37 /
# 0.58 for env / bsdf / product against MIS).
AGREEMENT = {
    "cornell": {"spp": {"env": 256, "bsdf": 1024, "mis": 256, "product": 256},
                "coverage": {"env": 0.9, "bsdf": 0.02, "product": 0.9}},
    "garage": {"spp": {"env": 256, "bsdf": 256, "mis": 256, "product": 256},
               "coverage": {"env": 0.45, "bsdf": 0.3, "product": 0.45}},
}


def _in_clt_regime(r):
    # A pixel that never found light has mean 0 and variance 0: not comparable.
    return (r.image > 0) & (np.sqrt(r.variance) <= 0.2 * r.image)


def _assert_agrees(r, ref, coverage):
    """Two independent unbiased renders of one view agree: every pixel channel in the CLT
    regime of both (at least ``coverage`` of them) within the Bonferroni threshold, and
    the image means within 4 SE."""
    n_pix = r.image.shape[0] * r.image.shape[1]
    diff = r.image - ref.image
    se = np.sqrt(r.variance + ref.variance)
    clt = _in_clt_regime(r) & _in_clt_regime(ref)
    assert clt.mean() >= coverage, f"only {clt.mean():.3f} of pixels compared"
    z = bonferroni_z(n_pix * 3)
    bad = clt & (np.abs(diff) > z * se)
    assert bad.sum() == 0, f"{bad.sum()} pixel channels beyond {z:.2f} SE"
    mean_se = math.sqrt(luminance_variance(r.variance + ref.variance).sum()) / n_pix
    assert abs(luminance(diff).mean() / mean_se) < 4


@pytest.mark.parametrize("name", ["cornell", "garage"])
def test_all_methods_agree_per_pixel_and_per_image(small_setups, name):
    setup = small_setups[name]
    spp, coverage = AGREEMENT[name]["spp"], AGREEMENT[name]["coverage"]
    results = {m: _render(setup, m, spp[m], seed=11 + i) for i, m in enumerate(METHODS)}
    for r in results.values():
        assert np.isfinite(r.image).all() and (r.image >= 0).all()
        assert np.isfinite(r.variance).all() and (r.variance >= 0).all()
    n_pix = setup.camera.width * setup.camera.height
    z = bonferroni_z(n_pix * 3)
    ref = results["mis"]
    assert luminance(ref.image).mean() > 0.01, "the scene must be lit"
    for m in ("env", "bsdf", "product"):
        r = results[m]
        diff = r.image - ref.image
        se = np.sqrt(r.variance + ref.variance)
        clt = _in_clt_regime(r) & _in_clt_regime(ref)
        assert clt.mean() >= coverage[m], f"{name}/{m}: only {clt.mean():.3f} of pixels compared"
        bad = clt & (np.abs(diff) > z * se)
        assert bad.sum() == 0, f"{name}/{m}: {bad.sum()} pixel channels beyond {z:.2f} SE"
        # Whole image: mean luminance, whose variance is the sum of pixel variances / N^2.
        mean_diff = luminance(diff).mean()
        mean_se = math.sqrt(luminance_variance(r.variance + ref.variance).sum()) / n_pix
        apart = mean_diff / mean_se
        assert abs(apart) < 4, f"{name}/{m}: image means {apart:.2f} SE apart"


def _furnace_setup(albedo):
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    scene = vc.Scene()
    scene.add_mesh(sphere.vertices, sphere.faces, material=vc.Material.lambert(albedo))
    camera = vc.Camera.look_at((0, 0, 4), (0, 0, 0), fov_deg=35.0, width=32, height=32)
    env = vc.envmaps.constant((1.0, 1.0, 1.0), resolution=32)
    return vc.Setup(scene, camera, env, name="furnace")


@pytest.mark.parametrize("method", METHODS)
def test_furnace_white_sphere_in_a_constant_environment(method):
    albedo = (0.8, 0.5, 0.3)
    setup = _furnace_setup(albedo)
    r = _render(setup, method, 64)
    g = setup.scene.gbuffer(setup.camera, jitter=False)
    hit = g["object"] == 0
    # Pixels whose 3x3 neighbourhood all hit the sphere: no jittered ray can miss it.
    inner = hit.copy()
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            inner &= np.roll(np.roll(hit, dy, 0), dx, 1)
    assert inner.sum() > 200
    img, se = r.image[inner], np.sqrt(r.variance[inner])
    err = np.abs(img - np.asarray(albedo, dtype=np.float32))
    # Channels are scaled copies of one estimate: one test per pixel. The 1e-5 absorbs f32
    # rounding where the estimator has zero variance (BSDF sampling of a Lambertian).
    z = bonferroni_z(int(inner.sum()))
    assert (err <= z * se + 1e-5).all(), f"{method}: worst {np.max(err / (se + 1e-12)):.2f} SE"


def test_extremes_give_finite_images():
    scene = vc.Scene()
    scene.add_mesh(
        np.array([[-5, 0, -5], [5, 0, -5], [5, 0, 5], [-5, 0, 5]], dtype=np.float32),
        [[0, 2, 1], [0, 3, 2]],
        material=vc.Material.phong((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), 1e4),
    )
    scene.add_mesh(
        np.array([[-1, 0, 0], [1, 0, 0], [0, 2, 0]], dtype=np.float32),
        [[0, 1, 2]],
        material=vc.Material.phong((0.5, 0.5, 0.5), (0.5, 0.5, 0.5), 1e4),
    )
    camera = vc.Camera.look_at((0, 2, 6), (0, 0, 0), width=24, height=18)
    sun = vc.envmaps.sky(sun_dir=(0.3, 1.0, -0.5), sun_radiance=1e6, resolution=64)
    for method in METHODS:
        r = vc.render(vc.Setup(scene, camera, sun), spp=4, method=method, progress=False)
        assert np.isfinite(r.image).all() and np.isfinite(r.variance).all(), method


def test_bit_identical_for_any_thread_count(small_setups):
    setup = small_setups["garage"]
    for method in METHODS:
        a = _render(setup, method, 3, seed=7, threads=1)
        b = _render(setup, method, 3, seed=7, threads=2)
        assert np.array_equal(a.image, b.image) and np.array_equal(a.variance, b.variance), method
    c = _render(setup, "mis", 3, seed=8)
    assert not np.array_equal(c.image, a.image)


@pytest.mark.parametrize("method", ["product", "cv"])
def test_light_samples_stay_unbiased_and_cut_the_variance(small_setups, method):
    # Four light draws per sample against MIS (independent seeds): every pixel channel in
    # the CLT regime within the Bonferroni threshold, the image means within 4 SE; and at
    # equal spp the draws' average leaves less variance than one draw does.
    setup = small_setups["garage"]
    ref = _render(setup, "mis", 256, seed=3)
    one = _render(setup, method, 64, seed=4)
    four = _render(setup, method, 64, seed=5, light_samples=4)
    assert four.stats["light_samples"] == 4 and one.stats["light_samples"] == 1
    assert four.stats["shadow_rays"] > 3 * one.stats["shadow_rays"]
    _assert_agrees(four, ref, coverage=0.45)
    ratio = four.variance.mean() / one.variance.mean()
    assert ratio < 0.5, f"variance with four draws {ratio:.2f}x one draw's"


def test_budgeted_product_renders_learn_their_mixture_and_stay_unbiased(small_setups):
    # Under a time budget method "product" learns its mixture weights from the probe pass
    # (reported); later samples use them. Against MIS at 256 spp (independent seeds): every
    # pixel channel in the CLT regime within the Bonferroni threshold, the means within 4 SE.
    setup = small_setups["garage"]
    ref = _render(setup, "mis", 256, seed=3)
    # A budget the render cannot spend, so that it takes its 200 samples a pixel on average
    # on any machine, however loaded (the adaptive pilot gives each pixel a quarter).
    r = vc.render(setup, method="product", time_budget=60.0, spp=200, seed=9, progress=False)
    w = r.stats["learnt_weights"]
    assert w is not None and abs(sum(w.values()) - 1.0) < 1e-5 and w["guided"] == 0.0
    assert min(w["product"], w["bsdf"], w["env"]) >= 0.05 - 1e-6
    assert r.stats["mean_spp"] == 200 and r.stats["spp"] >= 50
    _assert_agrees(r, ref, coverage=0.45)
    # Off, and for other methods or without a budget, nothing is learnt.
    off = vc.render(setup, method="product", time_budget=0.2, seed=9, progress=False,
                    learn_techniques=False)
    assert off.stats["learnt_weights"] is None
    assert _render(setup, "product", 4).stats["learnt_weights"] is None


def test_budgeted_product_renders_choose_light_draws_from_the_view():
    # Without a count, a budgeted product render reads its view's edge share from the
    # anchors: a garage of smooth floor and walls splits every sample into light draws
    # (at most 8, as many as its probe finds best: 4-5 at this size), grass keeps one.
    # The split image stays unbiased (against MIS as above).
    garage = vc.scenes.load("garage", detail=0.3)
    garage.camera = garage.camera.with_resolution(96, 72)
    r = vc.render(garage, method="product", time_budget=0.6, seed=13, progress=False)
    assert 2 <= r.stats["light_samples"] <= 8 and 0.05 < r.stats["edge_share"] < 0.275
    assert r.stats["shadow_rays"] > 1.5 * r.stats["samples"]
    ref = _render(garage, "mis", 256, seed=3)
    _assert_agrees(r, ref, coverage=0.45)
    garden = vc.scenes.load("garden", detail=0.3)
    garden.camera = garden.camera.with_resolution(48, 36)
    g = vc.render(garden, method="product", time_budget=0.2, seed=13, progress=False)
    assert g.stats["light_samples"] == 1 and g.stats["edge_share"] > 0.9
    # A count given is kept; without a budget, or for method "mis", nothing is chosen;
    # method "cv" chooses as "product" does.
    given = vc.render(garage, method="product", time_budget=0.2, light_samples=2,
                      progress=False)
    assert given.stats["light_samples"] == 2 and given.stats["edge_share"] is None
    plain = _render(garage, "product", 4)
    assert plain.stats["light_samples"] == 1 and plain.stats["edge_share"] is None
    cv = vc.render(garage, method="cv", time_budget=0.3, progress=False)
    assert cv.stats["light_samples"] >= 2 and cv.stats["edge_share"] == r.stats["edge_share"]
    mis = vc.render(garage, method="mis", time_budget=0.1, progress=False)
    assert mis.stats["light_samples"] == 1 and mis.stats["edge_share"] is None


def test_views_of_grass_draw_from_coarser_products_and_stay_unbiased():
    # Garden's jittered samples mostly leave their anchor's blade (edge share above 0.4):
    # its Lambert grass draws from 16^2 products, also under the control variate when its
    # "auto" cache keeps no records (the coherence check); garage's smooth surfaces keep
    # 32^2, as do fixed points, a level given and a control variate with records. Either
    # way unbiased: the coarse image agrees with MIS (independent seeds) per pixel and in
    # its mean.
    garden = vc.scenes.load("garden", detail=0.3)
    garden.camera = garden.camera.with_resolution(48, 36)
    coarse = _render(garden, "product", 64, seed=21)
    assert coarse.stats["coarse_products"] and coarse.stats["edge_share"] is None
    ref = _render(garden, "mis", 256, seed=5)
    _assert_agrees(coarse, ref, coverage=0.45)
    for kw in ({"jitter": False}, {"product_level": 5}):
        assert not _render(garden, "product", 2, **kw).stats["coarse_products"]
    no_records = _render(garden, "cv", 2)
    assert no_records.stats["cache_records"] == 0 and no_records.stats["coarse_products"]
    records = vc.VisibilityCache(garden.scene, preset="low", nearest_hits=False)
    records.build(camera=garden.camera, progress=False)
    assert len(records) > 0
    assert not _render(garden, "cv", 2, cache=records).stats["coarse_products"]
    garage = vc.scenes.load("garage", detail=0.3)
    garage.camera = garage.camera.with_resolution(48, 36)
    assert not _render(garage, "product", 2).stats["coarse_products"]


def test_the_probe_takes_fewer_draws_where_they_are_dear_and_the_hits_vary():
    # The Cornell box splits by its edge share, but a draw there traces two shadow rays
    # (the closed box's map and the ceiling light) against a primary ray into 1,262
    # triangles, and the light's edge and the blocks' silhouettes make the hits vary:
    # its probe measures about 2.4 draws as best (two-stage optimum, render/split.rs),
    # where garage's light noise outweighs its hits' (4-8 draws, above). The optimum
    # weighs a cost ratio measured in CPU time (1.5-4.1 draws under a loaded machine)
    # and a variance ratio that is a fixed function of the seed: the test holds the
    # first to its definition and the second to what it says of the two scenes.
    box = vc.scenes.load("cornell")
    box.camera = box.camera.with_resolution(160, 120)
    r = vc.render(box, method="product", time_budget=0.5, seed=5, progress=False)
    s = r.stats
    assert s["edge_share"] < 0.275
    cost, variance = s["probe_cost_ratio"], s["probe_variance_ratio"]
    assert cost > 0 and math.isclose(s["probe_draws"], math.sqrt(cost * variance),
                                     rel_tol=1e-12)
    assert s["light_samples"] == min(max(round(s["probe_draws"]), 1), 8)
    # The variance ratio is the seed's, whatever the budget, thread count and timing.
    again = vc.render(box, method="product", time_budget=0.3, seed=5, threads=1,
                      progress=False)
    assert again.stats["probe_variance_ratio"] == variance
    # The hits vary: even where the rest of a sample cost as much as a draw, an optimum
    # below four draws; garage's draws explain more of its variance than the box's do.
    assert math.sqrt(variance) < 4
    garage = vc.scenes.load("garage", detail=0.3)
    garage.camera = garage.camera.with_resolution(96, 72)
    g = vc.render(garage, method="product", time_budget=0.6, seed=13, progress=False)
    assert g.stats["probe_variance_ratio"] > 2 * variance
    # Draws per sample changed after the probe's samples: the image stays unbiased.
    ref = _render(box, "mis", 64, seed=3)
    _assert_agrees(r, ref, coverage=0.45)


def test_light_samples_are_bit_identical_for_any_thread_count(small_setups):
    setup = small_setups["garage"]
    for method in ("product", "cv"):
        a = _render(setup, method, 20, seed=7, threads=1, light_samples=3)
        b = _render(setup, method, 20, seed=7, threads=2, light_samples=3)
        assert np.array_equal(a.image, b.image) and np.array_equal(a.variance, b.variance)


@pytest.mark.parametrize("method", ["product", "cv"])
def test_adaptive_counts_stay_unbiased_and_follow_the_error(small_setups, method):
    # A pilot of a quarter of the samples, then shares from the neighbours' relative
    # variance: against MIS (independent seeds) every pixel channel in the CLT regime
    # within the Bonferroni threshold and the means within 4 SE; the counts average spp,
    # none below the pilot or above 16x the mean; noisy regions take more than quiet ones;
    # and the image's relMSE against a converged render is
    # below that of even counts at the same total.
    setup = small_setups["garage"]
    n = setup.camera.width * setup.camera.height
    ref = _render(setup, "mis", 1024, seed=3)
    spp = 64
    even = _render(setup, method, spp, seed=21)
    r = _render(setup, method, spp, seed=21, adaptive=True)
    counts = r.sample_counts
    assert counts.shape == (setup.camera.height, setup.camera.width)
    assert counts.dtype == np.uint32 and int(counts.sum()) == r.stats["samples"]
    assert spp * n - n <= counts.sum() <= spp * n
    assert counts.min() >= spp // 4 and counts.min() == r.stats["spp"]
    assert counts.max() <= 16 * spp
    assert r.stats["adaptive"] and not even.stats["adaptive"]
    assert (even.sample_counts == spp).all()
    # The relative variance of one sample that the even render measured, pooled over
    # each 5x5 window: the quarter of pixels where it is highest take on average more than
    # twice the samples of the quarter where it is lowest.
    v = (even.variance * spp / (even.image.astype(np.float64) ** 2 + 1e-2)).mean(axis=-1)
    pooled = sum(np.roll(np.roll(v, dy, 0), dx, 1) for dy in range(-2, 3) for dx in range(-2, 3))
    low, high = np.quantile(pooled, [0.25, 0.75])
    assert counts[pooled >= high].mean() > 2 * counts[pooled <= low].mean()
    # Unbiased: the mean of 32 independent adaptive renders against MIS, each pixel's
    # error judged by the spread over the renders (a pixel's own variance estimate is
    # least reliable where its count is low, which the counts make likelier).
    runs = np.stack([_render(setup, method, spp, seed=100 + k, adaptive=True).image
                     for k in range(32)]).astype(np.float64)
    mean, sem = runs.mean(0), runs.std(0, ddof=1) / math.sqrt(len(runs))
    se = np.sqrt(sem**2 + ref.variance)
    clt = (mean > 0) & (sem <= 0.2 * mean) & _in_clt_regime(ref)
    assert clt.mean() >= 0.45, f"only {clt.mean():.3f} of pixels compared"
    t = student_t_bonferroni(n * 3, dof=len(runs) - 1)
    bad = clt & (np.abs(mean - ref.image) > t * se)
    assert bad.sum() == 0, f"{bad.sum()} pixel channels beyond {t:.2f} SE"
    image_means = luminance(runs).mean(axis=(1, 2))
    image_se = math.hypot(image_means.std(ddof=1) / math.sqrt(len(runs)),
                          math.sqrt(luminance_variance(ref.variance).sum()) / n)
    assert abs(image_means.mean() - luminance(ref.image).mean()) < 4 * image_se
    from viscache_rs.metrics import relmse
    e_even, e_adaptive = relmse(even.image, ref.image), relmse(r.image, ref.image)
    assert e_adaptive < 0.8 * e_even, f"{e_adaptive:.3g} against {e_even:.3g}"


def test_hits_off_their_anchor_draw_from_products_by_normal_and_stay_unbiased():
    # Grass: most jittered samples land on another blade than their pixel's anchor and
    # draw from the product of the nearest grid normal. Against MIS (independent seeds):
    # every pixel channel in the CLT regime within the Bonferroni threshold, the means
    # within 4 SE; and at equal samples less variance than MIS's two rays per sample
    # (measured 0.86x; the mean of 768 pixels' variances is within about 1% of its own).
    setup = vc.scenes.load("garden", detail=0.1)
    setup.camera = setup.camera.with_resolution(32, 24)
    ref = _render(setup, "mis", 512, seed=3)
    r = _render(setup, "product", 256, seed=4)
    assert r.stats["unmatched_samples"] > 0.3 * r.stats["samples"]
    _assert_agrees(r, ref, coverage=0.8)
    mis = _render(setup, "mis", 256, seed=5)
    ratio = r.variance.mean() / mis.variance.mean()
    assert ratio < 0.95, f"variance {ratio:.2f}x MIS's"


def test_adaptive_counts_are_bit_identical_for_any_thread_count(small_setups):
    setup = small_setups["garage"]
    for method in ("product", "cv", "mis"):
        a = _render(setup, method, 24, seed=7, threads=1, adaptive=True)
        b = _render(setup, method, 24, seed=7, threads=2, adaptive=True)
        assert np.array_equal(a.image, b.image) and np.array_equal(a.variance, b.variance)
        assert np.array_equal(a.sample_counts, b.sample_counts)
        assert a.sample_counts.min() < a.sample_counts.max(), method


def test_budgets_adapt_by_default(small_setups):
    setup = small_setups["garage"]
    r = vc.render(setup, method="product", time_budget=0.3, spp=128, seed=9, progress=False)
    assert r.stats["adaptive"] and r.stats["passes"] >= 3
    # Each pixel's mixture was chosen after the pilot (the image's first, then 10 others).
    mixtures = r.stats["pixel_mixtures"]
    assert len(mixtures) == 11 and sum(mixtures) == setup.camera.width * setup.camera.height
    assert r.stats["spp"] < r.stats["mean_spp"] < r.stats["max_spp"] <= 16 * 128
    assert r.stats["mean_spp"] <= 128
    off = vc.render(setup, method="product", time_budget=0.3, spp=128, seed=9,
                    progress=False, adaptive=False)
    assert not off.stats["adaptive"] and (off.sample_counts == off.stats["spp"]).all()
    assert off.stats["pixel_mixtures"] is None
    # Short renders take their samples evenly.
    short = _render(setup, "product", 7, adaptive=True)
    assert (short.sample_counts == 7).all()


def test_stats_time_budget_and_progress(small_setups):
    setup = small_setups["cornell"]
    r = _render(setup, "mis", 4, jitter=False)
    s = r.stats
    n = setup.camera.width * setup.camera.height
    # One shading point per pixel: one primary ray per pixel and pass (a single pass here).
    assert s["spp"] == 4 and s["samples"] == 4 * n and s["primary_rays"] == n
    assert s["passes"] == 1 and s["complete"] and not s["jitter"]
    # Jittered (the default): a primary ray per sample, and for the product methods one more
    # per pixel through its centre, the anchor that their per-pixel work is done at.
    jittered = _render(setup, "mis", 4).stats
    assert jittered["jitter"] and jittered["samples"] == 4 * n
    assert jittered["primary_rays"] == 4 * n
    assert _render(setup, "product", 4).stats["primary_rays"] == 5 * n
    assert s["shadow_rays"] > 0 and s["bsdf_rays"] > 0 and s["seconds"] > 0
    assert s["primary_seconds"] > 0 and s["direct_seconds"] > 0
    # The samples' own primary rays are a part of their shading, and only jittered ones
    # trace them.
    assert s["sample_primary_seconds"] == 0
    assert 0 < jittered["sample_primary_seconds"] < jittered["shading_seconds"]
    # A budget stops after the pass that spends it and says how far it got.
    r = vc.render(setup, method="env", time_budget=0.05, progress=False)
    assert 1 <= r.stats["spp"] < 1 << 20
    assert np.isfinite(r.image).all()
    # A budget spent by the probe pass still gives every pixel a sample.
    tiny = vc.render(setup, method="product", time_budget=1e-9, progress=False)
    assert tiny.stats["spp"] >= 1 and np.isfinite(tiny.image).all()
    # One sample: the variance of the mean is unknown (infinite).
    assert np.isinf(_render(setup, "env", 1).variance).all()
    # The progress bar runs (tqdm writes to stderr).
    vc.render(setup, spp=2, method="env", progress=True)


@pytest.mark.parametrize(
    ("kwargs", "exc", "needle"),
    [
        ({"method": "whitted"}, ValueError, 'method.*"vpl", "vpl_sampled"'),
        ({"spp": 0}, ValueError, "spp"),
        ({"spp": 2.5}, TypeError, "spp"),
        ({"time_budget": -1.0}, ValueError, "time_budget"),
        ({"time_budget": float("nan")}, ValueError, "time_budget"),
        ({"threads": 0}, ValueError, "threads"),
        ({"seed": -1}, ValueError, "seed"),
        ({"product_level": 0}, ValueError, "product_level"),
        ({"method": "product", "light_samples": 0}, ValueError, "light_samples"),
        ({"method": "product", "light_samples": 65}, ValueError, "light_samples"),
        ({"method": "product", "light_samples": 2.5}, TypeError, "light_samples"),
        ({"method": "mis", "light_samples": 2}, ValueError, "light_samples.*product"),
        ({"adaptive": "yes"}, TypeError, "adaptive"),
        ({"method": "vpl", "adaptive": True}, ValueError, "adaptive"),
    ],
)
def test_bad_arguments_name_themselves(small_setups, kwargs, exc, needle):
    with pytest.raises(exc, match=needle):
        vc.render(small_setups["cornell"], progress=False, **{"spp": 1, **kwargs})


def test_the_registry_lists_every_method_and_refuses_what_a_method_ignores(small_setups):
    table = {m["name"]: m for m in vc.methods()}
    assert list(table) == ["env", "bsdf", "mis", "product", "cv", "path", "irradiance_cache",
                           "vpl", "vpl_sampled", "importance_cache", "vf",
                           "stochastic"]
    assert table["cv"]["caches"] == ["VisibilityCache"]
    assert table["irradiance_cache"]["caches"] == ["IrradianceCache"]
    assert table["importance_cache"]["caches"] == ["ImportanceCache"]
    assert all(not m["caches"] for name, m in table.items()
               if name not in ("cv", "irradiance_cache", "importance_cache"))
    assert (table["path"]["min_bounces"], table["path"]["default_bounces"]) == (1, 1)
    assert table["vpl"]["estimator"] == "many_lights"
    assert (table["mis"]["default_spp"], table["vpl"]["default_spp"]) == (16, 1)
    setup = small_setups["cornell"]
    # The core serves every row, and checks what a row does not read itself: a Rust
    # caller gets the same refusals as vc.render.
    cam = setup.camera.with_resolution(8, 6)
    out = vc._core.render(setup.scene, setup.envmap, cam, method="vpl")
    assert (out["sample_counts"] == 1).all() and out["stats"]["method"] == "vpl"
    assert out["stats"]["vpls"] > 0 and out["alpha"] is None
    with pytest.raises(ValueError, match=r'^clamp: method "mis"'):
        vc._core.render(setup.scene, setup.envmap, cam, method="mis", clamp=1.0)
    with pytest.raises(ValueError, match=r"^bounces"):
        vc._core.render(setup.scene, setup.envmap, cam, method="path", bounces=0)
    cache = vc.VisibilityCache(setup.scene, preset="low")
    # A cache for a method that takes none; a parameter only other methods read.
    with pytest.raises(ValueError, match=r'^cache: method "product" takes no cache'):
        vc.render(setup, spp=1, method="product", cache=cache, progress=False)
    takers = r'methods that do: \["cv", "importance_cache"\]'
    with pytest.raises(ValueError, match=r'^alpha: method "mis".*' + takers):
        vc.render(setup, spp=1, method="mis", alpha=0.5, progress=False)
    with pytest.raises(ValueError, match=r'^vpls: method "cv"'):
        vc.render(setup, spp=1, method="cv", vpls=object(), progress=False)
    with pytest.raises(TypeError, match="^cache"):
        vc.render(setup, spp=1, method="cv", cache=object(), progress=False)
    # Parameters at their defaults are not "given": any method accepts them.
    r = vc.render(setup, spp=1, method="mis", alpha=1.0, product_level="auto", progress=False)
    assert r.stats["method"] == "mis"
