//! `Σ weights[i]` over the set bits `i` of one 64-bit word of a record: the integral of
//! `L B~` over the visible texels of a partial word (CAM08 §5.5), branch-free.
//!
//! Every form adds in the same order — lane `j` of eight sums `weights[8k + j]` for
//! `k = 0..8` in turn, then the lanes pair up as `((0+4)+(2+6)) + ((1+5)+(3+7))` — so the
//! AVX-512, AVX2 and portable kernels return the same bits on every CPU. Adding `+0.0` for
//! a clear bit (AVX2, portable) equals not adding (AVX-512's masked add): the weights and
//! partial sums are `>= +0`.

/// The sum in the documented order, portable form.
#[inline(always)]
pub(super) fn masked_sum_portable(bits: u64, weights: &[f64; 64]) -> f64 {
    let mut acc = [0.0f64; 8];
    for k in 0..8 {
        let byte = (bits >> (8 * k)) as u32;
        for (j, a) in acc.iter_mut().enumerate() {
            *a += if byte >> j & 1 != 0 {
                weights[8 * k + j]
            } else {
                0.0
            };
        }
    }
    ((acc[0] + acc[4]) + (acc[2] + acc[6])) + ((acc[1] + acc[5]) + (acc[3] + acc[7]))
}

/// AVX-512: one masked add of eight weights per byte of `bits`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[inline]
pub(super) fn masked_sum_avx512(bits: u64, weights: &[f64; 64]) -> f64 {
    use std::arch::x86_64::*;
    let mut acc = _mm512_setzero_pd();
    for k in 0..8 {
        // SAFETY: `8k + 8 <= 64` weights; unaligned load.
        let w = unsafe { _mm512_loadu_pd(weights.as_ptr().add(8 * k)) };
        acc = _mm512_mask_add_pd(acc, (bits >> (8 * k)) as u8, acc, w);
    }
    reduce_lanes(acc)
}

/// The module's order over eight lanes: `(a0+a4, …, a3+a7)` and then [`reduce_pairs`].
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[inline]
fn reduce_lanes(acc: std::arch::x86_64::__m512d) -> f64 {
    use std::arch::x86_64::*;
    reduce_pairs(_mm256_add_pd(
        _mm512_castpd512_pd256(acc),
        _mm512_extractf64x4_pd::<1>(acc),
    ))
}

/// AVX2: lanes 0–3 and 4–7 as two accumulators, a nibble of `bits` masking each load.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
pub(super) fn masked_sum_avx2(bits: u64, weights: &[f64; 64]) -> f64 {
    use std::arch::x86_64::*;
    let low = _mm256_setr_epi64x(1, 2, 4, 8);
    let high = _mm256_setr_epi64x(16, 32, 64, 128);
    let (mut acc_low, mut acc_high) = (_mm256_setzero_pd(), _mm256_setzero_pd());
    for k in 0..8 {
        let byte = _mm256_set1_epi64x(((bits >> (8 * k)) & 0xff) as i64);
        let mask_low = _mm256_cmpeq_epi64(_mm256_and_si256(byte, low), low);
        let mask_high = _mm256_cmpeq_epi64(_mm256_and_si256(byte, high), high);
        // SAFETY: `8k + 8 <= 64` weights; unaligned loads.
        let (w_low, w_high) = unsafe {
            (
                _mm256_loadu_pd(weights.as_ptr().add(8 * k)),
                _mm256_loadu_pd(weights.as_ptr().add(8 * k + 4)),
            )
        };
        acc_low = _mm256_add_pd(acc_low, _mm256_and_pd(w_low, _mm256_castsi256_pd(mask_low)));
        acc_high = _mm256_add_pd(
            acc_high,
            _mm256_and_pd(w_high, _mm256_castsi256_pd(mask_high)),
        );
    }
    reduce_pairs(_mm256_add_pd(acc_low, acc_high))
}

/// `(h0 + h2) + (h1 + h3)` of `halves = [a0+a4, a1+a5, a2+a6, a3+a7]`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
#[inline]
fn reduce_pairs(halves: std::arch::x86_64::__m256d) -> f64 {
    use std::arch::x86_64::*;
    let pairs = _mm_add_pd(
        _mm256_castpd256_pd128(halves),
        _mm256_extractf128_pd::<1>(halves),
    );
    _mm_cvtsd_f64(_mm_add_sd(pairs, _mm_unpackhi_pd(pairs, pairs)))
}

