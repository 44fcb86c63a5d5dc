//! Early-exit shadow queries: one ray, or a coherent sequence of rays that first tries
//! the node where the previous ray found its occluder.

use glam::Vec3A;

use super::{Bvh, LocalRay, OccluderHint, TraversalCounters, NO_NODE, STACK};
use crate::geometry::bvh::bvh8::{
    decode, is_leaf, leaf_block, prefetch_lines, BoundedStack, BoxTest, Child, LevelBoxTest, Node8,
    Stack, TraversalStack,
};
use crate::simd::{Kernel, Level, SimdLevel};

impl Bvh {
    /// True when a triangle lies on the segment `origin + t direction`, `t` in `[0, tmax)`.
    /// Stops at the first hit found. `direction` must be finite and non-zero. `COUNT`
    /// selects whether `counters` is updated (it costs a few adds per node).
    #[inline]
    pub fn occluded<const COUNT: bool>(
        &self,
        origin: Vec3A,
        direction: Vec3A,
        tmax: f32,
        counters: &mut TraversalCounters,
    ) -> bool {
        let mut no_hint = OccluderHint::NONE;
        self.occluded_hinted::<COUNT>(origin, direction, tmax, &mut no_hint, counters)
    }

    /// [`Bvh::occluded`] that first searches the node whose leaf occluded the previous ray
    /// of a coherent sequence (`hint`), and records this ray's in it. Rays from one point in
    /// nearby directions are often blocked by the same wall, whose node then costs a few box
    /// and triangle tests instead of a traversal from the root; on a miss the root traversal
    /// skips that node. The answer is the same as without the hint.
    #[inline]
    pub fn occluded_hinted<const COUNT: bool>(
        &self,
        origin: Vec3A,
        direction: Vec3A,
        tmax: f32,
        hint: &mut OccluderHint,
        counters: &mut TraversalCounters,
    ) -> bool {
        crate::simd::dispatch(HintedRay::<COUNT> {
            bvh: self,
            origin,
            direction,
            tmax,
            hint,
            counters,
        })
    }

    /// [`Self::occluded_hinted`] with the box tests of instruction set `level`, for code
    /// compiled for it ([`Kernel`]): batch drivers call it from their own kernel, so that
    /// it is inlined into their loop. Under AVX-512 the same arithmetic runs in 256 bits
    /// with 32 vector registers instead of 16, so that the ray's origin, inverse and segment
    /// stay in registers across the leaf tests instead of being reloaded at every node, and
    /// with the box test of [`Node8::intersect_avx512`]; the ray's setup is compiled for it
    /// too. The vector forms take the fixed stack where the tree allows it.
    ///
    /// [`Node8::intersect_avx512`]: crate::geometry::bvh::bvh8::Node8::intersect_avx512
    #[inline(always)]
    pub(crate) fn occluded_hinted_at<const COUNT: bool, L: Level>(
        &self,
        origin: Vec3A,
        direction: Vec3A,
        tmax: f32,
        hint: &mut OccluderHint,
        counters: &mut TraversalCounters,
        level: L,
    ) -> bool {
        let box_test = LevelBoxTest(level);
        if L::LEVEL >= SimdLevel::Avx2 && self.stack_is_bounded() {
            type Bounded = BoundedStack<(u32, u32), STACK>;
            self.hinted_search::<COUNT, Bounded>(origin, direction, tmax, hint, counters, box_test)
        } else {
            type Spilling = Stack<(u32, u32), STACK>;
            self.hinted_search::<COUNT, Spilling>(origin, direction, tmax, hint, counters, box_test)
        }
    }

    /// The search of [`Self::occluded_hinted`]: the hinted node first, if any, then the
    /// root without it.
    #[inline(always)]
    fn hinted_search<const COUNT: bool, S: TraversalStack<(u32, u32)>>(
        &self,
        origin: Vec3A,
        direction: Vec3A,
        tmax: f32,
        hint: &mut OccluderHint,
        counters: &mut TraversalCounters,
        box_test: impl BoxTest,
    ) -> bool {
        if COUNT {
            counters.rays += 1;
        }
        if self.blocks.is_empty() {
            return false;
        }
        let r = self.local_ray(origin, direction, tmax);
        // One traversal site for both searches, so that it is inlined once.
        let mut from_hint = (hint.node as usize) < self.tree.nodes.len();
        let (mut start, mut skip) = (if from_hint { hint.node } else { 0 }, NO_NODE);
        loop {
            if let Some(node) = self.occluder_walk::<COUNT, S>(&r, start, skip, counters, box_test)
            {
                if !from_hint {
                    hint.node = self.hint_node(node);
                }
                return true;
            }
            if !from_hint || start == 0 {
                return false;
            }
            (start, skip, from_hint) = (0, start, false);
        }
    }

