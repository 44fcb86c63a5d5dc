"""Ray sets shared by tests, benches and the Embree peer scripts (pure functions of the seed).

``ground_hemisphere_rays(scene, n, seed=0)``: incoherent shadow rays from points on the
objects named like "ground", offset along the normal, directions uniform on the hemisphere.

``record_bundle_rays(scene, points, side=32, seed=0)``: ``points`` origins on the ground with
``side * side`` stratified hemisphere directions each, point after point, each point's
cells in Morton order as records trace them (the coherent workload of building visibility
records).

``view_shading_rays(setup, width=160, height=120, passes=32, seed=0)``: the rays a render
of ``setup``'s view shades with: per pass, one jittered first hit per pixel (pixel order)
and a cosine-weighted direction about its normal (turned to the viewer), the origin
offset along the normal by 2^-14 of its largest coordinate; what ``vc.render`` traces for
BSDF or product samples of a diffuse surface.

``simd_level()``: the vector instruction set the kernels use on this CPU ("avx512",
"avx2", "popcnt" or "portable"); tracer timings depend on it (packets need AVX-512).

``chi2_sphere(dirs, pdf, resolution=32, subdivisions=8, min_expected=5.0,
significance=0.01)``: Pearson's chi-square test of sampled directions against their
solid-angle pdf, binned by the equal-area octahedral map (every bin the same solid angle;
the pdf is integrated per bin on a ``subdivisions**2`` midpoint grid). ``dirs`` has one row
per attempt, all-NaN rows for rejected attempts; ``pdf`` maps an (M, 3) float32 array of
unit directions to (M,) densities. Returns a dict: ``statistic``, ``dof``, ``p_value``,
``integral`` (of the pdf), ``samples_where_pdf_is_zero``, ``rejected``, ``passed``.
"""

import numpy as np

from ._core import testing as _testing

ground_hemisphere_rays = _testing.ground_hemisphere_rays
record_bundle_rays = _testing.record_bundle_rays
chi2_sphere = _testing.chi2_sphere
simd_level = _testing.simd_level



def view_shading_rays(setup, width: int = 160, height: int = 120, passes: int = 32,
                      seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Origins and unit directions, (N, 3) float32 each; see the module docstring."""
    camera = setup.camera.with_resolution(width, height)
    rng = np.random.default_rng(seed)
    origins, directions = [], []
    for k in range(passes):
        g = setup.scene.gbuffer(camera, jitter=True, seed=seed * passes + k)
        hit = g["object"] >= 0
        p = g["position"][hit].astype(np.float64)
        n = g["normal"][hit].astype(np.float64)
        n = np.where((np.sum(n * g["direction"][hit], axis=1) > 0)[:, None], -n, n)
        u1, u2 = rng.random(len(p)), rng.random(len(p))
        r, phi = np.sqrt(u1), 2 * np.pi * u2
        helper = np.where(np.abs(n[:, :1]) > 0.9, [[0.0, 1.0, 0.0]], [[1.0, 0.0, 0.0]])
        b1 = np.cross(n, helper)
        b1 /= np.linalg.norm(b1, axis=1, keepdims=True)
        b2 = np.cross(n, b1)
        d = ((r * np.cos(phi))[:, None] * b1 + (r * np.sin(phi))[:, None] * b2
             + np.sqrt(1 - u1)[:, None] * n)
        offset = np.abs(p).max(axis=1, keepdims=True) * 2.0**-14
        origins.append(p + n * offset)
        directions.append(d / np.linalg.norm(d, axis=1, keepdims=True))
    return (np.ascontiguousarray(np.concatenate(origins), np.float32),
            np.ascontiguousarray(np.concatenate(directions), np.float32))


__all__ = ["chi2_sphere", "ground_hemisphere_rays", "record_bundle_rays", "simd_level",
           "view_shading_rays"]
