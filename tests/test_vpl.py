"""Virtual point lights (``vc.VPLs``) and the many-light renderer (``method="vpl"`` and
``"vpl_sampled"``): known answers for the VPLs' flux and for eq. 6.1, convergence to the
path-traced one-bounce image, the sampled gather's unbiasedness, determinism, bad input."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
import viscache_rs as vc
from viscache_rs import vpl as vpl_module

ALBEDO = np.array([0.5, 0.3, 0.8])


def furnace() -> vc.Setup:
    """The inside of a closed sphere of Lambert ``ALBEDO`` emitting radiance 1 inwards."""
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    scene = vc.Scene()
    faces = np.asarray(sphere.faces)[:, ::-1]
    obj = scene.add_mesh(np.asarray(sphere.vertices), faces, vc.Material.lambert(ALBEDO))
    scene.set_emitter(obj, [1.0, 1.0, 1.0])
    camera = vc.Camera.look_at([0.0, 0.1, 0.2], [0.3, -0.2, -1.0], fov_deg=60.0,
                               width=12, height=8)
    return vc.Setup(scene, camera, vc.EnvMap.constant(0.0, resolution=8)), sphere.area


def plane(envmap) -> vc.Setup:
    """A 2 x 2 Lambert plane at y = 0 seen from above."""
    scene = vc.Scene()
    v = np.array([[-1, 0, -1], [1, 0, -1], [1, 0, 1], [-1, 0, 1]], float)
    scene.add_mesh(v, np.array([[0, 2, 1], [0, 3, 2]]), vc.Material.lambert([0.6] * 3))
    camera = vc.Camera.look_at([0.0, 3.0, 0.1], [0, 0, 0], fov_deg=50.0, width=16, height=12)
    return vc.Setup(scene, camera, envmap)


def flux_and_se(vpls, bounce: int) -> tuple[np.ndarray, np.ndarray]:
    """Sum of the fluxes of generation ``bounce`` and its standard error over the paths
    (each path holds at most one VPL of a generation)."""
    x = vpls.flux[vpls.bounces == bounce].astype(np.float64)
    p = vpls.stats["paths"]
    s = x.sum(axis=0)
    var = ((x**2).sum(axis=0) - s**2 / p) * p / (p - 1)
    return s, np.sqrt(np.maximum(var, 0))


def test_a_constant_map_sends_two_pi_l_a_onto_a_plane():
    radiance = np.array([0.5, 1.0, 2.0])
    vpls = vc.VPLs.trace(plane(vc.EnvMap.constant(radiance, resolution=16)), count=30_000,
                         seed=1, importance=False, threads=2)
    got, se = flux_and_se(vpls, 1)
    want = 2 * np.pi * radiance * 4.0  # both sides of A = 4 m^2
    np.testing.assert_array_less(np.abs(got - want), 4 * se)
    assert np.all(se < 0.05 * want)
    assert len(vpls) == vpls.positions.shape[0] == vpls.normals.shape[0] > 25_000
    assert vpls.flux.dtype == np.float32 and vpls.flux.shape == (len(vpls), 3)
    # Surface VPLs lie on the plane, their normals facing the side the photon came from.
    on = vpls.kinds == 2
    np.testing.assert_allclose(vpls.positions[on, 1], 0.0, atol=1e-5)
    np.testing.assert_allclose(np.abs(vpls.normals[on, 1]), 1.0, atol=1e-6)


def test_an_area_light_in_a_closed_sphere_puts_its_power_in_each_bounce():
    setup, area = furnace()
    vpls = vc.VPLs.trace(setup, count=20_000, depth=2, seed=2, importance=False, threads=2)
    power = np.pi * area  # radiance 1 over the inner surface
    # Every photon hits the sphere, and a Lambert bounce keeps exactly the albedo.
    for bounce, want in [(0, power * np.ones(3)), (1, power * np.ones(3)), (2, power * ALBEDO)]:
        got = vpls.flux[vpls.bounces == bounce].astype(np.float64).sum(axis=0)
        np.testing.assert_allclose(got, want, rtol=1e-4)


def test_a_textured_light_sends_each_texel_its_power():
    """A quad light red on one half, green on the other: light VPLs carry the power of the
    texel they start on, so the red ones sit on the red half."""
    scene = vc.Scene()
    scene.add_mesh(np.array([[-5, 0, -5], [5, 0, -5], [5, 0, 5], [-5, 0, 5]], float),
                   np.array([[0, 2, 1], [0, 3, 2]]))
    light = scene.add_area_light(np.array([[-1, 1, -0.5], [1, 1, -0.5], [1, 1, 0.5],
                                           [-1, 1, 0.5]], float), (1, 1, 1))
    scene.set_emission_texture(light, np.array([[[3, 0, 0], [0, 1, 0]]], np.float32))
    cam = vc.Camera.look_at((0, 3, 0.01), (0, 0, 0), width=8, height=6)
    setup = vc.Setup(scene, cam, vc.EnvMap.constant(0.0, resolution=4))
    vpls = vc.VPLs.trace(setup, count=4_000, seed=3, importance=False, threads=2)
    got, se = flux_and_se(vpls, 0)
    want = np.pi * 2.0 * np.array([1.5, 0.5, 0.0])  # pi A times the texture's mean
    np.testing.assert_array_less(np.abs(got - want), 4 * se + 1e-6)
    on_light = vpls.bounces == 0
    x, red = vpls.positions[on_light, 0], vpls.flux[on_light, 0] > 0
    assert np.all(x[red] <= 1e-6) and np.all(x[~red] >= -1e-6)


def test_one_light_vpl_over_a_plane_gives_eq_6_1():
    setup = plane(vc.EnvMap.constant(0.0, resolution=8))
    h, phi, at = 1.5, np.array([2.0, 1.0, 0.5]), np.array([0.3, 1.5, 0.2])
    vpls = vc.VPLs.from_lights(setup.scene, at[None], [[0, -1, 0]], phi[None])
    res = vc.render(setup, method="vpl", vpls=vpls, jitter=False, progress=False)
    hits = setup.scene.intersect(*primary_rays(setup.camera))
    d2 = ((hits["position"] - at) ** 2).sum(axis=1)
    want = 0.6 * phi * h * h / (np.pi**2 * d2[:, None] ** 2)
    seen = np.isfinite(hits["t"])
    got = res.image.reshape(-1, 3)
    np.testing.assert_allclose(got[seen], want[seen], rtol=1e-4)
    assert np.all(got[~seen] == 0)
    s = res.stats
    assert s["vpls"] == 1 and s["shadow_rays"] == seen.sum() and s["method"] == "vpl"
    assert s["seconds"] > 0 and s["rays_per_second"] > 0 and s["shadow_rays_per_second"] > 0


def primary_rays(camera):
    """Rays through the pixels' centres, row-major."""
    w, h = camera.width, camera.height
    t = np.tan(np.radians(camera.fov_deg) / 2)
    x, y = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    sx = (2 * x / w - 1) * t * w / h
    sy = (1 - 2 * y / h) * t
    fwd, right, up = (np.asarray(a) for a in (camera.forward, camera.right, camera.up))
    d = fwd + sx.reshape(-1, 1) * right + sy.reshape(-1, 1) * up
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return np.broadcast_to(np.asarray(camera.eye), d.shape).copy(), d


