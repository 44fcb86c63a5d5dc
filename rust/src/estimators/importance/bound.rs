//! Row B's geometry term (survey §6.3, Fig. 6.5): a bound `G_max` of a light's geometry
//! term over a record's region of influence — every point within `radius` of the record
//! whose normal lies within `cone` of the record's — so that `L f_s G_max` bounds what
//! the light can give anywhere the record serves, and a light U and F miss at the record
//! itself (it lies just behind it, or grazes it) keeps a chance there.
//!
//! For a point light at `v` with unit normal `m` (light leaves on `m`'s side) and a
//! receiver at `x` with unit normal `n_x`, `G = max(0, n_x · ω) max(0, −m · ω) / |v − x|²`
//! with `ω = (v − x)/|v − x|` (Fig. 6.5b); for a directional light towards unit `ω`,
//! `G = max(0, n_x · ω)` (Fig. 6.5a). Seen from the ball of radius `r` about the record's
//! position `p`, the directions `ω` lie within `β = asin(r / |v − p|)` of the axis
//! `a = (v − p)/|v − p|` and the distance is at least `|v − p| − r`; each cosine is then
//! at most the cosine of the least angle its vectors can make, and the product of the
//! maxima bounds the maximum of the product. A light within the ball is unbounded
//! (`+∞`): the caller caps it.

use glam::{DVec3, Vec3};

/// A record's region of influence: the ball of `radius` (world units, `>= 0`) about
/// `position`, normals within `cone` (radians, `[0, π]`) of the unit `normal`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Region {
    pub position: Vec3,
    pub normal: Vec3,
    pub radius: f32,
    pub cone: f32,
}

/// Slack (radians) taken off the least angles, so that rounding never puts the bound below
/// a value it bounds.
const SLACK: f64 = 1e-6;

/// The angle between unit vectors `a` and `b`, radians in `[0, π]`.
fn angle(a: DVec3, b: DVec3) -> f64 {
    a.dot(b).clamp(-1.0, 1.0).acos()
}

/// `cos(max(0, θ))`, or 0 from `π/2` on: the largest cosine of an angle of at least `θ`,
/// clamped at a facing-away zero.
fn cos_at_least(theta: f64) -> f64 {
    let t = (theta - SLACK).max(0.0);
    if t >= std::f64::consts::FRAC_PI_2 {
        0.0
    } else {
        t.cos()
    }
}

/// `G_max` of a point light at `v` with unit normal `m` over `region` (1/m²; `+∞` when
/// `v` lies within the region's ball).
pub fn point_bound(region: &Region, v: Vec3, m: Vec3) -> f64 {
    let p = region.position.as_dvec3();
    let to = v.as_dvec3() - p;
    let dist = to.length();
    let r = region.radius as f64;
    if dist <= r || dist == 0.0 {
        return f64::INFINITY;
    }
    let axis = to / dist;
    let beta = (r / dist).min(1.0).asin();
    let cos_light = cos_at_least(angle(-m.as_dvec3(), axis) - beta);
    let cos_receiver =
        cos_at_least(angle(region.normal.as_dvec3(), axis) - beta - region.cone as f64);
    let near = dist - r;
    cos_light * cos_receiver / (near * near)
}

/// `G_max` of a directional light towards unit `w` over `region` (its cosine alone).
pub fn directional_bound(region: &Region, w: Vec3) -> f64 {
    cos_at_least(angle(region.normal.as_dvec3(), w.as_dvec3()) - region.cone as f64)
}

/// `G` of a point light at `v` (unit normal `m`) at `x` with unit normal `n` (1/m²).
pub fn point_g(x: Vec3, n: Vec3, v: Vec3, m: Vec3) -> f64 {
    let d = v.as_dvec3() - x.as_dvec3();
    let d2 = d.length_squared();
    if d2 == 0.0 {
        return f64::INFINITY;
    }
    let w = d / d2.sqrt();
    n.as_dvec3().dot(w).max(0.0) * (-m.as_dvec3().dot(w)).max(0.0) / d2
}

#[cfg(test)]
mod tests;
