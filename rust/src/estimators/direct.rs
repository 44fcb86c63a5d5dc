//! Direct illumination at one shading point from an environment map and area lights, by
//! four unbiased estimators that every later estimator is checked against:
//!
//! - [`Method::Env`]: light sampling. One sample of the environment map's own distribution
//!   plus one area-sampled point per area light.
//! - [`Method::Bsdf`]: one BSDF sample; its closest hit finds an emitter or escapes to the
//!   environment.
//! - [`Method::Mis`]: both, combined by the power heuristic (Veach 1997, §9.2), pairwise for
//!   every light (each light's integral has its own two strategies).
//! - [`Method::Product`]: the environment by product importance sampling (CAM08 §5.5 and
//!   Clarberg & Akenine-Möller, "Practical Product Importance Sampling", 2008), the area
//!   lights by light sampling. A coarse product `L_c · B~_c` over the cells of one
//!   octahedral level picks a cell; the environment map's own quadtree picks a texel inside
//!   it, so `p(ω) = L(ω) · B~(ω) / L_ns` with `L_ns = Σ_c L_c · B~_c` (CAM08 eq. 3), where
//!   `L` is the map's sampling weight (luminance). `B~` is conservative
//!   ([`Material::product_cells`]), so `p > 0` wherever the integrand is.
//!
//! All four return the estimate of `∫ f(ωo, ω) L(ω) V(ω) cos θ dω` for one sample index;
//! averaging over samples is the renderer's job.

use glam::{DVec2, UVec2, Vec2, Vec3};

use crate::bsdf::Material;
use crate::geometry::{Scene, TraversalCounters};
use crate::lights::envmap::EnvMap;
use crate::sampling::distribution::QuadPyramid;
use crate::sampling::octahedral::{morton_encode, square_to_sphere, texel_of, texel_solid_angle};
use crate::sampling::rng::SampleRng;

/// Which estimator of direct illumination to use.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Method {
    /// Light sampling: the environment's distribution and area sampling of each light.
    Env,
    /// BSDF sampling only.
    Bsdf,
    /// Light and BSDF sampling with the power heuristic.
    Mis,
    /// Product importance sampling of environment × BSDF (CAM08 §5.5); area lights by
    /// light sampling.
    Product,
    /// [`Method::Product`] with the visibility cache's `L B~ Ṽ` as a control variate
    /// (CAM08 eq. 2–3; [`super::control_variate`]). Needs a cache; without records at a
    /// point it is [`Method::Product`] there.
    ControlVariate,
}

impl Method {
    /// Every method, in a fixed order.
    pub const ALL: [Method; 5] = [
        Method::Env,
        Method::Bsdf,
        Method::Mis,
        Method::Product,
        Method::ControlVariate,
    ];

    /// The name Python uses.
    pub const fn name(self) -> &'static str {
        match self {
            Method::Env => "env",
            Method::Bsdf => "bsdf",
            Method::Mis => "mis",
            Method::Product => "product",
            Method::ControlVariate => "cv",
        }
    }

    /// The method of a name, if any.
    pub fn from_name(name: &str) -> Option<Method> {
        Method::ALL.into_iter().find(|m| m.name() == name)
    }
}

/// Random-number dimensions of one pixel sample, after the two of the pixel jitter.
pub mod dims {
    /// First dimension of the direct-lighting estimators.
    pub const FIRST: u64 = 2;
    /// BSDF lobe choice and direction (3 dimensions).
    pub const BSDF: u64 = FIRST;
    /// Environment or product sample (2 dimensions).
    pub const ENV: u64 = FIRST + 3;
    /// Area light `k` uses 3 dimensions from `AREA + 3k`.
    pub const AREA: u64 = FIRST + 5;
}

/// A surface point being shaded.
#[derive(Clone, Copy, Debug)]
pub struct ShadingPoint {
    /// Shadow-ray origin: the hit point offset along `normal`.
    pub origin: Vec3,
    /// Unit shading normal, on the side of `wo`.
    pub normal: Vec3,
    /// Unit direction towards the viewer.
    pub wo: Vec3,
    /// The surface's material.
    pub material: Material,
}

/// Work done by the estimators, for the renderer's statistics.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DirectCounters {
    /// Shadow rays traced (any-hit queries).
    pub shadow_rays: u64,
    /// BSDF rays traced (closest-hit queries).
    pub bsdf_rays: u64,
}

