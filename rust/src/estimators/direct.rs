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
//!
//! ## The product inside a one-sample mixture ([`Techniques`])
//! A product distribution is built for one point and costs microseconds; the renderer
//! builds it once per pixel (at the hit through the pixel's centre) and draws every
//! jittered sample of the pixel from it ([`Lighting::estimate_mixture`]). A sample whose
//! hit differs from that point may need light where the centre's `B~` is zero, so the
//! product is one technique of a one-sample mixture with BSDF sampling at the sample's own
//! point and the map's own distribution: a technique is picked with probability `c_t`, and
//! the estimate is `f L V cos / Σ_t c_t p_t(ω)` — the balance heuristic of Veach's
//! one-sample model (Veach 1997, §9.2.4), unbiased wherever one technique with `c_t > 0`
//! has `p_t > 0`. BSDF sampling covers every direction where `f cos > 0`, so any weights
//! with `c_bsdf > 0` are unbiased for any hit; weights `(1, 0, 0)` are CAM08's plain
//! product sampling, unbiased only at the point the product was built for.

use glam::{DVec2, UVec2, Vec2, Vec3};

use crate::bsdf::Material;
use crate::geometry::{Scene, TraversalCounters};
use crate::lights::area::{AreaLight, LightSample};
use crate::lights::envmap::product::{GuidedProduct, ProductDistribution, ProductSample};
use crate::lights::envmap::EnvMap;
use crate::sampling::octahedral::{sphere_to_square, texel_of, texel_of_square};
#[cfg(test)]
use crate::sampling::rng::SampleRng;
use crate::sampling::rng::Sampler;

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

/// Random-number dimensions of one pixel sample, laid out in sets of four (the renderer's
/// quasi-random samples stratify each set jointly, [`crate::sampling::sobol`]).
pub mod dims {
    /// Set 0 holds the pixel jitter (dimensions 0-1) and the environment's 2D sample
    /// (product, map, or the mixture's technique and direction).
    pub const ENV: u64 = 2;
    /// Set 1: the BSDF's lobe choice ...
    pub const BSDF_LOBE: u64 = 4;
    /// ... and the BSDF sample's direction (methods "bsdf" and "mis").
    pub const BSDF: u64 = 6;
    /// Area light `k` takes set `2 + k`: its triangle choice at `AREA + 4k` and the point
    /// on it at `AREA + 4k + 2` (two dimensions; [`super::sample_area_light`]).
    pub const AREA: u64 = 8;
}

/// A point of area light `k` (the scene's `k`-th) seen from `origin`, drawn by area with
/// the sample's dimensions of that light ([`dims::AREA`]), its set made once.
pub fn sample_area_light(
    light: &AreaLight,
    k: usize,
    origin: Vec3,
    rng: &impl Sampler,
) -> Option<LightSample> {
    let [choice, _, u, v] = rng.get_set(dims::AREA + 4 * k as u64);
    light.sample(origin, choice, Vec2::new(u, v))
}

/// Least share [`Techniques::learnt`] leaves a technique that had one.
pub const LEARN_FLOOR: f64 = 0.05;

/// Fixed-point steps of [`Techniques::learnt`].
pub const LEARN_STEPS: usize = 8;

/// Weights of the techniques of the one-sample mixture that samples the environment in the
/// product methods (module docs): the pixel's product distribution, the product guided by
/// the cache's records ([`GuidedProduct`], method "cv" only), BSDF sampling at the sample's
/// own hit, and the map's own distribution. Any non-negative weights with a positive sum;
/// they are normalised; the guided share falls to the plain product where no records guide
/// it, and a technique that cannot draw otherwise (no product at the point, an all-black
/// map) gives its share to the others in proportion.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Techniques {
    /// Weight of product sampling (CAM08 §5.5).
    pub product: f32,
    /// Weight of product sampling guided by the records' visibility.
    pub guided: f32,
    /// Weight of BSDF sampling at the sample's own hit.
    pub bsdf: f32,
    /// Weight of the map's own distribution.
    pub env: f32,
}

