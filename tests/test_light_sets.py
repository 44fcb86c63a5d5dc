"""Light sets beyond traced VPLs (``vc.VPLs``, survey ch. 6): an environment map as one
directional light per texel of a coarse octahedral level, directional lights (a sun), area
lights as one light each, unions ``a + b``, the share of a set that reaches the view, and
bad input."""

from __future__ import annotations

import numpy as np
import pytest
import viscache_rs as vc

KW = dict(jitter=False, threads=2, progress=False)


def lit_room(lights: int = 2) -> vc.Setup:
    """A 2 x 2 Lambert floor under ``lights`` small quad lights facing down, with a box
    between them and part of the floor (shadows), under a black map."""
    scene = vc.Scene()
    floor = np.array([[-1, 0, -1], [1, 0, -1], [1, 0, 1], [-1, 0, 1]], float)
    scene.add_mesh(floor, np.array([[0, 2, 1], [0, 3, 2]]), vc.Material.lambert([0.7] * 3))
    # A 0.3 m cube resting on the floor.
    c = np.array([[x, y, z] for x in (-0.15, 0.15) for y in (0.0, 0.3) for z in (-0.15, 0.15)])
    faces = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                      [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    scene.add_mesh(c, faces, vc.Material.lambert([0.5, 0.4, 0.3]))
    for i in range(lights):
        x = -0.6 + 1.2 * i / max(lights - 1, 1)
        quad = np.array([[x - 0.1, 0.8, -0.1], [x + 0.1, 0.8, -0.1], [x + 0.1, 0.8, 0.1],
                         [x - 0.1, 0.8, 0.1]], float)
        scene.add_area_light(quad, (30.0 + 10 * i, 20.0, 10.0 + 5 * i))
    camera = vc.Camera.look_at([0.0, 2.0, 1.6], [0, 0, 0], fov_deg=55.0, width=12, height=9)
    return vc.Setup(scene, camera, vc.EnvMap.constant(0.0, resolution=8))


def mean_and_se(res) -> tuple[np.ndarray, np.ndarray]:
    """The image's mean per channel and its standard error from the pixels' variances."""
    n = res.image.shape[0] * res.image.shape[1]
    mean = res.image.astype(np.float64).mean(axis=(0, 1))
    se = np.sqrt(res.variance.astype(np.float64).sum(axis=(0, 1))) / n
    return mean, se


def test_area_lights_as_one_light_each_match_the_direct_estimators():
    setup = lit_room()
    lights = vc.VPLs.from_area_lights(setup.scene, points=8)
    assert len(lights) == 2 and np.all(lights.kinds == 3) and np.all(lights.area_points == 8)
    # The exact sum: one shadow ray per light and pixel sample, a fresh point each.
    full = vc.render(setup, method="vpl", vpls=lights, spp=64, seed=1, **KW)
    assert full.stats["shadow_rays"] <= 2 * 64 * 12 * 9
    ref = vc.render(setup, method="mis", spp=64, seed=2, **KW)
    env = vc.render(setup, method="env", spp=64, seed=3, **KW)
    (m, se), (mr, ser), (me, see) = map(mean_and_se, (full, ref, env))
    assert np.all(se > 0) and np.all(m > 0.02)
    np.testing.assert_array_less(np.abs(m - mr), 4 * np.hypot(se, ser))
    np.testing.assert_array_less(np.abs(m - me), 4 * np.hypot(se, see))
    # Pixel by pixel too: the z-scores of the differences look like a standard normal.
    z = (full.image - ref.image) / np.sqrt(full.variance + ref.variance + 1e-12)
    assert np.abs(z).max() < 5 and abs(z.mean()) < 0.3
    # Drawn lights (their fixed points give the pdf, a fresh point the value): unbiased.
    for sampling in ("unoccluded", "power", "uniform"):
        s = vc.render(setup, method="vpl_sampled", vpls=lights, vpl_samples=2, spp=16,
                      seed=4, sampling=sampling, **KW)
        ms, ses = mean_and_se(s)
        np.testing.assert_array_less(np.abs(ms - m), 4 * np.hypot(ses, se))


def test_a_map_as_texel_lights_converges_on_an_open_plane():
    """Over an open plane the texel lights' image approaches the map's direct light as
    the level grows (the cosine integral, discretised)."""
    scene = vc.Scene()
    scene.add_mesh(np.array([[-1, 0, -1], [1, 0, -1], [1, 0, 1], [-1, 0, 1]], float),
                   np.array([[0, 2, 1], [0, 3, 2]]), vc.Material.lambert([0.6] * 3))
    camera = vc.Camera.look_at([0.0, 3.0, 0.1], [0, 0, 0], fov_deg=30.0, width=8, height=6)
    sky = vc.EnvMap.sky([0.3, 0.8, 0.2], 50.0, 10.0, [0.2, 0.4, 1.0], [0.8, 0.9, 1.0],
                        resolution=64)
    setup = vc.Setup(scene, camera, sky)
    ref = vc.render(setup, method="mis", spp=256, seed=1, **KW)
    want = ref.image.mean(axis=(0, 1))
    errors = []
    for level in (1, 3, 5):
        lights = vc.VPLs.from_envmap(setup, level=level)
        assert len(lights) == 4**level and np.all(lights.kinds == 1)
        got = vc.render(setup, method="vpl", vpls=lights, **KW).image.mean(axis=(0, 1))
        errors.append(np.abs(got / want - 1).max())
    assert errors[2] < 0.01 and errors[0] > errors[1] > errors[2], errors
    # An EnvMap needs its scene; the same lights then.
    same = vc.VPLs.from_envmap(setup.envmap, level=3, scene=scene)
    np.testing.assert_array_equal(same.flux, vc.VPLs.from_envmap(setup, level=3).flux)


def test_a_sun_and_a_sum_of_sets():
    setup = lit_room(1)
    sun = vc.VPLs.from_directions(setup.scene, [[0.3, 1.0, 0.2]], [[2.0, 1.8, 1.5]])
    area = vc.VPLs.from_area_lights(setup.scene)
    both = area + sun
    assert len(both) == 2 and list(both.kinds) == [3, 1]
    assert both.disk_area == sun.disk_area
    a = vc.render(setup, method="vpl", vpls=area, spp=4, seed=5, **KW)
    s = vc.render(setup, method="vpl", vpls=sun, spp=4, seed=5, **KW)
    ab = vc.render(setup, method="vpl", vpls=both, spp=4, seed=5, **KW)
    # The sun's light is exact (no sampling), the area light's sample is the same point.
    np.testing.assert_allclose(ab.image, a.image + s.image, rtol=1e-5, atol=1e-6)
    assert ab.stats["vpls"] == 2
    traced = vc.VPLs.trace(setup, count=200, seed=1, importance=False, threads=2)
    stats = (traced + traced).stats
    assert stats["paths"] == 2 * traced.stats["paths"] and stats["vpls"] == 2 * len(traced)


def test_view_share_with_and_without_importance():
    setup = vc.scenes.load("cornell")
    cam = setup.camera.with_resolution(32, 24)
    plain = vc.VPLs.trace(setup, count=1500, seed=2, importance=False, threads=2)
    aimed = vc.VPLs.trace(setup, count=1500, seed=2, importance=True, threads=2)
    a = plain.view_share(setup, camera=cam, width=24, threads=2)
    b = aimed.view_share(setup, camera=cam, width=24, threads=2)
    assert a["total"] == len(plain) and 0 < a["contributing"] <= a["total"]
    assert a["share"] == a["contributing"] / a["total"]
    # Algorithm 11 keeps VPLs the view sees: a larger share reaches it, of the surface
    # VPLs (kind 2) it decides on too.
    assert b["share"] > a["share"]
    (ca, ta), (cb, tb) = a["by_kind"][2], b["by_kind"][2]
    assert cb / tb > ca / ta
    assert sum(t for _, t in a["by_kind"].values()) == a["total"]
    assert sum(c for c, _ in a["by_kind"].values()) == a["contributing"]
    assert b == aimed.view_share(setup, camera=cam, width=24, threads=1)


def test_bad_input_is_named():
    setup = lit_room(1)
    scene = setup.scene
    for level in (-1, 4, 99):
        with pytest.raises(ValueError, match="level"):
            vc.VPLs.from_envmap(setup, level=level)  # an 8-texel map has levels 0..3
    with pytest.raises(TypeError, match="scene"):
        vc.VPLs.from_envmap(setup.envmap)
    with pytest.raises(TypeError, match="env_or_setup"):
        vc.VPLs.from_envmap("sky")
    for k in (0, -3):
        with pytest.raises(ValueError, match="points"):
            vc.VPLs.from_area_lights(scene, points=k)
    bare = vc.Scene()
    bare.add_mesh(np.eye(3), np.array([[0, 1, 2]]))
    with pytest.raises(ValueError, match="scene"):
        vc.VPLs.from_area_lights(bare)
    good = [[0.0, 1.0, 0.0]]
    for bad, name in [([[0.0, 0.0, 0.0]], "directions"), ([[np.nan, 1, 0]], "directions"),
                      ([[0.0, 1.0]], "directions"), (np.zeros((0, 3)), "directions")]:
        with pytest.raises(ValueError, match=name):
            vc.VPLs.from_directions(scene, bad, np.ones((len(bad), 3)))
    with pytest.raises(TypeError, match="directions"):
        vc.VPLs.from_directions(scene, [["a", "b", "c"]], [[1.0, 1.0, 1.0]])
    with pytest.raises(ValueError, match="irradiance"):
        vc.VPLs.from_directions(scene, good, [[-1.0, 1.0, 1.0]])
    with pytest.raises(ValueError, match="irradiance"):
        vc.VPLs.from_directions(scene, good, [[1.0, 1.0, 1.0]] * 2)
    with pytest.raises(ValueError, match="other"):
        _ = vc.VPLs.from_area_lights(scene) + vc.VPLs.from_directions(bare, good, [[1.0] * 3])
    with pytest.raises(TypeError, match="other"):
        _ = vc.VPLs.from_area_lights(scene) + 1  # type: ignore[operator]
    lights = vc.VPLs.from_area_lights(scene)
    for width in (0, 2000):
        with pytest.raises(ValueError, match="width"):
            lights.view_share(setup, width=width)
    with pytest.raises(ValueError, match="vpls"):
        vc.VPLs.from_directions(bare, good, [[1.0] * 3]).view_share(setup)


@pytest.mark.parametrize("method", ["vpl", "vpl_sampled"])
def test_area_light_renders_are_bit_identical_for_any_thread_count(method):
    setup = lit_room()
    lights = vc.VPLs.from_area_lights(setup.scene, points=4) + vc.VPLs.from_directions(
        setup.scene, [[0.2, 1.0, 0.1]], [[0.5, 0.5, 0.5]])
    ra, rb = (vc.render(setup, method=method, vpls=lights, spp=3, seed=6, threads=t,
                        progress=False) for t in (1, 2))
    np.testing.assert_array_equal(ra.image, rb.image)
    np.testing.assert_array_equal(ra.variance, rb.variance)
    # Another seed samples other points on the lights.
    rc = vc.render(setup, method=method, vpls=lights, spp=3, seed=7, threads=2, progress=False)
    assert np.any(rc.image != ra.image)
