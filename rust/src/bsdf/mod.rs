//! Surface materials and their BSDFs: evaluation, importance sampling, the solid-angle pdf
//! of the sampler, and B~, the conservative per-cell approximation of the reflectance that
//! product importance sampling multiplies with the lighting (CAM08 §3 eq. 1-2: `B` is the
//! BRDF times the cosine, `p ∝ L B~`; §5.5 and §7: B~ lives on the same equal-area
//! octahedral quadtree as the lighting and the visibility records; Clarberg &
//! Akenine-Möller, "Practical Product Importance Sampling for Direct Illumination", 2008).
//!
//! Two materials: Lambert (`f = albedo / π`) and the energy-normalised Phong BRDF of
//! Lafortune & Willems, "Using the modified Phong reflectance model for physically based
//! rendering" (1994): `f = kd / π + ks (e + 2) / (2π) cos^e α`, `α` the angle between `wi`
//! and the mirror direction of `wo` about `n`. With `kd + ks ≤ 1` per channel its
//! directional albedo never exceeds 1 (the maximum is at normal incidence).
//!
//! Conventions: `n` is the unit shading normal, `wo` the unit direction towards the
//! viewer, `wi` the unit direction towards the light, all pointing away from the surface.
//! The BSDF is zero when `wi` or `wo` is at or below the surface (`dot(n, ·) ≤ 0`).
//!
//! B~, the per-cell bounds of product sampling ([`Material::product_cells`]), is built in
//! `cells.rs`.

use glam::{DVec3, Vec2, Vec3};

use crate::error::{Error, Result};
use crate::math::LUMINANCE_F32;
use crate::sampling::rng::SampleRng;

mod cells;
pub mod rows;
#[cfg(test)]
mod tests;

pub use cells::{CellCones, BOUND_FLOOR, MAX_CELL_LEVEL};

/// A surface material. Colours are linear RGB reflectances in [0, 1].
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Material {
    /// Ideal diffuse reflector: f = albedo / pi.
    Lambert { albedo: [f32; 3] },
    /// Energy-normalised Phong: f = kd / pi + ks (e + 2) / (2 pi) cos^e(alpha), where alpha is
    /// the angle between the mirror direction and the outgoing direction. `kd + ks <= 1` per
    /// channel keeps it energy conserving; `exponent` lies in [1, 1e4].
    Phong {
        kd: [f32; 3],
        ks: [f32; 3],
        exponent: f32,
    },
}

impl Default for Material {
    fn default() -> Self {
        Material::DEFAULT
    }
}

fn check_color(name: &str, c: [f32; 3]) -> Result<()> {
    if c.iter().any(|v| !v.is_finite() || *v < 0.0 || *v > 1.0) {
        return Err(Error::invalid(
            name,
            format!("each channel must be finite and in [0, 1], got {c:?}"),
        ));
    }
    Ok(())
}

impl Material {
    /// A light grey diffuse material, used where none is given.
    pub const DEFAULT: Material = Material::Lambert {
        albedo: [0.7, 0.7, 0.7],
    };

    /// Lambertian material with the given albedo (each channel in [0, 1]).
    pub fn lambert(albedo: [f32; 3]) -> Result<Self> {
        check_color("albedo", albedo)?;
        Ok(Material::Lambert { albedo })
    }

    /// Normalised Phong; `kd + ks` must not exceed 1 in any channel, `exponent` in [1, 1e4].
    pub fn phong(kd: [f32; 3], ks: [f32; 3], exponent: f32) -> Result<Self> {
        check_color("kd", kd)?;
        check_color("ks", ks)?;
        if (0..3).any(|i| kd[i] + ks[i] > 1.0 + 1e-6) {
            return Err(Error::invalid(
                "ks",
                format!("kd + ks must not exceed 1 in any channel (energy conservation), got kd={kd:?} ks={ks:?}"),
            ));
        }
        if !(1.0..=1e4).contains(&exponent) {
            return Err(Error::invalid(
                "exponent",
                format!("must lie in [1, 1e4], got {exponent}"),
            ));
        }
        Ok(Material::Phong { kd, ks, exponent })
    }

