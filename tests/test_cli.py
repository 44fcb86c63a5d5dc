"""The command line runs end to end, and refuses bad options before any work."""

import numpy as np
import pytest
import viscache_rs as vc
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
        (["garage", "--width", "0"], "argument --width: must be an integer in 1..16384"),
        (["garage", "--budget-mb", "nan"], "argument --budget-mb: must be positive"),
    ):
        with pytest.raises(SystemExit) as e:
            cli.main(["preview", *args, "--out", str(tmp_path / "x")])
        assert e.value.code == 2
        assert message in capsys.readouterr().err, args
    with pytest.raises(SystemExit) as e:
        cli.main(["preview", "garage", "--envmap", "moon", "--out", str(tmp_path / "x")])
    assert e.value.code == 2
    assert "argument --envmap: unknown map 'moon'" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


def _refused(argv, capsys):
    """Runs ``viscache argv`` and returns its error line, after checking that it exited with
    status 2 and printed one usage line, that error line and no traceback."""
    with pytest.raises(SystemExit) as e:
        cli.main(argv)
    assert e.value.code == 2, argv
    err = capsys.readouterr().err
    lines = err.splitlines()
    assert len(lines) == 2 and lines[0].startswith("usage: viscache"), err
    assert "Traceback" not in err
    return lines[1]


@pytest.fixture
def no_work(monkeypatch):
    """Every subcommand's work fails the test: a refusal must come before it."""
    def work(args):
        raise AssertionError(f"ran with {args}")

    for name in ("demo", "preview", "experiment", "list_scenes"):
        monkeypatch.setattr(cli, name, work)


LIMITS = vc._core.LIMITS
SIDE = LIMITS["image_side"][1]
SPP = LIMITS["spp"][1]
THREADS = LIMITS["threads"][1]
SEED = LIMITS["seed"][1]

# Every option of every subcommand given a bad value, and what the error line must say:
# the option's name and what it accepts, the ranges being the library's own.
BAD = [
    (["demo", "--spp", "-4"], f"argument --spp: must be an integer in 1..{SPP}, got '-4'"),
    (["demo", "--spp", "0"], f"argument --spp: must be an integer in 1..{SPP}"),
    (["demo", "--spp", "1.5"], f"argument --spp: must be an integer in 1..{SPP}"),
    (["demo", "--spp", str(SPP + 1)], "argument --spp: must be an integer"),
    (["demo", "--width", "-5"], f"argument --width: must be an integer in 1..{SIDE}"),
    (["demo", "--width", str(SIDE + 1)], f"argument --width: must be an integer in 1..{SIDE}"),
    (["demo", "--height", "0"], f"argument --height: must be an integer in 1..{SIDE}"),
    (["demo", "--threads", "0"], f"argument --threads: must be an integer in 1..{THREADS}"),
    (["demo", "--threads", str(THREADS + 1)], "argument --threads: must be an integer"),
    (["demo", "--alpha", "3"], "argument --alpha: must be a number in [0, 2] or 'estimate'"),
    (["demo", "--alpha", "-0.5"], "argument --alpha: must be a number in [0, 2]"),
    (["demo", "--alpha", "nan"], "argument --alpha: must be a number in [0, 2]"),
    (["demo", "--alpha", "high"], "argument --alpha: must be a number in [0, 2]"),
    (["demo", "--resolution", "1"], "argument --resolution: must be a power of two in 2..128"),
    (["demo", "--resolution", "48"], "argument --resolution: must be a power of two in 2..128"),
    (["demo", "--resolution", "256"], "argument --resolution: must be a power of two"),
    (["demo", "--detail", "0"], "argument --detail: must be a number in (0, 16]"),
    (["demo", "--detail", "17"], "argument --detail: must be a number in (0, 16]"),
    (["demo", "--detail", "inf"], "argument --detail: must be a number in (0, 16]"),
    (["demo", "--seed", "-1"], f"argument --seed: must be an integer in 0..{SEED}"),
    (["demo", "--seed", str(SEED + 1)], f"argument --seed: must be an integer in 0..{SEED}"),
    (["demo", "--scene", "atlantis"], "argument --scene: invalid choice: 'atlantis'"),
    (["demo", "--preset", "extreme"], "argument --preset: invalid choice: 'extreme'"),
    (["demo", "--nosuch"], "unrecognized arguments: --nosuch"),
    (["experiment", "nosuch"], "argument name: invalid choice: 'nosuch' (choose from "),
    (["experiment", "ao", "--seed", "x"], "argument --seed: must be an integer in 0.."),
    (["experiment", "ao", "--threads", "0"], "argument --threads: must be an integer in 1.."),
    (["preview", "garage", "--height", "-1"], "argument --height: must be an integer in 1.."),
    (["preview", "garage", "--threads", "0"], "argument --threads: must be an integer in 1.."),
    (["preview", "garage", "--basis", "wavelets"], "argument --basis: invalid choice"),
    (["preview", "garage", "--budget-mb", "0"], "argument --budget-mb: must be positive"),
    (["preview", "garage", "--envmap", "sky.exr"], "argument --envmap: no such EXR file"),
    (["nosuch"], "argument command: invalid choice: 'nosuch'"),
]


