//! The visibility cache as a control variate (CAM08 §3, eq. 2–6; §5.5; §6.2).
//!
//! Product importance sampling draws `ω` with `p(ω) = L(ω) B~(ω) / L_ns` (CAM08 eq. 3, `L`
//! the map's luminance) and estimates `∫ L B V dω` by `L B V / p`. With the cache's
//! interpolated visibility `Ṽ = Σ β_i V_i` (a lookup's records and weights), the control
//! variate of channel `c` is `g_c(ω) = κ_c(ω) L(ω) B~(ω) Ṽ(ω)` with `κ_c(ω)` the colour of
//! the map's *region* holding `ω` (RGB over luminance of `∫ L_c` over the region; the
//! regions are the quadtree nodes one record word covers, 64 of them for 64² records, see
//! [`region_level`]). Its integral is `J_c = Σ_r κ_c(r) Σ_i β_i J_{i,r}`, and eq. 2 becomes
//!
//! `⟨L_o⟩ = (1/N) Σ [L B V / p − α g / p] + α J`, with `g_c / p = κ_c(ω) (∫ L B~ dω) Ṽ(ω)`,
//!
//! unbiased for any `α` and `κ` that do not depend on the samples they multiply. Using the
//! luminance `L B~` the sampler already holds times a colour per region (instead of
//! `L_c B~` per channel) makes `J` read the product's own pyramid, and costs the walk three
//! multiply-adds per word. One colour per *point* (what this module used before) is exact
//! only where the map's colour is uniform over what a point sees: under a yellow sun in a
//! blue sky it leaves the blue channel a residual `(L_b − κ_b L) B V / p` that no visibility
//! can cancel, and on `dynamics` the blue variance came out 1.3x plain product sampling's
//! (0.6x with a grey map). Per region, the sun's region takes the sun's colour and the sky's
//! the sky's.
//!
//! A region still mixes a sun with the sky around it: 64 regions are 25° across, and the
//! procedural daylight's sun, four texels of a 256² map, carries 58% of its power, so its
//! region's colour was the sun's and the blue sky beside it was scaled as yellow light.
//! The map's *peaks* ([`MapChroma::peaks`]: texels above
//! [`PEAK_FACTOR`](crate::lights::envmap::chroma::PEAK_FACTOR) times the mean, at most
//! [`MAX_PEAKS`](crate::lights::envmap::chroma::MAX_PEAKS)) therefore take their own colour, and each region the colour of its
//! other texels. `J` adds `Σ_peaks (κ_c(t) − κ_c(region)) L B~ Ṽ` over the peak texels to
//! the walk's sum (each lies inside one record texel and one product cell), so it stays
//! exact. On the meshes' ground (256x192, 32 spp) blue's variance ratio went from 0.29 to
//! 0.24 (red 0.13 to 0.12); 128² records, four times finer regions, give 0.23.
//!
//! ## Exactness of `J`
//! `L` is piecewise constant over the map's texels, `B~` over the product's cells and every
//! `V_i` over the record's texels, and all three grids are levels of one equal-area
//! octahedral quadtree. So `g` is piecewise constant on the finest of them and `J` is an
//! exact finite sum — there is no quadrature error for the control variate to leak into the
//! estimate. Each sample's `Ṽ` is read at the record texel that contains the *sampled point
//! of the square* (not a re-mapped direction), so `E[g/p] = J` holds to rounding.
//!
//! ## `J` by quadtree traversal (§5.5)
//! [`ControlTables::record_integral`] walks record `i`'s 2-bit hierarchy, skipping empty
//! nodes and stopping at full ones; a full node contributes its node of the product's
//! pyramid (nodes finer than the product's cells take the cell's `B~` times the map's own
//! pyramid), and a partial word the weights of its visible texels, summed under the
//! word as a bit mask (eight lanes at a time, the same bits on every CPU: `masked_sum`).
//! [`ControlTables::interpolated_integral`], which renders use, walks a lookup's records
//! together word by word and integrates each distinct word once — they share most words.
//! Partial words are the bulk of the work (garage, 64² records: about 35 per point against
//! 4 full ones, 4.6 runs of visible texels each); the masked sum replaced a split of each
//! run into aligned quadtree blocks, which branched on every run.
//!
//! ## Choosing `α` (eq. 4–5)
//! The variance of `Y = Z − α W` (eq. 4, `Z` the plain estimate and `W = g/p − J`) is least
//! at `α* = Cov(Z, W) / Var(W)` (eq. 5). Estimating `α*` from the same samples biases the
//! estimate (CAM08 §3.1). [`AlphaRule::Neighbours`] estimates it for a pixel from the
//! *other* pixels of a window around it, pooling their centred sums; those samples are
//! independent of the pixel's own (every random number comes from `(seed, pixel, sample,
//! dimension)`), so the pixel's estimate stays exactly unbiased. The estimate is clamped
//! to `[0, ALPHA_MAX]`, a function of the same independent data, which keeps it unbiased
//! and bounds the harm of a noisy window.

use glam::{DVec2, UVec2, Vec3};

use crate::lights::envmap::chroma::{MapChroma, Peak, MAX_REGION_LEVEL};
use crate::lights::envmap::EnvMap;
use crate::sampling::distribution::QuadPyramid;
use crate::sampling::octahedral::{morton_encode, texel_solid_angle};
use crate::visibility::cache::{CacheState, Lookup};
use crate::visibility::record::{word_level, Coverage, VisibilityView};

use crate::lights::envmap::product::ProductDistribution;
use crate::simd::{Kernel, Level, SimdLevel};

mod masked_sum;
use masked_sum::{word_sum, word_sum_portable, WordWeights};
#[cfg(target_arch = "x86_64")]
use masked_sum::{word_sum_avx2, word_sum_avx512};

/// Largest `α` an estimate may take (see the module docs).
pub const ALPHA_MAX: f64 = 2.0;

/// How `α` of eq. 2 is chosen.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum AlphaRule {
    /// A fixed value (CAM08 uses 1).
    Fixed(f64),
    /// Per pixel and channel, `Cov(Z, W) / Var(W)` pooled over the pixels of the
    /// `(2r + 1)²` window centred on it, the pixel itself left out (module docs).
    Neighbours {
        /// Window radius `r` in pixels, `>= 1`.
        radius: u32,
    },
}

impl AlphaRule {
    /// CAM08's choice: `α = 1`.
    pub const PAPER: Self = Self::Fixed(1.0);
    /// Estimated from a 9 x 9 window of neighbours.
    pub const ESTIMATE: Self = Self::Neighbours { radius: 4 };
}

/// The level of the regions whose colours scale the control variate for records of
/// `2^record_m` texels a side, a product of cells at `product_level` and a map of `depth`:
/// the records' words (each word then lies in one region, so the walks of `J` weight a
/// word's integral by one colour), no finer than the product's cells (whose pyramid holds
/// each region's integral) nor the map's texels.
pub fn region_level(record_m: u32, product_level: u32, depth: u32) -> u32 {
    word_level(record_m)
        .min(product_level)
        .min(depth)
        .min(MAX_REGION_LEVEL)
}

/// What the control variate needs of one shading point besides its product distribution:
/// the region level and colours, and the unoccluded integrals (module docs). Refilled per
/// point by [`Self::fill`]; no allocation.
#[derive(Clone, Copy, Debug)]
pub struct ControlTables<'c> {
    /// Level of the records' grid.
    record_m: u32,
    /// Level of the colour regions ([`region_level`]).
    region_level: u32,
    /// RGB over luminance of each region without the map's peaks (Morton order).
    colours: &'c [[f64; 3]],
    /// The map's peaks, which take their own colours, and its depth.
    peaks: &'c [Peak],
    map_depth: u32,
    /// `∫ L B~ dω` over the sphere (luminance).
    unoccluded_luminance: f64,
    /// `Σ_r κ_c(r) ∫_r L B~ dω` over the sphere, per channel.
    unoccluded: [f64; 3],
    /// Solid angle of one texel of the map (sr): the product pyramid's weights times it are
    /// integrals.
    texel_omega: f64,
}

