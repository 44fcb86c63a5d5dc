"""The G-buffer flows down: traced once by ``Scene.gbuffer`` and handed to the cache build,
the renderer, AO and the preview, which then trace no primary ray of their own and work at
exactly its points."""

import numpy as np
import pytest
import viscache_rs as vc

W, H = 40, 30


@pytest.fixture(scope="module")
def garage():
    setup = vc.scenes.load("garage")
    cam = setup.camera.with_resolution(W, H)
    return setup, cam, setup.scene.gbuffer(cam, jitter=False)


def _render(setup, **kw):
    return vc.render(setup, progress=False, threads=2, **kw)


def test_reads_like_a_dict_of_arrays(garage):
    setup, cam, g = garage
    assert isinstance(g, vc.GBuffer)
    assert (g.width, g.height, g.jittered, g.seed) == (W, H, False, 0)
    assert g.camera.width == W and g.camera.eye == cam.eye
    assert list(g) == g.keys() == ["position", "normal", "direction", "object", "prim",
                                   "depth", "footprint"]
    d = g.as_dict()
    for key in g:
        assert key in g
        np.testing.assert_array_equal(d[key], g[key])
    assert g["position"].shape == (H, W, 3) and g["object"].dtype == np.int32
    assert g.covered_pixels == int((g["object"] >= 0).sum()) > 0
    assert "uv" not in g
    with pytest.raises(KeyError, match="uv"):
        g["uv"]
    # The arrays are copies: editing one changes nothing the buffer holds.
    g["position"][:] = 0
    assert np.nanmax(np.abs(g["position"])) > 0
    assert "covered_pixels=" in repr(g)


def test_cache_built_from_the_gbuffer_is_the_camera_build(garage, tmp_path):
    setup, cam, g = garage
    files = []
    for kw in (dict(camera=cam), dict(gbuffer=g), dict(camera=cam, gbuffer=g)):
        cache = vc.VisibilityCache(setup.scene)
        report = cache.build(seed=1, threads=2, progress=False, **kw)
        assert report["records"] > 0 and report["covered_pixels"] == g.covered_pixels
        path = tmp_path / f"c{len(files)}.bin"
        cache.save(path)
        files.append(path.read_bytes())
    assert files[0] == files[1] == files[2]


@pytest.mark.parametrize("method, jitter", [("product", True), ("product", False),
                                            ("cv", True), ("cv", False), ("mis", False)])
def test_render_from_the_gbuffer_is_bit_identical_and_traces_no_anchor(garage, method, jitter):
    setup, cam, g = garage
    cache = None
    if method == "cv":
        cache = vc.VisibilityCache(setup.scene)
        cache.build(gbuffer=g, progress=False)
    kw = dict(method=method, spp=3, seed=4, jitter=jitter)
    a = _render(setup, camera=cam, cache=cache, **kw)
    b = _render(setup, gbuffer=g, cache=cache, **kw)
    np.testing.assert_array_equal(a.image, b.image)
    np.testing.assert_array_equal(a.variance, b.variance)
    n = W * H
    # Given the buffer, the render traces a primary ray per jittered sample only.
    assert a.stats["primary_rays"] == n + (3 * n if jitter else 0)
    assert b.stats["primary_rays"] == (3 * n if jitter else 0)


def test_cv_without_a_cache_traces_one_gbuffer(garage):
    setup, cam, g = garage
    # Enough samples to repay the records (at 2 spp the build would insert none).
    kw = dict(method="cv", spp=64, seed=9, jitter=False)
    own = _render(setup, camera=cam, **kw)
    given = _render(setup, gbuffer=g, **kw)
    np.testing.assert_array_equal(own.image, given.image)
    assert own.stats["cache_records"] == given.stats["cache_records"] > 0
    n = W * H
    assert own.stats["primary_rays"] == n and given.stats["primary_rays"] == 0


