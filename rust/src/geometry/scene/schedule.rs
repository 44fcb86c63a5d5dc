//! How a batch of rays is traced: fixed chunks (answers never depend on the thread count);
//! for shadow rays, runs from one origin as packets and bundles in an order of nearby
//! origins; scattered rays, shadow or closest-hit, several at a time where they wait on
//! memory.

use glam::{Vec3, Vec3A};
use obvhs::ploc::morton::morton_encode_u64;
use rayon::prelude::*;

use super::{RayBatch, Scene};
use crate::error::Result;
use crate::geometry::bvh::{Bvh, Hit, OccluderHint, TraversalCounters, PACKET};
use crate::parallel::{map_in_order, with_threads};
use crate::simd::{Kernel, Level};
use crate::stop::Stop;

/// Rays traced per parallel work item; fixed so results never depend on the thread count.
pub(super) const CHUNK: usize = 1024;

/// Shortest run of rays from one origin that [`Scene::occluded`] traces as a packet.
pub const MIN_PACKET: usize = 4;

/// Square of the least cosine between a packet's directions and their mean for
/// [`Scene::occluded`] to trace them together (45°): wider packets share few nodes, and
/// their rays go faster one by one.
const PACKET_COSINE_SQUARED: f32 = 0.5;

/// Smallest batch that [`Scene::occluded`] reorders by origin.
pub(super) const SPATIAL_ORDER_MIN: usize = 1 << 16;

/// Least mean number of node visits per ray, over a sample of a batch, for
/// [`Scene::occluded`] to reorder its bundles by origin or to interleave its scattered rays.
/// 4 rather than 6: `meshes`' incoherent rays (5 visits per ray in a 5 MB tree) 1.1x
/// faster in turns; a better tree of `blob` (built with its objects apart: 5.7 visits
/// against 6.5) was 1.4x slower than the worse one under 6, for falling below it, and as
/// fast under 4. Rays that leave after a node or two (hairball, panels) stay below it,
/// and no other suite scene moved (benches/HISTORY.md, 2026-12-02).
const SPATIAL_ORDER_NODES: f64 = 4.0;

/// Whether `directions` (non-zero) lie within 45° of their sum (their mean direction when
/// they have one length, as record bundles' unit directions do). Squared, so that no
/// direction is normalised (the normalisations were a large share of the batch driver's
/// time on record bundles): `d · m >= cos 45° |d| |m|` as `(d · m)² >= ½ |d|² |m|²` with
/// `d · m > 0`. It only chooses how rays are traced, never what they answer.
fn coherent(directions: &[Vec3A]) -> bool {
    let sum = directions.iter().sum::<Vec3A>();
    let sum_sq = sum.length_squared();
    sum_sq > 0.0
        && directions.iter().all(|d| {
            let along = d.dot(sum);
            along > 0.0 && along * along >= PACKET_COSINE_SQUARED * d.length_squared() * sum_sq
        })
}

/// A run of consecutive rays of a chunk from one origin (compared bit for bit: -0.0 and
/// 0.0 would round apart), at most [`PACKET`] long.
#[derive(Clone, Copy)]
struct OriginRun {
    /// Index of its first ray in the chunk.
    first: usize,
    len: usize,
    /// Whether the next run starts from the same origin.
    origin_continues: bool,
}

impl OriginRun {
    /// The run's directions and `tmax` as a packet (lanes past `len` repeat its last ray),
    /// when it is long enough ([`MIN_PACKET`]) and narrow enough ([`coherent`]); `base` is
    /// the chunk's first ray in `rays`.
    #[inline(always)]
    fn packet(&self, rays: &RayBatch, base: usize) -> Option<([Vec3A; PACKET], [f32; PACKET])> {
        if self.len < MIN_PACKET {
            return None;
        }
        let lane = |l: usize| base + self.first + l.min(self.len - 1);
        let directions: [Vec3A; PACKET] =
            std::array::from_fn(|l| Vec3A::from(rays.directions[lane(l)]));
        coherent(&directions[..self.len])
            .then(|| (directions, std::array::from_fn(|l| rays.tmax_of(lane(l)))))
    }
}

/// Ray `i` of `rays`: origin, direction and `tmax`.
#[inline(always)]
fn ray_at(rays: &RayBatch, i: usize) -> (Vec3A, Vec3A, f32) {
    let (o, d) = (rays.origins[i], rays.directions[i]);
    (Vec3A::from(o), Vec3A::from(d), rays.tmax_of(i))
}