    /// The diffuse colour, used for simple first-hit shading.
    pub fn base_color(&self) -> [f32; 3] {
        match *self {
            Material::Lambert { albedo } => albedo,
            Material::Phong { kd, ks, .. } => [kd[0] + ks[0], kd[1] + ks[1], kd[2] + ks[2]],
        }
    }

    /// Whether [`Self::product_cells`] depends on the outgoing direction beyond its side of
    /// the surface: only a specular lobe does. When it does not, points with the same
    /// normal and material share their product distribution bit for bit.
    pub fn product_depends_on_wo(&self) -> bool {
        match *self {
            Material::Lambert { .. } => false,
            Material::Phong { ks, .. } => luminance(ks) > 0.0,
        }
    }

    /// The product cells' level this material needs (CAM08 §5.5 refines B~ where the
    /// lobe is narrow): level 5 (32², cells about 6.4° across) for Lambert and for Phong
    /// lobes at least half a cell wide (`e` up to about 650), else 6 (3.2°). The lobe
    /// width is `sqrt(2 / (e + 2))` radians, the standard deviation of the normalised
    /// `cos^e` lobe about its axis for large `e`. Level 6 costs four times as many cells in
    /// B~ and gained nothing for the renderer's mixture, whose BSDF share draws narrow
    /// lobes: with level 5 instead of 6 for their Phong materials (e = 60 to 200), garage
    /// and dynamics rendered at the same relMSE at equal samples in less time.
    pub fn product_level_hint(&self) -> u32 {
        const CELL_5: f32 = 0.111; // sqrt(4π) / 32 rad: a level-5 cell's width
        match *self {
            Material::Lambert { .. } => 5,
            Material::Phong { exponent, ks, .. } => {
                let lobe = (2.0 / (exponent + 2.0)).sqrt();
                if luminance(ks) > 0.0 && lobe < 0.5 * CELL_5 {
                    6
                } else {
                    5
                }
            }
        }
    }

    /// How far (radians) a surface normal may turn from the normal a product distribution
    /// was built at before the product stops describing this material's reflection there:
    /// 10° for diffuse reflection (B~ follows the cosine), and a quarter of the specular
    /// lobe's width `sqrt(2 / (e + 2))` when that is less (the mirror direction turns
    /// twice as fast as the normal). The renderer shares a pixel's product with the
    /// samples whose hits lie within it.
    pub fn product_tolerance(&self) -> f32 {
        const DIFFUSE: f32 = 10.0 * std::f32::consts::PI / 180.0;
        match *self {
            Material::Phong { exponent, ks, .. } if luminance(ks) > 0.0 => {
                DIFFUSE.min(0.25 * (2.0 / (exponent + 2.0)).sqrt())
            }
            _ => DIFFUSE,
        }
    }

    /// Each channel of the albedo `kd + ks` over its luminance (0 for a black material):
    /// how a channel of `f` compares with the luminance `B~` approximates. Exact at every
    /// direction for Lambert; for Phong, where the diffuse and specular colours mix by
    /// direction, the ratio of the two lobes' combined albedos. The control variate scales
    /// channel `c` of `L B~ Ṽ` by it, so `Z_c ≈ W_c` where the records are right (by each
    /// lobe's own ratio where the two differ in colour: [`Self::lobe_channel_ratios`]).
    pub fn channel_ratios(&self) -> [f32; 3] {
        let albedo = self.base_color();
        let lum = luminance(albedo);
        if lum > 0.0 {
            albedo.map(|c| c / lum)
        } else {
            [0.0; 3]
        }
    }

    /// Per channel, each lobe's colour over its luminance, `(kd / lum(kd), ks / lum(ks))`,
    /// for a Phong material whose two lobes differ in colour (blue paint under a clear
    /// coat): there a channel of `f` over its luminance changes with direction, from the
    /// paint's colour away from the lobe to the coat's inside it, which one ratio per point
    /// ([`Self::channel_ratios`]) cannot follow. `None` for Lambert, a missing lobe, or
    /// lobes whose ratios differ by at most [`LOBE_COLOUR_TOLERANCE`] in every channel.
    pub fn lobe_channel_ratios(&self) -> Option<([f32; 3], [f32; 3])> {
        let Material::Phong { kd, ks, .. } = *self else {
            return None;
        };
        let (ld, ls) = (luminance(kd), luminance(ks));
        if !(ld > 0.0 && ls > 0.0) {
            return None;
        }
        let (d, s) = (kd.map(|c| c / ld), ks.map(|c| c / ls));
        let apart = d
            .iter()
            .zip(&s)
            .any(|(a, b)| (a - b).abs() > LOBE_COLOUR_TOLERANCE);
        apart.then_some((d, s))
    }

