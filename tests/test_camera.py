"""Camera conventions and the G-buffer."""

import numpy as np
import pytest
import viscache_rs as vc


def test_look_at_frame_and_vertical_fov():
    cam = vc.Camera.look_at((0, 0, 5), (0, 0, 0), fov_deg=60, width=40, height=20)
    np.testing.assert_allclose(cam.forward, (0, 0, -1), atol=1e-7)
    np.testing.assert_allclose(cam.right, (1, 0, 0), atol=1e-7)
    np.testing.assert_allclose(cam.up, (0, 1, 0), atol=1e-7)
    o, d = cam.rays(jitter=False)
    assert o.shape == d.shape == (800, 3)
    d = d.reshape(20, 40, 3)
    # Top row of pixel centres is half a pixel below the frustum's top edge.
    top = np.degrees(np.arctan2(d[0, 20, 1], -d[0, 20, 2]))
    assert top == pytest.approx(np.degrees(np.arctan(np.tan(np.radians(30)) * 19 / 20)), abs=1e-4)
    assert d[0, 0, 0] < 0 and d[0, 0, 1] > 0, "row 0 is the top, column 0 the left"
    small = cam.with_resolution(4, 2)
    assert (small.width, small.height, small.fov_deg) == (4, 2, 60)


@pytest.mark.parametrize(
    "kwargs, name",
    [
        (dict(eye=(0, 0, 0), target=(0, 0, 0)), "target"),
        (dict(eye=(0, 0, 0), target=(0, 1, 0)), "up"),
        (dict(eye=(0, 0, 0), target=(1, 0, 0), fov_deg=0), "fov_deg"),
        (dict(eye=(0, 0, 0), target=(1, 0, 0), width=0), "width"),
        (dict(eye=(0, 0, 0), target=(1, 0, 0), height=10**9), "height"),
        (dict(eye=(np.nan, 0, 0), target=(1, 0, 0)), "eye"),
        (dict(eye=(0, 0), target=(1, 0, 0)), "eye"),
    ],
)
def test_look_at_rejects_bad_arguments(kwargs, name):
    with pytest.raises(ValueError, match=f"^{name}"):
        vc.Camera.look_at(**kwargs)


def test_gbuffer_matches_intersect(cornell):
    cam = cornell.camera.with_resolution(32, 24)
    g = cornell.scene.gbuffer(cam, seed=3)
    o, d = cam.rays(seed=3)
    h = cornell.scene.intersect(o, d)
    np.testing.assert_array_equal(g["prim"].ravel(), h["prim"])
    np.testing.assert_array_equal(g["depth"].ravel(), h["t"])
    np.testing.assert_allclose(g["direction"].reshape(-1, 3), d)
    hit = h["prim"] >= 0
    n = g["normal"].reshape(-1, 3)[hit]
    np.testing.assert_allclose(np.abs(n), np.abs(h["normal"][hit]))
    assert np.all(np.einsum("ij,ij->i", n, d[hit]) <= 0), "normals face the camera"
    assert g["object"].shape == (24, 32) and g["position"].shape == (24, 32, 3)
    g2 = cornell.scene.gbuffer(cam, seed=3, threads=1)
    for key in g:
        np.testing.assert_array_equal(g[key], g2[key])
    assert not np.array_equal(cornell.scene.gbuffer(cam, seed=4)["position"], g["position"])


def test_footprint_is_the_projected_pixel():
    s = vc.Scene()
    s.add_mesh(np.array([[-50, -50, 0], [50, -50, 0], [50, 50, 0], [-50, 50, 0]]),
               np.array([[0, 1, 2], [0, 2, 3]]))
    cam = vc.Camera.look_at((0, 0, 10), (0, 0, 0), fov_deg=40, width=64, height=64)
    g = s.gbuffer(cam, jitter=False)
    side = 2 * 10 * np.tan(np.radians(20)) / 64  # face-on pixel side at the centre
    centre = g["footprint"][31:33, 31:33]
    np.testing.assert_allclose(centre, side, rtol=2e-3)
    # Tilted view: the footprint grows by 1/sqrt(cos) relative to the solid angle.
    tilted = vc.Camera.look_at((0, 5, 5), (0, 0, 0), fov_deg=10, width=9, height=9)
    gt = s.gbuffer(tilted, jitter=False)
    pixel_sr = (2 * np.tan(np.radians(5)) / 9) ** 2
    expect = np.sqrt(pixel_sr / np.cos(np.radians(45))) * np.sqrt(50)
    assert gt["footprint"][4, 4] == pytest.approx(expect, rel=1e-3)


def test_gbuffer_misses():
    s = vc.Scene()
    cam = vc.Camera.look_at((0, 0, 1), (0, 0, 0), width=4, height=3)
    g = s.gbuffer(cam)
    assert np.all(g["object"] == -1) and np.all(np.isinf(g["depth"]))
    assert np.all(np.isinf(g["footprint"])) and np.all(np.isnan(g["position"]))


@pytest.mark.parametrize(
    "eye, target, up",
    [
        ((0, 0, 1e20), (0, 0, 0), (0, 1, 0)),
        ((0, 0, 1e30), (0, 0, 0), (0, 1, 0)),
        ((0, 0, 3.4e38), (0, 0, 0), (0, 1, 0)),
        ((0, 0, 3.4e38), (0, 0, -3.4e38), (0, 1, 0)),
        ((0, 0, 1e-29), (0, 0, 0), (0, 1, 0)),
        ((0, 0, 5), (0, 0, 0), (0, 1e-40, 0)),
        ((0, 0, 5), (0, 0, 0), (0, 1e30, 0)),
    ],
)
def test_extreme_but_valid_cameras_are_formed(eye, target, up):
    """Normalised in f64, then judged: lengths that over- or underflow in float32 still
    give the camera looking down -z."""
    cam = vc.Camera.look_at(eye, target, up=up, width=4, height=4)
    np.testing.assert_array_equal(cam.forward, (0, 0, -1))
    np.testing.assert_array_equal(cam.right, (1, 0, 0))
    np.testing.assert_array_equal(cam.up, (0, 1, 0))


@pytest.mark.parametrize(
    "eye, target, up, message",
    [
        ((1, 2, 3), (1, 2, 3), (0, 1, 0), "^target: must differ from eye"),
        ((0, 0, 5), (0, 0, 0), (0, 0, 0), "^up: must be non-zero"),
        ((0, 0, 0), (0, 1e-30, 0), (0, -1e-40, 0), "^up: must not be parallel"),
    ],
)
def test_impossible_cameras_say_why(eye, target, up, message):
    with pytest.raises(ValueError, match=message):
        vc.Camera.look_at(eye, target, up=up, width=4, height=4)
