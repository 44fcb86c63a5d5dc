"""The lighting preview's cached transfer (issue 27): kept whole it gives the direct
preview's J; rotations, swaps and other map resolutions cost one projection; it follows
its cache (reused while unchanged, rebuilt after a change, refused for another scene);
material edits rebuild their object's pixels; bad input names its argument."""

import numpy as np
import pytest
import viscache_rs as vc


@pytest.fixture(scope="module")
def garage():
    setup = vc.scenes.load("garage", detail=0.3)
    setup.camera = setup.camera.with_resolution(40, 30)
    cache = vc.VisibilityCache(setup.scene)
    cache.build(setup.camera, seed=0, progress=False)
    return setup, cache


def _tinted(env, colour):
    """``env``'s luminance in one colour: the direct preview's per-region colours are then
    exact, so both previews integrate the same ``J``."""
    t = env.texels()
    y = t @ np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)
    return vc.EnvMap.from_octahedral(y[..., None] * np.asarray(colour, np.float32))


def _rel(a, b):
    scale = np.abs(b).max()
    return float((np.abs(a - b) / np.maximum(np.abs(b), 1e-3 * scale)).max())


def test_untruncated_transfer_equals_direct_preview(garage):
    setup, cache = garage
    view = vc.LightingPreview(setup.scene, setup.camera)
    info = view.prepare(cache, basis="full", product_level="auto", nearest=False)
    assert info["basis"] == "texels" and info["basis_level"] == info["level"]
    env = _tinted(setup.envmap, (1.0, 0.7, 0.4))
    for degrees in (0.0, 45.0, 135.0):
        turned = env.rotated(degrees)
        a = view.render(cache, turned)
        b = view.render(cache, turned, direct=True)
        assert _rel(a, b) < 1e-5, degrees
    # Every Haar term kept: an orthogonal change of basis, the same J but for the values'
    # 15-bit rounding (bounded per pixel in the Rust tests; here: far below the preview's
    # own error).
    info = view.prepare(cache, basis="haar", budget_mb=1e6, product_level="auto",
                        nearest=False)
    assert info["terms"] == 4 ** info["level"]
    a, b = view.render(cache, env), view.render(cache, env, direct=True)
    assert np.abs(a - b).max() < 1e-3 * np.abs(b).max()


def test_rotation_and_other_resolutions(garage):
    setup, cache = garage
    view = vc.LightingPreview(setup.scene, setup.camera)
    env = setup.envmap
    by_degrees = view.render(cache, env, rotation=30.0)
    c, s = np.cos(np.radians(30.0)), np.sin(np.radians(30.0))
    matrix = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    assert np.array_equal(view.render(cache, env, rotation=matrix), by_degrees)
    assert np.array_equal(view.render(cache, env, rotation=360.0),
                          view.render(cache, env, rotation=np.eye(3)))
    # Turning the map beforehand resamples it; the render bins texels instead.
    turned = view.render(cache, env.rotated(30.0))
    assert np.abs(by_degrees - turned).sum() < 0.01 * np.abs(turned).sum()
    # Maps of any resolution project exactly: a constant map at 8 and at 256 texels.
    lo = view.render(cache, vc.envmaps.constant((0.3, 0.5, 0.9), resolution=8))
    hi = view.render(cache, vc.envmaps.constant((0.3, 0.5, 0.9), resolution=256))
    assert _rel(lo, hi) < 1e-5


def test_transfer_follows_its_cache_and_traces_no_rays(garage):
    setup, _ = garage
    cache = vc.VisibilityCache(setup.scene)
    cache.build(setup.camera, seed=0, progress=False)
    view = vc.LightingPreview(setup.scene, setup.camera)
    assert view.transfer_info is None
    one = view.render(cache, setup.envmap, threads=1)  # prepares (tracing a few records)
    first = view.transfer_info
    setup.scene.counting = True
    try:
        setup.scene.reset_counters()
        assert np.array_equal(view.render(cache, setup.envmap, threads=2), one)
        two = view.render(cache, setup.envmap.rotated(90.0), threads=2)
        assert setup.scene.counters()["rays"] == 0, "after preparation, no rays"
    finally:
        setup.scene.counting = False
    assert first is not None and view.transfer_info == first, "reused"
    assert not np.allclose(one, two)
    cache.insert((0.0, 0.01, 0.0), (0.0, 1.0, 0.0))
    view.render(cache, setup.envmap)
    second = view.transfer_info
    assert second["seconds"] != first["seconds"], "rebuilt after an insertion"
    cache.build(setup.camera, seed=1, progress=False)
    view.render(cache, setup.envmap)
    assert view.transfer_info["seconds"] != second["seconds"], "rebuilt after a build"
    other = vc.scenes.load("cornell", detail=0.3)
    foreign = vc.VisibilityCache(other.scene)
    foreign.build(other.camera.with_resolution(16, 12), progress=False)
    with pytest.raises(ValueError, match="^cache: was built for another scene"):
        view.render(foreign, setup.envmap)