impl<'c> ControlTables<'c> {
    /// The tables of `product` under the map whose region colours are `chroma`, for records of
    /// `2^record_m` texels a side.
    pub fn new(product: &ProductDistribution, chroma: &'c MapChroma, record_m: u32) -> Self {
        let mut t = Self {
            record_m,
            region_level: 0,
            colours: chroma.control_colours(0),
            peaks: chroma.peaks(),
            map_depth: chroma.depth(),
            unoccluded_luminance: 0.0,
            unoccluded: [0.0; 3],
            texel_omega: 0.0,
        };
        t.fill(product, chroma, record_m);
        t
    }

    /// Refills the tables for another point (see [`Self::new`]).
    pub fn fill(&mut self, product: &ProductDistribution, chroma: &'c MapChroma, record_m: u32) {
        self.record_m = record_m;
        self.texel_omega = texel_solid_angle(1 << chroma.depth());
        self.region_level = region_level(record_m, product.level(), chroma.depth());
        self.colours = chroma.control_colours(self.region_level);
        self.peaks = chroma.peaks();
        self.map_depth = chroma.depth();
        // Each region's `Σ L B~` is a node of the product's pyramid (regions are no finer
        // than its cells).
        let weights = product.pyramid().level(self.region_level);
        let mut sum = [0.0f64; 3];
        for (&w, c) in weights.iter().zip(self.colours) {
            sum = std::array::from_fn(|k| sum[k] + w * c[k]);
        }
        let peaks = self.peak_excess(product, |_| 1.0);
        self.unoccluded_luminance = product.normalization() * self.texel_omega;
        self.unoccluded = std::array::from_fn(|k| (sum[k] + peaks[k]) * self.texel_omega);
    }

    /// `Σ_t (κ(t) − κ(region of t)) L_lum(t) B~(t) v(t)` over the map's peak texels `t`
    /// (`v` of a peak's record texel, at the tables' record level): what the walk over
    /// regions, which gives every texel its region's colour, misses of the peaks' own.
    /// In the pyramid's units (times `texel_omega`, an integral).
    #[inline]
    fn peak_excess(&self, product: &ProductDistribution, v: impl Fn(u32) -> f64) -> [f64; 3] {
        self.sum_over_peaks(product, |peak, region, texel| {
            let visible = v(texel);
            std::array::from_fn(|k| (peak.colour[k] - region[k]) * visible)
        })
    }

    /// `Σ_t κ(t) L_lum(t) B~(t) (sun − v(t))` over the map's peak texels `t`, times
    /// `texel_omega`: how `J` changes when `Ṽ` on the peaks is `sun` instead of the
    /// records' `v` (of a peak's record texel; [`Interpolant::with_sun`]).
    pub fn sun_change(
        &self,
        product: &ProductDistribution,
        v: impl Fn(u32) -> f64,
        sun: f64,
    ) -> [f64; 3] {
        let sum = self.sum_over_peaks(product, |peak, _, texel| {
            let change = sun - v(texel);
            peak.colour.map(|c| c * change)
        });
        sum.map(|s| s * self.texel_omega)
    }

    /// `Σ_t L_lum(t) B~(t) term(peak, κ(region of t), record texel of t)` over the map's
    /// peak texels `t` with `B~ > 0` (none where the product's cells are finer than the
    /// map's texels).
    #[inline]
    fn sum_over_peaks(
        &self,
        product: &ProductDistribution,
        term: impl Fn(&Peak, [f64; 3], u32) -> [f64; 3],
    ) -> [f64; 3] {
        let mut sum = [0.0f64; 3];
        let p = product.level();
        if self.peaks.is_empty() || p > self.map_depth {
            return sum;
        }
        let cells = product.bsdf_cells();
        for peak in self.peaks {
            let b = cells[(peak.code >> (2 * (self.map_depth - p))) as usize] as f64;
            if b == 0.0 {
                continue;
            }
            let texel = peak.code >> (2 * (self.map_depth - self.record_m));
            let region =
                self.colours[(peak.code >> (2 * (self.map_depth - self.region_level))) as usize];
            let y = b * peak.weight;
            let t = term(peak, region, texel);
            sum = std::array::from_fn(|k| sum[k] + t[k] * y);
        }
        sum
    }

    /// `Σ_r κ_c(r) ∫_r L B~ dω` over the whole sphere, per channel (`J` of a record that
    /// sees everything).
    pub fn total(&self) -> [f64; 3] {
        self.unoccluded
    }

    /// `∫ L B~ dω` over the whole sphere (luminance): `g_c / p = κ_c(ω)` times this times
    /// `Ṽ(ω)` for a product sample.
    pub fn total_luminance(&self) -> f64 {
        self.unoccluded_luminance
    }

    /// Level of the colour regions ([`region_level`]).
    pub fn region_level(&self) -> u32 {
        self.region_level
    }

    /// `J_i = ∫ κ(ω) L_lum B~ V_i dω` of one record (CAM08 §5.5): a walk of its 2-bit
    /// hierarchy that skips empty nodes and takes full ones whole from the product's own
    /// pyramid (descending to the colour regions where a full node spans several); a
    /// partial node of one word adds its visible texels' weights. `bits` must have the
    /// tables' record resolution, `product` be the point's and `env` its map.
    pub fn record_integral(
        &self,
        bits: VisibilityView,
        product: &ProductDistribution,
        env: &EnvMap,
    ) -> [f64; 3] {
        debug_assert_eq!(bits.m(), self.record_m);
        let Some(dist) = env.distribution() else {
            return [0.0; 3];
        };
        let nodes = LuminanceNodes { product, dist };
        let m = self.record_m;
        let r = self.region_level;
        let words = bits.bit_words();
        let (mut buf, mut scratch) = ([0.0f64; 64], [0.0f64; 64]);
        let mut visible_texels =
            |word: usize, x: u64| word_sum(x, nodes.word_weights(m, word, &mut buf), &mut scratch);
        let mut sum = [0.0f64; 3];
        let mut add = |region: u32, value: f64| {
            let c = self.colours[region as usize];
            sum = std::array::from_fn(|k| sum[k] + c[k] * value);
        };
        if m < 3 {
            // One word holds the whole map (and one region, level 0).
            add(0, visible_texels(0, words[0]));
        } else {
            let word_level = word_level(m);
            let mut stack = [(0u32, 0u32); 1 + 3 * 8];
            let mut len = 1;
            while len > 0 {
                len -= 1;
                let (level, node) = stack[len];
                match bits.coverage(level, node) {
                    Coverage::Empty => {}
                    Coverage::Full if level >= r => {
                        add(node >> (2 * (level - r)), nodes.node(level, node))
                    }
                    Coverage::Partial if level == word_level => add(
                        node >> (2 * (level - r)),
                        visible_texels(node as usize, words[node as usize]),
                    ),
                    // Partial, or full over several regions.
                    _ => {
                        for k in (0..4).rev() {
                            stack[len] = (level + 1, 4 * node + k);
                            len += 1;
                        }
                    }
                }
            }
        }
        let peaks = self.peak_excess(product, |texel| bits.get(texel as usize) as u8 as f64);
        std::array::from_fn(|k| (sum[k] + peaks[k]) * self.texel_omega)
    }
}

