//! How [`super::LightingPreview::prepare`] chooses what to keep: the bases that fit the
//! budget ([`candidates`]), measured against the untruncated transfer on a sample of
//! pixels ([`measure`]), and the form of `Ṽ` measured against records traced at a sample
//! of pixels ([`measure_visibility`]). Both poll the current [`Stop`]: per pixel (a
//! record traced at a fine level is a quarter of a million rays) and per candidate.

use glam::Vec3;
use rayon::prelude::*;

use super::transfer::{self, Basis, Transfer, TransferPoint, TransferSettings};
use super::{bright, BasisChoice, AUTO_SAMPLE, AUTO_SLACK, VISIBILITY_SAMPLE};
use crate::error::Result;
use crate::geometry::Scene;
use crate::lights::envmap::EnvMap;
use crate::stop::Stop;
use crate::visibility::cache::VisibilityCache;

/// The bases [`super::LightingPreview::prepare`] may keep for `choice` at full level `level`,
/// with `whole` bytes a pixel for the whole transfer and `truncated` for a truncated one
/// (which keeps the pixel's records too); finest first, empty when none fits.
pub(super) fn candidates(
    level: u32,
    whole: usize,
    truncated: usize,
    choice: BasisChoice,
) -> Vec<Basis> {
    let full = Basis::Texels { level };
    let full = (full.bytes_per_pixel() <= whole).then_some(full);
    let texels = (1..level)
        .rev()
        .map(|l| Basis::Texels { level: l })
        .find(|b| b.bytes_per_pixel() <= truncated);
    let terms = (truncated.saturating_sub(4) / 4).min(1 << (2 * level)) as u32;
    let haar = (terms >= 1).then_some(Basis::Haar { terms });
    let sh = (1..=transfer::MAX_SH_ORDER)
        .rev()
        .map(|order| Basis::Sh { order })
        .find(|b| b.bytes_per_pixel() <= truncated);
    match choice {
        BasisChoice::Full => full.into_iter().collect(),
        BasisChoice::Texels => texels.into_iter().collect(),
        BasisChoice::Haar => haar.into_iter().collect(),
        BasisChoice::Sh => sh.into_iter().collect(),
        BasisChoice::Auto if full.is_some() => full.into_iter().collect(),
        BasisChoice::Auto => texels.into_iter().chain(haar).chain(sh).collect(),
    }
}

/// A sun-and-sky map to measure candidates under when the caller gives none: both a
/// smooth sky and a sharp, bright sun (a third of the power).
pub(super) fn probe_map() -> Result<EnvMap> {
    crate::lights::procedural::sky(
        Vec3::new(0.5, 0.6, 0.3),
        [2000.0, 1800.0, 1500.0],
        2.0,
        [0.3, 0.45, 0.9],
        [0.8, 0.85, 0.9],
        128,
    )
}

/// [`BasisChoice::Auto`]'s measurement: the error of each candidate on up to
/// [`AUTO_SAMPLE`] pixels spread over the view, against the untruncated transfer under
/// `env`; returns the one to keep ([`cheapest_within_slack`]) and every figure. Stops with
/// [`crate::Error::Interrupted`] once the current [`Stop`] is set.
pub(super) fn measure(
    points: &[Option<TransferPoint>],
    cache: &VisibilityCache,
    settings: &TransferSettings,
    level: u32,
    candidates: &[Basis],
    env: &EnvMap,
    (cells, bright, masks): (&[[f64; 3]], &bright::BrightCells, &[u8]),
) -> Result<(Basis, Vec<(Basis, f64)>)> {
    let stop = Stop::current();
    let sample = spread(points, AUTO_SAMPLE);
    let full = Transfer::build(
        &sample,
        cache,
        *settings,
        level,
        Basis::Texels { level },
        None,
    )?;
    let full_light = full.light(env, None)?;
    let reference: Vec<[f64; 3]> = (0..sample.len())
        .map(|i| full.eval(i, &full_light))
        .collect();
    let power: [f64; 3] =
        std::array::from_fn(|c| reference.iter().map(|j| j[c] * j[c]).sum::<f64>());
    let records = bright::PixelRecords::gather(&sample, &cache.read(), cache.params())?;
    let weights = transfer::level_weights(cells);
    let mut measured = Vec::new();
    for &basis in candidates {
        stop.check(WHAT)?;
        let t = Transfer::build(
            &sample,
            cache,
            *settings,
            level,
            basis,
            Some(weights.clone()),
        )?;
        let light = t.light_for(env, None, cells.to_vec(), bright)?;
        let mut err = [0.0f64; 3];
        for (i, r) in reference.iter().enumerate() {
            let mut j = t.eval(i, &light);
            if let (Some(p), true) = (&sample[i], t.has_row(i)) {
                let b = records.eval(i, &p.shading(), bright, masks, settings.nearest);
                j = std::array::from_fn(|c| j[c] + b[c]);
            }
            for c in 0..3 {
                err[c] += (j[c] - r[c]).powi(2);
            }
        }
        let worst = (0..3)
            .map(|c| {
                if power[c] > 0.0 {
                    err[c] / power[c]
                } else {
                    0.0
                }
            })
            .fold(0.0, f64::max);
        measured.push((basis, worst));
    }
    Ok((cheapest_within_slack(&measured), measured))
}

