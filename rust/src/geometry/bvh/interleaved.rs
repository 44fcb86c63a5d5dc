//! Shadow rays with scattered origins, several traversals in flight at once.
//!
//! In a tree larger than L2 a lone shadow ray spends most of its time waiting for the
//! node or triangle block it pops next: the child it pushed last, requested a few
//! instructions earlier. Here [`LANES`] rays take turns, one node or leaf each, so a lane's
//! request has the other lanes' steps to arrive in, and the memory waits of different rays
//! overlap instead of adding up (the "interleaved" or AMAC style of hiding latency in
//! pointer chasing). Each ray's answer and the work it does are those of
//! [`Bvh::occluded`]: the same walk, only the order between rays changes.

use glam::Vec3A;

use super::shadow::AnyHitStep;
use super::{Bvh, LocalRay, TraversalCounters, STACK};
use crate::geometry::bvh8::{BoundedStack, LevelBoxTest, TraversalStack};
use crate::simd::Level;

/// Rays in flight: enough steps of other rays between a request and its use to cover a
/// wait on memory (a step costs 10-30 ns, a miss to memory about 100 ns).
pub const LANES: usize = 8;

/// One traversal in flight: its ray, its stack, the child reference it visits next and the
/// slot its answer goes to.
struct Lane {
    ray: LocalRay,
    stack: BoundedStack<u32, STACK>,
    next: u32,
    slot: usize,
}

impl Bvh {
    /// Whether [`Self::occluded_interleaved_at`] pays: trees larger than L2 (smaller ones
    /// stay cached and have nothing to overlap) whose depth-first search fits the fixed
    /// stack, under an instruction set with the vector box tests.
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
        mut answer: impl FnMut(usize, bool),
        counters: &mut TraversalCounters,
        level: L,
    ) {
        debug_assert!(self.interleaves::<L>());
        if COUNT {
            counters.rays += n as u64;
        }
        if self.blocks.is_empty() {
            (0..n).for_each(|k| answer(k, false));
            return;
        }
        let box_test = LevelBoxTest(level);
        let (mut nodes, mut tests) = (0u64, 0u64);
        let start = |k: usize| {
            let (o, d, t) = ray(k);
            Lane {
                ray: self.local_ray(o, d, t),
                stack: BoundedStack::new(),
                next: 0,
                slot: k,
            }
        };
        let mut lanes: Vec<Lane> = (0..n.min(LANES)).map(start).collect();
        let mut queued = lanes.len();
        let mut j = 0;
        while !lanes.is_empty() {
            let lane = &mut lanes[j];
            // One step: a leaf's triangles, or a node's children pushed and requested.
            let occluded = match self
                .any_hit_step::<COUNT>(&lane.ray, lane.next, box_test, &mut nodes, &mut tests)
            {
                AnyHitStep::Leaf(hit) => hit,
                AnyHitStep::Node(_, node, mut mask) => {
                    while mask != 0 {
                        let child = node.child(mask.trailing_zeros() as usize);
                        mask &= mask - 1;
                        self.request_child(node, child, true);
                        lane.stack.push(child);
                    }
                    false
                }
            };
            let popped = if occluded { None } else { lane.stack.pop() };
            match popped {
                Some(child) => {
                    lane.next = child;
                    j += 1;
                }
                None => {
                    answer(lane.slot, occluded);
                    if queued < n {
                        *lane = start(queued);
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
        if COUNT {
            counters.nodes += nodes;
            counters.triangles += tests;
        }
    }
}
