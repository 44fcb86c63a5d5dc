"""Ray queries against a numpy brute force, Embree, closed meshes, scales and thread counts."""

import threading
import time

import numpy as np
import pytest
import trimesh
import viscache_rs as vc
from conftest import brute_force, random_rays, random_soup, scene_from_triangles

N_RAYS = 10_000


def scene_rays(setup, seed):
    """Rays from random points inside the scene's bounds in random directions."""
    lo, hi = setup.scene.bounds
    pad = 0.05 * (hi - lo)
    return random_rays(np.random.default_rng(seed), N_RAYS, lo + pad, hi - pad)


def check_against_brute_force(scene, origins, dirs, tmax=np.inf):
    ref = brute_force(scene.triangles(), origins, dirs, tmax)
    hits = scene.intersect(origins, dirs, tmax=tmax)
    occ = scene.occluded(origins, dirs, tmax=tmax)
    ours = np.isfinite(hits["t"])
    theirs = np.isfinite(ref["t"])
    firm = ~ref["near_edge"]
    # Hit/miss must agree on every ray that does not pass within 1e-5 of an edge.
    assert np.array_equal(ours[firm], theirs[firm]), np.flatnonzero((ours != theirs) & firm)[:10]
    assert np.array_equal(occ, ours), "occluded and intersect disagree"
    both = ours & theirs & firm
    err = np.abs(hits["t"][both] - ref["t"][both])
    assert np.all(err <= ref["t_tolerance"][both]), np.max(err / ref["t_tolerance"][both])
    # The closest triangle is the same unless two triangles tie at that distance.
    clear = both & ~ref["tie"]
    np.testing.assert_array_equal(hits["prim"][clear], ref["prim"][clear])
    return ours, ref


@pytest.mark.parametrize("name", ["cornell", "dynamics"])
def test_builtin_scenes_match_brute_force(name):
    setup = vc.scenes.load(name)
    origins, dirs = scene_rays(setup, seed=1)
    ours, ref = check_against_brute_force(setup.scene, origins, dirs)
    assert 0.05 < ours.mean() <= 1.0
    assert ref["near_edge"].mean() < 0.01


def test_random_soup_matches_brute_force_with_finite_tmax():
    rng = np.random.default_rng(2)
    verts, faces = random_soup(rng)
    scene = vc.Scene()
    scene.add_mesh(verts, faces)
    origins, dirs = random_rays(rng, N_RAYS, -0.2, 1.2)
    tmax = rng.uniform(0.0, 1.0, N_RAYS).astype(np.float32)
    ours, _ = check_against_brute_force(scene, origins, dirs, tmax)
    assert 0.1 < ours.mean() < 0.9


def test_intersect_outputs_are_consistent():
    rng = np.random.default_rng(3)
    verts, faces = random_soup(rng, 200)
    scene = vc.Scene()
    scene.add_mesh(verts, faces)
    o, d = random_rays(rng, 2000, 0.0, 1.0)
    d = d * rng.uniform(0.1, 10.0, (len(d), 1)).astype(np.float32)  # any length
    h = scene.intersect(o, d)
    hit = h["prim"] >= 0
    assert hit.any() and (~hit).any()
    tris = scene.triangles()[h["prim"][hit]].astype(np.float64)
    u, v = h["u"][hit, None], h["v"][hit, None]
    from_bary = (1 - u - v) * tris[:, 0] + u * tris[:, 1] + v * tris[:, 2]
    from_ray = o[hit] + h["t"][hit, None] * d[hit]
    np.testing.assert_allclose(h["position"][hit], from_bary, atol=1e-5)
    np.testing.assert_allclose(from_ray, from_bary, atol=1e-4)
    n = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    np.testing.assert_allclose(h["normal"][hit], n, atol=1e-5)
    assert np.all(np.isinf(h["t"][~hit])) and np.all(h["obj"][~hit] == -1)
    assert np.all(np.isnan(h["position"][~hit]))