impl ControlTables<'_> {
    /// `J = Σ β_i J_i` of several records at once (the same value as summing
    /// [`Self::record_integral`]s). The records of one lookup agree on most of the sphere,
    /// so they are walked together one 64-texel word at a time: each distinct word is
    /// integrated once, weighted by the `β` of the records that share it; all-visible words
    /// are one node of the product's pyramid, all-occluded ones are skipped. Measured
    /// against separate hierarchy walks on garage's lookups (benches/control_variate.rs),
    /// this is the faster form of CAM08 §5.5's traversal for records that share words.
    pub fn interpolated_integral(
        &self,
        maps: &[VisibilityView],
        beta: &[f32],
        product: &ProductDistribution,
        env: &EnvMap,
    ) -> [f64; 3] {
        debug_assert_eq!(maps.len(), beta.len());
        let (Some(dist), Some(first)) = (env.distribution(), maps.first()) else {
            return [0.0; 3];
        };
        let nodes = LuminanceNodes { product, dist };
        let m = self.record_m;
        let words = first.bit_words().len();
        // Words per region: a word's colour is `colours[w >> shift]`.
        let shift = 2 * (word_level(m) - self.region_level);
        let regions = (self.colours, shift);
        let sum = crate::simd::dispatch(InterpolatedKernel {
            nodes: &nodes,
            m,
            words,
            maps,
            beta,
            regions,
        });
        let peaks = self.peak_excess(product, |texel| {
            maps.iter()
                .zip(beta)
                .filter(|(map, _)| map.get(texel as usize))
                .map(|(_, &b)| b as f64)
                .sum()
        });
        std::array::from_fn(|k| (sum[k] + peaks[k]) * self.texel_omega)
    }
}

/// [`LuminanceNodes::interpolated`] as a [`Kernel`]: picks the form with the masked sums of
/// the dispatched instruction set.
struct InterpolatedKernel<'a, 'b> {
    nodes: &'a LuminanceNodes<'a>,
    m: u32,
    words: usize,
    maps: &'a [VisibilityView<'b>],
    beta: &'a [f32],
    regions: (&'a [[f64; 3]], u32),
}

impl Kernel for InterpolatedKernel<'_, '_> {
    type Output = [f64; 3];

    #[inline(always)]
    fn run<L: Level>(self, _level: L) -> [f64; 3] {
        let Self {
            nodes,
            m,
            words,
            maps,
            beta,
            regions,
        } = self;
        match L::LEVEL {
            // SAFETY: a value of `L` exists only on CPUs with `L::LEVEL` (`Level`'s
            // contract), here AVX-512 F.
            #[cfg(target_arch = "x86_64")]
            SimdLevel::Avx512 => unsafe {
                nodes.interpolated_avx512(m, words, maps, beta, regions)
            },
            // SAFETY: as above, AVX2.
            #[cfg(target_arch = "x86_64")]
            SimdLevel::Avx2 => unsafe { nodes.interpolated_avx2(m, words, maps, beta, regions) },
            _ => nodes.interpolated(m, words, maps, beta, regions, word_sum_portable),
        }
    }
}

/// `Σ L_lum B~` (the map's sampling weights times `B~`) over quadtree nodes of any level:
/// the product's pyramid down to its cells, then `B~` of the cell times the map's own
/// luminance pyramid (split evenly below its texels).
struct LuminanceNodes<'a> {
    product: &'a ProductDistribution,
    dist: &'a QuadPyramid,
}

impl LuminanceNodes<'_> {
    #[inline]
    fn node(&self, level: u32, index: u32) -> f64 {
        let p = self.product.level();
        if level <= p {
            return self.product.pyramid().level(level)[index as usize];
        }
        let b = self.product.bsdf_cells()[(index >> (2 * (level - p))) as usize] as f64;
        let e = self.dist.depth();
        let l = if level <= e {
            self.dist.level(level)[index as usize]
        } else {
            let shift = 2 * (level - e);
            self.dist.level(e)[(index >> shift) as usize] / (1u64 << shift) as f64
        };
        b * l
    }

    /// The weights of the 64 texels of word `word` of a level-`m` map (zero past the map's
    /// `4^m` texels when `m < 3`): a slice of the product's pyramid where its cells are no
    /// finer than the texels, `B~` of the cell times the map's texel where they are and
    /// the map is as fine as the record, else [`Self::node`] per texel written into `buf`.
    #[inline(always)]
    fn word_weights<'s>(&'s self, m: u32, word: usize, buf: &'s mut [f64; 64]) -> WordWeights<'s> {
        let p = self.product.level();
        let base = 64 * word;
        if m >= 3 && m <= p {
            let level = self.product.pyramid().level(m);
            return WordWeights::Given(level[base..base + 64].try_into().expect("a word"));
        }
        if m >= 3 && m > p && m <= self.dist.depth() {
            let shift = 2 * (m - p);
            return WordWeights::Product {
                cells: &self.product.bsdf_cells()[base >> shift..],
                shift,
                texels: self.dist.level(m)[base..base + 64]
                    .try_into()
                    .expect("a word"),
            };
        }
        let texels = 64.min(1usize << (2 * m));
        for (i, w) in buf[..texels].iter_mut().enumerate() {
            *w = self.node(m, (base + i) as u32);
        }
        buf[texels..].fill(0.0);
        WordWeights::Given(buf)
    }

    /// `Σ_w κ(w) Σ_x β_x ∫_x` over the words `w` of `maps` (level `m`, `words` each) and
    /// each distinct non-zero word `x` among them, `β_x` the summed `β` of the maps holding
    /// it, `κ(w) = colours[w >> shift]` the colour of the word's region: full words are one
    /// node of the pyramid, partial ones `sum` over their texels' weights. Inlined into one
    /// function per kernel.
    #[inline(always)]
    fn interpolated(
        &self,
        m: u32,
        words: usize,
        maps: &[VisibilityView],
        beta: &[f32],
        (colours, shift): (&[[f64; 3]], u32),
        sum: impl Fn(u64, WordWeights, &mut [f64; 64]) -> f64,
    ) -> [f64; 3] {
        let mut total = [0.0f64; 3];
        let mut seen = [(0u64, 0.0f64); MAX_KEPT];
        let (mut buf, mut scratch) = ([0.0f64; 64], [0.0f64; 64]);
        let bits: [&[u64]; MAX_KEPT] =
            std::array::from_fn(|i| maps.get(i).map_or(&[][..], |v| &v.bit_words()[..words]));
        for w in 0..words {
            // The distinct words of the records here, with their summed β.
            let mut distinct = 0;
            for (map, &b) in bits[..maps.len()].iter().zip(beta) {
                let x = map[w];
                if x == 0 {
                    continue;
                }
                match seen[..distinct].iter_mut().find(|s| s.0 == x) {
                    Some(s) => s.1 += b as f64,
                    None => {
                        seen[distinct] = (x, b as f64);
                        distinct += 1;
                    }
                }
            }
            if distinct == 0 {
                continue;
            }
            let mut word_total = 0.0f64;
            for &(x, b) in &seen[..distinct] {
                let integral = if x == u64::MAX && m >= 3 {
                    self.node(m - 3, w as u32)
                } else {
                    sum(x, self.word_weights(m, w, &mut buf), &mut scratch)
                };
                word_total += b * integral;
            }
            let c = colours[w >> shift];
            total = std::array::from_fn(|k| total[k] + c[k] * word_total);
        }
        total
    }

    /// [`Self::interpolated`] with the AVX-512 kernel. The per-set forms are never inlined
    /// into the dispatcher's functions, whose feature sets differ (AVX-512 VL): each stays
    /// compiled exactly for its own set.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    #[inline(never)]
    fn interpolated_avx512(
        &self,
        m: u32,
        words: usize,
        maps: &[VisibilityView],
        beta: &[f32],
        regions: (&[[f64; 3]], u32),
    ) -> [f64; 3] {
        self.interpolated(m, words, maps, beta, regions, |x, w, buf| {
            word_sum_avx512(x, w, buf)
        })
    }

    /// [`Self::interpolated`] with the AVX2 kernel.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    #[inline(never)]
    fn interpolated_avx2(
        &self,
        m: u32,
        words: usize,
        maps: &[VisibilityView],
        beta: &[f32],
        regions: (&[[f64; 3]], u32),
    ) -> [f64; 3] {
        self.interpolated(m, words, maps, beta, regions, |x, w, buf| {
            word_sum_avx2(x, w, buf)
        })
    }
}

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
    /// shading point toward [`MapChroma::sun`], 0 or 1) instead of the records' blend there,
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

