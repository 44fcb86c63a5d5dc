"""Cross-validation against Mitsuba 3 (skipped without it): the exported scene renders the
same image as ours, so the peer benchmark compares like with like; Mitsuba's path tracer
agrees with our one-bounce path method; scenes read back (`from_mitsuba`) give the setup
back, XML scenes with every supported plugin read as Mitsuba means them, and anything else
is refused by name.

Mitsuba runs its `scalar_rgb` variant here (no LLVM needed). Image means are compared with
the standard errors both renders measure: ours from the per-pixel variance (conservative
for our stratified samples), Mitsuba's from the spread of independent chunks.
"""

import math

import numpy as np
import pytest
import viscache_rs as vc

mi = pytest.importorskip("mitsuba")


@pytest.fixture(scope="module", autouse=True)
def variant():
    if mi.variant() is None:
        mi.set_variant("scalar_rgb")


def _means_agree(setup, camera, chunks=8, chunk_spp=32, our_spp=256):
    ms = vc.mitsuba.load(setup, camera=camera, equirect_width=1024)
    images = np.stack([vc.mitsuba.render(ms, chunk_spp, seed=k) for k in range(chunks)])
    means = images.mean(axis=(1, 2, 3))
    mi_mean, mi_se = means.mean(), means.std(ddof=1) / math.sqrt(chunks)
    r = vc.render(setup, camera=camera, spp=our_spp, method="mis", seed=5, progress=False)
    ours = float(r.image.mean())
    ours_se = math.sqrt(float(r.variance.sum())) / r.variance.size
    z = (ours - mi_mean) / math.hypot(mi_se, ours_se)
    return ours, mi_mean, z


@pytest.mark.parametrize("name", ["garage", "cornell"])
def test_image_means_agree_with_mitsuba(name):
    # garage: Lambert and the Phong plugin under a windows map; cornell: its area light.
    setup = vc.scenes.load(name, detail=0.3)
    camera = setup.camera.with_resolution(24, 18)
    ours, theirs, z = _means_agree(setup, camera)
    assert abs(z) < 4, f"{name}: ours {ours:.5f}, Mitsuba {theirs:.5f} ({z:.2f} SE)"
    assert abs(ours / theirs - 1) < 0.03


def test_phong_plugin_equals_our_brdf_and_env_orientation():
    # A single bright region of the map lights a Phong plane from one side: both renderers
    # put the highlight and the lit side in the same place.
    scene = vc.Scene()
    quad = np.array([[-3, 0, -3], [3, 0, -3], [3, 0, 3], [-3, 0, 3]], np.float32)
    scene.add_mesh(quad, np.array([[0, 2, 1], [0, 3, 2]]),
                   material=vc.Material.phong((0.3, 0.2, 0.1), (0.5, 0.5, 0.5), 30.0))
    camera = vc.Camera.look_at((0, 2.5, 4), (0, 0, 0), width=24, height=18)
    env = vc.envmaps.windows([{"azimuth_deg": 80, "elevation_deg": 30, "width_deg": 40,
                               "height_deg": 20, "radiance": 20.0}],
                             background=0.05, resolution=64)
    setup = vc.Setup(scene, camera, env)
    ms = vc.mitsuba.load(setup, equirect_width=1024)
    theirs = np.mean([vc.mitsuba.render(ms, 64, seed=k) for k in range(8)], axis=0)
    ours = vc.render(setup, spp=512, method="mis", progress=False).image
    # Row-wise and column-wise profiles agree (orientation and the lobe's place).
    for axis in (0, 1):
        a, b = ours.mean(axis=(axis, 2)), theirs.mean(axis=(axis, 2))
        assert np.corrcoef(a, b)[0, 1] > 0.98
        assert np.allclose(a, b, rtol=0.08, atol=0.02 * b.max())


