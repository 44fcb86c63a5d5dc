//! The cache's interpolated visibility at one shading point, `Ṽ = Σ β_i V_i` over a
//! lookup's kept records and weights (CAM08 §3, eq. 2 and §5.1), with its integral `J`
//! against the point's product ([`integral`]). The control variate
//! (`estimators::control_variate`), the preview, the relighter and the renderer read it.

use glam::{DVec2, UVec2};

use crate::lights::envmap::product::ProductDistribution;
use crate::lights::envmap::EnvMap;
use crate::sampling::distribution::QuadPyramid;
use crate::sampling::octahedral::morton_encode;
use crate::visibility::record::VisibilityView;

use super::{CacheState, Lookup};

pub mod integral;
mod masked_sum;
#[cfg(test)]
pub(crate) mod tests;

pub use integral::{region_level, ControlTables};
use masked_sum::{word_sum, WordWeights};

/// Largest `α` an estimate of the control variate's coefficient may take (CAM08 eq. 4–5;
/// `estimators::control_variate` and the coherence check, [`super::coherence`]).
pub const ALPHA_MAX: f64 = 2.0;

/// The cache's part of one shading point: the kept records, their `β`, and `J`.
///
/// Invariant: `len <= ids.len()`, `Σ beta = 1` over the first `len` entries when `len > 0`.
#[derive(Clone, Copy, Debug)]
pub struct Interpolant {
    len: usize,
    ids: [u32; MAX_KEPT],
    beta: [f32; MAX_KEPT],
    /// `J = Σ β_i J_i` per channel (0 without records).
    pub j: [f64; 3],
    /// `∫ L B~ dω` unoccluded (luminance): `g_c/p = κ_c(ω) · unoccluded · Ṽ(ω)` for
    /// every product sample.
    pub unoccluded: f64,
    /// Level of the colour regions `κ` is read at ([`region_level`]).
    pub region_level: u32,
    /// `Ṽ` on the map's peaks, where [`Self::with_sun`] set it (else the records').
    pub sun: Option<f64>,
}

/// Most records an interpolant keeps (the cache's `n_keep` cap).
pub const MAX_KEPT: usize = crate::visibility::params::MAX_KEEP_COUNT as usize;

impl Interpolant {
    /// No records: `Ṽ = 0`, `J = 0` (plain product sampling).
    pub const EMPTY: Self = Self {
        len: 0,
        ids: [0; MAX_KEPT],
        beta: [0.0; MAX_KEPT],
        j: [0.0; 3],
        unoccluded: 0.0,
        region_level: 0,
        sun: None,
    };

    /// The interpolant of `lookup`, with `J = Σ β_i J_i` integrated against `tables` for
    /// the point's `product` under `env` (`None`: the point has no product, nothing to
    /// integrate, `J = 0`).
    pub fn new(
        state: &CacheState,
        lookup: &Lookup,
        tables: Option<(&ControlTables, &ProductDistribution, &EnvMap)>,
    ) -> Self {
        let mut out = Self::EMPTY;
        for k in lookup.neighbours() {
            out.ids[out.len] = k.id;
            out.beta[out.len] = k.beta;
            out.len += 1;
        }
        if let Some((tables, product, env)) = tables {
            out.unoccluded = tables.total_luminance();
            out.region_level = tables.region_level();
            let store = state.store();
            let maps: [VisibilityView; MAX_KEPT] =
                std::array::from_fn(|i| store.bits(out.ids[i.min(out.len.max(1) - 1)] as usize));
            out.j =
                tables.interpolated_integral(&maps[..out.len], &out.beta[..out.len], product, env);
        }
        out
    }

    /// The interpolant with `Ṽ = sun` on the map's peak texels (the shadow ray of the
    /// shading point toward [`MapChroma::sun`](crate::lights::envmap::chroma::MapChroma::sun), 0 or 1) instead of the records' blend there,
    /// and `J` changed to match ([`ControlTables::sun_change`], exact as `J` is). The records
    /// each give the sun one texel whose single ray passes up to a texel's width beside it,
    /// so near a shadow's edge their blend misjudges the sun that carries most of a daylight
    /// map's power; the point's own ray does not. `sun` depends on the point alone, not on
    /// the samples, so the estimate stays unbiased. `tables` and `product` must be the ones
    /// `J` was integrated with. Without records (`J = 0`, plain product sampling) nothing
    /// changes.
    pub fn with_sun(
        mut self,
        state: &CacheState,
        tables: &ControlTables,
        product: &ProductDistribution,
        sun: f64,
    ) -> Self {
        if self.len == 0 {
            return self;
        }
        let change = tables.sun_change(product, |texel| self.eval_texel(state, texel).0, sun);
        self.j = std::array::from_fn(|k| self.j[k] + change[k]);
        self.sun = Some(sun);
        self
    }

