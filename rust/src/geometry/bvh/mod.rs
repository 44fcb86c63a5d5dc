//! The BVH: a binary tree, built by our binned SAH builder ([`binned_sah`], the
//! default) or by obvhs's PLOC presets, is collapsed into an eight-wide tree with `f32`
//! child boxes ([`bvh8`]) and traversed with conservative SIMD box tests and
//! watertight triangle tests. Closest-hit and early-exit shadow queries keep exact
//! traversal counters.
//!
//! The tree is built in a *local frame*: world coordinates times a power of two chosen so
//! that the scene's largest side lies in [256, 512), which keeps every traversal quantity
//! in the same range at any scene scale. Power-of-two scaling is exact in floating point,
//! so it changes no vertex.
//!
//! Files: `binned_sah.rs` (the binned SAH builder), `bvh8.rs` (the eight-wide tree and its
//! box tests), `watertight.rs` (watertight triangle tests), `build.rs` (presets, the grouped
//! build, refits), `shadow.rs` (early-exit shadow queries and their hinted walks),
//! `packet.rs` (packets of shadow rays from one origin), `closest.rs` (closest hits).

use std::time::Duration;

use glam::Vec3A;

use bvh8::{decode, BoxRay, Bvh8, Child, Node8, Parents, TraversalStack, WIDTH};
use watertight::{Triangle4, WatertightRay};

pub mod binned_sah;
mod build;
pub mod bvh8;
mod closest;
mod closest_packet;
mod filtered;
mod interleaved;
mod packet;
mod shadow;
#[cfg(test)]
mod tests;
pub mod watertight;

use build::RefitBlocks;

pub use build::{
    AutoChoice, AutoCosts, BuildQuality, BvhUpdate, AUTO_ALTERNATIVE, AUTO_APART_LARGEST,
    AUTO_MARGIN, AUTO_MAX_TRIANGLES, AUTO_PROBE_RAYS, MAX_LEAF, NODE_COST,
};
pub use interleaved::LANES;
pub use packet::PACKET;

/// Traversal stack size: a fixed stack of this size serves trees of depth 18 or less (seven
/// entries per level, plus one); deeper ones use a stack that spills to the heap. The
/// built-in scenes' SAH trees are 4 to 9 deep.
const STACK: usize = 128;

/// Work done by traversals: rays traced, BVH nodes whose (up to eight) children were
/// tested, and ray/triangle tests. Exact counts, summed over threads.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TraversalCounters {
    pub rays: u64,
    pub nodes: u64,
    pub triangles: u64,
}

impl std::ops::AddAssign for TraversalCounters {
    fn add_assign(&mut self, o: Self) {
        self.rays += o.rays;
        self.nodes += o.nodes;
        self.triangles += o.triangles;
    }
}

/// Closest hit of one ray: ray parameter `t` (world units of the given direction), the
/// triangle index into [`crate::geometry::Mesh::triangles`], and barycentrics of the second and third vertex.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    pub t: f32,
    pub triangle: u32,
    pub u: f32,
    pub v: f32,
}

/// The occluder of the previous ray in a coherent sequence (see [`Bvh::occluded_hinted`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct OccluderHint {
    /// The BVH4 node with the occluding leaf among its children ([`NO_NODE`] for none).
    node: u32,
}

/// A node index that no tree has.
const NO_NODE: u32 = u32::MAX;

impl OccluderHint {
    /// No previous occluder.
    pub const NONE: OccluderHint = OccluderHint { node: NO_NODE };
}

impl Default for OccluderHint {
    fn default() -> Self {
        Self::NONE
    }
}

/// A ray mapped into the BVH's local frame.
#[derive(Clone, Copy)]
struct LocalRay {
    boxes: BoxRay,
    watertight: WatertightRay,
    tmax: f32,
    /// Local t times this gives the caller's ray parameter.
    t_to_param: f32,
}

/// A node's hit children sorted by entry distance, farthest first: pushed on a stack in this
/// order, the nearest is popped next (the closest-hit traversals).
pub(super) struct FarthestFirst<T> {
    hits: [(T, f32); WIDTH],
    len: usize,
}

impl<T: Copy> FarthestFirst<T> {
    /// No child yet (`fill` only fills the unused slots).
    #[inline(always)]
    pub(super) fn new(fill: T) -> Self {
        Self {
            hits: [(fill, 0.0); WIDTH],
            len: 0,
        }
    }

    /// Adds a child entered at distance `t` (at most [`WIDTH`] per node).
    #[inline(always)]
    pub(super) fn insert(&mut self, item: T, t: f32) {
        let mut j = self.len;
        while j > 0 && self.hits[j - 1].1 < t {
            self.hits[j] = self.hits[j - 1];
            j -= 1;
        }
        self.hits[j % WIDTH] = (item, t);
        self.len += 1;
    }
}

