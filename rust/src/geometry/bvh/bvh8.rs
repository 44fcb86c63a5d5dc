//! Eight-wide BVH with uncompressed `f32` child boxes, collapsed from a binary BVH (our
//! binned SAH tree or one of obvhs's PLOC trees), and its conservative SIMD ray/box test.
//!
//! Why not obvhs's CWBVH: its 8-bit quantised nodes are designed for GPUs; on the CPU every
//! visit converts 48 bytes to floats, and we measured its traversal far below Embree's
//! speed on our scenes (benches/README.md). Nodes in structure-of-arrays layout test all
//! their children at once: eight lanes per plane, one AVX register or two SSE ones (as
//! Embree's BVH8). Eight children rather than four halve the tree's depth, and so the
//! dependent node loads and the branches of a traversal (benches/README.md).
//!
//! The box test is robust in the sense of Ize ("Robust BVH Ray Traversal", JCGT 2013): each
//! child's exit distance is scaled by `1 + 2 gamma(3)`, entry distances are clamped at 0 (not
//! at an epsilon), and zero direction components are taken as `+0.0`, so rays lying in a
//! box's face and rays through box corners or shared vertices are never culled.

use std::mem::MaybeUninit;

use glam::{Vec3A, Vec4};
use obvhs::bvh2::Bvh2;

use crate::simd::{Level, SimdLevel};

/// Child reference bit marking a leaf: bits 0..27 its triangle block, bits 27..31 the
/// number of triangles in the block.
const LEAF: u32 = 1 << 31;
const LEAF_COUNT_SHIFT: u32 = 27;
/// Largest number of triangles in a leaf: one four-lane block.
pub const MAX_LEAF_TRIANGLES: u32 = 4;
/// Largest number of leaves a tree can index.
pub const MAX_LEAVES: usize = 1 << LEAF_COUNT_SHIFT;
/// Reference of an empty child slot: a leaf of no triangles (its box is empty and never
/// hit, so it is not even read).
const EMPTY: u32 = LEAF;

/// `1 + 2 gamma(3)` with `gamma(n) = n eps / (1 - n eps)`, `eps = 2^-24` (Ize 2013).
pub const EXIT_SCALE: f32 =
    1.0 + 2.0 * (3.0 * f32::EPSILON * 0.5) / (1.0 - 3.0 * f32::EPSILON * 0.5);

/// Children per node.
pub const WIDTH: usize = 8;

/// One node: the boxes of up to [`WIDTH`] children as planes (`[min_x, max_x, min_y,
/// max_y, min_z, max_z]`, each over the children) and their references.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(32))]
pub struct Node8 {
    planes: [[f32; WIDTH]; 6],
    children: [u32; WIDTH],
}

/// Asks for every cache line of the `T` at `at` (also when it starts mid-line) without
/// waiting for them. Any address will do: a prefetch never faults.
#[inline(always)]
pub fn prefetch_lines<T>(at: *const T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: prefetching is a hint and never faults, whatever the address.
    unsafe {
        use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
        let at = at.cast::<i8>();
        let skew = at as usize % 64;
        for line in (0..skew + std::mem::size_of::<T>()).step_by(64) {
            _mm_prefetch::<_MM_HINT_T0>(at.wrapping_add(line).wrapping_sub(skew));
        }
    }
}

/// What a child reference points to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Child {
    Node(u32),
    Leaf { first: u32, count: u32 },
}

/// Whether reference `r` is a leaf (with [`leaf_block`], [`decode`] without its branch).
#[inline(always)]
pub fn is_leaf(r: u32) -> bool {
    r & LEAF != 0
}

/// The triangle block of leaf reference `r`.
#[inline(always)]
pub fn leaf_block(r: u32) -> u32 {
    r & ((1 << LEAF_COUNT_SHIFT) - 1)
}

#[inline(always)]
pub fn decode(r: u32) -> Child {
    if is_leaf(r) {
        Child::Leaf {
            first: leaf_block(r),
            count: (r & !LEAF) >> LEAF_COUNT_SHIFT,
        }
    } else {
        Child::Node(r)
    }
}

/// A prepared ray for the node test: origin, inverse direction and the plane indices of
/// the near and far planes per axis.
#[derive(Clone, Copy, Debug)]
pub struct BoxRay {
    origin: [Vec4; 3],
    inv: [Vec4; 3],
    near: [usize; 3],
    far: [usize; 3],
    /// Per axis, all eight bits set where the direction is negative (the near plane is the
    /// max plane): a blend mask for [`Node8::intersect_avx512`].
    negative: [u8; 3],
}

