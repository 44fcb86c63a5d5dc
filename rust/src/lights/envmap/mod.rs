//! Octahedral HDR environment maps: radiance at infinity, stored on the equal-area
//! octahedral map of the whole sphere and importance-sampled by hierarchical warping.
//!
//! **Representation.** A `res x res` RGB `f32` texture (`res = 2^k`, 1..=4096), row-major
//! (`y * res + x`), over Clarberg's equal-area octahedral map
//! ([`crate::sampling::octahedral`]): every texel covers the same solid angle
//! `4π / res²`, and radiance is piecewise constant per texel. CAM08 §5.5 (Clarberg &
//! Akenine-Möller 2008) uses this parameterization for the visibility records and the
//! quadtree of the product `L·B~`; storing the lighting on the same grid makes the quadtree
//! nodes of the map, of the records and of the product line up.
//!
//! **Sampling.** Texels are chosen in proportion to their Rec.709 luminance (in `f64`,
//! so a texel with any positive channel has a positive weight) through a
//! [`QuadPyramid`], sampled by hierarchical warping (McCool & Harwood, "Probability trees",
//! GI 1997; the same descent as pbrt-v4's `WindowedPiecewiseConstant2D`), then uniformly
//! in area inside the texel, i.e. uniformly in solid angle. The solid-angle pdf is
//!
//! `pdf(ω) = luminance(texel(ω)) / Σ luminance · res² / (4π)`,
//!
//! exactly what [`EnvMap::pdf`] returns; [`EnvMap::eval`] is the same piecewise-constant
//! texel lookup, so `eval / pdf` is constant inside a texel. [`EnvMap::sample`],
//! [`EnvMap::pdf`] and [`EnvMap::invert`] form a consistent triplet: a sampled direction
//! always lies in the texel it was drawn from (samples within float rounding of a texel's
//! border are pulled a hair inside it), so the returned pdf equals `pdf(direction)`.
//! Product sampling (CAM08 §5.5) reads [`EnvMap::distribution`]'s level sums and continues
//! a descent from a coarse cell with [`QuadPyramid::descend`].
//!
//! **Lat-long images** (for [`EnvMap::from_equirect`], [`EnvMap::to_equirect`] and EXR
//! files) follow Mitsuba 3's `envmap` convention with +y up: pixel column `s ∈ [0,1)`
//! (left to right) is the azimuth `φ = 2π s`, row `t ∈ [0,1)` (top to bottom) the polar
//! angle `θ = π t` from +y, and `ω = (sin φ sin θ, cos θ, -cos φ sin θ)`: the left edge
//! looks toward -z, a quarter across toward +x, the centre toward +z.
//!
//! **EXR files** ([`EnvMap::from_exr`], [`EnvMap::to_exr`]): one RGB layer of `f32`
//! (lossless ZIP compression). The layout is read from the text attribute
//! `viscacheLayout` (`"octahedral"` or `"latlong"`) when the file has it, and otherwise
//! from the shape: a square image whose side is a power of two is octahedral, an image
//! twice as wide as high is lat-long; anything else is an error. Octahedral maps round-trip
//! bit-exactly.
//!
//! Files: `equirect.rs` (lat-long images to and from the map), `exr.rs` (EXR files).

use glam::{DVec2, DVec3, UVec2, Vec2, Vec3};
use rayon::prelude::*;

use crate::error::{Error, Result};
use crate::sampling::distribution::QuadPyramid;
use crate::sampling::octahedral::{sphere_to_square, square_to_sphere, texel_of};

pub mod chroma;
mod equirect;
mod exr;
pub mod product;
pub mod rows;
#[cfg(test)]
mod tests;

pub use crate::math::LUMINANCE;
pub use equirect::{dir_to_latlong, latlong_to_dir, MAX_EQUIRECT_SIDE};
pub use exr::{ExrLayout, EXR_LAYOUT_ATTRIBUTE};

/// Largest supported side of the octahedral texture (`4096² ≈ 16.8M` texels).
pub const MAX_RESOLUTION: u32 = 4096;

/// Largest `f64` below one: points inside a texel stay in `[0, 1)`.
const ONE_MINUS_EPSILON: f64 = 1.0 - f64::EPSILON / 2.0;

