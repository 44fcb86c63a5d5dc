"""Environment maps through the public Python API: sampling against the pdf, inversion,
lat-long conversion and power, EXR I/O, rotation, procedural maps and bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest
import viscache_rs as vc


def uniform_dirs(rng: np.random.Generator, n: int) -> np.ndarray:
    d = rng.normal(size=(n, 3))
    return (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)


def sunny(resolution: int = 64, angle: float = 4.0) -> vc.EnvMap:
    return vc.envmaps.sky(sun_dir=(0.3, 0.6, -0.7), sun_radiance=2e4,
                          sun_angle=angle, resolution=resolution)


def spike(resolution: int, x: int, y: int, value: float, rest: float) -> vc.EnvMap:
    t = np.full((resolution, resolution, 3), rest, dtype=np.float32)
    t[y, x] = value
    return vc.EnvMap.from_octahedral(t)


MAPS = {
    "constant": lambda: vc.envmaps.constant((0.5, 1.0, 2.0), resolution=16),
    "sky_sun": lambda: sunny(32, 4.0),
    "spike": lambda: spike(16, 3, 11, 1e6, 1.0),
    "single": lambda: spike(16, 7, 2, 1.0, 0.0),
}


@pytest.mark.parametrize("name", sorted(MAPS))
def test_sample_matches_pdf_chi_square(name):
    env = MAPS[name]()
    res = env.resolution
    rng = np.random.default_rng(1)
    n = 200_000
    dirs, pdf = env.sample(rng.random((n, 2)))
    assert dirs.shape == (n, 3) and dirs.dtype == np.float32 and pdf.shape == (n,)
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=1), 1.0, atol=1e-5)
    # The returned pdf is exactly pdf(dir), and positive.
    np.testing.assert_array_equal(pdf, env.pdf(dirs))
    assert (pdf > 0).all()
    # Texel probabilities: pdf is constant per texel, each texel is 4 pi / res^2.
    texel_pdf = env.pdf(texel_centres(res))
    expected = texel_pdf * 4 * math.pi / res**2 * n
    assert abs(expected.sum() - n) < 1e-6 * n
    # Bin the samples by texel.
    idx = nearest_texel(dirs, res)
    observed = np.bincount(idx, minlength=res * res)
    assert observed[expected == 0].sum() == 0
    keep = expected >= 5
    pooled_e = expected[~keep & (expected > 0)].sum()
    pooled_o = observed[~keep & (expected > 0)].sum()
    e = np.append(expected[keep], pooled_e) if pooled_e >= 5 else expected[keep]
    o = np.append(observed[keep], pooled_o) if pooled_e >= 5 else observed[keep]
    dof = max(len(e) - 1, 1)
    chi2 = float(((o - e) ** 2 / e).sum())
    # Wilson-Hilferty: about 4.5 standard deviations above the mean.
    limit = dof * (1 - 2 / (9 * dof) + 4.5 * math.sqrt(2 / (9 * dof))) ** 3 + 10
    assert chi2 < limit, (name, chi2, dof)


def texel_centres(res: int) -> np.ndarray:
    """Directions through the centres of all texels, row-major."""
    return octahedral_index_map(res)["dirs"]


_INDEX_MAPS: dict[int, dict[str, np.ndarray]] = {}


def octahedral_index_map(res: int) -> dict[str, np.ndarray]:
    """Texel centres of a res x res grid found through the public API: a map whose texel
    (x, y) has radiance (x + 1, y + 1, 1) identifies the texel of any direction."""
    if res not in _INDEX_MAPS:
        ys, xs = np.mgrid[0:res, 0:res]
        t = np.stack([xs + 1, ys + 1, np.ones_like(xs)], axis=-1).astype(np.float32)
        env = vc.EnvMap.from_octahedral(t)
        # The centres: search by sampling u at texel centres of a constant map of the same
        # resolution (its warp is the identity on the square).
        flat = vc.EnvMap.constant(1.0, resolution=res)
        u = np.stack([(xs + 0.5) / res, (ys + 0.5) / res], axis=-1).reshape(-1, 2)
        dirs, _ = flat.sample(u)
        got = env.eval(dirs)
        assert (got[:, 0] - 1 == xs.ravel()).all() and (got[:, 1] - 1 == ys.ravel()).all()
        _INDEX_MAPS[res] = {"env": env, "dirs": dirs}
    return _INDEX_MAPS[res]


def nearest_texel(dirs: np.ndarray, res: int) -> np.ndarray:
    rgb = octahedral_index_map(res)["env"].eval(dirs)
    return (rgb[:, 1] - 1).astype(np.int64) * res + (rgb[:, 0] - 1).astype(np.int64)


@pytest.mark.parametrize("name", sorted(MAPS))
def test_pdf_integrates_to_one_and_invert_undoes_sample(name):
    env = MAPS[name]()
    res = env.resolution
    total = env.pdf(texel_centres(res)).sum() * 4 * math.pi / res**2
    assert abs(total - 1) < 1e-9
    u = np.random.default_rng(2).random((20_000, 2))
    dirs, _ = env.sample(u)
    back = env.invert(dirs)
    assert back.shape == (20_000, 2) and back.dtype == np.float64
    tol = 5e-6 if name == "constant" else 1e-3
    assert np.abs(back - u).max() < tol
    again, _ = env.sample(back)
    assert np.abs(again - dirs).max() < 3e-5


def test_eval_is_piecewise_constant():
    env = sunny(32)
    flat = vc.EnvMap.constant(1.0, resolution=32)
    rng = np.random.default_rng(3)
    cells = rng.integers(0, 32, size=(5000, 2))
    inside = rng.uniform(0.01, 0.99, size=(5000, 2))
    centre, _ = flat.sample((cells + 0.5) / 32)
    anywhere, _ = flat.sample((cells + inside) / 32)
    np.testing.assert_array_equal(env.eval(centre), env.eval(anywhere))
    np.testing.assert_array_equal(env.pdf(centre), env.pdf(anywhere))
    t = env.texels()
    assert t.shape == (32, 32, 3) and t.dtype == np.float32
    np.testing.assert_array_equal(env.eval(centre), t[cells[:, 1], cells[:, 0]])


def latlong_power(rgb: np.ndarray) -> np.ndarray:
    h, w, _ = rgb.shape
    theta = np.pi * np.arange(h + 1) / h
    omega = 2 * np.pi / w * (np.cos(theta[:-1]) - np.cos(theta[1:]))
    return (rgb.astype(np.float64) * omega[:, None, None]).sum(axis=(0, 1))


def latlong_dirs(h: int, w: int) -> np.ndarray:
    s = (np.arange(w) + 0.5) / w
    t = (np.arange(h) + 0.5) / h
    phi, theta = np.meshgrid(2 * np.pi * s, np.pi * t)
    return np.stack([np.sin(phi) * np.sin(theta), np.cos(theta), -np.cos(phi) * np.sin(theta)],
                    axis=-1)


def test_from_equirect_preserves_power():
    h, w = 128, 256
    d = latlong_dirs(h, w)
    sun = np.array([0.3, 0.6, -0.7]) / np.linalg.norm([0.3, 0.6, -0.7])
    sky = 0.2 + 0.8 * np.clip(d[..., 1:2], 0, 1) * np.array([0.3, 0.5, 1.0])
    disc = (d @ sun) > math.cos(math.radians(1.5))
    rgb = np.where(disc[..., None], 3e4, sky).astype(np.float32)
    assert disc.sum() > 0
    for res in (32, 128, 512):
        env = vc.EnvMap.from_equirect(rgb, resolution=res)
        np.testing.assert_allclose(env.total_power(), latlong_power(rgb), rtol=5e-3)
        brightest = np.argmax(env.texels()[..., 0].ravel())
        assert texel_centres(res)[brightest] @ sun > 0.99
    noise = np.random.default_rng(4).exponential(size=(32, 64, 3)).astype(np.float32) ** 3
    for res in (8, 64, 256):
        env = vc.EnvMap.from_equirect(noise, resolution=res)
        np.testing.assert_allclose(env.total_power(), latlong_power(noise), rtol=5e-3)
    # Back to lat-long: power kept, image convention (centre column looks toward +z).
    img = sunny(64).to_equirect(256, 128)
    assert img.shape == (128, 256, 3) and img.dtype == np.float32
    np.testing.assert_allclose(latlong_power(img), sunny(64).total_power(), rtol=0.02)
    # The width Mitsuba gets: sixteen pixels per texel width, at most 8192.
    widths = {r: vc.mitsuba.equirect_width_for(sunny(r)) for r in (16, 64, 256, 1024)}
    assert widths == {16: 512, 64: 2048, 256: 8192, 1024: 8192}


def test_exr_round_trips(tmp_path):
    env = sunny(32)
    p = tmp_path / "oct.exr"
    env.to_exr(p)
    back = vc.EnvMap.from_exr(str(p))
    assert back.resolution == 32
    np.testing.assert_array_equal(back.texels().view(np.uint32), env.texels().view(np.uint32))
    p = tmp_path / "latlong.exr"
    env.to_exr(p, layout="latlong")
    back = vc.EnvMap.from_exr(p)
    assert back.resolution == 32
    np.testing.assert_allclose(back.total_power(), env.total_power(), rtol=0.02)
    assert vc.EnvMap.from_exr(p, resolution=8).resolution == 8


def test_exr_errors_name_the_path(tmp_path):
    missing = tmp_path / "nope.exr"
    with pytest.raises(FileNotFoundError, match="nope.exr"):
        vc.EnvMap.from_exr(missing)
    bad = tmp_path / "garbage.exr"
    bad.write_bytes(b"definitely not an OpenEXR file")
    with pytest.raises(ValueError, match="garbage.exr"):
        vc.EnvMap.from_exr(bad)
    good = tmp_path / "good.exr"
    sunny(16).to_exr(good)
    cut = tmp_path / "cut.exr"
    cut.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    with pytest.raises(ValueError, match="cut.exr"):
        vc.EnvMap.from_exr(cut)
    with pytest.raises(OSError, match="x.exr"):
        sunny(16).to_exr(tmp_path / "no_dir" / "x.exr")
    with pytest.raises(ValueError, match="layout"):
        sunny(16).to_exr(good, layout="cubemap")


def test_rotation():
    env = sunny(32, 8.0)
    np.testing.assert_array_equal(env.rotated(360).texels(), env.texels())
    sun = np.array([0.3, 0.6, -0.7]) / np.linalg.norm([0.3, 0.6, -0.7])
    r = env.rotated(90)
    brightest = texel_centres(32)[np.argmax(r.texels()[..., 0].ravel())]
    # +90 degrees about +y: (x, z) -> (z, -x).
    assert brightest @ np.array([sun[2], sun[1], -sun[0]]) > 0.99
    np.testing.assert_allclose(r.total_power(), env.total_power(), rtol=1e-9)
    np.testing.assert_allclose(env.rotated(17.5).total_power(), env.total_power(), rtol=0.03)


def test_black_map():
    env = vc.envmaps.constant(0.0, resolution=8)
    assert env.is_black
    with pytest.raises(ValueError, match="black"):
        env.sample([[0.5, 0.5]])
    with pytest.raises(ValueError, match="black"):
        env.invert([[0, 1, 0]])
    np.testing.assert_array_equal(env.pdf([[0, 1, 0], [1, 0, 0]]), [0.0, 0.0])
    np.testing.assert_array_equal(env.eval([[0, 1, 0]]), [[0, 0, 0]])
    assert env.total_power() == (0.0, 0.0, 0.0)


def test_procedural_maps_and_setups():
    w = vc.envmaps.windows(
        [dict(azimuth_deg=90, elevation_deg=30, width_deg=40, height_deg=20, radiance=100.0),
         (270, 10, 30, 16, (1, 2, 3))],
        background=0.01, resolution=64)
    np.testing.assert_array_equal(w.eval([[0.866, 0.5, 0.0]]), [[100, 100, 100]])
    np.testing.assert_array_equal(w.eval([[-0.985, 0.174, 0.0]]), [[1, 2, 3]])
    np.testing.assert_allclose(w.eval([[0, 0, 1]]), [[0.01] * 3])
    for name in vc.scenes.names():
        if name in ("garden", "hairball"):
            continue
        s = vc.scenes.load(name, detail=0.1)
        assert isinstance(s.envmap, vc.EnvMap) and s.envmap.resolution == 256
        assert not s.envmap.is_black
    s = vc.scenes.load("dynamics", detail=0.1)
    s.envmap = vc.envmaps.constant(2.0, resolution=4)
    assert s.envmap.resolution == 4
    assert "EnvMap(resolution=4" in repr(s.envmap)


@pytest.mark.parametrize(
    "call, exc, match",
    [
        (lambda: vc.EnvMap.from_octahedral(np.ones((4, 4), np.float32)), ValueError, "rgb"),
        (lambda: vc.EnvMap.from_octahedral(np.ones((3, 3, 3))), ValueError, "power of two"),
        (lambda: vc.EnvMap.from_octahedral(np.ones((4, 4, 3), bool)), TypeError, "rgb"),
        (lambda: vc.EnvMap.from_octahedral(np.ones((4, 4, 3), "U1")), TypeError, "rgb"),
        (lambda: vc.EnvMap.from_equirect(np.ones((4, 8, 3)), resolution=12), ValueError,
         "resolution"),
        (lambda: vc.EnvMap.from_equirect(np.ones((4, 8, 3)), resolution=8192), ValueError,
         "resolution"),
        (lambda: vc.EnvMap.from_equirect(np.ones((4, 8, 3)), resolution=2.0), TypeError,
         "resolution"),
        (lambda: vc.EnvMap.from_equirect(np.ones((0, 8, 3))), ValueError, "rgb"),
        (lambda: vc.EnvMap.from_equirect(np.ones((4, 8, 4))), ValueError, "rgb"),
        (lambda: vc.envmaps.constant(-1.0), ValueError, "value"),
        (lambda: vc.envmaps.constant(float("nan")), ValueError, "value"),
        (lambda: vc.envmaps.sky(sun_dir=(0, 0, 0)), ValueError, "sun_dir"),
        (lambda: vc.envmaps.sky(sun_angle=0), ValueError, "sun_angle"),
        (lambda: vc.envmaps.windows([(0, 95, 10, 10, 1)]), ValueError, "windows\\[0\\]"),
        (lambda: vc.envmaps.windows([dict(azimuth_deg=0)]), ValueError, "windows\\[0\\]"),
        (lambda: vc.envmaps.windows([3]), TypeError, "windows\\[0\\]"),
        (lambda: sunny(8).rotated(float("inf")), ValueError, "degrees"),
        (lambda: sunny(8).to_equirect(0, 4), ValueError, "width"),
    ],
)
def test_bad_construction(call, exc, match):
    with pytest.raises(exc, match=match):
        call()


@pytest.mark.parametrize("bad", [np.nan, np.inf, -1.0])
def test_bad_texels_name_the_first_bad_texel(bad):
    t = np.ones((4, 4, 3), np.float32)
    t[1, 2, 1] = bad
    t[3, 0, 0] = bad
    with pytest.raises(ValueError, match=r"rgb.*\(x=2, y=1\)"):
        vc.EnvMap.from_octahedral(t)
    img = np.ones((4, 8, 3))
    img[2, 5, 0] = bad
    with pytest.raises(ValueError, match=r"rgb.*\(x=5, y=2\)"):
        vc.EnvMap.from_equirect(img, resolution=4)


def test_bad_queries_leave_the_map_usable():
    env = sunny(16)
    before = env.texels().copy()
    for u, match in [([[0.5, 1.0]], "u"), ([[-0.1, 0.5]], "u"), ([[np.nan, 0.5]], "u"),
                     ([[0.5, 0.5, 0.5]], "u"), (np.ones(2), "u")]:
        with pytest.raises(ValueError, match=match):
            env.sample(u)
    with pytest.raises(TypeError, match="u"):
        env.sample([["a", "b"]])
    for method in (env.eval, env.pdf, env.invert):
        with pytest.raises(ValueError, match="dirs.*row 1"):
            method([[0, 1, 0], [0, 0, 0]])
        with pytest.raises(ValueError, match="dirs"):
            method([[0, np.nan, 1]])
        with pytest.raises(ValueError, match="dirs"):
            method(np.ones((3, 2)))
    np.testing.assert_array_equal(env.texels(), before)
    dirs, pdf = env.sample(np.zeros((0, 2)))
    assert dirs.shape == (0, 3) and pdf.shape == (0,)
