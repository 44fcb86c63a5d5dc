"""Clarberg's equal-area octahedral map of the sphere onto the unit square.

The one parameterization of the sphere in viscache_rs: visibility records, environment maps
and product distributions share it, so every texel of a ``res x res`` grid covers the same
solid angle ``4 pi / res**2``. The square's centre is +y and its four corners are -y; ``u``
grows with +x and ``v`` with +z.

``sphere_to_square(dirs)``: (N, 3) directions (normalised first) -> (N, 2) float32 in [0, 1].
``square_to_sphere(uv)``: (N, 2) points of [0, 1]^2 -> (N, 3) float32 unit directions.
``texel_of(dirs, res)``: (N, 2) int64 texel coordinates (x, y) on a ``res x res`` grid.
"""

import math

from ._core import octahedral as _octahedral

sphere_to_square = _octahedral.sphere_to_square
square_to_sphere = _octahedral.square_to_sphere
texel_of = _octahedral.texel_of


def texel_solid_angle(res: int) -> float:
    """Solid angle of one texel of a ``res x res`` grid, in steradians."""
    return 4.0 * math.pi / (res * res)


__all__ = ["sphere_to_square", "square_to_sphere", "texel_of", "texel_solid_angle"]