/// Rec.709 luminance of a linear RGB triple, in `f64`.
#[inline]
pub fn luminance(rgb: [f32; 3]) -> f64 {
    LUMINANCE[0] * rgb[0] as f64 + LUMINANCE[1] * rgb[1] as f64 + LUMINANCE[2] * rgb[2] as f64
}

/// An HDR environment map on the equal-area octahedral map (see the module docs).
///
/// Invariants: `resolution` is a power of two in `[1, 4096]`; `texels` has
/// `resolution²` finite, non-negative RGB radiances (W·sr⁻¹·m⁻², or any consistent unit)
/// in row-major order; `distribution` holds the per-texel luminances and is `None` exactly
/// when every texel is black.
#[derive(Clone)]
pub struct EnvMap {
    resolution: u32,
    texels: Vec<[f32; 3]>,
    distribution: Option<QuadPyramid>,
}

impl std::fmt::Debug for EnvMap {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("EnvMap")
            .field("resolution", &self.resolution)
            .field("total_power", &self.total_power())
            .field("black", &self.distribution.is_none())
            .finish()
    }
}

/// `resolution` must be a power of two in `[1, 4096]`.
pub fn check_resolution(resolution: u32, name: &str) -> Result<()> {
    if resolution.is_power_of_two() && resolution <= MAX_RESOLUTION {
        Ok(())
    } else {
        Err(Error::invalid(
            name,
            format!("must be a power of two in [1, {MAX_RESOLUTION}], got {resolution}"),
        ))
    }
}

/// The first texel (row-major index) with a channel that is NaN, infinite, negative or
/// above [`super::MAX_RADIANCE`].
fn first_bad(values: &[[f32; 3]]) -> Option<usize> {
    values.iter().position(|&t| !super::valid_radiance(t))
}

/// Solid angle of one texel of a `res x res` octahedral grid, in steradians.
#[inline]
fn texel_omega(res: u32) -> f64 {
    4.0 * std::f64::consts::PI / (res as f64 * res as f64)
}

/// Angular size (radians) of a texel: the side of a square of its solid angle.
#[inline]
fn texel_angle(res: u32) -> f64 {
    texel_omega(res).sqrt()
}

impl EnvMap {
    /// Builds a map from its octahedral texels, row-major (`y * resolution + x`).
    /// `resolution` must be a power of two in `[1, 4096]` and `texels` hold exactly
    /// `resolution²` finite, non-negative values; otherwise an [`Error::InvalidArgument`]
    /// names the argument (and, for bad values, the first bad texel's `(x, y)`).
    pub fn from_octahedral(resolution: u32, texels: Vec<[f32; 3]>) -> Result<EnvMap> {
        check_resolution(resolution, "resolution")?;
        let n = resolution as usize * resolution as usize;
        if texels.len() != n {
            return Err(Error::invalid(
                "texels",
                format!(
                    "expected {n} texels for resolution {resolution}, got {}",
                    texels.len()
                ),
            ));
        }
        if let Some(i) = first_bad(&texels) {
            let r = resolution as usize;
            return Err(Error::invalid(
                "texels",
                format!(
                    "texel at (x={}, y={}) is {:?}; radiance must be finite and in [0, 1e15]",
                    i % r,
                    i / r,
                    texels[i]
                ),
            ));
        }
        Ok(Self::new_unchecked(resolution, texels))
    }

    /// Builds the map and its distribution from validated texels.
    fn new_unchecked(resolution: u32, texels: Vec<[f32; 3]>) -> EnvMap {
        let weights: Vec<f64> = texels.iter().map(|&t| luminance(t)).collect();
        let distribution = if weights.iter().any(|&w| w > 0.0) {
            // The weights are finite and >= 0 and the grid is a power-of-two square.
            QuadPyramid::from_row_major(&weights, "texels").ok()
        } else {
            None
        };
        EnvMap {
            resolution,
            texels,
            distribution,
        }
    }

    /// A uniform map of `radiance` (finite, `>= 0` per channel) at `resolution`.
    pub fn constant(radiance: [f32; 3], resolution: u32) -> Result<EnvMap> {
        check_resolution(resolution, "resolution")?;
        if first_bad(&[radiance]).is_some() {
            return Err(Error::invalid(
                "radiance",
                super::radiance_problem(radiance),
            ));
        }
        let n = resolution as usize * resolution as usize;
        Ok(Self::new_unchecked(resolution, vec![radiance; n]))
    }

