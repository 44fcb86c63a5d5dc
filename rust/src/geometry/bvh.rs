//! The BVH: a binary tree, built by our binned SAH builder ([`super::binned_sah`], the
//! default) or by obvhs's PLOC presets, is collapsed into an eight-wide tree with `f32`
//! child boxes ([`super::bvh8`]) and traversed with conservative SIMD box tests and
//! watertight triangle tests. Closest-hit and early-exit shadow queries keep exact
//! traversal counters.
//!
//! The tree is built in a *local frame*: world coordinates times a power of two chosen so
//! that the scene's largest side lies in [256, 512), which keeps every traversal quantity
//! in the same range at any scene scale. Power-of-two scaling is exact in floating point,
//! so it changes no vertex.

use std::time::{Duration, Instant};

use glam::{Vec3, Vec3A};
use obvhs::bvh2::builder::build_bvh2_from_tris;
use obvhs::bvh2::node::Bvh2Node;
use obvhs::bvh2::Bvh2;
use obvhs::triangle::Triangle;
use obvhs::BvhBuildParams;

use super::binned_sah::{self, BinnedSahParams};
#[cfg(target_arch = "x86_64")]
use super::bvh8::slab_overlap_avx2;
use super::bvh8::{
    decode, is_leaf, leaf_block, prefetch_lines, BoundedStack, BoxRay, BoxTest, Bvh8, Child, Node8,
    Parents, PortableBoxTest, Stack, TraversalStack, EXIT_SCALE, WIDTH,
};
#[cfg(target_arch = "x86_64")]
use super::bvh8::{Avx2BoxTest, Avx512BoxTest};
use super::huge_pages::advise_huge_pages;
use super::mesh::{triangle_cross, Mesh};
#[cfg(target_arch = "x86_64")]
use super::watertight::{lanes, WatertightPacket};
use super::watertight::{Triangle4, TriangleHit, WatertightRay};
use crate::error::{Error, Result};

/// Build presets: our binned SAH builder ([`BuildQuality::Sah`]), one of obvhs's PLOC
/// presets ([`BvhBuildParams`], leaves capped at [`MAX_LEAF`] triangles), or the choice
/// between the two by measured cost ([`BuildQuality::Auto`], the default).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum BuildQuality {
    /// The default: builds the [`BuildQuality::Sah`] and the [`AUTO_ALTERNATIVE`] tree and
    /// keeps the one that does less work on [`AUTO_PROBE_RAYS`] sample shadow rays (the
    /// PLOC tree only when it saves more than [`AUTO_MARGIN`]); meshes of more than
    /// [`AUTO_MAX_TRIANGLES`] get the SAH tree alone. Neither builder wins on every scene:
    /// the binned SAH on the built-ins, PLOC (with its spatial pre-splits) on mixed scales
    /// and on small meshes over a large ground (benches/README.md). The SAH cost of the
    /// two trees ([`Bvh::sah_cost`]) did not tell them apart on the benchmark suite (equal
    /// on `meshes`, where PLOC traces 1.7x faster); the traversal work of sample rays does.
    #[default]
    Auto,
    /// Top-down binned SAH whose cost counts four-triangle blocks ([`super::binned_sah`]).
    /// Fewer node visits and block tests per ray than any PLOC preset below on the
    /// built-in scenes, at about the build time of `Medium` (benches/README.md).
    Sah,
    /// PLOC with search radius 1, no reinsertion; fastest build, slowest traversal.
    Fastest,
    VeryFast,
    Fast,
    /// obvhs's medium preset (the default before [`BuildQuality::Sah`]).
    Medium,
    /// Spatial pre-splits and more reinsertion; best traversal, several times slower build.
    Slow,
    VerySlow,
}

impl BuildQuality {
    /// All presets: the default, then obvhs's, fastest build first.
    pub const ALL: [BuildQuality; 8] = [
        BuildQuality::Auto,
        BuildQuality::Sah,
        BuildQuality::Fastest,
        BuildQuality::VeryFast,
        BuildQuality::Fast,
        BuildQuality::Medium,
        BuildQuality::Slow,
        BuildQuality::VerySlow,
    ];

    /// The obvhs parameters of this preset (None for [`BuildQuality::Sah`], which is not
    /// obvhs's).
    pub const fn params(self) -> Option<BvhBuildParams> {
        let Some(mut p) = self.obvhs_preset() else {
            return None;
        };
        if p.max_prims_per_leaf > MAX_LEAF {
            p.max_prims_per_leaf = MAX_LEAF;
        }
        Some(p)
    }

    const fn obvhs_preset(self) -> Option<BvhBuildParams> {
        Some(match self {
            BuildQuality::Auto | BuildQuality::Sah => return None,
            BuildQuality::Fastest => BvhBuildParams::fastest_build(),
            BuildQuality::VeryFast => BvhBuildParams::very_fast_build(),
            BuildQuality::Fast => BvhBuildParams::fast_build(),
            BuildQuality::Medium => BvhBuildParams::medium_build(),
            BuildQuality::Slow => BvhBuildParams::slow_build(),
            BuildQuality::VerySlow => BvhBuildParams::very_slow_build(),
        })
    }

    /// Builds the binary tree of this preset over `triangles` (local frame); `Auto` is
    /// resolved by [`Bvh::build_grouped`] before this and builds the SAH tree here.
    fn build_bvh2(self, triangles: &[Triangle]) -> Bvh2 {
        match self.params() {
            Some(p) => build_bvh2_from_tris(triangles, p, &mut Duration::default()),
            None => binned_sah::build_bvh2(triangles, &BinnedSahParams::default_build()),
        }
    }

    /// Snake-case name as used by the Python API (`"fast"`, `"very_slow"`, ...).
    pub const fn name(self) -> &'static str {
        match self {
            BuildQuality::Auto => "auto",
            BuildQuality::Sah => "sah",
            BuildQuality::Fastest => "fastest",
            BuildQuality::VeryFast => "very_fast",
            BuildQuality::Fast => "fast",
            BuildQuality::Medium => "medium",
            BuildQuality::Slow => "slow",
            BuildQuality::VerySlow => "very_slow",
        }
    }

    /// Parses a snake-case name; the error lists the valid ones.
    pub fn parse(name: &str) -> Result<Self> {
        Self::ALL
            .into_iter()
            .find(|q| q.name() == name)
            .ok_or_else(|| {
                let names: Vec<_> = Self::ALL.iter().map(|q| q.name()).collect();
                Error::invalid(
                    "quality",
                    format!("unknown preset {name:?}; use one of {names:?}"),
                )
            })
    }
}

/// The PLOC preset [`BuildQuality::Auto`] weighs against the binned SAH tree.
pub const AUTO_ALTERNATIVE: BuildQuality = BuildQuality::Slow;

/// Shadow rays [`BuildQuality::Auto`] traces in both trees to compare them.
pub const AUTO_PROBE_RAYS: usize = 4096;

/// [`BuildQuality::Auto`] keeps the PLOC tree only when the SAH tree's probe work is more
/// than this many times its own: where the two are within 5%, the probe's node and block
/// counts do not predict which traces faster (`blob`, `instances`, `panels` on the suite).
pub const AUTO_MARGIN: f64 = 1.05;

/// Meshes larger than this get the SAH tree without a comparison: the PLOC preset builds
/// several times slower (4 s for `hairball`'s 1.6M triangles on two cores, against a
/// 1 s budget for a million).
pub const AUTO_MAX_TRIANGLES: usize = 1 << 18;

/// Cost of visiting an eight-wide node relative to one four-triangle block test, in
/// [`Bvh::sah_cost`]: both are one SIMD test of similar latency.
pub const NODE_COST: f32 = 1.0;

/// Largest leaf the builder makes: one four-lane block of [`Triangle4`].
pub const MAX_LEAF: u32 = super::bvh8::MAX_LEAF_TRIANGLES;

/// Rays of a packet reaching a leaf from which its triangles are tested against the rays
/// all at once ([`WatertightPacket`]) rather than ray by ray.
#[cfg(target_arch = "x86_64")]
const VECTOR_TRIANGLE_LANES: u32 = 6;

/// Largest number of rays [`Bvh::occluded_packet`] traces together: one AVX-512 register
/// of `f32` lanes.
pub const PACKET: usize = 16;

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
/// triangle index into [`Mesh::triangles`], and barycentrics of the second and third vertex.
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
    /// Probe work per ray of the SAH and the PLOC tree when [`BuildQuality::Auto`]
    /// compared them.
    auto_costs: Option<[f64; 2]>,
    build_time: Duration,
    /// Parent links: the refit climbs them, and shadow-ray hints widen to a parent.
    parents: Parents,
    /// The leaf blocks of the last refit's triangle range, and which of its triangles the
    /// tree holds (a moving object is refit range after range).
    refit_blocks: Option<RefitBlocks>,
    /// Number of mesh triangles (kept or not) the tree was built over.
    mesh_triangles: usize,
}

/// Leaf blocks holding triangles `range`, and which of those triangles the tree holds.
#[derive(Clone, Debug)]
struct RefitBlocks {
    range: std::ops::Range<usize>,
    blocks: Vec<u32>,
    in_tree: Vec<bool>,
}

/// How a built BVH follows geometry that moved (see [`super::Scene::set_object_transform`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum BvhUpdate {
    /// Keep the tree's topology and recompute the boxes above the moved triangles: about
    /// 50 times faster than a rebuild for the animated `dynamics` sphere. With the object
    /// in a subtree of its own (as the scene builds moved objects) the refit tree traces
    /// as fast as a rebuilt one (benches/README.md).
    #[default]
    Refit,
    /// Drop the tree; it is rebuilt with the scene's preset on the next query.
    Rebuild,
}

/// The power of two `s` that brings a direction whose largest component magnitude is
/// `largest` (finite, non-zero) to a largest component in `[1, 2)`, and `1 / s`.
///
/// Local rays take `s · direction` instead of the unit direction: the scaling is exact, so
/// the box and triangle tests' relative rounding bounds hold as for any direction, and it
/// keeps every length in range as normalising did, without normalising's square root and
/// division (a third of cornell's per-ray setup time, on the critical path of each ray).
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

/// The power of two that brings `extent` into [256, 512).
fn local_scale(extent: f32) -> f32 {
    if !(extent > 0.0 && extent.is_finite()) {
        return 1.0;
    }
    let e = extent.log2().floor() as i32;
    2f32.powi((8 - e).clamp(-120, 120))
}

