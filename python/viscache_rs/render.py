"""The renderer: direct illumination from the environment map and area lights, and
indirect light by path tracing.

``render(setup, camera=None, spp=None, method="mis", seed=0, threads=None, progress=None,
time_budget=None, envmap=None, product_level="auto", cache=None, preset="auto", jitter=True,
alpha=1.0, alpha_radius=4, insert_missing=False, technique_weights=None, bounces=None,
direct=True, gbuffer=None, light_samples=None, learn_techniques=True, adaptive=None)`` renders
``setup.scene`` lit by ``setup.envmap`` (or ``envmap``) and the scene's area lights, through
``camera`` (default: the setup's). Methods:

- ``"env"``: light sampling (the map's own distribution, one point per area light);
- ``"bsdf"``: BSDF sampling (what the sampled ray finds);
- ``"mis"``: both, with the power heuristic;
- ``"product"``: product importance sampling of map x BSDF (CAM08 sec. 5.5); area lights
  by light sampling. The product's cells are 32^2 (``product_level=5``), or with
  ``"auto"`` (default) 32^2, 64^2 only for Phong lobes of exponent above about 650, and
  16^2 on Lambert surfaces of jittered views whose edge share (below) is at least 0.4,
  where most samples leave their anchor's surface and draw from products built for their
  own normals, so that a cheaper product pays (``stats["coarse_products"]``);
- ``"cv"``: product sampling with the visibility cache's ``L B~ V~`` as a control variate
  (CAM08 eq. 2-3): ``cache=`` a built :class:`VisibilityCache`, or None to build one for
  the view with ``preset`` (default "auto"; its cost is in ``stats["cache_seconds"]``, and
  under a ``time_budget`` it spends at most a quarter of the budget, the render the rest;
  it holds at most one record per 400 of the render's samples, so that a 10-spp render
  does not wait on a build it cannot repay, and its coherence check keeps no records
  where the predicted gain over product sampling, build included, is below 1. Under a
  budget alone the samples are estimated from two short pilots of product sampling (8
  and 32 spp over at most 1,200 pixels; ``stats["cache_planned_spp"]``), so that, as the
  number of passes, the records kept depend on the machine's speed.
  ``alpha`` is a number in [0, 2] (CAM08 uses 1) or ``"estimate"``: per pixel,
  Cov(Z, W) / Var(W) pooled over the other pixels of a ``(2 alpha_radius + 1)^2`` window,
  which keeps the estimate unbiased (``res.alpha`` holds it). The records' misses go back
  to the cache (CAM08 sec. 5.3); ``insert_missing=True`` then gives records to the points
  that found none;
- ``"path"``: the unbiased reference with indirect light: ``"mis"`` at the first hit plus
  ``bounces`` (default 1) bounces of a path that samples the BSDF and estimates direct
  light by MIS at every vertex it reaches; Russian roulette from the second bounce.
  ``direct=False`` keeps only the indirect part (no emitters or map seen by the camera, no
  direct light at the first hit): what irradiance caching and VF approximate. Any other
  method takes ``bounces`` too (default 0), its own estimator then shading the first hit;
- ``"vpl"`` and ``"vpl_sampled"``: the many-light renderer over virtual point lights
  (``vpls=``, ``clamp=``, ``vpl_samples=``, ``sampling=``; see :mod:`viscache_rs.vpl`);
- ``"irradiance_cache"`` (biased, the survey's ch. 3): one bounce (``bounces=1``), its
  diffuse part interpolated from an :class:`IrradianceCache` (``cache=``, grown for the
  view; or one built from ``a=``, ``strata=``, ``r_min=``, ``r_max=``, ``gradients=``,
  ``clamp_neighbours=``, ``secondary_spp=``), Phong's specular part and pixels without a
  usable record by paths; ``stats["seconds"]`` includes the build, ``stats["records"]``,
  ``stats["irradiance_misses"]`` say what it did. Direct light as ``"mis"`` unless
  ``direct=False``.
- ``"importance_cache"`` (unbiased for the VPL set; the survey's ch. 6): ``vpl_samples``
  (16) lights per row and sample drawn from the rows F, U, B, C of the ``nearest`` records
  of an :class:`ImportanceCache` (``cache=``, or one built for the view from ``spacing=``,
  ``nearest=``), ``combine`` "alpha_max" (default, confidences ``alpha=(α_F, α_U, α_B,
  α_C)``), "balance", or one row "F", "U", "B", "C" (biased but "C"), ``lam`` eq. 6.3's
  normal weight in median record reaches; ``stats["seconds"]`` includes a build,
  ``stats["build_seconds"]`` is the build alone.
- ``"vf"`` (biased; Chen et al. 2014, visibility filtering): one bounce from about
  ``proxies`` (default 24 000) point proxies placed by area and lit by shadow rays, each
  a first-bounce surface VPL, hashed into a ``voxels`` grid (default ``(6, 6, 6)``; an
  integer is the same on every axis); ``rays_per_pixel`` (16) cosine rays per pixel of a
  ``marching``-sized G-buffer (``(64, 64)``) march the voxels to the nearest proxy disc,
  the lists of hit voxels are united over a ``filter`` x ``filter`` window (odd, 7) of
  pixels on the same surface (relative depth within ``depth_tol``, normals' dot at least
  ``1 - normal_tol``; both in [0, 1], default 0.1), gathered at ``indirect`` resolution
  (``(256, 256)``, at most the camera's; ``marching`` at most that): voxels nearer than
  ``sh_range`` (world units, default 0.7 of the scene's diagonal; ``inf``: VPLs only)
  by their VPLs, farther ones by their bands 0-1 SH, and upsampled to the camera
  bilaterally. ``direct=True`` adds ``"mis"``'s direct light of ``spp`` samples.
  ``stats`` holds Table 1's ``voxelisation_seconds``, ``marching_seconds``,
  ``filter_seconds``, ``illumination_seconds``, ``upsampling_seconds`` and the counts
  ``proxies``, ``nonempty_voxels``, ``mean_list_before``/``mean_list_after``.
  ``proxies=`` may instead be a :class:`viscache_rs.vf.ProxyGrid` built beforehand (the
  proxies, their VPLs and grids, reusable across views; :mod:`viscache_rs.vf`;
  ``stats["grid_given"]``). Near voxels at least ``stats["merge_range"]`` away (one voxel
  diagonal) light a diffuse receiver by their VPLs pooled per quarter-voxel sub-cell and
  normal; ``stats["culled_voxels"]`` counts near voxels skipped as wholly below the
  receiver's tangent plane or behind their own.
- ``"stochastic"`` (unbiased; BLD, probabilistic visibility with geometry proxies):
  ``"env"``'s light samples with each shadow ray's visibility replaced by eq. 8's estimate
  (0, 1/p or -1/p, unclamped: pixels may be negative) against ``proxies=`` (a
  :class:`Proxies` set, required), with visibility splitting (eq. 27: the object at the
  shading point tested exactly); ``probabilities`` "optimal" (default: least variance from
  ``probe_rays``, 16, probes per pixel), "cost" (then eq. 22-24's heuristic) or "equal".
  ``stats`` counts ``shadow_rays``, ``proxy_rays``, ``scene_rays`` (of them
  ``split_rays`` and ``probe_rays``), ``terms`` (a, b, c), the traversal work per structure
  (``scene_nodes``, ``scene_triangle_tests``, ``proxy_nodes``, ``proxy_triangle_tests``)
  and ``pixel_scene_rays`` (row-major, Fig. 7's image).

All others are unbiased estimators of the same image. Every pixel's per-point work (the product
distribution, the cache lookup, J) is done once, at its *anchor*, the first hit through its
centre. By default (``jitter=True``, antialiased with a box filter) every sample traces its
own jittered primary ray and shades its own hit with the anchor's work: for "product" and
"cv" the environment is drawn from a one-sample mixture of the anchor's product
distribution, BSDF sampling at the hit and the map's own distribution, with probabilities
``technique_weights=(product, bsdf, env)`` (default (0.8, 0.1, 0.1)); the BSDF share keeps
it unbiased at any hit. A pixel's jittered rays are traced in packets of 16 from the eye
(they visit nearly the same nodes). ``light_samples=n`` (product methods) averages ``n`` draws
of the mixture, each with its shadow ray, at every sample's hit: worth it where shadow
rays are cheap beside the rest of a sample and visibility dominates the noise. Without it
(``None``, default) one draw, except for the product methods under a ``time_budget``,
which read the view's *edge share* from its anchors (the share of pixels that see a
surface whose 3x3 neighbourhood of anchors is not one object with close normals, the
image border included): below 0.275 (mostly smooth surfaces, where a pixel's jittered
hits stay on its anchor's surface) every sample takes up to 8 draws, else 1 (grass, hair,
thin parts). How many up to 8 the probe pass decides: from the variance of its samples,
of their first draws alone and the draws' share of their time, the two-stage sampling
optimum ``sqrt((c0 / c1) (V_w / V_b))`` (fewer where a draw is dear beside the rest of a
sample and the hits vary: 2 on the Cornell box at 160x120). ``stats["light_samples"]``,
``stats["edge_share"]`` and ``stats["probe_draws"]`` (the optimum before rounding; None
where the probe could not tell and the count stayed 8) report the choice, with the two
ratios it weighs: ``stats["probe_cost_ratio"]`` (``c0 / c1``, measured in CPU time, so it
moves with the machine's load) and ``stats["probe_variance_ratio"]`` (``V_w / V_b``, a
fixed function of the seed).
Under a ``time_budget``, method ``"product"`` learns its mixture weights from the probe
pass's draws (``learn_techniques=True``, default): fixed-point steps toward the weights of
least relMSE-weighted second moment, every technique kept at a share of 0.05 at least;
``stats["learnt_weights"]`` reports them (later samples stay unbiased: their weights are
fixed before they are drawn). With adaptive counts (below) every pixel then takes, for the
samples after the pilot, whichever of the image's mixture and 10 others (mostly product to
mostly BSDF, with more map sampling or none) gave its neighbours' pilot draws the least
second moment (``stats["pixel_mixtures"]`` counts the pixels per choice).
A jittered sample whose hit is not its anchor's surface (another blade of grass) cannot use
the anchor's product; where its material has a diffuse part it draws from the product of
the nearest of a 32x32 octahedral grid of normals, built once per render, for the diffuse
part's share of the product's weight (``stats["unmatched_samples"]`` counts such samples).
``jitter=False`` shades every sample at the anchor (CAM08's fixed
points; aliased); with ``technique_weights={"product": 1}`` that is the paper's plain product
sampling.
``gbuffer=`` (from ``setup.scene.gbuffer(camera, jitter=False)``) gives the anchors: the same
buffer given to ``VisibilityCache.build(gbuffer=...)`` places the records at exactly these
points, and no primary ray through a pixel centre is traced again (``camera`` then defaults
to the buffer's; another camera is refused). Method "cv" without a cache traces one G-buffer
and builds the cache and renders from it.
``spp`` defaults to the method's (16; 1 for "vpl" and "vpl_sampled"; ``vc.methods()``
lists it); with a ``time_budget`` (seconds, counted from the call's start, the default
VPLs' tracing and method "cv"'s own cache included) the render runs passes of growing size
until the budget is spent (at most ``spp`` samples per pixel on average if given). Every
pixel gets at least one sample: where the budget cannot buy that (thousands of VPLs per
sample at a large size), the render takes it anyway and ``stats["first_sample_seconds"]``
says when every pixel had one; pass fewer ``vpls`` or use "vpl_sampled" to fit a shorter
budget.

``adaptive`` (default: on under a ``time_budget``, off otherwise) spends the samples where
they cut the image's relMSE most: a pilot pass takes a quarter of them evenly, then every
pixel takes a share proportional to the relative standard deviation of one sample, as its
neighbours' samples (a 5x5 window without the pixel) measured it, never below the pilot
and at most 16 times the mean. ``spp`` is then the mean per pixel; renders of fewer than 8
samples per pixel take them evenly. ``res.sample_counts`` (H, W) holds every pixel's
count, ``stats["spp"]``, ``stats["mean_spp"]`` and ``stats["max_spp"]`` the least, mean
and most. The result is bit-identical for any ``threads`` at a fixed seed (with
``adaptive=True`` and no budget too: the shares are a function of the pilot's samples).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from . import _core
from ._checks import check_call
from ._progress import progress_bar
from ._result import RenderResult

# Method "cv" without a cache (the policy is Rust's, `render::own_cache`): the share of a
# time budget its build may spend, and the render's samples per record it may hold.
CACHE_BUDGET_SHARE: float = _core.OWN_CACHE_BUDGET_SHARE
SAMPLES_PER_RECORD: int = _core.OWN_CACHE_SAMPLES_PER_RECORD
# The registry's rows by name: default and most samples per pixel, for the progress bar.
_METHODS = {m["name"]: m for m in _core.methods()}


def render(
    setup,
    camera=None,
    spp: int | None = None,
    method: str = "mis",
    seed: int = 0,
    threads: int | None = None,
    progress: bool | None = None,
    time_budget: float | None = None,
    envmap=None,
    product_level: int | str = "auto",
    cache=None,
    preset: str = "auto",
    jitter: bool = True,
    alpha: float | str | tuple[float, float, float, float] = 1.0,
    alpha_radius: int = 4,
    insert_missing: bool = False,
    technique_weights: dict[str, float] | None = None,
    bounces: int | None = None,
    direct: bool = True,
    gbuffer: _core.GBuffer | None = None,
    vpls=None,
    clamp: float | None = None,
    vpl_samples: int | None = None,
    light_samples: int | None = None,
    learn_techniques: bool = True,
    adaptive: bool | None = None,
    a: float | None = None,
    strata: tuple[int, int] | None = None,
    r_min: float | None = None,
    r_max: float | None = None,
    gradients: str | None = None,
    clamp_neighbours: bool | None = None,
    secondary_spp: int | None = None,
    proxies: int | _core.ProxyGrid | _core.Proxies | None = None,
    voxels: int | tuple[int, int, int] | None = None,
    marching: int | tuple[int, int] | None = None,
    indirect: int | tuple[int, int] | None = None,
    rays_per_pixel: int | None = None,
    filter: int | None = None,
    depth_tol: float | None = None,
    normal_tol: float | None = None,
    sh_range: float | None = None,
    sampling: str | None = None,
    combine: str | None = None,
    lam: float | None = None,
    spacing: int | None = None,
    nearest: int | None = None,
    probabilities: str | None = None,
    probe_rays: int | None = None,
) -> RenderResult:
    """Renders direct illumination of a built-in or user setup; see the module docstring."""
    # (A cache is checked by the registry below, against the caches the method accepts.)
    check_call(setup, camera=camera, envmap=envmap, gbuffer=gbuffer)
    # The registry (Rust) says what each method reads: a parameter set for a method that
    # ignores it, or a cache it does not take, is an error naming it.
    given = {"product_level": product_level != "auto",
             "preset": preset != "auto", "alpha": alpha != 1.0,
             "alpha_radius": alpha_radius != 4, "insert_missing": bool(insert_missing),
             "technique_weights": technique_weights is not None,
             "gbuffer": gbuffer is not None, "vpls": vpls is not None,
             "clamp": clamp is not None, "vpl_samples": vpl_samples is not None,
             "light_samples": light_samples is not None,
             "learn_techniques": not learn_techniques, "adaptive": bool(adaptive),
             "a": a is not None, "strata": strata is not None, "r_min": r_min is not None,
             "r_max": r_max is not None, "gradients": gradients is not None,
             "clamp_neighbours": clamp_neighbours is not None,
             "secondary_spp": secondary_spp is not None,
             "sampling": sampling is not None,
             "proxies": proxies is not None, "voxels": voxels is not None,
             "marching": marching is not None, "indirect": indirect is not None,
             "rays_per_pixel": rays_per_pixel is not None, "filter": filter is not None,
             "depth_tol": depth_tol is not None, "normal_tol": normal_tol is not None,
             "sh_range": sh_range is not None, "combine": combine is not None,
             "lam": lam is not None, "spacing": spacing is not None,
             "nearest": nearest is not None,
             "probabilities": probabilities is not None,
             "probe_rays": probe_rays is not None}
    _core.check_method_args(method, [k for k, v in given.items() if v], cache)
    if camera is None:
        camera = setup.camera if gbuffer is None else gbuffer.camera
    envmap = setup.envmap if envmap is None else envmap
    # The bar counts samples per pixel; without a cap (a time budget alone) its total is
    # unknown. The core takes the method's default without spp.
    row = _METHODS[method]
    total = spp if spp is not None else (None if time_budget is not None else row["default_spp"])
    with progress_bar(progress, f"render ({method})", "spp", total=total,
                      per_unit=camera.width * camera.height) as callback:
        out = _core.render(
            setup.scene,
            envmap,
            camera,
            spp,
            method,
            seed=seed,
            threads=threads,
            time_budget=time_budget,
            product_level=product_level,
            callback=callback,
            cache=cache,
            jitter=jitter,
            # Method "importance_cache" reads alpha as (α_F, α_U, α_B, α_C); the default
            # 1.0 is CV's and means the cache's own there.
            alpha=None if method == "importance_cache" and alpha == 1.0 else alpha,
            alpha_radius=alpha_radius,
            insert_missing=insert_missing,
            technique_weights=technique_weights,
            bounces=bounces,
            direct=direct,
            gbuffer=gbuffer,
            light_samples=light_samples,
            learn_techniques=learn_techniques,
            adaptive=adaptive,
            preset=preset,
            vpls=vpls,
            clamp=clamp,
            vpl_samples=vpl_samples,
            a=a,
            strata=strata,
            r_min=r_min,
            r_max=r_max,
            gradients=gradients,
            clamp_neighbours=clamp_neighbours,
            secondary_spp=secondary_spp,
            sampling=sampling,
            proxies=proxies,
            voxels=voxels,
            marching=marching,
            indirect=indirect,
            rays_per_pixel=rays_per_pixel,
            filter=filter,
            depth_tol=depth_tol,
            normal_tol=normal_tol,
            sh_range=sh_range,
            combine=combine,
            lam=lam,
            spacing=spacing,
            nearest=nearest,
            probabilities=probabilities,
            probe_rays=probe_rays,
        )
    stats = out["stats"]
    return RenderResult(out["image"], out["variance"], stats, out["alpha"],
                        out["sample_counts"])


def record_cap(scene, pixels: int, spp: int, preset: str = "auto") -> int:
    """Records the cache ``render(method="cv")`` builds for itself may hold for ``pixels``
    pixels at ``spp``: one per ``SAMPLES_PER_RECORD`` samples, at least the bootstrap's,
    at most the preset's ``max_records`` (a checked build also stops at a tenth of the
    covered pixels). ``scene`` is not read (the cap depends on the preset alone)."""
    del scene
    return _core.own_cache_record_cap(pixels, spp, preset)


def preview(setup, cache, envmap=None, camera=None, product_level: int | str = "auto",
            threads: int | None = None, gbuffer: _core.GBuffer | None = None) -> np.ndarray:
    """CAM08 sec. 6.2's lighting preview: ``J = int L B~ V~`` per pixel, an (H, W, 3) float32
    image, from ``cache``'s records under ``envmap`` (default: the setup's), at the hits of
    ``gbuffer`` if given (the buffer the cache was built from), else through ``camera``'s
    pixel centres. One call integrates every pixel from scratch. For many lightings of one
    view, make a :class:`LightingPreview` once (it keeps the hits) and call its
    ``render(cache, envmap, rotation=...)``: it traces no ray and, after a first call that
    caches each pixel's transfer, answers a swap or rotation of the map in milliseconds."""
    check_call(setup, camera=camera, envmap=envmap, gbuffer=gbuffer)
    if not isinstance(cache, _core.VisibilityCache):
        raise TypeError(f"cache: expected a VisibilityCache, got {type(cache).__name__}")
    if camera is None and gbuffer is None:
        camera = setup.camera
    envmap = setup.envmap if envmap is None else envmap
    view = _core.LightingPreview(setup.scene, camera, threads=threads, gbuffer=gbuffer)
    return view.render(cache, envmap, product_level=product_level, threads=threads, direct=True)


def methods() -> list[dict[str, Any]]:
    """The method registry: one dict per ``render(method=...)`` name, in order, with
    ``name``, ``about``, ``estimator`` ("direct" or "many_lights"), ``params`` (the keyword
    parameters it reads beyond ``common``, which every method reads), ``caches`` (the cache
    types ``cache=`` accepts), ``min_bounces``, ``default_bounces``, ``default_spp`` and
    ``max_spp``. A parameter set for
    a method that does not read it raises ValueError naming it."""
    return _core.methods()


__all__ = ["RenderResult", "methods", "preview", "render"]
