//! Lat-long (equirectangular) images to and from the octahedral map, by supersampling
//! with the power of bright features kept exactly.

use glam::{DVec2, DVec3, UVec2, Vec3};
use rayon::prelude::*;

use super::{check_resolution, first_bad, texel_angle, texel_omega, EnvMap, ONE_MINUS_EPSILON};
use crate::error::{Error, Result};
use crate::sampling::octahedral::square_to_sphere;
use crate::stop::Stop;

/// One lat-long sub-pixel run's contribution to a texel (see [`EnvMap::from_equirect`]).
struct Splat {
    texel: u32,
    base: DVec3,
    excess: DVec3,
    omega: f64,
}

/// Run-length splats: consecutive sub-samples that land in the same cell are merged.
#[derive(Default)]
struct Splats(Vec<Splat>);

impl Splats {
    #[inline]
    fn add(&mut self, cell: u32, base: DVec3, excess: DVec3, d_omega: f64) {
        match self.0.last_mut() {
            Some(s) if s.texel == cell => {
                s.base += base * d_omega;
                s.excess += excess * d_omega;
                s.omega += d_omega;
            }
            _ => self.0.push(Splat {
                texel: cell,
                base: base * d_omega,
                excess: excess * d_omega,
                omega: d_omega,
            }),
        }
    }
}

/// Per-cell sums of splats: the base part's power and solid angle, the excess's power.
struct Accumulator {
    base: Vec<DVec3>,
    excess: Vec<DVec3>,
    omega: Vec<f64>,
}

impl Accumulator {
    fn new(n: usize) -> Self {
        Self {
            base: vec![DVec3::ZERO; n],
            excess: vec![DVec3::ZERO; n],
            omega: vec![0.0; n],
        }
    }

    /// Adds the splats of `work` over `units` ([`for_each_splat`]); stops as it does.
    fn run<U: Sync>(
        &mut self,
        units: &[U],
        cost: impl Fn(&U) -> usize,
        work: impl Fn(&U) -> Vec<Splat> + Sync,
    ) -> Result<()> {
        for_each_splat(units, cost, work, |s| {
            let t = s.texel as usize;
            self.base[t] += s.base;
            self.excess[t] += s.excess;
            self.omega[t] += s.omega;
        })
    }
}

/// Runs `work` over `units` in parallel batches of at most ~2M pending splats (`cost`
/// bounds a unit's), handing the results to `sink` in unit order: deterministic, bounded
/// memory. Polls the current [`Stop`] between batches (each is tens of milliseconds):
/// stopped, it returns [`Error::Interrupted`] with `sink` part-fed.
fn for_each_splat<U: Sync>(
    units: &[U],
    cost: impl Fn(&U) -> usize,
    work: impl Fn(&U) -> Vec<Splat> + Sync,
    mut sink: impl FnMut(&Splat),
) -> Result<()> {
    const BUDGET: usize = 1 << 21;
    let stop = Stop::current();
    let mut start = 0;
    while start < units.len() {
        stop.check("EnvMap.to_equirect")?;
        let mut end = start;
        let mut pending = 0;
        while end < units.len() && (end == start || pending + cost(&units[end]) <= BUDGET) {
            pending += cost(&units[end]);
            end += 1;
        }
        let done: Vec<Vec<Splat>> = units[start..end].par_iter().map(&work).collect();
        done.iter().flatten().for_each(&mut sink);
        start = end;
    }
    Ok(())
}
/// Largest accepted lat-long image side (width or height), in pixels.
pub const MAX_EQUIRECT_SIDE: usize = 1 << 15;
/// The direction of lat-long point `(s, t) ∈ [0,1]²` (see the module docs): azimuth
/// `φ = 2π s`, polar angle `θ = π t` from +y.
#[inline]
pub fn latlong_to_dir(s: f64, t: f64) -> DVec3 {
    let (sin_phi, cos_phi) = (std::f64::consts::TAU * s).sin_cos();
    let (sin_theta, cos_theta) = (std::f64::consts::PI * t).sin_cos();
    DVec3::new(sin_phi * sin_theta, cos_theta, -cos_phi * sin_theta)
}

