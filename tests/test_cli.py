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


def _read_png(path):
    """The pixels of a PNG that ``viscache_rs.io.encode_png`` wrote (RGB, no filters)."""
    import struct
    import zlib

    data = path.read_bytes()
    assert data.startswith(b"\x89PNG")
    w, h = struct.unpack(">II", data[16:24])
    idat = data[data.index(b"IDAT") + 4:data.index(b"IEND") - 8]
    raw = np.frombuffer(zlib.decompress(idat), dtype=np.uint8).reshape(h, 1 + 3 * w)
    return raw[:, 1:].reshape(h, w, 3)


def test_preview_writes_a_frame_per_rotation_and_times_them(tmp_path, capsys):
    import re

    out = tmp_path / "frames"
    assert cli.main(["preview", "garage", "--rotate", "0:721:360", "--width", "64",
                     "--height", "48", "--out", str(out), "--quiet"]) == 0
    text = capsys.readouterr().out
    assert sorted(p.name for p in out.iterdir()) == [f"garage_{i:03d}.png" for i in range(3)]
    frames = [_read_png(out / f"garage_{i:03d}.png") for i in range(3)]
    assert frames[0].shape == (48, 64, 3) and frames[0].max() > 0
    # Turning the map by 360 and 720 degrees is the identity (to rounding of 8 bits).
    for f in frames[1:]:
        assert np.abs(f.astype(int) - frames[0]).max() <= 1
    line = re.search(r"prepare (\S+) s, (\S+) MB, basis (\w+).*; render median (\S+) ms, "
                     r"max (\S+) ms per frame \(render only, 3 frames\)", text)
    assert line, text
    assert float(line[1]) > 0 and float(line[2]) > 0 and line[3] in ("haar", "texels")
    assert 0 < float(line[4]) <= float(line[5])
    assert "wrote 3 frames (0 to 720 deg)" in text


def test_preview_frames_change_with_the_rotation(tmp_path):
    assert cli.main(["preview", "garage", "--rotate", "0:180:90", "--width", "32",
                     "--height", "24", "--envmap", "low-sun", "--basis", "texels", "--out",
                     str(tmp_path), "--quiet"]) == 0
    a, b = _read_png(tmp_path / "garage_000.png"), _read_png(tmp_path / "garage_001.png")
    assert np.abs(a.astype(int) - b).mean() > 1


def test_preview_refuses_bad_arguments_clearly(tmp_path, capsys):
    import pytest

    for args, message in (
        (["garage", "--rotate", "0:360"], "expected A:B:STEP"),
        (["garage", "--rotate", "0:x:15"], "expected A:B:STEP"),
        (["garage", "--rotate", "0:360:0"], "STEP must be > 0"),
        (["garage", "--rotate", "0:360:-15"], "STEP must be > 0"),
        (["garage", "--rotate", "90:0:15"], "is empty"),
        (["garage", "--rotate", "0:inf:15"], "finite"),
        (["atlantis"], "invalid choice: 'atlantis'"),
        (["garage", "--width", "0"], "argument --width: must be positive"),
        (["garage", "--budget-mb", "nan"], "argument --budget-mb: must be positive"),
    ):
        with pytest.raises(SystemExit) as e:
            cli.main(["preview", *args, "--out", str(tmp_path / "x")])
        assert e.value.code == 2
        assert message in capsys.readouterr().err, args
    assert cli.main(["preview", "garage", "--envmap", "moon", "--out", str(tmp_path / "x")]) == 2
    assert "envmap: unknown map 'moon'" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()
