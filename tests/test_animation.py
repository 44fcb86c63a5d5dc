"""Animated setups: the rolling sphere of `dynamics`, frames, the refit BVH against brute
force, shadows near and far from the moving object, and argument checks."""

import numpy as np
import pytest
import viscache_rs as vc
from conftest import brute_force

SUN = np.radians([300.0, 45.0])  # the dynamics sun: azimuth, elevation
SUN_DIR = np.array(
    [np.sin(SUN[0]) * np.cos(SUN[1]), np.sin(SUN[1]), -np.cos(SUN[0]) * np.cos(SUN[1])],
    dtype=np.float32,
)


@pytest.fixture(scope="module")
def still():
    return vc.scenes.load("dynamics")


def animated():
    return vc.scenes.load("dynamics", animated=True)


def moving_mask(setup):
    return setup.scene.object_ids() == setup.moving_object


def test_animated_dynamics_starts_as_the_static_scene(still):
    a = animated()
    assert vc.scenes.animated_names() == ["dynamics"]
    assert a.animated and a.frame == 0 and a.period == 60
    assert a.scene.object_names()[a.moving_object] == "sphere"
    np.testing.assert_array_equal(a.scene.triangles(), still.scene.triangles())
    b = a.moving_bounds()
    assert b.shape == (2, 3) and b.dtype == np.float32
    np.testing.assert_allclose((b[0] + b[1]) / 2, [0.2, 0.8, 0.6], atol=0.02)
    a.at_frame(0)
    np.testing.assert_array_equal(a.scene.triangles(), still.scene.triangles())
    assert "frame=0" in repr(a)


def test_static_setups_have_only_frame_zero(still):
    s = vc.scenes.load("cornell")
    assert not s.animated and s.moving_object is None and s.period is None
    assert s.moving_bounds() is None
    before = s.scene.triangles()
    s.at_frame(0)
    with pytest.raises(ValueError, match="^frame"):
        s.at_frame(1)
    assert s.frame == 0
    np.testing.assert_array_equal(s.scene.triangles(), before)
    custom = vc.Setup(still.scene, still.camera, still.envmap)
    assert custom.moving_object is None
    with pytest.raises(ValueError, match="^frame"):
        custom.at_frame(3)


def test_at_frame_moves_only_the_sphere(still):
    a = animated()
    rest = still.scene.triangles()
    sphere = moving_mask(a)
    for frame in [1, 15, 30, 59, 60, 61, 10**12]:
        a.at_frame(frame)
        assert a.frame == frame
        tris = a.scene.triangles()
        np.testing.assert_array_equal(tris[~sphere], rest[~sphere])
        assert np.array_equal(tris[sphere], rest[sphere]) == (frame % 60 == 0)
        b = a.moving_bounds()
        pts = tris[sphere].reshape(-1, 3)
        np.testing.assert_array_equal(b, np.stack([pts.min(0), pts.max(0)]))
        assert -1e-4 < b[0, 1] < 0.01, "the sphere rolls on the ground"
    # Half way through a period the sphere is 2 m along (-1, 0, 1).
    a.at_frame(30)
    centre = a.moving_bounds().mean(axis=0)
    np.testing.assert_allclose(centre, [0.2 - 2 / np.sqrt(2), 0.8, 0.6 + 2 / np.sqrt(2)], atol=0.02)


def test_frames_do_not_depend_on_history():
    a, b = animated(), animated()
    for f in [17, 3, 59, 42]:
        a.at_frame(f)
    b.at_frame(np.int64(42))
    ta, tb = a.scene.triangles(), b.scene.triangles()
    np.testing.assert_array_equal(ta.view(np.uint32), tb.view(np.uint32))
    o, d = rays_around(a, 3000, seed=4)
    ha, hb = a.scene.intersect(o, d), b.scene.intersect(o, d)
    np.testing.assert_array_equal(ha["t"], hb["t"])
    np.testing.assert_array_equal(ha["prim"], hb["prim"])


def rays_around(setup, n, seed):
    """Rays from points within 1 m of the moving object's box, in uniform directions."""
    lo, hi = setup.moving_bounds()
    rng = np.random.default_rng(seed)
    o = rng.uniform(lo - 1.0, hi + 1.0, (n, 3)).astype(np.float32)
    d = rng.normal(size=(n, 3))
    return o, (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)


