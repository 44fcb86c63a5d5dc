//! Rays with scattered origins, several traversals in flight at once.
//!
//! In a tree larger than L2 a lone ray spends most of its time waiting for the node or
//! triangle block it pops next: the child it pushed last, requested a few instructions
//! earlier. Here [`LANES`] rays take turns, one node or leaf each, so a lane's request has
//! the other lanes' steps to arrive in, and the memory waits of different rays overlap
//! instead of adding up (the "interleaved" or AMAC style of hiding latency in pointer
//! chasing). Each ray's answer and the work it does are those of [`Bvh::occluded`] or
//! [`Bvh::intersect`]: the same walk, only the order between rays changes.

use glam::Vec3A;

use super::shadow::AnyHitStep;
use super::{Bvh, FarthestFirst, Hit, LocalRay, TraversalCounters, STACK};
use crate::geometry::bvh::bvh8::{
    decode, BoundedStack, BoxTest, Child, LevelBoxTest, TraversalStack,
};
use crate::geometry::bvh::watertight::TriangleHit;
use crate::simd::Level;

/// Rays in flight: enough steps of other rays between a request and its use to cover a
/// wait on memory (a step costs 10-30 ns, a miss to memory about 100 ns). 16 rather than
/// 8: garden's incoherent shadow rays 1.2x faster (4.58 against 5.55 Mrays/s on 2
/// threads), instances 1.05x, blob and strands 1.00-1.05x; 24 gained no more.
pub const LANES: usize = 16;

/// Node visits and triangle tests of a walk (counted when its `COUNT` is true).
#[derive(Default)]
struct Work {
    nodes: u64,
    tests: u64,
}

/// A kind of traversal run in turns: how a lane starts and takes one step.
trait Walk {
    type Lane;
    type Answer;
    /// A lane tracing ray `k`.
    fn start(&self, k: usize) -> Self::Lane;
    /// One node or leaf of `lane`'s walk, its work added to `work`; the lane's answer when
    /// its walk is done.
    fn step(&self, lane: &mut Self::Lane, work: &mut Work) -> Option<Self::Answer>;
}

/// Traces rays `0..n` of `walk`, [`LANES`] at a time in turns, handing each answer to
/// `answer` as its walk ends.
#[inline(always)]
fn in_turns<W: Walk>(
    walk: &W,
    n: usize,
    mut answer: impl FnMut(usize, W::Answer),
    work: &mut Work,
) {
    // Each lane with the index of its ray.
    let mut lanes: Vec<(usize, W::Lane)> = (0..n.min(LANES)).map(|k| (k, walk.start(k))).collect();
    let mut queued = lanes.len();
    let mut j = 0;
    while !lanes.is_empty() {
        match walk.step(&mut lanes[j].1, work) {
            None => j += 1,
            Some(a) => {
                answer(lanes[j].0, a);
                if queued < n {
                    lanes[j] = (queued, walk.start(queued));
                    queued += 1;
                    j += 1;
                } else {
                    // The last lane takes this one's place and its turn.
                    lanes.swap_remove(j);
                }
            }
        }
        if j >= lanes.len() {
            j = 0;
        }
    }
}

/// A shadow ray in flight: its ray, its stack and the child reference it visits next.
struct ShadowLane {
    ray: LocalRay,
    stack: BoundedStack<u32, STACK>,
    next: u32,
}

/// The any-hit walk of [`Bvh::occluded`] in turns.
struct ShadowWalk<'a, R, B, const COUNT: bool> {
    bvh: &'a Bvh,
    ray: R,
    box_test: B,
}

impl<R: Fn(usize) -> (Vec3A, Vec3A, f32), B: BoxTest, const COUNT: bool> Walk
    for ShadowWalk<'_, R, B, COUNT>
{
    type Lane = ShadowLane;
    type Answer = bool;

    #[inline(always)]
    fn start(&self, k: usize) -> ShadowLane {
        let (o, d, t) = (self.ray)(k);
        ShadowLane {
            ray: self.bvh.local_ray(o, d, t),
            stack: BoundedStack::new(),
            next: 0,
        }
    }

    #[inline(always)]
    fn step(&self, lane: &mut ShadowLane, work: &mut Work) -> Option<bool> {
        let bvh = self.bvh;
        let (nodes, tests) = (&mut work.nodes, &mut work.tests);
        match bvh.any_hit_step::<COUNT>(&lane.ray, lane.next, self.box_test, nodes, tests) {
            AnyHitStep::Leaf(true) => return Some(true),
            AnyHitStep::Leaf(false) => {}
            AnyHitStep::Node(_, node, mut mask) => {
                while mask != 0 {
                    let child = node.child(mask.trailing_zeros() as usize);
                    mask &= mask - 1;
                    bvh.request_child(node, child, true);
                    lane.stack.push(child);
                }
            }
        }
        match lane.stack.pop() {
            Some(child) => {
                lane.next = child;
                None
            }
            None => Some(false),
        }
    }
}

/// A closest-hit ray in flight: its ray, its stack of child references with their entry
/// distances, the reference it visits next and the nearest hit so far.
struct ClosestLane {
    ray: LocalRay,
    stack: BoundedStack<(u32, f32), STACK>,
    next: u32,
    best_t: f32,
    best: Option<(u32, TriangleHit)>,
}

