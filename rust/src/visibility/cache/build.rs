//! Building the cache for a view (§5): the bootstrap, the coherence check, and the
//! insertion waves of §5.2's criteria over the G-buffer ([`WaveBuilder`]); the one-pass
//! mode's insertion of handed-over points, and insertion on the fly.

use std::ops::{Deref, DerefMut};
use std::sync::atomic::Ordering;
use std::time::Instant;

use glam::Vec3;
use rayon::prelude::*;

use super::coherence::{pair_step, predicted_gain, predicted_variance_ratio, MapPair};
use super::{check_scene_and_budget, count_rays, CacheState, VisibilityCache};
use crate::camera::{Camera, GBuffer};
use crate::error::Result;
use crate::geometry::Scene;
use crate::parallel::with_threads;
use crate::sampling::pattern::default_pattern;
use crate::sampling::rng::SampleRng;
use crate::spatial::waves::{coarse_to_fine_levels, WaveBuilder, WaveTarget};
use crate::stop::Stop;
use crate::visibility::params::{record_cap, COHERENCE_LOG2_RESOLUTION, COHERENCE_PAIRS};
use crate::visibility::record::{Record, RecordRays, RecordTracing};

/// What [`VisibilityCache::build`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BuildReport {
    /// Records in the cache afterwards.
    pub records: usize,
    /// Records the bootstrap inserted (0 when the cache was not empty).
    pub bootstrap_records: usize,
    /// Records the G-buffer pass inserted.
    pub refined_records: usize,
    /// Records traced by a wave but found unneeded on re-check (their rays are counted).
    pub discarded_records: usize,
    /// Pixels of the camera.
    pub pixels: usize,
    /// Pixels whose primary ray hit something.
    pub covered_pixels: usize,
    /// Record shadow rays traced.
    pub shadow_rays: u64,
    /// Record closest-hit rays traced (for `R_i`).
    pub nearest_rays: u64,
    /// `shadow_rays / pixels`: CAM08 Table 2's amortised cost.
    pub shadow_rays_per_pixel: f64,
    /// Median footprint of the covered pixels (world units; `None` when nothing was hit):
    /// `d_max_scale` times it is a fair search radius for lookups without footprints.
    pub median_footprint: Option<f32>,
    /// Wall-clock seconds.
    pub seconds: f64,
    /// False when the time budget or the progress callback stopped the pass early.
    pub complete: bool,
    /// The coherence check's mean Jaccard distance between the visible sets of its pairs
    /// of records ([`CacheParams::check_coherence`]; `None` when it did not run).
    pub incoherence: Option<f32>,
    /// The control variate's variance over product sampling's that the check predicts
    /// ([`super::coherence::predicted_variance_ratio`]; `None` when it did not run or its
    /// maps saw no occlusion).
    pub predicted_variance_ratio: Option<f32>,
    /// The control variate's efficiency over product sampling's, build included, that the
    /// check predicts ([`super::coherence::predicted_gain`]).
    pub predicted_gain: Option<f32>,
    /// Whether the check predicted that records would not pay (gain below 1: visibility
    /// too incoherent at the records' spacing for the samples they serve) and stopped the
    /// build after it.
    pub incoherent: bool,
    /// Whether the check saw the map through none of its rays (a closed room lit by its
    /// own lights) and stopped the build after it: `Ṽ` would be zero everywhere, so the
    /// control variate would cancel nothing and records would only cost their rays.
    pub blind: bool,
}

impl VisibilityCache {
    /// The on-the-fly path for render threads: looks up at `x`; when §5.2 asks for a record,
    /// traces one (no lock held), then re-checks under the write lock (another thread may
    /// have inserted meanwhile) and inserts it. Returns the id inserted, if any.
    pub fn insert_if_needed(
        &self,
        scene: &Scene,
        x: Vec3,
        n: Vec3,
        d_max: f32,
    ) -> Result<Option<u32>> {
        if !self.lookup(x, n, d_max).needs_record(&self.params) {
            return Ok(None);
        }
        let (record, rays) = self.trace(scene, x, n)?;
        let mut state = self.write();
        count_rays(&mut state.counters, rays);
        if !state
            .lookup(&self.params, x, n, d_max)
            .needs_record(&self.params)
        {
            return Ok(None);
        }
        state.push(&self.params, &record)
    }

