"""``VisibilityCache``: the native visibility cache (``viscache_rs._core.VisibilityCache``,
CAM08 sec. 5) with a progress bar on ``build``. Everything else is the native class's."""

from __future__ import annotations

from typing import Any

from . import _core
from ._progress import Callback as _Callback
from ._progress import progress_bar


class VisibilityCache(_core.VisibilityCache):
    """World-space visibility records over a scene (CAM08 sec. 5): see the native class.
    ``VisibilityCache(scene, resolution=None, preset="auto", **overrides)``."""

    __slots__ = ()

    def build(
        self,
        camera: _core.Camera | None = None,
        seed: int | None = 0,
        threads: int | None = None,
        progress: bool | None = None,
        time_budget: float | None = None,
        *,
        gbuffer: _core.GBuffer | None = None,
        callback: _Callback | None = None,
        spp: int | None = None,
    ) -> dict[str, Any]:
        """Builds the cache for ``camera``'s view (bootstrap of ``n_startup`` records when
        empty, then a pass over the G-buffer applying both insertion criteria), or at the
        points of ``gbuffer`` (``scene.gbuffer(camera, jitter=False)``; ``render(...,
        gbuffer=)`` with the same buffer anchors its pixels at exactly these points).
        Deterministic for any ``threads``. Shows a progress bar with ``progress=True``
        (default None: only when stderr is a terminal); stops after the wave that
        spends ``time_budget`` seconds. Returns a dict: records, bootstrap_records,
        refined_records, discarded_records, pixels, covered_pixels,
        shadow_rays, nearest_rays, shadow_rays_per_pixel (CAM08 Table 2's last row),
        seconds, complete, and the coherence check's findings (the ``"auto"`` preset):
        incoherence (mean Jaccard distance of its pairs), predicted_variance_ratio and
        predicted_gain (the control variate's variance and efficiency over product
        sampling's, build included), incoherent (gain below 1: no records), blind (the
        check saw the map through none of its rays: no records, as the control variate
        would cancel nothing). ``spp``: the samples per pixel of the renders the records
        will serve (None: unknown, as for a cache kept across frames), which the check
        weighs their cost against. A ``callback(done, total)`` (pixels)
        replaces the bar: a falsy return or an exception stops the build."""
        if callback is not None:
            return super().build(camera, seed=seed, threads=threads, gbuffer=gbuffer,
                                 time_budget=time_budget, callback=callback, spp=spp)
        with progress_bar(progress, "cache build", "px") as bar:
            return super().build(camera, seed=seed, threads=threads, gbuffer=gbuffer,
                                 time_budget=time_budget, callback=bar, spp=spp)


__all__ = ["VisibilityCache"]
