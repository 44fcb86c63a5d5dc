//! The index proper: records' sites in the kd-tree and in chains, the gathering of a
//! lookup's neighbourhood and the `m` nearest matching records.

use std::sync::atomic::{AtomicU64, Ordering};

use glam::Vec3;

use super::candidates::candidate_key;
use super::reach::{
    distance2, reach_bound, reach_bound2, reaches, sort_by_key, with_reach_scratch, ReachScratch,
    Reached,
};
use super::score::Hits;
use super::scratch::{next_gather_is_wide, LookupScratch};
use super::tree::SiteTree;
use super::weight::{normal_angle, Weighting};
use crate::error::Result;

/// End of a chain of records sharing one position.
const NO_RECORD: u32 = u32::MAX;

/// The records a [`SpatialIndex`] indexes, by dense id `0..len()`: what the index reads of
/// each, the payload being the implementor's own (visibility maps, irradiance, …).
pub trait Records {
    /// Number of records.
    fn len(&self) -> usize;

    /// True without records.
    fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Position (finite, world units) and unit normal of record `id`.
    fn site(&self, id: usize) -> (Vec3, Vec3);

    /// Validity radius (reach) of record `id`, world units (`f32::INFINITY`: unbounded;
    /// 0 or NaN: reaches nothing), read by [`SpatialIndex::within_reach`]. The index
    /// bounds it when the record is admitted or re-indexed: it may shrink afterwards, not
    /// grow, until [`SpatialIndex::refresh_reach`].
    fn radius(&self, _id: usize) -> f32 {
        f32::INFINITY
    }

    /// Asks the CPU for the payload of record `id` ahead of a lookup that will read it
    /// (only a hint; by default nothing).
    #[inline(always)]
    fn prefetch(&self, _id: usize) {}
}

/// Records with position, normal and validity radius in a kd-tree (module docs of
/// [`crate::spatial`]). Ids are dense and stable until [`Self::rebuild`].
#[derive(Clone, Debug)]
pub struct SpatialIndex<S> {
    records: S,
    tree: SiteTree,
    /// Each record's position, decoded normal and chain link, by id: what the tree takes
    /// on insertion and rebuilds, and what lookups read of chained records (the tree
    /// holds only the first record at each position).
    sites: Vec<Site>,
    /// Changes with every insertion and re-index (see [`LookupScratch`]).
    generation: u64,
    /// Changes with every insertion, re-index, refresh of the reach bounds and access to
    /// the records that may change radii (see [`ReachScratch`]).
    reach_generation: u64,
    /// Whether the tree's lane bounds are exactly the reaches of their records (no radius
    /// changed through [`Self::records_mut`] since the last re-index or refresh).
    reach_exact: bool,
    /// Last record of each chain, indexed by its head (only valid for heads).
    chain_tail: Vec<u32>,
    /// Records that are not the first at their position (in a chain, not in the tree).
    chained: usize,
}

impl<S: Records> SpatialIndex<S> {
    /// An index over `records` (balanced when they are not empty).
    pub fn new(records: S) -> Self {
        let mut index = Self {
            records,
            tree: SiteTree::default(),
            sites: Vec::new(),
            generation: next_generation(),
            reach_generation: next_generation(),
            reach_exact: true,
            chain_tail: Vec::new(),
            chained: 0,
        };
        if !index.records.is_empty() {
            index.reindex();
        }
        index
    }

    /// The records.
    pub fn records(&self) -> &S {
        &self.records
    }

    /// The records, to change their payloads; positions and normals must stay as they are
    /// (the index keeps copies): [`Self::rebuild`] changes those. Radii may be lowered
    /// (the index's bounds on them stay valid, only looser: [`Self::refresh_reach`]
    /// tightens them), not raised without a [`Self::refresh_reach`] before the next
    /// [`Self::within_reach`].
    pub fn records_mut(&mut self) -> &mut S {
        self.reach_generation = next_generation();
        self.reach_exact = false;
        &mut self.records
    }

    /// Changes the records by `change` (removals, moves, radii), then rebuilds the index
    /// balanced, its reach bounds exact.
    pub fn rebuild(&mut self, change: impl FnOnce(&mut S)) {
        change(&mut self.records);
        self.reindex();
    }

    /// Number of records.
    pub fn len(&self) -> usize {
        self.sites.len()
    }

    /// True without records.
    pub fn is_empty(&self) -> bool {
        self.sites.is_empty()
    }