    /// Builds the cache for a view (§5): bootstraps `N_startup` records at the first hits of
    /// rays stratified over the image (only when the cache is empty), then passes over the
    /// G-buffer (pixel centres) applying §5.2's two criteria with `d_max = k · footprint`.
    ///
    /// Deterministic for any `threads`: pixels go coarse to fine (every 32nd pixel of every
    /// 32nd row first, then the ones between, …) in waves within a level, of a quarter of
    /// the records (between [`super::MIN_BUILD_WAVE`] and [`super::BUILD_WAVE`] pixels); a
    /// wave looks up in parallel, traces the requested records in parallel, then inserts them
    /// in that order, re-checking each against the records inserted before it (the losers'
    /// rays are still counted; [`WaveBuilder`]). `progress(done, total)` is called after each wave with pixels done;
    /// returning false stops, as does `time_budget` (seconds, checked between waves).
    /// The G-buffer is traced here; [`Self::build_from`] takes one already traced.
    pub fn build(
        &self,
        scene: &Scene,
        camera: &Camera,
        seed: u64,
        threads: Option<usize>,
        time_budget: Option<f64>,
        progress: &mut (dyn FnMut(usize, usize) -> bool + Send),
    ) -> Result<BuildReport> {
        check_scene_and_budget(scene, time_budget)?;
        let start = Instant::now();
        // Ctrl-C reaches the G-buffer through the current stop; `request_stop` only the
        // phases after it.
        let gbuffer = GBuffer::render(scene, camera, seed, false, threads)?;
        self.build_at(scene, &gbuffer, seed, threads, start, time_budget, progress)
    }

    /// [`Self::build`] at the points of `gbuffer` (which must describe `scene` as posed
    /// now), the same ones a render from that buffer anchors its pixels at
    /// ([`crate::render::render_from`]); the bootstrap's rays go through its camera. A
    /// jittered buffer is accepted (records are then inserted at its hits).
    pub fn build_from(
        &self,
        scene: &Scene,
        gbuffer: &GBuffer,
        seed: u64,
        threads: Option<usize>,
        time_budget: Option<f64>,
        progress: &mut (dyn FnMut(usize, usize) -> bool + Send),
    ) -> Result<BuildReport> {
        check_scene_and_budget(scene, time_budget)?;
        gbuffer.check(scene, None)?;
        let start = Instant::now();
        self.build_at(scene, gbuffer, seed, threads, start, time_budget, progress)
    }