/// The weights of one word's 64 texels.
#[derive(Clone, Copy, Debug)]
pub(super) enum WordWeights<'a> {
    /// Texel by texel.
    Given(&'a [f64; 64]),
    /// `cells[i >> shift] as f64 * texels[i]`: a factor per cell of `2^shift` texels
    /// (`shift >= 2`), `cells` starting at the word's first cell (the product's `B~` at
    /// cells coarser than the record's texels, times the map's luminance).
    Product {
        cells: &'a [f32],
        shift: u32,
        texels: &'a [f64; 64],
    },
}

impl<'a> WordWeights<'a> {
    /// The 64 weights, written into `buf` when they are a product.
    #[inline(always)]
    pub(super) fn expand<'b>(self, buf: &'b mut [f64; 64]) -> &'b [f64; 64]
    where
        'a: 'b,
    {
        match self {
            WordWeights::Given(w) => w,
            WordWeights::Product {
                cells,
                shift,
                texels,
            } => {
                let per_cell = 1usize << shift.min(6);
                let rows = buf
                    .chunks_exact_mut(per_cell)
                    .zip(texels.chunks_exact(per_cell));
                for ((w, l), &b) in rows.zip(cells) {
                    for (w, &l) in w.iter_mut().zip(l) {
                        *w = b as f64 * l;
                    }
                }
                buf
            }
        }
    }
}

/// `Σ` of `weights` over the set bits of `bits` (the module's order), portable form;
/// `buf` is scratch.
#[inline(always)]
pub(super) fn word_sum_portable(bits: u64, weights: WordWeights, buf: &mut [f64; 64]) -> f64 {
    masked_sum_portable(bits, weights.expand(buf))
}

/// [`word_sum_portable`] with AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
pub(super) fn word_sum_avx2(bits: u64, weights: WordWeights, buf: &mut [f64; 64]) -> f64 {
    masked_sum_avx2(bits, weights.expand(buf))
}

/// [`word_sum_portable`] with AVX-512 (`buf` unused: a product is formed in registers).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[inline]
pub(super) fn word_sum_avx512(bits: u64, weights: WordWeights, _buf: &mut [f64; 64]) -> f64 {
    match weights {
        WordWeights::Given(w) => masked_sum_avx512(bits, w),
        WordWeights::Product {
            cells,
            shift,
            texels,
        } => masked_product_sum_avx512(bits, cells, shift, texels),
    }
}

/// The masked sum of `cells[i >> shift] as f64 * texels[i]` ([`WordWeights::Product`]):
/// each cell's factor widened once and spread over its texels by a permute.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[inline]
fn masked_product_sum_avx512(bits: u64, cells: &[f32], shift: u32, texels: &[f64; 64]) -> f64 {
    use std::arch::x86_64::*;
    debug_assert!(shift >= 2);
    // The word spans `64 >> shift` cells (at most 16), or lies inside one.
    let spanned = (64usize >> shift.min(6)).min(cells.len());
    let load_mask = ((1u32 << spanned) - 1) as u16;
    // SAFETY: the load reads only the `spanned <= cells.len()` lanes its mask enables.
    let factors = unsafe { _mm512_maskz_loadu_ps(load_mask, cells.as_ptr()) };
    let low = _mm512_cvtps_pd(_mm512_castps512_ps256(factors));
    let high = _mm512_cvtps_pd(_mm256_castpd_ps(_mm512_extractf64x4_pd::<1>(
        _mm512_castps_pd(factors),
    )));
    let lane = _mm512_setr_epi64(0, 1, 2, 3, 4, 5, 6, 7);
    let shift = _mm512_set1_epi64(shift.min(63) as i64);
    let mut acc = _mm512_setzero_pd();
    for k in 0..8 {
        let cell = _mm512_srlv_epi64(
            _mm512_add_epi64(lane, _mm512_set1_epi64(8 * k as i64)),
            shift,
        );
        let factor = _mm512_permutex2var_pd(low, cell, high);
        // SAFETY: `8k + 8 <= 64` texels; unaligned load.
        let texel = unsafe { _mm512_loadu_pd(texels.as_ptr().add(8 * k)) };
        let product = _mm512_mul_pd(factor, texel);
        acc = _mm512_mask_add_pd(acc, (bits >> (8 * k)) as u8, acc, product);
    }
    reduce_lanes(acc)
}