impl BoxRay {
    /// `direction` must be finite and non-zero.
    #[inline(always)]
    pub fn new(origin: Vec3A, direction: Vec3A) -> Self {
        // -0.0 + 0.0 = +0.0: a ray lying in a slab's plane then counts as inside the slab
        // (a -0.0 component would place it outside and cull boxes it touches).
        let d = direction + Vec3A::ZERO;
        let inv = d.recip().clamp(Vec3A::splat(-1e30), Vec3A::splat(1e30));
        let neg = [inv.x < 0.0, inv.y < 0.0, inv.z < 0.0];
        Self {
            origin: [
                Vec4::splat(origin.x),
                Vec4::splat(origin.y),
                Vec4::splat(origin.z),
            ],
            inv: [Vec4::splat(inv.x), Vec4::splat(inv.y), Vec4::splat(inv.z)],
            negative: neg.map(|n| 0u8.wrapping_sub(n as u8)),
            near: [neg[0] as usize, 2 + neg[1] as usize, 4 + neg[2] as usize],
            far: [
                1 - neg[0] as usize,
                3 - neg[1] as usize,
                5 - neg[2] as usize,
            ],
        }
    }
}

impl BoxRay {
    /// The origin and the clamped inverse direction, per axis (what every lane of
    /// [`Node8::intersect`] uses).
    #[inline(always)]
    pub fn origin_and_inverse(&self) -> ([f32; 3], [f32; 3]) {
        (
            [self.origin[0].x, self.origin[1].x, self.origin[2].x],
            [self.inv[0].x, self.inv[1].x, self.inv[2].x],
        )
    }
}

impl Node8 {
    /// Child boxes as planes: `[min_x, max_x, min_y, max_y, min_z, max_z]`, each over the
    /// children (empty slots hold `min = inf`, `max = -inf`).
    #[inline(always)]
    pub fn planes(&self) -> &[[f32; WIDTH]; 6] {
        &self.planes
    }

    /// Entry distances of the children and the mask of those the segment `[0, tmax)` may
    /// touch (bit `i` for child `i`). Every lane takes the same operations, whichever
    /// instructions carry them ([`Self::intersect_avx2`] gives the same bits).
    #[inline(always)]
    pub fn intersect(&self, r: &BoxRay, tmax: f32) -> ([f32; WIDTH], u32) {
        let half = |h: usize| {
            let plane = |i: usize| Vec4::from_slice(&self.planes[i][4 * h..4 * h + 4]);
            let slab = |axis: usize| {
                let n = (plane(r.near[axis]) - r.origin[axis]) * r.inv[axis];
                let f = (plane(r.far[axis]) - r.origin[axis]) * r.inv[axis];
                (n, f)
            };
            let (nx, fx) = slab(0);
            let (ny, fy) = slab(1);
            let (nz, fz) = slab(2);
            let t_near = nx.max(ny).max(nz).max(Vec4::ZERO);
            let t_far = (fx.min(fy).min(fz) * EXIT_SCALE).min(Vec4::splat(tmax * EXIT_SCALE));
            (t_near, t_near.cmple(t_far).bitmask())
        };
        let (lo, lo_mask) = half(0);
        let (hi, hi_mask) = half(1);
        let mut t = [0.0; WIDTH];
        t[..4].copy_from_slice(&lo.to_array());
        t[4..].copy_from_slice(&hi.to_array());
        (t, lo_mask | hi_mask << 4)
    }

    /// [`Self::intersect`] in one AVX register per plane.
    /// Not itself compiled for AVX2 but always inlined, so that it inlines into traversals
    /// that are: a `#[target_feature]` function would be left as a call (LLVM declined to
    /// inline it, and the call cost a large share of a shadow ray's time).
    ///
    /// # Safety
    /// The CPU must have AVX2, and the caller should be compiled with it.
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    pub unsafe fn intersect_avx2(&self, r: &BoxRay, tmax: f32) -> ([f32; WIDTH], u32) {
        use std::arch::x86_64::*;
        // SAFETY: the CPU has AVX2 (the caller's contract); each plane row holds WIDTH = 8
        // f32s and `t` has room for 8.
        unsafe {
            // A function, not a closure: closures do not take `#[inline(always)]`, and one
            // was left as a call.
            #[inline(always)]
            unsafe fn slab(n: &Node8, r: &BoxRay, axis: usize) -> (__m256, __m256) {
                // SAFETY: as for the caller.
                unsafe {
                    let o = _mm256_set1_ps(r.origin[axis].x);
                    let inv = _mm256_set1_ps(r.inv[axis].x);
                    // `near` and `far` hold plane indices below 6 (set by `BoxRay::new`
                    // alone), so the rows are read without bounds checks: six per node.
                    let near = _mm256_loadu_ps(n.planes.get_unchecked(r.near[axis]).as_ptr());
                    let far = _mm256_loadu_ps(n.planes.get_unchecked(r.far[axis]).as_ptr());
                    (
                        _mm256_mul_ps(_mm256_sub_ps(near, o), inv),
                        _mm256_mul_ps(_mm256_sub_ps(far, o), inv),
                    )
                }
            }
            entries_and_mask([slab(self, r, 0), slab(self, r, 1), slab(self, r, 2)], tmax)
        }
    }