/// The product distribution of one shading point (CAM08 §5.5).
///
/// Invariants: `cells` holds `L_c · B~_c` over the `4^level` cells in Morton order, with a
/// positive total `L_ns`; `level` does not exceed the environment's quadtree depth.
#[derive(Clone, Debug)]
pub struct ProductDistribution {
    level: u32,
    bsdf_cells: Vec<f32>,
    cells: QuadPyramid,
}

impl ProductDistribution {
    /// Builds the product of `env`'s cell sums at `level` (capped at the map's depth) and
    /// `B~` of `material` at `(normal, wo)`. `None` when the product is zero everywhere
    /// (black map, or a surface that reflects nothing towards `wo`).
    pub fn new(
        env: &EnvMap,
        material: &Material,
        normal: Vec3,
        wo: Vec3,
        level: u32,
    ) -> Option<Self> {
        let dist = env.distribution()?;
        let level = level.min(dist.depth());
        let mut bsdf_cells = vec![0.0f32; 1 << (2 * level)];
        material.product_cells(normal, wo, level, &mut bsdf_cells);
        let product: Vec<f64> = dist
            .level(level)
            .iter()
            .zip(&bsdf_cells)
            .map(|(&l, &b)| l * b as f64)
            .collect();
        let cells = QuadPyramid::from_morton_unchecked(product);
        (cells.total() > 0.0).then_some(Self {
            level,
            bsdf_cells,
            cells,
        })
    }

    /// `L_ns = Σ_c L_c · B~_c` (CAM08 eq. 3), in the units of the map's sampling weights.
    pub fn normalization(&self) -> f64 {
        self.cells.total()
    }

    /// Samples a direction from `u ∈ [0,1)^2`: a cell of the product, then a texel of the
    /// map inside it. Returns the direction, its texel and its solid-angle pdf.
    pub fn sample(&self, env: &EnvMap, u: DVec2) -> (Vec3, UVec2, f64) {
        let s = self.sample_point(env, u);
        (s.direction, s.texel, s.pdf)
    }

    /// [`Self::sample`] with everything the control variate needs: the point of the
    /// equal-area square the direction comes from and `B~` of its cell.
    pub fn sample_point(&self, env: &EnvMap, u: DVec2) -> ProductSample {
        let dist = env
            .distribution()
            .expect("a product exists only for a lit map");
        let (cell, rest) = self
            .cells
            .sample(u)
            .expect("the product has a positive total");
        let cell_code = morton_encode(cell.x, cell.y);
        let (texel, within) = dist.descend(self.level, cell_code, rest);
        let res = env.resolution();
        let square = (texel.as_dvec2() + within) / res as f64;
        let bsdf = self.bsdf_cells[cell_code as usize] as f64;
        let pdf = bsdf * dist.weight(texel) / self.normalization() / texel_solid_angle(res);
        ProductSample {
            direction: square_to_sphere(square.as_vec2()),
            texel,
            square,
            bsdf,
            pdf,
        }
    }

    /// Octahedral level of the cells (`4^level` of them).
    pub fn level(&self) -> u32 {
        self.level
    }

    /// `B~` of every cell, Morton order.
    pub fn bsdf_cells(&self) -> &[f32] {
        &self.bsdf_cells
    }

    /// The product `L_c B~_c` as a quadtree of sums (levels `0..=level`, Morton order), in
    /// the map's sampling weights (luminance per texel, summed).
    pub fn pyramid(&self) -> &QuadPyramid {
        &self.cells
    }

    /// Solid-angle pdf of sampling a direction in `texel` of the map.
    pub fn texel_pdf(&self, env: &EnvMap, texel: UVec2) -> f64 {
        let dist = env
            .distribution()
            .expect("a product exists only for a lit map");
        let shift = dist.depth() - self.level;
        let cell = morton_encode(texel.x >> shift, texel.y >> shift) as usize;
        let b = self.bsdf_cells[cell] as f64;
        b * dist.weight(texel) / self.normalization() / texel_solid_angle(env.resolution())
    }

    /// Solid-angle pdf of [`Self::sample`] producing `dir`.
    pub fn pdf(&self, env: &EnvMap, dir: Vec3) -> f64 {
        self.texel_pdf(env, texel_of(dir, env.resolution()))
    }
}

/// One draw of [`ProductDistribution::sample_point`].
#[derive(Clone, Copy, Debug)]
pub struct ProductSample {
    /// Unit direction.
    pub direction: Vec3,
    /// The map's texel that contains it.
    pub texel: UVec2,
    /// Its point of the equal-area square, `[0,1)²` (what the direction was mapped from).
    pub square: DVec2,
    /// `B~` of the product cell that contains it.
    pub bsdf: f64,
    /// Solid-angle pdf, sr⁻¹ (`> 0`).
    pub pdf: f64,
}

