//! Small formulas shared by geometry, lights, materials and estimators, kept here so that
//! those modules need not import each other for them.

use std::f32::consts::TAU;

use glam::Vec3;

/// Rec. 709 / sRGB luminance weights of linear R, G, B (they sum to 1).
pub const LUMINANCE: [f64; 3] = [0.2126, 0.7152, 0.0722];

/// [`LUMINANCE`] in `f32`, each weight rounded to the nearest `f32` (the same values as
/// the decimal weights written as `f32` literals).
pub const LUMINANCE_F32: [f32; 3] = [
    LUMINANCE[0] as f32,
    LUMINANCE[1] as f32,
    LUMINANCE[2] as f32,
];

/// Unnormalised geometric normal `(v1 - v0) x (v2 - v0)`; zero for degenerate triangles.
#[inline]
pub fn triangle_cross(t: &[Vec3; 3]) -> Vec3 {
    (t[1] - t[0]).cross(t[2] - t[0])
}

/// The constant of relMSE's denominator `μ² + 10⁻²` (`viscache_rs.metrics`): keeps black
/// pixels from dominating. Every weighting of a pixel "as it counts in relMSE" uses it.
pub const RELMSE_FLOOR: f64 = 1e-2;

/// Radius of the window of neighbours (the centre excluded) that measures a pixel's share
/// of the samples and its mixture after an adaptive pilot: 5x5.
pub const WINDOW_RADIUS: usize = 2;

/// A unit vector uniform on the hemisphere around +z for `u` in [0,1)^2 (z = u0).
pub fn uniform_hemisphere(u: [f32; 2]) -> Vec3 {
    let z = u[0];
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = TAU * u[1];
    Vec3::new(r * phi.cos(), r * phi.sin(), z)
}

/// An orthonormal basis `(t, b)` completing unit `n` (Duff et al. 2017, "Building an
/// Orthonormal Basis, Revisited").
pub fn orthonormal_basis(n: Vec3) -> (Vec3, Vec3) {
    let sign = 1f32.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    (
        Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x),
        Vec3::new(b, sign + n.y * n.y * a, -n.y),
    )
}

/// Maps a local direction (z along `n`) into world space.
pub fn to_world(local: Vec3, n: Vec3) -> Vec3 {
    let (t, b) = orthonormal_basis(n);
    t * local.x + b * local.y + n * local.z
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn f32_luminance_weights_are_the_decimal_ones() {
        assert_eq!(
            LUMINANCE_F32.map(f32::to_bits),
            [0.2126f32, 0.7152, 0.0722].map(f32::to_bits)
        );
        assert_eq!(LUMINANCE.iter().sum::<f64>(), 1.0);
    }
}