    /// The diffuse lobe alone: Lambert of albedo `kd` (`self` for Lambert).
    pub fn diffuse_lobe(&self) -> Material {
        match *self {
            Material::Lambert { .. } => *self,
            Material::Phong { kd, .. } => Material::Lambert { albedo: kd },
        }
    }

    /// Probability that [`Material::sample`] picks the specular lobe: the lobe's share of
    /// the luminance of `kd + ks` (0 for Lambert and for a black material).
    #[inline]
    pub fn specular_probability(&self) -> f32 {
        match *self {
            Material::Lambert { .. } => 0.0,
            Material::Phong { kd, ks, .. } => {
                let (d, s) = (luminance(kd), luminance(ks));
                if d + s > 0.0 {
                    s / (d + s)
                } else {
                    0.0
                }
            }
        }
    }

    /// The BRDF `f_r(wo, wi)` in 1/sr, per RGB channel, without the cosine. Zero when `wo`
    /// or `wi` is at or below the surface, or when any input is NaN.
    pub fn eval(&self, n: Vec3, wo: Vec3, wi: Vec3) -> Vec3 {
        let (co, ci) = (n.dot(wo), n.dot(wi));
        if !(co > 0.0 && ci > 0.0) {
            return Vec3::ZERO;
        }
        match *self {
            Material::Lambert { albedo } => Vec3::from(albedo) * std::f32::consts::FRAC_1_PI,
            Material::Phong { kd, ks, exponent } => {
                let lobe = phong_lobe(exponent, cos_to_mirror(n, wo, wi)) as f32;
                Vec3::from(kd) * std::f32::consts::FRAC_1_PI + Vec3::from(ks) * lobe
            }
        }
    }

    /// Draws `wi` for a given `wo`: `uc ∈ [0,1)` picks the lobe (Phong: the specular lobe
    /// when `uc <` [`Material::specular_probability`]), `u ∈ [0,1)²` the direction within
    /// it (cosine-weighted hemisphere about `n`; Phong lobe `∝ cos^e α` about the mirror
    /// direction). `None` when the sample falls at or below the surface or `wo` is below it.
    /// The density of the returned directions is [`Material::pdf`].
    pub fn sample(&self, n: Vec3, wo: Vec3, uc: f32, u: Vec2) -> Option<Vec3> {
        if !is_above(n.dot(wo)) {
            return None;
        }
        let wi = match *self {
            Material::Phong { exponent, .. } if uc < self.specular_probability() => {
                let r = mirror(n.as_dvec3(), wo.as_dvec3());
                // cos α = u^(1/(e+1)); sin α from 1 - cos² = -expm1(2 ln u / (e+1)).
                let l = (u.x as f64).ln() / (exponent as f64 + 1.0);
                let cos_a = l.exp();
                let sin_a = (-(2.0 * l).exp_m1()).max(0.0).sqrt();
                let phi = std::f64::consts::TAU * u.y as f64;
                let (t, b) = r.normalize().any_orthonormal_pair();
                (t * (sin_a * phi.cos()) + b * (sin_a * phi.sin()) + r * cos_a)
                    .normalize()
                    .as_vec3()
            }
            _ => {
                let rad = u.x.sqrt();
                let phi = std::f32::consts::TAU * u.y;
                let z = (1.0 - u.x).max(0.0).sqrt();
                let (t, b) = n.any_orthonormal_pair();
                (t * (rad * phi.cos()) + b * (rad * phi.sin()) + n * z).normalize()
            }
        };
        (n.dot(wi) > 0.0 && wi.is_finite()).then_some(wi)
    }