/// Power heuristic with exponent 2 for a sample of density `a` against `b`.
#[inline]
fn power_heuristic(a: f64, b: f64) -> f64 {
    if a.is_infinite() {
        return 1.0;
    }
    let (a2, b2) = (a * a, b * b);
    if a2 + b2 > 0.0 {
        a2 / (a2 + b2)
    } else {
        0.0
    }
}

/// Octahedral level of the product's cells (`4^level` cells).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ProductLevel {
    /// The same level, `1..=8`, at every shading point.
    Fixed(u32),
    /// Each material's [`Material::product_level_hint`]: 32² cells for diffuse surfaces,
    /// 64² for narrow glossy lobes.
    PerMaterial,
}

impl ProductLevel {
    /// The level for a point of `material`.
    #[inline]
    pub fn for_material(self, material: &Material) -> u32 {
        match self {
            ProductLevel::Fixed(level) => level,
            ProductLevel::PerMaterial => material.product_level_hint(),
        }
    }

    /// Fails unless a fixed level lies in `1..=8`.
    pub fn validate(self) -> crate::error::Result<()> {
        match self {
            ProductLevel::Fixed(level) if !(1..=8).contains(&level) => {
                Err(crate::error::Error::invalid(
                    "product_level",
                    format!("must lie in [1, 8] or be \"auto\", got {level}"),
                ))
            }
            _ => Ok(()),
        }
    }
}

/// Everything the estimators read: the scene (geometry and area lights) and the map.
#[derive(Clone, Copy)]
pub struct Lighting<'a> {
    pub scene: &'a Scene,
    pub env: &'a EnvMap,
    /// Octahedral level of the product's cells.
    pub product_level: ProductLevel,
}

