//! A bucket kd-tree over record sites that keeps each site (position, decoded normal, id)
//! inline in its leaf, as structure of arrays.
//!
//! A range query then reads the records it finds from the few leaves it visits, in
//! sequence, instead of fetching each found record's site from an array indexed by id,
//! where records lie in insertion order and so scattered over memory: that fetch was
//! one cache miss per record and the larger part of a gathering's cost with kiddo's tree,
//! whose items are bare ids.
//!
//! Leaves split when full, at the median of the coordinate of widest extent (records on a
//! floor share their height, which a split on it could not separate). Positions held are
//! distinct: [`SiteTree::insert`] reports a record already at the exact position instead
//! of adding another (the index chains records sharing a position). [`SiteTree::build`] makes a balanced
//! tree from a whole set at once, for rebuilds after removals.
//!
//! ## Reach
//! Every record has a reach (its validity radius `R`, world units, `∞` unbounded; module
//! `reach`). Beside the sites, and apart from them so that range queries read the same
//! memory as before, the tree keeps bounds on `max(R, 0)`: per leaf lane (the lane's record
//! and the records chained to it; exactly its record's reach while the index says so) and,
//! squared, per node (everything under it, kept by the parent stem for both children).
//! Insertion raises them along its descent, builds and [`SiteTree::refresh_reach`] set
//! them exact. [`SiteTree::within_reach`] enters a node only when the distance from the
//! query point to its region (bounded by the split planes on the way down) is within the
//! node's bound: Algorithm 3 of the survey (ch. 3) with the kd-tree in place of its
//! multiply referenced octree.

use glam::Vec3;

use crate::simd::{Kernel, Level, SimdLevel};

#[cfg(target_arch = "x86_64")]
use super::gathered::offsets_avx512;
use super::gathered::{Entry, GatheredSites};

/// Records per leaf.
pub(super) const LEAF: usize = 32;
/// Marks a node reference as a leaf index.
const LEAF_BIT: u32 = 1 << 31;

/// A leaf's sites; lanes past `len` hold NaN positions, which no distance test passes.
#[derive(Clone, Debug)]
#[repr(C, align(64))]
struct Leaf {
    x: [f32; LEAF],
    y: [f32; LEAF],
    z: [f32; LEAF],
    nx: [f32; LEAF],
    ny: [f32; LEAF],
    nz: [f32; LEAF],
    id: [u32; LEAF],
    len: u32,
}

impl Leaf {
    fn empty() -> Self {
        Leaf {
            x: [f32::NAN; LEAF],
            y: [f32::NAN; LEAF],
            z: [f32::NAN; LEAF],
            nx: [0.0; LEAF],
            ny: [0.0; LEAF],
            nz: [0.0; LEAF],
            id: [u32::MAX; LEAF],
            len: 0,
        }
    }

    fn push(&mut self, (p, n, id): Entry) {
        let i = self.len as usize;
        debug_assert!(i < LEAF);
        (self.x[i], self.y[i], self.z[i]) = (p.x, p.y, p.z);
        (self.nx[i], self.ny[i], self.nz[i]) = (n.x, n.y, n.z);
        self.id[i] = id;
        self.len += 1;
    }

    /// The lane of the record held at exactly `position`, if any.
    fn holding(&self, position: Vec3) -> Option<usize> {
        (0..self.len as usize).find(|&i| {
            self.x[i] == position.x && self.y[i] == position.y && self.z[i] == position.z
        })
    }

    fn entry(&self, i: usize) -> Entry {
        (
            Vec3::new(self.x[i], self.y[i], self.z[i]),
            Vec3::new(self.nx[i], self.ny[i], self.nz[i]),
            self.id[i],
        )
    }
}

/// A split: positions with `p[dim] < split` lie under `children[0]`, the others under
/// `children[1]`. Children are stem indices, or leaf indices with [`LEAF_BIT`] set.
#[derive(Clone, Copy, Debug)]
struct Stem {
    split: f32,
    dim: u32,
    children: [u32; 2],
}

/// Bounds on `max(R, 0)` of a leaf's lanes, each over the lane's record and the records
/// chained to it; `−∞` past the leaf's `len`.
#[derive(Clone, Debug)]
#[repr(C, align(64))]
struct LaneReach([f32; LEAF]);

impl LaneReach {
    const EMPTY: Self = LaneReach([f32::NEG_INFINITY; LEAF]);

    /// The node bound of the leaf: [`squared`] of its largest lane.
    fn bound2(&self) -> f32 {
        squared(self.0.iter().copied().fold(f32::NEG_INFINITY, f32::max))
    }
}

/// A node bound from a lane bound `r`: `r²`, or `−∞` for `−∞` (nothing under the node).
/// Rounding is monotone, so the square of the largest lane bounds the squares of all.
#[inline]
fn squared(r: f32) -> f32 {
    if r >= 0.0 {
        r * r
    } else {
        f32::NEG_INFINITY
    }
}

/// A site with the bound on `max(R, 0)` of its lane: what builds and splits move around.
pub(super) type Reaching = (Entry, f32);

