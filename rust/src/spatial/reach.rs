//! Records by reach: which records cover a point, and how much.
//!
//! A record's reach is its validity radius `R_i` ([`super::Records::radius`], world units,
//! `∞` unbounded). Record `i` covers `x` when `|x − p_i| < R_i` (strict: a record reaches
//! nothing at its border, nor anything at all when `R_i` is 0 or NaN). With the squared
//! distance `d² = |p_i − x|²` summed as the kd-tree sums it ([`distance2`]), the test is
//! `√d² < R_i` ([`reaches`]), the form callers that weight by `1 − d/R_i` need: it keeps
//! that factor above 0.
//!
//! [`super::SpatialIndex::within_reach`] finds every covering record with the survey's
//! Algorithm 3 (ch. 3; its multiply referenced octree replaced by bounds on the kd-tree's
//! nodes, module `tree`), in id order so that sums over them come out bit for bit alike
//! for any tree shape. The bounds are `max(R_i, 0)` (`reach_bound`) per leaf lane and its
//! square per node, over the records under it; the index takes them from the records on
//! insertion and rebuild, and [`super::SpatialIndex::refresh_reach`] retakes them after
//! radii change. While no radius has changed since, a lane's bound is its record's reach
//! and queries test it without reading the records.
//!
//! ## Gathering
//! Queries go through a gathered set (`ReachScratch`, one per thread), as the
//! `m`-nearest lookups do (module `scratch`): the records that may cover some point
//! within `ρ` of an anchor (`|c − p_i| < R_i + ρ`, with a margin for rounding), with their
//! reach as read then, sorted by id once. A query within `ρ` of the anchor filters them
//! sixteen at a time and its answer comes out in id order without a sort of its own. The
//! set is valid while the index and its radii are unchanged (each admission, rebuild,
//! refresh and [`super::SpatialIndex::records_mut`] draws a new reach generation). Queries
//! in pixel order gather wide (`ρ` a few steps of the walk, the anchor ahead along it);
//! scattered ones query the tree at their point and sort what it finds (`sort_by_key`),
//! trying a wide gathering now and then, as the `m`-nearest lookups do. On benches/reach_query.rs's floor (100k records, spacing
//! 1; thread CPU time on a loaded machine), pixel-order queries took 130 ns at reaches 1–3
//! (13.6 records found) and 1.0 µs at 1–30 (928 found), against 380 ns and 10 µs with a
//! tree query and a sort each; scattered queries 0.5 µs and 12 µs either way.
//!
//! [`coverage`] is the test shared by the caches that insert a record where none covers a
//! point well enough: `max_i w_i · (1 − d_i / R_i)` over the records found (CAM08 §6.1 for
//! ambient occlusion; the irradiance cache's usability test has the same shape).

use glam::Vec3;

use super::gathered::GatheredSites;
use super::tree::{QueryScratch, ReachQueryScratch};
use crate::simd::{Kernel, Level, SimdLevel};

/// `|p − x|²` summed as the kd-tree's range and reach queries sum it: `x`, `y`, `z` terms
/// left to right, each product rounded (no fused multiply-add).
#[inline]
pub fn distance2(p: Vec3, x: Vec3) -> f32 {
    let (ex, ey, ez) = (p.x - x.x, p.y - x.y, p.z - x.z);
    ex * ex + ey * ey + ez * ez
}

/// Does a record of reach `radius` at squared distance `d2` ([`distance2`]) cover the
/// point: `√d2 < radius` (false for NaN either side).
#[inline]
pub fn reaches(d2: f32, radius: f32) -> bool {
    d2.sqrt() < radius
}

/// The bound the index keeps for a record of reach `radius`: `max(radius, 0)` (NaN counts
/// as 0, `∞` stays `∞`), which covers exactly the points `radius` covers.
#[inline]
pub(super) fn reach_bound(radius: f32) -> f32 {
    radius.max(0.0)
}

/// [`reach_bound`] squared. Whenever [`reaches`]`(d2, radius)`, `d2 <= reach_bound2(radius)`:
/// `√d2 < R` puts `d2` below `R²`, and rounding `R²` cannot take it under `d2`, a float.
#[inline]
pub(super) fn reach_bound2(radius: f32) -> f32 {
    let r = reach_bound(radius);
    r * r
}

