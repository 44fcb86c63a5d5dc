//! The visibility cache: records in a kd-tree, weighted lookups, adaptive insertion,
//! eviction and reuse over frames (CAM08 §5.1–5.3).
//!
//! ## Lookup (§5.1, eq. 9, Fig. 7)
//! For a query point `x` with unit normal `n` and radius `d_max`: take the `m` nearest
//! records among those within `d_max` (kd-tree range search) whose normals differ by
//! `θ_i < θ_max` — filtering before counting, so that records on a nearby face of another
//! orientation (a corner's other wall) cannot crowd out the matching ones — and weight
//! them `w_i = w_g · ŵ(d, θ)` with
//! `w(d, θ) = (1 − θ/π)(1 − x/(1 + λx))`, `x = d / d_max` (eq. 9),
//! `ŵ = (w − w_lo)/(1 − w_lo)` where `w_lo = w(d_max, θ_max)`, and
//! `w_g = sqrt(1 − |n·v|)` for the unit vector `v` from `x` to the record (`w_g = 1` for a
//! record exactly at `x`). The `n` heaviest (ties: nearer, then lower id) are kept and
//! normalised to `β_i = w_i / Σ w_j`; records of weight 0 carry nothing and are dropped.
//!
//! ## Insertion (§5.2)
//! A lookup asks for a new record at `x` when `max w_i < w_min` (geometry) or when the mean
//! pairwise eq. 11 difference `δ̄` of the kept records exceeds `δ̄_max` (visibility
//! disagreement — records near occluders see different things, so the cache refines there).
//!
//! ## Index
//! The records live in the crate's one spatial index ([`crate::spatial::SpatialIndex`]:
//! a bucket kd-tree over distinct positions, chains for shared ones, gathering through a
//! [`LookupScratch`] and SIMD scoring of the `m` nearest); the [`RecordStore`] is its
//! payload, and a wide gathering prefetches the maps of its records, which the lookups it
//! serves compare for `δ̄`. Removal happens only in [`VisibilityCache::end_frame`], which
//! compacts the store and rebuilds the tree balanced — the paper's "occasionally
//! rebalance". Record ids are therefore dense and stable between two `end_frame` calls.
//! Lookups made without a scratch of their own ([`CacheState::lookup`] as builds make
//! them, [`CacheState::lookup_records`] as the renderer and the preview make them) use
//! their thread's.
//!
//! ## Concurrency
//! One `RwLock` (as in the paper): lookups read in parallel, an insertion writes alone and
//! publishes a whole record at once. [`VisibilityCache::build`] is deterministic for any
//! thread count: it runs in waves (look up in parallel; trace the wave's requests in
//! parallel; insert them in a fixed pixel order, re-checking each against the records
//! inserted before it).
//!
//! ## Time (§5.3)
//! Estimators report per record how many traced samples it predicted wrongly
//! ([`VisibilityCache::record_misses`]). [`VisibilityCache::end_frame`] removes records
//! whose miss rate over the frame exceeds `ε_max` (or the `k` worst), and those unused for
//! `F` frames, then starts the next frame with fresh counters.

use std::ops::{Deref, DerefMut};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{RwLock, RwLockReadGuard, RwLockWriteGuard};
use std::time::Instant;

use glam::Vec3;
use rayon::prelude::*;

use super::params::{
    CacheParams, COHERENCE_LOG2_RESOLUTION, COHERENCE_PAIRS, INCOHERENCE_LIMIT, MAX_KEEP_COUNT,
};
use super::record::{Record, RecordHeader, RecordRays, RecordStore, VisibilityView};
use crate::camera::{Camera, GBuffer};
use crate::error::{Error, Result};
use crate::geometry::Scene;
use crate::parallel::with_threads;
use crate::sampling::octahedral::morton_decode;
use crate::sampling::pattern::{default_pattern, record_pattern, DEFAULT_LLOYD_ITERATIONS};
use crate::sampling::rng::SampleRng;

mod io;
pub mod nearest;

pub use crate::spatial::waves::{coarse_to_fine_levels, BUILD_WAVE, MIN_BUILD_WAVE};
use crate::spatial::waves::{WaveBuilder, WaveTarget};
pub(crate) use crate::spatial::with_thread_scratch;
pub use crate::spatial::LookupScratch;
use crate::spatial::{Hits, Records, SpatialIndex};
#[cfg(test)]
pub(crate) mod tests;

