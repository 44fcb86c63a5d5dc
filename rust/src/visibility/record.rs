//! Visibility cache records (CAM08 §5.5, eq. 10–12, Fig. 9; §6.1).
//!
//! ## The visibility map (eq. 10)
//! A record's visibility is a `2^M x 2^M` binary image over Clarberg's equal-area octahedral
//! map of the sphere (`M` in `1..=7`, default 5: 32 x 32), one bit per texel, `1` where the
//! direction through the texel's pattern sample ([`crate::sampling::pattern`]) is
//! unoccluded. Bits are stored in Morton order (eq. 10: `z = (y_{M-1} x_{M-1} … y_0 x_0)_2`,
//! x on the even bits), bit `z` in bit `z % 64` of `u64` word `z / 64`; a quadtree node of
//! level `l` is the contiguous run of `4^(M-l)` bits [`quadtree_range`] gives. Maps smaller
//! than a word (`M <= 2`) use its low `4^M` bits; the others are always zero.
//!
//! ## The hierarchy (Fig. 9)
//! Above the bits, a 2-bit [`Coverage`] code per quadtree node of levels `0..=W`, where
//! `W = max(M, 3) - 3` is the level whose nodes are exactly one word (8 x 8 texels) — below
//! it the bits themselves answer with one mask test. Codes are stored level after level
//! (node `j` of level `l` at code index `(4^l - 1) / 3 + j`, bits `2k..2k+2` of the codes'
//! words). A code's bit 0 says "some direction is visible" and bit 1 "some direction is
//! occluded", so a parent's code is the OR of its children's.
//!
//! ## Mean difference (eq. 11)
//! `δ_ij = popcount(V_i xor V_j) / 4^M`, by the fastest form of the count this CPU has
//! (`difference.rs`: AVX-512 `vpopcntq`, AVX2, `popcnt` or portable, chosen at run time).
//!
//! ## Ambient occlusion (eq. 12) and `R_i` (§6.1)
//! `A = ∫_Ω V (n·ω) dω / π` from the record's own rays: with equal-solid-angle samples
//! `ω_i`, `A = Σ V_i max(0, n·ω_i) / Σ max(0, n·ω_i)` — the ratio normalises with the same
//! samples, so an open record has `A = 1` and a closed one `A = 0` exactly. `R_i` is the
//! distance to the nearest surface any of the record's rays hits (`inf` if none).
//!
//! ## Memory: the packed layout
//! A [`RecordStore`] keeps every record of one resolution as a 36-byte [`RecordHeader`] plus
//! `words_per_map(M)` `u64` words (bits, then hierarchy codes) in two flat arrays — no
//! per-record pointers or allocations. Bytes per record ([`bytes_per_record`]):
//!
//! | M | grid      | bits (B) | hierarchy (levels, nodes, B) | header (B) | total (B) |
//! |---|-----------|----------|------------------------------|------------|-----------|
//! | 1 | 2 x 2     | 8        | 0, 1, 8                      | 36         | 52        |
//! | 2 | 4 x 4     | 8        | 0, 1, 8                      | 36         | 52        |
//! | 3 | 8 x 8     | 8        | 0, 1, 8                      | 36         | 52        |
//! | 4 | 16 x 16   | 32       | 0–1, 5, 8                    | 36         | 76        |
//! | 5 | 32 x 32   | 128      | 0–2, 21, 8                   | 36         | **172**   |
//! | 6 | 64 x 64   | 512      | 0–3, 85, 24                  | 36         | 572       |
//! | 7 | 128 x 128 | 2048     | 0–4, 341, 88                 | 36         | 2172      |
//!
//! At 32 x 32 that is CAM08's 172 bytes. The header ([`RecordHeader`], `repr(C)`, align 4):
//! position `3 x f32` (12 B), normal as two `u16` equal-area square coordinates (4 B, error
//! below 1e-4 rad), `R_i` `f32` (4 B), misses / uses / last frame `u32` (12 B), `A` as
//! `u16` in units of 1/65535 (2 B), 2 B reserved. The unpacked [`Record`] that
//! [`Record::trace`] returns holds the same fields in `f32`/`Vec3` and its bits in a boxed
//! slice; it is the exchange form, the store the resident one.
//!
//! Files: `store.rs` (the packed [`RecordStore`]), `emitter_stop.rs` (records that see area
//! lights), `difference.rs` (eq. 11's count per instruction set).