/// The basis with the fewest bytes a pixel (what a change reads) among `measured`'s whose
/// error is within [`AUTO_SLACK`] of the least; the lesser error breaks a tie.
pub(super) fn cheapest_within_slack(measured: &[(Basis, f64)]) -> Basis {
    let least = measured.iter().map(|m| m.1).fold(f64::INFINITY, f64::min);
    measured
        .iter()
        .filter(|m| m.1 <= AUTO_SLACK * least)
        .min_by(|a, b| {
            let bytes = |m: &(Basis, f64)| m.0.bytes_per_pixel();
            bytes(a).cmp(&bytes(b)).then(a.1.total_cmp(&b.1))
        })
        .map(|m| m.0)
        .expect("at least one candidate")
}

/// What a stopped measurement names.
const WHAT: &str = "LightingPreview.prepare";

/// The level of the records [`measure_visibility`] traces for a transfer of `level`:
/// twice the resolution (four rays a cell: a record of the cache's own resolution would
/// make a record at the pixel look exact when one ray a cell is itself a noisy estimate).
pub(super) fn sample_level(level: u32) -> u32 {
    (level + 1).min(crate::sampling::pattern::MAX_LOG2_RESOLUTION)
}

/// [`super::TransferRequest::choose_visibility`]'s measurement: at up to [`VISIBILITY_SAMPLE`]
/// pixels with records, the whole transfer's `J` under `env` with the cache's blend of
/// records and with the heaviest record alone, against `J` with a record traced now at the
/// pixel ([`sample_level`]); returns both errors in the relMSE of the images
/// (`Σ (Δ c J)² / ((c J)² + 0.01)` over pixels and channels, `c` the channel ratio). The
/// bright cells enter every `J` exactly (a shadow ray each): where the records disagree on
/// them each lighting traces rays ([`super::edges`]), so this measurement decides the rest.
/// Stops with [`crate::Error::Interrupted`] within a pixel of the current [`Stop`] being
/// set.
pub(super) fn measure_visibility(
    scene: &Scene,
    points: &[Option<TransferPoint>],
    cache: &VisibilityCache,
    settings: &TransferSettings,
    level: u32,
    (light, bright): (&[[f64; 3]], &bright::BrightCells),
) -> Result<VisibilityErrors> {
    const FLOOR: f64 = 1e-2;
    let pixels = spread_indices(points, VISIBILITY_SAMPLE);
    let pattern = crate::sampling::pattern::default_pattern(sample_level(level))?;
    let state = cache.read();
    let frame = state.frame();
    let params = cache.params();
    let blend = TransferSettings {
        nearest: false,
        ..*settings
    };
    let nearest = TransferSettings {
        nearest: true,
        ..*settings
    };
    let stop = Stop::current();
    let per_point: Vec<Result<Option<[f64; 2]>>> = pixels
        .par_iter()
        .map(|&i| {
            if stop.is_set() {
                return Ok(None);
            }
            let p = points[i].as_ref().expect("spread picks covered pixels");
            let (record, _) = crate::visibility::record::Record::trace_with(
                scene, p.position, p.normal, pattern, frame, false,
            )?;
            let n = 1usize << (2 * level);
            let mut dense = vec![0.0; n];
            let ratios = p.material.channel_ratios();
            let origin = scene.offset_point(p.position, p.normal);
            let mut counters = crate::geometry::TraversalCounters::default();
            let sun = bright.light(&p.shading(), |s| {
                let blocked = scene.occluded1(origin, bright.dirs[s], f32::INFINITY, &mut counters);
                if blocked {
                    0.0
                } else {
                    1.0
                }
            });
            scene.add_counters(counters);
            let j = |dense: &[f64]| -> [f64; 3] {
                std::array::from_fn(|c| {
                    let smooth = dense.iter().zip(light).map(|(t, l)| t * l[c]).sum::<f64>();
                    ratios[c] as f64 * (smooth + sun[c])
                })
            };
            let mut builder = transfer::PixelTransfer::new(&state, params, blend, level);
            if !builder.dense(p, &mut dense) {
                return Ok(None);
            }
            let j_blend = j(&dense);
            let mut builder = transfer::PixelTransfer::new(&state, params, nearest, level);
            builder.dense(p, &mut dense);
            let j_nearest = j(&dense);
            builder.dense_with(p, &[(record.bits.view(), 1.0)], &mut dense);
            let exact = j(&dense);
            let err = |x: [f64; 3]| -> f64 {
                (0..3)
                    .map(|c| (x[c] - exact[c]).powi(2) / (exact[c] * exact[c] + FLOOR))
                    .sum()
            };
            Ok(Some([err(j_blend), err(j_nearest)]))
        })
        .collect();
    stop.check(WHAT)?;
    let mut errors = Vec::new();
    for r in per_point {
        if let Some(e) = r? {
            errors.push(e.map(|x| x / 3.0));
        }
    }
    let n = errors.len().max(1) as f64;
    let mean = |k: usize| errors.iter().map(|e| e[k]).sum::<f64>() / n;
    // The paired differences' standard error: a pixel's two errors share its lighting.
    let diff: Vec<f64> = errors.iter().map(|e| e[0] - e[1]).collect();
    let d = diff.iter().sum::<f64>() / n;
    let var = diff.iter().map(|x| (x - d).powi(2)).sum::<f64>() / (n - 1.0).max(1.0);
    Ok(VisibilityErrors {
        blend: mean(0),
        nearest: mean(1),
        standard_error: (var / n).sqrt(),
    })
}