/// One record a lookup kept.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Neighbour {
    /// Record id.
    pub id: u32,
    /// `w_i = w_g · ŵ(d, θ)` in `(0, 1]`.
    pub weight: f32,
    /// `β_i = w_i / Σ w_j` over the kept records.
    pub beta: f32,
    /// Distance from the query point to the record, world units.
    pub distance: f32,
}

/// The result of one lookup: up to `n` records with their `β`, and the two insertion
/// figures of §5.2.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Lookup {
    len: usize,
    kept: [Neighbour; MAX_KEEP_COUNT as usize],
    /// `max w_i` over every candidate within `d_max` and `θ_max` (0 when none).
    pub max_weight: f32,
    /// `δ̄`: mean eq. 11 difference over the pairs of kept records (0 for fewer than two;
    /// NaN from [`CacheState::lookup_records`], which skips it).
    pub mean_difference: f32,
}

impl Default for Lookup {
    fn default() -> Self {
        Self {
            len: 0,
            kept: [Neighbour::default(); MAX_KEEP_COUNT as usize],
            max_weight: 0.0,
            mean_difference: 0.0,
        }
    }
}

impl Lookup {
    /// The kept records, heaviest first; their `beta` sum to 1 (empty when none found).
    pub fn neighbours(&self) -> &[Neighbour] {
        &self.kept[..self.len]
    }

    /// §5.2: a new record is wanted when `max w_i < w_min` or `δ̄ > δ̄_max` (a NaN `δ̄`, from
    /// [`CacheState::lookup_records`], counts as agreement: only the first test decides).
    pub fn needs_record(&self, params: &CacheParams) -> bool {
        self.max_weight < params.w_min || self.mean_difference > params.delta_max
    }
}

/// Totals since the cache was created (or loaded).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CacheCounters {
    /// Records inserted.
    pub inserted: u64,
    /// Records removed by [`VisibilityCache::end_frame`].
    pub evicted: u64,
    /// Insertions refused because the cache held `max_records`.
    pub refused_full: u64,
    /// Shadow rays traced for records (including ones a build traced and then discarded).
    pub shadow_rays: u64,
    /// Closest-hit rays traced for `R_i`.
    pub nearest_rays: u64,
    /// Lookups answered.
    pub lookups: u64,
}

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
    /// Whether the check found visibility too incoherent for records and stopped the build
    /// after it.
    pub incoherent: bool,
}

/// What [`VisibilityCache::end_frame`] removed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct EvictionReport {
    /// Frame that ended.
    pub frame: u32,
    /// Removed for their miss rate (or as the `k` worst).
    pub by_misses: usize,
    /// Removed for not being used for `F` frames.
    pub unused: usize,
    /// Records left.
    pub remaining: usize,
}

/// The visibility records as the spatial index reads them: position and decoded normal
/// from the header, `R_i` as the validity radius, the map as the payload a wide gathering
/// prefetches (the lookups it serves compare the kept records' maps for `δ̄`).
impl Records for RecordStore {
    fn len(&self) -> usize {
        RecordStore::len(self)
    }

    fn site(&self, id: usize) -> (Vec3, Vec3) {
        let header = self.header(id);
        (header.position(), header.normal())
    }

    fn radius(&self, id: usize) -> f32 {
        self.header(id).nearest_hit_distance
    }

    #[inline(always)]
    fn prefetch(&self, id: usize) {
        for line in self.bits(id).bit_words().chunks(8) {
            crate::spatial::prefetch(&line[0]);
        }
    }
}

/// The lock-protected part: records, their index and the frame.
#[derive(Clone, Debug)]
pub struct CacheState {
    /// The records in the spatial index.
    index: SpatialIndex<RecordStore>,
    frame: u32,
    counters: CacheCounters,
    /// [`Scene::geometry_fingerprint`] of the scene the records were traced in (`None`
    /// until the cache is first used with a scene; see [`VisibilityCache::bind_scene`]).
    scene: Option<u64>,
}

impl CacheState {
    fn new(m: u32) -> Result<Self> {
        Ok(Self {
            index: SpatialIndex::new(RecordStore::new(m)?),
            frame: 0,
            counters: CacheCounters::default(),
            scene: None,
        })
    }

    /// The fingerprint of the scene the cache is bound to, if any.
    pub fn scene_fingerprint(&self) -> Option<u64> {
        self.scene
    }

