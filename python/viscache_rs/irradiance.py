"""``IrradianceCache``: the native irradiance cache (``viscache_rs._core.IrradianceCache``,
the survey's ch. 3) with a progress bar on ``build``. Everything else is the native class's.

Records hold one-bounce irradiance ``E`` with its validity radius and gradients; a render
with ``method="irradiance_cache"`` interpolates them (eq. 3.8) for the diffuse part of the
first bounce. Biased: measure it against ``render(setup, method="path", bounces=1,
direct=False)``."""

from __future__ import annotations

from typing import Any

from . import _core
from ._progress import Callback as _Callback
from ._progress import progress_bar


class IrradianceCache(_core.IrradianceCache):
    """One-bounce irradiance records with gradients over a scene (survey ch. 3):
    ``IrradianceCache(scene, a=0.2, strata=(16, 64), r_min=1.5, r_max=32.0,
    gradients="both", clamp_neighbours=True, secondary_spp=1)``. ``a`` (in (0, 1]) sets a
    record's reach ``a * R_i``; ``r_min``/``r_max`` clamp ``R_i`` in pixel footprints;
    ``gradients`` is "none", "rotation" or "both"."""

    __slots__ = ()

    def build(
        self,
        camera: _core.Camera | None = None,
        seed: int | None = 0,
        threads: int | None = None,
        progress: bool | None = None,
        time_budget: float | None = None,
        *,
        envmap: _core.EnvMap,
        gbuffer: _core.GBuffer | None = None,
        callback: _Callback | None = None,
    ) -> dict[str, Any]:
        """Grows the cache for ``camera``'s view (or ``gbuffer``'s hits) lit by ``envmap``
        and the scene's area lights: every pixel whose surface reflects diffusely gets a
        usable record, placed coarse to fine. Deterministic for any ``threads``; stops
        after the wave that spends ``time_budget`` seconds. Returns a dict: records,
        inserted, discarded, pixels, points, hemisphere_rays, secondary_rays, rays,
        clamped_radii, seconds, complete."""
        if callback is not None:
            return super().build(camera, seed=seed, threads=threads, envmap=envmap,
                                 gbuffer=gbuffer, time_budget=time_budget, callback=callback)
        with progress_bar(progress, "irradiance records", "px") as bar:
            return super().build(camera, seed=seed, threads=threads, envmap=envmap,
                                 gbuffer=gbuffer, time_budget=time_budget, callback=bar)


__all__ = ["IrradianceCache"]