/// A built BVH over the non-degenerate triangles of a mesh.
#[derive(Clone, Debug)]
pub struct Bvh {
    tree: Bvh8,
    /// Local-frame triangles, one four-lane block per leaf.
    blocks: Vec<Triangle4>,
    /// Mesh triangle index of each slot (`4 * block + lane`).
    triangle_ids: Vec<u32>,
    to_local: f32,
    to_world: f32,
    /// The builder that made this tree (never `Auto`).
    quality: BuildQuality,
    /// The preset asked for (`Auto` when this tree won the comparison).
    requested: BuildQuality,
    /// [`Bvh8::sah_cost`] of the tree with [`NODE_COST`].
    sah_cost: f32,
    /// Probe work per ray of the trees [`BuildQuality::Auto`] compared, when it did.
    auto_costs: Option<AutoCosts>,
    build_time: Duration,
    /// Parent links: the refit climbs them, and shadow-ray hints widen to a parent.
    parents: Parents,
    /// The leaf blocks of the last refit's triangle range, and which of its triangles the
    /// tree holds (a moving object is refit range after range).
    refit_blocks: Option<RefitBlocks>,
    /// Number of mesh triangles (kept or not) the tree was built over.
    mesh_triangles: usize,
}

/// The power of two `s` that brings a direction whose largest component magnitude is
/// `largest` (finite, non-zero) to a largest component in `[1, 2)`, and `1 / s`.
///
/// Local rays take `s · direction` instead of the unit direction: the scaling is exact, so
/// the box and triangle tests' relative rounding bounds hold as for any direction, and it
/// keeps every length in range as normalising did, without normalising's square root and
/// division (a large share of the per-ray setup time, on the critical path of each ray).
/// The biased exponent is clamped to `[1, 253]` so that both powers are normal floats; a
/// subnormal `largest` then scales to below 1, which is harmless.
#[inline(always)]
fn direction_scale(largest: f32) -> (f32, f32) {
    let biased = (largest.to_bits() >> 23 & 0xff).clamp(1, 253);
    (
        f32::from_bits((254 - biased) << 23),
        f32::from_bits(biased << 23),
    )
}

impl Bvh {
    /// The builder that made the tree: [`BuildQuality::Auto`]'s choice, or the preset asked
    /// for.
    pub fn quality(&self) -> BuildQuality {
        self.quality
    }

    /// The preset asked for ([`BuildQuality::Auto`] when the tree won a comparison).
    pub fn requested_quality(&self) -> BuildQuality {
        self.requested
    }

    /// Node visits plus block tests (a quarter of the triangle tests) per probe ray of the
    /// trees [`BuildQuality::Auto`] compared, when it did.
    pub fn auto_costs(&self) -> Option<AutoCosts> {
        self.auto_costs
    }

    /// Whether [`BuildQuality::Auto`] kept the tree with each object of the mesh in a
    /// subtree of its own ([`AutoCosts::objects_apart`]).
    pub fn objects_apart(&self) -> bool {
        self.auto_costs
            .is_some_and(|c| c.chosen() == AutoChoice::ObjectsApart)
    }

    /// Expected block tests (and node visits at [`NODE_COST`]) of a ray crossing the
    /// scene's box, by the surface area heuristic ([`Bvh8::sah_cost`]). Refits leave it
    /// as built.
    pub fn sah_cost(&self) -> f32 {
        self.sah_cost
    }

    /// Wall time of [`Bvh::build`].
    pub fn build_time(&self) -> Duration {
        self.build_time
    }

    /// True when the tree outgrows a core's L2 cache (traversals then wait on memory, and
    /// batches gain from tracing nearby rays one after another).
    pub fn outgrows_l2(&self) -> bool {
        self.tree.outgrows_l2()
    }

    /// Number of eight-wide nodes.
    pub fn num_nodes(&self) -> usize {
        self.tree.nodes.len()
    }

    /// Nodes on the longest root-to-leaf path.
    pub fn depth(&self) -> u32 {
        self.tree.depth
    }

    /// Bytes held by nodes, leaf triangles and index maps.
    pub fn memory_bytes(&self) -> usize {
        self.tree.nodes.len() * std::mem::size_of::<Node8>()
            + self.blocks.len() * (std::mem::size_of::<Triangle4>() + 16)
    }

    #[inline(always)]
    fn local_ray(&self, origin: Vec3A, direction: Vec3A, tmax: f32) -> LocalRay {
        let (scale, unscale) = direction_scale(direction.abs().max_element());
        let d = direction * scale;
        let o = origin * self.to_local;
        LocalRay {
            boxes: BoxRay::new(o, d),
            watertight: WatertightRay::new(o, d),
            // Products of powers of two: exact, and never 0 · inf.
            tmax: tmax * unscale * self.to_local,
            t_to_param: self.to_world * scale,
        }
    }

    /// Whether a depth-first search of this tree never holds more than [`STACK`] entries:
    /// `7 depth + 1` (see [`BoundedStack`]).
    #[inline(always)]
    fn stack_is_bounded(&self) -> bool {
        7 * (self.tree.depth as usize) < STACK
    }

    /// Pushes `hits` on `stack` in their order, asking for the memory of each child node
    /// (`child` gives an entry's child reference).
    #[inline(always)]
    fn push_farthest_first<T: Copy, S: TraversalStack<(T, f32)>>(
        &self,
        stack: &mut S,
        hits: &FarthestFirst<T>,
        child: impl Fn(T) -> u32,
    ) {
        for &(item, t) in &hits.hits[..hits.len] {
            if let Child::Node(c) = decode(child(item)) {
                self.tree.prefetch(c);
            }
            stack.push((item, t));
        }
    }
}
