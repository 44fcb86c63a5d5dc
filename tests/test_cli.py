"""The command line runs end to end."""

import numpy as np
from viscache_rs import cli
from viscache_rs.io import to_srgb8, write_png


def test_demo_compares_product_and_cv_at_equal_time(tmp_path, capsys):
    code = cli.main(["demo", "--scene", "garage", "--detail", "0.3", "--width", "48",
                     "--height", "36", "--spp", "8", "--resolution", "32", "--quiet",
                     "--out", str(tmp_path)])
    assert code == 0
    out = capsys.readouterr().out
    assert "visibility cache" in out and "records" in out
    assert "product (equal time)" in out and "cv (with cache build)" in out
    assert "equal samples (8 spp): variance ratio cv/product" in out
    for name in ("product_vs_cv", "product", "cv"):
        png = (tmp_path / f"garage_{name}.png").read_bytes()
        assert png.startswith(b"\x89PNG") and len(png) > 100
    assert cli.main(["demo", "--scene", "garage", "--detail", "0.3", "--width", "16",
                     "--height", "12", "--spp", "2", "--alpha", "1", "--quiet",
                     "--out", str(tmp_path)]) == 0


def test_png_writer_roundtrip(tmp_path):
    import zlib

    img = to_srgb8(np.linspace(0, 1, 2 * 3 * 3).reshape(2, 3, 3))
    data = write_png(tmp_path / "x.png", img).read_bytes()
    idat = data[data.index(b"IDAT") + 4:data.index(b"IEND") - 8]
    raw = np.frombuffer(zlib.decompress(idat), dtype=np.uint8).reshape(2, 1 + 9)
    np.testing.assert_array_equal(raw[:, 1:].reshape(2, 3, 3), img)


def test_experiments_without_matplotlib_name_the_extra(tmp_path):
    import subprocess
    import sys

    code = (
        "import sys\n"
        "sys.modules['matplotlib'] = None  # as if not installed\n"
        "from viscache_rs import cli\n"
        f"sys.exit(cli.main(['experiment', 'ao', '--quick', '--out', {str(tmp_path)!r}]))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 2, out.stderr
    assert "pip install 'viscache_rs[experiments]'" in out.stderr
    assert "Traceback" not in out.stderr


def test_experiment_list_gives_whole_first_sentences(capsys):
    assert cli.main(["experiment", "--list"]) == 0
    out = capsys.readouterr().out
    entries = [e for e in out.split("\n") if e and not e.startswith(" ")]
    assert len(entries) >= 5
    for entry in out.replace("\n" + " " * 16, " ").splitlines():
        assert entry.rstrip().endswith((".", ")")), entry
