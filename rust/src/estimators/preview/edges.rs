//! The bright cells' light per pixel: the records' answer where they agree, shadow rays
//! where they disagree.
//!
//! A sun's light enters a pixel through one direction, and the records' bits for it are
//! one texel of each record, seen from up to `d_max` away. Where every record a pixel keeps
//! agrees (all see the sun, or none does) that answer is taken; where they disagree the
//! pixel lies on a shadow's edge as the cache resolves it, and the cache's blend of records
//! draws the edge as a ramp a record spacing wide, dark where the floor is lit and lit where
//! it is in shadow. Those pixels (and any that kept no record) trace rays instead, up to a
//! budget: one per direction of [`BrightCells::aims`], so that a sun partly hidden by a
//! strand or a leaf counts in quarters rather than all or nothing.
//!
//! Measured at 320x240 on the suite (`benches/README.md`, "Lighting preview"), with every
//! disagreeing pixel traced: room's map turned by 45°, where the blend's edges made the
//! transfer 1.27x the direct preview's relMSE, falls to 0.07x; one ray per cell instead
//! of four left strands' sun-and-sky at 1.65x (all or nothing behind thin hair). Where the
//! budget runs out, the pixels left untraced take the form of `Ṽ` (the blend or the
//! heaviest record) that the rays of a spread sample of them judge closer: with the
//! blend alone there, strands' sky was 2.6x. The rays replace a judge that traced a
//! sample of all pixels for that choice: both forms agree wherever the records do. With
//! the default budget ([`super::EDGE_RAYS`]) every one of the suite's 44 cases is at
//! most the direct preview's relMSE (worst garden 135°, 0.995; 18 were above before).

use rayon::prelude::*;

use super::bright::{BrightCells, PixelRecords, Shading, AIMS};
use crate::error::Result;
use crate::geometry::{RayBatch, Scene};
use crate::lights::envmap::LUMINANCE;
use crate::parallel::with_threads;

/// Each pixel's `J` under one lighting with bright cells ([`BrightLight::gather`]).
#[derive(Clone, Debug, Default)]
pub struct BrightLight {
    /// Per pixel, `J` but for its undecided cells: the truncated transfer's and the light
    /// of the cells its records agree on (RGB).
    base: Vec<[f64; 3]>,
    /// Per pixel where no cell is undecided, [`View::finish`] of `base`: the image there.
    image: Vec<[f32; 3]>,
    /// Per pixel, three bits per bright cell: [`DECIDED`], [`UNTRACED`] or the number of
    /// its [`AIMS`] shares the rays found open.
    codes: Vec<u32>,
    /// Rays traced; `None` when the gathering was given no scene to trace in.
    pub rays: Option<u64>,
    /// Pixels that traced rays.
    pub traced_pixels: usize,
    /// When the budget left pixels untraced: how each form of `Ṽ` fared on the spread
    /// sample of traced ones, which chose the form of the untraced.
    pub judged: Option<FormErrors>,
}

/// A cell the pixel's records agree on (its light is in the base).
const DECIDED: u32 = 7;
/// An undecided cell that traced no ray.
const UNTRACED: u32 = 5;
/// Bits per cell in a pixel's code.
const CODE_BITS: u32 = 3;

/// The code of a pixel whose `n` cells are all [`DECIDED`].
fn decided_code(n: usize) -> u32 {
    (0..n).fold(0u32, |c, s| c | DECIDED << (CODE_BITS * s as u32))
}

fn cell_code(code: u32, s: usize) -> u32 {
    code >> (CODE_BITS * s as u32) & 7
}

/// Each form's error on the sample pixels ([`BrightLight::gather`]): per pixel the
/// undecided cells' light in the form against the rays', squared over the pixel's `J`
/// by the rays squared plus 0.01 (the images' relMSE, in luminance), summed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FormErrors {
    pub blend: f64,
    pub nearest: f64,
    /// Sample pixels.
    pub pixels: usize,
}

impl FormErrors {
    /// The heaviest record wins when its error is lower.
    pub fn prefers_nearest(&self) -> bool {
        self.nearest < self.blend
    }
}