def blocks(x):
    """4 x 4 pixel means of a 24 x 32 image."""
    return x.reshape(6, 4, 8, 4, 3).mean(axis=(1, 3))


def test_vpl_image_converges_to_the_path_traced_one_bounce_image():
    setup = vc.scenes.load("cornell")
    cam = setup.camera.with_resolution(32, 24)
    ref = vc.render(setup, camera=cam, method="path", bounces=1, direct=False, spp=1024,
                    seed=1, threads=2, progress=False)
    r = blocks(ref.image)
    ref_noise = np.mean(blocks(ref.variance) / 16 / (r**2 + 1e-2))
    errors = {}
    for n in (1000, 4000, 16000):
        e = []
        for seed in range(3):
            vpls = vc.VPLs.trace(setup, count=n, seed=seed, threads=2)
            res = vc.render(setup, camera=cam, method="vpl", vpls=vpls, direct=False,
                            seed=seed, threads=2, progress=False)
            e.append(np.mean((blocks(res.image) - r) ** 2 / (r**2 + 1e-2)) - ref_noise)
        errors[n] = (np.mean(e), np.std(e, ddof=1) / np.sqrt(len(e)))
    # Measured (block relMSE less the reference's noise, 3 seeds): 1.0e-3, 4.1e-4, 2.0e-4
    # with SE 2e-4, 1e-5, 4e-6: each step falls by well over its standard errors (less than
    # 4x at the end: one jittered sample per pixel adds its own noise to the blocks).
    for small, large in [(1000, 4000), (4000, 16000)]:
        (e0, s0), (e1, s1) = errors[small], errors[large]
        assert e1 + 2 * s1 < e0 - 2 * s0, errors
    assert errors[16000][0] < 5e-4, errors