    /// Position and decoded unit normal of record `id`, as the index holds them.
    pub fn site(&self, id: usize) -> (Vec3, Vec3) {
        (self.sites[id].position, self.sites[id].normal)
    }

    /// Bytes of the index on top of the records: per record its site (position, decoded
    /// normal, chain link: 28 B) and chain tail (4 B), and the tree with its leaves (which
    /// hold position, normal and id inline, 28 B per record, with a reach bound beside,
    /// 4 B, at leaf fills of one half to whole), spare capacity included.
    pub fn memory_bytes(&self) -> usize {
        self.len() * (std::mem::size_of::<Site>() + 4) + self.tree.memory_bytes()
    }

    /// The `m` nearest records (ties by id) among those within `d_max` of `x` whose
    /// normals differ from the unit `n` by `θ_i < θ_max`, in no particular order, with
    /// their eq. 9 weights (all as `weighting` says). Shared positions are expanded. The
    /// visibility cache's lookups (§5.1) and its ambient occlusion (§6.1) start from this
    /// set. An empty index or a non-positive or non-finite `d_max` finds nothing.
    pub(crate) fn m_nearest<'b>(
        &self,
        weighting: &Weighting,
        x: Vec3,
        n: Vec3,
        d_max: f32,
        scratch: &'b mut LookupScratch,
    ) -> &'b Hits {
        scratch.hits.len = 0;
        if self.sites.is_empty() || !(d_max > 0.0 && d_max.is_finite()) {
            return &scratch.hits;
        }
        let (m, metric) = (weighting.m, weighting.metric);
        let theta_max = weighting.theta_max;
        let cos_max = theta_max.cos();
        self.gather(x, d_max, scratch);
        let LookupScratch {
            sites: gathered,
            passed,
            candidates,
            hits,
            ..
        } = scratch;
        // θ_i < θ_max (strict, as in §5.1). Only cosines within 1e-3 of θ_max's need the
        // angle to decide; the filter drops those clearly out, and θ is computed for the m
        // kept alone.
        let (loose, tight) = (cos_max - 1e-3, cos_max + 1e-3);
        gathered.filter(x, n, d_max * d_max, loose, passed);
        candidates.clear();
        for (j, (&k, &d2)) in passed.index.iter().zip(&passed.d2).enumerate() {
            if passed.cos[j] <= tight {
                let theta = normal_angle(passed.sin[j], passed.cos[j]);
                if theta.partial_cmp(&theta_max) != Some(std::cmp::Ordering::Less) {
                    continue;
                }
            }
            let key = metric.key(d2, passed.cos[j]);
            candidates.push(candidate_key(key, gathered.id(k as usize)), j as u32);
        }
        let mut i = 0;
        candidates.for_each_least(m, |key, j| {
            let j = j as usize;
            hits.key[i] = key;
            hits.d2[i] = passed.d2[j];
            hits.cos[i] = passed.cos[j];
            hits.sin[i] = passed.sin[j];
            hits.along[i] = passed.along[j];
            i += 1;
        });
        hits.len = i;
        hits.score(weighting, d_max);
        hits
    }

    /// Leaves in `scratch.sites` the records that may lie within `d_max` of `x`: those it
    /// holds when its gathered ball covers this one, else a new gathering (one kd-tree range
    /// query) of radius `LookupScratch::REACH · d_max` around `x` or just ahead of it, or
    /// of radius `d_max` around `x` when lookups come scattered.
    fn gather(&self, x: Vec3, d_max: f32, scratch: &mut LookupScratch) {
        // A margin of 1e-5 keeps rounding of the distances on the safe side: a record
        // within d_max of x is within (|x − anchor| + d_max)(1 + 1e-6) of the anchor.
        let covered = scratch.generation == self.generation
            && (x - scratch.anchor).length() + d_max <= scratch.reach * (1.0 - 1e-5);
        let previous = std::mem::replace(&mut scratch.previous, x);
        if covered {
            scratch.served += 1;
        } else {
            // Gather wide while that pays (the last gathering served another lookup); in
            // scattered order a wide ball costs four times the records for nothing, so
            // gather exactly, and try wide again after a while, less often each time a
            // try serves nothing more.
            let coherent = scratch.served > 1;
            let wide = next_gather_is_wide(
                scratch.served,
                &mut scratch.wide,
                &mut scratch.until_wide,
                &mut scratch.wide_interval,
                LookupScratch::WIDE_RETRY,
            );
            scratch.gathers = scratch.gathers.wrapping_add(1);
            let reach = if wide { LookupScratch::REACH } else { 1.0 } * d_max;
            // Lookups in pixel order walk on: a wide ball centred ahead of `x`, along the
            // last step, serves twice the lookups of one centred on it (those behind are
            // done). It must still cover this lookup's ball, or it is centred on `x`.
            let step = x - previous;
            let step_length = step.length();
            let mut anchor = x;
            if wide && step_length > 0.0 && step_length < d_max {
                let ahead = x + step * ((LookupScratch::REACH - 1.0) * 0.9 * d_max / step_length);
                if (x - ahead).length() + d_max <= reach * (1.0 - 1e-5) {
                    anchor = ahead;
                }
            }
            scratch.served = 1;
            scratch.generation = self.generation;
            scratch.anchor = anchor;
            scratch.reach = reach;
            scratch.sites.clear();
            self.tree.within(
                anchor,
                reach * reach,
                &mut scratch.query,
                &mut scratch.sites,
            );
            if self.chained > 0 {
                for k in 0..scratch.sites.len() {
                    let mut id = self.sites[scratch.sites.id(k) as usize].next;
                    while id != NO_RECORD {
                        let site = &self.sites[id as usize];
                        scratch.sites.push((site.position, site.normal, id));
                        id = site.next;
                    }
                }
            }
            scratch.sites.seal();
            // The lookups served from a wide gathering compare the maps of the records they
            // keep (δ̄); these are among the gathered, so fetch their bits ahead while the
            // walk is coherent. (A lookup alone needs the maps of n of them: fetching all
            // would only crowd those out.)
            if coherent && scratch.sites.len() <= PREFETCH_MAPS {
                for k in 0..scratch.sites.len() {
                    self.records.prefetch(scratch.sites.id(k) as usize);
                }
            }
        }
    }

    /// Every record `i` whose reach covers `x`, `|x − p_i| < radius(i)` ([`reaches`]: strict,
    /// `∞` reaches everywhere, 0 and NaN nowhere), records sharing a position included:
    /// appended to `out` as `(id, |p_i − x|²)` ([`distance2`]) in id order, so that sums
    /// over them have the same bits whatever the tree's shape and the order of queries.
    /// Filters the thread's gathered set when it serves `x` or a wide gathering is due, else
    /// queries the kd-tree at `x` (module `reach`): its nodes whose reach bound admits `x`
    /// or the ball gathered (survey ch. 3, Algorithm 3), then each record by its radius.
    /// Allocates nothing once `out` and the thread's working space have grown. A
    /// non-finite `x` finds nothing.
    pub fn within_reach(&self, x: Vec3, out: &mut Vec<(u32, f32)>) {
        with_reach_scratch(|scratch| {
            if self.gather_reach(x, scratch) {
                scratch.scale = scratch.near.covering(x, out).sqrt();
                return;
            }
            let start = out.len();
            let mut most = 0.0f32;
            self.tree
                .within_reach(x, 0.0, &mut scratch.reach, |head, d2, _, lane| {
                    self.for_chain(head, lane, |id, radius| {
                        if reaches(d2, radius) {
                            out.push((id, d2));
                            most = most.max(d2);
                        }
                    })
                });
            sort_by_key(&mut out[start..], &mut scratch.pairs, |&(id, _)| id);
            scratch.scale = most.sqrt();
        });
    }

    /// Whether `scratch.near` serves `x`: when its ball holds `x`, or after a new wide
    /// gathering while queries come in a walk; not when they come scattered (module
    /// `reach`), and then the set is dropped.
    fn gather_reach(&self, x: Vec3, scratch: &mut ReachScratch) -> bool {
        // A margin of 1e-5 keeps rounding on the safe side, as in `gather`.
        let covered = scratch.generation == self.reach_generation
            && (x - scratch.anchor).length() <= scratch.rho * (1.0 - 1e-5);
        let previous = std::mem::replace(&mut scratch.previous, x);
        if covered {
            scratch.served += 1;
            return true;
        }
        // Wide while that pays, else exact with a wide try now and then (less often each
        // time a try serves nothing more), as `gather` decides.
        let wide = next_gather_is_wide(
            scratch.served,
            &mut scratch.wide,
            &mut scratch.until_wide,
            &mut scratch.wide_interval,
            ReachScratch::WIDE_RETRY,
        );
        let step = x - previous;
        let step_length = step.length();
        let mut rho = 0.0;
        let mut anchor = x;
        if wide && step_length > 0.0 && step_length.is_finite() {
            rho = (ReachScratch::WIDE_STEPS * step_length).min(0.5 * scratch.scale);
            let ahead = x + step * (ReachScratch::ANCHOR_AHEAD * rho / step_length);
            if (x - ahead).length() <= rho * (1.0 - 1e-5) {
                anchor = ahead;
            }
        }
        scratch.served = 1;
        scratch.gathers = scratch.gathers.wrapping_add(1);
        if rho == 0.0 {
            // A query of its own serves this point alone: no set to gather.
            scratch.generation = 0;
            return false;
        }
        scratch.generation = self.reach_generation;
        scratch.anchor = anchor;
        scratch.rho = rho;
        let ReachScratch {
            reach,
            found,
            spare,
            near,
            ..
        } = scratch;
        found.clear();
        // Every record that covers some point within ρ of the anchor: `|c − p| < R + ρ`,
        // with a margin of 1e-5 (under the tree's, 2e-5) for the rounding of both
        // distances.
        self.tree
            .within_reach(anchor, rho, reach, |head, d2, position, lane| {
                let d = d2.sqrt();
                self.for_chain(head, lane, |id, radius| {
                    if radius > 0.0 && d < (radius + rho) * (1.0 + 1e-5) {
                        found.push(Reached {
                            id,
                            position,
                            radius,
                        });
                    }
                })
            });
        sort_by_key(found, spare, |r| r.id);
        near.fill(found);
        true
    }

    /// Calls `f(id, reach)` for `head` and each record chained to it, with `lane`, the
    /// bound of `head`'s lane, for the reach while the lanes are exact and unchained (a
    /// lane's 0 stands for a reach of 0, NaN or below: none covers anything), else with
    /// the records' radii (one cache miss per record) and chain links.
    #[inline(always)]
    fn for_chain(&self, head: u32, lane: f32, mut f: impl FnMut(u32, f32)) {
        if self.reach_exact && self.chained == 0 {
            return f(head, lane);
        }
        let mut id = head;
        loop {
            f(id, self.records.radius(id as usize));
            if self.chained == 0 {
                return;
            }
            id = self.sites[id as usize].next;
            if id == NO_RECORD {
                return;
            }
        }
    }

    /// Every record within `r` of `x` (`|x − p_i| < r`, [`reaches`]), records sharing a
    /// position included: appended to `out` as `(id, |p_i − x|²)` in id order. A
    /// non-positive, NaN `r` or non-finite `x` finds nothing; `r = ∞` finds every record.
    pub fn within_radius(&self, x: Vec3, r: f32, out: &mut Vec<(u32, f32)>) {
        if self.sites.is_empty() || r.is_nan() || r <= 0.0 {
            return;
        }
        let start = out.len();
        with_reach_scratch(|scratch| {
            scratch.sites.clear();
            self.tree
                .within(x, reach_bound2(r), &mut scratch.range, &mut scratch.sites);
            for k in 0..scratch.sites.len() {
                let d2 = distance2(scratch.sites.position(k), x);
                if reaches(d2, r) {
                    let mut id = scratch.sites.id(k);
                    while id != NO_RECORD {
                        out.push((id, d2));
                        id = self.sites[id as usize].next;
                    }
                }
            }
            sort_by_key(&mut out[start..], &mut scratch.pairs, |&(id, _)| id);
        });
    }

    /// Sets the kd-tree's reach bounds exact from the records' radii, in one pass over the
    /// records and the tree (about as long as one insertion per record would take). Needed
    /// after radii grow through [`Self::records_mut`]; after they shrink (the irradiance
    /// cache's neighbour clamping), answers stay exact without it and only the pruning of
    /// [`Self::within_reach`] loosens: refresh once in a while (say after each wave of
    /// insertions), not after every change. [`Self::rebuild`] refreshes too.
    pub fn refresh_reach(&mut self) {
        let Self {
            records,
            tree,
            sites,
            ..
        } = self;
        tree.refresh_reach(|head| chain_reach(records, sites, head));
        self.reach_generation = next_generation();
        self.reach_exact = true;
    }

    /// Appends a record by `push` (which returns its id, the next one: ids are dense) and
    /// indexes it. The record's position must be finite.
    pub fn admit(&mut self, push: impl FnOnce(&mut S) -> Result<usize>) -> Result<u32> {
        let id = push(&mut self.records)? as u32;
        self.sites.push(Site::of(&self.records, id as usize));
        self.generation = next_generation();
        self.reach_generation = next_generation();
        self.chain_tail.push(id);
        self.index(id);
        Ok(id)
    }

    /// Puts record `id` (the newest) into the tree, or at the end of the chain of a record
    /// with the same position; either way its reach raises the tree's bounds.
    fn index(&mut self, id: u32) {
        let site = self.sites[id as usize];
        let reach = reach_bound(self.records.radius(id as usize));
        if let Some(head) = self.tree.insert((site.position, site.normal, id), reach) {
            self.chain(head, id);
        }
    }

    /// Appends record `id` to the chain of `head`, the first record at its position.
    fn chain(&mut self, head: u32, id: u32) {
        let tail = self.chain_tail[head as usize] as usize;
        self.sites[tail].next = id;
        self.chain_tail[head as usize] = id;
        self.chained += 1;
    }

    /// Rebuilds tree and chains from the records: the first record at each position (in
    /// id order) goes into a balanced tree, the others into its chain.
    fn reindex(&mut self) {
        let n = self.records.len();
        self.sites = (0..n).map(|i| Site::of(&self.records, i)).collect();
        self.generation = next_generation();
        self.reach_generation = next_generation();
        self.reach_exact = true;
        self.chain_tail = (0..n as u32).collect();
        self.chained = 0;
        let mut heads: Vec<u32> = Vec::with_capacity(n);
        // Position -> first record there, in id order.
        let mut first = std::collections::HashMap::with_capacity(n);
        for id in 0..n as u32 {
            // `+ 0.0` makes −0 and 0 one key, as they are one position to the tree.
            let key = (self.sites[id as usize].position + 0.0)
                .to_array()
                .map(f32::to_bits);
            match first.entry(key) {
                std::collections::hash_map::Entry::Vacant(v) => {
                    v.insert(id);
                    heads.push(id);
                }
                std::collections::hash_map::Entry::Occupied(o) => self.chain(*o.get(), id),
            }
        }
        let entries = heads
            .iter()
            .map(|&id| {
                let site = &self.sites[id as usize];
                let reach = chain_reach(&self.records, &self.sites, id);
                ((site.position, site.normal, id), reach)
            })
            .collect();
        self.tree = SiteTree::build(entries);
    }
}