/// Centred sums of one pixel's samples of `Z` (the plain estimate) and `W` (the control
/// variate's zero-mean term `g/p − J`), per channel, from which the estimate and its
/// variance follow for any `α` ([`Self::estimate`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CvSums {
    /// Samples.
    pub n: u32,
    pub z: [f64; 3],
    pub w: [f64; 3],
    pub zz: [f64; 3],
    pub ww: [f64; 3],
    pub zw: [f64; 3],
}

impl CvSums {
    /// Adds one sample.
    #[inline]
    pub fn add(&mut self, z: Vec3, w: [f64; 3]) {
        self.n += 1;
        for c in 0..3 {
            let zc = z[c] as f64;
            self.z[c] += zc;
            self.w[c] += w[c];
            self.zz[c] += zc * zc;
            self.ww[c] += w[c] * w[c];
            self.zw[c] += zc * w[c];
        }
    }

    /// `(Σ (z−z̄)(w−w̄), Σ (w−w̄)²)` of channel `c`: what [`AlphaRule::Neighbours`] pools.
    pub fn centred(&self, c: usize) -> (f64, f64) {
        if self.n == 0 {
            return (0.0, 0.0);
        }
        let n = self.n as f64;
        let cov = self.zw[c] - self.z[c] * self.w[c] / n;
        let var = (self.ww[c] - self.w[c] * self.w[c] / n).max(0.0);
        (cov, var)
    }

    /// Mean of `Z − α W` per channel and the variance of that mean (`inf` below two
    /// samples, `NaN`-free: 0 samples give mean 0).
    pub fn estimate(&self, alpha: [f64; 3]) -> ([f64; 3], [f64; 3]) {
        let n = self.n as f64;
        let mut mean = [0.0; 3];
        let mut var = [f64::INFINITY; 3];
        for c in 0..3 {
            let a = alpha[c];
            let sy = self.z[c] - a * self.w[c];
            if self.n > 0 {
                mean[c] = sy / n;
            }
            if self.n >= 2 {
                let syy = self.zz[c] - 2.0 * a * self.zw[c] + a * a * self.ww[c];
                var[c] = ((syy - sy * sy / n) / (n - 1.0)).max(0.0) / n;
            }
        }
        (mean, var)
    }
}

/// Per-pixel `α` of [`AlphaRule::Neighbours`] over a `width x height` image of sums
/// (row-major): for each pixel and channel, the window's pooled centred covariance over its
/// pooled centred variance, the pixel itself excluded, clamped to `[0, ALPHA_MAX]`; `1`
/// where the window has no variance (the control variate is then constant and `α` does
/// not matter). The window sums are formed directly, never as a total minus the pixel's
/// own term, so not even rounding ties a pixel's `α` to its own samples.
pub fn neighbour_alphas(
    sums: &[CvSums],
    width: usize,
    height: usize,
    radius: u32,
) -> Vec<[f64; 3]> {
    use rayon::prelude::*;
    debug_assert_eq!(sums.len(), width * height);
    let r = radius as usize;
    let centred: Vec<[(f64, f64); 3]> = sums
        .iter()
        .map(|s| std::array::from_fn(|c| s.centred(c)))
        .collect();
    let mut out = vec![[1.0f64; 3]; sums.len()];
    out.par_chunks_mut(width.max(1))
        .enumerate()
        .for_each(|(y, row)| {
            let (y0, y1) = (y.saturating_sub(r), (y + r + 1).min(height));
            for (x, alpha) in row.iter_mut().enumerate() {
                let (x0, x1) = (x.saturating_sub(r), (x + r + 1).min(width));
                let mut pooled = [(0.0f64, 0.0f64); 3];
                for yy in y0..y1 {
                    for xx in x0..x1 {
                        if (xx, yy) == (x, y) {
                            continue;
                        }
                        for (p, q) in pooled.iter_mut().zip(&centred[yy * width + xx]) {
                            p.0 += q.0;
                            p.1 += q.1;
                        }
                    }
                }
                for (a, (cov, var)) in alpha.iter_mut().zip(pooled) {
                    if var > 0.0 {
                        *a = (cov / var).clamp(0.0, ALPHA_MAX);
                    }
                }
            }
        });
    out
}

/// What one pixel sample of the control-variate estimator found for the environment:
/// the plain term `L B V / p` is the renderer's; this is `g/p` and the records' verdicts.
#[derive(Clone, Copy, Debug, Default)]
pub struct ControlSample {
    /// `g / p = κ(ω) L_lum B~ Ṽ / p = κ(ω) (∫ L B~ dω) Ṽ` per channel.
    pub value: [f64; 3],
    /// Bit `i` set when kept record `i` sees the sampled direction.
    pub visible_mask: u32,
}

/// `g/p` for a product sample at square point `square`: the product's pdf is
/// `L_lum B~ / ∫ L_lum B~`, so `g/p` is the unoccluded integral times `Ṽ` there, in the
/// colour of the region of `chroma` (the map the interpolant's `J` was integrated under)
/// that holds the point.
#[inline]
pub fn control_sample(
    state: &CacheState,
    interpolant: &Interpolant,
    chroma: &MapChroma,
    square: DVec2,
) -> ControlSample {
    let (mut v, mask) = interpolant.eval(state, square);
    let code = record_texel_code(square, chroma.depth());
    let (colour, peak) = chroma.control_colour_of(code, interpolant.region_level);
    if let (true, Some(sun)) = (peak, interpolant.sun) {
        v = sun;
    }
    let scale = interpolant.unoccluded * v;
    ControlSample {
        value: colour.map(|c| c * scale),
        visible_mask: mask,
    }
}

/// The control variate of a material whose two lobes differ in colour
/// ([`crate::bsdf::Material::lobe_channel_ratios`]: `r_d` for the diffuse lobe, `r_s` for
/// the specular coat). Channel `c` of the control is `r_s,c g_c + (r_d,c − r_s,c) g_d,c`,
/// with `g = κ L B~ Ṽ` as for every material and `g_d = κ L B~_d Ṽ` the part of it from the
/// diffuse lobe's cells, `B~_d = min(B~ of the lobe, B~)`
/// ([`ProductDistribution::lobe_part`]): the paint's colour applies away from the coat's
/// lobe and the coat's inside it, as `f`'s channels do. With one ratio per point (the
/// albedo's, [`crate::bsdf::Material::channel_ratios`]) the blue channel of garage's blue
/// car under its grey coat kept 0.79x product sampling's variance, against 0.31x on the
/// grey car. `g_d / p` is `g / p` times `B~_d / B~` of the sample's cell (exact, since
/// `B~_d ≤ B~`), and `J_d` is its exact integral as `J` is `g`'s, so the control variate
/// keeps `E[W] = 0`.
#[derive(Clone, Debug)]
pub struct LobeControl {
    /// `r_d,c − r_s,c`.
    diffuse_excess: [f64; 3],
    /// `r_s,c`.
    coat: [f64; 3],
    /// `J_d` per channel.
    pub j: [f64; 3],
    /// `B~_d / B~` per product cell (Morton order; 0 where `B~` is).
    shares: Vec<f32>,
    /// The product's cell level.
    level: u32,
}