use glam::{UVec2, Vec2, Vec3};

use crate::error::{Error, Result};
use crate::geometry::{RayBatch, Scene, TMax, TraversalCounters};
use crate::sampling::octahedral::{
    morton_encode, quadtree_range, sphere_to_square, square_to_sphere,
};
use crate::sampling::pattern::check_log2_resolution;

mod difference;
mod emitter_stop;
mod store;

use difference::xor_popcount;

pub use store::{RecordHeader, RecordStore};

/// Number of `u64` words holding the `4^m` bits of a map (at least one).
pub const fn bit_words(m: u32) -> usize {
    let bits = 1usize << (2 * m);
    if bits < 64 {
        1
    } else {
        bits / 64
    }
}

/// The finest hierarchy level with a stored code: `max(m, 3) - 3`, whose nodes are one word
/// each (for `m >= 3`).
pub const fn word_level(m: u32) -> u32 {
    m.saturating_sub(3)
}

/// Number of quadtree nodes with a stored code: levels `0..=word_level(m)`.
pub const fn hierarchy_nodes(m: u32) -> usize {
    ((1usize << (2 * (word_level(m) + 1))) - 1) / 3
}

/// Number of `u64` words holding the 2-bit codes of the hierarchy.
pub const fn hierarchy_words(m: u32) -> usize {
    (2 * hierarchy_nodes(m)).div_ceil(64)
}

/// `u64` words of one map: bits, then hierarchy codes.
pub const fn words_per_map(m: u32) -> usize {
    bit_words(m) + hierarchy_words(m)
}

/// Bytes one record of resolution `2^m x 2^m` occupies in a [`RecordStore`]: the 36-byte
/// header plus [`words_per_map`] words (table in the module docs; 172 at `m = 5`).
pub const fn bytes_per_record(m: u32) -> usize {
    std::mem::size_of::<RecordHeader>() + 8 * words_per_map(m)
}

/// Index of the first code of level `l` in the stored hierarchy: `(4^l - 1) / 3`.
const fn level_offset(level: u32) -> usize {
    ((1usize << (2 * level)) - 1) / 3
}

const SOME_VISIBLE: u8 = 0b01;
const SOME_OCCLUDED: u8 = 0b10;

/// How much of a quadtree node's solid angle is visible (CAM08 Fig. 9). The 2-bit codes are
/// `Full = 0b01` (some visible, none occluded), `Empty = 0b10` (none visible: fully
/// occluded), `Partial = 0b11`; a parent's code is the OR of its children's.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum Coverage {
    /// Every direction of the node is occluded (no bit set).
    Empty = SOME_OCCLUDED,
    /// Some directions are visible, some occluded.
    Partial = SOME_VISIBLE | SOME_OCCLUDED,
    /// Every direction of the node is visible (all bits set).
    Full = SOME_VISIBLE,
}

impl Coverage {
    #[inline]
    fn from_code(code: u8) -> Self {
        match code & 3 {
            SOME_OCCLUDED => Coverage::Empty,
            SOME_VISIBLE => Coverage::Full,
            _ => Coverage::Partial,
        }
    }

    /// The code of a run of bits: `bits` are the node's bits, `mask` has one bit per
    /// direction of the node.
    #[inline]
    fn code_of(bits: u64, mask: u64) -> u8 {
        ((bits & mask != 0) as u8 * SOME_VISIBLE) | ((bits & mask != mask) as u8 * SOME_OCCLUDED)
    }
}