    /// The records.
    pub fn store(&self) -> &RecordStore {
        self.index.records()
    }

    /// Number of records.
    pub fn len(&self) -> usize {
        self.index.records().len()
    }

    /// True without records.
    pub fn is_empty(&self) -> bool {
        self.index.records().is_empty()
    }

    /// The current frame (starts at 0, advanced by `end_frame`).
    pub fn frame(&self) -> u32 {
        self.frame
    }

    /// §5.1 lookup at `x` (normal `n`, unit) within `d_max` (world units). A non-positive
    /// or non-finite `d_max` finds nothing.
    pub fn lookup(&self, params: &CacheParams, x: Vec3, n: Vec3, d_max: f32) -> Lookup {
        with_thread_scratch(|scratch| self.lookup_near(params, x, n, d_max, scratch))
    }

    /// [`Self::lookup`] for a sequence of nearby points (pixel order): `scratch` keeps the
    /// records around an earlier point and serves later ones from them while they are
    /// covered (see [`LookupScratch`]). The answer is the same as [`Self::lookup`]'s.
    pub fn lookup_near(
        &self,
        params: &CacheParams,
        x: Vec3,
        n: Vec3,
        d_max: f32,
        scratch: &mut LookupScratch,
    ) -> Lookup {
        self.lookup_with(params, x, n, d_max, scratch, true)
    }

    /// [`Self::lookup`] without §5.2's `δ̄` (left NaN): the records and their `β`, which is
    /// all a renderer reads. `δ̄` compares the kept records' maps pairwise, and their bits
    /// are the lookup's slowest memory reads when lookups come scattered.
    pub fn lookup_records(&self, params: &CacheParams, x: Vec3, n: Vec3, d_max: f32) -> Lookup {
        with_thread_scratch(|scratch| self.lookup_with(params, x, n, d_max, scratch, false))
    }

    fn lookup_with(
        &self,
        params: &CacheParams,
        x: Vec3,
        n: Vec3,
        d_max: f32,
        scratch: &mut LookupScratch,
        difference: bool,
    ) -> Lookup {
        let mut out = Lookup::default();
        let hits = self.m_nearest(params, x, n, d_max, scratch);
        let mut order = [0usize; MAX_KEEP_COUNT as usize];
        let (len, best) = hits.heaviest(params.n_keep as usize, &mut order);
        for (k, &i) in out.kept.iter_mut().zip(&order[..len]) {
            *k = Neighbour {
                id: hits.id(i),
                weight: hits.weight[i],
                beta: 0.0,
                distance: hits.distance[i],
            };
        }
        out.len = len;
        out.max_weight = best;
        let kept = &mut out.kept[..out.len];
        let total: f32 = kept.iter().map(|k| k.weight).sum();
        for k in kept.iter_mut() {
            k.beta = k.weight / total;
        }
        out.mean_difference = if difference {
            self.mean_difference(kept)
        } else {
            f32::NAN
        };
        out
    }
    /// The `m_search` nearest records (ties by id) among those within `d_max` of `x` whose
    /// normals differ from the unit `n` by `θ_i < θ_max`, in no particular order, with
    /// their eq. 9 weights ([`SpatialIndex::m_nearest`]). Both [`Self::lookup`] (§5.1) and
    /// [`Self::nearest`] (§6.1) start from this set.
    pub(crate) fn m_nearest<'b>(
        &self,
        params: &CacheParams,
        x: Vec3,
        n: Vec3,
        d_max: f32,
        scratch: &'b mut LookupScratch,
    ) -> &'b Hits {
        self.index
            .m_nearest(&params.weighting(), x, n, d_max, scratch)
    }

    /// `δ̄` of §5.2: mean eq. 11 difference over the pairs of `kept`.
    fn mean_difference(&self, kept: &[Neighbour]) -> f32 {
        if kept.len() < 2 {
            return 0.0;
        }
        let mut sum = 0u64;
        for (i, a) in kept.iter().enumerate() {
            let va = self.index.records().bits(a.id as usize);
            for b in &kept[i + 1..] {
                sum += va.xor_popcount(&self.index.records().bits(b.id as usize)) as u64;
            }
        }
        let pairs = (kept.len() * (kept.len() - 1) / 2) as f64;
        let texels = (1u64 << (2 * self.index.records().m())) as f64;
        (sum as f64 / (pairs * texels)) as f32
    }

    /// `Ṽ = Σ β_i V_i` of a lookup as `R x R` floats in texel layout (row `y`, column `x`
    /// of the equal-area square; row-major).
    pub fn interpolate(&self, lookup: &Lookup, out: &mut [f32]) {
        let r = 1usize << self.index.records().m();
        debug_assert_eq!(out.len(), r * r);
        out.fill(0.0);
        for k in lookup.neighbours() {
            let bits = self.index.records().bits(k.id as usize);
            for_each_set_bit(bits, |z| {
                let t = morton_decode(z as u32);
                out[t.y as usize * r + t.x as usize] += k.beta;
            });
        }
    }

    /// Appends a record (must have the store's resolution and a finite position); returns
    /// its id, or `None` when `max_records` is reached.
    fn push(&mut self, params: &CacheParams, record: &Record) -> Result<Option<u32>> {
        if !record.position.is_finite() {
            return Err(Error::invalid("position", "must be finite"));
        }
        self.admit(params, |store| store.push(record))
    }

    /// Appends a packed record (file loading).
    fn push_packed(
        &mut self,
        params: &CacheParams,
        header: RecordHeader,
        words: &[u64],
    ) -> Result<Option<u32>> {
        self.admit(params, |store| store.push_packed(header, words))
    }

    fn admit(
        &mut self,
        params: &CacheParams,
        push: impl FnOnce(&mut RecordStore) -> Result<usize>,
    ) -> Result<Option<u32>> {
        if self.index.len() >= params.max_records as usize {
            self.counters.refused_full += 1;
            return Ok(None);
        }
        let id = self.index.admit(push)?;
        self.counters.inserted += 1;
        Ok(Some(id))
    }
}

