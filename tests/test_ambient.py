"""Ambient occlusion (CAM08 sec. 6.1) from Python: the reference against known answers
(open plane, closed box, a wall's view factor), cache AO and the sec. 6.1 criterion against a
numpy re-implementation over the records the cache reports, determinism, extremes and bad
input."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import viscache_rs as vc


def quads_scene(quads, scale=1.0) -> vc.Scene:
    """One object per quad (4 corners each)."""
    scene = vc.Scene()
    for q in quads:
        v = np.asarray(q, np.float32) * scale
        scene.add_mesh(v, np.array([[0, 1, 2], [0, 2, 3]]))
    return scene


def floor_and_wall(scale=1.0, wall_x=1.0, height=1.5, wall=True) -> vc.Scene:
    """Floor y = 0 (object 0) and a wall x = wall_x of the given height, 200 long in z."""
    quads = [[(-10, 0, -10), (10, 0, -10), (10, 0, 10), (-10, 0, 10)]]
    if wall:
        quads.append([(wall_x, 0, -100), (wall_x, 0, 100), (wall_x, height, 100),
                      (wall_x, height, -100)])
    return quads_scene(quads, scale)


def setup_of(scene, eye, target, w=32, h=24, fov=50.0, scale=1.0):
    cam = vc.Camera.look_at(np.multiply(eye, scale), np.multiply(target, scale),
                            fov_deg=fov, width=w, height=h)
    return SimpleNamespace(scene=scene, camera=cam)


@pytest.fixture(scope="module")
def wall_setup():
    return setup_of(floor_and_wall(), (-2.0, 2.0, 0.0), (0.5, 0.0, 0.0))


def test_reference_on_an_open_plane_is_one():
    s = setup_of(floor_and_wall(wall=False), (0, 3, 0.01), (0, 0, 0), fov=40)
    r = vc.render_ao(s, reference_rays=64, progress=False)
    assert r.image.shape == (24, 32)
    assert np.all(r.image == 1.0)
    assert r.stats["rays_per_point"] == 64 and r.stats["complete"]


def test_reference_and_cache_inside_a_closed_box_are_zero():
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], np.float32)
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    box = quads_scene([corners[list(f)] for f in faces])
    s = setup_of(box, (0, 0, 0.5), (0, -1, -0.3), w=16, h=12, fov=60)
    ref = vc.render_ao(s, reference_rays=256, progress=False)
    assert np.all(ref.image == 0.0)
    cache = vc.render_ao(s, progress=False, resolution=8)
    assert np.all(cache.image == 0.0)


def test_reference_beside_a_wall_matches_its_view_factor(wall_setup):
    """Floor pixels at distance h from a wall of height H (lowered by the ray offset) see
    A = (1 + h / sqrt(h^2 + H^2)) / 2; the mean residual must lie within 4 standard errors
    computed from the residuals' spread."""
    s = wall_setup
    r = vc.render_ao(s, reference_rays=256, seed=3, progress=False)
    g = s.scene.gbuffer(s.camera, jitter=False)
    floor = (g["object"] == 0).ravel()
    pos = g["position"].reshape(-1, 3)[floor]
    origin = s.scene.offset_points(pos, np.tile([0, 1, 0], (len(pos), 1)).astype(np.float32))
    h = 1.0 - origin[:, 0].astype(np.float64)
    height = 1.5 - origin[:, 1].astype(np.float64)
    expected = 0.5 * (1 + h / np.sqrt(h * h + height * height))
    resid = r.image.ravel()[floor] - expected
    assert len(resid) > 300
    se = resid.std(ddof=1) / np.sqrt(len(resid))
    assert se > 0
    assert abs(resid.mean()) < 4 * se, (resid.mean(), se)


