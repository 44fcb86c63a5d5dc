//! Top-down binned SAH builder (Wald, "On fast Construction of SAH-based Bounding Volume
//! Hierarchies", IRT 2007), with a cost model that knows a leaf is tested as one four-lane
//! triangle block ([`super::watertight::Triangle4`]) whether it holds one triangle or four.
//!
//! Why our own and not obvhs's PLOC: PLOC clusters bottom-up and then collapses subtrees
//! into leaves, so it groups triangles into blocks by proximity rather than by cost. Our
//! traversal tests a whole block at once and eight child boxes at once; what it pays for is
//! the number of blocks and nodes a ray reaches, which is exactly what this builder's cost
//! counts. On the built-in scenes it gives trees that trace shadow rays faster than obvhs's
//! `medium` preset at a similar build time (benches/README.md).
//!
//! The output is an obvhs [`Bvh2`] (binary, leaves of at most [`MAX_LEAF`] triangles), which
//! [`super::bvh8::Bvh8::from_bvh2`] collapses into the eight-wide tree as for PLOC trees.
//! The tree depends only on the triangles: subtrees are built in parallel, but every split
//! and partition is computed the same way whatever the thread count.

use glam::Vec3A;
use obvhs::aabb::Aabb;
use obvhs::bvh2::node::Bvh2Node;
use obvhs::bvh2::Bvh2;
use obvhs::triangle::Triangle;
use rayon::prelude::*;

/// Largest number of triangles in a leaf: one four-lane block.
pub const MAX_LEAF: usize = 4;

/// The default [`BinnedSahParams::sliver_gain`]. Measured on the benchmark suite
/// (`benches/peer_embree.py`, 2 threads): strands' reeds traced 1.28x faster on incoherent
/// shadow rays, 1.15x on record bundles and 1.29x on camera rays, garden 1.07x, 1.01x and
/// 1.09x, instances 1.08x, the other scenes within noise. At 1.5 garden's tree grew
/// from 23 to 44 MB (38 MB here) and blob traced 3-5% slower; at 1.8 garden lost what it
/// gained (benches/README.md).
pub const SLIVER_GAIN: f32 = 1.67;

/// Parameters of the binned SAH builder. Costs are relative to one triangle-block test.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BinnedSahParams {
    /// Centroid bins per axis (2..=64).
    pub bins: usize,
    /// Cost of visiting a binary node, relative to one block test. Embree uses 1.
    pub traversal_cost: f32,
    /// Ranges larger than this are split and built in parallel (rayon tasks).
    pub parallel_threshold: usize,
    /// Slivers halved before the build ([`halve_slivers`]): a triangle whose box's area is
    /// at least this many times the sum of its two halves' areas enters the build as two
    /// references. 0 halves none.
    pub sliver_gain: f32,
}

impl BinnedSahParams {
    /// 16 bins, traversal cost 1 (as Embree's builders), tasks above 4096 triangles,
    /// slivers halved at a gain of [`SLIVER_GAIN`].
    ///
    /// 16 bins rather than the usual 32: on garden's grass they give trees with a quarter
    /// fewer triangle tests per shadow ray (21 against 28; 8 and 12 bins give 19 but cost
    /// garage a third more node visits), and the other built-in scenes trace the same.
    pub const fn default_build() -> Self {
        Self {
            bins: 16,
            traversal_cost: 1.0,
            parallel_threshold: 4096,
            sliver_gain: SLIVER_GAIN,
        }
    }
}

impl Default for BinnedSahParams {
    fn default() -> Self {
        Self::default_build()
    }
}

/// A triangle's box and index, 32 bytes, partitioned in place as the tree is built.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(32))]
struct PrimRef {
    lo: [f32; 3],
    id: u32,
    hi: [f32; 3],
    _pad: u32,
}

impl PrimRef {
    #[inline(always)]
    fn lo(&self) -> Vec3A {
        Vec3A::from_array(self.lo)
    }

    #[inline(always)]
    fn hi(&self) -> Vec3A {
        Vec3A::from_array(self.hi)
    }

    /// Twice the box centre (saves a multiply; only compared and binned).
    #[inline(always)]
    fn centroid2(&self) -> Vec3A {
        self.lo() + self.hi()
    }
}

