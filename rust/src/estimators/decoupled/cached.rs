//! `⟨V⟩` of an area light from the records of a cache that sees emitters
//! ([`VisibilitySource::Cache`], module docs of [`super`]): `E_p[Ṽ]` over
//! [`CACHED_AREA_DRAWS`] draws of the light's density, no ray traced.

use super::*;

/// `⟨V⟩` of an area light at a pixel from records that see emitters.
pub(super) struct CachedVisibility {
    /// `E_p[Ṽ]` over the draws.
    pub(super) v: f64,
    /// The records' spread about it: `sqrt(Σ β_i (E_p[V_i] − v)² / Σ β_i)`.
    pub(super) spread: f64,
    /// Draws with `LB > 0` it averages.
    pub(super) draws: u32,
}

/// `E_p[Ṽ]` for area light `k` at pixel `pixel` by [`CACHED_AREA_DRAWS`] draws of its
/// density (by area, as its `LB`-samples) that read each record's bit at the draw's
/// direction, no ray traced. Draws that cannot light the point (behind the light, below
/// the surface's horizon, on a black texel of the emitter) are left out, as `V`-samples
/// leave out draws with `LB = 0`; the BSDF is not evaluated (a Lambertian or Phong lobe
/// is not zero above the horizon). Each record's average over the same draws gives the
/// spread. The draws' own error is that of `V`-samples, `sqrt(⟨V⟩(1 − ⟨V⟩) / draws)`,
/// which the bound adds from the count. None when no draw can light the point.
pub(super) fn cached_area_visibility(
    at: &PixelLights,
    k: usize,
    state: &CacheState,
    interp: &Interpolant,
    seed: u64,
    pixel: usize,
) -> Option<CachedVisibility> {
    let light = &at.scene.area_lights()[k];
    let records = interp.ids().len();
    let mut seen_by = [0u32; crate::visibility::cache::interpolant::MAX_KEPT];
    let mut draws = 0u32;
    // A 3-D Hammersley set (triangle choice, point on it) turned by the pixel's own random
    // offset (Cranley-Patterson): stratified, at a fraction of a sampler's cost per draw.
    let shift = PixelSampler::new(seed, pixel as u64, STREAM_V_CACHE + k as u64).get_set(0);
    let turned = |x: f64, i: usize| (x as f32 + shift[i]).fract();
    for s in 0..CACHED_AREA_DRAWS {
        let choice = turned((s as f64 + 0.5) / CACHED_AREA_DRAWS as f64, 0);
        let point = Vec2::new(
            turned(radical_inverse(s, 2), 1),
            turned(radical_inverse(s, 3), 2),
        );
        let Some(d) = light.sample(at.sp.origin, choice, point) else {
            continue;
        };
        let reaches = at.scene.segment_end(d.distance, d.point) > 0.0;
        if !(reaches && at.sp.normal.dot(d.direction) > 0.0 && d.radiance != Vec3::ZERO) {
            continue;
        }
        let (_, mask) = interp.eval(state, sphere_to_square(d.direction).as_dvec2());
        for (r, n) in seen_by.iter_mut().enumerate().take(records) {
            *n += (mask >> r) & 1;
        }
        draws += 1;
    }
    if draws == 0 {
        return None;
    }
    let betas = interp.betas();
    let total: f64 = betas
        .iter()
        .map(|&b| b as f64)
        .sum::<f64>()
        .max(f64::MIN_POSITIVE);
    let averages = seen_by[..records].iter().map(|&n| n as f64 / draws as f64);
    let v = betas
        .iter()
        .zip(averages.clone())
        .map(|(&b, a)| b as f64 * a)
        .sum::<f64>()
        / total;
    let spread = betas
        .iter()
        .zip(averages)
        .map(|(&b, a)| b as f64 * (a - v).powi(2))
        .sum::<f64>()
        / total;
    Some(CachedVisibility {
        v: v.clamp(0.0, 1.0),
        spread: spread.sqrt(),
        draws,
    })
}

/// The radical inverse of `i` in `base`: its digits mirrored about the point, in `[0, 1)`.
pub(super) fn radical_inverse(mut i: u32, base: u32) -> f64 {
    let (mut out, mut scale) = (0.0, 1.0 / base as f64);
    while i > 0 {
        out += (i % base) as f64 * scale;
        i /= base;
        scale /= base as f64;
    }
    out
}