/// The tree's bound for the lane of `head`: [`reach_bound`] of the largest radius among
/// `head` and the records chained to it.
fn chain_reach<S: Records>(records: &S, sites: &[Site], head: u32) -> f32 {
    let mut bound = f32::NEG_INFINITY;
    let mut id = head;
    while id != NO_RECORD {
        bound = bound.max(reach_bound(records.radius(id as usize)));
        id = sites[id as usize].next;
    }
    bound
}

/// Source of [`SpatialIndex`] generations: every change takes the next number, so no
/// two indexes (clones included) that differ share one. 0 is never drawn (fresh scratches).
static GENERATIONS: AtomicU64 = AtomicU64::new(1);

fn next_generation() -> u64 {
    GENERATIONS.fetch_add(1, Ordering::Relaxed)
}

/// A record as the index reads it.
#[derive(Clone, Copy, Debug)]
struct Site {
    position: Vec3,
    /// Decoded unit normal (a store may keep it quantised; decoding costs a sine and a
    /// cosine, which lookups would otherwise pay per chained candidate).
    normal: Vec3,
    /// The next record with this exact position, or `NO_RECORD`. Only the first record at
    /// a position is in the tree.
    next: u32,
}

impl Site {
    fn of<S: Records>(records: &S, id: usize) -> Self {
        let (position, normal) = records.site(id);
        Site {
            position,
            normal,
            next: NO_RECORD,
        }
    }
}

/// Most gathered records whose payloads [`SpatialIndex::gather`] prefetches.
const PREFETCH_MAPS: usize = 256;

/// Asks the CPU to bring the cache line of `item` closer (no effect off x86-64).
#[inline(always)]
pub fn prefetch<T>(item: &T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: prefetching is a hint and never faults; `item` is a valid reference anyway.
    unsafe {
        use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
        _mm_prefetch::<_MM_HINT_T0>((item as *const T).cast());
    }
}
