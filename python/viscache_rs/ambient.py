"""Ambient occlusion from the visibility cache (CAM08 sec. 6.1) and its ray-traced reference.

``render_ao(setup, camera=None, cache=None, reference_rays=None, seed=0, threads=None,
progress=None, time_budget=None, sigma_scale=None, min_radius_scale=None, w_min=None,
gbuffer=None, **cache_overrides)`` computes, at the first hit through every pixel centre
(or every hit of ``gbuffer``, from ``setup.scene.gbuffer``), the ambient
occlusion ``A`` = eq. 12 / pi: the cosine-weighted visible fraction of the hemisphere, in
[0, 1] (1 = nothing occludes), exactly what every cache record stores.

- From the cache (default): the cache is grown for the view with sec. 6.1's criterion
  ``max_i[w_i (1 - d_i / R_i)] < w_min`` (``w_min`` is this criterion's own threshold, not
  the cache's sec. 5.2 one; ``R_i`` clamped below at ``min_radius_scale`` pixel
  footprints, ``inf`` ignores it), then each pixel averages the stored ``A`` of its
  ``m_search`` nearest records with Gaussian weights of width ``sigma_scale`` footprints.
  ``cache`` may be an existing :class:`VisibilityCache` of ``setup.scene`` (its records are
  reused and kept);
  otherwise a new one is made with ``VisibilityCache(setup.scene, **cache_overrides)``
  (``resolution``, ``preset`` (default "medium") and the cache's parameter names).
  Defaults (3, 40, 0.45) were tuned on ``garage``; see ``estimators/ambient.rs``.
- With ``reference_rays=N``: ray traced, N stratified cosine-weighted rays per point
  (unbiased).

Pixels that hit nothing are NaN in ``image``; so are pixels the work did not reach when a
``time_budget`` (seconds) or an interrupt stopped it (``stats["complete"]`` is then False).
The result is bit-identical for any ``threads`` at a fixed seed.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from . import _core, display
from ._checks import check_call
from ._progress import progress_bar
from .cache import VisibilityCache


@dataclass
class AOResult:
    """``image``: (H, W) float32 ambient occlusion in [0, 1], NaN where no surface (or no
    value); ``stats``: rays, rays_per_point (record shadow + closest-hit rays per covered
    pixel for the cache; primary rays not counted), records, seconds, ...; ``cache``: the
    cache used (None for the reference)."""

    image: np.ndarray
    stats: dict[str, Any] = field(default_factory=dict)
    cache: Any = None

    # Jupyter shows the AO as grey; ``save`` writes EXR or PNG (``viscache_rs.display``).
    _repr_png_ = display.ao_repr_png
    save = display.ao_save


def render_ao(
    setup,
    camera=None,
    cache=None,
    reference_rays: int | None = None,
    seed: int = 0,
    threads: int | None = None,
    progress: bool | None = None,
    time_budget: float | None = None,
    sigma_scale: float | None = None,
    min_radius_scale: float | None = None,
    w_min: float | None = None,
    gbuffer: _core.GBuffer | None = None,
    **cache_overrides,
) -> AOResult:
    """Ambient occlusion of a setup; see the module docstring."""
    check_call(setup, camera=camera, gbuffer=gbuffer, lit=False)
    if camera is None and gbuffer is None:
        camera = setup.camera
    if reference_rays is None and cache is None:
        # AO reads each record's nearest-hit distance R_i, which the default "auto" preset
        # (tuned for the control variate) skips: AO's own defaults are "medium"'s.
        cache = VisibilityCache(setup.scene, **{"preset": "medium", **cache_overrides})
    elif cache_overrides:
        raise TypeError(
            f"cache_overrides: {sorted(cache_overrides)} apply only when a new cache is made "
            "(cache=None and no reference_rays)"
        )
    if reference_rays is not None and cache is not None:
        raise TypeError("cache: pass cache or reference_rays, not both")
    if cache is not None and not isinstance(cache, _core.VisibilityCache):
        raise TypeError(f"cache: expected a VisibilityCache, got {type(cache).__name__}")
    desc = "AO reference" if reference_rays is not None else "AO cache"
    with progress_bar(progress, desc, "px") as callback:
        out = _core.render_ao(
            setup.scene,
            camera,
            cache=cache,
            reference_rays=reference_rays,
            seed=seed,
            threads=threads,
            time_budget=time_budget,
            sigma_scale=sigma_scale,
            min_radius_scale=min_radius_scale,
            w_min=w_min,
            callback=callback,
            gbuffer=gbuffer,
        )
    return AOResult(out["image"], out["stats"], cache)


__all__ = ["AOResult", "render_ao"]