/// The kd-tree (see the module docs). Positions must be finite.
#[derive(Clone, Debug)]
pub(super) struct SiteTree {
    stems: Vec<Stem>,
    leaves: Vec<Leaf>,
    root: u32,
    /// By stem: bounds on `max(R, 0)²` over everything under each child (the children's
    /// order; [`squared`] of the largest lane under it), upper bounds always, exact after
    /// a build or [`Self::refresh_reach`].
    stem_reach: Vec<[f32; 2]>,
    /// By leaf: the lanes' bounds.
    lane_reach: Vec<LaneReach>,
    /// The bound over the whole tree (`−∞` when empty).
    root_reach: f32,
}

impl Default for SiteTree {
    fn default() -> Self {
        Self {
            stems: Vec::new(),
            leaves: vec![Leaf::empty()],
            root: LEAF_BIT,
            stem_reach: Vec::new(),
            lane_reach: vec![LaneReach::EMPTY],
            root_reach: f32::NEG_INFINITY,
        }
    }
}

impl SiteTree {
    /// A balanced tree over `entries` (distinct finite positions, each with the bound of
    /// its lane), split at medians.
    pub(super) fn build(mut entries: Vec<Reaching>) -> Self {
        let leaves = entries.len().div_ceil(LEAF / 2) + 1;
        let mut tree = Self {
            stems: Vec::new(),
            leaves: Vec::with_capacity(leaves),
            root: 0,
            stem_reach: Vec::new(),
            lane_reach: Vec::with_capacity(leaves),
            root_reach: f32::NEG_INFINITY,
        };
        (tree.root, tree.root_reach) = tree.build_node(&mut entries);
        tree
    }

    /// Builds the subtree over `entries`: its node and its bound.
    fn build_node(&mut self, entries: &mut [Reaching]) -> (u32, f32) {
        if entries.len() <= LEAF {
            let (mut leaf, mut lanes) = (Leaf::empty(), LaneReach::EMPTY);
            for &(e, reach) in entries.iter() {
                lanes.0[leaf.len as usize] = reach;
                leaf.push(e);
            }
            let bound = lanes.bound2();
            self.leaves.push(leaf);
            self.lane_reach.push(lanes);
            return ((self.leaves.len() - 1) as u32 | LEAF_BIT, bound);
        }
        let (dim, split, left) = split_of(entries);
        let stem = self.stems.len();
        self.stems.push(Stem {
            split,
            dim,
            children: [0, 0],
        });
        self.stem_reach.push([f32::NEG_INFINITY; 2]);
        let (below, above) = entries.split_at_mut(left);
        let (low, high) = (self.build_node(below), self.build_node(above));
        self.stems[stem].children = [low.0, high.0];
        self.stem_reach[stem] = [low.1, high.1];
        (stem as u32, low.1.max(high.1))
    }

    /// Bytes held (stems and leaves with their reach bounds, spare capacity included).
    pub(super) fn memory_bytes(&self) -> usize {
        self.stems.capacity() * std::mem::size_of::<Stem>()
            + self.leaves.capacity() * std::mem::size_of::<Leaf>()
            + self.stem_reach.capacity() * std::mem::size_of::<[f32; 2]>()
            + self.lane_reach.capacity() * std::mem::size_of::<LaneReach>()
    }

    /// The id of the record held at exactly `position`, if any.
    #[cfg(test)]
    pub(super) fn find(&self, position: Vec3) -> Option<u32> {
        let mut node = self.root;
        while node & LEAF_BIT == 0 {
            let stem = &self.stems[node as usize];
            node = stem.children[(position[stem.dim as usize] >= stem.split) as usize];
        }
        let leaf = &self.leaves[(node & !LEAF_BIT) as usize];
        leaf.holding(position).map(|i| leaf.id[i])
    }

