//! One irradiance record (Survey §3.2.1–3.2.2, `004_d2289ee9e28a0f98.txt`; Ward & Heckbert
//! 1992, "Irradiance gradients"): `E` by `M x N` cosine-distributed strata (eq. 3.2–3.4),
//! the validity radius `R_i` and the rotational and translational gradients (eq. 3.5–3.6),
//! per RGB channel.
//!
//! Tracing ([`trace_strata`]) and the formulas ([`record_from_strata`]) are apart, so the
//! formulas are checked on synthetic radiance fields with known answers and the tracer on
//! scenes. Strata are numbered `j · N + k`: `j` in `θ` (from the normal down), `k` in `φ`.
//!
//! ## The gradients, as derived here
//! A cell's radiance `L_{j,k}` is taken as constant over the cell (the estimate is all
//! that is known of it), and each cell is weighted by its exact integral instead of the
//! survey's midpoint values:
//!
//! - Rotation (eq. 3.5). Turning the normal by `ε` about a tangent axis `a` changes
//!   `E = ∫ L (n·ω) dω` by `ε a · ∫ L (n × ω) dω` (the hemisphere's moving rim adds only
//!   `O(ε²)`), and `(n_i × n) = ε a` in eq. 3.8's `(n_i × n)·∇_r E`, so
//!   `∇_r E = ∫ L (n × ω) dω = ∫ L sin θ v(φ) dω` with `v(φ) = n × u(φ)` the tangent at
//!   `φ + π/2`. Per cell this is `L_{j,k} · ∫_{θ_{j−}}^{θ_{j+}} sin²θ dθ · 2 sin(π/N) v_k`:
//!   eq. 3.5's `π/(MN) · tan θ_j` is the midpoint rule of the `θ` integral, and its
//!   `−tan θ_j` goes with the opposite order of the cross product in eq. 3.8. The exact
//!   integral stays finite in the stratum at the horizon, where `tan θ` of a sample is
//!   unbounded (and the per-sample estimate has infinite variance).
//! - Translation (eq. 3.6). Moving the point by `δ` in the tangent plane leaves the cells
//!   where they are and moves what they see: a surface at distance `r` slides by
//!   `−δ_⊥ / r` over the sphere of directions. Inside a cell nothing changes (its `L` is
//!   constant); across the edge between two cells the nearer surface (the one that
//!   occludes) carries its radiance into the other cell. The edge at `θ_{j−}` between
//!   `(j−1, k)` and `(j, k)` moves in `θ` by `−cos θ_{j−} (δ·u(φ)) / r`; times the projected
//!   solid angle per unit of `θ`, `cos θ sin θ`, and integrated over the cell's `φ`
//!   (`∫ u dφ = 2 sin(π/N) u_k`, which eq. 3.6 writes `2π/N · u_k`):
//!   `u_k 2 sin(π/N) cos²θ_{j−} sin θ_{j−} / r_edge · (L_{j,k} − L_{j−1,k})`.
//!   The edge at `φ_{k−}` between `(j, k−1)` and `(j, k)` moves in `φ` by
//!   `−(δ·v_{k−}) / ρ`, with `ρ = r sin θ` the surface's distance from the normal's axis;
//!   integrated over the cell's `θ`, `∫ cos θ sin θ dθ = cos θ_j (cos θ_{j−} − cos θ_{j+})`
//!   with `cos θ_j` the mean of its edges' cosines (so the product is `1/(2M)`, exact where
//!   `ρ` is constant along the edge, as on a wall), giving eq. 3.6's second term
//!   `v_{k−} cos θ_j (cos θ_{j−} − cos θ_{j+}) / ρ_edge · (L_{j,k} − L_{j,k−1})`.
//!
//!   The distance is the edge's, not the samples': eq. 3.6's `min(r_{j,k}, r_{j−1,k})`
//!   takes the samples' own, which overstates the gradient wherever a surface is seen at a
//!   slant (a wall beside the point is much nearer at the lower sample than at the edge
//!   above it): +9% at 16 x 64 strata at the top edge of a wall, +31% in green beside
//!   cornell's red wall (the tests). Each hit's distance is carried to the edge's direction
//!   along its own tangent plane (geometric normal `m`: `r (m·ω)/(m·ω_edge)`, within
//!   `[r/2, 2r]`, and `2r` where the plane does not reach the edge: a silhouette, past
//!   which lies something farther), at the sample's own `φ` (`θ` edges) or `θ` (`φ` edges,
//!   then `ρ = r_edge sin θ`), and the nearer of the two is the edge's distance: exact for a
//!   planar occluder, and eq. 3.6's `min` in the limit of fine strata.
//!
//! ## The gradient limit (beyond the survey)
//! `R_i <= min_c E_c / |∇_t E_c|` over the channels with light, then at least `r_lo`: the
//! bound Ward & Heckbert (1992) draw from the translational gradient, as Křivánek and
//! Gautron's irradiance caching uses it. The harmonic mean knows distances, not light: at
//! the garage's sunlit opening it gave records a reach over which eq. 3.8's linear
//! extrapolation changed `E` by 1.2x its value, and gradients there raised the image's
//! relMSE by 72% (a = 0.2, 256x192). With the limit the same renders have 3.2x less
//! relMSE with or without gradients, for 48% more records (the experiment's figures).
//!
//! Hit distances that divide are taken at least `r_lo` (the lower radius bound), so
//! contact (distances below 1e-6, or 0) leaves the gradients finite. Escaped rays have
//! `r = ∞`: they add nothing to `1/R_i` and their edges move with the other side.