def test_agrees_with_embree(cornell):
    rtcs = pytest.importorskip("embreex.rtcore_scene")
    from embreex.mesh_construction import TriangleMesh

    origins, dirs = scene_rays(cornell, seed=4)
    ref = brute_force(cornell.scene.triangles(), origins, dirs)
    firm = ~ref["near_edge"]
    ours = cornell.scene.intersect(origins, dirs)
    for robust in (False, True):
        es = rtcs.EmbreeScene(robust=robust)
        TriangleMesh(es, cornell.scene.triangles())
        out = es.run(origins, dirs, output=1)
        e_hit = out["geomID"] >= 0
        assert np.array_equal(e_hit[firm], np.isfinite(ours["t"])[firm])
        both = e_hit & firm
        np.testing.assert_allclose(ours["t"][both], out["tfar"][both], rtol=1e-5)
        e_occ = es.run(origins, dirs, query="OCCLUDED") >= 0
        assert np.array_equal(e_occ[firm], cornell.scene.occluded(origins, dirs)[firm])


def test_closed_icosphere_does_not_leak():
    """1M rays from inside a closed icosphere aimed exactly at its vertices and at points on
    its shared edges (computed in float32, so within an ulp of the edge): none may escape."""
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    verts = sphere.vertices.astype(np.float32)
    scene = vc.Scene()
    scene.add_mesh(verts, sphere.faces)
    rng = np.random.default_rng(5)
    edges = sphere.edges_unique
    n = 1_000_000
    k = rng.integers(0, len(edges), n)
    s = rng.choice(np.array([0.0, 0.5, 1.0, 0.25], dtype=np.float32), n)
    s = np.where(rng.random(n) < 0.5, s, rng.random(n).astype(np.float32))
    a, b = verts[edges[k, 0]], verts[edges[k, 1]]
    targets = (a + (b - a) * s[:, None]).astype(np.float32)
    origins = np.zeros((n, 3), dtype=np.float32)
    origins[n // 2:] = rng.uniform(-0.3, 0.3, (n - n // 2, 3)).astype(np.float32)
    dirs = targets - origins
    occ = scene.occluded(origins, dirs)
    leaks = int((~occ).sum())
    assert leaks == 0, f"{leaks} of {n} rays leaked"
    h = scene.intersect(origins, dirs)
    assert int((h["prim"] < 0).sum()) == 0
    # They hit at the sphere's surface: t ~ 1 for rays aimed at surface points from inside.
    np.testing.assert_allclose(h["t"], 1.0, atol=2e-5)


@pytest.mark.parametrize("scale", [1e-4, 1e4])
def test_same_answers_at_extreme_scales(cornell, scale):
    tris = cornell.scene.triangles()
    origins, dirs = scene_rays(cornell, seed=6)
    ref = brute_force(tris, origins, dirs)
    firm = ~ref["near_edge"]
    base = cornell.scene.intersect(origins, dirs)
    scaled = scene_from_triangles(tris * np.float32(scale))
    h = scaled.intersect(origins * np.float32(scale), dirs)
    assert np.array_equal(h["prim"][firm] >= 0, base["prim"][firm] >= 0)
    # Scaling by a non-power of two rounds every vertex, so coincident faces may swap.
    clear = firm & ~ref["tie"]
    assert np.array_equal(h["prim"][clear], base["prim"][clear])
    hit = firm & (base["prim"] >= 0)
    err = np.abs(h["t"][hit] / scale - base["t"][hit])
    assert np.all(err <= 2 * ref["t_tolerance"][hit])
    occ = scaled.occluded(origins * np.float32(scale), dirs, tmax=base["t"] * 0.999 * scale)
    assert not occ[hit].any(), "shadow rays stopping short of the first hit are free"


def test_thread_count_does_not_change_answers(dynamics):
    origins, dirs = scene_rays(dynamics, seed=7)
    scene = dynamics.scene
    scene.reset_counters()
    a = scene.intersect(origins, dirs, threads=1)
    c1 = scene.counters()
    scene.reset_counters()
    b = scene.intersect(origins, dirs, threads=2)
    c2 = scene.counters()
    for key in a:
        np.testing.assert_array_equal(a[key], b[key])
    assert c1 == c2, "counters are exact, so thread-independent"
    np.testing.assert_array_equal(scene.occluded(origins, dirs, threads=1),
                                  scene.occluded(origins, dirs, threads=2))


def test_counters_count_exactly(cornell):
    scene = cornell.scene
    origins, dirs = scene_rays(cornell, seed=8)
    scene.counting = True
    scene.reset_counters()
    occ1 = scene.occluded(origins, dirs)
    c = scene.counters()
    assert c["rays"] == N_RAYS
    assert c["nodes"] >= N_RAYS and c["triangles"] > 0
    scene.occluded(origins, dirs)
    c2 = scene.counters()
    assert c2 == {k: 2 * v for k, v in c.items()}
    scene.counting = False
    scene.reset_counters()
    assert np.array_equal(scene.occluded(origins, dirs), occ1)
    assert scene.counters() == {"rays": 0, "nodes": 0, "triangles": 0}
    scene.counting = True
    # A closest-hit query does at least the work of a shadow query on the same rays.
    scene.reset_counters()
    scene.intersect(origins, dirs)
    assert scene.counters()["triangles"] >= c["triangles"]


def test_empty_scene_and_empty_batches():
    scene = vc.Scene()
    o, d = random_rays(np.random.default_rng(9), 100, -1, 1)
    assert not scene.occluded(o, d).any()
    h = scene.intersect(o, d)
    assert np.all(np.isinf(h["t"])) and np.all(h["prim"] == -1)
    empty = np.zeros((0, 3), dtype=np.float32)
    assert scene.occluded(empty, empty).shape == (0,)
    tri = scene_from_triangles(np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], np.float32))
    assert tri.occluded(empty, empty).shape == (0,)
    h = tri.intersect(empty, empty)
    assert h["t"].shape == (0,) and h["position"].shape == (0, 3)
    assert np.all(scene.bounds[0] == np.inf) and np.all(scene.bounds[1] == -np.inf)


