//! VF eq. 1: the voxel grid. Voxel `v = (x, y, z)` of a `Dx x Dy x Dz` grid over a box has
//! key `H(v) = z · Dx · Dy + y · Dx + x`; items (discs, VPLs) are counting-sorted by key
//! into one array, each non-empty voxel owning a range of it (an *entry*). A voxel's
//! entry is found through a dense table of every key when the grid has at most
//! [`DENSE_MAX_VOXELS`] voxels, else through a hashed table of `T` slots (slot `key mod
//! T`) whose entries keep their voxel's coordinates: keys that collide share a slot and
//! are told apart by the coordinates, never merged.
//!
//! An item enters every voxel its bounds touch (a disc's box, a point's voxel).

use glam::{UVec3, Vec3};

use crate::error::{Error, Result};
use crate::geometry::Bounds;

/// Most voxels a grid stores densely (a `u32` per voxel).
pub const DENSE_MAX_VOXELS: u64 = 1 << 24;

/// How a grid covers space: its box, voxel size and counts. Points outside the box map to
/// the nearest voxel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GridFrame {
    /// The box's low corner (world units).
    pub origin: Vec3,
    /// A voxel's size per axis (world units, `> 0`).
    pub cell: Vec3,
    /// Voxels per axis, `>= 1`.
    pub dims: [u32; 3],
}

impl GridFrame {
    /// `dims` voxels over `bounds`, padded by a part in 1e4 of its extent (at least the
    /// extent's rounding) so that points on the box's faces fall inside; flat axes get
    /// the padding as their size. Fails naming `voxels` on a zero count and `scene` on
    /// empty or non-finite bounds.
    pub fn new(bounds: Bounds, dims: [u32; 3]) -> Result<Self> {
        if dims.contains(&0) {
            return Err(Error::invalid(
                "voxels",
                format!("must be positive per axis, got {dims:?}"),
            ));
        }
        if bounds.is_empty() || !(bounds.min.is_finite() && bounds.max.is_finite()) {
            return Err(Error::invalid("scene", "has no finite bounds to voxelise"));
        }
        let size = bounds.max - bounds.min;
        let scale = size
            .max_element()
            .max(bounds.min.abs().max(bounds.max.abs()).max_element());
        let pad = (size.max_element() * 1e-4)
            .max(scale * 1e-6)
            .max(f32::MIN_POSITIVE);
        let origin = bounds.min - Vec3::splat(pad);
        let extent = size + Vec3::splat(2.0 * pad);
        let cell = extent / UVec3::from(dims).as_vec3();
        Ok(Self { origin, cell, dims })
    }

    /// Number of voxels.
    pub fn voxels(&self) -> u64 {
        self.dims.iter().map(|&d| d as u64).product()
    }

    /// Eq. 1: `z · Dx · Dy + y · Dx + x`.
    #[inline]
    pub fn key(&self, v: UVec3) -> u64 {
        let [dx, dy, _] = self.dims.map(|d| d as u64);
        v.z as u64 * dx * dy + v.y as u64 * dx + v.x as u64
    }

    /// The voxel of `key` (inverse of [`Self::key`]).
    #[inline]
    pub fn coords(&self, key: u64) -> UVec3 {
        let [dx, dy, _] = self.dims.map(|d| d as u64);
        UVec3::new(
            (key % dx) as u32,
            (key / dx % dy) as u32,
            (key / (dx * dy)) as u32,
        )
    }

    /// The voxel holding `p`, clamped to the grid (NaN maps to 0).
    #[inline]
    pub fn voxel_of(&self, p: Vec3) -> UVec3 {
        let f = (p - self.origin) / self.cell;
        let d = UVec3::from(self.dims);
        // `as u32` saturates: negatives and NaN to 0.
        UVec3::new(f.x as u32, f.y as u32, f.z as u32).min(d - UVec3::ONE)
    }

    /// The low and high corners of voxel `v`.
    pub fn voxel_bounds(&self, v: UVec3) -> (Vec3, Vec3) {
        let lo = self.origin + v.as_vec3() * self.cell;
        (lo, lo + self.cell)
    }

    /// The box of the whole grid.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        (
            self.origin,
            self.origin + UVec3::from(self.dims).as_vec3() * self.cell,
        )
    }
}

