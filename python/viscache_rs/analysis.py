"""Visibility correlation measurements (CAM08 sec. 4.1, Figs. 3-4).

A visibility map is the binary visibility of the whole sphere at a surface point, ``R x R``
directions of the record pattern (the lower hemisphere occluded), exactly as
:class:`VisibilityCache` records are traced. The correlation of two maps is Pearson's
coefficient over the ``N = R*R`` directions, from popcounts ``a``, ``b`` and ``c`` (bits set
in each map and in both): ``rho = (N c - a b) / sqrt(a (N - a) b (N - b))``; it is undefined
(NaN, counted apart) when a map is all visible or all occluded.

``visibility_maps(scene, points, normals, resolution=32, threads=None, progress=False)``
    -> :class:`VisibilityMaps` (``len``, ``resolution``, ``points``, ``normals``,
    ``bits(indices=None)`` (N, R, R) bool in texel layout, ``visible_fraction()``).
``sample_pairs(maps, neighbours=16, far=16, far_range=None, seed=0)`` -> (P, 2) uint32:
    each point's nearest neighbours, then partners at log-uniform distances along its
    tangent plane.
``pair_correlations(maps, pairs)`` -> dict of (P,) ``rho``, ``distance``, ``theta_deg``.
``correlation_bins(maps, distance_edges, theta_edges, pairs=None)`` -> dict of (D, T)
    ``count``, ``mean``, ``std``, ``undefined``: CAM08's ``rho_bar(d, theta)``.
``local_correlation(maps, d_max, theta_max_deg)`` -> dict of (N,) ``mean`` and ``count``:
    Fig. 4's per-point average correlation to its neighbourhood.

Everything is deterministic for any thread count.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ._core import analysis as _analysis
from ._progress import progress_bar

if TYPE_CHECKING:
    # The class lives in the native submodule, which the stubs type as a namespace.
    from ._core import _VisibilityMaps

VisibilityMaps = _analysis.VisibilityMaps
sample_pairs = _analysis.sample_pairs
pair_correlations = _analysis.pair_correlations
correlation_bins = _analysis.correlation_bins
local_correlation = _analysis.local_correlation


def visibility_maps(
    scene,
    points,
    normals,
    resolution: int = 32,
    threads: int | None = None,
    progress: bool | None = False,
) -> _VisibilityMaps:
    """Traces the ``resolution x resolution`` visibility map at each of the (N, 3)
    ``points`` with (N, 3) ``normals`` (normalised; rays leave on their side). With
    ``progress``, shows a progress bar over the points."""
    with progress_bar(progress, "visibility maps", "pt", total=len(points)) as callback:
        return _analysis.visibility_maps(scene, points, normals, resolution=resolution,
                                         threads=threads, callback=callback)


__all__ = [
    "VisibilityMaps",
    "correlation_bins",
    "local_correlation",
    "pair_correlations",
    "sample_pairs",
    "visibility_maps",
]
