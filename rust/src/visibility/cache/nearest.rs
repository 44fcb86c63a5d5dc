//! The `m` nearest records of a query, all of them (CAM08 §6.1), and ordered insertion of
//! records traced elsewhere.
//!
//! [`CacheState::lookup`] (§5.1) keeps only the `n` heaviest candidates; ambient occlusion
//! (§6.1) averages over all `m` nearest. The candidate set is the same: records within
//! `d_max` whose normals differ by `θ_i < θ_max`, the `m` nearest of those (ties by id),
//! each with its eq. 9 weight `w_i = w_g · ŵ(d, θ)`; both gather it with
//! [`CacheState::m_nearest`], and tests hold the two to the same candidates.

use std::cmp::Ordering;

use glam::Vec3;

use super::{CacheState, LookupScratch, VisibilityCache};
use crate::error::Result;
use crate::visibility::params::{CacheParams, MAX_SEARCH_COUNT};
use crate::visibility::record::{Record, RecordRays};

/// One of the `m` nearest records of a query.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Candidate {
    /// Record id.
    pub id: u32,
    /// Distance from the query point to the record, world units.
    pub distance: f32,
    /// Angle between the query's and the record's normals, radians in `[0, θ_max)`.
    pub theta: f32,
    /// Eq. 9 weight `w_i = w_g · ŵ(d, θ)` in `[0, 1]` (as [`CacheState::lookup`] scores it).
    pub weight: f32,
    /// Its geometric factor `w_g = sqrt(1 − |n·v|)` in `[0, 1]` (Fig. 7).
    pub geometric: f32,
}

/// The `m` nearest matching records of a query, nearest first (ties by id).
#[derive(Clone, Copy, Debug)]
pub struct Nearest {
    len: usize,
    items: [Candidate; MAX_SEARCH_COUNT as usize],
}

impl Default for Nearest {
    fn default() -> Self {
        Self {
            len: 0,
            items: [Candidate::default(); MAX_SEARCH_COUNT as usize],
        }
    }
}

impl Nearest {
    /// The candidates, nearest first; empty when none matched.
    pub fn candidates(&self) -> &[Candidate] {
        &self.items[..self.len]
    }
}

fn by_distance_then_id(a: &Candidate, b: &Candidate) -> Ordering {
    a.distance.total_cmp(&b.distance).then(a.id.cmp(&b.id))
}

impl CacheState {
    /// The `m_search` nearest records within `d_max` (world units) of `x` whose normals
    /// differ from the unit `n` by less than `θ_max`, with their eq. 9 weights. A
    /// non-positive or non-finite `d_max` finds nothing.
    pub fn nearest(&self, params: &CacheParams, x: Vec3, n: Vec3, d_max: f32) -> Nearest {
        super::with_thread_scratch(|scratch| self.nearest_near(params, x, n, d_max, scratch))
    }

    /// [`Self::nearest`] with a [`LookupScratch`] for sequences of nearby points; the same
    /// answer.
    pub fn nearest_near(
        &self,
        params: &CacheParams,
        x: Vec3,
        n: Vec3,
        d_max: f32,
        scratch: &mut LookupScratch,
    ) -> Nearest {
        let mut out = Nearest::default();
        let hits = self.m_nearest(params, x, n, d_max, scratch);
        out.len = hits.len;
        let items = &mut out.items[..hits.len];
        for (i, c) in items.iter_mut().enumerate() {
            *c = Candidate {
                id: hits.id(i),
                distance: hits.distance[i],
                theta: hits.theta[i],
                weight: hits.weight[i],
                geometric: hits.geometric[i],
            };
        }
        items.sort_unstable_by(by_distance_then_id);
        out
    }
}

impl VisibilityCache {
    /// Inserts a record traced earlier (by [`Self::trace`]) when `wanted(state)` still holds
    /// under the write lock, counting its rays either way (they were spent). Returns the id
    /// inserted, if any (`None` also at `max_records`). Drivers that insert a wave's records
    /// in a fixed order use this to re-check each against those inserted before it.
    pub fn insert_traced_if(
        &self,
        record: &Record,
        rays: RecordRays,
        wanted: impl FnOnce(&CacheState) -> bool,
    ) -> Result<Option<u32>> {
        self.write()
            .insert_traced_if(&self.params, record, rays, wanted)
    }
}

impl CacheState {
    /// [`VisibilityCache::insert_traced_if`] under a write lock already held.
    pub(crate) fn insert_traced_if(
        &mut self,
        params: &CacheParams,
        record: &Record,
        rays: RecordRays,
        wanted: impl FnOnce(&CacheState) -> bool,
    ) -> Result<Option<u32>> {
        super::count_rays(&mut self.counters, rays);
        if !wanted(self) {
            return Ok(None);
        }
        self.push(params, record)
    }
}