/// Box of a range and box of its (doubled) centroids.
#[derive(Clone, Copy, Debug)]
struct RangeBounds {
    boxes: Aabb,
    centroids: Aabb,
}

impl RangeBounds {
    const EMPTY: Self = Self {
        boxes: Aabb::INVALID,
        centroids: Aabb::INVALID,
    };

    fn of(refs: &[PrimRef]) -> Self {
        refs.iter().fold(Self::EMPTY, |mut b, r| {
            b.boxes.min = b.boxes.min.min(r.lo());
            b.boxes.max = b.boxes.max.max(r.hi());
            b.centroids.extend(r.centroid2());
            b
        })
    }

    fn union(self, o: Self) -> Self {
        Self {
            boxes: self.boxes.union(&o.boxes),
            centroids: self.centroids.union(&o.centroids),
        }
    }
}

/// Number of blocks (leaf tests) `n` triangles take.
#[inline(always)]
fn blocks(n: usize) -> f32 {
    n.div_ceil(MAX_LEAF) as f32
}

/// Maps a doubled centroid to its bin on each axis.
#[derive(Clone, Copy, Debug)]
struct Binning {
    origin: Vec3A,
    scale: Vec3A,
    bins: usize,
}

impl Binning {
    fn new(centroids: &Aabb, bins: usize) -> Self {
        let extent = centroids.max - centroids.min;
        // Slightly under `bins / extent`, so that the largest centroid falls in the last bin.
        let scale = Vec3A::select(
            extent.cmpgt(Vec3A::ZERO),
            Vec3A::splat(bins as f32 * (1.0 - 1e-5)) / extent,
            Vec3A::ZERO,
        );
        Self {
            origin: centroids.min,
            scale,
            bins,
        }
    }

    #[inline(always)]
    fn bin(&self, c: Vec3A) -> [usize; 3] {
        let b = ((c - self.origin) * self.scale).max(Vec3A::ZERO);
        let last = self.bins - 1;
        [
            (b.x as usize).min(last),
            (b.y as usize).min(last),
            (b.z as usize).min(last),
        ]
    }
}

/// Per-axis bins: the box and count of the triangles whose centroid falls in each.
#[derive(Clone, Debug)]
struct Bins {
    boxes: [Vec<Aabb>; 3],
    counts: [Vec<u32>; 3],
}

impl Bins {
    fn new(bins: usize) -> Self {
        Self {
            boxes: std::array::from_fn(|_| vec![Aabb::INVALID; bins]),
            counts: std::array::from_fn(|_| vec![0; bins]),
        }
    }

    fn fill(mut self, binning: &Binning, refs: &[PrimRef]) -> Self {
        for r in refs {
            let (lo, hi) = (r.lo(), r.hi());
            for (axis, b) in binning.bin(r.centroid2()).into_iter().enumerate() {
                let bx = &mut self.boxes[axis][b];
                bx.min = bx.min.min(lo);
                bx.max = bx.max.max(hi);
                self.counts[axis][b] += 1;
            }
        }
        self
    }

    fn merge(mut self, o: Self) -> Self {
        for axis in 0..3 {
            for (a, b) in self.boxes[axis].iter_mut().zip(&o.boxes[axis]) {
                *a = a.union(b);
            }
            for (a, b) in self.counts[axis].iter_mut().zip(&o.counts[axis]) {
                *a += b;
            }
        }
        self
    }
}

/// A split plane: triangles of bins below `bin` on `axis` go left. `cost` is the SAH of
/// the two sides, `Σ area · blocks`, without the parent's traversal term.
#[derive(Clone, Copy, Debug)]
struct Split {
    axis: usize,
    bin: usize,
    cost: f32,
}

/// Ranges at least this long bin on several rayon tasks.
const PARALLEL_BINNING: usize = 1 << 15;