/// The lat-long point `(s, t) ∈ [0,1)x[0,1]` of a direction (need not be unit; zero maps
/// to the top row); the inverse of [`latlong_to_dir`].
#[inline]
pub fn dir_to_latlong(d: DVec3) -> DVec2 {
    let d = d.normalize_or(DVec3::Y);
    let phi = d.x.atan2(-d.z).rem_euclid(std::f64::consts::TAU);
    let s = (phi / std::f64::consts::TAU).min(ONE_MINUS_EPSILON);
    let t = d.y.clamp(-1.0, 1.0).acos() / std::f64::consts::PI;
    DVec2::new(s, t)
}
/// The four pixels around lat-long point `st` of a `width x height` image and their
/// bilinear weights: pixel centres at half-integers, wrapping in azimuth, clamped at the
/// poles' rows.
#[inline]
fn bilinear_taps(st: DVec2, width: usize, height: usize) -> ([usize; 4], [f64; 4]) {
    let x = st.x * width as f64 - 0.5;
    let y = (st.y * height as f64 - 0.5).clamp(0.0, (height - 1) as f64);
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let i0 = (x0 as i64).rem_euclid(width as i64) as usize;
    let i1 = (i0 + 1) % width;
    let j0 = y0 as usize;
    let j1 = (j0 + 1).min(height - 1);
    (
        [
            j0 * width + i0,
            j0 * width + i1,
            j1 * width + i0,
            j1 * width + i1,
        ],
        [
            (1.0 - fx) * (1.0 - fy),
            fx * (1.0 - fy),
            (1.0 - fx) * fy,
            fx * fy,
        ],
    )
}
impl EnvMap {
    /// Resamples a lat-long image (row-major `rgb[y * width + x]`, row 0 at the top; see the
    /// module docs for the convention; any aspect ratio) onto a `resolution²` octahedral
    /// map: each texel is the mean, over its solid angle, of the image's bilinear
    /// interpolant (points of equal solid angle, at most half a pixel apart), so the map of
    /// a smooth image converges as texels shrink. Radiance above 16x the image's mean (a
    /// sun, a bright window) is resampled the same way and then scaled to the image's exact
    /// power in it, so a feature of a pixel keeps its power; the total `∫ L dω` matches the
    /// image's to about 0.1%. Bad sizes and NaN/Inf/negative pixels (naming the first) are
    /// errors. Stops with [`Error::Interrupted`] within a fraction of a second of the
    /// current [`Stop`] being set.
    pub fn from_equirect(
        rgb: &[[f32; 3]],
        width: usize,
        height: usize,
        resolution: u32,
    ) -> Result<EnvMap> {
        check_resolution(resolution, "resolution")?;
        for (v, name) in [(width, "width"), (height, "height")] {
            if v == 0 || v > MAX_EQUIRECT_SIDE {
                return Err(Error::invalid(
                    name,
                    format!("must be in [1, {MAX_EQUIRECT_SIDE}], got {v}"),
                ));
            }
        }
        if rgb.len() != width * height {
            return Err(Error::invalid(
                "rgb",
                format!(
                    "expected {width} x {height} = {} pixels, got {}",
                    width * height,
                    rgb.len()
                ),
            ));
        }
        if let Some(i) = first_bad(rgb) {
            return Err(Error::invalid(
                "rgb",
                format!(
                    "pixel at (x={}, y={}) is {:?}; radiance must be finite and in [0, 1e15]",
                    i % width,
                    i / width,
                    rgb[i]
                ),
            ));
        }
        // Polled between the passes over the image and per texel: a large image takes
        // seconds. A stopped call returns `Error::Interrupted`.
        const WHAT: &str = "EnvMap.from_equirect";
        let stop = Stop::current();
        stop.check(WHAT)?;
        let res = resolution;
        let (w, h) = (width as f64, height as f64);
        let pi = std::f64::consts::PI;
        let row_omega = |j: usize| {
            std::f64::consts::TAU / w
                * ((pi * j as f64 / h).cos() - (pi * (j + 1) as f64 / h).cos())
        };
        // Split L = base + excess, base = min(L, 16 x the mean radiance) per channel: the
        // excess (a sun, a bright window) gets its exact power back below.
        let mut mean = DVec3::ZERO;
        for j in 0..height {
            let mut row = DVec3::ZERO;
            for px in &rgb[j * width..(j + 1) * width] {
                row += Vec3::from(*px).as_dvec3();
            }
            mean += row * row_omega(j);
        }
        let cap = mean / (4.0 * pi) * 16.0;
        stop.check(WHAT)?;
        // The texels' buffers (the gathered pairs, the texels, the map's weights and
        // distribution: under 96 bytes a texel) are checked with the image's, so that a
        // size that cannot be met fails here rather than part-way.
        crate::alloc::check_memory(
            (res as usize * res as usize).saturating_mul(96),
            "resolution",
        )?;
        let base: Vec<DVec3> = crate::alloc::try_collect(
            rgb.iter().map(|p| Vec3::from(*p).as_dvec3().min(cap)),
            "rgb",
        )?;
        let excess: Vec<DVec3> = crate::alloc::try_collect(
            rgb.iter()
                .zip(&base)
                .map(|(p, b)| Vec3::from(*p).as_dvec3() - *b),
            "rgb",
        )?;
        let source_excess: DVec3 = (0..height)
            .map(|j| excess[j * width..(j + 1) * width].iter().sum::<DVec3>() * row_omega(j))
            .sum();
        // Each texel is the mean of the bilinear interpolant of the pixels over it, from
        // `sub x sub` points of equal solid angle (the map is equal-area), spaced at most half
        // a pixel apart so every pixel's interpolant is seen: the error of a smooth image
        // falls with the texel's size (an earlier splat of sub-pixels into texels kept a
        // fixed ±8% moiré at every resolution).
        let pixel = (pi / h).min(std::f64::consts::TAU / w);
        let sub = ((2.0 * texel_angle(res) / pixel).ceil() as usize).clamp(4, 64);
        let has_excess = source_excess.max_element() > 0.0;
        // Filled block by block, so that a stop leaves the later blocks untouched: writing
        // the rest of 16M texels (768 MB) after one took 0.5 s.
        const BLOCK: u32 = 1 << 18;
        let mut gathered: Vec<(DVec3, DVec3)> = Vec::with_capacity((res * res) as usize);
        for start in (0..res * res).step_by(BLOCK as usize) {
            stop.check(WHAT)?;
            gathered.par_extend(
                (start..(start + BLOCK).min(res * res))
                    .into_par_iter()
                    .map(|t| {
                        // A texel is at least 16 points of 4 taps: a poll costs nothing beside.
                        if stop.is_set() {
                            return (DVec3::ZERO, DVec3::ZERO);
                        }
                        let (x, y) = ((t % res) as f64, (t / res) as f64);
                        let (mut b, mut e) = (DVec3::ZERO, DVec3::ZERO);
                        for i in 0..sub {
                            for k in 0..sub {
                                let p = DVec2::new(
                                    (x + (k as f64 + 0.5) / sub as f64) / res as f64,
                                    (y + (i as f64 + 0.5) / sub as f64) / res as f64,
                                );
                                let st = dir_to_latlong(square_to_sphere(p.as_vec2()).as_dvec3());
                                let (taps, weights) = bilinear_taps(st, width, height);
                                for (&tap, &wt) in taps.iter().zip(&weights) {
                                    b += base[tap] * wt;
                                    if has_excess {
                                        e += excess[tap] * wt;
                                    }
                                }
                            }
                        }
                        let n = (sub * sub) as f64;
                        (b / n, e / n)
                    }),
            );
        }
        stop.check(WHAT)?;
        // The excess keeps the source's power exactly (a sun of a pixel or less would
        // otherwise gain or lose what the interpolant's samples happen to see of it).
        let gathered_excess: DVec3 = gathered.iter().map(|g| g.1).sum::<DVec3>() * texel_omega(res);
        let scale = DVec3::select(
            gathered_excess.cmpgt(DVec3::ZERO),
            source_excess / gathered_excess.max(DVec3::splat(f64::MIN_POSITIVE)),
            DVec3::ZERO,
        );
        let texels = gathered
            .iter()
            .map(|(b, e)| (*b + *e * scale).as_vec3().to_array())
            .collect();
        Ok(Self::new_unchecked(res, texels))
    }