/// Writes the hierarchy codes of `words` (bits then codes, resolution `m`) from its bits.
fn rebuild_hierarchy(m: u32, words: &mut [u64]) {
    let nb = bit_words(m);
    let (bits, codes) = words.split_at_mut(nb);
    codes.fill(0);
    let wl = word_level(m);
    let finest_mask = if m < 3 {
        (1u64 << (1 << (2 * m))) - 1
    } else {
        u64::MAX
    };
    for (j, w) in bits.iter().enumerate() {
        set_code(
            codes,
            level_offset(wl) + j,
            Coverage::code_of(*w, finest_mask),
        );
    }
    for level in (0..wl).rev() {
        for j in 0..1usize << (2 * level) {
            let c = (0..4).fold(0, |acc, k| {
                acc | get_code(codes, level_offset(level + 1) + 4 * j + k)
            });
            set_code(codes, level_offset(level) + j, c);
        }
    }
}

#[inline]
fn get_code(codes: &[u64], k: usize) -> u8 {
    ((codes[k / 32] >> (2 * (k % 32))) & 3) as u8
}

#[inline]
fn set_code(codes: &mut [u64], k: usize, code: u8) {
    let shift = 2 * (k % 32);
    codes[k / 32] = (codes[k / 32] & !(3u64 << shift)) | ((code as u64) << shift);
}

/// A borrowed visibility map: `4^m` bits in Morton order plus their hierarchy codes, as
/// laid out in the module docs. All read-only queries live here, so maps owned by a
/// [`VisibilityBits`] and maps packed in a [`RecordStore`] answer alike.
///
/// Invariant: `words.len() == words_per_map(m)`, unused bits of a sub-word map are zero, and
/// the codes match the bits.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct VisibilityView<'a> {
    m: u32,
    words: &'a [u64],
}

impl<'a> VisibilityView<'a> {
    /// Resolution exponent `M` (the grid is `2^M x 2^M`).
    #[inline]
    pub fn m(&self) -> u32 {
        self.m
    }

    /// Grid side `2^M`, in texels.
    #[inline]
    pub fn resolution(&self) -> u32 {
        1 << self.m
    }

    /// Number of directions (bits), `4^M`.
    #[inline]
    pub fn len(&self) -> usize {
        1 << (2 * self.m)
    }

    /// Never true: a map has at least 4 bits. (For API symmetry with `len`.)
    #[inline]
    pub fn is_empty(&self) -> bool {
        false
    }

    /// The bit words, Morton order (bit `z` is bit `z % 64` of word `z / 64`).
    #[inline]
    pub fn bit_words(&self) -> &'a [u64] {
        &self.words[..bit_words(self.m)]
    }

    /// The words of the 2-bit hierarchy codes (module docs for the layout).
    #[inline]
    pub fn hierarchy_words(&self) -> &'a [u64] {
        &self.words[bit_words(self.m)..]
    }

    /// All words: bits then codes (the packed form).
    #[inline]
    pub fn words(&self) -> &'a [u64] {
        self.words
    }

    /// Visibility of direction `z` (Morton index, `< 4^M`): `true` = unoccluded.
    #[inline]
    pub fn get(&self, z: usize) -> bool {
        debug_assert!(z < self.len());
        (self.words[z / 64] >> (z % 64)) & 1 != 0
    }

    /// Visibility of texel `(x, y)` of the `2^M x 2^M` grid.
    #[inline]
    pub fn get_texel(&self, texel: UVec2) -> bool {
        self.get(morton_encode(texel.x, texel.y) as usize)
    }

    /// Number of unoccluded directions.
    #[inline]
    pub fn popcount(&self) -> u32 {
        self.bit_words().iter().map(|w| w.count_ones()).sum()
    }

    /// Fraction of the sphere's solid angle that is unoccluded, `popcount / 4^M`.
    #[inline]
    pub fn visible_fraction(&self) -> f32 {
        self.popcount() as f32 / self.len() as f32
    }

    /// Number of directions whose visibility differs, `popcount(self xor other)`.
    /// Both maps must have the same resolution (panics otherwise).
    #[inline]
    pub fn xor_popcount(&self, other: &VisibilityView) -> u32 {
        assert_eq!(self.m, other.m, "maps of different resolutions");
        xor_popcount(self.bit_words(), other.bit_words())
    }

    /// CAM08 eq. 11: the mean difference `δ = popcount(self xor other) / 4^M` in `[0, 1]`,
    /// the probability that a random direction has different visibility in the two maps.
    /// Both maps must have the same resolution (panics otherwise).
    #[inline]
    pub fn difference(&self, other: &VisibilityView) -> f32 {
        // 4^-M exactly, built from its exponent: a multiply instead of a division, with the
        // same result since the divisor is a power of two.
        let inv_len = f32::from_bits((127 - 2 * self.m) << 23);
        self.xor_popcount(other) as f32 * inv_len
    }

    /// Coverage of node `node` (Morton index, `< 4^level`) of quadtree level `level`
    /// (`0..=M`; level `M` nodes are single directions). Levels up to `word_level(M)` read
    /// the stored codes, finer ones one mask test on a word.
    #[inline]
    pub fn coverage(&self, level: u32, node: u32) -> Coverage {
        debug_assert!(level <= self.m && (node as u64) < (1u64 << (2 * level)));
        let wl = word_level(self.m);
        if level <= wl {
            let k = level_offset(level) + node as usize;
            return Coverage::from_code(get_code(self.hierarchy_words(), k));
        }
        let (start, end) = quadtree_range(level, node, self.m);
        let n = end - start;
        let mask = (1u64 << n) - 1; // n <= 16 here
        let bits = self.words[(start / 64) as usize] >> (start % 64);
        Coverage::from_code(Coverage::code_of(bits, mask))
    }

    /// Pre-order walk of the quadtree that skips `Empty` nodes and does not descend into
    /// `Full` ones: yields every non-empty node whose ancestors are all `Partial`, children
    /// in Morton order. The `Full` nodes it yields tile the visible directions exactly, which
    /// is how J is integrated (CAM08 §5.5).
    pub fn nodes(&self) -> NodeIter<'a> {
        let mut it = NodeIter {
            view: *self,
            stack: [(0, 0); NODE_STACK],
            len: 0,
        };
        it.push(0, 0);
        it
    }
}