impl LobeControl {
    /// The control at `sp` with its product `product` under `env` and records `lookup`,
    /// with `Ṽ = sun` on the map's peaks where given ([`Interpolant::with_sun`]); `None`
    /// where the material's lobes share one colour (or its diffuse part is zero).
    pub fn new(
        product: &ProductDistribution,
        sp: &super::direct::ShadingPoint,
        (state, lookup): (&CacheState, &Lookup),
        chroma: &MapChroma,
        env: &EnvMap,
        sun: Option<f64>,
    ) -> Option<Self> {
        let (diffuse, coat) = sp.material.lobe_channel_ratios()?;
        let part = product.lobe_part(env, &sp.material.diffuse_lobe(), sp.normal, sp.wo)?;
        let tables = ControlTables::new(&part, chroma, state.store().m());
        let mut interpolant = Interpolant::new(state, lookup, Some((&tables, &part, env)));
        if let Some(sun) = sun {
            interpolant = interpolant.with_sun(state, &tables, &part, sun);
        }
        let j = interpolant.j;
        let shares = part
            .bsdf_cells()
            .iter()
            .zip(product.bsdf_cells())
            .map(|(&d, &b)| if b > 0.0 { d / b } else { 0.0 })
            .collect();
        Some(Self {
            diffuse_excess: std::array::from_fn(|c| (diffuse[c] - coat[c]) as f64),
            coat: coat.map(f64::from),
            j,
            shares,
            level: product.level(),
        })
    }

    /// `g_d / g` at the sampled point `square` of a draw: `B~_d / B~` of its cell.
    #[inline]
    pub fn share(&self, square: DVec2) -> f64 {
        self.shares[record_texel_code(square, self.level) as usize] as f64
    }