@pytest.mark.parametrize("argv, message", BAD, ids=[" ".join(a) for a, _ in BAD])
def test_a_bad_option_is_refused_before_any_work(argv, message, no_work, tmp_path, capsys,
                                                 monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert message in _refused(argv, capsys)


def test_an_output_folder_that_is_a_file_is_refused(no_work, tmp_path, capsys):
    file = tmp_path / "taken"
    file.write_text("")
    for argv in (["demo"], ["experiment", "ao"], ["preview", "garage"]):
        line = _refused([*argv, "--out", str(file)], capsys)
        assert f"argument --out: must be a folder, but {str(file)!r} is a file" in line


def test_every_option_is_checked_by_its_type_or_choices():
    """An option that takes a value and has neither would reach the work unchecked."""
    import argparse

    parser = cli.build_parser()
    subparsers = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    for command, sub in subparsers.choices.items():
        for action in sub._actions:
            if action.nargs == 0 or isinstance(action, argparse._HelpAction):
                continue
            assert action.type is not None or action.choices is not None, \
                (command, action.dest)


def test_version(capsys):
    with pytest.raises(SystemExit) as e:
        cli.main(["--version"])
    assert e.value.code == 0
    assert capsys.readouterr().out.strip() == f"viscache {vc.__version__}"


def test_listings_are_plain_text(capsys):
    assert cli.main(["scenes"]) == 0
    scenes = capsys.readouterr().out
    assert cli.main(["experiment", "--list"]) == 0
    experiments = capsys.readouterr().out
    for text in (scenes, experiments):
        assert "``" not in text and ":func:" not in text and ":mod:" not in text, text
    assert "garage" in scenes and "detail=1" in scenes
    assert "variance-table" in experiments
    assert cli.plain("see :func:`names` and ``load(name)``, :data:`MAPS`") == \
        "see names() and load(name), MAPS"


@pytest.fixture
def umask():
    """Sets the process's umask for a test and puts the old one back."""
    import os

    old = os.umask(0o022)
    yield os.umask
    os.umask(old)


def test_saved_files_follow_the_umask(tmp_path, umask):
    """PNG, JSON and Markdown outputs (the Python writer) were saved with mode 0600, the
    private mode of their temporary file; EXR files and caches (the Rust writer) with
    0666 less the umask. All follow the umask now, as any tool's files do."""
    import os
    import stat

    setup = vc.scenes.load("cornell", detail=0.3)
    cache = vc.VisibilityCache(setup.scene)
    img = np.zeros((2, 3, 3), np.float32)
    for mask in (0o022, 0o077, 0o002, 0o027):
        umask(mask)
        out = tmp_path / f"{mask:o}"
        files = [write_png(out / "a.png", to_srgb8(img)),
                 vc.io.write_bytes(out / "results.json", b"{}\n"),
                 vc.io.write_bytes(out / "results.md", b"# x\n"),
                 vc.io.write_exr(out / "a.exr", img)]
        cache.save(out / "view.vc")
        files.append(out / "view.vc")
        for path in files:
            assert stat.S_IMODE(os.stat(path).st_mode) == 0o666 & ~mask, (path, oct(mask))
        assert sorted(p.name for p in out.iterdir()) == sorted(p.name for p in files)


def _dead_pid():
    """The pid of a process that has ended (and been waited for)."""
    import subprocess
    import sys

    child = subprocess.Popen([sys.executable, "-c", ""])
    child.wait()
    return child.pid


@pytest.mark.parametrize("writer", ["png", "exr"])
def test_a_save_removes_temporaries_that_killed_saves_left(tmp_path, writer):
    """A process killed mid-save (SIGKILL) leaves ``.NAME.PID.N.tmp`` beside the target;
    the next save of that target removes those of processes that no longer run, and never
    a file of a running process (this one's, or its parent's) nor another target's."""
    import os

    img = np.zeros((2, 3, 3), np.float32)
    name = f"a.{writer}"
    dead = _dead_pid()
    stale = [f".{name}.{dead}.0.tmp", f".{name}.{dead}.17.tmp"]
    kept = [f".{name}.{os.getppid()}.0.tmp", f".{name}.{os.getpid()}.99999.tmp",
            f".b.{writer}.{dead}.0.tmp", f".{name}.x.tmp", f".{name}.{dead}.tmp"]
    for n in stale + kept:
        (tmp_path / n).write_bytes(b"half a file")
    if writer == "png":
        write_png(tmp_path / name, to_srgb8(img))
    else:
        vc.io.write_exr(tmp_path / name, img)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([name, *kept])
    assert vc.io.remove_stale_temporaries(tmp_path / name) == 0
