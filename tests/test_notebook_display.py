"""Notebooks: results show themselves (``_repr_png_``) and save themselves (``.save``),
``vc.plot.compare`` draws side-by-side panels with relMSE maps, the second example notebook
runs headless, and progress bars stay out of logs unless asked for.

PNG bytes are decoded with Pillow (matplotlib's own dependency) and EXR files read back with
Mitsuba's ``Bitmap``: readers of other projects, so a file that only our own code could read
would fail here."""

from __future__ import annotations

import io
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import viscache_rs as vc
from viscache_rs._progress import progress_bar, wants_bar
from viscache_rs.display import DISPLAY_MAX_WIDTH
from viscache_rs.io import auto_exposure, encode_png, to_srgb8

PIL = pytest.importorskip("PIL.Image")

NOTEBOOK = Path(__file__).resolve().parents[1] / "examples" / "mesh_to_efficiency.ipynb"


def _png(data: bytes) -> np.ndarray:
    """Decodes PNG bytes (Pillow) to an (H, W, 3) uint8 array."""
    image = PIL.open(io.BytesIO(data))
    assert image.mode == "RGB"
    return np.asarray(image)


def _read_exr(path: Path) -> np.ndarray:
    """An RGB EXR file as (H, W, 3) float32, read by Mitsuba."""
    mi = pytest.importorskip("mitsuba")
    if mi.variant() is None:
        mi.set_variant("scalar_rgb")
    bitmap = mi.Bitmap(str(path))
    assert bitmap.component_format() == mi.Struct.Type.Float32
    return np.array(bitmap, copy=True)


@pytest.fixture(scope="module")
def cornell():
    return vc.scenes.load("cornell")


@pytest.fixture(scope="module")
def small(cornell):
    return cornell.camera.with_resolution(20, 15)


@pytest.fixture(scope="module")
def rendered(cornell, small):
    return vc.render(cornell, camera=small, spp=4, method="mis", progress=False)


@pytest.fixture(scope="module")
def one_triangle():
    """A triangle that covers part of the view: pixels with and without a hit."""
    scene = vc.Scene()
    scene.add_mesh(np.array([[-1, -1, 0], [1, -1, 0], [0, 1, 0]], np.float32),
                   np.array([[0, 1, 2]], np.uint32))
    camera = vc.Camera.look_at((0, 0, 3), (0, 0, 0), width=16, height=12)
    return vc.Setup(scene, camera, vc.EnvMap.constant(1.0, resolution=16))


# ---- _repr_png_ ----------------------------------------------------------------------------


def test_a_render_shows_itself_at_auto_exposure(rendered):
    shown = _png(rendered._repr_png_())
    assert shown.shape == (15, 20, 3)
    img = rendered.image
    assert np.array_equal(shown, to_srgb8(img, auto_exposure(img)))
    assert 10 < shown.mean() < 245  # neither black nor blown out


def test_a_relit_image_shows_itself(cornell):
    cam = cornell.camera.with_resolution(12, 9)
    relighter = vc.Relighter(cornell, camera=cam)
    relighter.converge_visibility(spp=16, progress=False)
    res = relighter.render(lb_spp=4, lbv_spp=2)
    shown = _png(res._repr_png_())
    assert shown.shape == (9, 12, 3)
    assert np.array_equal(shown, to_srgb8(res.image, auto_exposure(res.image)))


def test_ambient_occlusion_shows_as_grey_with_no_surface_black(one_triangle):
    ao = vc.render_ao(one_triangle, reference_rays=4, progress=False)
    shown = _png(ao._repr_png_())
    assert shown.shape == (12, 16, 3)
    assert np.array_equal(shown[..., 0], shown[..., 1])
    assert np.array_equal(shown[..., 0], shown[..., 2])
    none = np.isnan(ao.image)
    assert none.any() and (~none).any()
    assert np.all(shown[none] == 0)
    # A lone triangle occludes nothing: AO = 1, white, at exposure 1.
    assert np.all(shown[~none] == 255)