/// The nearest-first walk of [`Bvh::intersect`] in turns.
struct ClosestWalk<'a, R, B, const COUNT: bool> {
    bvh: &'a Bvh,
    ray: R,
    box_test: B,
}

impl<R: Fn(usize) -> (Vec3A, Vec3A, f32), B: BoxTest, const COUNT: bool> Walk
    for ClosestWalk<'_, R, B, COUNT>
{
    type Lane = ClosestLane;
    type Answer = Option<Hit>;

    #[inline(always)]
    fn start(&self, k: usize) -> ClosestLane {
        let (o, d, t) = (self.ray)(k);
        let ray = self.bvh.local_ray(o, d, t);
        ClosestLane {
            best_t: ray.tmax,
            ray,
            stack: BoundedStack::new(),
            next: 0,
            best: None,
        }
    }

    #[inline(always)]
    fn step(&self, lane: &mut ClosestLane, work: &mut Work) -> Option<Option<Hit>> {
        let bvh = self.bvh;
        match decode(lane.next) {
            Child::Leaf { first, count } => {
                if COUNT {
                    work.tests += count as u64;
                }
                bvh.nearest_in_leaf(&lane.ray, first, &mut lane.best_t, &mut lane.best);
            }
            Child::Node(c) => {
                let n = &bvh.tree.nodes[c as usize];
                if COUNT {
                    work.nodes += 1;
                }
                let (t_near, mut mask) = self.box_test.test(n, &lane.ray.boxes, lane.best_t);
                let mut hits = FarthestFirst::new(0u32);
                while mask != 0 {
                    let i = mask.trailing_zeros() as usize;
                    mask &= mask - 1;
                    hits.insert(n.child(i), t_near[i]);
                }
                for &(child, t) in &hits.hits[..hits.len] {
                    bvh.request_child(n, child, true);
                    lane.stack.push((child, t));
                }
            }
        }
        // Entries behind the nearest hit are skipped without reading their memory.
        while let Some((child, t_enter)) = lane.stack.pop() {
            if t_enter <= lane.best_t {
                lane.next = child;
                return None;
            }
        }
        Some(bvh.closest_of(&lane.ray, lane.best))
    }
}

impl Bvh {
    /// Whether [`Self::occluded_interleaved_at`] and [`Self::intersect_interleaved_at`] pay:
    /// trees larger than L2 (smaller ones stay cached and have nothing to overlap) whose
    /// depth-first search fits the fixed stack, under an instruction set with the vector
    /// box tests.
    #[inline(always)]
    pub(crate) fn interleaves<L: Level>(&self) -> bool {
        L::LEVEL >= crate::simd::SimdLevel::Avx2 && self.outgrows_l2() && self.stack_is_bounded()
    }

    /// Shadow queries for `n` rays, `ray(k)` giving ray `k`'s origin, direction and `tmax`
    /// (valid, as for [`Self::occluded`]), answers into `answer(k, occluded)`, traced
    /// [`LANES`] at a time in turns (module docs). Only for trees where
    /// [`Self::interleaves`] holds.
    #[inline(always)]
    pub(crate) fn occluded_interleaved_at<const COUNT: bool, L: Level>(
        &self,
        n: usize,
        ray: impl Fn(usize) -> (Vec3A, Vec3A, f32),
        answer: impl FnMut(usize, bool),
        counters: &mut TraversalCounters,
        level: L,
    ) {
        let walk = ShadowWalk::<_, _, COUNT> {
            bvh: self,
            ray,
            box_test: LevelBoxTest(level),
        };
        self.traced_in_turns::<COUNT, L, _>(walk, n, answer, counters, false);
    }

    /// Closest hits of `n` rays, as [`Self::occluded_interleaved_at`] (each ray's hit is
    /// [`Self::intersect`]'s).
    #[inline(always)]
    pub(crate) fn intersect_interleaved_at<const COUNT: bool, L: Level>(
        &self,
        n: usize,
        ray: impl Fn(usize) -> (Vec3A, Vec3A, f32),
        answer: impl FnMut(usize, Option<Hit>),
        counters: &mut TraversalCounters,
        level: L,
    ) {
        let walk = ClosestWalk::<_, _, COUNT> {
            bvh: self,
            ray,
            box_test: LevelBoxTest(level),
        };
        self.traced_in_turns::<COUNT, L, _>(walk, n, answer, counters, None);
    }

    /// Runs `walk` over rays `0..n` in turns and adds its counts; an empty tree answers
    /// every ray with `nothing`.
    #[inline(always)]
    fn traced_in_turns<const COUNT: bool, L: Level, W: Walk<Answer: Copy>>(
        &self,
        walk: W,
        n: usize,
        mut answer: impl FnMut(usize, W::Answer),
        counters: &mut TraversalCounters,
        nothing: W::Answer,
    ) {
        debug_assert!(self.interleaves::<L>());
        if COUNT {
            counters.rays += n as u64;
        }
        if self.blocks.is_empty() {
            (0..n).for_each(|k| answer(k, nothing));
            return;
        }
        let mut work = Work::default();
        in_turns(&walk, n, answer, &mut work);
        if COUNT {
            counters.nodes += work.nodes;
            counters.triangles += work.tests;
        }
    }
}