/// Calls `f(z)` for every set bit `z` of a map.
fn for_each_set_bit(bits: VisibilityView, mut f: impl FnMut(usize)) {
    for (w, &word) in bits.bit_words().iter().enumerate() {
        let mut x = word;
        while x != 0 {
            f(w * 64 + x.trailing_zeros() as usize);
            x &= x - 1;
        }
    }
}

/// The visibility cache (module docs). `Sync`: share it between render threads.
#[derive(Debug)]
pub struct VisibilityCache {
    params: CacheParams,
    pattern: Vec<Vec3>,
    state: RwLock<CacheState>,
    lookups: AtomicU64,
    /// Set by [`VisibilityCache::request_stop`]; cleared when a build starts.
    stop: AtomicBool,
}

impl Clone for VisibilityCache {
    fn clone(&self) -> Self {
        Self {
            params: self.params,
            pattern: self.pattern.clone(),
            state: RwLock::new(self.read().clone()),
            lookups: AtomicU64::new(self.lookups.load(Ordering::Relaxed)),
            stop: AtomicBool::new(false),
        }
    }
}

impl VisibilityCache {
    /// An empty cache. Fails when `params` do not validate.
    pub fn new(params: CacheParams) -> Result<Self> {
        params.validate()?;
        let m = params.log2_resolution;
        let pattern = if params.pattern_seed == crate::sampling::pattern::DEFAULT_PATTERN_SEED {
            default_pattern(m)?.to_vec()
        } else {
            record_pattern(m, params.pattern_seed, DEFAULT_LLOYD_ITERATIONS)?
        };
        Ok(Self {
            params,
            pattern,
            state: RwLock::new(CacheState::new(m)?),
            lookups: AtomicU64::new(0),
            stop: AtomicBool::new(false),
        })
    }

    /// The parameters.
    pub fn params(&self) -> &CacheParams {
        &self.params
    }

    /// The record directions, unit vectors in Morton order (`4^M` of them): bit `z` of
    /// every record is the visibility along `directions()[z]`.
    pub fn directions(&self) -> &[Vec3] {
        &self.pattern
    }

    /// `2^M`.
    pub fn resolution(&self) -> u32 {
        1 << self.params.log2_resolution
    }

