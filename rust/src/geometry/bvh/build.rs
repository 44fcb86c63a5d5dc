//! Building the tree: presets, the choice between the binned SAH and a PLOC tree by
//! measured work, builds with moving objects in subtrees of their own, and refits.

use std::time::{Duration, Instant};

use glam::{Vec3, Vec3A};
use obvhs::aabb::Aabb;
use obvhs::bvh2::builder::build_bvh2_from_tris;
use obvhs::bvh2::node::Bvh2Node;
use obvhs::bvh2::Bvh2;
use obvhs::triangle::Triangle;
use obvhs::BvhBuildParams;

use super::{Bvh, TraversalCounters};
use crate::error::{Error, Result};
use crate::geometry::bvh::binned_sah::{self, BinnedSahParams};
use crate::geometry::bvh::bvh8::Bvh8;
use crate::geometry::bvh::watertight::Triangle4;
use crate::geometry::huge_pages::advise_huge_pages;
use crate::geometry::mesh::Mesh;
use crate::math::triangle_cross;

/// Build presets: our binned SAH builder ([`BuildQuality::Sah`]), one of obvhs's PLOC
/// presets ([`BvhBuildParams`], leaves capped at [`MAX_LEAF`] triangles), or the choice
/// between the two by measured cost ([`BuildQuality::Auto`], the default).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum BuildQuality {
    /// The default: builds the [`BuildQuality::Sah`] tree, the [`AUTO_ALTERNATIVE`] tree
    /// and, for a mesh of several objects none of which holds nearly all triangles, the SAH
    /// tree with each object in a subtree of its own ([`AutoCosts::objects_apart`]), and
    /// keeps the one that does least work on [`AUTO_PROBE_RAYS`] sample shadow rays
    /// (another than the plain SAH tree only when it saves more than [`AUTO_MARGIN`]:
    /// [`AutoCosts::chosen`]); meshes of more than
    /// [`AUTO_MAX_TRIANGLES`] get the SAH tree alone. No tree wins on every scene: the
    /// binned SAH on most built-ins, PLOC (with its spatial pre-splits) on mixed scales,
    /// the objects apart where rays leave a ground or a wall past objects standing on it
    /// (`meshes`, `cornell`, `scales`: a top-down split over all triangles mixes the ground
    /// under an object with the object, benches/README.md). The SAH cost of the trees
    /// ([`Bvh::sah_cost`]) did not tell them apart on the benchmark suite (equal on
    /// `meshes`, where PLOC traces faster); the traversal work of sample rays does.
    #[default]
    Auto,
    /// Top-down binned SAH whose cost counts four-triangle blocks, slivers halved by early
    /// split clipping first ([`crate::geometry::bvh::binned_sah`]). Fewer node visits and block
    /// tests per ray than any PLOC preset below on the built-in scenes, at about the build
    /// time of `Medium` (benches/README.md).
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

/// Probe work per ray (node visits plus block tests, [`Bvh::probe_work`]) of the trees
/// [`BuildQuality::Auto`] compared.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AutoCosts {
    /// The binned SAH tree.
    pub sah: f64,
    /// The [`AUTO_ALTERNATIVE`] (PLOC) tree.
    pub alternative: f64,
    /// The binned SAH tree with each object in a subtree of its own, joined by the SAH
    /// over the objects' boxes; None for a mesh of fewer than two non-empty objects or one
    /// whose largest object holds more than [`AUTO_APART_LARGEST`] of its triangles.
    pub objects_apart: Option<f64>,
}

/// The tree [`AutoCosts::chosen`] keeps.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AutoChoice {
    Sah,
    Alternative,
    ObjectsApart,
}

impl AutoCosts {
    /// The plain SAH tree, unless another's work is less by more than [`AUTO_MARGIN`]:
    /// then the one of least work (the PLOC tree on a tie).
    pub fn chosen(&self) -> AutoChoice {
        let (other, work) = match self.objects_apart {
            Some(apart) if apart < self.alternative => (AutoChoice::ObjectsApart, apart),
            _ => (AutoChoice::Alternative, self.alternative),
        };
        if self.sah > AUTO_MARGIN * work {
            other
        } else {
            AutoChoice::Sah
        }
    }
}

/// [`BuildQuality::Auto`] builds the tree with the objects apart only where no object
/// holds more than this share of the triangles: otherwise that tree is the largest
/// object's SAH tree beside a few small ones, which a top-down split of the whole finds as
/// well or better (strands, whose reeds hold nearly all its triangles, traced 0.76-0.87x
/// as fast apart), and the build would cost a third tree for nothing.
pub const AUTO_APART_LARGEST: f64 = 0.9;

/// Shadow rays [`BuildQuality::Auto`] traces in both trees to compare them.
pub const AUTO_PROBE_RAYS: usize = 4096;

