"""Ray sets shared by tests, benches and the Embree peer scripts (pure functions of the seed).

``ground_hemisphere_rays(scene, n, seed=0)``: incoherent shadow rays from points on the
objects named like "ground", offset along the normal, directions uniform on the hemisphere.

``record_bundle_rays(scene, points, side=32, seed=0)``: ``points`` origins on the ground with
``side * side`` stratified hemisphere directions each, point after point, each point's
cells in Morton order as records trace them (the coherent workload of building visibility
records).

``chi2_sphere(dirs, pdf, resolution=32, subdivisions=8, min_expected=5.0,
significance=0.01)``: Pearson's chi-square test of sampled directions against their
solid-angle pdf, binned by the equal-area octahedral map (every bin the same solid angle;
the pdf is integrated per bin on a ``subdivisions**2`` midpoint grid). ``dirs`` has one row
per attempt, all-NaN rows for rejected attempts; ``pdf`` maps an (M, 3) float32 array of
unit directions to (M,) densities. Returns a dict: ``statistic``, ``dof``, ``p_value``,
``integral`` (of the pdf), ``samples_where_pdf_is_zero``, ``rejected``, ``passed``.
"""

from ._core import testing as _testing

ground_hemisphere_rays = _testing.ground_hemisphere_rays
record_bundle_rays = _testing.record_bundle_rays
chi2_sphere = _testing.chi2_sphere

__all__ = ["chi2_sphere", "ground_hemisphere_rays", "record_bundle_rays"]