    /// Adds a record (finite position) whose lane bound is `reach >= 0` unless a record is
    /// held at exactly its position: then returns that record's id, raises that record's
    /// lane bound to `reach` (the new record will be chained to it) and leaves the tree as
    /// it was otherwise. Both are found by one descent, records at one position falling in
    /// one leaf; the descent raises the bounds of the nodes it passes.
    pub(super) fn insert(&mut self, entry: Entry, reach: f32) -> Option<u32> {
        debug_assert!(entry.0.is_finite() && reach >= 0.0);
        let reach2 = squared(reach);
        self.root_reach = self.root_reach.max(reach2);
        let mut node = self.root;
        let mut parent = None;
        while node & LEAF_BIT == 0 {
            let stem = &self.stems[node as usize];
            let side = (entry.0[stem.dim as usize] >= stem.split) as usize;
            let bound = &mut self.stem_reach[node as usize][side];
            *bound = bound.max(reach2);
            parent = Some((node as usize, side));
            node = stem.children[side];
        }
        let index = (node & !LEAF_BIT) as usize;
        if let Some(lane) = self.leaves[index].holding(entry.0) {
            let bound = &mut self.lane_reach[index].0[lane];
            *bound = bound.max(reach);
            return Some(self.leaves[index].id[lane]);
        }
        let len = self.leaves[index].len as usize;
        if len < LEAF {
            self.lane_reach[index].0[len] = reach;
            self.leaves[index].push(entry);
            return None;
        }
        // Full: split the leaf's records and the new one in two leaves under a new stem.
        let leaf = std::mem::replace(&mut self.leaves[index], Leaf::empty());
        let lanes = std::mem::replace(&mut self.lane_reach[index], LaneReach::EMPTY);
        let mut entries: Vec<Reaching> = (0..LEAF).map(|i| (leaf.entry(i), lanes.0[i])).collect();
        entries.push((entry, reach));
        let (dim, split, left) = split_of(&mut entries);
        let mut above = (Leaf::empty(), LaneReach::EMPTY);
        for (k, &(e, reach)) in entries.iter().enumerate() {
            let (leaf, lanes) = if k < left {
                (&mut self.leaves[index], &mut self.lane_reach[index])
            } else {
                (&mut above.0, &mut above.1)
            };
            lanes.0[leaf.len as usize] = reach;
            leaf.push(e);
        }
        let bounds = [self.lane_reach[index].bound2(), above.1.bound2()];
        self.leaves.push(above.0);
        self.lane_reach.push(above.1);
        let stem = self.stems.len() as u32;
        self.stems.push(Stem {
            split,
            dim,
            children: [node, (self.leaves.len() - 1) as u32 | LEAF_BIT],
        });
        self.stem_reach.push(bounds);
        match parent {
            Some((p, side)) => self.stems[p].children[side] = stem,
            None => self.root = stem,
        }
        None
    }

    /// Sets every bound exact: each lane's to `lane(id)` (`id` the lane's record, the
    /// first at its position), then each node's to the maximum under it. Children come
    /// after their parents in `stems` (builds push a stem before its subtrees, splits
    /// append), so one pass from the back sees every child before its parent.
    pub(super) fn refresh_reach(&mut self, lane: impl Fn(u32) -> f32) {
        for (leaf, lanes) in self.leaves.iter().zip(&mut self.lane_reach) {
            for i in 0..leaf.len as usize {
                lanes.0[i] = lane(leaf.id[i]);
            }
        }
        let bound_of = |node: u32, stem_reach: &[[f32; 2]], lane_reach: &[LaneReach]| {
            if node & LEAF_BIT != 0 {
                lane_reach[(node & !LEAF_BIT) as usize].bound2()
            } else {
                let [a, b] = stem_reach[node as usize];
                a.max(b)
            }
        };
        for s in (0..self.stems.len()).rev() {
            let children = self.stems[s].children;
            debug_assert!(children
                .iter()
                .all(|&c| c & LEAF_BIT != 0 || c as usize > s));
            self.stem_reach[s] = children.map(|c| bound_of(c, &self.stem_reach, &self.lane_reach));
        }
        self.root_reach = bound_of(self.root, &self.stem_reach, &self.lane_reach);
    }

    /// Calls `found(id, d2, p, r)` for every lane record (position `p`) whose lane bound
    /// `r` admits the ball of radius `rho >= 0` around `x`: `√d2 < widen_lane(r, rho)` with
    /// `d2 = |p − x|²` (summed as [`GatheredSites::filter`] sums it), leaf after leaf. A
    /// lane passes when any record of its chain may reach a point of the ball: with
    /// `rho = 0`, exactly when its record covers `x` if `r` is that record's reach and no
    /// record is chained to it. A node is entered only when its bound, widened by [`widen`],
    /// admits the squared distance from `x` to its region. `scratch` is working space.
    pub(super) fn within_reach(
        &self,
        x: Vec3,
        rho: f32,
        scratch: &mut ReachQueryScratch,
        mut found: impl FnMut(u32, f32, Vec3, f32),
    ) {
        let ReachQueryScratch { stack, leaves } = scratch;
        stack.clear();
        leaves.clear();
        // A region's squared offsets from x along each axis (0 inside its slab), summed
        // as a record's squared distance is (module `gathered`): the sum is at most that
        // distance for every record in the region, each term being at most the record's
        // and rounding monotone. Kept as three scalars, not an array written at a varying
        // index and read whole (a failed store forwarding per node).
        if widen(self.root_reach, rho) >= 0.0 {
            stack.push((self.root, 0.0, 0.0, 0.0));
        }
        while let Some((mut node, s0, s1, s2)) = stack.pop() {
            // Down the nearer side, which keeps the region's offsets; the farther side
            // moves the offset along the split's axis to the plane.
            let near_d2 = s0 + s1 + s2;
            let mut reached = true;
            while node & LEAF_BIT == 0 {
                let stem = &self.stems[node as usize];
                let bounds = &self.stem_reach[node as usize];
                let offset = x[stem.dim as usize] - stem.split;
                let near = (offset >= 0.0) as usize;
                let o2 = offset * offset;
                let far = match stem.dim {
                    0 => (o2, s1, s2),
                    1 => (s0, o2, s2),
                    _ => (s0, s1, o2),
                };
                if far.0 + far.1 + far.2 <= widen(bounds[1 - near], rho) {
                    stack.push((stem.children[1 - near], far.0, far.1, far.2));
                }
                // A NaN bound (nothing under the node) admits nothing; `near_d2` is never
                // NaN (a frame is pushed only when its distance passed a test).
                let bound = widen(bounds[near], rho);
                if near_d2 > bound || bound.is_nan() {
                    reached = false;
                    break;
                }
                node = stem.children[near];
            }
            if reached {
                let index = node & !LEAF_BIT;
                let leaf = &self.leaves[index as usize];
                leaf.prefetch_positions();
                leaf.prefetch_ids();
                super::index::prefetch(&self.lane_reach[index as usize].0[0]);
                super::index::prefetch(&self.lane_reach[index as usize].0[LEAF / 2]);
                leaves.push(index);
            }
        }
        for &index in leaves.iter() {
            let (leaf, lanes) = (
                &self.leaves[index as usize],
                &self.lane_reach[index as usize],
            );
            let (mut pass, d2) = leaf.reached(x, lanes, rho);
            while pass != 0 {
                let lane = pass.trailing_zeros() as usize;
                pass &= pass - 1;
                found(leaf.id[lane], d2[lane], leaf.entry(lane).0, lanes.0[lane]);
            }
        }
    }

