//! One irradiance record (Survey §3.2.1–3.2.2): `E` by `M x N` cosine-distributed strata
//! (eq. 3.2–3.4), the validity radius `R_i` and the rotational and translational gradients
//! (eq. 3.5–3.6), per RGB channel.

use glam::Vec3;

use crate::estimators::direct::{DirectCounters, Lighting};
use crate::geometry::TraversalCounters;

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
    /// clamped to the bounds the record was made with (finite, `> 0`).
    pub radius: f32,
    /// Rotational gradient `∇_r E` per channel (eq. 3.5), in the tangent plane, W/m² per
    /// radian.
    pub rotation: [Vec3; 3],
    /// Translational gradient `∇_t E` per channel (eq. 3.6), in the tangent plane, W/m³.
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

/// Traces the record at the surface point `position` (unit `normal`, the side to sample):
/// `M·N` hemisphere rays from `lighting.scene.offset_point(position, normal)`, each hit's
/// direct light towards the record by [`crate::estimators::direct::Method::Mis`] averaged
/// over `secondary_spp` samples; escaping rays give 0. `R_i` is clamped to
/// `radius_bounds = (r_lo, r_hi)` (world units, `0 < r_lo <= r_hi`, finite). Random
/// numbers come from `(seed, key, stratum, dimension)`. Adds its rays to `counters` and
/// `bvh`.
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
    let _ = (lighting, params, seed, key, counters, bvh);
    todo!("stratified hemisphere record at {position} {normal} {radius_bounds:?}")
}