def test_a_gbuffer_shows_its_normals(one_triangle):
    g = one_triangle.scene.gbuffer(one_triangle.camera, jitter=False)
    shown = _png(g._repr_png_())
    assert shown.shape == (12, 16, 3)
    hit = g["object"] >= 0
    assert hit.any() and (~hit).any()
    assert np.all(shown[~hit] == 0)
    # The triangle faces +z: (n + 1) / 2 = (0.5, 0.5, 1) in sRGB.
    want = to_srgb8(np.array([[[0.5, 0.5, 1.0]]]))[0, 0]
    assert np.all(shown[hit] == want)


def test_an_envmap_shows_its_latlong_image():
    env = vc.EnvMap.sky((0.3, 0.8, 0.2), 500.0, 3.0, (0.1, 0.2, 0.5), (0.7, 0.7, 0.8),
                        resolution=32)
    shown = _png(env._repr_png_())
    assert shown.shape == (32, 64, 3)
    latlong = env.to_equirect(64, 32)
    assert np.array_equal(shown, to_srgb8(latlong, auto_exposure(latlong)))
    # Sky above (blue over red), ground below it: rows differ.
    assert shown[1, :, 2].mean() > shown[1, :, 0].mean()
    # A large map is shown at most DISPLAY_MAX_WIDTH wide.
    big = vc.EnvMap.constant(0.5, resolution=2048)
    w = DISPLAY_MAX_WIDTH
    assert w < 2 * 2048 and _png(big._repr_png_()).shape == (w // 2, w, 3)


# ---- save ----------------------------------------------------------------------------------


def test_a_render_saves_exr_exactly_and_png_as_shown(rendered, tmp_path):
    out = rendered.save(tmp_path / "r.exr")
    assert out == tmp_path / "r.exr"
    back = _read_exr(out)
    assert back.dtype == np.float32 and np.array_equal(back, rendered.image)
    rendered.save(tmp_path / "r.png")
    assert np.array_equal(_png((tmp_path / "r.png").read_bytes()),
                          to_srgb8(rendered.image, auto_exposure(rendered.image)))
    rendered.save(tmp_path / "dark.PNG", exposure=0.25)  # extension case does not matter
    assert np.array_equal(_png((tmp_path / "dark.PNG").read_bytes()),
                          to_srgb8(rendered.image, 0.25))
    with pytest.raises(ValueError, match="exposure: must be a positive"):
        rendered.save(tmp_path / "bad.png", exposure=0.0)
    assert not (tmp_path / "bad.png").exists()


def test_ao_saves_nan_where_no_surface(one_triangle, tmp_path):
    ao = vc.render_ao(one_triangle, reference_rays=4, progress=False)
    back = _read_exr(ao.save(tmp_path / "ao.exr"))
    for c in range(3):
        np.testing.assert_array_equal(back[..., c], ao.image)  # NaN equal to NaN
    ao.save(tmp_path / "ao.png")
    assert (tmp_path / "ao.png").read_bytes() == encode_png(
        _png(ao._repr_png_()), level=6)


def test_a_gbuffer_saves_the_array_asked_for(one_triangle, tmp_path):
    g = one_triangle.scene.gbuffer(one_triangle.camera, jitter=False)
    np.testing.assert_array_equal(_read_exr(g.save(tmp_path / "n.exr")), g["normal"])
    np.testing.assert_array_equal(_read_exr(g.save(tmp_path / "d.exr", key="depth"))[..., 1],
                                  g["depth"])  # inf where no hit, kept
    with pytest.raises(ValueError, match="key: expected one of"):
        g.save(tmp_path / "x.exr", key="albedo")
    assert not (tmp_path / "x.exr").exists()


def test_an_envmap_saves_exr_that_loads_bit_exactly(tmp_path):
    env = vc.EnvMap.sky((0.3, 0.8, 0.2), 500.0, 3.0, (0.1, 0.2, 0.5), (0.7, 0.7, 0.8),
                        resolution=32)
    env.save(tmp_path / "sky.exr")
    assert np.array_equal(vc.EnvMap.from_exr(tmp_path / "sky.exr").texels(), env.texels())
    env.save(tmp_path / "sky.png")
    assert _png((tmp_path / "sky.png").read_bytes()).shape == (32, 64, 3)


@pytest.mark.parametrize("name", ["r.jpg", "r.tiff", "r", "r.exr.gz"])
def test_an_unknown_extension_names_the_path_and_writes_nothing(rendered, tmp_path, name):
    env = vc.EnvMap.constant(1.0, resolution=8)
    for obj in (rendered, env):
        with pytest.raises(ValueError, match=f"path: .*{name}"):
            obj.save(tmp_path / name)
    with pytest.raises(TypeError, match="path: expected a str or os.PathLike"):
        rendered.save(3)
    assert list(tmp_path.iterdir()) == []


# ---- vc.plot.compare -----------------------------------------------------------------------


def test_relmse_map_means_to_the_metric(cornell, small, rendered):
    other = vc.render(cornell, camera=small, spp=4, method="env", seed=3, progress=False)
    m = vc.plot.relmse_map(other, rendered)
    assert m.shape == (15, 20)
    assert math.isclose(float(m.mean()), vc.metrics.relmse(other.image, rendered.image),
                        rel_tol=1e-12)
    # Known answer: x = 2 ref everywhere gives ref^2 / (ref^2 + 1e-2) per pixel.
    ref = np.full((2, 3, 3), 0.1)
    assert np.allclose(vc.plot.relmse_map(2 * ref, ref), 0.01 / 0.02)


def test_compare_draws_the_panels_headless(cornell, small, rendered, tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    other = vc.render(cornell, camera=small, spp=4, method="env", seed=3, progress=False)
    fig = vc.plot.compare(other, rendered, labels=("env", "mis"))
    assert isinstance(fig, Figure)
    # two images, one map, its colour bar
    titles = [ax.get_title() for ax in fig.axes]
    assert titles[:2] == ["env", "mis"] and titles[2].startswith("relMSE of env against mis")
    assert len(fig.axes) == 4
    shown = fig.axes[2].images[0]
    m = vc.plot.relmse_map(other, rendered)
    exact = m == 0  # off a log scale: drawn at its bottom
    assert exact.any() and (m > 0).any()
    np.testing.assert_allclose(shown.get_array()[~exact], m[~exact], rtol=1e-12)
    assert np.all(shown.get_array()[exact] == shown.norm.vmin)

    reference = vc.render(cornell, camera=small, spp=16, method="mis", seed=9, progress=False)
    fig = vc.plot.compare(other.image, rendered, ref=reference, labels=("env", "mis"))
    titles = [ax.get_title() for ax in fig.axes]
    assert titles[:3] == ["env", "mis", "reference"] and len(fig.axes) == 6
    mean = vc.metrics.relmse(rendered.image, reference.image)
    assert titles[4] == f"relMSE of mis\nmean {mean:.3g}"
    # One colour scale for both maps.
    assert fig.axes[3].images[0].norm is fig.axes[4].images[0].norm
    png = fig._repr_png_()
    assert _png_size(png)[0] > 0
    fig.savefig(tmp_path / "compare.png")
    assert (tmp_path / "compare.png").stat().st_size > 0


def _png_size(data: bytes) -> tuple[int, int]:
    return PIL.open(io.BytesIO(data)).size


def test_compare_names_the_bad_argument(rendered):
    with pytest.raises(ValueError, match="b: shape"):
        vc.plot.compare(rendered, rendered.image[:5])
    with pytest.raises(ValueError, match="ref: shape"):
        vc.plot.compare(rendered, rendered, ref=np.zeros((2, 2, 3)))
    with pytest.raises(TypeError, match="a: expected an image"):
        vc.plot.compare(object(), rendered)
    with pytest.raises(ValueError, match="exposure"):
        vc.plot.compare(rendered, rendered, exposure=-1.0)


# ---- progress bars -------------------------------------------------------------------------


class _Terminal(io.StringIO):
    """A stderr that says it is a terminal."""

    def isatty(self) -> bool:
        return True


def test_progress_default_draws_no_bar_when_stderr_is_not_a_terminal(cornell, capfd):
    cam = cornell.camera.with_resolution(12, 9)
    assert not sys.stderr.isatty()  # pytest captures it
    vc.render(cornell, camera=cam, spp=2)
    relighter = vc.Relighter(cornell, camera=cam)
    relighter.converge_visibility(spp=32)
    err = capfd.readouterr().err
    assert "render (mis)" not in err and "visibility" not in err, err
    # Asked for, the bar is drawn all the same.
    relighter.converge_visibility(spp=32, progress=True)
    vc.render(cornell, camera=cam, spp=2, progress=True)
    err = capfd.readouterr().err
    assert "visibility" in err and "render (mis)" in err, err


def test_progress_default_draws_a_bar_on_a_terminal(cornell, monkeypatch):
    terminal = _Terminal()
    monkeypatch.setattr(sys, "stderr", terminal)
    cam = cornell.camera.with_resolution(12, 9)
    vc.render(cornell, camera=cam, spp=2)
    assert "render (mis)" in terminal.getvalue()
    terminal.truncate(0)
    vc.render(cornell, camera=cam, spp=2, progress=False)
    assert terminal.getvalue() == ""


def test_wants_bar_follows_tqdms_disable_none(monkeypatch):
    assert wants_bar(True) and not wants_bar(False)
    monkeypatch.setattr(sys, "stderr", _Terminal())
    assert wants_bar(None)
    monkeypatch.setattr(sys, "stderr", io.StringIO())
    assert not wants_bar(None)
    monkeypatch.setattr(sys, "stderr", None)  # pythonw: no stderr at all
    assert not wants_bar(None)
    with progress_bar(None, "x", "px") as callback:
        assert callback is None


# ---- the second notebook -------------------------------------------------------------------

# Appended to the notebook before it runs: what the test checks, as one line of JSON.
DRIVER = """
import json
print("RESULT " + json.dumps({"methods": [r["method"] for r in rows],
                              "efficiency": [r["efficiency"] for r in rows],
                              "best": best, "registry": [m["name"] for m in vc.methods()]}))
"""


def test_mesh_to_efficiency_notebook_runs_headless(tmp_path):
    """Runs ``examples/mesh_to_efficiency.ipynb`` headless: from the PLY file it writes to
    the efficiency of every registry method, the plot and the comparison figure. About 11 s
    on 2 cores, kernel start included (printed, not judged)."""
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    pytest.importorskip("ipykernel")

    nb = nbformat.read(NOTEBOOK, as_version=4)
    assert all(c.get("outputs", []) == [] for c in nb.cells if c.cell_type == "code"), \
        "store the notebook without outputs"
    nbformat.validate(nb)
    nb.cells.append(nbformat.v4.new_code_cell(DRIVER))
    t0 = time.perf_counter()
    client = nbclient.NotebookClient(nb, kernel_name="python3", timeout=120,
                                     resources={"metadata": {"path": str(tmp_path)}})
    client.execute()
    print(f"notebook ran in {time.perf_counter() - t0:.1f} s")

    text = "".join(o.get("text", "") for o in nb.cells[-1].outputs if o.output_type == "stream")
    result = json.loads(next(t for t in text.splitlines() if t.startswith("RESULT "))[7:])
    assert result["methods"] == result["registry"]  # every method, in registry order
    assert all(math.isfinite(e) and e > 0 for e in result["efficiency"]), result
    assert result["best"] in result["methods"]
    # Every picture came out as a PNG: the map, the G-buffer, the reference, the plot,
    # the comparison; and no stream of progress bars reached the notebook.
    pngs = [o for c in nb.cells if c.cell_type == "code" for o in c.outputs
            if "image/png" in o.get("data", {})]
    assert len(pngs) == 5, [c.source[:40] for c in nb.cells]
    streams = "".join(o.get("text", "") for c in nb.cells if c.cell_type == "code"
                      for o in c.outputs if o.output_type == "stream")
    assert "it/s" not in streams and "spp/s" not in streams
    assert list(tmp_path.iterdir()) == []  # the mesh went to a temporary folder