impl Lighting<'_> {
    /// One estimate of direct illumination at `sp` by `method` with the random numbers of
    /// `rng`; adds the rays it traced to `counters` and the BVH counters to `bvh`.
    /// [`Method::Product`] and [`Method::ControlVariate`] build the point's product
    /// distribution here; to reuse one over many samples call [`Self::estimate_product`].
    pub fn estimate(
        &self,
        sp: &ShadingPoint,
        method: Method,
        rng: &SampleRng,
        counters: &mut DirectCounters,
        bvh: &mut TraversalCounters,
    ) -> Vec3 {
        if matches!(method, Method::Product | Method::ControlVariate) {
            let product = self.product(sp);
            return self
                .estimate_product(sp, product.as_ref(), rng, counters, bvh)
                .0;
        }
        let mut total = Vec3::ZERO;
        let use_lights = method != Method::Bsdf;
        let use_bsdf = matches!(method, Method::Bsdf | Method::Mis);
        let mis = method == Method::Mis;

        // Environment by its own distribution.
        if use_lights {
            let u = DVec2::new(rng.get(dims::ENV) as f64, rng.get(dims::ENV + 1) as f64);
            if let Some((dir, pdf)) = self.env.sample(u) {
                let radiance = self.env.eval(dir);
                total += self.light_term(sp, dir, radiance, pdf, f32::INFINITY, mis, counters, bvh);
            }
            total += self.area_terms(sp, rng, mis, counters, bvh);
        }

        // BSDF sampling: what the sampled ray finds is the radiance.
        if use_bsdf {
            let u = Vec2::new(rng.get(dims::BSDF + 1), rng.get(dims::BSDF + 2));
            if let Some(wi) = sp.material.sample(sp.normal, sp.wo, rng.get(dims::BSDF), u) {
                total += self.bsdf_term(sp, wi, mis, counters, bvh);
            }
        }
        total
    }

    /// The product distribution of `sp` (`None` where the map or the surface sends no
    /// light towards `wo`).
    pub fn product(&self, sp: &ShadingPoint) -> Option<ProductDistribution> {
        ProductDistribution::new(
            self.env,
            &sp.material,
            sp.normal,
            sp.wo,
            self.product_level.for_material(&sp.material),
        )
    }

    /// [`Method::Product`] with a prebuilt `product` of `sp` (CAM08 builds it once per
    /// shading point and draws every sample from it): the environment by one product
    /// sample, each area light by one light sample. Also returns the environment sample and
    /// what its shadow ray found (`None` when no ray was needed: `f cos = 0`), which the
    /// control variate reads.
    pub fn estimate_product(
        &self,
        sp: &ShadingPoint,
        product: Option<&ProductDistribution>,
        rng: &SampleRng,
        counters: &mut DirectCounters,
        bvh: &mut TraversalCounters,
    ) -> (Vec3, Option<(ProductSample, Option<bool>)>) {
        let mut total = self.area_terms(sp, rng, false, counters, bvh);
        let Some(product) = product else {
            return (total, None);
        };
        let u = DVec2::new(rng.get(dims::ENV) as f64, rng.get(dims::ENV + 1) as f64);
        let s = product.sample_point(self.env, u);
        let cos = sp.normal.dot(s.direction);
        if cos <= 0.0 {
            return (total, Some((s, None)));
        }
        let f = sp.material.eval(sp.normal, sp.wo, s.direction);
        if f == Vec3::ZERO {
            return (total, Some((s, None)));
        }
        counters.shadow_rays += 1;
        let visible = !self
            .scene
            .occluded1(sp.origin, s.direction, f32::INFINITY, bvh);
        if visible {
            let res = self.env.resolution();
            let l = Vec3::from_array(self.env.texels()[(s.texel.y * res + s.texel.x) as usize]);
            total += f * l * cos * (1.0 / s.pdf) as f32;
        }
        (total, Some((s, Some(visible))))
    }

    /// One light sample of every area light (with the MIS weight against BSDF sampling
    /// when `mis`).
    fn area_terms(
        &self,
        sp: &ShadingPoint,
        rng: &SampleRng,
        mis: bool,
        counters: &mut DirectCounters,
        bvh: &mut TraversalCounters,
    ) -> Vec3 {
        let mut total = Vec3::ZERO;
        for (k, light) in self.scene.area_lights().iter().enumerate() {
            let d = dims::AREA + 3 * k as u64;
            let u = Vec2::new(rng.get(d + 1), rng.get(d + 2));
            if let Some(s) = light.sample(sp.origin, rng.get(d), u) {
                let tmax = s.distance - 2.0 * self.scene.ray_epsilon(s.point);
                total +=
                    self.light_term(sp, s.direction, s.radiance, s.pdf, tmax, mis, counters, bvh);
            }
        }
        total
    }

    /// `f cos L V / pdf` (times the MIS weight) for a light sample towards `dir`.
    #[allow(clippy::too_many_arguments)]
    fn light_term(
        &self,
        sp: &ShadingPoint,
        dir: Vec3,
        radiance: Vec3,
        pdf: f64,
        tmax: f32,
        mis: bool,
        counters: &mut DirectCounters,
        bvh: &mut TraversalCounters,
    ) -> Vec3 {
        let cos = sp.normal.dot(dir);
        if cos <= 0.0 || pdf <= 0.0 || radiance == Vec3::ZERO || tmax <= 0.0 {
            return Vec3::ZERO;
        }
        let f = sp.material.eval(sp.normal, sp.wo, dir);
        if f == Vec3::ZERO {
            return Vec3::ZERO;
        }
        counters.shadow_rays += 1;
        if self.scene.occluded1(sp.origin, dir, tmax, bvh) {
            return Vec3::ZERO;
        }
        let weight = if mis {
            power_heuristic(pdf, sp.material.pdf(sp.normal, sp.wo, dir))
        } else {
            1.0
        };
        f * radiance * cos * (weight / pdf) as f32
    }

    /// `f cos L / pdf` (times the MIS weight) for a BSDF sample towards `wi`.
    fn bsdf_term(
        &self,
        sp: &ShadingPoint,
        wi: Vec3,
        mis: bool,
        counters: &mut DirectCounters,
        bvh: &mut TraversalCounters,
    ) -> Vec3 {
        let cos = sp.normal.dot(wi);
        let pdf = sp.material.pdf(sp.normal, sp.wo, wi);
        if cos <= 0.0 || pdf <= 0.0 {
            return Vec3::ZERO;
        }
        let f = sp.material.eval(sp.normal, sp.wo, wi);
        counters.bsdf_rays += 1;
        let (radiance, light_pdf) = match self.scene.intersect1(sp.origin, wi, f32::INFINITY, bvh) {
            None => (self.env.eval(wi), self.env.pdf(wi)),
            Some(hit) => {
                let le = self.scene.emitted(&hit, -wi);
                if le == Vec3::ZERO {
                    return Vec3::ZERO;
                }
                let light = self.scene.emitter(hit.obj).expect("only emitters emit");
                (le, light.pdf_at(sp.origin, hit.position, hit.normal))
            }
        };
        let weight = if mis {
            power_heuristic(pdf, light_pdf)
        } else {
            1.0
        };
        f * radiance * cos * (weight / pdf) as f32
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lights::procedural::sky;
    use crate::sampling::chi2::{chi2_sphere, Chi2Params};
    use crate::sampling::octahedral::texel_solid_angle;

    fn test_sky(resolution: u32) -> EnvMap {
        let sun = Vec3::new(0.4, 0.6, -0.5).normalize();
        sky(
            sun,
            [2e3; 3],
            4.0,
            [0.2, 0.3, 0.6],
            [0.8, 0.8, 0.9],
            resolution,
        )
        .unwrap()
    }

    fn frames() -> [(Vec3, Vec3); 3] {
        [
            (Vec3::Y, Vec3::new(0.3, 0.8, 0.2).normalize()),
            (
                Vec3::new(0.2, 0.9, -0.3).normalize(),
                Vec3::new(-0.5, 0.4, 0.6).normalize(),
            ),
            // Grazing view on a tilted surface.
            (
                Vec3::new(0.6, 0.8, 0.0),
                Vec3::new(-0.79, 0.6, 0.1).normalize(),
            ),
        ]
    }

    fn uniform(i: u64) -> DVec2 {
        let r = SampleRng::new(17, i, 0);
        DVec2::new(r.get(0) as f64, r.get(1) as f64)
    }

    #[test]
    fn product_samples_follow_the_product_pdf() {
        let env = test_sky(64);
        let materials = [
            Material::lambert([0.8; 3]).unwrap(),
            Material::phong([0.2; 3], [0.7; 3], 30.0).unwrap(),
        ];
        for m in materials {
            for (n, wo) in frames() {
                let product = ProductDistribution::new(&env, &m, n, wo, 5).unwrap();
                let samples = (0..300_000).map(|i| {
                    let (dir, texel, pdf) = product.sample(&env, uniform(i));
                    assert_eq!(pdf, product.texel_pdf(&env, texel));
                    assert!(pdf > 0.0);
                    Some(dir)
                });
                // Bins are the map's texels, so the piecewise-constant pdf integrates exactly.
                let params = Chi2Params::with_resolution(64).with_subdivisions(1);
                let outcome = chi2_sphere(samples, |d| product.pdf(&env, d), &params);
                assert!(outcome.passed, "{m:?} {n} {wo}: {outcome:?}");
                assert!(
                    (outcome.integral - 1.0).abs() < 1e-9,
                    "{}",
                    outcome.integral
                );
            }
        }
    }

    #[test]
    fn product_pdf_is_positive_wherever_the_integrand_is() {
        // Conservative B~ times a map that is positive everywhere: every direction where
        // f cos L > 0 has p > 0, including the grazing horizon and a 1e4 lobe.
        let env = test_sky(128);
        let m = Material::phong([0.0; 3], [1.0; 3], 1e4).unwrap();
        for (n, wo) in frames() {
            let product = ProductDistribution::new(&env, &m, n, wo, 5).unwrap();
            let res = 512;
            for y in 0..res {
                for x in 0..res {
                    let d = square_to_sphere((Vec2::new(x as f32, y as f32) + 0.5) / res as f32);
                    let integrand = m.eval(n, wo, d).x * n.dot(d).max(0.0);
                    if integrand > 0.0 {
                        assert!(product.pdf(&env, d) > 0.0, "{n} {wo} {d}");
                    }
                }
            }
        }
    }

    #[test]
    fn black_maps_and_black_materials_have_no_product() {
        let black = EnvMap::constant([0.0; 3], 32).unwrap();
        let m = Material::lambert([0.5; 3]).unwrap();
        assert!(ProductDistribution::new(&black, &m, Vec3::Y, Vec3::Y, 5).is_none());
        let env = test_sky(32);
        let dark = Material::lambert([0.0; 3]).unwrap();
        assert!(ProductDistribution::new(&env, &dark, Vec3::Y, Vec3::Y, 5).is_none());
        // Level capped by the map's depth: a 4x4 map has 16 cells at most.
        let tiny = test_sky(4);
        let p = ProductDistribution::new(&tiny, &m, Vec3::Y, Vec3::Y, 5).unwrap();
        let total: f64 = (0..16)
            .map(|i| p.texel_pdf(&tiny, UVec2::new(i % 4, i / 4)) * texel_solid_angle(4))
            .sum();
        assert!((total - 1.0).abs() < 1e-9);
    }

    #[test]
    fn power_heuristic_handles_zero_and_infinite_densities() {
        assert_eq!(power_heuristic(0.0, 0.0), 0.0);
        assert_eq!(power_heuristic(f64::INFINITY, 1.0), 1.0);
        assert_eq!(power_heuristic(1.0, 1.0), 0.5);
        assert_eq!(power_heuristic(1.0, 0.0), 1.0);
    }
}