    /// [`Self::intersect_avx2`] without choosing plane rows by the ray's signs: both rows of
    /// each axis are loaded at fixed offsets and their distances blended by the ray's sign
    /// masks (AVX-512 mask registers). The same operations on the same values, so the same
    /// bits; but the six row offsets no longer take general registers, which the traversal
    /// had to reload from memory at every node.
    ///
    /// # Safety
    /// The CPU must have AVX-512 F and VL, and the caller should be compiled with them.
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    pub unsafe fn intersect_avx512(&self, r: &BoxRay, tmax: f32) -> ([f32; WIDTH], u32) {
        use std::arch::x86_64::*;
        // SAFETY: the CPU has AVX-512 F and VL (the caller's contract); each plane row holds
        // WIDTH = 8 f32s and `t` has room for 8.
        unsafe {
            #[inline(always)]
            unsafe fn slab(n: &Node8, r: &BoxRay, axis: usize) -> (__m256, __m256) {
                // SAFETY: as for the caller.
                unsafe {
                    let o = _mm256_set1_ps(r.origin[axis].x);
                    let inv = _mm256_set1_ps(r.inv[axis].x);
                    // No closure for the two rows: as in `intersect_avx2`.
                    let low = _mm256_loadu_ps(n.planes[2 * axis].as_ptr());
                    let high = _mm256_loadu_ps(n.planes[2 * axis + 1].as_ptr());
                    let (low, high) = (
                        _mm256_mul_ps(_mm256_sub_ps(low, o), inv),
                        _mm256_mul_ps(_mm256_sub_ps(high, o), inv),
                    );
                    let negative = r.negative[axis];
                    (
                        _mm256_mask_blend_ps(negative, low, high),
                        _mm256_mask_blend_ps(negative, high, low),
                    )
                }
            }
            entries_and_mask([slab(self, r, 0), slab(self, r, 1), slab(self, r, 2)], tmax)
        }
    }

    /// Reference of child `i`.
    #[inline(always)]
    pub fn child(&self, i: usize) -> u32 {
        self.children[i]
    }
}

/// A form of [`Node8::intersect`] (the forms differ in instructions, not in answers), as a
/// type whose test is always inlined into the traversal. Traversals took closures before,
/// and the Python module's build (other code, other inlining choices) left the closure as
/// a call at every node, a large share of the shadow rays' time.
pub trait BoxTest: Copy {
    fn test(self, n: &Node8, r: &BoxRay, tmax: f32) -> ([f32; WIDTH], u32);
}

/// [`Node8::intersect`].
#[derive(Clone, Copy, Debug)]
pub struct PortableBoxTest;

impl BoxTest for PortableBoxTest {
    #[inline(always)]
    fn test(self, n: &Node8, r: &BoxRay, tmax: f32) -> ([f32; WIDTH], u32) {
        n.intersect(r, tmax)
    }
}

/// [`Node8::intersect_avx512`]; made only on CPUs with AVX-512 F and VL, for code compiled
/// with them.
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy, Debug)]
pub struct Avx512BoxTest(());

#[cfg(target_arch = "x86_64")]
impl Avx512BoxTest {
    /// # Safety
    /// The CPU must have AVX-512 F and VL.
    pub unsafe fn new() -> Self {
        Self(())
    }
}

#[cfg(target_arch = "x86_64")]
impl BoxTest for Avx512BoxTest {
    #[inline(always)]
    fn test(self, n: &Node8, r: &BoxRay, tmax: f32) -> ([f32; WIDTH], u32) {
        // SAFETY: the CPU has AVX-512 F and VL (the contract of `new`).
        unsafe { n.intersect_avx512(r, tmax) }
    }
}

/// The box test of instruction set `L`: [`Node8::intersect`], [`Node8::intersect_avx2`]
/// or [`Node8::intersect_avx512`], chosen when the code is compiled, for kernels generic
/// over the instruction set ([`crate::simd::Kernel`]).
#[derive(Clone, Copy, Debug)]
pub struct LevelBoxTest<L: Level>(pub L);

impl<L: Level> BoxTest for LevelBoxTest<L> {
    #[inline(always)]
    fn test(self, n: &Node8, r: &BoxRay, tmax: f32) -> ([f32; WIDTH], u32) {
        match L::LEVEL {
            // SAFETY: a value of `L` exists only on CPUs with `L::LEVEL` (`Level`'s
            // contract), here AVX-512 F and VL.
            #[cfg(target_arch = "x86_64")]
            SimdLevel::Avx512 => unsafe { n.intersect_avx512(r, tmax) },
            // SAFETY: as above, AVX2.
            #[cfg(target_arch = "x86_64")]
            SimdLevel::Avx2 => unsafe { n.intersect_avx2(r, tmax) },
            _ => n.intersect(r, tmax),
        }
    }
}