/// The sum with the best kernel this CPU has (detected once; one call per word, for
/// callers off the hot path). A match on [`crate::simd::level`] rather than
/// [`crate::simd::dispatch`]: the per-set sums are inlined into the interpolated kernels,
/// so under `dispatch` they would either be compiled with AVX-512 VL too or cost a second
/// call per word.
pub(super) fn word_sum(bits: u64, weights: WordWeights, buf: &mut [f64; 64]) -> f64 {
    #[cfg(target_arch = "x86_64")]
    {
        use crate::simd::{level, SimdLevel};
        match level() {
            // SAFETY (both): the CPU has the features, detected by `crate::simd`.
            SimdLevel::Avx512 => return unsafe { word_sum_avx512(bits, weights, buf) },
            SimdLevel::Avx2 => return unsafe { word_sum_avx2(bits, weights, buf) },
            _ => {}
        }
    }
    word_sum_portable(bits, weights, buf)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::rng::{hash4, to_unit_f64};

    #[test]
    fn every_masked_sum_kernel_agrees_bit_for_bit_with_the_portable_sum() {
        for case in 0..2000u64 {
            // Weights over many magnitudes, so that any other order would round
            // differently; bits from empty through single bits to full.
            let weights: [f64; 64] = std::array::from_fn(|i| {
                let u = to_unit_f64(hash4(7, case, i as u64, 0));
                let e = (hash4(7, case, i as u64, 1) % 40) as i32 - 20;
                u * 2f64.powi(e)
            });
            let bits = match case {
                0 => 0,
                1 => u64::MAX,
                2..=65 => 1u64 << (case - 2),
                _ => hash4(8, case, 0, 0) & hash4(8, case, 1, 0).rotate_left(case as u32),
            };
            let expected = masked_sum_portable(bits, &weights);
            let plain: f64 = (0..64)
                .filter(|i| bits >> i & 1 == 1)
                .map(|i| weights[i])
                .sum();
            assert!(
                (expected - plain).abs() <= 1e-13 * plain,
                "{expected} vs {plain}"
            );
            let mut buf = [0.0; 64];
            let given = WordWeights::Given(&weights);
            assert_eq!(
                word_sum(bits, given, &mut buf).to_bits(),
                expected.to_bits()
            );
            // The same weights as a product of a factor per cell and one per texel, at
            // every cell size from 4 texels to more than the word.
            let shift = 2 + (case % 6) as u32;
            let cells: Vec<f32> = (0..16)
                .map(|c| to_unit_f64(hash4(9, case, c, 0)) as f32)
                .collect();
            let texels = weights;
            let product = WordWeights::Product {
                cells: &cells[..(64 >> shift.min(6)).max(1)],
                shift,
                texels: &texels,
            };
            let expanded: [f64; 64] = std::array::from_fn(|i| cells[i >> shift] as f64 * texels[i]);
            let expected_product = masked_sum_portable(bits, &expanded);
            let portable = word_sum_portable(bits, product, &mut buf);
            assert_eq!(portable.to_bits(), expected_product.to_bits());
            let dispatched = word_sum(bits, product, &mut buf);
            assert_eq!(dispatched.to_bits(), expected_product.to_bits());
            #[cfg(target_arch = "x86_64")]
            {
                use std::arch::is_x86_feature_detected as has;
                // SAFETY (each): the features were detected just before.
                if has!("avx512f") {
                    let got = unsafe { masked_sum_avx512(bits, &weights) };
                    assert_eq!(got.to_bits(), expected.to_bits(), "AVX-512, case {case}");
                    let got = unsafe { word_sum_avx512(bits, product, &mut buf) };
                    assert_eq!(got.to_bits(), expected_product.to_bits(), "case {case}");
                }
                if has!("avx2") {
                    let got = unsafe { masked_sum_avx2(bits, &weights) };
                    assert_eq!(got.to_bits(), expected.to_bits(), "AVX2, case {case}");
                    let got = unsafe { word_sum_avx2(bits, product, &mut buf) };
                    assert_eq!(got.to_bits(), expected_product.to_bits(), "case {case}");
                }
            }
        }
    }
}