    /// Resamples the map to a `width x height` lat-long image (row-major, row 0 at the top;
    /// see the module docs). As in [`Self::from_equirect`], radiance up to 16x the map's
    /// mean (the base) is averaged per pixel, and the excess above it (a sun) keeps its
    /// exact power: it is split into equal sub-texels, at least four per pixel width, each
    /// added to the pixel its centre falls in. The base is averaged the same way where
    /// pixels are at least a quarter of a texel wide (four sub-texels per pixel width,
    /// fewer for maps over 1024²); where they are smaller, each pixel averages it at 2x2
    /// points of equal solid angle (the texels are piecewise constant, so this is exact
    /// away from texel borders, and the base is too dim for their error to matter). The
    /// image's `∫ L dω` then matches [`Self::total_power`] to within a fraction of a percent
    /// at any size, and a sun's to float rounding: point samples of a sun a few texels
    /// wide missed or caught its border texels, which moved the irradiance it gives by
    /// -0.8% to +0.1% with the image's width (a renderer given the image then disagreed
    /// with ours by tens of standard errors). Sizes of zero give an empty image.
    ///
    /// Every pass polls the current [`Stop`] (per row of pixels, per batch of sub-texels):
    /// stopped, it returns [`Error::Interrupted`].
    pub fn to_equirect(&self, width: usize, height: usize) -> Result<Vec<[f32; 3]>> {
        if width == 0 || height == 0 {
            return Ok(Vec::new());
        }
        const WHAT: &str = "EnvMap.to_equirect";
        let stop = Stop::current();
        let res = self.resolution;
        let (w, h) = (width as f64, height as f64);
        let pi = std::f64::consts::PI;
        let pixel_angle = (pi / h).min(std::f64::consts::TAU / w);
        let gather = pixel_angle < 0.25 * texel_angle(res);
        let per_pixel = (4.0 * texel_angle(res) / pixel_angle).ceil();
        let sub = if gather {
            // Only the excess is split (at most 1/16 of the sphere is above the cap).
            per_pixel.min(64.0) as u32
        } else {
            // Within a budget of ~32M sub-texels.
            let budget = ((32.0 * 1024.0 * 1024.0) / (res as f64 * res as f64))
                .sqrt()
                .max(1.0);
            (per_pixel.min(budget) as u32).clamp(1, 16)
        };
        let cap = DVec3::from(self.total_power()) / (4.0 * pi) * 16.0;
        let split = |t: [f32; 3]| {
            let l = Vec3::from(t).as_dvec3();
            let base = l.min(cap);
            (base, l - base)
        };
        let d_omega = texel_omega(res) / (sub * sub) as f64;
        let pixel_of = |d: Vec3| {
            let st = dir_to_latlong(d.as_dvec3());
            let x = ((st.x * w) as usize).min(width - 1);
            let y = ((st.y * h) as usize).min(height - 1);
            (y * width + x) as u32
        };
        // One unit of work is a sub-row of a run of texels of one row (see
        // `from_equirect`): the whole row when splatting everything, else each texel with
        // an excess.
        let units: Vec<(u32, u32, u32, u32)> = if gather {
            (0..res * res)
                .filter(|&t| split(self.texels[t as usize]).1.max_element() > 0.0)
                .flat_map(|t| (0..sub).map(move |b| (t / res, t % res, t % res + 1, b)))
                .collect()
        } else {
            (0..res)
                .flat_map(|y| (0..sub).map(move |b| (y, 0, res, b)))
                .collect()
        };
        let unit_splats = |&(y, x0, x1, b): &(u32, u32, u32, u32)| {
            let mut out = Splats::default();
            for x in x0..x1 {
                let (base, excess) = split(self.texels[(y * res + x) as usize]);
                let base = if gather { DVec3::ZERO } else { base };
                for a in 0..sub {
                    let within =
                        DVec2::new((a as f64 + 0.5) / sub as f64, (b as f64 + 0.5) / sub as f64);
                    let p = ((UVec2::new(x, y).as_dvec2() + within) / res as f64).as_vec2();
                    out.add(pixel_of(square_to_sphere(p)), base, excess, d_omega);
                }
            }
            out.0
        };
        let cost = |u: &(u32, u32, u32, u32)| ((u.2 - u.1) * sub) as usize;
        let pixel_omega = |y: usize| {
            std::f64::consts::TAU / w
                * ((pi * y as f64 / h).cos() - (pi * (y + 1) as f64 / h).cos())
        };
        if gather {
            // The excess lands in few pixels: kept sparse beside the gathered base.
            let mut image = self.gather_equirect(width, height, |l| split(l).0)?;
            let mut excess = std::collections::BTreeMap::<u32, DVec3>::new();
            for_each_splat(&units, cost, unit_splats, |s| {
                *excess.entry(s.texel).or_default() += s.excess;
            })?;
            for (i, e) in excess {
                let px = &mut image[i as usize];
                let value = Vec3::from(*px).as_dvec3() + e / pixel_omega(i as usize / width);
                *px = value.as_vec3().to_array();
            }
            return Ok(image);
        }
        let mut acc = Accumulator::new(width * height);
        acc.run(&units, cost, unit_splats)?;
        let Accumulator {
            base,
            excess,
            omega,
        } = acc;
        // Each pixel on its own: the same image for any thread count.
        let image = (0..width * height)
            .into_par_iter()
            .with_min_len(width)
            .map(|i| {
                if stop.is_set() {
                    return [0.0; 3];
                }
                let (x, y) = (i % width, i / width);
                let b = if omega[i] > 0.0 {
                    base[i] / omega[i]
                } else {
                    // A pixel too thin to catch a sub-texel (near the poles): its centre.
                    let d = latlong_to_dir((x as f64 + 0.5) / w, (y as f64 + 0.5) / h);
                    split(self.texels[self.index_of(d.as_vec3())]).0
                };
                (b + excess[i] / pixel_omega(y)).as_vec3().to_array()
            })
            .collect();
        stop.check(WHAT)?;
        Ok(image)
    }