@pytest.mark.parametrize("sampling", [None, "uniform", "power", "unoccluded"])
def test_sampled_gather_is_unbiased_for_the_full_sum(sampling):
    setup = vc.scenes.load("cornell")
    cam = setup.camera.with_resolution(16, 12)
    vpls = vc.VPLs.trace(setup, count=800, seed=4, threads=2)
    kw = dict(camera=cam, vpls=vpls, jitter=False, spp=4, threads=2, progress=False)
    full = vc.render(setup, method="vpl", **kw)
    sampled = vc.render(setup, method="vpl_sampled", vpl_samples=16, seed=3,
                        sampling=sampling, **kw)
    diff = (sampled.image - full.image).astype(np.float64).sum(axis=(0, 1))
    se = np.sqrt(sampled.variance.astype(np.float64).sum(axis=(0, 1)))
    assert np.all(se > 0)
    np.testing.assert_array_less(np.abs(diff), 4 * se)
    assert sampled.stats["vpl_samples"] == 16
    assert sampled.stats["sampling"] == (sampling or "unoccluded")
    assert full.stats["sampling"] is None
    assert sampled.stats["shadow_rays"] <= 4 * 16 * 16 * 12 < full.stats["shadow_rays"]


def test_direct_and_indirect_parts_add_up():
    setup = vc.scenes.load("cornell")
    cam = setup.camera.with_resolution(16, 12)
    vpls = vc.VPLs.trace(setup, count=2000, seed=5, threads=2)
    kw = dict(camera=cam, vpls=vpls, jitter=False, threads=2, progress=False)
    both = vc.render(setup, method="vpl", **kw)
    indirect = vc.render(setup, method="vpl", direct=False, **kw)
    assert np.all(both.image >= indirect.image) and np.any(both.image > 2 * indirect.image)
    assert indirect.stats["vpls"] == int((vpls.bounces >= 1).sum()) < both.stats["vpls"]
    # A clamp of the geometry term only removes light.
    clamped = vc.render(setup, method="vpl", clamp=0.5, **kw)
    assert np.all(clamped.image <= both.image * (1 + 1e-6))


@pytest.mark.parametrize("method,sampling", [("vpl", None), ("vpl_sampled", None),
                                             ("vpl_sampled", "power"),
                                             ("vpl_sampled", "uniform")])
def test_renders_and_sets_are_bit_identical_for_any_thread_count(method, sampling):
    setup = vc.scenes.load("garage")
    cam = setup.camera.with_resolution(20, 14)
    a, b = (vc.VPLs.trace(setup, count=1500, seed=7, depth=2, threads=t) for t in (1, 2))
    np.testing.assert_array_equal(a.flux, b.flux)
    np.testing.assert_array_equal(a.positions, b.positions)
    ra, rb = (vc.render(setup, camera=cam, method=method, vpls=a, spp=2, threads=t,
                        sampling=sampling, progress=False) for t in (1, 2))
    np.testing.assert_array_equal(ra.image, rb.image)
    np.testing.assert_array_equal(ra.variance, rb.variance)