/// The runs of `origins` (a chunk's) from one origin, in order; each origin is read once.
#[inline(always)]
fn origin_runs(origins: &[[f32; 3]]) -> impl Iterator<Item = OriginRun> + '_ {
    let bits = |k: usize| origins.get(k).map(|o| o.map(f32::to_bits));
    let (mut first, mut next) = (0, bits(0));
    std::iter::from_fn(move || {
        let origin = next?;
        let mut len = 1;
        next = bits(first + 1);
        while len < PACKET && next == Some(origin) {
            len += 1;
            next = bits(first + len);
        }
        let run = OriginRun {
            first,
            len,
            origin_continues: next == Some(origin),
        };
        first += len;
        Some(run)
    })
}

/// How [`Scene::occluded`] traces a batch (see [`Scene::trace_order`]).
#[derive(Debug, PartialEq)]
pub(super) enum TraceOrder {
    /// In the order given.
    Given,
    /// In the order given, rays alone at their origin
    /// [`LANES`](crate::geometry::bvh::LANES) at a time in turns
    /// ([`Bvh::occluded_interleaved_at`]).
    Interleaved,
    /// Run after run of rays from one origin (ranges of the batch), in this order.
    Runs(Vec<std::ops::Range<u32>>),
}

/// The runs of consecutive rays from one origin (compared bit for bit) in the order of
/// `key` of their origins (ties in the given order); None when the runs are in that order
/// already.
pub(super) fn bundle_order(
    origins: &[[f32; 3]],
    key: impl Fn(&[f32; 3]) -> u64,
) -> Option<Vec<std::ops::Range<u32>>> {
    let bits = |o: &[f32; 3]| o.map(f32::to_bits);
    let mut runs: Vec<(u64, u32, u32)> = Vec::new();
    let mut start = 0;
    for i in 1..=origins.len() {
        if i == origins.len() || bits(&origins[i]) != bits(&origins[start]) {
            runs.push((key(&origins[start]), start as u32, i as u32));
            start = i;
        }
    }
    if runs.is_sorted() {
        return None;
    }
    runs.sort_unstable();
    Some(runs.into_iter().map(|(_, s, e)| s..e).collect())
}

/// Rays `base..base + out.len()` of a batch, answered into `out` by a [`Kernel`] compiled
/// once per instruction set, with the traversal inlined into its loop (one call and one
/// instruction-set dispatch less per ray): shadow queries into `bool`s ([`Scene::occluded`]),
/// closest hits into `Option<Hit>`s ([`Scene::closest_hits`]). `interleave` asks for
/// scattered rays to be traced several at a time, where the tree allows it
/// ([`Bvh::interleaves`]).
pub(super) struct Chunk<'a, T, const COUNT: bool> {
    pub(super) bvh: &'a Bvh,
    pub(super) rays: &'a RayBatch<'a>,
    pub(super) base: usize,
    pub(super) out: &'a mut [T],
    pub(super) counters: &'a mut TraversalCounters,
    pub(super) interleave: bool,
}

/// The shadow-query chunk kernel.
pub(super) type OccludedChunk<'a, const COUNT: bool> = Chunk<'a, bool, COUNT>;

/// The closest-hit chunk kernel.
pub(super) type ClosestChunk<'a, const COUNT: bool> = Chunk<'a, Option<Hit>, COUNT>;

/// Answers rays `base..base + out.len()` of `rays` into `out` ([`Chunk`]), with counters
/// on or off.
fn trace_chunk<T>(
    counting: bool,
    bvh: &Bvh,
    rays: &RayBatch,
    base: usize,
    out: &mut [T],
    counters: &mut TraversalCounters,
    interleave: bool,
) where
    for<'a> Chunk<'a, T, true>: Kernel<Output = ()>,
    for<'a> Chunk<'a, T, false>: Kernel<Output = ()>,
{
    if counting {
        crate::simd::dispatch(Chunk::<T, true> {
            bvh,
            rays,
            base,
            out,
            counters,
            interleave,
        });
    } else {
        crate::simd::dispatch(Chunk::<T, false> {
            bvh,
            rays,
            base,
            out,
            counters,
            interleave,
        });
    }
}

