"""Indirect light by path tracing (``method="path"``, ``bounces``, ``direct``): known answers
in a furnace, the split into direct and indirect parts, determinism and bad input."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
import viscache_rs as vc

ALBEDO = np.array([0.5, 0.3, 0.8])


def furnace(albedo=ALBEDO, size=(12, 8)) -> vc.Setup:
    """The inside of a closed sphere of Lambert ``albedo`` that emits radiance 1 inwards,
    under a black map: every point receives radiance 1 from every direction, so the
    camera sees 1, direct light reflects ``a``, and bounce ``j`` adds ``a^(j+1)``."""
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    scene = vc.Scene()
    faces = np.asarray(sphere.faces)[:, ::-1]  # inward winding: emission faces the centre
    obj = scene.add_mesh(np.asarray(sphere.vertices), faces, vc.Material.lambert(albedo))
    scene.set_emitter(obj, [1.0, 1.0, 1.0])
    camera = vc.Camera.look_at([0.0, 0.1, 0.2], [0.3, -0.2, -1.0], fov_deg=60.0,
                               width=size[0], height=size[1])
    return vc.Setup(scene, camera, vc.EnvMap.constant(0.0, resolution=8))


def mean_and_se(res) -> tuple[np.ndarray, np.ndarray]:
    """Image mean per channel and its standard error (pixels are independent)."""
    n = res.image.shape[0] * res.image.shape[1]
    return res.image.mean(axis=(0, 1)), np.sqrt(res.variance.sum(axis=(0, 1))) / n


@pytest.mark.parametrize("bounces", [1, 3])
@pytest.mark.parametrize("direct", [True, False])
def test_furnace_gives_the_geometric_series(bounces, direct):
    res = vc.render(furnace(), method="path", bounces=bounces, direct=direct, spp=256,
                    seed=4, threads=2, progress=False)
    series = sum(ALBEDO ** (j + 1) for j in range(1, bounces + 1))
    want = 1.0 + ALBEDO + series if direct else series
    mean, se = mean_and_se(res)
    np.testing.assert_array_less(np.abs(mean - want), 4 * se + 1e-5 * want)
    assert res.stats["method"] == "path" and res.stats["bounces"] == bounces
    # Every pixel sees the sphere and every path takes its first bounce.
    assert res.stats["bounce_rays"] >= res.stats["samples"]
    assert res.stats["indirect_seconds"] > 0


def test_path_is_mis_plus_the_indirect_part():
    setup = vc.scenes.load("cornell")
    cam = setup.camera.with_resolution(24, 18)
    kw = dict(camera=cam, spp=64, threads=2, progress=False)
    full = vc.render(setup, method="path", seed=1, **kw)
    direct = vc.render(setup, method="mis", seed=2, **kw)
    indirect = vc.render(setup, method="path", direct=False, seed=3, **kw)
    (m_full, se_full), (m_d, se_d), (m_i, se_i) = map(mean_and_se, (full, direct, indirect))
    np.testing.assert_array_less(np.abs(m_full - (m_d + m_i)),
                                 4 * np.sqrt(se_full**2 + se_d**2 + se_i**2))
    assert np.all(m_i > 0.05 * m_d), "cornell has visible indirect light"
    # The first hit's direct light takes the random numbers it takes without bounces, and
    # every path adds a non-negative amount: at one seed, no pixel gets darker.
    same = vc.render(setup, method="mis", seed=1, **kw)
    assert np.all(full.image >= same.image)
    assert np.mean(full.image > same.image) > 0.5


def test_paths_are_bit_identical_for_any_thread_count():
    setup = vc.scenes.load("garage")
    cam = setup.camera.with_resolution(20, 14)
    a = vc.render(setup, camera=cam, method="path", bounces=2, spp=8, threads=1, progress=False)
    b = vc.render(setup, camera=cam, method="path", bounces=2, spp=8, threads=2, progress=False)
    np.testing.assert_array_equal(a.image, b.image)
    np.testing.assert_array_equal(a.variance, b.variance)


def test_bounces_add_to_other_methods():
    setup = furnace()
    res = vc.render(setup, method="product", bounces=1, spp=128, seed=2, threads=2,
                    progress=False)
    mean, se = mean_and_se(res)
    want = 1.0 + ALBEDO + ALBEDO**2
    np.testing.assert_array_less(np.abs(mean - want), 4 * se + 1e-5)


@pytest.mark.parametrize(
    ("kwargs", "error", "name"),
    [
        (dict(method="path", bounces=0), ValueError, "bounces"),
        (dict(method="path", bounces=65), ValueError, "bounces"),
        (dict(method="mis", bounces=-1), ValueError, "bounces"),
        (dict(method="path", bounces=1.5), TypeError, "bounces"),
        (dict(method="mis", direct=False), ValueError, "direct"),
        (dict(method="paths"), ValueError, "method"),
    ],
)
def test_bad_path_arguments_name_the_argument(kwargs, error, name):
    setup = furnace(size=(4, 4))
    with pytest.raises(error, match=name):
        vc.render(setup, spp=1, progress=False, **kwargs)


def test_set_emitter_checks_and_keeps_the_scene_on_error():
    setup = furnace(size=(4, 4))
    with pytest.raises(ValueError, match="obj"):
        setup.scene.set_emitter(0, [1.0, 1.0, 1.0])  # already emits
    with pytest.raises(ValueError, match="obj"):
        setup.scene.set_emitter(5, [1.0, 1.0, 1.0])
    with pytest.raises(ValueError, match="radiance"):
        setup.scene.set_emitter(0, [np.nan, 1.0, 1.0])
    assert setup.scene.emission(0) == (1.0, 1.0, 1.0)


def test_the_indirect_part_alone_skips_the_anchors_direct_work():
    # Without direct light every method renders the same paths: the cache's records and
    # the anchors' products would shade nothing, so they are not consulted.
    setup = vc.scenes.load("garage")
    cam = setup.camera.with_resolution(16, 12)
    cache = vc.VisibilityCache(setup.scene)
    cache.build(cam, progress=False)
    kw = dict(camera=cam, spp=4, bounces=1, direct=False, threads=2, progress=False)
    path = vc.render(setup, method="path", **kw)
    cv = vc.render(setup, method="cv", cache=cache, **kw)
    np.testing.assert_array_equal(path.image, cv.image)
    assert cv.stats["cache_points"] == 0