    #[allow(clippy::too_many_arguments)]
    fn build_at(
        &self,
        scene: &Scene,
        gbuffer: &GBuffer,
        seed: u64,
        threads: Option<usize>,
        start: Instant,
        time_budget: Option<f64>,
        progress: &mut (dyn FnMut(usize, usize) -> bool + Send),
    ) -> Result<BuildReport> {
        self.bind_scene(scene)?;
        let stop = self.start_stop();
        let camera = &gbuffer.camera;
        let before = self.counters();
        let mut report = BuildReport {
            pixels: camera.num_pixels(),
            complete: true,
            ..BuildReport::default()
        };
        with_threads(threads, || -> Result<()> {
            let mut footprints: Vec<f32> = gbuffer
                .footprint
                .iter()
                .copied()
                .filter(|f| f.is_finite())
                .collect();
            report.covered_pixels = footprints.len();
            if !footprints.is_empty() {
                let mid = footprints.len() / 2;
                report.median_footprint =
                    Some(*footprints.select_nth_unstable_by(mid, f32::total_cmp).1);
            }
            if self.is_empty() && self.params.check_coherence {
                let covered = report.covered_pixels;
                let cap = record_cap(&self.params, covered);
                let check = self.coherence_check(scene, gbuffer, pair_step(covered, cap), &stop)?;
                count_rays(&mut self.write().counters, check.rays);
                report.incoherence = check.incoherence;
                report.predicted_variance_ratio = check.variance_ratio.map(|r| r as f32);
                let per_pixel = cap as f64 / covered.max(1) as f64;
                let gain = check
                    .variance_ratio
                    .map(|r| predicted_gain(r, self.planned_samples(), per_pixel));
                report.predicted_gain = gain.map(|g| g as f32);
                if gain.is_some_and(|g| g < 1.0) {
                    report.incoherent = true;
                    return Ok(());
                }
                if check.incoherence.is_some() && check.visible == 0 {
                    report.blind = true;
                    return Ok(());
                }
            }
            if self.is_empty() {
                report.bootstrap_records = self.bootstrap(scene, camera, seed, &stop)?;
            }
            let levels = coarse_to_fine_levels(camera.width, camera.height)
                .into_iter()
                .map(|level| {
                    level
                        .into_iter()
                        .filter(|&i| gbuffer.object[i as usize] >= 0)
                });
            let k = self.params.d_max_scale;
            stop.check(WHAT)?;
            let target = Refine {
                cache: self,
                stop: &stop,
                max_records: record_cap(&self.params, report.covered_pixels),
                scene,
                query: |i: u32| {
                    let i = i as usize;
                    (
                        Vec3::from(gbuffer.position[i]),
                        Vec3::from(gbuffer.normal[i]),
                        k * gbuffer.footprint[i],
                    )
                },
            };
            let waves = WaveBuilder::new(start, time_budget, progress).run(
                &target,
                levels,
                report.covered_pixels,
            )?;
            report.refined_records += waves.inserted;
            report.discarded_records += waves.discarded;
            report.complete = waves.complete;
            Ok(())
        })??;
        if let Some(f) = report.median_footprint {
            self.write().default_radius = Some(self.params.d_max_scale * f);
        }
        let after = self.counters();
        report.records = self.len();
        report.shadow_rays = after.shadow_rays - before.shadow_rays;
        report.nearest_rays = after.nearest_rays - before.nearest_rays;
        report.shadow_rays_per_pixel = report.shadow_rays as f64 / report.pixels.max(1) as f64;
        report.seconds = start.elapsed().as_secs_f64();
        Ok(report)
    }

    /// `N_startup` records at the first hits of rays through jittered cells of a grid over
    /// the image (as square as the aspect allows); returns how many were inserted.
    fn bootstrap(&self, scene: &Scene, camera: &Camera, seed: u64, stop: &Stop) -> Result<usize> {
        let n = self.params.n_startup as usize;
        if n == 0 {
            return Ok(0);
        }
        let (w, h) = (camera.width as f64, camera.height as f64);
        let cols = ((n as f64 * w / h).sqrt().round() as usize).max(1);
        let rows = n.div_ceil(cols);
        let cells: Vec<usize> = (0..n).collect();
        let traced: Vec<Option<(Record, RecordRays)>> = cells
            .par_iter()
            .map(|&c| {
                // Streams distinct from the G-buffer's: sample index u32::MAX.
                let rng = SampleRng::new(seed, c as u64, u32::MAX as u64);
                let [jx, jy] = rng.get2(0);
                let x = ((c % cols) as f64 + jx as f64) * w / cols as f64;
                let y = ((c / cols) as f64 + jy as f64) * h / rows as f64;
                let d = camera.direction(x as f32, y as f32);
                let mut counters = Default::default();
                let hit = scene.intersect1(camera.eye, d, f32::INFINITY, &mut counters)?;
                let normal = if hit.normal.dot(d) > 0.0 {
                    -hit.normal
                } else {
                    hit.normal
                };
                if let Err(e) = stop.check(WHAT) {
                    return Some(Err(e));
                }
                Some(self.trace(scene, hit.position, normal))
            })
            .map(|r| r.transpose())
            .collect::<Result<_>>()?;
        let mut state = self.write();
        let mut inserted = 0;
        for (record, rays) in traced.into_iter().flatten() {
            count_rays(&mut state.counters, rays);
            inserted += state.push(&self.params, &record)?.is_some() as usize;
        }
        Ok(inserted)
    }

