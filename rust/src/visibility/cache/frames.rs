//! The cache over frames (§5.3): per-record miss and use counts, re-validation against a
//! changed scene, and eviction at the end of each frame.

use rayon::prelude::*;

use super::VisibilityCache;
use crate::error::{Error, Result};
use crate::geometry::Scene;
use crate::parallel::with_threads;
use crate::stop::Stop;

/// The last frame a cache can be at: [`VisibilityCache::end_frame`] refuses to advance past
/// it rather than wrap to 0 (which would make every record look unused for billions of
/// frames), and a file holding a later frame does not load.
pub const LAST_FRAME: u32 = u32::MAX - 1;

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

impl VisibilityCache {
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
    /// [`Self::end_frame`] evicts the records the change made wrong. Stops with
    /// [`Error::Interrupted`] when the current [`Stop`] is set, counting nothing.
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
        let stop = Stop::current();
        let counts: Vec<(u32, u32)> = with_threads(threads, || {
            (0..n)
                .into_par_iter()
                .map(|i| {
                    if stop.is_set() {
                        return (0, 0);
                    }
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
        // Nothing is counted unless every record was checked.
        stop.check("cache.validate")?;
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
    /// advances the frame. At [`LAST_FRAME`] it fails, naming `frame`, and changes nothing.
    pub fn end_frame(&self) -> Result<EvictionReport> {
        let p = self.params;
        let mut state = self.write();
        let frame = state.frame;
        if frame >= LAST_FRAME {
            return Err(Error::invalid(
                "frame",
                format!("the cache is at its last frame ({frame}) and cannot advance"),
            ));
        }
        let n = state.len();
        let rate = |h: &crate::visibility::record::RecordHeader| {
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
        Ok(EvictionReport {
            remaining: state.len(),
            ..report
        })
    }
}