    /// Appends to `out` every record with `|p − x|² <= r2` (summed as
    /// [`GatheredSites::filter`] sums it), leaf after leaf.
    pub(super) fn within(
        &self,
        x: Vec3,
        r2: f32,
        scratch: &mut QueryScratch,
        out: &mut GatheredSites,
    ) {
        let QueryScratch { stack, leaves } = scratch;
        stack.clear();
        leaves.clear();
        stack.push(self.root);
        // The leaves in reach first, their positions asked for as they are found, so that
        // their cache misses overlap; then their records.
        while let Some(mut node) = stack.pop() {
            // Down to a leaf, nearer side first; the farther side waits unless the
            // splitting plane alone puts it out of reach. Rounding is monotone, so a
            // record beyond the plane is at least as far as the plane.
            while node & LEAF_BIT == 0 {
                let stem = &self.stems[node as usize];
                let offset = x[stem.dim as usize] - stem.split;
                let near = (offset >= 0.0) as usize;
                if offset * offset <= r2 {
                    stack.push(stem.children[1 - near]);
                }
                node = stem.children[near];
            }
            let leaf = &self.leaves[(node & !LEAF_BIT) as usize];
            leaf.prefetch_positions();
            leaves.push(node & !LEAF_BIT);
        }
        for &leaf in leaves.iter() {
            self.leaves[leaf as usize].append_within(x, r2, out);
        }
    }
}

/// A node's squared bound `b` widened by `rho >= 0`: `b` itself for `rho = 0`, else
/// `((√b + rho)(1 + 4e-5))²`, so that every record a lane test widened by `rho` passes
/// ([`widen_lane`], whose margin is half this one) lies within it. NaN for `b = −∞`
/// (nothing under the node), which no test passes.
#[inline(always)]
pub(super) fn widen(b: f32, rho: f32) -> f32 {
    if rho == 0.0 {
        b
    } else {
        let w = (b.sqrt() + rho) * (1.0 + 4e-5);
        w * w
    }
}

/// A lane bound `r` widened by `rho >= 0`: `r` itself for `rho = 0`, else
/// `(r + rho)(1 + 2e-5)`, above the `(R + rho)(1 + 1e-5)` of every reach `R <= r` with a
/// margin for the rounding of this.
#[inline(always)]
pub(super) fn widen_lane(r: f32, rho: f32) -> f32 {
    if rho == 0.0 {
        r
    } else {
        (r + rho) * (1.0 + 2e-5)
    }
}

/// [`Leaf::append_within`] as a [`Kernel`]: its AVX-512 form, else the portable one. The
/// AVX-512 form is never inlined into the dispatcher's function, whose feature set differs
/// (AVX-512 VL): it stays compiled exactly for its own set.
struct AppendWithinKernel<'a> {
    leaf: &'a Leaf,
    x: Vec3,
    r2: f32,
    out: &'a mut GatheredSites,
}

impl Kernel for AppendWithinKernel<'_> {
    type Output = ();

    #[inline(always)]
    fn run<L: Level>(self, _level: L) {
        let Self { leaf, x, r2, out } = self;
        match L::LEVEL {
            // SAFETY: a value of `L` exists only on CPUs with `L::LEVEL` (`Level`'s
            // contract), here AVX-512 F.
            #[cfg(target_arch = "x86_64")]
            SimdLevel::Avx512 => unsafe { leaf.append_within_avx512(x, r2, out) },
            _ => leaf.append_within_portable(x, r2, out),
        }
    }
}

/// Working space of [`SiteTree::within`].
#[derive(Clone, Debug, Default)]
pub(super) struct QueryScratch {
    stack: Vec<u32>,
    leaves: Vec<u32>,
}