    /// Solid-angle density (1/sr) of the directions [`Material::sample`] returns: the
    /// mixture of the cosine lobe (`cos θi / π`) and the Phong lobe (`(e+1)/(2π) cos^e α`)
    /// with the lobe-selection probabilities; zero at or below the surface, so its
    /// integral over the sphere is the probability that `sample` returns `Some`.
    pub fn pdf(&self, n: Vec3, wo: Vec3, wi: Vec3) -> f64 {
        let (co, ci) = (n.dot(wo), n.dot(wi));
        if !(co > 0.0 && ci > 0.0) {
            return 0.0;
        }
        let diffuse = ci as f64 * std::f64::consts::FRAC_1_PI;
        match *self {
            Material::Lambert { .. } => diffuse,
            Material::Phong { exponent, .. } => {
                let ps = self.specular_probability() as f64;
                let c = cos_to_mirror(n, wo, wi);
                let e = exponent as f64;
                let lobe = if c > 0.0 {
                    (e + 1.0) / std::f64::consts::TAU * c.powf(e)
                } else {
                    0.0
                };
                (1.0 - ps) * diffuse + ps * lobe
            }
        }
    }

    /// Monte Carlo estimate of the directional albedo `∫ f_r(wo, wi) cos θi dωi` per RGB
    /// channel (dimensionless, ≤ 1 for an energy-conserving material), from `samples`
    /// draws of [`Material::sample`] with the counter-based RNG of `seed`. Returns the mean
    /// and its standard error. For tests and diagnostics.
    pub fn directional_albedo(&self, n: Vec3, wo: Vec3, samples: u32, seed: u64) -> (DVec3, DVec3) {
        let (mut sum, mut sum2) = (DVec3::ZERO, DVec3::ZERO);
        for i in 0..samples as u64 {
            let rng = SampleRng::new(seed, 0, i);
            if let Some(wi) = self.sample(n, wo, rng.get(0), Vec2::from(rng.get2(1))) {
                let p = self.pdf(n, wo, wi);
                if p > 0.0 {
                    let x = self.eval(n, wo, wi).as_dvec3() * (n.dot(wi) as f64 / p);
                    sum += x;
                    sum2 += x * x;
                }
            }
        }
        let k = samples.max(1) as f64;
        let mean = sum / k;
        let var = (sum2 / k - mean * mean).max(DVec3::ZERO) / (k - 1.0).max(1.0);
        (mean, DVec3::new(var.x.sqrt(), var.y.sqrt(), var.z.sqrt()))
    }
}

/// How far apart (in a channel's ratio to luminance) a Phong material's two lobe colours
/// must be for [`Material::lobe_channel_ratios`] to tell them apart. Within it the
/// albedo's one ratio is within about 10% of each lobe's, and the control variate's second
/// integral costs more than it saves: on garage's white car (ratios within 0.03 of the
/// coat's) its blue variance ratio was 0.295 with it and 0.303 without, while the control
/// variate's per-point time of a 640x480, 10-spp render fell from 0.50 to 0.38 CPU-s
/// with this tolerance (2026-11-27).
pub const LOBE_COLOUR_TOLERANCE: f32 = 0.1;

/// Rec. 709 luminance of a linear RGB triple.
#[inline]
pub fn luminance(c: [f32; 3]) -> f32 {
    let w = LUMINANCE_F32;
    w[0] * c[0] + w[1] * c[1] + w[2] * c[2]
}

/// `x > 0`, false for NaN.
#[inline]
fn is_above(x: f32) -> bool {
    x > 0.0
}

/// Mirror direction of `wo` about `n` (unit when both are).
#[inline]
fn mirror(n: DVec3, wo: DVec3) -> DVec3 {
    2.0 * n.dot(wo) * n - wo
}

/// `cos α`: cosine between `wi` and the mirror direction of `wo`, in f64 (the lobe of
/// exponent 1e4 needs the precision).
#[inline]
fn cos_to_mirror(n: Vec3, wo: Vec3, wi: Vec3) -> f64 {
    let r = mirror(n.as_dvec3(), wo.as_dvec3());
    (r.dot(wi.as_dvec3()) / r.length()).min(1.0)
}

/// The normalised Phong lobe `(e+2)/(2π) cos^e α`, zero for `cos α ≤ 0`.
#[inline]
fn phong_lobe(e: f32, cos_a: f64) -> f64 {
    if cos_a > 0.0 {
        (e as f64 + 2.0) / std::f64::consts::TAU * cos_a.powf(e as f64)
    } else {
        0.0
    }
}