/// What [`BrightLight::gather`] needs of the view.
pub struct View<'a, P, S, F> {
    pub pixels: usize,
    /// A pixel's position and shading; `None` for pixels without a transfer.
    pub point: P,
    /// A pixel's `J` without the bright cells (its truncated transfer's).
    pub smooth: S,
    /// A pixel's colour from its `J` (zero where `point` is `None`).
    pub finish: F,
    pub records: &'a PixelRecords,
    pub bright: &'a BrightCells,
    /// [`super::bright::RecordColumns::masks`].
    pub masks: &'a [u8],
}

fn luminance(c: [f64; 3]) -> f64 {
    c.iter().zip(LUMINANCE).map(|(x, w)| x * w).sum()
}

impl BrightLight {
    /// `J` at every pixel of `view`: its smooth part, the light of the cells above its
    /// surface that its records agree on, and of those they leave undecided (they
    /// disagree, or the pixel kept no record). With `scene` and a `budget` of at least
    /// one ray (`scene` must be the one the records were traced in, [`BrightCells::aim`]
    /// called), the undecided cells trace rays: all of them when their rays number at most `budget`; else half the budget
    /// goes to a spread sample of the pixels with undecided cells (every so many in pixel
    /// order), which judges the two forms of `Ṽ` against the rays for the pixels left
    /// untraced, and the rest to the pixels whose light the records leave most in doubt
    /// (the cells' light times the blend's distance from all or nothing, all of it with
    /// no record, relative to the pixel's `J` as in the relMSE). Rays leave in pixel
    /// order, a pixel's consecutive from one origin (packets), so the answers are the
    /// same for any thread count.
    pub fn gather<P, S, F>(
        scene: Option<&Scene>,
        view: &View<'_, P, S, F>,
        budget: usize,
        threads: Option<usize>,
    ) -> Result<Self>
    where
        P: Fn(usize) -> Option<(glam::Vec3, Shading)> + Sync,
        S: Fn(usize) -> [f64; 3] + Sync,
        F: Fn(usize, [f64; 3]) -> [f32; 3] + Sync,
    {
        let View {
            pixels,
            ref point,
            ref smooth,
            ref finish,
            records,
            bright,
            masks,
        } = *view;
        let scene = scene.filter(|_| budget > 0);
        let n = bright.cells.len();
        debug_assert!(n <= 8 && CODE_BITS as usize * n <= 32);
        let every_cell = (1u16 << n).wrapping_sub(1) as u8;
        let decided_code = decided_code(n);
        // Per pixel: `J` but for the undecided cells, its code, and the error the
        // records' blend risks on those cells (their light times the blend's distance
        // from all or nothing, all of it with no record), squared over `J`'s square plus
        // 0.01 as the images' relMSE counts it. The pixel's colour from the base too, final
        // where no cell is left undecided (no second pass over those pixels).
        let mut base = vec![[0.0f64; 3]; pixels];
        let mut image = vec![[0.0f32; 3]; pixels];
        let mut codes = vec![decided_code; pixels];
        let mut risks = vec![0.0f32; pixels];
        with_threads(threads, || {
            let slots = (&mut base, &mut image, &mut codes, &mut risks);
            slots
                .into_par_iter()
                .enumerate()
                .with_min_len(1024)
                .for_each(|(i, slot)| {
                    let (base_out, image_out, code_out, risk_out) = slot;
                    let Some((_, at)) = point(i) else {
                        *image_out = finish(i, [0.0; 3]);
                        return;
                    };
                    let seen = records.seen(i, masks);
                    let (lit, open) = seen.map_or((0, every_cell), |(any, all)| (all, any & !all));
                    let light = bright.light(&at, |s| f64::from(lit >> s & 1));
                    let smooth = smooth(i);
                    let base: [f64; 3] = std::array::from_fn(|c| smooth[c] + light[c]);
                    let (mut code, mut risk, mut j) = (decided_code, 0.0, luminance(base));
                    for s in (0..n).filter(|s| open >> s & 1 == 1) {
                        if at.normal.dot(bright.dirs[s]) <= 0.0 {
                            continue;
                        }
                        code ^= (DECIDED ^ UNTRACED) << (CODE_BITS * s as u32);
                        let l = luminance(bright.light_of(&at, s));
                        let doubt = match seen {
                            Some(_) => {
                                let v = records.visibility(i, s, masks, false);
                                j += l * v;
                                v.min(1.0 - v).max(0.0)
                            }
                            None => 1.0,
                        };
                        risk += l * doubt;
                    }
                    if code == decided_code {
                        *image_out = finish(i, base);
                    }
                    (*base_out, *code_out) = (base, code);
                    *risk_out = (risk * risk / (j * j + 1e-2)) as f32;
                })
        })?;
        let rays_of = |code: u32| -> usize {
            (0..n)
                .filter(|&s| cell_code(code, s) == UNTRACED)
                .map(|s| bright.aims.get(s).map_or(0, Vec::len))
                .sum()
        };
        // Pixels with undecided cells, their rays and risk, in pixel order.
        let undecided: Vec<(u32, usize, f32)> = match scene {
            Some(_) => with_threads(threads, || {
                codes
                    .par_iter()
                    .zip(&risks)
                    .enumerate()
                    .with_min_len(4096)
                    .filter(|(_, (&code, _))| code != decided_code)
                    .map(|(i, (&code, &risk))| (i as u32, rays_of(code), risk))
                    .collect()
            })?,
            _ => Vec::new(),
        };
        let mut out = Self {
            base,
            image,
            codes,
            rays: scene.map(|_| 0),
            traced_pixels: 0,
            judged: None,
        };
        let Some(scene) = scene.filter(|_| !undecided.is_empty()) else {
            return Ok(out);
        };
        // The pixels to trace (ascending) and the judge's sample among them.
        let wanted: usize = undecided.iter().map(|u| u.1).sum();
        let (traced, sample): (Vec<u32>, Vec<u32>) = if wanted <= budget {
            (undecided.iter().map(|u| u.0).collect(), Vec::new())
        } else {
            // About half the budget's rays for the sample.
            let stride = (2 * wanted).div_ceil(budget);
            // Risks are >= 0, so their bits order as they do: one integer key, the
            // sample first, ties to the lower pixel.
            let mut keys: Vec<(u64, usize)> = undecided
                .iter()
                .enumerate()
                .map(|(k, &(i, rays, risk))| {
                    let risk = if k % stride == 0 { f32::INFINITY } else { risk };
                    (u64::from(!risk.to_bits()) << 32 | u64::from(i), rays)
                })
                .collect();
            // The riskiest pixels whose rays fit the budget (each traces at least one,
            // so no more than `budget` pixels can).
            if budget < keys.len() {
                keys.select_nth_unstable(budget);
                keys.truncate(budget);
            }
            keys.sort_unstable();
            let sampled = u64::from(!f32::INFINITY.to_bits());
            let (mut spent, mut traced, mut sample) = (0, Vec::new(), Vec::new());
            for &(key, rays) in &keys {
                let in_sample = key >> 32 == sampled;
                if spent + rays > budget {
                    break;
                }
                spent += rays;
                traced.push(key as u32);
                if in_sample {
                    sample.push(key as u32);
                }
            }
            traced.sort_unstable();
            sample.sort_unstable();
            (traced, sample)
        };
        let (mut origins, mut directions) = (Vec::new(), Vec::new());
        for &i in &traced {
            let (position, at) = point(i as usize).expect("an undecided pixel has a point");
            let origin = scene.offset_point(position, at.normal).to_array();
            let code = out.codes[i as usize];
            for s in (0..n).filter(|&s| cell_code(code, s) == UNTRACED) {
                for &(d, _) in &bright.aims[s] {
                    origins.push(origin);
                    directions.push(d.to_array());
                }
            }
        }
        let occluded = scene.occluded(&RayBatch::new(&origins, &directions), threads)?;
        out.rays = Some(occluded.len() as u64);
        out.traced_pixels = traced.len();
        let mut answers = occluded.iter();
        for &i in &traced {
            let code = &mut out.codes[i as usize];
            let untraced = *code;
            for s in (0..n).filter(|&s| cell_code(untraced, s) == UNTRACED) {
                let open: u32 = bright.aims[s]
                    .iter()
                    .zip(answers.by_ref())
                    .filter(|(_, &blocked)| !blocked)
                    .map(|(&(_, shares), _)| u32::from(shares))
                    .sum();
                *code ^= (UNTRACED ^ open) << (CODE_BITS * s as u32);
            }
        }
        if !sample.is_empty() {
            let kept = &out;
            let errors: Vec<[f64; 2]> = with_threads(threads, || {
                sample
                    .par_iter()
                    .map(|&i| {
                        let i = i as usize;
                        let (_, at) = point(i).expect("an undecided pixel has a point");
                        let code = kept.codes[i];
                        let cells: Vec<(usize, f64)> = (0..n)
                            .filter(|&s| cell_code(code, s) != DECIDED)
                            .map(|s| (s, cell_code(code, s) as f64 / AIMS as f64))
                            .collect();
                        let lights: Vec<f64> = cells
                            .iter()
                            .map(|&(s, _)| luminance(bright.light_of(&at, s)))
                            .collect();
                        let by_rays: f64 =
                            cells.iter().zip(&lights).map(|(&(_, v), l)| l * v).sum();
                        let j = luminance(kept.base[i]) + by_rays;
                        [false, true].map(|nearest| {
                            let form: f64 = cells
                                .iter()
                                .zip(&lights)
                                .map(|(&(s, _), l)| l * records.visibility(i, s, masks, nearest))
                                .sum();
                            (form - by_rays).powi(2) / (j * j + 1e-2)
                        })
                    })
                    .collect()
            })?;
            out.judged = Some(FormErrors {
                blend: errors.iter().map(|e| e[0]).sum(),
                nearest: errors.iter().map(|e| e[1]).sum(),
                pixels: errors.len(),
            });
        }
        Ok(out)
    }