/// A binary tree whose root has the roots of `a` and `b` as children. Nodes are laid out
/// `[root, a's root, b's root, a's other nodes, b's other nodes]` (children stay adjacent)
/// and `b`'s primitives follow `a`'s.
fn join_bvh2(a: Bvh2, b: Bvh2) -> Bvh2 {
    let (na, pa) = (a.nodes.len() as u32, a.primitive_indices.len() as u32);
    let map_a = |i: u32| if i == 0 { 1 } else { i + 2 };
    let map_b = |i: u32| if i == 0 { 2 } else { na + 1 + i };
    let moved = |n: &Bvh2Node, map: &dyn Fn(u32) -> u32, prims: u32| {
        let mut n = *n;
        n.first_index = if n.is_leaf() {
            n.first_index + prims
        } else {
            map(n.first_index)
        };
        n
    };
    let root = Bvh2Node::new(a.nodes[0].aabb().union(b.nodes[0].aabb()), 0, 1);
    let mut nodes = Vec::with_capacity(a.nodes.len() + b.nodes.len() + 1);
    nodes.push(root);
    nodes.push(moved(&a.nodes[0], &map_a, 0));
    nodes.push(moved(&b.nodes[0], &map_b, pa));
    nodes.extend(a.nodes[1..].iter().map(|n| moved(n, &map_a, 0)));
    nodes.extend(b.nodes[1..].iter().map(|n| moved(n, &map_b, pa)));
    let mut primitive_indices = a.primitive_indices;
    primitive_indices.extend(b.primitive_indices);
    Bvh2 {
        nodes,
        primitive_indices,
        ..Bvh2::default()
    }
}

/// `n` shadow rays like a renderer's: origins uniform by area over `mesh`'s triangles, on
/// the side facing up (+y, the scenes' up axis: the side a camera and the sky mostly see;
/// vertical triangles on their winding side), lifted off the surface by a millionth of the
/// scene's size, directions uniform over that side's hemisphere. A fixed function of the
/// mesh. Of the samplings tried on the suite (by area or by triangle, either side or the
/// upper one), this one's work ratios came closest to the measured speed ratios.
fn probe_rays(mesh: &Mesh, n: usize) -> Vec<(Vec3A, Vec3A)> {
    use crate::sampling::rng::SampleRng;
    use crate::testing::{to_world, uniform_hemisphere};
    let mut total = 0.0f64;
    let cdf: Vec<f64> = mesh
        .triangles
        .iter()
        .map(|t| {
            total += 0.5 * triangle_cross(t).length() as f64;
            total
        })
        .collect();
    if total.is_nan() || total <= 0.0 {
        return Vec::new();
    }
    let lift = 1e-6 * mesh.bounds().extent();
    (0..n as u64)
        .map(|k| {
            let rng = SampleRng::new(0x5eed_b0c5, k, 0);
            let pick = rng.get(0) as f64 * total;
            let i = cdf.partition_point(|&c| c <= pick).min(cdf.len() - 1);
            let [a, b, c] = mesh.triangles[i];
            let [u, v] = rng.get2(1);
            let (u, v) = if u + v > 1.0 {
                (1.0 - u, 1.0 - v)
            } else {
                (u, v)
            };
            let normal = triangle_cross(&mesh.triangles[i]).normalize_or_zero();
            let normal = if normal.y < 0.0 { -normal } else { normal };
            let p = a + (b - a) * u + (c - a) * v + normal * lift;
            let d = to_world(uniform_hemisphere(rng.get2(4)), normal);
            (Vec3A::from(p), Vec3A::from(d))
        })
        .collect()
}

impl Bvh {
    /// Builds over every triangle of `mesh` with non-zero area, in parallel on the current
    /// rayon pool. Degenerate triangles are left out: they can never be hit.
    pub fn build(mesh: &Mesh, quality: BuildQuality) -> Self {
        Self::build_grouped(mesh, quality, &[])
    }

    /// [`Bvh::build`] in which the triangles of each of `groups` (ranges of mesh triangles,
    /// disjoint; e.g. objects that move) get a subtree of their own under the root, built
    /// apart from the rest. A refit after such a group moves rigidly then keeps a tree as
    /// good as a rebuild: the rest's boxes never change and the group's own boxes move with
    /// it, instead of stretching boxes that mix it with the geometry it left. Without groups
    /// this is exactly [`Bvh::build`].
    pub fn build_grouped(
        mesh: &Mesh,
        quality: BuildQuality,
        groups: &[std::ops::Range<usize>],
    ) -> Self {
        let start = Instant::now();
        if quality == BuildQuality::Auto {
            let mut kept = if mesh.triangles.len() > AUTO_MAX_TRIANGLES {
                Self::build_grouped(mesh, BuildQuality::Sah, groups)
            } else {
                let (sah, alternative) = rayon::join(
                    || Self::build_grouped(mesh, BuildQuality::Sah, groups),
                    || Self::build_grouped(mesh, AUTO_ALTERNATIVE, groups),
                );
                let rays = probe_rays(mesh, AUTO_PROBE_RAYS);
                let costs = [sah.probe_work(&rays), alternative.probe_work(&rays)];
                let mut kept = if costs[0] > AUTO_MARGIN * costs[1] {
                    alternative
                } else {
                    sah
                };
                kept.auto_costs = Some(costs);
                kept
            };
            kept.requested = BuildQuality::Auto;
            kept.build_time = start.elapsed();
            return kept;
        }
        let non_degenerate = |&i: &u32| triangle_cross(&mesh.triangles[i as usize]) != Vec3::ZERO;
        // Kept triangles, the ungrouped first, then group after group.
        let grouped = |i: u32| groups.iter().any(|g| g.contains(&(i as usize)));
        let mut kept: Vec<u32> = (0..mesh.triangles.len() as u32)
            .filter(|i| !grouped(*i))
            .filter(non_degenerate)
            .collect();
        let mut spans = Vec::with_capacity(groups.len() + 1);
        spans.push(0..kept.len());
        for g in groups {
            let first = kept.len();
            kept.extend((g.start as u32..g.end as u32).filter(non_degenerate));
            spans.push(first..kept.len());
        }
        let mut bounds = super::mesh::Bounds::EMPTY;
        for &i in &kept {
            for v in &mesh.triangles[i as usize] {
                bounds.grow(*v);
            }
        }
        let to_local = local_scale(bounds.extent());
        let local: Vec<Triangle> = kept
            .iter()
            .map(|&i| {
                let [a, b, c] = mesh.triangles[i as usize];
                Triangle {
                    v0: Vec3A::from(a * to_local),
                    v1: Vec3A::from(b * to_local),
                    v2: Vec3A::from(c * to_local),
                }
            })
            .collect();
        let tree = spans
            .into_iter()
            .filter(|span| !span.is_empty())
            .map(|span| {
                let mut bvh2 = quality.build_bvh2(&local[span.clone()]);
                bvh2.primitive_indices
                    .iter_mut()
                    .for_each(|p| *p += span.start as u32);
                bvh2
            })
            .reduce(join_bvh2)
            .map_or_else(Bvh8::default, |bvh2| Bvh8::from_bvh2(&bvh2));
        let blocks: Vec<Triangle4> = tree
            .primitive_order
            .as_chunks::<4>()
            .0
            .iter()
            .map(|slots| {
                let tris = slots.map(|p| {
                    let t = &local[p as usize];
                    [t.v0, t.v1, t.v2]
                });
                Triangle4::pack(&tris)
            })
            .collect();
        // The arrays the traversals read at random.
        advise_huge_pages(&blocks);
        advise_huge_pages(&tree.nodes);
        let triangle_ids = tree
            .primitive_order
            .iter()
            .map(|&p| kept[p as usize])
            .collect();
        Bvh {
            parents: tree.parents(),
            sah_cost: tree.sah_cost(NODE_COST),
            tree,
            blocks,
            triangle_ids,
            to_local,
            to_world: 1.0 / to_local,
            quality,
            requested: quality,
            auto_costs: None,
            build_time: start.elapsed(),
            refit_blocks: None,
            mesh_triangles: mesh.triangles.len(),
        }
    }

    /// Follows triangles `changed` of `mesh` that moved since the build (or the last refit):
    /// repacks their leaf blocks and refits the boxes above them, keeping the topology.
    /// Returns false, leaving the tree unusable, when a refit cannot give the tree a
    /// rebuild would: the mesh has another number of triangles, a moved triangle became
    /// degenerate or stopped being so (the build leaves degenerate ones out), or a vertex
    /// leaves the `f32` range in the local frame. The caller must then rebuild.
    ///
    /// Boxes are the exact bounds of their triangles, as the builder makes them, so a
    /// refit tree answers every query exactly as the tree of the same topology built over
    /// the moved triangles (trees built with spatial splits get whole-triangle boxes).
    pub fn refit(&mut self, mesh: &Mesh, changed: std::ops::Range<usize>) -> bool {
        if mesh.triangles.len() != self.mesh_triangles || changed.end > self.mesh_triangles {
            return false;
        }
        if changed.is_empty() || self.blocks.is_empty() {
            return mesh.triangles[changed]
                .iter()
                .all(|t| triangle_cross(t) == Vec3::ZERO);
        }
        if self
            .refit_blocks
            .as_ref()
            .is_none_or(|r| r.range != changed)
        {
            // Blocks holding a moved triangle, and which moved triangles the tree holds.
            let mut in_tree = vec![false; changed.len()];
            let mut blocks: Vec<u32> = Vec::new();
            for (slot, &t) in self.triangle_ids.iter().enumerate() {
                if changed.contains(&(t as usize)) {
                    in_tree[t as usize - changed.start] = true;
                    let b = (slot / 4) as u32;
                    if blocks.last() != Some(&b) {
                        blocks.push(b);
                    }
                }
            }
            self.refit_blocks = Some(RefitBlocks {
                range: changed.clone(),
                blocks,
                in_tree,
            });
        }
        let RefitBlocks {
            blocks, in_tree, ..
        } = self.refit_blocks.as_ref().expect("set above");
        let same_set = mesh.triangles[changed.clone()]
            .iter()
            .zip(in_tree)
            .all(|(t, &kept)| (triangle_cross(t) != Vec3::ZERO) == kept);
        if !same_set {
            return false;
        }
        let to_local = self.to_local;
        let mut leaves = Vec::with_capacity(blocks.len());
        for &b in blocks {
            let slots = &self.triangle_ids[4 * b as usize..4 * b as usize + 4];
            let tris: [[Vec3A; 3]; 4] = std::array::from_fn(|l| {
                mesh.triangles[slots[l] as usize].map(|v| Vec3A::from(v * to_local))
            });
            if !tris.iter().flatten().all(|v| v.is_finite()) {
                return false;
            }
            // Unused lanes repeat the leaf's first triangle, so all four lanes bound it.
            let min = tris
                .iter()
                .flatten()
                .fold(Vec3A::INFINITY, |m, v| m.min(*v));
            let max = tris
                .iter()
                .flatten()
                .fold(Vec3A::NEG_INFINITY, |m, v| m.max(*v));
            self.blocks[b as usize] = Triangle4::pack(&tris);
            leaves.push((b, min, max));
        }
        self.tree.refit_leaves(&self.parents, leaves);
        true
    }

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
    /// SAH and the PLOC tree, when [`BuildQuality::Auto`] compared them.
    pub fn auto_costs(&self) -> Option<[f64; 2]> {
        self.auto_costs
    }