@pytest.mark.parametrize("frame", [7, 30])
def test_occluded_matches_brute_force_after_moving(frame):
    a = animated()
    a.scene.build()  # built at the rest pose, then refit by at_frame
    a.at_frame(frame)
    o, d = rays_around(a, 1500, seed=frame)
    for tmax in [np.inf, 0.7]:
        ref = brute_force(a.scene.triangles(), o, d, tmax)
        occ = a.scene.occluded(o, d, tmax=tmax)
        hits = a.scene.intersect(o, d, tmax=tmax)
        firm = ~ref["near_edge"]
        expected = np.isfinite(ref["t"])
        assert np.array_equal(occ[firm], expected[firm])
        assert np.array_equal(np.isfinite(hits["t"]), occ)
        clear = firm & expected & ~ref["tie"]
        np.testing.assert_array_equal(hits["prim"][clear], ref["prim"][clear])
        if tmax == np.inf:
            assert (hits["obj"] == a.moving_object).mean() > 0.05, "rays see the sphere"


def ground_grid(half=6.0, step=0.25):
    xs = np.arange(-half, half + 1e-6, step, dtype=np.float32)
    x, z = np.meshgrid(xs, xs)
    return np.stack([x.ravel(), np.full(x.size, 1e-3, np.float32), z.ravel()], axis=1)


def on_ground_outside_objects(scene, pts):
    """Points not covered by an object (a ray straight up from them is free)."""
    up = np.tile(np.float32([0, 1, 0]), (len(pts), 1))
    return pts[~scene.occluded(pts, up)]


def test_shadows_change_near_the_sphere_and_nowhere_else():
    a = animated()
    pts = on_ground_outside_objects(a.scene, ground_grid())
    sun = np.tile(SUN_DIR, (len(pts), 1))
    centres, shadowed = [], []
    for frame in [0, 30]:
        a.at_frame(frame)
        centres.append(a.moving_bounds().mean(axis=0))
        shadowed.append(a.scene.occluded(pts, sun))
    changed = shadowed[0] != shadowed[1]
    assert changed.sum() > 20, "the sphere's shadow moves"
    # A shadow point lies at most (height 1.6 m) / tan(45 deg) + radius from under the
    # sphere, along the sun's azimuth: within 2.6 m of either centre on the ground plane.
    dist = np.min([np.linalg.norm((pts - c)[:, [0, 2]], axis=1) for c in centres], axis=0)
    assert dist[changed].max() < 2.6
    # Far from the sphere (> 5 m from both positions) sky visibility barely changes.
    far = pts[dist > 5.0]
    rng = np.random.default_rng(2)
    d = rng.normal(size=(64, 3))
    d[:, 1] = np.abs(d[:, 1])
    d = (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)
    o = np.repeat(far, len(d), axis=0)
    dirs = np.tile(d, (len(far), 1))
    vis = []
    for frame in [0, 30]:
        a.at_frame(frame)
        vis.append(a.scene.occluded(o, dirs))
    assert (vis[0] != vis[1]).mean() < 0.01


def test_gbuffer_and_render_follow_the_frames():
    a = animated()
    cam = a.camera.with_resolution(64, 48)
    gs = []
    for frame in [0, 15, 30]:
        a.at_frame(frame)
        g = a.scene.gbuffer(cam, jitter=False)
        assert (g["object"] == a.moving_object).sum() > 50, "the camera sees the sphere"
        gs.append(g["object"])
    for g0, g1 in [(gs[0], gs[1]), (gs[1], gs[2])]:
        diff = g0 != g1
        assert diff.any()
        assert np.all((g0[diff] == a.moving_object) | (g1[diff] == a.moving_object))
    small = cam.with_resolution(32, 24)
    images = []
    for frame in [0, 30]:
        a.at_frame(frame)
        images.append(vc.render(a, camera=small, spp=2, method="env", progress=False).image)
    assert not np.array_equal(images[0], images[1])


def test_bad_frame_arguments_change_nothing():
    a = animated()
    a.at_frame(5)
    before = a.scene.triangles()
    for bad, err in [
        (-1, ValueError),
        (2**64, ValueError),
        (1.5, TypeError),
        (2.0, TypeError),
        ("3", TypeError),
        (True, TypeError),
        (None, TypeError),
    ]:
        with pytest.raises(err, match="^frame"):
            a.at_frame(bad)
        assert a.frame == 5
        np.testing.assert_array_equal(a.scene.triangles(), before)
    with pytest.raises(ValueError, match="^animated"):
        vc.scenes.load("garage", animated=True)
    with pytest.raises(ValueError, match="^name"):
        vc.scenes.load("nope", animated=True)
    with pytest.raises(ValueError, match="^detail"):
        vc.scenes.load("dynamics", detail=0.0, animated=True)