/// An eight-wide BVH: `nodes[0]` is the root; each leaf references one block of four triangle slots,
/// slots `4 * block .. 4 * block + 4` of `primitive_order` (unused slots repeat the
/// leaf's first primitive).
#[derive(Clone, Debug, Default)]
pub struct Bvh8 {
    pub nodes: Vec<Node8>,
    /// Index into the builder's primitive list of each triangle slot, four per leaf.
    pub primitive_order: Vec<u32>,
    /// Largest number of nodes from the root to a leaf.
    pub depth: u32,
}

impl Bvh8 {
    /// Nodes above which a tree outgrows a core's L2 cache (1 MB and more on current CPUs).
    const LARGE: usize = (1 << 20) / std::mem::size_of::<Node8>();

    /// True for trees whose nodes outgrow a core's L2 cache, where traversals wait on
    /// memory.
    #[inline(always)]
    pub fn outgrows_l2(&self) -> bool {
        self.nodes.len() > Self::LARGE
    }

    /// Asks for the cache lines of node `i`, in trees too large for the L2 cache, where a
    /// traversal waits on memory: a node pushed on the stack then arrives while its
    /// siblings are searched (measured on garden's 400k triangles, incoherent shadow rays).
    /// Small trees stay cached, and there the request would be pure overhead.
    #[inline(always)]
    pub fn prefetch(&self, i: u32) {
        if self.outgrows_l2() {
            prefetch_lines(self.nodes.as_ptr().wrapping_add(i as usize));
        }
    }

    /// Collapses a binary BVH (leaves of at most [`MAX_LEAF_TRIANGLES`] primitives) into an
    /// eight-wide one, greedily opening the child of largest surface area.
    pub fn from_bvh2(bvh2: &Bvh2) -> Self {
        let mut out = Bvh8 {
            nodes: Vec::with_capacity(bvh2.nodes.len() / 2 + 1),
            primitive_order: Vec::with_capacity(bvh2.primitive_indices.len()),
            depth: 0,
        };
        if bvh2.nodes.is_empty() {
            return out;
        }
        if bvh2.nodes[0].is_leaf() {
            // A root that is a leaf becomes a node with one child.
            let leaf = out.leaf(bvh2, 0);
            out.nodes.push(Node8::single(bvh2, 0, leaf));
            out.depth = 1;
            return out;
        }
        out.convert(bvh2, 0, 1);
        out
    }

    fn leaf(&mut self, bvh2: &Bvh2, n2: usize) -> u32 {
        let node = &bvh2.nodes[n2];
        assert!(
            (1..=MAX_LEAF_TRIANGLES).contains(&node.prim_count),
            "leaf of {} triangles",
            node.prim_count
        );
        let block = self.primitive_order.len() / 4;
        assert!(block < MAX_LEAVES, "more than {MAX_LEAVES} leaves");
        let block = block as u32;
        let first = node.first_index as usize;
        let prims = &bvh2.primitive_indices[first..first + node.prim_count as usize];
        self.primitive_order
            .extend((0..4).map(|l| prims[l.min(prims.len() - 1)]));
        LEAF | (node.prim_count << LEAF_COUNT_SHIFT) | block
    }

    fn convert(&mut self, bvh2: &Bvh2, n2: usize, depth: u32) -> u32 {
        self.depth = self.depth.max(depth);
        // Open the inner child of largest area until there are WIDTH.
        let first = bvh2.nodes[n2].first_index as usize;
        let mut kids = vec![first, first + 1];
        while kids.len() < WIDTH {
            let best = kids
                .iter()
                .enumerate()
                .filter(|(_, &k)| !bvh2.nodes[k].is_leaf())
                .max_by(|a, b| {
                    let area = |k: usize| bvh2.nodes[k].aabb().half_area();
                    area(*a.1).total_cmp(&area(*b.1))
                })
                .map(|(i, _)| i);
            let Some(i) = best else { break };
            let k = kids.swap_remove(i);
            let f = bvh2.nodes[k].first_index as usize;
            kids.extend([f, f + 1]);
        }
        let index = self.nodes.len();
        self.nodes.push(Node8::empty());
        for (slot, &k) in kids.iter().enumerate() {
            let r = if bvh2.nodes[k].is_leaf() {
                self.leaf(bvh2, k)
            } else {
                self.convert(bvh2, k, depth + 1)
            };
            self.nodes[index].set(slot, bvh2, k, r);
        }
        index as u32
    }
}

impl Node8 {
    fn empty() -> Self {
        let mut planes = [[f32::INFINITY; WIDTH]; 6];
        for axis in 0..3 {
            planes[2 * axis + 1] = [f32::NEG_INFINITY; WIDTH];
        }
        Node8 {
            planes,
            children: [EMPTY; WIDTH],
        }
    }