/// Best SAH split of `refs` (None when every centroid falls in one bin on every axis).
fn best_split(refs: &[PrimRef], binning: &Binning) -> Option<Split> {
    let bins = binning.bins;
    let filled = if refs.len() >= PARALLEL_BINNING {
        refs.par_chunks(PARALLEL_BINNING / 4)
            .map(|chunk| Bins::new(bins).fill(binning, chunk))
            .reduce(|| Bins::new(bins), Bins::merge)
    } else {
        Bins::new(bins).fill(binning, refs)
    };
    let mut best: Option<Split> = None;
    let mut right_cost = vec![0.0f32; bins];
    for axis in 0..3 {
        let (boxes, counts) = (&filled.boxes[axis], &filled.counts[axis]);
        // Sweep from the right: cost of bins `b..` on the right side.
        let (mut bx, mut n) = (Aabb::INVALID, 0usize);
        for b in (1..bins).rev() {
            bx = bx.union(&boxes[b]);
            n += counts[b] as usize;
            right_cost[b] = if n == 0 {
                f32::INFINITY
            } else {
                bx.half_area() * blocks(n)
            };
        }
        let (mut bx, mut n) = (Aabb::INVALID, 0usize);
        for b in 1..bins {
            bx = bx.union(&boxes[b - 1]);
            n += counts[b - 1] as usize;
            if n == 0 || n == refs.len() {
                continue;
            }
            let cost = bx.half_area() * blocks(n) + right_cost[b];
            if best.is_none_or(|s| cost < s.cost) {
                best = Some(Split { axis, bin: b, cost });
            }
        }
    }
    best
}

/// Moves the triangles going left to the front; returns how many there are.
fn partition(refs: &mut [PrimRef], binning: &Binning, split: Split) -> usize {
    let left = |r: &PrimRef| binning.bin(r.centroid2())[split.axis] < split.bin;
    let (mut i, mut j) = (0, refs.len());
    while i < j {
        if left(&refs[i]) {
            i += 1;
        } else {
            j -= 1;
            refs.swap(i, j);
        }
    }
    i
}

/// How a range is divided: `None` makes it a leaf.
fn divide(refs: &mut [PrimRef], bounds: &RangeBounds, params: &BinnedSahParams) -> Option<usize> {
    let n = refs.len();
    let binning = Binning::new(&bounds.centroids, params.bins);
    let split = best_split(refs, &binning);
    let leaf_cost = bounds.boxes.half_area() * blocks(n);
    match split {
        Some(s) => {
            let split_cost = params.traversal_cost * bounds.boxes.half_area() + s.cost;
            if n <= MAX_LEAF && split_cost >= leaf_cost {
                return None;
            }
            Some(partition(refs, &binning, s))
        }
        // Centroids that bins cannot separate: halve in order if too many for a leaf.
        None => (n > MAX_LEAF).then_some(n / 2),
    }
}

/// A subtree as built: either a flat list of nodes (root first, indices local) or a split
/// whose two sides were built as separate tasks.
enum Built {
    Flat(Vec<Bvh2Node>),
    Split(Aabb, Box<Built>, Box<Built>),
}

/// Builds `refs` (the triangles `first..first + refs.len()` of the final order) into
/// nodes without tasks, with an explicit stack (pathological splits can be deep).
fn build_flat(refs: &mut [PrimRef], first: u32, params: &BinnedSahParams) -> Vec<Bvh2Node> {
    let placeholder = Bvh2Node::new(Aabb::INVALID, 0, 0);
    let mut nodes = Vec::with_capacity(refs.len().div_ceil(2) * 2);
    nodes.push(placeholder);
    let mut work = vec![(0usize, 0usize, refs.len())];
    while let Some((slot, start, end)) = work.pop() {
        let range = &mut refs[start..end];
        let bounds = RangeBounds::of(range);
        match divide(range, &bounds, params) {
            None => {
                nodes[slot] =
                    Bvh2Node::new(bounds.boxes, (end - start) as u32, first + start as u32);
            }
            Some(mid) => {
                let child = nodes.len();
                nodes.extend([placeholder; 2]);
                nodes[slot] = Bvh2Node::new(bounds.boxes, 0, child as u32);
                work.push((child + 1, start + mid, end));
                work.push((child, start, start + mid));
            }
        }
    }
    nodes
}