/// [`BuildQuality::Auto`] keeps the PLOC tree only when the SAH tree's probe work is more
/// than this many times its own: where the two are within 5%, the probe's node and block
/// counts do not predict which traces faster (`blob`, `instances`, `panels` on the suite).
pub const AUTO_MARGIN: f64 = 1.05;

/// Meshes larger than this get the SAH tree without a comparison: the PLOC preset builds
/// several times slower, beyond the budget of a second for a million triangles.
pub const AUTO_MAX_TRIANGLES: usize = 1 << 18;

/// Cost of visiting an eight-wide node relative to one four-triangle block test, in
/// [`Bvh::sah_cost`]: both are one SIMD test of similar latency.
pub const NODE_COST: f32 = 1.0;

/// Largest leaf the builder makes: one four-lane block of [`Triangle4`].
pub const MAX_LEAF: u32 = crate::geometry::bvh::bvh8::MAX_LEAF_TRIANGLES;

/// Leaf blocks holding triangles `range`, and which of those triangles the tree holds.
#[derive(Clone, Debug)]
pub(super) struct RefitBlocks {
    range: std::ops::Range<usize>,
    blocks: Vec<u32>,
    in_tree: Vec<bool>,
}

/// How a built BVH follows geometry that moved (see [`crate::geometry::Scene::set_object_transform`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum BvhUpdate {
    /// Keep the tree's topology and recompute the boxes above the moved triangles: much
    /// faster than a rebuild (benches/README.md). With the object
    /// in a subtree of its own (as the scene builds moved objects) the refit tree traces
    /// as fast as a rebuilt one (benches/README.md).
    #[default]
    Refit,
    /// Drop the tree; it is rebuilt with the scene's preset on the next query.
    Rebuild,
}

