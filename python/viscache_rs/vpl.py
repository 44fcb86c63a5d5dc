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
VPLs), ``.kinds`` (0 area-light point, 1 directional light, 2 surface, 3 whole area
light), ``.area_points`` (the fixed points of each whole area light), ``len()``,
``.stats``.
``VPLs.from_lights(scene, positions, normals, flux)`` makes cosine point lights;
``VPLs.from_surface(scene, positions, normals, irradiance, areas, objects)`` first-bounce
surface VPLs (VF's proxies: flux ``irradiance * area``, the object's material).

Other lights in the same set type (survey sec. 6.3, the directional and surface lights of
Fig. 6.5): ``VPLs.from_envmap(env_or_setup, level=4, scene=None)`` makes the map one
directional light per texel of its octahedral level ``level`` (``4**level`` lights; the
texel's ``sum(radiance * solid angle)`` as the irradiance it gives a surface facing it,
from the luminance-weighted mean of its directions, so a sun keeps its direction; black
texels make none); ``VPLs.from_directions(scene, directions, irradiance)`` directional
lights such as a sun (the built-in setups carry their sun inside the map, so this is how
to give one on its own); ``VPLs.from_area_lights(scene, points=16)`` the scene's area
lights as one light each (``.kinds`` 3): what distributions read of it (``sampling=
"unoccluded"``) is the quadrature over ``points`` fixed stratified points on it, floored
to stay positive wherever the light can reach, and a render that picks it samples a fresh
point by area for each shadow ray, so ``"vpl"`` (one shadow ray per light and pixel
sample) and ``"vpl_sampled"`` stay unbiased for the true area light. ``a + b`` is the union
of two sets of the same scene (``ValueError`` naming ``other`` otherwise): directional
fluxes are rescaled to one disk and the stats add (``mean_contribution`` weighted by
pilot paths). ``vpls.view_share(setup, camera=None, width=64)`` counts the lights with a
positive, unoccluded term at one pixel centre at least of a ``width``-wide G-buffer (area
lights through their fixed points): ``{"share", "contributing", "total", "points"}``,
e.g. to see what Algorithm 11's ``importance=True`` buys.

``vc.render(setup, method="vpl", vpls=..., clamp=None, direct=True)`` sums every VPL's
term (survey eq. 6.1) with one shadow ray each at the first hit of every pixel sample
(``spp``, default 1, each its own jittered hit: antialiased); ``method="vpl_sampled"``
draws ``vpl_samples`` (default 16) VPLs per pixel sample, an unbiased estimate of the
same sum, in proportion to ``sampling=``: ``"unoccluded"`` (the default) their unoccluded
contribution at the pixel's hit, ``"power"`` the luminance of their flux, ``"uniform"``
every VPL alike (the survey's Fig. 6.8 baselines; ``stats["sampling"]``). ``clamp`` bounds the
geometry term ``cos cos / d^2`` (1/m^2; removes the bright spots of nearby VPLs, biased);
``direct=False`` keeps the surface VPLs only: the indirect light of ``method="path",
bounces=depth, direct=False``. Without ``vpls`` a set of 4096 is traced with
``depth=bounces`` (default 1), without light VPLs when ``direct=False``.

``vc.render`` renders these methods through the method registry (Rust) on the pass
layer, as it does the others. Without
``time_budget`` every pixel takes ``spp`` samples, bit-identical for any ``threads``. With
one, a probe pass takes a few samples in every eighth band of rows (its bands start within a
tenth of the budget), then passes sized by
the measured cost per sample take as many as fit (``spp`` at most, unbounded by default):
every pixel gets at least one, and the probe's pixels may keep up to four more than the
rest. ``stats["spp"]`` is the least samples any pixel took, ``stats["samples"]`` all of
them, and each pixel's mean and variance are over its own samples. Ctrl-C stops the pass
under way within a tile's sample and raises KeyboardInterrupt.
"""

from __future__ import annotations

from . import _core
from ._core import VPLs

# The core's defaults: the VPLs traced for a render given none, the draws of "vpl_sampled".
DEFAULT_COUNT: int = _core.DEFAULT_VPLS
DEFAULT_SAMPLES: int = _core.DEFAULT_VPL_SAMPLES
# The registry's many-light methods (``vc.render(method=...)``).
METHODS = tuple(m["name"] for m in _core.methods() if m["estimator"] == "many_lights")

__all__ = ["VPLs", "DEFAULT_COUNT", "DEFAULT_SAMPLES", "METHODS"]