    fn single(bvh2: &Bvh2, n2: usize, r: u32) -> Self {
        let mut n = Self::empty();
        n.set(0, bvh2, n2, r);
        n
    }

    fn set(&mut self, slot: usize, bvh2: &Bvh2, n2: usize, r: u32) {
        let b = bvh2.nodes[n2].aabb();
        for axis in 0..3 {
            self.planes[2 * axis][slot] = b.min[axis];
            self.planes[2 * axis + 1][slot] = b.max[axis];
        }
        self.children[slot] = r;
    }
}

/// Refitting: new boxes for moved leaves, propagated up to the root. The topology stays
/// the one the builder chose; only boxes change.
impl Bvh8 {
    /// Parent links: the node that references each node (`u32::MAX` for the root) and the
    /// node that references each leaf block.
    pub fn parents(&self) -> Parents {
        let mut p = Parents {
            node: vec![u32::MAX; self.nodes.len()],
            block: vec![u32::MAX; self.primitive_order.len() / 4],
        };
        for (i, n) in self.nodes.iter().enumerate() {
            for &r in &n.children {
                match decode(r) {
                    Child::Node(c) => p.node[c as usize] = i as u32,
                    Child::Leaf { first, count } if count > 0 => p.block[first as usize] = i as u32,
                    Child::Leaf { .. } => {}
                }
            }
        }
        p
    }

    /// Sets the boxes of the given leaf blocks (`(block, min, max)`, local frame) and
    /// refits every node above them, bottom-up. Nodes are stored after their parents (the
    /// collapse writes a node before its children), so taking dirty nodes from the highest
    /// index down finishes every child before its parent. A node whose box comes out
    /// unchanged does not dirty its parent.
    pub fn refit_leaves(
        &mut self,
        parents: &Parents,
        leaves: impl IntoIterator<Item = (u32, Vec3A, Vec3A)>,
    ) {
        let mut dirty = std::collections::BinaryHeap::new();
        let mut queued = vec![false; self.nodes.len()];
        for (block, min, max) in leaves {
            let n = parents.block[block as usize];
            let node = &mut self.nodes[n as usize];
            let slot = (0..WIDTH)
                .find(|&i| matches!(decode(node.children[i]), Child::Leaf { first, count } if first == block && count > 0))
                .expect("a leaf's parent references it");
            node.set_box(slot, min, max);
            if !std::mem::replace(&mut queued[n as usize], true) {
                dirty.push(n);
            }
        }
        while let Some(n) = dirty.pop() {
            let parent = parents.node[n as usize];
            if parent == u32::MAX {
                continue;
            }
            let (min, max) = self.nodes[n as usize].bounds();
            let node = &mut self.nodes[parent as usize];
            let slot = (0..WIDTH)
                .find(|&i| node.children[i] == n)
                .expect("a node's parent references it");
            if node.child_box(slot) == (min, max) {
                continue;
            }
            node.set_box(slot, min, max);
            if !std::mem::replace(&mut queued[parent as usize], true) {
                dirty.push(parent);
            }
        }
    }
}

/// Half the surface area of the box `(min, max)`; 0 for an empty box.
fn half_area(min: Vec3A, max: Vec3A) -> f32 {
    let d = (max - min).max(Vec3A::ZERO);
    d.x * d.y + d.y * d.z + d.z * d.x
}

impl Bvh8 {
    /// Expected work of a ray that crosses the root's box, by the surface area heuristic
    /// (MacDonald and Booth 1990): each node's visit costs `node_cost` (its eight box
    /// tests at once), each leaf's costs one block test (four triangles at once), both
    /// weighted by the chance `area / root area` that a random line through the root
    /// crosses their box. In units of one block test; 0 for an empty tree.
    ///
    /// The same cost as the binned SAH builder's, taken on the final eight-wide tree, so
    /// trees from different builders can be compared.
    pub fn sah_cost(&self, node_cost: f32) -> f32 {
        let Some(root) = self.nodes.first() else {
            return 0.0;
        };
        let (lo, hi) = root.bounds();
        let root_area = half_area(lo, hi);
        if root_area <= 0.0 {
            return node_cost + 1.0;
        }
        // Sum in f64: trees have millions of terms.
        let mut cost = 0.0f64;
        for n in &self.nodes {
            let (lo, hi) = n.bounds();
            cost += (node_cost * half_area(lo, hi)) as f64;
            for slot in 0..WIDTH {
                if matches!(decode(n.children[slot]), Child::Leaf { count, .. } if count > 0) {
                    let (lo, hi) = n.child_box(slot);
                    cost += half_area(lo, hi) as f64;
                }
            }
        }
        (cost / root_area as f64) as f32
    }
}