/// A non-empty voxel: its coordinates and its items' range in [`VoxelIndex::items`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Entry {
    pub voxel: UVec3,
    pub start: u32,
    pub end: u32,
}

/// How entries are found from a key.
#[derive(Clone, Debug, PartialEq)]
enum Table {
    /// Entry index per key (`u32::MAX`: empty voxel).
    Dense(Vec<u32>),
    /// `T` slots: slot `s` holds entries `order[starts[s]..starts[s + 1]]`.
    Hashed {
        slots: u32,
        starts: Vec<u32>,
        order: Vec<u32>,
    },
}

/// Items sorted into voxels (module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct VoxelIndex {
    pub frame: GridFrame,
    /// Item indices, voxel by voxel in key order; within a voxel in item order.
    pub items: Vec<u32>,
    /// Non-empty voxels in key order.
    pub entries: Vec<Entry>,
    table: Table,
}

impl VoxelIndex {
    /// Sorts `n` items into `frame`'s voxels: item `i` enters every voxel from `span(i).0`
    /// to `span(i).1` (inclusive, clamped to the grid). `slots`: a hashed table of that
    /// many slots; `None`: dense when the grid has at most [`DENSE_MAX_VOXELS`] voxels,
    /// else hashed with one slot per non-empty voxel.
    pub fn build(
        frame: GridFrame,
        n: usize,
        span: impl Fn(usize) -> (UVec3, UVec3),
        slots: Option<u32>,
    ) -> Result<Self> {
        if slots == Some(0) {
            return Err(Error::invalid("table_slots", "must be at least 1, got 0"));
        }
        if n > u32::MAX as usize {
            return Err(Error::invalid(
                "proxies",
                "more than 2^32 items to voxelise",
            ));
        }
        let top = UVec3::from(frame.dims) - UVec3::ONE;
        let each = |i: usize, f: &mut dyn FnMut(u64)| {
            let (lo, hi) = span(i);
            let (lo, hi) = (lo.min(top), hi.min(top));
            for z in lo.z..=hi.z {
                for y in lo.y..=hi.y {
                    for x in lo.x..=hi.x {
                        f(frame.key(UVec3::new(x, y, z)));
                    }
                }
            }
        };
        let dense = slots.is_none() && frame.voxels() <= DENSE_MAX_VOXELS;
        let (items, entries) = if dense {
            // Counting sort: counts per key, their prefix sums, then the items in order.
            let voxels = frame.voxels() as usize;
            crate::error::check_memory(voxels.saturating_mul(8), "voxels")?;
            let mut starts = vec![0u32; voxels + 1];
            for i in 0..n {
                each(i, &mut |k| starts[k as usize + 1] += 1);
            }
            for k in 0..voxels {
                starts[k + 1] += starts[k];
            }
            let mut fill = starts.clone();
            let mut items = vec![0u32; starts[voxels] as usize];
            for i in 0..n {
                each(i, &mut |k| {
                    items[fill[k as usize] as usize] = i as u32;
                    fill[k as usize] += 1;
                });
            }
            let entries = (0..voxels)
                .filter(|&k| starts[k + 1] > starts[k])
                .map(|k| Entry {
                    voxel: frame.coords(k as u64),
                    start: starts[k],
                    end: starts[k + 1],
                })
                .collect();
            (items, entries)
        } else {
            // Too many voxels to count densely: sort (key, item) pairs instead.
            let mut pairs = Vec::new();
            for i in 0..n {
                each(i, &mut |k| pairs.push((k, i as u32)));
            }
            pairs.sort_unstable();
            let mut entries: Vec<Entry> = Vec::new();
            for (j, &(k, _)) in pairs.iter().enumerate() {
                match entries.last_mut() {
                    Some(e) if frame.key(e.voxel) == k => e.end = j as u32 + 1,
                    _ => entries.push(Entry {
                        voxel: frame.coords(k),
                        start: j as u32,
                        end: j as u32 + 1,
                    }),
                }
            }
            (pairs.into_iter().map(|(_, i)| i).collect(), entries)
        };
        let table = if dense {
            let mut map = vec![u32::MAX; frame.voxels() as usize];
            for (e, entry) in entries.iter().enumerate() {
                map[frame.key(entry.voxel) as usize] = e as u32;
            }
            Table::Dense(map)
        } else {
            let t = slots.unwrap_or((entries.len() as u32).max(1));
            // Counting sort of the entries by slot.
            let mut starts = vec![0u32; t as usize + 1];
            for e in &entries {
                starts[(frame.key(e.voxel) % t as u64) as usize + 1] += 1;
            }
            for s in 0..t as usize {
                starts[s + 1] += starts[s];
            }
            let mut fill = starts.clone();
            let mut order = vec![0u32; entries.len()];
            for (j, e) in entries.iter().enumerate() {
                let s = (frame.key(e.voxel) % t as u64) as usize;
                order[fill[s] as usize] = j as u32;
                fill[s] += 1;
            }
            Table::Hashed {
                slots: t,
                starts,
                order,
            }
        };
        Ok(Self {
            frame,
            items,
            entries,
            table,
        })
    }