/// The power of two that brings `extent` into [256, 512).
pub(super) fn local_scale(extent: f32) -> f32 {
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

/// One tree over `trees` (each non-empty), their roots joined top-down: each set is split
/// in two where the surface area heuristic over the subtrees' boxes is least (subtrees
/// sorted by the centre of their box along the axis where the centres spread most,
/// weighted by their triangles), so that many subtrees make a balanced top rather than a
/// chain. None for no trees. A fixed function of the trees and their order.
fn join_by_sah(mut trees: Vec<Bvh2>) -> Option<Bvh2> {
    if trees.len() <= 1 {
        return trees.pop();
    }
    let boxes: Vec<Aabb> = trees.iter().map(|t| *t.nodes[0].aabb()).collect();
    let weights: Vec<f32> = trees
        .iter()
        .map(|t| t.primitive_indices.len() as f32)
        .collect();
    let centres = Aabb::from_points(&boxes.iter().map(|b| b.center()).collect::<Vec<_>>());
    let axis = centres.diagonal().max_position();
    let mut order: Vec<usize> = (0..trees.len()).collect();
    order.sort_by(|&a, &b| {
        let key = |i: usize| boxes[i].center()[axis];
        key(a).total_cmp(&key(b)).then(a.cmp(&b))
    });
    // Cost of the split before position `k` of `order`: area times weight on either side.
    let sweep = |indices: &mut dyn Iterator<Item = &usize>| {
        let (mut bounds, mut weight) = (Aabb::INVALID, 0.0f32);
        indices
            .map(|&i| {
                bounds = bounds.union(&boxes[i]);
                weight += weights[i];
                bounds.half_area() * weight
            })
            .collect::<Vec<f32>>()
    };
    let left = sweep(&mut order.iter());
    let mut right = sweep(&mut order.iter().rev());
    right.reverse();
    let split = (1..order.len())
        .min_by(|&a, &b| {
            let cost = |k: usize| left[k - 1] + right[k];
            cost(a).total_cmp(&cost(b))
        })
        .unwrap_or(1);
    let mut slots: Vec<Option<Bvh2>> = trees.drain(..).map(Some).collect();
    let mut take = |range: &[usize]| range.iter().filter_map(|&i| slots[i].take()).collect();
    let (low, high) = (take(&order[..split]), take(&order[split..]));
    Some(join_bvh2(join_by_sah(low)?, join_by_sah(high)?))
}

/// The groups of the tree [`BuildQuality::Auto`] builds with the objects apart: each
/// non-empty object's triangles (which takes in any moving ones), where there are two or
/// more and none holds more than [`AUTO_APART_LARGEST`] of the mesh's triangles.
fn objects_apart_groups(mesh: &Mesh) -> Option<Vec<std::ops::Range<usize>>> {
    let objects: Vec<_> = mesh
        .objects
        .iter()
        .map(|o| o.triangle_range())
        .filter(|r| !r.is_empty())
        .collect();
    let largest = objects.iter().map(|r| r.len()).max().unwrap_or(0);
    let share = largest as f64 / mesh.triangles.len() as f64;
    (objects.len() >= 2 && share <= AUTO_APART_LARGEST).then_some(objects)
}

/// `n` shadow rays like a renderer's: origins uniform by area over `mesh`'s triangles, on
/// the side facing up (+y, the scenes' up axis: the side a camera and the sky mostly see;
/// vertical triangles on their winding side), lifted off the surface by a millionth of the
/// scene's size, directions uniform over that side's hemisphere. A fixed function of the
/// mesh. Of the samplings tried on the suite (by area or by triangle, either side or the
/// upper one), this one's work ratios came closest to the measured speed ratios.
pub(super) fn probe_rays(mesh: &Mesh, n: usize) -> Vec<(Vec3A, Vec3A)> {
    use crate::math::{to_world, uniform_hemisphere};
    use crate::sampling::rng::SampleRng;
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
        Self::build_joined(mesh, quality, groups, join_by_sah)
    }

    /// [`Bvh::build_grouped`] with the subtrees joined in a chain, one above the other: a
    /// tree deeper than the fixed traversal stack serves, for tests of the spilling one.
    #[cfg(test)]
    pub(super) fn build_chained(
        mesh: &Mesh,
        quality: BuildQuality,
        groups: &[std::ops::Range<usize>],
    ) -> Self {
        Self::build_joined(mesh, quality, groups, |trees| {
            trees.into_iter().reduce(join_bvh2)
        })
    }

    /// [`Bvh::build_grouped`] whose subtrees `join` puts under one root.
    fn build_joined(
        mesh: &Mesh,
        quality: BuildQuality,
        groups: &[std::ops::Range<usize>],
        join: fn(Vec<Bvh2>) -> Option<Bvh2>,
    ) -> Self {
        let start = Instant::now();
        if quality == BuildQuality::Auto {
            let mut kept = if mesh.triangles.len() > AUTO_MAX_TRIANGLES {
                Self::build_grouped(mesh, BuildQuality::Sah, groups)
            } else {
                let objects = objects_apart_groups(mesh);
                let sah_over =
                    |g: &[std::ops::Range<usize>]| Self::build_grouped(mesh, BuildQuality::Sah, g);
                let (sah, (alternative, apart)) = rayon::join(
                    || sah_over(groups),
                    || {
                        rayon::join(
                            || Self::build_grouped(mesh, AUTO_ALTERNATIVE, groups),
                            || objects.as_deref().map(sah_over),
                        )
                    },
                );
                let rays = probe_rays(mesh, AUTO_PROBE_RAYS);
                let costs = AutoCosts {
                    sah: sah.probe_work(&rays),
                    alternative: alternative.probe_work(&rays),
                    objects_apart: apart.as_ref().map(|t| t.probe_work(&rays)),
                };
                let mut kept = match (costs.chosen(), apart) {
                    (AutoChoice::Sah, _) => sah,
                    (AutoChoice::Alternative, _) => alternative,
                    (AutoChoice::ObjectsApart, Some(apart)) => apart,
                    (AutoChoice::ObjectsApart, None) => unreachable!("chosen only when built"),
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
        let mut grouped = vec![false; mesh.triangles.len()];
        for g in groups {
            grouped[g.clone()].fill(true);
        }
        let mut kept: Vec<u32> = (0..mesh.triangles.len() as u32)
            .filter(|&i| !grouped[i as usize])
            .filter(non_degenerate)
            .collect();
        let mut spans = Vec::with_capacity(groups.len() + 1);
        spans.push(0..kept.len());
        for g in groups {
            let first = kept.len();
            kept.extend((g.start as u32..g.end as u32).filter(non_degenerate));
            spans.push(first..kept.len());
        }
        let mut bounds = crate::geometry::mesh::Bounds::EMPTY;
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
        let subtrees = spans
            .into_iter()
            .filter(|span| !span.is_empty())
            .map(|span| {
                let mut bvh2 = quality.build_bvh2(&local[span.clone()]);
                bvh2.primitive_indices
                    .iter_mut()
                    .for_each(|p| *p += span.start as u32);
                bvh2
            })
            .collect();
        let tree = join(subtrees).map_or_else(Bvh8::default, |bvh2| Bvh8::from_bvh2(&bvh2));
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

    /// Node visits plus block tests per ray of `rays` (origin, direction; unbounded).
    pub(super) fn probe_work(&self, rays: &[(Vec3A, Vec3A)]) -> f64 {
        let mut c = TraversalCounters::default();
        for &(o, d) in rays {
            self.occluded::<true>(o, d, f32::INFINITY, &mut c);
        }
        (c.nodes as f64 + c.triangles as f64 / 4.0) / rays.len().max(1) as f64
    }
}