impl Techniques {
    /// Plain product sampling (CAM08): unbiased only at the point the product was built
    /// for, so only for renders without jitter.
    pub const PRODUCT_ONLY: Self = Self::new(1.0, 0.0, 0.0, 0.0);
    /// The default of method "product": mostly the product, a tenth each of BSDF and map
    /// sampling for the parts of the integrand the pixel's product misses.
    pub const PRODUCT: Self = Self::new(0.8, 0.0, 0.1, 0.1);
    /// The default of method "cv": half the samples guided by the records, the rest by
    /// the plain product (where the records are wrong), the BSDF and the map.
    pub const CONTROL_VARIATE: Self = Self::new(0.3, 0.5, 0.1, 0.1);

    /// Weights `(product, guided, bsdf, env)`.
    pub const fn new(product: f32, guided: f32, bsdf: f32, env: f32) -> Self {
        Self {
            product,
            guided,
            bsdf,
            env,
        }
    }

    /// The method's default weights.
    pub const fn default_for(method: Method) -> Self {
        match method {
            Method::ControlVariate => Self::CONTROL_VARIATE,
            _ => Self::PRODUCT,
        }
    }

    /// The weights as an array `[product, guided, bsdf, env]`.
    pub const fn to_array(&self) -> [f32; 4] {
        [self.product, self.guided, self.bsdf, self.env]
    }

    /// Fails unless every weight is finite and non-negative with a positive sum, and
    /// (for samples away from the product's point, `jitter`) BSDF sampling has a share
    /// whenever a product technique has one.
    pub fn validate(&self, jitter: bool) -> crate::error::Result<()> {
        let w = self.to_array();
        if w.iter().any(|x| !(x.is_finite() && *x >= 0.0)) || w.iter().sum::<f32>() <= 0.0 {
            return Err(crate::error::Error::invalid(
                "technique_weights",
                format!(
                    "must be finite non-negative weights (product, guided, bsdf, env) with \
                     a positive sum, got {w:?}"
                ),
            ));
        }
        if jitter && self.product + self.guided > 0.0 && self.bsdf == 0.0 {
            return Err(crate::error::Error::invalid(
                "technique_weights",
                "with jitter a sample's hit differs from the point the pixel's product was \
                 built for, so BSDF sampling needs a positive weight to keep the estimate \
                 unbiased; render with jitter=False for plain product sampling",
            ));
        }
        Ok(())
    }

    /// The weights with `share` (in `[0, 1]`) of the product techniques' weight kept on
    /// the plain product and the rest moved to BSDF sampling: for a product that covers
    /// only part of the BSDF (a glossy material's diffuse part).
    pub fn with_product_share(&self, share: f32) -> Self {
        let product = self.product + self.guided;
        Self::new(
            product * share,
            0.0,
            self.bsdf + product * (1.0 - share),
            self.env,
        )
    }

    /// The weights for a sample that the product was not built for (another surface): the
    /// product techniques' shares split evenly between BSDF and map sampling.
    pub fn without_product(&self) -> Self {
        let half = 0.5 * (self.product + self.guided);
        Self::new(0.0, 0.0, self.bsdf + half, self.env + half)
    }

    /// The weights of least estimated error over an image, learnt from `draws` of this
    /// mixture at points with a product and without guidance: per draw a weight (its
    /// pixel's, `1 / (mean² + 10⁻²)` for relMSE), its value `f = f cos L V` in luminance,
    /// the techniques' own densities there `p_t` and the density `p₀` it was drawn with.
    /// The one-sample estimator's second moment under weights `c`, `M(c) = ∫ f² / q_c`
    /// with `q_c = Σ c_t p_t`, has the derivatives `−A_t = −∫ f² p_t / q_c²`, estimated as
    /// `Σ w f² p_t / (q_c² p₀)`; at the best weights every technique used has the same
    /// `A_t`. [`LEARN_STEPS`] fixed-point steps `c_t ← c_t A_t / Σ_s c_s A_s` go there,
    /// every technique that had a share keeping [`LEARN_FLOOR`] at least (BSDF sampling's
    /// share keeps a jittered sample unbiased). Unchanged when no draw saw light. Weights
    /// learnt from earlier samples leave later samples unbiased: each is unbiased for any
    /// fixed positive weights.
    pub fn learnt(&self, draws: &[(f64, f64, [f64; 4], f64)]) -> Self {
        let start = self.probabilities(true, false, true);
        let mut c = start;
        for _ in 0..LEARN_STEPS {
            let mut a = [0.0f64; 4];
            for &(w, f, p, p0) in draws {
                let q: f64 = c.iter().zip(&p).map(|(c, p)| c * p).sum();
                if f > 0.0 && q > 0.0 && p0 > 0.0 {
                    let k = w * f * f / (q * q * p0);
                    for t in 0..4 {
                        a[t] += k * p[t];
                    }
                }
            }
            let total: f64 = c.iter().zip(&a).map(|(c, a)| c * a).sum();
            if !(total > 0.0 && total.is_finite()) {
                return *self;
            }
            let next: [f64; 4] = std::array::from_fn(|t| c[t] * a[t] / total);
            c = with_floor(next, start.map(|s| s > 0.0), LEARN_FLOOR);
        }
        let c = c.map(|x| x as f32);
        Self::new(c[0], c[1], c[2], c[3])
    }

