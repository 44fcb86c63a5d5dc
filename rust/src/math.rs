//! Small formulas shared by geometry, lights, materials and estimators, kept here so that
//! those modules need not import each other for them.

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