/// Depth of [`NodeIter`]'s stack: at most three pending siblings per level plus one.
const NODE_STACK: usize = 1 + 3 * MAX_LEVELS;
const MAX_LEVELS: usize = crate::sampling::pattern::MAX_LOG2_RESOLUTION as usize + 1;

/// A quadtree node of a visibility map: level `0..=M`, Morton index within the level and
/// coverage.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Node {
    /// Quadtree level: 0 is the whole sphere, `M` single directions.
    pub level: u32,
    /// Morton index within the level, `< 4^level`.
    pub index: u32,
    /// Empty / partial / full.
    pub coverage: Coverage,
}

impl Node {
    /// The Morton range `[start, end)` of directions (bits) of a `2^m` map that the node
    /// covers.
    pub fn range(&self, m: u32) -> (u64, u64) {
        quadtree_range(self.level, self.index, m)
    }
}

/// Iterator of [`VisibilityView::nodes`]; allocation-free.
#[derive(Clone, Debug)]
pub struct NodeIter<'a> {
    view: VisibilityView<'a>,
    stack: [(u8, u32); NODE_STACK],
    len: usize,
}

impl NodeIter<'_> {
    #[inline]
    fn push(&mut self, level: u32, index: u32) {
        self.stack[self.len] = (level as u8, index);
        self.len += 1;
    }
}

impl Iterator for NodeIter<'_> {
    type Item = Node;

    fn next(&mut self) -> Option<Node> {
        while self.len > 0 {
            self.len -= 1;
            let (level, index) = self.stack[self.len];
            let level = level as u32;
            let coverage = self.view.coverage(level, index);
            if coverage == Coverage::Empty {
                continue;
            }
            if coverage == Coverage::Partial {
                for k in (0..4).rev() {
                    self.push(level + 1, 4 * index + k);
                }
            }
            return Some(Node {
                level,
                index,
                coverage,
            });
        }
        None
    }
}

/// An owned visibility map (module docs): `4^M` bits in Morton order, 1 = unoccluded, and
/// their 2-bit hierarchy, kept consistent by every mutation.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct VisibilityBits {
    m: u32,
    words: Box<[u64]>,
}