    /// Node visits plus block tests per ray of `rays` (origin, direction; unbounded).
    fn probe_work(&self, rays: &[(Vec3A, Vec3A)]) -> f64 {
        let mut c = TraversalCounters::default();
        for &(o, d) in rays {
            self.occluded::<true>(o, d, f32::INFINITY, &mut c);
        }
        (c.nodes as f64 + c.triangles as f64 / 4.0) / rays.len().max(1) as f64
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
        #[cfg(target_arch = "x86_64")]
        match crate::simd::level() {
            // SAFETY: the CPU has AVX-512 F and VL.
            crate::simd::SimdLevel::Avx512 => unsafe {
                return self.hinted_avx512::<COUNT>(origin, direction, tmax, hint, counters);
            },
            // SAFETY: the CPU has AVX2.
            crate::simd::SimdLevel::Avx2 => unsafe {
                return self.hinted_avx2::<COUNT>(origin, direction, tmax, hint, counters);
            },
            _ => {}
        }
        self.hinted_portable::<COUNT>(origin, direction, tmax, hint, counters)
    }

    /// [`Self::occluded_hinted`] with the portable box tests, whatever the CPU (tests hold
    /// the vector forms to it).
    pub(crate) fn hinted_portable<const COUNT: bool>(
        &self,
        origin: Vec3A,
        direction: Vec3A,
        tmax: f32,
        hint: &mut OccluderHint,
        counters: &mut TraversalCounters,
    ) -> bool {
        type Spilling = Stack<(u32, u32), STACK>;
        let box_test = PortableBoxTest;
        self.hinted_search::<COUNT, Spilling>(origin, direction, tmax, hint, counters, box_test)
    }

    /// [`Self::occluded_hinted`] with AVX2 box tests. Batch drivers compiled for AVX2 call
    /// it directly, so that it is inlined into their loop.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    #[inline]
    pub(crate) fn hinted_avx2<const COUNT: bool>(
        &self,
        origin: Vec3A,
        direction: Vec3A,
        tmax: f32,
        hint: &mut OccluderHint,
        counters: &mut TraversalCounters,
    ) -> bool {
        // SAFETY: the CPU has AVX2 (this function's contract).
        let box_test = unsafe { Avx2BoxTest::new() };
        self.hinted_vector::<COUNT>(origin, direction, tmax, hint, counters, box_test)
    }

    /// [`Self::hinted_avx2`] compiled for AVX-512 VL: the same arithmetic in 256 bits, but
    /// 32 vector registers instead of 16, so that the ray's origin, inverse and segment
    /// stay in registers across the leaf tests instead of being reloaded at every node,
    /// and the box test of [`Node8::intersect_avx512`]; the ray's setup is compiled for it
    /// too (cornell's shadow rays: 1.07x).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,avx512f,avx512vl")]
    #[inline]
    pub(crate) fn hinted_avx512<const COUNT: bool>(
        &self,
        origin: Vec3A,
        direction: Vec3A,
        tmax: f32,
        hint: &mut OccluderHint,
        counters: &mut TraversalCounters,
    ) -> bool {
        // SAFETY: the CPU has AVX-512 F and VL (this function's contract).
        let box_test = unsafe { Avx512BoxTest::new() };
        self.hinted_vector::<COUNT>(origin, direction, tmax, hint, counters, box_test)
    }