    /// [`CacheParams::check_coherence`]: visibility maps of [`COHERENCE_LOG2_RESOLUTION`]
    /// (16 x 16 directions, a sixteenth of a 64² record's rays; not inserted) at
    /// [`COHERENCE_PAIRS`] pixels on a grid over the image and at their partners `step`
    /// pixels to the side (both surface hits); returns the mean Jaccard distance
    /// `|A ⊕ B| / |A ∪ B|` of the pairs' visible sets and the predicted variance ratio
    /// ([`predicted_variance_ratio`]; both `None` without pairs), the visible directions
    /// summed over all maps and the rays traced. The pairs are fixed by the image and
    /// `step`, so the check is deterministic.
    fn coherence_check(
        &self,
        scene: &Scene,
        g: &GBuffer,
        step: usize,
        stop: &Stop,
    ) -> Result<CoherenceCheck> {
        let (w, h) = (g.width() as usize, g.height() as usize);
        let side = (COHERENCE_PAIRS as f64).sqrt().ceil() as usize;
        let mut pairs = Vec::new();
        for gy in 0..side {
            for gx in 0..side {
                let x = (2 * gx + 1) * w / (2 * side);
                let y = (2 * gy + 1) * h / (2 * side);
                let x2 = if x + step < w {
                    x + step
                } else {
                    x.saturating_sub(step)
                };
                let (a, b) = (y * w + x, y * w + x2);
                if a != b && g.object[a] >= 0 && g.object[b] >= 0 {
                    pairs.push((a, b));
                }
            }
        }
        if pairs.is_empty() {
            return Ok(CoherenceCheck::default());
        }
        let pattern = default_pattern(COHERENCE_LOG2_RESOLUTION)?;
        let map = |i: usize| {
            let (p, n) = (Vec3::from(g.position[i]), Vec3::from(g.normal[i]));
            let tracing = RecordTracing {
                nearest_hits: false,
                ..self.params.record_tracing()
            };
            Record::trace_as(scene, p, n, pattern, 0, tracing)
        };
        let traced: Vec<[(Record, RecordRays); 2]> = pairs
            .par_iter()
            .map(|&(a, b)| {
                stop.check(WHAT)?;
                Ok([map(a)?, map(b)?])
            })
            .collect::<Result<_>>()?;
        let mut distance = 0.0f64;
        let mut check = CoherenceCheck::default();
        let mut shares = Vec::with_capacity(traced.len());
        for [(a, ra), (b, rb)] in &traced {
            let (a, b) = (a.bits.view(), b.bits.view());
            let union = (a.popcount() + b.popcount() + a.xor_popcount(&b)) / 2;
            if union > 0 {
                distance += a.xor_popcount(&b) as f64 / union as f64;
            }
            let n = a.len() as f64;
            shares.push(MapPair {
                visible_a: a.popcount() as f64 / n,
                visible_b: b.popcount() as f64 / n,
                disagree: a.xor_popcount(&b) as f64 / n,
            });
            check.visible += (a.popcount() + b.popcount()) as u64;
            check.rays.shadow += ra.shadow + rb.shadow;
        }
        check.incoherence = Some((distance / traced.len() as f64) as f32);
        check.variance_ratio = predicted_variance_ratio(shares);
        Ok(check)
    }

