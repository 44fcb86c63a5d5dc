//! Small formulas shared by geometry, lights, materials and estimators, kept here so that
//! those modules need not import each other for them.

use glam::Vec3;

/// Unnormalised geometric normal `(v1 - v0) x (v2 - v0)`; zero for degenerate triangles.
#[inline]
pub fn triangle_cross(t: &[Vec3; 3]) -> Vec3 {
    (t[1] - t[0]).cross(t[2] - t[0])
}