    /// `Ṽ` over each cell of octahedral level `level` (Morton order): per cell, the `β`-
    /// weighted share of its record texels that the kept records see, in `[0, 1]`. What
    /// [`ProductDistribution::guided`] samples by.
    pub fn cell_visibility(&self, state: &CacheState, level: u32) -> Vec<f32> {
        let mut out = vec![0.0f32; 1 << (2 * level)];
        for (&id, &beta) in self.ids().iter().zip(self.betas()) {
            add_record_cells(state, id, beta, level, &mut out);
        }
        for v in &mut out {
            *v = v.min(1.0);
        }
        out
    }

    /// Each kept record's visibility averaged over octahedral cells weighted by `cells`
    /// (a pyramid of non-negative weights with a positive sum, its finest level the cells):
    /// `(β_i, E_w[V_i])`, heaviest record first. Their spread around `Ṽ`'s own average says
    /// how much the records that `Ṽ` blends disagree there.
    pub fn record_averages(&self, state: &CacheState, cells: &QuadPyramid) -> Vec<(f32, f64)> {
        let store = state.store();
        let texels = TexelWeights::new(cells, store.m());
        self.ids()
            .iter()
            .zip(self.betas())
            .map(|(&id, &beta)| (beta, texels.visible(store.bits(id as usize).bit_words())))
            .collect()
    }

    /// Record ids, heaviest first.
    pub fn ids(&self) -> &[u32] {
        &self.ids[..self.len]
    }

    /// Their weights `β`.
    pub fn betas(&self) -> &[f32] {
        &self.beta[..self.len]
    }

    /// Whether the point found no record.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// `Ṽ` at the record texel containing square point `square ∈ [0,1)²`, as `Σ β_i V_i`,
    /// and the record bits (bit `i` set when record `i` sees the direction).
    #[inline]
    pub fn eval(&self, state: &CacheState, square: DVec2) -> (f64, u32) {
        if self.len == 0 {
            return (0.0, 0);
        }
        self.eval_texel(state, record_texel_code(square, state.store().m()))
    }

    /// [`Self::eval`] at record texel `texel` (Morton code at the records' level).
    #[inline]
    pub fn eval_texel(&self, state: &CacheState, texel: u32) -> (f64, u32) {
        let store = state.store();
        let (mut v, mut mask) = (0.0f64, 0u32);
        for i in 0..self.len {
            if store.bits(self.ids[i] as usize).get(texel as usize) {
                v += self.beta[i] as f64;
                mask |= 1 << i;
            }
        }
        (v, mask)
    }
}

/// Cell weights spread over a record's texels, normalised to sum to one: a record's
/// weighted visibility is then the sum over its set bits. Records are mostly runs of
/// visible or blocked texels in Morton order, so most words are all ones (the word's total)
/// or all zeros (nothing); a mixed word takes the masked sum of CAM08 §5.5's `J`.
struct TexelWeights {
    /// Per texel, zero-padded to whole words.
    texel: Vec<f64>,
    word_total: Vec<f64>,
    /// The bits of a word that are texels (all but for `m < 3`).
    valid: u64,
}

impl TexelWeights {
    /// From the weights of `cells`' finest level over the texels of `4^m`-texel records:
    /// cells finer than the texels weigh as their sums (the pyramid's level `m`).
    fn new(cells: &QuadPyramid, m: u32) -> Self {
        let level = cells.depth().min(m);
        let cell_weights = cells.level(level);
        let total = cells.total();
        let scale = if total > 0.0 { 1.0 / total } else { 0.0 };
        // A cell covers 4^(m - level) texels, a Morton range, which share its weight.
        let shift = 2 * (m - level);
        let each = scale / (1u64 << shift) as f64;
        let mut texel: Vec<f64> = (0..1usize << (2 * m))
            .map(|t| cell_weights[t >> shift] * each)
            .collect();
        let bits = texel.len().min(64);
        texel.resize(texel.len().max(64), 0.0);
        let word_total = texel.chunks(64).map(|w| w.iter().sum()).collect();
        let valid = if bits == 64 {
            u64::MAX
        } else {
            (1u64 << bits) - 1
        };
        Self {
            texel,
            word_total,
            valid,
        }
    }