/// `1 − d / R`, the share of a record's reach `R` (world units) left at distance `d`:
/// 1 for an unbounded (or NaN) `R`, 0 at and beyond the border, even for `R = 0` and
/// `d = 0` (a record with no reach covers nothing, its own point included).
#[inline]
pub fn reach_factor(distance: f32, radius: f32) -> f32 {
    if !radius.is_finite() {
        1.0
    } else if distance < radius {
        1.0 - distance / radius
    } else {
        0.0
    }
}

/// `max_i w_i · (1 − d_i / R_i)` over `(w_i, d_i, R_i)` (weight, distance and reach in world
/// units, [`reach_factor`]), 0 when there are none: how well the records found cover a
/// point. Taken in the order given, so equal inputs give equal bits.
pub fn coverage(candidates: impl IntoIterator<Item = (f32, f32, f32)>) -> f32 {
    candidates
        .into_iter()
        .map(|(w, d, r)| w * reach_factor(d, r))
        .fold(0.0, f32::max)
}

/// Working space of the index's reach and radius queries, one per thread: the gathered
/// set of the reach queries (module docs) and the buffers of both, kept between calls so
/// that queries allocate nothing once warm.
#[derive(Debug, Default)]
pub(super) struct ReachScratch {
    /// Working space of the kd-tree's reach query.
    pub(super) reach: ReachQueryScratch,
    /// Working space of the kd-tree's range query, and the records it finds.
    pub(super) range: QueryScratch,
    pub(super) sites: GatheredSites,
    /// The reach generation of the index the gathered set comes from (0: none).
    pub(super) generation: u64,
    /// Centre and radius `ρ` of the ball whose points the gathered set serves.
    pub(super) anchor: Vec3,
    pub(super) rho: f32,
    /// The point of the last query.
    pub(super) previous: Vec3,
    /// The distance of the farthest record found by the last query (0 when none): `ρ`
    /// stays within half of it, so that a wide gathering holds a few times the records of
    /// a query, not the whole index.
    pub(super) scale: f32,
    /// Queries served by the current gathering.
    pub(super) served: u32,
    /// Whether the current gathering is wide, the exact gatherings left before the next
    /// wide try, and the interval between tries (0: not yet set).
    pub(super) wide: bool,
    pub(super) until_wide: u32,
    pub(super) wide_interval: u32,
    /// Records found while gathering, and room to sort them (and radius queries' answers).
    pub(super) found: Vec<Reached>,
    pub(super) spare: Vec<Reached>,
    pub(super) pairs: Vec<(u32, f32)>,
    /// The gathered set.
    pub(super) near: NearRecords,
    /// Gatherings so far.
    pub(super) gathers: u64,
}

impl ReachScratch {
    /// `ρ` of a wide gathering in steps of the walk (the distance between the last two
    /// queries), at most half the distance of the farthest record the last query found.
    /// The anchor lies `ANCHOR_AHEAD · ρ` ahead, so that a straight walk is served for
    /// about `(1 + ANCHOR_AHEAD) · WIDE_STEPS` steps. Chosen on benches/reach_query.rs's
    /// floor (thread CPU time, pixel order, reaches 1–30 and 1–3): at 1–30, 16 steps took
    /// 0.8x the time of 8, and 4 steps 1.5x; 0.8 ahead 0.85x the time of 0.5; half the
    /// farthest record 0.85x the time of all of it. At 1–3 all were within the noise.
    pub const WIDE_STEPS: f32 = 16.0;
    /// How far ahead of the query, along its step, a wide gathering's anchor lies, in `ρ`
    /// (below 1: the query stays in the ball; see [`Self::WIDE_STEPS`]).
    pub const ANCHOR_AHEAD: f32 = 0.8;
    /// Exact gatherings between tries of a wide one, at first and at most (as
    /// [`super::LookupScratch::WIDE_RETRY`]).
    pub const WIDE_RETRY: (u32, u32) = (8, 64);
}

/// A record gathered for the reach queries near an anchor: id, position and reach.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Reached {
    pub(super) id: u32,
    pub(super) position: Vec3,
    pub(super) radius: f32,
}

/// Lanes of the filter over a gathered set.
const LANES: usize = 16;

/// A gathered set as structure of arrays in id order, padded to whole groups of [`LANES`]
/// with NaN positions (no query reaches them).
#[derive(Clone, Debug, Default)]
pub(super) struct NearRecords {
    x: Vec<f32>,
    y: Vec<f32>,
    z: Vec<f32>,
    radius: Vec<f32>,
    id: Vec<u32>,
}

