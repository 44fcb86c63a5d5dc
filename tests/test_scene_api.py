"""Scene construction: numpy, OBJ, trimesh; materials; object bookkeeping; BVH presets."""

import numpy as np
import pytest
import trimesh
import viscache_rs as vc

QUAD_V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=np.float64)
QUAD_F = np.array([[0, 1, 2], [0, 2, 3]], dtype=np.uint32)


def test_add_mesh_dtypes_and_bookkeeping():
    s = vc.Scene()
    red = vc.Material.lambert((0.8, 0.1, 0.1))
    assert s.add_mesh(QUAD_V, QUAD_F, material=red, name="floor") == 0
    assert s.add_mesh(QUAD_V.astype(np.float32) + 2, QUAD_F.astype(np.int64)) == 1
    assert s.add_mesh(QUAD_V[:3], np.array([[0, 1, 2]], dtype=np.int32)) == 2
    assert (s.num_triangles, s.num_objects, len(s)) == (5, 3, 5)
    assert s.object_names() == ["floor", "object1", "object2"]
    assert list(s.object_ids()) == [0, 0, 1, 1, 2]
    assert s.material(0) == red and s.material(1).kind == "lambert"
    np.testing.assert_array_equal(s.bounds, [[0, 0, 0], [3, 3, 2]])
    tris = s.triangles()
    assert tris.shape == (5, 3, 3) and tris.dtype == np.float32
    np.testing.assert_array_equal(tris[1], QUAD_V[[0, 2, 3]])
    # Non-contiguous input is accepted.
    wide = np.zeros((4, 6))
    wide[:, ::2] = QUAD_V
    s.add_mesh(wide[:, ::2], QUAD_F[:, ::-1])
    np.testing.assert_array_equal(s.triangles()[5], QUAD_V[[2, 1, 0]])


def test_materials_validate():
    m = vc.Material.phong((0.3, 0.3, 0.3), (0.5, 0.5, 0.5), 100)
    assert m.kind == "phong" and m.params()["exponent"] == 100
    with pytest.raises(ValueError, match="^albedo"):
        vc.Material.lambert((1.5, 0, 0))
    with pytest.raises(ValueError, match="^ks"):
        vc.Material.phong((0.6,) * 3, (0.6,) * 3, 10)
    with pytest.raises(ValueError, match="^exponent"):
        vc.Material.phong((0.1,) * 3, (0.1,) * 3, 2e4)
    with pytest.raises(TypeError, match="^exponent"):
        vc.Material.phong((0.1,) * 3, (0.1,) * 3, "high")
    with pytest.raises(ValueError, match="^albedo"):
        vc.Material.lambert((0.5, 0.5))


def test_from_obj(tmp_path):
    p = tmp_path / "two.obj"
    p.write_text(
        "mtllib two.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n"
        "o floor\nusemtl red\nf 1 2 3 4\ng block\nf 1 2 3\n"
    )
    (tmp_path / "two.mtl").write_text("newmtl red\nKd 0.9 0.1 0.1\n")
    s = vc.Scene.from_obj(p)
    assert s.num_triangles == 3 and s.num_objects == 2
    assert s.object_names()[0] == "floor"
    np.testing.assert_allclose(s.material(0).params()["albedo"], [0.9, 0.1, 0.1], rtol=1e-6)
    assert s.occluded([[0.5, 0.5, 1]], [[0, 0, -1]])[0]


def test_from_obj_errors_name_the_path(tmp_path):
    missing = tmp_path / "nope.obj"
    with pytest.raises(FileNotFoundError, match="nope.obj"):
        vc.Scene.from_obj(missing)
    bad = tmp_path / "bad.obj"
    bad.write_text("v 0 0 0\nv 1 0 0\nf 1 2 7\n")
    with pytest.raises(ValueError, match="bad.obj"):
        vc.Scene.from_obj(bad)
    garbage = tmp_path / "garbage.obj"
    garbage.write_bytes(b"v 0 zero 0\n\xff\xfe f 1 1 1\n")
    with pytest.raises(ValueError, match="garbage.obj"):
        vc.Scene.from_obj(garbage)
    with pytest.raises(TypeError):
        vc.Scene.from_obj(12)