    /// The summed weight of the texels whose bits are set in `words`, in `[0, 1]`.
    fn visible(&self, words: &[u64]) -> f64 {
        let mut scratch = [0.0f64; 64];
        let mut sum = 0.0;
        for (k, &word) in words.iter().enumerate() {
            let word = word & self.valid;
            sum += match word {
                0 => continue,
                w if w == self.valid => self.word_total[k],
                w => {
                    let weights = self.texel[64 * k..64 * k + 64].try_into().expect("a word");
                    word_sum(w, WordWeights::Given(weights), &mut scratch)
                }
            };
        }
        sum.clamp(0.0, 1.0)
    }
}

/// Adds `beta` times record `id`'s visible share of each cell of octahedral level `level`
/// (Morton order) to `out`.
fn add_record_cells(state: &CacheState, id: u32, beta: f32, level: u32, out: &mut [f32]) {
    let store = state.store();
    let m = store.m();
    let words = store.bits(id as usize).bit_words();
    if m <= level {
        // Each record texel covers 4^(level - m) cells.
        let shift = 2 * (level - m);
        for (w, &word) in words.iter().enumerate() {
            let mut x = word;
            while x != 0 {
                let texel = 64 * w + x.trailing_zeros() as usize;
                x &= x - 1;
                let first = texel << shift;
                for v in &mut out[first..first + (1 << shift)] {
                    *v += beta;
                }
            }
        }
    } else {
        // Each cell covers 4^(m - level) record texels, a Morton range.
        let per_cell = 1usize << (2 * (m - level));
        let share = beta / per_cell as f32;
        match per_cell {
            // A word holds 16 or 4 cells: their counts side by side in one register
            // (SWAR), a word with no visible texel skipped. The same sums as below.
            4 | 16 => {
                // Each cell's count sits in a field `per_cell` bits wide.
                let cells = 64 / per_cell;
                let mask = (1u64 << per_cell) - 1;
                for (w, &word) in words.iter().enumerate() {
                    if word == 0 {
                        continue;
                    }
                    let counts = if per_cell == 4 {
                        nibble_counts(word)
                    } else {
                        let bytes = nibble_counts(word);
                        let bytes = (bytes + (bytes >> 4)) & 0x0f0f_0f0f_0f0f_0f0f;
                        (bytes + (bytes >> 8)) & 0x00ff_00ff_00ff_00ff
                    };
                    for (k, v) in out[w * cells..(w + 1) * cells].iter_mut().enumerate() {
                        *v += share * ((counts >> (k * per_cell)) & mask) as f32;
                    }
                }
            }
            _ => {
                for (c, v) in out.iter_mut().enumerate() {
                    let visible = count_bits(words, c * per_cell, per_cell);
                    *v += share * visible as f32;
                }
            }
        }
    }
}

/// The set bits of each 4-bit group of `x`, in that group.
#[inline]
fn nibble_counts(x: u64) -> u64 {
    let pairs = x - ((x >> 1) & 0x5555_5555_5555_5555);
    (pairs & 0x3333_3333_3333_3333) + ((pairs >> 2) & 0x3333_3333_3333_3333)
}

/// Set bits among bits `start .. start + len` of `words` (`len` a power of two, `start` a
/// multiple of it).
#[inline]
fn count_bits(words: &[u64], start: usize, len: usize) -> u32 {
    if len >= 64 {
        words[start / 64..(start + len) / 64]
            .iter()
            .map(|w| w.count_ones())
            .sum()
    } else {
        let mask = (1u64 << len) - 1;
        ((words[start / 64] >> (start % 64)) & mask).count_ones()
    }
}

/// Morton code of the texel of a `2^m` grid containing square point `p ∈ [0,1)²`.
#[inline]
pub fn record_texel_code(p: DVec2, m: u32) -> u32 {
    let r = (1u32 << m) as f64;
    let max = (1u32 << m) - 1;
    let t = UVec2::new(((p.x * r) as u32).min(max), ((p.y * r) as u32).min(max));
    morton_encode(t.x, t.y)
}