/// Splits ranges larger than the parallel threshold and builds the two sides as rayon
/// tasks; smaller ranges (or deep recursion) go to [`build_flat`].
fn build_tasks(refs: &mut [PrimRef], first: u32, params: &BinnedSahParams, depth: u32) -> Built {
    if refs.len() <= params.parallel_threshold || depth >= 48 {
        return Built::Flat(build_flat(refs, first, params));
    }
    let bounds = if refs.len() >= PARALLEL_BINNING {
        refs.par_chunks(PARALLEL_BINNING / 4)
            .map(RangeBounds::of)
            .reduce(|| RangeBounds::EMPTY, RangeBounds::union)
    } else {
        RangeBounds::of(refs)
    };
    let Some(mid) = divide(refs, &bounds, params) else {
        return Built::Flat(build_flat(refs, first, params));
    };
    let (l, r) = refs.split_at_mut(mid);
    let (left, right) = rayon::join(
        || build_tasks(l, first, params, depth + 1),
        || build_tasks(r, first + mid as u32, params, depth + 1),
    );
    Built::Split(bounds.boxes, Box::new(left), Box::new(right))
}

/// Writes `built` into `out` with its root at `slot` (children of a node stay adjacent).
fn place(built: Built, slot: usize, out: &mut Vec<Bvh2Node>) {
    match built {
        Built::Split(aabb, left, right) => {
            let child = out.len();
            out.extend([Bvh2Node::new(Aabb::INVALID, 0, 0); 2]);
            out[slot] = Bvh2Node::new(aabb, 0, child as u32);
            place(*left, child, out);
            place(*right, child + 1, out);
        }
        Built::Flat(nodes) => {
            // Local index i >= 1 lands at base + i.
            let base = out.len() as u32 - 1;
            out[slot] = shifted(&nodes[0], base);
            out.extend(nodes[1..].iter().map(|n| shifted(n, base)));
        }
    }
}

/// `n` with its child index moved by `base` (leaves index triangles, which do not move).
fn shifted(n: &Bvh2Node, base: u32) -> Bvh2Node {
    let mut n = *n;
    if !n.is_leaf() {
        n.first_index += base;
    }
    n
}

/// Builds a binary BVH over `triangles` (non-degenerate, finite) on the current rayon
/// pool: leaves of at most [`MAX_LEAF`] triangles, `primitive_indices` mapping leaf slots
/// to input indices. Empty input gives an empty tree.
pub fn build_bvh2(triangles: &[Triangle], params: &BinnedSahParams) -> Bvh2 {
    assert!((2..=64).contains(&params.bins), "bins must be in 2..=64");
    if triangles.is_empty() {
        return Bvh2::default();
    }
    let mut refs: Vec<PrimRef> = triangles
        .par_iter()
        .enumerate()
        .map(|(i, t)| {
            let lo = t.v0.min(t.v1).min(t.v2);
            let hi = t.v0.max(t.v1).max(t.v2);
            PrimRef {
                lo: lo.to_array(),
                id: i as u32,
                hi: hi.to_array(),
                _pad: 0,
            }
        })
        .collect();
    if params.sliver_gain > 0.0 {
        refs = halve_slivers(triangles, refs, params.sliver_gain);
    }
    let built = build_tasks(&mut refs, 0, params, 0);
    let mut nodes = Vec::with_capacity(2 * triangles.len().div_ceil(2));
    nodes.push(Bvh2Node::new(Aabb::INVALID, 0, 0));
    place(built, 0, &mut nodes);
    Bvh2 {
        nodes,
        primitive_indices: refs.iter().map(|r| r.id).collect(),
        ..Bvh2::default()
    }
}

/// Early split clipping (Ernst and Greiner, "Early Split Clipping for Bounding Volume
/// Hierarchies", RT 2007), one halving deep: each triangle's box is cut across its longest
/// axis at the middle, the triangle is clipped to either half, and where the two clipped
/// boxes' surface areas sum to at most `1 / gain` of the box's, the triangle enters the
/// build as two references with those boxes (same `id`). A slanted sliver (a blade of
/// grass, a leaning reed) gains up to 2; a triangle lying in a coordinate plane at most
/// 4/3. The reference count at most doubles, so a leaf may test one triangle twice.
///
/// The clipped boxes are conservative: the cut axis takes the plane itself (exact), the
/// other axes the vertices on that side and the edges' crossings of the plane, each
/// crossing widened by its rounding bound and the box clamped to the triangle's, so every
/// point of the triangle lies in the box of a reference holding it.
fn halve_slivers(triangles: &[Triangle], refs: Vec<PrimRef>, gain: f32) -> Vec<PrimRef> {
    let halves: Vec<Option<[PrimRef; 2]>> = refs
        .par_iter()
        .map(|r| {
            let t = &triangles[r.id as usize];
            let halves = clipped_halves(t, r.lo(), r.hi())?;
            let area = |lo: Vec3A, hi: Vec3A| {
                let e = hi - lo;
                e.x * e.y + e.y * e.z + e.z * e.x
            };
            let whole = area(r.lo(), r.hi());
            let split = area(halves[0].0, halves[0].1) + area(halves[1].0, halves[1].1);
            (split * gain <= whole).then(|| {
                halves.map(|(lo, hi)| PrimRef {
                    lo: lo.to_array(),
                    id: r.id,
                    hi: hi.to_array(),
                    _pad: 0,
                })
            })
        })
        .collect();
    let mut out = Vec::with_capacity(refs.len() + halves.iter().flatten().count());
    for (r, h) in refs.into_iter().zip(halves) {
        match h {
            Some(pair) => out.extend(pair),
            None => out.push(r),
        }
    }
    out
}

