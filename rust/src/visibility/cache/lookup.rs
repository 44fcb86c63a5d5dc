//! §5.1 lookups (eq. 9, Fig. 7): the records a point keeps with their `β`, §5.2's
//! insertion figures (`max w_i`, `δ̄`), and `Ṽ = Σ β_i V_i`.

use glam::Vec3;
use rayon::prelude::*;
use std::sync::atomic::Ordering;

use super::{CacheState, LookupScratch, VisibilityCache};
use crate::error::{Error, Result};
use crate::parallel::with_threads;
use crate::sampling::octahedral::morton_decode;
use crate::spatial::{with_thread_scratch, Hits};
use crate::visibility::params::{CacheParams, MAX_KEEP_COUNT};
use crate::visibility::record::VisibilityView;

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

impl CacheState {
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

impl VisibilityCache {
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
}