    /// Normalised probabilities `[product, guided, bsdf, env]` of the techniques that can
    /// draw (all zero when none can). Without guidance (no records) the guided share goes
    /// to the plain product, so "cv" without records samples as "product" does.
    #[inline]
    pub fn probabilities(&self, has_product: bool, has_guided: bool, has_env: bool) -> [f64; 4] {
        let (product, guided) = match (has_product, has_guided) {
            (false, _) => (0.0, 0.0),
            (true, false) => (self.product as f64 + self.guided as f64, 0.0),
            (true, true) => (self.product as f64, self.guided as f64),
        };
        let w = [
            product,
            guided,
            self.bsdf as f64,
            if has_env { self.env as f64 } else { 0.0 },
        ];
        let total: f64 = w.iter().sum();
        if total > 0.0 {
            w.map(|x| x / total)
        } else {
            [0.0; 4]
        }
    }
}

impl Default for Techniques {
    fn default() -> Self {
        Self::PRODUCT
    }
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
    /// Bounce rays of indirect paths (closest-hit queries,
    /// [`super::indirect::estimate_indirect`]).
    pub bounce_rays: u64,
}

/// The one-sample mixture of [`Techniques`] at one shading point (module docs): a sampler
/// and its density, the balance heuristic's `Σ_t c_t p_t(ω)`.
pub struct Mixture<'a> {
    env: &'a EnvMap,
    sp: &'a ShadingPoint,
    product: Option<&'a ProductDistribution>,
    guided: Option<&'a GuidedProduct>,
    /// Probabilities `[product, guided, bsdf, env]`.
    c: [f64; 4],
}

/// One draw of a [`Mixture`].
#[derive(Clone, Copy, Debug)]
pub struct MixtureDraw {
    /// Unit direction.
    pub direction: Vec3,
    /// Its point of the equal-area square (for product draws, the point it was mapped
    /// from), and the map's texel that every density is read at.
    pub square: DVec2,
    pub texel: UVec2,
    /// The mixture's solid-angle density there (`> 0`).
    pub pdf: f64,
    /// The plain product's density there (0 without a product).
    pub product_pdf: f64,
    /// Each technique's own density there, `[product, guided, bsdf, env]` (0 for the
    /// guided product, BSDF and map without a share).
    pub technique_pdfs: [f64; 4],
}

impl<'a> Mixture<'a> {
    /// The mixture of `techniques` at `sp` under `env` around `product` (and its `guided`
    /// form), with the shares of techniques that cannot draw given to the others.
    pub fn new(
        env: &'a EnvMap,
        sp: &'a ShadingPoint,
        product: Option<&'a ProductDistribution>,
        guided: Option<&'a GuidedProduct>,
        techniques: &Techniques,
    ) -> Self {
        let c = if env.is_black() {
            [0.0; 4]
        } else {
            techniques.probabilities(product.is_some(), guided.is_some(), true)
        };
        Self {
            env,
            sp,
            product,
            guided,
            c,
        }
    }