    /// The zero-mean term `W_c = r_s,c (g/p − J)_c + (r_d,c − r_s,c)(g_d/p − J_d)_c` from a
    /// sample's mean `g/p` and `g_d/p` and the point's `J`.
    pub fn w(&self, g_over_p: [f64; 3], gd_over_p: [f64; 3], j: &[f64; 3]) -> [f64; 3] {
        std::array::from_fn(|c| {
            self.coat[c] * (g_over_p[c] - j[c])
                + self.diffuse_excess[c] * (gd_over_p[c] - self.j[c])
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bsdf::Material;
    use crate::lights::envmap::chroma::MIN_PEAK_DEPTH;
    use crate::lights::procedural::sky;
    use crate::sampling::octahedral::morton_decode;
    use crate::sampling::octahedral::square_to_sphere;
    use crate::sampling::rng::{hash4, to_unit_f64, SampleRng};
    use crate::visibility::cache::VisibilityCache;
    use crate::visibility::params::CacheParams;
    use crate::visibility::record::{Record, VisibilityBits};

    fn test_sky(res: u32) -> EnvMap {
        let sun = Vec3::new(0.4, 0.6, -0.5).normalize();
        sky(
            sun,
            [2e3, 1.5e3, 1e3],
            6.0,
            [0.2, 0.3, 0.6],
            [0.8, 0.8, 0.9],
            res,
        )
        .unwrap()
    }

    fn frame() -> (Vec3, Vec3) {
        (
            Vec3::new(0.2, 0.9, -0.3).normalize(),
            Vec3::new(-0.5, 0.4, 0.6).normalize(),
        )
    }

    /// Random bits with some coherence: blocks of 4^k texels share a coin.
    fn random_bits(m: u32, seed: u64) -> VisibilityBits {
        VisibilityBits::from_fn(m, |z| {
            let block = (seed % 3) as u32 * 2;
            let key = (z >> block.min(2 * m)) as u64;
            !hash4(seed, key, 0, 0).is_multiple_of(3)
        })
        .unwrap()
    }

    /// `(∫ κ L_lum B~ dω, ∫ L_lum B~ dω, ∫ κ L_lum B~ V dω)` as plain sums over the finest
    /// grid of the three (texels of equal solid angle), `κ` the colour of each texel's
    /// region of level `regions` under `chroma`, independent of pyramids and hierarchies.
    fn brute_force(
        env: &EnvMap,
        chroma: &MapChroma,
        regions: u32,
        product: &ProductDistribution,
        bits: &VisibilityBits,
    ) -> ([f64; 3], f64, [f64; 3]) {
        let e = env.resolution().trailing_zeros();
        let (p, m) = (product.level(), bits.m());
        let f = e.max(p).max(m);
        let side = 1u32 << f;
        let omega = texel_solid_angle(side);
        let (mut total, mut lum, mut j) = ([0.0f64; 3], 0.0, [0.0f64; 3]);
        for code in 0..side * side {
            let t = morton_decode(code);
            let env_texel = UVec2::new(t.x >> (f - e), t.y >> (f - e));
            let l = env.texels()[(env_texel.y * env.resolution() + env_texel.x) as usize];
            let cell = morton_encode(t.x >> (f - p), t.y >> (f - p));
            let b = product.bsdf_cells()[cell as usize] as f64 * omega;
            let y = crate::lights::envmap::luminance(l) * b;
            let kappa = chroma.control_colour(code >> (2 * (f - e)), regions);
            let visible = bits.get(morton_encode(t.x >> (f - m), t.y >> (f - m)) as usize);
            for c in 0..3 {
                total[c] += kappa[c] * y;
                if visible {
                    j[c] += kappa[c] * y;
                }
            }
            lum += y;
        }
        (total, lum, j)
    }

    fn close(a: [f64; 3], b: [f64; 3], rel: f64) -> bool {
        (0..3).all(|c| (a[c] - b[c]).abs() <= rel * b[c].abs().max(1e-300))
    }

    #[test]
    fn record_integrals_equal_the_brute_force_sum() {
        // (record M, product level, map resolution): records coarser, equal and finer than
        // the cells; cells capped by coarse maps; sub-word maps.
        let cases = [
            (1, 1, 2),
            (2, 3, 8),
            (3, 3, 64),
            (5, 5, 64),
            (5, 3, 64),
            (4, 5, 256),
            (6, 5, 32),
            (7, 4, 16),
        ];
        let materials = [
            Material::lambert([0.8, 0.5, 0.3]).unwrap(),
            Material::phong([0.2; 3], [0.7; 3], 40.0).unwrap(),
        ];
        for (k, &(m, level, res)) in cases.iter().enumerate() {
            let env = test_sky(res);
            let chroma = MapChroma::new(&env);
            // The sun's texels take their own colour from 128² maps on.
            assert_eq!(
                !chroma.peaks().is_empty(),
                res >= 1 << MIN_PEAK_DEPTH,
                "{res}"
            );
            for (i, mat) in materials.iter().enumerate() {
                let (n, wo) = frame();
                let product = ProductDistribution::new(&env, mat, n, wo, level).unwrap();
                let tables = ControlTables::new(&product, &chroma, m);
                for seed in 0..4u64 {
                    let bits = random_bits(m, 100 * k as u64 + 10 * i as u64 + seed);
                    let j = tables.record_integral(bits.view(), &product, &env);
                    let r = tables.region_level();
                    assert_eq!(r, region_level(m, level, res.trailing_zeros()));
                    let (total, lum, expect) = brute_force(&env, &chroma, r, &product, &bits);
                    assert!(close(tables.total(), total, 1e-9));
                    assert!((tables.total_luminance() / lum - 1.0).abs() < 1e-9);
                    assert!(
                        close(j, expect, 1e-9),
                        "M={m} P={level} res={res}: {j:?} vs {expect:?}"
                    );
                }
                // Several records at once: shared, partial, full and empty words.
                let mut maps: Vec<VisibilityBits> = (0..3)
                    .map(|s| random_bits(m, 1000 + 10 * k as u64 + s))
                    .collect();
                maps.push(maps[0].clone());
                maps.push(VisibilityBits::from_fn(m, |_| true).unwrap());
                let beta = [0.3f32, 0.1, 0.25, 0.15, 0.2];
                let views: Vec<_> = maps.iter().map(|b| b.view()).collect();
                let together = tables.interpolated_integral(&views, &beta, &product, &env);
                let separate = maps.iter().zip(beta).fold([0.0; 3], |acc, (b, w)| {
                    let j = tables.record_integral(b.view(), &product, &env);
                    std::array::from_fn(|c| acc[c] + w as f64 * j[c])
                });
                assert!(
                    close(together, separate, 1e-12),
                    "{together:?} vs {separate:?}"
                );
                assert_eq!(
                    tables.interpolated_integral(&[], &[], &product, &env),
                    [0.0; 3]
                );
                let all = VisibilityBits::from_fn(m, |_| true).unwrap();
                let none = VisibilityBits::from_fn(m, |_| false).unwrap();
                assert!(close(
                    tables.record_integral(all.view(), &product, &env),
                    tables.total(),
                    1e-12
                ));
                assert_eq!(
                    tables.record_integral(none.view(), &product, &env),
                    [0.0; 3]
                );
                // The whole-sphere integral of L B~ is L_ns in RGB: its luminance is the
                // product's normalisation times a texel's solid angle, and the regions'
                // colours keep it (each has luminance 1).
                let lum: f64 = tables
                    .total()
                    .iter()
                    .zip(crate::lights::envmap::LUMINANCE)
                    .map(|(a, b)| a * b)
                    .sum();
                let l_ns = product.normalization() * texel_solid_angle(res);
                assert!((lum / l_ns - 1.0).abs() < 1e-9, "{lum} vs {l_ns}");
                assert!((tables.total_luminance() / l_ns - 1.0).abs() < 1e-9);
                // In RGB the total is the exact ∫ L_c B~ when the regions are no coarser
                // than the cells' colours vary: here, within 20% of it.
                let exact = exact_rgb(&env, &product);
                assert!(close(tables.total(), exact, 0.2), "{exact:?}");
            }
        }
    }

    /// `∫ L_c B~ dω` per channel over the product's cells and the map's texels.
    fn exact_rgb(env: &EnvMap, product: &ProductDistribution) -> [f64; 3] {
        let e = env.resolution().trailing_zeros();
        let p = product.level();
        let f = e.max(p);
        let side = 1u32 << f;
        let omega = texel_solid_angle(side);
        let mut rgb = [0.0f64; 3];
        for code in 0..side * side {
            let t = morton_decode(code);
            let l = env.texels()[((t.y >> (f - e)) * env.resolution() + (t.x >> (f - e))) as usize];
            let cell = morton_encode(t.x >> (f - p), t.y >> (f - p));
            let b = product.bsdf_cells()[cell as usize] as f64 * omega;
            for c in 0..3 {
                rgb[c] += l[c] as f64 * b;
            }
        }
        rgb
    }

    /// A cache with three records of chosen bits around the origin, and the lookup there.
    fn cache_with(bits: &[VisibilityBits]) -> (VisibilityCache, Lookup) {
        let m = bits[0].m();
        let cache = VisibilityCache::new(CacheParams::MEDIUM.with_log2_resolution(m)).unwrap();
        for (i, b) in bits.iter().enumerate() {
            let record = Record {
                position: Vec3::new(0.01 * (i as f32 + 1.0), 0.0, 0.0),
                normal: Vec3::Y,
                bits: b.clone(),
                ambient_occlusion: 0.5,
                nearest_hit_distance: 1.0,
                misses: 0,
                uses: 0,
                last_frame: 0,
            };
            cache.insert_record(&record).unwrap();
        }
        let lookup = cache.lookup(Vec3::ZERO, Vec3::Y, 1.0);
        assert_eq!(lookup.neighbours().len(), bits.len());
        (cache, lookup)
    }

    #[test]
    fn cell_visibility_is_the_weighted_share_of_visible_record_texels() {
        for m in [2u32, 3, 5, 6, 7] {
            let bits: Vec<_> = (0..3).map(|i| random_bits(m, 11 + i)).collect();
            let (cache, lookup) = cache_with(&bits);
            let state = cache.read();
            let interp = Interpolant::new(&state, &lookup, None);
            for level in [4u32, 5, 6] {
                let got = interp.cell_visibility(&state, level);
                for (c, &v) in got.iter().enumerate() {
                    let mut want = 0.0f64;
                    for (&id, &beta) in interp.ids().iter().zip(interp.betas()) {
                        let b = state.store().bits(id as usize);
                        let share = if m >= level {
                            let k = 1usize << (2 * (m - level));
                            (0..k).filter(|t| b.get(c * k + t)).count() as f64 / k as f64
                        } else {
                            b.get(c >> (2 * (level - m))) as u32 as f64
                        };
                        want += beta as f64 * share;
                    }
                    assert!(
                        (v as f64 - want.min(1.0)).abs() < 1e-5,
                        "m {m} level {level}"
                    );
                }
            }
        }
    }

    #[test]
    fn record_averages_are_each_records_weighted_share_and_blend_to_v_tilde() {
        // Scattered bits, and long runs (whole words visible or blocked, as real records
        // are) at odd offsets.
        let runs = |m: u32, seed: u64| {
            VisibilityBits::from_fn(m, move |z| {
                !((z as u64 + 37 * seed) / 150).is_multiple_of(3)
            })
            .unwrap()
        };
        for (m, scattered) in [(2u32, true), (3, true), (5, true), (6, true), (6, false)] {
            let bits: Vec<_> = (0..3)
                .map(|i| {
                    if scattered {
                        random_bits(m, 21 + i)
                    } else {
                        runs(m, i)
                    }
                })
                .collect();
            let (cache, lookup) = cache_with(&bits);
            let state = cache.read();
            let interp = Interpolant::new(&state, &lookup, None);
            for level in [4u32, 5] {
                let cells = 1usize << (2 * level);
                let weights: Vec<f64> = (0..cells).map(|c| 1.0 + (c % 7) as f64).collect();
                let total: f64 = weights.iter().sum();
                let pyramid = QuadPyramid::from_morton_unchecked(weights.clone());
                let got = interp.record_averages(&state, &pyramid);
                assert_eq!(got.len(), interp.ids().len());
                let mut blended = 0.0;
                for ((&(beta, avg), &id), &b) in got.iter().zip(interp.ids()).zip(interp.betas()) {
                    assert_eq!(beta, b);
                    let rec = state.store().bits(id as usize);
                    let want: f64 = (0..cells)
                        .map(|c| {
                            let share = if m >= level {
                                let k = 1usize << (2 * (m - level));
                                (0..k).filter(|t| rec.get(c * k + t)).count() as f64 / k as f64
                            } else {
                                rec.get(c >> (2 * (level - m))) as u32 as f64
                            };
                            weights[c] * share
                        })
                        .sum::<f64>()
                        / total;
                    assert!(
                        (avg - want).abs() < 1e-6,
                        "m {m} level {level}: {avg} {want}"
                    );
                    blended += beta as f64 * avg;
                }
                // With β summing to one no cell is clamped: the records' blend is Ṽ's.
                let v: f64 = interp
                    .cell_visibility(&state, level)
                    .iter()
                    .zip(&weights)
                    .map(|(&v, &w)| w * v as f64)
                    .sum::<f64>()
                    / total;
                assert!(
                    (blended - v).abs() < 1e-5,
                    "m {m} level {level}: {blended} {v}"
                );
            }
        }
    }

    #[test]
    fn the_control_variate_averages_to_j_under_the_mixture() {
        // E[g/p] = J for draws of the renderer's mixture (guided by these records, built
        // for the product's point but used at another: a jittered sample's hit). The
        // material is blue paint under a grey coat, so the lobes' part counts too: E[g_d/p]
        // = J_d and E[W] = 0 per channel, with the diffuse part's cells never above the
        // product's; lobes of nearly one colour are not told apart.
        use crate::estimators::direct::{Mixture, ShadingPoint, Techniques};
        // 256²: the sun's texels are peaks with their own colour.
        let env = test_sky(256);
        assert!(!MapChroma::new(&env).peaks().is_empty());
        let chroma = MapChroma::new(&env);
        let mat = Material::phong([0.05, 0.1, 0.45], [0.3; 3], 20.0).unwrap();
        for (kd, ks) in [([0.2; 3], [0.4; 3]), ([0.4, 0.4, 0.42], [0.45; 3])] {
            let near_grey = Material::phong(kd, ks, 30.0).unwrap();
            assert!(near_grey.lobe_channel_ratios().is_none());
        }
        let (n, wo) = frame();
        let bits: Vec<_> = (0..3).map(|i| random_bits(5, 17 + i)).collect();
        let (cache, lookup) = cache_with(&bits);
        let state = cache.read();
        let product = ProductDistribution::new(&env, &mat, n, wo, 5).unwrap();
        let part = product.lobe_part(&env, &mat.diffuse_lobe(), n, wo).unwrap();
        let cells = part.bsdf_cells().iter().zip(product.bsdf_cells());
        assert!(cells.into_iter().all(|(d, b)| d <= b));
        let tables = ControlTables::new(&product, &chroma, 5);
        let interp = Interpolant::new(&state, &lookup, Some((&tables, &product, &env)));
        let guided = product.guided(interp.cell_visibility(&state, 5)).unwrap();
        let anchor = ShadingPoint {
            origin: Vec3::ZERO,
            normal: n,
            wo,
            material: mat,
        };
        let lobes =
            LobeControl::new(&product, &anchor, (&state, &lookup), &chroma, &env, None).unwrap();
        let sp = ShadingPoint {
            normal: Vec3::new(0.3, 0.9, -0.2).normalize(),
            ..anchor
        };
        let mixture = Mixture::new(
            &env,
            &sp,
            Some(&product),
            Some(&guided),
            &Techniques::CONTROL_VARIATE,
        );
        let (mut sums, mut part_sums, mut w_sums) =
            (CvSums::default(), CvSums::default(), CvSums::default());
        for i in 0..300_000u64 {
            let rng = SampleRng::new(5, i, 0);
            let (g, gd) = match mixture.sample(rng.get2(0), rng.get(2)) {
                Some(d) => {
                    let g = control_sample(&state, &interp, &chroma, d.square)
                        .value
                        .map(|v| v * d.product_pdf / d.pdf);
                    (g, g.map(|v| v * lobes.share(d.square)))
                }
                None => ([0.0; 3], [0.0; 3]),
            };
            sums.add(Vec3::ZERO, g);
            part_sums.add(Vec3::ZERO, gd);
            w_sums.add(Vec3::ZERO, lobes.w(g, gd, &interp.j));
        }
        assert_mean_within_4_se(&sums, interp.j, "g/p");
        assert_mean_within_4_se(&part_sums, lobes.j, "g_d/p");
        assert_mean_within_4_se(&w_sums, [0.0; 3], "W");
        assert!((0..3).all(|c| lobes.j[c] > 0.0 && lobes.j[c] < interp.j[c]));
    }

    /// The mean of the samples `sums` holds (as `W`) lies within 4 of their standard errors
    /// of `want`, per channel.
    fn assert_mean_within_4_se(sums: &CvSums, want: [f64; 3], what: &str) {
        let (mean, var) = sums.estimate([-1.0; 3]);
        for c in 0..3 {
            let z = (mean[c] - want[c]) / var[c].sqrt();
            assert!(
                z.abs() < 4.0,
                "{what}, channel {c}: {} vs {} ({z:.2} SE)",
                mean[c],
                want[c]
            );
        }
    }

    #[test]
    fn the_sun_replaces_the_records_on_the_peaks_exactly() {
        // J with the point's own sun visibility on the peaks against a plain sum over the
        // finest grid, each texel's Ṽ the sun's where it is a peak and the records' blend
        // elsewhere; records coarser and finer than the cells.
        let env = test_sky(256);
        let chroma = MapChroma::new(&env);
        let sun = chroma.sun().expect("the test sky's peaks are one sun");
        let sky_sun = Vec3::new(0.4, 0.6, -0.5).normalize();
        assert!(sun.dot(sky_sun) > 1f32.to_radians().cos(), "{sun}");
        let mat = Material::phong([0.3; 3], [0.5; 3], 20.0).unwrap();
        let (n, wo) = frame();
        let product = ProductDistribution::new(&env, &mat, n, wo, 5).unwrap();
        let e = env.resolution().trailing_zeros();
        for m in [3u32, 5, 6] {
            let bits: Vec<_> = (0..3).map(|i| random_bits(m, 31 + i)).collect();
            let (cache, lookup) = cache_with(&bits);
            let state = cache.read();
            let tables = ControlTables::new(&product, &chroma, m);
            let interp = Interpolant::new(&state, &lookup, Some((&tables, &product, &env)));
            assert_eq!(interp.sun, None);
            let p = product.level();
            let f = e.max(p).max(m);
            let side = 1u32 << f;
            let omega = texel_solid_angle(side);
            for v_sun in [0.0, 1.0] {
                let sunny = interp.with_sun(&state, &tables, &product, v_sun);
                assert_eq!(sunny.sun, Some(v_sun));
                let mut want = [0.0f64; 3];
                for code in 0..side * side {
                    let t = morton_decode(code);
                    let map_code = code >> (2 * (f - e));
                    let l = env.texel(morton_decode(map_code));
                    let cell = morton_encode(t.x >> (f - p), t.y >> (f - p));
                    let b = product.bsdf_cells()[cell as usize] as f64 * omega;
                    let y = crate::lights::envmap::luminance(l.into()) * b;
                    let kappa = chroma.control_colour(map_code, interp.region_level);
                    let z = morton_encode(t.x >> (f - m), t.y >> (f - m)) as usize;
                    let v = match chroma.peak_index(map_code) {
                        Some(_) => v_sun,
                        None => interp
                            .ids()
                            .iter()
                            .zip(interp.betas())
                            .filter(|(&id, _)| state.store().bits(id as usize).get(z))
                            .map(|(_, &b)| b as f64)
                            .sum(),
                    };
                    want = std::array::from_fn(|c| want[c] + kappa[c] * y * v);
                }
                assert!(
                    close(sunny.j, want, 1e-9),
                    "M = {m}, sun {v_sun}: {:?} vs {want:?}",
                    sunny.j
                );
            }
        }
        // Without records nothing changes: J stays 0 and the samples' Ṽ too.
        let empty = Interpolant::EMPTY;
        let state = cache_with(&[random_bits(5, 1)]).0;
        let tables = ControlTables::new(&product, &chroma, 5);
        let same = empty.with_sun(&state.read(), &tables, &product, 1.0);
        assert_eq!((same.j, same.sun), ([0.0; 3], None));
    }

    #[test]
    fn the_control_variate_averages_to_j() {
        // E[g/p] = J: product samples of a sky against three random records. The mean of
        // g/p over N samples must lie within 4 standard errors (from the same samples).
        // 256²: the sun's texels are peaks with their own colour.
        let env = test_sky(256);
        let chroma = MapChroma::new(&env);
        let mat = Material::phong([0.3; 3], [0.5; 3], 20.0).unwrap();
        let (n, wo) = frame();
        for m in [3u32, 5, 6] {
            let bits: Vec<_> = (0..3).map(|i| random_bits(m, 7 + i)).collect();
            let (cache, lookup) = cache_with(&bits);
            let state = cache.read();
            let product = ProductDistribution::new(&env, &mat, n, wo, 5).unwrap();
            let tables = ControlTables::new(&product, &chroma, m);
            let interp = Interpolant::new(&state, &lookup, Some((&tables, &product, &env)));
            // g/p of 200k product samples of seed `seed`.
            let sample_sums = |interp: &Interpolant, seed: u64| {
                let mut sums = CvSums::default();
                for i in 0..200_000u64 {
                    let rng = SampleRng::new(seed, i, 0);
                    let u = DVec2::new(rng.get(0) as f64, rng.get(1) as f64);
                    let s = product.sample_point(&env, u);
                    let g = control_sample(&state, interp, &chroma, s.square);
                    sums.add(Vec3::ZERO, g.value);
                }
                sums
            };
            let sums = sample_sums(&interp, 3);
            assert_mean_within_4_se(&sums, interp.j, &format!("g/p at M = {m}"));
            // The same with the point's sun visibility on the peaks.
            for v_sun in [0.0, 1.0] {
                let sunny = interp.with_sun(&state, &tables, &product, v_sun);
                let what = format!("g/p at M = {m}, sun {v_sun}");
                assert_mean_within_4_se(&sample_sums(&sunny, 5), sunny.j, &what);
            }
            // Ṽ at a sample equals Σ β_i V_i of the records' bits at its texel.
            let p = DVec2::new(0.3, 0.7);
            let z = record_texel_code(p, m) as usize;
            let expect: f64 = interp
                .ids()
                .iter()
                .zip(interp.betas())
                .map(|(&id, &b)| {
                    if state.store().bits(id as usize).get(z) {
                        b as f64
                    } else {
                        0.0
                    }
                })
                .sum();
            assert!((interp.eval(&state, p).0 - expect).abs() < 1e-12);
            // The texel of a square point is the texel of its direction.
            let d = square_to_sphere(p.as_vec2());
            let t = crate::sampling::octahedral::texel_of(d, 1 << m);
            assert_eq!(morton_encode(t.x, t.y) as usize, z);
        }
    }

    #[test]
    fn cv_sums_give_the_mean_and_variance_of_z_minus_alpha_w() {
        let samples: Vec<(Vec3, [f64; 3])> = (0..50u64)
            .map(|i| {
                let a = to_unit_f64(hash4(1, i, 0, 0));
                let b = to_unit_f64(hash4(1, i, 0, 1));
                (
                    Vec3::new(a as f32, 2.0 * a as f32, 0.0),
                    [a - 0.5 + 0.1 * b, b, 0.0],
                )
            })
            .collect();
        let mut sums = CvSums::default();
        for (z, w) in &samples {
            sums.add(*z, *w);
        }
        for alpha in [0.0, 0.7, 1.0, 2.0] {
            let (mean, var) = sums.estimate([alpha; 3]);
            for c in 0..3 {
                let y: Vec<f64> = samples
                    .iter()
                    .map(|(z, w)| z[c] as f64 - alpha * w[c])
                    .collect();
                let n = y.len() as f64;
                let m = y.iter().sum::<f64>() / n;
                let v = y.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / (n - 1.0) / n;
                assert!((mean[c] - m).abs() < 1e-12 && (var[c] - v).abs() < 1e-12 * (1.0 + v));
            }
        }
        // Channel 2: Z = 0 and W = 0, so zero variance, never negative or NaN.
        assert_eq!(sums.estimate([1.0; 3]).1[2], 0.0);
        let one = {
            let mut s = CvSums::default();
            s.add(Vec3::ONE, [1.0; 3]);
            s
        };
        assert!(one.estimate([1.0; 3]).1.iter().all(|v| v.is_infinite()));
        assert_eq!(CvSums::default().estimate([1.0; 3]).0, [0.0; 3]);
    }

    #[test]
    fn neighbour_alphas_pool_the_window_without_the_pixel() {
        let (w, h) = (7usize, 5usize);
        let sums: Vec<CvSums> = (0..w * h)
            .map(|i| {
                let mut s = CvSums::default();
                for k in 0..6u64 {
                    let a = to_unit_f64(hash4(9, i as u64, k, 0));
                    let b = to_unit_f64(hash4(9, i as u64, k, 1));
                    // Z = 0.8 W + noise in channel 0; W constant in channel 1.
                    s.add(Vec3::new((0.8 * a + 0.3 * b) as f32, 1.0, 0.0), [a, 0.0, a]);
                }
                s
            })
            .collect();
        let alphas = neighbour_alphas(&sums, w, h, 2);
        for y in 0..h {
            for x in 0..w {
                let (mut cov, mut var) = (0.0, 0.0);
                for yy in y.saturating_sub(2)..(y + 3).min(h) {
                    for xx in x.saturating_sub(2)..(x + 3).min(w) {
                        if (xx, yy) != (x, y) {
                            let (c, v) = sums[yy * w + xx].centred(0);
                            cov += c;
                            var += v;
                        }
                    }
                }
                let a = alphas[y * w + x];
                assert!((a[0] - (cov / var).clamp(0.0, ALPHA_MAX)).abs() < 1e-12);
                assert_eq!(a[1], 1.0, "no variance in W: alpha does not matter");
                assert_eq!(a[2], 0.0, "Z = 0 is uncorrelated with W");
            }
        }
        // A pixel's own samples do not move its alpha.
        let mut changed = sums.clone();
        changed[2 * w + 3].add(Vec3::splat(1e6), [1e6; 3]);
        let again = neighbour_alphas(&changed, w, h, 2);
        assert_eq!(again[2 * w + 3], alphas[2 * w + 3]);
        assert_ne!(again[2 * w + 4], alphas[2 * w + 4]);
        // Clamped: perfectly anti-correlated neighbours give 0, steep ones ALPHA_MAX.
        let steep: Vec<CvSums> = (0..9)
            .map(|i| {
                let mut s = CvSums::default();
                for k in 0..3 {
                    let a = (i * 3 + k) as f64;
                    s.add(Vec3::new(10.0 * a as f32, -(a as f32), 0.0), [a, a, 0.0]);
                }
                s
            })
            .collect();
        let a = neighbour_alphas(&steep, 3, 3, 1);
        assert!(a
            .iter()
            .all(|a| a[0] == ALPHA_MAX && a[1] == 0.0 && a[2] == 1.0));
    }
}
