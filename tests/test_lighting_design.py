"""Lighting design: the notebook's slider renders every change, and the helpers of
``viscache_rs.design`` it and ``viscache preview`` share. How fast a change is belongs to
``benches/preview_transfer.py``, not to a test."""

import json
import math
import statistics
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from viscache_rs import design
from viscache_rs.io import encode_png, to_srgb8

NOTEBOOK = Path(__file__).resolve().parents[1] / "examples" / "lighting_design.ipynb"

CHANGES = 20

# Appended to the notebook before it runs: moves the slider as a user would (each assignment
# fires the observer, which renders and shows the frame) through 20 rotations, back to 0,
# then swaps the map once.
DRIVER = f"""
import json
first = image.value
timings.clear()
frames = []
for v in [(15 * k) % 360 for k in range(1, {CHANGES} + 1)]:
    rotation.value = v
    frames.append(image.value)
slider = list(timings)
rotation.value = 0
back = image.value
timings.clear()
envmap.value = "low-sun"
print("RESULT " + json.dumps({{
    "slider": slider, "swap": timings, "status": status.value,
    "distinct": len(set(frames)), "back_to_first": back == first,
    "swap_changed": image.value != back, "png": list(image.value[:32]),
}}))
"""


def test_notebook_slider_renders_every_change():
    """Runs ``examples/lighting_design.ipynb`` headless (garage at 640x480, 200 MB
    transfer, as a user gets it) and moves its rotation slider through 20 values.

    Per change the callback renders from the cached transfer, then displays the frame
    (table tone mapping, PNG encoding at zlib level 1, the bytes through the widget). Each
    change renders once and shows a frame of its own; turning back to 0 shows the first frame
    again, bit for bit; swapping the map changes the frame. The notebook's timings are
    printed for the record, not judged: ``benches/preview_transfer.py`` measures the
    slider's milliseconds per change. The test takes 10-20 s, most of it preparing the
    transfer.
    """
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    pytest.importorskip("ipykernel")
    pytest.importorskip("ipywidgets")

    nb = nbformat.read(NOTEBOOK, as_version=4)
    assert all(c.get("outputs", []) == [] for c in nb.cells if c.cell_type == "code"), \
        "store the notebook without outputs"
    nb.cells.append(nbformat.v4.new_code_cell(DRIVER))
    client = nbclient.NotebookClient(nb, kernel_name="python3", timeout=300,
                                     resources={"metadata": {"path": str(NOTEBOOK.parent)}})
    client.execute()

    text = "".join(o.get("text", "") for o in nb.cells[-1].outputs if o.output_type == "stream")
    line = next(t for t in text.splitlines() if t.startswith("RESULT "))
    result = json.loads(line.removeprefix("RESULT "))
    setup_text = "".join(o.get("text", "") for o in nb.cells[3].outputs)
    assert "garage 640x480" in setup_text and "prepared in" in setup_text, setup_text

    timings = result["slider"]
    assert len(timings) == CHANGES, timings  # one render per change
    assert all(t["render_ms"] > 0 and t["display_ms"] > 0 for t in timings), timings
    print(f"render median {statistics.median(t['render_ms'] for t in timings):.1f} ms, "
          f"display median {statistics.median(t['display_ms'] for t in timings):.1f} ms "
          "(for the record; the bench measures them)")
    # Every rotation shows a frame of its own, and 0 degrees the same frame as before.
    assert result["distinct"] == CHANGES
    assert result["back_to_first"]
    assert len(result["swap"]) == 1

    # The frame shown is a 640x480 RGB PNG, and swapping the map changes it.
    png = bytes(result["png"])
    assert png.startswith(b"\x89PNG\r\n\x1a\n") and png[12:16] == b"IHDR"
    assert struct.unpack(">II", png[16:24]) == (640, 480)
    assert result["swap_changed"]
    assert result["status"].startswith("render ")


def test_rotations_parse_the_range():
    assert design.rotations("0:360:15") == [15.0 * k for k in range(24)]
    assert design.rotations("0:721:360") == [0.0, 360.0, 720.0]
    assert design.rotations("-90:90:45") == [-90.0, -45.0, 0.0, 45.0]
    # B itself is left out even when rounding puts A + k STEP a hair below it.
    assert len(design.rotations("0:0.7:0.1")) == 7
    assert len(design.rotations("0:1:0.1")) == 10
    for spec, message in (("0:360", "expected A:B:STEP"), ("0:360:15:1", "expected A:B:STEP"),
                          ("a:b:c", "expected A:B:STEP"), ("0:360:0", "STEP must be > 0"),
                          ("0:360:-5", "STEP must be > 0"), ("10:10:1", "is empty"),
                          ("nan:1:1", "finite"), ("0:1e9:1", "more than 10,000")):
        with pytest.raises(ValueError, match="rotate: ") as e:
            design.rotations(spec)
        assert message in str(e.value)


def test_table_tone_map_is_within_one_level_of_the_exact_one():
    rng = np.random.default_rng(7)
    img = (rng.random((48, 64, 3)) ** 3 * 4).astype(np.float32)
    img[0, :4] = [[0, 0, 0], [1e-9, 1, 2], [np.inf, 0, 0], [np.nan, -1, 0.5]]
    for exposure in (0.05, 1.0, 3.7):
        fast = design.srgb8(img, exposure)
        exact = to_srgb8(img, exposure)
        assert fast.dtype == np.uint8 and fast.shape == img.shape
        assert np.abs(fast.astype(int) - exact).max() <= 1
        # Black, white and the ends of the clip are exact.
        ends = (exact == 0) | (exact == 255)
        np.testing.assert_array_equal(fast[ends], exact[ends])
    assert design.srgb8(img[:1, :4], 1.0)[0, 2, 0] == 255  # +inf is white, as to_srgb8
    assert design.srgb8(img[:1, :4], 1.0)[0, 3, 0] == 0  # NaN is black, as to_srgb8


def test_preview_png_decodes_to_the_tone_mapped_pixels():
    rng = np.random.default_rng(3)
    img = rng.random((5, 7, 3)).astype(np.float32)
    png = design.preview_png(img, 0.8)
    w, h = struct.unpack(">II", png[16:24])
    idat = png[png.index(b"IDAT") + 4:png.index(b"IEND") - 8]
    raw = np.frombuffer(zlib.decompress(idat), dtype=np.uint8).reshape(h, 1 + 3 * w)
    assert (w, h) == (7, 5) and not raw[:, 0].any()
    np.testing.assert_array_equal(raw[:, 1:].reshape(5, 7, 3), design.srgb8(img, 0.8))
    with pytest.raises(ValueError, match="level"):
        encode_png(design.srgb8(img), level=10)
    with pytest.raises(ValueError, match="rgb8"):
        encode_png(img)


def test_named_maps():
    import viscache_rs as vc

    setup = vc.scenes.load("cornell", detail=0.25)
    assert design.envmap(setup, "scene") is setup.envmap
    res = setup.envmap.resolution
    for name in design.MAPS:
        env = design.envmap(setup, name)
        assert env.resolution == res
    # The low sun sits at azimuth 180 (toward +z), elevation 15 degrees.
    x, y, z = design._direction(180.0, 15.0)
    assert math.isclose(y, math.sin(math.radians(15))) and z > 0.96 and abs(x) < 1e-12
    with pytest.raises(ValueError, match="envmap: unknown map 'moon'"):
        design.envmap(setup, "moon")
    with pytest.raises(ValueError, match="envmap: no such EXR file"):
        design.envmap(setup, "/nonexistent/sky.exr")