    /// Draws a direction from `u ∈ [0,1)²` (and `lobe ∈ [0,1)`, the BSDF's lobe choice):
    /// the technique takes the first coordinate's interval and the coordinate is rescaled
    /// inside it, so each technique's draws keep the samples' stratification. `None` when
    /// nothing can draw or the BSDF technique drew no direction (a sample of value zero).
    pub fn sample(&self, u: [f32; 2], lobe: f32) -> Option<MixtureDraw> {
        if self.c == [0.0; 4] {
            return None;
        }
        let (technique, ux) = pick_technique(u[0] as f64, &self.c);
        let u = DVec2::new(ux, u[1] as f64);
        let res = self.env.resolution();
        let (direction, square, texel) = match technique {
            0 | 1 => {
                let p = self.product?;
                let s = match self.guided {
                    Some(g) if technique == 1 => g.sample_point(p, self.env, u),
                    _ => p.sample_point(self.env, u),
                };
                (s.direction, s.square, s.texel)
            }
            _ => {
                let dir = if technique == 2 {
                    self.sp
                        .material
                        .sample(self.sp.normal, self.sp.wo, lobe, u.as_vec2())?
                } else {
                    self.env.sample(u)?.0
                };
                let square = sphere_to_square(dir);
                (dir, square.as_dvec2(), texel_of_square(square, res))
            }
        };
        let (pdf, technique_pdfs) = self.densities(direction, texel);
        (pdf > 0.0).then_some(MixtureDraw {
            direction,
            square,
            texel,
            pdf,
            product_pdf: technique_pdfs[0],
            technique_pdfs,
        })
    }

    /// The mixture's solid-angle density of drawing `dir` (sr⁻¹).
    pub fn pdf(&self, dir: Vec3) -> f64 {
        self.densities(dir, texel_of(dir, self.env.resolution())).0
    }

    /// The mixture's density at `dir` and the techniques' own
    /// ([`MixtureDraw::technique_pdfs`]), the map's densities read at `texel`.
    fn densities(&self, dir: Vec3, texel: UVec2) -> (f64, [f64; 4]) {
        let c = &self.c;
        let (product, guided) = match self.product {
            Some(p) => {
                let pp = p.texel_pdf(self.env, texel);
                let pg = self
                    .guided
                    .map_or(0.0, |g| pp * g.ratio(p.cell_of(self.env, texel)));
                (pp, pg)
            }
            None => (0.0, 0.0),
        };
        let bsdf = if c[2] > 0.0 {
            self.sp.material.pdf(self.sp.normal, self.sp.wo, dir)
        } else {
            0.0
        };
        let env = if c[3] > 0.0 {
            self.env.texel_pdf(texel)
        } else {
            0.0
        };
        let mixture = c[0] * product + c[1] * guided + c[2] * bsdf + c[3] * env;
        (
            if mixture.is_nan() { 0.0 } else { mixture },
            [product, guided, bsdf, env],
        )
    }
}

/// What [`Lighting::estimate_mixture`] drew for the environment, for the control variate.
#[derive(Clone, Copy, Debug)]
pub struct MixtureSample {
    /// The point of the equal-area square of the drawn direction (for a product draw,
    /// the point it was mapped from).
    pub square: DVec2,
    /// `p_product(ω) / p_mixture(ω)`: the control variate's `g / p_mixture` is its
    /// `g / p_product` times this.
    pub product_ratio: f64,
    /// Whether the shadow ray found the map (`None`: no ray was needed, `f cos L = 0`).
    pub visible: Option<bool>,
    /// What [`Techniques::learnt`] learns from: the draw's `f cos L V` (RGB), the
    /// techniques' own densities there and the mixture's.
    pub value: Vec3,
    pub technique_pdfs: [f64; 4],
    pub pdf: f64,
}

/// Probabilities `p` (summing to one) with every entry of `active` at `floor` at least:
/// those below are raised to it and the rest scaled down to keep the sum.
fn with_floor(mut p: [f64; 4], active: [bool; 4], floor: f64) -> [f64; 4] {
    let mut fixed = [false; 4];
    // Raising one may push another below: at most one round per entry.
    for _ in 0..4 {
        for t in 0..4 {
            fixed[t] |= active[t] && p[t] < floor;
        }
        let kept: f64 = (0..4).filter(|&t| fixed[t]).map(|_| floor).sum();
        let free: f64 = (0..4).filter(|&t| !fixed[t]).map(|t| p[t]).sum();
        if free <= 0.0 {
            break;
        }
        let scale = (1.0 - kept) / free;
        for t in 0..4 {
            p[t] = if fixed[t] { floor } else { p[t] * scale };
        }
        if (0..4).all(|t| !active[t] || p[t] >= floor) {
            break;
        }
    }
    p
}