    /// Asks for the memory of child reference `r` of node `n` (a node or a leaf block) in
    /// trees larger than L2, for the traversals that push it on their stack when `keep`.
    /// Without branches on `keep` or on whether `r` is a leaf, which the traversals cannot
    /// predict (with [`TraversalStack::push_if`], measured on garden's bundles): a child not kept
    /// asks for `n`'s own lines, which are cached.
    #[inline(always)]
    pub(super) fn request_child(&self, n: &Node8, r: u32, keep: bool) {
        if self.tree.outgrows_l2() {
            let block = self.blocks.as_ptr().wrapping_add(leaf_block(r) as usize);
            let child = self.tree.nodes.as_ptr().wrapping_add(r as usize);
            let at = if is_leaf(r) {
                block.cast::<u8>()
            } else {
                child.cast::<u8>()
            };
            let at = if keep {
                at
            } else {
                (n as *const Node8).cast::<u8>()
            };
            // Four lines from the line it starts in: a node (224 bytes, 32-byte aligned)
            // or a block (144 bytes, 16-byte aligned) lies within them.
            prefetch_lines(at.wrapping_sub(at as usize % 64).cast::<[u8; 256]>());
        }
    }

    /// The node a hint keeps for an occluder found in a leaf of `node`: its parent, whose
    /// subtree is a wider patch of surface (a wall's grid cells, a block's faces).
    #[inline]
    pub(super) fn hint_node(&self, node: u32) -> u32 {
        match self.parents.node[node as usize] {
            NO_NODE => node,
            parent => parent,
        }
    }

    /// Any-hit search of the subtree under node `start`, not entering node `skip`: the node
    /// whose leaf holds the first occluder found, if any. `box_test` is one of the forms of
    /// [`Node8::intersect`] (they differ in instructions, not in answers).
    ///
    /// A leaf whose box the ray touches is requested from memory and pushed on the stack
    /// with its node (`(child reference, node)` entries; nodes carry [`NO_NODE`]) instead of
    /// being tested at once, so that its triangles load while the node's other children
    /// are handled. In trees larger than L2, testing at once had left the traversal waiting
    /// on the block's first load (a large share of garden's bundle time in a profile).
    #[inline(always)]
    pub(super) fn occluder_walk<const COUNT: bool, S: TraversalStack<(u32, u32)>>(
        &self,
        r: &LocalRay,
        start: u32,
        skip: u32,
        counters: &mut TraversalCounters,
        box_test: impl BoxTest,
    ) -> Option<u32> {
        let (mut nodes, mut tests) = (0u64, 0u64);
        let mut stack = S::new();
        let mut entry = (start, NO_NODE);
        let mut occluder = None;
        loop {
            match self.any_hit_step::<COUNT>(r, entry.0, box_test, &mut nodes, &mut tests) {
                AnyHitStep::Leaf(true) => {
                    occluder = Some(entry.1);
                    break;
                }
                AnyHitStep::Leaf(false) => {}
                AnyHitStep::Node(node, n, mut mask) => {
                    while mask != 0 {
                        let i = mask.trailing_zeros() as usize;
                        mask &= mask - 1;
                        let r = n.child(i);
                        let keep = r != skip;
                        self.request_child(n, r, keep);
                        stack.push_if((r, if is_leaf(r) { node } else { NO_NODE }), keep);
                    }
                }
            }
            match stack.pop() {
                Some(e) => entry = e,
                None => break,
            }
        }
        if COUNT {
            counters.nodes += nodes;
            counters.triangles += tests;
        }
        occluder
    }
}

/// What one step of an any-hit walk found at a child reference.
pub(super) enum AnyHitStep<'a> {
    /// A leaf, and whether one of its triangles lies on the ray's segment.
    Leaf(bool),
    /// A node: its index, the node, and the mask of the children whose boxes the ray
    /// touches.
    Node(u32, &'a Node8, u32),
}

impl Bvh {
    /// One step of an any-hit walk at child reference `entry`: a leaf's triangle test or a
    /// node's box test, counted in `nodes` and `tests` when `COUNT`.
    #[inline(always)]
    pub(super) fn any_hit_step<const COUNT: bool>(
        &self,
        r: &LocalRay,
        entry: u32,
        box_test: impl BoxTest,
        nodes: &mut u64,
        tests: &mut u64,
    ) -> AnyHitStep<'_> {
        match decode(entry) {
            Child::Leaf { first, count } => {
                if COUNT {
                    *tests += count as u64;
                }
                let block = &self.blocks[first as usize];
                AnyHitStep::Leaf(r.watertight.intersect4(block, r.tmax).0 != 0)
            }
            Child::Node(node) => {
                let n = &self.tree.nodes[node as usize];
                if COUNT {
                    *nodes += 1;
                }
                AnyHitStep::Node(node, n, box_test.test(n, &r.boxes, r.tmax).1)
            }
        }
    }
}

/// [`Bvh::occluded_hinted`] as a [`Kernel`], compiled once per instruction set.
pub(super) struct HintedRay<'a, const COUNT: bool> {
    pub(super) bvh: &'a Bvh,
    pub(super) origin: Vec3A,
    pub(super) direction: Vec3A,
    pub(super) tmax: f32,
    pub(super) hint: &'a mut OccluderHint,
    pub(super) counters: &'a mut TraversalCounters,
}

impl<const COUNT: bool> Kernel for HintedRay<'_, COUNT> {
    type Output = bool;

    #[inline(always)]
    fn run<L: Level>(self, level: L) -> bool {
        let HintedRay {
            bvh,
            origin,
            direction,
            tmax,
            hint,
            counters,
        } = self;
        bvh.occluded_hinted_at::<COUNT, L>(origin, direction, tmax, hint, counters, level)
    }
}