use std::f64::consts::{PI, TAU};

use glam::{DVec3, Vec3};

use crate::estimators::direct::{DirectCounters, Lighting, Method};
use crate::estimators::indirect::{shading_point_at, BOUNCE_STRIDE};
use crate::geometry::TraversalCounters;
use crate::sampling::rng::{SampleRng, Sampler};

/// An irradiance record: 112 bytes.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct IrradianceRecord {
    /// Where `E` was estimated (the surface point, not offset), world units.
    pub position: Vec3,
    /// Unit normal there, on the side the hemisphere was sampled.
    pub normal: Vec3,
    /// One-bounce irradiance `E` (eq. 3.4), W/m² per RGB channel, `>= 0`.
    pub irradiance: [f32; 3],
    /// Validity radius `R_i`, world units: the harmonic mean of the strata's hit distances,
    /// at most `E / |∇_t E|` (the gradient limit, module docs), clamped to the bounds the
    /// record was made with (finite, `> 0`).
    pub radius: f32,
    /// Rotational gradient `∇_r E` per channel (eq. 3.5), in the tangent plane, W/m² per
    /// radian, for eq. 3.8's `E_i + (n_i × n)·∇_r E` (module docs).
    pub rotation: [Vec3; 3],
    /// Translational gradient `∇_t E` per channel (eq. 3.6), in the tangent plane, W/m³,
    /// for eq. 3.8's `(p − p_i)·∇_t E`.
    pub translation: [Vec3; 3],
}

/// How records are traced.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RecordParams {
    /// Strata in `θ` (`M`) and in `φ` (`N`), each `>= 1`: `M·N` rays per record.
    pub strata: (u32, u32),
    /// Direct-light samples at each stratum's hit (`>= 1`).
    pub secondary_spp: u32,
}

/// Rays one record traced.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RecordRays {
    /// Hemisphere rays (closest hits), `M·N`.
    pub hemisphere: u64,
    /// Rays of the direct estimates at the hits (shadow and BSDF rays).
    pub secondary: u64,
    /// Hemisphere rays that escaped.
    pub escaped: u64,
}

/// The key of a record's random numbers: a hash of its position and normal, so a record
/// made for a point is the same whichever worker, wave or call makes it.
pub fn record_key(position: Vec3, normal: Vec3) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    // `+ 0.0` makes −0 and 0 one key.
    for v in (position + 0.0)
        .to_array()
        .into_iter()
        .chain((normal + 0.0).to_array())
    {
        h ^= v.to_bits() as u64;
        h = h.wrapping_mul(0x0100_0000_01b3);
        h ^= h >> 29;
    }
    h
}

/// Offsets within a stratum's random numbers.
mod lanes {
    /// The stratum's direction (`ξ¹, ξ²` of eq. 3.3): two dimensions.
    pub const DIRECTION: u64 = 0;
}

/// A sampler read from dimension `offset` on: secondary sample `s` of a stratum reads its
/// direct estimate from `(s + 1) · BOUNCE_STRIDE` (the layout of the path tracer's
/// bounces), far above the stratum's own direction.
struct Shifted<'a> {
    inner: &'a SampleRng,
    offset: u64,
}