def test_jittered_anchors_keep_the_estimate_unbiased(garage):
    """Anchors anywhere in the pixel only move where the per-pixel work is done: the
    product mixture and the control variate stay unbiased for the antialiased image."""
    setup, cam, g = garage
    jittered = setup.scene.gbuffer(cam, seed=5, jitter=True)
    assert jittered.jittered and jittered.seed == 5
    cache = vc.VisibilityCache(setup.scene)
    cache.build(gbuffer=g, progress=False)
    for method in ("product", "cv"):
        kw = dict(method=method, spp=32, cache=cache if method == "cv" else None)
        centre = _render(setup, gbuffer=g, seed=21, **kw)
        moved = _render(setup, gbuffer=jittered, seed=22, **kw)
        diff = centre.image.mean(axis=(0, 1)) - moved.image.mean(axis=(0, 1))
        se = np.sqrt((centre.variance.sum(axis=(0, 1)) + moved.variance.sum(axis=(0, 1)))
                     / (W * H) ** 2)
        assert np.all(np.abs(diff) < 4 * se), (method, diff, se)


def test_ao_and_preview_from_the_gbuffer(garage):
    setup, cam, g = garage
    ref = [vc.render_ao(setup, reference_rays=16, progress=False, **kw).image
           for kw in (dict(camera=cam), dict(gbuffer=g))]
    np.testing.assert_array_equal(ref[0], ref[1])
    images = []
    for kw in (dict(camera=cam), dict(gbuffer=g)):
        cache = vc.VisibilityCache(setup.scene, preset="medium")
        images.append(vc.render_ao(setup, cache=cache, progress=False, **kw).image)
    np.testing.assert_array_equal(images[0], images[1])
    cache = vc.VisibilityCache(setup.scene)
    cache.build(gbuffer=g, progress=False)
    a = vc.preview(setup, cache, camera=cam)
    b = vc.preview(setup, cache, gbuffer=g)
    np.testing.assert_array_equal(a, b)
    assert vc.LightingPreview(setup.scene, gbuffer=g).size == (W, H)


def test_a_gbuffer_of_another_scene_pose_or_camera_is_refused(garage):
    setup, cam, g = garage
    other = vc.scenes.load("cornell")
    with pytest.raises(ValueError, match="^gbuffer"):
        _render(other, gbuffer=g, method="product", spp=1)
    with pytest.raises(ValueError, match="^gbuffer"):
        vc.VisibilityCache(other.scene).build(gbuffer=g, progress=False)
    with pytest.raises(ValueError, match="^gbuffer"):
        vc.LightingPreview(other.scene, gbuffer=g)
    with pytest.raises(ValueError, match="^gbuffer"):
        vc.render_ao(other, gbuffer=g, reference_rays=4, progress=False)
    with pytest.raises(ValueError, match="^gbuffer"):
        _render(setup, camera=cam.with_resolution(20, 15), gbuffer=g, method="mis", spp=1)
    with pytest.raises(ValueError, match="^gbuffer"):
        vc.VisibilityCache(setup.scene).build(cam.with_resolution(20, 15), gbuffer=g,
                                              progress=False)
    with pytest.raises(TypeError, match="gbuffer"):
        _render(setup, gbuffer=g.as_dict(), method="mis", spp=1)
    with pytest.raises(ValueError, match="^camera"):
        vc.VisibilityCache(setup.scene).build(progress=False)
    # A moved object is another pose: a buffer of frame 0 does not describe frame 30.
    moving = vc.scenes.load("dynamics", animated=True)
    small = moving.camera.with_resolution(16, 12)
    g0 = moving.scene.gbuffer(small, jitter=False)
    moving.at_frame(30)
    with pytest.raises(ValueError, match="^gbuffer.*pose"):
        _render(moving, gbuffer=g0, method="product", spp=1)
    moving.at_frame(0)
    _render(moving, gbuffer=g0, method="product", spp=1)