/// Working space of [`SiteTree::within_reach`]: nodes to visit with the offsets of their
/// regions, and the leaves found.
#[derive(Clone, Debug, Default)]
pub(super) struct ReachQueryScratch {
    stack: Vec<(u32, f32, f32, f32)>,
    leaves: Vec<u32>,
}

impl ReachQueryScratch {
    /// Leaves the last query visited.
    #[cfg(test)]
    pub(super) fn leaves_visited(&self) -> usize {
        self.leaves.len()
    }
}

/// [`Leaf::reached`] as a [`Kernel`]: its AVX-512 form, else the portable one.
struct ReachedKernel<'a> {
    leaf: &'a Leaf,
    x: Vec3,
    lanes: &'a LaneReach,
    rho: f32,
}

impl Kernel for ReachedKernel<'_> {
    type Output = (u32, [f32; LEAF]);

    #[inline(always)]
    fn run<L: Level>(self, _level: L) -> Self::Output {
        let Self {
            leaf,
            x,
            lanes,
            rho,
        } = self;
        match L::LEVEL {
            // SAFETY: a value of `L` exists only on CPUs with `L::LEVEL` (`Level`'s
            // contract), here AVX-512 F.
            #[cfg(target_arch = "x86_64")]
            SimdLevel::Avx512 => unsafe { leaf.reached_avx512(x, lanes, rho) },
            _ => leaf.reached_portable(x, lanes, rho),
        }
    }
}

impl Leaf {
    /// Asks for the cache lines of the ids (the 128 bytes after positions and normals).
    #[inline(always)]
    fn prefetch_ids(&self) {
        super::index::prefetch(&self.id[0]);
        super::index::prefetch(&self.id[LEAF / 2]);
    }

    /// Asks for the cache lines of the positions (`x`, `y`, `z`: the first 384 bytes).
    #[inline(always)]
    fn prefetch_positions(&self) {
        #[cfg(target_arch = "x86_64")]
        for line in 0..3 * LEAF * 4 / 64 {
            // SAFETY: prefetching is a hint and never faults; the address lies in `self`.
            unsafe {
                use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
                let at = (self as *const Self).cast::<u8>().add(64 * line);
                _mm_prefetch::<_MM_HINT_T0>(at.cast());
            }
        }
    }

    /// The lanes whose bound `r` in `lanes`, widened by `rho`, admits `x`
    /// (`√|p − x|² < widen_lane(r, rho)`; NaN lanes past `len` fail) as a mask, and every
    /// lane's `|p − x|²`.
    #[inline]
    fn reached(&self, x: Vec3, lanes: &LaneReach, rho: f32) -> (u32, [f32; LEAF]) {
        crate::simd::dispatch_avx512(ReachedKernel {
            leaf: self,
            x,
            lanes,
            rho,
        })
    }

    fn reached_portable(&self, x: Vec3, lanes: &LaneReach, rho: f32) -> (u32, [f32; LEAF]) {
        let mut d2 = [f32::NAN; LEAF];
        let mut pass = 0u32;
        for (i, d2) in d2.iter_mut().enumerate() {
            let (ex, ey, ez) = (self.x[i] - x.x, self.y[i] - x.y, self.z[i] - x.z);
            *d2 = ex * ex + ey * ey + ez * ez;
            pass |= ((d2.sqrt() < widen_lane(lanes.0[i], rho)) as u32) << i;
        }
        (pass, d2)
    }

    /// [`Self::reached_portable`] sixteen lanes at a time.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    #[inline(never)]
    fn reached_avx512(&self, x: Vec3, lanes: &LaneReach, rho: f32) -> (u32, [f32; LEAF]) {
        use std::arch::x86_64::*;
        let q = [x.x, x.y, x.z].map(|v| _mm512_set1_ps(v));
        let (wide, margin) = (_mm512_set1_ps(rho), _mm512_set1_ps(1.0 + 2e-5));
        // `widen_lane` and the test, operation for operation (the square root is
        // correctly rounded in both forms).
        let mut d2 = [f32::NAN; LEAF];
        let mut pass = 0u32;
        for c in (0..LEAF).step_by(16) {
            // SAFETY: `c + 16 <= LEAF`, the length of every lane array.
            unsafe {
                let (_, d) = offsets_avx512(
                    self.x.as_ptr().add(c),
                    self.y.as_ptr().add(c),
                    self.z.as_ptr().add(c),
                    q,
                );
                let mut bound = _mm512_loadu_ps(lanes.0.as_ptr().add(c));
                if rho != 0.0 {
                    bound = _mm512_mul_ps(_mm512_add_ps(bound, wide), margin);
                }
                let within = _mm512_cmp_ps_mask::<_CMP_LT_OQ>(_mm512_sqrt_ps(d), bound);
                pass |= (within as u32) << c;
                _mm512_storeu_ps(d2.as_mut_ptr().add(c), d);
            }
        }
        (pass, d2)
    }

    /// Appends to `out` the records with `|p − x|² <= r2`, in lane order.
    #[inline]
    fn append_within(&self, x: Vec3, r2: f32, out: &mut GatheredSites) {
        crate::simd::dispatch_avx512(AppendWithinKernel {
            leaf: self,
            x,
            r2,
            out,
        });
    }

