"""``ImportanceCache``: the native importance cache (``viscache_rs._core.ImportanceCache``,
the survey's ch. 6, after Georgiev et al.) with a progress bar on ``build``. Everything
else is the native class's.

Records at sparse camera-visible points hold, per light of a ``VPLs`` set, its
contribution with visibility (F), without (U) and bounded over the record's region (B); a
render with ``method="importance_cache"`` draws each sample's lights from its nearest
records' rows and uniformly (C), combined by the alpha-max heuristic (eq. 6.6) or the
balance heuristic. The cache shapes the pdf only: the render is unbiased for the set's sum,
``render(setup, method="vpl", vpls=lights)``."""

from __future__ import annotations

from typing import Any

from . import _core
from ._progress import Callback as _Callback
from ._progress import progress_bar


class ImportanceCache(_core.ImportanceCache):
    """Importance records over a scene and a light set (survey ch. 6):
    ``ImportanceCache(scene, lights, spacing=8, nearest=3, lam=1.0, alpha=(0.5, 0.5, 0.5,
    0.3))``. ``spacing`` (pixels) sets the grid of records, ``nearest`` how many records a
    lookup combines (points with fewer within reach get their own), ``lam`` eq. 6.3's
    normal weight in median record reaches, ``alpha`` the confidences of rows F, U, B, C
    (each in (0, 1]) renders take by default."""

    __slots__ = ()

    def build(
        self,
        camera: _core.Camera | None = None,
        seed: int | None = 0,
        threads: int | None = None,
        progress: bool | None = None,
        *,
        gbuffer: _core.GBuffer | None = None,
        time_budget: float | None = None,
        callback: _Callback | None = None,
    ) -> dict[str, Any]:
        """Grows the cache for ``camera``'s view (or ``gbuffer``'s hits): records every
        ``spacing`` pixels, then wherever fewer than ``nearest`` reach. Deterministic for
        any ``threads``; stops after the wave that spends ``time_budget`` seconds. Returns a
        dict: records, inserted, discarded, grid, pixels, points, pairs, rays, seconds,
        us_per_pair, complete."""
        if callback is not None:
            return super().build(camera, seed=seed, threads=threads, gbuffer=gbuffer,
                                 time_budget=time_budget, callback=callback)
        with progress_bar(progress, "importance records", "px") as bar:
            return super().build(camera, seed=seed, threads=threads, gbuffer=gbuffer,
                                 time_budget=time_budget, callback=bar)


__all__ = ["ImportanceCache"]
