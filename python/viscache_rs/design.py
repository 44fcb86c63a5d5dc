"""Lighting design with the cached-transfer preview (CAM08 §6.2).

:class:`viscache_rs.LightingPreview` keeps, per pixel of a view, the transfer
``T(p, ω) = B̃(p, ω) Ṽ(p, ω)`` of the control variate's integral ``J = ∫ L B̃ Ṽ dω`` in a
basis (texel cells, or the largest Haar terms that fit a memory budget), so that swapping or
rotating the environment map costs one projection of the map and a dot product per pixel:
the near-instant preview for lighting design of CAM08 §6.2 (Fig. 11). This module holds
what an interactive front end needs around it, shared by ``viscache preview`` and
``examples/lighting_design.ipynb``:

- :data:`MAPS` and :func:`envmap`: named maps to swap between;
- :func:`rotations`: the ``A:B:STEP`` range of rotations about +y;
- :func:`srgb8` and :func:`preview_png`: tone mapping and PNG encoding fast enough for a
  slider (a few milliseconds at 640x480, against tens for :func:`viscache_rs.io.to_srgb8`
  and matplotlib's ``imsave``).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from . import envmaps
from ._core import EnvMap, Setup
from .io import auto_exposure, encode_png, to_srgb8

__all__ = ["MAPS", "envmap", "exposure", "preview_png", "rotations", "srgb8"]

#: Names :func:`envmap` understands, with what each is.
MAPS: dict[str, str] = {
    "scene": "the scene's own map",
    "sky": "sun and sky: a gradient sky with a 1 degree sun at azimuth 45, elevation 45",
    "low-sun": "a low sun (azimuth 180, elevation 15) in a gradient sky",
    "white": "uniform white (radiance 1): the view's ambient occlusion",
}

#: Most frames :func:`rotations` gives; more is a mistyped range, not a preview.
MAX_FRAMES = 10_000

_LUT_SIZE = 16384
_lut: np.ndarray | None = None


def _direction(azimuth_deg: float, elevation_deg: float) -> tuple[float, float, float]:
    # The envmaps module's convention: azimuth 0 looks toward -z, 90 toward +x.
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    return (math.sin(az) * math.cos(el), math.sin(el), -math.cos(az) * math.cos(el))


def envmap(setup: Setup, name: str) -> EnvMap:
    """The map called ``name`` (a key of :data:`MAPS`, or the path of an EXR file as
    ``EnvMap.from_exr`` reads it) at the resolution of ``setup``'s own map."""
    if name.lower().endswith(".exr"):
        path = Path(name)
        if not path.is_file():
            raise ValueError(f"envmap: no such EXR file: {name}")
        return EnvMap.from_exr(str(path))
    res = setup.envmap.resolution
    if name == "scene":
        return setup.envmap
    if name == "sky":
        return envmaps.sky(resolution=res)
    if name == "low-sun":
        return envmaps.sky(sun_dir=_direction(180.0, 15.0), resolution=res)
    if name == "white":
        return envmaps.constant(1.0, resolution=res)
    raise ValueError(f"envmap: unknown map {name!r}; expected one of {', '.join(MAPS)} "
                     "or the path of an .exr file")


def rotations(spec: str) -> list[float]:
    """Degrees about +y from ``"A:B:STEP"``: ``A, A + STEP, ...`` while below ``B`` (so
    ``"0:360:15"`` gives 24 frames, 0 to 345). Raises ValueError naming ``rotate`` for bad
    syntax, non-finite numbers, ``STEP <= 0``, an empty range or more than
    :data:`MAX_FRAMES` frames."""
    parts = str(spec).split(":")
    try:
        if len(parts) != 3:
            raise ValueError
        a, b, step = (float(p) for p in parts)
    except ValueError:
        raise ValueError(f"rotate: expected A:B:STEP in degrees (e.g. 0:360:15), got "
                         f"{spec!r}") from None
    if not all(math.isfinite(x) for x in (a, b, step)):
        raise ValueError(f"rotate: A, B and STEP must be finite, got {spec!r}")
    if step <= 0:
        raise ValueError(f"rotate: STEP must be > 0, got {parts[2]!r}")
    if a >= b:
        raise ValueError(f"rotate: the range {spec!r} is empty (A must be below B)")
    # A frame within rounding of B is B itself, which the range excludes.
    frames = math.ceil((b - a) / step - 1e-9)
    if frames > MAX_FRAMES:
        raise ValueError(f"rotate: {spec!r} gives {frames:,} frames, more than {MAX_FRAMES:,}")
    return [a + k * step for k in range(frames)]


def exposure(image: np.ndarray) -> float:
    """The exposure that maps ``image``'s median luminance to middle grey
    (:func:`viscache_rs.io.auto_exposure`). Keep one per map rather than one per frame, so
    that a rotation shows the change in brightness it makes."""
    return auto_exposure(image)


def srgb8(image: np.ndarray, exposure: float = 1.0) -> np.ndarray:
    """Linear (H, W, 3) radiance times ``exposure`` as sRGB uint8, clipped at 1, by table:
    within one level of :func:`viscache_rs.io.to_srgb8` and several times faster."""
    global _lut
    if _lut is None:
        _lut = to_srgb8(np.linspace(0.0, 1.0, _LUT_SIZE))
    x = np.multiply(image, np.float32(exposure * (_LUT_SIZE - 1)), dtype=np.float32)
    np.nan_to_num(x, copy=False, nan=0.0, posinf=_LUT_SIZE - 1, neginf=0.0)
    np.clip(x + np.float32(0.5), 0, _LUT_SIZE - 1, out=x)
    return _lut[x.astype(np.uint16)]


def preview_png(image: np.ndarray, exposure: float = 1.0) -> bytes:
    """``image`` (linear, H x W x 3) tone mapped by :func:`srgb8` and encoded as PNG at zlib
    level 1: the bytes an ``ipywidgets.Image(format="png")`` shows."""
    return encode_png(srgb8(image, exposure), level=1)