def test_degenerate_triangles_never_hit():
    pts = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 0, 0]], dtype=np.float32)
    scene = vc.Scene()
    scene.add_mesh(pts, np.array([[0, 1, 2], [0, 0, 0], [0, 1, 3], [1, 1, 2]]))
    rng = np.random.default_rng(10)
    o, d = random_rays(rng, 5000, -0.5, 2.5)
    # Rays aimed exactly at points of the degenerate segment too.
    d[:2500] = pts[1] * rng.random((2500, 1)).astype(np.float32) - o[:2500]
    assert not scene.occluded(o, d).any()
    assert scene.num_triangles == 4


def test_single_triangle_and_tangent_rays():
    tri = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], np.float32)
    scene = scene_from_triangles(tri)
    o = np.array([[0.2, 0.2, 1], [0.2, 0.2, 0], [-1, 0.2, 0], [0.2, 0.2, -1]], np.float32)
    d = np.array([[0, 0, -1], [0, 0, 1], [1, 0, 0], [0, 0, 1]], np.float32)
    h = scene.intersect(o, d)
    # Ray 1 starts on the plane (t = 0 is inside [0, tmax)); ray 2 is tangent (in-plane).
    assert list(h["prim"]) == [0, 0, -1, 0]
    np.testing.assert_allclose(h["t"], [1, 0, np.inf, 1])
    occ = scene.occluded(o, d, tmax=np.array([1.0, 1.0, 5.0, 1.0]))
    assert list(occ) == [False, True, False, False]


def test_view_shading_rays_leave_the_seen_surfaces_toward_the_viewer_side():
    setup = vc.scenes.load("cornell", detail=0.3)
    passes, seed = 3, 2
    o, d = vc.testing.view_shading_rays(setup, width=16, height=12, passes=passes, seed=seed)
    assert o.dtype == np.float32 and d.dtype == np.float32 and o.shape == d.shape
    assert np.allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-5)
    # The first hits of the same jittered G-buffers, in the same order: each ray starts just
    # off its hit and leaves on the side the viewer sees.
    cam = setup.camera.with_resolution(16, 12)
    points, normals = [], []
    for k in range(passes):
        g = setup.scene.gbuffer(cam, jitter=True, seed=seed * passes + k)
        hit = g["object"] >= 0
        n = g["normal"][hit]
        n = np.where((np.sum(n * g["direction"][hit], axis=1) > 0)[:, None], -n, n)
        points.append(g["position"][hit])
        normals.append(n)
    p, n = np.concatenate(points), np.concatenate(normals)
    assert len(p) == len(o) > 0.9 * passes * 16 * 12
    assert np.allclose(o, p, atol=1e-3)
    assert (np.sum(d * n, axis=1) > 0).all()
    assert (np.sum((o - p) * n, axis=1) > 0).all()
    a, b = vc.testing.view_shading_rays(setup, width=16, height=12, passes=passes, seed=seed)
    assert np.array_equal(a, o) and np.array_equal(b, d)