def brute_cache_ao(cache, gb, sigma_scale, min_radius_scale):
    """Sec. 6.1 over every record by numpy: the m nearest within d_max and theta_max, the
    Gaussian average of their A and the criterion max w_i (1 - d/R_i). Returns (ao,
    coverage, ambiguous): pixels with a record within rounding of a boundary are flagged."""
    p = cache.params
    rec = cache.records()
    pos, nrm = rec["position"].astype(np.float64), rec["normal"].astype(np.float64)
    ao, radius = rec["ao"].astype(np.float64), rec["nearest_hit_distance"].astype(np.float64)
    theta_max = np.radians(p["theta_max_deg"])
    lam = p["lambda_falloff"]

    def w9(x, t):
        return (1 - t / np.pi) * (1 - x / (1 + lam * x))

    w_lo = w9(1.0, theta_max)
    n_px = gb["object"].size
    out, cover = np.full(n_px, np.nan), np.zeros(n_px)
    ambiguous = np.zeros(n_px, bool)
    P = gb["position"].reshape(-1, 3).astype(np.float64)
    N = gb["normal"].reshape(-1, 3).astype(np.float64)
    F = gb["footprint"].ravel().astype(np.float64)
    for i in np.flatnonzero(gb["object"].ravel() >= 0):
        x, n, f = P[i], N[i], F[i]
        d_max = p["d_max_scale"] * f
        v = pos - x
        d = np.linalg.norm(v, axis=1)
        theta = np.arctan2(np.linalg.norm(np.cross(n, nrm), axis=1), nrm @ n)
        ambiguous[i] = np.any((np.abs(d - d_max) < 1e-4 * d_max)
                              | (np.abs(theta - theta_max) < 1e-3))
        ok = np.flatnonzero((d <= d_max) & (theta < theta_max))
        ok = ok[np.lexsort((ok, d[ok]))][: p["m_search"]]
        if len(ok) == 0:
            continue
        dd, tt = d[ok], theta[ok]
        cos_v = np.where(dd > 0, np.abs(v[ok] @ n) / np.maximum(dd, 1e-300), 0.0)
        w_g = np.where(dd > 0, np.sqrt(1 - np.minimum(cos_v, 1)), 1.0)
        w_hat = np.clip((w9(dd / d_max, tt) - w_lo) / (1 - w_lo), 0, 1)
        g = np.exp(-dd**2 / (2 * (sigma_scale * f) ** 2)) * (1 - tt / np.pi) * w_g
        if g.sum() > 0:
            out[i] = (g * ao[ok]).sum() / g.sum()
        r = np.maximum(radius[ok], min_radius_scale * f)
        # Nothing is covered at or beyond R_i, also when R_i = 0 (a record in a corner).
        with np.errstate(divide="ignore", invalid="ignore"):
            factor = np.where(np.isfinite(r), np.where(dd < r, 1 - dd / r, 0.0), 1.0)
        cover[i] = (w_g * w_hat * factor).max()
    return out, cover, ambiguous


@pytest.mark.parametrize("min_radius_scale", [0.0, 40.0])
def test_cache_ao_equals_numpy_over_the_records(wall_setup, min_radius_scale):
    s = wall_setup
    r = vc.render_ao(s, progress=False, resolution=8, min_radius_scale=min_radius_scale)
    st = r.stats
    assert st["complete"] and st["resolved_pixels"] == st["covered_pixels"] > 0
    assert st["records"] == len(r.cache) == st["records_inserted"] > 0
    assert st["rays"] == st["shadow_rays"] + st["nearest_rays"] > 0
    assert st["rays_per_point"] == pytest.approx(st["rays"] / st["covered_pixels"])
    gb = s.scene.gbuffer(s.camera, jitter=False)
    want, cover, ambiguous = brute_cache_ao(r.cache, gb, st["sigma_scale"], min_radius_scale)
    got = r.image.ravel().astype(np.float64)
    hit = gb["object"].ravel() >= 0
    assert np.all(np.isnan(got[~hit]))
    check = hit & ~ambiguous
    assert check.sum() > 0.95 * hit.sum()
    np.testing.assert_allclose(got[check], want[check], atol=1e-4)
    # The build left every pixel covered: the criterion holds everywhere.
    assert np.all(cover[check] >= st["w_min"] - 1e-4), cover[check].min()


def test_clamping_r_i_trades_records_for_nothing_else(wall_setup):
    """R_i (unclamped, r = 0) refines near the wall; ignoring it (r = inf) does not."""
    runs = {r: vc.render_ao(wall_setup, progress=False, resolution=8, min_radius_scale=r)
            for r in (0.0, float("inf"))}
    assert runs[0.0].stats["records"] > runs[float("inf")].stats["records"]


def test_identical_for_any_thread_count():
    setup = vc.scenes.load("cornell", detail=0.5)
    cam = setup.camera.with_resolution(40, 30)
    a = vc.render_ao(setup, cam, threads=1, progress=False, resolution=8)
    b = vc.render_ao(setup, cam, threads=2, progress=False, resolution=8)
    assert a.image.tobytes() == b.image.tobytes()
    assert a.stats["records"] == b.stats["records"] and a.stats["rays"] == b.stats["rays"]
    ra = vc.render_ao(setup, cam, reference_rays=8, threads=1, progress=False)
    rb = vc.render_ao(setup, cam, reference_rays=8, threads=2, progress=False)
    assert ra.image.tobytes() == rb.image.tobytes()


