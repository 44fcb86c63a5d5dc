"""How results show themselves in Jupyter and save themselves to files.

Every image-like object of the package (``RenderResult``, ``RelightResult``, ``AOResult``,
``GBuffer``, ``EnvMap``) has ``_repr_png_()`` (Jupyter's rich display: the picture as PNG
bytes) and ``save(path)``, both built on the helpers of :mod:`viscache_rs.io`:

- ``.exr``: the linear data, float32, lossless (``io.write_exr``); read back it is the
  object's array bit for bit (NaN included).
- ``.png``: the picture ``_repr_png_`` shows, 8-bit sRGB (``io.to_srgb8``).
- anything else: ValueError naming the path.

What the picture is, per object:

- radiance (renders, relit images, environment maps): ``to_srgb8`` at
  ``io.auto_exposure`` (median luminance to middle grey), so a dim render is not shown
  black; pass ``exposure=`` to ``save`` to choose. The environment map's picture is its
  lat-long image, ``2R x R`` for a map of resolution ``R`` (shown at most
  :data:`DISPLAY_MAX_WIDTH` wide); its EXR is the octahedral texture itself
  (``EnvMap.to_exr``), which ``EnvMap.from_exr`` reads back bit for bit.
- ambient occlusion: already a fraction in [0, 1], shown at exposure 1 as grey (pixels
  without a surface black).
- G-buffer: one of its arrays (``key``, default "normal"): vectors (normal, position,
  direction) as RGB, normals and directions mapped from [-1, 1] to [0, 1] for the picture,
  positions scaled into the buffer's bounding box; scalars (depth, footprint) as grey,
  scaled by their largest finite value. Pixels without a hit are black in the picture and
  NaN (or what the buffer holds) in the EXR.

The ``save`` methods are atomic (:func:`viscache_rs.io.atomic_path`): a failed or
interrupted save leaves no partial file.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

import numpy as np

from .io import auto_exposure, encode_png, to_srgb8, write_exr, write_png

__all__ = ["save_image", "srgb8"]

#: What ``save`` writes, by the path's extension (lower case).
SAVE_FORMATS = {".exr": "linear float32 OpenEXR", ".png": "8-bit sRGB PNG"}

#: The G-buffer arrays shown and saved as three channels; the others are scalars.
_GBUFFER_VECTORS = ("normal", "position", "direction")


def srgb8(linear: np.ndarray, exposure: float | None = None) -> np.ndarray:
    """An (H, W, 3) linear image as display sRGB uint8 at ``exposure`` (default
    :func:`~viscache_rs.io.auto_exposure` of the finite pixels)."""
    linear = np.asarray(linear)
    if exposure is not None and not (isinstance(exposure, (int, float, np.floating))
                                     and np.isfinite(exposure) and exposure > 0):
        raise ValueError(f"exposure: must be a positive finite number, got {exposure!r}")
    if exposure is None:
        finite = np.nan_to_num(linear, nan=0.0, posinf=0.0, neginf=0.0)
        exposure = auto_exposure(finite)
    return to_srgb8(linear, exposure)


def _check_path(path: str | os.PathLike[str]) -> tuple[Path, str]:
    if not isinstance(path, (str, os.PathLike)):
        raise TypeError(f"path: expected a str or os.PathLike, got {type(path).__name__}")
    p = Path(path)
    ext = p.suffix.lower()
    if ext not in SAVE_FORMATS:
        known = ", ".join(f"{e} ({what})" for e, what in SAVE_FORMATS.items())
        raise ValueError(f"path: cannot tell the format of {str(p)!r} from its extension "
                         f"{p.suffix or '(none)'!r}; expected {known}")
    return p, ext


def save_image(path: str | os.PathLike[str], linear: np.ndarray,
               picture: Callable[[], np.ndarray]) -> Path:
    """Writes ``linear`` ((H, W, 3), float) to an ``.exr`` path or ``picture()`` ((H, W, 3)
    uint8, made only for a PNG) to a ``.png`` path and returns the path; another extension
    is a ValueError naming the path, raised before anything is written."""
    p, ext = _check_path(path)
    if ext == ".exr":
        return write_exr(p, np.asarray(linear, dtype=np.float32))
    return write_png(p, picture())


def _gray3(values: np.ndarray) -> np.ndarray:
    return np.repeat(np.asarray(values)[..., None], 3, axis=-1)


# ---- the methods, attached to each class (dataclasses here, native classes in __init__) ----


def radiance_repr_png(self) -> bytes:
    """The image in sRGB at auto exposure, as PNG bytes (Jupyter's rich display)."""
    return encode_png(srgb8(self.image), level=1)


def radiance_save(self, path: str | os.PathLike[str], exposure: float | None = None) -> Path:
    """Saves ``image``: ``.exr`` linear float32 (bit-exact), ``.png`` sRGB at ``exposure``
    (default: auto exposure, as shown in Jupyter). Returns the path."""
    return save_image(path, self.image, lambda: srgb8(self.image, exposure))


def ao_repr_png(self) -> bytes:
    """Ambient occlusion as grey (1 = white, no surface black), as PNG bytes."""
    return encode_png(to_srgb8(_gray3(self.image)), level=1)


def ao_save(self, path: str | os.PathLike[str]) -> Path:
    """Saves the AO image: ``.exr`` the (H, W) values in all three channels, float32
    (bit-exact, NaN where no surface); ``.png`` grey as shown. Returns the path."""
    gray = _gray3(self.image)
    return save_image(path, gray, lambda: to_srgb8(gray))


def _gbuffer_arrays(gbuffer, key: str) -> tuple[np.ndarray, np.ndarray]:
    """(linear, picture in [0, 1]) of one G-buffer array, both (H, W, 3)."""
    if not isinstance(key, str) or key not in gbuffer:
        raise ValueError(f"key: expected one of {list(gbuffer.keys())}, got {key!r}")
    values = np.asarray(gbuffer[key])
    picture: np.ndarray
    if key in _GBUFFER_VECTORS:
        linear = values.astype(np.float32)
        if key == "position":
            finite = linear[np.all(np.isfinite(linear), axis=-1)]
            lo = finite.min(axis=0) if len(finite) else np.zeros(3, np.float32)
            hi = finite.max(axis=0) if len(finite) else np.ones(3, np.float32)
            picture = (linear - lo) / np.where(hi > lo, hi - lo, 1.0)
        else:
            picture = 0.5 * (linear + 1.0)
    else:
        linear = _gray3(values.astype(np.float32))
        finite = linear[np.isfinite(linear)]
        top = float(finite.max()) if finite.size else 0.0
        picture = linear / top if top > 0 else linear
    hit = np.asarray(gbuffer["object"]) >= 0
    picture = np.where(hit[..., None], np.nan_to_num(picture), 0.0)
    return linear, picture


def gbuffer_repr_png(self) -> bytes:
    """The shading normals as RGB (``(n + 1) / 2``, no hit black), as PNG bytes."""
    return encode_png(to_srgb8(_gbuffer_arrays(self, "normal")[1]), level=1)


def gbuffer_save(self, path: str | os.PathLike[str], key: str = "normal") -> Path:
    """Saves the array ``key`` (default "normal"): ``.exr`` its values as float32 (scalars
    in all three channels), ``.png`` the picture (module docstring). Returns the path."""
    _check_path(path)  # a bad path before a bad key: nothing is computed for either
    linear, picture = _gbuffer_arrays(self, key)
    return save_image(path, linear, lambda: to_srgb8(picture))


#: Widest lat-long picture ``_repr_png_`` draws of a map (a 4096^2 map's full 8192 x 4096
#: would take seconds and gigabytes of resampling for a picture no screen shows whole).
DISPLAY_MAX_WIDTH = 1024


def envmap_image(envmap, max_width: int | None = None) -> np.ndarray:
    """The map's lat-long image, (R, 2R, 3) float32 for resolution R, or
    (max_width / 2, max_width, 3) when 2R is wider than ``max_width``."""
    width = 2 * envmap.resolution
    if max_width is not None:
        width = min(width, max_width)
    return envmap.to_equirect(width, width // 2)


def envmap_repr_png(self) -> bytes:
    """The lat-long image (2R x R, at most ``DISPLAY_MAX_WIDTH`` wide) in sRGB at auto
    exposure, as PNG bytes."""
    return encode_png(srgb8(envmap_image(self, DISPLAY_MAX_WIDTH)), level=1)


def envmap_save(self, path: str | os.PathLike[str], exposure: float | None = None) -> Path:
    """Saves the map: ``.exr`` its octahedral texture (``to_exr``: bit-exact, read back by
    ``EnvMap.from_exr``), ``.png`` the lat-long picture (2R x R) at ``exposure`` (default
    auto). Returns the path."""
    p, ext = _check_path(path)
    if ext == ".exr":
        p.parent.mkdir(parents=True, exist_ok=True)
        self.to_exr(p)
        return p
    return write_png(p, srgb8(envmap_image(self), exposure))