    fn append_within_portable(&self, x: Vec3, r2: f32, out: &mut GatheredSites) {
        for i in 0..self.len as usize {
            let (ex, ey, ez) = (self.x[i] - x.x, self.y[i] - x.y, self.z[i] - x.z);
            if ex * ex + ey * ey + ez * ez <= r2 {
                out.push(self.entry(i));
            }
        }
    }

    /// [`Self::append_within_portable`] sixteen lanes at a time: the distance test gives a
    /// mask (NaN lanes past `len` fail it) and the passing lanes are compressed and
    /// appended whole, without a branch per record.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    #[inline(never)]
    fn append_within_avx512(&self, x: Vec3, r2: f32, out: &mut GatheredSites) {
        use std::arch::x86_64::*;
        let q = [x.x, x.y, x.z].map(|v| _mm512_set1_ps(v));
        let reach = _mm512_set1_ps(r2);
        for c in (0..LEAF).step_by(16) {
            // SAFETY: `c + 16 <= LEAF`, the length of every lane array.
            unsafe {
                let (_, d2) = offsets_avx512(
                    self.x.as_ptr().add(c),
                    self.y.as_ptr().add(c),
                    self.z.as_ptr().add(c),
                    q,
                );
                let pass = _mm512_cmp_ps_mask::<_CMP_LE_OQ>(d2, reach);
                if pass != 0 {
                    let lanes = [&self.x, &self.y, &self.z, &self.nx, &self.ny, &self.nz]
                        .map(|a| _mm512_loadu_ps(a.as_ptr().add(c)));
                    let id = _mm512_loadu_si512(self.id.as_ptr().add(c).cast());
                    out.append_masked_avx512(pass, lanes, id);
                }
            }
        }
    }
}

