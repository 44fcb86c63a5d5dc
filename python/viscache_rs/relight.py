"""Relighting with decoupled visibility and an error bound (SBF: Schwenk, Behr & Fellner,
"An Error Bound for Decoupled Visibility with Application to Relighting").

``Relighter(setup, camera=None, visibility="pixels", cache=None, threads=None)`` keeps the
first hits of a view (a G-buffer through the pixel centres). Per pixel and light (the
environment map, sampled by the pixel's product distribution, and every area light,
sampled by area) it estimates ``<LB>`` (no shadow rays), ``<LBV>`` (one shadow ray per
sample) and takes ``<V>``, the expected visibility under the same density, from:

- ``visibility="pixels"``: ``converge_visibility(spp=256)`` traces V-samples at the pixels
  and keeps their counts and the first 224 bit by bit, per light. Edits that keep a light's
  density (area-light radiance, any edit of an area light's receivers' materials) reuse
  them as they are; an
  edit of the map's density (another or rotated map, another material) reweights them by
  ``p'/p`` (``res.effective_samples`` says how far the densities differ), with no ray;
  where the new density puts light the old one never drew toward (a sun turned to
  where the old map was dark), the bound widens by that share and ``t`` falls. With
  ``reuse=True`` (the default) the stored samples also join the unbiased part as
  ``LBV``-samples of the density they were drawn from, V known, no ray: every area light's,
  and the map's after an edit of its density, combined with the new draws by the balance
  heuristic, so it stays unbiased (on the Cornell box after SBF's pattern switch its
  relMSE at threshold 0 fell 100x for 3x the time; after map edits 1.8-4.9x for +8-10%);
- ``visibility="cache"``: the visibility cache's interpolated records ``V~`` averaged over
  directions drawn from the current density, with no ray, so ``render(camera=...)`` may
  move the view. ``cache`` (the map's) defaults to a "medium" cache built for the view.
  Its records see an area light's own triangles as occluders, as the map's visibility
  must, so area lights keep the unbiased ``<LBV>`` (``t = 0``) in this mode unless
  ``light_cache`` is given: a cache whose records count a ray that reaches a light as
  unoccluded (``VisibilityCache(scene, emitters_visible=True)``, built for the view), from
  which each pixel's ``<V>`` is averaged over 16 draws of the light's density (no ray).
  It is not the default: on the Cornell box its interpolated ``<V>`` is off by 0.02 on
  average, most at the blocks' shadows, and the first frame then has 3.7x the relMSE of
  ``<LBV>`` alone at equal time, where pixel visibility with its reused samples has 0.35x
  (``viscache experiment relight``, ``cache_lights`` rows).

``render(envmap=None, materials=None, lb_spp=64, lbv_spp=8, threshold=0.25, epsilon=0.1,
seed=0, camera=None, threads=None, time_budget=None, adaptive=True, least_error=True,
reuse=True, progress=False)`` returns SBF eq. 9's
blend ``(1 - t) <LBV> + t <LB> <V>`` per light, with ``t`` from the estimated relative error
bound ``sqrt(Var(LB/p) Var(V)) / <LB>`` (eq. 7, 10) against ``threshold`` (eq. 11; the worst
channel decides, ``t <= 1 - epsilon``; ``threshold=0`` is the unbiased part alone, and with
``reuse=False`` SBF's classical ``<LBV>``, which reads no ``<V>``: visibility and bound NaN), and
never above the share that minimises the blend's expected squared error for the bias
``<LB><V>`` and ``<LBV>`` measurably differ by: where they differ, ``t`` falls as
``LBV``-samples accumulate and the blend converges to ``<LBV>`` (eq. 11 alone keeps the bias
however many are taken; ``least_error=False`` gives eq. 11 alone). ``materials`` is a dict
of object id -> :class:`Material` overriding the scene's; area-light radiance and textures
are edited on the scene (``scene.set_emission``, ``scene.set_emission_texture``). Without
``time_budget`` the render is one pass: every pixel's ``LB``-samples, ``<V>`` and ``lbv_spp``
``LBV``-samples (SBF's first frame). With ``time_budget`` (seconds, counted from the call)
the first pass still gives every pixel its ``LB``-samples, ``<V>`` and ``lbv_spp``
``LBV``-samples, and the passes after it are the renderer's (``vc.render``): sized by the
first pass's timing, they bring every pixel to as many ``LBV``-samples as fit the budget
left (SBF's later frames: ``Var(LB/p)`` is known, a sample costs what a classical one
does; ``lbv_spp`` 0 still means no ``LBV``-samples: one pass). With ``adaptive`` (the
default; budgets only) the pass after the first is a pilot of a quarter of its samples,
after which each pixel takes the rest in proportion to ``sqrt(v / c)``, ``v`` its blend's
relative variance per sample, ``(1 - t)^2 Var(LBV/p) / (mean^2 + 1e-2)``, and ``c`` its cost
per sample, both pooled over its neighbours (the renderer's adaptive counts: relMSE's
optimum), so pixels that lean on ``<LB><V>`` take few; ``adaptive=False`` gives every pixel
the same count, and the image then equals a run without a budget asked for that count.
``stats["first_pass_seconds"]`` is the first pass's wall-clock time.
``stats["lbv_spp"]`` is the most a pixel took, ``stats["lbv_spp_mean"]`` the mean over the
pixels that see a surface. Where ``LB``-samples would change nothing they are not drawn
(``stats["lb_skipped"]`` counts them): at a light without ``<V>`` (an area light with
cache visibility and no ``light_cache``, or no records there: ``t = 0``), and at one
whose ``<V>`` is exactly 0 with a bound of 0 (every V-sample blocked: a closed room's
map). Results are bit-identical for any
``threads`` (under a budget, for the same passes).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from . import _core, display
from ._checks import check_call, check_optional
from ._progress import progress_bar
from .cache import VisibilityCache


@dataclass
class RelightResult:
    """``image`` and ``variance`` (H, W, 3) float32 (the variance treats ``<V>`` as exact);
    ``error_bound`` (H, W, 3): the estimated absolute error of ``<LB><V>`` summed over
    lights (eq. 7 plus two standard errors of ``<V>``: from its effective sample count, or
    from the cache, the spread of the records it blends; reweighted samples add the share
    of the new density they missed, ``1 - mean(p'/p)``, times ``max(<V>, 1 - <V>)``). Per
    pixel and light (H, W, L), light 0 the map, then the area lights: ``t`` (the blend
    factor), ``bound`` (estimated relative error bound, worst channel), ``visibility``
    (``<V>``) and ``effective_samples``; NaN where a pixel has no surface or a light no ``<V>``.
    ``lbv_counts`` (H, W) uint32: the ``LBV``-samples per light each pixel took (0 where it
    sees no surface)."""

    image: np.ndarray
    variance: np.ndarray
    error_bound: np.ndarray
    t: np.ndarray
    bound: np.ndarray
    visibility: np.ndarray
    effective_samples: np.ndarray
    lbv_counts: np.ndarray
    stats: dict[str, Any] = field(default_factory=dict)

    # Jupyter shows the image; ``save`` writes EXR or PNG (``viscache_rs.display``).
    _repr_png_ = display.radiance_repr_png
    save = display.radiance_save


class Relighter:
    """Relighting with decoupled visibility (SBF); see the module docstring."""

    def __init__(self, setup, camera=None, visibility: str = "pixels", cache=None,
                 threads: int | None = None, light_cache=None):
        check_call(setup, camera=camera, cache=cache)
        check_optional(light_cache, "light_cache", _core.VisibilityCache, "a VisibilityCache")
        if visibility not in ("pixels", "cache"):
            raise ValueError(f"visibility: expected 'pixels' or 'cache', got {visibility!r}")
        if cache is not None and visibility != "cache":
            raise ValueError("cache: only visibility='cache' reads a cache")
        if light_cache is not None and visibility != "cache":
            raise ValueError("light_cache: only visibility='cache' reads a cache")
        if light_cache is not None and not light_cache.params["emitters_visible"]:
            raise ValueError("light_cache: needs a cache built with emitters_visible=True")
        self.setup = setup
        self.threads = threads
        self.camera = setup.camera if camera is None else camera
        self.gbuffer = setup.scene.gbuffer(self.camera, jitter=False, threads=threads)
        self._core = _core.Relighter(setup.scene, self.gbuffer, visibility=visibility)
        if visibility == "cache" and cache is None:
            cache = VisibilityCache(setup.scene, preset="medium", nearest_hits=False)
            cache.build(gbuffer=self.gbuffer, threads=threads, progress=False)
        self.cache = cache
        self.light_cache = light_cache

    @property
    def visibility(self) -> str:
        """Where ``<V>`` comes from: "pixels" or "cache"."""
        return self._core.visibility

    def converge_visibility(self, spp: int = 256, seed: int = 0, envmap=None,
                            threads: int | None = None, time_budget: float | None = None,
                            progress: bool | None = None) -> dict[str, Any]:
        """Traces ``spp`` V-samples per pixel and light under ``envmap`` (default: the
        setup's) and the scene's materials, in passes of 16 (with ``time_budget`` seconds,
        no pass starts once it is spent; ``["spp"]`` says how many were taken). Shows a
        progress bar with ``progress=True`` (default None: only when stderr is a
        terminal); Ctrl-C stops and leaves the relighter as it was. Returns spp,
        shadow_rays, seconds and bytes_per_pixel_and_light (two 16-bit counts per light,
        and for the map a bit for each of its first 224 V-samples, to reweight them: at
        most 32 bytes, SBF's 8 floats)."""
        envmap = self.setup.envmap if envmap is None else envmap
        threads = self.threads if threads is None else threads
        pixels = self.camera.width * self.camera.height
        with progress_bar(progress, "visibility", "spp", total=spp, per_unit=pixels) as bar:
            return self._core.converge_visibility(envmap, spp, seed=seed, threads=threads,
                                                  time_budget=time_budget, callback=bar)

    def render(self, envmap=None, materials: dict[int, Any] | None = None, lb_spp: int = 64,
               lbv_spp: int = 8, threshold: float = 0.25, epsilon: float = 0.1, seed: int = 0,
               camera=None, threads: int | None = None, time_budget: float | None = None,
               adaptive: bool = True, least_error: bool = True, reuse: bool = True,
               progress: bool = False) -> RelightResult:
        """Relights the view; see the module docstring."""
        envmap = self.setup.envmap if envmap is None else envmap
        threads = self.threads if threads is None else threads
        if camera is not None and camera != self.camera:
            if self.visibility != "cache":
                raise ValueError("camera: only visibility='cache' lets the view move; "
                                 "pixel visibility belongs to the view it was traced for")
            self.camera = camera
            self.gbuffer = self.setup.scene.gbuffer(camera, jitter=False, threads=threads)
            self._core = _core.Relighter(self.setup.scene, self.gbuffer, visibility="cache")
        # The bar counts LBV-samples per pixel; under a time budget their total is unknown.
        pixels = self.camera.width * self.camera.height
        total = None if time_budget is not None else lbv_spp
        with progress_bar(progress, "relight", "spp", total=total, per_unit=pixels) as bar:
            out = self._core.render(envmap, materials=materials, cache=self.cache,
                                    light_cache=self.light_cache,
                                    lb_spp=lb_spp, lbv_spp=lbv_spp, threshold=threshold,
                                    epsilon=epsilon, seed=seed, threads=threads,
                                    time_budget=time_budget, adaptive=adaptive,
                                    least_error=least_error, reuse=reuse, callback=bar)
        return RelightResult(out["image"], out["variance"], out["error_bound"], out["t"],
                             out["bound"],
                             out["visibility"], out["effective_samples"], out["lbv_counts"],
                             out["stats"])


__all__ = ["RelightResult", "Relighter"]