    /// The base of [`Self::to_equirect`] for pixels much smaller than texels: `base` of the
    /// map's radiance at 2x2 equal-area points per pixel, averaged. Polls the current
    /// [`Stop`] per row.
    fn gather_equirect(
        &self,
        width: usize,
        height: usize,
        base: impl Fn([f32; 3]) -> DVec3 + Sync,
    ) -> Result<Vec<[f32; 3]>> {
        let (w, h) = (width as f64, height as f64);
        let pi = std::f64::consts::PI;
        let stop = Stop::current();
        let mut out = vec![[0.0f32; 3]; width * height];
        out.par_chunks_mut(width).enumerate().for_each(|(j, row)| {
            if stop.is_set() {
                return;
            }
            let (c0, c1) = ((pi * j as f64 / h).cos(), (pi * (j + 1) as f64 / h).cos());
            let ts = [0.25, 0.75].map(|f| (c0 + (c1 - c0) * f).clamp(-1.0, 1.0).acos() / pi);
            for (i, px) in row.iter_mut().enumerate() {
                let mut sum = DVec3::ZERO;
                for t in ts {
                    for f in [0.25, 0.75] {
                        let d = latlong_to_dir((i as f64 + f) / w, t);
                        sum += base(self.eval(d.as_vec3()).to_array());
                    }
                }
                *px = (sum * 0.25).as_vec3().to_array();
            }
        });
        stop.check("EnvMap.to_equirect")?;
        Ok(out)
    }
}