    /// The body of [`Self::hinted_avx2`] and [`Self::hinted_avx512`], inlined into each so
    /// that it is compiled for its instruction set, with its `box_test`.
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    fn hinted_vector<const COUNT: bool>(
        &self,
        origin: Vec3A,
        direction: Vec3A,
        tmax: f32,
        hint: &mut OccluderHint,
        counters: &mut TraversalCounters,
        box_test: impl BoxTest,
    ) -> bool {
        if self.stack_is_bounded() {
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
    /// predict (with [`TraversalStack::push_if`]: garden's bundles 1.1x): a child not kept
    /// asks for `n`'s own lines, which are cached.
    #[inline(always)]
    fn request_child(&self, n: &Node8, r: u32, keep: bool) {
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

    /// Whether a depth-first search of this tree never holds more than [`STACK`] entries:
    /// `7 depth + 1` (see [`BoundedStack`]).
    #[inline(always)]
    fn stack_is_bounded(&self) -> bool {
        7 * (self.tree.depth as usize) < STACK
    }

    /// The node a hint keeps for an occluder found in a leaf of `node`: its parent, whose
    /// subtree is a wider patch of surface (a wall's grid cells, a block's faces).
    #[inline]
    fn hint_node(&self, node: u32) -> u32 {
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
    /// on the block's first load (a quarter of garden's bundle time in a profile).
    #[inline(always)]
    fn occluder_walk<const COUNT: bool, S: TraversalStack<(u32, u32)>>(
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
            match decode(entry.0) {
                Child::Leaf { first, count } => {
                    if COUNT {
                        tests += count as u64;
                    }
                    let (hit, ..) = r
                        .watertight
                        .intersect4(&self.blocks[first as usize], r.tmax);
                    if hit != 0 {
                        occluder = Some(entry.1);
                        break;
                    }
                }
                Child::Node(node) => {
                    let n = &self.tree.nodes[node as usize];
                    if COUNT {
                        nodes += 1;
                    }
                    let (_, mut mask) = box_test.test(n, &r.boxes, r.tmax);
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

    /// Shadow queries for up to [`PACKET`] rays from one `origin` (`directions[l]`,
    /// `tmax[l]`), traced together: each node's children are first tested against the
    /// packet as one interval ray (eight at once), and the boxes that test keeps against
    /// all the packet's rays at once (AVX-512, sixteen lanes); each ray is tested against
    /// the triangles of the leaves its own box tests reach, by the single-ray watertight
    /// test. The box test is [`Node8::intersect`]'s, lane by lane, with the same
    /// operations, so a ray reaches exactly the leaves it reaches alone and every answer
    /// is [`Self::occluded`]'s. Like [`Self::occluded_hinted`], the packet first searches
    /// the node where the previous packet from this origin found an occluder (`hint`).
    /// Bit `l` of the result is set when ray `l` is occluded. Counters count each ray,
    /// each node test once per ray taking part, and each ray's triangle tests. Without
    /// AVX-512 the rays are traced one by one.
    ///
    /// [`Node8::intersect`]: Node8::intersect
    pub fn occluded_packet<const COUNT: bool>(
        &self,
        origin: Vec3A,
        directions: &[Vec3A],
        tmax: &[f32],
        hint: &mut OccluderHint,
        counters: &mut TraversalCounters,
    ) -> u16 {
        assert!(directions.len() <= PACKET && tmax.len() == directions.len());
        #[cfg(target_arch = "x86_64")]
        if !directions.is_empty()
            && !self.blocks.is_empty()
            && crate::simd::level() == crate::simd::SimdLevel::Avx512
        {
            if COUNT {
                counters.rays += directions.len() as u64;
            }
            // SAFETY: the CPU has AVX-512 F and VL, and popcnt (part of the level); 1 to
            // PACKET rays.
            return unsafe {
                let packet = Packet::new(self, origin, directions, tmax);
                let rays = &mut LaneRays::new(origin, directions, tmax);
                self.occluded_packet_avx512::<COUNT>(&packet, rays, hint, counters)
            };
        }
        let mut occluded = 0u16;
        for (l, (&d, &t)) in directions.iter().zip(tmax).enumerate() {
            if self.occluded_hinted::<COUNT>(origin, d, t, hint, counters) {
                occluded |= 1 << l;
            }
        }
        occluded
    }

    /// [`Self::occluded_packet`] under AVX-512: the hinted node's subtree, then the tree
    /// without it, for the rays still unanswered.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx512vl,popcnt")]
    fn occluded_packet_avx512<const COUNT: bool>(
        &self,
        packet: &Packet,
        rays: &mut LaneRays,
        hint: &mut OccluderHint,
        counters: &mut TraversalCounters,
    ) -> u16 {
        let mut active = packet.all;
        let mut skip = NO_NODE;
        if (hint.node as usize) < self.tree.nodes.len() {
            self.packet_search::<COUNT>(packet, rays, hint.node, NO_NODE, &mut active, counters);
            if hint.node == 0 || active == 0 {
                return packet.all & !active;
            }
            skip = hint.node;
        }
        if let Some(node) =
            self.packet_search::<COUNT>(packet, rays, 0, skip, &mut active, counters)
        {
            hint.node = self.hint_node(node);
        }
        packet.all & !active
    }

    /// [`Self::packet_subtree`] with the fixed stack where the tree is shallow enough for it
    /// (see [`BoundedStack`]).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx512vl,popcnt")]
    fn packet_search<const COUNT: bool>(
        &self,
        packet: &Packet,
        rays: &mut LaneRays,
        start: u32,
        skip: u32,
        active: &mut u16,
        counters: &mut TraversalCounters,
    ) -> Option<u32> {
        if self.stack_is_bounded() {
            type Bounded = BoundedStack<(u32, u16, u32), STACK>;
            type Single = BoundedStack<(u32, u32), STACK>;
            self.packet_subtree::<COUNT, Bounded, Single>(
                packet, rays, start, skip, active, counters,
            )
        } else {
            type Spilling = Stack<(u32, u16, u32), STACK>;
            type Single = Stack<(u32, u32), STACK>;
            self.packet_subtree::<COUNT, Spilling, Single>(
                packet, rays, start, skip, active, counters,
            )
        }
    }

    /// Any-hit search of the subtree under node `start`, not entering node `skip`, for the
    /// rays of `active`; clears the bits of those found occluded and returns the node whose
    /// leaf held the first occluder, if any. Leaves are requested and stacked as in
    /// [`Self::occluder_walk`] (entries: child reference, lanes, and the leaf's node).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx512vl,popcnt")]
    fn packet_subtree<
        const COUNT: bool,
        S: TraversalStack<(u32, u16, u32)>,
        S1: TraversalStack<(u32, u32)>,
    >(
        &self,
        packet: &Packet,
        rays: &mut LaneRays,
        start: u32,
        skip: u32,
        active: &mut u16,
        counters: &mut TraversalCounters,
    ) -> Option<u32> {
        let (mut nodes, mut tests) = (0u64, 0u64);
        let mut occluder = None;
        let mut stack = S::new();
        let lane_tmax = lanes(packet.tmax);
        let large = self.tree.outgrows_l2();
        stack.push((start, *active, NO_NODE));
        'trace: while let Some((entry, lanes, holder)) = stack.pop() {
            let lanes = lanes & *active;
            if lanes == 0 {
                continue;
            }
            let node = match decode(entry) {
                // In trees larger than L2, a subtree that one lane reaches is searched
                // by that lane's single ray: its eight-child box test is exact, where the
                // packet's interval test keeps children no lane hits (four in ten of
                // them), and a third of garden's packet node visits are by one lane
                // (its bundles about 1.03x; on cornell's small tree 0.95x, so not there).
                Child::Node(node) if large && lanes.count_ones() == 1 => {
                    let l = lanes.trailing_zeros() as usize % PACKET;
                    let r = self.local_ray(rays.origin, rays.directions[l], rays.tmax[l]);
                    // SAFETY: the CPU has AVX-512 F and VL (this function's contract).
                    let box_test = unsafe { Avx512BoxTest::new() };
                    if let Some(holder) =
                        self.occluder_walk::<COUNT, S1>(&r, node, skip, counters, box_test)
                    {
                        *active &= !lanes;
                        occluder.get_or_insert(holder);
                        if *active == 0 {
                            break 'trace;
                        }
                    }
                    continue;
                }
                Child::Node(node) => node,
                Child::Leaf { first, count } => {
                    let block = &self.blocks[first as usize];
                    if COUNT {
                        tests += count as u64 * lanes.count_ones() as u64;
                    }
                    let mut occluded = 0u16;
                    if lanes.count_ones() >= VECTOR_TRIANGLE_LANES {
                        for t in 0..count as usize {
                            occluded |=
                                packet
                                    .watertight
                                    .hits(block, t, packet.tmax, lanes & !occluded);
                        }
                    } else {
                        let mut rest = lanes;
                        while rest != 0 {
                            let l = rest.trailing_zeros() as usize;
                            rest &= rest - 1;
                            let r = rays.get(&packet.watertight, l);
                            if r.intersect4(block, lane_tmax[l]).0 != 0 {
                                occluded |= 1 << l;
                            }
                        }
                    }
                    if occluded != 0 {
                        *active &= !occluded;
                        occluder.get_or_insert(holder);
                        if *active == 0 {
                            break 'trace;
                        }
                    }
                    continue;
                }
            };
            let n = &self.tree.nodes[node as usize];
            if COUNT {
                nodes += lanes.count_ones() as u64;
            }
            let relative = packet.relative_planes(n);
            let mut touched = packet.children_touched(&relative);
            while touched != 0 {
                let j = touched.trailing_zeros() as usize;
                touched &= touched - 1;
                let r = n.child(j);
                let hit = packet.box_hits(&relative, j, lanes);
                let keep = hit != 0 && r != skip;
                self.request_child(n, r, keep);
                stack.push_if((r, hit, if is_leaf(r) { node } else { NO_NODE }), keep);
            }
        }
        if COUNT {
            counters.nodes += nodes;
            counters.triangles += tests;
        }
        occluder
    }

    /// Closest hit on `origin + t direction` with `t` in `[0, tmax)`, if any.
    #[inline]
    pub fn intersect<const COUNT: bool>(
        &self,
        origin: Vec3A,
        direction: Vec3A,
        tmax: f32,
        counters: &mut TraversalCounters,
    ) -> Option<Hit> {
        if COUNT {
            counters.rays += 1;
        }
        if self.blocks.is_empty() {
            return None;
        }
        #[cfg(target_arch = "x86_64")]
        match crate::simd::level() {
            // SAFETY: the CPU has AVX-512 F and VL.
            crate::simd::SimdLevel::Avx512 => unsafe {
                return self.closest_hit_avx512::<COUNT>(origin, direction, tmax, counters);
            },
            // SAFETY: the CPU has AVX2.
            crate::simd::SimdLevel::Avx2 => unsafe {
                return self.closest_hit_avx2::<COUNT>(origin, direction, tmax, counters);
            },
            _ => {}
        }
        let r = self.local_ray(origin, direction, tmax);
        self.closest_hit::<COUNT, Stack<_, STACK>>(&r, counters, PortableBoxTest)
    }

    /// [`Self::intersect`] on a non-empty tree (the ray not yet counted) with AVX2 box
    /// tests.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn closest_hit_avx2<const COUNT: bool>(
        &self,
        origin: Vec3A,
        direction: Vec3A,
        tmax: f32,
        counters: &mut TraversalCounters,
    ) -> Option<Hit> {
        // SAFETY: the CPU has AVX2 (this function's contract).
        let box_test = unsafe { Avx2BoxTest::new() };
        self.closest_hit_vector::<COUNT>(origin, direction, tmax, counters, box_test)
    }

    /// [`Self::closest_hit_avx2`] with 32 vector registers (see [`Self::hinted_avx512`]).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,avx512f,avx512vl")]
    fn closest_hit_avx512<const COUNT: bool>(
        &self,
        origin: Vec3A,
        direction: Vec3A,
        tmax: f32,
        counters: &mut TraversalCounters,
    ) -> Option<Hit> {
        // SAFETY: the CPU has AVX-512 F and VL (this function's contract).
        let box_test = unsafe { Avx512BoxTest::new() };
        self.closest_hit_vector::<COUNT>(origin, direction, tmax, counters, box_test)
    }

    /// The body of [`Self::closest_hit_avx2`] and [`Self::closest_hit_avx512`], with their
    /// `box_test`.
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    fn closest_hit_vector<const COUNT: bool>(
        &self,
        origin: Vec3A,
        direction: Vec3A,
        tmax: f32,
        counters: &mut TraversalCounters,
        box_test: impl BoxTest,
    ) -> Option<Hit> {
        let r = self.local_ray(origin, direction, tmax);
        if self.stack_is_bounded() {
            self.closest_hit::<COUNT, BoundedStack<_, STACK>>(&r, counters, box_test)
        } else {
            self.closest_hit::<COUNT, Stack<_, STACK>>(&r, counters, box_test)
        }
    }

    /// The traversal of [`Self::intersect`], with `box_test` one of the forms of
    /// [`Node8::intersect`].
    #[inline(always)]
    fn closest_hit<const COUNT: bool, S: TraversalStack<(u32, f32)>>(
        &self,
        r: &LocalRay,
        counters: &mut TraversalCounters,
        box_test: impl BoxTest,
    ) -> Option<Hit> {
        let (mut nodes, mut tests) = (0u64, 0u64);
        let mut best_t = r.tmax;
        let mut best: Option<(u32, TriangleHit)> = None;
        // Entries carry their entry distance so that boxes behind the closest hit found so
        // far are skipped when popped.
        let mut stack = S::new();
        stack.push((0, 0.0));
        while let Some((reference, t_enter)) = stack.pop() {
            if t_enter > best_t {
                continue;
            }
            match decode(reference) {
                Child::Leaf { first, count } => {
                    if COUNT {
                        tests += count as u64;
                    }
                    let (mut hit, t, u, v) = r
                        .watertight
                        .intersect4(&self.blocks[first as usize], best_t);
                    let (t, u, v) = (t.to_array(), u.to_array(), v.to_array());
                    // Nearest lane; the lowest lane wins ties, so the answer is deterministic.
                    while hit != 0 {
                        let l = hit.trailing_zeros() as usize;
                        hit &= hit - 1;
                        if t[l] < best_t {
                            best_t = t[l];
                            best = Some((
                                first * 4 + l as u32,
                                TriangleHit {
                                    t: t[l],
                                    u: u[l],
                                    v: v[l],
                                },
                            ));
                        }
                    }
                }
                Child::Node(c) => {
                    let n = &self.tree.nodes[c as usize];
                    if COUNT {
                        nodes += 1;
                    }
                    let (t_near, mut mask) = box_test.test(n, &r.boxes, best_t);
                    // Push the hit children farthest first, so the nearest is popped next.
                    let mut hits = [(0u32, 0f32); WIDTH];
                    let mut k = 0;
                    while mask != 0 {
                        let i = mask.trailing_zeros() as usize;
                        mask &= mask - 1;
                        let mut j = k;
                        while j > 0 && hits[j - 1].1 < t_near[i] {
                            hits[j] = hits[j - 1];
                            j -= 1;
                        }
                        hits[j] = (n.child(i), t_near[i]);
                        k += 1;
                    }
                    for &h in &hits[..k] {
                        if let Child::Node(c) = decode(h.0) {
                            self.tree.prefetch(c);
                        }
                        stack.push(h);
                    }
                }
            }
        }
        if COUNT {
            counters.nodes += nodes;
            counters.triangles += tests;
        }
        best.map(|(slot, h)| Hit {
            t: h.t * r.t_to_param,
            triangle: self.triangle_ids[slot as usize],
            u: h.u,
            v: h.v,
        })
    }
}

/// A packet's rays as given, for the lanes that continue alone, and their single
/// watertight rays, each prepared when its lane first tests a leaf alone and kept for the
/// packet's later leaves (extracting a lane's ray from the packet's registers at every
/// leaf cost about as much as the triangle test itself; garden's bundles test 2.4 lanes
/// per leaf, 36 leaves per packet).
#[cfg(target_arch = "x86_64")]
struct LaneRays<'a> {
    /// The packet's rays as given (one origin).
    origin: Vec3A,
    directions: &'a [Vec3A],
    tmax: &'a [f32],
    /// Left uninitialised until prepared: filling all sixteen up front cost a kilobyte of
    /// stores per packet, as much as a packet of `dynamics`'s short rays takes to trace.
    rays: [std::mem::MaybeUninit<WatertightRay>; PACKET],
    /// The lanes whose ray is prepared.
    ready: u16,
}

#[cfg(target_arch = "x86_64")]
impl<'a> LaneRays<'a> {
    #[inline(always)]
    fn new(origin: Vec3A, directions: &'a [Vec3A], tmax: &'a [f32]) -> Self {
        LaneRays {
            origin,
            directions,
            tmax,
            rays: [const { std::mem::MaybeUninit::uninit() }; PACKET],
            ready: 0,
        }
    }

    /// Lane `l`'s ray ([`WatertightPacket::lane_ray`]).
    #[inline(always)]
    fn get(&mut self, packet: &WatertightPacket, l: usize) -> &WatertightRay {
        let l = l % PACKET;
        if self.ready >> l & 1 == 0 {
            self.rays[l].write(packet.lane_ray(l));
            self.ready |= 1 << l;
        }
        // SAFETY: lane `l` was written above or when its `ready` bit was set.
        unsafe { self.rays[l].assume_init_ref() }
    }
}

/// A packet of up to [`PACKET`] rays from one origin, prepared for box tests sixteen lanes
/// at a time (see [`Bvh::occluded_packet`]).
#[cfg(target_arch = "x86_64")]
struct Packet {
    /// The lanes holding rays.
    all: u16,
    origin: [std::arch::x86_64::__m512; 3],
    inverse: [std::arch::x86_64::__m512; 3],
    /// Lanes whose direction is negative on each axis: they enter a box by its max plane.
    negative: [std::arch::x86_64::__mmask16; 3],
    /// Per axis, the row of [`Packet::relative_planes`] that every lane enters by and the
    /// row it leaves by, where the lanes agree in sign there (see `mixed_signs`).
    near_row: [usize; 3],
    far_row: [usize; 3],
    /// `tmax · EXIT_SCALE` per lane.
    exit: std::arch::x86_64::__m512,
    /// `tmax` per lane (local frame).
    tmax: std::arch::x86_64::__m512,
    watertight: WatertightPacket,
    /// The packet's rays as one interval ray, for [`Packet::children_touched`]: per axis
    /// the least and greatest inverse direction component over the lanes, and whether
    /// the lanes disagree in sign there.
    inverse_low: [f32; 3],
    inverse_high: [f32; 3],
    mixed_signs: [bool; 3],
    /// The greatest `tmax · EXIT_SCALE` over the lanes.
    exit_high: f32,
}

#[cfg(target_arch = "x86_64")]
impl Packet {
    /// `1..=PACKET` rays. Every lane computes what [`Bvh::local_ray`] computes for its ray,
    /// with the same operations in the same order (so the same bits), sixteen lanes at a
    /// time: preparing the rays one by one took as long as tracing them on cornell.
    #[target_feature(enable = "avx512f")]
    fn new(bvh: &Bvh, origin: Vec3A, directions: &[Vec3A], tmax: &[f32]) -> Self {
        use std::arch::x86_64::*;
        let count = directions.len();
        let lane = |l: usize| l.min(count - 1);
        let rows: [[f32; PACKET]; 4] = [
            std::array::from_fn(|l| directions[lane(l)].x),
            std::array::from_fn(|l| directions[lane(l)].y),
            std::array::from_fn(|l| directions[lane(l)].z),
            std::array::from_fn(|l| tmax[lane(l)]),
        ];
        // SAFETY: each row holds PACKET = 16 f32s.
        let [dx, dy, dz, t] = rows.map(|r| unsafe { _mm512_loadu_ps(r.as_ptr()) });
        let splat = _mm512_set1_ps;
        let (mul, add, div) = (_mm512_mul_ps, _mm512_add_ps, _mm512_div_ps);
        // `local_ray`: the direction scaled by `direction_scale`'s powers of two (formed
        // from the exponent bits of the largest magnitude, clamped alike) and the tmax.
        let largest = _mm512_max_ps(
            _mm512_max_ps(_mm512_abs_ps(dx), _mm512_abs_ps(dy)),
            _mm512_abs_ps(dz),
        );
        let biased = _mm512_min_epi32(
            _mm512_max_epi32(
                _mm512_and_si512(
                    _mm512_srli_epi32::<23>(_mm512_castps_si512(largest)),
                    _mm512_set1_epi32(0xff),
                ),
                _mm512_set1_epi32(1),
            ),
            _mm512_set1_epi32(253),
        );
        let power = |exponent: __m512i| _mm512_castsi512_ps(_mm512_slli_epi32::<23>(exponent));
        let scale = power(_mm512_sub_epi32(_mm512_set1_epi32(254), biased));
        let scaled = [mul(dx, scale), mul(dy, scale), mul(dz, scale)];
        let tmax = mul(mul(t, power(biased)), splat(bvh.to_local));
        let o = origin * bvh.to_local;
        // `BoxRay::new`: the inverse of the scaled direction plus +0.0, clamped.
        let inverse = scaled.map(|u| {
            let r = div(splat(1.0), add(u, _mm512_setzero_ps()));
            _mm512_min_ps(_mm512_max_ps(r, splat(-1e30)), splat(1e30))
        });
        // `WatertightRay::new`: the largest axis kz, then kx and ky, swapped when the
        // direction points backwards along kz, and the shear.
        let abs = scaled.map(|u| _mm512_abs_ps(u));
        let gt = |a: __m512, b: __m512| _mm512_cmp_ps_mask::<_CMP_GT_OQ>(a, b);
        let (x_y, x_z, y_z) = (gt(abs[0], abs[1]), gt(abs[0], abs[2]), gt(abs[1], abs[2]));
        let kz_is = [x_y & x_z, !x_y & y_z];
        let pick = |v: [__m512; 3], is: [__mmask16; 2]| {
            _mm512_mask_blend_ps(is[1], _mm512_mask_blend_ps(is[0], v[2], v[0]), v[1])
        };
        let d_kz = pick(scaled, kz_is);
        let backwards = _mm512_cmp_ps_mask::<_CMP_LT_OQ>(d_kz, _mm512_setzero_ps());
        // kx is kz + 1 (mod 3) and ky is kz + 2, or the other way round going backwards.
        let next = [!kz_is[0] & !kz_is[1], kz_is[0]];
        let after = [kz_is[1], !kz_is[0] & !kz_is[1]];
        let swap = |a: [__mmask16; 2], b: [__mmask16; 2]| {
            [0, 1].map(|i| (a[i] & !backwards) | (b[i] & backwards))
        };
        let (kx_is, ky_is) = (swap(next, after), swap(after, next));
        let sz = div(splat(1.0), d_kz);
        let sx = mul(pick(scaled, kx_is), sz);
        let sy = mul(pick(scaled, ky_is), sz);
        // Masks of the lanes where an axis is 1 and where it is 2 (else it is 0).
        let one_two = |is: [__mmask16; 2]| [is[1], !(is[0] | is[1])];
        let (kx_12, ky_12, kz_12) = (one_two(kx_is), one_two(ky_is), one_two(kz_is));
        let exit = mul(tmax, splat(EXIT_SCALE));
        let watertight = WatertightPacket::from_lanes(o, [kx_12, ky_12, kz_12], [sx, sy, sz]);
        let negative = inverse.map(|v| _mm512_cmp_ps_mask::<_CMP_LT_OQ>(v, _mm512_setzero_ps()));
        // Only read on axes where the lanes agree in sign, where any lane is every lane.
        let any_negative = negative.map(|m| m != 0);
        Packet {
            near_row: [0, 1, 2].map(|a| 2 * a + any_negative[a] as usize),
            far_row: [0, 1, 2].map(|a| 2 * a + 1 - any_negative[a] as usize),
            all: (u32::MAX >> (32 - count)) as u16,
            origin: [o.x, o.y, o.z].map(|v| _mm512_set1_ps(v)),
            inverse,
            negative,
            exit_high: _mm512_reduce_max_ps(exit),
            exit,
            tmax,
            watertight,
            inverse_low: inverse.map(|v| _mm512_reduce_min_ps(v)),
            inverse_high: inverse.map(|v| _mm512_reduce_max_ps(v)),
            mixed_signs: negative.map(|m| m != 0 && m != u16::MAX),
        }
    }

    /// The children of `n` whose box some ray of the packet may touch (bit `j` for child
    /// `j`): a superset of the children [`Self::box_hits`] finds for any lane, tested for
    /// all children at once against the interval of the lanes' inverse directions.
    ///
    /// Why it is conservative: the lanes share the origin, so a plane's offset `p - o` is
    /// the same in every lane, and rounded products are monotone in each factor, so
    /// `(p - o) · inv` over the lanes lies between its values at the least and greatest
    /// inverse. The lower ends of the entry terms and the upper ends of the exit terms
    /// then bound every lane's entry from below and exit from above through the same
    /// (monotone) max, min and scaling. On an axis where the lanes' signs differ, their
    /// near planes differ too, and that axis is left unbounded.
    #[target_feature(enable = "avx512f")]
    #[inline]
    fn children_touched(&self, relative: &[[f32; WIDTH]; 6]) -> u32 {
        use std::arch::x86_64::*;
        let bound = |axis: usize| {
            // The rows of the lanes' common sign; on an axis of mixed signs the bound
            // is dropped below, whichever rows these are.
            let (near, far) = (self.near_row[axis], self.far_row[axis]);
            let (lo, hi) = (
                _mm256_set1_ps(self.inverse_low[axis]),
                _mm256_set1_ps(self.inverse_high[axis]),
            );
            // SAFETY: each row holds WIDTH = 8 f32s.
            let (n, f) = unsafe {
                (
                    _mm256_loadu_ps(relative[near].as_ptr()),
                    _mm256_loadu_ps(relative[far].as_ptr()),
                )
            };
            let entry = _mm256_min_ps(_mm256_mul_ps(n, lo), _mm256_mul_ps(n, hi));
            let exit = _mm256_max_ps(_mm256_mul_ps(f, lo), _mm256_mul_ps(f, hi));
            if self.mixed_signs[axis] {
                (
                    _mm256_set1_ps(f32::NEG_INFINITY),
                    _mm256_set1_ps(f32::INFINITY),
                )
            } else {
                (entry, exit)
            }
        };
        let (nx, fx) = bound(0);
        let (ny, fy) = bound(1);
        let (nz, fz) = bound(2);
        // SAFETY: AVX-512 F includes AVX2, and this function is compiled for it.
        let (_, touched) = unsafe {
            slab_overlap_avx2([nx, ny, nz], [fx, fy, fz], _mm256_set1_ps(self.exit_high))
        };
        touched
    }

    /// Node `n`'s planes less the packet's origin, `planes[k][j] - origin[k / 2]`: the
    /// offsets that every lane's box test starts from (the lanes share the origin), so
    /// they are computed once per node, eight children at a time, instead of in each lane
    /// of each child's test (bit for bit the same differences).
    #[target_feature(enable = "avx512f")]
    #[inline]
    fn relative_planes(&self, n: &Node8) -> [[f32; WIDTH]; 6] {
        use std::arch::x86_64::*;
        let planes = n.planes();
        let mut relative = [[0.0; WIDTH]; 6];
        for (k, row) in relative.iter_mut().enumerate() {
            // The origin's splat, from the lower half of its sixteen-lane register.
            let o = _mm512_castps512_ps256(self.origin[k / 2]);
            // SAFETY: each row holds WIDTH = 8 f32s.
            unsafe {
                let d = _mm256_sub_ps(_mm256_loadu_ps(planes[k].as_ptr()), o);
                _mm256_storeu_ps(row.as_mut_ptr(), d);
            }
        }
        relative
    }

    /// The lanes of `lanes` whose segment touches child `j`'s box, given the node's
    /// [`Self::relative_planes`]: the test of [`Node8::intersect`] with the same operations
    /// in every lane. On an axis where the lanes agree in sign, every lane enters and
    /// leaves by the same planes, and their offsets are splatted without a blend.
    #[target_feature(enable = "avx512f")]
    #[inline]
    fn box_hits(&self, relative: &[[f32; WIDTH]; 6], j: usize, lanes: u16) -> u16 {
        use std::arch::x86_64::*;
        // Below WIDTH for the callers' child bits; said so, the row reads need no checks.
        let j = j % WIDTH;
        let slab = |axis: usize| {
            let (near, far) = if self.mixed_signs[axis] {
                let lo = _mm512_set1_ps(relative[2 * axis][j]);
                let hi = _mm512_set1_ps(relative[2 * axis + 1][j]);
                (
                    _mm512_mask_blend_ps(self.negative[axis], lo, hi),
                    _mm512_mask_blend_ps(self.negative[axis], hi, lo),
                )
            } else {
                // SAFETY: `near_row` and `far_row` hold `2 axis` or `2 axis + 1`, below 6.
                let (near, far) = unsafe {
                    (
                        relative.get_unchecked(self.near_row[axis]),
                        relative.get_unchecked(self.far_row[axis]),
                    )
                };
                (_mm512_set1_ps(near[j]), _mm512_set1_ps(far[j]))
            };
            (
                _mm512_mul_ps(near, self.inverse[axis]),
                _mm512_mul_ps(far, self.inverse[axis]),
            )
        };
        let (nx, fx) = slab(0);
        let (ny, fy) = slab(1);
        let (nz, fz) = slab(2);
        let t_near = _mm512_max_ps(
            _mm512_max_ps(_mm512_max_ps(nx, ny), nz),
            _mm512_setzero_ps(),
        );
        let t_far = _mm512_min_ps(
            _mm512_mul_ps(
                _mm512_min_ps(_mm512_min_ps(fx, fy), fz),
                _mm512_set1_ps(EXIT_SCALE),
            ),
            self.exit,
        );
        _mm512_mask_cmp_ps_mask::<_CMP_LE_OQ>(lanes, t_near, t_far)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bsdf::Material;
    use glam::vec3a;

    fn quad_mesh(scale: f32) -> Mesh {
        let mut m = Mesh::new();
        let v = [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [0.0, 1.0, 0.0],
        ]
        .map(|p: [f32; 3]| p.map(|c| c * scale));
        m.add_indexed(&v, &[[0, 1, 2], [0, 2, 3]], Material::DEFAULT, None)
            .unwrap();
        m
    }

    /// In trees larger than L2, where a subtree that one lane of a packet reaches is
    /// searched by that lane's single ray, packets still answer as single rays: garden's
    /// grass from points on the ground, in narrow and wide cones, with finite `tmax`.
    #[test]
    fn packets_in_large_trees_answer_as_single_rays() {
        use crate::sampling::rng::{hash4, to_unit_f32};
        let unit = |a: u64, b: u64| to_unit_f32(hash4(a, b, 0, 11));
        let scene = crate::scenes::load("garden", 0.25, 3).unwrap().scene;
        let bvh = scene.bvh();
        assert!(bvh.outgrows_l2(), "the test needs a tree larger than L2");
        let (mut occluded, mut open) = (0, 0);
        for (k, (p, n)) in crate::testing::surface_points(&scene, Some("ground"), 64, 7)
            .into_iter()
            .enumerate()
        {
            let origin = Vec3A::from(scene.offset_point(p, n));
            let mut hint = OccluderHint::NONE;
            for q in 0..4u64 {
                let s = 4 * k as u64 + q;
                let axis = vec3a(unit(1, s) - 0.5, unit(2, s) * 0.8 + 0.05, unit(3, s) - 0.5);
                let spread = [0.02, 0.2, 0.8][s as usize % 3];
                let dirs: Vec<Vec3A> = (0..PACKET as u64)
                    .map(|l| {
                        let e = vec3a(
                            unit(4, 16 * s + l),
                            unit(5, 16 * s + l),
                            unit(6, 16 * s + l),
                        );
                        axis + (e - 0.5) * spread
                    })
                    .collect();
                let tmax: Vec<f32> = (0..PACKET as u64)
                    .map(|l| [f32::INFINITY, 0.05, 0.3][((s + l) % 3) as usize])
                    .collect();
                let mut c = TraversalCounters::default();
                let got = bvh.occluded_packet::<true>(origin, &dirs, &tmax, &mut hint, &mut c);
                let mut none = TraversalCounters::default();
                for (l, (&d, &t)) in dirs.iter().zip(&tmax).enumerate() {
                    let alone = bvh.occluded::<false>(origin, d, t, &mut none);
                    assert_eq!(got >> l & 1 != 0, alone, "point {k} packet {q} ray {l}");
                    (occluded, open) = (occluded + alone as u32, open + !alone as u32);
                }
            }
        }
        assert!(
            occluded > 500 && open > 500,
            "{occluded} occluded, {open} open"
        );
    }

    #[test]
    fn local_scale_is_a_power_of_two_in_range() {
        for e in [1e-4f32, 0.3, 1.0, 255.9, 256.0, 511.0, 1e4, 3e7] {
            let s = local_scale(e);
            assert_eq!(s.to_bits() & 0x007f_ffff, 0, "not a power of two: {s}");
            assert!((256.0..512.0).contains(&(e * s)), "{e} -> {}", e * s);
        }
    }

    #[test]
    fn empty_single_and_degenerate() {
        let mut c = TraversalCounters::default();
        let empty = Bvh::build(&Mesh::new(), BuildQuality::Fast);
        let o = vec3a(0.5, 0.5, 1.0);
        let d = vec3a(0.0, 0.0, -1.0);
        assert!(!empty.occluded::<true>(o, d, f32::INFINITY, &mut c));
        assert!(empty
            .intersect::<true>(o, d, f32::INFINITY, &mut c)
            .is_none());
        assert_eq!(c.rays, 2);

        let mut m = Mesh::new();
        let v = [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [2.0, 0.0, 0.0],
        ];
        m.add_indexed(&v, &[[0, 1, 3], [0, 1, 2]], Material::DEFAULT, None)
            .unwrap();
        let single = Bvh::build(&m, BuildQuality::Fast);
        assert_eq!(single.blocks.len(), 1);
        assert!(
            single.triangle_ids.iter().all(|&t| t == 1),
            "the collinear triangle is left out"
        );
        let h = single
            .intersect::<false>(vec3a(0.25, 0.25, 1.0), d, f32::INFINITY, &mut c)
            .unwrap();
        assert_eq!(h.triangle, 1);
        assert!((h.t - 1.0).abs() < 1e-6);
    }

    /// `Auto` keeps the PLOC tree only where it does 5% less probe work, says which and
    /// why, and answers as both do; an empty mesh builds too.
    #[test]
    fn auto_keeps_the_cheaper_tree() {
        use crate::sampling::rng::{hash4, to_unit_f32};
        let unit = |a: u64, b: u64| to_unit_f32(hash4(a, b, 0, 23));
        let mut soup = Mesh::new();
        // Long thin slivers in random directions: trees from the two builders differ.
        let v: Vec<[f32; 3]> = (0..3000u64)
            .map(|i| {
                let s = if i % 3 == 1 { 4.0 } else { 0.1 };
                let c = i / 3;
                [
                    unit(1, c) * 8.0 + unit(4, i) * s,
                    unit(2, c) * 8.0 + unit(5, i) * 0.1,
                    unit(3, c) * 8.0 + unit(6, i) * 0.1,
                ]
            })
            .collect();
        let faces: Vec<[i64; 3]> = (0..1000).map(|k| [3 * k, 3 * k + 1, 3 * k + 2]).collect();
        soup.add_indexed(&v, &faces, Material::DEFAULT, None)
            .unwrap();
        let sah = Bvh::build(&soup, BuildQuality::Sah);
        let ploc = Bvh::build(&soup, AUTO_ALTERNATIVE);
        let auto = Bvh::build(&soup, BuildQuality::Auto);
        assert_ne!(sah.sah_cost(), ploc.sah_cost());
        let [s, p] = auto.auto_costs().expect("compared");
        let rays = probe_rays(&soup, AUTO_PROBE_RAYS);
        assert_eq!([s, p], [sah.probe_work(&rays), ploc.probe_work(&rays)]);
        assert!(s > 1.0 && p > 1.0, "{s} {p}");
        let chosen = if s > AUTO_MARGIN * p {
            AUTO_ALTERNATIVE
        } else {
            BuildQuality::Sah
        };
        assert_eq!(auto.quality(), chosen);
        let kept = if chosen == BuildQuality::Sah {
            &sah
        } else {
            &ploc
        };
        assert_eq!(auto.sah_cost(), kept.sah_cost());
        assert_eq!(sah.auto_costs(), None);
        assert_eq!(auto.requested_quality(), BuildQuality::Auto);
        assert_eq!(sah.requested_quality(), BuildQuality::Sah);
        assert!(sah.sah_cost() > 1.0 && ploc.sah_cost() > 1.0);
        let mut c = TraversalCounters::default();
        for k in 0..2000u64 {
            let o = vec3a(unit(7, k), unit(8, k), unit(9, k)) * 10.0 - 1.0;
            let d = vec3a(unit(10, k), unit(11, k), unit(12, k)) - 0.5;
            let a = auto.intersect::<false>(o, d, f32::INFINITY, &mut c);
            let b = sah.intersect::<false>(o, d, f32::INFINITY, &mut c);
            assert_eq!(a.map(|h| (h.t, h.triangle)), b.map(|h| (h.t, h.triangle)));
        }
        let empty = Bvh::build(&Mesh::new(), BuildQuality::Auto);
        assert_eq!(empty.sah_cost(), 0.0);
        assert!(!empty.occluded::<false>(vec3a(0.0, 0.0, 1.0), vec3a(0.0, 0.0, -1.0), 1.0, &mut c));
    }

    /// A packet prepares each lane exactly as the single-ray traversal prepares that ray:
    /// the same watertight ray (axes, shear, permuted origin), inverse direction and local
    /// `tmax`, bit for bit. Directions of every octant and largest axis, with zero and
    /// negative-zero components, ties between axes, tiny and huge lengths; packets of 1 to
    /// 16 rays; finite and infinite `tmax`.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn packets_prepare_each_lane_as_a_single_ray() {
        use crate::sampling::rng::{hash4, to_unit_f32};
        if crate::simd::level() != crate::simd::SimdLevel::Avx512 {
            return;
        }
        let unit = |a: u64, b: u64| to_unit_f32(hash4(a, b, 0, 33));
        let bvh = Bvh::build(&quad_mesh(3.0), BuildQuality::Sah);
        let special = [0.0, -0.0, 1.0, -1.0, 1e-20, -3e-38, 7e20];
        let mut checked = 0;
        for k in 0..400u64 {
            let count = 1 + (k as usize % PACKET);
            let origin = vec3a(unit(1, k), unit(2, k), unit(3, k)) * 20.0 - 10.0;
            let dirs: Vec<Vec3A> = (0..count as u64)
                .map(|l| {
                    let s = 16 * k + l;
                    let mut d = vec3a(unit(4, s), unit(5, s), unit(6, s)) * 2.0 - 1.0;
                    for axis in 0..3 {
                        if unit(7 + axis as u64, s) < 0.25 {
                            d[axis] = special[(unit(10, s) * 7.0) as usize % 7];
                        }
                    }
                    if unit(11, s) < 0.1 {
                        d = vec3a(d.x, d.x, -d.x);
                    }
                    let scale = [1.0, 1e-12, 1e12][s as usize % 3];
                    // Largest components that are subnormal or above 2^127, where the
                    // power-of-two scaling clamps its exponent.
                    let extreme = [
                        vec3a(1e-40, -3e-41, 0.0),
                        vec3a(-1.4e-45, 0.0, 1.4e-45),
                        vec3a(3e38, -1e38, 2e38),
                        vec3a(0.0, -f32::MAX, 1.0),
                    ];
                    match unit(12, s) {
                        u if u < 0.1 => extreme[s as usize % 4],
                        _ => d * scale,
                    }
                })
                .map(|d| {
                    if d.abs().max_element() > 0.0 && d.is_finite() {
                        d
                    } else {
                        Vec3A::X
                    }
                })
                .collect();
            let tmax: Vec<f32> = (0..count)
                .map(|l| [f32::INFINITY, 2.5, 1e-3, 0.0, f32::MAX][(k as usize + l) % 5])
                .collect();
            // SAFETY: the CPU has AVX-512 F.
            let packet = unsafe { Packet::new(&bvh, origin, &dirs, &tmax) };
            let singles: [LocalRay; PACKET] = std::array::from_fn(|l| {
                let s = l.min(count - 1);
                bvh.local_ray(origin, dirs[s], tmax[s])
            });
            // SAFETY: as above.
            let gathered = unsafe { WatertightPacket::new(&singles.map(|r| r.watertight)) };
            assert_eq!(packet.watertight.bits(), gathered.bits(), "packet {k}");
            let inverse = packet.inverse.map(lanes);
            for (l, r) in singles.iter().enumerate() {
                let ray = packet.watertight.lane_ray(l);
                assert_eq!(ray.bits(), r.watertight.bits(), "packet {k} lane {l}");
                assert_eq!(lanes(packet.tmax)[l].to_bits(), r.tmax.to_bits());
                let (o, inv) = r.boxes.origin_and_inverse();
                for axis in 0..3 {
                    assert_eq!(inverse[axis][l].to_bits(), inv[axis].to_bits());
                }
                assert_eq!(o.map(f32::to_bits), ray.bits()[..3]);
                checked += 1;
            }
        }
        assert_eq!(checked, 400 * PACKET);
    }

    /// Each lane of the packet's box test hits the children its ray's own box test hits,
    /// and the packet's interval test keeps every child that some lane hits, on every node
    /// of a random soup's tree, for packets narrow and wide, with lanes of one sign and of
    /// mixed signs per axis, axis-parallel directions and finite `tmax`.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn packet_interval_test_keeps_every_child_a_lane_touches() {
        use crate::sampling::rng::{hash4, to_unit_f32};
        if crate::simd::level() != crate::simd::SimdLevel::Avx512 {
            return;
        }
        let unit = |a: u64, b: u64| to_unit_f32(hash4(a, b, 0, 21));
        let mut soup = Mesh::new();
        let v: Vec<[f32; 3]> = (0..3000u64)
            .map(|i| [unit(1, i) * 8.0, unit(2, i) * 8.0, unit(3, i) * 8.0])
            .collect();
        let faces: Vec<[i64; 3]> = (0..1000).map(|k| [3 * k, 3 * k + 1, 3 * k + 2]).collect();
        soup.add_indexed(&v, &faces, Material::DEFAULT, None)
            .unwrap();
        let bvh = Bvh::build(&soup, BuildQuality::Medium);
        let (mut kept, mut culled) = (0u64, 0u64);
        for k in 0..300u64 {
            let origin = vec3a(unit(4, k), unit(5, k), unit(6, k)) * 10.0 - 1.0;
            let axis = vec3a(unit(7, k), unit(8, k), unit(9, k)) - 0.5;
            let spread = [0.02, 0.3, 2.0][k as usize % 3];
            let dirs: Vec<Vec3A> = (0..PACKET as u64)
                .map(|l| {
                    let s = 16 * k + l;
                    let d = axis + (vec3a(unit(10, s), unit(11, s), unit(12, s)) - 0.5) * spread;
                    if s % 11 == 0 {
                        vec3a(d.x, 0.0, d.z)
                    } else {
                        d
                    }
                })
                .filter(|d| d.length() > 0.0)
                .collect();
            let tmax: Vec<f32> = (0..dirs.len())
                .map(|l| [f32::INFINITY, 3.0, 0.5][(k as usize + l) % 3])
                .collect();
            // SAFETY: the CPU has AVX-512 F.
            let packet = unsafe { Packet::new(&bvh, origin, &dirs, &tmax) };
            let single: Vec<LocalRay> = (0..dirs.len())
                .map(|l| bvh.local_ray(origin, dirs[l], tmax[l]))
                .collect();
            for n in &bvh.tree.nodes {
                // SAFETY: as above.
                let relative = unsafe { packet.relative_planes(n) };
                // SAFETY: as above.
                let touched = unsafe { packet.children_touched(&relative) };
                let alone: Vec<u32> = single
                    .iter()
                    .map(|r| n.intersect(&r.boxes, r.tmax).1)
                    .collect();
                for j in 0..WIDTH {
                    // SAFETY: as above.
                    let lanes = unsafe { packet.box_hits(&relative, j, packet.all) };
                    for (l, a) in alone.iter().enumerate() {
                        assert_eq!(
                            u32::from(lanes >> l & 1),
                            a >> j & 1,
                            "packet {k}, lane {l}, child {j}"
                        );
                    }
                    if lanes != 0 {
                        assert!(touched >> j & 1 != 0, "packet {k}: child {j} culled");
                        kept += 1;
                    } else if touched >> j & 1 == 0 {
                        culled += 1;
                    }
                }
            }
        }
        assert!(
            kept > 1000 && culled > 10_000,
            "kept {kept}, culled {culled}"
        );
    }

    /// Packets answer as single rays, bit for bit: a random soup and a grid of
    /// axis-aligned quads (rays in their planes and through shared edges), packets of 1 to
    /// 16 rays in narrow and wide cones, axis-aligned directions, finite and infinite
    /// `tmax`, consecutive packets sharing a hint. Counters count every ray.
    #[test]
    fn packets_answer_as_single_rays() {
        use crate::sampling::rng::{hash4, to_unit_f32};
        let unit = |a: u64, b: u64| to_unit_f32(hash4(a, b, 0, 9));
        let mut soup = Mesh::new();
        let mut v = Vec::new();
        for k in 0..600u64 {
            let c = vec3a(unit(1, k), unit(2, k), unit(3, k)) * 4.0;
            for j in 0..3u64 {
                let e = vec3a(unit(4, 3 * k + j), unit(5, 3 * k + j), unit(6, 3 * k + j));
                v.push((c + (e - 0.5) * 0.6).to_array());
            }
        }
        let faces: Vec<[i64; 3]> = (0..600).map(|k| [3 * k, 3 * k + 1, 3 * k + 2]).collect();
        soup.add_indexed(&v, &faces, Material::DEFAULT, None)
            .unwrap();
        let mut grid = Mesh::new();
        for (i, j) in (0..4).flat_map(|i| (0..4).map(move |j| (i, j))) {
            let (x, y) = (i as f32, j as f32);
            let quad = [
                [x, y, 1.0],
                [x + 1.0, y, 1.0],
                [x + 1.0, y + 1.0, 1.0],
                [x, y + 1.0, 1.0],
            ];
            grid.add_indexed(&quad, &[[0, 1, 2], [0, 2, 3]], Material::DEFAULT, None)
                .unwrap();
        }
        // Each triangle of the soup a group of its own: a tree too deep for the fixed stack.
        let groups: Vec<_> = (0..600).map(|i| i..i + 1).collect();
        let deep = Bvh::build_grouped(&soup, BuildQuality::Sah, &groups);
        assert!(!deep.stack_is_bounded(), "depth {}", deep.depth());
        let mut tested = 0;
        for (bvh, centre) in [
            (
                Bvh::build(&soup, BuildQuality::Medium),
                vec3a(2.0, 2.0, 2.0),
            ),
            (deep, vec3a(2.0, 2.0, 2.0)),
            (
                Bvh::build(&grid, BuildQuality::Medium),
                vec3a(2.0, 2.0, 0.0),
            ),
        ] {
            for k in 0..400u64 {
                let origin = centre + (vec3a(unit(7, k), unit(8, k), unit(9, k)) - 0.5) * 3.0;
                let origin = if k % 5 == 0 { origin.round() } else { origin };
                let axis = vec3a(unit(10, k), unit(11, k), unit(12, k)) - 0.5;
                let spread = [0.05, 0.5, 3.0][k as usize % 3];
                let mut hint = OccluderHint::NONE;
                for p in 0..3u64 {
                    let count = 1 + ((k + p) % PACKET as u64) as usize;
                    let dirs: Vec<Vec3A> = (0..count as u64)
                        .map(|l| {
                            let s = 64 * k + 16 * p + l;
                            let d = axis
                                + (vec3a(unit(13, s), unit(14, s), unit(15, s)) - 0.5) * spread;
                            match s % 7 {
                                0 => vec3a(0.0, 0.0, d.z.signum()),
                                1 => vec3a(d.x, d.y, 0.0),
                                _ => d,
                            }
                        })
                        .filter(|d| d.length() > 0.0)
                        .collect();
                    let tmax: Vec<f32> = (0..dirs.len() as u64)
                        .map(|l| [f32::INFINITY, 0.5, 2.0, 0.0][((k + l) % 4) as usize])
                        .collect();
                    let mut c = TraversalCounters::default();
                    let got = bvh.occluded_packet::<true>(origin, &dirs, &tmax, &mut hint, &mut c);
                    assert_eq!(c.rays, dirs.len() as u64);
                    let mut none = TraversalCounters::default();
                    for (l, (&d, &t)) in dirs.iter().zip(&tmax).enumerate() {
                        let alone = bvh.occluded::<false>(origin, d, t, &mut none);
                        assert_eq!(got >> l & 1 != 0, alone, "k {k} packet {p} ray {l}");
                        tested += alone as usize;
                    }
                    assert_eq!(got as u32 >> dirs.len(), 0);
                }
            }
        }
        assert!(tested > 1000, "{tested} occluded rays");
    }

    /// The portable traversals (for CPUs without AVX2) and every vector one this CPU can run
    /// give the same answers and the same counts, any-hit and closest-hit, on a random soup
    /// in a shallow tree (traversed with the fixed stack) and in one too deep for it (with
    /// the spilling stack): rays from inside and outside, axis-parallel and with zero
    /// components, finite `tmax`.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn vector_and_portable_traversals_agree() {
        use crate::sampling::rng::{hash4, to_unit_f32};
        use crate::simd::SimdLevel;
        let level = crate::simd::level();
        if level < SimdLevel::Avx2 {
            return;
        }
        let unit = |a: u64, b: u64| to_unit_f32(hash4(a, b, 0, 33));
        let mut soup = Mesh::new();
        let v: Vec<[f32; 3]> = (0..6000u64)
            .map(|i| {
                let c = (i / 3) as f32;
                [
                    unit(1, i) + c % 7.0,
                    unit(2, i) * 2.0,
                    unit(3, i) + c % 11.0,
                ]
            })
            .collect();
        let faces: Vec<[i64; 3]> = (0..2000).map(|k| [3 * k, 3 * k + 1, 3 * k + 2]).collect();
        soup.add_indexed(&v, &faces, Material::DEFAULT, None)
            .unwrap();
        let soup_rays = |k: u64| {
            let o = vec3a(
                unit(4, k) * 10.0 - 1.5,
                unit(5, k) * 4.0 - 1.0,
                unit(6, k) * 13.0 - 1.0,
            );
            let mut d = vec3a(unit(7, k), unit(8, k), unit(9, k)) - 0.5;
            match k % 5 {
                0 => d.y = 0.0,
                1 => d = vec3a(0.0, 0.0, -1.0),
                _ => {}
            }
            (o, d, [f32::INFINITY, 1.0, 4.0][k as usize % 3])
        };
        // The soup's first 400 triangles each as a group of its own: the groups' subtrees
        // are joined one above the other, a chain far deeper than any SAH tree.
        let groups: Vec<_> = (0..400).map(|i| i..i + 1).collect();
        for (name, groups, bounded) in [("soup", &groups[..0], true), ("deep", &groups[..], false)]
        {
            let bvh = Bvh::build_grouped(&soup, BuildQuality::Sah, groups);
            assert_eq!(
                bvh.stack_is_bounded(),
                bounded,
                "{name}: depth {}",
                bvh.depth()
            );
            let (mut occluded, mut hit, mut missed) = (0, 0, 0);
            for k in 0..4000u64 {
                let (o, d, tmax) = soup_rays(k);
                if d.length() == 0.0 {
                    continue;
                }
                let mut c = TraversalCounters::default();
                let mut hint = OccluderHint::NONE;
                let portable = bvh.hinted_portable::<true>(o, d, tmax, &mut hint, &mut c);
                let mut ch = TraversalCounters::default();
                let r = bvh.local_ray(o, d, tmax);
                let closest =
                    bvh.closest_hit::<true, Stack<_, STACK>>(&r, &mut ch, PortableBoxTest);
                let bits = |h: Option<Hit>| {
                    h.map(|h| (h.t.to_bits(), h.triangle, h.u.to_bits(), h.v.to_bits()))
                };
                for simd in [SimdLevel::Avx2, SimdLevel::Avx512] {
                    if simd > level {
                        continue;
                    }
                    let (mut c2, mut ch2) =
                        (TraversalCounters::default(), TraversalCounters::default());
                    let mut hint2 = OccluderHint::NONE;
                    // SAFETY: the CPU has `simd`.
                    let (vector, vector_closest) = unsafe {
                        match simd {
                            SimdLevel::Avx2 => (
                                bvh.hinted_avx2::<true>(o, d, tmax, &mut hint2, &mut c2),
                                bvh.closest_hit_avx2::<true>(o, d, tmax, &mut ch2),
                            ),
                            _ => (
                                bvh.hinted_avx512::<true>(o, d, tmax, &mut hint2, &mut c2),
                                bvh.closest_hit_avx512::<true>(o, d, tmax, &mut ch2),
                            ),
                        }
                    };
                    assert_eq!(
                        (portable, hint, c),
                        (vector, hint2, c2),
                        "{name} {simd:?} ray {k}"
                    );
                    assert_eq!(
                        (bits(closest), ch),
                        (bits(vector_closest), ch2),
                        "{name} {simd:?} ray {k}"
                    );
                }
                occluded += portable as u32;
                hit += closest.is_some() as u32;
                missed += closest.is_none() as u32;
            }
            assert!(
                occluded > 500 && hit > 500 && missed > 500,
                "{name}: {occluded} occluded, {hit} hit, {missed} missed"
            );
        }
    }

    #[test]
    fn scale_invariant_answers() {
        for scale in [1e-4f32, 1.0, 1e4] {
            let bvh = Bvh::build(&quad_mesh(scale), BuildQuality::Fast);
            let mut c = TraversalCounters::default();
            // Direction of arbitrary length: t stays in its units.
            let o = vec3a(0.5, 0.25, 2.0) * scale;
            let h = bvh.intersect::<true>(o, vec3a(0.0, 0.0, -4.0), f32::INFINITY, &mut c);
            let h = h.unwrap();
            assert!((h.t - 0.5 * scale).abs() <= 1e-6 * scale, "{scale}: {h:?}");
            assert!(bvh.occluded::<true>(o, vec3a(0.0, 0.0, -1.0), 2.001 * scale, &mut c));
            assert!(!bvh.occluded::<true>(o, vec3a(0.0, 0.0, -1.0), 1.999 * scale, &mut c));
            assert!(c.nodes >= 3 && c.triangles >= 3, "{c:?}");
        }
    }

    #[test]
    fn refit_keeps_exact_boxes_and_detects_degeneracy_changes() {
        let mut m = quad_mesh(1.0);
        let v = [
            [0.0, 0.0, 1.0],
            [1.0, 0.0, 1.0],
            [0.0, 1.0, 1.0],
            [5.0, 5.0, 5.0],
        ];
        m.add_indexed(&v, &[[0, 1, 2], [3, 3, 3]], Material::DEFAULT, None)
            .unwrap();
        let built = Bvh::build(&m, BuildQuality::Medium);
        let mut refit = built.clone();
        // Unmoved: every box and triangle block comes out as the build made it.
        assert!(refit.refit(&m, 0..4));
        assert_eq!(
            format!("{:?}", refit.tree.nodes),
            format!("{:?}", built.tree.nodes)
        );
        assert_eq!(format!("{:?}", refit.blocks), format!("{:?}", built.blocks));
        // Moved: the boxes follow.
        let mut moved = m.clone();
        for t in &mut moved.triangles[2..3] {
            *t = t.map(|v| v + Vec3::new(0.0, 0.0, 2.0));
        }
        assert!(refit.refit(&moved, 2..4));
        let mut c = TraversalCounters::default();
        let o = vec3a(0.25, 0.25, 10.0);
        let d = vec3a(0.0, 0.0, -1.0);
        let h = refit
            .intersect::<true>(o, d, f32::INFINITY, &mut c)
            .unwrap();
        assert_eq!((h.triangle, h.t), (2, 7.0));
        // A triangle that becomes degenerate, or stops being so, needs a rebuild.
        let mut flat = m.clone();
        flat.triangles[2][2] = flat.triangles[2][1];
        assert!(!built.clone().refit(&flat, 2..3));
        let mut grown = m.clone();
        grown.triangles[3] = [Vec3::ZERO, Vec3::X, Vec3::Y];
        assert!(!built.clone().refit(&grown, 3..4));
        assert!(built.clone().refit(&grown, 0..2), "unchanged part");
        assert!(
            !built.clone().refit(&quad_mesh(1.0), 0..2),
            "other triangle count"
        );
        // Out of the f32 range in the local frame.
        let mut far = quad_mesh(1e-3);
        far.triangles[0][0] = Vec3::splat(3e38);
        let small = Bvh::build(&quad_mesh(1e-3), BuildQuality::Fast);
        assert!(!small.clone().refit(&far, 0..1));
    }

    #[test]
    fn grouped_builds_answer_as_whole_ones() {
        // A ground quad, a small soup, a one-triangle group, a group of degenerate
        // triangles only and an empty group.
        let mut m = quad_mesh(4.0);
        let mut tris = Vec::new();
        for i in 0..40 {
            let c = Vec3::new(
                (i % 7) as f32 * 0.5,
                0.2 + (i % 3) as f32 * 0.3,
                (i / 7) as f32 * 0.6,
            );
            tris.push([
                c,
                c + Vec3::new(0.3, 0.1, 0.0),
                c + Vec3::new(0.0, 0.2, 0.3),
            ]);
        }
        m.add_triangles(tris, Material::DEFAULT, None).unwrap();
        m.add_triangles([[Vec3::Z, Vec3::ONE, Vec3::Y]], Material::DEFAULT, None)
            .unwrap();
        m.add_triangles([[Vec3::X; 3], [Vec3::Y; 3]], Material::DEFAULT, None)
            .unwrap();
        let whole = Bvh::build(&m, BuildQuality::Medium);
        for groups in [
            vec![2usize..42; 1],
            vec![2..42, 42..43, 43..45, 45..45],
            vec![0usize..45; 1],
        ] {
            let grouped = Bvh::build_grouped(&m, BuildQuality::Medium, &groups);
            assert_eq!(grouped.triangle_ids.iter().max(), Some(&42), "{groups:?}");
            let mut c = TraversalCounters::default();
            for i in 0..2000u32 {
                let r = crate::sampling::rng::SampleRng::new(5, i as u64, 0);
                let o = Vec3A::new(r.get(0) * 4.0, r.get(1) * 2.0 - 0.5, r.get(2) * 4.0);
                let [u, v] = r.get2(3);
                let d = Vec3A::from(crate::scenes::shapes::sphere_dir(u, v));
                let (a, b) = (
                    whole.intersect::<true>(o, d, f32::INFINITY, &mut c),
                    grouped.intersect::<true>(o, d, f32::INFINITY, &mut c),
                );
                assert_eq!(
                    a.map(|h| (h.t, h.triangle)),
                    b.map(|h| (h.t, h.triangle)),
                    "{i}"
                );
                assert_eq!(
                    whole.occluded::<true>(o, d, 1.0, &mut c),
                    grouped.occluded::<true>(o, d, 1.0, &mut c)
                );
            }
        }
    }
}
