"""Virtual point lights and the many-light renderer (instant radiosity, survey ch. 6.2).

``VPLs.trace(setup, count, seed=0, importance=True, depth=1, epsilon=0.05,
pilot_paths=4000, lights=True, camera=None, envmap=None, threads=None)`` traces about ``count`` VPLs
by light tracing from the setup's map (a direction by the map's distribution, a start on
the disk that covers the scene) and its area lights (a point by area, a cosine-weighted
direction): a *light VPL* at each path's start (direct light) and a *surface VPL* at each
of its first ``depth`` hits (light that bounced that many times). With ``importance``
(survey sec. 6.2.2, Algorithm 11) surface VPLs are kept with probability
``min(Phi_i / Phi_v + epsilon, 1)`` by their contribution to the camera's view, their flux
divided by it: unbiased, with the VPLs where the camera looks. ``lights=False`` keeps no
light VPLs (``count`` then counts VPLs of indirect light only). ``.positions``,
``.normals``, ``.flux`` (N, 3) float32, ``.incident``, ``.bounces`` (generation, 0 for light
VPLs), ``.kinds`` (0 area-light point, 1 map direction, 2 surface), ``len()``, ``.stats``.
``VPLs.from_lights(scene, positions, normals, flux)`` makes cosine point lights.

``vc.render(setup, method="vpl", vpls=..., clamp=None, direct=True)`` sums every VPL's
term (survey eq. 6.1) with one shadow ray each at the first hit of every pixel sample
(``spp``, default 1, each its own jittered hit: antialiased); ``method="vpl_sampled"``
draws ``vpl_samples`` (default 16) VPLs per pixel sample in proportion to their
unoccluded contribution, an unbiased estimate of the same sum. ``clamp`` bounds the
geometry term ``cos cos / d^2`` (1/m^2; removes the bright spots of nearby VPLs, biased);
``direct=False`` keeps the surface VPLs only: the indirect light of ``method="path",
bounces=depth, direct=False``. Without ``vpls`` a set of 4096 is traced with
``depth=bounces`` (default 1), without light VPLs when ``direct=False``.

The render runs on the pass layer, as ``vc.render``'s other methods do. Without
``time_budget`` every pixel takes ``spp`` samples, bit-identical for any ``threads``. With
one, a probe pass takes a few samples in every eighth band of rows, then passes sized by
the measured cost per sample take as many as fit (``spp`` at most, unbounded by default):
every pixel gets at least one, and the probe's pixels may keep up to four more than the
rest. ``stats["spp"]`` is the least samples any pixel took, ``stats["samples"]`` all of
them, and each pixel's mean and variance are over its own samples. Ctrl-C stops the pass
under way within a tile's sample and raises KeyboardInterrupt.
"""

from __future__ import annotations

import numbers
from typing import Any

from . import _core
from ._core import VPLs
from ._progress import progress_bar
from ._result import RenderResult

_UNBOUNDED_SPP = 1 << 16
# The core's defaults: the VPLs traced for a render given none, the draws of "vpl_sampled".
DEFAULT_COUNT: int = _core.DEFAULT_VPLS
DEFAULT_SAMPLES: int = _core.DEFAULT_VPL_SAMPLES
METHODS = ("vpl", "vpl_sampled")


def _bounces(bounces: Any) -> int | None:
    if bounces is None:
        return None
    if isinstance(bounces, bool) or not isinstance(bounces, numbers.Integral):
        raise TypeError(f"bounces: expected an integer, got {type(bounces).__name__}")
    if bounces < 1:
        raise ValueError(f"bounces: must be >= 1 (the VPLs' depth), got {bounces}")
    return int(bounces)


def render_vpl(setup, camera=None, spp: int | None = None, method: str = "vpl",
               seed: int = 0, threads: int | None = None, progress: bool = True,
               time_budget: float | None = None, envmap=None, vpls: VPLs | None = None,
               clamp: float | None = None, vpl_samples: int | None = None,
               bounces: int | None = None, direct: bool = True, jitter: bool = True):
    """``vc.render``'s methods "vpl" and "vpl_sampled" (module docstring); returns a
    :class:`RenderResult` whose stats hold the VPL count, shadow rays, seconds and rays/s."""
    if method not in METHODS:
        raise ValueError(f"method: expected one of {METHODS}, got {method!r}")
    camera = setup.camera if camera is None else camera
    envmap = setup.envmap if envmap is None else envmap
    depth = _bounces(bounces)
    # Without a set the core traces its default one (render::many_lights::default_vpls).
    if vpls is not None and not isinstance(vpls, VPLs):
        raise TypeError(f"vpls: expected a VPLs set, got {type(vpls).__name__}")
    if vpls is not None and depth is not None:
        raise ValueError("bounces: a given VPL set has its own depth; pass bounces=None "
                         "or trace the set with depth=bounces")
    if method == "vpl_sampled":
        vpl_samples = DEFAULT_SAMPLES if vpl_samples is None else vpl_samples
    elif vpl_samples is not None:
        raise ValueError("vpl_samples: only method 'vpl_sampled' draws VPLs; "
                         "method 'vpl' sums them all")
    if spp is None:
        spp = _UNBOUNDED_SPP if time_budget is not None else 1
    total = None if time_budget is not None and spp >= _UNBOUNDED_SPP else spp
    with progress_bar(progress, f"render ({method})", "spp", total=total,
                      per_unit=camera.width * camera.height) as callback:
        out = _core.render_vpl(setup.scene, envmap, camera, vpls, spp=spp, seed=seed,
                               threads=threads, clamp=clamp, direct=direct, jitter=jitter,
                               vpl_samples=vpl_samples, time_budget=time_budget,
                               callback=callback, depth=depth)
    stats = out["stats"]
    stats["method"] = method
    return RenderResult(out["image"], out["variance"], stats)


__all__ = ["VPLs", "render_vpl"]