impl VisibilityBits {
    /// A map of `4^m` directions, all occluded. Fails for `m` outside `1..=7`.
    pub fn new(m: u32) -> Result<Self> {
        check_log2_resolution(m)?;
        let mut words = vec![0u64; words_per_map(m)].into_boxed_slice();
        rebuild_hierarchy(m, &mut words);
        Ok(Self { m, words })
    }

    /// A map whose bit `z` is `visible(z)`, for `z` in Morton order.
    pub fn from_fn(m: u32, mut visible: impl FnMut(usize) -> bool) -> Result<Self> {
        check_log2_resolution(m)?;
        let mut words = vec![0u64; words_per_map(m)].into_boxed_slice();
        for z in 0..1usize << (2 * m) {
            words[z / 64] |= (visible(z) as u64) << (z % 64);
        }
        rebuild_hierarchy(m, &mut words);
        Ok(Self { m, words })
    }

    /// A map from its bit words (`bit_words(m)` of them, Morton order); builds the
    /// hierarchy. Fails on a wrong count or on set bits beyond `4^m` (maps below 64 bits).
    pub fn from_bit_words(m: u32, bits: &[u64]) -> Result<Self> {
        check_log2_resolution(m)?;
        if bits.len() != bit_words(m) {
            return Err(Error::invalid(
                "bits",
                format!(
                    "need {} words for m = {m}, got {}",
                    bit_words(m),
                    bits.len()
                ),
            ));
        }
        if m < 3 && bits[0] >> (1 << (2 * m)) != 0 {
            return Err(Error::invalid(
                "bits",
                format!(
                    "bits beyond the {} directions of m = {m} are set",
                    1 << (2 * m)
                ),
            ));
        }
        let mut words = vec![0u64; words_per_map(m)].into_boxed_slice();
        words[..bits.len()].copy_from_slice(bits);
        rebuild_hierarchy(m, &mut words);
        Ok(Self { m, words })
    }

    /// The read-only view (all queries).
    #[inline]
    pub fn view(&self) -> VisibilityView<'_> {
        VisibilityView {
            m: self.m,
            words: &self.words,
        }
    }

    /// Resolution exponent `M`.
    #[inline]
    pub fn m(&self) -> u32 {
        self.m
    }

    /// Visibility of direction `z` (Morton order); see [`VisibilityView::get`].
    #[inline]
    pub fn get(&self, z: usize) -> bool {
        self.view().get(z)
    }

    /// Number of unoccluded directions.
    #[inline]
    pub fn popcount(&self) -> u32 {
        self.view().popcount()
    }

    /// CAM08 eq. 11, `popcount(self xor other) / 4^M`; see [`VisibilityView::difference`].
    #[inline]
    pub fn difference(&self, other: &VisibilityBits) -> f32 {
        self.view().difference(&other.view())
    }

    /// Coverage of a quadtree node; see [`VisibilityView::coverage`].
    #[inline]
    pub fn coverage(&self, level: u32, node: u32) -> Coverage {
        self.view().coverage(level, node)
    }

    /// Sets direction `z` (Morton order, `< 4^M`) to visible or occluded and updates the
    /// codes of its ancestors (`word_level(M) + 1` codes).
    pub fn set(&mut self, z: usize, visible: bool) {
        assert!(z < 1 << (2 * self.m), "direction {z} out of range");
        let bit = 1u64 << (z % 64);
        let w = z / 64;
        if visible {
            self.words[w] |= bit;
        } else {
            self.words[w] &= !bit;
        }
        let m = self.m;
        let wl = word_level(m);
        let finest_mask = if m < 3 {
            (1u64 << (1 << (2 * m))) - 1
        } else {
            u64::MAX
        };
        let word = self.words[w];
        let codes = &mut self.words[bit_words(m)..];
        set_code(
            codes,
            level_offset(wl) + w,
            Coverage::code_of(word, finest_mask),
        );
        let mut node = w;
        for level in (0..wl).rev() {
            node /= 4;
            let first = level_offset(level + 1) + 4 * node;
            let c = (0..4).fold(0, |acc, k| acc | get_code(codes, first + k));
            set_code(codes, level_offset(level) + node, c);
        }
    }
}

