//! `J = Σ β_i J_i`, the integral of the cache's interpolated visibility against one shading
//! point's product (CAM08 §3 eq. 2 and §5.5): `J_c = Σ_r κ_c(r) Σ_i β_i J_{i,r}`, the
//! control variate's integral, with `κ_c(r)` the colour of the map's region `r`
//! ([`crate::lights::envmap::chroma::MapChroma`]) and `J_{i,r} = ∫_r L B~ V_i dω`.
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

use crate::lights::envmap::chroma::{MapChroma, Peak, MAX_REGION_LEVEL};
use crate::lights::envmap::product::ProductDistribution;
use crate::lights::envmap::EnvMap;
use crate::sampling::distribution::QuadPyramid;
use crate::sampling::octahedral::texel_solid_angle;
use crate::simd::{Kernel, Level, SimdLevel};
use crate::visibility::record::{word_level, Coverage, VisibilityView};

use super::masked_sum::{word_sum, word_sum_portable, WordWeights};
#[cfg(target_arch = "x86_64")]
use super::masked_sum::{word_sum_avx2, word_sum_avx512};
use super::MAX_KEPT;

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
    /// records' `v` (of a peak's record texel; [`Interpolant::with_sun`](super::Interpolant::with_sun)).
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