/// What [`measure_visibility`] finds: the relMSE of each form of `Ṽ` and the standard
/// error of their difference.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VisibilityErrors {
    pub blend: f64,
    pub nearest: f64,
    pub standard_error: f64,
}

impl VisibilityErrors {
    /// The nearest record wins when its mean error is lower. (Per-pixel relative errors
    /// are heavy-tailed — a few dark pixels lit by a neighbour's record — so the standard
    /// error is wide and a two-SE rule kept the blend even on hairball, where the nearest
    /// record's image has a tenth of its relMSE; 1024 pixels made the plain comparison
    /// right on the five scenes probed.)
    pub fn prefers_nearest(&self) -> bool {
        self.nearest < self.blend
    }
}

/// Up to `n` of the view's surface points, spread evenly over it (every k-th).
pub(super) fn spread(points: &[Option<TransferPoint>], n: usize) -> Vec<Option<TransferPoint>> {
    spread_indices(points, n)
        .into_iter()
        .map(|i| points[i])
        .collect()
}

/// The pixels [`spread`] picks.
pub(super) fn spread_indices(points: &[Option<TransferPoint>], n: usize) -> Vec<usize> {
    let covered = points.iter().filter(|p| p.is_some()).count();
    let step = covered.div_ceil(n).max(1);
    (0..points.len())
        .filter(|&i| points[i].is_some())
        .step_by(step)
        .collect()
}