def test_exported_sun_lies_where_ours_does():
    # Mitsuba reads a lat-long image's rows at theta = pi y / (H - 1), poles included, not
    # at the rows' centres: an export that ignored this put a sun 35 degrees high 0.14 rows
    # too high and its light 0.23% brighter near it (and the suite's image means 0.04-0.06%
    # apart at 10 s). Mitsuba's radiance over a window around the sun, against ours: the
    # same power and the same centroid in elevation, to a fraction of a row.
    elevation = np.radians(35.0)
    env = vc.envmaps.sky(sun_dir=(0.0, np.sin(elevation), -np.cos(elevation)),
                         sun_radiance=4e4, sun_angle=2.0, resolution=128)
    scene = vc.Scene()
    scene.add_mesh(np.array([[0, -9, 0], [1, -9, 0], [0, -9, 1]], np.float32),
                   np.array([[0, 1, 2]]))
    setup = vc.Setup(scene, vc.Camera.look_at((0, 0, 3), (0, 0, 0), width=8, height=6), env)
    width = 512
    emitter = mi.load_dict(vc.mitsuba.to_mitsuba(setup, equirect_width=width)["environment"])
    el, az = np.meshgrid(np.radians(np.linspace(31, 39, 81)), np.radians(np.linspace(-5, 5, 81)),
                         indexing="ij")
    dirs = np.stack([np.cos(el) * np.sin(az), np.sin(el), -np.cos(el) * np.cos(az)], -1)
    dirs = dirs.reshape(-1, 3)
    d_omega = np.cos(el).ravel()
    ours = env.eval(dirs.astype(np.float32)).sum(axis=1)
    si = mi.SurfaceInteraction3f()
    theirs = np.empty(len(dirs))
    for i, d in enumerate(dirs):
        si.wi = mi.Vector3f(*(-d))
        theirs[i] = sum(emitter.eval(si))

    def centroid_deg(radiance):
        return np.degrees((radiance * d_omega * el.ravel()).sum() / (radiance * d_omega).sum())

    rows = (centroid_deg(theirs) - centroid_deg(ours)) / (180.0 / (width // 2))
    assert abs(rows) < 0.08, f"Mitsuba's sun is {rows:+.3f} rows off ours"
    power = (theirs * d_omega).sum() / (ours * d_omega).sum()
    assert power == pytest.approx(1.0, abs=2e-4)


def test_rows_at_mitsubas_latitudes_keep_power_and_place():
    # A bright row of a piecewise-constant image: its power is kept exactly and lands in
    # the two of Mitsuba's rows whose bands it overlaps, split by solid angle.
    h, w = 64, 4
    rgb = np.ones((h, w, 3), np.float32)
    rgb[20] = 1000.0
    out = vc.mitsuba.rows_at_mitsubas_latitudes(rgb)
    ours = -np.diff(np.cos(np.pi * np.arange(h + 1) / h))
    theirs = -np.diff(np.cos(np.pi * np.clip((np.arange(h + 1) - 0.5) / (h - 1), 0, 1)))
    assert (out[..., 0] * theirs[:, None]).sum() == pytest.approx(
        (rgb[..., 0] * ours[:, None]).sum(), rel=1e-6)
    bright = np.flatnonzero(out[:, 0, 0] > 2.0)
    # Our row 20 spans theta in [20, 21] pi / 64; Mitsuba's rows 20 and 21 sit at
    # 20 pi / 63 and 21 pi / 63, with bands half a row either side.
    assert bright.tolist() == [20, 21]
    assert np.all(out[:10] == pytest.approx(1.0, rel=1e-6))


def test_phong_plugin_evaluates_and_samples_our_brdf():
    # In the local frame (normal +z), Mitsuba's wi is our wo (toward the viewer) and its
    # wo our wi (toward the light). eval is f cos, pdf our sampling density.
    vc.mitsuba._register_phong(mi)
    rng = np.random.default_rng(7)
    for kd, ks, e in (((0.3, 0.2, 0.1), (0.5, 0.5, 0.5), 30.0), ((0.0,) * 3, (0.9,) * 3, 400.0),
                      ((0.6,) * 3, (0.1,) * 3, 2.0)):
        ours = vc.Material.phong(kd, ks, e)
        d, s = float(np.dot(kd, vc.metrics.LUMINANCE)), float(np.dot(ks, vc.metrics.LUMINANCE))
        bsdf = mi.load_dict({"type": vc.mitsuba.PHONG_PLUGIN, "kd": list(kd), "ks": list(ks),
                             "exponent": e, "specular_probability": s / (d + s)})
        ctx = mi.BSDFContext()
        n = np.array([[0.0, 0.0, 1.0]])
        for _ in range(60):
            view, light = rng.normal(size=(2, 3))
            view[2], light[2] = abs(view[2]) + 0.05, abs(light[2]) + 0.05
            view, light = view / np.linalg.norm(view), light / np.linalg.norm(light)
            if rng.uniform() < 0.5:  # near the mirror direction, where the lobe lives
                light = np.array([-view[0], -view[1], view[2]]) + 0.05 * rng.normal(size=3)
                light[2] = abs(light[2]) + 1e-3
                light /= np.linalg.norm(light)
            si = mi.SurfaceInteraction3f()
            si.wi = mi.Vector3f(*view)
            si.sh_frame = mi.Frame3f(mi.Vector3f(0.0, 0.0, 1.0))
            value, pdf = bsdf.eval_pdf(ctx, si, mi.Vector3f(*light))
            f = ours.eval(n, view[None], light[None])[0] * light[2]
            p = ours.pdf(n, view[None], light[None])[0]
            # Mitsuba computes in float32, we in float64 where the lobe needs it.
            np.testing.assert_allclose(np.array(value, float).ravel(), f, rtol=1e-4 * e,
                                       atol=1e-6)
            assert float(pdf) == pytest.approx(p, rel=1e-4 * e, abs=1e-6)
        # Samples land where the pdf is positive and weigh f cos / pdf.
        for _ in range(40):
            view = rng.normal(size=3)
            view[2] = abs(view[2]) + 0.05
            view /= np.linalg.norm(view)
            si = mi.SurfaceInteraction3f()
            si.wi = mi.Vector3f(*view)
            si.sh_frame = mi.Frame3f(mi.Vector3f(0.0, 0.0, 1.0))
            bs, weight = bsdf.sample(ctx, si, float(rng.uniform()),
                                     mi.Point2f(*rng.uniform(size=2)))
            if float(bs.pdf) > 0:
                wo = np.array(bs.wo, float).ravel()
                value, pdf = bsdf.eval_pdf(ctx, si, bs.wo)
                np.testing.assert_allclose(np.array(weight, float).ravel(),
                                           np.array(value, float).ravel() / float(pdf),
                                           rtol=1e-5)
                assert wo[2] > 0


# --- Import: from_mitsuba -------------------------------------------------------------

def _small_map_setup(name):
    # The suite scene with its map at 32² texels, exported 1024 pixels wide (the 16 pixels
    # per texel width of equirect_width_for), so that the round trip takes a fraction of
    # a second.
    setup = vc.scenes.load(name, detail=0.3)
    setup.envmap = vc.EnvMap.from_equirect(setup.envmap.to_equirect(256, 128), resolution=32)
    return setup


@pytest.mark.parametrize("name", ["cornell", "garage", "dynamics"])
def test_round_trip_gives_the_setup_back(name, tmp_path):
    # cornell: an area light; garage: Lambert and Phong under a windows map; dynamics: a sky
    # with a sun. Measured: triangles and materials identical, camera rays within 3e-7,
    # texels within 0.6% (99% within 0.04%), the map's power within 0.15%.
    setup = _small_map_setup(name)
    back = vc.mitsuba.from_mitsuba(
        vc.mitsuba.to_mitsuba(setup, equirect_width=1024, folder=tmp_path),
        envmap_resolution=32)
    a, b = setup.scene, back.scene
    assert b.num_objects == a.num_objects
    names = b.object_names()
    ta, tb = a.triangles(), b.triangles()
    ids_a, ids_b = a.object_ids(), b.object_ids()
    lights = set(a.area_lights())
    assert len(lights) == (1 if name == "cornell" else 0)
    for k in range(a.num_objects):
        kb = names.index(f"object{k}")
        np.testing.assert_array_equal(tb[ids_b == kb], ta[ids_a == k])
        assert b.emission(kb) == a.emission(k)
        if k in lights:
            # Exported with a black BSDF (see the module docstring), read back as such.
            assert b.material(kb).params() == {"albedo": [0.0, 0.0, 0.0]}
        else:
            assert b.material(kb).kind == a.material(k).kind
            assert b.material(kb).params() == a.material(k).params()
    assert sorted(b.area_lights()) == sorted(names.index(f"object{k}") for k in lights)
    for jitter in (False, True):
        (oa, da), (ob, db) = setup.camera.rays(jitter=jitter), back.camera.rays(jitter=jitter)
        np.testing.assert_allclose(ob, oa, atol=1e-6)
        np.testing.assert_allclose(db, da, atol=2e-6)
    te, tb_ = setup.envmap.texels(), back.envmap.texels()
    rel = np.abs(tb_ - te) / (te + 1e-3)
    assert rel.max() < 0.02 and np.quantile(rel, 0.99) < 2e-3
    np.testing.assert_allclose(back.envmap.total_power(), setup.envmap.total_power(),
                               rtol=5e-3)


def _write_serialized(path, vertices, faces):
    """One mesh in Mitsuba's serialized format (version 4, float32 positions only)."""
    import struct
    import zlib

    v = np.ascontiguousarray(vertices, "<f4")
    f = np.ascontiguousarray(faces, "<u4")
    body = (struct.pack("<I", 0x1000) + b"quad\x00" + struct.pack("<QQ", len(v), len(f))
            + v.tobytes() + f.tobytes())
    with open(path, "wb") as fh:
        # Header, the compressed mesh, then the table of mesh offsets and their count.
        fh.write(struct.pack("<HH", 0x041C, 4) + zlib.compress(body) + struct.pack("<QI", 0, 1))


def _sky_pixels(h, w):
    """A lat-long image of 1 + x/2 over Mitsuba's pixel directions (rows at theta =
    pi y / (H - 1), columns at their centres): linear in the direction, so a texel's mean
    is its value at the centroid."""
    theta = np.pi * np.arange(h) / (h - 1)
    phi = 2 * np.pi * (np.arange(w) + 0.5) / w
    x = np.sin(phi)[None, :] * np.sin(theta)[:, None]
    return np.repeat((1 + 0.5 * x)[..., None], 3, axis=2).astype(np.float32)


XML_SCENE = """<scene version="3.0.0">
  <sensor type="perspective" id="cam">
    <float name="fov" value="50"/>
    <string name="fov_axis" value="x"/>
    <transform name="to_world"><lookat origin="1, 2, 8" target="0, 0.5, 0" up="0, 1, 0"/>
    </transform>
    <film type="hdrfilm"><integer name="width" value="40"/><integer name="height" value="30"/>
    </film>
  </sensor>
  <bsdf type="twosided" id="blue">
    <bsdf type="diffuse"><rgb name="reflectance" value="0.2, 0.4, 0.6"/></bsdf>
  </bsdf>
  <shape type="rectangle" id="floor">
    <transform name="to_world"><scale value="3"/><rotate x="1" angle="-90"/></transform>
    <ref id="blue"/>
  </shape>
  <shape type="cube" id="box">
    <transform name="to_world"><scale value="0.5"/><translate x="1" y="0.5"/></transform>
    <bsdf type="diffuse"><float name="reflectance" value="0.3"/></bsdf>
  </shape>
  <shape type="sphere" id="ball">
    <point name="center" x="-1" y="1" z="0"/><float name="radius" value="0.5"/>
    <ref id="blue"/>
  </shape>
  <shape type="obj" id="tri">
    <string name="filename" value="tri.obj"/>
    <transform name="to_world"><translate z="-2"/></transform>
    <ref id="blue"/>
  </shape>
  <shape type="ply" id="quad_ply"><string name="filename" value="quad.ply"/><ref id="blue"/>
  </shape>
  <shape type="serialized" id="quad_serialized">
    <string name="filename" value="quad.serialized"/><ref id="blue"/>
  </shape>
  <shape type="rectangle" id="lamp">
    <transform name="to_world"><rotate x="1" angle="90"/><translate y="3"/></transform>
    <emitter type="area"><rgb name="radiance" value="5, 4, 3"/></emitter>
  </shape>
  <emitter type="envmap" id="sky">
    <string name="filename" value="sky.exr"/><float name="scale" value="2"/>
    <transform name="to_world"><rotate y="1" angle="90"/></transform>
  </emitter>
</scene>
"""


def _objects(scene):
    tris, ids, names = scene.triangles(), scene.object_ids(), scene.object_names()
    return {n: tris[ids == k] for k, n in enumerate(names)}


def test_xml_scene_reads_every_supported_plugin(tmp_path):
    import trimesh

    (tmp_path / "tri.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    quad = np.array([[0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], np.float32)
    quad_faces = np.array([[0, 1, 2], [0, 2, 3]])
    trimesh.Trimesh(quad, quad_faces, process=False).export(tmp_path / "quad.ply")
    _write_serialized(tmp_path / "quad.serialized", quad + [0, 0, 1], quad_faces)
    mi.Bitmap(_sky_pixels(64, 128)).write(str(tmp_path / "sky.exr"))
    (tmp_path / "scene.xml").write_text(XML_SCENE)

    setup = vc.mitsuba.from_mitsuba(tmp_path / "scene.xml", envmap_resolution=64)
    objs = _objects(setup.scene)
    assert set(objs) == {"floor", "box", "ball", "tri", "quad_ply", "quad_serialized", "lamp"}

    def corners(t):
        return {tuple(np.round(v, 5)) for v in t.reshape(-1, 3)}

    # rectangle: [-1, 1]² scaled by 3, then turned to face +y (winding normal up).
    assert corners(objs["floor"]) == {(x, 0.0, z) for x in (-3.0, 3.0) for z in (-3.0, 3.0)}
    e1, e2 = objs["floor"][:, 1] - objs["floor"][:, 0], objs["floor"][:, 2] - objs["floor"][:, 0]
    assert np.all(np.cross(e1, e2)[:, 1] > 0)
    assert len(objs["box"]) == 12
    np.testing.assert_allclose(objs["box"].reshape(-1, 3).min(0), [0.5, 0.0, -0.5], atol=1e-6)
    np.testing.assert_allclose(objs["box"].reshape(-1, 3).max(0), [1.5, 1.0, 0.5], atol=1e-6)
    assert len(objs["ball"]) == 20 * 4**4
    r = np.linalg.norm(objs["ball"].reshape(-1, 3) - [-1, 1, 0], axis=1)
    np.testing.assert_allclose(r, 0.5, rtol=1e-5)
    np.testing.assert_array_equal(objs["tri"], [[[0, 0, -2], [1, 0, -2], [0, 1, -2]]])
    np.testing.assert_array_equal(objs["quad_ply"], quad[quad_faces])
    np.testing.assert_array_equal(objs["quad_serialized"], (quad + [0, 0, 1])[quad_faces])

    scene, names = setup.scene, setup.scene.object_names()
    blue = scene.material(names.index("floor")).params()["albedo"]
    np.testing.assert_allclose(blue, [0.2, 0.4, 0.6], rtol=1e-6)
    assert scene.material(names.index("box")).params()["albedo"] == pytest.approx([0.3] * 3)
    assert scene.area_lights() == [names.index("lamp")]
    assert scene.emission(names.index("lamp")) == (5.0, 4.0, 3.0)

    # The camera: the same view, its 50 degrees across the width turned into ours (along
    # the height).
    fov_y = np.degrees(2 * np.arctan(np.tan(np.radians(25)) * 30 / 40))
    ref = vc.Camera.look_at((1, 2, 8), (0, 0.5, 0), (0, 1, 0), fov_deg=fov_y, width=40,
                            height=30)
    for got, want in zip(setup.camera.rays(jitter=False), ref.rays(jitter=False), strict=True):
        np.testing.assert_allclose(got, want, atol=2e-6)

    # The map: 1 + x_local / 2 scaled by 2 and turned 90 degrees about +y (local +x is
    # world -z), so 2 - z in the world: each texel is its mean over the texel (here from
    # 8 x 8 points per texel), up to Mitsuba's bilinear reading of the 64 x 128 image.
    n = 64 * 8
    t = (np.arange(n) + 0.5) / n
    u, v = np.meshgrid(t, t, indexing="xy")
    dirs = vc.octahedral.square_to_sphere(np.stack([u.ravel(), v.ravel()], -1))
    want = (2.0 - dirs[:, 2]).reshape(64, 8, 64, 8).mean(axis=(1, 3))
    got = setup.envmap.texels()
    assert np.abs(got - want[..., None]).max() < 2e-3  # measured 4.4e-4


def test_constant_emitter_and_no_emitter():
    rgb = [0.1, 0.2, 0.3]
    lit = vc.mitsuba.from_mitsuba(
        _scene_with(sky={"type": "constant", "radiance": {"type": "rgb", "value": rgb}}),
        envmap_resolution=8)
    np.testing.assert_allclose(lit.envmap.texels(), np.broadcast_to(rgb, (8, 8, 3)),
                               rtol=1e-6)
    assert vc.mitsuba.from_mitsuba(_scene_with(), envmap_resolution=8).envmap.is_black


@pytest.mark.parametrize("flip", [False, True])
def test_emitting_side_follows_flip_normals(flip):
    # A rectangle's normal is its local +z; flip_normals turns it, and Mitsuba's area light
    # with it, to -z: our winding normal follows, so the light emits on the same side.
    setup = vc.mitsuba.from_mitsuba(_scene_with(lamp={
        "type": "rectangle", "flip_normals": flip,
        "emitter": {"type": "area", "radiance": {"type": "rgb", "value": [1, 1, 1]}}}),
        envmap_resolution=8)
    t = setup.scene.triangles().astype(np.float64)
    normals = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    assert np.all(np.sign(normals[:, 2]) == (-1 if flip else 1))
    assert setup.scene.area_lights() == [0]


def test_import_keeps_the_callers_variant():
    # The importer works in scalar_rgb and gives back the variant it found.
    setup = _small_map_setup("cornell")
    d = vc.mitsuba.to_mitsuba(setup, equirect_width=1024)
    mi.set_variant("scalar_spectral")
    try:
        vc.mitsuba.from_mitsuba(d, envmap_resolution=8)
        assert mi.variant() == "scalar_spectral"
    finally:
        mi.set_variant("scalar_rgb")


def _scene_with(**entries):
    d = {"type": "scene",
         "sensor": {"type": "perspective", "film": {"type": "hdrfilm", "width": 8,
                                                      "height": 6}}}
    d.update(entries)
    return d


@pytest.mark.parametrize("entries, message", [
    ({"floor": {"type": "cube", "bsdf": {"type": "roughplastic", "id": "shiny"}}},
     r"shape plugin 'cube' \(id 'floor'\).*BSDF plugin 'roughplastic' \(id 'shiny'\)"),
    ({"lamp": {"type": "point", "position": [0, 1, 0]}}, r"emitter plugin 'point'"),
    ({"plate": {"type": "disk"}}, r"shape plugin 'disk' \(id 'plate'\)"),
    ({"sensor": {"type": "orthographic"}}, r"sensor plugin 'orthographic'"),
    ({"sensor": {"type": "perspective", "principal_point_offset_x": 0.1}},
     r"principal_point_offset_x"),
    # (Transforms exist once a variant is set: built when the test runs.)
    (lambda: {"sensor": {"type": "perspective",
                         "to_world": mi.ScalarTransform4f().scale([-1, 1, 1])}}, r"mirrors"),
    ({"floor": {"type": "cube", "bsdf": {"type": "twosided",
                                         "a": {"type": "diffuse", "reflectance": 0.2},
                                         "b": {"type": "diffuse", "reflectance": 0.7}}}},
     r"two different sides"),
    ({"floor": {"type": "cube", "bsdf": {"type": "diffuse", "reflectance": {
        "type": "checkerboard"}}}}, r"plugin 'checkerboard'.*varies"),
    ({"floor": {"type": "ply", "filename": "/nonexistent/mesh.ply"}}, r"mesh\.ply"),
    ({"floor": {"type": "no_such_plugin"}}, r"no_such_plugin"),
])
def test_unsupported_input_names_the_plugin(entries, message):
    entries = entries() if callable(entries) else entries
    with pytest.raises(ValueError, match=message):
        vc.mitsuba.from_mitsuba(_scene_with(**entries))


def test_bad_sources_raise_clear_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="missing.xml"):
        vc.mitsuba.from_mitsuba(tmp_path / "missing.xml")
    bad = tmp_path / "bad.xml"
    bad.write_text('<scene version="3.0.0"><shape type="cube"><bsdf type="diffuse"></shape>')
    with pytest.raises(ValueError, match="bad.xml"):
        vc.mitsuba.from_mitsuba(bad)
    with pytest.raises(ValueError, match="type 'scene'"):
        vc.mitsuba.from_mitsuba({"type": "cube"})
    with pytest.raises(ValueError, match="no sensor"):
        vc.mitsuba.from_mitsuba({"type": "scene", "box": {"type": "cube"}})
    with pytest.raises(TypeError, match="source"):
        vc.mitsuba.from_mitsuba(42)
    with pytest.raises(ValueError, match="envmap_resolution"):
        vc.mitsuba.from_mitsuba(_scene_with(), envmap_resolution=1)


# --- Export: the integrator -----------------------------------------------------------

def test_integrator_arguments():
    setup = _small_map_setup("cornell")
    d = vc.mitsuba.to_mitsuba(setup, equirect_width=64, integrator="path", max_depth=3)
    assert d["integrator"] == {"type": "path", "max_depth": 3}
    assert vc.mitsuba.to_mitsuba(setup, equirect_width=64)["integrator"] == {"type": "direct"}
    assert vc.mitsuba.to_mitsuba(setup, equirect_width=64,
                                 integrator="path")["integrator"] == {"type": "path"}
    with pytest.raises(ValueError, match="integrator"):
        vc.mitsuba.to_mitsuba(setup, integrator="volpath")
    with pytest.raises(ValueError, match="max_depth"):
        vc.mitsuba.to_mitsuba(setup, integrator="direct", max_depth=3)
    for bad in (0, -2, 2.5, True):
        with pytest.raises(ValueError, match="max_depth"):
            vc.mitsuba.to_mitsuba(setup, integrator="path", max_depth=bad)


def test_one_bounce_agrees_with_mitsubas_path_tracer():
    # Cornell's indirect share is 0.40: Mitsuba's path tracer with paths of at most three
    # segments (one bounce) against our path method with one bounce, image means within
    # 4 SE of each other (measured 0.97 SE), and far from Mitsuba's direct light alone
    # (measured 39 SE below).
    setup = vc.scenes.load("cornell", detail=0.3)
    camera = setup.camera.with_resolution(24, 18)
    chunks = 8

    def mitsuba_mean(max_depth):
        ms = vc.mitsuba.load(setup, camera=camera, equirect_width=1024, integrator="path",
                             max_depth=max_depth)
        means = np.array([vc.mitsuba.render(ms, 32, seed=k).mean() for k in range(chunks)])
        return means.mean(), means.std(ddof=1) / math.sqrt(chunks)

    theirs, theirs_se = mitsuba_mean(3)
    r = vc.render(setup, camera=camera, spp=256, method="path", bounces=1, seed=5,
                  progress=False)
    ours = float(r.image.mean())
    ours_se = math.sqrt(float(r.variance.sum())) / r.variance.size
    z = (ours - theirs) / math.hypot(theirs_se, ours_se)
    assert abs(z) < 4, f"ours {ours:.5f}, Mitsuba {theirs:.5f} ({z:.2f} SE)"
    direct, direct_se = mitsuba_mean(2)
    assert (theirs - direct) / math.hypot(theirs_se, direct_se) > 10