impl<const COUNT: bool> Kernel for OccludedChunk<'_, COUNT> {
    type Output = ();

    #[inline(always)]
    fn run<L: Level>(self, level: L) {
        let Chunk {
            bvh,
            rays,
            base,
            out,
            counters,
            interleave,
        } = self;
        // No closure for the single-ray traversal: a closure takes the target features of
        // the function that defines it, which here has none, and one left as a call would
        // run the portable target's code.
        occluded_chunk_with::<COUNT, L>(bvh, rays, base, out, counters, interleave, level);
    }
}

impl<const COUNT: bool> Kernel for ClosestChunk<'_, COUNT> {
    type Output = ();

    #[inline(always)]
    fn run<L: Level>(self, level: L) {
        let (bvh, rays, base, out, counters) =
            (self.bvh, self.rays, self.base, self.out, self.counters);
        let interleave = self.interleave && bvh.interleaves::<L>();
        // Rays not in a packet, traced after the loop (in turns where that pays).
        let mut singles = Vec::new();
        // Runs from one origin, a camera's rays, go as packets.
        for run in origin_runs(&rays.origins[base..base + out.len()]) {
            let (k, n) = (run.first, run.len);
            match run.packet(rays, base) {
                Some((directions, tmax)) => {
                    let o = Vec3A::from(rays.origins[base + k]);
                    let hits =
                        bvh.intersect_packet::<COUNT>(o, &directions[..n], &tmax[..n], counters);
                    out[k..k + n].copy_from_slice(&hits[..n]);
                }
                None => singles.extend(k..k + n),
            }
        }
        let ray = |s: usize| ray_at(rays, base + singles[s]);
        if interleave {
            let answer = |s: usize, hit: Option<Hit>| out[singles[s]] = hit;
            bvh.intersect_interleaved_at::<COUNT, L>(singles.len(), ray, answer, counters, level);
        } else {
            for s in 0..singles.len() {
                let (o, d, t) = ray(s);
                out[singles[s]] = bvh.intersect::<COUNT>(o, d, t, counters);
            }
        }
    }
}

/// The loop of [`OccludedChunk`], tracing single rays with the box tests of instruction
/// set `level` ([`Bvh::occluded_hinted_at`], [`Bvh::occluded_interleaved_at`]).
#[inline(always)]
fn occluded_chunk_with<const COUNT: bool, L: Level>(
    bvh: &Bvh,
    rays: &RayBatch,
    base: usize,
    out: &mut [bool],
    counters: &mut TraversalCounters,
    interleave: bool,
    level: L,
) {
    let mut hint = OccluderHint::NONE;
    // Rays alone at their origin, traced together after the loop.
    let interleave = interleave && bvh.interleaves::<L>();
    let mut singles = Vec::new();
    for run in origin_runs(&rays.origins[base..base + out.len()]) {
        let (k, n, i) = (run.first, run.len, base + run.first);
        let o = Vec3A::from(rays.origins[i]);
        if let Some((directions, tmax)) = run.packet(rays, base) {
            let occluded =
                bvh.occluded_packet::<COUNT>(o, &directions[..n], &tmax[..n], &mut hint, counters);
            for (l, slot) in out[k..k + n].iter_mut().enumerate() {
                *slot = occluded >> l & 1 != 0;
            }
        } else if n == 1 && interleave {
            singles.push(k);
        } else {
            // One by one: a run too short or too wide for a packet.
            for (l, slot) in out[k..k + n].iter_mut().enumerate() {
                let (d, t) = (Vec3A::from(rays.directions[i + l]), rays.tmax_of(i + l));
                *slot = bvh.occluded_hinted_at::<COUNT, L>(o, d, t, &mut hint, counters, level);
            }
        }
        // The hint carries over to the next run only when it shares the origin.
        if !run.origin_continues {
            hint = OccluderHint::NONE;
        }
    }
    if !singles.is_empty() {
        let ray = |s: usize| ray_at(rays, base + singles[s]);
        let answer = |s: usize, occluded: bool| out[singles[s]] = occluded;
        bvh.occluded_interleaved_at::<COUNT, L>(singles.len(), ray, answer, counters, level);
    }
}

