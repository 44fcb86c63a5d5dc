"""Built-in scenes: names, sizes, determinism, and each one's stated purpose."""

import numpy as np
import pytest
import viscache_rs as vc

SMALL = {"cornell": 1.0, "garage": 1.0, "dynamics": 1.0, "garden": 0.05, "hairball": 0.02}


def test_names():
    assert vc.scenes.names() == ["cornell", "garage", "garden", "dynamics", "hairball",
                                 "instances", "strands", "room", "panels", "scales", "blob"]


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


# The benchmark suite's stress scenes: the fraction of ground rays each blocks (measured
# at detail 1 with 200,000 rays and documented in vc.scenes), checked here from 20,000
# rays, at a smaller detail where that keeps the layout (instances and strands have fewer
# solids and reeds at lower detail): the band is the documented value +- 0.05, far beyond
# the binomial standard error (at most 0.0036).
SUITE = {"instances": (1.0, 0.43), "strands": (1.0, 0.47), "room": (0.5, 0.95),
         "panels": (1.0, 0.61), "scales": (0.25, 0.12), "blob": (0.0625, 0.31)}


@pytest.mark.parametrize("name", sorted(SUITE))
def test_suite_scenes_block_what_their_docs_say(name):
    detail, blocked = SUITE[name]
    setup = vc.scenes.load(name, detail=detail, seed=0)
    again = vc.scenes.load(name, detail=detail, seed=0)
    assert np.array_equal(setup.scene.triangles(), again.scene.triangles())
    o, d = vc.testing.ground_hemisphere_rays(setup.scene, 20_000, seed=1)
    fraction = setup.scene.occluded(o, d).mean()
    assert abs(fraction - blocked) < 0.05, f"{name}: {fraction:.3f}"
    # The camera sees the scene: most pixels hit something.
    g = setup.scene.gbuffer(setup.camera.with_resolution(64, 48), jitter=False)
    assert (g["object"] >= 0).mean() > 0.5


def test_suite_spans_open_to_closed_and_lists_the_meshes_when_present(tmp_path):
    blocked = [b for _, b in SUITE.values()]
    assert min(blocked) < 0.15 and max(blocked) > 0.9
    assert set(SUITE) <= set(vc.scenes.names())
    with pytest.raises(FileNotFoundError, match="models_dir"):
        vc.scenes.models_dir(tmp_path)
    if vc.scenes.models_dir(required=False) is None:
        assert "meshes" not in vc.scenes.suite_names()
        pytest.skip("the real meshes (../shared/models) are not on this machine")
    assert vc.scenes.suite_names()[-1] == "meshes"
    setup = vc.scenes.load("meshes")
    assert setup.scene.object_names() == ["ground", *vc.scenes.MODEL_NAMES]
    lo, hi = setup.scene.bounds
    assert lo[1] == pytest.approx(0.0, abs=1e-4) and hi[1] <= 1.5 + 1e-3


def test_read_obj_fans_polygons_and_names_bad_lines():
    import io

    v, f = vc.scenes.read_obj(io.BytesIO(
        b"# a quad and a triangle\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\n"
        b"vn 0 0 1\nf 1//1 2//1 4//1 3//1\nf -1 -2 -3\n"))
    assert v.shape == (4, 3)
    np.testing.assert_array_equal(f, [[0, 1, 3], [0, 3, 2], [3, 2, 1]])
    with pytest.raises(ValueError, match="line 2"):
        vc.scenes.read_obj(io.BytesIO(b"v 0 0 0\nv 1 x 0\n"))
    with pytest.raises(ValueError, match="vertex"):
        vc.scenes.read_obj(io.BytesIO(b"v 0 0 0\nf 1 2 3\n"))
