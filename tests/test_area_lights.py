"""Area lights from Python: adding them, what they occlude, and bad input."""

import numpy as np
import pytest
import viscache_rs as vc


def _quad(y=1.0):
    # Winding along +x then +z: normal -y, lighting what is below.
    return np.array([[0, y, 0], [0, y, 1], [1, y, 1], [1, y, 0]], dtype=np.float32)[[0, 3, 2, 1]]


def test_add_area_light_is_geometry_and_is_listed():
    scene = vc.Scene()
    oid = scene.add_area_light(_quad(), (1.0, 2.0, 3.0), name="lamp")
    assert scene.area_lights() == [oid]
    assert scene.object_names()[oid] == "lamp"
    assert scene.num_triangles == 2
    # It occludes rays that pass through it.
    hit = scene.occluded([[0.5, 0.0, 0.5]], [[0, 1, 0]])
    assert hit.tolist() == [True]
    tri = scene.add_area_light(_quad(2.0)[:3], (1.0, 1.0, 1.0))
    assert scene.area_lights() == [oid, tri]


def test_cornell_has_its_ceiling_light():
    setup = vc.scenes.load("cornell")
    lights = setup.scene.area_lights()
    assert len(lights) == 1
    assert setup.scene.object_names()[lights[0]] == "light"


@pytest.mark.parametrize(
    ("vertices", "radiance", "exc", "needle"),
    [
        (np.zeros((5, 3)), (1, 1, 1), ValueError, "vertices"),
        (np.zeros((3, 2)), (1, 1, 1), ValueError, "vertices"),
        ([[0, 0, 0], [1, 0, 0], [2, 0, 0]], (1, 1, 1), ValueError, "vertices"),
        ([[0, 0, 0], [1, 0, np.nan], [0, 0, 1]], (1, 1, 1), ValueError, "vertices"),
        ([[0, 0, 0], [1, 0, 0], [0, 0, 1]], (1, -1, 1), ValueError, "radiance"),
        ([[0, 0, 0], [1, 0, 0], [0, 0, 1]], (1, np.inf, 1), ValueError, "radiance"),
        ([[0, 0, 0], [1, 0, 0], [0, 0, 1]], (1, 1), ValueError, "radiance"),
        ([["a", "b", "c"]] * 3, (1, 1, 1), TypeError, "vertices"),
    ],
)
def test_bad_lights_raise_and_leave_the_scene_unchanged(vertices, radiance, exc, needle):
    scene = vc.Scene()
    scene.add_mesh(np.eye(3), [[0, 1, 2]])
    with pytest.raises(exc, match=needle):
        scene.add_area_light(vertices, radiance)
    assert scene.num_triangles == 1 and scene.num_objects == 1 and scene.area_lights() == []



def test_a_textured_quad_light_lights_what_its_texels_face():
    """A quad light with a red and a green half: points under the red half get more red
    than green, the image mean matches the same light split into two plain quads (by
    light sampling, within 4 SE), and bad textures name themselves."""
    def setup(split):
        scene = vc.Scene()
        scene.add_mesh(np.array([[-5, 0, -5], [5, 0, -5], [5, 0, 5], [-5, 0, 5]], float),
                       np.array([[0, 2, 1], [0, 3, 2]]))
        if split:
            ids = [scene.add_area_light(np.array([[x0, 1, -0.5], [x0 + 1, 1, -0.5],
                                                  [x0 + 1, 1, 0.5], [x0, 1, 0.5]]), rgb)
                   for x0, rgb in ((-1, (4, 0, 0)), (0, (0, 4, 0)))]
        else:
            ids = [scene.add_area_light(np.array([[-1, 1, -0.5], [1, 1, -0.5], [1, 1, 0.5],
                                                  [-1, 1, 0.5]]), (2, 2, 2))]
            scene.set_emission_texture(ids[0], np.array([[[2, 0, 0], [0, 2, 0]]], np.float32))
        cam = vc.Camera.look_at((0, 3, 0.01), (0, 0, 0), fov_deg=60, width=24, height=16)
        return vc.Setup(scene, cam, vc.EnvMap.constant(0.0, 4)), ids

    textured, (light,) = setup(False)
    split, _ = setup(True)
    kw = dict(spp=64, method="env", jitter=False, progress=False)
    a = vc.render(textured, seed=1, **kw)
    b = vc.render(split, seed=2, **kw)
    n = a.image.shape[0] * a.image.shape[1]
    diff = a.image.mean(axis=(0, 1)) - b.image.mean(axis=(0, 1))
    se = np.sqrt((a.variance.sum(axis=(0, 1)) + b.variance.sum(axis=(0, 1))) / n**2)
    assert np.all(np.abs(diff) <= 4 * se + 1e-6), (diff, se)
    g = textured.scene.gbuffer(textured.camera, jitter=False)
    x = g["position"][..., 0]
    floor = g["object"] == 0
    left, right = floor & (x < -0.3), floor & (x > 0.3)
    assert a.image[left][:, 0].mean() > 2 * a.image[left][:, 1].mean()
    assert a.image[right][:, 1].mean() > 2 * a.image[right][:, 0].mean()
    for bad, err in ((np.ones((2, 2)), ValueError), (np.full((1, 1, 3), -1.0), ValueError),
                     (np.full((1, 1, 3), np.nan), ValueError)):
        with pytest.raises(err, match="^texture"):
            textured.scene.set_emission_texture(light, bad)
    with pytest.raises(ValueError, match="^obj"):
        textured.scene.set_emission_texture(0, np.ones((1, 1, 3)))
    tri = vc.Scene()
    t = tri.add_area_light(np.array([[0, 1, 0], [1, 1, 0], [0, 1, 1]], float), (1, 1, 1))
    with pytest.raises(ValueError, match="^texture"):
        tri.set_emission_texture(t, np.ones((1, 1, 3)))
    textured.scene.set_emission_texture(light, None)