impl NearRecords {
    /// Holds `records` (in id order), padded.
    pub(super) fn fill(&mut self, records: &[Reached]) {
        let padded = records.len().next_multiple_of(LANES);
        for v in [&mut self.x, &mut self.y, &mut self.z, &mut self.radius] {
            v.clear();
        }
        self.id.clear();
        for r in records {
            self.x.push(r.position.x);
            self.y.push(r.position.y);
            self.z.push(r.position.z);
            self.radius.push(r.radius);
            self.id.push(r.id);
        }
        for v in [&mut self.x, &mut self.y, &mut self.z] {
            v.resize(padded, f32::NAN);
        }
        self.radius.resize(padded, 0.0);
        self.id.resize(padded, u32::MAX);
    }

    /// Appends to `out` the records that cover `x` ([`reaches`] on [`distance2`]), in the
    /// set's order, as `(id, d²)`; returns the largest `d²` appended (0 when none).
    pub(super) fn covering(&self, x: Vec3, out: &mut Vec<(u32, f32)>) -> f32 {
        crate::simd::dispatch_avx512(CoveringKernel { near: self, x, out })
    }

    fn covering_portable(&self, x: Vec3, out: &mut Vec<(u32, f32)>) -> f32 {
        let mut most = 0.0f32;
        for k in 0..self.x.len() {
            let d2 = distance2(Vec3::new(self.x[k], self.y[k], self.z[k]), x);
            if reaches(d2, self.radius[k]) {
                out.push((self.id[k], d2));
                most = most.max(d2);
            }
        }
        most
    }

    /// [`Self::covering_portable`] sixteen lanes at a time: the distance and the square
    /// root as the scalar forms compute them (both correctly rounded), a mask, then the
    /// passing lanes' ids and distances compressed and interleaved into pairs in
    /// registers, stored whole (a loop over the mask's bits mispredicts at every lane when
    /// most pass). Pairs are stored as `u32` words: only while `(u32, f32)` is laid out as
    /// two such words ([`PAIRS_AS_WORDS`]), else one by one.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    #[inline(never)]
    fn covering_avx512(&self, x: Vec3, out: &mut Vec<(u32, f32)>) -> f32 {
        use std::arch::x86_64::*;
        let q = [x.x, x.y, x.z].map(|v| _mm512_set1_ps(v));
        let mut most = _mm512_setzero_ps();
        // Word k of the pairs: id k / 2 (k even) or distance k / 2 (from the second source).
        let first = _mm512_setr_epi32(0, 16, 1, 17, 2, 18, 3, 19, 4, 20, 5, 21, 6, 22, 7, 23);
        let second = _mm512_add_epi32(first, _mm512_set1_epi32(8));
        let start = out.len();
        // Whole stores reach 16 pairs past the last written.
        out.reserve(self.x.len() + LANES);
        let room = out.spare_capacity_mut();
        let mut len = 0;
        for c in (0..self.x.len()).step_by(LANES) {
            // SAFETY: `c + 16 <= len`, the padded length of every array; stores go to
            // `room[len..len + 16]`, within it (`len` grows by at most 16 a group and stays
            // below the gathered records).
            unsafe {
                let (_, d2) = super::gathered::offsets_avx512(
                    self.x.as_ptr().add(c),
                    self.y.as_ptr().add(c),
                    self.z.as_ptr().add(c),
                    q,
                );
                let radius = _mm512_loadu_ps(self.radius.as_ptr().add(c));
                let pass = _mm512_cmp_ps_mask::<_CMP_LT_OQ>(_mm512_sqrt_ps(d2), radius);
                if pass == 0 {
                    continue;
                }
                most = _mm512_mask_max_ps(most, pass, most, d2);
                let id = _mm512_loadu_si512(self.id.as_ptr().add(c).cast());
                let ids = _mm512_maskz_compress_epi32(pass, id);
                let d2s = _mm512_castps_si512(_mm512_maskz_compress_ps(pass, d2));
                let count = pass.count_ones() as usize;
                if PAIRS_AS_WORDS {
                    let at = room.as_mut_ptr().add(len).cast::<u32>();
                    _mm512_storeu_si512(at.cast(), _mm512_permutex2var_epi32(ids, first, d2s));
                    if count > LANES / 2 {
                        let rest = _mm512_permutex2var_epi32(ids, second, d2s);
                        _mm512_storeu_si512(at.add(LANES).cast(), rest);
                    }
                } else {
                    let (mut i, mut d) = ([0u32; LANES], [0.0f32; LANES]);
                    _mm512_storeu_si512(i.as_mut_ptr().cast(), ids);
                    _mm512_storeu_si512(d.as_mut_ptr().cast(), d2s);
                    for k in 0..count {
                        room[len + k].write((i[k], d[k]));
                    }
                }
                len += count;
            }
        }
        // SAFETY: the first `len` slots past `start` were written above.
        unsafe { out.set_len(start + len) };
        _mm512_reduce_max_ps(most)
    }
}