impl Scene {
    /// Runs `per_ray` over `n` rays in fixed chunks on `threads` workers, collecting the
    /// results in order and adding the chunks' counters to the scene's.
    pub fn map_rays<T: Send + Copy + Default>(
        &self,
        n: usize,
        threads: Option<usize>,
        per_ray: impl Fn(usize, &mut TraversalCounters) -> T + Sync,
    ) -> Result<Vec<T>> {
        self.map_chunks(n, threads, |base, chunk, counters| {
            for (k, slot) in chunk.iter_mut().enumerate() {
                *slot = per_ray(base + k, counters);
            }
        })
    }

    /// Fills the results of `n` rays chunk by chunk on `threads` workers: `per_chunk(base,
    /// out, counters)` answers rays `base..base + out.len()`. Chunks are fixed, so results
    /// never depend on the thread count; their counters are added to the scene's.
    pub fn map_chunks<T: Send + Copy + Default>(
        &self,
        n: usize,
        threads: Option<usize>,
        per_chunk: impl Fn(usize, &mut [T], &mut TraversalCounters) + Sync,
    ) -> Result<Vec<T>> {
        let all = |base, out: &mut [T], c: &mut _| -> std::result::Result<(), ()> {
            per_chunk(base, out, c);
            Ok(())
        };
        Ok(self.try_map_chunks(n, threads, all)?.unwrap_or_default())
    }

    /// [`Self::map_chunks`] whose chunks may refuse their rays: `per_chunk` returns the
    /// reason, and the least reason over the refusing chunks (whichever threads ran them)
    /// is returned instead of the results. Counters are added only when no chunk refused.
    /// Chunks poll the current [`Stop`]: once it is set the rest are skipped and the call
    /// fails with [`crate::Error::Interrupted`].
    pub(super) fn try_map_chunks<T: Send + Copy + Default, E: Ord + Send>(
        &self,
        n: usize,
        threads: Option<usize>,
        per_chunk: impl Fn(usize, &mut [T], &mut TraversalCounters) -> std::result::Result<(), E> + Sync,
    ) -> Result<std::result::Result<Vec<T>, E>> {
        with_threads(threads, || {
            self.bvh();
            let stop = Stop::current();
            let mut out = vec![T::default(); n];
            let (counters, refused) = out
                .par_chunks_mut(CHUNK)
                .enumerate()
                .map(|(c, chunk)| {
                    let mut counters = TraversalCounters::default();
                    if stop.is_set() {
                        return (counters, None);
                    }
                    let refused = per_chunk(c * CHUNK, chunk, &mut counters).err();
                    (counters, refused)
                })
                .reduce(
                    || (TraversalCounters::default(), None),
                    |(mut a, ra), (b, rb)| {
                        a += b;
                        (a, ra.into_iter().chain(rb).min())
                    },
                );
            stop.check("tracing rays")?;
            Ok(match refused {
                Some(reason) => Err(reason),
                None => {
                    self.add_counters(counters);
                    Ok(out)
                }
            })
        })?
    }

    /// Shadow queries: `true` where something lies on the segment. Runs of at least
    /// [`MIN_PACKET`] consecutive rays from one origin (record bundles) are traced in
    /// packets ([`Bvh::occluded_packet`]); other rays one by one, first trying the previous
    /// ray's occluder when it shared their origin. The answers are the same either way.
    ///
    /// Large batches in trees larger than a core's L2 cache, whose rays visit many nodes
    /// (judged on every 256th ray), wait on memory. Their record bundles are traced in the
    /// Morton order of their origins, so that consecutive bundles reuse the same nodes and
    /// triangles from cache; their scattered rays [`LANES`](crate::geometry::bvh::LANES)
    /// at a time in turns, so that the rays' waits overlap
    /// ([`Bvh::occluded_interleaved_at`]). Answers come in the given order. The choice
    /// depends only on the rays, so answers and counters are the same for any thread
    /// count; the sample that decides is not counted.
    pub fn occluded(&self, rays: &RayBatch, threads: Option<usize>) -> Result<Vec<bool>> {
        rays.validate_shape()?;
        let mut interleave = false;
        if self.may_reorder(rays) {
            // Chosen before the rays are checked: a bad ray misleads only the order (its
            // Morton key or the sample's count), and every ray is checked before it is
            // traced, while in cache (a pass over the batch first cost hairball's
            // incoherent rays 6-10% on two threads).
            match with_threads(threads, || self.trace_order(rays))? {
                TraceOrder::Runs(runs) => return self.occluded_by_runs(rays, &runs, threads),
                TraceOrder::Interleaved => interleave = true,
                TraceOrder::Given => {}
            }
        }
        self.occluded_as_given(rays, threads, interleave)
    }