    /// Gives the points `(position, unit normal, d_max)` the records §5.2 asks for, in
    /// their order and in waves like [`Self::build`] (deterministic for any thread count);
    /// returns how many were inserted. This is the one-pass mode's insertion: a render
    /// collects the points that found no record and hands them over afterwards.
    pub fn refine_points(&self, scene: &Scene, points: &[(Vec3, Vec3, f32)]) -> Result<usize> {
        self.bind_scene(scene)?;
        let stop = self.start_stop();
        let target = Refine {
            cache: self,
            stop: &stop,
            max_records: self.params.max_records as usize,
            scene,
            query: |i: u32| points[i as usize],
        };
        let mut go_on = |_: usize, _: usize| true;
        let waves = WaveBuilder::new(Instant::now(), None, &mut go_on).run(
            &target,
            std::iter::once(0..points.len() as u32),
            points.len(),
        )?;
        Ok(waves.inserted)
    }
}

/// What a stopped build's [`Error::Interrupted`] names.
const WHAT: &str = "cache build";

/// What [`VisibilityCache::coherence_check`] measures.
#[derive(Clone, Copy, Debug, Default)]
struct CoherenceCheck {
    /// Mean Jaccard distance of the pairs (`None` without pairs).
    incoherence: Option<f32>,
    /// [`predicted_variance_ratio`] of the pairs.
    variance_ratio: Option<f64>,
    /// Visible directions over all the check's maps.
    visible: u64,
    rays: RecordRays,
}

/// The visibility cache as [`WaveBuilder`] grows it by §5.2's criteria, at the points
/// `query(i) = (position, unit normal, d_max)`: records are traced (stopping at
/// [`VisibilityCache::request_stop`]) and a full cache refuses requests before they are
/// traced.
struct Refine<'a, Q> {
    cache: &'a VisibilityCache,
    /// The build's stop ([`VisibilityCache::start_stop`]), polled per record.
    stop: &'a Stop,
    /// Records past which requests are refused ([`record_cap`] for a view's build).
    max_records: usize,
    scene: &'a Scene,
    query: Q,
}

impl<Q: Fn(u32) -> (Vec3, Vec3, f32) + Sync> WaveTarget for Refine<'_, Q> {
    type State = CacheState;
    type Record = (Record, RecordRays);

    fn read(&self) -> impl Deref<Target = CacheState> + '_ {
        self.cache.read()
    }

    fn write(&self) -> impl DerefMut<Target = CacheState> + '_ {
        self.cache.write()
    }

    fn records(&self) -> usize {
        self.cache.len()
    }

    fn point(&self, i: u32) -> (Vec3, Vec3, f32) {
        (self.query)(i)
    }

    fn cos_max(&self) -> f32 {
        self.cache.params.theta_max().cos()
    }

    fn wants(&self, state: &CacheState, i: u32) -> bool {
        let (x, n, d) = (self.query)(i);
        let params = &self.cache.params;
        state.lookup(params, x, n, d).needs_record(params)
    }

    fn limit(&self, requests: &mut Vec<u32>, deferred: &mut Vec<u32>) {
        // A full cache refuses every record: tracing them would only waste rays.
        let room = self.max_records.saturating_sub(self.cache.len());
        if room < requests.len() {
            let refused = (requests.len() - room) as u64;
            self.cache.write().counters.refused_full += refused;
            requests.truncate(room);
            deferred.clear();
        }
    }

    fn make(&self, i: u32) -> Result<(Record, RecordRays)> {
        self.stop.check(WHAT)?;
        let (x, n, _) = (self.query)(i);
        self.cache.trace(self.scene, x, n)
    }

    fn insert(
        &self,
        state: &mut CacheState,
        i: u32,
        (record, rays): &(Record, RecordRays),
    ) -> Result<bool> {
        count_rays(&mut state.counters, *rays);
        Ok(self.wants(state, i) && state.push(&self.cache.params, record)?.is_some())
    }

    fn looked_up(&self, count: usize) {
        self.cache
            .lookups
            .fetch_add(count as u64, Ordering::Relaxed);
    }
}