/// Parent links of a [`Bvh8`] (see [`Bvh8::parents`]).
#[derive(Clone, Debug, Default)]
pub struct Parents {
    /// Parent node of each node; `u32::MAX` for the root.
    pub node: Vec<u32>,
    /// Node whose child is each leaf block.
    pub block: Vec<u32>,
}

impl Node8 {
    /// Box of child `slot` as `(min, max)`.
    pub fn child_box(&self, slot: usize) -> (Vec3A, Vec3A) {
        let p = &self.planes;
        (
            Vec3A::new(p[0][slot], p[2][slot], p[4][slot]),
            Vec3A::new(p[1][slot], p[3][slot], p[5][slot]),
        )
    }

    /// Union of the children's boxes (empty slots hold the empty box).
    pub fn bounds(&self) -> (Vec3A, Vec3A) {
        let p = &self.planes;
        let lo = |a: usize| p[2 * a].iter().copied().fold(f32::INFINITY, f32::min);
        let hi = |a: usize| {
            p[2 * a + 1]
                .iter()
                .copied()
                .fold(f32::NEG_INFINITY, f32::max)
        };
        (
            Vec3A::new(lo(0), lo(1), lo(2)),
            Vec3A::new(hi(0), hi(1), hi(2)),
        )
    }

    fn set_box(&mut self, slot: usize, min: Vec3A, max: Vec3A) {
        for axis in 0..3 {
            self.planes[2 * axis][slot] = min[axis];
            self.planes[2 * axis + 1][slot] = max[axis];
        }
    }
}

/// The last step of the slab test over eight boxes, from the entry (`near`) and exit
/// (`far`) distances per axis: entry `max(near, 0)`, exit `min(far) · EXIT_SCALE` capped at
/// `exit_limit`, and the mask of boxes whose entry is not past their exit.
///
/// # Safety
/// The CPU must have AVX2, and the caller should be compiled with it (see
/// [`Node8::intersect_avx2`]).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub unsafe fn slab_overlap_avx2(
    near: [std::arch::x86_64::__m256; 3],
    far: [std::arch::x86_64::__m256; 3],
    exit_limit: std::arch::x86_64::__m256,
) -> (std::arch::x86_64::__m256, u32) {
    use std::arch::x86_64::*;
    // SAFETY: the CPU has AVX2 (the caller's contract).
    unsafe {
        let entry = _mm256_max_ps(
            _mm256_max_ps(_mm256_max_ps(near[0], near[1]), near[2]),
            _mm256_setzero_ps(),
        );
        let exit = _mm256_min_ps(
            _mm256_mul_ps(
                _mm256_min_ps(_mm256_min_ps(far[0], far[1]), far[2]),
                _mm256_set1_ps(EXIT_SCALE),
            ),
            exit_limit,
        );
        let mask = _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(entry, exit)) as u32;
        (entry, mask)
    }
}

/// A last-in first-out store of the nodes a traversal has yet to visit.
pub trait TraversalStack<T: Copy> {
    fn new() -> Self;
    fn push(&mut self, v: T);
    fn pop(&mut self) -> Option<T>;
    /// Pushes `v` when `keep`.
    #[inline(always)]
    fn push_if(&mut self, v: T, keep: bool) {
        if keep {
            self.push(v)
        }
    }
}

/// A traversal stack of fixed size that never spills, for trees shallow enough that a
/// depth-first search never holds more than `N` entries (seven per level below the root
/// and eight at the deepest: `7 depth + 1`). Without [`Stack`]'s spill path the traversal
/// loop makes no call, so the compiler keeps the ray in registers instead of reloading
/// it from memory at every node (measured on cornell's shadow rays). A push beyond
/// `N` panics rather than spills.
pub struct BoundedStack<T: Copy, const N: usize> {
    buf: [MaybeUninit<T>; N],
    len: usize,
}

impl<T: Copy, const N: usize> TraversalStack<T> for BoundedStack<T, N> {
    #[inline(always)]
    fn new() -> Self {
        Self {
            buf: [const { MaybeUninit::uninit() }; N],
            len: 0,
        }
    }

    #[inline(always)]
    fn push(&mut self, v: T) {
        self.buf[self.len] = MaybeUninit::new(v);
        self.len += 1;
    }

    /// Without a branch on `keep`, which traversals cannot predict (whether a child's box
    /// is hit): `v` is written to the free slot, which only `keep` claims.
    #[inline(always)]
    fn push_if(&mut self, v: T, keep: bool) {
        if self.len < N {
            self.buf[self.len] = MaybeUninit::new(v);
            self.len += keep as usize;
        } else if keep {
            self.push(v)
        }
    }

    #[inline(always)]
    fn pop(&mut self) -> Option<T> {
        self.len = self.len.checked_sub(1)?;
        // SAFETY: slots below the old `len` were written by `push` (T: Copy).
        Some(unsafe { self.buf[self.len].assume_init() })
    }
}