    /// [`Scene::occluded`] on rays of checked lengths, traced in the order given. Each
    /// chunk validates its rays before tracing them, while they are in cache (a separate
    /// pass over the batch cost measurable time on cornell's incoherent shadow rays);
    /// counters are added only when every ray is valid. `interleave`: as
    /// [`TraceOrder::Interleaved`].
    fn occluded_as_given(
        &self,
        rays: &RayBatch,
        threads: Option<usize>,
        interleave: bool,
    ) -> Result<Vec<bool>> {
        let counting = self.counting_enabled();
        self.try_map_chunks(rays.len(), threads, |base, out, counters| {
            if let Some(bad) = rays.first_bad(base..base + out.len()) {
                return Err(bad);
            }
            let bvh = self.bvh();
            trace_chunk(counting, bvh, rays, base, out, counters, interleave);
            Ok(())
        })?
        .map_err(|bad| rays.error_at(bad))
    }

    /// Whether [`Self::trace_order`] may choose other than [`TraceOrder::Given`]: a large
    /// batch in a tree larger than L2.
    fn may_reorder(&self, rays: &RayBatch) -> bool {
        rays.len() >= SPATIAL_ORDER_MIN && self.bvh().outgrows_l2()
    }

    /// How to trace `rays` (not yet checked), for large trees and large batches whose rays
    /// visit many nodes; [`TraceOrder::Given`] elsewhere. Runs of rays from one origin
    /// (record bundles) are coherent already and stay whole: the runs are ordered by the
    /// Morton order of their origins (ties in the given order), so that consecutive bundles
    /// start near each other and share the nodes and blades they read; runs already in that
    /// order are left as given. Scattered rays are interleaved in the given order
    /// ([`TraceOrder::Interleaved`]): on blob and instances 1.2-1.5x faster than tracing them
    /// one by one in the Morton order of their origins (whose sort and copies cost more
    /// than its locality gained there), as fast on garden (benches/README.md).
    pub(super) fn trace_order(&self, rays: &RayBatch) -> TraceOrder {
        let n = rays.len();
        let bvh = self.bvh();
        if !self.may_reorder(rays) {
            return TraceOrder::Given;
        }
        let repeated = rays
            .origins
            .windows(2)
            .step_by(61)
            .filter(|w| w[0] == w[1])
            .count();
        let bundles = repeated * 2 > n.div_ceil(61);
        let visits_many = self.visits_many(rays, |o, d, t, c| {
            bvh.occluded::<true>(o, d, t, c);
        });
        if !visits_many {
            return TraceOrder::Given;
        }
        if !bundles {
            return TraceOrder::Interleaved;
        }
        let b = self.bounds();
        let top = (1 << 21) as f32 - 1.0;
        let scale = Vec3::splat(top) / (b.max - b.min).max(Vec3::splat(1e-30));
        let key = |o: &[f32; 3]| {
            let q = ((Vec3::from(*o) - b.min) * scale).clamp(Vec3::ZERO, Vec3::splat(top));
            morton_encode_u64(q.x as u32, q.y as u32, q.z as u32)
        };
        bundle_order(rays.origins, key).map_or(TraceOrder::Given, TraceOrder::Runs)
    }

    /// Whether `rays` visit [`SPATIAL_ORDER_NODES`] or more nodes per ray, judged on every
    /// 256th one traced by `trace` (origin, direction, `tmax`, counters). Rays that leave
    /// the tree after a node or two (a small object under an open sky) gain nothing from
    /// another order; rays in dense geometry, which wait on memory, do. The sample is not
    /// counted.
    fn visits_many(
        &self,
        rays: &RayBatch,
        trace: impl Fn(Vec3A, Vec3A, f32, &mut TraversalCounters) + Sync,
    ) -> bool {
        let sample = (0..rays.len())
            .into_par_iter()
            .step_by(256)
            .map(|i| {
                let mut c = TraversalCounters::default();
                let (o, d, t) = ray_at(rays, i);
                trace(o, d, t, &mut c);
                c
            })
            .reduce(TraversalCounters::default, |mut a, b| {
                a += b;
                a
            });
        sample.nodes as f64 >= SPATIAL_ORDER_NODES * sample.rays as f64
    }