/// Where to split `entries` (at least two distinct positions): the coordinate of widest
/// extent (the lower axis on ties), the value nearest the median that leaves records on
/// both sides, and how many lie below it. Sorts `entries` by that coordinate, then id.
fn split_of(entries: &mut [Reaching]) -> (u32, f32, usize) {
    let (lo, hi) = entries.iter().fold(
        (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
        |(lo, hi), (e, _)| (lo.min(e.0), hi.max(e.0)),
    );
    let extent = hi - lo;
    let dim = if extent.x >= extent.y && extent.x >= extent.z {
        0
    } else if extent.y >= extent.z {
        1
    } else {
        2
    };
    entries.sort_unstable_by(|(a, _), (b, _)| a.0[dim].total_cmp(&b.0[dim]).then(a.2.cmp(&b.2)));
    let value = |i: usize| entries[i].0 .0[dim];
    let mid = entries.len() / 2;
    // The first change of value at or after the median, else the last before it; one
    // exists, the extent being positive.
    let left = (mid.max(1)..entries.len())
        .find(|&i| value(i) > value(i - 1))
        .or_else(|| (1..mid).rev().find(|&i| value(i) > value(i - 1)))
        .expect("entries hold two distinct positions");
    (dim as u32, value(left), left)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::rng::{hash4, to_unit_f32};

    fn unit(seed: u64, k: u64) -> f32 {
        to_unit_f32(hash4(seed, k, 0, 9))
    }

    /// Positions on a floor (shared height) with clusters and a grid, in a seeded order.
    fn entries(count: usize, seed: u64) -> Vec<Entry> {
        (0..count as u64)
            .map(|k| {
                let p = if k % 3 == 0 {
                    // A grid: many records share x or z exactly.
                    Vec3::new((k % 17) as f32 * 0.05, 0.0, (k / 17 % 13) as f32 * 0.05)
                } else {
                    Vec3::new(unit(seed, 2 * k), 0.0, unit(seed, 2 * k + 1))
                };
                (p, Vec3::Y, k as u32)
            })
            .collect()
    }

    fn distinct(mut e: Vec<Entry>) -> Vec<Entry> {
        let mut seen = std::collections::HashSet::new();
        e.retain(|x| seen.insert(x.0.to_array().map(f32::to_bits)));
        e
    }

    fn ids_within(tree: &SiteTree, x: Vec3, r2: f32) -> Vec<u32> {
        let mut out = GatheredSites::default();
        tree.within(x, r2, &mut QueryScratch::default(), &mut out);
        let mut ids: Vec<u32> = (0..out.len()).map(|k| out.id(k)).collect();
        ids.sort_unstable();
        ids
    }

    #[test]
    fn range_queries_find_exactly_the_records_within_reach() {
        for (count, seed) in [(0usize, 1u64), (1, 2), (33, 3), (2000, 4)] {
            let all = distinct(entries(count, seed));
            let mut grown = SiteTree::default();
            for &e in &all {
                assert_eq!(grown.find(e.0), None);
                assert_eq!(grown.insert(e, 1.0), None);
                assert_eq!(grown.find(e.0), Some(e.2));
                // A second record at the same position is reported, not added.
                assert_eq!(grown.insert((e.0, Vec3::X, u32::MAX), 1.0), Some(e.2));
            }
            let built = SiteTree::build(all.iter().map(|&e| (e, 1.0)).collect());
            for q in 0..200u64 {
                // Query points at records (exactly on the reach of others) and anywhere.
                let x = if q % 4 == 0 && !all.is_empty() {
                    all[q as usize % all.len()].0
                } else {
                    Vec3::new(unit(seed + 7, 2 * q), 0.0, unit(seed + 7, 2 * q + 1))
                };
                let r2 = [0.0f32, 0.0025, 0.01, 0.3][q as usize % 4];
                let want: Vec<u32> = {
                    let mut v: Vec<u32> = all
                        .iter()
                        .filter(|e| {
                            let d = e.0 - x;
                            d.x * d.x + d.y * d.y + d.z * d.z <= r2
                        })
                        .map(|e| e.2)
                        .collect();
                    v.sort_unstable();
                    v
                };
                assert_eq!(ids_within(&grown, x, r2), want, "grown, {count} records");
                assert_eq!(ids_within(&built, x, r2), want, "built, {count} records");
            }
        }
    }

    /// Every form of the leaf scan appends the same records in the same order with the
    /// same bits, for full and partly filled leaves, records exactly on the reach and at
    /// the query point.
    #[test]
    fn every_leaf_scan_form_appends_the_same_records() {
        let bits = |g: &GatheredSites| {
            (0..g.len())
                .map(|k| {
                    let (p, n) = (g.position(k), g.normal(k));
                    ([p, n].map(|v| v.to_array().map(f32::to_bits)), g.id(k))
                })
                .collect::<Vec<_>>()
        };
        for fill in [0usize, 1, 15, 16, 17, LEAF] {
            let mut leaf = Leaf::empty();
            for k in 0..fill as u64 {
                let p = match k % 5 {
                    0 => Vec3::new(0.3, 0.0, 0.0),
                    1 => Vec3::ZERO,
                    _ => Vec3::new(unit(40, 2 * k), 0.0, unit(40, 2 * k + 1)) - 0.5,
                };
                leaf.push((p, Vec3::new(0.0, 1.0, unit(41, k)), k as u32));
            }
            for r2 in [0.0f32, 0.09, 0.04, 1.0] {
                let mut want = GatheredSites::default();
                leaf.append_within_portable(Vec3::ZERO, r2, &mut want);
                let expected: Vec<u32> = (0..fill)
                    .filter(|&i| leaf.entry(i).0.length_squared() <= r2)
                    .map(|i| i as u32)
                    .collect();
                assert_eq!(
                    bits(&want).iter().map(|b| b.1).collect::<Vec<_>>(),
                    expected
                );
                let mut got = GatheredSites::default();
                leaf.append_within(Vec3::ZERO, r2, &mut got);
                assert_eq!(bits(&got), bits(&want), "dispatched, fill {fill}, r2 {r2}");
                #[cfg(target_arch = "x86_64")]
                if std::arch::is_x86_feature_detected!("avx512f") {
                    let mut wide = GatheredSites::default();
                    // Appending after records already held, as a range query does.
                    leaf.append_within_portable(Vec3::ZERO, r2, &mut wide);
                    // SAFETY: the feature was detected just before.
                    unsafe { leaf.append_within_avx512(Vec3::ZERO, r2, &mut wide) };
                    let twice = [bits(&want), bits(&want)].concat();
                    assert_eq!(bits(&wide), twice, "AVX-512, fill {fill}, r2 {r2}");
                }
            }
        }
    }

    /// Checks every stored node bound against the square of the largest lane under it:
    /// equal when `exact`, at least it otherwise. Lanes past a leaf's `len` must be `−∞`.
    fn check_bounds(tree: &SiteTree, exact: bool) {
        fn under(tree: &SiteTree, node: u32, exact: bool) -> f32 {
            if node & LEAF_BIT != 0 {
                let i = (node & !LEAF_BIT) as usize;
                let len = tree.leaves[i].len as usize;
                let lanes = &tree.lane_reach[i].0;
                assert!(lanes[len..].iter().all(|&b| b == f32::NEG_INFINITY));
                return lanes[..len]
                    .iter()
                    .copied()
                    .fold(f32::NEG_INFINITY, f32::max);
            }
            let stem = &tree.stems[node as usize];
            let mut most = f32::NEG_INFINITY;
            for side in 0..2 {
                let b = under(tree, stem.children[side], exact);
                let (stored, b2) = (tree.stem_reach[node as usize][side], squared(b));
                if exact {
                    assert_eq!(stored, b2, "stem {node}, side {side}");
                } else {
                    assert!(stored >= b2, "stem {node}, side {side}: {stored} < {b2}");
                }
                most = most.max(b);
            }
            most
        }
        let b = squared(under(tree, tree.root, exact));
        if exact {
            assert_eq!(tree.root_reach, b);
        } else {
            assert!(tree.root_reach >= b);
        }
    }

    /// Reach bounds are the maxima under each node after growth (chained records raising
    /// their head's lane), builds and refreshes, and bounds after lanes are lowered.
    #[test]
    fn reach_bounds_are_the_maxima_under_each_node() {
        let bound = |seed: u64, k: u64| match hash4(seed, k, 3, 3) % 8 {
            0 => f32::INFINITY,
            1 => 0.0,
            _ => unit(seed + 1, k),
        };
        for (count, seed) in [(0usize, 20u64), (1, 21), (40, 22), (3000, 23)] {
            let all = distinct(entries(count, seed));
            let mut grown = SiteTree::default();
            check_bounds(&grown, true);
            for (k, &e) in all.iter().enumerate() {
                assert_eq!(grown.insert(e, bound(seed, k as u64)), None);
                if k % 7 == 0 {
                    // Another record at this position: its reach raises the lane.
                    let other = (e.0, Vec3::X, u32::MAX);
                    assert_eq!(grown.insert(other, bound(seed + 2, k as u64)), Some(e.2));
                }
            }
            check_bounds(&grown, true);
            let with_bounds: Vec<Reaching> = all
                .iter()
                .enumerate()
                .map(|(k, &e)| (e, bound(seed, k as u64)))
                .collect();
            let mut built = SiteTree::build(with_bounds);
            check_bounds(&built, true);
            // Lower every lane behind the nodes' backs: bounds, not maxima, until refreshed.
            let lower = |id: u32| 0.5 * unit(seed + 3, id as u64);
            for tree in [&mut grown, &mut built] {
                for (leaf, lanes) in tree.leaves.iter().zip(&mut tree.lane_reach) {
                    for i in 0..leaf.len as usize {
                        lanes.0[i] = lower(leaf.id[i]);
                    }
                }
                check_bounds(tree, false);
                tree.refresh_reach(lower);
                check_bounds(tree, true);
            }
        }
    }

    /// Both forms of the reach scan give the same mask and, in the lanes held, the same
    /// squared distances, with bounds of 0, ∞ and exactly a lane's distance, unwidened and
    /// widened.
    #[test]
    fn every_reach_scan_form_gives_the_same_lanes() {
        let x = Vec3::splat(0.5);
        for fill in [0usize, 1, 15, 16, 17, LEAF] {
            let mut leaf = Leaf::empty();
            let mut lanes = LaneReach::EMPTY;
            for k in 0..fill as u64 {
                let p = Vec3::new(unit(42, 3 * k), unit(42, 3 * k + 1), unit(42, 3 * k + 2));
                let d = p - x;
                lanes.0[k as usize] = match k % 4 {
                    0 => 0.0,
                    1 => f32::INFINITY,
                    2 => (d.x * d.x + d.y * d.y + d.z * d.z).sqrt(),
                    _ => 0.3 * unit(43, k),
                };
                leaf.push((p, Vec3::Y, k as u32));
            }
            for rho in [0.0f32, 0.05, 0.3] {
                let (mask, d2) = leaf.reached_portable(x, &lanes, rho);
                let expected = (0..fill).fold(0u32, |m, i| {
                    let d = leaf.entry(i).0 - x;
                    let d2 = d.x * d.x + d.y * d.y + d.z * d.z;
                    m | ((d2.sqrt() < widen_lane(lanes.0[i], rho)) as u32) << i
                });
                assert_eq!(mask, expected, "fill {fill}, rho {rho}");
                if fill > 2 {
                    assert_ne!(mask & 0b10, 0, "infinite bounds pass");
                    assert_eq!(mask & 0b101 != 0, rho > 0.0, "0 and |p − x| pass widened");
                }
                let (got, got_d2) = leaf.reached(x, &lanes, rho);
                assert_eq!(got, mask, "dispatched, fill {fill}, rho {rho}");
                let held =
                    |d: [f32; LEAF]| d[..fill].iter().map(|v| v.to_bits()).collect::<Vec<_>>();
                assert_eq!(held(got_d2), held(d2));
                #[cfg(target_arch = "x86_64")]
                if std::arch::is_x86_feature_detected!("avx512f") {
                    // SAFETY: the feature was detected just before.
                    let (wide, wide_d2) = unsafe { leaf.reached_avx512(x, &lanes, rho) };
                    assert_eq!(wide, mask, "AVX-512, fill {fill}, rho {rho}");
                    assert_eq!(held(wide_d2), held(d2));
                }
            }
        }
    }

    #[test]
    fn records_on_one_line_and_sorted_insertion_still_split() {
        // Every record shares y and z; inserted in increasing x (a scanline).
        let mut tree = SiteTree::default();
        for k in 0..500u32 {
            tree.insert((Vec3::new(k as f32, 1.0, 2.0), Vec3::Y, k), 1.0);
        }
        assert!(tree.leaves.iter().all(|l| l.len as usize <= LEAF));
        assert_eq!(
            ids_within(&tree, Vec3::new(250.0, 1.0, 2.0), 4.0),
            vec![248, 249, 250, 251, 252]
        );
        assert_eq!(tree.find(Vec3::new(7.0, 1.0, 2.0)), Some(7));
        assert_eq!(tree.find(Vec3::new(7.5, 1.0, 2.0)), None);
    }
}