/// The entry distances and hit mask of one ray against eight boxes, from its `(near, far)`
/// distances per axis (see [`slab_overlap_avx2`]).
///
/// # Safety
/// The CPU must have AVX2, and the caller should be compiled with it.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn entries_and_mask(
    slabs: [(std::arch::x86_64::__m256, std::arch::x86_64::__m256); 3],
    tmax: f32,
) -> ([f32; WIDTH], u32) {
    use std::arch::x86_64::*;
    // SAFETY: the CPU has AVX2 (the caller's contract); `t` has room for 8 f32s.
    unsafe {
        let (t_near, mask) = slab_overlap_avx2(
            [slabs[0].0, slabs[1].0, slabs[2].0],
            [slabs[0].1, slabs[1].1, slabs[2].1],
            _mm256_set1_ps(tmax * EXIT_SCALE),
        );
        let mut t = [0.0; WIDTH];
        _mm256_storeu_ps(t.as_mut_ptr(), t_near);
        (t, mask)
    }
}

/// A traversal stack of fixed size that spills to the heap in degenerate trees. The
/// array is left uninitialised: zeroing it cost a memset per ray.
pub struct Stack<T: Copy, const N: usize> {
    buf: [MaybeUninit<T>; N],
    len: usize,
    spill: Vec<T>,
}

impl<T: Copy, const N: usize> Stack<T, N> {
    #[inline(always)]
    pub fn new() -> Self {
        Self {
            buf: [const { MaybeUninit::uninit() }; N],
            len: 0,
            spill: Vec::new(),
        }
    }

    #[inline(always)]
    pub fn push(&mut self, v: T) {
        if self.len < N {
            self.buf[self.len] = MaybeUninit::new(v);
            self.len += 1;
        } else {
            self.spill.push(v);
        }
    }

    #[inline(always)]
    pub fn pop(&mut self) -> Option<T> {
        if let Some(v) = self.spill.pop() {
            return Some(v);
        }
        if self.len == 0 {
            return None;
        }
        self.len -= 1;
        // SAFETY: slots below `len` were written by `push` and never moved out (T: Copy).
        Some(unsafe { self.buf[self.len].assume_init() })
    }
}

impl<T: Copy, const N: usize> TraversalStack<T> for Stack<T, N> {
    #[inline(always)]
    fn new() -> Self {
        Stack::new()
    }

    #[inline(always)]
    fn push(&mut self, v: T) {
        Stack::push(self, v)
    }

    #[inline(always)]
    fn pop(&mut self) -> Option<T> {
        Stack::pop(self)
    }
}

impl<T: Copy, const N: usize> Default for Stack<T, N> {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::vec3a;

    fn node_with_unit_box() -> Node8 {
        let mut n = Node8::empty();
        for axis in 0..3 {
            n.planes[2 * axis][0] = 0.0;
            n.planes[2 * axis + 1][0] = 1.0;
        }
        n.children[0] = LEAF | (1 << LEAF_COUNT_SHIFT);
        n
    }

    #[test]
    fn empty_slots_are_never_hit() {
        let n = node_with_unit_box();
        for d in [
            vec3a(1.0, 0.0, 0.0),
            vec3a(-1.0, -0.0, 0.3),
            vec3a(0.0, 0.0, -1.0),
        ] {
            let r = BoxRay::new(vec3a(0.5, 0.5, 0.5), d);
            let (_, mask) = n.intersect(&r, f32::INFINITY);
            assert_eq!(mask, 1, "{d:?}");
        }
    }

    #[test]
    fn corners_faces_and_negative_zero_are_hit() {
        let n = node_with_unit_box();
        // Through the corner (1, 1, 1) exactly, from outside.
        let r = BoxRay::new(vec3a(2.0, 2.0, 2.0), vec3a(-1.0, -1.0, -1.0));
        assert_eq!(n.intersect(&r, f32::INFINITY).1, 1);
        // Along a face, with -0.0 components.
        let r = BoxRay::new(vec3a(0.0, 0.5, -1.0), vec3a(-0.0, -0.0, 1.0));
        assert_eq!(n.intersect(&r, f32::INFINITY).1, 1);
        // Starting on the box: entry at t = 0.
        let r = BoxRay::new(vec3a(1.0, 0.5, 0.5), vec3a(1.0, 0.0, 0.0));
        let (t, mask) = n.intersect(&r, 1.0);
        assert_eq!((mask, t[0]), (1, 0.0));
        // Segment ending before the box.
        let r = BoxRay::new(vec3a(-2.0, 0.5, 0.5), vec3a(1.0, 0.0, 0.0));
        assert_eq!(n.intersect(&r, 1.5).1, 0);
        assert_eq!(n.intersect(&r, 2.5).1, 1);
    }

