"""``setup.save(path)`` and ``vc.Setup.load(path)``: the JSON setup file round trip, files
written by hand, bad files, and saves that fail half-way."""

import json
import os

import numpy as np
import pytest
import viscache_rs as vc

trimesh = pytest.importorskip("trimesh")


def _assert_same_setup(a, b):
    assert b.name == a.name
    sa, sb = a.scene, b.scene
    assert sb.object_names() == sa.object_names()
    np.testing.assert_array_equal(sb.triangles(), sa.triangles())
    np.testing.assert_array_equal(sb.object_ids(), sa.object_ids())
    for k in range(sa.num_objects):
        assert sb.material(k).kind == sa.material(k).kind
        assert sb.material(k).params() == sa.material(k).params()
        assert sb.emission(k) == sa.emission(k)
    assert sb.area_lights() == sa.area_lights()
    np.testing.assert_array_equal(b.envmap.texels(), a.envmap.texels())
    for jitter in (False, True):
        for got, want in zip(b.camera.rays(jitter=jitter), a.camera.rays(jitter=jitter),
                             strict=True):
            np.testing.assert_allclose(got, want, atol=1e-6)


@pytest.mark.parametrize("name", ["cornell", "garage"])
def test_round_trip_gives_the_setup_back(name, tmp_path):
    # cornell: an area light; garage: Lambert and Phong under a windows map.
    setup = vc.scenes.load(name, detail=0.3)
    setup.save(tmp_path / "setup.json")
    assert sorted(os.listdir(tmp_path)) == ["setup.json", "setup.parts"]
    _assert_same_setup(setup, vc.Setup.load(tmp_path / "setup.json"))


def test_a_black_map_and_a_saved_folder_moved_elsewhere(tmp_path):
    scene = vc.Scene()
    scene.add_mesh(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32), [[0, 1, 2]],
                   material=vc.Material.phong((0.1, 0.2, 0.3), (0.4, 0.4, 0.4), 12.0))
    setup = vc.Setup(scene, vc.Camera.look_at((0, 0, 3), (0, 0, 0), width=8, height=6),
                     vc.EnvMap.constant(0.0, resolution=8))
    (tmp_path / "a").mkdir()
    setup.save(tmp_path / "a" / "s.json")
    assert json.loads((tmp_path / "a" / "s.json").read_text())["envmap"] == {
        "constant": [0.0, 0.0, 0.0], "resolution": 8}
    # Paths in the file are relative to it: the folder can move.
    os.rename(tmp_path / "a", tmp_path / "b")
    back = vc.Setup.load(tmp_path / "b" / "s.json")
    _assert_same_setup(setup, back)
    assert back.envmap.is_black
    # Written by hand, null is a black map.
    doc = json.loads((tmp_path / "b" / "s.json").read_text())
    (tmp_path / "b" / "s.json").write_text(json.dumps({**doc, "envmap": None}))
    assert vc.Setup.load(tmp_path / "b" / "s.json").envmap.is_black


def test_a_file_written_by_hand(tmp_path):
    (tmp_path / "two.obj").write_text("o left\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"
                                      "o right\nv 2 0 0\nv 3 0 0\nv 2 1 0\nf 1 2 3\n")
    lamp = trimesh.Trimesh([[0, 3, 0], [0, 3, 1], [1, 3, 0]], [[0, 1, 2]], process=False)
    lamp.export(tmp_path / "lamp.ply")
    doc = {
        "format": "viscache-setup", "version": 1, "name": "by hand",
        "objects": [
            {"name": "pair", "mesh": "two.obj",
             "material": {"kind": "lambert", "albedo": [0.2, 0.3, 0.4]}},
            {"name": "lamp", "mesh": "lamp.ply", "emission": [5, 4, 3]},
        ],
        "envmap": {"constant": [0.5, 0.5, 0.5], "resolution": 16},
        "camera": {"eye": [0, 1, 5], "target": [0, 1, 0], "width": 16, "height": 12},
    }
    (tmp_path / "s.json").write_text(json.dumps(doc))
    setup = vc.Setup.load(tmp_path / "s.json")
    scene = setup.scene
    assert setup.name == "by hand"
    assert scene.object_names() == ["pair/left", "pair/right", "lamp"]
    np.testing.assert_allclose(scene.material(1).params()["albedo"], [0.2, 0.3, 0.4],
                               rtol=1e-6)
    assert scene.area_lights() == [2] and scene.emission(2) == (5.0, 4.0, 3.0)
    np.testing.assert_array_equal(scene.triangles()[2], [[0, 3, 0], [0, 3, 1], [1, 3, 0]])
    np.testing.assert_allclose(setup.envmap.texels(), 0.5)
    ref = vc.Camera.look_at((0, 1, 5), (0, 1, 0), width=16, height=12)
    for got, want in zip(setup.camera.rays(jitter=False), ref.rays(jitter=False), strict=True):
        np.testing.assert_array_equal(got, want)


