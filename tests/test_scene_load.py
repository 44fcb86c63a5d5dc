"""``Scene.load(path)``: mesh files by extension (OBJ through tobj, the rest through
trimesh), written by the tests; missing, unknown and corrupt files."""

import numpy as np
import pytest
import viscache_rs as vc

trimesh = pytest.importorskip("trimesh")


def _canonical(triangles):
    """Triangles as a sorted array, each rolled to start at its smallest vertex (the
    winding kept), so that two readers' orders compare."""
    t = np.round(np.asarray(triangles, np.float64), 5)
    out = []
    for tri in t:
        first = min(range(3), key=lambda i: tuple(tri[i]))
        out.append(np.roll(tri, -first, axis=0).ravel())
    out = np.array(out)
    return out[np.lexsort(out.T[::-1])]


def _two_parts():
    """A box turned and moved by its node's transform, and a ball at the origin."""
    ts = trimesh.Scene()
    move = trimesh.transformations.rotation_matrix(0.3, [0, 1, 0])
    move[:3, 3] = [5.0, 0.5, -1.0]
    ts.add_geometry(trimesh.creation.box(extents=(1, 2, 3)), node_name="box",
                    geom_name="box_mesh", transform=move)
    ts.add_geometry(trimesh.creation.icosphere(subdivisions=1), node_name="ball",
                    geom_name="ball_mesh")
    return ts


def _world_triangles(ts):
    return np.concatenate([m.triangles for m in ts.dump()])


@pytest.mark.parametrize("ext", ["ply", "glb", "stl", "off"])
def test_each_format_gives_the_world_space_triangles(ext, tmp_path):
    ts = _two_parts()
    path = tmp_path / f"parts.{ext}"
    # Single-mesh formats hold the parts merged, in world space.
    (ts if ext == "glb" else ts.to_mesh()).export(path)
    scene = vc.Scene.load(path)
    assert scene.num_triangles == 12 + 80
    np.testing.assert_allclose(_canonical(scene.triangles()), _canonical(_world_triangles(ts)),
                               atol=1e-5)
    if ext == "glb":
        # A scene graph: one object per node, named after it.
        assert sorted(scene.object_names()) == ["ball", "box"]
        ids, names = scene.object_ids(), scene.object_names()
        box = scene.triangles()[ids == names.index("box")].reshape(-1, 3)
        assert box.mean(axis=0) == pytest.approx([5.0, 0.5, -1.0], abs=1e-5)


def test_obj_goes_through_from_obj(tmp_path):
    path = tmp_path / "two.OBJ"  # the extension's case does not matter
    path.write_text("o first\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"
                    "o second\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\nf 4 5 6 7\n")
    scene = vc.Scene.load(path)
    ref = vc.Scene.from_obj(path)
    assert scene.object_names() == ref.object_names() == ["first", "second"]
    np.testing.assert_array_equal(scene.triangles(), ref.triangles())
    assert scene.num_triangles == 3


def test_missing_and_unknown_files_name_the_path(tmp_path):
    with pytest.raises(FileNotFoundError, match="nothing.ply"):
        vc.Scene.load(tmp_path / "nothing.ply")
    odd = tmp_path / "mesh.abc"
    odd.write_text("1 2 3\n")
    with pytest.raises(ValueError, match=r"mesh\.abc: no reader for \.abc"):
        vc.Scene.load(odd)
    bare = tmp_path / "mesh"
    bare.write_text("1 2 3\n")
    with pytest.raises(ValueError, match="without an extension"):
        vc.Scene.load(bare)
    with pytest.raises(TypeError, match="path"):
        vc.Scene.load(3)


@pytest.mark.parametrize("name, data", [
    ("cut.ply", b"ply\nformat binary_little_endian 1.0\nelement vertex 100\n"
                b"property float x\nproperty float y\nproperty float z\nend_header\n\x00\x01"),
    ("junk.glb", b"glTF\x02\x00\x00\x00garbage"),
    ("empty.off", b""),
    ("bad.obj", b"v 1 2\nf 1 2 3\n"),
])
def test_corrupt_files_name_the_path(name, data, tmp_path):
    path = tmp_path / name
    path.write_bytes(data)
    with pytest.raises(ValueError, match=name.replace(".", r"\.")):
        vc.Scene.load(path)


def test_a_file_without_triangles_is_an_error(tmp_path):
    # An ASCII STL with a facet cut off before its vertices: trimesh reads it as empty.
    path = tmp_path / "none.stl"
    path.write_text("solid x\nfacet normal 0 0 1\n outer loop\n vertex 1 2\n")
    with pytest.raises(ValueError, match="none.stl: holds no triangles"):
        vc.Scene.load(path)
    points = tmp_path / "points.ply"
    trimesh.PointCloud(np.random.default_rng(0).normal(size=(10, 3))).export(points)
    with pytest.raises(ValueError, match="points.ply: holds no triangles"):
        vc.Scene.load(points)