def test_bad_input_is_named():
    setup = vc.scenes.load("cornell")
    cam = setup.camera.with_resolution(8, 6)
    for count in (0, -3):
        with pytest.raises(ValueError, match="count"):
            vc.VPLs.trace(setup, count=count)
    with pytest.raises(ValueError, match="depth"):
        vc.VPLs.trace(setup, count=10, depth=0)
    with pytest.raises(ValueError, match="bounces"):
        vc.render(setup, camera=cam, method="vpl", bounces=0, progress=False)
    dark = plane(vc.EnvMap.constant(0.0, resolution=8))
    with pytest.raises(ValueError, match="setup"):
        vc.VPLs.trace(dark, count=10)
    with pytest.raises(ValueError, match="flux"):
        vc.VPLs.from_lights(dark.scene, [[0, 1, 0]], [[0, -1, 0]], [[np.nan, 1, 1]])
    with pytest.raises(ValueError, match="flux"):
        vc.VPLs.from_lights(dark.scene, [[0, 1, 0]], [[0, -1, 0]], [[-1, 1, 1]])
    vpls = vc.VPLs.trace(setup, count=50)
    for clamp in (-1.0, 0.0, np.nan):
        with pytest.raises(ValueError, match="clamp"):
            vc.render(setup, camera=cam, method="vpl", vpls=vpls, clamp=clamp, progress=False)
    with pytest.raises(ValueError, match="vpl_samples"):
        vc.render(setup, camera=cam, method="vpl", vpls=vpls, vpl_samples=4, progress=False)
    with pytest.raises(ValueError, match="vpl_samples"):
        vc.render(setup, camera=cam, method="vpl_sampled", vpls=vpls, vpl_samples=0,
                  progress=False)
    with pytest.raises(ValueError, match="vpls"):
        vc.render(setup, camera=cam, method="mis", vpls=vpls, progress=False)
    with pytest.raises(ValueError, match="sampling"):
        vc.render(setup, camera=cam, method="vpl", vpls=vpls, sampling="power", progress=False)
    for bad in ("Power", "", "cache"):
        with pytest.raises(ValueError, match="sampling"):
            vc.render(setup, camera=cam, method="vpl_sampled", vpls=vpls, sampling=bad,
                      progress=False)
    with pytest.raises(TypeError, match="sampling"):
        vc.render(setup, camera=cam, method="vpl_sampled", vpls=vpls, sampling=2,
                  progress=False)
    with pytest.raises(TypeError, match="vpls"):
        vc.render(setup, camera=cam, method="vpl", vpls="many", progress=False)
    with pytest.raises(ValueError, match="vpls"):
        vc.render(plane(setup.envmap), method="vpl", vpls=vpls, progress=False)
    # Without a set, one is traced with depth = bounces.
    res = vc.render(setup, camera=cam, method="vpl", bounces=2, progress=False)
    assert res.stats["bounces"] == 2 and res.stats["vpls"] > 1000


def test_a_time_budget_and_a_progress_bar():
    setup = vc.scenes.load("cornell")
    cam = setup.camera.with_resolution(16, 12)
    vpls = vc.VPLs.trace(setup, count=300, seed=1)
    res = vc.render(setup, camera=cam, method="vpl", vpls=vpls, time_budget=0.2, threads=2,
                    progress=True)
    assert 1 <= res.stats["spp"] and res.stats["complete"]
    assert np.all(np.isfinite(res.variance)) or res.stats["spp"] == 1
    # Every pixel took at least stats["spp"]; the probe's bands may have taken more.
    assert res.stats["samples"] >= res.stats["spp"] * 16 * 12


@pytest.mark.parametrize("direct", [True, False])
def test_a_render_given_no_vpls_traces_the_cores_default_set(direct):
    """Without ``vpls`` the core traces ``DEFAULT_COUNT`` VPLs of depth ``bounces`` (light
    VPLs only with ``direct``): the same image as that set given by hand, bit for bit."""
    setup = vc.scenes.load("cornell", detail=0.3)
    setup.camera = setup.camera.with_resolution(24, 18)
    own = vc.render(setup, method="vpl", bounces=2, direct=direct, seed=3, threads=2,
                    progress=False)
    given = vc.VPLs.trace(setup, vpl_module.DEFAULT_COUNT, seed=3, depth=2, lights=direct,
                          threads=2)
    by_hand = vc.render(setup, method="vpl", vpls=given, direct=direct, seed=3, threads=2,
                        progress=False)
    np.testing.assert_array_equal(own.image, by_hand.image)
    assert own.stats["vpls"] == by_hand.stats["vpls"] == len(given)
    assert own.stats["bounces"] == by_hand.stats["bounces"] == int(given.bounces.max())
    assert own.stats["vpl_trace_seconds"] > 0 and "vpl_trace_seconds" not in by_hand.stats
    assert vpl_module.DEFAULT_COUNT == 4096 and vpl_module.DEFAULT_SAMPLES == 16