    /// Shared read access (many readers at once).
    pub fn read(&self) -> RwLockReadGuard<'_, CacheState> {
        self.state.read().unwrap_or_else(|e| e.into_inner())
    }

    /// Exclusive access (for insertions).
    pub(crate) fn write(&self) -> RwLockWriteGuard<'_, CacheState> {
        self.state.write().unwrap_or_else(|e| e.into_inner())
    }

    /// Number of records.
    pub fn len(&self) -> usize {
        self.read().len()
    }

    /// True without records.
    pub fn is_empty(&self) -> bool {
        self.read().is_empty()
    }

    /// Bytes the records occupy ([`super::record::bytes_per_record`] each: 172 at 32 x 32).
    pub fn memory_bytes(&self) -> usize {
        self.read().store().memory_bytes()
    }

    /// Bytes of the index on top of the records ([`SpatialIndex::memory_bytes`]).
    pub fn index_bytes(&self) -> usize {
        self.read().index.memory_bytes()
    }

    /// Binds the cache to `scene`, or checks that it is the scene the cache is bound to.
    /// Records hold the visibility of one geometry: used in another scene they would
    /// shade it with the first one's shadows, silently. An unbound cache binds to the first
    /// scene it is used with; a bound one refuses a scene of another
    /// [`Scene::geometry_fingerprint`] with an error naming `cache`, and stays as it was.
    /// The same geometry in another [`Scene`] value is the same scene, and moving objects
    /// of the bound scene (animation) keeps the binding.
    pub fn bind_scene(&self, scene: &Scene) -> Result<()> {
        self.bind_fingerprint(scene.geometry_fingerprint())
    }

    /// [`Self::bind_scene`] for a scene known by its fingerprint `f`.
    pub fn bind_fingerprint(&self, f: u64) -> Result<()> {
        let check = |state: &CacheState| match state.scene {
            Some(bound) if bound != f => Err(Error::invalid("cache", other_scene(bound, f))),
            _ => Ok(()),
        };
        {
            let state = self.read();
            check(&state)?;
            if state.scene == Some(f) {
                return Ok(());
            }
        }
        let mut state = self.write();
        check(&state)?;
        state.scene = Some(f);
        Ok(())
    }

    /// Binds the cache to `scene` whatever it was bound to: for using records of another
    /// geometry on purpose (a stale or foreign cache in a study of robustness). The
    /// records stay as they are.
    pub fn rebind_scene(&self, scene: &Scene) {
        self.write().scene = Some(scene.geometry_fingerprint());
    }

    /// Asks a running [`Self::build`] (from another thread) to stop within one record's
    /// rays: the wave being traced is dropped, the build returns [`Error::Interrupted`]
    /// and the cache keeps the records of the waves before. A later build clears it.
    pub fn request_stop(&self) {
        self.stop.store(true, Ordering::Relaxed);
    }

    /// The fingerprint of the scene the cache is bound to ([`Self::bind_scene`]), if any.
    pub fn scene_fingerprint(&self) -> Option<u64> {
        self.read().scene
    }

    /// Totals since creation.
    pub fn counters(&self) -> CacheCounters {
        let mut c = self.read().counters;
        c.lookups = self.lookups.load(Ordering::Relaxed);
        c
    }

    /// One §5.1 lookup (see [`CacheState::lookup`]). For batches, take [`Self::read`] once.
    pub fn lookup(&self, x: Vec3, n: Vec3, d_max: f32) -> Lookup {
        self.lookups.fetch_add(1, Ordering::Relaxed);
        self.read().lookup(&self.params, x, n, d_max)
    }

    /// Lookups for a batch of points under one read lock, in parallel. `d_max[i]` per point.
    pub fn lookup_batch(
        &self,
        points: &[Vec3],
        normals: &[Vec3],
        d_max: &[f32],
        threads: Option<usize>,
    ) -> Result<Vec<Lookup>> {
        if normals.len() != points.len() || d_max.len() != points.len() {
            return Err(Error::invalid(
                "normals",
                "points, normals and radii must have the same length",
            ));
        }
        self.lookups
            .fetch_add(points.len() as u64, Ordering::Relaxed);
        let state = self.read();
        with_threads(threads, || {
            (0..points.len())
                .into_par_iter()
                .with_min_len(64)
                .map(|i| state.lookup(&self.params, points[i], normals[i], d_max[i]))
                .collect()
        })
    }

    /// Traces a record at `position` (normal `normal`, need not be unit) for the current
    /// frame. Takes no lock.
    pub fn trace(
        &self,
        scene: &Scene,
        position: Vec3,
        normal: Vec3,
    ) -> Result<(Record, RecordRays)> {
        let frame = self.read().frame;
        Record::trace_with(
            scene,
            position,
            normal,
            &self.pattern,
            frame,
            self.params.nearest_hits,
        )
    }

    /// Traces and inserts a record unconditionally; returns its id (`None` at
    /// `max_records`).
    pub fn insert(&self, scene: &Scene, position: Vec3, normal: Vec3) -> Result<Option<u32>> {
        self.bind_scene(scene)?;
        let (record, rays) = self.trace(scene, position, normal)?;
        let mut state = self.write();
        count_rays(&mut state.counters, rays);
        state.push(&self.params, &record)
    }

    /// Inserts a record traced elsewhere (its resolution must match).
    pub fn insert_record(&self, record: &Record) -> Result<Option<u32>> {
        self.write().push(&self.params, record)
    }

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

    /// Adds per-record miss and use counts for the current frame (§5.3); a record with uses
    /// counts as used this frame. Fails (changing nothing) on an unknown id or on lengths
    /// that differ.
    pub fn record_misses(&self, ids: &[u32], misses: &[u32], uses: &[u32]) -> Result<()> {
        if misses.len() != ids.len() || uses.len() != ids.len() {
            return Err(Error::invalid(
                "misses",
                "ids, misses and uses must have the same length",
            ));
        }
        let mut state = self.write();
        let len = state.len();
        if let Some(bad) = ids.iter().find(|&&i| i as usize >= len) {
            return Err(Error::invalid(
                "ids",
                format!("record {bad} does not exist (the cache holds {len})"),
            ));
        }
        if let Some(k) = (0..ids.len()).find(|&k| misses[k] > uses[k]) {
            return Err(Error::invalid(
                "misses",
                format!("entry {k}: {} misses exceed {} uses", misses[k], uses[k]),
            ));
        }
        let frame = state.frame;
        for k in 0..ids.len() {
            let h = state.index.records_mut().header_mut(ids[k] as usize);
            h.misses = h.misses.saturating_add(misses[k]);
            h.uses = h.uses.saturating_add(uses[k]);
            if uses[k] > 0 {
                h.last_frame = frame;
            }
        }
        Ok(())
    }

    /// Checks every record against `scene` as it is now, the way an estimator's samples do
    /// (§5.3): `rays_per_record` of the record's own pattern directions above its tangent
    /// plane, drawn from `(seed, record, frame)`, are traced again, and each one whose
    /// answer differs from the stored bit counts as a miss; all count as uses. Returns
    /// (rays traced, misses). For animations: call after the scene changed, then
    /// [`Self::end_frame`] evicts the records the change made wrong.
    pub fn validate(
        &self,
        scene: &Scene,
        rays_per_record: u32,
        seed: u64,
        threads: Option<usize>,
    ) -> Result<(u64, u64)> {
        if rays_per_record == 0 {
            return Err(Error::invalid("rays_per_record", "must be >= 1"));
        }
        let state = self.read();
        let frame = state.frame;
        let n = state.len();
        let texels = self.pattern.len() as u64;
        let counts: Vec<(u32, u32)> = with_threads(threads, || {
            (0..n)
                .into_par_iter()
                .map(|i| {
                    let (p, normal) = state.index.site(i);
                    let origin = scene.offset_point(p, normal);
                    let bits = state.store().bits(i);
                    let mut counters = Default::default();
                    let (mut uses, mut misses) = (0u32, 0u32);
                    // Draw until enough directions above the plane (bounded tries).
                    for k in 0..8 * rays_per_record as u64 {
                        if uses == rays_per_record {
                            break;
                        }
                        let z = (crate::sampling::rng::hash4(seed, i as u64, frame as u64, k)
                            % texels) as usize;
                        let d = self.pattern[z];
                        if normal.dot(d) <= 0.0 {
                            continue;
                        }
                        uses += 1;
                        let visible = !scene.occluded1(origin, d, f32::INFINITY, &mut counters);
                        misses += (visible != bits.get(z)) as u32;
                    }
                    (misses, uses)
                })
                .collect()
        })?;
        drop(state);
        let ids: Vec<u32> = (0..n as u32).collect();
        let misses: Vec<u32> = counts.iter().map(|c| c.0).collect();
        let uses: Vec<u32> = counts.iter().map(|c| c.1).collect();
        self.record_misses(&ids, &misses, &uses)?;
        Ok((
            uses.iter().map(|&u| u as u64).sum(),
            misses.iter().map(|&m| m as u64).sum(),
        ))
    }

    /// Ends the frame (§5.3): removes records whose miss rate this frame exceeds `ε_max`
    /// (or, with `evict_worst = k > 0`, the `k` with the highest rate among those that
    /// missed), and records not used (nor created) during the last `F` frames; then
    /// compacts ids (kept records keep their order), clears the miss and use counters and
    /// advances the frame.
    pub fn end_frame(&self) -> EvictionReport {
        let p = self.params;
        let mut state = self.write();
        let frame = state.frame;
        let n = state.len();
        let rate = |h: &super::record::RecordHeader| {
            if h.uses == 0 {
                0.0
            } else {
                h.misses as f64 / h.uses as f64
            }
        };
        let mut by_misses = vec![false; n];
        if p.evict_worst > 0 {
            let mut missed: Vec<(f64, u32)> = (0..n)
                .filter(|&i| state.store().header(i).misses > 0)
                .map(|i| (rate(state.store().header(i)), i as u32))
                .collect();
            missed.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
            for &(_, i) in missed.iter().take(p.evict_worst as usize) {
                by_misses[i as usize] = true;
            }
        } else {
            for (i, flag) in by_misses.iter_mut().enumerate() {
                *flag = rate(state.store().header(i)) > p.epsilon_max as f64;
            }
        }
        let unused: Vec<bool> = (0..n)
            .map(|i| {
                !by_misses[i]
                    && frame.saturating_sub(state.store().header(i).last_frame) >= p.unused_frames
            })
            .collect();
        let report = EvictionReport {
            frame,
            by_misses: by_misses.iter().filter(|&&b| b).count(),
            unused: unused.iter().filter(|&&b| b).count(),
            remaining: 0,
        };
        let removed = report.by_misses + report.unused;
        if removed > 0 {
            state
                .index
                .rebuild(|store| store.retain(|i| !(by_misses[i] || unused[i])));
        }
        for i in 0..state.len() {
            let h = state.index.records_mut().header_mut(i);
            h.misses = 0;
            h.uses = 0;
        }
        state.counters.evicted += removed as u64;
        state.frame = frame + 1;
        EvictionReport {
            remaining: state.len(),
            ..report
        }
    }

    /// Builds the cache for a view (§5): bootstraps `N_startup` records at the first hits of
    /// rays stratified over the image (only when the cache is empty), then passes over the
    /// G-buffer (pixel centres) applying §5.2's two criteria with `d_max = k · footprint`.
    ///
    /// Deterministic for any `threads`: pixels go coarse to fine (every 32nd pixel of every
    /// 32nd row first, then the ones between, …) in waves within a level, of a quarter of
    /// the records (between [`MIN_BUILD_WAVE`] and [`BUILD_WAVE`] pixels); a wave looks up
    /// in parallel, traces the requested records in parallel, then inserts them in that
    /// order, re-checking each against the records inserted before it (the losers' rays are
    /// still counted). `progress(done, total)` is called after each wave with pixels done;
    /// returning false stops, as does `time_budget` (seconds, checked between waves).
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
        self.bind_scene(scene)?;
        self.stop.store(false, Ordering::Relaxed);
        let start = Instant::now();
        let before = self.counters();
        let mut report = BuildReport {
            pixels: camera.num_pixels(),
            complete: true,
            ..BuildReport::default()
        };
        with_threads(threads, || -> Result<()> {
            let gbuffer = GBuffer::render(scene, camera, seed, false, None)?;
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
                let (incoherence, rays) = self.coherence_check(scene, camera, &gbuffer)?;
                count_rays(&mut self.write().counters, rays);
                report.incoherence = incoherence;
                if incoherence.is_some_and(|d| d > INCOHERENCE_LIMIT) {
                    report.incoherent = true;
                    return Ok(());
                }
            }
            if self.is_empty() {
                report.bootstrap_records = self.bootstrap(scene, camera, seed)?;
            }
            let levels = coarse_to_fine_levels(camera.width, camera.height)
                .into_iter()
                .map(|level| {
                    level
                        .into_iter()
                        .filter(|&i| gbuffer.object[i as usize] >= 0)
                });
            let k = self.params.d_max_scale;
            let target = Refine {
                cache: self,
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
    fn bootstrap(&self, scene: &Scene, camera: &Camera, seed: u64) -> Result<usize> {
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
                if self.stop.load(Ordering::Relaxed) {
                    return Some(Err(Error::Interrupted {
                        what: "cache build".into(),
                    }));
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
    /// [`COHERENCE_PAIRS`] pixels on a grid over the image and at their partners a quarter
    /// of `d_max` to the side (both surface hits); returns the mean Jaccard distance
    /// `|A ⊕ B| / |A ∪ B|` of the pairs' visible sets (`None` without pairs) and the rays
    /// traced. The pairs are fixed by the image, so the check is deterministic.
    fn coherence_check(
        &self,
        scene: &Scene,
        camera: &Camera,
        g: &GBuffer,
    ) -> Result<(Option<f32>, RecordRays)> {
        let (w, h) = (camera.width as usize, camera.height as usize);
        let step = ((self.params.d_max_scale / 4.0).round() as usize).max(1);
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
            return Ok((None, RecordRays::default()));
        }
        let pattern = default_pattern(COHERENCE_LOG2_RESOLUTION)?;
        let map = |i: usize| {
            let (p, n) = (Vec3::from(g.position[i]), Vec3::from(g.normal[i]));
            Record::trace_with(scene, p, n, pattern, 0, false)
        };
        let traced: Vec<[(Record, RecordRays); 2]> = pairs
            .par_iter()
            .map(|&(a, b)| Ok([map(a)?, map(b)?]))
            .collect::<Result<_>>()?;
        let mut distance = 0.0f64;
        let mut rays = RecordRays::default();
        for [(a, ra), (b, rb)] in &traced {
            let (a, b) = (a.bits.view(), b.bits.view());
            let union = (a.popcount() + b.popcount() + a.xor_popcount(&b)) / 2;
            if union > 0 {
                distance += a.xor_popcount(&b) as f64 / union as f64;
            }
            rays.shadow += ra.shadow + rb.shadow;
        }
        Ok((Some((distance / traced.len() as f64) as f32), rays))
    }

    /// Gives the points `(position, unit normal, d_max)` the records §5.2 asks for, in
    /// their order and in waves like [`Self::build`] (deterministic for any thread count);
    /// returns how many were inserted. This is the one-pass mode's insertion: a render
    /// collects the points that found no record and hands them over afterwards.
    pub fn refine_points(&self, scene: &Scene, points: &[(Vec3, Vec3, f32)]) -> Result<usize> {
        self.bind_scene(scene)?;
        let target = Refine {
            cache: self,
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

/// The visibility cache as [`WaveBuilder`] grows it by §5.2's criteria, at the points
/// `query(i) = (position, unit normal, d_max)`: records are traced (stopping at
/// [`VisibilityCache::request_stop`]) and a full cache refuses requests before they are
/// traced.
struct Refine<'a, Q> {
    cache: &'a VisibilityCache,
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
        let room = (self.cache.params.max_records as usize).saturating_sub(self.cache.len());
        if room < requests.len() {
            let refused = (requests.len() - room) as u64;
            self.cache.write().counters.refused_full += refused;
            requests.truncate(room);
            deferred.clear();
        }
    }

    fn make(&self, i: u32) -> Result<(Record, RecordRays)> {
        if self.cache.stop.load(Ordering::Relaxed) {
            return Err(Error::Interrupted {
                what: "cache build".into(),
            });
        }
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

/// Why a cache bound to geometry `bound` refuses a scene of fingerprint `f`.
pub(crate) fn other_scene(bound: u64, f: u64) -> String {
    format!(
        "was built for another scene (geometry fingerprint {bound:016x}, this scene's is \
         {f:016x}); build a cache for this scene"
    )
}

/// The arguments every pass over a camera's pixels checks: a scene with triangles and a
/// time budget, if any, that is a finite positive number of seconds.
pub(crate) fn check_scene_and_budget(scene: &Scene, time_budget: Option<f64>) -> Result<()> {
    if let Some(b) = time_budget {
        if !(b.is_finite() && b > 0.0) {
            return Err(Error::invalid(
                "time_budget",
                format!("must be finite and > 0 seconds, got {b}"),
            ));
        }
    }
    if scene.num_triangles() == 0 {
        return Err(Error::invalid("scene", "has no triangles"));
    }
    Ok(())
}

fn count_rays(c: &mut CacheCounters, rays: RecordRays) {
    c.shadow_rays += rays.shadow as u64;
    c.nearest_rays += rays.nearest as u64;
}
