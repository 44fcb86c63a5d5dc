//! Indirect illumination by path tracing: the unbiased reference that virtual point
//! lights, VF and the survey's irradiance and importance caches are measured against
//! (survey ch. 3 and 6, `004_d2289ee9e28a0f98.txt`).
//!
//! From a shading point `x_0` a path samples the BSDF
//! ([`Material::sample`](crate::bsdf::Material::sample)) and traces a closest-hit ray to
//! `x_1`, then `x_2`, ... up to `bounces` vertices. Its estimate of the
//! light reflected at `x_0` after one or more bounces is
//!
//! `L_ind(x_0) ≈ Σ_{j=1..k} T_j · L_dir(x_j)`, with `T_j = Π_{i<j} f(x_i) cos θ_i / p(ω_i)`,
//!
//! where `L_dir(x_j)` is the direct light leaving `x_j` towards `x_{j-1}`, estimated by the
//! same estimators as the primary vertex's (light and BSDF sampling with the power
//! heuristic by default, [`Lighting::estimate`]). Emission that a bounce ray finds (an area
//! light, the map through a gap) is not added: it is the previous vertex's *direct* light,
//! which that vertex's own estimate already counts (next-event estimation, as pbrt-v4's
//! `PathIntegrator` with its own MIS weights folded into the direct estimate). Each term is
//! unbiased for its bounce, so the sum is unbiased for the light of `k` bounces.
//!
//! Russian roulette from the second bounce on: the path survives with
//! `q = clamp(max_c T_c, MIN_SURVIVAL, 1)` and its throughput is divided by `q`, so the
//! expectation is unchanged while dim paths stop early. The first bounce, the one VF and
//! irradiance caching approximate, is never cut.
//!
//! ## Random numbers
//! Bounce `j` (1-based) reads the sampler shifted by `j · BOUNCE_STRIDE` dimensions: its
//! lobe choice, roulette and direction in one set of four, its vertex's direct estimate in
//! the sets after it (the direct estimators' own layout, [`super::direct::dims`]). The
//! primary vertex's dimensions are those below `BOUNCE_STRIDE`, so a render with bounces
//! shades its direct light with exactly the numbers it would use without them.

use glam::{Vec2, Vec3};

use crate::estimators::direct::{DirectCounters, Lighting, Method, ShadingPoint};
use crate::geometry::{Scene, SurfaceHit, TraversalCounters};
use crate::sampling::rng::Sampler;

/// Most bounces a path may take.
pub const MAX_BOUNCES: u32 = 64;

/// Survival probability below which Russian roulette does not go (so no path's weight
/// grows beyond `1 / MIN_SURVIVAL` in one step).
pub const MIN_SURVIVAL: f32 = 0.05;

/// The first bounce (1-based) that may be cut by Russian roulette.
pub const ROULETTE_FROM: u32 = 2;

/// Dimensions between bounces: far above any direct estimate's (which take
/// `8 + 4 · area lights`), a multiple of four so sets stay sets.
pub const BOUNCE_STRIDE: u64 = 1 << 32;

/// Offsets within a bounce's first set of four dimensions.
mod lanes {
    /// The BSDF's lobe choice.
    pub const LOBE: u64 = 0;
    /// Russian roulette.
    pub const ROULETTE: u64 = 1;
    /// The direction (two dimensions).
    pub const DIRECTION: u64 = 2;
    /// Where the vertex's direct estimate starts reading.
    pub const DIRECT: u64 = 4;
}

/// How paths are traced.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PathParams {
    /// Bounces after the primary vertex, `1..=MAX_BOUNCES`.
    pub bounces: u32,
    /// The direct-light estimator at every vertex after the first.
    pub vertex_method: Method,
}

impl PathParams {
    /// `bounces` bounces with light and BSDF sampling (MIS) at every vertex.
    pub const fn new(bounces: u32) -> Self {
        Self {
            bounces,
            vertex_method: Method::Mis,
        }
    }
}

/// A sampler read from dimension `offset` on (a multiple of four, so pairs stay in sets).
struct Shifted<'a, S> {
    inner: &'a S,
    offset: u64,
}

impl<S: Sampler> Sampler for Shifted<'_, S> {
    #[inline]
    fn get(&self, d: u64) -> f32 {
        self.inner.get(d + self.offset)
    }

    #[inline]
    fn get2(&self, d: u64) -> [f32; 2] {
        self.inner.get2(d + self.offset)
    }
}

/// The shading point of `hit` seen from direction `wo` (unit, towards the viewer): the
/// normal turned to `wo`'s side and the shadow-ray origin offset along it.
pub fn shading_point_at(scene: &Scene, hit: &SurfaceHit, wo: Vec3) -> ShadingPoint {
    let normal = if hit.normal.dot(wo) < 0.0 {
        -hit.normal
    } else {
        hit.normal
    };
    ShadingPoint {
        origin: scene.offset_hit(hit, normal),
        normal,
        wo,
        material: scene.mesh().objects[hit.obj as usize].material,
    }
}

/// One estimate of the light reflected at `sp` after `1..=params.bounces` bounces (module
/// docs), in W/(m² sr) per RGB channel; adds its bounce rays to `counters.bounce_rays` and
/// the vertices' shadow and BSDF rays to the other counters.
pub fn estimate_indirect(
    lighting: &Lighting,
    sp: &ShadingPoint,
    params: &PathParams,
    rng: &impl Sampler,
    counters: &mut DirectCounters,
    bvh: &mut TraversalCounters,
) -> Vec3 {
    let mut total = Vec3::ZERO;
    let mut throughput = Vec3::ONE;
    let mut vertex = *sp;
    for bounce in 1..=params.bounces {
        let base = bounce as u64 * BOUNCE_STRIDE;
        if bounce >= ROULETTE_FROM {
            let q = throughput.max_element().clamp(MIN_SURVIVAL, 1.0);
            if rng.get(base + lanes::ROULETTE) >= q {
                break;
            }
            throughput /= q;
        }
        let Some((wi, weight)) = sample_bounce(&vertex, rng, base) else {
            break;
        };
        throughput *= weight;
        if throughput == Vec3::ZERO {
            break;
        }
        counters.bounce_rays += 1;
        let Some(hit) = lighting
            .scene
            .intersect1(vertex.origin, wi, f32::INFINITY, bvh)
        else {
            break;
        };
        vertex = shading_point_at(lighting.scene, &hit, -wi);
        let shifted = Shifted {
            inner: rng,
            offset: base + lanes::DIRECT,
        };
        let direct = lighting.estimate(&vertex, params.vertex_method, &shifted, counters, bvh);
        total += throughput * direct;
    }
    total
}

/// A BSDF-sampled direction at `sp` and its weight `f cos θ / p`; `None` where the BSDF
/// returns no direction (below the surface).
fn sample_bounce(sp: &ShadingPoint, rng: &impl Sampler, base: u64) -> Option<(Vec3, Vec3)> {
    let material = &sp.material;
    let u = Vec2::from_array(rng.get2(base + lanes::DIRECTION));
    let wi = material.sample(sp.normal, sp.wo, rng.get(base + lanes::LOBE), u)?;
    let pdf = material.pdf(sp.normal, sp.wo, wi);
    let cos = sp.normal.dot(wi);
    if !(pdf > 0.0 && cos > 0.0) {
        return None;
    }
    let f = material.eval(sp.normal, sp.wo, wi);
    Some((wi, f * (cos as f64 / pdf) as f32))
}

#[cfg(test)]
mod tests;