    /// Side of the octahedral texture, a power of two in `[1, 4096]`.
    pub fn resolution(&self) -> u32 {
        self.resolution
    }

    /// The texels, row-major (`y * resolution + x`): finite, non-negative RGB radiance.
    pub fn texels(&self) -> &[[f32; 3]] {
        &self.texels
    }

    /// Whether every texel is black (the map cannot be sampled).
    pub fn is_black(&self) -> bool {
        self.distribution.is_none()
    }

    /// Radiance arriving from direction `dir` (pointing away from the receiver; need not
    /// be unit length): the value of the texel containing it, piecewise constant exactly as
    /// [`Self::pdf`] assumes. Zero or non-finite directions give some texel's value.
    #[inline]
    pub fn eval(&self, dir: Vec3) -> Vec3 {
        Vec3::from(self.texels[self.index_of(dir)])
    }

    #[inline]
    fn index_of(&self, dir: Vec3) -> usize {
        let t = texel_of(dir, self.resolution);
        (t.y * self.resolution + t.x) as usize
    }

    /// Radiance of texel `texel`.
    #[inline]
    pub fn texel(&self, texel: UVec2) -> Vec3 {
        Vec3::from(self.texels[(texel.y * self.resolution + texel.x) as usize])
    }

    /// Solid-angle pdf (sr⁻¹) of [`Self::sample`] for the texel `cell`.
    #[inline]
    pub fn texel_pdf(&self, cell: UVec2) -> f64 {
        match &self.distribution {
            Some(d) => d.probability(cell) / texel_omega(self.resolution),
            None => 0.0,
        }
    }

    /// Draws a direction with probability proportional to luminance from `u ∈ [0,1)²`
    /// (values outside are clamped). Returns the unit direction and its solid-angle pdf
    /// (sr⁻¹, equal to [`Self::pdf`] of the direction, always `> 0`); `None` for an
    /// all-black map. Stratification of `u` carries over (hierarchical warping).
    pub fn sample(&self, u: DVec2) -> Option<(Vec3, f64)> {
        let dist = self.distribution.as_ref()?;
        let (cell, within) = dist.sample(u)?;
        let dir = self.direction_in(cell, within);
        Some((dir, self.texel_pdf(cell)))
    }

    /// The direction at point `within ∈ [0,1)²` of texel `cell`, guaranteed to lie in that
    /// texel: points that float rounding would push across the border are moved towards
    /// the texel's centre by the smallest step that keeps them inside.
    pub(crate) fn direction_in(&self, cell: UVec2, within: DVec2) -> Vec3 {
        let res = self.resolution as f64;
        for shrink in [0.0, 1e-5, 1e-4, 1e-3, 1e-2, 0.1, 1.0] {
            let w = DVec2::splat(0.5) + (within - 0.5) * (1.0 - shrink);
            let p = ((cell.as_dvec2() + w) / res).as_vec2();
            let d = square_to_sphere(p);
            if texel_of(d, self.resolution) == cell {
                return d;
            }
        }
        square_to_sphere(((cell.as_dvec2() + 0.5) / res).as_vec2())
    }

    /// Solid-angle pdf (sr⁻¹) with which [`Self::sample`] draws `dir`:
    /// `luminance(texel) / Σ luminance · res² / (4π)`; 0 for an all-black map.
    #[inline]
    pub fn pdf(&self, dir: Vec3) -> f64 {
        self.texel_pdf(texel_of(dir, self.resolution))
    }

    /// The `u ∈ [0,1)²` that [`Self::sample`] maps to `dir` (up to float rounding, ~1e-6
    /// for smooth maps); `None` for an all-black map or a direction of zero pdf.
    pub fn invert(&self, dir: Vec3) -> Option<DVec2> {
        let dist = self.distribution.as_ref()?;
        let res = self.resolution;
        let p = sphere_to_square(dir).as_dvec2() * res as f64;
        let cell = texel_of(dir, res);
        let within = (p - cell.as_dvec2()).clamp(DVec2::ZERO, DVec2::splat(ONE_MINUS_EPSILON));
        dist.invert(cell, within)
    }

    /// The per-texel sampling weights (Rec.709 luminance, `> 0` wherever any channel is
    /// `> 0`) as a quadtree in Morton order; `None` when the map is all black. Its finest
    /// level is the texture's grid, so node `(level, index)` covers the same directions as
    /// the same node of any other octahedral quadtree (records, product distributions).
    pub fn distribution(&self) -> Option<&QuadPyramid> {
        self.distribution.as_ref()
    }