/// How [`Record::trace_as`] traces a record's rays.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RecordTracing {
    /// Find `R_i` with closest-hit rays on the occluded directions ([`Record::trace`]).
    pub nearest_hits: bool,
    /// Count a direction as unoccluded when its ray reaches an area light before anything
    /// else (`emitter_stop`): the record then holds the visibility of the scene's lights
    /// as well as the sky's, as the relighter needs for area lights. Off, a light's own
    /// triangles occlude like any surface, which is the sky's visibility alone.
    pub emitters_visible: bool,
}

/// Rays one [`Record::trace`] cast.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RecordRays {
    /// Shadow rays: the pattern directions above the tangent plane.
    pub shadow: u32,
    /// Closest-hit rays cast to find `R_i` (at most the occluded shadow rays).
    pub nearest: u32,
}

/// A visibility cache record, unpacked (CAM08 §5, §6.1). See [`RecordStore`] for the
/// 172-byte resident form.
#[derive(Clone, Debug, PartialEq)]
pub struct Record {
    /// The surface point, world units.
    pub position: Vec3,
    /// Unit surface normal (the side rays leave toward).
    pub normal: Vec3,
    /// World-space visibility over the sphere, 1 = unoccluded; directions on or below the
    /// tangent plane are 0.
    pub bits: VisibilityBits,
    /// Ambient occlusion, CAM08 eq. 12 divided by π: cosine-weighted visible fraction of
    /// the hemisphere, in `[0, 1]` (1 = nothing occludes).
    pub ambient_occlusion: f32,
    /// `R_i`: distance from the record to the nearest surface its rays hit, world units;
    /// `inf` when no ray hit anything.
    pub nearest_hit_distance: f32,
    /// Samples on which the record's visibility disagreed with a traced ray (CAM08 §5.3).
    pub misses: u32,
    /// Samples the record took part in (denominator of the miss rate).
    pub uses: u32,
    /// Last frame the record was used in (or created).
    pub last_frame: u32,
}

impl Record {
    /// Traces a record at `position` with unit-able `normal` over `pattern` (unit
    /// directions, Morton order, `4^M` of them for `M` in `1..=7`, e.g.
    /// [`crate::sampling::pattern::default_pattern`]).
    ///
    /// Directions with `normal · ω <= 0` are occluded by definition and not traced. The
    /// others leave from `scene.offset_point(position, normal)` as one contiguous same-origin
    /// run through [`Scene::occluded`] (which exploits such runs). `R_i` is found by
    /// closest-hit queries on the occluded rays only, in pattern order, each bounded by the
    /// nearest distance found so far — most are culled at the BVH's top once a close hit is
    /// known, and unoccluded rays need none. Counters on the scene count every ray.
    ///
    /// Counters start at `misses = uses = 0`, `last_frame = frame`. Fails on a non-finite
    /// position, a zero or non-finite normal, or a pattern of the wrong length.
    pub fn trace(
        scene: &Scene,
        position: Vec3,
        normal: Vec3,
        pattern: &[Vec3],
        frame: u32,
    ) -> Result<(Record, RecordRays)> {
        Self::trace_with(scene, position, normal, pattern, frame, true)
    }

    /// [`Self::trace`], finding `R_i` only when `nearest_hits` (else `R_i = inf` and no
    /// closest-hit ray is cast).
    pub fn trace_with(
        scene: &Scene,
        position: Vec3,
        normal: Vec3,
        pattern: &[Vec3],
        frame: u32,
        nearest_hits: bool,
    ) -> Result<(Record, RecordRays)> {
        let tracing = RecordTracing {
            nearest_hits,
            emitters_visible: false,
        };
        Self::trace_as(scene, position, normal, pattern, frame, tracing)
    }