/// Whether a `(u32, f32)` is two 4-byte words, the `u32` first (Rust does not promise a
/// tuple's layout; [`NearRecords::covering`] stores pairs whole only when it holds).
const PAIRS_AS_WORDS: bool = std::mem::size_of::<(u32, f32)>() == 8
    && std::mem::offset_of!((u32, f32), 0) == 0
    && std::mem::offset_of!((u32, f32), 1) == 4;

/// [`NearRecords::covering`] as a [`Kernel`]: its AVX-512 form, else the portable one.
struct CoveringKernel<'a> {
    near: &'a NearRecords,
    x: Vec3,
    out: &'a mut Vec<(u32, f32)>,
}

impl Kernel for CoveringKernel<'_> {
    type Output = f32;

    #[inline(always)]
    fn run<L: Level>(self, _level: L) -> f32 {
        let Self { near, x, out } = self;
        match L::LEVEL {
            // SAFETY: a value of `L` exists only on CPUs with `L::LEVEL` (`Level`'s
            // contract), here AVX-512 F.
            #[cfg(target_arch = "x86_64")]
            SimdLevel::Avx512 => unsafe { near.covering_avx512(x, out) },
            _ => near.covering_portable(x, out),
        }
    }
}

/// Sorts `items` by `key` (distinct keys): by least significant digit radix sort through
/// `spare` from [`RADIX_FROM`] items on, by comparison below. A pass takes a digit of
/// about `log2(len) + 1` bits (4 to 11: the counts stay about as many as the items), as
/// many passes as the largest key needs. Measured on ids below 100k, on a loaded machine:
/// 32 items 0.29 µs against 0.33 µs by comparison, 128 items 0.8 µs against 2.7 µs, 1000
/// items 5.8 µs against 20 µs.
pub(super) fn sort_by_key<T: Copy + Default>(
    items: &mut [T],
    spare: &mut Vec<T>,
    key: impl Fn(&T) -> u32,
) {
    if items.len() < RADIX_FROM {
        items.sort_unstable_by_key(&key);
        return;
    }
    let largest = items.iter().map(&key).max().unwrap_or(0);
    let bits = (u32::BITS - largest.leading_zeros()).max(1);
    let passes = bits.div_ceil((usize::BITS - items.len().leading_zeros()).clamp(4, 11));
    let digit = bits.div_ceil(passes);
    let buckets = 1usize << digit;
    let mask = (buckets - 1) as u32;
    spare.clear();
    spare.resize(items.len(), T::default());
    let mut counts = [0u32; 1 << 11];
    let counts = &mut counts[..buckets];
    let mut in_spare = false;
    for pass in 0..passes {
        let shift = pass * digit;
        let (from, to): (&[T], &mut [T]) = if in_spare {
            (&spare[..], &mut *items)
        } else {
            (&*items, &mut spare[..])
        };
        counts.fill(0);
        for item in from.iter() {
            counts[((key(item) >> shift) & mask) as usize] += 1;
        }
        let mut sum = 0;
        for c in counts.iter_mut() {
            (*c, sum) = (sum, sum + *c);
        }
        for item in from {
            let bucket = &mut counts[((key(item) >> shift) & mask) as usize];
            to[*bucket as usize] = *item;
            *bucket += 1;
        }
        in_spare = !in_spare;
    }
    if in_spare {
        items.copy_from_slice(spare);
    }
}

/// Items from which [`sort_by_key`] sorts by radix.
const RADIX_FROM: usize = 32;

thread_local! {
    static REACH_SCRATCH: std::cell::RefCell<ReachScratch> = Default::default();
}

/// Runs `f` with this thread's [`ReachScratch`] (a fresh one if it is in use).
pub(super) fn with_reach_scratch<R>(f: impl FnOnce(&mut ReachScratch) -> R) -> R {
    REACH_SCRATCH.with(|cell| match cell.try_borrow_mut() {
        Ok(mut scratch) => f(&mut scratch),
        Err(_) => f(&mut ReachScratch::default()),
    })
}

#[cfg(test)]
mod tests;
