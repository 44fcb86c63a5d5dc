"""Ray sets shared by tests, benches and the Embree peer scripts (pure functions of the seed).

``ground_hemisphere_rays(scene, n, seed=0)``: incoherent shadow rays from points on the
objects named like "ground", offset along the normal, directions uniform on the hemisphere.

``record_bundle_rays(scene, points, side=32, seed=0)``: ``points`` origins on the ground with
``side * side`` stratified hemisphere directions each, point after point (the coherent
workload of building visibility records).
"""

from ._core import testing as _testing

ground_hemisphere_rays = _testing.ground_hemisphere_rays
record_bundle_rays = _testing.record_bundle_rays

__all__ = ["ground_hemisphere_rays", "record_bundle_rays"]