    /// The map rotated by `degrees` about +y, right-handed: a feature in direction `ω`
    /// moves to `R_y(degrees)·ω`, so +90° takes +x to -z and +z to +x. Multiples of 90°
    /// permute texels exactly (360° is the identity); other angles resample with 4x4
    /// sub-samples per texel. Non-finite angles give a copy.
    pub fn rotated(&self, degrees: f32) -> EnvMap {
        let res = self.resolution as usize;
        let turns = degrees as f64 / 90.0;
        if !degrees.is_finite() || turns == turns.round() {
            let quarter = if degrees.is_finite() {
                (turns.round() as i64).rem_euclid(4)
            } else {
                0
            };
            if quarter == 0 {
                return self.clone();
            }
            let mut texels = self.texels.clone();
            for _ in 0..quarter {
                // +90°: (x, z) -> (z, -x); the square's (U, V) -> (V, -U), so the new texel
                // (i, j) takes the old one at (res - 1 - j, i).
                let old = texels.clone();
                for j in 0..res {
                    for i in 0..res {
                        texels[j * res + i] = old[i * res + (res - 1 - j)];
                    }
                }
            }
            return Self::new_unchecked(self.resolution, texels);
        }
        let (s, c) = (-(degrees as f64).to_radians()).sin_cos();
        let inverse = move |d: DVec3| DVec3::new(c * d.x + s * d.z, d.y, -s * d.x + c * d.z);
        let texels = supersample(self.resolution, 4, |d| {
            self.eval(inverse(d).as_vec3()).as_dvec3()
        });
        Self::new_unchecked(self.resolution, texels)
    }

    /// The map resampled to another `resolution` (a power of two in `[1, 4096]`) with 4x4
    /// sub-samples per new texel (a box filter; exact when `resolution` is the same).
    pub fn resampled(&self, resolution: u32) -> Result<EnvMap> {
        check_resolution(resolution, "resolution")?;
        if resolution == self.resolution {
            return Ok(self.clone());
        }
        let texels = supersample(resolution, 4, |d| self.eval(d.as_vec3()).as_dvec3());
        Ok(Self::new_unchecked(resolution, texels))
    }

    /// This map, or the same radiance on a finer grid when its resolution is below `min`
    /// (exact: texels are split into equal-area sub-texels of the same radiance). Product
    /// distributions need cells of level `>= 1`, so renders ask for `min = 2`.
    pub fn at_least(&self, min: u32) -> Result<std::borrow::Cow<'_, EnvMap>> {
        Ok(if self.resolution < min {
            std::borrow::Cow::Owned(self.resampled(min)?)
        } else {
            std::borrow::Cow::Borrowed(self)
        })
    }

    /// `∫ L dω` over the whole sphere per channel (radiance times steradians, e.g.
    /// W·m⁻² for radiance in W·sr⁻¹·m⁻²), summed in `f64`.
    pub fn total_power(&self) -> [f64; 3] {
        let mut sum = DVec3::ZERO;
        for t in &self.texels {
            sum += Vec3::from(*t).as_dvec3();
        }
        (sum * texel_omega(self.resolution)).to_array()
    }
}

/// Texels of a `res x res` map whose value is the mean of `f` over `sub x sub` sub-texel
/// points (of equal solid angle, as the map is equal-area). Rows run in parallel; each
/// texel is computed on its own, so results do not depend on the thread count.
pub(crate) fn supersample(res: u32, sub: u32, f: impl Fn(DVec3) -> DVec3 + Sync) -> Vec<[f32; 3]> {
    let r = res as usize;
    let mut out = vec![[0.0f32; 3]; r * r];
    out.par_chunks_mut(r).enumerate().for_each(|(y, row)| {
        for (x, t) in row.iter_mut().enumerate() {
            let mut sum = DVec3::ZERO;
            for sy in 0..sub {
                for sx in 0..sub {
                    let within = (Vec2::new(sx as f32, sy as f32) + 0.5) / sub as f32;
                    let p = (Vec2::new(x as f32, y as f32) + within) / res as f32;
                    sum += f(square_to_sphere(p).as_dvec3());
                }
            }
            *t = (sum / (sub * sub) as f64).as_vec3().to_array();
        }
    });
    out
}