    /// The AVX2 box test gives the portable one's bits: entry distances and masks, on
    /// random boxes (some empty, some flat, some holding the origin) and rays with zero,
    /// negative-zero and tiny direction components, at finite and infinite `tmax`.
    #[test]
    fn vector_and_portable_box_tests_agree_bit_for_bit() {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            use crate::sampling::rng::SampleRng;
            let mut compared = 0;
            for case in 0..20_000u64 {
                let rng = SampleRng::new(11, case, 0);
                let mut d = 0;
                let mut u = || {
                    d += 1;
                    rng.get(d)
                };
                let mut n = Node8::empty();
                for slot in 0..WIDTH {
                    if u() < 0.15 {
                        continue;
                    }
                    let c = Vec3A::new(u(), u(), u()) * 4.0 - 2.0;
                    let mut h = Vec3A::new(u(), u(), u());
                    if u() < 0.2 {
                        h.y = 0.0;
                    }
                    n.set_box(slot, c - h, c + h);
                    n.children[slot] = LEAF | (1 << LEAF_COUNT_SHIFT);
                }
                let special = [0.0, -0.0, 1e-30, -1e-38];
                let mut dir = Vec3A::new(u(), u(), u()) * 2.0 - 1.0;
                for axis in 0..3 {
                    if u() < 0.2 {
                        dir[axis] = special[(u() * 4.0) as usize % 4];
                    }
                }
                if dir.abs().max_element() == 0.0 {
                    continue;
                }
                let r = BoxRay::new(Vec3A::new(u(), u(), u()) * 4.0 - 2.0, dir);
                let tmax = if u() < 0.5 { f32::INFINITY } else { u() * 3.0 };
                let (t, mask) = n.intersect(&r, tmax);
                #[target_feature(enable = "avx2")]
                fn with_avx2(n: &Node8, r: &BoxRay, tmax: f32) -> ([f32; WIDTH], u32) {
                    // SAFETY: compiled for AVX2, and only called on CPUs that have it.
                    unsafe { n.intersect_avx2(r, tmax) }
                }
                // SAFETY: the CPU has AVX2.
                let (t2, mask2) = unsafe { with_avx2(&n, &r, tmax) };
                assert_eq!(mask, mask2, "case {case}");
                assert_eq!(t.map(f32::to_bits), t2.map(f32::to_bits), "case {case}");
                if crate::simd::has(crate::simd::SimdLevel::Avx512) {
                    #[target_feature(enable = "avx2,avx512f,avx512vl")]
                    fn with_avx512(n: &Node8, r: &BoxRay, tmax: f32) -> ([f32; WIDTH], u32) {
                        // SAFETY: compiled for AVX-512 VL, only called on CPUs that have it.
                        unsafe { n.intersect_avx512(r, tmax) }
                    }
                    // SAFETY: the CPU has AVX-512 F and VL.
                    let (t3, mask3) = unsafe { with_avx512(&n, &r, tmax) };
                    assert_eq!(mask, mask3, "case {case}");
                    assert_eq!(t.map(f32::to_bits), t3.map(f32::to_bits), "case {case}");
                }
                compared += mask.count_ones();
            }
            assert!(compared > 2_000, "too few boxes hit: {compared}");
        }
    }

    /// A root over a leaf and an inner node holding one leaf: every node and leaf weighted
    /// by its half area over the root's (5), nodes at `node_cost`, leaves at 1.
    #[test]
    fn sah_cost_weights_nodes_and_leaves_by_area() {
        let leaf = |block: u32| LEAF | (1 << LEAF_COUNT_SHIFT) | block;
        let mut root = Node8::empty();
        root.set_box(0, vec3a(1.0, 0.0, 0.0), vec3a(2.0, 1.0, 1.0)); // half area 3
        root.children[0] = leaf(0);
        root.set_box(1, vec3a(0.0, 0.0, 0.0), vec3a(1.0, 1.0, 0.5)); // half area 2
        root.children[1] = 1;
        let mut inner = Node8::empty();
        inner.set_box(0, vec3a(0.0, 0.0, 0.0), vec3a(1.0, 1.0, 0.5));
        inner.children[0] = leaf(1);
        let tree = Bvh8 {
            nodes: vec![root, inner],
            primitive_order: vec![0, 0, 0, 0, 1, 1, 1, 1],
            depth: 2,
        };
        // Nodes (5 + 2) / 5, leaves (3 + 2) / 5.
        assert!((tree.sah_cost(1.0) - 2.4).abs() < 1e-6);
        assert!((tree.sah_cost(2.0) - 3.8).abs() < 1e-6);
        assert_eq!(Bvh8::default().sah_cost(1.0), 0.0);
    }

    #[test]
    fn stack_spills_and_keeps_order() {
        let mut s: Stack<u32, 2> = Stack::new();
        for i in 0..5 {
            s.push(i);
        }
        let popped: Vec<u32> = std::iter::from_fn(|| s.pop()).collect();
        assert_eq!(popped, vec![4, 3, 2, 1, 0]);
    }
}