/// `[0,1)²` as doubles.
#[inline]
fn unit_pair(u: [f32; 2]) -> DVec2 {
    DVec2::new(u[0] as f64, u[1] as f64)
}

/// The technique whose interval of `[0, 1)` (lengths `c`, in order) holds `u`, and `u`
/// rescaled to `[0, 1)` inside it. A `u` past the last interval by rounding takes the last
/// technique with a share.
#[inline]
fn pick_technique(u: f64, c: &[f64; 4]) -> (usize, f64) {
    const BELOW_ONE: f64 = 1.0 - f64::EPSILON;
    let mut start = 0.0;
    let mut last = 0;
    for (t, &ct) in c.iter().enumerate() {
        if ct <= 0.0 {
            continue;
        }
        if u < start + ct {
            return (t, ((u - start) / ct).clamp(0.0, BELOW_ONE));
        }
        start += ct;
        last = t;
    }
    (last, BELOW_ONE)
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
    /// 64² for Phong lobes narrower than half a 32² cell (exponents above about 650).
    PerMaterial,
    /// [`Self::PerMaterial`] with Lambert surfaces one level coarser (16² cells). The
    /// renderer takes it for jittered product sampling (and control variates without
    /// records) of views whose samples mostly leave their anchor's surface
    /// (`render::COARSE_EDGE_SHARE`), where products are built again for most samples'
    /// normals and a product four times cheaper to build pays.
    CoarseDiffuse,
}

impl ProductLevel {
    /// The level for a point of `material`.
    #[inline]
    pub fn for_material(self, material: &Material) -> u32 {
        match self {
            ProductLevel::Fixed(level) => level,
            ProductLevel::PerMaterial => material.product_level_hint(),
            ProductLevel::CoarseDiffuse => match material {
                Material::Lambert { .. } => material.product_level_hint() - 1,
                Material::Phong { .. } => material.product_level_hint(),
            },
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
        rng: &impl Sampler,
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
            let u = unit_pair(rng.get2(dims::ENV));
            if let Some((dir, pdf)) = self.env.sample(u) {
                let radiance = self.env.eval(dir);
                total += self.light_term(sp, dir, radiance, pdf, f32::INFINITY, mis, counters, bvh);
            }
            total += self.area_terms(sp, rng, mis, counters, bvh);
        }

        // BSDF sampling: what the sampled ray finds is the radiance.
        if use_bsdf {
            let u = Vec2::from_array(rng.get2(dims::BSDF));
            if let Some(wi) = sp
                .material
                .sample(sp.normal, sp.wo, rng.get(dims::BSDF_LOBE), u)
            {
                total += self.bsdf_term(sp, wi, mis, counters, bvh);
            }
        }
        total
    }