impl Sampler for Shifted<'_> {
    #[inline]
    fn get(&self, d: u64) -> f32 {
        self.inner.get(d + self.offset)
    }

    #[inline]
    fn get2(&self, d: u64) -> [f32; 2] {
        self.inner.get2(d + self.offset)
    }
}

/// What one stratum's ray found.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StratumSample {
    /// `sin θ` of the ray (angle from the normal), `sqrt((j + ξ¹)/M)` in `[0, 1)`.
    pub sin_theta: f64,
    /// `φ` of the ray in the record's tangent frame, radians in `[0, 2π)`.
    pub phi: f64,
    /// Distance to the hit from the ray's origin, world units; `+∞` when the ray escaped.
    pub distance: f32,
    /// The hit surface's geometric unit normal (either side); zero when the ray escaped.
    pub surface_normal: Vec3,
    /// `L_{j,k}`: the direct light leaving the hit toward the record, W/(m² sr) per RGB
    /// channel (0 for an escaped ray).
    pub radiance: [f64; 3],
}

/// The record's tangent frame `(t1, t2, n)`: [`Vec3::any_orthonormal_pair`] of the normal.
pub fn tangent_frame(normal: Vec3) -> (DVec3, DVec3, DVec3) {
    let (t1, t2) = normal.any_orthonormal_pair();
    (t1.as_dvec3(), t2.as_dvec3(), normal.as_dvec3())
}

/// The direction of stratum `(j, k)` for random numbers `ξ = (ξ¹, ξ²)` (eq. 3.3):
/// `cos θ = sqrt(1 − (j + ξ¹)/M)`, `φ = 2π (k + ξ²)/N`; returns `(sin θ, φ)`.
pub fn stratum_angles(j: u32, k: u32, strata: (u32, u32), xi: [f32; 2]) -> (f64, f64) {
    let (m, n) = (strata.0 as f64, strata.1 as f64);
    let sin2 = (j as f64 + xi[0] as f64) / m;
    (sin2.sqrt(), TAU * (k as f64 + xi[1] as f64) / n)
}

/// The unit direction of `(sin θ, φ)` in the frame `(t1, t2, n)`.
pub fn frame_direction(frame: &(DVec3, DVec3, DVec3), sin_theta: f64, phi: f64) -> DVec3 {
    let cos_theta = (1.0 - sin_theta * sin_theta).max(0.0).sqrt();
    let (s, c) = phi.sin_cos();
    frame.0 * (sin_theta * c) + frame.1 * (sin_theta * s) + frame.2 * cos_theta
}

/// Traces the `M·N` strata of a record (eq. 3.3): one ray each from
/// `lighting.scene.offset_point(position, normal)`, and at its hit the direct light toward
/// the record by [`Method::Mis`] averaged over `params.secondary_spp` samples (emission at
/// the hit is not added: it is the record's direct light). Returns the samples in stratum
/// order (`j · N + k`) and the rays; adds the hemisphere rays to `counters.bounce_rays`,
/// the direct estimates' to its other counters, and all of them to `bvh`.
#[allow(clippy::too_many_arguments)]
pub fn trace_strata(
    lighting: &Lighting,
    position: Vec3,
    normal: Vec3,
    params: &RecordParams,
    seed: u64,
    key: u64,
    counters: &mut DirectCounters,
    bvh: &mut TraversalCounters,
) -> (Vec<StratumSample>, RecordRays) {
    let (m, n) = params.strata;
    let spp = params.secondary_spp.max(1);
    let scene = lighting.scene;
    let origin = scene.offset_point(position, normal);
    let frame = tangent_frame(normal);
    let before = counters.shadow_rays + counters.bsdf_rays;
    let mut rays = RecordRays::default();
    let mut samples = Vec::with_capacity(m as usize * n as usize);
    for j in 0..m {
        for k in 0..n {
            let rng = SampleRng::new(seed, key, j as u64 * n as u64 + k as u64);
            let (sin_theta, phi) = stratum_angles(j, k, params.strata, rng.get2(lanes::DIRECTION));
            let wi = frame_direction(&frame, sin_theta, phi).as_vec3();
            rays.hemisphere += 1;
            counters.bounce_rays += 1;
            let mut sample = StratumSample {
                sin_theta,
                phi,
                distance: f32::INFINITY,
                surface_normal: Vec3::ZERO,
                radiance: [0.0; 3],
            };
            match scene.intersect1(origin, wi, f32::INFINITY, bvh) {
                None => rays.escaped += 1,
                Some(hit) => {
                    let sp = shading_point_at(scene, &hit, -wi);
                    let mut sum = DVec3::ZERO;
                    for s in 0..spp {
                        let shifted = Shifted {
                            inner: &rng,
                            offset: (s as u64 + 1) * BOUNCE_STRIDE,
                        };
                        sum += lighting
                            .estimate(&sp, Method::Mis, &shifted, counters, bvh)
                            .as_dvec3();
                    }
                    sample.distance = hit.t;
                    sample.surface_normal = hit.normal;
                    sample.radiance = (sum / spp as f64).to_array();
                }
            }
            samples.push(sample);
        }
    }
    rays.secondary = counters.shadow_rays + counters.bsdf_rays - before;
    (samples, rays)
}

