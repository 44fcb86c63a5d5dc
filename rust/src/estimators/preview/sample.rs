//! A spread of the view's pixels at which each lighting's bright cells are judged.
//!
//! Which form of `Ṽ` serves a sun better — the cache's blend of records or the heaviest
//! record alone — depends on the scene and on where the sun stands: on garden the blend
//! wins with the map turned by 135° (relMSE 0.51 against 0.73 at 160x120) and the
//! heaviest record with it turned by 45° (0.35 against 0.46); under a sun and sky the
//! heaviest record wins on instances (0.023 against 0.12) and the blend on room (0.34
//! against 0.48). A sun's light enters a pixel through one direction, so one choice made
//! at preparation cannot serve every lighting. Each lighting change therefore evaluates
//! the bright cells at up to [`super::JUDGE_SAMPLE`] pixels in both forms and with a
//! shadow ray toward each, and keeps the form closer to the rays for the whole image:
//! at most [`super::bright::MAX_BRIGHT`] rays a sample pixel, none elsewhere.
//!
//! Two cheaper judges chose wrong. Against a record traced at each pixel at preparation
//! (no ray per change), where visibility changes within a record texel (garden's grass,
//! dynamics): the record's ray leaves up to a texel's width from the sun, and the
//! cache's records look along the same texel directions, so they agree with it more
//! than with the sun. With 1024 pixels instead of 16384, on room's sun and sky: few
//! sample pixels lie on the edges of the sun patches, where the forms differ, and the
//! choice flipped to the heaviest record (0.48 against 0.34 with the blend).

use glam::Vec3;

use super::bright::{BrightCells, PixelRecords, Shading};
use crate::geometry::{Scene, TraversalCounters};

/// What [`judge`] finds under one lighting: the bright cells' error in each form, in the
/// images' relMSE summed over the sample pixels, and the shadow rays it traced.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BrightErrors {
    pub blend: f64,
    pub nearest: f64,
    pub rays: u64,
}

impl BrightErrors {
    /// The heaviest record wins when its error is lower.
    pub fn prefers_nearest(&self) -> bool {
        self.nearest < self.blend
    }
}

/// The error of `bright`'s light at `pixels` (`point`: position and shading) in each form
/// of `Ṽ` against shadow rays in `scene`, per pixel `Σ_c (c ΔJ)² / ((c J)² + 0.01)` (`c` the channel ratio) with
/// `J = smooth(i) +` the bright light by the rays. Pixels without `smooth` (no
/// transfer) are skipped. Per-pixel errors are summed in pixel order: the same for
/// any thread count.
pub fn judge(
    scene: &Scene,
    pixels: &[usize],
    point: impl Fn(usize) -> Option<(Vec3, Shading)> + Sync,
    records: &PixelRecords,
    bright: &BrightCells,
    masks: &[u8],
    smooth: impl Fn(usize) -> Option<[f64; 3]> + Sync,
) -> BrightErrors {
    use rayon::prelude::*;
    const FLOOR: f64 = 1e-2;
    let per_pixel: Vec<(f64, f64, u64)> = pixels
        .par_iter()
        .map(|&i| {
            let (Some((position, p)), Some(smooth)) = (point(i), smooth(i)) else {
                return (0.0, 0.0, 0);
            };
            let origin = scene.offset_point(position, p.normal);
            let mut counters = TraversalCounters::default();
            let mut rays = 0u64;
            let exact = bright.light(&p, |s| {
                rays += 1;
                match scene.occluded1(origin, bright.dirs[s], f32::INFINITY, &mut counters) {
                    true => 0.0,
                    false => 1.0,
                }
            });
            scene.add_counters(counters);
            let ratios = p.material.channel_ratios();
            let err = |nearest: bool| -> f64 {
                let b = records.eval(i, &p, bright, masks, nearest);
                (0..3)
                    .map(|c| {
                        let r = ratios[c] as f64;
                        let j = r * (smooth[c] + exact[c]);
                        (r * (b[c] - exact[c])).powi(2) / (j * j + FLOOR)
                    })
                    .sum()
            };
            (err(false), err(true), rays)
        })
        .collect();
    per_pixel.iter().fold(
        BrightErrors {
            blend: 0.0,
            nearest: 0.0,
            rays: 0,
        },
        |a, &(blend, nearest, rays)| BrightErrors {
            blend: a.blend + blend,
            nearest: a.nearest + nearest,
            rays: a.rays + rays,
        },
    )
}