GOOD = {"format": "viscache-setup", "version": 1, "objects": [],
        "camera": {"eye": [0, 0, 3], "forward": [0, 0, -1]}}


@pytest.mark.parametrize("change, error, message", [
    ({"colour": 1}, ValueError, r"unknown key 'colour'"),
    ({"version": 2}, ValueError, r"version"),
    ({"objects": [{"mesh": "m.obj", "shader": "x"}]}, ValueError, r"objects\[0\].*'shader'"),
    ({"objects": [{"name": "x"}]}, ValueError, r"objects\[0\]: needs a 'mesh'"),
    ({"objects": [{"mesh": "gone.ply"}]}, FileNotFoundError, r"objects\[0\]\.mesh.*gone\.ply"),
    ({"objects": [{"mesh": "m.obj", "material": {"kind": "glass"}}]}, ValueError,
     r"objects\[0\]\.material"),
    ({"objects": [{"mesh": "m.obj", "material": {"kind": "lambert", "kd": [1, 1, 1]}}]},
     ValueError, r"objects\[0\]\.material: a lambert material has the keys"),
    ({"objects": [{"mesh": "m.obj", "emission": [1, -1, 1]}]}, ValueError,
     r"objects\[0\]\.emission"),
    ({"camera": {"eye": [0, 0, 3], "forward": [0, 0, -1], "zoom": 2}}, ValueError,
     r"camera: unknown key 'zoom'"),
    ({"camera": {"forward": [0, 0, -1]}}, ValueError, r"camera: needs 'eye'"),
    ({"camera": {"eye": [0, 0, 3], "forward": [0, 0, -1], "width": 0}}, ValueError,
     r"camera:.*width"),
    ({"envmap": {"file": "sky.exr", "constant": 1}}, ValueError, r"envmap: needs one of"),
    ({"envmap": {"file": "sky.exr"}}, FileNotFoundError, r"envmap:.*sky\.exr"),
    ({"envmap": {"sky": 1}}, ValueError, r"envmap: unknown key 'sky'"),
])
def test_bad_files_name_the_file_and_the_key(change, error, message, tmp_path):
    (tmp_path / "m.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    path = tmp_path / "bad.json"
    path.write_text(json.dumps({**GOOD, **change}))
    with pytest.raises(error, match=message) as e:
        vc.Setup.load(path)
    assert "bad.json" in str(e.value)


def test_files_that_are_not_setups(tmp_path):
    with pytest.raises(FileNotFoundError, match="none.json"):
        vc.Setup.load(tmp_path / "none.json")
    (tmp_path / "text.json").write_text("{not json")
    with pytest.raises(ValueError, match="text.json: not a JSON setup file"):
        vc.Setup.load(tmp_path / "text.json")
    (tmp_path / "list.json").write_text("[1, 2]")
    with pytest.raises(ValueError, match="list.json: expected an object"):
        vc.Setup.load(tmp_path / "list.json")


def test_a_failed_save_leaves_the_old_files(tmp_path, monkeypatch):
    setup = vc.scenes.load("cornell", detail=0.3)
    path = tmp_path / "s.json"
    setup.save(path)
    before = {p: (tmp_path / p).read_bytes() for p in ["s.json", "s.parts/object0.ply"]}
    calls = []

    def export_then_fail(self, *args, **kwargs):
        calls.append(1)
        if len(calls) == 3:
            raise OSError("disk full")
        return real_export(self, *args, **kwargs)

    real_export = trimesh.Trimesh.export
    monkeypatch.setattr(trimesh.Trimesh, "export", export_then_fail)
    other = vc.scenes.load("garage", detail=0.3)
    with pytest.raises(OSError, match="disk full"):
        other.save(path)
    # The old file and parts as they were, and no temporary folder left.
    assert sorted(os.listdir(tmp_path)) == ["s.json", "s.parts"]
    assert {p: (tmp_path / p).read_bytes() for p in before} == before
    _assert_same_setup(setup, vc.Setup.load(path))
    with pytest.raises(FileNotFoundError, match="folder"):
        setup.save(tmp_path / "missing" / "s.json")