/// Traces the record at the surface point `position` (unit `normal`, the side to sample):
/// `M·N` hemisphere rays from `lighting.scene.offset_point(position, normal)`, each hit's
/// direct light towards the record by [`crate::estimators::direct::Method::Mis`] averaged
/// over `secondary_spp` samples; escaping rays give 0. `R_i` is clamped to
/// `radius_bounds = (r_lo, r_hi)` (world units, `0 < r_lo <= r_hi`, finite). Random
/// numbers come from `(seed, key, stratum, dimension)`. Adds its rays to `counters` and
/// `bvh`. [`trace_strata`] then [`record_from_strata`].
#[allow(clippy::too_many_arguments)]
pub fn trace_record(
    lighting: &Lighting,
    position: Vec3,
    normal: Vec3,
    params: &RecordParams,
    radius_bounds: (f32, f32),
    seed: u64,
    key: u64,
    counters: &mut DirectCounters,
    bvh: &mut TraversalCounters,
) -> (IrradianceRecord, RecordRays) {
    let (samples, rays) =
        trace_strata(lighting, position, normal, params, seed, key, counters, bvh);
    let record = record_from_strata(position, normal, params.strata, &samples, radius_bounds);
    (record, rays)
}

/// The record of `samples` (`M·N` of them, stratum `j · N + k` at index `j · N + k`, as
/// [`trace_strata`] returns them) at `position` / unit `normal`: `E` (eq. 3.4), `R_i` (the
/// harmonic mean of the hit distances, escapes adding nothing, clamped to
/// `radius_bounds = (r_lo, r_hi)`, `0 < r_lo <= r_hi`) and the gradients of eq. 3.5–3.6 as
/// derived in the module docs, with every hit distance that divides taken at least `r_lo`.
/// Sums in f64, stored in f32.
pub fn record_from_strata(
    position: Vec3,
    normal: Vec3,
    strata: (u32, u32),
    samples: &[StratumSample],
    radius_bounds: (f32, f32),
) -> IrradianceRecord {
    let (m, n) = (strata.0 as usize, strata.1 as usize);
    assert!(
        m >= 1 && n >= 1,
        "strata {strata:?}: at least one in θ and in φ"
    );
    assert_eq!(samples.len(), m * n, "one sample per stratum");
    let (r_lo, r_hi) = radius_bounds;
    let at = |j: usize, k: usize| &samples[j * n + k];
    let frame = tangent_frame(normal);
    let (mf, nf) = (m as f64, n as f64);

    // E = π/(MN) Σ L (eq. 3.4).
    let mut sum = [0.0f64; 3];
    let mut inverse_distances = 0.0f64;
    for s in samples {
        for (total, l) in sum.iter_mut().zip(s.radiance) {
            *total += l;
        }
        // 1/0 = ∞ makes R_i = 0, then r_lo: contact is the smallest radius, never NaN.
        if s.distance.is_finite() {
            inverse_distances += 1.0 / s.distance as f64;
        }
    }
    let irradiance = sum.map(|x| (PI / (mf * nf) * x) as f32);
    let radius = if inverse_distances > 0.0 {
        ((mf * nf / inverse_distances) as f32).clamp(r_lo, r_hi)
    } else {
        r_hi
    };

    // Edges of the θ strata: cos²θ_{j−} = 1 − j/M.
    let sin_edge = |j: usize| (j as f64 / mf).sqrt();
    let cos_edge = |j: usize| (1.0 - j as f64 / mf).max(0.0).sqrt();
    let theta_edge = |j: usize| sin_edge(j).asin();
    // ∫ over one φ stratum of u(φ) (or v(φ)): 2 sin(π/N) times its value at the centre.
    let arc = 2.0 * (PI / nf).sin();
    let u = |phi: f64| {
        let (s, c) = phi.sin_cos();
        frame.0 * c + frame.1 * s
    };
    let v = |phi: f64| frame.2.cross(u(phi));
    // A hit's distance carried to direction `(sin θ_b, φ_b)` along its surface's tangent
    // plane (module docs): `r (m·ω) / (m·ω_b)`, within `[r/2, 2r]`, and `2r` where the
    // plane does not reach that direction (a silhouette: what lies past it is farther).
    let at_edge = |s: &StratumSample, sin_b: f64, phi_b: f64| -> f64 {
        if !s.distance.is_finite() {
            return f64::INFINITY;
        }
        let m = s.surface_normal.as_dvec3();
        let a = m.dot(frame_direction(&frame, s.sin_theta, s.phi));
        let b = m.dot(frame_direction(&frame, sin_b, phi_b));
        let q = if a * b > 0.0 {
            (a / b).clamp(0.5, 2.0)
        } else {
            2.0
        };
        (s.distance as f64 * q).max(r_lo as f64)
    };

    let mut rotation = [DVec3::ZERO; 3];
    let mut translation = [DVec3::ZERO; 3];
    for j in 0..m {
        // ∫_{θ_{j−}}^{θ_{j+}} sin²θ dθ: the rotational kernel's θ integral (eq. 3.5).
        let g = |t: f64| 0.5 * t - 0.25 * (2.0 * t).sin();
        let sin2_integral = g(theta_edge(j + 1)) - g(theta_edge(j));
        // cos θ_j (cos θ_{j−} − cos θ_{j+}) with cos θ_j the edges' mean: 1/(2M).
        let phi_weight = 0.5 * (cos_edge(j).powi(2) - cos_edge(j + 1).powi(2));
        // Eq. 3.6's second term divides by sin θ, which goes to 0 at the pole in the top
        // stratum. It is floored at half the stratum's upper edge's sine, sin θ_{j+}/2:
        // for j >= 1 that is below the lower edge's, sin θ_{j−} (4j >= j + 1), so only the
        // top stratum's samples with ξ¹ < 1/4 are touched, and the term stays below
        // 1/(M sin θ_{0+} min r) = 1/(√M min r).
        let sin_floor = 0.5 * sin_edge(j + 1);
        for k in 0..n {
            let here = at(j, k);
            let phi_centre = TAU * (k as f64 + 0.5) / nf;
            let rot = v(phi_centre) * (arc * sin2_integral);
            for (g, l) in rotation.iter_mut().zip(here.radiance) {
                *g += rot * l;
            }
            // θ edge between (j−1, k) and (j, k).
            if j > 0 {
                let above = at(j - 1, k);
                let sb = sin_edge(j);
                let r = at_edge(here, sb, here.phi).min(at_edge(above, sb, above.phi));
                let w = cos_edge(j).powi(2) * sin_edge(j) / r;
                let dir = u(phi_centre) * (arc * w);
                for ((g, l), l_above) in translation
                    .iter_mut()
                    .zip(here.radiance)
                    .zip(above.radiance)
                {
                    *g += dir * (l - l_above);
                }
            }
            // φ edge between (j, k−1) and (j, k), at φ_{k−} = 2πk/N.
            let left = at(j, (k + n - 1) % n);
            let phi_b = TAU * k as f64 / nf;
            let rho =
                |s: &StratumSample| at_edge(s, s.sin_theta, phi_b) * s.sin_theta.max(sin_floor);
            let dir = v(phi_b) * (phi_weight / rho(here).min(rho(left)));
            for ((g, l), l_left) in translation.iter_mut().zip(here.radiance).zip(left.radiance) {
                *g += dir * (l - l_left);
            }
        }
    }
    // The gradient limit (module docs).
    let limit = translation
        .iter()
        .zip(irradiance)
        .filter(|(g, e)| *e > 0.0 && g.length() > 0.0)
        .map(|(g, e)| (e as f64 / g.length()) as f32)
        .fold(f32::INFINITY, f32::min);
    let radius = radius.min(limit).max(r_lo);
    IrradianceRecord {
        position,
        normal,
        irradiance,
        radius,
        rotation: rotation.map(|g| g.as_vec3()),
        translation: translation.map(|g| g.as_vec3()),
    }
}

#[cfg(test)]
mod tests;