    /// Whether entries are found through the hashed table.
    pub fn is_hashed(&self) -> bool {
        matches!(self.table, Table::Hashed { .. })
    }

    /// The entry of voxel `v` (an index into [`Self::entries`]), `None` when empty.
    #[inline]
    pub fn entry(&self, v: UVec3) -> Option<usize> {
        let key = self.frame.key(v);
        match &self.table {
            Table::Dense(map) => match map[key as usize] {
                u32::MAX => None,
                e => Some(e as usize),
            },
            Table::Hashed {
                slots,
                starts,
                order,
            } => {
                let s = (key % *slots as u64) as usize;
                order[starts[s] as usize..starts[s + 1] as usize]
                    .iter()
                    .map(|&e| e as usize)
                    .find(|&e| self.entries[e].voxel == v)
            }
        }
    }

    /// The entry of the voxel with key `key`.
    #[inline]
    pub fn entry_of_key(&self, key: u64) -> Option<usize> {
        if key >= self.frame.voxels() {
            return None;
        }
        self.entry(self.frame.coords(key))
    }

    /// The items of voxel `v` (empty for an empty voxel).
    #[inline]
    pub fn get(&self, v: UVec3) -> &[u32] {
        match self.entry(v) {
            Some(e) => self.range(e),
            None => &[],
        }
    }

    /// The items of entry `e`.
    #[inline]
    pub fn range(&self, e: usize) -> &[u32] {
        let en = &self.entries[e];
        &self.items[en.start as usize..en.end as usize]
    }
}

/// A disc of [`super::proxies`]: centre, unit normal, radius (world units).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Disc {
    pub centre: Vec3,
    pub normal: Vec3,
    pub radius: f32,
}

impl Disc {
    /// Half the sides of the disc's bounding box: `r √(1 - n_i²)` per axis, grown by a
    /// part in 1e4 of the radius (and the centre's rounding) so that a hit point rounded
    /// onto a voxel face finds the disc on either side.
    pub fn half_extent(&self) -> Vec3 {
        let n2 = self.normal * self.normal;
        let e = (Vec3::ONE - n2).max(Vec3::ZERO).powf(0.5) * self.radius;
        e + Vec3::splat(self.radius * 1e-4 + self.centre.abs().max_element() * 1e-6)
    }
}

/// The box that holds every disc whole (and `base`): a grid over it meets every hit.
pub fn disc_bounds(base: Bounds, discs: &[Disc]) -> Bounds {
    let mut b = base;
    for d in discs {
        let e = d.half_extent();
        b.min = b.min.min(d.centre - e);
        b.max = b.max.max(d.centre + e);
    }
    b
}

/// The discs' index: every disc in every voxel its box touches.
pub fn index_discs(frame: GridFrame, discs: &[Disc], slots: Option<u32>) -> Result<VoxelIndex> {
    VoxelIndex::build(
        frame,
        discs.len(),
        |i| {
            let e = discs[i].half_extent();
            (
                frame.voxel_of(discs[i].centre - e),
                frame.voxel_of(discs[i].centre + e),
            )
        },
        slots,
    )
}

/// The points' index: each point in the voxel that holds it.
pub fn index_points(frame: GridFrame, points: &[Vec3], slots: Option<u32>) -> Result<VoxelIndex> {
    VoxelIndex::build(
        frame,
        points.len(),
        |i| {
            let v = frame.voxel_of(points[i]);
            (v, v)
        },
        slots,
    )
}
