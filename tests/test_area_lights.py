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