    /// [`Self::trace`] as `tracing` says: with or without `R_i`, and with rays that reach
    /// an area light counted as unoccluded or not ([`RecordTracing`]).
    pub fn trace_as(
        scene: &Scene,
        position: Vec3,
        normal: Vec3,
        pattern: &[Vec3],
        frame: u32,
        tracing: RecordTracing,
    ) -> Result<(Record, RecordRays)> {
        let RecordTracing {
            nearest_hits,
            emitters_visible,
        } = tracing;
        let m = pattern_log2_resolution(pattern.len())?;
        if !position.is_finite() {
            return Err(Error::invalid(
                "position",
                format!("must be finite, got {position}"),
            ));
        }
        let len = normal.length();
        if !(len.is_finite() && len > 0.0) {
            return Err(Error::invalid(
                "normal",
                format!("must be finite and non-zero, got {normal}"),
            ));
        }
        let n = normal / len;
        let origin = scene.offset_point(position, n);
        let mut dirs: Vec<[f32; 3]> = Vec::with_capacity(pattern.len() / 2 + 1);
        let mut index: Vec<u32> = Vec::with_capacity(pattern.len() / 2 + 1);
        let mut cosines: Vec<f32> = Vec::with_capacity(pattern.len() / 2 + 1);
        for (z, d) in pattern.iter().enumerate() {
            let c = n.dot(*d);
            if c > 0.0 {
                dirs.push(d.to_array());
                index.push(z as u32);
                cosines.push(c);
            }
        }
        let origins = vec![origin.to_array(); dirs.len()];
        let lights = scene.area_lights();
        let tmax: Vec<f32>;
        let mut batch = RayBatch::new(&origins, &dirs);
        if emitters_visible && !lights.is_empty() {
            // Each ray stops short of the emitter plane it reaches (`emitter_stop`).
            let planes = emitter_stop::EmitterPlanes::new(lights);
            let slack = emitter_stop::texel_radius(m);
            tmax = dirs
                .iter()
                .map(|&d| {
                    let t = planes.distance(origin, d.into(), slack);
                    if t.is_finite() {
                        scene.segment_end(t, origin + Vec3::from(d) * t).max(0.0)
                    } else {
                        t
                    }
                })
                .collect();
            batch.tmax = TMax::PerRay(&tmax);
        }
        let occluded = scene.occluded(&batch, None)?;

        let mut bits = vec![0u64; bit_words(m)];
        let (mut visible_cos, mut total_cos) = (0.0f64, 0.0f64);
        let mut nearest = f32::INFINITY;
        let mut rays = RecordRays {
            shadow: dirs.len() as u32,
            nearest: 0,
        };
        let mut counters = TraversalCounters::default();
        for (k, &occ) in occluded.iter().enumerate() {
            total_cos += cosines[k] as f64;
            if occ {
                if nearest_hits {
                    rays.nearest += 1;
                    if let Some(hit) =
                        scene.intersect1(origin, Vec3::from(dirs[k]), nearest, &mut counters)
                    {
                        nearest = hit.t;
                    }
                }
            } else {
                let z = index[k] as usize;
                bits[z / 64] |= 1 << (z % 64);
                visible_cos += cosines[k] as f64;
            }
        }
        if scene.counting_enabled() {
            scene.add_counters(counters);
        }
        let ambient_occlusion = if total_cos > 0.0 {
            (visible_cos / total_cos) as f32
        } else {
            0.0
        };
        let record = Record {
            position,
            normal: n,
            bits: VisibilityBits::from_bit_words(m, &bits)?,
            ambient_occlusion,
            nearest_hit_distance: nearest,
            misses: 0,
            uses: 0,
            last_frame: frame,
        };
        Ok((record, rays))
    }

    /// Bytes this record occupies in a [`RecordStore`] ([`bytes_per_record`]; 172 at
    /// 32 x 32). The unpacked `Record` itself is larger (a boxed slice and `f32` fields).
    pub fn memory_bytes(&self) -> usize {
        bytes_per_record(self.bits.m())
    }
}

/// `M` of a pattern of `len` directions (`len = 4^M`, `M` in `1..=7`).
fn pattern_log2_resolution(len: usize) -> Result<u32> {
    let m = len.trailing_zeros() / 2;
    if len.is_power_of_two() && len == 1 << (2 * m) && check_log2_resolution(m).is_ok() {
        Ok(m)
    } else {
        Err(Error::invalid(
            "pattern",
            format!("must hold 4^M directions for M in 1..=7 (4 to 16384), got {len}"),
        ))
    }
}

#[cfg(test)]
mod tests;