@pytest.mark.parametrize("scale", [1e-4, 1e4])
def test_scene_scale_does_not_change_the_image(wall_setup, scale):
    base = vc.render_ao(wall_setup, progress=False, resolution=8)
    s = setup_of(floor_and_wall(scale), (-2.0, 2.0, 0.0), (0.5, 0.0, 0.0), scale=scale)
    r = vc.render_ao(s, progress=False, resolution=8)
    hit = np.isfinite(base.image)
    assert np.array_equal(hit, np.isfinite(r.image))
    assert np.mean(np.abs(r.image[hit] - base.image[hit])) < 0.01
    ref = vc.render_ao(s, reference_rays=64, progress=False)
    assert np.all((ref.image[hit] >= 0) & (ref.image[hit] <= 1))


def test_single_triangle_and_a_cache_without_records_in_reach():
    tri = vc.Scene()
    tri.add_mesh(np.array([[-1, 0, -1], [1, 0, -1], [0, 0, 1]], np.float32),
                 np.array([[0, 1, 2]]))
    s = setup_of(tri, (0, 2, 0.01), (0, 0, 0), w=16, h=12)
    r = vc.render_ao(s, progress=False, resolution=8)
    hit = np.isfinite(r.image)
    assert hit.any() and np.all(r.image[hit] == 1.0)
    # One record allowed: far pixels have none within reach and stay NaN.
    one = vc.render_ao(setup_of(floor_and_wall(), (-2.0, 2.0, 0.0), (0.5, 0.0, 0.0)),
                       progress=False, resolution=8, max_records=1)
    assert one.stats["records"] == 1
    assert one.stats["resolved_pixels"] < one.stats["covered_pixels"]
    assert np.isnan(one.image).sum() > 0


def test_empty_scene_and_bad_input_name_the_argument(wall_setup):
    empty = SimpleNamespace(scene=vc.Scene(), camera=wall_setup.camera)
    with pytest.raises(ValueError, match="^scene"):
        vc.render_ao(empty, reference_rays=4, progress=False)
    with pytest.raises(ValueError, match="^scene"):
        vc.render_ao(empty, progress=False)
    s = wall_setup
    for kwargs, exc, name in [
        (dict(reference_rays=0), ValueError, "reference_rays"),
        (dict(reference_rays=1.5), TypeError, "reference_rays"),
        (dict(sigma_scale=-1.0), ValueError, "sigma_scale"),
        (dict(sigma_scale="wide"), TypeError, "sigma_scale"),
        (dict(min_radius_scale=float("nan")), ValueError, "min_radius_scale"),
        (dict(w_min=1.5), ValueError, "w_min"),
        (dict(threads=0), ValueError, "threads"),
        (dict(time_budget=-1.0), ValueError, "time_budget"),
        (dict(seed=-1), ValueError, "seed"),
        (dict(cache="no"), TypeError, "cache"),
        (dict(no_such_parameter=1), TypeError, "unknown parameter"),
    ]:
        with pytest.raises(exc, match=f"^{name}"):
            vc.render_ao(s, progress=False, **kwargs)
    other = vc.VisibilityCache(floor_and_wall(wall_x=2.0))
    with pytest.raises(ValueError, match="^cache: was built for another scene"):
        vc.render_ao(s, cache=other, progress=False)
    assert len(other) == 0
    with pytest.raises(TypeError, match="^cache_overrides"):
        vc.render_ao(s, cache=vc.VisibilityCache(s.scene), resolution=8, progress=False)
    with pytest.raises(TypeError, match="^cache"):
        vc.render_ao(s, cache=vc.VisibilityCache(s.scene), reference_rays=4, progress=False)


def test_an_existing_cache_is_reused_and_grows_no_further(wall_setup):
    cache = vc.VisibilityCache(wall_setup.scene, resolution=8)
    first = vc.render_ao(wall_setup, cache=cache, progress=False)
    again = vc.render_ao(wall_setup, cache=cache, progress=False)
    assert again.stats["records_inserted"] == 0 and again.stats["rays"] == 0
    assert again.image.tobytes() == first.image.tobytes()
    assert len(cache) == first.stats["records"]


def test_the_ao_experiment_is_registered():
    from viscache_rs import experiments

    assert "ao" in experiments.names()
    assert "1024" in experiments.describe("ao")


def test_a_spent_time_budget_stops_the_build_but_still_gives_an_image(wall_setup):
    r = vc.render_ao(wall_setup, progress=False, resolution=8, time_budget=1e-9)
    st = r.stats
    assert not st["complete"]
    assert 0 < st["records"] and st["resolved_pixels"] > 0
    full = vc.render_ao(wall_setup, progress=False, resolution=8)
    assert st["records"] < full.stats["records"]