def test_directions_of_no_representable_length_are_refused(cornell):
    """t is measured in units of a direction's length: a subnormal direction put every hit
    beyond float32 (it reported a hit at t = inf). Its squared length must be a normal
    float32, as for the tracer's own normalisations; a short but normal one still hits."""
    scene = cornell.scene
    origin = np.array([[0.0, 0.5, 3.0]], np.float32)
    for d in ([0, 0, -1e-40], [0, 0, -1e-20], [0, 0, -3e19], [1e-40, 1e-40, 1e-40]):
        for call in (scene.intersect, scene.occluded):
            with pytest.raises(ValueError, match=r"^directions: row 0 must be finite with a len"):
                call(origin, np.array([d], np.float32))
    unit = scene.intersect(origin, [[0, 0, -1]])
    for length in (1e-18, 1e18):
        h = scene.intersect(origin, [[0, 0, -length]])
        assert h["prim"][0] == unit["prim"][0] >= 0
        assert h["t"][0] == pytest.approx(unit["t"][0] / length, rel=1e-5)
        assert np.isfinite(h["t"][0])


def test_directions_are_normalised_in_f64_where_only_the_direction_matters():
    """Entry points that take directions only (octahedral maps, env maps) normalise in f64:
    a subnormal or huge row has a direction."""
    tiny = np.array([[0, 1e-40, 0], [3e38, 0, 0]], np.float32)
    unit = np.array([[0, 1, 0], [1, 0, 0]], np.float32)
    np.testing.assert_array_equal(vc.octahedral.sphere_to_square(tiny),
                                  vc.octahedral.sphere_to_square(unit))
    env = vc.EnvMap.sky((0.3, 1, 0.2), 1e3, 1.0, (0.2, 0.3, 0.8), (0.8, 0.8, 0.8), resolution=32)
    np.testing.assert_array_equal(env.eval(tiny), env.eval(unit))


class _SlowArray:
    """A per-ray `tmax` whose conversion, the last of the call's, hands the GIL to the
    scribbler for a while: origins and directions have been read by then."""

    def __init__(self, values, started):
        self.values, self.started = values, started

    def __array__(self, dtype=None, copy=None):
        self.started.set()
        time.sleep(0.05)
        return self.values if dtype is None else self.values.astype(dtype)


def _scribble(origins, dirs, started, done):
    started.wait(10)
    while not done.is_set():
        np.negative(dirs, out=dirs)
        np.add(origins, 0.25, out=origins)


def test_a_thread_writing_the_inputs_during_the_call_cannot_change_the_answer(cornell):
    """Inputs are copied under the GIL before it is released: another thread writing them
    meanwhile (flipping the directions, moving the origins) changes nothing."""
    scene = cornell.scene
    origins, dirs = random_rays(np.random.default_rng(3), 20_000, *scene.bounds)
    tmax = np.full(len(origins), np.inf, np.float32)
    expected = scene.intersect(origins.copy(), dirs.copy(), tmax)
    expected_occ = scene.occluded(origins.copy(), dirs.copy(), tmax)
    for call, want in ((scene.intersect, expected), (scene.occluded, expected_occ)):
        o, d = origins.copy(), dirs.copy()
        started, done = threading.Event(), threading.Event()
        t = threading.Thread(target=_scribble, args=(o, d, started, done))
        t.start()
        try:
            got = call(o, d, _SlowArray(tmax, started))
        finally:
            started.set()
            done.set()
            t.join()
        assert not np.array_equal(d, dirs) or not np.array_equal(o, origins), "never scribbled"
        if isinstance(want, dict):
            for key in want:
                np.testing.assert_array_equal(got[key], want[key], err_msg=key)
        else:
            np.testing.assert_array_equal(got, want)