    /// The image of `view`: every pixel's [`View::finish`] of its `J` ([`Self::eval`]),
    /// computed again only where a cell was left undecided.
    pub fn image<P, S, F>(
        mut self,
        view: &View<'_, P, S, F>,
        nearest: bool,
        threads: Option<usize>,
    ) -> Result<Vec<[f32; 3]>>
    where
        P: Fn(usize) -> Option<(glam::Vec3, Shading)> + Sync,
        S: Fn(usize) -> [f64; 3] + Sync,
        F: Fn(usize, [f64; 3]) -> [f32; 3] + Sync,
    {
        let decided_code = decided_code(view.bright.cells.len());
        let mut image = std::mem::take(&mut self.image);
        with_threads(threads, || {
            image
                .par_iter_mut()
                .zip(&self.codes)
                .enumerate()
                .with_min_len(1024)
                .filter(|(_, (_, &code))| code != decided_code)
                .for_each(|(i, (colour, _))| {
                    if let Some((_, at)) = (view.point)(i) {
                        let j = self.eval(i, || at, view.bright, view.records, view.masks, nearest);
                        *colour = (view.finish)(i, j);
                    }
                })
        })?;
        Ok(image)
    }

    /// Pixel `i`'s `J` (shaded `at`, asked for only where needed): the transfer's and the
    /// agreed cells', plus its undecided cells' by their rays or, untraced, with `Ṽ` in
    /// the form `nearest` names.
    pub fn eval(
        &self,
        i: usize,
        at: impl FnOnce() -> Shading,
        bright: &BrightCells,
        records: &PixelRecords,
        masks: &[u8],
        nearest: bool,
    ) -> [f64; 3] {
        let mut out = self.base[i];
        let code = self.codes[i];
        let n = bright.cells.len();
        if (0..n).all(|s| cell_code(code, s) == DECIDED) {
            return out;
        }
        let at = at();
        for s in (0..n).filter(|&s| cell_code(code, s) != DECIDED) {
            let v = match cell_code(code, s) {
                UNTRACED => records.visibility(i, s, masks, nearest),
                open => open as f64 / AIMS as f64,
            };
            if v > 0.0 {
                let l = bright.light_of(&at, s);
                for c in 0..3 {
                    out[c] += l[c] * v;
                }
            }
        }
        out
    }
}