def test_truncated_bases_and_auto(garage):
    setup, cache = garage
    view = vc.LightingPreview(setup.scene, setup.camera)
    env = setup.envmap
    exact = view.render(cache, env, direct=False)  # 40x30 fits whole in 200 MB
    assert view.transfer_info["basis_level"] == view.transfer_info["level"]
    budget = 40 * 30 * (4 + 512) / 1e6  # 512 bytes a pixel
    errors = {}
    for basis in ("texels", "haar"):
        info = view.prepare(cache, env, basis=basis, budget_mb=budget)
        assert info["bytes"] <= budget * 1e6
        img = view.render(cache, env)
        errors[basis] = float(((img - exact) ** 2).sum() / (exact ** 2).sum())
    assert errors["haar"] < errors["texels"] and errors["haar"] < 0.01, errors
    info = view.prepare(cache, env, budget_mb=budget)
    assert sorted(k.rstrip("0123456789") for k in info["measured"]) == ["haar", "sh", "texels"]
    kept = next(v for k, v in info["measured"].items() if k.startswith(info["basis"]))
    assert kept <= 1.25 * min(info["measured"].values())
    assert info["basis"] == "haar"  # its window edges need all frequencies


def test_material_edit_rebuilds_its_pixels(garage):
    setup, cache = garage
    scene = vc.scenes.load("garage", detail=0.3).scene
    view = vc.LightingPreview(scene, setup.camera)
    view.prepare(cache, setup.envmap, nearest=False)
    obj = int(scene.gbuffer(setup.camera)["object"].max())
    shiny = vc.Material.phong(kd=(0.2, 0.3, 0.1), ks=(0.5, 0.5, 0.5), exponent=40.0)
    assert view.set_material(obj, shiny, cache=cache) > 0
    assert view.transfer_info is not None, "patched, not dropped"
    patched = view.render(cache, setup.envmap)
    scene.set_material(obj, shiny)
    fresh_view = vc.LightingPreview(scene, setup.camera)
    fresh_view.prepare(cache, setup.envmap, nearest=False)
    fresh = fresh_view.render(cache, setup.envmap)
    assert np.array_equal(patched, fresh)
    assert view.set_material(obj, shiny) > 0
    assert view.transfer_info is None, "dropped without the cache"


def test_visibility_form_is_measured(garage):
    setup, cache = garage
    view = vc.LightingPreview(setup.scene, setup.camera)
    info = view.prepare(cache, setup.envmap)
    m = info["visibility_measured"]
    assert info["nearest"] == (m["nearest"] < m["blend"])
    assert "visibility_measured" not in view.prepare(cache, setup.envmap, nearest=True)
    assert view.transfer_info["nearest"] is True


def test_sun_traces_rays_where_records_disagree(garage):
    """A truncated transfer adds a sun's cells per pixel: where a pixel's records disagree
    on the sun it traces shadow rays toward it (at most four a cell, at most `edge_rays`
    per pixel of the view a change), elsewhere it takes their answer; those rays are the
    only ones after preparation, and the image is the same for any thread count. Where
    the budget runs out the rays' sample judges the form of the rest; 0 traces none."""
    setup, cache = garage
    view = vc.LightingPreview(setup.scene, setup.camera)
    sky = vc.envmaps.sky(sun_dir=(0.4, 0.6, -0.5), resolution=128)
    info = view.prepare(cache, sky, basis="haar", budget_mb=40 * 30 * 300 / 1e6)
    assert info["basis"] == "haar" and view.last_bright is None
    setup.scene.counting = True
    try:
        for degrees in (0.0, 90.0, 200.0):
            setup.scene.reset_counters()
            one = view.render(cache, sky, rotation=degrees, threads=1)
            rays = setup.scene.counters()["rays"]
            b = view.last_bright
            assert b["cells"] >= 1 and b["rays"] == rays
            assert b["pixels"] <= rays <= min(4 * b["pixels"] * b["cells"], 40 * 30 / 16)
            assert 0 < b["pixels"] < 40 * 30
            if b["errors"] is not None:
                e = b["errors"]
                assert e["pixels"] >= 1 and b["nearest"] == (e["nearest"] < e["blend"])
            assert np.array_equal(view.render(cache, sky, rotation=degrees, threads=2), one)
        view.prepare(cache, sky, basis="haar", budget_mb=40 * 30 * 300 / 1e6, edge_rays=0)
        setup.scene.reset_counters()
        view.render(cache, sky, rotation=90.0)
        assert setup.scene.counters()["rays"] == 0
        assert view.last_bright["rays"] is None
    finally:
        setup.scene.counting = False


def test_bad_input_names_the_argument(garage):
    setup, cache = garage
    view = vc.LightingPreview(setup.scene, setup.camera)
    env = setup.envmap
    for rotation in (float("nan"), np.full((3, 3), np.nan), np.diag([1.0, 1.0, 2.0]),
                     np.diag([1.0, 1.0, -1.0]), np.eye(2), "x"):
        with pytest.raises(ValueError, match="^rotation"):
            view.render(cache, env, rotation=rotation)
    with pytest.raises(ValueError, match="^rotation"):
        view.render(cache, env, rotation=45.0, direct=True)
    with pytest.raises(ValueError, match="^budget_mb"):
        view.prepare(cache, basis="haar", budget_mb=1e-4)
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="^budget_mb"):
            view.prepare(cache, budget_mb=bad)
    for bad in (-1.0, -1e-9, float("nan"), float("inf"), "many"):
        with pytest.raises((ValueError, TypeError), match="^edge_rays"):
            view.prepare(cache, edge_rays=bad)
    with pytest.raises(ValueError, match="^basis"):
        view.prepare(cache, basis="wavelets")
    with pytest.raises(ValueError, match="^obj"):
        view.set_material(10_000, vc.Material.lambert((0.5, 0.5, 0.5)), cache=cache)
    with pytest.raises(ValueError, match="^product_level"):
        view.prepare(cache, product_level=0)
    # Nothing was kept by the refused calls.
    assert view.transfer_info is None
