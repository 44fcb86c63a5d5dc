"""The command line runs end to end."""

import numpy as np
from viscache_rs import cli
from viscache_rs.io import to_srgb8, write_png


def test_demo_writes_an_image_per_method(tmp_path, capsys):
    code = cli.main(["demo", "--scene", "cornell", "--width", "48", "--height", "36",
                     "--spp", "2", "--quiet", "--out", str(tmp_path)])
    assert code == 0
    out = capsys.readouterr().out
    assert "Mrays/s" in out and "BVH build" in out and "standard error" in out
    assert "visibility cache" in out and "records" in out
    for method in ("mis", "product"):
        png = (tmp_path / f"cornell_{method}.png").read_bytes()
        assert png.startswith(b"\x89PNG") and len(png) > 100


def test_png_writer_roundtrip(tmp_path):
    import zlib

    img = to_srgb8(np.linspace(0, 1, 2 * 3 * 3).reshape(2, 3, 3))
    data = write_png(tmp_path / "x.png", img).read_bytes()
    idat = data[data.index(b"IDAT") + 4:data.index(b"IEND") - 8]
    raw = np.frombuffer(zlib.decompress(idat), dtype=np.uint8).reshape(2, 1 + 9)
    np.testing.assert_array_equal(raw[:, 1:].reshape(2, 3, 3), img)