def test_from_trimesh_applies_transforms():
    ts = trimesh.Scene()
    box = trimesh.creation.box(extents=(1, 1, 1))
    moved = trimesh.transformations.translation_matrix([5, 0, 0])
    ts.add_geometry(box, node_name="moved", transform=moved)
    ts.add_geometry(trimesh.creation.icosphere(1), node_name="ball")
    s = vc.Scene.from_trimesh(ts)
    assert s.num_objects == 2 and sorted(s.object_names()) == ["ball", "moved"]
    np.testing.assert_allclose(s.bounds, [[-1, -1, -1], [5.5, 1, 1]], atol=1e-6)
    hit = s.intersect([[10, 0, 0]], [[-1, 0, 0]])
    assert s.object_names()[hit["obj"][0]] == "moved"
    np.testing.assert_allclose(hit["t"], [4.5], rtol=1e-6)
    single = vc.Scene.from_trimesh(box)
    assert single.num_triangles == 12
    with pytest.raises(TypeError, match="^mesh"):
        vc.Scene.from_trimesh("not a mesh")


def test_build_presets_give_the_same_answers(cornell):
    tris = cornell.scene.triangles()
    rng = np.random.default_rng(0)
    o = rng.uniform(0.5, 5.0, (5000, 3)).astype(np.float32)
    d = rng.normal(size=(5000, 3)).astype(np.float32)
    answers, costs = [], {}
    for q in ["sah", "fastest", "fast", "medium", "slow", "auto"]:
        s = vc.Scene()
        s.add_mesh(tris.reshape(-1, 3), np.arange(3 * len(tris)).reshape(-1, 3))
        assert s.build(quality=q, threads=2) >= 0.0
        stats = s.bvh_stats()
        assert stats["requested"] == q
        costs[stats["quality"]] = stats["sah_cost"]
        if q != "auto":
            assert stats["quality"] == q
        answers.append(s.intersect(o, d)["t"])
    for a in answers[1:]:
        np.testing.assert_array_equal(a, answers[0])
    # "auto" keeps the "slow" PLOC tree where it does 5% less work on sample rays.
    work = stats["auto_costs"]
    assert set(work) == {"sah", "slow"} and min(work.values()) > 1.0
    assert stats["quality"] == ("slow" if work["sah"] > 1.05 * work["slow"] else "sah")
    assert stats["sah_cost"] == costs[stats["quality"]]
    assert all(c >= 1.0 for c in costs.values())
    with pytest.raises(ValueError, match="^quality"):
        vc.Scene().build(quality="best")


def test_auto_weighs_a_tree_with_objects_apart():
    # Cornell's objects (walls, boxes, light) are several: "auto" also builds the SAH tree
    # with each object in a subtree of its own, and keeps it where it does 5% less probe
    # work than the plain SAH tree and less than the PLOC one. Its answers are the same.
    s = vc.scenes.load("cornell").scene
    s.build(threads=2)
    stats = s.bvh_stats()
    work = stats["auto_costs"]
    assert set(work) == {"sah", "slow", "sah_objects_apart"}
    apart = work["sah_objects_apart"]
    assert stats["objects_apart"] == (apart < work["slow"] and work["sah"] > 1.05 * apart)
    o = np.tile([[2.78, 2.7, 2.0]], (2000, 1)).astype(np.float32)
    d = np.random.default_rng(3).normal(size=(2000, 3)).astype(np.float32)
    answers = []
    for quality in ["auto", "sah"]:
        s.build(quality=quality, threads=2)
        answers.append((s.intersect(o, d)["t"], s.occluded(o, d, tmax=1.0)))
    assert not s.bvh_stats()["objects_apart"]
    for a, b in zip(*answers, strict=True):
        np.testing.assert_array_equal(a, b)


def test_adding_geometry_invalidates_the_bvh():
    s = vc.Scene()
    s.add_mesh(QUAD_V, QUAD_F)
    o, d = [[0.5, 0.5, 1], [5.5, 5.5, 1]], [[0, 0, -1], [0, 0, -1]]
    assert list(s.occluded(o, d)) == [True, False]
    s.add_mesh(QUAD_V + [5, 5, 0], QUAD_F)
    assert list(s.occluded(o, d)) == [True, True]


def test_setup_shares_its_scene_object(cornell):
    assert cornell.scene is cornell.scene
    assert cornell.name == "cornell" and "cornell" in repr(cornell)
