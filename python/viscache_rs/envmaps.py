"""Environment maps: procedural constructors for :class:`viscache_rs.EnvMap`.

Every map lives on the equal-area octahedral map of the sphere (``resolution`` x
``resolution`` texels of equal solid angle, ``resolution`` a power of two <= 4096) and is
sampled in proportion to Rec.709 luminance.

Directions use azimuth and elevation in degrees: azimuth 0 looks toward -z, 90 toward +x,
180 toward +z, 270 toward -x; elevation is the angle above the horizon (+90 is +y, the up
axis). Lat-long images (``EnvMap.from_equirect``, ``to_equirect``, EXR files) use the same
convention: column 0 looks toward -z, a quarter across toward +x, the centre toward +z;
row 0 is straight up.

EXR files (``EnvMap.from_exr(path)``, ``env.to_exr(path, layout=...)``) hold one float32
RGB layer. The layout is taken from the ``viscacheLayout`` header attribute that
``to_exr`` writes ("octahedral" or "latlong"); files without it are octahedral when square
with a power-of-two side and lat-long when twice as wide as high. Octahedral files
round-trip bit-exactly.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from ._core import EnvMap

__all__ = ["EnvMap", "constant", "sky", "windows"]

DEFAULT_RESOLUTION = 256


def constant(value: float | Sequence[float], resolution: int = DEFAULT_RESOLUTION) -> EnvMap:
    """A uniform map of radiance ``value`` (a number or an RGB triple, finite and >= 0)."""
    return EnvMap.constant(value, resolution=resolution)


def sky(
    sun_dir: Sequence[float] = (0.5, 0.7, -0.5),
    sun_radiance: float | Sequence[float] = (4e4, 3.8e4, 3.4e4),
    sun_angle: float = 1.0,
    zenith: float | Sequence[float] = (0.25, 0.45, 1.0),
    horizon: float | Sequence[float] = (0.85, 0.9, 1.0),
    resolution: int = DEFAULT_RESOLUTION,
) -> EnvMap:
    """A smooth gradient sky with a disc sun.

    Above the horizon the radiance runs from ``horizon`` to ``zenith`` as ``sqrt(y)``; below
    it, it fades to a quarter of ``horizon`` at the nadir. The sun is a disc of angular
    diameter ``sun_angle`` (in (0, 90]; the real sun is 0.53) around ``sun_dir``
    (any non-zero vector) with uniform radiance ``sun_radiance``; its power
    ``sun_radiance * 2*pi*(1 - cos(sun_angle / 2))`` is exact at any resolution.
    """
    return EnvMap.sky(sun_dir, sun_radiance, sun_angle, zenith, horizon,
                      resolution=resolution)


def windows(
    windows: Sequence[Mapping[str, Any] | Sequence[Any]],
    background: float | Sequence[float] = (0.04, 0.05, 0.06),
    resolution: int = DEFAULT_RESOLUTION,
) -> EnvMap:
    """Bright rectangles of directions ("windows") on a dim ``background``.

    Each window is a dict with keys ``azimuth_deg``, ``elevation_deg`` (its centre),
    ``width_deg`` (extent in azimuth, in (0, 360]), ``height_deg`` (extent in elevation, in
    (0, 180]) and ``radiance`` (a number or RGB), or a 5-tuple in that order. Later windows
    cover earlier ones. This is the kind of lighting CAM08's garage is lit by: a few
    large, very bright regions carry most of the power.
    """
    return EnvMap.windows(list(windows), background, resolution=resolution)
