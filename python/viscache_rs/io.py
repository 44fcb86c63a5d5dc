"""Image output: sRGB PNG (no extra dependencies) and float OpenEXR (the Rust core)."""

from __future__ import annotations

import contextlib
import itertools
import os
import re
import struct
import zlib
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from .metrics import luminance

__all__ = [
    "atomic_path", "auto_exposure", "encode_png", "remove_stale_temporaries", "to_srgb8",
    "write_bytes", "write_exr", "write_png",
]


#: Numbers the temporary files of this process (``.<name>.<pid>.<n>.tmp``).
_NEXT_TEMPORARY = itertools.count()


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yields a temporary path beside ``path`` to write; on leaving without an exception it
    is flushed and renamed over ``path`` in one step, otherwise removed. A process killed
    while writing leaves the previous ``path`` whole. Creates missing parent folders.

    The temporary file, ``.<name>.<pid>.<n>.tmp``, is created as any new file is (mode 0666
    less the umask), so the saved file has the permissions the user's other tools give
    theirs. Temporary files of ``path`` left by processes that no longer run (killed
    mid-save) are removed first (:func:`remove_stale_temporaries`); the Rust writers (EXR,
    caches) name and clean theirs the same way."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_temporaries(path)
    while True:
        temp = path.with_name(f".{path.name}.{os.getpid()}.{next(_NEXT_TEMPORARY)}.tmp")
        try:
            # Exclusive: the name may be taken by a Rust writer of this process, which
            # counts its own n.
            os.close(os.open(temp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
            break
        except FileExistsError:
            continue
    try:
        yield temp
        with open(temp, "rb+") as f:
            os.fsync(f.fileno())
        os.replace(temp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(temp)
        raise


def _process_is_gone(pid: int) -> bool:
    """Whether no process ``pid`` runs. Where that cannot be told without side effects
    (Windows, whose ``os.kill`` would end the process) it answers False: keep the file."""
    if os.name != "posix" or pid <= 0:
        return False
    try:
        os.kill(pid, 0)  # signal 0: only checks that the process exists
    except ProcessLookupError:
        return True
    except (PermissionError, OverflowError):
        return False  # another user's process, or no valid pid: keep the file
    return False


def remove_stale_temporaries(path: str | Path) -> int:
    """Removes the temporary files of ``path`` (``.<name>.<pid>.<n>.tmp`` beside it, as
    :func:`atomic_path` and the Rust writers name them) whose process no longer runs, and
    returns how many it removed. A file whose process runs is never touched: it may be a
    save under way. Failures to list or remove are ignored."""
    path = Path(path)
    pattern = re.compile(re.escape(f".{path.name}.") + r"([0-9]+)\.[0-9]+\.tmp")
    removed = 0
    try:
        entries = list(os.scandir(path.parent))
    except OSError:
        return 0
    for entry in entries:
        match = pattern.fullmatch(entry.name)
        if not match:
            continue
        pid = int(match[1])
        if pid != os.getpid() and _process_is_gone(pid):
            with contextlib.suppress(OSError):
                os.unlink(entry.path)
                removed += 1
    return removed


def write_bytes(path: str | Path, data: bytes) -> Path:
    """Writes ``data`` to ``path`` atomically (:func:`atomic_path`) and returns the path."""
    path = Path(path)
    with atomic_path(path) as temp:
        temp.write_bytes(data)
    return path


def auto_exposure(linear: np.ndarray, key: float = 0.18) -> float:
    """Exposure for :func:`to_srgb8` that maps the image's median Rec. 709 luminance to
    ``key`` (photography's middle grey); 1 when the median is not positive (a mostly black
    image), so such an image is shown as it is rather than blown out."""
    median = float(np.median(luminance(linear)))
    return key / median if median > 0 else 1.0


def to_srgb8(linear: np.ndarray, exposure: float = 1.0) -> np.ndarray:
    """Linear radiance (H, W, 3) -> sRGB uint8, clipping at 1 after ``exposure``."""
    x = np.clip(np.nan_to_num(np.asarray(linear, dtype=np.float64) * exposure), 0.0, 1.0)
    srgb = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.round(srgb * 255.0).astype(np.uint8)


def encode_png(rgb8: np.ndarray, level: int = 6) -> bytes:
    """An (H, W, 3) uint8 array as the bytes of an 8-bit RGB PNG (no row filters), deflated
    at zlib ``level`` (0-9: 1 is several times faster than 6 for a slightly larger file, what
    an interactive preview wants)."""
    img = np.ascontiguousarray(rgb8)
    if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"rgb8: expected an (H, W, 3) uint8 array, got {img.dtype} {img.shape}")
    if not (isinstance(level, int) and 0 <= level <= 9):
        raise ValueError(f"level: must be an integer in 0..9, got {level!r}")
    h, w, _ = img.shape
    # Each scanline is its filter byte (0: none) followed by the row's bytes.
    raw = np.zeros((h, 1 + 3 * w), dtype=np.uint8)
    raw[:, 1:] = img.reshape(h, 3 * w)

    def chunk(tag: bytes, data: bytes) -> bytes:
        body = tag + data
        return struct.pack(">I", len(data)) + body + struct.pack(">I", zlib.crc32(body))

    header = struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)
    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header)
    png += chunk(b"IDAT", zlib.compress(raw.tobytes(), level))
    return png + chunk(b"IEND", b"")


def write_png(path: str | Path, rgb8: np.ndarray) -> Path:
    """Writes an (H, W, 3) uint8 array as an 8-bit RGB PNG (:func:`encode_png` at level 6)
    and returns the path."""
    return write_bytes(path, encode_png(rgb8))


def write_exr(path: str | Path, image: np.ndarray) -> Path:
    """Writes an (H, W, 3) array of linear radiance as a float32 RGB OpenEXR file (lossless,
    atomically: a killed process leaves the previous file) and returns the path."""
    from ._core import write_exr as _write_exr

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    _write_exr(path, image)
    return path
