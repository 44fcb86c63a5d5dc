"""Built-in scenes: names, sizes, determinism, and each one's stated purpose."""

import numpy as np
import pytest
import viscache_rs as vc

SMALL = {"cornell": 1.0, "garage": 1.0, "dynamics": 1.0, "garden": 0.05, "hairball": 0.02}


def test_names():
    assert vc.scenes.names() == ["cornell", "garage", "garden", "dynamics", "hairball"]


@pytest.mark.parametrize("name", list(SMALL))
def test_each_scene_loads_deterministically(name):
    a = vc.scenes.load(name, detail=SMALL[name], seed=1)
    b = vc.scenes.load(name, detail=SMALL[name], seed=1)
    assert a.scene.num_triangles > 0 and a.name == name
    np.testing.assert_array_equal(a.scene.triangles(), b.scene.triangles())
    assert np.isfinite(a.scene.triangles()).all()
    assert (a.camera.width, a.camera.height) == (256, 192)
    g = a.scene.gbuffer(a.camera.with_resolution(32, 24), jitter=False)
    assert (g["object"] >= 0).mean() > 0.5, "the camera frames the scene"
    smaller = vc.scenes.load(name, detail=SMALL[name] / 4, seed=1)
    assert smaller.scene.num_triangles < a.scene.num_triangles


@pytest.mark.parametrize("name", ["garden", "hairball"])
def test_random_scenes_depend_on_the_seed(name):
    a = vc.scenes.load(name, detail=SMALL[name], seed=1).scene.triangles()
    b = vc.scenes.load(name, detail=SMALL[name], seed=2).scene.triangles()
    assert a.shape != b.shape or not np.array_equal(a, b)


def test_documented_sizes():
    assert 500 <= vc.scenes.load("cornell").scene.num_triangles <= 2000
    assert 300_000 <= vc.scenes.load("garden").scene.num_triangles <= 500_000


def test_cornell_box_is_closed(cornell):
    lo, hi = cornell.scene.bounds
    centre = (lo + hi) / 2
    rng = np.random.default_rng(0)
    d = rng.normal(size=(20_000, 3)).astype(np.float32)
    o = np.broadcast_to(centre, d.shape).astype(np.float32)
    assert cornell.scene.occluded(o, d).all()


def test_garage_camera_looks_into_the_shadow():
    setup = vc.scenes.load("garage")
    g = setup.scene.gbuffer(setup.camera.with_resolution(32, 24), jitter=False)
    hit = g["object"] >= 0
    pts = setup.scene.offset_points(g["position"][hit], g["normal"][hit])
    rng = np.random.default_rng(1)
    d = rng.normal(size=(len(pts), 3)).astype(np.float32)
    d[:, 1] = np.abs(d[:, 1])  # the sky: upper hemisphere
    assert setup.scene.occluded(pts, d).mean() > 0.5