    /// [`Method::Env`]'s estimate (one sample of the map's distribution, one point on each
    /// area light, the same random numbers) with each shadow ray's visibility given by
    /// `visibility(direction, tmax)` instead of traced: any real, unclamped (BLD's
    /// stochastic visibility gives `0`, `1/p` or `−1/p`). Called only for rays
    /// [`Method::Env`] would trace, in its order; with a 0/1 answer equal to the scene's the
    /// result is [`Method::Env`]'s bit for bit. Counts the rays in `counters`.
    pub fn estimate_lights_with(
        &self,
        sp: &ShadingPoint,
        rng: &impl Sampler,
        counters: &mut DirectCounters,
        mut visibility: impl FnMut(Vec3, f32) -> f64,
    ) -> Vec3 {
        let mut total = Vec3::ZERO;
        let mut term = |dir: Vec3, radiance: Vec3, pdf: f64, tmax: f32| {
            let cos = sp.normal.dot(dir);
            if cos <= 0.0 || pdf <= 0.0 || radiance == Vec3::ZERO || tmax <= 0.0 {
                return Vec3::ZERO;
            }
            let f = sp.material.eval(sp.normal, sp.wo, dir);
            if f == Vec3::ZERO {
                return Vec3::ZERO;
            }
            counters.shadow_rays += 1;
            let v = visibility(dir, tmax);
            if v == 0.0 {
                return Vec3::ZERO;
            }
            f * radiance * cos * (v / pdf) as f32
        };
        let u = unit_pair(rng.get2(dims::ENV));
        if let Some((dir, pdf)) = self.env.sample(u) {
            let radiance = self.env.eval(dir);
            total += term(dir, radiance, pdf, f32::INFINITY);
        }
        for (k, light) in self.scene.area_lights().iter().enumerate() {
            if let Some(s) = sample_area_light(light, k, sp.origin, rng) {
                let tmax = self.scene.segment_end(s.distance, s.point);
                total += term(s.direction, s.radiance, s.pdf, tmax);
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
        rng: &impl Sampler,
        counters: &mut DirectCounters,
        bvh: &mut TraversalCounters,
    ) -> (Vec3, Option<(ProductSample, Option<bool>)>) {
        let mut total = self.area_terms(sp, rng, false, counters, bvh);
        let Some(product) = product else {
            return (total, None);
        };
        let s = product.sample_point(self.env, unit_pair(rng.get2(dims::ENV)));
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

    /// The environment by the one-sample mixture of `techniques` (module docs) around a
    /// `product` built for this point or for another point of the same pixel (and its
    /// `guided` form), and each area light by one light sample. Returns the estimate and
    /// what was drawn for the map (`None` when nothing could be drawn: a black map and no
    /// BSDF share, or the BSDF technique drew no direction — a sample of value zero either
    /// way).
    #[allow(clippy::too_many_arguments)]
    pub fn estimate_mixture(
        &self,
        sp: &ShadingPoint,
        product: Option<&ProductDistribution>,
        guided: Option<&GuidedProduct>,
        techniques: &Techniques,
        rng: &impl Sampler,
        counters: &mut DirectCounters,
        bvh: &mut TraversalCounters,
    ) -> (Vec3, Option<MixtureSample>) {
        let mut total = self.area_terms(sp, rng, false, counters, bvh);
        let mixture = Mixture::new(self.env, sp, product, guided, techniques);
        let Some(d) = mixture.sample(rng.get2(dims::ENV), rng.get(dims::BSDF_LOBE)) else {
            return (total, None);
        };
        let mut drawn = MixtureSample {
            square: d.square,
            product_ratio: d.product_pdf / d.pdf,
            visible: None,
            value: Vec3::ZERO,
            technique_pdfs: d.technique_pdfs,
            pdf: d.pdf,
        };
        let cos = sp.normal.dot(d.direction);
        if cos <= 0.0 {
            return (total, Some(drawn));
        }
        let f = sp.material.eval(sp.normal, sp.wo, d.direction);
        let l = self.env.texel(d.texel);
        if f == Vec3::ZERO || l == Vec3::ZERO {
            return (total, Some(drawn));
        }
        counters.shadow_rays += 1;
        let visible = !self
            .scene
            .occluded1(sp.origin, d.direction, f32::INFINITY, bvh);
        if visible {
            drawn.value = f * l * cos;
            total += drawn.value * (1.0 / d.pdf) as f32;
        }
        drawn.visible = Some(visible);
        (total, Some(drawn))
    }

    /// One light sample of every area light (with the MIS weight against BSDF sampling
    /// when `mis`).
    fn area_terms(
        &self,
        sp: &ShadingPoint,
        rng: &impl Sampler,
        mis: bool,
        counters: &mut DirectCounters,
        bvh: &mut TraversalCounters,
    ) -> Vec3 {
        let mut total = Vec3::ZERO;
        for (k, light) in self.scene.area_lights().iter().enumerate() {
            if let Some(s) = sample_area_light(light, k, sp.origin, rng) {
                let tmax = self.scene.segment_end(s.distance, s.point);
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

pub mod anchored;
pub mod light_split;
pub mod mixture_choice;

#[cfg(test)]
mod tests;
