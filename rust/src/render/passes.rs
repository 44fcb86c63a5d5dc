//! The pass driver: runs a [`PixelEstimator`]'s passes over an image and owns everything
//! about them that is not the method's — how many samples each pixel takes in each pass
//! (even counts, the probe and the passes a time budget fits, adaptive counts after a
//! pilot), the bands the workers take, progress, Ctrl-C (a `false` from the progress
//! callback), the figures the pass schedule and the stats need, and the determinism of the
//! result: a pixel is shaded by one worker per pass, in sample order, and every decision
//! between passes is made on the calling thread from sums in pixel order. A worker takes a
//! band of whole rows and hands it to [`PixelPass::shade_band`]: pixel by pixel unless the
//! method shades groups of pixels together (tiles), which must not change a pixel's values.
//!
//! ## Passes
//! Without a time budget the render is one pass of `spp` samples per pixel. With one, a
//! probe pass takes `PassSchedule::PROBE_SPP` (4) samples in every
//! `PassSchedule::PROBE_STRIDE`-th (8th) band of pixels; from its timing the driver models a
//! pixel's cost as its set-up plus a cost per sample, and the main pass brings every pixel
//! to the most samples that fit the budget left (the pass schedule); another follows only
//! when a whole sample per pixel still fits. With adaptive counts the main pass is a pilot
//! of a quarter of its samples, after which each pixel takes a share of the rest measured
//! from its neighbours' samples ([`super::adaptive`]); without a budget the same two passes spend
//! `spp` samples per pixel on average.

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use rayon::prelude::*;

use super::adaptive::{pilot_spp, sample_cap, SampleShares};
use super::estimator::{BandPixel, Merge, PassPlan, PixelEstimator, PixelPass, PixelTiming};
use super::schedule::{PassSchedule, PassWork};
use super::sums::PixelSums;
use super::MAX_SPP;
use crate::error::Result;
use crate::parallel::run_with_progress;
use crate::stop::Stop;

/// Rows per work item of a pass with even counts: small enough to balance two to hundreds
/// of threads. A band starts at a multiple of it ([`PixelPass::shade_band`]).
pub const BAND_ROWS: usize = 4;

/// How many samples the driver takes, and for how long.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PassParams {
    /// Samples per pixel (on average, with [`Self::adaptive`] counts); with a time budget,
    /// the most to take.
    pub spp: u32,
    /// Stop after the first pass that ends past this many seconds from `start` (the
    /// render's start, set-up included).
    pub time_budget: Option<f64>,
    /// Adaptive per-pixel counts after a pilot ([`super::adaptive`]).
    pub adaptive: bool,
    /// Under a time budget: a first pass that brings every pixel to this many samples,
    /// whatever the budget, instead of the probe (the passes after it are sized by its
    /// timing). For a method whose first samples are a minimum it promises (the
    /// relighter's `lbv_spp`); `None`: the probe.
    pub first_spp: Option<u32>,
}

/// What the passes left: every pixel's sums, the methods' counters added up, and how the
/// passes went.
#[derive(Clone, Debug)]
pub struct PassRun<S, W> {
    /// Row-major, one per pixel.
    pub sums: Vec<S>,
    /// Every band's work of every pass, merged in pass and band order.
    pub total: W,
    /// Passes made.
    pub passes: u32,
    /// False when progress stopped a pass part-way.
    pub complete: bool,
    /// The predicted gain of adaptive counts measured after the pilot
    /// ([`SampleShares::gain`]), when there was one.
    pub adaptive_gain: Option<f64>,
    /// Under a time budget that could not buy every pixel a sample: seconds from `start`
    /// to the end of the pass that gave every pixel its first sample anyway (the
    /// schedule found that none fitted). A budget shorter than this is overrun by the
    /// difference: a pixel's sample is the one step it cannot divide. `None` when every
    /// pixel's first sample fitted.
    pub first_sample_seconds: Option<f64>,
}

impl<S: PixelSums, W> PassRun<S, W> {
    /// Samples each pixel took, row-major.
    pub fn counts(&self) -> Vec<u32> {
        self.sums.iter().map(|s| s.samples()).collect()
    }