    /// Closest hits of valid `rays`, each at the distance [`Bvh::intersect`] finds for it.
    /// Runs of at least [`MIN_PACKET`] consecutive rays from one origin within 45° of their
    /// mean (a camera's rays) are traced in packets ([`Bvh::intersect_packet`], which may
    /// name the other triangle where two are hit at exactly that distance): camera rays at
    /// 160x120 through garden 1.5x faster than one by one. Of the other rays, large
    /// batches in trees larger than L2 whose rays visit many nodes
    /// ([`Self::visits_many`]) are traced [`LANES`](crate::geometry::bvh::LANES) at a time
    /// in turns ([`Bvh::intersect_interleaved_at`]); chunks are fixed, so hits and
    /// counters are the same for any thread count.
    pub(super) fn closest_hits(
        &self,
        rays: &RayBatch,
        threads: Option<usize>,
    ) -> Result<Vec<Option<Hit>>> {
        let bvh = self.bvh();
        let interleave = self.may_reorder(rays)
            && with_threads(threads, || {
                self.visits_many(rays, |o, d, t, c| {
                    bvh.intersect::<true>(o, d, t, c);
                })
            })?;
        let counting = self.counting_enabled();
        self.map_chunks(rays.len(), threads, |base, out, counters| {
            trace_chunk(counting, bvh, rays, base, out, counters, interleave);
        })
    }

    /// [`Scene::occluded`] on rays traced run after run in the order of `runs`
    /// (ranges of the batch that together cover it once) and answered in the given order.
    /// The runs are read where they lie, not copied into a reordered batch (the copy cost
    /// as much as the order gained on garden's bundles). Work items are consecutive runs
    /// of at least [`CHUNK`] rays together, fixed by the runs alone, so answers and
    /// counters are the same for any thread count; the threads take them in their order
    /// ([`map_in_order`]).
    fn occluded_by_runs(
        &self,
        rays: &RayBatch,
        runs: &[std::ops::Range<u32>],
        threads: Option<usize>,
    ) -> Result<Vec<bool>> {
        let mut items = Vec::new();
        let (mut first, mut size) = (0, 0);
        for (k, run) in runs.iter().enumerate() {
            size += run.len();
            if size >= CHUNK || k + 1 == runs.len() {
                items.push(first..k + 1);
                (first, size) = (k + 1, 0);
            }
        }
        let counting = self.counting_enabled();
        let bvh = self.bvh();
        let stop = Stop::current();
        let traced = with_threads(threads, || {
            // Each run is checked before it is traced. After a bad one the item's other
            // runs are only checked: its least bad row is the one to report, and its runs
            // are not in the batch's order.
            let trace = |item: &std::ops::Range<usize>| {
                let runs = &runs[item.clone()];
                let mut out = vec![false; runs.iter().map(|r| r.len()).sum()];
                let mut counters = TraversalCounters::default();
                let (mut k, mut least_bad) = (0, None);
                for run in runs {
                    let range = run.start as usize..run.end as usize;
                    least_bad = least_bad
                        .into_iter()
                        .chain(rays.first_bad(range.clone()))
                        .min();
                    if least_bad.is_none() && !stop.is_set() {
                        let (slots, c) = (&mut out[k..k + range.len()], &mut counters);
                        trace_chunk(counting, bvh, rays, range.start, slots, c, false);
                    }
                    k += range.len();
                }
                least_bad.map_or(Ok((out, counters)), Err)
            };
            // Neighbouring work items on the threads at any moment, which share the nodes
            // of neighbouring bundles in the cache the cores share.
            map_in_order(&items, trace)
        })??;
        stop.check("tracing rays")?;
        // The least bad row over the items is the batch's first, as `validate` names it.
        if let Some(bad) = traced.iter().filter_map(|t| t.as_ref().err()).min() {
            return Err(rays.error_at(*bad));
        }
        let mut out = vec![false; rays.len()];
        let mut counters = TraversalCounters::default();
        for (item, traced) in items.into_iter().zip(traced) {
            let (answers, c) = traced.expect("no item refused its rays");
            counters += c;
            let mut k = 0;
            for run in &runs[item] {
                let r = run.start as usize..run.end as usize;
                out[r].copy_from_slice(&answers[k..k + run.len()]);
                k += run.len();
            }
        }
        self.add_counters(counters);
        Ok(out)
    }
}
