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
//!
//! ## Files
//! `mod.rs`: the cache, its locked state and insertion; `lookup.rs`: §5.1 lookups;
//! `nearest.rs`: the `m` nearest for ambient occlusion; `build.rs`: builds for a view and
//! the insertion waves; `coherence.rs`: the check that predicts whether records repay
//! their build; `frames.rs`: §5.3 bookkeeping over frames; `io.rs`: the file format;
//! `interpolant.rs`: the interpolated visibility `Ṽ` of a lookup and its integral `J`.

use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};
use std::sync::{Mutex, RwLock, RwLockReadGuard, RwLockWriteGuard};

use glam::Vec3;

use super::params::CacheParams;
use super::record::{Record, RecordHeader, RecordRays, RecordStore};
use crate::error::{Error, Result};
use crate::geometry::Scene;
use crate::sampling::pattern::{default_pattern, record_pattern, DEFAULT_LLOYD_ITERATIONS};
use crate::stop::Stop;

mod build;
pub mod coherence;
mod frames;
pub mod interpolant;
mod io;
mod lookup;
pub mod nearest;

pub use build::BuildReport;
pub use frames::{EvictionReport, LAST_FRAME};
pub use lookup::{Lookup, Neighbour};

pub use crate::spatial::waves::{coarse_to_fine_levels, BUILD_WAVE, MIN_BUILD_WAVE};
pub(crate) use crate::spatial::with_thread_scratch;
pub use crate::spatial::LookupScratch;
use crate::spatial::{Records, SpatialIndex};
#[cfg(test)]
pub(crate) mod tests;

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
    /// `d_max_scale` times the median pixel footprint of the last build, world units: the
    /// radius of lookups that give none (`None` before a build).
    default_radius: Option<f32>,
}

impl CacheState {
    fn new(m: u32) -> Result<Self> {
        Ok(Self {
            index: SpatialIndex::new(RecordStore::new(m)?),
            frame: 0,
            counters: CacheCounters::default(),
            scene: None,
            default_radius: None,
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

/// The visibility cache (module docs). `Sync`: share it between render threads.
#[derive(Debug)]
pub struct VisibilityCache {
    params: CacheParams,
    pattern: Vec<Vec3>,
    state: RwLock<CacheState>,
    lookups: AtomicU64,
    /// The running build's stop, set by [`VisibilityCache::request_stop`]; a new one
    /// (a child of the calling thread's current stop) for every build.
    stop: Mutex<Stop>,
    /// [`VisibilityCache::plan_samples`]'s samples per pixel, 0 when not given.
    planned_spp: AtomicU32,
    /// Process-unique id of this cache object (a clone or a loaded file gets its own).
    id: u64,
    /// Bumped on every exclusive access: anything derived from the records (a preview's
    /// transfer) compares it to know when to rebuild.
    revision: AtomicU64,
}

/// Source of [`VisibilityCache`] ids.
static NEXT_CACHE_ID: AtomicU64 = AtomicU64::new(1);

impl Clone for VisibilityCache {
    fn clone(&self) -> Self {
        Self {
            params: self.params,
            pattern: self.pattern.clone(),
            state: RwLock::new(self.read().clone()),
            lookups: AtomicU64::new(self.lookups.load(Ordering::Relaxed)),
            stop: Mutex::default(),
            planned_spp: AtomicU32::new(self.planned_spp.load(Ordering::Relaxed)),
            id: NEXT_CACHE_ID.fetch_add(1, Ordering::Relaxed),
            revision: AtomicU64::new(0),
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
            stop: Mutex::default(),
            planned_spp: AtomicU32::new(0),
            id: NEXT_CACHE_ID.fetch_add(1, Ordering::Relaxed),
            revision: AtomicU64::new(0),
        })
    }

    /// Declares the samples per pixel of the renders the records will serve (`None`:
    /// unknown, as for a cache kept across frames). The coherence check of the next builds
    /// weighs the records' cost against them ([`coherence::predicted_gain`]).
    pub fn plan_samples(&self, spp: Option<u32>) {
        self.planned_spp.store(spp.unwrap_or(0), Ordering::Relaxed);
    }

    /// The samples per pixel given to [`Self::plan_samples`], if any.
    pub fn planned_samples(&self) -> Option<u32> {
        Some(self.planned_spp.load(Ordering::Relaxed)).filter(|&s| s > 0)
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
        let guard = self.state.write().unwrap_or_else(|e| e.into_inner());
        self.revision.fetch_add(1, Ordering::Release);
        guard
    }

    /// `(id, revision)`: the id is unique to this cache object in the process, the revision
    /// grows with every change of its records (insertions, builds, frames, loading). Equal
    /// pairs mean the same records.
    pub fn version(&self) -> (u64, u64) {
        (self.id, self.revision.load(Ordering::Acquire))
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
        self.stop.lock().unwrap_or_else(|e| e.into_inner()).set();
    }

    /// A stop for a build starting now: set by [`Self::request_stop`] or the calling
    /// thread's current [`Stop`] (Ctrl-C).
    pub(super) fn start_stop(&self) -> Stop {
        let stop = Stop::current().child(None);
        *self.stop.lock().unwrap_or_else(|e| e.into_inner()) = stop.clone();
        stop
    }

    /// The fingerprint of the scene the cache is bound to ([`Self::bind_scene`]), if any.
    pub fn scene_fingerprint(&self) -> Option<u64> {
        self.read().scene
    }

    /// The radius for lookups that give none: `d_max_scale` times the median pixel
    /// footprint of the last [`Self::build`] that hit something, world units (`None`
    /// before). Saved and loaded with the cache.
    pub fn default_radius(&self) -> Option<f32> {
        self.read().default_radius
    }

    /// Totals since creation.
    pub fn counters(&self) -> CacheCounters {
        let mut c = self.read().counters;
        c.lookups = self.lookups.load(Ordering::Relaxed);
        c
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
        Record::trace_as(
            scene,
            position,
            normal,
            &self.pattern,
            frame,
            self.params.record_tracing(),
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
    crate::error::check_time_budget(time_budget)?;
    if scene.num_triangles() == 0 {
        return Err(Error::invalid("scene", "has no triangles"));
    }
    Ok(())
}

fn count_rays(c: &mut CacheCounters, rays: RecordRays) {
    c.shadow_rays += rays.shadow as u64;
    c.nearest_rays += rays.nearest as u64;
}