    /// The least samples any pixel took.
    pub fn min_spp(&self) -> u32 {
        self.sums.iter().map(|s| s.samples()).min().unwrap_or(0)
    }

    /// The most samples any pixel took.
    pub fn max_spp(&self) -> u32 {
        self.sums.iter().map(|s| s.samples()).max().unwrap_or(0)
    }

    /// Pixel samples taken.
    pub fn samples(&self) -> u64 {
        self.sums.iter().map(|s| s.samples() as u64).sum()
    }

    /// Samples per pixel on average.
    pub fn mean_spp(&self) -> f64 {
        self.sums.iter().map(|s| s.samples() as f64).sum::<f64>() / self.sums.len().max(1) as f64
    }
}

/// The sample count a pass brings each pixel up to.
enum Targets {
    /// Every pixel the same.
    Even(u32),
    /// Per pixel, row-major ([`super::adaptive`]).
    PerPixel(Vec<u32>),
}

impl Targets {
    /// `shares` at scale `lambda` over the pixels' `current` counts.
    fn scaled(shares: &SampleShares, lambda: f64, current: &[u32], cap: u32) -> Self {
        Self::PerPixel(
            current
                .iter()
                .enumerate()
                .map(|(i, &n)| shares.target(i, lambda, n, cap))
                .collect(),
        )
    }

    fn of(&self, pixel: usize) -> u32 {
        match self {
            Self::Even(t) => *t,
            Self::PerPixel(t) => t[pixel],
        }
    }

    /// Samples the pass adds to pixels at `current`.
    fn added(&self, current: &[u32]) -> u64 {
        current
            .iter()
            .enumerate()
            .map(|(i, &n)| self.of(i).saturating_sub(n) as u64)
            .sum()
    }
}

/// What the driver keeps of a pixel across passes.
#[derive(Clone, Debug)]
struct PixelState<N> {
    /// CPU nanoseconds per sample of the pixel's latest pass (NaN before any).
    ns_per_sample: f32,
    /// The method's note ([`PixelEstimator::Note`]).
    note: N,
}

impl<N: Default> Default for PixelState<N> {
    fn default() -> Self {
        Self {
            ns_per_sample: f32::NAN,
            note: N::default(),
        }
    }
}

