"""Image output: sRGB PNG (no extra dependencies) and float OpenEXR (the Rust core)."""

from __future__ import annotations

import contextlib
import os
import struct
import tempfile
import zlib
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from .metrics import luminance

__all__ = [
    "atomic_path", "auto_exposure", "encode_png", "to_srgb8", "write_bytes", "write_exr",
    "write_png",
]


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yields a temporary path beside ``path`` to write; on leaving without an exception it
    is flushed and renamed over ``path`` in one step, otherwise removed. A process killed
    while writing leaves the previous ``path`` whole. Creates missing parent folders."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, temp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        yield Path(temp)
        with open(temp, "rb+") as f:
            os.fsync(f.fileno())
        os.replace(temp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(temp)
        raise


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
