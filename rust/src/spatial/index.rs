//! The index proper: records' sites in the kd-tree and in chains, the gathering of a
//! lookup's neighbourhood and the `m` nearest matching records.

use std::sync::atomic::{AtomicU64, Ordering};

use glam::Vec3;

use super::candidates::{candidate_key, key_d2};
use super::score::Hits;
use super::scratch::LookupScratch;
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

    /// Validity radius of record `id`, world units (`f32::INFINITY`: unbounded).
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
    /// (the index keeps copies): [`Self::rebuild`] changes those.
    pub fn records_mut(&mut self) -> &mut S {
        &mut self.records
    }

    /// Changes the records by `change` (removals, moves), then rebuilds the index balanced.
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
    /// hold position, normal and id inline: 28 B per record, at leaf fills of one half to
    /// whole), spare capacity included.
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
        let m = weighting.m;
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
            candidates.push(candidate_key(d2, gathered.id(k as usize)), j as u32);
        }
        let mut i = 0;
        candidates.for_each_least(m, |key, j| {
            let j = j as usize;
            hits.key[i] = key;
            hits.d2[i] = key_d2(key);
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
            let (first, most) = LookupScratch::WIDE_RETRY;
            scratch.wide_interval = if coherent || scratch.wide_interval == 0 {
                first
            } else if scratch.wide {
                (2 * scratch.wide_interval).min(most)
            } else {
                scratch.wide_interval
            };
            let wide = coherent || scratch.until_wide == 0;
            scratch.until_wide = if wide {
                scratch.wide_interval
            } else {
                scratch.until_wide - 1
            };
            scratch.wide = wide;
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

    /// Appends a record by `push` (which returns its id, the next one: ids are dense) and
    /// indexes it. The record's position must be finite.
    pub fn admit(&mut self, push: impl FnOnce(&mut S) -> Result<usize>) -> Result<u32> {
        let id = push(&mut self.records)? as u32;
        self.sites.push(Site::of(&self.records, id as usize));
        self.generation = next_generation();
        self.chain_tail.push(id);
        self.index(id);
        Ok(id)
    }

    /// Puts record `id` (the newest) into the tree, or at the end of the chain of a record
    /// with the same position.
    fn index(&mut self, id: u32) {
        let site = self.sites[id as usize];
        if let Some(head) = self.tree.insert((site.position, site.normal, id)) {
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
                (site.position, site.normal, id)
            })
            .collect();
        self.tree = SiteTree::build(entries);
    }
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