/// Runs `estimator`'s passes over a `width x height` image (module docs) on `threads`
/// workers (`None`: all cores). `progress(done, planned)` (pixel samples) is called on the
/// calling thread about every 0.1 s and after each pass; a `false` stops the pass under way
/// (pixels not started keep the samples they had) and the render. `start` is when the
/// render began: the budget counts from it. Ctrl-C (the current [`Stop`]) stops the pass
/// under way as a `false` does.
pub fn run_passes<E: PixelEstimator>(
    estimator: &mut E,
    width: usize,
    height: usize,
    params: &PassParams,
    start: Instant,
    threads: Option<usize>,
    progress: &mut (dyn FnMut(u64, u64) -> bool + Send),
) -> Result<PassRun<E::Sums, E::Work>> {
    let pixels = width * height;
    let mut sums = vec![E::Sums::default(); pixels];
    let mut total = E::Work::default();
    let mut passes = 0u32;
    let mut complete = true;
    let planned = params.spp as u64 * pixels as u64;
    let done = AtomicU64::new(0);
    // Ctrl-C (the current stop) or a `false` from progress: the pass under way stops.
    let cancel = Stop::current().child(None);
    let mut schedule = PassSchedule::default();
    let mut taken = 0u64;
    // Adaptive renders: the shares measured after the pilot pass, the most samples a
    // pixel may take, and each pixel's CPU nanoseconds per sample in its latest pass.
    let adapt = params.adaptive && E::ADAPTS;
    let mut shares: Option<(SampleShares, u32)> = None;
    let mut pixel_state = vec![PixelState::<E::Note>::default(); pixels];
    let mut adaptive_gain = None;
    let mut first_sample_seconds = None;
    let counts = |sums: &[E::Sums]| sums.iter().map(|s| s.samples()).collect::<Vec<u32>>();
    loop {
        // Each pass brings the pixels it covers up to their target.
        let mut pilot = None;
        // The pass that gives every pixel a sample though the budget fits none.
        let mut forced = false;
        let (targets, probe) = match params.time_budget {
            None if passes == 0 => match pilot_spp(params.spp).filter(|_| adapt) {
                Some(p) => {
                    pilot = Some(sample_cap(params.spp, MAX_SPP));
                    (Targets::Even(p), false)
                }
                None => (Targets::Even(params.spp), false),
            },
            // The adaptive pass of a render of `spp` samples per pixel on average: the
            // budget is the samples left.
            None if passes == 1 && shares.is_some() => {
                let (shares, cap) = shares.as_ref().expect("measured after the pilot");
                let current = counts(&sums);
                let left = planned.saturating_sub(taken) as f64;
                let lambda = shares.scale_for(&current, *cap, left, |_, added| added as f64);
                (Targets::scaled(shares, lambda, &current, *cap), false)
            }
            None => break,
            Some(_) if passes == 0 => match params.first_spp {
                Some(first) => (Targets::Even(first.min(params.spp)), false),
                None => (Targets::Even(PassSchedule::PROBE_SPP.min(params.spp)), true),
            },
            Some(budget) => {
                let left = budget - start.elapsed().as_secs_f64();
                let min = sums.iter().map(|s| s.samples()).min().unwrap_or(0);
                let done_all = match shares {
                    Some(_) => taken >= planned,
                    None => min >= params.spp,
                };
                if done_all {
                    break;
                }
                match &shares {
                    Some((shares, cap)) => {
                        let current = counts(&sums);
                        let (per_pixel, wall_ns) =
                            (schedule.anchor_seconds(), schedule.wall_per_cpu_ns());
                        let mean_ns = schedule.sample_ns_mean();
                        let cost = |i: usize, added: u32| {
                            let ns = match pixel_state[i].ns_per_sample {
                                ns if ns.is_finite() => ns as f64,
                                _ => mean_ns,
                            };
                            per_pixel + wall_ns * ns * added as f64
                        };
                        let by_time = shares.scale_for(&current, *cap, schedule.spend(left), cost);
                        let left_samples = planned.saturating_sub(taken) as f64;
                        let by_count =
                            shares.scale_for(&current, *cap, left_samples, |_, a| a as f64);
                        let t = Targets::scaled(shares, by_time.min(by_count), &current, *cap);
                        // A pass is worth its anchors when it adds a sample per pixel on
                        // average.
                        if t.added(&current) < pixels as u64 {
                            break;
                        }
                        (t, false)
                    }
                    None => match schedule.next_target(left, pixels as u64, taken, min) {
                        Some(t) => {
                            let t = t.min(params.spp);
                            match pilot_spp(t).filter(|&p| adapt && p > min) {
                                Some(p) => {
                                    pilot = Some(sample_cap(t, MAX_SPP));
                                    (Targets::Even(p), false)
                                }
                                None => (Targets::Even(t), false),
                            }
                        }
                        // Every pixel gets a sample, whatever the budget.
                        None if min == 0 => {
                            forced = true;
                            (Targets::Even(1), false)
                        }
                        None => break,
                    },
                }
            }
        };
        // Adaptive counts make some rows cost many times others: rows one by one keep
        // the threads busy to the end.
        let rows = match targets {
            Targets::PerPixel(_) => 1,
            Targets::Even(_) => BAND_ROWS,
        };
        let plan = PassPlan {
            index: passes,
            probe,
            pilot: pilot.is_some(),
        };
        let pass_start = Instant::now();
        // The probe spends at most its share of the budget left: a method whose samples
        // are dear (thousands of VPLs each) would spend more on the probe than the budget.
        // A method that learns from it takes it whole (PixelEstimator::LEARNS_FROM_PROBE).
        let probe_deadline = params
            .time_budget
            .filter(|_| probe && !E::LEARNS_FROM_PROBE);
        let probe_deadline = probe_deadline.map(|b| {
            let left = (b - start.elapsed().as_secs_f64()).max(0.0);
            pass_start + Duration::from_secs_f64(PassSchedule::PROBE_SHARE * left)
        });
        let bands = estimator.pass(&plan, |shader| {
            run_with_progress(
                threads,
                || {
                    sums.par_chunks_mut(rows * width.max(1))
                        .zip(pixel_state.par_chunks_mut(rows * width.max(1)))
                        .enumerate()
                        // Every band a task of its own: rayon's default splits the bands
                        // into a few runs per thread, and a thread that ends its runs first
                        // cannot take part of another's (measured: 13% of a pass idle on
                        // cornell).
                        .with_max_len(1)
                        .map(|(band, (band_sums, band_state))| {
                            let mut work = E::Work::default();
                            let mut tally = PassWork::default();
                            if cancel.is_set()
                                || (probe && band % PassSchedule::PROBE_STRIDE != 0)
                                || probe_deadline.is_some_and(|d| Instant::now() >= d)
                            {
                                return (work, tally);
                            }
                            let first = band * rows * width;
                            let before: Vec<u32> = band_sums.iter().map(|s| s.samples()).collect();
                            let mut band_pixels: Vec<_> = band_sums
                                .iter_mut()
                                .zip(band_state.iter_mut())
                                .enumerate()
                                .map(|(i, (acc, state))| BandPixel {
                                    pixel: first + i,
                                    target: targets.of(first + i),
                                    acc,
                                    note: &mut state.note,
                                    timing: Default::default(),
                                })
                                .collect();
                            shader.shade_band(&mut band_pixels, &mut work, &|| cancel.is_set());
                            // What each pixel took, counted from its sums.
                            let taken: Vec<_> = band_pixels
                                .iter()
                                .zip(&before)
                                .map(|(p, &n)| (p.acc.samples().saturating_sub(n), p.timing))
                                .collect();
                            // A pixel shaded (samples added, or a visit of its set-up alone:
                            // [`PixelSums::due`]) counts its set-up; one that took samples
                            // gives its cost per sample.
                            for (state, (added, timing)) in band_state.iter_mut().zip(taken) {
                                if added > 0 || timing != PixelTiming::default() {
                                    tally.samples += added as u64;
                                    tally.anchored_pixels += 1;
                                    tally.anchor_ns += timing.anchor_ns;
                                    tally.sample_ns += timing.sample_ns;
                                }
                                if added > 0 {
                                    state.ns_per_sample = timing.sample_ns as f32 / added as f32;
                                }
                            }
                            done.fetch_add(tally.samples, Ordering::Relaxed);
                            (work, tally)
                        })
                        .collect::<Vec<(E::Work, PassWork)>>()
                },
                &mut || {
                    let keep = progress(done.load(Ordering::Relaxed), planned);
                    if !keep {
                        cancel.set();
                    }
                    keep
                },
            )
        })?;
        let mut pass = PassWork::default();
        let mut works = Vec::with_capacity(bands.len());
        for (work, tally) in bands {
            pass += tally;
            works.push(work);
        }
        estimator.end_pass(&plan, &works, &sums);
        for w in works {
            total.merge(w);
        }
        passes += 1;
        taken += pass.samples;
        if forced {
            first_sample_seconds = Some(start.elapsed().as_secs_f64());
        }
        schedule.record(pass_start.elapsed().as_secs_f64(), pass);
        if let Some(cap) = pilot {
            // Under a budget, a sample's cost counts too: sky is cheap, grass is not.
            let ns: Vec<f32> = pixel_state.iter().map(|p| p.ns_per_sample).collect();
            let costs = params.time_budget.map(|_| &ns[..]);
            let measured = estimator
                .shares(&sums, costs, width, height)
                .expect("a method that adapts measures shares");
            let notes: Vec<E::Note> = pixel_state.iter().map(|p| p.note.clone()).collect();
            estimator.after_pilot(&notes, width, height);
            adaptive_gain = Some(measured.gain());
            shares = Some((measured, cap));
        }
        if cancel.is_set() {
            complete = false;
            break;
        }
        let keep_going = progress(done.load(Ordering::Relaxed), planned);
        // Every pixel gets a sample, whatever the budget: a probe pass alone leaves most
        // of them at none.
        let unsampled = sums.iter().any(|s| s.samples() == 0);
        let over_budget = params
            .time_budget
            .is_some_and(|b| start.elapsed().as_secs_f64() >= b && !unsampled);
        if !keep_going || over_budget {
            break;
        }
    }
    Ok(PassRun {
        sums,
        total,
        passes,
        complete,
        adaptive_gain,
        first_sample_seconds,
    })
}

#[cfg(test)]
mod tests;
