//! Eq. 9 of CAM08 (§5.1): how much a record at distance `d` whose normal differs by `θ`
//! counts for a lookup, and the angle between two normals it takes.

use super::metric::Metric;

/// What gathering and scoring a lookup's nearest records take: `m` nearest under `metric`,
/// normals within `θ_max`, weights eq. 9 rescaled from `[w_lo, 1]` to `[0, 1]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Weighting {
    /// Records kept by distance, `1..=MAX_NEAREST`.
    pub m: usize,
    /// `θ_max`, radians: records whose normal differs by as much or more are left out.
    pub theta_max: f32,
    /// `w_lo = w(d_max, θ_max)`, the smallest weight a lookup can accept, in `[0, 1)`.
    pub w_lo: f32,
    /// `λ` of eq. 9's falloff (`>= 0`); not eq. 6.3's, which is the metric's.
    pub lambda: f32,
    /// What ranks the records within `d_max` and `θ_max` for the `m` kept.
    pub metric: Metric,
}

/// The angle `θ = atan2(sin, cos)` in `[0, π]` between two unit normals, from
/// `sin = |a × b| >= 0` and `cos = a · b`: accurate near 0, where `acos` of an `f32` dot
/// product is off by up to 3e-4 rad. Evaluated without libm (a lookup takes one per
/// candidate): octant reduction to `t = min/max` in `[0, 1]`, then
/// `atan t = π/6 + atan((√3 t − 1)/(t + √3))` above `2 − √3`, and the Taylor series to
/// `t⁹/9` on `|t| <= 2 − √3`, whose truncation error is below `t¹¹/11 < 5e-8` rad.
#[inline]
pub fn normal_angle(sin: f32, cos: f32) -> f32 {
    use std::f32::consts::{FRAC_PI_2, FRAC_PI_6, PI};
    const TAN_PI_12: f32 = 0.267_949_2;
    const SQRT_3: f32 = 1.732_050_8;
    let (y, ax) = (sin.abs(), cos.abs());
    let steep = y > ax;
    let (num, den) = if steep { (ax, y) } else { (y, ax) };
    if den == 0.0 {
        return 0.0;
    }
    let t = num / den;
    let (offset, u) = if t > TAN_PI_12 {
        (FRAC_PI_6, (SQRT_3 * t - 1.0) / (t + SQRT_3))
    } else {
        (0.0, t)
    };
    let u2 = u * u;
    let series = u * (1.0 + u2 * (-1.0 / 3.0 + u2 * (0.2 + u2 * (-1.0 / 7.0 + u2 / 9.0))));
    let a = offset + series;
    let a = if steep { FRAC_PI_2 - a } else { a };
    if cos < 0.0 {
        PI - a
    } else {
        a
    }
}

/// Eq. 9: `w(d, θ) = (1 − θ/π)(1 − x/(1 + λx))` with `x = d / d_max` in `[0, 1]`.
#[inline]
pub fn raw_weight(x: f32, theta: f32, lambda: f32) -> f32 {
    (1.0 - theta * std::f32::consts::FRAC_1_PI) * (1.0 - x / (1.0 + lambda * x))
}
