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

    /// The id of the record held at exactly `position`, if any.
    fn holding(&self, position: Vec3) -> Option<u32> {
        (0..self.len as usize)
            .find(|&i| {
                self.x[i] == position.x && self.y[i] == position.y && self.z[i] == position.z
            })
            .map(|i| self.id[i])
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

/// The kd-tree (see the module docs). Positions must be finite.
#[derive(Clone, Debug)]
pub(super) struct SiteTree {
    stems: Vec<Stem>,
    leaves: Vec<Leaf>,
    root: u32,
}

impl Default for SiteTree {
    fn default() -> Self {
        Self {
            stems: Vec::new(),
            leaves: vec![Leaf::empty()],
            root: LEAF_BIT,
        }
    }
}

impl SiteTree {
    /// A balanced tree over `entries` (distinct finite positions), split at medians.
    pub(super) fn build(mut entries: Vec<Entry>) -> Self {
        let mut tree = Self {
            stems: Vec::new(),
            leaves: Vec::with_capacity(entries.len().div_ceil(LEAF / 2) + 1),
            root: 0,
        };
        tree.root = tree.build_node(&mut entries);
        tree
    }

    fn build_node(&mut self, entries: &mut [Entry]) -> u32 {
        if entries.len() <= LEAF {
            let mut leaf = Leaf::empty();
            for &e in entries.iter() {
                leaf.push(e);
            }
            self.leaves.push(leaf);
            return (self.leaves.len() - 1) as u32 | LEAF_BIT;
        }
        let (dim, split, left) = split_of(entries);
        let stem = self.stems.len();
        self.stems.push(Stem {
            split,
            dim,
            children: [0, 0],
        });
        let (below, above) = entries.split_at_mut(left);
        let children = [self.build_node(below), self.build_node(above)];
        self.stems[stem].children = children;
        stem as u32
    }

    /// Bytes held (stems and leaves, with spare capacity).
    pub(super) fn memory_bytes(&self) -> usize {
        self.stems.capacity() * std::mem::size_of::<Stem>()
            + self.leaves.capacity() * std::mem::size_of::<Leaf>()
    }

    /// The id of the record held at exactly `position`, if any.
    #[cfg(test)]
    pub(super) fn find(&self, position: Vec3) -> Option<u32> {
        let leaf = &self.leaves[(self.leaf_of(position).0 & !LEAF_BIT) as usize];
        leaf.holding(position)
    }

    /// Adds a record (finite position) unless a record is held at exactly its position:
    /// then returns that record's id and leaves the tree as it was. Both are found by one
    /// descent, records at one position falling in one leaf.
    pub(super) fn insert(&mut self, entry: Entry) -> Option<u32> {
        debug_assert!(entry.0.is_finite());
        let (node, parent) = self.leaf_of(entry.0);
        let index = (node & !LEAF_BIT) as usize;
        if let Some(id) = self.leaves[index].holding(entry.0) {
            return Some(id);
        }
        if (self.leaves[index].len as usize) < LEAF {
            self.leaves[index].push(entry);
            return None;
        }
        // Full: split the leaf's records and the new one in two leaves under a new stem.
        let leaf = std::mem::replace(&mut self.leaves[index], Leaf::empty());
        let mut entries: Vec<Entry> = (0..LEAF).map(|i| leaf.entry(i)).collect();
        entries.push(entry);
        let (dim, split, left) = split_of(&mut entries);
        for &e in &entries[..left] {
            self.leaves[index].push(e);
        }
        let mut above = Leaf::empty();
        for &e in &entries[left..] {
            above.push(e);
        }
        self.leaves.push(above);
        let stem = self.stems.len() as u32;
        self.stems.push(Stem {
            split,
            dim,
            children: [node, (self.leaves.len() - 1) as u32 | LEAF_BIT],
        });
        match parent {
            Some((p, side)) => self.stems[p].children[side] = stem,
            None => self.root = stem,
        }
        None
    }

    /// The leaf `position` falls in, with its parent stem and side.
    fn leaf_of(&self, position: Vec3) -> (u32, Option<(usize, usize)>) {
        let mut node = self.root;
        let mut parent = None;
        while node & LEAF_BIT == 0 {
            let stem = &self.stems[node as usize];
            let side = (position[stem.dim as usize] >= stem.split) as usize;
            parent = Some((node as usize, side));
            node = stem.children[side];
        }
        (node, parent)
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

impl Leaf {
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
fn split_of(entries: &mut [Entry]) -> (u32, f32, usize) {
    let (lo, hi) = entries.iter().fold(
        (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
        |(lo, hi), e| (lo.min(e.0), hi.max(e.0)),
    );
    let extent = hi - lo;
    let dim = if extent.x >= extent.y && extent.x >= extent.z {
        0
    } else if extent.y >= extent.z {
        1
    } else {
        2
    };
    entries.sort_unstable_by(|a, b| a.0[dim].total_cmp(&b.0[dim]).then(a.2.cmp(&b.2)));
    let value = |i: usize| entries[i].0[dim];
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
                assert_eq!(grown.insert(e), None);
                assert_eq!(grown.find(e.0), Some(e.2));
                // A second record at the same position is reported, not added.
                assert_eq!(grown.insert((e.0, Vec3::X, u32::MAX)), Some(e.2));
            }
            let built = SiteTree::build(all.clone());
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

    #[test]
    fn records_on_one_line_and_sorted_insertion_still_split() {
        // Every record shares y and z; inserted in increasing x (a scanline).
        let mut tree = SiteTree::default();
        for k in 0..500u32 {
            tree.insert((Vec3::new(k as f32, 1.0, 2.0), Vec3::Y, k));
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