/// The boxes of triangle `t` (box `lo..hi`) clipped to either half of its box cut at the
/// middle of its longest axis; None for a box flat on that axis.
fn clipped_halves(t: &Triangle, lo: Vec3A, hi: Vec3A) -> Option<[(Vec3A, Vec3A); 2]> {
    let extent = hi - lo;
    let axis = if extent.x >= extent.y && extent.x >= extent.z {
        0
    } else if extent.y >= extent.z {
        1
    } else {
        2
    };
    let (a, b) = (lo[axis], hi[axis]);
    let mid = 0.5 * (a + b);
    if !(a < mid && mid < b) {
        return None;
    }
    let v = [t.v0, t.v1, t.v2];
    let mut left = (Vec3A::INFINITY, Vec3A::NEG_INFINITY);
    let mut right = left;
    let grow = |bx: &mut (Vec3A, Vec3A), p: Vec3A, pad: Vec3A| {
        bx.0 = bx.0.min(p - pad);
        bx.1 = bx.1.max(p + pad);
    };
    for k in 0..3 {
        let (p, q) = (v[k], v[(k + 1) % 3]);
        if p[axis] <= mid {
            grow(&mut left, p, Vec3A::ZERO);
        }
        if p[axis] >= mid {
            grow(&mut right, p, Vec3A::ZERO);
        }
        if (p[axis] < mid) != (q[axis] < mid) && p[axis] != q[axis] {
            // The crossing `p + s (q - p)`: a few roundings of values below
            // `max(|p|, |q|)` each: 16 ulps of that bound cover them.
            let s = (mid - p[axis]) / (q[axis] - p[axis]);
            let mut x = p + (q - p) * s;
            x[axis] = mid;
            let mut pad = p.abs().max(q.abs()) * (16.0 * f32::EPSILON);
            pad[axis] = 0.0;
            grow(&mut left, x, pad);
            grow(&mut right, x, pad);
        }
    }
    let clamp = |(l, h): (Vec3A, Vec3A)| (l.max(lo), h.min(hi));
    let (mut left, mut right) = (clamp(left), clamp(right));
    left.1[axis] = mid;
    right.0[axis] = mid;
    Some([left, right])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::rng::SampleRng;

    fn soup(n: usize, seed: u64) -> Vec<Triangle> {
        (0..n as u64)
            .map(|i| {
                let rng = SampleRng::new(seed, i, 0);
                let c = Vec3A::new(rng.get(0), rng.get(1), rng.get(2)) * 100.0;
                let e = |d: u64| Vec3A::new(rng.get(d), rng.get(d + 1), rng.get(d + 2)) * 4.0 - 2.0;
                Triangle {
                    v0: c,
                    v1: c + e(3),
                    v2: c + e(6),
                }
            })
            .collect()
    }

    /// The default build without halved slivers: one reference per triangle.
    fn unsplit() -> BinnedSahParams {
        BinnedSahParams {
            sliver_gain: 0.0,
            ..BinnedSahParams::default()
        }
    }

    /// Every triangle in exactly one leaf, leaves of 1..=4, boxes that hold their children
    /// and triangles exactly (the union, not more), children adjacent.
    fn check_tree(bvh: &Bvh2, tris: &[Triangle]) {
        let mut seen = vec![0u32; tris.len()];
        let mut stack = vec![0usize];
        while let Some(i) = stack.pop() {
            let n = &bvh.nodes[i];
            let mut union = Aabb::INVALID;
            if n.is_leaf() {
                assert!((1..=MAX_LEAF as u32).contains(&n.prim_count));
                for k in n.first_index..n.first_index + n.prim_count {
                    let p = bvh.primitive_indices[k as usize] as usize;
                    seen[p] += 1;
                    let t = &tris[p];
                    for v in [t.v0, t.v1, t.v2] {
                        union.extend(v);
                    }
                }
            } else {
                let c = n.first_index as usize;
                for k in [c, c + 1] {
                    union = union.union(bvh.nodes[k].aabb());
                    stack.push(k);
                }
            }
            assert_eq!(
                (union.min, union.max),
                (n.aabb().min, n.aabb().max),
                "node {i}"
            );
        }
        assert!(seen.iter().all(|&s| s == 1), "every triangle in one leaf");
    }

    #[test]
    fn trees_are_complete_and_tight() {
        for n in [1, 2, 4, 5, 17, 1000, 20_000] {
            let tris = soup(n, n as u64);
            let bvh = build_bvh2(&tris, &unsplit());
            check_tree(&bvh, &tris);
        }
    }

    #[test]
    fn identical_centroids_and_empty_input() {
        // 40 copies of one triangle: no bin separates them, so ranges are halved.
        let t = soup(1, 3)[0];
        let tris = vec![t; 40];
        let bvh = build_bvh2(&tris, &unsplit());
        check_tree(&bvh, &tris);
        assert!(build_bvh2(&[], &BinnedSahParams::default())
            .nodes
            .is_empty());
    }

    #[test]
    fn same_tree_for_any_thread_count() {
        let tris = soup(60_000, 9);
        let on = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| build_bvh2(&tris, &BinnedSahParams::default()))
        };
        let (a, b) = (on(1), on(2));
        assert_eq!(a.primitive_indices, b.primitive_indices);
        let key = |t: &Bvh2| -> Vec<_> {
            t.nodes
                .iter()
                .map(|n| {
                    (
                        n.aabb().min.to_array(),
                        n.aabb().max.to_array(),
                        n.prim_count,
                        n.first_index,
                    )
                })
                .collect()
        };
        assert_eq!(key(&a), key(&b));
    }

    /// Leaves are grouped by cost: four triangles on each of two far-apart spots make two
    /// leaves of four, not leaves that mix the spots.
    #[test]
    fn blocks_group_neighbours() {
        let mut tris = soup(4, 1);
        for t in &mut tris {
            *t = Triangle {
                v0: t.v0 * 0.01,
                v1: t.v1 * 0.01,
                v2: t.v2 * 0.01,
            };
        }
        let far: Vec<Triangle> = tris
            .iter()
            .map(|t| Triangle {
                v0: t.v0 + 1000.0,
                v1: t.v1 + 1000.0,
                v2: t.v2 + 1000.0,
            })
            .collect();
        tris.extend(far);
        let bvh = build_bvh2(&tris, &unsplit());
        check_tree(&bvh, &tris);
        let leaves: Vec<_> = bvh.nodes.iter().filter(|n| n.is_leaf()).collect();
        assert_eq!(leaves.len(), 2);
        for l in leaves {
            let ids = &bvh.primitive_indices
                [l.first_index as usize..(l.first_index + l.prim_count) as usize];
            assert!(
                ids.iter().all(|&i| i < 4) || ids.iter().all(|&i| i >= 4),
                "{ids:?}"
            );
        }
    }

    /// Long thin triangles leaning across all three axes, as grass blades and reeds.
    fn slivers(n: usize, seed: u64) -> Vec<Triangle> {
        (0..n as u64)
            .map(|i| {
                let rng = SampleRng::new(seed, i, 0);
                let c = Vec3A::new(rng.get(0), rng.get(1), rng.get(2)) * 100.0;
                let along = Vec3A::new(rng.get(3), 2.0 + rng.get(4), rng.get(5)) * 3.0;
                let width = Vec3A::new(rng.get(6), 0.0, rng.get(7)) * 0.05;
                Triangle {
                    v0: c,
                    v1: c + width,
                    v2: c + along,
                }
            })
            .collect()
    }

    /// Points of `t`: its vertices, edge points and points inside.
    fn points_on(t: &Triangle, seed: u64) -> Vec<Vec3A> {
        let mut pts = vec![t.v0, t.v1, t.v2];
        for k in 0..64u64 {
            let rng = SampleRng::new(seed, k, 1);
            let (mut u, mut v) = (rng.get(0), rng.get(1));
            if u + v > 1.0 {
                (u, v) = (1.0 - u, 1.0 - v);
            }
            match k % 4 {
                0 => v = 0.0,
                1 => u = 0.0,
                2 => v = 1.0 - u,
                _ => {}
            }
            pts.push(t.v0 + (t.v1 - t.v0) * u + (t.v2 - t.v0) * v);
        }
        pts
    }

    /// The halves lie in the triangle's box, meet at the cut plane, shrink a sliver's box
    /// area by at least the gain, and together hold every point of the triangle
    /// (vertices, edges, inside).
    #[test]
    fn clipped_halves_hold_the_triangle() {
        let mut halved = 0;
        for (i, t) in slivers(500, 4).iter().chain(&soup(500, 5)).enumerate() {
            let (lo, hi) = (t.v0.min(t.v1).min(t.v2), t.v0.max(t.v1).max(t.v2));
            let [(llo, lhi), (rlo, rhi)] = clipped_halves(t, lo, hi).expect("not flat");
            for (a, b) in [(llo, lhi), (rlo, rhi)] {
                assert!(a.cmpge(lo).all() && b.cmple(hi).all() && a.cmple(b).all());
            }
            let inside = |p: Vec3A, a: Vec3A, b: Vec3A| p.cmpge(a).all() && p.cmple(b).all();
            for p in points_on(t, i as u64) {
                assert!(
                    inside(p, llo, lhi) || inside(p, rlo, rhi),
                    "triangle {i}: {p} outside both halves"
                );
            }
            let area = |a: Vec3A, b: Vec3A| {
                let e = b - a;
                e.x * e.y + e.y * e.z + e.z * e.x
            };
            if area(llo, lhi) + area(rlo, rhi) <= area(lo, hi) / SLIVER_GAIN {
                halved += 1;
            }
        }
        // Every leaning sliver gains; few of the soup's triangles do.
        assert!(halved >= 500, "{halved}");
        assert!(halved < 800, "{halved}");
    }

    /// With slivers halved, every triangle sits in one or two leaves (two only when it
    /// gains), every node's box holds its children's, and every point of a triangle lies
    /// in the box of a leaf holding it: a ray that hits the triangle reaches that leaf.
    #[test]
    fn halved_slivers_keep_every_triangle_reachable() {
        let mut tris = slivers(3000, 6);
        tris.extend(soup(1000, 7));
        let bvh = build_bvh2(&tris, &BinnedSahParams::default());
        let mut boxes: Vec<Vec<Aabb>> = vec![Vec::new(); tris.len()];
        let mut stack = vec![0usize];
        while let Some(i) = stack.pop() {
            let n = &bvh.nodes[i];
            if n.is_leaf() {
                assert!((1..=MAX_LEAF as u32).contains(&n.prim_count));
                for k in n.first_index..n.first_index + n.prim_count {
                    boxes[bvh.primitive_indices[k as usize] as usize].push(*n.aabb());
                }
            } else {
                let c = n.first_index as usize;
                for k in [c, c + 1] {
                    let b = bvh.nodes[k].aabb();
                    assert!(b.min.cmpge(n.aabb().min).all() && b.max.cmple(n.aabb().max).all());
                    stack.push(k);
                }
            }
        }
        let twice = boxes.iter().filter(|b| b.len() == 2).count();
        assert!(boxes.iter().all(|b| (1..=2).contains(&b.len())));
        assert!(twice >= 2500, "{twice} of 3000 slivers halved");
        for (i, t) in tris.iter().enumerate() {
            for p in points_on(t, i as u64) {
                assert!(
                    boxes[i]
                        .iter()
                        .any(|b| p.cmpge(b.min).all() && p.cmple(b.max).all()),
                    "triangle {i}: {p} in no leaf holding it"
                );
            }
        }
        // Without halving, the same triangles take one reference each.
        let whole = build_bvh2(&tris, &unsplit());
        assert_eq!(whole.primitive_indices.len(), tris.len());
    }
}
